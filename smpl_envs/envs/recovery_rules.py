"""The recovery rules of an imitation env (PHC's fail-state recovery; `smpl_envs.envs.recovery`
documents them): start kinds and their mix, the goal switch beyond `switch_distance`, the point
reward, the grace after a recovering step, and the per-world state that carries them
(`RecoveryController`). Imitation-v0 with `recovery=True` and Recovery-v0 both run them; the
module stands on its own so that the imitation env can use it without importing the Recovery
task built on the imitation env.
"""

from __future__ import annotations

import functools
from collections.abc import Mapping

import numpy as np

from ..features import BodyState, xp
from ..motion.approach import PACES
from ..motion.library import DeviceFrames, load_motions
from .base import check_number, check_range
from .fallen import FallenStates
from .getup_guide import DOWN_HEIGHT, RESTART_DISTANCE, SETTLE_STEPS, GetupGuide
from .walk_guide import OFF_SPOT, TURN_AWAY, WalkGuide, heading_of, wrap_angle

START_KINDS = ("reference", "fallen", "far", "fallen+far")
DEFAULT_STARTS = {"reference": 0.6, "fallen": 0.3, "far": 0.05, "fallen+far": 0.05}
SWITCH_DISTANCE = 0.5
CLAMP_DISTANCE = 5.0
POINT_SCALE = 9.0
POINT_CLIP = 1.0 / 3.0
RECOVERY_IMITATION_WEIGHT = 0.5
GRACE_STEPS = 90
# The get-up basin (`guide_basin`, off by default): the imitation reward's position term is
# exp(-100 e), e the mean squared body coordinate error, which is ~0 (1e-3) at the 0.4 m a fall
# leaves a body from the get-up it is shown; this scale keeps it 0.5 there and 0.9 at 0.1 m.
GUIDE_BASIN_SCALE = 10.0
FAR_DISTANCE = (2.0, 5.0)
# What a residual action is added to while the goal shows its recovery form (module docstring of
# `smpl_envs.envs.recovery`): the reference (as while tracking), the simulated pose, the PD
# target of the step before, or the simulated pose pulled toward the reference by at most a
# residual range.
ACTION_BASES = ("reference", "pose", "target", "pull")
FALLEN, FAR = np.array([False, True, False, True]), np.array([False, False, True, True])


# ---------------------------------------------------------------------- pure functions
def check_starts(starts) -> np.ndarray:
    """(4,) probabilities over START_KINDS from a {kind: probability} mapping summing to 1."""
    if not isinstance(starts, Mapping) or not starts:
        raise ValueError(f"starts must be a mapping of start kind -> probability over {START_KINDS}, got {starts!r}")
    unknown = sorted(set(starts) - set(START_KINDS))
    if unknown:
        raise ValueError(f"starts: unknown start kind(s) {unknown}; known: {list(START_KINDS)}")
    try:
        p = np.array([float(starts.get(k, 0.0)) for k in START_KINDS])
    except (TypeError, ValueError):
        raise ValueError(f"starts: probabilities must be numbers, got {starts!r}") from None
    if not np.isfinite(p).all() or (p < 0).any() or abs(p.sum() - 1.0) > 1e-6:
        raise ValueError(f"starts: probabilities must be >= 0 and sum to 1, got {starts!r} (sum {p.sum():.6g})")
    return p / p.sum()


def root_distance(sim: BodyState, ref: BodyState):
    """(N,) distance (m) between the simulated and the reference pelvis."""
    d = ref.pos[:, 0] - sim.pos[:, 0]
    return xp(d).sqrt((d * d).sum(-1))


def point_reward(d_prev, d, scale: float = POINT_SCALE, clip: float = POINT_CLIP):
    """(N,) root-distance progress reward scale x min(d_prev - d, clip): positive when closing in."""
    if xp(d_prev, d) is np:
        d_prev, d = np.asarray(d_prev), np.asarray(d)
    return scale * (d_prev - d).clip(max=clip)


def recovery_reference(sim: BodyState, ref: BodyState, far, clamp: float = CLAMP_DISTANCE) -> BodyState:
    """The reference the goal shows: for worlds in the mask `far`, non-root bodies replaced by the
    simulated ones and the root position clamped to `clamp` m from the simulated root along the
    same direction; other worlds keep `ref`."""
    m = xp(sim.pos, ref.pos)
    delta = ref.pos[:, 0] - sim.pos[:, 0]
    dist = m.sqrt((delta * delta).sum(-1))
    root = sim.pos[:, 0] + delta * (clamp / dist.clip(min=1e-9)).clip(max=1.0)[:, None]
    f3, f4 = far[:, None, None], far[:, None, None, None]
    out = {}
    for name, f in (("pos", f3), ("rot", f4), ("lin_vel", f3), ("ang_vel", f3)):
        a = m.where(f, getattr(sim, name), getattr(ref, name))
        a[:, 0] = getattr(ref, name)[:, 0]
        out[name] = a
    out["pos"][:, 0] = m.where(far[:, None], root, ref.pos[:, 0])
    return BodyState(dof_pos=ref.dof_pos, dof_vel=ref.dof_vel, **out)


def where_state(mask, a: BodyState, b: BodyState) -> BodyState:
    """Per world, `a` where the (N,) mask is set, else `b`."""
    m = xp(a.pos, b.pos)
    pick = lambda x, y: m.where(mask.reshape(-1, *([1] * (x.ndim - 1))), x, y)  # noqa: E731
    return BodyState(**{k: pick(getattr(a, k), getattr(b, k)) for k in ("pos", "rot", "lin_vel", "ang_vel", "dof_pos",
                                                                        "dof_vel")})


# ---------------------------------------------------------------------- per-world recovery state
class RecoveryController:
    """The recovery state and rules of an imitation env's worlds (module docstring); the env
    calls it from its hooks. kwargs are the recovery kwargs of Recovery-v0.

    One code path for both backends (`smpl_envs.backend`): per-world arrays, masks and random
    draws go through the env's backend, so on MuJoCo Warp everything a step or a reset does here
    stays in torch on the env's device; only the fallen states are made on the host (at setup,
    copied to the device once: `FallenStates`)."""

    def __init__(self, env, *, starts=None, switch_distance=SWITCH_DISTANCE, clamp_distance=CLAMP_DISTANCE,
                 point_scale=POINT_SCALE, point_clip=POINT_CLIP, recovery_imitation_weight=RECOVERY_IMITATION_WEIGHT,
                 grace_steps=GRACE_STEPS, continue_prob=0.0, far_distance=FAR_DISTANCE, hold_end=False,
                 fallen_cache_size=128, fallen_seed=0, recovery_action_base="reference", getup_guide=None,
                 walk_guide=False, guide_basin=0.0, guide_restart=RESTART_DISTANCE, getup_blend=0.0,
                 guide_match=0.0, reference_waits=False):
        self.p = check_starts({"reference": 1.0} if starts is None else starts)
        if recovery_action_base not in ACTION_BASES:
            raise ValueError(f"recovery_action_base must be one of {ACTION_BASES}, got {recovery_action_base!r}")
        self.action_base = recovery_action_base
        self.switch_distance = check_number("switch_distance", switch_distance, positive=True)
        self.clamp_distance = check_number("clamp_distance", clamp_distance, positive=True)
        self.point_clip = check_number("point_clip", point_clip, positive=True)
        self.point_scale = check_number("point_scale", point_scale)
        self.imitation_weight = check_number("recovery_imitation_weight", recovery_imitation_weight)
        self.continue_prob = check_number("continue_prob", continue_prob)
        if self.continue_prob > 1.0:
            raise ValueError(f"continue_prob must be a probability in [0, 1], got {continue_prob!r}")
        if isinstance(grace_steps, bool) or not isinstance(grace_steps, (int, np.integer)) or grace_steps < 0:
            raise ValueError(f"grace_steps must be a non-negative integer, got {grace_steps!r}")
        self.grace_steps = int(grace_steps)
        self.far_distance = check_range("far_distance", far_distance, 0.0)
        self.hold_end = bool(hold_end)
        if not isinstance(reference_waits, (bool, np.bool_)):
            raise ValueError(f"reference_waits must be True or False, got {reference_waits!r}")
        self.reference_waits = bool(reference_waits)
        self.backend = b = env.backend
        self.fallen = FallenStates(fallen_cache_size, fallen_seed, b)
        self.hum = env.humanoid
        self._fallen_kind, self._far_kind = b.asarray(FALLEN, "bool"), b.asarray(FAR, "bool")
        n = env.num_envs
        self.start_kind = b.zeros(n, "int")
        self.root_distance = b.zeros(n)
        self.grace = b.zeros(n, "int")
        self.showing = b.zeros(n, "bool")    # the last observation's goal is in the recovery form
        self.getup_blend = check_number("getup_blend", getup_blend)
        if self.getup_blend and getup_guide is None:
            raise ValueError("getup_blend fades a body's own pose into the get-up it is shown, so it needs getup_guide")
        self.guide_match = check_number("guide_match", guide_match)
        if self.guide_match and getup_guide is None:
            raise ValueError("guide_match chooses where a get-up starts, so it needs getup_guide")
        self.guide = None if getup_guide is None else _make_guide(getup_guide, env, self.getup_blend, self.guide_match)
        self.getup_guide = getup_guide
        pace = _walk_pace(walk_guide)
        self.walk = _make_walk_guide(env, pace) if pace else None
        self.walk_guide = walk_guide if isinstance(walk_guide, str) else bool(pace)  # as given: a policy setting
        self._walk_early = bool(pace) and PACES[pace].early
        self.guide_basin = check_number("guide_basin", guide_basin)
        self.guide_restart = check_number("guide_restart", guide_restart, positive=True)
        if self.guide_basin and self.guide is None:
            raise ValueError("guide_basin rewards nearing a get-up, so it needs getup_guide")
        self._guides = tuple(g for g in (self.guide, self.walk) if g is not None)  # fixed from here on
        self.guided = b.zeros(n, "bool")     # the last observation's goal is a guide's clip (get-up or walk)
        self._shown = [b.zeros(n, "bool") for _ in self._guides]  # ... per guide
        self.last_target = b.zeros((n, env.single_action_space.shape[0]))  # each world's last PD targets

    def set_starts(self, starts) -> None:
        """A new start mix ({kind: probability}, as `starts=`) for the resets from now on: what a
        get-up curriculum changes over training (`agents.curriculum`)."""
        self.p = check_starts(starts)

    @property
    def starts(self) -> dict[str, float]:
        return {k: float(p) for k, p in zip(START_KINDS, self.p)}

    def reset(self, ids, qpos, qvel, ref_root, kind, rng):
        """Start states of worlds `ids` from their reference-state (qpos, qvel) and reference
        roots (n, 3): drawn from the start mix, or `kind` (a START_KINDS name, or one per world)."""
        b, xp = self.backend, self.backend.xp
        n = len(ids)
        if kind is None:
            kinds = b.choice(rng, len(START_KINDS), n, self.p)
        else:
            names = [kind] * n if isinstance(kind, str) else list(kind)
            bad = sorted({str(k) for k in names} - set(START_KINDS))
            if bad or len(names) != n:
                raise ValueError(f"reset option recovery_start must be one of {START_KINDS} or {n} of them, got {kind!r}")
            kinds = b.asarray([START_KINDS.index(k) for k in names], "int")
        fallen, far = self._fallen_kind[kinds], self._far_kind[kinds]
        q = qpos[:, self.hum.qpos]  # a view: written in place
        if fallen.any():
            q[fallen] = self.fallen.place(rng, ref_root[fallen, :2])
            qvel[fallen, self.hum.qvel] = 0.0
        if far.any():
            m = int(far.sum())
            r = b.uniform(rng, m, *self.far_distance)
            bearing = b.uniform(rng, m, 0.0, 2.0 * np.pi)
            q[far, :2] += b.asarray(r[:, None] * xp.stack([xp.cos(bearing), xp.sin(bearing)], -1))
        self.start_kind[ids] = kinds
        for g, shown in zip(self._guides, self._shown):
            g.stop(ids)
            shown[ids] = False
        self.guided[ids] = False
        self.last_target[ids] = q[:, 7:]  # "target" base: a start holds the pose it starts in
        self.grace[ids] = xp.where(kinds > 0, self.grace_steps, 0)
        d = q[:, :3] - ref_root
        self.root_distance[ids] = xp.sqrt((d * d).sum(-1))
        return qpos, qvel

    def evaluate(self, body, ref, reward, terms, terminated, truncated, rng, guide_terms=None):
        """Reward, terms, terminated and truncated of the recovery rules, from Imitation's;
        `guide_terms`: the imitation terms against the get-ups (`guide_reference`), which the
        guided worlds get instead of the weighted ones."""
        b, xp = self.backend, self.backend.xp
        d = root_distance(body, ref)
        rec = d > self.switch_distance
        point = point_reward(self.root_distance, d, self.point_scale, self.point_clip)
        self.root_distance = d
        guided = None if guide_terms is None else self.guided
        held = rec  # what keeps the grace at its full length
        if rec.any() or guided is not None:
            w = xp.where(rec, self.imitation_weight, 1.0)
            terms = {k: (v if k == "energy" else v * w) for k, v in terms.items()}
            if guided is not None:
                terms = {k: (xp.where(guided, guide_terms[k], v) if k != "energy" else v) for k, v in terms.items()}
                # A get-up holds the grace; a walk shown to a body already near its goal (a turn, or
                # a step onto the spot) does not, so the grace that shows such walks runs out even
                # for a body that never lands within OFF_SPOT (it would be shown steps forever).
                if self.guide is not None:
                    held = rec | self._shown[0]
                rec = rec | guided  # no termination while a guide's clip plays
            if self.guide_basin:
                terms["basin"] = self._basin(body) if guided is not None else xp.zeros_like(reward)
            terms["point"] = xp.where(rec, point, 0.0)
            reward = sum(terms.values())
        else:
            terms = {**terms, "point": xp.zeros_like(reward)}
            if self.guide_basin:
                terms["basin"] = xp.zeros_like(reward)
        self.grace = xp.where(held, self.grace_steps, (self.grace - 1).clip(min=0))
        terminated = terminated & ~rec & (self.grace == 0)
        if self.continue_prob > 0 and terminated.any():
            ids = b.nonzero(terminated)
            go_on = ids[b.uniform(rng, len(ids)) < self.continue_prob]
            terminated[go_on] = False
            self.grace[go_on] = self.grace_steps
        if self.hold_end:
            truncated = xp.zeros_like(truncated)
        return reward, terms, terminated, truncated

    def _basin(self, body):
        """(N,) the get-up basin term (GUIDE_BASIN_SCALE) for the worlds shown a get-up, 0 elsewhere."""
        d = self.guide.current().pos - body.pos
        e = (d * d).sum((-1, -2)) * (1.0 / (3 * d.shape[1]))
        return self.backend.xp.where(self._shown[0], self.guide_basin * self.backend.xp.exp(-GUIDE_BASIN_SCALE * e), 0.0)

    def goal_reference(self, body, ref_next, rng=None):
        """The reference the observation shows (`recovery_reference` beyond switch_distance; with
        `getup_guide`, a get-up for a body down, started here: `smpl_envs.envs.getup_guide`)."""
        far = root_distance(body, ref_next) > self.switch_distance
        guides = self._guides
        if not guides:
            self.showing = far
            return recovery_reference(body, ref_next, far, self.clamp_distance) if far.any() else ref_next
        low = body.pos[:, 0, 2] < DOWN_HEIGHT
        down = far & low
        g, w = self.guide, self.walk
        if g is not None and down.any():
            lost = g.active & (g.age >= SETTLE_STEPS) & (g.distance(body) > self.guide_restart)
            new = down & (~g.active | lost)  # a body that fell while walking too
            g.start(new, body, rng)
            if w is not None:
                w.stop(self.backend.nonzero(new))
        if w is not None:
            busy = self.backend.zeros(len(far), "bool")
            if g is not None:  # rising: not yet; an early pace takes over from a get-up shown standing still
                busy = g.active & ~g.standing_still() if self._walk_early else g.active
            lost = w.active & (w.age >= SETTLE_STEPS) & (w.distance(body) > self.guide_restart)
            # Back near the goal but facing away (only just recovered: within the grace, so a
            # tracked clip's own quick turns are left to the tracker): a turn on the spot.
            just_back = self.grace > 0
            away = just_back & (abs(wrap_angle(heading_of(body.rot) - heading_of(ref_next.rot))) > TURN_AWAY)
            move = far
            if w.exact:  # or off the spot: a tracker shown a standing reference half a metre away stands
                off = just_back & (root_distance(body, ref_next) > OFF_SPOT)
                away, move = away | off, far | off
            walk = ~low & ~busy & (far | away) & (~w.active | lost)
            w.start(walk, body, ref_next, move)
            if g is not None:
                g.stop(self.backend.nonzero(walk & g.active))
        # Which guide each world's observation shows; the step's residual base and reward follow it
        # even when the clip ends in between (`advance`).
        self._shown = [self.backend.copy(guide.active) for guide in guides]
        self.guided = functools.reduce(lambda a, b: a | b, self._shown)
        self.showing = far & ~self.guided
        out = recovery_reference(body, ref_next, self.showing, self.clamp_distance) if self.showing.any() else ref_next
        for guide, shown in zip(guides, self._shown):
            if shown.any():
                out = where_state(shown, guide.next(), out)
        return out

    def guide_reference(self):
        """The guides' frames the guided worlds' bodies should match now; None when no world is
        guided (no guide, or none shown), so the reward's extra terms are computed only then."""
        if not bool(self.guided.any()):
            return None
        pairs = [(g, shown) for g, shown in zip(self._guides, self._shown) if shown.any()]
        out = pairs[0][0].current()
        for g, shown in pairs[1:]:
            out = where_state(shown, g.current(), out)
        return out

    def advance(self, active=None) -> None:
        for g in self._guides:
            g.advance(active)

    def reference_running(self, active=None):
        """The worlds whose reference clock moves on this step (of `active`, None: all): with
        `reference_waits`, not those whose last observation showed the recovery form or a guide's
        clip, so that a lost body is led back to the reference where it was lost, not where it
        has gone since."""
        if not self.reference_waits:
            return active
        waiting = self.showing | self.guided
        return ~waiting if active is None else active & ~waiting

    def pd_targets(self, targets, actions, action_scale, action_mode: str, residual_scale: float, pose, ref_pose):
        """The PD targets of a step: Imitation's `targets`, except for residual actions of worlds
        whose last observation showed the recovery goal, which are added to the base
        `recovery_action_base` names: the simulated hinge angles `pose` ("pose"), the PD targets
        of the world's last step ("target"), or `pose` moved toward the reference frame's hinge
        angles `ref_pose` by at most the residual range per hinge ("pull"). Records every world's
        targets for the next step."""
        if self.action_base != "reference" and action_mode == "residual" and bool(self.showing.any()):
            span = residual_scale * action_scale
            if self.action_base == "pull":
                base = pose + (ref_pose - pose).clip(-span, span)
            else:
                base = pose if self.action_base == "pose" else self.last_target
            moved = (base + actions * span).clip(-action_scale, action_scale)
            targets = self.backend.xp.where(self.showing[:, None], moved, targets)
        if action_mode == "residual" and bool(self.guided.any()):
            # A guide's clip is tracked as a reference is, around the body's pose pulled toward its
            # next frame by at most the residual range (near the clip: its frame), a range that
            # grows from 0 over the clip's first second, so that a body lying in another pose is
            # not yanked into the clip's by its PD gains (it leaves the floor).
            span = residual_scale * action_scale
            for g, shown in zip(self._guides, self._shown):
                if bool(shown.any()):
                    pull = span * g.settled()[:, None]
                    base = pose + (g.next_dof_pos() - pose).clip(-pull, pull)
                    follow = (base + actions * span).clip(-action_scale, action_scale)
                    targets = self.backend.xp.where(shown[:, None], follow, targets)
        self.last_target[:] = targets
        return targets

    def info(self) -> dict:
        copy = self.backend.copy
        info = {"recovering": self.root_distance > self.switch_distance, "root_distance": copy(self.root_distance),
                "start_kind": copy(self.start_kind)}
        if self._guides:
            info["guided"] = copy(self.guided)
        return info


def _make_guide(motions, env, blend: float, match: float) -> GetupGuide:
    try:
        lib = load_motions(motions)
    except (ValueError, FileNotFoundError) as e:
        raise ValueError(f"getup_guide: {e}") from None
    frames = lib if env.backend.name == "cpu" else DeviceFrames(lib, env.backend.device)
    return GetupGuide(lib, frames, env.num_envs, env.backend, blend, match)


def _walk_pace(walk_guide):
    """`walk_guide` as given (False, or a pace of `smpl_envs.motion.approach.PACES`); True is
    "steady", the pace of the first walk guide, so that policies trained with True keep it."""
    if walk_guide is True or walk_guide is np.True_:
        return "steady"
    if walk_guide is False or walk_guide is np.False_ or walk_guide is None:
        return False
    if not isinstance(walk_guide, str) or walk_guide not in PACES:
        raise ValueError(f"walk_guide must be True, False or a pace of {sorted(PACES)}, got {walk_guide!r}")
    return walk_guide


def _make_walk_guide(env, pace: str) -> WalkGuide:
    lib = approach_library(pace)
    frames = lib if env.backend.name == "cpu" else DeviceFrames(lib, env.backend.device)
    return WalkGuide(lib, frames, env.num_envs, env.backend, exact=PACES[pace].exact)


@functools.lru_cache(maxsize=2)
def approach_library(pace: str = "steady"):
    """The walk guide's clips at `pace` (`smpl_envs.motion.approach.approach_set`), made once per
    process: a few seconds of generation every recovery env would otherwise repeat."""
    from ..motion.approach import approach_set
    from ..motion.library import MotionLib

    return MotionLib(approach_set(pace))
