"""What every ``craterscape`` command group shares: parameter types, the version, progress.

The stage groups (:mod:`terrain.cli.commands`, :mod:`asteroid.cli`, :mod:`render.cli`,
:mod:`evaluation.cli`) take their click parameter types, the package version they record in
outputs and their progress bars from here, so a new command gets the same refusals and
display as the others. It lives in ``terrain``, the lowest layer, so every group may import it;
it imports nothing heavy (numpy, tqdm and the stage modules are imported when used).
"""

from __future__ import annotations

import contextlib
import math
import sys
from collections.abc import Callable, Iterator
from typing import Any

import click

from terrain.core.errors import InvalidParameterError
from terrain.core.metakeys import version
from terrain.core.progress import Progress

__all__ = ["FINITE", "PAIR", "TRIPLE", "WINDOW", "ImageSizeType", "progress_bar", "version",
           "version_option", "with_options"]


class _FiniteFloat(click.ParamType):
    """A float that is a number: NaN and infinity are refused with the option's name."""

    name = "float"

    def convert(self, value: Any, param: click.Parameter | None,
                ctx: click.Context | None) -> float:
        """Return the finite float ``value`` names, or fail with a usage error (exit 2)."""
        if isinstance(value, float) and math.isfinite(value):
            return value
        try:
            number = float(value)
        except (TypeError, ValueError):
            self.fail(f"{value!r} is not a number", param, ctx)
        if not math.isfinite(number):
            self.fail(f"must be a finite number; got {value!r}", param, ctx)
        return number


class _WindowType(click.ParamType):
    """A pixel window ``COL,ROW,WIDTH,HEIGHT`` (:class:`terrain.core.tile.Window`)."""

    name = "COL,ROW,WIDTH,HEIGHT"

    def convert(self, value: Any, param: click.Parameter | None,
                ctx: click.Context | None) -> Any:
        """Return the :class:`~terrain.core.tile.Window` ``value`` names, or fail (exit 2)."""
        from terrain.core.tile import Window

        if value is None or isinstance(value, Window):
            return value
        try:
            return Window.parse(value)
        except InvalidParameterError as exc:
            self.fail(str(exc), param, ctx)


class _NumbersType(click.ParamType):
    """``n`` finite numbers separated by commas, e.g. ``X,Y`` or ``X,Y,Z``."""

    def __init__(self, names: tuple[str, ...]) -> None:
        self.names = names
        self.name = ",".join(names)

    def convert(self, value: Any, param: click.Parameter | None,
                ctx: click.Context | None) -> tuple[float, ...]:
        """Return the tuple of floats ``value`` names, or fail with a usage error (exit 2)."""
        if isinstance(value, tuple):
            return value
        n = len(self.names)
        words = {2: "two", 3: "three"}.get(n, str(n))
        parts = str(value).split(",")
        try:
            if len(parts) != n:
                raise ValueError
            numbers = tuple(float(p) for p in parts)
        except ValueError:
            self.fail(self._expected(words, "", value), param, ctx)
        if not all(math.isfinite(v) for v in numbers):
            self.fail(self._expected(words, "finite ", value), param, ctx)
        return numbers

    def _expected(self, words: str, finite: str, value: Any) -> str:
        return f"expected {words} {finite}numbers {self.name}; got {value!r}"


class ImageSizeType(click.ParamType):
    """An image size ``WIDTHxHEIGHT`` in pixels, each side at most a limit.

    Parameters
    ----------
    largest_side : callable
        Returns the largest side allowed (called when a value is converted, so the command
        module need not import the stage that defines it).
    """

    name = "WxH"

    def __init__(self, largest_side: Callable[[], int]) -> None:
        self.largest_side = largest_side

    def convert(self, value: Any, param: click.Parameter | None,
                ctx: click.Context | None) -> tuple[int, int]:
        """Return the ``(width, height)`` ``value`` names, or fail with a usage error."""
        if isinstance(value, tuple):
            return value
        try:
            w, h = (int(v) for v in str(value).lower().split("x"))
            if w < 1 or h < 1:
                raise ValueError
        except ValueError:
            self.fail(f"expected WIDTHxHEIGHT such as 1024x1024; got {value!r}", param, ctx)
        largest = self.largest_side()
        if max(w, h) > largest:
            self.fail(f"{w}x{h} is larger than the largest image side, {largest} pixels",
                      param, ctx)
        return w, h


#: A finite float (every float option of every command is made this one by terrain.cli.commands).
FINITE = _FiniteFloat()
#: A pixel window COL,ROW,WIDTH,HEIGHT.
WINDOW = _WindowType()
#: Two finite numbers X,Y (a map position, a lon/lat pair).
PAIR = _NumbersType(("X", "Y"))
#: Three finite numbers X,Y,Z (a body-frame position).
TRIPLE = _NumbersType(("X", "Y", "Z"))


def with_options(options: list) -> Callable[[Any], Any]:
    """Return a decorator that adds a group of click options to a command, in list order.

    Parameters
    ----------
    options : list of click option decorators
        As ``click.option(...)`` returns them; they appear in ``--help`` in this order.

    Returns
    -------
    callable
        The decorator.
    """
    def decorate(func: Any) -> Any:
        for option in reversed(options):
            func = option(func)
        return func
    return decorate


#: ``--version`` of the root command.
version_option = click.version_option(package_name="craterscape")


@contextlib.contextmanager
def progress_bar(label: str, unit: str = "it", total: int | None = None
                 ) -> Iterator[Progress | None]:
    """Show a tqdm bar on a terminal; stay silent in pipes and tests.

    Parameters
    ----------
    label : str
        Shown before the bar.
    unit : str
        What one step is (``"chunk"``, ``"frame"``).
    total : int, optional
        Steps in all, when known before the first report.

    Yields
    ------
    Progress or None
        The callback to hand to a stage (``progress(done, total, detail)``; the detail is
        shown after the bar), or None when stderr is not a terminal.
    """
    if not sys.stderr.isatty():
        yield None
        return
    from tqdm import tqdm

    bar = tqdm(total=total, desc=label, unit=unit, leave=False)

    def update(done: int, total: int, detail: str = "") -> None:
        bar.total = total
        bar.n = done
        if detail:
            bar.set_postfix_str(detail, refresh=False)
        bar.refresh()

    try:
        yield update
    finally:
        bar.close()
