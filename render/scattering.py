"""Light that reaches terrain from elsewhere than the sun's disk: scattered light and earthshine.

Shadowed ground is not black: sunlit slopes around it scatter light into it (a few per cent
of the direct sunlight on the Moon's polar floors), and where the Earth is above the horizon
it lights the near side. This module computes both per point of a height grid, once per sun
direction, from the terrain's horizons (the method of horizon-based irradiance in terrain
rendering and of lunar illumination models such as Mazarico et al. 2011, Icarus 211, 1066,
reduced to single scattering):

- **Direct sun.** The horizon along the sun's azimuth (the highest elevation angle of the
  terrain seen from the point, searched every grid cell) against the solar disk: the
  fraction of the disk above the horizon (:func:`disk_fraction_above`).
- **Sources.** Every point then scatters as a Lambertian surface of the scene's normal albedo
  A: its radiosity over the solar irradiance F is ``B = A mu0 v`` (mu0 the cosine of the
  sun's incidence on its normal, v its visible fraction of the disk).
- **Single scattering.** From each receiver, :data:`AZIMUTHS` azimuth slices are walked
  outward, every cell to :data:`LINEAR_STEPS` cells, then in steps growing by
  :data:`STEP_GROWTH`; a sample whose elevation angle
  beta exceeds the highest one before it (the horizon h, starting at the receiver's own
  tangent plane) shows terrain across the elevations ``h..beta`` of the slice, of radiance
  ``B / pi`` (the mean of the sample's and the one's before it, each where its surface faces
  the receiver; else none: a rim's wall in its own shadow, not the lit top behind it). The
  irradiance it adds is that radiance times the projected
  solid angle of the band,
  ``dphi * integral_h^beta (a cos(theta) + n_z sin(theta)) cos(theta) dtheta``, with
  ``a`` the normal's component along the azimuth (a closed form, :func:`_band`). Summed,
  ``E / F`` is the scattered irradiance over the solar irradiance; a Lambertian receiver of
  albedo A adds ``A E / F`` to its I/F. A uniformly bright enclosure gives ``E = B``, and a
  floor beside a lit wall the wall's view factor (``tests/render/test_scattering.py``).
- **Earth.** The Earth's visible fraction likewise, from the horizon along its azimuth and its
  angular radius; the renderer multiplies it by the Earth's light on the surface's law.

The terrain scene (:mod:`render.terrain_scene`) computes one grid per layer, 1/``cells`` of
the layer's side, over the layer and half its side around it (heights from the finest layer
at each point), and the fragment shader reads it bilinearly: scattered light is smooth, so a
coarse grid holds it; the direct shadows stay the shadow maps' (sharp and extended-sun).
Light scattered twice or more (about A times less again, A near 0.1) is left out.
"""

from __future__ import annotations

import math
from typing import Any

import numba
import numpy as np

from terrain.core.errors import InvalidParameterError

__all__ = ["AZIMUTHS", "EARTH_RADIUS_M", "LINEAR_STEPS", "STEP_GROWTH", "disk_fraction_above",
           "horizon_light"]

#: Azimuth slices per receiver (22.5 degrees each).
AZIMUTHS = 16
#: The scattered light's walk outward: a step every grid cell out to this many cells, then
#: each step this factor longer than the one before.
LINEAR_STEPS = 16
STEP_GROWTH = 1.1
#: Equatorial radius of the Earth (m; IAU 2015 Resolution B3 nominal value), for its
#: angular radius seen from the body.
EARTH_RADIUS_M = 6_378_100.0


def disk_fraction_above(elevation: float | np.ndarray, horizon: np.ndarray,
                        radius: float) -> np.ndarray:
    """Fraction of a uniform disk centred at ``elevation`` that lies above ``horizon``.

    The horizon is taken as a straight edge across the disk (exact for a disk small against
    the horizon's curvature).

    Parameters
    ----------
    elevation : float or array, radians
        The disk centre's elevation angle.
    horizon : array, radians
        The horizon's elevation angle.
    radius : float, radians
        The disk's angular radius (0: a point, visible where above the horizon).

    Returns
    -------
    array of float64
        In [0, 1].

    Examples
    --------
    >>> float(disk_fraction_above(0.1, np.array(0.1), 0.01))
    0.5
    """
    elevation = np.asarray(elevation, dtype=np.float64)
    horizon = np.asarray(horizon, dtype=np.float64)
    if radius <= 0:
        return (elevation > horizon).astype(np.float64)
    u = np.clip((horizon - elevation) / radius, -1.0, 1.0)
    return (np.arccos(u) - u * np.sqrt(1.0 - u * u)) / math.pi


def _steps(spacing: float, reach: float) -> np.ndarray:
    d, out = spacing, []
    while d <= reach:
        out.append(d)
        d = d + spacing if d < LINEAR_STEPS * spacing else d * STEP_GROWTH
    return np.array(out)


class _Shifter:
    """Bilinear samples of grids at every point plus one fixed offset, beyond the edges too.

    Along one azimuth, every point's sample at distance d is the grid shifted by the same
    (fractional) number of cells, so a sample of the whole grid is four slices of it padded
    once, weighted: no per-point indices.
    """

    def __init__(self, grids: np.ndarray, reach_cells: float, heights: bool = True) -> None:
        self.pad = int(math.ceil(reach_cells)) + 2
        p = self.pad
        self.shape = grids.shape[-2:]
        if grids.ndim == 2:
            grids = grids[None]
        # heights (the first grid) continue their slope beyond the edges (an odd
        # reflection: a plane stays a plane, with no terrace at the edge for the points
        # below it to see); the other grids repeat their edges
        padded = [np.pad(g, p, mode="reflect", reflect_type="odd") if heights and i == 0
                  else np.pad(g, p, mode="edge") for i, g in enumerate(grids)]
        self.padded = np.stack(padded) if len(padded) > 1 else padded[0]

    def at(self, rows: float, cols: float) -> np.ndarray:
        """Sample every point's (row + ``rows``, col + ``cols``), offsets in cells."""
        h, w = self.shape
        i0, j0 = math.floor(rows), math.floor(cols)
        ti, tj = rows - i0, cols - j0
        r, c = self.pad + i0, self.pad + j0
        g = self.padded
        # top * (1 - ti) + bottom * ti of the rows' interpolations, in place (the same
        # operations in the same order as written out, fewer temporaries)
        top = np.multiply(g[..., r:r + h, c:c + w], 1 - tj)
        top += np.multiply(g[..., r:r + h, c + 1:c + 1 + w], tj)
        bottom = np.multiply(g[..., r + 1:r + 1 + h, c:c + w], 1 - tj)
        bottom += np.multiply(g[..., r + 1:r + 1 + h, c + 1:c + 1 + w], tj)
        top *= 1 - ti
        bottom *= ti
        top += bottom
        return top


@numba.njit(cache=True, nogil=True)
def _sample_sources(padded, pad, rows, cols, z, dx, dy, d, dz, here):  # pragma: no cover
    """One step of the scattered light's walk, for every receiver at once (compiled).

    Samples the padded grids of :class:`_Shifter` (height, normal x, y, z, radiosity) at
    every point plus (``rows``, ``cols``) cells, bilinearly, with the arithmetic of
    :meth:`_Shifter.at` in its order (IEEE operations only: the same float64 values), and
    writes ``dz``: the sample's height above the receiver, and ``here``: its radiosity
    where its surface faces the receiver, else 0 (the test of :func:`horizon_light`).
    One pass over the grids instead of NumPy's temporaries; ``atan2`` stays NumPy's.
    """
    h, w = z.shape
    i0, j0 = math.floor(rows), math.floor(cols)
    ti, tj = rows - i0, cols - j0
    r, c = pad + i0, pad + j0
    ui, uj = 1 - ti, 1 - tj
    for y in range(h):
        for x in range(w):
            zq = _bilinear(padded, 0, r + y, c + x, ti, tj, ui, uj)
            nxq = _bilinear(padded, 1, r + y, c + x, ti, tj, ui, uj)
            nyq = _bilinear(padded, 2, r + y, c + x, ti, tj, ui, uj)
            nzq = _bilinear(padded, 3, r + y, c + x, ti, tj, ui, uj)
            zr = z[y, x]
            dz[y, x] = zq - zr
            if (-(nxq * dx + nyq * dy) * d + nzq * (zr - zq)) > 0.0:
                here[y, x] = _bilinear(padded, 4, r + y, c + x, ti, tj, ui, uj)
            else:
                here[y, x] = 0.0


@numba.njit(cache=True, inline="always")
def _bilinear(padded, g, r, c, ti, tj, ui, uj):  # pragma: no cover
    """:meth:`_Shifter.at`'s value of grid ``g`` at padded (r, c) + (ti, tj), its order."""
    top = padded[g, r, c] * uj
    top += padded[g, r, c + 1] * tj
    bottom = padded[g, r + 1, c] * uj
    bottom += padded[g, r + 1, c + 1] * tj
    top *= ui
    bottom *= ti
    return top + bottom


def _band(a: np.ndarray, nz: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """Antiderivative of ``(a cos t + nz sin t) cos t`` at ``theta``."""
    return a * (0.5 * theta + 0.25 * np.sin(2.0 * theta)) + nz * 0.5 * np.sin(theta) ** 2


def _horizon(z: np.ndarray, spacing: float, azimuth: float, steps: np.ndarray) -> np.ndarray:
    """Highest elevation angle (radians) of the terrain along an azimuth from each point."""
    dx, dy = math.sin(azimuth), math.cos(azimuth)
    shift = _Shifter(z, steps[-1] / spacing if steps.size else 0.0)
    best = np.full(z.shape, -math.pi / 2)
    for d in steps:
        zq = shift.at(-dy * d / spacing, dx * d / spacing)
        np.maximum(best, np.arctan2(zq - z, d), out=best)
    return best


def _angles(direction: Any) -> tuple[float, float]:
    v = np.asarray(direction, dtype=np.float64)
    v = v / np.linalg.norm(v)
    return math.atan2(v[0], v[1]), math.asin(max(-1.0, min(1.0, v[2])))


def horizon_light(z: np.ndarray, spacing: float, sun: Any, *, albedo: float,
                  sun_radius: float = 0.0, earth: Any = None, reach: float | None = None,
                  azimuths: int = AZIMUTHS) -> dict[str, np.ndarray]:
    """Compute the direct sun's visibility, the single-scattered irradiance and the Earth's.

    Parameters
    ----------
    z : (h, w) float, metres
        Heights on a square grid, row 0 north (largest y), column 0 west; x east, y north.
    spacing : float, metres
        Grid spacing.
    sun : (3,) float
        Direction towards the sun (x east, y north, z up).
    albedo : float
        The terrain's normal albedo A (its Lambertian sources' reflectance).
    sun_radius : float, radians
        The solar disk's angular radius (0: a point).
    earth : (3,) float, optional
        Direction towards the Earth; its visibility is computed where given.
    reach : float, metres, optional
        How far the horizons are searched (default: the grid's diagonal).
    azimuths : int
        Azimuth slices of the scattered light.

    Returns
    -------
    dict
        ``"sun"``: (h, w) float32, the visible fraction of the solar disk; ``"scattered"``:
        (h, w) float32, scattered irradiance over the solar irradiance (E / F); ``"earth"``:
        (h, w) float32, the Earth's visible fraction (ones without ``earth``).

    Raises
    ------
    terrain.core.errors.InvalidParameterError
        For a grid that is not 2-D with at least 2 x 2 finite heights, or a spacing that is
        not positive.
    """
    z = np.asarray(z, dtype=np.float64)
    if z.ndim != 2 or min(z.shape) < 2 or not np.all(np.isfinite(z)):
        raise InvalidParameterError(
            f"heights must be a finite (h, w) grid of at least 2 x 2; got shape {z.shape}")
    if not (spacing > 0 and math.isfinite(spacing)):
        raise InvalidParameterError(f"grid spacing must be positive; got {spacing}")
    h, w = z.shape
    if reach is None:
        reach = spacing * math.hypot(h, w)
    steps = _steps(spacing, reach)
    dzdx = np.gradient(z, spacing, axis=1)
    dzdy = -np.gradient(z, spacing, axis=0)  # rows run south
    n = np.stack([-dzdx, -dzdy, np.ones_like(z)])
    n /= np.linalg.norm(n, axis=0)

    # the sun's and the Earth's horizons every cell out to the grid's size (one azimuth
    # each: a rim between two of the scattering's growing steps must not be missed)
    fine = np.arange(1, int(min(reach, spacing * math.hypot(h, w)) / spacing) + 1) * spacing
    sun_az, sun_el = _angles(sun)
    s = np.asarray(sun, dtype=np.float64) / np.linalg.norm(sun)
    vis = disk_fraction_above(sun_el, _horizon(z, spacing, sun_az, fine), sun_radius)
    mu0 = np.maximum(np.einsum("kij,k->ij", n, s), 0.0)
    radiosity = albedo * mu0 * vis  # B / F of each Lambertian source

    dphi = 2.0 * math.pi / azimuths
    scattered = np.zeros(z.shape)
    # what a sample needs of its source: height, normal, radiosity
    shift = _Shifter(np.stack([z, n[0], n[1], n[2], radiosity]),
                     steps[-1] / spacing if steps.size else 0.0)
    flat = scattered.ravel()  # a view: the receivers that see new terrain are updated
    nz = n[2].ravel()
    for k in range(azimuths):
        phi = (k + 0.5) * dphi  # clockwise from north
        dx, dy = math.sin(phi), math.cos(phi)
        a = n[0] * dx + n[1] * dy
        top = np.arctan2(-a, n[2])  # the receiver's own tangent plane
        low = _band(a, n[2], top).ravel()
        top = top.ravel()
        a = a.ravel()
        before = np.zeros(z.size)  # the previous sample's radiosity towards the receiver
        for d in steps:
            # each receiver's sample: its height above the receiver, and its radiosity where
            # its surface faces the receiver, else 0 (a source shines on the receiver only
            # with the side that faces it: a plateau's top seen from below its rim is the
            # rim's wall, not the lit top)
            dz, source = np.empty(z.shape), np.empty(z.shape)
            _sample_sources(shift.padded, shift.pad, -dy * d / spacing, dx * d / spacing, z,
                            dx, dy, d, dz, source)
            beta = np.arctan2(dz, d).ravel()
            seen = np.flatnonzero(beta > top)
            here = source.ravel()
            if not seen.size:
                before = here
                continue
            # only the receivers that see the sample above their horizon so far change: the
            # same arithmetic, element by element, on those alone
            rise = beta[seen]
            high = _band(a[seen], nz[seen], rise)
            # the band between two samples: the mean of their radiances (trapezoid rule)
            flat[seen] += (0.5 * (here[seen] + before[seen]) / math.pi * dphi
                           * (high - low[seen]))
            low[seen] = high
            top[seen] = rise
            before = here
    earth_vis = np.ones(z.shape)
    if earth is not None:
        e_az, e_el = _angles(earth)
        # the Earth's angular radius at the Moon's mean distance (384,400 km)
        earth_vis = disk_fraction_above(e_el, _horizon(z, spacing, e_az, fine),
                                        math.asin(EARTH_RADIUS_M / 384_400_000.0))
    return {"sun": vis.astype(np.float32), "scattered": scattered.astype(np.float32),
            "earth": earth_vis.astype(np.float32)}
