"""`python -m smpl_envs.motion.make_corpus [--seed N]`: generate and cache the procedural corpus
(both splits, as the environments load them, with progress bars) and print its family table,
the one in docs/corpus.md."""

from __future__ import annotations

from . import corpus
from .library import MotionLib
from .motion import FPS



def main(argv=None) -> None:
    """Generate (and cache) both splits as the environments load them, then print the family
    table."""
    import argparse
    import time

    parser = argparse.ArgumentParser(description=main.__doc__)
    parser.add_argument("--seed", type=int, default=corpus.DEFAULT_SEED)
    args = parser.parse_args(argv)
    records = []
    for split in corpus.SPLITS:
        start = time.perf_counter()
        lib = MotionLib.load(f"corpus:{split}#{args.seed}")
        print(f"corpus:{split}: {lib.num_motions} clips, {lib.num_frames / FPS / 3600:.2f} h "
              f"({time.perf_counter() - start:.0f} s)")
        records += _records(lib, split)
    print(corpus.table(records))


def _records(lib, split: str) -> list[corpus.ClipRecord]:
    """Manifest records of a loaded corpus library, from its clip names and lengths."""
    out = []
    for name, frames in zip(lib.names, lib.lengths):
        family = corpus.family_of(name)
        out.append(corpus.ClipRecord(name, family, split, int(frames), {}, 0))
    return out


if __name__ == "__main__":
    main()
