"""Regenerate docs/validation_figures.md: every check on every real DEM and counterexample.

Usage::

    .venv/bin/python docs/validation_figures.py [shared-data-folder]

Runs :func:`evaluation.validate.validate_dem` on every real lunar DEM of the shared data (for
its terrain type) and on the three non-lunar surfaces of :mod:`evaluation.counterexamples`,
measures what the thresholds are calibrated against (two real DEMs of the same ground, two
halves of one), and writes the tables with the slope-vs-baseline figure
(docs/validation_slopes.png). The figures in docs/validation.md come from here.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
sys.path.insert(0, str(REPO))

REAL = [  # file, terrain type, what it is
    ("LDEM_4.LBL", "south-polar", "LOLA LDEM_4 around the south pole (7.58 km)"),
    ("southpole_85S_nac_asp_sfs_dem_1p08m.tif", "south-polar", "NAC SfS DEM, Malapert (1.08 m)"),
    ("southpole_85S_nac_asp_stereo_dem_1p08m.tif", "south-polar",
     "NAC stereo DEM, Malapert (1.08 m)"),
    ("aristarchus_IMP_quickmap_hsr_4p76m.tif", "maria", "QuickMap, Aristarchus plateau (4.76 m)"),
    ("aristarchus_CP_quickmap_hsr_26p5m.tif", "highlands",
     "QuickMap, Aristarchus central peak (26.5 m)"),
]


def _row(label, terrain, v):
    cells = []
    for r in v.results:
        if r.status == "not applicable" or r.group.startswith("side"):
            continue
        cells.append(f"{r.status} {r.value:.3g}")
    fails = "; ".join(r.meaning for r in v.failures()) or "-"
    return f"| {label} | {terrain} | {v.verdict} | " + " | ".join(cells) + f" | {fails} |"


def main(data: Path) -> None:
    from evaluation import lunar_stats as ls
    from evaluation.counterexamples import fresh_crater_field, smoothed_8x
    from evaluation.figures import save_png, slope_baseline_figure
    from evaluation.spectrum import fractional_brownian_surface
    from evaluation.validate import compare_reference, hurst_estimate, validate_dem
    from evaluation.validate_report import load_input
    from terrain.core.tile import DEMTile

    lunar = data / "lunar"
    head = ("| DEM | terrain | verdict | slope vs law (worst factor, <= "
            f"{ls.SLOPE_BAND_FACTOR.threshold:g}) | abs(H - H_law) (<= "
            f"{ls.HURST_TOLERANCE.threshold:g}) | spectral H 4-16 px (<= "
            f"{ls.SMOOTHNESS.threshold:g}) | share > 35 deg (<= "
            f"{ls.STEEP_SLOPE.threshold:g}) | why it failed |\n|---|---|---|---|---|---|---|---|")
    rows, hurst_rows, curves, tiles = [], [], [], {}
    for name, terrain, what in REAL:
        label, tile, _, _ = load_input(lunar / name)
        tiles[name] = tile
        v = validate_dem(tile, terrain, label=what)
        rows.append(_row(what, terrain, v))
        for _lb, h in v.hurst:
            hurst_rows.append(f"| {what} | {h.hurst:.3f} +- {h.uncertainty:.3f} | "
                              f"{h.r_squared:.3f} | {h.band_m[0]:.3g}-{h.band_m[1]:.3g} | "
                              f"{', '.join(f'{x:.2f}' for x in h.per_axis)} | "
                              f"{v.data['period2_ratio']:.2f} |")
        curves.append(v.curves[0])
    sfs = tiles["southpole_85S_nac_asp_sfs_dem_1p08m.tif"]
    fake = [("pure fBm, H 0.5 (1 m, 256 px, RMS 3 m)", "south-polar",
             fractional_brownian_surface(256, 0.5, resolution=1.0, rms=3.0, seed=1)),
            ("the SfS DEM, bicubic-smoothed 8x", "south-polar", smoothed_8x(sfs)),
            ("fresh-crater walls everywhere (1 m, 256 px)", "highlands", fresh_crater_field())]
    fake_rows = [_row(label, terrain, validate_dem(t, terrain, label=label))
                 for label, terrain, t in fake]
    st = tiles["southpole_85S_nac_asp_stereo_dem_1p08m.tif"]
    v = validate_dem(sfs, "south-polar", label="sfs")
    compare_reference(v, sfs, st, "stereo")
    side = {r.name.split(" vs")[0]: r.value for r in v.results if r.group.startswith("side")}
    half = sfs.heights.shape[1] // 2
    halves = [DEMTile.from_array(sfs.heights[:, :half], resolution=sfs.resolution),
              DEMTile.from_array(sfs.heights[:, half:], resolution=sfs.resolution)]
    hh = [hurst_estimate(t).hurst for t in halves]
    from evaluation.compare import ks_distance
    from evaluation.slope import horn_slope

    sa, sb = (horn_slope(t) for t in halves)
    ks_halves = ks_distance(sa[np.isfinite(sa)], sb[np.isfinite(sb)])
    fig = slope_baseline_figure(curves[1:], ls.TERRAINS["south-polar"],
                                ls.SLOPE_BAND_FACTOR.threshold,
                                title="Real DEMs against the south-polar law")
    save_png(fig, HERE / "validation_slopes.png")
    body_rows = []
    from evaluation.gravity import coarsen
    from evaluation.meshslope import Spin, load_body, mesh_slopes

    for name, path, rho, period in (
            ("433 Eros (Gaskell)", "eros_gaskell_q64.obj", 2670.0, 5.27),
            ("25143 Itokawa (Gaskell)", "itokawa_gaskell_q32.obj", 1900.0, 12.13),
            ("101955 Bennu (OSIRIS-REx)", "bennu-osiris2019.ply", 1190.0, 4.296)):
        shape = load_body(data / "asteroids" / path, units="km")
        cells = []
        for n in (3072, 12288):
            v, f = coarsen(shape.vertices, shape.faces, n)
            m = mesh_slopes(v, f, radius_deg=0.0, density=rho, spin=Spin(period, (0, 0, 1)))
            g = m.slopes("gravitational")
            ok = np.isfinite(g)
            cells.append(f"{len(f)} facets: {np.average(g[ok], weights=m.vertex_area[ok]):.2f}")
        body_rows.append(f"| {name} | " + " | ".join(cells) + " |")
    text = [
        "<!-- generated by docs/validation_figures.py; do not edit by hand -->",
        "# Validation figures measured on the real DEMs",
        "",
        "Every check of `craterscape evaluation validate` on every real lunar DEM of the "
        "shared data (for its terrain type) and on three surfaces that are plainly not "
        "lunar. Values: the check's measure; checks that do not apply to a single DEM "
        "(craters, rocks, bodies) are left out.",
        "",
        "## Real lunar DEMs", "", head, *rows, "",
        "## Plainly not lunar", "", head, *fake_rows, "",
        "## Hurst exponents (median structure function, even lags 2-16 px)", "",
        "| DEM | H +- | R^2 | fit range (m) | H along x, y | period-2 ratio |",
        "|---|---|---|---|---|---|", *hurst_rows, "",
        "## Two real DEMs of the same ground", "",
        f"- SfS vs stereo (Malapert, 1.08 m): KS distance of Horn slopes "
        f"{side['KS distance of slopes']:.3f}, Hurst difference {side['Hurst difference']:.3f}",
        f"- left vs right half of the SfS DEM: KS {ks_halves:.3f}, Hurst "
        f"{hh[0]:.3f} vs {hh[1]:.3f}",
        "",
        "## Mean gravitational slope of real shape models against facet count", "",
        "Area-weighted, each vertex's own slope, spin about the model's z axis.", "",
        "| body | coarse | fine |", "|---|---|---|", *body_rows, "",
        "![Median slope against baseline](validation_slopes.png)", "",
    ]
    (HERE / "validation_figures.md").write_text("\n".join(text), encoding="utf-8")


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else REPO.parent / "shared" / "data")
