"""Known-answer tests for smpl_envs.metrics on hand-made trajectories.

Each case is built so that a wrong definition (dividing by dt, averaging vectors before taking
norms, max instead of mean over bodies, forgetting the root subtraction, ...) gives another number.
"""

import json
import math

import numpy as np
import pytest
from scipy.optimize import minimize
from scipy.spatial.transform import Rotation

from smpl_envs import metrics as M

J = 24


def walk(T=10, seed=0):
    """A reference that moves non-trivially: random body layout drifting and wobbling over time."""
    rng = np.random.default_rng(seed)
    t = np.arange(T)[:, None, None]
    return rng.normal(size=(1, J, 3)) + 0.02 * t * np.array([1.0, 0.3, 0.0]) + 0.05 * np.sin(0.7 * t)


def test_constant_offset_everywhere():
    ref = walk()
    sim = ref + np.array([0.03, 0.04, 0.0])  # |offset| = 50 mm on every body and frame
    assert M.body_distance(sim, ref) == pytest.approx(np.full(len(ref), 0.05), rel=1e-12)
    assert M.mpjpe_global(sim, ref) == pytest.approx(50.0, rel=1e-12)
    # the offset moves sim's root too, so relative to the root nothing is wrong
    assert M.mpjpe_local(sim, ref) == pytest.approx(0.0, abs=1e-9)
    # a constant offset has no velocity or acceleration
    assert M.vel_error(sim, ref) == pytest.approx(0.0, abs=1e-9)
    assert M.accel_error(sim, ref) == pytest.approx(0.0, abs=1e-9)


def test_offset_on_root_only():
    ref = walk()
    sim = ref.copy()
    sim[:, 0] += [0.03, 0.04, 0.0]
    # globally one body of 24 is 50 mm off
    assert M.mpjpe_global(sim, ref) == pytest.approx(50.0 / J, rel=1e-12)
    # root-relative: the root itself is exact, every other body looks 50 mm off
    assert M.mpjpe_local(sim, ref) == pytest.approx(50.0 * (J - 1) / J, rel=1e-12)
    # another root index: then the pelvis is the one body that looks off
    assert M.mpjpe_local(sim, ref, root=5) == pytest.approx(50.0 / J, rel=1e-12)
    with pytest.raises(ValueError, match="root"):
        M.mpjpe_local(sim, ref, root=J)


def test_static_sim_against_constant_velocity_ref():
    T = 7
    v = np.array([0.003, 0.004, 0.0])  # 5 mm per frame
    ref = walk(1) + np.arange(T)[:, None, None] * v
    sim = np.repeat(ref[:1], T, axis=0)  # stays where the reference started
    assert M.vel_error(sim, ref) == pytest.approx(5.0, rel=1e-12)  # per frame, not per second
    assert M.accel_error(sim, ref) == pytest.approx(0.0, abs=1e-9)
    assert M.mpjpe_global(sim, ref) == pytest.approx(5.0 * (T - 1) / 2, rel=1e-12)
    assert M.mpjpe_local(sim, ref) == pytest.approx(0.0, abs=1e-9)


def test_quadratic_trajectory():
    T = 5
    ref = np.zeros((T, J, 3))
    c = np.zeros((J, 3))
    c[:, 0] = 0.001 * (-1.0) ** np.arange(J)  # half the bodies speed up along +x, half along -x
    sim = np.arange(T)[:, None, None] ** 2 * c
    # p = c t^2: second difference 2c = 2 mm/frame^2 per body; mean of the norms, not norm of the
    # mean vector (which would be 0 here)
    assert M.accel_error(sim, ref) == pytest.approx(2.0, rel=1e-12)
    # first differences c (2t + 1), t = 0..3: 1, 3, 5, 7 mm -> mean 4 mm/frame
    assert M.vel_error(sim, ref) == pytest.approx(4.0, rel=1e-12)
    # positions 0, 1, 4, 9, 16 mm -> mean 6 mm
    assert M.mpjpe_global(sim, ref) == pytest.approx(6.0, rel=1e-12)


def random_similarity(T, rng):
    """Per frame a random rotation (T, 3, 3), scale in [0.5, 2) and translation of metres."""
    return (Rotation.random(T, random_state=rng).as_matrix(), rng.uniform(0.5, 2.0, T),
            rng.normal(scale=3.0, size=(T, 1, 3)))


def apply(sim, rot, scale, shift):
    return scale[:, None, None] * np.einsum("tik,tjk->tji", rot, sim) + shift


def test_pa_mpjpe_aligns_away_rotation_scale_and_translation():
    ref = walk(T=12)
    rot, scale, shift = random_similarity(len(ref), np.random.default_rng(1))
    sim = apply(ref, rot, scale, shift)
    assert M.mpjpe_global(sim, ref) > 100.0  # far off before alignment
    np.testing.assert_allclose(M.procrustes_align(sim, ref), ref, atol=1e-12)
    assert M.mpjpe_pa(sim, ref) == pytest.approx(0.0, abs=1e-9)
    assert M.clip_metrics(sim, ref, threshold=math.inf)["mpjpe_pa"] == pytest.approx(0.0, abs=1e-9)


def test_pa_mpjpe_of_a_known_perturbation():
    """ref + E with E orthogonal to what a similarity transform can change (sum_j e_j = 0 and
    Y^T E = 0 for the centred reference Y): the optimal rotation is the identity, the optimal
    scale s = |Y|^2 / (|Y|^2 + |E|^2) (Frobenius norms), so joint j ends up off by
    ||(s - 1) y_j + s e_j||. Moving the result by any similarity transform changes nothing."""
    rng = np.random.default_rng(2)
    ref = walk(T=6)
    y = ref - ref.mean(axis=1, keepdims=True)
    basis = np.concatenate([np.ones((len(ref), J, 1)), y], axis=2)  # (T, J, 4): [1, Y]
    raw = rng.normal(scale=0.03, size=ref.shape)
    e = np.stack([r - b @ np.linalg.lstsq(b, r, rcond=None)[0] for r, b in zip(raw, basis)])
    np.testing.assert_allclose(np.einsum("tji,tjk->tik", basis, e), 0.0, atol=1e-12)
    s = (y ** 2).sum(axis=(1, 2)) / ((y ** 2).sum(axis=(1, 2)) + (e ** 2).sum(axis=(1, 2)))
    s = s[:, None, None]
    want = 1000 * np.linalg.norm((s - 1) * y + s * e, axis=-1).mean()
    assert 5.0 < want < 100.0  # a visible error, not a rounding artefact
    assert M.mpjpe_pa(ref + e, ref) == pytest.approx(want, rel=1e-9)
    moved = apply(ref + e, *random_similarity(len(ref), rng))
    assert M.mpjpe_pa(moved, ref) == pytest.approx(want, rel=1e-9)


def _best_similarity_by_search(sim, ref):
    """Independent check of one frame: minimise the squared error over rotation vector, log scale
    and translation numerically (several starts), return the mean joint error there, in mm."""
    def moved(p):
        return np.exp(p[3]) * sim @ Rotation.from_rotvec(p[:3]).as_matrix().T + p[4:]

    def cost(p):
        return ((moved(p) - ref) ** 2).sum()

    rng = np.random.default_rng(0)
    starts = [np.concatenate([Rotation.random(random_state=rng).as_rotvec(), [0.0],
                              ref.mean(0) - sim.mean(0)]) for _ in range(8)]
    best = min((minimize(cost, p0, method="BFGS", options={"gtol": 1e-12}) for p0 in starts),
               key=lambda r: r.fun)
    return 1000 * np.linalg.norm(moved(best.x) - ref, axis=-1).mean()


def test_pa_mpjpe_is_the_optimum_and_a_reflection_is_not_aligned_away():
    ref = walk(T=3, seed=5)
    mirror = ref * np.array([-1.0, 1.0, 1.0])  # a mirror image: no rotation maps it back
    noisy = ref + np.random.default_rng(4).normal(scale=0.05, size=ref.shape)
    for sim in (mirror, noisy):
        got = 1000 * np.linalg.norm(M.procrustes_align(sim, ref) - ref, axis=-1).mean(axis=1)
        want = [_best_similarity_by_search(s, r) for s, r in zip(sim, ref)]
        np.testing.assert_allclose(got, want, rtol=1e-5)
    # the mirror stays far off: an improper "rotation" would have matched it exactly
    assert M.mpjpe_pa(mirror, ref) > 200.0
    aligned = M.procrustes_align(mirror, ref)
    x, y = mirror - mirror.mean(1, keepdims=True), aligned - aligned.mean(1, keepdims=True)
    # what was applied is a proper rotation times a positive scale (det > 0)
    for xt, yt in zip(x, y):
        a = np.linalg.lstsq(xt, yt, rcond=None)[0]
        assert np.linalg.det(a) > 0


def test_pa_mpjpe_degenerate_frames():
    ref = walk(T=4)
    collapsed = np.repeat(ref.mean(axis=1, keepdims=True), J, axis=1)  # every joint in one place
    want = 1000 * np.linalg.norm(ref - ref.mean(axis=1, keepdims=True), axis=-1).mean()
    with np.errstate(all="raise"):
        assert M.mpjpe_pa(collapsed, ref) == pytest.approx(want, rel=1e-12)
        one = M.mpjpe_pa(ref[:, :1] + 1.0, ref[:, :1])  # a single joint: only translation matters
    assert one == pytest.approx(0.0, abs=1e-9)


@pytest.mark.filterwarnings("error")
def test_short_clips_give_nan_without_warnings():
    ref = walk(T=2)
    one = M.clip_metrics(ref[:1] + 0.01, ref[:1])
    assert one["frames"] == 1 and math.isnan(one["vel"]) and math.isnan(one["accel"])
    assert one["mpjpe_g"] == pytest.approx(10.0 * math.sqrt(3), rel=1e-12)
    two = M.clip_metrics(ref + 0.01, ref)
    assert two["vel"] == pytest.approx(0.0, abs=1e-9) and math.isnan(two["accel"])


def test_success_threshold_boundary_and_fail_frame():
    T = 6
    ref = np.zeros((T, J, 3))
    sim = ref.copy()
    sim[2, :, 0] = 0.5  # exactly at the threshold: passes
    assert M.success(sim, ref)
    m = M.clip_metrics(sim, ref)
    assert m["success"] is True and m["fail_frame"] == -1

    sim[3:5, :, 0] = 0.5001  # just over, first at frame 3
    assert not M.success(sim, ref)
    m = M.clip_metrics(sim, ref)
    assert m["success"] is False and m["fail_frame"] == 3
    assert M.clip_metrics(sim, ref, threshold=0.6)["fail_frame"] == -1

    # the criterion is the mean over bodies, not the worst body
    sim = ref.copy()
    sim[:, 7, 2] = 1.0  # one body 1 m off: mean 1/24 m
    assert M.success(sim, ref)
    assert M.body_distance(sim, ref) == pytest.approx(np.full(T, 1.0 / J), rel=1e-12)


def test_clip_metrics_keys_and_types():
    ref = walk()
    m = M.clip_metrics(ref + 0.01, ref)
    assert set(m) == {"success", "frames", "mpjpe_g", "mpjpe_l", "mpjpe_pa", "accel", "vel",
                      "frames_pos", "frames_vel", "frames_acc", "fail_frame"}
    assert type(m["success"]) is bool and type(m["frames"]) is int and type(m["fail_frame"]) is int
    assert all(type(m[k]) is float for k in M.ERROR_KEYS)
    assert all(type(m[k]) is int for k in ("frames_pos", "frames_vel", "frames_acc"))


@pytest.mark.parametrize("T", [1, 2, 3, 10])
def test_clip_metrics_frame_counts(T):
    """Each count is the number of per-frame values its error averages: T positions, T - 1 first
    differences, T - 2 second differences (never negative)."""
    ref = walk(T=T)
    m = M.clip_metrics(ref + 0.01, ref)
    assert (m["frames"], m["frames_pos"], m["frames_vel"], m["frames_acc"]) == \
           (T, T, max(T - 1, 0), max(T - 2, 0))


@pytest.mark.parametrize("sim, ref, msg", [
    (np.zeros((5, J, 3)), np.zeros((4, J, 3)), "differ"),
    (np.zeros((5, J, 3)), np.zeros((5, J - 1, 3)), "differ"),
    (np.zeros((5, J)), np.zeros((5, J)), "shape"),
    (np.zeros((5, J, 4)), np.zeros((5, J, 4)), "shape"),
    (np.zeros((0, J, 3)), np.zeros((0, J, 3)), "shape"),
])
def test_bad_shapes_raise(sim, ref, msg):
    with pytest.raises(ValueError, match=msg):
        M.clip_metrics(sim, ref)


@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_non_finite_raises(bad):
    ref = walk(T=4)
    sim = ref.copy()
    sim[2, 3, 1] = bad
    with pytest.raises(ValueError, match="NaN"):
        M.clip_metrics(sim, ref)
    with pytest.raises(ValueError, match="ref"):
        M.mpjpe_global(ref, sim)


def rows():
    """Two successful clips (one too short for accel) and one failed clip with large errors, as
    clip_metrics writes them (frame counts T, T - 1, T - 2; the failed clip ends at its failure)."""
    return [
        {"name": "walk", "success": True, "frames": 100, "fail_frame": -1,
         "mpjpe_g": 10.0, "mpjpe_l": 8.0, "mpjpe_pa": 6.0, "accel": 2.0, "vel": 3.0,
         "frames_pos": 100, "frames_vel": 99, "frames_acc": 98},
        {"name": "jump", "success": True, "frames": 2, "fail_frame": -1,
         "mpjpe_g": 20.0, "mpjpe_l": 12.0, "mpjpe_pa": 9.0, "accel": math.nan, "vel": 5.0,
         "frames_pos": 2, "frames_vel": 1, "frames_acc": 0},
        {"name": "cartwheel", "success": False, "frames": 50, "fail_frame": 49,
         "mpjpe_g": 300.0, "mpjpe_l": 100.0, "mpjpe_pa": 80.0, "accel": 8.0, "vel": 10.0,
         "frames_pos": 50, "frames_vel": 49, "frames_acc": 48},
    ]


def test_summarize_frame_weighted_over_successful_clips():
    s = M.summarize(rows())
    assert s["clips"] == 3
    assert s["success_rate"] == pytest.approx(2 / 3)
    # successful clips: walk (100 frames) and jump (2 frames), each frame weighs the same
    assert s["mpjpe_g"] == pytest.approx((100 * 10.0 + 2 * 20.0) / 102)
    assert s["mpjpe_l"] == pytest.approx((100 * 8.0 + 2 * 12.0) / 102)
    assert s["mpjpe_pa"] == pytest.approx((100 * 6.0 + 2 * 9.0) / 102)
    assert s["accel"] == pytest.approx(2.0)  # jump has no second difference (and a NaN)
    assert s["vel"] == pytest.approx((99 * 3.0 + 1 * 5.0) / 100)
    # all clips, cartwheel's 50 frames up to its failure included
    assert s["all_mpjpe_g"] == pytest.approx((100 * 10.0 + 2 * 20.0 + 50 * 300.0) / 152)
    assert s["all_mpjpe_l"] == pytest.approx((100 * 8.0 + 2 * 12.0 + 50 * 100.0) / 152)
    assert s["all_mpjpe_pa"] == pytest.approx((100 * 6.0 + 2 * 9.0 + 50 * 80.0) / 152)
    assert s["all_accel"] == pytest.approx((98 * 2.0 + 48 * 8.0) / 146)
    assert s["all_vel"] == pytest.approx((99 * 3.0 + 1 * 5.0 + 49 * 10.0) / 149)


def test_summarize_keeps_the_per_clip_mean_view():
    s = M.summarize(rows())
    assert s["clip_mean_mpjpe_g"] == pytest.approx(15.0)
    assert s["clip_mean_mpjpe_l"] == pytest.approx(10.0)
    assert s["clip_mean_mpjpe_pa"] == pytest.approx(7.5)
    assert s["clip_mean_accel"] == pytest.approx(2.0)  # jump's NaN is skipped
    assert s["clip_mean_vel"] == pytest.approx(4.0)
    assert s["clip_mean_all_mpjpe_g"] == pytest.approx(110.0)
    assert s["clip_mean_all_mpjpe_l"] == pytest.approx(40.0)
    assert s["clip_mean_all_accel"] == pytest.approx(5.0)
    assert s["clip_mean_all_vel"] == pytest.approx(6.0)


@pytest.mark.parametrize("kind", ["position", "velocity", "acceleration"])
def test_two_clips_of_different_lengths_weigh_by_frames(kind):
    """Known answer: a short and a long clip, each with a constant per-frame error of a known
    size. The aggregate is the mean over all their frames (PHC), not the mean of the two means."""
    direction = np.array([0.6, 0.8, 0.0])

    def clip(T, mm):
        ref = walk(T=T, seed=T)
        t = np.arange(T)[:, None, None]
        # the error is constant per frame in the kind measured: an offset (position), a drift
        # of mm per frame (velocity) or e = c t^2 whose second difference is 2c (acceleration)
        shape = {"position": np.ones_like(t), "velocity": t, "acceleration": t ** 2 / 2.0}[kind]
        return {"name": f"T{T}", **M.clip_metrics(ref + shape * direction * mm / 1000.0, ref,
                                                   threshold=math.inf)}

    key = {"position": "mpjpe_g", "velocity": "vel", "acceleration": "accel"}[kind]
    lost = {"position": 0, "velocity": 1, "acceleration": 2}[kind]
    short, long = clip(8, 10.0), clip(68, 40.0)
    assert short[key] == pytest.approx(10.0, rel=1e-9) and long[key] == pytest.approx(40.0, rel=1e-9)
    n_short, n_long = 8 - lost, 68 - lost
    s = M.summarize([short, long])
    want = (n_short * 10.0 + n_long * 40.0) / (n_short + n_long)
    assert s[key] == pytest.approx(want, rel=1e-9) and s["all_" + key] == pytest.approx(want, rel=1e-9)
    assert s["clip_mean_" + key] == pytest.approx(25.0, rel=1e-9)
    assert abs(s[key] - 25.0) > 5.0  # the two views really differ here


def test_summarize_equals_pooling_every_frame_error():
    """The aggregate of clip_metrics rows equals PHC's computation: per-frame errors of all clips
    concatenated, then averaged; also for a failed clip, measured up to its failure frame."""
    rng = np.random.default_rng(3)
    clips = []
    for T in (3, 17, 40):
        ref = walk(T=T, seed=T)
        clips.append((ref + rng.normal(scale=0.02, size=ref.shape), ref))
    clips.append((clips[0][0] + 1.0, clips[0][1]))  # 1 m off everywhere: fails on its first frame
    rows_ = [M.clip_metrics(sim, ref) for sim, ref in clips]
    assert [r["success"] for r in rows_] == [True, True, True, False]

    def per_frame(sim, ref):
        e = sim - ref
        local = (sim - sim[:, :1]) - (ref - ref[:, :1])
        pa = M.procrustes_align(sim, ref) - ref
        return {"mpjpe_g": e, "mpjpe_l": local, "mpjpe_pa": pa,
                "vel": np.diff(e, axis=0), "accel": np.diff(e, 2, axis=0)}

    frames = [per_frame(sim, ref) for sim, ref in clips]
    s = M.summarize(rows_)
    for key in M.ERROR_KEYS:
        pooled = [1000 * np.linalg.norm(f[key], axis=-1).mean(axis=1) for f in frames]
        assert s[key] == pytest.approx(np.concatenate(pooled[:3]).mean(), rel=1e-12), key
        assert s["all_" + key] == pytest.approx(np.concatenate(pooled).mean(), rel=1e-12), key


def test_summarize_counts_from_rows_not_frames():
    """Evaluation may count a diverged final frame in `frames` that no error measures; the weights
    are the recorded counts. Rows without counts (older results) fall back on `frames`."""
    a, b = rows()[:2]
    a_more = {**a, "frames": 500}  # frames_pos etc. unchanged
    assert M.summarize([a_more, b])["mpjpe_g"] == pytest.approx(M.summarize([a, b])["mpjpe_g"])
    old = [{k: v for k, v in r.items() if not k.startswith("frames_")} for r in rows()]
    new, legacy = M.summarize(rows()), M.summarize(old)
    for key in M.ERROR_KEYS:
        assert legacy[key] == pytest.approx(new[key], nan_ok=True), key
        assert legacy["all_" + key] == pytest.approx(new["all_" + key]), key


@pytest.mark.filterwarnings("error")
def test_summarize_degenerate_inputs():
    failed = M.summarize([r for r in rows() if not r["success"]])
    assert failed["success_rate"] == 0.0 and math.isnan(failed["mpjpe_g"])
    assert failed["all_mpjpe_g"] == pytest.approx(300.0)
    empty = M.summarize([])
    assert empty["clips"] == 0
    assert all(math.isnan(empty[k]) for k in ("success_rate", "mpjpe_g", "all_vel"))


def test_format_table():
    text = M.format_table(rows())
    lines = text.splitlines()
    assert lines[0].split() == ["clip", "succ", "frames", "E_g-mpjpe", "E_mpjpe", "E_pa-mpjpe",
                                "E_acc", "E_vel"]
    assert "mm/frame^2" in lines[1] and "mm/frame" in lines[1]
    for r in rows():
        line = next(ln for ln in lines if ln.startswith(r["name"] + " "))
        assert line.split()[1] == ("yes" if r["success"] else "no")
    assert next(ln for ln in lines if ln.startswith("jump ")).split()[3:] == ["20.0", "12.0", "9.0", "-", "5.0"]
    all_line = lines[-2].split()
    # frame-weighted: (100 * 10 + 2 * 20) / 102 = 10.2 mm etc.
    assert all_line == ["ALL", "66.7%", "152", "10.2", "8.1", "6.1", "2.0", "3.0"]
    assert lines[-1].startswith("ALL:") and "successful clips" in lines[-1]
    assert len({len(ln) for ln in lines[:-1]}) == 1  # fixed width (all but the legend)
    # a different name key, and a given summary is used as is
    renamed = [{"clip_id": r["name"], **r} for r in rows()]
    s = {**M.summarize(rows()), "success_rate": 0.5}
    text = M.format_table(renamed, s, names_key="clip_id")
    assert "cartwheel" in text and text.splitlines()[-2].split()[1] == "50.0%"


def test_format_table_without_a_successful_clip_shows_tracked_frames():
    """No clip succeeded: the success-only aggregates are NaN; the ALL line shows the errors over
    all frames tracked instead, says so in the legend, and never prints 'nan'."""
    failed = rows()[2:] + [{**rows()[1], "name": "jump", "success": False, "fail_frame": 1}]
    s = M.summarize(failed)
    assert math.isnan(s["mpjpe_g"]) and s["success_rate"] == 0.0
    for summary in (s, json.loads(M.to_json(failed, s))["summary"]):  # NaN read back as None
        lines = M.format_table(failed, summary).splitlines()
        assert "nan" not in "\n".join(lines).lower()
        want = [s["all_" + k] for k in M.ERROR_KEYS]
        assert want[0] == pytest.approx((50 * 300.0 + 2 * 20.0) / 52)
        assert lines[-2].split() == ["ALL", "0.0%", "52"] + [f"{v:.1f}" for v in want]
        assert lines[-1].startswith("ALL:") and "no clip succeeded" in lines[-1]
        assert "all frames tracked" in lines[-1]
    # every clip too short for an error: that column shows '-', still no 'nan'
    short = [{**rows()[1], "success": False}]
    text = M.format_table(short)
    assert "nan" not in text.lower() and text.splitlines()[-2].split()[-2] == "-"
    # no clips at all
    empty = M.format_table([], M.summarize([]))
    assert "nan" not in empty.lower() and empty.splitlines()[-2].split()[1:] == ["-", "0"] + ["-"] * 5
    assert empty.splitlines()[-1].startswith("ALL: no clips")


def test_to_json_round_trip():
    r = rows()
    r[0].update(success=np.True_, frames=np.int64(100), mpjpe_g=np.float64(10.0))
    text = M.to_json(r, M.summarize(r))
    data = json.loads(text)
    assert "NaN" not in text and text.startswith("{\n  ")
    assert data["clips"][0] == {**rows()[0]}
    assert data["clips"][1]["accel"] is None
    assert data["summary"]["success_rate"] == pytest.approx(2 / 3)
    assert data["summary"]["clips"] == 3
    assert math.isnan(M.summarize([])["mpjpe_g"])
    assert json.loads(M.to_json([], M.summarize([])))["summary"]["mpjpe_g"] is None


def test_end_to_end_on_a_clip():
    ref = walk(T=30)
    sim = ref + np.array([0.0, 0.0, 0.02])
    row = {"name": "offset", **M.clip_metrics(sim, ref)}
    s = M.summarize([row])
    assert s["success_rate"] == 1.0 and s["mpjpe_g"] == pytest.approx(20.0, rel=1e-12)
    assert json.loads(M.to_json([row], s))["clips"][0]["name"] == "offset"
    assert "100.0%" in M.format_table([row])
