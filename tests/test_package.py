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


def test_the_console_script_reaches_each_packages_own_group():
    """`craterscape` is terrain's root command, and it reaches every package's group through
    the ``craterscape.groups`` entry points (so the lowest layer never imports a higher one):
    each name resolves to the very group object its own package defines, and every package
    registers exactly one."""
    from importlib.metadata import entry_points

    import click

    from terrain.cli.root import main

    (script,) = entry_points(group="console_scripts", name="craterscape")
    assert script.load() is main
    groups = {ep.name: ep for ep in entry_points(group="craterscape.groups")}
    assert set(groups) == {"terrain", "asteroid", "render", "evaluation"}
    ctx = click.Context(main)
    assert sorted(main.list_commands(ctx)) == sorted(groups)
    for name, ep in groups.items():
        group = ep.load()
        assert isinstance(group, click.Group) and group.commands, name
        assert main.get_command(ctx, name) is group
        assert ep.value.split(".")[0] == name, ep.value


def test_lower_layers_do_not_import_higher_ones():
    """The import-linter layers contract (also run by `make test`)."""
    lint = Path(sys.executable).with_name("lint-imports")
    if not lint.exists():
        pytest.skip("import-linter is not installed in this environment")
    proc = subprocess.run([str(lint)], cwd=REPO, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stdout + proc.stderr


def _imports(path: Path):
    """Yield (line, module, names) of every import statement of a Python file."""
    import ast

    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield node.lineno, alias.name, ()
        elif isinstance(node, ast.ImportFrom) and node.module:
            yield node.lineno, node.module, tuple(a.name for a in node.names)


def test_only_terrain_io_imports_rasterio():
    """One module reads and writes rasters: in the packages (also an import-linter contract),
    the examples and the benchmarks, where only a benchmark whose baseline *is* rasterio or
    GDAL may import it, saying so in a comment just above."""
    folders = ["terrain", "asteroid", "render", "evaluation", "examples", "benchmarks", "docs"]
    found = []
    for folder in folders:
        for path in sorted((REPO / folder).rglob("*.py")):
            lines = path.read_text(encoding="utf-8").splitlines()
            for line, module, _ in _imports(path):
                if module.split(".")[0] != "rasterio" or path == REPO / "terrain" / "io.py":
                    continue
                above = " ".join(lines[max(0, line - 4):line - 1]).lower()
                if folder == "benchmarks" and "baseline" in above:
                    continue
                found.append(f"{path.relative_to(REPO)}:{line} imports {module}")
    assert not found, found


def test_the_demo_script_imports_nothing_private():
    """examples/demo.py is what a newcomer copies: public names only, and short."""
    path = REPO / "examples" / "demo.py"
    for line, module, names in _imports(path):
        assert not any(part.startswith("_") for part in module.split(".")
                       if part != "__future__"), (line, module)
        assert not any(n.startswith("_") for n in names), (line, names)
    text = path.read_text(encoding="utf-8")
    assert "._" not in text.replace("__", "")
    assert len(text.splitlines()) < 150


def test_only_the_command_line_modules_import_click_or_the_terrain_cli():
    """The library is a library first: apart from the command-line modules (each package's
    ``cli.py`` and ``terrain/cli/``), no module of the four packages imports click or
    ``terrain.cli``, so nothing in the library drives the command line."""
    found = []
    for folder in ["terrain", "asteroid", "render", "evaluation"]:
        for path in sorted((REPO / folder).rglob("*.py")):
            rel = path.relative_to(REPO)
            if rel.name == "cli.py" or rel.parts[:2] == ("terrain", "cli"):
                continue
            for line, module, _ in _imports(path):
                if module.split(".")[0] == "click" or module.startswith("terrain.cli"):
                    found.append(f"{rel}:{line} imports {module}")
    assert not found, found
