"""A walk shown as the goal while a standing body is far from it: the recovery option `walk_guide`
(Recovery-v0's kwarg, or a key of Imitation-v0's `recovery` dict; off by default).

PHC's recovery goal for a body far from its reference is a point: the reference root, with the
body's own pose for the rest ("keep as you are"), and a reward for each step closer. A tracker has
learnt to walk where a reference walks, not towards a point, and standing 3 m away it stands
(docs/results/learning.md). With the guide, a world whose goal takes the recovery form while its
body is up (pelvis at or above `DOWN_HEIGHT`) is shown a walk instead: one of the clips of
`smpl_envs.motion.approach.approach_set` (from standing: a turn in small steps, a walk, a stop),
the one whose end lies nearest to the goal's pelvis, started at the body's pelvis facing its
heading and turned by the few degrees that put its end on the goal's bearing. It plays at the
control rate to its last frame (standing still); then the goal is the task's again, the
reference within `switch_distance`, and beyond it another walk from where the body stands. A
body more than `guide_restart` from its walk, `SETTLE_STEPS` or more after the start, is shown
a new one; a body that falls is shown a get-up (with `getup_guide`), and after it a walk. A body
back near its goal (within the grace that follows recovering) but facing more than `TURN_AWAY`
away is shown a turn on the spot to the goal's heading.

`walk_guide` names a pace of `smpl_envs.motion.approach.PACES` (True is "steady", whose policies
keep the pace and the rules they were trained with):

* "brisk" shows the grid at a quicker pace and starts a walk as soon as a get-up's clip stands
  still (`GetupGuide.standing_still`) instead of at its last frame (`Pace.early`).
* "brisk_exact" adds the exact rule (`Pace.exact`): a clip's end is moved onto the goal's pelvis
  over its frames (at most `MAX_SHIFT`), where the grid alone ends up to ~0.3 m short; steps
  without turning (sideways, backwards: `approach.step_to`) join the grid, and the choice weighs
  each clip's length (`TIME_COST`), so a goal close behind a body is a step back, not a turn and
  a walk; and a body back near its goal with its pelvis more than `OFF_SPOT` off is led onto the
  spot as a far one is.
* "brisk_direct" is "brisk_exact" with walks that head straight for the goal from the first step
  (`Pace.direct`), stepping sideways or backwards while the body turns to face it.
* "quick_direct" is "brisk_direct" turning at twice its rate with shorter ramps (`Pace.turn_rate`,
  `Pace.turn_speed`, `Pace.ramp`): a 3 m goal behind a body is reached 2.3 s sooner.

While guided, the goal, the residual base and the imitation terms of the reward are the walk's,
as with a get-up; the point reward towards the task's reference stays, and the evaluation is
unchanged.
"""

from __future__ import annotations

import numpy as np

from ..features import BodyState, xp
from .getup_guide import ClipGuide

# m of cost per radian of turn between the body's heading and the first frame of the walk it is
# shown: a clip that ends 0.3 m short is preferred to one that starts 17 deg off the body's heading
# (the approach grid's turns are 30 deg apart, so the extra turn stays within about 15 deg).
BEARING_COST = 1.0
TURN_REACH = 0.3     # m: a clip that ends nearer than this to where it starts is a turn on the spot
TURN_AWAY = np.radians(30)  # a standing body near its goal facing further away than this is shown a turn
# The exact rule (Pace.exact): a standing body near its goal with its pelvis further off than this
# (m) is led onto the spot; a clip's end moves at most MAX_SHIFT (m) to land on the goal.
OFF_SPOT = 0.25
MAX_SHIFT = 0.6
# m of cost per second a clip lasts, under the exact rule: with it, a goal 0.8 m behind a body is
# a 3.4 s step back, not a 7 s turn and walk (the step clips are there under that rule only).
TIME_COST = 0.1


def wrap_angle(a):
    """Angles (rad) wrapped into [-pi, pi)."""
    return (a + np.pi) % (2 * np.pi) - np.pi


class WalkGuide(ClipGuide):
    """Walks (or steps) to the goal for standing bodies far from it, and turns on the spot for
    standing bodies near it that face away (module docstring)."""

    def __init__(self, lib, frames, num_worlds: int, backend, exact: bool = False):
        super().__init__(lib, frames, num_worlds, backend)
        self.exact = bool(exact)
        first, last = self._first, lib.body_state(lib.starts + lib.lengths - 1)
        h0, h1 = heading_of(first.rot), heading_of(last.rot)
        d = last.pos[:, 0, :2] - first.pos[:, 0, :2]
        reach = np.hypot(d[:, 0], d[:, 1])
        b = backend
        self._start_heading = b.asarray(h0)
        self._reach = b.asarray(reach)  # (C,) how far each clip ends from where it starts ...
        self._bearing = b.asarray(wrap_angle(np.arctan2(d[:, 1], d[:, 0]) - h0))  # ... in which direction
        self._turn = b.asarray(wrap_angle(h1 - h0))  # ... and how far round it turns
        # A clip for the other kind of world costs this much more: never chosen. Under the exact
        # rule a walk's (or step's) length costs too.
        self._walk_cost = b.asarray(np.where(reach < TURN_REACH, 1e6, 0.0) + (TIME_COST * lib.durations if exact else 0.0))
        self._turn_only = b.asarray(np.where(reach < TURN_REACH, 0.0, 1e6))

    def start(self, mask, body: BodyState, goal: BodyState, far) -> None:
        """Worlds in `mask` start the clip that suits them best: those `far` from the `goal`'s
        pelvis (or, under the exact rule, off its spot) a walk or steps to it, the others a turn
        to its heading."""
        b = self.backend
        ids = b.nonzero(mask)
        if len(ids) == 0:
            return
        heading = heading_of(body.rot[ids])
        rel = goal.pos[ids, 0, :2] - body.pos[ids, 0, :2]
        reach = (rel * rel).sum(-1) ** 0.5
        bearing = wrap_angle(b.xp.arctan2(rel[:, 1], rel[:, 0]) - heading)
        off = wrap_angle(bearing[:, None] - self._bearing[None])  # (n, C): the extra turn each walk needs
        walk = abs(self._reach[None] - reach[:, None]) + BEARING_COST * abs(off) + self._walk_cost[None]
        need = wrap_angle(heading_of(goal.rot[ids]) - heading)
        turn_off = wrap_angle(need[:, None] - self._turn[None])  # (n, C): what each turn leaves to turn
        spin = abs(turn_off) + self._turn_only[None]
        away = far[ids][:, None]
        clip = b.xp.where(away, walk, spin).argmin(-1)
        rows = b.arange(len(ids))
        extra = b.xp.where(far[ids], off[rows, clip], turn_off[rows, clip])
        self._place(ids, clip, heading + extra - self._start_heading[clip], body.pos[ids, 0, :2])
        if self.exact:
            shift = goal.pos[ids, 0, :2] - self.end_pelvis(ids)
            size = (shift * shift).sum(-1, keepdims=True) ** 0.5
            self.set_shift(ids, shift * (MAX_SHIFT / size.clip(min=MAX_SHIFT)))


def heading_of(rot):
    """(N,) heading (rad about z) of the pelvis' forward axis, from body rotations (N, 24, 3, 3)."""
    return xp(rot).arctan2(rot[:, 0, 1, 0], rot[:, 0, 0, 0])
