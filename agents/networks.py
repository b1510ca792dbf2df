"""The policies the agents train: the plug-in interface (`Policy`) and PHC's actor-critic
(`ActorCritic`, the default).

A policy is made as `cls(obs_dim, action_space, **kwargs)`: the env's observation size, the
env's action Box (or, for an env whose actions are [-1, 1]^n, just n) and its own keyword
arguments. It remembers those arguments (`init_kwargs`), so a checkpoint records its class and
arguments and makes it again when loaded (`agents.policies`), as Stable-Baselines3 stores
`policy_class` and `policy_kwargs`; the weights come from the state dict.

A policy has its own actions: `act_dim` numbers, with a distribution from `forward`. The agent
samples, stores and scores those, and hands the env `env_action(action, obs)`: the policy's map
from its actions to the env's, which may read the observation. The actor-critic acts in
[-1, 1]^69 and its map clamps and rescales onto the env's box; a composer acts with primitive
weights and maps them to the weighted primitives' actions; a latent-space policy acts with a
latent code and maps it through its decoder.

The policy owns the observation normaliser (and the critic's return normaliser): they are part
of the function from observation to action, so a saved policy acts on raw observations without
the algorithm, and the normalisers travel inside `state_dict`. The algorithm decides when their
statistics move (`update_obs_stats` on the valid steps of a rollout, `update_value_stats` on a
rollout's returns), because only it knows which steps are real transitions.

Observations in a rollout are stored normalised with the statistics the rollout acted under
(`normalize`), so an update scores the actions on exactly the input the actor acted on. Hence
the split: `act` and `env_action` take raw observations; `forward`, `value` and
`evaluate_actions` take normalised ones (`nobs`).
"""
from __future__ import annotations

import inspect
from typing import Any, NamedTuple, Sequence

import gymnasium as gym
import numpy as np
import torch
from torch import nn
from torch.distributions import Normal

from .normalizer import RunningNorm

ACTIVATIONS = {"relu": nn.ReLU, "elu": nn.ELU, "silu": nn.SiLU, "tanh": nn.Tanh, "gelu": nn.GELU}


def activation(name: str) -> type[nn.Module]:
    try:
        return ACTIVATIONS[name.lower()]
    except KeyError:
        raise ValueError(f"activation must be one of {sorted(ACTIVATIONS)}, got {name!r}") from None


def mlp(in_dim: int, hidden: Sequence[int], out_dim: int, act: str, out_gain: float = 1.0) -> nn.Sequential:
    layers, dims = [], [in_dim, *hidden]
    for a, b in zip(dims[:-1], dims[1:]):
        layers += [nn.Linear(a, b), activation(act)()]
    out = nn.Linear(dims[-1], out_dim)
    # A small last layer starts every policy near the zero action and every critic near zero,
    # which matters for PD-controlled humanoids: a random large mean throws them to the floor.
    nn.init.orthogonal_(out.weight, gain=out_gain)
    nn.init.zeros_(out.bias)
    return nn.Sequential(*layers, out)


def action_box(action_space: gym.spaces.Box | int) -> gym.spaces.Box:
    """The env's action Box: as given, or [-1, 1]^n for a size n."""
    if isinstance(action_space, gym.spaces.Box):
        if len(action_space.shape) != 1:
            raise ValueError(f"the agents need a flat Box action space, got {action_space}")
        return action_space
    if isinstance(action_space, bool) or not isinstance(action_space, (int, np.integer)) or action_space < 1:
        raise TypeError(f"action_space must be the env's action Box or its size, got {action_space!r}")
    return gym.spaces.Box(-1.0, 1.0, (int(action_space),), np.float32)


class ActionEval(NamedTuple):
    """What a PPO update needs of a policy on a minibatch of stored (observation, action) pairs."""

    log_prob: torch.Tensor  # (B,) log-density of the stored actions under the current policy
    entropy: torch.Tensor   # (B,) entropy of the current action distribution
    mean: torch.Tensor      # (B, act_dim) action mean, for the bounds loss
    value: torch.Tensor     # (B,) critic output in its training units (`Policy.value_targets`)
    # What the policy computed on the way that an agent's own loss terms may reuse instead of
    # running the network twice (agents.simpoe: the refined joint angles); None: nothing.
    extras: dict[str, torch.Tensor] | None = None


class Policy(nn.Module):
    """What the agents need from a policy (module docstring). Subclasses call
    `super().__init__(obs_dim, action_space, act_dim)` and implement `forward`; the rest has
    defaults for a policy without normalisers that acts in the env's own [-1, 1]-space.

    Attributes: `obs_dim` (the env's observation size), `act_dim` (the policy's own action
    size), `action_space` (the env's action Box), `init_kwargs` (the keyword arguments it was
    made with, defaults included: what a checkpoint records).
    """

    obs_dim: int
    act_dim: int
    action_space: gym.spaces.Box

    def __new__(cls, *args, **kwargs):
        # The arguments, as the constructor binds them, before __init__ runs: every subclass gets
        # them recorded without writing a line for it. Defaults are recorded too, so a later
        # change of a default cannot change what a saved policy is made as.
        # (A partial bind: copy and pickle make the object without arguments, then restore its
        # __dict__, and a wrong call is for __init__ to refuse.)
        self = super().__new__(cls)
        bound = inspect.signature(cls.__init__).bind_partial(None, *args, **kwargs)
        bound.apply_defaults()
        object.__setattr__(self, "_init_arguments", dict(list(bound.arguments.items())[1:]))
        return self

    def __init__(self, obs_dim: int, action_space: gym.spaces.Box | int, act_dim: int | None = None):
        super().__init__()
        box = action_box(action_space)
        self.obs_dim, self.action_space = int(obs_dim), box
        self.act_dim = int(box.shape[0] if act_dim is None else act_dim)
        low, high = (torch.as_tensor(x, dtype=torch.float64) for x in (box.low, box.high))
        if not (torch.isfinite(low).all() and torch.isfinite(high).all()):
            raise ValueError("the agents need a bounded Box action space (finite low and high)")
        # Not in the state dict: the spaces come with the constructor's arguments.
        self.register_buffer("_action_low", low, persistent=False)
        self.register_buffer("_action_span", high - low, persistent=False)
        self._unit_box = bool((low == -1).all() and (high == 1).all())

    @property
    def init_kwargs(self) -> dict[str, Any]:
        """The keyword arguments the policy was made with, after the two spaces."""
        params = list(inspect.signature(type(self).__init__).parameters.values())[1:]
        if len(params) < 2 or any(p.kind is p.VAR_POSITIONAL for p in params[:2]):
            raise TypeError(f"{type(self).__name__}.__init__ must take (obs_dim, action_space, ...) first")
        out = {}
        for p in params[2:]:
            value = self._init_arguments.get(p.name, p.default)
            if p.kind is p.VAR_KEYWORD:
                out.update(value)
            elif p.kind is p.VAR_POSITIONAL:
                if value:
                    raise TypeError(f"{type(self).__name__} was made with *{p.name}, which a checkpoint "
                                    "cannot name; take keyword arguments")
            else:
                out[p.name] = value
        return out

    def forward(self, nobs: torch.Tensor) -> tuple[torch.distributions.Distribution, torch.Tensor]:
        """(distribution over the policy's actions, (B,) value in return units)."""
        raise NotImplementedError

    # --- the env's actions
    def env_action(self, action: torch.Tensor, obs: torch.Tensor) -> torch.Tensor:
        """The env's actions (B, env action size) for a batch of the policy's own actions and
        the raw observations they were chosen on. Default: clamped to [-1, 1], then rescaled
        onto the env's box. The rollout calls this once a step: keep it batched."""
        a = action.clamp(-1.0, 1.0)
        if self._unit_box:
            return a
        # In float64, as the agents mapped actions before policies owned the map (same actions).
        return (self._action_low + 0.5 * (a.double() + 1.0) * self._action_span).float()

    # --- observation statistics
    def normalize(self, obs: torch.Tensor) -> torch.Tensor:
        return obs

    def update_obs_stats(self, obs: torch.Tensor) -> None:
        """Fold raw observations of real transitions into the observation statistics."""

    # --- value units: the critic may learn returns on a normalised scale
    def value_targets(self, returns: torch.Tensor) -> torch.Tensor:
        """Returns (or values) in the critic's training units. A policy that overrides this
        also overrides `evaluate_actions` to give its critic's output in those units."""
        return returns

    def update_value_stats(self, returns: torch.Tensor) -> None:
        """Fold a rollout's returns into the return statistics."""

    def value(self, nobs: torch.Tensor) -> torch.Tensor:
        """(B,) value estimate in return units (override to skip the actor)."""
        return self(nobs)[1]

    def action_distribution(self, nobs: torch.Tensor) -> torch.distributions.Distribution:
        """The action distribution alone, what a rollout needs between env steps (override to
        skip the critic)."""
        return self(nobs)[0]

    # --- acting and scoring
    @torch.no_grad()
    def act(self, obs: torch.Tensor, deterministic: bool = True) -> torch.Tensor:
        """The policy's own actions (unclipped) for raw observations: the mean, or a sample."""
        dist = self.action_distribution(self.normalize(obs))
        return dist.mean if deterministic else dist.sample()

    def evaluate_actions(self, nobs: torch.Tensor, actions: torch.Tensor) -> ActionEval:
        dist, value = self(nobs)
        return ActionEval(dist.log_prob(actions).sum(-1), dist.entropy().sum(-1), dist.mean,
                          self.value_targets(value))

    def action_std(self) -> torch.Tensor | None:
        """Per-dimension action std when it is state-independent (logged), else None."""
        return None

    def freeze(self) -> "Policy":
        """No gradients, no statistics updates by an optimiser: a fixed part of another policy
        (a primitive, a decoder) or a teacher. Returns the policy."""
        self.requires_grad_(False)
        return self.eval()

    @property
    def frozen(self) -> bool:
        return not any(p.requires_grad for p in self.parameters())


class ValueCritic:
    """The critic half that ActorCritic, agents.Composer and agents.simpoe.KinematicRefinement
    share: an MLP `critic` reading `critic_input(nobs)` that predicts the value in units of
    `value_norm` (running return statistics; None: return units), and the PPO scoring of
    actions under `action_distribution` with that critic. Listed before `Policy` among a
    policy's bases so that these methods replace Policy's defaults."""

    critic: nn.Module
    value_norm: RunningNorm | None

    def critic_input(self, nobs: torch.Tensor) -> torch.Tensor:
        return nobs

    def critic_output(self, nobs: torch.Tensor) -> torch.Tensor:
        """(B,) the critic's raw output, in training units: what `evaluate_actions` returns
        (going through return units and back would only add rounding)."""
        return self.critic(self.critic_input(nobs)).squeeze(-1)

    def value(self, nobs: torch.Tensor) -> torch.Tensor:
        v = self.critic_output(nobs)
        return self.value_norm.denormalize(v) if self.value_norm is not None else v

    def value_targets(self, returns: torch.Tensor) -> torch.Tensor:
        return self.value_norm(returns) if self.value_norm is not None else returns

    def update_value_stats(self, returns: torch.Tensor) -> None:
        if self.value_norm is not None:
            self.value_norm.update(returns)

    def scored_distribution(self, nobs: torch.Tensor) -> tuple[torch.distributions.Distribution, dict | None]:
        """The action distribution `evaluate_actions` scores, and what the policy computed on
        the way that an agent's loss may reuse (`ActionEval.extras`; None: nothing)."""
        return self.action_distribution(nobs), None

    def evaluate_actions(self, nobs: torch.Tensor, actions: torch.Tensor) -> ActionEval:
        dist, extras = self.scored_distribution(nobs)
        return ActionEval(dist.log_prob(actions).sum(-1), dist.entropy().sum(-1), dist.mean,
                          self.critic_output(nobs), extras)


class ActorCritic(ValueCritic, Policy):
    """Gaussian policy N(mu(s), sigma) with a state-independent sigma over [-1, 1]^n, n the env's
    action size, and a value function: separate MLPs, as PHC trains them, both reading the
    normalised observation. Its actions reach the env clamped and rescaled (`Policy.env_action`).

    The critic predicts the value in units of `value_norm` (running return statistics) when
    `normalize_value` is on; `value` converts back to return units.

    Args (after the spaces): actor_hidden, critic_hidden (MLP hidden sizes; PHC: [1024, 512]),
    activation (relu, elu, silu, tanh or gelu; PHC: SiLU), log_std_init (initial log action std
    in [-1, 1] units; PHC fixes it at -2.9), learn_std (False: fixed at log_std_init),
    obs_clip (normalised observations are clipped to +-obs_clip), normalize_obs (running
    observation normalisation), normalize_value (the critic predicts normalised returns).
    """

    def __init__(self, obs_dim: int, action_space: gym.spaces.Box | int, *, actor_hidden: Sequence[int] = (256, 256),
                 critic_hidden: Sequence[int] = (256, 256), activation: str = "silu",
                 log_std_init: float = -1.0, learn_std: bool = True, obs_clip: float | None = 10.0,
                 normalize_obs: bool = True, normalize_value: bool = True):
        super().__init__(obs_dim, action_space)
        obs_dim, act_dim = self.obs_dim, self.act_dim
        # Module names are checkpoint keys (obs_norm.mean, actor.0.weight ...): keep them.
        self.obs_norm = RunningNorm(obs_dim, clip=obs_clip) if normalize_obs else nn.Identity()
        self.value_norm = RunningNorm((), clip=None) if normalize_value else None
        self.actor = mlp(obs_dim, _sizes("actor_hidden", actor_hidden), act_dim, activation, out_gain=0.01)
        self.critic = mlp(obs_dim, _sizes("critic_hidden", critic_hidden), 1, activation, out_gain=1.0)
        self.log_std = nn.Parameter(torch.full((act_dim,), float(log_std_init)), requires_grad=bool(learn_std))

    def normalize(self, obs: torch.Tensor) -> torch.Tensor:
        return self.obs_norm(obs)

    def update_obs_stats(self, obs: torch.Tensor) -> None:
        if isinstance(self.obs_norm, RunningNorm):
            self.obs_norm.update(obs)

    def distribution(self, nobs: torch.Tensor) -> Normal:
        mu = self.actor(nobs)
        # Validation checks every argument on every call: a tenth of a rollout step's policy time.
        return Normal(mu, self.log_std.exp().expand_as(mu), validate_args=False)

    def forward(self, nobs: torch.Tensor) -> tuple[Normal, torch.Tensor]:
        return self.distribution(nobs), self.value(nobs)

    def action_distribution(self, nobs: torch.Tensor) -> Normal:
        return self.distribution(nobs)

    def action_std(self) -> torch.Tensor:
        return self.log_std.detach().exp()


def _sizes(name: str, hidden) -> list[int]:
    # YAML and the command line give lists; a bare number is a mistake, not one layer.
    if not isinstance(hidden, (list, tuple)) or not all(isinstance(h, int) and not isinstance(h, bool) and h > 0
                                                        for h in hidden):
        raise TypeError(f"{name} must be a list of layer sizes such as [512, 256], got {hidden!r}")
    return list(hidden)
