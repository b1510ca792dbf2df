"""Motion loading speed: parsing a tree of AMASS-format files, reloading it from the cache, and
batched reference lookups.

    python benchmarks/bench_loading.py                 # 10,000 clips of 2 s at 60 fps
    python benchmarks/bench_loading.py --clips 1000    # quicker

The tree is generated from the shipped clips (cut into pieces, turned, written in AMASS layout)
in a temporary directory; nothing is downloaded. Reload and lookup times are medians of repeats.
"""

from __future__ import annotations

import argparse
import json
import statistics
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

from smpl_envs.humanoid.skeleton import MEAN_PELVIS_SMPL
from smpl_envs.motion import MotionLib, available_clips, load_motion
from smpl_envs.motion.export import local_quat_to_smpl_pose
from smpl_envs.progress import pbar


def make_tree(root: Path, clips: int, seconds: float, fps: float, seed: int = 0) -> None:
    """`clips` AMASS-layout files (SMPL-H poses, float32 like many AMASS releases)."""
    rng = np.random.default_rng(seed)
    sources = [load_motion(n).raw().resampled(fps) for n in available_clips()]
    n = int(seconds * fps) + 1
    for i in pbar(range(clips), desc="Writing AMASS-format tree", unit="file"):
        src = sources[i % len(sources)]
        start = rng.integers(0, max(src.num_frames - n, 1))
        piece = src.rotated_yaw(rng.uniform(-np.pi, np.pi))
        sl = slice(start, start + n)
        poses = np.zeros((len(piece.root_pos[sl]), 156), np.float32)
        poses[:, :66] = local_quat_to_smpl_pose(piece.local_quat[sl])[:, :66]
        folder = root / f"subject{i // 100:03d}"
        folder.mkdir(parents=True, exist_ok=True)
        np.savez(folder / f"clip{i:05d}_poses.npz", poses=poses,
                 trans=(piece.root_pos[sl] - MEAN_PELVIS_SMPL).astype(np.float32),
                 betas=np.zeros(16, np.float32), gender="neutral", mocap_framerate=float(fps))


def timed(fn, repeats: int) -> tuple[float, object]:
    times, out = [], None
    for _ in range(repeats):
        t = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t)
    return statistics.median(times), out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--clips", type=int, default=10_000)
    parser.add_argument("--seconds", type=float, default=2.0)
    parser.add_argument("--fps", type=float, default=60.0)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--envs", type=int, default=4096)
    parser.add_argument("--json", type=Path, help="also write the figures here")
    args = parser.parse_args()
    warnings.simplefilter("ignore")
    with tempfile.TemporaryDirectory() as tmp:
        root, cache = Path(tmp) / "amass", Path(tmp) / "cache"
        make_tree(root, args.clips, args.seconds, args.fps)
        t0 = time.perf_counter()
        lib = MotionLib.load(root, cache=cache)
        first = time.perf_counter() - t0
        second, lib = timed(lambda: MotionLib.load(root, cache=cache, progress=False), args.repeats)
        rng = np.random.default_rng(0)
        ids = lib.sample_motions(args.envs, rng)
        times = lib.sample_times(ids, rng)
        lib.get_state(ids, times)  # touch the memory-mapped pages once
        lookup, _ = timed(lambda: lib.get_state(ids, times), max(args.repeats, 20))
    result = {
        "clips": lib.num_motions, "frames_30fps": lib.num_frames,
        "first_load_s": round(first, 2), "cached_load_s": round(second, 3),
        "first_load_clips_per_s": round(lib.num_motions / first),
        f"get_state_{args.envs}_envs_ms": round(1000 * lookup, 2),
    }
    print(json.dumps(result, indent=2))
    if args.json:
        args.json.write_text(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
