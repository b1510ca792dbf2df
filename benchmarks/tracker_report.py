"""The generalist tracker's report: PHC's evaluation (every clip once from its first frame) on
both corpus splits and the shipped clips, per family, with the clips that still fail and where.

    python benchmarks/tracker_report.py CHECKPOINT_OR_RUN [--out DIR] [--num-envs 16]

Writes DIR/tracker_<split>.json (every clip's row and the per-family summaries) and prints
markdown tables: per family success, E_g-mpjpe, E_mpjpe, E_acc, E_vel (frame-weighted over the
successful clips, PHC's form) and the failing clips with the frame at which each failed.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import smpl_envs
from smpl_envs.metrics import summarize
from smpl_envs.motion import corpus
from smpl_envs.motion.library import available_clips

SPLITS = {"train": "corpus:train", "test": "corpus:test", "clips": available_clips()}
METRICS = (("mpjpe_g", "E_g-mpjpe"), ("mpjpe_l", "E_mpjpe"), ("accel", "E_acc"), ("vel", "E_vel"))


def family_of(name: str) -> str:
    return corpus.family_of(name) or name  # a shipped clip is its own family


def per_family(rows: list[dict]) -> list[dict]:
    groups: dict[str, list[dict]] = {}
    for row in rows:
        groups.setdefault(family_of(row["name"]), []).append(row)
    return [{"family": fam, **summarize(group)} for fam, group in groups.items()]


def markdown(title: str, families: list[dict], total: dict) -> str:
    def cell(x):
        return "-" if x is None or x != x else f"{x:.1f}"  # undefined (no clip succeeded): "-"
    head = "| family | clips | success | " + " | ".join(label for _, label in METRICS) + " |"
    lines = [f"**{title}**", "", head, "|" + "---|" * (3 + len(METRICS))]
    for row in families + [{"family": "**all**", **total}]:
        lines.append(f"| {row['family']} | {row['clips']} | {100 * row['success_rate']:.1f} % | "
                     + " | ".join(cell(row[key]) for key, _ in METRICS) + " |")
    return "\n".join(lines)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("target", help="a checkpoint, a run directory (its best.pt) or a shipped policy name")
    parser.add_argument("--out", type=Path, default=Path("."))
    parser.add_argument("--num-envs", type=int, default=16)
    parser.add_argument("--splits", nargs="+", choices=list(SPLITS), default=list(SPLITS))
    args = parser.parse_args(argv)
    from agents.checkpoint_commands import load_target  # the command line's own lookup of runs and names

    agent, ckpt, _, _ = load_target(args.target, "best", "cpu")
    args.out.mkdir(parents=True, exist_ok=True)
    for split in args.splits:
        result = smpl_envs.evaluate(agent, agent.env_id, motions=SPLITS[split], num_envs=args.num_envs)
        rows = result.rows
        families = per_family(rows)
        total = summarize(rows)
        (args.out / f"tracker_{split}.json").write_text(json.dumps(
            {"checkpoint": str(ckpt), "motions": SPLITS[split], "summary": total, "families": families,
             "clips": rows}, indent=1, default=float))
        print(markdown(f"{split} ({ckpt.name})", families, total), "\n")
        failed = [r for r in rows if not r["success"]]
        if failed:
            print("| failing clip | failed at frame |\n|---|---|")
            for r in failed:
                print(f"| {r['name']} | {r['fail_frame']} |")
            print()


if __name__ == "__main__":
    main()
