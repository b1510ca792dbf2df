"""A seeded model of a monocular video pose estimator: any clip of the suite in, the kinematic
estimate and 2D keypoints a video pipeline would give for it out, with the clip kept as ground
truth (`smpl_envs.motion.video_input.VideoInput`).

What a kinematic estimator gets wrong, each a knob of `EstimatorNoise` (defaults below):

| knob | what it does to the estimate |
|---|---|
| jitter_rotation | white noise on every joint's local rotation, frame by frame (rad, std of each axis-angle component) |
| jitter_translation | white noise on the pelvis position, frame by frame (m, std per axis) |
| rotation_error | a slowly varying rotation offset per joint, the root's global orientation included (rad, std per axis-angle component) |
| depth_drift | a slowly varying offset of the whole body along the camera ray through the pelvis (m, std): depth is what one camera sees worst, and it leaves the image unchanged |
| foot_sliding | a slowly varying horizontal offset of the whole body (m, std per axis): planted feet slide |
| ground_penetration | the body sinks into the floor by this depth on average (m), slowly varying, never rising above the truth |

and of the 2D keypoints, projected from the ground truth bodies through a random plausible camera
(`smpl_envs.camera.random_camera`; only the bodies a BODY-25 detector sees, `DETECTED_BODIES`):

| knob | what it does to the keypoints |
|---|---|
| keypoint_noise | Gaussian pixel noise (px, std per coordinate); confidences drawn in [0.7, 1] |
| low_confidence | the share of keypoints detected badly: 4x the pixel noise, confidence in [0.05, 0.3] |
| occlusion | the share of keypoints missing, in spans of about `drift_time` (confidence 0, position 0) |

Keypoints outside the image or behind the camera are missing too. "Slowly varying" is Gaussian
noise low-pass filtered along time with a kernel of `drift_time` seconds (unit std); `drift_time`
sets every slow knob's time scale. `scaled(s)` multiplies every magnitude (s = 0: the truth
itself, exact keypoints), the shares capped below 1.

Seeded: `degrade(motion, seed=...)` and `degrade_library(lib, seed=...)` (clip i gets the stream
(seed, i)) give the same input on any machine. Every random array is drawn whatever the knobs are,
in a fixed order, so each knob changes only what it names: turning one up leaves the others'
effects bit for bit as they were.
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace

import numpy as np
from scipy.ndimage import gaussian_filter1d
from scipy.stats import norm

from ..camera import Camera, random_camera
from ..humanoid.kinematics import forward_kinematics
from ..humanoid.skeleton import MEAN_SKELETON, NUM_BODIES
from ..rotations import quat_from_rotvec, quat_mul
from .video_input import DETECTED_BODIES, VideoInput, VideoLib
from .library import MotionLib, load_motions
from .motion import FPS, Motion, RawMotion

# Knobs that are shares (capped when scaled), and the one that is a time scale (never scaled).
_SHARES = ("low_confidence", "occlusion")
_TIME = ("drift_time",)
SHARE_CAP = 0.9
BASE_CONFIDENCE = (0.7, 1.0)
LOW_CONFIDENCE = (0.05, 0.3)
LOW_CONFIDENCE_NOISE = 4.0  # x keypoint_noise for the badly detected keypoints


@dataclass(frozen=True)
class EstimatorNoise:
    """The estimator model's knobs (module docstring has the table); units m, rad, px, s."""

    jitter_rotation: float = 0.012
    jitter_translation: float = 0.004
    rotation_error: float = 0.08
    depth_drift: float = 0.15
    foot_sliding: float = 0.05
    ground_penetration: float = 0.025
    keypoint_noise: float = 4.0
    low_confidence: float = 0.1
    occlusion: float = 0.05
    drift_time: float = 1.0

    def __post_init__(self):
        for f in fields(self):
            v = getattr(self, f.name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v) or v < 0:
                raise ValueError(f"EstimatorNoise.{f.name} must be a non-negative number, got {v!r}")
            if f.name in _SHARES and v > 1:
                raise ValueError(f"EstimatorNoise.{f.name} is a share of keypoints in [0, 1], got {v!r}")
        if self.drift_time <= 0:
            raise ValueError(f"EstimatorNoise.drift_time must be positive, got {self.drift_time!r}")

    def scaled(self, scale: float) -> "EstimatorNoise":
        """Every magnitude times `scale` (shares capped at SHARE_CAP; drift_time kept)."""
        scale = float(scale)
        if not (np.isfinite(scale) and scale >= 0):
            raise ValueError(f"noise scale must be a non-negative number, got {scale!r}")
        out = {}
        for f in fields(self):
            v = getattr(self, f.name)
            if f.name in _TIME:
                out[f.name] = v
            elif f.name in _SHARES:
                out[f.name] = min(v * scale, SHARE_CAP)
            else:
                out[f.name] = v * scale
        return replace(self, **out)

    @classmethod
    def make(cls, noise=None, scale: float = 1.0) -> "EstimatorNoise":
        """An EstimatorNoise from None (the defaults), a dict of knobs over the defaults or an
        EstimatorNoise, times `scale`. A ValueError names an unknown knob."""
        if noise is None:
            base = cls()
        elif isinstance(noise, cls):
            base = noise
        elif isinstance(noise, dict):
            known = {f.name for f in fields(cls)}
            unknown = sorted(set(noise) - known)
            if unknown:
                raise ValueError(f"noise: unknown knob(s) {unknown}; knobs: {', '.join(sorted(known))}")
            base = cls(**noise)
        else:
            raise ValueError(f"noise must be None, a dict of EstimatorNoise knobs or an EstimatorNoise, got {noise!r}")
        return base.scaled(scale) if scale != 1.0 else base


def slow_noise(rng: np.random.Generator, frames: int, shape: tuple, sigma_frames: float) -> np.ndarray:
    """(frames, *shape) Gaussian noise low-pass filtered along time (kernel std `sigma_frames`),
    rescaled to unit std; padded before filtering so the ends are as smooth as the middle."""
    pad = int(np.ceil(4 * sigma_frames))
    white = rng.standard_normal((frames + 2 * pad, *shape))
    smooth = gaussian_filter1d(white, sigma_frames, axis=0, mode="reflect")[pad:pad + frames]
    radius = int(4 * sigma_frames + 0.5)  # scipy's kernel: its norm is the filtered noise's std
    taps = np.exp(-0.5 * (np.arange(-radius, radius + 1) / sigma_frames) ** 2)
    taps /= taps.sum()
    return smooth / np.sqrt((taps ** 2).sum())


def degrade(motion: Motion, noise: EstimatorNoise | dict | None = None, *, seed: int | np.random.Generator = 0,
            camera: Camera | None = None, name: str | None = None, keep_truth: bool = True) -> VideoInput:
    """The video input an estimator would give for `motion` (module docstring), with `motion`
    as its ground truth (unless `keep_truth=False`: a caller that holds the truth already).
    `camera`: film with this one instead of a random plausible one."""
    noise = EstimatorNoise.make(noise)
    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
    if motion.fps != FPS:
        raise ValueError(f"degrade takes 30 fps motions (Motion.from_raw resamples), got {motion.fps}")
    t = motion.num_frames
    root = np.asarray(motion.qpos[:, :3], float)
    local = np.asarray(motion.local_quat, float)
    body_pos = np.asarray(motion.body_pos, float)
    if camera is None:
        camera = random_camera(rng, body_pos)
    sigma = noise.drift_time * FPS
    # Every draw happens, in this order, whatever the knobs (module docstring).
    d_jitter_rot = rng.standard_normal((t, NUM_BODIES, 3))
    d_rot_err = slow_noise(rng, t, (NUM_BODIES, 3), sigma)
    d_jitter_root = rng.standard_normal((t, 3))
    d_depth = slow_noise(rng, t, (), sigma)
    d_slide = slow_noise(rng, t, (2,), sigma)
    d_sink = slow_noise(rng, t, (), sigma)
    d_kp = rng.standard_normal((t, NUM_BODIES, 2))
    d_base_conf = rng.uniform(*BASE_CONFIDENCE, (t, NUM_BODIES))
    d_low = rng.random((t, NUM_BODIES))
    d_low_conf = rng.uniform(*LOW_CONFIDENCE, (t, NUM_BODIES))
    d_occ = slow_noise(rng, t, (NUM_BODIES,), sigma)

    # The estimate: rotation errors on the local rotations, whole-body offsets on the pelvis.
    rotvec = noise.jitter_rotation * d_jitter_rot + noise.rotation_error * d_rot_err
    est_local = quat_mul(local, quat_from_rotvec(rotvec))
    ray = root - camera.position
    ray /= np.linalg.norm(ray, axis=-1, keepdims=True)
    offset = noise.jitter_translation * d_jitter_root + noise.depth_drift * d_depth[:, None] * ray
    offset[:, :2] += noise.foot_sliding * d_slide
    offset[:, 2] -= noise.ground_penetration * np.maximum(1.0 + 0.5 * d_sink, 0.0)
    est_root = root + offset

    # The keypoints: the truth's bodies through the camera, then the detector's errors.
    px, depth = camera.project(body_pos)
    low = d_low < noise.low_confidence
    px = px + noise.keypoint_noise * np.where(low, LOW_CONFIDENCE_NOISE, 1.0)[..., None] * d_kp
    conf = np.where(low, d_low_conf, d_base_conf)
    occluded = d_occ > norm.ppf(1.0 - noise.occlusion) if noise.occlusion > 0 else np.zeros_like(low)
    detected = np.zeros(NUM_BODIES, bool)
    detected[DETECTED_BODIES] = True
    seen = detected & ~occluded & camera.visible(px, depth)
    conf = np.where(seen, conf, 0.0)
    px = np.where(seen[..., None], px, 0.0)
    truth = (RawMotion(motion.name, FPS, root.copy(), local.copy(), motion.betas, motion.gender, motion.source)
             if keep_truth else None)
    return VideoInput(name or motion.name, FPS, est_root, est_local, px, conf, camera, truth,
                      source=f"estimator model of {motion.source or motion.name}")


def degrade_library(motions, noise: EstimatorNoise | dict | None = None, *, seed: int = 0,
                    scale_range: tuple[float, float] | None = None, progress: bool = False) -> VideoLib:
    """A VideoLib of every clip of `motions` (anything `load_motions` takes), each degraded by
    `degrade_clip`, the clips themselves as truth."""
    from ..progress import pbar

    lib = motions if isinstance(motions, MotionLib) else load_motions(motions, progress=progress)
    noise = EstimatorNoise.make(noise)
    inputs = [degrade_clip(lib, i, noise, seed=seed, scale_range=scale_range, keep_truth=False)  # lib is the truth
              for i in pbar(range(lib.num_motions), desc="estimator model", unit="clip", disable=not progress)]
    return VideoLib(inputs, truth=lib)


def degrade_clip(lib: MotionLib, i: int, noise: EstimatorNoise, *, seed: int = 0,
                 scale_range: tuple[float, float] | None = None, keep_truth: bool = True) -> VideoInput:
    """Clip `i` of `lib` degraded by `noise` with the random stream (seed, i), so that any subset
    of a library gets the input the whole one would. `scale_range` (lo, hi): the noise times a
    scale drawn uniformly in [lo, hi] from a stream of its own, (seed, i, 1), so the errors are
    the unscaled clip's, scaled."""
    if scale_range is not None:
        lo, hi = check_scale_range(scale_range)
        noise = noise.scaled(np.random.default_rng(np.random.SeedSequence([int(seed), int(i), 1])).uniform(lo, hi))
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), int(i)]))
    return degrade(lib.motion(int(i)), noise, seed=rng, keep_truth=keep_truth)


def check_scale_range(scale_range) -> tuple[float, float]:
    """(lo, hi) of a per-clip noise scale range, 0 <= lo <= hi; a ValueError says what is wrong."""
    try:
        lo, hi = (float(v) for v in scale_range)
    except (TypeError, ValueError):
        raise ValueError(f"noise_scale_range must be a pair (lo, hi) of numbers, got {scale_range!r}") from None
    if not (np.isfinite(lo) and np.isfinite(hi) and 0 <= lo <= hi):
        raise ValueError(f"noise_scale_range must satisfy 0 <= lo <= hi, got {scale_range!r}")
    return lo, hi


def estimate_body_pos(video: VideoInput) -> np.ndarray:
    """(T, 24, 3) the estimate's body positions."""
    return forward_kinematics(video.root_pos, video.local_quat, MEAN_SKELETON.offsets)[0]


__all__ = ["EstimatorNoise", "check_scale_range", "degrade", "degrade_clip", "degrade_library", "slow_noise", "estimate_body_pos"]
