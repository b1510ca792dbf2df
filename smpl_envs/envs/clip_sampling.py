"""Failure-weighted clip sampling: PHC's hard-negative mining, kept online during training.

With many clips, uniform sampling spends most episodes on what the policy already does (standing,
gestures) and few on what it fails (running, jumping). PHC re-weights its motion sampling towards
the sequences that fail. Here the env itself keeps, per clip, a running count of early
terminations and of steps taken (both decayed, so the weights follow the policy as it improves),
and draws a `share` of its start clips in proportion to each clip's failure rate (terminations per
step: a long clip is not favoured for being long). The rest follow the library's own weights, so
mastered clips keep being rehearsed.

    p = (1 - share) x library weights + share x rate / sum(rate)

Until any clip has failed, or with `share` 0, p is the library's weights.
"""
from __future__ import annotations

import numpy as np

from ..backend import NumpyBackend

# Per env step, the counts shrink by this factor: a memory of ~1,000 steps (a few minutes of
# training at 64 worlds), long enough to average over many episodes per clip.
DECAY = 0.999


class FailureWeightedClips:
    """Per-clip failure rates of the episodes an env runs, and the start-clip weights they give."""

    def __init__(self, num_clips: int, share: float, backend=None, decay: float = DECAY):
        if not 0.0 <= float(share) <= 1.0:
            raise ValueError(f"failure_sampling must be a fraction in [0, 1], got {share!r}")
        self.share, self.decay = float(share), float(decay)
        self.backend = backend or NumpyBackend()
        self.failures = self.backend.zeros(int(num_clips))
        self.steps = self.backend.zeros(int(num_clips))

    def record(self, clips: np.ndarray, stepped: np.ndarray | None, failed: np.ndarray) -> None:
        """One env step: `clips` (N,) each world's clip, `stepped` (N,) bool the worlds that took
        a step (None: all), `failed` (N,) bool the worlds whose episode ended in failure."""
        k, xp = len(self.steps), self.backend.xp
        self.failures *= self.decay
        self.steps *= self.decay
        if stepped is not None:
            clips, failed = clips[stepped], failed[stepped]
        self.steps += xp.bincount(clips, minlength=k)
        self.failures += xp.bincount(clips, weights=failed * 1.0, minlength=k)

    def rates(self) -> np.ndarray:
        """(K,) recent failures per step of each clip (0 where it has not been played)."""
        return self.failures / self.steps.clip(min=1e-12)  # 0 / tiny = 0 where a clip is unplayed

    def weights(self, base: np.ndarray) -> np.ndarray:
        """(K,) probabilities of drawing each clip for a start, given the library's (`base`)."""
        rate = self.backend.to_numpy(self.rates())  # K numbers: the draw itself stays on the device
        total = rate.sum()
        if self.share == 0.0 or total <= 0.0:
            return base
        p = (1.0 - self.share) * base + self.share * rate / total
        return p / p.sum()
