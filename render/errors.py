"""Errors of the render stage (each also a CraterscapeError, so the CLI reports one line)."""

from __future__ import annotations

from terrain.errors import CraterscapeError

__all__ = ["RenderUnavailableError"]


class RenderUnavailableError(CraterscapeError, RuntimeError):
    """No OpenGL context could be created (EGL or the Mesa driver is missing)."""
