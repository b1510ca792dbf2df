"""Registered tasks. `gym.make(id)` gives one world; `gym.make_vec(id, num_envs=N)` the native
batched env over N worlds (no subprocesses)."""

from .base import HumanoidVecEnv, SingleEnv, load_motions
from .imitation import (ImitationEnv, ImitationVecEnv, KeypointImitationEnv,
                        KeypointImitationVecEnv)

__all__ = ["HumanoidVecEnv", "SingleEnv", "ImitationEnv", "ImitationVecEnv",
           "KeypointImitationEnv", "KeypointImitationVecEnv", "load_motions"]
