"""PMCP's composer (`agents.Composer`): the multiplicative and additive compositions, one-hot
weights giving a primitive's action exactly, frozen primitives through PPO training, and one
self-contained checkpoint that reloads (agents.load, smpl-envs eval) to identical actions
without the primitives' files."""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch

import agents
import smpl_envs
from agents import PPO, ActorCritic, Composer, load_policy
from agents.checkpoint import load_checkpoint
from agents.cli import main
from agents.composer import compose_additive, compose_multiplicative
from agents.recipes import find_checkpoint

ID = "SMPL/Imitation-v0"
RESIDUAL_WALK = {"motions": "walk", "action_mode": "residual", "residual_scale": 0.25}
COMPAT = Path(__file__).parent / "data" / "compat"
SMALL = dict(n_steps=8, batch_size=16, n_epochs=2, seed=0, verbose=0, device="cpu", learning_rate=1e-3)


def gaussian(mu, std, obs_dim=3) -> ActorCritic:
    """A primitive whose action distribution is N(mu, std) whatever the observation."""
    p = ActorCritic(obs_dim, len(mu), actor_hidden=[4], critic_hidden=[4], normalize_obs=False,
                    log_std_init=0.0, learn_std=False)
    with torch.no_grad():
        p.actor[-1].weight.zero_()
        p.actor[-1].bias.copy_(torch.tensor(mu))
        p.log_std.copy_(torch.tensor(std).log())
    return p


def test_the_multiplicative_formula_on_two_known_gaussians():
    # C = (0.5, 1.5), sigma = (0.1, 0.3), mu = (0.2, -0.4) in dimension 0:
    # C_i / sigma_i = 5, 5 -> sigma = 1 / 10 = 0.1, mu = 0.1 (5 x 0.2 + 5 x -0.4) = -0.1.
    # Dimension 1: sigma = (0.2, 0.2), mu = (1, 0): C_i / sigma_i = 2.5, 7.5 -> sigma = 0.1, mu = 0.25.
    w = torch.tensor([[0.5, 1.5]])
    mus = torch.tensor([[[0.2, 1.0], [-0.4, 0.0]]], dtype=torch.float64)
    stds = torch.tensor([[[0.1, 0.2], [0.3, 0.2]]], dtype=torch.float64)
    mu, sigma = compose_multiplicative(w.double(), mus, stds)
    torch.testing.assert_close(mu, torch.tensor([[-0.1, 0.25]], dtype=torch.float64))
    torch.testing.assert_close(sigma, torch.tensor([[0.1, 0.1]], dtype=torch.float64))
    torch.testing.assert_close(compose_additive(w.double(), mus), torch.tensor([[0.5 * 0.2 - 1.5 * 0.4, 0.5]],
                                                                              dtype=torch.float64))
    # The same through a Composer over two constant primitives, its weights held at C.
    comp = Composer(3, 2, primitives=[gaussian([0.2, 1.0], [0.1, 0.2]), gaussian([-0.4, 0.0], [0.3, 0.2])],
                    actor_hidden=[4], critic_hidden=[4])
    comp.weights = lambda obs: w.expand(len(obs), -1)
    dist = comp.action_distribution(torch.zeros(5, 3))
    torch.testing.assert_close(dist.mean, torch.tensor([[-0.1, 0.25]]).expand(5, -1))
    torch.testing.assert_close(dist.stddev, torch.full((5, 2), 0.1))
    assert comp.env_action(dist.mean, torch.zeros(5, 3)).shape == (5, 2)


def test_weights_are_non_negative_and_start_as_an_even_mix():
    torch.manual_seed(0)
    obs = torch.randn(64, 3) * 10
    for activation in ("sigmoid", "relu", "softplus", "softmax"):
        comp = Composer(3, 2, primitives=[gaussian([0.0, 0.0], [0.1, 0.1])] * 2, actor_hidden=[8], critic_hidden=[4],
                        weight_activation=activation)
        w = comp.weights(obs)
        assert w.shape == (64, 2) and (w >= 0).all()
    sigmoid = Composer(3, 2, primitives=[gaussian([0.0, 0.0], [0.1, 0.1])] * 2, actor_hidden=[8], critic_hidden=[4])
    assert torch.allclose(sigmoid.weights(obs), torch.tensor(0.5), atol=0.05)  # small last layer


def test_softmax_weights_sum_to_one_and_keep_the_primitives_std():
    torch.manual_seed(0)
    obs = torch.randn(64, 3) * 10
    three = [gaussian([0.0, 1.0], [0.1, 0.1]), gaussian([0.5, 0.0], [0.1, 0.1]), gaussian([-1.0, 0.0], [0.1, 0.1])]
    comp = Composer(3, 2, primitives=three, actor_hidden=[8], critic_hidden=[4], weight_activation="softmax")
    w = comp.weights(obs)
    torch.testing.assert_close(w.sum(1), torch.ones(64))
    assert torch.allclose(w, torch.tensor(1 / 3), atol=0.05)  # small last layer: the even mix
    torch.testing.assert_close(comp.action_distribution(obs).stddev, torch.full((64, 2), 0.1))
    # A logit gap of 10 hands the state to one primitive, which a sigmoid's other weights would not.
    with torch.no_grad():
        comp.weight_net[-1].weight.zero_()
        comp.weight_net[-1].bias.copy_(torch.tensor([0.0, 0.0, 10.0]))
    torch.testing.assert_close(comp.action_distribution(obs).mean, torch.tensor([[-1.0, 0.0]]).expand(64, -1),
                               atol=1e-3, rtol=0)
    comp.weight_activation = "sigmoid"  # the same logits through sigmoids: 1/3 of the mean is the others'
    assert (comp.action_distribution(obs).mean[:, 0] > -0.9).all()


def primitives() -> list:
    # The shipped residual walk tracker and the tiny old-format one: two primitives for residual walk.
    return [load_policy(find_checkpoint("walk")), load_policy(COMPAT / "ppo_v1.pt")]


def observations(n: int = 6) -> np.ndarray:
    return np.load(COMPAT / "actions_v1.npz")["walk/obs"][:n]


@pytest.mark.parametrize("composition", ["multiplicative", "additive"])
def test_one_hot_weights_reproduce_that_primitive_exactly(composition):
    comp = Composer(934, 69, primitives=primitives(), composition=composition, actor_hidden=[16], critic_hidden=[16])
    obs = torch.as_tensor(observations())
    for k, p in enumerate(comp.primitives):
        one_hot = torch.nn.functional.one_hot(torch.tensor(k), 2).float()
        comp.weights = lambda o, w=one_hot: w.expand(len(o), -1)
        mine = comp.env_action(comp.act(obs), obs)
        theirs = p.env_action(p.act(obs), obs)
        assert torch.equal(mine, theirs), (composition, k)
        if composition == "multiplicative":  # and its spread
            torch.testing.assert_close(comp.action_distribution(obs).stddev, p.action_std().expand(6, -1))
    assert not torch.equal(comp.primitives[0].act(obs), comp.primitives[1].act(obs))  # they do differ


def test_bad_primitives_are_named():
    with pytest.raises(ValueError, match="non-empty list"):
        Composer(3, 2, primitives=[])
    with pytest.raises(ValueError, match=r"primitives\[1\] is for obs 4 / action 2 features"):
        Composer(3, 2, primitives=[gaussian([0.0, 0.0], [0.1, 0.1]), gaussian([0.0, 0.0], [0.1, 0.1], obs_dim=4)])
    with pytest.raises(TypeError, match=r"primitives\[0\] is str"):
        Composer(3, 2, primitives=["walk"])
    with pytest.raises(ValueError, match="composition must be one of"):
        Composer(3, 2, primitives=[gaussian([0.0, 0.0], [0.1, 0.1])], composition="max")


# ---------------------------------------------------------------------------------------- trained with PPO
@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """A composer over a copy of the tiny primitive (deleted once loaded) and the shipped walk,
    trained three PPO iterations on residual walk, saved."""
    tmp = tmp_path_factory.mktemp("composer")
    copy = shutil.copy(COMPAT / "ppo_v1.pt", tmp / "primitive.pt")
    prims = [load_policy(find_checkpoint("walk")), load_policy(copy)]
    Path(copy).unlink()  # the composer's checkpoint must not need it
    before = [{k: v.clone() for k, v in p.state_dict().items()} for p in prims]
    model = PPO(ID, n_envs=2, env_kwargs=RESIDUAL_WALK, policy="Composer",
                policy_kwargs={"primitives": prims, "actor_hidden": [16], "critic_hidden": [16]}, **SMALL)
    weights = model.policy.weight_net[0].weight.detach().clone()
    model.learn(48, progress_bar=False)
    path = model.save(tmp / "composer.pt")
    yield path, model, before, weights
    model.close()


def test_primitives_stay_frozen_through_training(trained):
    _, model, before, weights = trained
    pol = model.policy
    optimised = {id(p) for g in model.optimizer.param_groups for p in g["params"]}
    for p, state in zip(pol.primitives, before):
        assert all(not q.requires_grad and id(q) not in optimised for q in p.parameters())
        for name, value in p.state_dict().items():  # weights and normaliser statistics alike
            assert torch.equal(value, state[name]), name
    assert not torch.equal(pol.weight_net[0].weight, weights)  # the composer did learn
    assert model.rollout_buffer.actions.shape == (8, 2, 69)   # PPO acts with the composite


def test_the_checkpoint_is_self_contained_and_reloads_to_identical_actions(trained, tmp_path):
    path, model, _, _ = trained
    ckpt = load_checkpoint(path)
    assert ckpt["policy_class"] == "Composer"
    assert [p["__policy__"]["class"] for p in ckpt["policy_kwargs"]["primitives"]] == ["ActorCritic"] * 2
    loaded = agents.load(path, device="cpu")
    assert type(loaded.policy) is Composer and all(p.frozen for p in loaded.policy.primitives)
    obs = observations()
    np.testing.assert_array_equal(loaded.predict(obs)[0], model.predict(obs)[0])
    for a, b in zip(loaded.policy.state_dict().values(), model.policy.state_dict().values()):
        assert torch.equal(a, b)


@pytest.mark.slow
def test_the_checkpoint_evaluates_records_and_resumes(trained, tmp_path):
    path, model, _, _ = trained
    # smpl-envs eval of the file: the same clip results as the trained agent in this process.
    out = tmp_path / "eval.json"
    assert main(["eval", str(path), "--num-envs", "1", "--no-progress", "--out", str(out)]) == 0
    in_process = smpl_envs.evaluate(model, ID, num_envs=1, progress=False)
    assert json.loads(out.read_text())["clips"] == json.loads(in_process.to_json())["clips"]
    assert main(["record", str(path), "--steps", "2", "--no-progress", "--out", str(tmp_path / "c.mp4")]) == 0
    # It resumes: PPO continues with the composite, the primitives still frozen.
    resumed = agents.load(path, env="auto", verbose=0)
    resumed.learn(16, reset_num_timesteps=False, progress_bar=False)
    assert resumed.num_timesteps == 64 and all(p.frozen for p in resumed.policy.primitives)
    resumed.close()
