"""Learning curves of a run: its logs/progress.csv drawn as a grid of panels in one PNG; and
several runs on shared panels, one colour a run, to compare recipes on the same task.

    from agents.plot import plot_run, plot_runs
    plot_run("runs/imitation_ppo-20250101-120000")       # -> runs/.../curves.png
    plot_runs(["runs/speed_pulse", "runs/speed_ppo"], "speed.png", labels=["PULSE", "scratch"], x="minutes")

Only the panels the logs have data for are drawn, so the same functions serve PPO and AMP runs,
runs with or without evaluation, and a run that has only logged its first row. A comparison
draws the evaluation columns and the episode statistics against timesteps or against minutes
of training (summed over the segments of a resumed run): agents that pay differently per sample
(PULSE's task policies decode every action) are compared at equal wall-clock budgets so.

A run trained in stages, each started from the one before with `--init` (whose step count starts
again at 0), is drawn as one curve by naming its directories joined with commas,
`runs/stage1,runs/stage2`: each stage's steps continue from where the one before ended.
"""
from __future__ import annotations

import csv
import math
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

X_KEY = "time/total_timesteps"
CSV_NAME = "progress.csv"


class EmptyLogError(ValueError):
    """The progress CSV exists but holds no rows to plot."""


@dataclass
class Panel:
    """One subplot: (column, legend label) pairs on the left axis and, for series of another
    scale, on a right axis."""

    title: str
    ylabel: str
    left: list[tuple[str, str]]
    right: list[tuple[str, str]] = field(default_factory=list)
    right_label: str = ""
    log: bool = False  # log y axis, for quantities whose rare spikes would flatten the rest
    fraction: bool = False  # left axis holds fractions: fix it to [0, 1] (a flat 1.0 stays readable)


def find_progress_csv(run_dir_or_csv: str | os.PathLike) -> Path:
    """The progress CSV of a run directory (<run>/logs/progress.csv), of a log directory, or a
    CSV path as is."""
    path = Path(run_dir_or_csv)
    if path.is_dir():
        for candidate in (path / "logs" / CSV_NAME, path / CSV_NAME):
            if candidate.is_file():
                return candidate
        raise FileNotFoundError(f"no {CSV_NAME} in {path} or {path / 'logs'}")
    if not path.is_file():
        raise FileNotFoundError(f"no progress CSV at {path}")
    return path


def run_stages(run: str | os.PathLike) -> list[str]:
    """The stage paths of a run named with commas (module docstring), or [run] for one path."""
    if "," not in str(run) or Path(run).exists():
        return [str(run)]
    stages = [s.strip() for s in str(run).split(",")]
    if not all(stages):
        raise ValueError(f"{run!r}: an empty stage; join run directories with commas, e.g. runs/a,runs/b")
    return stages


def run_name(run: str | os.PathLike) -> str:
    """A run's name for titles and legends: its directory's, or its stages' joined with " + "."""
    return " + ".join(Path(stage).name for stage in run_stages(run))


def read_run(run: str | os.PathLike) -> tuple[dict[str, np.ndarray], Path]:
    """The progress columns of a run (a directory or CSV), or of stages joined with commas (module
    docstring): each stage's steps follow on from the last step of the one before. Returns the
    columns and the last stage's CSV path."""
    parts, offset = [], 0.0
    for stage in run_stages(run):
        csv_path = find_progress_csv(stage)
        columns = read_progress(csv_path)
        if X_KEY not in columns:
            raise EmptyLogError(f"{csv_path} has no {X_KEY} column")
        columns[X_KEY] = columns[X_KEY] + offset
        offset = float(np.nanmax(columns[X_KEY]))
        parts.append(columns)
    keys = sorted({k for c in parts for k in c})
    rows = [len(c[X_KEY]) for c in parts]
    joined = {k: np.concatenate([c.get(k, np.full(n, math.nan)) for c, n in zip(parts, rows)]) for k in keys}
    return joined, csv_path


def read_progress(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Every column of a progress CSV as a float array; empty or non-numeric cells are NaN
    (the logger adds columns as keys first appear, so early rows have gaps)."""
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    if not rows:
        raise EmptyLogError(f"{path} has no rows yet; train for at least one iteration first")
    columns = {k for row in rows for k in row if k is not None}
    return {k: np.array([_number(row.get(k)) for row in rows]) for k in sorted(columns)}


def _number(cell: str | None) -> float:
    try:
        return float(cell)
    except (TypeError, ValueError):
        return math.nan


def panels_for(columns: dict[str, np.ndarray]) -> list[Panel]:
    """The panels worth drawing for these columns, in reading order."""
    has = lambda k: k in columns and np.isfinite(columns[k]).any()  # noqa: E731
    reward_terms = sorted(k for k in columns if k.startswith("rollout/reward_") and has(k))
    # An imitation evaluation logs `score` only to rank checkpoints (success rate less 1e-6 x
    # error): its errors are the curve to read, so the goal tasks' panel leaves the score out.
    imitation = has("eval/mpjpe_g") or has("eval/all_mpjpe_g")
    candidates = [
        Panel("Episode length", "steps", [("rollout/ep_len_mean", "mean episode length")]),
        Panel("Episode return", "return", [("rollout/ep_rew_mean", "mean episode return")]),
        Panel("Reward terms", "reward per step",
              [(k, k.removeprefix("rollout/reward_")) for k in reward_terms]
              + [("rollout/step_reward_mean", "total (as trained on)")]),
        Panel("Evaluation", "success rate", [("eval/success_rate", "success rate")],
              [("eval/mpjpe_g", "MPJPE-g (successful clips)"), ("eval/all_mpjpe_g", "MPJPE-g (all clips)")],
              "mm", fraction=True),
        # Goal tasks' episode evaluations: fractions on the left, distances and errors on the right.
        Panel("Task evaluation", "fraction / score",
              ([] if imitation else [("eval/score", "score (reward per step over 10 s)")])
              + [("eval/no_fall", "episodes without a fall"),
                 ("eval/toppled", "boxes toppled"), ("eval/targets_reached", "targets reached")],
              [("eval/speed_error", "speed error (m/s)"), ("eval/hand_distance", "hand distance (m)")], "m/s, m"),
        Panel("Adversarial motion prior", "reward / accuracy",
              [("amp/style_reward_mean", "style reward"), ("amp/task_reward_mean", "task reward"),
               ("amp/disc_agent_acc", "D accuracy on policy"), ("amp/disc_demo_acc", "D accuracy on demo")]),
        # The value loss is often orders of magnitude above the policy loss: give it its own axis.
        Panel("Losses", "policy loss", [("train/policy_loss", "policy loss")],
              [("train/value_loss", "value loss")], "value loss"),
        Panel("Update size", "", [("train/approx_kl", "approx. KL"), ("train/clip_fraction", "clip fraction")],
              log=True),
        # PULSE's distillation: the action error against the teacher falls by orders of magnitude,
        # and the KL to the prior measures how much the latent carries: both need a log axis.
        Panel("Distillation", "action error, KL (per dimension)",
              [("train/action_loss", "action error vs teacher"), ("train/kl", "KL(E || R)")],
              [("train/kl_weight", "KL weight"), ("train/encoder_std", "encoder std")], "weight, std", log=True),
        Panel("Throughput", "env steps / s", [("time/fps", "fps")]),
    ]
    out = []
    for panel in candidates:
        panel.left = [(k, label) for k, label in panel.left if has(k)]
        panel.right = [(k, label) for k, label in panel.right if has(k)]
        if panel.left or panel.right:
            out.append(panel)
    return out


def plot_run(run_dir_or_csv: str | os.PathLike, out: str | os.PathLike | None = None, dpi: int = 110) -> Path:
    """Draw the learning curves of a run (or of stages joined with commas) to `out` (default:
    <run>/curves.png, the last stage's); returns the path."""
    columns, csv_path = read_run(run_dir_or_csv)
    run_dir = csv_path.parent.parent if csv_path.parent.name == "logs" else csv_path.parent
    out = Path(out) if out is not None else run_dir / "curves.png"

    # A resumed run may repeat steps after an interrupt; a stable sort keeps each line drawable.
    order = np.argsort(columns[X_KEY], kind="stable")
    columns = {k: v[order] for k, v in columns.items()}
    panels = panels_for(columns)
    if not panels:
        raise EmptyLogError(f"{csv_path} has no column with data to plot")

    fig, axes = _grid(len(panels), 3.6)
    x = columns[X_KEY]
    lo, hi = np.nanmin(x), np.nanmax(x)
    for ax, panel in zip(axes, panels):
        _draw(ax, panel, columns)
        # One time axis for all panels, also for sparse ones (evaluations) that would zoom in.
        if hi > lo:
            ax.set_xlim(lo - 0.02 * (hi - lo), hi + 0.02 * (hi - lo))
    name = run_name(run_dir_or_csv) if len(run_stages(run_dir_or_csv)) > 1 else run_dir.name
    fig.suptitle(f"{name}: {int(hi):,} timesteps")
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=dpi)
    return out


def _grid(n: int, height: float):
    """A figure of n panels, three to a row, and its n axes (the grid's spare cells hidden)."""
    # Figure without pyplot: no global backend switch, nothing left open, safe in threads.
    from matplotlib.figure import Figure

    ncols = min(3, n)
    nrows = math.ceil(n / ncols)
    fig = Figure(figsize=(5.2 * ncols, height * nrows))
    axes = np.atleast_1d(fig.subplots(nrows, ncols, squeeze=False)).ravel()
    for ax in axes[n:]:
        ax.set_visible(False)
    return fig, axes[:n]


def _draw(ax, panel: Panel, columns: dict[str, np.ndarray]) -> None:
    x = columns[X_KEY]
    lines = _plot_series(ax, x, columns, panel.left, style="-", colors=0)
    ax.set_title(panel.title)
    ax.set_xlabel("timesteps")
    ax.set_ylabel(panel.ylabel)
    ax.grid(alpha=0.3)
    ax.ticklabel_format(axis="x", style="sci", scilimits=(-3, 4))
    if panel.log:
        ax.set_yscale("log")
    if panel.fraction:
        ax.set_ylim(-0.03, 1.03)
    if panel.right:
        twin = ax.twinx()
        lines += _plot_series(twin, x, columns, panel.right, style="--", colors=len(panel.left))
        twin.set_ylabel(panel.right_label)
    if len(lines) > 1 or panel.right:
        ax.legend(lines, [line.get_label() for line in lines], fontsize="small", loc="best")


def _plot_series(ax, x, columns, series, style: str, colors: int) -> list:
    lines = []
    for i, (key, label) in enumerate(series):
        y = columns[key]
        keep = np.isfinite(x) & np.isfinite(y)
        # Sparse series (evaluations, short runs) get markers, or a single point would be invisible.
        marker = "o" if keep.sum() < 30 else None
        color = f"C{colors + i}"
        xs, ys = x[keep], y[keep]
        window = len(ys) // 60
        if window >= 3:  # long, noisy runs: the raw series faint, a running mean on top
            ax.plot(xs, ys, style, color=color, alpha=0.25, linewidth=0.8)
            ys = np.convolve(ys, np.ones(window) / window, mode="same")
            xs, ys = xs[window // 2: len(xs) - window // 2], ys[window // 2: len(ys) - window // 2]
        (line,) = ax.plot(xs, ys, style, marker=marker, markersize=3, label=label, color=color)
        lines.append(line)
    return lines


# ---------------------------------------------------------------------------------------- comparisons
X_AXES = {"timesteps": (X_KEY, "timesteps"), "minutes": ("time/elapsed_s", "minutes of training")}
# Columns a comparison draws by default: every evaluation column but the variants of the same
# figure (over all clips, per-clip means), counts of trials (settings, not results) and final
# distances, with the ranking score only where there is no success rate; and the episode
# statistics. `metrics=` draws others.
COMPARED = ("rollout/ep_len_mean", "rollout/ep_rew_mean")
LEFT_OUT = ("eval/all_", "eval/clip_mean_", "eval/trials", "eval/final_distance")
FRACTIONS = ("success_rate", "no_fall", "toppled", "targets_reached", "succ_")
UNITS = {"mpjpe": "mm", "accel": "mm/frame²", "vel": "mm/frame", "speed_error": "m/s", "hand_distance": "m",
         "path_error": "m", "final_distance": "m", "ep_len_mean": "steps"}


def compared_columns(logs: list[dict[str, np.ndarray]]) -> list[str]:
    """The columns a comparison of runs with these logs draws by default (comment above)."""
    has = lambda k: any(k in c and np.isfinite(c[k]).any() for c in logs)  # noqa: E731
    keys = sorted({k for c in logs for k in c if k.startswith("eval/") and not k.startswith(LEFT_OUT) and has(k)})
    if "eval/success_rate" in keys:
        keys.remove("eval/score") if "eval/score" in keys else None
        keys.remove("eval/success_rate")
        keys.insert(0, "eval/success_rate")
    return keys + [k for k in COMPARED if has(k)]


def training_minutes(elapsed: np.ndarray) -> np.ndarray:
    """Minutes of training at each row from the logged `time/elapsed_s`, which starts again at 0
    when a run is resumed: each segment continues from where the one before ended."""
    out = np.array(elapsed, float)
    offset, last = 0.0, 0.0
    for i, e in enumerate(out):
        if not np.isfinite(e):
            continue
        if e < last:  # a new segment
            offset += last
        last = e
        out[i] = e + offset
    return out / 60.0


def plot_runs(runs, out: str | os.PathLike, labels=None, x: str = "timesteps", metrics=None,
              dpi: int = 110) -> Path:
    """Draw several runs' evaluation and episode curves on shared panels (module docstring) to
    `out`; `labels`: one per run (default: the run directories' names); `x`: "timesteps" or
    "minutes"; `metrics`: the columns to draw ("eval/no_fall" or just "no_fall"; default
    `compared_columns`). Returns the path."""
    runs = [str(r) for r in runs]
    if len(runs) < 2:
        raise ValueError("a comparison needs at least two runs")
    labels = [run_name(r) for r in runs] if labels is None else list(labels)
    if len(labels) != len(runs):
        raise ValueError(f"{len(labels)} label(s) for {len(runs)} runs; give one label a run")
    if x not in X_AXES:
        raise ValueError(f"x must be one of {sorted(X_AXES)}, got {x!r}")
    x_key, x_label = X_AXES[x]
    logs = []
    for run in runs:
        columns, csv_path = read_run(run)
        if x_key not in columns:
            raise EmptyLogError(f"{csv_path} has no {x_key} column")
        xs = training_minutes(columns[x_key]) if x == "minutes" else columns[x_key]
        order = np.argsort(xs, kind="stable")  # a resumed run may repeat steps (plot_run)
        logs.append((xs[order], {k: v[order] for k, v in columns.items()}))
    if metrics:
        known = sorted({k for _, c in logs for k in c})
        keys = []
        for m in metrics:
            key = m if m in known else f"eval/{m}"
            if key not in known:
                raise ValueError(f"no run logged {m!r}; evaluation columns: "
                                 f"{', '.join(k[5:] for k in known if k.startswith('eval/')) or 'none yet'}")
            keys.append(key)
    else:
        keys = compared_columns([c for _, c in logs])
    if not keys:
        raise EmptyLogError(f"none of {', '.join(map(str, runs))} has logged an evaluation or an episode yet")
    fig, axes = _grid(len(keys), 3.4)
    for ax, key in zip(axes, keys):
        for i, ((xs, columns), label) in enumerate(zip(logs, labels)):
            if key in columns:
                _plot_series(ax, xs, columns, [(key, label)], style="-", colors=i)
        name = key.split("/", 1)[1]
        ax.set_title(name)
        ax.set_xlabel(x_label)
        ax.grid(alpha=0.3)
        if x == "timesteps":
            ax.ticklabel_format(axis="x", style="sci", scilimits=(-3, 4))
        if any(name.startswith(f) for f in FRACTIONS):
            ax.set_ylim(-0.03, 1.03)
            ax.set_ylabel("fraction")
        else:
            ax.set_ylabel(next((u for k, u in UNITS.items() if k in name), ""))
        ax.legend(fontsize="small", loc="best")
    fig.suptitle(" vs ".join(labels))
    fig.tight_layout(rect=(0, 0, 1, 1 - 0.3 / fig.get_figheight()))  # room for the title
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=dpi)
    return out


__all__ = ["plot_run", "plot_runs", "compared_columns", "training_minutes", "read_progress", "read_run", "find_progress_csv", "panels_for",
           "EmptyLogError"]
