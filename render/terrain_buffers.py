"""A terrain layer's vertex, geomorphing and normal buffers, compiled.

What :class:`render.terrain_scene.TerrainScene` uploads for a layer when a frame first draws
it: every pixel centre's position and unit normal (``3f 3f``), its geomorphing target (the
next coarser level's height and normal below it, and its own level: ``4f 3f``, see
:mod:`render.terrain_scene`'s geomorphing), the skirt vertices following (lowered copies of
the block-boundary rows, then columns), and the float64 normals the normals texture is made
of. One pass per image row, on every core (:func:`terrain.core.parallel.run_blocks`), with
the same float64 arithmetic per vertex, in the same order, as the numpy expressions the
module docstring of :mod:`render.terrain_scene` states (central differences as
``numpy.gradient``, the norm as ``numpy.linalg.norm``, the triangle interpolation
``za + ti (zc - za) + tj (zb - za)`` in that order), so the bytes are those of the numpy
expressions.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from terrain.core.parallel import run_blocks

__all__ = ["block_indices", "fade_in", "half_floats", "layer_buffers", "morph_targets"]


@numba.njit(nogil=True, cache=True)
def _normals_rows(z, res, n, first, last):
    """Write the unit normals of rows ``first .. last - 1`` (central differences inside)."""
    h, w = z.shape
    two = 2.0 * res
    for i in range(first, last):
        for j in range(w):
            # numpy.gradient(z, res, axis=1), then axis=0 (rows run south: negated)
            if j == 0:
                gx = (z[i, 1] - z[i, 0]) / res
            elif j == w - 1:
                gx = (z[i, w - 1] - z[i, w - 2]) / res
            else:
                gx = (z[i, j + 1] - z[i, j - 1]) / two
            if i == 0:
                gy = (z[1, j] - z[0, j]) / res
            elif i == h - 1:
                gy = (z[h - 1, j] - z[h - 2, j]) / res
            else:
                gy = (z[i + 1, j] - z[i - 1, j]) / two
            nx = -gx
            ny = gy  # -dz/dy, with y north and rows running south
            # numpy.linalg.norm over the last axis: the first square, plus the others' sum
            length = math.sqrt(nx * nx + (ny * ny + 1.0))
            n[i, j, 0] = nx / length
            n[i, j, 1] = ny / length
            n[i, j, 2] = 1.0 / length


@numba.njit(nogil=True, cache=True, inline="always")
def _on_triangle(za, zb, zc, ti, tj):
    # za + ti (zc - za) + tj (zb - za), evaluated in this order
    out = (zc - za) * ti
    out += za
    out += (zb - za) * tj
    return out


@numba.njit(nogil=True, cache=True)
def _morph_rows(z, n, rl, cl, ra, rb, rt, ca, cb, ct, block, target, tnormal, level, first,
                last):
    """Morph targets of rows ``first .. last - 1`` (see ``morph_targets``)."""
    h, w = z.shape
    for i in range(first, last):
        for j in range(w):
            s = min(rl[i], cl[j])
            level[i, j] = s
            if s >= block:
                target[i, j] = z[i, j]
                for k in range(3):
                    tnormal[i, j, k] = n[i, j, k]
                continue
            q = 0
            while (1 << (q + 1)) <= s:
                q += 1
            ia, ib, ti = ra[q, i], rb[q, i], rt[q, i]
            ja, jb, tj = ca[q, j], cb[q, j], ct[q, j]
            if ti + tj <= 1.0:  # triangle (a, c, b); else (b, c, d)
                target[i, j] = _on_triangle(z[ia, ja], z[ia, jb], z[ib, ja], ti, tj)
                for k in range(3):
                    tnormal[i, j, k] = _on_triangle(n[ia, ja, k], n[ia, jb, k], n[ib, ja, k],
                                                    ti, tj)
            else:
                ui, uj = 1.0 - ti, 1.0 - tj
                target[i, j] = _on_triangle(z[ib, jb], z[ib, ja], z[ia, jb], ui, uj)
                for k in range(3):
                    tnormal[i, j, k] = _on_triangle(n[ib, jb, k], n[ib, ja, k], n[ia, jb, k],
                                                    ui, uj)


@numba.njit(nogil=True, cache=True)
def _fill_vertex_rows(out, xs, ys, height, normal, brows, bcols, depth, first, last):
    """Write rows ``first .. last - 1`` of the ``3f 3f`` buffer (flat), skirts included.

    ``out`` is ``(h w + len(brows) w + len(bcols) h) * 6`` float32: position and normal per
    vertex; the main vertices, then skirt rows ``brows``, then skirt columns ``bcols``
    (``depth`` below their edge). Skirt row ``k`` is written by the range holding main row
    ``brows[k]``. Straight-line stores into a flat array: the compiler keeps the row in
    registers (indexing a 2-D output through a helper cost ten times as much).
    """
    h, w = height.shape
    n_main = h * w
    n_rows = len(brows) * w
    for i in range(first, last):
        y = ys[i]
        o = i * w * 6
        for j in range(w):
            out[o] = xs[j]
            out[o + 1] = y
            out[o + 2] = height[i, j]
            out[o + 3] = normal[i, j, 0]
            out[o + 4] = normal[i, j, 1]
            out[o + 5] = normal[i, j, 2]
            o += 6
        for kb in range(len(bcols)):
            c = bcols[kb]
            o = (n_main + n_rows + kb * h + i) * 6
            out[o] = xs[c]
            out[o + 1] = y
            out[o + 2] = height[i, c] - depth
            out[o + 3] = normal[i, c, 0]
            out[o + 4] = normal[i, c, 1]
            out[o + 5] = normal[i, c, 2]
    for kb in range(len(brows)):
        r = brows[kb]
        if first <= r < last:
            o = (n_main + kb * w) * 6
            for j in range(w):
                out[o] = xs[j]
                out[o + 1] = ys[r]
                out[o + 2] = height[r, j] - depth
                out[o + 3] = normal[r, j, 0]
                out[o + 4] = normal[r, j, 1]
                out[o + 5] = normal[r, j, 2]
                o += 6


@numba.njit(nogil=True, cache=True)
def _fill_morph_rows(out, xs, ys, height, level, normal, brows, bcols, depth, first, last):
    """As :func:`_fill_vertex_rows` for the ``4f 3f`` buffer: position, level, normal.

    A kernel of its own, not one shared with the stride as an argument: that cost nine
    times as much (a run-time stride and level test per vertex), and ``numba.literally``
    compiled it anew on every call.
    """
    h, w = height.shape
    n_main = h * w
    n_rows = len(brows) * w
    for i in range(first, last):
        y = ys[i]
        o = i * w * 7
        for j in range(w):
            out[o] = xs[j]
            out[o + 1] = y
            out[o + 2] = height[i, j]
            out[o + 3] = level[i, j]
            out[o + 4] = normal[i, j, 0]
            out[o + 5] = normal[i, j, 1]
            out[o + 6] = normal[i, j, 2]
            o += 7
        for kb in range(len(bcols)):
            c = bcols[kb]
            o = (n_main + n_rows + kb * h + i) * 7
            out[o] = xs[c]
            out[o + 1] = y
            out[o + 2] = height[i, c] - depth
            out[o + 3] = level[i, c]
            out[o + 4] = normal[i, c, 0]
            out[o + 5] = normal[i, c, 1]
            out[o + 6] = normal[i, c, 2]
    for kb in range(len(brows)):
        r = brows[kb]
        if first <= r < last:
            o = (n_main + kb * w) * 7
            for j in range(w):
                out[o] = xs[j]
                out[o + 1] = ys[r]
                out[o + 2] = height[r, j] - depth
                out[o + 3] = level[r, j]
                out[o + 4] = normal[r, j, 0]
                out[o + 5] = normal[r, j, 1]
                out[o + 6] = normal[r, j, 2]
                o += 7


@numba.njit(nogil=True, cache=True, inline="always")
def _half(d):  # pragma: no cover - compiled
    """Give the bits of the IEEE half nearest the double of bits ``d``, ties to even.

    NumPy's conversion (``npy_doublebits_to_halfbits``): every case's result is formed and
    the right one selected (branch-free, so a row's conversions share vector lanes): the
    normal case, a half subnormal rounded at its own precision, a signed zero below that,
    infinity beyond the largest half, a NaN keeping its payload's top bits.
    """
    sign = (d >> np.uint64(48)) & np.uint64(0x8000)
    exp = d & np.uint64(0x7FF0000000000000)
    mant = d & np.uint64(0x000FFFFFFFFFFFFF)
    # normal: round the 52-bit significand to 10 bits, half to even (a carry bumps the
    # exponent, which is right)
    add = (np.uint64(0x0000020000000000)
           if (mant & np.uint64(0x000007FFFFFFFFFF)) != np.uint64(0x0000020000000000)
           else np.uint64(0))
    result = (((exp - np.uint64(0x3F00000000000000)) >> np.uint64(42))
              + ((mant + add) >> np.uint64(42)))
    # subnormal (2^-25 <= |x| < 2^-14): the implicit bit made explicit, shifted into place
    shift = min(max(exp >> np.uint64(52), np.uint64(998)), np.uint64(1008)) - np.uint64(998)
    sub = (np.uint64(0x0010000000000000) + mant) << shift
    add = (np.uint64(0x0010000000000000)
           if (sub & np.uint64(0x003FFFFFFFFFFFFF)) != np.uint64(0x0010000000000000)
           else np.uint64(0))
    if exp <= np.uint64(0x3F00000000000000):
        result = (sub + add) >> np.uint64(53)
    if exp < np.uint64(0x3E60000000000000):
        result = np.uint64(0)
    special = np.uint64(0x7C00)  # infinity, or a NaN that stays one
    if exp == np.uint64(0x7FF0000000000000) and mant != np.uint64(0):
        special = np.uint64(0x7C00) + max(mant >> np.uint64(42), np.uint64(1))
    if exp >= np.uint64(0x40F0000000000000):
        result = special
    return np.uint16(sign + result)


@numba.njit(nogil=True, cache=True)
def _half_rows(bits, out, first, last):
    """Convert rows ``first .. last - 1`` of ``bits`` (float64 as uint64) to half bits."""
    w = bits.shape[1]
    for i in range(first, last):
        for j in range(w):
            out[i, j] = _half(bits[i, j])


def half_floats(a: np.ndarray) -> np.ndarray:
    """Give ``a.astype(numpy.float16)``'s values, compiled and on every core.

    NumPy converts float64 to float16 one element at a time in C (a 1025^2 layer's normals
    took 14 ms, more than building its vertex buffer); this is its arithmetic on the bits.

    Parameters
    ----------
    a : float64 array
        Any shape.

    Returns
    -------
    float16 array
        Same shape, ties rounded to even, as NumPy rounds them.
    """
    a = np.ascontiguousarray(a, dtype=np.float64)
    rows = a.reshape(a.shape[0] if a.ndim > 1 else 1, -1)
    out = np.empty(rows.shape, dtype=np.uint16)
    run_blocks(_half_rows, rows.shape[0], rows.view(np.uint64), out)
    return out.view(np.float16).reshape(a.shape)


def layer_buffers(z: np.ndarray, xs: np.ndarray, ys: np.ndarray, res: float,
                  brows: np.ndarray, bcols: np.ndarray, depth: float, cells,
                  vertices: bool, morph: bool, step: int = 1):
    """Give a layer's normals and the buffers asked for.

    With ``step`` > 1 the buffers hold only every ``step``-th row and column of vertices
    (and the skirts of those), each vertex's values those of the full buffers (the normals
    and geomorphing targets of the full grid, sampled): a layer drawn at level ``step`` or
    coarser draws the same triangles from them with :func:`block_indices` of the sampled
    grid. Every block-boundary line must be a multiple of ``step``.

    Parameters
    ----------
    z : (h, w) float64, metres
        The layer's (curved, faded) heights at its pixel centres.
    xs, ys : (w,), (h,) float64, metres
        Pixel centres (scene-local).
    res : float, metres
        Pixel size.
    brows, bcols : (k,) int
        Block-boundary rows and columns (their skirts follow the main vertices).
    depth : float, metres
        How far the skirts hang below their edge.
    cells : tuple
        ``(rl, cl, ra, rb, rt, ca, cb, ct, block)``: each row's and column's coarsest level
        (int64), and per level index q (level ``2^q``) the first and last line of the
        level-``2^(q+1)`` cell holding each line and its fraction of the way (float64);
        block: the coarsest level.
    vertices, morph : bool
        Build the ``3f 3f`` vertex buffer; the ``4f 3f`` geomorphing buffer.
    step : int
        Keep every ``step``-th vertex line (1: all).

    Returns
    -------
    normals : (h, w, 3) float64
    vert : (n, 6) float32 or None
    morph_buf : (n, 7) float32 or None
    """
    h, w = z.shape
    z = np.ascontiguousarray(z, dtype=np.float64)
    xs = np.ascontiguousarray(xs, dtype=np.float64)
    ys = np.ascontiguousarray(ys, dtype=np.float64)
    brows = np.ascontiguousarray(brows, dtype=np.int64)
    bcols = np.ascontiguousarray(bcols, dtype=np.int64)
    n = np.empty((h, w, 3))
    run_blocks(_normals_rows, h, z, float(res), n)
    target = level = tnormal = None
    if morph:
        target, level, tnormal = morph_targets(z, n, cells)
    zs, ns = z, n
    if step > 1:
        if (h - 1) % step or (w - 1) % step or np.any(brows % step) or np.any(bcols % step):
            raise ValueError(f"a {h} x {w} layer's blocks do not fall on every {step}-th line")

        def sampled(a):
            return np.ascontiguousarray(a[::step, ::step])

        xs, ys, zs, ns = xs[::step].copy(), ys[::step].copy(), sampled(z), sampled(n)
        brows, bcols = brows // step, bcols // step
        if morph:
            target, level, tnormal = sampled(target), sampled(level), sampled(tnormal)
    hs, ws = zs.shape
    n_all = hs * ws + len(brows) * ws + len(bcols) * hs
    vert = morph_buf = None
    if vertices:
        vert = np.empty((n_all, 6), dtype=np.float32)
        run_blocks(_fill_vertex_rows, hs, vert.reshape(-1), xs, ys, zs, ns, brows, bcols,
                   float(depth))
    if morph:
        morph_buf = np.empty((n_all, 7), dtype=np.float32)
        run_blocks(_fill_morph_rows, hs, morph_buf.reshape(-1), xs, ys, target, level, tnormal,
                   brows, bcols, float(depth))
    return n, vert, morph_buf


def morph_targets(z: np.ndarray, normals: np.ndarray, cells) -> tuple:
    """Per vertex: the next coarser level's height and normal below it, and its own level.

    Parameters
    ----------
    z : (h, w) float64, metres
        Heights.
    normals : (h, w, 3) float64
        Unit normals.
    cells : tuple
        The lines' levels and cells (:func:`layer_buffers`).

    Returns
    -------
    target : (h, w) float64, metres
    level : (h, w) float64
    target_normal : (h, w, 3) float64
        As ``render.terrain_scene``'s ``_morph_targets`` states them.
    """
    h, w = z.shape
    rl, cl, ra, rb, rt, ca, cb, ct, block = cells
    target = np.empty((h, w))
    tnormal = np.empty((h, w, 3))
    level = np.empty((h, w))
    run_blocks(_morph_rows, h, np.ascontiguousarray(z, dtype=np.float64),
               np.ascontiguousarray(normals, dtype=np.float64), rl, cl, ra, rb, rt, ca, cb,
               ct, int(block), target, tnormal, level)
    return target, level, tnormal


@numba.njit(nogil=True, cache=True)
def _fade_rows(z, xs, ys, pz, px0, py0, pres, margin, out, first, last):
    """Blend rows ``first .. last - 1`` into the parent's surface (see :func:`fade_in`)."""
    h, w = z.shape
    ph, pw = pz.shape
    for i in range(first, last):
        ey = min(ys[0] - ys[i], ys[i] - ys[h - 1])
        r = (py0 - ys[i]) / pres
        i0 = min(max(np.int64(math.floor(r)), 0), ph - 2)
        ti = min(max(r - i0, 0.0), 1.0)
        for j in range(w):
            ex = min(xs[j] - xs[0], xs[w - 1] - xs[j])
            t = min(max(min(ey, ex) / margin, 0.0), 1.0)
            weight = t * t * (3.0 - 2.0 * t)
            if not weight < 1.0:
                out[i, j] = z[i, j]
                continue
            c = (xs[j] - px0) / pres
            j0 = min(max(np.int64(math.floor(c)), 0), pw - 2)
            tj = min(max(c - j0, 0.0), 1.0)
            za, zb = pz[i0, j0], pz[i0, j0 + 1]
            zc, zd = pz[i0 + 1, j0], pz[i0 + 1, j0 + 1]
            if ti + tj <= 1.0:
                under = za + ti * (zc - za) + tj * (zb - za)
            else:
                under = zd + (1.0 - ti) * (zb - zd) + (1.0 - tj) * (zc - zd)
            out[i, j] = weight * z[i, j] + (1.0 - weight) * under


def fade_in(z: np.ndarray, xs: np.ndarray, ys: np.ndarray, parent: tuple,
            margin: float) -> np.ndarray:
    """Blend a layer's heights into its parent's surface across ``margin`` inside its edge.

    Parameters
    ----------
    z : (h, w) float64, metres
        The layer's heights.
    xs, ys : (w,), (h,) float64, metres
        Its pixel centres (scene-local).
    parent : tuple
        ``(z, x of column 0, y of row 0, cell size)`` of the parent (curved heights,
        scene-local); its surface is its full-resolution triangulation (the diagonal from
        top-right to bottom-left, as drawn).
    margin : float, metres
        Width of the blend; the layer's own heights weigh a smoothstep of the distance to
        its edge over it.

    Returns
    -------
    (h, w) float64, metres
        The blended heights (a new array).
    """
    pz, px0, py0, pres = parent
    out = np.empty(z.shape)
    run_blocks(_fade_rows, z.shape[0], np.ascontiguousarray(z, dtype=np.float64),
               np.ascontiguousarray(xs, dtype=np.float64),
               np.ascontiguousarray(ys, dtype=np.float64),
               np.ascontiguousarray(pz, dtype=np.float64), float(px0), float(py0),
               float(pres), float(margin), out)
    return out


@numba.njit(nogil=True, cache=True, inline="always")
def _sampled(n, s):
    """Count 0, s, 2s, ... below n, and n itself."""
    return (n - 1) // s + 2 if n > 0 else 1


@numba.njit(nogil=True, cache=True, inline="always")
def _sample(k, n, s):
    """Give the k-th of 0, s, 2s, ... below n, then n."""
    return min(k * s, n)


@numba.njit(nogil=True, cache=True)
def _index_rows(out, offsets, brows, bcols, h, w, s, first, last):
    """Write the indices of the blocks in block rows ``first .. last - 1``."""
    nbx = len(bcols) - 1
    row_base = h * w
    col_base = row_base + len(brows) * w
    for bi in range(first, last):
        r0 = brows[bi]
        rlen = brows[bi + 1] - r0
        nr = _sampled(rlen, s)
        for bj in range(nbx):
            c0 = bcols[bj]
            clen = bcols[bj + 1] - c0
            nc = _sampled(clen, s)
            o = offsets[bi * nbx + bj]
            for i in range(nr - 1):
                ra = r0 + _sample(i, rlen, s)
                rb = r0 + _sample(i + 1, rlen, s)
                for j in range(nc - 1):
                    ca = c0 + _sample(j, clen, s)
                    cb = c0 + _sample(j + 1, clen, s)
                    a, b = ra * w + ca, ra * w + cb
                    c, d = rb * w + ca, rb * w + cb
                    out[o] = a
                    out[o + 1] = c
                    out[o + 2] = b
                    out[o + 3] = b
                    out[o + 4] = c
                    out[o + 5] = d
                    o += 6
            # skirts: top, bottom (along the columns), left, right (along the rows)
            for edge in range(4):
                along = nc if edge < 2 else nr
                for k in range(along - 1):
                    if edge < 2:
                        line = r0 + (0 if edge == 0 else rlen)
                        p0, p1 = c0 + _sample(k, clen, s), c0 + _sample(k + 1, clen, s)
                        e0, e1 = line * w + p0, line * w + p1
                        low = row_base + (bi + edge) * w
                        l0, l1 = low + p0, low + p1
                    else:
                        line = c0 + (0 if edge == 2 else clen)
                        p0, p1 = r0 + _sample(k, rlen, s), r0 + _sample(k + 1, rlen, s)
                        e0, e1 = p0 * w + line, p1 * w + line
                        low = col_base + (bj + edge - 2) * h
                        l0, l1 = low + p0, low + p1
                    out[o] = e0
                    out[o + 1] = e1
                    out[o + 2] = l1
                    out[o + 3] = e0
                    out[o + 4] = l1
                    out[o + 5] = l0
                    o += 6


def block_indices(h: int, w: int, s: int, brows: np.ndarray, bcols: np.ndarray):
    """Index buffer of a layer of (h, w) vertices at level s, with every block's range.

    Blocks in row-major order, each its cells' two triangles (a, c, b), (b, c, d) row by
    row, then the skirts of its top, bottom, left and right edges; the skirt vertices
    follow the layer's main vertices (rows of block-boundary lines ``brows``, then columns
    ``bcols``).

    Returns
    -------
    indices : (n,) uint32
    offsets, counts : (n_blocks,) int64
        Each block's first index and number of indices.
    """
    brows = np.ascontiguousarray(brows, dtype=np.int64)
    bcols = np.ascontiguousarray(bcols, dtype=np.int64)
    nr = np.array([_sampled(int(n), s) for n in np.diff(brows)], dtype=np.int64)
    nc = np.array([_sampled(int(n), s) for n in np.diff(bcols)], dtype=np.int64)
    per = (6 * (nr[:, None] - 1) * (nc[None, :] - 1) + 12 * (nc[None, :] - 1)
           + 12 * (nr[:, None] - 1)).ravel()
    offsets = np.zeros(per.size, dtype=np.int64)
    if per.size:
        offsets[1:] = np.cumsum(per)[:-1]
    out = np.empty(int(per.sum()), dtype=np.uint32)
    run_blocks(_index_rows, len(brows) - 1, out, offsets, brows, bcols, int(h), int(w),
               int(s))
    return out, offsets, per.astype(np.int64)
