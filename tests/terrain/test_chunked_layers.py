"""Layer stacks built chunk by chunk on Dask equal the in-memory build, layer by layer.

A real ``LocalCluster`` of 2 worker processes; the stack is small (33-pixel layers, 16-pixel
chunks) so the module runs in seconds once the workers are up.
"""

import json
import time

import numpy as np
import pytest
import rasterio

from terrain.core.tile import DEMTile
from terrain.core.zarrstore import ZarrDEM
from terrain.craters.population import Population
from terrain.execution.chunked import dask_client, open_reader
from terrain.fractal.synthetic import synthesize_tile
from terrain.io import read_dem, write_dem
from terrain.stack.build import build_stack
from terrain.stack.chunkedlayers import build_stack_chunked
from terrain.stack.store import INCOMPLETE, read_stack, write_stack
from terrain.surface.rocks import RockModel
from tests.cli_helpers import one_line_error
from tests.cli_helpers import run as cli

POP = Population(dmin=1.0, dmax=60.0, density=3e5, max_age=2.0)
ROCKS = RockModel.from_spec("golombek-rapp-mars:k=0.3,dmin=0.25")
SITE = (130.0, 130.0)
ARGS = dict(levels=3, layer_size=33, seed=3)


@pytest.fixture(scope="module")
def client():
    with dask_client(2) as c:
        yield c


@pytest.fixture(scope="module")
def base_path(tmp_path_factory):
    """A 65 x 65 DEM at 4 m in a projected CRS with a small gap and nodata -9999."""
    tile = synthesize_tile(65, resolution=4.0, relief=3.0, seed=2).tile
    h = tile.heights.copy()
    h[40:44, 10:15] = np.nan
    tile = DEMTile(h, np.isfinite(h), tile.transform,
                   rasterio.crs.CRS.from_epsg(32633).to_wkt(), -9999.0, {})
    path = tmp_path_factory.mktemp("stack") / "base.tif"
    write_dem(tile, path)
    return path


@pytest.fixture(scope="module")
def in_memory(base_path, tmp_path_factory):
    stack = build_stack(read_dem(base_path, exact=True), SITE, population=POP, rocks=ROCKS,
                        **ARGS)
    out = write_stack(stack, tmp_path_factory.mktemp("mem") / "stack")
    return read_stack(out)


def assert_same_stack(a, b):
    assert len(a.tiles) == len(b.tiles)
    for k, (ta, tb) in enumerate(zip(a.tiles, b.tiles, strict=True)):
        assert ta.shape == tb.shape, k
        assert np.array_equal(ta.heights, tb.heights), k  # bitwise, NaN-free layers
        assert ta.transform == tb.transform and ta.crs == tb.crs, k
    assert a.windows == b.windows and a.origins == b.origins
    for name, column in a.catalog.as_dict().items():
        assert np.array_equal(getattr(b.catalog, name), column), name
    for name, column in a.rocks.as_dict().items():
        assert np.array_equal(getattr(b.rocks, name), column, equal_nan=True), name


@pytest.mark.slow
def test_chunked_stack_on_two_workers_equals_the_in_memory_stack(in_memory, base_path, client,
                                                                  tmp_path):
    # the stack has what the comparison must cover: craters and rocks on several layers
    assert len(set(in_memory.catalog.layer.tolist())) >= 3
    assert len(set(in_memory.rocks.layer.tolist())) >= 2
    assert in_memory.info["base_filled_pixels"] == 20
    out = tmp_path / "chunked"
    result = build_stack_chunked(open_reader(base_path), out, SITE, population=POP,
                                 rocks=ROCKS, chunk=16, client=client, geotiff_pixels=40 * 40,
                                 **ARGS)
    # the 65 x 65 base is too big for the GeoTIFF limit given: it stays a Zarr DEM
    assert result["files"] == ["layer_00.zarr", "layer_01.tif", "layer_02.tif",
                               "layer_03.tif"]
    chunked = read_stack(out)
    assert_same_stack(in_memory, chunked)
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["base_filled_pixels"] == 20
    assert not (out / INCOMPLETE).exists() and not (out / ".craterscape.work").exists()
    # a layer still agrees with the finer one: coarse pixels are the co-located fine ones
    col, row, size, _ = chunked.windows[3]
    assert np.array_equal(chunked.tiles[2].heights[row:row + size, col:col + size],
                          chunked.tiles[3].heights[::2, ::2])


class Interrupt(Exception):
    pass


@pytest.mark.slow
def test_an_interrupted_build_resumes_without_computing_a_finished_chunk(in_memory, base_path,
                                                                         client, tmp_path):
    out = tmp_path / "resumed"

    def stop_in_stage(name):
        def update(done, total, rate):
            if name == "e2" and done == 3:
                raise Interrupt  # stopped part way through the expansion of layer 2
        return update

    with pytest.raises(Interrupt):
        build_stack_chunked(open_reader(base_path), out, SITE, population=POP, rocks=ROCKS,
                            chunk=16, client=client, progress=stop_in_stage, **ARGS)
    assert (out / INCOMPLETE).exists() and not (out / "manifest.json").exists()
    with pytest.raises(Exception, match="interrupted stack build"):
        read_stack(out)
    time.sleep(0.5)  # let the tasks still running when it stopped finish (or not)
    written = ZarrDEM(out / ".craterscape.work" / "e2.zarr").done_chunks()
    assert len(written) >= 3
    result = build_stack_chunked(open_reader(base_path), out, SITE, population=POP,
                                 rocks=ROCKS, chunk=16, client=client, **ARGS)
    stages = result["stages"]
    for name in ("e0", "c0", "e1", "c1"):  # finished before the interruption
        assert stages[name]["computed"] == 0 and stages[name]["skipped"] == stages[name]["total"]
    again = {tuple(c) for c in stages["e2"]["computed_chunks"]}
    assert not again & written  # no written chunk computed again ...
    assert len(again | written) == stages["e2"]["total"]  # ... and every other one computed
    assert_same_stack(in_memory, read_stack(out))


@pytest.mark.slow
def test_enhance_cli_runs_chunked_on_request_and_equals_the_in_memory_stack(base_path,
                                                                            tmp_path):
    common = ["--site", "130,130", "--levels", 2, "--layer-size", 33, "--seed", 3,
              "--dmin", 1, "--dmax", 60, "--density", 3e5, "--rocks",
              "golombek-rapp-mars:k=0.3,dmin=0.25"]
    mem = tmp_path / "mem"
    r = cli("terrain", "enhance", base_path, "-o", mem, *common)
    assert r.exit_code == 0, r.output
    chunked = tmp_path / "chunked"
    r = cli("terrain", "enhance", base_path, "-o", chunked, *common, "--chunk", 16)
    assert r.exit_code == 0, r.output
    assert "chunked:" in r.output
    a, b = read_stack(mem), read_stack(chunked)
    assert_same_stack(a, b)
    # too big for the memory there is: built out of core instead of refused, the base (too
    # big for one read) kept as a Zarr layer, the layers that fit as GeoTIFFs
    ooc = tmp_path / "ooc"
    r = cli("terrain", "enhance", base_path, "-o", ooc, *common,
            env={"CRATERSCAPE_MEMORY_LIMIT": "150K"})
    assert r.exit_code == 0, r.output
    assert "does not fit in memory" in r.output
    manifest = json.loads((ooc / "manifest.json").read_text())
    assert [e["file"] for e in manifest["layers"]] == ["layer_00.zarr", "layer_01.tif",
                                                        "layer_02.tif"]
    assert_same_stack(a, read_stack(ooc))
    # and it is edited like any stack: the changed Zarr layer is replaced by a new version
    r = cli("terrain", "replace-crater", ooc, "--at", "130,130", "--diameter", 6)
    assert r.exit_code == 0, r.output
    edited = read_stack(ooc)
    assert not (ooc / "layer_00.zarr").exists()
    assert not np.array_equal(edited.tiles[0].heights, a.tiles[0].heights)
    one_line_error(cli("terrain", "enhance", base_path, "-o", tmp_path / "x", *common,
                       "--chunk", 16, "--despike", 4), "--despike")
    one_line_error(cli("terrain", "enhance", base_path, "-o", tmp_path / "y", *common,
                       "--chunk", 16, "--halo", 1), "halo")
    assert not (tmp_path / "x").exists() and not (tmp_path / "y").exists()  # nothing written
