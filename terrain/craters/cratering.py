"""Adding craters to terrain: composition order, windows, and the compiled crater kernel.

Each crater is the profile of :mod:`terrain.craters.crater` on a plane fitted to the terrain it
lands on, with its rim riding on the terrain along every radius (``Tr``, ``Pr``), plus the
roughness of :mod:`terrain.craters.overlay`. What remains is the order in which craters see each
other, and that decides whether a window can be computed alone.

Composition order (and why)
---------------------------
If every crater were fitted to the terrain left by *all* older craters (the paper's literal
order), a pixel would depend on chains of overlapping craters that can cross the whole tile,
and no finite halo would make a window exact. We bound the chain as the paper's nested layers
do:

1. Craters are grouped into octave size classes and the classes are applied from the largest
   to the smallest. Every crater of a class is fitted (plane and rim terrain ``Tr``) to the
   terrain ``T`` as it stood after all larger classes.
2. Within a class, craters are composed per pixel in age order, oldest first (ties broken by
   the crater's id). Ejecta adds its change on top of what is there. A bowl replaces what is
   under it: inside the rim the height becomes the crater's ``P + h_in``, plus a residual
   that survives only near the rim: the class's earlier changes ``z - T`` and the terrain's
   deviation from the smoothed rim level the interior profile was built on
   (``T - P - (Tr - Pr)``, see :func:`rim_terrain`), weighted by one minus the obliteration
   factor, which is 1 on the floor and lower wall (x <= -:data:`OBLITERATION_BLEND`) and falls
   smoothly (smoothstep) to 0 at the rim. So a younger crater erases older same-class craters
   inside it, and its rim meets the exterior, which rides the real terrain and any older
   ejecta, without a step.

A pixel therefore depends only on the craters whose footprints cover it and on ``T`` within
their footprints: a halo of about 1.5 footprint radii per class (a few Dmax in all) makes any
window exact, bitwise. Only one crater of each class is ever in the same place at once.

What it costs in fidelity: within a class (diameters within a factor of two), a younger
crater's plane and rim terrain ignore the older craters of the same class, so a crater landing
on the ejecta of a similar-sized older one is not tilted by it, and older same-class relief
fades out on the younger crater's upper wall instead of being cut at the rim. Across classes
(smaller craters on larger ones) the model is the paper's: small craters sit on the slopes,
rims and floors of larger ones. Ages are respected within a class, not across classes: a
small old crater is never erased by a large young one (it is fitted onto it instead), which
on the real Moon is how the oldest small craters look anyway, fully eroded.

Pixels outside the DEM (a crater centred near an edge) are sampled from the nearest edge
pixel. Invalid pixels stay invalid; a crater whose plane has fewer than three valid samples
is skipped.
"""

from __future__ import annotations

import logging
import math
from dataclasses import asdict, dataclass, field, replace
from typing import NamedTuple

import numba
import numpy as np

from terrain.core import memory
from terrain.core import metakeys as mk
from terrain.core.arctan import atan2
from terrain.core.errors import InvalidParameterError
from terrain.core.parallel import run_blocks
from terrain.core.rng import check_seed
from terrain.core.tile import DEMTile, Window
from terrain.craters.catalog import CraterCatalog, CraterTable
from terrain.craters.crater import Morphology, crater_interior, exterior_height, shape_arrays
from terrain.craters.diffusion import DiffusionModel
from terrain.craters.erosion import ErosionModel, SlopeDegradation
from terrain.craters.overlay import (
    MAX_PATCH_LEVEL,
    RIM_SAMPLES,
    RimIrregularity,
    Roughness,
    crater_params,
    overlay_patch_part,
    patch_row,
    patch_value_in_row,
    periodic_sample,
    rim_table,
    smooth_periodic,
)
from terrain.craters.population import Population

__all__ = ["OBLITERATION_BLEND", "CraterModel", "CraterResult", "add_craters",
           "class_planes", "crater_heights", "describe_craters", "fit_plane",
           "obliteration", "rim_terrain"]

log = logging.getLogger(__name__)

#: Width (in x) of the inner-wall band over which older same-class relief fades out.
OBLITERATION_BLEND = 0.25
#: Most rings of the plane-fit sampling pattern (ring k holds 8k points).
PLANE_RINGS_MAX = 8
#: Most azimuths of the rim-terrain table (Tr - Pr along each radius); small craters use
#: fewer, about one per two pixels of rim, never fewer than RIM_TERRAIN_MIN.
RIM_TERRAIN_SAMPLES = 64
RIM_TERRAIN_MIN = 8
#: Bilinear samples averaged into each rim-terrain table entry (spread over one entry's arc).
RIM_TERRAIN_TAPS = 3
#: Circular binomial passes over the rim-terrain table (a low-pass of about 1/12 turn at 64).
RIM_TERRAIN_SMOOTHING = 4


@dataclass(frozen=True)
class CraterModel:
    """Everything about how a crater looks besides where it is.

    Erosion with age (the Ross/Soderblom :class:`terrain.craters.erosion.ErosionModel`, or
    topographic diffusion, :class:`terrain.craters.diffusion.DiffusionModel`), roughness and
    irregular rim (:mod:`terrain.craters.overlay`), which craters are complex
    (:class:`terrain.craters.crater.Morphology`),
    faster degradation on steep ground (:class:`terrain.craters.erosion.SlopeDegradation`),
    and ``min_depth_ratio``: a simple crater eroded below this d/D is gone (not drawn, not
    catalogued), as craters degraded past visibility are on the Moon (0: every crater stays).
    """

    erosion: ErosionModel | DiffusionModel = field(default_factory=ErosionModel.default)
    roughness: Roughness = field(default_factory=Roughness)
    rim: RimIrregularity = field(default_factory=RimIrregularity)
    morphology: Morphology = field(default_factory=Morphology)
    slope: SlopeDegradation = field(default_factory=SlopeDegradation)
    min_depth_ratio: float = 0.0

    def __post_init__(self):
        v = float(self.min_depth_ratio)
        if not 0.0 <= v < 1.0:
            raise InvalidParameterError(f"min_depth_ratio must lie in [0, 1); got {v}")
        object.__setattr__(self, "min_depth_ratio", v)

    def smooth(self, **changes) -> CraterModel:
        """Return the same model with the fractal overlay and the irregular rim switched off.

        Parameters
        ----------
        **changes
            Further fields to replace (``model.smooth(slope=SlopeDegradation(False))``).

        Returns
        -------
        CraterModel
        """
        return replace(self, roughness=Roughness(enabled=False),
                       rim=RimIrregularity(enabled=False), **changes)

    def factors(self, age, diameter, slope) -> tuple[np.ndarray, np.ndarray]:
        """Return the depth and rim fractions erosion leaves.

        Parameters
        ----------
        age : float or (n,) float, Gyr
        diameter : float or (n,) float, metres
        slope : float or (n,) float, radians
            Slope of the ground under each crater; a crater whose plane could not be fitted
            (NaN) is aged as on flat ground.

        Returns
        -------
        depth_fraction, rim_fraction : (n,) float64
            Of the fresh crater's depth and rim height.
        """
        slope = np.nan_to_num(np.asarray(slope, dtype=float), nan=0.0)
        return self.erosion.factors(self.slope.effective_age(age, slope), diameter)

    @property
    def footprint_factor(self) -> float:
        """Largest footprint radius over D (1 for a circular rim)."""
        return 1.0 + 2.0 * self.rim.effective_amplitude

    def as_dict(self) -> dict:
        """Return the model as plain data for metadata (``CRATERSCAPE_CRATER_MODEL``)."""
        return dict(erosion=self.erosion.as_dict(), roughness=asdict(self.roughness),
                    rim=asdict(self.rim), morphology=self.morphology.as_dict(),
                    slope_degradation=self.slope.as_dict(),
                    **({"min_depth_ratio": self.min_depth_ratio} if self.min_depth_ratio
                       else {}))


@dataclass(frozen=True, eq=False)
class CraterResult:
    """A cratered tile and the catalogue of every crater that touches it."""

    tile: DEMTile
    catalog: CraterCatalog


# ----------------------------------------------------------------------------------------
# compiled kernel


@numba.njit(cache=True)
def _bilinear(T, tr0, tc0, nrows, ncols, x0, y0, res, x, y):
    """Bilinear height of the pre-class terrain at map (x, y), clamped to the DEM's edges."""
    fr = min(max((y0 - y) / res - 0.5, 0.0), nrows - 1.0)
    fc = min(max((x - x0) / res - 0.5, 0.0), ncols - 1.0)
    i0 = int(fr)
    j0 = int(fc)
    i1 = min(i0 + 1, nrows - 1)
    j1 = min(j0 + 1, ncols - 1)
    ti = fr - i0
    tj = fc - j0
    a0 = i0 - tr0
    a1 = i1 - tr0
    b0 = j0 - tc0
    b1 = j1 - tc0
    if a0 < 0 or b0 < 0 or a1 >= T.shape[0] or b1 >= T.shape[1]:
        raise IndexError("crater kernel read outside its halo")
    return ((T[a0, b0] * (1.0 - tj) + T[a0, b1] * tj) * (1.0 - ti)
            + (T[a1, b0] * (1.0 - tj) + T[a1, b1] * tj) * ti)


@numba.njit(cache=True)
def _laplacian(T, tr0, tc0, nrows, ncols, x0, y0, res, x, y):
    """Pixel nearest (x, y) minus the mean of its four neighbours (NaN at DEM edges/gaps)."""
    i = int(math.floor((y0 - y) / res))
    j = int(math.floor((x - x0) / res))
    if i < 1 or j < 1 or i > nrows - 2 or j > ncols - 2:
        return math.nan
    a = i - tr0
    b = j - tc0
    if a < 1 or b < 1 or a > T.shape[0] - 2 or b > T.shape[1] - 2:
        raise IndexError("crater kernel read outside its halo")
    return T[a, b] - 0.25 * (T[a - 1, b] + T[a + 1, b] + T[a, b - 1] + T[a, b + 1])


@numba.njit(cache=True)
def _ring_directions(rings):
    """(cos, sin) of the azimuth of each point of the plane-fit pattern's rings 0 .. rings.

    Ring k (8k points, 1 at the centre) starts at row 1 + 4 k (k - 1); every crater's fit
    reads its directions here instead of evaluating them again (the same values, bitwise).
    """
    out = np.empty((1 + 4 * rings * (rings + 1), 2))
    for k in range(rings + 1):
        count = 1 if k == 0 else 8 * k
        start = 0 if k == 0 else 1 + 4 * k * (k - 1)
        for m in range(count):
            ang = 2.0 * math.pi * (m + 0.5 * (k % 2)) / count
            out[start + m, 0] = math.cos(ang)
            out[start + m, 1] = math.sin(ang)
    return out


#: :func:`_ring_directions` of the largest pattern (numba reads it as a constant).
RING_DIRECTIONS = _ring_directions(PLANE_RINGS_MAX)


@numba.njit(cache=True)
def fit_plane(T, tr0, tc0, nrows, ncols, x0, y0, res, cx, cy, radius):
    """Least-squares plane z = p0 + px dx + py dy over a symmetric polar pattern in the bowl.

    Returns (p0, px, py, valid samples, RMS residual, pixel roughness). The pattern (centre
    plus rings of 8k points) samples the terrain bilinearly, so the fit does not depend on
    how the pixel grid falls. Heights are accumulated relative to the first valid sample, so
    that absolute heights of kilometres do not swamp the residual. The pixel roughness is the
    RMS of (pixel - mean of its four neighbours) at the pixels nearest the samples.

    Parameters
    ----------
    T : (h, w) float64, metres
        Terrain heights of a part of the DEM (NaN unknown).
    tr0, tc0 : int
        The DEM pixel (row, col) of ``T[0, 0]``.
    nrows, ncols : int
        Size of the whole DEM.
    x0, y0 : float, map metres
        The whole DEM's upper-left corner.
    res : float, metres
        Pixel size.
    cx, cy : float, map metres
        Centre of the pattern.
    radius : float, metres
        Radius of the pattern (the bowl's, D / 2).

    Returns
    -------
    p0 : float, metres
        The plane's height at the centre (NaN without valid samples).
    px, py : float
        Its slopes along x and y (metres per metre).
    samples : float
        Valid samples used.
    rms : float, metres
        RMS residual of the samples about the plane.
    pixel_roughness : float, metres
    """
    rings = min(PLANE_RINGS_MAX, max(2, int(math.ceil(radius / res))))
    n = 0.0
    ref = math.nan
    sx = sy = sxx = sxy = syy = sz = sxz = syz = szz = 0.0
    npix = 0.0
    spix = 0.0
    for k in range(rings + 1):
        count = 1 if k == 0 else 8 * k
        start = 0 if k == 0 else 1 + 4 * k * (k - 1)
        rk = radius * k / rings
        for m in range(count):
            dx = rk * RING_DIRECTIONS[start + m, 0]
            dy = rk * RING_DIRECTIONS[start + m, 1]
            lap = _laplacian(T, tr0, tc0, nrows, ncols, x0, y0, res, cx + dx, cy + dy)
            if not math.isnan(lap):
                npix += 1.0
                spix += lap * lap
            z = _bilinear(T, tr0, tc0, nrows, ncols, x0, y0, res, cx + dx, cy + dy)
            if math.isnan(z):
                continue
            if n == 0.0:
                ref = z
            z -= ref
            n += 1.0
            sx += dx
            sy += dy
            sxx += dx * dx
            sxy += dx * dy
            syy += dy * dy
            sz += z
            sxz += dx * z
            syz += dy * z
            szz += z * z
    pix = math.sqrt(spix / npix) if npix > 0 else 0.0
    if n < 3.0:
        return math.nan, math.nan, math.nan, n, math.nan, pix
    det = n * (sxx * syy - sxy * sxy) - sx * (sx * syy - sxy * sy) + sy * (sx * sxy - sxx * sy)
    if not det > 1e-9 * n * sxx * syy:
        p0 = sz / n
        return p0 + ref, 0.0, 0.0, n, math.sqrt(max(0.0, szz / n - p0 * p0)), pix
    p0 = (sz * (sxx * syy - sxy * sxy) - sx * (sxz * syy - sxy * syz)
          + sy * (sxz * sxy - sxx * syz)) / det
    px = (n * (sxz * syy - sxy * syz) - sz * (sx * syy - sxy * sy)
          + sy * (sx * syz - sxz * sy)) / det
    py = (n * (sxx * syz - sxz * sxy) - sx * (sx * syz - sxz * sy)
          + sz * (sx * sxy - sxx * sy)) / det
    rss = szz - (p0 * sz + px * sxz + py * syz)  # normal-equation identity
    return p0 + ref, px, py, n, math.sqrt(max(0.0, rss / n)), pix


@numba.njit(cache=True)
def rim_terrain(T, tr0, tc0, nrows, ncols, x0, y0, res, cx, cy, radius, d, p0, px, py,
                 irregular, rim, out):
    """Fill ``out`` with Tr - Pr, the terrain's height above the plane at the rim, per azimuth.

    Entry m belongs to azimuth theta_m = 2 pi m / n - pi and averages RIM_TERRAIN_TAPS
    bilinear samples spread over its arc: the rim follows the terrain's undulations at the
    scale of the crater, not pixel noise, which would otherwise streak the inner wall
    radially; the table is then low-passed (RIM_TERRAIN_SMOOTHING binomial passes) and read
    with cubic interpolation. Unknown terrain counts as on the plane.

    Parameters
    ----------
    T, tr0, tc0, nrows, ncols, x0, y0, res
        The terrain and the DEM's grid, as for :func:`fit_plane`.
    cx, cy : float, map metres
        Crater centre.
    radius, d : float, metres
        Rim radius and diameter.
    p0, px, py : float
        The crater's plane (:func:`fit_plane`).
    irregular : bool
        Whether the rim radius varies with azimuth (by ``rim``, in units of D).
    rim : (m,) float64
        The irregular rim's radius table (:func:`terrain.craters.overlay.rim_table`).
    out : (n,) float64, metres
        Filled with the table.
    """
    n = out.size
    taps = RIM_TERRAIN_TAPS
    step = 2.0 * math.pi / (n * taps)
    # Unit vectors of the n * taps equally spaced tap azimuths, by rotation.
    cs, sn = math.cos(step), math.sin(step)
    th0 = -math.pi - step * (taps - 1) / 2.0
    c, s = math.cos(th0), math.sin(th0)
    for m in range(n):
        acc = 0.0
        cnt = 0
        for q in range(taps):
            th = th0 + (m * taps + q) * step
            rt = radius + periodic_sample(rim, th) * d if irregular else radius
            ox = rt * c
            oy = rt * s
            c, s = c * cs - s * sn, s * cs + c * sn
            z = _bilinear(T, tr0, tc0, nrows, ncols, x0, y0, res, cx + ox, cy + oy)
            if not math.isnan(z):
                acc += z - (p0 + px * ox + py * oy)
                cnt += 1
        out[m] = acc / cnt if cnt > 0 else 0.0
    smooth_periodic(out, RIM_TERRAIN_SMOOTHING)


@numba.njit(cache=True)
def obliteration(x):
    """Return how much older relief a crater erases: 1 inside, smoothstep down to 0 at the rim.

    Parameters
    ----------
    x : float
        Radial position relative to the rim (0 at the rim, negative inside; in units of the
        rim radius, as :data:`OBLITERATION_BLEND`).

    Returns
    -------
    float
        1 for ``x <= -OBLITERATION_BLEND``, 0 at the rim, smooth in between (defined for
        ``x <= 0``, the crater's inside).
    """
    if x <= -OBLITERATION_BLEND:
        return 1.0
    t = (x + OBLITERATION_BLEND) / OBLITERATION_BLEND
    return 1.0 - t * t * (3.0 - 2.0 * t)


@numba.njit(cache=True)
def class_planes(T, tr0, tc0, nrows, ncols, x0, y0, res, cx, cy, diam):
    """Return the :func:`fit_plane` results of the craters of one size class.

    Each crater's plane is fitted over its bowl on the terrain ``T`` before its class, so the
    planes (and the slope-dependent degradation they decide) need only that terrain.

    Parameters
    ----------
    T, tr0, tc0, nrows, ncols, x0, y0, res
        The terrain and the DEM's grid, as for :func:`fit_plane`.
    cx, cy : (n,) float64, map metres
        Crater centres.
    diam : (n,) float64, metres
        Crater diameters.

    Returns
    -------
    (n, 6) float64
        Per crater: p0, px, py, samples, RMS, pixel roughness.
    """
    out = np.empty((cx.size, 6))
    _planes_range(T, tr0, tc0, nrows, ncols, x0, y0, res, cx, cy, diam,
                  np.arange(cx.size), out, 0, cx.size)
    return out


@numba.njit(cache=True, nogil=True)
def _planes_range(T, tr0, tc0, nrows, ncols, x0, y0, res, cx, cy, diam, order, out, first,
                  last):
    """Fill the rows ``order[first .. last - 1]`` of :func:`class_planes`' result ``out``."""
    for t in range(first, last):
        n = order[t]
        p0, px, py, nvalid, rms, pix = fit_plane(T, tr0, tc0, nrows, ncols, x0, y0, res,
                                                  cx[n], cy[n], 0.5 * diam[n])
        out[n, 0] = p0
        out[n, 1] = px
        out[n, 2] = py
        out[n, 3] = nvalid
        out[n, 4] = rms
        out[n, 5] = pix


#: Craters per parallel block of plane fits.
PLANE_BLOCK = 256


def _class_planes_parallel(T, tr0, tc0, nrows, ncols, x0, y0, res, cx, cy, diam) -> np.ndarray:
    """:func:`class_planes` on every core (each crater's fit is its own: the same bytes)."""
    out = np.empty((cx.size, 6))
    blocks = (cx.size + PLANE_BLOCK - 1) // PLANE_BLOCK
    # fitted from north to south, so that neighbouring fits read terrain rows still in cache
    order = np.argsort(-cy, kind="stable")

    def kernel(first_block, last_block):
        _planes_range(T, tr0, tc0, nrows, ncols, x0, y0, res, cx, cy, diam, order, out,
                      first_block * PLANE_BLOCK, min(cx.size, last_block * PLANE_BLOCK))

    run_blocks(kernel, blocks)
    return out


class ClassCraters(NamedTuple):
    """The craters of one size class as named arrays, in composition (age) order.

    A namedtuple of arrays, which numba passes to :func:`_apply_class` as one argument
    (fields read as ``craters.x[n]``). All arrays have the class's length n.

    Attributes
    ----------
    x, y : (n,) float64, metres
        Centres, map coordinates.
    diameter : (n,) float64, metres
    depth, rim_height, fresh_rim_height : (n,) float64, metres
        Degraded depth and rim height, and the fresh rim height (:func:`shape_arrays`).
    ejecta, beta, a, b, c2, c3, alpha : (n,) float64
        Exterior and wall profile coefficients (:class:`terrain.craters.crater.CraterShape`).
    depth_fraction : (n,) float64
        Degraded depth over fresh depth (erosion).
    uid : (n,) uint64
        Each crater's key of its random draws.
    planes : (n, 6) float64
        :func:`class_planes` results (p0, px, py, samples, RMS, pixel roughness).
    complex : (n, 7) float64
        :data:`terrain.craters.crater.COMPLEX_FIELDS` of each crater.
    """

    x: np.ndarray
    y: np.ndarray
    diameter: np.ndarray
    depth: np.ndarray
    rim_height: np.ndarray
    fresh_rim_height: np.ndarray
    ejecta: np.ndarray
    beta: np.ndarray
    a: np.ndarray
    b: np.ndarray
    c2: np.ndarray
    c3: np.ndarray
    alpha: np.ndarray
    depth_fraction: np.ndarray
    uid: np.ndarray
    planes: np.ndarray
    complex: np.ndarray


class ClassSettings(NamedTuple):
    """What every crater of a run shares, as one numba argument of :func:`_apply_class`.

    Attributes
    ----------
    seed : int
        Key of every random draw.
    rim_amplitude, rim_hurst : float
        Rim irregularity (:class:`RimIrregularity`); amplitude 0 for circular rims.
    rough : bool
        Whether the roughness overlay is on.
    rough_params : (k,) float64
        The overlay's parameters (:meth:`CraterRoughness.as_array`).
    footprint_factor : float
        Reach of a crater's change in diameters.
    gaps : bool
        Whether the terrain has unknown (NaN) pixels, which craters leave alone; without
        any, the stamp does not read the pre-class terrain at every pixel to look for them.
    """

    seed: int
    rim_amplitude: float
    rim_hurst: float
    rough: bool
    rough_params: np.ndarray
    footprint_factor: float
    gaps: bool


#: Output rows of one parallel band of a size class: each band composes, in age order, the
#: craters that reach it, writing its own rows only.
BAND_ROWS = 32
#: Most patch values (float64) prepared at once: the class's craters are composed in groups
#: whose roughness patches together stay under this (8 MiB, to be read back from cache; at
#: 16 MiB the smallest craters' stamps read them back more slowly on a loaded machine).
PATCH_BUDGET = 1 << 20


@numba.njit(cache=True)
def _patch_level(d, res, footprint_factor):
    """Return the roughness patch level of a crater of diameter ``d`` (its side 2^level + 1)."""
    reach = d * footprint_factor
    level = int(round(math.log2(max(2.0, 2.0 * (reach + res) / res))))
    return min(MAX_PATCH_LEVEL, max(1, level))


def _apply_class(T, tr0, tc0, out, or0, oc0, nrows, ncols, x0, y0, res,
                 craters: ClassCraters, settings: ClassSettings) -> None:
    """Compose one size class of craters (already in age order) onto ``out``.

    ``T`` is the terrain before this class (origin tr0, tc0 in DEM pixels); ``out`` starts as
    a copy of T over the class's region (origin or0, oc0) and is updated in place.
    ``craters`` holds the class's craters (:class:`ClassCraters`), ``settings`` what they
    share (:class:`ClassSettings`).

    On every core, and bitwise the same on any number (:mod:`terrain.core.parallel`): what
    each crater needs besides the pixels (its rim tables and roughness patch, functions of
    ``T`` and its key alone) is prepared for a group of craters in parallel, then bands of
    :data:`BAND_ROWS` output rows are composed in parallel, each applying the group's
    craters in age order to its own rows, so every pixel sees its craters in the same order
    as on one thread.
    """
    n_all = craters.x.size
    size, reach_rows = _class_extents(craters, settings, y0, res)
    bands = (out.shape[0] + BAND_ROWS - 1) // BAND_ROWS
    first = 0
    while first < n_all:
        total = np.cumsum(size[first:])
        last = first + max(1, int(np.searchsorted(total, PATCH_BUDGET, side="right")))
        offsets = np.zeros(last - first + 1, dtype=np.int64)
        np.cumsum(size[first:last], out=offsets[1:])
        patches = np.empty(int(offsets[-1]))
        tables = np.zeros((last - first, RIM_SAMPLES))
        rim_tables = np.zeros((last - first, RIM_TERRAIN_SAMPLES))
        n_azimuths = np.zeros(last - first, dtype=np.int64)
        # prepared from north to south, so that neighbours read terrain rows still in cache
        order = np.argsort(-craters.y[first:last], kind="stable")
        run_blocks(_prepare_craters, last - first, T, tr0, tc0, nrows, ncols, x0, y0, res,
                   craters, settings, first, order, tables, rim_tables, n_azimuths, patches,
                   offsets, or0, or0 + out.shape[0] - 1, oc0, oc0 + out.shape[1] - 1)
        run_blocks(_stamp_bands, bands, T, tr0, tc0, out, or0, oc0, x0, y0, res, craters,
                   settings, first, last, size, reach_rows, tables, rim_tables, n_azimuths,
                   patches, offsets)
        first = last


@numba.njit(cache=True)
def _class_extents(craters, settings, y0, res):
    """Return each crater's patch size (values) and the output rows it can reach."""
    n_all = craters.x.size
    size = np.zeros(n_all, dtype=np.int64)
    reach_rows = np.zeros((n_all, 2), dtype=np.int64)
    for n in range(n_all):
        rc = (y0 - craters.y[n]) / res - 0.5
        rpix = craters.diameter[n] * settings.footprint_factor / res
        reach_rows[n, 0] = int(math.ceil(rc - rpix))
        reach_rows[n, 1] = int(math.floor(rc + rpix))
        if settings.rough:
            k = 2 ** _patch_level(craters.diameter[n], res, settings.footprint_factor) + 1
            size[n] = k * k
        else:
            size[n] = 4
    return size, reach_rows


@numba.njit(cache=True, nogil=True)
def _prepare_craters(T, tr0, tc0, nrows, ncols, x0, y0, res, craters, settings, first, order,
                     tables, rim_tables, n_azimuths, patches, offsets, or0, or1, oc0, oc1,
                     m_first, m_last):
    """Prepare the group's craters ``first + order[m_first .. m_last - 1]``."""
    for t in range(m_first, m_last):
        m = order[t]
        _prepare_crater(T, tr0, tc0, nrows, ncols, x0, y0, res, craters, settings, first + m,
                        tables[m], rim_tables[m], n_azimuths[m:m + 1],
                        patches[offsets[m]:offsets[m + 1]], or0, or1, oc0, oc1)


@numba.njit(cache=True, nogil=True)
def _stamp_bands(T, tr0, tc0, out, or0, oc0, x0, y0, res, craters, settings, first, last,
                 size, reach_rows, tables, rim_tables, n_azimuths, patches, offsets,
                 band_first, band_last):
    """Compose the group's craters, in age order, onto the bands ``band_first .. last - 1``."""
    azimuths = np.empty(out.shape[1])
    for band in range(band_first, band_last):
        row_first = or0 + band * BAND_ROWS
        row_last = min(or0 + out.shape[0], or0 + (band + 1) * BAND_ROWS) - 1
        for n in range(first, last):
            if (reach_rows[n, 1] < row_first or reach_rows[n, 0] > row_last
                    or craters.planes[n, 3] < 3.0):
                continue
            m = n - first
            k = int(round(math.sqrt(size[n])))
            _stamp_crater(T, tr0, tc0, out, or0, oc0, x0, y0, res, craters, settings, n,
                          tables[m], rim_tables[m, :n_azimuths[m]],
                          patches[offsets[m]:offsets[m + 1]].reshape((k, k)),
                          row_first, row_last, azimuths)


@numba.njit(cache=True)
def _prepare_crater(T, tr0, tc0, nrows, ncols, x0, y0, res, craters, settings, n, table,
                    rim_terrain_table, n_azimuth, patch, or0, or1, oc0, oc1):
    """Fill crater ``n``'s rim tables and roughness patch (functions of ``T`` and its key).

    The rim-terrain table's length goes to ``n_azimuth[0]``; the patch is flat, and holds
    the values the crater's pixels in output rows ``or0 .. or1`` and columns ``oc0 .. oc1``
    (DEM pixels, inclusive) read (:func:`terrain.craters.overlay.overlay_patch_part`).
    """
    if craters.planes[n, 3] < 3.0:
        return
    d = craters.diameter[n]
    irregular = settings.rim_amplitude > 0.0
    if irregular:
        rim_table(settings.seed, craters.uid[n], settings.rim_amplitude, settings.rim_hurst,
                  table)
    n_az = RIM_TERRAIN_MIN
    while n_az < RIM_TERRAIN_SAMPLES and n_az * 2.0 * res < math.pi * d:
        n_az *= 2
    n_azimuth[0] = n_az
    rim_terrain(T, tr0, tc0, nrows, ncols, x0, y0, res, craters.x[n], craters.y[n], 0.5 * d, d,
                craters.planes[n, 0], craters.planes[n, 1], craters.planes[n, 2], irregular,
                table, rim_terrain_table[:n_az])
    if settings.rough:
        level = _patch_level(d, res, settings.footprint_factor)
        reach_m = d * settings.footprint_factor
        half_extent = reach_m + res
        spacing = 2.0 * half_extent / 2**level
        params = np.zeros(7)
        crater_params(settings.rough_params, d, craters.depth_fraction[n], craters.planes[n, 4],
                      craters.planes[n, 5], level, params)
        # the overlay's floor region ends where the flat floor does on a complex crater
        row = craters.complex[n]
        region = row[0] if row[0] > -1.0 else craters.alpha[n]
        k = 2**level + 1
        # The stamp reads the patch's bilinear nodes around its pixels within the reach
        # (less than sqrt 2 spacings from each) and inside the class's region only.
        nodes = k - 1
        rc = (y0 - craters.y[n]) / res - 0.5
        cc = (craters.x[n] - x0) / res - 0.5
        rpix = reach_m / res
        i_lo = max(or0, int(math.ceil(rc - rpix)))
        i_hi = min(or1, int(math.floor(rc + rpix)))
        j_lo = max(oc0, int(math.ceil(cc - rpix)))
        j_hi = min(oc1, int(math.floor(cc + rpix)))
        if i_lo > i_hi or j_lo > j_hi:
            patch[:] = 0.0
            return
        # patch rows grow as the map's y does, against the DEM's rows
        p_lo = int(math.floor(((y0 - (i_hi + 0.5) * res) - craters.y[n] + half_extent)
                              / spacing)) - 1
        p_hi = int(math.floor(((y0 - (i_lo + 0.5) * res) - craters.y[n] + half_extent)
                              / spacing)) + 2
        q_lo = int(math.floor(((x0 + (j_lo + 0.5) * res) - craters.x[n] + half_extent)
                              / spacing)) - 1
        q_hi = int(math.floor(((x0 + (j_hi + 0.5) * res) - craters.x[n] + half_extent)
                              / spacing)) + 2
        overlay_patch_part(settings.seed, craters.uid[n], level, spacing, d, region, params,
                           patch.reshape((k, k)), reach_m / spacing + math.sqrt(2.0),
                           max(0, p_lo), min(nodes, p_hi), max(0, q_lo), min(nodes, q_hi))


@numba.njit(cache=True, error_model="numpy")
def _row_azimuths(x0, res, xc, dy, j_lo, j_hi, out):
    """Fill ``out[:j_hi - j_lo + 1]`` with the azimuths (rad) of the pixels ``j_lo .. j_hi``.

    A loop of :func:`terrain.core.arctan.atan2` alone, which the compiler vectorises; the
    numpy error model only drops the division-by-zero checks that would stop it (``atan2``
    never divides by zero).
    """
    for j in range(j_lo, j_hi + 1):
        out[j - j_lo] = atan2(dy, (x0 + (j + 0.5) * res) - xc)


@numba.njit(cache=True)
def _stamp_crater(T, tr0, tc0, out, or0, oc0, x0, y0, res, craters, settings, n, table,
                  rim_terrain_table, patch, row_first, row_last, azimuths):
    """Compose crater ``n`` onto the output rows ``row_first..row_last`` (DEM pixels).

    ``azimuths`` is scratch space of at least the output's width.
    """
    d = craters.diameter[n]
    radius = 0.5 * d
    xc = craters.x[n]
    yc = craters.y[n]
    p0 = craters.planes[n, 0]
    px = craters.planes[n, 1]
    py = craters.planes[n, 2]
    row = craters.complex[n]
    irregular = settings.rim_amplitude > 0.0
    rough = settings.rough
    gaps = settings.gaps
    reach = d * settings.footprint_factor
    if rough:
        level = _patch_level(d, res, settings.footprint_factor)
        half_extent = reach + res
        spacing = 2.0 * half_extent / 2**level
    else:
        half_extent = 0.0
        spacing = 1.0
    rim_h = craters.rim_height[n]
    curvature = craters.fresh_rim_height[n] - rim_h + craters.depth[n]
    floor = rim_h - craters.depth[n]
    hr = rim_h
    ejecta = craters.ejecta[n]
    beta = craters.beta[n]
    ca = craters.a[n]
    cb = craters.b[n]
    c2 = craters.c2[n]
    c3 = craters.c3[n]
    rc = (y0 - yc) / res - 0.5
    cc = (xc - x0) / res - 0.5
    rpix = reach / res
    i_lo = max(row_first, int(math.ceil(rc - rpix)))
    i_hi = min(row_last, int(math.floor(rc + rpix)))
    j_lo = max(oc0, int(math.ceil(cc - rpix)))
    j_hi = min(oc0 + out.shape[1] - 1, int(math.floor(cc + rpix)))
    for i in range(i_lo, i_hi + 1):
        dy = (y0 - (i + 0.5) * res) - yc
        # the columns of this row within the reach, and a pixel more (the test below decides)
        half = math.sqrt(max(0.0, reach * reach - dy * dy)) / res + 1.0
        row_j_lo = max(j_lo, int(math.ceil(cc - half)))
        row_j_hi = min(j_hi, int(math.floor(cc + half)))
        p_i0, p_ti = patch_row(patch, spacing, half_extent, dy) if rough else (0, 0.0)
        if irregular:  # every pixel of the row reads the rim at its azimuth
            _row_azimuths(x0, res, xc, dy, row_j_lo, row_j_hi, azimuths)
        for j in range(row_j_lo, row_j_hi + 1):
            dx = (x0 + (j + 0.5) * res) - xc
            r = math.sqrt(dx * dx + dy * dy)
            if r > reach:
                continue
            theta = 0.0
            if irregular:
                theta = azimuths[j - row_j_lo]
                rt = radius + periodic_sample(table, theta) * d
            else:
                rt = radius
            x = r / rt - 1.0
            if x > 1.0:
                continue
            if gaps and math.isnan(T[i - tr0, j - tc0]):
                continue
            cur = out[i - or0, j - oc0]
            ov = (patch_value_in_row(patch, spacing, half_extent, p_i0, p_ti, dx) if rough
                  else 0.0)
            if x <= 0.0:
                if not irregular:
                    theta = atan2(dy, dx)
                offset = periodic_sample(rim_terrain_table, theta)
                h = crater_interior(x, curvature, floor, hr + offset, row)
                plane = p0 + px * dx + py * dy
                # What the smoothed rim terrain and the plane leave out, here: the class's
                # older changes (cur - t) and the terrain's own deviation from the smoothed
                # rim level (t - plane - offset). It fades out down the upper inner wall, so
                # the bowl meets the exterior (cur + Hr at the rim) without a step.
                residual = cur - plane - offset
                out[i - or0, j - oc0] = plane + h + ov + residual * (1.0 - obliteration(x))
            else:
                out[i - or0, j - oc0] = cur + exterior_height(
                    x, hr, ejecta, beta, ca, cb, c2, c3) + ov * (1.0 - x)


# ----------------------------------------------------------------------------------------
# orchestration


class _Classes:
    """Size classes of a crater source, largest first, and the craters of each in an extent."""

    def __init__(self, source, seed):
        self.seed = seed
        if isinstance(source, Population):
            self.population = source
            bins = source.bins()
            self.classes = [(b, float(bins[b][1])) for b in range(len(bins))][::-1]
            self.table = None
        elif isinstance(source, CraterTable):
            self.population = None
            self.table = source
            ids = np.unique(source.size_class)[::-1]
            self.classes = [(int(c), float(source.diameter[source.size_class == c].max()))
                            for c in ids]
        else:
            raise InvalidParameterError(
                f"craters must be a Population or a CraterTable; got {type(source).__name__}")

    def craters(self, cls, extent, margin) -> CraterTable:
        if self.population is not None:
            return self.population.generate(self.seed, extent, margin=margin, bin_index=cls)
        t = self.table
        xmin, ymin, xmax, ymax = extent
        keep = ((t.size_class == cls) & (t.x >= xmin - margin) & (t.x <= xmax + margin)
                & (t.y >= ymin - margin) & (t.y <= ymax + margin))
        return t.take(np.flatnonzero(keep))


def crater_heights(base, shape, transform, craters, *, seed, model=None, window=None,
                   progress=None):
    """Cratered heights of a window, computing only the halo the window depends on.

    Parameters
    ----------
    base : callable (row0, row1, col0, col1) -> (row1 - row0, col1 - col0) float64
        Pre-crater heights of a pixel rectangle of the DEM (NaN where unknown).
    shape : (nrows, ncols)
        Size of the whole DEM (the window's frame of reference).
    transform : affine.Affine
        The whole DEM's north-up transform (metres).
    craters : Population or CraterTable
    seed : int
    model : CraterModel, optional
    window : Window, optional
    progress : callable, optional
        ``progress(done, total)`` after each size class.

    Returns
    -------
    heights : (height, width) float64, metres
    catalog : CraterCatalog
        Every crater whose footprint touches the window, in composition order.
    """
    seed = check_seed(seed)
    model = model or CraterModel()
    nrows, ncols = shape
    window = window or Window(0, 0, ncols, nrows)
    window.check_inside(nrows, ncols)
    res = float(transform.a)
    x0, y0 = float(transform.c), float(transform.f)
    classes = _Classes(craters, seed)
    factor = model.footprint_factor

    # Regions, from the last (smallest) class back to the base: each grows by its halo.
    regions = [(window.row, window.row + window.height, window.col, window.col + window.width)]
    for _, d_max in reversed(classes.classes):
        halo = int(math.ceil(1.5 * d_max * factor / res)) + 2
        r0, r1, c0, c1 = regions[0]
        regions.insert(0, (max(0, r0 - halo), min(nrows, r1 + halo),
                           max(0, c0 - halo), min(ncols, c1 + halo)))
    r0, r1, c0, c1 = regions[0]
    memory.require((r1 - r0) * (c1 - c0) * 8 * 3 + window.width * window.height * 4,
                   f"cratering a {window.width}x{window.height} window")

    terrain = np.ascontiguousarray(base(r0, r1, c0, c1), dtype=np.float64)
    origin = (r0, c0)
    # Craters never make a known pixel unknown or an unknown one known, so the first
    # region's gaps are every class's.
    settings = ClassSettings(seed, model.rim.effective_amplitude, model.rim.hurst,
                             model.roughness.enabled, model.roughness.as_array(), factor,
                             bool(np.isnan(terrain).any()))
    placed = []
    spare, owned = None, False  # base() may hand back the caller's own array
    total = len(classes.classes)
    for done, ((cls, d_max), region) in enumerate(
            zip(classes.classes, regions[1:], strict=True), start=1):
        q0, q1, p0, p1 = region
        extent = (x0 + p0 * res, y0 - q1 * res, x0 + p1 * res, y0 - q0 * res)
        table = classes.craters(cls, extent, d_max * factor + res)
        view = terrain[q0 - origin[0]:q1 - origin[0], p0 - origin[1]:p1 - origin[1]]
        out = spare if spare is not None and spare.shape == view.shape else np.empty(
            view.shape)
        spare = None
        _copy_rows(view, out)
        if len(table):
            table = table.take(table.composition_order())
            planes = _class_planes_parallel(terrain, origin[0], origin[1], nrows, ncols, x0,
                                            y0, res, table.x, table.y, table.diameter)
            slope = np.arctan(np.hypot(planes[:, 1], planes[:, 2]))
            depth_f, rim_f = model.factors(table.age, table.diameter, slope)
            s = shape_arrays(table.diameter, depth_f, rim_f, model.morphology)
            if model.min_depth_ratio > 0:
                # degraded past visibility: gone, skipped by the kernel and the catalogue
                gone = ((s["depth"] < model.min_depth_ratio * table.diameter)
                        & (s["complex"][:, 0] <= -1.0))
                planes[gone, 0] = np.nan
                planes[gone, 3] = 0.0
            craters = ClassCraters(
                table.x, table.y, table.diameter, s["depth"], s["rim_height"],
                s["fresh_rim_height"], s["ejecta"], s["beta"], s["a"], s["b"], s["c2"],
                s["c3"], s["alpha"], depth_f, table.uid, planes, s["complex"])
            _apply_class(terrain, origin[0], origin[1], out, q0, p0, nrows, ncols, x0, y0, res,
                         craters, settings)
            placed.append((table, depth_f, rim_f, s, planes))
            log.debug("size class %d (D <= %.3g m): %d craters", cls, d_max, len(table))
        if owned:  # the class before's terrain: reused as the next class's output
            spare = terrain
        terrain, origin, owned = out, (q0, p0), True
        if progress is not None:
            progress(done, total)
    catalog = _catalog(placed, window, x0, y0, res, factor)
    return terrain, catalog


#: Rows of one parallel block of :func:`_copy_rows`.
COPY_ROWS = 64


@numba.njit(cache=True, nogil=True)
def _copy_block(src, dst, first, last):
    """Copy the row blocks ``first .. last - 1`` (of :data:`COPY_ROWS` rows) of src to dst."""
    for i in range(first * COPY_ROWS, min(dst.shape[0], last * COPY_ROWS)):
        dst[i, :] = src[i, :]


def _copy_rows(src: np.ndarray, dst: np.ndarray) -> None:
    """``dst[...] = src`` on every core (a class's output starts as the terrain before it)."""
    run_blocks(_copy_block, (dst.shape[0] + COPY_ROWS - 1) // COPY_ROWS, src, dst)


def _catalog(placed, window: Window, x0: float, y0: float, res: float,
             factor: float) -> CraterCatalog:
    """Rows of every placed crater whose footprint touches the window, in composition order."""
    if not placed:
        return CraterCatalog.empty()
    wx0 = x0 + window.col * res
    wx1 = x0 + (window.col + window.width) * res
    wy1 = y0 - window.row * res
    wy0 = y0 - (window.row + window.height) * res
    parts = []
    for table, depth_f, rim_f, s, planes in placed:
        gx = np.clip(table.x, wx0, wx1) - table.x
        gy = np.clip(table.y, wy0, wy1) - table.y
        touch = np.hypot(gx, gy) <= table.diameter * factor
        touch &= np.isfinite(planes[:, 0])
        idx = np.flatnonzero(touch)
        parts.append(CraterCatalog(
            id=table.uid[idx], x_m=table.x[idx], y_m=table.y[idx],
            row=(y0 - table.y[idx]) / res - 0.5 - window.row,
            col=(table.x[idx] - x0) / res - 0.5 - window.col,
            diameter_m=table.diameter[idx], age_gyr=table.age[idx],
            size_class=table.size_class[idx], depth_fraction=depth_f[idx],
            rim_fraction=rim_f[idx], depth_m=s["depth"][idx],
            rim_height_m=s["rim_height"][idx], alpha=s["alpha"][idx], beta=s["beta"][idx],
            reference_elevation_m=planes[idx, 0]))
    return CraterCatalog.concatenate(parts)  # largest class first, oldest first


def add_craters(tile: DEMTile, craters, *, seed: int, model: CraterModel | None = None,
                window: Window | None = None, progress=None) -> CraterResult:
    """Add a crater population or an explicit crater table to a DEM tile.

    Parameters
    ----------
    tile : DEMTile
        Pre-crater terrain (metres). Invalid pixels stay invalid.
    craters : Population or CraterTable
        Craters in the tile's map coordinates.
    seed : int
        Keys the population and every crater's roughness.
    model : CraterModel, optional
        Erosion and roughness (defaults: the shipped Ross profile, roughness on).
    window : Window, optional
        Compute only this window of the tile (bitwise equal to the same window of a full run).
    progress : callable, optional
        ``progress(done, total)`` after each size class.

    Returns
    -------
    CraterResult
        The cratered tile (the window, if given) and its crater catalogue.
    """
    seed = check_seed(seed)
    model = model or CraterModel()
    heights = tile.heights

    def base(r0, r1, c0, c1):
        return heights[r0:r1, c0:c1].astype(np.float64)

    z, catalog = crater_heights(base, tile.shape, tile.transform, craters, seed=seed,
                                model=model, window=window, progress=progress)
    sub = tile.window(window) if window is not None else tile
    out = sub.replace(heights=z.astype(np.float32), valid=sub.valid)
    out = out.with_metadata(**{mk.SEED: str(seed),
                            mk.CRATER_MODEL: model.as_dict(),
                            mk.CRATERS: describe_craters(craters)})
    return CraterResult(out, catalog)


def describe_craters(craters) -> dict:
    """Return the provenance record of a crater source (for the DEM's metadata).

    Parameters
    ----------
    craters : Population or CraterTable

    Returns
    -------
    dict
        ``{"population": ...}`` (its parameters) or ``{"explicit_craters": n}``.
    """
    if isinstance(craters, Population):
        return {"population": craters.as_dict()}
    return {"explicit_craters": len(craters)}
