"""The one progress callback signature every long-running stage takes.

A stage that reports progress takes ``progress: Progress | None`` and calls it as
``progress(done, total, detail)``: ``done`` units of ``total`` finished, and an optional
short text (a stage name such as ``"craters"``, or a rate such as ``"12.5 Mpixel/s"``).
Command-line bars (:func:`terrain.cli.tools.progress_bar`) and tests both take this shape,
so any stage's progress can be shown by any command.
"""

from __future__ import annotations

from typing import Protocol

__all__ = ["Progress"]


class Progress(Protocol):
    """Called after each unit of work: ``progress(done, total, detail)``."""

    def __call__(self, done: int, total: int, detail: str = "", /) -> None:
        """Report that ``done`` of ``total`` units are finished.

        Parameters
        ----------
        done : int
            Units finished so far (0 before the first).
        total : int
            Units in all.
        detail : str, optional
            What is running or how fast, for display only.
        """
