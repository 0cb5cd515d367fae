"""Exceptions of the asteroid stage (the shared ones live in :mod:`terrain.core.errors`).

Each also inherits the builtin a caller would catch; the command line turns any
:class:`~terrain.core.errors.CraterscapeError` into one line on stderr and exit code 2.
"""

from __future__ import annotations

from terrain.core.errors import CraterscapeError

__all__ = ["InvalidShapeError"]


class InvalidShapeError(CraterscapeError, ValueError):
    """A shape model cannot be used: unreadable, not a closed surface, or not around its centre."""
