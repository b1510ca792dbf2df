"""Shipped policies: saved without the optimiser, found by name, loadable anywhere, and run as
the README shows at the success it reports."""
import re
from pathlib import Path

import numpy as np
import pytest

import agents
from agents import PPO
from agents.latent_policy import LatentActorCritic
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
        model = agents.load(path)
        assert model.env_id is not None and model.env_kwargs, name
        # a few MB per network: a composer holds its primitives too, a latent policy PULSE's networks
        held = 1 + getattr(model.policy, "num_primitives", 0) + int(isinstance(model.policy, LatentActorCritic))
        assert path.stat().st_size < 8_000_000 * held, name


def test_shipped_clips_policy_tracks_the_flight_clips():
    # The all-clips policy (README: every clip succeeds) through the evaluation protocol on the
    # two clips that were learnt last: a change to the env that breaks it fails here. Its
    # residual actions come from its checkpoint.
    import smpl_envs

    policy = agents.load(find_checkpoint("clips"), device="cpu")
    result = smpl_envs.evaluate(policy, "SMPL/Imitation-v0", motions=["run", "jump"], num_envs=2, progress=False)
    assert result.summary["success_rate"] == 1.0, result.rows
    assert result.summary["mpjpe_g"] < 100.0


def test_shipped_vr_policy_follows_three_points_while_stepping():
    # The latent VR policy (its target met on corpus:test) on the side steps it all follows, through
    # VR's protocol with its frozen PULSE decoder: a change to the env, the latent plug-in or the
    # decoder's inputs that breaks it fails here.
    import smpl_envs

    policy = agents.load(find_checkpoint("vr"), device="cpu")
    assert isinstance(policy.policy, LatentActorCritic)
    result = smpl_envs.evaluate(policy, "SMPL/VRTracking-v0", motions="corpus:test/side_step", num_envs=6,
                                progress=False)
    assert result.summary["clips"] == 6
    assert result.summary["success_rate"] >= 5 / 6, result.rows


def test_shipped_strike_policy_topples_boxes():
    # The latent Strike policy (85.5 % of 256 protocol episodes) on 4 seeded episodes of its own
    # env settings: a change to the task, the latent plug-in or the decoder that breaks it fails here.
    import smpl_envs

    policy = agents.load(find_checkpoint("strike"), device="cpu")
    assert isinstance(policy.policy, LatentActorCritic) and policy.env_kwargs["approach_radius"] == 1.0
    result = smpl_envs.evaluate(policy, "SMPL/Strike-v0", episodes=4, num_envs=4, progress=False)
    assert result.summary["toppled"] >= 0.5, result.rows


def test_shipped_reach_policy_reaches_targets():
    # The latent Reach policy (61.2 % of targets within 0.1 m on 256 protocol episodes) on 4 seeded
    # episodes of its own env settings: a policy that no longer steers the hand reaches none.
    import smpl_envs

    policy = agents.load(find_checkpoint("reach"), device="cpu")
    assert isinstance(policy.policy, LatentActorCritic) and policy.env_kwargs["reward_sharpness"] == 16.0
    result = smpl_envs.evaluate(policy, "SMPL/Reach-v0", episodes=4, num_envs=4, progress=False)
    assert result.summary["targets_reached"] >= 0.25, result.rows  # 47.9 % here (7 of 15 targets)


# ---------------------------------------------------------------------------------------- the README's examples
README = Path(__file__).resolve().parents[1] / "README.md"


def readme_block(marker: str) -> str:
    """The one python block of the README that contains `marker`."""
    (block,) = [b for b in re.findall(r"```python\n(.*?)```", README.read_text(), re.S) if marker in b]
    return block


EVALUATE, RECORD = "result = smpl_envs.evaluate(walk", "video = smpl_envs.record("


def test_the_docs_show_the_readmes_blocks():
    # The docs pages repeat the README's blocks of the shipped policy; the README's are run here,
    # so the copies must be the same code.
    docs = Path(__file__).resolve().parents[1] / "docs"
    for page, markers in (("agents.md", (EVALUATE, RECORD)), ("getting-started.md", (EVALUATE,))):
        text = (docs / page).read_text()
        for marker in markers:
            assert f"```python\n{readme_block(marker)}```" in text, (page, marker)


def test_readme_evaluates_the_shipped_walk_policy_at_its_real_success(capsys):
    # The README's own lines, no kwargs: the residual policy must run with residual actions.
    namespace = {}
    exec(readme_block(EVALUATE), namespace)
    summary = namespace["result"].summary
    assert summary["success_rate"] == 1.0 and summary["mpjpe_g"] < 40.0, summary
    assert "walk" in capsys.readouterr().out  # the table it prints


def test_recording_the_shipped_walk_policy_keeps_it_on_the_clip(tmp_path):
    # The README's record call, shortened: in absolute mode the policy leaves the reference by
    # 0.3 m (the training termination the video keeps) at step 26.
    import smpl_envs

    walk = agents.load(find_checkpoint("walk"), device="cpu")
    video = smpl_envs.record("SMPL/Imitation-v0", walk, tmp_path / "walk.mp4", steps=30, progress=False)
    assert (video["steps"], video["episodes"]) == (30, 1), video


@pytest.mark.slow
def test_readme_records_the_shipped_walk_policy(tmp_path, monkeypatch):
    # ~1 minute here: the offscreen renderer takes ~0.3 s a frame on this CPU.
    monkeypatch.chdir(tmp_path)
    namespace = {}
    exec(readme_block(EVALUATE), namespace)
    exec(readme_block(RECORD), namespace)
    video = namespace["video"]
    assert (video["steps"], video["episodes"]) == (180, 1), video  # the whole clip, no fall
    assert (tmp_path / "out" / "walk.mp4").stat().st_size > 0


@pytest.mark.slow
def test_shipped_tracker_tracks_held_out_corpus_clips():
    # Held-out clips (corpus:test) of five families that the shipped tracker succeeded on in its
    # run's final evaluation (docs/corpus.md): a change to the env, the corpus or the policy's
    # settings that breaks the generalist fails here.
    import smpl_envs
    from smpl_envs.motion.library import MotionLib, load_motions

    lib = load_motions("corpus:test", progress=False)
    names = ["walk_test_0000", "run_test_0003", "side_step_test_0000", "reach_test_0000", "squat_test_0000"]
    subset = MotionLib([lib.motion(lib.index(n)) for n in names])
    policy = agents.load(find_checkpoint("tracker"), device="cpu")
    result = smpl_envs.evaluate(policy, "SMPL/Imitation-v0", motions=subset, num_envs=5, progress=False)
    assert result.summary["success_rate"] == 1.0, [(r["name"], r["success"]) for r in result.rows]
    assert result.summary["mpjpe_g"] < 120.0


@pytest.mark.slow
def test_shipped_pmcp_composes_three_primitives_and_gets_up():
    # The composed policy of docs/pmcp.md's softmax section: three frozen primitives (tracker,
    # hard-clip primitive, recovery primitive), softmax weights and its recovery primitive's guides.
    # Fallen Succ-10s 88.5 % of 200 trials; at least 3 of these 4 seeded trials got up within
    # 10 s for each composer shipped so far.
    from agents.composer import Composer
    from agents.pmcp import RECOVERY, evaluate_as

    policy = agents.load(find_checkpoint("pmcp"), device="cpu")
    assert isinstance(policy.policy, Composer) and policy.policy.num_primitives == 3
    assert policy.policy.weight_activation == "softmax"
    assert policy.env_kwargs["recovery"]["getup_guide"] == "corpus:getup_quick"
    result = evaluate_as(policy, RECOVERY, "stand", 4, False, trials=4, kinds=["fallen"])
    assert result.summary["succ_10s_fallen"] >= 0.75, result.summary
