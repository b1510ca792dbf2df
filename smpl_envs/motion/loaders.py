"""Readers for the motion files researchers have: AMASS .npz (SMPL / SMPL-H / SMPL-X), PHC .pkl
and the project's own .npz. Each returns `RawMotion`s in the humanoid's frames at the source rate.

Every problem with a file raises `MotionFileError` naming the file and what is wrong with it.
"""

from __future__ import annotations

import pickle
import zipfile
from pathlib import Path

import numpy as np

from ..humanoid.skeleton import MEAN_SKELETON, NUM_BODIES, SMPL_JOINT_OF_BODY, SMPL_TO_BODY_FRAME, Skeleton
from ..rotations import quat_from_matrix, quat_from_rotvec, quat_inv, quat_mul
from .motion import FORMAT_NAME, FORMAT_VERSION, RawMotion

MOTION_SUFFIXES = (".npz", ".pkl")
_M = SMPL_TO_BODY_FRAME
_FRAME_QUAT = quat_from_matrix(_M)  # rotation taking SMPL-frame vectors to body-frame vectors
_POSE_WIDTHS = {72: "SMPL", 156: "SMPL-H", 165: "SMPL-X", 66: "body joints only"}  # AMASS 'poses'


class MotionFileError(ValueError):
    """A motion file that cannot be used: `path` and `reason` say which and why."""

    def __init__(self, path, reason: str):
        self.path, self.reason = str(path), reason
        super().__init__(f"{path}: {reason}")


class ShapeOnlyFile(MotionFileError):
    """An AMASS body-shape file (betas, no poses): not a motion, skipped when loading trees."""


def smpl_pose_to_local_quat(pose_aa: np.ndarray) -> np.ndarray:
    """SMPL axis-angle pose (T, J, 3) in SMPL joint order, J = 22 or 24, to local rotations
    (T, 24, 4) in BODY_NAMES order and body frames. Missing hand joints (22, 23) get identity.

    A local rotation L in SMPL's frame is M L M^T in the body frame (M = SMPL_TO_BODY_FRAME); the
    pelvis' global rotation G (SMPL frame -> world) becomes G M^T.
    """
    t, j = pose_aa.shape[:2]
    full = np.zeros((t, 24, 3))
    full[:, :j] = pose_aa
    q_smpl = quat_from_rotvec(full[:, SMPL_JOINT_OF_BODY])  # (T, 24, 4), body order
    conj = np.broadcast_to(_FRAME_QUAT, q_smpl.shape)
    inv = quat_inv(conj)
    local = quat_mul(quat_mul(conj, q_smpl), inv)
    local[:, 0] = quat_mul(q_smpl[:, 0], inv[:, 0])
    return local


def _as_str(value, default: str = "neutral") -> str:
    if value is None:
        return default
    value = np.asarray(value)
    if value.dtype.kind == "S":
        value = value.astype(str)
    s = str(value.item() if value.ndim == 0 else value.ravel()[0]) if value.size else default
    return s.strip().lower() or default


def _check(path, name: str, value, *tails: tuple[int, ...], labels: tuple[str, ...] = ()) -> np.ndarray:
    """A per-frame array (T, *tail) for one of `tails`, with T >= 1 frames, numeric and finite.
    `labels` name what each tail means (e.g. "SMPL") in the error message."""
    try:
        arr = np.asarray(value)
    except ValueError:  # ragged nested lists
        raise MotionFileError(path, f"'{name}' is not a rectangular array") from None
    if arr.dtype.kind not in "fiu":
        raise MotionFileError(path, f"'{name}' must be numeric, got dtype {arr.dtype}")
    shapes = ["(T, " + ", ".join(map(str, t)) + ")" for t in tails]
    if labels:
        shapes = [f"{s} for {label}" for s, label in zip(shapes, labels)]
    want = shapes[0] if len(shapes) == 1 else ", ".join(shapes[:-1]) + " or " + shapes[-1]
    if arr.ndim == 0 or arr.shape[1:] not in tails:
        raise MotionFileError(path, f"'{name}' has shape {arr.shape}, expected {want}")
    if len(arr) == 0:
        raise MotionFileError(path, f"'{name}' has no frames (shape {arr.shape}); expected {want} "
                                    "with T >= 1")
    if not np.all(np.isfinite(arr)):
        bad = np.argwhere(~np.isfinite(arr.reshape(len(arr), -1)))[0, 0]
        raise MotionFileError(path, f"'{name}' contains NaN or inf (first at frame {bad})")
    return arr.astype(np.float64)


def _betas(path, name: str, value) -> np.ndarray:
    try:
        return np.asarray(value, float).ravel()
    except (TypeError, ValueError):
        raise MotionFileError(path, f"'{name}' must be body shape coefficients (numbers)") from None


def _check_fps(path, fps) -> float:
    try:
        fps = float(np.asarray(fps).item())
    except (TypeError, ValueError):
        raise MotionFileError(path, f"frame rate {fps!r} is not a number") from None
    if not np.isfinite(fps) or fps <= 0:
        raise MotionFileError(path, f"frame rate must be positive, got {fps}")
    return fps


def _from_smpl_pose(path, name, pose, pelvis, fps, betas, gender) -> RawMotion:
    if len(pelvis) != len(pose):
        raise MotionFileError(path, f"{len(pose)} pose frames but {len(pelvis)} translation frames")
    return RawMotion(name, fps, pelvis, smpl_pose_to_local_quat(pose.reshape(len(pose), -1, 3)),
                     betas, gender, str(path))


def _read_amass(path, data, skeleton: Skeleton) -> RawMotion:
    if "poses" in data:
        poses = _check(path, "poses", data["poses"], *[(w,) for w in _POSE_WIDTHS],
                       labels=tuple(_POSE_WIDTHS.values()))
    elif "root_orient" in data and "pose_body" in data:  # SMPL-X "neutral" release layout
        poses = np.concatenate([_check(path, "root_orient", data["root_orient"], (3,)),
                                _check(path, "pose_body", data["pose_body"], (63,))], 1)
    else:
        raise MotionFileError(path, "AMASS file without 'poses'")
    # SMPL-H / SMPL-X: only root + 21 body joints (66 columns) are used; hands are not simulated.
    pose = poses if poses.shape[1] == 72 else poses[:, :66]
    if "trans" not in data:
        raise MotionFileError(path, "AMASS file without 'trans'")
    trans = _check(path, "trans", data["trans"], (3,))
    fps_key = next((k for k in ("mocap_framerate", "mocap_frame_rate", "fps") if k in data), None)
    if fps_key is None:
        raise MotionFileError(path, "no frame rate ('mocap_framerate' or 'mocap_frame_rate')")
    betas = _betas(path, "betas", data["betas"]) if "betas" in data else None
    # SMPL rotates the body about its rest pelvis joint, so the pelvis sits at trans + J0.
    pelvis = trans + skeleton.pelvis_smpl
    return _from_smpl_pose(path, Path(path).stem, pose, pelvis, _check_fps(path, data[fps_key]),
                           betas, _as_str(data["gender"] if "gender" in data else None))


def _read_own(path, data) -> RawMotion:
    version = int(np.asarray(data["version"]).item()) if "version" in data else 0
    if version > FORMAT_VERSION:
        raise MotionFileError(path, f"format version {version} is newer than this smpl_envs reads "
                                    f"({FORMAT_VERSION}); upgrade smpl_envs")
    for key in ("fps", "root_pos", "local_quat"):
        if key not in data:
            raise MotionFileError(path, f"missing '{key}'")
    root = _check(path, "root_pos", data["root_pos"], (3,))
    quat = _check(path, "local_quat", data["local_quat"], (NUM_BODIES, 4))
    if len(root) != len(quat):
        raise MotionFileError(path, f"{len(root)} root frames but {len(quat)} rotation frames")
    norms = np.linalg.norm(quat, axis=-1)
    if np.any(np.abs(norms - 1) > 1e-3):
        raise MotionFileError(path, "'local_quat' holds quaternions that are not unit length")
    name = str(data["name"]) if "name" in data else Path(path).stem
    betas = _betas(path, "betas", data["betas"]) if "betas" in data else None
    return RawMotion(name, _check_fps(path, data["fps"]), root, quat / norms[..., None], betas,
                     _as_str(data["gender"] if "gender" in data else None), str(path))


def _read_npz(path, skeleton: Skeleton) -> list[RawMotion]:
    if not zipfile.is_zipfile(path):
        raise MotionFileError(path, "not a .npz file (no zip archive inside; truncated or mislabelled?)")
    try:
        with np.load(path, allow_pickle=False) as npz:
            data = {k: npz[k] for k in npz.files}
    except (zipfile.BadZipFile, OSError, EOFError) as e:
        raise MotionFileError(path, f"not a readable .npz file ({e})") from None
    except ValueError as e:  # object arrays need pickle, which a motion file has no need for
        raise MotionFileError(path, f"unsupported .npz content ({e})") from None
    if "format" in data and str(data["format"]) == FORMAT_NAME:
        return [_read_own(path, data)]
    if "poses" in data or "pose_body" in data:
        return [_read_amass(path, data, skeleton)]
    if "betas" in data:
        raise ShapeOnlyFile(path, "body-shape file without poses (AMASS shape.npz)")
    raise MotionFileError(path, f"unrecognised .npz layout; keys: {sorted(data)}")


def _read_phc_sequence(path, name, seq, skeleton: Skeleton) -> RawMotion:
    if not isinstance(seq, dict) or "pose_aa" not in seq:
        raise MotionFileError(path, f"sequence {name!r} has no 'pose_aa'")
    pose = _check(path, f"{name}.pose_aa", seq["pose_aa"], (72,), (24, 3))
    pose = pose.reshape(len(pose), 72)
    if "root_trans_offset" in seq:  # already the pelvis position
        pelvis = _check(path, f"{name}.root_trans_offset", seq["root_trans_offset"], (3,))
    elif "trans" in seq:
        pelvis = _check(path, f"{name}.trans", seq["trans"], (3,)) + skeleton.pelvis_smpl
    else:
        raise MotionFileError(path, f"sequence {name!r} has neither 'root_trans_offset' nor 'trans'")
    betas = _betas(path, f"{name}.beta", seq["beta"]) if "beta" in seq else None
    return _from_smpl_pose(path, name, pose, pelvis, _check_fps(path, seq.get("fps", 30)), betas,
                           _as_str(seq.get("gender")))


def _read_pkl(path, skeleton: Skeleton) -> list[RawMotion]:
    import joblib  # PHC writes its motion files with joblib (plain pickle is read too)

    try:
        data = joblib.load(path)
    except (pickle.UnpicklingError, EOFError, ValueError, OSError, KeyError, IndexError) as e:
        raise MotionFileError(path, f"not a readable pickle ({type(e).__name__}: {e})") from None
    if isinstance(data, dict) and "pose_aa" in data:
        return [_read_phc_sequence(path, Path(path).stem, data, skeleton)]
    if isinstance(data, dict) and data and all(isinstance(v, dict) for v in data.values()):
        return [_read_phc_sequence(path, str(k), v, skeleton) for k, v in data.items()]
    raise MotionFileError(path, "unrecognised .pkl layout: expected a PHC motion dict "
                                "(name -> {'pose_aa', 'trans' or 'root_trans_offset', 'fps'})")


def read_motion_file(path: str | Path, skeleton: Skeleton = MEAN_SKELETON) -> list[RawMotion]:
    """All clips in one file, at the file's own frame rate."""
    path = Path(path)
    if not path.is_file():
        raise MotionFileError(path, "no such file")
    if path.suffix == ".npz":
        return _read_npz(path, skeleton)
    if path.suffix == ".pkl":
        return _read_pkl(path, skeleton)
    raise MotionFileError(path, f"unknown motion file type {path.suffix!r}; expected .npz or .pkl")
