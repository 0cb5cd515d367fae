r"""Where craters and boulders go: power-law counts over the body and uniform positions.

Counts
------
A :class:`terrain.craters.population.Population` gives the cumulative size-frequency distribution
``N_cum(D) = c D^k`` (Martin et al. 2014, section V.B; its density is craters with D >= dmin per
km^2). For each octave diameter bin ``[D1, D2)`` of
:meth:`~terrain.craters.population.Population.bins`
the expected number on the body is ``(N_cum(D1) - N_cum(D2)) A`` (eq. 5) for the body's surface
area A, and the count is Poisson with that mean, drawn by inverse-CDF sampling of one keyed
uniform per bin (``(seed, stream + "-count", bin)``). Feature j of bin b then takes its fields
from keyed uniforms ``(seed, stream, b, j, field)``, so adding a bin or changing another bin's
count never moves a feature, and the catalogue of a body is a pure function of its seed.

Diameters within a bin follow the truncated power law by inverse-transform sampling,
``D = (D1^k + u (D2^k - D1^k))^(1/k)`` (as :mod:`terrain.craters.population`).

Positions
---------
The paper's eqs. 1-2 normalise a point drawn uniformly in the cube [-0.5, 0.5]^3: the
directions then crowd towards the cube's eight corners (their density is proportional to the
cube's extent along each direction cubed, 5.2 times higher at a corner than at a face
centre). We use Archimedes' hat-box theorem instead: the area of a spherical zone is
proportional to its height, so ``z = 1 - 2 u1`` and ``phi = 2 pi u2`` are exactly uniform on
the sphere. Latitude and longitude then follow eqs. 3-4 with z as the polar axis (the paper
uses y). ``tests/asteroid/test_placement.py`` checks uniformity with a chi-square test over
the 20 equal-area cells of an icosahedron, which the cube method fails.

Examples
--------
>>> from terrain.craters.population import Population
>>> pop = Population(dmin=10.0, dmax=80.0, density=2.0)
>>> p = sample(pop, 4 * np.pi * 2000.0**2, seed=3, stream="demo")
>>> len(p), bool(np.allclose(np.linalg.norm(p.directions, axis=1), 1.0))
(83, True)
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np

from terrain.core import memory
from terrain.core.errors import InvalidParameterError
from terrain.core.rng import check_seed, hash64, stream_id, uniform
from terrain.craters.population import Population

__all__ = ["Placement", "expected_counts", "sample", "uniform_directions"]

#: Keyed uniform fields of every feature: 0, 1 position, 2 diameter, 3 age; 4.. free for the
#: caller (boulder shape and orientation).
FIELD_Z, FIELD_PHI, FIELD_DIAMETER, FIELD_AGE = 0, 1, 2, 3
FIRST_EXTRA_FIELD = 4
#: Bytes held per feature while sampling (fields, columns and sort keys).
_BYTES_PER_FEATURE = 256


def uniform_directions(u1, u2) -> np.ndarray:
    """Return unit vectors uniform on the sphere from two uniforms in (0, 1) (Archimedes).

    >>> uniform_directions(np.array([0.5]), np.array([0.25])).round(12).tolist()
    [[0.0, 1.0, 0.0]]
    """
    z = 1.0 - 2.0 * np.asarray(u1, dtype=np.float64)
    phi = 2.0 * np.pi * np.asarray(u2, dtype=np.float64)
    s = np.sqrt(np.maximum(0.0, 1.0 - z * z))
    return np.stack([s * np.cos(phi), s * np.sin(phi), z], axis=-1)


@dataclass(frozen=True, eq=False)
class Placement:
    """Features sampled over a body (columns of equal length n).

    Parameters
    ----------
    directions : (n, 3) float64, unit vectors from the body centre
    diameters : (n,) float64, metres
    ages : (n,) float64, Gyr
    uid : (n,) uint64, identity (keys each feature's own randomness)
    size_class : (n,) int64, the octave bin
    index : (n,) int64, the feature's index j within its bin
    extra : (n, e) float64, keyed uniforms of fields 4 .. 4 + e - 1
    """

    directions: np.ndarray
    diameters: np.ndarray
    ages: np.ndarray
    uid: np.ndarray
    size_class: np.ndarray
    index: np.ndarray
    extra: np.ndarray

    def __len__(self) -> int:
        return int(self.diameters.size)

    @property
    def latitude(self) -> np.ndarray:
        """Radians (eq. 3, z polar)."""
        return np.arcsin(np.clip(self.directions[:, 2], -1.0, 1.0))

    @property
    def longitude(self) -> np.ndarray:
        """Radians in [0, 2 pi) (eq. 4, written with atan2)."""
        return np.mod(np.arctan2(self.directions[:, 1], self.directions[:, 0]), 2 * np.pi)

    def take(self, order) -> Placement:
        """Return the placements in the given order (an index array or boolean mask)."""
        return Placement(self.directions[order], self.diameters[order], self.ages[order],
                         self.uid[order], self.size_class[order], self.index[order],
                         self.extra[order])


def expected_counts(population: Population, area_m2: float) -> np.ndarray:
    """Return expected features per octave bin over ``area_m2`` square metres (eq. 5)."""
    bins = population.bins()
    return np.array([population.bin_density(lo, hi) * area_m2 for lo, hi in bins])


@numba.njit(cache=True)
def _uids(seed, stream, b, j, out):
    for i in range(j.size):
        out[i] = hash64(seed, stream, b, j[i], 0, 0)


def sample(population: Population, area_m2: float, *, seed: int, stream: str,
           extra_fields: int = 0, max_features: int | None = None) -> Placement:
    """Every feature of ``population`` over a body of ``area_m2`` m^2.

    Parameters
    ----------
    population : Population
    area_m2 : float
        The body's surface area, m^2.
    seed : int
    stream : str
        Names the random stream ("asteroid-crater", "asteroid-boulder", ...).
    extra_fields : int
        Keyed uniforms per feature beyond position, diameter and age.
    max_features : int, optional
        Refuse (before sampling) a population expected to exceed this many features.

    Returns
    -------
    Placement
        Features in bin order, then index order.
    """
    seed = check_seed(seed)
    area_m2 = float(area_m2)
    if not (area_m2 > 0 and math.isfinite(area_m2)):
        raise InvalidParameterError(f"body area must be positive m^2; got {area_m2}")
    expected = expected_counts(population, area_m2)
    total = float(expected.sum())
    if max_features is not None and total > max_features:
        raise InvalidParameterError(
            f"the {stream} population expects {total:.3g} features on this body, more than "
            f"the limit of {max_features:,}; raise dmin or lower the density")
    memory.require((total + 10.0 * math.sqrt(total + 1.0)) * _BYTES_PER_FEATURE
                   * (1 + extra_fields / 4.0), f"sampling about {total:.3g} {stream} features")
    from scipy.stats import poisson  # here: scipy.stats costs every importer of asteroid ~1 s

    sid = stream_id(stream)
    count_stream = stream_id(stream + "-count")
    uid_stream = stream_id(stream + "-uid")
    k = population.sfd_exponent
    n_fields = FIRST_EXTRA_FIELD + int(extra_fields)
    parts = []
    for b, ((d_lo, d_hi), lam) in enumerate(zip(population.bins(), expected, strict=True)):
        if lam <= 0:
            continue
        u = float(uniform(seed, count_stream, b, 0, 0))
        n = int(poisson.ppf(u, lam))
        if n == 0:
            continue
        j = np.arange(n, dtype=np.int64)
        f = uniform(seed, sid, b, j[:, None], np.arange(n_fields)[None, :])
        lo_k = d_lo**k
        diam = (lo_k + f[:, FIELD_DIAMETER] * (d_hi**k - lo_k)) ** (1.0 / k)
        uid = np.empty(n, np.uint64)
        _uids(seed, uid_stream, b, j, uid)
        parts.append((uniform_directions(f[:, FIELD_Z], f[:, FIELD_PHI]), diam,
                      population.max_age * f[:, FIELD_AGE], uid, np.full(n, b, np.int64), j,
                      f[:, FIRST_EXTRA_FIELD:]))
    if not parts:
        return Placement(np.zeros((0, 3)), np.zeros(0), np.zeros(0), np.zeros(0, np.uint64),
                         np.zeros(0, np.int64), np.zeros(0, np.int64),
                         np.zeros((0, int(extra_fields))))
    cols = [np.concatenate([p[i] for p in parts]) for i in range(7)]
    return Placement(*cols)
