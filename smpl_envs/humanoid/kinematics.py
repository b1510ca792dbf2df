"""Kinematics of the SMPL skeleton: where the bodies are for given joint rotations, and where the
lowest point of the collision geometry is. Batched over any leading shape (frames, clips, envs).
"""

from __future__ import annotations

import numpy as np

from ..rotations import quat_apply, quat_mul, quat_z_axis_row
from .skeleton import PARENTS, Skeleton


def forward_kinematics(
    root_pos: np.ndarray, local_quat: np.ndarray, offsets: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Body positions (..., 24, 3) and world orientations (..., 24, 4) from the pelvis position
    (..., 3), local rotations (..., 24, 4; entry 0 is the pelvis' world orientation) and joint
    offsets (24, 3). This is MuJoCo's kinematics for bodies whose joints sit at the body origin."""
    pos = [root_pos]
    quat = [local_quat[..., 0, :]]
    for i in range(1, len(PARENTS)):  # tree depth forces a loop over bodies; frames are batched
        p = PARENTS[i]
        pos.append(pos[p] + quat_apply(quat[p], offsets[i]))
        quat.append(quat_mul(quat[p], local_quat[..., i, :]))
    return np.stack(pos, -2), np.stack(quat, -2)


def lowest_point(body_pos: np.ndarray, body_quat: np.ndarray, skeleton: Skeleton, support=None) -> np.ndarray:
    """Height (...,) of the lowest point of the humanoid's collision geometry in each frame.
    NumPy arrays, or torch tensors with `support`: `skeleton.support_points()` as tensors on
    their device (an env converts them once)."""
    points, radii = skeleton.support_points() if support is None else support  # (24, K, 3), (24, K)
    if isinstance(body_pos, np.ndarray):
        z = body_pos[..., None, 2] + np.einsum("...bj,bkj->...bk", quat_z_axis_row(body_quat), points)
        return (z - radii).min(axis=(-1, -2))
    import torch

    w, x, y, zq = body_quat.double().unbind(-1)  # float64, as quat_z_axis_row computes
    row = torch.stack([2 * (x * zq - w * y), 2 * (y * zq + w * x), 1 - 2 * (x * x + y * y)], -1)
    z = body_pos[..., None, 2] + torch.einsum("...bj,bkj->...bk", row.to(points.dtype), points)
    return torch.amin(z - radii, (-1, -2))
