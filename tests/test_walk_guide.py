"""The recovery option `walk_guide` (smpl_envs.envs.walk_guide) and its clips
(smpl_envs.motion.approach): a standing body far from its goal is shown a walk that starts where it
stands, facing its heading, and ends near the goal; one near its goal but facing away is shown a
turn on the spot; a body down is shown a get-up first; the clips are plausible; bad values are
named."""

import gymnasium as gym
import numpy as np
import pytest

import smpl_envs  # noqa: F401 (registers the ids)
from smpl_envs.envs.recovery import RecoveryVecEnv
from smpl_envs.envs.recovery_rules import approach_library
from smpl_envs.envs.walk_guide import TURN_AWAY, heading_of, wrap_angle
from smpl_envs.motion import MotionLib
from smpl_envs.motion.approach import DEG, approach, turn_on_the_spot
from smpl_envs.motion.getup import getup
from smpl_envs.motion.plausibility import check_motion


def _env(n=4, **kwargs):
    return gym.make_vec("SMPL/Recovery-v0", num_envs=n, walk_guide=True, action_mode="residual",
                        fallen_cache_size=16, **{"starts": {"far": 1.0}, **kwargs})


def _end(guide, world):
    """Where world `world`'s clip ends: its last frame, turned and placed as the guide shows it."""
    frame = guide.frame.copy()
    guide.frame[:] = guide.end
    last = guide.current()
    guide.frame[:] = frame
    return last.pos[world, 0], heading_of(last.rot[world:world + 1])[0]


@pytest.mark.parametrize("turn, distance", [(0.0, 0.5), (90 * DEG, 2.0), (-150 * DEG, 4.0), (180 * DEG, 5.5)])
def test_approach_clips_are_plausible_walks_from_standing_to_a_stop(turn, distance):
    raw = approach(turn, distance)
    assert check_motion(raw).ok
    lib = MotionLib([raw])
    vel = np.linalg.norm(lib.body_state(np.array([0, lib.lengths[0] - 1])).lin_vel[:, 0], axis=-1)
    assert vel.max() < 0.05  # standing still at both ends
    h = heading_of(lib.body_state(np.array([0, lib.lengths[0] - 1])).rot)
    assert abs(wrap_angle(h[1] - h[0] - turn)) < 10 * DEG  # turned as asked


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
    with pytest.raises(ValueError, match="walk_guide must be True or False"):
        gym.make_vec("SMPL/Recovery-v0", num_envs=1, walk_guide="yes")
    assert "walk_guide" in RecoveryVecEnv.policy_kwargs
    assert len(approach_library().names) == approach_library().num_motions  # made once, reused
