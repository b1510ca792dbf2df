"""Data-parallel training throughput: 1 process against N processes (torchrun), and the two ways
of averaging gradients (one all-reduce of the flat gradient, or DistributedDataParallel), side by
side in one run.

    python benchmarks/bench_distributed.py                     # imitation_ppo, 32 worlds in all, 1 vs 2 processes
    python benchmarks/bench_distributed.py --worlds 64 --nprocs 1 2 4 --repeats 5
    python benchmarks/bench_distributed.py --device cuda --worlds 4096 --set env.kwargs.backend=warp
    python benchmarks/bench_distributed.py --set agent.hyperparams.n_epochs=2   # any recipe value

Every configuration trains the recipe's agent (`--recipe`, default `imitation_ppo`) on the same
number of worlds in all (`--worlds`, split evenly over the processes) with the same minibatch of
the job (the recipe's batch_size, split likewise: a recipe's env.num_envs and batch_size are per
process), so the job does the same work per iteration and only its division differs. One
process runs without torch.distributed at all (the code path of every single-process run);
N > 1 processes run under torchrun (torch.distributed.run, standalone rendezvous, Gloo on
the CPU). Each measurement is a fresh job: one untimed warm-up iteration (first reset,
allocations, DDP's setup), then `--iterations` timed ones; the figures are samples/s of the job
over whole iterations (collection + update + logging) and seconds per update (rank 0's
`_update`, the part the gradient averaging is in). Each repeat measures every configuration in
turn (so load on the machine hits them alike); the table holds medians of `--repeats`.

The simulator's threads per process default to the machine's cores divided by the processes
(`--sim-threads`), so the configurations use the same cores; torch runs on `--threads` threads
(default 1).
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from agents.distributed import GRAD_SYNCS
from agents.on_policy import OnPolicyConfig

ROOT = Path(__file__).resolve().parents[1]


def worker(config: dict, out: Path) -> None:
    """One process of a measurement (rank 0 writes the result)."""
    import torch

    torch.set_num_threads(config["threads"])
    from agents import distributed
    from agents.recipes import load_recipe
    from agents.run import new_agent

    dp = distributed.init(600) if distributed.launched() else distributed.current()
    try:
        recipe = load_recipe(config["recipe"], config["overrides"])
        device = distributed.rank_device(config["device"]) if dp.enabled else config["device"]
        agent = new_agent(recipe, verbose=0, log_dir=None, tensorboard=False, device=device,
                          update_threads=config["update_threads"], **({"grad_sync": config["grad_sync"]}
                                                                       if dp.enabled else {}))
        per_iteration = agent.config.n_steps * agent.env.num_envs * dp.world_size
        agent.learn(per_iteration, progress_bar=False)  # warm-up
        update, update_s = agent._update, []

        def timed_update(buf):
            t = time.perf_counter()
            update(buf)
            update_s.append(time.perf_counter() - t)

        agent._update = timed_update
        dp.all_true(True)  # start together
        start, t = agent.num_timesteps, time.perf_counter()
        agent.learn(config["iterations"] * per_iteration, progress_bar=False, reset_num_timesteps=False)
        rate = (agent.num_timesteps - start) / (time.perf_counter() - t)
        if dp.main:
            out.write_text(json.dumps({"samples_per_s": rate, "update_s": float(np.median(update_s))}))
        agent.close()
    finally:
        distributed.shutdown()


def measure(args, nproc: int, grad_sync: str) -> dict:
    share = args.worlds // nproc
    overrides = [*args.set, f"env.num_envs={share}", f"agent.hyperparams.batch_size={args.batch_size // nproc}",
                 f"env.kwargs.num_threads={args.sim_threads or max(1, (os.cpu_count() or 1) // nproc)}"]
    config = {"recipe": args.recipe, "overrides": overrides, "device": args.device, "threads": args.threads,
              "update_threads": args.update_threads, "grad_sync": grad_sync, "iterations": args.iterations}
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "result.json"
        worker_args = [str(Path(__file__).resolve()), "--worker", json.dumps(config), "--out", str(out)]
        command = [sys.executable, *worker_args] if nproc == 1 else [
            sys.executable, "-m", "torch.distributed.run", "--standalone", f"--nproc-per-node={nproc}", *worker_args]
        env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]),
               "OMP_NUM_THREADS": str(args.threads)}
        done = subprocess.run(command, env=env, capture_output=True, text=True)
        if done.returncode != 0 or not out.is_file():
            raise SystemExit(f"{nproc} process(es), {grad_sync}: failed\n{done.stderr[-4000:]}")
        return json.loads(out.read_text())


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--recipe", default="imitation_ppo")
    p.add_argument("--worlds", type=int, default=None, help="worlds of the whole job (default: the recipe's num_envs)")
    p.add_argument("--nprocs", type=int, nargs="+", default=[1, 2], help="process counts to compare")
    p.add_argument("--grad-syncs", nargs="+", default=list(GRAD_SYNCS), choices=GRAD_SYNCS)
    p.add_argument("--iterations", type=int, default=3, help="timed iterations per measurement")
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--threads", type=int, default=1, help="torch CPU threads per process")
    p.add_argument("--update-threads", type=int, default=None, help="torch CPU threads while updating")
    p.add_argument("--sim-threads", type=int, default=None,
                   help="simulator threads per process (default: CPU cores / processes)")
    p.add_argument("--device", default="cpu")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="override a recipe value")
    p.add_argument("--worker", help=argparse.SUPPRESS)
    p.add_argument("--out", type=Path, help=argparse.SUPPRESS)
    args = p.parse_args()
    if args.worker:
        return worker(json.loads(args.worker), args.out)

    import torch

    from agents.recipes import load_recipe

    recipe = load_recipe(args.recipe, args.set)
    args.worlds = args.worlds or recipe["env"]["num_envs"]
    args.batch_size = recipe["agent"]["hyperparams"].get("batch_size", OnPolicyConfig.batch_size)
    for n in args.nprocs:
        if args.worlds % n or args.batch_size % n:
            raise SystemExit(f"--worlds {args.worlds} and batch_size {args.batch_size} must divide by {n} processes")
    configs = [(n, "allreduce") for n in args.nprocs if n == 1] + [
        (n, mode) for n in args.nprocs if n > 1 for mode in args.grad_syncs]
    print(f"{os.cpu_count()} CPU cores, torch {torch.__version__}, {args.device}; {recipe['env']['id']} "
          f"({args.recipe}), {args.worlds} worlds and minibatches of {args.batch_size} for the whole job; "
          f"{args.iterations} timed iterations a measurement, {args.repeats} repeats (medians)", flush=True)
    results = {c: [] for c in configs}
    for r in range(args.repeats):
        for c in configs:
            results[c].append(measure(args, *c))
        print(f"repeat {r + 1}: " + ", ".join(
            f"{n}x{mode if n > 1 else ''}: {results[(n, mode)][-1]['samples_per_s']:.0f}/s" for n, mode in configs),
            flush=True)
    base = np.median([m["samples_per_s"] for m in results[configs[0]]])
    print("| processes | worlds each | gradients | samples/s | vs first row | update s |")
    print("|---|---|---|---|---|---|")
    for n, mode in configs:
        rate = np.median([m["samples_per_s"] for m in results[(n, mode)]])
        update = np.median([m["update_s"] for m in results[(n, mode)]])
        print(f"| {n} | {args.worlds // n} | {mode if n > 1 else '-'} | {rate:.0f} | {rate / base:.2f} | {update:.3f} |")


if __name__ == "__main__":
    main()
