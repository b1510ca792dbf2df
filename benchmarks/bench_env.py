"""Environment throughput against raw physics of the same model, measured side by side, per task.

    python benchmarks/bench_env.py [--ids SMPL/Speed-v0 ...] [--worlds 64] [--steps 300] [--repeats 5]

Single env: `gym.make(id)` driven for `--steps` steps by a fixed policy (imitation: the
reference-tracking action from each clip's first frame, no early termination; goal tasks: the
zero action, under which the rest pose stands); then the same control sequence is replayed from
the same initial states with bare `mj_step` calls on one MjData of the same model (box included),
so both do identical physics and the ratio is the environment's overhead (observations, reward,
termination, AMP features, info).

N worlds: `gym.make_vec(id, num_envs=N)` driven the same way (imitation: every world from a
shipped clip's first frame), against raw physics replaying the same controls on N MjData stepped
by the same thread pool, and against the single env's rate. Figures are medians of `--repeats`.
Terrain runs with the off-path rule widened (no episode ends inside the run, as the replay needs).

Height map (tasks that observe one, e.g. `SMPL/Terrain-v0`): at N worlds, every env step is
followed by one extra `height_map` call on the state it left, timed on its own, so the two are
measured side by side in one run; the table gives the height map's time and its share of a step
(the step itself computes one), medians of `--repeats`.
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

IMITATION = ("SMPL/Imitation-v0", "SMPL/KeypointImitation-v0")
# Keeps every terrain episode running for the whole measurement (the rest pose stands, but the
# path it does not follow would end the episode 4 m later).
NO_END = {"SMPL/Terrain-v0": dict(off_path_distance=1e6)}


def _kwargs(env_id: str, single: bool) -> dict:
    if env_id in IMITATION:
        return dict(termination_distance=None, start="beginning", motions="walk" if single else available_clips())
    return dict(NO_END.get(env_id, {}))


def _policy(vec):
    # The reference-tracking action where the task has one, else standing still.
    if hasattr(vec, "reference_action"):
        return vec.reference_action
    return lambda: np.zeros((vec.num_envs, 69))


def single_env(env_id: str, steps: int) -> tuple[float, float]:
    env = gym.make(env_id, **_kwargs(env_id, True))
    env.reset(seed=0)
    vec = env.unwrapped.vec
    act = _policy(vec)
    m, d0 = vec.model, vec.sim.datas[0]
    episodes, current = [], None
    t_env = 0.0
    for _ in range(steps):
        if current is None:
            current = (d0.qpos.copy(), d0.qvel.copy(), [])
        action = act()[0]
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


def many_worlds(env_id: str, n: int, steps: int) -> tuple[float, float]:
    # No episode ends within `steps`, so the raw replay below repeats exactly the env's physics.
    env = gym.make_vec(env_id, num_envs=n, **_kwargs(env_id, False))
    env.reset(seed=0)
    sim, m = env.sim, env.model
    if env.motion_lib is not None and env_id in IMITATION:
        steps = min(steps, int(env.motion_lib.lengths.min()) - 1)
    if env.max_episode_steps is not None:
        steps = min(steps, env.max_episode_steps - 1)
    start = [(d.qpos.copy(), d.qvel.copy()) for d in sim.datas]
    act = _policy(env)
    actions = [act() for _ in range(steps)]  # drawn up front: not part of the timing
    ctrls = []
    t = time.perf_counter()
    for a in actions:
        env.step(a)
        ctrls.append(sim.ctrl.copy())  # what the env applied (a microsecond against ~10 ms a step)
    rate = n * steps / (time.perf_counter() - t)

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


def height_map_share(env_id: str, n: int, steps: int) -> tuple[float, float] | None:
    """(ms per height map of n worlds, its share of an env step), or None if the task has none."""
    from smpl_envs.features import heading_rotation

    env = gym.make_vec(env_id, num_envs=n, **_kwargs(env_id, False))
    u = env.unwrapped
    if not hasattr(u, "height_map"):
        env.close()
        return None
    env.reset(seed=0)
    act = _policy(env)
    actions = [act() for _ in range(steps)]
    t_step = t_map = 0.0
    for a in actions:
        t = time.perf_counter()
        env.step(a)
        t_step += time.perf_counter() - t
        body = env.sim.bodies
        heading = heading_rotation(body.rot[:, 0])
        t = time.perf_counter()
        u.height_map(body.pos[:, 0], heading)
        t_map += time.perf_counter() - t
    env.close()
    return 1e3 * t_map / steps, t_map / t_step


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--ids", nargs="+", default=list(smpl_envs.ENV_IDS), help="task ids (default: all)")
    p.add_argument("--worlds", type=int, default=64)
    p.add_argument("--steps", type=int, default=300)
    p.add_argument("--repeats", type=int, default=5)
    args = p.parse_args()
    print(f"{os.cpu_count()} CPU cores, MuJoCo {mujoco.__version__}, {args.repeats} repeats (medians)")
    print(f"| id | single env steps/s | raw physics | ratio | {args.worlds} worlds steps/s | raw physics | ratio "
          f"| {args.worlds} worlds / single |")
    print("|---|---|---|---|---|---|---|---|")
    for env_id in args.ids:
        singles = np.array([single_env(env_id, args.steps) for _ in range(args.repeats)])
        multi = np.array([many_worlds(env_id, args.worlds, args.steps) for _ in range(args.repeats)])
        env1, raw1 = np.median(singles, 0)
        envn, rawn = np.median(multi, 0)
        print(f"| `{env_id}` | {env1:.0f} | {raw1:.0f} | {np.median(singles[:, 0] / singles[:, 1]):.2f} "
              f"| {envn:.0f} | {rawn:.0f} | {np.median(multi[:, 0] / multi[:, 1]):.2f} | {envn / env1:.2f}x |",
              flush=True)
    maps = {}
    for env_id in args.ids:
        runs = [height_map_share(env_id, args.worlds, args.steps) for _ in range(args.repeats)]
        if runs[0] is not None:
            maps[env_id] = np.median(np.array(runs), 0)
    if maps:
        print(f"\n| id | height map at {args.worlds} worlds (ms) | share of an env step |")
        print("|---|---|---|")
        for env_id, (ms, share) in maps.items():
            print(f"| `{env_id}` | {ms:.2f} | {100 * share:.1f} % |", flush=True)
    if "SMPL/Recovery-v0" in args.ids:
        # Recovery's fallen starts: one batched simulation of 128 falls (2.5 s of physics each),
        # a fresh seed per repeat (the generator memoises per seed).
        from smpl_envs.envs.fallen import generate_fallen_states

        took = []
        for r in range(args.repeats):
            t = time.perf_counter()
            generate_fallen_states(128, seed=10_000 + r)
            took.append(time.perf_counter() - t)
        print(f"\nRecovery-v0 fallen-state cache: 128 states in {np.median(took):.1f} s (median of {args.repeats})",
              flush=True)


if __name__ == "__main__":
    main()
