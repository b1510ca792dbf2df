"""Physics speed of the humanoid, and the timestep choice behind PHYSICS_TIMESTEP.

For each (physics timestep, substeps per 1/30 s control step) it measures on one core: control
steps per second (set 69 PD targets from an action, then the substeps, as an environment does),
raw mj_step throughput inside the same rollouts, their ratio, and whether the humanoid stands
10 s at zero action. Figures are medians over repeats.

    python benchmarks/bench_physics.py
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from pathlib import Path

import mujoco
import numpy as np

from smpl_envs.humanoid import ACTION_SCALE, BODY_NAMES, build_humanoid

CONFIGS = [(1 / 60, 2), (1 / 120, 4), (1 / 240, 8), (1 / 450, 15)]
HEAD = BODY_NAMES.index("Head") + 1


def stands(model) -> bool:
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    head0 = data.xpos[HEAD, 2]
    mujoco.mj_step(model, data, nstep=int(round(10 / model.opt.timestep)))
    return bool(np.isfinite(data.qpos).all() and data.xpos[HEAD, 2] > head0 - 0.05)


def rollout_rates(model, substeps: int, steps: int, rng) -> tuple[float, float]:
    """An environment's control step (map an action in [-1, 1] to PD targets, then the substeps),
    timed whole and with only the mj_step call timed, in the same rollout, so both see exactly
    the same contacts and solver work. Returns (control steps / s, raw physics control steps / s)."""
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    actions = rng.uniform(-0.05, 0.05, (steps, model.nu))
    physics = 0.0
    t = time.perf_counter()
    for a in actions:
        data.ctrl[:] = ACTION_SCALE * a
        t_phys = time.perf_counter()
        mujoco.mj_step(model, data, nstep=substeps)
        physics += time.perf_counter() - t_phys
    total = time.perf_counter() - t
    return steps / total, steps / physics


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seconds", type=float, default=4.0, help="simulated seconds per repeat")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()
    rng = np.random.default_rng(0)
    rows = []
    for dt, substeps in CONFIGS:
        model = build_humanoid(timestep=dt)
        n_control = int(args.seconds * 30)
        ctl, raw = zip(*(rollout_rates(model, substeps, n_control, rng) for _ in range(args.repeats)))
        rows.append(dict(
            physics_hz=round(1 / dt), substeps=substeps, stands_10s=stands(model),
            mj_step_per_s=round(statistics.median(raw) * substeps),
            control_steps_per_s=round(statistics.median(ctl)),
            ratio_to_raw=round(statistics.median(np.array(ctl) / np.array(raw)), 3),
        ))
    print("| physics | substeps | stands 10 s | mj_step / s | control steps / s | ratio to raw |")
    print("|---|---|---|---|---|---|")
    for r in rows:
        print(f"| 1/{r['physics_hz']} s | {r['substeps']} | {'yes' if r['stands_10s'] else 'no'} | "
              f"{r['mj_step_per_s']:,} | {r['control_steps_per_s']:,} | {r['ratio_to_raw']:.2f} |")
    if args.json:
        args.json.write_text(json.dumps(rows, indent=2))


if __name__ == "__main__":
    main()
