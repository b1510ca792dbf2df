"""Rollouts apart from the update: where transitions are stored and how they are gathered.

- `RolloutBuffer`: `n_steps` x `n_envs` transitions in preallocated tensors, GAE over them, and
  minibatches of the valid ones. Algorithms that need more per step (AMP's discriminator windows)
  add named fields with `extra`.
- `RolloutCollector`: steps a vector env with a policy and fills a buffer, carrying the env's
  state (last observation, episode returns) from one rollout to the next. The buffer holds the
  policy's own actions and their log-probabilities; the env gets them through the policy's map
  (`Policy.env_action`). It calls a `RolloutHooks` object at reset, at the start of each
  rollout, after every step and at the end of a rollout.

An algorithm's iteration is then: `collector.collect(buffer)`, shape the rewards if it wants to,
`buffer.compute_advantages(...)`, then its own update over `buffer.minibatches(...)`.

Vector envs autoreset in one of two ways (Gymnasium's AutoresetMode). SameStep: the step that ends
an episode already returns the next episode's first observation. NextStep: the step after the end
only resets the world, its action is ignored and its reward is no transition; such steps are kept
in the buffer with `valid` = 0 so every tensor stays (n_steps, n_envs), and left out of GAE's
targets and of every minibatch.
"""
from __future__ import annotations

import contextlib
from collections import deque
from typing import Iterator

import numpy as np
import torch
from gymnasium.vector import AutoresetMode, VectorEnv

from .networks import Policy
from .vec import autoreset_mode, final_observations, reward_terms


class RolloutBuffer:
    """One rollout: tensors of shape (n_steps, n_envs, ...) allocated once and refilled.

    obs:        observations as the policy saw them (normalised with that step's statistics)
    actions:    sampled actions, the policy's own (before its map to the env's), unclipped
    log_probs:  log-density of `actions` when they were sampled
    values:     value estimates of `obs`, in return units
    rewards:    rewards (0 on invalid steps); algorithms may reshape them before GAE
    dones:      1 where the step ended its episode (terminated or truncated)
    bootstrap:  V(final observation) where a time limit cut the episode, else 0: a truncated
                episode's future is not zero; GAE adds gamma x this to the step's reward, which
                keeps its "no chaining across episodes" rule simple
    valid:      1 for real transitions, 0 for NextStep's reset-only steps
    advantages, returns: filled by `compute_advantages`
    """

    FIELDS = ("log_probs", "values", "rewards", "dones", "bootstrap", "valid", "advantages", "returns")

    def __init__(self, n_steps: int, n_envs: int, obs_dim: int, act_dim: int, device: torch.device | str = "cpu"):
        self.n_steps, self.n_envs, self.device = int(n_steps), int(n_envs), torch.device(device)
        self.obs = torch.zeros(n_steps, n_envs, obs_dim, device=self.device)
        self.actions = torch.zeros(n_steps, n_envs, act_dim, device=self.device)
        for name in self.FIELDS:
            setattr(self, name, torch.zeros(n_steps, n_envs, device=self.device))
        self.extras: dict[str, torch.Tensor] = {}
        self._carried: set[str] = set()  # extras that `transitions()` and its minibatches carry
        self._flat: dict[str, torch.Tensor] | None = None  # `transitions()`, once per rollout

    def extra(self, name: str, dim: int, carry: bool = False) -> torch.Tensor:
        """A named (n_steps, n_envs, dim) field an algorithm fills itself (allocated once).
        `carry=True`: `transitions()` (and so every minibatch of the update) holds it too, one
        row per transition, for a loss term of the update's own."""
        field = self.extras.get(name)
        if field is None or field.shape[-1] != dim:
            field = self.extras[name] = torch.zeros(self.n_steps, self.n_envs, dim, device=self.device)
        if carry:
            self._carried.add(name)
        return field

    def matches(self, n_steps: int, n_envs: int, obs_dim: int, act_dim: int) -> bool:
        return self.obs.shape == (n_steps, n_envs, obs_dim) and self.actions.shape[-1] == act_dim

    def reset(self) -> None:
        # Only `bootstrap` is written sparsely; the rest is overwritten step by step. Zeroing all
        # keeps a failed rollout from leaking into the next one.
        for t in (self.obs, self.actions, *(getattr(self, n) for n in self.FIELDS), *self.extras.values()):
            t.zero_()
        self._flat = None

    def compute_advantages(self, last_value: torch.Tensor, gamma: float, gae_lambda: float) -> None:
        """GAE(gamma, lambda) advantages and their value targets (`returns`), in place."""
        self.advantages.copy_(gae(self.rewards + gamma * self.bootstrap, self.values, self.dones, last_value,
                                  gamma, gae_lambda))
        self.returns.copy_(self.advantages + self.values)
        self._flat = None

    def valid_mask(self) -> torch.Tensor:
        """(n_steps * n_envs,) bool: which flattened transitions are real."""
        return self.valid.reshape(-1).bool()

    def transitions(self) -> dict[str, torch.Tensor]:
        """The valid transitions, flattened: obs, actions, log_probs, values, advantages, returns
        and the carried extras (gathered once per rollout, after `compute_advantages`)."""
        if self._flat is None:
            keep = self.valid_mask()
            fields = {n: getattr(self, n) for n in ("obs", "actions", "log_probs", "values", "advantages", "returns")}
            fields.update((n, self.extras[n]) for n in sorted(self._carried))
            self._flat = {n: f.reshape(-1, *f.shape[2:])[keep] for n, f in fields.items()}
        return self._flat

    def minibatches(self, batch_size: int, count: int | None = None) -> Iterator[dict[str, torch.Tensor]]:
        """One epoch over the valid transitions in shuffled minibatches (`minibatches`)."""
        return minibatches(self.transitions(), batch_size, count)


def minibatches(data: dict[str, torch.Tensor], batch_size: int,
                count: int | None = None) -> Iterator[dict[str, torch.Tensor]]:
    """One epoch over `data` (tensors of equal length) in shuffled minibatches: the
    round(n / batch_size) (at least one) equal shares of the n transitions, each within one of
    the others' size. Every transition is used: a rollout with a few invalid (reset-only) steps
    has slightly fewer than n_steps x n_envs transitions, and cutting it into whole
    `batch_size` pieces would drop almost a minibatch of them every epoch. `count`: that many
    shares instead (at most n; the ranks of a data-parallel job agree on one,
    `distributed.DataParallel.minibatch_count`)."""
    n = len(next(iter(data.values())))
    if count is None:
        count = minibatch_count(n, batch_size)
    if n == 0 or count == 0:
        return
    perm = torch.randperm(n, device=next(iter(data.values())).device)
    for i in torch.tensor_split(perm, count):
        yield {k: v[i] for k, v in data.items()}


def minibatch_count(n: int, batch_size: int) -> int:
    """How many minibatches `minibatches` cuts n transitions into: round(n / batch_size), at
    least one; none for no transitions."""
    return max(1, round(n / batch_size)) if n > 0 else 0


def gae(rewards: torch.Tensor, values: torch.Tensor, dones: torch.Tensor, last_value: torch.Tensor,
        gamma: float, gae_lambda: float) -> torch.Tensor:
    """Generalised advantage estimates of (T, N) rewards (bootstraps included) and values.

    A done step does not chain into the next (that step belongs to another episode); the last
    step chains into `last_value`, the value of the observation after the rollout.
    """
    adv = torch.zeros_like(rewards)
    running = torch.zeros_like(last_value)
    T = len(rewards)
    for t in reversed(range(T)):
        next_value = last_value if t == T - 1 else values[t + 1]
        live = 1.0 - dones[t]
        delta = rewards[t] + gamma * next_value * live - values[t]
        running = delta + gamma * gae_lambda * live * running
        adv[t] = running
    return adv


class RolloutHooks:
    """What a collector tells an algorithm that needs more than transitions. Defaults do nothing.

    on_reset(info): the env's first reset (the `info` of `env.reset`).
    on_rollout_start(buffer): before the first step of a rollout.
    on_step(t, info, done, valid): after step `t`; `done` marks worlds whose episode ended in this
        step, `valid` worlds whose step was a real transition (both (n_envs,) bool arrays).
    on_rollout_end(buffer): after the last step, while `buffer.obs` still holds the raw
        observations (before they are normalised): labels that need them, in one batch (a
        teacher's actions, for distillation).
    """

    def on_reset(self, info: dict) -> None:
        pass

    def on_rollout_start(self, buffer: RolloutBuffer) -> None:
        pass

    def on_step(self, t: int, info: dict, done: np.ndarray, valid: np.ndarray) -> None:
        pass

    def on_rollout_end(self, buffer: RolloutBuffer) -> None:
        pass


class InfoColumn(RolloutHooks):
    """Stores `info[key]`, which the env reports with each observation (`dim` numbers per world),
    beside that observation: the rollout's extra `key` (`carry`: in every minibatch too). The
    `info` of step t describes the observation after it, the next stored one; the last step's
    waits for the next rollout's first row. `missing`: the error when the env reports no `key`.
    `sources`: info keys whose values, side by side, make the column (default: `key` alone)."""

    def __init__(self, key: str, dim: int, device: torch.device, missing: str, carry: bool = False,
                 sources: tuple[str, ...] | None = None):
        self.key, self.dim, self.device, self.missing, self.carry = key, dim, device, missing, carry
        self.sources = (key,) if sources is None else tuple(sources)
        self.next: torch.Tensor | None = None  # the value for the next rollout's first observation

    def _value(self, info: dict) -> torch.Tensor:
        if any(k not in info for k in self.sources):
            raise ValueError(self.missing)
        return torch.cat([torch.as_tensor(info[k], dtype=torch.float32, device=self.device).reshape(len(info[k]), -1)
                          for k in self.sources], -1)

    def on_reset(self, info: dict) -> None:
        self.next = self._value(info)

    def on_rollout_start(self, buffer: RolloutBuffer) -> None:
        self.column = buffer.extra(self.key, self.dim, carry=self.carry)
        self.column[0] = self.next

    def on_step(self, t: int, info: dict, done: np.ndarray, valid: np.ndarray) -> None:
        if t + 1 < len(self.column):
            self.column[t + 1] = self._value(info)
        else:
            self.next = self._value(info)


class RolloutCollector:
    """Steps `env` with `policy` and fills a `RolloutBuffer`, one rollout per `collect` call.

    The env steps on `policy.env_action(action, obs)` of each sampled action, as the env's own
    kind of array; the buffer keeps the sampled actions.
    episodes: a deque that receives (return, length) of every episode that ends.
    hooks: a `RolloutHooks`.
    value_threads: torch CPU threads for the value pass after the last step (None: as set).
    noise_hold: steps each world keeps its exploration noise (1: the distribution's own sample
        every step). Above 1 the action is mean + std * eps with eps held for that many steps
        (and redrawn when an episode starts): each action still has the policy's distribution
        given its observation, which is what the stored log-probabilities score, but successive
        ones explore in one direction. A body driven through a latent space (PULSE) moves its
        hand three times as far in a second under held noise as under fresh noise of the same
        size (benchmarks/latent_steering.py). The update treats steps as independent, as
        Stable-Baselines3's gSDE does with its `sde_sample_freq`.

    Only the actor runs between env steps. The critic does not change during a rollout, so the
    values of all its observations (and of the final observations of time-limited episodes, for
    their bootstrap) come from one batched pass after the last step: one large
    matrix product instead of `n_steps` small ones, run while the simulator idles (on every core
    with `value_threads`). That pass is a third of the policy's time in a rollout.

    The observation statistics are frozen during a rollout (the policy acts as one function
    throughout it) and take in the rollout's valid observations in one batch at its end: a
    per-step update cost a fifth of the collector's own time on 64 worlds. Each valid
    observation is counted once; the reset observations are counted at `reset`.
    """

    def __init__(self, env: VectorEnv, policy: Policy, episodes: deque | None = None, hooks: RolloutHooks | None = None,
                 device: torch.device | str = "cpu", value_threads: int | None = None, noise_hold: int = 1):
        if isinstance(noise_hold, bool) or not isinstance(noise_hold, int) or noise_hold < 1:
            raise ValueError(f"noise_hold must be a whole number of steps >= 1, got {noise_hold!r}")
        self.env, self.policy = env, policy
        self.noise_hold = noise_hold
        self.episodes = episodes if episodes is not None else deque(maxlen=100)
        self.hooks = hooks if hooks is not None else RolloutHooks()
        self.device = torch.device(device)
        self.value_threads = value_threads
        self.autoreset = autoreset_mode(env)
        self.last_obs: np.ndarray | None = None  # None until `reset`

    def reset(self, seed: int | None = None) -> None:
        """Reset every world (the only full reset: afterwards the env autoresets)."""
        self.last_obs, info = self.env.reset(seed=seed)
        self.hooks.on_reset(info)
        n = self.env.num_envs
        # A torch-native env (smpl_envs' "warp" backend) hands tensors: then nothing of a
        # rollout leaves the device; a NumPy env's arrays are copied in once per step.
        self.native = isinstance(self.last_obs, torch.Tensor)
        # The statistics move once per rollout (see `collect`); the reset observations go in
        # now, so the first rollout does not act on unnormalised input. They are the next
        # rollout's first step, which `collect` then leaves out.
        self.policy.update_obs_stats(self._tensor(self.last_obs))
        self._first_step_folded = True
        self.prev_done = torch.zeros(n, dtype=torch.bool, device=self.device)
        self.ep_return = torch.zeros(n, dtype=torch.float64, device=self.device)
        self.ep_length = torch.zeros(n, dtype=torch.int64, device=self.device)
        self.noise: torch.Tensor | None = None  # the held exploration noise, (N, act_dim)
        self.noise_age = torch.zeros(n, dtype=torch.int64, device=self.device)

    def _tensor(self, x) -> torch.Tensor:
        return torch.as_tensor(x, dtype=torch.float32, device=self.device)

    def _flags(self, x) -> torch.Tensor:
        return torch.as_tensor(x, dtype=torch.bool, device=self.device)

    def _env_array(self, x: torch.Tensor):
        """`x` as the env's own kind of array, for the hooks (which read the env's `info`)."""
        return x if self.native else x.cpu().numpy()

    def _held_sample(self, dist: torch.distributions.Distribution) -> torch.Tensor:
        """mean + std * eps, eps redrawn for the worlds whose hold is over or just began."""
        if not isinstance(dist, torch.distributions.Normal):
            raise TypeError(f"noise_hold > 1 needs a Gaussian policy (torch Normal); this one acts with a "
                            f"{type(dist).__name__}")
        due = (self.noise_age % self.noise_hold == 0)[:, None]
        fresh = torch.randn_like(dist.mean)
        self.noise = fresh if self.noise is None else torch.where(due, fresh, self.noise)
        return dist.mean + dist.stddev * self.noise

    @torch.no_grad()
    def collect(self, buf: RolloutBuffer) -> tuple[torch.Tensor, dict[str, float]]:
        """Fill `buf` with `buf.n_steps` steps of every world. Returns the value of the
        observation after the last step (GAE's tail) and the mean per step of each `reward_*`
        term the env reports."""
        if self.last_obs is None:
            raise RuntimeError("call reset() before collect()")
        env, pol = self.env, self.policy
        N = env.num_envs
        buf.reset()
        self.hooks.on_rollout_start(buf)
        terms_sum: dict[str, float] = {}
        cut_obs = []  # final observations of time-limited episodes, in (step, world) order
        cut_at = torch.zeros(buf.n_steps, N, dtype=torch.bool, device=self.device)
        for t in range(buf.n_steps):
            # NextStep autoreset: the step after an episode's end only resets; it is no transition.
            valid = ~self.prev_done
            obs = self._tensor(self.last_obs)
            dist = pol.action_distribution(pol.normalize(obs))
            action = dist.sample() if self.noise_hold == 1 else self._held_sample(dist)
            buf.obs[t], buf.actions[t] = obs, action  # raw until the rollout's end
            buf.log_probs[t] = dist.log_prob(action).sum(-1)

            env_action = pol.env_action(action, obs)  # the policy's map: the one call it adds to a step
            next_obs, reward, terminated, truncated, info = env.step(env_action if self.native else
                                                                     env_action.cpu().numpy())
            terminated, truncated = self._flags(terminated), self._flags(truncated)
            done = terminated | truncated
            reward = torch.where(valid, torch.as_tensor(reward, device=self.device).double(), 0.0)
            done_env, valid_env = self._env_array(done), self._env_array(valid)
            # A time limit is not a failure: keep the value of where the episode stopped.
            cut = truncated & ~terminated & valid
            if cut.any():  # their values come with the batched pass at the end
                cut_obs.append(self._tensor(final_observations(next_obs, info, done_env, self.autoreset))[cut])
                cut_at[t] = cut
            buf.rewards[t] = reward
            buf.dones[t] = done
            buf.valid[t] = valid
            self.hooks.on_step(t, info, done_env, valid_env)
            for k, v in reward_terms(info, valid_env).items():
                terms_sum[k] = terms_sum.get(k, 0.0) + v

            self.ep_return += reward
            self.ep_length += valid
            ended = done & valid
            if ended.any():
                self.episodes.extend(zip(self.ep_return[ended].tolist(), self.ep_length[ended].tolist()))
            self.ep_return[done] = 0.0
            self.ep_length[done] = 0
            if self.noise_hold > 1:
                self.noise_age = torch.where(done, 0, self.noise_age + 1)
            self.prev_done = done if self.autoreset == AutoresetMode.NEXT_STEP else torch.zeros_like(done)
            self.last_obs = next_obs
            # The sum is non-finite iff an element is (or the sum overflows, itself divergence);
            # 20x cheaper than an elementwise isfinite at these sizes.
            if not bool(torch.as_tensor(next_obs).sum().isfinite()):
                raise FloatingPointError("the env returned a non-finite observation; the simulation diverged "
                                         "without ending its episode")

        self.hooks.on_rollout_end(buf)
        with torch_threads(self.value_threads):
            # Stored observations become what the actor saw (this rollout's statistics), then
            # every valid one not yet counted is folded into the statistics in one batch.
            first = 1 if self._first_step_folded else 0
            self._first_step_folded = False
            raw = buf.obs[first:][buf.valid[first:].bool()]
            buf.obs.copy_(pol.normalize(buf.obs))
            tail = pol.normalize(torch.cat([self._tensor(self.last_obs), *cut_obs]))
            pol.update_obs_stats(raw)
            values = pol.value(torch.cat([buf.obs.reshape(-1, buf.obs.shape[-1]), tail]))
        T = buf.n_steps
        buf.values.copy_(values[:T * N].reshape(T, N))
        buf.bootstrap[cut_at] = values[(T + 1) * N:]  # a mask selects in (step, world) order
        return values[T * N:(T + 1) * N], {k: float(s) / T for k, s in terms_sum.items()}


@contextlib.contextmanager
def torch_threads(n: int | None):
    """Run the block with `n` torch CPU threads (None: leave the setting alone)."""
    if n is None or n == torch.get_num_threads():
        yield
        return
    before = torch.get_num_threads()
    torch.set_num_threads(n)
    try:
        yield
    finally:
        torch.set_num_threads(before)
