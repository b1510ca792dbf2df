"""Walks from standing to a stop at a place: the clips the recovery option `walk_guide` shows a
standing body far from its goal (`smpl_envs.envs.walk_guide`).

A clip stands still for a moment, turns by `turn` (radians, left positive) in small slow steps
(people turn first, then walk), walks on `distance` m and stops, standing. `approach_set()` is the
grid of them the guide chooses from: their end points (relative to the start, in the start's
heading frame) cover every direction at 30 deg and distances of 0.9-6.2 m: turned by at most ~15 deg more, one of them ends within ~0.3 m of any goal in that
range. `turn_on_the_spot` clips turn a standing body round to face the way its goal faces;
`step_to` clips step a short way in any direction without turning (the exact rule's last metre).
A `direct` pace (`Pace.direct`) walks straight at the end from the first step instead, stepping
sideways or backwards while it turns. Frames, axes and signs are procedural's: x forward, y left,
z up.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from .motion import RawMotion
from .procedural import DEG, _keys, _locomotion
from .synthetic import WALK

STAND = 0.6                 # s standing still at the end (and, at the steady pace, at the start)
SLOW = 0.35                 # m/s while turning
# rad/s. The tracker followed every clip of the grid from its first frame at 45 deg/s, and lost
# left turns at 60 and 90 (19 % and 30 % of a fifth of the grid; runs/tracker_getup3 at 10M).
TURN_RATE = 45 * DEG
TURNS = np.arange(-150, 181, 30) * DEG
DISTANCES = np.arange(0.5, 5.51, 0.5)
STEP_SPEED = 0.5            # m/s stepping without turning (sideways, backwards)
STEP_STRIDE = 1.1           # s per gait cycle while stepping: short, deliberate steps
STEP_DISTANCES = (0.5, 0.8, 1.1, 1.4)   # m; shorter steps slide a planted foot (check_motion)


@dataclasses.dataclass(frozen=True)
class Pace:
    """How an approach is timed: `wait` s standing and `ready` s walking slowly before the turn,
    the turn at `turn_rate` rad/s walking at `turn_speed` m/s, `ramp` s from there to the cruising
    speed (and back to standing), cruising at `distance / cruise_time` m/s within [turn_speed,
    top_speed]. Two rules of the walk guide: `early`, a walk
    after a get-up sets off as soon as the get-up's clip stands still, not at its last frame;
    `exact`, a walk ends on the goal's pelvis, not within the grid's ~0.3 m of it, and a body
    back near its goal but off the spot is led onto it (`smpl_envs.envs.walk_guide`). `direct`
    (the clip's own shape): the path runs straight to the end from the first step, the body
    stepping sideways or backwards while it turns to face the way it goes."""

    wait: float
    ready: float
    ramp: float
    cruise_time: float
    top_speed: float
    early: bool = False
    exact: bool = False
    direct: bool = False
    turn_rate: float = TURN_RATE   # rad/s while turning ...
    turn_speed: float = SLOW       # ... at this speed (m/s)


# "steady" is the walk guide's first set: a 3 m walk with a quarter turn is within 0.3 m of its
# end only after 6.7 s, so a body that got up first has too little of PHC's 10 s left (far Succ-5s
# 26 %, fallen+far 0.7 %: training/recovery_roll). "brisk" is there in 5.6 s: a fifth of a second
# standing before the walk, a shorter slow start, cruising at up to 1.3 m/s (the corpus' walks
# cruise at 1.1 m/s, median, and a tenth of them faster than 1.6). Its ramps stay 1.5 s: at 1.2 s
# and up to 1.5 m/s (4.9 s) the primitive trained on the steady walks fell at the stop, and 4M
# samples of training on them made it fall in nearly every far trial (runs/recovery_brisk_fast);
# ramps of 0.8-1.0 s also slide the clips' planted feet.
PACES = {"steady": Pace(wait=STAND, ready=0.6, ramp=1.5, cruise_time=3.0, top_speed=1.1),
         "brisk": Pace(wait=0.2, ready=0.3, ramp=1.5, cruise_time=2.5, top_speed=1.3, early=True)}
# "brisk_exact": the brisk walks, ending exactly on the goal. Of the fallen trials the brisk
# primitive failed (training/recovery_brisk), a third stood up within 1 m of the goal and stayed
# there: a walk that ends 0.3 m short plus the tracking error leaves a standing body about 0.45 m
# off, where the goal is the reference again and a tracker, shown a standing reference 0.45 m
# away, stands too.
PACES["brisk_exact"] = dataclasses.replace(PACES["brisk"], exact=True)
# "brisk_direct": brisk_exact's walks heading straight for the goal from the first step (no slow
# steps before the turn, sideways or backwards while turning): fallen+far trials are short of
# time, and a 3 m goal behind a body is reached about a second sooner.
PACES["brisk_direct"] = dataclasses.replace(PACES["brisk_exact"], direct=True, ready=0.0)
# "quick_direct": brisk_direct turning twice as fast (90 deg/s) at 0.6 m/s instead of 0.35, with
# 1.2 s ramps and the top speed from 2.6 m on instead of 3.25: a 3 m goal is within 0.45 m 0.3 s sooner straight ahead, 1.3 s sooner at 90 deg and
# 2.3 s sooner behind (2.8 / 3.8 / 4.8 s). Fallen+far trials of training/recovery_direct stand up
# at about 5.3 s (median) and miss 10 s by 0.5-2 s. 1.0 s ramps or 1.5 m/s slide the clips' planted
# feet in 14-31 of the 132 walks of the grid (check_motion); these settings in none.
PACES["quick_direct"] = dataclasses.replace(PACES["brisk_direct"], turn_rate=90 * DEG, turn_speed=0.6, ramp=1.2,
                                            cruise_time=2.0)


def approach(turn: float, distance: float, name: str = "approach", pace: str = "steady") -> RawMotion:
    """A walk from standing that turns by `turn` (rad, |turn| <= pi), walks on `distance` m (>= 0.3)
    and stops, at a pace of PACES (module docstring)."""
    pc = _pace(pace)
    if not (np.isfinite(turn) and abs(turn) <= np.pi + 1e-9):
        raise ValueError(f"approach: turn = {turn!r} must be an angle in [-pi, pi] radians")
    if not (np.isfinite(distance) and distance >= 0.3):
        raise ValueError(f"approach: distance = {distance!r} must be at least 0.3 m")
    # People turn first, in small slow steps, then walk on: the turn is taken at the pace's
    # turn_speed (SLOW by default: 0.27 m/s^2 of lateral acceleration at TURN_RATE); short
    # approaches never go faster than a few small steps need.
    speed = float(np.clip(distance / pc.cruise_time, pc.turn_speed, pc.top_speed))
    turning = abs(turn) / pc.turn_rate
    sign = np.sign(turn)
    t0 = pc.wait + pc.ready                           # walking slowly, ready to turn
    t1 = t0 + turning                                 # turned: speeding up
    cruise = max(distance / speed - pc.ramp, 0.0)     # the two ramps walk about one ramp's time at speed
    duration = t1 + 2 * pc.ramp + cruise + STAND
    edge = min(0.2, turning / 2)                      # min-jerk edges of the turn rate
    rate = abs(turn) / max(turning - edge, 1e-9)      # so that the turn integrates to `turn`
    t_turn = np.array([0.0, t0, t0 + edge, t1 - edge, t1 + 1e-6, duration + 10])
    yaw_rate = lambda t: _keys(t, t_turn, sign * rate * np.array([0, 0, 1, 1, 0, 0]))  # noqa: E731
    t_speed = np.array([0.0, pc.wait, t0, t1, t1 + pc.ramp, t1 + pc.ramp + cruise, duration - STAND, duration + 10])
    spd = lambda t: _keys(t, t_speed, np.array([0, 0, pc.turn_speed, pc.turn_speed, speed, speed, 0, 0]))  # noqa: E731
    # Stepping starts before the body moves (a foot that moved unlifted would slide) and stops as it halts.
    t_act = np.array([0.0, pc.wait - 0.4 if pc.wait > 0.4 else pc.wait / 2, pc.wait + 0.2, duration - STAND - 0.7, duration - STAND + 0.1,
                      duration + 10])
    act = lambda t: _keys(t, t_act, np.array([0, 0, 1, 1, 0, 0]))  # noqa: E731
    stride = lambda t: np.minimum(np.clip((1.3 / np.maximum(spd(t), 0.3)) ** 0.35, 0.8, 1.4),  # noqa: E731
                                  0.55 / np.maximum(np.abs(yaw_rate(t)), 1e-3)).clip(0.55)
    travel = 0.0
    if pc.direct:
        # The path runs straight at the goal from the first step: while the body turns towards
        # it, it steps sideways or backwards (travel = the bearing still to turn through).
        grid = np.arange(0.0, duration + 10, 1e-3)
        yaw = np.concatenate([[0.0], np.cumsum(0.5 * (yaw_rate(grid[1:]) + yaw_rate(grid[:-1])) * 1e-3)])
        travel = lambda t: turn - np.interp(t, grid, yaw)  # noqa: E731
    return _locomotion(name, duration, WALK, spd, yaw_rate=yaw_rate, travel=travel, activity=act, stride=stride)


def turn_on_the_spot(turn: float, name: str = "turn") -> RawMotion:
    """Stepping round on the spot by `turn` (rad, left positive) at TURN_RATE, from standing to standing."""
    if not (np.isfinite(turn) and 0 < abs(turn) <= np.pi + 1e-9):
        raise ValueError(f"turn_on_the_spot: turn = {turn!r} must be a non-zero angle in [-pi, pi] radians")
    edge = 0.4                                        # s of easing at either end of the turn
    t0, t1 = STAND + 0.4, STAND + 0.4 + abs(turn) / TURN_RATE + edge
    t_turn = np.array([0.0, t0, t0 + edge, t1 - edge, t1, t1 + STAND + 10])
    yaw_rate = lambda t: _keys(t, t_turn, np.sign(turn) * TURN_RATE * np.array([0, 0, 1, 1, 0, 0]))  # noqa: E731
    t_act = np.array([0.0, STAND - 0.2, t0 + 0.2, t1, t1 + 0.6, t1 + STAND + 10])
    act = lambda t: _keys(t, t_act, np.array([0, 0, 1, 1, 0, 0]))  # noqa: E731
    stride = min(1.0, 0.55 / TURN_RATE)
    return _locomotion(name, t1 + 0.6 + STAND, WALK, 0.0, yaw_rate=yaw_rate, activity=act,
                       stride=lambda t: np.full(np.shape(t), stride))


def step_to(bearing: float, distance: float, name: str = "step") -> RawMotion:
    """Stepping `distance` m (0.5 to 2) towards `bearing` (rad from the heading, left positive:
    pi/2 a side step to the left, pi backwards) without turning, from standing to standing, at up
    to STEP_SPEED: how people cover the last metre to a spot behind or beside them."""
    if not np.isfinite(bearing):
        raise ValueError(f"step_to: bearing = {bearing!r} must be a finite angle in radians")
    if not (np.isfinite(distance) and 0.5 <= distance <= 2.0):
        raise ValueError(f"step_to: distance = {distance!r} must be 0.5 to 2 m")
    wait, ramp = 0.2, 0.4
    speed = min(STEP_SPEED, distance / (2 * ramp))
    cruise = distance / speed - ramp                  # the two ramps cover one ramp's time at speed
    duration = wait + 2 * ramp + cruise + STAND
    t_speed = np.array([0.0, wait, wait + ramp, wait + ramp + cruise, duration - STAND, duration + 10])
    spd = lambda t: _keys(t, t_speed, np.array([0, 0, speed, speed, 0, 0]))  # noqa: E731
    t_act = np.array([0.0, wait / 2, wait + 0.2, duration - STAND - 0.3, duration - STAND + 0.1, duration + 10])
    act = lambda t: _keys(t, t_act, np.array([0, 0, 1, 1, 0, 0]))  # noqa: E731
    return _locomotion(name, duration, WALK, spd, travel=float(bearing), activity=act,
                       stride=lambda t: np.full(np.shape(t), STEP_STRIDE))


def approach_set(pace: str = "steady") -> list[RawMotion]:
    """The guide's clips: every turn of TURNS with every distance of DISTANCES at `pace`, then a
    turn on the spot by each of TURNS (bar 0), which the guide shows a body near its goal but
    facing away; with an `exact` pace also steps without turning in every direction of TURNS by
    each of STEP_DISTANCES, for goals close behind or beside a body."""
    walks = [approach(float(a), float(d), f"approach_{round(a / DEG):+04d}_{d:.1f}", pace) for a in TURNS for d in DISTANCES]
    turns = [turn_on_the_spot(float(a), f"turn_{round(a / DEG):+04d}") for a in TURNS if a != 0]
    steps = [step_to(float(a), float(d), f"step_{round(a / DEG):+04d}_{d:.1f}")
             for a in TURNS for d in STEP_DISTANCES] if _pace(pace).exact else []
    return walks + turns + steps


def _pace(pace: str) -> Pace:
    if pace not in PACES:
        raise ValueError(f"approach: pace = {pace!r} must be one of {sorted(PACES)}")
    return PACES[pace]
