"""Checkpoint files: checksums catch damage, old files still load, recovery helpers; a checkpoint's
policy runs only in the env it was trained in (its task and recorded settings)."""
from __future__ import annotations

import errno
import os
import time

import gymnasium as gym
import numpy as np
import pytest
import torch

from agents.checkpoint import (FORMAT, CorruptCheckpointError, DiskFullError, clean_stale_temp_files,
                               load_checkpoint, newest_readable_checkpoint, save_checkpoint)


def _state(seed: int = 0) -> dict:
    # Big enough (about 1 MB) that the middle of the file is tensor data, like a real agent's.
    g = torch.Generator().manual_seed(seed)
    return {"class": "PPO", "num_timesteps": seed,
            "optimizer": {"exp_avg_sq": torch.rand(250_000, generator=g)}}


def _flip(path, offset: int, n: int) -> None:
    data = bytearray(path.read_bytes())
    data[offset:offset + n] = bytes(b ^ 0xFF for b in data[offset:offset + n])
    path.write_bytes(bytes(data))


def test_roundtrip_and_weights_only_container(tmp_path):
    state = _state()
    path = save_checkpoint(state, tmp_path / "a")
    assert path.name == "a.pt"
    loaded = load_checkpoint(path)
    assert loaded["format"] == FORMAT and loaded["num_timesteps"] == 0
    torch.testing.assert_close(loaded["optimizer"]["exp_avg_sq"], state["optimizer"]["exp_avg_sq"], rtol=0, atol=0)
    # The file itself stays readable by the safe loader (no custom classes in it).
    raw = torch.load(path, weights_only=True)
    assert set(raw) == {"format", "sha256", "payload"} and len(raw["sha256"]) == 64


@pytest.mark.skipif(os.name != "posix", reason="file modes are POSIX")
def test_saved_file_has_the_umask_mode_not_mkstemp_private(tmp_path):
    before = os.umask(0o022)
    try:
        path = save_checkpoint(_state(), tmp_path / "shared")
    finally:
        os.umask(before)
    assert path.stat().st_mode & 0o777 == 0o644


def test_flipped_bytes_are_detected(tmp_path):
    path = save_checkpoint(_state(), tmp_path / "ckpt.pt")
    size = path.stat().st_size
    _flip(path, size // 2, 4096)
    with pytest.raises(CorruptCheckpointError, match=r"ckpt\.pt.*corrupt") as err:
        load_checkpoint(path)
    assert isinstance(err.value, ValueError)  # callers catching ValueError keep working
    assert "checksum" in str(err.value)


def test_truncated_file_is_detected(tmp_path):
    path = save_checkpoint(_state(), tmp_path / "ckpt.pt")
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(CorruptCheckpointError, match=r"ckpt\.pt.*(truncated|corrupt)"):
        load_checkpoint(path)


def test_checkpoint_without_checksum_still_loads(tmp_path):
    # The layout written before checksums: the state dict saved directly.
    state = {"format": FORMAT, "class": "PPO", "num_timesteps": 7, "w": torch.arange(5.0)}
    torch.save(state, tmp_path / "old.pt")
    loaded = load_checkpoint(tmp_path / "old.pt")
    assert loaded["num_timesteps"] == 7
    np.testing.assert_allclose(loaded["w"].numpy(), np.arange(5.0), atol=0)


def test_foreign_files_are_still_told_apart(tmp_path):
    torch.save({"weights": torch.ones(2)}, tmp_path / "other.pt")
    with pytest.raises(ValueError, match="not a smpl-envs agent checkpoint") as err:
        load_checkpoint(tmp_path / "other.pt")
    assert not isinstance(err.value, CorruptCheckpointError)
    with pytest.raises(FileNotFoundError):
        load_checkpoint(tmp_path / "missing.pt")


def test_newest_readable_falls_back_past_damaged_files(tmp_path):
    for steps in (100, 200, 300):
        save_checkpoint(_state(steps), tmp_path / f"ckpt_{steps:012d}.pt")
    last = save_checkpoint(_state(300), tmp_path / "last.pt")
    assert newest_readable_checkpoint(tmp_path) == (last, [])

    # A crash outside the atomic save (disk full, copied run) truncates last.pt and corrupts the newest.
    last.write_bytes(last.read_bytes()[:1000])
    newest = tmp_path / "ckpt_000000000300.pt"
    _flip(newest, newest.stat().st_size // 2, 4096)
    path, skipped = newest_readable_checkpoint(tmp_path)
    assert path == tmp_path / "ckpt_000000000200.pt"
    assert [p for p, _ in skipped] == [last, newest]
    assert "truncated or corrupt" in skipped[0][1] and "checksum" in skipped[1][1]
    assert load_checkpoint(path)["num_timesteps"] == 200


def test_newest_readable_with_nothing_usable(tmp_path):
    assert newest_readable_checkpoint(tmp_path) == (None, [])
    (tmp_path / "last.pt").write_bytes(b"")
    path, skipped = newest_readable_checkpoint(tmp_path)
    assert path is None and [p.name for p, _ in skipped] == ["last.pt"]


def test_clean_stale_temp_files(tmp_path, monkeypatch):
    kept = save_checkpoint(_state(), tmp_path / "last.pt")
    # An interrupted save: the process dies after writing the temporary file, before the rename,
    # and (killed, not raising) never runs its cleanup.
    temps = []

    def crash(src, dst):
        temps.append(src)
        raise KeyboardInterrupt

    monkeypatch.setattr(os, "replace", crash)
    monkeypatch.setattr("pathlib.Path.unlink", lambda self, missing_ok=False: None)
    with pytest.raises(KeyboardInterrupt):
        save_checkpoint(_state(), tmp_path / "ckpt_000000000100.pt")
    monkeypatch.undo()

    stale = sorted(tmp_path.glob(".*.tmp"))
    assert [str(p) for p in stale] == temps
    (tmp_path / "notes.tmp").write_text("not ours")
    assert clean_stale_temp_files(tmp_path, min_age_s=3600) == []  # too recent: maybe a save in progress
    old = time.time() - 7200
    os.utime(stale[0], (old, old))
    assert clean_stale_temp_files(tmp_path, min_age_s=3600) == stale
    assert sorted(p.name for p in tmp_path.iterdir()) == ["last.pt", "notes.tmp"]
    assert load_checkpoint(kept)["class"] == "PPO"
    assert clean_stale_temp_files(tmp_path / "missing") == []


# ---------------------------------------------------------------------------------------- training settings
# A checkpoint records the env its policy was trained in; evaluate, record and load run it there.
ID = "SMPL/Imitation-v0"
RESIDUAL = {"action_mode": "residual", "residual_scale": 0.25}


@pytest.fixture(scope="module")
def residual_path(tmp_path_factory):
    """An untrained residual-action PPO whose mean action is zero, saved. Zero holds the
    reference's joint angles in residual mode and the rest pose in absolute mode, so which mode
    a policy runs in shows in its tracking error."""
    from agents import PPO

    model = PPO(ID, n_envs=1, env_kwargs={"motions": "walk", **RESIDUAL}, actor_hidden=[16], critic_hidden=[16],
                seed=0, verbose=0, device="cpu")
    model.policy.actor[-1].weight.data.zero_()
    model.policy.actor[-1].bias.data.zero_()
    path = model.save(tmp_path_factory.mktemp("residual") / "residual.pt", optimizer=False)
    model.close()
    return path


def _pose_error(result) -> float:
    return result.summary["all_mpjpe_pa"]


def test_evaluate_runs_a_policy_in_its_training_mode(residual_path):
    import smpl_envs
    from agents import load

    agent = load(residual_path, device="cpu")
    assert agent.env_kwargs == {"motions": "walk", "substeps": 4, **RESIDUAL}  # defaults recorded too
    # The README's call: no kwargs, yet the recorded mode (and clip) are used.
    recorded = smpl_envs.evaluate(agent, ID, num_envs=1, progress=False)
    explicit = smpl_envs.evaluate(lambda obs: agent(obs), ID, motions="walk", num_envs=1, progress=False,
                                  env_kwargs=RESIDUAL)
    assert recorded.rows == explicit.rows and recorded.rows[0]["name"] == "walk"
    assert smpl_envs.evaluate(agent.predict, ID, num_envs=1, progress=False).rows == recorded.rows  # a bound predict
    # Contradicting the record is refused by name, unless asked for.
    for kwargs in ({"action_mode": "absolute"}, {"residual_scale": 0.5}, {"substeps": 2}):
        (name,) = kwargs
        with pytest.raises(ValueError, match=rf"{name}=.*contradicts the policy's {name}=.*override_settings"):
            smpl_envs.evaluate(agent, ID, num_envs=1, progress=False, env_kwargs=kwargs)
    absolute = smpl_envs.evaluate(agent, ID, num_envs=1, progress=False, env_kwargs={"action_mode": "absolute"},
                                  override_settings={"action_mode"})
    assert _pose_error(recorded) < 0.5 * _pose_error(absolute), (recorded.summary, absolute.summary)
    with pytest.raises(ValueError, match=r"override_settings \['motions'\]: not a policy setting"):
        smpl_envs.evaluate(agent, ID, num_envs=1, progress=False, override_settings={"motions"})
    # Repeating the recorded values is no contradiction.
    assert smpl_envs.evaluate(agent, ID, num_envs=1, progress=False, env_kwargs=RESIDUAL).rows == recorded.rows

    # An existing env is checked, not changed.
    made = gym.make_vec(ID, num_envs=1, motions="walk", termination_distance=None, autoreset_mode="Disabled")
    with pytest.raises(ValueError, match=r"env runs action_mode='absolute', the policy was trained with "
                                         r"action_mode='residual'"):
        smpl_envs.evaluate(agent, made, progress=False)
    assert _pose_error(smpl_envs.evaluate(agent, made, progress=False, override_settings={"action_mode"})) == \
        pytest.approx(_pose_error(absolute))
    made.close()


def test_an_agent_made_on_an_env_records_its_settings(tmp_path):
    import smpl_envs
    from agents import PPO, load

    env = gym.make_vec(ID, num_envs=1, motions="walk", action_mode="residual", residual_scale=0.3)
    model = PPO(env, actor_hidden=[16], critic_hidden=[16], verbose=0, device="cpu")
    assert model.env_id == ID and model.env_kwargs == {"substeps": 4, "action_mode": "residual", "residual_scale": 0.3}
    agent = load(model.save(tmp_path / "m.pt"), device="cpu")
    with pytest.raises(ValueError, match="residual_scale=0.25 contradicts the policy's residual_scale=0.3"):
        smpl_envs.evaluate(agent, ID, num_envs=1, progress=False, env_kwargs={"residual_scale": 0.25})
    model.close()


def test_load_attaches_only_an_env_with_the_training_settings(residual_path):
    from agents import PPO

    with pytest.raises(ValueError, match="residual_scale=0.5 contradicts the policy's residual_scale=0.25"):
        PPO.load(residual_path, env="auto", env_kwargs={"residual_scale": 0.5}, verbose=0)
    # An env id gets the recorded settings filled in; "auto" the whole recorded env.
    for env in (ID, "auto"):
        agent = PPO.load(residual_path, env=env, env_kwargs={"motions": "run"}, verbose=0)
        assert (agent.env.action_mode, agent.env.residual_scale) == ("residual", 0.25)
        agent.close()
    absolute = gym.make_vec(ID, num_envs=1, motions="walk")
    with pytest.raises(ValueError, match="env runs action_mode='absolute'"):
        PPO.load(residual_path, env=absolute, verbose=0)
    absolute.close()
    # On purpose: the env changes, and so does what the agent records for its next checkpoint.
    agent = PPO.load(residual_path, env="auto", env_kwargs={"residual_scale": 0.5}, verbose=0,
                     override_settings={"residual_scale"})
    assert agent.env.residual_scale == 0.5 and agent.env_kwargs["residual_scale"] == 0.5
    agent.close()
    with pytest.raises(ValueError, match="pass env= too"):
        PPO.load(residual_path, override_settings={"residual_scale"}, verbose=0)


def test_amp_load_keeps_the_training_settings(tmp_path):
    from agents import AMP, load

    model = AMP(ID, n_envs=1, env_kwargs={"motions": "walk", **RESIDUAL}, actor_hidden=[16], critic_hidden=[16],
                disc_hidden=[16], verbose=0, device="cpu")
    path = model.save(tmp_path / "amp.pt", optimizer=False)
    model.close()
    with pytest.raises(ValueError, match="action_mode='absolute' contradicts the policy's action_mode='residual'"):
        load(path, env="auto", env_kwargs={"action_mode": "absolute"}, verbose=0)
    agent = load(path, env=ID, verbose=0)
    assert type(agent) is AMP and agent.env.action_mode == "residual"
    agent.close()


def test_a_policy_is_refused_on_another_task_of_the_same_sizes(tmp_path):
    import smpl_envs
    from agents import PPO, load

    model = PPO("SMPL/Speed-v0", n_envs=1, actor_hidden=[16], critic_hidden=[16], verbose=0, device="cpu")
    path = model.save(tmp_path / "speed.pt", optimizer=False)
    model.close()
    reach = gym.make_vec("SMPL/Reach-v0", num_envs=1)
    assert reach.single_observation_space.shape == (model.obs_dim,)  # the sizes alone let it through
    refused = "trained on SMPL/Speed-v0, not SMPL/Reach-v0"
    with pytest.raises(ValueError, match=refused):
        PPO.load(path, env="SMPL/Reach-v0", verbose=0)
    with pytest.raises(ValueError, match=refused):
        PPO.load(path, env=reach, verbose=0)
    reach.close()
    agent = load(path, device="cpu")
    with pytest.raises(ValueError, match=refused):
        smpl_envs.evaluate(agent, "SMPL/Reach-v0", episodes=1, progress=False)
    with pytest.raises(ValueError, match=refused):
        smpl_envs.record("SMPL/Reach-v0", agent, tmp_path / "reach.mp4", steps=1, progress=False)
    assert not (tmp_path / "reach.mp4").exists()


def test_record_runs_a_policy_in_its_training_mode(residual_path, tmp_path):
    import smpl_envs
    from agents import load

    agent = load(residual_path, device="cpu")
    small = {"steps": 3, "seed": 0, "progress": False, "render_size": (64, 48)}
    recorded = smpl_envs.record(ID, agent, tmp_path / "a.mp4", **small)
    # What the video's env is made with: the record's settings and clip, from the clip's start.
    explicit = smpl_envs.record(ID, lambda obs: agent(obs), tmp_path / "b.mp4", motions="walk", start="beginning",
                                **RESIDUAL, **small)
    absolute = smpl_envs.record(ID, agent, tmp_path / "c.mp4", action_mode="absolute",
                                override_settings={"action_mode"}, **small)
    assert recorded["steps"] == 3 and recorded["returns"] == explicit["returns"] != absolute["returns"]
    with pytest.raises(ValueError, match="action_mode='absolute' contradicts"):
        smpl_envs.record(ID, agent, tmp_path / "d.mp4", action_mode="absolute", **small)
    env = gym.make(ID, render_mode="rgb_array", motions="walk", render_size=(64, 48))
    with pytest.raises(ValueError, match="env runs action_mode='absolute'"):
        smpl_envs.record(env, agent, tmp_path / "e.mp4", steps=1, progress=False)
    env.close()
    with pytest.raises(ValueError, match="records none"):
        smpl_envs.record(ID, "zero", tmp_path / "f.mp4", steps=1, override_settings={"action_mode"})
    assert not any((tmp_path / f"{x}.mp4").exists() for x in "def")


def test_full_disk_is_one_clear_error_naming_the_file_and_the_old_file_survives(tmp_path, full_disk):
    path = save_checkpoint(_state(1), tmp_path / "last.pt")
    before = path.read_bytes()
    full_disk(after=0)
    with pytest.raises(DiskFullError) as exc:
        save_checkpoint(_state(2), path)
    err = exc.value
    assert isinstance(err, OSError) and err.errno == errno.ENOSPC and err.filename == str(path)
    assert str(err).startswith(f"no space left on device to save {path} (1.0 MB)")
    # One error, not the write's error chained to others raised while torch's writer unwound.
    assert err.__cause__ is None and err.__suppress_context__
    assert path.read_bytes() == before and load_checkpoint(path)["num_timesteps"] == 1
    assert [p.name for p in tmp_path.iterdir()] == ["last.pt"]  # the partial temporary file is gone
