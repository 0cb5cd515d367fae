"""Exceptions shared by every craterscape stage.

Each exception also inherits the builtin a caller would naturally catch, so
``except ValueError`` keeps working (the pattern of rasterio's ``errors.py``). The command line
turns any :class:`CraterscapeError` into one line on stderr and exit code 2.
"""

from __future__ import annotations

__all__ = [
    "CraterscapeError",
    "GapTooLargeError",
    "InvalidDEMError",
    "InvalidParameterError",
    "MemoryRequestError",
    "MissingInputError",
    "OutputPathError",
    "reject_unknown",
]


class CraterscapeError(Exception):
    """Base class of every error craterscape raises on purpose."""


class InvalidParameterError(CraterscapeError, ValueError):
    """A parameter is out of range, of the wrong type or inconsistent with another."""


class InvalidDEMError(CraterscapeError, ValueError):
    """A DEM file or array cannot be used (corrupt, unreadable, all nodata, wrong shape)."""


class MissingInputError(CraterscapeError, FileNotFoundError):
    """An input file does not exist."""


class OutputPathError(CraterscapeError, ValueError):
    """An output path is unusable: it would overwrite an input or its folder is missing."""


class MemoryRequestError(CraterscapeError, MemoryError):
    """A request would need more memory than the machine has; refused before allocating."""


class GapTooLargeError(CraterscapeError, ValueError):
    """A gap does not fit inside a chunk's halo, so it cannot be filled chunk by chunk."""


def reject_unknown(keys, known, what: str, noun: str = "key") -> None:
    """Refuse the first of ``keys`` (in sorted order) not in ``known``, naming the nearest.

    The one check behind every ``from_mapping`` that rejects an unknown key by name.

    Parameters
    ----------
    keys : iterable of str
        The keys given (a table's keys, a file's columns).
    known : iterable of str
        The valid ones.
    what : str
        What they belong to, for the message ("rock", "crater morphology").
    noun : str, optional
        What one of them is called ("key", "column").

    Raises
    ------
    InvalidParameterError
        ``unknown {what} {noun} 'name' (did you mean 'nearest'?)``.

    Examples
    --------
    >>> reject_unknown({"dmin": 1, "dnsty": 2}, ["dmin", "density"], "rocks")
    Traceback (most recent call last):
    ...
    terrain.core.errors.InvalidParameterError: unknown rocks key 'dnsty' (did you mean 'density'?)
    """
    import difflib

    known = list(known)
    unknown = sorted(str(k) for k in keys if k not in known)
    if unknown:
        near = difflib.get_close_matches(unknown[0], known, n=1)
        hint = f" (did you mean '{near[0]}'?)" if near else ""
        raise InvalidParameterError(f"unknown {what} {noun} '{unknown[0]}'{hint}")
