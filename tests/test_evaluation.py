"""smpl_envs.evaluation: the PHC protocol run batched over a queue of clips."""

import json
from dataclasses import replace

import gymnasium as gym
import numpy as np
import pytest

from smpl_envs.evaluation import EvalResult, evaluate  # importing smpl_envs registers the ids
from smpl_envs.motion import MotionLib

ID = "SMPL/Imitation-v0"
OFF = dict(termination_distance=None, autoreset_mode="Disabled")


def zero(obs):
    return np.zeros((len(obs), 69), np.float32)


def short_clips(spec):
    """MotionLib of shipped clips cut to their first `frames` frames: [(name, frames), ...].
    PD-only tracking has no balance feedback and tips over after ~50 frames even on "stand", so
    the success case needs clips shorter than that."""
    full = MotionLib.load([name for name, _ in spec], progress=False)
    raws = []
    for i, (_, n) in enumerate(spec):
        raw = full.motion(i).raw()
        raws.append(replace(raw, root_pos=raw.root_pos[:n], local_quat=raw.local_quat[:n]))
    return MotionLib(raws)


def run(policy_of_env, motions, num_envs, **kw):
    """evaluate() on an env we make, so policies may read the env (reference_action)."""
    env = gym.make_vec(ID, num_envs=num_envs, motions=motions, **OFF)
    try:
        return evaluate(policy_of_env(env), env, progress=False, **kw)
    finally:
        env.close()


def test_reference_action_tracks_short_clips():
    lib = short_clips([("stand", 30), ("gesture", 36)])
    result = run(lambda env: (lambda obs: env.reference_action()), lib, 2)
    assert isinstance(result, EvalResult)
    assert [r["name"] for r in result.rows] == ["stand", "gesture"]
    assert [r["motion_id"] for r in result.rows] == [0, 1]
    assert [r["frames"] for r in result.rows] == [30, 36]  # initial frame + every step to the last
    for r in result.rows:
        assert r["success"] and r["fail_frame"] == -1
        assert 0 < r["mpjpe_g"] < 100 and r["mpjpe_l"] < 100
    assert result.summary["success_rate"] == 1.0 and result.summary["clips"] == 2
    assert str(result) == result.table() and "gesture" in str(result)


def test_zero_action_falls_behind_on_walk():
    # A tuple return (stable-baselines' predict gives (actions, state)) counts by its first item.
    result = evaluate(lambda obs: (zero(obs), None), ID, motions="walk", progress=False)
    (row,) = result.rows
    assert row["name"] == "walk" and not row["success"]
    assert row["fail_frame"] >= 0 and row["frames"] == row["fail_frame"] + 1
    assert result.summary["success_rate"] == 0.0 and np.isnan(result.summary["mpjpe_g"])
    assert result.summary["all_mpjpe_g"] == pytest.approx(row["mpjpe_g"])


@pytest.mark.parametrize("policy", ["zero", "reference"])
def test_rows_do_not_depend_on_num_envs(policy):
    # Ends by failure (walk, run under both policies) and by truncation (stand under zero
    # actions), with 1 world every clip after the first comes through a partial reset.
    make = (lambda env: zero) if policy == "zero" else (lambda env: (lambda obs: env.reference_action()))
    lib = MotionLib.load(["walk", "stand", "run"], progress=False)
    results = [run(make, lib, n).rows for n in (1, 2, 3)]
    assert [r["name"] for r in results[0]] == ["walk", "stand", "run"]
    for rows in results[1:]:
        for a, b in zip(results[0], rows):
            assert {k: a[k] for k in ("name", "motion_id", "success", "frames", "fail_frame")} == \
                   {k: b[k] for k in ("name", "motion_id", "success", "frames", "fail_frame")}
            np.testing.assert_allclose([a[k] for k in ("mpjpe_g", "mpjpe_l", "accel", "vel")],
                                       [b[k] for k in ("mpjpe_g", "mpjpe_l", "accel", "vel")],
                                       rtol=1e-6)


def test_clip_failing_on_its_first_frame_hands_the_world_on():
    # Any distance exceeds a negative threshold: every clip ends at its initial frame, so the
    # single world is refilled without ever stepping.
    # (evaluate() refuses a negative threshold, so call the clip loop directly.)
    from smpl_envs.evaluation import _run_clips

    env = gym.make_vec(ID, num_envs=1, motions=["stand", "jump", "kick"], termination_distance=None,
                       autoreset_mode="Disabled")
    rows = _run_clips(zero, env, -1.0, progress=False)
    assert [(r["name"], r["frames"], r["fail_frame"]) for r in rows] == \
           [("stand", 1, 0), ("jump", 1, 0), ("kick", 1, 0)]


@pytest.mark.parametrize("kwargs", [dict(autoreset_mode="NextStep", termination_distance=None),
                                    dict(autoreset_mode="Disabled"),  # default early termination
                                    dict(autoreset_mode="Disabled", termination_distance=None,
                                         max_episode_steps=10)])
def test_misconfigured_env_is_refused(kwargs):
    env = gym.make_vec(ID, num_envs=1, motions="stand", **kwargs)
    with pytest.raises(ValueError, match="must be made with"):
        evaluate(zero, env, progress=False)
    env.close()


def test_bad_arguments_are_refused():
    env = gym.make_vec(ID, num_envs=1, motions="stand", **OFF)
    with pytest.raises(ValueError, match="only for an env id"):
        evaluate(zero, env, motions="walk", progress=False)
    env.close()
    with pytest.raises(ValueError, match="must not set"):
        evaluate(zero, ID, env_kwargs={"termination_distance": 0.5}, progress=False)


def test_save_writes_json(tmp_path):
    result = evaluate(zero, ID, motions=["walk", "run"], progress=False)
    path = result.save(tmp_path / "deep" / "dir" / "eval.json")
    data = json.loads(path.read_text())
    assert data["summary"]["success_rate"] == result.summary["success_rate"]
    assert [c["name"] for c in data["clips"]] == ["walk", "run"]
    assert data["summary"]["mpjpe_g"] is None  # NaN (no successful clip) is written as null


def test_a_clip_table_of_corpus_clips_ends_with_success_per_family():
    from smpl_envs.evaluation import EvalResult, ThreePointResult
    from smpl_envs.metrics import summarize

    def row(name, success):
        return {"name": name, "success": success, "frames": 30, "mpjpe_g": 50.0, "mpjpe_l": 40.0,
                "mpjpe_pa": 30.0, "accel": 5.0, "vel": 6.0}

    rows = [row("walk_test_0000", True), row("walk_test_0001", False), row("walk_test_0002", False),
            row("turn_in_place_test_0000", True)]
    for cls in (EvalResult, ThreePointResult):
        lines = cls(rows, summarize(rows)).table().splitlines()
        assert lines[lines.index("family         succeeded   rate") + 1:][:2] == [
            "turn_in_place     1 / 1    100.0%", "walk              1 / 3     33.3%"]
    # Not the corpus, or one family only: no block (a shipped clip is not a family).
    for names in (["walk", "run"], ["walk_test_0000", "walk_test_0001"], ["walk_test_0000", "run"]):
        assert "family" not in EvalResult([row(n, True) for n in names]).table()
