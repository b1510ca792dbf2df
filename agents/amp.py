"""Adversarial Motion Priors: PPO whose reward mixes the task's with a learned style reward.

A discriminator D sees windows of `amp_num_frames` consecutive AMP feature frames (232 each: root
height and rotation, root velocities, joint rotations and velocities, hands and feet) and learns to
score windows cut from the reference motion ("demo") high and windows the policy produced low. The
policy is paid -log(max(1 - sigmoid(D), 1e-4)) x `style_reward_scale` for looking like the demo.

The env must report the frame of every step in `info["amp_obs"]` and expose the `motion_lib` it
samples its reference from: every SMPL suite env does.
"""
from __future__ import annotations

import numpy as np
import torch
from torch import nn
from gymnasium.vector import AutoresetMode
from torch.nn import functional as F

from .networks import mlp
from .normalizer import RunningNorm
from .ppo import PPO
from .vec import final_info_array


# Above this many library frames (~460 MB of features) demo windows are computed per minibatch.
DEMO_TABLE_MAX_FRAMES = 500_000


class Discriminator(nn.Module):
    """MLP over a normalised window of frames -> one logit."""

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


class AMP(PPO):
    """PPO + adversarial motion prior (REFERENCE.md section 6).

    Args (besides every PPO argument):
        task_reward_weight, style_reward_weight: reward = w_task r_task + w_style r_style
            (0.5 / 0.5 as PHC; 0 / 1 for pure style).
        style_reward_scale: multiplies -log(max(1 - sigmoid(D), 1e-4)) (2).
        amp_num_frames: frames per discriminator window (10).
        disc_hidden, disc_activation: discriminator MLP (PHC: [1024, 512], ReLU).
        disc_learning_rate: Adam step size of the discriminator.
        disc_grad_penalty: weight of the gradient penalty on demo windows (5).
        disc_logit_reg: weight of the squared logit-layer weights (0.01).
        disc_weight_decay: weight of all squared discriminator weights (1e-4).
        disc_epochs: passes over each rollout's windows per update (default: n_epochs).
        replay_size, replay_keep_prob: policy-window replay buffer (200k / 0.01 in the anchors;
            the default here is smaller because CPU memory is: 50k windows are ~460 MB).
    """

    def __init__(self, env, *, task_reward_weight: float = 0.5, style_reward_weight: float = 0.5,
                 style_reward_scale: float = 2.0, amp_num_frames: int = 10,
                 disc_hidden=(1024, 512), disc_activation: str = "relu", disc_learning_rate: float = 1e-4,
                 disc_grad_penalty: float = 5.0, disc_logit_reg: float = 0.01, disc_weight_decay: float = 1e-4,
                 disc_epochs: int | None = None, replay_size: int = 50_000, replay_keep_prob: float = 0.01,
                 **ppo_kwargs):
        amp_hp = dict(
            task_reward_weight=float(task_reward_weight), style_reward_weight=float(style_reward_weight),
            style_reward_scale=float(style_reward_scale), amp_num_frames=int(amp_num_frames),
            disc_hidden=[int(h) for h in disc_hidden], disc_activation=disc_activation,
            disc_learning_rate=float(disc_learning_rate), disc_grad_penalty=float(disc_grad_penalty),
            disc_logit_reg=float(disc_logit_reg), disc_weight_decay=float(disc_weight_decay),
            disc_epochs=None if disc_epochs is None else int(disc_epochs), replay_size=int(replay_size),
            replay_keep_prob=float(replay_keep_prob),
        )
        self._amp_hp = amp_hp
        super().__init__(env, **ppo_kwargs)
        self.hyperparams.update(amp_hp)
        for k, v in amp_hp.items():
            setattr(self, k, v)

    # ------------------------------------------------------------------ setup
    def _build(self, obs_dim, action_space) -> None:
        super()._build(obs_dim, action_space)
        hp = self._amp_hp
        from smpl_envs.features import AMP_LAYOUT, layout_size

        self.frame_dim = layout_size(AMP_LAYOUT)
        self.disc = Discriminator(self.frame_dim, hp["amp_num_frames"], hp["disc_hidden"],
                                  hp["disc_activation"]).to(self.device)
        self.disc_optimizer = torch.optim.Adam(self.disc.net.parameters(), lr=hp["disc_learning_rate"])
        self.replay = ReplayBuffer(hp["replay_size"], self.frame_dim * hp["amp_num_frames"], self.device)

    def set_env(self, env, n_envs: int = 1, env_kwargs: dict | None = None) -> None:
        super().set_env(env, n_envs, env_kwargs)
        self.motion_lib = _find_motion_lib(self.env)
        if self.motion_lib is None:
            raise ValueError(
                "AMP needs an env that exposes the `motion_lib` of its reference motion and reports "
                "info['amp_obs'] every step (every SMPL/ env does); this one does not: "
                f"{getattr(self.env, 'spec', None) or self.env}")
        self._demo_rng = np.random.default_rng(self.seed)
        self._frame_table = self._build_frame_table()

    # ------------------------------------------------------------------ windows of AMP frames
    def _build_frame_table(self) -> np.ndarray | None:
        """AMP features of every library frame, (num_frames, 232), when that fits in memory.

        The env steps the reference on its exact frames (policy rate = clip rate), so demo windows
        are cut on exact frames too, and each frame's features are independent of its window.
        Looking them up replaces recomputing ~10k frames per discriminator minibatch (measured:
        a quarter of AMP's training time on walk)."""
        lib = self.motion_lib
        if lib.num_frames > DEMO_TABLE_MAX_FRAMES:
            return None
        frames = np.arange(lib.num_frames)
        ids = np.searchsorted(lib.starts, frames, side="right") - 1
        return lib.amp_features(ids, (frames - lib.starts[ids]) / lib.fps, num_frames=1)[:, 0]

    def _reference_windows(self, motion_ids, times) -> np.ndarray:
        """(N, amp_num_frames * 232) windows of the reference ending at `times` of `motion_ids`."""
        lib, ids = self.motion_lib, np.asarray(motion_ids)
        if self._frame_table is None:
            return lib.amp_features(ids, np.asarray(times), self.amp_num_frames).reshape(len(ids), -1)
        last = np.rint(np.asarray(times) * lib.fps).astype(np.int64)
        local = np.clip(last[:, None] + np.arange(1 - self.amp_num_frames, 1), 0, lib.lengths[ids, None] - 1)
        return self._frame_table[lib.starts[ids, None] + local].reshape(len(ids), -1)

    def _sample_demo(self, n: int) -> torch.Tensor:
        lib = self.motion_lib
        ids = lib.sample_motions(n, self._demo_rng)
        times = self._demo_rng.integers(0, lib.lengths[ids]) / lib.fps  # exact frames, as the env steps
        return torch.as_tensor(self._reference_windows(ids, times), device=self.device)

    def _require_amp_obs(self, info: dict) -> None:
        if "amp_obs" not in info:
            raise ValueError("AMP needs info['amp_obs'] from the env's reset and step; this env does not report it")

    def _on_reset(self, info: dict) -> None:
        self._require_amp_obs(info)
        # A reset world starts on a reference frame, so its history is the reference's past.
        self._history = self._reference_windows(info["motion_id"], info["motion_time"]).reshape(
            -1, self.amp_num_frames, self.frame_dim)

    def _on_rollout_start(self, n_steps: int, n_envs: int) -> None:
        self._windows = torch.zeros(n_steps, n_envs, self.amp_num_frames * self.frame_dim, device=self.device)

    def _on_step(self, t: int, info: dict, done: np.ndarray, valid: np.ndarray) -> None:
        self._require_amp_obs(info)
        frame = final_info_array(info, "amp_obs", done, self.autoreset)
        h = self._history
        h[valid] = np.concatenate([h[valid, 1:], frame[valid, None]], axis=1)
        self._windows[t] = torch.as_tensor(h.reshape(len(h), -1), device=self.device)
        # Worlds that start a new episode now: NextStep resets on the step after `done` (the
        # invalid ones), SameStep within the `done` step; both report the new episode's state.
        fresh = ~valid if self.autoreset == AutoresetMode.NEXT_STEP else done
        if fresh.any():
            ids = np.flatnonzero(fresh)
            h[ids] = self._reference_windows(info["motion_id"][ids], info["motion_time"][ids]).reshape(
                len(ids), self.amp_num_frames, self.frame_dim)

    # ------------------------------------------------------------------ rewards and D's update
    @torch.no_grad()
    def style_reward(self, windows: torch.Tensor) -> torch.Tensor:
        """-log(max(1 - sigmoid(D(w)), 1e-4)) x style_reward_scale for (B, frames * 232) windows."""
        prob = torch.sigmoid(self.disc(windows))
        return -torch.log((1.0 - prob).clamp(min=1e-4)) * self.style_reward_scale

    def _shape_rewards(self, buf: dict) -> torch.Tensor:
        T, N = buf["reward"].shape
        style = self.style_reward(self._windows.reshape(T * N, -1)).reshape(T, N) * buf["valid"]
        valid = buf["valid"].bool()
        if valid.any():
            self.logger.record("amp/style_reward_mean", style[valid].mean().item())
            self.logger.record("amp/task_reward_mean", buf["reward"][valid].mean().item())
        return self.task_reward_weight * buf["reward"] + self.style_reward_weight * style

    def _update_extra(self, buf: dict) -> None:
        agent = self._windows.reshape(-1, self._windows.shape[-1])[buf["valid"].reshape(-1).bool()]
        n = len(agent)
        if n == 0:
            return
        mb = min(self.batch_size, n)
        stats: dict[str, list[float]] = {k: [] for k in ("loss", "bce", "grad_penalty", "agent_acc", "demo_acc")}
        for _ in range(self.disc_epochs or self.n_epochs):
            perm = torch.randperm(n, device=self.device)
            for start in range(0, n - mb + 1, mb):
                fake = agent[perm[start:start + mb]]
                if self.replay.n > 0:  # half the negatives from older policies
                    fake = torch.cat([fake[: mb - mb // 2], self.replay.sample(mb // 2)])
                real = self._sample_demo(mb)
                self.disc.norm.update(real.reshape(-1, self.frame_dim))
                for k, v in self._disc_step(real, fake).items():
                    stats[k].append(v)
        keep = torch.rand(n, device=self.device) < self.replay_keep_prob
        self.replay.add(agent[keep] if self.replay.n > 0 else agent[: self.replay.size])
        for k, v in stats.items():
            if v:
                self.logger.record(f"amp/disc_{k}", float(np.mean(v)))

    def _disc_step(self, real: torch.Tensor, fake: torch.Tensor) -> dict[str, float]:
        # The penalty is on D's slope in normalised units: in raw units a feature the demo holds
        # constant (tiny std) would make any slope look enormous.
        real = self.disc.normalize(real).detach().requires_grad_(True)
        real_logit, fake_logit = self.disc.logits(real), self.disc(fake)
        bce = 0.5 * (F.binary_cross_entropy_with_logits(real_logit, torch.ones_like(real_logit))
                     + F.binary_cross_entropy_with_logits(fake_logit, torch.zeros_like(fake_logit)))
        grad = torch.autograd.grad(real_logit.sum(), real, create_graph=True)[0]
        grad_penalty = grad.square().sum(-1).mean()
        logit_reg = self.disc.logit_layer.weight.square().sum()
        weight_decay = sum(p.square().sum() for n, p in self.disc.net.named_parameters() if n.endswith("weight"))
        loss = (bce + self.disc_grad_penalty * grad_penalty + self.disc_logit_reg * logit_reg
                + self.disc_weight_decay * weight_decay)
        self.disc_optimizer.zero_grad(set_to_none=True)
        loss.backward()
        nn.utils.clip_grad_norm_(self.disc.net.parameters(), self.max_grad_norm)
        self.disc_optimizer.step()
        with torch.no_grad():
            return {"loss": loss.item(), "bce": bce.item(), "grad_penalty": grad_penalty.item(),
                    "agent_acc": (fake_logit < 0).float().mean().item(),
                    "demo_acc": (real_logit > 0).float().mean().item()}

    def discriminator_accuracy(self, real: torch.Tensor, fake: torch.Tensor) -> float:
        """Fraction of windows D labels right (demo logit > 0, policy logit < 0)."""
        with torch.no_grad():
            right = torch.cat([self.disc(real) > 0, self.disc(fake) < 0])
        return right.float().mean().item()

    # ------------------------------------------------------------------ persistence
    def _extra_state(self) -> dict:
        # The replay buffer is not saved (hundreds of MB); a resumed run refills it in a few updates.
        return {"disc": self.disc.state_dict(), "disc_optimizer": self.disc_optimizer.state_dict()}

    def _load_extra_state(self, state: dict) -> None:
        self.disc.load_state_dict(state["disc"])
        self.disc_optimizer.load_state_dict(state["disc_optimizer"])



def _find_motion_lib(vec):
    """The MotionLib behind a suite vector env, or behind the first env of a Sync/Async vector."""
    for candidate in (vec, getattr(vec, "unwrapped", None)):
        lib = getattr(candidate, "motion_lib", None)
        if lib is not None:
            return lib
    envs = getattr(vec, "envs", None)
    if envs:
        return getattr(envs[0].unwrapped, "motion_lib", None)
    return None
