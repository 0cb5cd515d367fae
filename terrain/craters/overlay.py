"""Crater roughness: the radial fractal overlay and the irregular rim (Martin et al. 2014, III.A).

Radial fractal overlay
----------------------
"A fractal surface is superimposed onto the new crater with fractal dimension defined as a
function of radius from the crater center, creating radial fractal regions which specify the
roughness and vertical height range": floor (x < alpha), wall (alpha < x < 0) and ejecta
(x > 0). We build it as the paper built its terrain, by diamond-square RMD
(:mod:`terrain.fractal.rmd`), on a square patch centred on the crater and covering its footprint,
with
the displacement scale of every new point set by the region the point lies in: half-step j
displaces by ``amplitude * S_f(F)^(j + 1)`` (eq. 14) with the region's amplitude (metres,
:func:`crater_params`) and fractal dimension F; across region boundaries the displacement
scales are blended linearly over :attr:`Roughness.blend` in x. The overlay's amplitude fades
linearly to zero from the rim to the ejecta edge (applied in :mod:`terrain.craters.cratering`). The
patch spacing is about one pixel, never finer than the footprint / 2^:data:`MAX_PATCH_LEVEL`;
every Gaussian is keyed by
``(seed, "crater-overlay", half-step, patch column, patch row, crater uid)``.

Irregular rim
-------------
"A one-dimensional fractal array is created with matching start and end values to create a
varying radius, filtered and scaled to a fraction of crater diameter." We use periodic 1-D
midpoint displacement over :data:`RIM_SAMPLES` azimuths (the array wraps, so start and end
match), two passes of a circular binomial filter, removal of the mean (so the mean radius is
D/2) and scaling so the largest deviation is ``amplitude * D`` with the amplitude drawn per
crater between half and all of :attr:`RimIrregularity.amplitude`. The whole radial profile is
stretched along each azimuth: ``R(theta) = D/2 + rho(theta) D``.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numba
import numpy as np

from terrain.core.errors import InvalidParameterError
from terrain.core.rng import key_prefix, normal_at, normal_scalar, stream_id, uniform_scalar

__all__ = ["MAX_PATCH_LEVEL", "RIM_SAMPLES", "RimIrregularity", "Roughness", "crater_params",
           "overlay_patch", "overlay_patch_part", "patch_row", "patch_value",
           "patch_value_in_row", "periodic_sample", "rim_table", "smooth_periodic"]

#: Azimuth samples of the periodic rim-radius array (a power of two).
RIM_SAMPLES = 64
#: Largest overlay patch: (2^9 + 1)^2 points.
MAX_PATCH_LEVEL = 9
#: Passes of the circular binomial filter applied to the rim-radius array.
RIM_SMOOTHING_PASSES = 2

STREAM_OVERLAY = stream_id("crater-overlay")
STREAM_RIM = stream_id("crater-rim")
_HALF_LN2 = 0.5 * math.log(2.0)


@dataclass(frozen=True)
class Roughness:
    """Radial fractal overlay parameters.

    An amplitude is the standard deviation of the coarsest displacement of the overlay patch,
    as a fraction of D, scaled by the crater's depth fraction (erosion smooths a crater). The
    defaults (0.2 % of D on the floor, 0.4 % on the wall, 0.3 % on the ejecta; F = 2.2 as the
    paper used for its overlays, a rougher 2.3 on the ejecta near the rim) give a fresh 100 m
    crater decimetre-scale roughness.

    ``terrain_match`` sets a floor under the floor and wall amplitudes: that fraction of the
    amplitude that makes the overlay as rough at the pixel scale as the terrain the crater
    obliterated (:func:`crater_params`). A crater on rough ground then keeps the ground's
    texture inside instead of a polished bowl, which matters most for old craters whose own
    relief is small, and for feature trackers, which find nothing on polished patches.
    0 switches it off.
    """

    enabled: bool = True
    floor_amplitude: float = 0.002
    wall_amplitude: float = 0.004
    ejecta_amplitude: float = 0.003
    floor_dimension: float = 2.2
    wall_dimension: float = 2.2
    ejecta_dimension: float = 2.3
    blend: float = 0.1
    terrain_match: float = 1.0

    def __post_init__(self):
        for name in ("floor_amplitude", "wall_amplitude", "ejecta_amplitude"):
            v = float(getattr(self, name))
            if not (0 <= v < 1):
                raise InvalidParameterError(f"roughness {name} must lie in [0, 1); got {v}")
            object.__setattr__(self, name, v)
        for name in ("floor_dimension", "wall_dimension", "ejecta_dimension"):
            v = float(getattr(self, name))
            if not (2 <= v < 3):
                raise InvalidParameterError(f"roughness {name} must lie in [2, 3); got {v}")
            object.__setattr__(self, name, v)
        if not (0 < float(self.blend) <= 1):
            raise InvalidParameterError(f"roughness blend must lie in (0, 1]; got {self.blend}")
        if not (0 <= float(self.terrain_match) <= 10):
            raise InvalidParameterError(
                f"roughness terrain_match must lie in [0, 10]; got {self.terrain_match}")
        object.__setattr__(self, "terrain_match", float(self.terrain_match))
        object.__setattr__(self, "enabled", bool(self.enabled))

    def as_array(self) -> np.ndarray:
        """Parameters packed for the compiled kernel (see :func:`crater_params`)."""
        return np.array([self.floor_amplitude, self.wall_amplitude, self.ejecta_amplitude,
                         self.floor_dimension, self.wall_dimension, self.ejecta_dimension,
                         self.blend, self.terrain_match], dtype=np.float64)

    def as_dict(self) -> dict:
        """Return the parameters as plain data for metadata."""
        return asdict(self)


@dataclass(frozen=True)
class RimIrregularity:
    """Irregular rim: the largest rim-radius deviation as a fraction of D, and its roughness."""

    enabled: bool = True
    amplitude: float = 0.02
    hurst: float = 0.7

    def __post_init__(self):
        if not (0 <= float(self.amplitude) < 0.25):
            raise InvalidParameterError(
                f"rim irregularity amplitude must lie in [0, 0.25); got {self.amplitude}")
        if not (0 < float(self.hurst) <= 1):
            raise InvalidParameterError(f"rim Hurst exponent must lie in (0, 1]; got {self.hurst}")
        object.__setattr__(self, "amplitude", float(self.amplitude))
        object.__setattr__(self, "hurst", float(self.hurst))
        object.__setattr__(self, "enabled", bool(self.enabled))

    @property
    def effective_amplitude(self) -> float:
        """The largest rim-radius deviation over D as applied: 0 when switched off."""
        return self.amplitude if self.enabled else 0.0

    def as_dict(self) -> dict:
        """Return the parameters as plain data for metadata."""
        return asdict(self)


@numba.njit(cache=True)
def rim_table(seed, uid, amplitude, hurst, out):
    """Fill ``out`` with a crater's irregular rim, rho(theta) in units of D.

    Parameters
    ----------
    seed : int
        The run's seed.
    uid : int
        The crater's identity (keys its rim).
    amplitude : float
        Largest |rho| over D (:attr:`RimIrregularity.effective_amplitude`); 0 fills zeros.
    hurst : float
        Hurst exponent of the rim's fractal profile.
    out : (RIM_SAMPLES,) float64
        Filled; entry i belongs to azimuth theta_i = 2 pi i / n - pi.
    """
    n = out.size
    if amplitude <= 0.0:
        out[:] = 0.0
        return
    work = np.empty(n + 1)
    work[0] = normal_scalar(seed, STREAM_RIM, 0, 0, 0, uid)
    work[n] = work[0]  # periodic: start and end match
    step = n
    sigma = 1.0
    level = 1
    while step > 1:
        half = step // 2
        sigma *= 0.5**hurst
        key = key_prefix(seed, STREAM_RIM, level, uid)  # normal_scalar's key, once a level
        for i in range(half, n, step):
            work[i] = 0.5 * (work[i - half] + work[i + half]) + sigma * normal_at(key, i, 0)
        step = half
        level += 1
    for i in range(n):
        out[i] = work[i]
    smooth_periodic(out, RIM_SMOOTHING_PASSES)
    mean = 0.0
    for i in range(n):
        mean += out[i]
    mean /= n
    peak = 0.0
    for i in range(n):
        out[i] -= mean
        peak = max(peak, abs(out[i]))
    if peak <= 0.0:
        out[:] = 0.0
        return
    scale = amplitude * (0.5 + 0.5 * uniform_scalar(seed, STREAM_RIM, -1, 0, 0, uid)) / peak
    for i in range(n):
        out[i] *= scale


@numba.njit(cache=True)
def periodic_sample(table, theta):
    """Value of a periodic azimuth table at ``theta`` (radians); the size is a power of two.

    Entry i belongs to theta_i = 2 pi i / n - pi. Catmull-Rom cubic interpolation keeps the
    value and its azimuthal slope continuous, so table nodes never show as radial spokes in a
    shaded crater.

    Parameters
    ----------
    table : (n,) float64
        Values at the azimuths theta_i; n a power of two.
    theta : float, radians

    Returns
    -------
    float
    """
    n = table.size
    mask = n - 1
    t = (theta + math.pi) * (n / (2.0 * math.pi))
    i1 = int(math.floor(t))
    f = t - i1
    p0 = table[(i1 - 1) & mask]
    p1 = table[i1 & mask]
    p2 = table[(i1 + 1) & mask]
    p3 = table[(i1 + 2) & mask]
    return p1 + 0.5 * f * (p2 - p0 + f * (2.0 * p0 - 5.0 * p1 + 4.0 * p2 - p3
                                          + f * (3.0 * (p1 - p2) + p3 - p0)))


@numba.njit(cache=True)
def smooth_periodic(values, passes):
    """Apply ``passes`` rounds of the circular binomial filter [1 2 1] / 4, in place.

    Parameters
    ----------
    values : (n,) float64
        A periodic table (changed in place).
    passes : int
    """
    n = values.size
    tmp = np.empty(n)
    for _ in range(passes):
        # the neighbours wrap by index, not by ``%``: an integer division per value cost
        # more than the filter itself
        prev = n - 1
        for i in range(n):
            nxt = i + 1 if i + 1 < n else 0
            tmp[i] = 0.25 * values[prev] + 0.5 * values[i] + 0.25 * values[nxt]
            prev = i
        values[:] = tmp


@numba.njit(cache=True)
def crater_params(packed, diameter, depth_fraction, terrain_rms, pixel_rms, level, out):
    """Absolute overlay parameters of one crater from :meth:`Roughness.as_array`.

    out[0:3] = floor, wall, ejecta amplitudes (m); out[3:6] = their fractal dimensions;
    out[6] = blend width.

    Terrain matching: the last of the patch's 2 * level half-steps displaces by
    ``amplitude * S_f^(2 level) = amplitude * 2^(-level (3 - F))`` (eq. 14), and on an RMD
    surface the last displacement is the RMS of a pixel minus the mean of its four
    neighbours (``pixel_rms``). Solving for the amplitude makes the floor and wall as rough
    as the obliterated terrain at the pixel scale; the result is capped at twice the
    terrain's residual RMS about the plane (``terrain_rms``) so that a rough-at-small-scale
    ground never produces crater-sized bumps.

    Parameters
    ----------
    packed : (8,) float64
        :meth:`Roughness.as_array`.
    diameter : float, metres
    depth_fraction : float
        Depth left by erosion (the amplitudes scale with the crater's depth).
    terrain_rms, pixel_rms : float, metres
        The obliterated terrain's residual RMS about the crater's plane and its pixel
        roughness (:func:`terrain.craters.cratering.fit_plane`).
    level : int
        Diamond-square levels of the crater's patch.
    out : (7,) float64
        Filled as above.
    """
    scale = diameter * depth_fraction
    match = packed[7]
    for region in range(2):
        dim = packed[3 + region]
        need = match * pixel_rms * 2.0 ** (level * (3.0 - dim))
        out[region] = max(packed[region] * scale, min(need, 2.0 * match * terrain_rms))
    out[2] = packed[2] * scale
    out[3] = packed[3]
    out[4] = packed[4]
    out[5] = packed[5]
    out[6] = packed[6]


@numba.njit(cache=True)
def _region_weights(x, alpha, blend):
    """Linear blend weights of (floor, wall, ejecta) at normalised radius x."""
    wf = min(1.0, max(0.0, (alpha - x) / blend + 0.5))
    we = min(1.0, max(0.0, x / blend + 0.5))
    ww = max(0.0, 1.0 - wf - we)
    total = wf + ww + we
    if total == 1.0:  # most points: dividing by 1 would change nothing, and costs three divisions
        return wf, ww, we
    return wf / total, ww / total, we / total


@numba.njit(cache=True)
def _patch_sigma(i, j, centre, spacing, radius, alpha, blend, s_floor, s_wall, s_ejecta):
    """Displacement scale (m) at patch point (i, j), given the three regions' scales."""
    dx = (j - centre) * spacing
    dy = (i - centre) * spacing
    x = math.sqrt(dx * dx + dy * dy) / radius - 1.0
    wf, ww, we = _region_weights(x, alpha, blend)
    return wf * s_floor + ww * s_wall + we * s_ejecta


#: Relative margin of :func:`_region_bounds`: far larger than the rounding of x.
REGION_MARGIN = 1e-6


@numba.njit(cache=True)
def _region_bounds(radius, alpha, blend):
    """Squared distances (m^2) from the centre within which one region's weight is 1.

    Returns (floor_max, wall_min, wall_max, ejecta_min): a point at squared distance d2 has
    weights (1, 0, 0) if d2 <= floor_max, (0, 1, 0) if wall_min <= d2 <= wall_max and
    (0, 0, 1) if d2 >= ejecta_min, by :data:`REGION_MARGIN` inside the blends (never the
    case where a bound is -1 or inf).
    """
    floor_max = wall_min = wall_max = -1.0
    ejecta_min = math.inf
    if not (math.isfinite(alpha) and 0.0 < radius < math.inf and 0.0 < blend < math.inf):
        return floor_max, wall_min, wall_max, ejecta_min
    lo, hi = 1.0 - REGION_MARGIN, 1.0 + REGION_MARGIN
    # floor: x below both alpha and 0 by half a blend; wall: x between them; ejecta: above
    f = 1.0 + min(alpha, 0.0) - 0.5 * blend
    if f > REGION_MARGIN:
        floor_max = (radius * f * lo) ** 2
    w0 = 1.0 + alpha + 0.5 * blend
    w1 = 1.0 - 0.5 * blend
    if w0 > REGION_MARGIN and w0 * hi < w1 * lo:
        wall_min = (radius * w0 * hi) ** 2
        wall_max = (radius * w1 * lo) ** 2
    ejecta_min = (radius * (1.0 + max(alpha, 0.0) + 0.5 * blend) * hi) ** 2
    return floor_max, wall_min, wall_max, ejecta_min


@numba.njit(cache=True)
def _sigma_at(i, j, centre, spacing, radius, alpha, blend, s_floor, s_wall, s_ejecta, bounds):
    """:func:`_patch_sigma`, bitwise, without its square root and divisions away from blends.

    Where one region's weight is 1 and the others' 0, the weighted sum is that region's
    scale exactly (1 s + 0 + 0 = s for finite scales, which ``bounds`` of -1 and inf ensure
    are never assumed otherwise).
    """
    dx = (j - centre) * spacing
    dy = (i - centre) * spacing
    d2 = dx * dx + dy * dy
    if d2 <= bounds[0]:
        return s_floor
    if d2 >= bounds[3]:
        return s_ejecta
    if bounds[1] <= d2 <= bounds[2]:
        return s_wall
    return _patch_sigma(i, j, centre, spacing, radius, alpha, blend, s_floor, s_wall, s_ejecta)


@numba.njit(cache=True)
def _step_scale(amplitude, dimension, step_index):
    """Return amplitude * S_f^(step_index + 1) with S_f = 2^(-(3 - F) / 2) (eq. 14)."""
    return amplitude * math.exp(-(step_index + 1) * (3.0 - dimension) * _HALF_LN2)


@numba.njit(cache=True)
def overlay_patch(seed, uid, level, spacing, diameter, alpha, params, out):
    """Diamond-square patch of (2^level + 1)^2 points at ``spacing`` m, centred on the crater.

    ``params`` holds the absolute amplitudes (m) of floor, wall and ejecta, their fractal
    dimensions and the blend width (see :func:`crater_params`); corners are 0.

    Parameters
    ----------
    seed, uid : int
        The run's seed and the crater's identity (key the patch).
    level : int
        The patch has (2^level + 1)^2 points.
    spacing : float, metres
        Between patch points.
    diameter : float, metres
    alpha : float
        The profile's bowl join in normalised radius x = r / R - 1 (<= 0;
        :mod:`terrain.craters.crater`): the boundary of the floor and wall regions.
    params : (7,) float64
        :func:`crater_params`.
    out : (2^level + 1, 2^level + 1) float64, metres
        Filled with the patch.
    """
    n = 2**level
    overlay_patch_part(seed, uid, level, spacing, diameter, alpha, params, out, math.inf,
                       0, n, 0, n)


#: Slack (patch spacings) added to the reach of every level of a partial patch.
PART_SLACK = 0.01


@numba.njit(cache=True)
def overlay_patch_part(seed, uid, level, spacing, diameter, alpha, params, out, need_radius,
                       i_lo, i_hi, j_lo, j_hi):
    """:func:`overlay_patch` at the points that the patch's values in a region depend on.

    The region is the points within ``need_radius`` (patch spacings) of the centre and in
    rows ``i_lo .. i_hi``, columns ``j_lo .. j_hi``; a point of the diamond-square cascade
    is computed when a point of the region depends on it (its parents, their parents...),
    so every value in the region equals :func:`overlay_patch`'s, bitwise (the Gaussians are
    keyed by position). Other points stay 0. A crater clipped by the tile, and the corners of
    its square patch outside its round footprint, then cost nothing.

    Parameters
    ----------
    seed, uid, level, spacing, diameter, alpha, params, out
        As :func:`overlay_patch`.
    need_radius : float, patch spacings
        Radius of the region about the patch's centre (``math.inf``: no limit).
    i_lo, i_hi, j_lo, j_hi : int
        Rows and columns of the region (inclusive).
    """
    n = 2**level
    centre = n // 2
    radius = 0.5 * diameter
    blend = params[6]
    out[:, :] = 0.0
    # Reach of each level's points: the finest diamond points are needed within the region;
    # a level's points are read by the next finer level from (h / 2) (1 + sqrt 2) away
    # (its diamond points' neighbours, its square points' corners), and a level's square
    # points by its own diamond points, h away.
    bounds = np.empty(4)
    bounds[0], bounds[1], bounds[2], bounds[3] = _region_bounds(radius, alpha, blend)
    plain = bounds.copy()
    plain[0] = plain[1] = plain[2] = -1.0
    plain[3] = math.inf
    reach = np.empty(level + 1)
    reach[0] = need_radius + PART_SLACK
    for q in range(1, level + 1):
        reach[q] = reach[q - 1] + 2.0 ** (q - 1) * (1.0 + math.sqrt(2.0)) + PART_SLACK
    step = n
    k = 0
    while step > 1:
        h = step // 2
        q = level - k - 1  # h = 2^q
        grow = reach[q] - reach[0]
        key_sq = key_prefix(seed, STREAM_OVERLAY, 2 * k, uid)
        key_di = key_prefix(seed, STREAM_OVERLAY, 2 * k + 1, uid)
        # Each region's displacement at half-steps 2k and 2k + 1: amplitude * S_f^(j + 1).
        sq_f = _step_scale(params[0], params[3], 2 * k)
        sq_w = _step_scale(params[1], params[4], 2 * k)
        sq_e = _step_scale(params[2], params[5], 2 * k)
        di_f = _step_scale(params[0], params[3], 2 * k + 1)
        di_w = _step_scale(params[1], params[4], 2 * k + 1)
        di_e = _step_scale(params[2], params[5], 2 * k + 1)
        # the one-region shortcut holds for finite scales only
        b_sq = bounds if (math.isfinite(sq_f) and math.isfinite(sq_w)
                          and math.isfinite(sq_e)) else plain
        b_di = bounds if (math.isfinite(di_f) and math.isfinite(di_w)
                          and math.isfinite(di_e)) else plain
        r2 = (reach[q] + h) ** 2
        a_lo = i_lo - (grow + h)
        a_hi = i_hi + (grow + h)
        b_lo = j_lo - (grow + h)
        b_hi = j_hi + (grow + h)
        for i in range(h, n, step):  # square phase
            if i < a_lo or i > a_hi:
                continue
            di = float(i - centre)
            for j in range(h, n, step):
                dj = float(j - centre)
                if j < b_lo or j > b_hi or di * di + dj * dj > r2:
                    continue
                avg = 0.25 * (out[i - h, j - h] + out[i - h, j + h] + out[i + h, j - h]
                              + out[i + h, j + h])
                sig = _sigma_at(i, j, centre, spacing, radius, alpha, blend, sq_f, sq_w, sq_e,
                                b_sq)
                out[i, j] = avg + sig * normal_at(key_sq, j, i)
        r2 = reach[q] ** 2
        a_lo = i_lo - grow
        a_hi = i_hi + grow
        b_lo = j_lo - grow
        b_hi = j_hi + grow
        for i in range(0, n + 1, h):  # diamond phase
            if i < a_lo or i > a_hi:
                continue
            di = float(i - centre)
            start = h if (i // h) % 2 == 0 else 0
            for j in range(start, n + 1, step):
                dj = float(j - centre)
                if j < b_lo or j > b_hi or di * di + dj * dj > r2:
                    continue
                total = 0.0
                count = 0
                if i - h >= 0:
                    total += out[i - h, j]
                    count += 1
                if j - h >= 0:
                    total += out[i, j - h]
                    count += 1
                if j + h <= n:
                    total += out[i, j + h]
                    count += 1
                if i + h <= n:
                    total += out[i + h, j]
                    count += 1
                sig = _sigma_at(i, j, centre, spacing, radius, alpha, blend, di_f, di_w, di_e,
                                b_di)
                out[i, j] = total / count + sig * normal_at(key_di, j, i)
        step = h
        k += 1


@numba.njit(cache=True)
def patch_value(patch, spacing, half_extent, dx, dy):
    """Bilinear sample of an overlay patch at offset (dx, dy) m from the crater centre.

    Patch row i lies at dy = (i - centre) * spacing, column j at dx = (j - centre) * spacing.

    Parameters
    ----------
    patch : (n + 1, n + 1) float64, metres
        :func:`overlay_patch`.
    spacing : float, metres
    half_extent : float, metres
        Half the patch's side (n / 2 * spacing).
    dx, dy : float, metres
        Offset from the crater centre; clamped to the patch.

    Returns
    -------
    float, metres
    """
    i0, ti = patch_row(patch, spacing, half_extent, dy)
    return patch_value_in_row(patch, spacing, half_extent, i0, ti, dx)


@numba.njit(cache=True)
def patch_row(patch, spacing, half_extent, dy):
    """Row part of :func:`patch_value` at offset ``dy``: (upper row index, weight of the next).

    A stamp computes it once per pixel row.
    """
    n = patch.shape[0] - 1
    fi = (dy + half_extent) / spacing
    fi = min(max(fi, 0.0), n * 1.0)
    i0 = min(int(fi), n - 1)
    return i0, fi - i0


@numba.njit(cache=True)
def patch_value_in_row(patch, spacing, half_extent, i0, ti, dx):
    """:func:`patch_value` at offset ``dx`` in the row of :func:`patch_row` (bitwise equal)."""
    n = patch.shape[0] - 1
    fj = (dx + half_extent) / spacing
    fj = min(max(fj, 0.0), n * 1.0)
    j0 = min(int(fj), n - 1)
    tj = fj - j0
    return ((patch[i0, j0] * (1.0 - tj) + patch[i0, j0 + 1] * tj) * (1.0 - ti)
            + (patch[i0 + 1, j0] * (1.0 - tj) + patch[i0 + 1, j0 + 1] * tj) * ti)
