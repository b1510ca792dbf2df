"""check_motion: every shipped clip passes, and each check fails on a clip broken in its way."""

from __future__ import annotations

import time
from dataclasses import replace
from functools import lru_cache

import numpy as np
import pytest

from smpl_envs.humanoid.kinematics import forward_kinematics
from smpl_envs.humanoid.skeleton import BODY_NAMES, MEAN_SKELETON
from smpl_envs.motion.loaders import read_motion_file
from smpl_envs.motion.plausibility import (
    FEET, FLIGHT_ACC_TOLERANCE, GRAVITY, MAX_SLIDE_SPEED, SUPPORT_MARGIN, centre_of_mass, check_motion,
    support_points_world, zmp_margin,
)
from smpl_envs.motion import procedural as syn
from smpl_envs.motion.synthetic import CLIP_NAMES, CLIPS_DIR
from smpl_envs.rotations import quat_apply, quat_mul, yaw_quat

FLYING = ("run", "jump")


@lru_cache(maxsize=None)
def shipped(name: str):
    return read_motion_file(CLIPS_DIR / f"{name}.npz")[0]


def edited(raw, root_pos=None, local_quat=None):
    return replace(raw, root_pos=raw.root_pos.copy() if root_pos is None else root_pos,
                   local_quat=raw.local_quat.copy() if local_quat is None else local_quat)


def axis_quat(axis: int, angle: float) -> np.ndarray:
    q = np.zeros(4)
    q[0], q[1 + axis] = np.cos(angle / 2), np.sin(angle / 2)
    return q


@pytest.mark.parametrize("name", CLIP_NAMES)
def test_shipped_clips_pass(name):
    report = check_motion(shipped(name), allow_flight=name in FLYING)
    assert report.ok, str(report)
    assert report.lowest > -0.01
    assert report.flight.any() == (name in FLYING)
    assert np.isnan(report.support_margin) or report.support_margin > 0.0  # CoM inside the support


@pytest.mark.parametrize("name", FLYING)
def test_flight_is_reported_and_ballistic(name):
    report = check_motion(shipped(name))
    assert report.flight_phases and report.flight_acc_error < 0.01
    assert "floating" in check_motion(shipped(name), allow_flight=False).failed


def test_a_ten_second_clip_is_checked_fast():
    raw = shipped("gesture")
    long = edited(raw, np.concatenate([raw.root_pos, raw.root_pos[:60]]),
                  np.concatenate([raw.local_quat, raw.local_quat[:60]]))
    assert long.num_frames == 301
    check_motion(long)
    best = min(_timed(check_motion, long) for _ in range(3))
    assert best < 0.05, f"{best * 1000:.0f} ms"


def _timed(f, *args):
    t0 = time.perf_counter()
    f(*args)
    return time.perf_counter() - t0


# ----------------------------------------------------------------------------- each check can fail

def test_sunk_into_the_floor():
    raw = shipped("stand")
    report = check_motion(edited(raw, raw.root_pos - [0.0, 0.0, 0.05]))
    assert report.failed == {"floor"} and report.lowest == pytest.approx(-0.05, abs=1e-3)


def test_a_planted_foot_dragged():
    # The body turns about the right foot at 0.4 rad/s: the right foot pivots (its corners move
    # ~4 cm/s), the left one, ~0.2 m away, is dragged over the floor at ~8 cm/s.
    raw = shipped("stand")
    t = np.arange(raw.num_frames) / raw.fps
    pos, quat = forward_kinematics(raw.root_pos[:1], raw.local_quat[:1], MEAN_SKELETON.offsets)
    corners, _ = support_points_world(pos, quat)
    pivot = corners[0, list(FEET["R"])].reshape(-1, 3).mean(0) * [1, 1, 0]
    q = yaw_quat(0.4 * t)
    local = raw.local_quat.copy()
    local[:, 0] = quat_mul(q, local[:, 0])
    report = check_motion(edited(raw, pivot + quat_apply(q, raw.root_pos - pivot), local))
    assert report.failed == {"planted feet"}
    assert report.slide_mean["L"] > MAX_SLIDE_SPEED > report.slide_mean["R"]
    assert report.slide_max["L"] >= report.slide_mean["L"]


def test_flight_with_the_wrong_gravity():
    raw = shipped("jump")
    first, last = check_motion(raw).flight_phases[0]
    # Bump the pelvis up along the flight by the difference of two parabolas: z'' becomes -6 m/s^2.
    t = np.arange(raw.num_frames) / raw.fps
    t0, t1 = (first - 1) / raw.fps, (last + 1) / raw.fps
    bump = np.clip(0.5 * (GRAVITY - 6.0) * (t - t0) * (t1 - t), 0.0, None)
    report = check_motion(edited(raw, raw.root_pos + bump[:, None] * [0, 0, 1]))
    assert report.failed == {"flight"}
    assert report.flight_acc_error == pytest.approx(GRAVITY - 6.0, abs=0.05)
    assert GRAVITY - 6.0 > FLIGHT_ACC_TOLERANCE


def test_hovering_above_the_floor():
    raw = shipped("stand")
    lifted = edited(raw, raw.root_pos + [0.0, 0.0, 0.03])
    assert check_motion(lifted, allow_flight=False).failed == {"floating"}
    # A body that hovers does not fall: its "flight" is not ballistic.
    report = check_motion(lifted)
    assert report.failed == {"flight"} and report.flight_acc_error > 9.0


def test_a_knee_bent_backwards():
    raw = shipped("stand")
    local = raw.local_quat.copy()
    local[:, BODY_NAMES.index("L_Knee")] = axis_quat(1, np.deg2rad(-30.0))  # flexion is +y
    report = check_motion(edited(raw, local_quat=local))
    assert "joint range" in report.failed and report.worst_hinge == "L_Knee_y"
    assert np.degrees(report.limit_distance) == pytest.approx(25.0, abs=0.5)


def test_a_joint_just_inside_its_range_margin_passes():
    raw = shipped("stand")
    local = raw.local_quat.copy()
    local[:, BODY_NAMES.index("L_Knee")] = axis_quat(1, np.deg2rad(-7.0))  # 2 deg past -5
    report = check_motion(edited(raw, local_quat=local))
    assert "joint range" not in report.failed
    assert np.degrees(report.limit_excess) == pytest.approx(2.0, abs=0.01)


@pytest.mark.parametrize("shift, fails", [(0.0, False), (0.06, False), (0.25, True)])
def test_centre_of_mass_outside_the_support(shift, fails):
    # Feet planted as in the stand clip, the pelvis held `shift` ahead of the balanced position.
    t = syn._time(3.0)
    spec = syn._Spec(t, np.zeros((len(t), 3)), syn._rot(0 * t, 4 * syn.DEG), syn._standing_legs(t),
                     syn._relaxed_arms(t), syn._upright_spine(t, 4 * syn.DEG))
    syn._balanced(spec, 0.5, drop=0.01)
    spec.pelvis_pos[:, 0] += shift
    syn._fit_height(spec, 0.01)
    raw = syn._raw("leaning", spec, syn._solve(spec))
    report = check_motion(raw)
    assert report.quasi_static.all()
    assert report.failed == ({"balance"} if fails else set()), str(report)
    assert (report.support_margin < -SUPPORT_MARGIN) == fails


def test_the_zero_moment_point_of_a_still_and_an_accelerating_body():
    stand = shipped("stand")
    still = edited(stand, root_pos=np.repeat(stand.root_pos[:1], 60, 0), local_quat=np.repeat(stand.local_quat[:1], 60, 0))
    static = zmp_margin(still)
    assert static.shape == (60,) and np.allclose(static, static[0]) and 0.02 < static[0] < 0.2
    assert static[0] == pytest.approx(check_motion(still).support_margin, abs=1e-9)  # at rest: the CoM's margin
    # The same pose pushed forward at a constant 2 m/s^2 (feet and all): the ZMP trails the centre
    # of mass by its height x a / g, so it leaves the feet behind.
    t = np.arange(60) / 30
    moving = edited(still, root_pos=still.root_pos + np.stack([t * t, 0 * t, 0 * t], -1))
    pos, quat = forward_kinematics(still.root_pos[:1], still.local_quat[:1], MEAN_SKELETON.offsets)
    lag = centre_of_mass(pos, quat, MEAN_SKELETON)[0, 2] * 2.0 / GRAVITY
    inner = zmp_margin(moving)[5:-5]  # away from the ends' one-sided differences
    assert np.all(inner < 0) and np.all(inner < static[0] - 0.5 * lag)
    # Off the floor there is no hull.
    assert np.isnan(zmp_margin(edited(still, root_pos=still.root_pos + [0, 0, 0.1]))).all()


def test_a_ninety_degree_jump_in_one_frame():
    raw = shipped("gesture")
    local = raw.local_quat.copy()
    elbow = BODY_NAMES.index("L_Elbow")
    local[100, elbow] = quat_mul(local[100, elbow], axis_quat(2, np.deg2rad(-90.0)))
    report = check_motion(edited(raw, local_quat=local))
    assert report.failed == {"smoothness"}
    assert np.degrees(report.max_joint_step) == pytest.approx(90.0, abs=0.5)


def test_a_body_moving_too_fast():
    raw = shipped("stand")
    root = raw.root_pos.copy()
    root[60:] += [0.5, 0.0, 0.0]  # a 0.5 m teleport: 15 m/s
    assert "smoothness" in check_motion(edited(raw, root)).failed


def test_a_hip_passing_gimbal_lock_is_caught_though_its_rotation_is_smooth():
    # The left thigh swings up through 90 deg of flexion turned 5 deg sideways: every local
    # rotation changes smoothly, but no x-y-z hinge path the humanoid could be driven with is
    # both smooth and in range. The per-frame rule flips x and z by half a turn at once; kept
    # continuous along the clip (as Motion.dof_pos is), x and z swing to ~170 deg, outside the hip's
    # range, which is what the check reports.
    from smpl_envs.motion.kinematics import Segments, hinge_angles
    raw = shipped("stand")
    flexion = np.deg2rad(np.linspace(-60.0, -120.0, raw.num_frames))
    sideways = np.array([np.cos(np.deg2rad(2.5)), 0.0, 0.0, np.sin(np.deg2rad(2.5))])
    local = raw.local_quat.copy()
    hip = BODY_NAMES.index("L_Hip")
    local[:, hip] = quat_mul(sideways, np.stack(
        [np.cos(flexion / 2), 0 * flexion, np.sin(flexion / 2), 0 * flexion], -1))
    x = slice(3 * (hip - 1), 3 * hip)
    per_frame = hinge_angles(local)[:, x]
    assert np.degrees(np.abs(np.diff(per_frame, axis=0)).max()) > 150
    kept = hinge_angles(local, Segments.from_lengths([raw.num_frames]))[:, x]
    assert np.degrees(np.abs(np.diff(kept, axis=0)).max()) < 20 and np.degrees(np.abs(kept[-1, 0])) > 150
    report = check_motion(edited(raw, local_quat=local))
    assert "joint range" in report.failed and not report.ok
    assert np.degrees(report.max_joint_step) < 5
