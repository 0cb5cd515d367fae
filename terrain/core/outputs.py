"""Guarding and committing outputs.

Nothing a command reads is overwritten, nothing half-written is ever seen, and files that
belong together appear together.

Every craterscape writer goes through :func:`atomic_path`; three mechanisms sit behind it.

The input guard
    :func:`check_output_path` (and :func:`check_output_folder` for folders) refuses an output
    that is an input (same real path or same inode), that lies inside an input folder (a layer
    stack, a run directory), or whose folder cannot be written. Inputs come from the caller's
    ``inputs`` and from :func:`protect`, which the command line calls with every input path of
    a command (see :mod:`terrain.cli.commands`) and which loaders call for files they find
    themselves
    (a scenario's stack, a recipe's shape model).
Atomic single files
    A file is written under a temporary name ``.NAME.PID-XXXX.partial`` in the destination
    folder and renamed into place only when complete. A target that is not a regular file
    (``/dev/null``, a FIFO) is written in place, never replaced; block devices, sockets and
    folders are refused. A symbolic link is written through (its target is replaced). Any
    ``OSError`` while writing (read-only folder, full disk, quota) becomes
    :class:`~terrain.core.errors.OutputPathError`, ``cannot write 'PATH': REASON`` (exit code 2).
    Temporaries left by a killed process (whose PID is gone) are removed by
    :func:`sweep_partials`, which every :class:`Transaction` runs on its folders.
Transactions (sets of files)
    Inside ``with transaction():`` every :func:`atomic_path` stages its file instead of
    renaming it. On success the set is committed behind one commit point: a journal
    ``.craterscape-commit.json`` naming every rename and every stale companion to remove is
    written atomically, then the renames and removals are done and the journal is deleted. A
    crash after the journal is rolled forward by the next writer or reader of the folder
    (:func:`settle`); a crash before it leaves the previous set untouched. On failure every
    staged file is removed, and a folder the transaction created is removed again if empty,
    so a command that fails leaves nothing behind.

>>> import tempfile, pathlib
>>> d = pathlib.Path(tempfile.mkdtemp())
>>> with transaction():
...     with atomic_path(d / "a.txt") as tmp:
...         _ = tmp.write_text("a")
...     with atomic_path(d / "b.txt") as tmp:
...         _ = tmp.write_text("b")
>>> sorted(p.name for p in d.iterdir())
['a.txt', 'b.txt']
"""

from __future__ import annotations

import contextlib
import contextvars
import errno
import fcntl
import json
import logging
import os
import re
import secrets
import shutil
import signal
import stat
import tempfile
from collections.abc import Iterable, Iterator
from pathlib import Path

from terrain.core.errors import OutputPathError

__all__ = ["JOURNAL", "Transaction", "atomic_path", "cannot_write", "check_output_folder",
           "check_output_path", "discard", "is_write_error", "make_output_folder", "protect",
           "protected", "remove_path", "remove_temporaries", "settle", "sweep_partials",
           "transaction"]

log = logging.getLogger(__name__)

#: Name of the commit journal a transaction writes in its first folder.
JOURNAL = ".craterscape-commit.json"
PARTIAL_SUFFIX = ".partial"
_PARTIAL_RE = re.compile(r"^\..+\.(\d+)-[A-Za-z0-9_]+\.partial$")
#: errno values that mean "this place cannot take the output" (exit code 2, one message).
WRITE_ERRNOS = frozenset({errno.ENOSPC, errno.EACCES, errno.EROFS, errno.EDQUOT, errno.EPERM,
                          errno.EFBIG, errno.ENAMETOOLONG, errno.ENOTDIR, errno.EISDIR,
                          errno.ENXIO, errno.ETXTBSY})

_PROTECTED: contextvars.ContextVar[tuple] = contextvars.ContextVar("craterscape_protected",
                                                                    default=())
_ACTIVE: contextvars.ContextVar = contextvars.ContextVar("craterscape_transaction",
                                                         default=None)
#: Outputs being written now, innermost last: a write error that names no file is theirs.
_WRITING: contextvars.ContextVar[tuple] = contextvars.ContextVar("craterscape_writing",
                                                                 default=())


# ------------------------------------------------------------------------------ inputs


def protect(*paths) -> None:
    """Add paths (files or folders) that no output of this command may replace or enter.

    The command line registers every input of a command; library code registers files it
    finds on its own (a scenario's layer stack). The registry lives in a context variable and
    is cleared with :func:`protected`.
    """
    extra = tuple(Path(p) for p in paths if p is not None and str(p) != "")
    if extra:
        _PROTECTED.set(_PROTECTED.get() + extra)


@contextlib.contextmanager
def protected(paths=()) -> Iterator[None]:
    """Scope of a command: inputs registered inside are forgotten afterwards."""
    token = _PROTECTED.set(tuple(Path(p) for p in paths if p is not None))
    try:
        yield
    finally:
        _PROTECTED.reset(token)


def _all_inputs(inputs) -> list[Path]:
    out = [Path(p) for p in (inputs or ()) if p is not None and str(p) != ""]
    return out + list(_PROTECTED.get())


def _real(path: Path) -> Path:
    try:
        return path.resolve()
    except (OSError, RuntimeError):  # pragma: no cover - symlink loops
        return Path(os.path.abspath(path))


def _same(a: Path, b: Path) -> bool:
    if _real(a) == _real(b):
        return True
    with contextlib.suppress(OSError):
        return a.exists() and b.exists() and os.path.samefile(a, b)
    return False


def _check_against_inputs(path: Path, inputs, what: str) -> None:
    target = _real(path)
    for item in _all_inputs(inputs):
        if _same(path, item):
            kind = "the input folder" if item.is_dir() else "the same file as input"
            raise OutputPathError(f"{what} '{path}' is {kind} '{item}'; choose another "
                                  "output name")
        if item.is_dir() and target.is_relative_to(_real(item)):
            raise OutputPathError(f"{what} '{path}' lies inside the input folder '{item}'; "
                                  "choose an output outside it")


def _check_writable_folder(folder: Path, what: str, path: Path) -> None:
    if not folder.is_dir():
        raise OutputPathError(f"{what} folder '{folder}' does not exist")
    if not os.access(folder, os.W_OK | os.X_OK):
        raise OutputPathError(f"cannot write '{path}': folder '{folder}' is not writable")


def check_output_path(path, inputs: Iterable = (), *, suffixes: Iterable[str] = (),
                      what: str = "") -> Path:
    """Validate an output file path before any work.

    Refused: a folder, a missing or unwritable parent folder, a block device or socket, an
    input (``inputs`` and :func:`protect`), a path inside an input folder, and a name whose
    extension is not one of ``suffixes`` (when given; ``what`` names the format written).
    """
    path = Path(path)
    if path.is_dir():
        raise OutputPathError(f"output '{path}' is a folder; give a file name")
    parent = path.parent if str(path.parent) else Path(".")
    if not _is_special(path):  # a device or FIFO is written in place, not beside
        _check_writable_folder(parent, "output", path)
    with contextlib.suppress(OSError):
        mode = os.stat(path).st_mode
        if stat.S_ISBLK(mode) or stat.S_ISSOCK(mode):
            raise OutputPathError(f"output '{path}' is a block device or socket; refusing to "
                                  "write into it")
    _check_against_inputs(path, inputs, "output")
    suffixes = tuple(s.lower() for s in suffixes)
    if suffixes and path.suffix.lower() not in suffixes and not _is_special(path):
        raise OutputPathError(
            f"output '{path}' would hold {what or suffixes[0].lstrip('.').upper()} data; give a "
            f"name ending in {' or '.join(suffixes)}")
    return path


def check_output_folder(folder, inputs: Iterable = (), *, must_be_empty: bool = False) -> Path:
    """Validate an output folder before any work (it is not created here).

    Refused: a file in its place, an input folder or a folder inside one, a folder holding an
    input (``-o .`` next to the inputs is fine; only the folder itself is checked), an
    unwritable or missing parent, and (``must_be_empty``) a folder with files in it.
    """
    folder = Path(folder)
    if folder.exists() and not folder.is_dir():
        raise OutputPathError(f"output '{folder}' exists and is not a folder")
    _check_against_inputs(folder, inputs, "output folder")
    if folder.is_dir():
        if not os.access(folder, os.W_OK | os.X_OK):
            raise OutputPathError(f"cannot write '{folder}': the folder is not writable")
        if must_be_empty and any(folder.iterdir()):
            raise OutputPathError(f"output folder '{folder}' is not empty; give a new folder")
    else:
        parent = folder.parent
        while not parent.exists() and parent != parent.parent:
            parent = parent.parent
        if not os.access(parent, os.W_OK | os.X_OK):
            raise OutputPathError(f"cannot write '{folder}': folder '{parent}' is not writable")
    return folder


# ------------------------------------------------------------------------------ errors


def is_write_error(exc: BaseException) -> bool:
    """Whether an exception means the output's place cannot take it (full, read-only, ...)."""
    return isinstance(exc, OSError) and exc.errno in WRITE_ERRNOS


def cannot_write(path, exc: BaseException) -> OutputPathError:
    """Return the one message for every "cannot write here": ``cannot write 'PATH': REASON``.

    Parameters
    ----------
    path : path-like or None
        What could not be written. None: the file the error names, else the output being
        written now (:func:`atomic_path`); a write() that fails names no file.
    exc : BaseException
        The error (its ``strerror`` is the reason).
    """
    if path is None:
        path = getattr(exc, "filename", None)
    if path is None and _WRITING.get():
        path = _WRITING.get()[-1]
    reason = getattr(exc, "strerror", None)
    if not reason:
        text = str(exc).strip()
        reason = text.splitlines()[0] if text else type(exc).__name__
    if path is None:
        return OutputPathError(f"cannot write an output: {reason}")
    return OutputPathError(f"cannot write '{path}': {reason}")


# ------------------------------------------------------------------------------ writing


#: Temporaries this process created and has neither put in place nor removed; an interrupt
#: (Ctrl-C, SIGTERM) removes them all (:func:`remove_temporaries`), whatever line it hit.
_LIVE: set = set()
_INTERRUPTS = {signal.SIGINT, signal.SIGTERM}


def _temp_beside(path: Path) -> Path:
    parent = path.parent if str(path.parent) else Path(".")
    if _is_special(path):  # bytes for a device or FIFO are copied in: stage them elsewhere
        parent = Path(tempfile.gettempdir())
    # The name is registered before the file exists, so no temporary escapes the registry:
    # an interrupt's Python handler runs in the main thread between any two bytecodes, even
    # while this thread blocks the signal, when the signal reached another thread (numba's,
    # GDAL's); a file made first and registered next could be left behind (it was, under a
    # SIGTERM during a threaded expansion). An interrupt before the file exists leaves a name
    # that remove_temporaries does not find.
    flags = os.O_RDWR | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0) \
        | getattr(os, "O_CLOEXEC", 0)
    for _ in range(100):
        tmp = parent / f".{path.name}.{os.getpid()}-{secrets.token_hex(4)}{PARTIAL_SUFFIX}"
        _LIVE.add(tmp)
        try:
            fd = os.open(tmp, flags, 0o600)
        except FileExistsError:
            _LIVE.discard(tmp)
            continue
        except OSError as exc:
            _LIVE.discard(tmp)
            raise cannot_write(path, exc) from exc
        os.close(fd)
        return tmp
    raise cannot_write(path, FileExistsError(errno.EEXIST, "no free temporary name", str(parent)))


def _forget(tmp: Path) -> None:
    _LIVE.discard(tmp)


def remove_temporaries() -> list[Path]:
    """Remove every temporary this process still holds.

    The command line calls it when interrupted; a temporary a committed set's journal names
    is never among them.
    """
    removed = []
    for tmp in list(_LIVE):
        with contextlib.suppress(OSError):
            tmp.unlink()
            removed.append(tmp)
        _LIVE.discard(tmp)
    return removed


def _target(path: Path) -> Path:
    """Where bytes for ``path`` go: through a symbolic link to its target."""
    return Path(os.path.realpath(path)) if path.is_symlink() else path


def _is_special(path: Path) -> bool:
    with contextlib.suppress(OSError):
        return not stat.S_ISREG(os.stat(path).st_mode)
    return False


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _fsync_file(path: Path) -> None:
    with open(path, "rb") as f:
        os.fsync(f.fileno())


def _fsync_dir(folder: Path) -> None:
    with contextlib.suppress(OSError):
        fd = os.open(folder, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def _install(tmp: Path, final: Path) -> None:
    """Put a complete temporary file in place: rename, or copy into a special file."""
    if _is_special(final):
        with open(tmp, "rb") as src, open(final, "wb") as dst:
            shutil.copyfileobj(src, dst)
        tmp.unlink()
    else:
        os.replace(tmp, final)
    _forget(tmp)


@contextlib.contextmanager
def atomic_path(path, inputs: Iterable = ()) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; put it in place if the block succeeds.

    Inside :func:`transaction` the file is staged and put in place with the rest of the set.
    """
    path = check_output_path(path, inputs)
    final = _target(path)
    tmp = _temp_beside(final)
    active = _ACTIVE.get()
    done = False
    writing = _WRITING.set((*_WRITING.get(), path))
    try:
        try:
            yield tmp
            _fsync_file(tmp)
            os.chmod(tmp, 0o666 & ~_umask())  # made 0600; give what open() would
            if active is not None:
                active._stage(tmp, final)
            else:
                _install(tmp, final)
                _fsync_dir(final.parent if str(final.parent) else Path("."))
            done = True
        except OSError as exc:
            if is_write_error(exc):
                raise cannot_write(path, exc) from exc
            raise
    finally:
        _WRITING.reset(writing)
        if not (done and active is not None):
            with contextlib.suppress(FileNotFoundError):
                tmp.unlink()
            _forget(tmp)


def _pid_alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def sweep_partials(folder, *, recursive: bool = False) -> list[Path]:
    """Remove temporaries (``.NAME.PID-XXXX.partial``) whose writing process is gone."""
    folder = Path(folder)
    removed: list[Path] = []
    if not folder.is_dir():
        return removed
    entries = folder.rglob(f"*{PARTIAL_SUFFIX}") if recursive \
        else folder.glob(f".*{PARTIAL_SUFFIX}")
    for p in entries:
        m = _PARTIAL_RE.match(p.name)
        if m and not _pid_alive(int(m.group(1))):
            with contextlib.suppress(OSError):
                p.unlink()
                removed.append(p)
    if removed:
        log.info("removed %d temporary file(s) left by an interrupted command in %s",
                 len(removed), folder)
    return removed


# ------------------------------------------------------------------------------ sets


@contextlib.contextmanager
def _folder_lock(folder: Path, shared: bool = False) -> Iterator[None]:
    """Flock on the folder itself: commits (and roll-forwards) in a folder never interleave."""
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:  # unreadable folder: nothing to lock against
        yield
        return
    try:
        fcntl.flock(fd, fcntl.LOCK_SH if shared else fcntl.LOCK_EX)
        yield
    finally:
        with contextlib.suppress(OSError):
            fcntl.flock(fd, fcntl.LOCK_UN)
        os.close(fd)


def _rel(path: Path, base: Path) -> str:
    with contextlib.suppress(ValueError):
        return str(Path(os.path.abspath(path)).relative_to(os.path.abspath(base)))
    return os.path.abspath(path)


def _apply(folder: Path, doc: dict) -> None:
    for tmp, final in doc.get("renames", []):
        tmp, final = folder / tmp, folder / final
        if tmp.exists():
            _install(tmp, final)
    for stale in doc.get("remove", []):
        with contextlib.suppress(FileNotFoundError, IsADirectoryError):
            (folder / stale).unlink()
    _fsync_dir(folder)


def settle(folder) -> bool:
    """Finish a committed set that a crash interrupted in ``folder``; True if there was one.

    Cheap when there is nothing to do (one ``stat``); readers of a set call it first.
    """
    folder = Path(folder)
    journal = folder / JOURNAL
    if not journal.exists():
        return False
    with _folder_lock(folder):
        try:
            doc = json.loads(journal.read_text(encoding="utf-8"))
        except FileNotFoundError:
            return False  # finished by its writer while we waited
        except (OSError, ValueError):
            log.warning("ignoring unreadable commit journal %s", journal)
            return False
        try:
            _apply(folder, doc)
            journal.unlink()
        except OSError as exc:
            log.warning("cannot finish the interrupted commit in %s: %s", folder, exc)
            return False
    log.info("finished an interrupted commit in %s", folder)
    return True


class Transaction:
    """Files staged by :func:`atomic_path` inside ``with transaction():`` (see module doc)."""

    def __init__(self, stale=()) -> None:
        self.staged: list[tuple[Path, Path]] = []
        self.stale: list[Path] = [Path(p) for p in stale]
        self.created: list[Path] = []
        self.committed: Path | None = None

    def _stage(self, tmp: Path, final: Path) -> None:
        self.staged = [(t, f) for t, f in self.staged if f != final]
        self.staged.append((tmp, final))

    def remove_on_commit(self, *paths) -> None:
        """Stale companions to delete when the set is committed (absent ones are skipped)."""
        self.stale += [Path(p) for p in paths if p is not None]

    def make_folder(self, folder) -> Path:
        """Create ``folder`` (and parents) now; removed again if the transaction fails."""
        folder = Path(folder)
        missing = []
        p = folder
        while not p.exists():
            missing.append(p)
            p = p.parent
        try:
            folder.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise cannot_write(folder, exc) from exc
        self.created += reversed(missing)
        return folder

    def _commit(self) -> None:
        for folder in {f.parent for _, f in self.staged}:  # what killed writers left here
            sweep_partials(folder if str(folder) else Path("."))
        finals = {f for _, f in self.staged}
        stale = [p for p in self.stale if p not in finals and (p.exists() or p.is_symlink())]
        if not self.staged and not stale:
            return
        first = (self.staged[0][1] if self.staged else stale[0]).parent
        folder = first if str(first) else Path(".")
        with _folder_lock(folder):
            if len(self.staged) + len(stale) == 1:  # one file: its rename is the commit
                if self.staged:
                    _install(*self.staged[0])
                else:
                    stale[0].unlink()
                _fsync_dir(folder)
                return
            doc = dict(renames=[[_rel(t, folder), _rel(f, folder)] for t, f in self.staged],
                       remove=[_rel(p, folder) for p in stale])
            jtmp = _temp_beside(folder / JOURNAL)
            try:
                jtmp.write_text(json.dumps(doc), encoding="utf-8")
                _fsync_file(jtmp)
                mask = signal.pthread_sigmask(signal.SIG_BLOCK, _INTERRUPTS)
                try:
                    os.replace(jtmp, folder / JOURNAL)  # the commit point
                    _forget(jtmp)
                    self.committed = folder  # from here on the set is finished, not undone
                    for tmp, _ in self.staged:
                        _forget(tmp)
                finally:
                    signal.pthread_sigmask(signal.SIG_SETMASK, mask)
            except OSError as exc:
                with contextlib.suppress(FileNotFoundError):
                    jtmp.unlink()
                _forget(jtmp)
                raise cannot_write(folder / JOURNAL, exc) from exc
            _fsync_dir(folder)
            _apply(folder, doc)
            (folder / JOURNAL).unlink()
            _fsync_dir(folder)

    def _abort(self) -> None:
        if self.committed is not None:  # interrupted after the commit point: finish it
            settle(self.committed)
            return
        for tmp, _ in self.staged:
            with contextlib.suppress(FileNotFoundError):
                tmp.unlink()
            _forget(tmp)
        for folder in reversed(self.created):
            with contextlib.suppress(OSError):
                folder.rmdir()


def remove_path(path) -> None:
    """Delete a file or a folder (a Zarr store, a stack) at once; a missing one is fine.

    Parameters
    ----------
    path : path-like
        The file, link or folder (a link is removed, never followed).
    """
    path = Path(path)
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        with contextlib.suppress(FileNotFoundError):
            path.unlink()


def discard(*paths) -> None:
    """Mark stale companions of the outputs being written for removal.

    They are removed when the current :func:`transaction` commits (at once outside one).
    Absent paths are ignored.
    """
    with transaction(stale=paths):
        pass


def make_output_folder(folder, inputs: Iterable = ()) -> Path:
    """Check (:func:`check_output_folder`) and create an output folder.

    Inside a :func:`transaction` a folder it creates is removed again if the transaction
    fails.
    """
    folder = check_output_folder(folder, inputs)
    txn = _ACTIVE.get()
    if txn is not None:
        return txn.make_folder(folder)
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise cannot_write(folder, exc) from exc
    return folder


@contextlib.contextmanager
def transaction(stale=(), folders=()) -> Iterator[Transaction]:
    """Stage every :func:`atomic_path` write inside the block and commit them as one set.

    ``stale`` names companions of the set to remove on commit (a catalogue the new set no
    longer has). ``folders`` are settled and swept of dead temporaries first.
    """
    if _ACTIVE.get() is not None:  # nested: join the outer set
        outer = _ACTIVE.get()
        outer.remove_on_commit(*stale)
        yield outer
        return
    for folder in folders:
        settle(folder)
        sweep_partials(folder)
    txn = Transaction(stale)
    token = _ACTIVE.set(txn)
    active = True
    ok = False
    try:
        yield txn
        _ACTIVE.reset(token)
        active = False
        try:
            txn._commit()
        except OSError as exc:
            if is_write_error(exc):
                raise cannot_write(txn.staged[0][1] if txn.staged else "?", exc) from exc
            raise
        ok = True
    finally:
        if active:
            _ACTIVE.reset(token)
        if not ok:
            txn._abort()
