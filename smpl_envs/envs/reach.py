"""`SMPL/Reach-v0`: bring the right hand to a target point (REFERENCE.md section 5).

Each world has a target within reach of the humanoid: x, y U[-1, 1] m around the pelvis in its
heading frame at the time it is drawn, height z U[0.2, 2.0] m above the floor (`target_range_xy`,
`target_range_z`), redrawn every U[resample_interval] (50-99) steps. A marker shows the target in
renders.

Observation (float32, heading frame):

| slice | size | content |
|---|---|---|
| 0:358 | 358 | self observation (`smpl_envs.features.SELF_OBS_LAYOUT`) |
| 358:361 | 3 | target position relative to the pelvis (m) |

Reward (one term, `info["reward_reach"]`): exp(-k ||p_hand - p_target||^2), right hand, with
k = `reward_sharpness` (4, the paper's). A smaller k keeps a gradient toward targets the hand is
far from (at 1.2 m, exp(-4 d^2) is 0.003); the evaluation's metrics do not depend on it.

Episode: 300 steps (10 s); a fall ends it. Starts: the rest pose, or random frames of `motions=`.

`info`: `hand_distance` (m), `target_pos` (world, (N, 3)), `target_index` (targets drawn so far
in the episode, from 0), plus the core's entries.

Evaluation: 32 seeded episodes; mean hand distance over the steps tracked, the fraction of
targets reached (the hand within 0.1 m at some step while the target stood; a target the time
limit cut short counts only if reached), the fraction of episodes without a fall, and the score
(mean reward per step over 10 s).
"""

from __future__ import annotations

import numpy as np

from ..evaluation import EpisodeProtocol
from ..features import self_obs, to_heading, xp
from ..humanoid.skeleton import BODY_NAMES
from .base import check_number, check_range
from .goal import GoalVecEnv, Schedule, check_interval

HAND = BODY_NAMES.index("R_Hand")
REACHED = 0.1  # m: a target counts as reached when the hand comes this close (evaluation)
REWARD_SHARPNESS = 4.0  # k of exp(-k d^2) (REFERENCE section 5)
REACH_LAYOUT = (("target_pos", 3, "target position relative to the pelvis (m)"),)


def reach_reward(hand_pos, target, sharpness: float = REWARD_SHARPNESS):
    """(reward (N,), hand distance (N,)) for hand and target positions (N, 3)."""
    d = hand_pos - target
    sq = (d * d).sum(-1)
    m = xp(sq)
    return m.exp(-sharpness * sq), m.sqrt(sq)


def reach_episode_metrics(log: dict) -> dict:
    index, dist = log["target_index"], log["hand_distance"]
    reached = [dist[index == k].min() < REACHED for k in np.unique(index)]
    if log["truncated"] and not reached[-1]:
        reached.pop()  # the time limit cut the last target short: it says nothing either way
    return {"hand_distance": float(dist.mean()), "targets_reached": float(np.mean(reached)) if reached else np.nan,
            "targets": len(reached)}


class ReachVecEnv(GoalVecEnv):
    """`gym.make_vec("SMPL/Reach-v0", num_envs=N, **kwargs)`.

    kwargs: target_range_xy ((-1, 1) m), target_range_z ((0.2, 2.0) m), resample_interval
    ((50, 99) steps), reward_sharpness (k of exp(-k d^2), REWARD_SHARPNESS), and GoalVecEnv's
    (fall_height, head_height, motions, start, ...).
    """

    task_layout = {"task": REACH_LAYOUT}
    evaluation = EpisodeProtocol(("hand_distance", "target_index"), reach_episode_metrics)
    backends = ("cpu", "warp")

    def __init__(self, num_envs: int = 1, *, target_range_xy=(-1.0, 1.0), target_range_z=(0.2, 2.0),
                 resample_interval=(50, 99), reward_sharpness: float = REWARD_SHARPNESS, **kwargs):
        self.reward_sharpness = check_number("reward_sharpness", reward_sharpness, positive=True)
        self.target_range_xy = check_range("target_range_xy", target_range_xy, -10.0, 10.0)
        self.target_range_z = check_range("target_range_z", target_range_z, 0.0, 3.0)
        interval = check_interval("resample_interval", resample_interval)
        super().__init__(num_envs, **kwargs)
        n, b = self.num_envs, self.backend
        self.target = b.zeros((n, 3))          # world frame
        self.target_index = b.zeros(n, "int")
        self.schedule = Schedule(n, interval, b)

    def _resample(self, ids: np.ndarray, qpos: np.ndarray) -> None:
        """New targets for worlds `ids` around the pose in their rows of full-model `qpos`."""
        rng, b = self.np_random, self.backend
        root, heading = self.root_pose(qpos)
        n = len(ids)
        local = b.xp.stack([b.uniform(rng, n, *self.target_range_xy), b.uniform(rng, n, *self.target_range_xy),
                            b.zeros(n)], -1)
        self.target[ids] = root + (heading @ b.asarray(local)[..., None])[..., 0]
        self.target[ids, 2] = b.asarray(b.uniform(rng, n, *self.target_range_z))
        self.schedule.reset(ids, self.elapsed, rng)

    def _reset_task(self, ids, options):
        qpos, qvel = super()._reset_task(ids, options)
        self.target_index[ids] = 0
        self._resample(ids, qpos)
        return qpos, qvel

    def _schedule(self, active):
        due = self.schedule.due(self.elapsed, active)
        if len(due):
            self.target_index[due] += 1
            self._resample(due, self.sim.qpos[due])

    def _evaluate(self, body, heading):
        reward, _ = reach_reward(body.pos[:, HAND], self.target, self.reward_sharpness)
        return reward, {"reach": reward}, self._fallen(body), self.backend.zeros(self.num_envs, "bool")

    def _observe(self, body, heading):
        rel = to_heading((self.target - body.pos[:, 0])[:, None], heading)[:, 0]
        return self.backend.xp.concatenate([self_obs(body, heading), rel], -1)

    def _task_info(self, body):
        copy = self.backend.copy
        return {"hand_distance": reach_reward(body.pos[:, HAND], self.target)[1], "target_pos": copy(self.target),
                "target_index": copy(self.target_index)}

    def _markers(self, world):
        return [(self.backend.to_numpy(self.target[world]), (0.95, 0.75, 0.1, 0.9), 0.05)]
