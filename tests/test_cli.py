"""The `smpl-envs` command line: recipes, run directories, and train -> eval -> record -> plot ->
resume end to end on budgets of a few thousand steps (the numbers learned mean nothing here)."""
import csv
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

import agents
from agents import PPO
from agents.cli import main
from agents.recipes import (RecipeError, find_checkpoint, load_recipe, make_run_dir, parse_value,
                            read_config)

TASKS = Path(agents.__file__).resolve().parents[1] / "tasks"
SHIPPED = sorted(p.stem for p in TASKS.glob("*.yaml"))
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"

# Small enough to train in seconds: 4 worlds, 32-unit networks, 16-step rollouts. One torch
# thread, because on a small shared CPU torch's thread pool fights the simulation for cores
# (an order of magnitude slower otherwise).
TINY = ["--set", "env.num_envs=4", "--set", "agent.hyperparams.n_steps=16",
        "--set", "agent.hyperparams.batch_size=64", "--set", "agent.hyperparams.actor_hidden=[32,32]",
        "--set", "agent.hyperparams.critic_hidden=[32,32]", "--no-progress", "--quiet", "--threads", "1"]


def read_rows(run: Path) -> list[dict]:
    with open(run / "logs" / "progress.csv", newline="") as f:
        return list(csv.DictReader(f))


def last_step(run: Path) -> float:
    return max(float(r["time/total_timesteps"]) for r in read_rows(run))


def assert_png(path: Path) -> None:
    data = path.read_bytes()
    assert data[:8] == PNG_MAGIC and len(data) > 20_000, path


# ---------------------------------------------------------------------------------------- recipes
@pytest.mark.parametrize("profile", [None, "paper"])
@pytest.mark.parametrize("name", SHIPPED)
def test_shipped_recipes_load(name, profile):
    # The latent-task recipes reference the shipped PULSE checkpoint; resolving a recipe only
    # checks that a reference names a file (test_pulse.py builds the agents on a real one).
    raw = yaml.safe_load((TASKS / f"{name}.yaml").read_text())
    refers = "pulse" in ((raw.get("agent") or {}).get("policy") or {}).get("kwargs", {})
    over = [f"agent.policy.kwargs.pulse.checkpoint={find_checkpoint('walk')}"] if refers else []
    recipe = load_recipe(name, over, profile=profile)
    assert recipe["recipe_name"] == name and recipe["profile"] == profile
    assert "profiles" not in recipe
    assert recipe["agent"]["class"] in agents.AGENTS
    if profile == "paper" and recipe["agent"]["class"] == "PULSE":  # PULSE's sizes, not PHC's
        assert recipe["agent"]["policy"]["kwargs"]["decoder_hidden"] == [3096, 2048, 1024]
    elif profile == "paper":
        hp, policy = recipe["agent"]["hyperparams"], recipe["agent"]["policy"]["kwargs"]
        assert recipe["env"]["num_envs"] == 1536 and hp["batch_size"] == 16384
        assert policy["actor_hidden"] == policy["critic_hidden"] == [1024, 512]
        assert recipe["train"]["total_timesteps"] == 10_000_000_000
        assert isinstance(hp["learning_rate"], float)


def test_every_task_has_ppo_and_amp_recipes():
    assert {"imitation_ppo", "imitation_amp", "keypoint_amp", "demo_walk_ppo", "speed_ppo", "speed_amp",
            "reach_ppo", "reach_amp", "strike_ppo", "strike_amp"} <= set(SHIPPED)


def test_recipes_share_values_through_base(tmp_path):
    demo, full = load_recipe("demo_walk_ppo"), load_recipe("imitation_ppo")
    assert demo["agent"] == full["agent"] and demo["env"]["num_envs"] == 16
    speed = load_recipe("speed_amp")
    assert speed["env"]["kwargs"] == {"motions": ["walk", "run"]}      # stated whole, not merged
    assert speed["eval"]["options"] == {"episodes": 32, "seed": 0}      # the task's own options
    assert speed["agent"] == load_recipe("imitation_amp")["agent"]
    (tmp_path / "a.yaml").write_text("base: b.yaml\n")
    (tmp_path / "b.yaml").write_text("base: a.yaml\n")
    with pytest.raises(RecipeError, match="loop"):
        load_recipe(tmp_path / "a.yaml")
    (tmp_path / "c.yaml").write_text("base: speed_ppo\neval: {options: {threshold: 0.5}}\n")
    with pytest.raises(RecipeError, match="threshold"):
        load_recipe(tmp_path / "c.yaml")


def test_profile_then_overrides(tmp_path):
    recipe = load_recipe("imitation_amp", profile="paper", overrides=[
        "agent.hyperparams.learning_rate=3e-4",       # YAML 1.1 reads this as a string
        "agent.hyperparams.actor_hidden=[64, 32]",
        "train.total_timesteps=1e6",                  # a whole float becomes an int budget
        "env.kwargs.reward_weights.pos=0.6",          # creates the missing levels
        "eval.motions=[walk, run]",
        "video.steps=0",
    ])
    hp = recipe["agent"]["hyperparams"]
    assert hp["learning_rate"] == pytest.approx(3e-4) and isinstance(hp["learning_rate"], float)
    # The actor-critic's former hyperparameter, moved to the policy's arguments over the recipe's.
    assert recipe["agent"]["policy"]["kwargs"]["actor_hidden"] == [64, 32] and "actor_hidden" not in hp
    assert hp["batch_size"] == 16384 and hp["disc_hidden"] == [1024, 512]   # from the profile
    assert recipe["train"]["total_timesteps"] == 1_000_000
    assert recipe["env"]["kwargs"] == {"motions": "walk", "reward_weights": {"pos": 0.6}}
    assert recipe["eval"]["motions"] == ["walk", "run"] and recipe["video"]["steps"] == 0
    assert recipe["overrides"][0] == "agent.hyperparams.learning_rate=3e-4"


@pytest.mark.parametrize("text, value", [("3e-4", 3e-4), ("-1E6", -1e6), ("0.5", 0.5), ("12", 12),
                                         ("[512,256]", [512, 256]), ("[1e-3, 2]", [1e-3, 2]), ("true", True),
                                         ("null", None), ("walk", "walk"), ("{pos: 1}", {"pos": 1})])
def test_parse_value(text, value):
    assert parse_value(text) == value


def test_names_resolve_from_the_working_directory_first(tmp_path, monkeypatch):
    local = yaml.safe_load((TASKS / "demo_walk_ppo.yaml").read_text())
    local["env"]["num_envs"] = 3
    (tmp_path / "tasks").mkdir()
    (tmp_path / "tasks" / "demo_walk_ppo.yaml").write_text(yaml.safe_dump(local))
    (tmp_path / "mine.yaml").write_text(yaml.safe_dump(local))
    monkeypatch.chdir(tmp_path)
    assert load_recipe("demo_walk_ppo")["env"]["num_envs"] == 3          # ./tasks shadows the repo's
    assert load_recipe("imitation_ppo")["env"]["num_envs"] == 32         # the repo's as fallback
    assert load_recipe(tmp_path / "mine.yaml")["recipe_name"] == "mine"  # a path as is


@pytest.mark.parametrize("kwargs, match", [
    (dict(name_or_path="nope"), r"no recipe named 'nope'.*available: .*demo_walk_ppo"),
    (dict(name_or_path="missing.yaml"), "does not exist"),
    (dict(name_or_path="imitation_ppo", profile="gpu"), "no profile 'gpu'; available: paper"),
    (dict(name_or_path="imitation_ppo", overrides=["agent.class=SAC"]), "agent.class must be one of PPO, AMP"),
    (dict(name_or_path="imitation_ppo", overrides=["env.id="]), "env.id"),
    (dict(name_or_path="imitation_ppo", overrides=["env.id=SMPL/Nope-v0"]), "not an smpl_envs task"),
    (dict(name_or_path="imitation_ppo", overrides=["train.total_timesteps=0"]), r"train.total_timesteps must be .*> 0"),
    (dict(name_or_path="imitation_ppo", overrides=["train.total_timestep=5"]), r"train.total_timestep'\]"),
    (dict(name_or_path="imitation_ppo", overrides=["agent.hyperparams.lr=1"]), "agent.hyperparams.lr"),
    (dict(name_or_path="imitation_ppo", overrides=["agent.hyperparams.seed=1"]), "train.seed"),
    (dict(name_or_path="imitation_ppo", overrides=["learning_rate"]), "expected KEY=VALUE"),
    (dict(name_or_path="imitation_ppo", overrides=["train.max_minutes=-1"]), "train.max_minutes must be"),
    (dict(name_or_path="imitation_ppo", overrides=["env.id.x=1"]), "not a mapping"),
])
def test_recipe_errors_name_the_problem(kwargs, match):
    with pytest.raises(RecipeError, match=match):
        load_recipe(**kwargs)


def test_run_dirs_and_checkpoint_lookup(tmp_path):
    recipe = load_recipe("demo_walk_ppo")
    run = make_run_dir(recipe, tmp_path)
    assert run.name.startswith("demo_walk_ppo-")
    assert all((run / d).is_dir() for d in ("checkpoints", "logs", "videos"))
    assert read_config(run) == recipe
    assert make_run_dir(recipe, tmp_path) != run  # same second: a distinct directory
    with pytest.raises(RecipeError, match="already exists"):
        make_run_dir(recipe, tmp_path, run.name)
    assert make_run_dir(recipe, tmp_path, run.name, resume=True) == run

    with pytest.raises(RecipeError, match="no checkpoint"):
        find_checkpoint(run)
    ckpts = run / "checkpoints"
    for name in ("ckpt_000000000512.pt", "ckpt_000000001024.pt"):
        (ckpts / name).touch()
    assert find_checkpoint(run).name == "ckpt_000000001024.pt"
    (ckpts / "last.pt").touch()
    assert find_checkpoint(run).name == "last.pt"
    (ckpts / "best.pt").touch()
    assert find_checkpoint(run).name == "best.pt"
    assert find_checkpoint(run, "last").name == "last.pt"
    assert find_checkpoint(ckpts / "ckpt_000000000512.pt").name == "ckpt_000000000512.pt"


# ---------------------------------------------------------------------------------------- end to end
@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """One tiny demo_walk_ppo run shared by the tests that read it (training is the slow part)."""
    tmp = tmp_path_factory.mktemp("cli")
    run = tmp / "run"
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("SMPL_ENVS_CACHE", str(tmp / "cache"))  # as conftest does for each test
        code = main(["train", "demo_walk_ppo", "--set", "train.total_timesteps=1024", "--set", "video.steps=10",
                     "--set", "train.checkpoint_every=512", "--run-dir", str(run), *TINY])
    assert code == 0
    return run


def test_train_writes_a_complete_run(trained):
    assert (trained / "config.yaml").is_file()
    assert agents.load(trained / "checkpoints" / "last.pt").num_timesteps == 1024
    assert sorted(p.name for p in (trained / "checkpoints").glob("ckpt_*.pt")) == [
        "ckpt_000000000512.pt", "ckpt_000000001024.pt"]
    rows = read_rows(trained)
    assert len(rows) >= 10 and "rollout/reward_pos" in rows[0] and "eval/success_rate" in rows[0]
    assert list((trained / "logs" / "tb").glob("events.out.tfevents.*"))
    assert_png(trained / "curves.png")
    assert (trained / "videos" / "final.mp4").stat().st_size > 1000
    summary = yaml.safe_load((trained / "eval.json").read_text())["summary"]  # JSON is YAML
    assert summary["clips"] == 1 and 0.0 <= summary["success_rate"] <= 1.0
    assert "walk" in (trained / "eval.txt").read_text()
    # Every evaluation's per-clip result is kept by timesteps (here the final one only).
    history = yaml.safe_load((trained / "evals" / "000000001024.json").read_text())
    assert [row["name"] for row in history["clips"]] == ["walk"] and history["summary"] == summary
    assert "walk" in (trained / "evals" / "000000001024.txt").read_text()


def test_eval_record_plot_commands(trained, tmp_path, capsys):
    (trained / "eval.json").unlink()
    assert main(["eval", str(trained), "--no-progress"]) == 0
    out = capsys.readouterr().out
    assert "walk" in out and "last.pt" in out  # no best.pt without periodic evaluation: last
    assert (trained / "eval.json").is_file() and (trained / "eval.txt").is_file()

    assert main(["eval", str(trained / "checkpoints" / "ckpt_000000000512.pt"), "--out", str(tmp_path / "e.json"),
                 "--motions", "walk", "--no-progress"]) == 0
    assert (tmp_path / "e.json").is_file() and (tmp_path / "e.txt").is_file()

    video = tmp_path / "clip.mp4"
    assert main(["record", str(trained), "--steps", "10", "--out", str(video), "--no-progress"]) == 0
    assert video.stat().st_size > 1000 and str(video) in capsys.readouterr().out

    png = tmp_path / "curves.png"
    assert main(["plot", str(trained), "--out", str(png)]) == 0
    assert_png(png)


def test_resume_continues_the_run(trained, tmp_path):
    run = tmp_path / "run"
    shutil.copytree(trained, run)
    before = last_step(run)
    assert main(["train", "--resume", str(run), "--set", "train.total_timesteps=2048",
                 "--set", "agent.hyperparams.learning_rate=5e-5", *TINY]) == 0
    assert last_step(run) > before
    agent = agents.load(run / "checkpoints" / "last.pt")
    assert agent.num_timesteps >= 2048 and agent.learning_rate == pytest.approx(5e-5)
    assert float(read_rows(run)[0]["time/total_timesteps"]) < before  # appended, not rewritten
    config = read_config(run)  # the resumed budget is recorded, after the first run's overrides
    assert config["train"]["total_timesteps"] == 2048
    assert config["overrides"].index("train.total_timesteps=2048") > config["overrides"].index("video.steps=10")
    with pytest.raises(SystemExit):  # the checkpoint's networks cannot change
        main(["train", "--resume", str(run), "--set", "agent.hyperparams.actor_hidden=[64]"])


def test_ctrl_c_saves_a_resumable_checkpoint(tmp_path, monkeypatch, capsys):
    update, calls = PPO._update, []

    def interrupted_update(self, buf):
        calls.append(1)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return update(self, buf)

    monkeypatch.setattr(PPO, "_update", interrupted_update)
    run = tmp_path / "run"
    code = main(["train", "demo_walk_ppo", "--set", "train.total_timesteps=4096", "--run-dir", str(run), *TINY])
    assert code == 130
    assert agents.load(run / "checkpoints" / "last.pt").num_timesteps == 2 * 64
    assert f"--resume {run}" in capsys.readouterr().err


def test_wall_clock_budget_stops_training(tmp_path):
    run = tmp_path / "run"
    assert main(["train", "demo_walk_ppo", "--set", "train.total_timesteps=1000000", "--set", "train.max_minutes=1e-6",
                 "--set", "video.steps=0", "--run-dir", str(run), *TINY]) == 0
    assert agents.load(run / "checkpoints" / "last.pt").num_timesteps == 64  # one iteration, then the budget
    assert (run / "eval.json").is_file()  # a budget stop still finishes the run


def test_amp_recipe_trains(tmp_path):
    run = tmp_path / "amp"
    assert main(["train", "keypoint_amp", "--set", "train.total_timesteps=256", "--set", "env.num_envs=2",
                 "--set", "agent.hyperparams.disc_hidden=[32,32]", "--set", "agent.hyperparams.replay_size=1000",
                 "--set", "video.steps=0", "--set", "eval.every=128", "--run-dir", str(run), *TINY]) == 0
    agent = agents.load(find_checkpoint(run, "last"))
    assert type(agent).__name__ == "AMP" and agent.env_id == "SMPL/KeypointImitation-v0"
    assert (run / "checkpoints" / "best.pt").is_file()  # periodic evaluation keeps the best
    assert "amp/disc_loss" in read_rows(run)[-1]
    assert not list((run / "videos").iterdir())  # video.steps: 0 records nothing
    assert_png(run / "curves.png")


@pytest.mark.parametrize("argv, match", [
    (["train", "nope"], "no recipe named 'nope'"),
    (["train", "demo_walk_ppo", "--set", "oops"], "bad override 'oops'"),
    (["train"], "needs a RECIPE"),
    (["eval", "{tmp}"], "no checkpoint in"),
    (["record", "{tmp}/nothing.pt"], "no checkpoint or run directory"),
    (["plot", "{tmp}"], "no progress.csv"),
    (["train", "--resume", "{tmp}"], "not a run directory"),
])
def test_bad_input_is_one_error_line_and_status_2(argv, match, tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        main([a.replace("{tmp}", str(tmp_path)) for a in argv])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1 and match in err


def test_python_dash_m_agents():
    out = subprocess.run([sys.executable, "-m", "agents", "--help"], capture_output=True, text=True, check=True)
    assert all(cmd in out.stdout for cmd in ("train", "eval", "record", "plot"))


# ---------------------------------------------------------------------------------------- README
def test_readme_demo_commands_run(tmp_path, monkeypatch):
    """The README's demo line, command by command, with the training budget cut to seconds."""
    readme = (Path(__file__).resolve().parents[1] / "README.md").read_text()
    line = next(ln for ln in readme.splitlines() if ln.startswith("pip install torch==2.13.0 && pip install -e . &&"))
    commands = [c.split() for c in line.split("&&")[2:]]
    assert [c[:2] for c in commands] == [["smpl-envs", "train"], ["smpl-envs", "eval"], ["smpl-envs", "record"],
                                         ["smpl-envs", "record"]]
    monkeypatch.chdir(tmp_path)
    for i, argv in enumerate(commands):
        argv = argv[1:]
        if argv[0] == "train":
            argv += TINY + ["--set", "train.total_timesteps=128", "--set", "video.steps=5"]
        elif argv[0] == "record":
            argv += ["--steps", "5"]
        assert main(argv) == 0, argv
    run = tmp_path / commands[0][commands[0].index("--run-dir") + 1]
    assert (run / "checkpoints" / "last.pt").is_file() and (run / "eval.json").is_file()
    assert any(p.stat().st_size > 1000 for p in (run / "videos").glob("*.mp4"))
    assert (run / "walk.mp4").stat().st_size > 1000  # the shipped walk policy, found by name
