"""The run directory: rendered frames, range and normal images, and per-frame ground truth.

Layout (``craterscape render sequence`` writes it; :mod:`evaluation` reads it)::

    RUN_DIR/
      manifest.json         run-level facts: format, scene, frame count, resolution, seed
                            (a binary scene: its orbit and spins under "binary")
      scenario.toml         a copy of the scenario that produced the run
      truth.json            one entry per frame (below), rewritten atomically after each frame
      frames/frame_NNNNNN.png     camera image, 8- or 16-bit grey, linear in radiance
      range/range_NNNNNN.tif      LIDAR range (float32 metres along the ray; NaN = no return)
      normals/normals_NNNNNN.tif  surface normals (3 bands, float32, world frame; NaN = none)
      radiance/radiance_NNNNNN.tif  spectral radiance (float32, W m^-2 sr^-1 nm^-1), on request
      labels/...            image-space labels and the dataset exports, on request
                            (:mod:`render.labels`, :mod:`render.dataset`, docs/labels.md)
      bodies/bodies_NNNNNN.png    binary scenes: which body each pixel shows (uint8; 0 sky,
                                  1 primary, 2 secondary)

A truth entry::

    {"index": 0, "time": 0.0,
     "image": "frames/frame_000000.png", "range": "range/range_000000.tif",
     "normals": "normals/normals_000000.tif",
     "camera": {"position": [x, y, z], "attitude": [w, x, y, z]},
     "intrinsics": {"width": .., "height": .., "fx": .., "fy": .., "cx": .., "cy": ..},
     "sun": {"direction": [x, y, z]},            # unit vector towards the sun, world frame
            # a dated sun adds et, azimuth, elevation, distance_au and, on the Moon, earth,
            # earth_azimuth, earth_elevation, earth_km, earth_phase, earthshine
            # (render.ephemeris.Sky.as_dict)
     "exposure": {"auto": true, "exposure": .., "settled": ..},  # auto-exposed frames only
            # (exposure_time for a physical sensor; render.sensor.ExposureControl)
     "body_rotation": [w, x, y, z],              # R_WB; identity for terrain scenes
     "drawn": {...},                             # layers / patches / boulders drawn
     "motion": {"velocity": [..], "angular_velocity": [..], "body_angular_velocity": [..],
                "exposure_time": .., "line_time": .., "samples": ..},   # blurred frames only
     "labels": {"rims": "labels/rims_000000.json", ...}}   # labelled runs only
     "bodies": [{"id": 1, "name": "primary", "position": [x, y, z], "attitude": [w, x, y, z],
                 "reach": ..}, ...],             # binary scenes: each body's centre and R_WB
     "body_ids": "bodies/bodies_000000.png"}     # binary scenes

``time`` is when the exposure of the first row starts and ``camera`` the pose then. With
motion, :meth:`FrameTruth.pose_at` gives the pose at any time and :meth:`FrameTruth.row_pose`
the pose at a row's mid-exposure time (``time + row line_time + exposure_time / 2``), where a
rolling-shutter row images the scene (see :mod:`render.motion`). Range and normals of a blurred
frame are those at the frame time.

Frames and conventions are those of :mod:`render.camera`. Every file is written atomically,
so an interrupted run leaves complete frames and a truth file that lists exactly them. Reading
a truth file or a manifest back refuses a key this module does not write, naming it and the
nearest valid one (``drawn`` and the manifest's ``renderer`` are free-form records).
"""

from __future__ import annotations

import json
import shutil
import threading
from collections import OrderedDict
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from render.camera import Intrinsics, Pose
from terrain.core.checks import check_keys
from terrain.core.errors import InvalidParameterError, MissingInputError
from terrain.core.outputs import atomic_path
from terrain.io import read_float_tiff, read_float_tiff_pixel, write_float_tiff, write_png

__all__ = ["FORMAT", "FrameTruth", "RunReader", "RunWriter"]

FORMAT = "craterscape-render-run"
#: Keys of a truth entry and of its tables (what :meth:`FrameTruth.as_dict` writes).
TRUTH_KEYS = frozenset({"index", "time", "image", "range", "normals", "camera", "intrinsics",
                        "sun", "body_rotation", "drawn", "motion", "radiance", "exposure",
                        "labels", "bodies", "body_ids"})
TRUTH_TABLE_KEYS = {"camera": frozenset({"position", "attitude"}),
                    "intrinsics": frozenset({"width", "height", "fx", "fy", "cx", "cy"}),
                    "sun": frozenset({"direction", "et", "azimuth", "elevation", "distance_au",
                                      "earth", "earth_azimuth", "earth_elevation", "earth_km",
                                      "earth_phase", "earthshine"}),
                    "exposure": frozenset({"auto", "exposure", "exposure_time", "settled",
                                           "percentile", "fraction", "rate"}),
                    "labels": frozenset({"rims", "instances", "semantic", "hazard", "flow",
                                         "occlusion"}),
                    "motion": frozenset({"velocity", "angular_velocity",
                                         "body_angular_velocity", "exposure_time", "line_time",
                                         "samples"})}
#: Keys of a run's manifest (what :func:`render.sequence.run_sequence` and :class:`RunWriter`
#: write), and of its lighting table.
MANIFEST_KEYS = frozenset({"format", "version", "scenario", "scene", "frames", "resolution",
                           "seed", "sensor", "lighting", "renderer", "render_seconds",
                           "frames_rendered_this_run", "frames_written", "events", "labels",
                           "binary"})
MANIFEST_LIGHTING_KEYS = frozenset({"sun", "albedo", "reflectance", "hapke", "distance_au",
                                    "spectral_irradiance", "utc"})


def check_manifest(manifest, where: str) -> dict:
    """Return a run manifest read back, or refuse an unknown key naming the nearest valid one.

    >>> check_manifest({"format": FORMAT, "seed": 1}, "manifest.json")["seed"]
    1
    """
    from render.sensor import Sensor

    m = check_keys(manifest, MANIFEST_KEYS, where)
    if isinstance(m.get("lighting"), dict):
        check_keys(m["lighting"], MANIFEST_LIGHTING_KEYS, f"{where} lighting")
    if isinstance(m.get("sensor"), dict):
        check_keys(m["sensor"], set(Sensor.__dataclass_fields__), f"{where} sensor")
    return m


@dataclass(frozen=True)
class FrameTruth:
    """Ground truth of one frame (see the module docstring)."""

    index: int
    time: float
    pose: Pose
    intrinsics: Intrinsics
    sun: tuple
    body_rotation: tuple = (1.0, 0.0, 0.0, 0.0)
    drawn: dict = field(default_factory=dict)
    image: str | None = None
    range: str | None = None
    normals: str | None = None
    motion: dict | None = None
    radiance: str | None = None
    sky: dict | None = None
    exposure: dict | None = None
    labels: dict | None = None
    bodies: list | None = None
    body_ids: str | None = None

    def as_dict(self) -> dict:
        """Return the frame's truth as plain data for the run's truth file."""
        d = dict(index=self.index, time=self.time, image=self.image, range=self.range,
                 normals=self.normals, camera=self.pose.as_dict(),
                 intrinsics=self.intrinsics.as_dict(),
                 sun={"direction": list(self.sun), **(self.sky or {})},
                 body_rotation=list(self.body_rotation), drawn=self.drawn)
        if self.exposure is not None:
            d["exposure"] = self.exposure
        if self.motion is not None:
            d["motion"] = self.motion
        if self.radiance is not None:
            d["radiance"] = self.radiance
        if self.labels:
            d["labels"] = self.labels
        if self.bodies is not None:
            d["bodies"] = self.bodies
        if self.body_ids is not None:
            d["body_ids"] = self.body_ids
        return d

    def pose_at(self, t: float) -> Pose:
        """Camera pose at time ``t`` (s, same clock as :attr:`time`)."""
        if not self.motion:
            return self.pose
        from render.motion import Motion

        m = Motion(self.motion["velocity"], self.motion["angular_velocity"])
        return m.pose_at(self.pose, t - self.time)

    def row_time(self, row) -> float:
        """Mid-exposure time of image row ``row`` (0 at the top)."""
        m = self.motion or {}
        return self.time + float(row) * m.get("line_time", 0.0) \
            + 0.5 * m.get("exposure_time", 0.0)

    def row_pose(self, row) -> Pose:
        """Camera pose at row ``row``'s mid-exposure time (rolling-shutter truth per row)."""
        return self.pose_at(self.row_time(row))

    @classmethod
    def from_dict(cls, d: dict, where: str = "truth entry") -> FrameTruth:
        """Build the frame's truth from what :meth:`as_dict` wrote.

        A key it does not write is refused by name (``where`` says which file and entry).
        """
        d = check_keys(d, TRUTH_KEYS, where)
        for key, allowed in TRUTH_TABLE_KEYS.items():
            if d.get(key) is not None:
                check_keys(d[key], allowed, f"{where} {key}")
        sky = {k: v for k, v in d["sun"].items() if k != "direction"}
        return cls(int(d["index"]), float(d.get("time", 0.0)),
                   Pose(tuple(d["camera"]["position"]), tuple(d["camera"]["attitude"])),
                   Intrinsics(**d["intrinsics"]), tuple(d["sun"]["direction"]),
                   tuple(d.get("body_rotation", (1.0, 0.0, 0.0, 0.0))), d.get("drawn", {}),
                   d.get("image"), d.get("range"), d.get("normals"), d.get("motion"),
                   d.get("radiance"), sky or None, d.get("exposure"), d.get("labels"),
                   d.get("bodies"), d.get("body_ids"))


#: Manifest facts a resumed run must share with the interrupted one.
RESUME_KEYS = ("scenario", "scene", "frames", "resolution", "seed")


class RunWriter:
    """Writes a run directory frame by frame.

    ``resume`` continues an interrupted run: only a run directory (its manifest says so) of
    the same scenario, frame count, resolution and seed is taken; temporaries the
    interrupted run left are removed.
    """

    @staticmethod
    def check(run_dir, *, resume: bool = False, manifest: dict | None = None) -> None:
        """Refuse an unusable run directory before any work (see the class docstring)."""
        from terrain.core.outputs import check_output_folder

        run_dir = Path(run_dir)
        if run_dir.exists() and not run_dir.is_dir():
            raise InvalidParameterError(f"run directory '{run_dir}' exists and is a file")
        check_output_folder(run_dir)
        if not (run_dir.exists() and any(run_dir.iterdir())):
            return
        if not resume:
            raise InvalidParameterError(
                f"run directory '{run_dir}' is not empty; choose a new one (or resume)")
        mpath = run_dir / "manifest.json"
        try:
            old = json.loads(mpath.read_text(encoding="utf-8"))
            if not isinstance(old, dict) or old.get("format") != FORMAT:
                raise ValueError
        except (OSError, ValueError, RecursionError):
            raise InvalidParameterError(
                f"'{run_dir}' is not a craterscape run directory (no run manifest.json); "
                "--resume continues an interrupted render only") from None
        check_manifest(old, f"run manifest '{mpath}'")
        if manifest is not None:
            for key in RESUME_KEYS:
                if key in manifest and old.get(key) != json.loads(json.dumps(manifest[key])):
                    raise InvalidParameterError(
                        f"run directory '{run_dir}' was rendered with {key} "
                        f"{old.get(key)!r}, not {manifest[key]!r}; resume with the same "
                        "scenario or choose a new folder")

    def __init__(self, run_dir, manifest: dict, scenario_file=None, *, resume: bool = False):
        from terrain.core.outputs import sweep_partials

        self.dir = Path(run_dir)
        # what is written must read back: refuse an unknown key before making anything
        written = check_manifest(dict(manifest, format=FORMAT, version=1), "run manifest")
        self.check(self.dir, resume=resume, manifest=manifest)
        existing = self.dir / "truth.json"
        self.frames: list[dict] = []
        if self.dir.exists() and any(self.dir.iterdir()):
            sweep_partials(self.dir, recursive=True)
            if existing.exists():
                try:
                    self.frames = json.loads(existing.read_text(encoding="utf-8"))
                    frames_ok = isinstance(self.frames, list) and all(
                        isinstance(f, dict) and "index" in f for f in self.frames)
                except (ValueError, RecursionError):
                    frames_ok = False
                if not frames_ok:
                    raise InvalidParameterError(f"truth file '{existing}' is corrupt; cannot "
                                                "resume this run")
                for i, f in enumerate(self.frames):
                    try:
                        FrameTruth.from_dict(f, f"truth file '{existing}' entry {i}")
                    except InvalidParameterError:
                        raise
                    except (ValueError, KeyError, TypeError) as exc:
                        raise InvalidParameterError(f"truth file '{existing}' is corrupt: "
                                                    f"{exc}; cannot resume this run") from None
        for sub in ("frames", "range", "normals"):
            (self.dir / sub).mkdir(parents=True, exist_ok=True)
        self.manifest = written
        if scenario_file is not None and not (self.dir / "scenario.toml").exists():
            with atomic_path(self.dir / "scenario.toml") as tmp:
                shutil.copyfile(scenario_file, tmp)
        self._write_manifest()

    def done(self) -> set[int]:
        """Return indices of frames already written (for resuming)."""
        return {int(f["index"]) for f in self.frames}

    def exposure_before(self, index: int) -> dict | None:
        """Return the auto-exposure record of the written frame just before ``index``."""
        before = [f for f in self.frames if int(f["index"]) == index - 1]
        return before[0].get("exposure") if before else None

    def write_frame(self, truth: FrameTruth, image: np.ndarray, range_m: np.ndarray | None,
                    normals: np.ndarray | None, radiance: np.ndarray | None = None, *,
                    body_ids: np.ndarray | None = None) -> None:
        """Write one frame's image and truth rasters and record the frame in ``truth.json``."""
        i = truth.index
        names = dict(image=f"frames/frame_{i:06d}.png")
        write_png(image, self.dir / names["image"])
        if range_m is not None:
            names["range"] = f"range/range_{i:06d}.tif"
            write_float_tiff(range_m, self.dir / names["range"], tags={"UNITS": "metre"})
        if normals is not None:
            names["normals"] = f"normals/normals_{i:06d}.tif"
            write_float_tiff(normals, self.dir / names["normals"],
                             tags={"FRAME": "world", "BANDS": "nx,ny,nz"})
        if radiance is not None:
            names["radiance"] = f"radiance/radiance_{i:06d}.tif"
            (self.dir / "radiance").mkdir(exist_ok=True)
            write_float_tiff(radiance, self.dir / names["radiance"],
                             tags={"UNITS": "W m-2 sr-1 nm-1"})
        if body_ids is not None:
            names["body_ids"] = f"bodies/bodies_{i:06d}.png"
            (self.dir / "bodies").mkdir(exist_ok=True)
            write_png(np.asarray(body_ids, dtype=np.uint8), self.dir / names["body_ids"])
        entry = FrameTruth(truth.index, truth.time, truth.pose, truth.intrinsics, truth.sun,
                           truth.body_rotation, truth.drawn, names["image"],
                           names.get("range"), names.get("normals"), truth.motion,
                           names.get("radiance"), truth.sky, truth.exposure,
                           truth.labels, truth.bodies, names.get("body_ids")).as_dict()
        self.frames = [f for f in self.frames if int(f["index"]) != i] + [entry]
        self.frames.sort(key=lambda f: int(f["index"]))
        self._write_truth()

    def add_labels(self, index: int, names: dict) -> None:
        """Record label files (paths relative to the run directory) in a frame's truth entry.

        Parameters
        ----------
        index : int
            A frame already written.
        names : dict
            ``{"rims": .., "instances": .., ...}`` (:data:`TRUTH_TABLE_KEYS` ``labels``).
        """
        for f in self.frames:
            if int(f["index"]) == index:
                f["labels"] = dict(f.get("labels") or {}, **names)
        self._write_truth()

    def _write_truth(self) -> None:
        with atomic_path(self.dir / "truth.json") as tmp:
            tmp.write_text(json.dumps(self.frames, indent=1), encoding="utf-8")

    def finish(self, **facts) -> None:
        """Record the run's final facts in the manifest and write it."""
        self.manifest.update(facts, frames_written=len(self.frames))
        self._write_manifest()

    def _write_manifest(self):
        with atomic_path(self.dir / "manifest.json") as tmp:
            tmp.write_text(json.dumps(self.manifest, indent=2, sort_keys=True), encoding="utf-8")


#: Decoded range images a :class:`RunReader` keeps (the evaluation reads a frame's range
#: once for each pair it belongs to, and again in each pass over the run).
RANGE_CACHE = 4
#: Bytes of decoded frame images a :class:`RunReader` keeps, first read first kept, none
#: dropped: the evaluation passes over a run's frames twice in one process (the tracker, then
#: the tracker on truth-warped frames), and a 1024^2 8-bit frame costs about 20 ms to decode.
#: A run larger than this keeps its first frames and reads the rest each time.
IMAGE_KEEP_BYTES = 256 * 2**20


class RunReader:
    """Reads a run directory; frames without truth are allowed (``truth`` is then empty)."""

    def __init__(self, run_dir):
        self._ranges: OrderedDict[int, np.ndarray] = OrderedDict()
        self._lock = threading.Lock()
        self._images: dict[int, np.ndarray] = {}
        self._images_bytes = 0
        self.dir = Path(run_dir)
        if not self.dir.is_dir():
            raise MissingInputError(f"run directory '{self.dir}' does not exist")
        mpath = self.dir / "manifest.json"
        self.manifest: dict = {}
        if mpath.exists():
            try:
                self.manifest = json.loads(mpath.read_text(encoding="utf-8"))
            except (ValueError, RecursionError) as exc:
                raise InvalidParameterError(f"run manifest '{mpath}' is corrupt: {exc}") \
                    from None
            check_manifest(self.manifest, f"run manifest '{mpath}'")
        tpath = self.dir / "truth.json"
        self.truth: list[FrameTruth] = []
        if tpath.exists():
            try:
                entries = json.loads(tpath.read_text(encoding="utf-8"))
                if not isinstance(entries, list):
                    raise TypeError("not a list of frames")
                self.truth = [FrameTruth.from_dict(d, f"truth file '{tpath}' entry {i}")
                              for i, d in enumerate(entries)]
            except InvalidParameterError:
                raise
            except (ValueError, KeyError, TypeError, RecursionError) as exc:
                raise InvalidParameterError(f"truth file '{tpath}' is corrupt: {exc}") from None
        if self.truth:
            self.images = [self.dir / t.image for t in self.truth]
        else:
            self.images = sorted((self.dir / "frames").glob("frame_*.png"))
        if not self.images:
            raise MissingInputError(f"run directory '{self.dir}' holds no frames")

    @property
    def has_truth(self) -> bool:
        """Whether the run has ground truth for its frames."""
        return bool(self.truth)

    def __len__(self) -> int:
        return len(self.images)

    def image(self, k: int) -> np.ndarray:
        """Return frame ``k``'s image as stored (uint8 or uint16): the caller's own copy."""
        import cv2

        with self._lock:
            kept = self._images.get(k)
        if kept is not None:
            return kept.copy()
        img = cv2.imread(str(self.images[k]), cv2.IMREAD_UNCHANGED)
        if img is None:
            raise MissingInputError(f"cannot read frame '{self.images[k]}'")
        with self._lock:
            if k not in self._images and self._images_bytes + img.nbytes <= IMAGE_KEEP_BYTES:
                self._images[k] = img.copy()
                self._images_bytes += img.nbytes
        return img

    def range(self, k: int) -> np.ndarray | None:
        """Return frame ``k``'s range in metres, (h, w), or None without truth."""
        if not self.truth or not self.truth[k].range:
            return None
        with self._lock:
            cached = self._ranges.get(k)
            if cached is not None:
                self._ranges.move_to_end(k)
                return cached.copy()  # callers may change theirs
        a = read_float_tiff(self.dir / self.truth[k].range)
        with self._lock:
            self._ranges[k] = a.copy()
            while len(self._ranges) > RANGE_CACHE:
                self._ranges.popitem(last=False)
        return a

    def range_at(self, k: int, row: int, col: int) -> float | None:
        """Return frame ``k``'s range at one pixel (m), or None without truth.

        The value :meth:`range` holds there, read from the one tile that holds it.
        """
        if not self.truth or not self.truth[k].range:
            return None
        with self._lock:
            cached = self._ranges.get(k)
        if cached is not None:
            return float(cached[row, col])
        return float(read_float_tiff_pixel(self.dir / self.truth[k].range, row, col)[0])

    def body_ids(self, k: int) -> np.ndarray | None:
        """Return frame ``k``'s body-id image (uint8, 0 sky), or None where it has none."""
        if not self.truth or not self.truth[k].body_ids:
            return None
        import cv2

        img = cv2.imread(str(self.dir / self.truth[k].body_ids), cv2.IMREAD_UNCHANGED)
        if img is None:
            raise MissingInputError(f"cannot read body ids '{self.truth[k].body_ids}'")
        return img

    def normals(self, k: int) -> np.ndarray | None:
        """Return frame ``k``'s world-frame surface normals, (h, w, 3), or None without truth."""
        if not self.truth or not self.truth[k].normals:
            return None
        return read_float_tiff(self.dir / self.truth[k].normals)
