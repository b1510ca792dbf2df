"""A task policy that acts in a PULSE latent space: PPO's (or AMP's) actor-critic whose actions
are latent actions a in R^32, mapped to the env's actions by a frozen PULSE prior and decoder,
D(s_p, mu_prior(s_p) + a) (`smpl_envs.latent.LatentDecoder`, the same map as
`smpl_envs.wrappers.LatentAction`).

A recipe names it with the PULSE checkpoint as an argument,

    agent:
      policy:
        class: LatentActorCritic
        kwargs: {pulse: {checkpoint: pulse}, log_std_init: -1.0}

and its checkpoints hold the frozen PULSE policy (as a nested policy record and its weights), so
`eval` and `record` need nothing else. PULSE's downstream settings (REFERENCE.md section 8):
a fixed action std exp(-1) = 0.37 (exp(-1.5) = 0.22 for VR tracking), no clipping or scaling of
a, a bounds loss of weight 10 on |mu| beyond 1 (PPO's bounds_loss_limit), learning rate 2e-5.
"""
from __future__ import annotations

from typing import Sequence

import gymnasium as gym
import numpy as np
import torch

from .networks import ActorCritic, Policy, action_box
from .policies import register_policy


@register_policy
class LatentActorCritic(ActorCritic):
    """ActorCritic over the task's observation whose actions (act_dim = the latent size) reach
    the env through `pulse.latent_decoder`, frozen. `pulse`: a PULSE policy (or any policy with
    a `latent_decoder`), usually a checkpoint reference; the rest as ActorCritic, with PULSE's
    fixed std as the default."""

    def __init__(self, obs_dim: int, action_space: gym.spaces.Box | int, *, pulse: Policy,
                 actor_hidden: Sequence[int] = (256, 256), critic_hidden: Sequence[int] = (256, 256),
                 activation: str = "silu", log_std_init: float = -1.0, learn_std: bool = False,
                 obs_clip: float | None = 5.0, normalize_obs: bool = True, normalize_value: bool = True):
        decoder = getattr(pulse, "latent_decoder", None)
        if not isinstance(pulse, Policy) or decoder is None:
            raise TypeError(f"pulse must be a PULSE policy (with a latent_decoder), such as {{checkpoint: pulse}}; "
                            f"got {type(pulse).__name__}")
        super().__init__(obs_dim, decoder.latent_dim, actor_hidden=actor_hidden, critic_hidden=critic_hidden,
                         activation=activation, log_std_init=log_std_init, learn_std=learn_std, obs_clip=obs_clip,
                         normalize_obs=normalize_obs, normalize_value=normalize_value)
        # Made for a latent box so the actor has latent_dim outputs; the env's box is the one the
        # agent checks its env against, and the decoder's to map onto.
        box = action_box(action_space)
        if box.shape != (decoder.action_dim,) or not (np.all(box.low == -1) and np.all(box.high == 1)):
            raise ValueError(f"the PULSE decoder acts in [-1, 1]^{decoder.action_dim}; the env's actions are {box}")
        self.action_space = box
        self.pulse = pulse.freeze()  # a submodule: its weights are in this policy's state dict

    @property
    def latent_decoder(self):
        return self.pulse.latent_decoder

    def env_action(self, action: torch.Tensor, obs: torch.Tensor) -> torch.Tensor:
        return self.pulse.latent_decoder(obs, action)


__all__ = ["LatentActorCritic"]
