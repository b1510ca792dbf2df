"""Benchmark a motion-imitation policy on every clip of a motion library (PHC's protocol).

    from smpl_envs.evaluation import evaluate
    result = evaluate(policy, "SMPL/Imitation-v0", motions="path/to/amass_test")
    print(result)                      # per-clip table, then the aggregate line
    result.save("runs/eval.json")

Protocol (Perpetual Humanoid Control, Luo et al. 2023):

* Every clip of the library is imitated exactly once, from its first frame (the humanoid starts
  in the reference state of frame 0), until its last frame. Nothing is random: the env is reset
  with seed 0 and no clip or start frame is sampled, so two runs give the same numbers.
* A clip fails at the first frame where the mean distance over all 24 bodies between the
  simulated and the reference humanoid exceeds `threshold` (0.5 m). Imitation stops there; the
  failing frame is the last one of the recorded trajectory. The env's own early termination is
  switched off (it leaves out the feet and would end clips by a different rule). A simulation
  that diverges also fails the clip at that frame.
* Per clip, `smpl_envs.metrics.clip_metrics` turns the recorded simulated and reference body
  positions (every frame from the initial one to the last one imitated) into success and the
  errors in mm: E_g-mpjpe, E_mpjpe (root-relative), E_acc, E_vel.
* The aggregate (`metrics.summarize`) is the success rate and each error averaged over the
  successful clips, as PHC reports them, with the averages over all clips alongside (`all_*`).

Clips run batched: each of the env's worlds takes the next clip from a queue whenever its
current one ends, so the result does not depend on the number of worlds.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np
from gymnasium.vector import AutoresetMode
from tqdm.auto import tqdm

from . import metrics

# evaluate() sets these when it makes the env itself; env_kwargs must not override them.
_FORCED_KWARGS = ("num_envs", "motions", "termination_distance", "autoreset_mode")


@dataclass
class EvalResult:
    """Per-clip rows (clip_metrics plus `name`, `motion_id`, in library order) and their summary."""

    rows: list[dict]
    summary: dict = field(default_factory=dict)

    def table(self) -> str:
        return metrics.format_table(self.rows, self.summary)

    def to_json(self) -> str:
        return metrics.to_json(self.rows, self.summary)

    def save(self, path) -> Path:
        """Write `to_json()` to `path` (parent directories created); returns the path."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(self.to_json() + "\n")
        return path

    def __str__(self) -> str:
        return self.table()


def evaluate(policy: Callable, env="SMPL/Imitation-v0", *, motions=None, num_envs: int = 8,
             threshold: float = 0.5, progress: bool = True, env_kwargs: dict | None = None) -> EvalResult:
    """Imitate every clip once with `policy` and measure it (protocol in the module docstring).

    policy: callable from observations (N, D) float32 to actions (N, 69); a returned tuple
        (e.g. stable-baselines' `predict`, which returns (actions, state)) counts by its first item.
    env: a registered task id (an env of min(num_envs, clips) worlds is made with `motions`
        (default "walk") and `env_kwargs`, and closed afterwards), or an existing smpl_envs vec
        env made with autoreset_mode="Disabled", termination_distance=None and no
        max_episode_steps; it is reset with seed 0 and evaluated on its own motion library.
    """
    made = isinstance(env, str)
    if made:
        env = _make_env(env, motions, num_envs, env_kwargs, progress)
    else:
        if motions is not None or env_kwargs is not None:
            raise ValueError("motions and env_kwargs are only for an env id; an existing env is "
                             "evaluated on its own motion library")
        _check_env(env)
    try:
        rows = _run(policy, env, threshold, progress)
    finally:
        if made:
            env.close()
    return EvalResult(rows, metrics.summarize(rows))


def _make_env(env_id: str, motions, num_envs: int, env_kwargs: dict | None, progress: bool):
    import gymnasium as gym

    from .envs import load_motions  # imported here: pulls in MuJoCo, not needed for the results API

    env_kwargs = dict(env_kwargs or {})
    clash = sorted(set(env_kwargs) & set(_FORCED_KWARGS))
    if clash:
        raise ValueError(f"env_kwargs must not set {clash}: evaluate() chooses them")
    if int(num_envs) < 1:
        raise ValueError(f"num_envs must be >= 1, got {num_envs}")
    # Load once here: the clip count sizes the env (no idle worlds), and the env reuses the library.
    lib = load_motions("walk" if motions is None else motions, progress=progress)
    env = gym.make_vec(env_id, num_envs=min(int(num_envs), lib.num_motions), motions=lib,
                       termination_distance=None, autoreset_mode="Disabled", **env_kwargs)
    try:
        _check_env(env)
    except ValueError:
        env.close()
        raise
    return env


def _check_env(env) -> None:
    """ValueError unless `env` is a suite vec env that never ends a clip early by itself."""
    u = getattr(env, "unwrapped", env)
    if not (hasattr(u, "motion_lib") and hasattr(u, "num_envs") and hasattr(u, "reference_action")):
        raise ValueError(f"env must be a smpl_envs vec env (gym.make_vec of an SMPL/ task), got {type(env).__name__}")
    mode = u.metadata.get("autoreset_mode")
    if mode is None or AutoresetMode(getattr(mode, "value", mode)) != AutoresetMode.DISABLED:
        raise ValueError(f"env must be made with autoreset_mode='Disabled' (evaluate resets worlds "
                         f"itself), got {getattr(mode, 'value', mode)!r}")
    if getattr(u, "termination_distance", None) is not None:
        raise ValueError(f"env must be made with termination_distance=None (evaluate applies the "
                         f"success threshold itself), got {u.termination_distance!r}")
    if getattr(u, "max_episode_steps", None) is not None:
        raise ValueError(f"env must be made with max_episode_steps=None (clips run to their last "
                         f"frame), got {u.max_episode_steps!r}")


def _run(policy: Callable, env, threshold: float, progress: bool) -> list[dict]:
    u = getattr(env, "unwrapped", env)
    lib = u.motion_lib
    n, m = u.num_envs, lib.num_motions
    clip = np.full(n, -1, np.int64)            # clip each world imitates; -1 = idle
    sim_traj = [[] for _ in range(n)]          # per world: (24, 3) frames of its current clip
    ref_traj = [[] for _ in range(n)]
    broke = np.zeros(n, bool)                  # current clip ended by the env (divergence)
    rows: list[dict | None] = [None] * m

    def record(worlds, info, terminated=None, truncated=None):
        """Append the current frame of `worlds`; return those whose clip ends at this frame."""
        sim = np.asarray(info["body_pos"])[worlds]
        ref = np.asarray(info["ref_body_pos"])[worlds]
        for k, w in enumerate(worlds):
            sim_traj[w].append(sim[k].copy())
            ref_traj[w].append(ref[k].copy())
        # Same formula as metrics.body_distance, in float64 like clip_metrics, so the stop
        # decision here and the fail frame it reports always agree.
        stop = np.linalg.norm(sim.astype(np.float64) - ref.astype(np.float64), axis=-1).mean(axis=1) > threshold
        if terminated is not None:
            # Termination is off, so the env only ends a clip early when its simulation diverged.
            broke[worlds] = terminated[worlds]
            stop |= terminated[worlds] | truncated[worlds]
        return worlds[stop]

    # Every world starts at once (idle ones on any clip: their steps are ignored). A fixed seed
    # only matters if something in the env draws randomness; with explicit clips and
    # start="beginning" nothing does.
    first = min(n, m)
    obs, info = env.reset(seed=0, options={"motion_ids": np.arange(n) % m, "start": "beginning"})
    obs = np.array(obs, copy=True)
    clip[:first] = np.arange(first)
    next_clip = first
    done = record(np.arange(first), info)
    bar = tqdm(total=m, desc="evaluate", unit="clip", disable=not progress)
    try:
        while True:
            # Finish ended clips and refill those worlds; a clip may end on its initial frame,
            # hence the loop.
            while len(done):
                for w in done:
                    rows[clip[w]] = _finish(lib, clip[w], sim_traj[w], ref_traj[w], broke[w], threshold)
                    sim_traj[w], ref_traj[w], clip[w], broke[w] = [], [], -1, False
                    bar.update(1)
                take = done[:m - next_clip]
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
            actions = policy(obs)
            if isinstance(actions, tuple):
                actions = actions[0]
            obs, _, terminated, truncated, info = env.step(np.asarray(actions))
            obs = np.array(obs, copy=True)
            done = record(active, info, np.asarray(terminated, bool), np.asarray(truncated, bool))
    finally:
        bar.close()
    return rows


def _finish(lib, motion_id: int, sim: list, ref: list, broke: bool, threshold: float) -> dict:
    """clip_metrics of one finished clip, plus its name and id."""
    sim, ref = np.stack(sim), np.stack(ref)
    # A diverged world's last frame may be non-finite; measure the frames before it and still
    # count the clip as failed at that frame.
    cut = len(sim) - 1 if broke and not np.isfinite(sim[-1]).all() else len(sim)
    row = metrics.clip_metrics(sim[:cut], ref[:cut], threshold)
    if broke and row["success"]:
        row.update(success=False, fail_frame=len(sim) - 1, frames=len(sim))
    return {"name": lib.names[motion_id], "motion_id": int(motion_id), **row}


__all__ = ["EvalResult", "evaluate"]
