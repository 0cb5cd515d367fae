"""Measure a descent frame's shadows against maps four times finer, and its light in shadows.

Renders one frame of a finished descent run (its truth gives the pose and the sun) over the
run's layer stack: without shadows, with the default shadow maps, with maps of four times the
default detail (the reference), and with scattered light; writes the figures to
``shadow_figures.json`` and a picture to ``shadow_figures.png`` beside this file.

Usage::

    PYTHONPATH=. .venv/bin/python docs/shadow_figures.py [RUN_DIR] [--frame 119]

``RUN_DIR`` is the descent's run folder (default: ``demo-output/lunar/run/run`` of a
finished ``make demo``); its ``scenario.toml`` names the stack.
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent


def main(argv=None) -> int:
    from render.camera import Intrinsics, Pose
    from render.renderer import Renderer, View
    from render.scenario import load_scenario
    from render.terrain_scene import TerrainScene

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run", nargs="?", default=str(HERE.parent / "demo-output/lunar/run/run"))
    parser.add_argument("--frame", type=int, default=119)
    args = parser.parse_args(argv)
    run = Path(args.run)
    scenario = load_scenario(run / "scenario.toml")
    truth = json.loads((run / "truth.json").read_text())[args.frame]
    k = Intrinsics(**{key: truth["intrinsics"][key]
                      for key in ("width", "height", "fx", "fy", "cx", "cy")})
    view = View(Pose(truth["camera"]["position"], truth["camera"]["attitude"]), k)
    light = replace(scenario.lighting, sun=tuple(truth["sun"]["direction"]))
    t0 = time.perf_counter()
    spec = scenario.scene
    scene = TerrainScene(scenario.resolve(spec.stack), curvature=spec.curvature,
                         radius=spec.radius)
    renderer = Renderer()
    # the descent example's cap on terrain maps (a run made before it may record 2048)
    base = replace(scenario.options, soft_shadows=False, scattering=False,
                   shadow_size=max(4096, scenario.options.shadow_size))
    opts = {
        "no_shadows": replace(base, shadows=False),
        "default": base,
        "reference_4x": replace(base, shadow_detail=4 * base.shadow_detail, shadow_size=8192),
        "default_soft": replace(base, soft_shadows=True),
        "default_soft_scattering": replace(base, soft_shadows=True, scattering=True),
    }
    images, seconds = {}, {}
    for name, o in opts.items():
        t = time.perf_counter()
        images[name] = renderer.render(scene, view, light, o).radiance
        seconds[name] = time.perf_counter() - t
    lit = images["no_shadows"]
    faces = lit > 1e-6
    masks = {name: faces & (images[name] < 0.5 * lit)
             for name in ("default", "reference_4x", "default_soft")}
    area = {name: float(m.mean()) for name, m in masks.items()}
    ref = masks["reference_4x"]
    shadowed = masks["default"]
    scat = images["default_soft_scattering"]
    sunlit = faces & ~shadowed
    out = {
        "run": str(run), "frame": args.frame, "options": str(base),
        "shadowed_area": area,
        "missing_shadow_area_vs_4x": (area["reference_4x"] - area["default"])
        / area["reference_4x"],
        "shadow_pixels_missing_vs_4x": float((ref & ~shadowed).sum() / ref.sum()),
        "median_lit_if": float(np.median(lit[sunlit])),
        "median_if_in_shadow_scattered": float(np.median(scat[shadowed])),
        "scattered_over_lit_median": float(np.median(scat[shadowed])
                                           / np.median(lit[sunlit])),
        "render_s": seconds, "total_s": time.perf_counter() - t0,
    }
    (HERE / "shadow_figures.json").write_text(json.dumps(out, indent=2) + "\n")
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(1, 3, figsize=(15, 5.4))
        ax[0].imshow(ref.astype(int) - shadowed.astype(int), cmap="coolwarm", vmin=-1, vmax=1,
                     interpolation="nearest")
        ax[0].set_title(f"shadows: default {area['default']:.1%}, 4x {area['reference_4x']:.1%}"
                        "\nred: only in 4x, blue: only in default")
        gamma = 1 / 2.2
        ax[1].imshow(np.clip(images["default_soft"] / np.percentile(lit[faces], 99), 0, 1)
                     ** gamma, cmap="gray")
        ax[1].set_title("extended sun, no scattered light")
        ax[2].imshow(np.clip(scat / np.percentile(lit[faces], 99), 0, 1) ** gamma, cmap="gray")
        ax[2].set_title("extended sun + scattered light")
        for a in ax:
            a.axis("off")
        fig.tight_layout()
        fig.savefig(HERE / "shadow_figures.png", dpi=80)
    except ImportError:
        pass
    print(json.dumps(out, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
