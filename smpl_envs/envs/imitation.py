"""Motion imitation: `SMPL/Imitation-v0` (rotation goal) and `SMPL/KeypointImitation-v0`.

The humanoid starts on a random frame of a clip drawn by the MotionLib's weights (reference state
initialisation), tracks the clip with PD targets, and its episode ends when its bodies drift on
average more than `termination_distance` from the reference (ankles and toes excluded; PHC's
relaxed early termination), when its simulation diverges, or at the clip's last frame
(truncation).

Observation (float32, everything in the simulated humanoid's heading frame; `t+1` is the next
reference frame, the one the action should reach):

| slice | size | Imitation-v0 | KeypointImitation-v0 |
|---|---|---|---|
| 0:1 | 1 | pelvis height | same |
| 1:70 | 69 | bodies 1-23 relative to the pelvis | same |
| 70:142 | 72 | 24 body linear velocities | same |
| 142:214 | 72 | 24 body angular velocities | same |
| 214:358 | 144 | 24 body rotations (6D) | same |
| 358:430 | 72 | ref - sim position, t+1 | same |
| 430:502 | 72 | ref - sim linear velocity, t+1 | same |
| 502:574 | 72 | ref - sim angular velocity, t+1 | ref position rel. sim pelvis, t+1 |
| 574:646 | 72 | ref position rel. sim pelvis, t+1 | - |
| 646:790 | 144 | ref rotation (-) sim rotation, t+1 (6D) | - |
| 790:934 | 144 | ref rotation, t+1 (6D) | - |

Totals: 934 (Imitation), 574 (KeypointImitation). Blocks over bodies follow BODY_NAMES; 6D is
the first two columns of the rotation matrix. `env.unwrapped.observation_structure` gives the
slices by name.

Reward (REFERENCE.md section 3, the anchors' code form, each term in `info["reward_<term>"]`):
    pos     0.5 exp(-100 mean ||p_ref - p||^2)
    rot     0.3 exp(-10 mean angle(q_ref, q)^2)
    lin_vel 0.1 exp(-0.1 mean ||v_ref - v||^2)
    ang_vel 0.1 exp(-0.1 mean ||w_ref - w||^2)
    energy  -0.00001 sum_j |tau_j qdot_j|   (torques of the last physics substep)
    action_rate  -action_rate_weight mean_j (a_j - a_prev_j)^2   (off by default; 0 on an
                 episode's first step)
The means run over the 24 bodies (and xyz); weights and scales are `gym.make` kwargs. The action
rate term, for smoother control (a policy's step-to-step action changes are what makes its
motion jerky), is named in `info` only when its weight is set.

Actions: `action_mode="absolute"` (PHC's, the default: PD target = pi x a per hinge, 5 x a for
knee flexion) or `"residual"` (PD target = next reference frame's joint angles + residual_scale
x that range x a; the zero action then tracks the reference with the PD controllers alone).
`env.unwrapped.reference_action()` is the action that does so in either mode.

`info` also carries the metrics' raw inputs (`body_pos`, `ref_body_pos`), `motion_id`,
`motion_time` (the reference frame being tracked), `diverged`, `amp_obs`, the AMP
discriminator features of the step (232), and `next_ref_dof_pos`, the joint angles (69) of the
reference frame the observation's goal shows: the base of residual actions, with which
`reference.residual_to_absolute` turns a residual action into the absolute one of the same PD
targets (a residual teacher's labels for an absolute student).

Evaluation (`smpl_envs.evaluate`, `smpl-envs eval`): PHC's protocol, every clip once from its
first frame; success, E_g-mpjpe, E_mpjpe, E_acc, E_vel (`smpl_envs.evaluation.ClipProtocol`).

Perpetual control: `recovery=True` (or a dict of Recovery-v0's recovery kwargs) switches on
fail-state recovery (`smpl_envs.envs.recovery`): a world whose pelvis is more than 0.5 m from the
reference's gets the recovery goal and reward instead of terminating, and the ordinary goal back
once within reach, in the same episode. `info` then adds `reward_point`, `recovering`,
`root_distance` and `start_kind`. Off (the default), nothing here changes.

Reset options: `motion_ids`, `start` (the core's), `start_frame` (a frame index within each
reset world's clip, with `motion_ids`: a world restarted where its reference is now), and with
recovery `recovery_start`.
"""

from __future__ import annotations

import numpy as np

from ..evaluation import ClipProtocol
from ..features import IMITATION_GOAL_LAYOUT, KEYPOINT_GOAL_LAYOUT, BodyState, rotation_angle, tracking_obs, xp
from ..humanoid.skeleton import BODY_NAMES
from .base import HumanoidVecEnv
from .recovery_rules import RecoveryController
from .reference import RESIDUAL_SCALE, ReferenceTracker, check_action_mode

REWARD_WEIGHTS = {"pos": 0.5, "rot": 0.3, "lin_vel": 0.1, "ang_vel": 0.1}
REWARD_SCALES = {"pos": 100.0, "rot": 10.0, "lin_vel": 0.1, "ang_vel": 0.1}
TERMS = ("pos", "rot", "lin_vel", "ang_vel")
MARKER_RGBA = (0.9, 0.1, 0.1, 0.8)  # reference bodies in renders
# The paper prints 5e-4, PHC's code uses 5e-5. Measured here on the walk clip with PHC's action
# noise (std 0.055), the energy term is about -6 a step at 5e-4 and -0.6 at 5e-5, against +0.2 to
# +0.3 of imitation reward for an untrained policy: the step reward is negative, so with early
# termination a policy earns most by falling sooner (PPO runs shortened their episodes). At 1e-5
# it is -0.11 and the step reward stays positive.
ENERGY_WEIGHT = 0.00001
TERMINATION_DISTANCE = 0.5
# Feet are left out of the termination test: their errors say little about a fall.
TERMINATION_BODIES = np.array([i for i, n in enumerate(BODY_NAMES) if not n.endswith(("Ankle", "Toe"))])


# ---------------------------------------------------------------------- pure task functions
def imitation_reward(sim: BodyState, ref: BodyState, actuator_force, weights=REWARD_WEIGHTS,
                     scales=REWARD_SCALES, energy_weight=ENERGY_WEIGHT):
    """(total (N,), {term: (N,)}) for the imitation reward defined in the module docstring."""
    m = xp(sim.pos)
    n, nb = sim.pos.shape[:2]
    # One reduction for the three vector errors: mean over bodies and xyz of squared differences.
    diff = m.concatenate([ref.pos - sim.pos, ref.lin_vel - sim.lin_vel, ref.ang_vel - sim.ang_vel], 1)
    sq = (diff * diff).reshape(n, 3, -1).sum(axis=-1) * (1.0 / (3 * nb))
    angle = rotation_angle(ref.rot, sim.rot)
    errors = m.concatenate([sq[:, :1], (angle * angle).sum(axis=-1)[:, None] * (1.0 / nb), sq[:, 1:]], -1)
    w = np.array([weights[k] for k in TERMS])
    k = np.array([-scales[k] for k in TERMS])
    if m is not np:
        w, k = (m.as_tensor(x, dtype=errors.dtype, device=errors.device) for x in (w, k))
    terms = m.exp(errors * k) * w
    energy = -energy_weight * m.abs(actuator_force * sim.dof_vel).sum(axis=-1)
    out = {name: terms[:, i] for i, name in enumerate(TERMS)}
    out["energy"] = energy
    return terms.sum(axis=-1) + energy, out


def mean_body_distance(sim: BodyState, ref: BodyState, bodies=None):
    """(N,) mean Euclidean distance (m) between simulated and reference bodies (all, or the
    index array `bodies`)."""
    m = xp(sim.pos)
    d = ref.pos - sim.pos
    dist = m.sqrt((d * d).sum(axis=-1))
    if bodies is None:
        return dist.sum(axis=-1) * (1.0 / dist.shape[-1])
    return dist[:, bodies].sum(axis=-1) * (1.0 / len(bodies))


def imitation_terminated(sim: BodyState, ref: BodyState, distance=TERMINATION_DISTANCE):
    """(N,) relaxed early termination: feet-excluded mean body distance above `distance`."""
    return mean_body_distance(sim, ref, TERMINATION_BODIES) > distance


# ---------------------------------------------------------------------- environments
class ImitationVecEnv(HumanoidVecEnv):
    """`gym.make_vec("SMPL/Imitation-v0", num_envs=N, **kwargs)`.

    kwargs: motions ("walk"; clip name, file, directory, saved library, list, or MotionLib),
    reward_weights / reward_scales (dicts over pos, rot, lin_vel, ang_vel), energy_weight,
    termination_distance (m; None disables early termination), action_mode ("absolute" or
    "residual"), residual_scale, recovery (False; True or a dict of recovery kwargs: see
    `smpl_envs.envs.recovery`), and the core's (start, cache, max_episode_steps,
    autoreset_mode, substeps, num_threads, render_mode, render_size, render_world,
    show_markers).
    """

    task_layout = {"goal": IMITATION_GOAL_LAYOUT}
    evaluation = ClipProtocol()
    policy_kwargs = (*HumanoidVecEnv.policy_kwargs, "action_mode", "residual_scale")  # what an action does
    reset_options = (*HumanoidVecEnv.reset_options, "start_frame")
    goal = "rotation"
    backends = ("cpu", "warp")

    def __init__(self, num_envs: int = 1, *, motions="walk", reward_weights: dict | None = None,
                 reward_scales: dict | None = None, energy_weight: float = ENERGY_WEIGHT,
                 termination_distance: float | None = TERMINATION_DISTANCE, action_mode: str = "absolute",
                 residual_scale: float = RESIDUAL_SCALE, recovery: bool | dict = False,
                 action_rate_weight: float = 0.0, **kwargs):
        if motions is None:
            raise ValueError("motions: imitation needs reference clips (a clip name, file, directory or list)")
        set_tracking_settings(self, reward_weights, reward_scales, energy_weight, termination_distance,
                              action_mode, residual_scale)
        self.action_rate_weight = float(action_rate_weight)
        if not (np.isfinite(self.action_rate_weight) and self.action_rate_weight >= 0):
            raise ValueError(f"action_rate_weight must be a non-negative number, got {action_rate_weight!r}")
        super().__init__(num_envs, motions=motions, **kwargs)
        self.ref = ReferenceTracker(self.motion_frames, self.num_envs, self.backend)
        self._prev_action = self.backend.zeros((self.num_envs, self.action_space.shape[-1]))
        self._first_step = self.backend.zeros(self.num_envs, "bool") | True
        self._action_rate = self.backend.zeros(self.num_envs)
        self.recovery = None
        if recovery is not False:
            if recovery is True:
                recovery = {}
            if not isinstance(recovery, dict):
                raise ValueError(f"recovery must be True, False or a dict of recovery kwargs, got {recovery!r}")
            self.recovery = RecoveryController(self, **recovery)
            self.reset_options = (*self.reset_options, "recovery_start")

    # The tracker's arrays, for callers that read where each world is in its clip.
    motion_id = property(lambda self: self.ref.motion_id)
    frame = property(lambda self: self.ref.frame)
    end_frame = property(lambda self: self.ref.end_frame)

    def _reset_task(self, ids, options):
        qpos, qvel = super()._reset_task(ids, options)
        self.ref.begin(ids, self.start_motion[ids], self.start_frame[ids])
        if self.action_rate_weight:
            self._first_step[ids] = True
        if self.recovery is not None:
            qpos, qvel = self.recovery.reset(ids, qpos, qvel, self.motion_frames.body_pos[self.ref.frame[ids], 0],
                                             options.get("recovery_start"), self.np_random)
        return qpos, qvel

    def _ctrl(self, actions):
        if self.action_rate_weight:
            # A world's first action has no predecessor; it is compared with itself (no penalty).
            m = xp(actions)
            prev = m.where(self._first_step[:, None], actions, self._prev_action)
            d = actions - prev
            self._action_rate = (d * d).sum(axis=-1) * (1.0 / d.shape[-1])
            self._prev_action[:] = actions
            self._first_step[:] = False
        targets = self.ref.pd_targets(actions, self.action_scale, self.action_mode, self.residual_scale)
        if self.recovery is not None:
            # While the goal shows its recovery form, a residual may be taken around another base
            # than the standing reference (`recovery_action_base`).
            targets = self.recovery.pd_targets(targets, actions, self.action_scale, self.action_mode,
                                               self.residual_scale, self.sim.qpos[:, self.humanoid.dof_qpos],
                                               self.ref.next_dof_pos())
        return targets

    def _advance(self, active):
        if self.recovery is None:
            self.ref.advance(active)
        else:
            self.ref.advance(self.recovery.reference_running(active))
            self.recovery.advance(active)

    def _evaluate(self, body, heading):
        ref = self.ref.current()
        reward, terms = imitation_reward(body, ref, self.sim.actuator_force, self.reward_weights,
                                         self.reward_scales, self.energy_weight)
        if self.action_rate_weight:
            terms["action_rate"] = -self.action_rate_weight * self._action_rate
            reward = reward + terms["action_rate"]
        terminated = (self.backend.zeros(self.num_envs, "bool") if self.termination_distance is None
                      else imitation_terminated(body, ref, self.termination_distance))
        if self.recovery is not None:
            guide = self.recovery.guide_reference()
            guide_terms = None if guide is None else imitation_reward(
                body, guide, self.sim.actuator_force, self.reward_weights, self.reward_scales, self.energy_weight)[1]
            return self.recovery.evaluate(body, ref, reward, terms, terminated, self.ref.at_end(), self.np_random,
                                          guide_terms)
        return reward, terms, terminated, self.ref.at_end()

    def _observe(self, body, heading):
        ref = self.ref.next()
        if self.recovery is not None:
            ref = self.recovery.goal_reference(body, ref, self.np_random)
        return tracking_obs(body, ref, self.goal, heading)

    def _task_info(self, body):
        copy = self.backend.copy
        info = {"motion_id": copy(self.ref.motion_id), "motion_time": self.ref.motion_time(),
                "ref_body_pos": copy(self.ref.current().pos),  # a copy: the array is cached
                "next_ref_dof_pos": self.backend.float32(self.ref.next_dof_pos())}
        if self.recovery is not None:
            info.update(self.recovery.info())
        return info

    def _markers(self, world):
        if self.recovery is not None and bool(self.recovery.guided[world]):  # the get-up it follows
            return [(self.backend.to_numpy(self.recovery.guide_reference().pos[world]), MARKER_RGBA, 0.03)]
        return [(self.motion_lib.body_pos[int(self.ref.frame[world])], MARKER_RGBA, 0.03)]

    def set_recovery_starts(self, starts: dict) -> None:
        """Draw the start kinds of the resets from now on from `starts` ({kind: probability} over
        reference, fallen, far, fallen+far): the hook of a get-up curriculum, which changes the
        mix over training (`agents.curriculum`). Needs recovery on."""
        if self.recovery is None:
            raise ValueError("set_recovery_starts needs recovery on (SMPL/Recovery-v0, or Imitation-v0 with "
                             "recovery=True)")
        self.recovery.set_starts(starts)

    def reference_action(self) -> np.ndarray:
        """(N, 69) actions whose PD targets are the next reference frame's joint angles (in either
        action mode): the policy-free baseline of "track the reference with PD alone"."""
        return self.ref.reference_action(self.action_scale, self.action_mode)


class KeypointImitationVecEnv(ImitationVecEnv):
    """`gym.make_vec("SMPL/KeypointImitation-v0", ...)`: as Imitation, with the keypoint goal
    (positions and velocities only); same kwargs."""

    task_layout = {"goal": KEYPOINT_GOAL_LAYOUT}
    goal = "keypoint"


def set_tracking_settings(env, reward_weights, reward_scales, energy_weight, termination_distance,
                          action_mode, residual_scale) -> None:
    """Check the kwargs every reference-tracking task shares and set them on `env` (reward
    weights and scales merged over the defaults, energy weight, termination distance, action mode
    and residual scale); a ValueError names a bad one."""
    env.reward_weights = _merge("reward_weights", REWARD_WEIGHTS, reward_weights)
    env.reward_scales = _merge("reward_scales", REWARD_SCALES, reward_scales)
    env.energy_weight = float(energy_weight)
    if termination_distance is not None and not float(termination_distance) > 0:
        raise ValueError(f"termination_distance must be a positive distance in metres or None, "
                         f"got {termination_distance!r}")
    env.termination_distance = termination_distance
    env.residual_scale = check_action_mode(action_mode, residual_scale)
    env.action_mode = action_mode


def _merge(name: str, defaults: dict, given: dict | None) -> dict:
    given = dict(given or {})
    unknown = set(given) - set(defaults)
    if unknown:
        raise ValueError(f"{name}: unknown terms {sorted(unknown)}; known: {sorted(defaults)}")
    return {**defaults, **{k: float(v) for k, v in given.items()}}
