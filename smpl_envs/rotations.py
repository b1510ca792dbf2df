"""Quaternion helpers in MuJoCo's (w, x, y, z) convention, batched over any leading shape.

Conversions go through `scipy.spatial.transform.Rotation` (well tested, vectorised), which stores
(x, y, z, w) and only takes flat stacks: here we reshape and pin the scalar-first order so the
rest of the package never thinks about either. Products and vector rotations are written out in
numpy, because scipy's measured ~20x slower on 300k-frame stacks; they neither renormalise nor
canonicalise the sign. Conversions return w >= 0.
"""

from __future__ import annotations

import warnings

import numpy as np
from scipy.spatial.transform import Rotation


def _rot(q: np.ndarray) -> Rotation:
    return Rotation.from_quat(np.require(np.reshape(q, (-1, 4)), float, 'CW'), scalar_first=True)


def _quat(r: Rotation, shape: tuple[int, ...]) -> np.ndarray:
    q = r.as_quat(canonical=True, scalar_first=True)  # w >= 0: one sign per rotation
    return q.reshape(*shape, 4)


def quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a * b (apply b first, then a). Leading shapes broadcast."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    aw, ax, ay, az = np.moveaxis(a, -1, 0)
    bw, bx, by, bz = np.moveaxis(b, -1, 0)
    return np.stack([
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    ], -1)


def quat_inv(q: np.ndarray) -> np.ndarray:
    return np.asarray(q) * np.array([1.0, -1.0, -1.0, -1.0])


def quat_apply(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate vectors v (..., 3) by q (..., 4). Leading shapes broadcast."""
    # v' = v + 2w (u x v) + 2 u x (u x v), u the vector part: numpy-fast on large stacks.
    q, v = np.asarray(q, float), np.asarray(v, float)
    u, w = q[..., 1:], q[..., :1]
    uv = np.cross(u, v)
    return v + 2.0 * (w * uv + np.cross(u, uv))


def quat_z_axis_row(q: np.ndarray) -> np.ndarray:
    """Third row of q's rotation matrix: the world z of a rotated vector is this row . v."""
    w, x, y, z = np.moveaxis(np.asarray(q, float), -1, 0)
    return np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1)


def quat_from_rotvec(rv: np.ndarray) -> np.ndarray:
    rv = np.asarray(rv, float)
    return _quat(Rotation.from_rotvec(rv.reshape(-1, 3)), rv.shape[:-1])


def quat_to_rotvec(q: np.ndarray) -> np.ndarray:
    return _rot(q).as_rotvec().reshape(*np.shape(q)[:-1], 3)


def quat_from_matrix(m: np.ndarray) -> np.ndarray:
    m = np.asarray(m, float)
    return _quat(Rotation.from_matrix(m.reshape(-1, 3, 3)), m.shape[:-2])


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    return _rot(q).as_matrix().reshape(*np.shape(q)[:-1], 3, 3)


def quat_from_euler_xyz(angles: np.ndarray) -> np.ndarray:
    """Intrinsic x-then-y-then-z rotation: how MuJoCo composes a body's x, y, z hinges."""
    angles = np.asarray(angles, float)
    return _quat(Rotation.from_euler("XYZ", angles.reshape(-1, 3)), angles.shape[:-1])


def quat_to_euler_xyz(q: np.ndarray) -> np.ndarray:
    """Inverse of quat_from_euler_xyz; angles in (-pi, pi], the middle one in [-pi/2, pi/2]."""
    with warnings.catch_warnings():
        # At the middle angle +-pi/2 scipy warns and sets the third angle to 0: the angles still
        # compose to the rotation, which is all callers need (a knee or hip bent 90 deg is common).
        warnings.filterwarnings("ignore", message="Gimbal lock detected")
        return _rot(q).as_euler("XYZ").reshape(*np.shape(q)[:-1], 3)


def quat_slerp(q0: np.ndarray, q1: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Shortest-arc interpolation; t (...,) or (..., 1) broadcasts against q0, q1 (..., 4)."""
    q0, q1 = np.asarray(q0), np.asarray(q1)
    t = np.asarray(t, q0.dtype)
    if t.ndim and t.shape[-1] != 1:
        t = t[..., None]
    dot = np.sum(q0 * q1, -1, keepdims=True)
    q1 = np.where(dot < 0, -q1, q1)  # q and -q are one rotation: take the short way round
    dot = np.clip(np.abs(dot), 0.0, 1.0)
    theta = np.arccos(dot)
    sin = np.sin(theta)
    near = sin < 1e-6  # (almost) equal rotations: linear blend, then renormalise
    safe = np.where(near, 1.0, sin)
    w0 = np.where(near, 1.0 - t, np.sin((1.0 - t) * theta) / safe)
    w1 = np.where(near, t, np.sin(t * theta) / safe)
    q = w0 * q0 + w1 * q1
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def yaw_quat(yaw: np.ndarray) -> np.ndarray:
    """Rotations about world z by the given angles."""
    yaw = np.asarray(yaw, float)
    return np.stack([np.cos(yaw / 2), 0 * yaw, 0 * yaw, np.sin(yaw / 2)], -1)
