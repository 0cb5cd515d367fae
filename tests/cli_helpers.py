"""Running `craterscape` as a user does, inside the test process (click's CliRunner)."""

from __future__ import annotations

from click.testing import CliRunner

from terrain.cli.commands import main


def run(*args, env=None):
    """Invoke ``craterscape ARGS...``; every argument is passed as text."""
    return CliRunner().invoke(main, [str(a) for a in args], env=env)


def one_line_error(result, *fragments):
    """Assert the command failed as bad input must: exit code 2, one line, no traceback."""
    assert result.exit_code == 2, result.output
    lines = [ln for ln in result.output.splitlines() if ln.strip()]
    assert len(lines) == 1, result.output
    assert lines[0].startswith("craterscape: error:") or lines[0].startswith("Error:")
    for fragment in fragments:
        assert fragment in lines[0], lines[0]
    assert "Traceback" not in result.output


def snapshot(*paths):
    """Bytes of every file under ``paths`` (files or folders): compare before and after."""
    from pathlib import Path

    out = {}
    for p in map(Path, paths):
        files = [p] if p.is_file() else sorted(q for q in p.rglob("*") if q.is_file())
        for f in files:
            out[f] = f.read_bytes()
    return out


def refused(result, before, *absent, fragments=(), folder=None):
    """Assert a clean refusal: exit code 2 and one line on stderr
    (:func:`one_line_error`), every input byte-identical (``before`` is a :func:`snapshot`),
    no output (``absent``) and no partial file left in ``folder``."""
    one_line_error(result, *fragments)
    assert snapshot(*before) == before
    for p in absent:
        assert not p.exists(), p
    if folder is not None:
        assert not [p for p in folder.rglob("*") if p.name.endswith(".partial")]


def unwritable_folder(tmp_path):
    """A folder this process cannot create files in: a read-only folder for a normal user;
    as root (who writes anywhere) sysfs, which refuses every new file."""
    import os
    from pathlib import Path

    if os.geteuid() == 0:
        return Path("/sys")
    folder = tmp_path / "read-only"
    folder.mkdir()
    folder.chmod(0o555)
    return folder


class file_size_limit:
    """A full disk, for this process: writes past ``nbytes`` fail with EFBIG (RLIMIT_FSIZE,
    with SIGXFSZ ignored so the write returns the error instead of killing the process)."""

    def __init__(self, nbytes):
        self.nbytes = nbytes

    def __enter__(self):
        import resource
        import signal

        self.sig = signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        self.old = resource.getrlimit(resource.RLIMIT_FSIZE)
        resource.setrlimit(resource.RLIMIT_FSIZE, (self.nbytes, self.old[1]))
        return self

    def __exit__(self, *exc):
        import resource
        import signal

        resource.setrlimit(resource.RLIMIT_FSIZE, self.old)
        signal.signal(signal.SIGXFSZ, self.sig)
        return False
