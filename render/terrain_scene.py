"""A DEM layer stack as one multi-resolution terrain mesh.

Every layer of a stack (:mod:`terrain.stack.model`) becomes a grid mesh with a vertex at every
pixel
centre, cut into blocks of :data:`BLOCK` x :data:`BLOCK` cells. Per frame, each block is culled
against the view frustum, dropped if a finer layer covers it completely, and otherwise drawn
at the coarsest level of detail (every s-th vertex, s = 1, 2, 4, ... BLOCK) whose cells stay
below ``RenderOptions.lod_pixels`` on screen at the block's nearest distance; the target is
relaxed until the frame fits ``RenderOptions.triangle_budget``. A layer is drawn only where
no finer layer covers it (its fragments inside the finer layer's extent are discarded, which is
exact because the finer layer's mesh spans exactly that rectangle of pixel centres).

Crack-free seams: every block edge, including a layer's outer edge, carries a *skirt*, a
vertical strip hanging :data:`SKIRT_PIXELS` pixels below the edge. Where neighbouring blocks
(or a layer and its parent) are drawn at different levels of detail, the skirts fill the gaps
their edges leave; seen from above, no background shows through.

World frame: the stack's map coordinates (x east, y north, metres) and heights; positions on
the GPU are relative to the landing site. With ``curvature`` on, heights drop by
``d^2 / (2 R)`` with d the horizontal distance from the site and R the body's radius (the
parabolic approximation of the sphere; within 10 % of R of the site it is exact to 0.5 % of the
drop). :meth:`TerrainScene.to_world` applies the same mapping to any point, e.g. a crater
centre from the catalogue, so truth and images agree.

Shadows: one map per layer, fitted to the layer's extent and deep enough for every caster up
sun, computed once per sun direction and reused by every frame (the terrain does not move).
The maps' light-space projections depend on the sun and the stack alone, never on the
camera, so for a fixed sun every shadow texel stays on the same patch of ground through a
whole sequence (no swimming), and the casters are drawn at one level of detail per layer,
chosen from the texel size, whatever the camera does. Each map is sized to resolve its
layer's pixels on the ground (``RenderOptions.shadow_detail`` texels per pixel, at most
``RenderOptions.shadow_size`` a side): across the sun's azimuth a texel is a pixel; along
it a texel of light-space y covers ``1 / sin(elevation)`` of ground, so that side has
``sin(elevation)`` times finer texels. The layer is the finest the camera sees where it is
drawn (the planner never draws a layer where a finer one lies), so every relief of two of its
pixels reaches the map. A layer's map draws the ground once: the layer itself whole and each
coarser layer outside the next finer one, culled to the map's window, so the maps' cost
grows with the layers, not with their square.

A layer seen only from afar, where an image pixel spans many of its pixels, needs no map at
its own resolution: its map is drawn ``c`` times coarser, ``c`` a power of two from
:data:`MIN_SHADOW_COARSENING` on such that an image pixel at the layer's nearest drawn block
spans :data:`SHADOW_PIXEL_CELLS` cells of ``c`` layer pixels (casters at the matching level
of detail), so a relief of half an image pixel reaches the map as one of two layer pixels
reaches a full map. ``c`` is a function of the frame's camera alone (the same frame gives
the same bytes whatever came before it); a map is kept per layer and ``c``, so a camera
coming from afar draws a fine layer's map once per halving of ``c`` down to 8, together
about a third of a full map, then the full map, and its first frame draws the distant fine
layers' maps at a fraction of their cost.
Scattered light likewise: a layer is lit by its own grid (:mod:`render.scattering`), or,
where an image pixel at its nearest drawn block spans a coarser layer's grid cell, by the
coarsest such layer's grid, which covers it and resolves the light to an image pixel.

Geomorphing: levels of detail change continuously, never from one frame to the next. With
``lambda(d) = log2(target * d / (cell * focal))`` the continuous level at distance d (the
planner's rule above picks ``s = 2^floor(lambda)`` at a block's nearest point), a vertex of a
block drawn at level s that level 2s lacks slides, in the vertex shader, from its own height
to the height of level 2s's surface below it (the coarser triangle's interpolation; its
normal likewise) as ``lambda`` at the vertex runs over the last :data:`MORPH_BAND` octave
before ``log2(2 s)``. Where the planner switches the block to 2s, every such vertex has
arrived, so the switch changes nothing on screen. The factor depends on the vertex's own
distance only, so a vertex shared by two blocks moves the same in both, and an edge between
a block at s and one at 2s matches exactly (the vertices of the finer block's edge are then
fully morphed); where levels differ by more, the skirts still close the seam. The
shadow-map bias that coarse geometry needs grows with the same continuous level instead of
jumping with s. When the triangle budget forces a coarser target, the target is the
smallest that fits (found by bisection), not the next of a few fixed steps, so it too moves
continuously. ``RenderOptions.geomorph = False`` restores switching.

Shading normals: with geomorphing on, every fragment is shaded with its layer's
full-resolution normals (a texture of the per-pixel normals, bilinear), not with normals
interpolated across the drawn triangles, so the shading of the ground, and with it every
shading corner a tracker follows, stays where it is on the ground whatever the level of
detail; the normal images are these normals too. The level of detail then changes only the
geometry's outline and range, within the error it allows.

Layer fade-in: a finer layer's heights blend into its parent's surface across
:data:`FADE_PARENT_PIXELS` parent pixels inside its extent (at most an eighth of the
layer's side; a smoothstep from the parent's
triangulated full-resolution surface at the layer's edge to the layer's own heights), so the
finer detail fades in instead of starting with a step at the layer's edge.

Loading: :meth:`TerrainScene.upload` prepares every layer's heights (invalid pixels
filled, curvature, fade-in), block bounds and shared index buffers; a layer's vertex buffer
is built when a frame first draws it or a shadow map first casts with it, and its
geomorphing buffer and normals texture when a frame first draws it. A layer no frame needs
costs its heights only, and the buffers are the same bytes whenever they are built.

Range and truth: range comes from the drawn (morphed) geometry, per fragment, and the images
and normal images from the same fragments (shaded with the layers' full-resolution normals),
so they agree with each other and with the poses exactly. Morphing moves a vertex only
between two levels of detail of the same layer, within the error the level of detail already
allowed; only the fade margin draws heights other than the layer's own (the parent's surface
blended in), and :meth:`TerrainScene.height_at` reads the layers' own heights.
"""

from __future__ import annotations

import functools
import logging
import math
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from render.scene import (
    MIN_LOD_DISTANCE_M,
    TERRAIN_SHADOW_BIAS,
    DrawBatch,
    FrameState,
    Gpu,
    Imposter,
    Morph,
    ShadowMap,
    box_corners,
    box_distance,
    far_plane,
    frustum_visible,
    light_basis,
    ortho_light,
    render_shadow_map,
)
from render.terrain_buffers import (
    block_indices,
    fade_in,
    half_floats,
    layer_buffers,
    morph_targets,
)
from terrain.core import metakeys as mk
from terrain.core.errors import InvalidParameterError

if TYPE_CHECKING:
    from render.renderer import Lighting, RenderOptions, View
    from terrain.core.tile import DEMTile
    from terrain.stack.model import LayerStack

__all__ = ["BLOCK", "FADE_PARENT_PIXELS", "MOON_RADIUS", "MORPH_BAND", "SKIRT_PIXELS",
           "TerrainScene"]

log = logging.getLogger(__name__)

#: Cells per block side (a power of two).
BLOCK = 64
#: A layer first drawn (or casting a shadow) at this level of detail or coarser gets vertex
#: buffers of only the vertices that level draws (every level-th row and column): from the
#: demo descent's first pose eight of its twelve drawn layers are drawn at levels 4 to 64,
#: and their full buffers (56 MB each at 1025^2) were most of the first frame's uploads. A
#: finer level later builds the full buffers once (a second build of a sixteenth or less).
SPARSE_FROM = 4
#: Skirt depth in pixels of the layer.
SKIRT_PIXELS = 8.0
#: Caster cells in a shadow map may be this many texels wide (along the map's coarser axis).
SHADOW_CELL_TEXELS = 1.0
#: Cells of a layer's coarsened shadow map (``c`` layer pixels each) an image pixel spans at
#: least at the layer's nearest drawn block (:func:`_shadow_coarsening`).
SHADOW_PIXEL_CELLS = 4.0
#: The least coarsening worth a map of its own (:func:`_shadow_coarsening`): at 2 and 4 a
#: coarser map still costs about half a full one (its casters keep their detail; measured on
#: the demo's stack), and a descent draws the full map anyway once it comes closer; from 8
#: on it costs a quarter or less, so a camera coming from afar pays at most about a third
#: of a full map more per layer, and its first frame a fraction.
MIN_SHADOW_COARSENING = 8
#: Smallest side of a layer's shadow map, texels.
MIN_SHADOW_SIDE = 64
#: Sines of sun elevations below this one size terrain maps as this one (0.57 degrees): the
#: map's side along the sun's azimuth is capped by ``RenderOptions.shadow_size`` anyway.
MIN_SIN_ELEVATION = 0.01
#: Sets of layer maps kept at once (two suns, or two map settings, without redrawing).
SHADOW_CACHE_SETS = 2
#: Cells of a layer's side in its grid of scattered light (:mod:`render.scattering`); the
#: grid spans the layer and half its side around it.
SCATTER_CELLS = 32
#: A layer's shadow map covers its extent and this many of its pixels around it, so the
#: skirts and the receivers at its edge still find texels of their own.
SHADOW_MARGIN_PIXELS = 2.0
#: Extra shadow-map depth bias for coarse visible geometry, in pixels of the layer per unit
#: of the drawn level s: a block drawn every s-th vertex (cells s pixels wide) is given a
#: quarter of its cell, ``0.25 s`` pixels, for lying above the surface the map was drawn
#: from (a margin found to remove the acne, not a bound).
LOD_BIAS_PIXELS = 0.25
#: Mean lunar radius (m), the default body radius for curvature (IAU/LOLA reference sphere).
MOON_RADIUS = 1_737_400.0
#: Octaves of distance over which a vertex morphs toward the next coarser level (half the
#: range a level is used over; CDLOD's morph region is of this order, Strugar 2009).
MORPH_BAND = 0.5
#: Width (parent pixels) of the margin inside a finer layer's edge across which it fades in.
FADE_PARENT_PIXELS = 8.0
#: ... but at most this fraction of the layer's smaller side (small layers keep their own
#: heights over most of their extent).
FADE_MAX_FRACTION = 0.125
#: Bisection steps of the budget-limited target (a 1.25 bracket to 1e-7 relative).
BUDGET_BISECTIONS = 22


@dataclass(eq=False)
class _Layer:
    level: int
    resolution: float
    shape: tuple
    vbo: Any              # interleaved positions and normals of every vertex (3f 3f), or None
    ibos: dict            # lod -> buffer
    vaos: dict            # lod -> (vao, depth_vao)
    offsets: dict         # lod -> (n_blocks,) first index
    counts: dict          # lod -> (n_blocks,) index count
    lo: np.ndarray        # (n_blocks, 3) block AABB minima (scene-local)
    hi: np.ndarray
    discard: tuple | None  # finer layer's extent (scene-local), or None
    covered: np.ndarray   # (n_blocks,) bool: entirely inside the finer layer
    extent: tuple         # (xmin, ymin, xmax, ymax) scene-local, pixel centres
    morph_vbo: object = None
    normal_map: tuple | None = None  # (texture, rect): see DrawBatch.normal_map
    # (z, xs, ys): the curved, faded heights and pixel centres the vertex buffers are built
    # from when a frame first needs them (:meth:`TerrainScene._vertex_buffers`)
    heights: tuple | None = None
    # the vertex buffers hold every step-th row and column (1: every vertex; 0: none built
    # since sparse ones were retired, the next are full; see SPARSE_FROM)
    step: int = 1


def _lods() -> list[int]:
    out, s = [], 1
    while s <= BLOCK:
        out.append(s)
        s *= 2
    return out


def _samples(start: int, stop: int, step: int) -> np.ndarray:
    """start, start + step, ..., always ending exactly at stop."""
    s = np.arange(start, stop, step)
    return np.append(s, stop)


class TerrainScene:
    """A layer stack ready to render (see the module docstring).

    Parameters
    ----------
    stack : terrain.stack.model.LayerStack, str or pathlib.Path
        The layer stack, or its folder.
    curvature : bool
        Drop heights by d^2 / (2 R) away from the site.
    radius : float, optional
        Body radius R (m); default: the stack's datum radius if recorded, else the Moon's.
    albedo_map : terrain.core.tile.DEMTile, str or pathlib.Path, optional
        Albedo factors over the terrain (:meth:`set_albedo_map`).

    Attributes
    ----------
    origin : (3,) float64, metres
        The landing site at height 0: positions on the GPU are relative to it.
    reach : float
        0: a terrain map does not turn (:class:`render.scene.Scene`).
    """

    kind = "terrain"
    reach = 0.0

    def __init__(self, stack: LayerStack | str | Path, *, curvature: bool = True,
                 radius: float | None = None,
                 albedo_map: DEMTile | str | Path | None = None) -> None:
        from terrain.stack.model import LayerStack
        from terrain.stack.store import read_stack

        if not isinstance(stack, LayerStack):
            stack = read_stack(Path(stack))
        self.stack = stack
        site = stack.info.get("site")
        if site is None:
            left, bottom, right, top = stack.tiles[-1].bounds
            site = [(left + right) / 2, (bottom + top) / 2]
        self.site = (float(site[0]), float(site[1]))
        self.origin = np.array([self.site[0], self.site[1], 0.0])
        self.curvature = bool(curvature)
        if radius is None:
            meta = stack.tiles[0].metadata
            radius = float(meta.get(mk.DATUM_RADIUS, MOON_RADIUS))
        if not radius > 0:
            raise InvalidParameterError(f"body radius must be positive; got {radius}")
        self.radius = float(radius)
        self._layers: list[_Layer] = []
        self._bounds: tuple | None = None
        self._index_cache: dict = {}
        self._retired: list = []  # vertex buffers of a frame gone sparse -> full (_retire_buffers)
        self._ctx: object = None  # the context the layers were uploaded to
        self._shadow_cache: dict = {}
        self._scatter_cache: dict = {}
        self._mean_heights: dict = {}  # layer -> mean of its valid heights (invalid pixels')
        self.triangles_full = 0
        self.albedo_map: DEMTile | None = None
        self._albedo_gpu: tuple | None = None
        if albedo_map is not None:
            self.set_albedo_map(albedo_map)

    def set_albedo_map(self, tile: DEMTile | str | Path) -> None:
        """Set the albedo factors over the terrain.

        Their values multiply the albedo (or Hapke's w) of the surface beneath, bilinearly
        interpolated between pixel centres; invalid pixels and ground outside the map keep a
        factor of 1 (edge values repeat).

        Parameters
        ----------
        tile : terrain.core.tile.DEMTile, str or pathlib.Path
            The factors (>= 0) in the stack's map frame, or a raster any GDAL reader opens.
        """
        from terrain.core.tile import DEMTile

        if not isinstance(tile, DEMTile):
            from terrain.io import read_dem

            tile = read_dem(Path(tile))
        a = np.where(tile.valid, tile.heights, 1.0).astype(np.float32)
        if not np.all(np.isfinite(a)) or a.min() < 0:
            raise InvalidParameterError("albedo map values must be finite and >= 0")
        self.albedo_map = tile
        self._albedo_gpu = None

    # ------------------------------------------------------------------ geometry
    def to_world(self, points: npt.ArrayLike) -> np.ndarray:
        """Map points of the stack's map frame to the rendered world frame.

        Parameters
        ----------
        points : (n, 3) float, metres
            Map x (east), y (north) and height.

        Returns
        -------
        (n, 3) float64, metres
            The same points with the curvature drop applied to their heights.
        """
        p = np.array(points, dtype=np.float64, ndmin=2)
        if self.curvature:
            d2 = (p[:, 0] - self.site[0]) ** 2 + (p[:, 1] - self.site[1]) ** 2
            p[:, 2] = p[:, 2] - d2 / (2.0 * self.radius)
        return p

    def height_at(self, x: float, y: float) -> float:
        """Give the terrain height under a map point, from the finest layer there.

        Parameters
        ----------
        x, y : float, metres
            Map coordinates.

        Returns
        -------
        float, metres
            World-frame height (bilinear in the layer's own heights, curvature applied).

        Raises
        ------
        terrain.core.errors.InvalidParameterError
            Where the point lies outside every layer.
        """
        for tile in reversed(self.stack.tiles):
            left, bottom, right, top = tile.bounds
            if left <= x <= right and bottom <= y <= top:
                row, col = tile.rowcol(x, y)
                r = min(max(float(row), 0.0), tile.shape[0] - 1.0)
                c = min(max(float(col), 0.0), tile.shape[1] - 1.0)
                i0, j0 = int(r), int(c)
                i1, j1 = min(i0 + 1, tile.shape[0] - 1), min(j0 + 1, tile.shape[1] - 1)
                h = tile.heights
                ti, tj = r - i0, c - j0
                z = ((h[i0, j0] * (1 - tj) + h[i0, j1] * tj) * (1 - ti)
                     + (h[i1, j0] * (1 - tj) + h[i1, j1] * tj) * ti)
                return float(self.to_world([[x, y, z]])[0, 2])
        raise InvalidParameterError(f"point {x:.6g},{y:.6g} lies outside the terrain")

    def set_body_rotation(self, quaternion: Any) -> None:
        """Ignored: a terrain map is drawn in the world frame and does not rotate.

        Parameters
        ----------
        quaternion : (4,) float
            R_WB as [w, x, y, z] (the :class:`render.scene.Scene` interface).
        """

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Give the world-frame bounding box of the whole scene.

        Returns
        -------
        lo, hi : (3,) float64, metres
            Its smallest and largest corner (the curvature drop included).
        """
        # the heights never change, so neither does the box: computed once (it is asked
        # every frame), for the stack, curvature and radius it was computed with
        key = (id(self.stack), self.curvature, self.radius)
        cached = self._bounds
        if cached is None or cached[0] != key:
            cached = (key, *self._compute_bounds())
            self._bounds = cached
        return cached[1].copy(), cached[2].copy()

    def _compute_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        lo = np.array([math.inf] * 3)
        hi = -lo
        for tile in self.stack.tiles:
            left, bottom, right, top = tile.bounds
            z = tile.heights[tile.valid]
            zmin, zmax = float(z.min()), float(z.max())
            corners = self.to_world([[left, bottom, zmin], [right, top, zmax],
                                     [left, top, zmin], [right, bottom, zmin]])
            drop = corners[:, 2].min() - zmin
            lo = np.minimum(lo, [left, bottom, zmin + min(drop, 0.0)])
            hi = np.maximum(hi, [right, top, zmax])
        return lo, hi

    # ------------------------------------------------------------------ GPU
    def upload(self, gpu: Gpu, *, eager: bool = False) -> None:
        """Prepare every layer for drawing (once per context).

        Every layer's heights, block bounds and index buffers are made here; its vertex
        buffers when a frame first draws it or casts a shadow with it, and its geomorphing
        buffer and normals texture when a frame first draws it (the same bytes either way:
        a layer no frame needs costs its heights only).

        Parameters
        ----------
        gpu : render.scene.Gpu
            The handle the buffers and normal textures are uploaded through.
        eager : bool
            Upload every layer's buffers now.
        """
        if not (self._ctx is gpu.context and self._layers):
            self._ctx = gpu.context
            self._layers = []
            self._index_cache = {}
            self._retired = []  # (another context's: dropped with it)
            tiles = self.stack.tiles
            total = 0
            parent = None
            for k, tile in enumerate(tiles):
                finer = tiles[k + 1] if k + 1 < len(tiles) else None
                layer, parent = self._build_layer(gpu, k, tile, finer, parent)
                self._layers.append(layer)
                total += int(layer.counts[1].sum()) // 3
            self.triangles_full = total
            log.info("terrain scene: %d layers, %d triangles at full resolution", len(tiles),
                     total)
        if eager:
            for layer in self._layers:
                self._vertex_buffers(gpu, layer, morph=True)

    def _local_extent(self, tile):
        left, bottom, right, top = tile.bounds
        r = tile.resolution
        return (left + r / 2 - self.site[0], bottom + r / 2 - self.site[1],
                right - r / 2 - self.site[0], top - r / 2 - self.site[1])

    def _build_layer(self, gpu, k, tile, finer, parent=None):
        """Prepare a layer (heights, blocks, indices); give it and its surface (for fade-in).

        Its vertex buffers are built when a frame first needs them (:meth:`_vertex_buffers`).
        """
        h, w = tile.shape
        res = tile.resolution
        x0, y0, x1, y1 = self._local_extent(tile)
        xs = x0 + np.arange(w) * res
        ys = y1 - np.arange(h) * res
        z = tile.heights.astype(np.float64)
        if not tile.valid.all():
            from scipy import ndimage

            idx = ndimage.distance_transform_edt(~tile.valid, return_distances=False,
                                                 return_indices=True)
            z = z[tuple(idx)]
        if self.curvature:
            z = z - (xs[None, :] ** 2 + ys[:, None] ** 2) / (2.0 * self.radius)
        if parent is not None:
            z = _fade_in(z, xs, ys, parent)
        surface = (z, xs[0], ys[0], res)
        brows = _samples(0, h - 1, BLOCK)
        bcols = _samples(0, w - 1, BLOCK)
        depth = SKIRT_PIXELS * res
        nby, nbx = len(brows) - 1, len(bcols) - 1
        lo = np.empty((nby * nbx, 3))
        hi = np.empty((nby * nbx, 3))
        if nby and nbx:
            zmin, zmax = _block_extremes(z, brows, bcols)
            lo[:, 0] = np.tile(xs[bcols[:-1]], nby)
            lo[:, 1] = np.repeat(ys[brows[1:]], nbx)
            lo[:, 2] = zmin.ravel() - depth
            hi[:, 0] = np.tile(xs[bcols[1:]], nby)
            hi[:, 1] = np.repeat(ys[brows[:-1]], nbx)
            hi[:, 2] = zmax.ravel()
        # every layer of one shape draws with the same indices: built and uploaded once
        key = (h, w)
        if key not in self._index_cache:
            built = {s: _block_indices(h, w, s) for s in _lods()}
            self._index_cache[key] = {s: (gpu.buffer(idx), off, cnt)
                                      for s, (idx, off, cnt) in built.items()}
        shared = self._index_cache[key]
        ibos = {s: shared[s][0] for s in shared}
        offsets = {s: shared[s][1] for s in shared}
        counts = {s: shared[s][2] for s in shared}
        vaos: dict = {}
        discard = None
        if finer is not None:
            # The finer layer covers exactly this rectangle of its pixel centres; this layer
            # keeps a one-pixel band of overlap inside it, so that no float rounding and no
            # step between the layers' surfaces at the seam can open a gap.
            fx0, fy0, fx1, fy1 = self._local_extent(finer)
            discard = (fx0 + res, fy0 + res, fx1 - res, fy1 - res)
        if discard is not None:
            covered = ((lo[:, 0] >= discard[0]) & (hi[:, 0] <= discard[2])
                       & (lo[:, 1] >= discard[1]) & (hi[:, 1] <= discard[3]))
        else:
            covered = np.zeros(nby * nbx, dtype=bool)
        layer = _Layer(k, res, (h, w), None, ibos, vaos, offsets, counts, lo, hi, discard,
                       covered, (x0, y0, x1, y1), heights=(z, xs, ys))
        return layer, surface

    def _vertex_buffers(self, gpu, layer: _Layer, morph: bool, finest: int = 1) -> None:
        """Upload what the layer lacks of its buffers, from its prepared heights.

        Its vertex buffer, and with ``morph`` its geomorphing buffer and normals texture,
        able to draw level ``finest`` and the coarser ones. A layer first needed at level
        :data:`SPARSE_FROM` or coarser gets buffers of only the vertices that level draws
        (``layer.step``: the same values per vertex, so the same frames); a finer level later
        replaces them with the full ones.
        """
        if layer.vbo is not None and layer.step > finest:
            self._retire_buffers(layer)  # too sparse now: every vertex from here on
            layer.step = 0
        if layer.vbo is not None and (layer.morph_vbo is not None or not morph):
            return
        assert layer.heights is not None  # dropped only once every buffer is built
        z, xs, ys = layer.heights
        h, w = layer.shape
        res = layer.resolution
        if layer.vbo is None:
            # sparse only the first time (0: once sparse, now full)
            layer.step = _sparse_step(h, w, finest) if layer.step else 1
        # vertices: every pixel centre, then the skirt rows (lowered copies of every
        # block-boundary row), then the skirt columns; the vertex buffer interleaves position
        # and normal (3f 3f), the geomorphing buffer the target position, the level and the
        # target normal (4f 3f; module docstring), skirts following their edge vertex.
        # Normals from central differences of the (curved) heights (render.terrain_buffers).
        n, vert, morph_buf = layer_buffers(
            z, xs, ys, res, _samples(0, h - 1, BLOCK), _samples(0, w - 1, BLOCK),
            SKIRT_PIXELS * res, _cell_tables(h, w) if morph else None,
            vertices=layer.vbo is None, morph=morph, step=layer.step)
        if morph and layer.normal_map is None:
            # the full-resolution normals as a texture (shading independent of the level of
            # detail, module docstring): texel (i, j) at pixel centre (xs[j], ys[i])
            normal_tex = gpu.texture((w, h), 3, half_floats(n).tobytes(), dtype="f2")
            layer.normal_map = (normal_tex, (xs[0] - 0.5 * res, ys[0] + 0.5 * res,
                                             1.0 / (w * res), 1.0 / (h * res)))
        if layer.vbo is None:
            layer.vbo = gpu.buffer(vert)
        if morph:
            layer.morph_vbo = gpu.buffer(morph_buf)
            if layer.step == 1:
                layer.heights = None  # every buffer is built

    def _retire_buffers(self, layer: _Layer) -> None:
        """Take the layer's vertex buffers and their vertex arrays out of use.

        Released when the next frame is planned (:meth:`_release_retired`): a batch of this
        frame may still draw them.
        """
        self._retired.append((list(layer.vaos.values()), layer.vbo, layer.morph_vbo))
        layer.vaos.clear()
        layer.vbo = layer.morph_vbo = None

    def _release_retired(self) -> None:
        for arrays, *buffers in self._retired:
            for pair in arrays:
                for mesh in pair if isinstance(pair, tuple) else (pair,):
                    mesh.release()
            for buffer in buffers:
                if buffer is not None:
                    buffer.release()
        self._retired.clear()

    def _ibo(self, gpu, layer: _Layer, s: int):
        """Give the index buffer that draws level s from the layer's vertex buffers."""
        if layer.step == 1:
            return layer.ibos[s]
        h, w = layer.shape
        key = (h, w, layer.step, s)
        if key not in self._index_cache:
            idx, _, counts = _block_indices(h, w, s, layer.step)
            # the same blocks, each the same number of indices as at level s of every vertex
            assert np.array_equal(counts, layer.counts[s])
            self._index_cache[key] = gpu.buffer(idx)
        return self._index_cache[key]

    def _vaos(self, gpu, layer: _Layer, s: int):
        """Give the layer's (camera, depth) vertex arrays at level s (its buffers built)."""
        key = (gpu.token, s)
        if key not in layer.vaos:
            self._vertex_buffers(gpu, layer, morph=True, finest=s)
            layer.vaos[key] = gpu.vertex_arrays(layer.vbo, self._ibo(gpu, layer, s),
                                                morph=layer.morph_vbo)
        return layer.vaos[key]

    def _depth_vao(self, gpu, layer: _Layer, s: int):
        """Give the layer's depth vertex array at level s (its vertex buffer built)."""
        pair = layer.vaos.get((gpu.token, s))
        if pair is not None:
            return pair[1]
        key = (gpu.token, s, "depth")
        if key not in layer.vaos:
            self._vertex_buffers(gpu, layer, morph=False, finest=s)
            layer.vaos[key] = gpu.vertex_arrays(layer.vbo, self._ibo(gpu, layer, s))[1]
        return layer.vaos[key]

    # ------------------------------------------------------------------ per frame
    def imposter(self, view: View, options: RenderOptions) -> Imposter | None:
        """Never: a terrain map is always drawn as geometry.

        Parameters
        ----------
        view : render.renderer.View
            The frame's camera.
        options : render.renderer.RenderOptions
            The frame's quality settings.

        Returns
        -------
        None
        """
        return None

    def frame_state(self, view: View, lighting: Lighting, options: RenderOptions,
                    gpu: Gpu, imposter: Imposter | None) -> FrameState:
        """Plan one frame: visible blocks at their levels of detail, with the layers' maps.

        Parameters
        ----------
        view : render.renderer.View
            The frame's camera.
        lighting : render.renderer.Lighting
            The sun (the shadow maps follow it).
        options : render.renderer.RenderOptions
            Level of detail target and triangle budget, shadows, geomorphing.
        gpu : render.scene.Gpu
            Uploads, vertex arrays and the shadow maps.
        imposter : render.scene.Imposter or None
            Always None (:meth:`imposter`).

        Returns
        -------
        render.scene.FrameState
            The batches (finest layer first: front to back) and what they draw.
        """
        self.upload(gpu)
        self._release_retired()
        k = view.intrinsics
        cam = np.asarray(view.pose.position) - self.origin
        rot = view.pose.rotation
        focal = max(k.fx, k.fy)
        target = options.lod_pixels
        visible, dist = [], []
        for layer in self._layers:
            corners = box_corners(layer.lo, layer.hi)
            vis = frustum_visible(corners, rot, cam, k) & ~layer.covered
            visible.append(vis)
            dist.append(np.maximum(box_distance(layer.lo, layer.hi, cam), MIN_LOD_DISTANCE_M))
        plan, total = self._plan(visible, dist, focal, target)
        if total > options.triangle_budget:
            # the smallest target that fits the budget (module docstring): bracket, bisect
            fits = target
            for _ in range(40):
                fits *= 1.25
                plan, total = self._plan(visible, dist, focal, fits)
                if total <= options.triangle_budget:
                    break
            if options.geomorph:
                low = fits / 1.25
                for _ in range(BUDGET_BISECTIONS):
                    mid = math.sqrt(low * fits)
                    if self._plan(visible, dist, focal, mid)[1] <= options.triangle_budget:
                        fits = mid
                    else:
                        low = mid
                plan, total = self._plan(visible, dist, focal, fits)
            target = fits
        # m per image pixel at each drawn layer's nearest block
        footprints = {layer.level: float(d[blocks].min()) / focal
                      for layer, (_, blocks), d in zip(self._layers, plan, dist, strict=True)
                      if blocks.size}
        scatter = None
        grids = None
        if lighting is not None and (options.scattering or (
                options.earthshine and lighting.earth is not None and lighting.earthshine > 0)):
            scatter = self._scatter_maps(gpu, lighting)
            # the grids of scattered light this frame lacks, computed on a thread of their
            # own while the vertex buffers and the shadow maps are built (most of their
            # time is the interpreter's; the buffers' kernels and GL's are not)
            missing = sorted({self._scatter_source(layer.level, footprints[layer.level])
                              for layer in self._layers if layer.level in footprints}
                             - set(scatter))
            if missing:
                grids = _background().submit(
                    lambda: {k: self._scatter_grid(self._layers[k], lighting) for k in missing})
        shadowed = options.shadows and lighting is not None
        for layer, (lods, blocks) in zip(self._layers, plan, strict=True):
            if blocks.size:  # drawn: every buffer at once (before a map casts with it)
                # a shadowed frame's maps draw the coarser layers whole (from the demo
                # descent's first pose every layer at level 1): full buffers at once
                self._vertex_buffers(gpu, layer, morph=True,
                                     finest=1 if shadowed else int(lods.min()))
        shadows = self._shadow_maps(gpu, lighting, options) if shadowed else None
        computed = grids.result() if grids is not None else {}
        batches: list[DrawBatch] = []
        drawn_layers: list[dict[str, Any]] = []
        for layer, (lods, blocks) in zip(self._layers, plan, strict=True):
            if not blocks.size:
                continue
            layer_batches: list[DrawBatch] = []
            tris = 0
            footprint = footprints[layer.level]
            shadow = None
            if shadows is not None:
                coarse = _shadow_coarsening(footprint, layer.resolution)
                shadow = self._layer_shadow(gpu, shadows, lighting, options, layer, coarse)
            light = None
            if scatter is not None:
                source = self._layers[self._scatter_source(layer.level, footprint)]
                light = self._layer_scatter(gpu, scatter, lighting, source,
                                            computed.get(source.level))
            by_lod: dict = {}
            for b, s in zip(blocks, lods, strict=True):
                by_lod.setdefault(int(s), []).append(int(b))
            for s, bl in sorted(by_lod.items()):
                vao, dvao = self._vaos(gpu, layer, s)
                ranges = _merge_ranges(layer.offsets[s][bl], layer.counts[s][bl])
                n = int(layer.counts[s][bl].sum()) // 3
                tris += n
                batch = DrawBatch(vao, dvao, ranges, discard=layer.discard, shadow=shadow,
                                  triangles=n,
                                  scatter=light)
                if options.geomorph:
                    # coarser visible geometry than the shadow map saw: the shader widens
                    # the bias with the continuous level (module docstring)
                    per_level = (LOD_BIAS_PIXELS * layer.resolution / shadow.depth_range_m
                                 if shadow is not None else 0.0)
                    scale = target / (layer.resolution * focal)  # 2^lambda per metre
                    batch.morph = Morph(1, math.log2(2 * s / scale), MORPH_BAND, level=s,
                                        scale=scale, top=min(2 * s, BLOCK),
                                        bias_per_level=per_level)
                    batch.normal_map = layer.normal_map
                elif shadow is not None and s > 1:
                    # coarser visible geometry than the shadow map saw: widen the bias
                    batch.shadow = _with_extra_bias(shadow, LOD_BIAS_PIXELS * s * layer.resolution)
                layer_batches.append(batch)
            # front to back: a finer layer (nearer the camera, which looks at the site) is
            # drawn before the coarser ones, whose hidden fragments then fail the depth test
            # before they are shaded
            batches[:0] = layer_batches
            drawn_layers.append({"level": layer.level, "resolution": layer.resolution,
                                 "blocks": int(blocks.size), "triangles": tris,
                                 "lod": sorted({int(s) for s in lods})})
        lo, hi = self.bounds()
        far = far_plane(float(np.max(np.linalg.norm(
            box_corners(lo - self.origin, hi - self.origin)[0] - cam, axis=1))))
        drawn = {"layers": drawn_layers, "triangles": sum(d["triangles"] for d in drawn_layers),
                 "lod_pixels": target, "geomorph": bool(options.geomorph)}
        return FrameState(batches, far, drawn, albedo=self._albedo(gpu))

    def _albedo(self, gpu):
        """Return (texture, scene-local window) of the albedo map, uploaded once per context."""
        if self.albedo_map is None:
            return None
        if self._albedo_gpu is None or self._albedo_gpu[0] is not gpu.context:
            t = self.albedo_map
            a = np.where(t.valid, t.heights, 1.0).astype(np.float32)[::-1]  # south row first
            tex = gpu.texture((a.shape[1], a.shape[0]), 1, np.ascontiguousarray(a).tobytes(),
                              dtype="f4")
            left, bottom, right, top = t.bounds
            window = (left - self.origin[0], bottom - self.origin[1],
                      right - self.origin[0], top - self.origin[1])
            self._albedo_gpu = (gpu.context, tex, window)
        return self._albedo_gpu[1], self._albedo_gpu[2]

    def _plan(self, visible, dist, focal, target):
        plan, total = [], 0
        lods = np.array(_lods())
        for layer, vis, d in zip(self._layers, visible, dist, strict=True):
            blocks = np.flatnonzero(vis)
            if not blocks.size:
                plan.append((np.zeros(0, int), blocks))
                continue
            # largest s with s * res * focal / d <= target
            ratio = target * d[blocks] / (layer.resolution * focal)
            s = np.clip(2 ** np.floor(np.log2(np.maximum(ratio, 1.0))), 1, BLOCK).astype(int)
            plan.append((s, blocks))
            for lod in lods:
                sel = blocks[s == lod]
                total += int(layer.counts[int(lod)][sel].sum()) // 3
        return plan, total

    def _shadow_maps(self, gpu, lighting, options):
        """Give the maps of this sun, (level, coarsening) -> map, drawn as frames need them.

        Shared by every renderer on the context; a layer no frame has shown has no map.
        """
        key = (gpu.context, tuple(np.round(lighting.sun, 12)), options.shadow_size,
               float(options.shadow_detail))
        if key in self._shadow_cache:
            return self._shadow_cache[key]
        while len(self._shadow_cache) >= SHADOW_CACHE_SETS:
            for m in self._shadow_cache.pop(next(iter(self._shadow_cache))).values():
                m.release()
        self._shadow_cache[key] = {}
        return self._shadow_cache[key]

    def _layer_shadow(self, gpu, maps, lighting, options, layer, coarse=1):
        """Give the layer's map in ``maps`` at ``coarse`` times its texel, drawn if missing."""
        if (layer.level, coarse) in maps:
            return maps[layer.level, coarse]
        basis = light_basis(lighting.sun)
        # light-space y runs up the sun's azimuth: a texel of y covers 1 / sin(elevation)
        # of ground there (module docstring)
        sin_e = min(max(abs(float(lighting.sun[2])), MIN_SIN_ELEVATION), 1.0)
        receivers = box_corners(layer.lo.min(axis=0), layer.hi.max(axis=0))[0]
        margin = SHADOW_MARGIN_PIXELS * layer.resolution * coarse
        *_, window = ortho_light(lighting.sun, receivers, receivers, margin=margin)
        casters = self._casters(layer.level, basis, window)
        corners = np.concatenate(
            [box_corners(self._layers[k].lo[b], self._layers[k].hi[b]).reshape(-1, 3)
             for k, b in casters] + [receivers])
        texel = coarse * layer.resolution / float(options.shadow_detail)
        cap = int(options.shadow_size)
        size = (min(max(math.ceil((window[2] - window[0]) / texel), MIN_SHADOW_SIDE), cap),
                min(max(math.ceil((window[3] - window[1]) / (texel * sin_e)),
                        MIN_SHADOW_SIDE), cap))
        tx = (window[2] - window[0]) / size[0]

        def draw(extent, window):
            return self._depth_batches(gpu, casters, tx)

        maps[layer.level, coarse] = render_shadow_map(gpu, None, size, lighting.sun,
                                                      receivers, corners, margin=margin,
                                                      bias=TERRAIN_SHADOW_BIAS, draw=draw)
        return maps[layer.level, coarse]

    def _scatter_maps(self, gpu, lighting):
        """Give level -> (texture, rect) of the scattered light and the Earth's visibility.

        Computed for a layer when a frame first draws it (:meth:`_layer_scatter`), kept for
        :data:`SHADOW_CACHE_SETS` lightings at a time.
        """
        earth = lighting.earth if lighting.earthshine > 0 else None
        key = (gpu.context, tuple(np.round(lighting.sun, 12)),
               None if earth is None else tuple(np.round(earth, 12)), lighting.albedo,
               lighting.distance)
        if key not in self._scatter_cache:
            while len(self._scatter_cache) >= SHADOW_CACHE_SETS:
                for tex, _ in self._scatter_cache.pop(next(iter(self._scatter_cache))).values():
                    tex.release()
            self._scatter_cache[key] = {}
        return self._scatter_cache[key]

    def _scatter_cell(self, level: int) -> float:
        x0, y0, x1, y1 = self._layers[level].extent
        return max(x1 - x0, y1 - y0) / SCATTER_CELLS

    def _scatter_source(self, level: int, footprint: float) -> int:
        """Give the layer whose grid of scattered light a layer is drawn with.

        Its own, or, where the camera is far enough that an image pixel (``footprint``, m,
        at the layer's nearest drawn block) spans a coarser layer's grid cell, the
        coarsest such layer's: it covers the layer (its grid spans its extent and more),
        resolves the scattered light to an image pixel, finer than the layer's own grid
        resolves it seen from close by, and is computed once for all the fine layers a
        distant camera sees.
        """
        source = level
        while source > 0 and self._scatter_cell(source - 1) <= footprint:
            source -= 1
        return source

    def _layer_scatter(self, gpu, maps, lighting, layer, grid=None):
        """Give the layer's grid in ``maps`` (:mod:`render.scattering`), computed if missing.

        ``grid``: its :meth:`_scatter_grid`, where already computed.
        """
        if layer.level in maps:
            return maps[layer.level]
        data, rect = grid if grid is not None else self._scatter_grid(layer, lighting)
        n = data.shape[0]
        tex = gpu.texture((n, n), 2, data.tobytes(), dtype="f4")
        maps[layer.level] = (tex, rect)
        return maps[layer.level]

    def _scatter_grid(self, layer, lighting):
        """Give the layer's grid of scattered light and Earth visibility, and its window.

        ``((n, n, 2) float32, rect)``: no GL (a worker thread may compute it).
        """
        from render.scattering import horizon_light

        x0, y0, x1, y1 = layer.extent
        spacing = max(x1 - x0, y1 - y0) / SCATTER_CELLS
        n = 2 * SCATTER_CELLS + 1
        steps = (np.arange(n) - (n - 1) / 2) * spacing
        xs = (x0 + x1) / 2 + steps
        ys = (y0 + y1) / 2 - steps  # row 0 north
        earth = lighting.earth if lighting.earthshine > 0 else None
        light = horizon_light(self._local_heights(xs, ys), spacing, lighting.sun,
                              albedo=lighting.albedo, sun_radius=lighting.sun_angular_radius,
                              earth=earth)
        data = np.ascontiguousarray(
            np.stack([light["scattered"], light["earth"]], axis=-1).astype("f4"))
        rect = (xs[0] - 0.5 * spacing, ys[0] + 0.5 * spacing, 1.0 / (n * spacing),
                1.0 / (n * spacing))
        return data, rect

    def _local_heights(self, xs, ys):
        """(len(ys), len(xs)) world heights at scene-local points, from the finest layer there.

        Bilinear in each layer's own heights (invalid pixels at the layer's mean); beyond the
        base, its edge cells extrapolate linearly.
        """
        gx = xs[None, :] + self.site[0] + np.zeros((len(ys), 1))
        gy = ys[:, None] + self.site[1] + np.zeros((1, len(xs)))
        z = np.zeros(gx.shape)
        for k, tile in enumerate(self.stack.tiles):
            left, bottom, right, top = tile.bounds
            res = tile.resolution
            h, w = tile.shape
            col = (gx - left) / res - 0.5
            row = (top - gy) / res - 0.5
            inside = np.ones(gx.shape, bool) if k == 0 else (
                (col >= 0) & (col <= w - 1) & (row >= 0) & (row <= h - 1))
            if not inside.any():
                continue
            mean = self._mean_heights.get(k)
            if mean is None:
                mean = self._mean_heights[k] = np.mean(tile.heights[tile.valid])
            r, c = row[inside], col[inside]
            # beyond the base, its edge cells' planes continue (no terrace at its edge)
            i0 = np.clip(np.floor(r), 0, max(h - 2, 0)).astype(np.int64)
            j0 = np.clip(np.floor(c), 0, max(w - 2, 0)).astype(np.int64)
            i1, j1 = np.minimum(i0 + 1, h - 1), np.minimum(j0 + 1, w - 1)
            ti, tj = r - i0, c - j0

            def height(i, j, tile=tile, mean=mean):
                # only the four corners' heights are read (never the whole layer)
                return np.where(tile.valid[i, j], tile.heights[i, j], mean)

            z[inside] = ((height(i0, j0) * (1 - tj) + height(i0, j1) * tj) * (1 - ti)
                         + (height(i1, j0) * (1 - tj) + height(i1, j1) * tj) * ti)
        if self.curvature:
            z -= (xs[None, :] ** 2 + ys[:, None] ** 2) / (2.0 * self.radius)
        return z

    def _casters(self, level, basis, window):
        """``[(layer, blocks)]`` that can shade a layer through its map's light-space window.

        The ground is drawn once: the layer itself whole (its own heights also where finer
        layers lie: its map resolves no more than its pixels), and each coarser layer outside
        the next finer one (the blocks a finer layer covers left out, the rest discarded
        there). An orthographic map sees a caster only where the caster's light-space x-y
        overlaps the window, so every other block is culled exactly; the cost of a layer's
        map is one layer's blocks plus the few coarser ones up the sun's azimuth.
        """
        out = []
        x0, y0, x1, y1 = window
        for layer in self._layers[:level + 1]:
            light_xy = box_corners(layer.lo, layer.hi) @ basis[:2].T  # (n, 8, 2)
            overlap = ((light_xy[..., 0].max(axis=1) >= x0)
                       & (light_xy[..., 0].min(axis=1) <= x1)
                       & (light_xy[..., 1].max(axis=1) >= y0)
                       & (light_xy[..., 1].min(axis=1) <= y1))
            if layer.level < level:
                overlap &= ~layer.covered
            blocks = np.flatnonzero(overlap)
            if blocks.size:
                out.append((layer.level, blocks))
        return out

    def _depth_batches(self, gpu, casters, texel):
        """Give the casters' depth batches, each layer at the detail ``texel`` (m) resolves."""
        batches = []
        for k, blocks in casters:
            layer = self._layers[k]
            # cells up to SHADOW_CELL_TEXELS: finer caster detail than the map resolves is
            # wasted
            s = int(min(BLOCK, 2 ** max(0, math.floor(math.log2(
                max(SHADOW_CELL_TEXELS * texel / layer.resolution, 1.0))))))
            dvao = self._depth_vao(gpu, layer, s)
            discard = None if k == casters[-1][0] else layer.discard
            # Blocks that keep a pixel clear of the discard rectangle lose no fragment to it:
            # they go to a batch without the test, which the depth-only program draws without
            # a fragment shader (the same depths: a map holds the least depth at each texel,
            # whatever the order of the draws).
            parts = [(blocks, None)]
            if discard is not None:
                near = _near_rectangle(layer.lo[blocks], layer.hi[blocks], discard,
                                       layer.resolution)
                parts = [(blocks[~near], None), (blocks[near], discard)]
            for part, rect in parts:
                if part.size:
                    ranges = _merge_ranges(layer.offsets[s][part], layer.counts[s][part])
                    batches.append(DrawBatch(None, dvao, ranges, discard=rect))
        return batches


def _near_rectangle(lo: np.ndarray, hi: np.ndarray, rect: tuple, margin: float) -> np.ndarray:
    """Give whether each box comes within ``margin`` of a rectangle, or overlaps it.

    ``lo``, ``hi`` are (n, 3) box corners (their x-y extent is compared), ``rect`` is
    ``(x0, y0, x1, y1)``, all scene-local metres.
    """
    return ((hi[:, 0] >= rect[0] - margin) & (lo[:, 0] <= rect[2] + margin)
            & (hi[:, 1] >= rect[1] - margin) & (lo[:, 1] <= rect[3] + margin))


def _block_extremes(z: np.ndarray, brows: np.ndarray, bcols: np.ndarray):
    """(nby, nbx) lowest and highest height of each block, its edge lines included."""
    def per_segment(a, lines, axis, ufunc):
        # lines[i] .. lines[i + 1] inclusive: reduce the half-open runs, then the closing line
        out = ufunc.reduceat(a, lines[:-1], axis=axis)
        closing = np.take(a, lines[1:-1], axis=axis)
        idx = [slice(None)] * a.ndim
        idx[axis] = slice(0, len(lines) - 2)
        out[tuple(idx)] = ufunc(out[tuple(idx)], closing)
        return out

    zmin = per_segment(per_segment(z, brows, 0, np.minimum), bcols, 1, np.minimum)
    zmax = per_segment(per_segment(z, brows, 0, np.maximum), bcols, 1, np.maximum)
    return zmin, zmax


def _block_indices(h: int, w: int, s: int, step: int = 1):
    """Index buffer of a layer of (h, w) vertices at level s, with every block's range.

    Blocks of :data:`BLOCK` cells (:func:`render.terrain_buffers.block_indices`: each
    block's cells' two triangles, then its skirts). With ``step`` > 1, the indices into
    buffers of every ``step``-th vertex line (:func:`_sparse_step`): the same triangles.

    Returns
    -------
    indices : (n,) uint32
    offsets, counts : (n_blocks,) int64
        Each block's first index and number of indices.
    """
    return block_indices((h - 1) // step + 1, (w - 1) // step + 1, s // step,
                         _samples(0, h - 1, BLOCK) // step, _samples(0, w - 1, BLOCK) // step)


def _levels_1d(n: int) -> np.ndarray:
    """(n,) float64: the coarsest level of detail whose samples include each grid line.

    Levels sample every s-th line of a block and its last line (:func:`_samples`); blocks
    start at multiples of :data:`BLOCK`, so line i is in level s when s divides i, or when i
    is a block boundary (then it is in every level).
    """
    out = np.ones(n)
    i = np.arange(n)
    for s in _lods()[1:]:
        out[i % s == 0] = s
    out[_samples(0, n - 1, BLOCK)] = BLOCK
    return out


def _coarse_cells(n: int, s: int):
    """Give the grid lines of level s exactly and of level 2s or coarser, with their cells.

    Returns ``(exact, coarse)``, each ``(lines, a, b, t)``: the lines, and for each the
    first and last line of the level-2s cell that holds it and its fraction t of the way
    from a to b (0 on a line of level 2s).
    """
    levels = _levels_1d(n)
    grid = np.union1d(np.arange(0, n, 2 * s), [n - 1])

    def cells(lines):
        k = np.searchsorted(grid, lines, side="right") - 1
        a = grid[k]
        b = grid[np.minimum(k + 1, len(grid) - 1)]
        t = np.where(b > a, (lines - a) / np.maximum(b - a, 1), 0.0)
        return lines, a, np.where(b > a, b, a), t

    return cells(np.flatnonzero(levels == s)), cells(np.flatnonzero(levels >= 2 * s))


def _line_cells(n: int):
    """Per level index q (level ``2^q`` below :data:`BLOCK`): each line's level-``2^(q+1)`` cell.

    Returns ``(levels, a, b, t)``: (n,) int64 coarsest level of each line, and (q, n)
    first and last line of the cell and the fraction (:func:`_coarse_cells`; lines of a
    coarser level lie on the cell grid, t = 0).
    """
    lods = _lods()[:-1]
    a = np.zeros((len(lods), n), dtype=np.int64)
    b = np.zeros((len(lods), n), dtype=np.int64)
    t = np.zeros((len(lods), n))
    for q, s in enumerate(lods):
        for lines, la, lb, lt in _coarse_cells(n, s):
            a[q, lines], b[q, lines], t[q, lines] = la, lb, lt
    return _levels_1d(n).astype(np.int64), a, b, t


@functools.cache
def _background() -> ThreadPoolExecutor:
    """Give the thread that computes a frame's missing grids of scattered light (one, shared)."""
    return ThreadPoolExecutor(max_workers=1, thread_name_prefix="craterscape-scatter")


def _sparse_step(h: int, w: int, finest: int) -> int:
    """Give the vertex step of a (h, w) layer's buffers first needed at level ``finest``.

    ``finest`` itself from :data:`SPARSE_FROM` on, where every block boundary falls on its
    lines (a side of ``k finest + 1`` pixels, as the stacks' ``2^n + 1``); else 1.
    """
    if finest < SPARSE_FROM or (h - 1) % finest or (w - 1) % finest:
        return 1
    return finest


def _cell_tables(h: int, w: int) -> tuple:
    """Give the rows' and columns' cells (:func:`render.terrain_buffers.layer_buffers`)."""
    rl, ra, rb, rt = _line_cells(h)
    cl, ca, cb, ct = _line_cells(w)
    return rl, cl, ra, rb, rt, ca, cb, ct, BLOCK


def _morph_targets(z: np.ndarray, normals: np.ndarray):
    """Per vertex: the next coarser level's height and normal below it, and its own level.

    Parameters
    ----------
    z : (h, w) float64, metres
        The layer's (curved) heights at its pixel centres.
    normals : (h, w, 3) float64
        Unit normals.

    Returns
    -------
    target : (h, w) float64, metres
        For a vertex whose coarsest level is s < BLOCK: the height of level 2s's surface at
        its position (linear on the triangle of level 2s's cell that holds it, with the
        cells' diagonal from top-right to bottom-left as the index buffers cut them);
        otherwise its own height.
    level : (h, w) float64
        The vertex's coarsest level s (1, 2, 4, ... BLOCK).
    target_normal : (h, w, 3) float64
        The coarser level's normal, interpolated the same way (not normalised).

    Notes
    -----
    A vertex's level is the smaller of its row's and its column's, and where it lies in a
    cell of level 2s depends on its row and its column separately (:func:`_cell_tables`);
    :func:`render.terrain_buffers.morph_targets` computes every vertex at once.
    """
    return morph_targets(z, normals, _cell_tables(*z.shape))


def _fade_in(z: np.ndarray, xs: np.ndarray, ys: np.ndarray, parent) -> np.ndarray:
    """Heights blended into the parent's surface across the margin inside the layer's edge.

    ``parent`` is ``(z, x of column 0, y of row 0, cell size)`` of the parent layer (curved
    heights, scene-local); its surface is its full-resolution triangulation (the diagonal
    from top-right to bottom-left, as drawn). The weight of the layer's own heights is a
    smoothstep of the distance to the layer's edge over :data:`FADE_PARENT_PIXELS` parent
    pixels (at most :data:`FADE_MAX_FRACTION` of the layer's smaller side).
    """
    pres = parent[3]
    size = min(abs(xs[-1] - xs[0]), abs(ys[0] - ys[-1]))
    return fade_in(z, xs, ys, parent, min(FADE_PARENT_PIXELS * pres, FADE_MAX_FRACTION * size))


def _shadow_coarsening(footprint: float, resolution: float) -> int:
    """Give the power of two by which a layer's shadow map may be coarser than its pixels.

    ``footprint`` is the ground an image pixel spans (m) at the layer's nearest drawn block
    (its distance over the focal length; farther and off-axis, a pixel spans more), and
    ``resolution`` the layer's pixel (m). The factor is the largest power of two ``c`` with
    ``SHADOW_PIXEL_CELLS * c * resolution <= footprint``, at most :data:`BLOCK` (casters
    are never drawn coarser), or 1 where that is below :data:`MIN_SHADOW_COARSENING`. A
    relief of half an image pixel then spans at least two cells of ``c`` layer pixels, so
    the map resolves it as a layer-resolution map resolves a relief of two layer pixels
    (the accuracy ``tests/render/test_shadow_maps.py`` measures), with a factor of four to
    spare for the rocks of two image pixels the shadows must hold.
    """
    ratio = footprint / (SHADOW_PIXEL_CELLS * resolution)
    if not ratio >= MIN_SHADOW_COARSENING:  # NaN, or not worth a map of its own
        return 1
    return int(min(BLOCK, 2 ** math.floor(math.log2(ratio))))


def _merge_ranges(offsets, counts) -> list[tuple[int, int]]:
    """Contiguous (first, count) index ranges, adjacent blocks merged into one draw."""
    order = np.argsort(offsets)
    out: list[list[int]] = []
    for o, c in zip(offsets[order], counts[order], strict=True):
        o, c = int(o), int(c)
        if out and out[-1][0] + out[-1][1] == o:
            out[-1][1] += c
        else:
            out.append([o, c])
    return [(a, b) for a, b in out]


def _with_extra_bias(shadow: ShadowMap, metres: float) -> ShadowMap:
    return replace(shadow, bias=shadow.bias + metres / shadow.depth_range_m, framebuffer=None)
