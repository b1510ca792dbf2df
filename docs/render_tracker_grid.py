"""A video grid of the tracker on held-out clips: one clip per corpus family, each tile the
policy from the clip's first frame (with the reference as red markers), labelled with the clip
and, where it fell, the frame it fell at; plus a PNG of one frame of every tile.

    python docs/render_tracker_grid.py CHECKPOINT_OR_RUN_OR_NAME [--split test] [--seconds 6]
        [--columns 6] [--out docs/videos/tracker_test_grid.mp4]

A tile whose episode ended (the training termination: a body 0.3 m from its reference) holds
its last frame, dimmed, for the rest of the video.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np

import smpl_envs
from smpl_envs.motion import corpus
from smpl_envs.motion.library import MotionLib, load_motions
from smpl_envs.render import write_strip, write_video

TILE = (320, 240)


def pick_clips(lib: MotionLib, seed: int) -> list[int]:
    """One clip per family, drawn with `seed` among the family's clips, in the corpus' family order."""
    rng = np.random.default_rng(seed)
    by_family: dict[str, list[int]] = {}
    for i, name in enumerate(lib.names):
        family = corpus.family_of(name)
        if family is not None:
            by_family.setdefault(family, []).append(i)
    return [int(rng.choice(by_family[f])) for f in corpus.FAMILIES if f in by_family]


def label(frame: np.ndarray, text: str, color=(255, 255, 255)) -> np.ndarray:
    """The frame with `text` on a black band across its top."""
    from PIL import Image, ImageDraw

    image = Image.fromarray(frame)
    draw = ImageDraw.Draw(image)
    draw.rectangle((0, 0, frame.shape[1], 18), fill=(0, 0, 0))
    draw.text((4, 3), text, fill=color)
    return np.asarray(image)


def tile_frames(agent, lib: MotionLib, clip: int, steps: int, tmp: Path) -> tuple[list[np.ndarray], int | None]:
    """The tile's frames and the step its episode ended at (None: it ran to the clip's end or `steps`)."""
    import imageio.v2 as imageio

    motion = MotionLib([lib.motion(clip)])
    path = tmp / f"{clip}.mp4"
    out = smpl_envs.record("SMPL/Imitation-v0", agent, path, steps=steps, episodes=1, progress=False,
                           motions=motion, render_size=TILE)
    with imageio.get_reader(path) as reader:
        frames = [np.asarray(f) for f in reader]
    # The episode ended early if it stopped before both the clip and the step budget ran out.
    ended = out["steps"] if out["steps"] < min(steps, lib.lengths[clip] - 1) else None
    return frames, ended


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("target", help="a checkpoint, a run directory (its best.pt) or a shipped policy name")
    parser.add_argument("--split", choices=list(corpus.SPLITS), default="test")
    parser.add_argument("--seconds", type=float, default=6.0)
    parser.add_argument("--columns", type=int, default=6)
    parser.add_argument("--seed", type=int, default=0, help="which clip of each family")
    parser.add_argument("--out", type=Path, default=Path("docs/videos/tracker_test_grid.mp4"))
    args = parser.parse_args(argv)
    from agents.checkpoint_commands import load_target  # the command line's own lookup of runs and names

    agent, ckpt, _, _ = load_target(args.target, "best", "cpu")
    lib = load_motions(f"corpus:{args.split}", progress=True)
    steps = int(round(args.seconds * lib.fps))
    tiles = []
    with tempfile.TemporaryDirectory() as tmp:
        for clip in pick_clips(lib, args.seed):
            frames, ended = tile_frames(agent, lib, clip, steps, Path(tmp))
            name = lib.names[clip]
            text = name + (f"  fell at frame {ended}" if ended is not None else "")
            frames = [label(f, text, (255, 120, 120) if ended is not None else (255, 255, 255)) for f in frames]
            hold = (frames[-1] * (0.5 if ended is not None else 1.0)).astype(np.uint8)
            tiles.append(frames + [hold] * (steps + 1 - len(frames)))
            print(f"{name}: {'fell at frame ' + str(ended) if ended is not None else 'tracked'}")
    blank = np.zeros_like(tiles[0][0])
    tiles += [[blank] * (steps + 1)] * (-len(tiles) % args.columns)

    def grid(t: int) -> np.ndarray:
        rows = [np.concatenate([tile[t] for tile in tiles[r:r + args.columns]], axis=1)
                for r in range(0, len(tiles), args.columns)]
        return np.concatenate(rows, axis=0)

    n = write_video(args.out, (grid(t) for t in range(steps + 1)), fps=lib.fps)
    still = args.out.with_suffix(".png")
    write_strip(still, [grid(min(steps, int(lib.fps * 2)))])
    print(f"{args.out} ({n} frames, {len(tiles)} tiles, policy {ckpt}); {still}")


if __name__ == "__main__":
    main()
