"""A progressive-network column (Rusu et al. 2016, "Progressive Neural Networks"): a new
actor-critic beside a frozen previous one, whose hidden layers also read the previous column's
hidden features through trainable lateral connections. PHC names this as the alternative to
starting each hard-clip primitive from a copy of the one before (`agents.warm_start`, the
pipeline's default); `smpl-envs pmcp` builds it with `primitive.lateral: true`, and a recipe
names it as

    agent:
      policy:
        class: ProgressiveActorCritic
        kwargs: {previous: {checkpoint: tracker}}

The column, for hidden layers l = 1 .. L of the previous column's actor (h'_l its features and
mu' its action mean, frozen) and of the new one (h_l, trainable):

    h_1 = act(W_1 x),   h_l = act(W_l h_{l-1} + U_l h'_{l-1}),   mu = mu' + W_out h_L + U_out h'_L

What it starts as, and why: the lateral adapters U_l and the new output layers W_out, U_out start
at zero, so at step 0 the column acts exactly as the previous primitive does (mu = mu') and PPO
starts from a policy that already tracks most clips, as weight copying does; what the new column
learns is added to that. (For a plain previous column, mu' is its output layer on h'_L, so the
output is Rusu et al.'s with U_out starting at that layer; the explicit mu' term keeps "starts as
the previous column" exact down a chain of columns too.) The critic starts as a copy of the
previous column's critic (trainable; the successor has the same reward), the action std as the
previous one's.

The input: the previous column's normalised observation (its frozen statistics), the input every
column then shares, so the lateral features are the ones the previous column learnt on. The new
column keeps no observation statistics of its own. A previous column that is itself progressive
brings its whole chain (each column laterally fed by the one before), frozen, inside its record:
a checkpoint of the last column holds every column's weights.
"""
from __future__ import annotations

from typing import Sequence

import gymnasium as gym
import torch
from torch import nn
from torch.distributions import Normal

from .networks import ActorCritic, Policy, _sizes
from .policies import register_policy


def _linear_layers(actor: nn.Sequential) -> tuple[list[nn.Linear], list[nn.Module]]:
    """(the Linear layers, the activation after each hidden one) of an `mlp` actor."""
    layers = list(actor)
    return layers[0::2], layers[1::2]


def column_features(policy: ActorCritic, nobs: torch.Tensor) -> tuple[list[torch.Tensor], torch.Tensor]:
    """(hidden features after each activation, action mean) of an actor-critic's actor."""
    if isinstance(policy, ProgressiveActorCritic):
        return policy.features(nobs)
    linears, acts = _linear_layers(policy.actor)
    hidden, x = [], nobs
    for lin, act in zip(linears[:-1], acts):
        x = act(lin(x))
        hidden.append(x)
    return hidden, linears[-1](x)


def made_with(policy: ActorCritic) -> dict:
    """The activation and learn_std an actor-critic was made with (a column's resolved ones)."""
    if isinstance(policy, ProgressiveActorCritic):
        return policy._made_with
    kwargs = policy.init_kwargs
    return {"activation": kwargs["activation"], "learn_std": kwargs["learn_std"]}


@register_policy
class ProgressiveActorCritic(ActorCritic):
    """A progressive column beside the frozen actor-critic `previous` (module docstring).

    Args (after the spaces): previous (an ActorCritic, or another ProgressiveActorCritic, for the
    same spaces; a recipe names it as {checkpoint: NAME_OR_PATH}); actor_hidden (the new column's
    hidden sizes, one per hidden layer of the previous actor), critic_hidden, activation,
    log_std_init, learn_std, normalize_value: None takes the previous column's.
    """

    def __init__(self, obs_dim: int, action_space: gym.spaces.Box | int, *, previous: Policy,
                 actor_hidden: Sequence[int] | None = None, critic_hidden: Sequence[int] | None = None,
                 activation: str | None = None, log_std_init: float | None = None, learn_std: bool | None = None,
                 normalize_value: bool | None = None):
        if not isinstance(previous, ActorCritic):
            raise TypeError(f"previous must be an actor-critic (a checkpoint of PPO or AMP on the same task, or "
                            f"another ProgressiveActorCritic), got {type(previous).__name__}")
        theirs = made_with(previous)
        prev_linears, _ = _linear_layers(previous.actor)
        prev_hidden = [lin.out_features for lin in prev_linears[:-1]]
        actor_hidden = prev_hidden if actor_hidden is None else _sizes("actor_hidden", actor_hidden)
        if len(actor_hidden) != len(prev_hidden):
            raise ValueError(f"actor_hidden {list(actor_hidden)} has {len(actor_hidden)} hidden layers, the previous "
                             f"column {prev_hidden} has {len(prev_hidden)}; a lateral connection joins layers one to one")
        critic_hidden = [lin.out_features for lin in _linear_layers(previous.critic)[0][:-1]] \
            if critic_hidden is None else critic_hidden
        pick = lambda given, key: theirs[key] if given is None else given  # noqa: E731
        self_made = {"activation": pick(activation, "activation"), "learn_std": bool(pick(learn_std, "learn_std"))}
        super().__init__(obs_dim, action_space, actor_hidden=actor_hidden, critic_hidden=critic_hidden,
                         log_std_init=float(previous.log_std[0]) if log_std_init is None else log_std_init,
                         normalize_obs=False,
                         normalize_value=previous.value_norm is not None if normalize_value is None else normalize_value,
                         **self_made)
        self._made_with = self_made
        if previous.obs_dim != self.obs_dim or previous.act_dim != self.act_dim:
            raise ValueError(f"previous is for obs {previous.obs_dim} / action {previous.act_dim} features, this "
                             f"column's env has {self.obs_dim} / {self.act_dim}")
        self.previous = previous.freeze()  # a submodule: its weights are in this policy's state dict
        # One adapter into each hidden layer after the first, and one into the output.
        self.lateral = nn.ModuleList(
            [nn.Linear(a, b) for a, b in zip(prev_hidden[:-1], actor_hidden[1:])] + [nn.Linear(prev_hidden[-1],
                                                                                                 self.act_dim)])
        with torch.no_grad():
            for layer in [*self.lateral, _linear_layers(self.actor)[0][-1]]:
                layer.weight.zero_()
                layer.bias.zero_()
            if log_std_init is None:
                self.log_std.copy_(previous.log_std)
            if [m.weight.shape for m in self.critic if isinstance(m, nn.Linear)] == \
                    [m.weight.shape for m in previous.critic if isinstance(m, nn.Linear)]:
                self.critic.load_state_dict(previous.critic.state_dict())
            if self.value_norm is not None and previous.value_norm is not None:
                self.value_norm.load_state_dict(previous.value_norm.state_dict())

    @property
    def columns(self) -> int:
        """How many columns the chain holds, this one included."""
        prev = self.previous
        return 1 + (prev.columns if isinstance(prev, ProgressiveActorCritic) else 1)

    def normalize(self, obs: torch.Tensor) -> torch.Tensor:
        return self.previous.normalize(obs)

    def update_obs_stats(self, obs: torch.Tensor) -> None:
        pass  # the shared input's statistics are the previous column's, frozen

    def features(self, nobs: torch.Tensor) -> tuple[list[torch.Tensor], torch.Tensor]:
        """(this column's hidden features, its action mean) for the shared normalised input."""
        prev_hidden, prev_mu = column_features(self.previous, nobs)
        linears, acts = _linear_layers(self.actor)
        hidden, x = [], nobs
        for i, (lin, act) in enumerate(zip(linears[:-1], acts)):
            z = lin(x)
            if i > 0:
                z = z + self.lateral[i - 1](prev_hidden[i - 1])
            x = act(z)
            hidden.append(x)
        return hidden, prev_mu + linears[-1](x) + self.lateral[-1](prev_hidden[-1])

    def distribution(self, nobs: torch.Tensor) -> Normal:
        mu = self.features(nobs)[1]
        return Normal(mu, self.log_std.exp().expand_as(mu), validate_args=False)


__all__ = ["ProgressiveActorCritic", "column_features"]
