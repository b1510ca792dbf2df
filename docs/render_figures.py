"""Render the README's pictures: the humanoid at rest and a strip of shipped clips.

    python docs/render_figures.py
"""

from pathlib import Path

import smpl_envs  # noqa: F401  (headless GL before mujoco)
import mujoco

from smpl_envs.humanoid import build_humanoid
from smpl_envs.motion import load_motion
from smpl_envs.render import FrameRenderer, write_strip

HERE = Path(__file__).parent


def main() -> None:
    model = build_humanoid()
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    with FrameRenderer(model, 800, 600) as r:
        write_strip(HERE / "humanoid.png", [r.render(data)])
        tiles = []
        for clip, frac in [("walk", 0.4), ("run", 0.5), ("jump", 0.45), ("kick", 0.5),
                           ("gesture", 0.3), ("crouch", 0.5)]:
            m = load_motion(clip)
            data.qpos[:] = m.qpos[int(frac * (m.num_frames - 1))]
            mujoco.mj_forward(model, data)
            tiles.append(r.render(data)[60:560, 170:630])
    write_strip(HERE / "clips.png", tiles, columns=6)


if __name__ == "__main__":
    main()
