"""The camera sensor: exposure, point-spread function, shot and read noise, quantisation.

Rendering produces the reflectance factor I/F per pixel under a unit sun. The sensor turns it
into digital numbers:

1. Optical blur: a Gaussian point-spread function of ``psf_sigma`` pixels (0: none).
2. Exposure: ``DN = I/F * exposure * (2^bits - 1)``; an I/F of ``1 / exposure`` saturates.
3. Shot noise: with ``gain`` electrons per DN, a pixel collecting ``e = DN * gain`` electrons
   gets Gaussian noise of ``sqrt(e)`` electrons (the Poisson limit; exact to < 1 % above 25
   electrons). 0 switches it off.
4. Read noise: Gaussian, ``read_noise`` DN rms.
5. Rounding and clipping to ``bits`` (8 or 16).

Noise is keyed by ``(seed, "sensor-shot"/"sensor-read", frame index, column, row)``, so a
frame's noise does not depend on which other frames were rendered, and the same scenario and
seed give the same bytes.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from terrain.errors import InvalidParameterError
from terrain.rng import check_seed, normal, stream_id

__all__ = ["Sensor"]

STREAM_SHOT = stream_id("sensor-shot")
STREAM_READ = stream_id("sensor-read")


@dataclass(frozen=True)
class Sensor:
    """Sensor parameters (see the module docstring)."""

    bits: int = 8
    exposure: float = 5.0
    psf_sigma: float = 0.0
    gain: float = 0.0
    read_noise: float = 0.0
    seed: int = 0

    def __post_init__(self):
        if self.bits not in (8, 16):
            raise InvalidParameterError(f"sensor bits must be 8 or 16; got {self.bits}")
        for name in ("exposure", "psf_sigma", "gain", "read_noise"):
            v = float(getattr(self, name))
            if not (v >= 0 and math.isfinite(v)):
                raise InvalidParameterError(f"sensor {name} must be >= 0; got {v}")
            object.__setattr__(self, name, v)
        if self.exposure == 0:
            raise InvalidParameterError("sensor exposure must be positive")
        object.__setattr__(self, "seed", check_seed(self.seed))

    @property
    def full_scale(self) -> int:
        return 2**self.bits - 1

    def expose(self, radiance: np.ndarray, frame: int = 0) -> np.ndarray:
        """Digital image (uint8 or uint16) of an I/F image (NaN counts as black).

        >>> Sensor(exposure=2.0).expose(np.array([[0.25, 0.5, 1.0]])).tolist()
        [[128, 255, 255]]
        """
        import cv2

        x = np.nan_to_num(np.asarray(radiance, dtype=np.float64), nan=0.0)
        if self.psf_sigma > 0:
            x = cv2.GaussianBlur(x, (0, 0), self.psf_sigma, borderType=cv2.BORDER_REFLECT)
        dn = x * self.exposure * self.full_scale
        h, w = dn.shape
        if self.gain > 0 or self.read_noise > 0:
            cols = np.arange(w)[None, :]
            rows = np.arange(h)[:, None]
            if self.gain > 0:
                electrons = np.maximum(dn, 0.0) * self.gain
                dn = dn + np.sqrt(electrons) / self.gain * normal(
                    self.seed, STREAM_SHOT, frame, cols, rows)
            if self.read_noise > 0:
                dn = dn + self.read_noise * normal(self.seed, STREAM_READ, frame, cols, rows)
        out = np.clip(np.rint(dn), 0, self.full_scale)
        return out.astype(np.uint8 if self.bits == 8 else np.uint16)

    def as_dict(self) -> dict:
        return asdict(self)
