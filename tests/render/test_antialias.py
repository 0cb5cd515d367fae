"""Antialiasing: a pixel's radiance is the mean of its samples; range and normals stay exact."""

import math

import numpy as np
import pytest

from render.camera import Intrinsics, look_at
from render.mesh_scene import MeshScene
from render.renderer import Lighting, RenderOptions, View
from terrain.core.errors import InvalidParameterError


def _uv_sphere(n: int = 48) -> tuple[np.ndarray, np.ndarray]:
    """A unit sphere: (n + 1) rings of 2n vertices, outward-wound faces."""
    lat = np.linspace(0.0, math.pi, n + 1)
    lon = np.linspace(0.0, 2.0 * math.pi, 2 * n, endpoint=False)
    t, p = np.meshgrid(lat, lon, indexing="ij")
    v = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], -1).reshape(-1, 3)
    faces = []
    m = 2 * n
    for i in range(n):
        for j in range(m):
            a, b = i * m + j, i * m + (j + 1) % m
            c, d = a + m, b + m
            faces += [[a, c, b], [b, c, d]]
    return v, np.array(faces, dtype=np.int64)


def _block_mean(image: np.ndarray, a: int) -> np.ndarray:
    h, w = image.shape[0] // a, image.shape[1] // a
    return image.reshape(h, a, w, a).mean(axis=(1, 3), dtype=np.float64)


@pytest.fixture(scope="module")
def sphere():
    return MeshScene(*_uv_sphere())


def test_antialiased_radiance_is_the_mean_of_the_pixels_samples(renderer, sphere):
    """Against a frame three times as fine with one sample a pixel: its 3 x 3 blocks are the
    antialiased pixels (the samples sit where the pixel's thirds have their centres), and the
    centre sample of each block is the pixel centre's own ray (range and normals)."""
    k = Intrinsics.from_fov(40, 32, 30.0)
    fine = Intrinsics(120, 96, 3 * k.fx, 3 * k.fy, 3 * (k.cx + 0.5) - 0.5,
                      3 * (k.cy + 0.5) - 0.5)
    pose = look_at((0.3, -4.0, 1.2), (0.1, 0.0, 0.0))
    light = Lighting((0.6, -0.5, 0.62), albedo=0.3, brdf="lambert")
    one = RenderOptions(shadows=False)
    aa = renderer.render(sphere, View(pose, k), light, RenderOptions(shadows=False,
                                                                     antialias=3))
    ref = renderer.render(sphere, View(pose, fine), light, one)
    plain = renderer.render(sphere, View(pose, k), light, one)
    assert aa.radiance.shape == (32, 40) and aa.radiance.dtype == np.float32
    assert np.allclose(aa.radiance, _block_mean(ref.radiance, 3), rtol=1e-5, atol=1e-7)
    # range and normals: the pixel centre's ray, as without antialiasing
    assert np.array_equal(np.isfinite(aa.range), np.isfinite(plain.range))
    hit = np.isfinite(plain.range)
    assert hit.sum() > 300
    assert np.allclose(aa.range[hit], plain.range[hit], rtol=1e-6)
    assert np.allclose(aa.normals[hit], plain.normals[hit], atol=1e-5)
    assert np.allclose(aa.range, ref.range[1::3, 1::3], rtol=1e-6, equal_nan=True)
    # smooth shading inside: the mean of a pixel's samples is its centre's value; at the
    # limb a pixel is as bright as the share of it the sphere covers
    inner = hit.copy()
    for axis in (0, 1):
        for step in (1, -1):
            inner &= np.roll(hit, step, axis=axis)
    lit = inner & (plain.radiance > 0.1)  # away from the kink at the terminator
    assert np.allclose(aa.radiance[lit], plain.radiance[lit], rtol=0.02)
    limb = hit & ~inner
    assert aa.radiance[limb].sum() < plain.radiance[limb].sum()
    assert np.all(plain.radiance[~hit] == 0) and (aa.radiance[~hit] > 0).sum() > 10


def _centroid_errors(renderer, antialias: int) -> tuple[np.ndarray, np.ndarray]:
    """A boulder 1.2 px across crossing 2 px of a black frame in steps of 0.1 px: how far its
    brightness centroid's offset from its true centre strays from the offset's median (px;
    a steady offset, from its faceted shading, is no jitter), and its total brightness."""
    from asteroid.boulders import icosahedron

    v, f = icosahedron()
    k = Intrinsics.from_fov(24, 24, 20.0)
    distance = 100.0
    radius = 0.6 * distance / k.fx  # 1.2 px across
    scene = MeshScene(v * radius, f)
    light = Lighting((0.0, -1.0, 0.0), albedo=0.3, brdf="lambert")  # behind the camera
    px = distance / k.fx  # metres per pixel at the boulder
    errors, flux = [], []
    for i in range(21):
        x = (0.1 * i - 1.0 + 0.17) * px
        pose = look_at((x, -distance, 0.4 * px), (x, 0.0, 0.4 * px))
        frame = renderer.render(scene, View(pose, k), light,
                                RenderOptions(shadows=False, antialias=antialias))
        r = frame.radiance.astype(np.float64)
        rows, cols = np.mgrid[0:k.height, 0:k.width]
        c = np.array([(r * cols).sum(), (r * rows).sum()]) / max(r.sum(), 1e-30)
        truth = pose.project(np.zeros((1, 3)), k)[0]
        errors.append(c - truth if r.sum() > 0 else np.full(2, np.inf))
        flux.append(r.sum())
    e = np.array(errors)
    return np.linalg.norm(e - np.median(e, axis=0), axis=1), np.array(flux)


def test_a_boulder_smaller_than_a_pixel_stays_put_when_antialiased(renderer):
    """One sample a pixel draws a sub-pixel boulder on whichever pixel centres it happens to
    cover, so its image jumps as it moves (the corners a tracker follows jitter by tenths of
    a pixel between frames); 3 x 3 samples follow it to a tenth of a pixel or better."""
    plain, plain_flux = _centroid_errors(renderer, 1)
    aa, aa_flux = _centroid_errors(renderer, 3)
    assert np.median(plain) > 0.2 and plain.max() > 0.45  # it snaps to pixel centres
    assert np.median(aa) < 0.4 * np.median(plain) and aa.max() < 0.2
    # its brightness: on one pixel centre or two without; about steady with
    assert plain_flux.max() > 3 * plain_flux.min()
    assert aa_flux.max() < 1.15 * aa_flux.min()


@pytest.mark.parametrize("bad", [0, 2, 4, 9, True, 3.0])
def test_antialias_must_be_a_small_odd_integer(bad):
    with pytest.raises(InvalidParameterError, match="antialias"):
        RenderOptions(antialias=bad)


def test_scenarios_set_antialias_in_their_render_table():
    from pathlib import Path

    from render.scenario import load_scenario, parse_scenario

    example = Path(__file__).resolve().parents[2] / "examples" / "asteroid_approach.toml"
    assert load_scenario(example).options.antialias == 3
    table = {"name": "aa", "scene": {"type": "asteroid", "body": "body.npz"},
             "trajectory": {"type": "approach", "start_distance": 9.0, "end_distance": 5.0}}
    assert parse_scenario(table).options.antialias == 1
    assert parse_scenario({**table, "render": {"antialias": 5}}).options.antialias == 5
    for bad in (2, 99, "3"):
        with pytest.raises(InvalidParameterError, match="antialias"):
            parse_scenario({**table, "render": {"antialias": bad}})
