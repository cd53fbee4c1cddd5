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
