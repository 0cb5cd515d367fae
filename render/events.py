"""An event camera: per-pixel log-intensity changes as (x, y, t, polarity) events.

A dynamic vision sensor (DVS) pixel remembers the log intensity at its last event and emits an
event each time the log intensity has moved one contrast threshold away from it: ON (+1) up,
OFF (-1) down (Lichtsteiner et al. 2008, IEEE JSSC 43, 566). The simulator follows ESIM
(Rebecq et al. 2018, CoRL) and v2e (Hu et al. 2021, CVPR workshops):

- the scene is rendered at instants fine enough that no pixel's log intensity moves more than
  ``max_crossings`` thresholds between two of them (adaptive: a step that moves further is
  halved and rendered again, a quiet one grows by half, within ``[min_step, max_step]``),
  except for at most ``outlier_fraction`` of the pixels: a rasteriser's image has pixels
  that jump at any step, however short (a silhouette or a crater rim crossing a pixel centre,
  sub-pixel triangles at grazing view flickering between two surfaces), and held to every
  pixel the step shrank to ``min_step`` and stayed there (the benchmark's 0.1 s of motion took
  10,000 renders: 11 pixels of 512^2 moved more than a threshold in any 10 us, the largest
  almost two). Those pixels' crossings are timed by the same interpolation across the step,
  as a forced step's are;
- between two instants the log intensity is linear in time, so each threshold crossing gets
  its own timestamp by interpolation;
- thresholds ``contrast_on`` and ``contrast_off`` vary from pixel to pixel as
  ``C (1 + contrast_spread z)`` with z a fixed standard normal per pixel and polarity (keyed by
  the seed and the pixel, so a camera keeps its pattern), never below 1 % of C;
- after an event a pixel is blind for ``refractory`` seconds; a crossing in that time is not
  emitted and the remembered level stays, so the pixel fires once the period ends if the
  change persists;
- ``cutoff_hz`` (0: none) is the photoreceptor's first-order low-pass on log intensity (v2e),
  the pixel's bandwidth;
- ``leak_rate`` (Hz) drifts every remembered level down by ``leak_rate C`` per second, so a
  still pixel emits ON leak events at about that rate (v2e); ``noise_rate`` (Hz) adds shot-noise
  events of either polarity, Poisson per pixel and step;
- ``max_event_rate`` (events per second, 0: unlimited) is the readout's bandwidth: of the
  events of a step beyond ``max_event_rate x step``, the latest are dropped (counted in the
  statistics).

Log intensity is ``ln(I + log_eps)`` of the radiance a frame renders (I/F), ``log_eps`` keeping
black pixels finite.

Events are written as an ``.npz`` file in the layout of ESA's ELOPE challenge (event-based
lunar descents): ``x``, ``y`` (uint16, pixels from the top-left), ``t`` (int64 microseconds
since the sequence's start), ``p`` (int8, +1 ON, -1 OFF), plus ``width``, ``height`` and the
camera's settings as JSON in ``camera``.

Every random draw is keyed by (seed, stream, step, column, row), so the same scene, camera and
seed give the same events.

Examples
--------
>>> cam = EventCamera(contrast_on=0.25, contrast_off=0.25, contrast_spread=0.0)
>>> sim = EventSimulator(cam, (1, 2), seed=1)
>>> sim.reset(0.0, np.log(np.array([[1.0, 1.0]])))
>>> ev = sim.step(1.0, np.log(np.array([[np.e, 1.0]])))  # one pixel rises by 1.0 in log
>>> ev.p.tolist(), ev.x.tolist()
([1, 1, 1, 1], [0, 0, 0, 0])
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from dataclasses import asdict, dataclass, fields
from pathlib import Path

import numpy as np

from terrain.core.checks import check_keys, number
from terrain.core.errors import InvalidParameterError
from terrain.core.outputs import atomic_path
from terrain.core.rng import normal, stream_id, uniform

__all__ = ["EventCamera", "EventSimulator", "Events", "event_frame", "simulate", "write_events"]

STREAM_THRESHOLD = stream_id("event-threshold")
STREAM_NOISE = stream_id("event-noise")
STREAM_NOISE_SIGN = stream_id("event-noise-sign")

#: Thresholds never fall below this fraction of their nominal value.
MIN_THRESHOLD_FRACTION = 0.01


@dataclass(frozen=True)
class EventCamera:
    """The settings of an event camera (a ``[events]`` table).

    Parameters
    ----------
    contrast_on, contrast_off : float
        Log-intensity thresholds of ON and OFF events (typical DVS: 0.15-0.5).
    contrast_spread : float
        Standard deviation of the thresholds from pixel to pixel, as a fraction of them.
    refractory : float
        Seconds a pixel is blind after an event.
    cutoff_hz : float
        Photoreceptor bandwidth (first-order low-pass on log intensity), Hz; 0 for none.
    leak_rate : float
        Leak events per pixel per second.
    noise_rate : float
        Shot-noise events per pixel per second.
    max_event_rate : float
        Readout limit, events per second; 0 for none.
    max_crossings : float
        Most thresholds a pixel may cross between two rendered instants.
    min_step, max_step : float
        Bounds of the adaptive step between rendered instants, seconds.
    outlier_fraction : float
        Share of the pixels that may move more than ``max_crossings`` thresholds in a step
        (and that the step's growth disregards); 0 holds every pixel to it.
    log_eps : float
        Added to the intensity before its logarithm.
    """

    contrast_on: float = 0.2
    contrast_off: float = 0.2
    contrast_spread: float = 0.03
    refractory: float = 0.0
    cutoff_hz: float = 0.0
    leak_rate: float = 0.0
    noise_rate: float = 0.0
    max_event_rate: float = 0.0
    max_crossings: float = 2.0
    min_step: float = 1e-5
    max_step: float = 0.01
    #: 1e-4: 26 pixels of 512^2, 104 of 1024^2; the flicker measured on the benchmark's
    #: terrain at 512^2 was 11-17 pixels above half the limit at steps of 10-100 us
    outlier_fraction: float = 1e-4
    log_eps: float = 1e-3

    def __post_init__(self):
        where = "events"
        for f in fields(self):
            v = number(getattr(self, f.name), f.name, low=0.0, where=where)
            object.__setattr__(self, f.name, float(v))
        for name in ("contrast_on", "contrast_off", "max_crossings", "min_step", "max_step",
                     "log_eps"):
            if not getattr(self, name) > 0:
                raise InvalidParameterError(f"{where} {name} must be positive; got "
                                            f"{getattr(self, name)}")
        if self.outlier_fraction >= 1.0:
            raise InvalidParameterError(
                f"{where} outlier_fraction must be below 1; got {self.outlier_fraction}")
        if self.contrast_spread >= 1.0:
            raise InvalidParameterError(
                f"{where} contrast_spread must be below 1; got {self.contrast_spread}")
        if self.min_step > self.max_step:
            raise InvalidParameterError(
                f"{where} min_step ({self.min_step}) exceeds max_step ({self.max_step})")

    @classmethod
    def from_mapping(cls, mapping) -> EventCamera:
        """Build the camera from a table; an unknown key is refused naming the nearest.

        >>> EventCamera.from_mapping({"contrast": 0.2})  # doctest: +ELLIPSIS
        Traceback (most recent call last):
        ...
        terrain.core.errors.InvalidParameterError: unknown events key 'contrast' (did you ...
        """
        data = check_keys(mapping, [f.name for f in fields(cls)], "events")
        return cls(**data)

    def as_dict(self) -> dict:
        """Return the settings as plain data."""
        return asdict(self)


@dataclass
class Events:
    """Events in time order: ``x``, ``y`` (pixels), ``t`` (seconds), ``p`` (+1 or -1)."""

    x: np.ndarray
    y: np.ndarray
    t: np.ndarray
    p: np.ndarray

    @classmethod
    def empty(cls) -> Events:
        """Return no events."""
        return cls(np.zeros(0, np.uint16), np.zeros(0, np.uint16), np.zeros(0, np.float64),
                   np.zeros(0, np.int8))

    @classmethod
    def concatenate(cls, parts) -> Events:
        """Join event lists (each already in time order, one after another)."""
        parts = list(parts)
        if not parts:
            return cls.empty()
        return cls(*(np.concatenate([getattr(e, k) for e in parts]) for k in "xytp"))

    def __len__(self) -> int:
        return int(self.t.size)


class EventSimulator:
    """The per-pixel state of an event camera between rendered instants.

    Parameters
    ----------
    camera : EventCamera
    shape : (h, w)
        Image size.
    seed : int
        Keys the threshold pattern and the noise.
    """

    def __init__(self, camera: EventCamera, shape: tuple[int, int], seed: int = 0) -> None:
        self.camera = camera
        self.shape = (int(shape[0]), int(shape[1]))
        self.seed = int(seed)
        h, w = self.shape
        rows, cols = np.mgrid[0:h, 0:w]
        spread = camera.contrast_spread
        floor = MIN_THRESHOLD_FRACTION

        def pattern(k: int, c: float) -> np.ndarray:
            z = normal(self.seed, STREAM_THRESHOLD, 0, cols, rows, k)
            return c * np.maximum(1.0 + spread * z, floor)

        self.c_on = pattern(0, camera.contrast_on)
        self.c_off = pattern(1, camera.contrast_off)
        self.ref = np.zeros(self.shape)
        self.level = np.zeros(self.shape)
        self.last = np.full(self.shape, -np.inf)
        self.time = 0.0
        self.steps = 0
        self.dropped = 0
        self._cols, self._rows = cols, rows

    def reset(self, t: float, log_intensity: np.ndarray) -> None:
        """Start at time ``t`` with every pixel's remembered level at ``log_intensity``."""
        li = self._check(log_intensity)
        self.ref = li.copy()
        self.level = li.copy()
        self.last = np.full(self.shape, -np.inf)
        self.time = float(t)
        self.steps = 0

    def _check(self, li) -> np.ndarray:
        li = np.asarray(li, dtype=np.float64)
        if li.shape != self.shape:
            raise InvalidParameterError(f"log intensity has shape {li.shape}; the event "
                                        f"camera's is {self.shape}")
        return li

    def step(self, t: float, log_intensity: np.ndarray) -> Events:
        """Advance to time ``t`` where the log intensity is ``log_intensity``.

        Returns
        -------
        Events
            The events between the previous instant and ``t``, in time order.
        """
        cam = self.camera
        t0, t1 = self.time, float(t)
        dt = t1 - t0
        if not dt > 0:
            raise InvalidParameterError(f"event time must increase: {t1} after {t0}")
        new = self._check(log_intensity)
        if cam.cutoff_hz > 0:  # the photoreceptor's low-pass
            a = 1.0 - math.exp(-2.0 * math.pi * cam.cutoff_hz * dt)
            new = self.level + a * (new - self.level)
        if cam.leak_rate > 0:
            self.ref = self.ref - cam.leak_rate * self.c_on * dt
        old = self.level
        span = new - old
        xs, ys, ts, ps = [], [], [], []
        for sign, c in ((1, self.c_on), (-1, self.c_off)):
            active = (sign * (new - self.ref)) >= c
            k = 0
            while active.any():
                k += 1
                target = self.ref + sign * c
                with np.errstate(divide="ignore", invalid="ignore"):
                    frac = np.where(span != 0, (target - old) / span, 0.0)
                tk = t0 + np.clip(frac, 0.0, 1.0) * dt
                tk = np.maximum(tk, self.last + cam.refractory)
                fire = active & (tk <= t1)
                r, cidx = np.nonzero(fire)
                xs.append(cidx)
                ys.append(r)
                ts.append(tk[fire])
                ps.append(np.full(r.size, sign, np.int8))
                self.ref = np.where(fire, target, self.ref)
                self.last = np.where(fire, tk, self.last)
                active = fire & ((sign * (new - self.ref)) >= c)
        if cam.noise_rate > 0:
            lam = cam.noise_rate * dt
            u = uniform(self.seed, STREAM_NOISE, self.steps, self._cols, self._rows)
            hit = u < (1.0 - math.exp(-lam))  # at most one noise event per pixel and step
            r, cidx = np.nonzero(hit)
            when = uniform(self.seed, STREAM_NOISE, self.steps, cidx, r, 1)
            polarity = np.where(
                uniform(self.seed, STREAM_NOISE_SIGN, self.steps, cidx, r) < 0.5, -1, 1)
            xs.append(cidx)
            ys.append(r)
            ts.append(t0 + when * dt)
            ps.append(polarity.astype(np.int8))
        self.level = new
        self.time = t1
        self.steps += 1
        if not ts:
            return Events.empty()
        x, y, tt, p = (np.concatenate(a) for a in (xs, ys, ts, ps))
        order = np.lexsort((x, y, tt))
        x, y, tt, p = x[order], y[order], tt[order], p[order]
        if cam.max_event_rate > 0:
            cap = int(cam.max_event_rate * dt)
            if tt.size > cap:
                self.dropped += int(tt.size - cap)
                x, y, tt, p = x[:cap], y[:cap], tt[:cap], p[:cap]
        return Events(x.astype(np.uint16), y.astype(np.uint16), tt, p.astype(np.int8))


def simulate(render: Callable[[float], np.ndarray], t0: float, t1: float, camera: EventCamera,
             *, seed: int = 0) -> tuple[Events, dict]:
    """Render at adaptive instants from ``t0`` to ``t1`` and return the events.

    Parameters
    ----------
    render : callable
        ``render(t)`` gives the (h, w) intensity (I/F) at time ``t`` (seconds).
    t0, t1 : float
        The interval, seconds.
    camera : EventCamera
    seed : int

    Returns
    -------
    events : Events
    stats : dict
        ``instants`` rendered (accepted), ``rejected`` steps (rendered, then halved),
        ``forced`` steps accepted at ``min_step`` beyond the crossing limit (a discontinuity
        in time: an object appearing, a level of detail switching), ``dropped`` events
        (readout limit), ``largest_crossings`` between two instants.
    """
    cam = camera

    def log_of(t: float) -> np.ndarray:
        return np.log(np.asarray(render(t), dtype=np.float64) + cam.log_eps)

    first = log_of(t0)
    sim = EventSimulator(cam, first.shape, seed)
    sim.reset(t0, first)
    c_min = float(min(sim.c_on.min(), sim.c_off.min()))
    limit = cam.max_crossings * c_min
    allowed = min(int(cam.outlier_fraction * first.size), first.size - 1)
    t, dt = float(t0), cam.max_step
    prev = first
    parts, instants, rejected, forced, largest = [], 1, 0, 0, 0.0
    while t < t1:
        dt = min(dt, t1 - t)
        nxt = log_of(t + dt)
        # the step's change: the largest but the outlier_fraction of the pixels (a jump);
        # the largest of all is among those the partition puts above it
        kth = first.size - 1 - allowed
        moved = np.partition(np.abs(nxt - prev).ravel(), kth)
        change, most = float(moved[kth]), float(moved[kth:].max())
        if change > limit and dt > cam.min_step * 1.0000001:
            dt = max(dt / 2.0, cam.min_step)
            rejected += 1
            continue
        parts.append(sim.step(t + dt, nxt))
        instants += 1
        forced += int(change > limit)
        largest = max(largest, most / c_min)
        t += dt
        prev = nxt
        if change < 0.5 * limit:
            dt = min(dt * 1.5, cam.max_step)
    stats = dict(instants=instants, rejected=rejected, forced=forced, dropped=sim.dropped,
                 largest_crossings=largest, events=sum(len(p) for p in parts))
    return Events.concatenate(parts), stats


def write_events(path, events: Events, shape: tuple[int, int], camera: EventCamera,
                 **meta) -> Path:
    """Write events as an ELOPE-like ``.npz`` (atomically); times in microseconds.

    Returns
    -------
    pathlib.Path
        ``path``.
    """
    path = Path(path)
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as fh:
            np.savez_compressed(
                fh, x=events.x.astype(np.uint16), y=events.y.astype(np.uint16),
                t=np.round(events.t * 1e6).astype(np.int64), p=events.p.astype(np.int8),
                width=np.int64(shape[1]), height=np.int64(shape[0]),
                camera=np.array(json.dumps(dict(camera.as_dict(), **meta))))
    return path


def event_frame(events: Events, shape: tuple[int, int]) -> np.ndarray:
    """Return an RGB preview: ON events red, OFF events blue, brighter where more fired.

    >>> ev = Events(np.array([1], np.uint16), np.array([0], np.uint16), np.zeros(1),
    ...             np.array([1], np.int8))
    >>> event_frame(ev, (2, 2))[0, 1].tolist()
    [255, 0, 0]
    """
    h, w = shape
    on = np.zeros(shape, np.int64)
    off = np.zeros(shape, np.int64)
    pos = events.p > 0
    np.add.at(on, (events.y[pos].astype(np.int64), events.x[pos].astype(np.int64)), 1)
    np.add.at(off, (events.y[~pos].astype(np.int64), events.x[~pos].astype(np.int64)), 1)
    top = max(int(on.max(initial=0)), int(off.max(initial=0)), 1)
    img = np.zeros((h, w, 3), np.uint8)
    img[..., 0] = np.round(255.0 * np.sqrt(on / top))
    img[..., 2] = np.round(255.0 * np.sqrt(off / top))
    return img
