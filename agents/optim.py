"""Optimiser helpers every agent uses: Adam with its fused kernel, and keeping its state clear of
subnormal floats (a slow path on CPUs)."""
from __future__ import annotations

import torch


def adam(params, **kwargs) -> torch.optim.Adam:
    """Adam (over tensors or parameter groups) with its fused kernel where torch has one for the
    device (CPU, CUDA): one pass over all parameters instead of a dozen ops per tensor, a seventh
    of the time per step here (measured: 3.7 ms to 0.5 ms for a 512-256 actor and critic on 2 cores)."""
    params = list(params)  # tensors, or parameter groups (dicts with "params")
    tensors = [p for g in params for p in g["params"]] if params and isinstance(params[0], dict) else params
    fused = bool(tensors) and all(p.device.type in ("cpu", "cuda") and p.is_floating_point() for p in tensors)
    return torch.optim.Adam(params, fused=fused, **kwargs)


# Below this an entry is zero for any network, and a zeroed one stays clear of the subnormal
# range (< 1.2e-38): decaying at Adam's rate, a value needs ~200 steps from here to reach it, and
# the next flush comes a few steps later.
FLUSH_BELOW = 1e-30


@torch.no_grad()
def flush_subnormals_(optimizer: torch.optim.Optimizer) -> None:
    """Zero, in place, the entries of an optimiser's CPU parameters and moments that are about
    to turn subnormal (|x| < FLUSH_BELOW).

    On a CPU, arithmetic on subnormal floats takes a slow path. Adam shrinks a weight that gets
    no gradient from the data (an input that is always zero, a dead ReLU unit) geometrically
    once an L2 term in the loss is all that moves it, as the discriminator's weight decay does,
    and its first moment decays the same way. Measured here, AMP on Speed: after ~1.5M steps,
    190k of the discriminator's weights were below 1e-20, its forward and backward ran 13-90x
    slower, and training fell from 2,100 to 510 samples/s. Zeroing only the subnormal entries
    was not enough: the weights just above the range kept making subnormal moments and
    products. `torch.set_flush_denormal` would only cover threads started after the call
    (torch's pool may already run), so the state itself is kept clean."""
    for group in optimizer.param_groups:
        for p in group["params"]:
            state = optimizer.state.get(p, {})
            for t in (p, *state.values()):
                if torch.is_tensor(t) and t.device.type == "cpu" and t.is_floating_point() and t.dim() > 0:
                    t.masked_fill_(t.abs() < FLUSH_BELOW, 0.0)


__all__ = ["adam", "flush_subnormals_", "FLUSH_BELOW"]
