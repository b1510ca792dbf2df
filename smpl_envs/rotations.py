"""Quaternion helpers in MuJoCo's (w, x, y, z) convention, batched over any leading shape.

Conversions go through `scipy.spatial.transform.Rotation` (well tested, vectorised), which stores
(x, y, z, w) and only takes flat stacks: here we reshape and pin the scalar-first order so the
rest of the package never thinks about either. Products do not renormalise or canonicalise the
sign; conversions return w >= 0.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation


def _rot(q: np.ndarray) -> Rotation:
    return Rotation.from_quat(np.require(np.reshape(q, (-1, 4)), float, 'CW'), scalar_first=True)


def _quat(r: Rotation, shape: tuple[int, ...]) -> np.ndarray:
    q = r.as_quat(canonical=True, scalar_first=True)  # w >= 0: one sign per rotation
    return q.reshape(*shape, 4)


def _broadcast(q: np.ndarray, v: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray, tuple]:
    q, v = np.asarray(q, float), np.asarray(v, float)
    shape = np.broadcast_shapes(q.shape[:-1], v.shape[:-1])
    return np.broadcast_to(q, shape + (4,)), np.broadcast_to(v, shape + (n,)), shape


def quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a * b (apply b first, then a). Leading shapes broadcast."""
    # Written out rather than scipy's `*`, which measured ~20x slower on 300k-frame stacks.
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
    q, v, shape = _broadcast(q, v, 3)
    return _rot(q).apply(np.require(v.reshape(-1, 3), requirements='CW')).reshape(shape + (3,))


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
    return _rot(q).as_euler("XYZ").reshape(*np.shape(q)[:-1], 3)


def quat_slerp(q0: np.ndarray, q1: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Shortest-arc interpolation; t broadcasts against the leading shape of q0, q1."""
    q0, q1 = np.broadcast_arrays(q0, q1)
    r0 = _rot(q0)
    rel = (r0.inv() * _rot(q1)).as_rotvec()
    t = np.broadcast_to(np.asarray(t, float)[..., None], q0.shape[:-1] + (1,)).reshape(-1, 1)
    return _quat(r0 * Rotation.from_rotvec(rel * t), q0.shape[:-1])


def yaw_quat(yaw: np.ndarray) -> np.ndarray:
    """Rotations about world z by the given angles."""
    yaw = np.asarray(yaw, float)
    return np.stack([np.cos(yaw / 2), 0 * yaw, 0 * yaw, np.sin(yaw / 2)], -1)
