"""The two sources of video input, resolved into one `VideoLib`: clips of the suite degraded by
the estimator model (`motion.estimator_noise`), or real estimator output
(`motion.estimator_files`). What `SMPL/VideoPose-v0` and its evaluation call.
"""

from __future__ import annotations

import functools
import os
from pathlib import Path

from .motion.estimator_files import load_estimator_output
from .motion.estimator_noise import EstimatorNoise, check_scale_range, degrade_library
from .motion.library import MotionLib
from .motion.video_input import VideoInput, VideoLib

ESTIMATOR_SUFFIXES = (".npz", ".pkl", ".json")


def video_library(motions=None, video=None, *, noise=None, noise_scale: float = 1.0, noise_seed: int = 0,
                  noise_scale_range: tuple[float, float] | None = None, cache: bool = True,
                  progress: bool = False) -> VideoLib:
    """A VideoLib from exactly one of
    - `motions`: clips (a shipped clip name, a corpus name, files, a directory, a list, a
      MotionLib) degraded by the estimator model with `noise` (None, a dict of knobs, or an
      `EstimatorNoise`) times `noise_scale`, clip i seeded (noise_seed, i) and, with
      `noise_scale_range` (lo, hi), its noise times a scale of its own drawn in [lo, hi]; or
    - `video`: a VideoLib, a VideoInput, an estimator output file (everything in one file, see
      `load_estimator_output`), a directory of such files, or a list of VideoInputs and files.
    Neither: the shipped walk clip, degraded. A VideoLib or VideoInputs given as `motions` are
    taken as `video` (evaluations pass their input where clips go). Generated libraries of named
    motions are kept in memory for the process (training evaluates the same input again and
    again)."""
    if isinstance(motions, (VideoLib, VideoInput)) or (
            isinstance(motions, (list, tuple)) and motions and all(isinstance(m, VideoInput) for m in motions)):
        if video is not None:
            raise ValueError("give the video input once: as motions= or as video=")
        motions, video = None, motions
    if video is not None:
        if motions is not None:
            raise ValueError("give motions= (clips to degrade with the estimator model) or video= (estimator "
                             "output), not both")
        if noise is not None or noise_scale != 1.0 or noise_scale_range is not None:
            raise ValueError("noise, noise_scale and noise_scale_range shape generated input (motions=); video= is "
                             "real estimator output, used as it is")
        return _video(video)
    noise = EstimatorNoise.make(noise, noise_scale)
    scale_range = None if noise_scale_range is None else check_scale_range(noise_scale_range)
    motions = "walk" if motions is None else motions
    key = _motions_key(motions)
    if key is not None and cache:
        return _generated(key, noise, int(noise_seed), scale_range)
    return degrade_library(motions, noise, seed=int(noise_seed), scale_range=scale_range, progress=progress)


@functools.lru_cache(maxsize=8)
def _generated(key, noise: EstimatorNoise, seed: int, scale_range: tuple[float, float] | None) -> VideoLib:
    motions = list(key) if isinstance(key, tuple) else key
    return degrade_library(motions, noise, seed=seed, scale_range=scale_range)


def _motions_key(motions):
    """A hashable key of named motions (names and paths), or None (a MotionLib, which may change)."""
    if isinstance(motions, (str, os.PathLike)):
        return str(motions)
    if isinstance(motions, (list, tuple)) and all(isinstance(m, (str, os.PathLike)) for m in motions):
        return tuple(str(m) for m in motions)
    return None


def _video(video) -> VideoLib:
    if isinstance(video, VideoLib):
        return video
    items = video if isinstance(video, (list, tuple)) else [video]
    inputs = []
    for item in items:
        if isinstance(item, VideoInput):
            inputs.append(item)
        elif isinstance(item, (str, os.PathLike)):
            path = Path(item).expanduser()
            if path.is_dir():
                files = sorted(p for p in path.iterdir() if p.suffix in ESTIMATOR_SUFFIXES and p.is_file())
                if not files:
                    raise FileNotFoundError(f"video: no estimator output files ({', '.join(ESTIMATOR_SUFFIXES)}) "
                                            f"in {path}")
                inputs += [load_estimator_output(f) for f in files]
            else:
                inputs.append(load_estimator_output(path))
        elif isinstance(item, MotionLib):
            raise ValueError("video= takes estimator output; pass clips as motions= to degrade them")
        else:
            raise ValueError(f"video= takes a VideoLib, VideoInputs or estimator output files, got {type(item).__name__}")
    return VideoLib(inputs)


__all__ = ["video_library"]
