"""The imitation env's residual action mode, end to end: its zero action is the reference's PD
targets, a checkpoint trained in it is evaluated in it, and the training benchmark runs."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import agents
import smpl_envs  # noqa: F401  (registers the ids)
from agents import PPO
from smpl_envs.humanoid.skeleton import ACTION_SCALE

ROOT = Path(__file__).resolve().parents[1]
N = 3


def _next_frames(lib, info) -> np.ndarray:
    """Global library frames after the ones each world was reset to (info at reset: the start frame)."""
    ids = np.asarray(info["motion_id"])
    frame = lib.starts[ids] + np.rint(np.asarray(info["motion_time"]) * lib.fps).astype(np.int64)
    return np.minimum(frame + 1, lib.starts[ids] + lib.lengths[ids] - 1)


def test_zero_residual_action_reproduces_the_reference_pd_targets():
    residual = gym.make_vec("SMPL/Imitation-v0", num_envs=N, motions=["walk", "jump"], action_mode="residual",
                            residual_scale=0.25)
    absolute = gym.make_vec("SMPL/Imitation-v0", num_envs=N, motions=["walk", "jump"])
    _, info = residual.reset(seed=3)
    _, info_abs = absolute.reset(seed=3)
    np.testing.assert_array_equal(info["motion_id"], info_abs["motion_id"])  # the same start frames
    np.testing.assert_array_equal(info["motion_time"], info_abs["motion_time"])
    lib = residual.motion_lib
    nxt = _next_frames(lib, info)
    np.testing.assert_array_equal(residual.reference_action(), 0.0)

    residual.step(np.zeros((N, len(ACTION_SCALE)), np.float32))
    absolute.step(absolute.reference_action())
    # The zero residual holds the next reference frame's joint angles, as far as the PD range allows ...
    expected = np.clip(lib.dof_pos[nxt], -ACTION_SCALE, ACTION_SCALE)
    np.testing.assert_allclose(residual.sim.ctrl, expected, rtol=0, atol=1e-12)
    # ... which is what absolute mode's reference action commands (that one passes through float32).
    np.testing.assert_allclose(residual.sim.ctrl, absolute.sim.ctrl, rtol=0, atol=1e-6)

    # A residual moves the target by residual_scale x ACTION_SCALE x action from the next frame.
    nxt = np.minimum(nxt + 1, lib.starts[info["motion_id"]] + lib.lengths[info["motion_id"]] - 1)
    residual.step(np.full((N, len(ACTION_SCALE)), 0.5, np.float32))
    np.testing.assert_allclose(residual.sim.ctrl,
                               np.clip(lib.dof_pos[nxt] + 0.125 * ACTION_SCALE, -ACTION_SCALE, ACTION_SCALE),
                               rtol=0, atol=1e-12)
    residual.close()
    absolute.close()


@pytest.fixture(scope="module")
def residual_checkpoint(tmp_path_factory):
    """A PPO trained for two iterations in residual mode, saved."""
    model = PPO("SMPL/Imitation-v0", n_envs=2, env_kwargs=dict(motions="walk", action_mode="residual",
                                                               residual_scale=0.25),
                n_steps=8, batch_size=16, n_epochs=1, seed=0, actor_hidden=(16,), critic_hidden=(16,), verbose=0)
    model.learn(2 * 8 * 2, progress_bar=False)
    assert model.iteration == 2
    path = model.save(tmp_path_factory.mktemp("residual") / "residual.pt")
    model.close()
    return path


def test_residual_checkpoint_is_evaluated_in_residual_mode(residual_checkpoint, tmp_path, monkeypatch, capsys):
    from agents.cli import main

    loaded = agents.load(residual_checkpoint, verbose=0)
    assert loaded.env_kwargs["action_mode"] == "residual" and loaded.env_kwargs["residual_scale"] == 0.25
    made = []
    make_vec = gym.make_vec

    def recording_make_vec(env_id, *args, **kwargs):
        made.append((env_id, kwargs))
        return make_vec(env_id, *args, **kwargs)

    monkeypatch.setattr(gym, "make_vec", recording_make_vec)
    assert main(["eval", str(residual_checkpoint), "--num-envs", "1", "--no-progress",
                 "--out", str(tmp_path / "eval.json")]) == 0
    assert (tmp_path / "eval.json").is_file()
    assert [env_id for env_id, _ in made] == ["SMPL/Imitation-v0"]
    assert made[0][1]["action_mode"] == "residual" and made[0][1]["residual_scale"] == 0.25


def test_zero_policy_tracks_better_in_residual_mode_than_in_absolute(residual_checkpoint):
    # The evaluation's own outcome tells the modes apart: a policy whose mean action is zero holds
    # the reference's joint angles in residual mode and the rest pose in absolute mode. PD control
    # alone falls in both within a second, so compare the pose (Procrustes-aligned error over every
    # frame tracked), not success or position.
    from agents.checkpoint_commands import evaluate_agent

    agent = agents.load(residual_checkpoint, verbose=0)
    last = agent.policy.actor[-1]
    last.weight.data.zero_()
    last.bias.data.zero_()
    residual = evaluate_agent(agent, num_envs=1, progress=False).summary
    agent.env_kwargs["action_mode"] = "absolute"
    absolute = evaluate_agent(agent, num_envs=1, progress=False).summary
    assert residual["all_mpjpe_pa"] < 0.5 * absolute["all_mpjpe_pa"], (residual, absolute)


def test_training_benchmark_runs_with_tiny_settings():
    # Not a measurement: only that the script runs end to end and prints its table line.
    out = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "bench_train.py"), "--worlds", "2",
                          "--iterations", "1", "--repeats", "1", "--set", "agent.hyperparams.n_epochs=1"],
                         capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert out.returncode == 0, out.stderr[-2000:]
    lines = out.stdout.splitlines()
    assert any(line.startswith("PPO/env ") and "AMP/PPO" in line for line in lines)
    cells = [c.strip() for c in lines[-1].strip("|").split("|")]
    assert cells[:3] == ["`SMPL/Imitation-v0`", "2", "1 (1)"] and len(cells) == 9, cells
    # Every rate (the env's under PPO's replayed actions and under random ones, PPO's, AMP's) and
    # both ratios are positive numbers.
    assert all(float(c) > 0 for c in cells[3:]), cells
    # A --set override that names no recipe key fails before anything is built.
    bad = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "bench_train.py"), "--set",
                          "agent.hyperparams.n_epoch=1"], capture_output=True, text=True, timeout=60, cwd=ROOT)
    assert bad.returncode != 0 and "n_epoch" in bad.stderr
