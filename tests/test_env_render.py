"""Rendering through the Gymnasium API: env.render(), RecordVideo, and smpl_envs.render.record."""

import warnings

import gymnasium as gym
import imageio.v3 as iio
import numpy as np
import pytest

from smpl_envs.render import record  # importing smpl_envs registers the ids

ENV_ID = "SMPL/Imitation-v0"
SMALL = dict(render_size=(160, 120), motions="walk")


def make(**kwargs):
    return gym.make(ENV_ID, render_mode="rgb_array", **{**SMALL, **kwargs})


def skin_pixels(frame):
    # The skin is rgba (0.84, 0.62, 0.48); lighting scales it, but it stays r > g > b with a wide
    # red-blue gap, unlike the grey floor and the blue-grey sky.
    r, g, b = (frame[..., i].astype(int) for i in range(3))
    return (r > g) & (g > b) & (r - b > 40)


def red_pixels(frame):
    r, g, b = (frame[..., i].astype(int) for i in range(3))
    return (r > 150) & (g < 80) & (b < 80)


def test_reset_frame_shows_the_humanoid():
    env = make()
    try:
        env.reset(seed=0)
        frame = env.render()
        assert frame.shape == (120, 160, 3) and frame.dtype == np.uint8
        assert frame.std() > 10  # not blank
        skin = skin_pixels(frame)
        assert skin.sum() > 200, skin.sum()
        assert 0.25 < np.nonzero(skin)[1].mean() / 160 < 0.75  # the camera follows the pelvis
        # The camera tracks the pelvis, so moving the humanoid does not take it out of view: hide
        # its geoms instead, and the skin-coloured pixels must go with it (none in the scene).
        model = env.unwrapped.model
        humanoid = model.geom_bodyid > 0
        model.geom_rgba[humanoid, 3] = 0.0
        model.geom_matid[humanoid] = -1
        assert skin_pixels(env.render()).sum() < 10
    finally:
        env.close()


def test_reference_markers_follow_show_markers():
    envs = [make(render_size=(320, 240), show_markers=s, start="beginning") for s in (True, False)]
    try:
        frames = []
        for env in envs:
            env.reset(seed=0)
            # Right after reset the humanoid sits exactly on the reference, hiding the markers
            # inside its limbs; a couple of unactuated steps let it drift off them.
            for _ in range(2):
                env.step(np.zeros(env.action_space.shape, np.float32))
            frames.append(env.render())
    finally:
        for env in envs:
            env.close()
    with_ref, without = frames
    assert not np.array_equal(with_ref, without)
    assert red_pixels(with_ref).sum() > 40 and red_pixels(without).sum() < 5


def test_record_video_wrapper_writes_an_episode(tmp_path):
    # RecordVideo saves through moviepy (a test dependency, gymnasium[other])
    # gym.make's own max_episode_steps= adds a TimeLimit: the episode ends after at most 10 steps.
    folder = tmp_path / "videos"  # a fresh folder: RecordVideo warns when it reuses one
    env = gym.wrappers.RecordVideo(make(max_episode_steps=10), str(folder), episode_trigger=lambda e: True,
                                   disable_logger=True)
    try:
        assert env.frames_per_sec == 30
        env.reset(seed=0)
        n, done = 0, False
        while not done:
            _, _, terminated, truncated, _ = env.step(env.unwrapped.reference_action())
            n, done = n + 1, terminated or truncated
    finally:
        env.close()  # RecordVideo saves the open recording on close
    assert 1 <= n <= 10
    videos = list(folder.glob("*.mp4"))
    assert [v.name for v in videos] == ["rl-video-episode-0.mp4"]
    frames = iio.imread(videos[0])
    assert frames.shape == (n + 1, 120, 160, 3)  # one frame after reset, one per step


def test_record_reference_rollout(tmp_path):
    env = make(start="beginning")  # walk is 181 frames: 12 reference steps stay in one episode
    try:
        out = record(env, "reference", tmp_path / "ref.mp4", steps=12, seed=3, progress=False)
        assert out == {"path": str(tmp_path / "ref.mp4"), "frames": 13, "steps": 12, "episodes": 1,
                       "reward": out["returns"][0], "returns": out["returns"]}
        assert iio.imread(tmp_path / "ref.mp4").shape == (13, 120, 160, 3)
        # The same seeded rollout without rendering earns the same reward: record's bookkeeping
        # (and rendering) does not disturb the episode.
        env.reset(seed=3)
        total = sum(env.step(env.unwrapped.reference_action())[1] for _ in range(12))
        assert out["reward"] == pytest.approx(total) and out["reward"] > 0
    finally:
        env.close()


def test_record_episodes_from_an_env_id(tmp_path):
    # Two 3-step episodes of collapsing: each episode adds its reset frame to its steps. Seeded,
    # from the clip's start: an unseeded start near the clip's end ends an episode early.
    out = record(ENV_ID, "zero", tmp_path / "zero.mp4", episodes=2, seed=0, progress=False,
                 max_episode_steps=3, start="beginning", **SMALL)
    assert (out["frames"], out["steps"], out["episodes"], len(out["returns"])) == (8, 6, 2, 2)
    assert len(iio.imread(tmp_path / "zero.mp4")) == 8


def test_record_rejects_what_it_cannot_render(tmp_path):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        env = gym.make(ENV_ID, motions="walk")  # no render_mode
    try:
        with pytest.raises(ValueError, match="render_mode"):
            record(env, "zero", tmp_path / "x.mp4", steps=1, progress=False)
        with pytest.raises(TypeError, match="gym.make"):
            record(env, "zero", tmp_path / "x.mp4", steps=1, progress=False, render_size=(8, 8))
    finally:
        env.close()
    vec = gym.make_vec(ENV_ID, num_envs=2, render_mode="rgb_array", **SMALL)
    try:
        with pytest.raises(ValueError, match="single env"):
            record(vec, "zero", tmp_path / "x.mp4", steps=1, progress=False)
    finally:
        vec.close()
    with pytest.raises(ValueError, match="policy"):
        record(ENV_ID, "random", tmp_path / "x.mp4", steps=1, progress=False, **SMALL)
    assert not (tmp_path / "x.mp4").exists()


def test_vec_env_renders_a_frame_per_world_and_the_chosen_world_by_name():
    vec = gym.make_vec(ENV_ID, num_envs=2, render_mode="rgb_array", render_world=1, **SMALL)
    try:
        vec.reset(seed=0)
        frames = vec.render()  # Gymnasium's vector contract: one frame per world
        assert isinstance(frames, tuple) and len(frames) == 2
        for frame in frames:
            assert frame.shape == (120, 160, 3) and frame.dtype == np.uint8 and frame.std() > 10
            assert skin_pixels(frame).sum() > 200
        assert not np.array_equal(frames[0], frames[1])  # two worlds, two random starts
        np.testing.assert_array_equal(vec.render_frame(), frames[1])  # render_world
        np.testing.assert_array_equal(vec.render_frame(0), frames[0])
        with pytest.raises(ValueError, match="world must be in"):
            vec.render_frame(2)
    finally:
        vec.close()


def test_gymnasium_vector_record_video_on_the_native_vector_env(tmp_path):
    from gymnasium.wrappers.vector import RecordVideo

    folder = tmp_path / "videos"
    envs = RecordVideo(gym.make_vec(ENV_ID, num_envs=2, render_mode="rgb_array", max_episode_steps=5, **SMALL),
                       str(folder), episode_trigger=lambda e: True, disable_logger=True)
    try:
        envs.reset(seed=0)
        for _ in range(5):
            envs.step(np.zeros((2, 69), np.float32))
    finally:
        envs.close()
    videos = sorted(folder.glob("*.mp4"))
    assert videos, "RecordVideo wrote nothing"
    frames = iio.imread(videos[0])
    assert frames.shape[1:] == (120, 320, 3) and len(frames) >= 5  # both worlds side by side, every step


def test_make_does_not_warn_about_render_mode():
    # gym.make checks render_mode against the class's metadata, before __init__ runs.
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        make().close()
