"""Crater populations from a power-law size-frequency distribution, generated seamlessly.

The cumulative size-frequency distribution (Martin et al. 2014, section III.C) is

    N_cum(D) = c D^k   craters with diameter >= D per km^2,

with k about -2 for a surface that looks the same at every scale and -1.8 for the lunar mare;
the number in a range follows from eq. 12, ``N(D1, D2) = N_cum(D1) - N_cum(D2)``. We set
``c`` from the user's density (craters with D >= Dmin per km^2), so ``c = density * Dmin^-k``.
Within a range, diameters are drawn by inverse-transform sampling of the truncated power law
(Clauset et al. 2009; Li et al. 2022, eq. 21)::

    D = (D1^k + u (D2^k - D1^k))^(1/k),   u ~ U(0, 1).

Ages follow the paper's linear age distribution: a constant cratering rate, so ages are
uniform between 0 and ``max_age`` (Gyr) and the cumulative count grows linearly with time.
A population of the craters that *survive* gives each size its lifetime, ``c D^2`` Gyr for
craters erased by topographic diffusion (:mod:`terrain.craters.diffusion`): at a constant
cratering rate the visible craters of diameter D have ages uniform over
``[0, min(max_age, c D^2)]``, and those older have gone. The density is then the visible
density, the one crater counts measure (the equilibrium, for sizes whose lifetime is shorter
than the surface's age). Larger craters are as many as the surface received: given
``production_n1`` (N(>=1 km) per km^2 produced over the surface's age,
:func:`terrain.craters.chronology.neukum_n1`), a crater of diameter D is kept with probability
``min(1, N_prod(>=D) / N(>=D))`` (:func:`terrain.craters.chronology.production_cumulative`
over this population's cumulative density), a draw keyed like the others, so the visible
density follows the smaller of the two.

Seamless generation
-------------------
Diameters are split into octave bins [Dmin 2^i, Dmin 2^(i+1)) (the last one truncated at Dmax).
Each bin tiles the map plane with square cells whose side is chosen so that a cell expects
:data:`CELL_EXPECTATION` craters; a cell's count is Poisson and every crater's position,
diameter and age are drawn from keys ``(seed, stream, bin, cell column, cell row, counter)``
(Gaskell 2005's chaotic functions of position). Cells are anchored at map coordinate (0, 0),
so the craters are a property of the map, not of a tile: any window, tile or DEM covering the
same map area enumerates exactly the same craters.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields

import numba
import numpy as np

from terrain.core import memory
from terrain.core.checks import check_keys, number
from terrain.core.errors import InvalidParameterError
from terrain.core.rng import check_seed, hash64, poisson, stream_id, uniform_scalar
from terrain.core.tomlfile import read_toml
from terrain.craters.catalog import CraterTable
from terrain.craters.chronology import SLOPE_ABOVE_1KM, SLOPE_BELOW_1KM

__all__ = ["CELL_EXPECTATION", "Population"]

#: Expected number of craters per generation cell of a bin.
CELL_EXPECTATION = 8.0
#: Bytes the generator holds per crater (columns and sort keys).
_BYTES_PER_CRATER = 96

STREAM_COUNT = stream_id("crater-count")
STREAM_CRATER = stream_id("crater")
STREAM_UID = stream_id("crater-uid")
STREAM_KEEP = stream_id("crater-keep")


#: Steepest size-frequency exponent accepted (observed lunar populations lie in -1.5..-4).
MIN_SFD_EXPONENT = -10.0


@dataclass(frozen=True)
class Population:
    """A power-law crater population.

    Parameters
    ----------
    dmin, dmax : float
        Diameter range in metres, 0 < dmin < dmax.
    density : float
        Craters with D >= dmin per km^2 (>= 0).
    sfd_exponent : float
        k of N_cum = c D^k (negative; -2 by default, -1.8 for mare).
    max_age : float
        Oldest crater age in Gyr; ages are uniform in [0, max_age].
    lifetime_coefficient : float
        c of a crater's lifetime ``c D^2`` (Gyr, D in metres): ages are uniform in
        ``[0, min(max_age, c D^2)]``. 0 (the default): every crater lives ``max_age``.
    production_n1 : float
        Craters >= 1 km per km^2 the surface received; where the production falls below the
        density, craters are thinned to it. 0 (the default): no thinning.

    Examples
    --------
    >>> p = Population(dmin=10, dmax=80, density=100.0)
    >>> p.bins().tolist()
    [[10.0, 20.0], [20.0, 40.0], [40.0, 80.0]]
    >>> round(p.expected_count(1.0), 6)    # per km^2, D in [10, 80)
    98.4375
    >>> t = Population(10, 80, 100.0, lifetime_coefficient=1e-5).generate(1, (0, 0, 500, 500))
    >>> bool((t.age <= 1e-5 * t.diameter**2).all())
    True
    """

    dmin: float
    dmax: float
    density: float
    sfd_exponent: float = -2.0
    max_age: float = 3.5
    lifetime_coefficient: float = 0.0
    production_n1: float = 0.0

    def __post_init__(self):
        for f in fields(self):
            object.__setattr__(self, f.name, number(getattr(self, f.name), f.name))
        if self.dmin <= 0:
            raise InvalidParameterError(f"dmin must be positive; got {self.dmin}")
        if self.dmax <= self.dmin:
            raise InvalidParameterError(
                f"dmin must be smaller than dmax; got dmin={self.dmin}, dmax={self.dmax}")
        if self.density < 0:
            raise InvalidParameterError(f"density must be >= 0 per km^2; got {self.density}")
        if not MIN_SFD_EXPONENT <= self.sfd_exponent < 0:
            raise InvalidParameterError(
                f"sfd exponent k must be negative and at least {MIN_SFD_EXPONENT:g} "
                f"(N_cum = c D^k; -2 for highlands, -1.8 for mare); got {self.sfd_exponent}")
        if self.max_age < 0:
            raise InvalidParameterError(f"max_age must be >= 0 Gyr; got {self.max_age}")
        if self.lifetime_coefficient < 0:
            raise InvalidParameterError(
                f"lifetime_coefficient must be >= 0 Gyr per m^2; got {self.lifetime_coefficient}")
        if self.production_n1 < 0:
            raise InvalidParameterError(
                f"production_n1 must be >= 0 per km^2; got {self.production_n1}")

    @classmethod
    def from_toml(cls, path, defaults=None, **overrides) -> Population:
        """Read ``[population]`` from a TOML file.

        Precedence: non-None ``overrides`` (command-line flags), then the file, then
        ``defaults``.
        """
        data = read_toml(path, "population file")
        known = {f.name for f in fields(cls)}
        if "population" in data:
            check_keys(data, {"population"}, f"population file '{path}'")
            table = data["population"]
            if not isinstance(table, dict):
                raise InvalidParameterError(
                    f"population file '{path}': population must be a table")
        else:
            table = data
        for key, value in table.items():
            if isinstance(value, dict):
                raise InvalidParameterError(
                    f"population file '{path}' has an unknown table [population.{key}]; "
                    f"[population] takes only {sorted(known)}")
        check_keys(table, known, f"population file '{path}'")
        values = dict(defaults or {})
        values.update({k: v for k, v in table.items() if k in known})
        values.update({k: v for k, v in overrides.items() if v is not None})
        missing = {"dmin", "dmax", "density"} - set(values)
        if missing:
            raise InvalidParameterError(f"population needs {sorted(missing)}")
        return cls(**values)

    def as_dict(self) -> dict:
        """Return the population as plain data for metadata."""
        return asdict(self)

    @property
    def sfd_constant(self) -> float:
        """C of N_cum = c D^k (per km^2, D in metres)."""
        return self.density * self.dmin ** (-self.sfd_exponent)

    def cumulative(self, diameter):
        """N_cum(D) per km^2 (eq. 12's building block)."""
        return self.sfd_constant * np.asarray(diameter, dtype=float) ** self.sfd_exponent

    def bins(self) -> np.ndarray:
        """(n, 2) octave diameter bins from dmin, the last truncated at dmax."""
        edges = [self.dmin]
        while edges[-1] * 2 < self.dmax * (1 - 1e-12):
            edges.append(edges[-1] * 2)
        edges.append(self.dmax)
        return np.column_stack([edges[:-1], edges[1:]])

    def bin_density(self, d_lo: float, d_hi: float) -> float:
        """Craters per m^2 with diameter in [d_lo, d_hi) (eq. 12)."""
        return float(self.cumulative(d_lo) - self.cumulative(d_hi)) / 1e6

    def expected_count(self, area_km2: float) -> float:
        """Return expected craters in [dmin, dmax) over an area in km^2."""
        return float(self.cumulative(self.dmin) - self.cumulative(self.dmax)) * area_km2

    def cell_size(self, d_lo: float, d_hi: float) -> float:
        """Side (m) of the generation cells of a bin: CELL_EXPECTATION craters per cell."""
        n = self.bin_density(d_lo, d_hi)
        return math.sqrt(CELL_EXPECTATION / n) if n > 0 else math.inf

    def generate(self, seed: int, extent, *, margin=0.0, bin_index=None,
                 min_diameter: float = 0.0) -> CraterTable:
        """Every crater whose centre lies in ``extent`` grown by ``margin``.

        Parameters
        ----------
        seed : int
        extent : (xmin, ymin, xmax, ymax), map metres
        margin : float or callable
            Metres added on every side; a callable gets the bin's upper diameter (so a caller
            can ask for every crater whose footprint may touch the extent).
        bin_index : int, optional
            Generate only this bin.
        min_diameter : float
            Drop craters smaller than this (metres). Bins wholly below it are skipped, so a
            coarse layer of a huge area does not enumerate its myriad small craters; the
            craters kept are exactly those the full population has there.
        """
        seed = check_seed(seed)
        xmin, ymin, xmax, ymax = (float(v) for v in extent)
        tables = []
        bins = self.bins()
        expected = 0.0
        for d_lo, d_hi in bins:
            if d_hi <= min_diameter:
                continue
            grow = margin(d_hi) if callable(margin) else float(margin)
            area = (xmax - xmin + 2 * grow) * (ymax - ymin + 2 * grow)
            expected += self.bin_density(d_lo, d_hi) * area
        memory.require(expected * _BYTES_PER_CRATER * 1.5,
                       f"generating about {expected:.3g} craters")
        for b, (d_lo, d_hi) in enumerate(bins):
            if (bin_index is not None and b != bin_index) or d_hi <= min_diameter:
                continue
            cell = self.cell_size(d_lo, d_hi)
            if not math.isfinite(cell):
                continue
            grow = margin(d_hi) if callable(margin) else float(margin)
            lo_x, hi_x = xmin - grow, xmax + grow
            lo_y, hi_y = ymin - grow, ymax + grow
            ix0, ix1 = math.floor(lo_x / cell), math.floor(hi_x / cell)
            iy0, iy1 = math.floor(lo_y / cell), math.floor(hi_y / cell)
            lam = self.bin_density(d_lo, d_hi) * cell * cell
            args = (seed, b, cell, lam, d_lo, d_hi, self.sfd_exponent, self.max_age,
                    self.lifetime_coefficient, self.production_n1, self.sfd_constant,
                    SLOPE_BELOW_1KM, SLOPE_ABOVE_1KM, ix0, ix1, iy0, iy1, lo_x, hi_x, lo_y, hi_y)
            n = _generate(*args, np.empty((0, 5)), np.empty(0, np.uint64), True)
            out = np.empty((n, 5))
            uid = np.empty(n, np.uint64)
            _generate(*args, out, uid, False)
            keep = out[:, 2] >= min_diameter
            tables.append(CraterTable(out[keep, 0], out[keep, 1], out[keep, 2], out[keep, 3],
                                      uid[keep], np.full(int(keep.sum()), b, dtype=np.int64)))
        return CraterTable.concatenate(tables)


@numba.njit(cache=True)
def _generate(seed, b, cell, lam, d_lo, d_hi, k, max_age, lifetime, n1, c_eq, below, above,
              ix0, ix1, iy0, iy1, lo_x, hi_x, lo_y, hi_y, out, uid, count_only):
    n = 0
    lo_k = d_lo**k
    span_k = d_hi**k - lo_k
    inv_k = 1.0 / k
    for iy in range(iy0, iy1 + 1):
        for ix in range(ix0, ix1 + 1):
            count = poisson(uniform_scalar(seed, STREAM_COUNT, b, ix, iy, 0), lam)
            for j in range(count):
                x = (ix + uniform_scalar(seed, STREAM_CRATER, b, ix, iy, 4 * j)) * cell
                y = (iy + uniform_scalar(seed, STREAM_CRATER, b, ix, iy, 4 * j + 1)) * cell
                if x < lo_x or x > hi_x or y < lo_y or y > hi_y:
                    continue
                u = uniform_scalar(seed, STREAM_CRATER, b, ix, iy, 4 * j + 2)
                d = (lo_k + u * span_k) ** inv_k
                if n1 > 0.0:
                    km = d / 1000.0
                    prod = n1 * km ** (below if km < 1.0 else above)
                    keep = prod / (c_eq * d**k)
                    if keep < 1.0 and uniform_scalar(seed, STREAM_KEEP, b, ix, iy, j) >= keep:
                        continue
                if not count_only:
                    out[n, 0] = x
                    out[n, 1] = y
                    span = max_age if lifetime <= 0.0 else min(max_age, lifetime * d * d)
                    out[n, 2] = d
                    out[n, 3] = span * uniform_scalar(seed, STREAM_CRATER, b, ix, iy, 4 * j + 3)
                    uid[n] = hash64(seed, STREAM_UID, b, ix, iy, j)
                n += 1
    return n
