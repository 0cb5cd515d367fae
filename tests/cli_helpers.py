"""Running `craterscape` as a user does, inside the test process (click's CliRunner)."""

from __future__ import annotations

from click.testing import CliRunner

from terrain.cli import main


def run(*args, env=None):
    """Invoke ``craterscape ARGS...``; every argument is passed as text."""
    return CliRunner().invoke(main, [str(a) for a in args], env=env)


def one_line_error(result, *fragments):
    """Assert the command failed as bad input must: exit code 2, one line, no traceback."""
    assert result.exit_code == 2, result.output
    lines = [ln for ln in result.output.splitlines() if ln.strip()]
    assert len(lines) == 1, result.output
    assert lines[0].startswith("craterscape: error:") or lines[0].startswith("Error:")
    for fragment in fragments:
        assert fragment in lines[0], lines[0]
    assert "Traceback" not in result.output
