"""What every on-policy agent here shares: settings, an env, a policy, rollouts, the learn loop,
logging, saving and loading (as Stable-Baselines3's OnPolicyAlgorithm). An algorithm is a
subclass that says how it learns from a rollout (`_update`); PPO is one (`ppo.py`), a
behaviour-cloning agent another (`Distill` in tests/plugin_policies.py).

Read top to bottom: `OnPolicyConfig` lists the shared settings with their defaults; the
constructor wires an env, a policy (a class with its keyword arguments, or a built `Policy`)
and an optimiser together; `learn` alternates `_collect` (a `rollout.RolloutCollector` fills the
`RolloutBuffer` with `n_steps` per world, the subclass shapes the rewards, then GAE) and the
subclass's `_update`; `save` and `load` write and read one self-contained checkpoint.

Subclasses extend it without touching the loop: `config_class` (their settings dataclass, a
subclass of `OnPolicyConfig`), `_update` (required), `_build` (more networks),
`_rollout_hooks` (a `rollout.RolloutHooks` the collector calls at reset, every step and at the
end of a rollout), `_shape_rewards` (before GAE), and `_extra_state` / `_load_extra_state`
(checkpointed state).

Data-parallel training (`distributed`): in a torch.distributed job (torchrun) every process
trains its own copy of the agent on its own worlds, and the base keeps the copies identical.
`learn` starts every rank from rank 0's weights and hooks the normalisers of the trained
networks (`_replicated_modules`) to combine their statistics across ranks; rollouts count the
steps and gather the episodes of every rank; an update takes the minibatch count the ranks
agree on (`_minibatches`) and averages every backward pass's gradients
(`_gradient_sync(module, optimizer)`: its `loss` and `backward` replace the plain calls);
training stops on every rank when a callback on one stops it. Rank r seeds torch with seed + r
and its env's first reset with seed + r x n_envs (so vector envs that seed world i with
seed + i never repeat another rank's worlds). The env's worlds and `batch_size` are per process. In one
process all of it is a no-op: training is exactly as without it.
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

from smpl_envs.backend import runnable_here
from smpl_envs.progress import pbar

from . import distributed
from .callbacks import as_callback
from .checkpoint import load_checkpoint, save_checkpoint
from .config import AgentConfig
from .distributed import GRAD_SYNCS, GradientSync
from .logger import Logger
from .networks import ActorCritic, Policy, action_box
from .normalizer import RunningNorm
from .optim import adam
from .policies import (PolicyClassError, checkpoint_policy, make_policy, policy_class, policy_record,
                       split_former_hyperparams)
from .rollout import RolloutBuffer, RolloutCollector, RolloutHooks, minibatches, torch_threads
from .vec import make_vec_env


@dataclasses.dataclass
class OnPolicyConfig(AgentConfig):
    """The settings every on-policy agent has: rollouts, minibatches, the optimiser, GAE, the seed."""

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
    lr_decay_from: float = 0.0
    """share of the budget "linear" holds the rate constant before it starts to fall (0: it falls
    from the first step; 0.67: constant for two thirds, then down to zero, as the stable-then-decay
    schedules of language-model training do)"""
    gamma: float = 0.99
    """discount (PHC: 0.99)"""
    gae_lambda: float = 0.95
    """GAE parameter (PHC: 0.95)"""
    max_grad_norm: float = 1.0
    """global gradient-norm clip (PHC: 50)"""
    exploration_hold: int = 1
    """steps each world keeps its exploration noise in a rollout (1: fresh every step; the
    action's mean still follows every observation, and acting and evaluation use no noise)"""
    seed: int | None = None
    """seeds torch (network initialisation, sampling) and the env's first reset"""

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.lr_schedule not in ("constant", "linear"):
            raise ValueError(f"lr_schedule must be 'constant' or 'linear', got {self.lr_schedule!r}")
        if not 0.0 <= self.lr_decay_from < 1.0:
            raise ValueError(f"lr_decay_from must be a share of the budget in [0, 1), got {self.lr_decay_from!r}")
        if self.exploration_hold < 1:
            raise ValueError(f"exploration_hold must be a whole number of steps >= 1, got {self.exploration_hold!r}")


def scheduled_learning_rate(config: OnPolicyConfig, timesteps: int, target: int) -> float:
    """The Adam step size after `timesteps` of a budget of `target` samples, as `config` schedules it."""
    lr = config.learning_rate
    if config.lr_schedule == "linear":
        start = config.lr_decay_from * target
        lr *= min(max((target - timesteps) / max(target - start, 1.0), 0.0), 1.0)
    return lr


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


class OnPolicyAlgorithm:
    """An on-policy agent on any Gymnasium env with a bounded Box action space, single or vector.

    Args:
        env: an env id (made with `n_envs` worlds and `env_kwargs`; suite ids use their native
            batched env), a `gymnasium.Env`, a `gymnasium.vector.VectorEnv`, or None to act only.
        policy: the policy class (a `networks.Policy` subclass, its registry name or an
            importable path "package.module:Class"; default `default_policy`, the actor-critic)
            made as `cls(obs_dim, env action space, **policy_kwargs)`; or a built `Policy` for
            the env's spaces. Checkpoints record the class and its arguments, and `load` makes
            it again from them (`agents.policies`).
        policy_kwargs: the policy class's keyword arguments (ActorCritic: actor_hidden,
            critic_hidden, activation, log_std_init, learn_std, obs_clip, normalize_obs,
            normalize_value). Those eight may also be given as hyperparameters, as before they
            were the policy's: that still works for the actor-critic, with a DeprecationWarning.
        device: "auto", "cpu", "cuda", ...
        verbose: 1 prints a table per log, 0 is silent.
        log_dir, tensorboard: where progress.csv and TensorBoard files go (None: stdout only).
            In a data-parallel job only rank 0 logs (the others are silent).
        update_threads: torch CPU threads during the update (None: as set).
        grad_sync: how a data-parallel job averages gradients, "allreduce" (one all-reduce of
            the flattened gradient after each backward pass) or "ddp" (DistributedDataParallel;
            every trainable parameter must take part in every loss); no effect in one process.
        **hyperparams: the fields of the settings dataclass (`config_class`), each with its
            default and meaning there. They are readable (and writable) as attributes too:
            `model.learning_rate` is `model.config.learning_rate`.

    `obs_dim` and `act_dim` are the env's observation and action sizes; the policy's own action
    size is `policy.act_dim`.
    """

    config_class: type[OnPolicyConfig] = OnPolicyConfig
    default_policy: type[Policy] = ActorCritic

    def __init__(self, env: str | gym.Env | VectorEnv | None, *, n_envs: int = 1, env_kwargs: dict | None = None,
                 policy: str | type[Policy] | Policy | None = None, policy_kwargs: dict | None = None,
                 device: str | torch.device = "auto", verbose: int = 1, log_dir: str | Path | None = None,
                 tensorboard: bool = True, update_threads: int | None = None, grad_sync: str = "allreduce",
                 **hyperparams):
        owner = type(self).__name__
        hyperparams, policy_kwargs = _policy_kwargs(owner, self.default_policy, policy, policy_kwargs, hyperparams)
        self.config = self.config_class.from_kwargs(owner, hyperparams)
        self.device = resolve_device(device)
        if grad_sync not in GRAD_SYNCS:
            raise ValueError(f"grad_sync must be one of {GRAD_SYNCS}, got {grad_sync!r}")
        self.grad_sync = grad_sync
        # The job this process trains in (one process unless torch.distributed runs several).
        self.data_parallel = distributed.current(self.device)
        self._grad_syncs: dict[int, GradientSync] = {}
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
        self._rank_episodes: deque = deque()  # in a job: this rank's episodes of the rollout, to gather
        self.rollout_buffer: RolloutBuffer | None = None
        # The policy to make once the env's spaces are known (a built one is taken as it is).
        built = policy if isinstance(policy, Policy) else None
        if built is None:
            self.policy_class, self.policy_kwargs = policy_class(policy or self.default_policy), policy_kwargs
        if self.config.seed is not None:
            torch.manual_seed(self.data_parallel.seed(self.config.seed))
        if env is not None:
            self.set_env(env, n_envs=n_envs, env_kwargs=env_kwargs)
            self._build(self.env.single_observation_space.shape[0], self.env.single_action_space, built)
        elif built is not None:
            raise ValueError(f"a built policy needs an env to train in; to act only, use {owner}.load(path)")
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
        """The policy (made from `policy_class` and `policy_kwargs`, unless built already) and
        its optimiser, for an env of these spaces."""
        self.obs_dim, self.action_space = int(obs_dim), action_box(action_space)
        self.act_dim = int(self.action_space.shape[0])
        if policy is None:
            policy = make_policy(self.policy_class, self.obs_dim, self.action_space, self.policy_kwargs)
        else:
            _check_policy_spaces(policy, self.obs_dim, self.action_space)
        self.policy = policy.to(self.device)
        self.policy_class, self.policy_kwargs = type(policy), policy.init_kwargs
        self.optimizer = adam(self._param_groups(), lr=self.config.learning_rate, eps=1e-5)
        self._collector = None
        self._grad_syncs = {}

    def _param_groups(self) -> list[dict]:
        """The optimiser's parameter groups: the policy's trainable parameters (not its frozen
        parts) in one group. A subclass may split them, each group with an `lr_scale` (a factor
        on the learning rate and its schedule); the group count is part of a checkpoint's
        optimiser state."""
        return [{"params": [p for p in self.policy.parameters() if p.requires_grad], "lr_scale": 1.0}]

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
            box = vec.single_action_space
            if vec.single_observation_space.shape != (self.obs_dim,) or box.shape != (self.act_dim,):
                raise ValueError(
                    f"env spaces obs {vec.single_observation_space.shape} / action {box.shape} "
                    f"do not match the agent's ({self.obs_dim},) / ({self.act_dim},)")
            if not (np.array_equal(box.low, self.action_space.low) and np.array_equal(box.high, self.action_space.high)):
                raise ValueError("the env's action box differs from the one the policy maps its actions onto")
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
        if not self.data_parallel.main:  # one writer per job: rank 0's logs speak for all
            log_dir, tensorboard = None, False
        self.logger = Logger(log_dir, stdout=self.verbose > 0 and self.data_parallel.main, tensorboard=tensorboard)

    def close(self) -> None:
        """Flush the logs and close the env's worlds."""
        self.logger.close()
        if self.env is not None:
            self.env.close()

    # ------------------------------------------------------------------ acting
    def predict(self, observation: np.ndarray, state=None, episode_start=None, deterministic: bool = True):
        """The env's actions for a batch of observations (or one): the policy's own actions
        mapped by `policy.env_action`. Returns `(actions, None)` like Stable-Baselines3 (the
        None is the absent recurrent state)."""
        obs = np.asarray(observation, dtype=np.float32)
        single = obs.ndim == 1
        if obs.shape[-1] != self.obs_dim:
            raise ValueError(f"observation has {obs.shape[-1]} features, the policy expects {self.obs_dim}")
        if not np.isfinite(obs).all():
            raise ValueError("observation contains NaN or inf")
        x = torch.as_tensor(obs.reshape(-1, self.obs_dim), device=self.device)
        with torch.no_grad():
            act = self.policy.env_action(self.policy.act(x, deterministic), x).cpu().numpy()
        return (act[0] if single else act), None

    def __call__(self, observation):
        """Deterministic actions: an agent is a policy for `smpl_envs.evaluate` and `record`."""
        return self.predict(observation, deterministic=True)[0]

    # ------------------------------------------------------------------ training loop
    def learn(self, total_timesteps: int, callback=None, progress_bar: bool = True,
              reset_num_timesteps: bool = True, log_interval: int = 1):
        """Train for `total_timesteps` more env steps (all worlds counted, of every process in a
        data-parallel job). With `reset_num_timesteps=False` the step count, iteration and
        episode statistics carry on, as when resuming from a checkpoint. Returns the agent."""
        if self.env is None:
            raise RuntimeError("no env attached; pass one to the constructor, to load(), or set_env()")
        if reset_num_timesteps:
            self.num_timesteps, self.iteration = 0, 0
            self.episodes.clear()
            self._rank_episodes.clear()
        target = self.num_timesteps + int(total_timesteps)
        callback = as_callback(callback)
        self._replicate()
        if self._collector is None:
            self._start_collector(seed=self.config.seed if reset_num_timesteps else None)
        callback.on_training_start(self)
        bar = pbar(total=target, initial=self.num_timesteps, disable=not progress_bar or not self.data_parallel.main,
                   unit="step", dynamic_ncols=True, desc=type(self).__name__)
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
                # One rank's callback stopping (a time budget, a signal) stops every rank.
                keep_going = self.data_parallel.all_true(callback.on_iteration(self) is not False)
                if self.iteration % log_interval == 0 or not keep_going or self.num_timesteps >= target:
                    self.logger.dump(self.num_timesteps)
                if not keep_going:
                    break
        finally:
            bar.close()
        callback.on_training_end(self)
        return self

    def _start_collector(self, seed: int | None) -> None:
        """A collector on the attached env, which it resets (with `seed`, this rank's in a job)."""
        episodes = self._rank_episodes if self.data_parallel.enabled else self.episodes
        self._collector = RolloutCollector(self.env, self.policy, episodes, self._rollout_hooks(), self.device,
                                           value_threads=self.update_threads,
                                           noise_hold=self.config.exploration_hold)
        self._collector.reset(seed=self.data_parallel.seed(seed, stride=self.env.num_envs))

    # ------------------------------------------------------------------ data parallelism
    def _replicated_modules(self) -> list[torch.nn.Module]:
        """The networks every rank of a job trains a copy of (subclasses add theirs)."""
        return [self.policy]

    def _replicate(self) -> None:
        """In a job: every rank takes rank 0's weights and statistics, and the normalisers of
        the trained networks combine their updates across ranks."""
        dp = self.data_parallel
        if not dp.enabled:
            return
        modules = self._replicated_modules()
        dp.broadcast_modules(modules)
        for module in modules:
            for m in module.modules():
                if isinstance(m, RunningNorm):
                    m.reduce_moments = dp.reduce_moments

    def _gradient_sync(self, module: torch.nn.Module, optimizer: torch.optim.Optimizer) -> GradientSync:
        """How the gradients of `module` that `optimizer` steps are averaged across the job's
        ranks (made on first use; in one process plain `loss` and `backward` calls)."""
        sync = self._grad_syncs.get(id(module))
        if sync is None or sync.module is not module:
            params = [p for g in optimizer.param_groups for p in g["params"]]
            sync = self._grad_syncs[id(module)] = self.data_parallel.gradient_sync(module, params, self.grad_sync)
        return sync

    def _minibatches(self, data: dict[str, torch.Tensor], batch_size: int):
        """One epoch over `data` in shuffled minibatches (`rollout.minibatches`), as many on
        every rank of a job."""
        n = len(next(iter(data.values())))
        return minibatches(data, batch_size, self.data_parallel.minibatch_count(n, batch_size))

    def _set_learning_rate(self, target: int) -> None:
        lr = scheduled_learning_rate(self.config, self.num_timesteps, target)
        for g in self.optimizer.param_groups:
            g["lr"] = lr * g.get("lr_scale", 1.0)
        self.logger.record("train/learning_rate", lr)

    @torch.no_grad()
    def _collect(self) -> RolloutBuffer:
        """One rollout of `n_steps` per world into the buffer; rewards shaped, advantages computed."""
        cfg = self.config
        if self._collector is None:
            self._start_collector(seed=cfg.seed)
        n_envs, act_dim = self.env.num_envs, self.policy.act_dim
        buf = self.rollout_buffer
        if buf is None or not buf.matches(cfg.n_steps, n_envs, self.obs_dim, act_dim):
            buf = self.rollout_buffer = RolloutBuffer(cfg.n_steps, n_envs, self.obs_dim, act_dim, self.device)
        last_value, reward_terms = self._collector.collect(buf)
        self.num_timesteps += self.data_parallel.sum(cfg.n_steps * n_envs)
        if self.data_parallel.enabled:  # every rank's episodes, in rank order: the same statistics everywhere
            ended = torch.tensor(list(self._rank_episodes), dtype=torch.float64).reshape(-1, 2)
            self._rank_episodes.clear()
            self.episodes.extend((r, int(n)) for r, n in self.data_parallel.gather_rows(ended).tolist())
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
        """Learn from one rollout (`buf`: advantages computed): the algorithm itself."""
        raise NotImplementedError

    # ------------------------------------------------------------------ subclass hooks
    def _rollout_hooks(self) -> RolloutHooks:
        """What the collector calls at reset, rollout start, every step and rollout end (nothing here)."""
        return RolloutHooks()

    def _shape_rewards(self, buf: RolloutBuffer) -> torch.Tensor:
        """The (n_steps, n_envs) rewards GAE sees, from the env's (`buf.rewards`)."""
        return buf.rewards

    def _extra_state(self) -> dict:
        return {}

    def _load_extra_state(self, state: dict) -> None:
        pass

    # ------------------------------------------------------------------ persistence
    def save(self, path: str | Path, optimizer: bool = True) -> Path:
        """One self-contained file: weights, normalisers, optimiser, hyperparameters, the policy's
        class and arguments, step count, env id and kwargs (when plain data), RNG state and
        library versions. Written atomically. `optimizer=False` leaves the optimiser's moments
        out (a third of the size): a policy to ship and act with; training from it starts the
        optimiser afresh."""
        env_kwargs = _plain(self.env_kwargs)
        dropped = sorted(set(self.env_kwargs) - set(env_kwargs))
        if dropped:
            warnings.warn(f"env kwargs {dropped} are not plain data and are left out of the checkpoint; "
                          "pass them again when loading with env='auto'", stacklevel=2)
        record = policy_record(self.policy)
        payload = {
            "class": type(self).__name__,
            "hyperparams": self.hyperparams,
            "policy_class": record["class"],
            "policy_kwargs": record["kwargs"],
            "spaces": {"obs_dim": self.obs_dim, "act_dim": self.act_dim,
                       "action_low": self.action_space.low.tolist(), "action_high": self.action_space.high.tolist()},
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
             override_settings: Iterable[str] = (), **overrides):
        """Rebuild an agent from `save`'s file: its policy made again from the recorded class and
        arguments (a checkpoint from before policies were plug-ins holds the actor-critic its
        hyperparameters describe), the weights, normalisers and optimiser loaded into it.

        With `env` (an env, or "auto" to make the recorded env id with its recorded kwargs,
        `env_kwargs` over them) it can continue training: call `learn(...,
        reset_num_timesteps=False)`. The env must be the recorded task, with the policy's
        recorded settings (`set_env`; `override_settings` names those `env_kwargs` or the env
        may change on purpose). `overrides` replace saved hyperparameters (learning rate,
        epochs ...), not the policy's arguments. `policy`: a fresh policy to load the weights
        into instead of the one the record makes."""
        device = resolve_device(device)
        ckpt = load_checkpoint(path, device)
        if ckpt["class"] != cls.__name__:
            raise ValueError(f"{path} holds a {ckpt['class']} agent; load it with agents.{ckpt['class']}.load "
                             "or agents.load")
        fixed = sorted(split_former_hyperparams(overrides)[1])
        if fixed:
            raise ValueError(f"{fixed} are arguments of the checkpoint's policy, which it fixes; a load cannot change "
                             "them")
        hp = {**split_former_hyperparams(ckpt["hyperparams"])[0], **overrides}
        agent = cls(None, device=device, verbose=verbose, **hp)
        if policy is None:
            try:
                policy = checkpoint_policy(ckpt)
            except PolicyClassError as e:
                raise PolicyClassError(f"{path}: {e}") from None
        sp = ckpt["spaces"]
        box = gym.spaces.Box(np.array(sp["action_low"], np.float32), np.array(sp["action_high"], np.float32))
        agent._build(sp["obs_dim"], box, policy)
        agent.policy.load_state_dict(ckpt["policy"])
        if ckpt["optimizer"] is not None:  # None: a policy saved to ship (save(optimizer=False))
            groups = len(ckpt["optimizer"]["param_groups"])
            if groups != len(agent.optimizer.param_groups):
                raise ValueError(f"{path}'s optimiser has {groups} parameter group(s), these settings give "
                                 f"{len(agent.optimizer.param_groups)}: a setting that splits the parameters "
                                 "(such as SimPoEPPO's refine_lr_scale) cannot change on a resume; start a new "
                                 "run from the checkpoint instead (agent.init)")
            agent.optimizer.load_state_dict(ckpt["optimizer"])
            for g, want in zip(agent.optimizer.param_groups, agent._param_groups()):
                g["lr_scale"] = want["lr_scale"]  # these settings' scale (a checkpoint before them has none)
        agent.num_timesteps, agent.iteration = ckpt["num_timesteps"], ckpt["iteration"]
        agent.episodes.extend(tuple(e) for e in ckpt["episodes"])
        agent.env_id, agent.env_kwargs = ckpt["env"]["id"], dict(ckpt["env"]["kwargs"] or {})
        torch.set_rng_state(ckpt["torch_rng"].cpu())
        agent.data_parallel.reseed_torch()  # every rank loaded rank 0's state; each needs its own
        if isinstance(env, str) and env == "auto":
            if agent.env_id is None:
                raise ValueError("the checkpoint records no env id; pass an env")
            env = agent.env_id
            env_kwargs = runnable_here(agent.env_kwargs, env_kwargs, f"{path}'s training")
            n_envs = n_envs or ckpt["env"]["n_envs"] or 1
        if env is not None:
            agent.set_env(env, n_envs=n_envs or 1, env_kwargs=env_kwargs, override_settings=override_settings)
        elif override_settings:
            raise ValueError("override_settings applies to the env load attaches; pass env= too")
        agent._load_extra_state(ckpt["extra"])
        agent.set_logger(log_dir, tensorboard)
        return agent


def _policy_kwargs(owner: str, default: type[Policy], policy, policy_kwargs: dict | None,
                   hyperparams: dict) -> tuple[dict, dict]:
    """(hyperparams, policy_kwargs) with the actor-critic's former hyperparameters moved over."""
    if isinstance(policy, Policy) and policy_kwargs:
        raise TypeError(f"{owner}(): policy_kwargs are for a policy class; this policy is built already")
    hyperparams, former = split_former_hyperparams(hyperparams)
    policy_kwargs = dict(policy_kwargs or {})
    if not former:
        return hyperparams, policy_kwargs
    names = ", ".join(sorted(former))
    if isinstance(policy, Policy):
        raise TypeError(f"{owner}(): {names} are arguments of the policy, which is built already")
    cls = policy_class(policy or default)
    if not issubclass(cls, ActorCritic):
        raise TypeError(f"{owner}(): {names} are ActorCritic's arguments, not {cls.__name__}'s; pass policy_kwargs")
    both = sorted(set(former) & set(policy_kwargs))
    if both:
        raise TypeError(f"{owner}(): {both} given both as hyperparameters and in policy_kwargs")
    warnings.warn(f"{owner}({', '.join(f'{k}=...' for k in sorted(former))}): the actor-critic's arguments are no "
                  "hyperparameters since policies are plug-ins; pass them as policy_kwargs={...}",
                  DeprecationWarning, stacklevel=3)
    return hyperparams, {**former, **policy_kwargs}


def _check_policy_spaces(policy: Policy, obs_dim: int, box: gym.spaces.Box) -> None:
    if (policy.obs_dim, policy.action_space.shape) != (obs_dim, box.shape):
        raise ValueError(f"the policy is for obs {policy.obs_dim} / action {policy.action_space.shape[0]} features, "
                         f"the env has {obs_dim} / {box.shape[0]}")
    if not (np.array_equal(policy.action_space.low, box.low) and np.array_equal(policy.action_space.high, box.high)):
        raise ValueError(f"the policy maps its actions onto [{policy.action_space.low.min()}, "
                         f"{policy.action_space.high.max()}], the env's action box is [{box.low.min()}, "
                         f"{box.high.max()}]; make the policy with the env's action space")


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

__all__ = ["OnPolicyAlgorithm", "OnPolicyConfig", "resolve_device"]
