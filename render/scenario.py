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

import math
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from render.camera import Intrinsics
from render.motion import Motion
from render.reflectance import Hapke, check_brdf
from render.renderer import Lighting, RenderOptions
from render.sensor import Sensor
from render.trajectory import Sample, approach, descent, keyframes
from terrain.errors import InvalidParameterError
from terrain.rng import check_seed
from terrain.tomlfile import read_toml

__all__ = ["Scenario", "load_scenario"]

_SECTIONS = {"name", "seed", "scene", "sun", "surface", "camera", "sensor", "render", "output",
             "trajectory", "description", "motion"}
_HAPKE_KEYS = set(Hapke.__dataclass_fields__)


def _section(data: dict, name: str, allowed: set[str]) -> dict:
    table = data.get(name, {})
    if not isinstance(table, dict):
        raise InvalidParameterError(f"scenario [{name}] must be a table")
    unknown = set(table) - allowed
    if unknown:
        raise InvalidParameterError(
            f"scenario [{name}] has unknown keys {sorted(unknown)}; expected some of "
            f"{sorted(allowed)}")
    return table


def _number(table, key, default, where, positive=False):
    v = table.get(key, default)
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise InvalidParameterError(f"scenario {where}.{key} must be a number; got {v!r}")
    v = float(v)
    if not math.isfinite(v) or (positive and v <= 0):
        raise InvalidParameterError(
            f"scenario {where}.{key} must be {'positive' if positive else 'finite'}; got {v}")
    return v


@dataclass(frozen=True)
class Scenario:
    """A parsed scenario (see the module docstring)."""

    name: str
    path: Path | None
    seed: int
    scene: dict
    lighting: Lighting
    intrinsics: Intrinsics
    sensor: Sensor
    options: RenderOptions
    outputs: dict
    trajectory: dict
    raw: dict = field(default_factory=dict)
    # {"blur": bool, "given": the velocity keys set in [motion], "motion": Motion}
    motion: dict = field(default_factory=dict)

    def resolve(self, value) -> Path:
        """A path from the scenario, relative to the scenario file."""
        p = Path(value)
        if not p.is_absolute() and self.path is not None:
            p = self.path.parent / p
        return p

    def with_overrides(self, frames=None, resolution=None) -> Scenario:
        """Copy with the frame count and/or the image size changed (field of view kept)."""
        traj = dict(self.trajectory)
        if frames is not None:
            if frames < 1:
                raise InvalidParameterError(f"frames must be positive; got {frames}")
            traj["frames"] = int(frames)
        k = self.intrinsics
        if resolution is not None:
            w, h = resolution
            sx, sy = w / k.width, h / k.height
            k = Intrinsics(w, h, k.fx * sx, k.fy * sy, (k.cx + 0.5) * sx - 0.5,
                           (k.cy + 0.5) * sy - 0.5)
        return replace(self, intrinsics=k, trajectory=traj)

    def samples(self, scene) -> list[Sample]:
        """The trajectory's frames for a loaded scene."""
        t = self.trajectory
        kind = t["type"]
        frames = int(t["frames"])
        duration = float(t.get("duration", max(frames - 1, 0)))
        if kind == "keyframes":
            return keyframes(frames, t["keyframe"])
        if kind == "descent":
            if scene.kind != "terrain":
                raise InvalidParameterError("a descent trajectory needs a terrain scene")
            site = t.get("site", scene.site)
            ground = scene.height_at(float(site[0]), float(site[1]))
            return descent(frames, (float(site[0]), float(site[1]), ground),
                           start_altitude=float(t["start_altitude"]),
                           end_altitude=float(t["end_altitude"]), duration=duration,
                           ground_track=t.get("ground_track", (0.0, 0.0)),
                           look=t.get("look", "site"), height_at=scene.height_at)
        if kind == "approach":
            s = self.scene
            return approach(frames, start_distance=float(t["start_distance"]),
                            end_distance=float(t["end_distance"]), duration=duration,
                            direction=t.get("direction", (1.0, 0.0, 0.0)),
                            spin_axis=s.get("spin_axis", (0.0, 0.0, 1.0)),
                            spin_period=float(s.get("spin_period", 0.0)),
                            spin_phase_deg=float(s.get("spin_phase", 0.0)))
        raise InvalidParameterError(f"unknown trajectory type {kind!r}")


def load_scenario(path) -> Scenario:
    """Parse and validate a scenario file."""
    path = Path(path)
    return parse_scenario(read_toml(path, "scenario"), path)


def parse_scenario(data: dict, path: Path | None = None) -> Scenario:
    unknown = set(data) - _SECTIONS
    if unknown:
        raise InvalidParameterError(f"scenario has unknown sections {sorted(unknown)}")
    name = str(data.get("name", path.stem if path else "scenario"))
    seed = check_seed(data.get("seed", 0))
    scene = _section(data, "scene", {"type", "stack", "curvature", "radius", "body",
                                     "boulders", "spin_axis", "spin_period", "spin_phase",
                                     "imposter_pixels"})
    if scene.get("type") not in ("terrain", "asteroid"):
        raise InvalidParameterError(
            f"scenario [scene] type must be 'terrain' or 'asteroid'; got {scene.get('type')!r}")
    if scene["type"] == "terrain" and "stack" not in scene:
        raise InvalidParameterError("scenario [scene] needs 'stack' (a layer-stack folder)")
    if scene["type"] == "asteroid" and "body" not in scene:
        raise InvalidParameterError("scenario [scene] needs 'body' (an asteroid .npz)")

    sun = _section(data, "sun", {"azimuth", "elevation", "direction", "distance", "irradiance"})
    surface = _section(data, "surface", {"albedo", "reflectance", "mcewen", "albedo_map"}
                       | _HAPKE_KEYS)
    brdf = check_brdf(surface.get("reflectance", "lunar-lambert"))
    albedo = _number(surface, "albedo", 0.12, "surface")
    extra = {"mcewen": tuple(surface["mcewen"])} if "mcewen" in surface else {}
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
        scene = dict(scene, albedo_map=str(surface["albedo_map"]))
    if "direction" in sun:
        lighting = Lighting(tuple(sun["direction"]), albedo, brdf, **extra)
    else:
        lighting = Lighting.from_angles(_number(sun, "azimuth", 90.0, "sun"),
                                        _number(sun, "elevation", 10.0, "sun"), albedo=albedo,
                                        brdf=brdf, **extra)

    cam = _section(data, "camera", {"width", "height", "fov", "fx", "fy", "cx", "cy"})
    w = int(cam.get("width", 1024))
    h = int(cam.get("height", 1024))
    if "fx" in cam:
        intrinsics = Intrinsics(w, h, float(cam["fx"]), float(cam.get("fy", cam["fx"])),
                                float(cam.get("cx", (w - 1) / 2)),
                                float(cam.get("cy", (h - 1) / 2)))
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
    ren = _section(data, "render", {"shadows", "shadow_size", "lod_pixels", "triangle_budget"})
    options = RenderOptions(shadows=bool(ren.get("shadows", True)),
                            shadow_size=int(ren.get("shadow_size", 2048)),
                            lod_pixels=float(ren.get("lod_pixels", 1.5)),
                            triangle_budget=int(ren.get("triangle_budget", 3_000_000)))
    out = _section(data, "output", {"range", "normals", "radiance"})
    outputs = {"range": bool(out.get("range", True)), "normals": bool(out.get("normals", True)),
               "radiance": bool(out.get("radiance", False))}

    traj = _section(data, "trajectory", {"type", "frames", "duration", "start_altitude",
                                         "end_altitude", "ground_track", "look", "site",
                                         "keyframe", "start_distance", "end_distance",
                                         "direction"})
    kind = traj.get("type")
    if kind not in ("descent", "keyframes", "approach"):
        raise InvalidParameterError(
            f"scenario [trajectory] type must be 'descent', 'keyframes' or 'approach'; got "
            f"{kind!r}")
    frames = traj.get("frames", 1)
    if isinstance(frames, bool) or not isinstance(frames, int) or frames < 1:
        raise InvalidParameterError(
            f"scenario [trajectory] frames must be a positive integer; got {frames!r}")
    if kind == "descent":
        for key in ("start_altitude", "end_altitude"):
            _number(traj, key, None, "trajectory", positive=True)
    if kind == "approach":
        for key in ("start_distance", "end_distance"):
            _number(traj, key, None, "trajectory", positive=True)
    if kind == "keyframes" and not traj.get("keyframe"):
        raise InvalidParameterError("scenario keyframe trajectory needs [[trajectory.keyframe]]")
    if "ground_track" in traj and np.asarray(traj["ground_track"]).shape != (2,):
        raise InvalidParameterError("scenario trajectory.ground_track must be [dx, dy]")
    return Scenario(name, path, seed, scene, lighting, intrinsics, sensor, options, outputs,
                    dict(traj), data, motion)
