"""The procedural motion machinery: clips described the way one would direct an actor, then
solved into joint rotations. The shipped clips (`synthetic`), the corpus' families
(`upper_body`, `whole_body`, `corpus`) and its locomotion all build on it.

A clip is described by
* a pelvis trajectory (position and yaw / pitch / roll),
* for each leg the world target of the ball of the foot (the toe joint) plus the foot's yaw and
  pitch; a closed-form two-bone IK turns that into hip, knee, ankle and toe rotations, so a
  planted foot is *exactly* still and its sole *exactly* on z = 0 (no sliding, no penetration),
* for each arm the directions of upper arm and forearm in the chest frame (a "look-at" solve that
  bends the elbow only about its flexion hinge),
* spine, neck and head hinge angles.

Physical sense is built in rather than checked afterwards: the pelvis height of a grounded clip is
the highest that keeps the knees slightly bent (so the legs always reach the floor), airborne
phases follow the ballistic parabola z'' = -g and join the stance phases with matching velocity,
and quasi-static motion shifts the pelvis so that the whole-body centre of mass stays over the
support foot / feet (`_balanced`). `_locomotion` walks and runs along a path with speed,
yaw-rate, travel-direction, activity (standing to stepping) and cadence profiles.

Sign conventions of the body frames (x forward, y left, z up), measured with forward kinematics:
hip flexion is a negative y rotation, knee flexion positive y, ankle plantar flexion (toes down)
positive y; a positive pelvis pitch leans forward, a positive roll tilts to the right; the left
elbow flexes about -z, the right about +z.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.interpolate import CubicHermiteSpline

from ..humanoid.skeleton import MEAN_SKELETON, NUM_BODIES
from ..rotations import (
    quat_apply, quat_from_euler_xyz, quat_from_matrix, quat_from_rotvec, quat_inv, quat_mul,
    quat_to_matrix, yaw_quat,
)
from ..humanoid.kinematics import forward_kinematics
from .motion import FPS, RawMotion
from .plausibility import GRAVITY, centre_of_mass

DEG = np.pi / 180.0

SKELETON = MEAN_SKELETON
OFFSETS = SKELETON.offsets
B = {name: i for i, name in enumerate((
    "Pelvis", "L_Hip", "L_Knee", "L_Ankle", "L_Toe", "R_Hip", "R_Knee", "R_Ankle", "R_Toe",
    "Torso", "Spine", "Chest", "Neck", "Head", "L_Thorax", "L_Shoulder", "L_Elbow", "L_Wrist",
    "L_Hand", "R_Thorax", "R_Shoulder", "R_Elbow", "R_Wrist", "R_Hand"))}
SIDES = {"L": 1.0, "R": -1.0}  # sign of the body's left axis for each side


def _sole_depth(body: int) -> float:
    """How far below its joint the lowest point of a body's geometry lies in the rest pose."""
    points, radii = SKELETON.support_points()
    return float(-(points[body, :, 2] - radii[body]).min())


# Height of the toe joint above the floor when the toe box lies flat on it.
BALL_HEIGHT = {s: _sole_depth(B[f"{s}_Toe"]) for s in SIDES}
# Centre of the foot's support (between heel box and toe box centres) relative to the toe joint,
# in the foot's rest frame: the point the centre of mass is balanced over.
FOOT_CENTRE = {
    s: 0.5 * (np.asarray(SKELETON.geoms[B[f"{s}_Ankle"]].pos) - OFFSETS[B[f"{s}_Toe"]]
              + np.asarray(SKELETON.geoms[B[f"{s}_Toe"]].pos)) * np.array([1.0, 1.0, 0.0])
    for s in SIDES
}


# ----------------------------------------------------------------------------- small helpers

def check_number(family: str, name: str, value, bounds: tuple[float, float]) -> float:
    """`value` as a float, or a ValueError naming the family, the parameter and its range."""
    lo, hi = bounds
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{family}: {name} must be a number, got {value!r}") from None
    if not np.isfinite(x) or not lo - 1e-9 <= x <= hi + 1e-9:
        raise ValueError(f"{family}: {name} = {value!r} is outside [{lo:.4g}, {hi:.4g}]")
    return x


def _time(duration: float) -> np.ndarray:
    return np.arange(int(round(duration * FPS)) + 1) / FPS


def _minjerk(x):
    """0 -> 1 with zero velocity and acceleration at both ends (the minimum-jerk profile)."""
    x = np.clip(x, 0.0, 1.0)
    return x ** 3 * (10.0 - 15.0 * x + 6.0 * x ** 2)


def _keys(t, times, values):
    """Piecewise minimum-jerk interpolation through keyframes (values may be (K,) or (K, D)):
    every key is reached at rest, which is how deliberate postural movements look."""
    t, times, values = np.asarray(t, float), np.asarray(times, float), np.asarray(values, float)
    i = np.clip(np.searchsorted(times, t, side="right") - 1, 0, len(times) - 2)
    s = _minjerk((t - times[i]) / (times[i + 1] - times[i]))
    s = s.reshape(s.shape + (1,) * (values.ndim - 1))
    return values[i] + s * (values[i + 1] - values[i])


def _hermite(t, times, values, slopes):
    """Cubic Hermite interpolation (C1), held constant outside the key range."""
    spline = CubicHermiteSpline(times, values, slopes)
    return spline(np.clip(t, times[0], times[-1]))


def _axis_quat(axis: int, angle) -> np.ndarray:
    angle = np.asarray(angle, float)
    q = np.zeros(angle.shape + (4,))
    q[..., 0] = np.cos(angle / 2)
    q[..., 1 + axis] = np.sin(angle / 2)
    return q


def _normalize(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _frame(a, b):
    """Rotation matrices (..., 3, 3) with columns (a, b orthogonalised against a, a x b)."""
    a = _normalize(a)
    b = _normalize(b - np.sum(a * b, -1, keepdims=True) * a)
    return np.stack([a, b, np.cross(a, b)], -1)


def _arm_dir(flex, abduct, side):
    """Unit direction from hanging straight down: `flex` swings it forward in the sagittal plane,
    `abduct` lifts it out sideways (to the body's left for side +1)."""
    flex, abduct = np.broadcast_arrays(np.asarray(flex, float), np.asarray(abduct, float))
    return np.stack([np.sin(flex) * np.cos(abduct), side * np.sin(abduct),
                     -np.cos(flex) * np.cos(abduct)], -1)


def _arm(t, side, flex, abduct, elbow, twist=0.0):
    """Arm posture per frame: upper arm along _arm_dir(flex, abduct) in the chest frame, elbow
    flexion `elbow`, and `twist` (external rotation of the upper arm, positive turns the forearm
    from forward towards up for an arm held out sideways)."""
    b = lambda v: np.broadcast_to(np.asarray(v, float), t.shape)
    return _arm_dir(b(flex), b(abduct), SIDES[side]), b(elbow), b(twist)


def _rot(yaw, pitch=0.0, roll=0.0):
    """World orientation: yaw about z, then pitch about the turned y, then roll about x."""
    yaw, pitch, roll = np.broadcast_arrays(*(np.asarray(a, float) for a in (yaw, pitch, roll)))
    return quat_mul(quat_mul(yaw_quat(yaw), _axis_quat(1, pitch)), _axis_quat(0, roll))


# ----------------------------------------------------------------------------- the clip description

@dataclass
class _Leg:
    """Targets of one leg per frame. `ball` is the world position of the toe joint; the foot
    (ankle body) has world orientation yaw(foot_yaw) * pitch(foot_pitch), positive pitch raising
    the heel; `toe_flat` in [0, 1] keeps the toe segment level with the floor (1) or lets it follow
    the foot (0)."""

    ball: np.ndarray
    foot_yaw: np.ndarray
    foot_pitch: np.ndarray
    toe_flat: np.ndarray
    grounded: np.ndarray  # bool: the ball is on the floor this frame


@dataclass
class _Spec:
    """Everything that defines a clip before it is solved into local rotations."""

    t: np.ndarray
    pelvis_pos: np.ndarray  # (T, 3)
    pelvis_quat: np.ndarray  # (T, 4)
    legs: dict[str, _Leg]
    arms: dict[str, tuple]  # per side: upper-arm direction (chest frame), elbow flexion, twist
    angles: np.ndarray = field(default=None)  # (T, 24, 3) hinge angles of the remaining bodies
    # Knee bend below which a leg whose foot is in the air is not straightened: its foot target is
    # pulled in smoothly instead (None: targets are always reached exactly).
    swing_knee: float | None = None

    def __post_init__(self):
        if self.angles is None:
            self.angles = np.zeros((len(self.t), NUM_BODIES, 3))


def _foot_quat(leg: _Leg) -> np.ndarray:
    return _rot(leg.foot_yaw, leg.foot_pitch)


def _ankle_target(leg: _Leg, side: str) -> np.ndarray:
    return leg.ball - quat_apply(_foot_quat(leg), OFFSETS[B[f"{side}_Toe"]])


def _hip_pos(spec: _Spec, side: str) -> np.ndarray:
    return spec.pelvis_pos + quat_apply(spec.pelvis_quat, OFFSETS[B[f"{side}_Hip"]])


def _knee_terms(side: str):
    """|a + Ry(k) b|^2 = c0 + 2 r cos(k - phi) for thigh a and shank b: the leg length as a
    function of knee flexion k, which the IK inverts in closed form."""
    a, b = OFFSETS[B[f"{side}_Knee"]], OFFSETS[B[f"{side}_Ankle"]]
    c0 = a @ a + b @ b + 2 * a[1] * b[1]
    p, q = a[0] * b[0] + a[2] * b[2], a[0] * b[2] - a[2] * b[0]
    return a, b, c0, np.hypot(p, q), np.arctan2(q, p)


def _leg_length(side: str, knee) -> np.ndarray:
    _, _, c0, r, phi = _knee_terms(side)
    return np.sqrt(c0 + 2 * r * np.cos(np.asarray(knee) - phi))


MIN_KNEE = 4 * DEG  # the straightest knee the IK is asked for: a locked knee is a singularity


def _max_pelvis_height(spec: _Spec, side: str, min_knee: float = MIN_KNEE) -> np.ndarray:
    """Highest pelvis z per frame at which this leg still reaches its ankle target with the knee
    bent at least `min_knee` (pelvis xy and orientation as in `spec`)."""
    hip_off = quat_apply(spec.pelvis_quat, OFFSETS[B[f"{side}_Hip"]])
    d = _ankle_target(spec.legs[side], side) - (spec.pelvis_pos * [1, 1, 0] + hip_off)
    reach = _leg_length(side, min_knee)
    return d[:, 2] + np.sqrt(np.maximum(reach ** 2 - d[:, 0] ** 2 - d[:, 1] ** 2, 0.0))


def _solve_leg(spec: _Spec, side: str, local: np.ndarray) -> None:
    """Closed-form IK: writes hip, knee, ankle and toe local rotations into `local`."""
    leg = spec.legs[side]
    hip, knee, ankle, toe = (B[f"{side}_{n}"] for n in ("Hip", "Knee", "Ankle", "Toe"))
    a, b, c0, r, phi = _knee_terms(side)
    d = _ankle_target(leg, side) - _hip_pos(spec, side)
    if spec.swing_knee is not None:
        # Soft-limit the reach of airborne feet (softplus, 1 cm wide) so a swing leg reaching
        # for a far target bends less instead of locking straight and then snapping at landing.
        dist = np.linalg.norm(d, axis=-1)
        d_max = _leg_length(side, spec.swing_knee)
        soft = d_max - 0.01 * np.logaddexp(0.0, (d_max - dist) / 0.01)
        d = d * np.where(leg.grounded, 1.0, np.minimum(soft / dist, 1.0))[:, None]
    dist2 = np.sum(d * d, -1)
    cos_arg = np.clip((dist2 - c0) / (2 * r), -1.0, np.cos(0.0 - phi))  # never hyperextend
    k = phi + np.arccos(cos_arg)
    leg_rest = a + quat_apply(_axis_quat(1, k), b)  # hip -> ankle in the hip's rest frame
    # The knee's hinge (hip-frame y) should point to the foot's left so the knee bends forwards.
    knee_axis = quat_apply(yaw_quat(leg.foot_yaw), [0.0, 1.0, 0.0])
    hip_world = _frame(d, knee_axis) @ np.swapaxes(_frame(leg_rest, np.array([0.0, 1.0, 0.0])), -1, -2)
    pelvis_m = quat_to_matrix(spec.pelvis_quat)
    local[:, hip] = quat_from_matrix(np.swapaxes(pelvis_m, -1, -2) @ hip_world)
    local[:, knee] = _axis_quat(1, k)
    shank_world = quat_mul(quat_from_matrix(hip_world), local[:, knee])
    local[:, ankle] = quat_mul(quat_inv(shank_world), _foot_quat(leg))
    local[:, toe] = _axis_quat(1, -leg.foot_pitch * leg.toe_flat)


def _solve_arm(side: str, chest_q, thorax_q, upper, elbow, twist, local: np.ndarray) -> None:
    """Shoulder and elbow rotations that point the upper arm along `upper` (chest frame) and bend
    the elbow by `elbow` about its flexion hinge (z), the arm twisted by `twist`."""
    s = SIDES[side]
    sh, el, wr = (B[f"{side}_{n}"] for n in ("Shoulder", "Elbow", "Wrist"))
    # The elbow's hinge axis where the arm hangs relaxed: the body's left for a hanging or
    # forward arm, up for an arm held out sideways (T-pose), the body's right overhead; this
    # blend of (forward x arm) and (left, orthogonal to the arm) never vanishes on those paths.
    y_perp = np.array([0.0, 1.0, 0.0]) - upper[..., 1:2] * upper
    axis = s * (np.cross([1.0, 0.0, 0.0], upper) + 0.5 * y_perp)
    axis = quat_apply(quat_from_rotvec(-s * twist[:, None] * upper), _normalize(axis))
    # The left elbow flexes about -z, the right about +z (measured with forward kinematics).
    fore = quat_apply(quat_from_rotvec(-s * elbow[:, None] * axis), upper)
    u, f, axis = (quat_apply(chest_q, v) for v in (upper, fore, axis))
    shoulder_world = _frame(u, axis) @ np.swapaxes(
        _frame(np.broadcast_to(OFFSETS[el], u.shape), np.array([0.0, 0.0, 1.0])), -1, -2)
    local[:, sh] = quat_from_matrix(np.swapaxes(quat_to_matrix(thorax_q), -1, -2) @ shoulder_world)
    f_sh = np.einsum("tji,tj->ti", shoulder_world, f)  # forearm direction in the shoulder frame
    w = OFFSETS[wr]
    gamma = np.arctan2(f_sh[:, 1], f_sh[:, 0]) - np.arctan2(w[1], w[0])
    local[:, el] = _axis_quat(2, (gamma + np.pi) % (2 * np.pi) - np.pi)


def _solve(spec: _Spec) -> np.ndarray:
    """Local rotations (T, 24, 4) realising the spec."""
    local = quat_from_euler_xyz(spec.angles)
    local[:, 0] = spec.pelvis_quat
    for side in SIDES:
        _solve_leg(spec, side, local)
    _, body_quat = forward_kinematics(spec.pelvis_pos, local, OFFSETS)
    for side in SIDES:
        _solve_arm(side, body_quat[:, B["Chest"]], body_quat[:, B[f"{side}_Thorax"]], *spec.arms[side], local)
    return local


def _centre_of_mass(root_pos, local) -> np.ndarray:
    return centre_of_mass(*forward_kinematics(root_pos, local, OFFSETS), SKELETON)


def _support_point(spec: _Spec, weight_left) -> np.ndarray:
    """Floor point under the feet, blended between the foot centres by `weight_left`."""
    pts = {s: spec.legs[s].ball + quat_apply(yaw_quat(spec.legs[s].foot_yaw), FOOT_CENTRE[s])
           for s in SIDES}
    w = np.asarray(weight_left, float)[..., None]
    return w * pts["L"] + (1 - w) * pts["R"]


def _smooth_below(z: np.ndarray, radius: int = 2, sigma: float = 0.8) -> np.ndarray:
    """A smooth curve that never exceeds z: a running minimum over +-radius frames, then a
    Gaussian truncated at the same radius (each average only mixes values below z there)."""
    pad = np.pad(z, radius, mode="edge")
    window = np.lib.stride_tricks.sliding_window_view(pad, 2 * radius + 1)
    taps = np.exp(-0.5 * (np.arange(-radius, radius + 1) / sigma) ** 2)
    eroded = np.pad(window.min(-1), radius, mode="edge")
    return np.lib.stride_tricks.sliding_window_view(eroded, 2 * radius + 1) @ (taps / taps.sum())


def _fit_height(spec: _Spec, drop) -> None:
    """Pelvis as high as both legs allow, lowered by `drop` (>= 0, per frame): the legs are then
    guaranteed to reach their targets with bent knees."""
    zmax = np.minimum(_max_pelvis_height(spec, "L"), _max_pelvis_height(spec, "R"))
    spec.pelvis_pos[:, 2] = zmax - drop


def _balanced(spec: _Spec, weight_left, drop, iterations: int = 4) -> np.ndarray:
    """Shift the pelvis horizontally until the centre of mass is over the support point (the
    static-balance condition a slow motion has to meet), refitting the height each time."""
    target = _support_point(spec, weight_left)[:, :2]
    for _ in range(iterations):
        _fit_height(spec, drop)
        local = _solve(spec)
        com = _centre_of_mass(spec.pelvis_pos, local)
        spec.pelvis_pos[:, :2] += target - com[:, :2]
    _fit_height(spec, drop)
    return _solve(spec)


def _upright_spine(t, pelvis_pitch, pelvis_roll=0.0, pelvis_yaw=0.0, lean=0.0, twist=0.0):
    """Hinge angles (T, 24, 3) of torso, spine, chest, neck and head that give the chest a world
    lean `lean` (forward positive) and yaw `twist` relative to the heading, and keep the head level
    and looking along the heading."""
    angles = np.zeros((len(t), NUM_BODIES, 3))
    pitch = np.broadcast_to(lean - np.asarray(pelvis_pitch), t.shape)
    roll = np.broadcast_to(-np.asarray(pelvis_roll), t.shape)
    yaw = np.broadcast_to(twist - np.asarray(pelvis_yaw), t.shape)
    for body, share in (("Torso", 0.4), ("Spine", 0.35), ("Chest", 0.25)):
        angles[:, B[body]] = np.stack([share * roll, share * pitch, share * yaw], -1)
    for body, share in (("Neck", 0.6), ("Head", 0.4)):
        angles[:, B[body]] = np.stack([0 * t, -share * np.broadcast_to(lean, t.shape),
                                       -share * np.broadcast_to(twist, t.shape)], -1)
    return angles


def _relaxed_arms(t, flex=0.0, abduct=10 * DEG, elbow=15 * DEG):
    """Arms hanging at the sides with a natural elbow bend."""
    return {side: _arm(t, side, flex, abduct, elbow) for side in SIDES}


def _standing_legs(t, width=0.1, toe_out=6 * DEG, x=0.0) -> dict[str, _Leg]:
    """Both feet flat and still, the toe joints `width` either side of the centre line."""
    legs = {}
    for side, s in SIDES.items():
        ball = np.tile([x + OFFSETS[B[f"{side}_Toe"]][0] - 0.05, s * width, BALL_HEIGHT[side]], (len(t), 1))
        legs[side] = _Leg(ball, np.full(len(t), s * toe_out), np.zeros(len(t)), np.ones(len(t)),
                          np.ones(len(t), bool))
    return legs


def _raw(name: str, spec: _Spec, local: np.ndarray) -> RawMotion:
    return RawMotion(name, FPS, spec.pelvis_pos.copy(), local, source="smpl_envs.motion.synthetic")


# ----------------------------------------------------------------------------- locomotion

@dataclass
class _Gait:
    stride: float  # s, one full cycle (two steps)
    duty: float  # fraction of the stride a foot is on the ground
    width: float  # lateral distance of each toe joint from the path
    ball_ahead: float  # toe joint ahead of the pelvis at mid-stance
    swing_height: float  # lift of the toe joint in swing
    swing_peak: float  # when in the swing the lift peaks (0..1)
    foot_pitch_keys: tuple  # (phase, pitch) keys over the stride, phase 0 = touchdown
    toe_release: float  # phase after lift-off by which the toe stops being held level
    pelvis_pitch: float
    lean: float  # chest lean
    yaw_swing: float  # pelvis rotation amplitude
    roll_swing: float
    sway: float  # lateral pelvis shift toward the stance foot
    arm_swing: float
    arm_flex: float
    elbow: float
    elbow_swing: float
    flight: bool
    liftoff_speed: float  # vertical speed of the toe joint as it leaves the floor (m/s)
    landing_speed: float  # vertical speed of the foot at touchdown (m/s)
    swing_land: float  # fraction of the swing after which the foot only descends
    landing_height: float  # height of the toe joint above its footstep at that moment
    bob: float = 0.0  # walk: amplitude of the pelvis' vertical oscillation
    stance_knee: float = MIN_KNEE  # run: the straightest knee on the ground (at touchdown)


def _path(t_fine, speed, yaw_rate, travel=0.0):
    """Integrate heading and position on a fine grid (xy (N, 2), heading (N,)); the body moves at
    `travel` radians from its heading (0 forwards, pi/2 a side step to the left, pi backwards)."""
    dt = t_fine[1] - t_fine[0]
    yaw = np.concatenate([[0.0], np.cumsum(0.5 * (yaw_rate[1:] + yaw_rate[:-1]) * dt)])
    vel = speed[:, None] * np.stack([np.cos(yaw + travel), np.sin(yaw + travel)], -1)
    xy = np.concatenate([[[0.0, 0.0]], np.cumsum(0.5 * (vel[1:] + vel[:-1]) * dt, 0)])
    return xy, yaw


def _as_profile(value):
    """A profile over time: a callable t -> array, or a constant."""
    return value if callable(value) else (lambda t, v=float(value): np.full(np.shape(t), v))


def _running_min_smooth(z: np.ndarray, radius: int) -> np.ndarray:
    """A smooth curve never above z: the minimum over +-radius frames, then averaged over the same
    window (each average mixes values that are below z there). With a radius as long as the
    clip it is z's global minimum."""
    if radius >= len(z):
        return np.full_like(z, z.min())
    pad = np.pad(z, radius, mode="edge")
    eroded = np.pad(np.lib.stride_tricks.sliding_window_view(pad, 2 * radius + 1).min(-1), radius, mode="edge")
    return np.lib.stride_tricks.sliding_window_view(eroded, 2 * radius + 1).mean(-1)


def _locomotion(name, duration, gait: _Gait, speed, yaw_rate=lambda t: 0 * t, travel=0.0,
                activity=1.0, arm_pose=None, stride=None) -> RawMotion:
    """Walking or running (`gait.flight`) along a path. `speed` (m/s), `yaw_rate` (rad/s),
    `travel` (direction of motion relative to the heading, rad) and `activity` (1 stepping,
    0 standing with both feet planted: gait amplitudes scale with it, so a clip can start from
    standing and stop) are constants or callables of time. `arm_pose(t, side, flex, abduct,
    elbow)` may replace the swinging arms' (flex, abduct, elbow, twist), for a gesture while
    walking. `stride` (s per gait cycle, a callable of time; walking only) lets the cadence
    change with the speed, as people's does; by default it is `gait.stride` throughout."""
    if stride is not None and gait.flight:
        raise ValueError("a varying stride is for walking: a run's flights assume a steady cadence")
    speed, travel, activity = _as_profile(speed), _as_profile(travel), _as_profile(activity)
    t = _time(duration)
    n = len(t)
    # Path on a fine grid reaching a stride beyond both ends so every footstep is defined.
    t_fine = np.arange(-2 * gait.stride, duration + 2 * gait.stride, 1e-3)
    xy_fine, yaw_fine = _path(t_fine, speed(t_fine), yaw_rate(t_fine), travel(t_fine))
    i0 = np.searchsorted(t_fine, 0.0)
    xy_fine, yaw_fine = xy_fine - xy_fine[i0], yaw_fine - yaw_fine[i0]  # start at the origin
    at = lambda tq: (np.stack([np.interp(tq, t_fine, xy_fine[:, 0]), np.interp(tq, t_fine, xy_fine[:, 1])], -1),
                     np.interp(tq, t_fine, yaw_fine))
    path_xy, heading = at(t)
    # Gait phase (cycles since t = 0) and its inverse; exact when the cadence is constant.
    if stride is None:
        cycles, time_at = (lambda tq: tq / gait.stride), (lambda p: p * gait.stride)
        stride_t = np.full(n, gait.stride)
    else:
        phi = np.concatenate([[0.0], np.cumsum(0.5 * (1 / stride(t_fine[1:]) + 1 / stride(t_fine[:-1])) * 1e-3)])
        phi -= np.interp(0.0, t_fine, phi)
        cycles, time_at = (lambda tq: np.interp(tq, t_fine, phi)), (lambda p: np.interp(p, phi, t_fine))
        stride_t = stride(t)
    act = np.clip(activity(t), 0.0, 1.0)
    # Heel-and-toe roll belongs to forward walking; stepping sideways or backwards rolls less.
    roll_over = act * (0.3 + 0.7 * np.maximum(np.cos(travel(t)), 0.0))
    stance = gait.duty * gait.stride
    first_td = {"L": 0.1, "R": 0.6}  # cycles at the first touchdowns: begin mid-gait
    legs, phase_of = {}, {}
    for side, s in SIDES.items():
        k = np.floor(cycles(t) - first_td[side])  # index of the last touchdown
        phase = cycles(t) - first_td[side] - k
        phase_of[side] = phase
        # Footsteps: the toe joint `ball_ahead` in front of the pelvis and `width` to the side at
        # the middle of the stance, turned with the heading of that moment.
        def step(kk):
            mid = time_at(first_td[side] + kk + 0.5 * gait.duty)
            p_xy, yaw = at(mid)
            off = np.stack([gait.ball_ahead * np.cos(yaw) - s * gait.width * np.sin(yaw),
                            gait.ball_ahead * np.sin(yaw) + s * gait.width * np.cos(yaw)], -1)
            return p_xy + off, yaw + s * 5 * DEG
        (xy0, yaw0), (xy1, yaw1) = step(k), step(k + 1)
        swing = np.clip((phase - gait.duty) / (1 - gait.duty), 0.0, 1.0)
        # Horizontal travel is over by `swing_land` of the swing: the foot then comes straight
        # down, so it never brushes the floor while moving.
        arrive = np.clip(swing / gait.swing_land, 0.0, 1.0)
        sw = (arrive * arrive * (3 - 2 * arrive))[:, None]
        ball = np.zeros((n, 3))
        ball[:, :2] = xy0 + sw * (xy1 - xy0)
        # The foot is still a few cm up when it is over its footstep and comes down with some
        # speed (as feet do): a foot that arrived at rest would hover just above the floor, far
        # in front of the hips, for the whole approach, and the legs could not reach it.
        t_sw = (1 - gait.duty) * stride_t
        # (Hermite interpolation is linear in its values and slopes: the slopes, speeds times the
        # swing's duration, enter per frame.)
        keys = [0, gait.swing_peak, gait.swing_land, 1]
        lift = (_hermite(swing, keys, [0, gait.swing_height, gait.landing_height, 0], [0, 0, 0, 0])
                + t_sw * _hermite(swing, keys, [0, 0, 0, 0],
                                  [gait.liftoff_speed, 0, -gait.landing_speed, -gait.landing_speed]))
        ball[:, 2] = BALL_HEIGHT[side] + act * lift
        kp, kv = np.array(gait.foot_pitch_keys).T
        pitch = roll_over * _keys(phase, kp, kv)
        release = np.clip((phase - gait.duty) / gait.toe_release, 0, 1)
        regrip = np.clip((phase - 0.9) / 0.1, 0, 1)
        toe_flat = 1 - act * (_minjerk(release) - _minjerk(regrip))
        legs[side] = _Leg(ball, yaw0 + sw[:, 0] * (yaw1 - yaw0), pitch, toe_flat, phase < gait.duty)

    # Pelvis: rotates with the forward leg, sways and rolls over the stance foot.
    cyc = 2 * np.pi * (cycles(t) - first_td["L"])  # 0 at left touchdown
    mid_cyc = cyc - np.pi * gait.duty  # 0 at left mid-stance
    yaw_osc = -act * gait.yaw_swing * np.cos(cyc)  # left hip forward (negative yaw) at left touchdown
    roll = act * gait.roll_swing * np.cos(mid_cyc)  # swing side (right) drops during left stance
    lean_in = -np.arctan(speed(t) * yaw_rate(t) / GRAVITY)  # bank into the curve
    # Slow steps shift the weight fully onto the stance foot (its centre of mass must be over it
    # for longer); at walking speeds from 1 m/s the gait's own small sway is enough.
    slow = np.clip(1.0 - speed(t), 0.0, 1.0)
    sway = act * (gait.sway + slow * max(gait.width - gait.sway, 0.0)) * np.cos(mid_cyc)
    pos = np.zeros((n, 3))
    pos[:, :2] = path_xy + sway[:, None] * np.stack([-np.sin(heading), np.cos(heading)], -1)
    quat = _rot(heading + yaw_osc, gait.pelvis_pitch, roll + lean_in)
    angles = _upright_spine(t, gait.pelvis_pitch, roll + lean_in, yaw_osc, gait.lean, -0.5 * yaw_osc)
    arms = {}
    for side, s in SIDES.items():
        # Each arm swings with the opposite leg: back when its own leg is forward.
        swing_fwd = -act * np.cos(2 * np.pi * phase_of[side])
        flex = gait.arm_flex + gait.arm_swing * swing_fwd
        elbow = gait.elbow + gait.elbow_swing * 0.5 * (1 + swing_fwd)
        pose = (flex, 10 * DEG, elbow) if arm_pose is None else arm_pose(t, side, flex, 10 * DEG, elbow)
        arms[side] = _arm(t, side, *pose)
    spec = _Spec(t, pos, quat, legs, arms, angles)

    # Every frame bounds the height, swing included: a leg that could not reach its target would
    # snap straight and bend again around touchdown.
    if gait.flight:
        spec.swing_knee = 8 * DEG
        zmax = np.minimum(*(np.where(legs[s].grounded, _max_pelvis_height(spec, s, gait.stance_knee), np.inf)
                            for s in SIDES))
    else:
        zmax = np.minimum(_max_pelvis_height(spec, "L"), _max_pelvis_height(spec, "R"))
    # A steady gait keeps one height (the lowest the legs need over the clip); a changing one
    # follows the lowest over each stride, smoothly, so a slow stretch is not crouched.
    steady = np.ptp(speed(t_fine)) == 0 and np.all(act == 1.0)
    radius = n if steady else int(round(np.mean(stride_t) * FPS))
    if gait.flight:
        # Spring-mass stance joined C1 to ballistic flights: flight lasts t_f, leaves and lands at
        # vertical speed v = g t_f / 2; a half sine in stance reverses that velocity.
        t_f = gait.stride / 2 - stance
        v = GRAVITY * t_f / 2
        tau = np.mod(t - first_td["L"] * gait.stride, gait.stride / 2)  # time since the last touchdown
        shape = np.where(tau < stance, -(v * stance / np.pi) * np.sin(np.pi * tau / stance),
                         v * (tau - stance) - 0.5 * GRAVITY * (tau - stance) ** 2)
        # Only stance frames bound the height here: in the air a swing foot that the leg cannot
        # quite reach just stays a little higher.
        grounded = legs["L"].grounded | legs["R"].grounded
        bound = np.where(grounded, zmax - shape, np.inf)
        if steady:
            base = np.min(bound)
        else:  # flight frames take the bound of the stance around them
            bound = np.interp(t, t[grounded], bound[grounded])
            base = _running_min_smooth(bound, radius)
        spec.pelvis_pos[:, 2] = base - 0.002 + shape
    else:
        # Walking: the pelvis vaults over each stance leg like an inverted pendulum (highest at
        # mid-stance), as high as the legs allow.
        shape = act * gait.bob * np.cos(2 * mid_cyc)
        spec.pelvis_pos[:, 2] = _running_min_smooth(zmax - shape, radius) - 0.002 + shape
    return _raw(name, spec, _solve(spec))


WALK = _Gait(
    stride=1.0, duty=0.61, width=0.075, ball_ahead=0.0, swing_height=0.07, swing_peak=0.35,
    foot_pitch_keys=((0, 0), (0.25, 0), (0.61, 50 * DEG), (0.72, 20 * DEG), (0.88, -5 * DEG), (1, 0)),
    toe_release=0.2, pelvis_pitch=6 * DEG, lean=3 * DEG, yaw_swing=5 * DEG, roll_swing=3 * DEG,
    sway=0.02, arm_swing=17 * DEG, arm_flex=3 * DEG, elbow=18 * DEG, elbow_swing=12 * DEG,
    flight=False, liftoff_speed=0.3, landing_speed=0.5, swing_land=0.85, landing_height=0.045, bob=0.03,
)
RUN = _Gait(
    stride=0.64, duty=0.28, width=0.05, ball_ahead=0.12, swing_height=0.10, swing_peak=0.4,
    foot_pitch_keys=((0, 0), (0.1, 0), (0.28, 30 * DEG), (0.4, 35 * DEG), (0.7, 0),
                     (0.88, -10 * DEG), (1, 0)),
    toe_release=0.12, pelvis_pitch=9 * DEG, lean=10 * DEG, yaw_swing=6 * DEG, roll_swing=3 * DEG,
    sway=0.01, arm_swing=32 * DEG, arm_flex=8 * DEG, elbow=80 * DEG, elbow_swing=15 * DEG,
    flight=True, stance_knee=12 * DEG, liftoff_speed=0.8, landing_speed=0.6, swing_land=0.85,
    landing_height=0.09,
)
