"""Compiled per-pixel kernels of the truth warps, on every core, the bytes the same.

The evaluation carries every pixel of a frame through its range image into another frame
(:func:`evaluation.consistency.camera_map`), samples range images at fractional pixels
(``evaluation.tracking._sample_range``) and adds fresh sensor noise to truth-warped frames
(``evaluation.tracking._fresh_noise``), a million pixels at a time for every step of a
run; and it masks a frame's large dark regions by component label for the tracker
(:func:`label_mask`, ``evaluation.tracking.near_dark``). Written as NumPy expressions each
of these made a dozen full-frame temporaries; here each pixel is computed once, by the same
floating-point operations in the same order (no fused multiply-adds, no reassociation), so
the results are those of the expressions, bit for bit. Rows or runs of points are blocks
of :func:`terrain.core.parallel.run_blocks`: each block writes only its own pixels, so the
bytes do not depend on the number of threads.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from terrain.core.parallel import run_blocks
from terrain.core.rng import check_seed, key_prefix, normal_at

__all__ = ["POINTS_PER_BLOCK", "camera_map_rows", "label_mask", "noisy_rows",
           "sample_range_points", "truth_warp_rows"]

#: Points of :func:`sample_range_points` per block of work.
POINTS_PER_BLOCK = 1 << 16


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _carry_pixel(rij, xi, yj, a, t, fx1, fy1, cx1, cy1):
    """One pixel of :func:`camera_map_rows`: (u1, v1, distance, ok)."""
    have = math.isfinite(rij) and rij > 0.0
    # as NumPy: scale = where(have, r, nan) / sqrt(x^2 + y^2 + 1)
    scale = (rij if have else np.nan) / math.sqrt(xi * xi + yj * yj + 1.0)
    c0 = t[0] + scale * (xi * a[0, 0] + yj * a[1, 0] + a[2, 0])
    c1 = t[1] + scale * (xi * a[0, 1] + yj * a[1, 1] + a[2, 1])
    c2 = t[2] + scale * (xi * a[0, 2] + yj * a[1, 2] + a[2, 2])
    u1 = fx1 * c0 / c2 + cx1  # IEEE division (error_model="numpy"), as NumPy's
    v1 = fy1 * c1 / c2 + cy1
    ok = have and c2 > 0.0 and math.isfinite(u1) and math.isfinite(v1)
    return (u1 if ok else np.nan), (v1 if ok else np.nan), \
        math.sqrt(c0 * c0 + c1 * c1 + c2 * c2), ok


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _camera_map_kernel(r, x, y, a, t, fx1, fy1, cx1, cy1, u_out, v_out, d_out, ok_out,
                       first, last):
    nx = x.size
    for j in range(first, last):
        for i in range(nx):
            u_out[j, i], v_out[j, i], d_out[j, i], ok_out[j, i] = _carry_pixel(
                np.float64(r[j, i]), x[i], y[j], a, t, fx1, fy1, cx1, cy1)


def camera_map_rows(r: np.ndarray, x: np.ndarray, y: np.ndarray, a: np.ndarray, t: np.ndarray,
                    fx1: float, fy1: float, cx1: float, cy1: float):
    """Compute the core of :func:`evaluation.consistency.camera_map` over a grid of pixels.

    Parameters
    ----------
    r : (ny, nx) float32 or float64, metres
        Range of the pixels carried (NaN: no return).
    x, y : (nx,), (ny,) float64
        Their normalised image coordinates in camera 0 (``(u - cx) / fx``, ``(v - cy) / fy``).
    a : (3, 3) float64
        Camera-0 directions to camera-1 axes (row vectors).
    t : (3,) float64, metres
        Camera 0's origin in camera 1's axes.
    fx1, fy1, cx1, cy1 : float, pixels
        Camera 1's intrinsics.

    Returns
    -------
    u1, v1, distance, ok
        As :func:`evaluation.consistency.camera_map` returns them.
    """
    ny, nx = r.shape
    u = np.empty((ny, nx))
    v = np.empty((ny, nx))
    d = np.empty((ny, nx))
    ok = np.empty((ny, nx), dtype=np.bool_)
    run_blocks(_camera_map_kernel, ny, r, np.ascontiguousarray(x, dtype=np.float64),
               np.ascontiguousarray(y, dtype=np.float64),
               np.ascontiguousarray(a, dtype=np.float64),
               np.ascontiguousarray(t, dtype=np.float64), float(fx1), float(fy1), float(cx1),
               float(cy1), u, v, d, ok)
    return u, v, d, ok


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _truth_warp_kernel(r1, x, y, a, t, fx0, fy0, cx0, cy0, range0, tol, keep, mu_out,
                       mv_out, ok_out, first, last):
    h0, w0 = range0.shape
    nx = x.size
    for j in range(first, last):
        for i in range(nx):
            u0, v0, dist, lifted = _carry_pixel(np.float64(r1[j, i]), x[i], y[j], a, t,
                                                fx0, fy0, cx0, cy0)
            good = False
            if lifted:
                seen = _sample_at(range0, u0, v0, tol)
                good = (u0 >= -0.5 and u0 <= w0 - 0.5 and v0 >= -0.5 and v0 <= h0 - 0.5
                        and math.isfinite(seen) and seen >= dist * keep)
            mu_out[j, i] = np.float32(u0) if good else np.float32(-10.0)
            mv_out[j, i] = np.float32(v0) if good else np.float32(-10.0)
            ok_out[j, i] = good


def truth_warp_rows(range1: np.ndarray, x: np.ndarray, y: np.ndarray, a: np.ndarray,
                    t: np.ndarray, fx0: float, fy0: float, cx0: float, cy0: float,
                    range0: np.ndarray, tolerance: float):
    """Compute the maps of :func:`evaluation.tracking.truth_warped_frame`, a pixel at a time.

    Each pixel of frame 1 is carried into frame 0 (:func:`camera_map_rows`, with the frames'
    roles swapped), frame 0's range is sampled there (:func:`sample_range_points`) and the
    pixel is kept where frame 0 sees the point; the same operations, in the same order, as
    those calls and the masks the warp built from their results, without the full-frame
    temporaries in between.

    Parameters
    ----------
    range1 : (h, w) float32 or float64, metres
        Range of frame 1, whose pixels are carried (NaN: no return).
    x, y : (w,), (h,) float64
        Frame 1's normalised image coordinates of its columns and rows.
    a, t : (3, 3), (3,) float64
        Camera-1 directions to camera-0 axes, and camera 1's origin in camera 0's axes.
    fx0, fy0, cx0, cy0 : float, pixels
        Frame 0's intrinsics.
    range0 : (h0, w0) float32 or float64, metres
        Range of frame 0.
    tolerance : float
        Relative distance by which a point may lie behind frame 0's surface and be seen
        (also the agreement of the four returns that are interpolated).

    Returns
    -------
    map_u, map_v : (h, w) float32, pixels
        Where each pixel of frame 1 lies in frame 0 (-10 where it is not kept).
    ok : (h, w) bool
        The pixels kept.
    """
    ny, nx = range1.shape
    img = np.ascontiguousarray(range0)
    if img.dtype not in (np.float32, np.float64):
        img = img.astype(np.float64)
    mu = np.empty((ny, nx), dtype=np.float32)
    mv = np.empty((ny, nx), dtype=np.float32)
    ok = np.empty((ny, nx), dtype=np.bool_)
    run_blocks(_truth_warp_kernel, ny, range1, np.ascontiguousarray(x, dtype=np.float64),
               np.ascontiguousarray(y, dtype=np.float64),
               np.ascontiguousarray(a, dtype=np.float64),
               np.ascontiguousarray(t, dtype=np.float64), float(fx0), float(fy0), float(cx0),
               float(cy0), img, img.dtype.type(tolerance), 1.0 - float(tolerance), mu, mv, ok)
    return mu, mv, ok


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _sample_at(range_m, up, vp, tol):
    """Range at one fractional pixel (NaN outside): what ``_sample_range`` gives a point."""
    h, w = range_m.shape
    if not (up >= -0.5 and up <= w - 0.5 and vp >= -0.5 and vp <= h - 0.5
            and math.isfinite(up) and math.isfinite(vp)):
        return np.nan
    u0 = min(max(int(math.floor(up)), 0), w - 2) if w > 1 else 0
    v0 = min(max(int(math.floor(vp)), 0), h - 2) if h > 1 else 0
    u1 = min(u0 + 1, w - 1)
    v1 = min(v0 + 1, h - 1)
    fu = min(max(up - u0, 0.0), 1.0)
    fv = min(max(vp - v0, 0.0), 1.0)
    c0 = range_m[v0, u0]
    c1 = range_m[v0, u1]
    c2 = range_m[v1, u0]
    c3 = range_m[v1, u1]
    agree = False
    if (math.isfinite(c0) and math.isfinite(c1) and math.isfinite(c2)
            and math.isfinite(c3)):
        low = min(min(c0, c1), min(c2, c3))
        spread = max(max(c0, c1), max(c2, c3)) - low
        agree = math.isfinite(spread) and spread <= tol * low
    if agree:
        return np.float64(c0 * (1 - fu) * (1 - fv) + c1 * fu * (1 - fv) + c2 * (1 - fu) * fv
                          + c3 * fu * fv)
    ri = min(max(int(np.rint(vp)), 0), h - 1)
    ci = min(max(int(np.rint(up)), 0), w - 1)
    return np.float64(range_m[ri, ci])


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _sample_kernel(range_m, u, v, tol, out, first, last):
    n = u.size
    for b in range(first, last):
        for p in range(b * POINTS_PER_BLOCK, min(n, (b + 1) * POINTS_PER_BLOCK)):
            out[p] = _sample_at(range_m, u[p], v[p], tol)


def sample_range_points(range_m: np.ndarray, u: np.ndarray, v: np.ndarray,
                        tolerance: float) -> np.ndarray:
    """Sample a range image at points ``(u, v)`` (:func:`evaluation.tracking._sample_range`).

    ``tolerance`` is applied in the range image's own precision (a float32 image's spread
    is compared with float32 ``tolerance * low``, as NumPy compares them).

    Returns
    -------
    (n,) float64, metres
    """
    u = np.ascontiguousarray(u, dtype=np.float64)
    v = np.ascontiguousarray(v, dtype=np.float64)
    out = np.empty(u.size)
    img = np.ascontiguousarray(range_m)
    if img.dtype not in (np.float32, np.float64):
        img = img.astype(np.float64)
    blocks = -(-u.size // POINTS_PER_BLOCK)
    run_blocks(_sample_kernel, blocks, img, u, v, img.dtype.type(tolerance), out)
    return out


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _noise_kernel(image, prefix, gain, read2, top, out, first, last):
    h, w, c = image.shape
    for j in range(first, last):
        for i in range(w):
            z = normal_at(prefix, i, j)
            for ch in range(c):
                dn = np.float64(image[j, i, ch])
                var = (max(dn, 0.0) / gain if gain > 0.0 else 0.0) + read2
                value = np.rint(dn + math.sqrt(var) * z)
                out[j, i, ch] = min(max(value, 0.0), top)


def noisy_rows(image: np.ndarray, seed: int, stream: int, level: int, gain: float,
               read_noise: float) -> np.ndarray:
    """Return an integer image with fresh shot and read noise keyed by (seed, stream, level, x, y).

    The deviate of pixel (x, y) is ``terrain.core.rng.normal(seed, stream, level, x, y)``,
    the same for every channel; the noise's standard deviation is
    ``sqrt(max(DN, 0) / gain + read_noise^2)`` (no shot noise where ``gain`` is 0); the
    result is rounded half to even and clipped to the dtype's range.

    Returns
    -------
    ndarray, ``image``'s shape and dtype
    """
    img = np.ascontiguousarray(image)
    view = img if img.ndim == 3 else img[:, :, None]
    out = np.empty(view.shape, dtype=img.dtype)
    prefix = np.uint64(key_prefix(check_seed(seed), int(stream), int(level), 0))
    read = float(read_noise)
    run_blocks(_noise_kernel, view.shape[0], view, prefix, float(gain), read * read,
               float(np.iinfo(img.dtype).max), out)
    return out.reshape(img.shape)


@numba.njit(cache=True, nogil=True)
def _label_mask_kernel(labels, keep, out, first, last):  # pragma: no cover - compiled
    for r in range(first, last):
        for c in range(labels.shape[1]):
            out[r, c] = keep[labels[r, c]]


def label_mask(labels: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """``keep[labels]`` as uint8 (0 or 1): which pixels belong to a kept component.

    Parameters
    ----------
    labels : (h, w) int32
        Component labels (OpenCV's ``connectedComponents``), each below ``keep.size``.
    keep : (n,) uint8
        1 for a kept label.

    Returns
    -------
    (h, w) uint8
        The gather NumPy's fancy indexing gives, rows on every core (a fifth of its time
        for a 1024^2 frame).

    >>> label_mask(np.array([[0, 2], [1, 2]], np.int32), np.array([0, 1, 1], np.uint8)).tolist()
    [[0, 1], [1, 1]]
    """
    labels = np.ascontiguousarray(labels, dtype=np.int32)
    out = np.empty(labels.shape, dtype=np.uint8)
    run_blocks(_label_mask_kernel, labels.shape[0], labels,
               np.ascontiguousarray(keep, dtype=np.uint8), out)
    return out
