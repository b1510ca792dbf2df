"""The goal tasks (Speed, Reach, Strike) with two policy-free baselines, measured by each task's own
evaluation protocol and recorded.

    python examples/goal_tasks.py --out out/                     # all three tasks
    python examples/goal_tasks.py SMPL/Reach-v0 --episodes 8 --out out/

"zero": action 0, the PD controllers hold the start pose. "random": uniform random actions (the
humanoid falls within a second). Each task starts from random frames of the walk and run clips,
the style clips its AMP recipe uses. Writes, under --out: `<task>_<policy>.json` (the evaluation:
per-episode rows and the summary) and `<task>_zero.mp4` (markers show the target).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

import smpl_envs
from smpl_envs.evaluation import evaluate
from smpl_envs.render import record

GOAL_TASKS = ["SMPL/Speed-v0", "SMPL/Reach-v0", "SMPL/Strike-v0"]


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("tasks", nargs="*", default=GOAL_TASKS, help="task ids (default: the three goal tasks)")
    p.add_argument("--episodes", type=int, default=16, help="evaluation episodes per policy")
    p.add_argument("--steps", type=int, default=150, help="video length in steps")
    p.add_argument("--size", type=int, nargs=2, default=(640, 480), metavar=("W", "H"))
    p.add_argument("--out", type=Path, default=Path("out"))
    args = p.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(0)
    policies = {"zero": lambda obs: np.zeros((len(obs), 69), np.float32),
                "random": lambda obs: rng.uniform(-1, 1, (len(obs), 69)).astype(np.float32)}
    for task in args.tasks:
        name = task.split("/")[1].split("-")[0].lower()
        for label, policy in policies.items():
            result = evaluate(policy, task, motions=["walk", "run"], episodes=args.episodes, progress=False)
            print(f"{task}, {label} policy: {result.table()}\n")
            result.save(args.out / f"{name}_{label}.json")
        info = record(task, "zero", args.out / f"{name}_zero.mp4", steps=args.steps, seed=0, progress=False,
                      motions=["walk", "run"], render_size=tuple(args.size))
        print(f"{info['path']} ({info['frames']} frames)\n")


if __name__ == "__main__":
    print(f"smpl_envs {smpl_envs.__version__}")
    main()
