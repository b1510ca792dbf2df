"""`SMPL/Recovery-v0`: fail-state recovery (PHC, REFERENCE.md sections 3 and 8), and the recovery
behaviour `gym.make("SMPL/Imitation-v0", recovery=True)` switches on (perpetual control: one
policy imitates, and when it falls or drifts away it gets back without a reset).

Recovery-v0 is Imitation-v0 (same observation, actions, reward terms) with recovery on, fallen
and far starts, the default clip "stand" and the reference held at its clip's last frame past
the clip's end (episodes end at the 300-step time limit, not at the clip's end).

Starts (`starts=`, a mapping of start kind -> probability that sums to 1):

| kind | start state |
|---|---|
| reference | reference state initialisation (a random frame of a clip, as Imitation) |
| fallen | a cached fallen state (`smpl_envs.envs.fallen`) placed under the reference root |
| far | the reference-state pose moved U[far_distance] (2-5 m) away at a random bearing |
| fallen+far | a fallen state, far away as above |

Default mix (section 8's training mix, with far starts added so the far case is learnt too):
reference 0.6, fallen 0.3, far 0.05, fallen+far 0.05; and a world that would terminate goes on
as a recovery episode instead with probability `continue_prob` (0.5) and a `grace_steps` (90,
3 s) grace. Imitation with recovery=True starts from the reference only and never continues
(continue_prob 0), unless told otherwise through `recovery={...}`.

Goal forms, per world and step (batched masks; d = distance between the simulated and the
reference pelvis, 3D, so lying at the reference spot is still "far"):

* d <= switch_distance (0.5 m): the ordinary imitation goal and reward.
* d > switch_distance: the recovery form. Observation: every non-root reference body
  (position, rotation, velocities) is replaced by the simulated body's own, so its goal columns
  say "keep as you are", and the reference root is clamped to `clamp_distance` (5 m) along the
  same direction. Reward (`info["reward_point"]` and the scaled imitation terms):
      point      point_scale x min(d_prev - d, point_clip)   (9 x min(progress, 1/3), section 8's
                 code form; progress in metres per step towards the reference root)
      imitation  recovery_imitation_weight (0.5) x the imitation terms against the real
                 reference (PHC's 0.5 style slot, which this project fills with imitation: its
                 rotation term rewards an upright pose even far away)
      energy     as Imitation.
  The observation's form is decided by the distance to the reference it shows (the next frame),
  the reward's by the current one.

Actions while recovering (`recovery_action_base`, residual action mode only; a policy setting):
a residual action is added to a base, and the goal's recovery form says "keep as you are", so
the base decides what the zero action does to a body on the floor.

* "reference" (the default, and all there was before): the next reference frame's joint angles,
  as while tracking. The reference stays a standing pose while the body lies on the floor, so
  the zero action asks a fallen body to hold a standing pose, which it cannot reach from there
  with residuals of a quarter range (REFERENCE.md section 8, measured: 0 % Succ-10s).
* "pose": the simulated hinge angles. The zero action holds no pose (the PD target follows the
  body, only damping acts), so every step's residual is close to a torque command.
* "target": the PD targets of the world's step before (a fallen or far start begins at its own
  pose). The zero action holds the last commanded pose stiffly, which matches the goal's "keep
  as you are", and successive residuals move the target anywhere in the joint range, so a
  tracker's small residuals (a quarter range per step) still add up to a get-up. Near the
  reference (the goal's ordinary form) every base is the reference, so a tracker's weights mean
  what they meant, and the step the goal switches back the target returns to reference +
  residual. `tasks/recovery_tracker_ppo.yaml` measured it: a tracker's residuals on states it
  never saw are not zero-mean, and the targets integrate them into the joint limits within a
  second (docs/results/learning.md#recovery-started-from-the-tracker).
* "pull": the simulated hinge angles moved toward the reference frame's by at most the residual
  range (residual_scale x the hinge's range) per hinge. Near the reference pose this is the
  reference itself, so a standing body far from its goal stands as under "reference"; a body on
  the floor gets a bounded pull toward the standing pose, and the residual, taken around the
  pose the body is in, reaches any pose over a few steps without integrating anything (the
  base is tied to the body, not to the last target).

A get-up as the goal (`getup_guide`, off by default; `smpl_envs.envs.getup_guide`): with
get-up clips given (e.g. "corpus:getup"), a world whose goal takes the recovery form while its
body is down (pelvis below 0.4 m) is shown a get-up instead, one starting the way the body lies
(front or back), turned and placed where it lies, until the clip's last frame; meanwhile the goal,
the residual base (the body's pose pulled toward the get-up, by a range growing over its first
second) and the imitation terms are the get-up's, as when tracking, and the episode does not
terminate. It is what a tracker that has learnt the corpus' get-ups needs to use them; PHC's
recovery shows the point goal only.

A walk as the goal (`walk_guide`, off by default; `smpl_envs.envs.walk_guide`): a world whose goal
takes the recovery form while its body is up is shown a walk from where it stands to the goal
(a turn in small steps, a walk, a stop: `smpl_envs.motion.approach`), under the same rules; after
a get-up, the walk. A tracker walks where a reference walks; towards a point it stands.

Episode rules: no termination while recovering (d > switch_distance) nor during the grace that
follows a recovering step, a fallen or far start, or a continued termination (`grace_steps`);
otherwise Imitation's relaxed early termination (termination_distance). A diverged simulation
always ends the episode; the time limit truncates it.

`info` adds `recovering` ((N,) bool), `root_distance` ((N,) m) and `start_kind` ((N,) index into
START_KINDS); with `getup_guide` or `walk_guide`, `guided` ((N,) bool: the observation showed a
guide's get-up or walk).

Backends: both (`backend="cpu"` or `"warp"`), with one code path; on MuJoCo Warp the per-world
recovery state, the start draws (the env's torch generator: the same seed gives the same
episodes, not the CPU backend's), the goal switch and the rewards stay in torch on the device, and
the fallen states are generated on the host once and copied to the device (`smpl_envs.envs.fallen`).

Evaluation (`smpl-envs eval`): `RecoveryProtocol`, PHC's Succ-5s / Succ-10s for fallen, far (3 m)
and fallen+far starts on the standing clip (module `RecoveryProtocol` docstring).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field

import numpy as np

from .. import metrics
from ..metrics import recovered_within, recovery_frame  # noqa: F401 (also this module's API)
from ..evaluation import EvalProtocol, EvalResult, check_disabled_autoreset, policy_actions
from ..progress import pbar
from .getup_guide import DOWN_HEIGHT, RESTART_DISTANCE
from .imitation import ImitationVecEnv
# The rules live in their own module (the imitation env runs them too); their names stay part of
# this module's API.
from .recovery_rules import (CLAMP_DISTANCE, DEFAULT_STARTS, FAR_DISTANCE, GRACE_STEPS,  # noqa: F401
                             POINT_CLIP, POINT_SCALE, RECOVERY_IMITATION_WEIGHT, START_KINDS, SWITCH_DISTANCE,
                             RecoveryController, check_starts, point_reward, recovery_reference, root_distance)


# ---------------------------------------------------------------------- evaluation
@dataclass
class RecoveryResult(EvalResult):
    """Recovery trials (one row each), the Succ-5s / Succ-10s summary, and the protocol's
    `settings` (threshold, hold_seconds, far_distance: part of the result, not metrics)."""

    settings: dict = field(default_factory=dict)

    def to_json(self) -> str:
        return json.dumps({"trials": metrics._plain(self.rows), "summary": metrics._plain(self.summary),
                           "settings": metrics._plain(self.settings)}, indent=2, allow_nan=False)

    def table(self) -> str:
        s, o = self.summary, self.settings
        lines = [f"recovery (success: back within {o['threshold']} m mean body distance by 5 s / 10 s and "
                 f"staying to the trial's end, {10 + o['hold_seconds']:g} s; far = {o['far_distance']} m)",
                 f"  {'start':<12}{'trials':>8}{'Succ-5s':>10}{'Succ-10s':>10}{'final m':>10}"]
        for kind in START_KINDS[1:]:
            if f"trials_{kind}" in s:
                lines.append(f"  {kind:<12}{s[f'trials_{kind}']:>8}{100 * s[f'succ_5s_{kind}']:>9.1f}%"
                             f"{100 * s[f'succ_10s_{kind}']:>9.1f}%{s[f'final_distance_{kind}']:>10.2f}")
        for kind in ("fallen", "fallen+far"):
            split = [f"{side} {100 * s[f'succ_10s_{kind}_{side}']:.1f}% of {s[f'trials_{kind}_{side}']}"
                     for side in ("front", "back") if f"trials_{kind}_{side}" in s]
            if split:
                lines.append(f"  {kind} Succ-10s by the side it lies on: " + ", ".join(split))
        lines.append("  final m: median mean body distance at the trial's end (progress short of success)")
        lines.append(f"  score {s['score']:.4f}")
        return "\n".join(lines)


class RecoveryProtocol(EvalProtocol):
    """PHC's recovery evaluation (Succ-5s, Succ-10s), batched, seeded, deterministic policy.

    * For each start kind in fallen, far, fallen+far (or those `kinds` names): `trials` (1000)
      trials on the standing clip ("stand" unless `motions=` says otherwise), from its first
      frame; the reference holds the clip's last frame past its end. A far start is exactly `far_distance` (3 m) away. Trials
      run in waves of `num_envs` worlds, wave k of start kind i reset with seed
      `seed + 10000 i + k`; the env's early termination is off, so a trial lasts 10 s +
      `hold_seconds` (330 steps) unless its simulation diverges (then it fails from there).
    * Per frame, the mean distance over the 24 bodies between the simulated and the reference
      humanoid (metres, as `metrics.body_distance`). A trial is back at frame t when that
      distance is <= `threshold` (0.5 m) at t and at every later frame of the trial: "stays" =
      to the trial's end, so a humanoid that gets up and falls again is not back, and a trial
      back by 10 s has held it for at least `hold_seconds` (1 s). Succ-5s: back at a frame
      <= 150 (5 s); Succ-10s: <= 300 (`recovery_frame`, `recovered_within`).
    * Summary: per kind, trials_<kind>, succ_5s_<kind>, succ_10s_<kind> (fractions),
      final_distance_<kind> (the median mean body distance at the trial's end, m: how far short
      of success a policy stays), for fallen and fallen+far also trials_<kind>_<side> and
      succ_10s_<kind>_<side> by the side the body lies on at the start (front / back), and `score`
      (their mean over the kinds and the two horizons), which ranks checkpoints.
    """

    kinds = ("fallen", "far", "fallen+far")
    options = {"trials": 1000, "seed": 0, "threshold": 0.5, "hold_seconds": 1.0, "far_distance": 3.0, "kinds": kinds}
    motions = "stand"
    train_only_kwargs = ("start", "starts", "continue_prob", "far_distance", "termination_distance",
                         "max_episode_steps", "hold_end")

    def check_options(self, options: dict) -> dict:
        options = dict(options)
        if "episodes" in options:  # smpl-envs eval --episodes
            options["trials"] = options.pop("episodes")
        options = super().check_options(options)
        for name in ("trials", "seed"):
            v = options[name]
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < (1 if name == "trials" else 0):
                raise ValueError(f"{name} must be an integer {'>= 1' if name == 'trials' else '>= 0'}, got {v!r}")
        for name in ("threshold", "far_distance", "hold_seconds"):
            v = options[name]
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v) or v < 0 \
                    or (v == 0 and name != "hold_seconds"):
                raise ValueError(f"{name} must be a positive number, got {v!r}")
        kinds = [options["kinds"]] if isinstance(options["kinds"], str) else list(options["kinds"])
        if not kinds or any(k not in self.kinds for k in kinds) or len(set(kinds)) < len(kinds):
            raise ValueError(f"kinds must name start kinds of {list(self.kinds)}, each once, got {options['kinds']!r}")
        options["kinds"] = tuple(k for k in self.kinds if k in kinds)  # the protocol's order
        return options

    def record_kwargs(self, train_kwargs: dict) -> dict:
        # A video shows a get-up: every episode from a fallen state.
        return {**super().record_kwargs(train_kwargs), "starts": {"fallen": 1.0}}

    def make_env(self, env_id, motions, num_envs, env_kwargs, progress, options):
        import gymnasium as gym

        forced = {"motions", "starts", "continue_prob", "far_distance", "termination_distance",
                  "max_episode_steps", "hold_end", *self.forced_kwargs}
        clash = sorted(set(env_kwargs) & forced)
        if clash:
            raise ValueError(f"env_kwargs must not set {clash}: evaluate() chooses them")
        fd = float(options["far_distance"])
        return gym.make_vec(env_id, num_envs=min(num_envs, options["trials"]), autoreset_mode="Disabled",
                            motions=self.motions if motions is None else motions, termination_distance=None,
                            continue_prob=0.0, far_distance=(fd, fd), hold_end=True,
                            max_episode_steps=self.steps(options), **env_kwargs)

    @staticmethod
    def steps(options: dict) -> int:
        return int(round((10.0 + options["hold_seconds"]) * 30))

    def check_env(self, env) -> None:
        u = getattr(env, "unwrapped", env)
        check_disabled_autoreset(u)
        if getattr(u, "recovery", None) is None:
            raise ValueError("env must be a recovery env (SMPL/Recovery-v0)")
        if getattr(u, "max_episode_steps", None) is None:
            raise ValueError("env must have a time limit (max_episode_steps) for a recovery evaluation")

    def run(self, policy, env, options, progress):
        u = getattr(env, "unwrapped", env)
        n, limit = u.num_envs, u.max_episode_steps
        rows = []
        bar = pbar(total=options["trials"] * len(options["kinds"]), desc="evaluate", unit="trial", disable=not progress)
        try:
            for kind in options["kinds"]:
                i = self.kinds.index(kind)  # a kind's trials are the same whichever others run
                done = 0
                for wave in range(-(-options["trials"] // n)):
                    count = min(n, options["trials"] - done)
                    dist, broke, lying = _run_wave(policy, env, kind, options["seed"] + 10000 * i + wave, limit)
                    frames = recovery_frame(dist[:count], options["threshold"])
                    for k in range(count):
                        rows.append({"start": kind, "lying": lying[k], "recovery_frame": int(frames[k]),
                                     "succ_5s": bool(recovered_within(frames[k], 5.0)),
                                     "succ_10s": bool(recovered_within(frames[k], 10.0)),
                                     "diverged": bool(broke[k]), "final_distance": float(dist[k, -1])})
                    done += count
                    bar.update(count)
        finally:
            bar.close()
        settings = {k: options[k] for k in ("threshold", "hold_seconds", "far_distance", "seed")}
        return RecoveryResult(rows, summarize_recovery(rows), "recovery", settings)


def summarize_recovery(rows: list[dict]) -> dict:
    """Per-kind trial counts and success rates, and the mean of the rates (`score`)."""
    summary = {}
    rates = []
    for kind in START_KINDS[1:]:
        mine = [r for r in rows if r["start"] == kind]
        if mine:
            summary[f"trials_{kind}"] = len(mine)
            for h in ("5s", "10s"):
                rate = float(np.mean([r[f"succ_{h}"] for r in mine]))
                summary[f"succ_{h}_{kind}"] = rate
                rates.append(rate)
            # Median: a diverged trial's distance is inf; it counts as far, not as a NaN mean.
            summary[f"final_distance_{kind}"] = float(np.median([r["final_distance"] for r in mine]))
            for side in ("front", "back"):  # fallen starts by the side they lie on (`lying_at_start`)
                some = [r for r in mine if r.get("lying") == side]
                if some and "fallen" in kind:
                    summary[f"trials_{kind}_{side}"] = len(some)
                    summary[f"succ_10s_{kind}_{side}"] = float(np.mean([r["succ_10s"] for r in some]))
    summary["score"] = float(np.mean(rates)) if rates else 0.0
    return summary


def _run_wave(policy, env, kind: str, seed: int, limit: int):
    """(n, limit + 1) mean body distances of one wave of trials from `kind` starts, and the
    (n,) mask of diverged worlds (their distance is inf from the divergence on), and how each
    world lies at the start (`lying_at_start`)."""
    u = getattr(env, "unwrapped", env)
    n = u.num_envs
    obs, info = env.reset(seed=seed, options={"recovery_start": kind, "start": "beginning"})
    lying = lying_at_start(u.backend.to_numpy(u.sim.bodies.rot[:, 0]), u.backend.to_numpy(u.sim.bodies.pos[:, 0]))
    obs = np.array(obs, copy=True)
    dist = np.full((n, limit + 1), np.inf)
    dist[:, 0] = _distance(info)
    alive = np.ones(n, bool)
    broke = np.zeros(n, bool)
    for t in range(1, limit + 1):
        obs, _, terminated, truncated, info = env.step(policy_actions(policy, obs))
        obs = np.array(obs, copy=True)
        diverged = np.asarray(info["diverged"], bool) | np.asarray(terminated, bool)
        broke |= alive & diverged
        alive &= ~diverged
        dist[alive, t] = _distance(info)[alive]
        if not alive.any() or np.asarray(truncated, bool)[alive].all():
            break
    return dist, broke, lying


def lying_at_start(pelvis_rot, pelvis_pos) -> list[str]:
    """Per world, "front" (face down) or "back" (face up) for a pelvis below DOWN_HEIGHT, by the
    sign of the height of its forward axis (the get-up guide's rule), else "up": a fall onto the
    back needs another get-up than one onto the front, and the split says which one fails."""
    down = np.asarray(pelvis_pos)[:, 2] < DOWN_HEIGHT
    face_down = np.asarray(pelvis_rot)[:, 2, 0] < 0
    return ["up" if not d else ("front" if f else "back") for d, f in zip(down, face_down)]


def _distance(info) -> np.ndarray:
    d = np.asarray(info["body_pos"], np.float64) - np.asarray(info["ref_body_pos"], np.float64)
    return np.linalg.norm(d, axis=-1).mean(-1)


# ---------------------------------------------------------------------- environment
class RecoveryVecEnv(ImitationVecEnv):
    """`gym.make_vec("SMPL/Recovery-v0", num_envs=N, **kwargs)`.

    kwargs: starts (mapping over START_KINDS, sums to 1; default DEFAULT_STARTS), switch_distance
    (0.5 m), clamp_distance (5 m), point_scale (9), point_clip (1/3 m), recovery_imitation_weight
    (0.5), grace_steps (90), continue_prob (0.5), far_distance ((2, 5) m), hold_end (True: the
    reference holds its last frame, no truncation at the clip's end), fallen_cache_size (128),
    fallen_seed (0), recovery_action_base ("reference", "pose", "target" or "pull": module docstring),
    getup_guide (None; get-up clips, e.g. "corpus:getup", shown as the goal of a body down:
    `smpl_envs.envs.getup_guide`), walk_guide (False; True: a walk to the goal shown to a standing
    body far from it: `smpl_envs.envs.walk_guide`; "brisk": the same at a quicker pace,
    `smpl_envs.motion.approach.PACES`; True is "steady"; "brisk_exact": brisk, ending on the goal;
    "brisk_direct": that, heading straight for the goal; "quick_direct": that, turning faster),
    guide_basin (0: off; a reward weight w, with getup_guide: w exp(-10 e) for a body shown a
    get-up, e its mean squared body coordinate error from the clip, a wide basin around the clip
    where the imitation terms are ~0; it pays nothing to a body shown a walk, so with fast walks
    it can pay a body to fall: docs/results/learning.md), guide_restart
    (0.6 m: a guided body this far, in mean body distance, from its clip a second or more after
    the clip began is shown a new one), getup_blend (0 s: off; with getup_guide, a get-up starts from
    the body's own pose and fades into the clip's over this many seconds), guide_match (0 s: off; with
    getup_guide, a get-up starts at the frame of its first this many seconds nearest the body's pose);
    and Imitation's (motions: "stand", reward_weights, reward_scales,
    energy_weight, termination_distance, action_mode, residual_scale, core kwargs).
    """

    evaluation = RecoveryProtocol()
    backends = ("cpu", "warp")
    # When and how the observation takes the recovery form, and what a residual action is added to then.
    policy_kwargs = (*ImitationVecEnv.policy_kwargs, "switch_distance", "clamp_distance", "recovery_action_base",
                     "getup_guide", "walk_guide", "guide_restart", "getup_blend", "guide_match")
    # Of those, the ones that choose which clips the goal shows, not what an observation or action
    # means: a warm start (`agents.warm_start`) may change them, as it may change the motions.
    goal_settings = ("getup_guide", "walk_guide", "guide_restart", "getup_blend", "guide_match")
    switch_distance = property(lambda self: self.recovery.switch_distance)
    clamp_distance = property(lambda self: self.recovery.clamp_distance)
    recovery_action_base = property(lambda self: self.recovery.action_base)
    getup_guide = property(lambda self: self.recovery.getup_guide)
    walk_guide = property(lambda self: self.recovery.walk_guide)
    guide_restart = property(lambda self: self.recovery.guide_restart)
    getup_blend = property(lambda self: self.recovery.getup_blend)
    guide_match = property(lambda self: self.recovery.guide_match)

    def __init__(self, num_envs: int = 1, *, motions="stand", starts=None, switch_distance=SWITCH_DISTANCE,
                 clamp_distance=CLAMP_DISTANCE, point_scale=POINT_SCALE, point_clip=POINT_CLIP,
                 recovery_imitation_weight=RECOVERY_IMITATION_WEIGHT, grace_steps=GRACE_STEPS,
                 continue_prob=0.5, far_distance=FAR_DISTANCE, hold_end=True, fallen_cache_size=128,
                 fallen_seed=0, recovery_action_base="reference", getup_guide=None, walk_guide=False,
                 guide_basin=0.0, guide_restart=RESTART_DISTANCE, getup_blend=0.0, guide_match=0.0,
                 **kwargs):
        if "recovery" in kwargs:
            raise ValueError("recovery: Recovery-v0 always recovers; its settings are its own kwargs")
        recovery = dict(starts=DEFAULT_STARTS if starts is None else starts, switch_distance=switch_distance,
                        clamp_distance=clamp_distance, point_scale=point_scale, point_clip=point_clip,
                        recovery_imitation_weight=recovery_imitation_weight, grace_steps=grace_steps,
                        continue_prob=continue_prob, far_distance=far_distance, hold_end=hold_end,
                        fallen_cache_size=fallen_cache_size, fallen_seed=fallen_seed,
                        recovery_action_base=recovery_action_base, getup_guide=getup_guide,
                        walk_guide=walk_guide, guide_basin=guide_basin, guide_restart=guide_restart,
                        getup_blend=getup_blend, guide_match=guide_match)
        super().__init__(num_envs, motions=motions, recovery=recovery, **kwargs)

    def regenerate_fallen(self, seed: int | None = None) -> None:
        """Draw a new set of fallen states (from `seed`, or the env's generator)."""
        self.recovery.fallen.regenerate(int(self.np_random.integers(2**31)) if seed is None else seed)
