"""PULSE: distil an imitator into a latent motion space (Luo et al., "Universal Humanoid Motion
Representations for Physics-Based Control"; REFERENCE.md sections 4 and 8).

    from agents import PULSE
    model = PULSE("SMPL/Imitation-v0", teacher="tracker", n_envs=16, env_kwargs={"motions": "corpus:train"})
    model.learn(2_000_000).save("pulse.pt")
    env = smpl_envs.wrappers.LatentAction(gym.make("SMPL/Speed-v0"), "pulse.pt")   # any task, latent actions

The policy (`PULSEPolicy`) has three diagonal Gaussians over z in R^32: the encoder E(z | s_p,
s_goal) on the whole imitation observation, the prior R(z | s_p) and the decoder D(a | s_p, z)
on the self observation (`smpl_envs.latent.LatentDecoder`, which holds the prior and the
decoder so that the env side can use them without agents). As PULSE's paper models it, the
encoder's mean is an offset from the prior's (`residual_encoder`), as the downstream tasks'
z = mu_prior + a is.

The algorithm (`PULSE`) is a sibling of PPO on the on-policy base: the base collects rollouts
(the student acts: z sampled from its encoder, decoded into the env's action), a rollout hook
has the teacher label every stored observation in one batch at the rollout's end (DAgger's
relabelling), and `_update` fits the student to the labels:

    loss = ||a_teacher - D(s_p, z)||^2 + smooth_weight ||mu_E(t) - mu_E(t-1)||^2 + beta KL(E || R),

z = mu_E + sigma_E eps (reparameterised), each term a mean over the minibatch and its
dimensions, the smoothness over consecutive steps of one episode; beta goes linearly from
kl_weight_start to kl_weight_end between iterations kl_anneal_start and kl_anneal_end (PULSE's
code: 0.01 to 0.001 between epochs 2500 and 5000); log-variances are clamped to [-5, 2].
Optionally (`kl_free_nats`) each dimension's KL is free up to a number of nats ("free bits",
Kingma et al. 2016), a standard guard against a posterior that collapses onto the prior.

The teacher is any imitation checkpoint of the suite (`teacher`: a path or a shipped policy's
name), acting on the raw observations with its own normaliser. The student's env takes the
teacher's control settings (substeps), but acts with absolute PD targets whatever the teacher's
action mode: absolute actions are the one form every task takes, which is what the decoder is
for. A residual teacher's labels (PD target = next reference joint angles + residual) become the
absolute actions of the same PD targets, from the reference angles the env reports
(`info["next_ref_dof_pos"]`; `smpl_envs.envs.reference.residual_to_absolute`).

Evaluation and videos act with the encoder's mean, decoded: the student as an imitator.
"""
from __future__ import annotations

import dataclasses
from typing import Iterable, Sequence

import gymnasium as gym
import numpy as np
import torch
from torch.distributions import Normal

from smpl_envs.envs.base import PROPRIO_DIM
from smpl_envs.envs.reference import residual_to_absolute
from smpl_envs.humanoid.skeleton import ACTION_SCALE
from smpl_envs.latent import LatentDecoder, split_gaussian

from .checkpoint import load_checkpoint
from .networks import Policy, mlp
from .normalizer import RunningNorm
from .on_policy import OnPolicyAlgorithm, OnPolicyConfig
from .optim import flush_subnormals_
from .policies import load_policy, register_policy
from .rollout import InfoColumn, RolloutBuffer, RolloutHooks

LABELS = "teacher_actions"  # the rollout buffer's field of the teacher's (absolute) actions
REF_DOF = "next_ref_dof_pos"  # the env's info key, and the buffer's field, of the reference angles


def gaussian_kl(mu_q: torch.Tensor, logvar_q: torch.Tensor, mu_p: torch.Tensor, logvar_p: torch.Tensor) -> torch.Tensor:
    """KL(N(mu_q, exp(logvar_q)) || N(mu_p, exp(logvar_p))) per dimension, for diagonal Gaussians."""
    return 0.5 * (logvar_p - logvar_q + (logvar_q.exp() + (mu_q - mu_p).square()) / logvar_p.exp() - 1.0)


def free_bits_kl(mu_q, logvar_q, mu_p, logvar_p, free_nats: float = 0.0) -> tuple[torch.Tensor, torch.Tensor]:
    """(the KL, its cost): the KL of (..., d) Gaussians as a mean over the batch and the d
    dimensions, and the same with each dimension's batch mean raised to at least `free_nats`
    (then it costs, and pulls, nothing below that; with 0 the cost is the KL)."""
    dims = gaussian_kl(mu_q, logvar_q, mu_p, logvar_p).reshape(-1, mu_q.shape[-1]).mean(0)
    kl = dims.mean()
    return kl, (dims.clamp(min=free_nats).mean() if free_nats else kl)


def kl_weight(iteration: int, start: float, end: float, anneal_start: int, anneal_end: int) -> float:
    """beta at `iteration`: `start` until `anneal_start`, then linearly to `end` at `anneal_end`."""
    if iteration <= anneal_start:
        return float(start)
    if iteration >= anneal_end:
        return float(end)
    return float(start + (end - start) * (iteration - anneal_start) / (anneal_end - anneal_start))


@register_policy
class PULSEPolicy(Policy):
    """Encoder, prior and decoder over z (module docstring). Its own actions are latents z; the
    env gets D(s_p, z) clamped to [-1, 1] (`env_action`). Acting deterministically is z =
    the encoder's mean. One running normaliser of the whole observation (clipped at obs_clip);
    its self-observation part is also the decoder's (`LatentDecoder.set_statistics`).

    Args (after the spaces): latent_dim (32), encoder_hidden, prior_hidden, decoder_hidden (MLP
    sizes; PULSE's code: [1536, 1024, 512] for both encoder and prior, [3096, 2048, 1024] for
    the decoder), activation (silu), obs_clip (5), residual_encoder (the encoder's mean is an
    offset from the prior's), encoder_log_std_init (0: the encoder's log std at the start).

    Why encoder_log_std_init: at 0 the encoder starts with unit noise around offsets near 0, so
    the first thing the decoder learns is to ignore z and act from s_p alone; the shipped `pulse`
    (distilled that way) moves its actions by 0.3 % of their range through the whole imitation
    signal in z (`benchmarks/latent_authority.py`). A small start (e.g. -2.5: std 0.08) gives the
    decoder a z worth reading from the first update; the KL term then sets the noise."""

    def __init__(self, obs_dim: int, action_space: gym.spaces.Box | int, *, latent_dim: int = 32,
                 encoder_hidden: Sequence[int] = (512, 256), prior_hidden: Sequence[int] = (512, 256),
                 decoder_hidden: Sequence[int] = (1024, 512), activation: str = "silu", obs_clip: float = 5.0,
                 residual_encoder: bool = True, encoder_log_std_init: float = 0.0):
        super().__init__(obs_dim, action_space, act_dim=latent_dim)
        if not self._unit_box:
            raise ValueError("PULSEPolicy decodes into [-1, 1] actions; the env's action box is "
                             f"[{self.action_space.low.min()}, {self.action_space.high.max()}]")
        if self.obs_dim <= PROPRIO_DIM:
            raise ValueError(f"the encoder reads a goal after the {PROPRIO_DIM} self-observation features; "
                             f"this observation has {self.obs_dim} in all")
        self.residual_encoder = bool(residual_encoder)
        self.obs_norm = RunningNorm(self.obs_dim, clip=obs_clip)
        self.latent = LatentDecoder(PROPRIO_DIM, latent_dim, int(self.action_space.shape[0]),
                                    prior_hidden=list(prior_hidden), decoder_hidden=list(decoder_hidden),
                                    activation=activation, obs_clip=obs_clip)
        self.encoder = mlp(self.obs_dim, list(encoder_hidden), 2 * latent_dim, activation, out_gain=0.01)
        if not np.isfinite(encoder_log_std_init):
            raise ValueError(f"encoder_log_std_init must be a finite number, got {encoder_log_std_init!r}")
        with torch.no_grad():  # the log-variance half of the output: 2 log std
            self.encoder[-1].bias[latent_dim:] = 2.0 * float(encoder_log_std_init)

    @property
    def latent_decoder(self) -> LatentDecoder:
        return self.latent

    def normalize(self, obs: torch.Tensor) -> torch.Tensor:
        return self.obs_norm(obs)

    def update_obs_stats(self, obs: torch.Tensor) -> None:
        self.obs_norm.update(obs)
        self.latent.set_statistics(self.obs_norm.mean[:PROPRIO_DIM], self.obs_norm.var[:PROPRIO_DIM])

    def distributions(self, nobs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """(encoder mean, encoder log-variance, prior mean, prior log-variance) on normalised
        observations."""
        prior_mu, prior_logvar = self.latent.prior(nobs[..., :PROPRIO_DIM])
        mu, logvar = split_gaussian(self.encoder(nobs))
        return (prior_mu + mu if self.residual_encoder else mu), logvar, prior_mu, prior_logvar

    def action_distribution(self, nobs: torch.Tensor) -> Normal:
        mu, logvar, _, _ = self.distributions(nobs)
        return Normal(mu, torch.exp(0.5 * logvar), validate_args=False)

    def value(self, nobs: torch.Tensor) -> torch.Tensor:
        return torch.zeros(nobs.shape[:-1], device=nobs.device)  # no critic: distillation has no returns

    def forward(self, nobs: torch.Tensor):
        return self.action_distribution(nobs), self.value(nobs)

    def decode(self, nobs: torch.Tensor, z: torch.Tensor) -> torch.Tensor:
        """The decoder's actions (unclamped) for normalised observations and latents."""
        return self.latent.decode(nobs[..., :PROPRIO_DIM], z)

    def env_action(self, action: torch.Tensor, obs: torch.Tensor) -> torch.Tensor:
        return self.latent.decode(self.latent.proprio(obs), action).clamp(-1.0, 1.0)


@dataclasses.dataclass
class PULSEConfig(OnPolicyConfig):
    """PULSE's hyperparameters (the on-policy base's first; gamma and gae_lambda go unused)."""

    teacher: str | None = None
    """the imitator to distil: a checkpoint path, a run directory or a shipped policy's name"""
    smooth_weight: float = 0.005
    """alpha: weight of the encoder mean's step-to-step change (PULSE's code: 0.005)"""
    kl_weight_start: float = 0.01
    """beta before the annealing (PULSE's code: 0.01)"""
    kl_weight_end: float = 0.001
    """beta after it (PULSE's code: 0.001)"""
    kl_anneal_start: int = 2500
    """iteration at which beta starts to move (PULSE's code: epoch 2500)"""
    kl_anneal_end: int = 5000
    """iteration at which it arrives (PULSE's code: epoch 5000)"""
    kl_free_nats: float = 0.0
    """free bits: each latent dimension's KL (mean over the minibatch) costs nothing up to this
    many nats (0: PULSE's plain KL). Without it the KL, scaled by Adam to full steps whatever beta
    is, drives the encoder onto the prior while the decoder does not yet read z (docs/pulse.md)"""

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.kl_anneal_end < self.kl_anneal_start:
            raise ValueError(f"kl_anneal_end ({self.kl_anneal_end}) must not come before kl_anneal_start "
                             f"({self.kl_anneal_start})")
        for name in ("smooth_weight", "kl_weight_start", "kl_weight_end", "kl_free_nats"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)!r}")


class TeacherLabels(RolloutHooks):
    """The teacher's actions on a rollout's raw observations, in one batch at its end, as
    absolute actions: a residual teacher's (`residual_scale` not None) converted with the
    reference joint angles the env reported with each observation."""

    def __init__(self, teacher: Policy, residual_scale: float | None, device: torch.device):
        self.teacher, self.residual_scale, self.device = teacher, residual_scale, device
        self.scale = torch.as_tensor(ACTION_SCALE, dtype=torch.float32, device=device)
        act_dim = teacher.action_space.shape[0]
        # a residual teacher's labels need the reference angles stored beside each observation
        self.ref = None if residual_scale is None else InfoColumn(REF_DOF, act_dim, device, missing=(
            f"the student's env reports no info[{REF_DOF!r}], which a residual teacher's labels need: "
            "distil on a reference-tracking task (SMPL/Imitation-v0)"))

    def on_reset(self, info: dict) -> None:
        if self.ref is not None:
            self.ref.on_reset(info)

    def on_rollout_start(self, buffer: RolloutBuffer) -> None:
        self.labels = buffer.extra(LABELS, self.teacher.action_space.shape[0])
        if self.ref is not None:
            self.ref.on_rollout_start(buffer)

    def on_step(self, t: int, info: dict, done: np.ndarray, valid: np.ndarray) -> None:
        if self.ref is not None:
            self.ref.on_step(t, info, done, valid)

    @torch.no_grad()
    def on_rollout_end(self, buffer: RolloutBuffer) -> None:
        obs = buffer.obs.reshape(-1, buffer.obs.shape[-1])
        actions = self.teacher.env_action(self.teacher.act(obs), obs)
        if self.residual_scale is not None:
            ref = self.ref.column.reshape(-1, self.ref.dim)
            actions = residual_to_absolute(actions, ref, self.scale, self.residual_scale)
        self.labels.copy_(actions.reshape(self.labels.shape))


class PULSE(OnPolicyAlgorithm):
    """Online distillation of `teacher` into a PULSEPolicy (module docstring). Arguments: those
    of `OnPolicyAlgorithm` (env, policy, policy_kwargs, device ...) and the fields of
    `PULSEConfig` as keyword arguments; `teacher` is required to train."""

    config_class = PULSEConfig
    default_policy = PULSEPolicy

    # ------------------------------------------------------------------ the teacher
    @property
    def teacher_policy(self) -> Policy:
        """The frozen teacher (loaded on first use, from the `teacher` setting)."""
        if self.__dict__.get("_teacher") is None:
            self._teacher, self._teacher_env = _load_teacher(self.config.teacher)
        return self._teacher

    def _teacher_settings(self) -> dict:
        from smpl_envs import policy_settings

        self.teacher_policy  # noqa: B018 (loads it)
        env_id, kwargs = self._teacher_env
        return policy_settings.trained_settings(env_id, kwargs) if env_id is not None else {}

    def set_env(self, env, n_envs: int = 1, env_kwargs: dict | None = None,
                override_settings: Iterable[str] = ()) -> None:
        """As the base's, with a new agent's env made (from an id) with the teacher's control
        settings and absolute actions, and any env checked for them."""
        from smpl_envs import policy_settings

        self.teacher_policy  # noqa: B018 (loads it, and its env record)
        teacher_id = self._teacher_env[0]
        new = not (hasattr(self, "policy") and self.env_id is not None)
        if new and isinstance(env, str):
            policy_settings.check_task(teacher_id, env)
            env_kwargs = self._student_kwargs(dict(env_kwargs or {}))
        super().set_env(env, n_envs, env_kwargs, override_settings)
        self._check_student_env()

    def _student_kwargs(self, kwargs: dict) -> dict:
        if kwargs.get("action_mode", "absolute") != "absolute":
            raise ValueError("PULSE's student acts with absolute PD targets (action_mode='absolute'), the form every "
                             f"task takes; got action_mode={kwargs['action_mode']!r} (a residual teacher's labels "
                             "are converted)")
        for name, value in self._teacher_settings().items():
            if name in ("action_mode", "residual_scale"):
                continue
            if name in kwargs and kwargs[name] != value:
                raise ValueError(f"{name}={kwargs[name]!r} contradicts the teacher's {name}={value!r}: the student acts "
                                 "at the teacher's control settings")
            kwargs[name] = value
        return {**kwargs, "action_mode": "absolute"}

    def _check_student_env(self) -> None:
        from smpl_envs import policy_settings

        obs_dim = self.env.single_observation_space.shape[0]
        if obs_dim != self.teacher_policy.obs_dim:
            raise ValueError(f"the env observes {obs_dim} features, the teacher {self.teacher_policy.obs_dim}")
        settings = policy_settings.settings_of(self.env)
        if settings.get("action_mode", "absolute") != "absolute":
            raise ValueError("PULSE's student acts with absolute PD targets; make its env with action_mode='absolute'")
        for name, value in self._teacher_settings().items():
            if name not in ("action_mode", "residual_scale") and name in settings and settings[name] != value:
                raise ValueError(f"the env runs {name}={settings[name]!r}, the teacher {name}={value!r}")

    def _rollout_hooks(self) -> RolloutHooks:
        teacher = self.teacher_policy.to(self.device)
        settings = self._teacher_settings()
        residual = settings.get("residual_scale") if settings.get("action_mode") == "residual" else None
        return TeacherLabels(teacher, residual, self.device)

    # ------------------------------------------------------------------ the update
    def _update(self, buf: RolloutBuffer) -> None:
        cfg, pol = self.config, self.policy
        T, N = buf.n_steps, buf.n_envs
        obs = buf.obs.reshape(T * N, -1)
        labels = buf.extras[LABELS].reshape(T * N, -1)
        # Step t's predecessor is step t - 1 of the same world (N rows back) when both are real
        # transitions of one episode.
        valid, dones = buf.valid.bool(), buf.dones.bool()
        has_prev = torch.zeros_like(valid)
        has_prev[1:] = valid[1:] & valid[:-1] & ~dones[:-1]
        has_prev = has_prev.reshape(-1)
        index = torch.arange(T * N, device=obs.device)[valid.reshape(-1)]
        beta = kl_weight(self.iteration, cfg.kl_weight_start, cfg.kl_weight_end, cfg.kl_anneal_start,
                         cfg.kl_anneal_end)
        stats: dict[str, list[float]] = {k: [] for k in ("action_loss", "kl", "smoothness", "loss", "grad_norm",
                                                         "encoder_std", "prior_std")}
        sync = self._gradient_sync(pol, self.optimizer)  # averages gradients across a job's ranks

        def losses(i: torch.Tensor) -> tuple[torch.Tensor, ...]:
            nobs = obs[i]
            mu, logvar, prior_mu, prior_logvar = pol.distributions(nobs)
            z = mu + torch.exp(0.5 * logvar) * torch.randn_like(mu)
            action_loss = (pol.decode(nobs, z) - labels[i]).square().mean()
            kl, kl_cost = free_bits_kl(mu, logvar, prior_mu, prior_logvar, cfg.kl_free_nats)
            prev = has_prev[i]
            if prev.any():
                mu_prev = pol.distributions(obs[i[prev] - N])[0]
                smoothness = (mu[prev] - mu_prev).square().mean()
            else:
                smoothness = torch.zeros((), device=obs.device)
            loss = action_loss + cfg.smooth_weight * smoothness + beta * kl_cost
            return loss, action_loss, kl, smoothness, logvar, prior_logvar

        for _ in range(cfg.n_epochs):
            for mb in self._minibatches({"index": index}, cfg.batch_size):
                loss, action_loss, kl, smoothness, logvar, prior_logvar = sync.loss(lambda: losses(mb["index"]))
                self.optimizer.zero_grad(set_to_none=True)
                sync.backward(loss)
                grad_norm = torch.nn.utils.clip_grad_norm_(pol.parameters(), cfg.max_grad_norm)
                self.optimizer.step()
                for k, v in (("action_loss", action_loss), ("kl", kl), ("smoothness", smoothness), ("loss", loss),
                             ("grad_norm", grad_norm), ("encoder_std", torch.exp(0.5 * logvar).mean()),
                             ("prior_std", torch.exp(0.5 * prior_logvar).mean())):
                    stats[k].append(float(v.detach()))
        for k, v in stats.items():
            if v:
                self.logger.record(f"train/{k}", float(np.mean(v)))
        self.logger.record("train/kl_weight", beta)
        if len(index):
            # How much z steers the decoder: the mean action change from the prior's mean to the
            # encoder's (what the reference adds through z), on up to one minibatch. Near 0, the
            # decoder acts from s_p alone and a latent task policy has nothing to steer with.
            with torch.no_grad():
                nobs = obs[index[:cfg.batch_size]]
                mu, _, prior_mu, _ = pol.distributions(nobs)
                effect = (pol.decode(nobs, mu).clamp(-1, 1) - pol.decode(nobs, prior_mu).clamp(-1, 1)).abs().mean()
            self.logger.record("train/z_effect", float(effect))
        flush_subnormals_(self.optimizer)

    # ------------------------------------------------------------------ the latent space
    @property
    def latent_decoder(self) -> LatentDecoder:
        """The policy's prior and decoder, with the settings of the env they were distilled in."""
        self.policy.latent.settings = self._decoder_settings()
        return self.policy.latent

    def _decoder_settings(self) -> dict:
        from smpl_envs import policy_settings

        if self.env_id is None:
            return {"action_mode": "absolute"}
        settings = policy_settings.trained_settings(self.env_id, self.env_kwargs)
        return {"substeps": settings.get("substeps"), "action_mode": settings.get("action_mode", "absolute")}

    def _extra_state(self) -> dict:
        # What smpl_envs.latent.LatentDecoder.from_checkpoint reads: the env side's way in.
        return {"latent_decoder": self.policy.latent.record("latent.", self._decoder_settings())}


def _load_teacher(name: str | None) -> tuple[Policy, tuple[str | None, dict]]:
    """(the frozen policy, (env id, env kwargs) it trained with) of the teacher checkpoint."""
    from .recipes import find_checkpoint  # recipes imports the agents package, which imports this module

    if name is None:
        raise ValueError("PULSE needs a teacher to learn from: teacher='tracker', 'clips', or a checkpoint path")
    path = find_checkpoint(name)
    env = load_checkpoint(path, "cpu")["env"]
    return load_policy(path), (env["id"], dict(env["kwargs"] or {}))


__all__ = ["PULSE", "PULSEConfig", "PULSEPolicy", "TeacherLabels", "gaussian_kl", "kl_weight"]
