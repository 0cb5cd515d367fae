"""Scenarios and sequences with the Sun on a date and an auto-exposing camera."""

import json
import math

import numpy as np
import pytest

from render import ephemeris as eph
from render.scenario import parse_scenario
from terrain.core.errors import InvalidParameterError
from tests.render.scenes import cratered_stack, descent_scenario

UTC = "2027-01-15T12:00:00"


def _scenario(sun: dict, scene: dict | None = None, sensor: dict | None = None):
    return parse_scenario({
        "scene": scene or {"type": "terrain", "stack": "stack"},
        "sun": sun, "sensor": sensor or {"exposure": 5.0},
        "trajectory": {"type": "descent", "frames": 2, "start_altitude": 100.0,
                       "end_altitude": 10.0}})


def test_a_dated_sun_is_the_ephemeris_sun_and_turns_with_the_moon():
    """[sun] utc with a site gives the Sun of render.ephemeris at that time; an hour later it
    has turned by the Moon's synodic rate, 360 deg / 29.53 d = 0.508 deg an hour, in azimuth
    (at 80 S the azimuth moves at nearly that rate)."""
    sc = _scenario({"utc": UTC, "longitude": 20.0, "latitude": -80.0, "irradiance": 1.6})
    sky = eph.lunar_sky(eph.et_from_utc(UTC), eph.Site(20.0, -80.0))
    assert np.allclose(sc.lighting.sun, sky.sun, atol=1e-12)
    assert sc.lighting.distance == pytest.approx(sky.sun_au)
    assert sc.lighting.spectral_irradiance == pytest.approx(1.6 / sky.sun_au**2)
    later = sc.lighting_at(3600.0)
    turn = math.degrees(math.acos(np.dot(later.sun, sc.lighting.sun)))
    assert 0.4 < turn < 0.52, turn
    assert sc.lighting_at(0.0) == sc.lighting


@pytest.mark.parametrize("sun, message", [
    ({"utcc": UTC}, "unknown scenario \\[sun\\] key 'utcc' \\(did you mean 'utc'\\?\\)"),
    ({"utc": UTC, "longitude": 1.0, "latitude": -80.0, "azimuth": 10.0}, "azimuth is hand-set"),
    ({"longitude": 1.0, "latitude": -80.0}, "needs utc"),
    ({"utc": "2027-01-15 noon", "longitude": 1.0, "latitude": -80.0}, "utc"),
    ({"utc": UTC, "longitude": 1.0, "latitude": -95.0}, "latitude"),
    ({"utc": UTC, "latitude": -80.0}, "longitude and latitude"),
])
def test_bad_sun_tables_are_refused_by_key(sun, message):
    with pytest.raises(InvalidParameterError, match=message):
        _scenario(sun)


def test_an_asteroid_sun_from_its_orbit():
    """An asteroid on a circular orbit of 1.5 au: the scenario's lighting is 1.5 au from the
    Sun, its irradiance 1/1.5^2 of the 1 au value."""
    sc = _scenario({"utc": UTC, "orbit": {"a": 1.5, "e": 0.0, "i": 5.0, "node": 10.0,
                                          "peri": 20.0, "mean_anomaly": 30.0, "epoch": UTC}},
                   scene={"type": "asteroid", "body": "eros.npz"})
    assert sc.lighting.distance == pytest.approx(1.5, rel=1e-9)
    assert sc.lighting.spectral_irradiance == pytest.approx(sc.lighting.irradiance / 2.25)
    with pytest.raises(InvalidParameterError, match="orbit\\] needs"):
        _scenario({"utc": UTC, "orbit": {"a": 1.5}},
                  scene={"type": "asteroid", "body": "eros.npz"})


def test_a_sequence_under_a_dated_sun_with_auto_exposure(tmp_path, gl):
    """A descent over 4 s under the Sun of 2027-01-15 at 80 S: every frame's truth holds the
    ephemeris sky at utc + its time and the exposure the camera used; the last frame's 95th
    percentile of lit pixels sits at the chosen 70 % of full scale."""
    import cv2

    from render.scenario import load_scenario
    from render.sequence import run_sequence

    stack = cratered_stack(tmp_path / "stack")
    text = descent_scenario(stack, "dated", frames=3)
    text = text.replace("azimuth = 100.0\nelevation = 15.0\n",
                        f'utc = "{UTC}"\nlongitude = 20.0\nlatitude = -80.0\n')
    text = text.replace("exposure = 4.0\ngain = 10.0\nread_noise = 2.0\n",
                        "exposure = 4.0\nauto_exposure = true\nae_percentile = 95.0\n"
                        "ae_fraction = 0.7\nae_rate = 1.0\n")
    path = tmp_path / "dated.toml"
    path.write_text(text)
    run_sequence(load_scenario(path), tmp_path / "run")
    truth = json.loads((tmp_path / "run" / "truth.json").read_text())
    et0 = eph.et_from_utc(UTC)
    for entry in truth:
        sky = eph.lunar_sky(et0 + entry["time"], eph.Site(20.0, -80.0))
        assert np.allclose(entry["sun"]["direction"], sky.sun, atol=1e-12)
        assert entry["sun"]["elevation"] == pytest.approx(sky.sun_angles[1])
        assert entry["exposure"]["auto"] and entry["exposure"]["exposure"] > 0
    last = truth[-1]
    image = cv2.imread(str(tmp_path / "run" / last["image"]), cv2.IMREAD_UNCHANGED)
    assert image.dtype == np.uint16
    lit = image > 0
    p95 = float(np.percentile(image[lit], 95.0))
    assert abs(p95 - 0.7 * 65535) <= 0.01 * 65535  # lit: DN > 0 (sensor noise is off)


def test_a_stack_with_a_crs_places_the_site_itself():
    """Without longitude and latitude, a terrain scene's stack places the site: 100 km from
    the pole on the map's -y axis of a south polar stereographic map is longitude 180, where
    the map's +y points at the pole, so the map sees the Sun 180 deg round from true north."""
    from types import SimpleNamespace

    from terrain.io import polar_crs

    tile = SimpleNamespace(crs=polar_crs(eph.MOON_RADIUS))
    scene = SimpleNamespace(stack=SimpleNamespace(tiles=[tile]), site=(0.0, -100_000.0),
                            radius=eph.MOON_RADIUS, height_at=lambda x, y: 0.0)
    sc = _scenario({"utc": UTC})
    lat = 2 * math.degrees(math.atan(100_000.0 / (2 * eph.MOON_RADIUS))) - 90.0
    true = eph.lunar_sky(eph.et_from_utc(UTC) + 60.0, eph.Site(180.0, lat))
    got = sc.sky_at(60.0, scene)
    assert (true.sun_angles[0] - got.sun_angles[0]) % 360.0 == pytest.approx(180.0, abs=1e-3)
    assert got.sun_angles[1] == pytest.approx(true.sun_angles[1], abs=1e-9)
    with pytest.raises(InvalidParameterError, match="longitude and latitude"):
        _scenario({"utc": UTC}).sky_at(0.0, SimpleNamespace(stack=None))
