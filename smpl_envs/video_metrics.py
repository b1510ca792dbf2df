"""SimPoE's metrics for motion from video (Yuan et al. 2021), in numpy, per sequence and pooled.

Inputs of one sequence of T frames at 30 fps: body positions (T, 24, 3) of the motion measured
(`sim`: the simulated humanoid, or the kinematic input itself), of the ground truth where it is
known, and of the input the motion followed; foot sample points (T, P, 3); the per-frame
confidence-weighted reprojection error and its weight. World frame, metres; errors in mm (px for
the reprojection error).

Definitions
-----------
MPJPE       root-relative mean per-joint position error against the ground truth (mm): each
            trajectory minus its own pelvis per frame, then the mean over frames and the 24 bodies
            of the Euclidean distance (`smpl_envs.metrics.mpjpe_local`; SimPoE's root-centred MPJPE).
PA-MPJPE    the same after a per-frame similarity (Procrustes) alignment (`metrics.mpjpe_pa`).
E_g-mpjpe   the global mean per-joint position error (`metrics.mpjpe_global`).
Accel       acceleration error, mm/frame^2: second differences of the global positions, not
            divided by dt^2 (`metrics.accel_error`, PHC's E_acc).
FS          foot sliding, mm: the mean horizontal displacement between adjacent frames of the foot
            points in ground contact at both frames (height below CONTACT_HEIGHT), pooled over
            every such (point, frame pair). The approximation: SimPoE measures the SMPL mesh's
            contact vertices; here the foot points are the 32 corners of the humanoid's four foot
            boxes (`video_features.foot_points`), the foot geometry it actually stands on.
GP          ground penetration, mm: per frame, how far the lowest foot point is below the floor
            (0 when none is), averaged over frames (SimPoE: the depth of the vertices below the
            ground; the same foot points stand for them).
reprojection  2D reprojection error, px: sum over frames and keypoints of c ||proj(X) - x|| over
            the sum of the confidences c (a keypoint not detected weighs 0).
no fall     the sequence ran to its end without a fall (`envs.base.fallen`) or a divergence. A
            fall ends the sequence: every error above is over the frames before it.
success     PHC's tracking success against the input the motion followed: the mean body distance
            never exceeds `threshold` (0.5 m). Used for the noisy-input robustness table.

Without ground truth MPJPE, PA-MPJPE, E_g-mpjpe and Accel are undefined (NaN); FS, GP, the
reprojection error and no fall are still measured.

Aggregates (`summarize`): no_fall and success_rate are shares of sequences; every error is pooled
over the frames (or contacts, or confidences) of all sequences, so a long sequence weighs more
(as `metrics.summarize` does); `g_mpjpe_success` is E_g-mpjpe over the successful sequences only
(PHC's reporting).
"""

from __future__ import annotations

import math

import numpy as np

from . import metrics

MM = 1000.0
CONTACT_HEIGHT = 0.02  # m: a foot point this close to the floor (or below it) is in contact
ERRORS = ("mpjpe", "pa_mpjpe", "g_mpjpe", "accel", "foot_sliding", "ground_penetration", "reprojection")
# The row key holding each error's weight in the pooled aggregate.
WEIGHTS = {"mpjpe": "frames", "pa_mpjpe": "frames", "g_mpjpe": "frames", "accel": "frames_acc",
           "foot_sliding": "contacts", "ground_penetration": "frames", "reprojection": "keypoint_weight",
           "g_mpjpe_input": "frames"}


def foot_sliding(points) -> tuple[float, int]:
    """(FS in mm, number of contact (point, frame pair) instances) of foot points (T, P, 3);
    NaN for a sequence without any contact."""
    p = np.asarray(points, float)
    if len(p) < 2:
        return math.nan, 0
    low = p[..., 2] < CONTACT_HEIGHT
    contact = low[1:] & low[:-1]
    n = int(contact.sum())
    if n == 0:
        return math.nan, 0
    step = np.linalg.norm(p[1:, :, :2] - p[:-1, :, :2], axis=-1)
    return float(step[contact].sum() / n * MM), n


def ground_penetration(points) -> float:
    """GP in mm of foot points (T, P, 3): the mean over frames of max(0, -lowest height)."""
    p = np.asarray(points, float)
    return float(np.maximum(-p[..., 2].min(-1), 0.0).mean() * MM)


def fall_frame(fallen) -> int:
    """The first frame flagged in `fallen` (T,), or -1."""
    idx = np.flatnonzero(np.asarray(fallen, bool))
    return int(idx[0]) if idx.size else -1


def sequence_metrics(sim, followed, foot, reproj, reproj_weight, truth=None, fell: bool = False,
                     threshold: float = 0.5) -> dict:
    """One sequence's row (module docstring): `sim`, `followed`, `truth` (T, 24, 3) or None,
    `foot` (T, P, 3), `reproj` (T,) per-frame confidence-weighted reprojection error (px) with
    its weights `reproj_weight` (T,); `fell`: the sequence ended in a fall or divergence."""
    sim, followed = np.asarray(sim, float), np.asarray(followed, float)
    t = len(sim)
    dist = metrics.body_distance(sim, followed)
    over = np.flatnonzero(dist > threshold)
    w = np.asarray(reproj_weight, float)
    fs, contacts = foot_sliding(foot)
    row = {"frames": t, "fell": bool(fell), "success": not over.size and not fell,
           "fail_frame": int(over[0]) if over.size else (t - 1 if fell else -1),
           "foot_sliding": fs, "contacts": contacts, "ground_penetration": ground_penetration(foot),
           "reprojection": float((np.asarray(reproj, float) * w).sum() / w.sum()) if w.sum() > 0 else math.nan,
           "keypoint_weight": float(w.sum()), "frames_acc": max(t - 2, 0),
           "g_mpjpe_input": metrics.mpjpe_global(sim, followed)}
    if truth is None:
        row.update(mpjpe=math.nan, pa_mpjpe=math.nan, g_mpjpe=math.nan, accel=math.nan)
    else:
        truth = np.asarray(truth, float)
        row.update(mpjpe=metrics.mpjpe_local(sim, truth), pa_mpjpe=metrics.mpjpe_pa(sim, truth),
                   g_mpjpe=metrics.mpjpe_global(sim, truth), accel=metrics.accel_error(sim, truth))
    return row


def pooled(rows: list[dict], key: str) -> float:
    """The rows' `key` pooled by its weight (WEIGHTS); NaN values and zero weights skipped."""
    pairs = [(float(r.get(key, math.nan)), float(r.get(WEIGHTS[key], 0))) for r in rows]
    pairs = [(e, n) for e, n in pairs if not math.isnan(e) and n > 0]
    if not pairs:
        return math.nan
    e, n = np.array(pairs).T
    return float((e * n).sum() / n.sum())


def summarize(rows: list[dict]) -> dict:
    """clips, no_fall, success_rate, every error pooled over all sequences, g_mpjpe_success."""
    out = {"clips": len(rows),
           "no_fall": float(np.mean([not r["fell"] for r in rows])) if rows else math.nan,
           "success_rate": float(np.mean([r["success"] for r in rows])) if rows else math.nan}
    for key in (*ERRORS, "g_mpjpe_input"):
        out[key] = pooled(rows, key)
    out["g_mpjpe_success"] = pooled([r for r in rows if r["success"]], "g_mpjpe")
    return out


COLUMNS = (("no fall", "no_fall"), ("MPJPE", "mpjpe"), ("PA-MPJPE", "pa_mpjpe"), ("Accel", "accel"),
           ("FS", "foot_sliding"), ("GP", "ground_penetration"), ("reproj px", "reprojection"))


def _cell(x, pct: bool = False) -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "-"
    return f"{100 * x:.1f}%" if pct else f"{x:.1f}"


def format_table(rows: list[dict], summary: dict | None = None) -> str:
    """Fixed-width table: a line per sequence, then ALL (the pooled summary) and a legend."""
    summary = summarize(rows) if summary is None else summary
    names = [str(r.get("name", i)) for i, r in enumerate(rows)]
    w = max([len("sequence"), *map(len, names)])
    widths = [max(len(h), 9) for h, _ in COLUMNS]

    def line(cells):
        return "  ".join([cells[0].ljust(w)] + [c.rjust(n) for c, n in zip(cells[1:], widths)])

    out = [line(["sequence"] + [h for h, _ in COLUMNS]), line(["", "", "mm", "mm", "mm/fr^2", "mm", "mm", "px"])]
    out.append("-" * len(out[0]))
    for name, r in zip(names, rows):
        fall = "-" if r.get("physics") is False else ("no" if r["fell"] else "yes")  # the input cannot fall
        out.append(line([name, fall] + [_cell(r.get(k)) for _, k in COLUMNS[1:]]))
    out.append("-" * len(out[0]))
    out.append(line(["ALL", _cell(summary.get("no_fall"), True)] + [_cell(summary.get(k)) for _, k in COLUMNS[1:]]))
    out.append("ALL: errors pooled over every frame of every sequence, each up to its fall if it fell; "
               "'-': undefined (no ground truth, or no contact).")
    return "\n".join(out)


__all__ = ["CONTACT_HEIGHT", "ERRORS", "foot_sliding", "ground_penetration", "fall_frame", "sequence_metrics",
           "summarize", "pooled", "format_table"]
