"""The house rules that tools check, run by the README's test command so that CI enforces them:
ruff (lint and format) and the design's import contracts (pyproject.toml, [tool.importlinter])."""

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent


def _run(*cmd: str) -> subprocess.CompletedProcess:
    return subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=300)


@pytest.mark.parametrize("args", [("check", "."), ("format", "--check", ".")], ids=["lint", "format"])
def test_ruff(args):
    r = _run(sys.executable, "-m", "ruff", *args)
    assert r.returncode == 0, r.stdout + r.stderr


def test_import_contracts():
    r = _run(str(BIN / "lint-imports"), "--no-cache")
    assert r.returncode == 0, r.stdout[-4000:] + r.stderr


def _import_cycles(graph) -> list[list[str]]:
    """The strongly connected components (more than one module) of the module import graph, lazy
    imports inside functions included (Tarjan's algorithm, iterative)."""
    index, low, on_stack, stack, cycles = {}, {}, set(), [], []
    for root in sorted(graph.modules):
        if root in index:
            continue
        work = [(root, iter(sorted(graph.find_modules_directly_imported_by(root))))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            v, children = work[-1]
            w = next(children, None)
            if w is not None:
                if w not in index:
                    index[w] = low[w] = len(index)
                    stack.append(w)
                    on_stack.add(w)
                    work.append((w, iter(sorted(graph.find_modules_directly_imported_by(w)))))
                elif w in on_stack:
                    low[v] = min(low[v], index[w])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[v])
            if low[v] == index[v]:
                component = []
                while True:
                    w = stack.pop()
                    on_stack.discard(w)
                    component.append(w)
                    if w == v:
                        break
                if len(component) > 1:
                    cycles.append(sorted(component))
    return cycles


def test_no_module_imports_itself_through_others():
    """No import cycle between modules, lazy imports included (import-linter's contracts see
    packages, not every module)."""
    import grimp

    graph = grimp.build_graph("semslam", "frontends", "factors")
    assert _import_cycles(graph) == []
    graph.add_import(importer="semslam.results", imported="semslam.eval.outputs")  # the check can fail
    assert _import_cycles(graph) != []
