"""The MotionLib cache: never a reason to fail, never trusted when damaged, off when asked."""

import os
import warnings

import numpy as np
import pytest

from conftest import sway_motion
from smpl_envs.motion import MotionFileError, MotionLib
from smpl_envs.motion.export import to_amass
from smpl_envs.motion.library import cache_dir

NAMES = ["c0", "c1", "c2"]


@pytest.fixture
def tree(tmp_path):
    root = tmp_path / "amass"
    root.mkdir()
    for i, name in enumerate(NAMES):
        to_amass(sway_motion(60, seconds=1.0 + 0.5 * i, name=name), root / f"{name}.npz")
    return root


def _no_parsing(monkeypatch):
    def fail(*a, **k):
        raise AssertionError("parsed a motion file although the tree was cached")
    monkeypatch.setattr("smpl_envs.motion.library.read_motion_file", fail)


def _quiet_load(*args, **kwargs):
    """MotionLib.load that fails on any warning."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        return MotionLib.load(*args, progress=False, **kwargs)


def _assert_same(lib, ref):
    assert lib.names == ref.names
    np.testing.assert_array_equal(lib.lengths, ref.lengths)
    for field in ("body_pos", "body_quat", "dof_pos", "dof_vel", "root_ang_vel_local"):
        np.testing.assert_allclose(np.asarray(getattr(lib, field)), getattr(ref, field), atol=1e-6)
    last = lib.lengths - 1
    np.testing.assert_allclose(lib.get_state(np.arange(len(lib)), last / lib.fps).qpos,
                               ref.get_state(np.arange(len(ref)), last / ref.fps).qpos, atol=1e-5)


# ---------------------------------------------------------------- a cache that cannot be written
def test_read_only_cache_dir_warns_and_still_loads(tree, tmp_path, monkeypatch):
    folder = tmp_path / "readonly"
    folder.mkdir()
    folder.chmod(0o555)
    monkeypatch.setenv("SMPL_ENVS_CACHE", str(folder))
    try:
        if os.access(folder, os.W_OK):  # root ignores the mode: fail the write as a user would
            def refuse(self, path):
                raise PermissionError(13, "Permission denied", str(path))
            monkeypatch.setattr(MotionLib, "save", refuse)
        with pytest.warns(UserWarning, match="cannot be written") as record:
            lib = MotionLib.load(tree, progress=False)
    finally:
        folder.chmod(0o755)
    assert lib.names == NAMES
    assert str(folder) in str(record[0].message)
    assert not list(folder.iterdir())  # nothing half-written left behind


def test_cache_under_a_regular_file_warns_and_still_loads(tree, tmp_path, monkeypatch):
    (tmp_path / "plain_file").write_text("not a directory")
    folder = tmp_path / "plain_file" / "cache"  # unwritable for every user, root included
    monkeypatch.setenv("SMPL_ENVS_CACHE", str(folder))
    for _ in range(2):  # and again: no cache entry, so it is parsed and warns each time
        with pytest.warns(UserWarning, match="cannot be written") as record:
            lib = MotionLib.load(tree, progress=False)
        assert lib.names == NAMES
        assert str(folder) in str(record[0].message)


# ---------------------------------------------------------------- the cache keyword
def test_cache_false_neither_reads_nor_writes(tree, monkeypatch):
    lib = _quiet_load(tree, cache=False)
    assert lib.names == NAMES
    assert not cache_dir().exists()
    _quiet_load(tree)  # now a cache entry exists...
    assert len(list(cache_dir().glob("motionlib-*"))) == 1

    def no_cache(*a, **k):
        raise AssertionError("touched the cache although cache=False")

    monkeypatch.setattr(MotionLib, "_read", no_cache)
    monkeypatch.setattr(MotionLib, "save", no_cache)
    _assert_same(_quiet_load(tree, cache=False), lib)  # ...and is not used


def test_cache_path_names_the_directory(tree, tmp_path, monkeypatch):
    first = _quiet_load(tree, cache=tmp_path / "mine")
    assert len(list((tmp_path / "mine").glob("motionlib-*"))) == 1
    assert not cache_dir().exists()
    _no_parsing(monkeypatch)
    _assert_same(_quiet_load(tree, cache=str(tmp_path / "mine")), first)
    with pytest.raises(TypeError, match="cache must be"):
        MotionLib.load(tree, cache=None)


# ---------------------------------------------------------------- a damaged cache entry
def _empty(entry):
    (entry / "body_pos.npy").write_bytes(b"")


def _fewer_rows(entry):
    dof = np.load(entry / "dof_pos.npy")
    np.save(entry / "dof_pos.npy", dof[:-7])


def _cut_short(entry):
    data = (entry / "body_quat.npy").read_bytes()
    (entry / "body_quat.npy").write_bytes(data[: len(data) // 2])  # header says more than is there


def _missing(entry):
    (entry / "dof_vel.npy").unlink()


def _not_finite(entry):
    pos = np.load(entry / "body_pos.npy")
    pos[0, 0, 0] = np.nan
    np.save(entry / "body_pos.npy", pos)


def _wrong_width(entry):
    rows = len(np.load(entry / "body_pos.npy", mmap_mode="r"))
    np.save(entry / "root_ang_vel_local.npy", np.zeros((rows, 4), np.float32))


def _empty_meta(entry):
    (entry / "meta.npz").write_bytes(b"")


@pytest.mark.parametrize("damage", [_empty, _fewer_rows, _cut_short, _missing, _not_finite,
                                    _wrong_width, _empty_meta])
def test_damaged_cache_entry_is_rebuilt_with_a_warning(tree, monkeypatch, damage):
    first = _quiet_load(tree)
    (entry,) = cache_dir().glob("motionlib-*")
    damage(entry)
    with pytest.warns(UserWarning, match="damaged.*rebuilding") as record:
        rebuilt = MotionLib.load(tree, progress=False)
    assert str(entry) in str(record[0].message)
    _assert_same(rebuilt, first)
    _no_parsing(monkeypatch)  # the rebuilt entry is good again: the next load comes from it
    _assert_same(_quiet_load(tree), first)


def test_damaged_saved_library_names_itself(tmp_path):
    MotionLib.load(["walk", "run"]).save(tmp_path / "mylib")
    _fewer_rows(tmp_path / "mylib")
    with pytest.raises(MotionFileError, match=r"mylib: dof_pos.npy holds .*, expected float32"):
        MotionLib.load(tmp_path / "mylib")
    _empty(tmp_path / "mylib")
    with pytest.raises(MotionFileError, match=r"mylib: body_pos.npy cannot be read"):
        MotionLib.load(tmp_path / "mylib")


def test_failed_save_leaves_nothing_behind(tmp_path, monkeypatch):
    lib = MotionLib.load("walk")
    real_save, calls = np.save, []

    def disk_full(*a, **k):
        calls.append(a)
        if len(calls) > 2:
            raise OSError(28, "No space left on device")
        return real_save(*a, **k)

    monkeypatch.setattr("smpl_envs.motion.library.np.save", disk_full)
    with pytest.raises(OSError, match="No space left"):
        lib.save(tmp_path / "lib")
    assert not list(tmp_path.iterdir())


# ---------------------------------------------------------------- a cached library on a device
def test_a_cached_library_goes_to_a_torch_device_as_writable_copies(tree, tmp_path):
    # A cached library is memory-mapped read-only: torch warned on every view of it, and a view
    # on the host would have written into the cache.
    torch = pytest.importorskip("torch")
    from smpl_envs.motion.library import DeviceFrames

    _quiet_load(tree, cache=tmp_path / "c")
    lib = _quiet_load(tree, cache=tmp_path / "c")
    assert not np.asarray(lib.dof_pos).flags.writeable
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        frames = DeviceFrames(lib, torch.device("cpu"))
    frames.dof_pos += 1.0
    np.testing.assert_allclose(frames.dof_pos.numpy() - 1.0, lib.dof_pos, atol=1e-6)
