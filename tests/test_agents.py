"""PPO and AMP: learning, persistence, resume, the discriminator, and bad input."""
from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
import torch

import agents
from agents import AMP, PPO, ActorCritic, AMPConfig, CheckpointCallback, PPOConfig, RolloutBuffer
from agents.checkpoint import save_checkpoint
from agents.logger import Logger
from agents.rollout import minibatches

TINY = dict(actor_hidden=(32, 32), critic_hidden=(32, 32), verbose=0)


def _rollout_return(model, env_id, episodes=5, seed=0):
    import gymnasium as gym

    env = gym.make(env_id)
    total = []
    for k in range(episodes):
        obs, _ = env.reset(seed=seed + k)
        done, ret = False, 0.0
        while not done:
            obs, r, term, trunc, _ = env.step(model.predict(obs, deterministic=True)[0])
            ret += r
            done = term or trunc
        total.append(ret)
    env.close()
    return float(np.mean(total))


@pytest.mark.slow
def test_ppo_solves_inverted_pendulum():
    # Gymnasium's reward threshold for InvertedPendulum-v5 is 950 (of 1000).
    model = PPO("InvertedPendulum-v5", n_envs=8, n_steps=128, batch_size=256, n_epochs=10, seed=0,
                actor_hidden=(64, 64), critic_hidden=(64, 64), activation="tanh", log_std_init=-0.5, verbose=0)
    model.learn(150_000, progress_bar=False)
    assert _rollout_return(model, "InvertedPendulum-v5") >= 950


def test_ppo_improves_on_pendulum_quickly():
    # A fast guard that the update moves the policy the right way: Pendulum's return rises.
    model = PPO("Pendulum-v1", n_envs=8, n_steps=64, batch_size=128, n_epochs=10, learning_rate=1e-3, seed=1,
                gamma=0.95, log_std_init=0.0, **TINY)
    before = _rollout_return(model, "Pendulum-v1", episodes=4)
    model.learn(24_000, progress_bar=False)
    after = _rollout_return(model, "Pendulum-v1", episodes=4)
    assert after > before + 200, (before, after)


def test_gae_matches_hand_computation():
    buf = RolloutBuffer(n_steps=3, n_envs=1, obs_dim=2, act_dim=1)
    buf.rewards[:, 0] = torch.tensor([1.0, 2.0, 3.0])
    buf.values[:, 0] = torch.tensor([0.5, 1.0, 1.5])
    buf.dones[:, 0] = torch.tensor([0.0, 1.0, 0.0])
    buf.bootstrap[:, 0] = torch.tensor([0.0, 4.0, 0.0])  # step 1 was cut by a time limit, V(final) = 4
    buf.compute_advantages(torch.tensor([2.0]), gamma=0.9, gae_lambda=0.5)
    d2 = 3.0 + 0.9 * 2.0 - 1.5
    d1 = 2.0 + 0.9 * 4.0 - 1.0               # episode ends: no chaining into step 2
    d0 = 1.0 + 0.9 * 1.0 - 0.5
    expected = [d0 + 0.9 * 0.5 * d1, d1, d2]
    np.testing.assert_allclose(buf.advantages[:, 0].numpy(), expected, rtol=1e-6)
    np.testing.assert_allclose(buf.returns.numpy(), buf.advantages.numpy() + buf.values.numpy(), rtol=1e-6)


def test_minibatches_cover_valid_transitions_once_per_epoch():
    buf = RolloutBuffer(n_steps=4, n_envs=3, obs_dim=2, act_dim=1)
    buf.obs[..., 0] = torch.arange(12.0).reshape(4, 3)
    buf.valid.fill_(1.0)
    buf.valid[1, 2] = buf.valid[3, 0] = 0.0  # NextStep's reset-only steps are no transitions
    buf.compute_advantages(torch.zeros(3), 0.99, 0.95)
    seen = [mb["obs"][:, 0] for mb in buf.minibatches(5)]
    assert [len(x) for x in seen] == [5, 5]  # 10 valid, in two full minibatches
    assert sorted(torch.cat(seen).tolist()) == [0, 1, 2, 3, 4, 6, 7, 8, 10, 11]


def test_minibatches_use_every_transition_when_a_few_steps_are_invalid():
    # 64 x 32 steps with 3 reset-only ones: two minibatches of ~1022, none left out (cutting
    # whole 1024-pieces would have trained on one minibatch and dropped the other 1021).
    data = {"x": torch.arange(2045.0)}
    sizes = [len(mb["x"]) for mb in minibatches(data, 1024)]
    assert sizes == [1023, 1022]
    seen = torch.cat([mb["x"] for mb in minibatches(data, 1024)])
    assert sorted(seen.tolist()) == data["x"].tolist()
    assert [len(mb["x"]) for mb in minibatches(data, 4096)] == [2045]


def test_save_load_gives_identical_deterministic_actions(tmp_path):
    model = PPO("Pendulum-v1", n_envs=2, n_steps=64, batch_size=64, seed=0, **TINY).learn(256, progress_bar=False)
    path = model.save(tmp_path / "pendulum")
    assert path.name == "pendulum.pt"
    loaded = agents.load(path, device="cpu", verbose=0)
    assert type(loaded) is PPO and loaded.env is None
    obs = np.random.default_rng(0).normal(size=(64, 3)).astype(np.float32)
    np.testing.assert_array_equal(model.predict(obs)[0], loaded.predict(obs)[0])
    single, state = loaded.predict(obs[0])
    assert single.shape == (1,) and state is None
    # Pendulum's box is [-2, 2]: the policy's [-1, 1] maps onto it.
    wild = loaded.predict(obs * 1e3, deterministic=False)[0]
    assert np.all(np.abs(wild) <= 2.0)


def test_resume_continues_step_count_and_normaliser(tmp_path):
    model = PPO("Pendulum-v1", n_envs=2, n_steps=32, batch_size=32, seed=0, **TINY).learn(256, progress_bar=False)
    model.save(tmp_path / "a.pt")
    norm = model.policy.obs_norm
    resumed = PPO.load(tmp_path / "a.pt", env="auto", verbose=0)
    assert resumed.num_timesteps == 256 and resumed.iteration == model.iteration
    assert resumed.env.num_envs == 2 and resumed.env_id == "Pendulum-v1"
    torch.testing.assert_close(resumed.policy.obs_norm.mean, norm.mean)
    torch.testing.assert_close(resumed.policy.obs_norm.count, norm.count)
    resumed.learn(128, reset_num_timesteps=False, progress_bar=False)
    assert resumed.num_timesteps == 384
    # The normaliser kept accumulating on top of the saved statistics, not from scratch.
    assert resumed.policy.obs_norm.count.item() == pytest.approx(norm.count.item() + 128, abs=1)
    fresh = PPO.load(tmp_path / "a.pt", env="Pendulum-v1", verbose=0).learn(128, progress_bar=False)
    assert fresh.num_timesteps == 128  # the default starts the count over, as Stable-Baselines3 does


def test_checkpoints_are_atomic(tmp_path, monkeypatch):
    path = save_checkpoint({"class": "PPO", "x": torch.ones(3)}, tmp_path / "ckpt.pt")
    before = path.read_bytes()

    def broken_save(obj, f):
        f.write(b"partial")
        raise OSError("disk full")

    monkeypatch.setattr(torch, "save", broken_save)
    with pytest.raises(OSError, match="disk full"):
        save_checkpoint({"class": "PPO", "x": torch.zeros(3)}, path)
    assert path.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["ckpt.pt"]  # no temporary left behind


def test_load_rejects_foreign_files_and_wrong_class(tmp_path):
    (tmp_path / "junk.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(ValueError, match="not a readable"):
        agents.load(tmp_path / "junk.pt")
    torch.save({"weights": torch.ones(2)}, tmp_path / "other.pt")
    with pytest.raises(ValueError, match="not a smpl-envs agent checkpoint"):
        agents.load(tmp_path / "other.pt")
    with pytest.raises(FileNotFoundError):
        agents.load(tmp_path / "missing.pt")
    PPO("Pendulum-v1", **TINY).save(tmp_path / "ppo.pt")
    with pytest.raises(ValueError, match="holds a PPO agent"):
        AMP.load(tmp_path / "ppo.pt")


def test_callbacks_checkpoint_and_stop(tmp_path):
    calls = []

    def stop_after_three(agent):
        calls.append(agent.num_timesteps)
        return len(calls) < 3

    model = PPO("Pendulum-v1", n_envs=2, n_steps=16, batch_size=32, **TINY)
    model.learn(10_000, progress_bar=False,
                callback=[CheckpointCallback(64, tmp_path / "ck", keep=1), stop_after_three])
    assert calls == [32, 64, 96] and model.num_timesteps == 96
    assert sorted(p.name for p in (tmp_path / "ck").iterdir()) == ["ckpt_000000000064.pt", "last.pt"]
    assert agents.load(tmp_path / "ck" / "last.pt").num_timesteps == 96


def test_bad_input_gives_clear_errors():
    model = PPO("Pendulum-v1", **TINY)
    with pytest.raises(ValueError, match="expects 3"):
        model.predict(np.zeros(5, np.float32))
    with pytest.raises(ValueError, match="NaN"):
        model.predict(np.array([np.nan, 0, 0], np.float32))
    with pytest.raises(TypeError, match="Box action space"):
        PPO("CartPole-v1", **TINY)
    with pytest.raises(TypeError, match="unexpected keyword"):
        PPO("Pendulum-v1", not_a_hyperparameter=1)
    with pytest.raises(ValueError, match="activation"):
        PPO("Pendulum-v1", activation="swish2")
    with pytest.raises(ValueError, match="motion_lib"):
        AMP("Pendulum-v1", **TINY)
    with pytest.raises(RuntimeError, match="no env"):
        PPO(None, **TINY).learn(10)


def test_cuda_device_without_cuda_is_a_value_error_that_says_what_to_install(tmp_path, monkeypatch):
    # As on a CPU-only torch build, whichever build runs the test.
    monkeypatch.setattr(torch.version, "cuda", None)
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    for make in (lambda: PPO("Pendulum-v1", device="cuda", **TINY),
                 lambda: AMP("SMPL/Speed-v0", env_kwargs={"motions": "walk"}, device="cuda:0", **TINY)):
        with pytest.raises(ValueError, match=r"device='cuda(:0)?'.*CPU-only build.*Install a CUDA build.*pip install"):
            make()
    path = PPO("Pendulum-v1", **TINY).save(tmp_path / "p.pt")
    with pytest.raises(ValueError, match="CPU-only build"):
        PPO.load(path, device="cuda")
    # A CUDA build without a visible GPU: a driver or CUDA_VISIBLE_DEVICES matter, not the build.
    monkeypatch.setattr(torch.version, "cuda", "12.8")
    with pytest.raises(ValueError, match="sees 0 CUDA device.*CUDA_VISIBLE_DEVICES"):
        PPO("Pendulum-v1", device="cuda", **TINY)
    with pytest.raises(ValueError, match="device='cdua' is not a torch device"):
        PPO("Pendulum-v1", device="cdua", **TINY)
    assert PPO("Pendulum-v1", device="auto", **TINY).device == torch.device("cpu")


def test_logger_writes_csv_with_late_columns_and_tensorboard(tmp_path):
    log = Logger(tmp_path, stdout=False)
    log.record("rollout/a", 1.0)
    log.dump(10)
    log.record("rollout/a", 2.0)
    log.record("rollout/b", 3.0)
    log.dump(20)
    log.close()
    lines = (tmp_path / "progress.csv").read_text().splitlines()
    assert lines[0].split(",") == ["time/total_timesteps", "rollout/a", "rollout/b"]
    assert lines[1:] == ["10.0,1.0,", "20.0,2.0,3.0"]
    assert list((tmp_path / "tb").glob("events.out.tfevents.*"))


@pytest.mark.parametrize("mode", ["NextStep", "SameStep"])
def test_ppo_on_suite_vector_env_both_autoreset_modes(mode):
    model = PPO("SMPL/Imitation-v0", n_envs=4, env_kwargs=dict(motions="walk", autoreset_mode=mode),
                n_steps=48, batch_size=64, n_epochs=1, seed=0, **TINY)
    model.learn(192, progress_bar=False)
    assert model.episodes, "a random policy falls within 48 steps"
    lengths = np.array([n for _, n in model.episodes])
    assert lengths.min() >= 1 and lengths.max() <= 48
    logged = {k.split("rollout/reward_")[1] for k in model.logger.last if k.startswith("rollout/reward_")}
    assert {"pos", "rot", "lin_vel", "ang_vel", "energy"} <= logged


def test_amp_discriminator_separates_reference_from_random_policy():
    # Policy frozen (learning rate 0) and wide (std 1): D alone learns, from rollouts of a random policy.
    model = AMP("SMPL/Imitation-v0", n_envs=8, env_kwargs=dict(motions="walk"), n_steps=32, batch_size=128,
                n_epochs=2, learning_rate=0.0, log_std_init=0.0, seed=0, disc_hidden=(64, 64),
                disc_learning_rate=1e-3, replay_size=2000, **TINY)
    real = model._sample_demo(256)
    model.learn(8 * 32 * 4, progress_bar=False)
    windows = model._collect().extras["amp_windows"]  # a fresh rollout D has not trained on
    fake = windows.reshape(-1, windows.shape[-1])
    assert model.discriminator_accuracy(real, fake) > 0.95
    # The style reward pays reference-like windows more.
    assert model.style_reward(real).mean() > 2 * model.style_reward(fake).mean()


def test_subnormals_are_flushed_from_parameters_and_moments():
    from agents.optim import adam, flush_subnormals_

    tiny = torch.finfo(torch.float32).tiny
    layer = torch.nn.Linear(4, 3)
    opt = adam(layer.parameters(), lr=1e-3)
    layer(torch.ones(2, 4)).sum().backward()
    opt.step()
    with torch.no_grad():
        layer.weight[0, :3] = torch.tensor([tiny / 4, -tiny / 8, 1e3 * tiny])  # subnormal, and near it
        layer.weight[1, 0] = 1e-20  # small, but far from the subnormal range: kept
    opt.state[layer.weight]["exp_avg"][2, 3] = tiny / 2
    kept = layer.weight.detach().clone()
    flush_subnormals_(opt)
    assert layer.weight[0, :3].tolist() == [0.0, 0.0, 0.0] and layer.weight[1, 0].item() == pytest.approx(1e-20)
    assert opt.state[layer.weight]["exp_avg"][2, 3].item() == 0.0
    torch.testing.assert_close(layer.weight[1:], kept[1:], rtol=0, atol=0)
    assert int(opt.state[layer.weight]["step"]) == 1  # the step count is no moment


def test_every_update_flushes_both_optimizers(monkeypatch):
    import agents.amp as amp_module
    import agents.ppo as ppo_module

    flushed = []
    for module in (ppo_module, amp_module):
        real = module.flush_subnormals_
        monkeypatch.setattr(module, "flush_subnormals_", lambda opt, real=real: (flushed.append(opt), real(opt)))
    model = AMP("SMPL/Imitation-v0", n_envs=2, env_kwargs=dict(motions="walk"), n_steps=16, batch_size=32,
                n_epochs=1, disc_hidden=(16,), replay_size=100, seed=0, **TINY)
    model.learn(64, progress_bar=False)  # two iterations
    assert flushed == [model.optimizer, model.disc_optimizer] * 2


def test_amp_disc_batch_size_sets_the_windows_per_discriminator_step(monkeypatch):
    model = AMP("SMPL/Imitation-v0", n_envs=2, env_kwargs=dict(motions="walk"), n_steps=32, batch_size=32,
                n_epochs=1, disc_hidden=(16,), disc_batch_size=8, replay_size=0, seed=0, **TINY)
    sizes, step = [], model._disc_step
    monkeypatch.setattr(model, "_disc_step", lambda real, fake: (sizes.append((len(real), len(fake))), step(real, fake))[1])
    model.learn(64, progress_bar=False)
    # One D step per policy minibatch (~2 of 32 per 64-sample rollout), each on 8 + 8 windows.
    assert len(sizes) >= 2 and set(sizes) == {(8, 8)}, sizes
    with pytest.raises(ValueError, match="disc_batch_size"):
        AMPConfig(disc_batch_size=0)


def test_amp_save_load_roundtrip(tmp_path):
    model = AMP("SMPL/KeypointImitation-v0", n_envs=2, env_kwargs=dict(motions="walk"), n_steps=16,
                batch_size=32, n_epochs=1, disc_hidden=(32, 32), replay_size=100, seed=0, **TINY)
    model.learn(64, progress_bar=False)
    model.save(tmp_path / "amp.pt")
    loaded = agents.load(tmp_path / "amp.pt", env="auto", verbose=0)
    assert type(loaded) is AMP and loaded.env_id == "SMPL/KeypointImitation-v0"
    windows = model._sample_demo(16)
    torch.testing.assert_close(loaded.style_reward(windows), model.style_reward(windows))
    obs = np.random.default_rng(0).normal(size=(4, loaded.obs_dim)).astype(np.float32)
    np.testing.assert_array_equal(loaded.predict(obs)[0], model.predict(obs)[0])
    loaded.learn(32, reset_num_timesteps=False, progress_bar=False)
    assert loaded.num_timesteps == 96


def test_save_warns_about_env_kwargs_it_cannot_store(tmp_path):
    from smpl_envs.envs import load_motions

    lib = load_motions("walk")
    model = PPO("SMPL/Imitation-v0", n_envs=1, env_kwargs={"motions": lib, "start": "beginning"}, **TINY)
    with pytest.warns(UserWarning, match=r"\['motions'\]"):
        model.save(tmp_path / "m.pt")
    # The rest is kept, and the policy settings are recorded even where they were defaults.
    assert agents.load(tmp_path / "m.pt").env_kwargs == {"start": "beginning", "substeps": 4,
                                                         "action_mode": "absolute", "residual_scale": 0.25}


def test_amp_demo_windows_from_frame_table_match_the_motion_library(monkeypatch):
    import agents.amp as amp_module

    model = AMP("SMPL/Imitation-v0", n_envs=1, env_kwargs=dict(motions=["walk", "jump"]), disc_hidden=(8,),
                **TINY)
    lib = model.motion_lib
    assert model._frame_table.shape == (lib.num_frames, 232)
    ids = np.array([0, 0, 1, 1, 1])
    times = np.array([0, 3, 0, 5, lib.lengths[1] - 1]) / lib.fps  # window starts before the clip, too
    table = model._reference_windows(ids, times)
    monkeypatch.setattr(model, "_frame_table", None)
    direct = model._reference_windows(ids, times)
    np.testing.assert_allclose(table, direct, atol=1e-5)
    monkeypatch.setattr(amp_module, "DEMO_TABLE_MAX_FRAMES", 10)
    model.set_env("SMPL/Imitation-v0", env_kwargs=dict(motions="walk"))
    assert model._frame_table is None  # large libraries fall back to computing windows


def test_settings_are_one_dataclass_per_agent():
    from agents.recipes import accepted_hyperparams

    assert set(PPOConfig.names()) < set(AMPConfig.names())
    assert accepted_hyperparams(PPO) == set(PPOConfig.names()) - {"seed"}  # the recipe sets the seed in train:
    model = PPO(None, n_steps=32, bounds_loss_coef=10, policy_kwargs={"actor_hidden": [8], "critic_hidden": [32, 32]},
                verbose=0)
    # Values take their field's type, so a checkpoint stores the same dict however they were spelled.
    assert model.hyperparams["bounds_loss_coef"] == 10.0 and isinstance(model.hyperparams["bounds_loss_coef"], float)
    # Network sizes are the policy's arguments, not hyperparameters.
    assert model.hyperparams == {**PPOConfig().to_dict(), "n_steps": 32, "bounds_loss_coef": 10.0}
    assert model.policy_class is ActorCritic and model.policy_kwargs == {"actor_hidden": [8], "critic_hidden": [32, 32]}
    # Attributes read and write through to the config.
    assert model.n_steps == 32 and model.learning_rate == 3e-4
    model.learning_rate = 1e-5
    assert model.config.learning_rate == 1e-5 and model.hyperparams["learning_rate"] == 1e-5
    with pytest.raises(TypeError, match=r"unexpected keyword argument\(s\) \['disc_hidden'\]"):
        PPO(None, disc_hidden=(8,))
    with pytest.raises(ValueError, match="lr_schedule"):
        PPO(None, lr_schedule="cosine")
    with pytest.raises(ValueError, match="lr_decay_from"):
        PPO(None, lr_schedule="linear", lr_decay_from=1.0)


def test_learning_rate_schedules():
    from agents.on_policy import scheduled_learning_rate
    constant = PPO(None, learning_rate=1e-3).config
    assert [scheduled_learning_rate(constant, t, 100) for t in (0, 50, 100)] == [1e-3] * 3
    linear = PPO(None, learning_rate=1e-3, lr_schedule="linear").config
    assert [scheduled_learning_rate(linear, t, 100) for t in (0, 50, 100, 150)] == pytest.approx([1e-3, 5e-4, 0, 0])
    # Held for the first 60 %, then down to zero over the last 40 %.
    held = PPO(None, learning_rate=1e-3, lr_schedule="linear", lr_decay_from=0.6).config
    assert [scheduled_learning_rate(held, t, 100) for t in (0, 60, 80, 100)] == pytest.approx([1e-3, 1e-3, 5e-4, 0])


def test_policy_can_be_built_apart_and_handed_in(tmp_path):
    torch.manual_seed(0)
    box = gym.spaces.Box(-2.0, 2.0, (1,))  # Pendulum's: the policy maps its [-1, 1] onto it
    policy = ActorCritic(3, box, actor_hidden=(16,), critic_hidden=(16,), log_std_init=-0.5)
    model = PPO("Pendulum-v1", n_envs=2, n_steps=16, batch_size=32, policy=policy, seed=0, verbose=0)
    assert model.policy is policy
    before = policy.actor[0].weight.detach().clone()
    model.learn(64, progress_bar=False)
    assert not torch.equal(before, policy.actor[0].weight)  # the handed-in policy is what trains
    path = model.save(tmp_path / "p.pt")
    again = PPO.load(path, verbose=0, policy=ActorCritic(3, box, actor_hidden=(16,), critic_hidden=(16,)))
    obs = np.random.default_rng(0).normal(size=(8, 3)).astype(np.float32)
    np.testing.assert_array_equal(again.predict(obs)[0], model.predict(obs)[0])
    np.testing.assert_array_equal(PPO.load(path, verbose=0).predict(obs)[0], model.predict(obs)[0])  # from the record
    with pytest.raises(ValueError, match="policy is for obs 4"):
        PPO("Pendulum-v1", policy=ActorCritic(4, box), verbose=0)
    with pytest.raises(ValueError, match=r"onto \[-1.0, 1.0\], the env's action box is \[-2.0, 2.0\]"):
        PPO("Pendulum-v1", policy=ActorCritic(3, 1), verbose=0)


def test_collector_fills_the_buffer_and_calls_its_hooks():
    from collections import deque

    import gymnasium as gym

    from agents.rollout import RolloutCollector, RolloutHooks

    class Recorder(RolloutHooks):
        def __init__(self):
            self.calls = []

        def on_reset(self, info):
            self.calls.append("reset")

        def on_rollout_start(self, buffer):
            self.calls.append("start")

        def on_step(self, t, info, done, valid):
            self.calls.append(t)

        def on_rollout_end(self, buffer):
            self.calls.append("end")

    env = gym.make_vec("Pendulum-v1", num_envs=2, vectorization_mode="sync")
    policy = ActorCritic(3, env.single_action_space, actor_hidden=(8,), critic_hidden=(8,))
    episodes, hooks = deque(), Recorder()
    collector = RolloutCollector(env, policy, episodes, hooks)
    collector.reset(seed=0)
    buf = RolloutBuffer(5, 2, 3, 1)
    last_value, _ = collector.collect(buf)
    assert hooks.calls == ["reset", "start", 0, 1, 2, 3, 4, "end"]
    assert last_value.shape == (2,) and bool(buf.valid.all())
    # Stored observations are the policy's normalised input of their step; values match them.
    torch.testing.assert_close(buf.values[-1], policy.value(buf.obs[-1]))
    assert policy.obs_norm.count.item() == pytest.approx(10, abs=1e-3)
    env.close()


def test_collector_bootstraps_time_limits_and_counts_each_observation_once():
    import gymnasium as gym
    from collections import deque
    from agents.rollout import RolloutCollector

    # NextStep autoreset with a 3-step limit: steps 2 and 6 end episodes by truncation, steps 3
    # and 7 only reset, and their observation is the truncated episode's final one.
    env = gym.make_vec("Pendulum-v1", num_envs=2, vectorization_mode="sync", max_episode_steps=3)
    policy = ActorCritic(3, env.single_action_space, actor_hidden=(8,), critic_hidden=(8,))
    collector = RolloutCollector(env, policy, deque())
    collector.reset(seed=0)
    assert policy.obs_norm.count.item() == pytest.approx(2, abs=1e-3)  # the reset observations
    buf = RolloutBuffer(8, 2, 3, 1)
    collector.collect(buf)
    assert buf.valid[:, 0].tolist() == [1, 1, 1, 0, 1, 1, 1, 0]
    # Bootstraps come from the batched value pass: V of the final observation, where cut.
    torch.testing.assert_close(buf.bootstrap[[2, 6]], policy.value(buf.obs[[3, 7]]))
    assert float(buf.bootstrap[[0, 1, 3, 4, 5, 7]].abs().sum()) == 0.0
    # 6 valid steps per world; the first step's observations were the reset's, counted then.
    assert policy.obs_norm.count.item() == pytest.approx(2 * 6, abs=1e-3)
    env.close()


def test_held_exploration_noise_keeps_its_direction_and_redraws_at_each_hold_and_episode():
    import gymnasium as gym
    from collections import deque
    from agents.rollout import RolloutCollector

    # 5-step episodes, NextStep autoreset: steps 0-4 one episode, 5 only resets, 6-11 the next.
    env = gym.make_vec("Pendulum-v1", num_envs=2, vectorization_mode="sync", max_episode_steps=5)
    policy = ActorCritic(3, env.single_action_space, actor_hidden=(8,), critic_hidden=(8,), log_std_init=-1.0)
    torch.manual_seed(0)
    collector = RolloutCollector(env, policy, deque(), noise_hold=3)
    collector.reset(seed=0)
    buf = RolloutBuffer(12, 2, 3, 1)
    collector.collect(buf)
    dist = policy.action_distribution(buf.obs)  # stored observations: what the actor saw
    eps = ((buf.actions - dist.mean) / dist.stddev)[:, 0, 0]
    # The stored log-probabilities score each action under its own step's distribution.
    torch.testing.assert_close(buf.log_probs, dist.log_prob(buf.actions).sum(-1))
    held = [(0, 1), (1, 2), (3, 4), (5, 6), (6, 7), (8, 9), (9, 10)]
    redrawn = [(2, 3), (4, 5), (7, 8), (10, 11)]  # a hold ends (2, 7, 10) or an episode does (4)
    for a, b in held:
        assert eps[a].item() == pytest.approx(eps[b].item(), abs=1e-5), (a, b)
    for a, b in redrawn:
        assert abs(eps[a].item() - eps[b].item()) > 1e-3, (a, b)
    # Worlds draw their own noise; and without a hold every step draws afresh.
    assert abs(eps[0].item() - ((buf.actions - dist.mean) / dist.stddev)[0, 1, 0].item()) > 1e-3
    fresh = RolloutCollector(env, policy, deque())
    fresh.reset(seed=0)
    fresh.collect(buf)
    dist = policy.action_distribution(buf.obs)
    eps = ((buf.actions - dist.mean) / dist.stddev)[:, 0, 0]
    assert (eps[1:] - eps[:-1]).abs().min().item() > 1e-4
    with pytest.raises(ValueError, match="noise_hold"):
        RolloutCollector(env, policy, deque(), noise_hold=0)
    with pytest.raises(ValueError, match="exploration_hold"):
        PPOConfig(exploration_hold=0)
    env.close()


def test_amp_reaches_the_clips_only_through_the_documented_motion_lib():
    import gymnasium as gym

    from agents.amp import reference_motion

    vec = gym.make_vec("SMPL/Speed-v0", num_envs=2, motions=["walk", "run"])
    single = gym.make("SMPL/Imitation-v0", motions="walk")
    assert reference_motion(vec) is vec.motion_lib
    assert reference_motion(gym.vector.SyncVectorEnv([lambda: single])) is single.unwrapped.motion_lib
    with pytest.raises(ValueError, match="motion_lib"):
        reference_motion(gym.make_vec("SMPL/Speed-v0", num_envs=1))  # a goal task made without style clips
    # A goal task's style clips are what AMP's demo windows come from.
    model = AMP(vec, n_steps=8, batch_size=16, n_epochs=1, disc_hidden=(16,), replay_size=50, seed=0, **TINY)
    assert model.motion_lib.num_motions == 2
    model.learn(16, progress_bar=False)
    assert "amp/disc_loss" in model.logger.last
    vec.close()
    single.close()


def test_update_threads_apply_to_the_update_only():
    import torch

    before = torch.get_num_threads()
    seen = []
    model = PPO("Pendulum-v1", n_envs=2, n_steps=8, batch_size=16, n_epochs=1, verbose=0, device="cpu",
                update_threads=before + 1)
    original = model._update

    def spy(buf):
        seen.append(torch.get_num_threads())
        return original(buf)

    model._update = spy
    model.learn(32, progress_bar=False)
    assert seen and set(seen) == {before + 1} and torch.get_num_threads() == before
    with pytest.raises(ValueError, match="update_threads"):
        PPO("Pendulum-v1", update_threads=0, verbose=0)
