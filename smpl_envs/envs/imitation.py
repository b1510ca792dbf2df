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
The means run over the 24 bodies (and xyz); weights and scales are `gym.make` kwargs.

`info` also carries the metrics' raw inputs (`body_pos`, `ref_body_pos`), `motion_id`,
`motion_time`, `diverged`, and `amp_obs`, the AMP discriminator features of the step (232).
"""

from __future__ import annotations

import numpy as np

from ..features import (IMITATION_GOAL_LAYOUT, KEYPOINT_GOAL_LAYOUT, SELF_OBS_LAYOUT, BodyState,
                        layout_size, layout_slices, rotation_angle, tracking_obs, xp)
from ..humanoid.skeleton import BODY_NAMES
from .base import HumanoidVecEnv, SingleEnv

REWARD_WEIGHTS = {"pos": 0.5, "rot": 0.3, "lin_vel": 0.1, "ang_vel": 0.1}
REWARD_SCALES = {"pos": 100.0, "rot": 10.0, "lin_vel": 0.1, "ang_vel": 0.1}
TERMS = ("pos", "rot", "lin_vel", "ang_vel")
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
    termination_distance (m; None disables early termination), start ("random" or
    "beginning"), max_episode_steps, autoreset_mode, substeps, num_threads, render_mode,
    render_size, show_reference, render_world.
    """

    goal_layout = IMITATION_GOAL_LAYOUT
    obs_dim = layout_size(SELF_OBS_LAYOUT) + layout_size(IMITATION_GOAL_LAYOUT)
    goal = "rotation"

    def __init__(self, num_envs: int = 1, *, reward_weights: dict | None = None,
                 reward_scales: dict | None = None, energy_weight: float = ENERGY_WEIGHT,
                 termination_distance: float | None = TERMINATION_DISTANCE, **kwargs):
        self.reward_weights = _merge("reward_weights", REWARD_WEIGHTS, reward_weights)
        self.reward_scales = _merge("reward_scales", REWARD_SCALES, reward_scales)
        self.energy_weight = float(energy_weight)
        self.termination_distance = termination_distance
        super().__init__(num_envs, **kwargs)

    def _observe(self, sim, ref_next, heading):
        return tracking_obs(sim, ref_next, self.goal, heading)

    def _evaluate(self, sim, ref):
        reward, terms = imitation_reward(sim, ref, self.sim.actuator_force, self.reward_weights,
                                         self.reward_scales, self.energy_weight)
        if self.termination_distance is None:
            return reward, terms, np.zeros(self.num_envs, bool)
        return reward, terms, imitation_terminated(sim, ref, self.termination_distance)

    @property
    def observation_structure(self) -> dict[str, slice]:
        return layout_slices({"self": SELF_OBS_LAYOUT, "goal": self.goal_layout})


class KeypointImitationVecEnv(ImitationVecEnv):
    """`gym.make_vec("SMPL/KeypointImitation-v0", ...)`: as Imitation, with the keypoint goal
    (positions and velocities only); same kwargs."""

    goal_layout = KEYPOINT_GOAL_LAYOUT
    obs_dim = layout_size(SELF_OBS_LAYOUT) + layout_size(KEYPOINT_GOAL_LAYOUT)
    goal = "keypoint"


class ImitationEnv(SingleEnv):
    """`gym.make("SMPL/Imitation-v0", **kwargs)`: one world; kwargs as ImitationVecEnv."""

    vec_class = ImitationVecEnv


class KeypointImitationEnv(SingleEnv):
    """`gym.make("SMPL/KeypointImitation-v0", **kwargs)`: one world; kwargs as ImitationVecEnv."""

    vec_class = KeypointImitationVecEnv


def _merge(name: str, defaults: dict, given: dict | None) -> dict:
    given = dict(given or {})
    unknown = set(given) - set(defaults)
    if unknown:
        raise ValueError(f"{name}: unknown terms {sorted(unknown)}; known: {sorted(defaults)}")
    return {**defaults, **{k: float(v) for k, v in given.items()}}
