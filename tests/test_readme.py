"""Every command block of README.md, then of docs/cookbook.md, runs as written, in order.

The tracked files of this checkout (as they are in the working tree) are copied into a
temporary folder, as ``git clone`` would lay them out, with ``.venv`` a link to the virtual
environment running this test (nothing is installed) and ``../shared/data`` a link to the real
data where this checkout has it beside it. The blocks of the README and then those of the
cookbook run in order in one bash session, as a reader would type them in one terminal (so a
server started in the background by one block serves the next, and a variable set in one is
there in the next):

- ``sh`` blocks run with ``set -e``: the first failing command fails the test, which shows
  the block and its stderr; each block has a time limit;
- ``python`` blocks run as scripts with the environment's Python;
- ``toml`` blocks are parsed by the parser of what they document (a ``[population]`` by
  :meth:`terrain.craters.population.Population.from_toml`, a ``[sensor]``/``[motion]`` by the
  scenario parser);
- blocks that need the real data (``../shared/data``) run where it is present;
- ``make demo``, ``make test`` and ``make bench`` are not run here: ``make test`` is this
  suite and cannot run inside itself (CI runs it), ``make demo`` is the campaign that
  ``tests/test_demo.py`` runs in its reduced ``--quick`` form (the full one takes about 12
  minutes), and ``make bench`` measures speed, not correctness. Their targets are checked
  with ``make -n`` (the Makefile parses and each target's recipe names what the README says).

Every process the blocks start (a render server, a Dask scheduler and its workers) belongs
to the session's process group, which is killed when the test ends, whatever happens.

The other pages of ``docs/`` are reference, not a walk-through: their TOML blocks are parsed
like the cookbook's, and every relative link of every page must name a file that exists.
"""

from __future__ import annotations

import os
import re
import select
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
README = REPO / "README.md"
COOKBOOK = REPO / "docs" / "cookbook.md"
#: The walk-throughs whose blocks run, in this order, in one shell session.
WALKTHROUGHS = (README, COOKBOOK)
SHARED = REPO.parent / "shared"

#: Seconds one block may take (the first render builds the reduced demo's lunar stack).
BLOCK_TIMEOUT = 900
FENCE = re.compile(r"^```([\w-]*)[ \t]*\n(.*?)^```[ \t]*$", re.M | re.S)
LINK = re.compile(r"\]\(([^)\s]+)\)|<img [^>]*src=\"([^\"]+)\"")
DONE = "__README_BLOCK_DONE__"
MAKE_TARGETS = {"demo": "examples/demo.py", "test": "-m pytest", "bench": "benchmarks/run.py"}


def readme_blocks(text: str) -> list[tuple[str, str, int]]:
    """Return every fenced block of a Markdown page: (language, body, line number)."""
    return [(m.group(1), m.group(2), text.count("\n", 0, m.start()) + 1)
            for m in FENCE.finditer(text)]


def commands(body: str) -> list[str]:
    """Return the command lines of a shell block (comments and blank lines left out)."""
    return [line.strip() for line in body.replace("\\\n", " ").splitlines()
            if line.strip() and not line.strip().startswith("#")]


def fresh_clone(dest: Path) -> Path:
    """Copy the files a clone of this checkout would have (working-tree contents)."""
    clone = dest / "clone"
    try:
        listed = subprocess.run(
            ["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"],
            cwd=REPO, capture_output=True, check=True).stdout.decode().split("\0")
        files = [f for f in listed if f and (REPO / f).is_file()]
    except (OSError, subprocess.CalledProcessError):  # not a git checkout: the tree itself
        skip = {".venv", "demo-output", ".git", "__pycache__", ".pytest_cache", ".ruff_cache"}
        files = [str(p.relative_to(REPO)) for p in REPO.rglob("*")
                 if p.is_file() and not skip & set(p.relative_to(REPO).parts)]
    for name in files:
        target = clone / name
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(REPO / name, target)
    (clone / ".venv").symlink_to(Path(sys.prefix), target_is_directory=True)
    if (SHARED / "data").is_dir():
        (dest / "shared").symlink_to(SHARED.resolve(), target_is_directory=True)
    return clone


def parse_toml_block(body: str, where: Path) -> None:
    """Parse a TOML block with the parser of what it documents."""
    import tomllib

    data = tomllib.loads(body)
    path = where / "block.toml"
    path.write_text(body, encoding="utf-8")
    if "population" in data:
        from terrain.craters.population import Population

        Population.from_toml(path)
    elif {"sensor", "motion", "sun", "labels", "radar", "lidar", "events", "stars",
          "lamp"} & set(data):
        from render.scenario import parse_scenario

        asteroid = any(k in data.get("sun", {}) for k in ("orbit", "target"))
        scene = {"type": "asteroid", "body": "body.npz"} if asteroid else \
            {"type": "terrain", "stack": "stack"}
        parse_scenario({**data, "scene": scene,
                        "trajectory": {"type": "descent", "start_altitude": 100.0,
                                       "end_altitude": 10.0}}, path)
    elif "scene" in data:
        from render.scenario import SceneSpec

        SceneSpec.from_mapping(data["scene"])
    else:
        raise AssertionError(f"no parser known for this TOML block:\n{body}")


def check_make_targets(clone: Path, targets: list[str], tmp: Path) -> None:
    """``make -n``: the Makefile parses and each target runs what the README says."""
    out = subprocess.run(["make", "-n", f"VENV={sys.prefix}", f"DEMO_OUT={tmp / 'demo'}",
                          *targets], cwd=clone, capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stdout + out.stderr
    for target in targets:
        assert MAKE_TARGETS[target] in out.stdout, (target, out.stdout)


class Session:
    """One bash session in the clone that runs blocks in order (see the module docstring)."""

    def __init__(self, clone: Path, scratch: Path):
        env = dict(os.environ)
        env["PATH"] = f"{Path(sys.prefix) / 'bin'}{os.pathsep}{env.get('PATH', '')}"
        env["MPLBACKEND"] = "Agg"
        env.pop("PYTHONPATH", None)
        self.scratch = scratch
        self.proc = subprocess.Popen(
            ["bash", "--noprofile", "--norc"], cwd=clone, env=env, stdin=subprocess.PIPE,
            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, start_new_session=True)

    def run(self, script: str, n: int, text: str, where: str) -> None:
        """Run one block's script; fail with its text, its output and its stderr."""
        err = self.scratch / f"block_{n}.err"
        assert self.proc.stdin is not None and self.proc.stdout is not None
        self.proc.stdin.write(f"{{ {script}\n}} 2> {err} < /dev/null\necho {DONE} $?\n".encode())
        self.proc.stdin.flush()
        out: list[str] = []
        deadline = time.monotonic() + BLOCK_TIMEOUT
        fd = self.proc.stdout.fileno()
        pending = b""
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                self._fail(f"timed out after {BLOCK_TIMEOUT} s", text, where, out, err)
            ready, _, _ = select.select([fd], [], [], min(left, 5.0))
            if not ready:
                continue
            chunk = os.read(fd, 65536)
            if not chunk:  # the shell exited: a command failed under set -e
                self.proc.wait(timeout=30)
                self._fail(f"failed (exit {self.proc.returncode})", text, where, out, err)
            pending += chunk
            *lines, pending = pending.split(b"\n")
            for raw in lines:
                decoded = raw.decode(errors="replace")
                if decoded.startswith(DONE):
                    code = int(decoded.split()[1])
                    if code != 0:
                        self._fail(f"failed (exit {code})", text, where, out, err)
                    return
                out.append(decoded)

    def _fail(self, what: str, text: str, where: str, out: list[str], err: Path) -> None:
        stderr = err.read_text(errors="replace") if err.exists() else ""
        pytest.fail(f"block at {where} {what}:\n{text}\n--- stdout (end):\n"
                    + "\n".join(out[-30:]) + f"\n--- stderr (end):\n{stderr[-4000:]}",
                    pytrace=False)

    def close(self) -> None:
        """End the session and every process its blocks started (their process group)."""
        for sig in (signal.SIGTERM, signal.SIGKILL):
            try:
                os.killpg(self.proc.pid, sig)
            except ProcessLookupError:
                break
            try:
                self.proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                continue
            if sig == signal.SIGTERM:
                time.sleep(2)  # let children that outlive the shell take the signal too


def page_name(page: Path) -> str:
    """A page's path relative to the repository, as a failure names it."""
    return str(page.relative_to(REPO))


@pytest.mark.slow
def test_every_command_block_of_readme_and_cookbook_runs_in_order_from_a_fresh_clone(tmp_path):
    if shutil.which("bash") is None:
        pytest.skip("no bash here to run the README's shell blocks")
    pages = [(page, readme_blocks(page.read_text(encoding="utf-8"))) for page in WALKTHROUGHS]
    counts = {page_name(page): len(blocks) for page, blocks in pages}
    assert counts["README.md"] >= 2 and counts["docs/cookbook.md"] >= 15, \
        f"the code blocks were not found: {counts}"
    clone = fresh_clone(tmp_path)
    # decided once, with the clone: the data may appear beside the checkout while this runs
    have_data = (tmp_path / "shared" / "data").is_dir()
    scratch = tmp_path / "blocks"
    scratch.mkdir()
    session = Session(clone, scratch)
    ran, skipped = 0, []
    n = 0
    try:
        for page, blocks in pages:
            for lang, body, line in blocks:
                n += 1
                where = f"{page_name(page)}:{line}"
                if lang == "toml":
                    parse_toml_block(body, scratch)
                    continue
                if lang in ("sh", "bash", "shell"):
                    lines = commands(body)
                    makes = [c for c in lines if c.startswith("make ")]
                    if makes:
                        assert makes == lines, f"mixed make block at {where}:\n{body}"
                        check_make_targets(clone, [c.split()[1] for c in makes], tmp_path)
                        continue
                    if "../shared/data" in body and not have_data:
                        skipped.append(where)
                        continue
                    script_file = scratch / f"block_{n}.sh"
                    script_file.write_text("set -e -o pipefail\n" + body, encoding="utf-8")
                    session.run(f"source {script_file}", n, body, where)
                elif lang == "python":
                    script_file = scratch / f"block_{n}.py"
                    script_file.write_text(body, encoding="utf-8")
                    session.run(f"python {script_file}", n, body, where)
                else:
                    raise AssertionError(f"block at {where} is '{lang}': say how to "
                                         "check it in tests/test_readme.py")
                ran += 1
    finally:
        session.close()
    assert ran >= 12
    if skipped:
        print(f"blocks needing ../shared/data, absent here, not run: {skipped}")


@pytest.mark.parametrize("page", WALKTHROUGHS, ids=page_name)
def test_the_block_parser_sees_every_fence(page):
    """Every ``` line of a walk-through opens or closes a block the test runs or parses."""
    text = page.read_text(encoding="utf-8")
    fences = sum(1 for line in text.splitlines() if line.startswith("```"))
    blocks = readme_blocks(text)
    assert fences == 2 * len(blocks)
    assert {lang for lang, _, _ in blocks} <= {"sh", "python", "toml"}


def test_every_toml_block_of_the_docs_is_accepted_by_its_parser(tmp_path):
    """A TOML example anywhere in docs/ is one the parser of what it documents accepts."""
    parsed = 0
    for page in sorted((REPO / "docs").glob("*.md")):
        for lang, body, line in readme_blocks(page.read_text(encoding="utf-8")):
            if lang == "toml":
                try:
                    parse_toml_block(body, tmp_path)
                except Exception as exc:
                    pytest.fail(f"TOML block at {page_name(page)}:{line}: {exc}", pytrace=False)
                parsed += 1
    assert parsed >= 2, "the population and sensor examples were not found"


def heading_anchors(page: Path) -> set[str]:
    """The anchors GitHub gives a page's headings (lower case, punctuation dropped)."""
    return {re.sub(r"[^\w\- ]", "", line.lstrip("#").strip().lower()).replace(" ", "-")
            for line in page.read_text(encoding="utf-8").splitlines()
            if line.startswith("#")}


def test_every_relative_link_of_the_readme_and_docs_names_a_file_that_exists():
    """Links and pictures point at files of this repository that are there (and sections
    of its pages that are there)."""
    broken = []
    for page in [README, *sorted((REPO / "docs").glob("*.md"))]:
        for match in LINK.finditer(page.read_text(encoding="utf-8")):
            target, _, anchor = (match.group(1) or match.group(2)).partition("#")
            if not target or "://" in target or target.startswith("mailto:"):
                continue
            path = page.parent / target
            if not path.exists():
                broken.append(f"{page_name(page)}: {target}")
            elif anchor and path.suffix == ".md" and anchor not in heading_anchors(path):
                broken.append(f"{page_name(page)}: {target}#{anchor}")
    assert not broken, f"links to missing files or sections: {broken}"
