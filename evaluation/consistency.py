r"""Frame-to-frame consistency of a rendered run, measured through its own truth.

A renderer that is consistent with itself shows the same surface point with the same
brightness in consecutive frames (up to the sensor's noise and the slow change of the viewing
geometry). Level-of-detail switches, layers switching on and shadow maps that move with the
camera break that: the shading under a feature jumps between two frames, and a tracker reads
the jump as motion. This module measures it, pair by pair.

Warp (:func:`pair_residual`)
----------------------------
For consecutive frames t and t+1, every pixel of frame t with a range return is lifted to
3-D with frame t's range image and pose (:meth:`render.camera.Pose.unproject`), carried into
the body frame with frame t's ``body_rotation`` R_WB and back into the world with frame
t+1's (identity for terrain), and projected into frame t+1. Frame t+1's image, sampled there
bilinearly, is frame t+1 warped into frame t; the residual is frame t minus it, in DN.

Masks: a pixel counts only when

* it is *seen in both*: frame t+1's range at the projection agrees with the point's distance
  from frame t+1's camera within ``occlusion_tolerance`` (relative), and the projection lies
  inside frame t+1;
* it is away from *silhouettes and occlusion edges*: more than ``edge_px`` pixels from a
  pixel without return or from a relative range jump above :data:`SILHOUETTE_JUMP`, in
  frame t and (through the warp) in frame t+1; there, the surface behind an outline slides
  against it and no warp can match the two frames;
* it is *lit in both*: its surface faces the sun in both frames (the normal images), and it
  is not dark (at most :data:`DARK_SIGMAS` noise levels above black) in both. A pixel that is
  lit in one frame and dark in the other stays in: on a fixed surface under a fixed sun, a
  shadow edge must not move, so one that does is an inconsistency to see;
* it is not next to a *shadow edge that moves*: where the sun turns in the body frame
  between the two frames (a spinning asteroid), shadows legitimately move, and pixels within
  ``edge_px`` of a dark pixel in either frame are dropped.

Noise: the run's manifest records the sensor (:class:`render.sensor.Sensor`); a pixel of
``DN`` digital numbers carries shot noise of variance ``DN / gain``, read noise
``read_noise^2`` and rounding ``1/12`` (DN^2). ``noise_dn`` is the rms of one frame's noise
over the counted pixels; ``noise_floor_dn`` is the rms the residual of two frames that agree
perfectly would have: frame t's noise plus frame t+1's, averaged by the bilinear sampling
(the squared weights), and ``excess_dn = sqrt(rms^2 - floor^2)`` what is left beyond the
noise. That excess holds the change of the viewing
geometry (the reflectance depends on the emission and phase angles), resampling of texture
finer than a pixel, and the renderer's own inconsistency.

Per frame, the residual's rms, mean and the counted fraction are reported; the run's
figure of merit is ``spike_ratio``, the largest per-frame rms over the median (at most
:data:`SPIKE_BOUND`): a level-of-detail switch or a layer switching on shows as a spike at its
frame. Frames where the drawn layers or the levels of detail change are marked, from each
frame's truth ``drawn`` record (:func:`change_marks`).
"""

from __future__ import annotations

import json
import logging
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from evaluation.silhouette import SILHOUETTE_JUMP, dilate, near_contours
from render.camera import quat_to_matrix
from render.rundir import RunReader
from terrain.core.errors import InvalidParameterError

__all__ = ["DARK_SIGMAS", "SAMPLED_PIXELS", "SILHOUETTE_JUMP", "SPIKE_BOUND", "Consistency",
           "PairResidual", "camera_affine", "camera_map", "change_marks", "consistency",
           "pair_residual", "sampling_stride", "save_consistency"]

log = logging.getLogger(__name__)

#: A pixel at most this many noise levels (read and rounding noise) above black is dark.
DARK_SIGMAS = 4.0
#: Acceptance bound: the largest per-frame rms at most this many times the median.
SPIKE_BOUND = 1.5
#: Sun directions (in the body frame) closer than this (radians) count as the same sun.
SUN_STILL_RAD = 1e-7
#: Side (pixels) of the tiles of :attr:`PairResidual.worst_tile_dn`.
TILE = 32
#: Pixels per frame a sampled measurement keeps at least (:func:`sampling_stride`): at
#: 2^18, a frame's rms moves by about 0.4 % and its worst tile by about 2 % against every
#: pixel (docs/speed.md, "Sampled consistency").
SAMPLED_PIXELS = 2**18


@dataclass(frozen=True, eq=False)
class PairResidual:
    """The residual of one pair of frames (t, t+1), warped into frame t.

    Parameters
    ----------
    residual : (h, w) float32, DN
        Frame t minus frame t+1 warped into frame t; NaN outside ``mask``.
    mask : (h, w) bool
        Pixels counted (module docstring).
    rms_dn, mean_dn : float
        Over ``mask`` (NaN when empty).
    noise_dn : float or None
        The rms of one frame's sensor noise over ``mask`` (None without a sensor record).
    fraction : float
        Counted pixels over all pixels.
    noise_floor_dn : float or None
        The rms the residual would have from the sensor noise alone: frame t's noise plus
        frame t+1's, averaged by the bilinear sampling.
    worst_tile_dn : float or None
        The largest residual rms over :data:`TILE` x :data:`TILE` pixel tiles at least half
        counted: a local jump (a few blocks changing level) that the frame's rms dilutes.
    """

    residual: np.ndarray
    mask: np.ndarray
    rms_dn: float
    mean_dn: float
    noise_dn: float | None
    fraction: float
    noise_floor_dn: float | None = None
    worst_tile_dn: float | None = None


def _grey(image: np.ndarray) -> np.ndarray:
    import cv2

    img = np.asarray(image)
    if img.ndim == 3:
        code = cv2.COLOR_BGRA2GRAY if img.shape[2] == 4 else cv2.COLOR_BGR2GRAY
        img = cv2.cvtColor(img, code)
    return img.astype(np.float32)


def _sensor_noise(sensor: dict | None):
    """(variance(DN) function, dark threshold DN) from a manifest's sensor record."""
    if not sensor:
        return None, 0.5
    gain = float(sensor.get("gain", 0.0))
    read = float(sensor.get("read_noise", 0.0))
    floor = read * read + 1.0 / 12.0

    def variance(dn):
        return (dn / gain if gain > 0 else 0.0) + floor

    return variance, DARK_SIGMAS * math.sqrt(floor)


def sampling_stride(shape: tuple[int, ...], pixels: int = SAMPLED_PIXELS) -> int:
    """Return the largest pixel spacing (1, 2 or 4) that still measures ``pixels`` a frame.

    Parameters
    ----------
    shape : (h, w, ...) of int
        The frames' shape.
    pixels : int
        The fewest pixels to measure per frame.

    Returns
    -------
    int
        The ``stride`` of :func:`pair_residual` and :func:`consistency`.

    >>> sampling_stride((1024, 1024)), sampling_stride((256, 256))
    (2, 1)
    """
    h, w = int(shape[0]), int(shape[1])
    stride = 1
    while stride < 4 and -(-h // (2 * stride)) * -(-w // (2 * stride)) >= pixels:
        stride *= 2
    return stride


def pair_residual(image0, image1, range0, range1, truth0, truth1, *, normals0=None,
                  normals1=None, sensor: dict | None = None, edge_px: int = 2,
                  occlusion_tolerance: float = 0.002, stride: int = 1,
                  contours0=None, contours1=None) -> PairResidual:
    """Photometric residual of frame t+1 warped into frame t through the truth.

    Parameters
    ----------
    image0, image1 : (h, w) uint8 or uint16 (or colour), DN
        Frames t and t+1.
    range0, range1 : (h, w) float32, metres
        Their range images (NaN: no return).
    truth0, truth1 : render.rundir.FrameTruth
        Their pose, intrinsics, sun and body rotation.
    normals0, normals1 : (h, w, 3) float32, optional
        World-frame normals; without them every surface counts as facing the sun.
    sensor : dict, optional
        The run manifest's ``sensor`` record (gain, read_noise), for the noise level and the
        dark threshold.
    edge_px : int, pixels
        Margin around silhouettes, occlusion edges and moving shadow edges.
    occlusion_tolerance : float
        Relative range disagreement above which a point counts as hidden in frame t+1.
    stride : int, pixels
        Measure the pixels of frame t on a grid of this spacing (1: every pixel); the
        residual and mask are then that grid's, ``(ceil(h / stride), ceil(w / stride))``,
        and the tiles of ``worst_tile_dn`` keep their side in frame t's pixels. Frame t+1
        is sampled at full resolution either way.
    contours0, contours1 : (h, w) bool, optional
        ``near_contours(range0, edge_px)`` and ``near_contours(range1, edge_px)`` where the
        caller has them (a run's frames are each in two pairs); computed here otherwise.

    Returns
    -------
    PairResidual
    """
    import cv2

    i0, i1 = _grey(image0), _grey(image1)
    h, w = i0.shape
    if i1.shape != (h, w) or range0.shape != (h, w) or range1.shape != (h, w):
        raise InvalidParameterError(
            f"frames, range images must share one shape; got {i0.shape}, {i1.shape}, "
            f"{range0.shape}, {range1.shape}")
    if not (occlusion_tolerance > 0 and edge_px >= 0 and stride >= 1
            and stride == int(stride) and TILE % int(stride) == 0):
        raise InvalidParameterError(
            f"occlusion_tolerance must be > 0, edge_px >= 0 and stride a divisor of {TILE};"
            f" got {occlusion_tolerance}, {edge_px}, {stride}")
    s = int(stride)
    variance, dark_dn = _sensor_noise(sensor)
    rot0 = quat_to_matrix(truth0.body_rotation)
    rot1 = quat_to_matrix(truth1.body_rotation)
    map_u, map_v, seen = _warp_maps(range0, truth0, truth1, s)
    inside = (map_u >= 0) & (map_u <= w - 1) & (map_v >= 0) & (map_v <= h - 1)
    # seen in both: frame t+1's range at the projection (nearest return) against the distance;
    # a pixel without return (NaN, copied by the nearest sample) fails both tests as -1 would
    r1_at = cv2.remap(np.asarray(range1, dtype=np.float32), map_u, map_v,
                      cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT, borderValue=-1.0)
    with np.errstate(invalid="ignore"):
        visible = inside & (r1_at > 0) & (np.abs(r1_at - seen) <= occlusion_tolerance * seen)
    if contours0 is None:
        contours0 = near_contours(range0, edge_px)
    if contours1 is None:
        contours1 = near_contours(range1, edge_px)
    edges1 = cv2.remap(contours1.astype(np.uint8), map_u, map_v,
                       cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT, borderValue=1) > 0
    mask = visible & ~contours0[::s, ::s] & ~edges1
    i0 = i0[::s, ::s]
    warped = cv2.remap(i1, map_u, map_v, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    # lit in both
    sun = np.asarray(truth0.sun, dtype=np.float64)
    sun1 = np.asarray(truth1.sun, dtype=np.float64)
    if normals0 is not None and normals1 is not None:
        # facing the sun: n . sun > 0, False without a normal (NaN); frame t+1's test is
        # taken at the projection (nearest pixel) as bytes, a quarter of its cosines' size
        with np.errstate(invalid="ignore"):
            facing0 = normals0[::s, ::s] @ sun.astype(np.float32) > 0
            facing1 = cv2.remap((normals1 @ sun1.astype(np.float32) > 0).view(np.uint8),
                                map_u, map_v, cv2.INTER_NEAREST,
                                borderMode=cv2.BORDER_CONSTANT, borderValue=0) > 0
        mask &= facing0 & facing1
    dark0 = i0 <= dark_dn
    dark1 = warped <= dark_dn
    mask &= ~(dark0 & dark1)
    sun_body0 = rot0.T @ sun
    sun_body1 = rot1.T @ sun1
    turn = math.acos(min(1.0, float(float(np.dot(sun_body0, sun_body1))
                                    / (np.linalg.norm(sun_body0) * np.linalg.norm(sun_body1)))))
    if turn > SUN_STILL_RAD:  # shadows move on the surface: drop their edges
        mask &= ~dilate(dark0 | dark1, -(-edge_px // s))
    residual = np.where(mask, i0 - warped, np.nan).astype(np.float32)
    vals = residual[mask].astype(np.float64)
    rms = float(np.sqrt(np.mean(vals * vals))) if vals.size else float("nan")
    mean = float(vals.mean()) if vals.size else float("nan")
    noise = floor = None
    if variance is not None and vals.size:
        var0, var1 = variance(i0[mask]), variance(warped[mask])  # each once, for both sums
        noise = float(np.sqrt(np.mean(0.5 * (var0 + var1))))
        # bilinear sampling averages frame t+1's noise: sum of the squared weights
        mu, mv = map_u[mask], map_v[mask]
        fu = mu - np.floor(mu)
        fv = mv - np.floor(mv)
        w2 = ((1 - fu) ** 2 + fu**2) * ((1 - fv) ** 2 + fv**2)
        floor = float(np.sqrt(np.mean(var0 + w2 * var1)))
    return PairResidual(residual, mask, rms, mean, noise, float(mask.mean()), floor,
                        _worst_tile(residual, mask, TILE // s))


def _warp_maps(range0, truth0, truth1, stride=1):
    """Where each pixel of frame t lands in frame t+1, and its distance from camera t+1.

    Returns
    -------
    map_u, map_v : (h, w) float32, pixels
        The projection in frame t+1 (-10 without a return or behind camera t+1), for the
        pixels of frame t every ``stride`` rows and columns.
    distance : (h, w) float64, metres
        From camera t+1 (NaN without a return).
    """
    u1, v1, distance, ok = camera_map(range0, truth0, truth1, stride)
    map_u = np.where(ok, u1, -10.0).astype(np.float32)
    map_v = np.where(ok, v1, -10.0).astype(np.float32)
    return map_u, map_v, distance


def camera_map(range0: np.ndarray, truth0, truth1, stride: int = 1):
    """Carry every pixel of one frame, lifted by its range, into another frame's image.

    A pixel's ray in camera 0, scaled by its range, carried through the body rotations
    (frame 0's R_WB back to the body, frame 1's out of it) into camera 1, in one affine map
    of camera frames (``c1 = t + r d A``): the world coordinates are never formed, so no
    precision is lost to their size, and the whole image goes at once.

    Parameters
    ----------
    range0 : (h, w) float32, metres
        Frame 0's range (NaN: no return).
    truth0, truth1 : render.rundir.FrameTruth
        The two frames' pose, intrinsics and body rotation.
    stride : int, pixels
        Carry the pixels every ``stride`` rows and columns.

    Returns
    -------
    u1, v1 : (ceil(h / stride), ceil(w / stride)) float64, pixels
        The projection in frame 1 (NaN where ``ok`` is False).
    distance : same shape, float64, metres
        From camera 1 (NaN without a return).
    ok : same shape, bool
        A return, in front of camera 1.
    """
    from evaluation.warpkernels import camera_map_rows

    x, y, a, t = camera_affine(range0.shape, truth0, truth1, stride)
    k1 = truth1.intrinsics
    # per pixel (compiled): scale = r / |(x, y, 1)|, c = t + scale (x, y, 1) A,
    # (u1, v1) = (fx c_x / c_z + cx, fy c_y / c_z + cy), distance = |c|
    return camera_map_rows(range0[::stride, ::stride], x, y, a, t, k1.fx, k1.fy, k1.cx, k1.cy)


def camera_affine(shape: tuple[int, ...], truth0, truth1, stride: int = 1):
    """Return the geometry :func:`camera_map` carries pixels with (rays, camera 0 to 1).

    Parameters
    ----------
    shape : (h, w, ...) of int
        Frame 0's shape.
    truth0, truth1 : render.rundir.FrameTruth
        The two frames' pose, intrinsics and body rotation.
    stride : int, pixels
        Every ``stride`` rows and columns.

    Returns
    -------
    x, y : (ceil(w / stride),), (ceil(h / stride),) float64
        Normalised image coordinates in camera 0 of the columns and rows.
    a : (3, 3) float64
        Camera-0 directions to camera-1 axes (row vectors).
    t : (3,) float64, metres
        Camera 0's origin in camera 1's axes.
    """
    h, w = int(shape[0]), int(shape[1])
    k0 = truth0.intrinsics
    r_wc0, r_wc1 = truth0.pose.rotation, truth1.pose.rotation
    # row vectors: world1 = world0 @ rot0 @ rot1.T, camera = (world - position) @ R_WC
    body = quat_to_matrix(truth0.body_rotation) @ quat_to_matrix(truth1.body_rotation).T
    a = r_wc0.T @ body @ r_wc1  # camera-0 directions to camera-1 axes (row vectors)
    t = (np.asarray(truth0.pose.position) @ body - np.asarray(truth1.pose.position)) @ r_wc1
    x = (np.arange(0, w, stride, dtype=np.float64) - k0.cx) / k0.fx
    y = (np.arange(0, h, stride, dtype=np.float64) - k0.cy) / k0.fy
    return x, y, a, t


def _worst_tile(residual: np.ndarray, mask: np.ndarray, tile: int = TILE) -> float | None:
    """Return the largest rms (DN) over tile x tile tiles at least half counted."""
    h, w = residual.shape
    ny, nx = h // tile, w // tile
    if ny == 0 or nx == 0:
        return None
    r = np.where(mask, residual, 0.0)[:ny * tile, :nx * tile].astype(np.float64)
    m = mask[:ny * tile, :nx * tile]
    sq = (r * r).reshape(ny, tile, nx, tile).sum(axis=(1, 3))
    n = m.reshape(ny, tile, nx, tile).sum(axis=(1, 3))
    ok = n >= tile * tile // 2
    return float(np.sqrt(sq[ok] / n[ok]).max()) if ok.any() else None


def change_marks(drawn_records) -> tuple[np.ndarray, np.ndarray]:
    """Frames where the drawn layers, and where the levels of detail, change.

    Parameters
    ----------
    drawn_records : sequence of dict
        Each frame's truth ``drawn`` record.

    Returns
    -------
    layer_change, lod_change : (n,) bool
        ``layer_change[k]``: frame k draws another set of terrain layers, or another body
        level of detail or imposter state, than frame k-1. ``lod_change[k]``: any level of
        detail changed (a terrain layer's set of block levels, the target on-screen cell
        size, a body magnitude or the boulder levels drawn).
    """
    from evaluation.tracking import resolution_key

    n = len(drawn_records)
    layer = np.zeros(n, dtype=bool)
    lod = np.zeros(n, dtype=bool)

    def lod_key(d):
        if not isinstance(d, dict):
            return json.dumps(d, sort_keys=True, default=str)
        if isinstance(d.get("layers"), list):
            return json.dumps([[x.get("level"), x.get("lod")] for x in d["layers"]]
                              + [d.get("lod_pixels")], default=str)
        return json.dumps([d.get("body_magnitude"), d.get("imposter"),
                           sorted((d.get("boulders") or {}).keys()), d.get("lod_edge_m")],
                          default=str)

    keys = [resolution_key(d) for d in drawn_records]
    lods = [lod_key(d) for d in drawn_records]
    for k in range(1, n):
        layer[k] = keys[k] != keys[k - 1]
        lod[k] = layer[k] or lods[k] != lods[k - 1]
    return layer, lod


def _median(values) -> float | None:
    v = [x for x in values if x is not None]
    return float(np.median(v)) if v else None


def _max(values) -> float | None:
    v = [x for x in values if x is not None]
    return float(max(v)) if v else None


@dataclass(frozen=True, eq=False)
class Consistency:
    """Per-pair consistency of a run (see the module docstring).

    ``frames[i]`` describes the pair (i, i+1): rms_dn, mean_dn, noise_dn, noise_floor_dn,
    excess_dn (the rms beyond the noise floor, ``sqrt(rms^2 - floor^2)``), worst_tile_dn,
    fraction, and whether frame i+1 changes layers (``layer_change``) or levels of detail
    (``lod_change``).
    """

    run_dir: str
    frames: list
    settings: dict
    notes: list = field(default_factory=list)

    def rms(self) -> np.ndarray:
        """(n_pairs,) float64, DN (NaN where nothing was counted)."""
        return np.array([f["rms_dn"] if f["rms_dn"] is not None else np.nan
                         for f in self.frames], dtype=np.float64)

    def summary(self) -> dict:
        """Return the residuals' median, largest and spikes, and noise, as plain data."""
        rms = self.rms()
        ok = np.isfinite(rms)
        median = float(np.median(rms[ok])) if ok.any() else None
        largest = float(rms[ok].max()) if ok.any() else None
        noise = [f["noise_dn"] for f in self.frames if f["noise_dn"] is not None]
        at_change = [f["rms_dn"] for f in self.frames
                     if (f["layer_change"] or f["lod_change"]) and f["rms_dn"] is not None]
        ordinary = [f["rms_dn"] for f in self.frames
                    if not (f["layer_change"] or f["lod_change"]) and f["rms_dn"] is not None]
        spikes = [i for i, r in enumerate(rms) if median and np.isfinite(r)
                  and r > SPIKE_BOUND * median]
        return dict(
            pairs=len(self.frames),
            rms_dn_median=median, rms_dn_max=largest,
            spike_ratio=(largest / median) if median and largest is not None else None,
            spike_bound=SPIKE_BOUND,
            spikes=spikes,
            noise_dn_median=float(np.median(noise)) if noise else None,
            noise_floor_dn_median=_median(f["noise_floor_dn"] for f in self.frames),
            excess_dn_median=_median(f["excess_dn"] for f in self.frames),
            excess_dn_max=_max(f["excess_dn"] for f in self.frames),
            worst_tile_dn_median=_median(f["worst_tile_dn"] for f in self.frames),
            worst_tile_dn_max=_max(f["worst_tile_dn"] for f in self.frames),
            rms_dn_median_at_changes=float(np.median(at_change)) if at_change else None,
            rms_dn_median_elsewhere=float(np.median(ordinary)) if ordinary else None,
            layer_changes=int(sum(f["layer_change"] for f in self.frames)),
            lod_changes=int(sum(f["lod_change"] for f in self.frames)),
            counted_fraction_median=(float(np.median([f["fraction"] for f in self.frames]))
                                     if self.frames else None))

    def as_dict(self) -> dict:
        """Return the whole check (settings, summary, frames) as plain data for JSON."""
        return dict(format="craterscape-consistency", version=1, run_dir=self.run_dir,
                    settings=self.settings, summary=self.summary(), frames=self.frames,
                    notes=list(self.notes))


def consistency(run, *, edge_px: int = 2, occlusion_tolerance: float = 0.002,
                stride: int = 1, progress=None) -> Consistency:
    """Measure every consecutive pair of a run (see the module docstring).

    Parameters
    ----------
    run : RunReader or path
        Needs truth and range images.
    edge_px, occlusion_tolerance, stride :
        As in :func:`pair_residual` (``stride`` 2 measures a quarter of the pixels; the
        uncertainty this adds to each figure is measured in ``docs/speed.md``).
    progress : callable, optional
        ``progress(done, total)`` after each pair.

    Returns
    -------
    Consistency
    """
    if not isinstance(run, RunReader):
        run = RunReader(run)
    if not run.has_truth:
        raise InvalidParameterError(
            f"run directory '{run.dir}' has no truth.json: consistency needs each frame's "
            "pose and range")
    if any(t.range is None for t in run.truth):
        raise InvalidParameterError(
            f"run directory '{run.dir}' has frames without range images: consistency warps "
            "frames through range, so render with range output on")
    if len(run) < 2:
        raise InvalidParameterError(f"run directory '{run.dir}' has {len(run)} frame; "
                                    "consistency compares consecutive frames")
    sensor = run.manifest.get("sensor")
    notes = []
    if not sensor:
        notes.append("the run's manifest records no sensor: noise levels are omitted")
    layer, lod = change_marks([t.drawn for t in run.truth])
    frames = []

    from evaluation.tracking import read_ahead

    def load(k):
        return run.image(k), run.range(k), run.normals(k)

    # the next frame is read (and decompressed, without the GIL) while a pair is measured
    ahead = read_ahead(load, len(run))
    image0, range0, normals0 = next(ahead)
    contours0 = near_contours(range0, edge_px)  # each frame's once, for both its pairs
    for k, (image1, range1, normals1) in enumerate(ahead):
        contours1 = near_contours(range1, edge_px)
        frames.append(_pair_record(k, pair_residual(
            image0, image1, range0, range1, run.truth[k], run.truth[k + 1],
            normals0=normals0, normals1=normals1, sensor=sensor, edge_px=edge_px,
            occlusion_tolerance=occlusion_tolerance, stride=stride, contours0=contours0,
            contours1=contours1), layer, lod))
        image0, range0, normals0, contours0 = image1, range1, normals1, contours1
        if progress is not None:
            progress(k + 1, len(run) - 1)
    result = Consistency(str(run.dir), frames,
                         dict(edge_px=int(edge_px), occlusion_tolerance=occlusion_tolerance,
                              dark_sigmas=DARK_SIGMAS, silhouette_jump=SILHOUETTE_JUMP,
                              stride=int(stride)),
                         notes)
    s = result.summary()
    log.info("consistency of %d pairs: median rms %s DN, spike ratio %s", s["pairs"],
             s["rms_dn_median"], s["spike_ratio"])
    return result


def _pair_record(k: int, pr: PairResidual, layer, lod) -> dict:
    """Return one pair's row of :attr:`Consistency.frames`."""
    return dict(
            frame=k, next=k + 1,
            rms_dn=pr.rms_dn if math.isfinite(pr.rms_dn) else None,
            mean_dn=pr.mean_dn if math.isfinite(pr.mean_dn) else None,
            noise_dn=pr.noise_dn,
            noise_floor_dn=pr.noise_floor_dn,
            excess_dn=(math.sqrt(max(pr.rms_dn**2 - pr.noise_floor_dn**2, 0.0))
                       if pr.noise_floor_dn is not None and math.isfinite(pr.rms_dn) else None),
            worst_tile_dn=pr.worst_tile_dn,
            fraction=pr.fraction, layer_change=bool(layer[k + 1]),
            lod_change=bool(lod[k + 1]))


def save_consistency(result: Consistency, folder, *, inputs=(),
                     drawn: dict | None = None) -> dict:
    """Write ``consistency.json``, ``consistency.csv`` and ``consistency.png`` atomically.

    Returns the summary. The figure's PNG bytes go to ``drawn`` when it is a dict
    (:func:`evaluation.figures.drawn_once`), for a report that shows it too.
    """
    import csv
    import io

    from evaluation.figures import consistency_figure, drawn_once, save_png
    from terrain.core.outputs import atomic_path

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    cols = ["frame", "next", "rms_dn", "mean_dn", "noise_dn", "noise_floor_dn", "excess_dn",
            "worst_tile_dn", "fraction",
            "layer_change", "lod_change"]
    writer.writerow(cols)
    for f in result.frames:
        writer.writerow(["" if f[c] is None else (f"{f[c]:.5g}" if isinstance(f[c], float)
                                                  else int(f[c])) for c in cols])
    for name, text in (("consistency.csv", buf.getvalue()),
                       ("consistency.json", json.dumps(result.as_dict(), indent=1))):
        with atomic_path(folder / name, inputs) as tmp:
            tmp.write_text(text, encoding="utf-8")
    save_png(drawn_once(drawn, "consistency", lambda: consistency_figure(result)),
             folder / "consistency.png", inputs=inputs)
    return result.summary()
