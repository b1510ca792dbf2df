"""Fallen states for fail-state recovery (REFERENCE.md sections 3 and 8): humanoids dropped in a
random orientation and left to collapse, generated in one batch and cached.

Generation (PHC's and PULSE's "getup" recipe, at this project's timestep):

* every world starts from the rest pose with all hinges at zero and a random root orientation,
  a normalised Gaussian quaternion (uniform over rotations), its pelvis over the xy origin and
  lifted so its lowest body origin is `CLEARANCE` above the floor (a random orientation at the
  rest height would put limbs inside the floor, and the contact solver would fling them out);
* one action per hinge, U(-0.5, 0.5), is held as absolute PD targets (action x ACTION_SCALE);
* physics runs 2.5 s (150 steps at 1/60 s in the anchors; 300 steps at our 1/120 s);
* the final pose is kept with every velocity zeroed.

All worlds fall together in a throwaway `CPUSim` (one `step` of 300 substeps), so 128 states
take a few seconds. The states are humanoid-only qpos rows (76: root position, root quaternion,
69 hinges) whose root xy is the offset from the point the body was dropped over; adding a
target's xy places a state anywhere (`FallenStates.place`). States are memoised per
(count, seed): envs that ask for the same set share it, and `FallenStates.regenerate` draws a
new set on demand (e.g. when the motion set changes).

Backends: the states are always generated on the host (NumPy, CPU MuJoCo: a setup cost); an env
on MuJoCo Warp gives `FallenStates` its torch backend, and the set is copied to the device once
(float32) and again after `regenerate`, so `place`, which runs at every fallen start, stays on
the device.
"""

from __future__ import annotations

import functools

import numpy as np

from ..backend import NumpyBackend
from ..humanoid.builder import build_spec, humanoid_addresses
from ..humanoid.skeleton import ACTION_SCALE
from ..sim import CPUSim

FALL_SECONDS = 2.5
DROP_ACTION = 0.5   # hinge actions held during the fall are U(-DROP_ACTION, DROP_ACTION)
CLEARANCE = 0.2     # m: the lowest body origin starts this high (capsule radii are <= 0.1 m)


@functools.lru_cache(maxsize=8)
def _generate(count: int, seed: int) -> np.ndarray:
    model = build_spec().compile()
    hum = humanoid_addresses(model)
    steps = int(round(FALL_SECONDS / model.opt.timestep))
    sim = CPUSim(model, count, substeps=steps, humanoid=hum)
    try:
        rng = np.random.default_rng(seed)
        qpos = np.tile(model.qpos0, (count, 1))
        root = qpos[:, hum.qpos]  # a copy: written back below
        quat = rng.normal(size=(count, 4))
        root[:, 3:7] = quat / np.linalg.norm(quat, axis=-1, keepdims=True)
        root[:, 7:] = 0.0
        root[:, :3] = 0.0
        qpos[:, hum.qpos] = root
        ids = np.arange(count)
        sim.set_state(ids, qpos, np.zeros((count, model.nv)))
        # Lift each world so its lowest body origin sits CLEARANCE above the floor.
        root[:, 2] = CLEARANCE - sim.bodies.pos[..., 2].min(axis=-1)
        qpos[:, hum.qpos] = root
        sim.set_state(ids, qpos, np.zeros((count, model.nv)))
        actions = rng.uniform(-DROP_ACTION, DROP_ACTION, (count, len(ACTION_SCALE)))
        diverged = sim.step(actions * ACTION_SCALE)
        states = sim.qpos[:, hum.qpos].copy()
    finally:
        sim.close()
    good = ~diverged & np.isfinite(states).all(-1)
    if not good.any():
        raise RuntimeError("fallen states: every simulated fall diverged")
    # A diverged fall (rare) is replaced by a good one, so the set keeps its size.
    states = np.resize(states[good], (count, states.shape[1]))
    states.setflags(write=False)
    return states


def generate_fallen_states(count: int = 128, seed: int = 0) -> np.ndarray:
    """(count, 76) humanoid qpos rows of fallen humanoids (module docstring), read-only and
    memoised per (count, seed)."""
    _check(count, seed)
    return _generate(int(count), int(seed))


def _check(count, seed) -> None:
    if isinstance(count, bool) or not isinstance(count, (int, np.integer)) or count < 1:
        raise ValueError(f"fallen_cache_size must be a positive integer, got {count!r}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"fallen_seed must be a non-negative integer, got {seed!r}")


class FallenStates:
    """A cache of fallen states, generated on first use (`states`) and on demand (`regenerate`).
    `backend`: where `place` returns its rows (the NumPy backend by default)."""

    def __init__(self, count: int = 128, seed: int = 0, backend=None):
        _check(count, seed)
        self.count, self.seed = int(count), int(seed)
        self.backend = backend or NumpyBackend()
        self._states = None
        self._placed = None  # `states` on the backend (the same array on the NumPy one)

    @property
    def states(self) -> np.ndarray:
        """(count, 76) the host (NumPy, read-only) states."""
        if self._states is None:
            self._states = generate_fallen_states(self.count, self.seed)
        return self._states

    def regenerate(self, seed: int) -> None:
        """A new set of states from `seed` (e.g. after the motion set changed)."""
        _check(self.count, seed)
        self.seed = int(seed)
        self._states = generate_fallen_states(self.count, self.seed)
        self._placed = None

    def place(self, rng: np.random.Generator, xy) -> np.ndarray:
        """(n, 76) humanoid qpos rows on the backend: random cached states with their root moved
        over `xy` (n, 2), drawn with the env's generator `rng`."""
        if self._placed is None:
            self._placed = self.backend.asarray(self.states)  # once per set: a device copy
        states = self._placed
        rows = states[self.backend.integers(rng, 0, len(states), len(xy))]  # indexing copies
        rows[:, :2] += xy
        return rows
