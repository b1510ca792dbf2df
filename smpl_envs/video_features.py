"""Batched features of the video task (`SMPL/VideoPose-v0`): its observation beyond the self
observation, the foot sample points its metrics use, and the confidence-weighted reprojection
error. Arrays of shape (N, ...), as `smpl_envs.features`.

The observation after the 358 self-observation columns (SimPoE's state):

| group | size | content (heading frame of the simulated humanoid; t+1 = the next input frame) |
|---|---|---|
| estimate | 576 | Imitation-v0's rotation goal towards the kinematic estimate of t+1 (`features.IMITATION_GOAL_LAYOUT`): estimate - sim positions, linear and angular velocities, estimate positions relative to the sim pelvis, estimate (-) sim rotations, estimate rotations |
| video/est_dof | 69 | the estimate's joint angles at t+1 (rad): what residual actions add to, what a refinement unit refines |
| video/keypoints | 48 | the 24 bodies' 2D keypoints at t+1, normalised image coordinates ((u - cx) / fx, (v - cy) / fy) |
| video/confidence | 24 | their confidences (0: not detected) |
| video/camera_rot | 9 | the camera's axes in the heading frame (rows: image x right, image y down, optical axis), row major |
| video/camera_pos | 3 | the camera centre relative to the sim pelvis (m) |

The first 934 columns are exactly Imitation-v0's observation with the estimate as its reference,
so a tracker trained there runs here unchanged (`benchmarks/videopose_report.py` does so). The
camera block turns heading-frame points X (as the estimate block gives them, relative to the sim
pelvis) into image coordinates: X_cam = camera_rot (X - camera_pos), then (x / z, y / z).
Keypoints are image quantities and stay in the image; the camera is what is expressed in the
humanoid's frame.
"""

from __future__ import annotations

import numpy as np

from .camera import project_normalized, to_camera
from .features import IMITATION_GOAL_LAYOUT, xp
from .humanoid.skeleton import BODY_NAMES, MEAN_GEOMS, NUM_BODIES, NUM_HINGES

VIDEO_LAYOUT = (
    ("est_dof", NUM_HINGES, "the kinematic estimate's joint angles, t+1 (rad)"),
    ("keypoints", 2 * NUM_BODIES, "2D keypoints of the 24 bodies, t+1, normalised image coordinates"),
    ("confidence", NUM_BODIES, "keypoint confidences, t+1 (0: not detected)"),
    ("camera_rot", 9, "camera axes in the heading frame (rows x right, y down, z forward)"),
    ("camera_pos", 3, "camera centre relative to the pelvis, heading frame (m)"),
)
VIDEO_TASK_LAYOUT = {"estimate": IMITATION_GOAL_LAYOUT, "video": VIDEO_LAYOUT}

# The feet as the metrics see them: the 8 corners of each foot box (ankle and toe boxes of
# both feet), 32 points in all, a vertex sample of the humanoid's foot geometry.
FOOT_BODIES = np.array([BODY_NAMES.index(n) for n in ("L_Ankle", "L_Toe", "R_Ankle", "R_Toe")])
_SIGNS = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], float)
FOOT_CORNERS = np.stack([np.asarray(MEAN_GEOMS[b].pos) + _SIGNS * np.asarray(MEAN_GEOMS[b].size)
                         for b in FOOT_BODIES])  # (4, 8, 3) in each body's frame


def foot_points(body_pos, body_rot):
    """(N, 32, 3) world positions of the foot box corners of bodies (N, 24, 3) with rotation
    matrices (N, 24, 3, 3)."""
    rot = body_rot[:, FOOT_BODIES]  # (N, 4, 3, 3)
    corners = FOOT_CORNERS if xp(body_pos) is np else xp(body_pos).as_tensor(FOOT_CORNERS, dtype=body_pos.dtype,
                                                                             device=body_pos.device)
    pts = corners @ rot.swapaxes(-1, -2) + body_pos[:, FOOT_BODIES, None]
    return pts.reshape(len(body_pos), -1, 3)


def camera_in_heading(cam_rotation, cam_position, root_pos, heading):
    """(rotation (N, 3, 3), centre (N, 3)) of world cameras (R world -> camera, C) in the heading
    frames `heading` (N, 3, 3) at pelvis positions `root_pos` (N, 3): X_cam = (R H)(X_h - H^T (C - p))."""
    return cam_rotation @ heading, ((cam_position - root_pos)[:, None] @ heading)[:, 0]


def video_obs(est_dof, keypoints, confidence, cam_rot_h, cam_pos_h):
    """The `video` block (N, 153) of VIDEO_LAYOUT from its parts."""
    m = xp(est_dof)
    n = len(est_dof)
    return m.concatenate([est_dof, keypoints.reshape(n, -1), confidence, cam_rot_h.reshape(n, 9), cam_pos_h], -1)


def reprojection_residual(points, keypoints, cam_rotation, cam_position):
    """(N, 24, 2) pi(X_j) - x_j in normalised image coordinates: points (N, 24, 3) projected by
    cameras (N, 3, 3) / (N, 3) in the points' frame, minus keypoints (N, 24, 2)."""
    return project_normalized(to_camera(points, cam_rotation, cam_position)) - keypoints


def weighted_mean(values, weights):
    """(N,) sum_j w_j v_j / sum_j w_j over the last axis (0 where every weight is 0)."""
    w = weights.sum(-1)
    return (values * weights).sum(-1) / xp(values).where(w > 0, w, 1.0)


__all__ = ["VIDEO_LAYOUT", "VIDEO_TASK_LAYOUT", "FOOT_BODIES", "FOOT_CORNERS", "foot_points", "camera_in_heading",
           "video_obs", "reprojection_residual", "weighted_mean"]
