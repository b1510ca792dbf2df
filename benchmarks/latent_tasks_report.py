"""PULSE's claim, measured: each goal task trained in the latent space beside PPO from scratch with
the same budget and seed. Evaluates each run's best checkpoint with its task's own protocol (the
run's evaluation settings, the same for both), prints a markdown table against the targets of
the PULSE issue, and draws each pair's curves side by side against minutes of training.

    python benchmarks/latent_tasks_report.py \
        --pair speed runs/speed_pulse runs/speed_ppo_60 \
        --pair reach runs/reach_pulse runs/reach_ppo_60 ... \
        [--out docs/results] [--num-envs 16]

Writes OUT/latent_tasks.json (every evaluation's summary), OUT/<task>_latent_vs_scratch.png, and
prints the table. A task name picks its targets (TARGETS); the pair is (latent run, scratch run).
"""

from __future__ import annotations

import argparse
import json
import operator
from pathlib import Path

# The PULSE issue's targets: (summary key, comparison, value).
TARGETS = {
    "speed": [("no_fall", ">=", 0.9), ("speed_error", "<=", 0.4)],
    "reach": [("targets_reached", ">=", 0.6), ("hand_distance", "<=", 0.15)],
    "strike": [("toppled", ">=", 0.5)],
    "terrain": [("no_fall", ">=", 0.5), ("path_error", "<=", 1.0)],
    "vr": [("success_rate", ">=", 0.8)],
}
COMPARE = {">=": operator.ge, "<=": operator.le}


def met(value, comparison: str, target: float) -> bool:
    return value is not None and value == value and COMPARE[comparison](value, target)


def evaluate(run: str, num_envs: int) -> dict:
    """The summary of the run's best checkpoint under its task's protocol, with its run's settings."""
    from agents.run import _load_target, evaluate_agent

    agent, ckpt, _, config = _load_target(run, "best", "cpu")
    ev = (config or {}).get("eval", {})
    result = evaluate_agent(agent, ev.get("motions"), num_envs, progress=True, **dict(ev.get("options") or {}))
    return {"checkpoint": str(ckpt), "timesteps": agent.num_timesteps,
            **{k: float(v) for k, v in result.summary.items() if isinstance(v, (int, float)) and not isinstance(v, bool)}}


def table(results: dict) -> str:
    lines = ["| task | metric | target | latent (PULSE) | scratch (PPO) |", "|---|---|---|---|---|"]
    for task, pair in results.items():
        for key, comparison, target in TARGETS[task]:
            cells = []
            for side in ("latent", "scratch"):
                value = pair[side].get(key)
                text = "-" if value is None else (f"{100 * value:.1f} %" if comparison == ">=" and target <= 1 else
                                                  f"{value:.2f}")
                cells.append(f"**{text}**" if met(value, comparison, target) else text)
            shown = f"{comparison} {100 * target:g} %" if comparison == ">=" and target <= 1 else f"{comparison} {target:g}"
            lines.append(f"| {task} | {key} | {shown} | {cells[0]} | {cells[1]} |")
    lines.append("")
    lines.append("Bold: the target is met. Each run's best checkpoint, its task's protocol with the run's "
                 "evaluation settings.")
    return "\n".join(lines)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--pair", nargs=3, action="append", required=True, metavar=("TASK", "LATENT_RUN", "SCRATCH_RUN"))
    parser.add_argument("--out", type=Path, default=Path("."))
    parser.add_argument("--num-envs", type=int, default=16)
    args = parser.parse_args(argv)
    for task, _, _ in args.pair:
        if task not in TARGETS:
            parser.error(f"unknown task {task!r}; tasks with targets: {', '.join(TARGETS)}")
    from agents.plot import plot_runs

    results = {}
    for task, latent, scratch in args.pair:
        results[task] = {"latent": evaluate(latent, args.num_envs), "scratch": evaluate(scratch, args.num_envs)}
        png = plot_runs([latent, scratch], args.out / f"{task}_latent_vs_scratch.png",
                        labels=["latent (PULSE)", "scratch (PPO)"], x="minutes")
        print(png)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "latent_tasks.json").write_text(json.dumps(results, indent=2) + "\n")
    print(table(results))


if __name__ == "__main__":
    main()
