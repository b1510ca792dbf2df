"""Batched physics: N humanoid worlds behind one object.

`CPUSim` steps MuJoCo worlds on a thread pool. `WarpSim` (optional extra `[gpu]`: MuJoCo Warp)
exposes the same members (`set_state`, `step`, `qpos`, `qvel`, `actuator_force`, `bodies`) as
torch tensors on its device; the task functions in `smpl_envs.features` and `smpl_envs.envs` are
written for either. `WarpSim` and `to_numpy` are imported on first use, so importing this package
never imports warp.
"""

from .cpu import CPUSim

__all__ = ["CPUSim", "WarpSim", "to_numpy"]


def __getattr__(name):
    if name in ("WarpSim", "to_numpy"):
        try:
            from . import warp
        except ImportError as e:
            raise ImportError(f"smpl_envs.sim.{name} needs MuJoCo Warp: pip install 'smpl-envs[gpu]' ({e})") from e
        return getattr(warp, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
