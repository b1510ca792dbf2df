"""Generation from a PULSE prior against the zero and the random policy: z sampled from the prior
every step, decoded, with no task (REFERENCE.md section 5: 300-step, 10 s episodes; a fall ends
one). For each policy, over `--worlds` seeded episodes from the first frame of `--motions`:

- no_fall: the share of episodes that reach 10 s without a fall;
- distance: mean distance (m) the pelvis ends up from where it started, over the ground;
- pose_spread: how much the body moves relative to the pelvis, the mean over bodies of the
  standard deviation over time of each body's position in the pelvis-centred frame (m);
- seconds: mean episode length.

    python benchmarks/pulse_generation.py agents/pretrained/pulse.pt [--worlds 32] [--noise-scale 1]

The worlds are SMPL/Speed-v0's (its target unused: the prior and the decoder read only the self
observation), so a fall is that task's (a body other than the feet below 0.15 m, the head below
0.3 m). The random policy draws actions uniformly from [-1, 1]^69.
"""
from __future__ import annotations

import argparse
import json

import gymnasium as gym
import numpy as np

import smpl_envs  # noqa: F401 (registers the ids)
from smpl_envs.latent import LatentDecoder, PriorSampler
from smpl_envs.wrappers import LatentAction

STEPS = 300


def rollout(env, act, seed: int) -> dict:
    """First episode of every world of `env` under `act` (obs -> actions), up to STEPS steps."""
    obs, info = env.reset(seed=seed)
    n = env.num_envs
    start = info["body_pos"][:, 0, :2].copy()
    alive = np.ones(n, bool)
    length = np.zeros(n)
    end = start.copy()
    rel = [info["body_pos"] - info["body_pos"][:, :1]]
    for _ in range(STEPS):
        obs, _, terminated, truncated, info = env.step(act(obs))
        length += alive
        end[alive] = info["body_pos"][alive, 0, :2]
        rel.append(np.where(alive[:, None, None], info["body_pos"] - info["body_pos"][:, :1], np.nan))
        alive &= ~(terminated | truncated)
    fell = length < STEPS
    spread = np.nanmean(np.nanstd(np.stack(rel), axis=0), axis=(-2, -1))
    return {"no_fall": float(np.mean(~fell)), "distance": float(np.linalg.norm(end - start, axis=-1).mean()),
            "pose_spread": float(spread.mean()), "seconds": float(length.mean() / 30)}


def main(argv=None) -> dict:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("checkpoint", help="a PULSE checkpoint file")
    p.add_argument("--worlds", type=int, default=32)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--noise-scale", type=float, default=1.0)
    p.add_argument("--motions", default="stand", help="start poses: the first frame of these clips")
    p.add_argument("--out", help="JSON file for the table")
    args = p.parse_args(argv)

    decoder = LatentDecoder.from_checkpoint(args.checkpoint)
    kwargs = {"motions": args.motions, "start": "beginning", "max_episode_steps": STEPS + 1}
    rng = np.random.default_rng(args.seed)
    results = {}
    env = LatentAction(gym.make_vec("SMPL/Speed-v0", num_envs=args.worlds, **kwargs), decoder)
    results["prior"] = rollout(env, PriorSampler(decoder, args.seed, args.noise_scale), args.seed)
    results["prior_mean"] = rollout(env, PriorSampler(decoder, args.seed, 0.0), args.seed)
    env.close()
    env = gym.make_vec("SMPL/Speed-v0", num_envs=args.worlds, **kwargs)
    results["zero"] = rollout(env, lambda obs: np.zeros((len(obs), 69), np.float32), args.seed)
    results["random"] = rollout(env, lambda obs: rng.uniform(-1, 1, (len(obs), 69)).astype(np.float32), args.seed)
    env.close()
    print(f"{'policy':<12}{'no_fall':>9}{'distance':>10}{'pose_spread':>13}{'seconds':>9}")
    for name, r in results.items():
        print(f"{name:<12}{r['no_fall']:>9.2f}{r['distance']:>10.2f}{r['pose_spread']:>13.3f}{r['seconds']:>9.1f}")
    if args.out:
        with open(args.out, "w") as f:
            json.dump({"checkpoint": args.checkpoint, "worlds": args.worlds, "seed": args.seed,
                       "noise_scale": args.noise_scale, "motions": args.motions, "results": results}, f, indent=2)
    return results


if __name__ == "__main__":
    main()
