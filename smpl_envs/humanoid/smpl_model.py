"""A humanoid body from the user's own SMPL model file (.pkl as released, or .npz).

SMPL model files are licensed and never shipped: the user points
`build_humanoid(smpl_model_path=...)` at their copy. This module reads it without chumpy (the
official .pkl is a Python 2 pickle of chumpy objects) and turns a shape `betas` into a `Skeleton`,
the way REFERENCE.md section 1 says the mean humanoid was made:

- joints J = J_regressor @ (v_template + shapedirs @ betas), in SMPL's y-up frame, converted to the
  humanoid's z-up body frame and reordered to BODY_NAMES; offsets are child minus parent joint;
- each vertex belongs to the bone with its largest skinning weight, and that bone's convex hull
  gives its volume;
- capsules span 20 % to 80 % of the segment from the joint to (the mean of) its children's joints
  (45 % to 55 % for Torso, Spine, Chest), with the radius whose volume is the hull's, then shrunk
  x0.7 (Torso, Spine, Chest, hips) or x0.9 (knees); ankles and toes are boxes from their vertex
  bounds, the toe's sole level with the ankle's; Pelvis, Head and hands are spheres of the hull's
  volume (the pelvis shrunk x0.6, or it would swallow the hips);
- with `mesh=True` every body is its convex hull instead (SimPoE's mesh humanoid).

Mass. Density is 1000 kg/m^3 and a shrunk primitive keeps the mass of the volume it was shrunk
from (mass = geom volume * density / shrink^2 for capsules, / shrink^3 for the pelvis sphere);
boxes weigh their box volume. This is the rule behind REFERENCE.md's mean-shape table: it
reproduces every listed mass (Pelvis 16.21 kg = hull of radius 0.0942 / 0.6 at 1000 kg/m^3, hips
7.47 kg, Torso 4.40 kg, ankle box 1.52 kg, ...) and its 74.0 kg total. Charging shrunk capsules
their full hull volume instead would make the mean body ~8 kg heavier than the table. The mesh
humanoid uses the same per-body masses, so both variants of one shape weigh the same and get the
same PD gains.
"""

from __future__ import annotations

import io
import pickle
import warnings
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial import ConvexHull, QhullError

from .skeleton import (
    BODY_NAMES, NUM_BODIES, PARENTS, SMPL_JOINT_OF_BODY, SMPL_TO_BODY_FRAME, Geom, Skeleton,
)

DENSITY = 1000.0  # kg/m^3: reproduces REFERENCE.md's 74.0 kg mean body (see module docstring)

# SMPL's kinematic tree in SMPL joint order, derived from the body-order tree so the two never
# disagree: body i is SMPL joint SMPL_JOINT_OF_BODY[i].
SMPL_PARENTS = np.full(NUM_BODIES, -1)
SMPL_PARENTS[SMPL_JOINT_OF_BODY[1:]] = SMPL_JOINT_OF_BODY[PARENTS[1:]]
BODY_OF_SMPL_JOINT = np.argsort(SMPL_JOINT_OF_BODY)

# Geometry recipe per body (REFERENCE.md section 1, "How those were made").
_SPHERES = {"Pelvis": 0.6, "Head": 1.0, "L_Hand": 1.0, "R_Hand": 1.0}  # name -> radius shrink
_BOXES = ("L_Ankle", "L_Toe", "R_Ankle", "R_Toe")
_CAPSULE_SHRINK = {"Torso": 0.7, "Spine": 0.7, "Chest": 0.7, "L_Hip": 0.7, "R_Hip": 0.7,
                   "L_Knee": 0.9, "R_Knee": 0.9}
_CAPSULE_SPAN = {"Torso": 0.45, "Spine": 0.45, "Chest": 0.45}  # else 0.2: capsule = [s, 1 - s]

_REQUIRED_KEYS = ("v_template", "shapedirs", "J_regressor", "weights", "kintree_table")
# Official release names, so a directory of SMPL models can be given instead of one file.
_MODEL_FILE_NAMES = {
    "neutral": ("SMPL_NEUTRAL", "basicmodel_neutral_lbs_10_207_0_v1.1.0",
                "basicModel_neutral_lbs_10_207_0_v1.0.0"),
    "male": ("SMPL_MALE", "basicmodel_m_lbs_10_207_0_v1.1.0", "basicModel_m_lbs_10_207_0_v1.0.0"),
    "female": ("SMPL_FEMALE", "basicmodel_f_lbs_10_207_0_v1.1.0",
               "basicModel_f_lbs_10_207_0_v1.0.0"),
}


class SMPLModelError(ValueError):
    """An SMPL model file that cannot be used: `path` and `reason` say which and why."""

    def __init__(self, path, reason: str):
        self.path, self.reason = str(path), reason
        super().__init__(f"SMPL model {path}: {reason}")


@dataclass(frozen=True)
class SMPLModel:
    """The parts of an SMPL model a rest-pose body needs, as dense float64 arrays.

    v_template (V, 3) and shapedirs (V, 3, B) are in SMPL's y-up frame; J_regressor (24, V);
    weights (V, 24); parents (24,) in SMPL joint order with -1 for the root; faces (F, 3) or None.
    """

    v_template: np.ndarray
    shapedirs: np.ndarray
    J_regressor: np.ndarray
    weights: np.ndarray
    parents: np.ndarray
    faces: np.ndarray | None = None

    @property
    def num_betas(self) -> int:
        return self.shapedirs.shape[-1]

    def vertices(self, betas: np.ndarray) -> np.ndarray:
        """Rest-pose vertices (V, 3) of shape `betas` (length at most num_betas)."""
        return self.v_template + self.shapedirs[..., : len(betas)] @ betas


# --------------------------------------------------------------------------------------------
# Reading files


def resolve_model_path(path, gender: str = "neutral") -> Path:
    """`path` itself, or for a directory the model file of `gender` under a release name."""
    path = Path(path).expanduser()
    if not path.is_dir():
        return path
    names = _MODEL_FILE_NAMES.get(gender)
    if names is None:
        raise ValueError(f"gender must be one of {', '.join(_MODEL_FILE_NAMES)}, got {gender!r}")
    for stem in names:
        for suffix in (".pkl", ".npz"):
            for candidate in (path / (stem + suffix), path / (stem.lower() + suffix)):
                if candidate.is_file():
                    return candidate
    raise SMPLModelError(path, f"directory has no {gender} SMPL model (looked for "
                         f"{', '.join(n + '.pkl/.npz' for n in names)})")


def load_smpl_model(path) -> SMPLModel:
    """Read and check an SMPL model file (.npz, or the official .pkl with or without chumpy)."""
    path = Path(path).expanduser()
    try:
        raw = path.read_bytes()
    except OSError as e:
        raise SMPLModelError(path, f"cannot read file ({e.strerror or e})") from None
    # Sniff the content rather than trust the suffix: renamed downloads are common.
    if raw[:4] == b"PK\x03\x04":
        data = _read_npz(path, raw)
    else:
        data = _read_pickle(path, raw)
    return _model_from_dict(path, data)


def _read_npz(path: Path, raw: bytes) -> dict:
    try:
        with np.load(io.BytesIO(raw), allow_pickle=False) as npz:
            return {k: npz[k] for k in npz.files}
    except ValueError as e:  # object arrays (e.g. a pickled sparse J_regressor) need pickle
        raise SMPLModelError(path, f"an array is stored as a pickled object, which .npz SMPL "
                             f"files are read without: save it as a plain array ({e})") from None
    except (OSError, zipfile.BadZipFile, EOFError) as e:
        raise SMPLModelError(path, f"not a readable .npz file ({e})") from None


class _Stub:
    """Stand-in for a class the loader will not import (chumpy, scipy.sparse of any version).

    Keeps whatever pickle hands it (constructor args and state) so the array can be pulled out.
    """

    module = name = ""

    def __init__(self, *args, **kwargs):
        self.args, self.state = args, None

    def __setstate__(self, state):
        self.state = state


_STUBS: dict[tuple[str, str], type] = {}
_NUMPY_NAMES = {"_reconstruct", "ndarray", "dtype", "scalar", "_frombuffer"}
_PY2_MODULES = {"copy_reg": "copyreg", "__builtin__": "builtins"}
_BUILTIN_NAMES = {"object", "set", "frozenset", "dict", "list", "tuple", "slice", "complex",
                  "int", "float", "bool", "str", "bytes", "bytearray"}


def _stub_class(module: str, name: str) -> type:
    key = (module, name)
    if key not in _STUBS:
        _STUBS[key] = type(f"_Stub_{name}", (_Stub,), {"module": module, "name": name})
    return _STUBS[key]


class _SMPLUnpickler(pickle.Unpickler):
    """Unpickles numpy arrays for real and everything else as inert `_Stub`s.

    The official SMPL .pkl holds chumpy `Ch` objects (chumpy does not install on current Python)
    and a scipy.sparse matrix pickled by a scipy whose module layout no longer exists. Importing
    nothing but numpy's array constructors also means a hostile file cannot run code here.
    """

    def find_class(self, module, name):
        module = _PY2_MODULES.get(module, module)  # Python 2 names of the allowed modules
        if module.split(".")[0] == "numpy" and name in _NUMPY_NAMES:
            if module.startswith("numpy.core") and hasattr(np, "_core"):
                module = "numpy._core" + module[len("numpy.core"):]  # numpy 1 pickles on numpy 2
            return super().find_class(module, name)
        if (module, name) in (("copyreg", "_reconstructor"), ("_codecs", "encode")):
            return super().find_class(module, name)
        if module == "builtins" and name in _BUILTIN_NAMES:
            return super().find_class(module, name)
        return _stub_class(module, name)


def _read_pickle(path: Path, raw: bytes) -> dict:
    try:
        data = _SMPLUnpickler(io.BytesIO(raw), encoding="latin1").load()  # Python 2 pickles
    except Exception as e:  # pickle signals corrupt input with many exception types
        raise SMPLModelError(path, f"neither an .npz nor a readable SMPL .pkl file "
                             f"({type(e).__name__}: {e})") from None
    if not isinstance(data, dict):
        raise SMPLModelError(path, f"expected a pickled dict of arrays, got {type(data).__name__}")
    return data


def _to_array(path: Path, key: str, value) -> np.ndarray:
    """A dense float/int array from a plain array, chumpy `Ch` or (stubbed) scipy.sparse matrix."""
    if isinstance(value, _Stub):
        if value.module.startswith("chumpy"):
            state = value.state if isinstance(value.state, dict) else {}
            if "x" not in state:
                raise SMPLModelError(path, f"{key!r} is a chumpy {value.name} expression, not a "
                                     "stored array; convert the file to .npz with chumpy first")
            return _to_array(path, key, state["x"])  # a basic Ch keeps its value in `x`
        if value.module.startswith("scipy.sparse"):
            return _sparse_to_dense(path, key, value)
        raise SMPLModelError(path, f"{key!r} is a {value.module}.{value.name}, not an array")
    if hasattr(value, "toarray"):  # a real scipy.sparse matrix
        value = value.toarray()
    try:
        return np.asarray(value)
    except Exception as e:
        raise SMPLModelError(path, f"{key!r} is not an array ({e})") from None


def _sparse_to_dense(path: Path, key: str, stub: _Stub) -> np.ndarray:
    import scipy.sparse as sp

    s = stub.state if isinstance(stub.state, dict) else {}
    shape = s.get("_shape", s.get("shape"))
    try:
        if stub.name in ("csc_matrix", "csr_matrix", "csc_array", "csr_array"):
            cls = sp.csc_matrix if stub.name.startswith("csc") else sp.csr_matrix
            m = cls((s["data"], s["indices"], s["indptr"]), shape=shape)
        elif stub.name in ("coo_matrix", "coo_array"):
            m = sp.coo_matrix((s["data"], (s["row"], s["col"])), shape=shape)
        else:
            raise KeyError(stub.name)
        return m.toarray()
    except Exception as e:
        raise SMPLModelError(path, f"{key!r} is a scipy.sparse {stub.name} that could not be "
                             f"rebuilt ({type(e).__name__}: {e})") from None


def _model_from_dict(path: Path, data: dict) -> SMPLModel:
    missing = [k for k in _REQUIRED_KEYS if k not in data]
    if missing:
        raise SMPLModelError(path, f"missing key(s) {', '.join(map(repr, missing))} "
                             f"(has {', '.join(sorted(map(str, data)))})")
    arr = {k: _to_array(path, k, data[k]) for k in _REQUIRED_KEYS}
    faces = _to_array(path, "f", data["f"]) if "f" in data else None

    v = _float(path, "v_template", arr["v_template"])
    nv = len(v)
    _check_shape(path, "v_template", v, (nv, 3))
    shapedirs = _float(path, "shapedirs", arr["shapedirs"])
    if shapedirs.ndim == 2 and shapedirs.shape[0] == nv * 3:  # some exports flatten (3V, B)
        shapedirs = shapedirs.reshape(nv, 3, -1)
    _check_shape(path, "shapedirs", shapedirs, (nv, 3, None))
    weights = _float(path, "weights", arr["weights"])
    regressor = _float(path, "J_regressor", arr["J_regressor"])
    kintree = arr["kintree_table"]
    _check_shape(path, "kintree_table", kintree, (2, None))
    nj = kintree.shape[1]
    if nj != NUM_BODIES:
        raise SMPLModelError(path, f"has {nj} joints, SMPL has {NUM_BODIES} (SMPL-H and SMPL-X "
                             "model files are not supported: use the SMPL body model)")
    _check_shape(path, "J_regressor", regressor, (NUM_BODIES, nv))
    _check_shape(path, "weights", weights, (nv, NUM_BODIES))
    parents = _parents(path, kintree)
    if faces is not None:
        faces = _faces(path, faces, nv)
    return SMPLModel(v, shapedirs, regressor, weights, parents, faces)


def _float(path: Path, key: str, a: np.ndarray) -> np.ndarray:
    try:
        a = np.asarray(a, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise SMPLModelError(path, f"{key!r} is not numeric ({e})") from None
    if not np.all(np.isfinite(a)):
        raise SMPLModelError(path, f"{key!r} has NaN or infinite entries")
    return a


def _check_shape(path: Path, key: str, a: np.ndarray, expected: tuple) -> None:
    ok = a.ndim == len(expected) and all(e is None or s == e for s, e in zip(a.shape, expected))
    if not ok:
        want = "(" + ", ".join("*" if e is None else str(e) for e in expected) + ")"
        raise SMPLModelError(path, f"{key!r} has shape {a.shape}, expected {want}")


def _parents(path: Path, kintree: np.ndarray) -> np.ndarray:
    # The release stores the root's parent as 2**32 - 1 (uint32 -1); any out-of-range value is it.
    parents = np.asarray(kintree[0]).astype(np.int64)
    parents[(parents < 0) | (parents >= NUM_BODIES)] = -1
    if not np.array_equal(parents, SMPL_PARENTS):
        raise SMPLModelError(path, f"kintree_table parents {parents.tolist()} are not SMPL's "
                             f"{SMPL_PARENTS.tolist()}")
    return parents


def _faces(path: Path, faces: np.ndarray, nv: int) -> np.ndarray:
    _check_shape(path, "f", faces, (None, 3))
    if faces.size and (not np.issubdtype(faces.dtype, np.integer) or faces.min() < 0
                       or faces.max() >= nv):
        raise SMPLModelError(path, f"'f' must hold vertex indices in [0, {nv})")
    return faces.astype(np.int64)


# --------------------------------------------------------------------------------------------
# Shape -> Skeleton


def skeleton_from_smpl(path, betas=None, gender: str = "neutral", mesh: bool = False) -> Skeleton:
    """The `Skeleton` of shape `betas` for the SMPL model at `path` (a file, or a directory with
    the release's per-gender files). Capsule / box / sphere geometry, or convex hulls if `mesh`.
    """
    if gender not in _MODEL_FILE_NAMES:
        raise ValueError(f"gender must be one of {', '.join(_MODEL_FILE_NAMES)}, got {gender!r}")
    file = resolve_model_path(path, gender)
    model = load_smpl_model(file)
    betas = _betas(betas, model.num_betas)

    v_smpl = model.vertices(betas)
    j_smpl = model.J_regressor @ v_smpl
    # Row-vector form of v_body = M @ v_smpl; then SMPL joint order -> body order.
    v_body = v_smpl @ SMPL_TO_BODY_FRAME.T
    j_body = (j_smpl @ SMPL_TO_BODY_FRAME.T)[SMPL_JOINT_OF_BODY]
    offsets = j_body - j_body[PARENTS]
    offsets[0] = 0.0

    bone = BODY_OF_SMPL_JOINT[model.weights.argmax(axis=1)]
    points = [v_body[bone == i] - j_body[i] for i in range(NUM_BODIES)]  # each in its body frame
    hulls = [_hull(file, BODY_NAMES[i], p) for i, p in enumerate(points)]
    geoms = _primitive_geoms(offsets, points, hulls)
    if mesh:
        geoms = tuple(Geom("mesh", (), g.mass, vertices=p[h.vertices])
                      for g, p, h in zip(geoms, points, hulls))
    return Skeleton(offsets=offsets, geoms=geoms, pelvis_smpl=j_smpl[0].copy(),
                    betas=betas.copy(), gender=gender)


def _betas(betas, num_betas: int) -> np.ndarray:
    if betas is None:
        return np.zeros(num_betas)
    betas = np.asarray(betas, dtype=np.float64)
    if betas.ndim == 2 and betas.shape[0] == 1:  # a batch of one, as AMASS stores them
        betas = betas[0]
    if betas.ndim != 1:
        raise ValueError(f"betas must be a vector, got shape {betas.shape}")
    if len(betas) > num_betas:
        if np.any(betas[num_betas:] != 0):
            warnings.warn(f"{len(betas)} betas given, the SMPL model has {num_betas} shape "
                          f"components: betas[{num_betas}:] are ignored", stacklevel=3)
        betas = betas[:num_betas]
    return betas


def _hull(path: Path, name: str, points: np.ndarray) -> ConvexHull:
    if len(points) < 4:
        raise SMPLModelError(path, f"only {len(points)} vertices are skinned mostly to {name}: "
                             "too few for a convex hull")
    try:
        return ConvexHull(points)
    except QhullError as e:
        raise SMPLModelError(path, f"the vertices of {name} have no convex hull (flat?): "
                             f"{str(e).splitlines()[0]}") from None


def _children_mean(offsets: np.ndarray) -> np.ndarray:
    """(24, 3): mean offset of each body's children (zero for leaves), i.e. where its bone ends."""
    total = np.zeros_like(offsets)
    np.add.at(total, PARENTS[1:], offsets[1:])
    count = np.bincount(PARENTS[1:], minlength=NUM_BODIES)
    return total / np.maximum(count, 1)[:, None]


def _capsule_radius(volume: float, length: float) -> float:
    """The r > 0 with pi r^2 L + 4/3 pi r^3 = volume (a capsule of that volume and length)."""
    roots = np.roots([4.0 / 3.0 * np.pi, np.pi * length, 0.0, -volume])
    return float(max(r.real for r in roots if abs(r.imag) < 1e-9 and r.real > 0))


def _primitive_geoms(offsets, points, hulls) -> tuple[Geom, ...]:
    ends = _children_mean(offsets)
    geoms = []
    for i, name in enumerate(BODY_NAMES):
        vol = hulls[i].volume
        if name in _SPHERES:
            s = _SPHERES[name]
            r = np.cbrt(3.0 * vol / (4.0 * np.pi))
            geoms.append(Geom("sphere", (float(r * s),), DENSITY * vol))
        elif name in _BOXES:
            lo, hi = points[i].min(axis=0), points[i].max(axis=0)
            pos, half = (lo + hi) / 2, (hi - lo) / 2
            if name.endswith("Toe"):
                # Sole level with the ankle box's and centred on it sideways, so the foot rests
                # flat (the anchors' "big ankle" boxes); offsets[i] moves parent frame -> toe frame.
                foot = geoms[PARENTS[i]]
                pos[1] = foot.pos[1] - offsets[i, 1]
                pos[2] = foot.pos[2] - foot.size[2] - offsets[i, 2] + half[2]
            geoms.append(Geom("box", tuple(map(float, half)), float(DENSITY * 8 * np.prod(half)),
                              pos=tuple(map(float, pos))))
        else:
            span = _CAPSULE_SPAN.get(name, 0.2)
            a, b = (1 - span) * ends[i], span * ends[i]  # from the far end back, as the table does
            s = _CAPSULE_SHRINK.get(name, 1.0)
            length = float(np.linalg.norm(a - b))
            r = _capsule_radius(vol, length)
            # The shrunk capsule keeps the mass of the volume it was shrunk from, per unit length.
            mass = DENSITY * (np.pi * (s * r) ** 2 * length + 4 / 3 * np.pi * (s * r) ** 3) / s**2
            geoms.append(Geom("capsule", (r * s,), float(mass),
                              fromto=tuple(map(float, np.concatenate([a, b])))))
    return tuple(geoms)
