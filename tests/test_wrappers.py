"""smpl_envs.wrappers.SB3VecEnv: the native batched env under Stable-Baselines3's VecEnv contract."""
from __future__ import annotations

import subprocess
import sys
import textwrap

import gymnasium as gym
import numpy as np
import pytest

import smpl_envs  # noqa: F401  (registers the ids)

pytest.importorskip("stable_baselines3")
from stable_baselines3.common.monitor import Monitor  # noqa: E402
from stable_baselines3.common.vec_env import VecEnv, VecMonitor, VecNormalize  # noqa: E402

from smpl_envs.wrappers import SB3VecEnv  # noqa: E402

ENV_ID = "SMPL/Imitation-v0"
OBS_DIM = 934


@pytest.fixture
def make():
    made = []

    def _make(env_or_id=ENV_ID, num_envs=3, **kwargs):
        venv = SB3VecEnv(env_or_id, num_envs=num_envs, **kwargs)
        made.append(venv)
        return venv

    yield _make
    for venv in made:
        venv.close()


def random_actions(venv, rng):
    low, high = venv.action_space.low, venv.action_space.high
    return rng.uniform(low, high, (venv.num_envs, *venv.action_space.shape)).astype(np.float32)


def assert_world_info(info: dict):
    assert not any(k.startswith("_") or k.startswith("final_") for k in info), sorted(info)
    assert np.ndim(info["motion_id"]) == 0 and np.ndim(info["motion_time"]) == 0
    assert np.shape(info["body_pos"]) == (24, 3)


def test_importing_the_module_needs_no_sb3():
    code = textwrap.dedent("""
        import sys
        import smpl_envs.wrappers as w
        assert "stable_baselines3" not in sys.modules and "torch" not in sys.modules
        sys.modules["stable_baselines3"] = None  # as if it were not installed
        try:
            w.SB3VecEnv
        except ImportError as e:
            print(e)
        else:
            raise SystemExit("no ImportError")
    """)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert "pip install stable-baselines3" in out.stdout


def test_spaces_dtypes_and_reset(make):
    venv = make(num_envs=3)
    assert isinstance(venv, VecEnv) and venv.num_envs == 3
    assert venv.observation_space == gym.spaces.Box(-np.inf, np.inf, (OBS_DIM,), np.float32)
    assert venv.action_space.shape == (69,) and venv.action_space.dtype == np.float32
    obs = venv.reset()
    assert obs.shape == (3, OBS_DIM) and obs.dtype == np.float32 and np.isfinite(obs).all()
    assert len(venv.reset_infos) == 3
    for info in venv.reset_infos:
        assert_world_info(info)

    # One seed for the batch, used by the next reset only.
    assert venv.seed(7) == [7, 7, 7]
    first = venv.reset()
    venv.step(random_actions(venv, np.random.default_rng(0)))
    venv.seed(7)
    np.testing.assert_allclose(venv.reset(), first, rtol=0, atol=1e-6)


def test_step_contract_with_early_termination(make):
    venv = make(num_envs=4, max_episode_steps=6)
    venv.seed(0)
    venv.reset()
    rng = np.random.default_rng(0)
    ends = 0
    for _ in range(20):
        obs, rewards, dones, infos = venv.step(random_actions(venv, rng))
        assert obs.shape == (4, OBS_DIM) and obs.dtype == np.float32 and np.isfinite(obs).all()
        assert rewards.shape == (4,) and rewards.dtype == np.float32 and np.isfinite(rewards).all()
        assert dones.shape == (4,) and dones.dtype == bool
        assert isinstance(infos, list) and len(infos) == 4
        for done, info in zip(dones, infos):
            assert_world_info(info)
            assert ("terminal_observation" in info) == done
            assert isinstance(info["TimeLimit.truncated"], bool)
            assert not info["TimeLimit.truncated"] or done
            if done:
                terminal = info["terminal_observation"]
                assert terminal.shape == (OBS_DIM,) and terminal.dtype == np.float32
        ends += int(dones.sum())
    assert ends >= 4  # 20 steps with episodes of at most 6: every world finished at least once


def test_time_limit_truncates_and_restarts_the_episode(make):
    venv = make(num_envs=3, max_episode_steps=5, start="beginning", termination_distance=None)
    first = venv.reset()
    zeros = np.zeros((3, 69), np.float32)
    for _ in range(4):
        obs, _, dones, infos = venv.step(zeros)
        assert not dones.any() and not any(i["TimeLimit.truncated"] for i in infos)
    obs, _, dones, infos = venv.step(zeros)
    assert dones.all()
    for i, info in enumerate(infos):
        assert info["TimeLimit.truncated"] is True
        # infos[i] is the finished episode's last step; the new episode's reset info is kept apart.
        assert info["motion_time"] == pytest.approx(5 / 30, abs=1e-6)
        assert venv.reset_infos[i]["motion_time"] == pytest.approx(0.0, abs=1e-9)
        assert np.abs(info["terminal_observation"] - obs[i]).max() > 1e-3
    # The returned observation is the new episode's first: the clip's first frame, as at reset.
    np.testing.assert_allclose(obs, first, rtol=0, atol=1e-4)


def test_termination_is_not_a_time_limit(make):
    # With a micrometre termination distance every world ends on its first step, by termination.
    venv = make(num_envs=3, termination_distance=1e-6, start="beginning")
    venv.reset()
    _, _, dones, infos = venv.step(np.zeros((3, 69), np.float32))
    assert dones.all()
    assert [i["TimeLimit.truncated"] for i in infos] == [False, False, False]
    assert all("terminal_observation" in i for i in infos)


def test_attributes_methods_and_options(make):
    venv = make(num_envs=3)
    assert venv.get_attr("start") == ["random"] * 3
    assert venv.get_attr("start", indices=[1]) == ["random"]
    venv.set_attr("start", "beginning")
    assert venv.get_attr("start") == ["beginning"] * 3
    with pytest.raises(ValueError, match="share one env"):
        venv.set_attr("start", "random", indices=[0])
    assert venv.has_attr("motion_lib") and not venv.has_attr("no_such_attribute")
    with pytest.raises(AttributeError):
        venv.get_attr("no_such_attribute")
    venv.reset()
    actions = venv.env_method("reference_action")
    assert len(actions) == 3 and actions[0].shape == (3, 69)
    assert venv.env_is_wrapped(Monitor) == [False] * 3

    venv.set_attr("start", "random")
    venv.set_options({"start": "beginning"})
    venv.reset()
    assert [i["motion_time"] for i in venv.reset_infos] == pytest.approx([0.0] * 3, abs=1e-9)
    venv.set_options([{"start": "beginning"}, {}, {}])
    with pytest.raises(ValueError, match="same options"):
        venv.reset()


def test_takes_an_existing_vector_env_only_in_same_step_mode(make):
    native = gym.make_vec(ENV_ID, num_envs=2, autoreset_mode="SameStep")
    venv = make(native, num_envs=None)
    assert venv.num_envs == 2 and venv.reset().shape == (2, OBS_DIM)
    next_step = gym.make_vec(ENV_ID, num_envs=2)
    try:
        with pytest.raises(ValueError, match="SameStep"):
            SB3VecEnv(next_step)
        with pytest.raises(TypeError, match="only apply"):
            SB3VecEnv(next_step, max_episode_steps=5)
    finally:
        next_step.close()
    with pytest.raises(ValueError, match="SameStep"):
        SB3VecEnv(ENV_ID, num_envs=2, autoreset_mode="NextStep")
    with pytest.raises(TypeError, match="DummyVecEnv"):
        SB3VecEnv(gym.make("Pendulum-v1"))


def test_render_tiles_a_frame_per_world(make):
    venv = make(num_envs=2, render_mode="rgb_array", render_size=(64, 48))
    assert venv.render_mode == "rgb_array"
    venv.reset()
    images = venv.get_images()
    assert len(images) == 2 and all(i.shape == (48, 64, 3) for i in images)
    frame = venv.render()  # SB3 tiles the worlds' frames into one image
    assert frame.shape == (96, 64, 3) and frame.dtype == np.uint8 and frame.std() > 1
    quiet = make(num_envs=2)
    quiet.reset()
    with pytest.warns(UserWarning):
        assert quiet.render() is None


def test_ppo_learns_on_it():
    from stable_baselines3 import PPO

    venv = SB3VecEnv(ENV_ID, num_envs=4, max_episode_steps=64)
    model = PPO("MlpPolicy", venv, n_steps=64, batch_size=64, n_epochs=1,
                policy_kwargs=dict(net_arch=[64, 64]), device="cpu", seed=0)
    model.learn(1024)
    assert model.num_timesteps >= 1024
    venv.close()


def test_vec_monitor_and_vec_normalize_wrap_it():
    from stable_baselines3 import PPO

    venv = VecNormalize(VecMonitor(SB3VecEnv(ENV_ID, num_envs=4, max_episode_steps=8)))
    model = PPO("MlpPolicy", venv, n_steps=16, batch_size=64, n_epochs=1,
                policy_kwargs=dict(net_arch=[32, 32]), device="cpu", seed=0)
    model.learn(128)
    assert len(model.ep_info_buffer) > 0  # VecMonitor saw episodes end
    rng = np.random.default_rng(0)
    for _ in range(8):
        obs, rewards, dones, infos = venv.step(random_actions(venv, rng))
        assert np.isfinite(obs).all() and np.abs(obs).max() <= venv.clip_obs + 1e-6
        for done, info in zip(dones, infos):
            if done:  # VecNormalize normalises the terminal observation as well
                assert np.abs(info["terminal_observation"]).max() <= venv.clip_obs + 1e-6
                assert "episode" in info
    venv.close()


def test_masked_and_nested_info_keys_follow_gymnasium_conventions(make):
    # Gymnasium's vector RecordEpisodeStatistics adds info["episode"] = {"r": (N,), ...} with an
    # "_episode" mask: world i's dict carries "episode" only where the mask is set.
    from gymnasium.wrappers.vector import RecordEpisodeStatistics

    # From a clip's first frame, so that the 3-step limit is the only way an episode ends (a
    # random start frame within 3 frames of the clip's end truncates it sooner).
    native = RecordEpisodeStatistics(gym.make_vec(ENV_ID, num_envs=3, autoreset_mode="SameStep",
                                                  max_episode_steps=3, termination_distance=None,
                                                  start="beginning"))
    venv = make(native, num_envs=None)
    venv.reset()
    for _ in range(3):
        _, _, dones, infos = venv.step(np.zeros((3, 69), np.float32))
    assert dones.all()
    for info in infos:
        assert info["episode"]["l"] == 3 and np.ndim(info["episode"]["r"]) == 0
