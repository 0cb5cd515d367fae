"""The crater catalogue as a frozen, validated table: CSV format, round trips, joins, checks."""

import dataclasses
import io
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from terrain.core.errors import InvalidParameterError
from terrain.core.tile import DEMTile, default_transform
from terrain.craters.catalog import (
    CATALOG_COLUMNS,
    CATALOG_LAYER_COLUMNS,
    ROCK_COLUMNS,
    CraterCatalog,
    CraterTable,
    RockCatalog,
)
from terrain.craters.cratering import add_craters
from terrain.craters.population import Population


def _catalog(n: int, *, layer=None, start: int = 0) -> CraterCatalog:
    """A catalogue of ``n`` made-up rows with distinct values in every column."""
    k = np.arange(start, start + n, dtype=float)
    cols = {name: k + i / 10 for i, name in enumerate(CATALOG_COLUMNS)}
    cols["id"] = np.arange(start, start + n, dtype=np.uint64) + np.uint64(2**63)
    cols["size_class"] = np.arange(start, start + n)
    cols["diameter_m"] = k + 1.0
    if layer is not None:
        cols["layer"] = np.full(n, layer)
    return CraterCatalog.from_columns(cols)


@pytest.fixture(scope="module")
def cratered():
    """A real cratering run: 129 x 129 pixels of 2 m, a few dozen craters."""
    heights = np.zeros((129, 129), np.float32)
    tile = DEMTile.from_array(heights, transform=default_transform(2.0, 129))
    pop = Population(dmin=4.0, dmax=60.0, density=3000.0, sfd_exponent=-2.0)
    return add_craters(tile, pop, seed=5)


def test_the_csv_is_what_the_header_promises():
    cat = CraterCatalog.from_columns({**_catalog(1).as_dict(),
                                      "reference_elevation_m": np.array([np.nan])})
    f = io.StringIO()
    cat.to_csv(f)
    header, line, end = f.getvalue().split("\r\n")
    assert header.split(",") == list(CATALOG_COLUMNS) and end == ""
    values = dict(zip(CATALOG_COLUMNS, line.split(","), strict=True))
    assert values["id"] == "8000000000000000"                  # 16 hex digits
    assert values["row"] == "0.300" and values["col"] == "0.400"  # pixels, 3 decimals
    assert values["size_class"] == "0"                          # an integer
    assert values["x_m"] == "0.1" and values["diameter_m"] == "1.0"  # shortest exact float
    assert values["reference_elevation_m"] == ""                # not a number: empty


def test_a_real_catalogue_survives_its_csv(cratered, tmp_path):
    cat = cratered.catalog
    assert len(cat) > 10
    path = tmp_path / "craters.csv"
    cat.to_csv(path)
    back = CraterCatalog.from_csv(path)
    assert back.columns == CATALOG_COLUMNS and len(back) == len(cat)
    for name in CATALOG_COLUMNS:
        a, b = getattr(cat, name), getattr(back, name)
        assert a.dtype == b.dtype, name
        if name in ("row", "col"):
            assert np.allclose(a, b, atol=5e-4, rtol=0), name
        else:
            assert np.array_equal(a, b), name
    again = tmp_path / "again.csv"
    back.to_csv(again)
    assert again.read_bytes() == path.read_bytes()


def test_the_catalogue_agrees_with_the_craters_it_describes(cratered):
    cat = cratered.catalog
    t = cratered.tile.transform
    # row and col are the centre in the tile's pixel grid (pixel centres whole numbers)
    assert np.allclose(cat.col, (cat.x_m - t.c) / t.a - 0.5)
    assert np.allclose(cat.row, (t.f - cat.y_m) / -t.e - 0.5)
    # composition order: larger classes first, then the oldest
    key = np.lexsort((cat.id, -cat.age_gyr, -cat.size_class))
    assert np.array_equal(key, np.arange(len(cat)))
    # a size class is an octave of diameters, and a larger class holds larger craters
    classes = np.unique(cat.size_class)
    assert len(classes) > 1
    spans = [(cat.diameter_m[cat.size_class == c].min(), cat.diameter_m[cat.size_class == c].max())
             for c in classes]
    assert all(hi <= 2 * lo for lo, hi in spans)
    assert all(a[1] <= b[0] for a, b in zip(spans[:-1], spans[1:], strict=True))


def test_a_catalogue_is_frozen(cratered):
    cat = cratered.catalog
    with pytest.raises(dataclasses.FrozenInstanceError):
        cat.id = cat.id[:1]  # type: ignore[misc]
    with pytest.raises(ValueError, match="read-only"):
        cat.depth_m[0] = 0.0
    source = np.arange(3.0) + 1
    made = CraterCatalog.from_columns({**_catalog(3).as_dict(), "diameter_m": source})
    source[0] = 99.0                             # the caller's array is copied, not shared
    assert made.diameter_m[0] == 1.0


@pytest.mark.parametrize(("change", "message"), [
    (dict(x_m=np.zeros(2)), "column x_m has 2 rows; expected 3"),
    (dict(depth_m=np.zeros((3, 1))), "depth_m must be one-dimensional"),
    (dict(diameter_m=np.array([1.0, 0.0, 2.0])), "diameter_m must be positive"),
    (dict(age_gyr=np.array([1.0, -1.0, 2.0])), "age_gyr must be >= 0"),
    (dict(y_m=np.array([1.0, np.inf, 2.0])), "x_m, y_m must be finite"),
    (dict(diameter=np.ones(3)), "unknown crater catalogue column 'diameter' "
                                "\\(did you mean 'diameter_m'\\?\\)"),
    (dict(layer=np.array([0, -1, 0])), "layers must be >= 0"),
    (dict(alpha=np.array(["a", "b", "c"])), "column alpha must be float64"),
])
def test_bad_columns_are_refused_by_name(change, message):
    with pytest.raises(InvalidParameterError, match=message):
        CraterCatalog.from_columns({**_catalog(3).as_dict(), **change})


def test_a_missing_column_is_named():
    cols = _catalog(2).as_dict()
    del cols["beta"]
    with pytest.raises(InvalidParameterError, match=r"missing columns \['beta'\]"):
        CraterCatalog.from_columns(cols)


def test_a_malformed_file_is_named(tmp_path):
    path = tmp_path / "bad.csv"
    _catalog(2).to_csv(path)
    path.write_text(path.read_text().replace("8000000000000001", "not-hex"))
    with pytest.raises(InvalidParameterError, match="bad.csv"):
        CraterCatalog.from_csv(path)


def test_joins_and_selections_keep_rows_in_order():
    a, b = _catalog(3, layer=0), _catalog(2, layer=2, start=3)
    both = CraterCatalog.concatenate([a, b])
    assert both.columns == CATALOG_LAYER_COLUMNS
    assert both.layer.tolist() == [0, 0, 0, 2, 2]
    assert np.array_equal(both.id, np.concatenate([a.id, b.id]))
    assert np.array_equal(both.take(both.layer == 2).id, b.id)
    assert both.take(np.array([4, 0])).diameter_m.tolist() == [5.0, 1.0]
    assert len(CraterCatalog.concatenate([])) == 0
    assert CraterCatalog.concatenate([], optional=["layer"]).columns == CATALOG_LAYER_COLUMNS
    with pytest.raises(InvalidParameterError, match="with different columns"):
        CraterCatalog.concatenate([a, _catalog(1)])
    layered = _catalog(2).with_layer(4)
    assert layered.layer.tolist() == [4, 4] and layered.layer.dtype == np.int64


@settings(max_examples=25, deadline=None)
@given(st.lists(st.integers(0, 6), min_size=1, max_size=5))
def test_splitting_and_joining_gives_the_catalogue_back(cuts):
    cat = _catalog(7, layer=1)
    edges = [0, *sorted(cuts), 7]
    parts = [cat.take(slice(lo, hi)) for lo, hi in zip(edges[:-1], edges[1:], strict=True)]
    joined = CraterCatalog.concatenate(parts)
    for name in CATALOG_LAYER_COLUMNS:
        assert np.array_equal(getattr(joined, name), getattr(cat, name)), name


def test_columns_are_attributes_not_items(cratered):
    cat = cratered.catalog
    assert len(cat.id) == len(cat)
    with pytest.raises(TypeError):
        cat["id"]


def test_explicit_craters_are_catalogued_where_they_were_put():
    tile = DEMTile.from_array(np.zeros((65, 65), np.float32),
                              transform=default_transform(1.0, 65))
    table = CraterTable.from_craters([])
    assert len(add_craters(tile, table, seed=1).catalog) == 0
    from terrain.craters.catalog import Crater

    x, y = tile.xy(20, 40)
    one = add_craters(tile, CraterTable.from_craters([Crater(x, y, 8.0, 0.0, 7)]), seed=1)
    cat = one.catalog
    assert cat.id.tolist() == [7] and math.isclose(cat.row[0], 20) and math.isclose(cat.col[0], 40)


# ------------------------------------------------------------------------- rock catalogue


@pytest.fixture(scope="module")
def rocky():
    """A real rock field: 0.25 m pixels, Golombek-Rapp rocks from 0.5 m."""
    from terrain.surface.rocks import RockModel, add_rocks

    tile = DEMTile.from_array(np.zeros((129, 129), np.float32),
                              transform=default_transform(0.25, 129))
    return add_rocks(tile, RockModel.from_spec("golombek-rapp-mars:k=0.1,dmin=0.5"), seed=3)


def test_a_rock_catalogue_survives_its_csv_and_describes_its_rocks(rocky, tmp_path):
    tile, cat = rocky
    assert len(cat) > 10 and cat.columns == ROCK_COLUMNS
    assert isinstance(cat, RockCatalog) and not cat.diameter_m.flags.writeable
    # the vertical semi-axis is split between the part above ground and the buried part
    assert np.allclose(cat.height_m + cat.burial_m, cat.axis_c_m)
    assert np.all((cat.orientation_deg >= 0) & (cat.orientation_deg < 180))
    left, bottom, right, top = tile.bounds
    assert np.all((cat.x_m >= left) & (cat.x_m <= right) & (cat.y_m >= bottom)
                  & (cat.y_m <= top))
    path = tmp_path / "rocks.csv"
    cat.to_csv(path)
    back = RockCatalog.from_csv(path)
    for name in ROCK_COLUMNS:
        assert np.array_equal(getattr(back, name), getattr(cat, name)), name
    again = tmp_path / "again.csv"
    back.to_csv(again)
    assert again.read_bytes() == path.read_bytes()


def test_a_rock_catalogue_refuses_bad_columns_by_name(rocky):
    cols = rocky[1].as_dict()
    with pytest.raises(InvalidParameterError, match="did you mean 'diameter_m'"):
        RockCatalog.from_columns({**cols, "diametre_m": cols["diameter_m"]})
    with pytest.raises(InvalidParameterError, match=r"missing columns \['layer'\]"):
        RockCatalog.from_columns({k: v for k, v in cols.items() if k != "layer"})
    with pytest.raises(InvalidParameterError, match="rock catalogue column z_base_m has"):
        RockCatalog.from_columns({**cols, "z_base_m": cols["z_base_m"][:-1]})
    with pytest.raises(InvalidParameterError, match="different columns"):
        CraterCatalog.concatenate([_catalog(1), _catalog(1, layer=0)])
