"""The one place that creates OpenGL contexts: headless moderngl on EGL.

On a machine without a GPU, Mesa's llvmpipe rasterises on the CPU (GL 4.5 core, bit-identical
images run to run, so golden images work); where a GPU and its EGL driver exist, the same code
runs there. If EGL or the Mesa driver is missing, :func:`create_context` raises
:class:`~render.errors.RenderUnavailableError` with one line naming the packages to install.

Which device: EGL lists the devices its drivers offer (``eglQueryDevicesEXT``; libglvnd asks
every vendor's driver, e.g. NVIDIA's and Mesa's). :func:`choose_device` takes the first
hardware device, one whose extensions do not include ``EGL_MESA_device_software``, and else
the software rasteriser; the environment variable :data:`DEVICE_ENV` asks for one by index,
or for ``software`` (``auto`` is the default). A device whose context cannot be made falls
back to the software one, then to EGL's default display, with a warning
(:func:`fallbacks`); no GPU is ever required. The renderer
string of the context (e.g. ``NVIDIA H200/PCIe/SSE2`` or ``llvmpipe (LLVM 15.0.6, 256
bits)``) is logged, and :func:`describe` gives it with the device to run manifests and
benchmark reports. glcontext's own ``GLCONTEXT_DEVICE_INDEX``, where set, still wins.
"""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import functools
import logging
import os
from collections.abc import Iterator, Sequence
from dataclasses import dataclass

from render.errors import RenderUnavailableError

__all__ = ["APT_PACKAGES", "DEVICE_ENV", "EglDevice", "choose_device", "create_context",
           "describe", "egl_devices", "fallbacks", "gl_function", "keep_current"]

log = logging.getLogger(__name__)

#: Debian packages that provide headless OpenGL through EGL (libgl1: glcontext loads libGL
#: even for EGL).
APT_PACKAGES = ("libegl1", "libegl-mesa0", "libgl1", "libgl1-mesa-dri")
#: OpenGL version the shaders need (330 core; llvmpipe gives 4.5).
REQUIRED_VERSION = 330


#: Environment variable choosing the EGL device: ``auto``, ``software`` or an index.
DEVICE_ENV = "CRATERSCAPE_EGL_DEVICE"
#: The extension Mesa's software devices (llvmpipe, softpipe) advertise.
SOFTWARE_EXTENSION = "EGL_MESA_device_software"
#: EGL enums: ``EGL_EXTENSIONS``, ``EGL_DRM_DEVICE_FILE_EXT``, ``EGL_RENDERER_EXT``.
_EGL_EXTENSIONS, _EGL_DRM_DEVICE_FILE, _EGL_RENDERER = 0x3055, 0x3233, 0x335F
#: The device the process's context was made on (``describe``), once made.
_device: dict = {}


@dataclass(frozen=True)
class EglDevice:
    """One EGL device, as ``eglQueryDevicesEXT`` lists it.

    Parameters
    ----------
    index : int
        Its place in EGL's list (glcontext's ``device_index``).
    extensions : tuple of str
        Its device extensions.
    name : str or None
        Its renderer name where the driver gives one (``EGL_EXT_device_query_name``).
    drm : str or None
        Its DRM device file, where it has one.
    """

    index: int
    extensions: tuple[str, ...] = ()
    name: str | None = None
    drm: str | None = None

    @property
    def software(self) -> bool:
        """Whether it rasterises on the CPU (Mesa's llvmpipe or softpipe)."""
        return SOFTWARE_EXTENSION in self.extensions


def choose_device(devices: Sequence[EglDevice], request: str | None = None) -> EglDevice | None:
    """Pick the EGL device to render on.

    Parameters
    ----------
    devices : sequence of EglDevice
        What EGL lists (:func:`egl_devices`), in its order.
    request : str, optional
        ``auto`` (or None or empty): the first hardware device, else the first device;
        ``software``: the first software device; an integer: that device.

    Returns
    -------
    EglDevice or None
        None where EGL lists no device (its default display is then used).

    Raises
    ------
    RenderUnavailableError
        A device was asked for that is not there (the message names :data:`DEVICE_ENV`).

    Examples
    --------
    >>> gpu, cpu = EglDevice(0, ("EGL_EXT_device_drm",)), EglDevice(1, (SOFTWARE_EXTENSION,))
    >>> choose_device([cpu, gpu]).index, choose_device([cpu, gpu], "software").index
    (0, 1)
    """
    want = (request or "auto").strip().lower()
    if want == "auto":
        hardware = [d for d in devices if not d.software]
        ordered = hardware or list(devices)
        return ordered[0] if ordered else None
    if want == "software":
        software = [d for d in devices if d.software]
        if not software:
            raise RenderUnavailableError(
                f"{DEVICE_ENV}=software, but EGL lists no software device "
                f"(of {len(devices)}); install libegl-mesa0 or unset {DEVICE_ENV}")
        return software[0]
    try:
        index = int(want)
    except ValueError:
        raise RenderUnavailableError(
            f"{DEVICE_ENV} must be auto, software or a device index; got {request!r}") from None
    for d in devices:
        if d.index == index:
            return d
    raise RenderUnavailableError(
        f"{DEVICE_ENV}={index}, but EGL lists {len(devices)} device(s) (0 to "
        f"{len(devices) - 1})")


def fallbacks(devices: Sequence[EglDevice],
              chosen: EglDevice | None) -> list[EglDevice | None]:
    """Return the devices to try in turn: the chosen one, the CPU, EGL's default display.

    A GPU is never required, and the result is never worse than asking EGL for its default
    (None stands for EGL's default display).

    Parameters
    ----------
    devices : sequence of EglDevice
        What EGL lists.
    chosen : EglDevice or None
        What :func:`choose_device` chose.

    Returns
    -------
    list of (EglDevice or None)

    Examples
    --------
    >>> gpu, cpu = EglDevice(0, ("EGL_EXT_device_drm",)), EglDevice(1, (SOFTWARE_EXTENSION,))
    >>> [d.index if d else None for d in fallbacks([gpu, cpu], gpu)]
    [0, 1, None]
    """
    attempts: list[EglDevice | None] = [chosen]
    software = next((d for d in devices if d.software), None)
    if chosen is not None and not chosen.software and software is not None:
        attempts.append(software)
    if chosen is not None:
        attempts.append(None)
    return attempts


def egl_devices() -> list[EglDevice]:
    """List the EGL devices of this machine (empty where EGL cannot enumerate them).

    Returns
    -------
    list of EglDevice
        In EGL's order (the ``device_index`` glcontext takes).
    """
    lib = _egl()
    if lib is None:
        return []
    lib.eglGetProcAddress.restype = ctypes.c_void_p
    lib.eglGetProcAddress.argtypes = [ctypes.c_char_p]
    query = lib.eglGetProcAddress(b"eglQueryDevicesEXT")
    string = lib.eglGetProcAddress(b"eglQueryDeviceStringEXT")
    if not query or not string:
        return []
    query_devices = ctypes.CFUNCTYPE(ctypes.c_uint, ctypes.c_int32,
                                     ctypes.POINTER(ctypes.c_void_p),
                                     ctypes.POINTER(ctypes.c_int32))(query)
    query_string = ctypes.CFUNCTYPE(ctypes.c_char_p, ctypes.c_void_p, ctypes.c_int32)(string)
    count = ctypes.c_int32(0)
    if not query_devices(0, None, ctypes.byref(count)) or count.value <= 0:
        return []
    handles = (ctypes.c_void_p * count.value)()
    if not query_devices(count.value, handles, ctypes.byref(count)):
        return []
    out = []
    for i in range(count.value):
        ext = (query_string(handles[i], _EGL_EXTENSIONS) or b"").decode("ascii", "replace")
        extensions = tuple(ext.split())

        def text(what, handle=handles[i]):
            value = query_string(handle, what)
            return value.decode("utf-8", "replace") if value else None

        name = text(_EGL_RENDERER) if "EGL_EXT_device_query_name" in extensions else None
        drm = text(_EGL_DRM_DEVICE_FILE) if "EGL_EXT_device_drm" in extensions else None
        out.append(EglDevice(i, extensions, name, drm))
    return out


def _device_words(device: EglDevice | None) -> str:
    """Name a device in a log line."""
    if device is None:
        return "EGL's default display"
    kind = "software" if device.software else "hardware"
    return f"EGL device {device.index} ({device.name or kind})"


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__


#: EGL's ``eglGetCurrentSurface`` selectors.
_EGL_DRAW, _EGL_READ = 0x3059, 0x305A
#: The process's context and its EGL handle, once made (one per process, reused).
_made: tuple | None = None


def create_context():
    """Return the process's standalone moderngl context on EGL, current in the calling thread.

    The context is made once and reused. Making it (or handing it out again) makes it current,
    as a renderer needs; :func:`keep_current` gives a caller's own context back afterwards.

    Returns
    -------
    moderngl.Context

    Raises
    ------
    RenderUnavailableError
        No headless OpenGL here (EGL or the Mesa driver is missing, or GL is older than 3.3).
    """
    global _made
    if _made is None:
        ctx = _new_context()
        current = _egl_current()  # a new context is current in the thread that made it
        _made = (ctx, current[3] if current is not None else None)
        return ctx
    ctx, handle = _made
    current = _egl_current()
    if current is None or current[3] != handle:
        ctx.__enter__()
    return ctx


def _new_context():
    try:
        import moderngl
    except ImportError as exc:  # pragma: no cover - a broken install
        raise RenderUnavailableError(f"moderngl is not installed ({exc}); run `make setup`") \
            from exc
    devices = egl_devices()
    chosen = choose_device(devices, os.environ.get(DEVICE_ENV))
    attempts = fallbacks(devices, chosen)
    first_error: Exception | None = None
    ctx = None
    device: EglDevice | None = None
    for device in attempts:
        try:
            ctx = moderngl.create_context(
                standalone=True, backend="egl",
                **({"device_index": device.index} if device is not None else {}))
            break
        except Exception as exc:
            first_error = first_error or exc
            if device is not attempts[-1]:
                log.warning("cannot make an OpenGL context on %s: %s; trying %s",
                            _device_words(device), _first_line(exc),
                            _device_words(attempts[attempts.index(device) + 1]))
    if ctx is None:
        raise RenderUnavailableError(
            "cannot create a headless OpenGL context through EGL "
            f"({_first_line(first_error) if first_error else 'no device'});"
            f" install {' '.join(APT_PACKAGES)} (Debian: apt-get install -y "
            f"--no-install-recommends {' '.join(APT_PACKAGES)}) or run `make setup`") \
            from first_error
    if ctx.version_code < REQUIRED_VERSION:
        raise RenderUnavailableError(
            f"OpenGL {ctx.version_code} is too old (need {REQUIRED_VERSION}); install "
            f"{' '.join(APT_PACKAGES)}")
    if device is not chosen:
        log.warning("rendering on %s, not on %s", _device_words(device), _device_words(chosen))
    _device.clear()
    _device.update(egl_device=device.index if device is not None else None,
                   egl_devices=len(devices),
                   hardware=(not device.software) if device is not None else None)
    log.info("OpenGL: %s, %s (EGL device %s of %d, %s)", ctx.info.get("GL_RENDERER"),
             ctx.info.get("GL_VERSION"), _device["egl_device"], len(devices),
             "software" if device is not None and device.software
             else "hardware" if device is not None else "EGL's default display")
    return ctx


@functools.lru_cache(maxsize=1)
def _egl():
    """Return libEGL (the library glcontext drives) through ctypes, or None where it is missing."""
    try:
        lib = ctypes.CDLL(ctypes.util.find_library("EGL") or "libEGL.so.1")
    except OSError:
        return None
    for name in ("eglGetCurrentContext", "eglGetCurrentDisplay", "eglGetCurrentSurface"):
        getattr(lib, name).restype = ctypes.c_void_p
    lib.eglGetCurrentSurface.argtypes = [ctypes.c_int32]
    lib.eglMakeCurrent.argtypes = [ctypes.c_void_p] * 4
    lib.eglMakeCurrent.restype = ctypes.c_uint
    return lib


@functools.cache
def gl_function(name: str, *argtypes: type) -> object | None:
    """Return an OpenGL entry point that moderngl does not wrap, or None where none is offered.

    Looked up through ``eglGetProcAddress`` (the driver's own function; it acts on the
    calling thread's current context, as moderngl's calls do).

    Parameters
    ----------
    name : str
        The GL function, e.g. ``"glClipControl"``.
    *argtypes : ctypes types
        Its arguments (it returns nothing).

    Returns
    -------
    ctypes function or None
        The callable, or None where EGL or the function is missing.
    """
    lib = _egl()
    if lib is None:
        return None
    lib.eglGetProcAddress.restype = ctypes.c_void_p
    lib.eglGetProcAddress.argtypes = [ctypes.c_char_p]
    address = lib.eglGetProcAddress(name.encode())
    if not address:
        return None
    return ctypes.CFUNCTYPE(None, *argtypes)(address)


def _egl_current() -> tuple[int, int, int, int] | None:
    """Return the calling thread's current EGL (display, draw, read, context), None if none."""
    lib = _egl()
    if lib is None:
        return None
    context = lib.eglGetCurrentContext()
    if not context:
        return None
    return (lib.eglGetCurrentDisplay(), lib.eglGetCurrentSurface(_EGL_DRAW),
            lib.eglGetCurrentSurface(_EGL_READ), context)


@contextlib.contextmanager
def keep_current() -> Iterator[None]:
    """Give the calling thread's current GL context back after the block (a render entry point).

    Rendering makes this process's context current (:func:`create_context`); a caller that had
    its own context current (an application, or a test session's GL fixture) finds it current
    again after the block, as EGL's ``eglMakeCurrent`` left it. With none current before, the
    renderer's context stays current: there was nothing to disturb.
    """
    before = _egl_current()
    try:
        yield
    finally:
        if before is not None and _egl_current() != before:
            lib = _egl()
            if not lib.eglMakeCurrent(*before):
                log.warning("could not make the caller's GL context current again")


def describe() -> dict:
    """Return the renderer and version of the context (for run manifests and benchmark reports)."""
    ctx = create_context()
    return {"renderer": ctx.info.get("GL_RENDERER"), "version": ctx.info.get("GL_VERSION"),
            "vendor": ctx.info.get("GL_VENDOR"), **_device}
