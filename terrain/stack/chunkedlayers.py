"""Layer stacks built chunk by chunk on Dask, bitwise equal to :func:`~.layers.build_stack`.

A layer stack whose layers do not fit in memory (a large base, or very large layers) is built
through the same path as the other chunked runs (:mod:`terrain.execution.chunked`): every stage of
every layer is a chunked run into a Zarr store, each chunk a pure function of its global
window, the seed and the stores of the stages before it. The stages of layer ``k`` are those
of the in-memory build, in its order:

``e`` (k = 0) the base with its gaps filled (:class:`terrain.execution.chunked.FillSource`), or
    (k > 0) the 2x expansion of the site window of the cratered layer ``k - 1``
    (:class:`StackExpandSource`, the local roughness map taken from the filled base);
``c`` the craters that belong to layer ``k`` (:class:`terrain.execution.chunked.CraterSource` with
the
    layer's crater table, :func:`terrain.stack.plan.layer_craters`);
``r`` the rocks the layer resolves (:class:`RockSource`), on every rock layer;
``f`` the agreement step, finest layer first: pixels inside layer ``k + 1`` take its
    co-located pixels (:class:`AgreeSource`).

The stages live in a work folder inside the stack folder (``.craterscape.work``); a build
that stops part way is resumed by giving the same command again (finished stages and chunks
are not computed again), so unlike an in-memory build, one that fails keeps its work folder
(and the folder's ``.craterscape.incomplete`` marker) until it is run again; a rerun with other
parameters starts the work folder anew. The stack's commit point is unchanged: the manifest,
written last, under the stack's edit lock. Memory per worker is bounded by a chunk and its
halo (the crater halo, the expansion's parent pixels, four chunks of the finer layer in the
agreement step); the client holds the layers' crater and rock catalogues, never a layer.
Layers small enough for memory are written as GeoTIFFs (``layer_NN.tif``) as in-memory
builds write them; larger ones stay Zarr DEMs (``layer_NN.zarr``), which
:func:`terrain.io.read_dem` and so :func:`terrain.stack.store.read_stack` open too.
"""

from __future__ import annotations

import hashlib
import json
import logging
import math
import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numba
import numpy as np
from affine import Affine

from terrain.core import memory
from terrain.core import metakeys as mk
from terrain.core.errors import InvalidDEMError, InvalidParameterError
from terrain.core.tile import Window
from terrain.execution.chunked import OnReaderGrid, filled_field, merge_chunk_catalogs
from terrain.stack.store import WORK
from terrain.surface.rocks import bilinear_at

if TYPE_CHECKING:
    from terrain.craters.catalog import CraterTable, RockCatalog
    from terrain.execution.chunked import DEMReader
    from terrain.fractal.roughness import ExpansionParameters
    from terrain.surface.rocks import RockModel

__all__ = ["WORK", "AgreeSource", "RockSource", "StackExpandSource", "build_stack_chunked",
           "stack_fits_in_memory"]

log = logging.getLogger(__name__)

_PLAN = "plan.json"


def stack_fits_in_memory(base_shape, shapes) -> bool:
    """Return whether :func:`terrain.stack.build.build_stack` may hold a stack in memory.

    The stack's layers are of ``shapes`` on a base of ``base_shape`` (its own memory estimate,
    and the input read once).
    """
    pixels = sum(h * w for h, w in shapes)
    need = pixels * (4 + 1) * 2 + base_shape[0] * base_shape[1] * (8 * 3 + 12)
    return need <= memory.available_bytes()


# --------------------------------------------------------------------------------------
# sources


def _stamp(reader) -> dict:
    from terrain.execution.chunked import input_stamp

    return input_stamp(reader)


@dataclass(frozen=True)
class StackExpandSource:
    """Layer ``level`` of a stack: the 2x expansion of a window of the layer above.

    Each chunk reads the parent pixels its window depends on (three either side, the
    parent layer's extent being the border, as in the in-memory build) and the part of the
    filled base the local roughness map needs, and calls :func:`terrain.fractal.expand.expand_level`
    with global positions, so it equals the same pixels of the in-memory layer.
    """

    parent: DEMReader  # reader of the cratered layer level - 1
    parent_origin: tuple  # global (row, col) of the parent's pixel (0, 0)
    origin: tuple  # global (row, col) of this layer's pixel (0, 0)
    size: int  # pixels per side of this layer
    transform: Affine
    level: int
    params: ExpansionParameters
    seed: int
    base: DEMReader | None = None  # reader of the filled base (local roughness map)
    law: Any = None  # terrain.core.presets.TerrainPreset whose slope law the level follows
    fill_target: float = 0.0  # its RMS gradient target (terrain.stack.slopelaw.fill_target)

    @property
    def shape(self):
        """The layer's (rows, cols)."""
        return (self.size, self.size)

    @property
    def crs(self):
        """The layer's CRS, that of the parent layer."""
        return self.parent.crs

    @property
    def nodata(self):
        """The parent layer's nodata value."""
        return self.parent.nodata

    has_catalog = False
    metadata: dict = field(default_factory=dict)

    def plan(self) -> dict:
        """Return what decides the layer's bytes, to match a resumed build."""
        from terrain.stack.slopelaw import law_record

        return dict(kind="stack-expand", input=_stamp(self.parent), level=self.level,
                    origin=list(self.origin), parent_origin=list(self.parent_origin),
                    params=self.params.as_dict(), seed=self.seed,
                    **({} if self.law is None else {"slope_law": law_record(self.law),
                                                    "fill_target": self.fill_target}))

    def compute(self, window: Window):
        """Compute the layer's heights in one window, equal to the in-memory layer's."""
        from terrain.fractal.expand import expand_level, parent_region
        from terrain.fractal.roughness import local_amplitude

        pr, pc = self.parent_origin
        ph, pw = self.parent.shape
        r0, c0 = self.origin[0] + window.row, self.origin[1] + window.col
        r1, c1 = r0 + window.height - 1, c0 + window.width - 1
        q0, q1 = parent_region(r0 - 2 * pr, r1 - 2 * pr, ph)
        p0, p1 = parent_region(c0 - 2 * pc, c1 - 2 * pc, pw)
        grid, _ = self.parent.read(Window(p0, q0, p1 - p0 + 1, q1 - q0 + 1))
        p = self.params
        sigmas = p.sigmas(self.level)
        amp, amp_origin, amp_level = None, (0, 0), 0
        if self.law is not None:
            amp, amp_origin = self._fill(r0, r1, c0, c1, float(sigmas[0]))
            amp_level = self.level - 1
        elif p.uses_local_map:
            base = filled_field(self.base)  # given whenever the roughness map is local
            ny, nx = base.shape
            scale = 0.5 ** self.level
            a0 = max(0, math.floor(r0 * scale) - 1)
            a1 = min(ny - 1, math.ceil(r1 * scale) + 1)
            b0 = max(0, math.floor(c0 * scale) - 1)
            b1 = min(nx - 1, math.ceil(c1 * scale) + 1)
            halo = p.local_box // 2 + 1
            g0, g1 = max(0, a0 - halo), min(ny - 1, a1 + halo)
            h0, h1 = max(0, b0 - halo), min(nx - 1, b1 + halo)
            sub, _ = base.read(Window(h0, g0, h1 - h0 + 1, g1 - g0 + 1))
            amp = local_amplitude(sub, p.base_sigma, p.local_box, (a0 - g0, a1 - g0),
                                  (b0 - h0, b1 - h0))
            amp_origin = (a0, b0)
        out = expand_level(grid, (pr + q0, pc + p0), (r0, r1), (c0, c1), level=self.level,
                           sigmas=sigmas, weights=p.weights(self.level),
                           taps=p.taps(self.level), seed=self.seed, amplitude=amp,
                           amplitude_origin=amp_origin, amplitude_level=amp_level)
        return out, None

    def _fill(self, r0, r1, c0, c1, sigma):
        """Return the slope law's fill map on the parent pixels child rows r0-r1, cols c0-c1 read.

        The expansion reads the map three child pixels beyond the window (its first pass);
        the parent is read a box's halo further, clipped at the parent layer's edges, so the
        values equal those of the whole parent (:func:`terrain.stack.slopelaw.fill_amplitude`).
        """
        from terrain.stack.slopelaw import fill_amplitude, map_halo

        pr, pc = self.parent_origin
        ph, pw = self.parent.shape
        g0 = max(0, (r0 - 3) // 2 - pr)
        g1 = min(ph - 1, -((-(r1 + 3)) // 2) - pr)
        h0 = max(0, (c0 - 3) // 2 - pc)
        h1 = min(pw - 1, -((-(c1 + 3)) // 2) - pc)
        halo = map_halo()
        w0, w1 = max(0, g0 - halo), min(ph - 1, g1 + halo)
        v0, v1 = max(0, h0 - halo), min(pw - 1, h1 + halo)
        grid, _ = self.parent.read(Window(v0, w0, v1 - v0 + 1, w1 - w0 + 1))
        amp = fill_amplitude(grid, float(self.parent.transform.a), self.fill_target, sigma,
                             rows=(g0 - w0, g1 - w0), cols=(h0 - v0, h1 - v0))
        return amp, (pr + g0, pc + h0)


@numba.njit(cache=True)
def _base_levels_at(T, tr0, tc0, ny, nx, x0, y0, res, xs, ys, out):
    for i in range(xs.size):
        out[i] = bilinear_at(T, tr0, tc0, ny, nx, x0, y0, res, xs[i], ys[i])


@dataclass(frozen=True)
class RockSource(OnReaderGrid):
    """The rocks a layer resolves, stood on it chunk by chunk (:func:`~.rocks.rock_heights`).

    A chunk enumerates the rocks that may touch it (position-keyed, so the same rocks as the
    whole layer's), takes each one's base level from the layer around its centre and raises
    its pixels to the rocks' tops. The chunk's marker keeps the rocks centred in it (the
    layer's rock catalogue rows).
    """

    reader: DEMReader  # the cratered layer
    rocks: RockModel
    seed: int
    craters: CraterTable | None = None  # craters raising the rock density, or None

    has_catalog = False
    metadata: dict = field(default_factory=dict)

    def plan(self) -> dict:
        """Return what decides the layer's bytes, to match a resumed build."""
        return dict(kind="stack-rocks", input=_stamp(self.reader), rocks=self.rocks.as_dict(),
                    seed=self.seed, craters=None if self.craters is None
                    else hashlib.sha256(
                        np.ascontiguousarray(self.craters.uid).tobytes()).hexdigest())

    def compute(self, window: Window):
        """Stand the rocks that touch one window on the layer; keep those centred in it."""
        from terrain.surface.rocks import MIN_ROCK_PIXELS, rasterise_rocks

        t = self.transform
        res = float(t.a)
        ny, nx = self.shape
        left, top = t @ (window.col, window.row)
        right, bottom = t @ (window.col + window.width, window.row + window.height)
        table = self.rocks.generate(self.seed, (left, bottom, right, top),
                                    min_diameter=MIN_ROCK_PIXELS * res, craters=self.craters)
        drawn = table.diameter >= MIN_ROCK_PIXELS * res
        rows = np.ascontiguousarray(table.rows[drawn])
        xs, ys = np.ascontiguousarray(table.x[drawn]), np.ascontiguousarray(table.y[drawn])
        z0 = np.empty(len(rows))
        if len(rows):
            cs = np.clip((xs - t.c) / res - 0.5, 0, nx - 1)
            rs = np.clip((t.f - ys) / res - 0.5, 0, ny - 1)
            g0 = max(0, int(np.floor(rs.min())) - 1)
            g1 = min(ny, int(np.floor(rs.max())) + 3)
            h0 = max(0, int(np.floor(cs.min())) - 1)
            h1 = min(nx, int(np.floor(cs.max())) + 3)
            around, valid = self.reader.read(Window(h0, g0, h1 - h0, g1 - g0))
            if not valid.all():
                raise InvalidDEMError("a chunked stack's rock layer has unknown pixels; build "
                                      "this stack in memory")
            _base_levels_at(np.ascontiguousarray(around), g0, h0, ny, nx, float(t.c),
                            float(t.f), res, xs, ys, z0)
        heights, valid = self.reader.read(window)
        z = heights.astype(np.float64)
        rasterise_rocks(z, window.row, window.col, float(t.c), float(t.f), res, rows, z0)
        out = z.astype(np.float32)
        out[~valid] = np.nan
        # catalogue rows: rocks centred in this chunk (the layer's edges closed)
        last_col = window.col + window.width == nx
        last_row = window.row + window.height == ny
        lo_x = (xs >= left) & ((xs < right) | (last_col & (xs <= right)))
        lo_y = (ys <= top) & ((ys > bottom) | (last_row & (ys >= bottom)))
        mine = lo_x & lo_y
        uid = table.uid[drawn]
        return out, dict(uid=uid[mine], rows=rows[mine], z0=z0[mine])


@dataclass(frozen=True)
class ReposeSource(OnReaderGrid):
    """A layer's slopes relaxed to the angle of repose (:func:`terrain.stack.build.relax_layer`).

    Each chunk relaxes its window grown by the relaxation's halo (one cell per sweep, so the
    window equals the whole layer's result) with the same fixed cells as the in-memory build:
    those co-located with a known pixel of the input base, and those inside fresh craters.
    The halo is ``iterations + 1`` cells (1025 by default): a chunk of the default 2048 cells
    inside a larger layer reads up to 4 times its area (a layer no larger than a chunk reads
    only itself), and its sweeps skip the grown window's settled blocks, so it repeats its
    neighbours' sweeps only where the ground within a halo of its edges still moves.
    """

    reader: DEMReader  # the layer after its craters
    base: DEMReader  # the input base, whose valid pixels are the known heights
    level: int
    origin: tuple  # global (row, col) of the layer's pixel (0, 0)
    repose: Any  # terrain.surface.repose.Repose
    craters: tuple  # (x, y, diameter, age) arrays of the craters of every layer so far

    has_catalog = False
    metadata: dict = field(default_factory=dict)

    def plan(self) -> dict:
        """Return what decides the layer's bytes, to match a resumed build."""
        digest = hashlib.sha256(b"".join(np.ascontiguousarray(a, dtype=np.float64).tobytes()
                                         for a in self.craters)).hexdigest()
        return dict(kind="stack-repose", input=_stamp(self.reader), base=_stamp(self.base),
                    level=self.level, origin=list(self.origin),
                    repose=self.repose.as_dict(), craters=digest)

    def compute(self, window: Window):
        """Relax one window of the layer, equal to the same pixels of the whole layer."""
        from terrain.stack.build import fixed_cells
        from terrain.surface.repose import relax_to_repose

        ny, nx = self.shape
        halo = self.repose.iterations + 1
        r0, c0 = max(0, window.row - halo), max(0, window.col - halo)
        r1 = min(ny, window.row + window.height + halo)
        c1 = min(nx, window.col + window.width + halo)
        grown = Window(c0, r0, c1 - c0, r1 - r0)
        heights, valid = self.reader.read(grown)
        step = 2 ** self.level
        g0, g1 = (self.origin[0] + r0) // step, (self.origin[0] + r1 - 1) // step + 1
        h0, h1 = (self.origin[1] + c0) // step, (self.origin[1] + c1 - 1) // step + 1
        bny, bnx = self.base.shape
        g1, h1 = min(g1, bny), min(h1, bnx)
        _, known = self.base.read(Window(h0, g0, max(1, h1 - h0), max(1, g1 - g0)))
        fixed = fixed_cells(heights.shape, self.level, (self.origin[0] + r0, self.origin[1] + c0),
                            known, (g0, h0))
        t = self.transform @ Affine.translation(c0, r0)
        fresh = self.repose.fresh_mask(heights.shape, t, *self.craters)
        z, _ = relax_to_repose(heights, float(self.transform.a), self.repose.angle_deg,
                               movable=~(fixed | fresh), iterations=self.repose.iterations)
        a, b = window.row - r0, window.col - c0
        out = z[a:a + window.height, b:b + window.width].astype(heights.dtype)
        out[~valid[a:a + window.height, b:b + window.width]] = np.nan
        return out, None


@dataclass(frozen=True)
class AgreeSource(OnReaderGrid):
    """The agreement step of a layer.

    Pixels of a layer inside the next finer layer take its co-located pixels (its even rows
    and columns), as :func:`terrain.stack.build.build_stack` does.
    """

    reader: DEMReader  # this layer (after craters and rocks)
    finer: DEMReader | None = None  # the next finer layer's final store, or None
    window_in_self: tuple | None = None  # (col, row, size, size) of the finer layer in this one
    metadata: dict = field(default_factory=dict)

    has_catalog = False

    def plan(self) -> dict:
        """Return what decides the layer's bytes, to match a resumed build."""
        return dict(kind="stack-agree", input=_stamp(self.reader),
                    finer=None if self.finer is None else _stamp(self.finer),
                    window=None if self.window_in_self is None else list(self.window_in_self),
                    metadata=self.metadata)

    def compute(self, window: Window):
        """Compute one window of the layer with the finer layer's pixels where it lies."""
        heights, _ = self.reader.read(window)
        if self.finer is None:
            return heights, None
        col, row, size, _ = filled_field(self.window_in_self)  # given with ``finer``
        a0, a1 = max(window.row, row), min(window.row + window.height, row + size)
        b0, b1 = max(window.col, col), min(window.col + window.width, col + size)
        if a0 < a1 and b0 < b1:
            fine, _ = self.finer.read(Window(2 * (b0 - col), 2 * (a0 - row),
                                             2 * (b1 - b0) - 1, 2 * (a1 - a0) - 1))
            heights = heights.copy()
            heights[a0 - window.row:a1 - window.row, b0 - window.col:b1 - window.col] = \
                fine[::2, ::2]
        return heights, None


@dataclass(frozen=True)
class _Layer:
    """What :func:`terrain.stack.store.stack_manifest` reads of a layer that is not in memory."""

    shape: tuple
    transform: Affine
    crs: object

    @property
    def resolution(self) -> float:
        """The pixel spacing in metres."""
        return float(self.transform.a)

    @property
    def bounds(self):
        """The layer's (left, bottom, right, top) in map metres."""
        from terrain.stack.plan import layer_bounds

        return layer_bounds(self.shape, self.transform)


# --------------------------------------------------------------------------------------
# the build


def _stage(name, source, work: Path, *, chunk, client, progress, reports, metadata=None):
    """Run one stage into ``work/name.zarr`` unless it is complete; return its store."""
    from terrain.core.zarrstore import ZarrDEM
    from terrain.execution.chunked import run

    path = work / f"{name}.zarr"
    if path.exists():
        store = ZarrDEM(path)
        if store.complete:
            ny, nx = store.grid
            reports[name] = dict(total=ny * nx, computed=0, skipped=ny * nx)
            return store
    report = run(source, path, chunk=chunk, client=client,
                 progress=None if progress is None else progress(name),
                 metadata=metadata)
    reports[name] = dict(total=report.total, computed=report.computed, skipped=report.skipped,
                         computed_chunks=list(report.computed_chunks), report=report)
    return ZarrDEM(path)


def _work_folder(outdir: Path, plan: dict) -> Path:
    """Return the work folder of this build: kept when it holds the same build, else anew."""
    work = outdir / WORK
    text = json.dumps(plan, sort_keys=True, default=str)
    if work.exists():
        try:
            same = (work / _PLAN).read_text(encoding="utf-8") == text
        except OSError:
            same = False
        if same:
            log.info("resuming the chunked stack build in %s", work)
            return work
        log.warning("the work folder %s holds another build; starting again", work)
        shutil.rmtree(work)
    work.mkdir()
    (work / _PLAN).write_text(text, encoding="utf-8")
    return work


def build_stack_chunked(reader, outdir, site, *, levels: int, layer_size: int = 1025,
                        seed: int = 0, population=None, model=None, params=None, estimate=None,
                        min_crater_pixels: float | None = None, rocks=None, chunk: int = 1024,
                        client=None, progress=None, halo: int = 256,
                        geotiff_pixels: int | None = None, info=None, inputs=(),
                        keep_known: bool = False, repose=None, slope_law=None) -> dict:
    """Build a layer stack chunk by chunk into ``outdir`` and commit it (manifest last).

    Parameters are those of :func:`terrain.stack.build.build_stack`, with the base given as a
    windowed reader (:func:`terrain.execution.chunked.open_reader`), and

    estimate : dict, optional
        Without ``params``: keywords of :func:`terrain.execution.chunked.estimate_parameters`
        (``fractal_dimension``, ``height_scale``, ``local_box``, ``regolith``) for the filled
        base.
    chunk : int
        Chunk side in pixels of every stage.
    client : dask.distributed.Client, optional
        Cluster to run on; None runs the chunks in this process.
    progress : callable, optional
        ``progress(stage)`` returns the ``progress(done, total, rate)`` of
        :func:`terrain.execution.chunked.run` for one stage (e.g. ``"e1"``, ``"c1"``).
    halo : int
        Halo of the base's gap filling (:class:`terrain.execution.chunked.FillSource`).
    geotiff_pixels : int, optional
        Layers of at most this many pixels are written as GeoTIFFs, larger ones stay Zarr
        (default: what fits in a quarter of the available memory).
    slope_law : terrain.core.presets.TerrainPreset, optional
        As :func:`terrain.stack.build.build_stack`'s; without ``params`` and with neither
        ``fractal_dimension`` nor ``height_scale`` in ``estimate``, the law's parameters.
    info : dict, optional
        Provenance added to the manifest.

    Returns
    -------
    dict
        ``files`` (layer files), ``craters`` and ``rocks`` (counts), ``stages`` (per stage:
        chunks in total, computed by this run and already written).
    """
    from terrain.core.rng import check_seed
    from terrain.craters.cratering import CraterModel
    from terrain.execution.chunked import CraterSource, FillSource
    from terrain.stack.plan import MIN_CRATER_PIXELS, GridShape, layer_craters, layer_plan
    from terrain.stack.slopelaw import law_record
    from terrain.stack.store import INCOMPLETE, prepare_folder, stack_lock

    seed = check_seed(seed)
    if isinstance(levels, bool) or not isinstance(levels, (int, np.integer)) or levels < 0:
        raise InvalidParameterError(f"levels must be a non-negative integer; got {levels!r}")
    min_crater_pixels = MIN_CRATER_PIXELS if min_crater_pixels is None else min_crater_pixels
    if not min_crater_pixels > 0:
        raise InvalidParameterError(
            f"min crater pixels must be positive; got {min_crater_pixels}")
    model = model or CraterModel()
    outdir = Path(outdir)
    from terrain.stack.plan import layer_bounds, site_in_bounds

    base_shape = GridShape(tuple(reader.shape), reader.transform)
    x, y = site_in_bounds(site, layer_bounds(base_shape.shape, reader.transform))
    windows, origins, shapes, transforms = layer_plan(base_shape, (x, y), levels, layer_size)

    plan = [(layer_bounds(sh, tr), tr.a) for sh, tr in zip(shapes, transforms, strict=True)]
    if geotiff_pixels is None:
        geotiff_pixels = int(memory.available_bytes() / 4 / 12)

    missing = _count_unknown(reader, chunk)
    fill = FillSource(reader, halo, seed) if missing else None
    if fill is not None:
        fill.check(chunk)  # a gap larger than the halo is refused before anything is written
    prepare_folder(outdir, inputs=inputs, keep=(WORK,))
    outdir.mkdir(parents=True, exist_ok=True)
    with stack_lock(outdir):
        if (outdir / "manifest.json").exists():  # another build finished here meanwhile
            raise InvalidParameterError(
                f"output folder '{outdir}' received a stack from another command meanwhile; "
                "give a new folder")
        (outdir / INCOMPLETE).write_text("a craterscape layer stack is being written here\n",
                                         encoding="utf-8")
        work = _work_folder(outdir, dict(
            input=_stamp(reader), site=[x, y], levels=levels, layer_size=layer_size, seed=seed,
            population=population.as_dict() if population else None, model=model.as_dict(),
            params=params.as_dict() if params else None, estimate=estimate,
            min_crater_pixels=min_crater_pixels,
            rocks=rocks.as_dict() if rocks else None, chunk=chunk, halo=halo,
            **({"keep_known": True} if keep_known else {}),
            **({"repose": repose.as_dict()} if repose is not None else {}),
            **({"slope_law": law_record(slope_law)} if slope_law is not None else {})))
        common = dict(chunk=chunk, client=client, progress=progress, reports={})
        reports = common["reports"]

        # layer 0: the base, gaps filled
        e = _stage("e0", fill, work, **common) if fill is not None else reader
        base = e
        params = params or _parameters(reader, base, estimate or {}, slope_law)
        cratered: list = []
        catalogs: list = []
        tables: list = []
        factor = model.footprint_factor
        for k in range(levels + 1):
            if k > 0:
                window = windows[k]
                assert window is not None  # every layer above the base has one
                col, row, size, _ = window
                target = (0.0 if slope_law is None
                          else _fill_target(cratered[k - 1], slope_law, chunk))
                e = _stage(f"e{k}", StackExpandSource(
                    cratered[k - 1], origins[k - 1], origins[k], shapes[k][0], transforms[k],
                    k, params, seed, base, slope_law, target), work, **common)
            table = None
            if population is not None:
                table = layer_craters(population, seed, plan, k, factor, min_crater_pixels)
                if not len(table):
                    table = None
            if table is not None:
                keep = 2**k if keep_known and k > 0 else 1
                store = _stage(f"c{k}", CraterSource(e, table, seed, model, keep, origins[k]),
                               work, **common)
                catalogs.append(merge_chunk_catalogs(store).with_layer(k))
                e = store
            tables.append(table)
            log.info("layer %d: %d craters", k, 0 if table is None else len(table))
            if repose is not None:
                parts = [c for c in catalogs if len(c.x_m)]
                craters = tuple(np.concatenate([getattr(c, n) for c in parts]) if parts
                                else np.empty(0) for n in ("x_m", "y_m", "diameter_m", "age_gyr"))
                e = _stage(f"p{k}", ReposeSource(e, reader, k, origins[k], repose, craters),
                           work, **common)
            cratered.append(e)

        rock_rows: dict = {}
        rock_layers = []
        if rocks is not None:
            from terrain.surface.rocks import MIN_ROCK_PIXELS

            rock_layers = [k for k in range(levels + 1)
                           if MIN_ROCK_PIXELS * plan[k][1] < rocks.dmax]
            craters_for_rocks = None
            if rock_layers and rocks.craters and population is not None:
                dmin = max(5.0 * rocks.regolith_m, population.dmin)
                if dmin < population.dmax:
                    craters_for_rocks = population.generate(
                        seed, plan[rock_layers[0]][0], margin=rocks.crater_margin,
                        min_diameter=dmin)
            for k in rock_layers:
                store = _stage(f"r{k}", RockSource(cratered[k], rocks, seed, craters_for_rocks),
                               work, **common)
                for i in range(store.grid[0]):
                    for j in range(store.grid[1]):
                        part = store.chunk_catalog(i, j)
                        for uid, rws, z0 in zip(part["uid"], part["rows"], part["z0"],
                                                strict=True):
                            first = rock_rows[int(uid)][2] if int(uid) in rock_rows else k
                            rock_rows[int(uid)] = (rws, z0, first)
                cratered[k] = store
                log.info("layer %d: rocks", k)

        finals: list = [None] * (levels + 1)  # one store per layer, finest first
        for k in range(levels, -1, -1):
            meta = _layer_metadata(reader, k, tables[k], seed, model)
            source = AgreeSource(cratered[k], finals[k + 1] if k < levels else None,
                                 windows[k + 1] if k < levels else None, meta)
            finals[k] = _stage(f"f{k}", source, work, **common,
                               metadata={**meta, mk.LAYER: str(k)})

        # commit: layer files, catalogues, then the manifest
        from terrain.core.outputs import atomic_path
        from terrain.stack.model import CATALOG, LayerStack, layer_records, merge_catalogs
        from terrain.stack.store import MANIFEST, READERS_LOCK, ROCK_CATALOG, stack_manifest

        files = []
        for k, store in enumerate(finals):
            if shapes[k][0] * shapes[k][1] <= geotiff_pixels:
                from terrain.io import read_dem, write_dem

                name = f"layer_{k:02d}.tif"
                tile = read_dem(store.path)
                meta = dict(tile.metadata)
                meta.pop(mk.SOURCE, None)
                write_dem(tile.replace(metadata=meta), outdir / name)
            else:
                name = f"layer_{k:02d}.zarr"
                target = outdir / name
                if target.exists():
                    shutil.rmtree(target)
                store.path.rename(target)
            files.append(name)
        catalog = merge_catalogs(catalogs)
        info = dict(info or {})
        info.update(base_filled_pixels=int(missing))
        rock_catalog = None
        if rocks is not None:
            rock_catalog = _rock_catalog(rock_rows)
            info.update(rocks=rocks.as_dict(), rock_catalog=ROCK_CATALOG,
                        rock_counts=np.bincount(rock_catalog.layer,
                                                minlength=levels + 1).tolist())
        info.update(seed=seed, site=[x, y], levels=levels, layer_size=layer_size,
                    expansion=params.as_dict(), min_crater_pixels=min_crater_pixels,
                    population=population.as_dict() if population else None,
                    crater_model=model.as_dict(), chunked=dict(chunk=chunk, halo=halo),
                    **({"repose": repose.as_dict()} if repose is not None else {}),
                    **({"slope_law": law_record(slope_law)} if slope_law is not None else {}))
        layers = [_Layer(sh, tr, reader.crs) for sh, tr in zip(shapes, transforms, strict=True)]
        stack = LayerStack(layer_records(layers, windows, origins), catalog, info, rock_catalog)
        with atomic_path(outdir / CATALOG) as tmp:
            catalog.to_csv(tmp)
        if rock_catalog is not None:
            with atomic_path(outdir / ROCK_CATALOG) as tmp:
                rock_catalog.to_csv(tmp)
        (outdir / READERS_LOCK).touch()
        manifest = stack_manifest(stack, files)
        manifest["catalog"] = CATALOG
        with atomic_path(outdir / MANIFEST) as tmp:
            tmp.write_text(json.dumps(manifest, indent=2, sort_keys=True), encoding="utf-8")
        (outdir / INCOMPLETE).unlink()
        shutil.rmtree(work, ignore_errors=True)
    stages = {name: {k: v for k, v in r.items() if k != "report"}
              for name, r in reports.items()}
    return dict(files=files, craters=len(catalog),
                rocks=None if rock_catalog is None else len(rock_catalog),
                stages=stages, finest_resolution=float(plan[-1][1]))


def _fill_target(parent, law, chunk: int) -> float:
    """Return a level's fill target from its parent read window by window, as in memory."""
    from terrain.stack.slopelaw import fill_target, gradient_sample, map_halo

    ny, nx = parent.shape
    res = float(parent.transform.a)
    halo = map_halo()
    parts = []
    for r0 in range(0, ny, chunk):
        for c0 in range(0, nx, chunk):
            r1, c1 = min(ny, r0 + chunk), min(nx, c0 + chunk)
            w0, w1 = max(0, r0 - halo), min(ny, r1 + halo)
            v0, v1 = max(0, c0 - halo), min(nx, c1 + halo)
            grid, _ = parent.read(Window(v0, w0, v1 - v0, w1 - w0))
            parts.append(gradient_sample(grid, res, (r0, c0), rows=(r0 - w0, r1 - 1 - w0),
                                         cols=(c0 - v0, c1 - 1 - v0)))
    return fill_target(np.concatenate(parts), res, law)


def _parameters(reader, base, estimate: dict, slope_law):
    """Return the expansion parameters: the slope law's (as in memory), else measured."""
    from terrain.execution.chunked import estimate_parameters
    from terrain.fractal.regolith import RegolithLaw
    from terrain.stack.slopelaw import law_parameters

    if slope_law is not None and estimate.get("fractal_dimension") is None \
            and estimate.get("height_scale") is None:
        regolith = estimate.get("regolith")
        if isinstance(regolith, dict):
            regolith = RegolithLaw(**regolith)
        return law_parameters(slope_law, float(reader.resolution),
                              max(2, max(reader.shape) - 1), regolith=regolith)
    return estimate_parameters(base, **estimate)


def _count_unknown(reader, chunk: int) -> int:
    """Unknown pixels of the input, read chunk by chunk."""
    ny, nx = reader.shape
    n = 0
    for r0 in range(0, ny, chunk):
        for c0 in range(0, nx, chunk):
            _, valid = reader.read(Window(c0, r0, min(chunk, nx - c0), min(chunk, ny - r0)))
            n += int(valid.size - np.count_nonzero(valid))
    return n


def _layer_metadata(reader, k: int, table, seed: int, model) -> dict:
    """Return the tags the in-memory build gives layer ``k``.

    The input's on the base, the craters' where the layer has craters.
    """
    from terrain.craters.cratering import describe_craters

    meta = {str(a): str(b) for a, b in reader.metadata.items()} if k == 0 else {}
    if table is not None:
        meta.update({mk.SEED: str(seed),
                     mk.CRATER_MODEL: json.dumps(model.as_dict(), sort_keys=True),
                     mk.CRATERS: json.dumps(describe_craters(table), sort_keys=True)})
    return meta


def _rock_catalog(rows: dict) -> RockCatalog:
    """Return the stack's rock catalogue, as :func:`terrain.stack.build._add_layer_rocks` does."""
    from terrain.surface.rocks import _OUT, RockTable, rock_catalog

    if not rows:
        return rock_catalog(RockTable(np.empty((0, _OUT)), np.empty(0, np.uint64)),
                            np.empty(0), np.empty(0, np.int64))
    uids = sorted(rows)
    table = RockTable(np.array([rows[u][0] for u in uids]), np.array(uids, dtype=np.uint64))
    z0 = np.array([rows[int(u)][1] for u in table.uid])
    first = np.array([rows[int(u)][2] for u in table.uid], dtype=np.int64)
    return rock_catalog(table, z0, first)

