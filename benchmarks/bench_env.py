"""Environment throughput against raw physics of the same model, measured side by side.

    python benchmarks/bench_env.py [--worlds 64] [--steps 300] [--repeats 5]

Single env: `gym.make("SMPL/Imitation-v0")` driven by the reference-tracking action for `--steps`
steps; then the same control sequence is replayed from the same initial state with bare
`mj_step` calls on one MjData, so both do identical physics and the ratio is the environment's
overhead (observations, reward, termination, AMP features, info).

N worlds: `gym.make_vec(..., num_envs=N)` over the shipped clips, each world from a clip's first
frame, against the single env's rate, and against raw physics replaying the same controls on N
MjData stepped by the same thread pool. Figures are medians of `--repeats` runs.
"""

from __future__ import annotations

import argparse
import os
import time

import gymnasium as gym
import mujoco
import numpy as np

import smpl_envs  # noqa: F401  (registers the ids)
from smpl_envs.motion import available_clips


def single_env(steps: int) -> tuple[float, float]:
    env = gym.make("SMPL/Imitation-v0", termination_distance=None, start="beginning", motions="walk")
    env.reset(seed=0)
    vec = env.unwrapped.vec
    m, d0 = vec.model, vec.sim.datas[0]
    episodes, current = [], None
    t_env = 0.0
    for _ in range(steps):
        if current is None:
            current = (d0.qpos.copy(), d0.qvel.copy(), [])
        action = env.unwrapped.reference_action()
        t = time.perf_counter()
        _, _, term, trunc, _ = env.step(action)
        t_env += time.perf_counter() - t
        current[2].append(d0.ctrl.copy())
        if term or trunc:
            episodes.append(current)
            current = None
            t = time.perf_counter()
            env.reset()
            t_env += time.perf_counter() - t
    if current is not None:
        episodes.append(current)

    d = mujoco.MjData(m)
    t_raw = 0.0
    for qpos, qvel, ctrls in episodes:
        mujoco.mj_resetData(m, d)
        d.qpos[:], d.qvel[:] = qpos, qvel
        t = time.perf_counter()
        for c in ctrls:
            d.ctrl[:] = c
            for _ in range(vec.sim.substeps):
                mujoco.mj_step(m, d)
        t_raw += time.perf_counter() - t
    env.close()
    return steps / t_env, steps / t_raw


def many_worlds(n: int, steps: int) -> tuple[float, float]:
    # Every world starts at the first frame of a shipped clip and no episode ends within `steps`,
    # so the raw replay below repeats exactly the env's physics.
    env = gym.make_vec("SMPL/Imitation-v0", num_envs=n, termination_distance=None, start="beginning",
                       motions=available_clips())
    env.reset(seed=0)
    sim, m = env.sim, env.model
    steps = min(steps, int(env.motion_lib.lengths.min()) - 1)
    start = [(d.qpos.copy(), d.qvel.copy()) for d in sim.datas]
    actions = [env.reference_action() for _ in range(steps)]  # drawn up front: not part of the timing
    t = time.perf_counter()
    for a in actions:
        env.step(a)
    rate = n * steps / (time.perf_counter() - t)
    ctrls = [np.clip(a, -1, 1) * env.action_scale for a in actions]

    for d, (qpos, qvel) in zip(sim.datas, start):
        mujoco.mj_resetData(m, d)
        d.qpos[:], d.qvel[:] = qpos, qvel

    def raw_slice(ids, ctrl):
        for i in ids:
            d = sim.datas[i]
            d.ctrl[:] = ctrl[i]
            for _ in range(sim.substeps):
                mujoco.mj_step(m, d)

    t = time.perf_counter()
    for ctrl in ctrls:
        if sim._pool is None:
            raw_slice(range(n), ctrl)
        else:
            list(sim._pool.map(raw_slice, sim._slices, [ctrl] * len(sim._slices)))
    raw = n * steps / (time.perf_counter() - t)
    env.close()
    return rate, raw


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--worlds", type=int, default=64)
    p.add_argument("--steps", type=int, default=300)
    p.add_argument("--repeats", type=int, default=5)
    args = p.parse_args()
    print(f"{os.cpu_count()} CPU cores, MuJoCo {mujoco.__version__}, {args.repeats} repeats (medians)")
    singles = np.array([single_env(args.steps) for _ in range(args.repeats)])
    env1, raw1 = np.median(singles, 0)
    ratio1 = np.median(singles[:, 0] / singles[:, 1])
    print(f"single env   : {env1:8.0f} steps/s   raw physics {raw1:8.0f} steps/s   ratio {ratio1:.2f}")
    multi = np.array([many_worlds(args.worlds, args.steps) for _ in range(args.repeats)])
    envn, rawn = np.median(multi, 0)
    print(f"{args.worlds:3d} worlds    : {envn:8.0f} steps/s   raw physics {rawn:8.0f} steps/s   "
          f"ratio {np.median(multi[:, 0] / multi[:, 1]):.2f}")
    print(f"{args.worlds} worlds vs single env: {envn / env1:.2f}x")


if __name__ == "__main__":
    main()
