"""The recovery primitive getting up: a video of one trial per start kind side by side
(fallen, far, fallen+far, 10 s each, started as PHC's recovery protocol starts them) and a frame
strip of the fallen start, six frames evenly over the trial (0, 2, ..., 10 s), for the README.

    python docs/render_getup.py CHECKPOINT_OR_RUN_OR_NAME [--seconds 10] [--seed 0]
        [--fallen-lying back] [--out docs/videos/getup.mp4]   # and docs/videos/getup.png, the strip

Each tile is labelled with its start kind and, from the frame the protocol counts the trial as
back (mean body distance to the standing reference <= 0.5 m from there to the end:
`smpl_envs.metrics.recovery_frame`), the second it got back.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np

import smpl_envs
from smpl_envs.features import facing_height
from smpl_envs.metrics import recovery_frame
from smpl_envs.render import write_strip, write_video

from render_tracker_grid import label  # a sibling script: docs/ is on the path when run

KINDS = ("fallen", "far", "fallen+far")
TILE = (320, 240)
FPS = 30
THRESHOLD = 0.5  # the protocol's success distance (m)


def episode(agent, kind: str, steps: int, seed: int, tmp: Path,
            lying: str | None = None) -> tuple[list[np.ndarray], np.ndarray]:
    """Frames of one trial from a `kind` start (the frame after the reset and after each step)
    and the mean body distance to the reference at each of them; with `lying` ("front" or
    "back"), from the first seed on whose start lies that way."""
    import gymnasium as gym
    import imageio.v2 as imageio

    from smpl_envs import policy_settings
    from smpl_envs.render import _trained_make_kwargs  # the settings the policy trained with

    distances: list[float] = []

    class Trial(gym.Wrapper):
        def reset(self, **kw):  # the protocol's start, and its distance
            obs, info = self.env.reset(**{**kw, "options": {"recovery_start": kind, "start": "beginning"}})
            distances.append(_distance(info))
            return obs, info

        def step(self, action):
            out = self.env.step(action)
            distances.append(_distance(out[-1]))
            return out

    trained = policy_settings.training_record(agent)
    # The protocol's trial (RecoveryProtocol.make_env): the standing clip, not the training clips,
    # whose reference would walk away from a body on the floor.
    kwargs = _trained_make_kwargs("SMPL/Recovery-v0", *trained, {"motions": "stand", "hold_end": True,
                                                                  "continue_prob": 0.0, "max_episode_steps": steps,
                                                                  "termination_distance": None,
                                                                  "far_distance": (3.0, 3.0), "render_size": TILE}, ())
    if lying is not None:  # the first seed from `seed` whose start lies that way (before any step)
        probe = gym.make("SMPL/Recovery-v0", **kwargs)
        try:
            while _lying(probe.reset(seed=seed, options={"recovery_start": kind, "start": "beginning"})[1]) != lying:
                seed += 1
        finally:
            probe.close()
    env = Trial(gym.make("SMPL/Recovery-v0", render_mode="rgb_array", **kwargs))
    path = tmp / f"{kind}.mp4"
    try:
        smpl_envs.record(env, lambda obs: agent.predict(obs, deterministic=True)[0], path, steps=steps,
                         episodes=1, seed=seed, progress=False)
    finally:
        env.close()
    with imageio.get_reader(path) as reader:
        return [np.asarray(f) for f in reader], np.asarray(distances)


def _lying(info) -> str:
    """"front" (face down) or "back", from the body positions in `info`."""
    return "front" if facing_height(np.asarray(info["body_pos"], np.float64)) < 0 else "back"


def _distance(info) -> float:
    d = np.asarray(info["body_pos"], np.float64) - np.asarray(info["ref_body_pos"], np.float64)
    return float(np.linalg.norm(d, axis=-1).mean())


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("target", help="a checkpoint, a run directory (its best.pt) or a shipped policy name")
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=Path("docs/videos/getup.mp4"))
    parser.add_argument("--fallen-lying", choices=("front", "back"),
                        help="the fallen trial: the first seed from --seed whose start lies this way (chosen by "
                             "how the body lies before any step, not by the outcome)")
    args = parser.parse_args(argv)
    from agents.checkpoint_commands import load_target  # the command line's own lookup of runs and names

    agent, ckpt, _, _ = load_target(args.target, "best", "cpu")
    steps = int(round(args.seconds * FPS))
    tiles = []
    with tempfile.TemporaryDirectory() as tmp:
        for kind in KINDS:
            lying = args.fallen_lying if kind == "fallen" else None
            frames, dist = episode(agent, kind, steps, args.seed, Path(tmp), lying)
            back = int(recovery_frame(dist[None], THRESHOLD)[0])
            back = back if back >= 0 else None
            text = lambda i: kind + (f"  back after {back / FPS:.1f} s" if back is not None and i >= back else "")  # noqa: E731
            frames = [label(f, text(i), (140, 255, 140) if back is not None and i >= back else (255, 255, 255))
                      for i, f in enumerate(frames)]
            tiles.append(frames + [frames[-1]] * (steps + 1 - len(frames)))
            print(f"{kind}: " + (f"back within {THRESHOLD} m after {back / FPS:.1f} s" if back is not None else
                                 f"not back in {args.seconds:g} s (distance at the end {dist[-1]:.2f} m)"))
            if kind == "fallen":
                strip = [tiles[-1][int(round(i))] for i in np.linspace(0, steps, 6)]
    n = write_video(args.out, (np.concatenate([t[i] for t in tiles], axis=1) for i in range(steps + 1)), fps=FPS)
    still = args.out.with_suffix(".png")
    write_strip(still, strip)
    print(f"{args.out} ({n} frames, policy {ckpt}); {still} (the fallen start, six frames over the trial)")


if __name__ == "__main__":
    main()
