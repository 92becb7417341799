"""Batch casts through packets (gridrt.trace.batch): ``cast_rays`` / ``RayCaster.cast`` trace
coherent runs of rays as CGT packets and the rest one at a time; the hits must not depend on it.

* every ray's t, triangle, u and v are the same bit for bit with packets and without, in the
  caller's order, shuffled and reversed, for 1, 2 and 3 threads;
* they agree with the float64 brute force (tests/reference.py, with its tie and grazing rules);
* ties (duplicated triangles: the same t by construction) go to the lower triangle index on both
  paths, so the packet and single-ray paths pick the same triangle there too;
* the routing is real: camera rays in pixel order go through packets in the first pass (as 8 x 8
  tiles of the image, whose rows it recognises), shuffled camera rays in the second (sorted)
  pass, random rays one at a time (cast_grouped's counts);
* any-hit casts report a hit exactly where the nearest-hit cast does, and the hit is real;
* far from the origin (a RayCaster mesh at 1e6) both paths agree;
* hypothesis: random batches (origins inside and outside, random and aimed directions, mixed
  lengths) give the same hits both ways and the brute force's;
* shadow segments that end just off a finely split surface, with occluders just before and just
  beyond their ends, are blocked exactly where the brute force blocks them.
"""

import importlib

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import reference as R
from conftest import TEAPOT, icosphere_tris, load_tris, random_rays, random_scene
from gridrt import RayCaster
from gridrt.camera import Camera
from gridrt.errors import InputError
from gridrt.grid import GridParams, build_grid
from gridrt.threads import use_threads
from gridrt.trace import cast_rays
from helpers.grids import CAST_KINDS

batch = importlib.import_module("gridrt.trace.batch")
FIELDS = ("t", "tri", "u", "v")


def same(a, b, label, perm=None):
    for f in FIELDS:
        x, y = getattr(a, f), getattr(b, f)
        if perm is not None:
            x = x[perm]
        bad = ~((x == y) | (np.isnan(x) & np.isnan(y)) if x.dtype.kind == "f" else (x == y))
        assert not bad.any(), f"{label}: {f} differs at {int(bad.sum())} rays, first {np.flatnonzero(bad)[:5]}"


def check_ref(tris, o, d, hits, label, tmax=np.inf):
    ref = R.ref_cast(tris, o, d, tmax=tmax)
    diff = R.compare_hits(hits.t, hits.tri, ref, t_rtol=1e-5, tie_rtol=1e-9, graze_tol=1e-9)
    assert len(diff.bad) == 0 and len(diff.t_off) == 0, f"{label}: {len(diff.bad)} wrong, {len(diff.t_off)} t off"
    assert len(diff.grazing) <= max(2, 1e-3 * len(o)), f"{label}: {len(diff.grazing)} grazing disagreements"
    return ref


def scene_and_camera(name):
    if name == "icosphere":
        tris = icosphere_tris(3)
        cam = Camera(eye=(0.4, 0.5, 2.6), target=(0.0, 0.0, 0.0), fov=55.0)
    elif name == "teapot":
        tris = load_tris(TEAPOT)
        lo, hi = tris.reshape(-1, 3).min(0), tris.reshape(-1, 3).max(0)
        c = 0.5 * (lo + hi)
        cam = Camera(eye=tuple(c + np.array([0.3, 0.4, 1.0]) * float((hi - lo).max()) * 1.2), target=tuple(c),
                     fov=50.0)
    else:  # duplicated triangles (exact ties) and zero-area ones
        tris = random_scene(np.random.default_rng(13), 400, "mixed", None, dup_frac=0.3, degen_frac=0.1)
        cam = Camera(eye=(0.5, 0.6, 2.8), target=(0.5, 0.5, 0.5), fov=45.0)
    return np.ascontiguousarray(tris, np.float32), cam


def shadow_rays(tris, hits, o, d, light):
    """Rays from the hit points (offset along -d) towards ``light``, unnormalised: t in (0, 1)."""
    h = hits.tri >= 0
    p = o[h] + d[h] * (hits.t[h] * (1 - 1e-6))[:, None]
    return p, np.asarray(light, np.float64)[None, :] - p


@pytest.mark.parametrize("name", ["icosphere", "teapot", "dups"])
def test_packets_equal_single_rays_any_order(name):
    tris, cam = scene_and_camera(name)
    grid = build_grid(tris, GridParams())
    o, d = cam.rays(96, 80)
    rng = np.random.default_rng(5)
    perm = rng.permutation(len(o))
    single = cast_rays(grid, tris, o, d, packets=False)
    check_ref(tris, o, d, single, f"{name} camera")
    for threads in (1, 2, 3):
        same(single, cast_rays(grid, tris, o, d, threads=threads), f"{name} camera T={threads}")
        same(single, cast_rays(grid, tris, o[perm], d[perm], threads=threads), f"{name} shuffled T={threads}", perm)
        rev = np.arange(len(o))[::-1]
        same(single, cast_rays(grid, tris, o[rev], d[rev], threads=threads), f"{name} reversed T={threads}", rev)
    # shadow rays towards a point light, in order and shuffled
    lo, hi = tris.reshape(-1, 3).min(0), tris.reshape(-1, 3).max(0)
    light = 0.5 * (lo + hi) + np.array([0.4, 1.5, 0.7]) * float((hi - lo).max())
    so, sd = shadow_rays(tris, single, o, d, light)
    s1 = cast_rays(grid, tris, so, sd, tmax=1.0, packets=False)
    check_ref(tris, so, sd, s1, f"{name} shadow", tmax=1.0)
    p2 = rng.permutation(len(so))
    for threads in (1, 2):
        same(s1, cast_rays(grid, tris, so, sd, tmax=1.0, threads=threads), f"{name} shadow T={threads}")
        same(s1, cast_rays(grid, tris, so[p2], sd[p2], tmax=1.0, threads=threads), f"{name} shadow shuffled", p2)
        a1 = cast_rays(grid, tris, so, sd, tmax=1.0, any_hit=True, threads=threads)
        a0 = cast_rays(grid, tris, so, sd, tmax=1.0, any_hit=True, packets=False, threads=threads)
        for a in (a0, a1):
            assert np.array_equal(a.tri >= 0, s1.tri >= 0), f"{name}: any-hit occlusion differs from nearest"
            hit = np.flatnonzero(a.tri >= 0)
            for k in hit[:200]:  # each reported hit is real: the brute force hits that triangle at that t
                rk = R.ref_cast(tris[[a.tri[k]]], so[k : k + 1], sd[k : k + 1], tmax=1.0)
                assert rk.tri[0] == 0 and abs(rk.t[0] - a.t[k]) <= 1e-5 * max(rk.t[0], 1e-9) + 1e-9, (name, k)
        # the material pass's casts read only the triangle (tri_only): the same occlusion, and each
        # reported triangle is hit within the segment
        from gridrt.trace.batch import SHADOW_MAX_CELLS, SHADOW_SORTED_MAX_CELLS, cast_grouped
        from gridrt.trace.grids import grid_arrays

        g = grid_arrays(grid, tris)
        for f32 in (False, True):
            out = (np.full(len(so), np.nan), np.full(len(so), -2, np.int32), np.full(len(so), np.nan),
                   np.full(len(so), np.nan))
            cast_grouped(g, so, sd, 0.0, 1.0, True, True, out, SHADOW_MAX_CELLS, f32, tri_only=True,
                         sorted_max_cells=SHADOW_SORTED_MAX_CELLS)
            assert np.array_equal(out[1] >= 0, s1.tri >= 0), f"{name}: tri_only occlusion differs (f32={f32})"
            hit = np.flatnonzero(out[1] >= 0)
            for k in hit[:200]:
                rk = R.ref_cast(tris[[out[1][k]]], so[k : k + 1], sd[k : k + 1], tmax=1.0)
                assert rk.tri[0] == 0, (name, k, f32)


def test_ties_go_to_the_lower_index():
    """A scene of duplicated triangles: wherever copies are hit at the same t, both paths report
    the lowest index among the exact copies of the triangle hit."""
    tris, cam = scene_and_camera("dups")
    grid = build_grid(tris, GridParams())
    o, d = cam.rays(120, 120)
    key = {}
    first = np.empty(len(tris), np.int64)
    for i, t in enumerate(tris):
        first[i] = key.setdefault(t.tobytes(), i)
    n_dup_hits = 0
    for packets in (False, True):
        h = cast_rays(grid, tris, o, d, packets=packets)
        hit = h.tri >= 0
        assert np.array_equal(h.tri[hit], first[h.tri[hit]]), "a tie went to a higher index"
        n_dup_hits = int((np.bincount(first, minlength=len(tris))[first[h.tri[hit]]] > 1).sum())
    assert n_dup_hits > 50, "the scene should produce hits on duplicated triangles"


def test_routing(monkeypatch):
    """Which path the rays take (cast_grouped's counts): camera rays in order mostly in pass 1,
    shuffled ones in pass 2, random rays from inside the bounds in neither."""
    from gridrt.trace.grids import grid_arrays

    tris, cam = scene_and_camera("icosphere")
    grid = build_grid(tris, GridParams())
    g = grid_arrays(grid, tris)
    o, d = cam.rays(128, 128)
    N = len(o)

    def run(o, d, **kw):
        out = (np.empty(N), np.empty(N, np.int32), np.empty(N), np.empty(N))
        return batch.cast_grouped(g, np.ascontiguousarray(o), np.ascontiguousarray(d), 0.0, np.inf, True, False,
                                  out, **kw)

    p1, p2 = run(o, d)
    assert p1 == N and p2 == 0, (p1, p2)  # (pass 1 takes the image's rows as 8 x 8 tiles)
    with monkeypatch.context() as mp:  # in the caller's order, runs of 64 are half rows here: some are too wide
        mp.setattr(batch, "pass1_order", lambda o, d: batch.NO_ROWS)
        p1, p2 = run(o, d)
    assert 0.5 * N <= p1 < N and p1 + p2 >= 0.9 * N, (p1, p2)
    perm = np.random.default_rng(2).permutation(N)
    p1, p2 = run(o[perm], d[perm])
    assert p1 < 0.05 * N and p2 >= 0.8 * N, (p1, p2)
    ro, rd = random_rays(np.random.default_rng(3), N, np.full(3, -1.0), np.full(3, 1.0), outside=0.0)
    assert run(ro, rd) == (0, 0)
    assert run(o, d, max_cells=0) == (0, 0)


def test_far_from_origin_caster():
    """A RayCaster mesh 1e6 from the origin: packets and single rays agree, and match the brute
    force in the mesh's own frame."""
    tris, cam = scene_and_camera("icosphere")
    shift = np.array([1e6, -2e6, 5e5])
    rc = RayCaster.from_triangles(tris.astype(np.float64) + shift)
    o, d = cam.rays(64, 64)
    a = rc.cast(o + shift, d, packets=False)
    for threads in (1, 2):
        same(a, rc.cast(o + shift, d, threads=threads), f"far T={threads}")
    check_ref(tris, o, d, a, "far (frame-local reference)")


def test_packets_argument_checked():
    tris, cam = scene_and_camera("icosphere")
    grid = build_grid(tris, GridParams())
    o, d = cam.rays(4, 4)
    for bad in ("yes", 1, None):
        with pytest.raises(InputError, match="packets"):
            cast_rays(grid, tris, o, d, packets=bad)
    rc = RayCaster.from_triangles(tris)
    with pytest.raises(InputError, match="packets"):
        rc.cast(o, d, packets="no")


_GRID = {}


def _grid():
    if not _GRID:
        tris = random_scene(np.random.default_rng(21), 300, "mixed", None, dup_frac=0.1, degen_frac=0.05)
        _GRID["v"] = (tris, build_grid(tris, GridParams()))
    return _GRID["v"]


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 700), outside=st.sampled_from([0.0, 0.5, 1.0]),
       aim=st.booleans(), coherent=st.booleans(), threads=st.sampled_from([1, 2, 3]))
def test_random_batches(seed, n, outside, aim, coherent, threads):
    tris, grid = _grid()
    rng = np.random.default_rng(seed)
    lo, hi = tris.reshape(-1, 3).min(0).astype(np.float64), tris.reshape(-1, 3).max(0).astype(np.float64)
    if coherent:  # a pencil of rays from one point, in a random order
        eye = rng.uniform(lo - 1.0, hi + 1.0)
        tgt = rng.uniform(lo, hi, (n, 3))
        o = np.repeat(eye[None], n, 0)
        d = (tgt - eye) * rng.uniform(0.1, 10.0, (n, 1))
    else:
        o, d = random_rays(rng, n, lo, hi, outside=outside, aim=aim)
    a = cast_rays(grid, tris, o, d, packets=False)
    b = cast_rays(grid, tris, o, d, threads=threads)
    same(a, b, f"seed {seed}")
    check_ref(tris, o, d, b, f"seed {seed}")


def image_rays(W, H, ortho=False, column_major=False):
    """A W x H image's camera rays (pinhole, or orthographic: one direction, origins on a plane)."""
    cam = Camera(eye=(0.4, 0.5, 2.6), target=(0.0, 0.0, 0.0), fov=55.0)
    o, d = cam.rays(W, H)
    if ortho:
        ys, xs = np.divmod(np.arange(W * H), W)
        o = np.stack([xs * 0.01, ys * -0.01, np.full(W * H, 3.0)], axis=1)
        d = np.tile(np.array([[0.05, -0.02, -1.0]]), (W * H, 1))
    if column_major:
        o = o.reshape(H, W, 3).transpose(1, 0, 2).reshape(-1, 3)
        d = d.reshape(H, W, 3).transpose(1, 0, 2).reshape(-1, 3)
    return np.ascontiguousarray(o), np.ascontiguousarray(d)


@pytest.mark.parametrize("W,H", [(96, 80), (100, 37), (640, 480), (16, 300)])
def test_image_width(W, H):
    """Pass 1 recognises the rows of an image (its width, and the column of the first ray) in
    row-major, column-major and orthographic camera rays, starting anywhere in a row, and nothing
    in rays that are not an image."""
    o, d = image_rays(W, H)
    assert batch.image_width(o, d) == (W, 0)
    for k in (1, 5, W - 1, W + 3):
        assert batch.image_width(o[k:], d[k:]) == (W, k % W), k
    assert batch.image_width(*image_rays(W, H, ortho=True)) == (W, 0)
    assert batch.image_width(*image_rays(W, H, column_major=True)) == ((H, 0) if H >= 2 * batch.TILE else (0, 0))
    perm = np.random.default_rng(1).permutation(len(o))
    assert batch.image_width(o[perm], d[perm]) == (0, 0)
    ro, rd = random_rays(np.random.default_rng(3), len(o), np.full(3, -1.0), np.full(3, 1.0), outside=0.0)
    assert batch.image_width(ro, rd) == (0, 0)
    assert batch.image_width(o[:W], d[:W]) == (0, 0)  # one row: no rows to tile
    assert batch.image_width(*image_rays(10, 400)) == (0, 0)  # narrower than two tiles


@pytest.mark.parametrize("N,W,c0", [(96 * 80, 96, 0), (96 * 80 - 7, 96, 7), (1000, 100, 0), (777, 40, 13)])
def test_tile_order(N, W, c0):
    """The order of pass 1 for an image: every ray once, and with a width that is a multiple of
    TILE and full rows, each run of RUN rays is one TILE x TILE square of pixels."""
    out = np.empty(N, np.int64)
    assert batch.tile_order(N, W, c0, out) == N
    assert np.array_equal(np.sort(out), np.arange(N))
    T = batch.TILE
    if W % T == 0 and c0 == 0 and N % (W * T) == 0:
        assert batch.RUN == T * T
        y, x = np.divmod(out, W)
        for s in range(0, N, batch.RUN):
            ys, xs = y[s : s + batch.RUN], x[s : s + batch.RUN]
            assert ys.max() - ys.min() == T - 1 and xs.max() - xs.min() == T - 1 and ys.min() % T == 0 and xs.min() % T == 0


def _tilted_surface(n, tilt):
    """A square of 2 n^2 triangles in the plane through the origin with normal ``tilt`` (unit):
    (corner, edge vectors e1, e2 of the square, the normal)."""
    nz = np.asarray(tilt, np.float64) / np.linalg.norm(tilt)
    e1 = np.cross(nz, [0.0, 0.0, 1.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(nz, e1)
    c0 = -0.5 * (e1 + e2)
    tris = []
    for i in range(n):
        for j in range(n):
            p = [c0 + (i + a) / n * e1 + (j + b) / n * e2 for a, b in ((0, 0), (1, 0), (1, 1), (0, 1))]
            tris += [(p[0], p[1], p[2]), (p[0], p[2], p[3])]
    return np.array(tris), c0, e1, e2, nz


@pytest.mark.parametrize("kind", CAST_KINDS)
def test_shadow_segments_ending_on_a_surface(kind):
    """Shadow segments from a point light to points just off a tilted, finely split surface (in 8x8
    tiles, as the material pass casts them), with small occluders all along the segments, some
    just before their ends and some just beyond them: the packets block exactly the segments the
    float64 brute force and the single rays block, uniform and two-level grids, at 1 and 2
    threads, float64 and float32 tests."""
    from gridrt.trace.batch import SHADOW_MAX_CELLS, SHADOW_SORTED_MAX_CELLS, cast_grouped
    from gridrt.trace.grids import grid_arrays

    rng = np.random.default_rng(8)
    surf, c0, e1, e2, nz = _tilted_surface(40, (0.35, 0.2, 1.0))
    light = np.array([0.3, -0.2, 2.5])
    off = 1e-6 * np.sqrt(3.0)
    W = 128  # W x W points of the middle of the surface, in 8 x 8 tiles
    ii, jj = np.meshgrid(np.arange(W), np.arange(W), indexing="ij")
    tile = ((ii // 8) * (W // 8) + jj // 8) * 64 + (ii % 8) * 8 + jj % 8
    s = np.empty((W * W, 2))
    s[tile.ravel(), 0] = 0.25 + 0.5 * (ii.ravel() + 0.5) / W
    s[tile.ravel(), 1] = 0.25 + 0.5 * (jj.ravel() + 0.5) / W
    ends = c0 + s[:, :1] * e1 + s[:, 1:] * e2 + off * nz
    o = np.repeat(light[None], len(ends), 0)
    d = ends - light
    # occluders: small triangles about points of random segments, anywhere along them, just before
    # their ends, and just beyond them (under the surface: never hit)
    occ = []
    for lo_t, hi_t, k in ((0.05, 0.999, 120), (0.9999, 0.99999, 80), (1.00001, 1.001, 80)):
        m = rng.integers(0, len(o), k)
        c = o[m] + d[m] * rng.uniform(lo_t, hi_t, (k, 1))
        occ.append(c[:, None, :] + rng.normal(0.0, 0.006, (k, 3, 3)))
    tris = np.ascontiguousarray(np.concatenate([surf, *occ]), np.float32)
    grid = build_grid(tris, GridParams(grid=kind))
    g = grid_arrays(grid, tris)
    ref = R.ref_cast(tris, o, d, tmax=1.0).tri >= 0
    assert 0.02 < ref.mean() < 0.5  # some segments blocked, most not
    single = cast_rays(grid, tris, o, d, tmax=1.0, any_hit=True, packets=False).tri >= 0
    assert np.array_equal(single, ref), f"single rays: {int((single != ref).sum())} differ from the brute force"
    for threads in (1, 2):
        for f32 in (False, True):
            out = (np.empty(len(o)), np.empty(len(o), np.int32), np.empty(len(o)), np.empty(len(o)))
            use_threads(threads)
            p1, _ = cast_grouped(g, o, d, 0.0, 1.0, True, True, out, SHADOW_MAX_CELLS, f32, tri_only=True,
                                 sorted_max_cells=SHADOW_SORTED_MAX_CELLS)
            assert p1 >= 0.9 * len(o), f"only {p1} of {len(o)} segments went through packets"
            got = out[1] >= 0
            assert np.array_equal(got, ref), f"{kind} T={threads} f32={f32}: {int((got != ref).sum())} differ"
            # pass 1 at a bound of half a cell leaves most tiles; sorted, pass 2 traces them as packets
            # of its own bound
            out = (np.empty(len(o)), np.empty(len(o), np.int32), np.empty(len(o)), np.empty(len(o)))
            p1, p2 = cast_grouped(g, o, d, 0.0, 1.0, True, True, out, 0.5, f32, tri_only=True,
                                  sorted_max_cells=SHADOW_SORTED_MAX_CELLS)
            assert p1 <= 0.5 * len(o) and p2 >= 0.5 * (len(o) - p1), (p1, p2)
            got = out[1] >= 0
            assert np.array_equal(got, ref), f"{kind} T={threads} f32={f32} pass 2: {int((got != ref).sum())} differ"
