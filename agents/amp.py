"""Adversarial Motion Priors: PPO whose reward mixes the task's with a learned style reward.

A discriminator D sees windows of `amp_num_frames` consecutive AMP feature frames (232 each: root
height and rotation, root velocities, joint rotations and velocities, hands and feet) and learns to
score windows cut from the reference motion ("demo") high and windows the policy produced low. The
policy is paid -log(max(1 - sigmoid(D), 1e-4)) x `style_reward_scale` for looking like the demo.

What AMP takes from the env is only what the env core documents for every SMPL suite env:

- `env.motion_lib`, the clips of the task (the references of an imitation task, the style clips
  of a goal task made with `motions=`, e.g. `gym.make_vec("SMPL/Speed-v0", motions=["walk",
  "run"])`): demo windows are cut from it;
- `info["amp_obs"]`, the AMP feature frame of every world, at reset and after every step;
- `info["motion_id"]`, `info["motion_time"]` at reset: the clip frame each world started from,
  whose past seeds that world's window history.

An env without them gets a clear error. The discriminator, its loss, the replay buffer and the
rollout hooks that turn each step's frames into windows (`StyleWindows`) are parts of their own
(`discriminator.py`); AMP is PPO with them: demo windows cut from the clips, `_shape_rewards`
(the mixed reward) and `_update_extra` (D's update).
"""
from __future__ import annotations

import dataclasses
from typing import Iterable

import numpy as np
import torch
from torch import nn

from .discriminator import WINDOWS, Discriminator, ReplayBuffer, StyleWindows, reference_motion
from .optim import adam, flush_subnormals_
from .ppo import PPO, PPOConfig
from .rollout import RolloutBuffer, minibatches
from .vec import autoreset_mode


# Above this many library frames (~460 MB of features) demo windows are computed per minibatch.
DEMO_TABLE_MAX_FRAMES = 500_000


@dataclasses.dataclass
class AMPConfig(PPOConfig):
    """AMP's hyperparameters: every PPO one, and the style reward's and discriminator's."""

    task_reward_weight: float = 0.5
    """reward = task_reward_weight r_task + style_reward_weight r_style (PHC: 0.5 / 0.5)"""
    style_reward_weight: float = 0.5
    """weight of the style reward (0 / 1 with the task weight for pure style)"""
    style_reward_scale: float = 2.0
    """multiplies -log(max(1 - sigmoid(D), 1e-4))"""
    amp_num_frames: int = 10
    """frames per discriminator window"""
    disc_hidden: list[int] = dataclasses.field(default_factory=lambda: [1024, 512])
    """discriminator MLP hidden sizes (PHC: [1024, 512])"""
    disc_activation: str = "relu"
    """discriminator hidden activation (PHC: ReLU)"""
    disc_learning_rate: float = 1e-4
    """Adam step size of the discriminator"""
    disc_grad_penalty: float = 5.0
    """weight of the gradient penalty on demo windows"""
    disc_logit_reg: float = 0.01
    """weight of the squared logit-layer weights"""
    disc_weight_decay: float = 1e-4
    """weight of all squared discriminator weights"""
    disc_epochs: int | None = None
    """passes over each rollout's windows per update (None: n_epochs)"""
    disc_batch_size: int | None = None
    """policy windows per discriminator step, with as many demo windows (None: batch_size). D
    takes one step per policy minibatch, on this many of its windows: the anchors train D on
    4,096 windows of each 16,384-transition minibatch (PHC's amp_minibatch_size), a quarter"""
    replay_size: int = 50_000
    """policy windows kept for D to revisit (the anchors use 200k; CPU memory is smaller: 50k
    windows of 10 frames are ~460 MB)"""
    replay_keep_prob: float = 0.01
    """chance that a rollout's window enters the replay buffer once it is full"""

    def __post_init__(self) -> None:
        super().__post_init__()
        for name in ("disc_epochs", "disc_batch_size"):
            value = getattr(self, name)
            if value is not None and value < 1:
                raise ValueError(f"{name} must be >= 1 (or None), got {value}")


class AMP(PPO):
    """PPO + adversarial motion prior (REFERENCE.md section 6).

    Takes every PPO argument; its hyperparameters are the fields of `AMPConfig` (PPO's and the
    style reward's and discriminator's). The env must offer what the module docstring lists.
    """

    config_class = AMPConfig

    # ------------------------------------------------------------------ setup
    def _build(self, obs_dim, action_space, policy=None) -> None:
        super()._build(obs_dim, action_space, policy)
        cfg = self.config
        from smpl_envs.features import AMP_LAYOUT, layout_size

        self.frame_dim = layout_size(AMP_LAYOUT)
        self.disc = Discriminator(self.frame_dim, cfg.amp_num_frames, cfg.disc_hidden,
                                  cfg.disc_activation).to(self.device)
        self.disc_optimizer = adam(self.disc.net.parameters(), lr=cfg.disc_learning_rate)
        self.replay = ReplayBuffer(cfg.replay_size, self.frame_dim * cfg.amp_num_frames, self.device)

    def set_env(self, env, n_envs: int = 1, env_kwargs: dict | None = None,
                override_settings: Iterable[str] = ()) -> None:
        super().set_env(env, n_envs, env_kwargs, override_settings)
        self.motion_lib = reference_motion(self.env)
        self._demo_rng = np.random.default_rng(self.data_parallel.seed(self.config.seed))
        self._frame_table = self._build_frame_table()

    def _rollout_hooks(self) -> StyleWindows:
        return StyleWindows(self._reference_windows, self.config.amp_num_frames, self.frame_dim,
                            autoreset_mode(self.env), self.device)

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
        k = self.config.amp_num_frames
        if self._frame_table is None:
            return lib.amp_features(ids, np.asarray(times), k).reshape(len(ids), -1)
        last = np.rint(np.asarray(times) * lib.fps).astype(np.int64)
        local = np.clip(last[:, None] + np.arange(1 - k, 1), 0, lib.lengths[ids, None] - 1)
        return self._frame_table[lib.starts[ids, None] + local].reshape(len(ids), -1)

    def _sample_demo(self, n: int) -> torch.Tensor:
        lib = self.motion_lib
        ids = lib.sample_motions(n, self._demo_rng)
        times = self._demo_rng.integers(0, lib.lengths[ids]) / lib.fps  # exact frames, as the env steps
        return torch.as_tensor(self._reference_windows(ids, times), device=self.device)

    # ------------------------------------------------------------------ rewards and D's update
    @torch.no_grad()
    def style_reward(self, windows: torch.Tensor) -> torch.Tensor:
        """-log(max(1 - sigmoid(D(w)), 1e-4)) x style_reward_scale for (B, frames * 232) windows."""
        prob = torch.sigmoid(self.disc(windows))
        return -torch.log((1.0 - prob).clamp(min=1e-4)) * self.config.style_reward_scale

    def _shape_rewards(self, buf: RolloutBuffer) -> torch.Tensor:
        cfg = self.config
        T, N = buf.rewards.shape
        style = self.style_reward(buf.extras[WINDOWS].reshape(T * N, -1)).reshape(T, N) * buf.valid
        valid = buf.valid.bool()
        if valid.any():
            self.logger.record("amp/style_reward_mean", style[valid].mean().item())
            self.logger.record("amp/task_reward_mean", buf.rewards[valid].mean().item())
        return cfg.task_reward_weight * buf.rewards + cfg.style_reward_weight * style

    def _update_extra(self, buf: RolloutBuffer) -> None:
        cfg = self.config
        windows = buf.extras[WINDOWS]
        agent = windows.reshape(-1, windows.shape[-1])[buf.valid_mask()]
        n = len(agent)
        count = self.data_parallel.minibatch_count(n, cfg.batch_size)  # as many D steps on every rank
        if count == 0:
            return
        stats: dict[str, list[float]] = {k: [] for k in ("loss", "bce", "grad_penalty", "agent_acc", "demo_acc")}
        for _ in range(cfg.disc_epochs or cfg.n_epochs):
            for mb in minibatches({"fake": agent}, cfg.batch_size, count):
                fake = mb["fake"][: cfg.disc_batch_size or cfg.batch_size]  # a shuffled minibatch's head
                size = len(fake)
                if self.replay.n > 0:  # half the negatives from older policies
                    fake = torch.cat([fake[: size - size // 2], self.replay.sample(size // 2)])
                real = self._sample_demo(size)
                self.disc.norm.update(real.reshape(-1, self.frame_dim))
                for k, v in self._disc_step(real, fake).items():
                    stats[k].append(v)
        flush_subnormals_(self.disc_optimizer)  # its weight decay makes them (see the function)
        keep = torch.rand(n, device=self.device) < cfg.replay_keep_prob
        self.replay.add(agent[keep] if self.replay.n > 0 else agent[: self.replay.size])
        for k, v in stats.items():
            if v:
                self.logger.record(f"amp/disc_{k}", float(np.mean(v)))

    def _disc_step(self, real: torch.Tensor, fake: torch.Tensor) -> dict[str, float]:
        cfg = self.config
        sync = self._gradient_sync(self.disc, self.disc_optimizer)
        loss, stats = sync.loss(lambda: self.disc.loss(real, fake, cfg.disc_grad_penalty, cfg.disc_logit_reg,
                                                       cfg.disc_weight_decay))
        self.disc_optimizer.zero_grad(set_to_none=True)
        sync.backward(loss)
        nn.utils.clip_grad_norm_(self.disc.net.parameters(), cfg.max_grad_norm)
        self.disc_optimizer.step()
        return stats

    def discriminator_accuracy(self, real: torch.Tensor, fake: torch.Tensor) -> float:
        """Fraction of windows D labels right (demo logit > 0, policy logit < 0)."""
        with torch.no_grad():
            right = torch.cat([self.disc(real) > 0, self.disc(fake) < 0])
        return right.float().mean().item()

    def _replicated_modules(self) -> list[nn.Module]:
        return [*super()._replicated_modules(), self.disc]

    # ------------------------------------------------------------------ persistence
    def _extra_state(self) -> dict:
        # The replay buffer is not saved (hundreds of MB); a resumed run refills it in a few updates.
        return {"disc": self.disc.state_dict(), "disc_optimizer": self.disc_optimizer.state_dict()}

    def _load_extra_state(self, state: dict) -> None:
        self.disc.load_state_dict(state["disc"])
        self.disc_optimizer.load_state_dict(state["disc_optimizer"])


__all__ = ["AMP", "AMPConfig", "reference_motion"]
