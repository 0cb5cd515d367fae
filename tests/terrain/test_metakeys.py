"""The metadata-key registry: one place names every CRATERSCAPE_* tag."""

import ast
from pathlib import Path

from terrain.core import metakeys as mk

ROOT = Path(__file__).resolve().parents[2]
PACKAGES = ("terrain", "asteroid", "render", "evaluation")
#: Environment variables share the prefix but are not tile metadata.
ENVIRONMENT = {"CRATERSCAPE_MEMORY_LIMIT", "CRATERSCAPE_TOKEN", "CRATERSCAPE_SHARED_DATA",
               "CRATERSCAPE_EGL_DEVICE"}


def _code_strings(path: Path):
    """String constants of a module that are not docstrings."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    docstrings = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            body = node.body
            if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant):
                docstrings.add(id(body[0].value))
    for node in ast.walk(tree):
        if (isinstance(node, ast.Constant) and isinstance(node.value, str)
                and id(node) not in docstrings):
            yield node.lineno, node.value


def test_no_module_spells_a_metadata_key_outside_the_registry():
    spelt = []
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            if path.name == "metakeys.py":
                continue
            for line, value in _code_strings(path):
                if value.startswith(mk.PREFIX) and value not in ENVIRONMENT:
                    spelt.append(f"{path.relative_to(ROOT)}:{line} {value}")
    assert spelt == []


def test_registry_values_are_unique_prefixed_and_match_their_names():
    values = list(mk.KEYS.values())
    assert len(values) == len(set(values))
    for name, value in mk.KEYS.items():
        assert value == mk.PREFIX + name
        assert mk.is_key(value)
    assert not mk.is_key("AREA_OR_POINT")
