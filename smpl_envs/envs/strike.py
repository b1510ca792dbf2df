"""`SMPL/Strike-v0`: walk to a tall box and knock it over with the right hand (REFERENCE.md
section 5).

A 0.4 x 0.4 x 1.8 m box of density 30 (8.6 kg, `box_size`, `box_density`) stands upright at
U[box_distance] (1.5-5 m) from the humanoid at a random bearing; a box_distance that could start
the box inside or touching the body (under `HUMANOID_REACH` plus the box's half-diagonal from the
pelvis) is refused. The box is a free body of the model (added to the `MjSpec` before compiling)
and collides with the humanoid; one MuJoCo contact sensor per humanoid body reports whether that
body touches the box.

Observation (float32, heading frame):

| slice | size | content |
|---|---|---|
| 0:358 | 358 | self observation (`smpl_envs.features.SELF_OBS_LAYOUT`) |
| 358:361 | 3 | box position relative to the pelvis (m) |
| 361:367 | 6 | box rotation, 6D |
| 367:370 | 3 | box linear velocity (m/s) |
| 370:373 | 3 | box angular velocity (rad/s) |

Reward (`info["reward_topple"]`, `info["reward_approach"]`; their sum):
    topple    0.6 max(0, 1 - up . up_target)  (the box's z axis against the world's)
    approach  0.4 exp(-4 max(0, 1 - v_toward)^2), 0 when the pelvis moves away from the box
and once the box is toppled (up . up_target < 0.2) the reward is 1 (all of it in `topple`).
`approach_radius` (None, the paper's) pays the approach term in full while the pelvis is within
that horizontal distance of the box's axis: PULSE's and ASE's term pays for walking on at 1 m/s
until a body touches the box, which ends the episode (ASE's location task has such a radius).

Episode: 300 steps (10 s); ends on a fall, or when a body other than the right hand, wrist or
elbow touches the box. Starts: the rest pose, or random frames of `motions=`.

`info`: `toppled`, `box_pos` (world), `box_up` (up . up_target), `touching` ((N, 24) bodies in
contact with the box), plus the core's entries.

Evaluation: 32 seeded episodes; the fraction that topple the box, the fraction without a fall
or a foul, and the score (mean reward per step over 10 s).
"""

from __future__ import annotations

import mujoco
import numpy as np

from ..evaluation import EpisodeProtocol
from ..features import rot6d, rot_to_heading, rotmat_from_quat, self_obs, to_heading, xp
from ..humanoid.skeleton import BODY_NAMES
from .base import check_number, check_range
from .goal import GoalVecEnv

STRIKERS = [BODY_NAMES.index(n) for n in ("R_Elbow", "R_Wrist", "R_Hand")]  # may touch the box
TOPPLED = 0.2  # up . up_target below this: the box is down
FLOOR_REACH = 90.0  # m: boxes stay well inside the 100 m floor
# m: the farthest the humanoid's geometry reaches horizontally from its pelvis (bounding spheres
# of its geoms): 0.81 in the rest pose (arms out), 0.87 at most over the shipped clips (kick).
# A box nearer than this plus its own half-diagonal could start inside or touching the body.
HUMANOID_REACH = 0.9
STRIKE_LAYOUT = (
    ("box_pos", 3, "box position relative to the pelvis (m)"),
    ("box_rot", 6, "box rotation, 6D"),
    ("box_lin_vel", 3, "box linear velocity (m/s)"),
    ("box_ang_vel", 3, "box angular velocity (rad/s)"),
)


def strike_reward(box_up, root_pos, root_vel, box_pos, approach_radius: float | None = None):
    """(reward (N,), {"topple", "approach"}) from the box's up . up_target (N,), pelvis position
    and velocity (N, 3) and box position (N, 3), world frame; within `approach_radius` (m) of the
    box the approach term is paid in full."""
    m = xp(box_pos)
    toppled = box_up < TOPPLED
    to_box = box_pos[:, :2] - root_pos[:, :2]
    distance = m.sqrt((to_box * to_box).sum(-1))
    to_box = to_box / (distance[:, None] + 1e-9)
    v = (root_vel[:, :2] * to_box).sum(-1)
    approach = m.where(v > 0.0, m.exp(-4.0 * (1.0 - v).clip(min=0.0) ** 2), 0.0)
    if approach_radius is not None:
        approach = m.where(distance < approach_radius, 1.0, approach)
    approach = 0.4 * approach
    topple = 0.6 * (1.0 - box_up).clip(min=0.0)
    terms = {"topple": m.where(toppled, 1.0, topple), "approach": m.where(toppled, 0.0, approach)}
    return terms["topple"] + terms["approach"], terms


def strike_episode_metrics(log: dict) -> dict:
    return {"toppled": bool(log["toppled"].any())}


class StrikeVecEnv(GoalVecEnv):
    """`gym.make_vec("SMPL/Strike-v0", num_envs=N, **kwargs)`.

    kwargs: box_distance ((1.5, 5.0) m from the pelvis; at least HUMANOID_REACH + the box's
    half-diagonal, 1.18 m for the default box), box_size ((0.4, 0.4, 1.8) m), box_density (30 kg/m^3),
    approach_radius (None: the paper's reward; m, see the module docstring), and GoalVecEnv's
    (fall_height, head_height, motions, start, ...).
    """

    task_layout = {"task": STRIKE_LAYOUT}
    evaluation = EpisodeProtocol(("toppled",), strike_episode_metrics)
    backends = ("cpu", "warp")

    def __init__(self, num_envs: int = 1, *, box_distance=(1.5, 5.0), box_size=(0.4, 0.4, 1.8),
                 box_density: float = 30.0, approach_radius: float | None = None, **kwargs):
        try:
            size = np.asarray(box_size, float)
        except (TypeError, ValueError):
            size = np.full(0, np.nan)
        if size.shape != (3,) or not (np.isfinite(size).all() and (size > 0).all()):
            raise ValueError(f"box_size must be three positive lengths (m), got {box_size!r}")
        self.box_distance = check_range("box_distance", box_distance, 0.0, FLOOR_REACH)
        clear = HUMANOID_REACH + float(np.hypot(*size[:2])) / 2
        if self.box_distance[0] < clear:
            raise ValueError(f"box_distance must keep the box clear of the humanoid: at least {clear:.2f} m "
                             f"(its reach {HUMANOID_REACH} m from the pelvis + the box's half-diagonal), "
                             f"got {box_distance!r}")
        self.box_size, self.box_density = size, check_number("box_density", box_density, positive=True)
        self.approach_radius = (None if approach_radius is None
                                else check_number("approach_radius", approach_radius, positive=True))
        super().__init__(num_envs, **kwargs)
        joint = self.model.body_jntadr[mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_BODY, "box")]
        q, v = self.model.jnt_qposadr[joint], self.model.jnt_dofadr[joint]
        self.box_qpos, self.box_qvel = slice(q, q + 7), slice(v, v + 6)

    def _configure(self, spec):
        # Parked far away; every reset places it.
        box = spec.worldbody.add_body(name="box", pos=[FLOOR_REACH, 0.0, self.box_size[2] / 2])
        box.add_freejoint(name="box_root")
        box.add_geom(name="box_geom", type=mujoco.mjtGeom.mjGEOM_BOX, size=self.box_size / 2,
                     density=self.box_density, rgba=[0.35, 0.55, 0.85, 1.0], friction=[1.0, 0.005, 0.0001])
        for name in BODY_NAMES:
            sensor = spec.add_sensor(name=f"touch_{name}", type=mujoco.mjtSensor.mjSENS_CONTACT,
                                     objtype=mujoco.mjtObj.mjOBJ_BODY, objname=name,
                                     reftype=mujoco.mjtObj.mjOBJ_GEOM, refname="box_geom")
            sensor.intprm[0], sensor.intprm[2] = 1, 1  # data "found" (a 0/1 count), one match

    def _reset_task(self, ids, options):
        qpos, qvel = super()._reset_task(ids, options)
        rng, b = self.np_random, self.backend
        root, _ = self.root_pose(qpos)
        distance = b.uniform(rng, len(ids), *self.box_distance)
        bearing = b.uniform(rng, len(ids), 0.0, 2.0 * np.pi)
        box = qpos[:, self.box_qpos]
        box[:, 0] = root[:, 0] + distance * b.xp.cos(bearing)
        box[:, 1] = root[:, 1] + distance * b.xp.sin(bearing)
        box[:, 2] = self.box_size[2] / 2
        box[:, 3:] = b.asarray([1.0, 0.0, 0.0, 0.0])
        qpos[:, self.box_qpos] = box
        qvel[:, self.box_qvel] = 0.0
        return qpos, qvel

    def box_state(self):
        """World-frame box (position (N, 3), rotation (N, 3, 3), linear and angular velocity)."""
        q, v = self.sim.qpos[:, self.box_qpos], self.sim.qvel[:, self.box_qvel]
        rot = rotmat_from_quat(q[:, 3:7])
        # A free joint's angular velocity is in the body's own frame.
        return q[:, :3], rot, v[:, :3], (rot @ v[:, 3:, None])[..., 0]

    def _evaluate(self, body, heading):
        pos, rot, _, _ = self.box_state()
        up = rot[:, 2, 2]
        reward, terms = strike_reward(up, body.pos[:, 0], body.lin_vel[:, 0], pos, self.approach_radius)
        touching = self.sim.sensordata > 0
        touching[:, STRIKERS] = False
        return reward, terms, self._fallen(body) | touching.any(-1), self.backend.zeros(self.num_envs, "bool")

    def _observe(self, body, heading):
        pos, rot, lin, ang = self.box_state()
        m = self.backend.xp
        vectors = to_heading(m.stack([pos - body.pos[:, 0], lin, ang], 1), heading)
        box_rot = rot6d(rot_to_heading(rot[:, None], heading))[:, 0]
        return m.concatenate([self_obs(body, heading), vectors[:, 0], box_rot, vectors[:, 1], vectors[:, 2]], -1)

    def _task_info(self, body):
        pos, rot, _, _ = self.box_state()
        up = rot[:, 2, 2]
        return {"toppled": up < TOPPLED, "box_pos": self.backend.copy(pos), "box_up": up,
                "touching": self.sim.sensordata > 0}
