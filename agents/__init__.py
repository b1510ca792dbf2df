"""Standalone agents for smpl-envs, shaped like Stable-Baselines3.

    from agents import PPO
    model = PPO("SMPL/Imitation-v0", n_envs=16).learn(1_000_000)
    model.save("walk.pt")
    model = agents.load("walk.pt")          # any agent class, from its checkpoint
    action, _ = model.predict(obs, deterministic=True)

The pieces, for agents built on this machinery: settings dataclasses (`PPOConfig`,
`AMPConfig`), the policy (`networks.Policy`, `networks.ActorCritic`), and rollouts apart from the
update (`rollout.RolloutBuffer`, `rollout.RolloutCollector`, `rollout.RolloutHooks`).
"""
from __future__ import annotations

from pathlib import Path

from .amp import AMP, AMPConfig
from .callbacks import Callback, CallbackList, CheckpointCallback, EvalCallback
from .checkpoint import load_checkpoint
from .logger import Logger
from .networks import ActorCritic, Policy
from .ppo import PPO, PPOConfig
from .rollout import RolloutBuffer, RolloutCollector, RolloutHooks

AGENTS = {"PPO": PPO, "AMP": AMP}


def load(path: str | Path, env=None, **kwargs):
    """Load a checkpoint of any shipped agent class (the class is recorded in the file)."""
    name = load_checkpoint(path, "cpu")["class"]
    if name not in AGENTS:
        raise ValueError(f"{path} holds an agent of unknown class {name!r}; known: {sorted(AGENTS)}")
    return AGENTS[name].load(path, env=env, **kwargs)


__all__ = ["PPO", "AMP", "AGENTS", "load", "Callback", "CallbackList", "CheckpointCallback", "EvalCallback",
           "Logger", "PPOConfig", "AMPConfig", "Policy", "ActorCritic", "RolloutBuffer", "RolloutCollector",
           "RolloutHooks"]
