"""The procedural motion corpus: a seeded, licence-free stand-in for AMASS, with a test split
that measures generalisation.

Clips come in families (walks, runs, reaches, kicks, transitions ...), each a generator of
`procedural` / `upper_body` / `whole_body` with parameters drawn from stated ranges. Every clip
has its own random stream, derived from (seed, split, family, index) by numpy's SeedSequence, so
a clip is the same on any machine and any subset (one family) can be made alone.

The test split is disjoint from the training split by construction. Each family names held-out
parameter bands (`Family.held_out`): a training clip draws every such parameter outside its band;
a test clip draws one of them, chosen at random, inside it (the others as in training). Reach
targets hold out a region of (azimuth, height); transitions hold out one sequence of actions that
training never strings together. So a test clip always contains a parameter value or combination
no training clip has.

A draw that does not pass the physical checks (`plausibility.check_motion`) is drawn again from
the clip's own stream (at most `MAX_TRIES` times); the number of redraws is part of the manifest.

Users name it wherever motions are accepted: "corpus:train", "corpus:test",
"corpus:<family>" (that family's training clips), "corpus:test/<family>", and groups of families
("corpus:locomotion", "corpus:test/upper_body").

One group is opt-in: "recovery" (getting up from the floor: "getup", and "getup_quick" at about
twice its pace) is left out of "corpus:train" and "corpus:test", whose meaning (and every result
measured on them) stays that of the imitation families; "corpus:getup", "corpus:test/getup",
"corpus:train+getup" and "corpus:recovery" (both families) name it.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from ..progress import pbar
from .motion import RawMotion
from .plausibility import check_motion
from . import getup as gu
from . import procedural as syn
from . import upper_body as ub
from . import whole_body as wb

CORPUS_VERSION = 1  # bump when a generator or a range shared by the families changes; it keys the cache
DEFAULT_SEED = 0
SPLITS = ("train", "test")
MAX_TRIES = 20
DEG = syn.DEG


# ----------------------------------------------------------------------------- drawing parameters

class Draw:
    """Parameter draws of one clip: uniform in a range, outside a held-out band in training and,
    for the one band chosen for a test clip, inside it."""

    def __init__(self, rng: np.random.Generator, split: str, held_out: dict[str, tuple[float, float]]):
        self.rng, self.split, self.held_out = rng, split, held_out
        self.chosen = rng.choice(sorted(held_out)) if split == "test" and held_out else None
        self.values: dict[str, float] = {}  # the last draw of each name: the manifest's record
        self.draws: dict[str, list[float]] = {}  # every draw of each name

    def uniform(self, name: str, lo: float, hi: float) -> float:
        band = self.held_out.get(name)
        if band is None:
            x = self.rng.uniform(lo, hi)
        elif name == self.chosen:
            x = self.rng.uniform(*band)
        else:  # the range with the band cut out: [lo, b0) U (b1, hi], by length
            b0, b1 = np.clip(band, lo, hi)
            left, right = b0 - lo, hi - b1
            u = self.rng.uniform(0.0, left + right)
            x = lo + u if u < left else b1 + (u - left)
        self.values[name] = float(x)
        self.draws.setdefault(name, []).append(float(x))
        return float(x)

    def choice(self, name: str, options):
        x = options[int(self.rng.integers(len(options)))]
        self.values[name] = x
        return x

    def sign(self, name: str) -> float:
        return self.choice(name, (-1.0, 1.0))

    def coin(self, name: str, p: float = 0.5) -> bool:
        x = bool(self.rng.uniform() < p)
        self.values[name] = x
        return x


def _profile(times, values):
    """A minimum-jerk profile through (time, value) keys, as a callable of time."""
    times, values = np.asarray(times, float), np.asarray(values, float)
    return lambda t: syn._keys(t, times, values)


# ----------------------------------------------------------------------------- held-out bands

# Locomotion: a band of walking and running speeds and one of (walking) yaw rates.
WALK_SPEED_BAND = (1.45, 1.65)  # m/s
RUN_SPEED_BAND = (3.2, 3.5)
YAW_RATE_BAND = (0.55, 0.7)  # rad/s, in magnitude (31-40 deg/s)
# Reaches: a region of targets, front-side at chest height.
REACH_AZIMUTH_BAND = (0.5, 0.9)  # rad towards the reaching hand's side
REACH_HEIGHT_BAND = (1.0, 1.3)  # m
# Lower and whole body: the corpus' ranges (the generators accept wider ones) and held-out bands.
KICK_HEIGHT, KICK_HEIGHT_BAND = (0.2, 0.9), (0.55, 0.63)  # m, the kicking foot's top height
KICK_TEMPO = (0.7, 1.4)
SQUAT_DEPTH, SQUAT_DEPTH_BAND = (0.05, 0.25), (0.14, 0.17)  # m of pelvis drop
SQUAT_DESCENT, SQUAT_HOLD, SQUAT_WIDTH = (0.5, 2.0), (0.0, 2.0), (0.08, 0.14)
LUNGE_LENGTH, LUNGE_LENGTH_BAND, LUNGE_DEPTH = (0.5, 0.9), (0.68, 0.74), (0.12, 0.3)
JUMP_FLIGHT, JUMP_DISTANCE, JUMP_DISTANCE_BAND = (0.25, 0.5), (0.0, 0.8), (0.4, 0.48)
HOP_FLIGHT, HOP_FLIGHT_BAND, HOP_DISTANCE = (0.15, 0.3), (0.2, 0.22), (0.0, 0.4)
# Transitions: training strings at most one action into a stop; the test split holds the one
# sequence "reach, then turn in place" before walking on.
TRANSITION_ACTIONS = ("none", "reach", "wave", "turn")
HELD_OUT_SEQUENCE = ("reach", "turn")
TRANSITION_TURN_RATE = 1.0  # rad/s, turning on the spot during a stop
GETUP_TEMPO_BAND = (0.95, 1.05)  # the get-up's speed factor (its range: getup.RANGES)
# The quick get-ups: twice the pace, little lying still. A body following `getup` perfectly is back
# within 0.5 m after 7.4 s (median), too late for PHC's 5 s and for a 3 m walk after it; at twice
# the pace PD on the reference follows the front starts further, not less far
# (docs/results/learning.md, "The get-up clips set a ceiling on guided recovery").
GETUP_QUICK_TEMPO, GETUP_QUICK_TEMPO_BAND, GETUP_QUICK_LIE = (1.8, 2.4), (2.05, 2.15), (0.3, 0.5)


# ----------------------------------------------------------------------------- locomotion

def _walk_gait(d: Draw, speed: float):
    """Walking gait variety: stride and cadence, step width, arm swing, lean, foot lift."""
    return syn._Gait(**{**syn.WALK.__dict__,
                        "width": d.uniform("step_width", 0.05, 0.11),
                        "arm_swing": syn.WALK.arm_swing * d.uniform("arm_swing", 0.5, 1.6),
                        "lean": d.uniform("lean", 0.0, 8 * DEG),
                        "swing_height": syn.WALK.swing_height * d.uniform("foot_lift", 0.8, 1.3)})


def _cadence(d: Draw, speed, yaw_rate):
    """Stride duration (s) as a callable: people step faster as they walk faster (stride ~ speed
    ^ -0.35 about the shipped walk's 1.0 s at 1.3 m/s), and take short steps in tight turns
    (at most ~32 degrees of turn per stride: longer strides there bend hips past their range)."""
    scale = d.uniform("cadence", 0.92, 1.08)

    def stride(t):
        v = np.maximum(speed(t), 0.3)
        base = scale * np.clip((1.3 / v) ** 0.35, 0.8, 1.4)
        return np.minimum(base, 0.55 / np.maximum(np.abs(yaw_rate(t)), 1e-3)).clip(0.55)
    return stride


MAX_LATERAL_ACC = 0.9  # m/s^2, speed x yaw rate: sharper curves at speed bend hips past range


def _yaw_profile(d: Draw, duration: float, speed_max: float, keys: int):
    """Yaw-rate keys: straight stretches and curves, |rate| <= 90 deg/s and lateral acceleration
    <= MAX_LATERAL_ACC. A test clip holding out the yaw-rate band curves at every key."""
    limit = min(90 * DEG, MAX_LATERAL_ACC / max(speed_max, 0.1))
    times = np.linspace(0.0, duration, keys)
    rates = []
    for i in range(keys):
        if d.chosen == "yaw_rate" or d.coin(f"curve_{i}", 0.6):
            rates.append(d.sign(f"turn_dir_{i}") * d.uniform("yaw_rate", min(0.1, limit), limit))
        else:
            rates.append(0.0)
    d.values["yaw_rates"] = [float(r) for r in rates]
    return _profile(times, rates)


def walk(d: Draw) -> RawMotion:
    """A walk at 0.3-2.2 m/s with speed changes (from standing and to a stop at times), curves."""
    duration = d.uniform("duration", 6.0, 10.0)
    # Curving at the held-out yaw rates needs speeds that keep the lateral acceleration in bounds.
    top = MAX_LATERAL_ACC / YAW_RATE_BAND[1] if d.chosen == "yaw_rate" else 2.2
    cruise = d.uniform("speed", 0.3, top)
    other = d.uniform("speed_b", 0.3, top)
    start_still, stop = d.coin("from_standing", 0.4), d.coin("to_stop", 0.4)
    speeds = [0.0 if start_still else cruise, cruise, other, 0.0 if stop else other]
    acts = [0.0 if start_still else 1.0, 1.0, 1.0, 0.0 if stop else 1.0]
    # Standing ends last 0.6 s; speed ramps over ~1.5 s as gait starts.
    times = [0.0, 0.6, 0.6 + 1.5, 0.7 * duration, duration - 2.1, duration - 0.6, duration]
    sp = _profile(times, [speeds[0], speeds[0], speeds[1], speeds[2], speeds[2], speeds[3], speeds[3]])
    act = _profile([0.0, 0.5, 1.3, duration - 1.3, duration - 0.5, duration], [acts[0], acts[0], 1, 1, acts[3], acts[3]])
    yaw = _yaw_profile(d, duration, max(cruise, other), int(d.rng.integers(2, 5)))
    return syn._locomotion("walk", duration, _walk_gait(d, cruise), sp, yaw_rate=yaw, activity=act,
                           stride=_cadence(d, sp, yaw))


def run(d: Draw) -> RawMotion:
    """A run at 2.0-4.5 m/s, speeding up or slowing down by up to 15 %, gentle curves. The
    cadence stays at ~95 strides/min (runners lengthen their steps to go faster) and the ground
    contact shortens with speed."""
    duration = d.uniform("duration", 4.0, 8.0)
    v0 = d.uniform("speed", 2.0, 4.5)
    v1 = float(np.clip(v0 * d.uniform("speed_change", 0.85, 1.15), 2.0, 4.5))
    gait = syn._Gait(**{**syn.RUN.__dict__, "stride": d.uniform("stride", 0.62, 0.72),
                        "duty": 0.28 * (3.0 / max(v0, v1)) ** 0.4,
                        "arm_swing": syn.RUN.arm_swing * d.uniform("arm_swing", 0.7, 1.3),
                        "lean": d.uniform("lean", 5 * DEG, 14 * DEG)})
    sp = _profile([0, 0.3 * duration, 0.7 * duration, duration], [v0, v0, v1, v1])
    # A body in flight cannot curve its path: the turn's centripetal acceleration (speed x rate)
    # is kept well below what the ballistic check allows.
    rate = d.sign("turn_dir") * d.uniform("yaw_rate_run", 0.0, 0.25 / max(v0, v1)) if d.coin("curve", 0.5) else 0.0
    yaw = _profile([0, 0.3 * duration, duration], [0.0, rate, rate])
    return syn._locomotion("run", duration, gait, sp, yaw_rate=yaw)


def turn_in_place(d: Draw) -> RawMotion:
    """Stepping round on the spot by 45-270 degrees at up to 90 deg/s."""
    angle = d.uniform("angle", 45 * DEG, 270 * DEG) * d.sign("direction")
    rate = d.uniform("yaw_rate", 0.3, 90 * DEG)
    ramp = 0.5  # s to reach the peak rate and to come back from it
    turning = abs(angle) / rate + ramp  # the eased ramps turn half as far as the peak rate would
    t0, t1 = 1.0, 1.0 + turning
    yaw = _profile([0, t0, t0 + ramp, t1 - ramp, t1, t1 + 1.4], np.sign(angle) * rate * np.array([0, 0, 1, 1, 0, 0]))
    act = _profile([0, 0.4, 1.0, t1, t1 + 0.8, t1 + 1.4], [0, 0, 1, 1, 0, 0])
    stride = min(d.uniform("stride", 0.8, 1.1), 0.55 / rate)
    return syn._locomotion("turn_in_place", t1 + 1.4, syn.WALK, 0.0, yaw_rate=yaw, activity=act,
                           stride=lambda t: np.full(np.shape(t), stride))


def _stepping(d: Draw, name: str, travel: float, speed_range) -> RawMotion:
    duration = d.uniform("duration", 4.0, 8.0)
    v = d.uniform("speed", *speed_range)
    sp = _profile([0, 0.5, 1.8, duration - 1.8, duration - 0.5, duration], [0, 0, v, v, 0, 0])
    act = _profile([0, 0.4, 1.2, duration - 1.2, duration - 0.4, duration], [0, 0, 1, 1, 0, 0])
    gait = syn._Gait(**{**syn.WALK.__dict__, "width": d.uniform("step_width", 0.07, 0.12),
                        "arm_swing": syn.WALK.arm_swing * d.uniform("arm_swing", 0.3, 1.0)})
    stride = d.uniform("stride", 0.9, 1.3)
    return syn._locomotion(name, duration, gait, sp, travel=travel, activity=act,
                           stride=lambda t: np.full(np.shape(t), stride))


def side_step(d: Draw) -> RawMotion:
    """Side steps, left or right, at 0.2-0.6 m/s, from standing to standing."""
    return _stepping(d, "side_step", d.sign("direction") * np.pi / 2, (0.2, 0.6))


def backward(d: Draw) -> RawMotion:
    """Walking backwards at 0.3-1.0 m/s, from standing to standing."""
    return _stepping(d, "backward", np.pi, (0.3, 1.0))


# ----------------------------------------------------------------------------- upper body

def _reach_target(d: Draw):
    """(azimuth, distance, height) of a reach target, the (azimuth, height) box held out."""
    test_region = d.split == "test" and d.coin("reach_region", 0.5)
    for _ in range(100):
        az = d.rng.uniform(*REACH_AZIMUTH_BAND) if test_region else d.rng.uniform(-0.5, 2.0)
        h = d.rng.uniform(*REACH_HEIGHT_BAND) if test_region else d.rng.uniform(0.35, 1.75)
        in_box = REACH_AZIMUTH_BAND[0] <= az <= REACH_AZIMUTH_BAND[1] and REACH_HEIGHT_BAND[0] <= h <= REACH_HEIGHT_BAND[1]
        if test_region or not in_box:
            break
    d.values.update(azimuth=float(az), height=float(h), held_out_region=bool(test_region))
    return az, d.uniform("distance", 0.3, 0.75), h


def reach(d: Draw) -> RawMotion:
    az, dist, h = _reach_target(d)
    return ub.reach(d.choice("side", ("L", "R")), az, dist, h, hold=d.uniform("hold", 0.2, 2.0),
                    tempo=d.uniform("tempo", 0.7, 1.5))


def wave(d: Draw) -> RawMotion:
    return ub.wave(d.choice("side", ("L", "R")), both=d.coin("both", 0.25),
                   raise_angle=d.uniform("raise_angle", 1.2, 2.3), waves=int(d.rng.integers(2, 6)),
                   frequency=d.uniform("frequency", 1.0, 2.2))


def punch(d: Draw) -> RawMotion:
    return ub.punch(d.choice("side", ("L", "R")), punches=int(d.rng.integers(1, 6)),
                    height=d.uniform("height", 1.0, 1.7), speed=d.uniform("speed", 0.7, 1.5))


def point(d: Draw) -> RawMotion:
    return ub.point(d.choice("side", ("L", "R")), direction=d.uniform("direction", -0.2, 1.4),
                    elevation=d.uniform("elevation", -0.5, 0.7), hold=d.uniform("hold", 0.5, 2.5))


def arm_raise(d: Draw) -> RawMotion:
    plane = d.uniform("plane", 0.0, np.pi / 2)
    # Forward raises stop at 115 degrees (the shoulder solve is singular beyond); sideways
    # ones go overhead.
    top = 2.0 + 0.8 * plane / (np.pi / 2)
    return ub.arm_raise(d.choice("side", ("L", "R")), both=d.coin("both", 0.5), plane=plane,
                        angle=d.uniform("angle", 0.9, top), hold=d.uniform("hold", 0.2, 2.0))


def walk_gesture(d: Draw) -> RawMotion:
    """A straight or gently curving walk with a wave, a point or a raised arm on the way."""
    duration = d.uniform("duration", 6.0, 9.0)
    v = d.uniform("speed", 0.6, 1.8)
    kind = d.choice("gesture", ("wave", "point", "raise"))
    start = d.uniform("gesture_start", 0.8, duration - 3.5)
    pose = ub.walking_arm_pose(kind, d.choice("side", ("L", "R")), start, d.uniform("gesture_length", 1.5, 3.0),
                               amount=d.uniform("amount", 0.0, 1.0))
    rate = d.sign("turn_dir") * d.uniform("yaw_rate_gentle", 0.0, 0.3)
    yaw = _profile([0, duration], [rate, rate])
    sp = lambda t: np.full(np.shape(t), v)
    return syn._locomotion("walk_gesture", duration, _walk_gait(d, v), v, yaw_rate=yaw, arm_pose=pose,
                           stride=_cadence(d, sp, yaw))


# ----------------------------------------------------------------------------- lower and whole body

def _within(d: Draw, name: str, lo: float, hi: float) -> float:
    """A draw between bounds that depend on other parameters, as a fraction of their span."""
    x = lo + d.uniform(f"{name}_fraction", 0.0, 1.0) * (hi - lo)
    d.values[name] = float(x)
    return x


def kick(d: Draw) -> RawMotion:
    side, height, tempo = d.choice("side", ("L", "R")), d.uniform("height", *KICK_HEIGHT), d.uniform("tempo", *KICK_TEMPO)
    reach = _within(d, "reach", *wb.kick_reach_range(height, side, tempo))
    return wb.kick(side, height=height, reach=reach, tempo=tempo)


def squat(d: Draw) -> RawMotion:
    return wb.squat(depth=d.uniform("depth", *SQUAT_DEPTH), descent=d.uniform("descent", *SQUAT_DESCENT),
                    hold=d.uniform("hold", *SQUAT_HOLD), width=d.uniform("width", *SQUAT_WIDTH))


def lunge(d: Draw) -> RawMotion:
    side, length = d.choice("side", ("L", "R")), d.uniform("length", *LUNGE_LENGTH)
    lo = max(LUNGE_DEPTH[0], wb.lunge_depth_min(length, side))
    return wb.lunge(side, length=length, depth=_within(d, "depth", lo, max(lo, LUNGE_DEPTH[1])))


def jump(d: Draw) -> RawMotion:
    return wb.jump(flight=d.uniform("flight", *JUMP_FLIGHT), distance=d.uniform("distance", *JUMP_DISTANCE),
                   direction=d.uniform("direction", -np.pi, np.pi), count=int(d.rng.integers(1, 4)))


def hop(d: Draw) -> RawMotion:
    return wb.hop(d.choice("side", ("L", "R")), count=int(d.rng.integers(1, 5)),
                  flight=d.uniform("flight", *HOP_FLIGHT), distance=d.uniform("distance", *HOP_DISTANCE),
                  direction=d.uniform("direction", -np.pi, np.pi))


def getup(d: Draw, ranges: dict | None = None) -> RawMotion:
    r = {**gu.RANGES["getup"], **(ranges or {})}
    return gu.getup(d.choice("start", gu.STARTS), d.choice("side", ("L", "R")), d.choice("roll", ("L", "R")),
                    **{name: d.uniform(name, *r[name]) for name in r})


def getup_quick(d: Draw) -> RawMotion:
    return getup(d, {"tempo": GETUP_QUICK_TEMPO, "lie": GETUP_QUICK_LIE})


# ----------------------------------------------------------------------------- transitions

def transition(d: Draw) -> RawMotion:
    """Walk, stop, do something (reach, wave, turn on the spot, or nothing), walk on. Training
    does one action per stop; the test split does the held-out sequence (reach, then turn)
    or a single action with a held-out speed."""
    if d.split == "test" and d.coin("held_out_sequence", 0.5):
        actions = HELD_OUT_SEQUENCE
    else:
        actions = (d.choice("action", TRANSITION_ACTIONS),)
    d.values["actions"] = list(actions)
    v_in, v_out = d.uniform("speed", 0.6, 1.9), d.uniform("speed_b", 0.6, 1.9)
    side = d.choice("side", ("L", "R"))
    walk_in, walk_out = d.uniform("walk_in", 2.5, 4.0), d.uniform("walk_out", 2.5, 4.0)
    t = walk_in + 1.2  # standing from here
    yaw_keys, arm_windows = [(0.0, 0.0), (t, 0.0)], []
    for a in actions:
        if a == "reach" or a == "wave":
            length = d.uniform(f"{a}_length", 1.8, 3.0)
            arm_windows.append((a, t, length))
            t += length
        elif a == "turn":
            angle = d.sign("turn_dir") * d.uniform("turn_angle", 45 * DEG, 180 * DEG)
            turning = abs(angle) / (0.8 * TRANSITION_TURN_RATE)  # eased in and out over a fifth each
            rate = np.sign(angle) * TRANSITION_TURN_RATE
            yaw_keys += [(t + 0.3, 0.0), (t + 0.3 + 0.2 * turning, rate), (t + 0.3 + 0.8 * turning, rate),
                         (t + 0.3 + turning, 0.0)]
            t += turning + 0.6
        else:
            t += d.uniform("pause", 0.5, 2.0)
    stand_end = t
    duration = stand_end + 1.2 + walk_out
    yaw_keys.append((duration, 0.0))
    yaw = _profile(*zip(*yaw_keys))
    # Walking in, a stop, standing (stepping while turning), walking on.
    sp = _profile([0, walk_in - 0.3, walk_in + 1.2, stand_end, stand_end + 1.5, duration],
                  [v_in, v_in, 0, 0, v_out, v_out])
    act_keys = _profile([0, walk_in + 0.2, walk_in + 1.2, stand_end - 0.2, stand_end + 0.8, duration],
                        [1, 1, 0, 0, 1, 1])
    act = lambda t_: np.maximum(act_keys(t_), np.clip(np.abs(yaw(t_)) / 0.3, 0, 1))
    poses = [ub.walking_arm_pose(kind, side, start, length, amount=d.uniform(f"amount_{i}", 0.3, 1.0))
             for i, (kind, start, length) in enumerate(arm_windows)]

    def arm_pose(t_, s, flex, abduct, elbow):
        twist = 0.0 * t_
        for p in poses:
            flex, abduct, elbow, tw = p(t_, s, flex, abduct, elbow)
            twist = twist + tw
        return flex, abduct, elbow, twist

    return syn._locomotion("transition", duration, _walk_gait(d, v_in), sp, yaw_rate=yaw, activity=act,
                           arm_pose=arm_pose, stride=_cadence(d, sp, yaw))


# ----------------------------------------------------------------------------- the families

@dataclass(frozen=True)
class Family:
    """A kind of motion: its generator, its group, how many clips each split has, and the
    parameter bands its test clips are drawn from (the training clips never are)."""

    name: str
    group: str
    make: Callable[[Draw], RawMotion]
    train: int
    test: int
    held_out: dict[str, tuple[float, float]] = field(default_factory=dict)
    description: str = ""
    default: bool = True  # part of "corpus:train" / "corpus:test" (else named explicitly)
    version: int = 1  # bump when this family's generator or ranges change (keys the caches that hold it)


FAMILIES: dict[str, Family] = {f.name: f for f in (
    Family("walk", "locomotion", walk, 270, 40,
           {"speed": WALK_SPEED_BAND, "speed_b": WALK_SPEED_BAND, "yaw_rate": YAW_RATE_BAND}, "walks 0.3-2.2 m/s with speed changes, curves, starts and stops"),
    Family("run", "locomotion", run, 120, 20, {"speed": RUN_SPEED_BAND}, "runs 2.0-4.5 m/s, speed changes, gentle curves"),
    Family("turn_in_place", "locomotion", turn_in_place, 45, 8, {"yaw_rate": YAW_RATE_BAND},
           "stepping round on the spot, 45-270 deg at up to 90 deg/s"),
    Family("side_step", "locomotion", side_step, 40, 6, {"speed": (0.35, 0.42)}, "side steps 0.2-0.6 m/s"),
    Family("backward", "locomotion", backward, 40, 6, {"speed": (0.6, 0.7)}, "walking backwards 0.3-1.0 m/s"),
    Family("reach", "upper_body", reach, 110, 20, {}, "one-hand reaches within 0.75 m, heights 0.35-1.75 m"),
    Family("wave", "upper_body", wave, 35, 6, {"frequency": (1.5, 1.7)}, "waves with one or both hands"),
    Family("punch", "upper_body", punch, 40, 6, {"height": (1.3, 1.4)}, "straight punches from a guard"),
    Family("point", "upper_body", point, 35, 6, {"direction": (0.5, 0.7)}, "pointing in a direction"),
    Family("arm_raise", "upper_body", arm_raise, 35, 6, {"plane": (0.6, 0.8)}, "arm raises forward to sideways"),
    Family("walk_gesture", "upper_body", walk_gesture, 50, 8, {"speed": WALK_SPEED_BAND},
           "a wave, point or raised arm while walking"),
    Family("kick", "whole_body", kick, 50, 8, {"height": KICK_HEIGHT_BAND}, "kicks of varied height, either leg"),
    Family("squat", "whole_body", squat, 45, 8, {"depth": SQUAT_DEPTH_BAND}, "squats and crouches of varied depth and speed"),
    Family("lunge", "whole_body", lunge, 30, 6, {"length": LUNGE_LENGTH_BAND}, "forward lunges"),
    Family("jump", "whole_body", jump, 60, 8, {"distance": JUMP_DISTANCE_BAND}, "two-foot jumps, varied height, distance, direction"),
    Family("hop", "whole_body", hop, 30, 6, {"flight": HOP_FLIGHT_BAND}, "one-leg hops"),
    Family("transition", "transitions", transition, 100, 16, {"speed": WALK_SPEED_BAND},
           "walk, stop, reach / wave / turn, walk on"),
    # Appended last: a family's index seeds its clips, so the others' stay as they were.
    Family("getup", "recovery", getup, 60, 10, {"tempo": GETUP_TEMPO_BAND},
           "from lying on the front or back to standing, by hands and knees, a bear stance and a crouch",
           default=False, version=4),  # 2: the knees slide on the push; 3: the bear-stance rise; 4: the push-off roll
    Family("getup_quick", "recovery", getup_quick, 60, 10, {"tempo": GETUP_QUICK_TEMPO_BAND},
           "the same get-ups at about twice the pace, after at most 0.5 s lying still", default=False,
           version=2),  # 2: the push-off roll
)}
GROUPS = tuple(dict.fromkeys(f.group for f in FAMILIES.values()))


# ----------------------------------------------------------------------------- making clips

@dataclass
class ClipRecord:
    """What the manifest keeps of one clip: its name, family, split, the parameters drawn and the
    number of redraws its physical checks asked for."""

    name: str
    family: str
    split: str
    frames: int
    params: dict
    redraws: int


def clip_stream(seed: int, split: str, family: str, index: int) -> np.random.Generator:
    """The random stream of one clip: the same on every machine, independent of every other."""
    words = [int(seed), SPLITS.index(split), list(FAMILIES).index(family), int(index)]
    return np.random.default_rng(np.random.SeedSequence(words))


def clip_name(family: str, split: str, index: int) -> str:
    """The name a corpus clip carries everywhere (the library, evaluation rows): walk_test_0003."""
    return f"{family}_{split}_{index:04d}"


def family_of(name: str) -> str | None:
    """The family of a clip named by `clip_name`, or None for any other name."""
    parts = name.rsplit("_", 2)
    if len(parts) != 3:
        return None
    family, split, index = parts
    ok = family in FAMILIES and split in SPLITS and len(index) == 4 and index.isdigit()
    return family if ok else None


def make_clip(seed: int, split: str, family: str, index: int) -> tuple[RawMotion, ClipRecord]:
    """Clip `index` of a family in a split, redrawn until it passes the physical checks."""
    fam = FAMILIES[family]
    rng = clip_stream(seed, split, family, index)
    problems = []
    for tries in range(MAX_TRIES):
        d = Draw(rng, split, fam.held_out)
        raw = fam.make(d)
        report = check_motion(raw)
        if report.ok:
            name = clip_name(family, split, index)
            raw = RawMotion(name, raw.fps, raw.root_pos, raw.local_quat, source=f"smpl_envs.corpus:{split}/{family}")
            params = {k: v for k, v in d.values.items()}
            if d.chosen is not None:
                params["held_out"] = d.chosen
                params["held_out_values"] = d.draws.get(d.chosen, [])
            return raw, ClipRecord(name, family, split, raw.num_frames, params, tries)
        problems = report.violations
    raise RuntimeError(f"corpus: {family} clip {index} ({split}) failed its physical checks "
                       f"{MAX_TRIES} times; last: {problems[:3]}")


def parse(spec: str) -> tuple[str, list[str]]:
    """("train" | "test", families) for "corpus:train", "corpus:test/<family or group>",
    "corpus:<family or group>" (training split), and "+"-joined terms ("corpus:test+getup")."""
    if not spec.startswith("corpus:"):
        raise ValueError(f"not a corpus name: {spec!r}")
    body = spec[len("corpus:"):]
    if "+" in body:  # "corpus:train+getup": more families or groups in the first term's split
        first, *more = body.split("+")
        split, families = parse(f"corpus:{first}")
        for term in more:
            if term not in FAMILIES and term not in GROUPS:
                raise ValueError(f"{spec!r}: {term!r} after '+' is not a corpus family or group; families: "
                                 f"{list(FAMILIES)}, groups: {list(GROUPS)}")
            _, extra = parse(f"corpus:{split}/{term}")
            families += [f for f in extra if f not in families]
        return split, families
    split, _, part = body.partition("/")
    if split not in SPLITS:
        split, part = "train", body
    defaults = [f.name for f in FAMILIES.values() if f.default]
    if part in ("", None):
        return split, defaults
    if part in FAMILIES:
        return split, [part]
    if part in GROUPS:
        return split, [f.name for f in FAMILIES.values() if f.group == part]
    raise ValueError(f"{spec!r}: unknown corpus family or group {part!r}; families: {list(FAMILIES)}, "
                     f"groups: {list(GROUPS)}, splits: {list(SPLITS)} (e.g. 'corpus:test/walk', 'corpus:train+getup')")


def generate(spec: str = "corpus:train", seed: int = DEFAULT_SEED, progress: bool = True,
             scale: float = 1.0) -> tuple[list[RawMotion], list[ClipRecord]]:
    """The clips (and their manifest records) a corpus name stands for. `scale` multiplies every
    family's clip count (tests make small corpora with it)."""
    split, families = parse(spec)
    jobs = [(f, i) for f in families for i in range(max(1, int(round(getattr(FAMILIES[f], split) * scale))))]
    raws, records = [], []
    for family, i in pbar(jobs, desc=f"generating {spec}", disable=not progress, unit="clip"):
        raw, rec = make_clip(seed, split, family, i)
        raws.append(raw)
        records.append(rec)
    return raws, records


def parse_seed(name: str) -> tuple[str, int]:
    """("corpus:...", seed) from a name with an optional "#<seed>" suffix ("corpus:test#3")."""
    spec, sep, seed = name.partition("#")
    if not sep:
        return spec, DEFAULT_SEED
    if not seed.isdigit():
        raise ValueError(f"{name!r}: the corpus seed after '#' must be a non-negative integer")
    return spec, int(seed)


def cache_key(spec: str, seed: int, scale: float = 1.0) -> str:
    split, families = parse(spec)
    # A family's own version enters the key only once bumped, so the corpora without it keep their caches.
    counts = [(f, getattr(FAMILIES[f], split), *([FAMILIES[f].version] if FAMILIES[f].version > 1 else []))
              for f in families]
    text = json.dumps([CORPUS_VERSION, int(seed), split, counts, float(scale)])
    return hashlib.sha1(text.encode()).hexdigest()[:16]


def write_manifest(path, spec: str, seed: int, records: list[ClipRecord]) -> None:
    """Every clip's family, split, frames and drawn parameters, and the per-family summary."""
    doc = dict(corpus=spec, seed=seed, version=CORPUS_VERSION, summary=summary(records),
               clips=[dict(name=r.name, family=r.family, split=r.split, frames=r.frames,
                           redraws=r.redraws, params=r.params) for r in records])
    with open(path, "w") as f:
        json.dump(doc, f, indent=1, default=float)


def summary(records: list[ClipRecord]) -> list[dict]:
    """Per family: clips, hours and frames, as docs/corpus.md's table shows them."""
    rows = []
    for fam in FAMILIES.values():
        recs = [r for r in records if r.family == fam.name]
        if recs:
            frames = sum(r.frames for r in recs)
            rows.append(dict(family=fam.name, group=fam.group, clips=len(recs),
                             hours=frames / syn.FPS / 3600, redraws=sum(r.redraws for r in recs),
                             description=fam.description))
    return rows


def table(records: list[ClipRecord]) -> str:
    """docs/corpus.md's table (markdown): per family, clips and hours of each split, ranges, and the
    bands only the test split draws from."""
    lines = ["| family | group | train clips | train h | test clips | test h | what it holds | held out for test |",
             "|---|---|---|---|---|---|---|---|"]
    for fam in FAMILIES.values():
        cell = []
        for split in SPLITS:
            recs = [r for r in records if r.family == fam.name and r.split == split]
            cell += [str(len(recs)), f"{sum(r.frames for r in recs) / syn.FPS / 3600:.2f}"]
        held = ", ".join(f"{k} {a:g}-{b:g}" for k, (a, b) in fam.held_out.items())
        if fam.name == "reach":
            held = (f"targets at azimuth {REACH_AZIMUTH_BAND[0]:g}-{REACH_AZIMUTH_BAND[1]:g} rad and height "
                    f"{REACH_HEIGHT_BAND[0]:g}-{REACH_HEIGHT_BAND[1]:g} m")
        if fam.name == "transition":
            held += f"; the sequence {' then '.join(HELD_OUT_SEQUENCE)}"
        lines.append(f"| {fam.name} | {fam.group} | {' | '.join(cell)} | {fam.description} | {held or '-'} |")
    frames = {s: sum(r.frames for r in records if r.split == s) for s in SPLITS}
    n = {s: sum(r.split == s for r in records) for s in SPLITS}
    lines.append(f"| **all** | | **{n['train']}** | **{frames['train'] / syn.FPS / 3600:.2f}** | **{n['test']}** | "
                 f"**{frames['test'] / syn.FPS / 3600:.2f}** | | |")
    return "\n".join(lines)

