"""Ray casting through the grid against the brute-force float64 caster (tests/reference.py).

Over 100k rays on three scenes (random triangles, a closed icosphere, the Utah teapot shipped in
assets/), starting inside and outside the grid, aimed and random, axis-parallel
and through cell corners, plus camera rays.  ``cast_rays`` must return, for every ray, the same
triangle as the reference (or, on an exact tie, a triangle at the same t), t within 1e-5
relative, and a miss exactly when the reference misses.  The watertight and the fast
(Moller-Trumbore) tests are both checked; disagreements are tolerated only on rays the reference
flags as grazing an edge (within 1e-9 barycentric) and their number is bounded and printed.
Thread counts must not change any result bit; tmin / tmax follow the documented open interval.
"""

import numpy as np
import pytest
from numba import njit

import reference as R
from conftest import random_rays
from gridrt.camera import Camera
from gridrt.config import RenderParams
from gridrt.grid import GridParams, build_grid
from gridrt.trace import cast_rays, render
from gridrt.trace.intersect import intersect_watertight, ray_shear
from gridrt.trace.traverse import CHUNK, SIDE_BY_SIDE
from helpers.rays import GRAZE, assert_hits_match, get_case


# ----------------------------------------------------------------------------------------------
# the reference itself


def test_ref_cast_hand_computed():
    tris = np.array(
        [
            [[0, 0, 0], [1, 0, 0], [0, 1, 0]],  # z = 0
            [[0, 0, 0.5], [1, 0, 0.5], [0, 1, 0.5]],  # z = 0.5
            [[2, 2, 2], [3, 3, 3], [4, 4, 4]],  # degenerate: never hit
        ],
        np.float32,
    )
    o = np.array([[0.25, 0.125, 1], [0.25, 0.125, -2], [0.8, 0.8, 1], [0.25, 0.125, 0.25], [-1, 0.2, 0]])
    d = np.array([[0, 0, -1], [0, 0, 2], [0, 0, -1], [0, 0, 1], [1, 0, 0]], float)
    h = R.ref_cast(tris, o, d)
    assert h.tri.tolist() == [1, 0, -1, 1, -1]  # nearest; double-sided; miss; inside; in-plane
    np.testing.assert_allclose(h.t[:2], [0.5, 1.0])  # t in units of the (non-unit) direction
    assert h.t[3] == 0.25 and np.isinf(h.t[2]) and np.isinf(h.t[4])
    np.testing.assert_allclose(h.u[:2], [0.25, 0.25])
    np.testing.assert_allclose(h.v[:2], [0.125, 0.125])
    np.testing.assert_allclose(h.t2[:2], [1.0, 1.25])  # second triangle behind the first
    np.testing.assert_allclose(h.edge[:2], [0.125, 0.125])
    np.testing.assert_allclose(h.graze[2], -0.6)  # (0.8, 0.8) is 0.6 outside in 1 - u - v
    # open interval tmin < t < tmax
    h = R.ref_cast(tris, o[:1], d[:1], tmin=0.5)
    assert h.tri[0] == 0 and h.t[0] == 1.0
    h = R.ref_cast(tris, o[:1], d[:1], tmax=0.5)
    assert h.tri[0] == -1
    # a hit exactly on the shared edge of two triangles is a tie
    quad = np.array([[[0, 0, 0], [1, 0, 0], [1, 1, 0]], [[0, 0, 0], [1, 1, 0], [0, 1, 0]]], np.float32)
    h = R.ref_cast(quad, [[0.5, 0.5, 1]], [[0, 0, -1]])
    assert h.tri[0] in (0, 1) and h.t[0] == h.t2[0] == 1.0 and h.edge[0] == 0.0


def test_compare_hits_classifies():
    tris = np.array([[[0, 0, 0], [1, 0, 0], [1, 1, 0]], [[0, 0, 0], [1, 1, 0], [0, 1, 0]]], np.float32)
    o = np.array([[0.5, 0.5, 1], [0.7, 0.2, 1], [5, 5, 1]])
    d = np.array([[0, 0, -1]] * 3, float)
    ref = R.ref_cast(tris, o, d)
    other = 1 - ref.tri[0]
    diff = R.compare_hits([1.0, 1.0, np.inf], [other, 0, -1], ref)
    assert diff.bad.tolist() == [] and diff.tie.tolist() == [0]
    diff = R.compare_hits([1.0, 1.0, 1.0], [ref.tri[0], 1, 0], ref)
    assert diff.bad.tolist() == [1, 2]
    diff = R.compare_hits([1.0, 1.1, np.inf], [ref.tri[0], 0, -1], ref)
    assert diff.bad.tolist() == [1] and diff.t_off.tolist() == [1]


def test_camera_rays_match_reference():
    """engine Camera.rays == the reference pinhole model (pixel centres, top-left origin)."""
    for cam, (w, h) in (
        (Camera(eye=(0, 0, 5), target=(0, 0, 0), fov=45), (8, 6)),
        (Camera(eye=(3, -2, 1), target=(0.5, 0.2, -0.3), up=(0, 0, 1), fov=70), (5, 9)),
        (Camera(eye=(-1, 2, -3), target=(1, 1, 1), up=(0.3, 1, 0.1), fov=20), (1, 1)),
    ):
        o, d = cam.rays(w, h)
        ro, rd = R.ref_camera_rays(cam.eye, cam.target, cam.up, cam.fov, w, h)
        assert o.shape == (w * h, 3) and d.shape == (w * h, 3)
        np.testing.assert_allclose(o, ro, rtol=0, atol=1e-12)
        np.testing.assert_allclose(d, rd, rtol=0, atol=1e-12)
    # orientation: top-left pixel looks up and left, bottom-right down and right
    o, d = Camera(eye=(0, 0, 5), target=(0, 0, 0)).rays(4, 4)
    assert d[0, 0] < 0 and d[0, 1] > 0 and d[-1, 0] > 0 and d[-1, 1] < 0


# ----------------------------------------------------------------------------------------------
# scenes and ray sets (built once per module; the brute-force reference is the slow part)


SCENES = ["random", "icosphere", "teapot"]


# ----------------------------------------------------------------------------------------------
# engine vs reference


@pytest.mark.parametrize("watertight", [True, False], ids=["watertight", "fast"])
@pytest.mark.parametrize("scene", SCENES)
def test_cast_rays_match_reference(scene, watertight):
    c = get_case(scene)
    hits = cast_rays(c.grid, c.tris, c.o, c.d, watertight=watertight)
    assert hits.t.shape == (len(c.o),) and hits.t.dtype == np.float64
    assert hits.tri.shape == (len(c.o),) and hits.tri.dtype == np.int32
    assert_hits_match(hits, c.ref, f"{scene} {'watertight' if watertight else 'fast'}", c.o, c.d)
    # the hit point from (u, v) lies on the ray at t
    h = np.flatnonzero(hits.tri >= 0)
    T = c.tris[hits.tri[h]].astype(np.float64)
    u, v = hits.u[h, None], hits.v[h, None]
    p_bary = (1 - u - v) * T[:, 0] + u * T[:, 1] + v * T[:, 2]
    p_ray = c.o[h] + hits.t[h, None] * c.d[h]
    scale = np.abs(c.tris).max() + np.abs(c.o).max()
    np.testing.assert_allclose(p_bary, p_ray, rtol=0, atol=1e-6 * scale)


def test_total_ray_count():
    """The cases above cover at least 100k rays (when the teapot is available)."""
    total = sum(len(get_case(s).o) for s in ("random", "icosphere"))
    assert total >= 95_000
    total += len(get_case("teapot").o)  # skips when the teapot is absent
    print(f"rays checked against the reference per intersection test: {total}")
    assert total >= 100_000


@pytest.mark.parametrize(
    "density,macro,insert",
    [(0.5, 1, "bbox"), (20.0, 8, "bbox"), (4.0, 3, "exact"), (1.0, 16, "exact")],
)
def test_cast_rays_grid_params(density, macro, insert):
    """Grid resolution, macro-cell size and insertion test change no hit."""
    c = get_case("random")
    grid = build_grid(c.tris, GridParams(density=density, macro=macro, insert=insert))
    hits = cast_rays(grid, c.tris, c.o, c.d)
    assert_hits_match(hits, c.ref, f"random density={density} macro={macro} {insert}", c.o, c.d)


def _strategy_names():
    from gridrt.grid import names

    return names()


@pytest.mark.parametrize("strategy", _strategy_names())
def test_cast_rays_every_strategy(strategy):
    """Grids from every build strategy (3 build threads; thread_grids keeps 3 layers that the
    caster must all visit) give the reference hits."""
    c = get_case("icosphere")
    grid = build_grid(c.tris, c.params.replace(strategy=strategy, threads=3))
    hits = cast_rays(grid, c.tris, c.o, c.d)
    assert_hits_match(hits, c.ref, f"icosphere {strategy}", c.o, c.d)


EXTREME = ["far 1e4", "far 1e7", "components 1e-12", "components 1e-200", "components 1e-310",
           "components 5e-324", "scale 1e-150", "scale 1e-08", "scale 1e+08", "scale 1e+150"]


def _extreme_rays(label):
    c = get_case("random")
    rng = np.random.default_rng(8)
    sel = rng.choice(len(c.o), 4000, replace=False)
    o, d = c.o[sel], c.d[sel]
    kind, value = label.split()
    value = float(value)
    if kind == "far":
        return o - value * d, d
    if kind == "scale":
        return o, d * value
    # tiny y component (subnormal for 1e-310 and 5e-324: 1/d overflows), and tiny x on every
    # other ray; some origins sit exactly on cell faces (the "hard" rays of the case)
    d2 = d.copy()
    d2[:, 1] = np.where(d2[:, 1] < 0, -value, value)
    d2[::2, 0] = value
    return o, d2


@pytest.mark.parametrize("label", EXTREME)
def test_extreme_rays(label):
    """Far origins, (sub)normal-tiny direction components and extreme direction scales."""
    c = get_case("random")
    o, d = _extreme_rays(label)
    ref = R.ref_cast(c.tris, o, d)
    assert ref.hit.sum() > 100
    # 1e7 away, float64 barycentrics of both casters lose ~7 digits (checked with exact
    # rational arithmetic: errors of 4e-7 (engine) and 1.5e-6 (reference) on one ray)
    uv_atol = 1e-4 if label.startswith("far") else 1e-6
    assert_hits_match(cast_rays(c.grid, c.tris, o, d), ref, label, o, d, uv_atol=uv_atol)


@pytest.mark.parametrize("scene", ["random", "icosphere"])
def test_threads_identical(scene):
    """1, 2 and 3+ threads give bitwise identical results."""
    c = get_case(scene)
    base = cast_rays(c.grid, c.tris, c.o, c.d, threads=1)
    for n in (2, 3, 7):
        h = cast_rays(c.grid, c.tris, c.o, c.d, threads=n)
        for f in ("t", "tri", "u", "v"):
            assert np.array_equal(getattr(h, f), getattr(base, f)), f"{f} differs between 1 and {n} threads"


def test_tmin_tmax():
    c = get_case("random")
    o, d = c.o[:20_000], c.d[:20_000]
    for tmin, tmax in ((0.3, np.inf), (0.0, 0.7), (0.25, 0.9), (0.0, 1e-9), (1.0, 1.6)):
        ref = R.ref_cast(c.tris, o, d, tmin=tmin, tmax=tmax)
        hits = cast_rays(c.grid, c.tris, o, d, tmin=tmin, tmax=tmax)
        diff = assert_hits_match(hits, ref, f"tmin={tmin} tmax={tmax}", o, d)
        assert ((hits.t > tmin) & (hits.t < tmax) | (hits.tri < 0)).all()
        assert len(diff.bad) == 0


def test_non_unit_directions():
    """t is measured in units of the given direction."""
    c = get_case("icosphere")
    rng = np.random.default_rng(5)
    o, d = c.o[:10_000], c.d[:10_000] * rng.uniform(0.01, 100.0, (10_000, 1))
    ref = R.ref_cast(c.tris, o, d)
    hits = cast_rays(c.grid, c.tris, o, d)
    assert_hits_match(hits, ref, "scaled directions", o, d)


@pytest.mark.parametrize("scene", SCENES)
def test_render_buffers_match_reference(scene):
    """render()'s t and tri buffers equal the reference on the camera's own rays."""
    c = get_case(scene)
    w, h = c.cam_size
    res = render(c.grid, c.tris, c.camera, RenderParams(width=w, height=h, shading="lambert", traversal="dda"))
    ref = R.ref_cast(c.tris, *R.ref_camera_rays(c.camera.eye, c.camera.target, c.camera.up, c.camera.fov, w, h))
    assert res.image.shape == (h, w, 4) and res.image.dtype == np.uint8
    assert res.t.shape == (h, w) and res.tri.shape == (h, w)
    t = res.t.reshape(-1).astype(np.float64)
    tri = res.tri.reshape(-1)
    # t is stored as float32: compare at float32 precision
    diff = R.compare_hits(t, tri, ref, t_rtol=1e-6, graze_tol=GRAZE)
    assert len(diff.bad) == 0, f"{len(diff.bad)} pixels differ from the reference, first {diff.bad[:5].tolist()}"
    assert ref.hit.mean() > 0.05, "camera framing sees almost nothing: the test would be vacuous"


def test_any_hit():
    """any_hit=True reports a hit exactly when the reference does, and the reported (tri, t) is a
    real hit of that triangle inside (tmin, tmax)."""
    c = get_case("icosphere")
    o, d = c.o[:20_000], c.d[:20_000]
    h = cast_rays(c.grid, c.tris, o, d, any_hit=True)
    ref = c.ref
    hit = h.tri >= 0
    assert np.array_equal(hit, ref.tri[:20_000] >= 0)
    idx = np.flatnonzero(hit)
    own = np.array([R.ref_cast(c.tris[h.tri[i] : h.tri[i] + 1], o[i : i + 1], d[i : i + 1]).t[0] for i in idx[:2000]])
    np.testing.assert_allclose(h.t[idx[:2000]], own, rtol=1e-9)


def cube_scene():
    """Axis-aligned unit cubes (12 triangles each) on an integer lattice, some touching."""
    corners = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], np.float32)
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    one = np.array([[corners[a], corners[b], corners[c]] for q in quads for a, b, c in ((q[0], q[1], q[2]), (q[0], q[2], q[3]))])
    offsets = [(0, 0, 0), (1, 0, 0), (0, 2, 0), (2, 2, 1), (3, 0, 3)]
    return np.concatenate([one + np.float32(off) for off in offsets]).astype(np.float32)


@pytest.mark.parametrize("watertight", [True, False], ids=["watertight", "fast"])
def test_cubes_axis_aligned_rays(watertight):
    """Axis-aligned faces and rays: along lattice lines (through edges and vertices: ties),
    in face planes, and diagonals through lattice points."""
    tris = cube_scene()
    rng = np.random.default_rng(12)
    grid = build_grid(tris, GridParams(density=6.0, macro=2))
    n = 6000
    o = rng.integers(-1, 6, (n, 3)).astype(np.float64) + rng.choice([0.0, 0.5, 0.25], (n, 3))
    d = np.zeros((n, 3))
    d[np.arange(n), rng.integers(0, 3, n)] = rng.choice([-1.0, 1.0], n)
    diag = rng.random(n) < 0.3
    d[diag] = rng.choice([-1.0, 1.0], (int(diag.sum()), 3))
    ref = R.ref_cast(tris, o, d)
    assert ref.hit.sum() > 400
    hits = cast_rays(grid, tris, o, d, watertight=watertight)
    assert_hits_match(hits, ref, f"cubes {'watertight' if watertight else 'fast'}", o, d)


@pytest.mark.parametrize("size,tile", [((1, 1), 16), ((37, 23), 7), ((5, 64), 1), ((64, 5), 256)])
def test_render_sizes_and_tiles(size, tile):
    """Odd image sizes and tile sizes that do not divide them: every pixel is the reference's."""
    c = get_case("icosphere")
    w, h = size
    cam = Camera(eye=(0.3, 0.3, 3.5), target=(0.3, -0.2, 0.1), fov=40.0)
    res = render(c.grid, c.tris, cam, RenderParams(width=w, height=h, tile=tile, shading="normal", traversal="dda"))
    ref = R.ref_render(c.tris, cam, w, h, "normal")
    diff = R.compare_hits(res.t.reshape(-1).astype(np.float64), res.tri.reshape(-1), ref.hits, t_rtol=1e-6, graze_tol=GRAZE)
    assert len(diff.bad) == 0
    assert (np.abs(res.image.astype(int) - ref.image.astype(int)).max(axis=2) > 2).sum() <= max(1, 0.005 * w * h)
    assert (res.image[:, :, 3] == 255).all()


def test_render_threads_identical():
    c = get_case("random")
    cam = c.camera
    outs = [render(c.grid, c.tris, cam, RenderParams(width=48, height=40, threads=n, shadows=True, traversal="dda")) for n in (1, 2, 5)]
    for o in outs[1:]:
        assert np.array_equal(o.image, outs[0].image)
        assert np.array_equal(o.tri, outs[0].tri) and np.array_equal(o.t, outs[0].t)


def test_duplicates_and_degenerates():
    """Duplicated triangles (exact ties: either copy is right) and zero-area triangles (never hit)."""
    from conftest import random_scene

    rng = np.random.default_rng(13)
    tris = random_scene(rng, 250, "mixed", None, dup_frac=0.3, degen_frac=0.2)
    grid = build_grid(tris, GridParams(density=4.0, macro=2))
    lo, hi = tris.reshape(-1, 3).min(0), tris.reshape(-1, 3).max(0)
    o, d = random_rays(rng, 20_000, lo, hi, outside=0.3, aim=True)
    ref = R.ref_cast(tris, o, d)
    for wt in (True, False):
        hits = cast_rays(grid, tris, o, d, watertight=wt)
        assert_hits_match(hits, ref, f"duplicates watertight={wt}", o, d)
        assert (ref.hit & (ref.t2 == ref.t)).sum() > 100  # the duplicates really produce ties
        area = np.linalg.norm(np.cross(*(R.tris64(tris)[:, 1:] - R.tris64(tris)[:, :1]).transpose(1, 0, 2)), axis=1)
        assert (area[hits.tri[hits.tri >= 0]] > 0).all()


@njit(cache=True)
def _exhaustive_wt(tris, o, d, tmin, tmax, out_t, out_f, out_u, out_v):
    """Each ray (t in (tmin, tmax)) against every triangle with the single-ray watertight test
    itself (intersect_watertight on the vertices permuted by the ray's shear), the nearest kept
    and a tie kept by the lower index: what a traversal of any grid must return bit for bit."""
    for i in range(o.shape[0]):
        sh = ray_shear((o[i, 0], o[i, 1], o[i, 2]), (d[i, 0], d[i, 1], d[i, 2]))
        kx, ky, kz = sh.kx, sh.ky, sh.kz
        bt, bf, bu, bv = tmax, -1, 0.0, 0.0
        for f in range(tris.shape[0]):
            hit, t, u, v = intersect_watertight(
                (np.float64(tris[f, 0, kx]), np.float64(tris[f, 0, ky]), np.float64(tris[f, 0, kz])),
                (np.float64(tris[f, 1, kx]), np.float64(tris[f, 1, ky]), np.float64(tris[f, 1, kz])),
                (np.float64(tris[f, 2, kx]), np.float64(tris[f, 2, ky]), np.float64(tris[f, 2, kz])),
                sh, tmin, np.inf)
            if hit and t < bt:
                bt, bf, bu, bv = t, f, u, v
        out_t[i], out_f[i], out_u[i], out_v[i] = (bt, bf, bu, bv) if bf >= 0 else (np.inf, -1, 0.0, 0.0)


# (two-level: its casts compile apart from the uniform grid's; test_two_level checks them in the quick run)
@pytest.mark.parametrize("kind", ["uniform", pytest.param("two_level", marks=pytest.mark.slow)])
def test_crowded_cells_bit_for_bit(kind):
    """Cells crowded with triangles (a coarse grid over 600 triangles, a third of them duplicates:
    exact ties) through the single-ray traversal, which tests a crowded cell's triangles side by
    side in vector lanes, CHUNK at a time: t, triangle, u and v equal the exhaustive watertight
    test's bit for bit at 1 and 3 threads; with any_hit the hit flags agree and each reported hit
    is that triangle's own; within a finite (tmin, tmax) the hits equal the exhaustive test's in
    that range."""
    from conftest import random_scene

    rng = np.random.default_rng(29)
    tris = random_scene(rng, 600, "mixed", None, dup_frac=0.3, degen_frac=0.05)
    params = GridParams(density=0.3, macro=2, grid=kind) if kind == "uniform" else GridParams(
        grid=kind, top_density=0.05, leaf_density=0.3)
    grid = build_grid(tris, params)
    counts = np.diff(np.asarray(grid.cell_start[0]))
    assert counts.max() >= 3 * CHUNK and (counts >= SIDE_BY_SIDE).sum() > 10  # several chunks, many cells
    lo, hi = tris.reshape(-1, 3).min(0), tris.reshape(-1, 3).max(0)
    o, d = random_rays(rng, 30_000, lo, hi, outside=0.3, aim=True)
    n = len(o)
    ref = np.empty(n), np.empty(n, np.int64), np.empty(n), np.empty(n)
    _exhaustive_wt(tris, o, d, 0.0, np.inf, *ref)
    assert (ref[1] >= 0).mean() > 0.25
    for threads in (1, 3):
        h = cast_rays(grid, tris, o, d, packets=False, threads=threads)
        assert np.array_equal(h.tri, ref[1]), f"{(h.tri != ref[1]).sum()} triangles differ"
        assert np.array_equal(h.t, ref[0]) and np.array_equal(h.u, ref[2]) and np.array_equal(h.v, ref[3])
        a = cast_rays(grid, tris, o, d, packets=False, threads=threads, any_hit=True)
        assert np.array_equal(a.tri >= 0, ref[1] >= 0)
        idx = np.flatnonzero(a.tri >= 0)[:3000]
        for k in idx:
            sub = tris[a.tri[k]:a.tri[k] + 1]
            one = np.empty(1), np.empty(1, np.int64), np.empty(1), np.empty(1)
            _exhaustive_wt(sub, o[k:k + 1], d[k:k + 1], 0.0, np.inf, *one)
            assert one[1][0] == 0 and one[0][0] == a.t[k]
    # a finite range: the nearest hit beyond tmin (often behind the nearest one) and before tmax
    hit_t = ref[0][ref[1] >= 0]
    tmin, tmax = float(np.quantile(hit_t, 0.3)), float(np.quantile(hit_t, 0.9))
    win = np.empty(n), np.empty(n, np.int64), np.empty(n), np.empty(n)
    _exhaustive_wt(tris, o, d, tmin, tmax, *win)
    assert (win[1] >= 0).sum() > 1000 and (win[1] != ref[1]).sum() > 1000  # the range changes many hits
    h = cast_rays(grid, tris, o, d, tmin=tmin, tmax=tmax, packets=False)
    assert np.array_equal(h.tri, win[1]) and np.array_equal(h.t, win[0])
    assert np.array_equal(h.u, win[2]) and np.array_equal(h.v, win[3])
