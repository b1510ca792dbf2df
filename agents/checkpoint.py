"""Checkpoint files: one self-contained torch file per save, written atomically and checksummed.

On disk a checkpoint is a torch file holding

    {"format": CONTAINER_FORMAT, "sha256": <hex digest of payload>, "payload": <uint8 tensor>}

where `payload` holds the bytes of the `torch.save` serialisation of the agent's state dict
(whose own "format" is FORMAT). The zip container torch writes does not verify its records on
load, so without the digest a few flipped bytes in a weight or optimiser tensor load silently as
garbage numbers. The payload is a tensor rather than `bytes` because torch pickles with protocol
2, which stores bytes as a latin-1 text string: twice the size, and damage to it shows up as a
text-decoding error instead of a checksum failure.
Files written before the checksum existed (the state dict saved directly) still load, unchecked.
Both layouts load with `torch.load(..., weights_only=True)`.

A full disk (or quota) during a save is a `DiskFullError` that names the file; the file it would
have replaced is untouched and the partial temporary file removed.

Helpers for resuming after a crash: `newest_readable_checkpoint` finds the newest file of a
checkpoint directory that loads and passes its checksum; `clean_stale_temp_files` removes the
temporary files interrupted saves leave behind.
"""
from __future__ import annotations

import errno
import hashlib
import io
import os
import platform
import tempfile
import time
from pathlib import Path
from typing import Any

import torch

# The state dict an agent saves. 2: it records its policy's class and arguments (policy_class,
# policy_kwargs); 1 had none, its policy was always the actor-critic (agents.policies reads both).
FORMAT = "smpl-envs-agent/2"
READABLE_FORMATS = ("smpl-envs-agent/1", FORMAT)
CONTAINER_FORMAT = "smpl-envs-agent-sha256/1"  # the checksummed wrapper around it
# `save_checkpoint` writes `.<name>.<random>.tmp` next to `<name>` (a .pt file) before renaming.
TEMP_GLOB = ".*.pt.*.tmp"


NO_SPACE = (errno.ENOSPC, errno.EDQUOT)  # what a full disk or an exhausted quota raises


class CorruptCheckpointError(ValueError):
    """A checkpoint file that cannot be read back intact: truncated, damaged, or failing its checksum."""


class DiskFullError(OSError):
    """No space (or quota) left to save checkpoint `filename`; the file it would have replaced
    is as it was."""

    def __init__(self, code: int, path: Path, size: int):
        super().__init__(code, f"no space left on device to save {path} ({size / 1e6:.1f} MB); "
                               f"the {path.name} already there, if any, is unchanged", str(path))

    def __str__(self) -> str:
        return self.strerror


def versions() -> dict[str, str]:
    import gymnasium
    import numpy

    out = {"python": platform.python_version(), "torch": str(torch.__version__),
           "numpy": numpy.__version__, "gymnasium": gymnasium.__version__}
    try:
        from importlib.metadata import version

        out["smpl_envs"] = version("smpl-envs")
    except Exception:  # running from a source tree without installation
        out["smpl_envs"] = "unknown"
    return out


def save_checkpoint(payload: dict[str, Any], path: str | os.PathLike) -> Path:
    """Write `payload` to `path` so that a crash mid-write never leaves a truncated file:
    the bytes go to a temporary file in the same directory, are fsynced, then renamed over.
    The file records a SHA-256 of the serialised payload, which `load_checkpoint` verifies."""
    path = Path(path)
    if path.suffix != ".pt":
        path = path.with_name(path.name + ".pt")
    path.parent.mkdir(parents=True, exist_ok=True)
    # Serialise first: a payload torch cannot save fails before any file is touched.
    buffer = io.BytesIO()
    torch.save({"format": FORMAT, "versions": versions(), **payload}, buffer)
    data = buffer.getvalue()
    container = {"format": CONTAINER_FORMAT, "sha256": hashlib.sha256(data).hexdigest(),
                 "payload": torch.frombuffer(bytearray(data), dtype=torch.uint8)}
    # The file's bytes are made in memory too, so that a failing write (a full disk) surfaces as
    # the OSError itself rather than inside torch's zip writer, as chained errors and an assertion.
    buffer = io.BytesIO()
    torch.save(container, buffer)
    del data, container
    blob = buffer.getbuffer()
    tmp = None
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
        # mkstemp makes the file private (0600); give it the mode a plain open() would, so
        # checkpoints stay readable where the user's umask shares files (a cluster's group).
        os.chmod(tmp, 0o666 & ~_umask())
        with os.fdopen(fd, "wb") as f:
            f.write(blob)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException as e:
        if tmp is not None:
            Path(tmp).unlink(missing_ok=True)
        if isinstance(e, OSError) and e.errno in NO_SPACE:
            raise DiskFullError(e.errno, path, len(blob)) from None
        raise
    _fsync_dir(path.parent)
    return path


def _umask() -> int:
    mask = os.umask(0)  # reading the umask means setting it; put it straight back
    os.umask(mask)
    return mask


def _fsync_dir(directory: Path) -> None:
    # The rename itself lives in the directory entry; without this a power cut can undo it.
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:  # platforms (Windows) that cannot open directories
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def load_checkpoint(path: str | os.PathLike, device: str | torch.device = "cpu") -> dict[str, Any]:
    """The state dict `save_checkpoint` wrote to `path`, tensors on `device`.

    Raises FileNotFoundError when there is no file, CorruptCheckpointError (a ValueError) when the
    file is truncated, damaged or fails its checksum, and ValueError when it is some other file."""
    path = Path(path)
    if not path.exists() and path.with_name(path.name + ".pt").exists():
        path = path.with_name(path.name + ".pt")
    if not path.is_file():
        raise FileNotFoundError(f"no checkpoint at {path}")
    # Checkpoints hold only tensors and plain Python data, so the safe loader suffices.
    # The container is read onto the CPU (its payload is raw bytes); the state dict onto `device`.
    ckpt = _torch_load(path, path, "cpu")
    if isinstance(ckpt, dict) and ckpt.get("format") == CONTAINER_FORMAT:
        payload, digest = ckpt.get("payload"), ckpt.get("sha256")
        if not (isinstance(payload, torch.Tensor) and payload.dtype == torch.uint8 and isinstance(digest, str)):
            raise CorruptCheckpointError(f"{path} is corrupt: its payload or checksum is missing")
        data = payload.numpy().tobytes()
        actual = hashlib.sha256(data).hexdigest()
        if actual != digest:
            raise CorruptCheckpointError(f"{path} is corrupt: its payload fails its SHA-256 checksum "
                                         f"(recorded {digest[:12]}..., computed {actual[:12]}...)")
        ckpt = _torch_load(io.BytesIO(data), path, device)
    elif str(device) != "cpu":
        ckpt = _torch_load(path, path, device)  # an unchecked old file: read again onto the device
    # Otherwise a file from before checksums, or not ours at all: the format test below decides.
    found = ckpt.get("format") if isinstance(ckpt, dict) else None
    if found not in READABLE_FORMATS:
        if isinstance(found, str) and found.startswith(FORMAT.split("/")[0] + "/"):
            raise ValueError(f"{path} is a smpl-envs agent checkpoint of format {found!r}, from a newer version; this "
                             f"one reads {', '.join(READABLE_FORMATS)}")
        raise ValueError(f"{path} is not a smpl-envs agent checkpoint (format {FORMAT!r})")
    return ckpt


def _torch_load(source, path: Path, device) -> Any:
    try:
        return torch.load(source, map_location=device, weights_only=True)
    except Exception as e:
        raise CorruptCheckpointError(f"{path} is not a readable smpl-envs checkpoint "
                                     f"(truncated or corrupt?): {e}") from e


def newest_readable_checkpoint(directory: str | os.PathLike) -> tuple[Path | None, list[tuple[Path, str]]]:
    """(path, skipped): the first of `directory`/last.pt, then its numbered ckpt_*.pt newest
    first, that loads and passes its checksum; `skipped` lists the (path, reason) of the files
    tried before it. path is None when no file qualifies (skipped then says why)."""
    directory = Path(directory)
    # Numbered checkpoints carry zero-padded step counts, so name order is step order.
    candidates = [directory / "last.pt"] + sorted(directory.glob("ckpt_*.pt"), reverse=True)
    skipped: list[tuple[Path, str]] = []
    for candidate in candidates:
        if not candidate.is_file():
            continue
        try:
            load_checkpoint(candidate, "cpu")
        except (ValueError, OSError, EOFError) as e:
            skipped.append((candidate, str(e)))
            continue
        return candidate, skipped
    return None, skipped


def clean_stale_temp_files(directory: str | os.PathLike, min_age_s: float = 0.0) -> list[Path]:
    """Delete the temporary files interrupted saves left in `directory` and return their paths.
    Files younger than `min_age_s` seconds are kept, in case another process is saving now."""
    directory = Path(directory)
    if not directory.is_dir():
        return []
    now, removed = time.time(), []
    for tmp in sorted(directory.glob(TEMP_GLOB)):
        try:
            if not tmp.is_file() or now - tmp.stat().st_mtime < min_age_s:
                continue
            tmp.unlink()
        except FileNotFoundError:  # a save finished (renamed it) or another cleaner won the race
            continue
        removed.append(tmp)
    return removed


__all__ = ["FORMAT", "READABLE_FORMATS", "CONTAINER_FORMAT", "NO_SPACE", "CorruptCheckpointError", "DiskFullError", "save_checkpoint",
           "load_checkpoint", "newest_readable_checkpoint", "clean_stale_temp_files", "versions"]
