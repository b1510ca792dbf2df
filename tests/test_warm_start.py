"""Warm starts (`smpl-envs train --init CHECKPOINT`, `agent.init`): the new run's policy holds the
checkpoint's weights and normalisers with a fresh optimiser and step count; a network, a policy
class or a policy setting that does not fit is refused by name."""
from __future__ import annotations

from pathlib import Path

import pytest
import torch
import yaml

import agents
from agents.checkpoint import load_checkpoint
from agents.cli import main
from agents.recipes import RecipeError, load_recipe
from agents.run import new_agent

COMPAT = Path(__file__).parent / "data" / "compat"
SOURCE = COMPAT / "ppo_v1.pt"  # a tiny PPO (actor and critic [16]) on residual walk
TINY = ["env.num_envs=2", "agent.hyperparams.n_steps=8", "agent.hyperparams.batch_size=16",
        "agent.hyperparams.n_epochs=1", "agent.policy.kwargs.actor_hidden=[16]",
        "agent.policy.kwargs.critic_hidden=[16]", "agent.policy.kwargs.log_std_init=-1.0",
        "agent.policy.kwargs.learn_std=true", "agent.policy.kwargs.obs_clip=10", "env.kwargs.motions=walk",
        "video.steps=0", "eval.num_envs=1", "train.total_timesteps=16", "train.checkpoint_every=0",
        "eval.every=0"]


def recipe(*extra):
    return load_recipe("walk_residual_ppo", [*TINY, *extra])


def test_init_copies_every_weight_and_normaliser_with_a_fresh_optimiser():
    agent = new_agent(recipe(f"agent.init={SOURCE}"), verbose=0, device="cpu")
    source = load_checkpoint(SOURCE)["policy"]
    state = agent.policy.state_dict()
    assert set(state) == set(source)
    for name, value in source.items():
        torch.testing.assert_close(state[name], value, rtol=0, atol=0, msg=name)
    assert source["obs_norm.count"] > 1 and not agent.optimizer.state and agent.num_timesteps == 0
    fresh = new_agent(recipe(), verbose=0, device="cpu")  # without init: other weights
    assert not torch.equal(fresh.policy.state_dict()["actor.0.weight"], source["actor.0.weight"])
    for a in (agent, fresh):
        a.close()


def test_exclude_leaves_the_named_parts_as_made():
    agent = new_agent(recipe(f"agent.init={{checkpoint: {SOURCE}, exclude: [critic., value_norm]}}"),
                      verbose=0, device="cpu")
    source, state = load_checkpoint(SOURCE)["policy"], agent.policy.state_dict()
    assert torch.equal(state["actor.0.weight"], source["actor.0.weight"])
    assert not torch.equal(state["critic.0.weight"], source["critic.0.weight"])
    assert state["value_norm.count"] != source["value_norm.count"]
    agent.close()


def test_train_init_from_the_command_line(tmp_path):
    """--init on `smpl-envs train`: the run starts from the checkpoint (a zero learning rate keeps
    its actor exactly), records agent.init, and its own step count starts at 0."""
    run = tmp_path / "run"
    args = ["train", "walk_residual_ppo", "--run-dir", str(run), "--init", str(SOURCE), "--no-progress", "--quiet",
            "--threads", "1", "--set", "agent.hyperparams.learning_rate=0"]
    assert main([*args, *[x for t in TINY for x in ("--set", t)]]) == 0
    config = yaml.safe_load((run / "config.yaml").read_text())
    assert config["agent"]["init"] == str(SOURCE)
    trained = load_checkpoint(run / "checkpoints" / "last.pt")
    assert trained["num_timesteps"] == 16 and trained["iteration"] == 1  # its own count, not the source's
    torch.testing.assert_close(trained["policy"]["actor.0.weight"], load_checkpoint(SOURCE)["policy"]["actor.0.weight"],
                               rtol=0, atol=0)
    with pytest.raises(SystemExit):
        main(["train", "--resume", str(run), "--init", str(SOURCE)])


@pytest.mark.parametrize("override, message", [
    ("agent.policy.kwargs.actor_hidden=[32]",
     r"parameter actor.0.weight is \(16, 934\) in the checkpoint, \(32, 934\) in this run's policy"),
    ("agent.policy.kwargs.actor_hidden=[16, 16]",
     r"the networks differ: this run's policy has actor.4.weight, actor.4.bias, the checkpoint does not"),
    ("agent.policy.kwargs.normalize_obs=false", r"the checkpoint has obs_norm.mean, obs_norm.var, obs_norm.count"),
    ("env.kwargs.residual_scale=0.5", r"trained with residual_scale=0.25, this run's env has residual_scale=0.5"),
    ("env.kwargs.action_mode=absolute", r"trained with action_mode='residual'"),
])
def test_init_refuses_what_does_not_fit_by_name(override, message):
    with pytest.raises((ValueError, RecipeError), match=message):
        new_agent(recipe(f"agent.init={SOURCE}", override), verbose=0, device="cpu")


def test_init_refuses_another_policy_class_and_a_missing_checkpoint(capsys):
    plugin = ["agent.policy.class=plugin_policies:PrimitiveMixer",
              "agent.policy.kwargs={primitives: [{checkpoint: " + str(SOURCE) + "}], hidden: [8]}"]
    with pytest.raises(ValueError, match=r"holds a ActorCritic policy, this run makes a plugin_policies:PrimitiveMixer"):
        new_agent(load_recipe("walk_residual_ppo", [*TINY[:4], *TINY[9:], f"agent.init={SOURCE}", *plugin]),
                  verbose=0, device="cpu")
    with pytest.raises(RecipeError, match="agent.init: no checkpoint or run directory at no_such_run"):
        new_agent(recipe("agent.init=no_such_run"), verbose=0, device="cpu")  # (the recipe itself loads)
    with pytest.raises(RecipeError, match="agent.init must be a checkpoint"):
        recipe("agent.init={path: x}")
    with pytest.raises(SystemExit) as exc:
        main(["train", "walk_residual_ppo", "--init", "no_such_run", "--no-progress"])
    assert exc.value.code == 2 and "agent.init: no checkpoint" in capsys.readouterr().err


def test_a_shipped_name_initialises_a_recovery_run():
    """`clips` (residual 0.25, a tracker of the shipped clips) starts a Recovery-v0 run: the task
    differs, the settings both tasks have agree."""
    r = load_recipe("recovery_tracker_ppo", ["agent.init=clips", "env.num_envs=1",
                                             "env.kwargs.fallen_cache_size=8"])
    agent = new_agent(r, verbose=0, device="cpu")
    torch.testing.assert_close(agent.policy.state_dict()["actor.0.weight"],
                               agents.load_policy(agents.recipes.find_checkpoint("clips")).state_dict()["actor.0.weight"])
    agent.close()


def test_critic_warmup_trains_only_the_critic_until_its_step_count():
    agent = new_agent(recipe(f"agent.init={SOURCE}", "agent.hyperparams.critic_warmup=16"), verbose=0, device="cpu")
    before = {k: v.clone() for k, v in agent.policy.state_dict().items()}
    agent.learn(16, progress_bar=False)  # one rollout of 2 worlds x 8 steps: inside the warm-up
    after = agent.policy.state_dict()
    assert all(torch.equal(after[k], v) for k, v in before.items() if k.startswith(("actor.", "log_std")))
    assert any(not torch.equal(after[k], v) for k, v in before.items() if k.startswith("critic."))
    agent.learn(16, progress_bar=False, reset_num_timesteps=False)  # past it: the policy learns too
    assert any(not torch.equal(agent.policy.state_dict()[k], v) for k, v in before.items() if k.startswith("actor."))


def test_a_recovery_fine_tune_may_change_its_guides_not_what_its_goal_means(tmp_path):
    """The guides (`goal_settings`) only choose which clips the goal shows: a warm start may move
    to others, as to other motions; switch_distance changes what the observation means."""
    small = ["env.num_envs=1", "env.kwargs.fallen_cache_size=8", "agent.policy.kwargs.actor_hidden=[16]",
             "agent.policy.kwargs.critic_hidden=[16]", "env.kwargs.motions=stand",
             "env.kwargs.getup_guide=null", "env.kwargs.guide_basin=0"]  # no corpus to build
    source = new_agent(load_recipe("recovery_quick_ppo", small), verbose=0, device="cpu")
    source.save(tmp_path / "quick.pt")
    source.close()
    init = [*small, f"agent.init={tmp_path / 'quick.pt'}"]
    agent = new_agent(load_recipe("recovery_brisk_ppo", init), verbose=0, device="cpu")
    assert agent.env_kwargs["walk_guide"] == "brisk"
    agent.close()
    with pytest.raises(ValueError, match=r"trained with switch_distance=0.5, this run's env has switch_distance=0.8"):
        new_agent(load_recipe("recovery_brisk_ppo", [*init, "env.kwargs.switch_distance=0.8"]), verbose=0, device="cpu")
