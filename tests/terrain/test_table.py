"""Catalogue CSV: read back exactly what was written, whichever parser reads it."""

from __future__ import annotations

import csv

import numpy as np
import pytest

from terrain.core.errors import InvalidParameterError
from terrain.core.table import read_table, write_table
from terrain.craters.catalog import CraterCatalog


def _by_csv_module(path, dtypes):
    """An independent reading: the csv module, one value at a time."""
    with open(path, newline="", encoding="utf-8") as f:
        rows = list(csv.DictReader(f))
    out = {}
    for name in rows[0]:
        values = [row[name] for row in rows]
        if name == "id":
            out[name] = np.array([int(v, 16) for v in values], dtype=np.uint64)
        elif name in dtypes:
            out[name] = np.array([int(v) for v in values], dtype=dtypes[name])
        else:
            out[name] = np.array([float(v) if v else np.nan for v in values])
    return out


@pytest.mark.parametrize("gap", [False, True])
def test_columns_read_back_bit_for_bit(tmp_path, gap):
    rng = np.random.default_rng(7)
    n = 500
    cols = {"id": rng.integers(0, 2**63, n, dtype=np.uint64) * np.uint64(2) + np.uint64(1),
            "diameter_m": rng.lognormal(3.0, 2.0, n), "x_m": rng.normal(0, 1e5, n),
            "layer": rng.integers(0, 15, n)}
    if gap:
        cols["diameter_m"][[3, 77]] = np.nan  # written empty: the slower path reads it
    path = tmp_path / "t.csv"
    write_table(path, cols, ("id", "diameter_m", "x_m", "layer"))
    got = read_table(path, {"layer": np.int16})
    want = _by_csv_module(path, {"layer": np.int16})
    assert list(got) == list(want)
    for name in want:
        assert got[name].dtype == want[name].dtype
        assert got[name].tobytes() == want[name].tobytes(), name
    assert got["id"].tobytes() == cols["id"].tobytes()


@pytest.mark.parametrize(("body", "words"), [
    ("1,2\n3\n", "line 3 has 1 values; expected 2"),
    ("1,2\n3,4,5\n", "line 3 has 3 values; expected 2"),
    ("1,2\nx,4\n", "could not convert"),
])
def test_a_bad_row_is_named(tmp_path, body, words):
    path = tmp_path / "bad.csv"
    path.write_text("x_m,y_m\n" + body)
    with pytest.raises(ValueError, match=words):
        read_table(path)


def test_a_bad_id_or_integer_is_refused_with_the_file(tmp_path):
    good = tmp_path / "good.csv"
    CraterCatalog.empty(optional=("layer",)).to_csv(good)
    header = good.read_text().splitlines()[0]
    n = len(header.split(","))
    for row in ("zz" + "0" * 14 + ",1" * (n - 2) + ",0", "0" * 16 + ",1" * (n - 2) + ",1.5"):
        bad = tmp_path / "bad.csv"
        bad.write_text(header + "\n" + row + "\n")
        with pytest.raises(InvalidParameterError, match="bad.csv"):
            CraterCatalog.from_csv(bad)


def test_reading_on_threads_leaves_every_warnings_filter_as_it_was(tmp_path):
    """Catalogues and sensor images are read on several threads at once (stacks, runs).

    ``warnings.catch_warnings`` puts back on exit the filter list it saw on entry, so two
    readers that overlap used to leave one's filter behind for the whole process: once an
    "error" filter of the table reader (a float in an integer column) outlived it, and a
    library's harmless PendingDeprecationWarning later stopped the demo's evaluation.
    """
    import threading
    import warnings

    from terrain.io import read_float_tiff, write_float_tiff

    table = tmp_path / "t.csv"
    write_table(table, {"x_m": np.arange(50.0), "layer": np.arange(50)}, ("x_m", "layer"))
    image = write_float_tiff(np.ones((8, 8), np.float32), tmp_path / "range.tif")
    before = list(warnings.filters)
    errors: list = []

    def work(k):
        try:
            for _ in range(40):
                if k % 2:
                    assert read_table(table, {"layer": np.int16})["layer"][-1] == 49
                else:
                    assert read_float_tiff(image).shape == (8, 8)
                # what another part of the process may say meanwhile: a warning, never an
                # exception
                warnings.warn("a library's notice", PendingDeprecationWarning, stacklevel=1)
        except BaseException as exc:  # noqa: BLE001 - reported below, whatever it is
            errors.append(exc)

    with warnings.catch_warnings():  # this test's own notices stay out of the report
        warnings.simplefilter("ignore", PendingDeprecationWarning)
        inside = list(warnings.filters)
        threads = [threading.Thread(target=work, args=(k,)) for k in range(6)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        assert warnings.filters == inside
    assert not errors, errors[0]
    assert warnings.filters == before
