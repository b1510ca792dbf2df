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
from smpl_envs.envs.walk_guide import TURN_AWAY, heading_of, wrap_angle
from smpl_envs.motion import MotionLib
from smpl_envs.motion.approach import DEG, PACES, approach, turn_on_the_spot
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
