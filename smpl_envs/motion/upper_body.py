"""Parametrised upper-body motions for the procedural corpus: reaches, waves, punches, pointing
and arm raises, standing (balanced, as the shipped quasi-static clips are) or as an arm pose to
lay over a walk (`procedural._locomotion(..., arm_pose=...)`).

An arm posture is four angles (radians): upper-arm flexion (forward swing) and abduction
(sideways lift) in the chest frame, elbow flexion, and the upper arm's twist; `procedural._arm`
turns them into a shoulder and elbow solve. A movement is a list of keyed postures, eased with
the minimum-jerk profile between keys (deliberate movements start and end at rest), so every
clip here begins and ends standing still with the arms relaxed. All functions are pure and
deterministic: the corpus draws their parameters.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import least_squares

from ..humanoid.kinematics import forward_kinematics
from ..rotations import quat_apply, quat_mul
from .motion import RawMotion
from .procedural import (
    B, DEG, OFFSETS, SIDES, _arm, _balanced, _fit_height, _solve_arm, _keys, _minjerk, _raw, _rot, _solve, _Spec,
    _standing_legs, _time, _upright_spine,
)

SOURCE = "smpl_envs.motion.upper_body"
REST = np.array([2, 10, 15, 0]) * DEG  # arms hanging relaxed: flex, abduct, elbow, twist
PELVIS_PITCH = 4 * DEG  # the standing clips' slight forward tilt


def _check(name: str, value, lo: float, hi: float) -> float:
    value = float(value)
    if not (np.isfinite(value) and lo <= value <= hi):
        raise ValueError(f"{name} must be a number in [{lo:g}, {hi:g}], got {value!r}")
    return value


def _side(side: str) -> str:
    if side not in SIDES:
        raise ValueError(f"side must be 'L' or 'R', got {side!r}")
    return side


def _other(side: str) -> str:
    return "R" if side == "L" else "L"


def arm_track(t, times, postures) -> tuple:
    """(flex, abduct, elbow, twist) per frame, eased through `postures` (K, 4) at `times` (K,)."""
    p = _keys(t, times, np.asarray(postures, float))
    return tuple(p[:, i] for i in range(4))


def _standing_clip(name, t, arms: dict, lean=None, drop=None, twist=None) -> RawMotion:
    """Both feet planted, the centre of mass balanced over them; `lean` (chest pitch), `drop`
    (pelvis lowering, m) and `twist` (chest yaw) per frame, zero by default."""
    zero = np.zeros(len(t))
    lean = zero if lean is None else lean
    drop = zero if drop is None else drop
    twist = zero if twist is None else twist
    # Bending far down tilts the pelvis too (hips flex), as people do rather than only the spine.
    pelvis_pitch = PELVIS_PITCH + 0.4 * lean
    angles = _upright_spine(t, pelvis_pitch, lean=1 * DEG + lean, twist=twist)
    angles[:, B["Neck"], 1] += 0.3 * lean  # keep looking at the hands' work, not the floor
    spec = _Spec(t, np.zeros((len(t), 3)), _rot(0 * t, pelvis_pitch),
                 _standing_legs(t, width=0.1 + 0.1 * np.max(drop)), arms, angles)
    return _raw(name, spec, _balanced(spec, 0.5, drop=0.004 + drop))


def _arms_from(t, tracks: dict) -> dict:
    """Arm dict for a spec: each side's posture track, or the relaxed rest."""
    return {s: _arm(t, s, *tracks.get(s, REST)) for s in SIDES}


# ----------------------------------------------------------------------------- reach

class _ArmModel:
    """Where a hand lands for an arm posture in a fixed standing pose: the body is solved once
    with the arms at rest, then only the shoulder-elbow-wrist chain is recomputed per posture
    (a posture changes nothing above the shoulder)."""

    def __init__(self, side: str, pelvis_pitch: float, lean: float, drop: float):
        t = np.zeros(1)
        spec = _Spec(t, np.zeros((1, 3)), _rot(t, pelvis_pitch), _standing_legs(t),
                     {s: _arm(t, s, *REST) for s in SIDES}, _upright_spine(t, pelvis_pitch, lean=1 * DEG + lean))
        _fit_height(spec, 0.004 + drop)
        self.side, self.local = side, _solve(spec)
        self.pos, self.quat = forward_kinematics(spec.pelvis_pos, self.local, OFFSETS)

    def hand(self, posture) -> np.ndarray:
        s = self.side
        local = self.local.copy()
        _solve_arm(s, self.quat[:, B["Chest"]], self.quat[:, B[f"{s}_Thorax"]], *_arm(np.zeros(1), s, *posture), local)
        pos, q = self.pos[0, B[f"{s}_Thorax"]], self.quat[0, B[f"{s}_Thorax"]]
        for body in ("Shoulder", "Elbow", "Wrist", "Hand"):
            i = B[f"{s}_{body}"]
            pos = pos + quat_apply(q, OFFSETS[i])
            q = quat_mul(q, local[0, i])
        return pos


def reach_posture(side: str, target, lean: float, drop: float) -> np.ndarray:
    """The arm posture (flex, abduct, elbow, twist) whose hand comes closest to `target` (world,
    m, the humanoid standing at the origin facing +x) with the chest leaning `lean` and the pelvis
    lowered by `drop`; a least-squares solve with a pull towards a natural, unstrained arm.
    (The balance shift applied to the whole clip afterwards moves the hand a few centimetres.)"""
    target = np.asarray(target, float)
    model = _ArmModel(side, PELVIS_PITCH + 0.4 * lean, lean, drop)
    natural = np.array([60, 20, 30, 0]) * DEG

    def residual(p):
        return np.concatenate([model.hand(p) - target, 0.02 * (p - natural)])

    # Forward flexion stops short of overhead (the shoulder solve is singular there): overhead
    # is reached through abduction, as in the shipped gesture clip.
    lo = np.array([-40, 0, 0, -60]) * DEG
    hi = np.array([115, 165, 140, 80]) * DEG
    return least_squares(residual, natural, bounds=(lo, hi), xtol=1e-6, max_nfev=100).x


def reach(side: str = "R", azimuth: float = 0.0, distance: float = 0.5, height: float = 1.2,
          hold: float = 0.8, tempo: float = 1.0, name: str = "reach") -> RawMotion:
    """Reach with one hand to a point and back. The point: `azimuth` (rad, from straight ahead,
    positive towards the reaching hand's side, [-0.6, 2.1]), `distance` (m, horizontal from the
    pelvis, [0.25, 0.8]) and `height` (m above the floor, [0.2, 1.9]). Low points are reached by
    leaning and bending the knees. `hold` (s, [0, 3]) at the point; `tempo` ([0.6, 1.6]) scales
    the speed of the movement."""
    side = _side(side)
    azimuth = _check("azimuth", azimuth, -0.6, 2.1)
    distance = _check("distance", distance, 0.25, 0.8)
    height = _check("height", height, 0.2, 1.9)
    hold = _check("hold", hold, 0.0, 3.0)
    tempo = _check("tempo", tempo, 0.6, 1.6)
    s = SIDES[side]
    target = np.array([distance * np.cos(azimuth), s * distance * np.sin(azimuth), height])
    # Points below the hip are reached by leaning forward and crouching, more the lower they are.
    lean = np.interp(height, [0.2, 0.6, 1.0], [75 * DEG, 35 * DEG, 0.0])
    drop = np.interp(height, [0.2, 0.5, 0.9], [0.32, 0.12, 0.0])
    posture = reach_posture(side, target, lean, drop)
    go = 0.9 / tempo
    keys = np.cumsum([0.0, 0.4, go, hold + 1e-3, go, 0.5])
    t = _time(keys[-1])
    amount = _keys(t, keys, [0, 0, 1, 1, 0, 0])
    track = arm_track(t, keys, [REST, REST, posture, posture, REST, REST])
    # The other arm moves a little out as a counterweight.
    counter = arm_track(t, keys, [REST, REST, REST + [0, 10 * DEG, 10 * DEG, 0], REST + [0, 10 * DEG, 10 * DEG, 0],
                                  REST, REST])
    twist = s * 0.25 * np.clip(azimuth, -0.5, 1.2) * amount  # the chest turns towards the point
    return _standing_clip(name, t, _arms_from(t, {side: track, _other(side): counter}),
                          lean=lean * amount, drop=drop * amount, twist=twist)


# ----------------------------------------------------------------------------- gestures

def wave(side: str = "R", both: bool = False, raise_angle: float = 95 * DEG, waves: int = 3,
         frequency: float = 1.5, name: str = "wave") -> RawMotion:
    """Raise an arm (`raise_angle`, rad of abduction, [1.0, 2.4]) and wave `waves` ([1, 6]) times
    at `frequency` Hz ([0.8, 2.5]) by swinging the forearm; `both` waves with both arms."""
    side = _side(side)
    raise_angle = _check("raise_angle", raise_angle, 1.0, 2.4)
    waves = int(_check("waves", waves, 1, 6))
    frequency = _check("frequency", frequency, 0.8, 2.5)
    waving = waves / frequency
    keys = np.cumsum([0.0, 0.4, 0.8, waving, 0.8, 0.4])
    t = _time(keys[-1])
    up = np.array([10 * DEG, raise_angle, 85 * DEG, 50 * DEG])
    track = list(arm_track(t, keys, [REST, REST, up, up, REST, REST]))
    on = _minjerk((t - keys[2]) / 0.25) * (1 - _minjerk((t - keys[3] + 0.25) / 0.25))
    track[2] = track[2] + 25 * DEG * on * np.sin(2 * np.pi * frequency * (t - keys[2]))
    tracks = {side: tuple(track)}
    if both:
        tracks[_other(side)] = tuple(track)
    return _standing_clip(name, t, _arms_from(t, tracks))


def punch(side: str = "R", punches: int = 2, height: float = 80 * DEG, speed: float = 1.0,
          name: str = "punch") -> RawMotion:
    """From a raised guard, `punches` ([1, 6]) straight punches alternating the hands, the first
    with `side`; `height` (rad of upper-arm flexion at full extension, [0.9, 1.8]: belly to
    head height); `speed` ([0.6, 1.6]) scales how fast each punch goes out and back."""
    side = _side(side)
    punches = int(_check("punches", punches, 1, 6))
    height = _check("height", height, 0.9, 1.8)
    speed = _check("speed", speed, 0.6, 1.6)
    guard = np.array([35, 25, 115, 10]) * DEG
    out = np.array([height, 8 * DEG, 8 * DEG, 0.0])
    beat = 0.55 / speed
    keys, tracks = [0.0, 0.4, 1.0], {s: [REST, REST, guard] for s in SIDES}
    twist_keys = [0.0, 0.0, 0.0]
    hand = side
    for _ in range(punches):
        keys += [keys[-1] + 0.45 * beat, keys[-1] + beat]
        for s in SIDES:
            tracks[s] += [out if s == hand else guard, guard]
        twist_keys += [-SIDES[hand] * 20 * DEG, 0.0]
        hand = _other(hand)
    keys += [keys[-1] + 0.7, keys[-1] + 1.1]
    for s in SIDES:
        tracks[s] += [REST, REST]
    twist_keys += [0.0, 0.0]
    t = _time(keys[-1])
    arms = _arms_from(t, {s: arm_track(t, keys, tracks[s]) for s in SIDES})
    return _standing_clip(name, t, arms, twist=_keys(t, keys, twist_keys))


def point(side: str = "R", direction: float = 0.3, elevation: float = 0.0, hold: float = 1.5,
          name: str = "point") -> RawMotion:
    """Point with a straight arm: `direction` (rad from straight ahead towards the pointing
    hand's side, [-0.3, 1.5]), `elevation` (rad above horizontal, [-0.6, 0.8]), held `hold` s
    ([0.3, 3])."""
    side = _side(side)
    direction = _check("direction", direction, -0.3, 1.5)
    elevation = _check("elevation", elevation, -0.6, 0.8)
    hold = _check("hold", hold, 0.3, 3.0)
    # A horizontal arm has 90 degrees of flexion; `direction` sweeps it out to the side.
    flex = (np.pi / 2 + elevation) * np.cos(direction)
    abduct = (np.pi / 2 + elevation) * np.sin(max(direction, 0.0))
    posture = np.array([flex, abduct, 10 * DEG, 0.0])
    keys = np.cumsum([0.0, 0.4, 0.8, hold, 0.8, 0.4])
    t = _time(keys[-1])
    amount = _keys(t, keys, [0, 0, 1, 1, 0, 0])
    return _standing_clip(name, t, _arms_from(t, {side: arm_track(t, keys, [REST, REST, posture, posture, REST, REST])}),
                          twist=SIDES[side] * 0.3 * direction * amount)


def arm_raise(side: str = "R", both: bool = True, plane: float = 0.0, angle: float = 150 * DEG,
              hold: float = 1.0, name: str = "arm_raise") -> RawMotion:
    """Raise one or `both` arms straight by `angle` (rad, [0.8, 2.9]) in a vertical plane turned
    `plane` rad from forward to sideways ([0, pi/2]), hold `hold` s ([0, 3]), lower."""
    side = _side(side)
    plane = _check("plane", plane, 0.0, np.pi / 2)
    angle = _check("angle", angle, 0.8, 2.9)
    hold = _check("hold", hold, 0.0, 3.0)
    posture = np.array([angle * np.cos(plane), angle * np.sin(plane), 12 * DEG, 0.0])
    keys = np.cumsum([0.0, 0.4, 1.1, hold + 1e-3, 1.1, 0.4])
    t = _time(keys[-1])
    track = arm_track(t, keys, [REST, REST, posture, posture, REST, REST])
    tracks = {side: track}
    if both:
        tracks[_other(side)] = track
    return _standing_clip(name, t, _arms_from(t, tracks))


# ----------------------------------------------------------------------------- while walking

def walking_arm_pose(kind: str, side: str, start: float, duration: float, amount: float = 1.0,
                     frequency: float = 1.5):
    """An `arm_pose` for `procedural._locomotion`: during [start, start + duration] s, arm `side`
    blends from its swing to a gesture (`kind`: "wave", "point", "raise" or "reach" (forward and
    up, as for something on a shelf); `amount` [0, 1]
    scales its height) and back; the other arm keeps swinging."""
    side = _side(side)
    if kind not in ("wave", "point", "raise", "reach"):
        raise ValueError(f"kind must be 'wave', 'point', 'raise' or 'reach', got {kind!r}")
    amount = _check("amount", amount, 0.0, 1.0)
    pose = {"wave": [10 * DEG, (60 + 50 * amount) * DEG, 85 * DEG, 50 * DEG],
            "point": [(50 + 50 * amount) * DEG, 15 * DEG, 10 * DEG, 0.0],
            "raise": [(60 + 50 * amount) * DEG, 10 * DEG, 15 * DEG, 0.0],
            "reach": [(60 + 50 * amount) * DEG, 20 * DEG, 25 * DEG, 0.0]}[kind]

    def arm_pose(t, s, flex, abduct, elbow):
        if s != side:
            return flex, abduct, elbow, 0.0
        w = _minjerk((t - start) / 0.6) * (1 - _minjerk((t - (start + duration - 0.6)) / 0.6))
        e = pose[2] + (25 * DEG * np.sin(2 * np.pi * frequency * (t - start)) if kind == "wave" else 0.0)
        return ((1 - w) * flex + w * pose[0], (1 - w) * abduct + w * pose[1],
                (1 - w) * elbow + w * e, w * pose[3])

    return arm_pose
