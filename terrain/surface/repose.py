r"""Slopes at repose: old ground relaxed so that it is nowhere steeper than the angle of repose.

Lunar regolith creeps downslope ever faster as the slope nears its angle of repose (about
35 degrees, Carrier et al. 1991, Lunar Sourcebook ch. 9), where it fails: the flux of the
nonlinear creep law of Roering et al. (1999, Water Resour. Res. 35, 853),
``q = K S / (1 - (S / Sc)^2)``, diverges at the critical gradient ``Sc``. Over the hundreds of
Myr that small lunar relief lives, any slope above Sc has long since failed; slopes below it
creep at the linear rate that :mod:`terrain.craters.diffusion` already gives the craters. So
on old ground the limit of the law is all that is left to apply: a *slope-limited
relaxation* (the "critical slope" limit of the law, as landscape models apply it, e.g. the
threshold hillslope of Roering et al. 1999, Fig. 1), which moves material from the upper to
the lower cell of every neighbour pair steeper than Sc until none is, conserving volume.

Each iteration looks at the four neighbour pairs of every cell (east, south, and the two
diagonals, at distances r and r sqrt 2) and, for a pair whose height difference exceeds
``Sc * distance``, moves :data:`RELAXATION` of the excess from the higher cell to the lower
(half to each side, all pairs at once: a Jacobi sweep, so the result is independent of cell
order). A cell that must not change (a known height, a fresh crater's wall) keeps its
height and the other cell of the pair takes the whole move. A pair limit of ``Sc cos(pi/8)``
bounds the gradient in every direction by Sc (the steepest direction lies within 22.5
degrees of one of the four pair directions), so the Horn slope of the relaxed ground stays
at or below the angle of repose.

A sweep visits only the blocks of :data:`BLOCK` x BLOCK cells that can still move: a block
is swept again only if one of its pairs exceeded its limit in the last sweep, or a cell of
the block or of its 1-cell border changed. A pair that was within its limit and whose two
cells did not change is still within it, so the skipped blocks would have moved nothing and
the result is bitwise that of sweeping every cell; what it costs is the area still moving.
That lets the relaxation run :data:`DEFAULT_ITERATIONS` sweeps for less than the cost of a
hundred full sweeps on the demo's layers, where most ground settles within a few sweeps
and only steep crater walls keep moving (Jacobi sweeps spread an excess like diffusion, so
a wall n cells wide takes of the order of n^2 sweeps to settle).

A cell depends only on cells within ``iterations`` of it, so a window grown by that halo
gives bitwise the same heights as the whole tile (:data:`DEFAULT_ITERATIONS`); the sweeps stop
early once no pair exceeds its limit by more than a thousandth of it (such pairs never move,
which keeps the early stop window-exact). The skipped blocks do not change this: they are
aligned to the window's own corner, but skipping changes no height.

Where cells that must not change pin two heights further apart than the limit allows along
any path of free cells between them (a fresh crater sitting on an old wall steeper than
repose keeps that wall's slope under it), no relaxation of the free cells can reach the
limit: there the sweeps settle into a steady flow from the higher pinned cell to the lower
(the free cell of a pair with a pinned one takes the whole move, so such a flow adds volume
at the top and takes it at the bottom), its pairs above their limit, until ``iterations``
ends them.

Examples
--------
>>> z = np.zeros((9, 9)); z[4, 4] = 10.0            # a 10 m spike on 1 m pixels
>>> out, moved = relax_to_repose(z, 1.0, 35.0)
>>> bool(horn_tangent(out, 1.0).max() <= math.tan(math.radians(35.0)) + 1e-9)
True
>>> round(float(out.sum()), 9) == round(float(z.sum()), 9)   # volume kept
True
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numba
import numpy as np

from terrain.core.errors import InvalidParameterError

log = logging.getLogger(__name__)

__all__ = ["BLOCK", "DEFAULT_FRESH_AGE_GYR", "DEFAULT_ITERATIONS", "RELAXATION", "Repose",
           "horn_tangent", "relax_to_repose"]

#: Most Jacobi iterations (and the halo a window needs): enough for the demo's crater walls to
#: settle where they can (see the module docstring), at the cost of fewer than a hundred
#: sweeps of every cell (benchmarks/bench_stack.py measures it).
DEFAULT_ITERATIONS = 1024
#: Side (cells) of the blocks a sweep skips while they are settled.
BLOCK = 16
#: Share of a pair's excess height difference moved per iteration (a cell has eight pairs).
RELAXATION = 0.25
#: Craters younger than this (Gyr) keep their walls: fresh walls stand above repose.
DEFAULT_FRESH_AGE_GYR = 0.1
#: A pair moves only when it exceeds its limit by more than this fraction of the limit, and
#: the sweeps stop once none does. Sub-threshold pairs never move, so a sweep that moves
#: nothing in a window would move nothing there in the whole tile either, and a window grown
#: by ``iterations`` cells still equals the whole tile's result.
_SETTLED = 1e-3
#: The pair limit as a fraction of Sc (see the module docstring).
_PAIR_FACTOR = math.cos(math.pi / 8.0)


@dataclass(frozen=True)
class Repose:
    """What relaxation to repose a terrain gets.

    Parameters
    ----------
    angle_deg : float
        Angle of repose (degrees, in (0, 90)).
    fresh_age_gyr : float
        Craters younger than this keep their walls.
    iterations : int
        Jacobi iterations at most.
    """

    angle_deg: float = 35.0
    fresh_age_gyr: float = DEFAULT_FRESH_AGE_GYR
    iterations: int = DEFAULT_ITERATIONS

    def __post_init__(self):
        a = float(self.angle_deg)
        if not 0.0 < a < 90.0:
            raise InvalidParameterError(f"angle of repose must lie in (0, 90) degrees; got {a}")
        if not float(self.fresh_age_gyr) >= 0.0:
            raise InvalidParameterError(
                f"fresh crater age must be >= 0 Gyr; got {self.fresh_age_gyr}")
        if int(self.iterations) < 1:
            raise InvalidParameterError(
                f"repose iterations must be >= 1; got {self.iterations}")
        object.__setattr__(self, "angle_deg", a)
        object.__setattr__(self, "fresh_age_gyr", float(self.fresh_age_gyr))
        object.__setattr__(self, "iterations", int(self.iterations))

    def as_dict(self) -> dict:
        """Return the settings as plain data for metadata."""
        return dict(angle_deg=self.angle_deg, fresh_age_gyr=self.fresh_age_gyr,
                    iterations=self.iterations)

    def fresh_mask(self, shape, transform, x, y, diameter, age) -> np.ndarray:
        """Pixels within 1.1 rim radii of a crater younger than ``fresh_age_gyr``.

        Parameters
        ----------
        shape : (rows, cols)
        transform : affine.Affine
            North-up, metres.
        x, y, diameter, age : (n,) float
            The craters: centres (map metres), diameters (m), ages (Gyr).

        Returns
        -------
        (rows, cols) bool
        """
        mask = np.zeros(shape, dtype=bool)
        res = float(transform.a)
        x0, y0 = float(transform.c), float(transform.f)
        ny, nx = shape
        x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
        reach = 0.55 * np.asarray(diameter, dtype=float)
        young = np.flatnonzero((np.asarray(age) < self.fresh_age_gyr)
                               & (x + reach >= x0) & (x - reach <= x0 + nx * res)
                               & (y + reach >= y0 - ny * res) & (y - reach <= y0))
        for i in young:
            cx, cy = float(x[i]), float(y[i])
            # the bowl, the rim crest and the ejecta's steep upper flank
            r = 0.55 * float(diameter[i])
            rc, cc = (y0 - cy) / res - 0.5, (cx - x0) / res - 0.5
            i0, i1 = max(0, math.ceil(rc - r / res)), min(ny - 1, math.floor(rc + r / res))
            j0, j1 = max(0, math.ceil(cc - r / res)), min(nx - 1, math.floor(cc + r / res))
            if i0 > i1 or j0 > j1:
                continue
            ii = np.arange(i0, i1 + 1)[:, None]
            jj = np.arange(j0, j1 + 1)[None, :]
            inside = (ii - rc) ** 2 + (jj - cc) ** 2 <= (r / res) ** 2
            mask[i0:i1 + 1, j0:j1 + 1] |= inside
        return mask


def horn_tangent(heights: np.ndarray, resolution: float) -> np.ndarray:
    """Tangent of Horn's slope at the interior cells (the edges repeat their neighbours).

    Parameters
    ----------
    heights : (ny, nx) float, metres
    resolution : float, metres per pixel

    Returns
    -------
    (ny, nx) float64
    """
    z = np.pad(np.asarray(heights, dtype=np.float64), 1, mode="edge")
    gx = ((z[:-2, 2:] + 2 * z[1:-1, 2:] + z[2:, 2:])
          - (z[:-2, :-2] + 2 * z[1:-1, :-2] + z[2:, :-2])) / (8.0 * resolution)
    gy = ((z[2:, :-2] + 2 * z[2:, 1:-1] + z[2:, 2:])
          - (z[:-2, :-2] + 2 * z[:-2, 1:-1] + z[:-2, 2:])) / (8.0 * resolution)
    return np.hypot(gx, gy)


@numba.njit(cache=True)
def _relax(z, free, limit, iterations, block):
    """Jacobi sweeps of the pair rule in place, over the active blocks only.

    Return the sweeps made, the pairs still above their limit at the last sweep, and the
    blocks swept (summed over the sweeps: the work).
    """
    ny, nx = z.shape
    nby = (ny + block - 1) // block
    nbx = (nx + block - 1) // block
    dz = np.zeros_like(z)
    active = np.ones((nby, nbx), dtype=np.bool_)
    nxt = np.zeros((nby, nbx), dtype=np.bool_)
    touched = np.zeros((nby, nbx), dtype=np.bool_)
    di = (0, 1, 1, 1)
    dj = (1, 0, 1, -1)
    dist = (1.0, 1.0, math.sqrt(2.0), math.sqrt(2.0))
    sweeps = 0
    left = 0
    work = 0
    for _ in range(iterations):
        left = 0
        nxt[:, :] = False
        touched[:, :] = False
        # the pairs a block owns: those of its cells with their east, south and two southern
        # diagonal neighbours (the south row and the side columns of its 1-cell border)
        for bi in range(nby):
            for bj in range(nbx):
                if not active[bi, bj]:
                    continue
                work += 1
                steep = False
                for i in range(bi * block, min(ny, (bi + 1) * block)):
                    for j in range(bj * block, min(nx, (bj + 1) * block)):
                        za = z[i, j]
                        if math.isnan(za):
                            continue
                        fa = free[i, j]
                        for p in range(4):
                            bi_ = i + di[p]
                            bj_ = j + dj[p]
                            if bi_ >= ny or bj_ < 0 or bj_ >= nx:
                                continue
                            zb = z[bi_, bj_]
                            if math.isnan(zb):
                                continue
                            fb = free[bi_, bj_]
                            if not (fa or fb):
                                continue
                            diff = za - zb
                            excess = abs(diff) - limit * dist[p]
                            if not excess > _SETTLED * limit:
                                continue
                            steep = True
                            left += 1
                            move = RELAXATION * excess * (1.0 if diff > 0.0 else -1.0)
                            if fa and fb:
                                dz[i, j] -= 0.5 * move
                                dz[bi_, bj_] += 0.5 * move
                            elif fa:
                                dz[i, j] -= move
                            else:
                                dz[bi_, bj_] += move
                if steep:
                    # a pair that moved may still be steep (its cells' moves may cancel)
                    nxt[bi, bj] = True
                    for a in range(bi, min(nby, bi + 2)):
                        for b in range(max(0, bj - 1), min(nbx, bj + 2)):
                            touched[a, b] = True
        if left == 0:
            break
        sweeps += 1
        for bi in range(nby):
            for bj in range(nbx):
                if not touched[bi, bj]:
                    continue
                for i in range(bi * block, min(ny, (bi + 1) * block)):
                    for j in range(bj * block, min(nx, (bj + 1) * block)):
                        d = dz[i, j]  # non-zero on free cells only
                        if d == 0.0:
                            continue
                        dz[i, j] = 0.0
                        znew = z[i, j] + d
                        if znew == z[i, j]:
                            continue
                        z[i, j] = znew
                        # every block owning a pair of this cell sweeps again
                        for a in range(max(0, i - 1) // block, min(ny - 1, i + 1) // block + 1):
                            for b in range(max(0, j - 1) // block,
                                           min(nx - 1, j + 1) // block + 1):
                                nxt[a, b] = True
        active, nxt = nxt, active
    return sweeps, left, work


def relax_to_repose(heights: np.ndarray, resolution: float, angle_deg: float, *,
                    movable: np.ndarray | None = None,
                    iterations: int = DEFAULT_ITERATIONS,
                    block: int = BLOCK) -> tuple[np.ndarray, np.ndarray]:
    """Relax slopes steeper than the angle of repose (see the module docstring).

    Parameters
    ----------
    heights : (ny, nx) float, metres
        NaN cells are unknown: they neither move nor limit their neighbours.
    resolution : float
        Metres per pixel.
    angle_deg : float
        Angle of repose, degrees.
    movable : (ny, nx) bool, optional
        Cells that may change (default: every known cell). Others keep their heights
        bitwise: pass False for known heights of a real DEM and fresh crater walls.
    iterations : int
        Most Jacobi iterations (it stops early once no pair is steeper than its limit by more
        than a thousandth of it).
    block : int
        Side (cells) of the blocks a sweep skips while they are settled; the heights do not
        depend on it, only the time they take.

    Returns
    -------
    heights : (ny, nx) float64, metres
        Relaxed; equal to the input wherever ``movable`` is False or nothing was too steep.
    changed : (ny, nx) bool
        Cells whose height changed.
    """
    z0 = np.asarray(heights, dtype=np.float64)
    if z0.ndim != 2:
        raise InvalidParameterError(f"heights must be (ny, nx); got shape {z0.shape}")
    if not (resolution > 0 and math.isfinite(resolution)):
        raise InvalidParameterError(f"resolution must be positive metres; got {resolution}")
    if not 0.0 < angle_deg < 90.0:
        raise InvalidParameterError(f"angle of repose must lie in (0, 90); got {angle_deg}")
    if int(block) < 1:
        raise InvalidParameterError(f"repose block must be >= 1 cell; got {block}")
    if movable is not None and np.shape(movable) != z0.shape:
        raise InvalidParameterError(
            f"movable must match heights {z0.shape}; got {np.shape(movable)}")
    known = np.isfinite(z0)
    free = known if movable is None else (np.asarray(movable, dtype=bool) & known)
    limit = math.tan(math.radians(angle_deg)) * _PAIR_FACTOR * resolution
    z = z0.copy()
    sweeps, left, work = _relax(z, np.ascontiguousarray(free), limit, int(iterations),
                                int(block))
    full = -(-z.shape[0] // int(block)) * -(-z.shape[1] // int(block))
    log.debug("repose: %d sweeps (the work of %.1f full sweeps), %d pairs still above the "
              "limit", sweeps, work / max(1, full), left)
    changed = free & (z != z0)
    z[~free] = z0[~free]
    return z, changed
