"""MotionLib: many reference clips in one set of arrays, looked up in batches.

Clips are concatenated along the frame axis; `get_state(motion_ids, times)` gathers and
interpolates the reference of N environments in one call. Loading a tree of motion files reports
every bad file by name and reason and keeps the rest; the parsed clips are cached as a saved
library (a directory of .npy files) so that a second load of the same tree skips parsing entirely.
The cache only ever speeds loading up: an unwritable cache warns, a damaged entry is rebuilt.
"""

from __future__ import annotations

import hashlib
import copy
import os
import shutil
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Sequence

import numpy as np

from ..features import BodyState, amp_features, rotmat_from_quat, xp
from ..humanoid.skeleton import MEAN_SKELETON, NUM_BODIES, NUM_HINGES, PARENTS, Skeleton
from ..progress import pbar
from ..rotations import quat_apply, quat_inv, quat_mul, quat_slerp, yaw_quat
from .kinematics import Segments
from .loaders import MOTION_SUFFIXES, MotionFileError, ShapeOnlyFile, read_motion_file
from .motion import FPS, Motion, RawMotion, derive_fields

LIBRARY_FORMAT = "smpl_envs.motionlib"
LIBRARY_VERSION = 1
CLIPS_DIR = Path(__file__).parent / "clips"


def available_clips() -> list[str]:
    """Names of the synthetic clips shipped with the package (usable wherever a path is)."""
    return sorted(p.stem for p in CLIPS_DIR.glob("*.npz"))


def is_clip_name(source: str | os.PathLike) -> bool:
    """Whether `source` names a shipped clip rather than a path (see `resolve_clip`)."""
    if not isinstance(source, str):
        return False  # a Path object is a path even when it has a single part
    return not (any(sep in source for sep in "/\\") or source.startswith((".", "~"))
                or Path(source).suffix)


def resolve_clip(name_or_path: str | os.PathLike) -> Path:
    """The file or directory a motion source means.

    A bare name -- a string with no path separator and no file extension, not starting with "."
    or "~", such as "walk" -- is always the shipped clip of that name, whatever files or folders
    of that name exist in the current directory. Anything else is a path: "./walk",
    "data/x.npz", "~/amass", "clip.pkl", or any `pathlib.Path`. To load a local folder whose name
    looks like a clip name, write it as a path ("./walk").
    """
    if is_clip_name(name_or_path):
        shipped = CLIPS_DIR / f"{name_or_path}.npz"
        if shipped.is_file():
            return shipped
        raise FileNotFoundError(f"{name_or_path!r} is not a shipped clip (shipped clips: "
                                f"{available_clips()}); write a path such as ./{name_or_path} "
                                "to load a file or directory")
    path = Path(name_or_path).expanduser()
    if not path.exists():
        raise FileNotFoundError(f"{str(name_or_path)!r}: no such file or directory")
    return path


def load_motion(path_or_name: str | os.PathLike, skeleton: Skeleton = MEAN_SKELETON,
                ground: bool = True) -> Motion:
    """One clip at 30 fps from a file (AMASS .npz, PHC .pkl, own .npz) or a shipped clip's name
    (a bare name such as "walk" is always a shipped clip; see `resolve_clip`).

    `skeleton` is the body the motion is retargeted to (bone lengths, pelvis offset); the default
    is the mean shape, whatever betas the file carries (they are kept in `Motion.betas`).
    """
    raws = read_motion_file(resolve_clip(path_or_name), skeleton)
    if len(raws) != 1:
        raise MotionFileError(path_or_name, f"holds {len(raws)} sequences; load it with MotionLib.load")
    return Motion.from_raw(raws[0], skeleton, ground)


def load_motions(motions: str | os.PathLike | list | MotionLib, progress: bool = False,
                 cache: bool = True) -> MotionLib:
    """A MotionLib from what a user passes as `motions=`: a shipped clip name, a motion file, a
    directory tree, a saved (cached) library, a list of those, or a MotionLib. `cache`: the
    MotionLib's disk cache (True, a directory, or False for none)."""
    lib = motions if isinstance(motions, MotionLib) else MotionLib.load(motions, progress=progress, cache=cache)
    short = [lib.names[i] for i in np.flatnonzero(lib.lengths < 2)]
    if short:
        raise ValueError(f"motions: clips need at least 2 frames; too short: {short[:5]}"
                         + (f" and {len(short) - 5} more" if len(short) > 5 else ""))
    return lib


@dataclass
class MotionState:
    """Reference of N environments at one instant; arrays (N, ...) as in `Motion`."""

    body_pos: np.ndarray
    body_quat: np.ndarray
    body_lin_vel: np.ndarray
    body_ang_vel: np.ndarray
    dof_pos: np.ndarray
    dof_vel: np.ndarray
    qpos: np.ndarray
    qvel: np.ndarray


class MotionLib:
    """Reference motions for batched environments.

    Build one with `MotionLib.load(source)` where source is a shipped clip name, a motion file, a
    directory tree (searched recursively), a saved library (the directory `save` writes), or a
    list of these; or directly from `Motion` / `RawMotion` objects.

    Arrays (F = total frames, float32): body_pos (F, 24, 3), body_quat (F, 24, 4), body_lin_vel,
    body_ang_vel (F, 24, 3, world frame), dof_pos, dof_vel (F, 69), root_ang_vel_local (F, 3);
    per clip: names, lengths (frames), starts, durations (s), sources, weights, yaw.
    """

    def __init__(
        self,
        motions: Sequence[Motion | RawMotion],
        skeleton: Skeleton = MEAN_SKELETON,
        *,
        random_yaw: bool = False,
        seed: int | None = None,
        ground: bool = True,
        errors: Sequence[tuple[str, str]] = (),
    ):
        if not motions:
            raise ValueError("MotionLib needs at least one motion" + (
                f"; every file failed, e.g. {errors[0][0]}: {errors[0][1]}" if errors else ""))
        raws = [(m.raw() if isinstance(m, Motion) else m).resampled(FPS) for m in motions]
        meta = dict(names=[r.name for r in raws], sources=[r.source for r in raws],
                    betas=[r.betas for r in raws], genders=[r.gender for r in raws],
                    lengths=np.array([r.num_frames for r in raws]), errors=list(errors))
        self._init(skeleton, meta, _derive_chunked(raws, skeleton, ground))
        if random_yaw:
            self.randomize_yaw(seed)

    def _init(self, skeleton: Skeleton, meta: dict, arrays: dict[str, np.ndarray]) -> None:
        self.skeleton = skeleton
        self.fps = FPS
        self.names, self.sources = list(meta["names"]), list(meta["sources"])
        self.betas, self.genders = list(meta["betas"]), list(meta["genders"])
        self.errors = list(meta["errors"])
        self.seg = Segments.from_lengths(meta["lengths"])
        self.lengths, self.starts = self.seg.lengths, self.seg.starts
        self.durations = (self.lengths - 1) / self.fps
        for name in LIB_FIELDS:
            setattr(self, name, arrays[name])
        self.weights = np.full(self.num_motions, 1.0 / self.num_motions)
        self.yaw = np.zeros(self.num_motions)

    # ------------------------------------------------------------------ loading and saving
    @classmethod
    def load(
        cls,
        source: str | os.PathLike | Iterable[str | os.PathLike],
        skeleton: Skeleton = MEAN_SKELETON,
        *,
        cache: bool | str | os.PathLike = True,
        progress: bool = True,
        random_yaw: bool = False,
        seed: int | None = None,
    ) -> "MotionLib":
        """Load clips from names, files, directory trees (recursively) or saved libraries.

        A bare name ("walk": no path separator, no extension, not starting with "." or "~") is
        always a shipped clip, never a file or folder of that name in the current directory;
        anything else is a path ("./walk", "data/x.npz", "~/amass", a `pathlib.Path`). See
        `resolve_clip`.

        Files that cannot be read are skipped and listed in `.errors` as (path, reason), with one
        warning summarising them; AMASS shape-only files are skipped silently.

        cache: a directory tree given alone is cached as a saved library, keyed by every file's
        path, size and modification time and by the skeleton: an unchanged tree loads from the
        cache (memory-mapped, in about a second), a changed one is parsed again. True caches in
        `cache_dir()` ($SMPL_ENVS_CACHE), a path caches in that directory, False neither reads
        nor writes any cache. A cache that cannot be written only warns; a cache entry that does
        not validate is rebuilt, with a warning.
        """
        if not isinstance(cache, (bool, str, os.PathLike)):
            raise TypeError(f"cache must be True, False or a directory path, got {cache!r}")
        items = [source] if isinstance(source, (str, os.PathLike)) else list(source)
        if any(_is_corpus_name(item) for item in items):
            if len(items) != 1:
                raise ValueError(f"a corpus name loads alone, not in a list with other motions: {items!r}")
            lib = cls._load_corpus(items[0], skeleton, cache, progress)
            if random_yaw:
                lib.randomize_yaw(seed)
            return lib
        paths = [resolve_clip(item) for item in items]
        if len(paths) == 1 and _is_library(paths[0]):
            lib = cls._read(paths[0], skeleton)
        elif len(paths) == 1 and paths[0].is_dir():
            lib = cls._load_tree(paths[0], skeleton, cache, progress)
        else:
            raws, errors = [], []
            for path in paths:
                files = _motion_files(path) if path.is_dir() else [path]
                r, e = _load_files(files, skeleton, progress and len(files) > 1)
                raws, errors = raws + r, errors + e
            lib = cls(raws, skeleton, errors=errors)
        if lib.errors:
            shown = "\n".join(f"  {p}: {why}" for p, why in lib.errors[:10])
            more = f"\n  ... and {len(lib.errors) - 10} more" if len(lib.errors) > 10 else ""
            warnings.warn(f"{len(lib.errors)} motion file(s) could not be loaded (see MotionLib.errors):"
                          f"\n{shown}{more}", stacklevel=2)
        if random_yaw:
            lib.randomize_yaw(seed)
        return lib

    @classmethod
    def _load_tree(cls, root: Path, skeleton, cache, progress) -> "MotionLib":
        files = _motion_files(root)

        def build():
            raws, errors = _load_files(files, skeleton, progress)
            return cls(raws, skeleton, errors=errors)

        if cache is False:
            return build()
        return cls._cached(f"motionlib-{_tree_key(files, skeleton)}", cache, skeleton, build, "parsed")

    @classmethod
    def _load_corpus(cls, name: str, skeleton, cache, progress) -> "MotionLib":
        """The procedural corpus (`smpl_envs.motion.corpus`) a name such as "corpus:train"
        stands for: generated on first use and cached like a tree, its manifest (every clip's
        parameters) written beside the cached library as JSON."""
        from . import corpus  # the corpus builds on synthetic and plausibility: loaded on demand

        spec, seed = corpus.parse_seed(name)
        corpus.parse(spec)  # a bad name fails here, before anything is generated

        records = []

        def build():
            raws, made = corpus.generate(spec, seed=seed, progress=progress)
            records.extend(made)
            return cls(raws, skeleton)

        def write_manifest(target):
            corpus.write_manifest(target.with_suffix(".json"), spec, seed, records)

        if cache is False:
            return build()
        key = f"corpus-{corpus.cache_key(spec, seed)}-{_skeleton_key(skeleton)[:12]}"
        return cls._cached(key, cache, skeleton, build, "generated", after_save=write_manifest)

    @classmethod
    def _cached(cls, key: str, cache, skeleton, build, remade: str, after_save=None) -> "MotionLib":
        """The saved library `key` in the cache directory, or `build()`'s, saved there (then
        `after_save(target)`). A cache only ever speeds loading up: a damaged entry is rebuilt,
        an unwritable directory only warns."""
        folder = cache_dir() if cache is True else Path(cache).expanduser()
        target = folder / key
        if target.exists():
            try:
                return cls._read(target, skeleton)
            except Exception as e:  # a cache is never trusted: whatever is wrong, make it again
                warnings.warn(f"motion cache entry {target} is damaged ({e}); rebuilding it",
                              stacklevel=4)
        lib = build()
        try:
            lib.save(target)
            if after_save is not None:
                after_save(target)
        except OSError as e:  # the motions are loaded; only the next load's speed-up is lost
            warnings.warn(f"motion cache directory {folder} cannot be written ({e}); the motions "
                          f"will be {remade} again next time (set SMPL_ENVS_CACHE or pass cache= "
                          "to use another directory, cache=False to stop caching)", stacklevel=4)
        return lib

    def save(self, path: str | os.PathLike) -> None:
        """Write the library (as loaded, before any yaw) to a directory that `load` reads back
        memory-mapped. Atomic: the directory appears complete or not at all."""
        path = Path(path)
        tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
        shutil.rmtree(tmp, ignore_errors=True)
        tmp.mkdir(parents=True)
        try:
            self._write(tmp)
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)  # no half-written directory left behind
            raise
        if path.exists():
            shutil.rmtree(path)
        os.replace(tmp, path)

    def _write(self, tmp: Path) -> None:
        lib = self if not np.any(self.yaw) else self._rotated_copy(-self.yaw)
        for name in LIB_FIELDS:
            np.save(tmp / f"{name}.npy", getattr(lib, name))
        betas = [np.zeros(0) if b is None else np.asarray(b, float).ravel() for b in self.betas]
        np.savez(tmp / "meta.npz", format=LIBRARY_FORMAT, version=LIBRARY_VERSION,
                 names=np.array(self.names, dtype=str), sources=np.array(self.sources, dtype=str),
                 genders=np.array(self.genders, dtype=str), lengths=self.lengths,
                 skeleton_key=_skeleton_key(self.skeleton),
                 betas=np.concatenate(betas), betas_lengths=np.array([len(b) for b in betas]),
                 error_paths=np.array([p for p, _ in self.errors], dtype=str),
                 error_reasons=np.array([w for _, w in self.errors], dtype=str))

    @classmethod
    def _read(cls, path: Path, skeleton: Skeleton) -> "MotionLib":
        with np.load(path / "meta.npz", allow_pickle=False) as z:
            if str(z["format"]) != LIBRARY_FORMAT:
                raise MotionFileError(path, "not a saved MotionLib")
            if int(z["version"]) > LIBRARY_VERSION:
                raise ValueError(f"{path}: library written by a newer smpl_envs")
            if str(z["skeleton_key"]) != _skeleton_key(skeleton):
                raise ValueError(f"{path}: library was built for another skeleton; load the "
                                 "motion files with this skeleton instead")
            betas = np.split(z["betas"], np.cumsum(z["betas_lengths"])[:-1])
            meta = dict(names=z["names"].tolist(), sources=z["sources"].tolist(),
                        genders=z["genders"].tolist(), lengths=z["lengths"],
                        betas=[b if len(b) else None for b in betas],
                        errors=list(zip(z["error_paths"].tolist(), z["error_reasons"].tolist())))
        arrays = {}
        for f in LIB_FIELDS:
            try:
                arrays[f] = np.load(path / f"{f}.npy", mmap_mode="r")
            except (OSError, EOFError, ValueError) as e:  # missing, empty, truncated
                raise MotionFileError(path, f"{f}.npy cannot be read ({type(e).__name__}: {e})") from None
        _validate(path, meta, arrays)
        lib = cls.__new__(cls)
        lib._init(skeleton, meta, arrays)
        return lib

    # ------------------------------------------------------------------ yaw
    def rotate_yaw(self, yaw: np.ndarray) -> None:
        """Turn clip i by yaw[i] radians about the world z axis through the origin (in place)."""
        rotated = self._rotated_copy(np.asarray(yaw, float))
        for name in LIB_FIELDS:
            setattr(self, name, getattr(rotated, name))
        self.yaw = self.yaw + yaw

    def randomize_yaw(self, seed: int | None = None) -> None:
        """Turn every clip by its own uniform random yaw (training sees all headings)."""
        self.rotate_yaw(np.random.default_rng(seed).uniform(-np.pi, np.pi, self.num_motions))

    def _rotated_copy(self, yaw: np.ndarray) -> "MotionLib":
        q = yaw_quat(yaw[self.seg.clip_of_frame])[:, None].astype(np.float32)
        out = copy.copy(self)
        out.body_pos = quat_apply(q, self.body_pos).astype(np.float32)
        out.body_quat = quat_mul(q, self.body_quat).astype(np.float32)
        out.body_lin_vel = quat_apply(q, self.body_lin_vel).astype(np.float32)
        out.body_ang_vel = quat_apply(q, self.body_ang_vel).astype(np.float32)
        return out

    # ------------------------------------------------------------------ queries
    @property
    def num_motions(self) -> int:
        return len(self.names)

    @property
    def num_frames(self) -> int:
        return self.seg.num_frames

    def __len__(self) -> int:
        return self.num_motions

    def __repr__(self) -> str:
        return (f"MotionLib({self.num_motions} motions, {self.num_frames} frames, "
                f"{self.durations.sum() / 60:.1f} min @ {self.fps:g} fps)")

    def motion(self, i: int) -> Motion:
        """Clip i as a float64 `Motion`."""
        s = slice(self.starts[i], self.starts[i] + self.lengths[i])
        f = {name: np.asarray(getattr(self, name)[s], np.float64) for name in LIB_FIELDS}
        body_quat = f["body_quat"]
        local = body_quat.copy()
        local[:, 1:] = quat_mul(quat_inv(body_quat[:, PARENTS[1:]]), body_quat[:, 1:])
        return Motion(self.names[i], self.fps, local_quat=local, body_pos=f["body_pos"],
                      body_quat=body_quat, body_lin_vel=f["body_lin_vel"],
                      body_ang_vel=f["body_ang_vel"], dof_pos=f["dof_pos"], dof_vel=f["dof_vel"],
                      qpos=_qpos(f), qvel=_qvel(f), betas=self.betas[i], gender=self.genders[i],
                      source=self.sources[i])

    def index(self, name: str) -> int:
        return self.names.index(name)

    def set_weights(self, weights: np.ndarray) -> None:
        """Sampling weights per clip (e.g. from hard-negative mining); normalised here."""
        weights = np.asarray(weights, dtype=float)
        if weights.shape != (self.num_motions,) or np.any(weights < 0) or not weights.sum() > 0:
            raise ValueError(f"weights must be {self.num_motions} non-negative numbers, not all zero")
        self.weights = weights / weights.sum()

    def sample_motions(self, n: int, rng: np.random.Generator) -> np.ndarray:
        return rng.choice(self.num_motions, size=n, p=self.weights)

    def sample_times(self, motion_ids: np.ndarray, rng: np.random.Generator,
                     truncate: float = 0.0) -> np.ndarray:
        """Uniform start times that leave at least `truncate` seconds of each clip."""
        return rng.uniform(0.0, 1.0, len(motion_ids)) * np.maximum(self.durations[motion_ids] - truncate, 0.0)

    def frame_blend(self, motion_ids: np.ndarray, times: np.ndarray):
        """Global frame indices (f0, f1) and blend weight between them; times clamp to the clip."""
        motion_ids = np.asarray(motion_ids)
        pos = np.clip(np.asarray(times, float), 0.0, self.durations[motion_ids]) * self.fps
        local0 = np.minimum(np.floor(pos).astype(np.int64), self.lengths[motion_ids] - 1)
        local1 = np.minimum(local0 + 1, self.lengths[motion_ids] - 1)
        start = self.starts[motion_ids]
        return start + local0, start + local1, (pos - local0).astype(np.float32)

    def get_state(self, motion_ids: np.ndarray, times: np.ndarray) -> MotionState:
        """Reference states at `times` (s) of clips `motion_ids`: positions, velocities and angles
        linearly interpolated, orientations slerped; qpos / qvel ready for MuJoCo."""
        f0, f1, w = self.frame_blend(motion_ids, times)

        def lerp(a):
            a0, a1 = a[f0], a[f1]
            return a0 + w.reshape(-1, *([1] * (a0.ndim - 1))) * (a1 - a0)

        f = {name: lerp(getattr(self, name)) for name in LIB_FIELDS if name != "body_quat"}
        f["body_quat"] = quat_slerp(self.body_quat[f0], self.body_quat[f1], w[:, None, None])
        return MotionState(f["body_pos"], f["body_quat"], f["body_lin_vel"], f["body_ang_vel"],
                           f["dof_pos"], f["dof_vel"], _qpos(f), _qvel(f))

    # ------------------------------------------------------------------ exact frames (env hot path)
    def body_state(self, frames: np.ndarray) -> BodyState:
        """Reference bodies at global frame indices `frames` (N,), no interpolation: the tasks
        step at the library's frame rate, so every lookup they make is an exact frame."""
        return BodyState(pos=self.body_pos[frames], rot=rotmat_from_quat(self.body_quat[frames]),
                         lin_vel=self.body_lin_vel[frames], ang_vel=self.body_ang_vel[frames],
                         dof_pos=self.dof_pos[frames], dof_vel=self.dof_vel[frames])

    def qpos_qvel(self, frames: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """MuJoCo (qpos, qvel) of global frame indices `frames`, for reference state init."""
        f = {name: getattr(self, name)[frames] for name in LIB_FIELDS}
        return _qpos(f), _qvel(f)

    def amp_features(self, motion_ids: np.ndarray, times: np.ndarray, num_frames: int = 10) -> np.ndarray:
        """Discriminator features of the reference: (N, num_frames, 232), frames spaced 1/fps and
        ending at `times`, built by the same function the environments use for the humanoid."""
        motion_ids = np.asarray(motion_ids)
        n = len(motion_ids)
        offsets = (np.arange(num_frames) - (num_frames - 1)) / self.fps
        t = (np.asarray(times, float)[:, None] + offsets).ravel()
        st = self.get_state(np.repeat(motion_ids, num_frames), t)
        state = BodyState(pos=st.body_pos, rot=rotmat_from_quat(st.body_quat), lin_vel=st.body_lin_vel,
                          ang_vel=st.body_ang_vel, dof_pos=st.dof_pos, dof_vel=st.dof_vel)
        return amp_features(state).astype(np.float32).reshape(n, num_frames, -1)


# What a library stores per frame; qpos / qvel / local rotations are assembled from these.
LIB_FIELDS = ("body_pos", "body_quat", "body_lin_vel", "body_ang_vel", "dof_pos", "dof_vel",
              "root_ang_vel_local")
_CHUNK_FRAMES = 200_000  # bounds the float64 temporaries of derivation to a few hundred MB
# Trailing shape of each stored field (rows are frames).
_FIELD_SHAPES = {"body_pos": (NUM_BODIES, 3), "body_quat": (NUM_BODIES, 4),
                 "body_lin_vel": (NUM_BODIES, 3), "body_ang_vel": (NUM_BODIES, 3),
                 "dof_pos": (NUM_HINGES,), "dof_vel": (NUM_HINGES,), "root_ang_vel_local": (3,)}


def _validate(path: Path, meta: dict, arrays: dict[str, np.ndarray]) -> None:
    """Check a saved library against its own metadata, so that a damaged one fails here, by
    name, and not later as an IndexError in get_state or a silently wrong reference."""
    lengths = np.asarray(meta["lengths"])
    counts = {len(meta[k]) for k in ("names", "sources", "genders", "betas")}
    if lengths.ndim != 1 or counts != {len(lengths)} or not len(lengths) or np.any(lengths < 1):
        raise MotionFileError(path, "meta.npz lists inconsistent clips")
    frames = int(lengths.sum())
    for name in LIB_FIELDS:
        a, tail = arrays[name], _FIELD_SHAPES[name]
        if a.shape != (frames, *tail) or a.dtype != np.float32:
            raise MotionFileError(path, f"{name}.npy holds {a.dtype} {a.shape}, expected "
                                        f"float32 {(frames, *tail)}")
    # Finiteness is checked on every clip's first and last frame only: reading every frame
    # would cost the memory-mapped load its speed on large trees.
    starts = np.concatenate([[0], np.cumsum(lengths)[:-1]])
    edges = np.concatenate([starts, starts + lengths - 1])
    for name in LIB_FIELDS:
        if not np.all(np.isfinite(arrays[name][edges])):
            raise MotionFileError(path, f"{name}.npy contains NaN or inf")


def _qpos(f: dict) -> np.ndarray:
    return xp(f["dof_pos"]).concatenate([f["body_pos"][:, 0], f["body_quat"][:, 0], f["dof_pos"]], -1)


def _qvel(f: dict) -> np.ndarray:
    return xp(f["dof_vel"]).concatenate([f["body_lin_vel"][:, 0], f["root_ang_vel_local"], f["dof_vel"]], -1)


class DeviceFrames:
    """A MotionLib's per-frame arrays as torch tensors on `device`: what an env on the MuJoCo
    Warp backend reads every step (exact-frame body states, start states, clip bounds), with the
    same `body_state` and `qpos_qvel` as the library (one implementation: they only index arrays
    and call functions written for NumPy and torch alike). Clip names, weights and everything
    else stay on the host library, `lib`. A subclass sets `fields` (and `dtype`) for another
    kind of library (`three_point.DeviceStreams`)."""

    fields: tuple[str, ...] = LIB_FIELDS
    dtype = None  # None: the library's own (float32)
    body_state = MotionLib.body_state
    qpos_qvel = MotionLib.qpos_qvel

    def __init__(self, lib, device):
        import torch

        self.lib, self.fps, self.num_motions = lib, lib.fps, lib.num_motions
        dtype = getattr(torch, self.dtype) if self.dtype else None
        for name in self.fields:  # copies: a cached library's arrays are read-only memory maps
            setattr(self, name, torch.tensor(getattr(lib, name), dtype=dtype, device=device))
        self.starts = torch.as_tensor(lib.starts, dtype=torch.int64, device=device)
        self.lengths = torch.as_tensor(lib.lengths, dtype=torch.int64, device=device)

    @property
    def weights(self) -> np.ndarray:
        return self.lib.weights  # the host library's, so `lib.set_weights` is seen at once


def _derive_chunked(raws: list[RawMotion], skeleton: Skeleton, ground: bool) -> dict[str, np.ndarray]:
    lengths = np.array([r.num_frames for r in raws])
    total = int(lengths.sum())
    out = None
    bounds = np.concatenate([[0], np.cumsum(lengths)])
    chunk_of_clip = bounds[:-1] // _CHUNK_FRAMES
    for c in np.unique(chunk_of_clip):
        clips = np.flatnonzero(chunk_of_clip == c)
        seg = Segments.from_lengths(lengths[clips])
        f = derive_fields(np.concatenate([raws[i].root_pos for i in clips]),
                          np.concatenate([raws[i].local_quat for i in clips]), seg, FPS,
                          skeleton, ground)
        f["root_ang_vel_local"] = f["qvel"][:, 3:6]
        if out is None:
            out = {n: np.empty((total,) + f[n].shape[1:], np.float32) for n in LIB_FIELDS}
        rows = slice(bounds[clips[0]], bounds[clips[-1] + 1])
        for n in LIB_FIELDS:
            out[n][rows] = f[n]
    return out


# ---------------------------------------------------------------------- files and the cache
def cache_dir() -> Path:
    """Where parsed trees are cached: $SMPL_ENVS_CACHE, else ~/.cache/smpl_envs."""
    return Path(os.environ.get("SMPL_ENVS_CACHE", Path.home() / ".cache" / "smpl_envs"))


def _load_files(paths, skeleton, progress) -> tuple[list[RawMotion], list[tuple[str, str]]]:
    raws, errors = [], []
    for path in pbar(paths, desc="Loading motions", unit="file", disable=not progress):
        try:
            raws += [r.resampled(FPS) for r in read_motion_file(path, skeleton)]
        except ShapeOnlyFile:
            continue
        except MotionFileError as e:
            errors.append((e.path, e.reason))
        except Exception as e:  # one odd file must not cost the user the other ten thousand
            errors.append((str(path), f"{type(e).__name__}: {e}"))
    return raws, errors


def _skeleton_key(skeleton: Skeleton) -> str:
    h = hashlib.sha1(np.asarray(skeleton.offsets, float).tobytes())
    h.update(np.asarray(skeleton.pelvis_smpl, float).tobytes())
    for g in skeleton.geoms:  # geometry decides where the ground is
        h.update(repr((g.kind, g.size, g.pos, g.fromto)).encode())
    return h.hexdigest()[:16]


def _tree_key(files: list[Path], skeleton: Skeleton) -> str:
    h = hashlib.sha1(f"{LIBRARY_FORMAT}/{LIBRARY_VERSION}/{_skeleton_key(skeleton)}".encode())
    for f in files:
        st = f.stat()
        h.update(f"{f.resolve()}|{st.st_size}|{st.st_mtime_ns}\n".encode())
    return h.hexdigest()[:20]


def _motion_files(root: Path) -> list[Path]:
    files = sorted(p for p in root.rglob("*") if p.suffix in MOTION_SUFFIXES and p.is_file())
    if not files:
        raise FileNotFoundError(f"no .npz or .pkl motion files under {root}")
    return files


def _is_corpus_name(item) -> bool:
    return isinstance(item, str) and item.startswith("corpus:")


def _is_library(path: Path) -> bool:
    meta = path / "meta.npz"
    if not meta.is_file():
        return False
    try:
        with np.load(meta, allow_pickle=False) as z:
            return str(z["format"]) == LIBRARY_FORMAT
    except Exception:
        return False
