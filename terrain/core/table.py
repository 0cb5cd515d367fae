r"""Tables of typed, equal-length, read-only columns, and their CSV form.

:class:`ColumnTable` is what every catalogue record shares (terrain's crater and rock
catalogues, the asteroid's crater and boulder catalogues): a frozen dataclass whose fields are
its columns, built from a mapping of columns that refuses an unknown column by name
(:meth:`ColumnTable.from_columns`), written and read as CSV (:meth:`ColumnTable.to_csv`,
:meth:`ColumnTable.from_csv`), joined and selected.

>>> import io
>>> buf = io.StringIO()
>>> write_table(buf, {"id": np.array([255], np.uint64), "diameter_m": np.array([12.5])},
...             ("id", "diameter_m"), line_end="\n")
>>> buf.getvalue().splitlines()
['id,diameter_m', '00000000000000ff,12.5']
"""

from __future__ import annotations

import contextlib
import csv
import io
import math
import os
from collections.abc import Iterable, Iterator, Mapping, Sequence
from typing import IO, ClassVar, TypeVar

import numpy as np

from terrain.core.checks import reject_unknown
from terrain.core.errors import InvalidParameterError

__all__ = ["ColumnTable", "csv_sink", "read_table", "write_table"]

TableT = TypeVar("TableT", bound="ColumnTable")


class ColumnTable:
    """What a catalogue record shares: equal-length, typed, read-only columns, and CSV.

    A subclass is a frozen dataclass whose fields are its columns (named as in the CSV) and
    says which they are in :attr:`COLUMNS` (required, in CSV order), :attr:`OPTIONAL`
    (trailing columns a table may lack; None then) and :attr:`DTYPES` (the columns that are
    not float64). Its ``__post_init__`` calls :meth:`_freeze_columns` and then checks values.
    """

    #: Required columns, in CSV order.
    COLUMNS: ClassVar[tuple[str, ...]] = ()
    #: Trailing columns a table may lack (None when absent).
    OPTIONAL: ClassVar[tuple[str, ...]] = ()
    #: Columns that are not float64, and their dtypes.
    DTYPES: ClassVar[Mapping[str, type]] = {}
    #: What the table is called in messages.
    WHAT: ClassVar[str] = "table"
    #: Columns written with a fixed format (``str.format`` of the float), e.g. ``"{:.3f}"``.
    FORMATS: ClassVar[Mapping[str, str]] = {}
    #: Line ending of the CSV.
    LINE_END: ClassVar[str] = "\r\n"

    def _freeze_columns(self) -> None:
        """Convert every present column to a read-only 1-D array of its dtype, equal lengths."""
        n = None
        for name in self.columns:
            dtype = self.DTYPES.get(name, np.float64)
            try:
                a: np.ndarray = np.array(getattr(self, name), dtype=dtype, copy=True)
            except (TypeError, ValueError, OverflowError) as exc:
                raise InvalidParameterError(
                    f"{self.WHAT} column {name} must be {np.dtype(dtype).name}: {exc}") from None
            if a.ndim != 1:
                raise InvalidParameterError(
                    f"{self.WHAT} column {name} must be one-dimensional; got shape {a.shape}")
            if n is None:
                n = a.size
            elif a.size != n:
                raise InvalidParameterError(
                    f"{self.WHAT} column {name} has {a.size} rows; expected {n}")
            a.flags.writeable = False
            object.__setattr__(self, name, a)

    @property
    def columns(self) -> tuple[str, ...]:
        """The column names, in CSV order (optional ones only when present)."""
        return self.COLUMNS + tuple(k for k in self.OPTIONAL if getattr(self, k) is not None)

    def __len__(self) -> int:
        return int(getattr(self, self.COLUMNS[0]).size)

    @classmethod
    def empty(cls: type[TableT], *, optional: Iterable[str] = ()) -> TableT:
        """Return a table without rows.

        Parameters
        ----------
        optional : iterable of str
            The optional columns it has.

        Returns
        -------
        ColumnTable
            Of the class it is called on.
        """
        names = cls.COLUMNS + tuple(optional)
        return cls(**{name: np.zeros(0, cls.DTYPES.get(name, np.float64)) for name in names})

    @classmethod
    def from_columns(cls: type[TableT], columns: Mapping[str, object]) -> TableT:
        """Return the table of a mapping of column arrays (the old dict form).

        Parameters
        ----------
        columns : mapping of str to (n,) array_like
            Every column of :attr:`COLUMNS`, and optionally those of :attr:`OPTIONAL`.

        Returns
        -------
        ColumnTable
            Of the class it is called on.

        Raises
        ------
        InvalidParameterError
            A column is missing, unknown (named, with the nearest valid name) or invalid.
        """
        known = cls.COLUMNS + cls.OPTIONAL
        reject_unknown(columns, known, cls.WHAT, "column")
        missing = [name for name in cls.COLUMNS if name not in columns]
        if missing:
            raise InvalidParameterError(f"{cls.WHAT} is missing columns {missing}")
        return cls(**{name: np.asarray(value) for name, value in columns.items()})

    def as_dict(self) -> dict[str, np.ndarray]:
        """Return the columns as a dict of read-only arrays, in CSV order."""
        return {name: getattr(self, name) for name in self.columns}

    def take(self: TableT, index: np.ndarray | slice) -> TableT:
        """Return the rows selected by ``index``.

        Parameters
        ----------
        index : (m,) int array, (n,) bool mask or slice
            The rows, in the order wanted.

        Returns
        -------
        ColumnTable
            Of the same class and columns.
        """
        return type(self)(**{name: getattr(self, name)[index] for name in self.columns})

    def with_columns(self: TableT, **columns: np.ndarray) -> TableT:
        """Return the table with some columns replaced or added (checked as when built).

        Parameters
        ----------
        **columns : (n,) array_like
            New values of columns, by name.

        Returns
        -------
        ColumnTable
            Of the same class.
        """
        return type(self).from_columns({**self.as_dict(), **columns})

    @classmethod
    def concatenate(cls: type[TableT], tables: Iterable[TableT], *,
                    optional: Iterable[str] = ()) -> TableT:
        """Return one table of the rows of ``tables``, in order.

        Parameters
        ----------
        tables : iterable of ColumnTable
            All with the same columns.
        optional : iterable of str
            The optional columns of an empty result (with tables, theirs decide).

        Returns
        -------
        ColumnTable
            Of the class it is called on.

        Raises
        ------
        InvalidParameterError
            The tables' columns differ.
        """
        tables = list(tables)
        if not tables:
            return cls.empty(optional=optional)
        names = tables[0].columns
        if any(t.columns != names for t in tables):
            raise InvalidParameterError(
                f"cannot join {cls.WHAT}s with different columns: "
                f"{sorted({t.columns for t in tables})}")
        return cls(**{name: np.concatenate([getattr(t, name) for t in tables])
                      for name in names})

    def to_csv(self, path_or_file: str | os.PathLike | IO[str]) -> None:
        """Write the table as CSV (the header :attr:`columns`, one line per row).

        Parameters
        ----------
        path_or_file : path or text file
            Where to write (a path is opened and closed here; write through
            :func:`terrain.core.outputs.atomic_path` to commit it atomically).
        """
        write_table(path_or_file, self.as_dict(), self.columns, formats=self.FORMATS,
                    line_end=self.LINE_END)

    @classmethod
    def from_csv(cls: type[TableT], path: str | os.PathLike) -> TableT:
        """Read a CSV written by :meth:`to_csv`.

        Parameters
        ----------
        path : path
            The CSV.

        Returns
        -------
        ColumnTable
            Of the class it is called on.

        Raises
        ------
        InvalidParameterError
            The file's columns or values are not the table's (the message names the file).
        """
        try:
            return cls.from_columns(read_table(path, cls.DTYPES))
        except ValueError as exc:
            raise InvalidParameterError(f"{cls.WHAT} '{path}': {exc}") from None


@contextlib.contextmanager
def csv_sink(path_or_file: str | os.PathLike | IO[str]) -> Iterator[IO[str]]:
    """Yield a text file for a CSV writer.

    Parameters
    ----------
    path_or_file : path or text file
        A file (anything with ``write``) is yielded itself; a path is opened for writing
        and closed afterwards.

    Yields
    ------
    text file
    """
    if not isinstance(path_or_file, (str, os.PathLike)):
        yield path_or_file
        return
    with open(path_or_file, "w", newline="", encoding="utf-8") as f:
        yield f


def write_table(path_or_file: str | os.PathLike | IO[str], columns: Mapping[str, object],
                order: Sequence[str], *, formats: Mapping[str, str] | None = None,
                line_end: str = "\r\n") -> None:
    """Write equal-length columns as CSV, the way every craterscape catalogue is.

    ``id`` is written as 16 hex digits, columns named in ``formats`` with their format,
    integer and boolean columns as integers, other numbers at full precision (``repr``) and
    non-finite numbers empty.

    Parameters
    ----------
    path_or_file : path or text file
        Where to write.
    columns : mapping of str to (n,) array_like
        The columns (at least those named by ``order``).
    order : sequence of str
        The header, in order.
    formats : mapping of str to str, optional
        ``str.format`` patterns of some columns' values (as floats).
    line_end : str, optional
        The line ending.

    Raises
    ------
    InvalidParameterError
        A column of ``order`` is missing or the columns' lengths differ.
    """
    formats = formats or {}
    missing = [name for name in order if name not in columns]
    if missing:
        raise InvalidParameterError(f"catalogue is missing columns {missing}")
    cols = [np.asarray(columns[name]) for name in order]
    n = len(cols[0]) if cols else 0
    for name, col in zip(order, cols, strict=True):
        if len(col) != n:
            raise InvalidParameterError(
                f"catalogue column {name} has {len(col)} rows; expected {n}")
    with csv_sink(path_or_file) as f:
        writer = csv.writer(f, lineterminator=line_end)
        writer.writerow(order)
        for i in range(n):
            row = []
            for name, col in zip(order, cols, strict=True):
                v = col[i]
                if name == "id":
                    row.append(f"{int(v):016x}")
                elif name in formats:
                    row.append(formats[name].format(float(v)))
                elif col.dtype.kind in "iub":
                    row.append(str(int(v)))
                else:
                    x = float(v)
                    row.append(repr(x) if math.isfinite(x) else "")
            writer.writerow(row)


def read_table(path: str | os.PathLike,
               dtypes: Mapping[str, type] | None = None) -> dict[str, np.ndarray]:
    """Read a CSV written by :func:`write_table` into column arrays.

    Parameters
    ----------
    path : path
        The CSV.
    dtypes : mapping of str to dtype, optional
        Integer columns, read as integers (``id`` is always read from hex as uint64); every
        other column is float64 (NaN where empty).

    Returns
    -------
    dict of str to (n,) array
        In the file's column order.

    Raises
    ------
    ValueError
        A value is not a number, or a row has more or fewer values than the header.

    Notes
    -----
    The file is split and its columns converted as arrays (no Python work per value); a
    file with quoted fields goes through the csv module.
    """
    dtypes = dtypes or {}
    with open(path, newline="", encoding="utf-8") as f:
        text = f.read()
    if '"' in text:
        return _read_quoted(text, dtypes)
    lines = text.splitlines()
    names = lines[0].split(",") if lines and lines[0] else []
    fast = _read_fast(lines, names, dtypes)
    if fast is not None:
        return fast
    rows = [line for line in lines[1:] if line]  # as the csv module, skip blank lines
    cells = np.array(",".join(rows).split(",") if rows else [], dtype=str)
    if cells.size != len(rows) * len(names):
        for number, line in enumerate(lines[1:], 2):
            if line and line.count(",") != len(names) - 1:
                raise ValueError(f"line {number} has {line.count(',') + 1} values; "
                                 f"expected {len(names)}")
    table = cells.reshape(len(rows), len(names))
    return {name: _parse_column(name, table[:, k], dtypes) for k, name in enumerate(names)}


def _read_fast(lines: list[str], names: list[str],
               dtypes: Mapping[str, type]) -> dict[str, np.ndarray] | None:
    """:func:`read_table` by NumPy's C parser, or None where it cannot (an empty value)."""
    if not names or len(lines) < 2 or len(set(names)) != len(names):
        return None
    # integer columns are read as text and converted here: NumPy's parser takes "1.5" for an
    # integer with only a DeprecationWarning, and turning that into an error would need a
    # warnings filter, which is process-wide: catalogues are read on several threads at once
    # (terrain.stack.store), and one thread's "error" filter would raise another's warnings
    fields = [(name, "<U17" if name == "id" else
               "<U32" if np.dtype(dtypes.get(name, np.float64)).kind in "iub" else
               np.dtype(np.float64)) for name in names]
    try:
        table = np.loadtxt(lines[1:], delimiter=",", dtype=fields, ndmin=1,
                           comments=None, encoding=None)
    except (ValueError, TypeError):
        return None
    out = {}
    for name in names:
        if name == "id":
            out[name] = _parse_hex(table[name])
        elif table.dtype[name].kind == "U":
            try:
                out[name] = table[name].astype(np.int64).astype(dtypes[name])
            except (ValueError, OverflowError):
                return None  # the csv path names the value
        else:
            out[name] = np.ascontiguousarray(table[name])
    return out


def _parse_column(name: str, values: np.ndarray, dtypes: Mapping[str, type]) -> np.ndarray:
    """One column of strings as numbers (see :func:`read_table`), at once."""
    kind = np.dtype(dtypes.get(name, np.float64)).kind
    if name == "id":
        return _parse_hex(values)
    if kind in "iub":
        try:
            return values.astype(np.int64).astype(dtypes[name])
        except ValueError:
            bad = next(v for v in values if not v.strip().lstrip("+-").isdigit())
            raise ValueError(f"invalid literal for int() with base 10: {bad!r}") from None
    return np.where(values == "", "nan", values).astype(np.float64)


#: Unicode code points of hexadecimal digits (and what they stand for).
_HEX_CODES = np.full(128, 255, dtype=np.uint64)
_HEX_CODES[np.frombuffer(b"0123456789abcdef", np.uint8)] = np.arange(16, dtype=np.uint64)
_HEX_CODES[np.frombuffer(b"ABCDEF", np.uint8)] = np.arange(10, 16, dtype=np.uint64)


def _parse_hex(values: np.ndarray) -> np.ndarray:
    """Ids of 16 hexadecimal digits as uint64, at once (other lengths one by one)."""
    if not values.size:
        return np.zeros(0, dtype=np.uint64)
    if not np.all(np.char.str_len(values) == 16):
        return np.array([int(v, 16) for v in values], dtype=np.uint64)
    codes = values.astype("<U16").view(np.uint32).reshape(-1, 16)
    digits = _HEX_CODES[np.minimum(codes, 127)]
    if np.any(digits == 255):
        bad = values[np.any(digits == 255, axis=1)][0]
        raise ValueError(f"invalid literal for int() with base 16: {bad!r}")
    shifts = np.arange(60, -4, -4, dtype=np.uint64)
    return np.bitwise_or.reduce(digits << shifts, axis=1).astype(np.uint64)


def _read_quoted(text: str, dtypes: Mapping[str, type]) -> dict[str, np.ndarray]:
    """:func:`read_table` of a CSV with quoted fields, through the csv module."""
    reader = csv.reader(io.StringIO(text, newline=""))
    rows = [row for row in reader if row]
    names = rows[0] if rows else []
    for number, row in enumerate(rows[1:], 2):
        if len(row) != len(names):
            raise ValueError(f"row {number} has {len(row)} values; expected {len(names)}")
    table = np.array(rows[1:], dtype=str).reshape(len(rows) - 1 if rows else 0, len(names))
    return {name: _parse_column(name, table[:, k], dtypes) for k, name in enumerate(names)}
