"""The composer of PHC's progressive multiplicative control policy (PMCP): K frozen primitive
policies and a trainable composer network C(s) >= 0, one weight per primitive, that mixes their
action distributions. Trained with the suite's PPO like any policy (`agents.policies`):

    PPO("SMPL/Imitation-v0", env_kwargs={..., "recovery": {...}}, policy="Composer",
        policy_kwargs={"primitives": [load_policy("tracker"), load_policy("runs/.../recovery")]})

or in a recipe, `agent.policy: {class: Composer, kwargs: {primitives: [{checkpoint: tracker}, ...]}}`.

Composition, per action dimension j (i over the primitives, each a Gaussian N(mu_i, sigma_i)):

* "multiplicative" (PHC's paper, after MCP), the default:
      sigma^j = (sum_i C_i / sigma_i^j)^-1,    mu^j = sigma^j sum_i (C_i / sigma_i^j) mu_i^j
  with sigma_i the primitive's standard deviation, as the paper writes it. (MCP derives the form
  from the weighted product of the Gaussians, which gives it with sigma read as the variance;
  with PHC's one fixed std for every primitive both readings give the same mean, and the same
  sigma whenever the weights sum to 1.) The composite is the action distribution PPO samples,
  scores and differentiates through C; sigma follows the weights.
* "additive" (PHC's code): mu = sum_i C_i mu_i, with the composer's own fixed std
  (`log_std_init`, PHC's -2.9).

C(s) is an MLP over the observation with a non-negative output: "sigmoid" (MCP's, the default:
each weight in (0, 1)), "relu" (PHC's code), "softplus", or "softmax" (weights that sum to 1). Its
last layer starts near zero, so the first composite is the primitives' even mixture.

Why softmax: a sigmoid weight reaches 0 only at a logit of minus infinity, so a sigmoid composer
hands a state to one primitive only as far as its other weights have been driven down. The
sigmoid composer once shipped as `pmcp` kept its tracker at a weight of about 0.6 on a body lying
on the floor beside the recovery primitive's 0.97, so a third of every get-up action was the
tracker's, and got up in 76 % of trials against its recovery primitive's 90 %; trained on with
softmax it got up in 88.5 % (docs/pmcp.md). With softmax a logit gap of 5 gives one primitive
99 %, and with PHC's one std for every primitive the composite std stays the primitives'
(sum C_i = 1).

A critic MLP of the same input as C gives the value (in normalised return units when
`normalize_value`).

Observations: the rollout stores raw observations (`normalize` is the identity), because each
primitive normalises its input with its own frozen statistics; C and the critic read the
observation normalised by the first primitive's statistics (frozen too), the input the
primitives learnt on. Nothing of the composer moves with the data but its weights and return
statistics, so an update scores actions on exactly the input they were chosen on.

Primitives are frozen (`Policy.freeze`): no gradients, not in the optimiser, their normalisers
never updated; they are submodules, so their weights are in the composer's state dict and its
checkpoint holds everything (reloading needs none of the primitives' files). A primitive is any
policy of the suite made for the same observation and action spaces: one whose actions are the
env's (an actor-critic of PPO or AMP, another composer) contributes its Gaussian; any other (a
latent-space policy) contributes its deterministic env action as the mean, with the composer's
own std.
"""
from __future__ import annotations

from typing import Sequence

import gymnasium as gym
import numpy as np
import torch
import torch.nn.functional as F
from torch import nn
from torch.distributions import Normal

from .networks import Policy, ValueCritic, _sizes, mlp
from .normalizer import RunningNorm
from .policies import register_policy

COMPOSITIONS = ("multiplicative", "additive")
WEIGHT_ACTIVATIONS = {"sigmoid": torch.sigmoid, "relu": F.relu, "softplus": F.softplus,
                      "softmax": lambda logits: torch.softmax(logits, dim=-1)}
_TINY = 1e-12  # keeps the composite finite where every weight is 0 (a dead ReLU)


def compose_multiplicative(weights: torch.Tensor, mus: torch.Tensor, stds: torch.Tensor):
    """(mu, sigma) (B, A) of the multiplicative composition (module docstring) of K Gaussians
    `mus`, `stds` (B, K, A) with weights (B, K) >= 0. The mean is computed as a convex mixture
    with coefficients (C_i / sigma_i) / sum_l (C_l / sigma_l), so one-hot weights give that
    primitive's mean exactly."""
    terms = weights[..., None] / stds              # C_i / sigma_i^j
    total = terms.sum(1).clamp(min=_TINY)         # sum_i C_i / sigma_i^j
    mu = ((terms / total[:, None]) * mus).sum(1)  # = sigma^j sum_i (C_i / sigma_i^j) mu_i^j
    return mu, 1.0 / total


def compose_additive(weights: torch.Tensor, mus: torch.Tensor) -> torch.Tensor:
    """(B, A) mean sum_i C_i mu_i of K means `mus` (B, K, A) with weights (B, K)."""
    return (weights[..., None] * mus).sum(1)


@register_policy
class Composer(ValueCritic, Policy):
    """PMCP's composer over frozen `primitives` (module docstring).

    Args (after the spaces): primitives (a list of policies for the env's spaces; a recipe
    names them as {checkpoint: NAME_OR_PATH}), composition ("multiplicative" or "additive"),
    actor_hidden (the composer network C's hidden sizes, named as the actor-critic's so profiles
    rescale both alike; PHC: [1024, 512]), critic_hidden, activation, weight_activation
    ("sigmoid", "relu", "softplus" or "softmax"), log_std_init (the additive form's fixed log std, and the
    std of a primitive that is not Gaussian over the env's actions), normalize_value.
    """

    def __init__(self, obs_dim: int, action_space: gym.spaces.Box | int, *, primitives: Sequence[Policy],
                 composition: str = "multiplicative", actor_hidden: Sequence[int] = (512, 256),
                 critic_hidden: Sequence[int] = (512, 256), activation: str = "silu",
                 weight_activation: str = "sigmoid", log_std_init: float = -2.9, normalize_value: bool = True):
        super().__init__(obs_dim, action_space)
        if composition not in COMPOSITIONS:
            raise ValueError(f"composition must be one of {COMPOSITIONS}, got {composition!r}")
        if weight_activation not in WEIGHT_ACTIVATIONS:
            raise ValueError(f"weight_activation must be one of {sorted(WEIGHT_ACTIVATIONS)}, got {weight_activation!r}")
        primitives = list(primitives) if isinstance(primitives, (list, tuple, nn.ModuleList)) else None
        if not primitives:
            raise ValueError("Composer needs a non-empty list of primitive policies (primitives=[...])")
        for i, p in enumerate(primitives):
            if not isinstance(p, Policy):
                raise TypeError(f"primitives[{i}] is {type(p).__name__}, not a Policy (load one with agents.load_policy)")
            if p.obs_dim != self.obs_dim or p.action_space.shape != self.action_space.shape or not (
                    np.array_equal(p.action_space.low, self.action_space.low)
                    and np.array_equal(p.action_space.high, self.action_space.high)):
                raise ValueError(f"primitives[{i}] is for obs {p.obs_dim} / action {p.action_space.shape[0]} features, "
                                 f"the composer's env has {self.obs_dim} / {self.act_dim}")
        self.composition, self.weight_activation = composition, weight_activation
        self.primitives = nn.ModuleList([p.freeze() for p in primitives])
        k = len(primitives)
        self.weight_net = mlp(self.obs_dim, _sizes("actor_hidden", actor_hidden), k, activation, out_gain=0.01)
        self.critic = mlp(self.obs_dim, _sizes("critic_hidden", critic_hidden), 1, activation, out_gain=1.0)
        self.value_norm = RunningNorm((), clip=None) if normalize_value else None
        # Fixed, hence a buffer: the additive form's std and a non-Gaussian primitive's.
        self.register_buffer("log_std", torch.full((self.act_dim,), float(log_std_init)))
        self._gaussian = [p.act_dim == self.act_dim and type(p).env_action is Policy.env_action for p in primitives]

    @property
    def num_primitives(self) -> int:
        return len(self.primitives)

    # --- what the primitives and C see
    def _input(self, obs: torch.Tensor) -> torch.Tensor:
        return self.primitives[0].normalize(obs)

    def weights(self, obs: torch.Tensor) -> torch.Tensor:
        """(B, K) composer weights C(s) >= 0 for raw observations."""
        return WEIGHT_ACTIVATIONS[self.weight_activation](self.weight_net(self._input(obs)))

    @torch.no_grad()
    def primitive_gaussians(self, obs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(mus, stds) (B, K, A): each primitive's action distribution on raw observations."""
        mus, stds = [], []
        for p, gaussian in zip(self.primitives, self._gaussian):
            if gaussian:
                d = p.action_distribution(p.normalize(obs))
                mus.append(d.mean)
                stds.append(d.stddev.expand_as(d.mean))
            else:
                mus.append(p.env_action(p.act(obs), obs).to(obs.dtype))
                stds.append(self.log_std.exp().expand(len(obs), -1))
        return torch.stack(mus, 1), torch.stack(stds, 1)

    def compose(self, weights: torch.Tensor, mus: torch.Tensor, stds: torch.Tensor) -> Normal:
        """The composite Gaussian of primitives (`mus`, `stds`) under `weights`."""
        if self.composition == "multiplicative":
            mu, sigma = compose_multiplicative(weights, mus, stds)
        else:
            mu = compose_additive(weights, mus)
            sigma = self.log_std.exp().expand_as(mu)
        return Normal(mu, sigma, validate_args=False)

    # --- the Policy interface (`nobs` is the raw observation here: `normalize` is the identity)
    def action_distribution(self, nobs: torch.Tensor) -> Normal:
        return self.compose(self.weights(nobs), *self.primitive_gaussians(nobs))

    def forward(self, nobs: torch.Tensor) -> tuple[Normal, torch.Tensor]:
        return self.action_distribution(nobs), self.value(nobs)

    def critic_input(self, nobs: torch.Tensor) -> torch.Tensor:
        return self._input(nobs)

    def action_std(self) -> torch.Tensor | None:
        return self.log_std.exp() if self.composition == "additive" else None


__all__ = ["Composer", "compose_multiplicative", "compose_additive", "COMPOSITIONS", "WEIGHT_ACTIVATIONS"]
