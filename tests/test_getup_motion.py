"""The get-up generator (smpl_envs.motion.getup): from lying on the front or the back to standing,
physically plausible by the corpus' own checks, and strict about its parameters."""

from __future__ import annotations

import numpy as np
import pytest

from smpl_envs.humanoid.kinematics import forward_kinematics
from smpl_envs.humanoid.skeleton import BODY_NAMES, MEAN_SKELETON
from smpl_envs.motion.getup import getup
from smpl_envs.motion.plausibility import check_motion
from smpl_envs.rotations import quat_apply

HEAD = BODY_NAMES.index("Head")


@pytest.mark.parametrize("start,side,roll", [("front", "L", "L"), ("front", "R", "L"), ("back", "L", "R"),
                                             ("back", "R", "L")])
def test_a_getup_goes_from_the_floor_to_standing_and_is_plausible(start, side, roll):
    raw = getup(start, side, roll)
    report = check_motion(raw)
    assert report.ok, report.violations
    pos, quat = forward_kinematics(raw.root_pos, raw.local_quat, MEAN_SKELETON.offsets)
    up = quat_apply(quat[:, 0], np.array([0.0, 0.0, 1.0]))  # the pelvis' up axis
    assert pos[0, HEAD, 2] < 0.25 and abs(up[0, 2]) < 0.3  # lying: head low, body horizontal
    face = quat_apply(quat[0, 0], np.array([1.0, 0.0, 0.0]))  # the pelvis' forward axis
    assert (face[2] < -0.7) if start == "front" else (face[2] > 0.7)  # face down / face up
    assert pos[-1, HEAD, 2] > 1.4 and up[-1, 2] > 0.99  # standing upright at the end
    still = np.linalg.norm(np.diff(raw.root_pos[-10:], axis=0), axis=-1) * raw.fps
    assert still.max() < 0.02  # and still, so the clip chains


def test_a_getup_is_a_function_of_its_parameters():
    a, b = getup("back", tempo=0.9), getup("back", tempo=0.9)
    assert np.array_equal(a.root_pos, b.root_pos) and np.array_equal(a.local_quat, b.local_quat)
    slow, fast = getup("front", tempo=0.8), getup("front", tempo=1.2)
    assert slow.num_frames > fast.num_frames


@pytest.mark.parametrize("kwargs,match", [({"start": "side"}, "start"), ({"side": "X"}, "side"),
                                          ({"tempo": 3.0}, "tempo"), ({"hand_width": "wide"}, "hand_width"),
                                          ({"lie": float("nan")}, "lie")])
def test_bad_parameters_are_named(kwargs, match):
    with pytest.raises(ValueError, match=match):
        getup(**kwargs)
