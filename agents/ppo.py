"""Proximal Policy Optimisation with the options PHC's recipe relies on.

Read top to bottom: the constructor wires an env and an actor-critic together, `learn` alternates
`_collect` (a rollout of `n_steps` per world) and `_update` (`n_epochs` of clipped-surrogate
minibatch steps). Everything PHC tunes is a constructor argument: fixed or learned action std,
running observation normalisation (stored in the checkpoint), GAE, value normalisation, bounds loss
on the action mean, gradient clipping, separate actor and critic MLPs.

Subclasses (AMP) hook in through `_on_step`, `_shape_rewards`, `_update_extra` and
`_extra_state` without touching the loop.
"""
from __future__ import annotations

import time
import warnings
from collections import deque
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch
from gymnasium.vector import AutoresetMode, VectorEnv
from tqdm.auto import tqdm

from .callbacks import as_callback
from .checkpoint import load_checkpoint, save_checkpoint
from .logger import Logger
from .networks import ActorCritic
from .vec import autoreset_mode, final_observations, make_vec_env, reward_terms


def resolve_device(device: str | torch.device) -> torch.device:
    if str(device) == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    return torch.device(device)


class PPO:
    """PPO for Box action spaces on any Gymnasium env, single or vector.

    Args:
        env: an env id (made with `n_envs` worlds and `env_kwargs`; suite ids use their native
            batched env), a `gymnasium.Env`, a `gymnasium.vector.VectorEnv`, or None to act only.
        n_steps: rollout length per world (PHC: 32).
        batch_size: minibatch size in transitions (PHC: 16384).
        n_epochs: passes over each rollout (PHC: 6).
        learning_rate, lr_schedule: Adam step size, "constant" or "linear" decay to zero.
        gamma, gae_lambda: discount and GAE parameter (PHC: 0.99, 0.95).
        clip_range: PPO ratio clip (0.2). clip_range_vf: optional value clip, normalised units.
        ent_coef, vf_coef: entropy bonus and value-loss weight (PHC: 0, 5).
        bounds_loss_coef: penalty on action means beyond +-1.1 (PHC: 10).
        max_grad_norm: global gradient-norm clip (PHC: 50).
        target_kl: stop an update's epochs early once the approximate KL exceeds 1.5x this.
        normalize_obs, obs_clip: running observation normalisation, clipped to +-obs_clip.
        normalize_value: critic predicts returns normalised by running statistics.
        normalize_advantage: per-minibatch advantage standardisation.
        actor_hidden, critic_hidden, activation: the two MLPs (PHC: [1024, 512], SiLU).
        log_std_init, learn_std: action std; PHC fixes log std at -2.9.
        seed: seeds torch and the env's first reset.
        device: "auto", "cpu", "cuda", ...
        verbose: 1 prints a table per log, 0 is silent.
        log_dir: where progress.csv and TensorBoard files go (None: stdout only).
    """

    def __init__(
        self,
        env: str | gym.Env | VectorEnv | None,
        *,
        n_envs: int = 1,
        env_kwargs: dict | None = None,
        n_steps: int = 64,
        batch_size: int = 1024,
        n_epochs: int = 5,
        learning_rate: float = 3e-4,
        lr_schedule: str = "constant",
        gamma: float = 0.99,
        gae_lambda: float = 0.95,
        clip_range: float = 0.2,
        clip_range_vf: float | None = None,
        ent_coef: float = 0.0,
        vf_coef: float = 1.0,
        bounds_loss_coef: float = 0.0,
        max_grad_norm: float = 1.0,
        target_kl: float | None = None,
        normalize_obs: bool = True,
        obs_clip: float | None = 10.0,
        normalize_value: bool = True,
        normalize_advantage: bool = True,
        actor_hidden: tuple[int, ...] | list[int] = (256, 256),
        critic_hidden: tuple[int, ...] | list[int] = (256, 256),
        activation: str = "silu",
        log_std_init: float = -1.0,
        learn_std: bool = True,
        seed: int | None = None,
        device: str | torch.device = "auto",
        verbose: int = 1,
        log_dir: str | Path | None = None,
        tensorboard: bool = True,
    ):
        if lr_schedule not in ("constant", "linear"):
            raise ValueError(f"lr_schedule must be 'constant' or 'linear', got {lr_schedule!r}")
        self.hyperparams = dict(
            n_steps=int(n_steps), batch_size=int(batch_size), n_epochs=int(n_epochs),
            learning_rate=float(learning_rate), lr_schedule=lr_schedule, gamma=float(gamma),
            gae_lambda=float(gae_lambda), clip_range=float(clip_range),
            clip_range_vf=None if clip_range_vf is None else float(clip_range_vf),
            ent_coef=float(ent_coef), vf_coef=float(vf_coef), bounds_loss_coef=float(bounds_loss_coef),
            max_grad_norm=float(max_grad_norm), target_kl=None if target_kl is None else float(target_kl),
            normalize_obs=bool(normalize_obs), obs_clip=None if obs_clip is None else float(obs_clip),
            normalize_value=bool(normalize_value), normalize_advantage=bool(normalize_advantage),
            actor_hidden=[int(h) for h in actor_hidden], critic_hidden=[int(h) for h in critic_hidden],
            activation=activation, log_std_init=float(log_std_init), learn_std=bool(learn_std), seed=seed,
        )
        for k, v in self.hyperparams.items():
            setattr(self, k, v)
        self.device = resolve_device(device)
        self.verbose = verbose
        self.env = self.env_id = None
        self.env_kwargs: dict = {}
        self.num_timesteps = 0
        self.iteration = 0
        self.episodes: deque = deque(maxlen=100)  # (return, length) of the latest episodes
        self._last_obs = None
        if seed is not None:
            torch.manual_seed(seed)
        if env is not None:
            self.set_env(env, n_envs=n_envs, env_kwargs=env_kwargs)
            self._build(self.env.single_observation_space.shape[0], self.env.single_action_space)
        self.set_logger(log_dir, tensorboard)

    # ------------------------------------------------------------------ setup
    def _build(self, obs_dim: int, action_space: gym.spaces.Box) -> None:
        h = self.hyperparams
        self.obs_dim, self.act_dim = int(obs_dim), int(action_space.shape[0])
        low, high = action_space.low.astype(np.float64), action_space.high.astype(np.float64)
        if not (np.isfinite(low).all() and np.isfinite(high).all()):
            raise ValueError("the agents need a bounded Box action space (finite low and high)")
        self.action_low, self.action_high = low, high
        self.policy = ActorCritic(
            self.obs_dim, self.act_dim, actor_hidden=h["actor_hidden"], critic_hidden=h["critic_hidden"],
            activation=h["activation"], log_std_init=h["log_std_init"], learn_std=h["learn_std"],
            obs_clip=h["obs_clip"], normalize_obs=h["normalize_obs"], normalize_value=h["normalize_value"],
        ).to(self.device)
        params = [p for p in self.policy.parameters() if p.requires_grad]
        self.optimizer = torch.optim.Adam(params, lr=h["learning_rate"], eps=1e-5)

    def set_env(self, env, n_envs: int = 1, env_kwargs: dict | None = None) -> None:
        """Attach an env to train on; its spaces must match the policy's."""
        vec = make_vec_env(env, n_envs, env_kwargs)
        if hasattr(self, "policy"):
            if vec.single_observation_space.shape != (self.obs_dim,) or vec.single_action_space.shape != (self.act_dim,):
                raise ValueError(
                    f"env spaces obs {vec.single_observation_space.shape} / action {vec.single_action_space.shape} "
                    f"do not match the agent's ({self.obs_dim},) / ({self.act_dim},)")
        self.env = vec
        if isinstance(env, str):
            self.env_id, self.env_kwargs = env, dict(env_kwargs or {})
        else:
            spec = getattr(vec, "spec", None) or getattr(env, "spec", None)
            self.env_id = spec.id if spec is not None else None
        self.autoreset = autoreset_mode(vec)
        self._last_obs = None

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
        if self._last_obs is None:
            self._last_obs, info = self.env.reset(seed=self.seed if reset_num_timesteps else None)
            self._on_reset(info)
            n = self.env.num_envs
            self._prev_done = np.zeros(n, bool)
            self._ep_return, self._ep_length = np.zeros(n), np.zeros(n, np.int64)
        callback.on_training_start(self)
        bar = tqdm(total=target, initial=self.num_timesteps, disable=not progress_bar, unit="step",
                   dynamic_ncols=True, desc=type(self).__name__)
        start_steps, t0 = self.num_timesteps, time.perf_counter()
        try:
            while self.num_timesteps < target:
                self._set_learning_rate(target)
                rollout = self._collect()
                self._update(rollout)
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

    def _set_learning_rate(self, target: int) -> None:
        lr = self.learning_rate
        if self.lr_schedule == "linear":
            lr *= max(1.0 - self.num_timesteps / max(target, 1), 0.0)
        for g in self.optimizer.param_groups:
            g["lr"] = lr
        self.logger.record("train/learning_rate", lr)

    @torch.no_grad()
    def _collect(self) -> dict[str, torch.Tensor]:
        env, pol, dev = self.env, self.policy, self.device
        T, N = self.n_steps, env.num_envs
        buf = {k: torch.zeros(T, N, device=dev) for k in ("logp", "value", "reward", "done", "valid", "bootstrap")}
        buf["obs"] = torch.zeros(T, N, self.obs_dim, device=dev)
        buf["action"] = torch.zeros(T, N, self.act_dim, device=dev)
        terms_sum: dict[str, float] = {}
        self._on_rollout_start(T, N)
        for t in range(T):
            # NextStep autoreset: the step after an episode's end only resets; it is no transition.
            valid = ~self._prev_done
            obs = torch.as_tensor(self._last_obs, dtype=torch.float32, device=dev)
            if self.normalize_obs:
                pol.obs_norm.update(obs[torch.as_tensor(valid, device=dev)])
            nobs = pol.normalize(obs)
            dist = pol.dist(nobs)
            action = dist.sample()
            buf["obs"][t], buf["action"][t] = nobs, action
            buf["logp"][t] = dist.log_prob(action).sum(-1)
            buf["value"][t] = pol.value(nobs)

            next_obs, reward, terminated, truncated, info = env.step(self._to_env_action(action))
            terminated, truncated = np.asarray(terminated, bool), np.asarray(truncated, bool)
            done = terminated | truncated
            reward = np.where(valid, np.asarray(reward, np.float64), 0.0)
            # A time limit is not a failure: fold the value of where the episode stopped into the reward.
            cut = truncated & ~terminated & valid
            if cut.any():
                final = final_observations(next_obs, info, done, self.autoreset)[cut]
                v = pol.value(pol.normalize(torch.as_tensor(final, dtype=torch.float32, device=dev)))
                buf["bootstrap"][t, torch.as_tensor(cut, device=dev)] = self.gamma * v
            buf["reward"][t] = torch.as_tensor(reward, dtype=torch.float32, device=dev)
            buf["done"][t] = torch.as_tensor(done, dtype=torch.float32, device=dev)
            buf["valid"][t] = torch.as_tensor(valid, dtype=torch.float32, device=dev)
            self._on_step(t, info, done, valid)
            for k, v in reward_terms(info, valid).items():
                terms_sum[k] = terms_sum.get(k, 0.0) + v

            self._ep_return += reward
            self._ep_length += valid
            for i in np.flatnonzero(done & valid):
                self.episodes.append((self._ep_return[i], self._ep_length[i]))
            self._ep_return[done] = 0.0
            self._ep_length[done] = 0
            self._prev_done = done if self.autoreset == AutoresetMode.NEXT_STEP else np.zeros(N, bool)
            self._last_obs = next_obs
            self.num_timesteps += N
            if not np.isfinite(next_obs).all():
                raise FloatingPointError("the env returned a non-finite observation; the simulation diverged "
                                         "without ending its episode")

        last_value = pol.value(pol.normalize(torch.as_tensor(self._last_obs, dtype=torch.float32, device=dev)))
        buf["reward"] = self._shape_rewards(buf)
        buf["advantage"], buf["return"] = self._gae(buf, last_value)
        v = buf["valid"].bool()
        self.logger.record("rollout/step_reward_mean", buf["reward"][v].mean().item() if v.any() else 0.0)
        for k, s in terms_sum.items():
            self.logger.record(f"rollout/reward_{k}", s / T)
        if self.episodes:
            ret, length = np.mean(self.episodes, axis=0)
            self.logger.record("rollout/ep_rew_mean", ret)
            self.logger.record("rollout/ep_len_mean", length)
        return buf

    def _gae(self, buf: dict, last_value: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        adv = torch.zeros_like(buf["reward"])
        running = torch.zeros_like(last_value)
        for t in reversed(range(self.n_steps)):
            next_value = last_value if t == self.n_steps - 1 else buf["value"][t + 1]
            live = 1.0 - buf["done"][t]
            delta = buf["reward"][t] + buf["bootstrap"][t] + self.gamma * next_value * live - buf["value"][t]
            running = delta + self.gamma * self.gae_lambda * live * running
            adv[t] = running
        return adv, adv + buf["value"]

    def _update(self, buf: dict) -> None:
        pol = self.policy
        keep = buf["valid"].reshape(-1).bool()
        b = {k: v.reshape(-1, *v.shape[2:])[keep] for k, v in buf.items() if k != "valid"}
        n = len(b["obs"])
        if self.normalize_value:
            pol.value_norm.update(b["return"])
        stats: dict[str, list[float]] = {k: [] for k in ("policy_loss", "value_loss", "entropy", "bounds_loss",
                                                         "approx_kl", "clip_fraction", "grad_norm")}
        mb = min(self.batch_size, n)
        stop = False
        for _ in range(self.n_epochs):
            perm = torch.randperm(n, device=self.device)
            for start in range(0, n - mb + 1, mb):
                i = perm[start:start + mb]
                dist = pol.dist(b["obs"][i])
                logp = dist.log_prob(b["action"][i]).sum(-1)
                log_ratio = logp - b["logp"][i]
                ratio = log_ratio.exp()
                adv = b["advantage"][i]
                if self.normalize_advantage and len(i) > 1:
                    adv = (adv - adv.mean()) / (adv.std() + 1e-8)
                policy_loss = torch.max(-adv * ratio, -adv * ratio.clamp(1 - self.clip_range, 1 + self.clip_range)).mean()

                v_pred = pol.critic(b["obs"][i]).squeeze(-1)  # in normalised units when normalize_value
                v_target, v_old = b["return"][i], b["value"][i]
                if self.normalize_value:
                    v_target, v_old = pol.value_norm(v_target), pol.value_norm(v_old)
                value_loss = (v_pred - v_target).square()
                if self.clip_range_vf is not None:
                    v_clip = v_old + (v_pred - v_old).clamp(-self.clip_range_vf, self.clip_range_vf)
                    value_loss = torch.max(value_loss, (v_clip - v_target).square())
                value_loss = 0.5 * value_loss.mean()

                entropy = dist.entropy().sum(-1).mean()
                mu = dist.mean
                bounds_loss = ((mu - 1.1).clamp(min=0).square() + (mu + 1.1).clamp(max=0).square()).sum(-1).mean()
                loss = (policy_loss + self.vf_coef * value_loss - self.ent_coef * entropy
                        + self.bounds_loss_coef * bounds_loss)

                self.optimizer.zero_grad(set_to_none=True)
                loss.backward()
                grad_norm = torch.nn.utils.clip_grad_norm_(pol.parameters(), self.max_grad_norm)
                self.optimizer.step()

                with torch.no_grad():
                    approx_kl = ((ratio - 1) - log_ratio).mean().item()
                    clip_fraction = ((ratio - 1).abs() > self.clip_range).float().mean().item()
                for k, v in (("policy_loss", policy_loss), ("value_loss", value_loss), ("entropy", entropy),
                             ("bounds_loss", bounds_loss), ("grad_norm", grad_norm)):
                    stats[k].append(float(v.detach()))
                stats["approx_kl"].append(approx_kl)
                stats["clip_fraction"].append(clip_fraction)
                if self.target_kl is not None and approx_kl > 1.5 * self.target_kl:
                    stop = True
                    break
            if stop:
                break
        for k, v in stats.items():
            if v:
                self.logger.record(f"train/{k}", float(np.mean(v)))
        ret, val = b["return"], b["value"]
        var = ret.var() if n > 1 else torch.tensor(0.0)
        self.logger.record("train/explained_variance", float(1 - (ret - val).var() / var) if var > 0 else float("nan"))
        self.logger.record("train/std", float(pol.log_std.detach().exp().mean()))
        self._update_extra(buf)

    # ------------------------------------------------------------------ subclass hooks
    def _on_reset(self, info: dict) -> None:
        pass

    def _on_rollout_start(self, n_steps: int, n_envs: int) -> None:
        pass

    def _on_step(self, t: int, info: dict, done: np.ndarray, valid: np.ndarray) -> None:
        pass

    def _shape_rewards(self, buf: dict) -> torch.Tensor:
        return buf["reward"]

    def _update_extra(self, buf: dict) -> None:
        pass

    def _extra_state(self) -> dict:
        return {}

    def _load_extra_state(self, state: dict) -> None:
        pass

    # ------------------------------------------------------------------ persistence
    def save(self, path: str | Path) -> Path:
        """One self-contained file: weights, normalisers, optimiser, hyperparameters, step count,
        env id and kwargs (when plain data), RNG state and library versions. Written atomically."""
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
            "optimizer": self.optimizer.state_dict(),
            "num_timesteps": self.num_timesteps,
            "iteration": self.iteration,
            "episodes": [[float(r), int(n)] for r, n in self.episodes],
            "torch_rng": torch.get_rng_state(),
            "extra": self._extra_state(),
        }
        return save_checkpoint(payload, path)

    @classmethod
    def load(cls, path: str | Path, env=None, device: str | torch.device = "auto", *,
             n_envs: int | None = None, env_kwargs: dict | None = None, verbose: int = 1,
             log_dir: str | Path | None = None, tensorboard: bool = True, **overrides) -> "PPO":
        """Rebuild an agent from `save`'s file. With `env` (an env, or "auto" to make the recorded
        env id with its recorded kwargs) it can continue training: call
        `learn(..., reset_num_timesteps=False)`. `overrides` replace saved hyperparameters
        (learning rate, epochs ... not network sizes)."""
        device = resolve_device(device)
        ckpt = load_checkpoint(path, device)
        if ckpt["class"] != cls.__name__:
            raise ValueError(f"{path} holds a {ckpt['class']} agent; load it with agents.{ckpt['class']}.load "
                             "or agents.load")
        hp = {**ckpt["hyperparams"], **overrides}
        agent = cls(None, device=device, verbose=verbose, **hp)
        sp = ckpt["spaces"]
        box = gym.spaces.Box(np.array(sp["action_low"], np.float32), np.array(sp["action_high"], np.float32))
        agent._build(sp["obs_dim"], box)
        agent.policy.load_state_dict(ckpt["policy"])
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
            agent.set_env(env, n_envs=n_envs or 1, env_kwargs=env_kwargs)
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

