"""Batched physics: N humanoid worlds behind one object.

`CPUSim` steps MuJoCo worlds on a thread pool. A GPU backend (MuJoCo Warp) would expose the same
members (`set_state`, `step`, `qpos`, `qvel`, `actuator_force`, `bodies`), returning arrays of its
own kind; the task functions in `smpl_envs.features` and `smpl_envs.envs` are written for either.
"""

from .cpu import CPUSim

__all__ = ["CPUSim"]
