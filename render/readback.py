"""A frame's images, from the bytes OpenGL reads back to the arrays a :class:`Frame` holds.

OpenGL's rows run upwards and the normals attachment carries a fourth channel that says
whether a pixel saw the surface. A frame's arrays run downwards, and where a pixel saw no
surface its range and normal are NaN. :func:`unpack` does that in one pass over the read
buffers, rows split over every core (:func:`terrain.core.parallel.run_blocks`), and gives the
same values as the numpy expressions it replaced::

    rad = rad_in[::-1].copy()
    hit = nrm_in[:, :, 3] > 0.5          # NaN is no hit
    range_m = rng_in[::-1].copy(); range_m[~hit[::-1]] = nan
    normals = np.where(hit[::-1, :, None], nrm_in[::-1, :, :3], nan)

Those took 24 ms a 1024^2 frame on one core, the most of a frame's time on a GPU, where
the picture itself takes a few milliseconds (docs/speed.md, "A frame on a GPU").
"""

from __future__ import annotations

from typing import Any, Literal, overload

import numba
import numpy as np

from terrain.core.parallel import run_blocks

__all__ = ["Staging", "read", "unpack"]


#: Rows per block of :func:`unpack`: a block is one dispatch to a thread (tens of
#: microseconds, more than a row's work), so a 1024^2 frame is 16 of them.
BAND_ROWS = 64


@numba.njit(nogil=True, cache=True)
def _unpack_rows(with_rad, rad_in, rng_in, nrm_in, rad, rng, nrm, first, last):
    """Bands ``first .. last - 1`` of the outputs (flipped from the read rows)."""
    h, w = rng.shape
    nan = np.float32(np.nan)
    for i in range(first * BAND_ROWS, min(h, last * BAND_ROWS)):
        s = h - 1 - i
        for j in range(w):
            if with_rad:
                rad[i, j] = rad_in[s, j]
            if nrm_in[s, j, 3] > 0.5:
                rng[i, j] = rng_in[s, j]
                nrm[i, j, 0] = nrm_in[s, j, 0]
                nrm[i, j, 1] = nrm_in[s, j, 1]
                nrm[i, j, 2] = nrm_in[s, j, 2]
            else:
                rng[i, j] = nan
                nrm[i, j, 0] = nan
                nrm[i, j, 1] = nan
                nrm[i, j, 2] = nan


class Staging:
    """The float32 buffers that a frame's attachments are read into.

    Parameters
    ----------
    size : (width, height)
        The frame's size in pixels.
    """

    def __init__(self, size: tuple[int, int]):
        w, h = size
        self.size = (int(w), int(h))
        self.radiance = np.empty((h, w), dtype=np.float32)
        self.range = np.empty((h, w), dtype=np.float32)
        self.normals = np.empty((h, w, 4), dtype=np.float32)


@overload
def unpack(staging: Staging, with_radiance: Literal[True] = ...
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray]: ...


@overload
def unpack(staging: Staging, with_radiance: Literal[False]
           ) -> tuple[None, np.ndarray, np.ndarray]: ...


def unpack(staging: Staging, with_radiance: bool = True
           ) -> tuple[np.ndarray | None, np.ndarray, np.ndarray]:
    """Return the frame's radiance (or None), range and normals from what ``staging`` holds.

    Returns
    -------
    radiance : (h, w) float32 or None
        Rows flipped to run downwards; None where ``with_radiance`` is false.
    range_m : (h, w) float32
        NaN where the pixel saw no surface.
    normals : (h, w, 3) float32
        NaN where the pixel saw no surface.
    """
    w, h = staging.size
    rad = np.empty((h, w), dtype=np.float32) if with_radiance \
        else np.empty((1, 1), dtype=np.float32)
    rng = np.empty((h, w), dtype=np.float32)
    nrm = np.empty((h, w, 3), dtype=np.float32)
    run_blocks(_unpack_rows, -(-h // BAND_ROWS), bool(with_radiance), staging.radiance,
               staging.range, staging.normals, rad, rng, nrm)
    return (rad if with_radiance else None), rng, nrm


@overload
def read(fbo: Any, size: tuple[int, int], with_radiance: Literal[True] = ...
         ) -> tuple[np.ndarray, np.ndarray, np.ndarray]: ...


@overload
def read(fbo: Any, size: tuple[int, int], with_radiance: Literal[False]
         ) -> tuple[None, np.ndarray, np.ndarray]: ...


def read(fbo: Any, size: tuple[int, int], with_radiance: bool = True
         ) -> tuple[np.ndarray | None, np.ndarray, np.ndarray]:
    """Read a frame's attachments (0 radiance, 1 range, 2 normals) and :func:`unpack` them.

    Read into fresh buffers, not kept ones: a server's memory budget counts the frames it
    holds, and buffers kept at the largest size asked for would stay outside it.

    Parameters
    ----------
    fbo : moderngl.Framebuffer
        The frame's framebuffer.
    size : (width, height)
        Its size in pixels.
    with_radiance : bool
        Whether to read attachment 0 too (an antialiased frame averages it elsewhere).
    """
    staging = Staging(size)
    if with_radiance:
        fbo.read_into(staging.radiance, attachment=0, components=1, dtype="f4")
    fbo.read_into(staging.range, attachment=1, components=1, dtype="f4")
    fbo.read_into(staging.normals, attachment=2, components=4, dtype="f4")
    if with_radiance:
        return unpack(staging)
    return unpack(staging, with_radiance=False)
