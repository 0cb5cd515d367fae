"""Occluding contours of a range image: where a tracker or a warp cannot follow the surface.

A pixel lies on a contour when it has no return (sky, or a surface beyond the sensor's range)
or when its range and a 4-neighbour's differ by more than :data:`SILHOUETTE_JUMP` of the
nearer one: there a nearer surface hides a farther one (a silhouette, a crater rim against
its far wall), and the surface behind slides against the outline from frame to frame. The
tracker flags features near contours (:mod:`evaluation.tracking`) and the frame-to-frame
consistency check leaves them out of its residual (:mod:`evaluation.consistency`).
"""

from __future__ import annotations

import math

import numba
import numpy as np

__all__ = ["SILHOUETTE_JUMP", "contour_pixels", "dilate", "near_contours"]

#: Relative range jump between neighbouring pixels that marks an occluding contour.
SILHOUETTE_JUMP = 0.05


def contour_pixels(range_m: np.ndarray, jump: float = SILHOUETTE_JUMP) -> np.ndarray:
    """Return the pixels of a range image on an occluding contour.

    Parameters
    ----------
    range_m : (h, w) float, metres
        Range per pixel; NaN (or inf) without return.
    jump : float
        Relative range jump between 4-neighbours that marks a contour (both pixels are on
        it).

    Returns
    -------
    (h, w) bool
        Pixels without return, and both pixels of every neighbouring pair with returns
        whose ranges differ by more than ``jump`` times the nearer one (a pixel beside one
        without return is not itself on the contour; :func:`near_contours` grows it).

    Examples
    --------
    >>> r = np.array([[10.0, 10.2, 20.0], [10.0, np.nan, 20.0]])
    >>> contour_pixels(r).astype(int)
    array([[0, 1, 1],
           [0, 1, 0]])
    """
    r = np.ascontiguousarray(range_m)
    if r.dtype not in (np.float32, np.float64):
        r = r.astype(np.float64)
    edge = np.empty(r.shape, dtype=bool)
    _contour_kernel(r, r.dtype.type(jump), edge)  # compared in the image's own precision
    return edge


@numba.njit(cache=True, nogil=True)
def _contour_kernel(r, jump, edge):
    h, w = r.shape
    for j in range(h):
        for i in range(w):
            edge[j, i] = not math.isfinite(r[j, i])
    for j in range(h):
        for i in range(w):
            a = r[j, i]
            if i + 1 < w:  # along a row
                b = r[j, i + 1]
                if abs(a - b) > jump * min(a, b):  # False where either has no return
                    edge[j, i] = True
                    edge[j, i + 1] = True
            if j + 1 < h:  # down a column
                b = r[j + 1, i]
                if abs(a - b) > jump * min(a, b):
                    edge[j, i] = True
                    edge[j + 1, i] = True


def dilate(mask: np.ndarray, px: int) -> np.ndarray:
    """Return ``mask`` grown by ``px`` pixels (a square of side 2 px + 1).

    Parameters
    ----------
    mask : (h, w) bool
    px : int, pixels
        Growth; 0 or less returns ``mask`` itself.

    Returns
    -------
    (h, w) bool
    """
    import cv2

    if px <= 0:
        return mask
    size = 2 * px + 1
    return cv2.dilate(mask.astype(np.uint8), np.ones((size, size), np.uint8)) > 0


def near_contours(range_m: np.ndarray, px: int, jump: float = SILHOUETTE_JUMP) -> np.ndarray:
    """Return the pixels within ``px`` pixels of an occluding contour.

    Parameters
    ----------
    range_m : (h, w) float, metres
        Range per pixel; NaN without return.
    px : int, pixels
        Distance (Chebyshev) from a contour pixel.
    jump : float
        See :func:`contour_pixels`.

    Returns
    -------
    (h, w) bool
    """
    return dilate(contour_pixels(range_m, jump), px)
