"""CGT packet tests in float32 (``RenderParams.packet_precision="float32"``, ``cast_rays(...,
packet_precision="float32")``): engine/trace/cgt.py's _test_wt32 / _test_mt32 and the float64
fallback _fix_wt64.  The renders' tests are in the slow run (the float32 render kernels compile
for them alone); the quick run keeps the batch casts, the packet tests and the fallback.

* Renders (both intersection tests; the test_cgt scenes and views) agree with the float64 brute
  force (tests/reference.py) up to float32 rounding: every pixel that differs is a near-tie in t
  or within F32_GRAZE (barycentric) of an edge, and t is within F32_T of the brute force's.  The
  float64 packets, checked alike, use test_cgt's much tighter tolerances.
* Images are identical across thread counts; packets of every size agree with the brute force.
* Far from the grid's frame (spheres 1e4 apart, a camera near one): packet coordinates are taken
  relative to the packet's origin in float64 before rounding, so float32 keeps the precision of
  the ray's own length; the same tolerances hold.  (float32 directions still limit where a ray
  crosses a triangle to about 1e-7 of its length: at 1e4 pixels' distance that is an edge band
  of 1e-3 of a pixel.)
* The float64 fallback: rays straight down through the diagonal of a square made of two
  triangles (the diagonal's edge function is exactly 0 in float32) and through its corner
  vertices all hit; the float32 loop really leaves them undecided (_test_wt32's flag).
* Batch casts: float32 packets pick the triangle, the float64 test of that triangle gives t, u
  and v (t to 1e-9 of the brute force's where the triangle is the same), any-hit shadow rays
  agree with the brute force; hypothesis batches of pencils of 1..200 rays (packets whose last
  block of 16 lanes is partly empty) likewise.
* Watertightness in float32 (star packets, camera rows): tests/test_watertight.py and
  tests/test_soak.py (10M probes under ``-m soak``) run the float32 watertight test beside the
  float64 one.
"""

import os
import subprocess
import sys

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import reference as R
from conftest import icosphere_tris, random_scene
from gridrt.camera import Camera
from gridrt.config import GridParams, RenderParams
from gridrt.errors import InputError
from gridrt.grid import build_grid
from gridrt.trace import cast_rays, cgt, render
from gridrt.trace.grids import grid_arrays
from helpers.cgt import camera, check_f32, grid_of, trace_one_packet


@pytest.mark.slow  # (the float32 packets' render kernels, about 18 s to compile, for these tests alone)
@pytest.mark.parametrize("watertight", [True, False])
@pytest.mark.parametrize("name", ["random", "icosphere", "teapot", "terrain", "cubes", "dups"])
def test_f32_render_matches_brute_force(name, watertight):
    tris, grid = grid_of(name)
    W, H = 45, 37
    for view in ("framed", "inside", "grazing", "axis", "diagonal"):
        cam = camera(view, tris)
        p = RenderParams(width=W, height=H, tile=8, shading="normal", watertight=watertight)
        ref = R.ref_render(tris, cam, W, H, "normal").hits
        r32 = render(grid, tris, cam, p.replace(packet_precision="float32"))
        d = check_f32(r32, ref, f"{name}/{view} float32")
        r64 = render(grid, tris, cam, p)
        n_diff = int((r64.tri != r32.tri).sum())
        print(f"{name}/{view} wt={watertight}: {(r32.tri >= 0).sum()} hits, {n_diff} pixels differ from the float64 "
              f"packets, {len(d.grazing)} grazing")
        if watertight:  # the float64 packets, with test_cgt's tolerances
            d64 = R.compare_hits(r64.t.reshape(-1).astype(np.float64), r64.tri.reshape(-1), ref, t_rtol=1e-6,
                                 graze_tol=1e-9)
            assert len(d64.bad) == 0


@pytest.mark.slow  # (the float32 packets' render kernels, about 18 s to compile, for these tests alone)
@pytest.mark.parametrize("packet", [1, 4, 16, (16, 4), (3, 7)])
def test_f32_packet_sizes(packet):
    """float32 packets of every size agree with the brute force alike.  (Not bit for bit with
    each other: a packet that straddles a change of the rays' major axis goes ray by ray through
    the float64 DDA, and which packets do depends on their size.)"""
    for name in ("teapot", "cubes", "icosphere"):
        tris, grid = grid_of(name)
        for view in ("framed", "inside", "axis"):
            cam = camera(view, tris)
            p = RenderParams(width=45, height=37, tile=12, shading="normal", packet=packet, packet_precision="float32")
            check_f32(render(grid, tris, cam, p), R.ref_render(tris, cam, 45, 37, "normal").hits,
                      f"{name}/{view} packet {packet}")


@pytest.mark.slow  # (the float32 packets' render kernels, about 18 s to compile, for these tests alone)
def test_f32_images_identical_across_threads():
    tris, grid = grid_of("teapot")
    cam = camera("framed", tris)
    lo, hi = grid.spec.scene_lo, grid.spec.scene_hi
    light = tuple(0.5 * (lo + hi) + np.array([0.3, 1.5, 0.8]) * float((hi - lo).max()))
    p = RenderParams(width=67, height=53, tile=16, shadows=True, light=light, packet_precision="float32")
    a = render(grid, tris, cam, p.replace(threads=1))
    for threads in (2, 3):
        b = render(grid, tris, cam, p.replace(threads=threads))
        for f in ("image", "t", "tri", "cost", "cells"):
            assert np.array_equal(getattr(a, f), getattr(b, f)), f"{f} differs at {threads} threads"


@pytest.mark.slow  # (the float32 packets' render kernels, about 18 s to compile, for these tests alone)
def test_f32_far_from_the_frame():
    """Two unit spheres 1e4 apart (the grid's frame is centred between them) and a camera 4 units
    from one: float32 of the frame coordinates themselves (5000 * 6e-8 = 3e-4) would move edges by
    about 2e-3 of a triangle (edges 0.15); relative to the packet's origin the error is that of a
    ray 3 units long."""
    one = icosphere_tris(3, radius=1.0)
    tris = np.concatenate([one + np.float32([5000.0, 0.0, 0.0]), one - np.float32([5000.0, 0.0, 0.0])])
    grid = build_grid(tris, GridParams())
    cam = Camera(eye=(5001.0123457, 1.5123457, 3.5012345), target=(5000.0, 0.0, 0.0), fov=40.0)
    W = H = 64
    ref = R.ref_render(tris, cam, W, H, "normal").hits
    for wt in (True, False):
        res = render(grid, tris, cam, RenderParams(W, H, shading="normal", watertight=wt, packet_precision="float32"))
        assert (res.tri >= 0).mean() > 0.2
        check_f32(res, ref, f"far from the frame, wt={wt}")


def _square():
    """The unit square in z = 0 as two triangles sharing the diagonal (0,0)-(1,1)."""
    return np.array([[[0, 0, 0], [1, 0, 0], [1, 1, 0]], [[0, 0, 0], [1, 1, 0], [0, 1, 0]]], np.float32)


def _packet(g, o, d, watertight=True, f32=True):
    return trace_one_packet(g, o, d, watertight, f32)


def test_f32_fallback_on_exact_edges():
    tris = _square()
    grid = build_grid(tris, GridParams())
    g = grid_arrays(grid, tris)
    s = np.linspace(0.0, 1.0, 37)
    # straight down through the diagonal (and its ends, the shared vertices), one packet of parallel rays
    o = np.stack([s, s, np.full_like(s, 2.0)], 1)
    d = np.tile([0.0, 0.0, -1.0], (len(s), 1))
    nf, t, f = _packet(g, o, d)
    assert nf == 0
    assert (f >= 0).all() and np.allclose(t, 2.0, rtol=1e-7), f"rays through the shared edge missed: {f}"
    assert (f == 0).all()  # on the edge both triangles are hit at the same t: the lower index wins
    # the float32 loop leaves these rays to the float64 fallback: its edge function is exactly 0
    S = np.zeros(cgt.NS * cgt.PN)
    S32 = S[cgt.O_F32:].view(np.float32)
    I32 = S[cgt.O_F32:].view(np.int32)
    n = len(s)
    S32[cgt.F_OU : cgt.F_OU + n] = o[:, 0] - o[0, 0]  # (permutation for d = -z: U = x, V = y, K = z)
    S32[cgt.F_OV : cgt.F_OV + n] = o[:, 1] - o[0, 1]
    S32[cgt.F_SZ : cgt.F_SZ + n] = -1.0
    S32[cgt.F_BT : cgt.F_BT + n] = np.inf
    I32[cgt.F_BF : cgt.F_BF + n] = -1
    q = (tris[1] - o[0]).astype(np.float32)
    hit, undecided = cgt._test_wt32(S32, I32, n, tuple(q[0]), tuple(q[1]), tuple(q[2]), np.int32(1), np.float32(0.0))
    assert undecided == 1 and hit == 0
    # a packet from one eye at the shared corner and along the diagonal: every ray hits
    eye = np.array([0.3, 0.7, 1.5])
    tg = np.stack([s, s, np.zeros_like(s)], 1)
    nf, t, f = _packet(g, np.tile(eye, (len(s), 1)), tg - eye)
    assert (f >= 0).all()
    np.testing.assert_allclose(t, 1.0, rtol=1e-6)


def test_f32_batch_casts():
    tris = np.ascontiguousarray(icosphere_tris(3), np.float32)
    grid = build_grid(tris, GridParams())
    cam = Camera(eye=(0.4, 0.5, 2.6), target=(0.0, 0.0, 0.0), fov=55.0)
    o, d = cam.rays(96, 80)
    ref = R.ref_cast(tris, o, d)
    perm = np.random.default_rng(4).permutation(len(o))
    for oo, dd, rr in ((o, d, ref), (o[perm], d[perm], R.ref_cast(tris, o[perm], d[perm]))):
        for threads in (1, 2):
            h = cast_rays(grid, tris, oo, dd, threads=threads, packet_precision="float32")
            diff = check_f32(h, rr, "camera rays", 0.002)
            # t, u, v: the float64 test's of the triangle chosen
            same = (h.tri == rr.tri) & (h.tri >= 0)
            np.testing.assert_allclose(h.t[same], rr.t[same], rtol=1e-9)
            assert ((h.u >= 0) & (h.v >= 0) & (h.u + h.v <= 1 + 1e-12))[h.tri >= 0].all()
            assert len(diff.grazing) <= 10
    # shadow rays towards a point, any hit
    hit = ref.tri >= 0
    p = o[hit] + d[hit] * (ref.t[hit] * (1 - 1e-6))[:, None]
    sd = np.array([2.0, 3.0, 1.5])[None, :] - p
    sref = R.ref_cast(tris, p, sd, tmax=1.0)
    a = cast_rays(grid, tris, p, sd, tmax=1.0, any_hit=True, packet_precision="float32")
    occl = (a.tri >= 0) != (sref.tri >= 0)
    assert occl.sum() <= 2, f"{occl.sum()} shadow rays disagree with the brute force"


def test_packet_precision_checked():
    tris = np.ascontiguousarray(icosphere_tris(1), np.float32)
    grid = build_grid(tris, GridParams())
    o, d = Camera(eye=(0, 0, 3.0), target=(0, 0, 0)).rays(4, 4)
    for bad in ("float16", "f32", None, 32):
        with pytest.raises(InputError, match="packet precision"):
            cast_rays(grid, tris, o, d, packet_precision=bad)
        with pytest.raises(InputError, match="packet precision"):
            RenderParams(packet_precision=bad)


_GRID = {}


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 200), threads=st.sampled_from([1, 2, 3]))
def test_f32_random_pencils(seed, n, threads):
    if not _GRID:
        tris = random_scene(np.random.default_rng(21), 300, "mixed", None, dup_frac=0.1, degen_frac=0.05)
        _GRID["v"] = (np.ascontiguousarray(tris, np.float32), build_grid(tris, GridParams()))
    tris, grid = _GRID["v"]
    rng = np.random.default_rng(seed)
    lo, hi = tris.reshape(-1, 3).min(0).astype(np.float64), tris.reshape(-1, 3).max(0).astype(np.float64)
    eye = rng.uniform(lo - 1.0, hi + 1.0)
    tgt = rng.uniform(lo, hi, (n, 3))
    o = np.repeat(eye[None], n, 0)
    d = (tgt - eye) * rng.uniform(0.1, 10.0, (n, 1))
    h = cast_rays(grid, tris, o, d, threads=threads, packet_precision="float32")
    check_f32(h, R.ref_cast(tris, o, d), f"seed {seed}", 0.02)


_KERNELS_RUN = """
import sys
import numpy as np
from gridrt.camera import Camera
from gridrt.config import GridParams, RenderParams
from gridrt.grid import build_grid
from gridrt.trace import render
from gridrt.trace.cgt import rays, walk
rng = np.random.default_rng(0)
tris = (rng.uniform(0, 1, (400, 1, 3)) + rng.uniform(-0.15, 0.15, (400, 3, 3))).astype(np.float32)
grid = build_grid(tris, GridParams())
cam = Camera.frame(tris.min(axis=(0, 1)), tris.max(axis=(0, 1)))
res = render(grid, tris, cam, RenderParams(40, 30, shading="lambert", shadows=True, traversal="cgt",
                                           packet_precision=sys.argv[1], threads=1))
assert (res.tri >= 0).mean() > 0.1
if sys.argv[1] == "float32":  # and from 1e9 away (its rays are moved nearer: the far-ray path)
    render(grid, tris, Camera(eye=(0.5, 0.5, 1e9), target=(0.5, 0.5, 0.5), fov=1e-6),
           RenderParams(8, 6, traversal="cgt", packet_precision="float32", threads=1))
for name in ("_setup32", "_dead32", "_test_wt32", "_fix_wt64", "_count_final32", "_best32", "_move32"):
    kernel = getattr(rays, name)
    s32 = kernel.py_func.__code__.co_varnames.index("S32")
    print(name, " ".join(sorted({str(sig[s32]).split("(")[0] for sig in kernel.signatures})))
print("_move_far", " ".join(sorted({str(sig[3]) for sig in walk._move_far.signatures})))
"""


@pytest.mark.slow  # (a fresh compile of a CGT render in a process of its own, about 20 s, for each precision)
@pytest.mark.parametrize("precision", ["float64", "float32"])
def test_float64_packets_compile_no_float32_tests(precision, tmp_path):
    """A CGT render with float64 packets (the default) compiles the float32 test kernels at most
    as the stubs that return at once on S32 None (their signatures all take none), none of their
    loops; with float32 packets they are compiled for the float32 rows (arrays) and not as stubs.
    Likewise a render whose eye is near the grid compiles the far-ray path (_move_far) only as
    its stub (far None), and one from 1e9 away compiles it whole (far bool).  (In a fresh process
    with an empty numba cache: this one may have compiled either, and a kernel loaded from the
    cache compiles none of the kernels it calls.)"""
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path)}
    r = subprocess.run([sys.executable, "-c", _KERNELS_RUN, precision], env=env, capture_output=True, text=True,
                       timeout=600)
    assert r.returncode == 0, r.stderr[-3000:]
    seen = dict(line.split(" ", 1) for line in r.stdout.strip().splitlines())
    assert set(seen) == {"_setup32", "_dead32", "_test_wt32", "_fix_wt64", "_count_final32", "_best32", "_move32",
                         "_move_far"}
    assert seen["_move_far"] == ("none" if precision == "float64" else "bool none"), seen["_move_far"]
    if precision == "float64":  # the stub at most (or not even that, where the caller's branch is dropped)
        for name in seen:
            if name != "_move_far":
                assert seen[name] in ("none", ""), f"{precision}: {name} compiled for {seen[name]!r}"
    else:  # the kernels the frame called (_fix_wt64 and _move32 only where a ray needs them)
        for name in ("_setup32", "_dead32", "_test_wt32", "_count_final32", "_best32"):
            assert seen[name] == "array", f"{precision}: {name} compiled for {seen[name]!r}"
        for name in ("_fix_wt64", "_move32"):
            assert seen[name] in ("array", ""), f"{precision}: {name} compiled for {seen[name]!r}"
