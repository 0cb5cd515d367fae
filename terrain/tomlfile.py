"""Reading the TOML files users write (populations, recipes, scenarios, thresholds)."""

from __future__ import annotations

import tomllib
from pathlib import Path

from terrain.errors import InvalidParameterError, MissingInputError

__all__ = ["read_toml"]


def read_toml(path, what: str) -> dict:
    """The parsed TOML file at ``path``; a missing or malformed file is refused in one line.

    ``what`` names the file in the message (``"scenario"``, ``"population file"``, ...).

    >>> read_toml("/nonexistent.toml", "scenario")
    Traceback (most recent call last):
    ...
    terrain.errors.MissingInputError: scenario '/nonexistent.toml' does not exist
    """
    path = Path(path)
    if not path.exists():
        raise MissingInputError(f"{what} '{path}' does not exist")
    try:
        return tomllib.loads(path.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise InvalidParameterError(f"{what} '{path}' is not valid TOML: {exc}") from None
