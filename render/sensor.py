"""The camera sensor: optics, a detector chain with data-sheet units, quantisation.

Rendering produces the reflectance factor I/F per pixel. The sensor turns it into digital
numbers the way a camera does, each step a ``[sensor]`` key with the unit of a data sheet:

1. Point-spread function on the optical image: a sum of Gaussians ``psf = [[weight, sigma
   (pixels)], ...]`` (weights normalised to 1) or a kernel file ``psf_kernel`` (.npy or text,
   normalised to 1; a regular file of at most 16 MiB and 1025 pixels a side, opened
   non-blocking); ``psf_sigma`` is the one-Gaussian shorthand. Every sigma is at most
   :data:`MAX_PSF_SIGMA` pixels.
2. Photons to electrons: the in-band radiance ``L = I/F F / pi`` (F: the solar spectral
   irradiance at the body, W m^-2 nm^-1, from the scenario's ``[sun]``) over ``bandwidth``
   (nm) enters an aperture of diameter ``aperture`` (m) from a pixel's solid angle
   ``1 / (fx fy)`` sr (intrinsics in pixels), or equivalently ``pi p^2 / (4 N^2)`` m^2 sr from
   ``f_number`` N and ``pixel_pitch`` p (um); ``transmission`` of the optics, quantum
   efficiency ``qe`` at ``wavelength`` (nm; photon energy h c / lambda) and ``exposure_time``
   (s) give the mean signal in electrons.
   ``natural_vignetting`` (off by default) scales pixels off the axis by cos^4 of their field
   angle (the projected aperture and pixel solid angle of an ideal thin lens).
   ``transfer_time`` (s, 0: none) adds frame-transfer smear: while a frame-transfer CCD shifts
   its image to the store, every pixel spends ``transfer_time / rows`` under each row of its
   column, collecting ``transfer_time / (rows exposure_time)`` of the column's summed signal.
3. Photo-response non-uniformity: the signal times ``1 + prnu z`` with z a fixed standard
   normal per pixel, keyed by the sensor's ``prnu_seed`` only (default: the scenario's seed),
   so the pattern is the same in every frame, and the same camera keeps its pattern across
   scenarios when ``prnu_seed`` is given.
4. Dark current ``dark_current`` (e-/s, as the data sheet gives it at ``dark_temperature``,
   default 20 C) times the exposure time joins the signal; at a detector ``temperature`` (C)
   it doubles every ``dark_doubling`` degrees (default 6.3 C, typical of silicon).
5. Shot noise (``shot_noise``, on by default): Poisson in electrons (exact below 30 e-,
   Gaussian sqrt(n) above it, where the two agree to better than 1 % in every moment).
6. Full well ``full_well`` (e-): a pixel holds at most this many electrons (0: whatever
   reaches the top DN).
7. Read noise ``read_noise`` (e- rms, Gaussian).
8. Gain and offset: ``DN = electrons / gain + bias`` (``gain`` e-/DN, ``bias`` DN), rounded
   and clipped to ``bits`` (1-16; 8-bit images are uint8, deeper ones uint16).

An I/F-calibrated sensor, given ``exposure`` (DN full scale per unit I/F), maps I/F straight
to electrons as ``I/F exposure (2^bits - 1) gain`` with ``gain`` in e-/DN switching shot noise
on (0: off, counted as 1 e-/DN) and ``read_noise`` in DN (bias 0, full well at the top DN;
``prnu``, ``full_well`` and ``bias`` may be added, while the optics and dark-current keys need
the physical chain). Giving ``exposure_time`` (and optics)
instead selects the physical chain; the two cannot be mixed.

Rolling shutter: ``line_time`` (s) delays each row's exposure by that much after the row above
(0: a global shutter); :mod:`render.motion` renders what moves during the exposures.

Auto-exposure (``auto_exposure = true``): before each frame is integrated, the controller
meters its optical image (after the PSF, vignetting and smear: the mean signal the detector
would collect) and finds the exposure (``exposure`` of an I/F-calibrated sensor, else
``exposure_time``) that places the ``ae_percentile`` percentile of the lit pixels (I/F above
``ae_threshold``) at ``ae_fraction`` of full scale (bias, gain and dark current accounted for;
exact for a chain linear in the exposure, i.e. all of it but frame-transfer smear). The
exposure in force then moves ``ae_rate`` of the way there, in logarithm, each frame
(``exposure *= (settled / exposure)^ae_rate``; 1: every frame settled), the first frame
settling at once; ``ae_max`` caps it (0: no cap but :data:`MAX_SENSOR_TIME`). A sequence
records each frame's exposure in its truth (:class:`ExposureControl`); the starting
``exposure`` or ``exposure_time`` only names the chain.

Every noise draw is keyed by ``(seed, stream, frame index, column, row)``, so a frame's noise
does not depend on which other frames were rendered, and the same scenario and seed give the
same bytes.
"""

from __future__ import annotations

import io
import math
import os
import stat
from dataclasses import asdict, dataclass, fields
from pathlib import Path

import numpy as np

from render.sensor_kernels import quantise, shot_gaussian
from terrain.core.checks import check_keys, number
from terrain.core.errors import InvalidParameterError, MissingInputError
from terrain.core.rng import check_seed, normal, stream_id, uniform

__all__ = ["PLANCK", "SPEED_OF_LIGHT", "ExposureControl", "Sensor"]

STREAM_SHOT = stream_id("sensor-shot")
STREAM_READ = stream_id("sensor-read")
STREAM_PRNU = stream_id("sensor-prnu")

#: Planck constant (J s) and speed of light (m/s), exact SI values (2019 redefinition).
PLANCK = 6.62607015e-34
SPEED_OF_LIGHT = 299_792_458.0
#: Below this many electrons shot noise is drawn from the exact Poisson distribution.
POISSON_EXACT_BELOW = 30.0
#: Widest Gaussian of a point-spread function (pixels): a blur of more than this is no longer
#: an image, and OpenCV's kernel size (8 sigma + 1) must stay a small integer.
MAX_PSF_SIGMA = 1000.0
#: Longest integration, row delay or transfer time (s). Flight navigation cameras integrate
#: for micro- to milliseconds and star trackers for at most seconds; an hour keeps every frame's
#: exposure span (rows x line time + integration) a finite, small multiple of the frame rate.
MAX_SENSOR_TIME = 3600.0
#: Largest kernel file read (bytes) and kernel side (pixels): a PSF kernel is a small table.
MAX_KERNEL_BYTES = 16 * 2**20
MAX_KERNEL_SIDE = 1025

_PHYSICAL = ("exposure_time", "aperture", "f_number", "pixel_pitch", "transmission", "qe",
             "wavelength", "bandwidth", "dark_current", "prnu", "full_well", "bias",
             "natural_vignetting", "transfer_time", "temperature", "dark_temperature",
             "dark_doubling")
#: Keys that only the physical chain uses (an I/F-calibrated sensor refuses them).
_PHYSICAL_ONLY = ("aperture", "f_number", "pixel_pitch", "transmission", "qe", "wavelength",
                  "bandwidth", "dark_current", "natural_vignetting", "transfer_time",
                  "temperature")


@dataclass(frozen=True)
class Sensor:
    """Sensor parameters (see the module docstring for every field and its unit).

    Built directly or by :meth:`from_mapping` (a scenario's ``[sensor]`` table or a server
    request), which rejects unknown keys by name.
    """

    bits: int = 8
    exposure: float = 5.0
    psf_sigma: float = 0.0
    gain: float = 0.0
    read_noise: float = 0.0
    seed: int = 0
    exposure_time: float = 0.0
    aperture: float = 0.0
    f_number: float = 0.0
    pixel_pitch: float = 0.0
    transmission: float = 1.0
    qe: float = 1.0
    wavelength: float = 643.0
    bandwidth: float = 1.0
    dark_current: float = 0.0
    prnu: float = 0.0
    shot_noise: bool = True
    full_well: float = 0.0
    bias: float = 0.0
    psf: tuple = ()
    psf_kernel: str | None = None
    line_time: float = 0.0
    natural_vignetting: bool = False
    transfer_time: float = 0.0
    temperature: float | None = None
    dark_temperature: float = 20.0
    dark_doubling: float = 6.3
    prnu_seed: int | None = None
    auto_exposure: bool = False
    ae_percentile: float = 99.0
    ae_fraction: float = 0.8
    ae_rate: float = 0.5
    ae_threshold: float = 0.0
    ae_max: float = 0.0

    def __post_init__(self):
        if isinstance(self.bits, bool) or not isinstance(self.bits, (int, np.integer)) \
                or not 1 <= int(self.bits) <= 16:
            raise InvalidParameterError(f"sensor bits must be an integer in [1, 16]; got "
                                        f"{self.bits!r}")
        object.__setattr__(self, "bits", int(self.bits))
        for name in ("exposure", "gain", "read_noise", "aperture", "f_number", "pixel_pitch",
                     "dark_current", "prnu", "full_well", "bias"):
            object.__setattr__(self, name, number(getattr(self, name), name, low=0.0,
                                                  where="sensor"))
        for name in ("exposure_time", "line_time", "transfer_time"):
            object.__setattr__(self, name, number(getattr(self, name), f"{name} (s)", low=0.0,
                                                  high=MAX_SENSOR_TIME, where="sensor"))
        object.__setattr__(self, "psf_sigma", number(self.psf_sigma, "psf_sigma", low=0.0,
                                                     high=MAX_PSF_SIGMA, where="sensor"))
        for name in ("transmission", "qe"):
            object.__setattr__(self, name, number(getattr(self, name), name, low=0.0,
                                                  high=1.0, low_open=True, where="sensor"))
        for name in ("wavelength", "bandwidth"):
            object.__setattr__(self, name, number(getattr(self, name), name, low=0.0,
                                                  low_open=True, where="sensor"))
        if self.temperature is not None:
            object.__setattr__(self, "temperature", number(self.temperature, "temperature",
                                                           low=-273.15, where="sensor"))
        object.__setattr__(self, "dark_temperature", number(
            self.dark_temperature, "dark_temperature", low=-273.15, where="sensor"))
        object.__setattr__(self, "dark_doubling", number(
            self.dark_doubling, "dark_doubling", low=0.0, low_open=True, where="sensor"))
        object.__setattr__(self, "ae_percentile", number(
            self.ae_percentile, "ae_percentile", low=0.0, high=100.0, low_open=True,
            where="sensor"))
        for name in ("ae_fraction", "ae_rate"):
            object.__setattr__(self, name, number(getattr(self, name), name, low=0.0, high=1.0,
                                                  low_open=True, where="sensor"))
        for name in ("ae_threshold", "ae_max"):
            object.__setattr__(self, name, number(getattr(self, name), name, low=0.0,
                                                  where="sensor"))
        for name in ("shot_noise", "natural_vignetting", "auto_exposure"):
            if not isinstance(getattr(self, name), (bool, np.bool_)):
                raise InvalidParameterError(
                    f"sensor {name} must be true or false; got {getattr(self, name)!r}")
            object.__setattr__(self, name, bool(getattr(self, name)))
        object.__setattr__(self, "seed", check_seed(self.seed))
        if self.prnu_seed is not None:
            object.__setattr__(self, "prnu_seed", check_seed(self.prnu_seed))
        if self.exposure == 0 and self.exposure_time == 0:
            raise InvalidParameterError(
                "sensor needs an exposure: exposure_time (s) for the physical chain, or "
                "exposure (DN full scale per unit I/F)")
        if self.exposure > 0 and self.exposure_time > 0:
            raise InvalidParameterError(
                "sensor takes exposure (I/F-calibrated) or exposure_time (physical), not both")
        if self.physical:
            if self.aperture == 0 and not (self.f_number > 0 and self.pixel_pitch > 0):
                raise InvalidParameterError(
                    "a physical sensor needs aperture (m) or f_number and pixel_pitch (um)")
            if self.gain == 0:
                raise InvalidParameterError("a physical sensor needs gain (e-/DN) > 0")
        if not self.physical:
            defaults = {f.name: f.default for f in fields(self)}
            stray = [k for k in _PHYSICAL_ONLY if getattr(self, k) != defaults[k]]
            if stray:
                raise InvalidParameterError(
                    f"sensor {', '.join(stray)} belong to the physical chain: give exposure_time "
                    f"(s) instead of exposure")
        if not isinstance(self.psf, (list, tuple)):
            raise InvalidParameterError(
                f"sensor psf must be a list of [weight, sigma_pixels] pairs; got {self.psf!r}")
        psf = []
        for term in self.psf:
            if np.shape(term) != (2,):
                raise InvalidParameterError(
                    f"sensor psf must be a list of [weight, sigma_pixels] pairs; got {term!r}")
            w = number(term[0], "psf weight", low=0.0, low_open=True, where="sensor")
            s = number(term[1], "psf sigma", low=0.0, high=MAX_PSF_SIGMA, where="sensor")
            psf.append((w, s))
        if self.psf_sigma > 0 and psf:
            raise InvalidParameterError("sensor takes psf_sigma or psf, not both")
        object.__setattr__(self, "psf", tuple(psf))
        if self.psf_kernel is not None:
            if psf or self.psf_sigma > 0:
                raise InvalidParameterError("sensor takes psf_kernel or a Gaussian psf, not both")
            object.__setattr__(self, "psf_kernel", str(self.psf_kernel))
            object.__setattr__(self, "_kernel", _load_kernel(self.psf_kernel))

    # ------------------------------------------------------------------ records
    @classmethod
    def from_mapping(cls, mapping, *, seed: int = 0, base: Path | None = None) -> Sensor:
        """Build a sensor from a ``[sensor]`` table; unknown keys are errors naming the nearest.

        ``base``: folder that a relative ``psf_kernel`` path is relative to.

        >>> Sensor.from_mapping({"exposure_time": 0.01, "aperture": 0.02, "gain": 4.0}).physical
        True
        """
        allowed = set(cls.__dataclass_fields__) - {"seed"}
        m = check_keys(mapping, allowed, "scenario [sensor]")
        if isinstance(m.get("psf"), (list, tuple)):
            m["psf"] = tuple(tuple(t) if isinstance(t, (list, tuple)) else t for t in m["psf"])
        if any(k in m for k in ("exposure_time", *_PHYSICAL)) and "exposure" not in m:
            m["exposure"] = 0.0
        if m.get("psf_kernel") is not None and base is not None:
            p = Path(m["psf_kernel"])
            m["psf_kernel"] = str(p if p.is_absolute() else base / p)
        return cls(seed=seed, **m)

    def as_dict(self) -> dict:
        """Return the sensor model as plain data for run manifests."""
        d = asdict(self)
        d["psf"] = [list(t) for t in self.psf]
        return d

    # ------------------------------------------------------------------ properties
    @property
    def physical(self) -> bool:
        """True for the data-sheet chain (``exposure_time``), False for I/F-calibrated."""
        return self.exposure == 0

    @property
    def kernel(self) -> np.ndarray | None:
        """The point-spread kernel read from ``psf_kernel`` when built, or None without one."""
        return self.__dict__.get("_kernel")

    @property
    def full_scale(self) -> int:
        """The largest digital number the sensor can output (2^bits - 1)."""
        return 2**self.bits - 1

    @property
    def rolling(self) -> bool:
        """Whether rows are exposed one after another (rolling shutter)."""
        return self.line_time > 0

    @property
    def integration_time(self) -> float:
        """Seconds each row integrates (the legacy mode has none: 0)."""
        return self.exposure_time if self.physical else 0.0

    @property
    def dark_rate(self) -> float:
        """Dark current (e-/s) at the detector's temperature."""
        if self.temperature is None:
            return self.dark_current
        return self.dark_current * 2.0 ** ((self.temperature - self.dark_temperature)
                                           / self.dark_doubling)

    def _gain(self) -> float:
        return self.gain if self.gain > 0 else 1.0

    def electrons_per_unit_if(self, intrinsics=None, spectral_irradiance: float = 1.58) -> float:
        """Mean signal electrons per unit I/F in one pixel (before PRNU, dark and noise).

        ``spectral_irradiance``: solar spectral irradiance at the body (W m^-2 nm^-1).
        Physical mode: ``F / pi * bandwidth * A Omega * transmission * qe * t / (h c /
        lambda)``; I/F-calibrated mode: ``exposure (2^bits - 1) gain``.
        """
        if not self.physical:
            return self.exposure * self.full_scale * self._gain()
        if self.aperture > 0:
            if intrinsics is None:
                raise InvalidParameterError(
                    "a sensor given by its aperture needs the camera intrinsics (fx, fy)")
            etendue = math.pi * self.aperture**2 / 4.0 / (intrinsics.fx * intrinsics.fy)
        else:
            etendue = math.pi * (self.pixel_pitch * 1e-6) ** 2 / (4.0 * self.f_number**2)
        photon = PLANCK * SPEED_OF_LIGHT / (self.wavelength * 1e-9)
        power = spectral_irradiance / math.pi * self.bandwidth * etendue * self.transmission
        return power / photon * self.qe * self.exposure_time

    def prnu_map(self, shape) -> np.ndarray:
        """(h, w) float64 gain factors ``1 + prnu z``, the same for every frame (seed only)."""
        h, w = shape
        if self.prnu == 0:
            return np.ones((h, w))
        seed = self.seed if self.prnu_seed is None else self.prnu_seed
        z = normal(seed, STREAM_PRNU, 0, np.arange(w)[None, :], np.arange(h)[:, None])
        return np.maximum(1.0 + self.prnu * z, 0.0)

    # ------------------------------------------------------------------ the chain
    def blur(self, image: np.ndarray) -> np.ndarray:
        """Return the optical image through the point-spread function (float64)."""
        import cv2

        x = np.asarray(image, dtype=np.float64)
        if self.psf_sigma > 0:
            return cv2.GaussianBlur(x, (0, 0), self.psf_sigma, borderType=cv2.BORDER_REFLECT)
        if self.psf:
            total = sum(w for w, _ in self.psf)
            out = np.zeros_like(x)
            for w, s in self.psf:
                part = x if s == 0 else cv2.GaussianBlur(x, (0, 0), s,
                                                         borderType=cv2.BORDER_REFLECT)
                out += (w / total) * part
            return out
        if self.kernel is not None:  # present exactly when psf_kernel is
            k = self.kernel
            # filter2D correlates; flipping the kernel makes it a convolution
            return cv2.filter2D(x, -1, k[::-1, ::-1].copy(), borderType=cv2.BORDER_REFLECT)
        return x

    def expose(self, radiance: np.ndarray, frame: int = 0, *, intrinsics=None,
               spectral_irradiance: float = 1.58) -> np.ndarray:
        """Digital image (uint8 for bits <= 8, else uint16) of an I/F image (NaN is black).

        ``intrinsics`` and ``spectral_irradiance`` (W m^-2 nm^-1 at the body) set the photon
        flux of a physical sensor; the I/F-calibrated mode ignores them.

        >>> Sensor(exposure=2.0).expose(np.array([[0.25, 0.5, 1.0]])).tolist()
        [[128, 255, 255]]
        """
        return self.digitise(self.signal(radiance, intrinsics=intrinsics,
                                         spectral_irradiance=spectral_irradiance), frame)

    def signal(self, radiance: np.ndarray, *, intrinsics=None,
               spectral_irradiance: float = 1.58) -> np.ndarray:
        """Mean signal electrons (steps 1-2 of the chain) of an I/F image (NaN is black).

        Parameters
        ----------
        radiance : (h, w) float
            I/F.
        intrinsics : render.camera.Intrinsics, optional
            A physical sensor's pixel solid angle and vignetting.
        spectral_irradiance : float
            W m^-2 nm^-1 at the body.

        Returns
        -------
        (h, w) float64
            Electrons, before PRNU, dark current and noise.
        """
        x = np.nan_to_num(np.asarray(radiance, dtype=np.float64), nan=0.0)
        x = self.blur(x)
        e = np.maximum(x, 0.0) * self.electrons_per_unit_if(intrinsics, spectral_irradiance)
        if self.physical and self.natural_vignetting:
            e = e * self.vignetting(e.shape, intrinsics)
        if self.physical and self.transfer_time > 0:
            e = e + self.transfer_time / (e.shape[0] * self.exposure_time) * e.sum(
                axis=0, keepdims=True)
        return e

    @property
    def exposure_value(self) -> float:
        """The exposure auto-exposure sets: ``exposure`` (I/F-calibrated) or ``exposure_time``."""
        return self.exposure_time if self.physical else self.exposure

    def with_exposure(self, value: float) -> Sensor:
        """Return the sensor with :attr:`exposure_value` set to ``value``."""
        from dataclasses import replace

        if self.physical:
            return replace(self, exposure_time=float(value))
        return replace(self, exposure=float(value))

    def metered(self, radiance: np.ndarray, *, intrinsics=None,
                spectral_irradiance: float = 1.58) -> float:
        """Return the exposure placing the lit pixels' percentile at the chosen fraction.

        Parameters
        ----------
        radiance : (h, w) float
            The frame's I/F.
        intrinsics, spectral_irradiance
            As :meth:`expose`.

        Returns
        -------
        float
            :attr:`exposure_value` placing the ``ae_percentile`` percentile of the mean DN of
            pixels whose I/F exceeds ``ae_threshold`` at ``ae_fraction`` of full scale (capped
            by ``ae_max``); the current exposure where no pixel is lit.
        """
        x = np.asarray(radiance, dtype=np.float64)
        lit = np.isfinite(x) & (x > self.ae_threshold)
        now = self.exposure_value
        if not lit.any():
            return now
        e = self.signal(x, intrinsics=intrinsics, spectral_irradiance=spectral_irradiance)
        p = float(np.percentile(e[lit], self.ae_percentile))
        want = (self.ae_fraction * self.full_scale - self.bias) * self._gain()  # electrons
        if self.physical:  # signal and dark current both grow with the time
            rate = p / self.exposure_time + self.dark_rate
            value = want / rate if rate > 0 else now
            cap = min(self.ae_max or MAX_SENSOR_TIME, MAX_SENSOR_TIME)
        else:
            value = now * want / p if p > 0 else now
            cap = self.ae_max or math.inf
        return float(min(max(value, 0.0), cap)) if value > 0 else now

    def vignetting(self, shape, intrinsics=None) -> np.ndarray:
        """(h, w) cos^4 of each pixel's field angle (needs the intrinsics)."""
        if intrinsics is None:
            raise InvalidParameterError("natural vignetting needs the camera intrinsics")
        h, w = shape
        k = intrinsics
        x = (np.arange(w)[None, :] - k.cx) / k.fx
        y = (np.arange(h)[:, None] - k.cy) / k.fy
        return 1.0 / (1.0 + x * x + y * y) ** 2

    def digitise(self, electrons: np.ndarray, frame: int = 0) -> np.ndarray:
        """Apply steps 3-8 of the chain on a mean-signal image in electrons."""
        e = np.asarray(electrons, dtype=np.float64)
        h, w = e.shape
        if self.prnu > 0:
            e = e * self.prnu_map((h, w))
        if self.physical:
            e = e + self.dark_rate * self.exposure_time
        shot = self.shot_noise and (self.physical or self.gain > 0)
        if shot:
            e = self._shot(e, frame)
        gain = self._gain()
        well = self.full_well if self.full_well > 0 else None
        read_e = self.read_noise * (gain if not self.physical else 1.0)
        return quantise(e, well, read_e, check_seed(self.seed), STREAM_READ, frame, gain,
                        self.bias, self.full_scale, np.uint8 if self.bits <= 8 else np.uint16)

    def _shot(self, e, frame):
        """Draw Poisson electrons of mean ``e``.

        Exact below :data:`POISSON_EXACT_BELOW`, else Gaussian; one keyed uniform per pixel
        either way (:mod:`render.sensor_kernels`).
        """
        out = shot_gaussian(e, check_seed(self.seed), STREAM_SHOT, frame, POISSON_EXACT_BELOW)
        rows, cols = np.nonzero(e < POISSON_EXACT_BELOW)
        if rows.size:
            out[rows, cols] = _poisson_inverse(uniform(self.seed, STREAM_SHOT, frame, cols, rows),
                                               e[rows, cols])
        return out


class ExposureControl:
    """A camera's auto-exposure loop over a sequence of frames (see the module docstring).

    Parameters
    ----------
    sensor : Sensor
        The sensor (``auto_exposure`` on; off, :meth:`expose` exposes as the sensor is).
    value : float, optional
        The exposure in force before the next frame; None settles the next frame at once.

    Examples
    --------
    >>> ctl = ExposureControl(Sensor(exposure=1.0, auto_exposure=True, ae_fraction=0.5,
    ...                              ae_percentile=100.0, ae_rate=0.5))
    >>> image, record = ctl.expose(np.full((2, 2), 0.25))
    >>> int(image.max()), record["exposure"]
    (128, 2.0)
    """

    def __init__(self, sensor: Sensor, value: float | None = None):
        self.sensor = sensor
        self.value = None if value is None else float(value)

    def expose(self, radiance: np.ndarray, frame: int = 0, *, intrinsics=None,
               spectral_irradiance: float = 1.58) -> tuple[np.ndarray, dict | None]:
        """Meter the frame, set the exposure, digitise.

        Parameters
        ----------
        radiance : (h, w) float
            The frame's I/F.
        frame : int
            The frame index (keys the noise).
        intrinsics, spectral_irradiance
            As :meth:`Sensor.expose`.

        Returns
        -------
        image : (h, w) uint8 or uint16
            The digital image.
        record : dict or None
            The frame's exposure for its truth: ``auto``, ``exposure`` (or
            ``exposure_time``), ``settled`` (the value that would place the percentile
            exactly), ``percentile``, ``fraction``, ``rate``; None without auto-exposure.
        """
        s = self.sensor
        if not s.auto_exposure:
            return s.expose(radiance, frame, intrinsics=intrinsics,
                            spectral_irradiance=spectral_irradiance), None
        if self.value is not None:
            s = s.with_exposure(self.value)
        settled = s.metered(radiance, intrinsics=intrinsics,
                            spectral_irradiance=spectral_irradiance)
        value = settled if self.value is None else \
            self.value * (settled / self.value) ** s.ae_rate
        self.value = value
        s = s.with_exposure(value)
        image = s.expose(radiance, frame, intrinsics=intrinsics,
                         spectral_irradiance=spectral_irradiance)
        key = "exposure_time" if s.physical else "exposure"
        return image, {"auto": True, key: value, "settled": settled,
                       "percentile": s.ae_percentile, "fraction": s.ae_fraction,
                       "rate": s.ae_rate}


def _poisson_inverse(u: np.ndarray, lam: np.ndarray) -> np.ndarray:
    """Return the smallest k with P(K <= k) >= u for Poisson means ``lam`` < 30.

    Inverse transform, summing the probability mass term by term; exact up to float64
    rounding. The values already found are dropped from the sums whenever they are half of
    those left (every value's terms are summed in the same order either way).
    """
    p = np.exp(-lam)
    cdf = p.copy()
    k = np.zeros_like(lam)
    todo = u > cdf
    at = np.flatnonzero(todo)  # where in k the values summed below go
    u, lam, p, cdf = u[todo], lam[todo], p[todo], cdf[todo]
    found = np.zeros_like(lam)  # terms each value has added: its k once found
    todo = np.ones(at.size, dtype=bool)
    left = at.size
    n = 0
    while left and n < 200:
        n += 1
        p *= lam
        p /= n
        cdf += p
        found += todo
        todo &= u > cdf
        left = int(np.count_nonzero(todo))
        if left <= todo.size // 2:
            k.flat[at] = found
            at, u, lam, p, cdf, found = (a[todo] for a in (at, u, lam, p, cdf, found))
            todo = np.ones(left, dtype=bool)
    k.flat[at] = found
    return k


def _load_kernel(path: str) -> np.ndarray:
    """Read a PSF kernel file (.npy, or a text table of numbers), normalised to sum 1.

    Only a regular file is opened (checked before opening, and again on the open file), and
    opened non-blocking, so a FIFO or a device named as a kernel is refused at once instead
    of stalling the reader. Errors name the file, never its content.
    """
    p = Path(path)
    try:
        st = os.stat(p)
    except (OSError, ValueError):
        raise MissingInputError(f"PSF kernel file '{p}' does not exist") from None
    if not stat.S_ISREG(st.st_mode):
        raise InvalidParameterError(f"PSF kernel '{p}' is not a regular file")
    if st.st_size > MAX_KERNEL_BYTES:
        raise InvalidParameterError(f"PSF kernel file '{p}' is larger than "
                                    f"{MAX_KERNEL_BYTES // 2**20} MiB")
    try:
        fd = os.open(p, os.O_RDONLY | os.O_NONBLOCK)
    except OSError as exc:
        raise MissingInputError(f"cannot read PSF kernel file '{p}': "
                                f"{exc.strerror or 'unreadable'}") from None
    try:
        if not stat.S_ISREG(os.fstat(fd).st_mode):  # replaced after the check above
            raise InvalidParameterError(f"PSF kernel '{p}' is not a regular file")
        with os.fdopen(fd, "rb", closefd=False) as f:
            data = f.read(MAX_KERNEL_BYTES + 1)
    except OSError as exc:
        raise MissingInputError(f"cannot read PSF kernel file '{p}': "
                                f"{exc.strerror or 'unreadable'}") from None
    finally:
        os.close(fd)
    if len(data) > MAX_KERNEL_BYTES:
        raise InvalidParameterError(f"PSF kernel file '{p}' is larger than "
                                    f"{MAX_KERNEL_BYTES // 2**20} MiB")
    try:
        if p.suffix == ".npy":
            k = np.load(io.BytesIO(data), allow_pickle=False)
        else:
            k = np.loadtxt(io.StringIO(data.decode("utf-8")), delimiter=None)
        k = np.atleast_2d(np.asarray(k, dtype=np.float64))
    except (ValueError, TypeError, EOFError, OSError):  # their messages quote the content
        raise InvalidParameterError(
            f"PSF kernel file '{p}' is not a numeric table (.npy, or rows of numbers)") \
            from None
    if k.ndim != 2 or not np.all(np.isfinite(k)) or k.sum() <= 0 or k.min() < 0:
        raise InvalidParameterError(
            f"PSF kernel '{p}' must be a 2-D table of finite values >= 0 with a positive sum")
    if max(k.shape) > MAX_KERNEL_SIDE:
        raise InvalidParameterError(f"PSF kernel '{p}' is {k.shape[1]}x{k.shape[0]}; at most "
                                    f"{MAX_KERNEL_SIDE} a side")
    return k / k.sum()
