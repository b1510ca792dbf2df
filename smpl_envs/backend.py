"""Array backends of the env core: NumPy beside CPU MuJoCo, torch beside MuJoCo Warp.

The task math (`smpl_envs.features`, the reward and termination functions of `smpl_envs.envs`) is
written once over operators NumPy and torch share, and `features.xp` picks the module from its
arguments. What an env keeps per world (episode clocks, reference frames, start clips) and the few
operations where the two libraries differ (allocation, index lists of a mask, copies, random
draws) go through a backend, so `HumanoidVecEnv` has one code path for both:

| backend | physics | arrays the env returns | floats | random numbers |
|---|---|---|---|---|
| `"cpu"` (default) | `CPUSim`, MuJoCo on a thread pool | NumPy | float64 (observations float32) | the env's NumPy generator |
| `"warp"` | `WarpSim`, MuJoCo Warp on `device` | torch tensors on `device` | float32 | a torch generator on `device`, seeded from the NumPy one |

Porting a task to the torch backend: per-world state from `backend.zeros / asarray`;
`xp = backend.xp` for module functions (`xp.where`, `xp.stack`, `xp.concatenate`, `xp.cos`,
`xp.minimum` of two arrays); methods both share (`.clip`, `.sum(axis=)`, `.any(axis=)`,
`.reshape`, `.swapaxes`); `backend.copy` for `.copy()`, `backend.float32` for
`.astype(np.float32)`, `backend.nonzero` for `np.flatnonzero`, `backend.rows` for `np.tile` of a
row; `xp.amax(x, axis)` (not `.max`, which is a pair in torch); random draws through the backend
with the env's `np_random` (`uniform`, `integers`, `choice`). Constants may stay NumPy
where they only index or scale (torch converts them); a table used in arithmetic is converted once.

Why torch for the device path, and not an array-API layer: the agents are torch, so observations,
rewards and actions stay in one library from the simulator to the optimiser (Warp shares its
memory with torch without copies), and torch is already a dependency.
"""
from __future__ import annotations

from typing import Any

import numpy as np

BACKENDS = ("cpu", "warp")


class MissingExtraError(ImportError):
    """A setting needs an optional dependency that is not installed; the message names the extra
    that installs it."""


class NumpyBackend:
    """Arrays on the host: NumPy, float64, the env's `np_random`."""

    name = "cpu"
    xp = np
    device = None

    def zeros(self, shape, kind: str = "float"):
        return np.zeros(shape, {"float": np.float64, "int": np.int64, "bool": bool}[kind])

    def asarray(self, x, kind: str = "float"):
        return np.asarray(x, {"float": np.float64, "int": np.int64, "bool": bool}[kind])

    def float32(self, x):
        return x.astype(np.float32)

    @staticmethod
    def nonzero(mask):
        return np.flatnonzero(mask)

    @staticmethod
    def copy(x):
        return x.copy()

    @staticmethod
    def to_numpy(x):
        return x

    @staticmethod
    def rows(x, n: int):
        """(n, ...) copies of the row `x`."""
        return x[None].repeat(n, axis=0)

    @staticmethod
    def arange(n: int):
        return np.arange(n)

    # Random draws take the env's generator (`self.np_random`); the NumPy backend makes exactly
    # the generator calls the tasks made before backends existed, so seeded episodes are unchanged.
    @staticmethod
    def uniform(rng: np.random.Generator, size, low: float | None = None, high: float | None = None):
        """U[0, 1) (`rng.random`) or U[low, high) (`rng.uniform`) of shape `size`."""
        return rng.random(size) if low is None else rng.uniform(low, high, size)

    @staticmethod
    def integers(rng: np.random.Generator, low: int, high: int, size):
        """Integers in [low, high)."""
        return rng.integers(low, high, size)

    @staticmethod
    def choice(rng: np.random.Generator, k: int, n: int, p):
        return rng.choice(k, size=n, p=p)


class TorchBackend:
    """Arrays on a torch device, float32 (MuJoCo Warp's precision)."""

    name = "warp"

    def __init__(self, device):
        import torch

        self.xp = torch
        self.device = torch.device(device)
        self._dtypes = {"float": torch.float32, "int": torch.int64, "bool": torch.bool}
        self.rng = torch.Generator(self.device)
        self._source = None  # the NumPy generator `rng` was last seeded from

    def zeros(self, shape, kind: str = "float"):
        return self.xp.zeros(shape, dtype=self._dtypes[kind], device=self.device)

    def asarray(self, x, kind: str = "float"):
        if isinstance(x, np.ndarray) and x.dtype.kind == "f" and kind == "float":
            x = x.astype(np.float32)  # a float64 array would become a float64 tensor first
        return self.xp.as_tensor(x, dtype=self._dtypes[kind], device=self.device)

    def float32(self, x):
        # Always a new tensor, as NumPy's astype: a float32 view of the simulator's state would
        # change under the caller at the next step.
        return x.to(self.xp.float32, copy=True)

    def nonzero(self, mask):
        return self.xp.nonzero(mask).reshape(-1)

    @staticmethod
    def copy(x):
        return x.clone()

    @staticmethod
    def to_numpy(x):
        from .sim.warp import to_numpy

        return to_numpy(x)

    @staticmethod
    def rows(x, n: int):
        return x[None].repeat(n, *([1] * x.dim()))

    def _generator(self, rng: np.random.Generator):
        # Seeded from the env's NumPy generator whenever that one is replaced (a seeded reset,
        # or gym.make's single env handing its own): the same seed gives the same episodes.
        if rng is not self._source:
            self.rng.manual_seed(int(rng.integers(2 ** 62)))
            self._source = rng
        return self.rng

    def arange(self, n: int):
        return self.xp.arange(n, device=self.device)

    def uniform(self, rng: np.random.Generator, size, low: float | None = None, high: float | None = None):
        # U[0, 1) in float64 (it picks frames of libraries longer than float32 counts exactly);
        # ranged draws in the env's float32, as they go into its per-world state.
        size = size if isinstance(size, tuple) else (int(size),)
        u = self.xp.rand(size, generator=self._generator(rng), device=self.device, dtype=self.xp.float64)
        return u if low is None else (low + (high - low) * u).to(self.xp.float32)

    def integers(self, rng: np.random.Generator, low: int, high: int, size):
        size = size if isinstance(size, tuple) else (int(size),)
        return self.xp.randint(int(low), int(high), size, generator=self._generator(rng), device=self.device)

    def choice(self, rng: np.random.Generator, k: int, n: int, p):
        p = self.xp.as_tensor(p, dtype=self.xp.float64, device=self.device)
        return self.xp.multinomial(p, n, replacement=True, generator=self._generator(rng))


def make_backend(backend: str, device: Any = None):
    """The backend named `backend` ("cpu" or "warp"); `device` only for "warp"."""
    if backend == "cpu":
        if device not in (None, "cpu"):
            raise ValueError(f"device={device!r} needs backend='warp' (the CPU backend runs on the host)")
        return NumpyBackend()
    if backend == "warp":
        wp = _warp()
        if device is None:
            device = "cuda" if wp.is_cuda_available() else "cpu"
        problem = warp_device_problem(device)
        if problem is not None:
            raise ValueError(f"device={device!r}: {problem}")
        return TorchBackend(device)
    raise ValueError(f"backend must be one of {BACKENDS}, got {backend!r}")


def _warp():
    """Warp, initialised; MissingExtraError naming the extra where MuJoCo Warp is not installed."""
    try:
        import warp as wp
        import mujoco_warp  # noqa: F401
    except ImportError as e:  # the reason is in the message; its traceback would only repeat it
        raise MissingExtraError(f"backend='warp' needs MuJoCo Warp: pip install 'smpl-envs[gpu]' ({e})") from None
    wp.init()
    return wp


def warp_device_problem(device) -> str | None:
    """Why MuJoCo Warp cannot run on `device` on this machine, or None when it can."""
    try:
        wp = _warp()
    except MissingExtraError as e:
        return str(e)
    if str(device).startswith("cuda") and not wp.is_cuda_available():  # asking Warp would print CUDA errors
        return "Warp sees no CUDA device on this machine"
    try:
        wp.get_device(str(device))
    except Exception as e:  # Warp raises its own error types for unknown devices
        return f"not a device Warp knows ('cpu', 'cuda', 'cuda:0' ...): {e}"
    return None


def runnable_here(recorded: dict, given: dict | None = None, what: str = "the run") -> dict:
    """A recorded run's env kwargs for this machine, with the caller's `given` ones over them.
    The backend and device say where the physics ran, not how the policy acts, so a run trained
    on a GPU evaluates and records on a machine without one: there a recorded warp backend whose
    device is missing becomes the CPU backend, with a warning that says so (float64 physics
    instead of float32: the same model). A backend or device the caller gives is used as given."""
    if recorded.get("backend", "cpu") == "warp" and not {"backend", "device"} & set(given or {}):
        device = recorded.get("device")  # None: CUDA where there is one, else Warp's CPU device
        problem = warp_device_problem("cpu" if device is None else device)
        if problem is not None:
            import warnings

            warnings.warn(f"{what} ran on backend='warp', device={device!r}, which this machine lacks ({problem}); "
                          "running it on the CPU backend", stacklevel=2)
            recorded = {k: v for k, v in recorded.items() if k not in ("backend", "device")}
    return {**recorded, **(given or {})}
