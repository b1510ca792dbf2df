"""PMCP as one command (`smpl-envs pmcp`, agents.pmcp): mining selects exactly the failed clips,
hard clips are learnt through the library's sampling weights, the pipeline recipe and its state
refuse mistakes, and (slow) the whole pipeline on two shipped clips with tiny budgets, stopped in
the middle of a stage and continued by the same command; eval and record on every stage and on
the composed policy; the perpetual test on a tiny setting."""
from __future__ import annotations

import json
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch
import yaml

import agents
import smpl_envs  # noqa: F401
from agents.cli import main
from agents.pmcp import (Pipeline, check_pipeline, hard_clips, load_pipeline, primitive_agent, settings_for,
                         split_primitive_target, success_on)
from agents.recipes import RecipeError, find_checkpoint
from smpl_envs.perpetual import (PerpetualResult, chained_reference, check_options, count_losses, heading,
                                 perpetual_env_kwargs)

TINY_TRAIN = ["env.num_envs=2", "agent.hyperparams.n_steps=16", "agent.hyperparams.batch_size=32",
              "agent.hyperparams.n_epochs=1", "eval.every=0", "video.steps=0", "eval.num_envs=2"]
PIPELINE = {
    "motions": ["walk", "jump"],
    "primitive0": "walk",          # tracks walk, fails jump
    "max_primitives": 1,
    "eval": {"num_envs": 2, "threshold": 0.5, "recovery_trials": 2},
    "primitive": {"recipe": "walk_residual_ppo",
                  "set": [*TINY_TRAIN, "train.total_timesteps=96", "train.checkpoint_every=32"]},
    "recovery": {"recipe": "recovery_tracker_ppo",
                 "set": [*TINY_TRAIN, "env.kwargs.fallen_cache_size=8", "train.total_timesteps=32",
                         "eval.options.trials=2"]},
    "composer": {"recipe": "composer_ppo",
                 "set": [*TINY_TRAIN, "env.kwargs.recovery.fallen_cache_size=8", "train.total_timesteps=32",
                         "agent.policy.kwargs.actor_hidden=[16]", "agent.policy.kwargs.critic_hidden=[16]"]},
    "perpetual": {"motions": ["walk"], "minutes": 0.1, "trials": 1, "shoves": True, "shove_every": [1, 2]},
}


def write(tmp_path, spec=PIPELINE, name="tiny.yaml") -> Path:
    path = tmp_path / name
    path.write_text(yaml.safe_dump(spec))
    return path


# ---------------------------------------------------------------------------------------- mining
def test_mining_selects_exactly_the_clips_that_failed():
    rows = [{"name": n, "success": s} for n, s in [("a", True), ("b", False), ("c", False), ("d", True), ("e", False)]]
    assert hard_clips(rows) == ["b", "c", "e"]
    assert hard_clips(rows, within=["a", "c", "e", "x"]) == ["c", "e"]  # Q_hard(k) within Q_hard(k-1)
    assert hard_clips([r for r in rows if r["success"]]) == []
    assert success_on(rows) == 0.4 and success_on(rows, ["b", "d"]) == 0.5 and success_on(rows, []) is None


@pytest.mark.slow
def test_mining_a_real_evaluation():
    """The shipped walk policy on walk and jump: exactly jump fails, as the per-clip rows say."""
    agent = agents.load(find_checkpoint("walk"), device="cpu", verbose=0)
    result = smpl_envs.evaluate(agent, "SMPL/Imitation-v0", motions=["walk", "jump"], num_envs=2, progress=False)
    failed = [r["name"] for r in result.rows if not r["success"]]
    assert hard_clips(result.rows) == failed == ["jump"]


def test_hard_clips_are_learnt_through_the_library_sampling_weights():
    env = gym.make_vec("SMPL/Imitation-v0", num_envs=32, motions=["walk", "jump", "run"],
                       motion_weights={"jump": 1.0, "run": 3.0})
    lib = env.unwrapped.motion_lib
    assert lib.num_motions == 3 and np.allclose(lib.weights, [0.0, 0.25, 0.75])  # the whole set, weighted
    _, info = env.reset(seed=0)
    assert set(np.unique(info["motion_id"])) <= {1, 2}
    env.close()
    for weights, message in [({"sprint": 1.0}, r"no clip named \['sprint'\]"), ({"walk": -1}, "non-negative"),
                             ({"walk": 0.0}, "every weight is 0")]:
        with pytest.raises(ValueError, match=message):
            gym.make_vec("SMPL/Imitation-v0", num_envs=1, motions=["walk", "jump"], motion_weights=weights)


def test_a_training_run_s_weights_do_not_follow_its_evaluation():
    from smpl_envs.evaluation import ClipProtocol

    kwargs = ClipProtocol().eval_kwargs({"motions": ["walk"], "motion_weights": {"walk": 1.0}, "recovery":
                                         {"starts": {"fallen": 1.0}, "continue_prob": 0.5}, "action_mode": "residual"})
    assert kwargs == {"action_mode": "residual", "recovery": {"starts": {"reference": 1.0}, "continue_prob": 0.0}}


# ---------------------------------------------------------------------------------------- recipe and state
def test_the_shipped_pipeline_recipe_loads():
    spec = load_pipeline("pmcp_corpus")
    assert spec["primitive0"] == "tracker" and spec["motions"] == "corpus:train" and spec["name"] == "pmcp_corpus"
    assert spec["recovery"]["init"] == "previous" and spec["composer"]["recipe"] == "composer_ppo"


@pytest.mark.parametrize("change, message", [
    ({"colour": "red"}, r"unknown pipeline key\(s\) \['colour'\]"),
    ({"motions": None}, "a pipeline needs motions"),
    ({"max_primitives": -1}, "max_primitives must be an integer >= 0"),
    ({"primitive": {"recipe": "walk_residual_ppo", "sett": []}}, r"\['primitive.sett'\]"),
    ({"composer": {"recipe": "composer_ppo", "set": ["agent.hyperparams.learnin_rate=1"]}}, "learnin_rate"),
    ({"perpetual": {"minutes": -2}}, "perpetual: minutes must be a positive number"),
    ({"primitive": {"recipe": "walk_residual_ppo", "given": "walk"}}, "primitive.given must be a list"),
    ({"primitive": {"recipe": "walk_residual_ppo", "given": ["walk", "walk"]}}, "more than max_primitives=1"),
])
def test_pipeline_recipe_mistakes_are_named(change, message):
    with pytest.raises((RecipeError, TypeError), match=message):
        check_pipeline({**PIPELINE, **change})


def test_a_recovery_policy_s_guides_travel_between_imitation_and_recovery():
    """A composer trained on Imitation-v0 with guides in its recovery dict is evaluated on
    Recovery-v0 with them, and the reverse direction keeps only what Imitation-v0 has."""
    from types import SimpleNamespace

    recovery = {"recovery_action_base": "pull", "getup_guide": "corpus:getup", "walk_guide": True,
                "starts": {"fallen": 1.0}, "continue_prob": 0.5}
    composer = SimpleNamespace(env_id="SMPL/Imitation-v0", env_kwargs={
        "action_mode": "residual", "residual_scale": 0.25, "recovery": recovery})
    got = settings_for(composer, "SMPL/Recovery-v0")
    assert got["getup_guide"] == "corpus:getup" and got["walk_guide"] is True
    assert got["recovery_action_base"] == "pull" and got["action_mode"] == "residual"
    assert "starts" not in got and "continue_prob" not in got  # training choices, not policy settings
    primitive = SimpleNamespace(env_id="SMPL/Recovery-v0", env_kwargs={
        "action_mode": "residual", "residual_scale": 0.25, "getup_guide": "corpus:getup", "walk_guide": True})
    back = settings_for(primitive, "SMPL/Imitation-v0")
    assert "getup_guide" not in back and back["residual_scale"] == 0.25
    # The perpetual test of a recovery primitive on its own: its guides go in the recovery dict.
    kwargs = perpetual_env_kwargs(primitive)
    assert kwargs["recovery"]["walk_guide"] is True and kwargs["recovery"]["getup_guide"] == "corpus:getup"
    assert "walk_guide" not in kwargs and kwargs["residual_scale"] == 0.25


def test_a_run_directory_keeps_its_recipe(tmp_path):
    run = tmp_path / "run"
    Pipeline(load_pipeline(write(tmp_path)), run)
    assert json.loads((run / "state.json").read_text())["recipe"]["max_primitives"] == 1
    Pipeline(load_pipeline(write(tmp_path)), run)  # the same recipe: the same pipeline
    with pytest.raises(RecipeError, match=r"another recipe \(max_primitives: 1 there, 2 now\)"):
        Pipeline(load_pipeline(write(tmp_path), ["max_primitives=2"]), run)
    # A run begun before a key existed resumes: its stored recipe is filled in with the defaults.
    state = json.loads((run / "state.json").read_text())
    del state["recipe"]["primitive"]["given"]
    (run / "state.json").write_text(json.dumps(state))
    Pipeline(load_pipeline(write(tmp_path)), run)
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "x.txt").write_text("x")
    with pytest.raises(RecipeError, match="holds no pipeline state"):
        Pipeline(load_pipeline(write(tmp_path)), tmp_path / "other")


# ---------------------------------------------------------------------------------------- perpetual
def test_losses_recoveries_and_resets_on_hand_made_traces():
    d = np.full(200, 0.1)
    d[10:20] = 0.8       # a loss from frame 10, back at 20 and staying (>= 30 frames): recovered in 1/3 s
    d[100:121] = 0.9     # a loss from 100 ended by a reset at 120 (then on the reference again)
    d[190:] = 0.7        # a loss open at the end
    down = np.zeros(200, bool)
    down[12] = True
    rows = count_losses(d, down, reset_frames=[120], shove_frames=[5, 150])
    assert [(r["start_s"] * 30, r["recovered"], r["reset"]) for r in rows] == [(10, True, False), (100, False, True),
                                                                               (190, False, False)]
    assert rows[0]["time_to_recover_s"] == pytest.approx(10 / 30) and rows[0]["fell"] and rows[0]["shoved"]
    assert not rows[1]["fell"] and not rows[1]["shoved"] and rows[1]["time_to_recover_s"] is None
    # Back, then lost again before the hold is over: one loss, recovered at the second return.
    d = np.full(120, 0.1)
    d[10:20] = 0.8
    d[30:35] = 0.8
    (row,) = count_losses(d, np.zeros(120, bool))
    assert row["recovered"] and row["time_to_recover_s"] == pytest.approx(25 / 30)


def test_perpetual_options_the_reference_waiting_and_no_termination():
    o = check_options({"reference_waits": True, "termination_distance": None})
    assert o["reference_waits"] is True and o["termination_distance"] is None
    assert check_options({})["reference_waits"] is False and check_options({})["termination_distance"] == 0.5
    with pytest.raises(ValueError, match="reference_waits must be true or false"):
        check_options({"reference_waits": "yes"})
    with pytest.raises(ValueError, match="termination_distance must be a positive number"):
        check_options({"termination_distance": -1})
    summary = {"minutes": 1, "trials": 1, "shoves": 0, "losses": 0, "falls": 0, "recovered": 0, "unrecovered": 0,
               "median_time_to_recover_s": None, "max_time_to_recover_s": None, "resets": 0, "perpetual": True}
    waits = PerpetualResult([], [], [], summary, {**check_options({"reference_waits": True}), "shove_every": (1, 2)})
    assert "the reference waits while a body is lost; termination beyond 0.5 m" in waits.table()
    live = PerpetualResult([], [], [], summary, check_options({"termination_distance": None}))
    assert "the reference walks on; no termination" in live.table()


def test_the_chained_reference_is_continuous_and_as_long_as_asked():
    lib, clips = chained_reference(["walk", "turn"], minutes=0.25, seed=0, blend_frames=5)
    assert lib.num_motions == 1 and lib.lengths[0] == 451 and [c[1] for c in clips][0] == 0
    root = lib.body_pos[:, 0]
    step = np.linalg.norm(np.diff(root[:, :2], axis=0), axis=-1)
    assert step.max() < 0.1  # no jump of the root at the joins (a run moves ~0.1 m a frame at most)
    yaw = heading(lib.body_quat[:, 0])
    assert np.abs(np.angle(np.exp(1j * np.diff(yaw)))).max() < 0.3


@pytest.mark.slow
def test_the_perpetual_test_on_a_tiny_setting(tmp_path):
    """The shipped clips policy through 12 s of chained walk and turn with hard shoves: every loss
    is counted as recovered or ended by a reset, and the command line writes the same result."""
    out = tmp_path / "perpetual.json"
    args = ["perpetual", "clips", "--motions", "walk", "turn", "--minutes", "0.2", "--option", "shove_every=[2, 3]",
            "--option", "shove_speed=[2, 2.5]", "--out", str(out), "--no-progress", "--device", "cpu"]
    assert main(args) == 0
    result = json.loads(out.read_text())
    s = result["summary"]
    assert s["shoves"] == len(result["shoves"]) >= 3 and s["losses"] >= 1
    assert s["recovered"] + s["unrecovered"] == s["losses"]
    assert s["resets"] == sum(r["reset"] for r in result["losses"]) and not s["perpetual"]
    assert all(2 <= b["time_s"] - a["time_s"] <= 3.05 for a, b in zip(result["shoves"], result["shoves"][1:]))
    calm = tmp_path / "calm.json"
    assert main([*args[:7], "--no-shoves", "--reference-waits", "--out", str(calm), "--no-progress"]) == 0
    calm = json.loads(calm.read_text())
    assert calm["summary"]["shoves"] == 0 and calm["settings"]["reference_waits"] and not result["settings"]["reference_waits"]
    video = tmp_path / "perpetual.mp4"
    assert main(["perpetual", "clips", "--motions", "walk", "--minutes", "0.03", "--video", str(video),
                 "--no-progress"]) == 0
    import imageio.v3 as iio

    assert sum(1 for _ in iio.imiter(video)) == 55  # the first frame and one per step


# ---------------------------------------------------------------------------------------- end to end
@pytest.mark.slow
def test_the_pipeline_end_to_end_stopped_and_resumed(tmp_path, monkeypatch, capsys):
    from agents.ppo import PPO

    recipe, run = write(tmp_path), tmp_path / "pmcp"
    command = ["pmcp", str(recipe), "--run-dir", str(run), "--quiet", "--no-progress", "--threads", "1"]
    real_update, updates = PPO._update, []

    def stop_at_the_second_update(self, buf):
        updates.append(self.num_timesteps)
        if len(updates) == 2:
            raise KeyboardInterrupt  # Ctrl-C in the middle of primitive1's training
        return real_update(self, buf)

    monkeypatch.setattr(PPO, "_update", stop_at_the_second_update)
    assert main(command) == 130
    state = json.loads((run / "state.json").read_text())
    assert state["order"] == ["primitive0", "primitive1"] and state["stages"]["primitive1"]["status"] == "training"
    assert state["stages"]["primitive0"]["hard"] == ["jump"]  # mined: Q_hard(0)
    assert agents.load(run / "stages" / "primitive1" / "checkpoints" / "last.pt").num_timesteps == 64
    first_eval = (run / "stages" / "primitive0" / "set_eval.json").stat().st_mtime_ns

    updates.clear()
    monkeypatch.setattr(PPO, "_update", lambda self, buf: (updates.append(self.num_timesteps), real_update(self, buf)))
    assert main(command) == 0
    assert updates[0] == 96  # primitive1 went on from its step 64 (one more rollout), not from 0
    assert (run / "stages" / "primitive0" / "set_eval.json").stat().st_mtime_ns == first_eval  # not redone
    state = json.loads((run / "state.json").read_text())
    assert state["order"] == ["primitive0", "primitive1", "recovery", "composer"] and state["done"]
    p1 = state["stages"]["primitive1"]
    assert p1["trained_on"] == ["jump"] and agents.load(p1["checkpoint"]).num_timesteps == 96
    config = yaml.safe_load((run / "stages" / "primitive1" / "config.yaml").read_text())
    assert config["env"]["kwargs"]["motion_weights"] == {"jump": 1.0}
    assert config["env"]["kwargs"]["motions"] == ["walk", "jump"]  # the whole set, weighted
    assert config["agent"]["init"] == state["stages"]["primitive0"]["checkpoint"]  # weights copied from the one before
    assert yaml.safe_load((run / "stages" / "recovery" / "config.yaml").read_text())["agent"]["init"] == p1["checkpoint"]

    # The composed policy: every primitive inside one file, the recovery primitive's settings in its env.
    composed = agents.load(run / "pmcp.pt")
    assert type(composed.policy) is agents.Composer and composed.policy.num_primitives == 3
    assert composed.env_kwargs["recovery"]["recovery_action_base"] == "pull"
    assert all(p.frozen for p in composed.policy.primitives)
    for name in ("summary.txt", "summary.json", "perpetual.json", "stages/composer/recovery_eval.json",
                 "stages/recovery/set_eval.json"):
        assert (run / name).is_file(), name
    summary = (run / "summary.txt").read_text()
    assert "forgetting" in summary and "against the best single primitive" in summary and "95.0 / 98.8" in summary

    # eval and record on each stage and on the composed policy.
    capsys.readouterr()
    for target in ("stages/primitive0", "stages/primitive1", "stages/recovery", "stages/composer", "pmcp.pt"):
        out = tmp_path / f"{target.replace('/', '_')}.json"
        assert main(["eval", str(run / target), "--no-progress", "--num-envs", "2", "--out", str(out),
                     "--option", "trials=2"] if target == "stages/recovery" else
                    ["eval", str(run / target), "--no-progress", "--num-envs", "2", "--out", str(out)]) == 0, target
    assert main(["record", str(run / "pmcp.pt"), "--steps", "3", "--no-progress",
                 "--out", str(tmp_path / "pmcp.mp4")]) == 0
    assert main(["record", str(run / "stages" / "primitive0"), "--steps", "3", "--no-progress",
                 "--out", str(tmp_path / "p0.mp4")]) == 0
    # The command again: nothing left to do, the same tables.
    assert main(command) == 0


def test_a_given_primitive_stands_in_for_training(tmp_path):
    """`primitive.given`: an earlier run's primitive is evaluated and mined like a trained one,
    and only the composer trains."""
    spec = {**PIPELINE, "primitive": {**PIPELINE["primitive"], "given": ["walk"]}, "recovery": None, "perpetual": None}
    run = tmp_path / "pmcp"
    assert main(["pmcp", str(write(tmp_path, spec)), "--run-dir", str(run), "--quiet", "--no-progress",
                 "--threads", "1"]) == 0
    state = json.loads((run / "state.json").read_text())
    assert state["order"] == ["primitive0", "primitive1", "composer"] and state["done"]
    p1 = state["stages"]["primitive1"]
    assert p1["source"] == str(find_checkpoint("walk").resolve()) and p1["trained_on"] == ["jump"]
    assert p1["hard"] == ["jump"]  # mined within Q_hard(0) as a trained primitive is
    assert not (run / "stages" / "primitive1" / "config.yaml").exists()  # not trained
    assert not (run / "recipes" / "primitive1.yaml").exists()
    composed = agents.load(run / "pmcp.pt")
    given = agents.load(find_checkpoint("walk")).policy.state_dict()
    inside = composed.policy.primitives[1].state_dict()
    assert composed.policy.num_primitives == 2 and all(torch.equal(given[k], inside[k]) for k in given)
    with pytest.raises(RecipeError, match="no_such_run"):
        Pipeline(load_pipeline(write(tmp_path, {**spec, "primitive": {**spec["primitive"], "given": ["no_such_run"]}},
                                     "missing.yaml")), tmp_path / "missing").run()


def test_a_composer_s_primitive_as_an_agent_of_its_own():
    """`COMPOSER#k`: the shipped composer's primitive 1 with the composer's imitation settings; its
    recovery primitive (the last) and a policy that is no composer are refused by name."""
    assert split_primitive_target("pmcp#1") == ("pmcp", 1) and split_primitive_target("runs/a#b") == ("runs/a#b", None)
    composer = agents.load(find_checkpoint("pmcp"), device="cpu")
    agent = primitive_agent(find_checkpoint("pmcp"), 1)
    inside = composer.policy.primitives[1].state_dict()
    assert all(torch.equal(v, inside[k]) for k, v in agent.policy.state_dict().items())
    assert "recovery" not in agent.env_kwargs and agent.env_kwargs["residual_scale"] == composer.env_kwargs["residual_scale"]
    obs = np.random.default_rng(0).normal(size=(3, agent.obs_dim)).astype(np.float32)
    x = torch.as_tensor(obs)
    inner = composer.policy.primitives[1]
    assert np.array_equal(agent.predict(obs)[0], inner.env_action(inner.act(x), x).numpy())
    with pytest.raises(RecipeError, match="the last of them its recovery primitive"):
        primitive_agent(find_checkpoint("pmcp"), composer.policy.num_primitives - 1)
    with pytest.raises(RecipeError, match="not a Composer"):
        primitive_agent(find_checkpoint("walk"), 0)
