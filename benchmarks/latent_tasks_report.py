"""PULSE's claim, measured: each goal task trained in the latent space beside PPO from scratch with
the same budget and seed. Evaluates each run's best checkpoint with its task's own protocol (the
run's evaluation settings, the same for both), prints a markdown table against the targets of
the PULSE issue, and draws each pair's curves side by side against minutes of training.

    python benchmarks/latent_tasks_report.py \
        --pair speed runs/speed_pulse runs/speed_ppo_60 \
        --pair reach runs/reach_pulse runs/reach_ppo_60 ... \
        [--out docs/results] [--num-envs N]

Writes OUT/latent_tasks.json (every evaluation's summary; the tasks it already holds and this call
does not evaluate are kept, so pairs can be run and reported one at a time),
OUT/<task>_latent_vs_scratch.png, and prints the table of every task in the file. A task name
picks its targets (TARGETS); the pair is (latent run, scratch run).
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


def evaluate(run: str, num_envs: int | None) -> dict:
    """The summary of the run's best checkpoint under its task's protocol, with its run's
    evaluation settings (`agents.checkpoint_commands.eval_settings`; its number of worlds too,
    unless `num_envs` is given), as `smpl-envs eval RUN` does."""
    from agents.checkpoint_commands import eval_settings, evaluate_agent, load_target

    agent, ckpt, _, config = load_target(run, "best", "cpu")
    motions, worlds, options = eval_settings(config, num_envs=num_envs)
    result = evaluate_agent(agent, motions, worlds, progress=True, **options)
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
    parser.add_argument("--num-envs", type=int, default=None,
                        help="worlds per evaluation (default: each run's eval.num_envs, as in training)")
    args = parser.parse_args(argv)
    for task, _, _ in args.pair:
        if task not in TARGETS:
            parser.error(f"unknown task {task!r}; tasks with targets: {', '.join(TARGETS)}")
    from agents.plot import plot_runs

    results = {}
    for task, latent, scratch in args.pair:
        results[task] = {"latent": evaluate(latent, args.num_envs), "scratch": evaluate(scratch, args.num_envs)}
        # the targets' metrics and the training episodes (an imitation task logs dozens of columns)
        metrics = [key for key, _, _ in TARGETS[task]] + ["rollout/ep_len_mean", "rollout/ep_rew_mean"]
        png = plot_runs([latent, scratch], args.out / f"{task}_latent_vs_scratch.png",
                        labels=["latent (PULSE)", "scratch (PPO)"], x="minutes", metrics=metrics)
        print(png)
    args.out.mkdir(parents=True, exist_ok=True)
    path = args.out / "latent_tasks.json"
    kept = json.loads(path.read_text()) if path.exists() else {}
    merged = {task: results.get(task, kept.get(task)) for task in TARGETS if task in results or task in kept}
    path.write_text(json.dumps(merged, indent=2) + "\n")
    print(table(merged))


if __name__ == "__main__":
    main()
