"""Running mean / variance normaliser, kept as module buffers so it travels inside checkpoints."""
from __future__ import annotations

import torch
from torch import nn


class RunningNorm(nn.Module):
    """Normalises inputs by statistics accumulated over everything passed to `update`.

    Statistics are float64 so that millions of updates do not drift; `count` starts at a tiny
    epsilon so the first batch defines the statistics almost entirely.
    """

    # In a data-parallel job the agent sets this, per module, to `DataParallel.reduce_moments`:
    # each update then folds in the moments of every process's batch together, so all processes
    # keep the statistics one process seeing every batch would. Not state: never saved.
    reduce_moments = None

    def __init__(self, shape: int | tuple[int, ...], clip: float | None = 10.0, eps: float = 1e-8):
        super().__init__()
        shape = (shape,) if isinstance(shape, int) else tuple(shape)
        self.clip, self.eps = clip, eps
        self.register_buffer("mean", torch.zeros(shape, dtype=torch.float64))
        self.register_buffer("var", torch.ones(shape, dtype=torch.float64))
        self.register_buffer("count", torch.tensor(1e-4, dtype=torch.float64))

    @torch.no_grad()
    def update(self, x: torch.Tensor) -> None:
        x = x.reshape(-1, *self.mean.shape)
        n = x.shape[0]
        if n:
            # One batch's moments are exact enough in its own precision (a float32 batch: half the
            # memory traffic of converting it first); the running combination is float64.
            batch_var, batch_mean = (m.to(torch.float64) for m in torch.var_mean(x, 0, correction=0))
        elif self.reduce_moments is None:
            return
        else:  # an empty batch here still takes part in the job's combination
            batch_mean, batch_var = torch.zeros_like(self.mean), torch.zeros_like(self.var)
        if self.reduce_moments is not None:
            n, batch_mean, batch_var = self.reduce_moments(n, batch_mean, batch_var)
            if n == 0:
                return
        delta, total = batch_mean - self.mean, self.count + n
        # Chan et al.'s parallel combination of two (mean, M2) summaries.
        m2 = self.var * self.count + batch_var * n + delta.square() * self.count * n / total
        self.mean += delta * n / total
        self.var.copy_(m2 / total)
        self.count.copy_(total)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = (x - self.mean.to(x.dtype)) / torch.sqrt(self.var.to(x.dtype) + self.eps)
        return y.clamp(-self.clip, self.clip) if self.clip else y

    def denormalize(self, y: torch.Tensor) -> torch.Tensor:
        return y * torch.sqrt(self.var.to(y.dtype) + self.eps) + self.mean.to(y.dtype)
