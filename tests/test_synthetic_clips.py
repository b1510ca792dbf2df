"""Plausibility of the shipped synthetic clips (smpl_envs/motion/clips, made by
smpl_envs.motion.synthetic): they load, last 2-10 s, keep the feet on and never in the floor, fly
ballistically, do not slide their feet, move at their intended speeds, use human-like knees,
reproduce from code, and pose the MuJoCo humanoid the way the motion pipeline says they do."""

from __future__ import annotations

from functools import lru_cache

import mujoco
import numpy as np
import pytest

from smpl_envs.humanoid import build_humanoid
from smpl_envs.humanoid.skeleton import BODY_NAMES, HINGE_NAMES, MEAN_SKELETON
from smpl_envs.humanoid.kinematics import forward_kinematics, lowest_point
from smpl_envs.motion.loaders import read_motion_file
from smpl_envs.motion.motion import Motion
from smpl_envs.motion.synthetic import CLIP_NAMES, CLIPS_DIR, GRAVITY, generate
from smpl_envs.rotations import quat_apply, quat_inv, quat_mul

FLYING = ("run", "jump")
PLANTED = ("stand", "walk", "turn", "crouch", "kick", "gesture")
FEET = ((BODY_NAMES.index("L_Ankle"), BODY_NAMES.index("L_Toe")),
        (BODY_NAMES.index("R_Ankle"), BODY_NAMES.index("R_Toe")))


@lru_cache(maxsize=None)
def shipped(name: str):
    raw = read_motion_file(CLIPS_DIR / f"{name}.npz")[0]
    return raw, Motion.from_raw(raw)


@lru_cache(maxsize=None)
def kinematics(name: str):
    raw, _ = shipped(name)
    pos, quat = forward_kinematics(raw.root_pos, raw.local_quat, MEAN_SKELETON.offsets)
    return pos, quat, lowest_point(pos, quat, MEAN_SKELETON)


def foot_corners(pos, quat, foot):
    """World positions (T, 16, 3) of the corners of a foot's two boxes (heel/ankle and toe)."""
    points, _ = MEAN_SKELETON.support_points()
    return np.concatenate(
        [pos[:, b, None] + quat_apply(quat[:, b, None], points[b]) for b in foot], axis=1)


@pytest.mark.parametrize("name", CLIP_NAMES)
def test_clip_loads_with_sane_length(name):
    raw, motion = shipped(name)
    assert raw.fps == 30.0 and motion.fps == 30.0
    assert 2.0 <= motion.duration <= 10.0
    assert np.all(np.isfinite(motion.qpos)) and np.all(np.isfinite(motion.qvel))
    # Already on the floor: the pipeline's grounding shift is (numerically) zero.
    assert np.allclose(motion.qpos[:, :3], raw.root_pos, atol=1e-6)


@pytest.mark.parametrize("name", CLIP_NAMES)
def test_regenerating_reproduces_the_shipped_clip(name):
    raw, _ = shipped(name)
    fresh = generate(name)
    assert fresh.fps == raw.fps and fresh.num_frames == raw.num_frames
    np.testing.assert_allclose(fresh.root_pos, raw.root_pos, atol=1e-6)
    # q and -q are the same rotation; compare up to sign.
    dots = np.abs(np.sum(fresh.local_quat * raw.local_quat, -1))
    assert np.all(dots > 1 - 1e-9)


@pytest.mark.parametrize("name", CLIP_NAMES)
def test_on_the_floor_never_in_it(name):
    _, _, low = kinematics(name)
    assert low.min() >= -0.01, f"penetrates the floor by {-low.min():.3f} m"
    if name in PLANTED:
        assert low.max() <= 0.01, f"floats {low.max():.3f} m above the floor"
    else:
        assert (low > 0.01).any(), "a run / jump has a flight phase"


@pytest.mark.parametrize("name", FLYING)
def test_flight_is_ballistic(name):
    raw, _ = shipped(name)
    _, _, low = kinematics(name)
    air = low > 0.005
    # Frames whose neighbours are airborne too: the pelvis' second difference is -g dt^2.
    inner = np.flatnonzero(air[1:-1] & air[:-2] & air[2:]) + 1
    assert len(inner) >= 3
    z = raw.root_pos[:, 2]
    acc = (z[inner + 1] - 2 * z[inner] + z[inner - 1]) * raw.fps ** 2
    np.testing.assert_allclose(acc, -GRAVITY, atol=0.05)
    # Horizontal velocity is constant in the air (no push-off from nothing).
    xy = raw.root_pos[:, :2]
    acc_xy = (xy[inner + 1] - 2 * xy[inner] + xy[inner - 1]) * raw.fps ** 2
    assert np.abs(acc_xy).max() < 0.5


@pytest.mark.parametrize("name", CLIP_NAMES)
def test_feet_in_contact_do_not_slide(name):
    pos, quat, _ = kinematics(name)
    fps = shipped(name)[0].fps
    for foot in FEET:
        corners = foot_corners(pos, quat, foot)
        touching = (corners[:-1, :, 2] < 0.01) & (corners[1:, :, 2] < 0.01)
        speed = np.linalg.norm(np.diff(corners[..., :2], axis=0), axis=-1) * fps
        if touching.any():
            # A touching corner can only pivot (heel rising, toe lifting): tiny, brief motion.
            assert speed[touching].mean() < 0.05, BODY_NAMES[foot[0]]
    if name in ("walk", "turn", "crouch", "kick"):
        # The lower ankle, while within 3 cm of its lowest height, is (nearly) planted.
        ankles = pos[:, [f[0] for f in FEET]]
        lower = ankles[np.arange(len(ankles)), np.argmin(ankles[..., 2], axis=1)]
        near = lower[:-1, 2] - lower[:, 2].min() < 0.03
        speed = np.linalg.norm(np.diff(lower[:, :2], axis=0), axis=-1) * fps
        assert near.any() and speed[near].mean() < 0.3


@pytest.mark.parametrize("name, lo, hi", [("walk", 1.1, 1.5), ("run", 2.6, 3.4)])
def test_locomotion_speed(name, lo, hi):
    raw, motion = shipped(name)
    step = np.linalg.norm(np.diff(raw.root_pos[:, :2], axis=0), axis=-1)
    assert lo <= step.sum() / motion.duration <= hi
    assert lo <= np.linalg.norm(raw.root_pos[-1, :2] - raw.root_pos[0, :2]) / motion.duration <= hi


def test_turn_turns_and_in_place_clips_stay():
    _, turn = shipped("turn")
    forward = quat_apply(turn.body_quat[:, 0], [1.0, 0.0, 0.0])
    heading = np.unwrap(np.arctan2(forward[:, 1], forward[:, 0]))
    assert abs(heading[-1] - heading[0]) >= np.pi
    for name in ("stand", "gesture", "crouch", "kick"):
        raw, _ = shipped(name)
        assert np.ptp(raw.root_pos[:, :2], axis=0).max() < 0.25, name
    _, crouch = shipped("crouch")
    assert np.ptp(crouch.qpos[:, 2]) > 0.15  # it does squat


@pytest.mark.parametrize("name", CLIP_NAMES)
def test_smooth_and_human_like(name):
    raw, motion = shipped(name)
    pos, _, _ = kinematics(name)
    speed = np.linalg.norm(np.diff(pos, axis=0), axis=-1) * raw.fps
    assert speed.max() < 12.0
    # No joint rotates by more than 45 degrees between frames (1350 deg/s).
    rel = quat_mul(quat_inv(raw.local_quat[:-1]), raw.local_quat[1:])
    angle = 2 * np.arccos(np.clip(np.abs(rel[..., 0]), 0, 1))
    assert np.degrees(angle.max()) < 45
    # Hinge angles as the pipeline derives them are continuous too (no Euler branch flips).
    assert np.degrees(np.abs(np.diff(motion.dof_pos, axis=0)).max()) < 45
    # Knees bend forwards only, within the anatomical range.
    for knee in ("L_Knee", "R_Knee"):
        flex = np.degrees(motion.dof_pos[:, HINGE_NAMES.index(f"{knee}_y")])
        side = np.degrees(motion.dof_pos[:, [HINGE_NAMES.index(f"{knee}_x"), HINGE_NAMES.index(f"{knee}_z")]])
        assert flex.min() > -5 and flex.max() < 150, knee
        assert np.abs(side).max() < 1.0, knee


@pytest.mark.parametrize("name", CLIP_NAMES)
def test_humanoid_takes_every_pose_above_the_floor(name):
    model = _humanoid()
    data = mujoco.MjData(model)
    _, motion = shipped(name)
    body_ids = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, b) for b in BODY_NAMES]
    foot_geoms = [g for g in range(model.ngeom) if model.geom_type[g] == mujoco.mjtGeom.mjGEOM_BOX]
    corners = np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1])).T.reshape(-1, 3)
    lowest = np.inf
    for t in range(0, motion.num_frames, 3):
        data.qpos[:] = motion.qpos[t]
        mujoco.mj_kinematics(model, data)
        # MuJoCo places the bodies exactly where the motion pipeline says.
        np.testing.assert_allclose(data.xpos[body_ids], motion.body_pos[t], atol=1e-6)
        for g in foot_geoms:
            world = data.geom_xpos[g] + (corners * model.geom_size[g]) @ data.geom_xmat[g].reshape(3, 3).T
            lowest = min(lowest, world[:, 2].min())
    assert len(foot_geoms) == 4 and lowest > -0.01


@lru_cache(maxsize=1)
def _humanoid():
    return build_humanoid()
