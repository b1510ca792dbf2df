"""Module structure: no import cycles in the packages, and each module imports first in a fresh
interpreter. A cycle hidden behind imports inside functions still breaks whoever imports the
wrong module first, or a refactor that moves one import to the top, so the check reads every
import statement, wherever it sits."""
from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("smpl_envs", "agents")


def _modules() -> dict[str, Path]:
    out = {}
    for package in PACKAGES:
        for path in (ROOT / package).rglob("*.py"):
            parts = list(path.relative_to(ROOT).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts.pop()
            out[".".join(parts)] = path
    return out


def import_graph() -> dict[str, set[str]]:
    """module -> the package modules it imports anywhere in its code. `from pkg import name`
    counts as importing pkg.name where that is a module, else pkg (its __init__). Importing a
    module's own ancestor package is no edge: Python initialises a package before any module in
    it, so the ancestor is complete by then."""
    modules = _modules()
    graph = {}
    for name, path in modules.items():
        package = name.split(".") if path.name == "__init__.py" else name.split(".")[:-1]
        deps = set()
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                deps.update(a.name for a in node.names)
            elif isinstance(node, ast.ImportFrom):
                base = ".".join(package[:len(package) - node.level + 1] + [node.module or ""]).strip(".") \
                    if node.level else node.module
                for a in node.names:
                    deps.add(f"{base}.{a.name}" if f"{base}.{a.name}" in modules else base)
        ancestors = {".".join(name.split(".")[:i]) for i in range(1, name.count(".") + 1)}
        graph[name] = {d for d in deps if d in modules and d != name and d not in ancestors}
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan)."""
    index, low, stack, on_stack, found = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def test_no_import_cycles():
    graph = import_graph()
    assert "smpl_envs.motion" in graph["smpl_envs.evaluation"]  # load_motions lives in the motion library
    assert not any(m.startswith("smpl_envs.envs") for m in graph["smpl_envs.evaluation"])
    assert "smpl_envs.envs.recovery" not in graph["smpl_envs.envs.imitation"]
    found = cycles(graph)
    assert not found, "\n".join(" <-> ".join(c) for c in found)


def test_the_graph_sees_imports_inside_functions():
    # The check itself: the cycle this suite once had (evaluation imported load_motions from
    # smpl_envs.envs inside a function, while the tasks import evaluation) is found.
    graph = import_graph()
    graph["smpl_envs.evaluation"].add("smpl_envs.envs")
    assert any("smpl_envs.evaluation" in c and "smpl_envs.envs" in c for c in cycles(graph))


@pytest.mark.parametrize("module", ["smpl_envs.evaluation", "smpl_envs.envs.recovery", "smpl_envs.envs.recovery_rules",
                                    "smpl_envs.motion", "smpl_envs.policy_settings", "agents.run", "agents.policies",
                                    "agents.on_policy", "agents.cli"])
def test_module_imports_first_in_a_fresh_interpreter(module):
    code = f"import {module}, gymnasium as gym; import smpl_envs; gym.make('SMPL/Recovery-v0').close()"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
