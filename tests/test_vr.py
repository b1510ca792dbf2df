"""SMPL/VRTracking-v0: Gymnasium contracts, the three-point goal (which references it reads and
that it is Imitation's goal of those bodies), rewards, termination, three-point stream files, the
evaluation protocol, and the MuJoCo Warp backend (on Warp's CPU device: parity with the CPU
backend for clips and streams, torch outputs, stream starts on the device)."""

import importlib.util
from dataclasses import replace

import gymnasium as gym
import numpy as np
import pytest

import smpl_envs
from smpl_envs.envs.imitation import imitation_reward
from smpl_envs.envs.vr import VR_GOAL_LAYOUT, tracked, vr_terminated, yaw_of
from smpl_envs.evaluation import _three_point_row
from smpl_envs.features import body_goal_obs, heading_rotation, layout_size, tracking_obs
from smpl_envs.humanoid import BODY_NAMES
from smpl_envs.motion import MotionFileError, MotionLib
from smpl_envs.motion.three_point import (TRACKED, ThreePointStream, load_stream, write_stream)
from smpl_envs.rotations import quat_to_matrix
from conftest import WARP_DEVICE, check_env_quietly, seeded_rollouts, step_backends_alike

ID = "SMPL/VRTracking-v0"
GOAL = slice(358, 430)
HEAD, KNEE = BODY_NAMES.index("Head"), BODY_NAMES.index("L_Knee")


@pytest.fixture(scope="module")
def walk_stream(tmp_path_factory):
    """A stream file cut from the shipped walk clip."""
    lib = MotionLib.load("walk", progress=False)
    s = ThreePointStream.from_motion((lib, 0))
    return write_stream(tmp_path_factory.mktemp("streams") / "walk_3p.npz", s.positions, s.quats)


def _vec(**kwargs):
    return gym.make_vec(ID, **{"num_envs": 2, "motions": "walk", **kwargs})


def test_registered_sizes_and_env_checker():
    assert ID in smpl_envs.ENV_IDS and layout_size(VR_GOAL_LAYOUT) == 72
    env = gym.make(ID, render_mode="rgb_array", render_size=(96, 72))
    check_env_quietly(env)
    assert env.observation_space.shape == (430,) and env.action_space.shape == (69,)
    env.reset(seed=0)
    assert env.render().shape == (72, 96, 3)
    env.close()


def test_make_vec_is_native_batched_and_seeded():
    env = gym.make_vec(ID, num_envs=8, motions=["walk", "run"])
    assert env.sim.num_worlds == 8
    (a, info), (b, _), (c, _) = seeded_rollouts(env)
    assert a[0].shape == (8, 430) and a[0].dtype == np.float32
    assert all(np.array_equal(x, y) for x, y in zip(a, b)) and not np.array_equal(a[0], c[0])
    assert info["point_pos"].shape == (8, 3, 3) and info["ref_body_pos"].shape == (8, 24, 3)
    terms = [k for k in info if k.startswith("reward_")]
    assert np.allclose(a[-3], sum(info[k] for k in terms))
    assert max(s.stop for s in env.observation_structure.values()) == 430
    env.close()


def test_goal_is_imitations_goal_of_the_three_bodies():
    env = _vec(start="random")
    env.reset(seed=1)
    env.step(np.random.default_rng(0).uniform(-0.2, 0.2, (2, 69)))
    u = env.unwrapped
    body, ref = u.sim.bodies, u.ref.next()
    heading = heading_rotation(body.rot[:, 0])
    full = tracking_obs(body, ref, "rotation", heading)[:, 358:]
    assert np.allclose(body_goal_obs(body, ref, np.arange(24), heading), full, atol=1e-6)
    # The VR goal = the imitation goal's columns of Head, L_Hand, R_Hand, block by block.
    cols = np.concatenate([start + (k * TRACKED[:, None] + np.arange(k)).ravel()
                           for start, k in zip(np.cumsum([0, 72, 72, 72, 72, 144])[:6], (3, 3, 3, 3, 6, 6))])
    assert np.allclose(u._observe(body, heading)[:, GOAL], full[:, cols], atol=1e-6)
    env.close()


def test_observation_reads_only_the_three_references():
    env = _vec(start="beginning")
    env.reset(seed=0)
    u = env.unwrapped
    body = u.sim.bodies
    heading = heading_rotation(body.rot[:, 0])
    before = u._observe(body, heading)
    lib = u.motion_lib
    lib.body_pos = lib.body_pos.copy()
    lib.body_pos[:, KNEE] += 0.3  # another body's reference moves: nothing changes
    u.ref._cache = {}
    assert np.array_equal(u._observe(body, heading), before)
    lib.body_pos[:, HEAD] += 0.1  # the head's moves: the goal changes, the self part does not
    u.ref._cache = {}
    after = u._observe(body, heading)
    assert np.array_equal(after[:, :358], before[:, :358])
    assert np.abs(after[:, GOAL] - before[:, GOAL]).max() > 0.05
    env.close()


def test_zero_error_in_the_reference_state_and_reward_kwarg_switches_terms():
    env = _vec(start="beginning")
    _, info = env.reset(seed=0)
    u = env.unwrapped
    assert info["point_error"].max() < 1e-4 and np.allclose(info["point_pos"], info["ref_point_pos"], atol=1e-4)
    body = u.sim.bodies
    goal = body_goal_obs(body, tracked(u.ref.current()), TRACKED, heading_rotation(body.rot[:, 0]))
    assert np.abs(goal[:, :9]).max() < 1e-4 and np.abs(goal[:, 36:54] - np.tile([1, 0, 0, 1, 0, 0], 3)).max() < 1e-4
    reward, terms, terminated, _ = u._evaluate(body, heading_rotation(body.rot[:, 0]))
    assert np.allclose(terms["pos"], 0.5, atol=1e-3) and np.allclose(terms["rot"], 0.3, atol=1e-3)
    assert not terminated.any()

    # "full" is Imitation's reward over 24 bodies; "three_point" the same terms over the three.
    ref = u.ref.current()
    ref_moved = replace(ref, pos=ref.pos.copy())
    ref_moved.pos[:, KNEE] += 0.2
    force = u.sim.actuator_force
    full, _ = imitation_reward(body, ref, force)
    full_moved, _ = imitation_reward(body, ref_moved, force)
    three, _ = imitation_reward(tracked(body), tracked(ref), force)
    three_moved, _ = imitation_reward(tracked(body), tracked(ref_moved), force)
    assert np.allclose(reward, full) and (full_moved < full - 0.01).all() and np.allclose(three_moved, three)
    env.close()
    env = _vec(start="beginning", reward="three_point")
    env.reset(seed=0)
    u = env.unwrapped
    body = u.sim.bodies
    reward, *_ = u._evaluate(body, heading_rotation(body.rot[:, 0]))
    assert np.allclose(reward, imitation_reward(tracked(body), tracked(u.ref.current()), u.sim.actuator_force)[0])
    env.close()


def test_termination_at_a_quarter_metre_of_one_point():
    sim = np.zeros((4, 3, 3))
    ref = sim.copy()
    ref[1, 2, 0], ref[2, 0, 2], ref[3, 1, 1] = 0.26, 0.24, -0.3
    assert vr_terminated(sim, ref).tolist() == [False, True, False, True]
    assert vr_terminated(sim, ref, 0.2).tolist() == [False, True, True, True]
    for shift, ends in ((0.1, False), (0.4, True)):
        env = _vec(start="beginning")
        env.reset(seed=0)
        u = env.unwrapped
        u.motion_lib.body_pos = u.motion_lib.body_pos.copy()
        u.motion_lib.body_pos[:, BODY_NAMES.index("R_Hand"), 1] += shift  # one point's reference
        u.ref._cache = {}
        _, _, terminated, _, info = env.step(u.reference_action())
        assert terminated.tolist() == [ends, ends], (shift, info["point_error"])
        env.close()


def test_stream_files_round_trip_and_bad_ones_are_refused(tmp_path):
    lib = MotionLib.load("gesture", progress=False)
    s = ThreePointStream.from_motion((lib, 0))
    a = load_stream(write_stream(tmp_path / "q.npz", s.positions, s.quats))
    b = load_stream(write_stream(tmp_path / "m.npz", s.positions, quat_to_matrix(s.quats), name="mat"))
    for got in (a, b):
        assert got.num_frames == lib.lengths[0] and np.allclose(got.positions, lib.body_pos[:, TRACKED], atol=1e-6)
        assert np.allclose(quat_to_matrix(got.quats), quat_to_matrix(lib.body_quat[:, TRACKED].astype(float)), atol=1e-5)
    assert a.name == "q" and b.name == "mat"
    # 60 fps streams are resampled to 30.
    c = load_stream(write_stream(tmp_path / "f.npz", np.repeat(s.positions, 2, 0)[:-1], np.repeat(s.quats, 2, 0)[:-1], fps=60))
    assert c.num_frames == s.num_frames and np.allclose(c.positions, s.positions, atol=1e-6)

    def bad(name, **arrays):
        np.savez(tmp_path / name, **{"positions": s.positions, "rotations": s.quats, **arrays})
        with pytest.raises(MotionFileError) as e:
            load_stream(tmp_path / name)
        assert name in str(e.value)
        return str(e.value)

    assert "shape" in bad("shape.npz", positions=s.positions[:, :2])
    nan = s.positions.copy()
    nan[7, 1, 2] = np.nan
    assert "frame 7" in bad("nan.npz", positions=nan)
    assert "at least 2" in bad("short.npz", positions=s.positions[:1], rotations=s.quats[:1])
    assert "unit" in bad("norm.npz", rotations=s.quats * np.where(np.arange(len(s.quats)) == 4, 2.0, 1.0)[:, None, None])
    assert "frame 4" in bad("norm2.npz", rotations=s.quats * np.where(np.arange(len(s.quats)) == 4, 2.0, 1.0)[:, None, None])
    assert "frames" in bad("count.npz", rotations=s.quats[:-3])


def test_a_stream_drives_the_env_like_the_clip_it_was_cut_from(walk_stream):
    # No early termination: an autoreset would restart the two differently (reference state vs
    # standing pose).
    clip = _vec(start="beginning", reward="three_point", termination_distance=None)
    stream = _vec(start="beginning", motions=str(walk_stream), termination_distance=None)
    clip.reset(seed=0)
    _, info = stream.reset(seed=0)
    us, uc = stream.unwrapped, clip.unwrapped
    assert us.streams is not None and us.motion_lib is None and us.reward_mode == "three_point"
    assert "ref_body_pos" not in info and info["point_error"].max() < 0.3  # standing pose under the head
    # Same physical state in both: then observations and rewards must agree step by step.
    qpos = np.stack([d.qpos.copy() for d in uc.sim.datas])
    qvel = np.stack([d.qvel.copy() for d in uc.sim.datas])
    us.sim.set_state(np.arange(2), qpos, qvel)
    rng = np.random.default_rng(0)
    for _ in range(10):
        action = uc.reference_action() + rng.uniform(-0.05, 0.05, (2, 69))
        oc, rc, *_ = clip.step(action)
        os_, rs, *_ = stream.step(action)
        assert np.allclose(oc, os_, atol=2e-4) and np.allclose(rc, rs, atol=1e-4)
    clip.close()
    stream.close()


def test_stream_mode_refuses_what_needs_a_full_body(walk_stream, tmp_path):
    with pytest.raises(ValueError, match="three_point"):
        _vec(motions=str(walk_stream), reward="full")
    with pytest.raises(ValueError, match="absolute"):
        _vec(motions=str(walk_stream), action_mode="residual")
    with pytest.raises(ValueError, match="mixed"):
        _vec(motions=[str(walk_stream), "walk"])
    with pytest.raises(ValueError, match="reward"):
        _vec(reward="hands")
    env = _vec(action_mode="residual")  # clips have joint angles: residual works
    env.reset(seed=0)
    assert np.array_equal(env.unwrapped.reference_action(), np.zeros((2, 69), np.float32))
    env.close()


def test_three_point_row_fails_at_the_first_point_beyond_the_threshold():
    frames = []
    for t in range(6):
        sim, ref = np.zeros((3, 3)), np.zeros((3, 3))
        ref[2, 0] = 0.1 if t < 3 else 0.6  # one hand only: the mean over points stays below 0.5
        frames.append([sim, ref])
    row = _three_point_row("x", 0, frames, False, 0.5)
    assert row["success"] is False and row["fail_frame"] == 3 and np.isnan(row["mpjpe_pa"])
    assert row["mpjpe_g"] == pytest.approx(1000 * (0.3 + 1.8) / 18)
    # Frames before the grace period are not tested; their errors still count.
    assert _three_point_row("x", 0, frames, False, 0.5, grace=4)["fail_frame"] == 4
    row = _three_point_row("x", 0, frames, False, 0.5, grace=6)
    assert row["success"] and row["fail_frame"] == -1 and row["mpjpe_g"] == pytest.approx(1000 * 2.1 / 18)


def test_streams_start_standing_under_the_head_with_a_grace_period(tmp_path):
    lib = MotionLib.load("run", progress=False)
    s = ThreePointStream.from_motion((lib, 0))
    path = write_stream(tmp_path / "run.npz", s.positions, s.quats)
    ends = []
    for grace in (0, None):
        env = _vec(motions=str(path), start="beginning", grace_steps=grace)
        _, info = env.reset(seed=0)
        u = env.unwrapped
        # Head over the stream's head, facing its way; the running hand starts far off.
        assert np.allclose(info["point_pos"][:, 0, :2], s.positions[0, 0, :2], atol=1e-6)
        assert info["point_error"][:, 2].min() > 0.25
        head_rot = u.sim.bodies.rot[:, HEAD]
        assert np.allclose(yaw_of(head_rot), yaw_of(quat_to_matrix(s.quats[:1, 0])), atol=1e-6)
        _, _, terminated, _, _ = env.step(np.tile(u._start_pose[7:] / u.action_scale, (2, 1)))
        ends.append(terminated.tolist())
        env.close()
    assert ends == [[True, True], [False, False]]
    with pytest.raises(ValueError, match="grace_steps"):
        _vec(grace_steps=-1)


def test_evaluation_on_clips_and_streams(walk_stream):
    env = gym.make_vec(ID, num_envs=2, motions=["stand", "gesture", "crouch"], termination_distance=None,
                       autoreset_mode="Disabled")
    result = smpl_envs.evaluate(lambda obs: env.unwrapped.reference_action(), env, progress=False)
    rows, s = result.rows, result.summary
    assert [r["name"] for r in rows] == ["stand", "gesture", "crouch"] and s["clips"] == 3
    # PD tracking of the reference without a policy loses balance: a clip stops at its fail frame.
    assert all(r["frames"] == (r["fail_frame"] + 1 if r["fail_frame"] >= 0 else lengths) for r, lengths
               in zip(rows, env.unwrapped.motion_lib.lengths))
    assert all(np.isfinite(r["body_mpjpe_g"]) and r["success"] == (r["fail_frame"] < 0) for r in rows)
    weights = np.array([r["frames_pos"] for r in rows])
    assert s["all_mpjpe_g"] == pytest.approx((weights * [r["mpjpe_g"] for r in rows]).sum() / weights.sum())
    assert s["body_clips"] == 3 and np.isfinite(s["body_all_mpjpe_g"]) and "full body" in result.table()
    env.close()
    # A stream: no full body, a policy-free baseline (hold the start pose's joint angles: zero
    # action is the T-pose) still gets a row with three-point errors.
    result = smpl_envs.evaluate(lambda obs: np.zeros((len(obs), 69)), ID, motions=str(walk_stream), progress=False)
    (row,) = result.rows
    assert "body_mpjpe_g" not in row and "body_clips" not in result.summary and np.isfinite(row["mpjpe_g"])


def test_vr_stream_example_runs(tmp_path):
    import json
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    out = subprocess.run([sys.executable, str(root / "examples" / "vr_stream.py"), "--clip", "crouch",
                          "--out", str(tmp_path)], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    assert load_stream(tmp_path / "crouch_3p.npz").num_frames == MotionLib.load("crouch", progress=False).lengths[0]
    stand = json.loads((tmp_path / "vr_crouch_stand.json").read_text())
    pd = json.loads((tmp_path / "vr_crouch_pd-reference.json").read_text())
    assert "body_clips" not in stand["summary"] and pd["summary"]["body_clips"] == 1
    assert "full body" in out.stdout


def test_a_directory_or_list_of_streams(tmp_path, walk_stream):
    lib = MotionLib.load("gesture", progress=False)
    s = ThreePointStream.from_motion((lib, 0))
    write_stream(tmp_path / "a" / "gesture.npz", s.positions, s.quats)
    write_stream(tmp_path / "a" / "deeper" / "again.npz", s.positions[:50], s.quats[:50])
    env = _vec(motions=str(tmp_path / "a"))
    assert env.unwrapped.streams.names == ["again", "gesture"] and list(env.unwrapped.streams.lengths) == [50, 241]
    env.close()
    env = _vec(motions=[str(walk_stream), str(tmp_path / "a" / "gesture.npz")])
    obs, info = env.reset(seed=0, options={"motion_ids": [1, 0], "start": "beginning"})
    assert info["motion_id"].tolist() == [1, 0] and np.allclose(info["ref_point_pos"][0], s.positions[0], atol=1e-6)
    env.close()


# ---------------------------------------------------------------------- the MuJoCo Warp backend
# Parity tolerance as tests/test_env_warp.py: float32 there, float64 here; from the walk clip's
# first frame observations agree to ~1e-5 (measured; the run and stand clips' foot contacts make
# the two diverge within a few steps, so parity is checked on walk).
warp = pytest.mark.skipif(importlib.util.find_spec("mujoco_warp") is None,
                          reason="MuJoCo Warp is not installed (pip install 'smpl-envs[gpu]')")


def _pair(**kwargs):
    """The same env on the warp backend (Warp's CPU device) and on the CPU one."""
    return _vec(backend="warp", device=WARP_DEVICE, **kwargs), _vec(num_threads=1, **kwargs)


@warp
@pytest.mark.parametrize("reward", ["full", "three_point"])
def test_warp_backend_matches_the_cpu_backend(reward):
    import torch

    # One clip and starts at its first frame: the episodes that end restart alike on both
    # backends (their random generators differ). A tight termination distance makes some end.
    n, begin = 3, {"motion_ids": [0, 0, 0], "start": "beginning"}
    w, c = _pair(num_envs=n, reward=reward, action_mode="residual", start="beginning", termination_distance=0.15)
    ow, iw = w.reset(seed=0, options=begin)
    oc, ic = c.reset(seed=0, options=begin)
    assert np.abs(ow.cpu().numpy() - oc).max() < 1e-4
    ended = step_backends_alike(w, c, info_keys=("point_pos", "ref_point_pos", "point_error", "ref_body_pos",
                                                  "reward_pos", "reward_rot"))
    assert ended >= 2  # terminations and the restarts after them were compared too
    w.close()
    c.close()


@warp
def test_warp_outputs_are_torch_tensors():
    import torch

    env = _vec(backend="warp", device=WARP_DEVICE, action_mode="residual", render_mode="rgb_array", render_size=(64, 48))
    obs, info = env.reset(seed=0)
    assert isinstance(obs, torch.Tensor) and obs.dtype == torch.float32 and obs.shape == (2, 430)
    assert all(isinstance(v, torch.Tensor) for v in info.values())
    u = env.unwrapped
    ref = u.reference_action()
    assert isinstance(ref, torch.Tensor) and torch.equal(ref, torch.zeros(2, 69, device=ref.device))
    obs, reward, terminated, truncated, info = env.step(ref)
    assert reward.dtype == torch.float32 and reward.shape == (2,)
    assert terminated.dtype == torch.bool and truncated.dtype == torch.bool
    assert all(isinstance(v, torch.Tensor) for v in info.values())
    assert info["point_pos"].shape == (2, 3, 3) and info["point_error"].shape == (2, 3)
    assert info["ref_body_pos"].shape == (2, 24, 3) and info["motion_id"].dtype == torch.int64
    assert torch.allclose(reward, sum(v for k, v in info.items() if k.startswith("reward_")))
    assert env.render_frame().shape == (48, 64, 3)  # the reference markers read the host library
    env.close()


@warp
def test_warp_backend_drives_streams(walk_stream, tmp_path):
    import torch

    lib = MotionLib.load("run", progress=False)
    s = ThreePointStream.from_motion((lib, 0))
    run = write_stream(tmp_path / "run.npz", s.positions, s.quats)  # its hand starts far from the pose
    kwargs = {"motions": [str(run), str(walk_stream)], "start": "beginning", "grace_steps": 2,
              "autoreset_mode": "SameStep"}
    w, c = _pair(**kwargs)
    u = w.unwrapped
    assert u.streams is not None and u.motion_lib is None and u.reward_mode == "three_point"
    assert isinstance(u.stream_frames.pos, torch.Tensor) and u.ref.lib is u.stream_frames
    assert u.references is u.streams  # the evaluation reads names and lengths on the host

    # Standing starts built on the device: the CPU backend's, to float32 rounding.
    begin = {"motion_ids": [0, 1], "start": "beginning"}
    ow, iw = w.reset(seed=0, options=begin)
    oc, ic = c.reset(seed=0, options=begin)
    assert isinstance(ow, torch.Tensor) and "ref_body_pos" not in iw
    assert np.abs(ow.cpu().numpy() - oc).max() < 1e-4
    assert np.abs(w.sim.qpos.cpu().numpy() - np.stack([d.qpos for d in c.unwrapped.sim.datas])).max() < 1e-5
    for key in ("point_pos", "ref_point_pos", "point_error", "motion_time"):
        assert np.abs(iw[key].cpu().numpy() - ic[key]).max() < 1e-5, key

    # Hold the start pose: the run stream's hand is beyond 0.25 m once the grace period is over.
    hold = u._start_pose[7:] / u.action_scale
    assert isinstance(hold, torch.Tensor)
    alike = np.ones(2, bool)  # worlds not restarted yet (a restart draws its stream on each backend's generator)
    for k in range(3):
        ow, rw, tw, uw, iw = w.step(hold.repeat(2, 1))
        oc, rc, tc, uc, ic = c.step(np.tile(hold.cpu().numpy(), (2, 1)))
        assert tw.tolist() == tc.tolist() and tc[0] == (k == 1), k
        assert np.abs(rw.cpu().numpy() - rc)[alike].max(initial=0) < 1e-3, k
        alike &= ~tc
        assert np.abs(ow.cpu().numpy() - oc)[alike].max(initial=0) < 1e-3, k
        ended = tw.nonzero().reshape(-1)
        if len(ended):
            # Restarted within the step (SameStep): from the first frame of a stream, standing
            # under its head; the info is the new episode's.
            assert (u.elapsed[ended] == 0).all() and torch.isfinite(ow).all()
            assert torch.equal(u.ref.frame[ended], u.stream_frames.starts[u.ref.motion_id[ended]])
            assert torch.allclose(iw["point_pos"][ended, 0, :2], iw["ref_point_pos"][ended, 0, :2], atol=1e-5)
    assert not alike[0]

    # Random starts on the device: frames inside their streams, the head under the stream head
    # and facing its way.
    obs, info = w.reset(seed=1, options={"start": "random"})
    frames, ids = u.ref.frame, u.ref.motion_id
    starts, lengths = u.stream_frames.starts[ids], u.stream_frames.lengths[ids]
    assert ((frames >= starts) & (frames < starts + lengths - 1)).all()
    host = u.streams.pos[frames.cpu().numpy()]
    assert np.allclose(info["ref_point_pos"].cpu().numpy(), host, atol=1e-6)
    assert torch.allclose(info["point_pos"][:, 0, :2], info["ref_point_pos"][:, 0, :2], atol=1e-5)
    head_yaw = yaw_of(u.sim.bodies.rot[:, HEAD])
    assert torch.allclose(head_yaw, yaw_of(u.stream_frames.rot[frames, 0]), atol=1e-4)
    w.close()
    c.close()


@warp
def test_warp_evaluation_of_a_stream(tmp_path):
    lib = MotionLib.load("crouch", progress=False)
    s = ThreePointStream.from_motion((lib, 0))
    path = str(write_stream(tmp_path / "crouch.npz", s.positions, s.quats))

    def zero(obs):  # T-pose targets: the humanoid falls away from the stream within a second
        return np.zeros((len(obs), 69), np.float32)

    rows = [smpl_envs.evaluate(zero, ID, motions=path, num_envs=1, progress=False, env_kwargs=kw).rows[0]
            for kw in ({"backend": "warp", "device": WARP_DEVICE}, {})]
    assert rows[0]["frames"] == rows[1]["frames"] and rows[0]["fail_frame"] == rows[1]["fail_frame"]
    assert rows[0]["mpjpe_g"] == pytest.approx(rows[1]["mpjpe_g"], rel=0.05)
