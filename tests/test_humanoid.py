import mujoco
import numpy as np
import pytest

from smpl_envs.humanoid import (
    ACTION_SCALE, BODY_NAMES, HINGE_NAMES, PARENTS, PHYSICS_TIMESTEP, build_humanoid,
)
from smpl_envs.humanoid.skeleton import KD, KP, MEAN_OFFSETS, TORQUE_LIMIT, anatomical_limits


@pytest.fixture(scope="module")
def model():
    return build_humanoid()


def test_structure_matches_the_reference(model):
    names = [mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, i) for i in range(1, model.nbody)]
    assert names == list(BODY_NAMES)
    assert list(model.body_parentid[1:] - 1) == [max(p, -1) for p in PARENTS]
    assert (model.nq, model.nv, model.nu) == (76, 75, 69)
    np.testing.assert_allclose(model.body_pos[2:], MEAN_OFFSETS[1:], atol=1e-9)
    assert model.body_mass[1:].sum() == pytest.approx(74.0, abs=0.05)
    assert model.opt.timestep == pytest.approx(PHYSICS_TIMESTEP)
    assert model.opt.integrator == mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    joints = [mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, i) for i in range(1, model.njnt)]
    assert joints == list(HINGE_NAMES)
    # every hinge is 1 dof at its body's origin, axes x, y, z in turn
    np.testing.assert_allclose(model.jnt_axis[1:], np.tile(np.eye(3), (23, 1)))


def test_pd_actuators_carry_the_listed_gains(model):
    np.testing.assert_allclose(model.actuator_gainprm[:, 0], KP)
    np.testing.assert_allclose(-model.actuator_biasprm[:, 1], KP)
    np.testing.assert_allclose(model.dof_damping[6:], KD)  # D term as implicit joint damping
    np.testing.assert_allclose(model.actuator_biasprm[:, 2], 0.0)
    np.testing.assert_allclose(model.actuator_forcerange[:, 1], TORQUE_LIMIT)
    np.testing.assert_allclose(model.actuator_ctrlrange[:, 1], ACTION_SCALE)
    assert ACTION_SCALE[HINGE_NAMES.index("L_Knee_y")] == 5.0


def test_hinges_wide_open_by_default_and_anatomical_on_request(model):
    assert not model.jnt_limited[1:].any()
    limited = build_humanoid(joint_limits="anatomical")
    assert limited.jnt_limited[1:].all()
    np.testing.assert_allclose(limited.jnt_range[1:], anatomical_limits())
    # mirrored: left and right hip roll ranges are negatives of each other
    lx, rx = HINGE_NAMES.index("L_Hip_x"), HINGE_NAMES.index("R_Hip_x")
    np.testing.assert_allclose(limited.jnt_range[1 + lx], -limited.jnt_range[1 + rx][::-1])


def test_stands_ten_seconds_at_zero_action(model):
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    start_head = data.xpos[BODY_NAMES.index("Head") + 1].copy()
    mujoco.mj_step(model, data, nstep=int(10.0 / model.opt.timestep))
    head = data.xpos[BODY_NAMES.index("Head") + 1]
    assert np.all(np.isfinite(data.qpos))
    assert head[2] > start_head[2] - 0.05, "the head sank: the humanoid did not stay upright"
    assert np.linalg.norm(head[:2] - start_head[:2]) < 0.1
    assert np.abs(data.qvel).max() < 0.5, "still moving after 10 s: not a stable stance"


def test_feet_start_on_the_floor(model):
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    floor_contacts = [c for c in data.contact[: data.ncon] if 0 in (c.geom1, c.geom2)]
    assert floor_contacts, "the standing pose does not touch the floor"
    assert min(c.dist for c in floor_contacts) > -2e-3


def test_clear_errors_for_bad_arguments():
    with pytest.raises(ValueError, match="joint_limits"):
        build_humanoid(joint_limits="tight")
    with pytest.raises(ValueError, match="smpl_model_path"):
        build_humanoid(betas=np.ones(10))
    with pytest.raises(ValueError, match="smpl_model_path"):
        build_humanoid(mesh=True)


def test_return_spec_gives_an_editable_spec():
    model, spec = build_humanoid(return_spec=True)
    spec.worldbody.add_geom(name="box", type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.1] * 3, pos=[2, 0, 0.1])
    assert spec.compile().ngeom == model.ngeom + 1
