"""The one place that creates OpenGL contexts: headless moderngl on EGL.

On a machine without a GPU, Mesa's llvmpipe rasterises on the CPU (GL 4.5 core, bit-identical
images run to run, so golden images work); where a GPU and its EGL driver exist, the same code
runs there. If EGL or the Mesa driver is missing, :func:`create_context` raises
:class:`~render.errors.RenderUnavailableError` with one line naming the packages to install.
"""

from __future__ import annotations

import functools
import logging

from render.errors import RenderUnavailableError

__all__ = ["APT_PACKAGES", "create_context", "describe"]

log = logging.getLogger(__name__)

#: Debian packages that provide headless OpenGL through EGL (libgl1: glcontext loads libGL
#: even for EGL).
APT_PACKAGES = ("libegl1", "libegl-mesa0", "libgl1", "libgl1-mesa-dri")
#: OpenGL version the shaders need (330 core; llvmpipe gives 4.5).
REQUIRED_VERSION = 330


@functools.lru_cache(maxsize=1)
def create_context():
    """Return a standalone moderngl context on EGL (one per process, reused)."""
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


def describe() -> dict:
    """Return the renderer and version of the context (for run manifests and benchmark reports)."""
    ctx = create_context()
    return {"renderer": ctx.info.get("GL_RENDERER"), "version": ctx.info.get("GL_VERSION"),
            "vendor": ctx.info.get("GL_VENDOR")}
