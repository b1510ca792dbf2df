"""How soon the get-up clips stand up: the ceiling they put on guided recovery's success times.

PHC's recovery protocol counts a fallen trial a success when the body is back within 0.5 m (mean
body distance) of its standing reference by 5 s or 10 s and stays there. A policy shown a get-up
clip (`Recovery-v0(getup_guide=...)`) can be no sooner than the clip itself, so per clip this
prints when the clip's own bodies are within `--threshold` of its last (standing) frame for good,
and when its pelvis first reaches 90 % of its standing height:

    python benchmarks/getup_timing.py                      # corpus:getup
    python benchmarks/getup_timing.py --motions corpus:test/getup --threshold 0.5

A perfect follower that starts the clip at the trial's start succeeds by 5 s only on the clips
whose "within" time is under 5 s; fallen+far (3 m away) needs the walk on top.
"""
from __future__ import annotations

import argparse

import numpy as np

from smpl_envs.motion.library import MotionLib


def timings(lib: MotionLib, threshold: float) -> tuple[np.ndarray, np.ndarray]:
    """(seconds until within `threshold` of the last frame for good, seconds until the pelvis
    first reaches 90 % of its last height) per clip."""
    within, up = [], []
    for m in range(lib.num_motions):
        s, n = int(lib.starts[m]), int(lib.lengths[m])
        pos = np.asarray(lib.body_pos[s:s + n])
        distance = np.linalg.norm(pos - pos[-1], axis=-1).mean(-1)
        outside = np.flatnonzero(distance >= threshold)
        within.append(0.0 if len(outside) == 0 else (outside[-1] + 1) / lib.fps)
        up.append(np.argmax(pos[:, 0, 2] >= 0.9 * pos[-1, 0, 2]) / lib.fps)
    return np.array(within), np.array(up)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--motions", default="corpus:getup")
    parser.add_argument("--threshold", type=float, default=0.5, help="m, mean body distance (PHC's 0.5)")
    args = parser.parse_args()
    lib = MotionLib.load(args.motions)
    within, up = timings(lib, args.threshold)
    lengths = np.asarray(lib.lengths) / lib.fps
    print(f"{args.motions}: {lib.num_motions} clips\n")
    print("| seconds | median | min | max | share by 5 s | share by 10 s |\n|---|---|---|---|---|---|")
    for name, x in (("clip length", lengths), (f"within {args.threshold} m of the standing end, for good", within),
                    ("pelvis at 90 % of standing height", up)):
        print(f"| {name} | {np.median(x):.1f} | {x.min():.1f} | {x.max():.1f} | {100 * (x <= 5).mean():.0f} % "
              f"| {100 * (x <= 10).mean():.0f} % |")


if __name__ == "__main__":
    main()
