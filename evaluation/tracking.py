r"""Harris feature tracking through a rendered sequence, scored against the renderer's truth.

The papers hand rendered descents to a Harris-corner tracker and show the tracks (Martin et
al. 2014, section V.F, Fig. 15; the asteroid paper, section VI.C): features should be found,
followed "across resolution jumps", and not cluster on artefacts. That shows the tracker
*works*; it cannot show it tracks the *right* point. A run directory
(:mod:`render.rundir`) carries the exact pose, intrinsics and range of every frame, so here
every feature is also scored against where it truly is.

Tracking (:func:`track`)
------------------------
* Corners: Harris response (``cv2.goodFeaturesToTrack(..., useHarrisDetector=True)``; Harris
  and Stephens 1988), at most ``max_corners``, at least ``min_distance`` pixels apart.
* No corners beside regions without signal: a connected region of pixels at most
  ``dark_level`` grey levels above the frame's darkest, at least a Lucas-Kanade window in
  area, is sky (around a body seen whole) or shadow too deep to show anything, and no corner
  is detected within ``dark_margin`` pixels of it. A corner there is the outline of such a
  region, not a point of the surface: a limb's corner slides along the limb as the body
  turns or the view changes (new surface turns into view behind it), a shadow's edge moves
  with the sun over a spinning body, and a window that straddles the outline follows the
  outline. The test uses the image alone, as a flight tracker must; tracks already live
  may go on into the margin (their window keeps the surface texture it started on).
* Motion: pyramidal Lucas-Kanade (``cv2.calcOpticalFlowPyrLK``; Bouguet 2001) from each frame
  to the next. With ``prewarp`` (the default), a first pass gives every live track's motion,
  the homography of the step is fitted to them (RANSAC), and Lucas-Kanade runs again from
  the previous frame warped by that homography: each window then follows only what the
  homography leaves (parallax, noise), not the zoom and roll of a descent, under which a
  shift-only window drifts by a biased fraction of a pixel at every step.
* Forward-backward check (Kalal, Mikolajczyk and Matas 2010): each point is tracked back to
  the previous frame; a track ends when the round trip misses its start by more than
  ``fb_threshold`` pixels, when either pass fails, or when it leaves the image (less
  ``border`` pixels).
* Replenishment: after every step new corners are detected away from the live tracks
  (``min_distance``) until ``max_corners`` are live again.

Images go to 8 bits for OpenCV with one scale for the whole sequence (16-bit frames are
divided by their first frame's 99.9th percentile over 255), so a brightness change between
frames stays a brightness change.

Against truth (:func:`score`)
-----------------------------
Each track is lifted to 3-D at its first frame: the range image there is sampled at the
feature (bilinearly when the four surrounding returns agree within
``occlusion_tolerance``, else the nearest return) and the pixel is unprojected with that
frame's pose (:meth:`render.camera.Pose.unproject`). Asteroid scenes rotate: the point is
carried into the body frame with the frame's ``body_rotation`` (R_WB) and back into the
world with each later frame's. Projecting it with the later frames' pose and intrinsics
gives where the feature truly is; the tracking error is the pixel distance from the tracked
position. Observations whose true point is hidden (the range image at its projection is
shorter than its distance by more than ``occlusion_tolerance`` of it) or out of the image
are not scored, and are counted. An observation further than ``outlier_px`` from the truth
is an outlier.

One step against many: the error above accumulates along a track (each step's error
stays in the position the next step starts from). The *one-step error* separates one step
from the rest: the tracked position at frame k-1 is lifted with frame k-1's range and pose
and carried by the truth into frame k; the distance of the tracked position at frame k from
it is what that single step of tracking got wrong, whatever the track did before. Both are
reported, each by track age: a one-step error that stays flat while the accumulated error
grows is tracker drift; a one-step error that jumps at some frames is the images changing
under the features (a renderer's level-of-detail switch, see
:mod:`evaluation.consistency`).

Silhouettes: a corner where the surface meets the sky, or where a nearer surface occludes a
farther one, is a strong Harris feature that is not fixed to the surface: as the view
changes it slides along the outline. A track whose first position lies within
:data:`SILHOUETTE_PX` pixels of a pixel without return or of a range jump of more than
:data:`SILHOUETTE_JUMP` is a *silhouette track*; the errors are reported for all tracks
(what the tracker delivers) and for the others alone (how well surface points are tracked).
On a small asteroid seen whole, most corners are silhouette corners and carry most of the
error; on terrain filling the frame there are none.

Without truth (no ``truth.json``) or without range images the tracks are still measured;
the error metrics are omitted, with a warning.

Resolution changes: a frame whose truth's ``drawn`` record shows a different resolution from
the previous frame's starts a *layer change*: for terrain scenes the set of drawn layer
levels, for asteroid scenes the body's level of detail (and imposter state), for mesh scenes
the mesh's level of detail, otherwise the whole record. The survival of tracks across those
steps is reported beside the survival across ordinary steps (the paper's "feature tracking
continuing successfully across resolution jumps"). Triangle counts and per-block levels of
detail, which change almost every frame, do not count.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field

import numpy as np

from evaluation.silhouette import SILHOUETTE_JUMP, near_contours
from render.camera import quat_to_matrix
from render.rundir import RunReader
from terrain.core import memory
from terrain.core.errors import InvalidParameterError

__all__ = ["ScoredTracks", "TrackerSettings", "Tracks", "ideal_one_step", "ideal_one_steps",
           "load_run", "median_by_age", "read_ahead", "save_tracks", "score", "track",
           "truth_round_trip", "truth_warped_frame"]

log = logging.getLogger(__name__)

#: Quantiles of the error distribution reported.
ERROR_QUANTILES = (0.5, 0.9, 0.95, 0.99)
#: A feature closer than this (pixels) to a silhouette at its first frame is a silhouette
#: feature: about a third of the default Lucas-Kanade window.
SILHOUETTE_PX = 6
#: Bytes per (track, frame) cell of the dense track arrays (positions float32 x 2; scoring
#: adds errors float64 and true positions float64 x 2, and temporaries).
TRACK_BYTES_PER_OBSERVATION = 48


#: Most pyramid levels (a 2^16 reduction is far below any frame).
MAX_PYRAMID_LEVELS = 16
#: Pixels the default ``dark_margin`` adds to half the Lucas-Kanade window: the blur of a
#: limb or shadow edge (the optics' PSF and the renderer's pixel footprint) reaches about
#: this far into the surface.
DARK_MARGIN_SLACK = 2


@dataclass(frozen=True)
class TrackerSettings:
    """Parameters of :func:`track` (defaults suit 256-1024 pixel frames).

    Parameters
    ----------
    max_corners : int
        Live tracks kept (replenished to this number every frame).
    quality : float
        Harris quality level relative to the frame's strongest corner.
    min_distance : float, pixels
        Least distance between corners (and between a new corner and a live track).
    block_size : int, pixels
        Harris window.
    harris_k : float
        Harris detector free parameter.
    win_size : int, pixels
        Lucas-Kanade window side.
    levels : int
        Pyramid levels above the full image.
    fb_threshold : float, pixels
        Largest forward-backward round-trip error of a kept point.
    border : int, pixels
        Points closer than this to the image edge are dropped.
    prewarp : bool
        Before Lucas-Kanade, warp the previous frame by the homography the step's first pass
        implies (RANSAC over all tracks), so that each window only has to follow what that
        homography does not: a shift-only window then no longer drifts under the zoom and
        roll of a descent (module docstring). Off: plain pyramidal Lucas-Kanade, frame to
        frame.
    dark_level : int, grey levels (of 255)
        Pixels at most this far above the frame's darkest pixel have no signal.
    dark_margin : int, pixels, or None
        No corner is detected this close to a region without signal (module docstring);
        0: anywhere. None (the default): ``win_size // 2 +``
        :data:`DARK_MARGIN_SLACK`, so that no detected corner's window reaches the region
        or the blur at its edge.
    """

    max_corners: int = 350
    quality: float = 0.01
    min_distance: float = 8.0
    block_size: int = 7
    harris_k: float = 0.04
    win_size: int = 21
    levels: int = 3
    fb_threshold: float = 0.5
    border: int = 4
    prewarp: bool = True
    dark_level: int = 2
    dark_margin: int | None = None

    def __post_init__(self):
        if not isinstance(self.prewarp, (bool, np.bool_)):
            raise InvalidParameterError(f"tracker prewarp must be true or false; got "
                                        f"{self.prewarp!r}")
        names = ["max_corners", "block_size", "win_size", "levels", "border", "dark_level"]
        if self.dark_margin is not None:
            names.append("dark_margin")
        for name in names:
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
                raise InvalidParameterError(f"tracker {name} must be an integer; got {value!r}")
        if self.max_corners < 1 or self.block_size < 3 or self.win_size < 5 or self.levels < 0 \
                or self.border < 0 or not 0 <= self.dark_level <= 255 \
                or (self.dark_margin is not None and self.dark_margin < 0):
            raise InvalidParameterError(
                "tracker needs max_corners >= 1, block_size >= 3, win_size >= 5, levels >= 0, "
                f"border >= 0, dark_level in [0, 255] and dark_margin >= 0; got {self}")
        if not 0.0 < self.quality < 1.0:
            raise InvalidParameterError(f"tracker quality must lie in (0, 1); got "
                                        f"{self.quality}")
        if not (self.min_distance >= 0 and self.fb_threshold > 0 and self.harris_k > 0):
            raise InvalidParameterError(
                "tracker min_distance must be >= 0, fb_threshold and harris_k > 0; got "
                f"{self.min_distance}, {self.fb_threshold}, {self.harris_k}")

    def as_dict(self) -> dict:
        """Return the settings as plain data for the report's JSON."""
        return dict(max_corners=self.max_corners, quality=self.quality,
                    min_distance=self.min_distance, block_size=self.block_size,
                    harris_k=self.harris_k, win_size=self.win_size, levels=self.levels,
                    fb_threshold=self.fb_threshold, border=self.border,
                    prewarp=bool(self.prewarp), dark_level=self.dark_level,
                    dark_margin=self.margin)

    @property
    def margin(self) -> int:
        """The ``dark_margin`` in effect (pixels; its default resolved)."""
        if self.dark_margin is None:
            return self.win_size // 2 + DARK_MARGIN_SLACK
        return int(self.dark_margin)


@dataclass(frozen=True, eq=False)
class Tracks:
    """Feature tracks through a sequence.

    Parameters
    ----------
    positions : (n_tracks, n_frames, 2) float32, pixels (u = column, v = row)
        NaN outside each track's life; a track lives in consecutive frames only. Dense, so
        scoring holds about :data:`TRACK_BYTES_PER_OBSERVATION` bytes per track and frame
        (a 60-frame descent with 3,000 tracks: 9 MB; a 1,000-frame run with 50,000 tracks
        would need 2.4 GB and is refused up front where that is not available).
    start, stop : (n_tracks,) int64
        First and last frame (inclusive) of each track.
    layer_change : (n_frames,) bool
        True where a frame's drawn layers differ from the previous frame's.
    shape : (int, int)
        Image (height, width).
    settings : TrackerSettings
    """

    positions: np.ndarray
    start: np.ndarray
    stop: np.ndarray
    layer_change: np.ndarray
    shape: tuple
    settings: TrackerSettings

    @property
    def n_frames(self) -> int:
        """The number of frames of the sequence."""
        return self.positions.shape[1]

    @property
    def n_tracks(self) -> int:
        """The number of tracks (features ever detected)."""
        return self.positions.shape[0]

    @property
    def lengths(self) -> np.ndarray:
        """(n_tracks,) int64: frames each track lives in."""
        return self.stop - self.start + 1

    def alive(self) -> np.ndarray:
        """(n_tracks, n_frames) bool."""
        return np.isfinite(self.positions[:, :, 0])

    def survival(self) -> np.ndarray:
        """(n_frames,) float64: fraction of frame k-1's tracks still alive at k (NaN at 0)."""
        alive = self.alive()
        out = np.full(self.n_frames, np.nan)
        for k in range(1, self.n_frames):
            before = alive[:, k - 1]
            if before.any():
                out[k] = float((alive[:, k] & before).sum() / before.sum())
        return out

    def summary(self) -> dict:
        """Return track counts and lengths, and survival (also at layer changes), as plain data."""
        alive = self.alive()
        per_frame = alive.sum(axis=0)
        surv = self.survival()
        ordinary = surv[1:][~self.layer_change[1:]]
        at_change = surv[1:][self.layer_change[1:]]
        lengths = self.lengths
        return dict(
            frames=self.n_frames, tracks=self.n_tracks,
            tracks_per_frame_mean=float(per_frame.mean()),
            tracks_per_frame_min=int(per_frame.min()),
            track_length_mean=float(lengths.mean()) if lengths.size else 0.0,
            track_length_median=float(np.median(lengths)) if lengths.size else 0.0,
            track_length_max=int(lengths.max()) if lengths.size else 0,
            tracks_spanning_sequence=int(((self.start == 0)
                                          & (self.stop == self.n_frames - 1)).sum()),
            survival_mean=_nanmean(ordinary),
            layer_changes=int(self.layer_change.sum()),
            survival_at_layer_change=_nanmean(at_change),
            settings=self.settings.as_dict())


def _nanmean(a) -> float | None:
    a = np.asarray(a, dtype=np.float64)
    a = a[np.isfinite(a)]
    return float(a.mean()) if a.size else None


# ------------------------------------------------------------------------------ frames


class _Grey:
    """Frames as 8-bit grey images with one sequence-wide scale (module docstring)."""

    def __init__(self):
        self.scale = None

    def __call__(self, image: np.ndarray) -> np.ndarray:
        import cv2

        img = np.asarray(image)
        if img.ndim == 3:
            code = cv2.COLOR_BGRA2GRAY if img.shape[2] == 4 else cv2.COLOR_BGR2GRAY
            img = cv2.cvtColor(img, code)
        if img.ndim != 2:
            raise InvalidParameterError(f"frames must be grey or colour images; got shape "
                                        f"{img.shape}")
        if img.dtype == np.uint8:
            return img
        if self.scale is None:
            top = float(np.percentile(img, 99.9))
            self.scale = 255.0 / top if top > 0 else 1.0
        return np.clip(img.astype(np.float32) * self.scale, 0, 255).astype(np.uint8)


def resolution_key(drawn) -> str:
    """Return what decides a frame's resolution in its truth's ``drawn`` record."""
    import json

    if not isinstance(drawn, dict):
        return json.dumps(drawn, sort_keys=True, default=str)
    layers = drawn.get("layers")
    if isinstance(layers, list) and all(isinstance(x, dict) and "level" in x for x in layers):
        key: object = ["layers", sorted(x["level"] for x in layers)]  # terrain scenes
    elif "body_magnitude" in drawn:  # asteroid scenes: the body's level of detail
        key = ["body", drawn["body_magnitude"], bool(drawn.get("imposter", False))]
    elif "lod_edge_m" in drawn:  # mesh scenes
        key = ["mesh", drawn["lod_edge_m"]]
    else:
        key = drawn
    return json.dumps(key, sort_keys=True, default=str)


def load_run(run_dir) -> RunReader:
    """Open a run directory (:class:`render.rundir.RunReader`)."""
    return RunReader(run_dir)


def track(run, settings: TrackerSettings | None = None, *, progress=None) -> Tracks:
    """Track Harris corners through every frame of a run (see the module docstring).

    Parameters
    ----------
    run : RunReader or path
    settings : TrackerSettings, optional
    progress : callable, optional
        ``progress(done, total)`` after each frame.

    Returns
    -------
    Tracks
    """
    import cv2

    if not isinstance(run, RunReader):
        run = RunReader(run)
    s = settings or TrackerSettings()
    n = len(run)
    grey = _Grey()
    prev = grey(run.image(0))
    h, w = prev.shape
    if n > 1 and (h < 2 * s.border + 8 or w < 2 * s.border + 8):
        raise InvalidParameterError(f"frames of {w}x{h} pixels are too small to track in")
    if s.win_size > min(h, w) or s.block_size > min(h, w):
        raise InvalidParameterError(
            f"tracker windows (win_size {s.win_size}, block_size {s.block_size} px) must fit "
            f"in the {w}x{h} frames")
    if s.levels > MAX_PYRAMID_LEVELS:
        raise InvalidParameterError(f"tracker levels must be at most {MAX_PYRAMID_LEVELS}; got "
                                    f"{s.levels}")
    from terrain.core import memory

    # two frames, their pyramids and derivative images, and per track its window patches
    memory.require(h * w * 4 * 12 + s.max_corners * s.win_size ** 2 * 4 * 6,
                   f"tracking {w}x{h} frames with {s.max_corners} corners")
    layer_change = np.zeros(n, dtype=bool)
    if run.has_truth:
        keys = [resolution_key(t.drawn) for t in run.truth]
        layer_change[1:] = [keys[k] != keys[k - 1] for k in range(1, n)]
    lk = dict(winSize=(s.win_size, s.win_size), maxLevel=s.levels,
              criteria=(cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 0.01))
    tracks: list[list] = []  # per track: [start, [positions...]]
    live: list[int] = []  # indices into tracks

    def replenish(image, k):
        need = s.max_corners - len(live)
        if need <= 0:
            return
        mask = np.full(image.shape, 255, dtype=np.uint8)
        if s.border:
            mask[:s.border] = 0
            mask[-s.border:] = 0
            mask[:, :s.border] = 0
            mask[:, -s.border:] = 0
        radius = max(1, int(math.ceil(s.min_distance)))
        for t in live:
            u, v = tracks[t][1][-1]
            cv2.circle(mask, (int(round(u)), int(round(v))), radius, 0, -1)
        if s.margin:
            mask[near_dark(image, s.dark_level, s.margin, s.win_size * s.win_size)] = 0
        corners = cv2.goodFeaturesToTrack(image, maxCorners=need, qualityLevel=s.quality,
                                          minDistance=s.min_distance, mask=mask,
                                          blockSize=s.block_size, useHarrisDetector=True,
                                          k=s.harris_k)
        if corners is None:
            return
        for u, v in corners.reshape(-1, 2):
            live.append(len(tracks))
            tracks.append([k, [(float(u), float(v))]])

    replenish(prev, 0)
    if progress is not None:
        progress(1, n)
    frames = read_ahead(lambda j: run.image(j + 1), n - 1)
    for k, frame in enumerate(frames, start=1):
        image = grey(frame)
        if image.shape != prev.shape:
            raise InvalidParameterError(
                f"frame {k} is {image.shape[1]}x{image.shape[0]}; frame 0 is {w}x{h}")
        if live:
            p0 = np.array([tracks[t][1][-1] for t in live], dtype=np.float32).reshape(-1, 1, 2)
            # OpenCV's stubs make nextPts required; its documentation (and these calls) pass
            # None for 'start from prevPts'.
            p1, st1, _ = cv2.calcOpticalFlowPyrLK(prev, image, p0, None, **lk)  # type: ignore[call-overload]
            source, start_pts = prev, p0
            if s.prewarp:
                source, start_pts, p1, st1 = _prewarped(prev, image, p0, p1, st1, lk)
            p0b, st2, _ = cv2.calcOpticalFlowPyrLK(image, source, p1, None, **lk)  # type: ignore[call-overload]
            fb = np.linalg.norm((p0b - start_pts).reshape(-1, 2), axis=1)
            q = p1.reshape(-1, 2)
            inside = ((q[:, 0] >= s.border) & (q[:, 0] <= w - 1 - s.border)
                      & (q[:, 1] >= s.border) & (q[:, 1] <= h - 1 - s.border))
            ok = (st1.reshape(-1) == 1) & (st2.reshape(-1) == 1) & (fb <= s.fb_threshold) \
                & inside & np.isfinite(q).all(axis=1)
            kept = []
            for t, good, (u, v) in zip(live, ok, q, strict=True):
                if good:
                    tracks[t][1].append((float(u), float(v)))
                    kept.append(t)
            live[:] = kept
        replenish(image, k)
        prev = image
        if progress is not None:
            progress(k + 1, n)
    memory.require(len(tracks) * n * float(TRACK_BYTES_PER_OBSERVATION),
                   f"{len(tracks):,} tracks over {n} frames")
    positions = np.full((len(tracks), n, 2), np.nan, dtype=np.float32)
    start = np.zeros(len(tracks), dtype=np.int64)
    stop = np.zeros(len(tracks), dtype=np.int64)
    for i, (k0, pts) in enumerate(tracks):
        positions[i, k0:k0 + len(pts)] = pts
        start[i] = k0
        stop[i] = k0 + len(pts) - 1
    log.info("tracked %d features through %d frames", len(tracks), n)
    return Tracks(positions, start, stop, layer_change, (h, w), s)


def near_dark(image: np.ndarray, level: int, margin: int, min_area: int) -> np.ndarray:
    """Pixels within ``margin`` of a region without signal (see :class:`TrackerSettings`).

    Parameters
    ----------
    image : (h, w) uint8, grey levels
        A frame as the tracker sees it.
    level : int, grey levels
        Pixels at most this far above the frame's darkest have no signal.
    margin : int, pixels
        Distance (Euclidean) from such a region that counts as near it.
    min_area : int, pixels
        Smallest region (8-connected) that counts: smaller dark spots (a boulder's shadow, a
        pit) are surface detail, good to track.

    Returns
    -------
    (h, w) bool
        True within ``margin`` of a region without signal (and on it).

    Examples
    --------
    >>> img = np.full((40, 40), 120, np.uint8)
    >>> img[:, :10] = 0  # sky to the left
    >>> img[30, 30] = 0  # a dark speck on the surface
    >>> near = near_dark(img, 2, 5, 25)
    >>> bool(near[20, 14]), bool(near[20, 16]), bool(near[30, 30])
    (True, False, False)
    """
    import cv2

    img = np.asarray(image)
    if img.ndim != 2 or img.dtype != np.uint8:
        raise InvalidParameterError(f"near_dark needs an (h, w) uint8 image; got {img.shape} "
                                    f"{img.dtype}")
    from evaluation.warpkernels import label_mask

    # 1 at and below the frame's darkest level + level (OpenCV's threshold: the same 0/1)
    _, dark = cv2.threshold(img, int(img.min()) + level, 1, cv2.THRESH_BINARY_INV)
    count, labels, stats, _ = cv2.connectedComponentsWithStats(dark, connectivity=8)
    big = np.flatnonzero(stats[:, cv2.CC_STAT_AREA] >= min_area)
    big = big[big > 0]  # label 0: the pixels with signal
    if not big.size or margin < 0:
        return np.zeros(img.shape, dtype=bool)
    if big.size == count - 1:
        region = dark  # every dark region counts
    else:
        lookup = np.zeros(count, dtype=np.uint8)  # a table by label: one gather per pixel
        lookup[big] = 1
        region = label_mask(labels, lookup)
    # within ``margin`` (Euclidean) of the region: the region grown by every integer offset
    # (dx, dy) with dx^2 + dy^2 <= margin^2: the same pixels as an exact Euclidean distance
    # transform's ``distance <= margin`` (cv2.DIST_MASK_PRECISE; a distance between pixels is
    # the root of an integer), at a fifth of its cost for the default margin
    reach = np.arange(-math.floor(margin), math.floor(margin) + 1)
    disk = (reach[:, None] ** 2 + reach[None, :] ** 2 <= margin * margin).astype(np.uint8)
    return cv2.dilate(region, disk).view(bool)  # 0 or 1, as the region; the border adds nothing


#: Fewest first-pass tracks from which a step's homography is estimated for prewarping.
PREWARP_MIN_TRACKS = 12
#: RANSAC inlier distance (pixels) of that homography.
PREWARP_RANSAC_PX = 2.0


def _prewarped(prev, image, p0, p1, st1, lk):
    """Return (source, start, p1, status) of a step tracked from a pre-warped frame.

    The previous frame warped by the step's homography, the points' positions in it, and
    Lucas-Kanade's answer from there (see ``prewarp``).
    """
    import cv2

    ok = (st1.reshape(-1) == 1) & np.isfinite(p1.reshape(-1, 2)).all(axis=1)
    if ok.sum() < PREWARP_MIN_TRACKS:
        return prev, p0, p1, st1
    hom, _ = cv2.findHomography(p0.reshape(-1, 2)[ok], p1.reshape(-1, 2)[ok], cv2.RANSAC,
                                PREWARP_RANSAC_PX)
    if hom is None or not np.all(np.isfinite(hom)):
        return prev, p0, p1, st1
    h, w = prev.shape
    source = cv2.warpPerspective(prev, hom, (w, h), flags=cv2.INTER_LINEAR,
                                 borderMode=cv2.BORDER_REPLICATE)
    start = cv2.perspectiveTransform(p0.astype(np.float64), hom).astype(np.float32)
    p1w, st, _ = cv2.calcOpticalFlowPyrLK(source, image, start, start.copy(),
                                          flags=cv2.OPTFLOW_USE_INITIAL_FLOW, **lk)
    return source, start, p1w, st


# ------------------------------------------------------------------------------ truth


def _sample_range(range_m: np.ndarray, uv: np.ndarray, tolerance: float) -> np.ndarray:
    """Range at fractional pixels: bilinear where the 4 returns agree, else nearest; NaN.

    The four returns agree when their spread is at most ``tolerance`` times the nearest of
    them; points outside the image (by more than half a pixel) get NaN. Compiled
    (:func:`evaluation.warpkernels.sample_range_points`).
    """
    from evaluation.warpkernels import sample_range_points

    uv = np.asarray(uv, dtype=np.float64)
    return sample_range_points(range_m, uv[:, 0], uv[:, 1], tolerance)


def truth_round_trip(run, *, step: int = 1, spacing: int = 8) -> float:
    """Median pixel error of a round trip through two frames' truth and range images.

    Pixels of frame k (every ``spacing`` pixels) are lifted with its range and pose,
    carried into the body frame and into frame k + ``step``, lifted again there with that
    frame's range, and projected back into frame k; about 8 frame pairs spread over the run
    are used. Rendering and truth agree exactly when this is zero: it shows tracking errors
    are the tracker's, not the ground truth's.

    Parameters
    ----------
    run : RunReader
        A rendered run with range images (:func:`load_run`).
    step : int, optional
        Frames between the two ends of a round trip.
    spacing : int, optional
        Pixel spacing of the lifted grid.

    Returns
    -------
    float
        Median round-trip error (pixels); NaN when no pixel made the round trip.
    """
    errors = []
    for k in range(0, len(run) - step, max(1, (len(run) - step) // 8)):
        a, b = run.truth[k], run.truth[k + step]
        ra = run.range(k)
        if ra is None:
            raise InvalidParameterError(f"frame {k} of the run has no range image; the truth "
                                        "round trip needs [output] range = true")
        v, u = np.mgrid[spacing // 2:ra.shape[0]:spacing, spacing // 2:ra.shape[1]:spacing]
        uv = np.stack([u.ravel(), v.ravel()], 1).astype(np.float64)
        r = ra[v.ravel(), u.ravel()]
        ok = np.isfinite(r) & (r > 0)
        body = a.pose.unproject(uv[ok], r[ok], a.intrinsics) @ quat_to_matrix(a.body_rotation)
        world = body @ quat_to_matrix(b.body_rotation).T
        uv2 = b.pose.project(world, b.intrinsics)
        seen = _sample_range(run.range(k + step), uv2, 0.02)
        dist = np.linalg.norm(world - np.asarray(b.pose.position), axis=1)
        with np.errstate(invalid="ignore"):
            good = np.isfinite(seen) & (np.abs(seen - dist) < 0.001 * dist)
        back = (b.pose.unproject(uv2[good], seen[good], b.intrinsics)
                @ quat_to_matrix(b.body_rotation) @ quat_to_matrix(a.body_rotation).T)
        errors.append(np.linalg.norm(a.pose.project(back, a.intrinsics) - uv[ok][good],
                                     axis=1))
    values = np.concatenate(errors) if errors else np.zeros(0)
    return float(np.median(values)) if values.size else float("nan")


def _near_silhouette(range_m: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """(n,) bool: pixels within SILHOUETTE_PX of no return or of an occluding contour."""
    h, w = range_m.shape
    near = near_contours(range_m, SILHOUETTE_PX, SILHOUETTE_JUMP)
    cols = np.clip(np.rint(uv[:, 0]).astype(np.int64), 0, w - 1)
    rows = np.clip(np.rint(uv[:, 1]).astype(np.int64), 0, h - 1)
    return near[rows, cols]


def median_by_age(values: np.ndarray, age: np.ndarray) -> list:
    """Return ``[age, median, count]`` of the finite values of each track age from 1 up.

    Parameters
    ----------
    values : (n_tracks, n_frames) float64
        NaN where there is nothing.
    age : (n_tracks, n_frames) int
        Frames since each track started.

    Returns
    -------
    list of [int, float, int]
        One row per age that has a finite value, ages in increasing order.

    Examples
    --------
    >>> median_by_age(np.array([[np.nan, 1.0, 3.0], [np.nan, 2.0, np.nan]]),
    ...               np.array([[0, 1, 2], [0, 1, 2]]))
    [[1, 1.5, 2], [2, 3.0, 1]]
    """
    ok = np.isfinite(values) & (age >= 1)
    ages = age[ok]
    vals = values[ok]
    # grouped by one stable sort; a median does not depend on the order of its values
    order = np.argsort(ages, kind="stable")
    ages, vals = ages[order], vals[order]
    found, starts, counts = np.unique(ages, return_index=True, return_counts=True)
    return [[int(a), float(np.median(vals[i:i + n])), int(n)]
            for a, i, n in zip(found, starts, counts, strict=True)]


@dataclass(frozen=True, eq=False)
class ScoredTracks:
    """Tracks with their error against the truth (see :func:`score`).

    Parameters
    ----------
    tracks : Tracks
    errors : (n_tracks, n_frames) float64, pixels, or None
        Distance of the tracked position from the true one; NaN where not scored (the first
        frame, not tracked, hidden, outside, or unliftable). None without truth.
    predicted : (n_tracks, n_frames, 2) float64, pixels, or None
        True positions.
    counts : dict
        ``scored``, ``hidden``, ``outside``, ``unlifted_tracks``, ``silhouette_tracks``.
    outlier_px : float
    notes : list of str
        Why metrics are missing, if they are.
    silhouette : (n_tracks,) bool or None
        Tracks that start on a silhouette (module docstring).
    one_step : (n_tracks, n_frames) float64, pixels, or None
        One-step error: the distance of the tracked position at frame k from where the
        truth carries the *tracked* position at frame k-1 (module docstring). NaN where not
        scored.
    """

    tracks: Tracks
    errors: np.ndarray | None
    predicted: np.ndarray | None
    counts: dict = field(default_factory=dict)
    outlier_px: float = 2.0
    notes: list = field(default_factory=list)
    silhouette: np.ndarray | None = None
    one_step: np.ndarray | None = None

    @property
    def has_errors(self) -> bool:
        """Whether the tracks were scored against ground truth."""
        return self.errors is not None

    def error_values(self) -> np.ndarray:
        """(k,) float64: every scored observation's error, pixels."""
        if self.errors is None:
            return np.zeros(0)
        return self.errors[np.isfinite(self.errors)]

    def error_summary(self) -> dict | None:
        """Median, mean, quantiles, max and outlier fraction of the errors (None: no truth)."""
        if self.errors is None:
            return None
        e = self.error_values()
        out = dict(observations=int(e.size), outlier_px=self.outlier_px, **self.counts)
        if e.size == 0:
            out.update(median_px=None, mean_px=None, max_px=None, outlier_fraction=None)
            return out
        out.update(median_px=float(np.median(e)), mean_px=float(e.mean()),
                   max_px=float(e.max()), outlier_fraction=float((e > self.outlier_px).mean()))
        for q in ERROR_QUANTILES[1:]:
            out[f"p{round(q * 100):d}_px"] = float(np.quantile(e, q))
        age = np.arange(self.tracks.n_frames)[None, :] - self.tracks.start[:, None]
        out["median_px_by_track_age"] = median_by_age(self.errors, age)
        if self.one_step is not None:
            one = self.one_step[np.isfinite(self.one_step)]
            out["one_step"] = dict(
                observations=int(one.size),
                median_px=float(np.median(one)) if one.size else None,
                mean_px=float(one.mean()) if one.size else None,
                p90_px=float(np.quantile(one, 0.9)) if one.size else None,
                outlier_fraction=(float((one > self.outlier_px).mean()) if one.size
                                  else None))
            out["one_step_median_px_by_track_age"] = median_by_age(self.one_step, age)
            if self.silhouette is not None:
                surface = self.one_step[~self.silhouette]
                surface = surface[np.isfinite(surface)]
                out["one_step"]["surface_median_px"] = (float(np.median(surface))
                                                        if surface.size else None)
        if self.silhouette is not None:
            surface = self.errors[~self.silhouette]
            surface = surface[np.isfinite(surface)]
            out["surface_tracks"] = dict(
                observations=int(surface.size),
                median_px=float(np.median(surface)) if surface.size else None,
                outlier_fraction=(float((surface > self.outlier_px).mean())
                                  if surface.size else None))
        return out

    def summary(self) -> dict:
        """Return the tracking and error summaries and the notes, as plain data."""
        return dict(tracking=self.tracks.summary(), errors=self.error_summary(),
                    notes=list(self.notes))


def score(tracks: Tracks, run, *, outlier_px: float = 2.0,
          occlusion_tolerance: float = 0.02) -> ScoredTracks:
    """Score tracks against the run's truth (see the module docstring).

    Parameters
    ----------
    tracks : Tracks
    run : RunReader or path
    outlier_px : float, pixels
        Errors above this are outliers.
    occlusion_tolerance : float
        Fraction of the range by which a point may lie behind the rendered surface and still
        count as visible (also the agreement needed to interpolate range bilinearly).

    Returns
    -------
    ScoredTracks
        ``errors`` is None (with a note and a warning) when the run has no truth or no range
        images.
    """
    if not isinstance(run, RunReader):
        run = RunReader(run)
    if not (outlier_px > 0 and occlusion_tolerance > 0):
        raise InvalidParameterError(
            f"outlier_px and occlusion_tolerance must be positive; got {outlier_px}, "
            f"{occlusion_tolerance}")
    if len(run) != tracks.n_frames:
        raise InvalidParameterError(
            f"the tracks cover {tracks.n_frames} frames; the run has {len(run)}")
    if not run.has_truth:
        note = (f"run directory '{run.dir}' has no truth.json: tracks are measured, but "
                "tracking errors against truth are omitted")
        log.warning(note)
        return ScoredTracks(tracks, None, None, {}, float(outlier_px), [note])
    if any(t.range is None for t in run.truth):
        note = (f"run directory '{run.dir}' has frames without range images: features cannot "
                "be lifted to 3-D, so tracking errors against truth are omitted")
        log.warning(note)
        return ScoredTracks(tracks, None, None, {}, float(outlier_px), [note])
    n = tracks.n_frames
    truth = run.truth
    h, w = tracks.shape
    memory.require(tracks.n_tracks * n * float(TRACK_BYTES_PER_OBSERVATION),
                   f"scoring {tracks.n_tracks:,} tracks over {n} frames")
    for k, t in enumerate(truth):
        if (t.intrinsics.height, t.intrinsics.width) != (h, w):
            raise InvalidParameterError(
                f"frame {k}'s truth says {t.intrinsics.width}x{t.intrinsics.height} pixels; "
                f"its image is {w}x{h}")
    # one pass over the frames, each range image read once: lift the tracks born at frame
    # k (into the body frame), score those born before it, and take each step's one-step error
    body = np.full((tracks.n_tracks, 3), np.nan)
    silhouette = np.zeros(tracks.n_tracks, dtype=bool)
    errors = np.full((tracks.n_tracks, n), np.nan)
    predicted = np.full((tracks.n_tracks, n, 2), np.nan)
    one_step = np.full((tracks.n_tracks, n), np.nan)
    hidden = outside = 0
    alive = tracks.alive()
    prev = None
    for k, range_m in enumerate(read_ahead(run.range, n)):
        t = truth[k]
        sel = np.flatnonzero(tracks.start == k)
        if sel.size:
            uv = tracks.positions[sel, k].astype(np.float64)
            silhouette[sel] = _near_silhouette(range_m, uv)
            r = _sample_range(range_m, uv, occlusion_tolerance)
            ok = np.isfinite(r)
            if ok.any():
                world = t.pose.unproject(uv[ok], r[ok], t.intrinsics)
                body[sel[ok]] = world @ quat_to_matrix(t.body_rotation)  # R_WB^T p_W
        if prev is not None and range_m is not None:  # every frame has range (checked above)
            _one_step_at(tracks, run, k, alive, prev, range_m, occlusion_tolerance, one_step)
        prev = range_m
        # tracks born before frame k were lifted at their first frame, earlier in this pass
        sel = np.flatnonzero(alive[:, k] & (tracks.start < k))
        sel = sel[np.isfinite(body[sel]).all(axis=1)]
        if sel.size == 0:
            continue
        world = body[sel] @ quat_to_matrix(t.body_rotation).T
        uv = t.pose.project(world, t.intrinsics)
        predicted[sel, k] = uv
        within = (np.isfinite(uv).all(axis=1) & (uv[:, 0] >= -0.5) & (uv[:, 0] <= w - 0.5)
                  & (uv[:, 1] >= -0.5) & (uv[:, 1] <= h - 0.5))
        outside += int((~within).sum())
        dist = np.linalg.norm(world - np.asarray(t.pose.position), axis=1)
        seen = _sample_range(range_m, uv, occlusion_tolerance)
        with np.errstate(invalid="ignore"):
            blocked = within & (~np.isfinite(seen)
                                | (seen < dist * (1.0 - occlusion_tolerance)))
        hidden += int(blocked.sum())
        good = within & ~blocked
        err = np.linalg.norm(tracks.positions[sel, k].astype(np.float64) - uv, axis=1)
        errors[sel[good], k] = err[good]
    lifted = np.isfinite(body).all(axis=1)
    counts = dict(scored=int(np.isfinite(errors).sum()), hidden=hidden, outside=outside,
                  unlifted_tracks=int((~lifted).sum()),
                  silhouette_tracks=int(silhouette.sum()))
    return ScoredTracks(tracks, errors, predicted, counts, float(outlier_px), [], silhouette,
                        one_step)


def _carry(run, k0: int, k1: int, uv: np.ndarray, range0: np.ndarray, range1: np.ndarray,
           tolerance: float) -> np.ndarray:
    """Return where the truth puts pixels ``uv`` of frame k0 in frame k1.

    NaN where a pixel is unliftable, hidden or outside.
    """
    a, b = run.truth[k0], run.truth[k1]
    h, w = range1.shape
    out = np.full((len(uv), 2), np.nan)
    r = _sample_range(range0, uv, tolerance)
    ok = np.flatnonzero(np.isfinite(r))
    if not ok.size:
        return out
    world = (a.pose.unproject(uv[ok], r[ok], a.intrinsics) @ quat_to_matrix(a.body_rotation)
             @ quat_to_matrix(b.body_rotation).T)
    q = b.pose.project(world, b.intrinsics)
    dist = np.linalg.norm(world - np.asarray(b.pose.position), axis=1)
    seen = _sample_range(range1, q, tolerance)
    with np.errstate(invalid="ignore"):
        good = (np.isfinite(q).all(axis=1) & (q[:, 0] >= -0.5) & (q[:, 0] <= w - 0.5)
                & (q[:, 1] >= -0.5) & (q[:, 1] <= h - 0.5) & np.isfinite(seen)
                & (seen >= dist * (1.0 - tolerance)))
    out[ok[good]] = q[good]
    return out


def read_ahead(load, n: int):
    """Yield ``load(0) .. load(n - 1)``, each next one loaded in a thread while the caller works.

    For passes over a run's frames: decoding PNGs and GeoTIFFs releases the GIL, so reading
    frame k+1 overlaps measuring frame k, and what is yielded is what ``load`` returns, in
    order.

    >>> list(read_ahead(lambda k: k * k, 4))
    [0, 1, 4, 9]
    """
    from concurrent.futures import ThreadPoolExecutor

    if n <= 0:
        return
    with ThreadPoolExecutor(max_workers=1) as reader:
        ahead = reader.submit(load, 0)
        for k in range(n):
            value = ahead.result()
            if k + 1 < n:
                ahead = reader.submit(load, k + 1)
            yield value


def _one_step_at(tracks: Tracks, run, k: int, alive: np.ndarray, prev: np.ndarray,
                 range_m: np.ndarray, tolerance: float, out: np.ndarray) -> None:
    """Fill ``out[:, k]`` with step k-1 -> k's one-step errors (see :class:`ScoredTracks`)."""
    sel = np.flatnonzero(alive[:, k] & alive[:, k - 1])
    if sel.size:
        q = _carry(run, k - 1, k, tracks.positions[sel, k - 1].astype(np.float64), prev,
                   range_m, tolerance)
        out[sel, k] = np.linalg.norm(tracks.positions[sel, k].astype(np.float64) - q, axis=1)


def truth_warped_frame(run, k0: int, k1: int, image0=None, image1=None) -> np.ndarray:
    """Frame k0 warped through the truth into frame k1's view (same dtype as the frames).

    Every pixel of frame k1 with a range return is lifted with frame k1's range and pose,
    carried into frame k0 (body rotation included) and, where frame k0 sees that point,
    takes frame k0's brightness there (bilinear); other pixels keep frame k1's own. The
    result shows frame k1's geometry with frame k0's pixels: what a perfectly consistent
    renderer (and a sensor without fresh noise) would deliver.
    """
    import cv2

    img0 = run.image(k0) if image0 is None else image0
    img1 = run.image(k1) if image1 is None else image1
    range0, range1 = run.range(k0), run.range(k1)
    if range0 is None or range1 is None:
        raise InvalidParameterError("truth-warped frames need range images")
    from evaluation.consistency import camera_affine
    from evaluation.warpkernels import truth_warp_rows

    # what _carry does for every pixel of frame k1 at once (at a pixel centre the range
    # sampled is the pixel's own): lift, carry into frame k0, keep what frame k0 sees; one
    # compiled pass per pixel (camera_map's carry, then _sample_range's sample of range0)
    x, y, a, t = camera_affine(range1.shape, run.truth[k1], run.truth[k0])
    k0_in = run.truth[k0].intrinsics
    mu, mv, okm = truth_warp_rows(range1, x, y, a, t, k0_in.fx, k0_in.fy, k0_in.cx, k0_in.cy,
                                  range0, tolerance=0.002)
    src = img0.astype(np.float32)
    warped = cv2.remap(src, mu, mv, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    if src.ndim == 3:
        okm = okm[:, :, None]
    out = np.where(okm, warped, img1.astype(np.float32))
    return np.clip(np.rint(out), 0, np.iinfo(img1.dtype).max).astype(img1.dtype)


#: Random stream of the fresh sensor noise :func:`ideal_one_step` may add.
STREAM_IDEAL_NOISE = "ideal-tracker-noise"


def _fresh_noise(image: np.ndarray, sensor: dict, seed: int, frame: int) -> np.ndarray:
    """Return ``image`` with new shot and read noise of the run's sensor.

    The noise is keyed by seed, frame, column and row, and rounded and clipped as the sensor
    does (:func:`evaluation.warpkernels.noisy_rows`).
    """
    from evaluation.warpkernels import noisy_rows
    from terrain.core.rng import stream_id

    return noisy_rows(image, seed, stream_id(STREAM_IDEAL_NOISE), frame,
                      float(sensor.get("gain", 0.0)), float(sensor.get("read_noise", 0.0)))


def ideal_one_step(scored: ScoredTracks, run, *, sensor_noise: bool = False,
                   seed: int = 0) -> np.ndarray:
    """One-step errors of the same tracker on truth-warped frames (tracker's own share).

    For every step k-1 -> k, the tracker (the same Lucas-Kanade settings, from the same
    tracked positions at k-1) follows its features from frame k-1 into
    :func:`truth_warped_frame` (frame k-1 warped into frame k's view), and is scored as
    :attr:`ScoredTracks.one_step` is. The images then agree with the truth exactly, so the
    error left is the tracker's own (its motion model, interpolation and the warp's
    resampling); the rest of the real one-step error comes from the frames themselves
    (renderer inconsistency and fresh sensor noise).

    With ``sensor_noise``, the warped frame gets fresh shot and read noise of the run's
    sensor (its manifest's ``sensor`` record; keyed by ``seed``, frame, column and row), as a
    new exposure would: the error is then the tracker's and the noise's, and what the real
    frames add beyond it is how the images themselves change (the renderer, and the shading
    that truly changes with the view and, on a spinning body, the sun).

    Returns
    -------
    (n_tracks, n_frames) float64, pixels; NaN where the real one-step error is NaN or the
    tracker lost the point.
    """
    return ideal_one_steps(scored, run, noises=(seed if sensor_noise else None,))[0]


def ideal_one_steps(scored: ScoredTracks, run, *, noises: tuple[int | None, ...] = (None,),
                    every: int = 1) -> list[np.ndarray]:
    """:func:`ideal_one_step` for several noise settings, each truth-warped frame made once.

    Parameters
    ----------
    scored : ScoredTracks
        Tracks scored against truth.
    run : RunReader or path
        The run.
    noises : tuple of (int or None)
        Per result: None for the warped frames as they are, or the seed of their fresh
        sensor noise.
    every : int, optional
        Measure only the steps k-1 -> k whose k is a multiple of ``every`` (the others are
        NaN); a measured step's errors are those ``every=1`` gives.

    Returns
    -------
    list of (n_tracks, n_frames) float64, pixels
        One per entry of ``noises``, each what :func:`ideal_one_step` returns.
    """
    every = int(every)
    if every < 1:
        raise InvalidParameterError(f"every must be a positive number of steps; got {every}")
    import cv2

    if scored.one_step is None:
        raise InvalidParameterError("the tracks were scored without truth: no one-step error")
    if not isinstance(run, RunReader):
        run = RunReader(run)
    tracks = scored.tracks
    s = tracks.settings
    sensor = run.manifest.get("sensor") or {}
    if any(seed is not None for seed in noises) and not sensor:
        raise InvalidParameterError(
            f"run directory '{run.dir}' records no sensor: no noise to add to ideal frames")
    lk = dict(winSize=(s.win_size, s.win_size), maxLevel=s.levels,
              criteria=(cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 0.01))
    grey = _Grey()
    outs = [np.full((tracks.n_tracks, tracks.n_frames), np.nan) for _ in noises]
    def load(k):  # the frame and its range (kept by the reader for the warp)
        run.range(k)
        return run.image(k)

    frames = read_ahead(load, tracks.n_frames)
    prev_img = next(frames)
    grey(prev_img)  # the sequence's scale comes from frame 0, as in track()
    for k, img in enumerate(frames, start=1):
        sel = np.flatnonzero(np.isfinite(scored.one_step[:, k]))
        if sel.size and k % every == 0:
            warped = truth_warped_frame(run, k - 1, k, prev_img, img)
            p0 = tracks.positions[sel, k - 1].astype(np.float32).reshape(-1, 1, 2)
            p0_64 = p0.reshape(-1, 2).astype(np.float64)
            q = _carry(run, k - 1, k, p0_64, run.range(k - 1), run.range(k), 0.02)
            a = grey(prev_img)
            for out, seed in zip(outs, noises, strict=True):
                ideal = warped if seed is None else _fresh_noise(warped, sensor, seed, k)
                b = grey(ideal)
                # nextPts None: see track() on OpenCV's stubs
                p1, st, _ = cv2.calcOpticalFlowPyrLK(a, b, p0, None, **lk)  # type: ignore[call-overload]
                if s.prewarp:  # the same tracker: its homography from these tracks
                    _, _, p1, st = _prewarped(a, b, p0, p1, st, lk)
                err = np.linalg.norm(p1.reshape(-1, 2).astype(np.float64) - q, axis=1)
                err[st.reshape(-1) != 1] = np.nan
                out[sel, k] = err
        prev_img = img
    return outs


def save_tracks(scored: ScoredTracks, run, folder, *, inputs=(),
                drawn: dict | None = None) -> dict:
    """Write a scored run's tracks where a user looks for them, each file atomically.

    ``tracks.csv`` (one row per observation: track, frame, tracked u/v and, with truth, the
    true u/v and the error, all in pixels), ``tracking.json`` (:meth:`ScoredTracks.summary`),
    ``tracks.png`` (the tracks over the last frame) and, with errors, ``tracking_error.png``.
    ``inputs`` are files none of these may replace. Returns the summary. The figures' PNG
    bytes go to ``drawn`` when it is a dict (:func:`evaluation.figures.drawn_once`), for a
    report that shows them too.
    """
    import csv
    import io
    import json
    from pathlib import Path

    from evaluation.figures import drawn_once, error_figure, save_png, tracks_figure
    from terrain.core.outputs import atomic_path

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    tracks = scored.tracks
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    header = ["track", "frame", "u_px", "v_px"]
    if scored.predicted is not None:
        header += ["true_u_px", "true_v_px", "error_px"]
    writer.writerow(header)
    predicted, errors = scored.predicted, scored.errors
    for i in range(tracks.n_tracks):
        # a track's life as Python floats at once (the same values; no NumPy scalar a cell)
        first, last = int(tracks.start[i]), int(tracks.stop[i]) + 1
        uv = tracks.positions[i, first:last].tolist()
        true_uv = err = None
        if predicted is not None and errors is not None:  # scored together
            true_uv = predicted[i, first:last].tolist()
            err = errors[i, first:last].tolist()
        for j, k in enumerate(range(first, last)):
            u, v = uv[j]
            row = [i, k, f"{u:.3f}", f"{v:.3f}"]
            if true_uv is not None and err is not None:
                tu, tv = true_uv[j]
                e = err[j]
                row += [f"{tu:.3f}" if math.isfinite(tu) else "",
                        f"{tv:.3f}" if math.isfinite(tv) else "",
                        f"{e:.4f}" if math.isfinite(e) else ""]
            writer.writerow(row)
    summary = scored.summary()
    for name, text in (("tracks.csv", buf.getvalue()),
                       ("tracking.json", json.dumps(summary, indent=1))):
        with atomic_path(folder / name, inputs) as tmp:
            tmp.write_text(text, encoding="utf-8")
    save_png(drawn_once(drawn, "tracks", lambda: tracks_figure(run.image(len(run) - 1), scored)),
             folder / "tracks.png", inputs=inputs)
    if scored.has_errors and scored.error_values().size:
        save_png(drawn_once(drawn, "tracking_error", lambda: error_figure(scored)),
                 folder / "tracking_error.png", inputs=inputs)
    return summary
