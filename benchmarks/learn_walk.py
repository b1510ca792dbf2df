"""Measured learning on this machine: PPO imitating the shipped walk clip for a wall-clock budget.

    python benchmarks/learn_walk.py --minutes 45 --run-dir runs/learn_walk

Trains with the values of tasks/imitation_ppo.yaml, stops at the time budget, then evaluates the
last checkpoint with the papers' metrics and plots the learning curves. The run directory has the
same layout as `smpl-envs train` makes, so `smpl-envs eval|record|plot RUN` work on it.
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import torch

from agents import PPO, CheckpointCallback
from agents.recipes import load_recipe

# The recipe's values, read from it so the two cannot drift apart.
RECIPE = load_recipe("imitation_ppo")
HYPERPARAMS = RECIPE["agent"]["hyperparams"]
POLICY = RECIPE["agent"]["policy"]  # the actor-critic and its sizes
ENV_KWARGS = RECIPE["env"]["kwargs"]  # motions: walk; the env's default energy weight (1e-5)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--minutes", type=float, default=45.0)
    p.add_argument("--num-envs", type=int, default=32)
    p.add_argument("--run-dir", default="runs/learn_walk")
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args()
    # One torch thread: on 2 cores a second one only fights the physics threads (measured 2x slower).
    torch.set_num_threads(1)
    run = Path(args.run_dir)
    (run / "checkpoints").mkdir(parents=True, exist_ok=True)
    config = {"env": {"id": "SMPL/Imitation-v0", "num_envs": args.num_envs, "kwargs": ENV_KWARGS},
              "agent": {"class": "PPO", "policy": POLICY, "hyperparams": HYPERPARAMS},
              "train": {"seed": args.seed, "minutes": args.minutes}}
    (run / "config.json").write_text(json.dumps(config, indent=2))

    model = PPO("SMPL/Imitation-v0", n_envs=args.num_envs, env_kwargs=ENV_KWARGS, seed=args.seed,
                log_dir=run / "logs", verbose=0, policy=POLICY["class"], policy_kwargs=POLICY["kwargs"],
                **HYPERPARAMS)
    deadline = time.monotonic() + 60 * args.minutes
    model.learn(10**10, log_interval=1, progress_bar=False, callback=[
        CheckpointCallback(250_000, run / "checkpoints"),
        lambda agent: time.monotonic() < deadline,
    ])
    model.save(run / "checkpoints" / "last.pt")
    print(f"trained {model.num_timesteps} steps in {args.minutes} min; run: {run}")


if __name__ == "__main__":
    main()
