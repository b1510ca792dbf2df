"""Render the get-up family's frame strip: one clip from the front and one from the back, every
0.75 s, as the reference the tracker would follow (kinematic, not simulated).

    python docs/render_getup_motion.py          # writes docs/getup_motion.png
"""

from pathlib import Path

import smpl_envs  # noqa: F401  (headless GL before mujoco)
import mujoco
import numpy as np
from PIL import Image, ImageDraw

from smpl_envs.humanoid import build_humanoid
from smpl_envs.motion.getup import getup
from smpl_envs.motion.motion import Motion
from smpl_envs.render import FrameRenderer, write_strip

HERE = Path(__file__).parent


def main(out: Path = HERE / "getup_motion.png", every: float = 0.75, size=(220, 220)) -> None:
    model = build_humanoid()
    data = mujoco.MjData(model)
    rows = []
    with FrameRenderer(model, 440, 440) as r:
        for start in ("front", "back"):
            m = Motion.from_raw(getup(start, side="L", roll="L"))
            row = []
            for i in range(0, m.num_frames, int(round(every * m.fps))):
                data.qpos[:] = m.qpos[i]
                mujoco.mj_forward(model, data)
                img = Image.fromarray(r.render(data)).resize(size)
                ImageDraw.Draw(img).text((6, 6), f"{start} {i / m.fps:.2f} s", fill=(0, 0, 0))
                row.append(np.asarray(img))
            rows.append(row)
    columns = max(len(row) for row in rows)
    tiles = [t for row in rows for t in row + [np.full_like(row[0], 255)] * (columns - len(row))]
    write_strip(out, tiles, columns=columns)
    print(out)


if __name__ == "__main__":
    main()
