"""Writes tests/data/imitation_regression.npz: short seeded trajectories of the imitation envs.

Run once with the code whose behaviour the regression test pins (it was generated before the
environment core was redesigned); `test_envs_regression.py` replays the same seeds and actions.
"""
from pathlib import Path

import gymnasium as gym
import numpy as np

import smpl_envs  # noqa: F401

IDS = {"imitation": "SMPL/Imitation-v0", "keypoint": "SMPL/KeypointImitation-v0"}
KWARGS = dict(num_envs=3, motions=["walk", "run", "turn"], termination_distance=0.15)
STEPS = 16


def actions(steps: int = STEPS, n: int = 3) -> np.ndarray:
    return (np.random.default_rng(7).normal(0.0, 0.15, (steps, n, 69))).astype(np.float32)


def rollout(env_id: str, **overrides) -> dict[str, np.ndarray]:
    env = gym.make_vec(env_id, **{**KWARGS, **overrides})
    obs, info = env.reset(seed=123)
    out = {"obs": [obs], "reward": [], "terminated": [], "truncated": [], "motion_id": [info["motion_id"]]}
    for a in actions():
        obs, r, te, tr, info = env.step(a)
        out["obs"].append(obs)
        out["reward"].append(r)
        out["terminated"].append(te)
        out["truncated"].append(tr)
        out["motion_id"].append(info["motion_id"])
    env.close()
    return {k: np.stack(v) for k, v in out.items()}


if __name__ == "__main__":
    arrays = {f"{name}/{k}": v for name, env_id in IDS.items() for k, v in rollout(env_id).items()}
    path = Path(__file__).parent / "data" / "imitation_regression.npz"
    np.savez_compressed(path, **arrays)
    print(path, path.stat().st_size, {k: v.shape for k, v in arrays.items()})
    print("terminations:", arrays["imitation/terminated"].sum(), arrays["keypoint/terminated"].sum())
