"""Progressive-network columns (`agents.ProgressiveActorCritic`, the pipeline's
`primitive.lateral`): a new column acts exactly as the frozen column before it at step 0, down a
chain too; its layers follow the lateral formula; PPO trains the column and leaves the previous
one's weights and statistics alone; its checkpoint reloads to identical actions without the
previous column's file; mismatches are refused by name; the pipeline builds it."""
from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

import agents
from agents import PPO, ActorCritic, ProgressiveActorCritic, load_policy
from agents.checkpoint import load_checkpoint
from agents.pmcp import Pipeline, check_pipeline, load_pipeline
from agents.recipes import RecipeError, find_checkpoint
from agents.run import new_agent

ID = "SMPL/Imitation-v0"
COMPAT = Path(__file__).parent / "data" / "compat"
RESIDUAL_WALK = {"motions": "walk", "action_mode": "residual", "residual_scale": 0.25, "substeps": 4}


def column(obs_dim=10, act_dim=4, hidden=(8, 6), seed=0) -> ActorCritic:
    torch.manual_seed(seed)
    p = ActorCritic(obs_dim, act_dim, actor_hidden=list(hidden), critic_hidden=[5], log_std_init=-2.0)
    p.obs_norm.update(torch.randn(200, obs_dim) * 3 + 1)
    with torch.no_grad():  # a previous column whose output is far from zero, as a trained one's is
        p.actor[-1].weight.normal_()
    return p.freeze()


def test_a_new_column_starts_as_the_one_before_it_down_a_chain():
    prev = column()
    obs = torch.randn(32, 10) * 2
    first = ProgressiveActorCritic(10, 4, previous=prev)
    torch.testing.assert_close(first.act(obs), prev.act(obs), rtol=0, atol=0)
    assert prev.act(obs).abs().max() > 0.5  # a meaningful comparison
    torch.testing.assert_close(first.action_std(), prev.action_std())
    torch.testing.assert_close(first.value(first.normalize(obs)), prev.value(prev.normalize(obs)))  # critic copied
    with torch.no_grad():  # once the first column has learnt something, the second starts as it
        for p in first.parameters():
            if p.requires_grad:
                p.normal_(0, 0.1)
    second = ProgressiveActorCritic(10, 4, previous=first.freeze(), actor_hidden=[3, 3])
    assert not torch.allclose(first.act(obs), prev.act(obs))
    torch.testing.assert_close(second.act(obs), first.act(obs), rtol=0, atol=0)
    assert second.columns == 3 and first.columns == 2


def test_the_lateral_formula_by_hand():
    prev = column()
    col = ProgressiveActorCritic(10, 4, previous=prev)
    torch.manual_seed(1)
    with torch.no_grad():
        for p in col.parameters():
            if p.requires_grad:
                p.normal_(0, 0.3)
    x = prev.normalize(torch.randn(5, 10))
    silu = torch.nn.functional.silu
    # The previous column, frozen: h'_1, h'_2, mu'.
    h1p = silu(prev.actor[0](x))
    h2p = silu(prev.actor[2](h1p))
    mup = prev.actor[4](h2p)
    # The new one: h_1 = act(W_1 x), h_2 = act(W_2 h_1 + U_2 h'_1), mu = mu' + W_out h_2 + U_out h'_2.
    h1 = silu(col.actor[0](x))
    h2 = silu(col.actor[2](h1) + col.lateral[0](h1p))
    mu = mup + col.actor[4](h2) + col.lateral[1](h2p)
    torch.testing.assert_close(col.action_distribution(x).mean, mu)
    assert col.normalize is not None and torch.equal(col.normalize(torch.ones(1, 10)), prev.normalize(torch.ones(1, 10)))


def test_mismatches_are_refused_by_name():
    prev = column()
    with pytest.raises(ValueError, match=r"actor_hidden \[8\] has 1 hidden layers, the previous column \[8, 6\] has 2"):
        ProgressiveActorCritic(10, 4, previous=prev, actor_hidden=[8])
    with pytest.raises(ValueError, match="previous is for obs 10 / action 4 features, this column's env has 12 / 4"):
        ProgressiveActorCritic(12, 4, previous=prev)
    with pytest.raises(TypeError, match="previous must be an actor-critic"):
        ProgressiveActorCritic(10, 4, previous="tracker")


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """A column beside a copy of the tiny residual-walk primitive (deleted once loaded), trained
    three PPO iterations, saved."""
    tmp = tmp_path_factory.mktemp("progressive")
    copy = shutil.copy(COMPAT / "ppo_v1.pt", tmp / "previous.pt")
    prev = load_policy(copy)
    Path(copy).unlink()  # the column's checkpoint must not need it
    before = {k: v.clone() for k, v in prev.state_dict().items()}
    model = PPO(ID, n_envs=2, env_kwargs=RESIDUAL_WALK, policy="ProgressiveActorCritic",
                policy_kwargs={"previous": prev}, n_steps=8, batch_size=16, n_epochs=2, seed=0, verbose=0,
                device="cpu", learning_rate=1e-3)
    adapter = model.policy.lateral[-1].weight.detach().clone()
    model.learn(48, progress_bar=False)
    path = model.save(tmp / "column.pt")
    yield path, model, before, adapter
    model.close()


def test_ppo_trains_the_column_and_leaves_the_previous_one_alone(trained):
    _, model, before, adapter = trained
    pol = model.policy
    optimised = {id(p) for g in model.optimizer.param_groups for p in g["params"]}
    assert all(not p.requires_grad and id(p) not in optimised for p in pol.previous.parameters())
    for name, value in pol.previous.state_dict().items():  # weights and observation statistics alike
        assert torch.equal(value, before[name]), name
    assert not torch.equal(pol.lateral[-1].weight, adapter)  # the column learnt
    assert {id(p) for p in pol.lateral.parameters()} <= optimised


def test_the_checkpoint_holds_both_columns_and_reloads_to_identical_actions(trained):
    path, model, _, _ = trained
    ckpt = load_checkpoint(path)
    assert ckpt["policy_class"] == "ProgressiveActorCritic"
    assert ckpt["policy_kwargs"]["previous"]["__policy__"]["class"] == "ActorCritic"
    loaded = agents.load(path, device="cpu", verbose=0)
    assert type(loaded.policy) is ProgressiveActorCritic and loaded.policy.previous.frozen
    obs = np.load(COMPAT / "actions_v1.npz")["walk/obs"][:6]
    np.testing.assert_array_equal(loaded.predict(obs)[0], model.predict(obs)[0])
    # A composer takes a column as a primitive: its Gaussian is the column's.
    comp = agents.Composer(934, 69, primitives=[loaded.policy], actor_hidden=[8], critic_hidden=[8])
    t = torch.as_tensor(obs)
    torch.testing.assert_close(comp.action_distribution(t).mean, loaded.policy.act(t))


def test_a_recipe_names_the_previous_column_as_a_checkpoint(trained):
    path, _, _, _ = trained
    from agents.recipes import load_recipe

    recipe = load_recipe("walk_residual_ppo", [
        "env.num_envs=1", "env.kwargs.substeps=4",
        f"agent.policy={{class: ProgressiveActorCritic, kwargs: {{previous: {{checkpoint: {path}}}}}}}"])
    agent = new_agent(recipe, device="cpu", verbose=0, tensorboard=False)
    try:
        assert isinstance(agent.policy.previous, ProgressiveActorCritic) and agent.policy.columns == 3
    finally:
        agent.close()


# ---------------------------------------------------------------------------------------- the pipeline
def test_the_pipeline_builds_columns_when_asked(tmp_path):
    spec = {"motions": ["walk", "jump"], "primitive0": "walk", "max_primitives": 1,
            "primitive": {"recipe": "walk_residual_ppo", "set": [], "lateral": True},
            "recovery": None, "composer": {"recipe": "composer_ppo", "set": []}, "perpetual": None}
    pipeline = Pipeline(check_pipeline(spec) | {"name": "lateral"}, tmp_path / "run")
    walk = str(find_checkpoint("walk").resolve())
    recipe = pipeline._primitive_recipe({"name": "primitive0", "checkpoint": walk, "hard": ["jump"]})
    assert recipe["agent"]["policy"] == {"class": "ProgressiveActorCritic", "kwargs": {"previous": {"checkpoint": walk}}}
    assert recipe["agent"]["init"] is None and recipe["env"]["kwargs"]["motion_weights"] == {"jump": 1.0}
    # Copying stays the default; a column beside a primitive of other action settings is refused.
    assert load_pipeline("pmcp_corpus")["primitive"]["lateral"] is False
    spec["primitive"]["set"] = ["env.kwargs.residual_scale=0.5"]
    pipeline = Pipeline(check_pipeline(spec) | {"name": "lateral"}, tmp_path / "run2")
    with pytest.raises(RecipeError, match="residual_scale=0.25, primitive.recipe has residual_scale=0.5"):
        pipeline._primitive_recipe({"name": "primitive0", "checkpoint": walk, "hard": ["jump"]})
    with pytest.raises(RecipeError, match="primitive.lateral must be true or false"):
        check_pipeline({**spec, "primitive": {"recipe": "walk_residual_ppo", "set": [], "lateral": "yes"}})
