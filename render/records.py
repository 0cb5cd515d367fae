"""Checking the tables that build frozen records (a sensor, Hapke parameters, motion).

Every record that a scenario file or a server request fills is built by a ``from_mapping``
classmethod that calls :func:`check_keys` first, so an unknown key is an error naming the key and
the nearest valid one, and :func:`number` to convert and range-check each value.
"""

from __future__ import annotations

import difflib
import math

import numpy as np

from terrain.core.errors import InvalidParameterError

__all__ = ["check_keys", "number"]


def check_keys(mapping, allowed, where: str) -> dict:
    """Return ``mapping`` as a dict, or refuse its first unknown key naming the nearest match.

    >>> check_keys({"gain": 2.0}, {"gain", "bias"}, "[sensor]")
    {'gain': 2.0}
    """
    if not isinstance(mapping, dict):
        raise InvalidParameterError(
            f"{where} must be a table of keys; got {type(mapping).__name__}")
    for key in mapping:
        if key not in allowed:
            near = difflib.get_close_matches(str(key), sorted(allowed), n=1)
            hint = (f"; did you mean {near[0]!r}?" if near
                    else f"; expected one of {sorted(allowed)}")
            raise InvalidParameterError(f"{where} has an unknown key {key!r}{hint}")
    return dict(mapping)


def number(value, name: str, *, low=None, high=None, low_open=False, where: str = "") -> float:
    """``value`` as a finite float in [low, high] (``low_open``: strictly above low)."""
    label = f"{where} {name}".strip()
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer,
                                                                      np.floating)):
        raise InvalidParameterError(f"{label} must be a number; got {value!r}")
    v = float(value)
    if not math.isfinite(v):
        raise InvalidParameterError(f"{label} must be finite; got {v}")
    if low is not None and (v < low or (low_open and v == low)):
        op = ">" if low_open else ">="
        raise InvalidParameterError(f"{label} must be {op} {low}; got {v}")
    if high is not None and v > high:
        raise InvalidParameterError(f"{label} must be <= {high}; got {v}")
    return v
