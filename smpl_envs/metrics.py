"""Motion-imitation metrics of Perpetual Humanoid Control (PHC, Luo et al. 2023), in numpy.

Inputs are body-position trajectories of one clip: ``sim`` (what the simulated humanoid did) and
``ref`` (the reference motion it imitated), float arrays of shape (T, J, 3) with T >= 1 frames and
J bodies (the 24 SMPL bodies; index 0 is the pelvis, the root). Positions are in metres in the
world frame, sampled at 30 frames per second. Write p_t,j for the position of body j at frame t
and ||.|| for the Euclidean norm. Reported errors are in millimetres (metres x 1000).

Definitions
-----------
body distance  d_t = (1/J) sum_j ||sim_t,j - ref_t,j||, per frame, in metres.

success        The clip succeeds iff d_t <= threshold (0.5 m by default) at every frame; a frame
               with d_t strictly greater fails it. The fail frame is the first such t (-1 if none).
               PHC counts the whole clip as failed from that frame on, so errors of failed clips
               are reported separately (see `summarize`).

E_g-mpjpe      Global mean per-joint position error, in mm:
               1000 * mean over t and j of ||sim_t,j - ref_t,j||  (= 1000 * mean_t d_t).

E_mpjpe        Root-relative mean per-joint position error, in mm: as E_g-mpjpe after replacing
               each trajectory's positions by p_t,j - p_t,root (each by its own root, per frame).
               The root itself then has zero error and still counts among the J bodies.

E_pa-mpjpe     Procrustes-aligned mean per-joint position error, in mm (reported by PHC's
               evaluation and SimPoE): per frame t, the similarity transform (rotation R_t with
               det R_t = +1, translation c_t, uniform scale s_t) minimising
               sum_j ||s_t R_t sim_t,j + c_t - ref_t,j||^2 is applied to the simulated joints
               (Umeyama's closed form, with the reflection correction, so a mirror image is
               never "aligned"), then 1000 * mean over t and j of
               ||s_t R_t sim_t,j + c_t - ref_t,j||. Only the pose is scored: where the body is,
               which way it faces and how big it is are all aligned away.

E_acc          Acceleration error, in mm/frame^2: with second differences
               a_t,j = p_t+1,j - 2 p_t,j + p_t-1,j  (t = 1 .. T-2; not divided by dt^2),
               1000 * mean over t and j of ||a^sim_t,j - a^ref_t,j||. NaN when T < 3.

E_vel          Velocity error, in mm/frame: with first differences v_t,j = p_t+1,j - p_t,j
               (t = 0 .. T-2; not divided by dt), 1000 * mean over t and j of
               ||v^sim_t,j - v^ref_t,j||. NaN when T < 2.

Row keys       `clip_metrics` writes E_g-mpjpe as mpjpe_g, E_mpjpe as mpjpe_l, E_pa-mpjpe as
               mpjpe_pa, E_acc as accel and E_vel as vel (ERROR_KEYS).

Frame counts   Each per-clip error is a mean over frames; a clip row records how many:
               frames_pos = T for E_g-mpjpe, E_mpjpe and E_pa-mpjpe, frames_vel = T - 1 for E_vel
               (first differences) and frames_acc = max(T - 2, 0) for E_acc (second differences).

Aggregates (`summarize`): success rate = successful clips / clips. Each error is aggregated as
PHC's evaluation does it: the per-frame errors of the clips are pooled and averaged, so every frame
weighs the same (a 20 s clip counts ten times a 2 s clip). From the per-clip means that is
sum_i n_i e_i / sum_i n_i, with n_i the clip's frame count for that error (above). The plain keys
are over the successful clips (how PHC reports them; NaN if none succeeded), ``all_*`` over all
clips (failed clips up to their failure frame). The per-clip-mean view (every clip weighs the same
whatever its length) is kept under ``clip_mean_*`` (successful clips) and ``clip_mean_all_*``.
Clip values that are NaN (too short a clip) are skipped.

Recovery       (PHC's fail-state recovery, `SMPL/Recovery-v0`) per trial from its body distances
               d_t: the trial is back from the first frame t after which d stays <= threshold to
               the trial's end (`recovery_frame`; -1 if its last frame is beyond); Succ-5s /
               Succ-10s: back at a frame <= 150 / 300 (`recovered_within`).
"""

from __future__ import annotations

import json
import math

import numpy as np

MM = 1000.0  # metres -> millimetres
ERROR_KEYS = ("mpjpe_g", "mpjpe_l", "mpjpe_pa", "accel", "vel")
# The row key holding the number of frames each error averages over (the weight of the clip's
# value in the frame-weighted aggregate).
COUNT_KEYS = {"mpjpe_g": "frames_pos", "mpjpe_l": "frames_pos", "mpjpe_pa": "frames_pos",
              "accel": "frames_acc", "vel": "frames_vel"}
# Frames lost by each count to differencing (used when a row carries only `frames`).
_LOST = {"frames_pos": 0, "frames_vel": 1, "frames_acc": 2}


def _check(sim, ref) -> tuple[np.ndarray, np.ndarray]:
    """Both as float (T, J, 3) arrays of the same shape, finite; ValueError otherwise."""
    sim, ref = np.asarray(sim, dtype=float), np.asarray(ref, dtype=float)
    for name, a in (("sim", sim), ("ref", ref)):
        if a.ndim != 3 or a.shape[2] != 3 or a.shape[0] < 1 or a.shape[1] < 1:
            raise ValueError(f"{name} must have shape (T, J, 3) with T, J >= 1, got {a.shape}")
    if sim.shape != ref.shape:
        raise ValueError(f"sim and ref shapes differ: {sim.shape} vs {ref.shape}")
    for name, a in (("sim", sim), ("ref", ref)):
        if not np.isfinite(a).all():
            raise ValueError(f"{name} contains NaN or inf")
    return sim, ref


def _mean_norm(diff: np.ndarray) -> float:
    """Mean Euclidean norm over all (frame, body) vectors, in mm; NaN for no vectors."""
    if diff.shape[0] == 0:  # too few frames for this difference order: no warning, just NaN
        return math.nan
    return float(np.linalg.norm(diff, axis=-1).mean() * MM)


def body_distance(sim, ref) -> np.ndarray:
    """(T,) mean over bodies of the Euclidean distance between sim and ref, in metres."""
    sim, ref = _check(sim, ref)
    return np.linalg.norm(sim - ref, axis=-1).mean(axis=1)


def _fail_frame(dist: np.ndarray, threshold: float) -> int:
    over = np.flatnonzero(dist > threshold)
    return int(over[0]) if over.size else -1


def success(sim, ref, threshold: float = 0.5) -> bool:
    """True iff the mean body distance never exceeds `threshold` metres (equal still passes)."""
    return bool((body_distance(sim, ref) <= threshold).all())


def mpjpe_global(sim, ref) -> float:
    """E_g-mpjpe in mm: mean over frames and bodies of ||sim - ref||."""
    sim, ref = _check(sim, ref)
    return _mean_norm(sim - ref)


def mpjpe_local(sim, ref, root: int = 0) -> float:
    """E_mpjpe in mm: as `mpjpe_global` with each trajectory made relative to its own root."""
    sim, ref = _check(sim, ref)
    if not -sim.shape[1] <= root < sim.shape[1]:
        raise ValueError(f"root index {root} out of range for {sim.shape[1]} bodies")
    # [root] (not root) keeps the body axis so the subtraction broadcasts over bodies
    return _mean_norm((sim - sim[:, [root]]) - (ref - ref[:, [root]]))


def procrustes_align(sim, ref) -> np.ndarray:
    """`sim` (T, J, 3) moved, frame by frame, onto `ref` by the best similarity transform.

    Per frame, with centred point sets x_j = sim_j - mean(sim), y_j = ref_j - mean(ref) and their
    cross-covariance C = sum_j y_j x_j^T = U diag(d) V^T (SVD), the least-squares optimum is
    R = U S V^T with S = diag(1, 1, sign(det U det V)), s = tr(diag(d) S) / sum_j ||x_j||^2 and
    the translation that maps mean(sim) onto mean(ref) (Umeyama 1991). S keeps R a rotation: a
    mirror image of the reference stays a mirror image. A frame whose simulated joints all
    coincide gets s = 0 (every joint lands on the reference's centroid). All frames at once.
    """
    sim, ref = _check(sim, ref)
    mu_sim, mu_ref = sim.mean(axis=1, keepdims=True), ref.mean(axis=1, keepdims=True)
    x, y = sim - mu_sim, ref - mu_ref
    cov = np.einsum("tji,tjk->tik", y, x)  # (T, 3, 3): sum over joints of y_j x_j^T
    u, d, vt = np.linalg.svd(cov)
    # Reflection correction: if U V^T would be a reflection, flip the axis of the smallest
    # singular value (the cheapest one to get wrong) so R is a proper rotation.
    flip = np.where(np.linalg.det(u) * np.linalg.det(vt) < 0.0, -1.0, 1.0)
    u[:, :, 2] *= flip[:, None]
    d[:, 2] *= flip
    rot = u @ vt
    var = np.einsum("tji,tji->t", x, x)
    scale = np.divide(d.sum(axis=1), var, out=np.zeros_like(var), where=var > 0.0)
    # rotate each joint (a row vector) by R: x R^T
    return scale[:, None, None] * (x @ rot.transpose(0, 2, 1)) + mu_ref


def mpjpe_pa(sim, ref) -> float:
    """E_pa-mpjpe in mm: mean over frames and bodies of ||aligned sim - ref|| after the per-frame
    similarity alignment of `procrustes_align` (rotation, translation, uniform scale)."""
    sim, ref = _check(sim, ref)
    return _mean_norm(procrustes_align(sim, ref) - ref)


def accel_error(sim, ref) -> float:
    """E_acc in mm/frame^2 from second differences (not divided by dt^2); NaN when T < 3."""
    sim, ref = _check(sim, ref)
    # the second difference is linear, so difference the error instead of each trajectory
    e = sim - ref
    return _mean_norm(e[2:] - 2.0 * e[1:-1] + e[:-2])


def vel_error(sim, ref) -> float:
    """E_vel in mm/frame from first differences (not divided by dt); NaN when T < 2."""
    sim, ref = _check(sim, ref)
    return _mean_norm(np.diff(sim - ref, axis=0))


def clip_metrics(sim, ref, threshold: float = 0.5) -> dict:
    """All metrics of one clip: success, frames, the errors (ERROR_KEYS, in mm), the number of
    frames each error averages over (frames_pos, frames_vel, frames_acc; see COUNT_KEYS) and
    fail_frame."""
    sim, ref = _check(sim, ref)
    fail = _fail_frame(body_distance(sim, ref), threshold)
    T = int(sim.shape[0])
    return {
        "success": fail < 0,
        "frames": T,
        "mpjpe_g": mpjpe_global(sim, ref),
        "mpjpe_l": mpjpe_local(sim, ref),
        "mpjpe_pa": mpjpe_pa(sim, ref),
        "accel": accel_error(sim, ref),
        "vel": vel_error(sim, ref),
        **{key: max(T - lost, 0) for key, lost in _LOST.items()},
        "fail_frame": fail,
    }


def _count(row: dict, error_key: str) -> int:
    """Frames the row's `error_key` averages over. Rows written before the counts existed carry
    only `frames` (T); the count then follows from the difference order."""
    count_key = COUNT_KEYS[error_key]
    if count_key in row:
        return int(row[count_key])
    return max(int(row["frames"]) - _LOST[count_key], 0)


def _frame_mean(rows: list[dict], key: str) -> float:
    """Frame-weighted mean of the rows' `key`: sum_i n_i e_i / sum_i n_i, i.e. the mean of all
    their per-frame errors pooled (PHC). Rows whose value is NaN or counts no frame are skipped;
    NaN if none is left."""
    pairs = [(float(r.get(key, math.nan)), _count(r, key)) for r in rows]
    pairs = [(e, n) for e, n in pairs if not math.isnan(e) and n > 0]
    if not pairs:
        return math.nan
    e, n = np.array(pairs).T
    return float((n * e).sum() / n.sum())


def _clip_mean(rows: list[dict], key: str) -> float:
    """Mean of the rows' `key` with every clip weighted equally; NaN values are skipped and NaN
    if none is left (np.nanmean would warn)."""
    a = np.array([r.get(key, math.nan) for r in rows], dtype=float)
    a = a[~np.isnan(a)]
    return float(a.mean()) if a.size else math.nan


def summarize(rows: list[dict]) -> dict:
    """Aggregate row of clip_metrics rows (definitions in the module docstring).

    clips, success_rate; per error key (ERROR_KEYS), in mm:
      key                 frame-weighted over the successful clips (PHC's numbers)
      all_key             frame-weighted over all clips
      clip_mean_key       mean of the per-clip values over the successful clips
      clip_mean_all_key   mean of the per-clip values over all clips
    """
    ok = [r for r in rows if r["success"]]
    out = {
        "clips": len(rows),
        "success_rate": len(ok) / len(rows) if rows else math.nan,
    }
    for prefix, agg in (("", _frame_mean), ("clip_mean_", _clip_mean)):
        for key in ERROR_KEYS:
            out[prefix + key] = agg(ok, key)
        for key in ERROR_KEYS:
            out[prefix + "all_" + key] = agg(rows, key)
    return out


def _num(x) -> str:
    """One decimal; '-' for an undefined value (None, as JSON writes NaN, or NaN itself)."""
    return "-" if x is None or not math.isfinite(x) else f"{x:.1f}"


def format_table(rows: list[dict], summary: dict | None = None, names_key: str = "name") -> str:
    """Fixed-width text table: one line per clip (errors over the frames it tracked, i.e. up to
    its failure frame), then the ALL line (success %, total frames, aggregate errors) and a legend
    line saying what the ALL errors are.

    ALL shows the frame-weighted errors over the successful clips (PHC's numbers). When no clip
    succeeded those are undefined, so ALL shows the frame-weighted errors over all the frames
    tracked (the ``all_*`` aggregates) instead, and the legend says so. Undefined values print as
    '-', never 'nan'. A given summary is used as is.
    """
    if summary is None:
        summary = summarize(rows)
    names = [str(r.get(names_key, i)) for i, r in enumerate(rows)]
    w = max([len("clip"), len("ALL"), *map(len, names)])
    cols = (("succ", 6), ("frames", 7), ("E_g-mpjpe", 10), ("E_mpjpe", 8), ("E_pa-mpjpe", 10),
            ("E_acc", 11), ("E_vel", 9))

    def line(cells):
        return "  ".join([cells[0].ljust(w)] + [c.rjust(n) for c, (_, n) in zip(cells[1:], cols)])

    lines = [
        line(["clip"] + [h for h, _ in cols]),
        line(["", "", "", "mm", "mm", "mm", "mm/frame^2", "mm/frame"]),
    ]
    lines.append("-" * len(lines[0]))
    for name, r in zip(names, rows):
        lines.append(line([name, "yes" if r["success"] else "no", str(int(r["frames"]))]
                          + [_num(r.get(k)) for k in ERROR_KEYS]))
    rate = summary.get("success_rate")
    rate = math.nan if rate is None else float(rate)  # None: NaN read back from JSON
    if math.isnan(rate):
        prefix, legend = "", "ALL: no clips."
    elif rate > 0.0:
        prefix, legend = "", ("ALL: errors over the frames of the successful clips, every frame "
                              "weighted equally (PHC).")
    else:
        prefix, legend = "all_", ("ALL: no clip succeeded; errors over all frames tracked (each "
                                  "clip up to its failure frame), every frame weighted equally.")
    lines.append("-" * len(lines[0]))
    lines.append(line(["ALL", "-" if math.isnan(rate) else f"{100 * rate:.1f}%",
                       str(sum(int(r["frames"]) for r in rows))]
                      + [_num(summary.get(prefix + k)) for k in ERROR_KEYS]))
    lines.append(legend + " '-': undefined.")
    return "\n".join(lines)


def _plain(x):
    """Recursively to JSON-native types: numpy scalars/arrays unpacked, NaN/inf -> None."""
    if isinstance(x, dict):
        return {str(k): _plain(v) for k, v in x.items()}
    if isinstance(x, (list, tuple, np.ndarray)):
        return [_plain(v) for v in x]
    if isinstance(x, (bool, np.bool_)):
        return bool(x)
    if isinstance(x, (int, np.integer)):
        return int(x)
    if isinstance(x, (float, np.floating)):
        return float(x) if math.isfinite(x) else None
    return x


def to_json(rows: list[dict], summary: dict | None = None) -> str:
    """JSON text {"clips": rows, "summary": summary}, indent 2, NaN written as null."""
    if summary is None:
        summary = summarize(rows)
    # allow_nan=False: any non-finite value that slipped through is a bug, not invalid JSON output
    return json.dumps({"clips": _plain(rows), "summary": _plain(summary)}, indent=2, allow_nan=False)


# ---------------------------------------------------------------------- fail-state recovery (PHC)
def recovery_frame(dist, threshold: float = 0.5) -> np.ndarray:
    """The frame from which a trial is back for good: the first t with dist[t:] all <= threshold
    (the frame after the last one beyond it; 0 if none is), -1 if the trial's last frame is
    beyond. `dist` (..., T) mean body distances per frame (non-finite counts as beyond);
    returns (...) ints."""
    dist = np.asarray(dist, float)
    bad = ~(dist <= threshold)
    t = dist.shape[-1]
    last_bad = np.where(bad.any(-1), t - 1 - bad[..., ::-1].argmax(-1), -1)
    return np.where(last_bad == t - 1, -1, last_bad + 1).astype(np.int64)


def recovered_within(frames, seconds: float, fps: float = 30.0) -> np.ndarray:
    """Succ-<seconds>s per trial: back (recovery_frame >= 0) at a frame <= seconds x fps."""
    frames = np.asarray(frames)
    return (frames >= 0) & (frames <= seconds * fps + 1e-9)
