"""Scenario files: what to render, how, and along which trajectory (TOML).

A scenario names the scene, the sun, the surface, the camera and sensor, the outputs and the
trajectory. Paths are relative to the scenario file. Example (``examples/lunar_descent.toml``)::

    name = "lunar-descent"
    seed = 1

    [scene]
    type = "terrain"                 # or "asteroid"
    stack = "../demo-output/stack"   # a layer-stack folder (craterscape terrain enhance)
    curvature = true
    # asteroid scenes: body = "eros.npz", boulders = true
    # [scene.build]: the scene's recipe, built where the scene is missing
    # (render.scene_build: [scene.build.base] and [scene.build.stack], or [scene.build.body])

    [sun]
    azimuth = 90.0                   # degrees clockwise from north (terrain) ...
    elevation = 5.0                  # ... above the horizon; or direction = [x, y, z]
    distance = 1.0                   # the body's distance from the Sun (au)
    irradiance = 1.58                # solar spectral irradiance at 1 au (W m^-2 nm^-1)

    [surface]
    albedo = 0.12                    # Lambert, Lommel-Seeliger, lunar-Lambert (Hapke: w)
    reflectance = "lunar-lambert"    # "lambert", "lommel-seeliger", "lunar-lambert", "hapke"
    # albedo_map = "albedo.tif"      # terrain: a raster of albedo factors in the map frame;
                                     # asteroid: a .npy with one factor per body vertex
    # Hapke (reflectance = "hapke"): w, b, c, bs0, hs, bc0, hc, theta_bar (deg), phi;
    # defaults: Sato et al. 2014, LROC WAC 643 nm (render.reflectance.SATO_643NM)

    [camera]
    width = 1024
    height = 1024
    fov = 60.0                       # horizontal, degrees; or fx, fy, cx, cy

    [sensor]                         # I/F-calibrated (see render.sensor) ...
    bits = 8
    exposure = 5.0                   # DN full scale per unit I/F
    psf_sigma = 0.5                  # pixels
    gain = 20.0                      # electrons per DN (shot noise; 0 off)
    read_noise = 1.0                 # DN rms
    # ... or from a data sheet: exposure_time (s), aperture (m) or f_number and
    # pixel_pitch (um), transmission, qe, wavelength and bandwidth (nm), dark_current (e-/s;
    # temperature, dark_temperature, dark_doubling in C), natural_vignetting, transfer_time (s),
    # prnu, prnu_seed, shot_noise, read_noise (e-), full_well (e-), gain (e-/DN), bias (DN), bits,
    # psf = [[weight, sigma_px], ...] or psf_kernel = "file.npy", line_time (s, rolling)

    [motion]                         # optional: blur from motion during the exposure
    blur = true
    # velocity = [vx, vy, vz]        # m/s, world; default: from the trajectory
    # angular_velocity = [wx, wy, wz]  # rad/s, world; default: from the trajectory
    # samples = 0                    # sub-frames per exposure (0: automatic)

    [render]
    shadows = true
    shadow_size = 2048
    lod_pixels = 1.5
    triangle_budget = 3000000
    geomorph = true                  # levels of detail morph instead of switching
    antialias = 1                    # samples per pixel side (odd): radiance is their mean

    [output]
    range = true
    normals = true
    radiance = false                 # also radiance/radiance_NNNNNN.tif, W m^-2 sr^-1 nm^-1

    [trajectory]
    type = "descent"                 # "descent", "keyframes" or "approach"
    frames = 60
    duration = 120.0                 # s
    start_altitude = 10000.0         # m above the site
    end_altitude = 20.0
    ground_track = [3000.0, -2000.0] # start offset from the site (m)
    look = "site"                    # or "nadir"

Keyframes: ``[[trajectory.keyframe]]`` tables with ``time``, ``position`` and ``attitude``
(quaternion [w, x, y, z], R_WC) or ``look_at``. Approach (asteroids): ``start_distance``,
``end_distance``, ``direction``, and under ``[scene]`` ``spin_axis``, ``spin_period`` (s),
``spin_phase`` (degrees).
"""

from __future__ import annotations

import difflib
import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from render.camera import Intrinsics
from render.motion import Motion
from render.reflectance import Hapke, check_brdf
from render.renderer import MAX_ANTIALIAS, Lighting, RenderOptions
from render.scene_build import SceneBuild
from render.sensor import Sensor
from render.trajectory import Sample, approach, descent, keyframes
from terrain.core.errors import InvalidParameterError
from terrain.core.rng import check_seed
from terrain.core.tomlfile import read_toml

__all__ = ["SceneSpec", "Scenario", "TrajectorySpec", "load_scenario"]

_SECTIONS = {"name", "seed", "scene", "sun", "surface", "camera", "sensor", "render", "output",
             "trajectory", "description", "motion"}
_HAPKE_KEYS = set(Hapke.__dataclass_fields__)


def _section(data: dict, name: str, allowed: set[str]) -> dict:
    table = data.get(name, {})
    if not isinstance(table, dict):
        raise InvalidParameterError(f"scenario [{name}] must be a table")
    unknown = set(table) - allowed
    if unknown:
        key = sorted(unknown)[0]
        near = difflib.get_close_matches(key, sorted(allowed), n=1)
        raise InvalidParameterError(
            f"scenario [{name}] has unknown keys {sorted(unknown)}"
            + (f" (did you mean {near[0]!r}?)" if near else "")
            + f"; expected some of {sorted(allowed)}")
    return table


def _bool(table, key, default, where):
    v = table.get(key, default)
    if not isinstance(v, bool):
        raise InvalidParameterError(
            f"scenario {where}.{key} must be true or false (unquoted); got {v!r}")
    return v


def _int(table, key, default, where, minimum=None, maximum=None):
    v = table.get(key, default)
    if isinstance(v, bool) or not isinstance(v, int):
        raise InvalidParameterError(f"scenario {where}.{key} must be an integer; got {v!r}")
    if (minimum is not None and v < minimum) or (maximum is not None and v > maximum):
        raise InvalidParameterError(
            f"scenario {where}.{key} must lie in [{minimum}, {maximum}]; got {v}")
    return v


def _text(table, key, default, where):
    v = table.get(key, default)
    if not isinstance(v, str):
        raise InvalidParameterError(f"scenario {where}.{key} must be a string; got {v!r}")
    return v


def _vector(table, key, n, where):
    v = table.get(key)
    if (not isinstance(v, list) or len(v) != n
            or any(isinstance(x, bool) or not isinstance(x, (int, float)) for x in v)
            or not all(math.isfinite(x) for x in v)):
        raise InvalidParameterError(
            f"scenario {where}.{key} must be a list of {n} finite numbers; got {v!r}")
    return tuple(float(x) for x in v)


#: Largest image side a scenario may ask for (pixels).
MAX_IMAGE_SIDE = 32768


def _number(table, key, default, where, positive=False):
    v = table.get(key, default)
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise InvalidParameterError(f"scenario {where}.{key} must be a number; got {v!r}")
    v = float(v)
    if not math.isfinite(v) or (positive and v <= 0):
        raise InvalidParameterError(
            f"scenario {where}.{key} must be {'positive' if positive else 'finite'}; got {v}")
    return v


#: Bodies an asteroid scene is drawn as an imposter below, in pixels across.
DEFAULT_IMPOSTER_PIXELS = 24.0
#: Keys of a scenario's [scene] table.
SCENE_KEYS = frozenset({"type", "stack", "curvature", "radius", "body", "boulders", "spin_axis",
                        "spin_period", "spin_phase", "imposter_pixels", "build"})
#: Keys of a scenario's [trajectory] table.
TRAJECTORY_KEYS = frozenset({"type", "frames", "duration", "start_altitude", "end_altitude",
                             "ground_track", "look", "site", "keyframe", "start_distance",
                             "end_distance", "direction"})


@dataclass(frozen=True)
class SceneSpec:
    """A scenario's ``[scene]``: what to load, validated, with its defaults in one place.

    Parameters
    ----------
    type : {"terrain", "asteroid"}
    stack : str, optional
        Layer-stack folder (terrain), relative to the scenario file.
    body : str, optional
        Asteroid ``.npz`` (asteroid), relative to the scenario file.
    curvature : bool
        Terrain: bend the map onto the body's sphere.
    radius : float, optional
        Terrain: the body's radius (m); the stack's datum (or the Moon's) when None.
    boulders : bool
        Asteroid: draw the body's boulders.
    spin_axis : (3,) float
        Asteroid: spin axis, body frame.
    spin_period : float
        Asteroid: spin period (s); 0 for no spin.
    spin_phase : float
        Asteroid: spin phase at t = 0 (degrees).
    imposter_pixels : float
        Asteroid: below this apparent size (pixels) the body is drawn as an imposter.
    albedo_map : str, optional
        Albedo factors (``[surface] albedo_map``), relative to the scenario file.
    build : render.scene_build.SceneBuild, optional
        ``[scene.build]``: the recipe the scene is built from where it is missing
        (:func:`render.scene_build.ensure_scene`).
    """

    type: str
    stack: str | None = None
    body: str | None = None
    curvature: bool = True
    radius: float | None = None
    boulders: bool = True
    spin_axis: tuple[float, float, float] = (0.0, 0.0, 1.0)
    spin_period: float = 0.0
    spin_phase: float = 0.0
    imposter_pixels: float = DEFAULT_IMPOSTER_PIXELS
    albedo_map: str | None = None
    build: SceneBuild | None = None

    @classmethod
    def from_mapping(cls, table: dict) -> SceneSpec:
        """Build the record of a ``[scene]`` table; unknown keys are errors naming the nearest.

        Parameters
        ----------
        table : dict
            The TOML table (``albedo_map`` comes from ``[surface]``, set by the parser).

        Returns
        -------
        SceneSpec
        """
        scene = _section({"scene": table}, "scene", set(SCENE_KEYS))
        kind = scene.get("type")
        if kind not in ("terrain", "asteroid"):
            raise InvalidParameterError(
                f"scenario [scene] type must be 'terrain' or 'asteroid'; got {kind!r}")
        if kind == "terrain" and "stack" not in scene:
            raise InvalidParameterError("scenario [scene] needs 'stack' (a layer-stack folder)")
        if kind == "asteroid" and "body" not in scene:
            raise InvalidParameterError("scenario [scene] needs 'body' (an asteroid .npz)")
        values: dict = {"type": kind}
        for key in ("stack", "body"):
            if key in scene:
                values[key] = _text(scene, key, "", "scene")
                if Path(values[key]).name in ("", ".", ".."):  # "", "/", ".", "x/.."
                    what = "a layer-stack folder" if key == "stack" else "an asteroid .npz"
                    raise InvalidParameterError(
                        f"scenario [scene] {key} must name {what}, not a folder above it; "
                        f"got {values[key]!r}")
        for key in ("curvature", "boulders"):
            if key in scene:
                values[key] = _bool(scene, key, True, "scene")
        for key in ("spin_period", "spin_phase"):
            if key in scene:
                values[key] = _number(scene, key, 0.0, "scene")
        if "radius" in scene:
            values["radius"] = _number(scene, "radius", 1.0, "scene", positive=True)
        if "imposter_pixels" in scene:
            values["imposter_pixels"] = _number(scene, "imposter_pixels",
                                                DEFAULT_IMPOSTER_PIXELS, "scene", positive=True)
        if "spin_axis" in scene:
            values["spin_axis"] = _vector(scene, "spin_axis", 3, "scene")
        if "build" in scene:
            values["build"] = SceneBuild.from_mapping(scene["build"], kind)
        return cls(**values)

    def inputs(self) -> tuple[str, ...]:
        """List the files and folders the scene reads (relative to the scenario file).

        Returns
        -------
        tuple of str
        """
        return tuple(v for v in (self.stack, self.body) if v is not None)


@dataclass(frozen=True)
class TrajectorySpec:
    """A scenario's ``[trajectory]``, validated, with its defaults in one place.

    Parameters
    ----------
    type : {"descent", "keyframes", "approach"}
    frames : int
        Frames to render (>= 1).
    duration : float, optional
        Seconds from the first frame to the last; ``frames - 1`` when None.
    start_altitude, end_altitude : float, optional
        Descent: metres above the site (required for a descent).
    ground_track : (2,) float
        Descent: start offset from the site (m).
    look : {"site", "nadir"}
        Descent: where the camera looks.
    site : (2,) float, optional
        Descent: the site (map x, y); the stack's when None.
    keyframe : tuple of dict
        Keyframes: ``time``, ``position`` and ``attitude`` or ``look_at`` of each.
    start_distance, end_distance : float, optional
        Approach: metres from the body's centre (required for an approach).
    direction : (3,) float
        Approach: direction from the body to the camera, body frame.
    """

    type: str
    frames: int = 1
    duration: float | None = None
    start_altitude: float | None = None
    end_altitude: float | None = None
    ground_track: tuple[float, float] = (0.0, 0.0)
    look: str = "site"
    site: tuple[float, float] | None = None
    keyframe: tuple[dict, ...] = ()
    start_distance: float | None = None
    end_distance: float | None = None
    direction: tuple[float, float, float] = (1.0, 0.0, 0.0)

    @classmethod
    def from_mapping(cls, table: dict) -> TrajectorySpec:
        """Build the record of a ``[trajectory]`` table; an unknown key names the nearest.

        Parameters
        ----------
        table : dict
            The TOML table.

        Returns
        -------
        TrajectorySpec
        """
        traj = _section({"trajectory": table}, "trajectory", set(TRAJECTORY_KEYS))
        kind = traj.get("type")
        if kind not in ("descent", "keyframes", "approach"):
            raise InvalidParameterError(
                f"scenario [trajectory] type must be 'descent', 'keyframes' or 'approach'; "
                f"got {kind!r}")
        frames = traj.get("frames", 1)
        if isinstance(frames, bool) or not isinstance(frames, int) or frames < 1:
            raise InvalidParameterError(
                f"scenario [trajectory] frames must be a positive integer; got {frames!r}")
        values: dict = {"type": kind, "frames": frames}
        if "duration" in traj:
            values["duration"] = _number(traj, "duration", 0.0, "trajectory")
        if "look" in traj:
            look = _text(traj, "look", "site", "trajectory")
            if look not in ("site", "nadir"):
                raise InvalidParameterError(
                    f"scenario trajectory.look must be 'site' or 'nadir'; got {look!r}")
            values["look"] = look
        if "site" in traj:
            values["site"] = _vector(traj, "site", 2, "trajectory")
        if "direction" in traj:
            values["direction"] = _vector(traj, "direction", 3, "trajectory")
        if kind == "descent":
            for key in ("start_altitude", "end_altitude"):
                values[key] = _number(traj, key, None, "trajectory", positive=True)
        if kind == "approach":
            for key in ("start_distance", "end_distance"):
                values[key] = _number(traj, key, None, "trajectory", positive=True)
        if "keyframe" in traj and (not isinstance(traj["keyframe"], list) or not all(
                isinstance(k, dict) for k in traj["keyframe"])):
            raise InvalidParameterError("scenario trajectory.keyframe must be "
                                        "[[trajectory.keyframe]] tables")
        for n, key in enumerate(traj.get("keyframe", []), start=1):
            where = f"trajectory.keyframe #{n}"
            _section({"keyframe": key}, "keyframe", {"time", "position", "attitude", "look_at"})
            _number(key, "time", None, where)
            _vector(key, "position", 3, where)
            if "attitude" in key:
                _vector(key, "attitude", 4, where)
            if "look_at" in key:
                _vector(key, "look_at", 3, where)
        if kind == "keyframes" and not traj.get("keyframe"):
            raise InvalidParameterError(
                "scenario keyframe trajectory needs [[trajectory.keyframe]]")
        values["keyframe"] = tuple(dict(k) for k in traj.get("keyframe", []))
        if "ground_track" in traj:
            values["ground_track"] = _vector(traj, "ground_track", 2, "trajectory")
        return cls(**values)


@dataclass(frozen=True)
class Scenario:
    """A parsed scenario (see the module docstring)."""

    name: str
    path: Path | None
    seed: int
    scene: SceneSpec
    lighting: Lighting
    intrinsics: Intrinsics
    sensor: Sensor
    options: RenderOptions
    outputs: dict
    trajectory: TrajectorySpec
    raw: dict = field(default_factory=dict)
    # {"blur": bool, "given": the velocity keys set in [motion], "motion": Motion}
    motion: dict = field(default_factory=dict)

    def resolve(self, value: str | Path) -> Path:
        """Resolve a path the scenario names.

        Parameters
        ----------
        value : str or pathlib.Path
            A path, absolute or relative to the scenario file.

        Returns
        -------
        pathlib.Path
            The path itself when absolute (or when the scenario has no file), else joined
            to the scenario file's folder.
        """
        p = Path(value)
        if not p.is_absolute() and self.path is not None:
            p = self.path.parent / p
        return p

    def with_overrides(self, frames: int | None = None,
                       resolution: tuple[int, int] | None = None) -> Scenario:
        """Copy the scenario with the frame count and/or the image size changed.

        Parameters
        ----------
        frames : int, optional
            The trajectory's frame count (positive).
        resolution : (int, int), optional
            ``(width, height)`` pixels; the field of view is kept (focal lengths and
            principal point scale with the image).

        Returns
        -------
        Scenario
            The changed copy.
        """
        traj = self.trajectory
        if frames is not None:
            if frames < 1:
                raise InvalidParameterError(f"frames must be positive; got {frames}")
            traj = replace(traj, frames=int(frames))
        k = self.intrinsics
        if resolution is not None:
            w, h = resolution
            sx, sy = w / k.width, h / k.height
            k = Intrinsics(w, h, k.fx * sx, k.fy * sy, (k.cx + 0.5) * sx - 0.5,
                           (k.cy + 0.5) * sy - 0.5)
        return replace(self, intrinsics=k, trajectory=traj)

    def samples(self, scene: Any) -> list[Sample]:
        """Sample the trajectory's frames for a loaded scene.

        Parameters
        ----------
        scene : render.scene.Scene
            The scene the scenario names (a descent needs a terrain scene's ``site`` and
            ``height_at``; an approach stays outside the scene's ``reach``).

        Returns
        -------
        list of render.trajectory.Sample
            One pose, time and body rotation per frame.
        """
        t = self.trajectory
        kind = t.type
        frames = int(t.frames)
        duration = float(t.duration if t.duration is not None else max(frames - 1, 0))
        if kind == "keyframes":
            return keyframes(frames, list(t.keyframe))
        if kind == "descent":
            if scene.kind != "terrain":
                raise InvalidParameterError("a descent trajectory needs a terrain scene")
            site = t.site if t.site is not None else scene.site
            ground = scene.height_at(float(site[0]), float(site[1]))
            # required of a descent by TrajectorySpec.from_mapping
            assert t.start_altitude is not None and t.end_altitude is not None
            return descent(frames, (float(site[0]), float(site[1]), ground),
                           start_altitude=float(t.start_altitude),
                           end_altitude=float(t.end_altitude), duration=duration,
                           ground_track=t.ground_track, look=t.look, height_at=scene.height_at)
        if kind == "approach":
            s = self.scene
            # required of an approach by TrajectorySpec.from_mapping
            assert t.start_distance is not None and t.end_distance is not None
            reach = scene.reach
            closest = min(float(t.start_distance), float(t.end_distance))
            if closest <= reach:
                raise InvalidParameterError(
                    f"the approach comes to {closest:g} m from the body's centre, inside the "
                    f"body (it reaches {reach:.6g} m); end the approach further out")
            return approach(frames, start_distance=float(t.start_distance),
                            end_distance=float(t.end_distance), duration=duration,
                            direction=t.direction, spin_axis=s.spin_axis,
                            spin_period=float(s.spin_period),
                            spin_phase_deg=float(s.spin_phase))
        raise InvalidParameterError(f"unknown trajectory type {kind!r}")


def load_scenario(path: str | Path) -> Scenario:
    """Parse and validate a scenario file.

    The files it reads (the scene's stack or body, an albedo map) are protected as inputs:
    no output may be written over them.

    Parameters
    ----------
    path : str or pathlib.Path
        The scenario's TOML file.

    Returns
    -------
    Scenario
        The validated scenario (paths in it relative to the file's folder).
    """
    from terrain.core.outputs import protect

    path = Path(path)
    scenario = parse_scenario(read_toml(path, "scenario"), path)
    for item in scenario.scene.inputs():  # what the scenario reads is an input too
        protect(scenario.resolve(item))
    return scenario


def parse_scenario(data: dict, path: Path | None = None) -> Scenario:
    """Build a scenario from its parsed TOML tables.

    Parameters
    ----------
    data : dict
        The scenario's tables; an unknown section or key is an error naming the nearest.
    path : pathlib.Path, optional
        The file it came from (relative paths resolve against its folder).

    Returns
    -------
    Scenario
        The validated scenario.
    """
    unknown = set(data) - _SECTIONS
    if unknown:
        key = sorted(unknown)[0]
        near = difflib.get_close_matches(key, sorted(_SECTIONS), n=1)
        raise InvalidParameterError(f"scenario has unknown section or key {key!r}"
                                    + (f" (did you mean {near[0]!r}?)" if near else ""))
    for section in _SECTIONS - {"name", "seed", "description"}:
        if section in data and not isinstance(data[section], dict):
            raise InvalidParameterError(f"scenario [{section}] must be a table; got "
                                        f"{data[section]!r}")
    name = _text(data, "name", path.stem if path else "scenario", "scenario")
    if "description" in data:
        _text(data, "description", "", "scenario")
    try:
        seed = check_seed(data.get("seed", 0))
    except ValueError as exc:
        raise InvalidParameterError(f"scenario seed: {exc}") from None
    scene = SceneSpec.from_mapping(data.get("scene", {}))
    sun = _section(data, "sun", {"azimuth", "elevation", "direction", "distance", "irradiance"})
    surface = _section(data, "surface", {"albedo", "reflectance", "mcewen", "albedo_map"}
                       | _HAPKE_KEYS)
    brdf = check_brdf(_text(surface, "reflectance", "lunar-lambert", "surface"))
    albedo = _number(surface, "albedo", 0.12, "surface")
    extra = {"mcewen": _vector(surface, "mcewen", len(surface["mcewen"])
                               if isinstance(surface["mcewen"], list) else 0, "surface")} \
        if "mcewen" in surface else {}
    hapke_keys = sorted(k for k in surface if k in _HAPKE_KEYS)
    if hapke_keys and brdf != "hapke":
        raise InvalidParameterError(
            f"scenario [surface] {', '.join(hapke_keys)} are Hapke parameters, but reflectance "
            f"is {brdf!r}; set reflectance = \"hapke\" or remove them")
    extra["hapke"] = Hapke.from_mapping({k: surface[k] for k in hapke_keys})
    for key in ("distance", "irradiance"):
        if key in sun:
            extra[key] = _number(sun, key, None, "sun", positive=True)
    if "albedo_map" in surface:
        scene = replace(scene, albedo_map=_text(surface, "albedo_map", "", "surface"))
    if "direction" in sun:
        lighting = Lighting(_vector(sun, "direction", 3, "sun"), albedo, brdf, **extra)
    else:
        lighting = Lighting.from_angles(_number(sun, "azimuth", 90.0, "sun"),
                                        _number(sun, "elevation", 10.0, "sun"), albedo=albedo,
                                        brdf=brdf, **extra)

    cam = _section(data, "camera", {"width", "height", "fov", "fx", "fy", "cx", "cy"})
    w = _int(cam, "width", 1024, "camera", 1, MAX_IMAGE_SIDE)
    h = _int(cam, "height", 1024, "camera", 1, MAX_IMAGE_SIDE)
    if "fx" in cam:
        fx = _number(cam, "fx", None, "camera", True)
        intrinsics = Intrinsics(w, h, fx, _number(cam, "fy", fx, "camera", True),
                                _number(cam, "cx", (w - 1) / 2, "camera"),
                                _number(cam, "cy", (h - 1) / 2, "camera"))
    else:
        intrinsics = Intrinsics.from_fov(w, h, _number(cam, "fov", 60.0, "camera", True))

    sen = data.get("sensor", {})
    sensor = Sensor.from_mapping(sen, seed=seed, base=path.parent if path else None)
    mot = dict(_section(data, "motion", {"blur", *Motion.__dataclass_fields__}))
    blur = mot.pop("blur", bool(mot))
    if not isinstance(blur, bool):
        raise InvalidParameterError(f"scenario [motion] blur must be true or false; got {blur!r}")
    if blur and not sensor.physical and not sensor.rolling:
        raise InvalidParameterError(
            "scenario [motion] blur needs the sensor's exposure_time (s); an I/F-calibrated "
            "sensor (exposure) has none")
    motion = {"blur": blur or sensor.rolling,
              "given": sorted(k for k in mot if k in ("velocity", "angular_velocity",
                                                      "body_angular_velocity")),
              "motion": Motion.from_mapping(mot)}
    ren = _section(data, "render", {"shadows", "shadow_size", "lod_pixels", "triangle_budget",
                                    "geomorph", "antialias"})
    defaults = RenderOptions()  # the one place render defaults live
    options = RenderOptions(shadows=_bool(ren, "shadows", defaults.shadows, "render"),
                            shadow_size=_int(ren, "shadow_size", defaults.shadow_size, "render",
                                             1, MAX_IMAGE_SIDE),
                            lod_pixels=_number(ren, "lod_pixels", defaults.lod_pixels, "render",
                                               True),
                            triangle_budget=_int(ren, "triangle_budget",
                                                 defaults.triangle_budget, "render", 1),
                            geomorph=_bool(ren, "geomorph", defaults.geomorph, "render"),
                            antialias=_int(ren, "antialias", defaults.antialias, "render", 1,
                                           MAX_ANTIALIAS))
    out = _section(data, "output", {"range", "normals", "radiance"})
    outputs = {"range": _bool(out, "range", True, "output"),
               "normals": _bool(out, "normals", True, "output"),
               "radiance": _bool(out, "radiance", False, "output")}

    trajectory = TrajectorySpec.from_mapping(data.get("trajectory", {}))
    return Scenario(name, path, seed, scene, lighting, intrinsics, sensor, options, outputs,
                    trajectory, data, motion)
