"""Policy-free rollouts of SMPL/Imitation-v0: the two baselines every learned policy must beat.

    python examples/imitation_rollout.py --out out/            # all shipped clips
    python examples/imitation_rollout.py walk run --out out/   # some clips

"zero": action 0, the PD controllers hold the rest pose. "reference": each action sets the PD
targets to the next reference frame's joint angles (open-loop tracking; nothing controls the
unactuated root, so balance is lost within a second or two on anything dynamic).

Writes, under --out: a video per baseline of the first clip (reference bodies as red markers),
and the metrics table of each baseline over the clips (printed, and as JSON).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import gymnasium as gym
import numpy as np

import smpl_envs
from smpl_envs.evaluation import evaluate
from smpl_envs.motion import available_clips
from smpl_envs.render import record


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("clips", nargs="*", default=None, help="shipped clip names or motion files (default: all shipped clips, walk first)")
    p.add_argument("--out", default="out", help="output directory")
    p.add_argument("--num-envs", type=int, default=8, help="worlds stepped together during evaluation")
    p.add_argument("--size", type=int, nargs=2, default=(640, 480), metavar=("W", "H"))
    args = p.parse_args()
    clips = args.clips or ["walk"] + [c for c in available_clips() if c != "walk"]
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)

    env = gym.make_vec("SMPL/Imitation-v0", num_envs=min(args.num_envs, len(clips)), motions=clips,
                       termination_distance=None, autoreset_mode="Disabled")
    baselines = {"zero": lambda obs: np.zeros((len(obs), 69), np.float32),
                 "reference": lambda obs: env.reference_action()}
    for name, policy in baselines.items():
        result = evaluate(policy, env, progress=True)
        print(f"\n{name} action, {len(clips)} clips:\n{result.table()}")
        result.save(out / f"metrics_{name}.json")
    env.close()

    first = clips[0]
    for name in baselines:
        video = gym.make("SMPL/Imitation-v0", motions=first, start="beginning", render_mode="rgb_array",
                         render_size=tuple(args.size))
        stats = record(video, name, out / f"imitation_{Path(first).stem}_{name}.mp4", episodes=1, seed=0)
        print(f"{name}: {stats['frames']} frames -> {stats['path']}")
        video.close()
    print(f"\nsmpl-envs {smpl_envs.__version__}: outputs in {out.resolve()}")


if __name__ == "__main__":
    main()
