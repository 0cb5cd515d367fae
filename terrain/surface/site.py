"""Choosing a landing site on a DEM, and a sun azimuth that lights it.

A mission lands where the ground is flattest over the lander's approach scale, and a
descent test wants the site lit: at a polar site under a low sun, the wrong azimuth puts the
whole descent in a crater's night. :func:`landing_site` picks the flattest spot of a DEM's
central half; :func:`lit_sun_azimuth` marches a ray up-sun from the site for each candidate
azimuth (with the body's curvature) and keeps the unshadowed one that strikes the site's
regional slope most steeply.
"""

from __future__ import annotations

import math

import numpy as np

from terrain.core.errors import InvalidParameterError
from terrain.core.tile import DEMTile

__all__ = ["MOON_RADIUS", "landing_site", "lit_sun_azimuth"]

#: Mean radius of the Moon (m; IAU 2015, Archinal et al. 2018).
MOON_RADIUS = 1_737_400.0
#: Height a ray must clear over the ground to count as lit (m): hides single-pixel noise.
SHADOW_MARGIN_M = 5.0
#: Smoothing of the heights for the site's regional slope (pixels, Gaussian sigma).
REGIONAL_SIGMA_PX = 10.0


def landing_site(tile: DEMTile, slope_deg: np.ndarray, *, box: int = 9) -> tuple[float, float]:
    """Return the flattest spot of a DEM's central half: where a mission would choose to land.

    The score of a pixel is the mean tangent of the slope over a ``box`` x ``box`` pixel
    window; the site is the centre of the best-scoring pixel of the central half (the
    outer quarter on every side is left out).

    Parameters
    ----------
    tile : DEMTile
        The DEM (its transform places the site).
    slope_deg : (ny, nx) float, degrees
        Slope of every pixel, NaN where unknown (counted as vertical), e.g. the Horn slope
        of :func:`evaluation.slope.horn_slope`.
    box : int, optional
        Side of the averaging window (pixels).

    Returns
    -------
    x, y : float
        The site in the tile's map coordinates (metres).

    Examples
    --------
    >>> z = np.add.outer(np.zeros(16), np.abs(np.arange(16.0) - 10.0) ** 2)
    >>> t = DEMTile.from_array(z)
    >>> slope = np.degrees(np.arctan(np.abs(np.gradient(z, axis=1))))
    >>> landing_site(t, slope, box=1)[0]
    10.5
    """
    from scipy import ndimage

    slope = np.asarray(slope_deg)
    if slope.shape != tile.shape:
        raise InvalidParameterError(f"slope_deg must be {tile.shape} like the tile; got "
                                    f"{slope.shape}")
    if box < 1:
        raise InvalidParameterError(f"box must be at least 1 pixel; got {box}")
    slope = np.nan_to_num(slope, nan=90.0)
    score = ndimage.uniform_filter(np.tan(np.radians(np.minimum(slope, 89.0))), box)
    n, m = score.shape
    q, p = n // 4, m // 4
    r, c = np.unravel_index(np.argmin(score[q:n - q, p:m - p]), (n - 2 * q, m - 2 * p))
    x, y = tile.transform @ (c + p + 0.5, r + q + 0.5)
    return float(x), float(y)


def lit_sun_azimuth(tile: DEMTile, site: tuple[float, float], elevation: float, *,
                    radius: float = MOON_RADIUS, step_deg: int = 15,
                    max_steps: int = 200) -> float:
    """Sun azimuth (degrees clockwise from north) that lights a site best at ``elevation``.

    For every azimuth in ``step_deg`` steps, a ray is marched up-sun from the site, pixel by
    pixel to ``max_steps`` pixels, over ground that drops ``d^2 / 2R`` with distance ``d``
    (the body's curvature): the site is shadowed where the ground rises above the ray by
    more than :data:`SHADOW_MARGIN_M`. Among unshadowed azimuths, the one whose sun strikes
    the site's regional slope (heights smoothed over :data:`REGIONAL_SIGMA_PX` pixels) most
    steeply wins; where every azimuth is shadowed, 0.

    Parameters
    ----------
    tile : DEMTile
        The DEM, metres on square pixels.
    site : (float, float)
        The site in the tile's map coordinates (metres), at least one pixel inside.
    elevation : float
        Sun elevation above the horizon (degrees).
    radius : float, optional
        Body radius (m) for the curvature drop.
    step_deg : int, optional
        Azimuth step (degrees).
    max_steps : int, optional
        Longest ray (pixels).

    Returns
    -------
    float
        The azimuth, degrees in [0, 360).

    Examples
    --------
    A wall to the north shadows the site under a northern sun; a southern sun lights it:

    >>> z = np.zeros((41, 41)); z[:15] = 1000.0
    >>> t = DEMTile.from_array(z, resolution=10.0)
    >>> lit_sun_azimuth(t, t.transform @ (20.5, 20.5), 20.0, step_deg=90) in (90.0, 180.0, 270.0)
    True
    """
    from scipy import ndimage

    if not 0.0 < elevation < 90.0:
        raise InvalidParameterError(f"sun elevation must lie in (0, 90) degrees; got {elevation}")
    z = ndimage.gaussian_filter(tile.heights.astype(np.float64), REGIONAL_SIGMA_PX)
    ny, nx = z.shape
    col, row = ~tile.transform @ site
    r0, c0 = int(row), int(col)
    if not (1 <= r0 < ny - 1 and 1 <= c0 < nx - 1):
        raise InvalidParameterError(f"site {site} is not inside the tile's interior")
    res = tile.resolution
    gx = (z[r0, c0 + 1] - z[r0, c0 - 1]) / (2 * res)
    gy = (z[r0 - 1, c0] - z[r0 + 1, c0]) / (2 * res)
    normal = np.array([-gx, -gy, 1.0]) / math.hypot(math.hypot(gx, gy), 1.0)
    best, best_score = 0.0, -1.0
    for az in range(0, 360, step_deg):
        a, e = math.radians(az), math.radians(elevation)
        sun = np.array([math.sin(a) * math.cos(e), math.cos(a) * math.cos(e), math.sin(e)])
        shadowed = False
        for d in np.arange(2.0, float(max_steps), 1.0) * res:
            r = r0 - d * math.cos(a) / res
            c = c0 + d * math.sin(a) / res
            if not (0 <= r < ny - 1 and 0 <= c < nx - 1):
                break
            ground = tile.heights[int(r), int(c)] - d * d / (2 * radius)
            if ground > tile.heights[r0, c0] + d * math.tan(e) + SHADOW_MARGIN_M:
                shadowed = True
                break
        score = float(normal @ sun) if not shadowed else -1.0
        if score > best_score:
            best, best_score = float(az), score
    return best
