r"""Perlin-noise asteroid bases: 3-D gradient noise sampled on the unit sphere (section IV.B).

"A three-dimensional Perlin noise function with ten octaves was implemented and sampled on
the surface of a normalized sphere to obtain displacement values [...] Standard parameters
that control the form of terrain generated are the number of summed noise functions
(octaves), the frequency of the lowest frequency band (frequency), the amplitude drop with
frequency band (persistence) and the frequency multiplier between successive bands
(lacunarity). Further control can be obtained by customizing the frequency and amplitude
changes between specific frequency bands." (Martin et al. 2014, section IV.B)

The noise
---------
Perlin's improved noise (Perlin 2002): pseudo-random gradients at the integer lattice,
dotted with the offset to each of the eight cell corners and blended with the quintic
``f(t) = 6t^5 - 15t^4 + 10t^3`` (the paper's second blending function; its first, the cubic
``3t^2 - 2t^3``, has a discontinuous second derivative that shows as creases in shading).
The gradient at lattice point (i, j, k) of octave o is one of Perlin's twelve cube-edge
vectors, picked by the top four bits of the key ``(seed, "perlin", o, i, j * 2^32 + k)``
(:mod:`terrain.core.rng`), instead of Perlin's permutation table: the value at a point depends on
nothing but the point and the seed, so any subset of vertices gets exactly the values of the
whole body, bitwise, and the noise never repeats (a 256-entry table repeats every 256 cells).

The body
--------
Band o has frequency ``f_o = frequency * lacunarity^o`` (lattice cells per body radius) and
amplitude ``a_o = amplitude * persistence^o`` (a fraction of the reference radius R), unless
a :class:`Band` overrides either; the radius along direction u is

    r(u) = R (1 + sum_o a_o noise(f_o u))

Improved Perlin noise stays within about +-1 (three dimensions; Perlin 2002), so the radius
stays positive while ``sum a_o`` is below 1; a body whose radius would reach zero anywhere is
refused.

Presets
-------
The paper's Fig. 5 shows three ten-octave bases "with varying standard noise parameters"
without printing their values. :data:`FIG5_PRESETS` are our reconstructions of the three looks
it describes, documented here rather than claimed as the paper's numbers:
``fig5-smooth`` (a gently lumpy body: frequency 1, persistence 0.40), ``fig5-lumpy`` (lumpier at
middle scales: persistence 0.50, lacunarity 2.1) and ``fig5-rugged`` (a strongly irregular
body with a boosted second band and a rough surface: persistence 0.55, band 1 amplitude
0.12).

Examples
--------
>>> from asteroid.sphere import SphereMesh
>>> mesh = SphereMesh(16)
>>> noise = PerlinNoise(octaves=4, amplitude=0.2)
>>> whole = noise.radii(mesh, 1000.0, seed=5)
>>> part = noise.radii(mesh, 1000.0, seed=5, vertices=np.array([7, 300, 1200]))
>>> bool(np.array_equal(whole[[7, 300, 1200]], part))
True
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

import numba
import numpy as np

from asteroid.body import Stretch
from asteroid.sphere import SphereMesh, unit_vertex
from terrain.core import memory
from terrain.core.checks import integer, number
from terrain.core.errors import InvalidParameterError
from terrain.core.rng import check_seed, hash_at, key_prefix, stream_id

__all__ = ["FIG5_PRESETS", "MAX_FREQUENCY", "Band", "PerlinNoise", "perlin3"]

STREAM_PERLIN = stream_id("asteroid-perlin")
#: Highest band frequency: lattice coordinates of the unit sphere must fit 31 bits for the
#: (j, k) packing of the gradient key.
MAX_FREQUENCY = 2.0**30
#: Bytes per vertex the Perlin base holds (index, radius and the output copy).
_BYTES_PER_VERTEX = 32
_SHIFT = np.uint64(60)
_MASK = np.int64(0xFFFFFFFF)


@numba.njit(cache=True, inline="always")
def _fade(t):
    return t * t * t * (t * (t * 6.0 - 15.0) + 10.0)


@numba.njit(cache=True, inline="always")
def _grad(prefix, i, j, k, x, y, z):
    """Dot product of lattice point (i, j, k)'s gradient with the offset (x, y, z)."""
    h = int(hash_at(prefix, i, (j << 32) | (k & _MASK)) >> _SHIFT)
    u = x if h < 8 else y
    if h < 4:
        v = y
    elif h == 12 or h == 14:
        v = x
    else:
        v = z
    return (u if (h & 1) == 0 else -u) + (v if (h & 2) == 0 else -v)


@numba.njit(cache=True)
def perlin3(prefix, x, y, z):
    """Improved Perlin noise at (x, y, z) with gradients from the key ``prefix``."""
    fx = math.floor(x)
    fy = math.floor(y)
    fz = math.floor(z)
    i = np.int64(fx)
    j = np.int64(fy)
    k = np.int64(fz)
    x -= fx
    y -= fy
    z -= fz
    u = _fade(x)
    v = _fade(y)
    w = _fade(z)
    x1 = x - 1.0
    y1 = y - 1.0
    z1 = z - 1.0
    a0 = _grad(prefix, i, j, k, x, y, z)
    a1 = _grad(prefix, i + 1, j, k, x1, y, z)
    b0 = _grad(prefix, i, j + 1, k, x, y1, z)
    b1 = _grad(prefix, i + 1, j + 1, k, x1, y1, z)
    c0 = _grad(prefix, i, j, k + 1, x, y, z1)
    c1 = _grad(prefix, i + 1, j, k + 1, x1, y, z1)
    d0 = _grad(prefix, i, j + 1, k + 1, x, y1, z1)
    d1 = _grad(prefix, i + 1, j + 1, k + 1, x1, y1, z1)
    e0 = a0 + u * (a1 - a0)
    e1 = b0 + u * (b1 - b0)
    f0 = c0 + u * (c1 - c0)
    f1 = d0 + u * (d1 - d0)
    g0 = e0 + v * (e1 - e0)
    g1 = f0 + v * (f1 - f0)
    return g0 + w * (g1 - g0)


@numba.njit(cache=True, parallel=True)
def _radii(m, idx, prefixes, freqs, amps, inv_stretch, stretched, radius, out):
    for n in numba.prange(idx.size):
        sx, sy, sz = unit_vertex(m, idx[n])
        length = 1.0
        if stretched:
            # the stretched body's radius along u is r0(u0) / |S^-1 u| (asteroid.body.Stretch)
            sx *= inv_stretch[0]
            sy *= inv_stretch[1]
            sz *= inv_stretch[2]
            length = math.sqrt(sx * sx + sy * sy + sz * sz)
            sx /= length
            sy /= length
            sz /= length
        total = 0.0
        for o in range(freqs.size):
            f = freqs[o]
            total += amps[o] * perlin3(prefixes[o], sx * f, sy * f, sz * f)
        out[n] = radius * (1.0 + total) / length


@dataclass(frozen=True)
class Band:
    """Override of one octave's frequency and/or amplitude (None keeps the standard value).

    Parameters
    ----------
    octave : int
        0-based band index.
    frequency : float, optional
        Lattice cells per body radius.
    amplitude : float, optional
        Fraction of the reference radius.
    """

    octave: int
    frequency: float | None = None
    amplitude: float | None = None

    def __post_init__(self):
        if isinstance(self.octave, bool) or not isinstance(self.octave, (int, np.integer)) \
                or self.octave < 0:
            raise InvalidParameterError(f"band octave must be an integer >= 0; got {self.octave!r}")
        object.__setattr__(self, "octave", int(self.octave))
        if self.frequency is not None:
            f = float(self.frequency)
            if not (0 < f <= MAX_FREQUENCY):
                raise InvalidParameterError(
                    f"band {self.octave} frequency must lie in (0, 2^30]; got {f}")
            object.__setattr__(self, "frequency", f)
        if self.amplitude is not None:
            a = float(self.amplitude)
            if not (a >= 0 and math.isfinite(a)):
                raise InvalidParameterError(
                    f"band {self.octave} amplitude must be >= 0; got {a}")
            object.__setattr__(self, "amplitude", a)


@dataclass(frozen=True)
class PerlinNoise:
    """Fractal sum of 3-D Perlin noise bands on the unit sphere.

    Parameters
    ----------
    octaves : int
        Number of bands (>= 1; the paper used 10).
    frequency : float
        Lowest band's frequency, lattice cells per body radius (> 0).
    persistence : float
        Amplitude ratio between successive bands, in (0, 1].
    lacunarity : float
        Frequency ratio between successive bands (> 1).
    amplitude : float
        Lowest band's amplitude as a fraction of the reference radius (>= 0).
    bands : tuple of Band
        Per-band overrides.
    """

    octaves: int = 10
    frequency: float = 1.0
    persistence: float = 0.5
    lacunarity: float = 2.0
    amplitude: float = 0.25
    bands: tuple = field(default_factory=tuple)

    def __post_init__(self):
        object.__setattr__(self, "octaves", integer(self.octaves, "octaves", low=1, high=30,
                                                    where="perlin"))
        bounds = {"frequency": dict(low=0, low_open=True, high=MAX_FREQUENCY),
                  "persistence": dict(low=0, low_open=True, high=1),
                  "lacunarity": dict(low=1, low_open=True, high=16),
                  "amplitude": dict(low=0, high=1, high_open=True)}
        for name, bound in bounds.items():
            object.__setattr__(self, name, number(getattr(self, name), name, where="perlin",
                                                  **bound))
        bands = tuple(b if isinstance(b, Band) else Band(**b) for b in self.bands)
        seen = set()
        for b in bands:
            if b.octave >= self.octaves:
                raise InvalidParameterError(
                    f"band override for octave {b.octave} but there are only {self.octaves} "
                    "octaves (0-based)")
            if b.octave in seen:
                raise InvalidParameterError(f"two overrides for band {b.octave}")
            seen.add(b.octave)
        object.__setattr__(self, "bands", tuple(sorted(bands, key=lambda b: b.octave)))
        if self.band_frequencies().max() > MAX_FREQUENCY:
            raise InvalidParameterError(
                f"the highest band frequency {self.band_frequencies().max():.3g} exceeds 2^30; "
                "use fewer octaves or a smaller lacunarity")

    def band_frequencies(self) -> np.ndarray:
        """(octaves,) float64: lattice cells per body radius of each band."""
        f = self.frequency * self.lacunarity ** np.arange(self.octaves)
        for b in self.bands:
            if b.frequency is not None:
                f[b.octave] = b.frequency
        return f

    def band_amplitudes(self) -> np.ndarray:
        """(octaves,) float64: amplitude of each band as a fraction of R."""
        a = self.amplitude * self.persistence ** np.arange(self.octaves)
        for b in self.bands:
            if b.amplitude is not None:
                a[b.octave] = b.amplitude
        return a

    def as_dict(self) -> dict:
        """Return the parameters as plain data (bands as a list of tables) for metadata."""
        d = asdict(self)
        d["bands"] = [asdict(b) for b in self.bands]
        return d

    def radii(self, mesh: SphereMesh, radius: float, *, seed: int,
              stretch: Stretch | None = None, vertices=None) -> np.ndarray:
        """Vertex radii (metres) of the Perlin body.

        Parameters
        ----------
        mesh : SphereMesh
        radius : float
            Reference radius R, metres.
        seed : int
        stretch : Stretch, optional
            Affine stretch of the body.
        vertices : (n,) int, optional
            Flat vertex indices to evaluate (default all); values equal the whole body's.

        Returns
        -------
        (n,) float64, metres
        """
        seed = check_seed(seed)
        radius = float(radius)
        if not (radius > 0 and math.isfinite(radius)):
            raise InvalidParameterError(f"radius must be positive metres; got {radius}")
        stretch = stretch or Stretch()
        if vertices is None:
            memory.require(mesh.n_vertices * _BYTES_PER_VERTEX,
                           f"a Perlin base of {mesh.n_vertices:,} vertices")
            idx = np.arange(mesh.n_vertices, dtype=np.int64)
        else:
            idx = np.ascontiguousarray(vertices, dtype=np.int64).reshape(-1)
            if idx.size and (idx.min() < 0 or idx.max() >= mesh.n_vertices):
                raise InvalidParameterError(
                    f"vertex indices must lie in [0, {mesh.n_vertices})")
        prefixes = np.array([key_prefix(seed, STREAM_PERLIN, o, 0) for o in range(self.octaves)],
                            dtype=np.uint64)
        out = np.empty(idx.size)
        _radii(mesh.magnitude, idx, prefixes, self.band_frequencies(), self.band_amplitudes(),
               1.0 / stretch.factors, not stretch.is_identity, radius, out)
        bad = ~(out > 0)
        if bad.any():
            raise InvalidParameterError(
                f"the Perlin amplitudes (sum {self.band_amplitudes().sum():.3g} of the radius) "
                f"make the radius reach zero at {int(bad.sum())} vertices; lower the amplitude")
        return out


#: Reconstructions of the three Fig. 5 bases (ten octaves each; see the module docstring).
FIG5_PRESETS = {
    "fig5-smooth": PerlinNoise(octaves=10, frequency=1.0, persistence=0.40, lacunarity=2.0,
                               amplitude=0.22),
    "fig5-lumpy": PerlinNoise(octaves=10, frequency=1.2, persistence=0.50, lacunarity=2.1,
                              amplitude=0.25),
    "fig5-rugged": PerlinNoise(octaves=10, frequency=0.9, persistence=0.55, lacunarity=2.0,
                               amplitude=0.22, bands=(Band(1, amplitude=0.12),)),
}
