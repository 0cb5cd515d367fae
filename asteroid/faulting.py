r"""Two-phase Poisson faulting asteroid bases (Martin et al. 2014, section IV.A).

"A single fault is applied by choosing a great circle at random which splits the sphere into
two hemispheres. All height points on one hemisphere are modified by a fault height calculated
from a Gaussian random distribution scaled by the maximum fault size. The great circle is
selected by defining a vector with a random direction which defines the normal to a plane
intersecting the origin [...] The sign of the dot product between each vertex point and the
random vector determines in which hemisphere each vertex lies." Then: "An excessively rough
object is created with Poisson faulting using a large maximum fault size. A smoothing filter
is applied followed by a second phase of Poisson faulting with a small maximum fault size."

Our reading
-----------
* Fault j of a phase has a normal uniform on the sphere (Archimedes: ``z = 1 - 2 u1``,
  ``phi = 2 pi u2``) and a height ``h = S g / 3`` with g a standard Gaussian truncated to
  [-3, 3] (inverse-CDF sampling of the truncated range, so no rejection), i.e. sigma = S / 3
  and never more than the maximum fault size S, which the paper calls "faults up to 5 m".
  Vertices with ``u . n > 0`` rise by h; the others stay (the paper modifies one side only).
* Smoothing: ``passes`` separable box filters of ``filter_width`` metres on the sphere of
  the reference radius (:mod:`asteroid.smoothing`).
* The stretch (if any) is applied after smoothing and before the second phase, so that the
  fine roughness is not stretched with the body (Fig. 4's middle row shows the stretched
  first phase).
* The second phase adds its faults to the stretched body at the final vertex directions.

Every random number is keyed ``(seed, "asteroid-fault", phase, fault index, field)``; a vertex
accumulates its faults in index order, so its value does not depend on the other vertices and a
subset equals the same vertices of the whole body, bitwise (with smoothing, the subset's rings
are computed from the rings the filter reaches).

Speed: the paper calls faulting "a slow O(N^3) algorithm". Here it is O(vertices x faults)
of branch-free multiply-adds, in cache-sized blocks of vertices against every fault (four
faults held in registers per pass; the inner loop over vertices vectorises), in parallel
over blocks: the Fig. 9 model at M = 400 (960,002 vertices, 21,000 faults, three smoothing
passes, the stretch) takes about 4 s on two cores (``benchmarks/bench_asteroid.py``).

Preset
------
:data:`FIG8_FAULTING` is the paper's Fig. 8/9 model (section VI.B): "1000 faults up to 5 m,
three smoothing passes with 20 m filters, a second phase of faulting with 20000 faults up to
0.03 m, a factor 2 stretch on the x axis".

Examples
--------
>>> from asteroid.sphere import SphereMesh
>>> mesh = SphereMesh(12)
>>> f = Faulting(faults=50, max_fault=2.0, passes=1, filter_width=30.0, fine_faults=20,
...              fine_max_fault=0.1)
>>> whole = f.radii(mesh, 100.0, seed=3)
>>> part = f.radii(mesh, 100.0, seed=3, vertices=np.array([0, 400, 865]))
>>> bool(np.array_equal(whole[[0, 400, 865]], part))
True
"""

from __future__ import annotations

import logging
import math
from dataclasses import asdict, dataclass

import numba
import numpy as np

from asteroid.body import Stretch
from asteroid.smoothing import dependency, smooth
from asteroid.sphere import SphereMesh, ring_offset, ring_size, surface_radius_scalar, unit_vertex
from terrain.core import memory
from terrain.core.checks import integer, number
from terrain.core.errors import InvalidParameterError
from terrain.core.rng import check_seed, gaussian, stream_id, uniform

__all__ = ["FIG8_FAULTING", "Faulting", "TRUNCATION", "fault_table", "fault_sum"]

log = logging.getLogger(__name__)

STREAM_FAULT = stream_id("asteroid-fault")
#: Fault heights are Gaussian truncated at this many standard deviations; the maximum fault
#: size S is TRUNCATION sigma.
TRUNCATION = 3.0
#: Standard normal CDF at -TRUNCATION and +TRUNCATION.
_CDF_LO = 0.5 * math.erfc(TRUNCATION / math.sqrt(2.0))
_CDF_HI = 1.0 - _CDF_LO
#: Vertices per block of the fault kernel (a block's coordinates and sums stay in L1/L2).
BLOCK = 2048
#: Faults per keyed batch (bounds the fault table's memory for huge fault counts).
_FAULT_BATCH = 1 << 16


def fault_table(seed: int, phase: int, count: int, max_size: float, start: int = 0):
    """Return normals (n, 3) and heights (n,) of a phase's faults ``start .. start + count - 1``."""
    j = np.arange(start, start + count, dtype=np.int64)
    u = uniform(seed, STREAM_FAULT, phase, j[:, None], np.arange(3)[None, :])
    z = 1.0 - 2.0 * u[:, 0]
    phi = 2.0 * np.pi * u[:, 1]
    s = np.sqrt(np.maximum(0.0, 1.0 - z * z))
    normals = np.column_stack([s * np.cos(phi), s * np.sin(phi), z])
    p = _CDF_LO + u[:, 2] * (_CDF_HI - _CDF_LO)
    heights = max_size * _gaussians(p) / TRUNCATION
    return np.ascontiguousarray(normals), heights


@numba.njit(cache=True)
def _gaussians(p):
    out = np.empty(p.size)
    for i in range(p.size):
        out[i] = gaussian(p[i])
    return out


@numba.njit(cache=True, inline="always")
def _side(h, x, y, z, a, b, c):
    """H where (x, y, z) lies on the positive side of the great circle with normal (a, b, c)."""
    return h if x * a + y * b + z * c > 0.0 else 0.0


@numba.njit(cache=True, parallel=True)
def _fault_kernel(m, idx, nx, ny, nz, h, out):
    """out[v] += sum of h_j over faults j with u_v . n_j > 0, in fault order.

    Blocks of vertices in parallel; within a block, four faults at a time are held in
    registers while the (vectorised) inner loop runs over the block's vertices, so each
    vertex's coordinates and sum are loaded once per four faults. The additions stay in
    fault order, so a vertex's value does not depend on the block it falls in.
    """
    n = idx.size
    nblocks = (n + BLOCK - 1) // BLOCK
    nf = h.size
    nf4 = nf - nf % 4
    for blk in numba.prange(nblocks):
        lo = blk * BLOCK
        hi = min(n, lo + BLOCK)
        size = hi - lo
        x = np.empty(size)
        y = np.empty(size)
        z = np.empty(size)
        acc = np.empty(size)
        for i in range(size):
            x[i], y[i], z[i] = unit_vertex(m, idx[lo + i])
            acc[i] = out[lo + i]
        for j in range(0, nf4, 4):
            a0, b0, c0, h0 = nx[j], ny[j], nz[j], h[j]
            a1, b1, c1, h1 = nx[j + 1], ny[j + 1], nz[j + 1], h[j + 1]
            a2, b2, c2, h2 = nx[j + 2], ny[j + 2], nz[j + 2], h[j + 2]
            a3, b3, c3, h3 = nx[j + 3], ny[j + 3], nz[j + 3], h[j + 3]
            for i in range(size):
                xi, yi, zi = x[i], y[i], z[i]
                s = acc[i] + _side(h0, xi, yi, zi, a0, b0, c0)
                s += _side(h1, xi, yi, zi, a1, b1, c1)
                s += _side(h2, xi, yi, zi, a2, b2, c2)
                acc[i] = s + _side(h3, xi, yi, zi, a3, b3, c3)
        for j in range(nf4, nf):
            for i in range(size):
                acc[i] += _side(h[j], x[i], y[i], z[i], nx[j], ny[j], nz[j])
        for i in range(size):
            out[lo + i] = acc[i]


def fault_sum(mesh: SphereMesh, idx: np.ndarray, seed: int, phase: int, count: int,
              max_size: float, out: np.ndarray) -> None:
    """Add the ``count`` faults of a phase to ``out`` (metres) at vertices ``idx``."""
    for start in range(0, count, _FAULT_BATCH):
        n = min(_FAULT_BATCH, count - start)
        normals, heights = fault_table(seed, phase, n, max_size, start)
        _fault_kernel(mesh.magnitude, idx, np.ascontiguousarray(normals[:, 0]),
                      np.ascontiguousarray(normals[:, 1]), np.ascontiguousarray(normals[:, 2]),
                      heights, out)


@numba.njit(cache=True)
def _ring_vertices(m, rings):
    total = 0
    for g in range(rings.size):
        if rings[g]:
            total += ring_size(m, g)
    out = np.empty(total, np.int64)
    k = 0
    for g in range(rings.size):
        if rings[g]:
            o = ring_offset(m, g)
            for p in range(ring_size(m, g)):
                out[k] = o + p
                k += 1
    return out


@numba.njit(cache=True, parallel=True)
def _stretched(m, radii, idx, inv, out):
    """Radius of the stretched body along each vertex direction (asteroid.body.Stretch)."""
    for k in numba.prange(idx.size):
        x, y, z = unit_vertex(m, idx[k])
        sx = x * inv[0]
        sy = y * inv[1]
        sz = z * inv[2]
        length = math.sqrt(sx * sx + sy * sy + sz * sz)
        out[k] = surface_radius_scalar(m, radii, sx / length, sy / length, sz / length) / length


@dataclass(frozen=True)
class Faulting:
    """Two-phase Poisson faulting parameters.

    Parameters
    ----------
    faults : int
        First-phase faults (>= 0).
    max_fault : float
        First-phase maximum fault size S, metres.
    passes : int
        Smoothing passes after the first phase (>= 0).
    filter_width : float
        Width of each smoothing filter, metres.
    fine_faults : int
        Second-phase faults (>= 0).
    fine_max_fault : float
        Second-phase maximum fault size, metres.
    """

    faults: int = 1000
    max_fault: float = 5.0
    passes: int = 3
    filter_width: float = 20.0
    fine_faults: int = 20000
    fine_max_fault: float = 0.03

    def __post_init__(self):
        for name in ("faults", "passes", "fine_faults"):
            object.__setattr__(self, name, integer(getattr(self, name), name, low=0,
                                                   where="faulting"))
        for name in ("max_fault", "filter_width", "fine_max_fault"):
            object.__setattr__(self, name, number(getattr(self, name), name, low=0,
                                                  where="faulting"))

    def as_dict(self) -> dict:
        """Return the parameters as plain data (metres and counts) for recipes and metadata."""
        return asdict(self)

    def radii(self, mesh: SphereMesh, radius: float, *, seed: int,
              stretch: Stretch | None = None, vertices=None, progress=None) -> np.ndarray:
        """Vertex radii (metres) of the faulted body.

        Parameters
        ----------
        mesh : SphereMesh
        radius : float
            Reference radius R, metres: the sphere the faults displace.
        seed : int
        stretch : Stretch, optional
        vertices : (n,) int, optional
            Flat indices to evaluate (default all); values equal the whole body's, bitwise.
        progress : callable, optional
            ``progress(done, total)`` after each stage.

        Returns
        -------
        (n,) float64, metres
        """
        seed = check_seed(seed)
        radius = float(radius)
        if not (radius > 0 and math.isfinite(radius)):
            raise InvalidParameterError(f"radius must be positive metres; got {radius}")
        stretch = stretch or Stretch()
        m = mesh.magnitude
        n = mesh.n_vertices
        memory.require(n * 8 * 5, f"a faulting base of {n:,} vertices")
        if vertices is None:
            idx = np.arange(n, dtype=np.int64)
        else:
            idx = np.ascontiguousarray(vertices, dtype=np.int64).reshape(-1)
            if idx.size and (idx.min() < 0 or idx.max() >= n):
                raise InvalidParameterError(f"vertex indices must lie in [0, {n})")
        stages = 3
        # rings the second phase reads (its vertices', or the stretched sources' triangles)
        if stretch.is_identity:
            rings_out = np.zeros(2 * m + 1, bool)
            rings_out[mesh.ring_of(idx)[0]] = True
        elif vertices is None:
            rings_out = np.ones(2 * m + 1, bool)
        else:
            u0, _ = stretch.source(mesh.directions(idx))
            _, corners, _ = mesh.locate(u0)
            rings_out = np.zeros(2 * m + 1, bool)
            rings_out[mesh.ring_of(corners.reshape(-1))[0]] = True
        width = self.filter_width / radius
        needed = rings_out
        for _ in range(self.passes):
            needed = dependency(mesh, needed, width)
        # phase 1 on the rings the filter reaches
        phase1 = np.zeros(n)
        first = _ring_vertices(m, needed)
        acc = np.zeros(first.size)
        fault_sum(mesh, first, seed, 1, self.faults, self.max_fault, acc)
        phase1[first] = acc
        if progress:
            progress(1, stages)
        smoothed = smooth(mesh, phase1, width=width, passes=self.passes, rings=rings_out)
        if progress:
            progress(2, stages)
        base = radius + smoothed
        out = np.empty(idx.size)
        if stretch.is_identity:
            out[:] = base[idx]
        else:
            if not np.all(base[_ring_vertices(m, rings_out)] > 0):
                raise InvalidParameterError(
                    "the first faulting phase makes the radius reach zero; lower max_fault or "
                    "the number of faults, or raise the radius")
            _stretched(m, base, idx, 1.0 / stretch.factors, out)
        fine = np.zeros(idx.size)
        fault_sum(mesh, idx, seed, 2, self.fine_faults, self.fine_max_fault, fine)
        out += fine
        if progress:
            progress(3, stages)
        bad = ~(out > 0)
        if bad.any():
            raise InvalidParameterError(
                f"the faults make the radius reach zero at {int(bad.sum())} vertices; lower "
                "max_fault or the number of faults, or raise the radius")
        return out


#: The paper's Fig. 8/9 faulting model (section VI.B).
FIG8_FAULTING = Faulting(faults=1000, max_fault=5.0, passes=3, filter_width=20.0,
                         fine_faults=20000, fine_max_fault=0.03)
