"""Registered tasks. `gym.make(id)` gives one world; `gym.make_vec(id, num_envs=N)` the native
batched env over N worlds (no subprocesses). `base` holds the task-agnostic core and its task
interface; `reference` the reference-tracking part shared by the imitation-style tasks.
`load_motions` belongs to the motion library (`smpl_envs.motion`); it is named here too, where
it was first."""

from ..motion import load_motions
from .base import HumanoidVecEnv, SingleEnv
from .imitation import ImitationVecEnv, KeypointImitationVecEnv

__all__ = ["HumanoidVecEnv", "SingleEnv", "ImitationVecEnv", "KeypointImitationVecEnv", "load_motions"]
