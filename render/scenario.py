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
    # binary scenes (render.binary_scene): type = "binary", primary = "didymos.npz",
    # secondary = "dimorphos.npz" (native bodies or shape files), [scene.orbit] semi_major_axis,
    # eccentricity, inclination, node, periapsis, mean_anomaly, period, mass_ratio;
    # [scene.primary_spin] / [scene.secondary_spin] axis, period, phase (none: tidally locked)
    # [scene.build]: the scene's recipe, built where the scene is missing
    # (render.scene_build: [scene.build.base] and [scene.build.stack], or [scene.build.body])

    [sun]
    azimuth = 90.0                   # degrees clockwise from north (terrain) ...
    elevation = 5.0                  # ... above the horizon; or direction = [x, y, z]
    distance = 1.0                   # the body's distance from the Sun (au)
    irradiance = 1.58                # solar spectral irradiance at 1 au (W m^-2 nm^-1)
    # or the Sun (and Earth) on a date, instead of azimuth, elevation and distance
    # (render.ephemeris, docs/ephemeris.md): the trajectory's times add to utc
    # utc = "2027-01-15T12:00:00"
    # longitude = 0.0                # the site (degrees; terrain: the stack's CRS by default)
    # latitude = -89.5
    # height = 0.0                   # m; grid_north (degrees): azimuth of the map's +y
    # kernels = ["moon_pa_de440_200625.bpc", "moon_de440_250416.tf"]; frame = "MOON_ME"
    # asteroids: [sun.orbit] a, e, i, node, peri, mean_anomaly, epoch; or target (an SPK)

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
    # auto_exposure = true: ae_percentile of lit pixels at ae_fraction of full scale, moving
    # ae_rate of the way each frame (ae_threshold, ae_max; render.sensor, docs/ephemeris.md)

    [motion]                         # optional: blur from motion during the exposure
    blur = true
    # velocity = [vx, vy, vz]        # m/s, world; default: from the trajectory
    # angular_velocity = [wx, wy, wz]  # rad/s, world; default: from the trajectory
    # samples = 0                    # sub-frames per exposure (0: automatic)

    [radar]                          # optional, or [[radar]] for several beams (render.radar)
    direction = [0.0, 0.0, 1.0]      # camera frame; width (deg), pattern, range/doppler bins
    [lidar]                          # optional (render.lidar): mode = "flash" or "scan"
    width = 64

    [render]
    shadows = true
    shadow_size = 2048
    lod_pixels = 1.5
    triangle_budget = 3000000
    geomorph = true                  # levels of detail morph instead of switching
    antialias = 1                    # samples per pixel side (odd): radiance is their mean
    soft_shadows = true              # the sun's disk casts penumbrae (false: a point sun)
    scattering = true                # terrain scatters sunlight into shadows (single)
    earthshine = true                # the Earth lights the surface where [sun] gives it
    shadow_detail = 2.0              # terrain shadow-map texels per layer pixel

    [output]
    range = true
    normals = true
    radiance = false                 # also radiance/radiance_NNNNNN.tif, W m^-2 sr^-1 nm^-1
    body_ids = true                  # binary scenes: bodies/bodies_NNNNNN.png, 0 sky, 1, 2

    [labels]                         # optional: image-space labels (render/labels.py,
    min_crater_pixels = 8.0          # docs/labels.md); rims, masks and flow on by default
    lander_diameter = 4.0            # hazards in image space for this lander (m) ...
    max_slope = 10.0                 # ... degrees
    max_step = 0.3                   # ... m

    [trajectory]
    type = "descent"                 # "descent", "keyframes" or "approach"
    frames = 60
    duration = 120.0                 # s
    start_altitude = 10000.0         # m above the site
    end_altitude = 20.0
    ground_track = [3000.0, -2000.0] # start offset from the site (m)
    look = "site"                    # or "nadir"

    [dispersion]                     # optional: the trajectory as flown, dispersed
    position = [0.0, 0.0, 0.0]       # m, world: added to every frame's position
    velocity = [0.0, 0.0, 0.0]       # m/s, world: adds velocity * (t - t_first)
    attitude = [0.0, 0.0, 0.0]       # degrees: rotation vector in the camera frame

Keyframes: ``[[trajectory.keyframe]]`` tables with ``time``, ``position`` and ``attitude``
(quaternion [w, x, y, z], R_WC) or ``look_at``. Approach (asteroids): ``start_distance``,
``end_distance``, ``direction``, and under ``[scene]`` ``spin_axis``, ``spin_period`` (s),
``spin_phase`` (degrees).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from render.camera import Intrinsics
from render.ephemeris import DATED_KEYS, Sky, SunEphemeris, site_on_map
from render.events import EventCamera
from render.labels import LabelSpec
from render.lamp import Lamp
from render.lidar import Lidar
from render.motion import Motion
from render.orbit import MutualOrbit, Spin
from render.radar import RadarBeam
from render.reflectance import Hapke, check_brdf
from render.renderer import MAX_ANTIALIAS, Lighting, RenderOptions
from render.scene_build import SceneBuild
from render.sensor import Sensor
from render.stars import StarField
from render.trajectory import Sample, approach, descent, keyframes
from terrain.core.checks import boolean, check_keys, integer, number, text, vector
from terrain.core.errors import InvalidParameterError
from terrain.core.rng import check_seed
from terrain.core.tomlfile import read_toml

__all__ = ["Dispersion", "SceneSpec", "Scenario", "TrajectorySpec", "load_scenario"]

_SECTIONS = {"name", "seed", "scene", "sun", "surface", "camera", "sensor", "render", "output",
             "trajectory", "description", "motion", "events", "stars", "labels", "dispersion",
             "lamp", "radar", "lidar"}
_HAPKE_KEYS = set(Hapke.__dataclass_fields__)
#: How each section is named in messages.
_SCENE, _TRAJECTORY, _SURFACE, _SUN, _CAMERA, _RENDER, _OUTPUT = (
    f"scenario [{name}]" for name in ("scene", "trajectory", "surface", "sun", "camera", "render",
                                      "output"))


def _section(data: dict, name: str, allowed: set[str]) -> dict:
    return check_keys(data.get(name, {}), allowed, f"scenario [{name}]")


#: Bounds of a value that must be positive.
_POSITIVE: dict = {"low": 0, "low_open": True}

#: Largest image side a scenario may ask for (pixels).
MAX_IMAGE_SIDE = 32768


#: Bodies an asteroid scene is drawn as an imposter below, in pixels across.
DEFAULT_IMPOSTER_PIXELS = 24.0
#: Keys of a scenario's [scene] table.
SCENE_KEYS = frozenset({"type", "stack", "curvature", "radius", "body", "boulders", "spin_axis",
                        "spin_period", "spin_phase", "imposter_pixels", "build", "primary",
                        "secondary", "orbit", "primary_spin", "secondary_spin"})
#: Keys of [scene] that only a binary scene takes, and those a binary scene refuses.
BINARY_KEYS = frozenset({"primary", "secondary", "orbit", "primary_spin", "secondary_spin"})
NOT_BINARY_KEYS = frozenset({"stack", "curvature", "radius", "body", "spin_axis", "spin_period",
                             "spin_phase", "imposter_pixels", "build"})
#: Keys of a scenario's [trajectory] table.
TRAJECTORY_KEYS = frozenset({"type", "frames", "duration", "start_altitude", "end_altitude",
                             "ground_track", "look", "site", "keyframe", "start_distance",
                             "end_distance", "direction"})


@dataclass(frozen=True)
class SceneSpec:
    """A scenario's ``[scene]``: what to load, validated, with its defaults in one place.

    Parameters
    ----------
    type : {"terrain", "asteroid", "binary"}
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
    primary, secondary : str, optional
        Binary: the two bodies (native ``.npz`` or shape files), relative to the scenario.
    orbit : render.orbit.MutualOrbit, optional
        Binary: ``[scene.orbit]`` (Didymos-Dimorphos where not given).
    primary_spin, secondary_spin : render.orbit.Spin, optional
        Binary: each body's spin; a secondary without one is tidally locked.
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
    primary: str | None = None
    secondary: str | None = None
    orbit: MutualOrbit | None = None
    primary_spin: Spin | None = None
    secondary_spin: Spin | None = None

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
        scene = check_keys(table, SCENE_KEYS, _SCENE)
        kind = scene.get("type")
        if kind not in ("terrain", "asteroid", "binary"):
            raise InvalidParameterError(
                f"scenario [scene] type must be 'terrain' or 'asteroid' or 'binary'; got {kind!r}")
        if kind == "binary":
            return cls._binary(scene)
        extra = sorted(BINARY_KEYS & set(scene))
        if extra:
            raise InvalidParameterError(f"scenario [scene] {extra[0]} belongs to a binary scene "
                                        f"(type = \"binary\"), not a {kind} scene")
        if kind == "terrain" and "stack" not in scene:
            raise InvalidParameterError("scenario [scene] needs 'stack' (a layer-stack folder)")
        if kind == "asteroid" and "body" not in scene:
            raise InvalidParameterError("scenario [scene] needs 'body' (an asteroid .npz)")
        values: dict = {"type": kind}
        for key in ("stack", "body"):
            if key in scene:
                values[key] = text(scene.get(key, ""), key, where=_SCENE)
                if Path(values[key]).name in ("", ".", ".."):  # "", "/", ".", "x/.."
                    what = "a layer-stack folder" if key == "stack" else "an asteroid .npz"
                    raise InvalidParameterError(
                        f"scenario [scene] {key} must name {what}, not a folder above it; "
                        f"got {values[key]!r}")
        for key in ("curvature", "boulders"):
            if key in scene:
                values[key] = boolean(scene.get(key, True), key, where=_SCENE)
        for key in ("spin_period", "spin_phase"):
            if key in scene:
                values[key] = number(scene.get(key, 0.0), key, where=_SCENE)
        if "radius" in scene:
            values["radius"] = number(scene.get("radius", 1.0), "radius", **_POSITIVE, where=_SCENE)
        if "imposter_pixels" in scene:
            values["imposter_pixels"] = number(scene["imposter_pixels"], "imposter_pixels",
                                               **_POSITIVE, where=_SCENE)
        if "spin_axis" in scene:
            values["spin_axis"] = vector(scene.get("spin_axis"), "spin_axis", 3, where=_SCENE)
        if "build" in scene:
            values["build"] = SceneBuild.from_mapping(scene["build"], kind)
        return cls(**values)

    @classmethod
    def _binary(cls, scene: dict) -> SceneSpec:
        """Build the record of a binary ``[scene]`` (see :meth:`from_mapping`)."""
        wrong = sorted(NOT_BINARY_KEYS & set(scene))
        if wrong:
            hint = (" (give each body's spin in [scene.primary_spin] and "
                    "[scene.secondary_spin])" if wrong[0].startswith("spin") else "")
            raise InvalidParameterError(f"scenario [scene] {wrong[0]} does not apply to a "
                                        f"binary scene{hint}")
        values: dict = {"type": "binary"}
        for key in ("primary", "secondary"):
            if key not in scene:
                raise InvalidParameterError(f"scenario [scene] needs '{key}' (a native body "
                                            "or a shape file) for a binary scene")
            values[key] = text(scene[key], key, where=_SCENE)
            if Path(values[key]).name in ("", ".", ".."):
                raise InvalidParameterError(f"scenario [scene] {key} must name a body file; "
                                            f"got {values[key]!r}")
        if "boulders" in scene:
            values["boulders"] = boolean(scene["boulders"], "boulders", where=_SCENE)
        orbit = scene.get("orbit", {})
        if not isinstance(orbit, dict):
            raise InvalidParameterError(f"scenario [scene.orbit] must be a table; got {orbit!r}")
        values["orbit"] = MutualOrbit.from_mapping(orbit)
        values["primary_spin"] = Spin.from_mapping(scene.get("primary_spin", {}),
                                                   "scenario [scene.primary_spin]")
        if "secondary_spin" in scene:
            values["secondary_spin"] = Spin.from_mapping(scene["secondary_spin"],
                                                         "scenario [scene.secondary_spin]")
        return cls(**values)

    def inputs(self) -> tuple[str, ...]:
        """List the files and folders the scene reads (relative to the scenario file).

        Returns
        -------
        tuple of str
        """
        return tuple(v for v in (self.stack, self.body, self.primary, self.secondary)
                     if v is not None)


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
        traj = check_keys(table, TRAJECTORY_KEYS, _TRAJECTORY)
        kind = traj.get("type")
        if kind not in ("descent", "keyframes", "approach"):
            raise InvalidParameterError(
                f"scenario [trajectory] type must be 'descent', 'keyframes' or 'approach'; "
                f"got {kind!r}")
        frames = integer(traj.get("frames", 1), "frames", low=1, where=_TRAJECTORY)
        values: dict = {"type": kind, "frames": frames}
        if "duration" in traj:
            values["duration"] = number(traj.get("duration", 0.0), "duration", where=_TRAJECTORY)
        if "look" in traj:
            values["look"] = text(traj["look"], "look", choices=("site", "nadir"),
                                  where=_TRAJECTORY)
        if "site" in traj:
            values["site"] = vector(traj.get("site"), "site", 2, where=_TRAJECTORY)
        if "direction" in traj:
            values["direction"] = vector(traj.get("direction"), "direction", 3, where=_TRAJECTORY)
        if kind == "descent":
            for key in ("start_altitude", "end_altitude"):
                values[key] = number(traj.get(key), key, **_POSITIVE, where=_TRAJECTORY)
        if kind == "approach":
            for key in ("start_distance", "end_distance"):
                values[key] = number(traj.get(key), key, **_POSITIVE, where=_TRAJECTORY)
        if "keyframe" in traj and (not isinstance(traj["keyframe"], list) or not all(
                isinstance(k, dict) for k in traj["keyframe"])):
            raise InvalidParameterError("scenario trajectory.keyframe must be "
                                        "[[trajectory.keyframe]] tables")
        for n, key in enumerate(traj.get("keyframe", []), start=1):
            where = f"scenario [[trajectory.keyframe]] #{n}"
            check_keys(key, {"time", "position", "attitude", "look_at"}, where)
            number(key.get("time"), "time", where=where)
            vector(key.get("position"), "position", 3, where=where)
            if "attitude" in key:
                vector(key.get("attitude"), "attitude", 4, where=where)
            if "look_at" in key:
                vector(key.get("look_at"), "look_at", 3, where=where)
        if kind == "keyframes" and not traj.get("keyframe"):
            raise InvalidParameterError(
                "scenario keyframe trajectory needs [[trajectory.keyframe]]")
        values["keyframe"] = tuple(dict(k) for k in traj.get("keyframe", []))
        if "ground_track" in traj:
            values["ground_track"] = vector(traj["ground_track"], "ground_track", 2,
                                            where=_TRAJECTORY)
        return cls(**values)


#: Keys of a scenario's [dispersion] table.
DISPERSION_KEYS = frozenset({"position", "velocity", "attitude"})


@dataclass(frozen=True)
class Dispersion:
    """A scenario's ``[dispersion]``: how the flown trajectory departs from the nominal one.

    Monte Carlo campaigns (:mod:`render.montecarlo`) write one per case; a scenario without
    the table flies the nominal trajectory. The attitude rule of the trajectory (``look``)
    is not solved again: the camera keeps the nominal attitude, turned by ``attitude``.

    Parameters
    ----------
    position : (3,) float, metres
        Added to every frame's camera position (world frame).
    velocity : (3,) float, m/s
        Adds ``velocity * (t - t_first)`` to each frame's position (world frame).
    attitude : (3,) float, degrees
        Rotation vector (axis times angle) in the camera frame: ``R_WC' = R_WC R(attitude)``.
    """

    position: tuple[float, float, float] = (0.0, 0.0, 0.0)
    velocity: tuple[float, float, float] = (0.0, 0.0, 0.0)
    attitude: tuple[float, float, float] = (0.0, 0.0, 0.0)

    @classmethod
    def from_mapping(cls, table: dict) -> Dispersion:
        """Build the record of a ``[dispersion]`` table; an unknown key names the nearest.

        Parameters
        ----------
        table : dict
            The TOML table.

        Returns
        -------
        Dispersion

        Examples
        --------
        >>> Dispersion.from_mapping({"velocity": [1, 0, 0]}).velocity
        (1.0, 0.0, 0.0)
        """
        d = check_keys(table, DISPERSION_KEYS, "scenario [dispersion]")
        values: dict[str, Any] = {k: vector(v, k, 3, where="scenario [dispersion]")
                                   for k, v in d.items()}
        return cls(**values)

    @property
    def nominal(self) -> bool:
        """Whether the trajectory is flown as given (every offset zero)."""
        return not any(any(v) for v in (self.position, self.velocity, self.attitude))

    def apply(self, samples: list[Sample]) -> list[Sample]:
        """Return the samples as flown: shifted, drifting and turned (see the class).

        Parameters
        ----------
        samples : list of render.trajectory.Sample
            The nominal trajectory.

        Returns
        -------
        list of render.trajectory.Sample
            The same times and body rotations; the samples themselves when nominal.
        """
        if self.nominal or not samples:
            return samples
        import math

        import numpy as np

        from render.camera import Pose, quat_from_matrix, quat_to_matrix
        from render.motion import rotation_vector_matrix

        turn = rotation_vector_matrix(np.radians(np.asarray(self.attitude, dtype=np.float64)))
        p0, v = np.asarray(self.position, np.float64), np.asarray(self.velocity, np.float64)
        t0 = samples[0].time
        out = []
        for s in samples:
            pos = np.asarray(s.pose.position, np.float64) + p0 + v * (s.time - t0)
            att = quat_from_matrix(quat_to_matrix(s.pose.attitude) @ turn)
            if not np.all(np.isfinite(pos)) or not math.isfinite(float(att[0])):
                raise InvalidParameterError(f"scenario [dispersion] gives a non-finite pose at "
                                            f"t = {s.time} s")
            out.append(replace(s, pose=Pose(tuple(pos.tolist()), tuple(att.tolist()))))
        return out


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
    #: The Sun on a date ([sun] utc); None for a hand-set sun.
    ephemeris: SunEphemeris | None = None
    #: The event camera of an ``[events]`` table (render.events), None without one.
    events: EventCamera | None = None
    #: The star field of a ``[stars]`` table (render.stars), None without one.
    stars: StarField | None = None
    #: Image-space labels to write with each frame (:mod:`render.labels`); None: none.
    labels: LabelSpec | None = None
    #: The dispersion of a Monte Carlo case (render.dispersions); none by default.
    dispersion: Dispersion = field(default_factory=Dispersion)
    #: The spacecraft's lamp of a ``[lamp]`` table (render.lamp), None without one.
    lamp: Lamp | None = None
    #: The radar beams of a ``[radar]`` table or ``[[radar]]`` tables (render.radar).
    radar: tuple[RadarBeam, ...] = ()
    #: The LIDAR of a ``[lidar]`` table (render.lidar), None without one.
    lidar: Lidar | None = None

    def sky_at(self, time: float, scene: Any = None) -> Sky | None:
        """Return the Sun and Earth at trajectory time ``time`` (s); None for a hand-set sun.

        Parameters
        ----------
        time : float
            Seconds after ``[sun] utc``.
        scene : render.scene.Scene, optional
            A terrain scene places a site the scenario does not give (its stack's CRS).

        Returns
        -------
        render.ephemeris.Sky or None
        """
        eph = self.ephemeris
        if eph is None:
            return None
        if eph.site is None and eph.orbit is None and eph.target is None:
            placed = eph._cache.get("placed")  # the site the scene places, found once
            if placed is None:
                placed = eph._cache["placed"] = eph.with_site(scene_site(scene))
            eph = placed
        return eph.sky(time)

    def lighting_at(self, time: float, scene: Any = None) -> Lighting:
        """Return the lighting at trajectory time ``time`` (s), dated where the sun is.

        Parameters
        ----------
        time : float
            Seconds after ``[sun] utc``.
        scene : render.scene.Scene, optional
            See :meth:`sky_at`.

        Returns
        -------
        render.renderer.Lighting
            The Sun's direction and distance and the Earth at that time; the scenario's own
            lighting for a hand-set sun.
        """
        sky = self.sky_at(time, scene)
        return self.lighting if sky is None else sky.lighting(self.lighting)

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
        """Sample the trajectory's frames for a loaded scene, as flown (``[dispersion]``).

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
        return self.dispersion.apply(self._nominal_samples(scene))

    def _nominal_samples(self, scene: Any) -> list[Sample]:
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


def scene_site(scene: Any):
    """Return the site of a terrain scene on its body, from its layer stack's CRS.

    Parameters
    ----------
    scene : render.terrain_scene.TerrainScene
        Its stack's CRS, site (map x, y), ground height there and body radius.

    Returns
    -------
    render.ephemeris.Site
    """
    stack = getattr(scene, "stack", None)
    if stack is None:
        raise InvalidParameterError("scenario [sun] utc needs the site: give [sun] longitude "
                                    "and latitude")
    x, y = scene.site
    return site_on_map(stack.tiles[0].crs, x, y, height=float(scene.height_at(x, y)),
                       radius=float(scene.radius))


def _dated_sun(sun: dict, scene: SceneSpec, path: Path | None,
               extra: dict) -> SunEphemeris | None:
    """Return the ``[sun]`` table's dated Sun or None; refuse hand-set keys with ``utc``."""
    dated = sorted(k for k in sun if k in DATED_KEYS and k != "utc")
    if "utc" not in sun:
        if dated:
            raise InvalidParameterError(f"scenario [sun] {dated[0]} places the Sun on a date; "
                                        "it needs utc")
        return None
    mixed = sorted(k for k in ("azimuth", "elevation", "direction", "distance") if k in sun)
    if mixed:
        raise InvalidParameterError(f"scenario [sun] {mixed[0]} is hand-set, but utc places "
                                    "the Sun on a date; give one or the other")
    extra.pop("distance", None)
    return SunEphemeris.from_mapping({k: sun[k] for k in DATED_KEYS if k in sun},
                                     asteroid=scene.type in ("asteroid", "binary"),
                                     base=path.parent if path else None)


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
    check_keys(data, _SECTIONS, "scenario")
    for section in _SECTIONS - {"name", "seed", "description", "radar"}:
        if section in data and not isinstance(data[section], dict):
            raise InvalidParameterError(f"scenario [{section}] must be a table; got "
                                        f"{data[section]!r}")
    name = text(data.get("name", path.stem if path else "scenario"), "name", where="scenario")
    if "description" in data:
        text(data.get("description", ""), "description", where="scenario")
    try:
        seed = check_seed(data.get("seed", 0))
    except ValueError as exc:
        raise InvalidParameterError(f"scenario seed: {exc}") from None
    scene = SceneSpec.from_mapping(data.get("scene", {}))
    sun = _section(data, "sun", {"azimuth", "elevation", "direction", "distance", "irradiance"}
                   | DATED_KEYS)
    surface = _section(data, "surface", {"albedo", "reflectance", "mcewen", "albedo_map"}
                       | _HAPKE_KEYS)
    brdf = check_brdf(text(surface.get("reflectance", "lunar-lambert"), "reflectance",
                           where=_SURFACE))
    albedo = number(surface.get("albedo", 0.12), "albedo", where=_SURFACE)
    extra: dict[str, Any] = {"mcewen": vector(surface["mcewen"], "mcewen", len(surface["mcewen"])
                                              if isinstance(surface["mcewen"], list) else 0,
                                              where=_SURFACE)} if "mcewen" in surface else {}
    hapke_keys = sorted(k for k in surface if k in _HAPKE_KEYS)
    if hapke_keys and brdf != "hapke":
        raise InvalidParameterError(
            f"scenario [surface] {', '.join(hapke_keys)} are Hapke parameters, but reflectance "
            f"is {brdf!r}; set reflectance = \"hapke\" or remove them")
    extra["hapke"] = Hapke.from_mapping({k: surface[k] for k in hapke_keys})
    for key in ("distance", "irradiance"):
        if key in sun:
            extra[key] = number(sun.get(key), key, **_POSITIVE, where=_SUN)
    if "albedo_map" in surface:
        if scene.type == "binary":
            raise InvalidParameterError("scenario [surface] albedo_map does not apply to a "
                                        "binary scene")
        scene = replace(scene, albedo_map=text(surface["albedo_map"], "albedo_map",
                                               where=_SURFACE))
    ephemeris = _dated_sun(sun, scene, path, extra)
    if ephemeris is not None:  # the sky at time 0 where the site is known; else overhead
        lighting = Lighting((0.0, 0.0, 1.0), albedo, brdf, **extra)
        if ephemeris.site is not None or scene.type in ("asteroid", "binary"):
            lighting = ephemeris.sky(0.0).lighting(lighting)
    elif "direction" in sun:
        lighting = Lighting(vector(sun["direction"], "direction", 3, where=_SUN), albedo, brdf,
                            **extra)
    else:
        lighting = Lighting.from_angles(number(sun.get("azimuth", 90.0), "azimuth", where=_SUN),
                                        number(sun.get("elevation", 10.0), "elevation",
                                               where=_SUN),
                                        albedo=albedo, brdf=brdf, **extra)

    cam = _section(data, "camera", {"width", "height", "fov", "fx", "fy", "cx", "cy"})
    w = integer(cam.get("width", 1024), "width", low=1, high=MAX_IMAGE_SIDE, where=_CAMERA)
    h = integer(cam.get("height", 1024), "height", low=1, high=MAX_IMAGE_SIDE, where=_CAMERA)
    if "fx" in cam:
        fx = number(cam.get("fx"), "fx", **_POSITIVE, where=_CAMERA)
        intrinsics = Intrinsics(w, h, fx,
                                number(cam.get("fy", fx), "fy", **_POSITIVE, where=_CAMERA),
                                number(cam.get("cx", (w - 1) / 2), "cx", where=_CAMERA),
                                number(cam.get("cy", (h - 1) / 2), "cy", where=_CAMERA))
    else:
        intrinsics = Intrinsics.from_fov(w, h, number(cam.get("fov", 60.0), "fov", **_POSITIVE,
                                                      where=_CAMERA))

    sen = data.get("sensor", {})
    sensor = Sensor.from_mapping(sen, seed=seed, base=path.parent if path else None)
    mot = dict(_section(data, "motion", {"blur", *Motion.__dataclass_fields__}))
    blur = boolean(mot.pop("blur", bool(mot)), "blur", where="scenario [motion]")
    if blur and not sensor.physical and not sensor.rolling:
        raise InvalidParameterError(
            "scenario [motion] blur needs the sensor's exposure_time (s); an I/F-calibrated "
            "sensor (exposure) has none")
    motion = {"blur": blur or sensor.rolling,
              "given": sorted(k for k in mot if k in ("velocity", "angular_velocity",
                                                      "body_angular_velocity")),
              "motion": Motion.from_mapping(mot)}
    ren = _section(data, "render", {"shadows", "shadow_size", "lod_pixels", "triangle_budget",
                                    "geomorph", "antialias", "soft_shadows", "scattering",
                                    "earthshine", "shadow_detail"})
    defaults = RenderOptions()  # the one place render defaults live
    options = RenderOptions(
        shadows=boolean(ren.get("shadows", defaults.shadows), "shadows", where=_RENDER),
        shadow_size=integer(ren.get("shadow_size", defaults.shadow_size), "shadow_size", low=1,
                            high=MAX_IMAGE_SIDE, where=_RENDER),
        lod_pixels=number(ren.get("lod_pixels", defaults.lod_pixels), "lod_pixels", **_POSITIVE,
                          where=_RENDER),
        triangle_budget=integer(ren.get("triangle_budget", defaults.triangle_budget),
                                "triangle_budget", low=1, where=_RENDER),
        geomorph=boolean(ren.get("geomorph", defaults.geomorph), "geomorph", where=_RENDER),
        antialias=integer(ren.get("antialias", defaults.antialias), "antialias", low=1,
                          high=MAX_ANTIALIAS, where=_RENDER),
        soft_shadows=boolean(ren.get("soft_shadows", defaults.soft_shadows), "soft_shadows",
                             where=_RENDER),
        scattering=boolean(ren.get("scattering", defaults.scattering), "scattering",
                           where=_RENDER),
        earthshine=boolean(ren.get("earthshine", defaults.earthshine), "earthshine",
                           where=_RENDER),
        shadow_detail=number(ren.get("shadow_detail", defaults.shadow_detail),
                             "shadow_detail", low=0.25, high=8.0, where=_RENDER))
    out = _section(data, "output", {"range", "normals", "radiance", "body_ids"})
    outputs = {"range": boolean(out.get("range", True), "range", where=_OUTPUT),
               "body_ids": boolean(out.get("body_ids", True), "body_ids", where=_OUTPUT),
               "normals": boolean(out.get("normals", True), "normals", where=_OUTPUT),
               "radiance": boolean(out.get("radiance", False), "radiance", where=_OUTPUT)}

    trajectory = TrajectorySpec.from_mapping(data.get("trajectory", {}))
    events = EventCamera.from_mapping(data["events"]) if "events" in data else None
    stars = StarField.from_mapping(data["stars"]) if "stars" in data else None
    labels = LabelSpec.from_mapping(data["labels"]) if "labels" in data else None
    dispersion = Dispersion.from_mapping(data.get("dispersion", {}))
    lamp = Lamp.from_mapping(data["lamp"]) if "lamp" in data else None
    beams = data.get("radar", [])
    if isinstance(beams, dict):
        beams = [beams]
    if not isinstance(beams, list) or not all(isinstance(b, dict) for b in beams):
        raise InvalidParameterError("scenario [radar] must be a table or an array of tables")
    radar = tuple(RadarBeam.from_mapping(b) for b in beams)
    lidar = Lidar.from_mapping(data["lidar"]) if "lidar" in data else None
    return Scenario(name, path, seed, scene, lighting, intrinsics, sensor, options, outputs,
                    trajectory, data, motion, ephemeris=ephemeris, events=events, stars=stars,
                    labels=labels, dispersion=dispersion, lamp=lamp,
                    radar=radar, lidar=lidar)
