"""What a bug report needs: `smpl-envs info` prints the versions, the GL backend and the devices.

Every probe is guarded: a missing optional package or a device that fails to start is reported
as such, never raised, so the command works on every installation it is asked to describe.
"""
from __future__ import annotations

import os
import platform
import sys
from importlib import metadata
from importlib.util import find_spec


def _version(distribution: str) -> str:
    try:
        return metadata.version(distribution)
    except metadata.PackageNotFoundError:
        return "not installed"


def _torch() -> dict[str, str]:
    import torch

    out = {"torch": str(torch.__version__), "torch build": f"CUDA {torch.version.cuda}" if torch.version.cuda else "CPU only"}
    if torch.cuda.is_available():
        names = [torch.cuda.get_device_name(i) for i in range(torch.cuda.device_count())]
        out["torch CUDA devices"] = ", ".join(f"cuda:{i} {n}" for i, n in enumerate(names))
    else:
        out["torch CUDA devices"] = "none"
    return out


def _warp() -> dict[str, str]:
    """MuJoCo Warp and Warp: installed or not, and the devices Warp sees."""
    out = {"mujoco-warp": _version("mujoco-warp"), "warp-lang": _version("warp-lang")}
    if find_spec("warp") is None:
        out["warp devices"] = "none (GPU backend not installed: pip install 'smpl-envs[gpu]')"
        return out
    try:
        import warp as wp

        wp.config.quiet = True  # no start-up banner in the middle of the report
        wp.init()
        out["warp devices"] = ", ".join(str(d) for d in wp.get_devices()) or "none"
    except Exception as e:  # a broken driver or toolkit is a fact for the report, not a crash
        out["warp devices"] = f"error: {type(e).__name__}: {str(e).splitlines()[0] if str(e) else ''}"
    return out


def system_info() -> dict[str, str]:
    import gymnasium
    import mujoco
    import numpy

    import smpl_envs

    gl = os.environ.get("MUJOCO_GL")
    how = "chosen by smpl_envs: no display" if smpl_envs.GL_CHOSEN_HERE else "set in the environment"
    info = {
        "smpl-envs": f"{smpl_envs.__version__} ({os.path.dirname(smpl_envs.__file__)})",
        "python": f"{platform.python_version()} ({sys.executable})",
        "platform": platform.platform(),
        "mujoco": mujoco.__version__,
        "gymnasium": gymnasium.__version__,
        "numpy": numpy.__version__,
    }
    info.update(_torch())
    info["MUJOCO_GL"] = f"{gl} ({how})" if gl else "unset (MuJoCo's default: a display's GLFW)"
    info.update(_warp())
    return info


def format_info(info: dict[str, str]) -> str:
    width = max(map(len, info))
    return "\n".join(f"{key:<{width}}  {value}" for key, value in info.items())


__all__ = ["system_info", "format_info"]
