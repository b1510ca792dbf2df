"""Getting up from the floor: from lying on the front or the back to standing, the way many
people do it (roll onto the front, push back onto hands and knees, tuck the toes and lift the knees
into a bear stance, walk the feet in towards the hands one after the other, shift the weight back
over the feet, lift the hands and stand up).

The corpus has no other motion that starts on the floor, so without this family a tracker, and
everything distilled from it, has never seen a body rise (docs/results/learning.md, the recovery
runs). The clip is directed in phases, each a minimum-jerk blend between key postures:

* rolling from the back onto the front (`_ROLL`), the top leg sets its foot flat beside the
  buttock and pushes off it (its ankle held on the floor by IK while the pelvis turns), the arm
  underneath is swept overhead along the floor, out of the way, and the top knee crosses over.
  The roll used to turn the body over its edge on the arm along its side, the hips lifted off the
  floor, with no support on the side it left: no policy or PD follows that (docs/results/learning.md);
* on the floor (lying, rolling, pushing back, on hands and knees) the legs and spine are hinge
  angles; the pelvis height puts the lowest point of the body (hands aside) on the floor, and its
  horizontal position keeps the body's contacts with the floor where they were (a body pushes
  itself over its contacts, it does not slide on them), except that pushing back onto hands and
  knees the knees slide forward for half the way (`_KNEE_SLIDE`: what a simulated body does);
* hands on the floor are placed by inverse kinematics on fixed floor points, blended with the
  free arm posture as they are put down and lifted;
* from the bear stance on, both legs are solved by the closed-form IK of `procedural`: the balls
  of the feet stay where they are put down, and while the hands are down the pelvis follows its
  key heights; from the crouch on it moves so that the centre of mass comes over the feet before
  the hands lift.

The rise used to be a lunge (one foot stepped forward between the hands, then up over it). Its
zero-moment point left the contacts' hull by 0.15-0.34 m for 11-12 frames in every test clip
(`plausibility.zmp_margin`, `benchmarks/getup_follow.py`), and that is where PD on the reference
lost it: no body can do it slowly. This rise keeps hands and feet on the floor until the centre of
mass is over the feet. Its key postures (`_PELVIS_PITCH`, `_SPINE_LEAN`, `_PELVIS_HEIGHT`, `_FEET`)
came from a search that kept the zero-moment point inside the hull and every hinge inside its
anatomical range over several parameter draws (docs/corpus.md has the figures).

Every clip passes `check_motion` as it is drawn for the corpus (it redraws the third that do
not, most often hand placements at the ends of their ranges). Three choices make that so: the
knees stay under the hips on hands and knees; the feet keep the pelvis' heading while the hips
flex past 90 deg, since the humanoid's x-y-z hip hinges are in gimbal lock there and any twist or
abduction makes them flip; and bodies on the floor rest `_SINK` deep in it.

`getup(...)` is a pure, deterministic function of its parameters; `RANGES["getup"]` holds them.
The clip ends standing still, feet about hip width apart, so it chains with the other families.
Frames, axes and signs are procedural's: x forward, y left, z up.
"""

from __future__ import annotations

import numpy as np

from ..humanoid.kinematics import forward_kinematics, lowest_point
from ..rotations import (quat_apply, quat_from_euler_xyz, quat_from_matrix, quat_inv, quat_mul, quat_slerp,
                         quat_to_matrix, yaw_quat)
from .motion import FPS, RawMotion
from .plausibility import centre_of_mass, support_points_world
from .procedural import (
    B, BALL_HEIGHT, DEG, FOOT_CENTRE, MIN_KNEE, check_number, OFFSETS, SIDES, SKELETON, _arm, _axis_quat, _frame,
    _keys, _knee_terms, _max_pelvis_height, _minjerk, _normalize, _rot, _solve_arm, _solve_leg, _Spec, _standing_legs,
)

SOURCE = "smpl_envs.motion.getup"

RANGES: dict[str, dict[str, tuple[float, float]]] = {
    "getup": {
        # speed factor of the whole movement (durations / tempo)
        "tempo": (0.7, 1.3),
        # lateral half-distance of the hands on the floor, and how far ahead of the shoulders
        "hand_width": (0.16, 0.24),
        "hand_ahead": (-0.04, 0.06),
        # seconds spent lying before moving, and on hands and knees
        "lie": (0.3, 1.5),
        "kneel": (0.1, 0.8),
    },
}
STARTS = ("front", "back")
# The tempos getup() makes; the corpus draws from RANGES' narrower band. Faster get-ups are for
# measuring what a quicker family would ask of a body (benchmarks/getup_follow.py --tempo-scale).
TEMPO_LIMITS = (0.5, 3.0)

_FLOOR_BODIES = np.array([i for i in range(24) if i not in {B[f"{s}_{p}"] for s in SIDES
                                                            for p in ("Shoulder", "Elbow", "Wrist", "Hand")}])
# Of the way the pelvis travels back over the knees while pushing onto hands and knees, the share
# the knees slide forward instead (the shoulders move back by the rest). Pinned on the legs' contacts
# alone, the upper body would make all of the 0.46 m, which a simulated body whose hands bear weight
# cannot: PD on the reference with no residual (benchmarks/getup_follow.py) was 0.18-0.28 m off on
# hands and knees with no sliding and 0.03-0.07 m with half (docs/corpus.md; 0.3 and 0.7 did worse).
_KNEE_SLIDE = 0.5
_ANKLE_HEIGHT = 0.08  # m: the ankle joint above the floor, a foot flat on it
_HAND_REST = 0.003  # m: how far above the floor the hand's lowest point is aimed (inside the contact band)
_PHASES = ("lie", "roll", "hands", "push", "kneel", "bear", "foot_1", "foot_2", "crouch", "lift", "up", "stand",
           "still", "end")
_NEXT = dict(zip(_PHASES[:-1], _PHASES[1:]))
# m: bodies on the floor rest this deep in it, as soft tissue and MuJoCo's soft contacts do: a
# capsule body otherwise rests on its one lowest point, and a few mm decide which limb that is.
_SINK = 0.004
# The rise's key postures, each reached at the start of its phase (degrees, metres). foot_1 and
# foot_2 are the phases in which the `side` foot, then the other, walks in towards the hands.
_PELVIS_PITCH = (("lie", 90), ("push", 90), ("bear", 88), ("foot_1", 87), ("foot_2", 79),
                 ("crouch", 72), ("lift", 28), ("up", 19), ("stand", 0))
_SPINE_LEAN = (("lie", -4), ("push", -4), ("kneel", 6), ("bear", 6), ("foot_1", 7), ("foot_2", 17),
               ("crouch", 28), ("lift", 36), ("up", 3), ("stand", 0))
# pelvis heights from the bear stance on (the knees leave the floor), capped by the legs' reach
_PELVIS_HEIGHT = (("foot_1", 0.543), ("foot_2", 0.543), ("crouch", 0.485), ("lift", 0.43),
                  ("up", 0.614), ("stand", 2.0))
_FEET = dict(
    behind=0.486,  # where the feet walk to: this far behind the hands' midpoint,
    width=0.116,  # and this far either side of it (toe joints)
    swing=0.019,  # how high a foot is lifted walking in
    ball_pitch=52 * DEG,  # the heel raised on the balls of the feet, in the bear stance
    heel_land=28 * DEG,  # ... as a foot lands (then flattened in the crouch)
)
_OVER_FEET = 0.92  # share of the crouch by which the centre of mass is over the feet
# The roll from the back onto the front, each time a share of the roll phase. The top leg sets its
# foot beside the buttock and pushes off it while the pelvis turns (a simulated pelvis has no
# motor: it turns only when a limb pushes it over); the arm underneath sweeps overhead along the
# floor, out from under the body, and comes down for the push once the body is face down; the top
# arm reaches forward; the top knee crosses over.
_ROLL = dict(
    duration=2.0,          # s at tempo 1
    turn=0.2,              # the pelvis starts to turn about its long axis
    overhead=172 * DEG,    # abduction of the arm underneath, swept overhead by
    sweep=0.35,            # ... here, held there lifted off the floor
    overhead_lift=15 * DEG,
    down=0.8,              # ... and brought down from here to the push (the top arm too)
    top_reach=(0.35, 0.6),  # the top arm reaches forward between these shares,
    top_flex=30 * DEG,     # this far
    plant=(0.05, 0.3),     # the top foot is set down beside the buttock between these shares,
    push=0.6,              # pushes (its ankle stays on its floor point as the pelvis turns) until here,
    release=0.85,          # and the leg is back in its crossed posture by here
    foot_along=0.42,       # m: the planted ankle, this far from the hip towards the feet,
    foot_out=0.06,         # and this far out to the top side
    foot_flex=-10 * DEG,   # the ankle's hinge while the foot is down
    cross=0.5,             # the top leg crossed over by here, held until `down`
    cross_flex=50 * DEG, cross_knee=70 * DEG, cross_adduct=8 * DEG,
)
_DURATIONS = (("hands", 0.7), ("push", 1.3), ("bear", 0.9), ("foot_1", 0.8), ("foot_2", 0.8), ("crouch", 1.0),
              ("lift", 0.9), ("up", 1.2), ("stand", 0.6))  # s at tempo 1 (lie, kneel and still: parameters)


def _check(name: str, value) -> float:
    return check_number("getup", name, value, RANGES["getup"][name])


def getup(start: str = "back", side: str = "L", roll: str = "L", tempo: float = 1.0,
          hand_width: float = 0.18, hand_ahead: float = 0.02,
          lie: float = 0.8, kneel: float = 0.3, name: str = "getup") -> RawMotion:
    """Lying on the `start` ("front": face down, "back": face up), getting up to standing.

    side: the leg ("L" / "R") whose foot walks in first. roll: the side rolled over
    onto the front from the back (ignored for "front"). The other parameters: `RANGES["getup"]`.
    About 9.5 s from the front and 11 s from the back at tempo 1.
    """
    return _made(start, side, roll, tempo, hand_width, hand_ahead, lie, kneel).clip(name)


def phases(start: str = "back", side: str = "L", roll: str = "L", tempo: float = 1.0,
           hand_width: float = 0.18, hand_ahead: float = 0.02, lie: float = 0.8,
           kneel: float = 0.3) -> dict[str, tuple[float, float]]:
    """{phase: (start, end)} in seconds of the clip `getup` makes with these parameters, in
    order, phases of no length left out ("roll" from the front)."""
    keys = _made(start, side, roll, tempo, hand_width, hand_ahead, lie, kneel).keys
    return {p: (keys[p], keys[_NEXT[p]]) for p in _PHASES[:-1] if keys[_NEXT[p]] > keys[p]}


def _made(start, side, roll, tempo, hand_width, hand_ahead, lie, kneel) -> "_Getup":
    if start not in STARTS:
        raise ValueError(f"getup: start = {start!r} must be one of {STARTS}")
    for key, value in (("side", side), ("roll", roll)):
        if value not in SIDES:
            raise ValueError(f"getup: {key} = {value!r} must be 'L' or 'R'")
    tempo = check_number("getup", "tempo", tempo, TEMPO_LIMITS)
    p = {k: _check(k, v) for k, v in (("hand_width", hand_width), ("hand_ahead", hand_ahead),
                                       ("lie", lie), ("kneel", kneel))}
    return _Getup(start, side, roll, tempo, **p)


class _Getup:
    """The phases, their key postures and the solve. Times in seconds from the clip's start."""

    def __init__(self, start, side, roll, tempo, hand_width, hand_ahead, lie, kneel):
        self.side, self.back = side, ("R" if side == "L" else "L")
        self.hand_width, self.hand_ahead = hand_width, hand_ahead
        rolling = _ROLL["duration"] if start == "back" else 0.0
        durations = [("lie", lie), ("roll", rolling), *_DURATIONS[:2], ("kneel", kneel), *_DURATIONS[2:], ("still", 0.5)]
        self.keys, t = {}, 0.0
        for phase, d in durations:
            self.keys[phase] = t
            t += d / tempo if phase not in ("lie", "kneel", "still") else d
        self.keys["end"] = t
        self.t = np.arange(int(round(t * FPS)) + 1) / FPS
        self.start, self.roll_sign = start, SIDES[roll]
        # Rolling from the back the body lies on the shoulder underneath (its upper arm is
        # overhead): that counts in the body's height and levelling, as the trunk and legs do.
        self.floor_bodies = _FLOOR_BODIES if start == "front" else np.sort(
            np.append(_FLOOR_BODIES, B[f"{self._roll_sides()[0]}_Shoulder"]))

    def curve(self, keys) -> np.ndarray:
        """Minimum-jerk curve through (phase, value) keys, each reached at that phase's start;
        held before the first and after the last."""
        times = np.array([self.keys[p] if isinstance(p, str) else self.keys[p[0]] + p[1] * (
            self.keys[_NEXT[p[0]]] - self.keys[p[0]]) for p, _ in keys])
        values = np.array([v for _, v in keys], float)
        keep = np.append(np.diff(times) > 0, True)  # a phase of no length: its end's value wins
        return _keys(self.t, times[keep], values[keep]) if keep.sum() > 1 else np.full(len(self.t), values[-1])

    # ----------------------------------------------------------------- key postures

    def postures(self):
        """Per-frame pelvis orientation and hinge angles of the floor phases."""
        t, c = self.t, self.curve
        n = len(t)
        # The pelvis pitches up from face down as the body rises; the spine bends while the
        # hands are down, so that they reach the floor with the hips over the feet.
        pitch = c([(k, v * DEG) for k, v in _PELVIS_PITCH])
        # From the back the body rolls about its long axis onto the front: psi 180 -> 0 deg.
        psi = (c([("lie", np.pi), (("roll", _ROLL["turn"]), np.pi), ("hands", 0.0)]) * self.roll_sign
               if self.start == "back" else np.zeros(n))
        angles = np.zeros((n, 24, 3))
        for s, sign in SIDES.items():
            hip, knee, ankle = (B[f"{s}_{j}"] for j in ("Hip", "Knee", "Ankle"))
            # Hip flexion, knee flexion: straight lying, then the thighs swing under the body.
            # Lying, a little flexion (front) or extension (back) brings the thighs onto the floor.
            lying = 6 * DEG if self.start == "front" else -6 * DEG
            flex = c([("lie", lying), ("roll", lying), ("hands", 6 * DEG), ("push", 6 * DEG), ("kneel", 92 * DEG)])
            knee_flex = c([("lie", 4 * DEG), ("push", 8 * DEG), ("kneel", 118 * DEG)])
            if self.start == "back" and sign == self.roll_sign:
                # the leg on top crosses over, knee to the floor: the body rolls over it instead
                # of balancing on its side
                cross = self.curve([("roll", 0.0), (("roll", _ROLL["cross"]), 1.0), (("roll", _ROLL["down"]), 1.0),
                                    (("hands", 0.3), 0.0)])
                flex = flex + cross * _ROLL["cross_flex"]
                knee_flex = knee_flex + cross * _ROLL["cross_knee"]
            angles[:, hip, 1] = -flex
            angles[:, knee, 1] = knee_flex
            # Legs a little apart lying; on hands and knees each knee under its hip (the hips are
            # flexed 90 deg there, where abduction would make their hinges flip).
            angles[:, hip, 0] = sign * c([("lie", 3 * DEG), ("push", 3 * DEG), ("kneel", 0.0)])
            if self.start == "back" and sign == self.roll_sign:
                angles[:, hip, 0] -= sign * cross * _ROLL["cross_adduct"]
            # Toes tucked under on the floor: the foot at a right angle to the shin.
            angles[:, ankle, 1] = c([("lie", 25 * DEG), ("hands", 25 * DEG), ("kneel", 0.0)])
            angles[:, B[f"{s}_Toe"], 1] = self.toe_curve(s)
        # The spine: a slight arch lying, a flat back on hands and knees, bent forward while the
        # feet walk in and the hands lift, upright when standing.
        lean = c([(k, v * DEG) for k, v in _SPINE_LEAN])
        for body, share in (("Torso", 0.4), ("Spine", 0.35), ("Chest", 0.25)):
            angles[:, B[body], 1] = share * lean
        # The head looks at the floor ahead on the floor and forward when up.
        look = c([("lie", -10 * DEG), ("push", -25 * DEG), ("crouch", -25 * DEG), ("up", 0.0)])
        angles[:, B["Neck"], 1] = 0.6 * look
        angles[:, B["Head"], 1] = 0.4 * look
        quat = quat_mul(_rot(np.zeros(n), pitch), _axis_quat(2, psi))
        return quat, angles

    def hand_weight(self) -> np.ndarray:
        """0: the arm free, 1: the hand on its floor point."""
        return self.curve([("roll", 0.0), ("hands", 0.0), ("push", 1.0), ("lift", 1.0), (("lift", 0.6), 0.0)])

    def _roll_sides(self):
        """(the side rolled onto, the side on top) of a roll from the back."""
        bottom = next(s for s, sign in SIDES.items() if sign != self.roll_sign)
        return bottom, next(s for s in SIDES if s != bottom)

    def free_arms(self):
        """Arm posture when not on the floor: along the body lying, forward while rising. Rolling
        from the back, the arm underneath sweeps overhead and the top arm reaches forward."""
        c = self.curve
        flex_keys = [("lie", -10 * DEG), ("lift", -10 * DEG), ("up", 35 * DEG), ("stand", 8 * DEG), ("still", 0.0)]
        abduct_keys = [("lie", 8 * DEG), ("up", 12 * DEG), ("stand", 10 * DEG)]
        elbow = c([("lie", 10 * DEG), ("lift", 10 * DEG), ("up", 30 * DEG), ("stand", 15 * DEG)])
        arms = {s: _arm(self.t, s, c(flex_keys), c(abduct_keys), elbow) for s in SIDES}
        if self.start == "back":
            bottom, top = self._roll_sides()
            r = _ROLL
            abduct = c([("lie", 8 * DEG), ("roll", 8 * DEG), (("roll", r["sweep"]), r["overhead"]),
                        (("roll", r["down"]), r["overhead"]), ("push", 8 * DEG)] + abduct_keys[1:])
            # overhead, the arm is lifted off the floor towards whichever side of the body is up
            # (the chest while on the back, the back once on the front), so it never digs in
            psi = c([("lie", -1.0), (("roll", r["turn"]), -1.0), ("hands", 1.0)])
            up = c([("roll", 0.0), (("roll", r["sweep"]), 1.0), (("roll", r["down"]), 1.0), ("push", 0.0)])
            flex = c(flex_keys) * (1 - up) + up * psi * r["overhead_lift"]
            arms[bottom] = _arm(self.t, bottom, flex, abduct, elbow)
            reach = r["top_reach"]
            flex = c([("lie", -10 * DEG), (("roll", reach[0]), -10 * DEG), (("roll", reach[1]), r["top_flex"]),
                      (("roll", r["down"]), -10 * DEG)] + flex_keys[1:])
            arms[top] = _arm(self.t, top, flex, c(abduct_keys), elbow)
        return arms

    # ----------------------------------------------------------------- the solve

    def clip(self, name: str) -> RawMotion:
        t, n = self.t, len(self.t)
        pelvis_quat, angles = self.postures()
        local = quat_from_euler_xyz(angles)
        local[:, 0] = pelvis_quat
        root = np.zeros((n, 3))
        self._level(local)
        free = self.free_arms()
        self._solve_arms(root, local, free, None, None)

        # Floor phases: height from the lowest point (hands aside), position pinned on contacts.
        root[:, 2] = self._floor_height(root, local) - _SINK
        root[:, :2] = self._pinned(root, local)
        if self.start == "back":
            self._push_off(root, local)
        self._slide_knees(root, local)

        # From the bear stance on: both legs by IK on their feet, the pelvis on its key heights and,
        # from the crouch, over the feet.
        i_bear = self._index("bear")
        spec = _Spec(t, root, local[:, 0].copy(), self._leg_targets(root, local, i_bear), free)
        self._rise(spec, local, i_bear)
        root = spec.pelvis_pos

        # Hands on fixed floor points while they bear weight.
        w = self.hand_weight()
        self._solve_arms(root, local, free, self._hand_targets(root, local), w)
        # Whatever the blend left under the floor is lifted out (a few mm at most).
        body_pos, body_quat = forward_kinematics(root, local, OFFSETS)
        low = lowest_point(body_pos, body_quat, SKELETON)
        root[:, 2] -= np.minimum(low + _SINK, 0.0)
        return RawMotion(name, FPS, root.copy(), local, source=SOURCE)

    def _level(self, local) -> None:
        """Pitch the lying body about the floor's lateral axis so that its upper body and its
        legs reach equally low: it then rests on both, with the centre of mass between them,
        instead of balancing on its pelvis. Blended out as the hands take the weight."""
        upper = [B[b] for b in ("Torso", "Spine", "Chest", "Neck", "Head", "L_Thorax", "R_Thorax")]
        upper += [int(i) for i in np.setdiff1d(self.floor_bodies, _FLOOR_BODIES)]
        lower = [0] + [B[f"{s}_{j}"] for s in SIDES for j in ("Hip", "Knee", "Ankle", "Toe")]
        grid = np.linspace(-12, 12, 25) * DEG
        gaps = []
        for d in grid:
            trial = local.copy()
            trial[:, 0] = quat_mul(_axis_quat(1, np.full(len(local), d)), local[:, 0])
            pos, q = forward_kinematics(np.zeros((len(local), 3)), trial, OFFSETS)
            pts, reach = support_points_world(pos, q, SKELETON)
            z = (pts[..., 2] - reach).min(-1)
            gaps.append(z[:, upper].min(1) - z[:, lower].min(1))
        gaps = np.array(gaps)  # (grid, T): crosses zero where both rest on the floor
        best = grid[np.argmin(np.abs(gaps), axis=0)]
        weight = self.curve([("lie", 1.0), ("push", 1.0), (("push", 0.5), 0.0)])
        delta = _smooth(best, 5) * weight
        local[:, 0] = quat_mul(_axis_quat(1, delta), local[:, 0])

    def _push_off(self, root, local) -> None:
        """Rolling from the back, the top leg sets its foot on the floor beside the buttock and
        pushes: the ankle stays on its floor point while the pelvis turns (the knee bending about
        the hip's own hinge axis, so the thigh turns with the pelvis and the foot rolls onto its
        edge), and the body rolls over a support on the side it leaves rather than tipping over
        its edge. The floor phases' height and position are then solved again with that leg."""
        r, c = _ROLL, self.curve
        bottom, top = self._roll_sides()
        i0 = self._index("roll")
        body_pos, _ = forward_kinematics(root, local, OFFSETS)
        hip0 = body_pos[i0, B[f"{top}_Hip"]]
        feet = _normalize(body_pos[i0, B["Pelvis"], :2] - body_pos[i0, B["Head"], :2])
        out = _normalize(hip0[:2] - body_pos[i0, B[f"{bottom}_Hip"], :2])
        planted = np.append(hip0[:2] + r["foot_along"] * feet + r["foot_out"] * out, _ANKLE_HEIGHT)
        lying = body_pos[:, B[f"{top}_Ankle"]]
        u = c([(("roll", r["plant"][0]), 0.0), (("roll", r["plant"][1]), 1.0)])
        ankle = lying + u[:, None] * (planted - lying)
        ankle[:, 2] += 0.08 * np.sin(np.pi * u)  # lifted on the way
        hip = body_pos[:, B[f"{top}_Hip"]]
        thigh, shank, c0, rr, phi = _knee_terms(top)
        d = ankle - hip
        k = phi + np.arccos(np.clip((np.sum(d * d, -1) - c0) / (2 * rr), -1.0, np.cos(MIN_KNEE - phi)))
        leg_rest = thigh + quat_apply(_axis_quat(1, k), shank)  # hip -> ankle in the hip's rest frame
        pelvis_m = quat_to_matrix(local[:, 0])
        # the knee bends about the pelvis' own left axis (the hip's flexion hinge), not a level one
        hip_world = _frame(d, pelvis_m[:, :, 1]) @ np.swapaxes(_frame(leg_rest, np.array([0.0, 1.0, 0.0])), -1, -2)
        solved = {"Hip": quat_from_matrix(np.swapaxes(pelvis_m, -1, -2) @ hip_world), "Knee": _axis_quat(1, k),
                  # the foot at about a right angle to the shank, its sole towards the floor
                  "Ankle": _axis_quat(1, np.full(len(k), r["foot_flex"]))}
        w = c([(("roll", r["plant"][0]), 0.0), (("roll", r["plant"][1]), 1.0), (("roll", r["push"]), 1.0),
               (("roll", r["release"]), 0.0)])
        for joint, q in solved.items():
            j = B[f"{top}_{joint}"]
            local[:, j] = quat_slerp(local[:, j], q, w)
        # Solved once: the new contacts move the body a little (the pinning averages over all of
        # them), so the planted foot drifts a few cm over the push; iterating the two made the
        # leg's solution jump between frames at the quick tempos.
        root[:, 2] = self._floor_height(root, local) - _SINK
        root[:, :2] = self._pinned(root, local)

    def _index(self, phase: str) -> int:
        return int(np.searchsorted(self.t, self.keys[phase] - 1e-9))

    def _floor_height(self, root, local) -> np.ndarray:
        """Pelvis height per frame that puts the lowest floor body (the arms aside) on the floor."""
        body_pos, body_quat = forward_kinematics(root * [1, 1, 0], local, OFFSETS)
        pts, reach = support_points_world(body_pos, body_quat, SKELETON)
        z = pts[:, self.floor_bodies][..., 2] - reach[self.floor_bodies]
        return -z.reshape(len(z), -1).min(1)

    def _pinned(self, root, local) -> np.ndarray:
        """Pelvis xy per frame such that the floor contacts common to consecutive frames do not
        move horizontally (their mean displacement is cancelled)."""
        body_pos, body_quat = forward_kinematics(root * [0, 0, 1], local, OFFSETS)
        pts, reach = support_points_world(body_pos, body_quat, SKELETON)
        pts, reach = pts[:, self.floor_bodies], reach[self.floor_bodies]
        touch = pts[..., 2] - reach < 0.015
        both = (touch[1:] & touch[:-1])[..., None]  # (T-1, bodies, K, 1)
        moved = np.where(both, pts[1:, ..., :2] - pts[:-1, ..., :2], 0.0).sum((1, 2))
        delta = moved / np.maximum(both.sum((1, 2)), 1)  # no common contact: no correction
        return np.concatenate([np.zeros((1, 2)), -np.cumsum(delta, axis=0)])

    def _slide_knees(self, root, local) -> None:
        """While pushing onto hands and knees, move the body forward by `_KNEE_SLIDE` of the way
        its shoulders travel back, so the knees slide under the hips for that share; the offset
        holds from then on."""
        body_pos, _ = forward_kinematics(root, local, OFFSETS)
        shoulders = body_pos[:, [B["L_Shoulder"], B["R_Shoulder"]], :2].mean(1)
        i0, i1 = self._index("push"), self._index("kneel")
        w = _KNEE_SLIDE * self.curve([("push", 0.0), ("kneel", 1.0)])
        shift = w[:, None] * (shoulders[i0] - shoulders)
        shift[i1:] = shift[i1]
        root[:, :2] += shift

    def _hand_targets(self, root, local):
        """Floor points of the hands: beside and a little ahead of where the shoulders are on
        hands and knees, fixed from the moment the hands are down until they lift."""
        body_pos, _ = forward_kinematics(root, local, OFFSETS)
        i = self._index("bear")
        chest = body_pos[i, B["Chest"], :2]
        forward = _normalize(body_pos[i, B["Head"], :2] - body_pos[i, B["Pelvis"], :2])
        left = np.array([-forward[1], forward[0]])
        targets = {}
        for s, sign in SIDES.items():
            along = (body_pos[i, B[f"{s}_Shoulder"], :2] - chest) @ forward
            xy = chest + (along + self.hand_ahead) * forward + sign * self.hand_width * left
            targets[s] = np.concatenate([xy, [0.0]])
        return targets

    def _solve_arms(self, root, local, free, targets, w):
        """Shoulder and elbow rotations: the free posture; where `w` > 0 the hand is aimed at the
        point blending where the free posture puts it (w = 0) and its floor target (w = 1), so a
        hand is put down and lifted along a path, never through the floor."""
        for s in SIDES:
            upper, elbow, twist = (np.array(a, float) for a in free[s])
            _, body_quat = forward_kinematics(root, local, OFFSETS)
            _solve_arm(s, body_quat[:, B["Chest"]], body_quat[:, B[f"{s}_Thorax"]], upper, elbow, twist, local)
            if targets is None:
                continue
            free_low = self._hand_low(root, local, s)
            aim = (1 - w[:, None]) * free_low + w[:, None] * targets[s]
            aim[:, 2] = np.maximum(aim[:, 2], 0.0)
            on = w > 0
            upper_f, elbow_f = self._reach(root[on], local[on], s, aim[on], upper[on], elbow[on], twist[on])
            upper, elbow = upper.copy(), elbow.copy()
            upper[on], elbow[on] = upper_f, elbow_f
            _solve_arm(s, body_quat[:, B["Chest"]], body_quat[:, B[f"{s}_Thorax"]], upper, elbow, twist, local)

    @staticmethod
    def _hand_low(root, local, s):
        """World point (T, 3) of the lowest point of a hand's geometry."""
        pos, q = forward_kinematics(root, local, OFFSETS)
        pts, reach = support_points_world(pos, q, SKELETON)
        hand = B[f"{s}_Hand"]
        z = pts[:, hand, :, 2] - reach[hand]
        k = np.argmin(z, axis=1)
        low = pts[np.arange(len(k)), hand, k].copy()
        low[:, 2] -= reach[hand][k]
        return low

    def _reach(self, root, local, s, aim, upper, elbow, twist):
        """Upper-arm direction (chest frame) and elbow flexion that put the hand's lowest point
        on `aim` (T, 3), _HAND_REST above it where it is on the floor."""
        work = local.copy()
        upper, elbow = upper.copy(), elbow.copy()
        l1 = np.linalg.norm(OFFSETS[B[f"{s}_Elbow"]])
        l2 = np.linalg.norm(OFFSETS[B[f"{s}_Wrist"]])
        goal_low = aim + [0, 0, _HAND_REST]
        for _ in range(40):
            _, q = forward_kinematics(root, work, OFFSETS)
            chest_q = q[:, B["Chest"]]
            _solve_arm(s, chest_q, q[:, B[f"{s}_Thorax"]], upper, elbow, twist, work)
            pos, _ = forward_kinematics(root, work, OFFSETS)
            wrist_goal = pos[:, B[f"{s}_Wrist"]] + (goal_low - self._hand_low(root, work, s))
            shoulder = pos[:, B[f"{s}_Shoulder"]]
            to_goal = wrist_goal - shoulder
            d = np.clip(np.linalg.norm(to_goal, axis=-1), abs(l1 - l2) + 1e-3, l1 + l2 - 1e-3)
            elbow = np.pi - np.arccos(np.clip((l1 ** 2 + l2 ** 2 - d ** 2) / (2 * l1 * l2), -1, 1))
            to_wrist = pos[:, B[f"{s}_Wrist"]] - shoulder
            # turn the upper arm by the rotation taking the current wrist direction to the goal's
            rot = _rotation_between(_normalize(to_wrist), _normalize(to_goal))
            upper = quat_apply(quat_inv(chest_q), quat_apply(rot, quat_apply(chest_q, upper)))
        return upper, elbow

    def _leg_targets(self, root, local, i_bear):
        """IK targets of both legs from the bear stance on (before it they are hinge angles): the
        tucked toes come down onto the floor, the knees lift, each foot walks in on its turn."""
        t, n = self.t, len(self.t)
        body_pos, body_quat = forward_kinematics(root, local, OFFSETS)
        legs = _standing_legs(t, width=_FEET["width"])
        hands = np.mean([xyz[:2] for xyz in self._hand_targets(root, local).values()], axis=0)
        # the pelvis' heading, which the feet keep: a foot turned from it twists its hip, and a hip
        # flexed 90 deg with any twist flips its x-y-z hinges
        forward = _normalize(quat_apply(local[i_bear, 0], np.array([0.0, 0.0, 1.0]))[:2])
        left = np.array([-forward[1], forward[0]])
        yaw = float(np.arctan2(forward[1], forward[0]))
        down = self.curve([("bear", 0.0), (("bear", 0.3), 1.0)])  # toes onto the floor
        heel = self.curve([("crouch", _FEET["heel_land"]), (("crouch", 0.8), 0.0)])
        for phase, s in (("foot_1", self.side), ("foot_2", self.back)):
            leg = legs[s]
            ball = np.tile(body_pos[i_bear, B[f"{s}_Toe"]], (n, 1))
            ball[:, 2] += down * (BALL_HEIGHT[s] - ball[:, 2])
            land = np.append(hands - _FEET["behind"] * forward + SIDES[s] * _FEET["width"] * left, BALL_HEIGHT[s])
            u = _minjerk((t - self.keys[phase]) / (self.keys[_NEXT[phase]] - self.keys[phase]))
            leg.ball = ball + u[:, None] * (land - ball)
            leg.ball[:, 2] += _FEET["swing"] * np.sin(np.pi * u)
            leg.foot_yaw = np.full(n, yaw)
            tucked = self._foot_pitch(body_quat[i_bear, B[f"{s}_Ankle"]], yaw)
            leg.foot_pitch = (1 - u) * ((1 - down) * tucked + down * _FEET["ball_pitch"]) + u * heel
            leg.grounded = (u <= 0) | (u >= 1)
            # the toe segment: as tucked (50 deg to the foot) until the toes are down, then flat
            leg.toe_flat = np.clip((1 - down) * (50 * DEG / max(tucked, 1e-3)) + down, 0, 1)
        return legs

    @staticmethod
    def _foot_pitch(foot_quat, yaw) -> float:
        """The foot's pitch about its yawed left axis, up to 180 degrees (a tucked foot points
        back and down)."""
        x = quat_apply(foot_quat, [1.0, 0.0, 0.0])
        return float(np.arctan2(-x[2], x[0] * np.cos(yaw) + x[1] * np.sin(yaw)))

    @staticmethod
    def _solve_legs(spec, local, i0):
        solved = local.copy()
        for side in SIDES:
            _solve_leg(spec, side, solved)
            for j in ("Hip", "Knee", "Ankle", "Toe"):
                local[i0:, B[f"{side}_{j}"]] = solved[i0:, B[f"{side}_{j}"]]

    def toe_curve(self, side: str) -> np.ndarray:
        """The toes' hinge on the floor: tucked under once on hands and knees (the legs' IK takes
        over from the bear stance)."""
        return self.curve([("lie", 0.0), ("hands", 0.0), ("kneel", -50 * DEG)])

    def _rise(self, spec, local, i_bear):
        """The pelvis from the bear stance to the end. Until the knees lift the legs rest on the
        floor; then the pelvis follows `_PELVIS_HEIGHT` (where the legs reach); from the crouch
        on it moves so that the centre of mass comes over the feet before the hands lift."""
        c, root = self.curve, spec.pelvis_pos
        root[i_bear:, :2] = root[i_bear, :2]
        height = c(_PELVIS_HEIGHT)
        knees_up = c([(("bear", 0.45), 0.0), ("foot_1", 1.0)])
        i_up = int(np.argmax(knees_up > 0))
        feet = 0.5 * sum(spec.legs[s].ball + quat_apply(yaw_quat(spec.legs[s].foot_yaw), FOOT_CENTRE[s])
                         for s in SIDES)[:, :2]
        i_crouch = self._index("crouch")
        over = c([("crouch", 0.0), (("crouch", _OVER_FEET), 1.0)])[:, None]
        for k in range(6):
            reach = np.minimum(_max_pelvis_height(spec, "L"), _max_pelvis_height(spec, "R")) - 0.01
            self._solve_legs(spec, local, i_bear)
            floor = self._floor_height(root, local) - _SINK
            floor[i_up:] = floor[i_up]
            root[i_bear:, 2] = np.minimum(floor + knees_up * (height - floor), reach)[i_bear:]
            self._solve_legs(spec, local, i_bear)
            com = centre_of_mass(*forward_kinematics(root, local, OFFSETS), SKELETON)[:, :2]
            if k == 0:
                com_crouch = com[i_crouch].copy()
            root[i_crouch:, :2] += ((1 - over) * com_crouch + over * feet - com)[i_crouch:]
        # the last move was horizontal: lower the pelvis where that took a foot out of reach
        reach = np.minimum(_max_pelvis_height(spec, "L"), _max_pelvis_height(spec, "R")) - 0.01
        root[i_bear:, 2] = np.minimum(root[:, 2], reach)[i_bear:]
        self._solve_legs(spec, local, i_bear)


def _smooth(x, radius: int):
    """Gaussian smoothing, sigma radius / 2, truncated at the radius, edges repeated (the clip's
    drawn parameters are tuned with exactly this one)."""
    taps = np.exp(-0.5 * (np.arange(-radius, radius + 1) / (radius / 2)) ** 2)
    return np.convolve(np.pad(x, radius, mode="edge"), taps / taps.sum(), mode="valid")


def _rotation_between(a, b):
    """Quaternions (..., 4) of the shortest rotation taking unit vectors a to b."""
    w = 1.0 + np.sum(a * b, -1, keepdims=True)
    q = np.concatenate([w, np.cross(a, b)], -1)
    return q / np.linalg.norm(q, axis=-1, keepdims=True)
