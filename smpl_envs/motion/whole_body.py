"""Parametrised lower- and whole-body motion families: kicks, squats, lunges, jumps and hops.

Each family is a pure, deterministic function of a few physical parameters returning a
`RawMotion` at 30 fps that starts and ends standing still (so clips can be chained), built on the
machinery of `smpl_envs.motion.procedural` (pelvis trajectory + foot / arm targets solved by
closed-form IK, centre of mass balanced over the support where the motion is slow, ballistic
flight where the body leaves the ground). The shipped clips "kick", "crouch" and "jump" are
particular members (synthetic.py calls these functions).

Parameters are validated: a value that is not finite or outside its range raises ValueError
naming it. `RANGES[family][parameter]` holds each range (the corpus samples from them); where a
range depends on another parameter (a kick's reach on its height), a function gives it.
Lengths in metres, times in seconds, angles in radians; positions are of the toe joint (the ball
of the foot) unless stated, heights above the floor z = 0, the body facing +x.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from ..rotations import quat_apply, yaw_quat
from .motion import FPS, RawMotion
from .plausibility import GRAVITY
from .procedural import (
    B, BALL_HEIGHT, DEG, FOOT_CENTRE, OFFSETS, SIDES, SKELETON, _arm, _balanced, _centre_of_mass,
    _hermite, _keys, _leg_length, check_number, _max_pelvis_height, _minjerk, _rot, _smooth_below, _solve, _Spec,
    _standing_legs, _support_point, _time, _upright_spine,
)

SOURCE = "smpl_envs.motion.whole_body"

RANGES: dict[str, dict[str, tuple[float, float]]] = {
    # height: toe joint at full extension; reach: its forward travel (see kick_reach_range);
    # tempo: speed factor of the whole movement (duration 4 s / tempo).
    "kick": {"height": (0.2, 0.9), "tempo": (0.7, 1.4)},
    # depth: pelvis drop at the bottom; descent / hold / ascent: durations; width: lateral offset
    # of each toe joint from the centre line.
    "squat": {"depth": (0.05, 0.25), "descent": (0.5, 2.0), "hold": (0.0, 2.0), "ascent": (0.5, 2.0),
              "width": (0.08, 0.14)},
    # length: forward step of the front toe joint; depth: pelvis drop at the bottom.
    "lunge": {"length": (0.5, 0.9), "depth": (0.12, 0.3)},
    # flight: time in the air per jump; distance: travel per jump; direction: of travel relative
    # to the facing direction (the body keeps facing +x).
    "jump": {"flight": (0.25, 0.5), "distance": (0.0, 0.8), "direction": (-np.pi, np.pi), "count": (1, 3)},
    "hop": {"flight": (0.15, 0.3), "distance": (0.0, 0.4), "direction": (-np.pi, np.pi), "count": (1, 4)},
}


# ----------------------------------------------------------------------------- validation

def _check(family: str, name: str, value, bounds: tuple[float, float] | None = None) -> float:
    return check_number(family, name, value, RANGES[family][name] if bounds is None else bounds)


def _check_count(family: str, value) -> int:
    lo, hi = RANGES[family]["count"]
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not lo <= value <= hi:
        raise ValueError(f"{family}: count = {value!r} must be an integer in [{lo}, {hi}]")
    return int(value)


def _check_side(family: str, side) -> str:
    if side not in SIDES:
        raise ValueError(f"{family}: side = {side!r} must be 'L' or 'R'")
    return side


def _other(side: str) -> str:
    return "R" if side == "L" else "L"


def _clip(name: str, spec: _Spec, local: np.ndarray) -> RawMotion:
    return RawMotion(name, FPS, spec.pelvis_pos.copy(), local, source=SOURCE)


# ----------------------------------------------------------------------------- kick

# The shipped kick, the reference the family scales from: toe joint 0.50 m above its standing
# height and 0.70 m ahead at full extension.
_KICK_LIFT, _KICK_REACH = 0.50, 0.70
# Nominal hip of the kicking leg at extension relative to the standing toe joint (back, up): for
# rough angles only (the foot's tilt with the leg, how high the thigh goes, a first guess).
_KICK_HIP = (-0.05, 0.80)
# Straightest and most bent knee at full extension: a locked knee cannot snap, and beyond 80 deg
# the "kick" is a knee raise.
_KICK_KNEE = (10 * DEG, 80 * DEG)
_KICK_DURATION, _KICK_EXTENSION = 4.0, 1.7  # s at tempo 1: the clip, the moment of full extension


def _kick_elevation(lift, reach):
    """Angle above the horizontal of the line from the (nominal) hip to the extended toe joint."""
    return np.arctan2(lift - _KICK_HIP[1], reach - _KICK_HIP[0])


def _kick_thigh_elevation(lift, reach):
    """Rough angle of the thigh above the horizontal with the toe joint at (reach, lift): the
    (nominal) hip to toe-joint line plus the knee bend the distance asks for (thigh 0.38 m, shank
    and foot 0.53 m)."""
    thigh, shank = 0.38, 0.53
    dist = np.hypot(lift - _KICK_HIP[1], reach - _KICK_HIP[0])
    opening = np.arccos(np.clip((thigh ** 2 + dist ** 2 - shank ** 2) / (2 * thigh * dist), -1.0, 1.0))
    return _kick_elevation(lift, reach) + opening


def kick(side: str = "R", height: float = 0.5, reach: float | None = None, tempo: float = 1.0,
         name: str = "kick") -> RawMotion:
    """A front kick with the `side` leg, standing on the other.

    Weight onto the standing foot, chamber the knee, snap the foot out until its toe joint is
    `height` m above the floor and `reach` m ahead of where it stood, re-chamber, put the foot
    back, weight back onto both feet. The arms hold a guard that counter-swings (the arm opposite
    the kicking leg forward at impact); the trunk leans back more for higher kicks. The centre of
    mass stays over the standing foot throughout.

    height: 0.2-0.9 m. reach: within `kick_reach_range(height, side, tempo)`, which keeps the
    extended knee bent 10-80 deg (checked on the solved kick, to 3 deg); None picks the middle of
    that range. tempo: 0.7-1.4, the clip lasting 4 s / tempo.
    """
    side = _check_side("kick", side)
    height = _check("kick", "height", height)
    tempo = _check("kick", "tempo", tempo)
    if reach is None:
        reach = float(np.mean(kick_reach_range(height, side, tempo)))
    reach = _check("kick", "reach", reach, (0.0, 1.0))  # finite; the leg's own bound follows
    spec = _kick_spec(side, height - BALL_HEIGHT[side], reach, tempo)
    local = _solve(spec)
    knee = 2 * np.arctan2(local[:, B[f"{side}_Knee"], 2], local[:, B[f"{side}_Knee"], 0])  # about y
    bend = knee[int(round(_KICK_EXTENSION / tempo * FPS))]
    if not _KICK_KNEE[0] - 3 * DEG <= bend <= _KICK_KNEE[1] + 3 * DEG:
        lo, hi = kick_reach_range(height, side, tempo)
        raise ValueError(f"kick: reach = {reach!r} m leaves the extended knee bent {np.degrees(bend):.0f} deg; "
                         f"a kick {height:.3g} m high reaches [{lo:.3f}, {hi:.3f}] m")
    return _clip(name, spec, local)


@lru_cache(maxsize=1024)
def kick_reach_range(height: float, side: str = "R", tempo: float = 1.0) -> tuple[float, float]:
    """(shortest, longest) reach (m) of a kick `height` m high: the extended knee bent 80 and
    10 deg (to within a degree or two)."""
    side = _check_side("kick", side)
    height = _check("kick", "height", height)
    tempo = _check("kick", "tempo", tempo)
    lift = height - BALL_HEIGHT[side]
    guess = float(np.sqrt(max(0.8 ** 2 - (_KICK_HIP[1] - lift) ** 2, 0.0))) + _KICK_HIP[0]
    knee = np.array(_KICK_KNEE[::-1])
    reach = np.full(2, guess)
    for _ in range(5):  # fixed point: the hip (balance, lean) and the foot's tilt move with the reach
        # Every frame of the kick is solved on its own: two copies of the extension frame, one
        # per bound, tell where the hip is.
        spec = _kick_spec(side, lift, reach, tempo, t=np.full(2, _KICK_EXTENSION / tempo))
        hip = spec.pelvis_pos + quat_apply(spec.pelvis_quat, OFFSETS[B[f"{side}_Hip"]])
        leg = spec.legs[side]
        toe_off = quat_apply(_rot(leg.foot_yaw, leg.foot_pitch), OFFSETS[B[f"{side}_Toe"]])
        ankle = leg.ball - toe_off
        # Toe joint x at which the hip-ankle distance is the leg length for this knee bend.
        dyz2 = (ankle[:, 1] - hip[:, 1]) ** 2 + (ankle[:, 2] - hip[:, 2]) ** 2
        x = hip[:, 0] + np.sqrt(np.maximum(_leg_length(side, knee) ** 2 - dyz2, 0.0)) + toe_off[:, 0]
        reach = reach + x - leg.ball[:, 0]
    return float(reach[0]), float(reach[1])


def _kick_spec(side: str, lift: float, reach, tempo: float, t=None) -> _Spec:
    """The kick solved up to its final IK: pelvis placed, every target set (at times `t`, default
    the whole clip; `reach` may differ per frame)."""
    stand = _other(side)
    t = _time(_KICK_DURATION / tempo) if t is None else t
    legs = _standing_legs(t)
    # Timeline: weight onto the standing foot, chamber the knee, snap the kick, re-chamber, put the
    # foot back, weight back to both feet.
    keys = np.array([0.0, 0.5, 1.1, 1.45, _KICK_EXTENSION, 2.0, 2.45, 3.1, _KICK_DURATION]) / tempo
    on_standing = _keys(t, keys, [0.5, 0.5, 0.97, 0.97, 0.97, 0.97, 0.97, 0.5, 0.5])
    weight_left = on_standing if stand == "L" else 1 - on_standing
    # Kicking foot, toe-joint target relative to the standing position (forward, up); the chamber
    # is the same fraction of the extension for every kick.
    chamber_fwd, chamber_up = 0.30 / _KICK_REACH, 0.24 / _KICK_LIFT
    fwd = reach * _keys(t, keys, [0, 0, 0, chamber_fwd, 1, chamber_fwd, 0, 0, 0])
    up = lift * _keys(t, keys, [0, 0, 0, chamber_up, 1, chamber_up, 0, 0, 0])
    # Foot world pitch: toes pointed down under the chambered knee; at full extension the ankle is
    # extended so the sole faces the target (ball-of-foot strike), the foot tilting up with the
    # leg for higher kicks.
    extension = -40 * DEG - (_kick_elevation(lift, reach) - _kick_elevation(_KICK_LIFT, _KICK_REACH))
    pitch = (_keys(t, keys, [0, 0, 0, 20 * DEG, 0, 20 * DEG, 0, 0, 0])
             + extension * _keys(t, keys, [0, 0, 0, 0, 1, 0, 0, 0, 0]))
    k = legs[side]
    k.ball = k.ball + np.stack([fwd, 0 * t, up], -1)
    k.foot_pitch = pitch
    k.toe_flat = 1 - _minjerk(up / 0.05)  # toes relax once the foot is off the floor
    k.grounded = up < 1e-4
    lean_back = _keys(t, keys, np.deg2rad([0, 0, 0, -6, -14, -6, 0, 0, 0])) * (lift / _KICK_LIFT)
    pelvis_pitch = 4 * DEG + lean_back
    angles = _upright_spine(t, pelvis_pitch, lean=1 * DEG + 0.6 * lean_back)
    # Arms: raised guard that counter-swings, the arm opposite the kicking leg forward and the
    # other back at impact.
    guard = _keys(t, keys, [0, 0, 0.6, 1, 1, 1, 0.6, 0, 0])
    snap = _keys(t, keys, [0, 0, 0, 0.3, 1, 0.3, 0, 0, 0])
    arms = {stand: _arm(t, stand, (5 + 25 * guard + 20 * snap) * DEG, (12 + 20 * guard) * DEG,
                        (15 + 75 * guard) * DEG),
            side: _arm(t, side, (5 + 15 * guard - 40 * snap) * DEG, (12 + 25 * guard) * DEG,
                       (15 + 70 * guard - 30 * snap) * DEG)}
    spec = _Spec(t, np.zeros((len(t), 3)), _rot(0 * t, pelvis_pitch), legs, arms, angles)
    # Only the standing leg limits the height once the kicking foot is off the floor.
    target = _support_point(spec, weight_left)[:, :2]
    # A leg raised to near horizontal can hardly swing sideways (and the humanoid's x-y-z hip
    # hinges lock there: a degree of it takes tens of degrees of abduction and twist). Kicks
    # raising the thigh higher than the shipped one move in the hip's sagittal plane: the ankle straight in front
    # of the hip (offset as in the rest pose) instead of ahead of where the foot stood, the foot
    # (whose yaw sets the knee's hinge axis) not turned out.
    raised = np.maximum(*(  # thigh higher than the shipped kick's, at extension and at the chamber
        _kick_thigh_elevation(f * lift, g * reach) - _kick_thigh_elevation(f * _KICK_LIFT, g * _KICK_REACH)
        for f, g in ((1.0, 1.0), (chamber_up, chamber_fwd))))
    # Exactly full from half the chamber's height up, where the hip may pass 90 deg of flexion.
    aim = _minjerk(raised / (3 * DEG)) * _minjerk(up / (0.5 * chamber_up * lift))
    stand_y = k.ball[:, 1].copy()
    k.foot_yaw = k.foot_yaw * (1 - aim)  # the knee bends in that plane too: no toe-out
    leg_y = OFFSETS[B[f"{side}_Knee"], 1] + OFFSETS[B[f"{side}_Ankle"], 1]  # kept by hip flexion
    toe_y = quat_apply(_rot(k.foot_yaw, k.foot_pitch), OFFSETS[B[f"{side}_Toe"]])[:, 1]

    def aim_at_hip():  # near gimbal lock a millimetre of sideways error is degrees of hip hinge
        hip_y = (spec.pelvis_pos + quat_apply(spec.pelvis_quat, OFFSETS[B[f"{side}_Hip"]]))[:, 1]
        k.ball[:, 1] = stand_y + aim * (hip_y + leg_y + toe_y - stand_y)

    for _ in range(5):
        aim_at_hip()
        zs, zk = _max_pelvis_height(spec, stand), _max_pelvis_height(spec, side)
        spec.pelvis_pos[:, 2] = np.where(k.grounded, np.minimum(zs, zk), zs) - 0.02
        local = _solve(spec)
        spec.pelvis_pos[:, :2] += target - _centre_of_mass(spec.pelvis_pos, local)[:, :2]
    aim_at_hip()
    # Smooth the switch of height limit at lift-off (tiny, but keeps the velocity continuous).
    zs, zk = _max_pelvis_height(spec, stand), _max_pelvis_height(spec, side)
    z = np.where(k.grounded, np.minimum(zs, zk), zs) - 0.02
    spec.pelvis_pos[:, 2] = np.minimum(np.convolve(np.pad(z, 3, mode="edge"), np.ones(7) / 7, "valid"),
                                       np.minimum(zs, np.where(k.grounded, zk, np.inf)) - 0.005)
    return spec


# ----------------------------------------------------------------------------- squat

_SQUAT_LEAD, _SQUAT_TAIL = 0.6, 1.1  # s standing still before and after
# The shipped crouch's bend, which the posture scales from: pelvis 0.21 m below the highest the
# legs allow in the squatting posture.
_SQUAT_BEND = 0.21
_SQUAT_BASE_DROP = 0.008  # standing knees slightly soft


def squat(depth: float = 0.2, descent: float = 1.0, hold: float = 0.5, width: float = 0.12,
          ascent: float | None = None, name: str = "squat") -> RawMotion:
    """A squat: feet flat, `width` m either side of the centre line and turned out 12 deg; the
    pelvis sinks `depth` m in `descent` s (minimum jerk), stays `hold` s, and rises in `ascent` s
    (None: as long as the descent). The pelvis tips and the chest leans forward and the arms come
    up in front as counterweight with the depth (the pelvis tips and the arms rise no further
    than in the shipped crouch's 0.22 m), the centre of mass staying over the middle of the feet.

    depth: 0.05-0.25 m (knees bent up to ~90 deg; deeper, the hips flex past 90 deg with the
    thighs turned out over the toes, which the humanoid's x-y-z hip hinges reach only outside
    their anatomical ranges). descent, ascent: 0.5-2 s. hold: 0-2 s. width: 0.08-0.14 m (wider, the
    turned-out thighs of a deep squat leave the hip's range too).
    """
    depth = _check("squat", "depth", depth)
    descent = _check("squat", "descent", descent)
    hold = _check("squat", "hold", hold)
    width = _check("squat", "width", width)
    ascent = descent if ascent is None else _check("squat", "ascent", ascent)
    return _squat(_squat_bend(depth, width), descent, hold, ascent, width, name)


def _squat(bend: float, descent: float, hold: float, ascent: float, width: float, name: str) -> RawMotion:
    """The squat whose bottom pelvis is `bend` m below the highest the legs allow there."""
    t0 = _SQUAT_LEAD
    keys = [0.0, t0, t0 + descent, t0 + descent + hold, t0 + descent + hold + ascent,
            t0 + descent + hold + ascent + _SQUAT_TAIL]
    t = _time(keys[-1])
    spec, drop = _squat_spec(t, _keys(t, keys, [0, 0, 1, 1, 0, 0]), bend, width)
    return _clip(name, spec, _balanced(spec, 0.5, drop=drop))


def _squat_spec(t, depth, bend: float, width: float):
    """Squat posture for bottom fraction `depth` (0 standing .. 1 bottom) per frame, and the drop
    below the legs' reach that goes with it."""
    legs = _standing_legs(t, width=width, toe_out=12 * DEG)
    s = bend / _SQUAT_BEND  # posture relative to the shipped crouch's
    pelvis_pitch = 4 * DEG + 20 * DEG * min(s, 1.0) * depth
    lean = 1 * DEG + 30 * DEG * s * depth
    angles = _upright_spine(t, pelvis_pitch, lean=lean)
    angles[:, B["Neck"], 1] += 15 * DEG * s * depth  # keep looking ahead, not at the ceiling
    # Arms come forward as a counterweight, to shoulder height at most (world flex minus the lean).
    flex = 3 * DEG + 80 * DEG * min(s, 1.0) * depth
    arms = {side: _arm(t, side, flex - lean, 10 * DEG, 15 * DEG) for side in SIDES}
    spec = _Spec(t, np.zeros((len(t), 3)), _rot(0 * t, pelvis_pitch), legs, arms, angles)
    return spec, _SQUAT_BASE_DROP + bend * depth


def _squat_bend(depth: float, width: float) -> float:
    """The bend whose squat sinks the pelvis `depth` m: tipping the pelvis and sitting back lower
    the legs' reach too, so the bend is a little less than the depth (secant on a two-frame
    squat: standing and bottom, each solved exactly as in the clip)."""
    t = np.zeros(2)

    def sink(bend):
        spec, drop = _squat_spec(t, np.array([0.0, 1.0]), bend, width)
        _balanced(spec, 0.5, drop=drop)
        return spec.pelvis_pos[0, 2] - spec.pelvis_pos[1, 2]

    b0, b1 = depth, depth * depth / sink(depth)
    f0, f1 = sink(b0) - depth, sink(b1) - depth
    for _ in range(8):
        if abs(f1) < 1e-7 or f1 == f0:
            break
        b0, b1, f0 = b1, b1 - f1 * (b1 - b0) / (f1 - f0), f1
        f1 = sink(b1) - depth
    return b1


# ----------------------------------------------------------------------------- jump

# Timeline of one jump from the start of its dip (s): bottom of the dip, heels start rising,
# take-off; after landing the heels are down at +0.12, the landing absorbed at +0.3, the hips
# forward again at +0.35, standing at _JUMP_CYCLE.
_JUMP_LEAD, _JUMP_TAIL = 0.5, 0.5
_JUMP_BOTTOM, _JUMP_HEELS, _JUMP_OFF, _JUMP_CYCLE = 0.55, 0.65, 0.9, 2.6
_JUMP_HEEL = 32 * DEG  # heels up at take-off and landing (on the balls of the feet)
_JUMP_REF_FLIGHT = 0.4  # the shipped jump's: dip and landing absorption scale with the flight
_JUMP_DIP, _JUMP_ABSORB = 0.20, 0.15
_JUMP_HIPS = -0.02  # pelvis x relative to its standing position at take-off and landing
# Above this horizontal speed the pelvis leads the feet at take-off and trails them at landing by
# _JUMP_LEAD_GAIN s per m/s of the excess: a fast jump leans into its take-off and lands with the
# feet ahead, so the hips neither swing back before take-off nor overshoot the feet after landing.
_JUMP_LEAD_SPEED, _JUMP_LEAD_GAIN = 0.75, 0.12


def jump(flight: float = 0.4, distance: float = 0.3, direction: float = 0.0, count: int = 1,
         name: str = "jump") -> RawMotion:
    """Two-footed countermovement jumps: dip (hips back, arms back), drive up onto the balls of the
    feet with the arms swinging up, a ballistic flight of `flight` s with the legs tucked a
    little, land on the balls, absorb, stand up; `count` times in a row, each travelling
    `distance` m in the direction `direction` (rad, 0 = forward, pi/2 = to the left; the body
    keeps facing +x).

    flight: 0.25-0.5 s (pelvis apex g flight^2 / 8 = 8-31 cm above take-off). distance: 0-0.8 m.
    direction: -pi..pi. count: 1-3 (the clip lasts 1 + 2.6 count s).
    """
    flight = _check("jump", "flight", flight)
    distance = _check("jump", "distance", distance)
    direction = _check("jump", "direction", direction)
    count = _check_count("jump", count)
    t = _time(_JUMP_LEAD + count * _JUMP_CYCLE + _JUMP_TAIL)
    legs = _standing_legs(t)
    n = len(t)
    travel = distance * np.array([np.cos(direction), np.sin(direction)])
    at_off, at_land, v_xy = _jump_hips(flight, travel)
    starts = _JUMP_LEAD + _JUMP_CYCLE * np.arange(count)  # start of each dip
    t_off = starts + _JUMP_OFF
    t_land = t_off + flight
    air = np.zeros(n, bool)
    for a, b in zip(t_off, t_land):
        air |= (t > a + 1e-6) & (t < b - 1e-6)

    # Feet: heels rise before take-off and drop after landing; in the air the balls follow the
    # pelvis with the legs tucked a little; each stance is `travel` beyond the last.
    pitch = sum(_keys(t, [0, s + _JUMP_HEELS, a, b, b + 0.12, s + _JUMP_CYCLE + _JUMP_TAIL],
                      [0, 0, _JUMP_HEEL, _JUMP_HEEL, 0, 0]) for s, a, b in zip(starts, t_off, t_land))
    stance = sum(np.clip((t - a) / flight, 0, 1)[:, None] * travel for a in t_off)
    for leg in legs.values():
        leg.foot_pitch = pitch
        leg.grounded = ~air

    # Pelvis xy, each jump's share relative to its own stance (zero before it, `travel` after):
    # hips back during the dip, forward through the flight, absorbing after landing.
    xy = sum(_hermite(t, [0, s, s + _JUMP_BOTTOM, a, b, b + 0.35, s + _JUMP_CYCLE - 0.1, s + _JUMP_CYCLE + _JUMP_TAIL],
                      np.array([[0, 0], [0, 0], [-0.08, 0], at_off, travel + at_land, travel + [-0.06, 0],
                                travel, travel]),
                      np.array([[0, 0], [0, 0], [0, 0], v_xy, v_xy, [0, 0], [0, 0], [0, 0]]))
             for s, a, b in zip(starts, t_off, t_land))
    # One hermite shape per signal and jump: the trunk pitches with the dip and the landing, the
    # arms swing back in the dip and up through take-off, forward for the landing.
    def posture(values):
        return sum(_hermite(t, [0, s, s + _JUMP_BOTTOM, a, b, b + 0.3, s + _JUMP_CYCLE, s + _JUMP_CYCLE + _JUMP_TAIL],
                            values, [0] * 8) for s, a, b in zip(starts, t_off, t_land))

    pelvis_pitch = 4 * DEG + posture(np.deg2rad([0, 0, 18, 5, 8, 15, 0, 0]))
    lean = 1 * DEG + posture(np.deg2rad([0, 0, 32, 4, 8, 24, 0, 0]))
    pos = np.zeros((n, 3))
    pos[:, :2] = xy
    spec = _Spec(t, pos, _rot(0 * t, pelvis_pitch), legs, {}, _upright_spine(t, pelvis_pitch, lean=lean))
    flex = np.deg2rad(3 + posture([0, 0, -48, 107, 57, 37, 0, 0])) - lean
    spec.arms = {side: _arm(t, side, flex, 12 * DEG, 25 * DEG) for side in SIDES}

    for leg in legs.values():
        leg.ball = leg.ball + np.concatenate([stance, np.zeros((n, 1))], -1)
    _jump_flights(spec, flight, starts, t_off, t_land, air, at_off - at_land)
    return _clip(name, spec, _solve(spec))


def _jump_hips(flight: float, travel: np.ndarray):
    """Pelvis xy relative to the stance at take-off and at landing, and its velocity in the air.

    Up to _JUMP_LEAD_SPEED the hips are at _JUMP_HIPS both times; faster, they lead the feet at
    take-off and trail them at landing by _JUMP_LEAD_GAIN s times the excess speed, which
    itself depends on the lead: |v| flight = distance - 2 lead(|v|)."""
    distance = float(np.linalg.norm(travel))
    speed = distance / flight
    if speed > _JUMP_LEAD_SPEED:
        speed = (distance + 2 * _JUMP_LEAD_GAIN * _JUMP_LEAD_SPEED) / (flight + 2 * _JUMP_LEAD_GAIN)
    lead = _JUMP_LEAD_GAIN * max(speed - _JUMP_LEAD_SPEED, 0.0) * travel / max(distance, 1e-12)
    hips = np.array([_JUMP_HIPS, 0.0])
    at_off, at_land = hips + lead, hips - lead
    return at_off, at_land, (travel + at_land - at_off) / flight


def _jump_flights(spec: _Spec, flight: float, starts, t_off, t_land, air, swing) -> None:
    """Pelvis height through every jump and the feet in the air (`swing`: how far the feet move
    forward relative to the hips during a flight)."""
    t, legs, pos = spec.t, spec.legs, spec.pelvis_pos
    n = len(t)
    vz = GRAVITY * flight / 2  # take-off and landing at the same height
    scale = flight / _JUMP_REF_FLIGHT
    # Where the legs allow the pelvis at take-off (heels up, knees nearly straight); the landing
    # pose mirrors it, so take-off and landing heights are equal and the flight is symmetric.
    zmax = np.minimum(_max_pelvis_height(spec, "L"), _max_pelvis_height(spec, "R"))
    z_stand = np.min(zmax[: int(_JUMP_LEAD * FPS)]) - 0.005
    z = np.full(n, z_stand)
    rel = {s: np.zeros((n, 3)) for s in SIDES}
    for s, a, b in zip(starts, t_off, t_land):
        i_off, i_land = int(round(a * FPS)), min(int(round(b * FPS)), n - 1)
        z_off = min(zmax[i_off], zmax[i_land]) - 0.01
        rise = _hermite(t, [0, s, s + _JUMP_BOTTOM, a],
                        [z_stand, z_stand, z_stand - _JUMP_DIP * scale, z_off], [0, 0, 0, vz])
        tau = t - a
        ballistic = z_off + vz * tau - 0.5 * GRAVITY * tau ** 2
        settle = _hermite(t, [b, b + 0.3, s + _JUMP_CYCLE, s + _JUMP_CYCLE + _JUMP_TAIL],
                          [z_off, z_stand - _JUMP_ABSORB * scale, z_stand, z_stand], [-vz, 0, 0, 0])
        mine = (t > s - 1e-6) & (t < s + _JUMP_CYCLE + 1e-6)
        z = np.where(mine, np.where(t > a + 1e-6, np.where(t >= b - 1e-6, settle, ballistic), rise), z)
        # In the air the balls hang below the hips as at take-off, swinging to where they land
        # relative to the hips, and tucked by up to 12 cm at the apex.
        in_flight = (t > a + 1e-6) & (t < b - 1e-6)
        frac = np.clip(tau / flight, 0, 1)
        tuck = 0.12 * np.sin(np.pi * frac) ** 2
        for side, leg in legs.items():
            off = leg.ball[i_off] - [*pos[i_off, :2], z_off]
            land = off + np.append(swing, 0.0)
            rel[side][in_flight] = (off + _minjerk(frac)[:, None] * (land - off)
                                    + np.stack([0 * t, 0 * t, tuck], -1))[in_flight]
    spec.pelvis_pos[:, 2] = z
    for side, leg in legs.items():
        leg.ball = np.where(air[:, None], spec.pelvis_pos + rel[side], leg.ball)
    # Never ask a leg for more than it reaches (grounded frames only; the flight is fixed).
    zmax = np.minimum(_max_pelvis_height(spec, "L"), _max_pelvis_height(spec, "R"))
    spec.pelvis_pos[:, 2] = np.where(air, z, np.minimum(z, zmax - 0.005))


# ----------------------------------------------------------------------------- hop

_HOP_STANCE = 0.3  # s on the ground between hops
_HOP_HEEL = 25 * DEG  # the hopping foot's heel up from take-off to the last landing
_HOP_HOLD = np.array([-0.10, 0.0, 0.22])  # the free toe joint held back and up (m, from standing)
_HOP_TUCK = 0.05  # m, the hopping foot drawn up at the apex


def hop(side: str = "L", count: int = 2, flight: float = 0.25, distance: float = 0.0,
        direction: float = 0.0, name: str = "hop") -> RawMotion:
    """Hops on the `side` leg, the other foot held up behind: weight onto the hopping foot, lift
    the other, a dip, then `count` hops of `flight` s in the air each travelling `distance` m in
    the direction `direction` (rad, 0 = forward; the body keeps facing +x), landing on the ball
    of the foot; settle, put the free foot down beside it, weight back onto both feet.

    Between hops the stance lasts 0.3 s and the pelvis moves on at the hop's mean speed, its
    height a half sine that reverses the landing speed (a spring-mass stance); in the air it
    follows z'' = -g and carries on at that speed. The centre of mass is over the hopping foot
    while the body is still.

    count: 1-4. flight: 0.15-0.3 s (pelvis apex g flight^2 / 8 = 3-11 cm above take-off).
    distance: 0-0.4 m per hop. direction: -pi..pi.
    """
    side = _check_side("hop", side)
    count = _check_count("hop", count)
    flight = _check("hop", "flight", flight)
    distance = _check("hop", "distance", distance)
    direction = _check("hop", "direction", direction)
    free = _other(side)
    # Timeline (s): weight over by 1.1, free foot up by 1.5, dip from 1.6, hops, settle.
    t_dip = 1.6
    t_bottom, t_off = t_dip + 0.3, t_dip + 0.5
    t_offs = t_off + np.arange(count) * (flight + _HOP_STANCE)
    t_lands = t_offs + flight
    t_end = t_lands[-1]
    t_settled, t_still = t_end + 0.4, t_end + 0.7
    keys = [0.0, 0.5, 1.1, 1.5, t_still, t_still + 0.5, t_still + 1.1, t_still + 1.6]
    t = _time(keys[-1])
    n = len(t)
    legs = _standing_legs(t)
    on_hop = _keys(t, keys, [0.5, 0.5, 0.97, 0.97, 0.97, 0.97, 0.5, 0.5])
    weight_left = on_hop if side == "L" else 1 - on_hop
    up = _keys(t, keys, [0, 0, 0, 1, 1, 0, 0, 0])  # free foot: 0 down .. 1 held

    u = np.array([np.cos(direction), np.sin(direction), 0.0])
    speed = distance / (flight + _HOP_STANCE)  # mean horizontal speed while hopping
    half = speed * _HOP_STANCE / 2  # the pelvis passes over the foot at mid-stance
    # Pelvis travel along u: from rest at the dip's bottom to `speed` at the first take-off, then
    # steady (ballistic in the air), back to rest over the last footstep.
    travel = _hermite(t, [t_bottom, t_offs[0], t_end, t_settled],
                      [0.0, half, count * distance - half, count * distance], [0.0, speed, speed, 0.0])
    air = np.zeros(n, bool)
    landed = np.zeros(n)
    for a, b in zip(t_offs, t_lands):
        air |= (t > a + 1e-6) & (t < b - 1e-6)
        landed += t >= b - 1e-6
    h, f = legs[side], legs[free]
    home = h.ball.copy()
    h.ball = home + (landed * distance)[:, None] * u
    h.foot_pitch = _keys(t, [0, t_bottom, t_offs[0], t_end, t_end + 0.12, keys[-1]], [0, 0, _HOP_HEEL, _HOP_HEEL, 0, 0])
    h.grounded = ~air
    f.foot_pitch = 30 * DEG * up  # the held foot hangs, toes down
    f.toe_flat = 1 - up
    f.grounded = up <= 0
    free_home = f.ball.copy()
    moved = (t > 0.5 * (t_offs[0] + t_end))[:, None] * (count * distance) * u  # stance it returns to

    pelvis_pitch = np.full(n, 4 * DEG)
    angles = _upright_spine(t, pelvis_pitch, lean=3 * DEG)
    # Arms a little out for balance, swinging up with each take-off.
    spec = _Spec(t, np.zeros((n, 3)), _rot(0 * t, pelvis_pitch), legs,
                 {s: _arm(t, s, 10 * DEG, (12 + 20 * up) * DEG, (20 + 40 * up) * DEG) for s in SIDES}, angles)
    spec.pelvis_pos[:, :2] = moved[:, :2]
    target = _support_point(spec, weight_left)[:, :2]  # recomputed: the hopping foot moves
    still = (t <= t_dip + 1e-6) | (t >= t_settled - 1e-6)  # balanced statically
    i_dip = int(round(t_dip * FPS))
    vz = GRAVITY * flight / 2
    dip = vz * _HOP_STANCE / np.pi  # as deep as a stance between hops compresses

    def hold_free_foot():
        rest = spec.pelvis_pos[0] + moved  # where the pelvis stands on two feet
        f.ball = free_home + moved + up[:, None] * (spec.pelvis_pos - rest + _HOP_HOLD)

    def place_height():
        zh, zf = _max_pelvis_height(spec, side), _max_pelvis_height(spec, free)
        z_still = np.where(f.grounded, np.minimum(zh, zf), zh) - 0.02
        z1 = z_still[i_dip]  # standing on one leg
        contact = [int(round(x * FPS)) for x in np.concatenate([t_offs, t_lands])]
        z_off = np.min(zh[np.minimum(contact, n - 1)]) - 0.01  # heel up, knee nearly straight
        z = _hermite(t, [t_dip, t_bottom, t_offs[0]], [z1, z1 - dip, z_off], [0, 0, vz])
        for j, (a, b) in enumerate(zip(t_offs, t_lands)):
            tau = t - a
            z = np.where(t > a + 1e-6, z_off + vz * tau - 0.5 * GRAVITY * tau ** 2, z)
            if j + 1 < count:  # spring-mass stance to the next take-off
                tau = t - b
                z = np.where(t >= b - 1e-6, z_off - dip * np.sin(np.pi * tau / _HOP_STANCE), z)
        settle = _hermite(t, [t_end, t_settled, t_still], [z_off, z1 - dip, z1], [-vz, 0, 0])
        z = np.where(t >= t_end - 1e-6, settle, z)
        z = np.where(air, z, np.minimum(z, zh - 0.005))  # grounded frames within reach
        # Smooth the switch of height limit at the free foot's lift-off and touchdown.
        smooth = np.minimum(np.convolve(np.pad(z_still, 3, mode="edge"), np.ones(7) / 7, "valid"),
                            np.minimum(zh, np.where(f.grounded, zf, np.inf)) - 0.005)
        spec.pelvis_pos[:, 2] = np.where((t < t_dip + 1e-6) | (t > t_still - 1e-6), smooth, z)
        return z_off

    # With the heel up only the toe box bears weight: the body leans on over it (the whole body
    # but the foot moves, so the pelvis shifts about as far as the centre of mass has to).
    on_ball = h.foot_pitch / _HOP_HEEL
    toe_box = np.asarray(SKELETON.geoms[B[f"{side}_Toe"]].pos) * [1.0, 1.0, 0.0]
    to_ball = quat_apply(yaw_quat(h.foot_yaw[0]), toe_box - FOOT_CENTRE[side])[:2]
    for _ in range(6):
        hold_free_foot()
        place_height()
        target = _support_point(spec, weight_left)[:, :2]
        com = _centre_of_mass(spec.pelvis_pos, _solve(spec))[:, :2]
        spec.pelvis_pos[still, :2] += (target - com)[still]
        offset = spec.pelvis_pos[i_dip, :2] - home[i_dip, :2]  # pelvis over the hopping foot
        spec.pelvis_pos[~still, :2] = (home[:, :2] + offset + on_ball[:, None] * to_ball
                                       + travel[:, None] * u[:2])[~still]
    hold_free_foot()
    z_off = place_height()
    # The hopping foot in the air: below the hips as at take-off, swinging forward to where it
    # lands, drawn up a little at the apex.
    for a, b in zip(t_offs, t_lands):
        frac = np.clip((t - a) / flight, 0.0, 1.0)
        swing = (travel - half + 2 * half * _minjerk(frac))[:, None] * u
        lift = spec.pelvis_pos[:, 2] - z_off + _HOP_TUCK * np.sin(np.pi * frac) ** 2
        in_air = home + swing + lift[:, None] * [0.0, 0.0, 1.0]
        mine = (t > a + 1e-6) & (t < b - 1e-6)
        h.ball[mine] = in_air[mine]
    return _clip(name, spec, _solve(spec))


# ----------------------------------------------------------------------------- lunge

# Timeline (s): weight onto the back foot, step (a controlled fall onto the front foot), sink,
# hold, rise, step back (pushing off the front foot), weight to the middle, stand.
_LUNGE_KEYS = (0.0, 0.5, 1.1, 1.7, 2.7, 3.2, 4.2, 4.8, 5.4, 5.9)
_LUNGE_STEPS = ((1.1, 1.7), (4.2, 4.8))  # the front foot in the air; the body not balanced
_LUNGE_HEEL = 45 * DEG  # back heel raised at the bottom (the back foot on its ball)
_LUNGE_ARC = 0.06  # m, front toe joint's clearance at mid-swing


def lunge(side: str = "L", length: float = 0.7, depth: float = 0.2, name: str = "lunge") -> RawMotion:
    """A forward lunge onto the `side` foot: weight onto the back foot, the front foot steps
    `length` m forward on a low arc while the body falls forward onto it, the pelvis sinks until
    it is `depth` m below its standing height with the back heel rising onto the ball, holds,
    rises, and the front foot steps back beside the other; 5.9 s. While the feet are planted the
    centre of mass is balanced over the support (the front foot and the back foot's ball).

    length: 0.5-0.9 m. depth: 0.12-0.3 m, and at least `lunge_depth_min(length)` (the legs
    already straddle that low, however straight).
    """
    side = _check_side("lunge", side)
    length = _check("lunge", "length", length)
    lo = lunge_depth_min(length, side)
    depth = _check("lunge", "depth", depth, (max(lo, RANGES["lunge"]["depth"][0]), RANGES["lunge"]["depth"][1]))
    spec = _lunge_spec(side, length, depth)
    return _clip(name, spec, _solve(spec))


def lunge_depth_min(length: float, side: str = "L") -> float:
    """The smallest pelvis drop (m) of a lunge `length` m long: at the bottom both legs must
    reach the floor with their knees bent."""
    side = _check_side("lunge", side)
    length = _check("lunge", "length", length)
    t = np.array([0.0, 3.0])  # standing, and the middle of the hold
    spec = _lunge_spec(side, length, 0.0, t)
    return float(spec.pelvis_pos[0, 2] - spec.pelvis_pos[1, 2])


def _lunge_spec(side: str, length: float, depth: float, t=None) -> _Spec:
    """The lunge with its pelvis placed. At times `t` (default the clip's) that are all frames of
    planted feet it is solved frame by frame; depth 0 puts the pelvis as high as the legs allow."""
    back = _other(side)
    keys = np.array(_LUNGE_KEYS)
    t = _time(keys[-1]) if t is None else t
    n = len(t)
    legs = _standing_legs(t)
    f, b = legs[side], legs[back]
    step = _keys(t, keys, [0, 0, 0, 1, 1, 1, 1, 0, 0, 0])  # front foot: 0 home .. 1 forward
    f.ball = f.ball + np.stack([length * step, 0 * t, _LUNGE_ARC * np.sin(np.pi * step)], -1)
    f.grounded = (step <= 0) | (step >= 1)
    f.toe_flat = np.where(f.grounded, 1.0, 0.5)
    sink = _keys(t, keys, [0, 0, 0, 0, 1, 1, 0, 0, 0, 0])  # 0 upright .. 1 at the bottom
    b.foot_pitch = _LUNGE_HEEL * sink
    # Weight share of the front foot: off it for the step, caught at 45 %, then half and half.
    w_front = _keys(t, keys, [0.5, 0.5, 0.03, 0.45, 0.5, 0.5, 0.45, 0.03, 0.5, 0.5])
    # The pelvis tips back a little as it sinks, so the back hip need not extend past its range.
    pelvis_pitch = 4 * DEG - 10 * DEG * sink
    angles = _upright_spine(t, pelvis_pitch, lean=2 * DEG)
    arms = {s: _arm(t, s, 5 * DEG, 12 * DEG, 20 * DEG) for s in SIDES}
    spec = _Spec(t, np.zeros((n, 3)), _rot(0 * t, pelvis_pitch), legs, arms, angles, swing_knee=8 * DEG)
    spec.pelvis_pos[:, 0] = 0.5 * length * step  # start near the answer
    toe_box = np.asarray(SKELETON.geoms[B[f"{back}_Toe"]].pos) * [1.0, 1.0, 0.0]
    back_centre = FOOT_CENTRE[back] + (b.foot_pitch / _LUNGE_HEEL)[:, None] * (toe_box - FOOT_CENTRE[back])
    back_support = b.ball + quat_apply(yaw_quat(b.foot_yaw), back_centre)
    front_support = _support_point(spec, 1.0 if side == "L" else 0.0)
    target = (w_front[:, None] * front_support + (1 - w_front[:, None]) * back_support)[:, :2]
    planted = f.grounded
    windows = [(int(round(a * FPS)), int(round(c * FPS))) for a, c in _LUNGE_STEPS]
    for _ in range(5):
        _lunge_height(spec, side, back, sink, depth)
        com = _centre_of_mass(spec.pelvis_pos, _solve(spec))[:, :2]
        spec.pelvis_pos[planted, :2] += (target - com)[planted]
        for i0, i1 in windows:  # in the air: carried from one balanced pose to the next
            if i1 < n and not planted[i0 + 1 : i1].all():
                a, c = spec.pelvis_pos[i0, :2].copy(), spec.pelvis_pos[i1, :2].copy()
                s = _minjerk((t[i0:i1 + 1] - t[i0]) / (t[i1] - t[i0]))[:, None]
                spec.pelvis_pos[i0:i1 + 1, :2] = a + s * (c - a)
    _lunge_height(spec, side, back, sink, depth)
    return spec


def _lunge_height(spec: _Spec, side: str, back: str, sink, depth: float) -> None:
    """Pelvis height: standing height less `depth` times the sink, never higher than the legs
    reach their targets (the swinging foot's too, so it lands without the knee snapping); where
    the straddle alone brings it lower it follows that, rounded off."""
    reach = np.minimum(_max_pelvis_height(spec, side), _max_pelvis_height(spec, back)) - 0.02
    stand = reach[0]
    z = np.minimum(stand - depth * sink, reach)
    spec.pelvis_pos[:, 2] = _smooth_below(z) if len(z) > 5 else z
