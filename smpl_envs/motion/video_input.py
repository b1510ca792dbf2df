"""What a video pipeline gives, frame by frame, and the batched library the video task reads.

A `VideoInput` is one sequence: a kinematic estimate (pelvis position and 24 local rotations per
frame, in the suite's world frame and body frames, like a `RawMotion`), 2D keypoints of the 24
bodies in pixels with confidences in [0, 1] (0: not detected), the calibrated camera they were
seen with (`smpl_envs.camera.Camera`), and, where it is known, the ground truth motion (same
frames). Two sources make them: the estimator model (`smpl_envs.motion.estimator_noise`), which
degrades any clip of the suite and keeps the clip as ground truth, and the loaders of real
estimator output (`smpl_envs.motion.estimator_files`), which have none.

Keypoints are stored per SMPL body (BODY_NAMES order) whatever layout the detector used (COCO-17,
OpenPose BODY-25): a body no keypoint maps to has confidence 0. `DETECTED_BODIES` are the bodies a
BODY-25 detector sees (the others, thorax, spine and hands, never get a keypoint).

A `VideoLib` holds many sequences as concatenated per-frame arrays, as a `MotionLib` holds clips:
the estimate as a MotionLib (not grounded: sinking into the floor is part of an estimate), the
ground truth as another (or None), and keypoints, confidences and camera parameters; every
sequence is resampled to 30 fps. `SMPL/VideoPose-v0` reads it.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..camera import Camera
from ..humanoid.kinematics import forward_kinematics, lowest_point
from ..humanoid.skeleton import BODY_NAMES, MEAN_SKELETON, NUM_BODIES
from .library import MotionLib
from .motion import FPS, RawMotion, resample_frames

DETECTED_NAMES = ("Pelvis", "L_Hip", "L_Knee", "L_Ankle", "L_Toe", "R_Hip", "R_Knee", "R_Ankle", "R_Toe",
                  "Neck", "Head", "L_Shoulder", "L_Elbow", "L_Wrist", "R_Shoulder", "R_Elbow", "R_Wrist")
DETECTED_BODIES = np.array([BODY_NAMES.index(n) for n in DETECTED_NAMES])


@dataclass
class VideoInput:
    """One video sequence (module docstring). Arrays float64: root_pos (T, 3) and local_quat
    (T, 24, 4, wxyz) of the estimate, keypoints (T, 24, 2) pixels, confidence (T, 24); truth a
    RawMotion of the same T frames at `fps`, or None."""

    name: str
    fps: float
    root_pos: np.ndarray
    local_quat: np.ndarray
    keypoints: np.ndarray
    confidence: np.ndarray
    camera: Camera
    truth: RawMotion | None = None
    source: str = ""

    def __post_init__(self):
        t = len(self.root_pos)
        shapes = {"root_pos": (t, 3), "local_quat": (t, NUM_BODIES, 4), "keypoints": (t, NUM_BODIES, 2),
                  "confidence": (t, NUM_BODIES)}
        for name, shape in shapes.items():
            a = np.asarray(getattr(self, name), float)
            if a.shape != shape:
                raise ValueError(f"VideoInput {self.name!r}: {name} has shape {a.shape}, expected {shape}")
            if not np.isfinite(a).all():
                raise ValueError(f"VideoInput {self.name!r}: {name} contains NaN or inf")
            setattr(self, name, a)
        if t < 2:
            raise ValueError(f"VideoInput {self.name!r}: needs at least 2 frames, got {t}")
        if (self.confidence < 0).any() or (self.confidence > 1).any():
            raise ValueError(f"VideoInput {self.name!r}: confidence must lie in [0, 1]")
        if self.truth is not None and (self.truth.num_frames != t or self.truth.fps != self.fps):
            raise ValueError(f"VideoInput {self.name!r}: the ground truth has {self.truth.num_frames} frames at "
                             f"{self.truth.fps} fps, the estimate {t} at {self.fps}")

    @property
    def num_frames(self) -> int:
        return len(self.root_pos)

    def estimate(self) -> RawMotion:
        """The kinematic estimate as a RawMotion."""
        return RawMotion(self.name, self.fps, self.root_pos, self.local_quat, source=self.source)

    def estimate_bodies(self) -> tuple[np.ndarray, np.ndarray]:
        """(positions (T, 24, 3), world quaternions (T, 24, 4)) of the estimate."""
        return forward_kinematics(self.root_pos, self.local_quat, MEAN_SKELETON.offsets)

    def resampled(self, fps: float = FPS) -> "VideoInput":
        """The sequence at `fps`: the estimate and truth as `RawMotion.resampled`, keypoints
        blended linearly and each blended confidence the smaller of its two (a keypoint missing
        in either source frame stays missing)."""
        if self.fps == fps:
            return self
        est = self.estimate().resampled(fps)
        i0, i1, w = resample_frames(self.num_frames, self.fps, fps)
        kp = self.keypoints[i0] + w[:, None, None] * (self.keypoints[i1] - self.keypoints[i0])
        conf = np.where(w[:, None] > 0, np.minimum(self.confidence[i0], self.confidence[i1]), self.confidence[i0])
        truth = None if self.truth is None else self.truth.resampled(fps)
        return replace(self, fps=fps, root_pos=est.root_pos, local_quat=est.local_quat, keypoints=kp,
                       confidence=conf, truth=truth)


class VideoLib:
    """Many `VideoInput`s in concatenated arrays, looked up by global frame (module docstring).

    estimate: MotionLib of the estimates (not grounded); truth: MotionLib of the ground truth
    (None when the sequences have none); pixels (F, 24, 2) and keypoints (F, 24, 2, normalised
    image coordinates) float32; confidence (F, 24) float32; per sequence cameras (list), and
    cam_rotation (M, 3, 3), cam_position (M, 3), focal (M, 2), principal (M, 2); start_lift (F,)
    how far each estimate frame must be raised for its lowest point to clear the floor (0 if it
    does): a simulated start there would otherwise begin inside the ground.
    """

    def __init__(self, inputs: list[VideoInput], truth: MotionLib | None = None):
        """`inputs`: the sequences; `truth`: a MotionLib of their ground truth (the same clips
        in the same order and lengths) instead of the inputs' own, which may then be None."""
        if not inputs:
            raise ValueError("VideoLib needs at least one VideoInput")
        inputs = [v.resampled(FPS) for v in inputs]
        has_truth = [v.truth is not None for v in inputs]
        if any(has_truth) and not all(has_truth):
            missing = [v.name for v, h in zip(inputs, has_truth) if not h][:5]
            raise ValueError(f"VideoLib: either every sequence has ground truth or none does; none for {missing}")
        # The inputs themselves are not kept: a corpus' worth of float64 copies is half a gigabyte.
        self.names = [v.name for v in inputs]
        self.estimate = MotionLib([v.estimate() for v in inputs], ground=False)
        if truth is None and all(has_truth):
            truth = MotionLib([v.truth for v in inputs], ground=False)
        if truth is not None and not np.array_equal(truth.lengths, self.estimate.lengths):
            raise ValueError("VideoLib: the ground truth clips and the estimates differ in length")
        self.truth = truth
        self.pixels = np.concatenate([v.keypoints for v in inputs]).astype(np.float32)
        self.confidence = np.concatenate([v.confidence for v in inputs]).astype(np.float32)
        self.cameras = [v.camera for v in inputs]
        self.cam_rotation = np.stack([c.rotation for c in self.cameras])
        self.cam_position = np.stack([c.position for c in self.cameras])
        self.focal = np.stack([c.focal for c in self.cameras])
        self.principal = np.stack([c.principal_point for c in self.cameras])
        clip = self.estimate.seg.clip_of_frame
        self.keypoints = ((self.pixels - self.principal[clip, None]) / self.focal[clip, None]).astype(np.float32)
        floor = lowest_point(self.estimate.body_pos.astype(float), self.estimate.body_quat.astype(float),
                             MEAN_SKELETON)
        self.start_lift = np.maximum(-floor, 0.0)

    @property
    def num_motions(self) -> int:
        return len(self.names)

    @property
    def has_truth(self) -> bool:
        return self.truth is not None

    @property
    def lengths(self) -> np.ndarray:
        return self.estimate.lengths

    @property
    def starts(self) -> np.ndarray:
        return self.estimate.starts

    def __len__(self) -> int:
        return self.num_motions

    def __repr__(self) -> str:
        return (f"VideoLib({self.num_motions} sequences, {self.estimate.num_frames} frames, "
                f"{'with' if self.has_truth else 'no'} ground truth)")


__all__ = ["VideoInput", "VideoLib", "DETECTED_BODIES", "DETECTED_NAMES"]
