"""SimPoE's kinematic refinement unit (Yuan et al. 2021), the part of its policy that reads the 2D
keypoints: `iterations` updates of a kinematic estimate's joint angles (and, optionally, its root
position) from the gradient of the confidence-weighted reprojection loss, each a damped
Gauss-Newton step carried through the kinematic chain plus a learnt correction
(`agents.simpoe` has the method and the policy around it).

Plain torch on batches: forward kinematics of the suite's hinge skeleton (`MEAN_SKELETON`), the
pinhole projection's Jacobian (`smpl_envs.camera`), the chain rule to every hinge and the
Gauss-Newton diagonal, so that the unit is differentiable end to end and trains with PPO.
"""
from __future__ import annotations

from typing import NamedTuple, Sequence

import numpy as np
import torch
from torch import nn

from smpl_envs.camera import normalized_jacobian, project_normalized
from smpl_envs.humanoid.skeleton import MEAN_SKELETON, NUM_BODIES, NUM_HINGES, PARENTS

from .networks import _sizes, mlp

GRAD_FEATURE_SCALE = 100.0  # dL/dX is ~1e-2 per joint; the MLPs see it near unit scale
STEP_FEATURE_SCALE = 10.0
# Damped Gauss-Newton: on 256 start frames of corpus:test at the default noise, 5 updates with
# this damping and step lower the reprojection loss to 0.27 of the estimate's and the pose error
# (from the estimate's root) from 55.7 to 48.7 mm; a damping of 1e-3 lowers the loss as much but
# moves ill-determined hinges (twists, hands) and raises the pose error to 60 mm and more.
GN_DAMPING = 0.03           # added to the Gauss-Newton diagonal (normalised image units^2)
DEFAULT_STEP = 0.3          # initial step size: diagonal steps of coupled hinges overshoot at 1
MAX_STEP = 0.2              # rad: the analytic part of one update, per hinge, at most


def _subtree_mask() -> torch.Tensor:
    """(24, 24) S[i, j] = 1 if body j is body i or one of its descendants."""
    s = torch.eye(NUM_BODIES)
    for j in range(NUM_BODIES):
        p = PARENTS[j]
        while p >= 0:
            s[p, j] = 1.0
            p = PARENTS[p]
    return s


def _skew(v: torch.Tensor) -> torch.Tensor:
    """(..., 3, 3) cross-product matrices [v] of vectors (..., 3): [v] u = v x u."""
    x, y, z = v.unbind(-1)
    zero = torch.zeros_like(x)
    return torch.stack([torch.stack([zero, -z, y], -1), torch.stack([z, zero, -x], -1),
                        torch.stack([-y, x, zero], -1)], -2)


def rot6d_to_matrix(x: torch.Tensor) -> torch.Tensor:
    """(..., 6) the suite's 6D rotations (first two columns, row by row) -> (..., 3, 3)."""
    m = x.reshape(*x.shape[:-1], 3, 2)
    c0 = nn.functional.normalize(m[..., 0], dim=-1)
    c1 = nn.functional.normalize(m[..., 1] - (c0 * m[..., 1]).sum(-1, keepdim=True) * c0, dim=-1)
    return torch.stack([c0, c1, torch.linalg.cross(c0, c1)], -1)


def _axis_rotations(angles: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Rx, Ry, Rz (B, 23, 3, 3) of hinge angles (B, 69)."""
    a = angles.reshape(*angles.shape[:-1], NUM_BODIES - 1, 3)
    c, s = a.cos(), a.sin()
    one, zero = torch.ones_like(c[..., 0]), torch.zeros_like(c[..., 0])

    def mat(rows):
        return torch.stack([torch.stack(r, -1) for r in rows], -2)

    rx = mat([[one, zero, zero], [zero, c[..., 0], -s[..., 0]], [zero, s[..., 0], c[..., 0]]])
    ry = mat([[c[..., 1], zero, s[..., 1]], [zero, one, zero], [-s[..., 1], zero, c[..., 1]]])
    rz = mat([[c[..., 2], -s[..., 2], zero], [s[..., 2], c[..., 2], zero], [zero, zero, one]])
    return rx, ry, rz


class Refinement(NamedTuple):
    """What `RefinementUnit` returns: the refined angles (B, 69), the refined pose's dL/dX
    (B, 24, 3), the reprojection loss before the first and after the last update (B,), the poses
    by forward kinematics (heading frame) of the refined pose (`pos` (B, 24, 3), `rot`
    (B, 24, 3, 3)) and of the estimate (`est_pos`, `est_rot`), and the refined root position
    (B, 3: the estimate's unless the unit refines it)."""

    angles: torch.Tensor
    grad: torch.Tensor
    loss_before: torch.Tensor
    loss_after: torch.Tensor
    pos: torch.Tensor
    rot: torch.Tensor
    est_pos: torch.Tensor
    est_rot: torch.Tensor
    root: torch.Tensor


class RefinementUnit(nn.Module):
    """SimPoE's kinematic refinement (module docstring): `iterations` updates of the estimate's
    joint angles from the gradient of the confidence-weighted reprojection loss."""

    def __init__(self, iterations: int = 5, hidden: Sequence[int] = (256, 256), activation: str = "silu",
                 step: float = DEFAULT_STEP, root: bool = False):
        super().__init__()
        self.iterations = int(iterations)
        self.register_buffer("offsets", torch.as_tensor(MEAN_SKELETON.offsets, dtype=torch.float32))
        self.register_buffer("subtree", _subtree_mask())
        self.parents = [int(p) for p in PARENTS]
        feat = NUM_HINGES + 3 * NUM_BODIES + 3 * NUM_BODIES + NUM_HINGES + NUM_BODIES
        self.correction = mlp(feat, _sizes("refine_hidden", hidden), NUM_HINGES, activation, out_gain=0.0)
        self.log_step = nn.Parameter(torch.full((max(self.iterations, 1),), float(np.log(step))))
        # The root's correction, after the angles': an MLP of the refined pose (its bodies relative
        # to its root and their heights above the floor), the reprojection gradient's sum (dL/d root),
        # the confidences and the root's and the camera's places; its last layer starts at zero.
        self.root_correction = (mlp(3 * NUM_BODIES + NUM_BODIES + 3 + NUM_BODIES + 3 + 3,
                                    _sizes("refine_hidden", hidden), 3, activation, out_gain=0.0) if root else None)

    # --- kinematics
    def forward_kinematics(self, root_pos, root_rot, angles):
        """(positions (B, 24, 3), rotations (B, 24, 3, 3), hinge axes (B, 23, 3, 3): [body, hinge
        x/y/z, xyz]) in the frame of `root_pos` (B, 3) / `root_rot` (B, 3, 3). Body frames at rest
        are aligned with their parents' (the builder's), hinges compose x, then y, then z."""
        rx, ry, rz = _axis_rotations(angles)
        local = rx @ ry @ rz
        pos, rot = [root_pos], [root_rot]
        for i in range(1, NUM_BODIES):  # the tree's depth forces a loop over bodies; the batch is one
            p = self.parents[i]
            pos.append(pos[p] + (rot[p] @ self.offsets[i, :, None])[..., 0])
            rot.append(rot[p] @ local[:, i - 1])
        pos, rot = torch.stack(pos, 1), torch.stack(rot, 1)
        parent_rot = rot[:, self.parents[1:]]
        prx = parent_rot @ rx
        axes = torch.stack([parent_rot[..., :, 0], prx[..., :, 1], (prx @ ry)[..., :, 2]], 2)
        return pos, rot, axes

    # --- the reprojection loss and its gradients
    def reprojection(self, pos, keypoints, confidence, cam_rot, cam_pos):
        """(loss (B,), dL/dX (B, 24, 3), projection Jacobians P (B, 24, 2, 3) in the points' frame)."""
        pc = (pos - cam_pos[:, None]) @ cam_rot.swapaxes(-1, -2)
        r = project_normalized(pc) - keypoints
        jac = normalized_jacobian(pc) @ cam_rot[:, None]
        loss = (confidence * (r * r).sum(-1)).sum(-1)
        grad = 2.0 * (confidence[..., None, None] * (jac.swapaxes(-1, -2) @ r[..., None]))[..., 0]
        return loss, grad, jac

    def angle_gradient(self, pos, axes, grad):
        """(B, 69) dL/dtheta from dL/dX through the chain: axis . (sum_sub X_j x g_j - X_i x sum_sub g_j)."""
        s = self.subtree
        xg = torch.einsum("ij,bjk->bik", s, torch.linalg.cross(pos, grad))
        g = torch.einsum("ij,bjk->bik", s, grad)
        moment = (xg - torch.linalg.cross(pos, g))[:, 1:]  # (B, 23, 3)
        return (axes * moment[:, :, None]).sum(-1).reshape(len(pos), -1)

    @torch.no_grad()
    def gauss_newton_diagonal(self, pos, axes, jac, confidence):
        """(B, 69) H = sum_j c_j ||P_j (a x (X_j - X_i))||^2 over each hinge's subtree: the diagonal
        of J^T C J, a preconditioner (no gradient flows through it).

        With Q_j = P_j^T P_j and [v] the cross-product matrix, a x (X_j - X_i) = -([X_j] - [X_i]) a,
        so H = a^T M_i a with M_i = sum_j w_ij ([X_j] - [X_i])^T Q_j ([X_j] - [X_i]), w_ij = S_ij c_j,
        which expands into three subtree sums of per-joint 3 x 3 matrices: O(24^2) per sample
        instead of a (hinge, joint) pair each."""
        e = _skew(pos)                                             # (B, 24, 3, 3)
        q = (jac.swapaxes(-1, -2) @ jac) * confidence[..., None, None]
        qe = q @ e
        s = self.subtree
        a_sum = torch.einsum("ij,bjxy->bixy", s, e.swapaxes(-1, -2) @ qe)
        b_sum = torch.einsum("ij,bjxy->bixy", s, qe)
        c_sum = torch.einsum("ij,bjxy->bixy", s, q)
        f = e
        m = a_sum - f.swapaxes(-1, -2) @ b_sum - b_sum.swapaxes(-1, -2) @ f + f.swapaxes(-1, -2) @ c_sum @ f
        m = m[:, 1:]                                               # hinges belong to bodies 1..23
        return torch.einsum("bikx,bixy,biky->bik", axes, m, axes).reshape(len(pos), -1)

    def forward(self, root_pos, root_rot, angles, keypoints, confidence, cam_rot, cam_pos,
                floor: torch.Tensor | None = None) -> Refinement:
        """The refined estimate (`Refinement`). `floor` (B,): the floor's height in the frame of
        `root_pos` (the simulated pelvis's: minus its height); needed when the unit refines the root."""
        losses, poses = [], []
        for k in range(self.iterations + 1):
            pos, rot, axes = self.forward_kinematics(root_pos, root_rot, angles)
            loss, grad, jac = self.reprojection(pos, keypoints, confidence, cam_rot, cam_pos)
            losses.append(loss)
            poses.append((pos, rot))
            if k == self.iterations:
                break
            g_theta = self.angle_gradient(pos, axes, grad)
            h = self.gauss_newton_diagonal(pos, axes, jac, confidence)
            gn = -g_theta / (2.0 * h + GN_DAMPING)
            rel = (pos - pos[:, :1]).reshape(len(pos), -1)
            feat = torch.cat([angles, rel, GRAD_FEATURE_SCALE * grad.reshape(len(pos), -1),
                              STEP_FEATURE_SCALE * gn.clamp(-1.0, 1.0), confidence], -1)
            angles = angles + (self.log_step[k].exp() * gn).clamp(-MAX_STEP, MAX_STEP) + self.correction(feat)
        pos, rot = poses[-1]
        if self.root_correction is not None:
            if floor is None:
                raise ValueError("a unit that refines the root needs the floor's height (floor=)")
            # A read-out of the refined pose: the root's loss trains this MLP alone, not the angles
            # (through its inputs it pulled them from 2.1 to 3.3 deg rms in the pretraining).
            b, p, g = len(pos), pos.detach(), grad.detach()
            feat = torch.cat([(p - p[:, :1]).reshape(b, -1), p[..., 2] - floor[:, None],
                              GRAD_FEATURE_SCALE * g.sum(1), confidence, root_pos, cam_pos], -1)
            move = self.root_correction(feat)
            root_pos, pos = root_pos + move, pos + move[:, None]
            loss, grad, _ = self.reprojection(pos, keypoints, confidence, cam_rot, cam_pos)
            losses[-1] = loss
        return Refinement(angles, grad, losses[0], losses[-1], pos, rot, *poses[0], root_pos)


__all__ = ["GRAD_FEATURE_SCALE", "Refinement", "RefinementUnit", "rot6d_to_matrix"]
