"""Every registered task on the task-agnostic core: Gymnasium contracts, the goal tasks' rewards
with known answers, their schedules, falls, bad input, and an outside client (SB3)."""

import importlib
import subprocess
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import smpl_envs
from smpl_envs.envs.base import fallen
from smpl_envs.envs.reach import HAND, reach_reward
from smpl_envs.envs.speed import speed_reward
from smpl_envs.envs.strike import STRIKERS, strike_reward
from smpl_envs.features import heading_rotation
from smpl_envs.humanoid import BODY_NAMES
from conftest import check_env_quietly, seeded_rollouts

OBS_DIM = {"SMPL/Imitation-v0": 934, "SMPL/KeypointImitation-v0": 574, "SMPL/Speed-v0": 361,
           "SMPL/Reach-v0": 361, "SMPL/Strike-v0": 373}
GOAL_IDS = ["SMPL/Speed-v0", "SMPL/Reach-v0", "SMPL/Strike-v0"]


def test_every_id_is_registered_with_both_entry_points():
    # Tasks with their own test module (terrain, VR tracking, recovery) check their sizes there.
    assert set(OBS_DIM) <= set(smpl_envs.ENV_IDS)
    for env_id in smpl_envs.ENV_IDS:
        spec = gym.spec(env_id)
        assert spec.entry_point is not None and spec.vector_entry_point is not None
    for env_id in GOAL_IDS:
        assert gym.spec(env_id).max_episode_steps == 300


@pytest.mark.parametrize("env_id", GOAL_IDS)
def test_env_checker_passes(env_id):
    env = gym.make(env_id, motions="walk", render_mode="rgb_array", render_size=(96, 72))
    check_env_quietly(env)
    assert env.observation_space.shape == (OBS_DIM[env_id],) and env.action_space.shape == (69,)
    env.close()


@pytest.mark.parametrize("env_id", GOAL_IDS)
def test_make_vec_is_native_batched_and_seeded(env_id):
    env = gym.make_vec(env_id, num_envs=8, motions=["walk", "run"])
    assert env.sim.num_worlds == 8 and env.metadata["autoreset_mode"] == gym.vector.AutoresetMode.NEXT_STEP
    (a, info), (b, _), (c, _) = seeded_rollouts(env, steps=25)
    assert a[0].shape == (8, OBS_DIM[env_id]) and a[0].dtype == np.float32
    assert all(np.array_equal(x, y) for x, y in zip(a, b))
    assert not np.array_equal(a[0], c[0])
    assert info["amp_obs"].shape == (8, 232) and "motion_id" in info and "motion_time" in info
    terms = [k for k in info if k.startswith("reward_")]
    assert terms and np.allclose(a[-3], sum(info[k] for k in terms))
    s = env.observation_structure
    assert max(v.stop for v in s.values()) == OBS_DIM[env_id]
    env.close()


@pytest.mark.parametrize("env_id", GOAL_IDS)
def test_runs_without_clips_from_the_rest_pose(env_id):
    env = gym.make_vec(env_id, num_envs=2)
    obs, info = env.reset(seed=0)
    assert env.motion_lib is None and "motion_id" not in info
    assert 0.85 < obs[0, 0] < 1.0  # standing pelvis height
    for _ in range(30):  # the rest pose stands at zero action
        obs, rew, term, trunc, info = env.step(np.zeros((2, 69)))
        assert not term.any()
    env.close()


# ---------------------------------------------------------------------------------------- speed
def test_speed_reward_known_answers():
    d = np.array([[1.0, 0.0], [0.0, 1.0]])
    v = np.array([[2.0, 0.0, 0.0], [0.0, 3.0, 0.5]])
    r, err = speed_reward(v, d, np.array([2.0, 3.0]))
    np.testing.assert_allclose(r, 1.0) and np.testing.assert_allclose(err, 0.0, atol=1e-12)
    r, err = speed_reward(np.array([[0.0, 1.0, 0.0]]), d[:1], np.array([1.0]))  # sideways at 1 m/s
    np.testing.assert_allclose(r, np.exp(-0.25 * (1.0 + 0.1)))
    np.testing.assert_allclose(err, 1.0)


def test_moving_at_the_target_speed_scores_one():
    env = gym.make_vec("SMPL/Speed-v0", num_envs=3)
    env.reset(seed=0)
    qpos, qvel = env.sim.qpos.copy(), np.zeros_like(env.sim.qvel)
    qvel[:, :2] = env.target_dir * env.target_speed[:, None]  # the pelvis glides at the target velocity
    env.sim.set_state(np.arange(3), qpos, qvel)
    body = env.sim.bodies
    reward, terms, term, trunc = env._evaluate(body, heading_rotation(body.rot[:, 0]))
    np.testing.assert_allclose(reward, 1.0, atol=1e-9)
    np.testing.assert_allclose(env._task_info(body)["speed_error"], 0.0, atol=1e-9)
    env.close()


def test_speed_target_resamples_on_schedule():
    env = gym.make_vec("SMPL/Speed-v0", num_envs=2, resample_interval=(5, 5))
    _, info = env.reset(seed=0)
    dirs = [info["target_dir"].copy()]
    for _ in range(12):
        dirs.append(env.step(np.zeros((2, 69)))[4]["target_dir"].copy())
    # Redrawn after the reward of steps 5 and 10: that step's info still describes the target its
    # reward used, the next one the new target.
    changed = [t for t in range(1, 13) if not np.array_equal(dirs[t], dirs[t - 1])]
    assert changed == [6, 11]
    # The observation carries the target in the heading frame (a unit vector) and the speed.
    obs = env.step(np.zeros((2, 69)))[0]
    np.testing.assert_allclose(np.linalg.norm(obs[:, 358:360], axis=-1), 1.0, atol=1e-5)
    np.testing.assert_allclose(obs[:, 360], env.target_speed, atol=1e-5)
    env.close()


# ---------------------------------------------------------------------------------------- reach
def test_hand_on_the_target_scores_one():
    np.testing.assert_allclose(reach_reward(np.ones((1, 3)), np.ones((1, 3)))[0], 1.0)
    np.testing.assert_allclose(reach_reward(np.zeros((1, 3)), np.array([[0.5, 0, 0]]))[0], np.exp(-1.0))
    env = gym.make_vec("SMPL/Reach-v0", num_envs=2, motions="walk")
    env.reset(seed=0)
    body = env.sim.bodies
    env.target[:] = body.pos[:, HAND]
    reward, terms, _, _ = env._evaluate(body, heading_rotation(body.rot[:, 0]))
    np.testing.assert_allclose(reward, 1.0) and np.testing.assert_allclose(terms["reach"], 1.0)
    env.close()


def test_reach_reward_sharpness_widens_the_kernel_and_nothing_else():
    np.testing.assert_allclose(reach_reward(np.zeros((1, 3)), np.array([[0.5, 0, 0]]), 1.0)[0], np.exp(-0.25))
    envs = [gym.make_vec("SMPL/Reach-v0", num_envs=3, reward_sharpness=k) for k in (4.0, 1.0)]
    out = []
    for env in envs:
        env.reset(seed=0)
        out.append(env.step(np.zeros((3, 69))))
    (obs4, r4, *_, info4), (obs1, r1, *_, info1) = out
    np.testing.assert_array_equal(obs4, obs1)  # the same episode, scored with a wider kernel
    d = info1["hand_distance"]
    np.testing.assert_allclose(r1, np.exp(-d ** 2), rtol=1e-6)
    np.testing.assert_allclose(r4, np.exp(-4 * d ** 2), rtol=1e-6)
    for env in envs:
        env.close()
    with pytest.raises(ValueError, match="reward_sharpness"):
        gym.make_vec("SMPL/Reach-v0", num_envs=1, reward_sharpness=0)


def test_reach_targets_lie_in_range_and_resample_on_schedule():
    env = gym.make_vec("SMPL/Reach-v0", num_envs=16, resample_interval=(3, 3))
    obs, info = env.reset(seed=0)
    for t in range(1, 7):
        obs, *_, info = env.step(np.zeros((16, 69)))
        assert (info["target_index"] == (t - 1) // 3).all()  # redrawn after the reward of steps 3, 6
        rel = obs[:, 358:361]  # target relative to the pelvis, heading frame
        assert (np.abs(rel[:, :2]) <= 1.0 + 0.05).all()  # drawn within +-1 m, the pelvis moved little
        assert ((info["target_pos"][:, 2] >= 0.2) & (info["target_pos"][:, 2] <= 2.0)).all()
    env.close()


# ---------------------------------------------------------------------------------------- strike
def test_strike_reward_known_answers():
    root, box = np.zeros((2, 3)), np.array([[2.0, 0, 0.9], [2.0, 0, 0.9]])
    vel = np.array([[1.0, 0, 0], [-1.0, 0, 0]])  # towards the box at 1 m/s; away from it
    r, terms = strike_reward(np.array([1.0, 1.0]), root, vel, box)
    np.testing.assert_allclose(terms["approach"], [0.4, 0.0]) and np.testing.assert_allclose(terms["topple"], 0.0)
    r, terms = strike_reward(np.array([0.1, 0.5]), root, vel, box)
    np.testing.assert_allclose(r, [1.0, 0.6 * 0.5])  # toppled: 1; half way: the tilt term only
    # approach_radius: standing still (or backing off) within the radius is paid as a full approach
    near = np.array([[1.5, 0, 0.0], [0.0, 0, 0.0]])  # 0.5 m and 2 m from the box
    still = np.zeros((2, 3))
    _, terms = strike_reward(np.array([1.0, 1.0]), near, still, box, approach_radius=1.0)
    np.testing.assert_allclose(terms["approach"], [0.4, 0.0])
    _, terms = strike_reward(np.array([1.0, 1.0]), near, still, box)
    np.testing.assert_allclose(terms["approach"], [0.0, 0.0])


def test_box_pushed_over_scores_one():
    env = gym.make_vec("SMPL/Strike-v0", num_envs=1, box_distance=(3.0, 3.0), autoreset_mode="Disabled")
    env.reset(seed=0)
    qpos, qvel = env.sim.qpos.copy(), env.sim.qvel.copy()
    away = qpos[0, env.box_qpos][:2] / np.linalg.norm(qpos[0, env.box_qpos][:2])
    # A scripted push of the box (not of the humanoid): spin it about the horizontal axis
    # across the line to the humanoid, so it falls away from it.
    qvel[0, env.box_qvel.start + 3:env.box_qvel.start + 6] = 3.0 * np.array([-away[1], away[0], 0.0])
    env.sim.set_state([0], qpos, qvel)
    for _ in range(60):
        _, reward, term, trunc, info = env.step(np.zeros((1, 69)))
        assert not term[0]
        if info["toppled"][0]:
            break
    assert info["toppled"][0] and reward[0] == pytest.approx(1.0)
    result = smpl_envs.evaluate(lambda obs: np.zeros((len(obs), 69)), "SMPL/Strike-v0", episodes=2, num_envs=2,
                                progress=False)
    assert result.summary["toppled"] == 0.0  # nobody pushes the box in the evaluation
    env.close()


def test_a_torso_touching_the_box_ends_the_episode_and_the_hand_does_not():
    env = gym.make_vec("SMPL/Strike-v0", num_envs=2, autoreset_mode="Disabled")
    _, info = env.reset(seed=0)
    qpos, qvel = env.sim.qpos.copy(), env.sim.qvel.copy()
    box = slice(env.box_qpos.start, env.box_qpos.start + 2)
    qpos[0, box] = qpos[0, :2] + [-0.3, 0.0]  # against the back
    hand = info["body_pos"][1, BODY_NAMES.index("R_Hand")]
    qpos[1, box] = hand[:2] + [0.0, -(env.box_size[1] / 2 + 0.02)]  # against the outstretched right hand
    env.sim.set_state([0, 1], qpos, qvel)
    _, _, term, _, info = env.step(np.zeros((2, 69)))
    touching = info["touching"]
    others = [i for i in range(24) if i not in STRIKERS]
    assert touching[0, others].any() and term[0]
    assert touching[1, BODY_NAMES.index("R_Hand")] and not touching[1, others].any() and not term[1]
    env.close()


BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"


def _outcome_summary(name: str):
    """The `summarise` of benchmarks/<name>.py (the benchmarks folder is not a package)."""
    sys.path.insert(0, str(BENCHMARKS))
    try:
        return importlib.import_module(name).summarise
    finally:
        sys.path.remove(str(BENCHMARKS))


def _tiny_ppo(tmp_path, env_id: str, **env_kwargs) -> Path:
    """An untrained PPO checkpoint for env_id, saved in tmp_path."""
    from agents import PPO

    model = PPO(env_id, n_envs=1, env_kwargs=env_kwargs, n_steps=8, batch_size=8,
                policy_kwargs={"actor_hidden": [16], "critic_hidden": [16]}, verbose=0, device="cpu")
    path = tmp_path / f"{env_id.split('/')[1]}.pt"
    model.save(path, optimizer=False)
    model.close()
    return path


def _run_outcomes(name: str, tmp_path, env_id: str, env_kwargs: dict, episodes: int, num_envs: int,
                  other: str = "SMPL/Speed-v0") -> str:
    """benchmarks/<name>.py on an untrained env_id policy: its output; and the script refuses a
    checkpoint of another task (it reads its own task's info)."""
    script = str(BENCHMARKS / f"{name}.py")
    out = subprocess.run([sys.executable, script, str(_tiny_ppo(tmp_path, env_id, **env_kwargs)), "--episodes",
                          str(episodes), "--num-envs", str(num_envs)], capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-2000:]
    refused = subprocess.run([sys.executable, script, str(_tiny_ppo(tmp_path, other))], capture_output=True,
                             text=True, timeout=600)
    assert refused.returncode != 0 and f"not {env_id}" in refused.stderr
    return out.stdout


def test_strike_outcomes_splits_falls_from_fouls(tmp_path):
    # benchmarks/strike_outcomes.py on an untrained policy with the box next to it: every episode
    # is counted once, as a fall, a foul or a full one, and a non-Strike checkpoint is refused.
    stdout = _run_outcomes("strike_outcomes", tmp_path, "SMPL/Strike-v0", {"box_distance": (1.2, 1.3)}, 3, 3)
    counts = {line.split("|")[1].strip(): int(line.split("|")[4].split()[0])
              for line in stdout.splitlines() if line.startswith(("| full", "| fall", "| foul"))}
    assert set(counts) == {"full", "fall", "foul"} and sum(counts.values()) == 3
    assert "| all |" in stdout and "3 episodes" in stdout


def test_reach_outcomes_place_and_time_every_target(tmp_path):
    # benchmarks/reach_outcomes.py: the summary of known targets, then a run of an untrained policy
    # whose every target is counted once on each split (front / behind, side) and a non-Reach
    # checkpoint refused.
    summarise = _outcome_summary("reach_outcomes")
    rows = np.array([[0.5, -0.3, 0.1, 1.0, 0.05, 15],     # in front, right side, middle: reached in 0.5 s
                     [0.5, 0.3, 0.9, 1.8, 0.04, 45],      # in front, across, high: reached in 1.5 s
                     [-0.5, -0.3, -0.6, 0.3, 0.60, -1]])  # behind, low: missed
    table = {line.split("|")[1].strip(): line.split("|")[2:6] for line in summarise(rows, 30.0)[2:]}
    assert [c.strip() for c in table["all"]] == ["3", "66.7%", "0.050", "1.00"]
    assert [c.strip() for c in table["behind (x < 0)"]] == ["1", "0.0%", "0.600", "-"]
    assert [c.strip() for c in table["high (height >= 1.4 m)"]] == ["1", "100.0%", "0.040", "1.50"]

    stdout = _run_outcomes("reach_outcomes", tmp_path, "SMPL/Reach-v0",
                           {"resample_interval": (5, 5), "max_episode_steps": 32}, 3, 2)
    counts = {line.split("|")[1].strip(): int(line.split("|")[2]) for line in stdout.splitlines()
              if line.startswith("| ") and not line.startswith("| targets")}
    assert "3 episodes" in stdout and counts["all"] >= 3
    assert counts["all"] == counts.get("in front (x > 0)", 0) + counts.get("behind (x < 0)", 0)
    assert counts["all"] == counts.get("right-hand side (y < 0)", 0) + counts.get("across the body (y > 0)", 0)


def test_speed_outcomes_split_every_step_once(tmp_path):
    # benchmarks/speed_outcomes.py: the summary of known steps, then a run of an untrained policy
    # with commands redrawn every 5 steps, whose every step is counted once on each split (by
    # time since the draw, first command or later), and a Reach checkpoint refused.
    summarise = _outcome_summary("speed_outcomes")
    rows = np.array([[0.5, 0.5, 0.0, 10.0, 0.0, 1],    # slow, just drawn, first: standing still
                     [4.5, 1.5, 2.5, 170.0, 3.0, 0],   # fast, held, after a turn about
                     [4.5, 2.5, 3.5, 20.0, 2.0, 0]])   # fast, held longer
    table = {line.split("|")[1].strip(): [c.strip() for c in line.split("|")[2:7]] for line in summarise(rows)[2:]}
    assert table["all"] == ["100.0%", "1.50", "1.67", "2.00", "2.90"]
    assert table["commanded 4-5 m/s"] == ["66.7%", "2.00", "2.50", "2.00", "2.90"]
    assert table["0-1 s after the draw"] == ["33.3%", "0.50", "0.00", "-", "-"]
    assert table["turn asked over 135 deg"][:2] == ["33.3%", "1.50"]
    assert "commanded 1-2 m/s" not in table

    stdout = _run_outcomes("speed_outcomes", tmp_path, "SMPL/Speed-v0",
                           {"resample_interval": (5, 5), "max_episode_steps": 32}, 3, 2, other="SMPL/Reach-v0")
    share = {line.split("|")[1].strip(): float(line.split("|")[2].strip(" %")) for line in stdout.splitlines()
             if line.startswith("| ") and not line.startswith("| steps")}
    assert "3 episodes" in stdout and share["all"] == 100.0
    # every command lasts 5 steps: the first 5 of each episode are its first command's
    first, later = share["the episode's first command (standing start)"], share["later commands"]
    assert abs(first + later - 100.0) < 0.2 and 0 < first < 100
    since = [v for k, v in share.items() if "after the draw" in k]
    assert abs(sum(since) - 100.0) < 0.3 and "1-2 s after the draw" not in share


def test_a_box_too_close_to_start_clear_of_the_humanoid_is_refused():
    for distance in [(0.0, 0.0), (0.2, 0.2), (0.5, 4.0), (1.1, 4.0)]:
        with pytest.raises(ValueError, match=r"box_distance must keep the box clear of the humanoid: at least 1.18 m"):
            gym.make_vec("SMPL/Strike-v0", num_envs=1, box_distance=distance)
    with pytest.raises(ValueError, match="at least 1.61 m"):  # a wider box needs more room
        gym.make("SMPL/Strike-v0", box_distance=(1.5, 4.0), box_size=(1.0, 1.0, 1.8))
    # The nearest box allowed starts clear of the body in the rest pose and in every kick frame.
    for motions in (None, "kick"):
        env = gym.make_vec("SMPL/Strike-v0", num_envs=16, box_distance=(1.19, 1.19), motions=motions,
                           autoreset_mode="Disabled")
        _, info = env.reset(seed=0)
        assert not info["touching"].any(), motions
        env.close()


# ---------------------------------------------------------------------------------------- episodes
def test_a_fall_ends_the_episode():
    body = type("B", (), {})()
    pos = np.zeros((3, 24, 3))
    pos[..., 2] = 1.0
    pos[1, BODY_NAMES.index("L_Hand"), 2] = 0.1   # a hand on the floor
    pos[2, BODY_NAMES.index("L_Toe"), 2] = 0.0    # feet may touch it
    body.pos = pos
    assert fallen(body).tolist() == [False, True, False]
    env = gym.make_vec("SMPL/Speed-v0", num_envs=2, autoreset_mode="Disabled")
    env.reset(seed=0)
    qpos = env.sim.qpos.copy()
    qpos[1, 2] = 0.12                       # world 1 lies on its back
    qpos[1, 3:7] = [np.cos(np.pi / 4), 0.0, np.sin(np.pi / 4), 0.0]
    env.sim.set_state([0, 1], qpos, np.zeros_like(env.sim.qvel))
    _, _, term, trunc, _ = env.step(np.zeros((2, 69)))
    assert term.tolist() == [False, True] and not trunc.any()
    env.close()


@pytest.mark.parametrize("env_id", GOAL_IDS)
def test_episode_evaluation_runs_the_protocol(env_id):
    zero = lambda obs: np.zeros((len(obs), 69))  # noqa: E731
    result = smpl_envs.evaluate(zero, env_id, episodes=3, num_envs=2, progress=False)
    assert len(result.rows) == 3 and result.summary["episodes"] == 3
    assert all(r["length"] == 300 for r in result.rows)  # the rest pose stands for 10 s
    assert result.summary["no_fall"] == 1.0 and 0.0 <= result.summary["score"] <= 1.0
    assert "episodes" in result.table()
    with pytest.raises(ValueError, match="threshold"):
        smpl_envs.evaluate(zero, env_id, threshold=0.5, progress=False)


# ---------------------------------------------------------------------------------------- bad input
@pytest.mark.parametrize("env_id, kwargs, match", [
    ("SMPL/Speed-v0", dict(speed_range=(3.0, 1.0)), "speed_range"),
    ("SMPL/Speed-v0", dict(speed_range=(-1.0, 1.0)), "speed_range"),
    ("SMPL/Speed-v0", dict(resample_interval=(-5, 10)), "resample_interval"),
    ("SMPL/Reach-v0", dict(target_range_z=(2.0, 0.2)), "target_range_z"),
    ("SMPL/Reach-v0", dict(resample_interval=(10, 5)), "resample_interval"),
    ("SMPL/Strike-v0", dict(box_distance=(1.5, 500.0)), "box_distance"),
    ("SMPL/Strike-v0", dict(box_size=(0.4, -1, 1.8)), "box_size"),
    ("SMPL/Strike-v0", dict(box_size=("x", 0.4, 1.8)), "box_size"),
    ("SMPL/Strike-v0", dict(box_density="x"), "box_density"),
    ("SMPL/Strike-v0", dict(box_density=float("nan")), "box_density"),
    ("SMPL/Strike-v0", dict(approach_radius=0), "approach_radius"),
    ("SMPL/Speed-v0", dict(render_size=(0, 0)), "render_size"),
    ("SMPL/Speed-v0", dict(render_size=(4000, 3000)), "render_size"),
    ("SMPL/Speed-v0", dict(render_size=640), "render_size"),
    ("SMPL/Speed-v0", dict(substeps=0), "substeps"),
    ("SMPL/Speed-v0", dict(fall_height=-1), "fall_height"),
    ("SMPL/Speed-v0", dict(head_height="x"), "head_height"),
    ("SMPL/Imitation-v0", dict(termination_distance=-1), "termination_distance"),
    ("SMPL/Imitation-v0", dict(action_mode="torque"), "action_mode"),
])
def test_bad_kwargs_name_themselves(env_id, kwargs, match):
    with pytest.raises(ValueError, match=match):
        gym.make_vec(env_id, num_envs=1, **kwargs)


@pytest.mark.parametrize("env_id", GOAL_IDS)
def test_unknown_kwarg_names_itself(env_id):
    with pytest.raises(TypeError, match="no_such_option"):
        gym.make(env_id, no_such_option=1)


@pytest.mark.parametrize("mode", ["NextStep", "SameStep"])
def test_nan_action_ends_only_that_world(mode):
    env = gym.make_vec("SMPL/Speed-v0", num_envs=3, autoreset_mode=mode)
    env.reset(seed=0)
    actions = np.zeros((3, 69))
    actions[1, 7] = np.nan
    obs, rew, term, trunc, info = env.step(actions)
    assert term.tolist() == [False, True, False] and info["diverged"].tolist() == [False, True, False]
    assert rew[1] == 0.0 and np.isfinite(obs).all()
    obs, rew, term, trunc, info = env.step(np.zeros((3, 69)))
    assert not term.any() and not info["diverged"].any()
    env.close()


def test_reset_mask_must_be_a_boolean_mask_of_every_world():
    env = gym.make_vec("SMPL/Reach-v0", num_envs=4, autoreset_mode="Disabled")
    obs, _ = env.reset(seed=0)
    for bad in ([0, 2], [True, False, True], [True] * 6):
        with pytest.raises(ValueError, match="boolean mask of 4"):
            env.reset(options={"reset_mask": bad})
    obs2, info = env.reset(options={"reset_mask": np.isin(range(4), [0, 2])})
    assert info["_reset"].tolist() == [True, False, True, False]
    np.testing.assert_array_equal(obs2[[1, 3]], obs[[1, 3]])
    env.close()


# ---------------------------------------------------------------------------------------- clients
@pytest.mark.parametrize("env_id", GOAL_IDS)
def test_stable_baselines3_ppo_trains(env_id):
    import stable_baselines3 as sb3

    env = gym.make(env_id, motions=["walk", "run"], max_episode_steps=100)
    model = sb3.PPO("MlpPolicy", env, n_steps=512, batch_size=128, n_epochs=1, seed=0, device="cpu",
                    policy_kwargs=dict(net_arch=[64, 64]))
    model.learn(total_timesteps=2048)
    assert model.num_timesteps >= 2048
    action, _ = model.predict(env.reset(seed=0)[0], deterministic=True)
    assert action.shape == (69,) and np.isfinite(action).all()
    env.close()


@pytest.mark.parametrize("env_id", ["SMPL/Imitation-v0", "SMPL/Speed-v0"])
def test_cache_kwarg_reaches_the_motion_library(env_id, tmp_path, monkeypatch):
    from smpl_envs.motion import load_motion
    from smpl_envs.motion.export import to_amass

    tree = tmp_path / "clips"  # a directory tree is what the MotionLib caches
    tree.mkdir()
    to_amass(load_motion("walk"), tree / "walk_poses.npz")
    monkeypatch.setenv("SMPL_ENVS_CACHE", str(tmp_path / "cache"))
    gym.make_vec(env_id, num_envs=1, motions=str(tree), cache=False).close()
    assert not (tmp_path / "cache").exists()
    gym.make_vec(env_id, num_envs=1, motions=str(tree)).close()
    assert any((tmp_path / "cache").iterdir())


def test_beginning_share_starts_that_fraction_at_the_first_frame():
    env = gym.make_vec("SMPL/Imitation-v0", num_envs=400, motions="walk", beginning_share=0.5, num_threads=1)
    _, info = env.reset(seed=0)
    share = (info["motion_time"] == 0).mean()
    assert 0.4 < share < 0.6  # 0.5, plus the random starts that land on frame 0 (1 in 180)
    env.close()
    with pytest.raises(ValueError, match="beginning_share"):
        gym.make_vec("SMPL/Speed-v0", num_envs=1, beginning_share=1.5)


def test_reach_metrics_leave_out_a_target_cut_short_by_the_time_limit():
    from smpl_envs.envs.reach import reach_episode_metrics

    log = {"target_index": np.array([0, 0, 1, 1, 2]), "hand_distance": np.array([0.5, 0.05, 0.3, 0.2, 0.4]),
           "truncated": True, "terminated": False}
    assert reach_episode_metrics(log)["targets_reached"] == 0.5       # target 2 had one step
    log["truncated"], log["terminated"] = False, True
    assert reach_episode_metrics(log)["targets_reached"] == pytest.approx(1 / 3)  # a fall: it counts


def test_episode_evaluation_meets_the_same_episodes_whatever_the_policy():
    starts = {}
    for name, policy in (("zero", lambda obs: np.zeros((len(obs), 69))),
                         ("flail", lambda obs: np.random.default_rng(len(obs)).uniform(-1, 1, (len(obs), 69)))):
        env = gym.make_vec("SMPL/Speed-v0", num_envs=2, motions=["walk", "run"], autoreset_mode="Disabled")
        seen = []
        original = env.reset

        def reset(**kwargs):
            out = original(**kwargs)
            seen.append((out[1]["motion_id"].copy(), out[1]["target_speed"].copy()))
            return out

        env.reset = reset
        smpl_envs.evaluate(policy, env, episodes=5, progress=False)
        starts[name] = seen
        env.close()
    assert len(starts["zero"]) == 3  # waves of 2, 2 and 1
    for (a_ids, a_speed), (b_ids, b_speed) in zip(starts["zero"], starts["flail"]):
        np.testing.assert_array_equal(a_ids, b_ids)
        np.testing.assert_array_equal(a_speed, b_speed)


def test_evaluate_refuses_a_one_world_env_clearly():
    env = gym.make("SMPL/Speed-v0")
    with pytest.raises(ValueError, match="vector env"):
        smpl_envs.evaluate(lambda obs: np.zeros((len(obs), 69)), env, progress=False)
    env.close()


def test_goal_tasks_example_runs(tmp_path):
    import json
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    out = subprocess.run([sys.executable, str(root / "examples" / "goal_tasks.py"), "SMPL/Reach-v0", "--episodes", "2",
                          "--steps", "10", "--size", "160", "120", "--out", str(tmp_path)],
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    for label in ("zero", "random"):
        assert json.loads((tmp_path / f"reach_{label}.json").read_text())["summary"]["episodes"] == 2
    assert (tmp_path / "reach_zero.mp4").stat().st_size > 1000
    assert "hand_distance" in out.stdout


def test_failure_sampling_draws_failing_clips_more_often():
    from smpl_envs.envs.clip_sampling import FailureWeightedClips

    s = FailureWeightedClips(3, share=0.5, decay=1.0)
    base = np.full(3, 1 / 3)
    np.testing.assert_allclose(s.weights(base), base)  # nothing failed yet: the library's weights
    clips = np.array([0, 0, 1, 1, 2, 2])
    s.record(clips, None, np.array([0, 0, 1, 0, 1, 1], bool))       # rates 0, 1/2, 1
    s.record(clips, np.array([1, 1, 0, 0, 1, 1], bool), np.zeros(6, bool))  # clip 1 idle: rates 0, 1/2, 1/2
    np.testing.assert_allclose(s.rates(), [0.0, 0.5, 0.5])
    np.testing.assert_allclose(s.weights(base), [0.5 / 3, 0.5 / 3 + 0.25, 0.5 / 3 + 0.25])

    # Through the env: PD tracking alone (the zero residual) holds "stand" far longer than "run",
    # so "run" is drawn more often than the library's even split.
    env = gym.make_vec("SMPL/Imitation-v0", num_envs=32, motions=["stand", "run"], failure_sampling=0.8,
                       action_mode="residual", termination_distance=0.3, num_threads=1)
    env.reset(seed=0)
    for _ in range(90):
        env.step(np.zeros((32, 69), np.float32))
    rates = env.clip_sampler.rates()
    assert rates[1] > 2 * rates[0] > 0
    w = env.clip_sampler.weights(env.motion_lib.weights)
    assert abs(w.sum() - 1) < 1e-9 and w[1] > 0.6
    with pytest.raises(ValueError, match="failure_sampling"):
        gym.make_vec("SMPL/Imitation-v0", num_envs=1, failure_sampling=1.5)
    with pytest.raises(ValueError, match="failure_sampling"):
        gym.make_vec("SMPL/Speed-v0", num_envs=1, failure_sampling=0.5)
    env.close()
