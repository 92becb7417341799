"""Numerical stability at the extremes: hits against the float64 brute force.

Every test casts rays through the engine and compares each ray's triangle and t with
``tests/reference.py`` (float64 Moller-Trumbore over all triangles, on the same
float32-rounded triangles the engine stores).  A ray may disagree only where the reference itself
calls the case ambiguous: an exact tie (two triangles at the same t) or a ray that passes within
``GRAZE`` (barycentric) of an edge.  Each test prints one ``FIGURE`` line per case (run with
``-s`` or ``-rP`` to see them): rays, hits, ties, grazing rays, wrong rays, largest relative t error.

Cases: scenes scaled by 1e-6 and 1e6 (and measured out to 1e-30 and 1e29; powers of two must give
bitwise the same hits); scenes offset by 1e5, 1e6 and 1e7 from the origin, and a sweep to 1e12
measuring where float32 storage stops keeping hits on the right triangle and showing that a frame
centred on the scene removes that floor; flat scenes (zero extent on one, two or three axes); a
single triangle; one huge triangle among tiny ones; needles and slivers of aspect ratio 1e6 (and
a plane tiled by them, probed at its shared edges); zero-area and duplicated triangles; rays
exactly parallel to the axes with +0.0 and -0.0 components; rays starting on cell boundaries,
on triangles and inside the grid; grazing rays; the camera inside the scene (both traversals);
extreme lambda (one cell, a grid capped by max_cells with a clear warning, and the max_bytes
memory budget with a clear error); extreme direction magnitudes.  Tests that say "regression
test" guard engine defects this work found (since fixed).
"""

import math
import warnings

import numpy as np
import pytest

import reference as R
from conftest import icosphere_tris, random_rays, random_scene, random_triangles
from gridrt.api import RayCaster
from gridrt.camera import Camera
from gridrt.config import GridParams, RenderParams
from gridrt.errors import InputError
from gridrt.grid import GridBuilder, GridCapWarning, build_grid, names
from gridrt.trace import cast_rays, render

#: barycentric distance from an edge under which the reference calls a ray ambiguous
GRAZE = 1e-9
#: same triangle: relative t difference allowed between the engine and the reference
T_RTOL = 1e-6
#: largest fraction of grazing disagreements tolerated in a ray set
MAX_GRAZING = 2e-3
STRATEGIES = names()

# the brute force computes 1 - u - v for parallel rays too (inf - inf): harmless, and not ours
pytestmark = pytest.mark.filterwarnings("ignore:invalid value encountered:RuntimeWarning")


# ----------------------------------------------------------------------------------------------
# helpers


def compare(label, t, tri, ref, graze=GRAZE, t_rtol=T_RTOL, max_grazing=MAX_GRAZING, strict=True):
    """Compare engine hits with a reference; print the FIGURE line; assert no wrong ray (when
    ``strict``).  Returns the :class:`reference.HitDiff`."""
    t = np.asarray(t, np.float64)
    tri = np.asarray(tri)
    diff = R.compare_hits(t, tri, ref, t_rtol=t_rtol, tie_rtol=1e-9, graze_tol=graze)
    n = len(ref.t)
    same = np.flatnonzero((tri == ref.tri) & (tri >= 0))
    terr = float((np.abs(t[same] - ref.t[same]) / np.maximum(np.abs(ref.t[same]), 1e-300)).max()) if len(same) else 0.0
    print(
        f"FIGURE {label}: {n} rays, {int(ref.hit.sum())} hits, {len(diff.tie)} ties, {len(diff.grazing)} grazing, "
        f"{len(diff.bad)} wrong ({len(diff.t_off)} with t off), max |dt|/t {terr:.1e}"
    )
    if strict:
        if len(diff.bad):
            i = diff.bad[:4]
            raise AssertionError(
                f"{label}: {len(diff.bad)} of {n} rays disagree with the brute force; rays {i.tolist()}: engine "
                f"tri {tri[i].tolist()} t {t[i].tolist()}, reference tri {ref.tri[i].tolist()} t {ref.t[i].tolist()}"
            )
        assert len(diff.grazing) <= max(2, max_grazing * n), f"{label}: {len(diff.grazing)} grazing disagreements"
    return diff


def cast_and_compare(label, grid, tris, o, d, ref=None, watertight=True, tmin=0.0, tmax=np.inf, **kw):
    h = cast_rays(grid, tris, o, d, tmin=tmin, tmax=tmax, watertight=watertight)
    if ref is None:
        ref = R.ref_cast(tris, o, d, tmin=tmin, tmax=tmax)
    return h, ref, compare(label, h.t, h.tri, ref, **kw)


def hard_rays(rng, spec, n):
    """Rays that stress the DDA: axis-parallel from cell corners and faces, exact cell
    diagonals, origins on the grid bounds, rays lying in boundary planes."""
    lo, hi, cell, dims = spec.lo, spec.hi, spec.cell, spec.dims
    k = n // 4
    ijk = rng.integers(0, dims + 1, (k, 3))
    o1 = lo + ijk * cell
    o1[:, 0] += rng.uniform(0, 1, k) * cell[0] * (rng.random(k) < 0.5)
    d1 = np.zeros((k, 3))
    d1[np.arange(k), rng.integers(0, 3, k)] = rng.choice([-1.0, 1.0], k)
    o2 = lo + rng.integers(0, dims + 1, (k, 3)) * cell
    d2 = rng.choice([-1.0, 1.0], (k, 3)) * cell
    o3 = rng.uniform(lo, hi, (k, 3))
    ax = rng.integers(0, 3, k)
    o3[np.arange(k), ax] = np.where(rng.random(k) < 0.5, lo[ax], hi[ax])
    d3 = rng.normal(size=(k, 3))
    m = n - 3 * k
    o4 = rng.uniform(lo, hi, (m, 3))
    ax = rng.integers(0, 3, m)
    o4[np.arange(m), ax] = np.where(rng.random(m) < 0.5, lo[ax], hi[ax])
    d4 = rng.normal(size=(m, 3))
    d4[np.arange(m), ax] = 0.0
    return np.concatenate([o1, o2, o3, o4]), np.concatenate([d1, d2, d3, d4])


def mixed_rays(rng, tris, spec, n, pad=0.0):
    """Half aimed at the scene, a quarter random, a quarter :func:`hard_rays` (float64).
    Origins come from the scene's box grown by ``pad`` on every side (and by half its size)."""
    lo = tris.reshape(-1, 3).min(0).astype(np.float64) - pad
    hi = tris.reshape(-1, 3).max(0).astype(np.float64) + pad
    a = random_rays(rng, n // 2, lo, hi, outside=0.5, aim=True)
    b = random_rays(rng, n // 4, lo, hi, outside=0.2)
    c = hard_rays(rng, spec, n - n // 2 - n // 4)
    return np.concatenate([a[0], b[0], c[0]]), np.concatenate([a[1], b[1], c[1]])


def mixed_scene(seed, n=300):
    """Random triangles of every size class (small, medium, huge, slivers) with 5% duplicates and
    5% zero-area ones, plus a closed icosphere: (F, 3, 3) float32 in about [0, 1]^3."""
    rng = np.random.default_rng(seed)
    t = random_scene(rng, n, "mixed", dup_frac=0.05, degen_frac=0.05)
    return np.concatenate([t, icosphere_tris(2, 0.3, (0.5, 0.5, 0.5))]).astype(np.float32)


# ----------------------------------------------------------------------------------------------
# scale


@pytest.fixture(scope="module")
def unit_case():
    tris = mixed_scene(101)
    grid = build_grid(tris, GridParams(density=4.0, macro=2))
    rng = np.random.default_rng(102)
    o, d = mixed_rays(rng, tris, grid.spec, 16_000)
    h = cast_rays(grid, tris, o, d)
    return tris, grid, o, d, h


@pytest.mark.parametrize("scale", [1e-6, 1e6, 1e-30, 1e29])
def test_scaled_scene(unit_case, scale):
    """The unit scene scaled by 1e-6 and 1e6 (and 1e-30, 1e29 near float32's limits): the hits
    equal the brute force on the scaled float32 triangles, and equal the unscaled scene's
    triangles except where float32 rounding of the scaled vertices moved an edge (grazing rays)."""
    tris, grid, o, d, h1 = unit_case
    st = (tris.astype(np.float64) * scale).astype(np.float32)
    g = build_grid(st, GridParams(density=4.0, macro=2))
    assert np.array_equal(g.spec.dims, grid.spec.dims), (g.spec.dims, grid.spec.dims)
    os_ = o * scale
    h, ref, diff = cast_and_compare(f"scale {scale:g}", g, st, os_, d)
    # t is measured along d, so it scales too (up to float32 rounding of the scaled vertices,
    # which grazing hits amplify)
    same = (h.tri == h1.tri) & (h.tri >= 0)
    t_moved = int((np.abs(h.t[same] - h1.t[same] * scale) > 1e-5 * h1.t[same] * scale).sum())
    moved = int((h.tri != h1.tri).sum())
    print(f"FIGURE scale {scale:g}: against the unscaled scene {moved} of {len(o)} rays hit another triangle and "
          f"{t_moved} the same one with t off by > 1e-5 (float32 rounding of the scaled vertices); "
          f"dims {tuple(int(x) for x in g.spec.dims)}")
    assert moved + t_moved <= 5e-3 * len(o)


@pytest.mark.parametrize("exp2", [-20, 20, -100, 90])
def test_power_of_two_scale_is_exact(unit_case, exp2):
    """Scaling scene and ray origins by 2**k is exact in floating point, so every hit must be the
    same triangle at t * 2**k, bit for bit (the grid geometry scales exactly too)."""
    tris, grid, o, d, h1 = unit_case
    s = 2.0 ** exp2
    st = (tris.astype(np.float64) * s).astype(np.float32)
    assert np.array_equal(st.astype(np.float64) / s, tris.astype(np.float64))
    g = build_grid(st, GridParams(density=4.0, macro=2))
    h = cast_rays(g, st, o * s, d)
    assert np.array_equal(h.tri, h1.tri)
    assert np.array_equal(h.t, h1.t * s)
    print(f"FIGURE scale 2^{exp2}: {len(o)} rays, tri and t bitwise equal to the unscaled scene")


# ----------------------------------------------------------------------------------------------
# offset from the origin


def offset_scene(seed=3):
    rng = np.random.default_rng(seed)
    local = np.concatenate([icosphere_tris(3, 0.4, (0.5, 0.5, 0.5)), random_triangles(rng, 300, size=0.08)])
    return local.astype(np.float32), rng


def offset_vector(X):
    return np.array([X, -0.7 * X, 0.3 * X])


def offset_measure(local, o_loc, d, X, strict):
    """Hits of the unit scene moved by X, three ways (see :func:`test_offset_scene`).

    Returns (wrong fraction with float32 storage in world coordinates or None when float32 makes
    every triangle degenerate, engine-vs-brute-force diffs on the stored float32 triangles,
    diffs in the scene-centred frame)."""
    off = offset_vector(X)
    T64 = local.astype(np.float64) + off  # the user's scene, float64 (exact for X <= 1e8)
    o_w = o_loc + off  # the user's rays
    # float64 truth in the user's coordinates: translate by -off, exactly (Sterbenz)
    truth = R.ref_cast(T64 - off, o_w - off, d)
    world = None
    arith = None
    T32 = T64.astype(np.float32)
    try:
        g = build_grid(T32, GridParams(density=4.0))
    except InputError as e:
        assert "degenerate" in str(e)
    else:
        h = cast_rays(g, T32, o_w, d)
        floor = compare(f"offset {X:g} float32 world vs float64 truth", h.t, h.tri, truth, graze=1e-6, t_rtol=np.inf,
                        strict=False)
        world = len(floor.bad) / len(d)
        arith = compare(f"offset {X:g} engine vs brute force on the stored float32 triangles", h.t, h.tri,
                        R.ref_cast(T32, o_w, d), strict=strict)
    c = 0.5 * (T64.reshape(-1, 3).min(0) + T64.reshape(-1, 3).max(0))
    Tc = (T64 - c).astype(np.float32)
    gc = build_grid(Tc, GridParams(density=4.0))
    hc = cast_rays(gc, Tc, o_w - c, d)
    centred = compare(f"offset {X:g} scene-centred frame vs float64 truth", hc.t, hc.tri, truth, graze=1e-6,
                      t_rtol=1e-4, strict=strict)
    return world, arith, centred


@pytest.mark.parametrize("X", [1e5, 1e6, 1e7])
def test_offset_scene(X):
    """A unit-size scene (icosphere + 300 random triangles) moved by X * (1, -0.7, 0.3).

    1. float32 triangles in world coordinates: the engine's float64 ray and cell arithmetic must
       give exactly the brute force's hits on those stored triangles (and a camera at the
       offset must render the brute force's pixels);
    2. float32 storage itself moves vertices by up to ulp(X)/2 (0.004 at 1e5, 0.5 at 1e7), so the
       wrong-triangle rate against the user's float64 scene is measured (the float32 floor);
    3. in a frame centred on the scene (subtract the float64 centre before rounding to float32,
       and from the ray origins) the hits equal the float64 truth: the floor is gone.
    """
    local, rng = offset_scene()
    lo, hi = local.reshape(-1, 3).min(0), local.reshape(-1, 3).max(0)
    o_loc, d = random_rays(rng, 4000, lo, hi, outside=0.5, aim=True)
    world, arith, centred = offset_measure(local, o_loc, d, X, strict=True)
    print(f"FIGURE offset {X:g}: float32 world storage puts {100 * world:.2f}% of the rays on a wrong triangle; "
          f"engine arithmetic {len(arith.bad)} wrong; scene-centred frame {len(centred.bad)} wrong")
    # a camera at the offset renders the brute force's pixels
    T32 = (local.astype(np.float64) + offset_vector(X)).astype(np.float32)
    g = build_grid(T32, GridParams(density=4.0))
    # build_grid centres the far scene (grid.origin); its spec is in that frame, render takes world inputs
    cam = Camera.frame(g.spec.scene_lo + g.origin, g.spec.scene_hi + g.origin, fov=50.0)
    res = render(g, T32, cam, RenderParams(width=40, height=30, shading="normal", traversal="dda"))
    ref = R.ref_cast(T32, *R.ref_camera_rays(cam.eye, cam.target, cam.up, cam.fov, 40, 30))
    compare(f"offset {X:g} camera", res.t.reshape(-1), res.tri.reshape(-1), ref, t_rtol=1e-6)
    assert ref.hit.mean() > 0.05


def test_offset_floor_sweep():
    """Where float32 storage stops keeping hits on the right triangle, 1e2 .. 1e12: the
    wrong-triangle rate grows with X / scene size; past ~1e8 every triangle of the unit scene
    rounds to zero area and build_grid refuses it with a clear InputError.  The scene-centred frame
    has no wrong ray at any offset, and the engine's own arithmetic none wherever a grid exists."""
    local, rng = offset_scene()
    lo, hi = local.reshape(-1, 3).min(0), local.reshape(-1, 3).max(0)
    o_loc, d = random_rays(rng, 1500, lo, hi, outside=0.5, aim=True)
    rows = []
    for e in range(2, 13):
        X = 10.0**e
        world, arith, centred = offset_measure(local, o_loc, d, X, strict=True)
        rows.append((X, world))
    table = ", ".join(f"{X:.0e}: " + ("all degenerate" if w is None else f"{100 * w:.2f}%") for X, w in rows)
    print(f"FIGURE float32 floor (wrong-triangle rate of float32 world storage, unit scene): {table}")
    rates = {X: w for X, w in rows}
    assert rates[1e2] < 1e-3  # ulp(100) = 8e-6: only grazing rays move
    assert rates[1e6] > 0.05  # ulp(1e6) = 0.06: the floor is real (this is what the centred frame removes)
    assert rates[1e12] is None


@pytest.mark.parametrize("X", [1e6, 1e9])
def test_raycaster_far_from_origin_keeps_hits(X):
    """RayCaster takes float64 vertices and rays and works in a frame centred on the mesh
    (regression test: float32 world coordinates had a precision floor): far from the origin its hits
    equal the float64 brute force."""
    local, rng = offset_scene()
    lo, hi = local.reshape(-1, 3).min(0), local.reshape(-1, 3).max(0)
    o_loc, d = random_rays(rng, 2000, lo, hi, outside=0.5, aim=True)
    off = offset_vector(X)
    F = len(local)
    verts = local.reshape(-1, 3).astype(np.float64) + off
    caster = RayCaster(verts, np.arange(3 * F).reshape(F, 3))
    h = caster.cast(o_loc + off, d)
    truth = R.ref_cast((verts - off).reshape(F, 3, 3), (o_loc + off) - off, d)
    compare(f"RayCaster at offset {X:g} vs float64 truth", h.t, h.tri, truth, graze=1e-6, t_rtol=1e-4)
    assert truth.hit.mean() > 0.3


# ----------------------------------------------------------------------------------------------
# flat scenes, single triangle, huge among tiny, slivers, degenerate and duplicated triangles


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_flat_scene_one_axis(axis):
    """Zero extent along one axis: the grid is one cell thick there; every strategy (3 threads)
    gives the brute force's hits, including rays lying in the plane (all miss)."""
    rng = np.random.default_rng(200 + axis)
    tris = random_scene(rng, 200, "mixed", flat_axis=axis, dup_frac=0.05, degen_frac=0.05)
    g0 = build_grid(tris, GridParams(density=4.0, macro=2))
    assert g0.spec.dims[axis] == 1
    o, d = mixed_rays(rng, tris, g0.spec, 6000, pad=0.5)
    plane = float(tris[0, 0, axis])
    o_in = o[:1000].copy()
    o_in[:, axis] = plane
    d_in = d[:1000].copy()
    d_in[:, axis] = 0.0
    keep = np.abs(d_in).max(axis=1) > 0
    o = np.concatenate([o, o_in[keep]])
    d = np.concatenate([d, d_in[keep]])
    # tmin = 1e-9: an origin exactly in the plane would otherwise hit at t = +-1e-18 (rounding)
    ref = R.ref_cast(tris, o, d, tmin=1e-9)
    assert ref.hit[: len(o) - keep.sum()].mean() > 0.03
    assert not ref.hit[len(o) - keep.sum():].any()
    for s in STRATEGIES:
        g = build_grid(tris, GridParams(strategy=s, threads=3, density=4.0, macro=2))
        h, _, _ = cast_and_compare(f"flat axis {axis} {s}", g, tris, o, d, ref=ref, tmin=1e-9)
        assert (h.tri[len(o) - keep.sum():] == -1).all(), "a ray lying in the plane hit a triangle"


def test_flat_scene_two_and_three_axes():
    """Zero extent on two axes (every triangle on one line) or on all three (one point): such a
    scene has only zero-area triangles, so build_grid refuses it with a clear InputError; the
    per-frame GridBuilder (an animation may pass through such a frame) builds a grid one cell
    thick on the flat axes and every ray misses, as in the brute force (rays aimed exactly at the
    line: see test_zero_area_triangle_never_hit)."""
    rng = np.random.default_rng(210)
    line = np.zeros((50, 3, 3), np.float32)
    line[:, :, 0] = rng.uniform(-1, 1, (50, 3))
    line[:, :, 1] = 0.25
    line[:, :, 2] = -3.0
    point = np.full((20, 3, 3), 7.5, np.float32)
    for name, tris, flat in (("line", line, (1, 2)), ("point", point, (0, 1, 2))):
        with pytest.raises(InputError, match="degenerate"):
            build_grid(tris)
        for s in ("serial", "thread_grids", "counting"):
            g = GridBuilder(GridParams(strategy=s, threads=2)).build(tris)
            assert all(g.spec.dims[a] == 1 for a in flat), g.spec.dims
            assert (g.spec.lo < tris.reshape(-1, 3).min(0)).all() and (g.spec.hi > tris.reshape(-1, 3).max(0)).all()
            c = tris.reshape(-1, 3).mean(0).astype(np.float64)
            o = c + rng.normal(size=(2000, 3))
            aim = c + (0.0 if name == "point" else np.array([0.0, 1e-3, 0.0]))  # the point / beside the line
            d = np.concatenate([aim - o[:1000], rng.normal(size=(1000, 3))])
            h = cast_rays(g, tris, o, d)
            ref = R.ref_cast(tris, o, d)
            assert not ref.hit.any() and (h.tri == -1).all() and np.isinf(h.t).all()
        print(f"FIGURE flat {name}: build_grid refuses (all degenerate), GridBuilder dims "
              f"{tuple(int(x) for x in g.spec.dims)}, 2000 rays all miss")


def test_zero_area_triangle_never_hit():
    """Rays aimed exactly at points of zero-area triangles (three distinct collinear vertices)
    must miss them: such a triangle has no surface (the brute force: determinant 0); a test that
    accepts a zero determinant hits 1280 of these 4000 rays."""
    rng = np.random.default_rng(215)
    n = 40
    line = np.zeros((n, 3, 3), np.float32)
    line[:, :, 0] = rng.uniform(-1, 1, (n, 3))
    line[:, :, 1] = 0.25
    line[:, :, 2] = -3.0
    proper = np.array([[[5, 5, 5], [6, 5, 5], [5, 6, 5]]], np.float32)
    tris = np.concatenate([line, proper])
    g = build_grid(tris)
    tgt = np.stack([rng.uniform(-0.9, 0.9, 4000), np.full(4000, 0.25), np.full(4000, -3.0)], axis=1)
    o = tgt + rng.normal(size=(4000, 3))
    ref = R.ref_cast(tris, o, tgt - o)
    assert not (ref.tri[ref.hit] < n).any()  # the brute force never hits them (some rays go on to the proper one)
    counts = {}
    for wt in (True, False):
        h = cast_rays(g, tris, o, tgt - o, watertight=wt)
        counts[wt] = int(((h.tri >= 0) & (h.tri < n)).sum())
    print(f"FIGURE zero-area triangles: of {len(o)} rays aimed at them, {counts[True]} report a hit on one with the "
          f"watertight test, {counts[False]} with the fast test")
    assert counts[True] == 0 and counts[False] == 0


def test_nearly_flat_scene():
    """Thickness 1e-12 of the extent (z in [0, 1e-12], representable in float32 near 0): treated
    as flat (one cell thick), hits equal the brute force."""
    rng = np.random.default_rng(220)
    tris = random_triangles(rng, 300, size=0.1).astype(np.float64)
    tris[:, :, 2] = rng.uniform(0, 1e-12, tris.shape[:2])
    tris = tris.astype(np.float32)
    assert 0 < np.ptp(tris[:, :, 2]) < 1.1e-12
    g = build_grid(tris, GridParams(density=4.0))
    assert g.spec.dims[2] == 1
    o, d = mixed_rays(rng, tris, g.spec, 6000, pad=0.5)
    cast_and_compare("nearly flat (1e-12)", g, tris, o, d, tmin=1e-9)


def test_single_triangle():
    """One triangle: rays from every direction (aimed at its vertices, edges, centroid and
    random points, and random ones) give the brute force's hits for every strategy; rays aimed at
    the centroid hit at t = |centroid - origin| (analytic)."""
    rng = np.random.default_rng(230)
    tri = np.array([[[0.1, 0.2, 0.3], [1.3, -0.4, 0.5], [0.2, 0.9, -0.7]]], np.float32)
    v = tri[0].astype(np.float64)
    targets = np.concatenate([
        np.repeat(v, 200, axis=0),
        (v[[0, 1, 2]] + v[[1, 2, 0]]) / 2.0,
        v[0] + rng.uniform(0, 1, (2000, 1)) * (v[1] - v[0]),
        np.repeat(v.mean(0, keepdims=True), 2000, axis=0),
    ])
    o = targets + rng.normal(size=targets.shape) * rng.uniform(0.1, 10, (len(targets), 1))
    d = targets - o
    o2, d2 = random_rays(rng, 4000, v.min(0), v.max(0), outside=2.0)
    o, d = np.concatenate([o, o2]), np.concatenate([d, d2])
    ref = R.ref_cast(tri, o, d)
    cen = slice(len(targets) - 2000, len(targets))
    for s in STRATEGIES:
        g = build_grid(tri, GridParams(strategy=s, threads=2))
        # a third of the rays are aimed exactly at a vertex or an edge: grazing by construction
        h, _, _ = cast_and_compare(f"single triangle {s}", g, tri, o, d, ref=ref, max_grazing=0.4)
        assert (h.tri[cen] == 0).all()
        np.testing.assert_allclose(h.t[cen], 1.0, rtol=1e-9)  # d = target - origin: the centroid is at t = 1
    assert g.spec.n_cells >= 1


def test_huge_triangle_among_tiny():
    """One triangle spanning the whole grid among 4000 tiny ones (edges ~1e-3): the huge one is
    in every cell its box touches (bbox insertion) or only the cells its plane crosses (exact);
    hits equal the brute force with both, for every strategy."""
    rng = np.random.default_rng(240)
    tiny = random_triangles(rng, 4000, size=1e-3)
    huge = np.array([[[-0.05, -0.05, -0.05], [1.05, -0.05, 1.05], [-0.05, 1.05, 1.05]]], np.float32)
    tris = np.concatenate([tiny[:2000], huge, tiny[2000:]]).astype(np.float32)
    o, d = random_rays(rng, 8000, np.zeros(3), np.ones(3), outside=0.3, aim=True)
    ref = R.ref_cast(tris, o, d)
    assert (ref.tri == 2000).mean() > 0.2
    figs = {}
    for insert in ("bbox", "exact"):
        for s in STRATEGIES:
            g = build_grid(tris, GridParams(strategy=s, threads=2, density=4.0, insert=insert))
            cast_and_compare(f"huge among tiny {insert} {s}", g, tris, o, d, ref=ref)
        huge_refs = sum(int((g.cell_tris(c) == 2000).any()) for c in range(g.spec.n_cells))
        figs[insert] = (g.spec.n_cells, huge_refs, g.references)
    print(f"FIGURE huge among tiny: cells {figs['bbox'][0]}; the huge triangle is in {figs['bbox'][1]} cells with "
          f"bbox insertion, {figs['exact'][1]} with exact; references {figs['bbox'][2]} vs {figs['exact'][2]}")
    assert figs["bbox"][1] == figs["bbox"][0]  # its box is the whole grid
    assert figs["exact"][1] < 0.5 * figs["bbox"][1]


def needle_scene(rng, n=400, aspect=1e6):
    """n needles: length ~0.3..0.8, width length/aspect, random orientation, in [0, 1]^3."""
    c = rng.uniform(0.1, 0.9, (n, 3))
    a = rng.normal(size=(n, 3))
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    b = np.cross(a, rng.normal(size=(n, 3)))
    b /= np.linalg.norm(b, axis=1, keepdims=True)
    L = rng.uniform(0.3, 0.8, (n, 1))
    w = L / aspect
    t = np.stack([c - 0.5 * L * a, c + 0.5 * L * a, c + w * b], axis=1)
    return t.astype(np.float32)


def test_needles_aspect_1e6():
    """400 needles of aspect ratio ~1e6 among 200 ordinary triangles, rays aimed at random
    points of the needles and of the scene: hits equal the brute force (watertight and fast)."""
    rng = np.random.default_rng(250)
    needles = needle_scene(rng)
    t64 = needles.astype(np.float64)
    e = np.linalg.norm(t64[:, 1] - t64[:, 0], axis=1)
    area2 = np.linalg.norm(np.cross(t64[:, 1] - t64[:, 0], t64[:, 2] - t64[:, 0]), axis=1)
    aspect = e * e / area2
    print(f"FIGURE needles: aspect ratio (longest edge / height) median {np.median(aspect):.2e}")
    assert np.median(aspect) > 3e5
    tris = np.concatenate([needles, random_triangles(rng, 200, size=0.1)]).astype(np.float32)
    g = build_grid(tris, GridParams(density=4.0))
    k = rng.integers(0, len(needles), 6000)
    bary = rng.dirichlet([1, 1, 1], 6000)
    target = np.einsum("nk,nkc->nc", bary, t64[k])
    o = target + rng.normal(size=(6000, 3))
    d = target - o
    o2, d2 = mixed_rays(rng, tris, g.spec, 6000)
    o, d = np.concatenate([o, o2]), np.concatenate([d, d2])
    ref = R.ref_cast(tris, o, d)
    assert (ref.tri[:6000] < len(needles)).mean() > 0.5
    for wt in (True, False):
        cast_and_compare(f"needles {'watertight' if wt else 'fast'}", g, tris, o, d, ref=ref, watertight=wt)


def sliver_strip(n_strips=40, width=2.0**-20, length=1.0):
    """A flat closed-looking sheet z = 0.5 tiled by 2 * n_strips slivers of aspect
    length / width = 2^20 (~1e6): strip i spans y in [i w, (i + 1) w] (exact in float32)."""
    tris = []
    for i in range(n_strips):
        y0, y1 = i * width, (i + 1) * width
        tris.append([[0, y0, 0.5], [length, y0, 0.5], [length, y1, 0.5]])
        tris.append([[0, y0, 0.5], [length, y1, 0.5], [0, y1, 0.5]])
    return np.array(tris, np.float32)


def test_sliver_sheet_is_watertight():
    """Rays aimed exactly at the shared edges and vertices of a sheet of slivers (aspect 2^20):
    the watertight test lets none through (the hit is at the target's t); the fast test's
    hole count is printed."""
    rng = np.random.default_rng(260)
    tris = sliver_strip()
    w = 2.0**-20
    n = 20_000
    i = rng.integers(1, 40, n)  # interior strip boundaries y = i w
    x = rng.uniform(0.01, 0.99, n)
    tgt = np.stack([x, i * w, np.full(n, 0.5)], axis=1)
    diag = rng.random(n) < 0.5  # or the diagonal of strip i: y = y0 + x w
    tgt[diag, 1] = (i[diag] - 1) * w + x[diag] * w
    vert = rng.random(n) < 0.1  # or an interior vertex
    tgt[vert, 0] = rng.choice([0.0, 1.0], int(vert.sum()))
    tgt[vert, 1] = i[vert] * w
    o = tgt + np.stack([rng.normal(0, 0.3, n), rng.normal(0, 0.3, n), rng.choice([-1.0, 1.0], n)], axis=1)
    d = tgt - o
    g = build_grid(tris, GridParams(density=4.0))
    holes = {}
    for wt in (True, False):
        h = cast_rays(g, tris, o, d, watertight=wt)
        holes[wt] = int(((h.tri < 0) | (h.t > 1.0 + 1e-9)).sum())
    print(f"FIGURE sliver sheet (aspect 2^20): {n} rays at shared edges/vertices; holes: watertight "
          f"{holes[True]}, fast (Moller-Trumbore) {holes[False]}")
    assert holes[True] == 0


def test_zero_area_and_duplicates_every_strategy():
    """A scene where 30% of the triangles are exact duplicates and 30% have zero area (repeated
    or collinear vertices): every strategy gives the brute force's hits, a zero-area triangle is
    never reported, and the duplicates really produce exact ties."""
    rng = np.random.default_rng(270)
    tris = random_scene(rng, 400, "mixed", dup_frac=0.3, degen_frac=0.3)
    t64 = R.tris64(tris)
    area = np.linalg.norm(np.cross(t64[:, 1] - t64[:, 0], t64[:, 2] - t64[:, 0]), axis=1)
    g0 = build_grid(tris, GridParams(density=4.0))
    o, d = mixed_rays(rng, tris, g0.spec, 8000)
    ref = R.ref_cast(tris, o, d)
    ties = int((ref.hit & (ref.t2 == ref.t)).sum())
    assert ties > 20
    for s in STRATEGIES:
        g = build_grid(tris, GridParams(strategy=s, threads=3, density=4.0))
        for wt in (True, False):
            h, _, _ = cast_and_compare(f"zero-area + duplicates {s} {'wt' if wt else 'fast'}", g, tris, o, d, ref=ref,
                                       watertight=wt)
            assert (area[h.tri[h.tri >= 0]] > 0).all(), "a zero-area triangle was reported as hit"
    print(f"FIGURE zero-area + duplicates: {int((area == 0).sum())} zero-area triangles, {ties} rays at exact ties")


# ----------------------------------------------------------------------------------------------
# special rays


def cube_scene():
    """Axis-aligned unit cubes (12 triangles each) on an integer lattice, some sharing faces."""
    corners = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], np.float32)
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    one = np.array([[corners[a], corners[b], corners[c]] for q in quads for a, b, c in ((q[0], q[1], q[2]), (q[0], q[2], q[3]))])
    offsets = [(0, 0, 0), (1, 0, 0), (0, 2, 0), (2, 2, 1), (3, 0, 3), (1, 1, 2)]
    return np.concatenate([one + np.float32(off) for off in offsets]).astype(np.float32)


def test_axis_parallel_rays_signed_zero():
    """Directions with components in {1, -1, +0.0, -0.0} (56 of them), from lattice points,
    cell corners and cube vertices: hits equal the brute force, and flipping the sign of the
    zero components changes no result bit (t, tri; u, v compare equal)."""
    tris = cube_scene()
    rng = np.random.default_rng(280)
    g = build_grid(tris, GridParams(density=6.0, macro=2))
    comps = [1.0, -1.0, 0.0, -0.0]
    dirs = [(a, b, c) for a in comps for b in comps for c in comps if (a, b, c) != (0, 0, 0) and any(x != 0 for x in (a, b, c))]
    dirs = np.array(dirs, np.float64)
    assert len(dirs) == 56
    n_o = 300
    o = np.concatenate([
        rng.integers(-1, 6, (n_o // 3, 3)) + rng.choice([0.0, 0.5, 0.25], (n_o // 3, 3)),
        g.spec.lo + rng.integers(0, g.spec.dims + 1, (n_o // 3, 3)) * g.spec.cell,
        tris.reshape(-1, 3)[rng.integers(0, tris.size // 3, n_o - 2 * (n_o // 3))].astype(np.float64),
    ])
    O = np.repeat(o, len(dirs), axis=0)
    D = np.tile(dirs, (len(o), 1))
    ref = R.ref_cast(tris, O, D, tmin=1e-9)
    assert ref.hit.mean() > 0.1
    h = cast_rays(g, tris, O, D, tmin=1e-9)
    compare("axis-parallel +-0 (cubes)", h.t, h.tri, ref, max_grazing=0.5)
    flipped = np.where(D == 0.0, np.copysign(0.0, -np.copysign(1.0, D)), D)
    assert (np.signbit(flipped) != np.signbit(D))[D == 0].all()
    h2 = cast_rays(g, tris, O, flipped, tmin=1e-9)
    assert np.array_equal(h.tri, h2.tri) and np.array_equal(h.t, h2.t)
    assert np.array_equal(h.u, h2.u) and np.array_equal(h.v, h2.v)
    hf = cast_rays(g, tris, O, flipped, tmin=1e-9, watertight=False)
    compare("axis-parallel +-0 (cubes) fast", hf.t, hf.tri, ref, max_grazing=0.5)
    # and on a random scene, where no ray runs along a face
    rt = mixed_scene(281, 200)
    g2 = build_grid(rt, GridParams(density=4.0))
    o2 = rng.uniform(-0.3, 1.3, (600, 3))
    O2, D2 = np.repeat(o2, len(dirs), axis=0), np.tile(dirs, (600, 1))
    cast_and_compare("axis-parallel +-0 (random scene)", g2, rt, O2, D2)


def test_origins_on_cell_boundaries_and_triangles():
    """Origins exactly on cell corners, cell faces and the grid bounds (inside the grid and on
    its surface), and on triangles (their vertices, and points of axis-aligned faces): with
    tmin = 1e-9 every hit equals the brute force; with tmin = 0 the only differences allowed are
    hits within rounding of the origin's own triangle (t < 1e-12), which are counted."""
    rng = np.random.default_rng(290)
    tris = np.concatenate([cube_scene(), (random_triangles(rng, 200, size=0.4) * 5.0)]).astype(np.float32)
    g = build_grid(tris, GridParams(density=4.0, macro=2))
    s = g.spec
    n = 3000
    corner = s.lo + rng.integers(0, s.dims + 1, (n, 3)) * s.cell
    face = s.lo + rng.uniform(0, 1, (n, 3)) * (s.hi - s.lo)
    ax = rng.integers(0, 3, n)
    face[np.arange(n), ax] = s.lo[ax] + rng.integers(0, s.dims[ax] + 1) * s.cell[ax]
    vert = tris.reshape(-1, 3)[rng.integers(0, tris.size // 3, n)].astype(np.float64)
    cf = cube_scene().astype(np.float64)  # points of axis-aligned cube faces
    k = rng.integers(0, len(cf), n)
    onface = np.einsum("nk,nkc->nc", rng.dirichlet([1, 1, 1], n), cf[k])
    o = np.concatenate([corner, face, vert, onface])
    d = rng.normal(size=o.shape)
    d[::3] = 0.0
    d[::3][np.arange(len(d[::3])), rng.integers(0, 3, len(d[::3]))] = rng.choice([-1.0, 1.0], len(d[::3]))
    inside = ((o > s.lo) & (o < s.hi)).all(axis=1)
    print(f"FIGURE origins: {int(inside.sum())} of {len(o)} strictly inside the grid")
    cast_and_compare("origins on boundaries/triangles, tmin=1e-9", g, tris, o, d, tmin=1e-9, max_grazing=0.05)
    h = cast_rays(g, tris, o, d)
    ref = R.ref_cast(tris, o, d)
    diff = compare("origins on boundaries/triangles, tmin=0", h.t, h.tri, ref, strict=False, max_grazing=0.05)
    self_hits = [i for i in diff.bad if min(h.t[i], ref.t[i]) < 1e-12]
    print(f"FIGURE origins, tmin=0: {len(self_hits)} rays differ only by a self-hit at t < 1e-12")
    assert set(diff.bad.tolist()) == set(self_hits)


def test_grazing_rays():
    """Rays nearly parallel to triangles.  A tiled quad sheet z = 0.5 and a tilted copy:
    1. rays lying exactly in the sheet's plane miss (zero determinant), as in the brute force;
    2. rays at angles 1e-2 .. 1e-12 to the sheet, aimed at points away from its edges, hit the
       brute force's triangle with t to the conditioning the angle allows (t error printed);
    3. rays aimed exactly at edges of the tilted copy at grazing angles: only ties/grazing."""
    rng = np.random.default_rng(300)
    n_q = 8
    xs = np.linspace(0, 1, n_q + 1)
    quads = []
    for i in range(n_q):
        for j in range(n_q):
            a, b, c, e = (xs[i], xs[j]), (xs[i + 1], xs[j]), (xs[i + 1], xs[j + 1]), (xs[i], xs[j + 1])
            quads += [[(*a, 0.5), (*b, 0.5), (*c, 0.5)], [(*a, 0.5), (*c, 0.5), (*e, 0.5)]]
    sheet = np.array(quads, np.float64)
    rot = np.array([[1, 0, 0], [0, math.cos(0.3), -math.sin(0.3)], [0, math.sin(0.3), math.cos(0.3)]])
    tilted = (sheet - 0.5) @ rot.T + np.array([0.5, 0.5, 2.5])
    tris = np.concatenate([sheet, tilted]).astype(np.float32)
    g = build_grid(tris, GridParams(density=4.0))
    # 1. in the plane
    n = 3000
    o = np.stack([rng.uniform(-0.5, 1.5, n), rng.uniform(-0.5, 1.5, n), np.full(n, 0.5)], axis=1)
    d = np.stack([rng.normal(size=n), rng.normal(size=n), np.zeros(n)], axis=1)
    h = cast_rays(g, tris, o, d)
    ref = R.ref_cast(tris, o, d)
    sheet_hits = int(((h.tri >= 0) & (h.tri < len(sheet))).sum())
    print(f"FIGURE grazing: {n} rays in the sheet's plane, {sheet_hits} report a sheet triangle")
    assert sheet_hits == 0 and not (ref.hit & (ref.tri < len(sheet))).any()
    compare("grazing: in the plane", h.t, h.tri, ref)
    # 2. small angles, targets inside triangles (barycentric >= 0.05 from every edge)
    T = sheet[rng.integers(0, len(sheet), n)]
    bary = 0.05 + 0.85 * rng.dirichlet([1, 1, 1], n)
    tgt = np.einsum("nk,nkc->nc", bary, T)
    worst = []
    for ang in (1e-2, 1e-4, 1e-6, 1e-8, 1e-10, 1e-12):
        phi = rng.uniform(0, 2 * np.pi, n)
        dd = np.stack([np.cos(phi), np.sin(phi), -np.full(n, math.tan(ang))], axis=1)
        oo = tgt - 0.3 * dd
        h = cast_rays(g, tris, oo, dd)
        ref = R.ref_cast(tris, oo, dd)
        # t of a hit at angle a is conditioned like 1 / a: allow that, relative to the float32 data
        diff = compare(f"grazing angle {ang:g}", h.t, h.tri, ref, t_rtol=max(1e-9, 1e-15 / ang))
        worst.append(len(diff.grazing))
        assert (ref.tri < len(sheet)).mean() > 0.9
    # 3. at edges of the tilted copy
    tt = tilted[rng.integers(0, len(tilted), n)]
    s = rng.uniform(0, 1, (n, 1))
    tgt = tt[:, 0] + s * (tt[:, 1] - tt[:, 0])
    nrm = rot @ np.array([0, 0, 1.0])
    side = np.cross(nrm, rng.normal(size=(n, 3)))
    side /= np.linalg.norm(side, axis=1, keepdims=True)
    dd = side - 1e-7 * nrm
    oo = tgt - dd
    h = cast_rays(g, tris, oo, dd)
    ref = R.ref_cast(tris, oo, dd)
    compare("grazing at tilted edges", h.t, h.tri, ref, max_grazing=1.0)


@pytest.mark.parametrize("traversal", ["dda", "cgt"])
def test_camera_inside_scene(traversal):
    """The camera inside a closed icosphere among 300 random triangles: every pixel hits
    something (the sphere encloses the eye) and t / tri equal the brute force's on the camera's
    rays; the image equals the brute-force shading (normal mode) up to rounding."""
    rng = np.random.default_rng(310)
    sphere = icosphere_tris(3, 1.0)
    inner = (random_triangles(rng, 300, size=0.1) - 0.5) * 1.2
    tris = np.concatenate([sphere, inner]).astype(np.float32)
    g = build_grid(tris, GridParams(density=4.0, macro=2))
    w, hgt = 48, 36
    for eye, target in (((0.05, 0.02, -0.03), (1.0, 0.2, 0.1)), ((0.3, -0.6, 0.2), (-1.0, 1.0, -0.5))):
        cam = Camera(eye=eye, target=target, fov=80.0)
        res = render(g, tris, cam, RenderParams(width=w, height=hgt, shading="normal", traversal=traversal))
        ref = R.ref_render(tris, cam, w, hgt, "normal")
        assert ref.hits.hit.all()
        compare(f"camera inside ({traversal}) eye {eye}", res.t.reshape(-1), res.tri.reshape(-1), ref.hits)
        assert (res.tri >= 0).all()
        bad = (np.abs(res.image.astype(int) - ref.image.astype(int)).max(axis=2) > 2).sum()
        assert bad <= 0.005 * w * hgt


# ----------------------------------------------------------------------------------------------
# extreme lambda and the memory cap


def test_extreme_lambda_tiny():
    """lambda = 1e-12: one cell holds every triangle of non-zero area (zero-area ones are in no
    cell: float64 cross product of the float32 edges exactly zero); hits equal the brute force."""
    tris = mixed_scene(320, 200)
    g = build_grid(tris, GridParams(density=1e-12))
    t64 = tris.astype(np.float64)
    proper = int((np.cross(t64[:, 1] - t64[:, 0], t64[:, 2] - t64[:, 0]) != 0).any(axis=1).sum())
    assert 0 < proper < len(tris)
    assert tuple(g.spec.dims) == (1, 1, 1) and g.references == proper
    o, d = mixed_rays(np.random.default_rng(321), tris, g.spec, 5000)
    cast_and_compare("lambda 1e-12 (1 cell)", g, tris, o, d)


def test_extreme_lambda_huge_capped(monkeypatch):
    """lambda = 1e12 asks for far more cells than max_cells: the resolution is capped with a
    GridCapWarning naming max_cells, lambda and the dims used, the grid holds at most max_cells
    cells, and the hits still equal the brute force (every strategy, up to 16 threads).

    The warnings are taken where gridrt.grid.build issues them, not through pytest.warns: a
    kernel compiling in a background thread (a warm-up an earlier build started) sets and
    restores the process's warning filters around its compile, which can leave pytest.warns
    without the warning; it did once, on a cold numba cache.  test_grid_reference checks the
    warning itself through pytest.warns."""
    from importlib import import_module

    caught = []

    class Record:
        @staticmethod
        def warn(message, category=UserWarning, stacklevel=1):
            caught.append((category, str(message)))

    monkeypatch.setattr(import_module("gridrt.grid.build"), "warnings", Record)
    tris = mixed_scene(330, 200)
    o, d = mixed_rays(np.random.default_rng(331), tris, build_grid(tris).spec, 4000)
    ref = R.ref_cast(tris, o, d)
    cap = 1 << 15
    for s, th in zip(STRATEGIES, (1, 2, 3, 4, 16, 2, 16, 3, 2)):
        n = len(caught)
        g = build_grid(tris, GridParams(strategy=s, threads=th, density=1e12, max_cells=cap))
        caps = [m for c, m in caught[n:] if issubclass(c, GridCapWarning)]
        assert len(caps) == 1, f"{s} x{th}: {caught[n:]}"
        msg = caps[0]
        assert f"max_cells={cap}" in msg and "1e+12" in msg and "dims" in msg, msg
        assert g.spec.capped and g.spec.n_cells <= cap and g.spec.n_cells > cap // 2
        cast_and_compare(f"lambda 1e12 capped at {cap} cells, {s} x{th}", g, tris, o, d, ref=ref)
    print(f"FIGURE lambda 1e12: capped to dims {tuple(int(x) for x in g.spec.dims)} ({g.spec.n_cells} cells); "
          f"warning: {msg}")


def spanning_triangles(n, seed):
    """n triangles whose bounding boxes are the whole unit cube: each is in every cell."""
    u = np.random.default_rng(seed).uniform(0, 1, (n, 3))
    return np.stack([np.stack([np.zeros(n), u[:, 0], np.ones(n)], 1),
                     np.stack([np.ones(n), np.zeros(n), u[:, 1]], 1),
                     np.stack([u[:, 2], np.ones(n), np.zeros(n)], 1)], axis=1).astype(np.float32)


def test_grid_memory_budget():
    """GridParams.max_bytes caps the grid's memory, documented as "the cell arrays plus
    references": need = 4 B x references + layers x (2 cells + 1) x 4 B (thread_grids_merge also
    holds its per-thread grids and a second copy of the references while merging).  For every strategy at 1
    and 16 threads, a build with max_bytes = need succeeds and one with need - 1 is refused with an
    InputError naming max_bytes and lambda; 60 triangles spanning the scene at lambda 1e12 against
    an 8 MiB budget are refused.  The allocation of a build that fits is printed against its
    budget (the reference buffer grows with 1.5x slack).  Regression test
    (grids once grew without a memory cap)."""
    tris = spanning_triangles(60, 340)
    cap = 1 << 16
    ratios = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", GridCapWarning)
        for s in STRATEGIES:
            for th in (1, 16):
                p = GridParams(strategy=s, threads=th, density=1e12, max_cells=cap)
                g0 = build_grid(tris[:20], p)
                need = 4 * g0.references + g0.layers * (2 * g0.spec.n_cells + 1) * 4
                if s == "thread_grids_merge":  # its per-thread grids and references exist while merging
                    need += th * (2 * g0.spec.n_cells + 1) * 4 + 4 * g0.references
                g = build_grid(tris[:20], p.replace(max_bytes=need))
                assert g.references == g0.references
                ratios.append(g.memory_bytes() / need)
                with pytest.raises(InputError, match=r"max_bytes.*lambda|lambda.*max_bytes"):
                    build_grid(tris[:20], p.replace(max_bytes=need - 1))
                with pytest.raises(InputError, match="max_bytes") as info:
                    build_grid(tris, p.replace(max_bytes=8 << 20))
    print(f"FIGURE memory budget: for every strategy x (1, 16) threads max_bytes = need builds and need - 1 is "
          f"refused; allocated / budget of the builds that fit: {min(ratios):.2f} .. {max(ratios):.2f}; "
          f"60 spanning triangles in {cap} cells vs 8 MiB: {info.value}")
    assert max(ratios) <= 1.5 + 1e-3


# ----------------------------------------------------------------------------------------------
# extreme direction magnitudes


def scaled_ref(tris, o, d_unit, mag):
    """Brute force for directions d_unit * mag: cast with the unit directions (accurate in
    float64) and divide the t values by mag (one correctly rounded operation)."""
    ref = R.ref_cast(tris, o, d_unit)
    ref.t = ref.t / mag
    ref.t2 = ref.t2 / mag
    return ref


@pytest.mark.parametrize("mag", [1e-280, 1e-150, 1e150, 1e300])
def test_direction_magnitudes(unit_case, mag):
    """Directions scaled to |d| = mag (t is in units of d, so it scales by 1 / mag): hits
    equal the brute force."""
    tris, grid, o, d, h1 = unit_case
    du = (d / np.linalg.norm(d, axis=1, keepdims=True))[:6000]
    cast_and_compare(f"|d| = {mag:g}", grid, tris, o[:6000], du * mag, ref=scaled_ref(tris, o[:6000], du, mag))


@pytest.mark.parametrize("mag", [5e-301, 1e-305, 1e-307])
def test_direction_magnitudes_below_tiny_dir(unit_case, mag):
    """|d| below 1e-300 in every component: a valid (non-zero) direction; hits at t ~ 1 / mag
    are representable, so they must equal the brute force (a DDA that treats such a direction
    as zero misses them)."""
    tris, grid, o, d, h1 = unit_case
    du = (d / np.linalg.norm(d, axis=1, keepdims=True))[:3000]
    cast_and_compare(f"|d| = {mag:g}", grid, tris, o[:3000], du * mag, ref=scaled_ref(tris, o[:3000], du, mag))
