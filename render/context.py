"""The one place that creates OpenGL contexts: headless moderngl on EGL.

On a machine without a GPU, Mesa's llvmpipe rasterises on the CPU (GL 4.5 core, bit-identical
images run to run, so golden images work); where a GPU and its EGL driver exist, the same code
runs there. If EGL or the Mesa driver is missing, :func:`create_context` raises
:class:`~render.errors.RenderUnavailableError` with one line naming the packages to install.
"""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import functools
import logging
from collections.abc import Iterator

from render.errors import RenderUnavailableError

__all__ = ["APT_PACKAGES", "create_context", "describe", "keep_current"]

log = logging.getLogger(__name__)

#: Debian packages that provide headless OpenGL through EGL (libgl1: glcontext loads libGL
#: even for EGL).
APT_PACKAGES = ("libegl1", "libegl-mesa0", "libgl1", "libgl1-mesa-dri")
#: OpenGL version the shaders need (330 core; llvmpipe gives 4.5).
REQUIRED_VERSION = 330


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
    try:
        ctx = moderngl.create_context(standalone=True, backend="egl")
    except Exception as exc:
        raise RenderUnavailableError(
            "cannot create a headless OpenGL context through EGL "
            f"({str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__});"
            f" install {' '.join(APT_PACKAGES)} (Debian: apt-get install -y "
            f"--no-install-recommends {' '.join(APT_PACKAGES)}) or run `make setup`") from exc
    if ctx.version_code < REQUIRED_VERSION:
        raise RenderUnavailableError(
            f"OpenGL {ctx.version_code} is too old (need {REQUIRED_VERSION}); install "
            f"{' '.join(APT_PACKAGES)}")
    log.info("OpenGL: %s, %s", ctx.info.get("GL_RENDERER"), ctx.info.get("GL_VERSION"))
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
            "vendor": ctx.info.get("GL_VENDOR")}
