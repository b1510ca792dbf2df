"""SMPL skeleton facts: body order, parents, mean-shape offsets, geometry, masses and PD gains.

Every number here is from ../shared/REFERENCE.md section 1 (the neutral SMPL mean shape). Body rest
frames are world-aligned: z up, metres, the humanoid facing +x with its left on +y. SMPL's own
canonical frame is y-up facing +z with its left on +x; `SMPL_TO_BODY_FRAME` converts between them.

A `Skeleton` is the one description of a body that both the MJCF builder and the motion library
read, so the reference motion and the simulated humanoid can never disagree about bone lengths.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

BODY_NAMES: tuple[str, ...] = (
    "Pelvis", "L_Hip", "L_Knee", "L_Ankle", "L_Toe", "R_Hip", "R_Knee", "R_Ankle", "R_Toe",
    "Torso", "Spine", "Chest", "Neck", "Head", "L_Thorax", "L_Shoulder", "L_Elbow", "L_Wrist",
    "L_Hand", "R_Thorax", "R_Shoulder", "R_Elbow", "R_Wrist", "R_Hand",
)
NUM_BODIES = len(BODY_NAMES)
NUM_HINGES = 3 * (NUM_BODIES - 1)  # 69: x, y, z hinges of every body but the pelvis

PARENTS = np.array(
    [-1, 0, 1, 2, 3, 0, 5, 6, 7, 0, 9, 10, 11, 12, 11, 14, 15, 16, 17, 11, 19, 20, 21, 22]
)
# Body i is SMPL joint SMPL_JOINT_OF_BODY[i]; used to reorder AMASS / SMPL arrays.
SMPL_JOINT_OF_BODY = np.array(
    [0, 1, 4, 7, 10, 2, 5, 8, 11, 3, 6, 9, 12, 15, 13, 16, 18, 20, 22, 14, 17, 19, 21, 23]
)
HINGE_AXES = ("x", "y", "z")
HINGE_NAMES: tuple[str, ...] = tuple(f"{b}_{a}" for b in BODY_NAMES[1:] for a in HINGE_AXES)

# v_body = SMPL_TO_BODY_FRAME @ v_smpl: SMPL (x, y, z) = (left, up, forward) -> (forward, left, up).
SMPL_TO_BODY_FRAME = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])

# Parent-to-child joint offsets of the neutral mean shape (body frame, metres).
MEAN_OFFSETS = np.array([
    [0.0, 0.0, 0.0],
    [-0.0068, 0.0695, -0.0914], [-0.0045, 0.0343, -0.3752], [-0.0437, -0.0136, -0.3980],
    [0.1193, 0.0264, -0.0558],
    [-0.0043, -0.0677, -0.0905], [-0.0089, -0.0383, -0.3826], [-0.0423, 0.0158, -0.3984],
    [0.1233, -0.0254, -0.0481],
    [-0.0267, -0.0025, 0.1090], [0.0011, 0.0055, 0.1352], [0.0254, 0.0015, 0.0529],
    [-0.0429, -0.0028, 0.2139], [0.0513, 0.0052, 0.0650],
    [-0.0341, 0.0788, 0.1217], [-0.0089, 0.0910, 0.0305], [-0.0275, 0.2596, -0.0128],
    [-0.0012, 0.2492, 0.0090], [-0.0149, 0.0840, -0.0082],
    [-0.0386, -0.0818, 0.1188], [-0.0091, -0.0960, 0.0326], [-0.0214, -0.2537, -0.0133],
    [-0.0056, -0.2553, 0.0078], [-0.0103, -0.0846, -0.0061],
])
# Rest pelvis joint of the neutral mean shape in SMPL's y-up frame: AMASS `trans` + this = pelvis.
MEAN_PELVIS_SMPL = np.array([-0.0018, -0.2233, 0.0282])


@dataclass(frozen=True)
class Geom:
    """One collision geom in its body's frame.

    kind: "sphere" (size = (r,), pos), "capsule" (size = (r,), fromto), "box" (size = half extents,
    pos) or "mesh" (vertices). mass in kg.
    """

    kind: str
    size: tuple[float, ...]
    mass: float
    pos: tuple[float, float, float] = (0.0, 0.0, 0.0)
    fromto: tuple[float, ...] | None = None
    vertices: np.ndarray | None = None


def _capsule(r, a, b, m):
    return Geom("capsule", (r,), m, fromto=tuple(a) + tuple(b))


MEAN_GEOMS: tuple[Geom, ...] = (
    Geom("sphere", (0.0942,), 16.21),
    _capsule(0.0615, (-0.0036, 0.0274, -0.3002), (-0.0009, 0.0069, -0.0750), 7.47),
    _capsule(0.0541, (-0.0350, -0.0109, -0.3184), (-0.0087, -0.0027, -0.0796), 3.55),
    Geom("box", (0.085, 0.0483, 0.0464), 1.52, pos=(0.0242, 0.0233, -0.0239)),
    Geom("box", (0.0496, 0.0478, 0.02), 0.38, pos=(0.0248, -0.003, 0.0055)),
    _capsule(0.0606, (-0.0071, -0.0306, -0.3061), (-0.0018, -0.0077, -0.0765), 7.34),
    _capsule(0.0541, (-0.0338, 0.0126, -0.3187), (-0.0085, 0.0032, -0.0797), 3.55),
    Geom("box", (0.0865, 0.0483, 0.0478), 1.60, pos=(0.0256, -0.0212, -0.0174)),
    Geom("box", (0.0493, 0.0479, 0.0216), 0.41, pos=(0.0227, 0.0042, 0.0045)),
    _capsule(0.0769, (0.0006, 0.003, 0.0743), (0.0005, 0.0025, 0.0608), 4.40),
    _capsule(0.0755, (0.014, 0.0008, 0.0291), (0.0114, 0.0007, 0.0238), 3.89),
    _capsule(0.1002, (-0.0212, -0.001, 0.0833), (-0.0173, -0.0009, 0.0682), 9.60),
    _capsule(0.0436, (0.0411, 0.0041, 0.052), (0.0103, 0.001, 0.013), 0.64),
    Geom("sphere", (0.1011,), 4.33),
    _capsule(0.0521, (-0.0071, 0.0728, 0.0244), (-0.0018, 0.0182, 0.0061), 1.09),
    _capsule(0.0517, (-0.022, 0.2077, -0.0102), (-0.0055, 0.0519, -0.0026), 1.90),
    _capsule(0.0405, (-0.0009, 0.1994, 0.0072), (-0.0002, 0.0498, 0.0018), 1.05),
    _capsule(0.0318, (-0.012, 0.0672, -0.0065), (-0.003, 0.0168, -0.0016), 0.30),
    Geom("sphere", (0.0337,), 0.16),
    _capsule(0.0511, (-0.0073, -0.0768, 0.026), (-0.0018, -0.0192, 0.0065), 1.06),
    _capsule(0.0531, (-0.0171, -0.203, -0.0107), (-0.0043, -0.0507, -0.0027), 1.98),
    _capsule(0.0408, (-0.0044, -0.2042, 0.0062), (-0.0011, -0.0511, 0.0016), 1.09),
    _capsule(0.0326, (-0.0083, -0.0677, -0.0049), (-0.0021, -0.0169, -0.0012), 0.32),
    Geom("sphere", (0.0340,), 0.16),
)
MEAN_MASS = sum(g.mass for g in MEAN_GEOMS)  # 74.0 kg: the body the listed gains were tuned for

# PD gains per body (kp N*m/rad, kd N*m*s/rad, torque limit N*m), the same for its 3 hinges.
_GAINS_BY_PART = {
    ("Hip", "Knee", "Ankle"): (800.0, 80.0, 1000.0),
    ("Toe",): (500.0, 50.0, 500.0),
    ("Torso", "Spine", "Chest"): (1000.0, 100.0, 500.0),
    ("Neck", "Head"): (500.0, 50.0, 250.0),
    ("Thorax", "Shoulder"): (500.0, 50.0, 1000.0),
    ("Elbow",): (500.0, 50.0, 250.0),
    ("Wrist", "Hand"): (300.0, 30.0, 250.0),
}


def _part(name: str) -> str:
    return name.split("_")[-1]


def _gain_row(name: str) -> tuple[float, float, float]:
    for parts, row in _GAINS_BY_PART.items():
        if _part(name) in parts:
            return row
    raise KeyError(name)


# (69,) arrays in HINGE_NAMES order.
KP, KD, TORQUE_LIMIT = (
    np.repeat(np.array([_gain_row(n)[k] for n in BODY_NAMES[1:]]), 3) for k in range(3)
)

# Action a in [-1, 1] maps to a PD target of ACTION_SCALE * a radians. PHC widens knee flexion
# (the y hinge: knees bend about the body's left axis) to 5 rad so a deep squat is reachable.
ACTION_SCALE = np.full(NUM_HINGES, np.pi)
for _knee in ("L_Knee_y", "R_Knee_y"):
    ACTION_SCALE[HINGE_NAMES.index(_knee)] = 5.0

# Anatomical hinge ranges in degrees (x = roll about forward, y = pitch about left, z = yaw about
# up), for the optional `joint_limits="anatomical"`. Generous: they stop impossible poses, not
# athletic ones. Left/right mirror by negating the x and z ranges.
_LEFT_LIMITS_DEG = {
    "Hip": ((-45, 90), (-140, 30), (-60, 45)),
    "Knee": ((-10, 10), (-5, 160), (-25, 25)),
    "Ankle": ((-35, 35), (-50, 50), (-40, 40)),
    "Toe": ((-10, 10), (-60, 45), (-10, 10)),
    "Thorax": ((-30, 30), (-20, 20), (-30, 30)),
    "Shoulder": ((-120, 90), (-100, 100), (-120, 90)),
    "Elbow": ((-20, 20), (-30, 30), (-160, 5)),  # the left elbow flexes about -z
    "Wrist": ((-80, 80), (-40, 40), (-80, 80)),
    "Hand": ((-20, 20), (-20, 20), (-30, 30)),
}
_CENTRE_LIMITS_DEG = {
    "Torso": ((-40, 40), (-60, 50), (-45, 45)),
    "Spine": ((-30, 30), (-40, 40), (-30, 30)),
    "Chest": ((-30, 30), (-30, 30), (-30, 30)),
    "Neck": ((-40, 40), (-50, 60), (-60, 60)),
    "Head": ((-30, 30), (-40, 40), (-40, 40)),
}


def anatomical_limits() -> np.ndarray:
    """(69, 2) hinge ranges in radians, in HINGE_NAMES order."""
    rows = []
    for name in BODY_NAMES[1:]:
        part = _part(name)
        if part in _CENTRE_LIMITS_DEG:
            rows += _CENTRE_LIMITS_DEG[part]
            continue
        left = _LEFT_LIMITS_DEG[part]
        if name.startswith("L_"):
            rows += left
        else:  # mirror across the sagittal plane: roll and yaw flip sign
            (xl, xh), y, (zl, zh) = left
            rows += [(-xh, -xl), y, (-zh, -zl)]
    return np.deg2rad(np.array(rows, dtype=float))


@dataclass(frozen=True)
class Skeleton:
    """The body of one humanoid: joint offsets, collision geoms and masses, in BODY_NAMES order.

    offsets[i] is body i's joint relative to its parent's joint (offsets[0] is unused: the pelvis
    is placed by the free joint). pelvis_smpl is the rest pelvis joint in SMPL's y-up frame, which
    turns an AMASS `trans` into a pelvis position.
    """

    offsets: np.ndarray = field(default_factory=lambda: MEAN_OFFSETS.copy())
    geoms: tuple[Geom, ...] = MEAN_GEOMS
    pelvis_smpl: np.ndarray = field(default_factory=lambda: MEAN_PELVIS_SMPL.copy())
    betas: np.ndarray | None = None
    gender: str = "neutral"

    @property
    def mass(self) -> float:
        return float(sum(g.mass for g in self.geoms))

    def support_points(self) -> tuple[np.ndarray, np.ndarray]:
        """Points and radii whose lowest (z - r) is the lowest point of the body's geometry.

        Returns (points (24, K, 3), radii (24, K)) in each body's frame, padded by repeating a
        body's first point. Spheres give their centre, capsules their two ends, boxes their eight
        corners and meshes their vertices' hull (all of them: min over vertices is the hull's min).
        """
        per_body = []
        for g in self.geoms:
            if g.kind == "sphere":
                pts, r = np.array([g.pos]), g.size[0]
            elif g.kind == "capsule":
                pts, r = np.reshape(g.fromto, (2, 3)), g.size[0]
            elif g.kind == "box":
                corners = np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1])).T.reshape(-1, 3)
                pts, r = np.asarray(g.pos) + corners * np.asarray(g.size), 0.0
            elif g.kind == "mesh":
                pts, r = np.asarray(g.vertices), 0.0
            else:
                raise ValueError(f"unknown geom kind {g.kind!r}")
            per_body.append((pts, np.full(len(pts), r)))
        k = max(len(p) for p, _ in per_body)
        points = np.stack([np.concatenate([p, np.repeat(p[:1], k - len(p), 0)]) for p, _ in per_body])
        radii = np.stack([np.concatenate([r, np.repeat(r[:1], k - len(r))]) for _, r in per_body])
        return points, radii


MEAN_SKELETON = Skeleton()
