"""Policies as plug-ins: a checkpoint records its policy's class and arguments and every loader
(agents.load, smpl-envs eval / record / train --resume) makes it again; a policy owns its action
size and its map to the env's actions; recipes name the policy and may hand it other
checkpoints; old checkpoints load to the very same actions and resume; a second algorithm on
the on-policy base."""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch
import yaml

import agents
import smpl_envs
from agents import PPO, ActorCritic, PolicyClassError, load_policy
from agents.checkpoint import load_checkpoint, save_checkpoint
from agents.cli import main
from agents.recipes import RecipeError, find_checkpoint, load_recipe
from plugin_policies import Distill, PrimitiveMixer

ID = "SMPL/Imitation-v0"
RESIDUAL_WALK = {"motions": "walk", "action_mode": "residual", "residual_scale": 0.25}
COMPAT = Path(__file__).parent / "data" / "compat"
SMALL = dict(n_steps=8, batch_size=16, n_epochs=1, seed=0, verbose=0, device="cpu")
CLI_SMALL = ["--set", "env.num_envs=2", "--set", "agent.hyperparams.n_steps=8", "--set",
             "agent.hyperparams.batch_size=16", "--set", "video.steps=0", "--no-progress", "--quiet", "--threads", "1"]


def observations(n: int = 6) -> np.ndarray:
    """Observations of SMPL/Imitation-v0 (real ones first, then far outside the data)."""
    return np.load(COMPAT / "actions_v1.npz")["walk/obs"][:n]


def primitives() -> list:
    # The shipped walk policy and the old-format tiny one: both residual walk trackers.
    return [load_policy(find_checkpoint("walk")), load_policy(COMPAT / "ppo_v1.pt")]


# ---------------------------------------------------------------------------------------- a plug-in
@pytest.fixture(scope="module")
def mixer_path(tmp_path_factory):
    """A PrimitiveMixer PPO trained two iterations on walk, saved (with the model, for comparing)."""
    model = PPO(ID, n_envs=2, env_kwargs=RESIDUAL_WALK, policy=PrimitiveMixer,
                policy_kwargs={"primitives": primitives(), "hidden": [16]}, **SMALL)
    calls = []
    env_action = model.policy.env_action
    model.policy.env_action = lambda a, obs: (calls.append(len(a)), env_action(a, obs))[1]
    prim = model.policy.primitives[0].actor[0].weight.detach().clone()
    actor = model.policy.actor[0].weight.detach().clone()
    model.learn(32, progress_bar=False)
    del model.policy.env_action
    # The rollout keeps the policy's own actions (2 weights), the env got 69 numbers per world,
    # through one call of the policy's map per step.
    assert model.rollout_buffer.actions.shape == (8, 2, 2) and calls == [2] * 16
    assert torch.equal(model.policy.primitives[0].actor[0].weight, prim)  # frozen
    assert not torch.equal(model.policy.actor[0].weight, actor)           # trained
    path = model.save(tmp_path_factory.mktemp("mixer") / "mixer.pt")
    yield path, model
    model.close()


def test_the_map_sees_the_observation_and_the_action_size_is_the_policy_s(mixer_path):
    _, model = mixer_path
    obs = torch.as_tensor(observations(2))
    weights = torch.tensor([[3.0, -3.0], [3.0, -3.0]])
    env_action = model.policy.env_action(weights, obs)
    assert env_action.shape == (2, 69) and not torch.equal(env_action[0], env_action[1])  # depends on obs
    assert not torch.equal(env_action, model.policy.env_action(-weights, obs))             # and on the action
    assert model.policy.act_dim == 2 and model.act_dim == 69


def test_a_plugin_checkpoint_loads_to_identical_actions(mixer_path):
    path, model = mixer_path
    ckpt = load_checkpoint(path)
    assert ckpt["policy_class"] == "plugin_policies:PrimitiveMixer" and ckpt["policy_kwargs"]["hidden"] == [16]
    walk = ckpt["policy_kwargs"]["primitives"][0]["__policy__"]
    assert walk["class"] == "ActorCritic" and walk["frozen"] and walk["kwargs"]["actor_hidden"] == [512, 256]
    loaded = agents.load(path, device="cpu")
    assert type(loaded.policy) is PrimitiveMixer and loaded.policy.primitives[1].frozen
    obs = observations()
    np.testing.assert_array_equal(loaded.predict(obs)[0], model.predict(obs)[0])
    # Every weight came from the checkpoint, the primitives' included (not from their files).
    for a, b in zip(loaded.policy.state_dict().values(), model.policy.state_dict().values()):
        torch.testing.assert_close(a, b, rtol=0, atol=0)


def test_a_plugin_checkpoint_evaluates_and_resumes(mixer_path, tmp_path):
    path, model = mixer_path
    out = tmp_path / "eval.json"
    assert main(["eval", str(path), "--num-envs", "1", "--no-progress", "--out", str(out)]) == 0
    in_process = smpl_envs.evaluate(model, ID, num_envs=1, progress=False)
    assert json.loads(out.read_text())["clips"] == json.loads(in_process.to_json())["clips"]  # the same actions

    resumed = agents.load(path, env="auto", verbose=0)
    assert resumed.env.action_mode == "residual" and resumed.optimizer.state  # its Adam moments came back
    resumed.learn(16, reset_num_timesteps=False, progress_bar=False)
    assert resumed.num_timesteps == 48 and resumed.rollout_buffer.actions.shape[-1] == 2
    resumed.close()


def test_a_recipe_names_the_policy_and_other_checkpoints(tmp_path, capsys):
    recipe = {
        "env": {"id": ID, "num_envs": 2, "kwargs": RESIDUAL_WALK},
        "agent": {"class": "PPO", "hyperparams": {"n_steps": 8, "batch_size": 16, "n_epochs": 1},
                  "policy": {"class": "plugin_policies:PrimitiveMixer",
                             "kwargs": {"primitives": [{"checkpoint": "walk"}, {"checkpoint": str(COMPAT / "ppo_v1.pt")}],
                                        "hidden": [16]}}},
        "train": {"total_timesteps": 32},
        "eval": {"num_envs": 1},
        "video": {"steps": 0},
    }
    (tmp_path / "mixer.yaml").write_text(yaml.safe_dump(recipe))
    run = tmp_path / "run"
    assert main(["train", str(tmp_path / "mixer.yaml"), "--run-dir", str(run), *CLI_SMALL]) == 0
    assert read_policy(run) == recipe["agent"]["policy"]  # the resolved recipe keeps the references
    trained = agents.load(run / "checkpoints" / "last.pt")
    assert type(trained.policy) is PrimitiveMixer and trained.num_timesteps == 32
    assert main(["eval", str(run), "--no-progress"]) == 0 and (run / "eval.json").is_file()
    assert main(["record", str(run), "--steps", "2", "--no-progress"]) == 0
    assert main(["train", "--resume", str(run), "--set", "train.total_timesteps=48", *CLI_SMALL]) == 0
    assert agents.load(run / "checkpoints" / "last.pt").num_timesteps == 48
    with pytest.raises(SystemExit):  # the policy is the checkpoint's
        main(["train", "--resume", str(run), "--set", "agent.policy.kwargs.hidden=[32]", *CLI_SMALL])
    assert "keeps the env id, agent class and" in capsys.readouterr().err


def read_policy(run: Path) -> dict:
    return yaml.safe_load((run / "config.yaml").read_text())["agent"]["policy"]


def test_recipe_policy_mistakes_are_named(tmp_path):
    for overrides, match in [
        (["agent.policy.class=NoSuchPolicy"], r"agent.policy.class: unknown policy class 'NoSuchPolicy'"),
        (["agent.policy.class=no_such_package.nets:Policy"], r"cannot be imported \(ModuleNotFoundError"),
        (["agent.policy.class=collections:OrderedDict"], "not a Policy subclass"),
        (["agent.policy.kwargs.actor_hiden=[8]"], r"unknown ActorCritic argument\(s\) \['agent.policy.kwargs.actor_hiden'\]"),
        (["agent.policy.class=plugin_policies:PrimitiveMixer",
          "agent.policy.kwargs={primitives: [{checkpoint: walk}, {checkpoint: no_such_policy}]}"],
         r"agent.policy.kwargs.primitives\[1\]: no checkpoint or run directory at no_such_policy; shipped policies"),
        (["agent.policy.class=plugin_policies:PrimitiveMixer", "agent.hyperparams.actor_hidden=[8]"],
         "agent.hyperparams.actor_hidden: arguments of ActorCritic"),
        (["agent.policy.colour=red"], "agent.policy has class and kwargs"),
    ]:
        with pytest.raises(RecipeError, match=match):
            load_recipe("imitation_ppo", overrides)


# ---------------------------------------------------------------------------------------- a missing class
@pytest.fixture
def orphan(tmp_path):
    """A checkpoint whose policy class cannot be imported (its package is not installed)."""
    ckpt = load_checkpoint(COMPAT / "ppo_v1.pt")
    payload = {k: v for k, v in ckpt.items() if k not in ("format", "versions")}
    payload.update(policy_class="no_such_package.policies:Composer", policy_kwargs={})
    return save_checkpoint(payload, tmp_path / "orphan.pt")


def test_a_checkpoint_naming_a_missing_class_is_a_clear_error(orphan, capsys):
    message = r"orphan\.pt: policy class 'no_such_package.policies:Composer' cannot be imported \(ModuleNotFound"
    with pytest.raises(PolicyClassError, match=message):
        agents.load(orphan)
    with pytest.raises(PolicyClassError, match=message):
        load_policy(orphan)
    for command in ("eval", "record"):
        with pytest.raises(SystemExit) as exc:
            main([command, str(orphan), "--no-progress"])
        err = capsys.readouterr().err
        assert exc.value.code == 2 and err.startswith("error: ") and err.count("\n") == 1
        assert "no_such_package.policies:Composer" in err and "install or import the package" in err


# ---------------------------------------------------------------------------------------- old checkpoints
@pytest.mark.parametrize("name", ["walk", "clips", "ppo_v1", "amp_v1", "pendulum_v1"])
def test_old_checkpoints_act_as_before(name):
    """Actions the code before plug-ins gave (tests/make_compat_data.py) on fixed observations,
    from checkpoints without a policy class: the shipped policies, tiny PPO / AMP agents and a
    Pendulum agent whose [-2, 2] box the policy's map now rescales onto."""
    stored = np.load(COMPAT / "actions_v1.npz")
    path = find_checkpoint(name) if name in ("walk", "clips") else COMPAT / f"{name}.pt"
    assert "policy_class" not in load_checkpoint(path)
    agent = agents.load(path, device="cpu")
    assert type(agent.policy) is ActorCritic
    # Equal up to float32 rounding: the stored actions came from another CPU, whose matmul
    # kernels sum in another order (~3e-7 apart); a changed network or map moves them far more.
    np.testing.assert_allclose(agent.predict(stored[f"{name}/obs"])[0], stored[f"{name}/actions"], rtol=0, atol=1e-5)


@pytest.mark.parametrize("name", ["ppo_v1", "amp_v1"])
def test_old_checkpoints_resume_and_save_in_the_new_format(name, tmp_path):
    old = load_checkpoint(COMPAT / f"{name}.pt")
    agent = agents.load(COMPAT / f"{name}.pt", env="auto", verbose=0)
    assert agent.policy_kwargs["actor_hidden"] == [16] and "actor_hidden" not in agent.hyperparams
    assert agent.optimizer.state_dict()["state"][0]["step"] == old["optimizer"]["state"][0]["step"]
    agent.learn(16, reset_num_timesteps=False, progress_bar=False)
    assert agent.num_timesteps == old["num_timesteps"] + 16
    new = load_checkpoint(agent.save(tmp_path / "new.pt"))
    assert new["policy_class"] == "ActorCritic" and new["policy_kwargs"]["actor_hidden"] == [16]
    assert new["policy_kwargs"]["obs_clip"] == old["hyperparams"]["obs_clip"]
    agent.close()


OLD_CONFIG = """\
recipe_name: walk_residual_ppo
recipe_path: /somewhere/tasks/walk_residual_ppo.yaml
profile: null
overrides: []
env:
  id: SMPL/Imitation-v0
  num_envs: 2
  kwargs: {motions: walk, action_mode: residual, residual_scale: 0.25}
agent:
  class: PPO
  hyperparams: {n_steps: 8, batch_size: 16, n_epochs: 1, actor_hidden: [16], critic_hidden: [16]}
train: {total_timesteps: 32, max_minutes: null, seed: 0, checkpoint_every: 0, log_interval: 1, device: auto}
eval: {every: 0, num_envs: 1, motions: null, options: {threshold: 0.5}}
video: {steps: 0, fps: null, motions: null}
"""


def test_a_run_of_the_old_format_resumes_from_the_command_line(tmp_path, capsys):
    """A run directory as the code before plug-ins wrote it (network sizes among the
    hyperparameters of its config.yaml, a checkpoint without a policy class) continues."""
    run = tmp_path / "old_run"
    (run / "checkpoints").mkdir(parents=True)
    (run / "config.yaml").write_text(OLD_CONFIG)
    shutil.copy(COMPAT / "ppo_v1.pt", run / "checkpoints" / "last.pt")
    assert main(["train", "--resume", str(run), "--set", "train.total_timesteps=48",
                 "--set", "agent.hyperparams.actor_hidden=[16]", "--no-progress", "--quiet", "--threads", "1"]) == 0
    agent = agents.load(run / "checkpoints" / "last.pt")
    assert agent.num_timesteps == 48 and agent.policy_kwargs["actor_hidden"] == [16]
    assert read_policy(run) == {"class": "ActorCritic", "kwargs": {"actor_hidden": [16], "critic_hidden": [16]}}
    with pytest.raises(SystemExit):  # the old spelling of a network change is refused as the new one is
        main(["train", "--resume", str(run), "--set", "agent.hyperparams.actor_hidden=[32]", "--no-progress"])
    assert "network sizes" in capsys.readouterr().err


def test_former_hyperparameters_still_make_the_actor_critic():
    with pytest.warns(DeprecationWarning, match="policy_kwargs"):
        old = PPO("Pendulum-v1", actor_hidden=[8], log_std_init=0.5, verbose=0, seed=0)
    new = PPO("Pendulum-v1", policy_kwargs={"actor_hidden": [8], "log_std_init": 0.5}, verbose=0, seed=0)
    assert old.policy_kwargs == new.policy_kwargs and old.hyperparams == new.hyperparams
    with pytest.raises(TypeError, match="both as hyperparameters and in policy_kwargs"):
        PPO("Pendulum-v1", actor_hidden=[8], policy_kwargs={"actor_hidden": [8]}, verbose=0)
    with pytest.raises(TypeError, match="ActorCritic's arguments, not PrimitiveMixer's"):
        PPO("Pendulum-v1", policy=PrimitiveMixer, actor_hidden=[8], verbose=0)
    with pytest.raises(ValueError, match="fixes"):
        PPO.load(COMPAT / "pendulum_v1.pt", actor_hidden=[32])


# ---------------------------------------------------------------------------------------- a second algorithm
def test_a_distillation_agent_on_the_on_policy_base(tmp_path):
    box = gym.spaces.Box(-2.0, 2.0, (1,))
    torch.manual_seed(1)
    teacher = ActorCritic(3, box, actor_hidden=[16], critic_hidden=[16], normalize_obs=False)
    teacher.actor[-1].weight.data.mul_(100.0)  # a teacher with a mind of its own
    student = Distill("Pendulum-v1", teacher=teacher, n_envs=4, n_steps=32, batch_size=64, n_epochs=4,
                      learning_rate=3e-3, policy_kwargs={"actor_hidden": [64], "critic_hidden": [8]}, seed=0,
                      verbose=0)
    rng = np.random.default_rng(0)
    angle, speed = rng.uniform(-np.pi, np.pi, 256), rng.uniform(-3.0, 3.0, 256)  # Pendulum: cos, sin, velocity
    obs = torch.as_tensor(np.stack([np.cos(angle), np.sin(angle), speed], -1), dtype=torch.float32)

    def gap() -> float:
        return float((student.policy.act(obs) - teacher.act(obs)).square().mean())

    before = gap()
    student.learn(4 * 32 * 50, progress_bar=False)
    assert gap() < 0.1 * before, (before, gap())  # measured: 0.127 -> 0.006
    assert student.logger.last["train/bc_loss"] < 0.01 * before  # on its own states, which it visits
    # The base's checkpoints work for it as they do for PPO.
    path = student.save(tmp_path / "student.pt")
    again = Distill.load(path, teacher=teacher, verbose=0)
    np.testing.assert_array_equal(again.predict(obs.numpy())[0], student.predict(obs.numpy())[0])
    student.close()
