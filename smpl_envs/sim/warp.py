"""N humanoid worlds on MuJoCo Warp (GPU, or Warp's CPU device): `CPUSim`'s interface on torch.

One compiled `MjModel` (the humanoid plus whatever a task added: a box, contact sensors, a
heightfield) is put on the device once with `mujoco_warp.put_model`, and `put_data` allocates
`num_worlds` worlds of it. Every state array of the Warp `Data` is exposed as a zero-copy torch
view (`wp.to_torch`), so actions go in and states come out without a host round trip.

Members (torch tensors on `device`, float32 as MuJoCo Warp computes; row i is world i; views
that the next `set_state` / `step` overwrite in place, as `CPUSim`'s arrays are):

| member | shape | |
|---|---|---|
| qpos, qvel | (N, nq), (N, nv) | whole-model state |
| ctrl | (N, nu) | PD targets of the last step |
| actuator_force | (N, nu) | of the last substep |
| sensordata | (N, nsensordata) | of the last substep, acceleration-stage sensors included (then a fresh tensor) |
| bodies | BodyState of (N, 24, ...) | the humanoid's 24 bodies, world frame (a fresh tensor each read) |
| overflow | (N,) int32 | MuJoCo Warp's overflow bits per world (`mujoco_warp.OverflowType`), cleared by `set_state` |

`to_numpy(x)` turns a tensor, a `BodyState` or a dict of them into NumPy (zero-copy on the CPU).

Control: the humanoid's actuators are MuJoCo position actuators (gain kp, bias -kp q - kd qdot),
so writing the PD targets into `ctrl` and stepping `substeps` times inside `step` is the CPU
backend's control law, run by the physics engine.

Observed state (the CPU backend's step1/step2 convention): each substep is `step2` then `step1`
(MuJoCo Warp has both halves too), and `set_state` ends with `step1`. So positions, rotations and
com-based velocities always describe the *current* state, as in `CPUSim`, with no extra forward
call. One difference of MuJoCo Warp is handled here: its `step1` clears every sensor, also the
acceleration-stage ones (touch, force, accelerometer) that the `step2` before it computed and that
CPU MuJoCo keeps (its `step2` adds onto the cleared values, so they cannot simply be written
back); they are copied aside after the last `step2`, and `sensordata` merges them in.

Divergence: a world whose qpos or qvel turns non-finite, or whose speed reaches `cpu.MAX_SPEED`,
is set in the (N,) bool tensor `step` returns; the task resets that world alone with `set_state`.
A small Warp kernel checks after every substep's integration and parks such a world at the
model's rest pose (qpos0, at rest) before collision detection runs, as CPU MuJoCo resets a world
on a bad state: MuJoCo Warp's contact pool (`nconmax` x N) is shared by all worlds, and a world
flung through the floor would otherwise take the other worlds' contact slots. So a diverged world
leaves the others bit-identical (the tests check it).

Masks: `set_state(ids, ...)` resets worlds `ids` with `mujoco_warp.reset_data(reset=mask)`, writes
their state and re-runs `step1` over all worlds (it is a pure function of each world's state, so
the other worlds' outputs come out unchanged, the price is half a substep). `step(ctrl, active)`
steps every world (one launch serves all) and then puts the inactive worlds' state back, with
`torch.where` on the device (no host sync), and runs `step1` again when some world is inactive.

CUDA: the substep loop is captured once in a CUDA graph (`graph=True`, the default) and replayed
each step; if capture fails the loop runs eagerly. Warp works on its own stream, ordered after
and before torch's current stream with events, so torch code may read and write the views freely.

SimPoE's two inputs (`SMPL/VideoPose-v0` only), as on `CPUSim`: assigning `pd_scales` (N,
substeps, 2) turns meta-PD on (a small kernel sets each substep's scaled setpoints and damping
controls, inside the CUDA graph, which is captured again), and assigning `root_wrench` (N, 6)
turns the pelvis force and torque on (written into `xfrc_applied` before each step). Both are
then device tensors that the task writes in place, as it writes CPUSim's arrays; None turns them
off again. (The meta-PD graph's recapture has not yet run on a GPU.)

Parity with `CPUSim` (tests/test_sim_warp.py, Warp's CPU device): float32 here, float64 there.
While both see the same contacts, states agree to ~1e-6 (a standing humanoid: 1e-6 after 30
control steps). A contact that starts or ends within float32 rounding of distance zero does so a
substep earlier on one backend, and that world's state then differs by up to ~1e-2 within a few
steps and grows as contacts make motion chaotic (walk / run / turn clips tracked for 60 steps:
0.2-0.8 at worst). Start poses with the feet exactly at z = 0 (as the shipped clips have) are
such a case: the first substep already differs.
"""

from __future__ import annotations

from dataclasses import fields

import mujoco
import numpy as np
import torch
import warp as wp
import mujoco_warp as mjw

from ..features import BodyState
from ..humanoid.builder import HumanoidAddresses, humanoid_addresses
from .cpu import MAX_SPEED, damping_actuators

# Contacts per world and constraint rows (pyramidal friction cone of condim 3: 4 rows a contact).
# The humanoid touches the floor at 2-8 points standing or lying, and at 52 (208 rows) with every
# geom below it, so these hold the worst case with room for a task's box; MuJoCo Warp's defaults
# (48, 64) are sized for a standing robot. Overflowing them drops contacts (`overflow` tells).
NCONMAX = 64
NJMAX = 256


@wp.kernel(enable_backward=False)
def _park_diverged(qpos0: wp.array(dtype=float), max_speed: float, qpos: wp.array2d(dtype=float),
                   qvel: wp.array2d(dtype=float), warmstart: wp.array2d(dtype=float), bad: wp.array(dtype=wp.int32)):
    # A world whose state blew up is put back at the model's rest pose, at rest, before collision
    # detection sees it (as CPU MuJoCo resets a world on bad qpos / qvel / qacc): Warp's contact
    # pool is shared by all worlds, and a world flung through the floor would fill it.
    w = wp.tid()
    n_bad = int(0)
    for i in range(qvel.shape[1]):
        x = qvel[w, i]
        if wp.isnan(x) or wp.abs(x) >= max_speed:
            n_bad += 1
    for i in range(qpos.shape[1]):
        if wp.isnan(qpos[w, i]) or wp.isinf(qpos[w, i]):
            n_bad += 1
    if n_bad > 0:
        bad[w] = 1
        for i in range(qpos.shape[1]):
            qpos[w, i] = qpos0[i]
        for i in range(qvel.shape[1]):
            qvel[w, i] = 0.0
            warmstart[w, i] = 0.0


@wp.kernel(enable_backward=False)
def _meta_pd_ctrl(k: int, q0: int, pd0: int, damp0: int, target: wp.array2d(dtype=float),
                  scales: wp.array3d(dtype=float), qpos: wp.array2d(dtype=float), ctrl: wp.array2d(dtype=float)):
    # Substep k's controls of CPUSim._step_slice_meta_pd: a setpoint of q + s_kp (target - q)
    # pulls with s_kp times the gain, and the damping actuator adds (s_kd - 1) times the damping.
    w, j = wp.tid()
    q = qpos[w, q0 + j]
    ctrl[w, pd0 + j] = q + scales[w, k, 0] * (target[w, j] - q)
    ctrl[w, damp0 + j] = scales[w, k, 1] - 1.0


def to_numpy(x):
    """NumPy of a tensor, a `BodyState` of tensors, or a dict / tuple / list of them (zero-copy
    for CPU tensors); anything else is returned as it is."""
    if isinstance(x, torch.Tensor):
        return x.detach().cpu().numpy()
    if isinstance(x, BodyState):
        return BodyState(**{f.name: to_numpy(getattr(x, f.name)) for f in fields(x)})
    if isinstance(x, dict):
        return {k: to_numpy(v) for k, v in x.items()}
    if isinstance(x, (tuple, list)):
        return type(x)(to_numpy(v) for v in x)
    return x


class WarpSim:
    """`num_worlds` copies of `model` on MuJoCo Warp, stepped `substeps` physics steps per
    `step(ctrl)`; the interface of `CPUSim` with torch tensors on `device` (see the module).

    device: "cpu", "cuda" or "cuda:k" (default: "cuda" when Warp sees one, else "cpu").
    nconmax / njmax: contacts and constraint rows allocated per world. graph: capture the substep
    loop in a CUDA graph (ignored on the CPU). deterministic: ask MuJoCo Warp for stable contact
    and constraint ordering on CUDA (slower; the CPU device is deterministic anyway).
    """

    def __init__(self, model: mujoco.MjModel, num_worlds: int, substeps: int, device: str | None = None,
                 humanoid: HumanoidAddresses | None = None, nconmax: int = NCONMAX, njmax: int = NJMAX,
                 graph: bool = True, deterministic: bool = False):
        for name, value in (("num_worlds", num_worlds), ("substeps", substeps), ("nconmax", nconmax), ("njmax", njmax)):
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
                raise ValueError(f"{name} must be a positive integer, got {value!r}")
        wp.init()
        if device is None:
            device = "cuda" if wp.is_cuda_available() else "cpu"
        try:
            self._wp_device = wp.get_device(device)
        except Exception as e:  # Warp raises its own error types for unknown devices
            raise ValueError(f"device must be 'cpu' or a CUDA device Warp sees ('cuda', 'cuda:0'), got {device!r}: {e}") from None
        self.device = torch.device(wp.device_to_torch(self._wp_device))
        self.model = model
        self.num_worlds = int(num_worlds)
        self.substeps = int(substeps)
        self.humanoid = humanoid or humanoid_addresses(model)
        ids = self.humanoid.body_ids
        self._bodies = (slice(int(ids[0]), int(ids[0]) + len(ids)) if np.array_equal(ids, ids[0] + np.arange(len(ids)))
                        else torch.as_tensor(ids, device=self.device))
        self._root = self.humanoid.root
        self._cuda = self._wp_device.is_cuda

        with wp.ScopedDevice(self._wp_device):
            self.wp_model = mjw.put_model(model)
            if deterministic:
                self.wp_model.opt.deterministic = mjw.DeterminismType.ALL
            host = mujoco.MjData(model)
            mujoco.mj_forward(model, host)
            self.wp_data = mjw.put_data(model, host, nworld=self.num_worlds, nconmax=int(nconmax), njmax=int(njmax))
            self._stream = wp.get_stream(self._wp_device) if self._cuda else None
        d, view = self.wp_data, wp.to_torch
        self.qpos, self.qvel, self.ctrl = view(d.qpos), view(d.qvel), view(d.ctrl)
        self.actuator_force, self._sensordata = view(d.actuator_force), view(d.sensordata)
        self.overflow = view(d.overflow)
        self._xpos, self._xmat, self._cvel = view(d.xpos), view(d.xmat), view(d.cvel)
        self._subtree_com = view(d.subtree_com)
        # Everything a world carries from one step to the next: put back for inactive worlds.
        acc = np.zeros(model.nsensordata, bool)
        for i in np.flatnonzero(model.sensor_needstage == mujoco.mjtStage.mjSTAGE_ACC):
            acc[model.sensor_adr[i]:model.sensor_adr[i] + model.sensor_dim[i]] = True
        self._acc_sensors = torch.as_tensor(acc, device=self.device) if acc.any() else None
        self._sensor_acc = torch.zeros_like(self._sensordata)
        self._carried = [self.qpos, self.qvel, self.ctrl, view(d.act), view(d.qacc_warmstart), view(d.time),
                         self.actuator_force, self._sensordata, self._sensor_acc]
        self._bad = torch.zeros(self.num_worlds, dtype=torch.bool, device=self.device)
        self._parked = wp.zeros(self.num_worlds, dtype=wp.int32, device=self._wp_device)
        self._parked_t = wp.to_torch(self._parked)
        self._qpos0 = wp.array(model.qpos0.astype(np.float32), device=self._wp_device)

        self._xfrc = view(d.xfrc_applied)
        # SimPoE's inputs, off (the properties below).
        self._pd_scales = self._pd_target = self._damping = self._root_wrench = None

        # Load every kernel (a graph cannot compile), then start all worlds at the model's rest.
        self._graph = None
        self._use_graph = bool(graph) and self._cuda
        self._run(self._substeps_eager)
        self._run(self._reset_mask, torch.ones(self.num_worlds, dtype=torch.bool, device=self.device))
        if self._use_graph:
            self._recapture()
            self._run(self._reset_mask, torch.ones(self.num_worlds, dtype=torch.bool, device=self.device))

    def _recapture(self) -> None:
        """(Re)capture the substep loop in a CUDA graph; the loop's launches changed (or first)."""
        if not self._use_graph:
            return
        self._graph = None
        try:
            self._run(self._capture)
        except Exception as e:  # a driver without conditional graph nodes, say: run eagerly
            import warnings

            warnings.warn(f"CUDA graph capture failed, stepping without a graph: {e}")
            self._graph = None
            self._use_graph = False

    # ------------------------------------------------------------------ SimPoE's inputs
    @property
    def pd_scales(self) -> torch.Tensor | None:
        """(N, substeps, 2) per-substep scales of the PD gains (kp, kd), or None (meta-PD off)."""
        return self._pd_scales

    @pd_scales.setter
    def pd_scales(self, value) -> None:
        was_on = self._pd_scales is not None
        if value is None:
            self._pd_scales = self._pd_target = None
        elif was_on:
            self._pd_scales.copy_(self._input("pd_scales", value, self._pd_scales.shape))  # the graph reads this memory
        else:
            self._damping = damping_actuators(self.model, self.humanoid)
            pd = self.humanoid.actuators
            self._pd_scales = self._input("pd_scales", value, (self.num_worlds, self.substeps, 2)).clone()
            self._pd_target = torch.zeros((self.num_worlds, pd.stop - pd.start), dtype=self.qpos.dtype,
                                          device=self.device)
        if was_on != (self._pd_scales is not None):
            self._recapture()  # the substep loop gains or loses the meta-PD launches

    @property
    def root_wrench(self) -> torch.Tensor | None:
        """(N, 6) world force (N) and torque (N m) on the pelvis, or None (off)."""
        return self._root_wrench

    @root_wrench.setter
    def root_wrench(self, value) -> None:
        if value is None and self._root_wrench is not None:
            self._xfrc[:, self._root] = 0.0
        self._root_wrench = None if value is None else self._input("root_wrench", value, (self.num_worlds, 6)).clone()

    def _input(self, name: str, value, shape) -> torch.Tensor:
        value = torch.as_tensor(value, dtype=self.qpos.dtype, device=self.device)
        if tuple(value.shape) != tuple(shape):
            raise ValueError(f"{name} must have shape {tuple(shape)}, got {tuple(value.shape)}")
        return value

    # ------------------------------------------------------------------ state in and out
    def set_state(self, ids, qpos, qvel) -> None:
        """Place worlds `ids` at (qpos, qvel), at rest otherwise (time, ctrl, forces, warm start,
        overflow bits cleared). Arrays may be NumPy or torch; they are copied to the device."""
        if not (isinstance(ids, torch.Tensor) and ids.is_cuda):  # checked on the host; CUDA ids unchecked (no sync)
            host = np.asarray(ids.cpu() if isinstance(ids, torch.Tensor) else ids).reshape(-1)
            if host.size and (host.dtype.kind not in "iu" or host.min() < 0 or host.max() >= self.num_worlds):
                raise ValueError(f"ids must be integer world indices in [0, {self.num_worlds}), got {host!r}")
        ids = torch.as_tensor(ids, device=self.device).reshape(-1).long()
        n = len(ids)
        qpos = torch.as_tensor(qpos, dtype=self.qpos.dtype, device=self.device)
        qvel = torch.as_tensor(qvel, dtype=self.qvel.dtype, device=self.device)
        if qpos.numel() != n * self.model.nq or qvel.numel() != n * self.model.nv:
            raise ValueError(f"qpos and qvel must be ({n}, {self.model.nq}) and ({n}, {self.model.nv}) for {n} ids, "
                             f"got {tuple(qpos.shape)} and {tuple(qvel.shape)}")
        mask = torch.zeros(self.num_worlds, dtype=torch.bool, device=self.device)
        mask[ids] = True
        self._run(self._reset_mask, mask, ids, qpos.reshape(n, -1), qvel.reshape(n, -1))

    def _reset_mask(self, mask, ids=None, qpos=None, qvel=None) -> None:
        mjw.reset_data(self.wp_model, self.wp_data, reset=wp.from_torch(mask))
        if ids is not None:
            self.qpos[ids] = qpos
            self.qvel[ids] = qvel
        self.actuator_force.masked_fill_(mask[:, None], 0.0)  # reset_data leaves it
        self._sensor_acc.masked_fill_(mask[:, None], 0.0)
        self._parked_t.masked_fill_(mask, 0)
        self._park()  # a bad state placed here is parked now and reported by the next step
        self._step1()

    def step(self, ctrl, active=None) -> torch.Tensor:
        """Apply `ctrl` (N, nu) for `substeps` physics steps in every world (or only where the
        (N,) bool mask `active` is set: the others keep their state); returns the (N,) bool
        tensor of worlds that diverged in this step (never an inactive one)."""
        ctrl = torch.as_tensor(ctrl, dtype=self.ctrl.dtype, device=self.device)
        if ctrl.shape != self.ctrl.shape:
            raise ValueError(f"ctrl must have shape {tuple(self.ctrl.shape)}, got {tuple(ctrl.shape)}")
        if active is not None:
            active = torch.as_tensor(active, dtype=torch.bool, device=self.device).reshape(-1)
            if active.shape != (self.num_worlds,):
                raise ValueError(f"active must be a bool mask of {self.num_worlds} worlds, got shape {tuple(active.shape)}")
        self._run(self._step, ctrl, active)
        return self._bad.clone()

    def _step(self, ctrl, active) -> None:
        saved = None if active is None else [a.clone() for a in self._carried]
        self.ctrl.copy_(ctrl)
        if self._root_wrench is not None:
            self._xfrc[:, self._root] = self._root_wrench
        if self._pd_scales is not None:
            self._pd_target.copy_(ctrl[:, self.humanoid.actuators])
        if self._graph is not None:
            wp.capture_launch(self._graph, stream=self._stream)
        else:
            self._substeps_eager()
        if self._pd_scales is not None:
            self.ctrl.copy_(ctrl)  # the PD targets given, as CPUSim keeps them (the kernel rewrote them)
        torch.ne(self._parked_t, 0, out=self._bad)
        self._parked_t.zero_()
        if active is not None:
            keep = ~active
            for a, s in zip(self._carried, saved):
                a.copy_(torch.where(keep.reshape(-1, *[1] * (a.dim() - 1)), s, a))
            self._bad &= active
            # The derived quantities (kinematics, contacts, mass matrix) of the restored worlds
            # belong to their old state again; acceleration-stage sensors were restored above.
            self._step1()

    def _substeps_eager(self) -> None:
        for k in range(self.substeps):
            if self._pd_scales is not None:
                self._launch_meta_pd(k)
            mjw.step2(self.wp_model, self.wp_data)
            self._park()
            if k == self.substeps - 1 and self._acc_sensors is not None:
                # step1 zeroes every sensor (MuJoCo Warp's step2 adds onto zeroed values), while
                # CPU MuJoCo keeps the acceleration-stage ones of the last step2: keep a copy.
                self._sensor_acc.copy_(self._sensordata)
            self._step1()

    def _launch_meta_pd(self, k: int) -> None:
        pd, d = self.humanoid.actuators, self.wp_data
        wp.launch(_meta_pd_ctrl, dim=(self.num_worlds, pd.stop - pd.start),
                  inputs=[k, self.humanoid.dof_qpos.start, pd.start, self._damping.start,
                          wp.from_torch(self._pd_target), wp.from_torch(self._pd_scales), d.qpos, d.ctrl])

    def _park(self) -> None:
        d = self.wp_data
        wp.launch(_park_diverged, dim=self.num_worlds, inputs=[self._qpos0, MAX_SPEED, d.qpos, d.qvel, d.qacc_warmstart,
                                                               self._parked])

    def _capture(self) -> None:
        with wp.ScopedCapture(stream=self._stream) as capture:
            self._substeps_eager()
        self._graph = capture.graph

    def _step1(self) -> None:
        mjw.step1(self.wp_model, self.wp_data)

    @property
    def sensordata(self) -> torch.Tensor:
        """(N, nsensordata) after the last substep, acceleration-stage sensors (touch, force,
        accelerometer) included as on the CPU; a view when the model has none of those."""
        if self._acc_sensors is None:
            return self._sensordata
        return torch.where(self._acc_sensors, self._sensor_acc, self._sensordata)

    def _run(self, fn, *args) -> None:
        # On CUDA, Warp's stream runs after what torch queued before, and torch's after Warp's.
        if not self._cuda:
            fn(*args)
            return
        torch_stream = wp.stream_from_torch(torch.cuda.current_stream(self.device))
        self._stream.wait_stream(torch_stream)
        with wp.ScopedDevice(self._wp_device), wp.ScopedStream(self._stream), torch.cuda.stream(
                torch.cuda.ExternalStream(self._stream.cuda_stream, device=self.device)):
            fn(*args)
        torch_stream.wait_stream(self._stream)

    @property
    def bodies(self) -> BodyState:
        """Positions, rotation matrices and velocities of the humanoid's 24 bodies, world frame
        (torch tensors on the device)."""
        b = self._bodies
        pos, cvel = self._xpos[:, b], self._cvel[:, b]
        ang = cvel[..., :3]
        # cvel is the spatial velocity at the root subtree's centre of mass; move it to each
        # body origin: v = v_com + w x (x_body - x_com).
        lin = cvel[..., 3:] + torch.linalg.cross(ang, pos - self._subtree_com[:, self._root, None], dim=-1)
        return BodyState(pos=pos, rot=self._xmat[:, b], lin_vel=lin, ang_vel=ang,
                         dof_pos=self.qpos[:, self.humanoid.dof_qpos], dof_vel=self.qvel[:, self.humanoid.dof_qvel])

    def close(self) -> None:
        self._graph = None
