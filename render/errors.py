"""Errors of the render stage (each also a CraterscapeError, so the CLI reports one line)."""

from __future__ import annotations

from terrain.core.errors import CraterscapeError

__all__ = ["ProtocolError", "RenderUnavailableError", "ServerError"]


class RenderUnavailableError(CraterscapeError, RuntimeError):
    """No OpenGL context could be created (EGL or the Mesa driver is missing)."""


class ProtocolError(CraterscapeError, ValueError):
    """A message broke the render server's wire protocol (``code``: its error code)."""

    def __init__(self, code: int, reason: str):
        super().__init__(reason)
        self.code = int(code)
        self.reason = reason


class ServerError(CraterscapeError, RuntimeError):
    """The render server answered a request with an error reply (``code``, ``reason``)."""

    def __init__(self, code: int, reason: str):
        from render.protocol import ErrorCode

        try:
            name = ErrorCode(code).name
        except ValueError:
            name = f"code {code}"
        super().__init__(f"render server: {name}: {reason}")
        self.code = int(code)
        self.reason = reason
