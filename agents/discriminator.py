"""The adversarial motion prior's parts, for any agent that wants a style reward (AMP in
`amp.py`; a distillation or composer agent later): the discriminator network and its loss, the
replay buffer of past policy windows, and the rollout hooks that cut each step's AMP features
into windows. What it reads from an env is what every SMPL suite env documents (`amp.py`'s
module docstring): `env.motion_lib` (`reference_motion`) and `info["amp_obs"]`,
`info["motion_id"]`, `info["motion_time"]`.
"""
from __future__ import annotations

from typing import Callable

import numpy as np
import torch
from gymnasium.vector import AutoresetMode
from torch import nn
from torch.nn import functional as F

from .networks import mlp
from .normalizer import RunningNorm
from .rollout import RolloutBuffer, RolloutHooks
from .vec import final_info_array

WINDOWS = "amp_windows"  # the rollout buffer's field of policy windows, (n_steps, n_envs, frames * 232)


class Discriminator(nn.Module):
    """MLP over a normalised window of frames -> one logit (demo windows high, policy ones low)."""

    def __init__(self, frame_dim: int, num_frames: int, hidden=(1024, 512), activation: str = "relu",
                 obs_clip: float | None = 5.0):
        super().__init__()
        self.frame_dim, self.num_frames = frame_dim, num_frames
        self.norm = RunningNorm(frame_dim, clip=obs_clip)
        self.net = mlp(frame_dim * num_frames, hidden, 1, activation, out_gain=1.0)

    def normalize(self, windows: torch.Tensor) -> torch.Tensor:
        """(B, num_frames * frame_dim) raw windows, each frame normalised by the same statistics."""
        return self.norm(windows.reshape(-1, self.num_frames, self.frame_dim)).reshape(windows.shape[0], -1)

    def logits(self, normalized: torch.Tensor) -> torch.Tensor:
        return self.net(normalized).squeeze(-1)

    def forward(self, windows: torch.Tensor) -> torch.Tensor:
        """(B, num_frames * frame_dim) raw windows -> (B,) logits."""
        return self.logits(self.normalize(windows))

    @property
    def logit_layer(self) -> nn.Linear:
        return self.net[-1]

    def loss(self, real: torch.Tensor, fake: torch.Tensor, grad_penalty: float, logit_reg: float,
             weight_decay: float) -> tuple[torch.Tensor, dict[str, float]]:
        """(loss, its terms) of raw demo (`real`) and policy (`fake`) windows: BCE, plus the
        gradient penalty on demo windows, the squared logit-layer weights and all squared weights."""
        # The penalty is on D's slope in normalised units: in raw units a feature the demo holds
        # constant (tiny std) would make any slope look enormous.
        real = self.normalize(real).detach().requires_grad_(True)
        real_logit, fake_logit = self.logits(real), self(fake)
        bce = 0.5 * (F.binary_cross_entropy_with_logits(real_logit, torch.ones_like(real_logit))
                     + F.binary_cross_entropy_with_logits(fake_logit, torch.zeros_like(fake_logit)))
        grad = torch.autograd.grad(real_logit.sum(), real, create_graph=True)[0]
        penalty = grad.square().sum(-1).mean()
        logit_weights = self.logit_layer.weight.square().sum()
        weights = sum(p.square().sum() for n, p in self.net.named_parameters() if n.endswith("weight"))
        loss = bce + grad_penalty * penalty + logit_reg * logit_weights + weight_decay * weights
        with torch.no_grad():
            return loss, {"loss": loss.item(), "bce": bce.item(), "grad_penalty": penalty.item(),
                          "agent_acc": (fake_logit < 0).float().mean().item(),
                          "demo_acc": (real_logit > 0).float().mean().item()}


class ReplayBuffer:
    """Fixed-size ring of past policy windows, so D does not forget what older policies did."""

    def __init__(self, size: int, dim: int, device: torch.device):
        self.size, self.dim, self.device = int(size), dim, device
        self.data: torch.Tensor | None = None  # allocated on first insert
        self.n = self.head = 0

    def add(self, x: torch.Tensor) -> None:
        if self.size == 0 or len(x) == 0:
            return
        if self.data is None:
            self.data = torch.zeros(self.size, self.dim, device=self.device)
        x = x[-self.size:]
        idx = (self.head + torch.arange(len(x), device=self.device)) % self.size
        self.data[idx] = x
        self.head = int((self.head + len(x)) % self.size)
        self.n = min(self.n + len(x), self.size)

    def sample(self, k: int) -> torch.Tensor:
        return self.data[torch.randint(self.n, (k,), device=self.device)]


class StyleWindows(RolloutHooks):
    """Rollout hooks that keep each world's last `num_frames` AMP frames and write the window of
    every step into the rollout buffer's `WINDOWS` field.

    reference_windows(motion_ids, times) -> (N, num_frames * frame_dim): the demo windows ending
    at those clip times; a world that (re)starts an episode starts on a reference frame, so its
    history is the reference's past.
    """

    def __init__(self, reference_windows: Callable[[np.ndarray, np.ndarray], np.ndarray], num_frames: int,
                 frame_dim: int, autoreset: AutoresetMode, device: torch.device):
        self.reference_windows = reference_windows
        self.num_frames, self.frame_dim = num_frames, frame_dim
        self.autoreset, self.device = autoreset, device
        self.history: torch.Tensor | None = None  # (n_envs, num_frames, frame_dim)
        self.windows: torch.Tensor | None = None  # the buffer's field being filled

    def _restart(self, info: dict, ids: np.ndarray) -> torch.Tensor:
        # The demo windows come from the host library, once per episode start (a NumPy lookup).
        motion_id, motion_time = (_host(info[k])[ids] for k in ("motion_id", "motion_time"))
        windows = self.reference_windows(motion_id, motion_time)
        return torch.as_tensor(windows, dtype=torch.float32, device=self.device).reshape(
            len(ids), self.num_frames, self.frame_dim)

    def on_reset(self, info: dict) -> None:
        _require_amp_obs(info)
        self.history = self._restart(info, np.arange(len(info["amp_obs"])))

    def on_rollout_start(self, buffer: RolloutBuffer) -> None:
        self.windows = buffer.extra(WINDOWS, self.num_frames * self.frame_dim)

    def on_step(self, t: int, info: dict, done, valid) -> None:
        """`done` and `valid` come as the env's arrays (NumPy, or tensors of a torch-native env);
        the history stays a tensor on the agent's device either way."""
        _require_amp_obs(info)
        frame = torch.as_tensor(final_info_array(info, "amp_obs", done, self.autoreset), dtype=torch.float32,
                                device=self.device)
        live = torch.as_tensor(valid, device=self.device)
        h = self.history
        h[live] = torch.cat([h[live, 1:], frame[live, None]], 1)
        self.windows[t] = h.reshape(len(h), -1)
        # Worlds that start a new episode now: NextStep resets on the step after `done` (the
        # invalid ones), SameStep within the `done` step; both report the new episode's state.
        fresh = ~live if self.autoreset == AutoresetMode.NEXT_STEP else torch.as_tensor(done, device=self.device)
        if fresh.any():
            ids = np.flatnonzero(fresh.cpu().numpy())
            h[torch.as_tensor(ids, device=self.device)] = self._restart(info, ids)


def _host(x) -> np.ndarray:
    return x.detach().cpu().numpy() if isinstance(x, torch.Tensor) else np.asarray(x)


def _require_amp_obs(info: dict) -> None:
    if "amp_obs" not in info:
        raise ValueError("AMP needs info['amp_obs'] from the env's reset and step; this env does not report it")


def reference_motion(env):
    """The `motion_lib` a suite env documents (the clips of its task), reached through the
    standard Gymnasium ways of holding an env: the vector env itself (`gym.make_vec`), the env
    under its vector wrappers (`.unwrapped`), or the first env of a `SyncVectorEnv` of
    `gym.make` envs (`envs[0].unwrapped.motion_lib`). A ValueError when there is none."""
    candidates = [env, getattr(env, "unwrapped", None)]
    if getattr(env, "envs", None):
        candidates.append(env.envs[0].unwrapped)
    for candidate in candidates:
        lib = getattr(candidate, "motion_lib", None)
        if lib is not None:
            return lib
    raise ValueError(
        "AMP needs the reference motion the env documents as `env.motion_lib` (every SMPL/ env made with "
        "clips has one: imitation tasks always, goal tasks with motions=[...] for their style) and "
        f"info['amp_obs'] every step; this env has no motion_lib: {getattr(env, 'spec', None) or env}")


__all__ = ["Discriminator", "ReplayBuffer", "StyleWindows", "WINDOWS", "reference_motion"]
