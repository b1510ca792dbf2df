"""A task on the MuJoCo Warp backend next to the same task on the CPU backend.

    python examples/warp_backend.py [--device cuda] [--worlds 4096] [--steps 20]

Makes `SMPL/Imitation-v0` on both backends from the walk clip's first frame, steps them with the
same small residual actions and prints how far their observations drift apart (float32 physics
against float64), then trains PPO for two iterations on the warp env (its rollout stays in torch
on the device) and evaluates the zero residual through `smpl_envs.evaluate`, which reads the warp
env through `NumpyVecEnv`. Needs `pip install -e ".[gpu]"`; runs on Warp's CPU device without a
GPU (slowly: it is for checking, not for speed).
"""
from __future__ import annotations

import argparse

import gymnasium as gym
import numpy as np
import torch

import smpl_envs
from agents import PPO


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    p.add_argument("--worlds", type=int, default=4)
    p.add_argument("--steps", type=int, default=10)
    args = p.parse_args()

    kw = {"motions": "walk", "action_mode": "residual"}
    warp = gym.make_vec("SMPL/Imitation-v0", num_envs=args.worlds, backend="warp", device=args.device, **kw)
    cpu = gym.make_vec("SMPL/Imitation-v0", num_envs=args.worlds, **kw)
    begin = {"motion_ids": [0] * args.worlds, "start": "beginning"}
    ow, _ = warp.reset(seed=0, options=begin)
    oc, _ = cpu.reset(seed=0, options=begin)
    print(f"observations: {type(ow).__name__} {tuple(ow.shape)} on {ow.device}")
    rng = np.random.default_rng(0)
    for k in range(args.steps):
        a = rng.uniform(-0.3, 0.3, (args.worlds, 69)).astype(np.float32)
        ow = warp.step(torch.as_tensor(a, device=args.device))[0]
        oc = cpu.step(a)[0]
        print(f"step {k + 1:2d}: max |obs warp - obs cpu| = {np.abs(ow.cpu().numpy() - oc).max():.2e}")

    model = PPO(warp, n_steps=8, batch_size=args.worlds * 8, n_epochs=1, verbose=0, tensorboard=False,
                device=args.device, seed=0)
    model.learn(2 * 8 * args.worlds, progress_bar=False)
    print(f"PPO: {model.num_timesteps} steps on the warp env, rollout values on {model.rollout_buffer.values.device}")

    result = smpl_envs.evaluate(lambda obs: np.zeros((len(obs), 69), np.float32), "SMPL/Imitation-v0",
                                motions="stand", num_envs=1, progress=False,
                                env_kwargs={"action_mode": "residual", "backend": "warp", "device": args.device})
    row = result.rows[0]
    print(f"zero residual on stand (warp): success {row['success']}, {row['frames']} frames tracked")
    warp.close()
    cpu.close()


if __name__ == "__main__":
    main()
