"""`SMPL/VRTracking-v0`: drive the whole humanoid from three points, the head and both hands, as
a VR headset and two controllers give them (REFERENCE.md sections 5 and 8).

References come from either
- full-body clips (`motions=` a clip name, motion file, directory or list, as Imitation): the
  three points are the clip's Head, L_Hand and R_Hand; episodes start on a frame of the clip in
  its reference state (random, or the first with `start="beginning"`), and the full body is known
  for the reward and the metrics; or
- three-point streams (`motions=` a stream .npz, a directory of them, a list, or a
  `ThreePointLib`; format in `smpl_envs.motion.three_point`): no full body. Episodes start from
  a standing pose (`stream_start_pose`: the first frame of the shipped "stand" clip by default,
  or "rest", the T-pose) turned and moved so that its head's heading and ground position are the
  stream's at the start frame; velocities zero. The stream's hands may start far from that
  pose's, so the first `grace_steps` steps (15, half a second) are not checked for termination
  (nor for failure by the evaluation).

Observation (float32, heading frame of the simulated humanoid; `t+1` is the next reference frame):

| slice | size | content |
|---|---|---|
| 0:358 | 358 | self observation (`smpl_envs.features.SELF_OBS_LAYOUT`) |
| 358:367 | 9 | ref - sim position of Head, L_Hand, R_Hand, t+1 (m) |
| 367:376 | 9 | ref - sim linear velocity, t+1 (m/s) |
| 376:385 | 9 | ref - sim angular velocity, t+1 (rad/s) |
| 385:394 | 9 | ref position relative to the sim pelvis, t+1 (m) |
| 394:412 | 18 | ref rotation (-) sim rotation, t+1, 6D |
| 412:430 | 18 | ref rotation, t+1, 6D |

The goal part is Imitation-v0's goal restricted to the three bodies (same blocks, same order,
24 per body; `features.body_goal_obs`), so it changes with those bodies' references only.

Reward (`reward=`; each term in `info["reward_<term>"]`):
- "full" (default where the full body is known): Imitation-v0's reward over all 24 bodies,
    0.5 exp(-100 mean ||dp||^2) + 0.3 exp(-10 mean angle^2) + 0.1 exp(-0.1 mean ||dv||^2)
    + 0.1 exp(-0.1 mean ||dw||^2) - energy_weight sum |tau qdot|;
- "three_point" (the only one for streams): the same terms with the means over the three points.
"auto" picks "full" for clips and "three_point" for streams. Weights and scales: kwargs.

Episode: ends when any of the three points is more than `termination_distance` (0.25 m, PULSE's
code; None disables) from its reference (not in the first `grace_steps` steps of an episode: 0
for clips, which start in the reference state, 15 for streams), or the simulation diverges;
truncated at the reference's last frame.

Actions: `action_mode="absolute"` (PD target = pi x a) or `"residual"` (PD target = the next
reference frame's joint angles + residual_scale x range x a), as Imitation-v0; residual needs
joint angles, so only full-body clips have it.

`info`: `point_pos` and `ref_point_pos` ((N, 3, 3) simulated and reference head and hands, world),
`point_error` ((N, 3) m), `motion_id`, `motion_time`, plus the core's entries; with clips also
`ref_body_pos` ((N, 24, 3)). Streams have no full-body entries (no `ref_body_pos`).

Evaluation (`smpl_envs.evaluate`, `smpl-envs eval`): `smpl_envs.evaluation.ThreePointProtocol`,
every clip or stream once from its first frame; success = no point beyond 0.5 m at any frame;
E_g-mpjpe, E_acc, E_vel of the three points, and of the full body where known.

Backends: "cpu" (MuJoCo, NumPy) and "warp" (MuJoCo Warp, torch tensors on `device`;
`smpl_envs.backend`), one code path: the task functions below take NumPy arrays or torch tensors,
and on the warp backend the tracker reads the clips' `DeviceFrames` or the streams'
`DeviceStreams` (the stream start poses are built on the device too).
"""

from __future__ import annotations

import mujoco
import numpy as np

from ..evaluation import ThreePointProtocol
from ..features import BodyState, body_goal_obs, goal_layout, self_obs, xp
from ..humanoid.skeleton import BODY_NAMES
from ..motion import load_motions
from ..motion.three_point import TRACKED, DeviceStreams, as_three_point_lib
from .base import HumanoidVecEnv
from .imitation import ENERGY_WEIGHT, imitation_reward, set_tracking_settings
from .reference import RESIDUAL_SCALE, ReferenceTracker

VR_GOAL_LAYOUT = goal_layout(len(TRACKED))
TERMINATION_DISTANCE = 0.25
# Steps after a stream start without the termination test: the standing start pose only matches
# the stream's head, and the hands need a moment to reach theirs (half a second).
STREAM_GRACE_STEPS = 15
REWARDS = ("auto", "full", "three_point")
MARKER_RGBA = (0.1, 0.5, 0.95, 0.85)  # the three reference points in renders
HEAD = BODY_NAMES.index("Head")


# ---------------------------------------------------------------------- pure task functions
def tracked(state: BodyState) -> BodyState:
    """The head and hands of a 24-body state (joint angles and rates kept: the energy term reads
    the whole body's)."""
    return BodyState(pos=state.pos[:, TRACKED], rot=state.rot[:, TRACKED], lin_vel=state.lin_vel[:, TRACKED],
                     ang_vel=state.ang_vel[:, TRACKED], dof_pos=state.dof_pos, dof_vel=state.dof_vel)


def point_distance(sim_pos, ref_pos):
    """(N, 3) distances (m) between the simulated and reference head and hands."""
    d = ref_pos - sim_pos
    return xp(d).sqrt((d * d).sum(axis=-1))


def vr_terminated(sim_pos, ref_pos, distance=TERMINATION_DISTANCE):
    """(N,) any of the three points farther than `distance` from its reference."""
    return (point_distance(sim_pos, ref_pos) > distance).any(axis=-1)


def yaw_of(rot):
    """(N,) heading angle of rotation matrices (N, 3, 3): the direction of their x axis."""
    return xp(rot).arctan2(rot[:, 1, 0], rot[:, 0, 0])


def turn_about_z(yaw, quat):
    """Unit quaternions `quat` (..., 4, wxyz) turned about world z by the angles `yaw`:
    quat_mul(yaw_quat(yaw), quat) with the yaw quaternion's zero terms left out (the same
    products, so the same float64 values), for NumPy and torch."""
    m = xp(yaw, quat)
    c, s = m.cos(yaw / 2), m.sin(yaw / 2)
    w, x, y, z = quat[..., 0], quat[..., 1], quat[..., 2], quat[..., 3]
    return m.stack([c * w - s * z, c * x - s * y, c * y + s * x, c * z + s * w], -1)


# ---------------------------------------------------------------------- environment
class VRTrackingVecEnv(HumanoidVecEnv):
    """`gym.make_vec("SMPL/VRTracking-v0", num_envs=N, **kwargs)`.

    kwargs: motions ("walk"; full-body clips as Imitation-v0, or three-point streams), reward
    ("auto", "full" or "three_point"), reward_weights / reward_scales (dicts over pos, rot,
    lin_vel, ang_vel), energy_weight, termination_distance (m, any of the three points; None
    disables), action_mode ("absolute" or "residual", clips only), residual_scale,
    stream_start_pose ("stand": a clip name or file whose first frame streams start from, or
    "rest"), grace_steps (steps after a reset without the termination test; None: 0 for clips,
    STREAM_GRACE_STEPS for streams), and the core's (start, beginning_share, cache, max_episode_steps, autoreset_mode,
    substeps, num_threads, render_mode, render_size, render_world, show_markers, backend,
    device).
    """

    task_layout = {"goal": VR_GOAL_LAYOUT}
    evaluation = ThreePointProtocol()
    policy_kwargs = (*HumanoidVecEnv.policy_kwargs, "action_mode", "residual_scale")  # what an action does
    backends = ("cpu", "warp")

    def __init__(self, num_envs: int = 1, *, motions="walk", reward: str = "auto",
                 reward_weights: dict | None = None, reward_scales: dict | None = None,
                 energy_weight: float = ENERGY_WEIGHT,
                 termination_distance: float | None = TERMINATION_DISTANCE, action_mode: str = "absolute",
                 residual_scale: float = RESIDUAL_SCALE, stream_start_pose: str = "stand",
                 grace_steps: int | None = None, **kwargs):
        if motions is None:
            raise ValueError("motions: VR tracking needs references (clips or three-point streams)")
        if reward not in REWARDS:
            raise ValueError(f"reward must be one of {REWARDS}, got {reward!r}")
        set_tracking_settings(self, reward_weights, reward_scales, energy_weight, termination_distance,
                              action_mode, residual_scale)
        self.streams = as_three_point_lib(motions)
        if self.streams is not None:
            if reward == "full":
                raise ValueError("reward='full' needs the full body; a three-point stream has only the head "
                                 "and hands: use reward='three_point' (or 'auto')")
            if action_mode == "residual":
                raise ValueError("action_mode='residual' adds to the reference joint angles, which a "
                                 "three-point stream does not have: use action_mode='absolute'")
        if grace_steps is None:
            grace_steps = STREAM_GRACE_STEPS if self.streams is not None else 0
        if isinstance(grace_steps, bool) or not isinstance(grace_steps, (int, np.integer)) or grace_steps < 0:
            raise ValueError(f"grace_steps must be an integer >= 0 or None, got {grace_steps!r}")
        self.grace_steps = int(grace_steps)
        self.reward_mode = ("three_point" if self.streams is not None else "full") if reward == "auto" else reward
        super().__init__(num_envs, motions=None if self.streams is not None else motions, **kwargs)
        # What the step reads of the streams: the library itself on the host, its tensors on the device.
        self.stream_frames = self.streams
        if self.streams is not None and self.backend.name != "cpu":
            self.stream_frames = DeviceStreams(self.streams, self.backend.device)
        self.ref = ReferenceTracker(self.motion_frames if self.streams is None else self.stream_frames,
                                    self.num_envs, self.backend)
        if self.streams is not None:
            pose, head, self._start_yaw = self._standing_pose(stream_start_pose)
            self._start_pose, self._start_head = self.backend.asarray(pose), self.backend.asarray(head)

    @property
    def references(self):
        """What the worlds track: the MotionLib of full-body clips, or the ThreePointLib of streams."""
        return self.motion_lib if self.streams is None else self.streams

    motion_id = property(lambda self: self.ref.motion_id)
    frame = property(lambda self: self.ref.frame)

    # ------------------------------------------------------------------ starts
    def _standing_pose(self, source: str):
        """(humanoid qpos (76,), head position (3,), head yaw) of the stream start pose."""
        if source == "rest":
            qpos = self.model.qpos0[self.humanoid.qpos].copy()
        else:
            try:
                lib = load_motions(source, cache=False)
            except (OSError, ValueError) as e:
                raise ValueError(f"stream_start_pose must be 'rest' or a clip name or motion file, got "
                                 f"{source!r} ({e})") from None
            qpos = lib.qpos_qvel(np.array([0]))[0][0].astype(np.float64)
        # Where that pose puts the head: MuJoCo's own kinematics of the pose.
        data = mujoco.MjData(self.model)
        data.qpos[self.humanoid.qpos] = qpos
        mujoco.mj_kinematics(self.model, data)
        head = self.humanoid.body_ids[HEAD]
        return qpos, data.xpos[head].copy(), float(yaw_of(data.xmat[head].reshape(1, 3, 3))[0])

    def _stream_start(self, ids, motion_ids, start):
        """Full-model (qpos, qvel) of worlds `ids` starting on streams: the standing pose turned
        about z to the stream head's heading and moved under the stream head (xy)."""
        b, xp = self.backend, self.backend.xp
        lib, n = self.stream_frames, len(ids)
        motion_ids, frames = self.start_frames(lib, n, motion_ids, start)
        self.start_motion[ids], self.start_frame[ids] = motion_ids, frames
        turn = yaw_of(b.asarray(lib.rot[frames, 0])) - self._start_yaw
        c, s = xp.cos(turn), xp.sin(turn)
        root = self._start_pose[:3] - self._start_head  # pelvis seen from the head
        pose = b.rows(self._start_pose, n)
        pose[:, 0] = lib.pos[frames, 0, 0] + c * root[0] - s * root[1]
        pose[:, 1] = lib.pos[frames, 0, 1] + s * root[0] + c * root[1]
        pose[:, 3:7] = turn_about_z(turn, self._start_pose[3:7])
        qpos = b.rows(self._qpos0, n)
        qpos[:, self.humanoid.qpos] = pose
        return qpos, b.zeros((n, self.model.nv))

    # ------------------------------------------------------------------ task hooks
    def _reset_task(self, ids, options):
        if self.streams is None:
            qpos, qvel = super()._reset_task(ids, options)
        else:
            qpos, qvel = self._stream_start(ids, options.get("motion_ids"), options.get("start", self.start))
        self.ref.begin(ids, self.start_motion[ids], self.start_frame[ids])
        return qpos, qvel

    def _ctrl(self, actions):
        return self.ref.pd_targets(actions, self.action_scale, self.action_mode, self.residual_scale)

    def _advance(self, active):
        self.ref.advance(active)

    def _points(self, ref: BodyState) -> BodyState:
        return ref if self.streams is not None else tracked(ref)

    def _evaluate(self, body, heading):
        ref = self.ref.current()
        ref_points = self._points(ref)
        if self.reward_mode == "full":
            reward, terms = imitation_reward(body, ref, self.sim.actuator_force, self.reward_weights,
                                             self.reward_scales, self.energy_weight)
        else:
            reward, terms = imitation_reward(tracked(body), ref_points, self.sim.actuator_force,
                                             self.reward_weights, self.reward_scales, self.energy_weight)
        terminated = (self.backend.zeros(self.num_envs, "bool") if self.termination_distance is None
                      else vr_terminated(body.pos[:, TRACKED], ref_points.pos, self.termination_distance))
        if self.grace_steps:
            terminated &= self.elapsed >= self.grace_steps
        return reward, terms, terminated, self.ref.at_end()

    def _observe(self, body, heading):
        goal = body_goal_obs(body, self._points(self.ref.next()), TRACKED, heading)
        return self.backend.xp.concatenate([self_obs(body, heading), goal], -1)

    def _task_info(self, body):
        ref = self.ref.current()
        b = self.backend
        sim_points, ref_points = body.pos[:, TRACKED], self._points(ref).pos
        info = {"motion_id": b.copy(self.ref.motion_id), "motion_time": self.ref.motion_time(),
                "point_pos": b.float32(sim_points), "ref_point_pos": b.copy(ref_points),
                "point_error": point_distance(sim_points, ref_points)}
        if self.streams is None:
            info["ref_body_pos"] = b.copy(ref.pos)  # a copy: the tracker caches the array
        return info

    def _markers(self, world):
        frame = int(self.ref.frame[world])  # drawn from the host library on either backend
        return [(self.references.body_pos[frame][TRACKED] if self.streams is None
                 else self.streams.pos[frame], MARKER_RGBA, 0.05)]

    def reference_action(self) -> np.ndarray:
        """(N, 69) actions whose PD targets are the next reference frame's joint angles (clips
        only): the policy-free baseline "track the reference with PD alone"."""
        if self.streams is not None:
            raise ValueError("reference_action needs the reference joint angles; a three-point stream has none")
        return self.ref.reference_action(self.action_scale, self.action_mode)
