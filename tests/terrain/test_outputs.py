"""The output machinery every writer shares (terrain.core.outputs): guards, atomic files, sets."""

import json
import os
import subprocess
import sys

import pytest

from terrain.core.errors import OutputPathError
from terrain.core.outputs import (
    JOURNAL,
    atomic_path,
    check_output_path,
    protected,
    settle,
    sweep_partials,
    transaction,
)


def test_a_failed_set_leaves_nothing_and_keeps_the_previous_files(tmp_path):
    (tmp_path / "a.txt").write_text("old a")
    with pytest.raises(RuntimeError), transaction():
        with atomic_path(tmp_path / "a.txt") as tmp:
            tmp.write_text("new a")
        with atomic_path(tmp_path / "b.txt") as tmp:
            tmp.write_text("new b")
        raise RuntimeError("the third file failed")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.txt"]
    assert (tmp_path / "a.txt").read_text() == "old a"


def test_a_commit_interrupted_after_its_journal_is_finished_by_the_next_reader(tmp_path):
    (tmp_path / "a.txt").write_text("old a")
    (tmp_path / "stale.csv").write_text("old")
    (tmp_path / ".a.txt.1-x.partial").write_text("new a")  # staged, then the crash
    (tmp_path / ".b.txt.1-y.partial").write_text("new b")
    (tmp_path / JOURNAL).write_text(json.dumps(dict(
        renames=[[".a.txt.1-x.partial", "a.txt"], [".b.txt.1-y.partial", "b.txt"]],
        remove=["stale.csv"])))
    assert settle(tmp_path)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.txt", "b.txt"]
    assert (tmp_path / "a.txt").read_text() == "new a"
    assert not settle(tmp_path)


def test_symlinks_are_written_through_and_inputs_behind_them_are_protected(tmp_path):
    target = tmp_path / "real.txt"
    target.write_text("old")
    link = tmp_path / "link.txt"
    link.symlink_to(target)
    with atomic_path(link) as tmp:
        tmp.write_text("new")
    assert link.is_symlink() and target.read_text() == "new"
    with pytest.raises(OutputPathError, match="same file as input"):
        check_output_path(link, [target])
    with protected([tmp_path]), pytest.raises(OutputPathError, match="inside the input"):
        check_output_path(tmp_path / "x.txt")


def test_only_temporaries_of_dead_processes_are_swept(tmp_path):
    dead = int(subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                              capture_output=True, text=True, check=True).stdout)
    gone = tmp_path / f".x.tif.{dead}-abc.partial"
    alive = tmp_path / f".y.tif.{os.getpid()}-abc.partial"
    gone.write_text("")
    alive.write_text("")
    assert sweep_partials(tmp_path) == [gone]
    assert alive.exists()


def test_a_write_error_without_a_file_name_names_the_output_being_written(tmp_path):
    import errno

    from terrain.core.outputs import cannot_write

    full = OSError(errno.EFBIG, "File too large")  # what a failed write() raises: no filename
    with atomic_path(tmp_path / "x.tif"):
        message = str(cannot_write(None, full))
    assert message == f"cannot write '{tmp_path / 'x.tif'}': File too large"
    named = OSError(errno.ENOSPC, "No space left on device", str(tmp_path / "y.csv"))
    assert str(cannot_write(None, named)) == (f"cannot write '{tmp_path / 'y.csv'}': "
                                              "No space left on device")
    assert "'output'" not in str(cannot_write(None, full))


def test_a_full_disk_under_a_zarr_store_names_the_chunk(tmp_path):
    from terrain.execution.chunked import SynthSource, run
    from tests.cli_helpers import file_size_limit

    run(SynthSource(129, seed=1), tmp_path / "warm.zarr", chunk=64)  # compiled kernels cached
    with file_size_limit(2_000), pytest.raises(OutputPathError) as info:
        run(SynthSource(129, seed=1), tmp_path / "full.zarr", chunk=64)
    assert "full.zarr" in str(info.value) and "File too large" in str(info.value)


def test_an_interrupt_while_a_temporary_is_made_leaves_none_behind(tmp_path, monkeypatch):
    # an interrupt's handler may run between any two lines (the signal reached a worker
    # thread, so blocking it here does not hold it back): whenever it lands, from the name
    # to the open file, the command line's cleanup finds what was made
    from terrain.core import outputs

    real_close = os.close
    for when in ("open", "close"):
        original = getattr(os, when)

        def interrupt(*args, real=original, when=when):
            fd = real(*args)  # the file exists (or is closed) when the interrupt lands
            if when == "open":
                real_close(fd)
            monkeypatch.undo()
            raise KeyboardInterrupt

        monkeypatch.setattr(outputs.os, when, interrupt)
        with pytest.raises(KeyboardInterrupt):
            with outputs.atomic_path(tmp_path / "out.tif") as tmp:
                tmp.write_bytes(b"never")
        outputs.remove_temporaries()
        assert not list(tmp_path.glob("*.partial")) and not (tmp_path / "out.tif").exists()
    assert os.close is real_close
