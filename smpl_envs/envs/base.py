"""The batched humanoid environment every task builds on, and the one-world `gym.Env` view of it.

`HumanoidVecEnv` owns the physics (`smpl_envs.sim.CPUSim`), the reference motions (`MotionLib`)
and the episode bookkeeping (which clip and frame each world follows, autoreset). A task subclass
supplies two batched functions of the state: `_observe` and `_evaluate` (reward, termination).

Time: the policy acts at the motion library's 30 Hz; each action is held for `substeps` physics
steps (4 x 1/120 s). Episodes start on an exact reference frame (reference state initialisation)
and advance one frame per step, so the reference never needs interpolating.
"""

from __future__ import annotations

import os
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from ..features import SELF_OBS_LAYOUT, BodyState, amp_features, heading_rotation, layout_size
from ..humanoid.builder import build_humanoid
from ..humanoid.skeleton import ACTION_SCALE
from ..motion.library import MotionLib
from ..sim import CPUSim

CONTROL_FPS = 30
# "human" opens MuJoCo's viewer, so it is only offered where a display exists.
RENDER_MODES = ["rgb_array"] + (["human"] if os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY") else [])
PROPRIO_DIM = layout_size(SELF_OBS_LAYOUT)  # every task's observation starts with the self observation


def load_motions(motions: str | os.PathLike | list | MotionLib, progress: bool = False) -> MotionLib:
    """A MotionLib from what a user passes as `motions=`: a shipped clip name, a motion file, a
    directory tree, a saved (cached) library, a list of those, or a MotionLib."""
    lib = motions if isinstance(motions, MotionLib) else MotionLib.load(motions, progress=progress)
    short = [lib.names[i] for i in np.flatnonzero(lib.lengths < 2)]
    if short:
        raise ValueError(f"clips need at least 2 frames to be imitated; too short: {short[:5]}"
                         + (f" and {len(short) - 5} more" if len(short) > 5 else ""))
    return lib


def _autoreset_mode(mode: str | AutoresetMode) -> AutoresetMode:
    try:
        return AutoresetMode(mode) if isinstance(mode, str) else AutoresetMode(mode.value)
    except ValueError:
        raise ValueError(f"autoreset_mode must be one of {[m.value for m in AutoresetMode]}, got {mode!r}") from None


class HumanoidVecEnv(VectorEnv):
    """N simulated SMPL humanoids following reference motions, stepped together.

    Subclasses set `single_observation_space` size via `obs_dim` and implement `_observe`,
    `_evaluate` (reward, its terms, termination). See the task modules for their layouts.
    """

    metadata = {"render_modes": RENDER_MODES, "render_fps": CONTROL_FPS,
                "autoreset_mode": AutoresetMode.NEXT_STEP}
    obs_dim: int = 0

    def __init__(
        self,
        num_envs: int = 1,
        *,
        motions: str | os.PathLike | list | MotionLib = "walk",
        start: str = "random",
        max_episode_steps: int | None = None,
        autoreset_mode: str | AutoresetMode = AutoresetMode.NEXT_STEP,
        substeps: int = 4,
        num_threads: int | None = None,
        render_mode: str | None = None,
        render_size: tuple[int, int] = (640, 480),
        show_reference: bool = True,
        render_world: int = 0,
    ):
        if start not in ("random", "beginning"):
            raise ValueError(f"start must be 'random' or 'beginning', got {start!r}")
        if render_mode not in (None, *self.metadata["render_modes"]):
            raise ValueError(f"render_mode must be one of {self.metadata['render_modes']} or None, got {render_mode!r}")
        self.num_envs = int(num_envs)
        self.motion_lib = load_motions(motions)
        self.start = start
        self.max_episode_steps = max_episode_steps
        self.autoreset_mode = _autoreset_mode(autoreset_mode)
        self.metadata = {**self.metadata, "autoreset_mode": self.autoreset_mode}
        self.model = build_humanoid()
        self.sim = CPUSim(self.model, self.num_envs, substeps, num_threads)
        self.action_scale = np.asarray(ACTION_SCALE, dtype=np.float64)

        self.single_action_space = gym.spaces.Box(-1.0, 1.0, (self.model.nu,), np.float32)
        self.single_observation_space = gym.spaces.Box(-np.inf, np.inf, (self.obs_dim,), np.float32)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)

        self.render_mode = render_mode
        self.render_size = tuple(render_size)
        self.show_reference = show_reference
        self.render_world = int(render_world)
        self._renderer = self._viewer = None

        n = self.num_envs
        self.motion_id = np.zeros(n, np.int64)
        self.frame = np.zeros(n, np.int64)       # global library frame the simulated state matches
        self.end_frame = np.zeros(n, np.int64)   # last frame of each world's clip
        self.elapsed = np.zeros(n, np.int64)     # steps since the world's last reset
        self._needs_reset = np.zeros(n, bool)
        self._ref_cache = None

    # ------------------------------------------------------------------ task interface
    def _observe(self, sim: BodyState, ref_next: BodyState, heading: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def _evaluate(self, sim: BodyState, ref: BodyState) -> tuple[np.ndarray, dict[str, np.ndarray], np.ndarray]:
        """(reward (N,), reward terms {name: (N,)}, terminated (N,) bool) of the current state."""
        raise NotImplementedError

    # ------------------------------------------------------------------ gymnasium API
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        """Reset every world, or with `options={"reset_mask": mask}` only the masked ones.

        Other options: `motion_ids` (one clip per reset world, instead of sampling by the
        library's weights) and `start` ("random" or "beginning", overriding the env's default).
        """
        if seed is not None:
            self._np_random, self._np_random_seed = gym.utils.seeding.np_random(seed)
        options = dict(options or {})
        mask = options.pop("reset_mask", None)
        motion_ids = options.pop("motion_ids", None)
        start = options.pop("start", self.start)
        if options:
            raise ValueError(f"unknown reset options {sorted(options)}; known: reset_mask, motion_ids, start")
        ids = np.arange(self.num_envs) if mask is None else np.flatnonzero(np.asarray(mask, bool))
        self._reset_worlds(ids, motion_ids, start)
        state = self.sim.bodies
        heading = heading_rotation(state.rot[:, 0])
        obs = self._observe(state, self._ref_next(), heading)
        info = self._info(state, self._reference(self.frame), obs[:, :PROPRIO_DIM], None, np.zeros(self.num_envs, bool))
        obs = self._finish_obs(obs)
        if mask is not None:
            # Worlds left running keep their observation; only the reset ones change.
            info["_reset"] = np.zeros(self.num_envs, bool)
            info["_reset"][ids] = True
        return obs, info

    def step(self, actions):
        actions = np.asarray(actions, dtype=np.float64)
        if actions.shape != (self.num_envs, self.model.nu):
            raise ValueError(f"actions must have shape {(self.num_envs, self.model.nu)}, got {actions.shape}")
        if not np.isfinite(actions).all():
            bad = np.flatnonzero(~np.isfinite(actions).all(-1))
            raise ValueError(f"actions contain NaN or inf in worlds {bad.tolist()[:10]}")

        # NEXT_STEP autoreset: worlds that ended last step restart now and ignore their action.
        # The common case (nobody restarting) skips every mask below.
        running = None
        if self._needs_reset.any():
            running = ~self._needs_reset
            self._reset_worlds(np.flatnonzero(self._needs_reset), None, self.start)
        diverged = self.sim.step(actions.clip(-1.0, 1.0) * self.action_scale, active=running)
        if running is None:
            np.minimum(self.frame + 1, self.end_frame, out=self.frame)
            self.elapsed += 1
        else:
            diverged &= running
            self.frame[running] = np.minimum(self.frame[running] + 1, self.end_frame[running])
            self.elapsed[running] += 1

        state = self.sim.bodies
        heading = heading_rotation(state.rot[:, 0])
        ref = self._reference(self.frame)
        reward, terms, terminated = self._evaluate(state, ref)
        terminated = terminated | diverged
        truncated = self.frame >= self.end_frame
        if self.max_episode_steps is not None:
            truncated |= self.elapsed >= self.max_episode_steps
        if running is not None or diverged.any():
            valid = ~diverged if running is None else running & ~diverged
            reward = np.where(valid, reward, 0.0)
            terms = {k: np.where(valid, v, 0.0) for k, v in terms.items()}
            if running is not None:
                terminated &= running
                truncated &= running
        truncated &= ~terminated
        obs = self._observe(state, self._ref_next(), heading)
        info = self._info(state, ref, obs[:, :PROPRIO_DIM], terms, diverged)
        obs = self._finish_obs(obs)

        done = terminated | truncated
        if self.autoreset_mode == AutoresetMode.NEXT_STEP:
            self._needs_reset = done
        elif self.autoreset_mode == AutoresetMode.SAME_STEP and done.any():
            ids = np.flatnonzero(done)
            info["final_obs"], info["_final_obs"] = obs.copy(), done
            info["final_info"], info["_final_info"] = {k: v.copy() for k, v in info.items()}, done
            self._reset_worlds(ids, None, self.start)
            state = self.sim.bodies
            heading = heading_rotation(state.rot[:, 0])
            fresh_obs = self._observe(state, self._ref_next(), heading)
            fresh = self._info(state, self._reference(self.frame), fresh_obs[:, :PROPRIO_DIM], None,
                               np.zeros(self.num_envs, bool))
            obs[ids] = self._finish_obs(fresh_obs[ids])
            for k, v in fresh.items():
                info[k][ids] = v[ids]
        return obs, np.asarray(reward, np.float64), terminated, truncated, info

    # ------------------------------------------------------------------ internals
    def _reset_worlds(self, ids: np.ndarray, motion_ids, start: str) -> None:
        if len(ids) == 0:
            return
        lib, rng = self.motion_lib, self.np_random
        if motion_ids is None:
            motion_ids = lib.sample_motions(len(ids), rng)
        motion_ids = np.asarray(motion_ids, np.int64).reshape(-1)
        if len(motion_ids) != len(ids) or motion_ids.min() < 0 or motion_ids.max() >= lib.num_motions:
            raise ValueError(f"motion_ids must be {len(ids)} indices in [0, {lib.num_motions})")
        if start == "random":  # any frame that leaves at least one step to imitate
            local = (rng.random(len(ids)) * (lib.lengths[motion_ids] - 1)).astype(np.int64)
        elif start == "beginning":
            local = np.zeros(len(ids), np.int64)
        else:
            raise ValueError(f"start must be 'random' or 'beginning', got {start!r}")
        self.motion_id[ids] = motion_ids
        self.frame[ids] = lib.starts[motion_ids] + local
        self.end_frame[ids] = lib.starts[motion_ids] + lib.lengths[motion_ids] - 1
        self.elapsed[ids] = 0
        self._needs_reset[ids] = False
        qpos, qvel = lib.qpos_qvel(self.frame[ids])
        self.sim.set_state(ids, qpos, qvel)

    def reference_action(self) -> np.ndarray:
        """(N, 69) actions whose PD targets are the next reference frame's joint angles: the
        policy-free baseline of "track the reference with the PD controllers alone"."""
        target = self.motion_lib.dof_pos[self._next_frame()] / self.action_scale
        return np.clip(target, -1.0, 1.0).astype(np.float32)

    def _next_frame(self) -> np.ndarray:
        return np.minimum(self.frame + 1, self.end_frame)

    def _ref_next(self) -> BodyState:
        return self._reference(self._next_frame())

    def _reference(self, frames: np.ndarray) -> BodyState:
        # The frames observed as "next" in one step are the frames rewarded in the following one.
        cached = self._ref_cache
        if cached is not None and np.array_equal(cached[0], frames):
            return cached[1]
        ref = self.motion_lib.body_state(frames)
        self._ref_cache = (frames.copy(), ref)
        return ref

    def _finish_obs(self, obs: np.ndarray) -> np.ndarray:
        # A diverged world's state may be garbage; keep the batch finite for the learner.
        obs = obs.astype(np.float32)
        if not np.isfinite(obs.sum()):
            obs = np.nan_to_num(obs, nan=0.0, posinf=0.0, neginf=0.0)
        return obs

    def _info(self, state: BodyState, ref: BodyState, proprio, terms: dict | None,
              diverged: np.ndarray) -> dict[str, Any]:
        lib = self.motion_lib
        info = {f"reward_{k}": v for k, v in (terms or {}).items()}
        info.update(
            motion_id=self.motion_id.copy(),
            motion_time=(self.frame - lib.starts[self.motion_id]) * (1.0 / lib.fps),
            body_pos=state.pos.astype(np.float32),
            ref_body_pos=ref.pos,
            diverged=diverged,
            amp_obs=amp_features(state, proprio=proprio).astype(np.float32),
        )
        return info

    @property
    def observation_structure(self) -> dict[str, slice]:
        """{"group/name": slice into the flat observation}; the module docstring has the table."""
        raise NotImplementedError

    # ------------------------------------------------------------------ rendering
    def render(self):
        """An RGB frame of world `render_world` (rgb_array) or a live viewer window (human)."""
        if self.render_mode is None:
            gym.logger.warn("render() called without a render_mode; pass render_mode='rgb_array' to gym.make")
            return None
        world = self.render_world
        data = self.sim.datas[world]
        markers = self.motion_lib.body_pos[self.frame[world]] if self.show_reference else None
        if self.render_mode == "human":
            return self._render_human(data, markers)
        if self._renderer is None:
            from ..render import FrameRenderer

            self._renderer = FrameRenderer(self.model, *self.render_size)
        return self._renderer.render(data, markers)

    def _render_human(self, data, markers):
        if self._viewer is None:
            if not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
                raise RuntimeError("render_mode='human' needs a display; use render_mode='rgb_array' "
                                   "and smpl_envs.record(...) on a headless machine")
            import mujoco.viewer

            self._viewer = mujoco.viewer.launch_passive(self.model, data)
        self._viewer.sync()
        return None

    def close(self, **kwargs):
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
        if self._viewer is not None:
            self._viewer.close()
            self._viewer = None
        self.sim.close()


class SingleEnv(gym.Env):
    """A `gymnasium.Env` over one world of a `HumanoidVecEnv`: the batch of one, not a second
    implementation. Episodes end as the task says; the caller resets (no autoreset)."""

    vec_class: type[HumanoidVecEnv] = HumanoidVecEnv
    metadata = {"render_modes": RENDER_MODES, "render_fps": CONTROL_FPS}

    def __init__(self, render_mode: str | None = None, **kwargs):
        for bad in ("num_envs", "autoreset_mode", "render_world"):
            if bad in kwargs:
                raise TypeError(f"{bad!r} is for gym.make_vec, not gym.make")
        self.vec = self.vec_class(1, autoreset_mode=AutoresetMode.DISABLED, render_mode=render_mode, **kwargs)
        self.render_mode = render_mode
        self.action_space = self.vec.single_action_space
        self.observation_space = self.vec.single_observation_space

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        self.vec._np_random = self.np_random  # one seed stream: gym.Env's generator drives the world
        options = dict(options or {})
        if "motion_id" in options:
            options["motion_ids"] = [options.pop("motion_id")]
        obs, info = self.vec.reset(options=options)
        return obs[0], _unbatch(info)

    def step(self, action):
        obs, reward, terminated, truncated, info = self.vec.step(np.asarray(action)[None])
        return obs[0], float(reward[0]), bool(terminated[0]), bool(truncated[0]), _unbatch(info)

    def render(self):
        return self.vec.render()

    def close(self):
        self.vec.close()

    # The task's public attributes, reachable as env.unwrapped.<name>.
    observation_structure = property(lambda self: self.vec.observation_structure)
    motion_lib = property(lambda self: self.vec.motion_lib)
    model = property(lambda self: self.vec.model)
    sim = property(lambda self: self.vec.sim)

    def reference_action(self) -> np.ndarray:
        return self.vec.reference_action()[0]


def _unbatch(info: dict) -> dict:
    return {k: (_unbatch(v) if isinstance(v, dict) else v[0]) for k, v in info.items() if not k.startswith("_")}
