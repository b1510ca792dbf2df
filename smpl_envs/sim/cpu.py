"""N humanoid worlds on the CPU: one MjModel, N MjData, stepped by a thread pool.

MuJoCo's Python bindings release the GIL inside every `mj_*` call, so plain threads use every
core without subprocesses or copies of the model. Each thread owns a fixed slice of worlds.

Each physics substep is run as `mj_step2` then `mj_step1` rather than `mj_step`. The pair does
exactly the same arithmetic (the tests check bit-equality), but it leaves positions, rotations and
com-based velocities computed for the *current* state, so observations need no extra
`mj_forward`: after `mj_step` they would describe the state one substep earlier.

The model may hold more than the humanoid (a box to strike, a target marker, a terrain): the
humanoid is read through the builder's `HumanoidAddresses`, and the whole model's state stays
available as `qpos`, `qvel` and `sensordata`.

Two optional inputs exist for the one task that uses them (SimPoE's, `SMPL/VideoPose-v0`), both
None otherwise and then never touched: `pd_scales` (N, substeps, 2), per-substep scales of the PD
gains (meta-PD), and `root_wrench` (N, 6), a force and torque on the pelvis (SimPoE's residual
root force, the suite's only external force, off unless that task enables it). Set them before a
`step`; they hold until changed.

A world whose state turns non-finite, whose speeds explode, or that MuJoCo itself resets after a
numerical warning is reported in the mask `step` returns; the task ends that episode and resets
only that world.
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor

import mujoco
import numpy as np

from ..features import BodyState
from ..humanoid.builder import HumanoidAddresses, humanoid_addresses
from ..humanoid.skeleton import HINGE_NAMES

# Speeds no humanoid motion reaches (m/s, rad/s): treat them as a diverged simulation.
MAX_SPEED = 1.0e3
# MuJoCo's warnings that come with its automatic reset of a world.
_BAD_STATE = [int(w) for w in (mujoco.mjtWarning.mjWARN_BADQPOS, mujoco.mjtWarning.mjWARN_BADQVEL,
                                 mujoco.mjtWarning.mjWARN_BADQACC)]


class CPUSim:
    """`num_worlds` copies of `model`, stepped `substeps` physics steps per `step(ctrl)`.

    After construction, `set_state` and `step`, the arrays below hold every world's current state
    (row i is world i); they are overwritten in place by the next call.

    qpos (N, nq), qvel (N, nv) of the whole model, ctrl (N, nu), actuator_force (N, nu) of the
    last substep, sensordata (N, nsensordata), and `bodies`, a `BodyState` of the 24 humanoid
    bodies. `humanoid` (HumanoidAddresses) says where the humanoid sits in the model.
    """

    def __init__(self, model: mujoco.MjModel, num_worlds: int, substeps: int,
                 num_threads: int | None = None, humanoid: HumanoidAddresses | None = None):
        if num_worlds < 1:
            raise ValueError(f"num_worlds must be >= 1, got {num_worlds}")
        if int(substeps) < 1:
            raise ValueError(f"substeps must be >= 1, got {substeps}")
        self.model = model
        self.num_worlds = num_worlds
        self.substeps = int(substeps)
        self.humanoid = humanoid or humanoid_addresses(model)
        ids = self.humanoid.body_ids
        # Plain slices copy faster than index arrays; the builder makes the bodies contiguous.
        self._bodies = slice(int(ids[0]), int(ids[0]) + len(ids)) if np.array_equal(ids, ids[0] + np.arange(len(ids))) else ids
        self._root = self.humanoid.root
        self.datas = [mujoco.MjData(model) for _ in range(num_worlds)]
        n, nb = num_worlds, len(ids)
        self.qpos = np.zeros((n, model.nq))
        self.qvel = np.zeros((n, model.nv))
        self.ctrl = np.zeros((n, model.nu))
        self.actuator_force = np.zeros((n, model.nu))
        self.sensordata = np.zeros((n, model.nsensordata))
        self._xpos = np.zeros((n, nb, 3))
        self._xmat = np.zeros((n, nb, 9))
        self._cvel = np.zeros((n, nb, 6))
        self._com = np.zeros((n, 3))
        self._time = np.zeros(n)
        self._last_time = np.zeros(n)
        self._bad = np.zeros(n, bool)
        self._warnings = np.zeros(n, np.int64)  # MuJoCo's bad qpos/qvel/qacc warnings so far
        self._last_warnings = np.zeros(n, np.int64)
        self.pd_scales: np.ndarray | None = None    # (N, substeps, 2): kp, kd scales per substep
        self.root_wrench: np.ndarray | None = None  # (N, 6): world force (N) and torque (N m) on the pelvis
        self._damping = None  # the damping actuators meta-PD needs (found on first use)
        threads = num_threads or min(os.cpu_count() or 1, num_worlds)
        self.num_threads = max(1, min(threads, num_worlds))
        self._slices = [s for s in np.array_split(np.arange(n), self.num_threads) if len(s)]
        self._pool = ThreadPoolExecutor(self.num_threads) if self.num_threads > 1 else None
        for d in self.datas:
            mujoco.mj_step1(model, d)
        self._gather(np.arange(n), elapsed=0.0)

    # ------------------------------------------------------------------ state in and out
    def set_state(self, ids: np.ndarray, qpos: np.ndarray, qvel: np.ndarray) -> None:
        """Place worlds `ids` at (qpos, qvel), at rest otherwise (time, warnings, ctrl cleared)."""
        ids = np.asarray(ids, dtype=np.int64).reshape(-1)
        qpos, qvel = np.asarray(qpos, float).reshape(len(ids), -1), np.asarray(qvel, float).reshape(len(ids), -1)
        for k, i in enumerate(ids):
            d = self.datas[i]
            mujoco.mj_resetData(self.model, d)
            d.qpos[:] = qpos[k]
            d.qvel[:] = qvel[k]
            mujoco.mj_step1(self.model, d)
        self._last_time[ids] = 0.0
        self._last_warnings[ids] = 0
        self.ctrl[ids] = 0.0
        self.actuator_force[ids] = 0.0
        self._gather(ids, elapsed=0.0)

    def step(self, ctrl: np.ndarray, active: np.ndarray | None = None) -> np.ndarray:
        """Apply `ctrl` (N, nu) for `substeps` physics steps in every world (or only where the
        (N,) mask `active` is set); returns the (N,) mask of worlds that diverged in this step."""
        self.ctrl[:] = ctrl
        self._bad[:] = False
        slices = self._slices if active is None else [s[active[s]] for s in self._slices]
        if self._pool is None:
            for s in slices:
                self._step_slice(s)
        else:
            for f in [self._pool.submit(self._step_slice, s) for s in slices if len(s)]:
                f.result()
        return self._bad.copy()

    def _step_slice(self, ids: np.ndarray) -> None:
        m, step1, step2 = self.model, mujoco.mj_step1, mujoco.mj_step2
        if self.root_wrench is not None:
            for i in ids:
                self.datas[i].xfrc_applied[self._root] = self.root_wrench[i]
        if self.pd_scales is not None:
            self._step_slice_meta_pd(ids)
            return
        for i in ids:
            d = self.datas[i]
            d.ctrl[:] = self.ctrl[i]
            for _ in range(self.substeps):
                step2(m, d)
                step1(m, d)
        self._gather(ids, elapsed=self.substeps * m.opt.timestep)

    def _step_slice_meta_pd(self, ids: np.ndarray) -> None:
        """Substeps with the PD gains scaled per world and substep. kp: the position actuators
        pull with kp (ctrl - q), so a setpoint of q + s (target - q) pulls with s kp (target - q),
        still within the actuator's force limit. kd: the joint damping stays as built, and a
        damping actuator per hinge (force -kd qdot u, not force-limited, so implicitfast
        integrates it implicitly like the joint damping itself) adds u = s - 1 times it."""
        m, step1, step2 = self.model, mujoco.mj_step1, mujoco.mj_step2
        if self._damping is None:
            self._damping = damping_actuators(m, self.humanoid)
        pd, damp, q_adr = self.humanoid.actuators, self._damping, self.humanoid.dof_qpos
        for i in ids:
            d = self.datas[i]
            d.ctrl[:] = self.ctrl[i]
            target = self.ctrl[i, pd]
            scales = self.pd_scales[i]
            for k in range(self.substeps):
                q = d.qpos[q_adr]
                d.ctrl[pd] = q + scales[k, 0] * (target - q)
                d.ctrl[damp] = scales[k, 1] - 1.0
                step2(m, d)
                step1(m, d)
        self._gather(ids, elapsed=self.substeps * m.opt.timestep)

    def _gather(self, ids: np.ndarray, elapsed: float) -> None:
        b, root, sensors = self._bodies, self._root, self.model.nsensordata > 0
        for i in ids:
            d = self.datas[i]
            self.qpos[i] = d.qpos
            self.qvel[i] = d.qvel
            self.actuator_force[i] = d.actuator_force
            self._xpos[i] = d.xpos[b]
            self._xmat[i] = d.xmat[b]
            self._cvel[i] = d.cvel[b]
            self._com[i] = d.subtree_com[root]
            self._time[i] = d.time
            self._warnings[i] = d.warning.number[_BAD_STATE].sum()
            if sensors:
                self.sensordata[i] = d.sensordata
        # MuJoCo resets a world's data (time back to 0) on NaN or huge accelerations; beyond that,
        # non-finite or absurd speeds also count as divergence.
        # A reset inside a step's first substep leaves the clock where it should be; the warning
        # counters (cleared only by set_state's mj_resetData) still tell.
        speed = np.abs(self.qvel[ids]).max(-1)
        stepped = self._time[ids] - self._last_time[ids]
        self._bad[ids] = ((np.abs(stepped - elapsed) > 0.5 * self.model.opt.timestep) | ~(speed < MAX_SPEED)
                          | (self._warnings[ids] > self._last_warnings[ids]))
        self._last_time[ids] = self._time[ids]
        self._last_warnings[ids] = self._warnings[ids]

    @property
    def bodies(self) -> BodyState:
        """Positions, rotation matrices and velocities of the humanoid's 24 bodies, world frame."""
        ang = self._cvel[..., :3]
        # cvel is the spatial velocity at the root subtree's centre of mass; move it to each
        # body origin: v = v_com + w x (x_body - x_com).
        r = self._xpos - self._com[:, None]
        lin = self._cvel[..., 3:] + _cross(ang, r)
        return BodyState(pos=self._xpos, rot=self._xmat.reshape(*self._xmat.shape[:2], 3, 3),
                         lin_vel=lin, ang_vel=ang, dof_pos=self.qpos[:, self.humanoid.dof_qpos],
                         dof_vel=self.qvel[:, self.humanoid.dof_qvel])

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=False)
            self._pool = None


DAMPING_SUFFIX = "_damping"  # the meta-PD damping actuators are named <hinge>_damping


def damping_actuators(model: mujoco.MjModel, humanoid: HumanoidAddresses) -> slice:
    """The slice of the 69 meta-PD damping actuators (hinge order) a task added to `model`."""
    ids = np.array([mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_ACTUATOR, n + DAMPING_SUFFIX) for n in HINGE_NAMES])
    if (ids < 0).any() or not np.array_equal(ids, ids[0] + np.arange(len(ids))):
        raise ValueError("pd_scales needs the model's damping actuators (<hinge>_damping, contiguous, hinge order); "
                         "a task adds them when it offers meta-PD")
    return slice(int(ids[0]), int(ids[0]) + len(ids))


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    # np.cross costs more in call overhead than this does in arithmetic at these sizes.
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], -1)
