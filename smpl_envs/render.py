"""Rendering: frames from MuJoCo's offscreen renderer, reference markers, mp4 and PNG strips.

Videos are streamed to disk frame by frame through imageio's ffmpeg writer, so recording a long
rollout never holds the episode in memory.
"""

from __future__ import annotations

from pathlib import Path
from typing import Iterable

import mujoco
import numpy as np

MARKER_RGBA = np.array([0.9, 0.1, 0.1, 0.8], dtype=np.float32)
MARKER_RADIUS = 0.03


class FrameRenderer:
    """RGB frames of a humanoid model from its tracking camera, optionally with red markers at
    reference body positions."""

    def __init__(self, model: mujoco.MjModel, width: int = 640, height: int = 480, camera: str = "track"):
        self.renderer = mujoco.Renderer(model, height, width)
        self.camera = camera

    def render(self, data: mujoco.MjData, markers: np.ndarray | None = None) -> np.ndarray:
        self.renderer.update_scene(data, camera=self.camera)
        if markers is not None:
            scene = self.renderer.scene
            for p in np.asarray(markers, float).reshape(-1, 3):
                if scene.ngeom >= scene.maxgeom:
                    break
                mujoco.mjv_initGeom(scene.geoms[scene.ngeom], mujoco.mjtGeom.mjGEOM_SPHERE,
                                    np.full(3, MARKER_RADIUS), p, np.eye(3).ravel(), MARKER_RGBA)
                scene.ngeom += 1
        return self.renderer.render().copy()

    def close(self) -> None:
        self.renderer.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def write_video(path: str | Path, frames: Iterable[np.ndarray], fps: float = 30.0) -> int:
    """Stream frames to an H.264 mp4; returns the number of frames written."""
    import imageio.v2 as imageio

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    n = 0
    with imageio.get_writer(path, fps=fps, codec="libx264", quality=7, macro_block_size=8) as writer:
        for frame in frames:
            writer.append_data(frame)
            n += 1
    return n


def write_strip(path: str | Path, frames: list[np.ndarray], columns: int | None = None) -> np.ndarray:
    """Tile frames left to right (and in rows of `columns`) into one PNG; returns the image."""
    import imageio.v3 as iio

    columns = columns or len(frames)
    rows = [np.concatenate(frames[i:i + columns], axis=1) for i in range(0, len(frames), columns)]
    if len(rows) > 1 and rows[-1].shape != rows[0].shape:
        pad = np.zeros_like(rows[0])
        pad[:, : rows[-1].shape[1]] = rows[-1]
        rows[-1] = pad
    image = np.concatenate(rows, axis=0)
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    iio.imwrite(path, image)
    return image
