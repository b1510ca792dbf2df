"""Standalone agents for smpl-envs, shaped like Stable-Baselines3.

    from agents import PPO
    model = PPO("SMPL/Imitation-v0", n_envs=16, policy_kwargs={"actor_hidden": [512, 256]}).learn(1_000_000)
    model.save("walk.pt")
    model = agents.load("walk.pt")          # any agent class and any policy, from its checkpoint
    action, _ = model.predict(obs, deterministic=True)

The pieces, for agents and policies built on this machinery: the on-policy base
(`OnPolicyAlgorithm`, its settings `OnPolicyConfig`; PPO, AMP and PULSE are subclasses), settings
dataclasses (`PPOConfig`, `AMPConfig`), policies as plug-ins (`Policy`, the default
`ActorCritic`, PMCP's `Composer` over frozen primitives and `ProgressiveActorCritic` (a
progressive-network column beside a frozen primitive), SimPoE's `KinematicRefinement` (trained by
`SimPoEPPO`), `register_policy`, `load_policy` for a
checkpoint's frozen policy), and rollouts
apart from the update (`RolloutBuffer`, `RolloutCollector`, `RolloutHooks`).
"""
from __future__ import annotations

from pathlib import Path

from .amp import AMP, AMPConfig
from .callbacks import Callback, CallbackList, CheckpointCallback, EvalCallback
from .checkpoint import load_checkpoint
from .composer import Composer
from .logger import Logger
from .latent_policy import LatentActorCritic
from .networks import ActorCritic, Policy
from .on_policy import OnPolicyAlgorithm, OnPolicyConfig
from .policies import PolicyClassError, load_policy, register_policy
from .ppo import PPO, PPOConfig
from .progressive import ProgressiveActorCritic
from .pulse import PULSE, PULSEConfig, PULSEPolicy
from .rollout import RolloutBuffer, RolloutCollector, RolloutHooks
from .simpoe import KinematicRefinement, SimPoEPPO, SimPoEPPOConfig

AGENTS = {"PPO": PPO, "AMP": AMP, "PULSE": PULSE, "SimPoEPPO": SimPoEPPO}


def load(path: str | Path, env=None, **kwargs):
    """Load a checkpoint of any shipped agent class (the class is recorded in the file), with
    its policy made again from the recorded policy class and arguments."""
    name = load_checkpoint(path, "cpu")["class"]
    if name not in AGENTS:
        raise ValueError(f"{path} holds an agent of unknown class {name!r}; known: {sorted(AGENTS)}")
    return AGENTS[name].load(path, env=env, **kwargs)


__all__ = ["PPO", "AMP", "PULSE", "AGENTS", "PULSEConfig", "PULSEPolicy", "LatentActorCritic",
           "load", "Callback", "CallbackList", "CheckpointCallback", "EvalCallback",
           "Logger", "SimPoEPPO", "SimPoEPPOConfig", "KinematicRefinement", "OnPolicyAlgorithm", "OnPolicyConfig", "PPOConfig", "AMPConfig", "Policy", "ActorCritic",
           "PolicyClassError", "register_policy", "Composer", "ProgressiveActorCritic", "load_policy", "RolloutBuffer", "RolloutCollector", "RolloutHooks"]
