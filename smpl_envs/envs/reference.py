"""Reference tracking: the reusable part of every task that follows a reference motion
(Imitation, KeypointImitation, and next VR tracking and Recovery).

A `ReferenceTracker` holds, per world, the clip and the global library frame the humanoid should
match now; it advances one frame per policy step (policy rate = clip rate, so every lookup is an
exact frame and nothing is interpolated) and stops at the clip's last frame. It also turns actions
into PD targets in either action mode:

- "absolute" (PHC): PD target = ACTION_SCALE * a, a in [-1, 1] (pi rad per hinge, 5 rad for knee
  flexion);
- "residual" (SimPoE's form, without its root force): PD target = the next reference frame's
  joint angles + residual_scale * ACTION_SCALE * a, so the zero action tracks the reference with
  the PD controllers alone and the policy learns corrections.
"""

from __future__ import annotations

import numpy as np

from ..backend import NumpyBackend
from ..features import BodyState
from ..motion.library import MotionLib

ACTION_MODES = ("absolute", "residual")
RESIDUAL_SCALE = 0.25  # fraction of the absolute range: 0.25 pi rad per hinge (measured, issue 10)


def check_action_mode(action_mode: str, residual_scale: float) -> float:
    if action_mode not in ACTION_MODES:
        raise ValueError(f"action_mode must be one of {ACTION_MODES}, got {action_mode!r}")
    scale = float(residual_scale)
    if not (np.isfinite(scale) and scale > 0):
        raise ValueError(f"residual_scale must be a positive number, got {residual_scale!r}")
    return scale


def residual_to_absolute(actions, ref_dof_pos, action_scale, residual_scale: float):
    """The absolute-mode actions that give the PD targets residual-mode `actions` (in [-1, 1],
    clipped as the env clips them) give on top of the reference joint angles `ref_dof_pos`
    (N, 69; `info["next_ref_dof_pos"]` of the reference-tracking tasks). NumPy or torch.

    What a distillation needs to learn absolute actions, which every task takes, from a
    residual teacher (agents.PULSE)."""
    target = ref_dof_pos + actions.clip(-1.0, 1.0) * (residual_scale * action_scale)
    return target.clip(-action_scale, action_scale) / action_scale


class ReferenceTracker:
    """Per-world reference frames of `lib` for `num_worlds` worlds (arrays of shape (N,)).

    `lib` is a MotionLib, or its `DeviceFrames` with the torch `backend` of an env on MuJoCo Warp.
    """

    def __init__(self, lib: MotionLib, num_worlds: int, backend=None):
        self.lib = lib
        self.backend = b = backend or NumpyBackend()
        self.motion_id = b.zeros(num_worlds, "int")
        self.frame = b.zeros(num_worlds, "int")      # global frame the simulated state should match
        self.end_frame = b.zeros(num_worlds, "int")  # last frame of each world's clip
        # The current and next reference bodies of the frames as they stand now. The frames
        # change only in `begin` and `advance`, which clear it, so a lookup is reused without
        # comparing frame arrays (on a GPU each comparison would wait for the device).
        self._cache: dict[str, BodyState] = {}

    def begin(self, ids: np.ndarray, motion_ids: np.ndarray, frames: np.ndarray) -> None:
        """Worlds `ids` start following clips `motion_ids` at global frames `frames`."""
        self.motion_id[ids] = motion_ids
        self.frame[ids] = frames
        self.end_frame[ids] = self.lib.starts[motion_ids] + self.lib.lengths[motion_ids] - 1
        self._cache = {}

    def advance(self, active: np.ndarray | None = None) -> None:
        """One frame on, for every world or those in the mask `active`; clips hold their last frame."""
        xp = self.backend.xp
        following = self._cache.get("next")
        self._cache = {}
        if active is None:
            xp.minimum(self.frame + 1, self.end_frame, out=self.frame)
            if following is not None:  # every world moved onto exactly its next frame
                self._cache["current"] = following
        else:
            self.frame[active] = xp.minimum(self.frame[active] + 1, self.end_frame[active])

    def at_end(self) -> np.ndarray:
        return self.frame >= self.end_frame

    def next_frame(self) -> np.ndarray:
        return self.backend.xp.minimum(self.frame + 1, self.end_frame)

    def motion_time(self) -> np.ndarray:
        return (self.frame - self.lib.starts[self.motion_id]) * (1.0 / self.lib.fps)

    def bodies(self, frames: np.ndarray) -> BodyState:
        """Reference bodies at global `frames` (not cached)."""
        return self.lib.body_state(frames)

    def current(self) -> BodyState:
        """Reference bodies at the current frames. A step reads them (reward, info) and the next
        ones (observation), and the next ones become the following step's current ones: one new
        lookup per step. Callers must not write into the result (it is shared)."""
        if "current" not in self._cache:
            self._cache["current"] = self.lib.body_state(self.frame)
        return self._cache["current"]

    def next(self) -> BodyState:
        """Reference bodies at the next frames (shared, as `current`'s)."""
        if "next" not in self._cache:
            self._cache["next"] = self.lib.body_state(self.next_frame())
        return self._cache["next"]

    def pd_targets(self, actions: np.ndarray, action_scale: np.ndarray, mode: str, residual_scale: float) -> np.ndarray:
        """(N, 69) PD targets of actions in [-1, 1] under `mode` (module docstring)."""
        if mode == "absolute":
            return actions * action_scale
        target = self.lib.dof_pos[self.next_frame()] + actions * (residual_scale * action_scale)
        return target.clip(-action_scale, action_scale)

    def next_dof_pos(self):
        """(N, 69) the next reference frame's joint angles: what residual actions add to."""
        return self.lib.dof_pos[self.next_frame()]

    def reference_action(self, action_scale: np.ndarray, mode: str) -> np.ndarray:
        """(N, 69) actions whose PD targets are the next reference frame's joint angles: the
        policy-free baseline "track the reference with the PD controllers alone"."""
        b = self.backend
        if mode == "residual":
            return b.float32(b.zeros((len(self.frame), len(action_scale))))
        return b.float32((self.lib.dof_pos[self.next_frame()] / action_scale).clip(-1.0, 1.0))
