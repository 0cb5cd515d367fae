"""Surfaces that are plainly not lunar, to show that :mod:`evaluation.validate` says so.

* :func:`smoothed_8x`: a DEM decimated 8x and brought back to its spacing by bicubic
  interpolation: the relief of the real DEM above 16 px, none below.
* :func:`fresh_crater_field`: fresh simple craters laid over each other until their walls
  cover everything, untouched by erosion.
* pure fBm with H = 0.5 is :func:`evaluation.spectrum.fractional_brownian_surface`.
"""

from __future__ import annotations

import numpy as np

from terrain.core import metakeys as mk
from terrain.core.tile import DEMTile
from terrain.craters.crater import CraterShape, profile

__all__ = ["fresh_crater_field", "smoothed_8x"]


def smoothed_8x(tile: DEMTile) -> DEMTile:
    """Return the DEM decimated 8x (every 8th pixel) and bicubic-interpolated back.

    >>> t = DEMTile.from_array(np.arange(64.0).reshape(8, 8) % 3, resolution=2.0)
    >>> smoothed_8x(t).shape, smoothed_8x(t).resolution
    ((8, 8), 2.0)
    """
    from scipy import ndimage

    z = np.where(tile.valid, tile.heights, np.nanmean(tile.heights))
    small = z[::8, ::8]
    big = ndimage.zoom(small, 8, order=3)
    ny, nx = z.shape
    pad = ((0, max(0, ny - big.shape[0])), (0, max(0, nx - big.shape[1])))
    big = np.pad(big, pad, mode="edge")[:ny, :nx]
    return DEMTile.from_array(big, resolution=tile.resolution)


def fresh_crater_field(size: int = 256, resolution: float = 1.0, *, seed: int = 0,
                       diameters=(15.0, 60.0)) -> DEMTile:
    """Return a surface saturated by fresh simple craters (walls everywhere).

    Each crater (diameter uniform in ``diameters``, centre uniform over the tile, drawn from
    NumPy's PCG64 seeded with ``seed``) replaces what was inside its rim by its fresh bowl
    (Melosh's depth and rim height, :mod:`terrain.craters.crater`) at the height of the
    ground under its rim, and adds its rim and ejecta outside; one crater per 200 pixels.

    Parameters
    ----------
    size : int
        Pixels per side.
    resolution : float
        Metres per pixel.
    seed : int
    diameters : (2,) float
        Smallest and largest diameter (m).

    Returns
    -------
    DEMTile
    """
    rng = np.random.default_rng(int(seed))
    z = np.zeros((size, size))
    yy, xx = (np.mgrid[0:size, 0:size] + 0.5) * resolution
    for _ in range(size * size // 200):
        d = rng.uniform(*diameters)
        cx, cy = rng.uniform(0.0, size * resolution, 2)
        x = 2.0 * np.hypot(xx - cx, yy - cy) / d - 1.0
        near = x <= 1.0
        rim = (x > 0.9) & near
        level = z[rim].mean() if rim.any() else 0.0
        p = profile(x[near], CraterShape.from_state(d))
        inside = x[near] <= 0.0
        new = z[near] + p
        new[inside] = level + p[inside]
        z[near] = new
    return DEMTile.from_array(z, resolution=resolution,
                              metadata={mk.SEED: str(int(seed)),
                                        mk.GENERATOR: "fresh_crater_field"})
