"""Image-space labels of a rendered frame: crater rims, instance and semantic masks, flow, hazards.

What a navigation team trains and scores against, computed from the frame's exact camera, its
range image and the scene's catalogues (:mod:`terrain.craters.catalog`), never from the
pixels' brightness alone:

Crater rims
    Each catalogue crater whose rim spans at least ``min_crater_pixels`` in the image gets its
    rim's image conic. The 3-D rim is the circle of the catalogue's diameter about its centre
    (horizontally), on the plane fitted to the rendered heights along it
    (:meth:`Labeller.crater_geometry`: level at the crest height for a crater on level ground,
    tilted with the ground on a slope and with the planetary curvature's drop). With ``H`` the
    homography from that plane's coordinates ``(s, t)`` (metres east and north of the centre)
    to pixels, ``H = K R_CW [e_s, e_t, P_0 - C]``, the circle ``s^2 + t^2 = R^2`` maps to the
    conic ``A = H^-T diag(1, 1, -R^2) H^-1`` (Hartley and Zisserman 2004, sec. 2.2.3; Christian
    et al. 2021, "Lunar crater identification in digital images", J. Astronaut. Sci. 68, 1056,
    eq. 9), and its centre, semi-axes and angle follow from ``A``. The angle is the major
    axis's, in degrees from the image's +u axis towards +v, in [0, 180). Visibility is sampled
    at :data:`RIM_SAMPLES` points of the 3-D rim: the fraction in the frame, the fraction of
    those hidden by terrain (the rendered range at the point's pixel shorter than the point's
    distance), and the fraction of the visible ones lit (not shadowed in the semantic mask).
Instance mask
    Each pixel the number of the instance its surface point belongs to (0: none): a crater
    where the point lies within its rim radius horizontally (smaller craters over larger
    ones), a rock where it lies within the rock's footprint ellipse (its catalogue semi-axes
    stretched by the outline's largest harmonic, :data:`ROCK_OUTLINE_STRETCH`) and above its
    base by :data:`ROCK_BASE_FRACTION` of its height (rocks over craters). The frame's
    instance table maps each number to its catalogue (``crater``/``rock``) and stable id (the
    catalogue's 16 hex digits).
Semantic mask
    :data:`SKY` (no surface), :data:`TERRAIN`, :data:`ROCK`, and :data:`SHADOWED` for any
    surface the sun does not reach directly (facing away from it, or its I/F below
    :data:`SHADOW_FRACTION` of the lit value its incidence would give).
Flow
    Forward optical flow to the next frame: each pixel's surface point (its range along its
    ray) projected with the next frame's pose (an asteroid's point turned with the body),
    ``(du, dv)`` pixels; the occlusion mask marks pixels whose point leaves the next frame or
    is hidden there (the next range at the landing pixel shorter than the point's distance by
    more than :func:`occlusion_tolerance`).
Hazards
    The scene's hazard map (:func:`terrain.surface.hazards.hazard_map`, for the lander the
    ``[labels]`` table names) sampled at each pixel's surface point: :data:`UNSAFE`,
    :data:`SAFE` or :data:`UNKNOWN` (sky, outside the hazard layer, or an unknown footprint).

Terrain scenes carry the catalogues; an asteroid scene gets the semantic mask, flow and no
rims, instances or hazards. Labels are computed on request only (a scenario's ``[labels]``
table, ``--labels``, or the server's ``GET_LABELS``); the dataset they make on disk is
described in ``docs/labels.md``.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from typing import Any

import numba
import numpy as np

from render.camera import Intrinsics, Pose, quat_to_matrix
from terrain.core.checks import boolean, check_keys, number
from terrain.core.errors import InvalidParameterError

__all__ = ["LABEL_KEYS", "ROCK", "SAFE", "SHADOWED", "SKY", "TERRAIN", "UNKNOWN", "UNSAFE",
           "FrameLabels", "LabelSpec", "Labeller", "ellipse_from_conic", "ellipses_from_conics",
           "flow_to", "rim_conic", "rim_conics", "shadow_mask"]

log = logging.getLogger(__name__)

#: Semantic classes (uint8).
SKY, TERRAIN, ROCK, SHADOWED = 0, 1, 2, 3
#: Hazard classes in image space (uint8).
UNSAFE, SAFE, UNKNOWN = 0, 1, 255
#: Points sampled on each 3-D rim for its visibility.
RIM_SAMPLES = 64
#: A surface is shadowed where its I/F is below this fraction of ``albedo * cos(incidence)``
#: (Lambert's I/F; lunar-Lambert and Hapke give at least about as much at the incidences a
#: descent sees), so earthshine or scattered light in a shadow does not count as lit.
SHADOW_FRACTION = 0.05
#: A rock's footprint ellipse is stretched by this factor, the largest outline harmonic
#: sum :mod:`terrain.surface.rocks` draws (its catalogue keeps the mean semi-axes only).
ROCK_OUTLINE_STRETCH = 1.3
#: A point belongs to a rock when it stands above the rock's base by this fraction of the
#: rock's exposed height (the ground at the rock's foot is the base).
ROCK_BASE_FRACTION = 0.1
#: The most instances one frame's mask numbers (uint16 PNG); the smallest beyond are dropped.
MAX_INSTANCES = 65535
#: Keys of a ``[labels]`` table.
LABEL_KEYS = frozenset({"craters", "min_crater_pixels", "masks", "flow", "hazards",
                        "lander_diameter", "max_slope", "max_step"})


@dataclass(frozen=True)
class LabelSpec:
    """What labels to compute (a scenario's ``[labels]`` table).

    Parameters
    ----------
    craters : bool
        Project crater rims (terrain scenes).
    min_crater_pixels : float
        Smallest rim diameter labelled, pixels (> 0).
    masks : bool
        Instance and semantic masks.
    flow : bool
        Forward optical flow to the next frame, with its occlusion mask.
    hazards : bool
        The hazard map in image space (needs ``lander_diameter``).
    lander_diameter : float or None
        The lander's footprint diameter, metres.
    max_slope : float
        Steepest safe slope, degrees.
    max_step : float
        Highest safe step (rock, rim) inside the footprint, metres.
    """

    craters: bool = True
    min_crater_pixels: float = 8.0
    masks: bool = True
    flow: bool = True
    hazards: bool = False
    lander_diameter: float | None = None
    max_slope: float = 10.0
    max_step: float = 0.3

    def __post_init__(self):
        if not (self.min_crater_pixels > 0 and math.isfinite(self.min_crater_pixels)):
            raise InvalidParameterError(
                f"labels min_crater_pixels must be positive; got {self.min_crater_pixels}")
        if self.hazards and self.lander_diameter is None:
            raise InvalidParameterError("labels hazards need the lander: give lander_diameter "
                                        "(m), max_slope (degrees) and max_step (m)")

    @classmethod
    def from_mapping(cls, table: Any) -> LabelSpec:
        """Build the record of a ``[labels]`` table; an unknown key names the nearest.

        Parameters
        ----------
        table : dict
            The TOML table.

        Returns
        -------
        LabelSpec

        Examples
        --------
        >>> LabelSpec.from_mapping({"min_crater_pixels": 4}).min_crater_pixels
        4.0
        """
        where = "scenario [labels]"
        t = check_keys(table, LABEL_KEYS, where)
        d = cls()
        values: dict[str, Any] = {}
        for key in ("craters", "masks", "flow"):
            values[key] = boolean(t.get(key, getattr(d, key)), key, where=where)
        values["min_crater_pixels"] = number(t.get("min_crater_pixels", d.min_crater_pixels),
                                             "min_crater_pixels", low=0.0, where=where)
        if "lander_diameter" in t:
            values["lander_diameter"] = number(t["lander_diameter"], "lander_diameter",
                                               low=0.0, where=where)
        values["hazards"] = boolean(t.get("hazards", "lander_diameter" in t), "hazards",
                                    where=where)
        values["max_slope"] = number(t.get("max_slope", d.max_slope), "max_slope", low=0.0,
                                     high=90.0, where=where)
        values["max_step"] = number(t.get("max_step", d.max_step), "max_step", low=0.0,
                                    where=where)
        return cls(**values)

    def as_dict(self) -> dict:
        """Return the spec as plain data (for a run's manifest)."""
        return {k: getattr(self, k) for k in self.__dataclass_fields__}


# ---------------------------------------------------------------------------- conics


def rim_conic(centre, radius: float, gradient, pose: Pose, intrinsics: Intrinsics) -> np.ndarray:
    """Give the image conic of a rim circle (see the module docstring).

    Parameters
    ----------
    centre : (3,) float, metres
        The rim circle's centre, world frame.
    radius : float, metres
        Its radius, measured horizontally.
    gradient : (2,) float
        The rim plane's height gradient (dz/dx, dz/dy); (0, 0) for a level rim.
    pose : render.camera.Pose
        The camera.
    intrinsics : render.camera.Intrinsics
        Its pinhole.

    Returns
    -------
    (3, 3) float64
        The symmetric conic matrix A, normalised to unit Frobenius norm: pixels (u, v) on the
        rim's image satisfy ``[u, v, 1] A [u, v, 1]^T = 0``.

    Examples
    --------
    >>> from render.camera import look_at
    >>> k = Intrinsics(101, 101, 100.0, 100.0, 50.0, 50.0)
    >>> a = rim_conic((0, 0, 0), 10.0, (0, 0), look_at((0, 0, 100), (0, 0, 0)), k)
    >>> [round(v, 6) for v in ellipse_from_conic(a)[:4]]
    [50.0, 50.0, 10.0, 10.0]
    """
    return rim_conics(np.reshape(centre, (1, 3)), np.reshape(radius, 1),
                      np.reshape(gradient, (1, 2)), pose, intrinsics)[0]


def rim_conics(centres: np.ndarray, radii: np.ndarray, gradients: np.ndarray, pose: Pose,
               intrinsics: Intrinsics) -> np.ndarray:
    """Give the image conics of many rim circles at once (:func:`rim_conic`).

    Parameters
    ----------
    centres : (n, 3) float, metres
    radii : (n,) float, metres
    gradients : (n, 2) float
    pose : render.camera.Pose
    intrinsics : render.camera.Intrinsics

    Returns
    -------
    (n, 3, 3) float64
        Each rim's conic matrix, unit Frobenius norm.
    """
    centres = np.asarray(centres, np.float64).reshape(-1, 3)
    n = len(centres)
    basis = np.zeros((n, 3, 3))
    basis[:, 0, 0] = basis[:, 1, 1] = 1.0
    basis[:, 2, 0], basis[:, 2, 1] = gradients[:, 0], gradients[:, 1]
    basis[:, :, 2] = centres - np.asarray(pose.position)
    h = (intrinsics.matrix @ pose.rotation.T) @ basis
    hinv = np.linalg.inv(h)
    q = np.zeros((n, 3, 3))
    q[:, 0, 0] = q[:, 1, 1] = 1.0
    q[:, 2, 2] = -np.asarray(radii, np.float64) ** 2
    a = np.transpose(hinv, (0, 2, 1)) @ q @ hinv
    a = 0.5 * (a + np.transpose(a, (0, 2, 1)))
    return a / np.linalg.norm(a, axis=(1, 2))[:, None, None]


def ellipses_from_conics(a: np.ndarray) -> np.ndarray:
    """Give ``(u, v, major, minor, angle)`` of many conics (:func:`ellipse_from_conic`).

    Parameters
    ----------
    a : (n, 3, 3) float
        Symmetric conic matrices.

    Returns
    -------
    (n, 5) float64
        One row per conic; NaN where it is no real ellipse.
    """
    out = np.full((len(a), 5), np.nan)
    m = a[:, :2, :2]
    ok = np.linalg.det(m) > 0  # else a parabola or hyperbola: the rim reaches behind the camera
    if not ok.any():
        return out
    a, m = a[ok], m[ok]
    x0 = -np.linalg.solve(m, a[:, :2, 2:3])[:, :, 0]
    g = -(a[:, 2, 2] + np.einsum("ni,ni->n", x0, a[:, :2, 2]))
    lam, vec = np.linalg.eigh(m)  # ascending: the first is the major axis's
    with np.errstate(divide="ignore", invalid="ignore"):
        major, minor = np.sqrt(g / lam[:, 0]), np.sqrt(g / lam[:, 1])
    angle = np.degrees(np.arctan2(vec[:, 1, 0], vec[:, 0, 0])) % 180.0
    rows = np.column_stack([x0, major, minor, angle])
    rows[~(np.isfinite(major) & np.isfinite(minor) & (g / lam[:, 0] > 0))] = np.nan
    out[ok] = rows
    return out


def ellipse_from_conic(a: np.ndarray) -> tuple[float, float, float, float, float] | None:
    """Give centre, semi-axes and angle of an ellipse conic; None if it is no real ellipse.

    Parameters
    ----------
    a : (3, 3) float
        A symmetric conic matrix.

    Returns
    -------
    (u, v, major, minor, angle) or None
        Centre (pixels), semi-major and semi-minor axes (pixels), and the major axis's angle
        (degrees from +u towards +v, in [0, 180)).
    """
    row = ellipses_from_conics(np.asarray(a, np.float64)[None])[0]
    if not np.all(np.isfinite(row)):
        return None
    u, v, major, minor, angle = (float(x) for x in row)
    return u, v, major, minor, angle


# ---------------------------------------------------------------------------- per pixel


def surface_points(range_m: np.ndarray, pose: Pose, intrinsics: Intrinsics) -> np.ndarray:
    """(h, w, 3) float64 world points of every pixel's surface (NaN where none)."""
    rays = intrinsics.rays() @ pose.rotation.T
    return np.asarray(pose.position) + rays * range_m.astype(np.float64)[:, :, None]


def shadow_mask(radiance: np.ndarray, normals: np.ndarray, lighting: Any) -> np.ndarray:
    """Give the pixels the sun does not reach directly (see the module docstring).

    Parameters
    ----------
    radiance : (h, w) float32
        I/F under a unit sun.
    normals : (h, w, 3) float32
        World-frame normals (NaN: no surface).
    lighting : render.renderer.Lighting
        The sun and the surface's albedo (Hapke's single-scattering albedo w for ``hapke``).

    Returns
    -------
    (h, w) bool
        True on shadowed surface; False on lit surface and where there is none.
    """
    mu0 = normals.astype(np.float64) @ np.asarray(lighting.sun, np.float64)
    albedo = lighting.hapke.w if lighting.brdf == "hapke" else lighting.albedo
    hit = np.isfinite(mu0)
    with np.errstate(invalid="ignore"):
        dark = (mu0 <= 0) | (radiance < SHADOW_FRACTION * albedo * mu0)
    return hit & dark


def occlusion_tolerance(distance: np.ndarray, focal: float) -> np.ndarray:
    """Give the range shortfall (m) that counts as hidden at ``distance`` m.

    Three pixel footprints (a range image's slope across a pixel at grazing incidence) plus
    0.2 % of the distance (the level of detail's geometric error, within ``lod_pixels``).
    """
    return 3.0 * distance / focal + 2e-3 * distance


def flow_to(range_m: np.ndarray, pose: Pose, next_pose: Pose, intrinsics: Intrinsics,
            next_range: np.ndarray | None = None, *,
            turn: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Give the forward optical flow of a frame to the next, and its occlusion mask.

    Parameters
    ----------
    range_m : (h, w) float32, metres
        This frame's range (NaN: nothing).
    pose, next_pose : render.camera.Pose
        The two frames' cameras.
    intrinsics : render.camera.Intrinsics
        Both frames' pinhole.
    next_range : (h, w) float32, optional
        The next frame's range: points hidden there are marked occluded.
    turn : (3, 3) float, optional
        The rotation carrying a world point of this frame to the next (a spinning body,
        ``R_WB(t1) R_WB(t0)^T``); identity by default.

    Returns
    -------
    flow : (h, w, 2) float32, pixels
        ``(du, dv)``: where each pixel's surface point lands in the next frame, less its
        own pixel; NaN where there is no surface.
    occluded : (h, w) bool
        The point leaves the next frame, falls behind its camera, or is hidden there.
    """
    k = intrinsics
    p = surface_points(range_m, pose, k).reshape(-1, 3)
    if turn is not None:
        p = p @ np.asarray(turn, np.float64).T
    uv = next_pose.project(p, k)
    v, u = np.mgrid[0:k.height, 0:k.width]
    flow = np.stack([uv[:, 0].reshape(k.height, k.width) - u,
                     uv[:, 1].reshape(k.height, k.width) - v], axis=-1).astype(np.float32)
    hit = np.isfinite(range_m)
    flow[~hit] = np.nan
    with np.errstate(invalid="ignore"):
        ui, vi = np.rint(uv[:, 0]), np.rint(uv[:, 1])
        inside = (ui >= 0) & (ui < k.width) & (vi >= 0) & (vi < k.height)
    occluded = ~inside
    if next_range is not None:
        idx = np.flatnonzero(inside)
        dist = np.linalg.norm(p[idx] - np.asarray(next_pose.position), axis=1)
        seen = next_range[vi[idx].astype(np.intp), ui[idx].astype(np.intp)].astype(np.float64)
        with np.errstate(invalid="ignore"):
            hidden = ~(seen >= dist - occlusion_tolerance(dist, k.fx))
        occluded[idx[hidden]] = True
    occluded = occluded.reshape(k.height, k.width) & hit
    return flow, occluded


# ---------------------------------------------------------------------------- records


@dataclass(eq=False)
class FrameLabels:
    """The labels of one frame (see the module docstring).

    Parameters
    ----------
    craters : list of dict
        One record per labelled rim: ``id`` (16 hex digits), ``layer``, ``diameter_m``,
        ``centre_world`` (m), ``ellipse`` ``{"centre": [u, v], "axes": [major, minor],
        "angle_deg": ..}``, ``conic`` (the 3 x 3 matrix, row by row), ``in_frame``,
        ``occluded`` (of the in-frame samples), ``lit`` (of the visible samples) fractions,
        and ``instance`` (its number in the instance mask, 0 if it covers no pixel).
    instances : list of dict
        ``{"instance": n, "kind": "crater" | "rock", "id": hex, "pixels": count}``.
    instance_mask : (h, w) uint16 or None
    semantic : (h, w) uint8 or None
    hazard : (h, w) uint8 or None
    flow : (h, w, 2) float32 or None
    occluded : (h, w) bool or None
    """

    craters: list = field(default_factory=list)
    instances: list = field(default_factory=list)
    instance_mask: np.ndarray | None = None
    semantic: np.ndarray | None = None
    hazard: np.ndarray | None = None
    flow: np.ndarray | None = None
    occluded: np.ndarray | None = None

    def as_dict(self) -> dict:
        """Return the craters and instances as plain data (the frame's labels JSON)."""
        return {"craters": self.craters, "instances": self.instances}


def _hex(uid) -> str:
    return f"{int(uid):016x}"


class Labeller:
    """Computes the labels of frames of one scene (see the module docstring).

    Parameters
    ----------
    scene : render.scene.Scene
        The frames' scene (a :class:`render.terrain_scene.TerrainScene` carries catalogues).
    spec : LabelSpec
        What to compute.
    """

    def __init__(self, scene: Any, spec: LabelSpec) -> None:
        self.scene = scene
        self.spec = spec
        stack = getattr(scene, "stack", None)
        self.catalog = stack.catalog if stack is not None else None
        self.rocks = stack.rocks if stack is not None else None
        self._hazard: Any = None
        self._geometry: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        #: The catalogue ids as written (16 hex digits), once.
        self._crater_ids = [] if self.catalog is None else [
            f"{v:016x}" for v in self.catalog.id.tolist()]
        if spec.hazards and stack is None:
            raise InvalidParameterError("labels hazards need a terrain scene (a layer stack)")

    # ------------------------------------------------------------------ craters
    def crater_geometry(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Give the catalogue's 3-D rim circles, fitted to the terrain once per labeller.

        A crater's rim circle lies on the plane ``z = z0 + gx s + gy t`` fitted (least
        squares) to the rendered heights at :data:`RIM_SAMPLES` points of its rim, the circle
        of its catalogue radius about its centre, in the finest layer that holds the whole
        rim (curvature drop included): the rim crest of a fresh crater on level ground, and
        the tilted rim of one on a slope. With evenly spaced samples the fit is closed form:
        ``z0`` the mean height, ``(gx, gy) = 2 / (n R) sum z (cos, sin)``.

        Returns
        -------
        centres : (n, 3) float64, metres
            The rim circles' centres, world frame.
        radii : (n,) float64, metres
            Their radii (horizontal).
        gradients : (n, 2) float64
            Their planes' slopes dz/dx, dz/dy.
        """
        if self._geometry is not None:
            return self._geometry
        from scipy.ndimage import map_coordinates

        c = self.catalog
        if c is None:
            raise InvalidParameterError("crater rims need a terrain scene with a crater "
                                        "catalogue")
        n = len(c)
        radii = 0.5 * c.diameter_m
        # the catalogue's level rim where no layer holds it whole
        pts = np.stack([c.x_m, c.y_m, c.reference_elevation_m + c.rim_height_m], axis=1)
        centres = self.scene.to_world(pts) if n else pts.reshape(0, 3)
        grad = np.zeros((n, 2))
        th = np.linspace(0.0, 2 * math.pi, RIM_SAMPLES, endpoint=False)
        cos, sin = np.cos(th), np.sin(th)
        todo = np.ones(n, bool)
        for tile in reversed(self.scene.stack.tiles):
            left, bottom, right, top = tile.bounds
            inside = todo & (c.x_m - radii >= left) & (c.x_m + radii <= right) \
                & (c.y_m - radii >= bottom) & (c.y_m + radii <= top)
            idx = np.flatnonzero(inside)
            if not len(idx):
                continue
            x = c.x_m[idx, None] + radii[idx, None] * cos
            y = c.y_m[idx, None] + radii[idx, None] * sin
            row, col = tile.rowcol(x, y)
            z = map_coordinates(tile.heights.astype(np.float64), [row.ravel(), col.ravel()],
                                order=1, mode="nearest").reshape(x.shape)
            z = self.scene.to_world(np.stack([x.ravel(), y.ravel(), z.ravel()], axis=1))[:, 2] \
                .reshape(x.shape)
            centres[idx, 2] = z.mean(axis=1)
            grad[idx, 0] = 2.0 / (RIM_SAMPLES * radii[idx]) * (z @ cos)
            grad[idx, 1] = 2.0 / (RIM_SAMPLES * radii[idx]) * (z @ sin)
            todo[idx] = False
        self._geometry = (centres, radii, grad)
        return self._geometry

    def rims(self, pose: Pose, k: Intrinsics, range_m: np.ndarray,
             shadowed: np.ndarray | None) -> list[dict]:
        """Label the rims of the catalogue's craters large enough in this view.

        Parameters
        ----------
        pose : render.camera.Pose
            The frame's camera.
        k : render.camera.Intrinsics
            Its pinhole.
        range_m : (h, w) float32, metres
            The frame's range (the occlusion test).
        shadowed : (h, w) bool, optional
            The frame's shadows (the lit fraction; None: not computed).

        Returns
        -------
        list of dict
            The rim records (:class:`FrameLabels`), largest first.
        """
        if self.catalog is None or not len(self.catalog):
            return []
        centres, radii, grad = self.crater_geometry()
        cam = pose.to_camera(centres)
        dist = np.linalg.norm(cam, axis=1)
        # a rim's image spans at most f D / (distance - R); nearer than that it may reach
        # behind the camera, and farther than f D / min px it is too small
        near = dist - radii
        with np.errstate(divide="ignore"):
            span = np.where(near > 0, 2 * radii * max(k.fx, k.fy) / np.maximum(near, 1e-9),
                            np.inf)
        half_fov = math.hypot(k.width, k.height) / min(k.fx, k.fy)
        ahead = cam[:, 2] > -radii
        lateral = np.hypot(cam[:, 0], cam[:, 1]) - radii
        in_cone = lateral <= half_fov * np.maximum(cam[:, 2] + radii, 0.0) + radii
        pick = np.flatnonzero((span >= self.spec.min_crater_pixels) & ahead & in_cone)
        pick = pick[near[pick] > 0]  # within the rim's sphere the rim has no closed image
        pick = pick[np.argsort(-radii[pick], kind="stable")]
        conics = rim_conics(centres[pick], radii[pick], grad[pick], pose, k)
        ells = ellipses_from_conics(conics)
        ok = np.isfinite(ells[:, 0]) & (2 * ells[:, 2] >= self.spec.min_crater_pixels)
        pick, conics, ells = pick[ok], conics[ok], ells[ok]
        # the rims' sample points, (n, RIM_SAMPLES, 3), projected at once
        th = np.linspace(0.0, 2 * math.pi, RIM_SAMPLES, endpoint=False)
        ds = radii[pick, None] * np.cos(th)
        dt = radii[pick, None] * np.sin(th)
        pts = np.stack([centres[pick, 0, None] + ds, centres[pick, 1, None] + dt,
                        centres[pick, 2, None] + grad[pick, 0, None] * ds
                        + grad[pick, 1, None] * dt], axis=-1)
        rel = pts - np.asarray(pose.position)
        cam_pts = rel @ pose.rotation
        dist_pts = np.linalg.norm(rel, axis=-1)
        with np.errstate(divide="ignore", invalid="ignore"):
            ui = np.rint(k.fx * cam_pts[..., 0] / cam_pts[..., 2] + k.cx)
            vi = np.rint(k.fy * cam_pts[..., 1] / cam_pts[..., 2] + k.cy)
            inside = (cam_pts[..., 2] > 0) & (ui >= 0) & (ui < k.width) & (vi >= 0) \
                & (vi < k.height)
        ui = np.where(inside, ui, 0).astype(np.intp)
        vi = np.where(inside, vi, 0).astype(np.intp)
        with np.errstate(invalid="ignore"):
            hidden = inside & ~(range_m[vi, ui] >= dist_pts
                                - occlusion_tolerance(dist_pts, k.fx))
        visible = inside & ~hidden
        n_in = inside.sum(axis=1)
        n_vis = visible.sum(axis=1)
        lit = None
        if shadowed is not None:
            lit = (visible & ~shadowed[vi, ui]).sum(axis=1) / np.maximum(n_vis, 1)
        c = self.catalog
        out = []
        for j in np.flatnonzero(n_in > 0):
            i = pick[j]
            e = ells[j]
            out.append({
                "id": self._crater_ids[i],
                "layer": int(c.layer[i]) if c.layer is not None else 0,
                "diameter_m": float(c.diameter_m[i]),
                "centre_world": centres[i].tolist(),
                "ellipse": {"centre": [float(e[0]), float(e[1])],
                            "axes": [float(e[2]), float(e[3])], "angle_deg": float(e[4])},
                "conic": conics[j].reshape(-1).tolist(),
                "in_frame": float(n_in[j] / RIM_SAMPLES),
                "occluded": float((n_in[j] - n_vis[j]) / n_in[j]),
                "lit": float(lit[j]) if lit is not None and n_vis[j] else None,
                "instance": 0})
        return out

    # ------------------------------------------------------------------ masks
    def instance_mask(self, points: np.ndarray, rims: list[dict],
                      pose: Pose, k: Intrinsics) -> tuple[np.ndarray, list[dict]]:
        """Give each pixel the number of its crater or rock (see the module docstring).

        Parameters
        ----------
        points : (h, w, 3) float64
            The pixels' world points (NaN: none).
        rims : list of dict
            The frame's rim records (their ``instance`` is filled in).
        pose : render.camera.Pose
            The camera.
        k : render.camera.Intrinsics
            Its pinhole.

        Returns
        -------
        mask : (h, w) uint16
        instances : list of dict
        """
        h, w = points.shape[:2]
        # provisional numbers: craters 1..m (largest first, so smaller ones paint over them),
        # then rocks; compacted to 1..K over what covers pixels at the end
        draft = np.zeros((h, w), np.int32)
        boxes = np.zeros((len(rims), 4), np.int64)
        for j, rec in enumerate(rims):
            u, v = rec["ellipse"]["centre"]
            ext = rec["ellipse"]["axes"][0] + 1.0
            boxes[j] = _box(u - ext, u + ext, v - ext, v + ext, w, h) or (0, 0, 0, 0)
        if len(rims):
            centre = np.array([rec["centre_world"][:2] for rec in rims], np.float64)
            r2 = (0.5 * np.array([rec["diameter_m"] for rec in rims])) ** 2
            _paint_discs(np.ascontiguousarray(points[..., 0]),
                         np.ascontiguousarray(points[..., 1]), draft, boxes,
                         centre[:, 0].copy(), centre[:, 1].copy(), r2)
        kinds: list[tuple[str, str]] = [("crater", rec["id"]) for rec in rims]
        for i in self._visible_rocks(pose, k):
            on, box = self._rock_pixels(points, i, pose, k)
            if box is None or not on.any():
                continue
            assert self.rocks is not None  # rocks are listed only where there are some
            r0, r1, c0, c1 = box
            draft[r0:r1, c0:c1][on] = len(kinds) + 1
            kinds.append(("rock", _hex(self.rocks.id[i])))
        counts = np.bincount(draft.reshape(-1), minlength=len(kinds) + 1)
        kept = np.flatnonzero(counts[1:]) + 1
        if len(kept) > MAX_INSTANCES:
            log.warning("frame has %d instances; the smallest beyond %d are not numbered",
                        len(kept), MAX_INSTANCES)
            kept = kept[:MAX_INSTANCES]
        lut = np.zeros(len(kinds) + 1, np.uint16)
        lut[kept] = np.arange(1, len(kept) + 1)
        mask = lut[draft]
        table = [{"instance": int(lut[p]), "kind": kinds[p - 1][0], "id": kinds[p - 1][1],
                  "pixels": int(counts[p])} for p in kept]
        for j, rec in enumerate(rims):  # 0: painted over entirely by smaller craters, or hidden
            rec["instance"] = int(lut[j + 1])
        return mask, table

    def _visible_rocks(self, pose: Pose, k: Intrinsics) -> np.ndarray:
        """Return the catalogue rocks at least a pixel wide ahead of the camera, largest first."""
        r = self.rocks
        if r is None or not len(r):
            return np.zeros(0, np.intp)
        base = self.scene.to_world(np.stack([r.x_m, r.y_m, r.z_base_m], axis=1))
        cam = pose.to_camera(base)
        reach = ROCK_OUTLINE_STRETCH * r.axis_a_m
        with np.errstate(divide="ignore", invalid="ignore"):
            span = 2 * reach * k.fx / cam[:, 2]
            u = k.fx * cam[:, 0] / cam[:, 2] + k.cx
            v = k.fy * cam[:, 1] / cam[:, 2] + k.cy
        ok = (cam[:, 2] > reach) & (span >= 1.0) & (u > -span) & (u < k.width + span) \
            & (v > -span) & (v < k.height + span)
        pick = np.flatnonzero(ok)
        return pick[np.argsort(-r.diameter_m[pick], kind="stable")]

    def _rock_pixels(self, points, i, pose, k):
        r = self.rocks
        reach = ROCK_OUTLINE_STRETCH * float(r.axis_a_m[i])
        base = self.scene.to_world([[r.x_m[i], r.y_m[i], r.z_base_m[i]]])[0]
        top = base[2] + float(r.height_m[i])
        corners = np.array([[base[0] + sx * reach, base[1] + sy * reach, z]
                            for sx in (-1, 1) for sy in (-1, 1) for z in (base[2], top)])
        uv = pose.project(corners, k)
        if not np.all(np.isfinite(uv)):
            return None, None
        box = _box(uv[:, 0].min() - 1, uv[:, 0].max() + 1, uv[:, 1].min() - 1,
                   uv[:, 1].max() + 1, k.width, k.height)
        if box is None:
            return None, None
        r0, r1, c0, c1 = box
        p = points[r0:r1, c0:c1]
        th = math.radians(float(r.orientation_deg[i]))
        dx, dy = p[..., 0] - base[0], p[..., 1] - base[1]
        along = dx * math.cos(th) + dy * math.sin(th)
        across = -dx * math.sin(th) + dy * math.cos(th)
        a = ROCK_OUTLINE_STRETCH * float(r.axis_a_m[i])
        b = ROCK_OUTLINE_STRETCH * float(r.axis_b_m[i])
        with np.errstate(invalid="ignore"):
            on = ((along / a) ** 2 + (across / b) ** 2 < 1.0) \
                & (p[..., 2] > base[2] + ROCK_BASE_FRACTION * float(r.height_m[i]))
        return on, box

    # ------------------------------------------------------------------ hazards
    def hazard_image(self, points: np.ndarray) -> np.ndarray:
        """Sample the scene's hazard map at each pixel's surface point (see the docstring)."""
        from terrain.surface.hazards import hazard_map, pick_layer

        spec = self.spec
        assert spec.lander_diameter is not None  # required of hazards by LabelSpec
        if self._hazard is None:
            tiles = self.scene.stack.tiles
            kl = pick_layer([t.resolution for t in tiles], spec.lander_diameter)
            tile = tiles[kl]
            self._hazard = (tile, hazard_map(tile, lander_diameter=spec.lander_diameter,
                                             max_slope=spec.max_slope,
                                             max_step=spec.max_step).safe)
        tile, safe = self._hazard
        h, w = points.shape[:2]
        out = np.full((h, w), UNKNOWN, np.uint8)
        x, y = points[..., 0], points[..., 1]
        hit = np.isfinite(x)
        row, col = tile.rowcol(np.where(hit, x, 0.0), np.where(hit, y, 0.0))
        row, col = np.rint(row), np.rint(col)
        ok = hit & (row >= 0) & (row < tile.shape[0]) & (col >= 0) & (col < tile.shape[1])
        s = safe[row[ok].astype(np.intp), col[ok].astype(np.intp)]
        vals = np.where(np.isnan(s), UNKNOWN, np.where(s > 0.5, SAFE, UNSAFE)).astype(np.uint8)
        out[ok] = vals
        return out

    # ------------------------------------------------------------------ a frame
    def label(self, frame: Any, pose: Pose, k: Intrinsics, lighting: Any) -> FrameLabels:
        """Label one rendered frame (everything but the flow, :meth:`add_flow`).

        Parameters
        ----------
        frame : render.renderer.Frame
            Its radiance, range and normals.
        pose : render.camera.Pose
            Its camera.
        k : render.camera.Intrinsics
            Its pinhole.
        lighting : render.renderer.Lighting
            Its sun.

        Returns
        -------
        FrameLabels
        """
        spec = self.spec
        shadowed = shadow_mask(frame.radiance, frame.normals, lighting)
        out = FrameLabels()
        if spec.craters:
            out.craters = self.rims(pose, k, frame.range, shadowed)
        need_points = spec.masks or spec.hazards
        points = surface_points(frame.range, pose, k) if need_points else None
        if spec.masks:
            assert points is not None
            if self.catalog is not None:
                out.instance_mask, out.instances = self.instance_mask(points, out.craters,
                                                                      pose, k)
            else:
                out.instance_mask = np.zeros(frame.range.shape, np.uint16)
            sem = np.where(np.isfinite(frame.range), TERRAIN, SKY).astype(np.uint8)
            rock_ids = {r["instance"] for r in out.instances if r["kind"] == "rock"}
            if rock_ids:
                sem[np.isin(out.instance_mask, sorted(rock_ids))] = ROCK
            sem[shadowed] = SHADOWED
            out.semantic = sem
        if spec.hazards:
            assert points is not None
            out.hazard = self.hazard_image(points)
        return out

    @staticmethod
    def add_flow(labels: FrameLabels, range_m: np.ndarray, pose: Pose, body_rotation,
                 next_range: np.ndarray, next_pose: Pose, next_body_rotation,
                 k: Intrinsics) -> None:
        """Fill in a frame's flow to the next frame (:func:`flow_to`)."""
        r0 = quat_to_matrix(body_rotation)
        r1 = quat_to_matrix(next_body_rotation)
        turn = r1 @ r0.T
        turn = None if np.allclose(turn, np.eye(3)) else turn
        labels.flow, labels.occluded = flow_to(range_m, pose, next_pose, k, next_range,
                                               turn=turn)


@numba.njit(cache=True)
def _paint_discs(px, py, mask, boxes, cx, cy, r2):  # pragma: no cover - compiled
    """Set ``mask`` to i + 1 where a pixel's point lies within disc i (in its image box)."""
    for i in range(boxes.shape[0]):
        for r in range(boxes[i, 0], boxes[i, 1]):
            for c in range(boxes[i, 2], boxes[i, 3]):
                x = px[r, c]
                if x != x:  # no surface
                    continue
                dx = x - cx[i]
                dy = py[r, c] - cy[i]
                if dx * dx + dy * dy < r2[i]:
                    mask[r, c] = i + 1


def _box(u0, u1, v0, v1, w, h):
    """Pixel rows/cols (r0, r1, c0, c1) of an image box, clipped; None when empty."""
    c0, c1 = max(int(math.floor(u0)), 0), min(int(math.ceil(u1)) + 1, w)
    r0, r1 = max(int(math.floor(v0)), 0), min(int(math.ceil(v1)) + 1, h)
    if c0 >= c1 or r0 >= r1:
        return None
    return r0, r1, c0, c1

