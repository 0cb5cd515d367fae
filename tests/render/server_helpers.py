"""Starting `craterscape render serve` as a user does: a subprocess on a free port."""

from __future__ import annotations

import contextlib
import os
import re
import select
import signal
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
#: Starts the command line exactly as the `craterscape` script does.
CRATERSCAPE = [sys.executable, "-c",
               "import sys; from terrain.cli.commands import main; sys.exit(main())"]


def rss_bytes(pid: int) -> int:
    """Resident memory of a process (Linux /proc)."""
    with open(f"/proc/{pid}/status", encoding="ascii") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) * 1024
    raise RuntimeError("no VmRSS")


@contextlib.contextmanager
def served(scenario, *args, startup: float = 180.0, env: dict | None = None):
    """Run ``craterscape render serve SCENARIO --port 0 ARGS``; yield (process, port).

    The port is read from the line the server prints once it is ready. On exit the server is
    sent SIGTERM and must stop cleanly (exit status 0). ``env``: variables added to the
    server's environment.
    """
    proc = subprocess.Popen([*CRATERSCAPE, "render", "serve", str(scenario), "--port", "0",
                             *map(str, args)], stderr=subprocess.PIPE, text=True,
                            env=dict(os.environ, PYTHONUNBUFFERED="1", **(env or {})))
    port = None
    deadline = time.monotonic() + startup
    lines = []
    try:
        while port is None:
            left = deadline - time.monotonic()
            if left <= 0 or proc.poll() is not None:
                raise RuntimeError(f"server did not start: {''.join(lines)}"
                                   f"{proc.stderr.read() if proc.poll() is not None else ''}")
            ready, _, _ = select.select([proc.stderr], [], [], left)
            if ready:
                line = proc.stderr.readline()
                lines.append(line)
                m = re.search(r"serving .* on [\d.:a-f]+:(\d+)\s*$", line)
                if m:
                    port = int(m.group(1))
        yield proc, port
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
            try:
                proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        proc.stderr.close()
