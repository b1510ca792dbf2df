"""Three-point streams: head and hand poses with no full body (what a VR headset and two
controllers give), their file format, and a batched library of them for the VR tracking task.

File format (`.npz`, written by `write_stream` / `ThreePointStream.save`):

| key | shape | content |
|---|---|---|
| positions | (T, 3, 3) | Head, L_Hand, R_Hand body origins, world frame, metres |
| rotations | (T, 3, 4) or (T, 3, 3, 3) | the same bodies' orientations, body-to-world: (w, x, y, z) unit quaternions or rotation matrices |
| fps | scalar, optional | frame rate (default 30); other rates are resampled to 30 (positions linearly, rotations by slerp) |
| name | scalar, optional | the stream's name (default: the file's stem) |
| format, version | scalars, optional | "smpl_envs.three_point", 1 |

The world frame is the suite's: z up, metres, the floor at z = 0. Orientations are those of the
SMPL humanoid's Head, L_Hand and R_Hand bodies (at rest the three frames are aligned with the
world, the humanoid facing +x); turning a headset's or controller's own frame into these is a
calibration the device's user makes once. A stream needs at least `MIN_FRAMES` frames; a file
with the wrong shapes, too few frames, NaN / inf or non-unit quaternions / non-rotation matrices
raises `MotionFileError` naming the file and, for bad values, the first bad frame.

Velocities are finite differences of the poses (central inside a stream, smoothed with the same
sigma as the MotionLib's), so a stream cut from a clip has the clip's three-point velocities.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable

import numpy as np

from ..features import BodyState, rotmat_from_quat
from ..humanoid.skeleton import BODY_NAMES
from ..rotations import quat_from_matrix, quat_slerp
from .kinematics import Segments, angular_velocity, smooth, time_derivative
from .library import DeviceFrames, MotionLib
from .loaders import MotionFileError, _check, _check_fps
from .motion import FPS, VELOCITY_SMOOTHING_SIGMA, resample_frames

STREAM_FORMAT = "smpl_envs.three_point"
STREAM_VERSION = 1
TRACKED_NAMES = ("Head", "L_Hand", "R_Hand")
TRACKED = np.array([BODY_NAMES.index(n) for n in TRACKED_NAMES])  # their indices among the 24 bodies
MIN_FRAMES = 2  # one step to track: the env observes frame t + 1 from frame t
_UNIT_TOL = 1e-3  # quaternion norms / matrix orthonormality accepted as unit


@dataclass
class ThreePointStream:
    """One stream at 30 fps: positions (T, 3, 3) m and quaternions (T, 3, 4, wxyz), float64, in
    TRACKED_NAMES order, world frame."""

    name: str
    positions: np.ndarray
    quats: np.ndarray
    source: str = ""
    fps: float = FPS

    @property
    def num_frames(self) -> int:
        return len(self.positions)

    def save(self, path: str | os.PathLike) -> Path:
        return write_stream(path, self.positions, self.quats, fps=self.fps, name=self.name)

    @classmethod
    def from_motion(cls, motion, name: str | None = None) -> "ThreePointStream":
        """The head and hands of a full-body `Motion` (or a clip index of a `MotionLib` given as
        `(lib, i)`): what a VR rig would have recorded of that motion."""
        if isinstance(motion, tuple):
            lib, i = motion
            motion = lib.motion(i)
        return cls(name or motion.name, np.asarray(motion.body_pos[:, TRACKED], float),
                   np.asarray(motion.body_quat[:, TRACKED], float), source=motion.source, fps=motion.fps)


def validate_stream(positions, rotations, fps=FPS, where: str = "stream") -> tuple[np.ndarray, np.ndarray]:
    """(positions (T, 3, 3), unit quaternions (T, 3, 4)) float64 from the arrays of a stream, or
    `MotionFileError` naming `where` (the file) and what is wrong (the first bad frame)."""
    pos = _check(where, "positions", positions, (3, 3))
    rot = _check(where, "rotations", rotations, (3, 4), (3, 3, 3), labels=("quaternions", "matrices"))
    if len(pos) != len(rot):
        raise MotionFileError(where, f"{len(pos)} position frames but {len(rot)} rotation frames")
    if len(pos) < MIN_FRAMES:
        raise MotionFileError(where, f"has {len(pos)} frame(s); a stream needs at least {MIN_FRAMES}")
    if rot.shape[2:] == (4,):
        bad = np.abs(np.linalg.norm(rot, axis=-1) - 1.0) > _UNIT_TOL
        what = "quaternions that are not unit length"
    else:
        gram = rot.swapaxes(-1, -2) @ rot
        bad = ((np.abs(gram - np.eye(3)) > _UNIT_TOL).any(axis=(-1, -2))
               | (np.linalg.det(rot) < 0))  # a reflection is not an orientation
        what = "matrices that are not rotations"
    if bad.any():
        frame = int(np.argwhere(bad)[0, 0])
        raise MotionFileError(where, f"'rotations' holds {what} (first at frame {frame})")
    quat = (rot / np.linalg.norm(rot, axis=-1, keepdims=True) if rot.shape[2:] == (4,)
            else quat_from_matrix(rot))
    fps = _check_fps(where, fps)
    if fps != FPS:
        pos, quat = _resampled(pos, quat, fps)
        if len(pos) < MIN_FRAMES:
            raise MotionFileError(where, f"has {len(pos)} frame(s) at {FPS:g} fps; a stream needs at least {MIN_FRAMES}")
    return pos, quat


def _resampled(pos: np.ndarray, quat: np.ndarray, fps: float) -> tuple[np.ndarray, np.ndarray]:
    """A stream at `fps` resampled to 30 fps (the rule of RawMotion.resampled)."""
    i0, i1, w = resample_frames(len(pos), fps, FPS)
    return (pos[i0] + w[:, None, None] * (pos[i1] - pos[i0]),
            quat_slerp(quat[i0], quat[i1], w[:, None, None]))


def is_stream_file(path: str | os.PathLike) -> bool:
    """Whether `path` is an .npz holding a three-point stream (keys positions and rotations)."""
    path = Path(path)
    if path.suffix != ".npz" or not path.is_file():
        return False
    try:
        with np.load(path, allow_pickle=False) as z:
            return "positions" in z.files and "rotations" in z.files
    except Exception:
        return False


def load_stream(path: str | os.PathLike) -> ThreePointStream:
    """A `ThreePointStream` from a file of the format in the module docstring."""
    path = Path(path).expanduser()
    try:
        data = np.load(path, allow_pickle=False)
    except (OSError, ValueError) as e:
        raise MotionFileError(path, f"cannot be read as .npz ({type(e).__name__}: {e})") from None
    with data:
        for key in ("positions", "rotations"):
            if key not in data.files:
                raise MotionFileError(path, f"missing '{key}' (a three-point stream holds positions "
                                            "(T, 3, 3) and rotations (T, 3, 4) or (T, 3, 3, 3))")
        if "format" in data.files and str(data["format"]) != STREAM_FORMAT:
            raise MotionFileError(path, f"format {str(data['format'])!r} is not {STREAM_FORMAT!r}")
        if "version" in data.files and int(np.asarray(data["version"]).item()) > STREAM_VERSION:
            raise MotionFileError(path, "written by a newer smpl_envs; upgrade smpl_envs")
        pos, quat = validate_stream(data["positions"], data["rotations"],
                                    data["fps"] if "fps" in data.files else FPS, str(path))
        name = str(data["name"]) if "name" in data.files else path.stem
    return ThreePointStream(name, pos, quat, source=str(path))


def write_stream(path: str | os.PathLike, positions, rotations, *, fps: float = FPS,
                 name: str | None = None) -> Path:
    """Write a stream file (validated first, so a bad array fails here and not at load time);
    returns the path. `rotations`: quaternions (T, 3, 4, wxyz) or matrices (T, 3, 3, 3)."""
    path = Path(path)
    pos, quat = validate_stream(positions, rotations, fps, str(path))
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez(path, format=STREAM_FORMAT, version=STREAM_VERSION, name=name or path.stem, fps=FPS,
             positions=pos, rotations=quat)
    return path if path.suffix == ".npz" else path.with_name(path.name + ".npz")


class ThreePointLib:
    """Many streams concatenated along frames, looked up by global frame like a `MotionLib`
    (the interface `ReferenceTracker` reads: names, lengths, starts, fps, num_motions,
    body_state(frames)); arrays float32: pos (F, 3, 3), quat (F, 3, 4), lin_vel, ang_vel
    (F, 3, 3), and rot (F, 3, 3, 3) float64 (computed from quat), world frame. `DeviceStreams`
    is its view on a torch device for an env on the MuJoCo Warp backend."""

    def __init__(self, streams: Iterable[ThreePointStream]):
        streams = list(streams)
        if not streams:
            raise ValueError("ThreePointLib needs at least one stream")
        self.fps = FPS
        self.names = [s.name for s in streams]
        self.sources = [s.source for s in streams]
        self.seg = Segments.from_lengths([s.num_frames for s in streams])
        self.lengths, self.starts = self.seg.lengths, self.seg.starts
        self.durations = (self.lengths - 1) / self.fps
        pos = np.concatenate([s.positions for s in streams]).astype(np.float64)
        quat = np.concatenate([s.quats for s in streams]).astype(np.float64)
        dt = 1.0 / self.fps
        self.pos, self.quat = pos.astype(np.float32), quat.astype(np.float32)
        self.rot = rotmat_from_quat(self.quat)
        self.lin_vel = smooth(time_derivative(pos, self.seg, dt), self.seg, VELOCITY_SMOOTHING_SIGMA).astype(np.float32)
        self.ang_vel = smooth(angular_velocity(quat, self.seg, dt), self.seg, VELOCITY_SMOOTHING_SIGMA).astype(np.float32)
        self.weights = np.full(self.num_motions, 1.0 / self.num_motions)

    @classmethod
    def load(cls, source) -> "ThreePointLib":
        """From a stream file, a directory of them (recursively), or a list of those."""
        items = [source] if isinstance(source, (str, os.PathLike)) else list(source)
        files = []
        for item in items:
            path = Path(item).expanduser()
            if not path.exists():
                raise FileNotFoundError(f"{str(item)!r}: no such file or directory")
            files += sorted(path.rglob("*.npz")) if path.is_dir() else [path]
        if not files:
            raise FileNotFoundError(f"no .npz stream files in {source!r}")
        return cls([load_stream(f) for f in files])

    # The clip-index queries (start_frames and the evaluation's clip queue use them) are
    # MotionLib's own: they read only names, seg and weights, which a ThreePointLib has too.
    num_motions = MotionLib.num_motions
    num_frames = MotionLib.num_frames
    __len__ = MotionLib.__len__
    sample_motions = MotionLib.sample_motions

    def __repr__(self) -> str:
        return f"ThreePointLib({self.num_motions} streams, {self.num_frames} frames @ {self.fps:g} fps)"

    def stream(self, i: int) -> ThreePointStream:
        s = slice(self.starts[i], self.starts[i] + self.lengths[i])
        return ThreePointStream(self.names[i], self.pos[s].astype(float), self.quat[s].astype(float), self.sources[i])

    def body_state(self, frames: np.ndarray) -> BodyState:
        """The three points at global `frames` (N,) as a BodyState over 3 bodies (no joint
        angles: dof_pos and dof_vel are None)."""
        return BodyState(pos=self.pos[frames], rot=self.rot[frames], lin_vel=self.lin_vel[frames],
                         ang_vel=self.ang_vel[frames], dof_pos=None, dof_vel=None)


# What a ThreePointLib stores per frame (its `body_state` reads these).
STREAM_FIELDS = ("pos", "quat", "rot", "lin_vel", "ang_vel")


class DeviceStreams(DeviceFrames):
    """A ThreePointLib's per-frame arrays as float32 torch tensors on `device`: what an env on
    the MuJoCo Warp backend reads every step (three-point states, stream bounds), with the
    library's own `body_state`; names and weights stay on the host library, `lib`."""

    fields = STREAM_FIELDS
    dtype = "float32"  # rot is float64 on the host
    body_state = ThreePointLib.body_state
    qpos_qvel = None  # streams have no joint angles


def as_three_point_lib(source) -> ThreePointLib | None:
    """A ThreePointLib when `source` is one, or a stream file, or a list of stream files (a
    directory counts when it holds .npz files that are all streams); None when it is anything
    else (clip names, motion files: full bodies). A list mixing streams with motions is refused:
    the two have different rewards and starts."""
    if isinstance(source, ThreePointLib):
        return source
    if source is None or not isinstance(source, (str, os.PathLike, list, tuple)):
        return None
    items = [source] if isinstance(source, (str, os.PathLike)) else list(source)
    kinds = []
    for item in items:
        if not isinstance(item, (str, os.PathLike)):
            kinds.append(False)
            continue
        path = Path(item).expanduser()
        if path.is_dir():
            npz = list(path.rglob("*.npz"))
            kinds.append(bool(npz) and all(is_stream_file(p) for p in npz))
        else:
            kinds.append(is_stream_file(path))
    if not any(kinds):
        return None
    if not all(kinds):
        mixed = [str(i) for i, k in zip(items, kinds) if not k]
        raise ValueError(f"motions: three-point streams cannot be mixed with full-body motions "
                         f"({mixed[:3]}); make one env per kind")
    return ThreePointLib.load(items)
