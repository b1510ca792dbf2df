"""`SMPL/Speed-v0`: move in a target direction at a target speed (REFERENCE.md section 5).

Each world has a target heading, uniform over the circle, and a target speed U[speed_range]
(0-5 m/s), both redrawn every U[resample_interval] (100-199) steps. The humanoid's pelvis velocity
is measured in the target's frame: v_x along the target direction, v_y across it.

Observation (float32, heading frame):

| slice | size | content |
|---|---|---|
| 0:358 | 358 | self observation (`smpl_envs.features.SELF_OBS_LAYOUT`) |
| 358:360 | 2 | target direction in the heading frame (cos, sin) |
| 360:361 | 1 | target speed (m/s) |

Reward (one term, `info["reward_speed"]`): exp(-0.25 ((v* - v_x)^2 + 0.1 v_y^2)).

Episode: 300 steps (10 s); a fall ends it (a body other than the feet below 0.15 m, the head
below 0.3 m). Starts: the rest pose, or random frames of `motions=` (also AMP's style clips).

`info`: `speed_error` |v* - v_x|, `target_speed`, `target_dir` (world, (N, 2)), plus the core's
(`amp_obs`, `body_pos`, `diverged`, and `motion_id` / `motion_time` of the start frame).

Evaluation (`smpl_envs.evaluate`, `smpl-envs eval`): 32 seeded episodes; mean absolute speed
error over the steps tracked, the fraction of episodes without a fall, and the score (mean reward
per step over 10 s).
"""

from __future__ import annotations

import numpy as np

from ..evaluation import EpisodeProtocol
from ..features import self_obs, xp
from .base import check_range
from .goal import GoalVecEnv, Schedule, check_interval

SPEED_LAYOUT = (
    ("target_dir", 2, "target direction in the heading frame (cos, sin)"),
    ("target_speed", 1, "target speed (m/s)"),
)


def speed_reward(root_vel, target_dir, target_speed):
    """(reward (N,), speed error |v* - v_x| (N,)) for world-frame pelvis velocities (N, 3),
    unit target directions (N, 2) and target speeds (N,)."""
    vx = root_vel[:, 0] * target_dir[:, 0] + root_vel[:, 1] * target_dir[:, 1]
    vy = root_vel[:, 1] * target_dir[:, 0] - root_vel[:, 0] * target_dir[:, 1]
    err = target_speed - vx
    m = xp(root_vel)
    return m.exp(-0.25 * (err * err + 0.1 * vy * vy)), m.abs(err)


def speed_episode_metrics(log: dict) -> dict:
    return {"speed_error": float(log["speed_error"].mean())}


class SpeedVecEnv(GoalVecEnv):
    """`gym.make_vec("SMPL/Speed-v0", num_envs=N, **kwargs)`.

    kwargs: speed_range ((0, 5) m/s), resample_interval ((100, 199) steps), and GoalVecEnv's
    (fall_height, head_height, motions, start, ...).
    """

    task_layout = {"task": SPEED_LAYOUT}
    evaluation = EpisodeProtocol(("speed_error",), speed_episode_metrics)
    backends = ("cpu", "warp")

    def __init__(self, num_envs: int = 1, *, speed_range=(0.0, 5.0), resample_interval=(100, 199), **kwargs):
        self.speed_range = check_range("speed_range", speed_range, low=0.0)
        interval = check_interval("resample_interval", resample_interval)
        super().__init__(num_envs, **kwargs)
        n, b = self.num_envs, self.backend
        self.target_dir = b.rows(b.asarray([1.0, 0.0]), n)  # world frame, unit
        self.target_speed = b.zeros(n)
        self.schedule = Schedule(n, interval, b)

    def _resample(self, ids: np.ndarray) -> None:
        rng, b = self.np_random, self.backend
        yaw = b.uniform(rng, len(ids), 0.0, 2.0 * np.pi)
        self.target_dir[ids] = b.xp.stack([b.xp.cos(yaw), b.xp.sin(yaw)], -1)
        self.target_speed[ids] = b.uniform(rng, len(ids), *self.speed_range)
        self.schedule.reset(ids, self.elapsed, rng)

    def _reset_task(self, ids, options):
        qpos, qvel = super()._reset_task(ids, options)
        self._resample(ids)
        return qpos, qvel

    def _schedule(self, active):
        due = self.schedule.due(self.elapsed, active)
        if len(due):
            self._resample(due)

    def _evaluate(self, body, heading):
        reward, _ = speed_reward(body.lin_vel[:, 0], self.target_dir, self.target_speed)
        return reward, {"speed": reward}, self._fallen(body), self.backend.zeros(self.num_envs, "bool")

    def _observe(self, body, heading):
        # The target direction in the heading frame: rotate by minus the heading's yaw.
        c, s = heading[:, 0, 0], heading[:, 1, 0]
        d = self.target_dir
        m = self.backend.xp
        local = m.stack([c * d[:, 0] + s * d[:, 1], c * d[:, 1] - s * d[:, 0]], -1)
        return m.concatenate([self_obs(body, heading), local, self.target_speed[:, None]], -1)

    def _task_info(self, body):
        error = speed_reward(body.lin_vel[:, 0], self.target_dir, self.target_speed)[1]
        copy = self.backend.copy
        return {"speed_error": error, "target_speed": copy(self.target_speed), "target_dir": copy(self.target_dir)}

    def _markers(self, world):
        # A dotted arrow from the pelvis along the target direction, one dot per 0.25 m/s.
        to_numpy = self.backend.to_numpy
        root = to_numpy(self.sim.bodies.pos[world, 0])
        k = max(1, int(round(float(self.target_speed[world]) / 0.25)))
        steps = 0.15 * np.arange(1, k + 1)[:, None]
        dots = root + np.concatenate([steps * to_numpy(self.target_dir[world]), np.zeros((k, 1))], -1)
        return [(dots, (0.1, 0.6, 0.9, 0.9), 0.025)]
