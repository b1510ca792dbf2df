"""Actor and critic MLPs: separate networks, as PHC trains them, sharing one observation normaliser."""
from __future__ import annotations

from typing import Sequence

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


class ActorCritic(nn.Module):
    """Gaussian policy N(mu(s), sigma) with a state-independent sigma, and a value function.

    Both networks read the normalised observation. The critic predicts the value in units of
    `value_norm` (running return statistics) when `normalize_value` is on.
    """

    def __init__(self, obs_dim: int, act_dim: int, *, actor_hidden: Sequence[int] = (256, 256),
                 critic_hidden: Sequence[int] = (256, 256), activation: str = "silu",
                 log_std_init: float = -1.0, learn_std: bool = True, obs_clip: float | None = 10.0,
                 normalize_obs: bool = True, normalize_value: bool = True):
        super().__init__()
        self.obs_norm = RunningNorm(obs_dim, clip=obs_clip) if normalize_obs else nn.Identity()
        self.value_norm = RunningNorm((), clip=None) if normalize_value else None
        self.actor = mlp(obs_dim, actor_hidden, act_dim, activation, out_gain=0.01)
        self.critic = mlp(obs_dim, critic_hidden, 1, activation, out_gain=1.0)
        self.log_std = nn.Parameter(torch.full((act_dim,), float(log_std_init)), requires_grad=learn_std)

    def normalize(self, obs: torch.Tensor) -> torch.Tensor:
        return self.obs_norm(obs)

    def dist(self, nobs: torch.Tensor) -> Normal:
        mu = self.actor(nobs)
        return Normal(mu, self.log_std.exp().expand_as(mu))

    def value(self, nobs: torch.Tensor) -> torch.Tensor:
        """Value in return units (denormalised)."""
        v = self.critic(nobs).squeeze(-1)
        return self.value_norm.denormalize(v) if self.value_norm is not None else v

    @torch.no_grad()
    def act(self, obs: torch.Tensor, deterministic: bool = True) -> torch.Tensor:
        d = self.dist(self.normalize(obs))
        return d.mean if deterministic else d.sample()

