"""Regenerate the README's gallery (docs/gallery/*.png) from a `make demo` output folder.

Usage::

    .venv/bin/python docs/make_gallery.py [demo-output]

Small 8-bit PNGs: frames of the lunar descent and of the asteroid approach, a LIDAR range
image, the feature tracks of the descent and the slope distributions of every layer.
"""

from __future__ import annotations

import sys
from pathlib import Path

import cv2
import numpy as np

HERE = Path(__file__).resolve().parent


def grey(path: Path, size: int) -> np.ndarray:
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img.dtype != np.uint8:
        img = np.clip(img / max(np.percentile(img, 99.9), 1) * 255, 0, 255).astype(np.uint8)
    if img.ndim == 2:
        img = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
    return cv2.resize(img, (size, size), interpolation=cv2.INTER_AREA)


def stretch(img: np.ndarray) -> np.ndarray:
    """Contrast stretch for display only (the frames themselves are linear in radiance)."""
    lo, hi = np.percentile(img, [0.5, 99.5])
    return np.clip((img.astype(np.float64) - lo) / max(hi - lo, 1) * 255, 0, 255).astype(np.uint8)


def range_colour(path: Path, size: int) -> np.ndarray:
    from matplotlib import colormaps

    from terrain.io import read_float_tiff

    rng = read_float_tiff(path)
    ok = np.isfinite(rng)
    lo, hi = np.percentile(rng[ok], [0.5, 99.5])
    rgb = np.zeros(rng.shape + (3,), np.uint8)
    rgb[ok] = (colormaps["viridis"](np.clip((rng[ok] - lo) / (hi - lo), 0, 1))[:, :3]
               * 255).astype(np.uint8)
    return cv2.resize(rgb[..., ::-1], (size, size), interpolation=cv2.INTER_AREA)


def save(img: np.ndarray, name: str) -> None:
    out = HERE / "gallery" / name
    out.parent.mkdir(exist_ok=True)
    cv2.imwrite(str(out), img, [cv2.IMWRITE_PNG_COMPRESSION, 9])
    print(f"wrote {out} ({out.stat().st_size // 1024} KiB)")


def main(demo: Path) -> None:
    lunar = demo / "lunar" / "run" / "run"
    n = len(list((lunar / "frames").glob("*.png")))
    picks = [0, n // 4, n // 2, (3 * n) // 4]
    save(np.hstack([stretch(grey(lunar / "frames" / f"frame_{k:06d}.png", 256))
                    for k in picks]), "lunar_descent.png")
    ast = demo / "asteroid" / "run" / "run"
    m = len(list((ast / "frames").glob("*.png")))
    save(np.hstack([grey(ast / "frames" / f"frame_{k:06d}.png", 256)
                    for k in (0, m // 2, m - 1)]
                   + [range_colour(ast / "range" / f"range_{m - 1:06d}.tif", 256)]),
         "asteroid_approach.png")
    tracks = cv2.imread(str(demo / "evaluation" / "lunar_tracks" / "tracks.png"))
    h, w = tracks.shape[:2]
    save(cv2.resize(tracks, (400, round(400 * h / w)), interpolation=cv2.INTER_AREA),
         "lunar_tracks.png")

    from evaluation.figures import png_bytes, slope_distribution_figure
    from evaluation.slope import slope_distribution
    from terrain.stack.store import read_stack

    stack = read_stack(demo / "lunar" / "stack" / "stack")
    fig = slope_distribution_figure([slope_distribution(t, label=f"{t.resolution:.3g} m")
                                     for t in stack.tiles[::2]],
                                    title="Slopes of every other layer")
    img = cv2.imdecode(np.frombuffer(png_bytes(fig), np.uint8), cv2.IMREAD_COLOR)
    h, w = img.shape[:2]
    save(cv2.resize(img, (480, round(480 * h / w)), interpolation=cv2.INTER_AREA),
         "lunar_slopes.png")


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else HERE.parent / "demo-output")
