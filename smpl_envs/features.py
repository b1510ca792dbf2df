"""Pure, batched features of humanoid body states: heading frame, observations, AMP features.

Every function takes arrays of shape (N, ...) and works unchanged on numpy arrays and on torch
tensors (CPU or CUDA): only operators and functions the two share are used, and `xp(...)` picks
the module. That is the contract a GPU physics backend relies on: it hands tensors to the same
task functions (`tests/test_features.py` checks numpy and torch agree).

Rotations are 3x3 matrices here, not quaternions: MuJoCo computes them anyway, and a change of
frame is then one batched matmul. "6D" rotation = the first two columns of the matrix, flattened
row by row (R00, R01, R10, R11, R20, R21).

The heading frame of a humanoid: origin at its root (pelvis), rotated about world z by the root's
yaw (the direction of the pelvis x-axis in the ground plane), so that "forward" is +x.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from .humanoid.skeleton import BODY_NAMES, PARENTS

NUM_BODIES = len(BODY_NAMES)
KEY_BODIES = tuple(BODY_NAMES.index(n) for n in ("L_Ankle", "R_Ankle", "L_Hand", "R_Hand"))
_PARENT_IDX = np.asarray(PARENTS[1:])


def xp(*arrays):
    """numpy, or torch if any argument is a torch tensor."""
    for a in arrays:
        if type(a).__module__.startswith("torch"):
            import torch

            return torch
    return np


@dataclass
class BodyState:
    """State of N humanoids: world-frame arrays over the 24 bodies in BODY_NAMES order.

    pos (N, 24, 3) m, rot (N, 24, 3, 3) body-to-world rotation matrices, lin_vel (N, 24, 3) m/s
    of each body origin, ang_vel (N, 24, 3) rad/s, dof_pos / dof_vel (N, 69) hinge angles (rad)
    and rates (rad/s).
    """

    pos: np.ndarray
    rot: np.ndarray
    lin_vel: np.ndarray
    ang_vel: np.ndarray
    dof_pos: np.ndarray
    dof_vel: np.ndarray

    def __getitem__(self, idx) -> "BodyState":
        return BodyState(**{f.name: getattr(self, f.name)[idx] for f in fields(self)})

    def copy(self) -> "BodyState":
        return BodyState(**{f.name: getattr(self, f.name).copy() for f in fields(self)})


# ---------------------------------------------------------------------- rotations
def rotmat_from_quat(q):
    """(..., 4) unit quaternions (w, x, y, z) -> (..., 3, 3) rotation matrices."""
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    m = xp(q).stack([
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    ], -1)
    return m.reshape(*q.shape[:-1], 3, 3)


def rot6d(rot):
    """(..., 3, 3) -> (..., 6): first two columns, row by row."""
    return rot[..., :, :2].reshape(*rot.shape[:-2], 6)


def rotation_angle(a, b):
    """Angle (rad) of the relative rotation between matching rotation matrices a and b."""
    m = xp(a, b)
    cos = ((a * b).sum(axis=(-1, -2)) - 1.0) * 0.5  # trace(a^T b) = sum of elementwise product
    return m.arccos(m.clip(cos, -1.0, 1.0))


def heading_rotation(root_rot):
    """(N, 3, 3) rotations about world z by the yaw of each root's x-axis."""
    m = xp(root_rot)
    cx, sx = root_rot[:, 0, 0], root_rot[:, 1, 0]
    norm = m.sqrt(cx * cx + sx * sx) + 1e-9
    c, s = cx / norm, sx / norm
    zero, one = c * 0, c * 0 + 1
    return m.stack([c, -s, zero, s, c, zero, zero, zero, one], -1).reshape(-1, 3, 3)


def to_heading(v, heading):
    """World vectors (N, ..., 3) expressed in each humanoid's heading frame (rotation only)."""
    # Row vectors: (H^T v)^T = v^T H, so one matmul; flatten middle axes for a single batch.
    return (v.reshape(v.shape[0], -1, 3) @ heading).reshape(v.shape)


def rot_to_heading(rot, heading):
    """World rotations (N, B, 3, 3) expressed in the heading frame: H^T R."""
    return heading.swapaxes(-1, -2)[:, None] @ rot


# ---------------------------------------------------------------------- observations
SELF_OBS_LAYOUT = (
    ("root_height", 1, "pelvis height above the floor (m)"),
    ("body_pos", 69, "bodies 1-23 relative to the pelvis, heading frame (m)"),
    ("body_rot", 144, "24 body rotations, heading frame, 6D"),
    ("body_lin_vel", 72, "24 body linear velocities, heading frame (m/s)"),
    ("body_ang_vel", 72, "24 body angular velocities, heading frame (rad/s)"),
)
IMITATION_GOAL_LAYOUT = (
    ("diff_rot", 144, "reference (-) simulated rotation per body, heading frame, 6D"),
    ("diff_pos", 72, "reference - simulated body position, heading frame (m)"),
    ("diff_lin_vel", 72, "reference - simulated linear velocity, heading frame (m/s)"),
    ("diff_ang_vel", 72, "reference - simulated angular velocity, heading frame (rad/s)"),
    ("ref_rot", 144, "reference rotation per body, heading frame, 6D"),
    ("ref_pos", 72, "reference body position relative to the simulated pelvis, heading frame (m)"),
)
KEYPOINT_GOAL_LAYOUT = (
    ("diff_pos", 72, "reference - simulated body position, heading frame (m)"),
    ("diff_lin_vel", 72, "reference - simulated linear velocity, heading frame (m/s)"),
    ("ref_pos", 72, "reference body position relative to the simulated pelvis, heading frame (m)"),
)
AMP_LAYOUT = (
    ("root_height", 1, "pelvis height (m)"),
    ("root_rot", 6, "pelvis rotation, heading frame, 6D"),
    ("root_lin_vel", 3, "pelvis linear velocity, heading frame (m/s)"),
    ("root_ang_vel", 3, "pelvis angular velocity, heading frame (rad/s)"),
    ("joint_rot", 138, "23 joint rotations relative to the parent body, 6D"),
    ("dof_vel", 69, "hinge rates (rad/s)"),
    ("key_body_pos", 12, "ankles and hands relative to the pelvis, heading frame (m)"),
)


def layout_size(layout) -> int:
    return sum(n for _, n, _ in layout)


def self_obs(s: BodyState, heading):
    """Proprioception (N, 358), layout SELF_OBS_LAYOUT."""
    m = xp(s.pos)
    n = s.pos.shape[0]
    root = s.pos[:, :1]
    return m.concatenate([
        s.pos[:, 0, 2:3],
        to_heading(s.pos[:, 1:] - root, heading).reshape(n, -1),
        rot6d(rot_to_heading(s.rot, heading)).reshape(n, -1),
        to_heading(s.lin_vel, heading).reshape(n, -1),
        to_heading(s.ang_vel, heading).reshape(n, -1),
    ], -1)


def imitation_goal(s: BodyState, ref: BodyState, heading):
    """Rotation-based imitation goal (N, 576), layout IMITATION_GOAL_LAYOUT (blocks of 24 bodies)."""
    m = xp(s.pos)
    n = s.pos.shape[0]
    diff_rot = rot_to_heading(ref.rot @ s.rot.swapaxes(-1, -2), heading) @ heading[:, None]
    return m.concatenate([
        rot6d(diff_rot).reshape(n, -1),
        to_heading(ref.pos - s.pos, heading).reshape(n, -1),
        to_heading(ref.lin_vel - s.lin_vel, heading).reshape(n, -1),
        to_heading(ref.ang_vel - s.ang_vel, heading).reshape(n, -1),
        rot6d(rot_to_heading(ref.rot, heading)).reshape(n, -1),
        to_heading(ref.pos - s.pos[:, :1], heading).reshape(n, -1),
    ], -1)


def keypoint_goal(s: BodyState, ref: BodyState, heading):
    """Keypoint-only imitation goal (N, 216), layout KEYPOINT_GOAL_LAYOUT."""
    m = xp(s.pos)
    n = s.pos.shape[0]
    return m.concatenate([
        to_heading(ref.pos - s.pos, heading).reshape(n, -1),
        to_heading(ref.lin_vel - s.lin_vel, heading).reshape(n, -1),
        to_heading(ref.pos - s.pos[:, :1], heading).reshape(n, -1),
    ], -1)


def amp_features(s: BodyState):
    """Per-frame discriminator features (N, 232), layout AMP_LAYOUT. The same function serves the
    simulated humanoid and the reference motion (`MotionLib.amp_features`)."""
    m = xp(s.pos)
    n = s.pos.shape[0]
    heading = heading_rotation(s.rot[:, 0])
    root_rot = rot_to_heading(s.rot[:, :1], heading)
    local_rot = s.rot[:, _PARENT_IDX].swapaxes(-1, -2) @ s.rot[:, 1:]
    return m.concatenate([
        s.pos[:, 0, 2:3],
        rot6d(root_rot).reshape(n, -1),
        to_heading(s.lin_vel[:, 0], heading),
        to_heading(s.ang_vel[:, 0], heading),
        rot6d(local_rot).reshape(n, -1),
        s.dof_vel,
        to_heading(s.pos[:, list(KEY_BODIES)] - s.pos[:, :1], heading).reshape(n, -1),
    ], -1)


def layout_slices(layouts: dict[str, tuple]) -> dict[str, slice]:
    """{"group/name": slice} over consecutive layouts, for `observation_structure`."""
    out, start = {}, 0
    for group, layout in layouts.items():
        for name, size, _ in layout:
            out[f"{group}/{name}"] = slice(start, start + size)
            start += size
    return out
