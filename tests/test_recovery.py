"""SMPL/Recovery-v0 and Imitation's recovery option: Gymnasium contracts, fallen and far starts,
the start mix, the recovery goal form and its switch, the point reward, termination rules,
the reference held past the clip's end, the recovery metrics on hand-made trajectories, the
evaluation protocol, bad input, and the MuJoCo Warp backend (parity with the CPU one, starts
and outputs in torch, Imitation's recovery option)."""


import importlib.util

import gymnasium as gym
import numpy as np
import pytest

import smpl_envs
from smpl_envs.envs.fallen import generate_fallen_states
from smpl_envs.envs.recovery import (START_KINDS, RecoveryProtocol, check_starts, point_reward, recovered_within,
                                     recovery_frame, recovery_reference)
from smpl_envs.features import BodyState, heading_rotation, to_heading, tracking_obs
from conftest import WARP_DEVICE, check_env_quietly, seeded_rollouts

ID = "SMPL/Recovery-v0"
SMALL = {"fallen_cache_size": 16}  # a small fallen set keeps the tests quick (memoised across envs)


def _vec(n=4, **kwargs):
    return gym.make_vec(ID, num_envs=n, **{**SMALL, **kwargs})


def _slices(env):
    return env.observation_structure


def test_registered_and_env_checker():
    assert ID in smpl_envs.ENV_IDS and gym.spec(ID).max_episode_steps == 300
    env = gym.make(ID, render_mode="rgb_array", render_size=(96, 72), **SMALL)
    check_env_quietly(env)
    assert env.observation_space.shape == (934,) and env.action_space.shape == (69,)
    env.reset(seed=0)
    assert env.render().shape == (72, 96, 3)
    env.close()


def test_make_vec_is_native_batched_and_seeded():
    env = _vec(8)

    assert env.sim.num_worlds == 8 and env.max_episode_steps == 300
    (a, ia), (b, ib), (c, _) = seeded_rollouts(env, seeds=(5, 5, 6))
    assert a[0].shape == (8, 934) and a[0].dtype == np.float32
    assert all(np.array_equal(x, y) for x, y in zip(a, b))
    assert np.array_equal(ia["start_kind"], ib["start_kind"])
    assert not np.array_equal(a[0], c[0])
    env.close()


def test_fallen_states_lie_on_the_ground_and_generate_quickly():
    # Its speed (seconds for a cache) is measured by benchmarks/bench_env.py, not timed here.
    states = generate_fallen_states(64, seed=12345)  # a seed no other test uses: really generated
    assert states.shape == (64, 76) and np.isfinite(states).all() and not states.flags.writeable
    assert (states[:, 2] < 0.5).all()  # pelvis low: lying, sitting or kneeling, not standing
    # Random orientations: the pelvis' up axis points every which way, not only up.
    assert len(np.unique(states[:, 3:7].round(2), axis=0)) == 64
    assert generate_fallen_states(64, seed=12345) is states  # memoised

    env = _vec(4)
    env.reset(seed=0, options={"recovery_start": "fallen"})
    body = env.sim.bodies
    assert (body.pos[:, 0, 2] < 0.5).all()
    np.testing.assert_array_equal(env.sim.qvel, 0.0)  # velocities zeroed
    # Placed under the reference root (up to the drift of the fall).
    ref_root = env.unwrapped.motion_lib.body_pos[env.unwrapped.ref.frame, 0]
    assert (np.linalg.norm(body.pos[:, 0, :2] - ref_root[:, :2], axis=-1) < 1.0).all()
    # Starting from rest on the floor, nothing explodes.
    for _ in range(10):
        _, _, term, _, info = env.step(np.zeros((4, 69)))
    assert not info["diverged"].any() and np.isfinite(info["root_distance"]).all()
    # Regenerated on demand: another set.
    before = env.unwrapped.recovery.fallen.states
    env.unwrapped.regenerate_fallen(seed=7)
    after = env.unwrapped.recovery.fallen.states
    assert after.shape == before.shape and not np.allclose(after, before)
    env.close()


def test_far_starts_are_two_to_five_metres_away_in_the_reference_pose():
    env = _vec(16)
    _, info = env.reset(seed=1, options={"recovery_start": "far"})
    u = env.unwrapped
    ref_root = u.motion_lib.body_pos[u.ref.frame, 0]
    sim_root = env.sim.bodies.pos[:, 0]
    d = np.linalg.norm(sim_root[:, :2] - ref_root[:, :2], axis=-1)
    assert ((d >= 2.0 - 1e-6) & (d <= 5.0 + 1e-6)).all() and d.std() > 0.3
    np.testing.assert_allclose(sim_root[:, 2], ref_root[:, 2], atol=1e-6)  # same height: only moved
    np.testing.assert_allclose(env.sim.bodies.dof_pos, u.motion_lib.dof_pos[u.ref.frame], atol=1e-9)
    np.testing.assert_allclose(info["root_distance"], d, atol=1e-6)
    assert info["recovering"].all() and (info["start_kind"] == START_KINDS.index("far")).all()
    # Fallen and far: lying, and far.
    env.reset(seed=2, options={"recovery_start": "fallen+far"})
    body = env.sim.bodies
    d = np.linalg.norm(body.pos[:, 0, :2] - u.motion_lib.body_pos[u.ref.frame, 0, :2], axis=-1)
    assert (body.pos[:, 0, 2] < 0.5).all() and (d > 1.0).all()
    env.close()


def test_start_mix_is_honoured():
    p = {"reference": 0.5, "fallen": 0.25, "far": 0.25}
    env = _vec(64, starts=p)
    kinds = np.concatenate([env.reset(seed=s)[1]["start_kind"] for s in range(8)])
    counts = np.bincount(kinds, minlength=4)
    expected = 512 * np.array([0.5, 0.25, 0.25, 0.0])
    assert counts[3] == 0
    assert (np.abs(counts - expected) < 4 * np.sqrt(512 * 0.25)).all(), counts
    env.close()


def test_goal_switches_to_recovery_form_beyond_half_a_metre_and_back():
    env = _vec(2, far_distance=(7.0, 8.0))
    u = env.unwrapped
    s = _slices(u)
    obs, info = env.reset(seed=0, options={"recovery_start": ["far", "reference"]})
    body = env.sim.bodies
    heading = heading_rotation(body.rot[:, 0])
    # World 0 is far: its non-root goal columns are the humanoid's own.
    diff_pos = obs[:, s["goal/diff_pos"]].reshape(2, 24, 3)
    ref_pos = obs[:, s["goal/ref_pos"]].reshape(2, 24, 3)
    own = obs[:, s["self/body_pos"]].reshape(2, 23, 3)
    np.testing.assert_allclose(diff_pos[0, 1:], 0.0, atol=1e-6)
    np.testing.assert_allclose(ref_pos[0, 1:], own[0], atol=1e-5)
    for name in ("diff_lin_vel", "diff_ang_vel"):
        np.testing.assert_allclose(obs[0, s[f"goal/{name}"]].reshape(24, 3)[1:], 0.0, atol=1e-5)
    ident6 = np.array([1, 0, 0, 1, 0, 0], np.float32)
    np.testing.assert_allclose(obs[0, s["goal/diff_rot"]].reshape(24, 6)[1:], np.tile(ident6, (23, 1)), atol=1e-5)
    # ... and its reference root is clamped to 5 m along the true direction.
    true = u.ref.next().pos[0, 0] - body.pos[0, 0]
    np.testing.assert_allclose(np.linalg.norm(ref_pos[0, 0]), 5.0, atol=1e-5)
    expect = to_heading((5.0 * true / np.linalg.norm(true))[None, None], heading[:1])[0, 0]
    np.testing.assert_allclose(ref_pos[0, 0], expect, atol=1e-5)
    # World 1 (reference start) sees Imitation's goal, unchanged.
    np.testing.assert_allclose(obs[1], tracking_obs(body, u.ref.next(), "rotation", heading)[1], atol=1e-5)
    assert info["recovering"].tolist() == [True, False]

    # Back within reach: put world 0 into the reference state, and the ordinary goal returns.
    qpos = env.sim.qpos.copy()
    qpos[0] = qpos[1]
    u.ref.frame[0] = u.ref.frame[1]
    env.sim.set_state(np.array([0]), qpos[:1], env.sim.qvel[1:2].copy())
    obs, _, _, _, info = env.step(np.zeros((2, 69)))
    body = env.sim.bodies
    assert not info["recovering"][0]
    np.testing.assert_allclose(obs[0], tracking_obs(body, u.ref.next(), "rotation", heading_rotation(body.rot[:, 0]))[0],
                               atol=1e-5)
    env.close()


def test_recovery_reference_is_pure_and_masked():
    rng = np.random.default_rng(0)

    def state():
        rot = np.linalg.qr(rng.normal(size=(2, 24, 3, 3)))[0]
        return BodyState(rng.normal(size=(2, 24, 3)), rot, rng.normal(size=(2, 24, 3)),
                         rng.normal(size=(2, 24, 3)), np.zeros((2, 69)), np.zeros((2, 69)))

    sim, ref = state(), state()
    ref.pos[0, 0] = sim.pos[0, 0] + [0.0, 8.0, 0.0]
    out = recovery_reference(sim, ref, np.array([True, False]), clamp=5.0)
    np.testing.assert_allclose(out.pos[0, 0], sim.pos[0, 0] + [0.0, 5.0, 0.0])
    for name in ("pos", "rot", "lin_vel", "ang_vel"):
        np.testing.assert_array_equal(getattr(out, name)[0, 1:], getattr(sim, name)[0, 1:])
        np.testing.assert_array_equal(getattr(out, name)[1], getattr(ref, name)[1])
    np.testing.assert_array_equal(out.rot[0, 0], ref.rot[0, 0])
    # Closer than the clamp: the root stays where the reference has it.
    ref.pos[0, 0] = sim.pos[0, 0] + [1.0, 0.0, 0.0]
    np.testing.assert_allclose(recovery_reference(sim, ref, np.array([True, True])).pos[0, 0], ref.pos[0, 0])


def test_point_reward_sign_and_clip():
    np.testing.assert_allclose(point_reward([1.0, 1.0, 1.0], [0.9, 1.1, 0.0]), [0.9, -0.9, 3.0])
    # In the env: moving a far humanoid 1 m closer pays 9 x min(1, 1/3) = 3; 1 m away costs 9.
    env = _vec(2, far_distance=(3.0, 3.0), energy_weight=0.0)
    env.reset(seed=0, options={"recovery_start": "far"})
    u = env.unwrapped
    ref_root = u.motion_lib.body_pos[u.ref.frame, 0]
    qpos, qvel = env.sim.qpos.copy(), env.sim.qvel.copy()
    toward = (ref_root - qpos[:, :3]) * [1, 1, 0]
    toward /= np.linalg.norm(toward, axis=-1, keepdims=True)
    qpos[:, :3] += toward * np.array([[1.0], [-1.0]])
    env.sim.set_state(np.arange(2), qpos, qvel)
    _, reward, _, _, info = env.step(np.zeros((2, 69)))
    point = info["reward_point"]
    assert point[0] == pytest.approx(3.0, abs=1e-6) and point[1] == pytest.approx(-9.0, abs=0.3)
    terms = sum(info[f"reward_{k}"] for k in ("pos", "rot", "lin_vel", "ang_vel", "energy", "point"))
    np.testing.assert_allclose(reward, terms, atol=1e-9)
    assert info["recovering"].all()
    env.close()


def test_imitation_with_recovery_does_not_terminate_when_far():
    def shifted_step(env):
        env.reset(seed=0)
        qpos = env.sim.qpos.copy()
        qpos[:, 0] += 3.0
        env.sim.set_state(np.arange(2), qpos, env.sim.qvel.copy())
        return env.step(env.unwrapped.reference_action())

    plain = gym.make_vec("SMPL/Imitation-v0", num_envs=2, motions="walk")
    assert shifted_step(plain)[2].all()  # without recovery: 3 m away ends the episode
    plain.close()
    env = gym.make_vec("SMPL/Imitation-v0", num_envs=2, motions="walk", recovery=True)
    _, _, term, _, info = shifted_step(env)
    assert not term.any() and info["recovering"].all()
    for _ in range(30):
        _, _, term, trunc, info = env.step(env.unwrapped.reference_action())
        assert not term.any()
    assert info["recovering"].all()
    # The default Imitation env keeps its info (no recovery entries).
    assert "recovering" not in gym.make_vec("SMPL/Imitation-v0", num_envs=1).reset(seed=0)[1]
    env.close()


def test_reference_waits_while_a_body_is_lost_and_goes_on_from_the_same_frame():
    """reference_waits: a world shown the recovery form keeps its reference frame; a world on
    its reference, and every world without the option, moves one frame a step."""
    def frames(waits):
        env = gym.make_vec("SMPL/Imitation-v0", num_envs=2, motions="walk", recovery={"reference_waits": waits})
        env.reset(seed=0, options={"start": "beginning"})
        u = env.unwrapped
        qpos = u.sim.qpos.copy()
        qpos[1, 0] += 3.0  # world 1 is 3 m from its reference
        u.sim.set_state(np.arange(2), qpos, u.sim.qvel.copy())
        env.step(u.reference_action())  # the observation after it shows world 1 the recovery form
        start = np.asarray(u.frame).copy()
        seen = []
        for _ in range(10):
            _, _, _, _, info = env.step(u.reference_action())
            seen.append(np.asarray(u.frame) - start)
            assert info["recovering"][1] and not info["recovering"][0]
        # Back on its reference: the held world's clock goes on from where it stopped.
        qpos = u.sim.qpos.copy()
        qpos[1, :3] = np.asarray(info["ref_body_pos"])[1, 0]
        u.sim.set_state(np.array([1]), qpos[[1]], u.sim.qvel.copy()[[1]])
        env.step(u.reference_action())
        env.step(u.reference_action())
        after = np.asarray(u.frame) - start
        env.close()
        return np.array(seen), after

    seen, after = frames(True)
    assert (seen[:, 0] == np.arange(1, 11)).all() and (seen[:, 1] == 0).all()
    assert after[0] == 12 and after[1] >= 1
    seen, _ = frames(False)
    assert (seen[:, 1] == np.arange(1, 11)).all()
    with pytest.raises(ValueError, match="reference_waits must be True or False"):
        gym.make_vec("SMPL/Imitation-v0", num_envs=1, motions="walk", recovery={"reference_waits": "yes"})


def test_termination_continues_as_recovery_with_grace():
    def first_termination(continue_prob):
        env = _vec(4, starts={"reference": 1.0}, termination_distance=0.05, continue_prob=continue_prob,
                   grace_steps=90)
        env.reset(seed=0)
        for t in range(40):
            _, _, term, _, info = env.step(np.zeros((4, 69)))  # absolute zero: the pose drifts away
            if term.any():
                env.close()
                return t
        grace = env.unwrapped.recovery.grace.copy()
        env.close()
        return grace

    assert isinstance(first_termination(0.0), int)
    grace = first_termination(1.0)
    assert not isinstance(grace, int) and (grace > 0).any()  # continued, with a grace running


def test_reference_is_held_past_the_clip_end():
    env = gym.make_vec(ID, num_envs=1, starts={"reference": 1.0}, action_mode="residual", max_episode_steps=None,
                       **SMALL)
    u = env.unwrapped
    env.reset(seed=0, options={"start": "beginning"})
    end = u.ref.end_frame[0]
    for _ in range(u.motion_lib.lengths[0] + 5):
        _, _, term, trunc, _ = env.step(np.zeros((1, 69)))
        assert not trunc[0]
    assert u.ref.frame[0] == end
    env.close()


def test_recovery_metrics_on_hand_made_trajectories():
    far, near = 1.0, 0.2
    # Back at frame 3 and stays: recovery frame 3.
    assert recovery_frame(np.array([far, far, far] + [near] * 10), 0.5) == 3
    # Back at 2, out again at 4 (a dip in reach that does not stay), back for good at 6.
    assert recovery_frame(np.array([far, far, near, near, far, far] + [near] * 8), 0.5) == 6
    # Within from the start: 0. Exactly the threshold counts as within.
    assert recovery_frame(np.full(5, near), 0.5) == 0
    assert recovery_frame(np.array([far, 0.5, 0.5, 0.5]), 0.5) == 1
    # Out at the last frame (got up, fell again), or never back: -1. NaN counts as out.
    assert recovery_frame(np.array([far, near, near, far]), 0.5) == -1
    assert recovery_frame(np.full(5, far), 0.5) == -1
    assert recovery_frame(np.array([far, near, np.nan, near, near]), 0.5) == 3
    # Batched over trials of 330 frames (10 s + 1 s): back by 5 s exactly, one frame late, late.
    batch = np.stack([np.r_[np.full(150, far), np.full(180, near)], np.r_[np.full(151, far), np.full(179, near)],
                      np.r_[np.full(301, far), np.full(29, near)], np.full(330, near)])
    frames = recovery_frame(batch, 0.5)
    assert frames.tolist() == [150, 151, 301, 0]
    assert recovered_within(frames, 5.0).tolist() == [True, False, False, True]
    assert recovered_within(frames, 10.0).tolist() == [True, True, False, True]
    assert not recovered_within(np.array([-1]), 10.0)[0]


def test_evaluation_protocol_runs_and_reports_the_table():
    zero = lambda obs: np.zeros((len(obs), 69), np.float32)  # noqa: E731
    result = smpl_envs.evaluate(zero, ID, num_envs=2, progress=False, trials=2, hold_seconds=0.2,
                                env_kwargs={"action_mode": "residual", **SMALL})
    s = result.summary
    for kind in ("fallen", "far", "fallen+far"):
        assert s[f"trials_{kind}"] == 2
        assert s[f"succ_10s_{kind}"] >= s[f"succ_5s_{kind}"]
    # The PD controllers alone do not walk 3 m: far trials fail.
    assert s["succ_10s_far"] == 0.0 and len(result.rows) == 6
    # Fallen trials are split by the side they lie on; standing ones are "up".
    assert {r["lying"] for r in result.rows if r["start"] == "far"} == {"up"}
    for kind in ("fallen", "fallen+far"):
        assert {r["lying"] for r in result.rows if r["start"] == kind} <= {"front", "back"}
        assert sum(s.get(f"trials_{kind}_{side}", 0) for side in ("front", "back")) == 2
    table = result.table()
    assert "Succ-5s" in table and "fallen+far" in table
    assert '"settings"' in result.to_json()
    # One kind alone: the same trials as among all three (its seeds are the kind's, not the order's).
    alone = smpl_envs.evaluate(zero, ID, num_envs=2, progress=False, trials=2, hold_seconds=0.2, kinds="fallen+far",
                               env_kwargs={"action_mode": "residual", **SMALL})
    assert [r["start"] for r in alone.rows] == ["fallen+far"] * 2 and "trials_fallen" not in alone.summary
    assert alone.rows == [r for r in result.rows if r["start"] == "fallen+far"]
    with pytest.raises(ValueError, match="kinds must name start kinds"):
        smpl_envs.evaluate(zero, ID, trials=1, kinds=["fallen", "lying"])
    with pytest.raises(ValueError, match="trials"):
        smpl_envs.evaluate(zero, ID, trials=0)
    with pytest.raises(ValueError, match="starts"):
        smpl_envs.evaluate(zero, ID, trials=1, env_kwargs={"starts": {"fallen": 1.0}})


def test_the_protocol_measures_on_the_standing_clip_whatever_the_policy_trained_on(monkeypatch):
    # A policy recording training on [stand, walk] (as the recovery recipes do) is measured on
    # "stand" unless told otherwise: a walking reference would leave a fallen body behind.
    class Trained:
        env_id, env_kwargs = ID, {"motions": ["stand", "walk"], "action_mode": "residual", **SMALL}

        def __call__(self, obs):
            return np.zeros((len(obs), 69), np.float32)

    made = []
    make_env = RecoveryProtocol.make_env
    monkeypatch.setattr(RecoveryProtocol, "make_env",
                        lambda self, env_id, motions, *a: made.append(motions) or make_env(self, env_id, motions, *a))
    for motions in (None, "walk"):
        smpl_envs.evaluate(Trained(), ID, motions=motions, num_envs=1, progress=False, trials=1, hold_seconds=0.1)
    assert made == ["stand", "walk"]


def test_bad_kwargs_raise_clear_errors():
    with pytest.raises(ValueError, match="starts"):
        check_starts({"reference": 0.5, "fallen": 0.4})
    with pytest.raises(ValueError, match="starts"):
        check_starts({"reference": 0.5, "flying": 0.5})
    with pytest.raises(ValueError, match="starts"):
        check_starts({"reference": 1.5, "fallen": -0.5})
    with pytest.raises(ValueError, match="starts"):
        gym.make_vec(ID, num_envs=1, starts={"fallen": 0.9})
    with pytest.raises(ValueError, match="starts"):
        gym.make_vec(ID, num_envs=1, starts="fallen")
    with pytest.raises(ValueError, match="continue_prob"):
        gym.make_vec(ID, num_envs=1, continue_prob=1.5)
    with pytest.raises(ValueError, match="far_distance"):
        gym.make_vec(ID, num_envs=1, far_distance=(5.0, 2.0))
    with pytest.raises(ValueError, match="switch_distance"):
        gym.make_vec(ID, num_envs=1, switch_distance=0.0)
    with pytest.raises(ValueError, match="clamp_distance"):
        gym.make_vec(ID, num_envs=1, clamp_distance="far")
    with pytest.raises(ValueError, match="point_scale"):
        gym.make_vec(ID, num_envs=1, point_scale=float("nan"))
    with pytest.raises(ValueError, match="grace_steps"):
        gym.make_vec(ID, num_envs=1, grace_steps=1.5)
    with pytest.raises(ValueError, match="fallen_cache_size"):
        gym.make_vec(ID, num_envs=1, fallen_cache_size=0)
    with pytest.raises(ValueError, match="recovery"):
        gym.make_vec("SMPL/Imitation-v0", num_envs=1, recovery="yes")
    env = _vec(2)
    with pytest.raises(ValueError, match="recovery_start"):
        env.reset(seed=0, options={"recovery_start": "flying"})
    env.close()
    with pytest.raises(ValueError, match="recovery_start"):  # only recovery envs take the option
        gym.make_vec("SMPL/Imitation-v0", num_envs=1).reset(options={"recovery_start": "far"})


def test_baselines_example_runs():
    import subprocess
    import sys
    from pathlib import Path

    script = Path(__file__).parents[1] / "examples" / "recovery_baselines.py"
    out = subprocess.run([sys.executable, str(script), "--trials", "1", "--num-envs", "1", "--fallen-cache-size", "16"],
                         capture_output=True, text=True, timeout=300, check=True).stdout
    assert "zero, residual" in out and "fallen+far 10s" in out and out.count("%") == 18
    guided = subprocess.run([sys.executable, str(script), "--trials", "1", "--num-envs", "1", "--fallen-cache-size", "16",
                             "--getup-guide", "corpus:test/getup"], capture_output=True, text=True, timeout=300,
                            check=True).stdout
    assert "zero, residual, guided" in guided and guided.count("%") == 24


def test_lying_at_start_reads_face_down_from_the_pelvis_forward_axis():
    from smpl_envs.envs.recovery import lying_at_start
    from smpl_envs.features import rotmat_from_quat
    from smpl_envs.rotations import quat_from_euler_xyz

    # pitched +90 deg about y the forward axis (x) points down: face down; -90: face up
    rot = rotmat_from_quat(quat_from_euler_xyz(np.array([[0, np.pi / 2, 0], [0, -np.pi / 2, 0], [0, np.pi / 2, 0]])))
    pos = np.array([[0, 0, 0.15], [0, 0, 0.15], [0, 0, 0.9]])
    assert lying_at_start(rot, pos) == ["front", "back", "up"]


def test_protocol_measures_from_the_trial_start_to_its_end():
    # End to end on a case with a known answer: from the reference state of the standing clip,
    # the PD controllers alone (zero residual) stand for a moment, then fall (measured: within
    # 2 s). The trial starts within reach but does not stay: it is never back.
    from smpl_envs.envs.recovery import RecoveryVecEnv, _run_wave

    proto = RecoveryVecEnv.evaluation
    options = proto.check_options({"trials": 2, "hold_seconds": 0.2})
    env = proto.make_env(ID, None, 2, {"action_mode": "residual", **SMALL}, False, options)
    assert env.max_episode_steps == 306
    dist, broke, lying = _run_wave(lambda obs: np.zeros((len(obs), 69)), env, "reference", 0, env.max_episode_steps)
    assert dist.shape == (2, 307) and not broke.any() and np.isfinite(dist).all() and lying == ["up", "up"]
    assert (dist[:, :10] < 0.2).all() and (dist[:, -1] > 0.5).all()
    assert recovery_frame(dist, 0.5).tolist() == [-1, -1]
    assert recovery_frame(dist[:, :10], 0.5).tolist() == [0, 0]
    env.close()


# ---------------------------------------------------------------------- the MuJoCo Warp backend
warp = pytest.mark.skipif(importlib.util.find_spec("mujoco_warp") is None,
                          reason="MuJoCo Warp is not installed (pip install 'smpl-envs[gpu]')")
KINDS4 = list(START_KINDS)  # reference, fallen, far, fallen+far: one world each


def _warp_vec(env_id=ID, n=4, backend="warp", **kwargs):
    kwargs = {"motions": "walk", "action_mode": "residual", **SMALL, **kwargs}
    kwargs.update({"device": WARP_DEVICE} if backend == "warp" else {"num_threads": 1})
    if env_id != ID:
        kwargs.pop("fallen_cache_size")
    return gym.make_vec(env_id, num_envs=n, backend=backend, **kwargs)


@warp
def test_warp_backend_matches_the_cpu_backend_from_the_same_starts():
    # Each backend draws its far bearings and fallen states from its own generator (NumPy's, or
    # torch's on the device), so the warp env is put into the CPU env's start states; the
    # recovery state the reset computed from them (start kind, grace, root distance) is the same
    # on both. A clamp of 3 m clamps the far worlds' goal; continue_prob 1 makes the
    # continue-as-recovery rule deterministic, and termination_distance 0.1 triggers it.
    import torch

    kw = {"far_distance": (3.0, 4.0), "clamp_distance": 3.0, "continue_prob": 1.0, "grace_steps": 2,
          "termination_distance": 0.1}
    w, c = _warp_vec(**kw), _warp_vec(backend="cpu", **kw)
    options = {"recovery_start": KINDS4, "motion_ids": [0] * 4, "start": "beginning"}
    _, iw = w.reset(seed=0, options=options)
    _, ic = c.reset(seed=0, options=options)
    np.testing.assert_array_equal(iw["start_kind"].cpu().numpy(), ic["start_kind"])
    assert iw["recovering"].tolist() == ic["recovering"].tolist() == [False, True, True, True]
    w.sim.set_state(torch.arange(4), c.sim.qpos, c.sim.qvel)
    w.recovery.root_distance[:] = torch.as_tensor(c.recovery.root_distance)
    np.testing.assert_array_equal(w.recovery.grace.cpu().numpy(), c.recovery.grace)
    rng = np.random.default_rng(0)
    continued = False
    for k in range(10):
        a = rng.uniform(-0.3, 0.3, (4, 69)).astype(np.float32)
        ow, rw, tw, uw, iw = w.step(torch.as_tensor(a))
        oc, rc, tc, uc, ic = c.step(a)
        tol = 1e-3 if k < 3 else 1e-2
        assert np.abs(ow.cpu().numpy() - oc).max() < tol, k
        assert np.abs(rw.cpu().numpy() - rc).max() < tol, k
        assert np.abs(iw["reward_point"].cpu().numpy() - ic["reward_point"]).max() < tol, k
        np.testing.assert_allclose(iw["root_distance"].cpu().numpy(), ic["root_distance"], atol=tol)
        assert tw.tolist() == tc.tolist() and uw.tolist() == uc.tolist(), k
        assert iw["recovering"].tolist() == ic["recovering"].tolist(), k
        np.testing.assert_array_equal(w.recovery.grace.cpu().numpy(), c.recovery.grace)
        continued |= bool(c.recovery.grace[0] == 2 and not ic["recovering"][0])  # a termination went on
    assert continued
    w.close()
    c.close()


@warp
def test_far_and_fallen_starts_on_the_warp_backend_stay_in_torch():
    import torch

    env = _warp_vec(far_distance=(2.0, 5.0), termination_distance=0.05, continue_prob=0.5, grace_steps=2)
    u = env.unwrapped
    obs, info = env.reset(seed=1, options={"recovery_start": KINDS4})
    assert isinstance(obs, torch.Tensor) and obs.dtype == torch.float32 and obs.shape == (4, 934)
    assert all(isinstance(v, torch.Tensor) for v in info.values())
    assert info["start_kind"].tolist() == [0, 1, 2, 3] and info["recovering"].tolist() == [False, True, True, True]
    body = env.sim.bodies
    ref_root = u.motion_frames.body_pos[u.ref.frame, 0]
    d = torch.linalg.norm(body.pos[:, 0, :2] - ref_root[:, :2], dim=-1)
    assert d[0] < 1e-5 and 2.0 - 1e-4 <= d[2] <= 5.0 + 1e-4  # reference, far
    assert (body.pos[[1, 3], 0, 2] < 0.5).all() and d[1] < 1.0 and d[3] > 1.0  # fallen (and far)
    assert not env.sim.qvel[[1, 3]][:, u.humanoid.qvel].any()  # fallen: at rest
    torch.testing.assert_close(info["root_distance"], torch.linalg.norm(body.pos[:, 0] - ref_root, dim=-1),
                               atol=1e-5, rtol=0)
    assert info["root_distance"][2] > 2.0 - 1e-4
    # The start mix drawn on the device, and steps with continue-as-recovery (continue_prob 0.5).
    _, info = env.reset(seed=2)
    assert isinstance(info["start_kind"], torch.Tensor) and ((info["start_kind"] >= 0) & (info["start_kind"] < 4)).all()
    for _ in range(8):
        obs, reward, term, trunc, info = env.step(torch.zeros(4, 69))
        assert isinstance(reward, torch.Tensor) and reward.dtype == torch.float32
        assert isinstance(info["reward_point"], torch.Tensor) and isinstance(info["recovering"], torch.Tensor)
        assert torch.isfinite(obs).all() and not info["diverged"].any()
    assert u.recovery.grace.device == obs.device and not trunc.any()  # hold_end: no clip-end truncation
    # Regenerated states reach the device.
    u.regenerate_fallen(seed=7)
    placed = u.recovery.fallen.place(u.np_random, torch.zeros(3, 2))
    assert isinstance(placed, torch.Tensor) and placed.shape == (3, 76)
    assert any(np.allclose(placed[0].cpu().numpy(), s, atol=1e-6) for s in u.recovery.fallen.states)
    env.close()


@warp
def test_imitation_with_recovery_on_the_warp_backend():
    import torch

    env = _warp_vec("SMPL/Imitation-v0", n=2, recovery=True, autoreset_mode="SameStep")
    env.reset(seed=0)
    qpos = env.sim.qpos.clone()
    qpos[:, 0] += 3.0
    env.sim.set_state(torch.arange(2), qpos, env.sim.qvel.clone())
    for _ in range(5):
        obs, reward, term, trunc, info = env.step(env.unwrapped.reference_action())
        assert not term.any() and info["recovering"].all()
        assert isinstance(info["reward_point"], torch.Tensor) and isinstance(info["root_distance"], torch.Tensor)
    assert (info["root_distance"] > 2.5).all() and info["start_kind"].tolist() == [0, 0]
    # Back within reach: the ordinary goal and termination rules again.
    env.reset(seed=0)
    _, _, term, _, info = env.step(env.unwrapped.reference_action())
    assert not info["recovering"].any() and (info["reward_point"] == 0).all()
    env.close()


def test_the_settings_benchmark_swaps_goal_settings_only_and_traces_trials(tmp_path, capsys):
    import importlib.util
    from pathlib import Path

    from agents import PPO

    path = Path(__file__).parents[1] / "benchmarks" / "recovery_settings.py"
    spec = importlib.util.spec_from_file_location("recovery_settings", path)
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    model = PPO(ID, n_envs=1, env_kwargs={"action_mode": "residual", "walk_guide": "brisk", **SMALL},
                policy_kwargs={"actor_hidden": (16,), "critic_hidden": (16,)}, verbose=0, device="cpu", seed=0)
    model.save(tmp_path / "m.pt")
    bench.main([str(tmp_path / "m.pt"), "--kinds", "far", "--trials", "2", "--num-envs", "2",
                "--sweep", "walk_guide=brisk,brisk_exact"])
    out = capsys.readouterr().out
    assert "walk_guide=brisk:" in out and "walk_guide=brisk_exact:" in out and "far 0.0 /" in out
    bench.main([str(tmp_path / "m.pt"), "--trace", "2", "--kinds", "far"])
    out = capsys.readouterr().out
    assert "back within 10 s: 0 of 2" in out  # an untrained policy walks nowhere
    with pytest.raises(SystemExit, match="not a goal setting"):
        bench.main([str(tmp_path / "m.pt"), "--set", "residual_scale=1.0"])


@warp
def test_the_reference_waits_on_the_warp_backend_as_on_the_cpu():
    """reference_waits in torch: the worlds started lost keep their reference frame while the
    world started on its reference moves on, as on the CPU backend."""
    frames = {}
    for backend in ("warp", "cpu"):
        env = _warp_vec("SMPL/Imitation-v0", backend=backend, recovery={"reference_waits": True,
                                                                         "starts": {"reference": 1.0}})
        u = env.unwrapped
        env.reset(seed=0, options={"start": "beginning"})
        qpos, qvel = u.sim.qpos, u.sim.qvel
        qpos = qpos.clone() if backend == "warp" else qpos.copy()
        qpos[1:, 0] += 3.0  # worlds 1-3 are 3 m from their reference
        u.sim.set_state(u.backend.asarray([1, 2, 3], "int"), qpos[1:], (qvel.clone() if backend == "warp"
                                                                       else qvel.copy())[1:])
        zero = u.backend.zeros((4, 69))
        env.step(zero)
        start = u.backend.to_numpy(u.ref.frame).copy()
        for _ in range(5):
            env.step(zero)
        frames[backend] = u.backend.to_numpy(u.ref.frame) - start
        env.close()
    assert frames["warp"].tolist() == frames["cpu"].tolist() == [5, 0, 0, 0]
