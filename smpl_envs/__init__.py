"""smpl-envs: physics-based SMPL humanoid control on MuJoCo."""

import os as _os

# MuJoCo picks its OpenGL backend when it is first imported. On a server (no display) choose the
# headless EGL backend unless the user chose one, so rendering just works; import smpl_envs before
# mujoco for this to take effect.
if "MUJOCO_GL" not in _os.environ and not (_os.environ.get("DISPLAY") or _os.environ.get("WAYLAND_DISPLAY")):
    _os.environ["MUJOCO_GL"] = "egl"

__version__ = "0.1.0"
