"""Checkpoint files: checksums catch damage, old files still load, recovery helpers."""
from __future__ import annotations

import errno
import os
import time

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
