"""The registered imitation envs: Gymnasium contracts, batching, reproducibility, task behaviour."""

import gymnasium as gym
import mujoco
import numpy as np
import pytest

import smpl_envs  # noqa: F401  (registers the ids)
from smpl_envs.envs import ImitationVecEnv
from smpl_envs.sim import CPUSim
from conftest import check_env_quietly

IDS = ["SMPL/Imitation-v0", "SMPL/KeypointImitation-v0"]
OBS_DIM = {"SMPL/Imitation-v0": 934, "SMPL/KeypointImitation-v0": 574}


@pytest.mark.parametrize("env_id", IDS)
def test_env_checker_passes(env_id):
    env = gym.make(env_id, render_mode="rgb_array", render_size=(96, 72))
    check_env_quietly(env)
    assert env.observation_space.shape == (OBS_DIM[env_id],)
    assert env.action_space.shape == (69,)
    env.close()


@pytest.mark.parametrize("env_id", IDS)
def test_observation_structure_tiles_the_observation(env_id):
    env = gym.make(env_id)
    s = env.unwrapped.observation_structure
    spans = sorted((v.start, v.stop) for v in s.values())
    assert spans[0][0] == 0 and spans[-1][1] == OBS_DIM[env_id]
    assert all(a[1] == b[0] for a, b in zip(spans, spans[1:]))
    assert s["self/root_height"] == slice(0, 1)
    obs, _ = env.reset(seed=0)
    assert 0.7 < obs[s["self/root_height"]][0] < 1.1  # a standing pelvis


def test_make_vec_is_native_and_batched():
    env = gym.make_vec("SMPL/Imitation-v0", num_envs=8)
    assert isinstance(env, ImitationVecEnv) and env.sim.num_worlds == 8
    assert env.metadata["autoreset_mode"] == gym.vector.AutoresetMode.NEXT_STEP
    obs, info = env.reset(seed=0)
    assert obs.shape == (8, 934) and obs.dtype == np.float32
    assert info["amp_obs"].shape == (8, 232) and info["body_pos"].shape == (8, 24, 3)
    assert len(set(info["motion_time"].round(3))) > 1  # random start frames differ across worlds
    obs, rew, term, trunc, info = env.step(env.reference_action())
    assert rew.shape == term.shape == trunc.shape == (8,)
    for k in ("reward_pos", "reward_rot", "reward_lin_vel", "reward_ang_vel", "reward_energy"):
        assert info[k].shape == (8,)
    np.testing.assert_allclose(rew, sum(info[k] for k in info if k.startswith("reward_")), atol=1e-9)
    env.close()


def _rollout(env, seed, steps=40):
    obs, _ = env.reset(seed=seed)
    out = [obs]
    rng = np.random.default_rng(0)
    for _ in range(steps):
        obs, rew, term, trunc, _ = env.step(rng.uniform(-0.3, 0.3, env.action_space.shape))
        out += [obs, rew, term, trunc]
    return out


def test_same_seed_same_episode_different_seed_different():
    env = gym.make_vec("SMPL/Imitation-v0", num_envs=3, motions=["walk", "run", "kick"])
    a, b, c = _rollout(env, 7), _rollout(env, 7), _rollout(env, 8)
    assert all(np.array_equal(x, y) for x, y in zip(a, b))
    assert not np.array_equal(a[0], c[0])
    env.close()


def test_threads_do_not_change_results():
    kw = dict(num_envs=4, motions=["walk", "run"])
    one = gym.make_vec("SMPL/Imitation-v0", num_threads=1, **kw)
    two = gym.make_vec("SMPL/Imitation-v0", num_threads=2, **kw)
    assert all(np.array_equal(x, y) for x, y in zip(_rollout(one, 3), _rollout(two, 3)))


def test_split_substep_equals_mj_step():
    """CPUSim steps with mj_step2 + mj_step1 so kinematics stay current; physics must be identical."""
    sim = CPUSim(smpl_envs.humanoid.build_humanoid(), 1, substeps=4)
    m = sim.model
    d = mujoco.MjData(m)
    q0 = sim.qpos[0].copy()
    q0[2] += 0.05
    sim.set_state([0], q0, np.zeros(m.nv))
    d.qpos[:] = q0
    ctrl = np.random.default_rng(0).uniform(-1, 1, m.nu)
    for _ in range(10):
        sim.step(ctrl[None])
        d.ctrl[:] = ctrl
        for _ in range(4):
            mujoco.mj_step(m, d)
    assert np.array_equal(sim.qpos[0], d.qpos) and np.array_equal(sim.qvel[0], d.qvel)
    mujoco.mj_forward(m, d)  # the sim's body arrays describe the current state, not the previous substep
    np.testing.assert_allclose(sim.bodies.pos[0], d.xpos[1:], atol=1e-12)


def test_kinematic_replay_scores_maximum_and_zero_error():
    """Place the humanoid on the reference every step: full imitation reward, no termination."""
    env = gym.make_vec("SMPL/Imitation-v0", num_envs=2, motions=["walk", "jump"], start="beginning",
                       autoreset_mode="Disabled", energy_weight=0.0)
    env.reset(seed=0, options={"motion_ids": [0, 1]})
    lib, sim = env.motion_lib, env.sim

    def replay(ctrl, active=None):
        qpos, qvel = lib.qpos_qvel(np.minimum(env.frame + 1, env.end_frame))
        sim.set_state(np.arange(2), qpos, qvel)
        return np.zeros(2, bool)

    sim.step = replay
    for _ in range(60):
        obs, rew, term, trunc, info = env.step(np.zeros((2, 69)))
        assert not term.any()
        np.testing.assert_allclose(info["body_pos"], info["ref_body_pos"], atol=1e-5)
        assert info["reward_pos"].min() > 0.4999 and info["reward_rot"].min() > 0.2999
        assert rew.min() > 0.97  # velocities are finite differences vs exact joint rates
        # Goal: the position difference is exactly one frame of reference motion, in heading frame.
        nxt = lib.body_pos[np.minimum(env.frame + 1, env.end_frame)]
        step = np.linalg.norm(nxt - lib.body_pos[env.frame], axis=-1)
        np.testing.assert_allclose(np.linalg.norm(obs[:, 358:430].reshape(2, 24, 3), axis=-1), step, atol=1e-4)


def test_zero_action_falls_behind_and_terminates():
    env = gym.make("SMPL/Imitation-v0", motions="walk", start="beginning")
    env.reset(seed=0)
    for t in range(150):
        _, _, term, trunc, info = env.step(np.zeros(69))
        if term or trunc:
            break
    assert term and not trunc, "a limp humanoid must lose the walking reference before the clip ends"
    dist = np.linalg.norm(info["body_pos"] - info["ref_body_pos"], axis=-1)
    assert np.delete(dist, [3, 4, 7, 8]).mean() > 0.5


def test_truncation_at_clip_end_and_autoreset_modes():
    lib_len = smpl_envs.motion.MotionLib.load("jump", progress=False).lengths[0]
    for mode in ("NextStep", "SameStep"):
        env = gym.make_vec("SMPL/Imitation-v0", num_envs=1, motions="jump", start="beginning",
                           termination_distance=None, autoreset_mode=mode)
        env.reset(seed=0)
        for t in range(lib_len - 1):
            obs, rew, term, trunc, info = env.step(env.reference_action())
        assert trunc[0] and not term[0], mode
        if mode == "SameStep":
            assert info["_final_obs"][0] and info["final_obs"].shape == (1, 934)
            assert info["motion_time"][0] == 0.0  # already restarted
        else:
            obs2, rew2, term2, trunc2, info2 = env.step(env.reference_action())
            assert rew2[0] == 0.0 and not (term2[0] or trunc2[0]) and info2["motion_time"][0] == 0.0
        env.close()


def test_partial_reset_with_mask():
    env = gym.make_vec("SMPL/Imitation-v0", num_envs=3, autoreset_mode="Disabled", motions=["walk", "run"])
    obs, _ = env.reset(seed=0)
    obs, *_ = env.step(np.zeros((3, 69)))
    obs2, info = env.reset(options={"reset_mask": [False, True, False], "motion_ids": [1], "start": "beginning"})
    assert np.array_equal(obs2[[0, 2]], obs[[0, 2]])
    assert info["motion_id"][1] == 1 and info["motion_time"][1] == 0.0
    with pytest.raises(ValueError, match="reset options"):
        env.reset(options={"bogus": 1})


def test_bad_input_gives_clear_errors():
    env = gym.make_vec("SMPL/Imitation-v0", num_envs=2)
    env.reset(seed=0)
    with pytest.raises(ValueError, match="shape"):
        env.step(np.zeros((2, 68)))
    with pytest.raises(TypeError, match="no_such_option"):
        gym.make("SMPL/Imitation-v0", no_such_option=1)
    with pytest.raises(ValueError, match="reward_weights"):
        gym.make("SMPL/Imitation-v0", reward_weights={"style": 1.0})
    with pytest.raises(ValueError, match="start"):
        gym.make("SMPL/Imitation-v0", start="middle")
    with pytest.raises(Exception, match="no_such_clip"):
        gym.make("SMPL/Imitation-v0", motions="no_such_clip")


def test_diverged_world_ends_cleanly_and_others_continue(monkeypatch, tmp_path):
    monkeypatch.chdir(tmp_path)  # MuJoCo logs its warnings to ./MUJOCO_LOG.TXT
    env = gym.make_vec("SMPL/Imitation-v0", num_envs=2, motions="stand", termination_distance=None)
    env.reset(seed=0)
    env.sim.datas[1].qvel[:] = 1e6  # an exploding world
    obs, rew, term, trunc, info = env.step(np.zeros((2, 69)))
    assert info["diverged"].tolist() == [False, True]
    assert term.tolist() == [False, True] and rew[1] == 0.0 and np.isfinite(obs).all()
    obs, rew, term, trunc, info = env.step(np.zeros((2, 69)))  # world 1 restarts, world 0 carries on
    assert not term.any() and not info["diverged"].any() and np.isfinite(obs).all()


def test_reward_terms_configurable():
    env = gym.make("SMPL/Imitation-v0", reward_weights={"pos": 1.0, "rot": 0.0, "lin_vel": 0.0, "ang_vel": 0.0},
                   energy_weight=0.0)
    env.reset(seed=0)
    _, rew, _, _, info = env.step(env.unwrapped.reference_action())
    assert info["reward_rot"] == 0.0 and info["reward_energy"] == 0.0
    assert rew == pytest.approx(info["reward_pos"]) and 0.5 < rew <= 1.0


def test_amp_features_of_env_match_motionlib_on_reference_state():
    env = gym.make_vec("SMPL/Imitation-v0", num_envs=1, motions="run", start="beginning",
                       autoreset_mode="Disabled")
    _, info = env.reset(seed=0)
    lib = env.motion_lib
    ref = lib.amp_features(np.array([0]), np.array([0.0]), num_frames=1)[0, 0]
    # Same function; differences only from exact joint rates vs finite-difference reference rates.
    np.testing.assert_allclose(info["amp_obs"][0, :25], ref[:25], atol=0.05)
    np.testing.assert_allclose(info["amp_obs"][0, 25:163], ref[25:163], atol=1e-4)


@pytest.mark.parametrize("env_id", IDS)
def test_stable_baselines3_ppo_trains(env_id, tmp_path):
    """A real external client: SB3's PPO runs its own VecEnv over gym.make'd envs."""
    import stable_baselines3 as sb3  # a test dependency (pyproject's `test` extra)

    env = gym.make(env_id, max_episode_steps=64)
    model = sb3.PPO("MlpPolicy", env, n_steps=256, batch_size=64, n_epochs=2, seed=0, device="cpu",
                    policy_kwargs=dict(net_arch=[64, 64]))
    model.learn(total_timesteps=2048)
    assert model.num_timesteps >= 2048
    model.save(tmp_path / "ppo")
    action, _ = sb3.PPO.load(tmp_path / "ppo", device="cpu").predict(env.reset(seed=0)[0], deterministic=True)
    assert action.shape == (69,) and np.isfinite(action).all()


def test_world_mujoco_resets_is_reported_as_diverged(monkeypatch, tmp_path):
    monkeypatch.chdir(tmp_path)  # MuJoCo logs its warnings to ./MUJOCO_LOG.TXT
    """MuJoCo silently resets a world after a NaN; the sim must report it, not carry on."""
    sim = CPUSim(smpl_envs.humanoid.build_humanoid(), 2, substeps=4)
    sim.step(np.zeros((2, 69)))
    sim.datas[0].qacc_warmstart[:] = np.nan
    sim.datas[0].qpos[3] = np.nan  # MuJoCo's mj_checkPos resets this world on the next substep
    bad = sim.step(np.zeros((2, 69)))
    assert bad.tolist() == [True, False]
    assert not sim.step(np.zeros((2, 69))).any()
