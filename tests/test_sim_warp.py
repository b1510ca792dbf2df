"""The MuJoCo Warp backend (`smpl_envs.sim.WarpSim`) on Warp's CPU device (on a GPU
with SMPL_ENVS_WARP_DEVICE=cuda): parity with `CPUSim`, divergence isolation, resets of some
worlds, determinism and `active` masks.

Parity tolerance (measured, walk clip, 8 worlds, PD targets tracking the clip): MuJoCo Warp
computes in float32, CPU MuJoCo in float64, so states agree to ~1e-6 for as long as both backends
see the same contacts. A foot that meets or leaves the floor within float32 rounding of distance
zero does so one substep earlier on one backend; that world's qpos then differs by up to ~1e-2
(contacts are discontinuous). The test therefore starts from poses lowered 1 mm (the shipped
clips put the feet exactly at z = 0, where the two precisions disagree at once) and asserts: the
first control step within 1e-5 in every world; over 10 steps, most worlds within 1e-4 and every
world within 5e-2. A standing humanoid (contacts steady) stays within 1e-5 over 30 steps.
"""

import subprocess
import sys

import mujoco
import numpy as np
import pytest

pytest.importorskip("mujoco_warp", reason="MuJoCo Warp is not installed (pip install 'smpl-envs[gpu]')")
torch = pytest.importorskip("torch")

from smpl_envs.features import BodyState  # noqa: E402
from smpl_envs.humanoid import BODY_NAMES, build_humanoid  # noqa: E402
from smpl_envs.humanoid.builder import build_spec, humanoid_addresses  # noqa: E402
from smpl_envs.motion.library import MotionLib  # noqa: E402
from smpl_envs.sim import CPUSim, WarpSim, to_numpy  # noqa: E402

from conftest import WARP_DEVICE, warp_same  # noqa: E402

N = 4


@pytest.fixture(scope="module")
def model():
    return build_humanoid()


@pytest.fixture(scope="module")
def lib():
    return MotionLib.load("walk")


@pytest.fixture(scope="module")
def sims(model):
    """Two Warp sims of the same model (determinism compares them); tests reset what they use."""
    a, b = WarpSim(model, N, 4, device=WARP_DEVICE), WarpSim(model, N, 4, device=WARP_DEVICE)
    yield a, b
    a.close()
    b.close()


def _starts(lib, n, lower=0.001):
    q, v = lib.qpos_qvel(np.arange(n) * 7)
    q[:, 2] -= lower  # feet 1 mm into the floor: the contacts exist in float32 and float64 alike
    return q, v


def _tracking(lib, n, k):
    """PD targets of the clip's next frame: a policy that walks, as a trained imitator does."""
    q, _ = lib.qpos_qvel(np.minimum(np.arange(n) * 7 + k + 1, lib.lengths[0] - 1))
    return q[:, 7:]


def _snapshot(sim):
    b = sim.bodies
    return [t.clone() for t in (sim.qpos, sim.qvel, sim.actuator_force, b.pos, b.rot, b.lin_vel, b.ang_vel)]


def _equal(a, b):
    return warp_same(list(a), list(b))


def test_import_of_sim_does_not_import_warp():
    code = "import sys, smpl_envs.sim; assert 'warp' not in sys.modules and 'mujoco_warp' not in sys.modules"
    subprocess.run([sys.executable, "-c", code], check=True)


def test_members_are_device_tensors(sims, model, lib):
    sim = sims[0]
    q, v = _starts(lib, N)
    sim.set_state(torch.arange(N), torch.as_tensor(q), torch.as_tensor(v))  # torch in, as NumPy
    np.testing.assert_allclose(to_numpy(sim.qpos), q, atol=1e-6)
    assert sim.num_worlds == N and sim.substeps == 4 and sim.device.type == torch.device(WARP_DEVICE).type
    for t, shape in ((sim.qpos, (N, model.nq)), (sim.qvel, (N, model.nv)), (sim.ctrl, (N, model.nu)),
                     (sim.actuator_force, (N, model.nu)), (sim.sensordata, (N, 0))):
        assert isinstance(t, torch.Tensor) and t.shape == shape and t.dtype == torch.float32
    b = sim.bodies
    assert isinstance(b, BodyState) and b.pos.shape == (N, 24, 3) and b.rot.shape == (N, 24, 3, 3)
    assert b.dof_pos.shape == b.dof_vel.shape == (N, 69)
    diverged = sim.step(np.zeros((N, model.nu)))
    assert diverged.dtype == torch.bool and diverged.shape == (N,) and not diverged.any()
    nb = to_numpy(sim.bodies)
    assert isinstance(nb.pos, np.ndarray) and nb.pos.shape == (N, 24, 3)
    if sim.device.type == "cpu":  # to_numpy on a CPU tensor is a view: no copy of the state
        assert np.shares_memory(to_numpy(sim.qpos), sim.qpos.numpy())


def test_bodies_match_cpu_after_set_state(sims, model, lib):
    sim, cpu = sims[0], CPUSim(model, N, 4, num_threads=1)
    q, v = _starts(lib, N)
    sim.set_state(np.arange(N), q, v)
    cpu.set_state(np.arange(N), q, v)
    w, c = to_numpy(sim.bodies), cpu.bodies
    np.testing.assert_allclose(w.pos, c.pos, atol=1e-5)
    np.testing.assert_allclose(w.rot, c.rot, atol=1e-5)
    np.testing.assert_allclose(w.lin_vel, c.lin_vel, atol=1e-4)
    np.testing.assert_allclose(w.ang_vel, c.ang_vel, atol=1e-4)
    np.testing.assert_allclose(w.dof_pos, c.dof_pos, atol=1e-6)
    np.testing.assert_allclose(w.dof_vel, c.dof_vel, atol=1e-5)
    # the walk has real speeds: the comparison above is not between zeros
    assert np.abs(c.lin_vel).max() > 0.5
    cpu.close()


def test_parity_with_cpu_over_ten_steps(model, lib):
    n = 8
    sim, cpu = WarpSim(model, n, 4, device=WARP_DEVICE), CPUSim(model, n, 4, num_threads=1)
    q, v = _starts(lib, n)
    sim.set_state(np.arange(n), q, v)
    cpu.set_state(np.arange(n), q, v)
    errors = []
    for k in range(10):
        ctrl = _tracking(lib, n, k)
        assert not sim.step(ctrl).any() and not cpu.step(ctrl).any()
        errors.append(np.abs(to_numpy(sim.qpos) - cpu.qpos).max(-1))
        if k == 0:
            np.testing.assert_allclose(to_numpy(sim.actuator_force), cpu.actuator_force, atol=1e-2)
    errors = np.array(errors)
    assert errors[0].max() < 1e-5, errors[0]
    assert (errors[-1] < 1e-4).sum() >= n // 2, errors[-1]
    assert errors.max() < 5e-2, errors.max(0)
    np.testing.assert_allclose(to_numpy(sim.bodies.pos), cpu.bodies.pos, atol=5e-2)
    # the humanoids did move: parity is not two frozen states
    assert np.abs(cpu.qpos[:, :2] - q[:, :2]).max() > 0.05
    sim.close()
    cpu.close()


def test_standing_parity_is_tight(model):
    """Without contacts starting or ending, the backends differ by float32 rounding only: a
    standing humanoid holding its pose, 30 control steps (120 substeps), within 1e-5."""
    stand, n = MotionLib.load("stand"), 2
    sim, cpu = WarpSim(model, n, 4, device=WARP_DEVICE), CPUSim(model, n, 4, num_threads=1)
    q, v = _starts(stand, n)
    sim.set_state(np.arange(n), q, v)
    cpu.set_state(np.arange(n), q, v)
    for _ in range(30):
        sim.step(q[:, 7:])
        cpu.step(q[:, 7:])
    np.testing.assert_allclose(to_numpy(sim.qpos), cpu.qpos, atol=1e-5)
    np.testing.assert_allclose(to_numpy(sim.bodies.pos), cpu.bodies.pos, atol=1e-5)
    sim.close()
    cpu.close()


def _slab_model():
    """The humanoid standing on a free slab with a contact sensor per body (as Strike's box) and a
    touch sensor under the slab: touch is acceleration-stage, which MuJoCo Warp's step1 clears."""
    spec = build_spec()
    slab = spec.worldbody.add_body(name="slab", pos=[0.0, 0.0, 0.009])  # 1 mm into the floor
    slab.add_freejoint(name="slab_root")
    slab.add_geom(name="slab_geom", type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.6, 0.6, 0.01], density=500)
    # the touch volume covers the slab's top face only, not its contacts with the floor
    slab.add_site(name="slab_site", type=mujoco.mjtGeom.mjGEOM_BOX, pos=[0.0, 0.0, 0.02], size=[0.7, 0.7, 0.015])
    spec.add_sensor(name="slab_touch", type=mujoco.mjtSensor.mjSENS_TOUCH, objtype=mujoco.mjtObj.mjOBJ_SITE,
                    objname="slab_site")
    for name in BODY_NAMES:
        s = spec.add_sensor(name=f"touch_{name}", type=mujoco.mjtSensor.mjSENS_CONTACT, objtype=mujoco.mjtObj.mjOBJ_BODY,
                            objname=name, reftype=mujoco.mjtObj.mjOBJ_GEOM, refname="slab_geom")
        s.intprm[0], s.intprm[2] = 1, 1
    return spec.compile()


def test_task_objects_and_contact_sensors_match_cpu(lib):
    model, n = _slab_model(), 2
    h = humanoid_addresses(model)
    sim, cpu = WarpSim(model, n, 4, device=WARP_DEVICE, humanoid=h), CPUSim(model, n, 4, num_threads=1, humanoid=h)
    hq, hv = _starts(lib, n)
    q, v = np.tile(model.qpos0, (n, 1)), np.zeros((n, model.nv))
    q[:, h.qpos], v[:, h.qvel] = hq, hv
    q[:, 2] += 0.019  # onto the slab (top at 0.019 m), feet 1 mm into it
    slab_q = slice(h.qpos.stop, h.qpos.stop + 7)
    q[:, slab_q.start:slab_q.start + 2] = hq[:, :2]
    sim.set_state(np.arange(n), q, v)
    cpu.set_state(np.arange(n), q, v)
    touching, pushes = [], []
    for k in range(4):
        sim.step(_tracking(lib, n, k))
        cpu.step(_tracking(lib, n, k))
        found, touch = to_numpy(sim.sensordata[:, 1:]), to_numpy(sim.sensordata[:, 0])  # touch added first
        np.testing.assert_array_equal(found > 0, cpu.sensordata[:, 1:] > 0)
        # the feet's push on the slab, N: MuJoCo Warp's step1 zeroes it and its step2 adds onto
        # what is there, so a backend that kept or lost it would be off by a whole step's force
        np.testing.assert_allclose(touch, cpu.sensordata[:, 0], rtol=1e-3, atol=0.5)
        touching.append(cpu.sensordata[:, 1:].sum())
        pushes.append(touch.max())
        np.testing.assert_allclose(to_numpy(sim.qpos[:, slab_q]), cpu.qpos[:, slab_q], atol=1e-4)
    assert min(touching) > 0 and min(pushes) > 300  # feet on the slab: the sensors had something to report
    sim.close()
    cpu.close()


def test_determinism(sims, model, lib):
    a, b = sims
    q, v = _starts(lib, N)
    runs = []
    for sim in (a, b, a):  # two instances, and the first again after a reset
        sim.set_state(np.arange(N), q, v)
        rng = np.random.default_rng(3)
        for _ in range(5):
            sim.step(rng.uniform(-0.5, 0.5, (N, model.nu)))
        runs.append(_snapshot(sim))
    assert _equal(runs[0], runs[1]) and _equal(runs[0], runs[2])


def _run(sim, q, v, steps, bad_world=None, bad="nan"):
    q, v = q.copy(), v.copy()
    if bad_world is not None:
        if bad == "nan":
            q[bad_world, 10] = np.nan
        else:
            v[bad_world, :3] = 1e5
    sim.set_state(np.arange(N), q, v)
    flags = []
    for k in range(steps):
        flags.append(to_numpy(sim.step(np.full((N, 69), 0.1 * k))).copy())
    return np.array(flags)


@pytest.mark.parametrize("bad", ["nan", "huge"])
def test_divergence_is_isolated_and_reset_alone(sims, lib, bad):
    a, b = sims
    q, v = _starts(lib, N)
    _run(a, q, v, 3)
    clean = _snapshot(a)
    flags = _run(b, q, v, 3, bad_world=2, bad=bad)
    assert flags[0].tolist() == [False, False, True, False]
    others = [0, 1, 3]
    assert _equal([t[others] for t in clean], [t[others] for t in _snapshot(b)])
    before = _snapshot(b)
    b.set_state([2], q[2:3], v[2:3])
    after = _snapshot(b)
    assert _equal([t[others] for t in before], [t[others] for t in after])  # reset touched world 2 only
    a.set_state(np.arange(N), q, v)
    assert _equal([t[2] for t in _snapshot(a)], [t[2] for t in after])      # world 2 as freshly placed
    assert not b.step(np.zeros((N, 69))).any()
    assert torch.isfinite(b.qpos).all()


def test_set_state_of_some_worlds_mid_run(sims, lib):
    a, b = sims
    q, v = _starts(lib, N)
    _run(a, q, v, 4)
    b.set_state(np.arange(N), q, v)
    placed = _snapshot(b)
    before = _snapshot(a)
    a.set_state([1, 3], q[[1, 3]], v[[1, 3]])
    after = _snapshot(a)
    assert _equal([t[[0, 2]] for t in before], [t[[0, 2]] for t in after])
    assert _equal([t[[1, 3]] for t in placed], [t[[1, 3]] for t in after])
    assert not _equal([t[[1, 3]] for t in before], [t[[1, 3]] for t in after])
    assert not a.ctrl[[1, 3]].any() and not a.actuator_force[[1, 3]].any()


def test_inactive_worlds_keep_their_state(sims, lib):
    a, b = sims
    q, v = _starts(lib, N)
    active = np.array([True, False, True, False])
    for sim in (a, b):
        sim.set_state(np.arange(N), q, v)
        sim.step(np.full((N, 69), 0.2))
    before = _snapshot(a)
    ctrl = np.full((N, 69), -0.3)
    diverged = a.step(ctrl, active=active)
    b.step(ctrl)
    masked, full = _snapshot(a), _snapshot(b)
    assert diverged.shape == (N,) and not diverged.any()
    assert _equal([t[~active] for t in before], [t[~active] for t in masked])
    assert _equal([t[active] for t in full], [t[active] for t in masked])
    assert not _equal([t[active] for t in before], [t[active] for t in masked])
    # and the kept worlds step on exactly as if they had not been held
    a.step(ctrl, active=torch.as_tensor(~active))
    b.set_state(np.arange(N), q, v)
    b.step(np.full((N, 69), 0.2))
    b.step(ctrl)
    assert _equal([t[~active] for t in _snapshot(a)], [t[~active] for t in _snapshot(b)])


def test_bad_input_raises(sims, model):
    sim = sims[0]
    with pytest.raises(ValueError, match="ctrl"):
        sim.step(np.zeros((N + 1, model.nu)))
    with pytest.raises(ValueError, match="active"):
        sim.step(np.zeros((N, model.nu)), active=np.ones(N + 1, bool))
    with pytest.raises(ValueError, match="qpos"):
        sim.set_state([0], np.zeros((1, 3)), np.zeros((1, model.nv)))
    with pytest.raises(ValueError, match="ids"):
        sim.set_state([N], np.zeros((1, model.nq)), np.zeros((1, model.nv)))
    for kwarg in ("num_worlds", "substeps", "nconmax", "njmax"):
        args = {"num_worlds": 1, "substeps": 1, kwarg: 0}
        with pytest.raises(ValueError, match=kwarg):
            WarpSim(model, args.pop("num_worlds"), args.pop("substeps"), device=WARP_DEVICE, **args)
    with pytest.raises(ValueError, match="device"):
        WarpSim(model, 1, 1, device="tpu")
