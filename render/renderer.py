"""The renderer: camera images, exact LIDAR range and normals, with shadows.

A frame is two passes. The surface pass draws the scene once into float32 colour
attachments: the world-frame surface normal and what shading needs of the nearest surface
(its camera-relative position, a body's per-vertex albedo factor and scattered light); its
stencil holds each pixel's group (the batches that share a shadow map and maps). The
shading pass then computes, once per pixel, the radiance (reflectance factor I/F under a
unit sun, see :mod:`render.reflectance`) and the range (the Euclidean distance from the
camera centre, from the camera-relative float32 position: not recovered from the depth
buffer), a full-screen triangle per group drawn where the stencil holds it: a CPU
rasteriser shades a 4x4 block of pixels for every triangle that touches it, so drawn
forward, with triangles of a pixel or two, each pixel's shadows were computed many times
over. The stencil test also lets the rasteriser skip a block whose fragments all lie behind what is
already drawn (with a depth test alone it shades them and drops the results). Depth
testing uses reversed Z: a float32 depth buffer holding ``near / z`` (an infinite-far
projection, clip z in [0, 1]), whose relative depth resolution is float32's own (6e-8) at
every distance, from centimetres to a thousand kilometres, so descents from orbit to
touchdown need no depth partitioning, and the fragment shader writes no depth (so the depth
test comes before the fragment shader).

Each pass draws with programs specialised at compile time (``#define`` switches in
``shaders/scene.frag`` and ``shaders/shade.frag``): one per combination of the maps and
per-vertex values its batches carry, and one per reflectance law and effects, compiled once
per renderer, so that no fragment pays for a path it never takes.

The projection follows :mod:`render.camera` exactly: pixel (u, v) is centred where the
OpenCV pinhole model puts it, so a world point's rendered pixel and its projection with the
frame's truth agree (tests check this to a fraction of a pixel).

Shadows are shadow maps: orthographic depth maps from the sun, looked up with a normal offset,
a constant plus slope-scaled bias (the sun is often only a few degrees high, so the slope term
matters at the terminator) and 3x3 percentage-closer filtering. Scenes decide which maps to
use: a terrain layer stack fits one map to every layer (computed once per sun direction, so
long descents stay sharp from 10 km to the ground), an asteroid fits one to the body every
frame.
"""

from __future__ import annotations

import ctypes
import itertools
import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from importlib import resources
from typing import Any

import numpy as np

from render.camera import Intrinsics, Pose
from render.context import create_context, gl_function
from render.errors import RenderUnavailableError
from render.imposter import blend, composite
from render.readback import read as read_frame
from render.reflectance import BRDF_CODES, MCEWEN_MOON, SATO_643NM, Hapke, check_brdf
from render.scene import DrawBatch, Imposter, Scene
from terrain.core.errors import InvalidParameterError

__all__ = ["Frame", "Lighting", "RenderOptions", "Renderer", "SceneGpu", "View",
           "clip_from_camera"]

log = logging.getLogger(__name__)

#: The near clip plane (m): the reversed-Z depth buffer holds ``NEAR_M / z``.
NEAR_M = 0.01
#: Image sizes whose offscreen framebuffers are kept at once (a frame, its imposter, and
#: the sizes of a client switching between a few).
MAX_TARGETS = 4
#: Solar spectral irradiance at 1 au near 643 nm (W m^-2 nm^-1), the LROC WAC red band of
#: :data:`render.reflectance.SATO_643NM`: approximately the ASTM E-490 AM0 spectrum there.
SOLAR_643NM = 1.58

_TOKENS = itertools.count(1)


@dataclass(frozen=True)
class Lighting:
    """Sun direction (unit vector towards the sun, world frame), albedo and reflectance.

    :attr:`spectral_irradiance` (``irradiance / distance^2``) turns I/F into radiance
    (:meth:`radiance`).

    Parameters
    ----------
    sun : (3,) float
        Direction towards the sun, world frame (normalised when built).
    albedo : float
        Normal albedo in [0, 1] (the Lambert and Lommel-Seeliger laws' factor).
    brdf : str
        Reflectance law (:data:`render.reflectance.BRDF_CODES`).
    mcewen : tuple of float
        McEwen's lunar-Lambert phase polynomial.
    hapke : render.reflectance.Hapke
        The Hapke parameters where ``brdf`` is "hapke".
    irradiance : float
        Solar spectral irradiance at 1 au in the camera's band, W m^-2 nm^-1.
    distance : float
        The body's distance from the Sun, au.
    earth : (3,) float or None
        Direction towards the Earth (unit vector, world frame) where earthshine is drawn;
        None for no second source.
    earthshine : float
        Irradiance from the Earth on a surface facing it, as a fraction of the direct solar
        irradiance at the body (its phase, albedo and distance folded in; 0 for none).
    """

    sun: tuple
    albedo: float = 0.12
    brdf: str = "lunar-lambert"
    mcewen: tuple = MCEWEN_MOON
    hapke: Hapke = SATO_643NM
    irradiance: float = SOLAR_643NM
    distance: float = 1.0
    earth: tuple | None = None
    earthshine: float = 0.0

    def __post_init__(self):
        s = np.asarray(self.sun, dtype=np.float64).reshape(-1)
        if s.shape != (3,) or not np.all(np.isfinite(s)) or np.linalg.norm(s) == 0:
            raise InvalidParameterError(f"sun direction must be a non-zero 3-vector; got {s}")
        object.__setattr__(self, "sun", tuple((s / np.linalg.norm(s)).tolist()))
        if not (0.0 <= float(self.albedo) <= 1.0):
            raise InvalidParameterError(f"albedo must lie in [0, 1]; got {self.albedo}")
        object.__setattr__(self, "albedo", float(self.albedo))
        object.__setattr__(self, "brdf", check_brdf(self.brdf))
        if not isinstance(self.hapke, Hapke):
            raise InvalidParameterError(f"hapke must be a Hapke record; got {self.hapke!r}")
        for name in ("irradiance", "distance"):
            v = float(getattr(self, name))
            if not (v > 0 and math.isfinite(v)):
                raise InvalidParameterError(f"sun {name} must be positive; got {v}")
            object.__setattr__(self, name, v)
        if self.earth is not None:
            e = np.asarray(self.earth, dtype=np.float64).reshape(-1)
            if e.shape != (3,) or not np.all(np.isfinite(e)) or np.linalg.norm(e) == 0:
                raise InvalidParameterError(
                    f"earth direction must be a non-zero 3-vector; got {e}")
            object.__setattr__(self, "earth", tuple((e / np.linalg.norm(e)).tolist()))
        es = float(self.earthshine)
        if not (0.0 <= es < 1.0):
            raise InvalidParameterError(f"earthshine must lie in [0, 1); got {es}")
        object.__setattr__(self, "earthshine", es)

    @property
    def sun_angular_radius(self) -> float:
        """Angular radius of the solar disk seen from the body (radians).

        The Sun's photospheric radius 695,700 km (IAU 2015 Resolution B3 nominal value) over
        the body's distance (1 au = 149,597,870.7 km, IAU 2012 Resolution B2).
        """
        return math.asin(695_700.0 / (self.distance * 149_597_870.7))

    @property
    def spectral_irradiance(self) -> float:
        """Solar spectral irradiance at the body (W m^-2 nm^-1): irradiance / distance^2."""
        return self.irradiance / self.distance**2

    def radiance(self, i_over_f: np.ndarray) -> np.ndarray:
        """Convert an I/F image to spectral radiance: ``I/F F / pi``.

        F is the solar spectral irradiance at the body (I/F is radiance over that of a
        perfect diffuser lit at normal incidence, F / pi).

        Parameters
        ----------
        i_over_f : (h, w) float
            Reflectance factor I/F.

        Returns
        -------
        (h, w) float32
            Spectral radiance, W m^-2 sr^-1 nm^-1.
        """
        return np.asarray(i_over_f, dtype=np.float32) * np.float32(
            self.spectral_irradiance / math.pi)

    @classmethod
    def from_angles(cls, azimuth_deg: float, elevation_deg: float, **kwargs: Any) -> Lighting:
        """Build the lighting of a sun at an azimuth and elevation.

        Parameters
        ----------
        azimuth_deg : float
            Degrees clockwise from north (+y) towards east (+x).
        elevation_deg : float
            Degrees above the x-y plane.
        **kwargs
            The other fields of :class:`Lighting`.

        Returns
        -------
        Lighting
            The sun at that direction.
        """
        az, el = math.radians(azimuth_deg), math.radians(elevation_deg)
        return cls((math.sin(az) * math.cos(el), math.cos(az) * math.cos(el), math.sin(el)),
                   **kwargs)


@dataclass(frozen=True)
class View:
    """Where the camera is and what it is.

    Parameters
    ----------
    pose : render.camera.Pose
        World-frame camera centre and attitude.
    intrinsics : render.camera.Intrinsics
        Image size and pinhole.
    time : float
        Seconds since the sequence's start.
    """

    pose: Pose
    intrinsics: Intrinsics
    time: float = 0.0


#: Most samples per pixel side of an antialiased frame (49 samples a pixel).
MAX_ANTIALIAS = 7


@dataclass(frozen=True)
class RenderOptions:
    """Quality and cost settings of a frame.

    Parameters
    ----------
    shadows : bool
        Draw shadow maps.
    shadow_size : int
        Side of each shadow map, texels (64 to 8192).
    lod_pixels : float
        Target on-screen size (pixels) of a cell; terrain blocks and bodies are drawn at the
        coarsest level of detail that keeps cells below it.
    triangle_budget : int
        The most triangles a terrain frame may draw; the target is relaxed until it fits.
    geomorph : bool
        Levels of detail change continuously (vertices morph toward the coarser level over a
        band of distance, see :mod:`render.terrain_scene`); off, they switch.
    antialias : int
        Samples per pixel side (odd, at most :data:`MAX_ANTIALIAS`). With more than one, a
        frame is drawn at ``antialias`` times the resolution and each pixel's radiance is the
        mean of its ``antialias`` squared samples, as a detector integrates its pixel's area;
        one sample per pixel instead aliases what is smaller than a pixel (a distant
        asteroid's boulders cover one pixel centre or three as they move, and the corners a
        tracker follows on them jitter by tenths of a pixel between frames). Range and
        normals stay the centre sample's, the pixel centre's own ray, so they stay exact;
        levels of detail are chosen for the output pixels, so the scene drawn is the same.
    soft_shadows : bool
        The sun is its disk (:attr:`Lighting.sun_angular_radius`): shadows have the penumbrae
        it casts (percentage-closer soft shadows, ``render/shaders/scene.frag``); off, a point.
    scattering : bool
        Add the sunlight that terrain scatters once into other terrain (shadowed ground
        included), where the scene computes it (:mod:`render.scattering`).
    earthshine : bool
        Add the Earth's light (:attr:`Lighting.earth`, :attr:`Lighting.earthshine`).
    shadow_detail : float
        Terrain shadow maps' texels per layer pixel (0.25 to 8): each layer's map is sized so
        that its texels resolve the layer's pixels on the ground, up to ``shadow_size`` texels
        a side (:mod:`render.terrain_scene`); bodies' maps are ``shadow_size`` square. Two
        hold the shadow of every relief two pixels across (``tests/render/
        test_shadow_maps.py``: one loses a fifth of a rock field's shadows under a 20 degree
        sun, two none).

    Notes
    -----
    These defaults are the only ones: a scenario's ``[render]`` table falls back to them
    (they are the values scenarios have always used; the 3.0 / 1,000,000 this class once
    had applied only to direct library calls).
    """

    shadows: bool = True
    shadow_size: int = 2048
    lod_pixels: float = 1.5
    triangle_budget: int = 3_000_000
    geomorph: bool = True
    antialias: int = 1
    soft_shadows: bool = True
    scattering: bool = True
    earthshine: bool = True
    shadow_detail: float = 2.0

    def __post_init__(self):
        if not 0.25 <= float(self.shadow_detail) <= 8.0:
            raise InvalidParameterError(
                f"shadow_detail must lie in [0.25, 8] texels per pixel; got {self.shadow_detail}")
        a = self.antialias
        if isinstance(a, bool) or not isinstance(a, (int, np.integer)) \
                or not 1 <= a <= MAX_ANTIALIAS or a % 2 == 0:
            raise InvalidParameterError(
                f"antialias must be an odd number of samples per pixel side in [1, "
                f"{MAX_ANTIALIAS}]; got {a!r}")
        if not 64 <= int(self.shadow_size) <= 8192:
            raise InvalidParameterError(
                f"shadow map size must lie in [64, 8192]; got {self.shadow_size}")
        if not self.lod_pixels > 0:
            raise InvalidParameterError(f"lod_pixels must be positive; got {self.lod_pixels}")
        if int(self.triangle_budget) < 1000:
            raise InvalidParameterError(
                f"triangle budget must be at least 1000; got {self.triangle_budget}")


@dataclass(eq=False)
class Frame:
    """What one frame produced (images top row first).

    Parameters
    ----------
    radiance : (h, w) float32
        Reflectance factor I/F under a unit sun.
    range : (h, w) float32, metres
        Distance along each pixel's ray from the camera centre; NaN where nothing was hit.
    normals : (h, w, 3) float32
        World-frame unit surface normals; NaN where nothing was hit.
    drawn : dict
        What the scene drew (levels of detail, triangles, imposter state).
    body_ids : (h, w) uint8, optional
        Which body each pixel shows (0 sky) in a scene of several bodies
        (:meth:`render.binary_scene.BinaryScene.body_ids`); None for a single body or terrain.
    """

    radiance: np.ndarray
    range: np.ndarray
    normals: np.ndarray
    drawn: dict = field(default_factory=dict)
    body_ids: np.ndarray | None = None


def clip_from_camera(intrinsics: Intrinsics, near: float, far: float) -> np.ndarray:
    """Give the clip-space matrix acting on OpenCV camera coordinates (X, Y, Z, 1).

    Pixel (u, v) with v counted from the top maps to the centre of framebuffer texel
    (u, h - 1 - v): ``x_ndc = (2u + 1) / w - 1``, ``y_ndc = 1 - (2v + 1) / h``. Reversed Z
    with an infinite far plane: clip z is ``near``, so ``z_ndc = near / Z``, 1 at the near
    plane and falling towards 0 with distance (drawn with clip z in [0, 1], a depth test
    "greater" and a float depth buffer cleared to 0, see :class:`Renderer`); only the near
    plane clips, so no far plane can cut distant geometry through float32 rounding (a finite
    far plane with a near plane of 1 cm loses whole bodies at 100 km that way).

    Parameters
    ----------
    intrinsics : render.camera.Intrinsics
        Image size and pinhole.
    near : float
        Near clip distance, metres.
    far : float
        Accepted for symmetry and unused.

    Returns
    -------
    (4, 4) float64
        Clip from camera coordinates.
    """
    k = intrinsics
    w, h = k.width, k.height
    m = np.zeros((4, 4))
    m[0, 0] = 2.0 * k.fx / w
    m[0, 2] = (2.0 * k.cx + 1.0) / w - 1.0
    m[1, 1] = -2.0 * k.fy / h
    m[1, 2] = 1.0 - (2.0 * k.cy + 1.0) / h
    m[2, 3] = near
    m[3, 2] = 1.0
    return m


def _shader(name: str, defines: dict[str, int] | None = None) -> str:
    """Read a shader, with ``#define NAME value`` lines after its ``#version`` line."""
    text = resources.files("render").joinpath(f"shaders/{name}").read_text(encoding="utf-8")
    if not defines:
        return text
    version, _, rest = text.partition("\n")
    lines = [f"#define {k} {int(v)}" for k, v in sorted(defines.items())]
    return "\n".join([version, "#define SPECIALISED 1", *lines, rest])


#: The compile-time switches of the surface pass's programs (``shaders/scene.vert`` and
#: ``shaders/scene.frag``).
SWITCHES = ("VERTEX_ALBEDO", "VERTEX_SCATTER", "DISCARD", "NORMAL_MAP", "NORMAL_CUBE", "MORPH")
#: The compile-time switches of the shading pass's programs (``shaders/shade.frag``).
SHADE_SWITCHES = ("BRDF", "VERTEX_ALBEDO", "VERTEX_SCATTER", "ALBEDO_MAP", "SCATTER_MAP",
                  "SHADOWS", "SOFT_SHADOWS", "SCATTERING", "EARTHSHINE")

# GL enums glClipControl and a float depth renderbuffer need (moderngl wraps neither)
_GL_LOWER_LEFT, _GL_NEGATIVE_ONE_TO_ONE, _GL_ZERO_TO_ONE = 0x8CA1, 0x935E, 0x935F
_GL_RENDERBUFFER, _GL_DEPTH32F_STENCIL8 = 0x8D41, 0x8CAD
# ... and the stencil test that selects each shading pass's pixels
_GL_FRAMEBUFFER, _GL_STENCIL_ATTACHMENT, _GL_DEPTH_STENCIL_ATTACHMENT = 0x8D40, 0x8D20, 0x821A
_GL_STENCIL_TEST, _GL_STENCIL_BUFFER_BIT = 0x0B90, 0x0400
_GL_ALWAYS, _GL_EQUAL, _GL_KEEP, _GL_REPLACE = 0x0207, 0x0202, 0x1E00, 0x1E01
#: Groups of batches a frame can shade (the stencil's 8 bits, 0 meaning none).
MAX_GROUPS = 255
#: Texture units the shading pass reads the surface pass's normal, position and per-vertex
#: values from.
_SURFACE_UNITS = (6, 7, 8)


def _gl(name: str, *argtypes: Any) -> Any:
    fn = gl_function(name, *argtypes)
    if fn is None:
        raise RenderUnavailableError(
            f"the OpenGL driver lacks {name} (OpenGL 4.5 or ARB_clip_control is needed)")
    return fn


def _set(prog: Any, name: str, value: Any) -> None:
    """Set a uniform where the program uses it (a specialised one drops unused uniforms)."""
    member = prog.get(name, None)
    if member is not None:
        member.value = value


def _write(prog: Any, name: str, data: bytes) -> None:
    """Write a uniform's bytes where the program uses it."""
    member = prog.get(name, None)
    if member is not None:
        member.write(data)


class MeshArrays:
    """A mesh bound to the programs that draw it: one vertex array per program.

    The renderer draws a mesh with the camera-pass program its batch's switches select (see
    :data:`SWITCHES`), and its depth with one of the shadow pass's two programs (with or
    without a discard rectangle); each program's vertex array is made the first time it is
    asked for.

    Parameters
    ----------
    ctx : moderngl.Context
        The renderer's context.
    content : list of tuple
        The vertex array's content (buffer, format, attribute names).
    ibo : moderngl.Buffer
        The index buffer.
    """

    def __init__(self, ctx: Any, content: list, ibo: Any) -> None:
        self._ctx = ctx
        self._content = content
        self._ibo = ibo
        self._arrays: dict[int, Any] = {}

    def bound(self, program: Any) -> Any:
        """Give the vertex array binding the mesh to ``program`` (made on first use).

        Parameters
        ----------
        program : moderngl.Program
            A camera-pass or shadow-pass program.

        Returns
        -------
        moderngl.VertexArray
            The vertex array.
        """
        key = program.glo
        vao = self._arrays.get(key)
        if vao is None:
            # an attribute a specialised program dropped (in_albedo, in_morph) is skipped
            content = []
            for buffer, fmt, *names in self._content:
                if all(_has(program, n) for n in names):
                    content.append((buffer, fmt, *names))
                else:  # skip the attributes' bytes, keep the others
                    parts = fmt.split()
                    kept = [n for n in names if _has(program, n)]
                    fmt = " ".join(p if _has(program, n) else _skip(p)
                                   for p, n in zip(parts, names, strict=True))
                    if kept:
                        content.append((buffer, fmt, *kept))
            vao = self._ctx.vertex_array(program, content, self._ibo)
            self._arrays[key] = vao
        return vao

    def release(self) -> None:
        """Release every vertex array (the buffers stay the scene's)."""
        for vao in self._arrays.values():
            vao.release()
        self._arrays.clear()


def _has(program: Any, name: str) -> bool:
    return program.get(name, None) is not None


def _skip(fmt: str) -> str:
    """Turn one attribute's moderngl format (``"3f"``) into padding of its bytes (``"12x"``)."""
    count = int(fmt[:-1] or 1)
    return f"{4 * count}x"


class SceneGpu:
    """The handle to the GPU a renderer passes its scenes (:class:`render.scene.Gpu`).

    Buffers and textures are uploaded here (the scene owns them); vertex arrays bind the
    renderer's programs; shadow maps are allocated and their depth drawn here. Nothing
    else: the context itself and camera passes stay the renderer's.

    Parameters
    ----------
    ctx : moderngl.Context
        The renderer's context.
    scene_program, depth_program, plain_depth_program : moderngl.Program
        The camera pass's program, and the shadow pass's with a discard rectangle and
        without one.
    """

    def __init__(self, ctx: Any, scene_program: Any, depth_program: Any,
                 plain_depth_program: Any) -> None:
        self._ctx = ctx
        # Scenes cache vertex arrays per renderer (they bind this renderer's programs). A
        # never-reused token, not id(self): a new renderer can get a dead one's id.
        self.token = next(_TOKENS)
        self._scene_program = scene_program
        self._depth_program = depth_program
        self._plain_depth_program = plain_depth_program

    @property
    def context(self) -> object:
        """The context uploads go to, as an opaque key (scenes cache uploads under it)."""
        return self._ctx

    def buffer(self, data: bytes) -> Any:
        """Upload a vertex, index or attribute buffer (the scene owns it).

        Parameters
        ----------
        data : bytes
            Its contents.

        Returns
        -------
        moderngl.Buffer
            The buffer.
        """
        return self._ctx.buffer(data)

    def texture(self, size: tuple[int, int], components: int, data: bytes,
                dtype: str) -> Any:
        """Upload a 2-D texture, sampled bilinearly and clamped at its edges (the scene owns it).

        Parameters
        ----------
        size : (int, int)
            Width and height, texels.
        components : int
            Values per texel (1 to 4).
        data : bytes
            Rows from the texture's first (v = 0) row.
        dtype : str
            moderngl's texel type, e.g. ``"f2"`` or ``"f4"``.

        Returns
        -------
        moderngl.Texture
            The texture.
        """
        import moderngl

        tex = self._ctx.texture(size, components, data, dtype=dtype)
        tex.filter = (moderngl.LINEAR, moderngl.LINEAR)
        tex.repeat_x = False
        tex.repeat_y = False
        return tex

    def texture_cube(self, size: tuple[int, int], components: int, data: bytes,
                     dtype: str) -> Any:
        """Upload a cube map, sampled bilinearly (the scene owns it).

        Parameters
        ----------
        size : (int, int)
            Side of each face, texels.
        components : int
            Values per texel (1 to 4).
        data : bytes
            The faces +X, -X, +Y, -Y, +Z, -Z in GL's order.
        dtype : str
            moderngl's texel type, e.g. ``"f2"``.

        Returns
        -------
        moderngl.TextureCube
            The cube map.
        """
        import moderngl

        tex = self._ctx.texture_cube(size, components, data, dtype=dtype)
        tex.filter = (moderngl.LINEAR, moderngl.LINEAR)
        return tex

    def vertex_arrays(self, vbo: Any, ibo: Any, albedo: Any = None,
                      morph: Any = None, scatter: Any = None) -> tuple[Any, Any]:
        """Bind a mesh's buffers to the renderer's camera and depth programs.

        ``vbo`` interleaves position and normal (3f 3f); the depth pass reads positions only.
        Scenes cache the pair under :attr:`token`.

        Parameters
        ----------
        vbo, ibo : moderngl.Buffer
            Interleaved position and normal (3f 3f, scene-local metres) and uint32 indices.
        albedo : moderngl.Buffer, optional
            One float32 albedo factor per vertex (draw such a mesh with
            ``DrawBatch.vertex_albedo`` set).
        morph : moderngl.Buffer, optional
            Per-vertex geomorphing targets (4f 3f: the coarser level's position, a key, the
            coarser level's normal; see :class:`render.scene.Morph` and
            ``shaders/scene.vert``).
        scatter : moderngl.Buffer, optional
            One float32 scattered irradiance (over the solar irradiance) per vertex
            (:mod:`render.body_scattering`; draw such a mesh with ``DrawBatch.vertex_scatter``
            set).

        Returns
        -------
        tuple
            ``(MeshArrays, MeshArrays)``: the camera pass's vertex arrays (one per
            specialised program, made as the renderer asks) and the depth pass's.
        """
        content: list[tuple[Any, ...]] = [(vbo, "3f 3f", "in_position", "in_normal")]
        if albedo is not None:
            content.append((albedo, "1f", "in_albedo"))
        if morph is not None:
            content.append((morph, "4f 3f", "in_morph", "in_morph_normal"))
        if scatter is not None:
            content.append((scatter, "1f", "in_scatter"))
        vao = MeshArrays(self._ctx, content, ibo)
        dvao = MeshArrays(self._ctx, [(vbo, "3f 12x", "in_position")], ibo)
        return vao, dvao

    def shadow_target(self, size: tuple[int, int]) -> tuple[Any, Any]:
        """Allocate a depth texture and framebuffer for one shadow map (caller owns them).

        Parameters
        ----------
        size : (int, int)
            Width and height of the map, texels.

        Returns
        -------
        tuple
            ``(moderngl.Texture, moderngl.Framebuffer)``: a depth texture that compares
            ``<=`` with 2x2 percentage-closer filtering, clamped at its edges.
        """
        import moderngl

        tex = self._ctx.depth_texture((int(size[0]), int(size[1])))
        tex.compare_func = "<="
        tex.filter = (moderngl.LINEAR, moderngl.LINEAR)  # 2x2 percentage-closer filtering
        tex.repeat_x = False
        tex.repeat_y = False
        fbo = self._ctx.framebuffer(depth_attachment=tex)
        return tex, fbo

    def draw_depth(self, framebuffer: Any, size: tuple[int, int], light_clip: np.ndarray,
                   batches: Sequence[DrawBatch]) -> None:
        """Draw the depth of ``batches`` into a shadow map with the orthographic ``light_clip``.

        Parameters
        ----------
        framebuffer : moderngl.Framebuffer
            The map's framebuffer (:meth:`shadow_target`).
        size : (int, int)
            Width and height of the map, texels.
        light_clip : (4, 4) float64
            Clip-from-scene-local matrix of the sun's orthographic view.
        batches : sequence of DrawBatch
            What casts shadows (their ``depth_vao``, ``ranges``, model transforms and
            discard rectangles).
        """
        import moderngl

        ctx = self._ctx
        framebuffer.use()
        ctx.viewport = (0, 0, int(size[0]), int(size[1]))
        ctx.enable(moderngl.DEPTH_TEST)
        ctx.disable(moderngl.CULL_FACE)
        ctx.depth_func = "<"
        framebuffer.clear(depth=1.0)
        clip = light_clip.T.astype("f4").tobytes()
        for prog in (self._depth_program, self._plain_depth_program):
            prog["u_clip_from_world"].write(clip)
        for batch in batches:
            # a batch without a discard rectangle is drawn with no fragment shader at all:
            # llvmpipe then writes depth straight from the rasteriser (a shader that may
            # discard costs every fragment, even when its branch is not taken)
            prog = self._depth_program if batch.discard is not None else self._plain_depth_program
            prog["u_world_from_model"].write(
                np.asarray(batch.world_from_model, dtype="f4").T.tobytes())
            prog["u_model_offset"].value = tuple(np.asarray(batch.model_offset).tolist())
            if batch.discard is not None:
                prog["u_discard"].value = tuple(batch.discard)
            vao = batch.depth_vao.bound(prog)
            for first, count in batch.ranges:
                vao.render(moderngl.TRIANGLES, vertices=count, first=first)


class _Stencil:
    """The stencil test, which moderngl does not wrap.

    The surface pass writes each pixel's group; each shading pass draws where it holds its
    own.
    """

    def __init__(self) -> None:
        u, i = ctypes.c_uint, ctypes.c_int
        self._enable, self._disable = _gl("glEnable", u), _gl("glDisable", u)
        self._func, self._op = _gl("glStencilFunc", u, i, u), _gl("glStencilOp", u, u, u)
        self._mask = _gl("glStencilMask", u)
        self._clear_value, self._clear = _gl("glClearStencil", i), _gl("glClear", u)

    def clear(self) -> None:
        """Set the bound framebuffer's stencil to 0 (no group) within the scissor."""
        self._mask(0xFF)
        self._clear_value(0)
        self._clear(_GL_STENCIL_BUFFER_BIT)

    def write(self, group: int) -> None:
        """Write ``group`` where a fragment passes the depth test."""
        self._enable(_GL_STENCIL_TEST)
        self._mask(0xFF)
        self._func(_GL_ALWAYS, group, 0xFF)
        self._op(_GL_KEEP, _GL_KEEP, _GL_REPLACE)

    def select(self, group: int) -> None:
        """Draw only where the stencil holds ``group``, leaving it as it is."""
        self._enable(_GL_STENCIL_TEST)
        self._mask(0)
        self._func(_GL_EQUAL, group, 0xFF)
        self._op(_GL_KEEP, _GL_KEEP, _GL_KEEP)

    def off(self) -> None:
        """Back to GL's defaults."""
        self._disable(_GL_STENCIL_TEST)
        self._mask(0xFF)
        self._func(_GL_ALWAYS, 0, 0xFF)
        self._op(_GL_KEEP, _GL_KEEP, _GL_KEEP)


@dataclass(eq=False)
class _Target:
    """The offscreen framebuffers of one image size.

    ``surface`` (normal, position; the depth and stencil buffer) is what the surface pass
    draws into (``surface_vertex`` also the per-vertex values, made on first use),
    ``shade`` (radiance, range) the shading pass, and ``frame`` (radiance, range, normal) is read
    back; ``inputs`` are the surface pass's images the shading pass reads.
    """

    frame: Any
    surface: Any
    shade: Any
    inputs: list
    owned: list
    surface_vertex: Any = None

    def release(self) -> None:
        fbos = (self.frame, self.surface, self.shade, self.surface_vertex)
        for obj in (*(f for f in fbos if f is not None), *self.owned):
            obj.release()


class Renderer:
    """Holds the GL programs and offscreen framebuffers; renders scenes frame by frame.

    Parameters
    ----------
    ctx : moderngl.Context, optional
        The context to render with (default: a new headless one,
        :func:`render.context.create_context`).
    """

    def __init__(self, ctx: Any = None) -> None:
        import moderngl

        self.ctx = ctx or create_context()
        #: The generic camera-pass program (every switch a uniform); frames are drawn with
        #: the specialised ones (:meth:`program`).
        self.scene_program = self.ctx.program(vertex_shader=_shader("scene.vert"),
                                              fragment_shader=_shader("scene.frag"))
        self._programs: dict[tuple, Any] = {}
        self._shade_programs: dict[tuple, tuple[Any, Any]] = {}
        self._resolve_program: Any = None
        self._resolve_vao: Any = None
        self._resolve: dict = {}
        self._clip_control = _gl("glClipControl", ctypes.c_uint, ctypes.c_uint)
        self._stencil = _Stencil()
        self.depth_program = self.ctx.program(
            vertex_shader=_shader("depth.vert"),
            fragment_shader=_shader("depth.frag", {"DISCARD_RECT": 1}))
        #: The shadow pass's program for batches without a discard rectangle.
        self.plain_depth_program = self.ctx.program(vertex_shader=_shader("depth.vert"),
                                                    fragment_shader=_shader("depth.frag"))
        #: The handle scenes get: uploads, vertex arrays and shadow maps, no camera pass.
        self.gpu = SceneGpu(self.ctx, self.scene_program, self.depth_program,
                            self.plain_depth_program)
        self._fbos: dict = {}
        self._dummy_shadow = self.ctx.depth_texture((1, 1))
        self._dummy_shadow.compare_func = "<="
        # the raw depths of the bound shadow map (blocker search): a sampler on its own unit
        self._depth_sampler = self.ctx.sampler(
            filter=(moderngl.NEAREST, moderngl.NEAREST), compare_func="", repeat_x=False,
            repeat_y=False, texture=self._dummy_shadow)
        self._dummy_scatter = self.ctx.texture((1, 1), 2, np.array([0, 1], "f4").tobytes(),
                                               dtype="f4")
        self._dummy_albedo = self.ctx.texture((1, 1), 1, np.ones(1, "f4").tobytes(), dtype="f4")
        self._dummy_normals = self.ctx.texture((1, 1), 3, np.array([0, 0, 1], "f2").tobytes(),
                                               dtype="f2")
        self._dummy_cube = self.ctx.texture_cube((1, 1), 3, np.tile(np.array([0, 0, 1], "f2"),
                                                                     6).tobytes(), dtype="f2")

    def program(self, switches: dict[str, int]) -> Any:
        """Give the surface-pass program specialised for ``switches`` (compiled once).

        Parameters
        ----------
        switches : dict
            A value, 0 or 1, for each of :data:`SWITCHES`.

        Returns
        -------
        moderngl.Program
            The program.
        """
        key = tuple(int(switches[name]) for name in SWITCHES)
        prog = self._programs.get(key)
        if prog is None:
            defines = dict(zip(SWITCHES, key, strict=True))
            prog = self.ctx.program(vertex_shader=_shader("scene.vert", defines),
                                    fragment_shader=_shader("scene.frag", defines))
            self._programs[key] = prog
        return prog

    def shade_program(self, switches: dict[str, int]) -> tuple[Any, Any]:
        """Give the shading-pass program specialised for ``switches`` (compiled once).

        Parameters
        ----------
        switches : dict
            A value for each of :data:`SHADE_SWITCHES` (the reflectance law's code for
            ``BRDF``, 0 or 1 for the others).

        Returns
        -------
        tuple
            ``(moderngl.Program, moderngl.VertexArray)``: the program and the vertex array
            of its full-screen triangle.
        """
        key = tuple(int(switches[name]) for name in SHADE_SWITCHES)
        shade = self._shade_programs.get(key)
        if shade is None:
            defines = dict(zip(SHADE_SWITCHES, key, strict=True))
            prog = self.ctx.program(vertex_shader=_shader("fullscreen.vert"),
                                    fragment_shader=_shader("shade.frag", defines))
            for name, unit in zip(("u_surface_normal", "u_surface_rel", "u_surface_vertex"),
                                  _SURFACE_UNITS, strict=True):
                _set(prog, name, unit)
            for name, unit in (("u_shadow_map", 0), ("u_albedo_map", 1), ("u_shadow_depth", 4),
                               ("u_scatter", 5)):
                _set(prog, name, unit)
            shade = self._shade_programs[key] = (prog, self.ctx.vertex_array(prog, []))
        return shade

    # ------------------------------------------------------------------ framebuffers
    def _target(self, size: tuple[int, ...]) -> _Target:
        """Return the offscreen framebuffers for an image size.

        Kept per size (an imposter renders a small image just before a full-size frame), at
        most :data:`MAX_TARGETS` sizes, the oldest dropped first.
        """
        size = tuple(size)
        if size not in self._fbos:
            if len(self._fbos) >= MAX_TARGETS:  # drop the oldest size
                old = next(iter(self._fbos))
                self._fbos.pop(old).release()
            ctx = self.ctx
            radiance, range_ = (ctx.texture(size, 1, dtype="f4") for _ in range(2))
            normal, rel = (ctx.texture(size, 4, dtype="f4") for _ in range(2))
            depth = ctx.depth_renderbuffer(size)
            # reversed Z needs a float depth buffer (moderngl makes 24-bit fixed point)
            _gl("glBindRenderbuffer", ctypes.c_uint, ctypes.c_uint)(_GL_RENDERBUFFER, depth.glo)
            # (and a stencil, the group of each pixel: moderngl makes neither)
            _gl("glRenderbufferStorage", ctypes.c_uint, ctypes.c_uint, ctypes.c_int,
                ctypes.c_int)(_GL_RENDERBUFFER, _GL_DEPTH32F_STENCIL8, size[0], size[1])
            _gl("glBindRenderbuffer", ctypes.c_uint, ctypes.c_uint)(_GL_RENDERBUFFER, 0)
            surface = ctx.framebuffer(color_attachments=[normal, rel],
                                      depth_attachment=depth)
            shade = ctx.framebuffer(color_attachments=[radiance, range_])
            self._attach_stencil(surface, _GL_STENCIL_ATTACHMENT, depth)
            self._attach_stencil(shade, _GL_DEPTH_STENCIL_ATTACHMENT, depth)
            self._fbos[size] = _Target(
                ctx.framebuffer(color_attachments=[radiance, range_, normal]), surface, shade,
                [normal, rel], [radiance, range_, normal, rel, depth])
        return self._fbos[size]

    def _attach_stencil(self, fbo: Any, point: int, depth: Any) -> None:
        fbo.use()
        _gl("glFramebufferRenderbuffer", ctypes.c_uint, ctypes.c_uint, ctypes.c_uint,
            ctypes.c_uint)(_GL_FRAMEBUFFER, point, _GL_RENDERBUFFER, depth.glo)

    def _vertex_target(self, target: _Target) -> Any:
        """Give the surface pass's framebuffer with the per-vertex values' attachment too.

        Made when a frame of that size first draws a batch that carries them (bodies), so
        that frames without any (terrain) allocate none.
        """
        if target.surface_vertex is None:
            ctx = self.ctx
            size = target.frame.size
            vertex = ctx.texture(size, 2, dtype="f4")
            normal = target.frame.color_attachments[2]
            depth = target.surface.depth_attachment
            fbo = ctx.framebuffer(color_attachments=[normal, target.inputs[1], vertex],
                                  depth_attachment=depth)
            self._attach_stencil(fbo, _GL_STENCIL_ATTACHMENT, depth)
            target.surface_vertex = fbo
            target.inputs.append(vertex)
            target.owned.append(vertex)
        return target.surface_vertex

    # ------------------------------------------------------------------ passes
    def render(self, scene: Scene, view: View, lighting: Lighting,
               options: RenderOptions | None = None, *,
               rows: tuple[int, int] | None = None) -> Frame:
        """Render one frame of ``scene`` (see :mod:`render.scene`).

        The pose is in the world frame; the scene's ``origin`` (world) is subtracted in float64
        before anything reaches the GPU. Imposter first: when the scene asks for an imposter
        (:meth:`render.scene.Scene.imposter`), its small view is rendered as geometry, the
        frame is planned with the request, and the imposter is composited into the read-back
        images (:mod:`render.imposter`).

        Parameters
        ----------
        scene : render.scene.Scene
            What to draw.
        view : View
            The camera: world-frame pose, intrinsics and time.
        lighting : Lighting
            The sun and the surface's reflectance.
        options : RenderOptions, optional
            Quality settings (default: :class:`RenderOptions`' defaults).
        rows : (int, int), optional
            ``(top, bottom)``: shade only image rows ``top <= row < bottom`` (a scissor; a
            rolling shutter's sub-frames need no more); the rest of the images is left
            undefined.

        Returns
        -------
        Frame
            Radiance, range and normals, ``(height, width)`` images, top row first.
        """
        options = options or RenderOptions()
        imposter = scene.imposter(view, options)
        if imposter is None:
            return self._render(scene, view, lighting, options, None, rows)
        sub_view = View(imposter.pose, imposter.intrinsics, view.time)
        sub = self._render(scene, sub_view, lighting,
                           replace(options, lod_pixels=imposter.lod_pixels), None,
                           None)
        frame = self._render(scene, view, lighting, options, imposter, rows)
        if imposter.blend is None:
            composite(view, frame.radiance, frame.range, frame.normals, sub, imposter.pose,
                      imposter.intrinsics)
            # the frame shows what the imposter drew, with the scene's own facts on top
            frame.drawn = dict(sub.drawn, **frame.drawn)
        else:
            blend(view, frame.radiance, frame.range, frame.normals, sub, imposter.pose,
                  imposter.intrinsics, imposter.blend)
        return frame

    def _render(self, scene: Scene, view: View, lighting: Lighting, options: RenderOptions,
                imposter: Imposter | None, rows: tuple[int, int] | None) -> Frame:
        """One camera pass of the scene's plan for ``view`` (see :meth:`render`)."""
        import moderngl

        k = view.intrinsics
        ctx = self.ctx
        state = scene.frame_state(view, lighting, options, self.gpu, imposter)
        origin = np.asarray(scene.origin, dtype=np.float64)
        cam = np.asarray(view.pose.position, dtype=np.float64) - origin  # scene-local
        r_cw = view.pose.rotation.T
        cam_rel = np.eye(4)
        cam_rel[:3, :3] = r_cw
        # antialiasing: the batches are drawn at a = antialias samples per pixel side,
        # through intrinsics whose sample a u + (a - 1) / 2 is pixel u's centre
        a = int(options.antialias)
        ka = k if a == 1 else Intrinsics(k.width * a, k.height * a, k.fx * a, k.fy * a,
                                         a * (k.cx + 0.5) - 0.5, a * (k.cy + 0.5) - 0.5)
        clip = clip_from_camera(ka, NEAR_M, state.far) @ cam_rel
        hp = lighting.hapke
        sun_tan = math.tan(lighting.sun_angular_radius) if options.soft_shadows else 0.0
        earth = lighting.earth if options.earthshine and lighting.earthshine > 0 else None
        frame_uniforms: dict[str, Any] = {
            "u_camera": tuple(cam.tolist()), "u_sun": tuple(lighting.sun),
            "u_albedo": lighting.albedo, "u_mcewen": tuple(lighting.mcewen),
            "u_hapke_a": (hp.w, hp.b, hp.c, hp.bs0),
            "u_hapke_b": (hp.hs, hp.bc0, hp.hc, math.radians(hp.theta_bar)),
            "u_hapke_k": hp.porosity_k, "u_shadow_map": 0, "u_shadow_depth": 4,
            "u_scatter": 5, "u_albedo_map": 1, "u_normals": 2, "u_normal_cube_map": 3,
            "u_sun_tan": sun_tan,
            "u_earth": tuple(earth) if earth is not None else (0.0, 0.0, 1.0),
            "u_earthshine": lighting.earthshine if earth is not None else 0.0}
        if state.albedo is not None:
            frame_uniforms["u_albedo_window"] = tuple(float(v) for v in state.albedo[1])
        clip_bytes = clip.T.astype("f4").tobytes()
        shade_switches = dict(
            BRDF=BRDF_CODES[lighting.brdf], ALBEDO_MAP=state.albedo is not None,
            SOFT_SHADOWS=sun_tan > 0, SCATTERING=bool(options.scattering),
            EARTHSHINE=earth is not None)
        self._set_albedo_map(state.albedo)
        shadows = options.shadows and lighting is not None

        target = self._target((ka.width, ka.height))
        surface = target.surface
        if any(b.vertex_albedo or b.vertex_scatter for b in state.batches):
            surface = self._vertex_target(target)
        scissor = None
        if rows is not None:
            top, bottom = (int(r) * a for r in rows)
            scissor = (0, ka.height - bottom, ka.width, bottom - top)
        for fbo in (surface, target.shade):
            fbo.viewport = (0, 0, ka.width, ka.height)
            fbo.scissor = scissor
        self._clip_control(_GL_LOWER_LEFT, _GL_ZERO_TO_ONE)
        try:
            # the surface pass: every batch, each pixel keeping its nearest fragment's
            # surface; a group is the batches one shading pass shades (one shadow map, one
            # scattered light map, the same per-vertex values)
            surface.use()
            ctx.enable(moderngl.DEPTH_TEST)
            ctx.disable(moderngl.CULL_FACE)
            ctx.depth_func = ">"  # reversed Z: nearer is greater
            surface.clear(color=(0.0, 0.0, 0.0, 0.0), depth=0.0)
            self._stencil.clear()
            groups: dict[tuple, tuple[int, Any, Any, dict]] = {}
            ready: set[int] = set()  # programs whose frame uniforms are set
            for batch in state.batches:
                shadow = batch.shadow if shadows else None
                scatter = batch.scatter
                vertex = dict(VERTEX_ALBEDO=bool(batch.vertex_albedo),
                              VERTEX_SCATTER=bool(batch.vertex_scatter))
                key = (id(shadow), None if scatter is None else (id(scatter[0]),
                                                                 tuple(scatter[1])),
                       *vertex.values())
                group = groups.setdefault(key, (len(groups) + 1, shadow, scatter, vertex))[0]
                if group > MAX_GROUPS:
                    raise RuntimeError(f"a frame shades at most {MAX_GROUPS} groups of "
                                       f"batches (one per shadow map); this one has more")
                prog = self.program(dict(
                    vertex, DISCARD=batch.discard is not None,
                    NORMAL_MAP=batch.normal_map is not None,
                    NORMAL_CUBE=batch.normal_cube is not None, MORPH=batch.morph is not None))
                if prog.glo not in ready:
                    ready.add(prog.glo)
                    _write(prog, "u_clip_from_camera_rel", clip_bytes)
                    for name, value in frame_uniforms.items():
                        _set(prog, name, value)
                self._stencil.write(group)
                self._set_batch(prog, batch, cam)
                vao = batch.vao.bound(prog)
                for first, count in batch.ranges:
                    vao.render(moderngl.TRIANGLES, vertices=count, first=first)
            # the shading pass: each group's pixels once (shaders/shade.frag)
            ctx.disable(moderngl.DEPTH_TEST)
            target.shade.use()
            target.shade.clear(color=(0.0, 0.0, 0.0, 0.0))
            # (the per-vertex values' unit stays unbound where no batch of any frame had them)
            for unit, texture in zip(_SURFACE_UNITS, target.inputs, strict=False):
                texture.use(location=unit)
            for group, shadow, scatter, vertex in groups.values():
                prog, triangle = self.shade_program(dict(
                    shade_switches, **vertex, SHADOWS=shadow is not None,
                    SCATTER_MAP=scatter is not None))
                if prog.glo not in ready:
                    ready.add(prog.glo)
                    for name, value in frame_uniforms.items():
                        _set(prog, name, value)
                self._stencil.select(group)
                self._set_shadow(prog, shadow, cam)
                if scatter is not None:
                    scatter[0].use(location=5)
                    _set(prog, "u_scatter_rect", tuple(float(v) for v in scatter[1]))
                else:
                    self._dummy_scatter.use(location=5)
                triangle.render(moderngl.TRIANGLES, vertices=3)
        finally:
            self._clip_control(_GL_LOWER_LEFT, _GL_NEGATIVE_ONE_TO_ONE)
            self._stencil.off()
            surface.scissor = None
            target.shade.scissor = None
            ctx.depth_func = "<"
        err = ctx.error
        if err != "GL_NO_ERROR":
            raise RuntimeError(f"OpenGL error while rendering: {err}")
        w, h = ka.width, ka.height
        fbo = target.frame
        if a == 1:
            rad, range_m, normals = read_frame(fbo, (w, h))
        else:  # radiance: the mean of each pixel's samples; range, normals: its centre's
            samples = np.frombuffer(fbo.read(attachment=0, components=1, dtype="f4"),
                                    dtype=np.float32).reshape(h, w)[::-1].copy()
            rad = samples.reshape(k.height, a, k.width, a).mean(axis=(1, 3), dtype=np.float64) \
                .astype(np.float32)
            fbo = self._centre_samples(fbo, (k.width, k.height), a)
            _, range_m, normals = read_frame(fbo, (k.width, k.height), with_radiance=False)
        return Frame(rad, range_m, normals, dict(state.drawn))

    def _centre_samples(self, fbo: Any, size: tuple[int, int], a: int) -> Any:
        """Copy each pixel's centre sample of an antialiased frame's range and normals.

        Done on the GPU, so that only a pixel's one sample of them is read back (sample
        ``a x + (a - 1) / 2`` of pixel x, the same in rows: ``a`` is odd).

        Returns
        -------
        moderngl.Framebuffer
            A ``size`` framebuffer whose attachments 1 and 2 hold them.
        """
        import moderngl

        ctx = self.ctx
        if self._resolve_program is None:
            self._resolve_program = ctx.program(vertex_shader=_shader("fullscreen.vert"),
                                                fragment_shader=_shader("centre.frag"))
            self._resolve_vao = ctx.vertex_array(self._resolve_program, [])
        target = self._resolve.get(size)
        if target is None:
            for old in self._resolve.values():  # one size at a time
                for tex in old.color_attachments:
                    tex.release()
                old.release()
            self._resolve.clear()
            # attachment 0 is unused: the attachments keep the camera pass's numbering
            color = [ctx.texture(size, 1, dtype="f4"), ctx.texture(size, 1, dtype="f4"),
                     ctx.texture(size, 4, dtype="f4")]
            target = self._resolve[size] = ctx.framebuffer(color_attachments=color)
        prog = self._resolve_program
        prog["u_factor"].value = a
        prog["u_range"].value = 6
        prog["u_normal"].value = 7
        fbo.color_attachments[1].use(location=6)
        fbo.color_attachments[2].use(location=7)
        target.use()
        ctx.viewport = (0, 0, size[0], size[1])
        ctx.disable(moderngl.DEPTH_TEST)
        self._resolve_vao.render(moderngl.TRIANGLES, vertices=3)
        return target

    def _set_albedo_map(self, albedo):
        """Bind a scene's albedo map ((texture, (xmin, ymin, xmax, ymax) scene-local)) or none."""
        if albedo is None:
            self._dummy_albedo.use(location=1)
        else:
            albedo[0].use(location=1)

    def _set_batch(self, prog, batch, cam):
        """Set a batch's uniforms and textures in a surface-pass program."""
        _write(prog, "u_world_from_model",
               np.asarray(batch.world_from_model, dtype="f4").T.tobytes())
        _set(prog, "u_model_offset", tuple((np.asarray(batch.model_offset) - cam).tolist()))
        if batch.discard is not None:
            _set(prog, "u_discard", tuple(batch.discard))
        morph = batch.morph
        if morph is not None:
            _set(prog, "u_morph", int(morph.mode))
            _set(prog, "u_morph_level", float(morph.level))
            _set(prog, "u_morph_k", float(morph.k))
            _set(prog, "u_morph_band", float(morph.band))
            _set(prog, "u_morph_scale", float(morph.scale))
            _set(prog, "u_morph_top", float(morph.top))
            _set(prog, "u_bias_per_level", float(morph.bias_per_level))
        if batch.normal_map is not None:  # its own unit, never the shadow map's
            texture, rect = batch.normal_map
            texture.use(location=2)
            _set(prog, "u_normal_rect", tuple(float(v) for v in rect))
        else:
            self._dummy_normals.use(location=2)
        if batch.normal_cube is not None:
            batch.normal_cube.use(location=3)
        else:
            self._dummy_cube.use(location=3)

    def _set_shadow(self, prog, shadow, cam):
        """Bind a group's shadow map (or none) and set its uniforms in a shading program."""
        if shadow is not None:
            shadow.texture.use(location=0)
            light = shadow.light_from_world @ _translation(cam)
            _write(prog, "u_light_from_world", light.T.astype("f4").tobytes())
            _set(prog, "u_normal_offset", shadow.normal_offset)
            _set(prog, "u_bias", shadow.bias)
            _set(prog, "u_slope_texels", shadow.slope_texels)
            _set(prog, "u_texel", tuple(float(t) for t in shadow.texel_xy))
            _set(prog, "u_shadow_extent", (shadow.texel_xy[0] * shadow.shape[0],
                                           shadow.texel_xy[1] * shadow.shape[1]))
            _set(prog, "u_depth_range", shadow.depth_range_m)
            _write(prog, "u_light_axes", np.asarray(shadow.axes, "f4").T.tobytes())
            self._depth_sampler.texture = shadow.texture
        else:
            self._dummy_shadow.use(location=0)
            self._depth_sampler.texture = self._dummy_shadow
        self._depth_sampler.use(location=4)


def _translation(t) -> np.ndarray:
    m = np.eye(4)
    m[:3, 3] = t
    return m
