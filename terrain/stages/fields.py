"""The fields of a stage spec: a default, a help line and a kind that converts and checks.

A stage spec (:mod:`terrain.stages.specs`) declares each field once with :func:`option`; the
spec's ``from_mapping`` converts values with the field's kind (through the one family of checks,
:mod:`terrain.core.checks`), and the command line builds its options from the same fields
(:mod:`terrain.cli.options`), so a field's name, default, type and help live in one place.
"""

from __future__ import annotations

import contextlib
import contextvars
import dataclasses
import os
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any, ClassVar

from terrain.core import checks
from terrain.core.errors import InvalidParameterError
from terrain.core.tile import Window

__all__ = ["FLAG", "OUTPUT_PATH", "PAIR", "PATH", "REQUIRED", "WINDOW", "Kind", "Spec",
           "choice", "integer", "named_as_options", "number", "option", "text"]

#: Whether fields are named as command-line options (``--layer-size``) in messages.
_AS_OPTIONS: contextvars.ContextVar[bool] = contextvars.ContextVar("as_options", default=False)


@dataclasses.dataclass(frozen=True)
class Kind:
    """How one field's value is converted and checked, and what the command line shows.

    Parameters
    ----------
    cli : str
        The click parameter kind: ``int``, ``float``, ``flag``, ``text``, ``choice``,
        ``path``, ``pair`` or ``window``.
    bounds : mapping
        Keyword arguments of the check (``low``, ``high``, ``low_open``, ``choices``).
    """

    cli: str
    bounds: Mapping[str, Any] = dataclasses.field(default_factory=dict)

    def convert(self, value: Any, label: str) -> Any:
        """Return ``value`` converted, or raise naming ``label`` (None stays None)."""
        if value is None:
            return None
        if self.cli == "int":
            return checks.integer(value, label, **self.bounds)
        if self.cli == "float":
            return checks.number(value, label, **self.bounds)
        if self.cli == "flag":
            return checks.boolean(value, label)
        if self.cli in ("text", "choice"):
            return checks.text(value, label, **self.bounds)
        if self.cli == "pair":
            return checks.vector(value, label, 2)
        if self.cli == "path":
            if not isinstance(value, (str, os.PathLike)) or not str(value):
                raise InvalidParameterError(f"{label} must be a file path; got {value!r}")
            return Path(value)
        return _window(value, label)


def _window(value: Any, label: str) -> Window:
    if isinstance(value, Window):
        return value
    if isinstance(value, str):
        return Window.parse(value)
    if isinstance(value, (list, tuple)) and len(value) == 4:
        return Window(*(checks.integer(v, label) for v in value))
    raise InvalidParameterError(f"{label} must be COL,ROW,WIDTH,HEIGHT; got {value!r}")


def integer(**bounds: Any) -> Kind:
    """Return an integer field's kind, checked against ``low``/``high``."""
    return Kind("int", bounds)


def number(**bounds: Any) -> Kind:
    """Return a finite float field's kind, checked against ``low``/``high`` (open where asked)."""
    return Kind("float", bounds)


def choice(*choices: str) -> Kind:
    """Return the kind of a text field that must be one of ``choices``."""
    return Kind("choice", {"choices": choices})


def text() -> Kind:
    """Return the kind of a free text field."""
    return Kind("text")


#: A boolean field (a command-line flag).
FLAG = Kind("flag")
#: A file path (an input the stage reads, or a companion output).
PATH = Kind("path")
#: A file path the stage writes beside its output (a companion picture).
OUTPUT_PATH = Kind("path", {"output": True})
#: Two finite numbers X,Y.
PAIR = Kind("pair")
#: A pixel window COL,ROW,WIDTH,HEIGHT (:class:`terrain.core.tile.Window`).
WINDOW = Kind("window")

#: Marks a field with no default: a table must give it.
REQUIRED = dataclasses.MISSING


def option(default: Any, help: str, kind: Kind) -> Any:  # noqa: A002 - click's word
    """Declare a spec field: its default (:data:`REQUIRED` for none), help line and kind."""
    meta = {"help": help, "kind": kind}
    if default is REQUIRED:
        return dataclasses.field(metadata=meta)
    return dataclasses.field(default=default, metadata=meta)


@contextlib.contextmanager
def named_as_options() -> Iterator[None]:
    """Inside the block, specs name their fields as command-line options in messages."""
    token = _AS_OPTIONS.set(True)
    try:
        yield
    finally:
        _AS_OPTIONS.reset(token)


class Spec:
    """Base of the frozen stage specs: conversion, checks and ``from_mapping`` in one place.

    A subclass is a frozen keyword-only dataclass whose fields come from :func:`option`; it
    sets ``STAGE`` (its name in messages) and may add cross-field checks in ``_check``.
    """

    STAGE: ClassVar[str] = ""

    @classmethod
    def label(cls, name: str) -> str:
        """Return how field ``name`` is named in messages (``--layer-size`` on the command line)."""
        return "--" + name.replace("_", "-") if _AS_OPTIONS.get() else name

    @classmethod
    def defaults(cls) -> dict[str, Any]:
        """Return the table of defaults: every field that has one."""
        return {f.name: f.default for f in dataclasses.fields(cls)  # type: ignore[arg-type]
                if f.default is not dataclasses.MISSING}

    @classmethod
    def from_mapping(cls, table: Mapping[str, Any]) -> Any:
        """Return the spec of a table (TOML, JSON, keyword options), checked.

        Parameters
        ----------
        table : mapping
            Field names (the command's long options with ``-`` as ``_``) and values; a missing
            field takes its default.

        Returns
        -------
        Spec
            The frozen spec.

        Raises
        ------
        InvalidParameterError
            An unknown key (named with the nearest valid one), a missing required field, or a
            value of the wrong type or out of range.
        """
        names = [f.name for f in dataclasses.fields(cls)]  # type: ignore[arg-type]
        table = checks.check_keys(table, names, f"terrain {cls.STAGE}")
        defaults = cls.defaults()
        missing = [n for n in names if n not in table and n not in defaults]
        if missing:
            raise InvalidParameterError(f"terrain {cls.STAGE} needs {cls.label(missing[0])}")
        return cls(**table)

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):  # type: ignore[arg-type]
            value = f.metadata["kind"].convert(getattr(self, f.name), self.label(f.name))
            object.__setattr__(self, f.name, value)
        self._check()

    def _check(self) -> None:
        """Cross-field checks of a subclass (none here)."""

    def reads(self) -> list[Path]:
        """Return the files the spec names for the stage to read (never to be written)."""
        return [getattr(self, f.name) for f in dataclasses.fields(self)  # type: ignore[arg-type]
                if f.metadata["kind"].cli == "path" and not f.metadata["kind"].bounds
                and getattr(self, f.name) is not None]

    def as_dict(self) -> dict[str, Any]:
        """Return the fields as plain data (paths and windows as text), for metadata."""
        out = {}
        for f in dataclasses.fields(self):  # type: ignore[arg-type]
            value = getattr(self, f.name)
            if isinstance(value, Path):
                value = str(value)
            elif isinstance(value, Window):
                value = [value.col, value.row, value.width, value.height]
            out[f.name] = value
        return out
