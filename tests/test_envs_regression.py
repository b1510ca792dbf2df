"""The imitation envs behave as they did before the environment core was redesigned.

`tests/data/imitation_regression.npz` holds short trajectories (3 worlds, 16 steps, seeded
resets, fixed noisy actions, a tight termination distance so worlds terminate and autoreset
inside the horizon) written by `tests/make_regression_data.py` with the old core. Replaying them
must give the same observations, rewards, terminations and clips. The horizon is short so that
rounding differences between CPUs (other SIMD paths in MuJoCo) stay far below the tolerance.
"""
from pathlib import Path

import numpy as np
import pytest

from make_regression_data import IDS, rollout

DATA = np.load(Path(__file__).parent / "data" / "imitation_regression.npz")


@pytest.mark.parametrize("name", sorted(IDS))
def test_trajectory_matches_the_stored_one(name):
    got = rollout(IDS[name])
    for key in ("terminated", "truncated", "motion_id"):
        np.testing.assert_array_equal(got[key], DATA[f"{name}/{key}"], err_msg=key)
    np.testing.assert_allclose(got["reward"], DATA[f"{name}/reward"], rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(got["obs"], DATA[f"{name}/obs"], rtol=1e-4, atol=1e-4)
