"""The imitation tasks' optional action-rate penalty: -w mean_j (a_j - a_prev_j)^2, zero on an
episode's first step, absent from info when off."""

import gymnasium as gym
import numpy as np
import pytest

import smpl_envs  # noqa: F401


def _env(weight, env_id="SMPL/Imitation-v0"):
    env = gym.make_vec(env_id, num_envs=2, motions="walk", action_mode="residual", action_rate_weight=weight)
    env.reset(seed=0)
    return env


@pytest.mark.parametrize("env_id", ["SMPL/Imitation-v0", "SMPL/KeypointImitation-v0"])
def test_penalty_is_the_mean_squared_action_change(env_id):
    env = _env(0.5, env_id)
    a = np.zeros((2, 69), np.float32)
    *_, info = env.step(a)
    np.testing.assert_allclose(info["reward_action_rate"], 0.0)  # the first step has no predecessor
    b = a.copy()
    b[0, :23] = 0.6
    _, reward_b, *_, info = env.step(b)
    np.testing.assert_allclose(info["reward_action_rate"], [-0.5 * 23 * 0.36 / 69, 0.0], rtol=1e-6)
    *_, info = env.step(b)
    np.testing.assert_allclose(info["reward_action_rate"], 0.0)  # held actions cost nothing


def test_a_reset_forgets_the_previous_action():
    env = _env(1.0)
    env.step(np.full((2, 69), 0.8, np.float32))
    env.reset(seed=1)
    *_, info = env.step(np.zeros((2, 69), np.float32))
    np.testing.assert_allclose(info["reward_action_rate"], 0.0)


def test_off_by_default_and_validated():
    env = gym.make_vec("SMPL/Imitation-v0", num_envs=1, motions="walk")
    env.reset(seed=0)
    *_, info = env.step(np.zeros((1, 69), np.float32))
    assert "reward_action_rate" not in info
    for bad in (-1.0, float("nan")):
        with pytest.raises(ValueError, match="action_rate_weight"):
            gym.make_vec("SMPL/Imitation-v0", num_envs=1, motions="walk", action_rate_weight=bad)
