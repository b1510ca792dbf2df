"""Data-parallel training on torch.distributed: what the on-policy base needs from the job.

Every process of a job (launched by torchrun: `torchrun --nproc-per-node N -m agents train ...`,
or `smpl-envs train ... --nproc N`, which starts torchrun) steps its own worlds and trains its
own copy of the agent; the copies stay identical because everything that moves them is reduced
across the processes:

- gradients, averaged after every minibatch's backward pass (`GradientSync`: one all-reduce of
  the flattened gradient, "allreduce", or torch's DistributedDataParallel, "ddp"), before the
  clip, so every rank clips and steps on the same numbers;
- running normaliser statistics (observations, returns, AMP's discriminator input): each
  update's batch moments are combined across the ranks (`reduce_moments`), so every rank folds
  in the moments of the union of the ranks' batches, as one process that saw them all would;
- the episode statistics (`gather_rows`), the step count (`sum`), how many minibatches an update
  takes (`minibatch_count`: the ranks' collective steps must pair up even when their rollouts
  hold different numbers of valid transitions) and whether training goes on (`all_true`: one
  rank's callback stopping stops all).

The agent finds the job by itself: `current()` describes the default process group when one is
initialised with more than one process, and a single process (every method a no-op that
returns its input) otherwise, so one process trains exactly as it did before this module.
`init()` starts the process group from torchrun's environment; a user's own torchrun script may
call it, or `torch.distributed.init_process_group` itself.

A collective that fails or waits past the job's timeout (a process died or stalled) is a
`PeerError` naming the operation and the rank, not a hang.
"""
from __future__ import annotations

import contextlib
import datetime
import hashlib
import inspect
import os
import sys
from typing import Callable, Iterable, Iterator, TypeVar

import torch
import torch.distributed as dist
from torch import nn

from .rollout import minibatch_count

T = TypeVar("T")

DEFAULT_TIMEOUT_S = 1800.0
"""how long a collective waits for the other processes before the job ends with a PeerError; it
must exceed the longest time one rank spends alone (rank 0's evaluations and checkpoints)"""
GRAD_SYNCS = ("allreduce", "ddp")
"""how gradients are averaged: one all-reduce of the flattened gradient after backward (the
default: works with any loss), or DistributedDataParallel (bucketed all-reduces overlapping the
backward pass; every trainable parameter must take part in every loss)"""
_timeout_s: float | None = None  # the timeout `init` started the process group with (None: started elsewhere)
ENV_VARS = ("RANK", "WORLD_SIZE", "LOCAL_RANK", "MASTER_ADDR", "MASTER_PORT")  # what torchrun sets


class PeerError(RuntimeError):
    """A collective of a data-parallel job failed or timed out: another process died or stalled."""


def initialized() -> bool:
    """Whether this process has a default process group (started by `init` or by its caller)."""
    return dist.is_available() and dist.is_initialized()


def launched() -> bool:
    """Whether this process is one of several that torchrun started (WORLD_SIZE > 1)."""
    return int(os.environ.get("WORLD_SIZE", "1")) > 1


def local_rank() -> int:
    return int(os.environ.get("LOCAL_RANK", "0"))


def shares_gpus() -> bool:
    """Whether this machine runs more processes of the job than it has GPUs (they then share
    them, and NCCL, which needs one GPU per process, cannot connect them)."""
    return int(os.environ.get("LOCAL_WORLD_SIZE", "1")) > max(torch.cuda.device_count(), 1)


def rank_device(device: str) -> str:
    """The torch device a process of the job trains on for the setting `device`: "auto" and
    "cuda" become this process's GPU (cuda:LOCAL_RANK, modulo the GPUs there are, so processes
    share GPUs when there are more of them); a device with an index, or the CPU, stays."""
    if str(device) == "auto":
        device = "cuda" if torch.cuda.is_available() else "cpu"
    if str(device) == "cuda" and torch.cuda.is_available():
        return f"cuda:{local_rank() % torch.cuda.device_count()}"
    return str(device)


def init(timeout_s: float = DEFAULT_TIMEOUT_S, backend: str | None = None) -> "DataParallel":
    """Start the default process group from torchrun's environment (its rendezvous: RANK,
    WORLD_SIZE, MASTER_ADDR, MASTER_PORT) and return the job as `current()` sees it. Backend
    (None): Gloo for CPU tensors, and NCCL for CUDA tensors where every process has a GPU of its
    own (Gloo carries GPU tensors through the host where processes share GPUs). A process group
    already started is kept."""
    global _timeout_s
    if not dist.is_initialized():
        missing = [v for v in ENV_VARS if v not in os.environ]
        if missing:
            raise RuntimeError(f"agents.distributed.init needs torchrun's environment; {', '.join(missing)} not set "
                               "(launch with torchrun --nproc-per-node N, or smpl-envs train ... --nproc N)")
        if not timeout_s > 0:
            raise ValueError(f"the collective timeout must be a positive number of seconds, got {timeout_s!r}")
        if backend is None:
            gpus = torch.cuda.is_available() and dist.is_nccl_available() and not shares_gpus()
            backend = "cpu:gloo,cuda:nccl" if gpus else "gloo"
        if torch.cuda.is_available():  # NCCL's communicators bind to the current device
            torch.cuda.set_device(local_rank() % torch.cuda.device_count())
        dist.init_process_group(backend, timeout=datetime.timedelta(seconds=float(timeout_s)))
        _timeout_s = float(timeout_s)
    return current()


def shutdown() -> None:
    """End the default process group (if one is running)."""
    if initialized():
        dist.destroy_process_group()


def current(device: torch.device | str = "cpu") -> "DataParallel":
    """The job this process belongs to, for an agent on `device`: the default process group's
    when one runs with more than one process, else a single process."""
    if not initialized() or dist.get_world_size() < 2:
        return DataParallel()
    device = torch.device(device)
    # Collectives run where the backend takes the tensors: NCCL on this process's GPU, Gloo on the host.
    nccl = device.type == "cuda" and dist.get_backend() in ("nccl", "cpu:gloo,cuda:nccl")
    return DataParallel(dist.get_rank(), dist.get_world_size(), device if nccl else torch.device("cpu"), _timeout_s)


def torchrun_command(nproc: int, args: Iterable[str]) -> list[str]:
    """The command that runs `python -m agents ARGS` as `nproc` processes on this machine:
    torchrun (torch.distributed.run, as a module of this interpreter) with its standalone
    rendezvous."""
    if isinstance(nproc, bool) or not isinstance(nproc, int) or nproc < 1:
        raise ValueError(f"--nproc must be a positive number of processes, got {nproc!r}")
    return [sys.executable, "-m", "torch.distributed.run", "--standalone", f"--nproc-per-node={nproc}",
            "-m", "agents", *args]


class DataParallel:
    """One process's place in a data-parallel job: `rank` of `world_size`, the `device`
    collectives run on and their `timeout_s`. `DataParallel()` is a single process: every
    method returns its input unchanged (no copies, no collectives)."""

    def __init__(self, rank: int = 0, world_size: int = 1, device: torch.device | str = "cpu",
                 timeout_s: float | None = None):
        self.rank, self.world_size = int(rank), int(world_size)
        self.device, self.timeout_s = torch.device(device), timeout_s

    @property
    def enabled(self) -> bool:
        return self.world_size > 1

    @property
    def main(self) -> bool:
        """Whether this is rank 0, the process that writes logs, checkpoints and evaluations."""
        return self.rank == 0

    def __repr__(self) -> str:
        return f"DataParallel(rank={self.rank}, world_size={self.world_size}, device={self.device})"

    def describe(self) -> str:
        backend = dist.get_backend() if self.enabled else "none"
        processes = f"{self.world_size} process{'es' if self.world_size > 1 else ''}"
        return f"{processes} ({backend}, collectives on {self.device})"

    # ------------------------------------------------------------------ errors
    @contextlib.contextmanager
    def collective(self, what: str) -> Iterator[None]:
        """Turn a failed or timed-out collective into a PeerError that says what happened."""
        try:
            yield
        except (RuntimeError, dist.DistError) as e:
            if isinstance(e, PeerError) or not _is_collective_error(e):
                raise
            wait = f" (or did not answer within the collective timeout, {self.timeout_s:g} s)" if self.timeout_s else ""
            raise PeerError(f"rank {self.rank} of {self.world_size}: {what} failed: another process of the job died "
                            f"or stalled{wait}: {' '.join(str(e).split())[:300]}") from e

    # ------------------------------------------------------------------ seeds
    def seed(self, seed: int | None, stride: int = 1) -> int | None:
        """This rank's seed: `seed` + rank x `stride` (None stays None). Rank 0 keeps `seed`."""
        return None if seed is None else int(seed) + self.rank * int(stride)

    def reseed_torch(self) -> None:
        """Give ranks > 0 their own torch stream, derived from the state every rank restored
        from one checkpoint (so a resumed job is as reproducible as the checkpoint)."""
        if self.rank == 0:
            return
        digest = hashlib.sha256(torch.get_rng_state().numpy().tobytes() + self.rank.to_bytes(4, "little")).digest()
        torch.manual_seed(int.from_bytes(digest[:8], "little") >> 1)

    # ------------------------------------------------------------------ collectives
    def _to(self, x: torch.Tensor) -> torch.Tensor:
        return x.to(self.device)

    def broadcast_modules(self, modules: Iterable[nn.Module]) -> None:
        """Every parameter and buffer of `modules` as rank 0 has them."""
        if not self.enabled:
            return
        with self.collective("broadcasting rank 0's weights"), torch.no_grad():
            for module in modules:
                for t in [*module.parameters(), *module.buffers()]:
                    buf = self._to(t.detach())
                    dist.broadcast(buf, src=0)
                    if buf is not t:
                        t.copy_(buf)

    def broadcast_object(self, obj: T) -> T:
        """Rank 0's `obj` (picklable) on every rank."""
        if not self.enabled:
            return obj
        box = [obj]
        with self.collective("broadcasting from rank 0"):
            dist.broadcast_object_list(box, src=0, device=self.device)
        return box[0]

    def reduce_moments(self, n: float, mean: torch.Tensor, var: torch.Tensor) -> tuple[float, torch.Tensor,
                                                                                        torch.Tensor]:
        """(count, mean, population variance) of the union of every rank's batch, from each
        rank's own: Chan et al.'s combination, in rank order, identical on every rank."""
        if not self.enabled:
            return n, mean, var
        packed = torch.cat([torch.tensor([float(n)], dtype=torch.float64, device=mean.device),
                            mean.reshape(-1).double(), var.reshape(-1).double()])
        parts = [torch.empty_like(packed, device=self.device) for _ in range(self.world_size)]
        with self.collective("combining normaliser statistics"):
            dist.all_gather(parts, self._to(packed))
        k = mean.numel()
        total, m, v = 0.0, torch.zeros_like(packed[1:1 + k]), torch.zeros_like(packed[1:1 + k])
        for p in parts:
            p = p.to(mean.device)
            nb = float(p[0])
            if nb == 0:
                continue
            mb, vb = p[1:1 + k], p[1 + k:]
            new = total + nb
            delta = mb - m
            v = (v * total + vb * nb + delta.square() * total * nb / new) / new
            m = m + delta * nb / new
            total = new
        return total, m.reshape(mean.shape).to(mean.dtype), v.reshape(var.shape).to(var.dtype)

    def minibatch_count(self, n: int, batch_size: int) -> int:
        """How many minibatches an epoch over this rank's `n` transitions takes: one process's
        `rollout.minibatch_count`; in a job, the smallest of the ranks' counts (a rank with more
        transitions takes a little larger minibatches), none anywhere if a rank has none: the
        ranks' collective steps must pair up."""
        count = minibatch_count(n, batch_size)
        if not self.enabled:
            return count
        t = torch.tensor([count], dtype=torch.int64, device=self.device)
        with self.collective("agreeing on the minibatch count"):
            dist.all_reduce(t, op=dist.ReduceOp.MIN)
        return int(t)

    def all_true(self, flag: bool) -> bool:
        """Whether `flag` holds on every rank."""
        if not self.enabled:
            return bool(flag)
        t = torch.tensor([int(bool(flag))], dtype=torch.int64, device=self.device)
        with self.collective("agreeing whether to go on"):
            dist.all_reduce(t, op=dist.ReduceOp.MIN)
        return bool(t)

    def sum(self, value: int) -> int:
        """The sum over the ranks of an integer."""
        if not self.enabled:
            return value
        t = torch.tensor([int(value)], dtype=torch.int64, device=self.device)
        with self.collective("summing the step count"):
            dist.all_reduce(t)
        return int(t)

    def mean(self, value: float) -> float:
        """The mean over the ranks of a number."""
        if not self.enabled:
            return value
        t = torch.tensor([float(value)], dtype=torch.float64, device=self.device)
        with self.collective("averaging a statistic"):
            dist.all_reduce(t)
        return float(t) / self.world_size

    def gather_rows(self, rows: torch.Tensor) -> torch.Tensor:
        """Every rank's (n_r, d) rows, concatenated in rank order (the n_r may differ)."""
        if not self.enabled:
            return rows
        with self.collective("gathering episode statistics"):
            n = torch.tensor([len(rows)], dtype=torch.int64, device=self.device)
            counts = [torch.zeros_like(n) for _ in range(self.world_size)]
            dist.all_gather(counts, n)
            counts = [int(c) for c in counts]
            padded = torch.zeros(max(counts), *rows.shape[1:], dtype=rows.dtype, device=self.device)
            padded[:len(rows)] = rows.to(self.device)
            parts = [torch.empty_like(padded) for _ in range(self.world_size)]
            dist.all_gather(parts, padded)
        return torch.cat([p[:c] for p, c in zip(parts, counts)]).to(rows.device)

    def gradient_sync(self, module: nn.Module, params: Iterable[torch.Tensor], mode: str = "allreduce"
                      ) -> "GradientSync":
        return GradientSync(self, module, params, mode)


class GradientSync:
    """Averages the gradients of `params` (those an optimiser steps, of `module`) over the job's
    processes after each backward pass. Use as

        loss = sync.loss(lambda: compute_loss(...))   # inside DDP's forward in "ddp" mode
        optimizer.zero_grad(); sync.backward(loss)     # backward, then the average
        clip_grad_norm_(...); optimizer.step()

    In one process both calls are exactly `compute_loss(...)` and `loss.backward()`."""

    def __init__(self, dp: DataParallel, module: nn.Module, params: Iterable[torch.Tensor], mode: str = "allreduce"):
        if mode not in GRAD_SYNCS:
            raise ValueError(f"grad_sync must be one of {GRAD_SYNCS}, got {mode!r}")
        self.dp, self.module, self.mode = dp, module, mode
        self.params = [p for p in params if p.requires_grad]
        self._ddp = None
        if dp.enabled and mode == "ddp":
            device = next(iter(self.params)).device if self.params else torch.device("cpu")
            # Buffers (the normalisers) are kept equal by reduce_moments, not re-sent each forward
            # (the option's name changed in torch 2.13).
            ddp = nn.parallel.DistributedDataParallel
            no_buffer_sync = ({"forward_sync_buffers": False} if "forward_sync_buffers" in
                              inspect.signature(ddp.__init__).parameters else {"broadcast_buffers": False})
            with dp.collective("setting up DistributedDataParallel"):
                self._ddp = ddp(_Closure(module), device_ids=[device.index] if device.type == "cuda" else None,
                                **no_buffer_sync)

    def loss(self, compute: Callable[[], T]) -> T:
        """compute(), the loss and whatever else it returns (inside DDP's forward in "ddp" mode)."""
        return self._ddp(compute) if self._ddp is not None else compute()

    def backward(self, loss: torch.Tensor) -> None:
        """loss.backward(), then every rank holds the mean over the ranks of the gradients."""
        if not self.dp.enabled:
            loss.backward()
            return
        with self.dp.collective("averaging gradients"):
            loss.backward()  # DDP's all-reduces run inside
            if self._ddp is None:
                self._average()

    @torch.no_grad()
    def _average(self) -> None:
        # A parameter without a gradient here (its branch of the loss unused on this rank) counts
        # as a zero gradient: every rank must send the same layout.
        grads = [p.grad if p.grad is not None else torch.zeros_like(p) for p in self.params]
        if not grads:
            return
        flat = torch.cat([g.reshape(-1) for g in grads]).to(self.dp.device)
        dist.all_reduce(flat)
        flat /= self.dp.world_size
        flat = flat.to(grads[0].device)
        offset = 0
        for p, g in zip(self.params, grads):
            n = g.numel()
            p.grad = flat[offset:offset + n].view_as(p).clone() if p.grad is None else p.grad.copy_(
                flat[offset:offset + n].view_as(p))
            offset += n


class _Closure(nn.Module):
    """The module DDP wraps: its forward runs a closure over the real module's methods, so a
    loss made of several calls (evaluate_actions, value_targets ...) is one DDP forward."""

    def __init__(self, module: nn.Module):
        super().__init__()
        self.module = module

    def forward(self, compute: Callable[[], T]) -> T:
        return compute()


def _is_collective_error(e: BaseException) -> bool:
    if isinstance(e, dist.DistError):
        return True
    text = str(e).lower()
    return any(s in text for s in ("gloo", "nccl", "timed out", "timeout", "connection", "peer", "socket",
                                   "process group", "broken pipe"))


__all__ = ["DataParallel", "GradientSync", "PeerError", "init", "shutdown", "current", "launched", "rank_device",
           "torchrun_command", "DEFAULT_TIMEOUT_S", "GRAD_SYNCS"]
