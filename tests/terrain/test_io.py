"""GeoTIFF and PDS3 reading, atomic GeoTIFF writing, refusal to overwrite inputs."""

import numpy as np
import pytest
import rasterio
from affine import Affine
from rasterio.crs import CRS

from terrain import io
from terrain.core import outputs
from terrain.core.errors import (
    InvalidDEMError,
    InvalidParameterError,
    MissingInputError,
    OutputPathError,
)
from terrain.core.tile import DEMTile

MOON_EQC = ('PROJCS["Moon eqc",GEOGCS["Moon",DATUM["Moon",SPHEROID["Moon",1737400,0]],'
            'PRIMEM["Reference",0],UNIT["degree",0.0174532925199433]],'
            'PROJECTION["Equirectangular"],PARAMETER["standard_parallel_1",0],'
            'PARAMETER["central_meridian",0],PARAMETER["false_easting",0],'
            'PARAMETER["false_northing",0],UNIT["metre",1]]')


def _write_raw(path, data, nodata=None, crs=MOON_EQC, transform=None, dtype=None, **extra):
    transform = transform or Affine(2.0, 0, 1000.0, 0, -2.0, 5000.0)
    with rasterio.open(path, "w", driver="GTiff", width=data.shape[1], height=data.shape[0],
                       count=1, dtype=dtype or data.dtype,
                       crs=CRS.from_user_input(crs) if crs else None, transform=transform,
                       nodata=nodata, **extra) as dst:
        dst.write(data, 1)


def test_geotiff_roundtrip_preserves_everything(tmp_path):
    h = np.arange(300 * 280, dtype=np.float32).reshape(300, 280) / 7
    h[5, 7] = np.nan
    tile = DEMTile.from_array(h, transform=Affine(2.0, 0, 1000.0, 0, -2.0, 5000.0),
                              crs=CRS.from_wkt(MOON_EQC).to_wkt(), nodata=-9999.0,
                              metadata={"CRATERSCAPE_SEED": "42", "CRATERSCAPE_X": "{}"})
    out = io.write_dem(tile, tmp_path / "out.tif")
    back = io.read_dem(out)
    assert np.array_equal(back.heights, tile.heights, equal_nan=True)
    assert np.array_equal(back.valid, tile.valid)
    assert back.transform == tile.transform
    assert CRS.from_wkt(back.crs) == CRS.from_wkt(tile.crs)
    assert back.nodata == -9999.0
    assert back.metadata["CRATERSCAPE_SEED"] == "42"
    with rasterio.open(out) as src:
        assert src.dtypes[0] == "float32"
        assert src.profile["tiled"] and src.profile["compress"] == "deflate"
        assert src.read(1)[5, 7] == -9999.0


def test_nodata_and_nan_both_become_the_mask(tmp_path):
    data = np.array([[1.0, -32768.0], [np.nan, 4.0]], dtype=np.float32)
    _write_raw(tmp_path / "a.tif", data, nodata=-32768.0)
    t = io.read_dem(tmp_path / "a.tif")
    assert t.valid.tolist() == [[True, False], [False, True]]


def test_scale_is_applied(tmp_path):
    data = np.array([[10, 20], [30, 40]], dtype=np.int16)
    _write_raw(tmp_path / "s.tif", data)
    with rasterio.open(tmp_path / "s.tif", "r+") as dst:
        dst.scales = (0.5,)
        dst.offsets = (3.0,)
    t = io.read_dem(tmp_path / "s.tif")
    assert t.heights.tolist() == [[8.0, 13.0], [18.0, 23.0]]


def test_lola_pds3_label_is_read_relative_to_the_reference_sphere(shared_file):
    t = io.read_dem(shared_file("lunar", "LDEM_4.LBL"))
    assert t.shape == (720, 1440)
    assert t.resolution == pytest.approx(7580.84, rel=1e-6)
    assert t.valid.all()
    # heights = DN * 0.5 m above the 1737.4 km sphere: the Moon spans about -9 km .. +11 km
    assert -9500 < float(np.nanmin(t.heights)) < -8000
    assert 10000 < float(np.nanmax(t.heights)) < 11000
    assert float(t.metadata["CRATERSCAPE_DATUM_RADIUS"]) == 1737400.0


def test_real_geotiff_with_float64_and_nodata(shared_file):
    t = io.read_dem(shared_file("lunar", "southpole_85S_nac_asp_sfs_dem_1p08m.tif"))
    assert t.shape == (405, 450) and t.valid.all()
    assert t.resolution == pytest.approx(1.0779, rel=1e-3)


def test_missing_corrupt_and_empty_inputs(tmp_path):
    with pytest.raises(MissingInputError, match="does not exist"):
        io.read_dem(tmp_path / "nope.tif")
    bad = tmp_path / "bad.tif"
    bad.write_bytes(b"II*\x00garbage" * 10)
    with pytest.raises(InvalidDEMError, match="cannot read DEM"):
        io.read_dem(bad)
    _write_raw(tmp_path / "empty.tif", np.full((3, 3), -1.0, np.float32), nodata=-1.0)
    with pytest.raises(InvalidDEMError, match="no valid pixels"):
        io.read_dem(tmp_path / "empty.tif")
    with pytest.raises(InvalidDEMError, match="band 2"):
        io.read_dem(tmp_path / "empty.tif", band=2)


def test_geographic_dems_are_refused(tmp_path):
    _write_raw(tmp_path / "geo.tif", np.zeros((3, 3), np.float32), crs="EPSG:4326",
               transform=Affine(0.1, 0, 0, 0, -0.1, 0))
    with pytest.raises(InvalidDEMError, match="geographic"):
        io.read_dem(tmp_path / "geo.tif")


def test_output_over_an_input_is_refused_before_writing(tmp_path):
    src = tmp_path / "in.tif"
    tile = DEMTile.from_array(np.ones((4, 4)))
    io.write_dem(tile, src)
    before = src.read_bytes()
    with pytest.raises(OutputPathError, match="same file as input"):
        io.write_dem(tile, tmp_path / "." / "in.tif", inputs=[src])
    (tmp_path / "link.tif").symlink_to(src)
    with pytest.raises(OutputPathError, match="same file as input"):
        io.write_dem(tile, tmp_path / "link.tif", inputs=[src])
    assert src.read_bytes() == before
    with pytest.raises(OutputPathError, match="does not exist"):
        io.write_dem(tile, tmp_path / "missing" / "out.tif")


def test_writes_are_atomic(tmp_path):
    target = tmp_path / "keep.tif"
    target.write_bytes(b"previous content")
    with pytest.raises(RuntimeError), outputs.atomic_path(target) as tmp:
        tmp.write_bytes(b"half-written")
        raise RuntimeError("crash while writing")
    assert target.read_bytes() == b"previous content"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["keep.tif"]


def test_written_files_get_normal_permissions(tmp_path):
    import os
    import stat

    old = os.umask(0o022)
    try:
        path = io.write_dem(DEMTile.from_array(np.ones((4, 4))), tmp_path / "p.tif")
    finally:
        os.umask(old)
    assert stat.S_IMODE(path.stat().st_mode) == 0o644


def test_png_writer(tmp_path):
    import cv2

    img = (np.arange(64, dtype=np.uint8).reshape(8, 8))
    io.write_png(img, tmp_path / "a.png")
    assert np.array_equal(cv2.imread(str(tmp_path / "a.png"), cv2.IMREAD_UNCHANGED), img)


def test_float_tiffs_read_back_whole_in_the_same_bytes_and_a_cut_file_is_refused(tmp_path):
    import os
    import shutil
    import sys
    from pathlib import Path

    sys.path.append(str(Path(__file__).resolve().parent.parent))
    from cli_helpers import file_size_limit

    rng = np.random.default_rng(3)
    a = np.cumsum(rng.normal(size=(300, 280, 3)), axis=1).astype(np.float32)
    a[5, 7, 1] = np.nan
    first, second = tmp_path / "a.tif", tmp_path / "b.tif"
    io.write_float_tiff(a, first, tags={"FRAME": "world"})
    io.write_float_tiff(a, second, tags={"FRAME": "world"})
    assert first.read_bytes() == second.read_bytes()
    np.testing.assert_array_equal(io.read_float_tiff(first), a)
    with rasterio.open(first) as src:  # any GDAL reader: the codec and the tags
        assert src.tags()["FRAME"] == "world" and src.count == 3
        np.testing.assert_array_equal(src.read(2), a[..., 1])
    # a file cut short (a full disk) is found by its directory, not written into place
    size = first.stat().st_size
    for cut in (200, size // 2, size - 1):
        shutil.copy(first, tmp_path / "cut.tif")
        os.truncate(tmp_path / "cut.tif", cut)
        with pytest.raises(OutputPathError, match="cannot write 'x.tif'"):
            io._verify_blocks(tmp_path / "cut.tif", "x.tif", bands=3, tags={"FRAME": "world"})
    with file_size_limit(size // 2), pytest.raises(OutputPathError, match="c.tif"):
        io.write_float_tiff(a, tmp_path / "c.tif")
    assert not (tmp_path / "c.tif").exists()


def test_one_pixel_of_a_float_tiff_is_the_whole_read_s_value_there(tmp_path):
    # range images are tiled 256^2: pixels in several tiles, at their corners and the
    # image's edges, bands and all, against the whole image as GDAL reads it
    rng = np.random.default_rng(5)
    a = rng.normal(size=(600, 530, 2)).astype(np.float32)
    a[300, 0, 1] = np.nan
    io.write_float_tiff(a, tmp_path / "a.tif")
    whole = io.read_float_tiff(tmp_path / "a.tif")
    for row, col in ((0, 0), (255, 256), (300, 0), (599, 529), (511, 300)):
        assert io.read_float_tiff_pixel(tmp_path / "a.tif", row, col).tobytes() == \
            whole[row, col].tobytes()
    with pytest.raises(InvalidParameterError, match="outside image"):
        io.read_float_tiff_pixel(tmp_path / "a.tif", 600, 3)


def test_writes_on_threads_keep_the_process_stderr(tmp_path):
    # frames are written on a thread while the next renders: each write points file
    # descriptor 2 at a capture for GDAL's messages, and two at once must not leave the
    # process writing its stderr into a deleted capture file
    import os
    import threading

    before = os.fstat(2)
    tile = DEMTile.from_array(np.arange(64 * 64, dtype=np.float32).reshape(64, 64),
                              transform=Affine(2.0, 0, 1000.0, 0, -2.0, 5000.0))

    def write(k):
        for i in range(15):
            io.write_dem(tile, tmp_path / f"t{k}_{i}.tif")

    threads = [threading.Thread(target=write, args=(k,)) for k in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    after = os.fstat(2)
    assert (after.st_dev, after.st_ino) == (before.st_dev, before.st_ino)
    assert len(list(tmp_path.glob("*.tif"))) == 60
