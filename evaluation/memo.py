"""Measure each DEM once per evaluation: a scoped cache of per-tile measurements.

The campaign's evaluation measures every layer of a stack several times over: its slope
distribution for the evidence tables and again for the realism checks, its Horn slope for
the distribution and again for the share steeper than repose, its period-2 ratio for the
slope curve and again for the per-layer table, its power spectrum for the evidence and again
for the smoothness check. Inside :func:`measured_once`, :func:`once`
computes each such measurement of a tile the first time it is asked for and returns that
same result afterwards; outside it, :func:`once` simply computes. A result is keyed by the
tile object itself (kept alive with it), never by its contents, so a tile never gets another
tile's figures, and the results are the very ones the uncached calls return.
"""

from __future__ import annotations

from collections.abc import Callable, Hashable, Iterator
from contextlib import contextmanager
from typing import Any

__all__ = ["horn_slope_of", "measured_once", "once", "radial_spectrum_of",
           "slope_distribution_of"]

_active: list[dict] = []


@contextmanager
def measured_once() -> Iterator[None]:
    """Within the block, each measurement of a tile asked for through :func:`once` is made once.

    Examples
    --------
    >>> calls = []
    >>> tile = object()
    >>> with measured_once():
    ...     a = once("area", tile, None, lambda: calls.append(1) or 4.0)
    ...     b = once("area", tile, None, lambda: calls.append(1) or 4.0)
    >>> a, b, len(calls)
    (4.0, 4.0, 1)
    """
    _active.append({})
    try:
        yield
    finally:
        _active.pop()


def once(kind: str, tile: Any, key: Hashable, compute: Callable[[], Any]) -> Any:
    """Return ``compute()``, computed once per (``kind``, ``tile``, ``key``) in the scope.

    Parameters
    ----------
    kind : str
        The measurement (``"horn_slope"``, ``"slope_distribution"``, ...).
    tile : object
        What is measured (identity, not equality, decides a hit).
    key : hashable
        The measurement's other arguments.
    compute : callable
        Makes the measurement.

    Returns
    -------
    object
        What ``compute`` returned (the first time, in the scope).
    """
    if not _active:
        return compute()
    cache = _active[-1]
    k = (kind, id(tile), key)
    hit = cache.get(k)
    if hit is not None and hit[0] is tile:
        return hit[1]
    value = compute()
    cache[k] = (tile, value)
    return value


def horn_slope_of(tile, edges: str = "mask"):
    """Return :func:`evaluation.slope.horn_slope` of a tile, once per scope (read-only)."""
    from evaluation.slope import horn_slope

    def compute():
        s = horn_slope(tile, edges=edges)
        s.flags.writeable = False  # shared by every caller in the scope
        return s

    return once("horn_slope", tile, edges, compute)


def slope_distribution_of(tile, label: str = "", edges: str = "mask"):
    """Return :func:`evaluation.slope.slope_distribution` of a tile, once per scope."""
    from evaluation.slope import slope_distribution

    return once("slope_distribution", tile, (label, edges),
                lambda: slope_distribution(tile, label=label, edges=edges,
                                           slopes=horn_slope_of(tile, edges)))


def radial_spectrum_of(tile, label: str = ""):
    """Return :func:`evaluation.spectrum.radial_spectrum` of a tile (its defaults), once per scope.

    The evidence tables and the realism's smoothness check both ask for a layer's spectrum;
    the second gets the first's numbers (read-only) under its own label. The label only
    names the record and the warning about gaps, which is logged the first time only.

    Examples
    --------
    >>> from evaluation.spectrum import fractional_brownian_surface
    >>> tile = fractional_brownian_surface(64, 0.8, seed=1)
    >>> with measured_once():
    ...     a, b = radial_spectrum_of(tile, "layer 0"), radial_spectrum_of(tile)
    >>> a.power is b.power, a.label, b.label
    (True, 'layer 0', '')
    """
    from dataclasses import replace

    from evaluation.spectrum import radial_spectrum

    def compute():
        spec = radial_spectrum(tile, label=label)
        for a in (spec.frequency, spec.power, spec.counts):
            a.flags.writeable = False  # shared by every caller in the scope
        return spec

    spec = once("radial_spectrum", tile, None, compute)
    return spec if spec.label == label else replace(spec, label=label)
