"""The `Motion` record and the one pipeline that derives every per-frame quantity.

A clip is stored canonically as the pelvis position and the 24 local rotations per frame, in the
humanoid's body frames (`RawMotion`). Everything an environment reads (body positions, world
orientations, velocities, hinge angles, MuJoCo qpos / qvel) is derived from that by
`derive_fields`, batched over many clips, with the skeleton the humanoid was built from.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from ..humanoid.kinematics import forward_kinematics, lowest_point
from ..humanoid.skeleton import MEAN_SKELETON, Skeleton
from ..rotations import quat_apply, quat_inv, quat_mul, quat_slerp, yaw_quat
from .kinematics import Segments, angular_velocity, hinge_angles, smooth, time_derivative, unwrap

FPS = 30.0
FORMAT_NAME = "smpl_envs.motion"
FORMAT_VERSION = 1
VELOCITY_SMOOTHING_SIGMA = 1.0  # frames; light, so velocities keep the motion's sharp events


def resample_frames(num_frames: int, src_fps: float, fps: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(i0, i1, w): for every frame of `num_frames` frames at `src_fps` resampled to `fps`, the two
    source frames around its time and the blend weight of the second (0 where a target time is a
    source frame, as when `src_fps` is a multiple of `fps`)."""
    n = int(np.floor((num_frames - 1) / src_fps * fps + 1e-6)) + 1
    src = np.arange(n) * (src_fps / fps)
    i0 = np.minimum(np.floor(src + 1e-9).astype(int), num_frames - 1)
    i1 = np.minimum(i0 + 1, num_frames - 1)
    return i0, i1, np.clip(src - i0, 0.0, 1.0)


@dataclass
class RawMotion:
    """A clip as read from a file: pelvis position (T, 3) and local rotations (T, 24, 4, wxyz) in
    the humanoid's body frames and the simulator's world frame, at `fps`."""

    name: str
    fps: float
    root_pos: np.ndarray
    local_quat: np.ndarray
    betas: np.ndarray | None = None
    gender: str = "neutral"
    source: str = ""

    @property
    def num_frames(self) -> int:
        return len(self.root_pos)

    def resampled(self, fps: float = FPS) -> "RawMotion":
        """The clip at `fps`: positions interpolated linearly, rotations by slerp. When the source
        rate is a multiple of `fps` every target time is a source frame and nothing is blended."""
        if self.fps == fps:
            return self
        i0, i1, w = resample_frames(self.num_frames, self.fps, fps)
        root = self.root_pos[i0] + w[:, None] * (self.root_pos[i1] - self.root_pos[i0])
        quat = quat_slerp(self.local_quat[i0], self.local_quat[i1], w[:, None, None])
        return replace(self, fps=fps, root_pos=root, local_quat=quat)

    def rotated_yaw(self, yaw: float) -> "RawMotion":
        """The clip turned by `yaw` radians about the world z axis through the origin."""
        q = yaw_quat(yaw)
        local = self.local_quat.copy()
        local[:, 0] = quat_mul(q, local[:, 0])
        return replace(self, root_pos=quat_apply(q, self.root_pos), local_quat=local)

    def save(self, path: str | Path) -> None:
        """Write the project's own .npz format (what the shipped clips use)."""
        extra = {} if self.betas is None else {"betas": np.asarray(self.betas)}
        np.savez(
            path, format=FORMAT_NAME, version=FORMAT_VERSION, name=self.name, fps=self.fps,
            root_pos=self.root_pos, local_quat=self.local_quat, gender=self.gender, **extra,
        )


def derive_fields(
    root_pos: np.ndarray,
    local_quat: np.ndarray,
    seg: Segments,
    fps: float,
    skeleton: Skeleton = MEAN_SKELETON,
    ground: bool = True,
    sigma: float = VELOCITY_SMOOTHING_SIGMA,
) -> dict[str, np.ndarray]:
    """All per-frame arrays of concatenated clips (F frames split by `seg`).

    With `ground`, each clip is lifted or lowered so that the lowest point of the humanoid's
    geometry over the whole clip touches z = 0.
    """
    body_pos, body_quat = forward_kinematics(root_pos, local_quat, skeleton.offsets)
    if ground:
        floor = np.minimum.reduceat(lowest_point(body_pos, body_quat, skeleton), seg.starts)
        lift = -floor[seg.clip_of_frame]
        root_pos = root_pos + lift[:, None] * np.array([0.0, 0.0, 1.0])
        body_pos = body_pos + lift[:, None, None] * np.array([0.0, 0.0, 1.0])
    dt = 1.0 / fps
    lin_vel = smooth(time_derivative(body_pos, seg, dt), seg, sigma)
    ang_vel = smooth(angular_velocity(body_quat, seg, dt), seg, sigma)
    dof_pos = unwrap(hinge_angles(local_quat, seg), seg)
    dof_vel = smooth(time_derivative(dof_pos, seg, dt), seg, sigma)
    root_quat = body_quat[:, 0]
    # MuJoCo's free joint: linear velocity in the world frame, angular velocity in the body frame.
    root_ang_local = quat_apply(quat_inv(root_quat), ang_vel[:, 0])
    return dict(
        local_quat=local_quat,
        body_pos=body_pos,
        body_quat=body_quat,
        body_lin_vel=lin_vel,
        body_ang_vel=ang_vel,
        dof_pos=dof_pos,
        dof_vel=dof_vel,
        qpos=np.concatenate([root_pos, root_quat, dof_pos], -1),
        qvel=np.concatenate([lin_vel[:, 0], root_ang_local, dof_vel], -1),
    )


@dataclass
class Motion:
    """One reference clip at 30 fps, every array in BODY_NAMES / HINGE_NAMES order, world frame.

    body_pos (T, 24, 3), body_quat (T, 24, 4, wxyz), body_lin_vel and body_ang_vel (T, 24, 3,
    world frame), dof_pos and dof_vel (T, 69), qpos (T, 76: pelvis position, pelvis quaternion,
    69 hinge angles) and qvel (T, 75) ready to write into MuJoCo, local_quat (T, 24, 4).
    """

    name: str
    fps: float
    local_quat: np.ndarray
    body_pos: np.ndarray
    body_quat: np.ndarray
    body_lin_vel: np.ndarray
    body_ang_vel: np.ndarray
    dof_pos: np.ndarray
    dof_vel: np.ndarray
    qpos: np.ndarray
    qvel: np.ndarray
    betas: np.ndarray | None = None
    gender: str = "neutral"
    source: str = ""

    @property
    def num_frames(self) -> int:
        return len(self.qpos)

    @property
    def duration(self) -> float:
        """Seconds from the first to the last frame."""
        return (self.num_frames - 1) / self.fps

    def raw(self) -> RawMotion:
        return RawMotion(self.name, self.fps, self.qpos[:, :3].copy(), self.local_quat.copy(),
                         self.betas, self.gender, self.source)

    def save(self, path: str | Path) -> None:
        self.raw().save(path)

    def __repr__(self) -> str:
        return f"Motion({self.name!r}, {self.num_frames} frames, {self.duration:.2f} s @ {self.fps:g} fps)"

    @classmethod
    def from_raw(cls, raw: RawMotion, skeleton: Skeleton = MEAN_SKELETON, ground: bool = True) -> "Motion":
        raw = raw.resampled(FPS)
        seg = Segments.from_lengths([raw.num_frames])
        fields = derive_fields(raw.root_pos, raw.local_quat, seg, raw.fps, skeleton, ground)
        return cls(raw.name, raw.fps, betas=raw.betas, gender=raw.gender, source=raw.source, **fields)
