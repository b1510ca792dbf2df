import pickle
from pathlib import Path

import joblib
import mujoco
import numpy as np
import pytest

from conftest import sway_motion
from smpl_envs.humanoid import build_humanoid
from smpl_envs.motion import (
    Motion, MotionFileError, MotionLib, available_clips, load_motion, read_motion_file,
)
from smpl_envs.motion.export import to_amass, to_phc_pkl
from smpl_envs.motion.library import CLIPS_DIR
from smpl_envs.motion.motion import FORMAT_NAME, FORMAT_VERSION
from smpl_envs.humanoid.kinematics import lowest_point
from smpl_envs.humanoid.skeleton import MEAN_SKELETON
from smpl_envs.rotations import quat_apply, yaw_quat

SHIPPED = ("stand", "walk", "run", "turn", "jump", "kick", "gesture", "crouch")


@pytest.fixture(scope="module")
def model():
    return build_humanoid()


def max_kinematic_error(model, motion) -> float:
    """Largest distance between MuJoCo's bodies at motion.qpos and motion.body_pos."""
    data = mujoco.MjData(model)
    worst = 0.0
    for qpos, body_pos in zip(motion.qpos, motion.body_pos):
        data.qpos[:] = qpos
        mujoco.mj_kinematics(model, data)
        worst = max(worst, np.linalg.norm(data.xpos[1:] - body_pos, axis=-1).max())
    return worst


# ---------------------------------------------------------------- kinematic consistency
def test_every_clip_ships_and_replays_exactly(model):
    assert set(SHIPPED) <= set(available_clips())
    for name in available_clips():
        motion = load_motion(name)
        assert motion.fps == 30 and 2.0 <= motion.duration <= 10.0, name
        assert max_kinematic_error(model, motion) < 1e-3, name


def test_amass_file_replays_exactly(tmp_path, model):
    to_amass(sway_motion(120), tmp_path / "a.npz")
    assert max_kinematic_error(model, load_motion(tmp_path / "a.npz")) < 1e-3


def test_library_lookup_at_frame_times_matches_the_clip(model):
    lib = MotionLib.load(["walk", "jump"])
    for i in range(lib.num_motions):
        m = load_motion(lib.names[i])
        frames = np.arange(m.num_frames)
        s = lib.get_state(np.full(len(frames), i), frames / lib.fps)
        np.testing.assert_allclose(s.body_pos, m.body_pos, atol=1e-5)
        np.testing.assert_allclose(s.qpos, m.qpos, atol=1e-5)
        np.testing.assert_allclose(s.qvel, m.qvel, atol=1e-4)
        assert max_kinematic_error(model, lib.motion(i)) < 1e-3


# ---------------------------------------------------------------- formats and frame rates
@pytest.mark.parametrize("fps, layout, rate_key", [
    (120, "smplh", "mocap_framerate"), (100, "smplx", "mocap_frame_rate"),
    (60, "smpl", "mocap_framerate"), (250, "smplh", "mocap_framerate"),
])
def test_amass_rates_and_layouts_resample_to_30_fps(tmp_path, fps, layout, rate_key):
    source = sway_motion(fps, seconds=3.0)
    assert source.num_frames == 3 * fps + 1
    to_amass(source, tmp_path / "clip.npz", layout=layout, rate_key=rate_key)
    motion = load_motion(tmp_path / "clip.npz")
    assert motion.fps == 30
    assert motion.num_frames == 91  # 3 s at 30 fps, first and last frame included
    # the pelvis follows the source trajectory at the resampled times
    t = np.arange(91) / 30
    np.testing.assert_allclose(motion.qpos[:, 0], 1.2 * t + motion.qpos[0, 0], atol=1e-6)


def test_non_multiple_rates_interpolate_rotations():
    """From 100 fps, 30 fps frames fall between source frames: slerp, not nearest frame."""
    raw = sway_motion(100, seconds=2.0)
    out = raw.resampled(30)
    exact = sway_motion(30, seconds=2.0)  # the same analytic motion sampled at 30 fps directly
    assert out.num_frames == exact.num_frames
    dot = np.abs(np.sum(out.local_quat * exact.local_quat, -1))
    angle_error = 2 * np.arccos(np.clip(dot, 0, 1))
    assert angle_error.max() < 2e-3  # interpolation error of a smooth motion, well under a degree
    dropped = raw.local_quat[np.round(np.arange(out.num_frames) * 100 / 30).astype(int)]
    dropped_error = 2 * np.arccos(np.clip(np.abs(np.sum(dropped * exact.local_quat, -1)), 0, 1))
    assert angle_error.mean() < 0.2 * dropped_error.mean()


def test_phc_pickle_and_own_format_round_trip(tmp_path):
    walk, jump = load_motion("walk"), load_motion("jump")
    to_phc_pkl([walk, jump], tmp_path / "phc.pkl")
    lib = MotionLib.load(tmp_path / "phc.pkl")
    assert lib.names == ["walk", "jump"]
    np.testing.assert_allclose(lib.motion(0).body_pos, walk.body_pos, atol=1e-5)
    with pytest.raises(MotionFileError, match="2 sequences"):
        load_motion(tmp_path / "phc.pkl")
    walk.save(tmp_path / "own.npz")
    again = load_motion(tmp_path / "own.npz")
    np.testing.assert_allclose(again.qpos, walk.qpos, atol=1e-12)


def test_source_betas_are_kept_but_ignored_by_default(tmp_path):
    raw = sway_motion(60)
    raw.betas = np.linspace(-1, 1, 16)
    to_amass(raw, tmp_path / "a.npz")
    plain = sway_motion(60)
    to_amass(plain, tmp_path / "b.npz")
    a, b = load_motion(tmp_path / "a.npz"), load_motion(tmp_path / "b.npz")
    np.testing.assert_allclose(a.betas, raw.betas)
    np.testing.assert_allclose(a.body_pos, b.body_pos)  # same mean body either way


# ---------------------------------------------------------------- derived quantities
def test_clips_touch_the_ground():
    for name in ("walk", "jump"):
        m = load_motion(name)
        assert lowest_point(m.body_pos, m.body_quat, MEAN_SKELETON).min() == pytest.approx(0, abs=1e-9)


def test_velocities_match_the_motion(model):
    m = Motion.from_raw(sway_motion(30))
    # pelvis moves forward at 1.2 m/s: finite differences recover it away from the clip ends
    np.testing.assert_allclose(m.body_lin_vel[5:-5, 0, 0], 1.2, atol=0.01)
    # MuJoCo's own finite difference of qpos agrees with qvel
    for t in range(5, m.num_frames - 5, 10):
        v = np.zeros(model.nv)
        mujoco.mj_differentiatePos(model, v, 2 / 30, m.qpos[t - 1], m.qpos[t + 1])
        np.testing.assert_allclose(m.qvel[t], v, atol=0.05)


def test_hinge_angles_are_continuous():
    m = load_motion("turn")
    assert np.abs(np.diff(m.dof_pos, axis=0)).max() < 1.0  # no 2*pi wraps between frames



def test_hinge_angles_keep_their_decomposition_through_a_tie():
    # The left arm held forward at shoulder height, jittering by half a degree: its two x-y-z
    # decompositions, about (-90, 0, -90) and (90, 180, 90) deg, tie under the |x| + |z| rule,
    # which alone takes a different one from frame to frame (a half-turn jump every frame).
    from smpl_envs.motion.kinematics import Segments, hinge_angles
    from smpl_envs.rotations import quat_from_euler_xyz
    from smpl_envs.humanoid.skeleton import BODY_NAMES, HINGE_NAMES
    body, n = BODY_NAMES.index("L_Shoulder"), 40
    cols = slice(HINGE_NAMES.index("L_Shoulder_x"), HINGE_NAMES.index("L_Shoulder_z") + 1)
    jitter = np.radians(0.5) * (-1.0) ** np.arange(n)
    euler = np.zeros((2 * n, 24, 3))
    euler[:n, body] = np.stack([-np.pi / 2 + jitter, np.zeros(n), -np.pi / 2 + jitter], -1)
    euler[n:, body] = euler[:n, body][::-1]  # a second clip: the same, played backwards
    local = quat_from_euler_xyz(euler)
    per_frame = hinge_angles(local)[:, cols]
    assert np.abs(np.diff(per_frame[:n], axis=0)).max() > np.radians(170)  # the rule alone flips
    seg = Segments.from_lengths([n, n])
    kept = hinge_angles(local, seg)[:, cols]
    for clip in (kept[:n], kept[n:]):
        assert np.abs(np.diff(clip, axis=0)).max() < np.radians(2)
        np.testing.assert_allclose(np.abs(clip[:, [0, 2]]), np.pi / 2, atol=np.radians(1))
    # both decompositions compose to the same rotations
    from smpl_envs.rotations import quat_to_matrix
    rebuilt = quat_from_euler_xyz(kept.reshape(2 * n, 1, 3))[:, 0]
    np.testing.assert_allclose(quat_to_matrix(rebuilt), quat_to_matrix(local[:, body]), atol=1e-9)

# ---------------------------------------------------------------- bad input
def _amass(path, **override):
    data = dict(poses=np.zeros((10, 156)), trans=np.zeros((10, 3)), mocap_framerate=120.0,
                betas=np.zeros(16), gender="neutral")
    data.update(override)
    np.savez(path, **{k: v for k, v in data.items() if v is not None})
    return path


def _own(path, **override):
    identity = np.zeros((5, 24, 4))
    identity[..., 0] = 1
    data = dict(format=FORMAT_NAME, version=FORMAT_VERSION, fps=30.0, root_pos=np.zeros((5, 3)),
                local_quat=identity)
    data.update(override)
    np.savez(path, **data)
    return path


@pytest.mark.parametrize("make, reason", [
    (lambda p: p.write_bytes(b"definitely not a zip") and p, "not a .npz"),
    (lambda p: _amass(p, trans=None), "without 'trans'"),
    (lambda p: _amass(p, poses=np.zeros((10, 50))), r"shape \(10, 50\), expected \(T, 72\) for SMPL"),
    (lambda p: _amass(p, poses=np.zeros((10, 52, 3))), r"shape \(10, 52, 3\), expected \(T, 72\) for SMPL"),
    (lambda p: _amass(p, poses=np.zeros(72), trans=np.zeros(3)), r"shape \(72,\), expected \(T, 72\)"),
    (lambda p: _amass(p, trans=np.zeros((10, 3, 1))), r"'trans' has shape \(10, 3, 1\), expected \(T, 3\)"),
    (lambda p: _amass(p, betas="tall"), "'betas' must be body shape coefficients"),
    (lambda p: _amass(p, poses=None, trans=np.zeros((0, 3)), root_orient=np.zeros((0, 3)),
                      pose_body=np.zeros((0, 63))), r"'root_orient' has no frames.*\(T, 3\)"),
    (lambda p: _own(p, root_pos=np.zeros((0, 3)), local_quat=np.zeros((0, 24, 4))),
     r"'root_pos' has no frames.*\(T, 3\)"),
    (lambda p: _own(p, local_quat=np.zeros((5, 96))), r"shape \(5, 96\), expected \(T, 24, 4\)"),
    (lambda p: _amass(p, poses=np.full((10, 156), np.nan)), "NaN"),
    (lambda p: _amass(p, poses=np.zeros((0, 156)), trans=np.zeros((0, 3))), "no frames"),
    (lambda p: _amass(p, mocap_framerate=-5.0), "frame rate must be positive"),
    (lambda p: _amass(p, mocap_framerate=None), "no frame rate"),
    (lambda p: _amass(p, trans=np.zeros((7, 3))), "10 pose frames but 7"),
    (lambda p: np.savez(p, something=np.zeros(3)) or p, "unrecognised .npz layout"),
])
def test_malformed_files_name_the_file_and_the_problem(tmp_path, make, reason):
    path = make(tmp_path / "broken.npz")
    with pytest.raises(MotionFileError, match=reason) as err:
        load_motion(path)
    assert str(path) in str(err.value)


def _phc(path, dump=joblib.dump, **override):
    seq = dict(pose_aa=np.zeros((5, 72)), trans=np.zeros((5, 3)), fps=30)
    seq.update(override)
    dump({"seq": seq}, path)
    return path


def _pickle_dump(obj, path):
    with open(path, "wb") as f:
        pickle.dump(obj, f)


@pytest.mark.parametrize("make, reason", [
    (lambda p: _phc(p, pose_aa=np.zeros((0, 72)), trans=np.zeros((0, 3))),
     r"'seq.pose_aa' has no frames.*expected \(T, 72\) or \(T, 24, 3\)"),
    (lambda p: _phc(p, _pickle_dump, pose_aa=np.zeros((0, 72)), trans=np.zeros((0, 3))),
     r"'seq.pose_aa' has no frames"),
    (lambda p: _phc(p, pose_aa=np.zeros((5, 2, 24, 3))),
     r"'seq.pose_aa' has shape \(5, 2, 24, 3\), expected \(T, 72\) or \(T, 24, 3\)"),
    (lambda p: _phc(p, pose_aa=np.zeros(72)), r"'seq.pose_aa' has shape \(72,\)"),
    (lambda p: _phc(p, pose_aa=0.0), r"'seq.pose_aa' has shape \(\)"),
    (lambda p: _phc(p, pose_aa=[[0.0] * 72, [0.0] * 3]), "'seq.pose_aa' is not a rectangular array"),
    (lambda p: _phc(p, trans=np.zeros((0, 3))), r"'seq.trans' has no frames.*\(T, 3\)"),
    (lambda p: _phc(p, root_trans_offset=np.zeros((5, 1, 3))), r"'seq.root_trans_offset' has shape"),
    (lambda p: _phc(p, beta="tall"), "'seq.beta' must be body shape coefficients"),
])
def test_malformed_phc_sequences_name_the_file_and_the_shape(tmp_path, make, reason):
    path = make(tmp_path / "broken.pkl")
    with pytest.raises(MotionFileError, match=reason) as err:
        load_motion(path)
    assert str(path) in str(err.value)
    with pytest.warns(UserWarning, match="1 motion file"):  # in a tree: reported, not fatal
        lib = MotionLib.load([path, "walk"], progress=False)
    assert lib.names == ["walk"] and lib.errors[0][0] == str(path)


def test_phc_pose_as_joints_reads_like_flat(tmp_path):
    pose = 0.2 * np.sin(np.arange(5 * 72)).reshape(5, 72)
    flat = load_motion(_phc(tmp_path / "flat.pkl", pose_aa=pose))
    joints = load_motion(_phc(tmp_path / "joints.pkl", pose_aa=pose.reshape(5, 24, 3)))
    np.testing.assert_allclose(joints.body_pos, flat.body_pos, atol=1e-12)


def test_malformed_pickles_and_suffixes(tmp_path):
    (tmp_path / "x.pkl").write_bytes(b"\x80\x04garbage")
    with pytest.raises(MotionFileError, match="x.pkl: not a readable pickle"):
        load_motion(tmp_path / "x.pkl")
    joblib.dump({"seq": {"pose_aa": np.zeros((5, 72))}}, tmp_path / "y.pkl")
    with pytest.raises(MotionFileError, match="neither 'root_trans_offset' nor 'trans'"):
        load_motion(tmp_path / "y.pkl")
    (tmp_path / "z.bvh").write_text("HIERARCHY")
    with pytest.raises(MotionFileError, match="unknown motion file type"):
        read_motion_file(tmp_path / "z.bvh")
    with pytest.raises(FileNotFoundError, match="shipped clips"):
        load_motion("no_such_clip")


# ---------------------------------------------------------------- the library
def test_a_bare_name_is_always_the_shipped_clip(tmp_path, monkeypatch):
    """Local folders named like shipped clips (a run directory called `run`) change nothing."""
    for folder in ("walk", "run"):
        (tmp_path / folder).mkdir()
        to_amass(sway_motion(60, name="x"), tmp_path / folder / "x.npz")
    (tmp_path / "jump").write_bytes(b"not a clip")  # a plain file of that name, too
    monkeypatch.chdir(tmp_path)
    shipped = {name: Motion.from_raw(read_motion_file(CLIPS_DIR / f"{name}.npz")[0])
               for name in ("walk", "run", "jump")}
    lib = MotionLib.load(["walk", "run", "jump"], progress=False)
    assert lib.names == ["walk", "run", "jump"]
    for i, name in enumerate(lib.names):
        np.testing.assert_allclose(lib.motion(i).body_pos, shipped[name].body_pos, atol=1e-5)
    assert MotionLib.load("walk", progress=False).names == ["walk"]
    np.testing.assert_allclose(load_motion("walk").body_pos, shipped["walk"].body_pos, atol=1e-9)
    # written as a path, the local folder is what is loaded
    for local in ("./walk", str(tmp_path / "walk"), tmp_path / "walk", Path("walk")):
        assert MotionLib.load(local, progress=False).names == ["x"], local
    assert load_motion("walk/x.npz").name == "x"


def test_paths_expand_home_and_unknown_names_say_what_exists(tmp_path, monkeypatch):
    monkeypatch.setenv("HOME", str(tmp_path))
    (tmp_path / "amass").mkdir()
    to_amass(sway_motion(60, name="x"), tmp_path / "amass" / "x.npz")
    assert MotionLib.load("~/amass", progress=False).names == ["x"]
    monkeypatch.chdir(tmp_path)
    with pytest.raises(FileNotFoundError, match=r"'amass' is not a shipped clip.*shipped clips.*\./amass"):
        MotionLib.load("amass")
    with pytest.raises(FileNotFoundError, match="'nowhere/x.npz': no such file"):
        MotionLib.load("nowhere/x.npz")
    with pytest.raises(FileNotFoundError, match="'walk.npz': no such file"):
        load_motion("walk.npz")  # an extension makes it a path, even next to no such file


def _tree(root, n=6):
    (root / "subject1").mkdir(parents=True)
    for i in range(n):
        to_amass(sway_motion(60, seconds=1.0 + 0.2 * i, name=f"c{i}"), root / "subject1" / f"c{i}_poses.npz")
    np.savez(root / "subject1" / "shape.npz", betas=np.zeros(16), gender="female")
    (root / "subject1" / "broken_poses.npz").write_bytes(b"oops")
    _amass(root / "nan_poses.npz", poses=np.full((10, 156), np.nan))
    return root


def test_tree_loads_good_files_reports_bad_ones_by_name(tmp_path):
    root = _tree(tmp_path / "amass")
    with pytest.warns(UserWarning, match="2 motion file"):
        lib = MotionLib.load(root, progress=False)
    assert lib.num_motions == 6  # shape.npz skipped silently, the two bad ones reported
    assert sorted(p.split("/")[-1] for p, _ in lib.errors) == ["broken_poses.npz", "nan_poses.npz"]
    assert any("NaN" in why for _, why in lib.errors)


def test_second_load_comes_from_the_cache_and_changes_invalidate_it(tmp_path, monkeypatch):
    root = _tree(tmp_path / "amass")
    with pytest.warns(UserWarning):
        first = MotionLib.load(root, progress=False)

    def no_parsing(*a, **k):
        raise AssertionError("parsed a file although the tree was cached")

    monkeypatch.setattr("smpl_envs.motion.library.read_motion_file", no_parsing)
    with pytest.warns(UserWarning):  # the cached errors are reported again
        second = MotionLib.load(root, progress=False)
    assert second.names == first.names and len(second.errors) == 2
    np.testing.assert_array_equal(second.body_pos, first.body_pos)
    monkeypatch.undo()
    to_amass(sway_motion(60, seconds=2.0, name="new"), root / "new_poses.npz")
    with pytest.warns(UserWarning):
        third = MotionLib.load(root, progress=False)
    assert third.num_motions == 7


def test_saved_library_loads_back(tmp_path):
    lib = MotionLib.load(["walk", "run", "kick"])
    lib.save(tmp_path / "mylib")
    back = MotionLib.load(tmp_path / "mylib")
    assert back.names == lib.names
    np.testing.assert_array_equal(np.asarray(back.dof_pos), lib.dof_pos)


def test_interpolation_between_frames():
    lib = MotionLib.load("run")
    ids = np.zeros(3, dtype=int)
    a, b, mid = lib.get_state(ids, np.array([10, 11, 10.5]) / 30).body_pos
    np.testing.assert_allclose(mid, (a + b) / 2, atol=1e-6)
    q = lib.get_state(ids, np.array([0.123, 1.5, 99.0])).body_quat
    np.testing.assert_allclose(np.linalg.norm(q, axis=-1), 1, atol=1e-6)
    end = lib.get_state(ids[:1], np.array([99.0])).qpos  # past the end: the last frame
    np.testing.assert_allclose(end[0], lib.motion(0).qpos[-1], atol=1e-5)


def test_sampling_weights():
    lib = MotionLib.load(["walk", "run", "jump"])
    rng = np.random.default_rng(0)
    lib.set_weights([0, 1, 0])
    assert set(lib.sample_motions(100, rng)) == {1}
    lib.set_weights([1, 3, 0])
    counts = np.bincount(lib.sample_motions(4000, rng), minlength=3)
    assert counts[2] == 0 and 2.5 < counts[1] / counts[0] < 3.5
    with pytest.raises(ValueError):
        lib.set_weights([0, 0, 0])
    times = lib.sample_times(np.array([0, 1, 2] * 50), rng, truncate=0.5)
    assert np.all(times <= np.tile(lib.durations - 0.5, 50) + 1e-9)


def test_random_yaw_turns_whole_clips_reproducibly():
    plain = MotionLib.load(["walk", "turn"])
    turned = MotionLib.load(["walk", "turn"], random_yaw=True, seed=3)
    again = MotionLib.load(["walk", "turn"], random_yaw=True, seed=3)
    np.testing.assert_array_equal(turned.body_pos, again.body_pos)
    assert np.all(turned.yaw != 0)
    q = yaw_quat(turned.yaw[turned.seg.clip_of_frame])[:, None]
    np.testing.assert_allclose(turned.body_pos, quat_apply(q, plain.body_pos), atol=1e-5)
    np.testing.assert_allclose(turned.dof_pos, plain.dof_pos)  # the pose itself is unchanged
    np.testing.assert_allclose(turned.body_lin_vel, quat_apply(q, plain.body_lin_vel), atol=1e-4)


def test_deep_bends_decompose_into_the_bending_hinge(model):
    """A knee bent 130 degrees is 130 degrees about its y hinge, not a 180-degree flip of x and z."""
    from smpl_envs.humanoid import HINGE_NAMES
    from smpl_envs.motion import RawMotion
    from smpl_envs.rotations import quat_from_euler_xyz

    t = np.linspace(0, 1, 31)
    angles = np.zeros((31, 24, 3))
    angles[:, 2, 1] = np.deg2rad(10 + 130 * t)   # L_Knee flexes past 90 degrees
    angles[:, 1, 1] = -np.deg2rad(120 * t)       # L_Hip flexes past 90 degrees the other way
    quat = quat_from_euler_xyz(angles)
    raw = RawMotion("bend", 30.0, np.tile([0, 0, 1.0], (31, 1)), quat)
    m = Motion.from_raw(raw)
    knee_y, hip_y = HINGE_NAMES.index("L_Knee_y"), HINGE_NAMES.index("L_Hip_y")
    np.testing.assert_allclose(m.dof_pos[:, knee_y], angles[:, 2, 1], atol=1e-9)
    np.testing.assert_allclose(m.dof_pos[:, hip_y], angles[:, 1, 1], atol=1e-9)
    assert np.abs(m.dof_pos[:, [knee_y - 1, knee_y + 1]]).max() < 1e-9
    assert max_kinematic_error(model, m) < 1e-3


def test_motion_retargets_exactly_to_a_user_body(tmp_path):
    """With the user's SMPL file and betas, the reference is computed for that body's bones."""
    from synthetic_smpl import write_synthetic_smpl
    from smpl_envs.humanoid.smpl_model import skeleton_from_smpl

    write_synthetic_smpl(tmp_path / "SMPL_NEUTRAL.npz")
    betas = np.array([1.5, 0.0, 0.5])
    body = build_humanoid(betas=betas, smpl_model_path=tmp_path / "SMPL_NEUTRAL.npz")
    motion = load_motion("kick", skeleton=skeleton_from_smpl(tmp_path, betas=betas))
    assert max_kinematic_error(body, motion) < 1e-3
    mean = load_motion("kick")
    assert np.abs(motion.body_pos - mean.body_pos).max() > 0.02  # a taller body, other positions
    assert lowest_point(motion.body_pos, motion.body_quat,
                        skeleton_from_smpl(tmp_path, betas=betas)).min() == pytest.approx(0, abs=1e-9)
