"""The four packages import from this repository, not from unrelated PyPI projects."""

import importlib
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("name", ["terrain", "asteroid", "render", "evaluation"])
def test_packages_resolve_to_this_repository(name):
    module = importlib.import_module(name)
    assert Path(module.__file__).resolve().parent == REPO / name


def test_console_script_lists_the_terrain_group():
    from click.testing import CliRunner

    from terrain.cli import main

    result = CliRunner().invoke(main, ["--help"])
    assert result.exit_code == 0
    assert "terrain" in result.output


def test_lower_layers_do_not_import_higher_ones():
    """The import-linter layers contract (also run by `make test`)."""
    lint = Path(sys.executable).with_name("lint-imports")
    if not lint.exists():
        pytest.skip("import-linter is not installed in this environment")
    proc = subprocess.run([str(lint)], cwd=REPO, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stdout + proc.stderr
