"""Pure feature functions: known answers, numpy/torch agreement, and the env/MotionLib AMP path."""

import numpy as np
import pytest
import torch

from smpl_envs.features import (AMP_LAYOUT, IMITATION_GOAL_LAYOUT, KEYPOINT_GOAL_LAYOUT,
                                SELF_OBS_LAYOUT, BodyState, amp_features, heading_rotation,
                                layout_size, quat_from_rotmat, rotation_angle, rotmat_from_quat, self_obs,
                                to_heading, tracking_obs)
from smpl_envs.motion import MotionLib
from smpl_envs.rotations import quat_from_rotvec, quat_to_matrix, yaw_quat


@pytest.fixture(scope="module")
def lib():
    return MotionLib.load(["walk", "turn"], progress=False)


def _state(lib, frames) -> BodyState:
    return lib.body_state(np.asarray(frames))


def test_layout_sizes_match_reference():
    assert layout_size(SELF_OBS_LAYOUT) == 358
    assert layout_size(IMITATION_GOAL_LAYOUT) == 576
    assert layout_size(KEYPOINT_GOAL_LAYOUT) == 216
    assert layout_size(AMP_LAYOUT) == 232


def test_rotmat_from_quat_matches_scipy():
    q = quat_from_rotvec(np.random.default_rng(0).normal(size=(50, 3)))
    np.testing.assert_allclose(rotmat_from_quat(q), quat_to_matrix(q), atol=1e-12)


def test_quat_from_rotmat_inverts_rotmat_from_quat_at_every_angle():
    rv = np.random.default_rng(1).normal(size=(200, 3))
    rv = np.concatenate([rv, np.pi * np.eye(3), np.pi * np.array([[0.6, 0.8, 0]]), np.zeros((1, 3))])  # half turns, none
    m = quat_to_matrix(quat_from_rotvec(rv))
    q = quat_from_rotmat(m)
    assert (q[:, 0] >= 0).all()
    np.testing.assert_allclose(np.linalg.norm(q, axis=-1), 1, atol=1e-12)
    np.testing.assert_allclose(rotmat_from_quat(q), m, atol=1e-12)
    np.testing.assert_allclose(quat_from_rotmat(torch.as_tensor(m)).numpy(), q, atol=1e-12)


def test_heading_removes_yaw_only():
    yaw = np.array([0.3, -2.0, 3.0])
    tilt = quat_from_rotvec(np.array([[0.2, 0.1, 0.0]] * 3))  # pitch/roll must not change heading
    from smpl_envs.rotations import quat_mul
    root = rotmat_from_quat(quat_mul(yaw_quat(yaw), tilt))
    h = heading_rotation(root)
    np.testing.assert_allclose(h, quat_to_matrix(yaw_quat(yaw)), atol=0.03)
    # A vector along the heading direction maps to +x.
    fwd = h[:, :, 0]
    np.testing.assert_allclose(to_heading(fwd, h), np.tile([1.0, 0, 0], (3, 1)), atol=1e-12)


def test_rotation_angle_known():
    a = quat_to_matrix(quat_from_rotvec(np.array([[0.0, 0.0, 0.7], [0.5, 0, 0]])))
    b = np.broadcast_to(np.eye(3), a.shape)
    np.testing.assert_allclose(rotation_angle(a, b), [0.7, 0.5], atol=1e-7)


def test_observations_invariant_to_world_yaw_and_position(lib):
    """Heading frame: turning and shifting the whole scene leaves every observation unchanged."""
    frames = np.array([10, 40, 200])
    sim, ref = _state(lib, frames), _state(lib, frames + 1)
    q = yaw_quat(np.array([1.1]))[0]
    r = quat_to_matrix(q)

    def moved(s):
        return BodyState(pos=s.pos @ r.T + [3.0, -2.0, 0.0], rot=r @ s.rot, lin_vel=s.lin_vel @ r.T,
                         ang_vel=s.ang_vel @ r.T, dof_pos=s.dof_pos, dof_vel=s.dof_vel)

    for goal in ("rotation", "keypoint"):
        a = tracking_obs(sim, ref, goal)
        b = tracking_obs(moved(sim), moved(ref), goal)
        np.testing.assert_allclose(a, b, atol=2e-5)
    np.testing.assert_allclose(amp_features(sim), amp_features(moved(sim)), atol=2e-5)


def test_tracking_obs_starts_with_self_obs_and_goal_is_zero_on_reference(lib):
    s = _state(lib, [5, 77])
    obs = tracking_obs(s, s, "rotation")
    np.testing.assert_allclose(obs[:, :358], self_obs(s, heading_rotation(s.rot[:, 0])), atol=1e-6)
    goal = obs[:, 358:]
    np.testing.assert_allclose(goal[:, :216], 0.0, atol=1e-6)  # position / velocity differences
    diff6 = goal[:, 288:432].reshape(2, 24, 6)  # identity rotation: columns (1,0,0), (0,1,0)
    np.testing.assert_allclose(diff6, np.tile([1, 0, 0, 1, 0, 0], (2, 24, 1)), atol=1e-6)
    assert tracking_obs(s, s, "keypoint").shape == (2, 574)
    with pytest.raises(ValueError, match="goal"):
        tracking_obs(s, s, "bogus")


def test_numpy_and_torch_agree(lib):
    """The contract a GPU backend relies on: the same functions run on torch tensors."""
    s, r = _state(lib, [3, 90, 150]), _state(lib, [4, 91, 151])

    def tt(b):
        return BodyState(**{k: torch.as_tensor(np.asarray(v, np.float64)) for k, v in vars(b).items()})

    for goal in ("rotation", "keypoint"):
        np.testing.assert_allclose(tracking_obs(tt(s), tt(r), goal).numpy(), tracking_obs(s, r, goal), atol=1e-5)
    np.testing.assert_allclose(amp_features(tt(s)).numpy(), amp_features(s), atol=1e-5)
    from smpl_envs.envs.imitation import imitation_reward, imitation_terminated
    force = np.random.default_rng(1).normal(size=(3, 69))
    tot_np, _ = imitation_reward(s, r, force)
    tot_t, _ = imitation_reward(tt(s), tt(r), torch.as_tensor(force))
    np.testing.assert_allclose(tot_t.numpy(), tot_np, rtol=1e-6)
    assert (imitation_terminated(tt(s), tt(r)).numpy() == imitation_terminated(s, r)).all()
    q = torch.as_tensor(lib.body_quat[:5], dtype=torch.float64)
    np.testing.assert_allclose(rotmat_from_quat(q).numpy(), rotmat_from_quat(lib.body_quat[:5].astype(float)), atol=1e-6)


def test_motionlib_amp_features_window(lib):
    f = lib.amp_features(np.array([0, 1]), np.array([1.0, 0.5]), num_frames=10)
    assert f.shape == (2, 10, 232) and f.dtype == np.float32
    # The last frame of the window is the state at the requested time, via the same function.
    frame = lib.starts[0] + 30
    np.testing.assert_allclose(f[0, -1], amp_features(_state(lib, [frame]))[0], atol=1e-4)
    np.testing.assert_allclose(f[0, -2], amp_features(_state(lib, [frame - 1]))[0], atol=1e-4)
