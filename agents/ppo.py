"""Proximal Policy Optimisation with the options PHC's recipe relies on.

Read top to bottom: `PPOConfig` lists every setting with its default; the constructor wires an
env, a policy (`networks.ActorCritic` unless one is passed in) and a rollout buffer together;
`learn` alternates `_collect` (a `rollout.RolloutCollector` fills the `RolloutBuffer` with
`n_steps` per world, then GAE) and `_update` (`n_epochs` of clipped-surrogate minibatch steps).
Everything PHC tunes is a setting: fixed or learned action std, running observation
normalisation (stored in the checkpoint), GAE, value normalisation, bounds loss on the action
mean, gradient clipping, separate actor and critic MLPs.

Subclasses (AMP) extend it without touching the loop: `config_class` (their settings dataclass),
`_build` (their networks), `_rollout_hooks` (a `rollout.RolloutHooks` the collector calls at reset
and every step), `_shape_rewards` (before GAE), `_update_extra` (after the policy's update), and
`_extra_state` / `_load_extra_state` (checkpointed state).
"""
from __future__ import annotations

import dataclasses
import time
import warnings
from collections import deque
from pathlib import Path
from typing import Any, Iterable

import gymnasium as gym
import numpy as np
import torch
from gymnasium.vector import VectorEnv
from tqdm.auto import tqdm

from .callbacks import as_callback
from .checkpoint import load_checkpoint, save_checkpoint
from .config import AgentConfig
from .logger import Logger
from .networks import ActorCritic, Policy
from .rollout import RolloutBuffer, RolloutCollector, RolloutHooks, torch_threads
from .vec import make_vec_env


@dataclasses.dataclass
class PPOConfig(AgentConfig):
    """PPO's hyperparameters: keyword arguments of `PPO(...)`, stored in checkpoints."""

    n_steps: int = 64
    """rollout length per world (PHC: 32)"""
    batch_size: int = 1024
    """minibatch size in transitions (PHC: 16384)"""
    n_epochs: int = 5
    """passes over each rollout (PHC: 6)"""
    learning_rate: float = 3e-4
    """Adam step size"""
    lr_schedule: str = "constant"
    """"constant", or "linear" decay to zero at the end of `learn`'s budget"""
    gamma: float = 0.99
    """discount (PHC: 0.99)"""
    gae_lambda: float = 0.95
    """GAE parameter (PHC: 0.95)"""
    clip_range: float = 0.2
    """PPO ratio clip"""
    clip_range_vf: float | None = None
    """optional clip of the value update around the old value, in the critic's (normalised) units"""
    ent_coef: float = 0.0
    """entropy bonus weight (PHC: 0)"""
    vf_coef: float = 1.0
    """value-loss weight (PHC: 5)"""
    bounds_loss_coef: float = 0.0
    """penalty on action means beyond +-1.1 (PHC: 10)"""
    max_grad_norm: float = 1.0
    """global gradient-norm clip (PHC: 50)"""
    target_kl: float | None = None
    """stop an update's epochs early once the approximate KL exceeds 1.5x this"""
    normalize_obs: bool = True
    """running observation normalisation"""
    obs_clip: float | None = 10.0
    """normalised observations are clipped to +-obs_clip"""
    normalize_value: bool = True
    """the critic predicts returns normalised by running statistics"""
    normalize_advantage: bool = True
    """per-minibatch advantage standardisation"""
    actor_hidden: list[int] = dataclasses.field(default_factory=lambda: [256, 256])
    """actor MLP hidden sizes (PHC: [1024, 512])"""
    critic_hidden: list[int] = dataclasses.field(default_factory=lambda: [256, 256])
    """critic MLP hidden sizes (PHC: [1024, 512])"""
    activation: str = "silu"
    """hidden activation of both MLPs: relu, elu, silu, tanh or gelu (PHC: SiLU)"""
    log_std_init: float = -1.0
    """initial log action std, in the policy's [-1, 1] units (PHC fixes it at -2.9)"""
    learn_std: bool = True
    """learn the action std (False: fixed at log_std_init)"""
    seed: int | None = None
    """seeds torch (network initialisation, sampling) and the env's first reset"""

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.lr_schedule not in ("constant", "linear"):
            raise ValueError(f"lr_schedule must be 'constant' or 'linear', got {self.lr_schedule!r}")


def adam(params, **kwargs) -> torch.optim.Adam:
    """Adam with its fused kernel where torch has one for the device (CPU, CUDA): one pass over
    all parameters instead of a dozen ops per tensor, a seventh of the time per step here
    (measured: 3.7 ms to 0.5 ms for a 512-256 actor and critic on 2 cores)."""
    params = list(params)
    fused = bool(params) and all(p.device.type in ("cpu", "cuda") and p.is_floating_point() for p in params)
    return torch.optim.Adam(params, fused=fused, **kwargs)


# Below this an entry is zero for any network, and a zeroed one stays clear of the subnormal
# range (< 1.2e-38): decaying at Adam's rate, a value needs ~200 steps from here to reach it, and
# the next flush comes a few steps later.
FLUSH_BELOW = 1e-30


@torch.no_grad()
def flush_subnormals_(optimizer: torch.optim.Optimizer) -> None:
    """Zero, in place, the entries of an optimiser's CPU parameters and moments that are about
    to turn subnormal (|x| < FLUSH_BELOW).

    On a CPU, arithmetic on subnormal floats takes a slow path. Adam shrinks a weight that gets
    no gradient from the data (an input that is always zero, a dead ReLU unit) geometrically
    once an L2 term in the loss is all that moves it, as the discriminator's weight decay does,
    and its first moment decays the same way. Measured here, AMP on Speed: after ~1.5M steps,
    190k of the discriminator's weights were below 1e-20, its forward and backward ran 13-90x
    slower, and training fell from 2,100 to 510 samples/s. Zeroing only the subnormal entries
    was not enough: the weights just above the range kept making subnormal moments and
    products. `torch.set_flush_denormal` would only cover threads started after the call
    (torch's pool may already run), so the state itself is kept clean."""
    for group in optimizer.param_groups:
        for p in group["params"]:
            state = optimizer.state.get(p, {})
            for t in (p, *state.values()):
                if torch.is_tensor(t) and t.device.type == "cpu" and t.is_floating_point() and t.dim() > 0:
                    t.masked_fill_(t.abs() < FLUSH_BELOW, 0.0)


def resolve_device(device: str | torch.device, name: str = "device") -> torch.device:
    """The torch device `device` names ("auto": CUDA where torch sees a GPU, else the CPU), checked
    here: a CUDA device on a torch that cannot use one is a ValueError saying what to install, not
    an assertion inside torch once the env is built. `name`: the setting, as the message calls it."""
    if str(device) == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    try:
        resolved = torch.device(device)
    except (RuntimeError, TypeError) as e:
        reason = str(e).splitlines()[0]
        raise ValueError(f"{name}={device!r} is not a torch device (auto, cpu, cuda, cuda:1, ...): {reason}") from None
    if resolved.type != "cuda" or (torch.cuda.is_available() and (resolved.index or 0) < torch.cuda.device_count()):
        return resolved
    if torch.version.cuda is None:
        release = torch.__version__.split("+")[0]
        raise ValueError(f"{name}={device!r}: this torch ({torch.__version__}) is a CPU-only build. Install a CUDA "
                         f"build (on Linux PyPI's wheels are: pip install --force-reinstall torch=={release}; other "
                         "platforms and CUDA versions: https://pytorch.org/get-started/locally/), or use cpu or auto")
    raise ValueError(f"{name}={device!r}: this torch (CUDA {torch.version.cuda}) sees {torch.cuda.device_count()} CUDA "
                     "device(s) (no NVIDIA driver, or CUDA_VISIBLE_DEVICES hides them); use cpu or auto")


class PPO:
    """PPO for Box action spaces on any Gymnasium env, single or vector.

    Args:
        env: an env id (made with `n_envs` worlds and `env_kwargs`; suite ids use their native
            batched env), a `gymnasium.Env`, a `gymnasium.vector.VectorEnv`, or None to act only.
        policy: a `networks.Policy` to train (its obs/act sizes must match the env); default: an
            `ActorCritic` built from the hyperparameters. `load` rebuilds an `ActorCritic` unless
            handed the same kind of policy again.
        device: "auto", "cpu", "cuda", ...
        verbose: 1 prints a table per log, 0 is silent.
        log_dir, tensorboard: where progress.csv and TensorBoard files go (None: stdout only).
        **hyperparams: the fields of `PPOConfig` (`config_class`), each with its default and
            meaning there. They are readable (and writable) as attributes too:
            `model.learning_rate` is `model.config.learning_rate`.
    """

    config_class: type[AgentConfig] = PPOConfig

    def __init__(self, env: str | gym.Env | VectorEnv | None, *, n_envs: int = 1, env_kwargs: dict | None = None,
                 policy: Policy | None = None, device: str | torch.device = "auto", verbose: int = 1,
                 log_dir: str | Path | None = None, tensorboard: bool = True, update_threads: int | None = None,
                 **hyperparams):
        self.config = self.config_class.from_kwargs(type(self).__name__, hyperparams)
        self.device = resolve_device(device)
        # Torch CPU threads while updating: the simulator's threads sit idle then, so the update
        # may use every core even when collection runs torch on one (None: leave torch's setting).
        if update_threads is not None and (isinstance(update_threads, bool) or not isinstance(update_threads, int)
                                           or update_threads < 1):
            raise ValueError(f"update_threads must be a positive integer or None, got {update_threads!r}")
        self.update_threads = update_threads
        self.verbose = verbose
        self.env = self.env_id = None
        self.env_kwargs: dict = {}
        self.num_timesteps = 0
        self.iteration = 0
        self.episodes: deque = deque(maxlen=100)  # (return, length) of the latest episodes
        self._collector: RolloutCollector | None = None  # made on the first rollout
        self.rollout_buffer: RolloutBuffer | None = None
        if self.config.seed is not None:
            torch.manual_seed(self.config.seed)
        if env is not None:
            self.set_env(env, n_envs=n_envs, env_kwargs=env_kwargs)
            self._build(self.env.single_observation_space.shape[0], self.env.single_action_space, policy)
        elif policy is not None:
            raise ValueError("policy= needs an env (its action bounds); to act only, use PPO.load(path, policy=...)")
        self.set_logger(log_dir, tensorboard)

    @property
    def hyperparams(self) -> dict[str, Any]:
        """The settings as a plain dict (what checkpoints store)."""
        return self.config.to_dict()

    def __getattr__(self, name: str):
        # Only reached when normal lookup fails: hyperparameters read through to the config.
        config = self.__dict__.get("config")
        if config is not None and name in config.names():
            return getattr(config, name)
        raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")

    def __setattr__(self, name: str, value) -> None:
        # `model.learning_rate = x` changes the setting training reads, not a shadow copy.
        config = self.__dict__.get("config")
        if config is not None and name in config.names():
            setattr(config, name, value)
        else:
            super().__setattr__(name, value)

    # ------------------------------------------------------------------ setup
    def _build(self, obs_dim: int, action_space: gym.spaces.Box, policy: Policy | None = None) -> None:
        cfg = self.config
        self.obs_dim, self.act_dim = int(obs_dim), int(action_space.shape[0])
        low, high = action_space.low.astype(np.float64), action_space.high.astype(np.float64)
        if not (np.isfinite(low).all() and np.isfinite(high).all()):
            raise ValueError("the agents need a bounded Box action space (finite low and high)")
        self.action_low, self.action_high = low, high
        if policy is None:
            policy = ActorCritic(
                self.obs_dim, self.act_dim, actor_hidden=cfg.actor_hidden, critic_hidden=cfg.critic_hidden,
                activation=cfg.activation, log_std_init=cfg.log_std_init, learn_std=cfg.learn_std,
                obs_clip=cfg.obs_clip, normalize_obs=cfg.normalize_obs, normalize_value=cfg.normalize_value)
        elif (policy.obs_dim, policy.act_dim) != (self.obs_dim, self.act_dim):
            raise ValueError(f"the policy is for obs {policy.obs_dim} / action {policy.act_dim} features, "
                             f"the env has {self.obs_dim} / {self.act_dim}")
        self.policy = policy.to(self.device)
        params = [p for p in self.policy.parameters() if p.requires_grad]
        self.optimizer = adam(params, lr=cfg.learning_rate, eps=1e-5)
        self._collector = None

    def set_env(self, env, n_envs: int = 1, env_kwargs: dict | None = None,
                override_settings: Iterable[str] = ()) -> None:
        """Attach an env to train on; its spaces must match the policy's. An agent whose policy
        has a recorded env (a loaded one) keeps to it (`smpl_envs.policy_settings`): an env id
        must be its task, and gets its policy settings (action_mode, residual_scale, substeps
        ...) unless `env_kwargs` sets them; an env must be its task, made with those settings.
        A contradicting value is a ValueError naming the setting, unless the setting is named
        in `override_settings`.

        The agent then records this env: its id and kwargs, its policy settings included, as
        `save` writes them into checkpoints."""
        from smpl_envs import policy_settings

        trained = hasattr(self, "policy") and self.env_id is not None
        if not trained and override_settings:
            raise ValueError("override_settings is for an agent with a recorded env (a loaded one); this one has none")
        if trained and isinstance(env, str):
            policy_settings.check_task(self.env_id, env)
            env_kwargs = policy_settings.with_trained_settings(env, self.env_kwargs, env_kwargs or {},
                                                               override_settings)
        elif trained:
            policy_settings.check_env(env, self.env_id, self.env_kwargs, override_settings)
        vec = make_vec_env(env, n_envs, env_kwargs)
        if hasattr(self, "policy"):
            if vec.single_observation_space.shape != (self.obs_dim,) or vec.single_action_space.shape != (self.act_dim,):
                raise ValueError(
                    f"env spaces obs {vec.single_observation_space.shape} / action {vec.single_action_space.shape} "
                    f"do not match the agent's ({self.obs_dim},) / ({self.act_dim},)")
        self.env = vec
        # The settings are read from the env itself, so a checkpoint names them even where they
        # were defaults (a later default cannot change what an old policy runs with).
        if isinstance(env, str):
            self.env_id, self.env_kwargs = env, {**(env_kwargs or {}), **policy_settings.settings_of(vec)}
        else:
            self.env_id = policy_settings.env_id_of(env)
            self.env_kwargs = {**(self.env_kwargs if trained else {}), **policy_settings.settings_of(env)}
        self._collector = None  # the next rollout starts with a reset of this env

    def set_logger(self, log_dir: str | Path | None = None, tensorboard: bool = True) -> None:
        self.logger = Logger(log_dir, stdout=self.verbose > 0, tensorboard=tensorboard)

    def close(self) -> None:
        """Flush the logs and close the env's worlds."""
        self.logger.close()
        if self.env is not None:
            self.env.close()

    # ------------------------------------------------------------------ acting
    def _to_env_action(self, a: torch.Tensor) -> np.ndarray:
        # The policy acts in [-1, 1]^d; the env's box can be anything bounded.
        if self._collector is not None and self._collector.native:  # a torch env: stay on the device
            low, high = (torch.as_tensor(x, dtype=a.dtype, device=a.device) for x in (self.action_low, self.action_high))
            return low + 0.5 * (a.clamp(-1.0, 1.0) + 1.0) * (high - low)
        a = a.clamp(-1.0, 1.0).double().cpu().numpy()
        return (self.action_low + 0.5 * (a + 1.0) * (self.action_high - self.action_low)).astype(np.float32)

    def predict(self, observation: np.ndarray, state=None, episode_start=None, deterministic: bool = True):
        """Actions for a batch of observations (or one), in the env's action box. Returns
        `(actions, None)` like Stable-Baselines3 (the None is the absent recurrent state)."""
        obs = np.asarray(observation, dtype=np.float32)
        single = obs.ndim == 1
        if obs.shape[-1] != self.obs_dim:
            raise ValueError(f"observation has {obs.shape[-1]} features, the policy expects {self.obs_dim}")
        if not np.isfinite(obs).all():
            raise ValueError("observation contains NaN or inf")
        a = self.policy.act(torch.as_tensor(obs.reshape(-1, self.obs_dim), device=self.device), deterministic)
        act = self._to_env_action(a)
        return (act[0] if single else act), None

    def __call__(self, observation):
        """Deterministic actions: an agent is a policy for `smpl_envs.evaluate` and `record`."""
        return self.predict(observation, deterministic=True)[0]

    # ------------------------------------------------------------------ training loop
    def learn(self, total_timesteps: int, callback=None, progress_bar: bool = True,
              reset_num_timesteps: bool = True, log_interval: int = 1) -> "PPO":
        """Train for `total_timesteps` more env steps (all worlds counted). With
        `reset_num_timesteps=False` the step count, iteration and episode statistics carry on,
        as when resuming from a checkpoint."""
        if self.env is None:
            raise RuntimeError("no env attached; pass one to the constructor, to load(), or set_env()")
        if reset_num_timesteps:
            self.num_timesteps, self.iteration = 0, 0
            self.episodes.clear()
        target = self.num_timesteps + int(total_timesteps)
        callback = as_callback(callback)
        if self._collector is None:
            self._start_collector(seed=self.config.seed if reset_num_timesteps else None)
        callback.on_training_start(self)
        bar = tqdm(total=target, initial=self.num_timesteps, disable=not progress_bar, unit="step",
                   dynamic_ncols=True, desc=type(self).__name__)
        start_steps, t0 = self.num_timesteps, time.perf_counter()
        try:
            while self.num_timesteps < target:
                self._set_learning_rate(target)
                buffer = self._collect()
                with torch_threads(self.update_threads):
                    self._update(buffer)
                self.iteration += 1
                bar.update(self.num_timesteps - bar.n)
                if self.episodes:
                    ret, length = np.mean(self.episodes, axis=0)
                    bar.set_postfix(ep_len=f"{length:.0f}", ep_rew=f"{ret:.3g}", refresh=False)
                elapsed = time.perf_counter() - t0
                self.logger.record("time/fps", (self.num_timesteps - start_steps) / max(elapsed, 1e-9))
                self.logger.record("time/iterations", self.iteration)
                self.logger.record("time/elapsed_s", elapsed)
                keep_going = callback.on_iteration(self) is not False
                if self.iteration % log_interval == 0 or not keep_going or self.num_timesteps >= target:
                    self.logger.dump(self.num_timesteps)
                if not keep_going:
                    break
        finally:
            bar.close()
        callback.on_training_end(self)
        return self

    def _start_collector(self, seed: int | None) -> None:
        """A collector on the attached env, which it resets (with `seed`)."""
        self._collector = RolloutCollector(self.env, self.policy, self._to_env_action, self.episodes,
                                           self._rollout_hooks(), self.device, value_threads=self.update_threads)
        self._collector.reset(seed=seed)

    def _set_learning_rate(self, target: int) -> None:
        lr = self.config.learning_rate
        if self.config.lr_schedule == "linear":
            lr *= max(1.0 - self.num_timesteps / max(target, 1), 0.0)
        for g in self.optimizer.param_groups:
            g["lr"] = lr
        self.logger.record("train/learning_rate", lr)

    @torch.no_grad()
    def _collect(self) -> RolloutBuffer:
        """One rollout of `n_steps` per world into the buffer; rewards shaped, advantages computed."""
        cfg = self.config
        if self._collector is None:
            self._start_collector(seed=cfg.seed)
        n_envs = self.env.num_envs
        buf = self.rollout_buffer
        if buf is None or not buf.matches(cfg.n_steps, n_envs, self.obs_dim, self.act_dim):
            buf = self.rollout_buffer = RolloutBuffer(cfg.n_steps, n_envs, self.obs_dim, self.act_dim, self.device)
        last_value, reward_terms = self._collector.collect(buf)
        self.num_timesteps += cfg.n_steps * n_envs
        buf.rewards.copy_(self._shape_rewards(buf))
        buf.compute_advantages(last_value, cfg.gamma, cfg.gae_lambda)

        v = buf.valid.bool()
        self.logger.record("rollout/step_reward_mean", buf.rewards[v].mean().item() if v.any() else 0.0)
        for k, mean in reward_terms.items():
            self.logger.record(f"rollout/reward_{k}", mean)
        if self.episodes:
            ret, length = np.mean(self.episodes, axis=0)
            self.logger.record("rollout/ep_rew_mean", ret)
            self.logger.record("rollout/ep_len_mean", length)
        return buf

    def _update(self, buf: RolloutBuffer) -> None:
        cfg, pol = self.config, self.policy
        data = buf.transitions()
        pol.update_value_stats(data["returns"])
        stats: dict[str, list[float]] = {k: [] for k in ("policy_loss", "value_loss", "entropy", "bounds_loss",
                                                         "approx_kl", "clip_fraction", "grad_norm")}
        stop = False
        for _ in range(cfg.n_epochs):
            for mb in buf.minibatches(cfg.batch_size):
                ev = pol.evaluate_actions(mb["obs"], mb["actions"])
                log_ratio = ev.log_prob - mb["log_probs"]
                ratio = log_ratio.exp()
                adv = mb["advantages"]
                if cfg.normalize_advantage and len(adv) > 1:
                    adv = (adv - adv.mean()) / (adv.std() + 1e-8)
                policy_loss = torch.max(-adv * ratio, -adv * ratio.clamp(1 - cfg.clip_range, 1 + cfg.clip_range)).mean()

                # The critic learns in its own units (normalised returns when normalize_value).
                v_pred = ev.value
                v_target, v_old = pol.value_targets(mb["returns"]), pol.value_targets(mb["values"])
                value_loss = (v_pred - v_target).square()
                if cfg.clip_range_vf is not None:
                    v_clip = v_old + (v_pred - v_old).clamp(-cfg.clip_range_vf, cfg.clip_range_vf)
                    value_loss = torch.max(value_loss, (v_clip - v_target).square())
                value_loss = 0.5 * value_loss.mean()

                entropy = ev.entropy.mean()
                mu = ev.mean
                bounds_loss = ((mu - 1.1).clamp(min=0).square() + (mu + 1.1).clamp(max=0).square()).sum(-1).mean()
                loss = (policy_loss + cfg.vf_coef * value_loss - cfg.ent_coef * entropy
                        + cfg.bounds_loss_coef * bounds_loss)

                self.optimizer.zero_grad(set_to_none=True)
                loss.backward()
                grad_norm = torch.nn.utils.clip_grad_norm_(pol.parameters(), cfg.max_grad_norm)
                self.optimizer.step()

                with torch.no_grad():
                    approx_kl = ((ratio - 1) - log_ratio).mean().item()
                    clip_fraction = ((ratio - 1).abs() > cfg.clip_range).float().mean().item()
                for k, v in (("policy_loss", policy_loss), ("value_loss", value_loss), ("entropy", entropy),
                             ("bounds_loss", bounds_loss), ("grad_norm", grad_norm)):
                    stats[k].append(float(v.detach()))
                stats["approx_kl"].append(approx_kl)
                stats["clip_fraction"].append(clip_fraction)
                if cfg.target_kl is not None and approx_kl > 1.5 * cfg.target_kl:
                    stop = True
                    break
            if stop:
                break
        for k, v in stats.items():
            if v:
                self.logger.record(f"train/{k}", float(np.mean(v)))
        ret, val = data["returns"], data["values"]
        var = ret.var() if len(ret) > 1 else torch.tensor(0.0)
        self.logger.record("train/explained_variance", float(1 - (ret - val).var() / var) if var > 0 else float("nan"))
        std = pol.action_std()
        if std is not None:
            self.logger.record("train/std", float(std.mean()))
        flush_subnormals_(self.optimizer)
        self._update_extra(buf)

    # ------------------------------------------------------------------ subclass hooks
    def _rollout_hooks(self) -> RolloutHooks:
        """What the collector calls at reset, rollout start and every step (nothing, for PPO)."""
        return RolloutHooks()

    def _shape_rewards(self, buf: RolloutBuffer) -> torch.Tensor:
        """The (n_steps, n_envs) rewards GAE sees, from the env's (`buf.rewards`)."""
        return buf.rewards

    def _update_extra(self, buf: RolloutBuffer) -> None:
        """Anything else to train on the rollout, after the policy's update."""

    def _extra_state(self) -> dict:
        return {}

    def _load_extra_state(self, state: dict) -> None:
        pass

    # ------------------------------------------------------------------ persistence
    def save(self, path: str | Path, optimizer: bool = True) -> Path:
        """One self-contained file: weights, normalisers, optimiser, hyperparameters, step count,
        env id and kwargs (when plain data), RNG state and library versions. Written atomically.
        `optimizer=False` leaves the optimiser's moments out (a third of the size): a policy to
        ship and act with; training from it starts the optimiser afresh."""
        env_kwargs = _plain(self.env_kwargs)
        dropped = sorted(set(self.env_kwargs) - set(env_kwargs))
        if dropped:
            warnings.warn(f"env kwargs {dropped} are not plain data and are left out of the checkpoint; "
                          "pass them again when loading with env='auto'", stacklevel=2)
        payload = {
            "class": type(self).__name__,
            "hyperparams": self.hyperparams,
            "spaces": {"obs_dim": self.obs_dim, "act_dim": self.act_dim,
                       "action_low": self.action_low.tolist(), "action_high": self.action_high.tolist()},
            "env": {"id": self.env_id, "kwargs": env_kwargs,
                    "n_envs": None if self.env is None else self.env.num_envs},
            "policy": self.policy.state_dict(),
            "optimizer": self.optimizer.state_dict() if optimizer else None,
            "num_timesteps": self.num_timesteps,
            "iteration": self.iteration,
            "episodes": [[float(r), int(n)] for r, n in self.episodes],
            "torch_rng": torch.get_rng_state(),
            "extra": self._extra_state(),
        }
        return save_checkpoint(payload, path)

    @classmethod
    def load(cls, path: str | Path, env=None, device: str | torch.device = "auto", *,
             n_envs: int | None = None, env_kwargs: dict | None = None, policy: Policy | None = None,
             verbose: int = 1, log_dir: str | Path | None = None, tensorboard: bool = True,
             override_settings: Iterable[str] = (), **overrides) -> "PPO":
        """Rebuild an agent from `save`'s file. With `env` (an env, or "auto" to make the recorded
        env id with its recorded kwargs, `env_kwargs` over them) it can continue training: call
        `learn(..., reset_num_timesteps=False)`. The env must be the recorded task, with the
        policy's recorded settings (`set_env`; `override_settings` names those `env_kwargs`
        or the env may change on purpose). `overrides` replace saved hyperparameters
        (learning rate, epochs ... not network sizes). `policy`: a fresh policy of the kind
        that was saved, when it was not the default `ActorCritic`; the saved weights go into it."""
        device = resolve_device(device)
        ckpt = load_checkpoint(path, device)
        if ckpt["class"] != cls.__name__:
            raise ValueError(f"{path} holds a {ckpt['class']} agent; load it with agents.{ckpt['class']}.load "
                             "or agents.load")
        hp = {**ckpt["hyperparams"], **overrides}
        agent = cls(None, device=device, verbose=verbose, **hp)
        sp = ckpt["spaces"]
        box = gym.spaces.Box(np.array(sp["action_low"], np.float32), np.array(sp["action_high"], np.float32))
        agent._build(sp["obs_dim"], box, policy)
        agent.policy.load_state_dict(ckpt["policy"])
        if ckpt["optimizer"] is not None:  # None: a policy saved to ship (save(optimizer=False))
            agent.optimizer.load_state_dict(ckpt["optimizer"])
        agent.num_timesteps, agent.iteration = ckpt["num_timesteps"], ckpt["iteration"]
        agent.episodes.extend(tuple(e) for e in ckpt["episodes"])
        agent.env_id, agent.env_kwargs = ckpt["env"]["id"], dict(ckpt["env"]["kwargs"] or {})
        torch.set_rng_state(ckpt["torch_rng"].cpu())
        if isinstance(env, str) and env == "auto":
            if agent.env_id is None:
                raise ValueError("the checkpoint records no env id; pass an env")
            env = agent.env_id
            env_kwargs = {**agent.env_kwargs, **(env_kwargs or {})}
            n_envs = n_envs or ckpt["env"]["n_envs"] or 1
        if env is not None:
            agent.set_env(env, n_envs=n_envs or 1, env_kwargs=env_kwargs, override_settings=override_settings)
        elif override_settings:
            raise ValueError("override_settings applies to the env load attaches; pass env= too")
        agent._load_extra_state(ckpt["extra"])
        agent.set_logger(log_dir, tensorboard)
        return agent


def _plain(x: Any) -> Any:
    """`x` if it is plain data a safe checkpoint loader accepts, with unsupported leaves dropped."""
    if isinstance(x, dict):
        out = {str(k): _plain(v) for k, v in x.items()}
        return {k: v for k, v in out.items() if v is not _DROP}
    if isinstance(x, (list, tuple)):
        items = [_plain(v) for v in x]
        return _DROP if any(v is _DROP for v in items) else list(items)
    if x is None or isinstance(x, (bool, int, float, str)):
        return x
    if isinstance(x, Path):
        return str(x)
    return _DROP


_DROP = object()

