"""`SMPL/VideoPose-v0`: physically plausible motion from what a video pipeline gives (SimPoE,
Yuan et al. 2021; REFERENCE section 7). The humanoid follows a kinematic pose estimate frame by
frame while it also sees the 2D keypoints the estimate came with, and gives back motion that is
physically possible and, with a trained policy, closer to the truth.

Input (`smpl_envs.motion.video_input.VideoLib`), from one of two sources:
- `motions=`: any clips of the suite (a clip name, "corpus:train", files, a directory, a list),
  degraded by the seeded estimator model (`smpl_envs.motion.estimator_noise`: jitter, depth
  drift along the camera ray, foot sliding, ground penetration, per-joint rotation error; 2D
  keypoints through a random plausible camera with noise, low confidences and occlusions), with
  knobs `noise` (a dict over `EstimatorNoise`'s defaults), `noise_scale` and `noise_seed`. The
  clean clip is the ground truth of the reward and the metrics. Default: the walk clip.
  `noise_scale_range` (lo, hi), for training only: each clip's noise times a scale of its own,
  drawn uniformly in [lo, hi] (seeded), so a policy learns on easy and hard input at once; the
  evaluation leaves it out and measures at `noise_scale`.
- `video=`: real estimator output (`smpl_envs.motion.estimator_files`: SMPL parameters, COCO-17
  or BODY-25 keypoints, intrinsics) or VideoInputs / a VideoLib. No ground truth: the reward's
  pose, velocity and joint terms measure against the estimate, and the evaluation reports the
  physics metrics and the reprojection error only.

Episodes start on a frame of a sequence (random, or the first with `start="beginning"`) in the
estimate's pose and velocities, raised just enough for its lowest point to clear the floor where
the estimate sinks into it. One frame per step (30 Hz, 4 physics substeps).

Observation (float32, 1087; `smpl_envs.video_features` has the table): the self observation
(358), Imitation-v0's goal towards the next frame's estimate (576; the first 934 columns are
Imitation-v0's observation with the estimate as reference), the estimate's joint angles (69),
the 24 bodies' keypoints in normalised image coordinates (48) and confidences (24), and the
camera's rotation (9) and centre (3) in the humanoid's heading frame.

Actions, in [-1, 1] (`env.unwrapped.action_layout` names the slices):
- 0:69, residual PD targets around the estimate (SimPoE's residual angles): target = the next
  frame's estimated joint angles + residual_scale x range x a. A policy with a refinement unit
  (`agents.simpoe.KinematicRefinement`) puts its refined pose into these residuals.
- with `meta_pd=True`, 2 x substeps more: per substep, scales of every PD gain, kp then kd,
  s = meta_pd_range ** a (in [1/range, range]; 1 at a = 0). Off by default.
- with `residual_force=True`, 6 more: a force (residual_force_scale N x a) and torque
  (residual_torque_scale N m x a) on the pelvis, in the heading frame: SimPoE's residual root
  force, the suite's one external force, off by default. Every result table says whether it
  was on (`residual_force` is a policy setting, so checkpoints and evaluations carry it).

Reward (SimPoE's multiplicative form; each factor in `info["reward_<term>"]`, the reward is
their product), against the ground truth where it is known, else the estimate:
    pose      exp(-reward_scales["pose"] mean_b angle(R_b, R*_b)^2)              (10)
    velocity  exp(-reward_scales["velocity"] mean ||v_b - v*_b||^2)              (0.1)
    joint     exp(-reward_scales["joint"] mean ||(p_b - p_0) - (p*_b - p*_0)||^2) (100)
    keypoint  exp(-reward_scales["keypoint"] sum_j c_j ||proj(p_j) - x_j||^2 / sum_j c_j)  (500,
              normalised image coordinates: the simulated bodies reprojected against the keypoints)
Means over the 24 bodies (and xyz).

Episode: ends on a fall (`base.fallen`), a divergence, or (training) when the bodies are on
average more than `termination_distance` (0.5 m; None disables) from the estimate they follow
(not from the truth: where the truth is in the world, its depth above all, is not observable);
truncated at the sequence's last frame.

`info`: the reward factors, `est_body_pos` and (with ground truth) `truth_body_pos` (N, 24, 3)
of the current frame, `next_est_dof_pos` and `next_truth_dof_pos` (N, 69), (with ground truth)
`next_truth_root_pos` (N, 3: the next frame's true pelvis relative to the simulated one, heading
frame, as the observation's estimate root), `foot_points`
(N, 32, 3), `reprojection_error` (N, px, confidence-weighted mean over keypoints) and
`keypoint_weight` (N, the confidences' sum), `fallen`, `motion_id`, `motion_time`, and the core's.

Evaluation: `smpl_envs.video_eval.VideoProtocol` (every sequence once; MPJPE, PA-MPJPE, Accel,
foot sliding, ground penetration, reprojection error, no-fall share).

Backends: "cpu" and "warp" (both simulators take meta-PD's per-substep gain scales and the root
wrench; on MuJoCo Warp the video arrays the task reads every step live on the device).
"""

from __future__ import annotations

import mujoco
import numpy as np
from gymnasium import spaces
from gymnasium.vector.utils import batch_space

from ..features import BodyState, heading_rotation, rotation_angle, to_heading, tracking_obs, xp
from ..humanoid.skeleton import HINGE_NAMES, KD, NUM_HINGES
from ..sim.cpu import DAMPING_SUFFIX
from ..video_eval import VideoProtocol
from ..video_features import (VIDEO_TASK_LAYOUT, camera_in_heading, foot_points, reprojection_residual, video_obs,
                              weighted_mean)
from ..motion.library import DeviceFrames
from ..motion.video_input import VideoLib
from ..video_sources import video_library
from .base import HumanoidVecEnv, check_number, fallen
from .imitation import _merge, mean_body_distance
from .reference import RESIDUAL_SCALE, ReferenceTracker, check_action_mode

TERMS = ("pose", "velocity", "joint", "keypoint")
REWARD_SCALES = {"pose": 10.0, "velocity": 0.1, "joint": 100.0, "keypoint": 500.0}
TERMINATION_DISTANCE = 0.5
META_PD_RANGE = 2.0
RESIDUAL_FORCE_SCALE = 300.0   # N at |a| = 1 (about 40 % of the body's weight)
RESIDUAL_TORQUE_SCALE = 100.0  # N m at |a| = 1
INPUT_RGBA = (0.9, 0.2, 0.1, 0.8)   # the kinematic input's bodies in renders
TRUTH_RGBA = (0.1, 0.8, 0.3, 0.8)   # the ground truth's


# ---------------------------------------------------------------------- pure task functions
def videopose_reward(sim: BodyState, target: BodyState, keypoint_sq, confidence, scales=REWARD_SCALES):
    """(reward (N,), {term: (N,)}): the module docstring's product of four factors; keypoint_sq
    (N, 24) squared reprojection residuals of the simulated bodies, confidence (N, 24)."""
    m = xp(sim.pos)
    nb = sim.pos.shape[1]
    angle = rotation_angle(target.rot, sim.rot)
    dv = target.lin_vel - sim.lin_vel
    dp = (target.pos - target.pos[:, :1]) - (sim.pos - sim.pos[:, :1])
    errors = {"pose": (angle * angle).sum(-1) / nb, "velocity": (dv * dv).sum((-1, -2)) / (3 * nb),
              "joint": (dp * dp).sum((-1, -2)) / (3 * nb), "keypoint": weighted_mean(keypoint_sq, confidence)}
    terms = {k: m.exp(-scales[k] * errors[k]) for k in TERMS}
    reward = terms["pose"] * terms["velocity"] * terms["joint"] * terms["keypoint"]
    return reward, terms


# ---------------------------------------------------------------------- environment
class VideoPoseVecEnv(HumanoidVecEnv):
    """`gym.make_vec("SMPL/VideoPose-v0", num_envs=N, **kwargs)` (module docstring).

    kwargs: motions (clips to degrade; default "walk") or video (estimator output), noise,
    noise_scale (1.0), noise_seed (0), noise_scale_range (None; training only), reward_scales (dict over pose, velocity, joint, keypoint),
    termination_distance (0.5 m; None disables), residual_scale (0.25), meta_pd (False),
    meta_pd_range (2.0), residual_force (False), residual_force_scale (300 N),
    residual_torque_scale (100 N m), ghost_offset ((0, 0, 0) m: where renders draw the input and
    truth markers relative to their place, e.g. (0, 1, 0) beside the body), and the core's (start,
    beginning_share, failure_sampling, motion_weights, cache, max_episode_steps, autoreset_mode,
    substeps, num_threads, render_mode, render_size, render_world, show_markers).
    """

    task_layout = VIDEO_TASK_LAYOUT
    evaluation = VideoProtocol()
    # What an action and an observation mean: a policy runs only with the values it trained with.
    policy_kwargs = (*HumanoidVecEnv.policy_kwargs, "residual_scale", "meta_pd", "meta_pd_range", "residual_force",
                     "residual_force_scale", "residual_torque_scale")
    backends = ("cpu", "warp")

    def __init__(self, num_envs: int = 1, *, motions=None, video=None, noise: dict | None = None,
                 noise_scale: float = 1.0, noise_seed: int = 0, noise_scale_range: tuple[float, float] | None = None,
                 reward_scales: dict | None = None,
                 termination_distance: float | None = TERMINATION_DISTANCE, residual_scale: float = RESIDUAL_SCALE,
                 meta_pd: bool = False, meta_pd_range: float = META_PD_RANGE, residual_force: bool = False,
                 residual_force_scale: float = RESIDUAL_FORCE_SCALE,
                 residual_torque_scale: float = RESIDUAL_TORQUE_SCALE, ghost_offset=(0.0, 0.0, 0.0), **kwargs):
        self.reward_scales = _merge("reward_scales", REWARD_SCALES, reward_scales)
        if termination_distance is not None and not float(termination_distance) > 0:
            raise ValueError(f"termination_distance must be a positive distance in metres or None, "
                             f"got {termination_distance!r}")
        self.termination_distance = termination_distance
        self.residual_scale = check_action_mode("residual", residual_scale)
        for name, flag in (("meta_pd", meta_pd), ("residual_force", residual_force)):
            if not isinstance(flag, (bool, np.bool_)):
                raise ValueError(f"{name} must be True or False, got {flag!r}")
        self.meta_pd, self.residual_force = bool(meta_pd), bool(residual_force)
        self.meta_pd_range = check_number("meta_pd_range", meta_pd_range, positive=True)
        if self.meta_pd_range < 1:
            raise ValueError(f"meta_pd_range must be >= 1 (gain scales lie in [1/range, range]), got {meta_pd_range!r}")
        self.residual_force_scale = check_number("residual_force_scale", residual_force_scale)
        self.residual_torque_scale = check_number("residual_torque_scale", residual_torque_scale)
        self.ghost_offset = np.asarray(ghost_offset, float).reshape(3)
        self.video: VideoLib = video_library(motions, video, noise=noise, noise_scale=noise_scale,
                                             noise_seed=noise_seed, noise_scale_range=noise_scale_range,
                                             cache=kwargs.get("cache", True))
        super().__init__(num_envs, motions=self.video.estimate, **kwargs)
        b = self.backend
        self.truth = self.video.truth
        self.ref = ReferenceTracker(self.motion_frames, self.num_envs, b)
        # What every step reads of the input, where the task's arrays live (the host library's own
        # arrays on the CPU backend; device copies on MuJoCo Warp).
        on = (lambda x: x) if b.name == "cpu" else b.asarray
        v = self.video
        self._keypoints, self._confidence, self._start_lift = on(v.keypoints), on(v.confidence), on(v.start_lift)
        self._cam_rotation, self._cam_position, self._focal = on(v.cam_rotation), on(v.cam_position), on(v.focal)
        self._truth = self.truth if self.truth is None or b.name == "cpu" else DeviceFrames(self.truth, b.device)

        # The action: 69 residual targets, then meta-PD's gain scales, then the root wrench.
        sizes = {"residual": NUM_HINGES, "meta_pd": 2 * self.substeps if self.meta_pd else 0,
                 "root_wrench": 6 if self.residual_force else 0}
        self.action_layout, start = {}, 0
        for name, size in sizes.items():
            if size:
                self.action_layout[name] = slice(start, start + size)
                start += size
        self.single_action_space = spaces.Box(-1.0, 1.0, (start,), np.float32)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self._ctrl_buf = b.zeros((self.num_envs, self.model.nu))
        if self.meta_pd:
            self.sim.pd_scales = b.zeros((self.num_envs, self.substeps, 2)) + 1.0
        if self.residual_force:
            self.sim.root_wrench = b.zeros((self.num_envs, 6))

    def _configure(self, spec: mujoco.MjSpec) -> None:
        if not self.meta_pd:
            return
        # Meta-PD's damping: per hinge a velocity-gain actuator, force = -kd qdot u (CPUSim sets u
        # per substep); not force-limited, so implicitfast integrates it as it does joint damping.
        for j, name in enumerate(HINGE_NAMES):
            act = spec.add_actuator(name=name + DAMPING_SUFFIX, target=name, trntype=mujoco.mjtTrn.mjTRN_JOINT)
            act.gaintype = mujoco.mjtGain.mjGAIN_AFFINE
            act.gainprm[:3] = [0.0, 0.0, -KD[j]]
            act.biastype = mujoco.mjtBias.mjBIAS_NONE
            act.ctrllimited = mujoco.mjtLimited.mjLIMITED_TRUE
            act.ctrlrange = [1.0 / self.meta_pd_range - 1.0, self.meta_pd_range - 1.0]

    # ------------------------------------------------------------------ task hooks
    motion_id = property(lambda self: self.ref.motion_id)
    frame = property(lambda self: self.ref.frame)

    def _reset_task(self, ids, options):
        qpos, qvel = super()._reset_task(ids, options)
        # Out of the floor where the estimate sinks into it: a start inside the ground explodes.
        qpos[:, self.humanoid.qpos.start + 2] += self._start_lift[self.start_frame[ids]]
        self.ref.begin(ids, self.start_motion[ids], self.start_frame[ids])
        return qpos, qvel

    def _ctrl(self, actions):
        lay = self.action_layout
        ctrl = self._ctrl_buf
        ctrl[:, self.humanoid.actuators] = self.ref.pd_targets(actions[:, lay["residual"]], self.action_scale,
                                                               "residual", self.residual_scale)
        if self.meta_pd:
            a = actions[:, lay["meta_pd"]].reshape(self.num_envs, self.substeps, 2)
            self.sim.pd_scales[:] = self.meta_pd_range ** a
        if self.residual_force:
            a = actions[:, lay["root_wrench"]]
            heading = heading_rotation(self.sim.bodies.rot[:, 0])
            local = self.backend.xp.concatenate([a[:, :3] * self.residual_force_scale,
                                                 a[:, 3:] * self.residual_torque_scale], -1)
            # Heading frame -> world: v_w = H v_h for the force and the torque.
            self.sim.root_wrench[:] = (local.reshape(-1, 2, 3) @ heading.swapaxes(-1, -2)).reshape(-1, 6)
        return ctrl

    def _advance(self, active):
        self.ref.advance(active)

    def _target(self) -> BodyState:
        """What the reward and termination measure against: the truth, else the estimate."""
        return self.ref.current() if self._truth is None else self._truth.body_state(self.ref.frame)

    def _keypoint_residual(self, body):
        """(N, 24, 2) reprojection residuals of the simulated bodies at the current frame."""
        f, m = self.ref.frame, self.ref.motion_id
        return reprojection_residual(body.pos, self._keypoints[f], self._cam_rotation[m], self._cam_position[m])

    def _evaluate(self, body, heading):
        target = self._target()
        r = self._keypoint_residual(body)
        reward, terms = videopose_reward(body, target, (r * r).sum(-1), self._confidence[self.ref.frame],
                                         self.reward_scales)
        terminated = fallen(body)
        if self.termination_distance is not None:
            # Against the input followed, not the truth: the truth's place in the world (depth
            # above all) is not observable, the input's is.
            terminated |= mean_body_distance(body, self.ref.current()) > self.termination_distance
        return reward, terms, terminated, self.ref.at_end()

    def _observe(self, body, heading):
        est = self.ref.next()
        nxt, m = self.ref.next_frame(), self.ref.motion_id
        cam_rot, cam_pos = camera_in_heading(self._cam_rotation[m], self._cam_position[m], body.pos[:, 0], heading)
        extra = video_obs(est.dof_pos, self._keypoints[nxt], self._confidence[nxt], cam_rot, cam_pos)
        return self.backend.xp.concatenate([tracking_obs(body, est, "rotation", heading), extra], -1)

    def _task_info(self, body):
        b, f, m = self.backend, self.ref.frame, self.ref.motion_id
        conf = b.asarray(self._confidence[f])
        r = self._keypoint_residual(body) * self._focal[m][:, None]
        px = xp(r).sqrt((r * r).sum(-1))
        info = {"motion_id": b.copy(self.ref.motion_id), "motion_time": self.ref.motion_time(),
                "est_body_pos": b.copy(self.ref.current().pos),
                "next_est_dof_pos": b.float32(self.ref.next_dof_pos()),
                "foot_points": b.float32(foot_points(body.pos, body.rot)),
                "reprojection_error": weighted_mean(px, conf), "keypoint_weight": conf.sum(-1),
                "fallen": fallen(body)}
        if self._truth is not None:
            nxt = self.ref.next_frame()
            info["truth_body_pos"] = self._truth.body_pos[f]
            info["next_truth_dof_pos"] = self._truth.dof_pos[nxt]
            # In the observation's frame of the estimate's root: a refinement of the root learns from it.
            info["next_truth_root_pos"] = b.float32(to_heading(self._truth.body_pos[nxt][:, 0] - body.pos[:, 0],
                                                               heading_rotation(body.rot[:, 0])))
        return info

    def _markers(self, world):
        frame = int(self.ref.frame[world])
        out = [(self.video.estimate.body_pos[frame] + self.ghost_offset, INPUT_RGBA, 0.03)]
        if self.truth is not None:
            out.append((self.truth.body_pos[frame] + self.ghost_offset, TRUTH_RGBA, 0.025))
        return out

    def reference_action(self) -> np.ndarray:
        """(N, action size) zeros: PD tracking of the estimate with the built gains and no force."""
        return self.backend.float32(self.backend.zeros((self.num_envs, self.single_action_space.shape[0])))
