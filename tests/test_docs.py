"""The README and the documentation site: the site builds with `mkdocs build --strict` (a broken
link, anchor, page or API reference fails), the README stays short, its links into docs/ land on
pages and anchors that exist, and its two commands are the ones CI and the docs run."""
from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
DEMO_PREFIX = "pip install torch==2.13.0 && pip install -e . &&"


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Path:
    """The site, built strictly into a temporary directory (~3 s here)."""
    out = tmp_path_factory.mktemp("site")
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1"}
    build = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(out)],
                           cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)
    assert build.returncode == 0, build.stdout[-3000:] + build.stderr[-5000:]
    assert "WARNING" not in build.stderr, build.stderr[-5000:]
    return out


def _page(site: Path, doc: str) -> Path:
    """The built HTML of docs/<doc> (MkDocs' directory URLs: a/b.md -> a/b/index.html)."""
    doc = doc.removesuffix(".md")
    return site / ("index.html" if doc == "index" else f"{doc.removesuffix('/index')}/index.html")


def test_the_site_builds_strictly_with_every_page(site):
    import yaml

    def pages(nav):
        for item in nav:
            value = next(iter(item.values())) if isinstance(item, dict) else item
            yield from (pages(value) if isinstance(value, list) else [value])

    nav = yaml.safe_load((ROOT / "mkdocs.yml").read_text())["nav"]
    for doc in pages(nav):
        assert _page(site, doc).is_file(), doc
    # The API reference is generated from the docstrings, not left empty.
    api = _page(site, "api/agents.md").read_text()
    assert "OnPolicyAlgorithm" in api and "clipped" in api.lower()
    assert "Observation" in _page(site, "api/smpl_envs.md").read_text()


def test_readme_links_into_the_docs_land_on_real_pages_and_anchors(site):
    links = re.findall(r"\]\((docs/[^)\s]+)\)", README.read_text())
    assert len(links) > 20
    for link in links:
        path, _, anchor = link.partition("#")
        assert (ROOT / path).is_file(), link
        if path.endswith(".md") and anchor:
            html = _page(site, path.removeprefix("docs/")).read_text()
            assert f'id="{anchor}"' in html, link


def test_readme_is_short():
    assert len(README.read_text().splitlines()) <= 160  # the rest lives in docs/ (docs/status.md)


def test_readme_test_command_is_what_ci_runs():
    ci = (ROOT / ".ci" / "run").read_text().strip().splitlines()[-1]
    readme_lines = README.read_text().splitlines()
    assert ci in readme_lines, ci
    getting_started = (ROOT / "docs" / "getting-started.md").read_text().splitlines()
    demo = next(line for line in readme_lines if line.startswith(DEMO_PREFIX))
    assert ci in getting_started and demo in getting_started  # the docs show the same two commands


@pytest.mark.slow
def test_readme_quickstarts_run(tmp_path, monkeypatch):
    # The environment and training quickstarts, with the budgets cut (the shipped policy's blocks
    # are run by tests/test_pretrained.py, the demo line by tests/test_cli.py).
    monkeypatch.chdir(tmp_path)
    blocks = re.findall(r"```python\n(.*?)```", README.read_text(), re.S)
    env_block = next(b for b in blocks if "gym.make_vec" in b)
    train_block = next(b for b in blocks if "model.learn(" in b)
    namespace = {}
    exec(env_block.replace("steps=150", "steps=3"), namespace)
    assert namespace["obs"].shape == (64, 361)
    assert (tmp_path / "out" / "walk.mp4").stat().st_size > 0
    exec(train_block.replace("model.learn(1_000_000)", "model.learn(64)")
         .replace("n_envs=32", "n_envs=2, n_steps=16, batch_size=32, verbose=0"), namespace)
    assert (tmp_path / "runs" / "mine.pt").stat().st_size > 1000
