"""Refuse requests whose memory would exceed the machine, before allocating anything.

Operations estimate the bytes they will hold at their peak and call :func:`require` first;
a request above the memory the machine has available raises
:class:`~terrain.errors.MemoryRequestError` with the figures, so a user gets a one-line
refusal instead of an out-of-memory kill half way through writing a file.
"""

from __future__ import annotations

import logging
import os

from terrain.errors import MemoryRequestError

__all__ = ["available_bytes", "format_bytes", "require"]

log = logging.getLogger(__name__)

#: Environment variable that caps the memory craterscape will plan to use (bytes, or with a
#: K/M/G suffix); handy on shared machines and for testing the refusal path.
LIMIT_ENV = "CRATERSCAPE_MEMORY_LIMIT"

_UNITS = {"K": 1024, "M": 1024**2, "G": 1024**3, "T": 1024**4}


def _parse_size(text: str) -> int:
    text = text.strip().upper().removesuffix("B")
    factor = _UNITS.get(text[-1:], 1)
    number = text[:-1] if text[-1:] in _UNITS else text
    return int(float(number) * factor)


def available_bytes() -> int:
    """Memory this process may plan to use: MemAvailable, capped by ``CRATERSCAPE_MEMORY_LIMIT``."""
    avail = None
    try:
        with open("/proc/meminfo", encoding="ascii") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    avail = int(line.split()[1]) * 1024
                    break
    except OSError:
        pass
    if avail is None:
        try:
            avail = os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
        except (ValueError, OSError, AttributeError):
            avail = 2**62
    limit = os.environ.get(LIMIT_ENV)
    if limit:
        try:
            avail = min(avail, _parse_size(limit))
        except ValueError:
            log.warning("ignoring unparseable %s=%r", LIMIT_ENV, limit)
    return avail


def format_bytes(n: float) -> str:
    """Human-readable size.

    >>> format_bytes(3 * 1024**3)
    '3.0 GiB'
    """
    for unit in ("B", "KiB", "MiB", "GiB", "TiB"):
        if abs(n) < 1024 or unit == "TiB":
            return f"{n:.1f} {unit}" if unit != "B" else f"{int(n)} B"
        n /= 1024
    return f"{n:.1f} TiB"  # pragma: no cover


def require(nbytes: float, what: str) -> None:
    """Raise :class:`MemoryRequestError` if ``nbytes`` exceeds the available memory."""
    avail = available_bytes()
    if nbytes > avail:
        raise MemoryRequestError(
            f"{what} needs about {format_bytes(nbytes)} of memory but only "
            f"{format_bytes(avail)} is available; use --window or a smaller size")
    log.debug("%s: planning %s of %s available", what, format_bytes(nbytes), format_bytes(avail))
