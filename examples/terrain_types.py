"""A picture of every terrain type of `SMPL/Terrain-v0`, rendered with MuJoCo (headless: EGL).

    python examples/terrain_types.py                     # writes docs/terrain.png
    python examples/terrain_types.py --difficulty 1.0 --out /tmp/terrain.png

One panel per type: a single 20 x 20 m tile of it at `--difficulty`, the humanoid standing on the
tile's centre platform (its start pose) and the first 5 s of its path (orange: now, green: ahead).
The last panel is the default mixed terrain (4 x 4 tiles, PULSE's shares, difficulty by row) from
above.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import smpl_envs  # noqa: F401  (headless GL before mujoco)
import mujoco
import numpy as np

from smpl_envs.envs.terrain import TerrainVecEnv
from smpl_envs.render import write_strip
from smpl_envs.terrain import TERRAIN_TYPES

ROOT = Path(__file__).resolve().parents[1]


def panel(env: TerrainVecEnv, size, lookat, distance, elevation, label: str) -> np.ndarray:
    """One frame of world 0 from a free camera, with the path markers and a label."""
    from PIL import Image, ImageDraw

    width, height = size
    with mujoco.Renderer(env.model, height, width) as r:
        cam = mujoco.MjvCamera()
        cam.lookat[:], cam.distance, cam.azimuth, cam.elevation = lookat, distance, 135.0, elevation
        r.update_scene(env.sim.datas[0], camera=cam)
        scene = r.scene
        for positions, rgba, radius in env._markers(0):
            for p in positions:
                if scene.ngeom < scene.maxgeom:
                    mujoco.mjv_initGeom(scene.geoms[scene.ngeom], mujoco.mjtGeom.mjGEOM_SPHERE, np.full(3, 2.5 * radius),
                                        p, np.eye(3).ravel(), np.asarray(rgba, np.float32))
                    scene.ngeom += 1
        image = Image.fromarray(r.render())
    ImageDraw.Draw(image).text((8, 6), label, fill=(255, 255, 255))
    return np.asarray(image)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--difficulty", type=float, default=0.6)
    p.add_argument("--size", type=int, nargs=2, default=(480, 360), metavar=("W", "H"))
    p.add_argument("--out", type=Path, default=ROOT / "docs" / "terrain.png")
    args = p.parse_args()

    panels = []
    for kind in TERRAIN_TYPES:
        # A mapping, so that "flat" too is a heightfield tile (terrain="flat" is the plain floor).
        env = TerrainVecEnv(1, terrain={kind: 1.0}, terrain_size=(1, 1), terrain_difficulty=args.difficulty,
                            terrain_border=4.0, terrain_seed=1)
        env.reset(seed=2)
        centre = env.ground(np.zeros(2))
        panels.append(panel(env, args.size, [0.0, 0.0, 0.5 * centre + 0.5], 21.0, -32.0,
                            f"{kind} (difficulty {args.difficulty:g})"))
        env.close()
    env = TerrainVecEnv(1)  # the default: 4 x 4 mixed tiles, difficulty 0, 0.25, 0.5, 0.75 by row
    env.reset(seed=0)
    panels.append(panel(env, args.size, [0.0, 0.0, 0.0], 95.0, -50.0, "mixed, 4 x 4 tiles (default)"))
    env.close()
    write_strip(args.out, panels, columns=4)
    print(args.out)


if __name__ == "__main__":
    main()
