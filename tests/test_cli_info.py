"""The command line a user meets first: --version, `smpl-envs recipes`, `smpl-envs info`, and
the recipe lookup that works from any directory."""
import sys
import types
from importlib import metadata

import pytest
import yaml

import smpl_envs
from agents import info, recipes
from agents.cli import main


def test_version_is_the_package_version(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--version"])
    assert exc.value.code == 0
    assert capsys.readouterr().out.strip() == f"smpl-envs {smpl_envs.__version__}"
    assert smpl_envs.__version__ == metadata.version("smpl-envs")  # pyproject reads it from the package


def test_recipes_lists_every_shipped_recipe_with_its_first_sentence(capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # no ./tasks here: the shipped recipes only
    assert main(["recipes"]) == 0
    out = capsys.readouterr().out.splitlines()
    shipped = sorted(p.stem for p in recipes.shipped_recipe_dir().glob("*.yaml"))
    assert out[0] == f"{recipes.shipped_recipe_dir()}:" and len(out) == 1 + len(shipped)
    listed = {line.split()[0]: line.split(None, 1)[1] for line in out[1:]}
    assert sorted(listed) == shipped and "demo_walk_ppo" in listed
    assert listed["imitation_ppo"] == 'Motion imitation with PPO: the SMPL humanoid learns to track the shipped "walk" clip.'
    assert all(len(d) <= 110 for d in listed.values())


def test_a_recipe_in_the_working_directory_is_listed_and_found_first(capsys, tmp_path, monkeypatch):
    (tmp_path / "tasks").mkdir()
    mine = yaml.safe_load(recipes.resolve_recipe_path("demo_walk_ppo").read_text())
    (tmp_path / "tasks" / "mine.yaml").write_text("# My own walk: shorter. Second sentence.\n" + yaml.safe_dump(mine))
    monkeypatch.chdir(tmp_path)
    assert recipes.resolve_recipe_path("mine") == tmp_path / "tasks" / "mine.yaml"
    assert recipes.resolve_recipe_path("imitation_ppo").parent == recipes.shipped_recipe_dir()
    main(["recipes"])
    out = capsys.readouterr().out
    assert f"{tmp_path / 'tasks'}:\n  mine  My own walk: shorter.\n" in out


def test_description_of_a_recipe_without_a_comment_is_empty(tmp_path):
    (tmp_path / "x.yaml").write_text("env: {id: SMPL/Speed-v0}\n")
    assert recipes.recipe_description(tmp_path / "x.yaml") == ""


def test_info_names_what_a_bug_report_needs(capsys):
    assert main(["info"]) == 0
    out = capsys.readouterr().out
    for key in ("smpl-envs", "python", "mujoco", "torch", "gymnasium", "MUJOCO_GL", "mujoco-warp", "warp devices"):
        assert any(line.split("  ")[0].strip() == key for line in out.splitlines()), key
    import mujoco
    import torch

    assert mujoco.__version__ in out and str(torch.__version__) in out and smpl_envs.__version__ in out


def test_info_reports_a_broken_gpu_backend_instead_of_crashing(monkeypatch):
    broken = types.ModuleType("warp")
    broken.config = types.SimpleNamespace(quiet=False)
    broken.__spec__ = types.SimpleNamespace(name="warp")

    def init():
        raise RuntimeError("CUDA driver version is insufficient\nmore detail")

    broken.init = init
    monkeypatch.setitem(sys.modules, "warp", broken)
    monkeypatch.setattr(info, "find_spec", lambda name: object())
    assert info._warp()["warp devices"] == "error: RuntimeError: CUDA driver version is insufficient"


def test_info_without_the_gpu_backend_says_how_to_install_it(monkeypatch):
    monkeypatch.setattr(info, "find_spec", lambda name: None)
    assert "pip install 'smpl-envs[gpu]'" in info._warp()["warp devices"]
