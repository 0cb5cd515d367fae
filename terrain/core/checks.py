"""The one family of checks behind every record built from a table, file or option.

Every ``from_mapping`` in craterscape (stage specs, scenarios, recipes, campaign files, sensor and
motion tables, server requests) refuses an unknown key with :func:`check_keys` and converts
each value with :func:`number`, :func:`integer`, :func:`boolean`, :func:`text` or
:func:`vector`, so every file and option is refused in the same words: the place (``where``),
the field, what was expected and what arrived.
"""

from __future__ import annotations

import difflib
import math
from collections.abc import Iterable, Mapping
from typing import Any

import numpy as np

from terrain.core.errors import InvalidParameterError

__all__ = ["boolean", "check_keys", "integer", "number", "reject_unknown", "text", "vector"]

_REAL = (int, float, np.integer, np.floating)


def _label(where: str, name: str) -> str:
    return f"{where} {name}".strip() if where else name


def reject_unknown(keys: Iterable[Any], known: Iterable[str], what: str,
                   noun: str = "key") -> None:
    """Refuse the first of ``keys`` (in sorted order) not in ``known``, naming the nearest.

    Parameters
    ----------
    keys : iterable of str
        The keys given (a table's keys, a file's columns).
    known : iterable of str
        The valid ones.
    what : str
        What they belong to, for the message (``"rock"``, ``"scenario [sensor]"``).
    noun : str, optional
        What one of them is called (``"key"``, ``"column"``).

    Raises
    ------
    InvalidParameterError
        ``unknown {what} {noun} 'name' (did you mean 'nearest'?)``, or with the valid ones listed
        where none is near.

    Examples
    --------
    >>> reject_unknown({"dmin": 1, "dnsty": 2}, ["dmin", "density"], "rocks")
    Traceback (most recent call last):
    ...
    terrain.core.errors.InvalidParameterError: unknown rocks key 'dnsty' (did you mean 'density'?)
    """
    known = sorted(str(k) for k in known)
    unknown = sorted(str(k) for k in keys if str(k) not in known)
    if unknown:
        near = difflib.get_close_matches(unknown[0], known, n=1)
        hint = f" (did you mean '{near[0]}'?)" if near else f" (expected one of {known})"
        raise InvalidParameterError(f"unknown {what} {noun} '{unknown[0]}'{hint}")


def check_keys(mapping: Any, allowed: Iterable[str], where: str) -> dict:
    """Return ``mapping`` as a dict after refusing a non-table or an unknown key.

    Parameters
    ----------
    mapping : mapping
        The table as read (TOML, JSON, keyword options).
    allowed : iterable of str
        Its valid keys.
    where : str
        The table's name in messages (``"scenario [sensor]"``).

    Returns
    -------
    dict
        A copy of ``mapping``.

    Raises
    ------
    InvalidParameterError
        When ``mapping`` is not a table, or names a key not in ``allowed``.

    Examples
    --------
    >>> check_keys({"gain": 2.0}, {"gain", "bias"}, "[sensor]")
    {'gain': 2.0}
    >>> check_keys({"gian": 2.0}, {"gain", "bias"}, "[sensor]")
    Traceback (most recent call last):
    ...
    terrain.core.errors.InvalidParameterError: unknown [sensor] key 'gian' (did you mean 'gain'?)
    """
    if not isinstance(mapping, Mapping):
        raise InvalidParameterError(
            f"{where} must be a table of keys; got {type(mapping).__name__}")
    reject_unknown(mapping, allowed, where)
    return dict(mapping)


def number(value: Any, name: str, *, low: float | None = None, high: float | None = None,
           low_open: bool = False, high_open: bool = False, where: str = "") -> float:
    """Return ``value`` as a finite float in the interval given, or refuse it by name.

    Parameters
    ----------
    value : int or float
        What arrived (booleans and strings are refused).
    name : str
        The field's name in messages.
    low, high : float, optional
        Bounds (inclusive unless ``low_open``/``high_open``).
    low_open, high_open : bool, optional
        Exclude the bound itself.
    where : str, optional
        The table the field belongs to.

    Returns
    -------
    float

    Raises
    ------
    InvalidParameterError
        ``{where} {name} must be ...; got ...``.

    Examples
    --------
    >>> number(3, "gain", low=0, low_open=True)
    3.0
    >>> number(float("nan"), "gain", where="[sensor]")
    Traceback (most recent call last):
    ...
    terrain.core.errors.InvalidParameterError: [sensor] gain must be finite; got nan
    """
    label = _label(where, name)
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, _REAL):
        raise InvalidParameterError(f"{label} must be a number; got {value!r}")
    v = float(value)
    if not math.isfinite(v):
        raise InvalidParameterError(f"{label} must be finite; got {v}")
    if low is not None and (v < low or (low_open and v == low)):
        raise InvalidParameterError(f"{label} must be {'>' if low_open else '>='} {low}; got {v}")
    if high is not None and (v > high or (high_open and v == high)):
        raise InvalidParameterError(
            f"{label} must be {'<' if high_open else '<='} {high}; got {v}")
    return v


def integer(value: Any, name: str, *, low: int | None = None, high: int | None = None,
            where: str = "") -> int:
    """Return ``value`` as an int in [low, high]; a float with a fraction is refused.

    Examples
    --------
    >>> integer(12.0, "bits", low=1, high=16)
    12
    >>> integer(8.7, "bits")
    Traceback (most recent call last):
    ...
    terrain.core.errors.InvalidParameterError: bits must be an integer; got 8.7
    """
    label = _label(where, name)
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, _REAL):
        raise InvalidParameterError(f"{label} must be an integer; got {value!r}")
    if isinstance(value, (float, np.floating)):
        if not math.isfinite(value) or value != int(value):
            raise InvalidParameterError(f"{label} must be an integer; got {value!r}")
    v = int(value)
    if (low is not None and v < low) or (high is not None and v > high):
        span = f"[{low if low is not None else '-inf'}, {high if high is not None else 'inf'}]"
        raise InvalidParameterError(f"{label} must lie in {span}; got {v}")
    return v


def boolean(value: Any, name: str, *, where: str = "") -> bool:
    """Return ``value`` if it is a boolean (TOML ``true``/``false``), or refuse it.

    Examples
    --------
    >>> boolean("yes", "shadows")
    Traceback (most recent call last):
    ...
    terrain.core.errors.InvalidParameterError: shadows must be true or false (unquoted); got 'yes'
    """
    if not isinstance(value, (bool, np.bool_)):
        raise InvalidParameterError(
            f"{_label(where, name)} must be true or false (unquoted); got {value!r}")
    return bool(value)


def text(value: Any, name: str, *, choices: Iterable[str] | None = None, where: str = "",
         empty: bool = True) -> str:
    """Return ``value`` if it is a string (one of ``choices`` where given), or refuse it.

    Examples
    --------
    >>> text("hapke", "reflectance", choices=["hapke", "lunar-lambert"])
    'hapke'
    """
    label = _label(where, name)
    if not isinstance(value, str):
        raise InvalidParameterError(f"{label} must be a string; got {value!r}")
    if not empty and not value.strip():
        raise InvalidParameterError(f"{label} must not be empty")
    if choices is not None:
        options = sorted(choices)
        if value not in options:
            near = difflib.get_close_matches(value, options, n=1)
            hint = f" (did you mean '{near[0]}'?)" if near else f" (expected one of {options})"
            raise InvalidParameterError(f"{label} '{value}' is not known{hint}")
    return value


def vector(value: Any, name: str, n: int, *, where: str = "") -> tuple[float, ...]:
    """Return ``value`` as a tuple of ``n`` finite floats, or refuse it.

    Examples
    --------
    >>> vector([1, 2.5], "site", 2)
    (1.0, 2.5)
    """
    if (not isinstance(value, (list, tuple, np.ndarray)) or len(value) != n
            or any(isinstance(x, (bool, np.bool_)) or not isinstance(x, _REAL) for x in value)
            or not all(math.isfinite(float(x)) for x in value)):
        raise InvalidParameterError(
            f"{_label(where, name)} must be a list of {n} finite numbers; got {value!r}")
    return tuple(float(x) for x in value)
