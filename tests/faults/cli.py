"""`semslam info` as a user runs it, and what a refusal or a warning must look like."""

from __future__ import annotations

from typer.testing import CliRunner

from semslam.cli import app


def info(*args):
    return CliRunner().invoke(app, ["info", *map(str, args)])


def assert_refused(result, *fragments) -> str:
    """Exit status 1, no traceback, and the refusal as one line on stderr naming every fragment."""
    assert result.exit_code == 1, result.output
    assert isinstance(result.exception, SystemExit), result.exception
    assert "Traceback" not in result.output
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert lines[0].startswith("semslam: error: "), lines[0]
    for f in fragments:
        assert f in lines[0], (f, lines[0])
    return lines[0]


def assert_accepted(result) -> str:
    """Exit status 0 with nothing on stderr (warnings are part of the report); the report."""
    assert result.exit_code == 0, result.output
    assert "Traceback" not in result.output
    return result.stdout


def check_section(stdout: str) -> list[str]:
    """The lines of info's ``check:`` section."""
    lines = stdout.splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith("check:"))
    out = []
    for line in lines[start + 1 :]:
        if not line.startswith("  "):
            break
        out.append(line.strip())
    return out
