"""Known-answer tests for smpl_envs.metrics on hand-made trajectories.

Each case is built so that a wrong definition (dividing by dt, averaging vectors before taking
norms, max instead of mean over bodies, forgetting the root subtraction, ...) gives another number.
"""

import json
import math

import numpy as np
import pytest

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
    assert set(m) == {"success", "frames", "mpjpe_g", "mpjpe_l", "accel", "vel", "fail_frame"}
    assert type(m["success"]) is bool and type(m["frames"]) is int and type(m["fail_frame"]) is int
    assert all(type(m[k]) is float for k in M.ERROR_KEYS)


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
    """Two successful clips (one too short for accel) and one failed clip with large errors."""
    return [
        {"name": "walk", "success": True, "frames": 100, "fail_frame": -1,
         "mpjpe_g": 10.0, "mpjpe_l": 8.0, "accel": 2.0, "vel": 3.0},
        {"name": "jump", "success": True, "frames": 2, "fail_frame": -1,
         "mpjpe_g": 20.0, "mpjpe_l": 12.0, "accel": math.nan, "vel": 5.0},
        {"name": "cartwheel", "success": False, "frames": 50, "fail_frame": 17,
         "mpjpe_g": 300.0, "mpjpe_l": 100.0, "accel": 8.0, "vel": 10.0},
    ]


def test_summarize_over_successful_clips():
    s = M.summarize(rows())
    assert s["clips"] == 3
    assert s["success_rate"] == pytest.approx(2 / 3)
    assert s["mpjpe_g"] == pytest.approx(15.0)
    assert s["mpjpe_l"] == pytest.approx(10.0)
    assert s["accel"] == pytest.approx(2.0)  # jump's NaN is skipped
    assert s["vel"] == pytest.approx(4.0)
    assert s["all_mpjpe_g"] == pytest.approx(110.0)
    assert s["all_mpjpe_l"] == pytest.approx(40.0)
    assert s["all_accel"] == pytest.approx(5.0)
    assert s["all_vel"] == pytest.approx(6.0)


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
    assert lines[0].split() == ["clip", "succ", "frames", "E_g-mpjpe", "E_mpjpe", "E_acc", "E_vel"]
    assert "mm/frame^2" in lines[1] and "mm/frame" in lines[1]
    for r in rows():
        line = next(ln for ln in lines if ln.startswith(r["name"] + " "))
        assert line.split()[1] == ("yes" if r["success"] else "no")
    assert next(ln for ln in lines if ln.startswith("jump ")).split()[3:] == ["20.0", "12.0", "-", "5.0"]
    all_line = lines[-1].split()
    assert all_line == ["ALL", "66.7%", "152", "15.0", "10.0", "2.0", "4.0"]
    assert len({len(ln) for ln in lines}) == 1  # fixed width
    # a different name key, and a given summary is used as is
    renamed = [{"clip_id": r["name"], **r} for r in rows()]
    s = {**M.summarize(rows()), "success_rate": 0.5}
    text = M.format_table(renamed, s, names_key="clip_id")
    assert "cartwheel" in text and text.splitlines()[-1].split()[1] == "50.0%"


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
