"""The video task's report (SimPoE's tables and PHC's noisy-input robustness), on the same
held-out sequences of corpus:test degraded by the estimator model.

    python benchmarks/videopose_report.py                               # input and tracker rows, robustness
    python benchmarks/videopose_report.py --run simpoe=runs/videopose \\
        --run "no refinement=runs/videopose_no_refinement" --run "no meta-PD=runs/videopose_no_meta_pd" \\
        --run "residual force=runs/videopose_residual_force" --sequences 184 --out docs/results/videopose

Table 1 (default noise, `EstimatorNoise()`): the noisy kinematic input itself; the generalist
tracker (`tracker`, a policy of SMPL/Imitation-v0) following the noisy input as its reference,
PHC's way of using video (VideoPose-v0's first 934 observation columns are Imitation-v0's
observation with the estimate as reference, and its actions are the same residual PD targets);
and every `--run` (a run directory, a checkpoint, or a shipped policy name). Columns: whether the
residual root force was on, no-fall share, MPJPE, PA-MPJPE, Accel, foot sliding, ground
penetration, reprojection error (`smpl_envs.video_metrics`).

Table 2 (PHC's robustness): the tracker's success (mean body distance to the input it follows
never above 0.5 m), no-fall share and E_g-mpjpe against the ground truth (over the successful
sequences, and over all, each up to its fall) as the noise scale grows.

`--sequences N` takes N sequences of corpus:test evenly spaced over its families (all 184 by
default); sequence i of the split gets the estimator stream (seed, i) whatever subset is taken, so
a subset's rows are the full run's rows for those sequences. Writes OUT/videopose_report.json
and prints markdown.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

import smpl_envs
from smpl_envs.motion import load_motions
from smpl_envs.motion.estimator_noise import EstimatorNoise, degrade_clip
from smpl_envs.video_eval import input_result
from smpl_envs.motion.video_input import VideoLib

TRACKER_OBS = 934  # Imitation-v0's observation: the first columns of VideoPose-v0's
COLUMNS = (("no fall", "no_fall", True), ("MPJPE", "mpjpe", False), ("PA-MPJPE", "pa_mpjpe", False),
           ("Accel", "accel", False), ("FS", "foot_sliding", False), ("GP", "ground_penetration", False),
           ("reproj px", "reprojection", False))


def video_input(split: str, indices: np.ndarray, scale: float, seed: int = 0) -> VideoLib:
    """The split's clips `indices` degraded at `scale` x the default noise, clip i of the split
    with the stream (seed, i), as `estimator_noise.degrade_library` seeds the whole split."""
    return VideoLib(degraded(load_motions(split), indices, EstimatorNoise().scaled(scale), seed))


def degraded(lib, indices: np.ndarray, noise: EstimatorNoise, seed: int = 0) -> list:
    """VideoInputs of clips `indices` of `lib` degraded by `noise`, each as in the whole library."""
    return [degrade_clip(lib, i, noise, seed=seed) for i in indices]


def evenly_spaced(n_total: int, n: int | None) -> np.ndarray:
    if n is None or n >= n_total:
        return np.arange(n_total)
    return np.unique(np.linspace(0, n_total - 1, n).round().astype(int))


class TrackerOnVideo:
    """The tracker as a VideoPose-v0 policy: it reads the Imitation-v0 part of the observation."""

    def __init__(self, agent):
        self.agent = agent

    def __call__(self, obs):
        return self.agent.predict(np.asarray(obs)[:, :TRACKER_OBS], deterministic=True)[0]


def cell(x, pct=False) -> str:
    if x is None or (isinstance(x, float) and not np.isfinite(x)):
        return "-"
    return f"{100 * x:.1f} %" if pct else f"{x:.1f}"


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--run", action="append", default=[], metavar="NAME=TARGET",
                        help="a SimPoE policy row: a run directory (its best.pt), a checkpoint or a shipped name")
    parser.add_argument("--tracker", default="tracker", help="the generalist tracker (default: the shipped one)")
    parser.add_argument("--split", default="corpus:test")
    parser.add_argument("--sequences", type=int, default=None, help="evenly spaced sequences of the split (default all)")
    parser.add_argument("--noise-scales", type=float, nargs="+", default=[0.0, 0.5, 1.0, 2.0, 3.0])
    parser.add_argument("--num-envs", type=int, default=16)
    parser.add_argument("--out", type=Path, default=Path("."))
    parser.add_argument("--no-robustness", action="store_true")
    args = parser.parse_args(argv)
    from agents.checkpoint_commands import load_target  # the command line's own lookup of runs and names

    t0 = time.time()
    n_total = load_motions(args.split).num_motions
    indices = evenly_spaced(n_total, args.sequences)
    inputs = {1.0: video_input(args.split, indices, 1.0)}
    tracker = TrackerOnVideo(load_target(args.tracker, "best", "cpu")[0])

    def evaluate(policy, lib):
        return smpl_envs.evaluate(policy, "SMPL/VideoPose-v0", motions=lib, num_envs=args.num_envs, progress=False)

    rows = [("noisy kinematic input", "-", input_result(inputs[1.0]).summary),
            (f"tracker ({args.tracker}) on the noisy input", "off", evaluate(tracker, inputs[1.0]).summary)]
    for spec in args.run:
        name, _, target = spec.partition("=")
        agent = load_target(target or name, "best", "cpu")[0]
        force = "on" if agent.env_kwargs.get("residual_force", False) else "off"
        rows.append((name, force, evaluate(agent, inputs[1.0]).summary))

    n = len(indices)
    lines = [f"**{args.split}, {n} sequences, default estimator noise** (errors pooled over frames, each "
             "sequence up to its fall; the input itself cannot fall)", "",
             "| row | residual force | " + " | ".join(h for h, _, _ in COLUMNS) + " |",
             "|---|---|" + "---|" * len(COLUMNS)]
    for name, force, s in rows:
        no_fall = "-" if name.startswith("noisy kinematic") else cell(s["no_fall"], True)
        lines.append(f"| {name} | {force} | {no_fall} | " + " | ".join(cell(s[k]) for _, k, _ in COLUMNS[1:]) + " |")
    report = {"split": args.split, "indices": indices.tolist(), "rows": [
        {"name": name, "residual_force": force, "summary": s} for name, force, s in rows]}

    if not args.no_robustness:
        lines += ["", f"**PHC's noisy-input robustness: the tracker on {n} sequences**", "",
                  "| noise scale | success | no fall | E_g-mpjpe, successful (mm) | E_g-mpjpe, all (mm) | "
                  "MPJPE, all (mm) |", "|---|---|---|---|---|---|"]
        report["robustness"] = []
        for scale in args.noise_scales:
            lib = inputs.get(scale) or video_input(args.split, indices, scale)
            s = evaluate(tracker, lib).summary
            report["robustness"].append({"noise_scale": scale, "summary": s})
            lines.append(f"| {scale:g} | {cell(s['success_rate'], True)} | {cell(s['no_fall'], True)} | "
                         f"{cell(s['g_mpjpe_success'])} | {cell(s['g_mpjpe'])} | {cell(s['mpjpe'])} |")
    report["seconds"] = time.time() - t0
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "videopose_report.json").write_text(json.dumps(report, indent=1, default=float))
    print("\n".join(lines))
    print(f"\n({report['seconds']:.0f} s; {args.out / 'videopose_report.json'})")


if __name__ == "__main__":
    main()
