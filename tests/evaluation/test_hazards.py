"""The landing-site section: rock size-frequency measured from a catalogue, hazard summary."""

import numpy as np
import pytest

from evaluation.hazards import rock_sfd, site_section
from terrain.core.tile import DEMTile
from terrain.craters.catalog import RockCatalog
from terrain.surface.hazards import hazard_image, hazard_map
from terrain.surface.rocks import RockModel, rock_catalog


def _rocks(x, y, d):
    """A rock catalogue of rocks at (x, y) of diameter d (the other columns plausible)."""
    d = np.asarray(d, float)
    zero = np.zeros(d.size)
    return RockCatalog(id=np.arange(d.size), x_m=x, y_m=y, z_base_m=zero, diameter_m=d,
                       height_m=d / 4, burial_m=d / 4, axis_a_m=d / 2, axis_b_m=d / 2,
                       axis_c_m=d / 2, orientation_deg=zero, layer=np.zeros(d.size, int))


def test_rock_sfd_of_an_extent_without_rocks_that_large_is_zero():
    cat = _rocks([1.0, 2.0], [1.0, 2.0], [0.2, 0.4])
    m = rock_sfd(cat, (0.0, 0.0, 10.0, 10.0), 1.0, points=4)
    assert m["rocks"] == 0
    assert not np.any(m["number_per_m2"]) and not np.any(m["fractional_area"])


def test_rock_sfd_counts_area_and_number_of_rocks_at_least_d():
    cat = _rocks([1.0, 2.0, 3.0, 50.0], [1.0, 2.0, 3.0, 3.0], [0.2, 0.4, 0.8, 5.0])
    m = rock_sfd(cat, (0.0, 0.0, 10.0, 10.0), 0.2, points=3)  # the 5 m rock lies outside
    np.testing.assert_allclose(m["diameter_m"], [0.2, 0.4, 0.8])
    np.testing.assert_allclose(m["number_per_m2"], [3 / 100, 2 / 100, 1 / 100])
    np.testing.assert_allclose(m["fractional_area"] * 100,
                               np.pi / 4 * np.array([0.84, 0.8, 0.64]))


@pytest.mark.slow
def test_rock_sfd_of_a_generated_field_follows_its_model():
    model = RockModel.from_spec("golombek-rapp-mars:k=0.1,dmin=0.1")
    rocks = model.generate(8, (0.0, 0.0, 100.0, 100.0), margin=False)
    cat = rock_catalog(rocks, np.zeros(len(rocks)), np.zeros(len(rocks), int))
    m = rock_sfd(cat, (0.0, 0.0, 100.0, 100.0), 0.1, points=5)
    d = m["diameter_m"][:3]   # 0.1 .. 0.3 m, well sampled
    expected = model.fractional_area(d) - model.fractional_area(model.dmax)
    np.testing.assert_allclose(m["fractional_area"][:3], expected, rtol=0.15)


def test_site_section_reports_the_hazard_map_and_the_rocks(tmp_path):
    from terrain.io import write_png

    y, x = np.mgrid[0:61, 0:61] * 0.1
    tile = DEMTile.from_array(x * np.tan(np.radians(14.0)) * (x > 3), resolution=0.1)
    h = hazard_map(tile, lander_diameter=1.0, max_slope=12.0, max_step=0.3)
    png = write_png(hazard_image(h), tmp_path / "h.png")
    model = RockModel.from_spec("power:a=0.01,b=-2.5,dmin=0.1")
    rocks = model.generate(1, tile.bounds, margin=False)
    cat = rock_catalog(rocks, np.zeros(len(rocks)), np.zeros(len(rocks), int))
    sec = site_section(h, png, layer=0, resolution=0.1, rocks=cat, rock_model=model,
                       rock_extent=(tile.bounds, 0.2),
                       descent=[dict(frame=0, altitude_m=20.0, range_m=22.0, gsd_m=0.025,
                                     layer=3, layer_resolution_m=0.03, ratio=1.2,
                                     lod_step=1, cell_m=0.03)],
                       frames=(0,))
    assert [f.id for f in sec.figures] == ["hazards", "rock_sfd"]
    assert sec.data["safe_fraction"] == pytest.approx(h.safe_fraction)
    assert 0.2 < h.safe_fraction < 0.8   # flat west, 14 degrees east
    assert sec.checks[0].passed is True


def test_evaluation_report_takes_a_hazard_map_of_a_rocky_stack(tmp_path):
    import json

    from tests.cli_helpers import run

    base = tmp_path / "b.tif"
    assert run("terrain", "synth", "-o", base, "--size", 65, "--resolution", 4.0, "--relief",
               3, "--seed", 2).exit_code == 0
    stack = tmp_path / "stack"
    assert run("terrain", "enhance", base, "-o", stack, "--site", "130,130", "--levels", 5,
               "--layer-size", 65, "--rocks", "golombek-rapp-mars:k=0.15").exit_code == 0
    hz = tmp_path / "hazards.tif"
    r = run("terrain", "hazards", stack, "-o", hz, "--lander-diameter", 1.5, "--max-slope",
            12, "--max-step", 0.2)
    assert r.exit_code == 0, r.output
    out = tmp_path / "report.html"
    r = run("evaluation", "report", "-o", out, "--hazards", hz)
    assert r.exit_code == 0, r.output
    doc = json.loads(out.with_suffix(".json").read_text())
    assert [s["id"] for s in doc["sections"]] == ["site"]
    assert {f["id"] for f in doc["figures"]} == {"hazards", "rock_sfd"}
    assert 0 <= doc["sections"][0]["data"]["safe_fraction"] <= 1
