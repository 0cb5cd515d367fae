"""What a scene hands the renderer: draw batches, shadow maps and per-frame facts.

A scene (:class:`render.terrain_scene.TerrainScene`, :class:`render.asteroid_scene.AsteroidScene`,
:class:`render.mesh_scene.MeshScene`; the :class:`Scene` protocol) owns its GPU buffers and,
for every frame, decides what to draw (culling, level of detail, whether a body is an
imposter) and which shadow map each part uses; the renderer runs every pass. A scene reaches
the GPU only through the :class:`Gpu` handle the renderer gives it (uploads, vertex arrays,
shadow maps), and every shadow map, a terrain layer's or a body's, is fitted and drawn by
:func:`render_shadow_map`. Positions on the GPU are relative to the scene's ``origin``
(float64, world frame), so float32 keeps millimetres across hundreds of kilometres.

One frame, in order: the renderer asks :meth:`Scene.imposter`; if the scene wants one, the
imposter's small view is rendered as geometry first; then :meth:`Scene.frame_state` plans the
frame (drawing its shadow maps through the handle), the renderer draws the plan, reads the
images back and composites the imposter (:mod:`render.imposter`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

if TYPE_CHECKING:
    from render.camera import Intrinsics, Pose
    from render.renderer import Lighting, RenderOptions, View

__all__ = ["BODY_SHADOW_BIAS", "TERRAIN_SHADOW_BIAS", "DrawBatch", "FrameState", "Gpu",
           "Imposter", "Morph", "Scene", "ShadowBias", "ShadowMap", "body_shadow_map",
           "far_plane", "frustum_visible", "light_basis", "ortho_light", "render_shadow_map"]


#: Shadow-map biases, in texels of the map (``texel`` = map extent / map size, metres). A
#: receiver is looked up ``NORMAL_OFFSET_TEXELS`` texels along its normal, so a surface
#: lit at a grazing sun does not shadow itself through the map's stair steps ("acne"); the
#: depth comparison then allows a constant ``BIAS_TEXELS`` (one texel's depth
#: quantisation and rasterisation difference, plus margin) and ``SLOPE_BIAS_TEXELS`` times
#: the tangent of the sun's incidence (a sloped receiver's depth changes across a texel; the
#: tangent is capped at 20 in ``shaders/shade.frag``, ``MAX_TAN_INCIDENCE``).
#: Bodies (asteroids, meshes) are drawn into the map with the same mesh as the camera sees.
NORMAL_OFFSET_TEXELS = 1.0
BODY_BIAS_TEXELS = 1.5
BODY_SLOPE_BIAS_TEXELS = 1.0
#: Terrain biases are wider: its shadow map is drawn from coarser levels of detail than
#: the camera's view, so the map's surface can lie up to a coarse cell above the fine one.
TERRAIN_BIAS_TEXELS = 2.0
TERRAIN_SLOPE_BIAS_TEXELS = 1.5
#: A body's shadow map covers its bounding cube grown by this fraction of its radius, so
#: the limb's texels are not clamped at the map's edge.
BODY_SHADOW_MARGIN = 0.01
#: Far clip plane: the farthest point of the scene times ``FAR_FACTOR`` plus ``FAR_SLACK_M``
#: metres, so the farthest geometry is never clipped by rounding of the log depth.
FAR_FACTOR = 1.01
FAR_SLACK_M = 1.0
#: Smallest distance (m) a level-of-detail choice divides by: the camera touching a bounding
#: box still gives a finite on-screen size.
MIN_LOD_DISTANCE_M = 1e-3
#: Metres a shadow map's depth range extends beyond its nearest caster and its farthest
#: receiver (after any margin), so neither lies on a clip plane where depth rounding could
#: clip it.
LIGHT_DEPTH_SLACK_M = 1.0
#: Smallest side (m) of a shadow map's footprint: receivers all on one light ray still give
#: an invertible projection.
MIN_LIGHT_EXTENT_M = 1e-6


def far_plane(farthest: float) -> float:
    """Give the far clip distance for a scene whose farthest point is ``farthest`` away.

    Parameters
    ----------
    farthest : float
        Distance of the farthest point, metres.

    Returns
    -------
    float
        ``farthest * FAR_FACTOR + FAR_SLACK_M``.
    """
    return farthest * FAR_FACTOR + FAR_SLACK_M


@dataclass(frozen=True)
class ShadowBias:
    """How a shadow map is looked up, in texels of the map (see the constants above).

    Parameters
    ----------
    normal_offset : float
        Texels along the receiver's normal the lookup moves.
    constant : float
        Texels of depth the comparison allows.
    slope : float
        Texels of depth allowed per unit tangent of the sun's incidence.
    """

    normal_offset: float
    constant: float
    slope: float


#: Biases of body maps (asteroids, meshes) and of terrain maps.
BODY_SHADOW_BIAS = ShadowBias(NORMAL_OFFSET_TEXELS, BODY_BIAS_TEXELS, BODY_SLOPE_BIAS_TEXELS)
TERRAIN_SHADOW_BIAS = ShadowBias(NORMAL_OFFSET_TEXELS, TERRAIN_BIAS_TEXELS,
                                 TERRAIN_SLOPE_BIAS_TEXELS)


class Gpu(Protocol):
    """The narrow handle to the GPU a renderer passes its scenes.

    A scene uploads and owns its buffers and textures (:meth:`buffer`, :meth:`texture`,
    :meth:`texture_cube`), binds them to the renderer's programs (:meth:`vertex_arrays`)
    and draws its shadow maps (:meth:`shadow_target`, :meth:`draw_depth`, through
    :func:`render_shadow_map`); it never sees the context or runs a camera pass: the
    renderer does (:class:`render.renderer.SceneGpu` is the handle).

    Attributes
    ----------
    token : int
        Never reused between renderers: scenes cache vertex arrays under it (they bind one
        renderer's programs).
    """

    token: int

    @property
    def context(self) -> object:
        """The context uploads go to, as an opaque key: scenes cache their uploads under it."""
        ...

    def buffer(self, data: bytes) -> Any:
        """Upload a vertex, index or attribute buffer.

        Parameters
        ----------
        data : bytes
            Its contents.

        Returns
        -------
        moderngl.Buffer
            The buffer (the scene owns it).
        """
        ...

    def texture(self, size: tuple[int, int], components: int, data: bytes,
                dtype: str) -> Any:
        """Upload a 2-D texture, sampled bilinearly and clamped at its edges.

        Parameters
        ----------
        size : (int, int)
            Width and height, texels.
        components : int
            Values per texel.
        data : bytes
            Rows from the texture's first (v = 0) row.
        dtype : str
            The texel type, e.g. ``"f2"`` or ``"f4"``.

        Returns
        -------
        moderngl.Texture
            The texture (the scene owns it).
        """
        ...

    def texture_cube(self, size: tuple[int, int], components: int, data: bytes,
                     dtype: str) -> Any:
        """Upload a cube map, sampled bilinearly.

        Parameters
        ----------
        size : (int, int)
            Side of each face, texels.
        components : int
            Values per texel.
        data : bytes
            The faces +X, -X, +Y, -Y, +Z, -Z in GL's order.
        dtype : str
            The texel type, e.g. ``"f2"``.

        Returns
        -------
        moderngl.TextureCube
            The cube map (the scene owns it).
        """
        ...

    def vertex_arrays(self, vbo: Any, ibo: Any, albedo: Any = None,
                      morph: Any = None, scatter: Any = None) -> tuple[Any, Any]:
        """Bind a mesh's buffers to the camera and depth programs.

        Parameters
        ----------
        vbo, ibo : moderngl.Buffer
            Interleaved position and normal (3f 3f, scene-local metres) and uint32 indices.
        albedo : moderngl.Buffer, optional
            One float32 albedo factor per vertex.
        morph : moderngl.Buffer, optional
            Per-vertex geomorphing targets (4f 3f, see :class:`Morph`).
        scatter : moderngl.Buffer, optional
            One float32 scattered irradiance per vertex (:mod:`render.body_scattering`).

        Returns
        -------
        tuple
            ``(scene, depth)``: the mesh bound to the camera pass's programs and to the
            shadow pass's (opaque handles that go into a :class:`DrawBatch`).
        """
        ...

    def shadow_target(self, size: tuple[int, int]) -> tuple[Any, Any]:
        """Allocate a depth texture of ``size`` texels and its framebuffer (caller owns them).

        Parameters
        ----------
        size : (int, int)
            Width and height of the map, texels.

        Returns
        -------
        tuple
            ``(moderngl.Texture, moderngl.Framebuffer)``.
        """
        ...

    def draw_depth(self, framebuffer: Any, size: tuple[int, int], light_clip: np.ndarray,
                   batches: Sequence[DrawBatch]) -> None:
        """Draw the depth of ``batches`` into a shadow map's framebuffer.

        Parameters
        ----------
        framebuffer : moderngl.Framebuffer
            From :meth:`shadow_target`.
        size : (int, int)
            Width and height of the map, texels.
        light_clip : (4, 4) float64
            Orthographic clip-from-scene-local matrix of the sun.
        batches : sequence of DrawBatch
            What casts shadows (their ``depth_vao``).
        """
        ...


def render_shadow_map(gpu: Gpu, current: ShadowMap | None, size: int | tuple[int, int],
                      sun: Any, receivers: np.ndarray, casters: np.ndarray, *, margin: float,
                      bias: ShadowBias,
                      draw: Callable[[float, tuple[float, float, float, float]],
                                     Sequence[DrawBatch]]) -> ShadowMap:
    """Fit a shadow map to the sun and draw it: the one setup every scene's maps go through.

    The map is orthographic from the sun (:func:`ortho_light`): its footprint covers the
    ``receivers``, its depth runs from the ``casters`` nearest the sun to the receiver
    farthest from it. Its biases are ``bias`` times its texel (depth biases in metres, see
    :class:`ShadowMap`).

    Parameters
    ----------
    gpu : Gpu
        Allocates the map and draws its depth.
    current : ShadowMap or None
        A map to draw into again: reused when its size matches, released when not.
    size : int or (int, int)
        Map side, texels, or its (width, height) along light-space x and y.
    sun : (3,) float
        Unit vector towards the sun, world frame.
    receivers, casters : (n, 3) float64, metres, scene-local
        Points the map must cover, and points whose shadows it must hold.
    margin : float
        Metres added around the receivers (and to the depth range).
    bias : ShadowBias
        The lookup's biases in texels.
    draw : callable
        ``draw(extent, window)``: what casts shadows (a sequence of :class:`DrawBatch` with
        depth vertex arrays), given the map's larger texel times its larger side (m) and its
        light-space window ``(x0, y0, x1, y1)`` (m, see :func:`ortho_light`), so a scene may
        pick the level of detail the map's texels resolve and cull what the map cannot see.

    Returns
    -------
    ShadowMap
        ``current`` updated in place, or a new map.
    """
    clip, light, _, depth, window = ortho_light(sun, receivers, casters, margin=margin)
    w, h = (size, size) if isinstance(size, (int, np.integer)) else size
    w, h = int(w), int(h)
    if current is None or current.shape != (w, h):
        if current is not None:
            current.release()
        tex, fbo = gpu.shadow_target((w, h))
        current = ShadowMap(tex, max(w, h), light, 0.0, 0.0, 0.0, framebuffer=fbo,
                            shape=(w, h))
    sx, sy = window[2] - window[0], window[3] - window[1]
    tx, ty = sx / w, sy / h
    gpu.draw_depth(current.framebuffer, (w, h), clip, draw(max(tx, ty) * max(w, h), window))
    texel = min(tx, ty)
    current.light_from_world = light
    current.normal_offset = bias.normal_offset * texel
    current.bias = bias.constant * texel / depth
    current.slope_bias = bias.slope * texel / depth
    current.texel_m = max(tx, ty)
    current.depth_range_m = depth
    current.texel_xy = (tx, ty)
    current.slope_texels = bias.slope
    current.axes = light_basis(sun)
    return current


def body_shadow_map(gpu: Gpu, current: ShadowMap | None, size: int, sun: Any,
                    radius: float, casters: Callable[[float], Sequence[DrawBatch]]) -> ShadowMap:
    """Render a body's shadow map from the sun, fitted to its bounding cube.

    Parameters
    ----------
    gpu : Gpu
        Allocates the map and draws its depth.
    current : ShadowMap or None
        The scene's map of an earlier frame: reused when its size matches, released when not.
    size : int
        Map side, texels.
    sun : (3,) float
        Unit vector towards the sun, world frame.
    radius : float
        Bounding radius of the body (m) about the scene origin: the map covers its cube,
        grown by :data:`BODY_SHADOW_MARGIN` of it.
    casters : callable
        ``casters(extent)``: what casts shadows, given the map's extent in metres.

    Returns
    -------
    ShadowMap
        ``current`` updated in place, or a new map (:func:`render_shadow_map`).
    """
    r = radius
    pts = np.array([[sx * r, sy * r, sz * r] for sx in (-1, 1) for sy in (-1, 1)
                    for sz in (-1, 1)])
    return render_shadow_map(gpu, current, size, sun, pts, pts, margin=BODY_SHADOW_MARGIN * r,
                             bias=BODY_SHADOW_BIAS, draw=lambda extent, window: casters(extent))


class Scene(Protocol):
    """What the renderer and the frame loop need from a scene.

    A new kind of scene is a new class with these members, not a new ``hasattr`` branch in
    the renderer or :mod:`render.sequence` (:class:`render.terrain_scene.TerrainScene`,
    :class:`render.asteroid_scene.AsteroidScene`, :class:`render.mesh_scene.MeshScene`).
    Scenes plan; the renderer runs every pass: a scene reaches the GPU only through the
    :class:`Gpu` handle it is given, and asks for an imposter (:meth:`imposter`) instead of
    rendering one itself.

    Attributes
    ----------
    kind : str
        ``"terrain"``, ``"asteroid"``, ``"mesh"`` or ``"binary"``.
    origin : (3,) float64, metres
        World point subtracted before anything reaches the GPU.
    reach : float, metres
        How far the scene's geometry reaches from the centre a body rotation turns it
        about (a body's bounding radius, boulders included): the lever arm of its spin in
        motion blur and the sphere a trajectory must stay outside. 0 for a scene that does
        not turn (a terrain map).
    """

    kind: str
    origin: np.ndarray

    @property
    def reach(self) -> float:
        """Reach of the scene's geometry from its centre of rotation (m; see above)."""
        ...

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """World-frame bounding box of the scene.

        Returns
        -------
        lo, hi : (3,) float64, metres
            Its smallest and largest corner.
        """
        ...

    def set_body_rotation(self, quaternion: Any) -> None:
        """Set the body's rotation for the next frame (scenes that do not rotate ignore it).

        Parameters
        ----------
        quaternion : (4,) float
            R_WB as [w, x, y, z], body to world.
        """
        ...

    def imposter(self, view: View, options: RenderOptions) -> Imposter | None:
        """Whether the frame shows the scene (partly) as an imposter, and how to render it.

        The renderer asks before :meth:`frame_state` ("imposter first"), renders the
        imposter's view of the scene as geometry, then plans the frame with the request.

        Parameters
        ----------
        view : render.renderer.View
            The frame's camera.
        options : render.renderer.RenderOptions
            The frame's quality settings.

        Returns
        -------
        Imposter or None
            The imposter to render, or None: the frame is geometry only.
        """
        ...

    def frame_state(self, view: View, lighting: Lighting, options: RenderOptions, gpu: Gpu,
                    imposter: Imposter | None) -> FrameState:
        """Plan one frame: batches in draw order, shadow maps and per-frame facts.

        Parameters
        ----------
        view : render.renderer.View
            The frame's camera.
        lighting : render.renderer.Lighting
            The sun and reflectance.
        options : render.renderer.RenderOptions
            The frame's quality settings.
        gpu : Gpu
            The handle to upload, bind and draw shadow maps with.
        imposter : Imposter or None
            What :meth:`imposter` asked for this view (None: draw geometry only): the
            geometry an imposter replaces is left out.

        Returns
        -------
        FrameState
            The plan the renderer draws.
        """
        ...


@dataclass(frozen=True)
class Imposter:
    """An imposter a scene asks the renderer for (the asteroid paper's distant body).

    The renderer renders the scene from ``pose`` with ``intrinsics`` (a small image; the
    camera shares the frame camera's centre), as geometry, with ``lod_pixels`` as the level
    of detail target, and maps that image into the frame as a homography of the image plane
    (:mod:`render.imposter`).

    Parameters
    ----------
    pose : render.camera.Pose
        The imposter's camera: the frame camera's centre, looking at the body.
    intrinsics : render.camera.Intrinsics
        Its square image.
    lod_pixels : float
        The level-of-detail target of its render, pixels of its image.
    blend : float or None
        None: the imposter replaces the geometry (radiance, range and normals). A weight in
        [0, 1]: the frame is the geometry's, with the imposter's radiance blended in by this
        weight where both see the body (the fade between the two).
    """

    pose: Pose
    intrinsics: Intrinsics
    lod_pixels: float
    blend: float | None = None


@dataclass(eq=False)
class ShadowMap:
    """An orthographic depth map from the sun and how to look it up.

    The lookup's depth bias is ``bias`` plus ``slope_texels`` times the length of the
    receiver's depth gradient in light space (its tilt from the light, from its normal),
    each component times the texel along its axis (:attr:`texel_xy`): a map whose texels
    differ along x and y is biased by what each axis cannot resolve, never by the coarser
    one alone (a square map's bias is the texel times the tangent of the incidence).

    Parameters
    ----------
    texture : moderngl.Texture
        The depth texture (compares ``<=``, bilinear), :attr:`shape` texels.
    size : int
        Its larger side, texels.
    light_from_world : (4, 4) float64
        Scene-local coordinates (world minus the scene origin, metres) to texture
        coordinates and depth, each in [0, 1].
    normal_offset : float
        Metres along the receiver's normal the lookup moves.
    bias, slope_bias : float
        Constant depth bias and the slope bias of the map's finer texel, in depth units
        (fractions of the depth range).
    texel_m : float
        Larger side of a texel, metres.
    depth_range_m : float
        Depth the map spans, metres.
    framebuffer : moderngl.Framebuffer, optional
        The framebuffer it is drawn through (None for a copy that shares the texture).
    shape : (int, int), optional
        (width, height) in texels along light-space x and y (default: ``size`` square).
    texel_xy : (float, float)
        Texel side along light-space x and y, metres.
    slope_texels : float
        Texels of depth allowed per unit of the receiver's depth gradient.
    axes : (3, 3) float64
        The light-space axes (:func:`light_basis`).
    """

    texture: Any
    size: int
    light_from_world: np.ndarray
    normal_offset: float
    bias: float
    slope_bias: float
    texel_m: float = 0.0
    depth_range_m: float = 1.0
    framebuffer: Any = None
    shape: tuple = ()
    texel_xy: tuple = (0.0, 0.0)
    slope_texels: float = 0.0
    axes: np.ndarray = field(default_factory=lambda: np.eye(3))

    def __post_init__(self):
        if not self.shape:
            self.shape = (int(self.size), int(self.size))
        if self.texel_xy == (0.0, 0.0):
            self.texel_xy = (self.texel_m, self.texel_m)

    def release(self) -> None:
        """Release the map's texture and framebuffer on the GPU."""
        if self.framebuffer is not None:
            self.framebuffer.release()
        self.texture.release()


@dataclass(frozen=True)
class Morph:
    """How a batch's vertices morph toward the next coarser level of detail.

    The vertex buffer's morph attributes hold each vertex's position on the coarser level and
    a key (:meth:`Gpu.vertex_arrays`).

    Parameters
    ----------
    mode : int
        1: vertices whose key equals ``level`` morph, completing at distance ``2^k`` metres;
        2: every vertex morphs, completing at ``2^(k + key)`` metres.
    k : float
        log2 of the distance (m) where the morph completes (mode 1), or its common part
        (mode 2).
    band : float
        Octaves of distance the morph takes.
    level : float
        The level of detail drawn (mode 1).
    scale, top, bias_per_level : float
        Widen a terrain shadow map's bias by ``bias_per_level`` (depth units) per unit of
        the continuous level ``clamp(scale * d, level, top)``, d the distance in metres
        (0: no extra bias).
    """

    mode: int
    k: float
    band: float
    level: float = 0.0
    scale: float = 0.0
    top: float = 0.0
    bias_per_level: float = 0.0


@dataclass(eq=False)
class DrawBatch:
    """Index ranges of one vertex array to draw with one set of uniforms.

    Parameters
    ----------
    vao, depth_vao : handles
        The mesh bound to the camera and the depth programs (:meth:`Gpu.vertex_arrays`);
        ``vao`` is None in a batch only shadow maps draw.
    ranges : list of (int, int)
        ``(first, count)`` index ranges to draw.
    world_from_model : (3, 3) float64
        Rotation of the mesh into the world frame (R_WB for a body).
    model_offset : (3,) float64, metres
        Where the mesh's origin lies, scene-local.
    discard : (4,) float, optional
        ``(xmin, ymin, xmax, ymax)`` scene-local metres: fragments inside are discarded
        (a finer terrain layer draws there).
    shadow : ShadowMap, optional
        The map the batch's fragments look up.
    triangles : int
        Triangles drawn (for the frame's facts).
    vertex_albedo : bool
        The vertex array binds a per-vertex albedo factor.
    morph : Morph, optional
        Geomorphing of the batch's vertices (see ``render/shaders/scene.vert``).
    normal_map : tuple, optional
        Shading normals from a texture instead of the vertices: ``(texture, (x0, y0,
        1/width, 1/height))`` mapping scene-local x, y to texture coordinates
        ``((x - x0) / width, (y0 - y) / height)``.
    normal_cube : moderngl.TextureCube, optional
        Shading normals from a cube map looked up by model-frame direction from the model
        origin (a star-shaped body's finest normals).
    scatter : tuple, optional
        Light from elsewhere than the sun (:mod:`render.scattering`): ``(texture, rect)``,
        ``rect`` as for ``normal_map``; a two-channel float texture of the irradiance the
        terrain scatters (over the solar irradiance) and the Earth's visibility.
    vertex_scatter : bool
        The vertex array binds a per-vertex scattered irradiance (over the solar irradiance,
        :mod:`render.body_scattering`), which then stands for ``scatter``'s first channel.
    """

    vao: Any
    depth_vao: Any
    ranges: list
    world_from_model: np.ndarray = field(default_factory=lambda: np.eye(3))
    model_offset: np.ndarray = field(default_factory=lambda: np.zeros(3))
    discard: tuple | None = None
    shadow: ShadowMap | None = None
    triangles: int = 0
    vertex_albedo: bool = False
    morph: Morph | None = None
    normal_map: tuple | None = None
    normal_cube: Any = None
    scatter: tuple | None = None
    vertex_scatter: bool = False


@dataclass(eq=False)
class FrameState:
    """A scene's plan for one frame: batches in draw order, the far distance, what is drawn.

    Parameters
    ----------
    batches : list of DrawBatch
        What to draw, in order.
    far : float
        Distance (m) of the farthest point the frame may show (:func:`far_plane`).
    drawn : dict
        Facts about what is drawn (levels, triangles, imposter state) for the frame's truth.
    albedo : tuple, optional
        ``(texture, (xmin, ymin, xmax, ymax))``: a float texture whose value at scene-local
        (x, y) multiplies the albedo (or Hapke's w), the window (metres) spanning the
        texture's outer edges.
    """

    batches: list
    far: float
    drawn: dict = field(default_factory=dict)
    albedo: tuple | None = None


def light_basis(sun: Any) -> np.ndarray:
    """Give the light-space axes of a sun direction.

    Parameters
    ----------
    sun : (3,) float
        Direction towards the sun, world frame (need not be unit).

    Returns
    -------
    (3, 3) float64
        Rows: light-space x and y axes and the direction light travels (-sun), unit.
    """
    s = np.asarray(sun, dtype=np.float64)
    s = s / np.linalg.norm(s)
    d = -s
    helper = np.array([0.0, 0.0, 1.0]) if abs(d[2]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(helper, d)
    x /= np.linalg.norm(x)
    y = np.cross(d, x)
    return np.stack([x, y, d])


def ortho_light(sun: Any, receivers: np.ndarray, casters: np.ndarray, margin: float = 0.0
                ) -> tuple[np.ndarray, np.ndarray, float, float,
                           tuple[float, float, float, float]]:
    """Fit an orthographic light matrix to ``receivers``, deep enough for ``casters``.

    The map's footprint covers the receivers; its depth range runs from the caster nearest
    the sun to the receiver farthest from it, so every occluder that can shade a receiver
    is inside. :data:`LIGHT_DEPTH_SLACK_M` more at either end keeps the extreme points off
    the clip planes.

    Parameters
    ----------
    sun : (3,) float
        Direction towards the sun, world frame.
    receivers, casters : (n, 3) float64, metres, scene-local
        Points the map must cover, and points whose shadows it must hold.
    margin : float
        Metres added around the receivers and to either end of the depth range.

    Returns
    -------
    clip_from_world : (4, 4) float64
        Scene-local coordinates to clip space.
    light_from_world : (4, 4) float64
        Scene-local coordinates to texture coordinates and depth in [0, 1].
    extent : float
        The map's larger side, metres.
    depth : float
        The depth range, metres.
    window : (4,) float
        The map's ``(x0, y0, x1, y1)`` in light-space coordinates (``points @
        light_basis(sun).T``, metres), for culling casters.
    """
    basis = light_basis(sun)
    r = np.atleast_2d(receivers) @ basis.T
    c = np.atleast_2d(casters) @ basis.T
    x0, y0 = r[:, 0].min() - margin, r[:, 1].min() - margin
    x1, y1 = r[:, 0].max() + margin, r[:, 1].max() + margin
    near = min(c[:, 2].min(), r[:, 2].min()) - margin - LIGHT_DEPTH_SLACK_M
    far = r[:, 2].max() + margin + LIGHT_DEPTH_SLACK_M
    sx, sy = max(x1 - x0, MIN_LIGHT_EXTENT_M), max(y1 - y0, MIN_LIGHT_EXTENT_M)
    view = np.eye(4)
    view[:3, :3] = basis
    ortho = np.eye(4)
    ortho[0, 0] = 2.0 / sx
    ortho[0, 3] = -(x0 + x1) / sx
    ortho[1, 1] = 2.0 / sy
    ortho[1, 3] = -(y0 + y1) / sy
    ortho[2, 2] = 2.0 / (far - near)
    ortho[2, 3] = -(far + near) / (far - near)
    clip = ortho @ view
    to_tex = np.array([[0.5, 0, 0, 0.5], [0, 0.5, 0, 0.5], [0, 0, 0.5, 0.5], [0, 0, 0, 1.0]])
    return clip, to_tex @ clip, max(sx, sy), far - near, (x0, y0, x1, y1)


def frustum_visible(corners: np.ndarray, view_rotation: np.ndarray, camera: np.ndarray,
                    intrinsics: Intrinsics, far: float = math.inf) -> np.ndarray:
    """Tell which boxes may intersect the view frustum.

    Conservative plane tests in OpenCV camera coordinates: a box is culled only when all its
    corners lie outside one plane (behind the camera, beyond an image edge, or beyond far).

    Parameters
    ----------
    corners : (n, 8, 3) float64, metres, scene-local
        The boxes' corners (:func:`box_corners`).
    view_rotation : (3, 3) float64
        R_WC, camera to world.
    camera : (3,) float64, metres, scene-local
        The camera centre.
    intrinsics : render.camera.Intrinsics
        The camera's image and pinhole.
    far : float
        Distance (m) along the optical axis beyond which nothing is seen.

    Returns
    -------
    (n,) bool
        True where the box may be seen.
    """
    c = (corners - camera) @ view_rotation  # (n, 8, 3) camera coordinates
    x, y, z = c[..., 0], c[..., 1], c[..., 2]
    k = intrinsics
    outside = [
        np.all(z <= 0.0, axis=1),
        np.all(k.fx * x + (k.cx + 0.5) * z < 0.0, axis=1),
        np.all(k.fx * x + (k.cx - k.width + 0.5) * z > 0.0, axis=1),
        np.all(k.fy * y + (k.cy + 0.5) * z < 0.0, axis=1),
        np.all(k.fy * y + (k.cy - k.height + 0.5) * z > 0.0, axis=1),
        np.all(z > far, axis=1),
    ]
    return ~np.any(outside, axis=0)


def box_corners(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Give the corners of axis-aligned boxes.

    Parameters
    ----------
    lo, hi : (n, 3) or (3,) float64, metres
        The boxes' minima and maxima.

    Returns
    -------
    (n, 8, 3) float64
        Corner i takes x, y, z from ``hi`` where bits 0, 1, 2 of i are set.
    """
    lo = np.atleast_2d(lo)
    hi = np.atleast_2d(hi)
    out = np.empty((lo.shape[0], 8, 3))
    for i in range(8):
        out[:, i, 0] = hi[:, 0] if i & 1 else lo[:, 0]
        out[:, i, 1] = hi[:, 1] if i & 2 else lo[:, 1]
        out[:, i, 2] = hi[:, 2] if i & 4 else lo[:, 2]
    return out


def box_distance(lo: np.ndarray, hi: np.ndarray, point: np.ndarray) -> np.ndarray:
    """Give the distance from a point to each axis-aligned box.

    Parameters
    ----------
    lo, hi : (n, 3) float64, metres
        The boxes' minima and maxima.
    point : (3,) float64, metres
        The point, in the boxes' frame.

    Returns
    -------
    (n,) float64, metres
        Euclidean distance to each box (0 inside).
    """
    d = np.maximum(np.maximum(lo - point, 0.0), point - hi)
    return np.sqrt((d * d).sum(axis=1))
