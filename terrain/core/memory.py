"""Refuse requests whose memory would exceed the machine, before allocating anything.

Operations estimate the bytes they will hold at their peak and call :func:`require` first;
a request above the memory this process may use (the machine's available memory, capped by
the process's address-space limit ``ulimit -v`` and by the container's cgroup limit,
``memory.max`` in cgroup v2 or ``memory.limit_in_bytes`` in v1, less what is in use) raises
:class:`~terrain.core.errors.MemoryRequestError` with the figures, so a user gets a one-line
refusal instead of an out-of-memory kill half way through writing a file.
"""

from __future__ import annotations

import logging
import os
import resource
from pathlib import Path

from terrain.core.errors import MemoryRequestError

__all__ = ["available_bytes", "format_bytes", "keep_freed_memory", "require"]

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


#: Where the process's cgroup hierarchy is mounted.
CGROUP_ROOT = Path("/sys/fs/cgroup")


def _read_int(path: Path) -> int | None:
    try:
        text = path.read_text(encoding="ascii").strip()
    except OSError:
        return None
    if not text or text == "max":
        return None
    try:
        return int(text)
    except ValueError:
        return None


def _cgroup_headroom(root: Path = CGROUP_ROOT, proc_cgroup: Path = Path("/proc/self/cgroup")) \
        -> int | None:
    """Bytes the process's cgroup (v2 or v1) still allows, or None without a limit."""
    try:
        lines = proc_cgroup.read_text(encoding="ascii").splitlines()
    except OSError:
        return None
    best = None
    for line in lines:
        parts = line.split(":", 2)
        if len(parts) != 3:
            continue
        _, controllers, rel = parts
        rel = rel.lstrip("/")
        if controllers == "":  # v2: the limit of this group and of every parent applies
            candidates = [(root / rel, "memory.max", "memory.current")]
            p = Path(rel)
            while str(p) not in ("", "."):
                p = p.parent
                candidates.append((root / p, "memory.max", "memory.current"))
        elif "memory" in controllers.split(","):
            base = root / "memory"
            candidates = [(base / rel, "memory.limit_in_bytes", "memory.usage_in_bytes"),
                          (base, "memory.limit_in_bytes", "memory.usage_in_bytes")]
        else:
            continue
        for folder, limit_name, usage_name in candidates:
            limit = _read_int(folder / limit_name)
            if limit is None or limit >= 2**60:  # v1 writes a huge number for "no limit"
                continue
            headroom = max(0, limit - (_read_int(folder / usage_name) or 0))
            best = headroom if best is None else min(best, headroom)
    return best


def _address_space_headroom() -> int | None:
    """Bytes ``ulimit -v`` (RLIMIT_AS) still allows this process to map, or None."""
    try:
        soft, _ = resource.getrlimit(resource.RLIMIT_AS)
    except (OSError, ValueError):  # pragma: no cover
        return None
    if soft == resource.RLIM_INFINITY:
        return None
    used = 0
    try:
        with open("/proc/self/status", encoding="ascii") as f:
            for line in f:
                if line.startswith("VmSize:"):
                    used = int(line.split()[1]) * 1024
                    break
    except OSError:
        pass
    return max(0, soft - used)


def available_bytes() -> int:
    """Return the memory this process may plan to use, in bytes.

    MemAvailable, capped by the process's address-space limit, its cgroup's limit and
    ``CRATERSCAPE_MEMORY_LIMIT``.
    """
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
    for cap in (_address_space_headroom(), _cgroup_headroom()):
        if cap is not None:
            avail = min(avail, cap)
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


#: glibc allocator settings of :func:`keep_freed_memory` (``mallopt``: M_MMAP_THRESHOLD,
#: M_TRIM_THRESHOLD, M_TOP_PAD): blocks up to 256 MiB come from the heap instead of fresh
#: mappings, up to 1 GiB of freed heap is kept rather than handed back, and the heap grows
#: 64 MiB at a time.
KEEP_FREED_MALLOPT = ((-3, 256 * 2**20), (-1, 2**30), (-2, 64 * 2**20))


def keep_freed_memory() -> bool:
    """Have this process's C allocator reuse freed memory for large arrays (glibc only).

    By default glibc serves each block above a threshold (128 KiB, raised as such blocks
    are freed, to 32 MiB at most) from a new mapping and unmaps it when freed, so the pages
    of every frame-sized temporary are faulted in and zeroed by the kernel again. A process
    that makes and drops such arrays thousands of times (the campaign's evaluation: frames,
    range and normal images, warps) spends much of its system time there: in the demo's
    evaluation stage, 1.5 million page faults and 5 s of system CPU fall to 0.3 million and
    3 s, and the stage takes a second less (docs/speed.md). The freed memory stays with the
    process (up to 1 GiB more of resident memory than with the defaults) until it exits:
    for processes that run one job, not for a long-lived server. The setting lasts for the
    process.

    Returns
    -------
    bool
        Whether the settings were applied (False without glibc's ``mallopt``).
    """
    import ctypes
    import ctypes.util

    try:
        mallopt = ctypes.CDLL(ctypes.util.find_library("c")).mallopt
    except (OSError, AttributeError, TypeError):  # not glibc: its allocator as it is
        return False
    mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
    mallopt.restype = ctypes.c_int
    return all(mallopt(param, value) == 1 for param, value in KEEP_FREED_MALLOPT)
