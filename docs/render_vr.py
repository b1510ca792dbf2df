"""Render docs/vr.png: SMPL/VRTracking-v0 on the walk clip with the zero residual action (the PD
controllers alone track the clip's joint angles), frames 0, 8, 16 and 24; the markers are the head
and hand references the task observes.

    MUJOCO_GL=egl python docs/render_vr.py
"""
from pathlib import Path

import gymnasium as gym
import numpy as np

import smpl_envs  # noqa: F401  (registers the ids, picks a headless GL backend)
from smpl_envs.render import write_strip

HERE = Path(__file__).resolve().parent
FRAMES = (0, 8, 16, 24)


def main() -> None:
    env = gym.make("SMPL/VRTracking-v0", motions="walk", action_mode="residual", start="beginning",
                   render_mode="rgb_array", render_size=(480, 480))
    env.reset(seed=0)
    frames = []
    for t in range(max(FRAMES) + 1):
        if t in FRAMES:
            frames.append(env.render())
        env.step(np.zeros(69, np.float32))
    write_strip(HERE / "vr.png", frames)
    env.close()


if __name__ == "__main__":
    main()
