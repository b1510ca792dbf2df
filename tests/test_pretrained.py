"""Shipped policies: saved without the optimiser, found by name, loadable anywhere."""
import numpy as np
import pytest

import agents
from agents import PPO
from agents import recipes
from agents.recipes import RecipeError, find_checkpoint


def test_policy_saved_without_optimizer_is_smaller_and_acts_the_same(tmp_path):
    model = PPO("SMPL/Imitation-v0", n_envs=2, env_kwargs={"motions": "walk"}, n_steps=8, batch_size=16,
                actor_hidden=[64], critic_hidden=[64], verbose=0, device="cpu")
    model.learn(16, progress_bar=False)
    full, slim = model.save(tmp_path / "full.pt"), model.save(tmp_path / "slim.pt", optimizer=False)
    assert slim.stat().st_size < 0.6 * full.stat().st_size
    obs = np.random.default_rng(0).normal(size=(3, 934)).astype(np.float32)
    a, _ = agents.load(full).predict(obs)
    b, _ = agents.load(slim).predict(obs)
    np.testing.assert_allclose(a, b, atol=1e-6)
    resumed = agents.load(slim, env="auto", n_envs=2, verbose=0)  # trains on, with a fresh optimiser
    resumed.learn(16, reset_num_timesteps=False, progress_bar=False)
    assert resumed.num_timesteps >= 32
    model.close()
    resumed.close()


def test_shipped_policies_are_found_by_name(tmp_path, monkeypatch):
    model = PPO("SMPL/Imitation-v0", n_envs=1, env_kwargs={"motions": "walk"}, n_steps=8, batch_size=8,
                actor_hidden=[32], critic_hidden=[32], verbose=0, device="cpu")
    monkeypatch.setattr(recipes, "PRETRAINED_DIR", tmp_path)
    model.save(tmp_path / "walk_test.pt", optimizer=False)
    assert recipes.pretrained_checkpoints() == {"walk_test": tmp_path / "walk_test.pt"}
    assert find_checkpoint("walk_test") == tmp_path / "walk_test.pt"
    with pytest.raises(RecipeError, match="shipped policies: walk_test"):
        find_checkpoint("no_such_policy")
    model.close()


def test_every_shipped_file_is_a_loadable_policy():
    for name, path in recipes.pretrained_checkpoints().items():
        assert path.stat().st_size < 8_000_000, name   # a few MB each
        model = agents.load(path)
        assert model.env_id is not None and model.env_kwargs, name


def test_shipped_clips_policy_tracks_the_flight_clips():
    # The all-clips policy (README: every clip succeeds) through the evaluation protocol on the
    # two clips that were learnt last: a change to the env that breaks it fails here.
    import smpl_envs

    policy = agents.load(find_checkpoint("clips"), device="cpu")
    result = smpl_envs.evaluate(policy, "SMPL/Imitation-v0", motions=["run", "jump"], num_envs=2, progress=False,
                                env_kwargs={"action_mode": "residual", "residual_scale": 0.25})
    assert result.summary["success_rate"] == 1.0, result.rows
    assert result.summary["mpjpe_g"] < 100.0
