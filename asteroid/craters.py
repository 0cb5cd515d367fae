r"""Craters on an asteroid: the lunar crater model mapped onto the curved mesh (section V.A).

The profile, erosion and roughness are those of the flat-terrain model
(:mod:`terrain.craters.crater`,
:mod:`terrain.craters.erosion`, :mod:`terrain.craters.overlay`,
:class:`terrain.craters.cratering.CraterModel`); this
module adapts it to the 6M^2 + 2 mesh as Martin et al. (2014, section V.A) describe:

1. **Region.** The vertices within the crater's footprint (ejecta edge at r = D, widened by the
   irregular rim) are listed ring by ring from the latitude/longitude structure
   (:func:`asteroid.sphere.cap_ranges`).
2. **True distances and angles.** For a vertex with unit direction u and a crater centred on
   c, the angle at the centre of the body is ``gamma = atan2(|u x c|, u . c)`` and the
   distance from the crater centre is the arc ``s = R_c gamma`` on the sphere through the
   crater centre (``R_c``, the surface radius there); the azimuth is
   ``theta = atan2(u . n, u . e)`` with east ``e = z x c / |z x c|`` and north ``n = c x e``.
   The crater is evaluated at these true distances and angles, "instead of grid distances"
   (the paper names grid distances as the cause of radial artefacts). Heights are radial:
   ``h = r - R_c``.
3. **The local DEM.** The plane fit, the terrain at the rim and the pixel roughness of the
   lunar model need a grid: each vertex is dropped into the grid cell at
   ``(s cos theta, s sin theta) / Delta`` (cells averaging their vertices), with the spacing
   Delta the mean vertex spacing at ``R_c`` (the paper's "average distance between vertex
   points"); "any holes in the grid are filled by interpolating neighboring points using a
   weighted average of the nearest known values in eight directions" (inverse-distance
   weights). The paper places vertices with dot products on east and north (an orthographic
   projection, which shortens distances by ``sin(gamma) / gamma``); we use the same azimuthal
   equidistant coordinates as the profile, so the grid and the profile agree.
4. **Mapping back.** Each vertex's new height ``h'`` rescales its radius: ``r' = R_c + h'``.
   Outside the rim the ejecta adds to the terrain, ``h' = h + dh``, as in the flat model.
   Inside, the bowl replaces the terrain on the fitted plane P, with its rim riding on the
   terrain's level at the rim along each azimuth (``Tr - Pr``, sampled at up to 64 azimuths
   and low-passed, as the flat model does). On the rough bases of asteroids the terrain
   deviates from that smoothed rim level by metres at the scale of the rim, and the flat
   model's interior would step against the ejecta there ("the crater model is smoothly
   integrated into rough terrain", section V, is what the paper asks). So the deviation
   ``h - (P + Tr - Pr)`` is kept on the upper inner wall with the flat model's obliteration
   weight (:func:`terrain.craters.cratering.obliteration`: all of it at the rim, smoothstep to none
   at ``x = -OBLITERATION_BLEND``), and the rim joins the ejecta continuously:
   ``h' = P + h_in(x) + overlay + (h - P - (Tr - Pr)) (1 - w(x))``.
5. **Order.** Craters are applied one after another in age order, oldest first (ties by
   identity), each fitted to the surface the older craters left: the paper's order. (The
   flat model's size-class order exists only to make DEM windows exact; a body is computed
   whole.)

Limits the paper recommends
---------------------------
* **Maximum extent.** "Large craters extending greater than approximately 60 degrees of the
  asteroid radius can have artifacts near the edge of their ejecta." We measure a crater's
  extent as the angle its ejecta blanket (diameter 2D) subtends at the body's centre, ``2D / R``
  for the reference radius R, and refuse craters beyond :attr:`CraterSettings.max_extent_deg`
  (default 60 degrees, so D <= pi R / 6, about 0.52 R).
* **Slope erosion.** "Artifacts can also be introduced around crater rims when craters are
  added to excessively steep slopes. These artifacts can be eliminated or reduced by adding
  in a slope based erosion factor which reduces crater depth and rim height on steep slopes."
  The slope is the tilt of the plane fitted over the bowl, in the radial frame (so the angle
  between the local surface and the sphere through it). No law is published; we scale both
  the depth and rim fractions by a factor that is 1 up to :attr:`SlopeErosion.start_deg`
  (default 30 degrees) and falls linearly to 0 at :attr:`SlopeErosion.stop_deg` (default
  50 degrees, past the 32-35 degree angle of repose of loose regolith). A crater whose factor
  reaches 0 is not applied (it could not persist on such a slope; the catalogue keeps it with
  ``applied = 0``).
  Before that guard, a crater on sloping ground also ages faster, as on flat terrain
  (:class:`terrain.craters.erosion.SlopeDegradation`, the model's ``slope``, switchable): its depth
  and rim fractions are read at the effective age ``m(S) T``.
* **Complex craters.** Craters wider than the model's
  :attr:`~terrain.craters.crater.Morphology.transition_diameter` take the complex profile (flat
  floor, terraced wall, central peak or peak ring). The lunar default (15 km) scales roughly
  as 1/g, so on small bodies set it for the body (or leave it: no crater reaches it).

Reuse
-----
The profile (:func:`terrain.craters.crater.crater_interior`, simple or complex by the model's
:class:`~terrain.craters.crater.Morphology`, :func:`~terrain.craters.crater.exterior_height`,
:func:`~terrain.craters.crater.shape_arrays`), erosion, overlay and irregular rim are terrain's
public
functions. The plane fit, the rim-terrain table and the obliteration weight are terrain's
compiled kernels ``fit_plane``, ``rim_terrain`` and ``obliteration``
(:mod:`terrain.craters.cratering`), imported rather than copied; they take a north-up grid in map
metres, which the local DEM above is.

On a large sphere a fresh crater reproduces the flat profile in true distance (the fitted
plane is the sphere, so ``h' - h`` is the profile) to within the chord depth of the flat
triangles, ``R (a / 2)^2`` for the mean spacing a (``tests/asteroid/test_craters.py``).

Examples
--------
>>> from asteroid.body import Body
>>> from asteroid.sphere import SphereMesh
>>> body = Body.sphere(SphereMesh(64), 1000.0)
>>> crater = craters_at([10.0], [45.0], [200.0], seed=1)
>>> result = add_craters(body, crater, seed=1, model=CraterModel().smooth())
>>> float(result.body.radii.min()) < 1000.0 - 30.0, int(result.catalog.applied[0])
(True, 1)
"""

from __future__ import annotations

import logging
import math
from dataclasses import asdict, dataclass, field
from typing import NamedTuple

import numba
import numpy as np

from asteroid.body import Body
from asteroid.catalog import CRATER_COLUMNS, CraterCatalog
from asteroid.placement import Placement, sample
from asteroid.sphere import (
    SphereMesh,
    cap_ranges,
    ring_offset,
    ring_size,
    surface_radius_scalar,
    unit_vertex,
)
from terrain.core import memory
from terrain.core.errors import InvalidParameterError
from terrain.core.rng import check_seed, hash64, stream_id
from terrain.craters.crater import Profile, crater_interior, exterior_height, shape_arrays
from terrain.craters.cratering import (
    RIM_TERRAIN_MIN,
    RIM_TERRAIN_SAMPLES,
    CraterModel,
    fit_plane,
    obliteration,
    rim_terrain,
)
from terrain.craters.overlay import (
    MAX_PATCH_LEVEL,
    RIM_SAMPLES,
    crater_params,
    overlay_patch,
    patch_value,
    periodic_sample,
    rim_table,
)
from terrain.craters.population import Population

__all__ = ["CraterModel", "CraterResult", "CraterSettings", "SlopeErosion",
           "add_craters", "craters_at", "max_diameter", "sample_craters"]

log = logging.getLogger(__name__)

#: Random stream of asteroid crater lists.
CRATER_STREAM = "asteroid-crater"
#: Default largest angular extent of a crater's ejecta blanket (degrees; section VII).
DEFAULT_MAX_EXTENT_DEG = 60.0
#: Extra grid cells around the rim in the local DEM (bilinear taps and the Laplacian).
DEM_MARGIN = 2
#: Most craters a population may expect on one body (a guard against typos in the density).
MAX_CRATERS = 20_000_000

@dataclass(frozen=True)
class SlopeErosion:
    """Depth and rim reduction on steep local slopes (degrees; see the module docstring).

    >>> s = SlopeErosion(30.0, 50.0)
    >>> [s.factor(math.radians(a)) for a in (10.0, 40.0, 60.0)]
    [1.0, 0.5, 0.0]
    """

    start_deg: float = 30.0
    stop_deg: float = 50.0
    enabled: bool = True

    def __post_init__(self):
        a, b = float(self.start_deg), float(self.stop_deg)
        if not (0.0 <= a < b <= 90.0):
            raise InvalidParameterError(
                f"slope erosion needs 0 <= start < stop <= 90 degrees; got start={a}, stop={b}")
        object.__setattr__(self, "start_deg", a)
        object.__setattr__(self, "stop_deg", b)
        object.__setattr__(self, "enabled", bool(self.enabled))

    def factor(self, slope_rad: float) -> float:
        """Multiplier of the depth and rim fractions at a slope (radians)."""
        if not self.enabled:
            return 1.0
        deg = math.degrees(slope_rad)
        if deg <= self.start_deg:
            return 1.0
        if deg >= self.stop_deg:
            return 0.0
        return (self.stop_deg - deg) / (self.stop_deg - self.start_deg)


@dataclass(frozen=True)
class CraterSettings:
    """How craters are made on a body (everything but the list of craters).

    Parameters
    ----------
    model : CraterModel
        Erosion, roughness overlay and irregular rim of the flat model.
    max_extent_deg : float
        Largest angle the ejecta blanket (diameter 2D) may subtend at the centre.
    slope : SlopeErosion
    """

    model: CraterModel = field(default_factory=CraterModel)
    max_extent_deg: float = DEFAULT_MAX_EXTENT_DEG
    slope: SlopeErosion = field(default_factory=SlopeErosion)

    def __post_init__(self):
        v = float(self.max_extent_deg)
        if not (0.0 < v <= 180.0):
            raise InvalidParameterError(f"max extent must lie in (0, 180] degrees; got {v}")
        object.__setattr__(self, "max_extent_deg", v)

    def as_dict(self) -> dict:
        """Return the settings as plain data for the model's metadata."""
        return dict(model=self.model.as_dict(), max_extent_deg=self.max_extent_deg,
                    slope=asdict(self.slope))


def max_diameter(radius: float, max_extent_deg: float = DEFAULT_MAX_EXTENT_DEG) -> float:
    """Largest crater diameter (m) whose ejecta spans at most ``max_extent_deg`` of a body.

    >>> round(max_diameter(1000.0), 3)     # pi R / 6
    523.599
    """
    return float(radius) * math.radians(max_extent_deg) / 2.0


def _check_extent(diameters, radius, settings: CraterSettings) -> None:
    d_max = max_diameter(radius, settings.max_extent_deg)
    big = np.asarray(diameters) > d_max * (1.0 + 1e-12)
    if big.any():
        d = float(np.max(diameters))
        extent = math.degrees(2.0 * d / radius)
        raise InvalidParameterError(
            f"a crater of diameter {d:.6g} m would span {extent:.1f} degrees of this body "
            f"(radius {radius:.6g} m), beyond the maximum extent of "
            f"{settings.max_extent_deg:g} degrees; the largest allowed is {d_max:.6g} m")


def sample_craters(population: Population, body: Body, *, seed: int,
                   settings: CraterSettings | None = None) -> Placement:
    """Return the crater list of a population over the body's surface area (section V.B).

    Refuses a population whose dmax exceeds the maximum extent.
    """
    settings = settings or CraterSettings()
    _check_extent([population.dmax], body.radius, settings)
    return sample(population, body.area(), seed=seed, stream=CRATER_STREAM,
                  max_features=MAX_CRATERS)


def craters_at(lat_deg, lon_deg, diameters, ages=None, *, seed: int = 0) -> Placement:
    """Explicit craters at latitudes/longitudes (degrees), diameters (m), ages (Gyr, default 0).

    Each crater's identity (which keys its roughness) is a hash of its position and size.
    """
    lat = np.radians(np.atleast_1d(np.asarray(lat_deg, dtype=np.float64)))
    lon = np.radians(np.atleast_1d(np.asarray(lon_deg, dtype=np.float64)))
    d = np.atleast_1d(np.asarray(diameters, dtype=np.float64))
    age = np.zeros_like(d) if ages is None else np.atleast_1d(np.asarray(ages, np.float64))
    lat, lon, d, age = np.broadcast_arrays(lat, lon, d, age)
    if not (np.all(np.abs(lat) <= np.pi / 2 + 1e-12) and np.all(np.isfinite(lon))):
        raise InvalidParameterError("crater latitudes must lie in [-90, 90] degrees")
    if not np.all((d > 0) & np.isfinite(d)):
        raise InvalidParameterError("crater diameters must be positive metres")
    if not np.all((age >= 0) & np.isfinite(age)):
        raise InvalidParameterError("crater ages must be >= 0 Gyr")
    seed = check_seed(seed)
    dirs = np.column_stack([np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)])
    sid = stream_id("asteroid-add-crater")
    uid = np.array([hash64(seed, sid, 0, int(round(a * 1e9)), int(round(b * 1e9)),
                           int(round(c * 1e3))) for a, b, c in zip(lat, lon, d, strict=True)],
                   dtype=np.uint64)
    n = d.size
    return Placement(dirs, d.copy(), age.copy(), uid, np.floor(np.log2(d)).astype(np.int64),
                     np.arange(n, dtype=np.int64), np.zeros((n, 0)))


@dataclass(frozen=True, eq=False)
class CraterResult:
    """A cratered body and its catalogue (in age order)."""

    body: Body
    catalog: CraterCatalog


# ----------------------------------------------------------------------------------------
# compiled kernels


@numba.njit(cache=True)
def _gather(m, cx, cy, cz, ex, ey, ez, nx, ny, nz, rc, angle, limit):
    """Vertices within ``angle`` of the centre: indices, arc distance s (m) and azimuth."""
    ranges = np.empty((2 * m + 1, 3), dtype=np.int64)
    rows = cap_ranges(m, cx, cy, cz, angle, ranges)
    total = 0
    for r in range(rows):
        total += ranges[r, 2]
    idx = np.empty(total, np.int64)
    dist = np.empty(total)
    theta = np.empty(total)
    k = 0
    for r in range(rows):
        g = ranges[r, 0]
        n = ring_size(m, g)
        o = ring_offset(m, g)
        for j in range(ranges[r, 2]):
            i = o + ((ranges[r, 1] + j) % n)
            ux, uy, uz = unit_vertex(m, i)
            dot = ux * cx + uy * cy + uz * cz
            wx = uy * cz - uz * cy
            wy = uz * cx - ux * cz
            wz = ux * cy - uy * cx
            gamma = math.atan2(math.sqrt(wx * wx + wy * wy + wz * wz), dot)
            s = rc * gamma
            if s > limit:
                continue
            idx[k] = i
            dist[k] = s
            theta[k] = math.atan2(ux * nx + uy * ny + uz * nz, ux * ex + uy * ey + uz * ez)
            k += 1
    return idx[:k], dist[:k], theta[:k]


@numba.njit(cache=True)
def _local_dem(radii, idx, dist, theta, rc, spacing, half):
    """Return the crater's grid of heights r - R_c, holes filled from eight directions.

    A hole with no neighbour in any direction stays NaN.

    Cell (i, j) is centred at east (j - half) * spacing, north (half - i) * spacing.
    """
    size = 2 * half + 1
    total = np.zeros((size, size))
    count = np.zeros((size, size), np.int64)
    for k in range(idx.size):
        x = dist[k] * math.cos(theta[k]) / spacing
        y = dist[k] * math.sin(theta[k]) / spacing
        j = int(math.floor(x + 0.5)) + half
        i = half - int(math.floor(y + 0.5))
        if 0 <= i < size and 0 <= j < size:
            total[i, j] += radii[idx[k]] - rc
            count[i, j] += 1
    dem = np.empty((size, size))
    for i in range(size):
        for j in range(size):
            dem[i, j] = total[i, j] / count[i, j] if count[i, j] > 0 else math.nan
    for i in range(size):
        for j in range(size):
            if count[i, j] > 0:
                continue
            acc = 0.0
            weight = 0.0
            for di in range(-1, 2):
                for dj in range(-1, 2):
                    if di == 0 and dj == 0:
                        continue
                    step = math.sqrt(di * di + dj * dj)
                    a, b = i + di, j + dj
                    n = 1
                    while 0 <= a < size and 0 <= b < size:
                        if count[a, b] > 0:
                            w = 1.0 / (n * step)
                            acc += w * total[a, b] / count[a, b]
                            weight += w
                            break
                        a += di
                        b += dj
                        n += 1
            if weight > 0.0:
                dem[i, j] = acc / weight
    return dem


class RimTables(NamedTuple):
    """A crater's rim, as one numba argument of :func:`_impact`.

    Attributes
    ----------
    irregular : bool
        Whether the rim radius varies with azimuth.
    table : (m,) float64
        Rim radius offsets per azimuth, in diameters (:func:`terrain.craters.overlay.rim_table`).
    terrain : (n,) float64, metres
        The terrain's height above the plane at the rim, per azimuth
        (:func:`terrain.craters.cratering.rim_terrain`).
    """

    irregular: bool
    table: np.ndarray
    terrain: np.ndarray


class OverlayPatch(NamedTuple):
    """A crater's roughness overlay, as one numba argument of :func:`_impact`.

    Attributes
    ----------
    rough : bool
        Whether the overlay is on (otherwise the patch is ignored).
    patch : (k, k) float64, metres
        The overlay heights (:func:`terrain.craters.overlay.overlay_patch`).
    spacing : float, metres
        Patch sample spacing.
    half_extent : float, metres
        Half the patch's side.
    """

    rough: bool
    patch: np.ndarray
    spacing: float
    half_extent: float


@numba.njit(cache=True)
def _impact(radii, idx, dist, theta, rc, diameter, rim: RimTables, overlay: OverlayPatch,
            plane: tuple[float, float, float], profile: Profile):
    """Rescale each vertex radius by the crater's new height (see the module docstring).

    ``rim`` holds the crater's rim tables (:class:`RimTables`), ``overlay`` its roughness
    patch (:class:`OverlayPatch`), ``plane`` the fitted plane (p0, px, py) and ``profile``
    its profile coefficients (:class:`terrain.craters.crater.Profile`).
    """
    irregular = rim.irregular
    table = rim.table
    terrain_table = rim.terrain
    rough = overlay.rough
    patch = overlay.patch
    spacing = overlay.spacing
    half_extent = overlay.half_extent
    p0, px, py = plane
    curvature = profile.curvature
    floor = profile.floor
    hr = profile.rim_height
    ejecta = profile.ejecta
    beta = profile.beta
    ca = profile.a
    cb = profile.b
    c2 = profile.c2
    c3 = profile.c3
    cplx = profile.complex
    radius = 0.5 * diameter
    for k in range(idx.size):
        th = theta[k]
        if irregular:
            rt = radius + periodic_sample(table, th) * diameter
        else:
            rt = radius
        x = dist[k] / rt - 1.0
        if x > 1.0:
            continue
        dx = dist[k] * math.cos(th)
        dy = dist[k] * math.sin(th)
        ov = patch_value(patch, spacing, half_extent, dx, dy) if rough else 0.0
        i = idx[k]
        if x <= 0.0:
            plane = p0 + px * dx + py * dy
            rim_offset = periodic_sample(terrain_table, th)
            h = crater_interior(x, curvature, floor, hr + rim_offset, cplx)
            # the terrain's relief about its smoothed rim level fades out down the inner
            # wall, so the rim joins the ejecta continuously (see the module docstring)
            residual = (radii[i] - rc) - (plane + rim_offset)
            radii[i] = rc + (plane + h + ov + residual * (1.0 - obliteration(x)))
        else:
            radii[i] += exterior_height(x, hr, ejecta, beta, ca, cb, c2, c3) + ov * (1.0 - x)


# ----------------------------------------------------------------------------------------
# orchestration


def _frame(c):
    """East ``z x c / |z x c|`` and north ``c x east`` at unit direction c (east = x at a pole)."""
    e = np.cross([0.0, 0.0, 1.0], c)
    norm = float(np.linalg.norm(e))
    e = np.array([1.0, 0.0, 0.0]) if norm < 1e-12 else e / norm
    return e, np.cross(c, e)


def add_craters(body: Body, craters: Placement, *, seed: int,
                model: CraterModel | None = None, settings: CraterSettings | None = None,
                progress=None) -> CraterResult:
    """Add craters to a body in age order (section V.A).

    Parameters
    ----------
    body : Body
    craters : Placement
        Crater centres, diameters (m), ages (Gyr) and identities (:func:`sample_craters`,
        :func:`craters_at`).
    seed : int
        Keys every crater's roughness.
    model : CraterModel, optional
        Overrides ``settings.model``.
    settings : CraterSettings, optional
    progress : callable, optional
        ``progress(done, total)`` now and then.

    Returns
    -------
    CraterResult
    """
    seed = check_seed(seed)
    settings = settings or CraterSettings()
    if model is not None:
        settings = CraterSettings(model, settings.max_extent_deg, settings.slope)
    model = settings.model
    _check_extent(craters.diameters, body.radius, settings)
    mesh: SphereMesh = body.mesh
    m = mesh.magnitude
    n = len(craters)
    memory.require(body.mesh.n_vertices * 8.0 * 2 + n * 200.0,
                   f"adding {n:,} craters to {mesh.n_vertices:,} vertices")
    radii = np.array(body.radii, dtype=np.float64, copy=True)
    order = np.lexsort((craters.uid, -craters.ages))
    cr = craters.take(order)
    depth_f0, rim_f0 = model.erosion.factors(cr.ages, cr.diameters)
    depth_f0 = np.atleast_1d(depth_f0)
    rim_f0 = np.atleast_1d(rim_f0)
    factor = model.footprint_factor
    irregular = model.rim.effective_amplitude > 0.0
    rough = model.roughness.enabled
    rough_params = model.roughness.as_array()
    table = np.zeros(RIM_SAMPLES)
    rim_buffer = np.zeros(RIM_TERRAIN_SAMPLES)
    params = np.zeros(7)
    unit_spacing = mesh.mean_spacing
    cols = {name: np.zeros(n) for name in CRATER_COLUMNS}
    cols["id"] = cr.uid.copy()
    cols["size_class"] = cr.size_class.copy()
    cols["applied"] = np.zeros(n, np.int64)
    lat, lon = cr.latitude, cr.longitude
    cols["lat_deg"], cols["lon_deg"] = np.degrees(lat), np.degrees(lon)
    cols["x"], cols["y"], cols["z"] = cr.directions.T.copy()
    cols["diameter_m"], cols["age_gyr"] = cr.diameters.copy(), cr.ages.copy()
    cols["extent_deg"] = np.degrees(2.0 * cr.diameters / body.radius)
    step = max(1, n // 200)
    for k in range(n):
        if progress is not None and k % step == 0:
            progress(k, n)
        c = cr.directions[k]
        d = float(cr.diameters[k])
        uid = cr.uid[k]  # numpy uint64: the type terrain's kernels were compiled for
        e, nn = _frame(c)
        rc = surface_radius_scalar(m, radii, c[0], c[1], c[2])
        delta = unit_spacing * rc
        half = int(math.ceil(0.5 * d * factor / delta)) + DEM_MARGIN
        reach = d * factor
        limit = max(reach, math.sqrt(2.0) * (half + 0.5) * delta)
        angle = min(math.pi, limit / rc)
        idx, dist, theta = _gather(m, c[0], c[1], c[2], e[0], e[1], e[2], nn[0], nn[1], nn[2],
                                   rc, angle, limit)
        dem = _local_dem(radii, idx, dist, theta, rc, delta, half)
        size = 2 * half + 1
        x0 = -(half + 0.5) * delta
        y0 = (half + 0.5) * delta
        p0, px, py, nvalid, rms, pix = fit_plane(dem, 0, 0, size, size, x0, y0, delta, 0.0,
                                                  0.0, 0.5 * d)
        slope = math.atan(math.hypot(px, py)) if nvalid >= 3 else math.nan
        sf = settings.slope.factor(slope) if nvalid >= 3 else 0.0
        if model.slope.enabled and nvalid >= 3 and math.isfinite(slope):
            # faster degradation on steep ground (terrain.craters.erosion.SlopeDegradation), then
            # the paper's artefact guard on the steepest slopes
            d0, r0 = model.factors(cr.ages[k], d, slope)
            depth_f0[k], rim_f0[k] = float(d0), float(r0)
        depth_f = float(depth_f0[k]) * sf
        rim_f = float(rim_f0[k]) * sf
        s = shape_arrays(np.array([d]), np.array([depth_f]), np.array([rim_f]),
                         model.morphology)
        cols["depth_fraction"][k] = depth_f
        cols["rim_fraction"][k] = rim_f
        cols["slope_deg"][k] = math.degrees(slope)
        cols["slope_factor"][k] = sf
        cols["depth_m"][k] = s["depth"][0]
        cols["rim_height_m"][k] = s["rim_height"][0]
        cols["alpha"][k] = s["alpha"][0]
        cols["beta"][k] = s["beta"][0]
        cols["reference_radius_m"][k] = rc + p0 if nvalid >= 3 else math.nan
        if nvalid < 3 or sf <= 0.0:
            continue
        if irregular:
            rim_table(seed, uid, model.rim.effective_amplitude, model.rim.hurst, table)
        n_az = RIM_TERRAIN_MIN
        while n_az < RIM_TERRAIN_SAMPLES and n_az * 2.0 * delta < math.pi * d:
            n_az *= 2
        terrain_table = rim_buffer[:n_az]
        rim_terrain(dem, 0, 0, size, size, x0, y0, delta, 0.0, 0.0, 0.5 * d, d, p0, px, py,
                    irregular, table, terrain_table)
        if rough:
            level = int(round(math.log2(max(2.0, 2.0 * (reach + delta) / delta))))
            level = min(MAX_PATCH_LEVEL, max(1, level))
            half_extent = reach + delta
            spacing = 2.0 * half_extent / 2**level
            patch = np.empty((2**level + 1, 2**level + 1))
            crater_params(rough_params, d, depth_f, rms, pix, level, params)
            cplx = s["complex"][0]
            region = cplx[0] if cplx[0] > -1.0 else float(s["alpha"][0])
            overlay_patch(seed, uid, level, spacing, d, region, params, patch)
        else:
            half_extent, spacing, patch = 0.0, 1.0, np.zeros((2, 2))
        hr = float(s["rim_height"][0])
        curvature = float(s["fresh_rim_height"][0]) - hr + float(s["depth"][0])
        floor = hr - float(s["depth"][0])
        profile = Profile(curvature, floor, hr, float(s["ejecta"][0]), float(s["beta"][0]),
                          float(s["a"][0]), float(s["b"][0]), float(s["c2"][0]),
                          float(s["c3"][0]), s["complex"][0])
        _impact(radii, idx, dist, theta, rc, d, RimTables(irregular, table, terrain_table),
                OverlayPatch(rough, patch, spacing, half_extent), (p0, px, py), profile)
        cols["applied"][k] = 1
    if progress is not None:
        progress(n, n)
    bad = ~(radii > 0)
    if bad.any():
        raise InvalidParameterError(
            f"craters dug through the body at {int(bad.sum())} vertices; lower dmax")
    applied = int(cols["applied"].sum())
    log.info("applied %d of %d craters (%d skipped on steep slopes)", applied, n, n - applied)
    meta = dict(craters=dict(count=n, applied=applied, seed=seed, settings=settings.as_dict()))
    return CraterResult(body.replace(radii=radii, **meta), CraterCatalog.from_columns(cols))
