"""Position-keyed, counter-based randomness.

Every random number in craterscape is a pure function of a key
``(seed, stream, level, ix, iy, k)``: the user's seed, a named stream (what the number is
for), a level (resolution level, RMD half-step or size class), a global integer position and
a counter. There is no sequential generator state anywhere, so any window, tile or subset of
points computed alone draws exactly the numbers the full run draws, on any machine and in any
order. This is the scheme of Gaskell's small-body simulator ("each point i,j on the
fundamental grid has its own generator, completely independent from neighboring points",
Gaskell 2005, section 2, eq. 7) extended with streams and levels.

The hash absorbs the six 64-bit words one at a time through the SplitMix64 finaliser
(Steele, Lea and Flood 2014), a bijective avalanche mixer; uniforms take the top 53 bits and
Gaussians come from the inverse normal CDF of one uniform (Wichura 1988, algorithm AS241,
tabulated in the body of the distribution, see :func:`gaussian`), so one key gives one
Gaussian.

Examples
--------
>>> a = normal(7, stream_id("demo"), 0, np.arange(5), 3)
>>> b = normal(7, stream_id("demo"), 0, np.arange(2, 5), 3)
>>> bool(np.array_equal(a[2:], b))
True
"""

from __future__ import annotations

import hashlib
import math

import numba
import numpy as np

from terrain.core.parallel import run_blocks

__all__ = [
    "MAX_SEED",
    "check_seed",
    "gaussian",
    "hash64",
    "hash_at",
    "key_prefix",
    "normal",
    "normal_at",
    "normal_scalar",
    "poisson",
    "stream_id",
    "uniform",
    "uniform_at",
    "uniform_scalar",
]

#: Seeds are non-negative integers below 2**63 (they travel as int64 through compiled code).
MAX_SEED = 2**63 - 1

_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_INIT = np.uint64(0x243F6A8885A308D3)  # first 64 bits of pi's fraction
_M1 = np.uint64(0xBF58476D1CE4E5B9)  # SplitMix64 multipliers
_M2 = np.uint64(0x94D049BB133111EB)
_S30 = np.uint64(30)
_S27 = np.uint64(27)
_S31 = np.uint64(31)
_S11 = np.uint64(11)
_TWO_M53 = 2.0**-53


def check_seed(seed) -> int:
    """Return ``seed`` as a Python int, or raise ``ValueError`` naming what arrived.

    >>> check_seed(42)
    42
    """
    from terrain.core.errors import InvalidParameterError

    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)):
        raise InvalidParameterError(f"seed must be an integer in [0, 2**63); got {seed!r}")
    seed = int(seed)
    if not 0 <= seed <= MAX_SEED:
        raise InvalidParameterError(f"seed must be an integer in [0, 2**63); got {seed}")
    return seed


def stream_id(name: str) -> int:
    """Stable 63-bit identifier of a named random stream (BLAKE2b of the name).

    >>> stream_id("rmd") == stream_id("rmd") != stream_id("crater-count")
    True
    """
    digest = hashlib.blake2b(name.encode("utf-8"), digest_size=8).digest()
    return int.from_bytes(digest, "little") & MAX_SEED


@numba.njit(cache=True, inline="always")
def _mix(z):
    z = (z ^ (z >> _S30)) * _M1
    z = (z ^ (z >> _S27)) * _M2
    return z ^ (z >> _S31)


@numba.njit(cache=True, inline="always")
def _absorb(h, v):
    return _mix((h ^ v) + _GOLDEN)


@numba.njit(cache=True)
def key_prefix(seed, stream, level, k):
    """Hash state after absorbing (seed, stream, level, k); finish it with :func:`hash_at`.

    Inner loops compute the prefix once per level and pay two absorptions per position.
    """
    h = _INIT
    h = _absorb(h, np.uint64(seed))
    h = _absorb(h, np.uint64(stream))
    h = _absorb(h, np.uint64(level))
    h = _absorb(h, np.uint64(k))
    return h


@numba.njit(cache=True, inline="always")
def hash_at(prefix, ix, iy):
    """Finish a key prefix with a global integer position."""
    return _absorb(_absorb(prefix, np.uint64(ix)), np.uint64(iy))


@numba.njit(cache=True)
def hash64(seed, stream, level, ix, iy, k):
    """64-bit hash of the key (all arguments int64; negative positions are fine)."""
    return hash_at(key_prefix(seed, stream, level, k), ix, iy)


@numba.njit(cache=True, inline="always")
def _unit(h):
    return (float(h >> _S11) + 0.5) * _TWO_M53


@numba.njit(cache=True)
def uniform_at(prefix, ix, iy):
    """Uniform (0, 1) deviate of a key prefix at a position."""
    return _unit(hash_at(prefix, ix, iy))


@numba.njit(cache=True)
def uniform_scalar(seed, stream, level, ix, iy, k):
    """Uniform on the open interval (0, 1) from the key's top 53 bits."""
    return _unit(hash64(seed, stream, level, ix, iy, k))


@numba.njit(cache=True)
def _ppnd16(p):
    """Inverse standard normal CDF, Wichura (1988) AS241 PPND16, for 0 < p < 1."""
    q = p - 0.5
    if abs(q) <= 0.425:
        r = 0.180625 - q * q
        num = (((((((2509.0809287301226727 * r + 33430.575583588128105) * r
                    + 67265.770927008700853) * r + 45921.953931549871457) * r
                  + 13731.693765509461125) * r + 1971.5909503065514427) * r
                + 133.14166789178437745) * r + 3.387132872796366608)
        den = (((((((5226.495278852545925 * r + 28729.085735721942674) * r
                    + 39307.89580009271061) * r + 21213.794301586595867) * r
                  + 5394.1960214247511077) * r + 687.1870074920579083) * r
                + 42.313330701600911252) * r + 1.0)
        return q * num / den
    r = p if q < 0.0 else 1.0 - p
    r = math.sqrt(-math.log(r))
    if r <= 5.0:
        r -= 1.6
        num = (((((((7.7454501427834140764e-4 * r + 0.0227238449892691845833) * r
                    + 0.24178072517745061177) * r + 1.27045825245236838258) * r
                  + 3.64784832476320460504) * r + 5.7694972214606914055) * r
                + 4.6303378461565452959) * r + 1.42343711074968357734)
        den = (((((((1.05075007164441684324e-9 * r + 5.475938084995344946e-4) * r
                    + 0.0151986665636164571966) * r + 0.14810397642748007459) * r
                  + 0.68976733498510000455) * r + 1.6763848301838038494) * r
                + 2.05319162663775882187) * r + 1.0)
    else:
        r -= 5.0
        num = (((((((2.01033439929228813265e-7 * r + 2.71155556874348757815e-5) * r
                    + 0.0012426609473880784386) * r + 0.026532189526576123093) * r
                  + 0.29656057182850489123) * r + 1.7848265399172913358) * r
                + 5.4637849111641143699) * r + 6.6579046435011037772)
        den = (((((((2.04426310338993978564e-15 * r + 1.4215117583164458887e-7) * r
                    + 1.8463183175100546818e-5) * r + 7.868691311456132591e-4) * r
                  + 0.0148753612908506148525) * r + 0.13692988092273580531) * r
                + 0.59983220655588793769) * r + 1.0)
    val = num / den
    return -val if q < 0.0 else val


#: Inverse normal CDF table: _TABLE[i] = PPND16((i + 0.5) / _TABLE_SIZE).
_TABLE_SIZE = 1 << 14
#: Below this probability (and above 1 - it) the table is bypassed for the exact AS241 tails.
_TABLE_TAIL = 1.0 / 1024.0


def _build_table():
    return np.array([_ppnd16((i + 0.5) / _TABLE_SIZE) for i in range(_TABLE_SIZE)])


_TABLE = _build_table()


@numba.njit(cache=True)
def gaussian(u):
    """Return the standard normal deviate for a uniform u in (0, 1).

    Inverse-CDF sampling: linear interpolation in a 2^14-entry table of AS241 values for
    1/1024 < u < 1 - 1/1024 (quantile error below 2e-4, about 5x faster than evaluating the
    rational approximation, whose long dependency chain dominates fractal synthesis), exact
    AS241 in the tails.
    """
    if u < _TABLE_TAIL or u > 1.0 - _TABLE_TAIL:
        return _ppnd16(u)
    t = u * _TABLE_SIZE - 0.5
    i = int(t)
    f = t - i
    a = _TABLE[i]
    return a + f * (_TABLE[i + 1] - a)


@numba.njit(cache=True)
def poisson(u, lam):
    """Return the Poisson(lam) count at quantile u in (0, 1): inverse-CDF sampling.

    A sequential search of the CDF for lam <= 500 (the crater and rock generators use about
    8 and 16 per cell), a normal approximation N(lam, lam) rounded to the nearest count above
    (where the search would be long and the Poisson is close to normal).

    >>> poisson(0.5, 8.0), poisson(1e-9, 8.0), poisson(0.5, 1000.0)
    (8, 0, 1000)
    """
    if lam > 500.0:
        from_normal = lam + math.sqrt(lam) * gaussian(u) + 0.5
        return max(int(from_normal), 0)
    p = math.exp(-lam)
    cdf = p
    k = 0
    limit = int(lam + 40.0 * math.sqrt(lam) + 100.0)
    while u > cdf and k < limit:
        k += 1
        p *= lam / k
        cdf += p
    return k


@numba.njit(cache=True)
def normal_scalar(seed, stream, level, ix, iy, k):
    """Return the standard normal deviate of the key."""
    return gaussian(uniform_scalar(seed, stream, level, ix, iy, k))


@numba.njit(cache=True)
def normal_at(prefix, ix, iy):
    """Return the standard normal deviate of a key prefix at a position (equals normal_scalar)."""
    return gaussian(uniform_at(prefix, ix, iy))


@numba.njit(nogil=True, cache=True)
def _uniform_rows(seed, stream, level, ix, iy, k, out, first, last):
    for i in range(first, last):
        for j in range(out.shape[1]):
            out[i, j] = uniform_scalar(seed, stream, level, ix[i, j], iy[i, j], k[i, j])


@numba.njit(nogil=True, cache=True)
def _normal_rows(seed, stream, level, ix, iy, k, out, first, last):
    for i in range(first, last):
        for j in range(out.shape[1]):
            out[i, j] = normal_scalar(seed, stream, level, ix[i, j], iy[i, j], k[i, j])


#: Below this many deviates a call runs on the calling thread (a dispatch costs more).
_PARALLEL_FROM = 1 << 16


def _keyed(kernel, seed, stream, level, ix, iy, k):
    """Deviates of broadcast keys, read through the broadcast views (never materialised).

    The positions of an image are a row and a column (``cols[None, :]``, ``rows[:, None]``):
    broadcasting them to the image's shape and copying each (24 bytes a pixel) cost more
    than the hashing. The rows go to every core; each deviate depends only on its key, so
    the values are the same on any number of threads.
    """
    seed = check_seed(seed)
    keys = [np.asarray(a, dtype=np.int64) for a in (ix, iy, k)]
    shape = np.broadcast_shapes(*(a.shape for a in keys))
    out = np.empty(shape, dtype=np.float64)
    if out.size == 0:
        return out
    shape2 = (out.size, 1) if out.ndim < 2 else (-1, out.shape[-1])
    keys = [np.broadcast_to(a, shape).reshape(shape2) for a in keys]
    flat = out.reshape(shape2)
    rows = flat.shape[0]
    if out.size < _PARALLEL_FROM:
        kernel(seed, int(stream), int(level), *keys, flat, 0, rows)
    else:
        run_blocks(kernel, rows, seed, int(stream), int(level), *keys, flat)
    return out


def uniform(seed, stream, level, ix, iy, k=0):
    """Uniform (0, 1) deviates for broadcast integer positions ``ix, iy`` (float64 array)."""
    return _keyed(_uniform_rows, seed, stream, level, ix, iy, k)


def normal(seed, stream, level, ix, iy, k=0):
    """Return standard normal deviates for broadcast integer positions ``ix, iy`` (float64)."""
    return _keyed(_normal_rows, seed, stream, level, ix, iy, k)
