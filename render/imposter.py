"""Imposters: a distant body rendered into a small image, mapped into the frame.

A scene asks for an imposter (:class:`render.scene.Imposter`) when a body spans few pixels;
the renderer renders the scene from a camera at the frame camera's centre looking at the
body, as geometry, into a small square image, and maps it into the frame here. The imposter
stands for a camera-facing quad through the body's centre (the asteroid paper's imposter);
because both cameras share their centre, the quad's image is the imposter image mapped by a
homography of the image plane, which is how it is composited. Range and normals come from
the imposter's nearest texel (range is measured from the same centre, so it stays the true
range); radiance is interpolated bilinearly over the body's own texels.

While a body fades from geometry to imposter, the frame is the geometry's with the
imposter's radiance blended in (:func:`blend`); range and normals stay the geometry's.
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["blend", "composite"]


def composite(view: Any, radiance: np.ndarray, range_m: np.ndarray, normals: np.ndarray,
              imposter: Any, pose: Any, intrinsics: Any) -> None:
    """Draw an imposter image into a frame's images, in place, where it shows the body.

    Parameters
    ----------
    view : render.renderer.View
        The frame's camera.
    radiance, range_m : (h, w) float32
        The frame's I/F and range (m, NaN where nothing was hit), top row first.
    normals : (h, w, 3) float32
        The frame's world-frame normals (NaN where nothing was hit).
    imposter : render.renderer.Frame
        The imposter's images (square, ``intrinsics.width`` a side).
    pose : render.camera.Pose
        The imposter camera's pose (the frame camera's centre).
    intrinsics : render.camera.Intrinsics
        The imposter camera's intrinsics.
    """
    import cv2

    k = view.intrinsics
    v, u = np.mgrid[0:k.height, 0:k.width].astype(np.float64)
    rays = np.stack([(u - k.cx) / k.fx, (v - k.cy) / k.fy, np.ones_like(u)], -1)
    world = rays @ view.pose.rotation.T          # same centre: only directions matter
    c = world @ pose.rotation                     # into the imposter camera
    ok = c[..., 2] > 0
    ki = intrinsics
    with np.errstate(divide="ignore", invalid="ignore"):
        iu = ki.fx * c[..., 0] / c[..., 2] + ki.cx
        iv = ki.fy * c[..., 1] / c[..., 2] + ki.cy
    n = ki.width
    ok &= (iu > -0.5) & (iu < n - 0.5) & (iv > -0.5) & (iv < n - 0.5)
    ju = np.clip(np.rint(iu[ok]).astype(int), 0, n - 1)
    jv = np.clip(np.rint(iv[ok]).astype(int), 0, n - 1)
    hit = np.isfinite(imposter.range[jv, ju])
    rows, cols = np.nonzero(ok)
    rows, cols, ju, jv = rows[hit], cols[hit], ju[hit], jv[hit]
    # bilinear over the body's own texels only (weights renormalised), so the limb does
    # not blend with the black sky of the imposter
    mask = np.isfinite(imposter.range).astype(np.float32)
    mu, mv = iu.astype(np.float32), iv.astype(np.float32)
    num = cv2.remap(np.nan_to_num(imposter.radiance) * mask, mu, mv, cv2.INTER_LINEAR,
                    borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    den = cv2.remap(mask, mu, mv, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                    borderValue=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        rad = np.where(den > 0, num / np.maximum(den, 1e-12), 0.0)
    radiance[rows, cols] = rad[rows, cols]
    range_m[rows, cols] = imposter.range[jv, ju]
    normals[rows, cols] = imposter.normals[jv, ju]


def blend(view: Any, radiance: np.ndarray, range_m: np.ndarray, normals: np.ndarray,
          imposter: Any, pose: Any, intrinsics: Any, weight: float) -> None:
    """Blend an imposter's radiance into a geometry frame, in place (the fade).

    Where both the geometry and the imposter see the body, the radiance becomes
    ``(1 - weight) geometry + weight imposter``; range and normals stay the geometry's.

    Parameters
    ----------
    view, radiance, range_m, normals, imposter, pose, intrinsics
        As :func:`composite`; ``range_m`` and ``normals`` are read, not changed.
    weight : float
        The imposter's weight, clamped to [0, 1].
    """
    w = float(min(max(weight, 0.0), 1.0))
    rad = np.zeros_like(radiance)
    r = np.full_like(range_m, np.nan)
    n = np.full_like(normals, np.nan)
    composite(view, rad, r, n, imposter, pose, intrinsics)
    both = np.isfinite(r) & np.isfinite(range_m)
    radiance[both] = (1.0 - w) * radiance[both] + w * rad[both]
