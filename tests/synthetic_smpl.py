"""A small synthetic model file in the SMPL format, for tests (the real SMPL model is licensed).

It is not a human mesh: each of the 24 bones is a cloud of ~70 vertices on the surface of the
primitive of REFERENCE.md's mean-shape table, inflated back to the size it had before the table's
shrink factors (hips' capsules / 0.7, pelvis sphere / 0.6, ...), so that the SMPL -> humanoid recipe
run on this file gives back that table. Each joint also has a ring of 8 vertices centred on it, and
J_regressor averages the ring, so with betas = 0 the regressed joints are REFERENCE.md's mean
skeleton exactly (MEAN_OFFSETS, pelvis at MEAN_PELVIS_SMPL).

Shape components (per unit beta): 0 scales the whole body by 6 % about SMPL's origin (taller),
1 fattens every bone by 10 % without moving joints, 2 lengthens the legs by 8 %, 3 widens the
shoulders by 3 cm, 4 lengthens the arms by 6 %, later ones move each bone by a few mm at random.

Everything is built in the humanoid's z-up body frame and written in SMPL's y-up frame.
"""

from __future__ import annotations

import pickle
import sys
import types
from pathlib import Path

import numpy as np
from scipy.optimize import brentq
from scipy.spatial import ConvexHull

from smpl_envs.humanoid.skeleton import (
    BODY_NAMES, MEAN_GEOMS, MEAN_OFFSETS, MEAN_PELVIS_SMPL, NUM_BODIES, PARENTS,
    SMPL_JOINT_OF_BODY, SMPL_TO_BODY_FRAME,
)

# The table's shrink factors, undone here so the recipe's shrink lands back on the table.
_SHRINK = {"Pelvis": 0.6, "Torso": 0.7, "Spine": 0.7, "Chest": 0.7, "L_Hip": 0.7, "R_Hip": 0.7,
           "L_Knee": 0.9, "R_Knee": 0.9}
_RING_RADIUS = 0.01
_RING_SIZE = 8
_ROOT_PARENT = 2**32 - 1  # how the SMPL release writes the root's parent in kintree_table
_LEGS = ("Hip", "Knee", "Ankle", "Toe")
_ARMS = ("Thorax", "Shoulder", "Elbow", "Wrist", "Hand")


def mean_joints_body() -> np.ndarray:
    """(24, 3) rest joints of the mean shape, body frame, BODY_NAMES order."""
    joints = np.zeros((NUM_BODIES, 3))
    joints[0] = SMPL_TO_BODY_FRAME @ MEAN_PELVIS_SMPL
    for i in range(1, NUM_BODIES):  # parents precede children
        joints[i] = joints[PARENTS[i]] + MEAN_OFFSETS[i]
    return joints


def _basis(u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    u = u / np.linalg.norm(u)
    helper = np.eye(3)[np.argmin(np.abs(u))]
    e1 = np.cross(u, helper)
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(u, e1)


def _ring(u: np.ndarray, radius: float, n: int) -> np.ndarray:
    """n points on a circle about the origin, perpendicular to u: their mean is the origin."""
    e1, e2 = _basis(u)
    t = 2 * np.pi * np.arange(n) / n
    return radius * (np.cos(t)[:, None] * e1 + np.sin(t)[:, None] * e2)


def _capsule_surface(a, b, radius, n_around=12, n_lat=3) -> tuple[np.ndarray, np.ndarray]:
    """Points on a capsule's surface and, per point, the axis point it sits over."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    u = (b - a) / np.linalg.norm(b - a)
    circle = _ring(u, 1.0, n_around)
    lat = np.linspace(0.0, np.pi / 2, n_lat + 1)[:-1]  # equator up to (not incl.) the pole
    pts, centres = [], []
    for end, sign in ((a, -1.0), (b, 1.0)):
        cap = radius * (np.cos(lat)[:, None, None] * circle + sign * np.sin(lat)[:, None, None] * u)
        pts += [end + cap.reshape(-1, 3), (end + sign * radius * u)[None]]
        centres += [np.repeat(end[None], len(lat) * n_around + 1, 0)]
    return np.concatenate(pts), np.concatenate(centres)


def _sphere_surface(radius, n=64) -> np.ndarray:
    """Fibonacci points on a sphere about the origin."""
    k = np.arange(n) + 0.5
    z = 1 - 2 * k / n
    phi = np.pi * (1 + 5**0.5) * k
    rho = np.sqrt(1 - z**2)
    return radius * np.stack([rho * np.cos(phi), rho * np.sin(phi), z], -1)


def _box_surface(pos, half) -> np.ndarray:
    """Corners, edge midpoints and face centres of a box."""
    grid = np.stack(np.meshgrid(*[[-1.0, 0.0, 1.0]] * 3, indexing="ij"), -1).reshape(-1, 3)
    grid = grid[np.abs(grid).max(1) == 1]  # drop the centre
    return np.asarray(pos) + grid * np.asarray(half)


def _fit_to_volume(make, volume, r0) -> np.ndarray:
    """Scale a point-cloud family make(r) so its convex hull has exactly `volume`."""
    r = brentq(lambda r: ConvexHull(make(r)).volume - volume, 0.5 * r0, 2.0 * r0, xtol=1e-10)
    return make(r)


def _bone_cloud(i: int, ring: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Vertices of body i (body frame, relative to its joint) and the centre each bulges from."""
    g, name = MEAN_GEOMS[i], BODY_NAMES[i]
    s = _SHRINK.get(name, 1.0)
    if g.kind == "box":
        pts = _box_surface(g.pos, g.size)
        return pts, np.repeat(np.asarray(g.pos)[None], len(pts), 0)
    if g.kind == "sphere":
        r = g.size[0] / s
        pts = _fit_to_volume(lambda q: np.vstack([_sphere_surface(q), ring]),
                             4 / 3 * np.pi * r**3, r)[: -len(ring)]
        return pts, np.zeros_like(pts)
    a, b = np.reshape(g.fromto, (2, 3))
    r, length = g.size[0] / s, np.linalg.norm(b - a)
    volume = np.pi * r**2 * length + 4 / 3 * np.pi * r**3
    pts = _fit_to_volume(lambda q: np.vstack([_capsule_surface(a, b, q)[0], ring]), volume, r)
    return pts[: -len(ring)], _capsule_surface(a, b, r)[1]


def _bone_direction(i: int) -> np.ndarray:
    children = np.flatnonzero(PARENTS == i)
    return MEAN_OFFSETS[children].mean(0) if len(children) else MEAN_OFFSETS[i]


def build_synthetic_smpl(num_betas: int = 10, seed: int = 0) -> dict:
    """The model as a dict of arrays in SMPL's conventions (y-up frame, SMPL joint order)."""
    joints = mean_joints_body()
    verts, centres, owner, faces, ring_idx = [], [], [], [], []
    count = 0
    for i in range(NUM_BODIES):
        ring = _ring(_bone_direction(i), _RING_RADIUS, _RING_SIZE)
        surface, surface_centres = _bone_cloud(i, ring)
        pts = np.vstack([surface, ring])
        faces.append(ConvexHull(pts).simplices + count)
        ring_idx.append(count + len(surface) + np.arange(_RING_SIZE))
        verts.append(joints[i] + pts)
        centres.append(joints[i] + np.vstack([surface_centres, np.zeros_like(ring)]))
        owner.append(np.full(len(pts), i))
        count += len(pts)
    v, centre, owner = np.concatenate(verts), np.concatenate(centres), np.concatenate(owner)
    nv = len(v)

    # Skinning mostly to the own bone, some to the parent (as a real mesh blends near joints).
    weights = np.zeros((nv, NUM_BODIES))
    smpl_owner, smpl_parent = SMPL_JOINT_OF_BODY[owner], SMPL_JOINT_OF_BODY[PARENTS[owner]]
    has_parent = owner > 0
    weights[np.arange(nv), smpl_owner] = np.where(has_parent, 0.8, 1.0)
    weights[np.flatnonzero(has_parent), smpl_parent[has_parent]] += 0.2

    regressor = np.zeros((NUM_BODIES, nv))
    for i, idx in enumerate(ring_idx):
        regressor[SMPL_JOINT_OF_BODY[i], idx] = 1.0 / _RING_SIZE

    dirs = _shape_directions(v, centre, owner, joints, num_betas, seed)
    to_smpl = SMPL_TO_BODY_FRAME  # row vectors: v_smpl = v_body @ M (M orthogonal)
    smpl_parents = np.full(NUM_BODIES, _ROOT_PARENT, dtype=np.int64)
    smpl_parents[SMPL_JOINT_OF_BODY[1:]] = SMPL_JOINT_OF_BODY[PARENTS[1:]]
    return {
        "v_template": v @ to_smpl,
        "shapedirs": np.einsum("vkb,kl->vlb", dirs, to_smpl),
        "J_regressor": regressor,
        "weights": weights,
        "kintree_table": np.stack([smpl_parents, np.arange(NUM_BODIES)]),
        "f": np.concatenate(faces).astype(np.uint32),
        "J": regressor @ (v @ to_smpl),
    }


def _shape_directions(v, centre, owner, joints, num_betas, seed) -> np.ndarray:
    """(V, 3, num_betas) vertex displacement per unit beta, body frame."""
    names = np.array(BODY_NAMES)[owner]
    part = np.array([n.split("_")[-1] for n in names])
    leg, arm = np.isin(part, _LEGS), np.isin(part, _ARMS)
    side = np.where(np.char.startswith(names, "L_"), 1.0, -1.0)[:, None]
    thorax = joints[[BODY_NAMES.index("L_Thorax" if s > 0 else "R_Thorax") for s in side[:, 0]]]
    up = np.array([0.0, 0.0, 1.0])

    comps = [
        0.06 * v,                                                 # taller / shorter overall
        0.10 * (v - centre),                                      # girth; ring means stay put
        0.08 * leg[:, None] * ((v - joints[0]) @ up)[:, None] * up,  # longer legs
        0.03 * arm[:, None] * side * np.array([0.0, 1.0, 0.0]),   # broader shoulders
        0.06 * arm[:, None] * (v - thorax),                       # longer arms
    ]
    rng = np.random.default_rng(seed)
    while len(comps) < num_betas:  # small rigid shifts of each bone
        comps.append(rng.normal(0.0, 0.004, (NUM_BODIES, 3))[owner])
    return np.stack(comps[:num_betas], -1)


class _FakeCh:
    """Pickles like chumpy's basic `Ch`: state is its __dict__ with the value in `x`."""

    def __init__(self, x):
        self.x = np.asarray(x)

    def __getstate__(self):
        return {"x": self.x, "_dirty_vars": set(), "_itr": None, "_depends_on_deps": {},
                "_make_dense": False, "_make_sparse": False}


def _pickle_release_like(data: dict, chumpy: bool, protocol: int = 2) -> bytes:
    import scipy.sparse as sp

    obj = dict(data)
    obj["J_regressor"] = sp.csc_matrix(data["J_regressor"])
    obj.update(bs_style="lbs", bs_type="lrotmin")
    if not chumpy:
        return pickle.dumps(obj, protocol=protocol)
    # Register a throwaway `chumpy.ch` module for the pickler's class lookup, then remove it.
    saved = {k: sys.modules.get(k) for k in ("chumpy", "chumpy.ch")}
    pkg, mod = types.ModuleType("chumpy"), types.ModuleType("chumpy.ch")
    ch = type("Ch", (_FakeCh,), {"__module__": "chumpy.ch", "__qualname__": "Ch"})
    mod.Ch, pkg.ch = ch, mod
    sys.modules.update({"chumpy": pkg, "chumpy.ch": mod})
    try:
        for key in ("v_template", "shapedirs", "J"):
            obj[key] = ch(data[key])
        raw = pickle.dumps(obj, protocol=protocol)
    finally:
        for k, m in saved.items():
            if m is None:
                sys.modules.pop(k, None)
            else:
                sys.modules[k] = m
    # Name classes the way the 2015 release (numpy 1, scipy < 1.8) does; protocols 0 to 2 write
    # them as text lines, so this is a plain substitution.
    return (raw.replace(b"cnumpy._core.multiarray\n", b"cnumpy.core.multiarray\n")
               .replace(b"cscipy.sparse._csc\n", b"cscipy.sparse.csc\n"))


def write_synthetic_smpl(path, fmt: str = "npz", num_betas: int = 10, *, chumpy: bool = False,
                         protocol: int = 2, seed: int = 0) -> Path:
    """Write the synthetic model to `path` as .npz (dense arrays) or a release-like .pkl
    (sparse J_regressor, pickle `protocol` 0 to 2 as Python 2 wrote; `chumpy=True` wraps
    v_template, shapedirs and J in a fake chumpy Ch under the release's legacy class names)."""
    path = Path(path)
    data = build_synthetic_smpl(num_betas, seed)
    if fmt == "npz":
        with open(path, "wb") as fh:  # np.savez would append .npz to other suffixes
            np.savez(fh, **data)
    elif fmt == "pkl":
        if not 0 <= protocol <= 2:
            raise ValueError("the legacy class names need a text protocol: 0, 1 or 2")
        path.write_bytes(_pickle_release_like(data, chumpy, protocol))
    else:
        raise ValueError(f"fmt must be 'npz' or 'pkl', got {fmt!r}")
    return path
