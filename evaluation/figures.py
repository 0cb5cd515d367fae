"""The evaluation figures, drawn with matplotlib's Agg backend (no display needed).

One function per figure of the papers: cumulative slope-frequency distributions (Martin et
al. 2014, Fig. 11-13), radially averaged power spectra (Fig. 14), feature tracks over the
last frame (Fig. 15), slope-area histograms of asteroids (the asteroid paper's Fig. 9), and
the tracking-error distribution that the papers could not draw. Each returns a
``matplotlib.figure.Figure``; :func:`png_bytes` renders one to PNG, and :func:`save_png`
writes it atomically.

Figures are built with ``matplotlib.figure.Figure`` directly (not ``pyplot``), so nothing
touches global plotting state and no GUI backend is ever loaded.
"""

from __future__ import annotations

import io
from collections.abc import Sequence

import numpy as np

from terrain.core.outputs import atomic_path

__all__ = ["as_png", "consistency_figure", "crater_sfd_figure", "depth_diameter_figure",
           "drawn_once", "error_figure", "png_bytes", "range_thumbnail", "read_png",
           "save_png", "slope_area_figure", "slope_baseline_figure",
           "slope_distribution_figure", "spectrum_figure", "structure_function_figure",
           "thumbnail", "tracks_figure"]

#: Figure size (inches) and resolution (dots per inch) of every figure.
FIGSIZE = (7.0, 4.5)
DPI = 110
#: Lowest percentage drawn on logarithmic "percent steeper" axes.
PERCENT_FLOOR = 1e-3


def new_figure(figsize=FIGSIZE):
    """Return an empty matplotlib figure in the reports' size, resolution and layout.

    Parameters
    ----------
    figsize : (2,) float, inches
        Width and height.

    Returns
    -------
    matplotlib.figure.Figure
        A figure with no pyplot state behind it (safe in threads and servers).
    """
    from matplotlib.figure import Figure

    return Figure(figsize=figsize, dpi=DPI, layout="constrained")


def png_bytes(fig) -> bytes:
    """Return the figure as PNG bytes (Agg renderer): the bytes ``fig.savefig`` writes.

    With a layout engine, ``savefig`` first draws the whole figure with rendering turned off
    to run the layout, then draws it again to render. Here the layout runs alone (the
    engine's ``execute``, which measures what it needs), and the figure is saved with the
    engine set aside: one whole draw fewer, the same positions, the same bytes
    (``tests/evaluation/test_figures.py`` compares them with ``savefig``'s), about a sixth
    of the time of the stage's figures. A figure at another resolution than :data:`DPI` is
    saved by ``savefig`` alone (the layout depends on it).
    """
    import matplotlib
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    FigureCanvasAgg(fig)
    buf = io.BytesIO()
    engine = fig.get_layout_engine()
    laid_out = engine is not None and fig.dpi == DPI
    if laid_out:
        engine.execute(fig)
        # None is "no engine" only where the rc parameters choose none by default
        with matplotlib.rc_context({"figure.autolayout": False,
                                    "figure.constrained_layout.use": False}):
            fig.set_layout_engine(None)
    try:
        fig.savefig(buf, format="png", dpi=DPI)
    finally:
        if laid_out:
            fig.set_layout_engine(engine)
    return buf.getvalue()


def as_png(fig) -> bytes:
    """Return a figure's PNG bytes: :func:`png_bytes` of a figure, PNG bytes as they are."""
    return fig if isinstance(fig, bytes) else png_bytes(fig)


def save_png(fig, path, *, inputs=()) -> None:
    """Write the figure (or PNG bytes already drawn) as a PNG, atomically."""
    data = as_png(fig)
    with atomic_path(path, inputs) as tmp:
        tmp.write_bytes(data)


def drawn_once(drawn: dict | None, name: str, draw) -> bytes:
    """Return the PNG bytes of ``draw()`` (a figure), drawn once per ``name`` in ``drawn``.

    A figure written to a run's folder is often shown in the report too; the caller that
    draws it first keeps its bytes in ``drawn`` (a dict, or None to keep nothing) and the
    second takes them from there instead of drawing the same figure again.

    >>> drawn = {}
    >>> calls = []
    >>> def draw():
    ...     import matplotlib.figure
    ...     calls.append(1)
    ...     return matplotlib.figure.Figure(figsize=(1, 1))
    >>> drawn_once(drawn, "a", draw) == drawn_once(drawn, "a", draw), len(calls)
    (True, 1)
    """
    if drawn is not None and name in drawn:
        return drawn[name]
    data = png_bytes(draw())
    if drawn is not None:
        drawn[name] = data
    return data


def _legend(fig, ax) -> None:
    """Place a legend inside the axes, or beside them (a wider figure) for many entries."""
    n = len(ax.get_legend_handles_labels()[0])
    if n <= 6:
        ax.legend(fontsize="small")
        return
    w, h = fig.get_size_inches()
    fig.set_size_inches(w * 1.35, h)
    ax.legend(fontsize="x-small", loc="upper left", bbox_to_anchor=(1.02, 1.0),
              ncols=2 if n > 14 else 1)


def slope_distribution_figure(distributions: Sequence, *, title: str = "") -> object:
    """Percentage of terrain steeper than each angle, one line per DEM or layer (Fig. 11).

    Parameters
    ----------
    distributions : sequence of evaluation.slope.SlopeDistribution
    """
    fig = new_figure()
    ax = fig.add_subplot()
    top = 10.0
    for d in distributions:
        pct = np.maximum(d.percent_steeper, PERCENT_FLOOR)
        ax.plot(d.angles_deg, pct, label=f"{d.label} ({d.resolution_m:.3g} m)")
        reach = d.angles_deg[d.percent_steeper > 0.01]
        top = max(top, float(reach.max()) + 2.0 if reach.size else top)
    ax.set_yscale("log")
    ax.set_ylim(PERCENT_FLOOR * 10, 100.0)
    ax.set_xlim(0.0, min(90.0, top))
    ax.set_xlabel("slope (degrees)")
    ax.set_ylabel("terrain steeper than slope (%)")
    ax.grid(True, which="both", alpha=0.3)
    _legend(fig, ax)
    ax.set_title(title or "Cumulative slope-frequency distributions")
    return fig


def spectrum_figure(spectra: Sequence, fits: Sequence | None = None, *,
                    title: str = "") -> object:
    """Radially averaged power spectra on log-log axes, with fitted power laws (Fig. 14).

    Parameters
    ----------
    spectra : sequence of evaluation.spectrum.RadialSpectrum
    fits : sequence of evaluation.spectrum.HurstFit or None, optional
        One per spectrum; drawn as dashed lines over their fitted band.
    """
    fig = new_figure()
    ax = fig.add_subplot()
    fits = list(fits) if fits is not None else [None] * len(spectra)
    for s, fit in zip(spectra, fits, strict=True):
        (line,) = ax.loglog(s.frequency, s.power,
                            label=f"{s.label} ({s.resolution_m:.3g} m)" if s.label else None)
        if fit is not None:
            f = np.geomspace(fit.f_low, fit.f_high, 20)
            ax.loglog(f, 10 ** fit.intercept * f ** -fit.beta, "--", color=line.get_color(),
                      label=f"H = {fit.hurst:.2f}")
    ax.set_xlabel("radial frequency (cycles per metre)")
    ax.set_ylabel("power spectral density (m$^4$)")
    ax.grid(True, which="both", alpha=0.3)
    _legend(fig, ax)
    secax = ax.secondary_xaxis("top", functions=(lambda f: 1.0 / np.maximum(f, 1e-300),
                                                 lambda w: 1.0 / np.maximum(w, 1e-300)))
    secax.set_xlabel("wavelength (m)")
    ax.set_title(title or "Radially averaged power spectra")
    return fig


def slope_baseline_figure(curves: Sequence, law, band_factor: float, *,
                          title: str = "") -> object:
    """Median slope against baseline, 1 cm to 10 km, over a terrain law and its band.

    Parameters
    ----------
    curves : sequence of evaluation.validate.SlopeCurve
        Measured points (one line per DEM or layer).
    law : evaluation.lunar_stats.TerrainLaw
        Drawn as a line, with the band ``law / band_factor`` to ``law * band_factor`` shaded.
    band_factor : float
    """
    fig = new_figure()
    ax = fig.add_subplot()
    b = np.geomspace(0.01, 1e4, 200)
    if curves:
        lo = min(float(np.min(c.baseline_m)) for c in curves if len(c.baseline_m))
        hi = max(float(np.max(c.baseline_m)) for c in curves if len(c.baseline_m))
        b = np.geomspace(min(0.01, lo / 2), max(1e4, hi * 2), 200)
    m = law.median_slope_deg(b)
    ax.fill_between(b, m / band_factor, np.minimum(m * band_factor, 90.0), color="0.85",
                    label=f"{law.name} law x/{band_factor:g}")
    ax.loglog(b, m, color="0.3", lw=1.5, label=f"{law.name}: {law.slope_17m_deg:g} deg at 17 m, "
              f"H {law.hurst:g}")
    for c in curves:
        if len(c.baseline_m):
            ax.loglog(c.baseline_m, c.median_deg, "o-", ms=3, label=c.label)
    ax.axvline(17.0, color="0.6", lw=0.8, ls=":")
    ax.set_xlabel("baseline (m)")
    ax.set_ylabel("median bidirectional slope (degrees)")
    ax.grid(True, which="both", alpha=0.3)
    _legend(fig, ax)
    ax.set_title(title or "Median slope against baseline")
    return fig


def structure_function_figure(estimates: Sequence, *, title: str = "") -> object:
    """Median |height difference| against lag, per axis, with the fitted Hurst exponent.

    Parameters
    ----------
    estimates : sequence of (label, evaluation.validate.HurstEstimate)
    """
    fig = new_figure()
    ax = fig.add_subplot()
    for label, e in estimates:
        lags = np.asarray(e.structure["lags_px"], float)
        (line,) = ax.loglog(lags * e.band_m[0] / lags[0], e.structure["x"], "o-", ms=3,
                            label=f"{label}: H {e.hurst:.2f} +- {e.uncertainty:.2f}, "
                                  f"R$^2$ {e.r_squared:.2f}")
        ax.loglog(lags * e.band_m[0] / lags[0], e.structure["y"], "s--", ms=3,
                  color=line.get_color())
    ax.set_xlabel("lag (m); circles along x, squares along y")
    ax.set_ylabel("median |height difference| (m)")
    ax.grid(True, which="both", alpha=0.3)
    _legend(fig, ax)
    ax.set_title(title or "Structure functions over the Hurst fit range (even lags)")
    return fig


def depth_diameter_figure(diameter_m, depth_m, *, fresh=0.196, title: str = "") -> object:
    """Depth against diameter of measured craters, with the fresh-crater line."""
    fig = new_figure()
    ax = fig.add_subplot()
    d = np.asarray(diameter_m, float)
    ax.loglog(d, np.maximum(np.asarray(depth_m, float), 1e-3), ".", ms=4, label="measured")
    if d.size:
        g = np.geomspace(d.min(), d.max(), 20)
        ax.loglog(g, fresh * g, "k-", label=f"fresh (d/D {fresh:g}, Melosh 1989)")
        ax.loglog(g, 0.05 * g, "k:", label="degraded (d/D 0.05)")
    ax.set_xlabel("diameter (m)")
    ax.set_ylabel("rim-to-floor depth (m)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize="small")
    ax.set_title(title or "Crater depth against diameter")
    return fig


def crater_sfd_figure(diameter_m, n_per_m2, equilibrium_per_m2, *, title: str = "") -> object:
    """Cumulative crater density N(>=D) per km^2 against the empirical equilibrium."""
    fig = new_figure()
    ax = fig.add_subplot()
    ax.loglog(diameter_m, np.maximum(np.asarray(n_per_m2) * 1e6, 1e-6), "o-", ms=3,
              label="measured")
    ax.loglog(diameter_m, np.asarray(equilibrium_per_m2) * 1e6, "k--",
              label="equilibrium (Trask 1966)")
    ax.set_xlabel("diameter D (m)")
    ax.set_ylabel("N(>=D) per km$^2$")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize="small")
    ax.set_title(title or "Crater size-frequency against equilibrium")
    return fig


def slope_area_figure(histograms: Sequence, *, title: str = "") -> object:
    """Percentage of surface area per slope bin, one line per body (asteroid paper, Fig. 9).

    Parameters
    ----------
    histograms : sequence of evaluation.meshslope.SlopeAreaHistogram
    """
    fig = new_figure()
    ax = fig.add_subplot()
    top = 30.0
    for h in histograms:
        ax.stairs(h.area_percent, h.edges_deg, label=f"{h.label} ({h.kind})")
        nz = h.edges_deg[1:][h.area_percent > 0.05]
        top = max(top, float(nz.max()) + 3.0 if nz.size else top)
    ax.set_xlim(0.0, min(180.0, top))
    ax.set_xlabel("slope (degrees)")
    ax.set_ylabel("surface area per bin (%)")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize="small")
    ax.set_title(title or "Slope-area histograms")
    return fig


def tracks_figure(image: np.ndarray, scored, *, title: str = "") -> object:
    """Feature tracks drawn over the last frame (Fig. 15), coloured by error when known.

    Parameters
    ----------
    image : (h, w) or (h, w, 3) array
        The last frame.
    scored : evaluation.tracking.ScoredTracks
    """
    from matplotlib import colormaps
    from matplotlib.collections import LineCollection
    from matplotlib.colors import Normalize

    tracks = scored.tracks
    h, w = tracks.shape
    fig = new_figure(figsize=(7.0, 7.0 * h / w + 0.6))
    ax = fig.add_subplot()
    img = np.asarray(image)
    if img.ndim == 3:
        img = img[:, :, ::-1]  # BGR (OpenCV) to RGB
    ax.imshow(img, cmap="gray", interpolation="nearest")
    last = tracks.n_frames - 1
    alive = tracks.alive()
    lines, colours = [], []
    final_error = None
    if scored.errors is not None:
        final_error = scored.errors[:, last]
    for i in range(tracks.n_tracks):
        if tracks.lengths[i] < 2:
            continue
        pts = tracks.positions[i][alive[i]]
        lines.append(pts)
        if final_error is not None:
            colours.append(final_error[i] if tracks.stop[i] == last else np.nan)
    if lines:
        if final_error is not None:
            cmap = colormaps["viridis"]
            norm = Normalize(0.0, max(2.0 * scored.outlier_px, 1e-6))
            c = [cmap(norm(e)) if np.isfinite(e) else (1.0, 0.4, 0.0, 0.35) for e in colours]
            ax.add_collection(LineCollection(lines, colors=c, linewidths=1.0))
            from matplotlib.cm import ScalarMappable

            fig.colorbar(ScalarMappable(norm, cmap), ax=ax, shrink=0.7,
                         label="error at the last frame (px); orange: ended earlier")
        else:
            ax.add_collection(LineCollection(lines, colors="lime", linewidths=1.0))
    ends = tracks.positions[tracks.stop == last, last]
    if ends.size:
        ax.plot(ends[:, 0], ends[:, 1], ".", color="red", markersize=2.0)
    ax.set_xlim(-0.5, w - 0.5)
    ax.set_ylim(h - 0.5, -0.5)
    ax.set_axis_off()
    ax.set_title(title or f"{tracks.n_tracks} tracks over the last of {tracks.n_frames} frames")
    return fig


def error_figure(scored, *, title: str = "") -> object:
    """Tracking-error distribution and its growth with track age (needs truth)."""
    fig = new_figure(figsize=(9.0, 4.0))
    ax1, ax2 = fig.subplots(1, 2)
    e = scored.error_values()
    if e.size:
        top = max(float(np.quantile(e, 0.995)), 2.0 * scored.outlier_px)
        ax1.hist(np.minimum(e, top), bins=60, range=(0.0, top), color="tab:blue")
        ax1.axvline(float(np.median(e)), color="k", linestyle="--",
                    label=f"median {np.median(e):.3f} px")
        ax1.axvline(scored.outlier_px, color="tab:red", linestyle=":",
                    label=f"outlier > {scored.outlier_px:g} px")
        ax1.legend(fontsize="small")
        summary = scored.error_summary() or {}
        by_age = np.array(summary.get("median_px_by_track_age") or [], dtype=np.float64)
        if by_age.size:
            ax2.plot(by_age[:, 0], by_age[:, 1], "o-", label="accumulated")
        one = np.array(summary.get("one_step_median_px_by_track_age") or [],
                       dtype=np.float64)
        if one.size:
            ax2.plot(one[:, 0], one[:, 1], "s--", label="one step")
            ax2.legend(fontsize="small")
    ax1.set_xlabel("tracking error (px)")
    ax1.set_ylabel("observations")
    ax2.set_xlabel("frames since the feature was found")
    ax2.set_ylabel("median error (px)")
    ax1.grid(True, alpha=0.3)
    ax2.grid(True, alpha=0.3)
    fig.suptitle(title or "Tracking error against the renderer's truth")
    return fig


def consistency_figure(result, *, title: str = "") -> object:
    """Per-frame consistency residual over a run, with layer and level-of-detail changes.

    ``result`` is an :class:`evaluation.consistency.Consistency`.
    """
    fig = new_figure(figsize=(9.0, 4.0))
    ax = fig.subplots()
    frames = result.frames
    x = np.array([f["next"] for f in frames], dtype=np.float64)
    rms = result.rms()
    ax.plot(x, rms, "o-", ms=3, color="tab:blue", label="residual rms (DN)")
    floor = np.array([np.nan if f["noise_floor_dn"] is None else f["noise_floor_dn"]
                      for f in frames], dtype=np.float64)
    if np.isfinite(floor).any():
        ax.plot(x, floor, "--", color="tab:gray", label="sensor noise of a pair (DN)")
    summary = result.summary()
    if summary["rms_dn_median"]:
        ax.axhline(summary["spike_bound"] * summary["rms_dn_median"], color="tab:red",
                   linestyle=":", label=f"{summary['spike_bound']:g} x median")
    first_layer = first_lod = True
    for f in frames:
        if f["layer_change"]:
            ax.axvline(f["next"], color="tab:orange", alpha=0.6, lw=1.2,
                       label="layers change" if first_layer else None)
            first_layer = False
        elif f["lod_change"]:
            ax.axvline(f["next"], color="tab:green", alpha=0.25, lw=0.8,
                       label="level of detail changes" if first_lod else None)
            first_lod = False
    ax.set_xlabel("frame (residual of it warped into the previous frame)")
    ax.set_ylabel("DN")
    ax.set_ylim(bottom=0)
    ax.grid(True, alpha=0.3)
    _legend(fig, ax)
    ax.set_title(title or "Frame-to-frame consistency through the truth")
    return fig


# ------------------------------------------------------------------------------ thumbnails

#: Longest side of a report thumbnail (pixels).
THUMBNAIL_SIDE = 384


def read_png(path) -> np.ndarray:
    """Return a PNG as an array: ``(h, w)`` grey or ``(h, w, 3)`` RGB, uint8 or uint16.

    Parameters
    ----------
    path : path-like
        The PNG file.

    Returns
    -------
    numpy.ndarray
        The image, RGB channel order where it has colour.
    """
    import cv2

    from terrain.core.errors import MissingInputError

    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise MissingInputError(f"cannot read the image '{path}'")
    return img if img.ndim == 2 else img[..., ::-1]


def thumbnail(image: np.ndarray, target, size: int = THUMBNAIL_SIDE):
    """Write a small 8-bit copy of a grey or RGB image (a frame, a hillshade) as PNG.

    Images that are not uint8 are scaled so their 99.9th percentile is white.

    Parameters
    ----------
    image : (h, w) or (h, w, 3) array
        Grey or RGB image, any numeric dtype.
    target : path-like
        The PNG to write (atomically).
    size : int, optional
        Longest side of the thumbnail (pixels).

    Returns
    -------
    pathlib.Path
        ``target``.
    """
    import cv2

    from terrain.io import write_png

    img = np.asarray(image)
    if img.dtype != np.uint8:
        top = float(np.percentile(img, 99.9)) or 1.0
        img = np.clip(img.astype(np.float64) / top * 255.0 + 0.5, 0, 255).astype(np.uint8)
    h, w = img.shape[:2]
    scale = size / max(h, w)
    small = cv2.resize(img, (max(1, round(w * scale)), max(1, round(h * scale))),
                       interpolation=cv2.INTER_AREA)
    if small.ndim == 3:  # RGB in, BGR for OpenCV
        small = np.ascontiguousarray(small[..., ::-1])
    return write_png(small, target)


def range_thumbnail(range_m: np.ndarray, target, size: int = THUMBNAIL_SIDE):
    """Write a range image colour-mapped (viridis, near = dark; no return black) as PNG.

    Parameters
    ----------
    range_m : (h, w) float array, metres
        Range image; NaN or 0 where there is no return.
    target : path-like
        The PNG to write (atomically).
    size : int, optional
        Longest side of the thumbnail (pixels).

    Returns
    -------
    pathlib.Path
        ``target``.
    """
    from matplotlib import colormaps

    finite = np.isfinite(range_m) & (range_m > 0)
    rgb = np.zeros(range_m.shape + (3,), dtype=np.uint8)
    if finite.any():
        lo, hi = np.percentile(range_m[finite], [0.5, 99.5])
        t = np.clip((range_m - lo) / max(hi - lo, 1e-9), 0, 1)
        rgb[finite] = (colormaps["viridis"](t[finite])[:, :3] * 255 + 0.5).astype(np.uint8)
    return thumbnail(rgb, target, size)
