"""Where a task step's time goes on the MuJoCo Warp backend: physics against the task code around it.

Builds `gym.make_vec(TASK, num_envs=N, backend="warp", device=...)` with residual actions and
steps it with small random actions drawn on the device. Then, per step (medians over --repeats
runs of --steps steps):

- wall time of the whole step, and of `sim.step` (the physics, its CUDA graph included) timed
  with a device synchronisation on each side; the rest is the task code;
- torch operator calls and host synchronisations (a tensor's truth value, `.item()`,
  `.tolist()`: each makes the host wait for the device), with the source lines that make them;
- the operators that take the most host time (`torch.profiler`), and on CUDA the most device time.

    python benchmarks/profile_step.py --device cuda --worlds 4096
    python benchmarks/profile_step.py --device cpu --worlds 64 --steps 5 --repeats 2

The synchronisations around `sim.step` are the profiler's own, so the whole step is timed in
separate runs without them.
"""

from __future__ import annotations

import argparse
import collections
import json
import statistics
import time
import traceback
from pathlib import Path

import gymnasium as gym
import torch

import smpl_envs  # noqa: F401  (registers the ids)


def sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def step_loop(env, actions, steps: int, device: torch.device) -> float:
    """Seconds per step over `steps` steps."""
    sync(device)
    t0 = time.perf_counter()
    for k in range(steps):
        env.step(actions[k])
    sync(device)
    return (time.perf_counter() - t0) / steps


def physics_share(env, actions, steps: int, device: torch.device) -> float:
    """Seconds per step inside `sim.step`, each call bracketed by device synchronisations."""
    sim, inner, spent = env.sim, env.sim.step, []

    def timed(*args, **kwargs):
        sync(device)
        t0 = time.perf_counter()
        out = inner(*args, **kwargs)
        sync(device)
        spent.append(time.perf_counter() - t0)
        return out

    sim.step = timed
    try:
        step_loop(env, actions, steps, device)
    finally:
        del sim.step  # the instance attribute goes; the class's method shows through again
    return sum(spent) / steps


def host_syncs(env, actions, steps: int) -> collections.Counter:
    """Host synchronisations per source line of smpl_envs over `steps` steps."""
    sites: collections.Counter = collections.Counter()
    originals = {name: getattr(torch.Tensor, name) for name in ("__bool__", "item", "tolist")}

    def where() -> str:
        for frame in reversed(traceback.extract_stack()[:-2]):
            if "smpl_envs" in frame.filename.replace("\\", "/").split("/"):
                return f"{frame.filename.split('smpl_envs')[-1].lstrip('/')}:{frame.lineno}: {frame.line}"
        return "(outside smpl_envs)"

    def counting(name):
        def call(self, *args, **kwargs):
            sites[where()] += 1
            return originals[name](self, *args, **kwargs)
        return call

    for name in originals:
        setattr(torch.Tensor, name, counting(name))
    try:
        for k in range(steps):
            env.step(actions[k])
    finally:
        for name, fn in originals.items():
            setattr(torch.Tensor, name, fn)
    return sites


def profile_ops(env, actions, steps: int, device: torch.device, top: int) -> dict:
    from torch.profiler import ProfilerActivity, profile

    activities = [ProfilerActivity.CPU] + ([ProfilerActivity.CUDA] if device.type == "cuda" else [])
    with profile(activities=activities) as prof:
        for k in range(steps):
            env.step(actions[k])
        sync(device)
    events = [e for e in prof.key_averages() if e.key.startswith("aten::")]
    calls = sum(e.count for e in events) / steps
    by_host = sorted(events, key=lambda e: e.self_cpu_time_total, reverse=True)[:top]
    out = {"op_calls_per_step": calls,
           "top_host": [(e.key, e.count / steps, e.self_cpu_time_total / steps) for e in by_host]}
    if device.type == "cuda":
        device_time = "self_device_time_total" if hasattr(events[0], "self_device_time_total") else "self_cuda_time_total"
        by_device = sorted(events, key=lambda e: getattr(e, device_time), reverse=True)[:top]
        out["top_device"] = [(e.key, e.count / steps, getattr(e, device_time) / steps) for e in by_device]
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--task", default="SMPL/Imitation-v0")
    parser.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    parser.add_argument("--worlds", type=int, default=4096)
    parser.add_argument("--steps", type=int, default=20)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--top", type=int, default=12)
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()

    env = gym.make_vec(args.task, num_envs=args.worlds, backend="warp", device=args.device, action_mode="residual")
    device = env.backend.device
    env.reset(seed=0)
    g = torch.Generator(device=device).manual_seed(0)
    actions = torch.rand(args.steps, args.worlds, env.single_action_space.shape[0], generator=g, device=device)
    actions = actions * 0.2 - 0.1
    step_loop(env, actions, args.steps, device)  # kernels loaded, graphs captured

    whole = statistics.median(step_loop(env, actions, args.steps, device) for _ in range(args.repeats))
    physics = statistics.median(physics_share(env, actions, args.steps, device) for _ in range(args.repeats))
    sites = host_syncs(env, actions, args.steps)
    ops = profile_ops(env, actions, args.steps, device, args.top)
    env.close()

    name = torch.cuda.get_device_name(device) if device.type == "cuda" else "Warp's CPU device"
    print(f"{args.task}, {args.worlds} worlds on {name}; medians of {args.repeats} x {args.steps} steps\n")
    print("| per step | ms |\n|---|---|")
    print(f"| whole step | {1e3 * whole:.2f} |\n| physics (`sim.step`, synchronised) | {1e3 * physics:.2f} |")
    print(f"| the rest: task code, dispatch, waits | {1e3 * max(whole - physics, 0.0):.2f} |\n")
    print(f"torch operator calls per step: {ops['op_calls_per_step']:.0f}; "
          f"host synchronisations per step: {sum(sites.values()) / args.steps:.1f}\n")
    print("| host synchronisations per step | where |\n|---|---|")
    for site, count in sites.most_common():
        print(f"| {count / args.steps:.1f} | `{site}` |")
    for key, title, unit in (("top_host", "host", "self CPU"), ("top_device", "device", "self device")):
        if key in ops:
            print(f"\n| operator (most {title} time) | calls per step | {unit} µs per step |\n|---|---|---|")
            for op, calls, us in ops[key]:
                print(f"| `{op}` | {calls:.1f} | {us:.0f} |")
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps({
            "task": args.task, "worlds": args.worlds, "device": str(device), "device_name": name,
            "step_ms": 1e3 * whole, "physics_ms": 1e3 * physics,
            "host_syncs_per_step": {site: count / args.steps for site, count in sites.items()}, **ops}, indent=1))


if __name__ == "__main__":
    main()
