r"""Triangle strips and the patch tree for view culling (Martin et al. 2014, section III.B).

"We generate long triangle strips across the model as shown in Figure 3 and then recursively
sub-divide the strips [...] with a parameter, K, specifying the desired number of strips and
strip size within mesh patches. If the current mesh contains at least K strips and the longest
strip contains at least K triangles then the mesh will be split into four by dividing into two
groups of strips and splitting each strip in half."

Strips
------
Strip b is the band of triangles between global rings b and b + 1 (:mod:`asteroid.sphere`),
``6 (2L + 1)`` triangles in canonical order running east from longitude 0. A patch holds a
contiguous range of bands and, in each band, the triangles whose canonical index t satisfies
``floor(T_b lo) <= t < floor(T_b hi)`` for a longitude fraction ``[lo, hi)`` of the band
(``T_b`` triangles; lo and hi are dyadic, so the cut points are exact integers). Halving the
fraction of every strip at once splits all the strips "in half" at about the same longitude.

Splitting rule
--------------
A node with more than K strips *and* a longest strip of more than K triangles splits into four
(two groups of strips, each strip halved), as the paper says; a node with only one of the two
too large splits in two along that direction. So every leaf holds at most K strips of at most
K triangles, and every triangle lies in exactly one leaf (the ranges of sibling nodes meet at
the same integer cut points). Leaves without triangles (thin polar bands cut many times) are
dropped.

Each node carries a bounding sphere of its vertices: leaves take the centre of their bounding
box and the farthest vertex from it; inner nodes enclose their children's spheres.

For drawing, :meth:`PatchTree.strip` returns one ``GL_TRIANGLE_STRIP`` index sequence per
node: every band piece is a run of 60 degree sectors, each a perfect strip
``b_0, a_0, b_1, a_1, ..., b_L, a_L, b_{L+1}``, joined by repeated indices (degenerate
triangles, which rasterisers discard) with the parity fixed so that every real triangle keeps
its outward winding.

Examples
--------
>>> from asteroid.sphere import SphereMesh
>>> mesh = SphereMesh(8)
>>> tree = PatchTree.build(mesh, np.ones(mesh.n_vertices), k=8)
>>> leaves = tree.leaves()
>>> int(sum(len(tree.triangles(n)) for n in leaves)) == mesh.n_faces
True
>>> int(tree.n_strips[leaves].max()) <= 8 and int(tree.n_triangles_max[leaves].max()) <= 8
True
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numba
import numpy as np

from asteroid.sphere import (
    SphereMesh,
    band_offset,
    band_size,
    band_small_ring,
    band_triangle,
    ring_offset,
    ring_size,
)
from terrain.core.errors import InvalidParameterError

__all__ = ["DEFAULT_PATCH_SIZE", "PatchTree", "decode_strip"]

log = logging.getLogger(__name__)

#: Default K: patches of at most 64 strips of at most 64 triangles (4096 triangles), a size
#: that keeps per-draw overhead small on current GPUs while culling a 6M-vertex body well.
DEFAULT_PATCH_SIZE = 64


@numba.njit(cache=True)
def _cut(total, numerator, depth):
    """floor(total * numerator / 2^depth) without overflow for realistic sizes."""
    return (total * numerator) >> depth


@numba.njit(cache=True)
def _longest(m, b0, b1, lo, hi, depth):
    best = 0
    for b in range(b0, b1):
        t = band_size(m, b)
        best = max(best, _cut(t, hi, depth) - _cut(t, lo, depth))
    return best


@numba.njit(cache=True)
def _count(m, b0, b1, lo, hi, depth):
    total = 0
    for b in range(b0, b1):
        t = band_size(m, b)
        total += _cut(t, hi, depth) - _cut(t, lo, depth)
    return total


@numba.njit(cache=True)
def _leaf_sphere(m, b0, b1, lo, hi, depth, vertices, out):
    """Bounding sphere (centre of the bounding box, farthest vertex) of a node's triangles."""
    mn = np.full(3, np.inf)
    mx = np.full(3, -np.inf)
    for b in range(b0, b1):
        t_all = band_size(m, b)
        for t in range(_cut(t_all, lo, depth), _cut(t_all, hi, depth)):
            tri = band_triangle(m, b, t)
            for i in tri:
                for c in range(3):
                    mn[c] = min(mn[c], vertices[i, c])
                    mx[c] = max(mx[c], vertices[i, c])
    for c in range(3):
        out[c] = 0.5 * (mn[c] + mx[c])
    r2 = 0.0
    for b in range(b0, b1):
        t_all = band_size(m, b)
        for t in range(_cut(t_all, lo, depth), _cut(t_all, hi, depth)):
            tri = band_triangle(m, b, t)
            for i in tri:
                dx = vertices[i, 0] - out[0]
                dy = vertices[i, 1] - out[1]
                dz = vertices[i, 2] - out[2]
                r2 = max(r2, dx * dx + dy * dy + dz * dz)
    out[3] = np.sqrt(r2)


def _enclose(spheres: np.ndarray) -> np.ndarray:
    """Return a sphere enclosing spheres (rows x, y, z, r): bounding-box centre, farthest reach."""
    lo = (spheres[:, :3] - spheres[:, 3:]).min(axis=0)
    hi = (spheres[:, :3] + spheres[:, 3:]).max(axis=0)
    centre = 0.5 * (lo + hi)
    radius = (np.linalg.norm(spheres[:, :3] - centre, axis=1) + spheres[:, 3]).max()
    return np.concatenate([centre, [radius]])


@dataclass(frozen=True, eq=False)
class PatchTree:
    """The recursive patch tree of one body.

    Node arrays (length n_nodes; node 0 is the root, children follow their parent):

    Parameters
    ----------
    mesh : SphereMesh
    k : int
        The paper's K.
    band_start, band_stop : (n,) int64
        Strips (bands) ``band_start <= b < band_stop``.
    lon_lo, lon_hi, lon_depth : (n,) int64
        Longitude fraction ``[lon_lo, lon_hi) / 2^lon_depth`` of every strip.
    parent : (n,) int64
        -1 for the root.
    children : (n, 4) int64
        Child node indices, -1 where absent.
    spheres : (n, 4) float64
        Bounding sphere centre (x, y, z) and radius, in the units of the vertices.
    n_triangles, n_strips, n_triangles_max : (n,) int64
        Triangles, non-empty strips and the longest strip's triangles of each node.
    """

    mesh: SphereMesh
    k: int
    band_start: np.ndarray
    band_stop: np.ndarray
    lon_lo: np.ndarray
    lon_hi: np.ndarray
    lon_depth: np.ndarray
    parent: np.ndarray
    children: np.ndarray
    spheres: np.ndarray
    n_triangles: np.ndarray
    n_strips: np.ndarray
    n_triangles_max: np.ndarray

    @classmethod
    def build(cls, mesh: SphereMesh, radii, *, k: int = DEFAULT_PATCH_SIZE) -> PatchTree:
        """Split the strips of ``mesh`` recursively into patches of at most K x K triangles.

        Parameters
        ----------
        mesh : SphereMesh
        radii : (N,) float64
            Vertex radii (the bounding spheres are computed from the vertices they place).
        k : int
            K >= 2.
        """
        if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or k < 2:
            raise InvalidParameterError(f"patch size K must be an integer >= 2; got {k!r}")
        k = int(k)
        radii = np.asarray(radii, dtype=np.float64)
        if radii.shape != (mesh.n_vertices,):
            raise InvalidParameterError(
                f"radii must be ({mesh.n_vertices},); got {radii.shape}")
        m = mesh.magnitude
        vertices = mesh.directions() * radii[:, None]
        nodes: list[tuple[int, ...]] = []  # [b0, b1, lo, hi, depth, parent]
        children = []
        stack = [(0, 2 * m, 0, 1, 0, -1)]
        leaf_flags = []
        while stack:
            b0, b1, lo, hi, depth, parent = stack.pop()
            me = len(nodes)
            nodes.append((b0, b1, lo, hi, depth, parent))
            children.append([-1, -1, -1, -1])
            if parent >= 0:
                slot = children[parent].index(-1)
                children[parent][slot] = me
            many_strips = (b1 - b0) > k
            long_strips = _longest(m, b0, b1, lo, hi, depth) > k
            parts = []
            if many_strips:
                mid = (b0 + b1) // 2
                groups = [(b0, mid), (mid, b1)]
            else:
                groups = [(b0, b1)]
            if long_strips:
                halves = [(2 * lo, 2 * lo + 1, depth + 1), (2 * lo + 1, 2 * hi, depth + 1)]
            else:
                halves = [(lo, hi, depth)]
            if many_strips or long_strips:
                for g0, g1 in groups:
                    for h_lo, h_hi, h_depth in halves:
                        if _count(m, g0, g1, h_lo, h_hi, h_depth) > 0:
                            parts.append((g0, g1, h_lo, h_hi, h_depth, me))
            leaf_flags.append(not parts)
            stack.extend(reversed(parts))
        arr = np.array(nodes, dtype=np.int64)
        ch = np.array(children, dtype=np.int64)
        n = len(arr)
        spheres = np.zeros((n, 4))
        n_tri = np.zeros(n, np.int64)
        n_strips = np.zeros(n, np.int64)
        longest = np.zeros(n, np.int64)
        for i in range(n):
            b0, b1, lo, hi, depth = (int(v) for v in arr[i, :5])
            sizes = np.array([band_size(m, b) for b in range(b0, b1)], dtype=np.int64)
            counts = (sizes * hi >> depth) - (sizes * lo >> depth)
            n_tri[i] = counts.sum()
            n_strips[i] = np.count_nonzero(counts)
            longest[i] = counts.max() if counts.size else 0
        # spheres: leaves from their vertices, then inner nodes bottom-up (children follow
        # parents in the node order, so a reverse pass sees children first)
        for i in range(n - 1, -1, -1):
            kids = ch[i][ch[i] >= 0]
            if kids.size == 0:
                b0, b1, lo, hi, depth = (int(v) for v in arr[i, :5])
                _leaf_sphere(m, b0, b1, lo, hi, depth, vertices, spheres[i])
            else:
                spheres[i] = _enclose(spheres[kids])
        log.debug("patch tree: %d nodes, %d leaves (K = %d)", n, int(sum(leaf_flags)), k)
        return cls(mesh, k, arr[:, 0].copy(), arr[:, 1].copy(), arr[:, 2].copy(),
                   arr[:, 3].copy(), arr[:, 4].copy(), arr[:, 5].copy(), ch, spheres, n_tri,
                   n_strips, longest)

    @property
    def n_nodes(self) -> int:
        """The number of nodes in the tree (all levels)."""
        return int(self.band_start.size)

    def leaves(self) -> np.ndarray:
        """Return indices of the leaf nodes (the patches), in depth-first order."""
        return np.flatnonzero((self.children < 0).all(axis=1))

    def _pieces(self, node: int):
        """(band, first triangle, stop triangle) of each non-empty strip piece of a node."""
        m = self.mesh.magnitude
        lo, hi, depth = int(self.lon_lo[node]), int(self.lon_hi[node]), int(self.lon_depth[node])
        for b in range(int(self.band_start[node]), int(self.band_stop[node])):
            t = band_size(m, b)
            t0, t1 = (t * lo) >> depth, (t * hi) >> depth
            if t1 > t0:
                yield b, t0, t1

    def triangles(self, node: int) -> np.ndarray:
        """Canonical indices (rows of :meth:`SphereMesh.faces`) of a node's triangles."""
        m = self.mesh.magnitude
        parts = [band_offset(m, b) + np.arange(t0, t1) for b, t0, t1 in self._pieces(node)]
        return np.concatenate(parts) if parts else np.zeros(0, np.int64)

    def strip(self, node: int) -> np.ndarray:
        """One ``GL_TRIANGLE_STRIP`` vertex index sequence (int64) drawing the node's triangles.

        Decoding it (:func:`decode_strip`) and dropping degenerate triangles gives exactly the
        node's triangles, outward wound.
        """
        m = self.mesh.magnitude
        out: list[int] = []
        for b, t0, t1 in self._pieces(node):
            gs, gl, el = band_small_ring(m, b)
            per = 2 * el + 1
            north = b < m
            s_first, s_last = t0 // per, (t1 - 1) // per
            for s in range(s_first, s_last + 1):
                k0 = max(t0 - s * per, 0)
                k1 = min(t1 - s * per, per)
                seq = _sector_sequence(m, gs, gl, el, s)[k0:k1 + 2]
                # triangle k of a sector keeps its winding when its first vertex sits at a
                # strip position of parity k + 1 in the north and k in the south
                _append(out, seq, (k0 + (1 if north else 0)) % 2)
        return np.asarray(out, dtype=np.int64)


def _sector_sequence(m, gs, gl, el, s) -> list[int]:
    """b_0, a_0, b_1, a_1, ..., b_L, a_L, b_{L+1} of sector s of a band."""
    na, nb = ring_size(m, gs), ring_size(m, gl)
    oa, ob = ring_offset(m, gs), ring_offset(m, gl)
    seq = []
    for i in range(el + 1):
        seq.append(ob + (s * (el + 1) + i) % nb)
        seq.append(oa + (s * el + i) % na)
    seq.append(ob + (s * (el + 1) + el + 1) % nb)
    return seq


def _append(out: list, seq: list, parity: int) -> None:
    """Append a strip so that its first vertex lands on a strip position of ``parity``."""
    if out:
        # X, X, P0, P0 (, P0): every triangle across the join has a repeated index
        out.append(out[-1])
        out.append(seq[0])
        out.append(seq[0])
        if (len(out) - 1) % 2 != parity:
            out.append(seq[0])
        out.extend(seq[1:])
    else:
        if parity == 1:
            out.append(seq[0])
        out.extend(seq)


def decode_strip(strip) -> np.ndarray:
    """Triangles of a ``GL_TRIANGLE_STRIP`` (OpenGL winding rule), degenerate ones dropped.

    >>> decode_strip([0, 1, 2, 3]).tolist()
    [[0, 1, 2], [2, 1, 3]]
    """
    s = np.asarray(strip, dtype=np.int64)
    if s.size < 3:
        return np.zeros((0, 3), np.int64)
    a, b, c = s[:-2], s[1:-1], s[2:]
    odd = (np.arange(a.size) % 2) == 1
    tri = np.column_stack([np.where(odd, b, a), np.where(odd, a, b), c])
    keep = (tri[:, 0] != tri[:, 1]) & (tri[:, 1] != tri[:, 2]) & (tri[:, 0] != tri[:, 2])
    return tri[keep]
