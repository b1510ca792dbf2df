"""Bodies from an SMPL model file, tested on a synthetic file in its format (synthetic_smpl.py).

The synthetic model is built so that its mean shape is REFERENCE.md's mean humanoid: the recipe
must give back the table's offsets, pelvis, geoms and masses.
"""

from __future__ import annotations

import io
import pickle
import sys
import warnings

import mujoco
import numpy as np
import pytest
from synthetic_smpl import build_synthetic_smpl, write_synthetic_smpl

from smpl_envs.humanoid import build_humanoid, standing_height
from smpl_envs.humanoid.skeleton import (
    BODY_NAMES, MEAN_GEOMS, MEAN_OFFSETS, MEAN_PELVIS_SMPL, NUM_BODIES, PARENTS,
)
from smpl_envs.humanoid.smpl_model import (
    SMPL_PARENTS, SMPLModelError, load_smpl_model, skeleton_from_smpl,
)

NUM_BETAS = 10


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("smpl")
    return {
        "npz": write_synthetic_smpl(d / "model.npz", "npz", NUM_BETAS),
        "pkl": write_synthetic_smpl(d / "model.pkl", "pkl", NUM_BETAS),
        "chumpy": write_synthetic_smpl(d / "model_ch.pkl", "pkl", NUM_BETAS, chumpy=True),
        "chumpy-protocol-0": write_synthetic_smpl(d / "model_ch0.pkl", "pkl", NUM_BETAS,
                                                  chumpy=True, protocol=0),
    }


@pytest.fixture(scope="module")
def model_path(files):
    return files["npz"]


# ------------------------------------------------------------------------------------------
# Mean shape = REFERENCE.md


def test_zero_betas_reproduce_mean_skeleton(model_path):
    for betas in (None, np.zeros(NUM_BETAS), np.zeros(3)):
        sk = skeleton_from_smpl(model_path, betas=betas)
        np.testing.assert_allclose(sk.offsets[1:], MEAN_OFFSETS[1:], atol=1e-6)
        np.testing.assert_allclose(sk.offsets[0], 0.0)
        np.testing.assert_allclose(sk.pelvis_smpl, MEAN_PELVIS_SMPL, atol=1e-9)
    assert sk.gender == "neutral" and len(sk.betas) == 3


def test_recipe_gives_back_reference_geometry(model_path):
    """The capsule / box / sphere recipe and its mass rule reproduce REFERENCE.md's table."""
    sk = skeleton_from_smpl(model_path)
    for name, got, want in zip(BODY_NAMES, sk.geoms, MEAN_GEOMS):
        assert got.kind == want.kind, name
        np.testing.assert_allclose(got.size, want.size, atol=6e-4, err_msg=name)
        np.testing.assert_allclose(got.pos, want.pos, atol=6e-4, err_msg=name)
        if want.fromto is not None:
            np.testing.assert_allclose(got.fromto, want.fromto, atol=6e-4, err_msg=name)
        assert got.mass == pytest.approx(want.mass, abs=0.02), name
    assert sk.mass == pytest.approx(74.0, abs=0.1)


def test_mesh_variant_is_hulls_with_same_masses(model_path):
    prim = skeleton_from_smpl(model_path, betas=[0.5, 0.5])
    mesh = skeleton_from_smpl(model_path, betas=[0.5, 0.5], mesh=True)
    # Same file, same code path (the bones are computed before `mesh` is looked at), same
    # process: bit-identical is a fair demand here.
    np.testing.assert_array_equal(mesh.offsets, prim.offsets)
    for name, g, p in zip(BODY_NAMES, mesh.geoms, prim.geoms):
        assert g.kind == "mesh" and g.vertices.shape[1] == 3 and len(g.vertices) >= 4, name
        assert g.mass == pytest.approx(p.mass), name
    # Hull vertices are in the body frame: the pelvis hull surrounds its joint.
    pelvis = mesh.geoms[0].vertices
    assert np.all(pelvis.min(0) < 0) and np.all(pelvis.max(0) > 0)


# ------------------------------------------------------------------------------------------
# Other shapes


def _height(sk):
    return standing_height(sk) + sk.offsets[[9, 10, 11, 12, 13]].sum(0)[2]  # soles to head joint


def test_height_beta_makes_a_taller_heavier_body(model_path):
    mean = skeleton_from_smpl(model_path)
    tall = skeleton_from_smpl(model_path, betas=[1.0])
    short = skeleton_from_smpl(model_path, betas=[-1.0])
    assert not np.allclose(tall.offsets, mean.offsets)
    assert _height(short) < _height(mean) < _height(tall)
    assert _height(tall) / _height(mean) == pytest.approx(1.06, rel=0.01)
    assert short.mass < mean.mass < tall.mass
    assert not np.allclose(tall.pelvis_smpl, mean.pelvis_smpl)


def test_girth_beta_changes_mass_not_bones(model_path):
    mean = skeleton_from_smpl(model_path)
    fat = skeleton_from_smpl(model_path, betas=[0.0, 1.0])
    np.testing.assert_allclose(fat.offsets, mean.offsets, atol=1e-9)
    assert fat.mass > 1.15 * mean.mass
    assert fat.geoms[1].size[0] > mean.geoms[1].size[0]


def test_every_component_and_betas_length(model_path):
    mean = skeleton_from_smpl(model_path)
    for k in (2, 3, 4, 7):  # legs, shoulders, arms, a random one
        betas = np.zeros(NUM_BETAS)
        betas[k] = 1.0
        assert not np.allclose(skeleton_from_smpl(model_path, betas=betas).offsets, mean.offsets)
    short = skeleton_from_smpl(model_path, betas=[0.3, -0.2])
    padded = skeleton_from_smpl(model_path, betas=[0.3, -0.2] + [0.0] * 8)
    np.testing.assert_allclose(short.offsets, padded.offsets)
    with pytest.warns(UserWarning, match="ignored"):
        long = skeleton_from_smpl(model_path, betas=[0.3, -0.2] + [0.0] * 8 + [1.0, 2.0])
    np.testing.assert_allclose(long.offsets, padded.offsets)
    with pytest.raises(ValueError, match="betas"):
        skeleton_from_smpl(model_path, betas=np.zeros((2, 10)))


# ------------------------------------------------------------------------------------------
# File formats


def test_npz_pkl_and_chumpy_pkl_load_identically(files):
    for name in ("chumpy", "chumpy-protocol-0", "pkl"):
        with warnings.catch_warnings():
            warnings.simplefilter("error")  # legacy class names (numpy.core...) load silently
            load_smpl_model(files[name])
        assert "chumpy" not in sys.modules
    models = {k: load_smpl_model(p) for k, p in files.items()}
    ref = models["npz"]
    np.testing.assert_array_equal(ref.parents, SMPL_PARENTS)
    assert ref.parents[0] == -1 and ref.J_regressor.shape == (NUM_BODIES, len(ref.v_template))
    for k, m in models.items():
        # The stored arrays themselves are read, not computed: loading must be lossless, bit for bit.
        for field in ("v_template", "shapedirs", "J_regressor", "weights", "parents", "faces"):
            np.testing.assert_array_equal(getattr(m, field), getattr(ref, field), err_msg=k)
    # What is computed from them may differ in the last bits: the arrays from the three formats
    # can differ in memory layout, and BLAS picks kernels (and summation orders) by layout and CPU
    # (4.4e-16 m seen with numpy 2.4 on an AVX-512 machine). Equal up to rounding is the claim.
    sks = [skeleton_from_smpl(p, betas=[1.0, -0.5, 0.3]) for p in files.values()]
    for name, sk in zip(list(files)[1:], sks[1:]):
        np.testing.assert_allclose(sk.offsets, sks[0].offsets, rtol=0, atol=1e-12, err_msg=name)
        np.testing.assert_allclose(sk.pelvis_smpl, sks[0].pelvis_smpl, rtol=0, atol=1e-12, err_msg=name)
        assert sk.mass == pytest.approx(sks[0].mass, rel=1e-12, abs=0), name


def test_directory_of_models_by_gender(tmp_path):
    write_synthetic_smpl(tmp_path / "SMPL_NEUTRAL.npz", "npz", 4)
    write_synthetic_smpl(tmp_path / "SMPL_FEMALE.pkl", "pkl", 4, chumpy=True)
    assert skeleton_from_smpl(tmp_path).gender == "neutral"
    assert skeleton_from_smpl(tmp_path, gender="female").gender == "female"
    with pytest.raises(SMPLModelError, match="male"):
        skeleton_from_smpl(tmp_path, gender="male")


def _npz(path, data):
    with open(path, "wb") as fh:
        np.savez(fh, **data)
    return path


def _malformed(tmp_path):
    data = build_synthetic_smpl(4)
    nv = len(data["v_template"])
    bad_parents = data["kintree_table"].copy()
    bad_parents[0, 5] = 3
    return {
        "missing key": (_npz(tmp_path / "nokey.npz", {k: v for k, v in data.items()
                                                       if k != "weights"}), "weights"),
        "wrong shape": (_npz(tmp_path / "shape.npz", {**data, "weights": data["weights"].T}),
                        "weights"),
        "wrong vertex count": (_npz(tmp_path / "nv.npz", {**data, "J_regressor":
                                                           data["J_regressor"][:, : nv - 1]}),
                               "J_regressor"),
        "nan": (_npz(tmp_path / "nan.npz", {**data, "v_template": data["v_template"] * np.nan}),
                "NaN"),
        "smpl-h": (_npz(tmp_path / "smplh.npz", {**data, "kintree_table":
                                                 np.zeros((2, 52), np.int64)}), "52 joints"),
        "other tree": (_npz(tmp_path / "tree.npz", {**data, "kintree_table": bad_parents}),
                       "parents"),
        "bad faces": (_npz(tmp_path / "faces.npz", {**data, "f": data["f"] + nv}), "'f'"),
        "garbage": (tmp_path / "garbage.pkl", "readable"),
        "empty": (tmp_path / "empty.npz", "readable"),
        "truncated npz": (tmp_path / "trunc.npz", "readable"),
        "not a dict": (tmp_path / "list.pkl", "dict"),
        "missing file": (tmp_path / "nothere.pkl", "cannot read"),
    }


def test_malformed_files_raise_naming_file_and_problem(tmp_path):
    cases = _malformed(tmp_path)
    (tmp_path / "garbage.pkl").write_bytes(np.random.default_rng(0).bytes(3000))
    (tmp_path / "empty.npz").write_bytes(b"")
    good = _npz(tmp_path / "good.npz", build_synthetic_smpl(4))
    (tmp_path / "trunc.npz").write_bytes(good.read_bytes()[:5000])
    (tmp_path / "list.pkl").write_bytes(pickle.dumps([1, 2, 3], protocol=2))
    for case, (path, problem) in cases.items():
        with pytest.raises(SMPLModelError) as err:
            load_smpl_model(path)
        assert str(path) in str(err.value), case
        assert problem in str(err.value), (case, str(err.value))
        assert isinstance(err.value, ValueError)
    with pytest.raises(SMPLModelError, match="garbage.pkl"):
        build_humanoid(smpl_model_path=tmp_path / "garbage.pkl")


def test_pickle_cannot_run_code(tmp_path):
    """Classes outside numpy's array constructors are never imported, let alone called."""

    class Boom:
        def __reduce__(self):
            return (print, ("pwned",))

    path = tmp_path / "evil.pkl"
    data = build_synthetic_smpl(2)
    buf = io.BytesIO()
    pickle.dump({**data, "v_template": Boom()}, buf, protocol=2)
    path.write_bytes(buf.getvalue())
    with pytest.raises(SMPLModelError, match="v_template"):
        load_smpl_model(path)


# ------------------------------------------------------------------------------------------
# The simulated humanoid


def _stands(model, seconds=2.0):
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    heights = []
    for _ in range(int(seconds / model.opt.timestep)):
        mujoco.mj_step(model, data)  # ctrl stays zero: PD targets at the rest pose
        heights.append(data.qpos[2])
    return min(heights) > 0.7 and abs(heights[-1] - heights[0]) < 0.05


@pytest.mark.parametrize("mesh", [False, True])
def test_build_humanoid_from_model_file_stands(model_path, mesh):
    default = build_humanoid()
    model = build_humanoid(smpl_model_path=model_path, betas=[1.0, 0.5], mesh=mesh)
    assert model.nbody == NUM_BODIES + 1 and model.nu == 69 and model.nq == 76
    kinds = {int(model.geom_type[model.body_geomadr[b]]) for b in range(1, model.nbody)}
    if mesh:
        assert kinds == {int(mujoco.mjtGeom.mjGEOM_MESH)}
    else:
        assert int(mujoco.mjtGeom.mjGEOM_CAPSULE) in kinds
    assert not np.allclose(model.body_mass, default.body_mass)
    assert model.body_mass[1:].sum() > default.body_mass[1:].sum()
    assert _stands(model)


def test_parents_table_matches_body_tree():
    from smpl_envs.humanoid.skeleton import SMPL_JOINT_OF_BODY

    for i in range(1, NUM_BODIES):
        assert SMPL_PARENTS[SMPL_JOINT_OF_BODY[i]] == SMPL_JOINT_OF_BODY[PARENTS[i]]
