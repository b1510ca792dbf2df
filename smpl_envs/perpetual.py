"""Perpetual control, measured: one long reference made of clips played one after another, in
`SMPL/Imitation-v0` with recovery on, with random shoves, and the falls, recoveries and resets
counted (PHC's perpetual humanoid control: no reset, every fall recovered).

    import smpl_envs.perpetual as perpetual
    result = perpetual.evaluate_perpetual(agent, motions="corpus:test", minutes=5)
    print(result.table())

The reference (`chained_reference`): the clips of `motions` in a seeded random order (repeated
when they are shorter than `minutes` in all), each turned and moved so it starts where the one
before ended (root position in the ground plane and heading), joined by `blend_frames` frames
that slerp every joint from the last pose to the next first pose; cut at `minutes`.

The run (`evaluate_perpetual`): `trials` worlds follow that reference from its first frame in
Imitation-v0 with recovery on (the policy's own recovery settings where it trained with them,
else the defaults; no continued terminations, reference starts only), deterministic policy, the
env's relaxed early termination at `termination_distance` (0.5 m) applying when the humanoid is
not recovering (`smpl_envs.envs.recovery`).

* Shoves (an evaluation perturbation, never part of any training): every U(`shove_every`)
  seconds (10-20 s), each world's pelvis gets a horizontal velocity change of U(`shove_speed`)
  m/s (0.5-1.5) in a uniformly random direction, added to its state between two steps (the
  observation before it does not show it). Seeded: `seed` + world.
* Per frame, the mean distance over the 24 bodies between the humanoid and the reference (m).
  A loss starts at the first frame above `threshold` (0.5 m, PHC's failure distance) and ends
  when the humanoid is back: within `threshold` at a frame and for `hold_seconds` (1 s) after
  it (as `RecoveryProtocol` counts a recovery). Its time to recover runs from its start to that
  frame. A loss is a fall when a body other than the feet went below 0.15 m or the head below
  0.3 m during it (`smpl_envs.envs.base.fallen`), and caused by a shove when one came within
  `shove_window` (2 s) before it.
* A reset: the env ends a world's episode (its own termination rule, or a diverged simulation);
  the world restarts in the reference state where the reference is then (reset option
  `start_frame`) and the loss it was in ends unrecovered. `termination_distance=None` turns the
  rule off: a body whose pose is lost with its pelvis near (where the recovery form does not
  apply) then has to find the reference again itself, and only a diverged simulation resets.
* The reference walks on while a body is lost (the default: live input, as from a video), or,
  with `reference_waits=True` (the recovery option of `smpl_envs.envs.recovery_rules`), its clock
  stops while the body is shown the recovery form or a guide's clip and goes on from the same
  frame once the body is back within `switch_distance` (input that can wait, as a generated or
  recorded motion played back): each loss is then a recovery to a fixed reference, as Recovery-v0
  trains and `RecoveryProtocol` measures, followed by the clip from where it was left.

Summary: minutes, trials, shoves, losses, falls, recovered (losses back within
`recover_within`, 10 s), unrecovered, median and max time to recover (s), resets, and
`perpetual` (True when no world was reset and every loss recovered within `recover_within`:
PHC's target).
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from types import SimpleNamespace
from typing import Iterable

import numpy as np

from . import metrics
from .evaluation import policy_actions

CONTROL_FPS = 30
ENV_ID = "SMPL/Imitation-v0"
DEFAULTS = {"motions": "corpus:test", "minutes": 5.0, "trials": 1, "shoves": True, "shove_every": (10.0, 20.0),
            "shove_speed": (0.5, 1.5), "shove_window": 2.0, "threshold": 0.5, "hold_seconds": 1.0,
            "recover_within": 10.0, "termination_distance": 0.5, "blend_frames": 10, "seed": 0,
            "reference_waits": False}


# ---------------------------------------------------------------------------------------- the reference
def heading(quat: np.ndarray) -> np.ndarray:
    """Yaw (rad) of the forward (x) axis of rotations `quat` (..., 4, wxyz) in the ground plane."""
    w, x, y, z = np.moveaxis(np.asarray(quat, float), -1, 0)
    return np.arctan2(2.0 * (x * y + w * z), 1.0 - 2.0 * (y * y + z * z))


def chained_reference(motions="corpus:test", minutes: float = 5.0, seed: int = 0, blend_frames: int = 10,
                      progress: bool = False):
    """A MotionLib of one clip, "perpetual", `minutes` long, made of the clips of `motions`
    (module docstring). Returns (library, [(clip name, first frame in the chain), ...])."""
    from .motion import MotionLib, load_motions
    from .motion.motion import RawMotion
    from .rotations import quat_slerp

    if not (isinstance(minutes, (int, float)) and minutes > 0):
        raise ValueError(f"minutes must be a positive number, got {minutes!r}")
    if isinstance(blend_frames, bool) or not isinstance(blend_frames, int) or blend_frames < 0:
        raise ValueError(f"blend_frames must be an integer >= 0, got {blend_frames!r}")
    lib = load_motions(motions, progress=progress)
    need = int(round(minutes * 60 * CONTROL_FPS)) + 1
    rng = np.random.default_rng(seed)
    roots, quats, order, total = [], [], [], 0
    while total < need:
        for i in rng.permutation(lib.num_motions):
            raw = lib.motion(int(i)).raw()
            if roots:
                end_root, end_quat = roots[-1][-1], quats[-1][-1]
                raw = raw.rotated_yaw(float(heading(end_quat[0]) - heading(raw.local_quat[0, 0])))
                root = raw.root_pos.copy()
                root[:, :2] += end_root[:2] - root[0, :2]
                if blend_frames:
                    t = (np.arange(1, blend_frames + 1) / (blend_frames + 1))[:, None]
                    roots.append(end_root + t * (root[0] - end_root))
                    quats.append(quat_slerp(end_quat[None], raw.local_quat[:1], t[:, :, None]))
                    total += blend_frames
                raw = RawMotion(raw.name, raw.fps, root, raw.local_quat)
            order.append((lib.names[int(i)], total))
            roots.append(raw.root_pos)
            quats.append(raw.local_quat)
            total += raw.num_frames
            if total >= need:
                break
    chain = RawMotion("perpetual", float(CONTROL_FPS), np.concatenate(roots)[:need], np.concatenate(quats)[:need],
                      source=f"smpl_envs.perpetual:{motions}")
    return MotionLib([chain]), order


# ---------------------------------------------------------------------------------------- the result
@dataclass
class PerpetualResult:
    """Losses (one row each), shoves, resets, the summary and the settings of a perpetual run."""

    losses: list[dict]
    shoves: list[dict]
    resets: list[dict]
    summary: dict
    settings: dict = field(default_factory=dict)
    clips: list = field(default_factory=list)

    def to_json(self) -> str:
        return json.dumps({k: metrics._plain(getattr(self, k)) for k in
                           ("summary", "settings", "losses", "shoves", "resets", "clips")}, indent=2, allow_nan=False)

    def save(self, path) -> Path:
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(self.to_json() + "\n")
        return path

    def table(self) -> str:
        s, o = self.summary, {**DEFAULTS, **self.settings}  # a result saved before an option existed
        shoves = (f"shoves every {o['shove_every'][0]:g}-{o['shove_every'][1]:g} s of {o['shove_speed'][0]:g}-"
                  f"{o['shove_speed'][1]:g} m/s" if o["shoves"] else "no shoves")
        ttr = ("-" if s["median_time_to_recover_s"] is None else
               f"{s['median_time_to_recover_s']:.2f} s median, {s['max_time_to_recover_s']:.2f} s max")
        waits = "the reference waits while a body is lost" if o["reference_waits"] else "the reference walks on"
        resets = ("no termination" if o["termination_distance"] is None
                  else f"termination beyond {o['termination_distance']:g} m")
        return "\n".join([
            f"perpetual control: {s['minutes']:g} min of {o['motions']} chained, {s['trials']} world(s), {shoves}",
            f"  {waits}; {resets}",
            f"  shoves {s['shoves']}, losses (> {o['threshold']:g} m) {s['losses']}, of them falls {s['falls']}",
            f"  recovered within {o['recover_within']:g} s: {s['recovered']}, unrecovered {s['unrecovered']}",
            f"  time to recover: {ttr}",
            f"  resets {s['resets']}",
            f"  perpetual (no reset, every loss recovered): {'yes' if s['perpetual'] else 'no'}"])

    def __str__(self) -> str:
        return self.table()


# ---------------------------------------------------------------------------------------- the run
def check_options(options: dict) -> dict:
    """The run's options with defaults filled in; a ValueError names a bad one."""
    unknown = sorted(set(options) - set(DEFAULTS))
    if unknown:
        raise ValueError(f"unknown perpetual option(s) {unknown}; options: {', '.join(DEFAULTS)}")
    o = {**DEFAULTS, **options}
    for name in ("trials", "blend_frames", "seed"):
        v = o[name]
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < (1 if name == "trials" else 0):
            raise ValueError(f"{name} must be an integer {'>= 1' if name == 'trials' else '>= 0'}, got {v!r}")
    for name in ("minutes", "threshold", "hold_seconds", "recover_within", "termination_distance", "shove_window"):
        v = o[name]
        if v is None and name == "termination_distance":
            continue
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v) or v < 0 or (
                v == 0 and name not in ("hold_seconds", "shove_window")):
            raise ValueError(f"{name} must be a positive number, got {v!r}")
    for name in ("shove_every", "shove_speed"):
        try:
            lo, hi = (float(x) for x in o[name])
        except (TypeError, ValueError):
            raise ValueError(f"{name} must be a (min, max) pair, got {o[name]!r}") from None
        if not (0 <= lo <= hi and np.isfinite(hi)) or (name == "shove_every" and lo <= 0):
            raise ValueError(f"{name} must be a (min, max) pair with 0 < min <= max, got {o[name]!r}")
        o[name] = (lo, hi)
    for name in ("shoves", "reference_waits"):
        if not isinstance(o[name], (bool, np.bool_)):
            raise ValueError(f"{name} must be true or false, got {o[name]!r}")
        o[name] = bool(o[name])
    return o


def perpetual_env_kwargs(policy, env_kwargs: dict | None = None, override_settings: Iterable[str] = ()) -> dict:
    """Imitation-v0 kwargs for `policy`: for an agent that records its training, its policy
    settings and its recovery settings (an Imitation-v0 policy's `recovery`, a Recovery-v0
    policy's own recovery kwargs); `env_kwargs` over them."""
    from . import policy_settings

    env_kwargs = dict(env_kwargs or {})
    trained = policy_settings.training_record(policy)
    if trained is None:
        return env_kwargs
    trained_id, trained_kwargs = trained
    bare = (trained_id or "").split(":", 1)[-1]
    if bare == "SMPL/Recovery-v0":
        # A recovery primitive on its own: Recovery-v0's policy settings split into the
        # imitation env's (substeps, action_mode, residual_scale) and its recovery kwargs (the
        # rest: how the recovery goal is shown, the guides included).
        settings = policy_settings.trained_settings(bare, trained_kwargs)
        imitation = policy_settings.trained_settings(ENV_ID, {})
        recovery = {k: settings.pop(k) for k in list(settings) if k not in imitation}
        return {**settings, "recovery": recovery, **env_kwargs}
    policy_settings.check_task(trained_id, ENV_ID)
    recovery = trained_kwargs.get("recovery")
    recovery = dict(recovery) if isinstance(recovery, dict) else {}
    carried = {"recovery": recovery}
    for name in ("reward_weights", "reward_scales", "energy_weight"):
        if name in trained_kwargs:
            carried[name] = trained_kwargs[name]
    return policy_settings.with_trained_settings(ENV_ID, trained_kwargs, {**carried, **env_kwargs}, override_settings)


def evaluate_perpetual(policy, *, env_kwargs: dict | None = None, override_settings: Iterable[str] = (),
                       video: str | Path | None = None, render_size: tuple[int, int] = (640, 480),
                       progress: bool = True, **options) -> PerpetualResult:
    """Run `policy` (a callable obs -> actions, or an agent) through the perpetual test (module
    docstring). `options`: those of DEFAULTS. `video`: an mp4 of world 0 (with the reference
    markers), rendered as the test runs."""
    import gymnasium as gym
    from tqdm.auto import tqdm

    o = check_options(options)
    kwargs = perpetual_env_kwargs(policy, env_kwargs, override_settings)
    recovery = kwargs.get("recovery")
    recovery = {} if recovery in (None, True, False) else dict(recovery)
    # Perpetual: a world is never continued past a termination by chance, and starts on the reference.
    recovery.update(continue_prob=0.0, starts={"reference": 1.0}, hold_end=False, reference_waits=o["reference_waits"])
    kwargs["recovery"] = recovery
    clash = sorted(set(kwargs) & {"motions", "num_envs", "autoreset_mode", "start", "termination_distance",
                                  "max_episode_steps", "motion_weights"})
    if clash:
        raise ValueError(f"env_kwargs must not set {clash}: the perpetual test chooses them")
    lib, clips = chained_reference(o["motions"], o["minutes"], o["seed"], o["blend_frames"], progress)
    n = int(o["trials"])
    render = {"render_mode": "rgb_array", "render_size": tuple(render_size)} if video is not None else {}
    env = gym.make_vec(ENV_ID, num_envs=n, motions=lib, autoreset_mode="Disabled", start="beginning",
                       termination_distance=o["termination_distance"], **kwargs, **render)
    steps = int(lib.lengths[0]) - 1
    bar = tqdm(total=steps, desc="perpetual", unit="step", disable=not progress)
    state = {}
    frames = _run(policy, env, o, steps, state, bar, render=video is not None)
    try:
        if video is not None:
            from .render import write_video

            write_video(video, frames, fps=CONTROL_FPS)
        else:
            for _ in frames:
                pass
    finally:
        bar.close()
        env.close()
    losses = []
    for w in range(n):
        for row in count_losses(state["dist"][w], state["down"][w],
                                [r["frame"] for r in state["resets"] if r["world"] == w],
                                [r["frame"] for r in state["shoves"] if r["world"] == w],
                                o["threshold"], o["hold_seconds"], o["shove_window"]):
            losses.append({"world": w, **row})
    times = [r["time_to_recover_s"] for r in losses if r["recovered"]]
    recovered = [r for r in losses if r["recovered"] and r["time_to_recover_s"] <= o["recover_within"]]
    summary = {"minutes": steps / CONTROL_FPS / 60.0, "trials": n, "shoves": len(state["shoves"]),
               "losses": len(losses), "falls": sum(r["fell"] for r in losses), "recovered": len(recovered),
               "unrecovered": len(losses) - len(recovered),
               "median_time_to_recover_s": float(np.median(times)) if times else None,
               "max_time_to_recover_s": float(np.max(times)) if times else None,
               "resets": len(state["resets"])}
    summary["perpetual"] = summary["resets"] == 0 and summary["unrecovered"] == 0
    settings = {k: (list(v) if isinstance(v, tuple) else v) for k, v in o.items()}
    return PerpetualResult(losses, state["shoves"], state["resets"], summary, settings,
                           [{"name": c, "frame": f} for c, f in clips])


def _run(policy, env, o: dict, steps: int, state: dict, bar, render: bool):
    """The perpetual test's loop, a generator of world 0's frames when `render` (else of None);
    fills `state` with the per-frame distances and falls, and the shoves and resets."""
    from .envs.base import fallen

    u = env.unwrapped
    n, b = u.num_envs, u.backend
    hum = u.humanoid
    rngs = [np.random.default_rng(o["seed"] * 100003 + w) for w in range(n)]

    def next_shove(w, t):
        return t + int(round(rngs[w].uniform(*o["shove_every"]) * CONTROL_FPS))

    obs, info = env.reset(seed=o["seed"], options={"motion_ids": np.zeros(n, np.int64), "start": "beginning"})
    obs = np.array(b.to_numpy(obs), copy=True)
    if render:
        yield u.render_frame(0)
    due = np.array([next_shove(w, 0) for w in range(n)])
    dist = np.zeros((n, steps + 1))
    down = np.zeros((n, steps + 1), bool)
    dist[:, 0] = _distance(info)
    shoves, resets = [], []
    state.update(dist=dist, down=down, shoves=shoves, resets=resets)
    for t in range(1, steps + 1):
        if o["shoves"]:
            hit = np.flatnonzero(due <= t)
            if len(hit):
                qpos, qvel = b.copy(u.sim.qpos[hit]), b.copy(u.sim.qvel[hit])
                dv = np.zeros((len(hit), 2))
                for k, w in enumerate(hit):
                    angle, speed = rngs[w].uniform(0, 2 * np.pi), rngs[w].uniform(*o["shove_speed"])
                    dv[k] = speed * np.cos(angle), speed * np.sin(angle)
                    shoves.append({"world": int(w), "frame": t, "time_s": t / CONTROL_FPS, "dv": dv[k].tolist()})
                    due[w] = next_shove(w, t)
                # The free joint's linear velocity (world frame): the pelvis' first qvel entries.
                qvel[:, hum.qvel.start:hum.qvel.start + 2] += b.asarray(dv)
                u.sim.set_state(b.asarray(hit, "int"), qpos, qvel)
        obs, _, terminated, truncated, info = env.step(policy_actions(policy, obs))
        obs = np.array(b.to_numpy(obs), copy=True)
        terminated, truncated = np.asarray(b.to_numpy(terminated), bool), np.asarray(b.to_numpy(truncated), bool)
        dist[:, t] = _distance(info)
        down[:, t] = np.asarray(fallen(SimpleNamespace(pos=np.asarray(b.to_numpy(info["body_pos"])))), bool)
        ended = np.flatnonzero(terminated & ~truncated)
        if len(ended) and t < steps:
            diverged = np.asarray(b.to_numpy(info["diverged"]), bool)
            resets.extend({"world": int(w), "frame": t, "time_s": t / CONTROL_FPS, "diverged": bool(diverged[w])}
                          for w in ended)
            mask = np.zeros(n, bool)
            mask[ended] = True
            frames = np.asarray(b.to_numpy(u.ref.frame))[ended] - int(u.motion_lib.starts[0])
            new_obs, _ = env.reset(options={"reset_mask": mask, "motion_ids": np.zeros(len(ended), np.int64),
                                            "start_frame": frames})
            obs[ended] = np.asarray(b.to_numpy(new_obs))[ended]
        bar.update(1)
        if render:
            yield u.render_frame(0)
        if truncated.all():
            break


def count_losses(dist: np.ndarray, down: np.ndarray, reset_frames: Iterable[int] = (),
                 shove_frames: Iterable[int] = (), threshold: float = 0.5, hold_seconds: float = 1.0,
                 shove_window: float = 2.0) -> list[dict]:
    """The losses of one world (module docstring) from its per-frame mean body distance `dist`
    (T,), fallen flags `down` (T,), the frames its episode was reset at (the distance there is
    the state that ended) and the frames it was shoved at. Each loss: start_s, fell, shoved,
    recovered, time_to_recover_s (None unless recovered), reset."""
    resets, shoved_at = set(int(f) for f in reset_frames), sorted(int(f) for f in shove_frames)
    hold, window = int(round(hold_seconds * CONTROL_FPS)), shove_window * CONTROL_FPS
    out, start, back, fell = [], -1, -1, False

    def close(recovered: bool, at: int, reset: bool = False):
        nonlocal start, back, fell
        out.append({"start_s": start / CONTROL_FPS, "fell": bool(fell),
                    "shoved": any(0 <= start - f <= window for f in shoved_at), "recovered": recovered,
                    "time_to_recover_s": (at - start) / CONTROL_FPS if recovered else None, "reset": reset})
        start, back, fell = -1, -1, False

    for t in range(1, len(dist)):
        lost = dist[t] > threshold
        if start < 0 and (lost or t in resets):
            start, fell = t, bool(down[t])
        elif start >= 0:
            fell |= bool(down[t])
        if start < 0:
            continue
        if t in resets:  # the episode ended here; the world restarts on the reference
            close(False, t, reset=True)
            continue
        if lost:
            back = -1
        elif back < 0:
            back = t
        if back >= 0 and t - back >= hold:
            close(True, back)
    if start >= 0:  # open at the end: back by then (if not held for long yet), or not
        close(back >= 0, back)
    return out


def _distance(info) -> np.ndarray:
    d = np.asarray(info["body_pos"], np.float64) - np.asarray(info["ref_body_pos"], np.float64)
    return np.linalg.norm(d, axis=-1).mean(-1)


__all__ = ["chained_reference", "evaluate_perpetual", "count_losses", "perpetual_env_kwargs", "check_options", "PerpetualResult",
           "DEFAULTS", "heading"]
