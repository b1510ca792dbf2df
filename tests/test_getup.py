"""What a recovery run started from a tracker needs: the action base while recovering
(reference, pose, target, pull), the get-up curriculum (the start mix over training, set through the
env's documented hook), and the recipe that puts them together."""
from __future__ import annotations

import csv

import gymnasium as gym
import numpy as np
import pytest

from smpl_envs import policy_settings
from agents.cli import main
from agents.curriculum import StartCurriculum, check_curriculum, start_mix
from agents.recipes import load_recipe

SMALL = {"fallen_cache_size": 8}


def _env(n=4, **kwargs):
    return gym.make_vec("SMPL/Recovery-v0", num_envs=n, **{**SMALL, "action_mode": "residual", **kwargs})


def _ctrl(env):
    u = env.unwrapped
    return u.sim.ctrl[:, u.humanoid.actuators]


def test_target_base_holds_the_pose_and_adds_residuals_up():
    env = _env(starts={"fallen": 1.0}, recovery_action_base="target")
    _, info = env.reset(seed=0)
    u = env.unwrapped
    pose = u.sim.qpos[:, u.humanoid.dof_qpos].copy()
    assert (info["start_kind"] == 1).all() and u.recovery.showing.all()
    env.step(np.zeros((4, 69)))
    np.testing.assert_allclose(_ctrl(env), pose, atol=1e-12)  # the zero action holds the fallen pose
    a = np.full((4, 69), 0.1)
    env.step(a)
    env.step(a)  # two residuals on top of each other
    scale = u.action_scale * u.residual_scale
    np.testing.assert_allclose(_ctrl(env), np.clip(pose + 2 * 0.1 * scale, -u.action_scale, u.action_scale),
                               atol=1e-9)
    env.close()


def test_pose_base_follows_the_body_and_reference_base_is_as_before():
    env = _env(starts={"fallen": 1.0}, recovery_action_base="pose")
    env.reset(seed=0)
    u = env.unwrapped
    for _ in range(3):
        pose = u.sim.qpos[:, u.humanoid.dof_qpos].copy()
        env.step(np.zeros((4, 69)))
        np.testing.assert_allclose(_ctrl(env), pose, atol=1e-12)
    env.close()
    # The default base and any base near the reference: the next reference frame + residual.
    for base, starts in (("reference", {"fallen": 1.0}), ("target", {"reference": 1.0})):
        env = _env(starts=starts, recovery_action_base=base)
        env.reset(seed=0)
        u = env.unwrapped
        ref = u.motion_lib.dof_pos[u.ref.next_frame()].copy()
        env.step(np.zeros((4, 69)))
        np.testing.assert_allclose(_ctrl(env), np.clip(ref, -u.action_scale, u.action_scale), atol=1e-6)
        env.close()


def test_pull_base_moves_the_pose_toward_the_reference_by_at_most_a_residual_range():
    env = _env(starts={"fallen": 1.0}, recovery_action_base="pull")
    env.reset(seed=0)
    u = env.unwrapped
    span = u.action_scale * u.residual_scale
    for a in (np.zeros((4, 69)), np.full((4, 69), -0.3)):
        pose = u.sim.qpos[:, u.humanoid.dof_qpos].copy()
        ref = u.motion_lib.dof_pos[u.ref.next_frame()].copy()
        env.step(a)
        expected = np.clip(pose + np.clip(ref - pose, -span, span) + a * span, -u.action_scale, u.action_scale)
        np.testing.assert_allclose(_ctrl(env), expected, atol=1e-9)
        # A fallen body is far from the standing pose: the pull is capped on many hinges.
        assert (np.abs(ref - pose) > span).mean() > 0.05
    env.close()
    # A body at the reference pose but far from it, standing: the pull base is the reference itself.
    env = _env(starts={"far": 1.0}, recovery_action_base="pull")
    env.reset(seed=0)
    u = env.unwrapped
    assert u.recovery.showing.all()
    ref = u.motion_lib.dof_pos[u.ref.next_frame()].copy()
    env.step(np.zeros((4, 69)))
    np.testing.assert_allclose(_ctrl(env), np.clip(ref, -u.action_scale, u.action_scale), atol=1e-6)
    env.close()


def test_action_base_is_a_policy_setting_and_bad_values_are_named():
    env = _env(recovery_action_base="target")
    assert policy_settings.settings_of(env)["recovery_action_base"] == "target"
    env.close()
    with pytest.raises(ValueError, match="recovery_action_base must be one of"):
        _env(recovery_action_base="floor")
    imitation = gym.make_vec("SMPL/Imitation-v0", num_envs=1, recovery={"recovery_action_base": "target"})
    assert imitation.unwrapped.recovery.action_base == "target"
    imitation.close()


def test_set_recovery_starts_changes_the_draws():
    env = _env(64)
    env.unwrapped.set_recovery_starts({"far": 1.0})
    _, info = env.reset(seed=1)
    assert (info["start_kind"] == 2).all()
    env.unwrapped.set_recovery_starts({"fallen": 0.5, "reference": 0.5})
    _, info = env.reset(seed=1)
    assert set(np.unique(info["start_kind"])) == {0, 1} and 20 < (info["start_kind"] == 1).sum() < 44
    env.close()
    with pytest.raises(ValueError, match="needs recovery on"):
        gym.make_vec("SMPL/Imitation-v0", num_envs=1).unwrapped.set_recovery_starts({"fallen": 1.0})


SCHEDULE = {"starts": [[0, {"fallen": 1.0}], [100, {"fallen": 1.0}], [300, {"reference": 0.5, "far": 0.5}]]}


def test_the_schedule_is_piecewise_linear_in_timesteps():
    spec = check_curriculum(SCHEDULE)
    assert start_mix(spec, 0) == start_mix(spec, 100) == {"reference": 0.0, "fallen": 1.0, "far": 0.0,
                                                           "fallen+far": 0.0}
    mid = start_mix(spec, 200)
    assert mid["fallen"] == pytest.approx(0.5) and mid["reference"] == mid["far"] == pytest.approx(0.25)
    assert start_mix(spec, 10**9) == {"reference": 0.5, "fallen": 0.0, "far": 0.5, "fallen+far": 0.0}
    for bad, message in [({"starts": [[10, {"fallen": 1.0}], [5, {"fallen": 1.0}]]}, "increasing order"),
                         ({"starts": [[0, {"fallen": 0.5}]]}, "sum to 1"),
                         ({"starts": [[0, {"lying": 1.0}]]}, "unknown start kind"),
                         ({"heights": []}, "expected")]:
        with pytest.raises(ValueError, match=message):
            check_curriculum(bad)


class _Agent:
    """What the callback reads of an agent."""

    def __init__(self, env, steps):
        from agents.logger import Logger

        self.env, self.num_timesteps, self.env_id = env, steps, "SMPL/Recovery-v0"
        self.logger = Logger(None, stdout=False, tensorboard=False)


def test_the_callback_sets_the_env_mix_the_schedule_states():
    env = _env(64)
    curriculum = StartCurriculum(SCHEDULE)
    for steps, kinds in ((0, {1}), (300, {0, 2})):
        curriculum.on_iteration(_Agent(env, steps))
        _, info = env.reset(seed=2)
        assert set(np.unique(info["start_kind"]).tolist()) == kinds
    curriculum.on_iteration(_Agent(env, 200))
    assert env.unwrapped.recovery.starts == pytest.approx({"reference": 0.25, "fallen": 0.5, "far": 0.25,
                                                           "fallen+far": 0.0})
    env.close()


@pytest.mark.slow
def test_a_recipe_with_a_curriculum_trains_and_logs_the_mix(tmp_path):
    run = tmp_path / "run"
    schedule = "{starts: [[0, {fallen: 1.0}], [64, {reference: 1.0}]]}"
    args = ["train", "recovery_tracker_ppo", "--run-dir", str(run), "--init", "clips", "--no-progress", "--quiet",
            "--threads", "1"]
    sets = ["env.num_envs=2", "env.kwargs.fallen_cache_size=8", "agent.hyperparams.n_steps=16",
            "agent.hyperparams.batch_size=32", "agent.hyperparams.n_epochs=1", "train.total_timesteps=96",
            f"train.curriculum={schedule}", "train.checkpoint_every=0", "eval.every=0", "eval.num_envs=2",
            "eval.options.trials=2", "video.steps=0"]
    assert main([*args, *[x for s in sets for x in ("--set", s)]]) == 0
    with open(run / "logs" / "progress.csv", newline="") as f:
        rows = [r for r in csv.DictReader(f) if r.get("curriculum/fallen")]
    fallen = [float(r["curriculum/fallen"]) for r in rows]
    assert fallen[0] == pytest.approx(0.5) and fallen[-1] == 0.0  # after 32 steps halfway, from 64 on none
    assert (run / "eval.json").is_file()


def test_the_recovery_recipe_starts_from_a_tracker():
    r = load_recipe("recovery_tracker_ppo")
    assert r["agent"]["init"] == "tracker" and r["env"]["kwargs"]["recovery_action_base"] == "pull"
    assert r["env"]["kwargs"]["residual_scale"] == load_recipe("tracker_ppo")["env"]["kwargs"]["residual_scale"]
    assert r["agent"]["policy"] == load_recipe("tracker_ppo")["agent"]["policy"]  # the same network
    assert start_mix(r["train"]["curriculum"], 0)["fallen"] == 1.0
