"""Render the corpus figure: one tile per family of the procedural corpus, each showing
(the pose of its first training clip farthest from its standing start).

    python docs/render_corpus.py          # writes docs/corpus.png
"""

from pathlib import Path

import smpl_envs  # noqa: F401  (headless GL before mujoco)
import mujoco
import numpy as np
from PIL import Image, ImageDraw

from smpl_envs.humanoid import build_humanoid
from smpl_envs.motion import corpus
from smpl_envs.motion.motion import Motion
from smpl_envs.render import FrameRenderer, write_strip

HERE = Path(__file__).parent


def main(out: Path = HERE / "corpus.png", size=(300, 360)) -> None:
    model = build_humanoid()
    data = mujoco.MjData(model)
    tiles = []
    with FrameRenderer(model, 480, 576) as r:
        for name in corpus.FAMILIES:
            raw, _ = corpus.make_clip(corpus.DEFAULT_SEED, "train", name, 0)
            m = Motion.from_raw(raw)
            # The pose with the most going on: the frame farthest from the clip's first (standing)
            # pose, in hinge angles and pelvis height.
            spread = np.abs(m.dof_pos - m.dof_pos[0]).sum(1) + 10 * np.abs(m.qpos[:, 2] - m.qpos[0, 2])
            data.qpos[:] = m.qpos[int(np.argmax(spread))]
            data.qpos[:2] = 0.0  # centred in the tracking camera
            mujoco.mj_forward(model, data)
            img = Image.fromarray(r.render(data)).resize(size)
            ImageDraw.Draw(img).text((8, 8), name, fill=(0, 0, 0))
            tiles.append(np.asarray(img))
    legend = Image.new("RGB", size, (255, 255, 255))
    ImageDraw.Draw(legend).text((12, size[1] // 2 - 20), f"smpl-envs corpus\n{len(corpus.FAMILIES)} families\n"
                                 "(docs/render_corpus.py)", fill=(0, 0, 0))
    write_strip(out, tiles + [np.asarray(legend)], columns=6)
    print(out)


if __name__ == "__main__":
    main()
