"""VR three-point tracking from a stream file: cut the head and hands out of a shipped clip, write
them as a three-point stream (the format a VR rig's recording is converted to), and measure
policy-free baselines with SMPL/VRTracking-v0's evaluation protocol.

    python examples/vr_stream.py --out out/                   # the gesture clip
    python examples/vr_stream.py --clip walk --video --out out/

Baselines:
- "stand" on the stream (no full body: the three-point reward and metrics only): the PD targets
  hold the standing start pose, so the head and hands stay where that pose puts them;
- "pd-reference" on the clip it was cut from (full body known): the PD targets are the clip's
  joint angles, what a perfect kinematic pose estimate would give without a policy to balance.

Writes, under --out: `<clip>_3p.npz` (the stream), `vr_<clip>_stand.json`,
`vr_<clip>_pd-reference.json` (per-clip rows and the summary), and with --video
`vr_<clip>_stand.mp4` (markers show the three reference points).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import gymnasium as gym
import numpy as np

import smpl_envs  # noqa: F401  (registers the SMPL/ ids)
from smpl_envs.evaluation import evaluate
from smpl_envs.humanoid.skeleton import ACTION_SCALE
from smpl_envs.motion import MotionLib
from smpl_envs.motion.three_point import ThreePointStream, write_stream
from smpl_envs.render import record

ID = "SMPL/VRTracking-v0"


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--clip", default="gesture", help="shipped clip to cut the stream from")
    p.add_argument("--video", action="store_true", help="also record the stand baseline on the stream")
    p.add_argument("--steps", type=int, default=150, help="video length in steps")
    p.add_argument("--out", type=Path, default=Path("out"))
    args = p.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)

    lib = MotionLib.load(args.clip, progress=False)
    stream = ThreePointStream.from_motion((lib, 0))
    path = write_stream(args.out / f"{args.clip}_3p.npz", stream.positions, stream.quats)
    print(f"{path}: {stream.num_frames} frames of Head, L_Hand, R_Hand at 30 fps\n")

    # Absolute PD targets equal to the standing start pose's joint angles (the first frame of the
    # shipped stand clip, the env's default stream start pose).
    stand = np.clip(MotionLib.load("stand", progress=False).dof_pos[0] / ACTION_SCALE, -1, 1).astype(np.float32)
    hold = lambda obs: stand if np.ndim(obs) == 1 else np.tile(stand, (len(obs), 1))  # noqa: E731
    result = evaluate(hold, ID, motions=str(path), progress=False)
    print(f"{ID} on the stream, stand baseline:\n{result.table()}\n")
    result.save(args.out / f"vr_{args.clip}_stand.json")

    env = gym.make_vec(ID, num_envs=1, motions=args.clip, termination_distance=None, autoreset_mode="Disabled")
    result = evaluate(lambda obs: env.unwrapped.reference_action(), env, progress=False)
    print(f"{ID} on the {args.clip} clip, PD-reference baseline:\n{result.table()}\n")
    result.save(args.out / f"vr_{args.clip}_pd-reference.json")
    env.close()

    if args.video:
        info = record(ID, hold, args.out / f"vr_{args.clip}_stand.mp4", steps=args.steps, seed=0,
                      progress=False, motions=str(path), start="beginning", termination_distance=None)
        print(f"{info['path']} ({info['frames']} frames)")


if __name__ == "__main__":
    main()
