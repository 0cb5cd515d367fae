"""Hillshade of a DEM tile: a quick look at terrain as an 8-bit grey image.

Gradients are Horn's (1981) 3x3 weighted differences, the same stencil GDAL's ``gdaldem
hillshade`` uses, with edge pixels replicated. Illumination follows GDAL's convention:
``azimuth`` in degrees clockwise from north, ``altitude`` above the horizon. Invalid pixels
(and pixels whose stencil touches one) come out black, so no gap is shaded as if it were
terrain.
"""

from __future__ import annotations

import math

import numpy as np

from terrain.core.tile import DEMTile

__all__ = ["hillshade", "horn_gradient"]


def horn_gradient(tile: DEMTile, z_factor: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Horn's (1981) 3x3 gradients (dz/dx east, dz/dy north), edges replicated.

    Returns
    -------
    dzdx, dzdy : (ny, nx) float64, metres per metre (NaN where the stencil meets a gap)
    """
    z = np.pad(tile.heights.astype(np.float64) * float(z_factor), 1, mode="edge")
    res = tile.resolution
    # x to the east (columns), y to the north (rows decrease northwards)
    dzdx = ((z[:-2, 2:] + 2 * z[1:-1, 2:] + z[2:, 2:])
            - (z[:-2, :-2] + 2 * z[1:-1, :-2] + z[2:, :-2])) / (8 * res)
    dzdy = ((z[:-2, :-2] + 2 * z[:-2, 1:-1] + z[:-2, 2:])
            - (z[2:, :-2] + 2 * z[2:, 1:-1] + z[2:, 2:])) / (8 * res)
    return dzdx, dzdy


def hillshade(tile: DEMTile, *, azimuth: float = 315.0, altitude: float = 45.0,
              z_factor: float = 1.0) -> np.ndarray:
    """Shaded relief of a tile.

    Returns
    -------
    (ny, nx) uint8
        0 for invalid pixels, otherwise 1 + 254 * max(0, cos(incidence)).

    Examples
    --------
    >>> flat = DEMTile.from_array(np.zeros((4, 4)))
    >>> int(hillshade(flat, altitude=90.0)[1, 1])
    255
    """
    dzdx, dzdy = horn_gradient(tile, z_factor)
    az = math.radians(azimuth)
    alt = math.radians(altitude)
    # Sun direction (east, north, up) and the surface normal (-dz/dx, -dz/dy, 1).
    sx, sy, sz = math.sin(az) * math.cos(alt), math.cos(az) * math.cos(alt), math.sin(alt)
    with np.errstate(invalid="ignore"):
        shade = (-dzdx * sx - dzdy * sy + sz) / np.sqrt(1 + dzdx**2 + dzdy**2)
    out = np.where(np.isfinite(shade) & tile.valid, 1 + 254 * np.clip(shade, 0, 1), 0)
    return np.rint(out).astype(np.uint8)
