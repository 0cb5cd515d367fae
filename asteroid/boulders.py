r"""Multi-resolution boulders on the asteroid surface (Martin et al. 2014, section V.C).

"A multi-resolution mesh based on a regular icosahedron was developed to procedurally create
boulders from a small set of initial parameters that control the general form and roughness
characteristics. [...] Higher resolutions are obtained through RMD triangle edge subdivision
by inserting new vertices between existing vertices and new strips between existing strips."

Shape
-----
Level 0 is a regular icosahedron (circumradius 1) whose twelve vertices are pushed in or out
along their direction by ``sigma_0 N(0, 1)`` (:attr:`BoulderSettings.roughness`). Level l + 1
splits every triangle of level l into four at its edge midpoints, and each new vertex, the
midpoint of its edge, moves along its direction by ``sigma_0 2^-(l + 1) H N(0, 1)``: random
midpoint displacement with Hurst exponent H (:attr:`BoulderSettings.hurst`), so older
vertices never move and every level refines the one before. The shape is then scaled to the
boulder's size and "flattened": x by ``(D / 2) sqrt(e)``, y by ``(D / 2) / sqrt(e)`` and z by
``(D / 2) f`` for an elongation e and a flattening f drawn per boulder (the paper's Fig. 7
shows a flattened icosahedron). Every Gaussian is keyed
``(seed, "asteroid-boulder-shape", level, vertex a, vertex b, boulder id)`` with (a, b) the
edge's end vertices (a = b for the icosahedron's corners), so a boulder is a function of its
identity alone.

Levels of detail
----------------
Because refinement never moves a vertex, level l's vertices are the first ``10 4^l + 2`` of
the finest level's, and each level only needs its own triangle list. "Multi-resolution
boulders are represented as a sequence of bi-resolution nodes": :func:`lod_tree` builds the
paper's Fig. 7 chain, each node holding the lowest remaining level in its low branch and the
node of the higher levels in its high branch, down to (B + 2, B + 3) for four levels from B.

Placement
---------
Counts, positions (uniform on the sphere), sizes and identities come from a power-law
population exactly as craters do (:mod:`asteroid.placement`; boulder size-frequency slopes
are steeper than craters', about -3 to -4 on Eros, Thomas et al. 2001, hence the default
k = -3). "Each boulder is initially rotated so that the 'up' axis is aligned with the local
zenith axis [...] rotated about their local vertical axis to account for the longitude [...]
The 3D position on the surface is computed and then adjusted to take burial depth into
account. The boulder can then be randomly rotated around each local axis." The rotation is

    R = Rz(lon) Ry(colatitude) Rz(yaw) Ry(pitch) Rx(roll)

(identity at the north pole, 90 degrees at the equator, 180 at the south pole), yaw uniform
in [0, 360) degrees and pitch and roll uniform within +-:attr:`BoulderSettings.max_tilt_deg`.
The base of the unrotated boulder touches the body's surface (the flat-triangle mesh, so
renders and truth agree) along the zenith, then sinks by a burial fraction of its height
drawn uniformly in [0, :attr:`BoulderSettings.max_burial`].

Boulders are separate meshes (they overhang, so no radius function can hold them); the
catalogue is the ground truth: centre, size, height, burial, rotation.

Examples
--------
>>> lod = boulder_lod(seed=1, uid=7, levels=3)
>>> [len(f) for f in lod.faces], len(lod.vertices)
([20, 80, 320], 162)
>>> lod_tree(0, 4)
BiResolutionNode(low=0, high=BiResolutionNode(low=1, high=BiResolutionNode(low=2, high=3)))
"""

from __future__ import annotations

import logging
import math
from dataclasses import asdict, dataclass
from functools import lru_cache

import numpy as np

from asteroid.body import Body
from asteroid.catalog import BoulderCatalog
from asteroid.placement import Placement, sample
from terrain.core.errors import InvalidParameterError
from terrain.core.rng import check_seed, normal, stream_id
from terrain.craters.population import Population

__all__ = ["BiResolutionNode", "BoulderLOD", "BoulderSettings", "Boulders",
           "boulder_lod", "icosahedron", "lod_tree", "place_boulders", "subdivision"]

log = logging.getLogger(__name__)

BOULDER_STREAM = "asteroid-boulder"
STREAM_SHAPE = stream_id("asteroid-boulder-shape")
#: Most boulders a population may expect on one body.
MAX_BOULDERS = 2_000_000
#: Extra keyed uniforms per boulder: flattening, elongation, burial, yaw, pitch, roll.
_EXTRA = 6

def icosahedron() -> tuple[np.ndarray, np.ndarray]:
    """Regular icosahedron of circumradius 1: (12, 3) vertices, (20, 3) outward faces."""
    p = (1.0 + math.sqrt(5.0)) / 2.0
    v = np.array([[-1, p, 0], [1, p, 0], [-1, -p, 0], [1, -p, 0],
                  [0, -1, p], [0, 1, p], [0, -1, -p], [0, 1, -p],
                  [p, 0, -1], [p, 0, 1], [-p, 0, -1], [-p, 0, 1]], dtype=np.float64)
    v /= np.linalg.norm(v, axis=1)[:, None]
    f = np.array([[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11],
                  [1, 5, 9], [5, 11, 4], [11, 10, 2], [10, 7, 6], [7, 1, 8],
                  [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8], [3, 8, 9],
                  [4, 9, 5], [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1]], dtype=np.int64)
    return v, f


@lru_cache(maxsize=16)
def subdivision(levels: int) -> tuple[tuple[np.ndarray, ...], tuple[np.ndarray, ...]]:
    """Topology of ``levels`` levels of edge subdivision of the icosahedron.

    Returns
    -------
    faces : tuple of (20 4^l, 3) int64, one per level
    parents : tuple of (n_l, 2) int64
        For level l >= 1, the end vertices (a < b) of the edge each new vertex splits, in the
        order the new vertices are numbered (after all older vertices).
    """
    _, f = icosahedron()
    faces = [f]
    parents = []
    n = 12
    for _ in range(1, levels):
        e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
        e = np.sort(e, axis=1)
        uniq, inverse = np.unique(e, axis=0, return_inverse=True)
        mid = n + inverse.reshape(3, -1).T  # (faces, 3): midpoints of edges 01, 12, 20
        a, b, c = f[:, 0], f[:, 1], f[:, 2]
        m01, m12, m20 = mid[:, 0], mid[:, 1], mid[:, 2]
        f = np.concatenate([np.column_stack([a, m01, m20]), np.column_stack([m01, b, m12]),
                            np.column_stack([m20, m12, c]), np.column_stack([m01, m12, m20])])
        faces.append(f)
        parents.append(uniq)
        n += len(uniq)
    for a in faces + parents:
        a.flags.writeable = False
    return tuple(faces), tuple(parents)


@dataclass(frozen=True)
class BiResolutionNode:
    """The paper's bi-resolution node: a low-resolution level and the node (or level) above."""

    low: int
    high: BiResolutionNode | int


def lod_tree(base_level: int, levels: int) -> BiResolutionNode:
    """Return the chain of bi-resolution nodes for ``levels`` levels starting at ``base_level``."""
    if levels < 2:
        raise InvalidParameterError(f"a bi-resolution tree needs >= 2 levels; got {levels}")
    node = BiResolutionNode(base_level + levels - 2, base_level + levels - 1)
    for level in range(base_level + levels - 3, base_level - 1, -1):
        node = BiResolutionNode(level, node)
    return node


@dataclass(frozen=True, eq=False)
class BoulderLOD:
    """One boulder's levels of detail in its own frame (metres, z up, centred).

    Parameters
    ----------
    vertices : (10 4^(L-1) + 2, 3) float64
        Finest level's vertices; level l uses the first ``10 4^l + 2``.
    faces : tuple of (20 4^l, 3) int64
        Triangles of each level, outward wound.
    """

    vertices: np.ndarray
    faces: tuple

    def level(self, level: int) -> tuple[np.ndarray, np.ndarray]:
        """(vertices, faces) of one level of detail."""
        n = 10 * 4**level + 2
        return self.vertices[:n], self.faces[level]


def _unit_shapes(seed: int, uids: np.ndarray, levels: int, roughness: float,
                 hurst: float) -> np.ndarray:
    """(n, V, 3) unit-size RMD icosahedra for boulder identities ``uids``."""
    v0, _ = icosahedron()
    faces, parents = subdivision(levels)
    n_final = 10 * 4 ** (levels - 1) + 2
    keys = uids.view(np.int64)[:, None]
    out = np.empty((len(uids), n_final, 3))
    corner = np.arange(12)[None, :]
    g = normal(seed, STREAM_SHAPE, 0, corner, corner, keys)
    out[:, :12] = v0[None] * (1.0 + roughness * g)[..., None]
    n = 12
    for level, par in enumerate(parents, start=1):
        mid = 0.5 * (out[:, par[:, 0]] + out[:, par[:, 1]])
        direction = mid / np.linalg.norm(mid, axis=-1, keepdims=True)
        sigma = roughness * 2.0 ** (-level * hurst)
        g = normal(seed, STREAM_SHAPE, level, par[None, :, 0], par[None, :, 1], keys)
        out[:, n:n + len(par)] = mid + (sigma * g)[..., None] * direction
        n += len(par)
    return out


def boulder_lod(*, seed: int, uid: int, levels: int = 4, roughness: float = 0.12,
                hurst: float = 0.8, diameter: float = 1.0, flattening: float = 1.0,
                elongation: float = 1.0) -> BoulderLOD:
    """Levels of detail of one boulder (see the module docstring), in metres."""
    seed = check_seed(seed)
    unit = _unit_shapes(seed, np.array([uid], dtype=np.uint64), levels, roughness, hurst)[0]
    scale = 0.5 * diameter * np.array([math.sqrt(elongation), 1.0 / math.sqrt(elongation),
                                       flattening])
    faces, _ = subdivision(levels)
    return BoulderLOD(unit * scale, faces)


@dataclass(frozen=True)
class BoulderSettings:
    """Boulder shape and placement parameters.

    Parameters
    ----------
    levels : int
        Levels of detail (the paper's Fig. 7 has 4), 1 .. 7.
    roughness : float
        sigma_0: displacement of the icosahedron's corners, fraction of the radius.
    hurst : float
        Hurst exponent of the midpoint displacement, (0, 1].
    flattening : (float, float)
        Range of the height-to-width ratio f.
    elongation : (float, float)
        Range of the length-to-width ratio e (>= 1).
    max_burial : float
        Largest buried fraction of the height, [0, 1).
    max_tilt_deg : float
        Largest random pitch and roll, degrees.
    """

    levels: int = 4
    roughness: float = 0.12
    hurst: float = 0.8
    flattening: tuple = (0.5, 0.9)
    elongation: tuple = (1.0, 1.5)
    max_burial: float = 0.4
    max_tilt_deg: float = 20.0

    def __post_init__(self):
        if isinstance(self.levels, bool) or not isinstance(self.levels, (int, np.integer)) \
                or not 1 <= self.levels <= 7:
            raise InvalidParameterError(f"boulder levels must be an integer in [1, 7]; got "
                                        f"{self.levels!r}")
        object.__setattr__(self, "levels", int(self.levels))
        if not 0 <= float(self.roughness) < 0.5:
            raise InvalidParameterError(f"boulder roughness must lie in [0, 0.5); got "
                                        f"{self.roughness}")
        if not 0 < float(self.hurst) <= 1:
            raise InvalidParameterError(f"boulder hurst must lie in (0, 1]; got {self.hurst}")
        for name, lo_ok in (("flattening", lambda v: 0 < v <= 2), ("elongation",
                                                                   lambda v: 1 <= v <= 4)):
            pair = tuple(float(v) for v in getattr(self, name))
            if len(pair) != 2 or not (lo_ok(pair[0]) and lo_ok(pair[1]) and pair[0] <= pair[1]):
                raise InvalidParameterError(f"boulder {name} must be a range (lo, hi) with "
                                            f"lo <= hi in the allowed interval; got {pair}")
            object.__setattr__(self, name, pair)
        if not 0 <= float(self.max_burial) < 1:
            raise InvalidParameterError(f"boulder max_burial must lie in [0, 1); got "
                                        f"{self.max_burial}")
        if not 0 <= float(self.max_tilt_deg) <= 90:
            raise InvalidParameterError(f"boulder max_tilt_deg must lie in [0, 90]; got "
                                        f"{self.max_tilt_deg}")
        for name in ("roughness", "hurst", "max_burial", "max_tilt_deg"):
            object.__setattr__(self, name, float(getattr(self, name)))

    def as_dict(self) -> dict:
        """Return the settings as plain data for the model's metadata (tuples as lists)."""
        d = asdict(self)
        d["flattening"] = list(self.flattening)
        d["elongation"] = list(self.elongation)
        return d


def rotation_z(a):
    c, s = np.cos(a), np.sin(a)
    r = np.zeros(np.shape(a) + (3, 3))
    r[..., 0, 0], r[..., 0, 1], r[..., 1, 0], r[..., 1, 1], r[..., 2, 2] = c, -s, s, c, 1.0
    return r


def rotation_y(a):
    c, s = np.cos(a), np.sin(a)
    r = np.zeros(np.shape(a) + (3, 3))
    r[..., 0, 0], r[..., 0, 2], r[..., 2, 0], r[..., 2, 2], r[..., 1, 1] = c, s, -s, c, 1.0
    return r


def rotation_x(a):
    c, s = np.cos(a), np.sin(a)
    r = np.zeros(np.shape(a) + (3, 3))
    r[..., 1, 1], r[..., 1, 2], r[..., 2, 1], r[..., 2, 2], r[..., 0, 0] = c, -s, s, c, 1.0
    return r


def local_shapes(seed: int, settings: BoulderSettings, uid, diameter, elongation,
                  flattening) -> np.ndarray:
    """(n, V, 3) finest-level vertices of boulders in their own frames, metres."""
    unit = _unit_shapes(seed, np.asarray(uid, dtype=np.uint64), settings.levels,
                        settings.roughness, settings.hurst)
    d, e, f = diameter, elongation, flattening
    scale = 0.5 * d[:, None] * np.column_stack([np.sqrt(e), 1.0 / np.sqrt(e), f])
    return unit * scale[:, None, :]


@dataclass(frozen=True, eq=False)
class Boulders:
    """Boulders placed on a body: their catalogue and, on demand, their meshes.

    Parameters
    ----------
    catalog : asteroid.catalog.BoulderCatalog
    settings : BoulderSettings
    seed : int
    """

    catalog: BoulderCatalog
    settings: BoulderSettings
    seed: int

    def __len__(self) -> int:
        return len(self.catalog)

    def rotations(self) -> np.ndarray:
        """(n, 3, 3) rotation of each boulder from its own frame to the body frame."""
        return self.catalog.rotations()

    def local_shapes(self, chunk: slice | None = None) -> np.ndarray:
        """(n, V, 3) finest-level vertices of the boulders in their own frames, metres."""
        c = self.catalog
        sl = chunk or slice(None)
        return local_shapes(self.seed, self.settings, c.id[sl], c.diameter_m[sl],
                             c.elongation[sl], c.flattening[sl])

    def mesh(self, level: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """All boulders at one level of detail (default the finest) in the body frame.

        Returns
        -------
        vertices : (n V_l, 3) float64, metres
        faces : (n F_l, 3) int64
        """
        levels = self.settings.levels
        level = levels - 1 if level is None else int(level)
        if not 0 <= level < levels:
            raise InvalidParameterError(f"boulder level must lie in [0, {levels}); got {level}")
        faces_all, _ = subdivision(levels)
        nv = 10 * 4**level + 2
        f = faces_all[level]
        n = len(self)
        if n == 0:
            return np.zeros((0, 3)), np.zeros((0, 3), np.int64)
        c = self.catalog
        centres = np.column_stack([c.x_m, c.y_m, c.z_m])
        rot = self.rotations()
        out = np.empty((n, nv, 3))
        step = 4096
        for start in range(0, n, step):
            sl = slice(start, min(n, start + step))
            local = self.local_shapes(sl)[:, :nv]
            out[sl] = np.einsum("nij,nvj->nvi", rot[sl], local) + centres[sl, None, :]
        faces = (f[None, :, :] + (np.arange(n) * nv)[:, None, None]).reshape(-1, 3)
        return out.reshape(-1, 3), faces

    def lod(self, index: int) -> BoulderLOD:
        """Levels of detail of boulder ``index`` in its own frame."""
        shapes = self.local_shapes(slice(index, index + 1))[0]
        faces, _ = subdivision(self.settings.levels)
        return BoulderLOD(shapes, faces)


def place_boulders(body: Body, population: Population, *, seed: int,
                   settings: BoulderSettings | None = None) -> Boulders:
    """Sample a boulder population over the body and place every boulder on its surface.

    Parameters
    ----------
    body : Body
        The finished surface (after craters).
    population : Population
        Boulder sizes (diameter range, density per km^2 of D >= dmin, exponent k).
    seed : int
    settings : BoulderSettings, optional
    """
    seed = check_seed(seed)
    settings = settings or BoulderSettings()
    placement: Placement = sample(population, body.area(), seed=seed, stream=BOULDER_STREAM,
                                  extra_fields=_EXTRA, max_features=MAX_BOULDERS)
    n = len(placement)
    u = placement.extra
    f_lo, f_hi = settings.flattening
    e_lo, e_hi = settings.elongation
    flattening = f_lo + (f_hi - f_lo) * u[:, 0]
    elongation = e_lo + (e_hi - e_lo) * u[:, 1]
    burial = settings.max_burial * u[:, 2]
    tilt = math.radians(settings.max_tilt_deg)
    yaw = 2.0 * np.pi * u[:, 3]
    pitch = tilt * (2.0 * u[:, 4] - 1.0)
    roll = tilt * (2.0 * u[:, 5] - 1.0)
    lat, lon = placement.latitude, placement.longitude
    colat = np.pi / 2 - lat
    rot = (rotation_z(lon) @ rotation_y(colat) @ rotation_z(yaw) @ rotation_y(pitch)
           @ rotation_x(roll))
    surface = body.surface_radius(placement.directions) if n else np.zeros(0)
    # the lowest point of each unrotated boulder (its own frame) sets how far up it sits
    zmin = np.empty(n)
    height = np.empty(n)
    for start in range(0, n, 4096):
        sl = slice(start, min(n, start + 4096))
        z = local_shapes(seed, settings, placement.uid[sl], placement.diameters[sl],
                          elongation[sl], flattening[sl])[..., 2]
        zmin[sl] = z.min(axis=1)
        height[sl] = z.max(axis=1) - zmin[sl]
    depth = burial * height
    lift = -zmin - depth
    centres = placement.directions * (surface + lift)[:, None]
    cat = dict(id=placement.uid, lat_deg=np.degrees(lat), lon_deg=np.degrees(lon),
               x_m=centres[:, 0], y_m=centres[:, 1], z_m=centres[:, 2],
               diameter_m=placement.diameters, height_m=height, flattening=flattening,
               elongation=elongation, burial_fraction=burial, burial_depth_m=depth,
               surface_radius_m=surface, yaw_deg=np.degrees(yaw), pitch_deg=np.degrees(pitch),
               roll_deg=np.degrees(roll), size_class=placement.size_class)
    for i in range(3):
        for j in range(3):
            cat[f"r{i}{j}"] = rot[:, i, j]
    log.info("placed %d boulders", n)
    return Boulders(BoulderCatalog.from_columns(cat), settings, seed)
