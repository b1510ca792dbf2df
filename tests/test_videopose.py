"""SMPL/VideoPose-v0 (SimPoE): cameras, the estimator model, the estimator-file loaders, the
metrics on known answers, the env's contracts (checker, seeding, actions, no external force unless
asked for), the refinement unit and SimPoE's PPO."""

from __future__ import annotations

import dataclasses
import math

import gymnasium as gym
import numpy as np
import pytest
import torch

import smpl_envs
from smpl_envs import metrics, video_metrics
from smpl_envs.camera import Camera, normalized_jacobian, random_camera
from smpl_envs.humanoid.kinematics import forward_kinematics, lowest_point
from smpl_envs.humanoid.skeleton import BODY_NAMES, MEAN_SKELETON
from smpl_envs.motion import load_motion, load_motions
from smpl_envs.motion.estimator_files import (EstimatorFileError, export_estimator_output, load_estimator_output,
                                              write_openpose)
from smpl_envs.motion.estimator_noise import EstimatorNoise, degrade, degrade_library
from smpl_envs.video_eval import input_rows
from smpl_envs.motion.video_input import DETECTED_BODIES, VideoInput, VideoLib
from conftest import check_env_quietly, seeded_rollouts

ID = "SMPL/VideoPose-v0"
OBS_DIM = 1087


@pytest.fixture(scope="module")
def walk():
    return load_motion("walk")


@pytest.fixture(scope="module")
def walk_input(walk):
    return degrade(walk, seed=1)


def bodies(root_pos, local_quat):
    return forward_kinematics(root_pos, local_quat, MEAN_SKELETON.offsets)[0]


# ---------------------------------------------------------------------------------------- camera
def test_projection_round_trip_and_its_jacobian_against_finite_differences():
    cam = Camera.look_at([4.0, -2.0, 1.5], [0.0, 0.0, 1.0], fx=1100.0, fy=1050.0, width=1280, height=720,
                         cx=650.0, cy=350.0, roll=0.05)
    rng = np.random.default_rng(0)
    pts = rng.uniform([-1, -1, 0], [1, 1, 2], (50, 3))
    px, depth = cam.project(pts)
    assert (depth > 0).all()
    np.testing.assert_allclose(cam.backproject(px, depth), pts, atol=1e-9)
    # A point on the optical axis lands on the principal point.
    on_axis = cam.position + 3.0 * cam.rotation[2]
    np.testing.assert_allclose(cam.project(on_axis)[0], [650.0, 350.0], atol=1e-9)
    jac, eps = cam.jacobian(pts), 1e-6
    for k in range(3):
        d = np.zeros(3)
        d[k] = eps
        fd = (cam.project(pts + d)[0] - cam.project(pts - d)[0]) / (2 * eps)
        np.testing.assert_allclose(jac[..., k], fd, rtol=1e-5, atol=1e-4)
    # The normalised Jacobian is the same function in torch.
    pc = cam.to_camera(pts)
    np.testing.assert_allclose(normalized_jacobian(torch.as_tensor(pc)).numpy(), normalized_jacobian(pc), atol=1e-12)


def test_random_cameras_film_the_motion(walk):
    for seed in range(5):
        cam = random_camera(np.random.default_rng(seed), walk.body_pos)
        px, depth = cam.project(walk.body_pos)
        assert (depth > 0.5).all()
        assert cam.visible(px[:, 0], depth[:, 0]).mean() >= 0.9
        assert 0.8 <= cam.position[2] <= 1.8


# ---------------------------------------------------------------------------------------- estimator model
def test_the_estimator_model_is_seeded(walk):
    a, b, c = degrade(walk, seed=3), degrade(walk, seed=3), degrade(walk, seed=4)
    for name in ("root_pos", "local_quat", "keypoints", "confidence"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
        assert not np.array_equal(getattr(a, name), getattr(c, name)), name
    lib1, lib2 = degrade_library(["walk", "run"], seed=7), degrade_library(["walk", "run"], seed=7)
    np.testing.assert_array_equal(lib1.estimate.body_pos, lib2.estimate.body_pos)


def test_zero_noise_is_the_truth_with_exact_keypoints(walk):
    v = degrade(walk, EstimatorNoise().scaled(0.0), seed=2)
    np.testing.assert_allclose(bodies(v.root_pos, v.local_quat), walk.body_pos, atol=1e-6)
    px, _ = v.camera.project(walk.body_pos)
    seen = v.confidence > 0
    np.testing.assert_allclose(v.keypoints[seen], px[seen], atol=1e-9)
    not_detected = np.setdiff1d(np.arange(24), DETECTED_BODIES)
    assert (v.confidence[:, not_detected] == 0).all() and seen[:, DETECTED_BODIES].mean() > 0.9


def test_each_knob_changes_only_what_it_names(walk):
    zero = {f.name: 0.0 for f in dataclasses.fields(EstimatorNoise) if f.name != "drift_time"}
    clean = degrade(walk, EstimatorNoise(**zero), seed=5)

    def only(**knob):
        return degrade(walk, EstimatorNoise(**{**zero, **knob}), seed=5)

    def same_estimate(v):
        np.testing.assert_array_equal(v.root_pos, clean.root_pos)
        np.testing.assert_array_equal(v.local_quat, clean.local_quat)

    def same_keypoints(v):
        np.testing.assert_array_equal(v.keypoints, clean.keypoints)
        np.testing.assert_array_equal(v.confidence, clean.confidence)

    for knob in ("jitter_rotation", "rotation_error"):
        v = only(**{knob: 0.1})
        np.testing.assert_array_equal(v.root_pos, clean.root_pos)
        assert not np.allclose(v.local_quat, clean.local_quat)
        same_keypoints(v)
    v = only(jitter_translation=0.02)
    np.testing.assert_array_equal(v.local_quat, clean.local_quat)
    assert not np.allclose(v.root_pos, clean.root_pos)
    same_keypoints(v)
    # Depth drift moves the body along the camera ray through the pelvis: the pelvis's image stays.
    v = only(depth_drift=0.3)
    np.testing.assert_array_equal(v.local_quat, clean.local_quat)
    assert np.abs(v.root_pos - clean.root_pos).max() > 0.1
    np.testing.assert_allclose(v.camera.project(v.root_pos)[0], clean.camera.project(clean.root_pos)[0], atol=1e-6)
    same_keypoints(v)
    v = only(foot_sliding=0.1)
    np.testing.assert_array_equal(v.root_pos[:, 2], clean.root_pos[:, 2])
    assert np.abs(v.root_pos[:, :2] - clean.root_pos[:, :2]).max() > 0.02
    same_keypoints(v)
    v = only(ground_penetration=0.05)
    np.testing.assert_array_equal(v.root_pos[:, :2], clean.root_pos[:, :2])
    sink = clean.root_pos[:, 2] - v.root_pos[:, 2]
    assert (sink >= 0).all() and 0.02 < sink.mean() < 0.08
    same_keypoints(v)
    v = only(keypoint_noise=5.0)
    same_estimate(v)
    np.testing.assert_array_equal(v.confidence, clean.confidence)
    seen = v.confidence > 0
    assert 4.5 < (v.keypoints - clean.keypoints)[seen].std() < 5.5
    v = only(low_confidence=0.3)
    same_estimate(v)
    assert (v.confidence <= clean.confidence).all() and 0.2 < ((v.confidence < 0.31) & (v.confidence > 0)).mean() / \
        (clean.confidence > 0).mean() < 0.4
    v = only(occlusion=0.2)
    same_estimate(v)
    missing = (v.confidence == 0) & (clean.confidence > 0)
    assert 0.1 < missing.sum() / (clean.confidence > 0).sum() < 0.35


def test_noise_degrades_every_metric_and_grows_with_its_scale():
    lib = load_motions(["walk", "run", "turn"])
    summaries = {s: video_metrics.summarize(input_rows(degrade_library(lib, EstimatorNoise().scaled(s), seed=0)))
                 for s in (0.0, 0.5, 1.0, 2.0)}
    clean = summaries[0.0]
    assert clean["mpjpe"] < 1e-3 and clean["reprojection"] < 1e-3 and clean["ground_penetration"] < 1e-3
    for key in ("mpjpe", "pa_mpjpe", "accel", "foot_sliding", "ground_penetration", "reprojection"):
        values = [summaries[s][key] for s in (0.0, 0.5, 1.0, 2.0)]
        assert all(a < b for a, b in zip(values, values[1:])), (key, values)


def test_a_noise_scale_range_scales_each_clips_own_errors_and_stays_out_of_the_evaluation():
    from smpl_envs.motion.estimator_noise import check_scale_range

    lib = load_motions(["walk", "run", "turn"])
    default = degrade_library(lib, seed=0)
    np.testing.assert_array_equal(degrade_library(lib, seed=0, scale_range=(1, 1)).pixels, default.pixels)
    clean = video_metrics.summarize(input_rows(degrade_library(lib, seed=0, scale_range=(0, 0))))
    assert clean["mpjpe"] < 1e-3 and clean["reprojection"] < 1e-3
    mixed = degrade_library(lib, seed=0, scale_range=(0.0, 2.0))
    np.testing.assert_array_equal(mixed.pixels, degrade_library(lib, seed=0, scale_range=(0.0, 2.0)).pixels)
    # Clip i: the default clip's own draws, every magnitude times its scale from stream (0, i, 1).
    scales, start = [], 0
    for i in range(lib.num_motions):
        s = np.random.default_rng(np.random.SeedSequence([0, i, 1])).uniform(0.0, 2.0)
        one = degrade(lib.motion(i), EstimatorNoise().scaled(s), seed=np.random.default_rng(np.random.SeedSequence([0, i])))
        np.testing.assert_allclose(mixed.estimate.motion(i).qpos[:, :3], one.root_pos, atol=1e-6)
        np.testing.assert_allclose(mixed.pixels[start:start + len(one.keypoints)], one.keypoints, atol=1e-3)
        start += len(one.keypoints)
        scales.append(s)
    assert np.ptp(scales) > 0.1
    for bad in ((2, 1), (-1, 1), "x", (0, float("nan"))):
        with pytest.raises(ValueError, match="noise_scale_range"):
            check_scale_range(bad)
    # The env takes it; a training run's evaluation measures at noise_scale alone.
    env = gym.make_vec(ID, num_envs=1, motions="walk", noise_scale_range=(0.0, 0.0))
    np.testing.assert_allclose(env.unwrapped.video.estimate.body_pos, env.unwrapped.truth.body_pos, atol=1e-6)
    env.close()
    from smpl_envs.video_eval import VideoProtocol
    assert VideoProtocol().eval_kwargs({"noise_scale_range": [0, 1], "noise_scale": 1.0}) == {"noise_scale": 1.0}


# ---------------------------------------------------------------------------------------- metrics
def test_metrics_on_known_answers():
    t = np.arange(10)
    # A foot point sliding 1 cm per frame on the floor: FS 10 mm; lifted 5 cm: no contact.
    slide = np.stack([0.01 * t, 0 * t, 0 * t + 0.005], -1)[:, None]
    assert video_metrics.foot_sliding(slide) == (pytest.approx(10.0), 9)
    fs, n = video_metrics.foot_sliding(slide + [0, 0, 0.05])
    assert math.isnan(fs) and n == 0
    # A foot sunk 3 cm (its lowest point): GP 30 mm; above the floor: 0.
    sunk = np.zeros((4, 2, 3))
    sunk[..., 2] = [-0.03, 0.02]
    assert video_metrics.ground_penetration(sunk) == pytest.approx(30.0)
    assert video_metrics.ground_penetration(sunk + [0, 0, 0.1]) == 0.0
    # A jittering joint: +-1 cm every other frame on one of 4 joints; second differences 4 cm.
    truth = np.random.default_rng(0).normal(size=(12, 4, 3))
    sim = truth.copy()
    sim[:, 2, 0] += 0.01 * (-1.0) ** np.arange(12)
    assert metrics.accel_error(sim, truth) == pytest.approx(40.0 / 4)
    # PA-MPJPE is blind to a similarity transform, MPJPE to a translation only.
    rot = np.linalg.qr(np.random.default_rng(1).normal(size=(3, 3)))[0]
    rot *= np.sign(np.linalg.det(rot))
    moved = 1.3 * truth @ rot.T + [1.0, -2.0, 0.5]
    row = video_metrics.sequence_metrics(moved, moved, np.zeros((12, 1, 3)) + 1, np.ones(12), np.ones(12), truth)
    assert row["pa_mpjpe"] < 1e-6 and row["mpjpe"] > 100
    row = video_metrics.sequence_metrics(truth + 0.2, truth, np.zeros((12, 1, 3)) + 1, np.ones(12), np.ones(12), truth)
    assert row["mpjpe"] < 1e-9 and row["g_mpjpe"] == pytest.approx(200 * math.sqrt(3))
    # The reprojection error is pooled by confidence.
    row = video_metrics.sequence_metrics(truth, truth, np.ones((12, 1, 3)), np.r_[np.full(6, 2.0), np.full(6, 8.0)],
                                         np.r_[np.full(6, 3.0), np.full(6, 1.0)], truth)
    assert row["reprojection"] == pytest.approx((6 * 3 * 2 + 6 * 1 * 8) / 24)


# ---------------------------------------------------------------------------------------- estimator files
@pytest.mark.parametrize("layout, suffix, matrices", [("coco17", "npz", False), ("body25", "pkl", True),
                                                      ("body25", "npz", True), ("coco17", "pkl", False)])
def test_estimator_files_in_each_layout_load_back(walk_input, tmp_path, layout, suffix, matrices):
    v = walk_input
    path = export_estimator_output(v, tmp_path / f"smpl.{suffix}", layout=layout, matrices=matrices)
    w = load_estimator_output(path)
    assert w.truth is None and w.fps == 30 and w.name == "smpl"
    np.testing.assert_allclose(bodies(w.root_pos, w.local_quat), bodies(v.root_pos, v.local_quat), atol=1e-9)
    mapped = w.confidence > 0
    np.testing.assert_allclose(w.keypoints[mapped], v.keypoints[mapped], atol=1e-9)
    np.testing.assert_allclose(w.confidence[mapped], v.confidence[mapped], atol=1e-12)
    # COCO has no pelvis, neck or toes: those bodies get nothing.
    missing = [BODY_NAMES.index(n) for n in ("Pelvis", "Neck", "L_Toe", "R_Toe")]
    assert (w.confidence[:, missing] == 0).all() == (layout == "coco17")
    assert (w.camera.fx, w.camera.cy, w.camera.width) == (v.camera.fx, v.camera.cy, v.camera.width)


def test_without_extrinsics_the_camera_is_level_and_the_floor_under_the_estimate(walk_input, tmp_path):
    v = walk_input
    w = load_estimator_output(export_estimator_output(v, tmp_path / "smpl.npz", extrinsics=False))
    np.testing.assert_allclose(w.camera.rotation[1], [0, 0, -1], atol=1e-12)  # image y = world down
    a, b = bodies(v.root_pos, v.local_quat), bodies(w.root_pos, w.local_quat)
    np.testing.assert_allclose(w.camera.project(b)[0], v.camera.project(a)[0], atol=1e-6)  # the same images
    floor = lowest_point(*forward_kinematics(w.root_pos, w.local_quat, MEAN_SKELETON.offsets), MEAN_SKELETON)
    assert np.percentile(floor, 5) == pytest.approx(0.0, abs=1e-9)


def test_openpose_json_keypoints_and_a_separate_camera_file(walk_input, tmp_path):
    v = walk_input
    smpl = export_estimator_output(v, tmp_path / "smpl.npz")
    with np.load(smpl) as z:
        fields = {k: z[k] for k in z.files if not k.startswith(("keypoint", "focal", "principal", "image"))}
    np.savez(tmp_path / "bare.npz", **fields)
    op = write_openpose(v, tmp_path / "openpose")
    cam = {"K": v.camera.intrinsics.tolist(), "image_size": [v.camera.width, v.camera.height]}
    w = load_estimator_output(tmp_path / "bare.npz", keypoints=op, camera=cam)
    np.testing.assert_allclose(w.keypoints[w.confidence > 0], v.keypoints[w.confidence > 0], atol=1e-9)
    assert (w.confidence > 0).sum() == (v.confidence > 0).sum()


@pytest.mark.parametrize("edit, field", [
    (lambda f, t: f.pop("transl"), "transl"),
    (lambda f, t: f.update(body_pose=np.zeros((t, 50))), "body_pose"),
    (lambda f, t: f.pop("global_orient"), "global_orient"),
    (lambda f, t: (f.update(keypoints_2d=np.zeros((t, 20, 3))), f.pop("keypoint_layout")), "keypoint_layout"),
    (lambda f, t: f.update(keypoints_2d=np.full((5, 25, 3), 0.5)), "frames of keypoints"),
    (lambda f, t: f.update(keypoints_2d=np.full((t, 25, 3), 2.0)), "confidences"),
    (lambda f, t: f.pop("focal_length"), "intrinsics"),
    (lambda f, t: f.pop("image_size"), "image_size"),
    (lambda f, t: f.update(camera_rotation=np.ones((3, 3))), "camera_rotation"),
    (lambda f, t: f.pop("camera_position"), "camera_position"),
    (lambda f, t: f.update(fps=np.array(-3.0)), "frame rate"),
    (lambda f, t: f.update(transl=np.full((t, 3), np.nan)), "transl"),
])
def test_broken_estimator_files_name_the_file_and_the_field(walk_input, tmp_path, edit, field):
    with np.load(export_estimator_output(walk_input, tmp_path / "good.npz")) as z:
        fields = {k: z[k] for k in z.files}
    edit(fields, walk_input.num_frames)
    np.savez(tmp_path / "bad.npz", **fields)
    with pytest.raises(EstimatorFileError, match=field) as e:
        load_estimator_output(tmp_path / "bad.npz")
    assert "bad.npz" in str(e.value)


def test_many_people_need_a_choice(walk_input, tmp_path):
    import joblib

    export_estimator_output(walk_input, tmp_path / "one.pkl")
    fields = joblib.load(tmp_path / "one.pkl")
    joblib.dump({1: fields, 7: fields}, tmp_path / "two.pkl")
    with pytest.raises(EstimatorFileError, match="person="):
        load_estimator_output(tmp_path / "two.pkl")
    assert load_estimator_output(tmp_path / "two.pkl", person=7).num_frames == walk_input.num_frames


def test_video_input_resamples_to_30_fps(walk_input):
    v = walk_input
    fast = dataclasses.replace(v, fps=60.0, truth=None)
    slow = fast.resampled(30.0)
    assert slow.num_frames == (v.num_frames - 1) // 2 + 1
    np.testing.assert_allclose(slow.root_pos, v.root_pos[::2])
    np.testing.assert_allclose(slow.keypoints, v.keypoints[::2])


# ---------------------------------------------------------------------------------------- the env
def test_registered_with_a_native_batched_env_that_passes_the_checker():
    assert ID in smpl_envs.ENV_IDS and gym.spec(ID).vector_entry_point is not None
    env = gym.make(ID, motions="walk", render_mode="rgb_array", render_size=(96, 72))
    check_env_quietly(env)
    assert env.observation_space.shape == (OBS_DIM,) and env.action_space.shape == (69,)
    env.close()
    env = gym.make_vec(ID, num_envs=4, motions=["walk", "run"])
    assert env.sim.num_worlds == 4
    (a, info), (b, _), (c, _) = seeded_rollouts(env, steps=15)
    assert all(np.array_equal(x, y) for x, y in zip(a, b)) and not np.array_equal(a[0], c[0])
    terms = [info[f"reward_{k}"] for k in ("pose", "velocity", "joint", "keypoint")]
    np.testing.assert_allclose(a[-3], np.prod(terms, axis=0), rtol=1e-6)  # the reward is their product
    assert max(s.stop for s in env.observation_structure.values()) == OBS_DIM
    env.close()


def test_the_observation_holds_the_imitation_observation_of_the_estimate():
    # What lets the Imitation-v0 tracker run here unchanged.
    env = gym.make_vec(ID, num_envs=2, motions="walk", noise_scale=0.0)
    imit = gym.make_vec("SMPL/Imitation-v0", num_envs=2, motions=env.video.estimate)
    opts = {"motion_ids": [0, 0], "start": "beginning"}
    a, _ = env.reset(seed=0, options=opts)
    b, _ = imit.reset(seed=0, options=opts)
    np.testing.assert_allclose(a[:, :934], b, atol=1e-5)
    env.close(), imit.close()


@pytest.mark.parametrize("options", [{}, {"meta_pd": True, "residual_force": True}])
def test_the_warp_backend_matches_the_cpu_backend(options):
    """Both simulators take meta-PD's per-substep gains and the root wrench: with random actions
    on every component the two backends agree step by step (float32 against float64). Zeroing
    either component on one side alone moves the observations by ~1 within a step (measured)."""
    pytest.importorskip("mujoco_warp", reason="MuJoCo Warp is not installed")
    torch = pytest.importorskip("torch")
    from conftest import WARP_DEVICE, step_backends_alike

    w = gym.make_vec(ID, num_envs=2, motions="walk", backend="warp", device=WARP_DEVICE, **options)
    c = gym.make_vec(ID, num_envs=2, motions="walk", num_threads=1, **options)
    begin = {"motion_ids": [0, 0], "start": "beginning"}
    ow, _ = w.reset(seed=0, options=begin)
    oc, _ = c.reset(seed=0, options=begin)
    assert isinstance(ow, torch.Tensor) and np.abs(ow.cpu().numpy() - oc).max() < 1e-4
    step_backends_alike(w, c, steps=6, info_keys=("est_body_pos", "truth_body_pos", "next_truth_root_pos",
                                                  "foot_points", "reprojection_error", "keypoint_weight",
                                                  "reward_keypoint"))
    if options:
        assert w.sim.pd_scales.shape == (2, w.substeps, 2) and w.sim.root_wrench.abs().max() > 1.0
    w.close(), c.close()


def test_residual_root_force_is_absent_unless_enabled():
    env = gym.make_vec(ID, num_envs=2, motions="walk", autoreset_mode="Disabled")
    assert env.single_action_space.shape == (69,) and env.sim.root_wrench is None
    env.reset(seed=0)
    for _ in range(5):
        env.step(np.ones((2, 69)) * 0.1)
    assert all(not d.xfrc_applied.any() for d in env.sim.datas)
    env.close()
    forced = gym.make_vec(ID, num_envs=2, motions="walk", residual_force=True, autoreset_mode="Disabled")
    assert forced.single_action_space.shape == (75,) and forced.action_layout["root_wrench"] == slice(69, 75)
    pelvis = []
    for push in (0.0, 1.0):
        forced.reset(seed=0, options={"start": "beginning", "motion_ids": [0, 0]})
        a = np.zeros((2, 75))
        a[:, 70] = push  # 300 N to the humanoid's left (heading frame)
        for _ in range(10):
            info = forced.step(a)[-1]
        pelvis.append(info["body_pos"][:, 0].copy())
    assert (np.linalg.norm(pelvis[1] - pelvis[0], axis=-1) > 0.05).all()
    wrench = forced.sim.datas[0].xfrc_applied[forced.humanoid.root]
    assert np.linalg.norm(wrench[:2]) == pytest.approx(300.0) and wrench[2] == 0 and not wrench[3:].any()
    forced.close()
    # No other task takes it.
    for env_id in smpl_envs.ENV_IDS:
        if env_id != ID:
            with pytest.raises(TypeError, match="residual_force"):
                gym.make_vec(env_id, num_envs=1, residual_force=True)


def test_meta_pd_scales_the_gains_per_substep():
    plain = gym.make_vec(ID, num_envs=1, motions="walk", autoreset_mode="Disabled")
    meta = gym.make_vec(ID, num_envs=1, motions="walk", meta_pd=True, autoreset_mode="Disabled")
    assert meta.single_action_space.shape == (69 + 2 * meta.substeps,)
    opts = {"start": "beginning", "motion_ids": [0]}

    def roll(env, extra):
        env.reset(seed=0, options=opts)
        for _ in range(10):
            obs, *_ = env.step(np.concatenate([np.zeros((1, 69)), extra], -1))
        return obs

    neutral = roll(meta, np.zeros((1, 2 * meta.substeps)))
    np.testing.assert_allclose(neutral, roll(plain, np.zeros((1, 0))), atol=1e-4)  # scales 1: the plain PD
    soft = roll(meta, -np.ones((1, 2 * meta.substeps)))  # half the gains
    stiff = roll(meta, np.ones((1, 2 * meta.substeps)))
    assert np.abs(soft - neutral).max() > 0.05 and np.abs(stiff - neutral).max() > 0.01
    plain.close(), meta.close()


def test_evaluation_without_ground_truth_reports_physics_and_reprojection(walk_input, tmp_path):
    path = export_estimator_output(walk_input, tmp_path / "mine.npz")
    result = smpl_envs.evaluate(lambda obs: np.zeros((len(obs), 69)), ID, env_kwargs={"video": str(path)},
                                progress=False)
    row = result.rows[0]
    assert math.isnan(row["mpjpe"]) and math.isnan(row["pa_mpjpe"])
    assert np.isfinite(row["reprojection"]) and np.isfinite(row["ground_penetration"]) and row["frames"] > 1
    assert "-" in result.table() and result.summary["clips"] == 1


def test_evaluation_with_ground_truth_and_the_input_row():
    lib = degrade_library(["walk", "turn"], seed=0)
    zero = lambda obs: np.zeros((len(obs), 69))  # noqa: E731
    one = smpl_envs.evaluate(zero, ID, motions=lib, num_envs=1, progress=False)
    two = smpl_envs.evaluate(zero, ID, motions=lib, num_envs=2, progress=False)
    assert [r["mpjpe"] for r in one.rows] == [r["mpjpe"] for r in two.rows]  # whatever the number of worlds
    assert all(np.isfinite(r["mpjpe"]) for r in one.rows) and 0.0 <= one.summary["no_fall"] <= 1.0
    rows = input_rows(lib)
    assert all(not r["fell"] and r["mpjpe"] > 20 for r in rows)


# ---------------------------------------------------------------------------------------- SimPoE
@pytest.fixture(scope="module")
def video_obs():
    env = gym.make_vec(ID, num_envs=32, motions=["walk", "run", "turn", "kick"])
    obs, info = env.reset(seed=0)
    env.close()
    return torch.as_tensor(obs), torch.as_tensor(info["next_truth_dof_pos"]), env.single_action_space


def test_refinement_kinematics_match_the_env_and_reduce_the_reprojection_loss(video_obs):
    from agents.simpoe import OBS, KinematicRefinement, split_observation

    obs, truth, space = video_obs
    pol = KinematicRefinement(OBS_DIM, space, iterations=5)
    parts = split_observation(obs)
    pos, _, axes = pol.refine.forward_kinematics(parts["root_pos"], parts["root_rot"], parts["angles"])
    np.testing.assert_allclose(pos.reshape(len(obs), -1), obs[:, OBS["estimate/ref_pos"]], atol=1e-5)
    with torch.no_grad():
        refined, est, grad, before, after = pol.refined(obs)
    assert after.sum() < 0.5 * before.sum()
    assert not torch.equal(refined, est)
    # The analytic dL/dtheta is the gradient of the loss through the kinematics.
    # (in float64 from the start: the root's rotation must be orthonormal to float64 precision)
    p = split_observation(obs.double())
    angles = p["angles"].clone().requires_grad_(True)
    pol = pol.double()
    pos, _, axes = pol.refine.forward_kinematics(p["root_pos"], p["root_rot"], angles)
    loss, g_x, jac = pol.refine.reprojection(pos, p["keypoints"], p["confidence"], p["cam_rot"], p["cam_pos"])
    (auto,) = torch.autograd.grad(loss.sum(), angles)
    np.testing.assert_allclose(pol.refine.angle_gradient(pos, axes, g_x).detach(), auto, rtol=1e-6, atol=1e-10)
    # The factored Gauss-Newton diagonal is the sum over (hinge, joint) pairs.
    d = pos[:, None] - pos[:, 1:, None]
    u = torch.linalg.cross(axes[:, :, :, None], d[:, :, None], dim=-1)
    pu = torch.einsum("bjmn,bikjn->bikjm", jac, u)
    brute = ((pu * pu).sum(-1) * (pol.refine.subtree[1:, None, :] * p["confidence"][:, None, None])).sum(-1)
    np.testing.assert_allclose(pol.refine.gauss_newton_diagonal(pos, axes, jac, p["confidence"]),
                               brute.reshape(len(obs), -1).detach(), rtol=1e-8, atol=1e-12)


def test_no_refinement_acts_on_the_estimate_and_the_raw_columns_stay_raw(video_obs):
    from agents.simpoe import OBS, KinematicRefinement

    obs, _, space = video_obs
    pol = KinematicRefinement(OBS_DIM, space, iterations=0)
    pol.update_obs_stats(obs * 3 + 1)
    nobs = pol.normalize(obs)
    refined, est, *_ = pol.refined(nobs)
    assert torch.equal(refined, est) and torch.equal(est, obs[:, OBS["video/est_dof"]])
    for name in ("video/keypoints", "video/camera_rot", "estimate/ref_rot"):
        assert torch.equal(nobs[:, OBS[name]], obs[:, OBS[name]])
    assert not torch.allclose(nobs[:, OBS["self/body_lin_vel"]], obs[:, OBS["self/body_lin_vel"]])
    # the actor and the critic read every column normalised, the raw ones too
    feat = pol.features(nobs)
    np.testing.assert_allclose(feat, pol.obs_norm(obs), atol=1e-6)
    with torch.no_grad():
        feat = torch.cat([feat, est, 100.0 * pol.refined(nobs)[2].reshape(len(obs), -1)], -1)
        np.testing.assert_allclose(pol.distribution(nobs).mean, pol.actor(feat), atol=1e-6)
        np.testing.assert_allclose(pol.critic_output(nobs), pol.critic(pol.obs_norm(obs)).squeeze(-1), atol=1e-6)


def test_the_refined_reference_is_the_imitation_goal_of_the_refined_pose(video_obs):
    from agents.simpoe import OBS, KinematicRefinement, rot6d_to_matrix, split_observation

    obs, truth, space = video_obs
    pol = KinematicRefinement(OBS_DIM, space, iterations=2, refined_reference=True)
    pol.update_obs_stats(obs * 2 + 1)
    nobs = pol.normalize(obs)
    for name in ("estimate/diff_pos", "estimate/diff_rot"):  # kept raw: the goal is re-posed from them
        assert torch.equal(nobs[:, OBS[name]], obs[:, OBS[name]])
    # Re-posed on the true angles, the goal's reference is the true pose, and what it says about
    # the simulated bodies (their positions and rotations) is unchanged.
    parts = split_observation(nobs)
    with torch.no_grad():
        pos, rot, _ = pol.refine.forward_kinematics(parts["root_pos"], parts["root_rot"], truth)
        out = pol.reference_on(nobs, pol.refine(**parts)._replace(angles=truth, pos=pos, rot=rot))
    b = len(obs)
    np.testing.assert_allclose(out[:, OBS["estimate/ref_pos"]], pos.reshape(b, -1), atol=1e-5)
    np.testing.assert_allclose(out[:, OBS["estimate/ref_rot"]], rot[..., :2].reshape(b, -1), atol=1e-5)

    def simulated(x):
        ref = rot6d_to_matrix(x[:, OBS["estimate/ref_rot"]].reshape(b, 24, 6))
        diff = rot6d_to_matrix(x[:, OBS["estimate/diff_rot"]].reshape(b, 24, 6))  # R_ref R_sim^T
        return x[:, OBS["estimate/ref_pos"]] - x[:, OBS["estimate/diff_pos"]], ref.swapaxes(-1, -2) @ diff

    for before, after in zip(simulated(obs), simulated(out)):
        np.testing.assert_allclose(after, before, atol=1e-5)
    assert (out[:, OBS["estimate/ref_pos"]] - obs[:, OBS["estimate/ref_pos"]]).abs().max() > 0.01
    rest = torch.ones(OBS_DIM, dtype=torch.bool)
    for name in ("estimate/diff_pos", "estimate/ref_pos", "estimate/diff_rot", "estimate/ref_rot"):
        rest[OBS[name]] = False
    assert torch.equal(out[:, rest], nobs[:, rest])
    # The actor reads it; without refinement it is the estimate's goal, as the plain policy's.
    with torch.no_grad():
        r = pol.refine(**parts)
        feat = torch.cat([pol.features(pol.reference_on(nobs, r)), r.angles, 100.0 * r.grad.reshape(b, -1)], -1)
        offset = (r.angles - split_observation(nobs)["angles"]) / pol._residual_unit
        np.testing.assert_allclose(pol.distribution(nobs).mean, pol.actor(feat) + offset, atol=1e-5)
        plain = KinematicRefinement(OBS_DIM, space, iterations=0)
        same = KinematicRefinement(OBS_DIM, space, iterations=0, refined_reference=True)
        same.load_state_dict(plain.state_dict())
        torch.testing.assert_close(same.distribution(same.normalize(obs)).mean,
                                   plain.distribution(plain.normalize(obs)).mean)


def test_a_warm_start_from_the_tracker_acts_as_the_tracker_on_the_estimate(video_obs):
    from agents import SimPoEPPO, load
    from agents.recipes import find_checkpoint
    from agents.simpoe import IMITATION_OBS, KinematicRefinement
    from agents.warm_start import init_policy

    obs = video_obs[0].numpy()
    tracker_path = find_checkpoint("tracker")
    tracker = load(tracker_path)

    def make(**policy_kwargs):
        return SimPoEPPO(ID, n_envs=2, env_kwargs={"motions": ["walk"], "meta_pd": True}, verbose=0,
                         tensorboard=False, device="cpu", policy_kwargs={"iterations": 0, **policy_kwargs})

    model = make()
    out = init_policy(model, tracker_path)
    assert "actor.0.weight" in out["copied"] and "obs_norm.mean" in out["copied"]
    act = model.predict(obs, deterministic=True)[0]
    assert act.shape == (len(obs), 69 + 2 * 4)  # + meta-PD's kp and kd scales per substep
    np.testing.assert_allclose(act[:, :69], tracker.predict(obs[:, IMITATION_OBS], deterministic=True)[0], atol=1e-5)
    assert np.all(act[:, 69:] == 0)  # nominal gains
    np.testing.assert_allclose(model.policy.value(model.policy.normalize(torch.as_tensor(obs))).detach(),
                               tracker.policy.value(tracker.policy.normalize(torch.as_tensor(obs[:, IMITATION_OBS])))
                               .detach(), rtol=1e-4, atol=1e-4)
    # With refinement the tracker's action moves by the refinement's offset only.
    refining = make(iterations=2)
    init_policy(refining, tracker_path)
    pol = refining.policy
    nobs = pol.normalize(torch.as_tensor(obs))
    with torch.no_grad():
        angles, est, *_ = pol.refined(nobs)
        offset = ((angles - est) / pol._residual_unit).numpy()
    np.testing.assert_allclose(refining.predict(obs, deterministic=True)[0][:, :69] - offset,
                               act[:, :69], atol=1e-4)
    with pytest.raises(ValueError, match=r"actor layer 0 is \(512, 934\) in the source, this policy's is "
                                         r"\(32, 1228\): make actor_hidden the source's"):
        init_policy(make(actor_hidden=[32]), tracker_path)
    with pytest.raises(ValueError, match="starts from an imitation ActorCritic"):
        model.policy.init_from(KinematicRefinement, model.policy.state_dict())
    for m in (model, refining):
        m.close()


@pytest.mark.parametrize("target, unit", [("angles", "deg"), ("positions", "mm")])
def test_supervised_pretraining_lowers_the_refinement_error(target, unit):
    from agents import SimPoEPPO

    model = SimPoEPPO(ID, n_envs=8, env_kwargs={"motions": ["walk", "run"]}, policy_kwargs={
        "iterations": 2, "refine_hidden": [64], "actor_hidden": [32], "critic_hidden": [32]},
        refine_pretrain_samples=128, refine_pretrain_epochs=6, refine_target=target, batch_size=64, verbose=0,
        seed=0, tensorboard=False, device="cpu")
    out = model.pretrain_refinement(128)
    assert out[f"after_{unit}"] < out[f"before_{unit}"] and model.refine_pretrained
    model.close()
    with pytest.raises(ValueError, match="ground truth"):
        lib = VideoLib([dataclasses.replace(degrade(load_motion("walk"), seed=0), truth=None)])
        SimPoEPPO(ID, n_envs=2, env_kwargs={"video": lib}, policy_kwargs={"iterations": 1, "refine_hidden": [8],
                  "actor_hidden": [8], "critic_hidden": [8]}, verbose=0, tensorboard=False,
                  device="cpu").pretrain_refinement(16)


def test_the_supervised_loss_during_ppo_pairs_each_observation_with_its_truth_and_lowers_the_error():
    from agents import SimPoEPPO
    from agents.simpoe import OBS, TRUTH

    # Without noise the estimate is the truth: each stored observation's estimate columns must be
    # the truth stored beside it, across the resets a tight termination distance forces.
    model = SimPoEPPO(ID, n_envs=4, env_kwargs={"motions": ["walk", "run"], "noise_scale": 0.0,
                                                "termination_distance": 0.02},
                      policy_kwargs={"iterations": 2, "refine_hidden": [64], "actor_hidden": [32], "critic_hidden": [32]},
                      refine_aux_coef=1000.0, n_steps=24, batch_size=48, n_epochs=4, learning_rate=1e-3, verbose=0,
                      seed=0, tensorboard=False, device="cpu")
    model._start_collector(seed=0)
    buf = model._collect()
    data = buf.transitions()
    assert buf.dones.sum() > 0  # resets happened inside the rollout
    np.testing.assert_allclose(data["obs"][:, OBS["video/est_dof"]].numpy(), data[TRUTH].numpy(), atol=1e-6)
    model.close()

    model = SimPoEPPO(ID, n_envs=4, env_kwargs={"motions": ["walk", "run"]},
                      policy_kwargs={"iterations": 2, "refine_hidden": [64], "actor_hidden": [32], "critic_hidden": [32]},
                      refine_aux_coef=1000.0, n_steps=32, batch_size=64, n_epochs=4, learning_rate=1e-3, verbose=0,
                      seed=0, tensorboard=False, device="cpu")
    model._start_collector(seed=0)
    data = model._collect().transitions()

    def error() -> float:
        with torch.no_grad():
            return float(model.policy.refinement_angle_error(data["obs"], data[TRUTH]).mean())

    # The supervised term reuses the refined angles of PPO's own forward pass: the same loss as
    # PPO's plus the error computed on its own.
    from agents import PPO
    with torch.no_grad():
        mb = {k: v[:64] for k, v in data.items()}
        model._refine_errors = {}
        expected = PPO._loss(model, mb)[0] + 1000.0 * model.policy.refinement_angle_error(mb["obs"], mb[TRUTH]).mean()
        assert float(model._loss(mb)[0]) == pytest.approx(float(expected), rel=1e-5)

    before = error()
    model.learn(6 * 128, progress_bar=False)
    assert error() < 0.8 * before
    model.close()
    with pytest.raises(ValueError, match="refine_target must be one of angles, positions"):
        SimPoEPPO(ID, n_envs=2, env_kwargs={"motions": ["walk"]}, refine_target="joints", verbose=0, tensorboard=False)
    with pytest.raises(ValueError, match="refine_aux_coef needs ground truth"):
        lib = VideoLib([dataclasses.replace(degrade(load_motion("walk"), seed=0), truth=None)])
        SimPoEPPO(ID, n_envs=2, env_kwargs={"video": lib}, policy_kwargs={"iterations": 1, "refine_hidden": [8],
                  "actor_hidden": [8], "critic_hidden": [8]}, refine_aux_coef=1.0, n_steps=4, batch_size=8,
                  verbose=0, tensorboard=False, device="cpu").learn(8, progress_bar=False)


def test_the_bounds_loss_can_leave_the_refinements_offset_out(video_obs):
    from agents import SimPoEPPO

    obs, _, _ = video_obs
    model = SimPoEPPO(ID, n_envs=2, env_kwargs={"motions": ["walk"]}, bounds_on_refinement=False, verbose=0,
                      tensorboard=False, device="cpu", policy_kwargs={"iterations": 2, "refine_hidden": [16],
                                                                      "actor_hidden": [16], "critic_hidden": [16]})
    pol = model.policy
    with torch.no_grad():
        pol.refine.correction[-1].bias.fill_(0.5)  # refined angles beyond the residual range: offsets past the bounds
        nobs = pol.normalize(obs)
        dist, extras = pol.scored_distribution(nobs)
        own = dist.mean - extras["offset"]
        np.testing.assert_allclose(own, pol.actor(torch.cat([pol.features(nobs), extras["refined_angles"],
                                                            100.0 * pol.refined(nobs)[2].reshape(len(obs), -1)], -1)),
                                   atol=1e-5)
        actions = dist.mean.clamp(-1, 1)
        mb = {"obs": nobs, "actions": actions, "log_probs": dist.log_prob(actions).sum(-1),
              "advantages": torch.zeros(len(obs)), "returns": torch.zeros(len(obs)), "values": torch.zeros(len(obs))}

        def bounds(mu):
            return ((mu - 1.1).clamp(min=0).square() + (mu + 1.1).clamp(max=0).square()).sum(-1).mean()

        assert bounds(dist.mean) > 1.0
        assert float(model._loss(mb)[4]) == pytest.approx(float(bounds(own)), rel=1e-5)
        model.config.bounds_on_refinement = True
        assert float(model._loss(mb)[4]) == pytest.approx(float(bounds(dist.mean)), rel=1e-5)
    model.close()


def test_the_refinements_learning_rate_scale_holds_it_or_slows_it_and_survives_a_resume(tmp_path):
    from agents import SimPoEPPO

    def make(scale, **kw):
        return SimPoEPPO(ID, n_envs=4, env_kwargs={"motions": ["walk", "run"]}, refine_lr_scale=scale,
                         policy_kwargs={"iterations": 2, "refine_hidden": [16], "actor_hidden": [16],
                                        "critic_hidden": [16]}, refine_aux_coef=1000.0, n_steps=16, batch_size=32,
                         learning_rate=1e-3, lr_schedule="linear", verbose=0, seed=0, tensorboard=False,
                         device="cpu", **kw)

    model = make(0.0)
    refine = {k: v.clone() for k, v in model.policy.refine.state_dict().items()}
    actor = {k: v.clone() for k, v in model.policy.actor.state_dict().items()}
    model.learn(128, progress_bar=False)
    # Its supervised loss and PPO's reach it, but at a scale of 0 it stays as it was; the actor learns.
    for k, v in model.policy.refine.state_dict().items():
        torch.testing.assert_close(v, refine[k], rtol=0, atol=0)
    assert any(not torch.equal(v, actor[k]) for k, v in model.policy.actor.state_dict().items())
    model.close()

    model = make(0.25)
    model.learn(128, progress_bar=False)
    main, refining = model.optimizer.param_groups
    assert {id(p) for p in refining["params"]} == {id(p) for p in model.policy.refine.parameters()}
    assert 0 < main["lr"] < 1e-3 and refining["lr"] == pytest.approx(0.25 * main["lr"])
    model.save(tmp_path / "scaled.pt")
    model.close()
    loaded = SimPoEPPO.load(tmp_path / "scaled.pt", env=None, device="cpu")
    assert [g["lr_scale"] for g in loaded.optimizer.param_groups] == [1.0, 0.25]
    with pytest.raises(ValueError, match="2 parameter group.*refine_lr_scale"):
        SimPoEPPO.load(tmp_path / "scaled.pt", env=None, device="cpu", refine_lr_scale=1.0)
    with pytest.raises(ValueError, match="refine_lr_scale must be >= 0"):
        make(-0.1)


def test_a_unit_that_refines_the_root_learns_where_the_estimate_puts_it():
    from agents import SimPoEPPO
    from agents.simpoe import OBS, TRUTH, split_observation

    kwargs = dict(policy_kwargs={"iterations": 1, "refine_hidden": [64], "actor_hidden": [32], "critic_hidden": [32],
                                 "refine_root": True, "refined_reference": True},
                  refine_aux_coef=1000.0, n_steps=16, batch_size=64, verbose=0, seed=0, tensorboard=False, device="cpu")
    # Without noise the truth stored beside each observation is the estimate: its angles and root.
    model = SimPoEPPO(ID, n_envs=4, env_kwargs={"motions": ["walk", "run"], "noise_scale": 0.0}, **kwargs)
    model._start_collector(seed=0)
    data = model._collect().transitions()
    assert data[TRUTH].shape[1] == 69 + 3
    np.testing.assert_allclose(data[TRUTH][:, 69:], data["obs"][:, OBS["estimate/ref_pos"]][:, :3], atol=1e-5)
    np.testing.assert_allclose(data[TRUTH][:, :69], data["obs"][:, OBS["video/est_dof"]], atol=1e-6)
    model.close()
    # With the estimator's errors (the estimate sinks and drifts), regression moves the root towards the truth,
    # and the actor's goal moves with it.
    model = SimPoEPPO(ID, n_envs=8, env_kwargs={"motions": ["walk", "run", "turn"]}, refine_pretrain_epochs=30, **kwargs)
    out = model.pretrain_refinement(2048)
    assert out["after_root_mm"] < 0.8 * out["before_root_mm"]
    assert out["after_deg"] < out["before_deg"]
    obs = torch.as_tensor(model.env.reset(seed=1)[0])
    pol = model.policy
    with torch.no_grad():
        r = pol.refinement(pol.normalize(obs))
    est_root = obs[:, OBS["estimate/ref_pos"]][:, :3]
    assert (r.root - est_root).norm(dim=-1).mean() > 0.005
    np.testing.assert_allclose(r.pos[:, 0], r.root, atol=1e-6)
    with pytest.raises(ValueError, match="needs the floor's height"):
        pol.refine(**split_observation(obs))
    model.close()


@pytest.mark.slow
def test_the_recipes_smoke_profile_trains_saves_and_loads(tmp_path, monkeypatch):
    import agents
    from agents.recipes import load_recipe
    from agents.run import train

    monkeypatch.chdir(tmp_path)
    for profile in ("no_refinement", "no_meta_pd", "residual_force", "paper"):
        load_recipe("videopose_ppo", profile=profile)  # every profile validates
    assert train("videopose_ppo", profile="smoke", run_dir=tmp_path / "run", progress=False, quiet=True) == 0
    ckpt = tmp_path / "run" / "checkpoints" / "last.pt"
    model = agents.load(ckpt)
    assert type(model).__name__ == "SimPoEPPO" and model.refine_pretrained
    assert type(model.policy).__name__ == "KinematicRefinement" and model.env_kwargs["meta_pd"] is True
    env = gym.make_vec(ID, num_envs=2, motions="walk", meta_pd=True)
    obs, _ = env.reset(seed=0)
    first = model.predict(obs)[0]
    model.save(tmp_path / "again.pt")
    again = agents.load(tmp_path / "again.pt")
    np.testing.assert_array_equal(again.predict(obs)[0], first)
    assert first.shape == (2, 69 + 2 * env.substeps)
    result = smpl_envs.evaluate(again, ID, motions=["walk"], progress=False)
    assert result.summary["clips"] == 1 and "score" in result.summary
    env.close()


@pytest.mark.slow
def test_the_video_to_motion_example_runs(tmp_path):
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    out = subprocess.run([sys.executable, str(root / "examples" / "video_to_motion.py"), "--size", "96", "72",
                          "--out", str(tmp_path)], capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-2000:]
    with np.load(tmp_path / "walk_physics.npz") as z:
        assert z["body_pos"].shape[1:] == (24, 3) and z["qpos"].shape[1] == 76 and len(z["body_pos"]) > 10
    assert load_motion(tmp_path / "walk_physics_amass.npz").num_frames == len(np.load(tmp_path / "walk_physics.npz")["qpos"])
    assert (tmp_path / "walk_physics.mp4").stat().st_size > 1000
    assert "the kinematic input itself" in out.stdout and "MPJPE" in out.stdout
