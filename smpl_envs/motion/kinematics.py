"""Per-clip operations along time, over many clips concatenated along the frame axis, and the
hinge-angle decomposition. (Where the bodies are for given rotations: humanoid.kinematics.)

A MotionLib holds thousands of clips as one (F, ...) array per quantity. Everything here works on
such arrays at once; per-clip operations along time (finite differences, smoothing, unwrapping)
take a `Segments` that tells each frame where its clip starts and ends, and never read across a
clip boundary. A single clip is the batch of one.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..rotations import quat_inv, quat_mul, quat_to_euler_xyz, quat_to_rotvec


def hinge_angles(local_quat: np.ndarray, seg: "Segments | None" = None) -> np.ndarray:
    """(..., 69) hinge angles whose x-y-z composition reproduces each non-root local rotation.

    Every rotation has two x-y-z decompositions, (x, y, z) with |y| <= pi/2 and
    (x + pi, pi - y, z + pi). A knee or hip bent past 90 degrees is the second one with small x
    and z; the first would spin x and z by half a turn. Take whichever has the smaller |x| + |z|.

    With `seg` (local_quat of shape (F, 24, 4), clips concatenated along frames) a joint keeps the
    decomposition it has on the previous frame where switching would jump: an arm held forward
    at shoulder height is (x, y, z) ~ (90, 0, 90) deg or (-90, 180, -90) deg, a tie that the rule
    alone breaks differently from frame to frame, while the joint itself moves smoothly.
    """
    a = quat_to_euler_xyz(local_quat[..., 1:, :])
    b = np.stack([_wrap(a[..., 0] + np.pi), _wrap(np.pi - a[..., 1]), _wrap(a[..., 2] + np.pi)], -1)
    cost = lambda e: np.abs(e[..., 0]) + np.abs(e[..., 2])  # noqa: E731
    pick_b = cost(b) < cost(a)
    if seg is not None:
        pick_b ^= _keep_decomposition(a, b, pick_b, seg)
    angles = np.where(pick_b[..., None], b, a)
    return angles.reshape(*local_quat.shape[:-2], -1)


def _wrap(v):
    return (v + np.pi) % (2 * np.pi) - np.pi


def _keep_decomposition(a, b, pick_b, seg: "Segments") -> np.ndarray:
    """(F, J) bool: where to take the other decomposition than `pick_b` so that no joint changes
    decomposition between frames when keeping it is the smaller step. Greedy over the frames
    where the rule's choice changes (there are few), each deciding until the next one."""
    change = np.zeros_like(pick_b)
    change[1:] = pick_b[1:] != pick_b[:-1]
    change[seg.starts] = False
    flip = np.zeros_like(pick_b)
    if not change.any():
        return flip
    step = lambda x, y: np.abs(_wrap(x - y)).max(-1)  # noqa: E731
    clip, last = seg.clip_of_frame, seg.last
    frames, joints = np.nonzero(change.T)[::-1]  # sorted by joint, then frame
    # each change decides up to the next one of its joint and clip, or to the clip's end
    same_column = np.append((joints[1:] == joints[:-1]) & (clip[frames[1:]] == clip[frames[:-1]]), False)
    upto = np.where(same_column, np.append(frames[1:], 0), last[frames] + 1)
    parity = False
    for k, (t, j) in enumerate(zip(frames, joints)):
        if k == 0 or not same_column[k - 1]:
            parity = False  # a new joint or clip starts with the rule's choice
        kept, other = (b, a) if pick_b[t - 1, j] ^ parity else (a, b)
        if step(kept[t, j], kept[t - 1, j]) < step(other[t, j], kept[t - 1, j]):
            parity = not parity
        flip[t:upto[k], j] = parity
    return flip


@dataclass(frozen=True)
class Segments:
    """Clip boundaries of a concatenated frame axis: frame f belongs to [first[f], last[f]]."""

    starts: np.ndarray  # (M,) first frame of each clip
    lengths: np.ndarray  # (M,)

    @classmethod
    def from_lengths(cls, lengths) -> "Segments":
        lengths = np.asarray(lengths, dtype=np.int64)
        return cls(np.concatenate([[0], np.cumsum(lengths)[:-1]]).astype(np.int64), lengths)

    @property
    def num_frames(self) -> int:
        return int(self.lengths.sum())

    @property
    def clip_of_frame(self) -> np.ndarray:
        return np.repeat(np.arange(len(self.lengths)), self.lengths)

    @property
    def first(self) -> np.ndarray:
        return np.repeat(self.starts, self.lengths)

    @property
    def last(self) -> np.ndarray:
        return np.repeat(self.starts + self.lengths - 1, self.lengths)

    def shifted(self, k: int) -> np.ndarray:
        """Index of frame f + k, clamped to f's own clip."""
        return np.clip(np.arange(self.num_frames) + k, self.first, self.last)


def _central_difference(x: np.ndarray, seg: Segments, dt: float, delta) -> np.ndarray:
    """delta(x[next], x[prev]) / elapsed time, with next / prev clamped to each frame's clip:
    central inside a clip, one-sided at its ends, zero for one-frame clips."""
    nxt, prv = seg.shifted(1), seg.shifted(-1)
    span = (nxt - prv).astype(float).reshape(-1, *([1] * (x.ndim - 1)))
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(span > 0, delta(x[nxt], x[prv]) / (span * dt), 0.0)


def time_derivative(x: np.ndarray, seg: Segments, dt: float) -> np.ndarray:
    """Per-clip finite-difference velocity of x (F, ...)."""
    return _central_difference(x, seg, dt, np.subtract)


def angular_velocity(quat: np.ndarray, seg: Segments, dt: float) -> np.ndarray:
    """World-frame angular velocity (F, ..., 3) of orientations (F, ..., 4)."""
    return _central_difference(quat, seg, dt, lambda a, b: quat_to_rotvec(quat_mul(a, quat_inv(b))))


def smooth(x: np.ndarray, seg: Segments, sigma: float) -> np.ndarray:
    """Gaussian smoothing along frames inside each clip (edge frames repeated at clip ends)."""
    if sigma <= 0:
        return x
    radius = int(np.ceil(3 * sigma))
    taps = np.exp(-0.5 * (np.arange(-radius, radius + 1) / sigma) ** 2)
    taps /= taps.sum()
    out = np.zeros_like(x, dtype=float)
    for k, w in zip(range(-radius, radius + 1), taps):  # a handful of taps, each one gather
        out += w * x[seg.shifted(k)]
    return out


def unwrap(angles: np.ndarray, seg: Segments) -> np.ndarray:
    """np.unwrap along frames, restarting at every clip's first frame."""
    step = np.diff(angles, axis=0, prepend=angles[:1])
    step = (step + np.pi) % (2 * np.pi) - np.pi
    step[seg.starts] = 0.0
    total = np.cumsum(step, axis=0)
    return angles[seg.first] + total - total[seg.first]
