"""Asteroid crater and boulder catalogues: typed columns, refusals by name, exact CSV."""

import numpy as np
import pytest

from asteroid.body import Body
from asteroid.boulders import place_boulders
from asteroid.catalog import BoulderCatalog, CraterCatalog, save_table
from asteroid.craters import add_craters, craters_at
from asteroid.sphere import SphereMesh
from terrain.core.errors import InvalidParameterError
from terrain.craters.population import Population


@pytest.fixture(scope="module")
def catalogues():
    body = Body.sphere(SphereMesh(48), 1000.0)
    craters = craters_at([0.0, 30.0, -60.0], [0.0, 90.0, 200.0], [120.0, 80.0, 60.0],
                         [0.5, 0.2, 0.0])
    cratered = add_craters(body, craters, seed=3)
    pop = Population(dmin=4.0, dmax=40.0, density=400.0, sfd_exponent=-3.0, max_age=0.0)
    boulders = place_boulders(cratered.body, pop, seed=3)
    return cratered.catalog, boulders.catalog


def test_the_catalogues_are_typed_read_only_tables(catalogues):
    craters, boulders = catalogues
    assert isinstance(craters, CraterCatalog) and isinstance(boulders, BoulderCatalog)
    assert craters.id.dtype == np.uint64 and craters.applied.dtype == np.int64
    assert boulders.size_class.dtype == np.int64 and boulders.r22.dtype == np.float64
    with pytest.raises(ValueError):
        craters.diameter_m[0] = 1.0


@pytest.mark.parametrize("which", [0, 1])
def test_csv_round_trip_is_exact(tmp_path, catalogues, which):
    table = catalogues[which]
    first = save_table(tmp_path / "a.csv", table)
    back = type(table).from_csv(first)
    for name in table.columns:
        assert np.array_equal(getattr(back, name), getattr(table, name), equal_nan=True), name
    again = save_table(tmp_path / "b.csv", back)
    assert first.read_bytes() == again.read_bytes()
    text = first.read_text()
    assert "\r" not in text and text.splitlines()[0] == ",".join(table.columns)
    assert text.splitlines()[1].split(",")[0] == f"{int(table.id[0]):016x}"


def test_unknown_and_missing_columns_are_refused_by_name(catalogues):
    craters, boulders = catalogues
    cols = craters.as_dict()
    with pytest.raises(InvalidParameterError,
                       match=r"unknown asteroid crater catalogue column 'diameter' "
                             r"\(did you mean 'diameter_m'\?\)"):
        CraterCatalog.from_columns({**cols, "diameter": cols["diameter_m"]})
    short = {k: v for k, v in boulders.as_dict().items() if k != "r11"}
    with pytest.raises(InvalidParameterError, match=r"missing columns \['r11'\]"):
        BoulderCatalog.from_columns(short)
    with pytest.raises(InvalidParameterError, match="diameter_m must be positive"):
        CraterCatalog.from_columns({**cols, "diameter_m": -cols["diameter_m"]})
