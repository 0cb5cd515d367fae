r"""Synthetic bodies of any shape: a sphere packing, an implicit surface over it, a mesh.

Li et al. (2022) build small bodies that no radius function can hold (two lobes and a neck,
elongated, flattened) from a non-uniform packing of spheres, smooth the union of the spheres
into an implicit surface, and mesh it. Here:

1. **Packing.** A preset (:data:`PACKINGS`) is a list of lobes, each an ellipsoid (centre and
   semi-axes, in units of the body's size) filled with spheres whose centres and radii are
   drawn keyed by ``(seed, "asteroid-packing", lobe, sphere)``: radii uniform between
   ``rmin`` and ``rmax`` of the lobe's smallest semi-axis, centres uniform in the lobe's
   ellipsoid shrunk by the sphere's radius, so the packing is lumpy and non-uniform, and
   a "neck" lobe of small spheres joins two large ones.
2. **Implicit surface.** The signed distance to the union of the spheres, smoothed by a
   log-sum-exp (a soft minimum, ``d = -s ln sum exp(-(|x - c_i| - r_i) / s)``, with ``s``
   a fraction of the size: the metaball blending of the spheres), then scaled along the
   axes (elongated, flattened).
3. **Mesh.** Marching tetrahedra on a regular grid (each cube split into six tetrahedra
   around its main diagonal, the same in every cube, so neighbouring cubes agree on their
   shared faces); a vertex on each grid edge crossing the surface, shared by every
   tetrahedron that uses the edge, so the mesh is closed and manifold by construction. No
   grid value is exactly zero (zeros are nudged inwards), so no triangle degenerates.

The result is a :class:`asteroid.surface.MeshBody` of equivalent radius ``radius``; craters
and boulders go on it as on any closed shape (:mod:`asteroid.surface`).

Examples
--------
>>> body = packing_body("contact-binary", radius=500.0, seed=1, cells=40)
>>> body.check_closed()
>>> bool(abs(body.equivalent_radius - 500.0) < 1e-6 * 500.0)
True
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from asteroid.surface import MeshBody, signed_volume
from terrain.core.errors import InvalidParameterError
from terrain.core.rng import check_seed, stream_id, uniform

__all__ = ["PACKINGS", "Lobe", "Packing", "marching_tetrahedra", "packing_body",
           "sphere_packing"]

#: Random stream of the sphere packings.
PACKING_STREAM = stream_id("asteroid-packing")


@dataclass(frozen=True)
class Lobe:
    """An ellipsoid filled with spheres (lengths in units of the body's size).

    Parameters
    ----------
    centre : (float, float, float)
    axes : (float, float, float)
        Semi-axes.
    spheres : int
        How many spheres fill it.
    rmin, rmax : float
        Sphere radii as fractions of the smallest semi-axis.
    """

    centre: tuple
    axes: tuple
    spheres: int
    rmin: float = 0.35
    rmax: float = 0.7


@dataclass(frozen=True)
class Packing:
    """A preset: lobes, blending and the overall stretch (x, y, z scale factors)."""

    lobes: tuple
    blend: float = 0.08
    stretch: tuple = (1.0, 1.0, 1.0)


#: Presets: two lobes and a neck (a contact binary, about 2:1 in size, like Itokawa or
#: Arrokoth), and a 67P-like nucleus (a large flattened lobe, a smaller head, a narrow neck).
PACKINGS = {
    "contact-binary": Packing(
        lobes=(Lobe((-0.75, 0.0, 0.0), (0.6, 0.5, 0.45), 24),
               Lobe((0.8, 0.0, 0.0), (0.45, 0.4, 0.38), 18),
               Lobe((0.05, 0.0, 0.0), (0.45, 0.14, 0.13), 10, 0.7, 0.95)),
        blend=0.06, stretch=(1.0, 0.95, 0.85)),
    "67p-like": Packing(
        lobes=(Lobe((-0.5, 0.0, -0.05), (0.75, 0.55, 0.42), 32),
               Lobe((0.75, 0.05, 0.45), (0.45, 0.38, 0.33), 20),
               Lobe((0.22, 0.02, 0.2), (0.3, 0.15, 0.14), 8, 0.7, 0.95)),
        blend=0.05, stretch=(1.1, 1.0, 0.8)),
}


def sphere_packing(packing: Packing, *, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Centres (n, 3) and radii (n,) of a preset's spheres, in units of the body's size."""
    seed = check_seed(seed)
    centres, radii = [], []
    for li, lobe in enumerate(packing.lobes):
        k = np.arange(lobe.spheres)
        u = uniform(seed, PACKING_STREAM, 0, li, k[:, None], np.arange(5)[None, :])
        axes = np.asarray(lobe.axes, dtype=np.float64)
        r = (lobe.rmin + (lobe.rmax - lobe.rmin) * u[:, 0]) * axes.min()
        # a uniform point in the unit ball (radius u^(1/3), direction from two uniforms)
        z = 2.0 * u[:, 1] - 1.0
        phi = 2.0 * math.pi * u[:, 2]
        rho = u[:, 3] ** (1.0 / 3.0)
        ball = rho[:, None] * np.column_stack([np.sqrt(1 - z * z) * np.cos(phi),
                                               np.sqrt(1 - z * z) * np.sin(phi), z])
        room = np.maximum(axes[None, :] - r[:, None], 0.0)
        centres.append(np.asarray(lobe.centre)[None, :] + ball * room)
        radii.append(r)
        # the lobe's centre always holds its largest sphere, so every lobe is solid
        centres.append(np.asarray(lobe.centre, dtype=np.float64)[None, :])
        radii.append(np.array([lobe.rmax * axes.min()]))
    return np.concatenate(centres), np.concatenate(radii)


def _field(points: np.ndarray, centres: np.ndarray, radii: np.ndarray, blend: float) \
        -> np.ndarray:
    """Soft-minimum signed distance to the spheres' union (negative inside)."""
    out = np.empty(len(points))
    for start in range(0, len(points), 1 << 16):
        p = points[start:start + (1 << 16)]
        d = np.linalg.norm(p[:, None, :] - centres[None], axis=2) - radii[None]
        m = d.min(axis=1)
        out[start:start + len(p)] = m - blend * np.log(
            np.exp(-(d - m[:, None]) / blend).sum(axis=1))
    return out


#: The six tetrahedra of a cube around its 0-7 diagonal (corner bits: x=1, y=2, z=4).
_TETS = np.array([[0, 1, 3, 7], [0, 3, 2, 7], [0, 2, 6, 7], [0, 6, 4, 7], [0, 4, 5, 7],
                  [0, 5, 1, 7]])


def marching_tetrahedra(values: np.ndarray, origin, step: float) \
        -> tuple[np.ndarray, np.ndarray]:
    """Mesh the zero level of a grid (negative inside): closed, outward wound.

    Parameters
    ----------
    values : (nx, ny, nz) float64
        Field on the grid, negative inside; the outer layer must be positive.
    origin : (3,) float
        Position of ``values[0, 0, 0]``.
    step : float
        Grid spacing.

    Returns
    -------
    vertices : (n, 3) float64
    faces : (m, 3) int64
    """
    f = np.array(values, dtype=np.float64)
    if f.ndim != 3 or min(f.shape) < 2:
        raise InvalidParameterError(f"values must be a 3-D grid; got shape {f.shape}")
    if (f[0] <= 0).any() or (f[-1] <= 0).any() or (f[:, 0] <= 0).any() \
            or (f[:, -1] <= 0).any() or (f[:, :, 0] <= 0).any() or (f[:, :, -1] <= 0).any():
        raise InvalidParameterError("the field must be positive (outside) on the grid's border")
    tiny = 1e-9 * max(1e-300, float(np.abs(f).max()))
    f[f == 0] = -tiny
    nx, ny, nz = f.shape
    flat = f.reshape(-1)
    inside = flat < 0
    # cubes whose corners disagree
    ins = inside.reshape(nx, ny, nz)
    corner_sum = np.zeros((nx - 1, ny - 1, nz - 1), np.int8)
    for c in range(8):
        corner_sum += ins[c & 1:nx - 1 + (c & 1), (c >> 1) & 1:ny - 1 + ((c >> 1) & 1),
                          (c >> 2) & 1:nz - 1 + ((c >> 2) & 1)]
    ci, cj, ck = np.nonzero((corner_sum > 0) & (corner_sum < 8))
    offs = np.array([(c & 1) * ny * nz + ((c >> 1) & 1) * nz + ((c >> 2) & 1)
                     for c in range(8)], np.int64)
    base = (ci * ny + cj) * nz + ck
    tets = (base[:, None, None] + offs[_TETS][None]).reshape(-1, 4)
    tin = inside[tets]
    count = tin.sum(axis=1)
    tets, tin, count = tets[(count > 0) & (count < 4)], tin[(count > 0) & (count < 4)], \
        count[(count > 0) & (count < 4)]
    # order each tetrahedron's corners: inside ones first
    order = np.argsort(~tin, axis=1, kind="stable")
    t = np.take_along_axis(tets, order, axis=1)
    n_grid = np.int64(flat.size)

    def edge(a, b):
        return np.minimum(a, b) * n_grid + np.maximum(a, b)

    tris, ref = [], []
    one = count == 1
    a = t[one]
    tris.append(np.stack([edge(a[:, 0], a[:, 1]), edge(a[:, 0], a[:, 2]),
                          edge(a[:, 0], a[:, 3])], axis=1))
    ref.append(a[:, :1])
    three = count == 3
    a = t[three]
    tris.append(np.stack([edge(a[:, 3], a[:, 0]), edge(a[:, 3], a[:, 1]),
                          edge(a[:, 3], a[:, 2])], axis=1))
    ref.append(a[:, :3])
    two = count == 2
    a = t[two]
    e02, e03 = edge(a[:, 0], a[:, 2]), edge(a[:, 0], a[:, 3])
    e12, e13 = edge(a[:, 1], a[:, 2]), edge(a[:, 1], a[:, 3])
    tris.append(np.stack([e02, e03, e13], axis=1))
    tris.append(np.stack([e02, e13, e12], axis=1))
    ref.append(a[:, :2])
    ref.append(a[:, :2])
    keys, inverse = np.unique(np.concatenate([x.reshape(-1) for x in tris]),
                              return_inverse=True)
    ga, gb = keys // n_grid, keys % n_grid
    fa, fb = flat[ga], flat[gb]
    w = fa / (fa - fb)
    gi = np.stack(np.unravel_index(ga, f.shape), axis=1).astype(np.float64)
    gj = np.stack(np.unravel_index(gb, f.shape), axis=1).astype(np.float64)
    vertices = np.asarray(origin, dtype=np.float64) + step * (gi + w[:, None] * (gj - gi))
    faces = inverse.reshape(-1, 3).astype(np.int64)
    # wind each triangle away from the inside corners of its tetrahedron
    inside_points = [np.stack(np.unravel_index(r.reshape(-1), f.shape), axis=1)
                     .reshape(r.shape[0], r.shape[1], 3).mean(axis=1) for r in ref]
    ip = np.asarray(origin) + step * np.concatenate(inside_points)
    tri = vertices[faces]
    nrm = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    flip = np.einsum("ij,ij->i", nrm, tri.mean(axis=1) - ip) < 0
    faces[flip] = faces[flip][:, ::-1]
    return vertices, faces


def packing_body(preset: str | Packing, *, radius: float, seed: int, cells: int = 96) \
        -> MeshBody:
    """Mesh a packing preset as a closed body of equivalent radius ``radius`` (metres).

    Parameters
    ----------
    preset : str or Packing
        A name of :data:`PACKINGS` or a packing.
    radius : float
        Equivalent (same-volume) radius, metres.
    seed : int
    cells : int
        Grid cells along the longest axis (the mesh's resolution).
    """
    if isinstance(preset, str):
        if preset not in PACKINGS:
            raise InvalidParameterError(
                f"unknown packing {preset!r}; choose one of {', '.join(sorted(PACKINGS))}")
        packing = PACKINGS[preset]
    else:
        packing = preset
    radius = float(radius)
    if not (radius > 0 and math.isfinite(radius)):
        raise InvalidParameterError(f"radius must be positive metres; got {radius}")
    if not 8 <= int(cells) <= 1024:
        raise InvalidParameterError(f"cells must lie in [8, 1024]; got {cells}")
    centres, radii = sphere_packing(packing, seed=seed)
    stretch = np.asarray(packing.stretch, dtype=np.float64)
    lo = (centres - radii[:, None]).min(axis=0) * stretch
    hi = (centres + radii[:, None]).max(axis=0) * stretch
    pad = 2.0 * packing.blend + 0.05
    lo, hi = lo - pad, hi + pad
    step = float((hi - lo).max()) / int(cells)
    shape = np.ceil((hi - lo) / step).astype(int) + 1
    axes = [lo[i] + step * np.arange(shape[i]) for i in range(3)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    values = _field(grid / stretch, centres, radii, packing.blend).reshape(tuple(shape))
    vertices, faces = marching_tetrahedra(values, lo, step)
    volume = signed_volume(vertices, faces)
    centroid = _centroid(vertices, faces, volume)
    scale = radius / (3.0 * volume / (4.0 * math.pi)) ** (1.0 / 3.0)
    name = preset if isinstance(preset, str) else "custom"
    return MeshBody((vertices - centroid) * scale, faces,
                    dict(packing=dict(preset=name, seed=int(seed), cells=int(cells),
                                      spheres=len(radii))))


def _centroid(vertices, faces, volume):
    a, b, c = (vertices[faces[:, i]] for i in range(3))
    vol = np.einsum("ij,ij->i", a, np.cross(b, c)) / 6.0
    return (vol[:, None] * (a + b + c) / 4.0).sum(axis=0) / volume
