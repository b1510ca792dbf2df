"""The recovery option `walk_guide` (smpl_envs.envs.walk_guide) and its clips
(smpl_envs.motion.approach): a standing body far from its goal is shown a walk that starts where it
stands, facing its heading, and ends near the goal; one near its goal but facing away is shown a
turn on the spot; a body down is shown a get-up first; the clips are plausible; bad values are
named."""

import gymnasium as gym
import numpy as np
import pytest

import smpl_envs  # noqa: F401 (registers the ids)
from smpl_envs.envs.getup_guide import STILL_SPEED, still_from
from smpl_envs.envs.recovery import RecoveryVecEnv
from smpl_envs.envs.recovery_rules import approach_library
from smpl_envs.envs.walk_guide import MAX_SHIFT, TURN_AWAY, heading_of, wrap_angle
from smpl_envs.motion import MotionLib
from smpl_envs.motion.approach import DEG, PACES, STEP_DISTANCES, TURNS, approach, step_to, turn_on_the_spot
from smpl_envs.motion.getup import getup
from smpl_envs.motion.plausibility import check_motion


def _env(n=4, **kwargs):
    return gym.make_vec("SMPL/Recovery-v0", num_envs=n, action_mode="residual", fallen_cache_size=16,
                        **{"starts": {"far": 1.0}, "walk_guide": True, **kwargs})


def _end(guide, world):
    """Where world `world`'s clip ends: its last frame, turned and placed as the guide shows it."""
    frame = guide.frame.copy()
    guide.frame[:] = guide.end
    last = guide.current()
    guide.frame[:] = frame
    return last.pos[world, 0], heading_of(last.rot[world:world + 1])[0]


@pytest.mark.parametrize("pace", sorted(PACES))
@pytest.mark.parametrize("turn, distance", [(0.0, 0.5), (90 * DEG, 2.0), (-150 * DEG, 4.0), (180 * DEG, 5.5)])
def test_approach_clips_are_plausible_walks_from_standing_to_a_stop(turn, distance, pace):
    raw = approach(turn, distance, pace=pace)
    assert check_motion(raw).ok
    lib = MotionLib([raw])
    vel = np.linalg.norm(lib.body_state(np.array([0, lib.lengths[0] - 1])).lin_vel[:, 0], axis=-1)
    assert vel.max() < 0.05  # standing still at both ends
    h = heading_of(lib.body_state(np.array([0, lib.lengths[0] - 1])).rot)
    assert abs(wrap_angle(h[1] - h[0] - turn)) < 10 * DEG  # turned as asked


def _arrival(raw, within=0.3):
    """Seconds until the clip's pelvis is within `within` m of where it ends, and stays."""
    lib = MotionLib([raw])
    pos = lib.body_state(np.arange(lib.lengths[0])).pos[:, 0, :2]
    far = np.linalg.norm(pos - pos[-1], axis=-1) > within
    return (np.nonzero(far)[0][-1] + 1) / 30


def test_brisk_walks_arrive_sooner_and_end_where_steady_ones_do():
    for turn, distance in [(0.0, 1.0), (90 * DEG, 3.0), (-150 * DEG, 5.0)]:
        steady, brisk = approach(turn, distance), approach(turn, distance, pace="brisk")
        assert _arrival(brisk) < _arrival(steady) - 0.9
        ends = [MotionLib([r]).body_state(np.array([MotionLib([r]).lengths[0] - 1])).pos[0, 0, :2] for r in (steady, brisk)]
        np.testing.assert_allclose(ends[0], ends[1], atol=0.2)  # the grid's end points stay put
    assert _arrival(approach(90 * DEG, 3.0, pace="brisk")) < 5.7 < 6.5 < _arrival(approach(90 * DEG, 3.0))
    with pytest.raises(ValueError, match="approach: pace = 'fast' must be one of"):
        approach(0.0, 1.0, pace="fast")


def test_turns_on_the_spot_turn_and_stay_put():
    raw = turn_on_the_spot(-120 * DEG)
    assert check_motion(raw).ok
    lib = MotionLib([raw])
    ends = lib.body_state(np.array([0, lib.lengths[0] - 1]))
    assert np.linalg.norm(ends.pos[1, 0, :2] - ends.pos[0, 0, :2]) < 0.1
    h = heading_of(ends.rot)
    assert abs(wrap_angle(h[1] - h[0] + 120 * DEG)) < 10 * DEG
    with pytest.raises(ValueError, match="turn_on_the_spot: turn"):
        turn_on_the_spot(0.0)
    with pytest.raises(ValueError, match="approach: distance"):
        approach(0.0, 0.1)


def test_a_standing_body_far_away_is_shown_a_walk_from_where_it_stands_to_its_goal():
    env = _env(n=6)
    u = env.unwrapped
    obs, info = env.reset(seed=1)
    assert info["guided"].all()
    w, body = u.recovery.walk, u.sim.bodies
    shown = w.current()
    np.testing.assert_allclose(shown.pos[:, 0, :2], body.pos[:, 0, :2], atol=1e-9)  # starts where it stands
    turned = wrap_angle(heading_of(shown.rot) - heading_of(body.rot))
    assert np.abs(turned).max() < 25 * DEG  # facing (nearly) its heading
    goal = u.ref.current().pos[:, 0, :2]
    for world in range(6):
        end, _ = _end(w, world)
        assert np.linalg.norm(end[:2] - goal[world]) < 0.5  # ... and it ends near the goal
    # The goal shows the walk, not the recovery form.
    o2, _ = gym.make_vec("SMPL/Recovery-v0", num_envs=6, action_mode="residual", fallen_cache_size=16,
                         starts={"far": 1.0}).reset(seed=1)
    assert np.abs(obs - o2).max() > 0.1 and np.abs(obs[:, :358] - o2[:, :358]).max() < 1e-6
    env.close()


def test_near_but_facing_away_a_body_is_shown_a_turn_to_the_goals_heading():
    env = _env(n=3, starts={"reference": 1.0})
    u = env.unwrapped
    env.reset(seed=0)
    rec, body, ref = u.recovery, u.sim.bodies, u.ref.next()
    rec.grace[:] = 10  # just recovered
    # Turn the bodies' headings by 0 (nothing to do), 100 and -150 degrees about their pelvis.
    angle = np.array([0.0, 100.0, -150.0]) * DEG
    c, s = np.cos(angle), np.sin(angle)
    r = np.stack([c, -s, 0 * c, s, c, 0 * c, 0 * c, 0 * c, 1 + 0 * c], -1).reshape(-1, 3, 3)
    turned = type(body)(pos=body.pos, rot=r[:, None] @ body.rot, lin_vel=body.lin_vel, ang_vel=body.ang_vel,
                        dof_pos=body.dof_pos, dof_vel=body.dof_vel)
    rec.goal_reference(turned, ref, np.random.default_rng(0))
    assert rec.guided.tolist() == [False, True, True]
    for world in (1, 2):
        end, h = _end(rec.walk, world)
        assert abs(wrap_angle(h - heading_of(ref.rot[world:world + 1])[0])) < TURN_AWAY / 2  # ends facing as the goal
        assert np.linalg.norm(end[:2] - turned.pos[world, 0, :2]) < 0.15  # on the spot
    env.close()


def test_a_body_down_gets_a_getup_first_and_bad_values_are_named():
    clips = MotionLib([getup("front", tempo=1.3, lie=0.3, kneel=0.1, name="front"),
                       getup("back", tempo=1.3, lie=0.3, kneel=0.1, name="back")])
    env = _env(n=4, getup_guide=clips, starts={"fallen+far": 1.0})
    u = env.unwrapped
    _, info = env.reset(seed=0)
    assert info["guided"].all() and u.recovery.guide.active.all() and not u.recovery.walk.active.any()
    env.close()
    with pytest.raises(ValueError, match="walk_guide must be True, False or a pace of"):
        gym.make_vec("SMPL/Recovery-v0", num_envs=1, walk_guide="yes")
    for given in (True, "steady", "brisk"):
        env = gym.make_vec("SMPL/Recovery-v0", num_envs=1, walk_guide=given)
        assert env.unwrapped.walk_guide == given  # the policy setting as given: a True policy keeps True
        assert env.unwrapped.recovery.walk.lib is approach_library("brisk" if given == "brisk" else "steady")
        env.close()
    assert "walk_guide" in RecoveryVecEnv.policy_kwargs
    assert len(approach_library().names) == approach_library().num_motions  # made once, reused


@pytest.mark.parametrize("pace", ["steady", "brisk"])
def test_the_brisk_walk_takes_over_from_a_getup_shown_standing_still(pace):
    clips = MotionLib([getup("front", tempo=1.3, lie=0.3, kneel=0.1, name="front"),
                       getup("back", tempo=1.3, lie=0.3, kneel=0.1, name="back")])
    still = still_from(clips)
    for c in range(2):  # the still tail: every body below STILL_SPEED from that frame on, not before
        speed = np.linalg.norm(clips.body_state(clips.starts[c] + np.arange(clips.lengths[c])).lin_vel, axis=-1).max(-1)
        k = still[c] - clips.starts[c]
        assert 0 < k < clips.lengths[c] - 1 and speed[k:].max() < STILL_SPEED <= speed[k - 1]
    env = _env(n=2, getup_guide=clips, walk_guide=pace, starts={"fallen+far": 1.0})
    u = env.unwrapped
    env.reset(seed=0)
    rec, g = u.recovery, u.recovery.guide
    upright = u.ref.current()  # a standing body, 3 m from its goal as the start put the fallen one
    body = type(upright)(pos=u.sim.bodies.pos[:, :1] * [1, 1, 0] + upright.pos - upright.pos[:, :1] * [1, 1, 0],
                         rot=upright.rot, lin_vel=upright.lin_vel, ang_vel=upright.ang_vel,
                         dof_pos=upright.dof_pos, dof_vel=upright.dof_vel)
    g.frame[:] = [g.still[0] - 1, g.still[1]]  # world 0 still rising in the clip, world 1 shown standing
    rec.goal_reference(body, u.ref.next(), np.random.default_rng(0))
    if pace == "brisk":
        assert rec.walk.active.tolist() == [False, True] and g.active.tolist() == [True, False]
    else:  # the steady guide waits for the get-up's last frame, as policies trained with it expect
        assert not rec.walk.active.any() and g.active.all()
    env.close()


# ------------------------------------------------------------------------- the exact rule
def test_steps_move_the_body_where_asked_without_turning():
    for bearing, distance in [(0.0, 0.5), (90 * DEG, 1.1), (180 * DEG, 1.4), (-120 * DEG, 0.8)]:
        raw = step_to(bearing, distance)
        assert check_motion(raw).ok
        lib = MotionLib([raw])
        ends = lib.body_state(np.array([0, lib.lengths[0] - 1]))
        moved = ends.pos[1, 0, :2] - ends.pos[0, 0, :2]
        h = heading_of(ends.rot)
        assert abs(np.linalg.norm(moved) - distance) < 0.1
        assert abs(wrap_angle(np.arctan2(moved[1], moved[0]) - h[0] - bearing)) < 10 * DEG
        assert abs(wrap_angle(h[1] - h[0])) < 5 * DEG  # no turn
        assert np.linalg.norm(ends.lin_vel[:, 0], axis=-1).max() < 0.05
    for bad in (0.3, 2.5, np.nan):
        with pytest.raises(ValueError, match="step_to: distance"):
            step_to(0.0, bad)
    names = lambda pace: [n for n in approach_library(pace).names if n.startswith("step")]  # noqa: E731
    assert not names("brisk") and len(names("brisk_exact")) == len(TURNS) * len(STEP_DISTANCES)


def _exact_env(n, **kwargs):
    return _env(n=n, walk_guide="brisk_exact", **kwargs)


def test_under_the_exact_rule_a_walk_ends_on_the_goal_and_its_velocities_match_its_path():
    ends = {}
    for pace in ("brisk", "brisk_exact"):
        env = _env(n=6, walk_guide=pace)
        u = env.unwrapped
        env.reset(seed=3)
        w, goal = u.recovery.walk, u.ref.current().pos[:, 0, :2]
        ends[pace] = np.array([np.linalg.norm(_end(w, k)[0][:2] - goal[k]) for k in range(6)])
        if pace == "brisk_exact":
            assert np.abs(w.shift).max() > 0.01 and np.linalg.norm(w.shift, axis=-1).max() <= MAX_SHIFT + 1e-9
            # The shown state's velocities are those of its positions (finite differences at 30 fps).
            w.frame[:] = (w.begin + w.end) // 2
            a = w.current()
            w.frame[:] += 1
            b = w.current()
            mid = 0.5 * (a.lin_vel + b.lin_vel)[:, 0, :2]
            np.testing.assert_allclose((b.pos - a.pos)[:, 0, :2] * 30, mid, atol=0.05)
        env.close()
    assert ends["brisk_exact"].max() < 0.02 < ends["brisk"].max()


def _place_near(u, offsets):
    """The reference pose, its pelvis moved by `offsets` (n, 2): bodies standing near their goal."""
    ref = u.ref.next()
    shift = np.concatenate([offsets, np.zeros((len(offsets), 1))], -1)[:, None]
    return type(ref)(pos=ref.pos + shift, rot=ref.rot, lin_vel=ref.lin_vel, ang_vel=ref.ang_vel,
                     dof_pos=ref.dof_pos, dof_vel=ref.dof_vel), ref


def test_under_the_exact_rule_a_body_near_but_off_the_spot_steps_onto_it():
    offsets = np.array([[0.1, 0.0], [0.0, 0.4], [-0.35, 0.2]])
    guided = {}
    for pace in ("brisk", "brisk_exact"):
        env = _env(n=3, walk_guide=pace, starts={"reference": 1.0})
        u = env.unwrapped
        env.reset(seed=0)
        rec = u.recovery
        rec.grace[:] = 10  # just recovered
        body, ref = _place_near(u, offsets)
        rec.goal_reference(body, ref, np.random.default_rng(0))
        guided[pace] = rec.guided.tolist()
        if pace == "brisk_exact":
            for world in (1, 2):
                end, h = _end(rec.walk, world)
                assert np.linalg.norm(end[:2] - ref.pos[world, 0, :2]) < 0.02  # on the spot
                assert abs(wrap_angle(h - heading_of(body.rot[world:world + 1])[0])) < 20 * DEG  # by steps, not a turn
        env.close()
    assert guided == {"brisk": [False, False, False], "brisk_exact": [False, True, True]}


def test_a_body_that_never_lands_on_the_spot_is_not_shown_steps_forever():
    """The grace that shows steps onto the spot runs out while they play: a body that stays 0.4 m
    off its goal (it does not follow its steps) is shown the task's goal again once its step has
    played, not a new step each time the last one leaves it behind."""
    env = _exact_env(1, starts={"reference": 1.0})
    u = env.unwrapped
    env.reset(seed=0)
    rec, rng, zero = u.recovery, np.random.default_rng(0), np.zeros(1)
    rec.grace[:] = 10  # just recovered
    body, ref = _place_near(u, np.array([[0.0, 0.4]]))
    shown = []
    for _ in range(600):
        rec.goal_reference(body, ref, rng)
        shown.append(bool(rec.guided[0]))
        rec.advance()
        rec.evaluate(body, ref, zero.copy(), {"energy": zero.copy()}, np.zeros(1, bool), np.zeros(1, bool), rng,
                     guide_terms={"energy": zero.copy()})
    env.close()
    assert shown[0] and not any(shown[-300:])


def test_under_the_exact_rule_a_goal_close_behind_is_a_step_back_not_a_turn_and_a_walk():
    lengths = {}
    for pace in ("brisk", "brisk_exact"):
        env = _env(n=1, walk_guide=pace, starts={"reference": 1.0})
        u = env.unwrapped
        env.reset(seed=0)
        ref = u.ref.next()
        back = -0.9 * np.array([np.cos(heading_of(ref.rot)[0]), np.sin(heading_of(ref.rot)[0])])
        body, ref = _place_near(u, -back[None])  # the goal 0.9 m behind the body
        u.recovery.goal_reference(body, ref, np.random.default_rng(0))
        w = u.recovery.walk
        assert w.active.all()
        lengths[pace] = int(w.end[0] - w.begin[0])
        _, h = _end(w, 0)
        turned = abs(wrap_angle(h - heading_of(body.rot)[0]))
        assert (turned < 20 * DEG) if pace == "brisk_exact" else (turned > 120 * DEG)
        env.close()
    assert lengths["brisk_exact"] < 0.6 * lengths["brisk"]


def test_the_exact_walk_guide_shows_the_same_clips_in_torch_as_in_numpy():
    # The MuJoCo Warp backend runs the guide on torch tensors; the same starts give the same frames.
    import torch

    from smpl_envs.backend import TorchBackend
    from smpl_envs.features import BodyState
    from smpl_envs.envs.walk_guide import WalkGuide
    from smpl_envs.motion.library import DeviceFrames

    env = _exact_env(4)
    u = env.unwrapped
    env.reset(seed=5)
    body, goal, w = u.sim.bodies, u.ref.next(), u.recovery.walk
    tb = TorchBackend("cpu")
    tw = WalkGuide(w.lib, DeviceFrames(w.lib, "cpu"), 4, tb, exact=True)
    fields = ("pos", "rot", "lin_vel", "ang_vel", "dof_pos", "dof_vel")
    as_torch = lambda s: BodyState(**{f: torch.as_tensor(np.asarray(getattr(s, f)), dtype=torch.float32) for f in fields})  # noqa: E731
    far = np.array([True, True, False, True])
    w.start(np.ones(4, bool), body, goal, far)
    tw.start(torch.ones(4, dtype=torch.bool), as_torch(body), as_torch(goal), torch.as_tensor(far))
    for step in range(40):
        np.testing.assert_allclose(tw.next().pos.numpy(), w.next().pos, atol=2e-3)
        np.testing.assert_allclose(tw.next().lin_vel.numpy(), w.next().lin_vel, atol=2e-2)
        w.advance(), tw.advance()
    env.close()


@pytest.mark.parametrize("pace", ["brisk_direct", "quick_direct"])
@pytest.mark.parametrize("turn", [60 * DEG, -150 * DEG, 180 * DEG])
def test_direct_walks_head_straight_for_the_goal_while_they_turn(turn, pace):
    raw, steady = approach(turn, 2.0, pace=pace), approach(turn, 2.0, pace="brisk")
    assert check_motion(raw).ok
    lib = MotionLib([raw])
    s = lib.body_state(np.arange(lib.lengths[0]))
    pos, h = s.pos[:, 0, :2] - s.pos[0, 0, :2], heading_of(s.rot)
    end = pos[-1]
    # The pelvis keeps to the straight line from the start to the end (within the sway of a gait) ...
    across = np.abs(pos[:, 0] * end[1] - pos[:, 1] * end[0]) / np.linalg.norm(end)
    assert across.max() < 0.1
    assert abs(wrap_angle(np.arctan2(end[1], end[0]) - h[0] - turn)) < 5 * DEG  # ... at the bearing `turn`
    assert abs(wrap_angle(h[-1] - h[0] - turn)) < 10 * DEG  # and it ends facing that way
    # ... and never moves away from the end: no curve round, no turn on the spot first.
    remaining = np.linalg.norm(pos - end, axis=-1)
    assert np.all(np.diff(remaining) < 0.01)
    assert _arrival(raw) < _arrival(steady)


def test_quick_direct_walks_turn_faster_and_arrive_sooner_at_the_same_place():
    for turn, soon in [(0.0, 0.2), (90 * DEG, 1.0), (-180 * DEG, 2.0)]:
        brisk, quick = approach(turn, 3.0, pace="brisk_direct"), approach(turn, 3.0, pace="quick_direct")
        assert _arrival(quick) < _arrival(brisk) - soon
        ends = [MotionLib([r]).body_state(np.array([MotionLib([r]).lengths[0] - 1])) for r in (brisk, quick)]
        np.testing.assert_allclose(ends[0].pos[0, 0, :2], ends[1].pos[0, 0, :2], atol=0.15)  # the grid stays put
        assert abs(wrap_angle(heading_of(ends[0].rot)[0] - heading_of(ends[1].rot)[0])) < 5 * DEG
