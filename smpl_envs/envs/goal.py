"""What the goal-directed tasks (Speed, Reach, Strike; Terrain next) share: start poses at the
origin, fall termination, a per-world resampling schedule, and the style clips.

`motions=` is optional for them: without clips every episode starts from the rest pose; with clips
(e.g. `motions=["walk", "run"]`) episodes start from random frames of those clips, moved to the
origin, and the clips are the style an AMP agent learns from (`info["amp_obs"]`, `motion_lib`).
Episodes last 300 steps (10 s, the registered time limit) and end early on a fall
(`smpl_envs.envs.base.fallen`).
"""

from __future__ import annotations

import numpy as np

from ..backend import NumpyBackend
from ..features import heading_rotation, rotmat_from_quat
from .base import HumanoidVecEnv, check_number, fallen


def check_interval(name: str, value) -> tuple[int, int]:
    """A (min, max) number of steps, both >= 1, min <= max; else a ValueError naming the kwarg."""
    try:
        lo, hi = (int(v) for v in value)
        exact = all(float(v) == int(v) for v in value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a (min, max) pair of step counts, got {value!r}") from None
    if not exact or lo < 1 or hi < lo:
        raise ValueError(f"{name} must be a (min, max) pair of whole step counts with 1 <= min <= max, got {value!r}")
    return lo, hi


class Schedule:
    """Per-world step at which the task next resamples its target, U[low, high] steps apart."""

    def __init__(self, num_worlds: int, interval: tuple[int, int], backend=None):
        self.low, self.high = interval
        self.backend = backend or NumpyBackend()
        self.next = self.backend.zeros(num_worlds, "int")

    def reset(self, ids: np.ndarray, elapsed: np.ndarray, rng: np.random.Generator) -> None:
        self.next[ids] = elapsed[ids] + self.backend.integers(rng, self.low, self.high + 1, len(ids))

    def due(self, elapsed: np.ndarray, active: np.ndarray | None) -> np.ndarray:
        """World ids whose resample is due now (among `active` ones)."""
        due = elapsed >= self.next
        if active is not None:
            due &= active
        return self.backend.nonzero(due)


class GoalVecEnv(HumanoidVecEnv):
    """Base of the goal-directed tasks: starts at the origin, a fall ends the episode.

    kwargs: fall_height (0.15 m: a body other than the feet below it is a fall), head_height
    (0.3 m), and the core's (motions, start, cache, max_episode_steps, ...).
    """

    def __init__(self, num_envs: int = 1, *, fall_height: float = 0.15, head_height: float = 0.3, **kwargs):
        self.fall_height = check_number("fall_height", fall_height)
        self.head_height = check_number("head_height", head_height)
        super().__init__(num_envs, **kwargs)

    def _reset_task(self, ids, options):
        qpos, qvel = super()._reset_task(ids, options)
        # Every world starts over the origin: targets and objects are placed around it.
        qpos[:, self.humanoid.qpos.start:self.humanoid.qpos.start + 2] = 0.0
        return qpos, qvel

    def _fallen(self, body) -> np.ndarray:
        return fallen(body, self.fall_height, self.head_height)

    def root_pose(self, qpos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(root position (N, 3), heading rotation (N, 3, 3)) from full-model qpos rows."""
        q = qpos[:, self.humanoid.qpos]
        return q[:, :3], heading_rotation(rotmat_from_quat(q[:, 3:7]))
