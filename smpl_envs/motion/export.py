"""Write clips in the layouts other tools read: AMASS .npz and PHC .pkl.

The inverse of the loaders' conversion, so a clip made here (or retargeted here) can go to any
SMPL tool, and so the tests can make AMASS-format files without shipping AMASS data.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..humanoid.skeleton import MEAN_SKELETON, SMPL_JOINT_OF_BODY, Skeleton
from ..rotations import quat_inv, quat_mul, quat_to_rotvec
from .loaders import _FRAME_QUAT
from .motion import Motion, RawMotion

_POSE_WIDTH = {"smpl": 72, "smplh": 156, "smplx": 165}


def local_quat_to_smpl_pose(local_quat: np.ndarray) -> np.ndarray:
    """(T, 24, 4) body-frame local rotations -> (T, 72) SMPL axis-angle in SMPL joint order."""
    conj = np.broadcast_to(_FRAME_QUAT, local_quat.shape)
    q = quat_mul(quat_mul(quat_inv(conj), local_quat), conj)
    q[:, 0] = quat_mul(local_quat[:, 0], conj[:, 0])
    pose = np.zeros(local_quat.shape[:2] + (3,))
    pose[:, SMPL_JOINT_OF_BODY] = quat_to_rotvec(q)
    return pose.reshape(len(local_quat), 72)


def _raw(motion: Motion | RawMotion) -> RawMotion:
    return motion.raw() if isinstance(motion, Motion) else motion


def to_amass(motion: Motion | RawMotion, path: str | Path, *, fps: float | None = None,
             layout: str = "smplh", skeleton: Skeleton = MEAN_SKELETON,
             rate_key: str = "mocap_framerate") -> None:
    """Write an AMASS-layout .npz (poses, trans, betas, gender, frame rate), resampled to `fps`."""
    raw = _raw(motion)
    if fps is not None:
        raw = raw.resampled(fps)
    pose72 = local_quat_to_smpl_pose(raw.local_quat)
    poses = np.zeros((raw.num_frames, _POSE_WIDTH[layout]))
    poses[:, :72 if layout == "smpl" else 66] = pose72[:, :72 if layout == "smpl" else 66]
    betas = np.zeros(16) if raw.betas is None else np.asarray(raw.betas, float)
    np.savez(path, poses=poses, trans=raw.root_pos - skeleton.pelvis_smpl, betas=betas,
             gender=np.array(raw.gender), **{rate_key: np.array(float(raw.fps))})


def to_phc_pkl(motions: list[Motion | RawMotion], path: str | Path) -> None:
    """Write a PHC-style motion .pkl (name -> pose_aa, root_trans_offset, beta, gender, fps)."""
    import joblib

    out = {}
    for m in map(_raw, motions):
        out[m.name] = dict(pose_aa=local_quat_to_smpl_pose(m.local_quat), root_trans_offset=m.root_pos,
                           beta=np.zeros(10) if m.betas is None else np.asarray(m.betas),
                           gender=m.gender, fps=m.fps)
    joblib.dump(out, path)
