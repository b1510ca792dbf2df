"""A get-up shown as the goal while a body on the floor recovers: the recovery option
`getup_guide` (Recovery-v0's kwarg, or a key of Imitation-v0's `recovery` dict; off by default).

PHC's recovery goal is a point: a body on the floor sees the reference root and its own pose, and
has to discover getting up from the reward (GPU-days with a style reward in the paper; 0 % here on
2 cores, docs/results/learning.md). A tracker that has learnt the corpus' get-up family can
already rise when a reference shows it how. With the guide, a world whose goal takes the recovery
form while its body is down (pelvis below `DOWN_HEIGHT`) is shown a get-up clip instead, one that
starts the way the body lies (on the front or the back: the sign of the pelvis' forward axis'
height), turned about the vertical so that its head points where the body's head does, and
placed under the body's pelvis. It plays at the control rate until its last frame (the body
standing still); then the goal is the task's again: the reference within `switch_distance`, the
recovery form beyond. A guided body that ends up more than the recovery option `guide_restart`
(`RESTART_DISTANCE` by default) from its get-up while down, `SETTLE_STEPS` or more after the
start, is shown a new one. With the recovery option `getup_blend` (seconds; 0, off, by default)
a get-up starts from the body's own pose instead of the clip's first frame, and fades into the
clip over that time (`ClipGuide.lie_in`); with `guide_match` (seconds; 0, off) it starts at the
frame of its first that many seconds whose pose lies nearest the body's. Both measured, neither
helps yet (docs/results/learning.md, "A get-up from the body's own lie").

While guided, the goal, the residual actions' base and the imitation terms of the reward are the
get-up's (as when tracking); the episode does not terminate; the point reward towards the task's
reference stays. Evaluation is unchanged: recovery is measured against the task's reference.

Backends: the get-up clips are a MotionLib (DeviceFrames on MuJoCo Warp), the per-world state
(clip frame, turn, offset) arrays of the env's backend.
"""

from __future__ import annotations

import numpy as np

from ..features import BodyState, quat_from_rotmat, rotmat_from_quat, xp
from ..humanoid.skeleton import BODY_NAMES

DOWN_HEIGHT = 0.4       # m: a pelvis lower than this is on the floor (hands and knees: 0.4)
RESTART_DISTANCE = 0.6  # m of mean body distance from its clip at which a guided body starts a new one (default)
SETTLE_STEPS = 30       # steps after a start before a restart may come (the body settles into the lie)
STILL_SPEED = 0.05      # m/s: a clip whose every body moves slower than this from a frame on stands still
HEAD = BODY_NAMES.index("Head")


def _flat_angle(v):
    """Angle about z of horizontal vectors (N, 2)."""
    return xp(v).arctan2(v[:, 1], v[:, 0])


def turn(state: BodyState, cos, sin, offset) -> BodyState:
    """`state` turned about the world z axis by the angles of (cos, sin) (N,) and moved by
    `offset` (N, 3): positions, rotations and velocities (hinge angles are local)."""
    m = xp(state.pos)
    zero, one = m.zeros_like(cos), m.ones_like(cos)
    r = m.stack([cos, -sin, zero, sin, cos, zero, zero, zero, one], -1).reshape(-1, 3, 3)
    rt = r.swapaxes(-1, -2)  # row vectors (N, 24, 3) @ R^T, one matrix per world
    return BodyState(pos=state.pos @ rt + offset[:, None], rot=r[:, None] @ state.rot,
                     lin_vel=state.lin_vel @ rt, ang_vel=state.ang_vel @ rt,
                     dof_pos=state.dof_pos, dof_vel=state.dof_vel)


class ClipGuide:
    """Per-world playback of the clips of one MotionLib (`frames`: its `DeviceFrames` on a torch
    backend), each turned about the vertical and moved to where a world's body is: the state and
    playback the get-up guide and the walk guide (`smpl_envs.envs.walk_guide`) share; their
    `start` rules say which clip a world is shown and how it is placed."""

    def __init__(self, lib, frames, num_worlds: int, backend, blend: float = 0.0):
        self.lib, self.frames, self.backend = lib, frames, backend
        b = backend
        self._first = lib.body_state(lib.starts)  # host arrays: each clip's first frame
        self.active = b.zeros(num_worlds, "bool")
        self.frame = b.zeros(num_worlds, "int")
        self.end = b.zeros(num_worlds, "int")
        self.age = b.zeros(num_worlds, "int")
        self.cos, self.sin = b.zeros(num_worlds) + 1.0, b.zeros(num_worlds)
        self.offset = b.zeros((num_worlds, 3))
        # A ground-plane shift each world's clip takes on over its frames (smoothstep from none at
        # the first to all of it at the last): where a clip's end should land elsewhere than the
        # clip puts it (the walk guide's exact rule); zero unless a guide sets it.
        self.begin = b.zeros(num_worlds, "int")
        self.shift = b.zeros((num_worlds, 2))
        self._shifting = False  # host flag: no shift was ever set (no device sync to find out)
        # The body's own pose at a clip's start, as offsets from the clip's first frame (positions,
        # a rotation per body, hinge angles), faded out over the clip's first `blend` seconds
        # (smoothstep): the clip then starts where the body is, not where the clip's author lay.
        # Set by a guide's `start` (`lie_in`); zero for a clip started otherwise.
        self._blend_frames = int(round(blend * lib.fps))
        if self._blend_frames:
            self._lie_pos = b.zeros((num_worlds, *self._first.pos.shape[1:]))
            self._lie_quat = b.zeros((num_worlds, self._first.pos.shape[1], 4))
            self._lie_quat[..., 0] = 1.0
            self._lie_dof = b.zeros((num_worlds, self._first.dof_pos.shape[1]))

    def _place(self, ids, clip, angle, pelvis_xy, skip=0) -> None:
        """Worlds `ids` start clips `clip` `skip` frames in (0: at their first), turned by `angle`
        about z, that frame's pelvis moved onto `pelvis_xy` (heights as the clip has them)."""
        m = self.backend.xp
        c, s = m.cos(angle), m.sin(angle)
        first = self.frames.starts[clip] + skip
        root = self.frames.body_pos[first, 0]
        turned = m.stack([c * root[:, 0] - s * root[:, 1], s * root[:, 0] + c * root[:, 1]], -1)
        self.offset[ids, :2] = pelvis_xy - turned
        self.offset[ids, 2] = 0.0
        self.cos[ids], self.sin[ids] = c, s
        self.frame[ids] = self.begin[ids] = first
        self.end[ids] = self.frames.starts[clip] + self.frames.lengths[clip] - 1
        self.shift[ids] = 0.0
        if self._blend_frames:
            self._lie_pos[ids], self._lie_quat[ids], self._lie_dof[ids] = 0.0, 0.0, 0.0
            self._lie_quat[ids, :, 0] = 1.0
        self.age[ids] = 0
        self.active[ids] = True

    def lie_in(self, ids, body: BodyState) -> None:
        """Worlds `ids`' clips, just placed, start from `body`'s pose and fade into their own over
        `blend` seconds (the constructor's; nothing without one)."""
        if not self._blend_frames or len(ids) == 0:
            return
        first = turn(self.frames.body_state(self.frame[ids]), self.cos[ids], self.sin[ids], self.offset[ids])
        self._lie_pos[ids] = body.pos[ids] - first.pos
        self._lie_quat[ids] = quat_from_rotmat(body.rot[ids] @ first.rot.swapaxes(-1, -2))
        self._lie_dof[ids] = body.dof_pos[ids] - self.frames.dof_pos[self.frame[ids]]

    def stop(self, ids) -> None:
        self.active[ids] = False

    def advance(self, active=None) -> None:
        """One frame on for the guided worlds (of the mask `active`); a clip whose last frame was
        shown ends."""
        step = self.active if active is None else self.active & active
        done = step & (self.frame >= self.end)
        self.frame[step] = self.backend.xp.minimum(self.frame[step] + 1, self.end[step])
        self.age[step] += 1
        self.active &= ~done

    def settled(self):
        """(N,) how far each clip is into its first SETTLE_STEPS steps, 0 to 1: the share of the
        residual range a guided body is pulled toward its clip by (`RecoveryController.pd_targets`).
        A blended clip starts where the body is, so it pulls with the whole range from the start."""
        if self._blend_frames:
            return self.backend.zeros(len(self.age)) + 1.0
        return (self.age * (1.0 / SETTLE_STEPS)).clip(max=1.0)

    def distance(self, body: BodyState):
        """(N,) mean body distance (m) between `body` and each world's clip frame now."""
        d = self.current().pos - body.pos
        return xp(d).sqrt((d * d).sum(-1)).mean(-1)

    def _at(self, frames) -> BodyState:
        state = turn(self.frames.body_state(frames), self.cos, self.sin, self.offset)
        if self._shifting:
            state = self._shifted(state, frames)
        if self._blend_frames:
            state = self._blended(state, frames)
        return state

    def _fade(self, frames):
        """(N,) how much of the body's own pose is left at `frames` (1 at the clip's start, 0 from
        `blend` seconds in) and its rate of change (1/s)."""
        u = ((frames - self.begin) * (1.0 / self._blend_frames)).clip(0.0, 1.0)
        return 1.0 - u * u * (3.0 - 2.0 * u), -6.0 * u * (1.0 - u) * (self.lib.fps / self._blend_frames)

    def _blended(self, state: BodyState, frames) -> BodyState:
        m = xp(state.pos)
        left, rate = self._fade(frames)
        q = self._lie_quat
        sin_half = m.sqrt((q[..., 1:] * q[..., 1:]).sum(-1))
        half = m.arctan2(sin_half, q[..., 0])                       # (N, B): half the angle
        axis = q[..., 1:] / sin_half.clip(min=1e-9)[..., None]
        part = left[:, None] * half
        lie = rotmat_from_quat(m.concatenate([m.cos(part)[..., None], m.sin(part)[..., None] * axis], -1))
        spin = (2.0 * rate[:, None] * half)[..., None] * axis      # the fading rotation's angular velocity
        return BodyState(pos=state.pos + left[:, None, None] * self._lie_pos,
                         rot=lie @ state.rot,
                         lin_vel=state.lin_vel + rate[:, None, None] * self._lie_pos,
                         ang_vel=(lie @ state.ang_vel[..., None])[..., 0] + spin,
                         dof_pos=state.dof_pos + left[:, None] * self._lie_dof,
                         dof_vel=state.dof_vel + rate[:, None] * self._lie_dof)

    def _shifted(self, state: BodyState, frames) -> BodyState:
        span = (self.end - self.begin).clip(min=1)
        u = ((frames - self.begin) / span).clip(0.0, 1.0)
        w = u * u * (3.0 - 2.0 * u)
        rate = 6.0 * u * (1.0 - u) * self.lib.fps / span  # dw/dt, 1/s
        m = xp(state.pos)
        pad = m.zeros_like(self.shift[:, :1])
        shift = m.concatenate([self.shift, pad], -1)[:, None]   # (N, 1, 3)
        return BodyState(pos=state.pos + w[:, None, None] * shift, rot=state.rot,
                         lin_vel=state.lin_vel + rate[:, None, None] * shift, ang_vel=state.ang_vel,
                         dof_pos=state.dof_pos, dof_vel=state.dof_vel)

    def set_shift(self, ids, shift) -> None:
        """Worlds `ids`' clips end `shift` (n, 2) m away from where they would (module docstring)."""
        self.shift[ids] = shift
        self._shifting = True

    def end_pelvis(self, ids):
        """(n, 2) where the clips of worlds `ids` put the pelvis at their last frame, unshifted."""
        last = self.frames.body_state(self.end[ids])
        return turn(last, self.cos[ids], self.sin[ids], self.offset[ids]).pos[:, 0, :2]

    def current(self) -> BodyState:
        return self._at(self.frame)

    def next(self) -> BodyState:
        return self._at(self.backend.xp.minimum(self.frame + 1, self.end))

    def next_dof_pos(self):
        frames = self.backend.xp.minimum(self.frame + 1, self.end)
        if not self._blend_frames:
            return self.frames.dof_pos[frames]
        return self.frames.dof_pos[frames] + self._fade(frames)[0][:, None] * self._lie_dof


class GetupGuide(ClipGuide):
    """Get-ups for bodies down (module docstring): from the front for a body face down, from
    the back for one face up, turned so the head points where the body's does."""

    def __init__(self, lib, frames, num_worlds: int, backend, blend: float = 0.0, match: float = 0.0):
        super().__init__(lib, frames, num_worlds, backend, blend)
        # Start frames a get-up may begin at (the recovery option `guide_match`): its first `match`
        # seconds; 1 (its first frame only) without.
        self._match = backend.asarray(np.arange(max(1, int(round(match * lib.fps)))), "int")
        b, first = backend, self._first
        prone = first.rot[:, 0, 2, 0] < 0   # the pelvis' forward axis points down: face down
        if prone.all() or not prone.any():
            have = "on the front" if prone.any() else "on the back"
            raise ValueError(f"getup_guide: the get-up clips must start both on the front and on the back; "
                             f"all {lib.num_motions} start {have}")
        self._prone = b.asarray(np.flatnonzero(prone), "int")
        self._supine = b.asarray(np.flatnonzero(~prone), "int")
        self._still_from = b.asarray(still_from(lib), "int")   # (C,) first frame of each clip's still tail
        self.still = b.zeros(num_worlds, "int")                # ... of the clip each world is shown

    def standing_still(self):
        """(N,) the worlds whose get-up is playing its still tail: the body is shown standing."""
        return self.active & (self.frame >= self.still)

    def start(self, mask, body: BodyState, rng) -> None:
        """Worlds in `mask` start a get-up matching how their `body` lies."""
        b, m = self.backend, self.backend.xp
        ids = b.nonzero(mask)
        n = len(ids)
        if n == 0:
            return
        prone = body.rot[ids, 0, 2, 0] < 0
        clip = m.where(prone, self._prone[b.integers(rng, 0, len(self._prone), n)],
                       self._supine[b.integers(rng, 0, len(self._supine), n)])
        heading = _flat_angle(body.pos[ids, HEAD, :2] - body.pos[ids, 0, :2])
        skip = self._nearest_frame(clip, heading, body.pos[ids]) if len(self._match) > 1 else 0
        first = self.frames.body_pos[self.frames.starts[clip] + skip]
        angle = heading - _flat_angle(first[:, HEAD, :2] - first[:, 0, :2])
        self._place(ids, clip, angle, body.pos[ids, 0, :2], skip)
        self.lie_in(ids, body)
        self.still[ids] = self._still_from[clip]

    def _nearest_frame(self, clip, heading, pos):
        """(n,) the frame offset, within the first `match` seconds of each clip `clip`, whose pose,
        turned to `heading` and placed on the pelvis as a start would place it, is nearest the
        bodies at `pos` (n, 24, 3) in mean body distance."""
        m = self.backend.xp
        last = self.frames.lengths[clip] - 1
        skip = m.minimum(self._match[None, :], last[:, None])                  # (n, W)
        cand = self.frames.body_pos[self.frames.starts[clip][:, None] + skip]  # (n, W, 24, 3)
        head = cand[..., HEAD, :2] - cand[..., 0, :2]
        angle = heading[:, None] - m.arctan2(head[..., 1], head[..., 0])
        c, s = m.cos(angle)[..., None], m.sin(angle)[..., None]
        rel = cand - cand[..., :1, :]
        placed = m.stack([c * rel[..., 0] - s * rel[..., 1] + pos[:, None, :1, 0],
                          s * rel[..., 0] + c * rel[..., 1] + pos[:, None, :1, 1], cand[..., 2]], -1)
        d = placed - pos[:, None]
        pick = m.sqrt((d * d).sum(-1)).mean(-1).argmin(-1)
        return m.minimum(pick, last)  # candidate k is frame min(k, last)


def still_from(lib) -> np.ndarray:
    """(C,) the library frame from which each clip of `lib` stands still to its end (every body
    slower than STILL_SPEED); a clip moving to its end gives its last frame."""
    out = np.empty(lib.num_motions, int)
    for c in range(lib.num_motions):
        frames = lib.starts[c] + np.arange(lib.lengths[c])
        speed = np.linalg.norm(lib.body_state(frames).lin_vel, axis=-1).max(-1)
        moving = np.flatnonzero(speed >= STILL_SPEED)
        out[c] = frames[-1] if len(moving) == 0 or moving[-1] == len(frames) - 1 else frames[moving[-1] + 1]
    return out
