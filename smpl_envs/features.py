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


# ---------------------------------------------------------------------- rotations
# R (row-major, 9) = outer(q, q) (16) @ _QUAT_TO_MAT: every entry of a unit quaternion's matrix
# is a fixed combination of the products q_i q_j, so the conversion is two batched operations.
_QUAT_TO_MAT = np.zeros((16, 9))
for _entry, _terms in enumerate([
    ((0, 0, 1), (1, 1, 1), (2, 2, -1), (3, 3, -1)), ((1, 2, 2), (0, 3, -2)), ((1, 3, 2), (0, 2, 2)),
    ((1, 2, 2), (0, 3, 2)), ((0, 0, 1), (1, 1, -1), (2, 2, 1), (3, 3, -1)), ((2, 3, 2), (0, 1, -2)),
    ((1, 3, 2), (0, 2, -2)), ((2, 3, 2), (0, 1, 2)), ((0, 0, 1), (1, 1, -1), (2, 2, -1), (3, 3, 1)),
]):
    for _i, _j, _c in _terms:
        _QUAT_TO_MAT[4 * _i + _j, _entry] = _c


def rotmat_from_quat(q):
    """(..., 4) unit quaternions (w, x, y, z) -> (..., 3, 3) rotation matrices."""
    m = xp(q)
    outer = (q[..., :, None] * q[..., None, :]).reshape(*q.shape[:-1], 16)
    return (outer @ _const(m, _QUAT_TO_MAT, q)).reshape(*q.shape[:-1], 3, 3)


def quat_from_rotmat(r):
    """(..., 3, 3) rotation matrices -> (..., 4) unit quaternions (w, x, y, z), w >= 0. Each of
    the four textbook formulas divides by one of w, x, y, z; the one with the largest divisor is
    taken per matrix, so the result is accurate at every angle, a half turn included."""
    m = xp(r)
    r00, r11, r22 = r[..., 0, 0], r[..., 1, 1], r[..., 2, 2]
    t = m.stack([1 + r00 + r11 + r22, 1 + r00 - r11 - r22, 1 - r00 + r11 - r22, 1 - r00 - r11 + r22], -1)
    a, b, c = r[..., 2, 1] - r[..., 1, 2], r[..., 0, 2] - r[..., 2, 0], r[..., 1, 0] - r[..., 0, 1]
    d, e, f = r[..., 0, 1] + r[..., 1, 0], r[..., 0, 2] + r[..., 2, 0], r[..., 1, 2] + r[..., 2, 1]
    cand = m.stack([m.stack([t[..., 0], a, b, c], -1), m.stack([a, t[..., 1], d, e], -1),
                    m.stack([b, d, t[..., 2], f], -1), m.stack([c, e, f, t[..., 3]], -1)], -2)
    cand = cand / (2.0 * m.sqrt(t.clip(min=1e-12)))[..., None]
    four = m.arange(4) if m is np else m.arange(4, device=r.device)
    q = (cand * (t.argmax(-1)[..., None] == four)[..., None]).sum(-2)
    return q * m.where(q[..., :1] < 0, -1.0, 1.0)


def rot6d(rot):
    """(..., 3, 3) -> (..., 6): first two columns, row by row."""
    return rot[..., :, :2].reshape(*rot.shape[:-2], 6)


def rotation_angle(a, b):
    """Angle (rad) of the relative rotation between matching rotation matrices a and b."""
    cos = ((a * b).sum(axis=(-1, -2)) - 1.0) * 0.5  # trace(a^T b) = sum of elementwise product
    return xp(a, b).arccos(cos.clip(-1.0, 1.0))


# H (row-major, 9) = (cos, sin) @ _HEADING_BASIS + _HEADING_CONST: a rotation about z.
_HEADING_BASIS = np.array([[1, 0, 0, 0, 1, 0, 0, 0, 0], [0, -1, 0, 1, 0, 0, 0, 0, 0]], float)
_HEADING_CONST = np.array([0, 0, 0, 0, 0, 0, 0, 0, 1], float)


def _const(m, table, like):
    return table if m is np else m.as_tensor(table, dtype=like.dtype, device=like.device)


def heading_rotation(root_rot):
    """(N, 3, 3) rotations about world z by the yaw of each root's x-axis."""
    m = xp(root_rot)
    x = root_rot[:, :2, 0]
    cs = x / (m.sqrt((x * x).sum(axis=-1))[:, None] + 1e-9)
    return (cs @ _const(m, _HEADING_BASIS, cs) + _const(m, _HEADING_CONST, cs)).reshape(-1, 3, 3)


_HIPS = (BODY_NAMES.index("L_Hip"), BODY_NAMES.index("R_Hip"))
_TORSO = BODY_NAMES.index("Torso")


def facing_height(body_pos):
    """(...,) height of the pelvis' unit forward axis (-1: face down, +1: face up) from body
    positions (..., 24, 3) alone, for callers that see `info["body_pos"]` and no rotations:
    forward = left (right hip to left hip) x up (pelvis to torso)."""
    m = xp(body_pos)
    left = body_pos[..., _HIPS[0], :] - body_pos[..., _HIPS[1], :]
    up = body_pos[..., _TORSO, :] - body_pos[..., 0, :]
    forward = m.stack([left[..., 1] * up[..., 2] - left[..., 2] * up[..., 1],
                       left[..., 2] * up[..., 0] - left[..., 0] * up[..., 2],
                       left[..., 0] * up[..., 1] - left[..., 1] * up[..., 0]], -1)
    return forward[..., 2] / m.sqrt((forward * forward).sum(-1))


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
    ("body_pos", 69, "bodies 1-23 relative to the pelvis (m)"),
    ("body_lin_vel", 72, "24 body linear velocities (m/s)"),
    ("body_ang_vel", 72, "24 body angular velocities (rad/s)"),
    ("body_rot", 144, "24 body rotations, 6D"),
)
IMITATION_GOAL_LAYOUT = (
    ("diff_pos", 72, "reference - simulated body positions (m)"),
    ("diff_lin_vel", 72, "reference - simulated linear velocities (m/s)"),
    ("diff_ang_vel", 72, "reference - simulated angular velocities (rad/s)"),
    ("ref_pos", 72, "reference body positions relative to the simulated pelvis (m)"),
    ("diff_rot", 144, "reference rotation (-) simulated rotation per body, 6D"),
    ("ref_rot", 144, "reference body rotations, 6D"),
)
KEYPOINT_GOAL_LAYOUT = (
    ("diff_pos", 72, "reference - simulated body positions (m)"),
    ("diff_lin_vel", 72, "reference - simulated linear velocities (m/s)"),
    ("ref_pos", 72, "reference body positions relative to the simulated pelvis (m)"),
)
AMP_LAYOUT = (
    ("root_height", 1, "pelvis height (m)"),
    ("root_rot", 6, "pelvis rotation, heading frame, 6D"),
    ("root_lin_vel", 3, "pelvis linear velocity, heading frame (m/s)"),
    ("root_ang_vel", 3, "pelvis angular velocity, heading frame (rad/s)"),
    ("key_body_pos", 12, "ankles and hands relative to the pelvis, heading frame (m)"),
    ("joint_rot", 138, "23 joint rotations relative to the parent body, 6D"),
    ("dof_vel", 69, "hinge rates (rad/s)"),
)


def layout_size(layout) -> int:
    return sum(n for _, n, _ in layout)


def self_obs(s: BodyState, heading):
    """Proprioception (N, 358), heading frame, layout SELF_OBS_LAYOUT."""
    m = xp(s.pos)
    n = s.pos.shape[0]
    vectors = m.concatenate([s.pos[:, 1:] - s.pos[:, :1], s.lin_vel, s.ang_vel], 1)
    return m.concatenate([s.pos[:, 0, 2:3], to_heading(vectors, heading).reshape(n, -1),
                          rot6d(rot_to_heading(s.rot, heading)).reshape(n, -1)], -1)


def tracking_obs(s: BodyState, ref: BodyState, goal: str = "rotation", heading=None):
    """Self observation followed by the imitation goal towards `ref`, heading frame:
    (N, 358 + 576) for goal="rotation" (IMITATION_GOAL_LAYOUT), (N, 358 + 216) for "keypoint"
    (KEYPOINT_GOAL_LAYOUT). The first 358 columns equal `self_obs`.

    Written as one heading transform of every vector and one of every rotation, because on the
    CPU a single env's step time is dominated by the number of array operations, not their size.
    """
    m = xp(s.pos)
    n, nb = s.pos.shape[:2]
    heading = heading_rotation(s.rot[:, 0]) if heading is None else heading
    root = s.pos[:, :1]
    vectors = [s.pos[:, 1:] - root, s.lin_vel, s.ang_vel, ref.pos - s.pos, ref.lin_vel - s.lin_vel]
    if goal == "rotation":
        vectors.append(ref.ang_vel - s.ang_vel)
    vectors.append(ref.pos - root)
    v = to_heading(m.concatenate(vectors, 1), heading).reshape(n, -1)
    split = 3 * (3 * nb - 1)  # pos (23) + lin vel + ang vel (24 each) belong to the self part
    if goal == "keypoint":
        return m.concatenate([s.pos[:, 0, 2:3], v[:, :split],
                              rot6d(rot_to_heading(s.rot, heading)).reshape(n, -1), v[:, split:]], -1)
    if goal != "rotation":
        raise ValueError(f"goal must be 'rotation' or 'keypoint', got {goal!r}")
    rots = rot_to_heading(m.concatenate([s.rot, ref.rot], 1), heading)
    sim_rot, ref_rot = rots[:, :nb], rots[:, nb:]
    diff = ref_rot @ sim_rot.swapaxes(-1, -2)  # = H^T R_ref R_sim^T H
    return m.concatenate([s.pos[:, 0, 2:3], v[:, :split], rot6d(sim_rot).reshape(n, -1), v[:, split:],
                          rot6d(diff).reshape(n, -1), rot6d(ref_rot).reshape(n, -1)], -1)


def _self_obs_columns() -> np.ndarray:
    # Columns of the self observation that the AMP features reuse (same quantities, same frame).
    at = {name: start for name, start in zip([n for n, _, _ in SELF_OBS_LAYOUT],
                                             np.cumsum([0] + [k for _, k, _ in SELF_OBS_LAYOUT]))}
    key = [at["body_pos"] + 3 * (b - 1) + np.arange(3) for b in KEY_BODIES]
    return np.concatenate([[at["root_height"]], at["body_rot"] + np.arange(6),
                           at["body_lin_vel"] + np.arange(3), at["body_ang_vel"] + np.arange(3), *key])


AMP_FROM_SELF_OBS = _self_obs_columns()


def amp_features(s: BodyState, heading=None, proprio=None):
    """Per-frame discriminator features (N, 232), layout AMP_LAYOUT. The same function serves the
    simulated humanoid and the reference motion (`MotionLib.amp_features`).

    The root and key-body terms are columns of the self observation; pass `proprio` (the
    `self_obs` of `s`, e.g. the first 358 observation columns) to reuse it instead of recomputing.
    """
    m = xp(s.pos)
    n = s.pos.shape[0]
    if proprio is None:
        proprio = self_obs(s, heading_rotation(s.rot[:, 0]) if heading is None else heading)
    local_rot = s.rot[:, _PARENT_IDX].swapaxes(-1, -2) @ s.rot[:, 1:]
    return m.concatenate([proprio[:, AMP_FROM_SELF_OBS], rot6d(local_rot).reshape(n, -1), s.dof_vel], -1)


def layout_slices(layouts: dict[str, tuple]) -> dict[str, slice]:
    """{"group/name": slice} over consecutive layouts, for `observation_structure`."""
    out, start = {}, 0
    for group, layout in layouts.items():
        for name, size, _ in layout:
            out[f"{group}/{name}"] = slice(start, start + size)
            start += size
    return out


def goal_layout(bodies: int) -> tuple:
    """IMITATION_GOAL_LAYOUT for `bodies` tracked bodies (same blocks, same order, 24 per body)."""
    return tuple((name, size // NUM_BODIES * bodies, what) for name, size, what in IMITATION_GOAL_LAYOUT)


def body_goal_obs(s: BodyState, ref: BodyState, bodies, heading=None):
    """The rotation imitation goal (IMITATION_GOAL_LAYOUT's six blocks, heading frame) of a
    subset of the bodies: (N, 24 B) for the index array `bodies` (B,), with `ref` holding only
    those bodies' references ((N, B, ...); its dof fields are not read). With every body it
    equals `tracking_obs(s, ref)[:, 358:]`; the VR task uses it for the head and hands."""
    m = xp(s.pos)
    n, nb = ref.pos.shape[:2]
    heading = heading_rotation(s.rot[:, 0]) if heading is None else heading
    pos = s.pos[:, bodies]
    v = to_heading(m.concatenate([ref.pos - pos, ref.lin_vel - s.lin_vel[:, bodies],
                                  ref.ang_vel - s.ang_vel[:, bodies], ref.pos - s.pos[:, :1]], 1), heading)
    rots = rot_to_heading(m.concatenate([s.rot[:, bodies], ref.rot], 1), heading)
    sim_rot, ref_rot = rots[:, :nb], rots[:, nb:]
    diff = ref_rot @ sim_rot.swapaxes(-1, -2)
    return m.concatenate([v.reshape(n, -1), rot6d(diff).reshape(n, -1), rot6d(ref_rot).reshape(n, -1)], -1)
