"""Reading the TOML files users write, and writing the ones a run records.

Users write populations, recipes, scenarios and thresholds; a run records a scenario as
run.
"""

from __future__ import annotations

import json
import math
import tomllib
from pathlib import Path

from terrain.core.errors import InvalidParameterError, MissingInputError

__all__ = ["MAX_DEPTH", "merge_tables", "read_toml", "toml_text"]

#: Deepest nesting of tables and arrays a user's file may have (craterscape's own files nest
#: four deep at most; the bound keeps every reader's recursion far from Python's limit).
MAX_DEPTH = 64


def _depth(value) -> int:
    """Nesting depth of parsed TOML (a scalar is 0), walked without recursion."""
    deepest = 0
    todo = [(value, 0)]
    while todo:
        item, level = todo.pop()
        children = item.values() if isinstance(item, dict) else \
            item if isinstance(item, list) else None
        if children is None:
            continue
        deepest = max(deepest, level + 1)
        if deepest > MAX_DEPTH:
            break
        todo.extend((child, level + 1) for child in children)
    return deepest


def read_toml(path, what: str) -> dict:
    """Return the parsed TOML file at ``path``; a missing or malformed file is refused in one line.

    So is a file nesting tables or arrays more than :data:`MAX_DEPTH` deep.

    ``what`` names the file in the message (``"scenario"``, ``"population file"``, ...).

    >>> read_toml("/nonexistent.toml", "scenario")
    Traceback (most recent call last):
    ...
    terrain.core.errors.MissingInputError: scenario '/nonexistent.toml' does not exist
    """
    path = Path(path)
    if not path.exists():
        raise MissingInputError(f"{what} '{path}' does not exist")
    deep = InvalidParameterError(f"{what} '{path}' nests deeper than {MAX_DEPTH} tables or "
                                 "arrays")
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise InvalidParameterError(f"{what} '{path}' is not valid TOML: {exc}") from None
    except RecursionError:  # the parser recurses once per level of nesting
        raise deep from None
    if _depth(data) > MAX_DEPTH:
        raise deep
    return data


def merge_tables(data: dict, overrides: dict) -> dict:
    """Return a copy of ``data`` with ``overrides`` merged in, table by table.

    Nested dicts merge, anything else replaces.

    Parameters
    ----------
    data : dict
        Parsed TOML.
    overrides : dict
        Values to set, nested like ``data``.

    Returns
    -------
    dict
        The merged mapping (``data`` is not changed).

    Examples
    --------
    >>> merge_tables({"sun": {"azimuth": 45.0, "elevation": 7.0}}, {"sun": {"azimuth": 210}})
    {'sun': {'azimuth': 210, 'elevation': 7.0}}
    """
    out = dict(data)
    for key, value in overrides.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = merge_tables(out[key], value)
        else:
            out[key] = value
    return out


def _key(k: str) -> str:
    return k if k and all(c.isascii() and (c.isalnum() or c in "_-") for c in k) \
        else json.dumps(k)


def _value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if math.isnan(v):
            return "nan"
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return repr(v)
    if isinstance(v, str):
        return json.dumps(v)  # a JSON string is a valid TOML basic string
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{_key(k)} = {_value(x)}" for k, x in v.items()) + "}"
    raise TypeError(f"cannot write {type(v).__name__} {v!r} as TOML")


def _table(lines: list, name: str, table: dict) -> None:
    scalars = {k: v for k, v in table.items()
               if not isinstance(v, dict)
               and not (isinstance(v, list) and v and all(isinstance(x, dict) for x in v))}
    if name and (scalars or not table):
        lines += ["", f"[{name}]"]
    lines += [f"{_key(k)} = {_value(v)}" for k, v in scalars.items()]
    for k, v in table.items():
        key = f"{name}.{_key(k)}" if name else _key(k)
        if isinstance(v, dict):
            _table(lines, key, v)
        elif isinstance(v, list) and v and all(isinstance(x, dict) for x in v):
            for item in v:
                lines += ["", f"[[{key}]]"]
                lines += [f"{_key(k2)} = {_value(x)}" for k2, x in item.items()]


def toml_text(data: dict) -> str:
    """TOML text of a parsed TOML mapping (tables, arrays of tables, scalars, arrays).

    ``tomllib.loads(toml_text(d)) == d`` for any mapping ``tomllib`` can produce (dates
    aside); arrays of tables hold plain values.

    Parameters
    ----------
    data : dict
        The mapping.

    Returns
    -------
    str
        TOML text.

    Examples
    --------
    >>> d = {"name": "x", "sun": {"azimuth": 45.0}, "k": [{"time": 0}, {"time": 1}]}
    >>> tomllib.loads(toml_text(d)) == d
    True
    """
    lines: list = []
    _table(lines, "", data)
    return "\n".join(lines).lstrip("\n") + "\n"
