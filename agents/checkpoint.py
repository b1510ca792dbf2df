"""Checkpoint files: one self-contained torch file per save, written atomically."""
from __future__ import annotations

import os
import platform
import tempfile
from pathlib import Path
from typing import Any

import torch

FORMAT = "smpl-envs-agent/1"


def versions() -> dict[str, str]:
    import gymnasium
    import numpy

    out = {"python": platform.python_version(), "torch": str(torch.__version__),
           "numpy": numpy.__version__, "gymnasium": gymnasium.__version__}
    try:
        from importlib.metadata import version

        out["smpl_envs"] = version("smpl-envs")
    except Exception:  # running from a source tree without installation
        out["smpl_envs"] = "unknown"
    return out


def save_checkpoint(payload: dict[str, Any], path: str | os.PathLike) -> Path:
    """Write `payload` to `path` so that a crash mid-write never leaves a truncated file:
    the bytes go to a temporary file in the same directory, are fsynced, then renamed over."""
    path = Path(path)
    if path.suffix != ".pt":
        path = path.with_name(path.name + ".pt")
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            torch.save({"format": FORMAT, "versions": versions(), **payload}, f)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def load_checkpoint(path: str | os.PathLike, device: str | torch.device = "cpu") -> dict[str, Any]:
    path = Path(path)
    if not path.exists() and path.with_name(path.name + ".pt").exists():
        path = path.with_name(path.name + ".pt")
    if not path.is_file():
        raise FileNotFoundError(f"no checkpoint at {path}")
    try:
        # Checkpoints hold only tensors and plain Python data, so the safe loader suffices.
        ckpt = torch.load(path, map_location=device, weights_only=True)
    except Exception as e:
        raise ValueError(f"{path} is not a readable smpl-envs checkpoint: {e}") from e
    if not isinstance(ckpt, dict) or ckpt.get("format") != FORMAT:
        raise ValueError(f"{path} is not a smpl-envs agent checkpoint (format {FORMAT!r})")
    return ckpt
