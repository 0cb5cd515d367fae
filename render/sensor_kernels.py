"""The sensor chain's per-pixel noise and quantisation, compiled, rows on every core.

:meth:`render.sensor.Sensor.digitise` draws shot noise, clips at the full well, adds read
noise and rounds to digital numbers. In numpy that was a dozen passes over the image, each a
temporary, on one core: about 45 ms of a 1024^2 frame, more than a GPU takes to render it
(docs/speed.md, "A frame on a GPU"). These kernels do the same arithmetic per pixel, in the
same order, with the same deviates (:func:`terrain.core.rng.uniform_scalar` and
:func:`~terrain.core.rng.normal_scalar` of the pixel's key) and the same inverse normal CDF
(SciPy's ``ndtri``, called through its exported C function), so the bytes are those of the
numpy expressions they replace::

    u = uniform(seed, shot_stream, frame, cols, rows)
    e = np.maximum(e + np.sqrt(e) * ndtri(u), 0)     # Gaussian shot noise, e >= exact_below
    e = np.minimum(e, well)
    e = e + read_e * normal(seed, read_stream, frame, cols, rows)
    out = np.clip(np.rint(e / gain + bias), 0, full_scale).astype(dtype)

Pixels below the exact-Poisson limit are left to the caller (:func:`render.sensor.
_poisson_inverse`, in numpy, as before).
"""

from __future__ import annotations

import functools
import math

import llvmlite.binding as llvm
import numba
import numpy as np
from numba import types
from numba.extending import get_cython_function_address

from terrain.core.parallel import run_blocks
from terrain.core.rng import normal_scalar, uniform_scalar

__all__ = ["quantise", "shot_gaussian"]

#: SciPy's inverse normal CDF, the function ``scipy.special.ndtri`` calls, by its C symbol
#: (registered under a name of ours, so compiled code cached on disk finds it again; on
#: first use, as importing SciPy's table of C functions takes a tenth of a second).
_NDTRI = "craterscape_scipy_special_ndtri"
_ndtri = types.ExternalFunction(_NDTRI, types.float64(types.float64))


@functools.cache
def _register_ndtri() -> None:
    llvm.add_symbol(_NDTRI, get_cython_function_address("scipy.special.cython_special", "ndtri"))


@numba.njit(nogil=True, cache=True)
def _shot_rows(e, seed, stream, frame, exact_below, out, first, last):
    for i in range(first, last):
        for j in range(e.shape[1]):
            x = e[i, j]
            if x < exact_below:
                out[i, j] = 0.0  # the caller's exact Poisson draw
                continue
            v = x + math.sqrt(x) * _ndtri(uniform_scalar(seed, stream, frame, j, i, 0))
            if v < 0.0:
                v = 0.0
            out[i, j] = v


@numba.njit(nogil=True, cache=True)
def _quantise_rows(e, well, read_e, seed, stream, frame, gain, bias, full_scale, out,
                   first, last):
    for i in range(first, last):
        for j in range(e.shape[1]):
            x = e[i, j]
            if x > well:
                x = well
            if read_e > 0.0:
                x = x + read_e * normal_scalar(seed, stream, frame, j, i, 0)
            r = np.rint(x / gain + bias)
            if r < 0.0:
                r = 0.0
            elif r > full_scale:
                r = full_scale
            out[i, j] = r


def shot_gaussian(e: np.ndarray, seed: int, stream: int, frame: int,
                  exact_below: float) -> np.ndarray:
    """Return Gaussian shot noise draws of mean ``e`` (float64), 0 where ``e < exact_below``."""
    _register_ndtri()
    e = np.ascontiguousarray(e, dtype=np.float64)
    out = np.empty_like(e)
    run_blocks(_shot_rows, e.shape[0], e, int(seed), int(stream), int(frame),
               float(exact_below), out)
    return out


def quantise(e: np.ndarray, well: float | None, read_e: float, seed: int, stream: int,
             frame: int, gain: float, bias: float, full_scale: int,
             dtype: type) -> np.ndarray:
    """Return the digital image of electrons ``e``: full well, read noise, gain, rounding."""
    e = np.ascontiguousarray(e, dtype=np.float64)
    out: np.ndarray = np.empty(e.shape, dtype=dtype)
    run_blocks(_quantise_rows, e.shape[0], e, math.inf if well is None else float(well),
               float(read_e), int(seed), int(stream), int(frame), float(gain), float(bias),
               float(full_scale), out)
    return out
