"""Physics-level throughput of the MuJoCo Warp backend against the number of worlds.

For each world count N it builds `WarpSim(model, N, substeps=4, device)`, places the worlds at
random frames of the shipped walk clip, and times `--steps` control steps whose PD targets track
the clip (the actions live on the device, so the loop has no host round trip); the figure is env
steps / s = control steps x N / seconds, 4 physics substeps each included. The CPU backend
(`CPUSim`, one thread per core) runs the same actions at the same N for reference (`--cpu-max`
caps it: past that N the column shows "-"). Medians over `--repeats`; the device's name and the
first-call time (kernel loading, CUDA graph capture) are printed with a Markdown table.

Then the whole task on the backend, for each N: `gym.make_vec("SMPL/Imitation-v0", num_envs=N,
backend="warp", device=...)` stepped with random residual actions drawn on the device
(observation, reward, termination, resets and `info` included: what a learner sees), and PPO
training samples/s on that env (the `imitation_ppo` recipe's agent, with its `paper` profile's
minibatch and networks on CUDA; rollout collection + update, after one untimed iteration).
`--no-task` and `--no-train` skip these.

    python benchmarks/bench_warp.py                           # CUDA: 1024 .. 16384 worlds
    python benchmarks/bench_warp.py --device cpu --worlds 16 64 --steps 10 --repeats 3
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import time
from pathlib import Path

import gymnasium as gym
import numpy as np
import torch
import warp as wp

import smpl_envs  # noqa: F401  (registers the ids)

from smpl_envs.humanoid import build_humanoid
from smpl_envs.motion.library import MotionLib
from smpl_envs.sim import CPUSim, WarpSim

SUBSTEPS = 4


def device_name(device: str) -> str:
    if device.startswith("cuda"):
        return torch.cuda.get_device_name(torch.device(device))
    try:
        with open("/proc/cpuinfo") as f:
            model = next(line.split(":", 1)[1].strip() for line in f if line.startswith("model name"))
    except (OSError, StopIteration):
        model = platform.processor() or platform.machine()
    return f"{model} ({os.cpu_count()} cores)"


def workload(lib: MotionLib, n: int, steps: int, seed: int = 0):
    """Start states of n worlds at random walk frames and, per control step, the clip's next
    frame as PD targets: (qpos (n, nq), qvel, targets (steps, n, 69))."""
    rng = np.random.default_rng(seed)
    start = rng.integers(0, lib.lengths[0] - 1, n)
    q, v = lib.qpos_qvel(start)
    frames = np.minimum(start[None] + np.arange(1, steps + 1)[:, None], lib.lengths[0] - 1)
    targets = lib.qpos_qvel(frames.ravel())[0][:, 7:].reshape(steps, n, -1)
    return q, v, targets


def time_warp(sim: WarpSim, q, v, targets, sync) -> float:
    sim.set_state(np.arange(sim.num_worlds), q, v)
    ctrl = torch.as_tensor(targets, dtype=torch.float32, device=sim.device)
    sync()
    t = time.perf_counter()
    for c in ctrl:
        sim.step(c)
    sync()
    return len(ctrl) * sim.num_worlds / (time.perf_counter() - t)


def time_cpu(sim: CPUSim, q, v, targets) -> float:
    sim.set_state(np.arange(sim.num_worlds), q, v)
    t = time.perf_counter()
    for c in targets:
        sim.step(c)
    return len(targets) * sim.num_worlds / (time.perf_counter() - t)


def time_task(env, steps: int, sync) -> float:
    """Env steps/s of the whole task (all worlds counted), random residual actions on the device."""
    g = torch.Generator(env.backend.device).manual_seed(0)
    actions = torch.rand(steps, env.num_envs, 69, generator=g, device=env.backend.device) * 0.5 - 0.25
    sync()
    t = time.perf_counter()
    for a in actions:
        env.step(a)
    sync()
    return steps * env.num_envs / (time.perf_counter() - t)


def time_training(env, cuda: bool, iterations: int, sync) -> float:
    """PPO samples/s on `env` over `iterations` whole iterations, after one untimed."""
    from agents.recipes import load_recipe
    from agents.run import new_agent

    recipe = load_recipe("imitation_ppo", profile="paper" if cuda else None)
    hp = recipe["agent"]["hyperparams"]
    hp["batch_size"] = min(hp["batch_size"], hp["n_steps"] * env.num_envs)
    agent = new_agent(recipe, env=env, device=env.backend.device, verbose=0, tensorboard=False, seed=0)
    per = agent.config.n_steps * env.num_envs
    agent.learn(per, progress_bar=False)
    sync()
    t = time.perf_counter()
    agent.learn(iterations * per, progress_bar=False, reset_num_timesteps=False)
    sync()
    return iterations * per / (time.perf_counter() - t)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    parser.add_argument("--worlds", type=int, nargs="+", help="world counts (default: 1024..16384 on CUDA, 16..256 on the CPU)")
    parser.add_argument("--steps", type=int, default=60, help="control steps per repeat (2 s of motion)")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--cpu-max", type=int, default=4096, help="largest N the CPU backend is timed at")
    parser.add_argument("--json", type=Path)
    parser.add_argument("--no-task", action="store_true", help="skip the whole-task (SMPL/Imitation-v0) rates")
    parser.add_argument("--no-train", action="store_true", help="skip PPO's training rate")
    parser.add_argument("--train-iterations", type=int, default=3, help="timed PPO iterations")
    args = parser.parse_args()
    for name in ("steps", "repeats"):
        if getattr(args, name) < 1:
            parser.error(f"--{name} must be >= 1")
    cuda = args.device.startswith("cuda")
    worlds = args.worlds or ([1024, 2048, 4096, 8192, 16384] if cuda else [16, 64, 256])
    if min(worlds) < 1:
        parser.error("--worlds must be positive")
    sync = (lambda: torch.cuda.synchronize(args.device)) if cuda else (lambda: None)

    wp.config.quiet = True  # no line per kernel module loaded
    model, lib = build_humanoid(), MotionLib.load("walk")
    print(f"device: {args.device} = {device_name(args.device)}; CPU backend: {device_name('cpu')}")
    rows = []
    for n in worlds:
        q, v, targets = workload(lib, n, args.steps)
        t = time.perf_counter()
        sim = WarpSim(model, n, SUBSTEPS, device=args.device)
        sync()
        setup = time.perf_counter() - t
        time_warp(sim, q, v, targets[:2], sync)  # first steps outside the timing
        warp_rate = statistics.median(time_warp(sim, q, v, targets, sync) for _ in range(args.repeats))
        fell = int((sim.qpos[:, 2] < 0.5).sum())
        sim.close()
        cpu_rate = None
        if n <= args.cpu_max:
            cpu = CPUSim(model, n, SUBSTEPS)
            cpu_rate = statistics.median(time_cpu(cpu, q, v, targets) for _ in range(args.repeats))
            cpu.close()
        task_rate = train_rate = None
        if not args.no_task:
            env = gym.make_vec("SMPL/Imitation-v0", num_envs=n, motions="walk", action_mode="residual",
                               backend="warp", device=args.device)
            env.reset(seed=0)
            time_task(env, 2, sync)
            task_rate = statistics.median(time_task(env, args.steps, sync) for _ in range(args.repeats))
            if not args.no_train:
                train_rate = time_training(env, cuda, args.train_iterations, sync)
            env.close()
        rows.append(dict(worlds=n, warp_env_steps_per_s=round(warp_rate), warp_physics_steps_per_s=round(warp_rate * SUBSTEPS),
                         cpu_env_steps_per_s=None if cpu_rate is None else round(cpu_rate), setup_s=round(setup, 1),
                         fallen_at_end=fell, task_steps_per_s=None if task_rate is None else round(task_rate),
                         ppo_samples_per_s=None if train_rate is None else round(train_rate)))
        print(f"  N={n}: physics {warp_rate:,.0f} env steps/s (setup {setup:.1f} s)"
              + ("" if task_rate is None else f", Imitation-v0 {task_rate:,.0f} steps/s")
              + ("" if train_rate is None else f", PPO {train_rate:,.0f} samples/s"), flush=True)

    print(f"\nMuJoCo Warp on {device_name(args.device)}; {SUBSTEPS} substeps of 1/120 s per env step; "
          f"median of {args.repeats} x {args.steps} steps\n")
    print("| worlds | Warp env steps/s (physics) | Warp physics steps/s | CPU backend env steps/s | Warp / CPU "
          "| Imitation-v0 steps/s (whole task) | PPO samples/s | setup (s) |")
    print("|---|---|---|---|---|---|---|---|")
    fmt = lambda x: "-" if x is None else f"{x:,}"  # noqa: E731
    for r in rows:
        c = r["cpu_env_steps_per_s"]
        ratio = "-" if c is None else f"{r['warp_env_steps_per_s'] / c:.2f}"
        print(f"| {r['worlds']:,} | {r['warp_env_steps_per_s']:,} | {r['warp_physics_steps_per_s']:,} | "
              f"{fmt(c)} | {ratio} | {fmt(r['task_steps_per_s'])} | {fmt(r['ppo_samples_per_s'])} | {r['setup_s']} |")
    if args.json:
        args.json.write_text(json.dumps(dict(device=args.device, device_name=device_name(args.device), rows=rows), indent=2))


if __name__ == "__main__":
    main()
