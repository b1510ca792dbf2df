"""The policy PPO trains: an interface (`Policy`) and PHC's actor-critic (`ActorCritic`).

PPO is handed a `Policy` (`PPO(env, policy=...)`) or builds an `ActorCritic` from its
hyperparameters. A policy maps observations to a Gaussian over actions in [-1, 1]^act_dim (the
agent maps those onto the env's action box) and to a value estimate.

The policy owns the observation normaliser (and the critic's return normaliser): they are part of
the function from observation to action, so a saved policy acts on raw observations without
the algorithm, and the normalisers travel inside `state_dict`. The algorithm decides when their
statistics move (`update_obs_stats` on the valid steps of a rollout, `update_value_stats` on a
rollout's returns), because only it knows which steps are real transitions.

Observations in a rollout are stored normalised with the statistics the rollout acted under
(`normalize`), so an update scores the actions on exactly the input the actor acted on. Hence
the split: `act` takes raw observations; `forward`, `value` and `evaluate_actions` take
normalised ones (`nobs`).
"""
from __future__ import annotations

from typing import NamedTuple, Sequence

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


class ActionEval(NamedTuple):
    """What a PPO update needs of a policy on a minibatch of stored (observation, action) pairs."""

    log_prob: torch.Tensor  # (B,) log-density of the stored actions under the current policy
    entropy: torch.Tensor   # (B,) entropy of the current action distribution
    mean: torch.Tensor      # (B, act_dim) action mean, for the bounds loss
    value: torch.Tensor     # (B,) critic output in its training units (`Policy.value_targets`)


class Policy(nn.Module):
    """What PPO (and AMP) need from a policy. Subclasses implement `forward`; the rest has
    defaults for a policy without normalisers.

    Attributes `obs_dim` and `act_dim` give the sizes it was built for.
    """

    obs_dim: int
    act_dim: int

    def forward(self, nobs: torch.Tensor) -> tuple[torch.distributions.Distribution, torch.Tensor]:
        """(action distribution over [-1, 1]^act_dim, (B,) value in return units)."""
        raise NotImplementedError

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
        """Actions in [-1, 1]-space (unclipped) for raw observations: the mean, or a sample."""
        dist, _ = self(self.normalize(obs))
        return dist.mean if deterministic else dist.sample()

    def evaluate_actions(self, nobs: torch.Tensor, actions: torch.Tensor) -> ActionEval:
        dist, value = self(nobs)
        return ActionEval(dist.log_prob(actions).sum(-1), dist.entropy().sum(-1), dist.mean,
                          self.value_targets(value))

    def action_std(self) -> torch.Tensor | None:
        """Per-dimension action std when it is state-independent (logged), else None."""
        return None


class ActorCritic(Policy):
    """Gaussian policy N(mu(s), sigma) with a state-independent sigma, and a value function:
    separate MLPs, as PHC trains them, both reading the normalised observation.

    The critic predicts the value in units of `value_norm` (running return statistics) when
    `normalize_value` is on; `value` converts back to return units.
    """

    def __init__(self, obs_dim: int, act_dim: int, *, actor_hidden: Sequence[int] = (256, 256),
                 critic_hidden: Sequence[int] = (256, 256), activation: str = "silu",
                 log_std_init: float = -1.0, learn_std: bool = True, obs_clip: float | None = 10.0,
                 normalize_obs: bool = True, normalize_value: bool = True):
        super().__init__()
        self.obs_dim, self.act_dim = int(obs_dim), int(act_dim)
        # Module names are checkpoint keys (obs_norm.mean, actor.0.weight ...): keep them.
        self.obs_norm = RunningNorm(obs_dim, clip=obs_clip) if normalize_obs else nn.Identity()
        self.value_norm = RunningNorm((), clip=None) if normalize_value else None
        self.actor = mlp(obs_dim, actor_hidden, act_dim, activation, out_gain=0.01)
        self.critic = mlp(obs_dim, critic_hidden, 1, activation, out_gain=1.0)
        self.log_std = nn.Parameter(torch.full((act_dim,), float(log_std_init)), requires_grad=learn_std)

    def normalize(self, obs: torch.Tensor) -> torch.Tensor:
        return self.obs_norm(obs)

    def update_obs_stats(self, obs: torch.Tensor) -> None:
        if isinstance(self.obs_norm, RunningNorm):
            self.obs_norm.update(obs)

    def value_targets(self, returns: torch.Tensor) -> torch.Tensor:
        return self.value_norm(returns) if self.value_norm is not None else returns

    def update_value_stats(self, returns: torch.Tensor) -> None:
        if self.value_norm is not None:
            self.value_norm.update(returns)

    def distribution(self, nobs: torch.Tensor) -> Normal:
        mu = self.actor(nobs)
        # Validation checks every argument on every call: a tenth of a rollout step's policy time.
        return Normal(mu, self.log_std.exp().expand_as(mu), validate_args=False)

    def forward(self, nobs: torch.Tensor) -> tuple[Normal, torch.Tensor]:
        return self.distribution(nobs), self.value(nobs)

    def action_distribution(self, nobs: torch.Tensor) -> Normal:
        return self.distribution(nobs)

    def value(self, nobs: torch.Tensor) -> torch.Tensor:
        v = self.critic(nobs).squeeze(-1)
        return self.value_norm.denormalize(v) if self.value_norm is not None else v

    def evaluate_actions(self, nobs: torch.Tensor, actions: torch.Tensor) -> ActionEval:
        # The critic's raw output is already in training units; going through return units and
        # back would only add rounding.
        dist = self.distribution(nobs)
        return ActionEval(dist.log_prob(actions).sum(-1), dist.entropy().sum(-1), dist.mean,
                          self.critic(nobs).squeeze(-1))

    @torch.no_grad()
    def act(self, obs: torch.Tensor, deterministic: bool = True) -> torch.Tensor:
        d = self.distribution(self.normalize(obs))
        return d.mean if deterministic else d.sample()

    def action_std(self) -> torch.Tensor:
        return self.log_std.detach().exp()
