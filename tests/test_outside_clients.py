"""Outside RL libraries on the suite: each path of docs/other-libraries.md, run for a
few hundred steps with a small update on them. Stable-Baselines3's paths are tested in
test_wrappers.py (SB3VecEnv on the native vector env) and test_tasks.py / test_envs.py (PPO on
gym.make ids). A library that is not installed skips its tests, saying so."""
from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
import torch
from gymnasium.vector import VectorEnv
from torch import nn

import smpl_envs  # noqa: F401  (registers the ids)
from smpl_envs.envs.base import VECTOR_ONLY

ENV_ID = "SMPL/Speed-v0"
OBS_DIM, ACT_DIM = 361, 69


@pytest.fixture(autouse=True)
def _one_torch_thread():
    # Small networks: torch's thread pool would only fight the simulation for the cores.
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)


def snapshot(module: nn.Module) -> list[torch.Tensor]:
    return [p.detach().clone() for p in module.parameters()]


def changed(module: nn.Module, before: list[torch.Tensor]) -> bool:
    return any(not torch.equal(p, q) for p, q in zip(module.parameters(), before))


# ---------------------------------------------------------------------------------------- the one-world env
def test_one_world_env_looks_like_a_plain_gymnasium_env():
    env = gym.make("SMPL/Imitation-v0", motions="walk")
    u = env.unwrapped
    assert isinstance(u, gym.Env) and not isinstance(u, VectorEnv)
    for name in VECTOR_ONLY:  # what makes other libraries take an env for a batched one
        assert not hasattr(u, name) and not hasattr(env, name), name
    # Everything else of the task stays reachable, the vector core through .vec.
    obs, info = env.reset(seed=0)
    assert obs.shape == (934,) and u.observation_structure["goal/diff_pos"] == slice(358, 430)
    assert u.motion_lib.num_motions == 1 and u.model.nu == ACT_DIM and u.reference_action().shape == (ACT_DIM,)
    assert u.vec.num_envs == 1 and u.vec.single_action_space == env.action_space
    obs, reward, terminated, truncated, info = env.step(u.reference_action())
    assert isinstance(reward, float) and info["amp_obs"].shape == (232,)
    env.close()


# ---------------------------------------------------------------------------------------- CleanRL-style
def test_cleanrl_style_ppo_loop_on_gymnasium_vector_wrappers():
    """The README's wrapper stack under a hand-written PPO loop (CleanRL's shape): NextStep
    autoreset, so the step after an episode's end only restarts that world and is masked out."""
    from gymnasium.wrappers.vector import ClipAction, NormalizeObservation, RecordEpisodeStatistics
    from torch.distributions import Normal

    torch.manual_seed(0)
    envs = RecordEpisodeStatistics(NormalizeObservation(ClipAction(
        gym.make_vec(ENV_ID, num_envs=4, motions=["walk", "run"], max_episode_steps=24))))
    n, steps = envs.num_envs, 64
    actor = nn.Sequential(nn.Linear(OBS_DIM, 32), nn.Tanh(), nn.Linear(32, ACT_DIM))
    critic = nn.Sequential(nn.Linear(OBS_DIM, 32), nn.Tanh(), nn.Linear(32, 1))
    log_std = nn.Parameter(torch.full((ACT_DIM,), -1.0))
    optimizer = torch.optim.Adam([*actor.parameters(), *critic.parameters(), log_std], lr=1e-3)
    before = snapshot(actor)
    obs, _ = envs.reset(seed=0)
    restarting = np.zeros(n, bool)
    returns = []
    for _ in range(2):  # 2 iterations x 64 steps x 4 worlds
        rollout = []
        for _ in range(steps):
            o = torch.as_tensor(obs)
            with torch.no_grad():
                dist = Normal(actor(o), log_std.exp())
                action = dist.sample()
                logp, value = dist.log_prob(action).sum(-1), critic(o)[:, 0]
            obs, reward, terminated, truncated, info = envs.step(action.numpy())
            assert obs.shape == (n, OBS_DIM) and obs.dtype == np.float32 and np.isfinite(obs).all()
            rollout.append((o, action, logp, value, torch.as_tensor(reward, dtype=torch.float32),
                            torch.as_tensor(terminated | truncated), torch.as_tensor(~restarting)))
            if "episode" in info:
                returns += info["episode"]["r"][info["_episode"]].tolist()
            restarting = terminated | truncated
        o, a, logp, v, r, done, valid = (torch.stack(x) for x in zip(*rollout))
        with torch.no_grad():  # GAE; time limits treated as ends, as CleanRL does
            next_v = torch.cat([v[1:], critic(torch.as_tensor(obs))[:, 0][None]])
            adv, last = torch.zeros_like(r), torch.zeros(n)
            for t in reversed(range(steps)):
                delta = r[t] + 0.99 * next_v[t] * ~done[t] - v[t]
                adv[t] = last = delta + 0.99 * 0.95 * ~done[t] * last
        m = valid
        dist = Normal(actor(o[m]), log_std.exp())
        ratio = (dist.log_prob(a[m]).sum(-1) - logp[m]).exp()
        advantage = (adv[m] - adv[m].mean()) / (adv[m].std() + 1e-8)
        policy_loss = torch.max(-advantage * ratio, -advantage * ratio.clamp(0.8, 1.2)).mean()
        value_loss = 0.5 * (critic(o[m])[:, 0] - (adv + v)[m]).square().mean()
        optimizer.zero_grad()
        (policy_loss + value_loss).backward()
        optimizer.step()
        assert torch.isfinite(policy_loss) and torch.isfinite(value_loss)
        assert int((~valid).sum()) > 0  # episodes ended and their reset-only steps were masked
    assert returns and np.isfinite(returns).all()  # RecordEpisodeStatistics saw episodes end
    assert changed(actor, before)
    envs.close()


# ---------------------------------------------------------------------------------------- skrl
def test_skrl_ppo_trains_on_the_native_vector_env(tmp_path):
    pytest.importorskip("skrl", reason="skrl is not installed (pip install skrl)")
    from skrl.agents.torch.ppo import PPO, PPO_CFG
    from skrl.envs.wrappers.torch import wrap_env
    from skrl.memories.torch import RandomMemory
    from skrl.trainers.torch import SequentialTrainer
    from skrl.utils.model_instantiators.torch import deterministic_model, gaussian_model

    env = wrap_env(gym.make_vec(ENV_ID, num_envs=4, autoreset_mode="SameStep", max_episode_steps=24),
                   wrapper="gymnasium")
    assert env.num_envs == 4 and env.observation_space.shape == (OBS_DIM,) and env.action_space.shape == (ACT_DIM,)
    net = [{"name": "net", "input": "OBSERVATIONS", "layers": [32, 32], "activations": "elu"}]
    spaces = dict(observation_space=env.observation_space, action_space=env.action_space, device=env.device)
    models = {"policy": gaussian_model(**spaces, network=net, output="ACTIONS"),
              "value": deterministic_model(**spaces, network=net, output="ONE")}
    models["policy"].act({"observations": torch.zeros(1, OBS_DIM)}, role="policy")  # skrl's layers are lazy
    before = snapshot(models["policy"])
    cfg = PPO_CFG(rollouts=32, learning_epochs=1, mini_batches=2)
    cfg.experiment.directory, cfg.experiment.write_interval, cfg.experiment.checkpoint_interval = str(tmp_path), 0, 0
    agent = PPO(models=models, memory=RandomMemory(memory_size=32, num_envs=4, device=env.device), cfg=cfg, **spaces)
    trainer = SequentialTrainer(env=env, agents=agent, cfg={"timesteps": 96, "headless": True,
                                                           "disable_progressbar": True,
                                                           "close_environment_at_exit": False})
    trainer.train()  # 96 steps x 4 worlds, 3 updates; episodes end within (24-step limit, falls)
    assert changed(models["policy"], before)
    obs, _ = env.reset()  # a vector env: skrl keeps the autoreset env's current observation
    assert obs.shape == (4, OBS_DIM) and torch.isfinite(obs).all()
    env.close()


# ---------------------------------------------------------------------------------------- torchrl
def test_torchrl_gym_env_on_an_id_with_a_collector_and_ppo_loss():
    """torchrl's PPO tutorial in small: GymEnv on the id, a collector, GAE and ClipPPOLoss."""
    pytest.importorskip("torchrl", reason="torchrl is not installed (pip install torchrl)")
    from tensordict.nn import NormalParamExtractor, TensorDictModule
    from torchrl.collectors import Collector
    from torchrl.envs import Compose, DoubleToFloat, GymEnv, StepCounter, TransformedEnv
    from torchrl.envs.utils import check_env_specs
    from torchrl.modules import ProbabilisticActor, TanhNormal, ValueOperator
    from torchrl.objectives import ClipPPOLoss
    from torchrl.objectives.value import GAE

    torch.manual_seed(0)
    base = GymEnv(ENV_ID, max_episode_steps=50)
    assert base.batch_size == torch.Size([])  # one world: not taken for a batched env
    env = TransformedEnv(base, Compose(DoubleToFloat(), StepCounter()))
    check_env_specs(env)
    actor_net = nn.Sequential(nn.Linear(OBS_DIM, 32), nn.Tanh(), nn.Linear(32, 2 * ACT_DIM), NormalParamExtractor())
    policy = ProbabilisticActor(
        TensorDictModule(actor_net, in_keys=["observation"], out_keys=["loc", "scale"]), spec=env.action_spec,
        in_keys=["loc", "scale"], distribution_class=TanhNormal, return_log_prob=True,
        distribution_kwargs={"low": env.action_spec.space.low, "high": env.action_spec.space.high})
    value = ValueOperator(nn.Sequential(nn.Linear(OBS_DIM, 32), nn.Tanh(), nn.Linear(32, 1)), in_keys=["observation"])
    advantage = GAE(gamma=0.99, lmbda=0.95, value_network=value, average_gae=True)
    loss = ClipPPOLoss(policy, value)
    optimizer = torch.optim.Adam(loss.parameters(), 1e-3)
    before = snapshot(actor_net)
    collector = Collector(env, policy, frames_per_batch=100, total_frames=300, auto_register_policy_transforms=False)
    frames = episodes = 0
    for data in collector:
        assert data.batch_size == torch.Size([100]) and data["observation"].shape == (100, OBS_DIM)
        advantage(data)
        out = loss(data)
        total = out["loss_objective"] + out["loss_critic"] + out["loss_entropy"]
        optimizer.zero_grad()
        total.backward()
        optimizer.step()
        assert torch.isfinite(total.detach())
        frames, episodes = frames + data.numel(), episodes + int(data["next", "done"].sum())
    collector.shutdown()
    assert frames == 300 and episodes >= 1 and changed(actor_net, before)


def test_torchrl_gym_wrapper_on_a_same_step_vector_env():
    pytest.importorskip("torchrl", reason="torchrl is not installed (pip install torchrl)")
    from torchrl.collectors import Collector
    from torchrl.envs import GymWrapper
    from torchrl.envs.utils import check_env_specs

    env = GymWrapper(gym.make_vec(ENV_ID, num_envs=4, autoreset_mode="SameStep", max_episode_steps=20))
    assert env.batch_size == torch.Size([4])
    check_env_specs(env)
    collector = Collector(env, None, frames_per_batch=80, total_frames=240)  # a random policy
    frames, ended = 0, torch.zeros(4, dtype=torch.long)
    for data in collector:
        assert data.batch_size == torch.Size([4, 20]) and torch.isfinite(data["next", "observation"]).all()
        frames += data.numel()
        ended += data["next", "done"][..., 0].sum(-1)
    collector.shutdown()
    assert frames == 240 and (ended >= 3).all()  # 60 steps a world, episodes of at most 20
