"""`SMPL/Terrain-v0` and its terrain generator: Gymnasium contracts, a seeded terrain at the requested
shares, the height map on a hand-made step, grounded start poses, terrain-relative falls, the
off-path rule, bad input; on the MuJoCo Warp backend: parity with the CPU one, torch outputs,
seeding."""


import importlib.util

import gymnasium as gym
import mujoco
import numpy as np
import pytest

import smpl_envs
from smpl_envs.envs.terrain import MAP_OFFSETS, height_map, make_paths, path_at, path_reward
from smpl_envs.humanoid import BODY_NAMES
from smpl_envs.terrain import DEFAULT_SHARES, SPACING, TERRAIN_TYPES, Terrain, make_terrain, stair_height
from conftest import WARP_DEVICE, check_env_quietly, seeded_rollouts, warp_same

ENV_ID = "SMPL/Terrain-v0"
OBS_DIM = 358 + 20 + 1024
SMALL = dict(terrain_size=(2, 2))  # 4 tiles: quick to build, every test that needs no more


def test_registered_with_both_entry_points_and_a_time_limit():
    spec = gym.spec(ENV_ID)
    assert spec.vector_entry_point == smpl_envs.ENV_IDS[ENV_ID][0] and spec.max_episode_steps == 300


@pytest.mark.parametrize("kwargs", [SMALL, dict(terrain="flat")], ids=["tiles", "flat"])
def test_env_checker_passes(kwargs):
    env = gym.make(ENV_ID, motions="walk", render_mode="rgb_array", render_size=(96, 72), **kwargs)
    check_env_quietly(env)
    assert env.observation_space.shape == (OBS_DIM,) and env.action_space.shape == (69,)
    env.reset(seed=0)
    frame = env.render()
    assert frame.shape == (72, 96, 3) and frame.std() > 5  # terrain, humanoid and path drawn
    env.close()


def test_make_vec_is_native_batched_and_seeded():
    env = gym.make_vec(ENV_ID, num_envs=8, motions=["walk", "run"], **SMALL)
    assert env.sim.num_worlds == 8 and env.model.nhfield == 1
    (a, info), (b, _), (c, _) = seeded_rollouts(env)
    assert a[0].shape == (8, OBS_DIM) and a[0].dtype == np.float32
    assert all(np.array_equal(x, y) for x, y in zip(a, b))
    assert not np.array_equal(a[0], c[0])
    assert {"reward_path", "path_error", "path_point", "path_length", "start_tile"} <= set(info)
    env.close()


# ---------------------------------------------------------------------------------------- terrain
def test_terrain_is_reproducible_from_its_seed_and_differs_across_seeds():
    a, b = make_terrain(seed=7), make_terrain(seed=7)
    c = make_terrain(seed=8)
    assert np.array_equal(a.heights, b.heights) and np.array_equal(a.types, b.types)
    assert not np.array_equal(a.heights, c.heights)
    assert a.heights.shape == (4 * 200 + 2 * 100 + 1,) * 2  # 0.1 m samples over 4 x 20 m + 2 x 10 m
    # Heights on the 0.005 m vertical grid; the border is flat at 0.
    assert np.allclose(a.heights / 0.005, np.round(a.heights / 0.005), atol=1e-6)
    assert np.all(a.heights[:100] == 0) and np.all(a.heights[:, -100:] == 0)


def test_every_type_appears_at_its_share():
    t = make_terrain("mixed", size=(10, 20), tile_size=6.0, border=0.0, seed=1)
    counts = np.bincount(t.types.ravel(), minlength=len(TERRAIN_TYPES))
    for i, name in enumerate(TERRAIN_TYPES):
        assert abs(counts[i] - DEFAULT_SHARES[name] * 200) <= 1, (name, counts[i])
    shares = {"stairs_up": 0.5, "poles": 0.3, "flat": 0.2}
    t = make_terrain(shares, size=(5, 4), tile_size=6.0, border=0.0, seed=2)
    counts = {n: int((t.types == TERRAIN_TYPES.index(n)).sum()) for n in TERRAIN_TYPES}
    assert counts == {**dict.fromkeys(TERRAIN_TYPES, 0), "stairs_up": 10, "poles": 6, "flat": 4}
    # Difficulty "levels": row r of tiles at r / rows; a range: per tile, inside it.
    assert np.allclose(t.difficulty, (np.arange(5) / 5)[:, None])
    t = make_terrain(size=(3, 3), tile_size=6.0, difficulty=(0.2, 0.4), seed=3)
    assert (t.difficulty >= 0.2).all() and (t.difficulty <= 0.4).all() and t.difficulty.std() > 0


def test_tile_shapes_follow_the_reference_numbers():
    n = 200
    # Stairs up at difficulty 1: 0.225 m steps, 0.31 m deep, rising to the centre platform.
    t = make_terrain("stairs_up", difficulty=1.0, size=(1, 1), border=0.0)
    row = t.heights[n // 2, :n // 2]  # from the west edge to the centre
    steps = np.diff(row)[np.diff(row) != 0]
    assert np.allclose(steps, stair_height(1.0)) and len(steps) == int((10 - 1.5) / 0.31)
    assert np.allclose(np.diff(np.flatnonzero(np.diff(row))), 0.31 / SPACING, atol=1)
    assert t.height(np.zeros(2)) == pytest.approx(len(steps) * 0.225, abs=1e-6)
    t = make_terrain("stairs_down", difficulty=0.0, size=(1, 1), border=0.0)
    assert t.height(np.zeros(2)) == pytest.approx(-0.05 * int((10 - 1.5) / 0.31), abs=1e-6)
    # Poles: 1.0-2.5 m tall, none within 2 m of the centre; obstacles no higher than 0.175 m.
    t = make_terrain("poles", difficulty=1.0, size=(1, 1), border=0.0, seed=4)
    raised = t.heights[t.heights > 0]
    assert len(raised) > 0 and raised.min() >= 1.0 and raised.max() <= 2.5
    assert np.all(t.heights[n // 2 - 20:n // 2 + 21, n // 2 - 20:n // 2 + 21] == 0)
    t = make_terrain("obstacles", difficulty=1.0, size=(1, 1), border=0.0, seed=5)
    assert np.abs(t.heights).max() == pytest.approx(0.175) and len(np.unique(t.heights)) == 5


def test_height_map_reads_a_hand_made_step():
    # 0 m for x < 0, 0.3 m from x = 0 on (samples every 0.1 m from -5 m).
    x = -5.0 + SPACING * np.arange(101)
    heights = np.where(x >= -1e-9, 0.3, 0.0)[None].repeat(101, 0)
    step = Terrain(heights, -5.0, -5.0, 10.0, 0.0, np.zeros((1, 1), int), np.zeros((1, 1)))
    root = np.array([[-0.5, 0.0, 1.0]])
    forward = np.eye(3)[None]
    world_x = -0.5 + MAP_OFFSETS[:, 0]
    m = height_map(step, root, forward)[0]
    assert np.allclose(m[world_x >= 0], (1.0 - 0.3) * 5) and np.allclose(m[world_x <= -0.1], 5.0)
    ramp = (world_x > -0.1) & (world_x < 0)
    assert np.allclose(m[ramp], (1.0 - 0.3 * (world_x[ramp] + 0.1) / 0.1) * 5)
    # Facing +y the step lies to the right: it shows along the map's leftward axis.
    left = np.array([[[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]])
    m = height_map(step, root, left)[0]
    world_x = -0.5 - MAP_OFFSETS[:, 1]
    assert np.allclose(m[world_x >= 0], 3.5) and np.allclose(m[world_x <= -0.1], 5.0)
    # Clipped at +-3 m before scaling.
    assert np.allclose(height_map(step, np.array([[-3.0, 0.0, 9.0]]), forward)[0], 15.0)


def test_flat_gives_the_plain_floor():
    env = gym.make_vec(ENV_ID, num_envs=2, terrain="flat")
    assert env.model.nhfield == 0 and env.unwrapped.terrain is None
    floor = mujoco.mj_name2id(env.model, mujoco.mjtObj.mjOBJ_GEOM, "floor")
    assert env.model.geom_pos[floor, 2] == 0.0
    obs, _ = env.reset(seed=0)
    assert obs.shape == (2, OBS_DIM)
    root_z = env.sim.bodies.pos[:, 0, 2]
    assert np.allclose(obs[:, 378:], (np.clip(root_z, -3, 3) * 5)[:, None], atol=1e-5)
    env.close()


def test_floor_is_lowered_under_the_heightfield():
    env = gym.make_vec(ENV_ID, num_envs=1, **SMALL)
    floor = mujoco.mj_name2id(env.model, mujoco.mjtObj.mjOBJ_GEOM, "floor")
    assert env.model.geom_pos[floor, 2] < env.unwrapped.terrain.heights.min() - 0.5
    env.close()


# ---------------------------------------------------------------------------------------- starts
def _terrain_contacts(env, world):
    d = env.sim.datas[world]
    hfield = mujoco.mj_name2id(env.model, mujoco.mjtObj.mjOBJ_GEOM, "terrain")
    return [c.dist for c in d.contact[:d.ncon] if hfield in c.geom]


def test_start_poses_never_interpenetrate_the_terrain():
    env = gym.make_vec(ENV_ID, num_envs=32, motions=["walk", "run", "jump", "kick", "crouch", "turn"],
                       terrain_difficulty=1.0)
    u = env.unwrapped
    for seed in range(3):
        env.reset(seed=seed)
        assert all(d > -1e-4 for w in range(32) for d in _terrain_contacts(env, w))
        # ... and stand on it: the feet' lowest sample point a few millimetres above the surface.
        body = env.sim.bodies
        feet = [BODY_NAMES.index(n) for n in ("L_Ankle", "R_Ankle", "L_Toe", "R_Toe")]
        clearance = body.pos[:, feet, 2] - u.ground(body.pos[:, feet, :2])
        assert (clearance.min(-1) < 0.2).all()  # no world dropped from high above
        # Spawns lie on their tiles' flat platforms.
        tile = u.start_tile
        assert (np.abs(body.pos[:, 0, :2] - u.terrain.centres[tile]) <= 1.0 + 1e-9).all()
    env.close()


def test_a_humanoid_on_a_stair_tile_stands_on_the_stairs():
    kwargs = dict(terrain="stairs_up", terrain_difficulty=1.0, terrain_size=(1, 1))
    env = gym.make_vec(ENV_ID, num_envs=2, autoreset_mode="Disabled", **kwargs)
    flat = gym.make_vec(ENV_ID, num_envs=2, autoreset_mode="Disabled", terrain="flat")
    platform = 27 * 0.225
    env.reset(seed=0)
    flat.reset(seed=0)
    for _ in range(15):
        _, _, term, _, _ = env.step(np.zeros((2, 69)))
        flat.step(np.zeros((2, 69)))
        assert not term.any()
    feet = [BODY_NAMES.index(n) for n in ("L_Ankle", "R_Ankle")]
    ground = env.unwrapped.ground(env.sim.bodies.pos[:, feet, :2])
    assert np.allclose(ground, platform, atol=1e-6)
    # The same pose as on the flat floor, raised by the stairs' height: feet on the surface.
    np.testing.assert_allclose(env.sim.bodies.pos[:, feet, 2] - platform, flat.sim.bodies.pos[:, feet, 2], atol=0.02)
    assert all(len(_terrain_contacts(env, w)) > 0 for w in range(2))
    env.close()
    flat.close()


# ---------------------------------------------------------------------------------------- path
def test_paths_follow_the_reference_rules():
    rng = np.random.default_rng(0)
    start = rng.uniform(-5, 5, (256, 2))
    path, length = make_paths(start, rng)
    assert path.shape == (256, 101, 2) and np.allclose(path[:, 0], start)
    speed = np.linalg.norm(np.diff(path, axis=1), axis=-1) / 0.1
    assert speed.min() >= -1e-9 and speed.max() <= 3.0 + 1e-9
    assert np.abs(np.diff(speed, axis=1)).max() <= 0.2 + 1e-9
    assert np.allclose(length[:, -1], (speed * 0.1).sum(1))
    assert np.allclose(path_at(path, np.full((256, 1), 0.05))[:, 0], 0.5 * (path[:, 0] + path[:, 1]))
    assert np.allclose(path_at(path, np.full((256, 1), 99.0))[:, 0], path[:, -1])
    bounded, _ = make_paths(start, rng, bounds=(-6, 6, -6, 6))
    assert np.abs(bounded).max() <= 5.0 + 1e-9


def test_path_reward_known_answers():
    reward, error = path_reward(np.array([[0.0, 0.0], [3.0, 4.0]]), np.array([[0.0, 0.0], [0.0, 0.0]]))
    assert np.allclose(reward, [1.0, np.exp(-50.0)]) and np.allclose(error, [0.0, 5.0])


def test_observed_path_points_lie_ahead_in_the_heading_frame():
    env = gym.make_vec(ENV_ID, num_envs=4, **SMALL)
    obs, info = env.reset(seed=1)
    u = env.unwrapped
    body = env.sim.bodies
    yaw = np.arctan2(body.rot[:, 0, 1, 0], body.rot[:, 0, 0, 0])
    ahead = path_at(u.path, np.arange(1, 11)[None] * 0.5 * np.ones((4, 1))) - body.pos[:, None, 0, :2]
    local = obs[:, 358:378].reshape(4, 10, 2)
    c, s = np.cos(yaw)[:, None], np.sin(yaw)[:, None]
    np.testing.assert_allclose(local[..., 0], c * ahead[..., 0] + s * ahead[..., 1], atol=1e-4)
    np.testing.assert_allclose(local[..., 1], c * ahead[..., 1] - s * ahead[..., 0], atol=1e-4)
    np.testing.assert_allclose(info["path_error"], 0.0, atol=1e-9)  # paths start under the pelvis
    env.close()


# ---------------------------------------------------------------------------------------- episodes
def test_a_fall_on_high_ground_and_leaving_the_path_end_the_episode():
    env = gym.make_vec(ENV_ID, num_envs=3, autoreset_mode="Disabled", terrain="stairs_up",
                       terrain_difficulty=1.0, terrain_size=(1, 1))
    u = env.unwrapped
    env.reset(seed=0)
    qpos = env.sim.qpos.copy()
    qpos[1, 2] = 27 * 0.225 + 0.12               # world 1 lies on its back, 6 m above z = 0
    qpos[1, 3:7] = [np.cos(np.pi / 4), 0.0, np.sin(np.pi / 4), 0.0]
    env.sim.set_state([0, 1, 2], qpos, np.zeros_like(env.sim.qvel))
    u.path[2] += 5.0                             # world 2's path jumps 5 m away
    u.path[0] += 3.0 / np.sqrt(2)                # world 0's only 3 m: still on it
    _, reward, term, trunc, info = env.step(np.zeros((3, 69)))
    assert term.tolist() == [False, True, True] and not trunc.any()
    assert info["path_error"][2] > 4.0 and 2.5 < info["path_error"][0] < 3.5
    env.close()


def test_episode_evaluation_runs_the_protocol():
    zero = lambda obs: np.zeros((len(obs), 69))  # noqa: E731
    result = smpl_envs.evaluate(zero, ENV_ID, episodes=2, num_envs=2, progress=False, env_kwargs=SMALL)
    assert len(result.rows) == 2
    for row in result.rows:
        assert {"path_error", "distance_m", "no_fall", "score"} <= set(row)
        assert row["path_error"] >= 0 and row["distance_m"] >= 0 and 0 <= row["score"] <= 1


# ---------------------------------------------------------------------------------------- bad input
@pytest.mark.parametrize("kwargs, match", [
    (dict(terrain="lava"), "terrain"),
    (dict(terrain=["stairs_up", "moat"]), "terrain"),
    (dict(terrain={"stairs_up": -0.5, "flat": 1.5}), "terrain"),
    (dict(terrain={"stairs_up": 0.5, "flat": 0.2}), "sum to 1"),
    (dict(terrain_difficulty=1.5), "terrain_difficulty"),
    (dict(terrain_difficulty=(0.5, 0.2)), "terrain_difficulty"),
    (dict(terrain_difficulty="hard"), "terrain_difficulty"),
    (dict(terrain_size=(0, 3)), "terrain_size"),
    (dict(terrain_size=(2.5, 3)), "terrain_size"),
    (dict(tile_size=3.0), "tile_size"),
    (dict(tile_size=float("nan")), "tile_size"),
    (dict(tile_size=float("inf")), "tile_size"),
    (dict(terrain_border=-1.0), "terrain_border"),
    (dict(terrain_border=float("nan")), "terrain_border"),
    (dict(terrain_border=float("inf")), "terrain_border"),
    (dict(terrain_seed=-1), "terrain_seed"),
    (dict(off_path_distance=0), "off_path_distance"),
])
def test_bad_kwargs_name_themselves(kwargs, match):
    with pytest.raises(ValueError, match=match):
        gym.make_vec(ENV_ID, num_envs=1, **kwargs)


def test_terrain_types_example_writes_its_picture(tmp_path):
    import subprocess
    import sys
    from pathlib import Path

    import imageio.v3 as iio

    script = Path(__file__).resolve().parents[1] / "examples" / "terrain_types.py"
    out = subprocess.run([sys.executable, str(script), "--size", "80", "60", "--out", str(tmp_path / "t.png")],
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    image = iio.imread(tmp_path / "t.png")
    assert image.shape == (120, 320, 3) and image.std() > 5  # 8 panels, 4 x 2


# ---------------------------------------------------------------------------------------- warp backend
# The task on MuJoCo Warp (Warp's CPU device here), against the CPU backend. A tiny terrain (2 x 2
# tiles of 6 m) keeps the build short; the kernels compile once per model and are then cached.
warp = pytest.mark.skipif(importlib.util.find_spec("mujoco_warp") is None,
                          reason="MuJoCo Warp is not installed (pip install 'smpl-envs[gpu]')")
TINY = dict(terrain_size=(2, 2), tile_size=6.0, terrain_border=2.0, terrain_seed=1, motions="walk")
WORLDS = 3


def _make(backend):
    extra = dict(device=WARP_DEVICE) if backend == "warp" else dict(num_threads=1)
    return gym.make_vec(ENV_ID, num_envs=WORLDS, backend=backend, autoreset_mode="Disabled", **TINY, **extra)


@pytest.fixture(scope="module")
def warp_env():
    env = _make("warp")
    yield env
    env.close()


def _copy_task_state(w, c, qpos, qvel):
    """The CPU env `c`'s worlds, at (qpos, qvel), into the warp env `w`: the backends draw
    different random numbers, so the warp worlds get the CPU worlds' starts, paths and clocks."""
    import torch

    ids = np.arange(WORLDS)
    c.sim.set_state(ids, qpos, qvel)
    w.sim.set_state(torch.as_tensor(ids), torch.as_tensor(qpos, dtype=torch.float32),
                    torch.as_tensor(qvel, dtype=torch.float32))
    for name in ("path", "path_length", "start_tile", "start_motion", "start_frame", "elapsed"):
        getattr(w, name)[:] = torch.as_tensor(getattr(c, name))
    w._refresh_points()
    c._refresh_points()


@warp
def test_warp_backend_agrees_with_the_cpu_backend(warp_env):
    import torch

    from smpl_envs.features import heading_rotation

    w, c = warp_env, _make("cpu")
    c.reset(seed=0)
    w.reset(seed=0)
    # Through step(): the CPU worlds' starts raised 0.5 m, so that 5 steps stay in the air (MuJoCo
    # Warp's heightfield collisions make other contact points than CPU MuJoCo's: on the terrain
    # the two physics part by ~1e-2 m within a step, whatever the task does). Observations
    # (height map included), rewards, terminations and info agree to float32 rounding.
    z = c.humanoid.qpos.start + 2
    qpos = c.sim.qpos.copy()
    qpos[:, z] += 0.5
    _copy_task_state(w, c, qpos, c.sim.qvel.copy())
    rng = np.random.default_rng(0)
    for k in range(5):
        a = rng.uniform(-0.2, 0.2, (WORLDS, 69)).astype(np.float32)
        ow, rw, tw, uw, iw = w.step(torch.as_tensor(a))
        oc, rc, tc, uc, ic = c.step(a)
        assert np.abs(ow.cpu().numpy() - oc).max() < 1e-3, k
        assert np.abs(rw.cpu().numpy() - rc).max() < 1e-4, k
        assert tw.tolist() == tc.tolist() and uw.tolist() == uc.tolist()
        for key in ("path_error", "path_point", "path_length"):
            assert np.abs(iw[key].cpu().numpy() - ic[key]).max() < 1e-4, key
        assert iw["start_tile"].tolist() == ic["start_tile"].tolist()
    # On the terrain, from one state: world 1 lies on its back on its platform, world 2's path
    # jumped 5 m away; the task's reads of that state agree, terminations included.
    qpos = c.sim.qpos.copy()
    qpos[1, z] = c.ground(qpos[1:2, z - 2:z])[0] + 0.12
    qpos[1, z + 1:z + 5] = [np.cos(np.pi / 4), 0.0, np.sin(np.pi / 4), 0.0]
    c.path[2] += 5.0
    _copy_task_state(w, c, qpos, np.zeros_like(c.sim.qvel))
    out = []
    for e in (w, c):
        body = e.sim.bodies
        heading = heading_rotation(body.rot[:, 0])
        reward, _, terminated, _ = e._evaluate(body, heading)
        out.append((e.backend.to_numpy(e._observe(body, heading)), e.backend.to_numpy(reward),
                    e.backend.to_numpy(terminated), e.backend.to_numpy(e._task_info(body))))
    (ow, rw, tw, iw), (oc, rc, tc, ic) = out
    assert tc.tolist() == [False, True, True] and tw.tolist() == tc.tolist()
    assert np.abs(ow - oc).max() < 1e-3 and np.abs(rw - rc).max() < 1e-4
    assert all(np.abs(iw[k] - ic[k]).max() < 1e-4 for k in ("path_error", "path_point", "path_length"))
    # Start placement: the lowest point of a pose and the terrain reads, as the CPU backend's.
    from smpl_envs.humanoid.kinematics import lowest_point
    from smpl_envs.humanoid.skeleton import MEAN_SKELETON

    lib = c.motion_lib
    frames = np.arange(0, len(lib.body_pos), 7)[:40]
    pos, quat = lib.body_pos[frames], lib.body_quat[frames]
    dev = w._support[0].device
    low = lowest_point(torch.as_tensor(pos, device=dev), torch.as_tensor(quat, device=dev), MEAN_SKELETON,
                       w._support).cpu().numpy()
    np.testing.assert_allclose(low, lowest_point(pos, quat, MEAN_SKELETON), atol=1e-5)
    xy = np.random.default_rng(1).uniform(-9, 9, (50, 2))
    for mode in ("bilinear", "min", "max", "dilated"):
        np.testing.assert_allclose(w.ground(torch.as_tensor(xy, dtype=torch.float32, device=dev), mode).cpu().numpy(),
                                   c.ground(xy, mode), atol=1e-5)
    c.close()


@warp
def test_warp_outputs_are_torch_tensors_and_starts_are_grounded(warp_env):
    import torch

    w = warp_env
    obs, info = w.reset(seed=1)
    assert isinstance(obs, torch.Tensor) and obs.dtype == torch.float32 and obs.shape == (WORLDS, OBS_DIM)
    assert all(isinstance(v, torch.Tensor) for v in info.values())
    assert {"path_error", "path_point", "path_length", "start_tile"} <= set(info)
    body = w.sim.bodies
    # Spawns on their tiles' platforms, paths from the pelvis, feet just above the terrain.
    centres = torch.as_tensor(w.terrain.centres, dtype=torch.float32)[info["start_tile"]]
    assert ((body.pos[:, 0, :2] - centres).abs() <= 1.0 + 1e-5).all()
    assert info["path_error"].abs().max() < 1e-5
    feet = [BODY_NAMES.index(n) for n in ("L_Ankle", "R_Ankle", "L_Toe", "R_Toe")]
    clearance = body.pos[:, feet, 2] - w.ground(body.pos[:, feet, :2])
    assert (clearance.amin(-1) < 0.2).all() and (clearance.amin(-1) > -0.05).all()
    obs, reward, terminated, truncated, info = w.step(torch.zeros(WORLDS, 69))
    assert reward.dtype == torch.float32 and reward.shape == (WORLDS,)
    assert terminated.dtype == torch.bool and truncated.dtype == torch.bool and not terminated.any()
    # A world whose path jumps 5 m away ends its episode; markers come back as NumPy.
    w.path[2] += 5.0
    w._refresh_points()
    _, _, terminated, _, info = w.step(torch.zeros(WORLDS, 69))
    assert terminated.tolist() == [False, False, True] and info["path_error"][2] > 4.0
    markers = w._markers(0)
    assert isinstance(markers[0][0], np.ndarray) and markers[0][0].shape == (1, 3) and markers[1][0].shape == (10, 3)


@warp
def test_warp_same_seed_same_episodes_and_partial_resets(warp_env):
    import torch

    w = warp_env

    def run(seed):
        obs, _ = w.reset(seed=seed)
        out = [obs.clone()]
        g = torch.Generator().manual_seed(0)
        for _ in range(4):
            out.append(w.step(torch.rand(WORLDS, 69, generator=g) * 0.4 - 0.2)[0].clone())
        return torch.stack(out), w.path.clone()

    (a, pa), (b, pb), (c, pc) = run(5), run(5), run(6)
    assert warp_same(a, b) and torch.equal(pa, pb)
    assert not torch.allclose(a, c) and not torch.allclose(pa, pc)
    # A masked reset redraws only the masked worlds' starts and paths.
    before = w.path.clone()
    w.reset(options={"reset_mask": np.array([False, True, False])})
    assert torch.equal(w.path[[0, 2]], before[[0, 2]]) and not torch.equal(w.path[1], before[1])
