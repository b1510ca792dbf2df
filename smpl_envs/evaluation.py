"""Evaluate a policy the way its task is measured: every task carries its own protocol.

    import smpl_envs
    result = smpl_envs.evaluate(policy, "SMPL/Imitation-v0", motions="path/to/amass_test")
    result = smpl_envs.evaluate(policy, "SMPL/Speed-v0", motions=["walk", "run"], episodes=64)
    print(result)                      # per-clip or per-episode table, then the aggregate line
    result.save("runs/eval.json")

A task's vector class names its protocol in the class attribute `evaluation`; `evaluate`, the
`smpl-envs eval` command and the training runs' periodic evaluations ask it, so nothing outside
the task module knows what a task's success is. Two protocols cover the tasks:

`ClipProtocol` (imitation; PHC, Luo et al. 2023):

* Every clip of the library is imitated exactly once, from its first frame (the humanoid starts
  in the reference state of frame 0), until its last frame. Nothing is random.
* A clip fails at the first frame where the mean distance over all 24 bodies between the
  simulated and the reference humanoid exceeds `threshold` (0.5 m). Imitation stops there. The
  env's own early termination is switched off. A simulation that diverges also fails the clip.
* Per clip, `smpl_envs.metrics.clip_metrics` turns the recorded simulated and reference body
  positions into success and the errors in mm; `metrics.summarize` aggregates them as PHC does.
  `score` (the success rate minus 1e-6 x E_g-mpjpe over all frames tracked) ranks checkpoints:
  between equal success rates, the lower error wins.
* Clips run batched: each world takes the next clip from a queue whenever its current one ends,
  so the result does not depend on the number of worlds.

`EpisodeProtocol` (goal-directed tasks: speed, reach, strike ...):

* `episodes` episodes (default 32) run to their end (a fall, the task's own termination, or the
  time limit), the env's starts and targets as in training, deterministic policy. They run in
  waves of `num_envs` worlds, each wave from a reset of every world seeded `seed + wave`; nothing
  resets inside a wave, so every checkpoint meets the same starts and targets (for a given
  `seed` and `num_envs`).
* Every step, the task's `info` entries named by the protocol are logged per world; at the end of
  an episode the task's `episode_metrics(log)` turns the log into that episode's row.
* The summary is the mean of every row metric over episodes, plus `score`: the mean task reward
  per step over the full time limit, steps after an early end counting zero, which ranks
  checkpoints (a policy cannot score by falling early).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable

import numpy as np
from gymnasium.vector import AutoresetMode

from . import metrics
from .backend import runnable_here
from .progress import pbar

# Env kwargs that only make sense for the env an evaluation builds itself.
_VEC_ONLY = ("num_envs", "autoreset_mode", "render_mode", "render_world")
# Env kwargs that belong to the training motions: they go where the motions go.
_MOTION_KWARGS = ("motions", "motion_weights")


@dataclass
class EvalResult:
    """Per-clip or per-episode rows and their summary; `kind` is "clips" or "episodes"."""

    rows: list[dict]
    summary: dict = field(default_factory=dict)
    kind: str = "clips"

    def table(self) -> str:
        if self.kind == "clips":
            return metrics.format_table(self.rows, self.summary) + family_table(self.rows)
        return format_episode_table(self.rows, self.summary)

    def to_json(self) -> str:
        if self.kind == "clips":
            return metrics.to_json(self.rows, self.summary)
        # metrics' JSON conversion: numpy scalars unpacked, undefined values (NaN) as null.
        return json.dumps({"episodes": metrics._plain(self.rows), "summary": metrics._plain(self.summary)},
                          indent=2, allow_nan=False)

    def save(self, path) -> Path:
        """Write `to_json()` to `path` (parent directories created); returns the path."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(self.to_json() + "\n")
        return path

    def __str__(self) -> str:
        return self.table()


def family_table(rows: list[dict]) -> str:
    """Success per motion family, as a block to append to a clip table, when the rows are corpus
    clips of two or more families ("" otherwise): which kinds of motion a policy keeps is what a
    success rate over a mixed set hides."""
    from .motion.corpus import family_of

    by_family: dict[str, list[bool]] = {}
    for row in rows:
        family = family_of(str(row.get("name", "")))
        if family is None:
            return ""
        by_family.setdefault(family, []).append(bool(row["success"]))
    if len(by_family) < 2:
        return ""
    w = max(len("family"), *map(len, by_family))
    lines = ["", "", f"{'family'.ljust(w)}  succeeded   rate"]
    for family in sorted(by_family):
        ok = by_family[family]
        lines.append(f"{family.ljust(w)}  {sum(ok):>4} / {len(ok):<4} {100 * sum(ok) / len(ok):5.1f}%")
    return "\n".join(lines)


# ---------------------------------------------------------------------------------------- protocols
class EvalProtocol:
    """What a task's evaluation is. Subclasses set:

    key / minimize: the summary metric that ranks checkpoints (best.pt), and its direction;
    options: the protocol's own options with their defaults (`evaluate(..., **options)`);
    train_only_kwargs: env kwargs of a training run that its evaluation does not inherit
        (they shape training episodes; the protocol chooses its own).
    """

    key: str = "score"
    minimize: bool = False
    options: dict[str, Any] = {}
    # The clips the protocol measures on when `motions` is not given, over a policy's training
    # motions (None: those): PHC's recovery protocol is the standing clip whatever a policy
    # trained on, and a walking reference would leave a fallen body behind.
    motions: str | None = None
    train_only_kwargs: tuple[str, ...] = ()
    forced_kwargs: tuple[str, ...] = ("num_envs", "autoreset_mode")

    def check_options(self, options: dict) -> dict:
        """The protocol's options with defaults filled in; ValueError names an unknown one."""
        unknown = sorted(set(options) - set(self.options))
        if unknown:
            known = ", ".join(self.options) or "none"
            raise ValueError(f"unknown evaluation option(s) {unknown} for {type(self).__name__}; it takes: {known}")
        return {**self.options, **options}

    def eval_kwargs(self, train_kwargs: dict) -> dict:
        """Env kwargs of a training run that carry over to its evaluation (reward weights,
        substeps, action mode ...)."""
        drop = set(self.train_only_kwargs) | set(_VEC_ONLY) | set(_MOTION_KWARGS)
        return {k: v for k, v in train_kwargs.items() if k not in drop}

    def record_kwargs(self, train_kwargs: dict) -> dict:
        """Env kwargs for a video of a training run's policy (one world, as in training)."""
        return {k: v for k, v in train_kwargs.items() if k not in set(_VEC_ONLY) | set(_MOTION_KWARGS)}

    def run(self, policy: Callable, env, options: dict, progress: bool) -> EvalResult:
        raise NotImplementedError

    def make_env(self, env_id: str, motions, num_envs: int, env_kwargs: dict, progress: bool, options: dict):
        raise NotImplementedError


class ClipProtocol(EvalProtocol):
    """PHC's imitation protocol (module docstring). Option: threshold (m)."""

    key = "score"  # success rate, ties broken by the lower E_g-mpjpe
    options = {"threshold": 0.5}
    train_only_kwargs = ("start", "max_episode_steps", "termination_distance")

    def check_options(self, options: dict) -> dict:
        options = super().check_options(options)
        t = options["threshold"]
        if isinstance(t, bool) or not isinstance(t, (int, float)) or not t > 0:
            raise ValueError(f"threshold must be a positive distance in metres, got {t!r}")
        return options

    def eval_kwargs(self, train_kwargs: dict) -> dict:
        return _reference_starts(super().eval_kwargs(train_kwargs))

    def record_kwargs(self, train_kwargs: dict) -> dict:
        # From a clip's first frame, with the training termination and episode length, so a
        # fall restarts the clip as in training.
        return _reference_starts({**super().record_kwargs(train_kwargs), "start": "beginning"})

    def make_env(self, env_id, motions, num_envs, env_kwargs, progress, options):
        import gymnasium as gym

        from .motion import load_motions  # imported here: the results API needs no motion code

        clash = sorted(set(env_kwargs) & {"motions", "termination_distance", *self.forced_kwargs})
        if clash:
            raise ValueError(f"env_kwargs must not set {clash}: evaluate() chooses them")
        # Load once here: the clip count sizes the env (no idle worlds), and the env reuses the library.
        lib = load_motions("walk" if motions is None else motions, progress=progress)
        return gym.make_vec(env_id, num_envs=min(num_envs, lib.num_motions), motions=lib,
                            termination_distance=None, autoreset_mode="Disabled", **env_kwargs)

    def check_env(self, env) -> None:
        u = getattr(env, "unwrapped", env)
        check_disabled_autoreset(u)
        if getattr(u, "termination_distance", None) is not None:
            raise ValueError(f"env must be made with termination_distance=None (evaluate applies the "
                             f"success threshold itself), got {u.termination_distance!r}")
        if getattr(u, "max_episode_steps", None) is not None:
            raise ValueError(f"env must be made with max_episode_steps=None (clips run to their last "
                             f"frame), got {u.max_episode_steps!r}")

    def run(self, policy, env, options, progress):
        rows = _run_clips(policy, env, options["threshold"], progress)
        summary = metrics.summarize(rows)
        # One number that ranks checkpoints: the success rate first; between equal rates, the
        # lower global error over the frames tracked (mm, far below 1e6) wins.
        error = summary.get("all_mpjpe_g")
        summary["score"] = float(summary["success_rate"]) - (1e-6 * error if error is not None and np.isfinite(error) else 0.0)
        return EvalResult(rows, summary, "clips")


def _reference_starts(kwargs: dict) -> dict:
    """`kwargs` with a training run's recovery settings (Imitation's `recovery` dict) kept, but
    every clip starting on its reference and no termination continued: a clip is imitated from
    its first frame, not from the fallen or far starts a recovery mix trained on."""
    recovery = kwargs.get("recovery")
    if isinstance(recovery, dict):
        kwargs = {**kwargs, "recovery": {**recovery, "starts": {"reference": 1.0}, "continue_prob": 0.0}}
    return kwargs


class EpisodeProtocol(EvalProtocol):
    """Seeded episodes of a goal-directed task (module docstring). Options: episodes, seed.

    step_keys: the `info` entries logged every step; episode_metrics(log) -> row, where `log`
    maps each step key to its (T,) values over the episode and also holds `reward` (T,),
    `terminated`, `truncated`, `diverged` (bools of the last step) and `length`.
    """

    train_only_kwargs = ("start",)

    def __init__(self, step_keys: tuple[str, ...], episode_metrics: Callable[[dict], dict]):
        self.step_keys = tuple(step_keys)
        self.episode_metrics = episode_metrics
        self.options = {"episodes": 32, "seed": 0}

    def check_options(self, options: dict) -> dict:
        options = super().check_options(options)
        for name in ("episodes", "seed"):
            v = options[name]
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < (1 if name == "episodes" else 0):
                raise ValueError(f"{name} must be an integer {'>= 1' if name == 'episodes' else '>= 0'}, got {v!r}")
        return options

    def make_env(self, env_id, motions, num_envs, env_kwargs, progress, options):
        import gymnasium as gym

        clash = sorted(set(env_kwargs) & {"motions", *self.forced_kwargs})
        if clash:
            raise ValueError(f"env_kwargs must not set {clash}: evaluate() chooses them")
        kwargs = dict(env_kwargs) if motions is None else {**env_kwargs, "motions": motions}
        return gym.make_vec(env_id, num_envs=min(num_envs, options["episodes"]), autoreset_mode="Disabled", **kwargs)

    def check_env(self, env) -> None:
        u = getattr(env, "unwrapped", env)
        check_disabled_autoreset(u)
        if getattr(u, "max_episode_steps", None) is None:
            raise ValueError("env must have a time limit (max_episode_steps) for an episode evaluation")

    def run(self, policy, env, options, progress):
        rows = _run_episodes(policy, env, self, options["episodes"], options["seed"], progress)
        summary = {"episodes": len(rows)}
        for key in rows[0]:
            values = np.array([r[key] for r in rows], float)
            if np.isfinite(values).any():
                summary[key] = float(np.nanmean(values))
        return EvalResult(rows, summary, "episodes")


def check_disabled_autoreset(u) -> None:
    if hasattr(u, "vec"):
        raise ValueError("evaluate needs an env id or a vector env (gym.make_vec(..., autoreset_mode='Disabled')), "
                         "not a one-world gym.make env")
    mode = u.metadata.get("autoreset_mode")
    if mode is None or AutoresetMode(getattr(mode, "value", mode)) != AutoresetMode.DISABLED:
        raise ValueError(f"env must be made with autoreset_mode='Disabled' (evaluate resets worlds "
                         f"itself), got {getattr(mode, 'value', mode)!r}")


def protocol_for(env) -> EvalProtocol:
    """The evaluation protocol of a registered task id or of a suite env."""
    if isinstance(env, str):
        import gymnasium as gym

        from gymnasium.envs.registration import load_env_creator

        try:
            spec = gym.spec(env)
        except gym.error.Error as e:
            raise ValueError(f"unknown env id {env!r}: {e}") from None
        entry = spec.vector_entry_point
        cls = load_env_creator(entry) if isinstance(entry, str) else entry
    else:
        u = getattr(env, "unwrapped", env)
        cls = type(getattr(u, "vec", u))  # a single env evaluates through its vector class
    protocol = getattr(cls, "evaluation", None)
    if not isinstance(protocol, EvalProtocol):
        raise ValueError(f"{env!r} is not an smpl_envs task with an evaluation protocol")
    return protocol


# ---------------------------------------------------------------------------------------- entry point
def evaluate(policy: Callable, env="SMPL/Imitation-v0", *, motions=None, num_envs: int = 8,
             progress: bool = True, env_kwargs: dict | None = None, override_settings: Iterable[str] = (),
             **options) -> EvalResult:
    """Measure `policy` on a task with the task's own protocol (module docstring).

    policy: callable from observations (N, D) float32 to actions (N, 69); a returned tuple
        (e.g. stable-baselines' `predict`, which returns (actions, state)) counts by its first item.
        A policy that records its training (an `agents` agent, or its bound `predict`) runs in
        the env it was trained in (`smpl_envs.policy_settings`): only on its task; with its
        policy settings (action_mode, residual_scale, substeps ...); with the rest of its
        training env kwargs as the protocol carries them over, under `env_kwargs`; and on its
        training motions unless `motions` says otherwise (or the protocol measures on clips of
        its own: recovery on "stand").
    env: a registered task id (an env of at most `num_envs` worlds is made with `motions` and
        `env_kwargs`, and closed afterwards), or an existing suite vec env made with
        autoreset_mode="Disabled" (imitation also: termination_distance=None, no
        max_episode_steps); it is reset with the protocol's seed. An env on the "warp"
        backend (env_kwargs backend="warp") is read through `wrappers.NumpyVecEnv`.
    override_settings: the names of policy settings that `env_kwargs` (or the existing env)
        may set to other values than the policy was trained with; any other contradiction of
        them is a ValueError naming the setting.
    options: the protocol's own (imitation: threshold=0.5; episode tasks: episodes=32, seed=0).
    """
    from . import policy_settings

    trained = policy_settings.training_record(policy)
    if trained is None and override_settings:
        raise ValueError("override_settings is for a policy that records its training settings (an agent); "
                         "this policy records none")
    protocol = protocol_for(env)
    options = protocol.check_options(options)
    made = isinstance(env, str)
    if made:
        if isinstance(num_envs, bool) or not isinstance(num_envs, (int, np.integer)) or num_envs < 1:
            raise ValueError(f"num_envs must be an integer >= 1, got {num_envs!r}")
        env_kwargs = dict(env_kwargs or {})
        if trained is not None:
            trained_id, trained_kwargs = trained
            policy_settings.check_task(trained_id, env)
            carried = runnable_here(protocol.eval_kwargs(trained_kwargs), env_kwargs, "the policy's training")
            env_kwargs = policy_settings.with_trained_settings(env, trained_kwargs, carried, override_settings)
            if motions is None:
                motions = protocol.motions or trained_kwargs.get("motions")
        env = protocol.make_env(env, motions, int(num_envs), env_kwargs, progress, options)
    elif motions is not None or env_kwargs is not None:
        raise ValueError("motions and env_kwargs are only for an env id; an existing env is "
                         "evaluated as it was made")
    elif trained is not None:
        policy_settings.check_env(env, *trained, override_settings)
    if getattr(env, "metadata", {}).get("backend", "cpu") != "cpu":
        from .wrappers import NumpyVecEnv  # the protocols count in NumPy; the physics stays on the device

        env = NumpyVecEnv(env)
    try:
        protocol.check_env(env)
        return protocol.run(policy, env, options, progress)
    finally:
        if made:
            env.close()


def policy_actions(policy, obs):
    actions = policy(obs)
    if isinstance(actions, tuple):
        actions = actions[0]
    return np.asarray(actions)


# ---------------------------------------------------------------------------------------- clips
def _clip_queue(policy: Callable, env, num_clips: int, keys: Callable[[dict], tuple[str, ...]],
                fails: Callable[[list, np.ndarray], np.ndarray], finish: Callable[[int, list, bool], dict],
                progress: bool) -> list[dict]:
    """Every clip once, from its first frame, batched: each world takes the next clip of the queue
    whenever its own ends, so the result does not depend on the number of worlds.

    keys(info): the `info` entries recorded every frame (float64, one array per key);
    fails(arrays, lengths): (k,) bool, which of the recorded worlds fail their clip at this frame
    (`lengths`: frames recorded so far, this one included);
    finish(clip, frames, broke): the clip's row from its frames (per frame, one array per key) and
    whether the env ended it early (a divergence: the env's own termination is off)."""
    n = getattr(env, "unwrapped", env).num_envs
    clip = np.full(n, -1, np.int64)            # clip each world imitates; -1 = idle
    frames: list[list] = [[] for _ in range(n)]
    broke = np.zeros(n, bool)
    rows: list[dict | None] = [None] * num_clips

    def record(worlds, info, terminated=None, truncated=None):
        """Append the current frame of `worlds`; return those whose clip ends at this frame."""
        arrays = [np.asarray(info[k], np.float64)[worlds] for k in keys(info)]
        for k, w in enumerate(worlds):
            frames[w].append([a[k] for a in arrays])
        stop = fails(arrays, np.array([len(frames[w]) for w in worlds], np.int64))
        if terminated is not None:
            broke[worlds] = terminated[worlds]
            stop |= terminated[worlds] | truncated[worlds]
        return worlds[stop]

    # Every world starts at once (idle ones on any clip: their steps are ignored).
    first = min(n, num_clips)
    obs, info = env.reset(seed=0, options={"motion_ids": np.arange(n) % num_clips, "start": "beginning"})
    obs = np.array(obs, copy=True)
    clip[:first] = np.arange(first)
    next_clip = first
    done = record(np.arange(first), info)
    bar = pbar(total=num_clips, desc="evaluate", unit="clip", disable=not progress)
    try:
        while True:
            # Finish ended clips and refill those worlds; a clip may end on its initial frame,
            # hence the loop.
            while len(done):
                for w in done:
                    rows[clip[w]] = finish(int(clip[w]), frames[w], bool(broke[w]))
                    frames[w], clip[w], broke[w] = [], -1, False
                    bar.update(1)
                take = done[:num_clips - next_clip]
                if not len(take):
                    break
                ids = np.arange(next_clip, next_clip + len(take))
                next_clip += len(take)
                mask = np.zeros(n, bool)
                mask[take] = True
                new_obs, info = env.reset(options={"reset_mask": mask, "motion_ids": ids, "start": "beginning"})
                obs[take] = np.asarray(new_obs)[take]
                clip[take] = ids
                done = record(take, info)
            active = np.flatnonzero(clip >= 0)
            if not len(active):
                break
            obs, _, terminated, truncated, info = env.step(policy_actions(policy, obs))
            obs = np.array(obs, copy=True)
            done = record(active, info, np.asarray(terminated, bool), np.asarray(truncated, bool))
    finally:
        bar.close()
    return rows


def _run_clips(policy: Callable, env, threshold: float, progress: bool) -> list[dict]:
    lib = getattr(env, "unwrapped", env).motion_lib
    return _clip_queue(
        policy, env, lib.num_motions, lambda info: ("body_pos", "ref_body_pos"),
        # Same formula as metrics.body_distance, in float64 like clip_metrics, so the stop
        # decision here and the fail frame it reports always agree.
        lambda a, _: np.linalg.norm(a[0] - a[1], axis=-1).mean(axis=1) > threshold,
        lambda c, frames, broke: _finish_clip(lib, c, *zip(*frames), broke, threshold), progress)


def _finish_clip(lib, motion_id: int, sim: list, ref: list, broke: bool, threshold: float) -> dict:
    """clip_metrics of one finished clip, plus its name and id."""
    sim, ref = np.stack(sim), np.stack(ref)
    # A diverged world's last frame may be non-finite; measure the frames before it and still
    # count the clip as failed at that frame.
    cut = len(sim) - 1 if broke and not np.isfinite(sim[-1]).all() else len(sim)
    row = metrics.clip_metrics(sim[:cut], ref[:cut], threshold)
    if broke and row["success"]:
        row.update(success=False, fail_frame=len(sim) - 1, frames=len(sim))
    return {"name": lib.names[motion_id], "motion_id": int(motion_id), **row}


# ---------------------------------------------------------------------------------------- episodes
def _run_episodes(policy: Callable, env, protocol: EpisodeProtocol, episodes: int, seed: int,
                  progress: bool) -> list[dict]:
    # Episodes run in waves of num_envs, each wave from a reset of every world with its own seed
    # (seed, seed + 1, ...). Nothing resets inside a wave, so the starts and targets a wave draws
    # do not depend on when the policy falls: two checkpoints meet the same episodes.
    u = getattr(env, "unwrapped", env)
    n, limit = u.num_envs, u.max_episode_steps
    rows: list[dict] = []
    bar = pbar(total=episodes, desc="evaluate", unit="episode", disable=not progress)
    try:
        for wave in range(-(-episodes // n)):
            count = min(n, episodes - len(rows))
            obs, _ = env.reset(seed=seed + wave)
            obs = np.array(obs, copy=True)
            logs = [_new_log(protocol) for _ in range(count)]
            finished: dict[int, dict] = {}
            active = np.zeros(n, bool)
            active[:count] = True
            while active.any():
                obs, reward, terminated, truncated, info = env.step(policy_actions(policy, obs))
                obs = np.array(obs, copy=True)
                terminated, truncated = np.asarray(terminated, bool), np.asarray(truncated, bool)
                for w in np.flatnonzero(active):
                    logs[w]["reward"].append(float(reward[w]))
                    for key in protocol.step_keys:
                        logs[w][key].append(np.asarray(info[key])[w])
                done = active & (terminated | truncated)
                for w in np.flatnonzero(done):
                    finished[w] = _finish_episode(protocol, logs[w], terminated[w], truncated[w],
                                                  bool(np.asarray(info["diverged"])[w]), limit)
                    bar.update(1)
                active &= ~done
            rows.extend(finished[w] for w in range(count))
    finally:
        bar.close()
    return rows


def _new_log(protocol: EpisodeProtocol) -> dict[str, list]:
    return {"reward": [], **{k: [] for k in protocol.step_keys}}


def _finish_episode(protocol: EpisodeProtocol, log: dict, terminated: bool, truncated: bool,
                    diverged: bool, limit: int) -> dict:
    arrays = {k: np.asarray(v) for k, v in log.items()}
    length = len(arrays["reward"])
    arrays.update(terminated=bool(terminated), truncated=bool(truncated), diverged=diverged, length=length)
    # An episode the task or a divergence ended early counts as a fall: it did not last.
    row = {"length": length, "no_fall": not terminated, "diverged": diverged,
           "score": float(arrays["reward"].sum() / limit)}
    row.update(protocol.episode_metrics(arrays))
    return row


def format_episode_table(rows: list[dict], summary: dict) -> str:
    """The summary of an episode evaluation as aligned `metric  value` lines."""
    lines = [f"{len(rows)} episodes"]
    width = max((len(k) for k in summary), default=0)
    for key, value in summary.items():
        if key == "episodes":
            continue
        text = f"{value:.4f}" if isinstance(value, float) else str(value)
        lines.append(f"  {key:<{width}}  {text}")
    return "\n".join(lines)


__all__ = ["EvalResult", "EvalProtocol", "ClipProtocol", "EpisodeProtocol", "evaluate", "protocol_for"]


# ---------------------------------------------------------------------------------------- VR tracking
class ThreePointResult(EvalResult):
    """A three-point evaluation: rows and summary as `EvalResult` (three-point errors under the
    plain keys, full-body ones under `body_*`); the table shows the three points, then the full
    body over the clips where it is known."""

    def table(self) -> str:
        head = "three points (Head, L_Hand, R_Hand); E_mpjpe relative to the head, E_pa-mpjpe undefined:"
        text = f"{head}\n{metrics.format_table(self.rows, self.summary)}{family_table(self.rows)}"
        body_rows = [_body_row(r) for r in self.rows if "body_mpjpe_g" in r]
        if body_rows:
            summary = {"clips": len(body_rows), "success_rate": np.mean([r["success"] for r in body_rows]),
                       **{k[len("body_"):]: v for k, v in self.summary.items() if k.startswith("body_")}}
            text += ("\n\nfull body (clips with a known body; success is the three-point one):\n"
                     + metrics.format_table(body_rows, summary))
        return text


def _body_row(row: dict) -> dict:
    """A three-point row's full-body errors under the plain metric keys."""
    out = {k: row[k] for k in ("name", "success", "frames", "frames_pos", "frames_vel", "frames_acc", "fail_frame")}
    out.update({k: row[f"body_{k}"] for k in metrics.ERROR_KEYS})
    return out


class ThreePointProtocol(ClipProtocol):
    """VR three-point tracking (`SMPL/VRTracking-v0`): every clip or stream once from its first
    frame, as `ClipProtocol`, with the env's early termination off. Option: threshold (0.5 m).

    * A clip fails at the first frame where any of the three points (Head, L_Hand, R_Hand) is
      farther than `threshold` from its reference (PULSE's paper; its code trains at 0.25 m);
      tracking stops there. Frames before the env's `grace_steps` (streams: the hands moving from
      the standing start pose to the stream's) are not tested, but their errors count. A
      divergence fails it too.
    * Per clip: success, fail_frame, and `metrics.clip_metrics` of the three points' trajectories
      (E_g-mpjpe, E_acc, E_vel in mm; E_mpjpe relative to the head; E_pa-mpjpe is NaN, a
      similarity fit of three points says nothing); where the clip's full body is known, the
      same errors of all 24 bodies as `body_mpjpe_g`, `body_mpjpe_l`, `body_mpjpe_pa`,
      `body_accel`, `body_vel`.
    * Summary: `metrics.summarize` of the rows (frame weighted, as PHC; plain keys over the
      successful clips, `all_*` over all), the full-body aggregates under `body_*` (over the
      clips with a body, `body_clips`), and `score` (success rate, ties broken by the lower
      three-point E_g-mpjpe).
    """

    def make_env(self, env_id, motions, num_envs, env_kwargs, progress, options):
        import gymnasium as gym

        from .motion import load_motions
        from .motion.three_point import as_three_point_lib

        clash = sorted(set(env_kwargs) & {"motions", "termination_distance", *self.forced_kwargs})
        if clash:
            raise ValueError(f"env_kwargs must not set {clash}: evaluate() chooses them")
        motions = "walk" if motions is None else motions
        refs = as_three_point_lib(motions) or load_motions(motions, progress=progress)
        return gym.make_vec(env_id, num_envs=min(num_envs, refs.num_motions), motions=refs,
                            termination_distance=None, autoreset_mode="Disabled", **env_kwargs)

    def run(self, policy, env, options, progress):
        rows = _run_three_point(policy, env, options["threshold"], progress)
        summary = metrics.summarize(rows)
        body_rows = [_body_row(r) for r in rows if "body_mpjpe_g" in r]
        if body_rows:
            body = metrics.summarize(body_rows)
            summary["body_clips"] = body.pop("clips")
            body.pop("success_rate")
            summary.update({f"body_{k}": v for k, v in body.items()})
        error = summary.get("all_mpjpe_g")
        summary["score"] = float(summary["success_rate"]) - (1e-6 * error if error is not None and np.isfinite(error) else 0.0)
        return ThreePointResult(rows, summary, "clips")


def _run_three_point(policy: Callable, env, threshold: float, progress: bool) -> list[dict]:
    # The clip queue, recording the three points and, where the env reports it, the full body.
    u = getattr(env, "unwrapped", env)
    refs = u.references
    grace = int(getattr(u, "grace_steps", 0))
    return _clip_queue(
        policy, env, refs.num_motions,
        lambda info: ("point_pos", "ref_point_pos") + (("body_pos", "ref_body_pos") if "ref_body_pos" in info else ()),
        # A point beyond `threshold` fails the clip, from frame index `grace` on.
        lambda a, lengths: (np.linalg.norm(a[0] - a[1], axis=-1).max(axis=-1) > threshold) & (lengths > grace),
        lambda c, frames, broke: _three_point_row(refs.names[c], c, frames, broke, threshold, grace), progress)


def _three_point_row(name: str, motion_id: int, frames: list, broke: bool, threshold: float,
                     grace: int = 0) -> dict:
    """One finished clip's row (ThreePointProtocol's docstring)."""
    tracks = [np.stack(t) for t in zip(*frames)]
    # A diverged world's last frame may be non-finite: measure the frames before it.
    cut = len(frames) - 1 if broke and not all(np.isfinite(t[-1]).all() for t in tracks) else len(frames)
    sim, ref = tracks[0][:cut], tracks[1][:cut]
    row = metrics.clip_metrics(sim, ref, threshold)
    over = np.flatnonzero(np.linalg.norm(sim - ref, axis=-1).max(axis=-1)[grace:] > threshold) + grace
    row.update(success=not over.size, fail_frame=int(over[0]) if over.size else -1, mpjpe_pa=float("nan"))
    if broke and row["success"]:
        row.update(success=False, fail_frame=len(frames) - 1, frames=len(frames))
    if len(tracks) == 4:
        body = metrics.clip_metrics(tracks[2][:cut], tracks[3][:cut], threshold)
        row.update({f"body_{k}": body[k] for k in metrics.ERROR_KEYS})
    return {"name": name, "motion_id": motion_id, **row}

