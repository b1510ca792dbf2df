"""The batched environment core every task builds on, and the one-world `gym.Env` view of it.

`HumanoidVecEnv` knows no task. It owns the physics (`smpl_envs.sim.CPUSim` over a model the task
may extend), episodes and time limits, the three autoreset modes, seeding, divergence isolation,
start poses drawn from the motion library, and rendering. A task is a subclass that fills in the
hooks below; its per-world state lives in arrays of shape (N, ...) on the env (MuJoCo
Playground's style: state carried explicitly, resampled inside the step).

The task interface (all batched over worlds; `ids` are world indices):

| hook | called | returns / does |
|---|---|---|
| `task_layout` (class attribute) | at construction | {group: layout} of the observation after the self observation |
| `_configure(spec)` | before compiling | add bodies, geoms, sensors or terrain to the `MjSpec` |
| `_reset_task(ids, options)` | on reset of `ids` | full-model (qpos, qvel) of their start states; resets their task state |
| `_ctrl(actions)` | every step | PD targets (N, 69) from actions in [-1, 1] (default: `action_scale * a`) |
| `_advance(active)` | after physics | task clocks the reward needs (the reference frame) |
| `_evaluate(body, heading)` | after `_advance` | (reward, {term: (N,)}, terminated, truncated) |
| `_task_info(body)` | after `_evaluate`, and after a reset | extra `info` entries {name: (N, ...)} of the state the reward measured |
| `_schedule(active)` | after `_task_info` | redraw what is due (a target every k steps): the next observation shows it, the next reward uses it |
| `_observe(body, heading)` | last | observation (N, 358 + task columns), self observation first |
| `_markers(world)` | on render | [(positions (K, 3), rgba, radius)] drawn into the frame |
| `evaluation` (class attribute) | `smpl_envs.evaluate`, `smpl-envs eval` | the task's evaluation protocol (`smpl_envs.evaluation`) |
| `policy_kwargs` (class attribute) | `smpl_envs.evaluate`, `record`, `agents` loading | the kwargs that give a policy's actions and observations their meaning, each also an attribute holding the env's value: a policy runs only with those it was trained with (`smpl_envs.policy_settings`) |
| `goal_settings` (class attribute, optional) | `agents.warm_start` | the policy settings that only choose which clips the goal shows (recovery's guides): a warm start may change them, as it may change the motions |

`body` is the humanoid's `BodyState` in the world frame and `heading` its (N, 3, 3) heading
rotation, computed once per step and shared by the hooks.

Time: the policy acts at the motion library's 30 Hz; each action is held for `substeps` physics
steps (4 x 1/120 s). Every episode starts from a pose of the motion library (a random frame, or a
clip's first frame with `start="beginning"`), or the rest pose when the task runs without clips.
"""

from __future__ import annotations

import copy
import os
from typing import Any, ClassVar

import gymnasium as gym
import mujoco
import numpy as np
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from ..backend import make_backend
from ..features import SELF_OBS_LAYOUT, BodyState, amp_features, heading_rotation, layout_size, layout_slices
from ..humanoid.builder import build_spec, humanoid_addresses
from ..humanoid.skeleton import ACTION_SCALE, BODY_NAMES
from ..motion.library import MotionLib, load_motions
from ..sim import CPUSim
from .clip_sampling import FailureWeightedClips

CONTROL_FPS = 30
# "human" opens MuJoCo's viewer, so it is only offered where a display exists.
RENDER_MODES = ["rgb_array"] + (["human"] if os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY") else [])
PROPRIO_DIM = layout_size(SELF_OBS_LAYOUT)  # every task's observation starts with the self observation
STARTS = ("random", "beginning")
FEET = np.array([i for i, n in enumerate(BODY_NAMES) if n.endswith(("Ankle", "Toe"))])
# Attributes of the batched core that the one-world env does not pass on (SingleEnv).
VECTOR_ONLY = frozenset({"num_envs", "single_observation_space", "single_action_space", "autoreset_mode",
                         "render_world"})


def _autoreset_mode(mode: str | AutoresetMode) -> AutoresetMode:
    try:
        return AutoresetMode(mode) if isinstance(mode, str) else AutoresetMode(mode.value)
    except ValueError:
        raise ValueError(f"autoreset_mode must be one of {[m.value for m in AutoresetMode]}, got {mode!r}") from None


def _positive_int(name: str, value, allow_none: bool = False):
    if value is None and allow_none:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
        raise ValueError(f"{name} must be a positive integer{' or None' if allow_none else ''}, got {value!r}")
    return int(value)


def check_range(name: str, value, low: float = -np.inf, high: float = np.inf) -> tuple[float, float]:
    """A (min, max) kwarg as floats, or a ValueError naming it."""
    try:
        lo, hi = (float(v) for v in value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a (min, max) pair of numbers, got {value!r}") from None
    if not (np.isfinite(lo) and np.isfinite(hi)) or lo > hi:
        raise ValueError(f"{name} must be a (min, max) pair with min <= max, got {value!r}")
    if lo < low or hi > high:
        raise ValueError(f"{name} must lie within [{low}, {high}], got {value!r}")
    return lo, hi


def check_number(name: str, value, positive: bool = False) -> float:
    """A finite number >= 0 (> 0 if `positive`), or a ValueError naming the kwarg."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        v = float("nan")
    if isinstance(value, bool) or not np.isfinite(v) or v < 0 or (positive and v == 0):
        raise ValueError(f"{name} must be a {'positive' if positive else 'non-negative'} finite number, got {value!r}")
    return v


def clip_weights(names: list[str], weights) -> np.ndarray:
    """(K,) sampling weights of clips `names` from a {clip name: weight} mapping (`motion_weights`):
    the clips it does not name weigh 0. A ValueError names an unknown clip, an ambiguous name or a
    bad weight."""
    if not isinstance(weights, dict) or not weights:
        raise ValueError(f"motion_weights must be a non-empty mapping of clip name -> weight, got {weights!r}")
    index = {}
    for i, name in enumerate(names):
        index.setdefault(name, []).append(i)
    unknown = sorted(str(k) for k in weights if k not in index)
    if unknown:
        raise ValueError(f"motion_weights: no clip named {unknown[:5]}" + (f" and {len(unknown) - 5} more"
                                                                            if len(unknown) > 5 else ""))
    out = np.zeros(len(names))
    for name, w in weights.items():
        if len(index[name]) > 1:
            raise ValueError(f"motion_weights: {len(index[name])} clips are named {name!r}; weights go by name")
        if isinstance(w, bool) or not isinstance(w, (int, float)) or not np.isfinite(w) or w < 0:
            raise ValueError(f"motion_weights[{name!r}] must be a non-negative number, got {w!r}")
        out[index[name][0]] = float(w)
    if not out.sum() > 0:
        raise ValueError("motion_weights: every weight is 0; no clip could be drawn")
    return out


def fallen(body: BodyState, height: float = 0.15, head_height: float = 0.3):
    """(N,) a fall: a body origin other than the feet' below `height` m, or the head's below
    `head_height` m. REFERENCE section 5 also asks for ground contact; heights alone are cheaper
    and, this close to the floor, a body touches it or is about to (a hand reaching below
    0.15 m counts as a fall)."""
    z = body.pos[..., 2]
    low = z < height
    low[:, FEET] = False
    return low.any(axis=-1) | (z[:, BODY_NAMES.index("Head")] < head_height)


def _render_size(value, model: mujoco.MjModel) -> tuple[int, int]:
    """render_size as (width, height), each a whole number from 1 up to the model's offscreen
    buffer; else a ValueError naming the kwarg (0 gave empty frames, a size beyond the buffer an
    error at the first render)."""
    limit = (model.vis.global_.offwidth, model.vis.global_.offheight)
    try:
        size = tuple(int(v) for v in value)
        exact = all(float(v) == int(v) and not isinstance(v, bool) for v in value)
    except (TypeError, ValueError, OverflowError):
        size, exact = (), False
    if not exact or len(size) != 2 or not all(1 <= s <= m for s, m in zip(size, limit)):
        raise ValueError(f"render_size must be (width, height) in pixels, from (1, 1) up to the offscreen "
                         f"buffer's {limit}, got {value!r}")
    return size


class HumanoidVecEnv(VectorEnv):
    """N simulated SMPL humanoids stepped together; a task subclass supplies what they do.

    Core kwargs (every task): motions (clips for start poses, references or style; None: the rest
    pose), motion_weights (a mapping {clip name: weight}: the library's sampling weights, clips
    it does not name weighing 0; PMCP trains a primitive on its hard clips so: `clip_sampling`),
    start ("random" frame or "beginning" of a clip), beginning_share (the fraction of
    random starts moved to a clip's first frame), failure_sampling (the share of start clips drawn
    by their recent failure rate, PHC's hard-negative mining: `clip_sampling`), cache (the
    MotionLib's disk cache),
    max_episode_steps, autoreset_mode, substeps, num_threads, render_mode, render_size,
    render_world (the world `render_frame` and the human viewer show; `render()` gives every
    world's frame), show_markers, backend ("cpu": MuJoCo, NumPy arrays; "warp": MuJoCo Warp on
    `device`, torch tensors in and out; `smpl_envs.backend`) and device.

    A task lists the backends its code runs on in `backends`.
    """

    metadata = {"render_modes": RENDER_MODES, "render_fps": CONTROL_FPS,
                "autoreset_mode": AutoresetMode.NEXT_STEP}
    task_layout: ClassVar[dict[str, tuple]] = {}
    evaluation: ClassVar[Any] = None
    # The control period: a policy trained at one rate acts wrongly at another.
    policy_kwargs: ClassVar[tuple[str, ...]] = ("substeps",)
    reset_options: ClassVar[tuple[str, ...]] = ("motion_ids", "start")
    backends: ClassVar[tuple[str, ...]] = ("cpu",)

    def __init__(
        self,
        num_envs: int = 1,
        *,
        motions: str | os.PathLike | list | MotionLib | None = None,
        motion_weights: dict | None = None,
        start: str = "random",
        beginning_share: float = 0.0,
        failure_sampling: float = 0.0,
        cache: bool = True,
        max_episode_steps: int | None = None,
        autoreset_mode: str | AutoresetMode = AutoresetMode.NEXT_STEP,
        substeps: int = 4,
        num_threads: int | None = None,
        render_mode: str | None = None,
        render_size: tuple[int, int] = (640, 480),
        render_world: int = 0,
        show_markers: bool = True,
        backend: str = "cpu",
        device: str | None = None,
    ):
        self.num_envs = _positive_int("num_envs", num_envs)
        if backend not in self.backends:
            raise ValueError(f"{type(self).__name__} runs on backend {' or '.join(map(repr, self.backends))}, "
                             f"got {backend!r} (a task opts in to a backend with its `backends` attribute)")
        self.backend = make_backend(backend, device)
        if start not in STARTS:
            raise ValueError(f"start must be one of {STARTS}, got {start!r}")
        if not 0.0 <= float(beginning_share) <= 1.0:
            raise ValueError(f"beginning_share must be a fraction in [0, 1], got {beginning_share!r}")
        self.beginning_share = float(beginning_share)
        if render_mode not in (None, *self.metadata["render_modes"]):
            raise ValueError(f"render_mode must be one of {self.metadata['render_modes']} or None, got {render_mode!r}")
        if not 0 <= int(render_world) < self.num_envs:
            raise ValueError(f"render_world must be in [0, {self.num_envs}), got {render_world!r}")
        self.motion_lib = None if motions is None else load_motions(motions, cache=cache)
        if motion_weights is not None:
            if self.motion_lib is None:
                raise ValueError("motion_weights needs clips to weigh: pass motions=")
            # A copy: a library the caller passed in keeps its own weights.
            self.motion_lib = copy.copy(self.motion_lib)
            self.motion_lib.set_weights(clip_weights(self.motion_lib.names, motion_weights))
        if not (isinstance(failure_sampling, (int, float)) and 0.0 <= float(failure_sampling) <= 1.0):
            raise ValueError(f"failure_sampling must be a fraction in [0, 1], got {failure_sampling!r}")
        if failure_sampling and self.motion_lib is None:
            raise ValueError("failure_sampling needs clips to sample: pass motions=")
        self.clip_sampler = (FailureWeightedClips(self.motion_lib.num_motions, failure_sampling, self.backend)
                             if failure_sampling else None)
        # What the step reads of the clips, where the arrays live (the library itself on the host).
        self.motion_frames = self.motion_lib
        if self.motion_lib is not None and self.backend.name != "cpu":
            from ..motion.library import DeviceFrames

            self.motion_frames = DeviceFrames(self.motion_lib, self.backend.device)
        self.start = start
        self.max_episode_steps = _positive_int("max_episode_steps", max_episode_steps, allow_none=True)
        self.autoreset_mode = _autoreset_mode(autoreset_mode)
        self.metadata = {**self.metadata, "autoreset_mode": self.autoreset_mode, "backend": backend,
                         "device": None if self.backend.device is None else str(self.backend.device)}

        spec = build_spec()
        self._configure(spec)
        self.model = spec.compile()
        self.humanoid = humanoid_addresses(self.model)
        self.substeps = substeps = _positive_int("substeps", substeps)
        if self.backend.name == "cpu":
            self.sim = CPUSim(self.model, self.num_envs, substeps, num_threads, self.humanoid)
        else:
            from ..sim.warp import WarpSim

            self.sim = WarpSim(self.model, self.num_envs, substeps, device=str(self.backend.device),
                               humanoid=self.humanoid)
        self.action_scale = self.backend.asarray(ACTION_SCALE)
        self._qpos0 = self.backend.asarray(self.model.qpos0)

        self.obs_dim = PROPRIO_DIM + sum(layout_size(layout) for layout in self.task_layout.values())
        self.single_action_space = gym.spaces.Box(-1.0, 1.0, (len(ACTION_SCALE),), np.float32)
        self.single_observation_space = gym.spaces.Box(-np.inf, np.inf, (self.obs_dim,), np.float32)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)

        self.render_mode = render_mode
        self.render_size = _render_size(render_size, self.model)
        self.render_world = int(render_world)
        self.show_markers = bool(show_markers)
        self._renderer = self._viewer = None

        n, zeros = self.num_envs, self.backend.zeros
        self.elapsed = zeros(n, "int")       # steps since each world's last reset
        self.start_motion = zeros(n, "int")  # clip and global library frame of the start pose
        self.start_frame = zeros(n, "int")
        self._needs_reset = zeros(n, "bool")

    # ------------------------------------------------------------------ task interface (defaults)
    def _configure(self, spec: mujoco.MjSpec) -> None:
        """Add the task's objects to the model before it is compiled (default: nothing)."""

    def _reset_task(self, ids: np.ndarray, options: dict) -> tuple[np.ndarray, np.ndarray]:
        """Start states (qpos, qvel of the whole model) of worlds `ids`; reset their task state."""
        return self.start_pose(ids, options.get("motion_ids"), options.get("start", self.start),
                               options.get("start_frame"))

    def _ctrl(self, actions: np.ndarray) -> np.ndarray:
        """PD targets (N, 69) of actions in [-1, 1]."""
        return actions * self.action_scale

    def _advance(self, active: np.ndarray | None) -> None:
        """Advance the task clocks of the worlds that stepped (`active`; None: all)."""

    def _schedule(self, active: np.ndarray | None) -> None:
        """Redraw what is due in the worlds that stepped, after this step's reward."""

    def _evaluate(self, body: BodyState, heading) -> tuple[np.ndarray, dict, np.ndarray, np.ndarray]:
        raise NotImplementedError

    def _observe(self, body: BodyState, heading) -> np.ndarray:
        raise NotImplementedError

    def _task_info(self, body: BodyState) -> dict[str, np.ndarray]:
        return {}

    def _markers(self, world: int) -> list[tuple[np.ndarray, tuple, float]]:
        return []

    # ------------------------------------------------------------------ helpers for tasks
    def start_pose(self, ids: np.ndarray, motion_ids=None, start: str = "random",
                   start_frame=None) -> tuple[np.ndarray, np.ndarray]:
        """Full-model (qpos, qvel) for worlds `ids`: a frame of the motion library (clips drawn by
        its weights unless `motion_ids`; a random frame that leaves one step to go, or the first,
        or `start_frame`, a frame index within each world's clip, for a task that offers the
        reset option), or the model's rest pose when there are no clips. Records `start_motion` /
        `start_frame`."""
        n = len(ids)
        qpos = self.backend.rows(self._qpos0, n)
        qvel = self.backend.zeros((n, self.model.nv))
        lib = self.motion_frames
        if lib is None:
            if motion_ids is not None:
                raise ValueError("reset option motion_ids needs an env made with motions=")
            return qpos, qvel
        self.start_motion[ids], self.start_frame[ids] = self.start_frames(lib, n, motion_ids, start)
        if start_frame is not None:
            # An exact frame of each world's clip (perpetual control restarts a world where its
            # reference is now), clamped to the clip.
            b = self.backend
            local = b.asarray(start_frame, "int").reshape(-1)
            if len(local) not in (1, n) or bool((local < 0).any()):
                raise ValueError(f"reset option start_frame must be one frame index >= 0 or {n} of them")
            m = self.start_motion[ids]
            self.start_frame[ids] = lib.starts[m] + b.xp.minimum(local, lib.lengths[m] - 1)
        hq, hv = lib.qpos_qvel(self.start_frame[ids])
        qpos[:, self.humanoid.qpos], qvel[:, self.humanoid.qvel] = hq, hv
        return qpos, qvel

    def start_frames(self, lib, n: int, motion_ids=None, start: str = "random") -> tuple[np.ndarray, np.ndarray]:
        """(clip ids, global frames) of `n` start poses in `lib` (a MotionLib or any library with
        its `lengths`, `starts`, `num_motions` and `sample_motions`): clips drawn by the library's
        weights unless `motion_ids`; a random frame that leaves one step to go (a
        `beginning_share` of them moved to the first frame), or the first frame."""
        if start not in STARTS:
            raise ValueError(f"start must be one of {STARTS}, got {start!r}")
        rng, b = self.np_random, self.backend
        if motion_ids is None:
            p = lib.weights
            if self.clip_sampler is not None and lib is self.motion_frames:
                p = self.clip_sampler.weights(p)
            motion_ids = b.choice(rng, lib.num_motions, n, p)
        motion_ids = b.asarray(motion_ids, "int").reshape(-1)
        if len(motion_ids) != n or motion_ids.min() < 0 or motion_ids.max() >= lib.num_motions:
            raise ValueError(f"motion_ids must be {n} indices in [0, {lib.num_motions})")
        local = (b.asarray(b.uniform(rng, n) * (lib.lengths[motion_ids] - 1), "int") if start == "random"
                 else b.zeros(n, "int"))
        if start == "random" and self.beginning_share > 0:
            # A share of the random starts goes to the clip's first frame, so the clip's start,
            # which random starts rarely train on, is learnt too (AMP's "stand still" trap).
            local[b.uniform(rng, n) < self.beginning_share] = 0
        return motion_ids, lib.starts[motion_ids] + local

    @property
    def observation_structure(self) -> dict[str, slice]:
        """{"group/name": slice into the flat observation}; the task module has the table."""
        return layout_slices({"self": SELF_OBS_LAYOUT, **self.task_layout})

    # ------------------------------------------------------------------ gymnasium API
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        """Reset every world, or with `options={"reset_mask": mask}` (a boolean mask of num_envs
        entries) only the masked ones. Other options: `motion_ids` (one clip per reset world
        instead of sampling by the library's weights), `start` ("random" or "beginning"), and
        those of the task (`reset_options`)."""
        if seed is not None:
            self._np_random, self._np_random_seed = gym.utils.seeding.np_random(seed)
        options = dict(options or {})
        mask = options.pop("reset_mask", None)
        unknown = sorted(set(options) - set(self.reset_options))
        if unknown:
            raise ValueError(f"unknown reset options {unknown}; known: reset_mask, {', '.join(self.reset_options)}")
        b = self.backend
        ids = b.arange(self.num_envs) if mask is None else b.nonzero(b.asarray(self._check_mask(mask), "bool"))
        self._reset_worlds(ids, options)
        body = self.sim.bodies
        heading = heading_rotation(body.rot[:, 0])
        obs = self._observe(body, heading)
        info = self._info(body, obs, None, self.backend.zeros(self.num_envs, "bool"), self._task_info(body))
        obs = self._finish_obs(obs)
        if mask is not None:
            # Worlds left running keep their observation; only the reset ones change.
            info["_reset"] = self.backend.zeros(self.num_envs, "bool")
            info["_reset"][ids] = True
        return obs, info

    def step(self, actions):
        b, xp = self.backend, self.backend.xp
        actions = b.asarray(actions)
        # A task may act with more than the 69 PD targets (SimPoE's meta-PD and root force).
        width = self.single_action_space.shape[0]
        if tuple(actions.shape) != (self.num_envs, width):
            raise ValueError(f"actions must have shape {(self.num_envs, width)}, got {tuple(actions.shape)}")
        # A world handed NaN or inf ends its episode as diverged; the others carry on.
        broken = None
        if not xp.isfinite(actions.sum()):
            broken = ~xp.isfinite(actions).all(-1)
            actions = xp.where(broken[:, None], 0.0, actions)

        # NEXT_STEP autoreset: worlds that ended last step restart now and ignore their action.
        # The common case (nobody restarting) skips every mask below.
        running = None
        if self._needs_reset.any():
            running = ~self._needs_reset
            self._reset_worlds(b.nonzero(self._needs_reset), {})
        diverged = self.sim.step(self._ctrl(actions.clip(-1.0, 1.0)), active=running)
        if broken is not None:
            diverged |= broken
        if running is None:
            self.elapsed += 1
        else:
            diverged &= running
            self.elapsed[running] += 1
        self._advance(running)

        body = self.sim.bodies
        heading = heading_rotation(body.rot[:, 0])
        reward, terms, terminated, truncated = self._evaluate(body, heading)
        task_info = self._task_info(body)
        self._schedule(running)
        terminated = terminated | diverged
        if self.max_episode_steps is not None:
            truncated = truncated | (self.elapsed >= self.max_episode_steps)
        if running is not None or diverged.any():
            valid = ~diverged if running is None else running & ~diverged
            reward = xp.where(valid, reward, 0.0)
            terms = {k: xp.where(valid, v, 0.0) for k, v in terms.items()}
            if running is not None:
                terminated &= running
                truncated &= running
        truncated &= ~terminated
        if self.clip_sampler is not None:
            self.clip_sampler.record(self.start_motion, running, terminated)
        obs = self._observe(body, heading)
        info = self._info(body, obs, terms, diverged, task_info)
        obs = self._finish_obs(obs)

        done = terminated | truncated
        if self.autoreset_mode == AutoresetMode.NEXT_STEP:
            self._needs_reset = done
        elif self.autoreset_mode == AutoresetMode.SAME_STEP and done.any():
            ids = b.nonzero(done)
            info["final_info"], info["_final_info"] = {k: b.copy(v) for k, v in info.items()}, done
            info["final_obs"], info["_final_obs"] = b.copy(obs), done
            self._reset_worlds(ids, {})
            body = self.sim.bodies
            fresh_obs = self._observe(body, heading_rotation(body.rot[:, 0]))
            fresh = self._info(body, fresh_obs, None, diverged, self._task_info(body))
            obs[ids] = self._finish_obs(fresh_obs[ids])
            for k, v in fresh.items():
                if k != "diverged":  # the flag reports this step's event in every mode
                    info[k][ids] = v[ids]
        return obs, b.asarray(reward), terminated, truncated, info

    # ------------------------------------------------------------------ internals
    def _check_mask(self, mask) -> np.ndarray:
        mask = np.asarray(self.backend.to_numpy(mask))
        if mask.dtype != bool or mask.shape != (self.num_envs,):
            raise ValueError(f"reset_mask must be a boolean mask of {self.num_envs} entries (one per world), "
                             f"got {mask.dtype} of shape {mask.shape}; for indices use np.isin(range(num_envs), ids)")
        return mask

    def _reset_worlds(self, ids: np.ndarray, options: dict) -> None:
        if len(ids) == 0:
            return
        self.elapsed[ids] = 0
        self._needs_reset[ids] = False
        qpos, qvel = self._reset_task(ids, options)
        self.sim.set_state(ids, qpos, qvel)

    def _finish_obs(self, obs: np.ndarray) -> np.ndarray:
        # A diverged world's state may be garbage; keep the batch finite for the learner.
        xp = self.backend.xp
        obs = self.backend.float32(obs)
        if not xp.isfinite(obs.sum()):
            obs = xp.nan_to_num(obs, nan=0.0, posinf=0.0, neginf=0.0)
        return obs

    def _info(self, body: BodyState, obs, terms: dict | None, diverged: np.ndarray, task_info: dict) -> dict[str, Any]:
        b = self.backend
        info = {f"reward_{k}": v for k, v in (terms or {}).items()}
        info.update(body_pos=b.float32(body.pos), diverged=diverged,
                    amp_obs=b.float32(amp_features(body, proprio=obs[:, :PROPRIO_DIM])))
        if diverged.any():  # a diverged world's state may be garbage: keep info finite, as obs
            for key in ("body_pos", "amp_obs"):
                info[key] = b.xp.nan_to_num(info[key], nan=0.0, posinf=0.0, neginf=0.0)
        lib = self.motion_frames
        if lib is not None:
            # The clip frame each world's pose came from at its last reset (AMP seeds its
            # discriminator history there); reference-following tasks report the current frame.
            info.update(motion_id=b.copy(self.start_motion),
                        motion_time=(self.start_frame - lib.starts[self.start_motion]) * (1.0 / lib.fps))
        info.update(task_info)
        return info

    # ------------------------------------------------------------------ rendering
    def render(self):
        """Gymnasium's vector contract: a tuple of one RGB frame per world (rgb_array; that is
        num_envs renders, `render_frame` renders one), or a live viewer window of world
        `render_world` (human; returns None)."""
        if self.render_mode is None:
            gym.logger.warn("render() called without a render_mode; pass render_mode='rgb_array' to gym.make")
            return None
        if self.render_mode == "human":
            return self._render_human(self._render_data(self.render_world))
        return tuple(self.render_frame(world) for world in range(self.num_envs))

    def render_frame(self, world: int | None = None):
        """An RGB frame (height, width, 3) of one world: `world`, by default `render_world`, with
        its markers unless show_markers=False."""
        if self.render_mode is None:
            gym.logger.warn("render_frame() called without a render_mode; pass render_mode='rgb_array'")
            return None
        world = self.render_world if world is None else world
        if not 0 <= world < self.num_envs:
            raise ValueError(f"world must be in [0, {self.num_envs}), got {world!r}")
        if self._renderer is None:
            from ..render import FrameRenderer

            self._renderer = FrameRenderer(self.model, *self.render_size)
        return self._renderer.render(self._render_data(world), self._markers(world) if self.show_markers else [])

    def _render_data(self, world: int) -> mujoco.MjData:
        if self.backend.name == "cpu":
            return self.sim.datas[world]
        # MuJoCo Warp's state lives on the device: a host copy of this world for the renderer.
        if getattr(self, "_host_data", None) is None:
            self._host_data = mujoco.MjData(self.model)
        d = self._host_data
        d.qpos[:], d.qvel[:] = (self.backend.to_numpy(x[world]) for x in (self.sim.qpos, self.sim.qvel))
        mujoco.mj_forward(self.model, d)
        return d

    def _render_human(self, data):
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
    """A `gymnasium.Env` over one world of a task's `HumanoidVecEnv`: the batch of one, not a
    second implementation. `gym.make` builds it from the task's vector class at registration.
    Episodes end as the task says; the caller resets (no autoreset)."""

    metadata = {"render_modes": RENDER_MODES, "render_fps": CONTROL_FPS}

    def __init__(self, vec_class: type[HumanoidVecEnv], render_mode: str | None = None, **kwargs):
        for bad in ("num_envs", "autoreset_mode", "render_world"):
            if bad in kwargs:
                raise TypeError(f"{bad!r} is for gym.make_vec, not gym.make")
        self.vec = vec_class(1, autoreset_mode=AutoresetMode.DISABLED, render_mode=render_mode, **kwargs)
        self.metadata = {**self.metadata, **{k: self.vec.metadata[k] for k in ("backend", "device")}}
        self.render_mode = render_mode
        self.action_space = self.vec.single_action_space
        self.observation_space = self.vec.single_observation_space

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        self.vec._np_random = self.np_random  # one seed stream: gym.Env's generator drives the world
        options = dict(options or {})
        if "motion_id" in options:
            options["motion_ids"] = [options.pop("motion_id")]
        obs, info = self.vec.backend.to_numpy(self.vec.reset(options=options))
        return obs[0], _unbatch(info)

    def step(self, action):
        obs, reward, terminated, truncated, info = self.vec.step(np.asarray(action)[None])
        obs, info = self.vec.backend.to_numpy((obs, info))  # the one-world API speaks NumPy
        return obs[0], float(reward[0]), bool(terminated[0]), bool(truncated[0]), _unbatch(info)

    def render(self):
        return self.vec.render_frame() if self.render_mode == "rgb_array" else self.vec.render()

    def close(self):
        self.vec.close()

    def reference_action(self) -> np.ndarray:
        return self.vec.reference_action()[0]

    def __getattr__(self, name: str):
        # The task's public attributes (observation_structure, motion_lib, model, sim ...),
        # reachable as env.unwrapped.<name>; the vector API is not, or other libraries would take
        # this env for a batched one (torchrl reads num_envs). env.unwrapped.vec has it all.
        if name.startswith("_") or name == "vec" or name in VECTOR_ONLY:
            raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")
        return getattr(self.vec, name)


def _unbatch(info: dict) -> dict:
    return {k: (_unbatch(v) if isinstance(v, dict) else v[0]) for k, v in info.items() if not k.startswith("_")}
