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

