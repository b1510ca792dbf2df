"""The package as a user installs it: a wheel built from the source, installed (not editable) into
a fresh virtual environment, driven by its `smpl-envs` script from a directory outside the
checkout. Everything the command line needs (recipes, shipped policies, clips) must be inside.

The venv is made with --system-site-packages so torch, MuJoCo and the rest come from this
machine (the wheel goes in with --no-deps). Those site-packages may hold an editable install of
smpl-envs pointing at a checkout; the venv's own site-packages come first on sys.path, and the
test asserts that the interpreter imports the wheel's files, not a checkout's."""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
# What a source distribution holds (MANIFEST.in, pyproject.toml): build from a copy of just that,
# so the build leaves nothing in the checkout and needs nothing else from it.
SOURCE = ("pyproject.toml", "setup.py", "MANIFEST.in", "README.md", "smpl_envs", "agents", "tasks")
TINY = ["--threads", "1", "--quiet", "--set", "env.num_envs=2", "--set", "agent.hyperparams.n_steps=16",
        "--set", "agent.hyperparams.batch_size=32", "--set", "train.total_timesteps=64",
        "--set", "video.steps=5", "--set", "eval.num_envs=2"]


def _run(argv, cwd, env, timeout=300):
    out = subprocess.run(argv, cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)
    assert out.returncode == 0, f"{argv}\n{out.stdout[-2000:]}\n{out.stderr[-3000:]}"
    return out


@pytest.fixture(scope="module")
def installed(tmp_path_factory):
    """(venv's python, its smpl-envs script, a working directory outside the checkout, env)."""
    tmp = tmp_path_factory.mktemp("wheel")
    src = tmp / "src"
    src.mkdir()
    for name in SOURCE:
        if (ROOT / name).is_dir():
            shutil.copytree(ROOT / name, src / name, ignore=shutil.ignore_patterns("__pycache__"))
        else:
            shutil.copy2(ROOT / name, src / name)
    # Nothing of this checkout may leak in: no PYTHONPATH, and the venv's site first.
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME", "PYTHONSTARTUP")}
    env["MUJOCO_GL"] = env.get("MUJOCO_GL", "egl")
    _run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q", "-w", str(tmp / "dist"),
          str(src)], cwd=tmp, env=env)
    (wheel,) = (tmp / "dist").glob("smpl_envs-*.whl")
    venv = tmp / "venv"
    _run([sys.executable, "-m", "venv", "--system-site-packages", "--without-pip", str(venv)], cwd=tmp, env=env)
    python = venv / "bin" / "python"
    # This interpreter's pip, run by the venv's python, installs into the venv.
    _run([str(python), "-m", "pip", "install", "--no-deps", "--no-index", "-q", str(wheel)], cwd=tmp, env=env)
    outside = tmp / "outside"
    outside.mkdir()
    return python, venv / "bin" / "smpl-envs", outside, env


@pytest.mark.slow
def test_the_wheel_holds_the_recipes_policies_and_clips(installed):
    python, _, outside, env = installed
    code = ("import smpl_envs, agents; from agents.recipes import shipped_recipe_dir, pretrained_checkpoints; "
            "from smpl_envs.motion import available_clips; "
            "print(smpl_envs.__file__); print(agents.__file__); print(shipped_recipe_dir()); "
            "print(','.join(sorted(pretrained_checkpoints()))); print(','.join(available_clips()))")
    lines = _run([str(python), "-c", code], cwd=outside, env=env).stdout.splitlines()
    site = python.parents[1]
    for path in lines[:3]:
        assert Path(path).resolve().is_relative_to(site.resolve()), (path, "not the installed wheel")
    shipped = sorted(p.name for p in (ROOT / "tasks").glob("*.yaml"))
    assert sorted(p.name for p in Path(lines[2]).glob("*.yaml")) == shipped
    assert lines[3] == ",".join(sorted(p.stem for p in (ROOT / "agents" / "pretrained").glob("*.pt")))
    assert {"walk", "run", "jump", "stand"} <= set(lines[4].split(","))


@pytest.mark.slow
def test_the_installed_command_line_trains_evaluates_and_records(installed):
    python, script, outside, env = installed
    # The script's first line runs the venv's interpreter, which imports the wheel.
    assert script.read_text().splitlines()[0] == f"#!{python}"
    info = _run([str(script), "info"], cwd=outside, env=env).stdout
    assert str(python.parents[1]) in info.splitlines()[0]  # "smpl-envs  0.1.0 (<venv>/lib/.../smpl_envs)"
    assert "demo_walk_ppo" in _run([str(script), "recipes"], cwd=outside, env=env).stdout

    _run([str(script), "train", "demo_walk_ppo", "--run-dir", "runs/demo", *TINY], cwd=outside, env=env)
    run = outside / "runs" / "demo"
    assert (run / "checkpoints" / "last.pt").is_file() and (run / "eval.json").is_file()
    assert (run / "config.yaml").read_text().count("demo_walk_ppo") >= 1

    out = _run([str(script), "eval", "walk", "--out", "walk_eval.json", "--threads", "1", "--no-progress"],
               cwd=outside, env=env).stdout
    assert "ALL   100.0%" in out  # the shipped policy, found by name, at its real success
    _run([str(script), "record", "walk", "--steps", "10", "--out", "walk.mp4", "--no-progress"], cwd=outside, env=env)
    assert (outside / "walk.mp4").stat().st_size > 1000
