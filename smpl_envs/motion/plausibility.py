"""Physical plausibility of a motion clip: is it something a body could do on flat ground?

`check_motion(raw)` measures a clip against the following checks (batched numpy over frames, a
few milliseconds for a 10 s clip) and returns a `PlausibilityReport` with the figures and a
readable list of violations. The tolerances are module constants:

* **Floor**: the lowest point of the body's collision geometry is never below -FLOOR_TOLERANCE
  (1 cm).
* **Planted feet**: a foot-box corner below CONTACT_HEIGHT (1 cm) in two consecutive frames is in
  contact; the mean horizontal speed of a foot's contacting corners is below MAX_SLIDE_SPEED
  (5 cm/s). Corners of a rolling foot (heel rising, toes lifting) move a little; a sliding foot
  moves them all.
* **Flight**: frames whose lowest point is above CONTACT_HEIGHT are airborne. With
  `allow_flight=False` any such frame is floating. Otherwise every airborne frame whose
  neighbours are airborne too must be ballistic: the pelvis' vertical second difference within
  FLIGHT_ACC_TOLERANCE (0.3 m/s^2) of -GRAVITY and its horizontal one below
  MAX_FLIGHT_ACC_XY (0.5 m/s^2). A body hovering above the floor fails this (z'' = 0); an
  airborne phase of one or two frames has no such frame and is not judged.
* **Joint ranges**: every joint's local rotation is within LIMIT_MARGIN (3 degrees of rotation)
  of one its x-y-z hinges reach inside `anatomical_limits()`. Where the hinge angles as
  `Motion.from_raw(raw).dof_pos` decomposes them are in range this is zero; near gimbal lock
  (a hip flexed ~90 degrees, whose abduction and twist axes then nearly coincide) that
  decomposition can put one hinge out of range while an in-range split of the same rotation
  exists, so the distance is searched for. The excursion of the decomposition is reported too.
* **Static balance**: in quasi-static frames (on the ground, horizontal centre-of-mass speed below
  QUASI_STATIC_SPEED, 0.15 m/s, and acceleration below QUASI_STATIC_ACC, 0.3 m/s^2, so that
  inertia shifts the centre of pressure by at most ~3 cm) the centre of mass projects inside the
  convex hull of the contacting support points expanded by SUPPORT_MARGIN (2 cm).
* **Smoothness**: no local rotation changes by more than MAX_JOINT_STEP (45 degrees) between
  frames at 30 fps, nor does any hinge angle the humanoid is driven with (a joint passing close
  to gimbal lock with some rotation about the missing axis makes the x-y-z decomposition flip),
  and no body moves faster than MAX_BODY_SPEED (12 m/s).

`zmp_margin(raw)` is a measure, not a check: per frame, how far the zero-moment point of the
centre of mass (its floor projection shifted by inertia, c - c_z c'' / (g + c_z''); a point mass,
angular momentum ignored) lies inside the contacts' hull. A motion whose ZMP leaves the hull for
long cannot be done as drawn (the body tips over the hull's edge), however slowly it moves; the
static balance check above sees only the slow frames. `benchmarks/getup_follow.py` reports it
per phase of the get-ups.

The clip is checked where it is (not grounded first: a clip sunk into the floor must fail) and
resampled to 30 fps, as `Motion.from_raw` does, so per-frame figures mean the same for every clip.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..humanoid.kinematics import forward_kinematics, lowest_point
from ..humanoid.skeleton import BODY_NAMES, HINGE_NAMES, MEAN_SKELETON, Skeleton, anatomical_limits
from ..rotations import quat_apply, quat_from_euler_xyz, quat_inv, quat_mul, quat_to_matrix, quat_to_rotvec
from .kinematics import Segments, hinge_angles, unwrap
from .motion import FPS, RawMotion

GRAVITY = 9.81  # m/s^2
DEG = np.pi / 180.0

FLOOR_TOLERANCE = 0.01  # m: deepest allowed penetration of the floor
CONTACT_HEIGHT = 0.01  # m: a support point this close to the floor touches it
MAX_SLIDE_SPEED = 0.05  # m/s: mean horizontal speed of a foot's contacting corners
FLIGHT_ACC_TOLERANCE = 0.3  # m/s^2: |pelvis z'' + g| in the air
MAX_FLIGHT_ACC_XY = 0.5  # m/s^2: |pelvis xy''| in the air
LIMIT_MARGIN = 3 * DEG  # beyond the anatomical hinge ranges
QUASI_STATIC_SPEED = 0.15  # m/s: horizontal centre-of-mass speed below which balance is static
QUASI_STATIC_ACC = 0.3  # m/s^2: ... and horizontal acceleration below this
SUPPORT_MARGIN = 0.02  # m: the support polygon is expanded by this much
MAX_JOINT_STEP = 45 * DEG  # rad per frame at 30 fps
MAX_BODY_SPEED = 12.0  # m/s

FEET = {side: (BODY_NAMES.index(f"{side}_Ankle"), BODY_NAMES.index(f"{side}_Toe")) for side in "LR"}
# Unit directions for the support-function test of the support polygon: with 64 of them the
# polygon they bound exceeds the true one by 0.12% of its size (< 0.5 mm for a stance).
_DIRECTIONS = np.stack([np.cos(a := np.linspace(0, 2 * np.pi, 64, endpoint=False)), np.sin(a)], -1)


def geom_centres(skeleton: Skeleton = MEAN_SKELETON) -> np.ndarray:
    """(24, 3) centre of each body's geom in the body frame (its centre of mass)."""
    centres = []
    for g in skeleton.geoms:
        if g.kind == "capsule":
            centres.append(np.reshape(g.fromto, (2, 3)).mean(0))
        elif g.kind == "mesh":
            centres.append(np.asarray(g.vertices).mean(0))
        else:
            centres.append(np.asarray(g.pos))
    return np.array(centres)


def centre_of_mass(body_pos: np.ndarray, body_quat: np.ndarray, skeleton: Skeleton = MEAN_SKELETON) -> np.ndarray:
    """Whole-body centre of mass (..., 3) from body positions (..., 24, 3) and world orientations
    (..., 24, 4): each geom's mass at its centre."""
    world = body_pos + quat_apply(body_quat, geom_centres(skeleton))
    masses = np.array([g.mass for g in skeleton.geoms])
    return np.einsum("...bi,b->...i", world, masses) / masses.sum()


def support_points_world(body_pos, body_quat, skeleton: Skeleton = MEAN_SKELETON):
    """World positions (T, 24, K, 3) of every body's support points (`Skeleton.support_points`)
    and how far each reaches below its point (24, K): box corners 0, capsule ends and spheres
    their radius."""
    points, radii = skeleton.support_points()
    rot = quat_to_matrix(body_quat)  # one matrix per body: cheaper than rotating K points by quaternion
    return body_pos[:, :, None] + np.einsum("tbij,bkj->tbki", rot, points), radii


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """(first, last) frame of every run of True in a 1-D bool array."""
    edges = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    return list(zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1) - 1))


def _second_difference(x: np.ndarray, fps: float) -> np.ndarray:
    """x'' at frames 1..T-2."""
    return (x[2:] - 2 * x[1:-1] + x[:-2]) * fps ** 2


@dataclass
class PlausibilityReport:
    """Measured figures of one clip (SI units; nan where a check had no frames to measure) and
    the violations found, one readable string each."""

    name: str
    num_frames: int
    lowest: float  # m, lowest point of the geometry over the clip
    flight: np.ndarray  # (T,) bool, airborne frames
    flight_phases: list[tuple[int, int]]  # (first, last) airborne frame of each phase
    slide_mean: dict[str, float]  # per foot, m/s, mean speed of its contacting corners
    slide_max: dict[str, float]  # per foot, m/s
    flight_acc_error: float  # m/s^2, max |pelvis z'' + g| over interior airborne frames
    flight_acc_xy: float  # m/s^2, max |pelvis xy''| over interior airborne frames
    limit_excess: float  # rad, largest hinge excursion beyond an anatomical range (<= 0: within)
    worst_hinge: str  # the hinge of that excursion
    limit_distance: float  # rad, largest rotation from a joint's pose to one within its ranges
    quasi_static: np.ndarray  # (T,) bool, frames where static balance is checked
    support_margin: float  # m, min over quasi-static frames of the CoM's distance inside the support
    max_joint_step: float  # rad, largest change of a local rotation between frames
    max_hinge_step: float  # rad, largest change of a hinge angle (as Motion.dof_pos) between frames
    max_body_speed: float  # m/s
    violations: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not self.violations

    @property
    def failed(self) -> set[str]:
        """Names of the failed checks: "floor", "planted feet", "floating", "flight", "joint range",
        "balance", "smoothness"."""
        return {v.split(":")[0] for v in self.violations}

    def __str__(self) -> str:
        head = f"{self.name}: {'plausible' if self.ok else 'IMPLAUSIBLE'}"
        return "\n  ".join([head, *self.violations])


def check_motion(raw: RawMotion, skeleton: Skeleton = MEAN_SKELETON, allow_flight: bool = True) -> PlausibilityReport:
    """Measure `raw` against the module's plausibility checks (see the module docstring).

    `allow_flight=False` declares that the clip never leaves the ground (a squat, a kick), so any
    airborne frame is reported as floating instead of being checked for ballistic flight.
    """
    raw = raw.resampled(FPS)
    fps, n = raw.fps, raw.num_frames
    body_pos, body_quat = forward_kinematics(raw.root_pos, raw.local_quat, skeleton.offsets)
    low = lowest_point(body_pos, body_quat, skeleton)
    flight = low > CONTACT_HEIGHT
    points, reach = support_points_world(body_pos, body_quat, skeleton)
    touching = points[..., 2] - reach < CONTACT_HEIGHT  # (T, 24, K)
    violations: list[str] = []

    if low.min() < -FLOOR_TOLERANCE:
        violations.append(f"floor: penetrated by {-low.min() * 100:.1f} cm at frame {int(low.argmin())}")

    slide_mean, slide_max = _foot_slide(points, touching, fps)
    for side, speed in slide_mean.items():
        if speed > MAX_SLIDE_SPEED:
            violations.append(f"planted feet: {side} foot slides at {speed * 100:.1f} cm/s on average "
                              f"(max {slide_max[side] * 100:.1f} cm/s)")

    phases = _runs(flight)
    acc_err, acc_xy = _flight_accelerations(raw.root_pos, flight, fps)
    if phases and not allow_flight:
        violations.append(f"floating: {int(flight.sum())} airborne frames in {len(phases)} phases "
                          f"(first {phases[0]}), up to {low.max() * 100:.1f} cm above the floor")
    elif acc_err > FLIGHT_ACC_TOLERANCE or acc_xy > MAX_FLIGHT_ACC_XY:
        violations.append(f"flight: not ballistic, pelvis z'' off -g by up to {acc_err:.2f} m/s^2, "
                          f"|xy''| up to {acc_xy:.2f} m/s^2")

    seg = Segments.from_lengths([n])
    dof = unwrap(hinge_angles(raw.local_quat, seg), seg)  # as Motion.dof_pos
    excess, worst, distance = _limit_excess(raw.local_quat, dof)
    if distance > LIMIT_MARGIN:
        violations.append(f"joint range: a joint is {np.degrees(distance):.1f} deg (rotation) from its "
                          f"anatomical range ({worst} {np.degrees(excess):.1f} deg beyond)")

    quasi, margin = _static_balance(centre_of_mass(body_pos, body_quat, skeleton), points, touching,
                                    flight, fps)
    if margin < -SUPPORT_MARGIN:
        violations.append(f"balance: centre of mass {-margin * 100:.1f} cm outside the support in a "
                          f"quasi-static frame")

    step = _joint_steps(raw.local_quat)
    speed = np.linalg.norm(np.diff(body_pos, axis=0), axis=-1) * fps if n > 1 else np.zeros(1)
    if step.max() > MAX_JOINT_STEP:
        f, b = np.unravel_index(step.argmax(), step.shape)
        violations.append(f"smoothness: {BODY_NAMES[b]} turns {np.degrees(step.max()):.0f} deg "
                          f"between frames {f} and {f + 1}")
    hinge_step = np.abs(np.diff(dof, axis=0)).max(axis=0) if n > 1 else np.zeros(dof.shape[1])
    if hinge_step.max() > MAX_JOINT_STEP:
        violations.append(f"smoothness: hinge {HINGE_NAMES[hinge_step.argmax()]} jumps "
                          f"{np.degrees(hinge_step.max()):.0f} deg between frames (its x-y-z "
                          f"decomposition flips near gimbal lock)")
    if speed.max() > MAX_BODY_SPEED:
        violations.append(f"smoothness: a body moves at {speed.max():.1f} m/s")

    return PlausibilityReport(
        raw.name, n, float(low.min()), flight, phases, slide_mean, slide_max, acc_err, acc_xy,
        excess, worst, distance, quasi, margin, float(step.max()), float(hinge_step.max()),
        float(speed.max()), violations)


def _foot_slide(points, touching, fps):
    """Per foot, mean and max horizontal speed of its box corners touching in consecutive frames."""
    mean, peak = {}, {}
    for side, bodies in FEET.items():
        pts = points[:, bodies].reshape(len(points), -1, 3)
        touch = touching[:, bodies].reshape(len(points), -1)
        touch = touch[:-1] & touch[1:]
        speed = np.linalg.norm(np.diff(pts[..., :2], axis=0), axis=-1) * fps
        mean[side] = float(speed[touch].mean()) if touch.any() else 0.0
        peak[side] = float(speed[touch].max()) if touch.any() else 0.0
    return mean, peak


def _flight_accelerations(root_pos, flight, fps):
    """Max |z'' + g| and max |xy''| of the pelvis over airborne frames with airborne neighbours."""
    if len(flight) < 3:
        return np.nan, np.nan
    inner = flight[1:-1] & flight[:-2] & flight[2:]
    if not inner.any():
        return np.nan, np.nan
    acc = _second_difference(root_pos, fps)[inner]
    return float(np.abs(acc[:, 2] + GRAVITY).max()), float(np.linalg.norm(acc[:, :2], axis=-1).max())


def _limit_excess(local_quat, dof):
    """How far the pose leaves the anatomical ranges: the largest excursion of a hinge angle `dof`
    (T, 69) beyond its range (rad), its hinge, and the largest rotation angle (rad) between a
    joint's local rotation and the nearest one its hinges reach within range."""
    t = len(local_quat)
    dof = dof.reshape(t, -1, 3)
    lo, hi = anatomical_limits().reshape(-1, 3, 2).transpose(2, 0, 1)  # (23, 3) each
    excess = np.maximum(lo - dof, dof - hi)  # (T, 23, 3)
    worst = int(excess.max(axis=0).argmax())
    out = (excess > 0).any(-1)
    distance = _distance_to_range(local_quat[:, 1:][out], dof[out], lo[out.nonzero()[1]],
                                  hi[out.nonzero()[1]]) if out.any() else np.zeros(1)
    return float(excess.reshape(t, -1)[:, worst].max()), HINGE_NAMES[worst], float(distance.max())


def _distance_to_range(quat, angles, lo, hi, iterations: int = 60):
    """Rotation angle (N,) from each rotation (N, 4) to the nearest intrinsic x-y-z hinge setting
    within [lo, hi] (N, 3), by projected damped Gauss-Newton from its decomposition `angles`.

    The decomposition alone overstates excursions near gimbal lock: with a hip flexed ~90 deg its
    x (abduction) and z (twist) axes nearly coincide and the split between them is arbitrary, so
    one of them can leave its range while an in-range split gives almost the same rotation.
    Being a feasible point, the result is an upper bound on the true distance."""
    e = np.clip(angles, lo, hi)
    for _ in range(iterations):
        r = quat_to_rotvec(quat_mul(quat, quat_inv(quat_from_euler_xyz(e))))  # parent frame
        a, b = e[:, 0], e[:, 1]
        # Angular velocity of Rx(a) Ry(b) Rz(c) per unit rate of a, b, c (parent frame).
        jac = np.stack([np.broadcast_to([1.0, 0.0, 0.0], r.shape),
                        np.stack([0 * a, np.cos(a), np.sin(a)], -1),
                        np.stack([np.sin(b), -np.sin(a) * np.cos(b), np.cos(a) * np.cos(b)], -1)], -1)
        step = _damped_step(jac, r)
        # A hinge at its bound and pushed outwards is held, and the others solve for the rest:
        # that is how the twin axis takes over near gimbal lock.
        held = ((e <= lo) & (step < 0)) | ((e >= hi) & (step > 0))
        step = _damped_step(jac * ~held[:, None, :], r)
        e, e_old = np.clip(e + step, lo, hi), e
        if np.abs(e - e_old).max() < 1e-6:  # converged (slowly only near gimbal lock)
            break
    return np.linalg.norm(quat_to_rotvec(quat_mul(quat, quat_inv(quat_from_euler_xyz(e)))), axis=-1)


def _damped_step(jac, r, damping: float = 1e-4):
    """Damped least-squares solution of jac @ step = r, batched (N, 3, 3) @ (N, 3)."""
    jt = np.swapaxes(jac, -1, -2)
    return np.linalg.solve(jt @ jac + damping * np.eye(3), (jt @ r[..., None]))[..., 0]


def zmp_margin(raw: RawMotion, skeleton: Skeleton = MEAN_SKELETON) -> np.ndarray:
    """(T,) signed distance (m) of the zero-moment point inside the convex hull of the contacting
    support points per frame of `raw` at 30 fps (module docstring; negative: outside, NaN: no
    contact)."""
    raw = raw.resampled(FPS)
    body_pos, body_quat = forward_kinematics(raw.root_pos, raw.local_quat, skeleton.offsets)
    points, reach = support_points_world(body_pos, body_quat, skeleton)
    touching = points[..., 2] - reach < CONTACT_HEIGHT
    com = centre_of_mass(body_pos, body_quat, skeleton)
    acc = np.gradient(np.gradient(com, 1 / raw.fps, axis=0), 1 / raw.fps, axis=0) if len(com) > 2 else 0 * com
    zmp = com[:, :2] - com[:, 2:] * acc[:, :2] / (GRAVITY + acc[:, 2:])
    t = len(com)
    margin = _hull_margin(zmp, points.reshape(t, -1, 3)[..., :2], touching.reshape(t, -1))
    return np.where(touching.reshape(t, -1).any(1), margin, np.nan)


def _hull_margin(xy, pts, touch):
    """(F,) signed distance of the points xy (F, 2) inside the convex hull of those of pts (F, N, 2)
    where touch (F, N) is set; -inf for a frame with none."""
    # Support function of the hull, h(u) = max over contacts of u . p: the signed distance of a
    # point c inside a convex polygon is min over u of h(u) - u . c (minus the distance outside).
    proj = np.where(touch[..., None], pts @ _DIRECTIONS.T, -np.inf)  # (F, N, D)
    return (proj.max(axis=1) - xy @ _DIRECTIONS.T).min(axis=1)


def _static_balance(com, points, touching, flight, fps):
    """Quasi-static frames and the smallest signed distance (m) of the centre of mass' floor
    projection inside the convex hull of the contacting support points (negative: outside)."""
    com = com[:, :2]
    if len(com) < 3:
        return np.zeros(len(com), bool), np.nan
    vel = np.gradient(com, 1 / fps, axis=0)
    acc = np.gradient(vel, 1 / fps, axis=0)
    quasi = (~flight & (np.linalg.norm(vel, axis=-1) < QUASI_STATIC_SPEED)
             & (np.linalg.norm(acc, axis=-1) < QUASI_STATIC_ACC))
    if not quasi.any():
        return quasi, np.nan
    pts = points[quasi].reshape(int(quasi.sum()), -1, 3)
    touch = touching[quasi].reshape(len(pts), -1)  # every frame on the ground has a contact
    ever = touch.any(axis=0)  # a few dozen points (the soles) of the ~200: a small product below
    return quasi, float(_hull_margin(com[quasi], pts[:, ever, :2], touch[:, ever]).min())


def _joint_steps(local_quat):
    """(T-1, 24) rotation angle of each local rotation's change between consecutive frames."""
    if len(local_quat) < 2:
        return np.zeros((1, local_quat.shape[1]))
    rel = quat_mul(quat_inv(local_quat[:-1]), local_quat[1:])
    return 2 * np.arccos(np.clip(np.abs(rel[..., 0]), 0.0, 1.0))
