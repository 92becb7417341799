"""Lights drawn per pixel (RenderParams.light_samples): the material mode's shadow rays go to k
lights a pixel drawn in proportion to their unshadowed light there, weighted by 1 / (k p).  The
draws of seeds 0 .. N-1 average to the exact image within the bound their stratification gives,
against the float64 brute-force reference; the draws do not depend on threads or traversal; bad
settings are refused before any kernel runs."""

import dataclasses
import math
import subprocess
import sys

import numpy as np
import pytest

import reference as R
from gridrt.app.viewer.accumulate import Accumulator
from gridrt.config import MAX_LIGHT_SAMPLES, GridParams, RenderParams
from gridrt.errors import InputError
from gridrt.grid import GridBuilder
from gridrt.trace.material import draw_shift, drawn_segments
from gridrt.trace.records import HitPoints, make_draws
from gridrt.trace.render import GUIDE_BLOCK, GUIDE_FLOOR, Looks, Renderer, segment_buffers
from helpers.material_scene import CAM, H, W, _diag, compare, engine_lights, engine_surface, scene

def _render(tris, looks, grid, renderer=None, size=(W, H), **kw):
    params = RenderParams(width=size[0], height=size[1], shading="material", shadows=True, **kw)
    res = (renderer or Renderer()).render(grid, tris, CAM, params, looks=Looks(tris, engine_surface(looks),
                                                                               looks.normals, engine_lights(looks)))
    return res, res.hdr.copy()


def _guide_min(renderer):
    """(H, W): the least guide factor of any light at each pixel (Renderer.guide of its last render)."""
    guide, bw = renderer.guide
    y, x = np.mgrid[0:H, 0:W]
    return guide.min(axis=1)[(y // GUIDE_BLOCK) * bw + x // GUIDE_BLOCK]


@pytest.mark.parametrize("k,traversal,threads", [(1, "cgt", 2), (2, "dda", 1), (1, "cgt", 3)])
def test_draws_average_to_the_exact_image(rng, k, traversal, threads):
    """Exact (every light) equals the float64 brute force; the mean of N = 32 draws is within
    L t_vd total / (k N g) of the exact colours at every hit pixel (each light drawn within one of
    N k p times: the stratified draws; g the least guide factor there), their errors cancel over
    the image, the first draw alone is not within the bound, and fewer rays are cast."""
    tris, looks = scene(rng)
    ref = R.ref_material(tris, CAM, W, H, looks, shadows=True, shadow_offset=1e-6 * _diag(tris))
    g = GridBuilder().build(tris)
    res, exact = _render(tris, looks, g, traversal=traversal, threads=threads)
    inside = compare(res, ref, True)
    assert np.abs(exact[inside] - ref.colour[inside]).max() < 1e-4   # exact: the brute force's colours
    L, N = len(looks.lights), 32
    renderer = Renderer()
    total, first, rays = 0.0, None, []
    for seed in range(N):
        r, hdr = _render(tris, looks, g, renderer, traversal=traversal, threads=threads, light_samples=k,
                         light_seed=seed)
        assert np.array_equal(r.tri, res.tri)
        rays.append(r.stats["shadow_rays_per_pixel"])
        total = total + hdr.astype(np.float64)
        if first is None:
            first = hdr
    mean = total / N
    # the stratification bound, from the reference's own terms and the least guide factor g at the
    # pixel (p >= g w / total for every light; slack for float32 buffers)
    bound = L * ref.tvd * ref.light_total[..., None] / (k * N * _guide_min(renderer)[..., None]) * (1 + 1e-4) + 1e-5
    hit = res.tri >= 0
    assert np.all(mean[~hit] == -1.0)
    err = np.abs(mean - exact)[hit]
    assert np.all(err <= bound[hit]), (err - bound[hit]).max()
    # no bias: over all hit pixels the errors cancel (1e-4 of the light here; a 2% one is 1.7e-2)
    assert abs((mean - exact)[hit].sum() / exact[hit].sum()) < 2e-3
    err1 = np.abs(first - exact)[hit]
    assert (err1 > bound[hit]).any()          # one draw is noisy where a drawn light is blocked
    assert np.sqrt((err ** 2).mean()) < np.sqrt((err1 ** 2).mean()) / 4
    assert max(rays) <= k and max(rays) < res.stats["shadow_rays_per_pixel"]


@pytest.mark.parametrize("grid", ["uniform", pytest.param("two_level", marks=pytest.mark.slow)])
def test_light_guide_against_brute_force(rng, grid):
    """The guide: in each GUIDE_BLOCK square, GUIDE_FLOOR for the lights whose shadow ray from the
    hit at the square's centre pixel a float64 brute force finds blocked, 1 for the others (and
    for misses and lights behind the hit); squares at the image's edges are cut, their centre
    clamped into the image."""
    tris, looks = scene(rng)
    looks = dataclasses.replace(looks, normals=None)   # (n_s = n_g: a light lights a hit where n_g . l > 0)
    g = GridBuilder().build(tris, GridParams(grid=grid))
    renderer = Renderer()
    w, h = 251, 189   # (squares cut at the right and bottom edges)
    _render(tris, looks, g, renderer, size=(w, h), light_samples=1, threads=2)
    guide, bw = renderer.guide
    bh = -(-h // GUIDE_BLOCK)
    assert bw == -(-w // GUIDE_BLOCK) and guide.shape == (bw * bh, len(looks.lights))
    by, bx = np.divmod(np.arange(bw * bh), bw)
    py = np.minimum(by * GUIDE_BLOCK + GUIDE_BLOCK // 2, h - 1)
    px = np.minimum(bx * GUIDE_BLOCK + GUIDE_BLOCK // 2, w - 1)
    o, d = R.ref_camera_rays(CAM.eye, CAM.target, CAM.up, CAM.fov, w, h)
    o, d = o[py * w + px], d[py * w + px]
    h = R.ref_cast(tris, o, d)
    want = np.ones_like(guide)
    hit = np.flatnonzero(h.tri >= 0)
    T = tris.astype(np.float64)[h.tri[hit]]
    ng = np.cross(T[:, 1] - T[:, 0], T[:, 2] - T[:, 0])
    ng /= np.linalg.norm(ng, axis=1, keepdims=True)
    ng = np.where(((ng * d[hit]).sum(1) > 0)[:, None], -ng, ng)
    p = o[hit] + h.t[hit, None] * d[hit] + ng * 1e-6 * _diag(tris)
    for li, (kind, xyz, rgb, falloff) in enumerate(looks.lights):
        to = np.asarray(xyz) - p if kind == "point" else np.broadcast_to(2.0 * _diag(tris) * np.asarray(xyz), p.shape)
        lit = (ng * to).sum(1) > 0
        blocked = R.ref_cast(tris, p[lit], to[lit], 0.0, 1.0).tri >= 0
        want[hit[lit][blocked], li] = GUIDE_FLOOR
    assert (want == GUIDE_FLOOR).sum() > 10 and (want == 1).sum() > 10   # both kinds are there
    assert np.array_equal(guide, want)


def test_draws_do_not_depend_on_threads_or_traversal(rng):
    """One seed's image and colours are the same at 1, 2 and 3 threads and through DDA and CGT;
    another seed draws other lights."""
    tris, looks = scene(rng)
    g = GridBuilder().build(tris, GridParams(grid="two_level"))
    _, a = _render(tris, looks, g, light_samples=2, light_seed=5, threads=1, traversal="dda")
    for threads in (2, 3):
        _, b = _render(tris, looks, g, light_samples=2, light_seed=5, threads=threads)
        assert np.array_equal(a, b)
    _, c = _render(tris, looks, g, light_samples=2, light_seed=6, threads=2)
    assert not np.array_equal(a, c)


def test_one_light_is_exact_either_way(rng):
    """With one light there is nothing to draw: every light_samples renders the exact image."""
    tris, looks = scene(rng)
    looks = dataclasses.replace(looks, lights=looks.lights[:1])
    g = GridBuilder().build(tris)
    r0, h0 = _render(tris, looks, g)
    r1, h1 = _render(tris, looks, g, light_samples=3, light_seed=7)
    assert np.array_equal(r0.image, r1.image) and np.array_equal(h0, h1)


def _weights(lights, p, ng, ns):
    """numpy: each light's n_s . l (/ d^2 with falloff) times its r + g + b, 0 where n_g . l <= 0."""
    out = np.zeros((len(p), len(lights)))
    for li, row in enumerate(lights):
        if row[0] == 0.0:
            v = row[1:4] - p
            dist = np.linalg.norm(v, axis=1)
            u = v / dist[:, None]
        else:
            u, dist = np.broadcast_to(row[1:4], p.shape), np.full(len(p), np.inf)
        s = (ns * u).sum(1)
        s = np.where(((ng * u).sum(1) > 0) & (s > 0), s, 0.0)
        if row[7] == 1.0 and row[0] == 0.0:
            s = s / dist ** 2
        out[:, li] = s * row[4:7].sum()
    return out


def _hits(rng, n):
    pos = rng.uniform(-1, 1, (n, 3))
    ng = rng.normal(size=(n, 3))
    ng /= np.linalg.norm(ng, axis=1, keepdims=True)
    ns = ng + rng.normal(0, 0.3, (n, 3))
    ns /= np.linalg.norm(ns, axis=1, keepdims=True)
    ns = np.where(((ns * ng).sum(1) < 0)[:, None], -ns, ns)
    acc = np.zeros((n, 3), np.float32)
    acc[rng.random(n) < 0.1, 0] = -1.0   # misses
    return HitPoints(pos, ng, ns.astype(np.float32), np.ones((n, 3), np.float32), acc)


def _draw(lights, hp, W_, k, seed, order=None):
    """drawn_segments of every pixel (in ``order``, default pixel order): (lit, factor, start, segs)."""
    n, K = len(hp.pos), min(k, len(lights))
    lit, fac = np.empty((n, K), np.int32), np.empty((n, K))
    segs = segment_buffers(n * K)
    order = np.arange(n, dtype=np.int64) if order is None else order
    start = drawn_segments(lights, hp, W_, make_draws(k, draw_shift(seed), lit, fac), 1e-6, 10.0, order, segs,
                           np.empty((0, 7)))
    return lit, fac, start, segs


@pytest.mark.parametrize("k", [1, 3, 8])
def test_drawn_lights_are_stratified(rng, k):
    """Over seeds 0 .. 2^m - 1 each light is drawn within one of N k p times (p from numpy's own
    weights), lights that do not light a hit (behind it, or black) never; every draw's factors sum
    to 1 over p (an unbiased estimate: sum p f = 1)."""
    n, W_ = 3000, 60
    hp = _hits(rng, n)
    lights = np.array([[0, 2.0, 1.0, 0.5, 0.7, 0.6, 0.5, 0], [0, -1.5, 2.0, 1.0, 3.0, 2.0, 2.0, 1],
                       [1, 0.0, 1.0, 0.0, 0.3, 0.3, 0.4, 0], [0, 0.0, -3.0, 0.0, 1.0, 1.0, 1.0, 0],
                       [0, 0.5, 0.5, 3.0, 0.0, 0.0, 0.0, 0], [1, 0.6, 0.0, 0.8, 0.2, 0.5, 0.1, 0]])
    w = _weights(lights, hp.pos, hp.ng, hp.ns.astype(np.float64))
    w[hp.acc[:, 0] < 0] = 0.0
    p = w / np.where(w.sum(1) > 0, w.sum(1), 1.0)[:, None]
    K = min(k, len(lights))
    N = 16
    counts = np.zeros((n, len(lights)))
    for seed in range(N):
        lit, fac, _, _ = _draw(lights, hp, W_, k, seed)
        f = np.zeros((n, len(lights)))
        rows = np.repeat(np.arange(n), K)[lit.ravel() >= 0]
        f[rows, lit.ravel()[lit.ravel() >= 0]] = fac.ravel()[lit.ravel() >= 0]
        drawn = f > 0
        assert not (drawn & (w == 0)).any()
        some = w.sum(1) > 0
        assert np.allclose((p * f).sum(1)[some], 1.0, rtol=1e-9) and not drawn[~some].any()
        counts += np.rint(f * k * p)
    assert np.all(np.abs(counts - N * k * p) <= 1 + 1e-6)
    assert (counts[:, 4] == 0).all() and (counts > 0).sum() > n
    assert ((w[:, :4] == 0) & (hp.acc[:, :1] >= 0)).sum() > n // 4    # lights behind hits: there, never drawn


def test_drawn_segments_light_by_light(rng):
    """Each light's segments form one run, in the order given, one per pixel that drew it: from
    the light (a point light's position, or far along a directional one's vector from the hit
    moved off its surface) back to that point, weighted by n_s . l times the factor."""
    n, W_ = 2000, 50
    hp = _hits(rng, n)
    lights = np.array([[0, 2.0, 1.0, 0.5, 0.7, 0.6, 0.5, 0], [0, -1.5, 2.0, 1.0, 3.0, 2.0, 2.0, 1],
                       [1, 0.0, 1.0, 0.0, 0.3, 0.3, 0.4, 0]])
    order = rng.permutation(n).astype(np.int64)
    lit, fac, start, segs = _draw(lights, hp, W_, 2, 3, order)
    w = _weights(lights, hp.pos, hp.ng, hp.ns.astype(np.float64)) / lights[:, 4:7].sum(1)   # n_s . l (/ d^2)
    rank = np.empty(n, np.int64)
    rank[order] = np.arange(n)
    assert start[0] == 0 and np.all(np.diff(start) >= 0)
    for li in range(len(lights)):
        rows = segs.rows[start[li]:start[li + 1]]
        drew = order[np.flatnonzero((lit == li).any(1))]     # (lit and fac: a row per place in the order)
        assert np.array_equal(rows, drew) and np.all(np.diff(rank[rows]) > 0)
        f = fac[rank[rows]][lit[rank[rows]] == li]
        assert np.allclose(segs.weight[start[li]:start[li + 1]], w[rows, li] * f, rtol=1e-12)
        p0 = hp.pos[rows] + hp.ng[rows] * 1e-6
        end = lights[li, 1:4] * 10.0 + p0 if lights[li, 0] == 1 else np.broadcast_to(lights[li, 1:4], p0.shape)
        assert np.allclose(segs.o[start[li]:start[li + 1]], end, rtol=0, atol=1e-12)
        assert np.allclose(segs.o[start[li]:start[li + 1]] + segs.d[start[li]:start[li + 1]], p0, rtol=0, atol=1e-12)


def test_draws_at_extremes(rng):
    """A light at 1e-160 of a hit with inverse-square falloff (an infinite weight) is that pixel's
    light, factor 1 (no NaN: the pixel is white where it is not blocked, as in the exact sum); a
    hit no light lights draws none."""
    n = 4
    hp = _hits(rng, n)
    hp.acc[:, 0] = 0.0
    ng = hp.ng[0]
    hp.pos[0] = 0.0
    lights = np.array([[0, *(ng * 1e-160), 1.0, 1.0, 1.0, 1],
                       [0, *(hp.pos[0] + ng), 0.5, 0.5, 0.5, 0]])
    hp.ns[0] = ng
    hp.pos[1:] = hp.pos[0] + 5.0 * ng          # beyond both lights: behind them, facing away
    hp.ng[1:] = ng
    hp.ns[1:] = ng
    lit, fac, start, segs = _draw(lights, hp, 2, 1, 0)
    assert lit[0].tolist() == [0] and fac[0].tolist() == [1.0] and start.tolist() == [0, 1, 1]
    assert segs.weight[0] == np.inf
    assert (lit[1:] == -1).all() and (fac[1:] == 0).all() and np.isfinite(fac).all()


@pytest.mark.parametrize("field,value", [("light_samples", -1), ("light_samples", MAX_LIGHT_SAMPLES + 1),
                                         ("light_samples", 1.5), ("light_samples", "2x"),
                                         ("light_samples", math.inf), ("light_samples", math.nan),
                                         ("light_seed", -1), ("light_seed", 2**31), ("light_seed", None)])
def test_bad_settings_are_refused(field, value):
    """In one line naming the setting, whatever the shading (the memory check of shadows reads the
    count too)."""
    for kw in ({}, dict(shading="material", shadows=True)):
        with pytest.raises(InputError, match=field.replace("_", " ")):
            RenderParams(**{field: value}, **kw)


def test_cli_refuses_a_bad_count_in_one_line(tmp_path):
    p = subprocess.run([sys.executable, "-m", "gridrt", "dump", "--scene", "marbles", "--count", "10", "--frames", "1",
                        "--size", "16x16", "--light-samples", "99", "--out", str(tmp_path / "o")],
                       capture_output=True, text=True, timeout=300)
    assert p.returncode != 0 and "Traceback" not in p.stderr
    assert p.stderr.strip().splitlines() == [f"gridrt: error: light samples must be between 0 and {MAX_LIGHT_SAMPLES}, "
                                             "got 99"], p.stderr


def test_accumulator_averages_colours_before_clamping():
    """With hdr the shown image is the rounded mean of 255 x the unclamped colours at hit pixels
    (two draws of 1.6 and 0 give 0.8, where the clamped images' mean is 0.5) and of the image's
    values at misses; the first sample is shown as it is."""
    img = np.zeros((1, 2, 4), np.uint8)
    img[..., 3] = 255
    img[0, 1, :3] = 40      # a miss: the background
    a, b = img.copy(), img.copy()
    a[0, 0, :3] = 255
    ha = np.array([[[1.6, 1.6, 0.2], [-1, -1, -1]]], np.float32)
    hb = np.array([[[0.0, 0.0, 0.2], [-1, -1, -1]]], np.float32)
    acc = Accumulator()
    assert acc.add("k", a, ha) is a
    shown = acc.add("k", b, hb)
    assert shown[0, 0, :3].tolist() == [204, 204, 51] and shown[0, 1].tolist() == [40, 40, 40, 255]
