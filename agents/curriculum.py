"""A get-up curriculum: the start mix of a recovery env (reference, fallen, far, fallen+far
starts) scheduled over training, as `train.curriculum` in a recipe:

    train:
      curriculum:
        starts:                       # [timestep, start mix] knots, linear in between
          - [0, {fallen: 1.0}]                          # first only getting up (PHC's getup phase)
          - [1000000, {fallen: 1.0}]
          - [3000000, {reference: 0.4, fallen: 0.3, far: 0.15, fallen+far: 0.15}]

Before the first knot the first mix holds, after the last knot the last one. The mix is a
function of the agent's step count, so a resumed run is at the same point of its schedule as the
run it continues. The env learns the mix through its documented hook
`set_recovery_starts(starts)` (SMPL/Recovery-v0, or Imitation-v0 with recovery on); the mix in
force is logged as `curriculum/<kind>` with every iteration's row.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from .callbacks import Callback

START_KINDS = ("reference", "fallen", "far", "fallen+far")  # smpl_envs.envs.recovery_rules.START_KINDS


def check_curriculum(spec: Any) -> dict:
    """`train.curriculum` validated: {"starts": [[timestep, {kind: p}], ...]} with increasing
    timesteps and each mix a distribution over the start kinds; a ValueError says what is wrong."""
    from smpl_envs.envs.recovery_rules import check_starts

    if not isinstance(spec, dict) or set(spec) != {"starts"}:
        raise ValueError(f"expected {{starts: [[timestep, {{kind: probability}}], ...]}}, got {spec!r}")
    knots = spec["starts"]
    if not isinstance(knots, list) or not knots:
        raise ValueError(f"starts must be a non-empty list of [timestep, start mix] pairs, got {knots!r}")
    out, last = [], -1
    for i, knot in enumerate(knots):
        if not (isinstance(knot, (list, tuple)) and len(knot) == 2):
            raise ValueError(f"starts[{i}] must be a [timestep, start mix] pair, got {knot!r}")
        step, mix = knot
        if isinstance(step, float) and step.is_integer():
            step = int(step)
        if isinstance(step, bool) or not isinstance(step, int) or step < 0 or step <= last:
            raise ValueError(f"starts[{i}]: timesteps must be integers >= 0 in increasing order, got {step!r}")
        try:
            check_starts(mix)
        except ValueError as e:
            raise ValueError(f"starts[{i}]: {e}") from None
        out.append([step, {k: float(v) for k, v in mix.items()}])
        last = step
    return {"starts": out}


def start_mix(spec: dict, timestep: int) -> dict[str, float]:
    """The start mix of curriculum `spec` (checked) at `timestep`: piecewise linear in the knots."""
    steps = np.array([k[0] for k in spec["starts"]], float)
    mixes = np.array([[float(k[1].get(kind, 0.0)) for kind in START_KINDS] for k in spec["starts"]])
    p = np.array([np.interp(timestep, steps, mixes[:, j]) for j in range(len(START_KINDS))])
    p = p / p.sum()
    return {kind: float(v) for kind, v in zip(START_KINDS, p)}


class StartCurriculum(Callback):
    """Sets the env's start mix from the schedule at the start of training and after every
    iteration (module docstring)."""

    def __init__(self, spec: dict):
        self.spec = check_curriculum(spec)
        self.current: dict[str, float] | None = None

    def _apply(self, agent) -> None:
        mix = start_mix(self.spec, agent.num_timesteps)
        env = getattr(agent.env, "unwrapped", agent.env)
        setter = getattr(env, "set_recovery_starts", None)
        if setter is None:
            raise ValueError(f"train.curriculum schedules recovery starts; {agent.env_id} has no set_recovery_starts "
                             "(use SMPL/Recovery-v0, or SMPL/Imitation-v0 with recovery on)")
        if mix != self.current:
            setter(mix)
            self.current = mix
        for kind, p in mix.items():
            agent.logger.record(f"curriculum/{kind}", p)

    def on_training_start(self, agent) -> None:
        self._apply(agent)

    def on_iteration(self, agent):
        self._apply(agent)
        return True


__all__ = ["StartCurriculum", "check_curriculum", "start_mix"]
