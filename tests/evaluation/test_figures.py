"""evaluation.figures.png_bytes against matplotlib's own savefig."""

from __future__ import annotations

import io

import numpy as np

from evaluation import figures
from evaluation.slope import slope_distribution
from evaluation.spectrum import fractional_brownian_surface


def _savefig(fig) -> bytes:
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    FigureCanvasAgg(fig)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=figures.DPI)
    return buf.getvalue()


def _distributions(n):
    return [slope_distribution(fractional_brownian_surface(49, 0.6 + 0.02 * k, resolution=1.0,
                                                           rms=2.0 + k, seed=k),
                               label=f"layer {k}") for k in range(n)]


def _panels():
    # two axes, log-log and an image with a colorbar, a suptitle: what the layout must fit
    fig = figures.new_figure()
    a, b = fig.subplots(1, 2)
    x = np.logspace(-2, 3, 50)
    a.loglog(x, x ** -1.7, label="power law")
    a.legend()
    im = b.imshow(np.arange(64.0).reshape(8, 8))
    fig.colorbar(im, ax=b, label="height (m)")
    fig.suptitle("two panels")
    return fig


def test_png_bytes_are_the_bytes_savefig_writes():
    # the layout run alone, then the figure rendered once: the same pixels and file as
    # savefig's layout-then-draw; a legend beside log axes (many lines), a colorbar, a
    # figure at another resolution, and one without a layout engine
    makers = [lambda: figures.slope_distribution_figure(_distributions(9)), _panels]
    for make in makers:
        fig, reference = make(), make()
        engine = fig.get_layout_engine()
        assert figures.png_bytes(fig) == _savefig(reference)
        assert fig.get_layout_engine() is engine  # the engine is the figure's again
        # drawn again, as savefig draws a figure again (a colorbar's layout moves then)
        assert figures.png_bytes(fig) == _savefig(reference)
    odd = _panels()
    odd.set_dpi(72)
    other = _panels()
    other.set_dpi(72)
    assert figures.png_bytes(odd) == _savefig(other)
    plain = _panels()
    plain.set_layout_engine("none")
    bare = _panels()
    bare.set_layout_engine("none")
    assert figures.png_bytes(plain) == _savefig(bare)
