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

Each iteration looks at the eight neighbours of every cell (at distances r and r sqrt 2)
and, for a pair whose height difference exceeds ``Sc * distance``, moves :data:`RELAXATION`
of the excess from the higher cell to the lower (half to each side, all pairs at once: a
Jacobi sweep; each cell sums its moves over its neighbours in one fixed order, so the result
depends neither on the order the cells are visited in nor on where a window starts). A cell
that must not change (a known height, a fresh crater's wall) keeps its height and the other
cell of the pair takes the whole move. A pair limit of ``Sc cos(pi/8)`` bounds the gradient
in every direction by Sc (the steepest direction lies within 22.5 degrees of one of the four
pair directions), so the Horn slope of the relaxed ground stays at or below the angle of
repose.

A sweep visits only the blocks of :data:`BLOCK` x BLOCK cells where a cell of the block or
of its 1-cell border changed in the last sweep. A cell none of whose 3 x 3 neighbourhood
changed gets the same moves as in the last sweep, which left it unchanged, so it stays
unchanged: the skipped blocks would have changed nothing, and the heights are bitwise those
of sweeping every cell. What a sweep costs is the area still moving, which lets the
relaxation run :data:`DEFAULT_ITERATIONS` sweeps for not much more than the 96 sweeps of
every cell it ran before: most ground settles within a few sweeps, and only steep walls
(Jacobi sweeps spread an excess like diffusion, so a wall n cells wide takes of the order
of n^2 sweeps to settle) and the free cells between pinned ones (below) keep moving.

A cell depends only on cells within ``iterations`` of it, so a window grown by that halo
gives bitwise the same heights as the whole tile (:data:`DEFAULT_ITERATIONS`); the sweeps stop
early once a sweep changes nothing (pairs within a thousandth of their limit do not move;
a window that has stopped would change nothing more, and what still moves outside it
reaches at most ``iterations`` cells in).

Where cells that must not change pin two heights further apart than the limit allows along
every path of free cells between them (known pixels of a base steeper than the limit at the
layer's pixel size, or a fresh crater on an old wall steeper than repose, which keeps that
wall's slope under it), no relaxation of the free cells reaches the limit: there the sweeps
settle into a flow from the higher pinned cell to the lower (the free cell of a pair with a
pinned one takes the whole move, so such a flow adds volume at the top and takes it at the
bottom), its pairs above their limit, until ``iterations`` ends them. Volume is conserved
where no pinned cell takes part.

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

#: Most Jacobi iterations (and the halo a window needs): enough for every layer of the demo's
#: stack to keep at most 0.5 % of its old ground above 35 deg (evaluation.validate), for about
#: a third more time than the 96 sweeps of every cell the relaxation made before it skipped
#: settled blocks (see the module docstring).
DEFAULT_ITERATIONS = 1024
#: Side (cells) of the blocks a sweep skips while they are settled.
BLOCK = 8
#: Share of a pair's excess height difference moved per iteration (a cell has eight pairs).
RELAXATION = 0.25
#: Craters younger than this (Gyr) keep their walls: fresh walls stand above repose.
DEFAULT_FRESH_AGE_GYR = 0.1
#: A pair moves only when it exceeds its limit by more than this fraction of the limit, so
#: the sweeps come to a stop (they stop once one changes nothing).
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
    """Jacobi sweeps of the pair rule in place, over the blocks that can still change.

    Return the sweeps made, the pairs above their limit at the end, and the blocks swept
    (summed over the sweeps: the work).
    """
    ny, nx = z.shape
    nby = (ny + block - 1) // block
    nbx = (nx + block - 1) // block
    dz = np.zeros_like(z)
    active = np.ones((nby, nbx), dtype=np.bool_)
    nxt = np.zeros((nby, nbx), dtype=np.bool_)
    # the eight neighbours, each cell's in the same order, so that a cell's sum of moves
    # does not depend on the blocks or on where a window starts
    di = (-1, -1, -1, 0, 0, 1, 1, 1)
    dj = (-1, 0, 1, -1, 1, -1, 0, 1)
    r2 = math.sqrt(2.0)
    dist = (r2, 1.0, r2, 1.0, 1.0, r2, 1.0, r2)
    sweeps = 0
    work = 0
    for _ in range(iterations):
        any_active = False
        for bi in range(nby):
            for bj in range(nbx):
                if not active[bi, bj]:
                    continue
                any_active = True
                work += 1
                for i in range(bi * block, min(ny, (bi + 1) * block)):
                    for j in range(bj * block, min(nx, (bj + 1) * block)):
                        za = z[i, j]
                        if not free[i, j] or math.isnan(za):
                            continue
                        d = 0.0
                        for p in range(8):
                            ii = i + di[p]
                            jj = j + dj[p]
                            if ii < 0 or ii >= ny or jj < 0 or jj >= nx:
                                continue
                            zb = z[ii, jj]
                            if math.isnan(zb):
                                continue
                            excess = abs(za - zb) - limit * dist[p]
                            if not excess > _SETTLED * limit:
                                continue
                            move = RELAXATION * excess
                            if free[ii, jj]:
                                move *= 0.5  # half to each cell; a fixed one takes none
                            d += -move if za > zb else move
                        dz[i, j] = d
        if not any_active:
            break
        sweeps += 1
        nxt[:, :] = False
        for bi in range(nby):
            for bj in range(nbx):
                if not active[bi, bj]:
                    continue
                for i in range(bi * block, min(ny, (bi + 1) * block)):
                    for j in range(bj * block, min(nx, (bj + 1) * block)):
                        d = dz[i, j]
                        if d == 0.0:
                            continue
                        dz[i, j] = 0.0
                        znew = z[i, j] + d
                        if znew == z[i, j]:
                            continue
                        z[i, j] = znew
                        # the blocks holding this cell or a neighbour sweep again
                        for a in range(max(0, i - 1) // block, min(ny - 1, i + 1) // block + 1):
                            for b in range(max(0, j - 1) // block,
                                           min(nx - 1, j + 1) // block + 1):
                                nxt[a, b] = True
        active, nxt = nxt, active
    left = 0
    for i in range(ny):
        for j in range(nx):
            za = z[i, j]
            if math.isnan(za):
                continue
            for p in range(4, 8):  # each pair once: east and the three southern neighbours
                ii = i + di[p]
                jj = j + dj[p]
                if ii >= ny or jj < 0 or jj >= nx:
                    continue
                zb = z[ii, jj]
                if math.isnan(zb) or not (free[i, j] or free[ii, jj]):
                    continue
                if abs(za - zb) - limit * dist[p] > _SETTLED * limit:
                    left += 1
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
