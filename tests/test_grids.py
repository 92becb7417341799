"""Kernels that take a sequence of grids (gridrt.trace.grids): one scene split into 1, 2 and 3
parts, each part gridded on its own in one frame, traced through the tuple of their GridArrays.

* the single-ray traversal (traverse.trace_grids) and the packet traversal
  (cgt.trace_packet_grids) give the brute-force float64 caster's nearest hits (tests/reference.py),
  as scene ids through each part's ids map, differing only at exact ties;
* the packet traversal gives the single-ray one's t bit for bit, and so does one grid over the
  whole scene (splitting changes which grid holds a triangle, not the arithmetic);
* any_hit (shadow rays): a hit exactly where the reference has one before tmax.
"""

import numpy as np
import pytest
from numba import njit, typeof

import reference as R
from conftest import icosphere_tris, random_triangles
from gridrt.config import GridParams
from gridrt.grid import build_grid
from gridrt.trace import cgt
from gridrt.trace.grids import GridArrays, carries_leaves, grid_tuple
from gridrt.trace.traverse import SCRATCH, trace_grids


@njit(cache=True)
def _dda(grids, origins, dirs, tmax, any_hit, out_w, out_f, out_t):
    mb = np.empty(SCRATCH, np.int32)
    for i in range(origins.shape[0]):
        w, f, t, u, v, nc, nt = trace_grids(grids, (origins[i, 0], origins[i, 1], origins[i, 2]),
                                            (dirs[i, 0], dirs[i, 1], dirs[i, 2]), 0.0, tmax[i], True, any_hit, mb)
        out_w[i] = w
        out_f[i] = f
        out_t[i] = t


@njit(cache=True)
def _packets(grids, origins, dirs, tmax, any_hit, out_w, out_f, out_t):
    """Rays in packets of cgt.PN consecutive rays, traced by cgt.trace_packet_grids."""
    S = np.empty(cgt.NS * cgt.PN)
    io = np.empty(cgt.NIO * cgt.PN)
    io2 = np.empty(cgt.NIO * cgt.PN)
    mb = np.empty(cgt.MBOX, np.int32)
    for a in range(0, origins.shape[0], cgt.PN):
        n = min(cgt.PN, origins.shape[0] - a)
        for j in range(n):
            io[cgt.IO_OX * cgt.PN + j] = origins[a + j, 0]
            io[cgt.IO_OY * cgt.PN + j] = origins[a + j, 1]
            io[cgt.IO_OZ * cgt.PN + j] = origins[a + j, 2]
            io[cgt.IO_DX * cgt.PN + j] = dirs[a + j, 0]
            io[cgt.IO_DY * cgt.PN + j] = dirs[a + j, 1]
            io[cgt.IO_DZ * cgt.PN + j] = dirs[a + j, 2]
            io[cgt.IO_TMAX * cgt.PN + j] = tmax[a + j]
        cgt.trace_packet_grids(grids, n, io, io2, cgt.PacketQuery(0.0, True, any_hit, False, True), S, mb)
        for j in range(n):
            out_w[a + j] = int(io[cgt.IO_W * cgt.PN + j])
            out_f[a + j] = int(io[cgt.IO_F * cgt.PN + j])
            out_t[a + j] = io[cgt.IO_T * cgt.PN + j]


def split_scene(tris, parts, seed=0, kinds=None):
    """The scene's triangles dealt at random into ``parts`` parts: a tuple of GridArrays (all in the
    world's frame; part p's grid of kind kinds[p], uniform by default), the scene ids of each part
    and the frame's origin."""
    rng = np.random.default_rng(seed)
    which = rng.integers(0, parts, len(tris))
    which[:parts] = np.arange(parts)  # no part empty
    kinds = kinds or ("uniform",) * parts
    built, ids, origin = [], [], np.zeros(3)  # one frame for every part and every split
    for p in range(parts):
        idx = np.flatnonzero(which == p).astype(np.int32)
        g = build_grid(tris[idx], GridParams(macro=2, grid=kinds[p]), origin=origin)
        assert g.kind == kinds[p]
        t = np.ascontiguousarray(tris[idx].astype(np.float64) - g.origin, dtype=np.float32)
        built.append((g, t, idx if parts > 1 else None))
        ids.append(idx)
    return grid_tuple(*built), ids, origin


def rays(tris, n, seed=1):
    """Rays from points around the scene towards random points inside its bounds."""
    rng = np.random.default_rng(seed)
    lo, hi = tris.reshape(-1, 3).min(0), tris.reshape(-1, 3).max(0)
    c, r = 0.5 * (lo + hi), float(np.linalg.norm(hi - lo))
    o = c + rng.normal(size=(n, 3)) * r
    d = lo + rng.uniform(size=(n, 3)) * (hi - lo) - o
    # packets of nearby rays from one eye (coherent) and random ones (split by direction class)
    o[: n // 2] = o[0]
    return o, d / np.linalg.norm(d, axis=1, keepdims=True)


def trace(kernel, grids, ids, origin, o, d, tmax, any_hit):
    n = len(o)
    w, f, t = np.empty(n, np.int64), np.empty(n, np.int64), np.empty(n)
    kernel(grids, np.ascontiguousarray(o - origin), d, tmax, any_hit, w, f, t)
    scene = np.full(n, -1, np.int64)
    hit = f >= 0
    if len(grids) > 1:
        for p, idx in enumerate(ids):
            sel = hit & (w == p)
            scene[sel] = idx[f[sel]]
    else:
        assert (w[hit] == 0).all()
        scene[hit] = f[hit]
    return scene, t


SCENES = {
    "icosphere": lambda: icosphere_tris(3, radius=1.0, center=(0.3, -0.2, 0.1)),
    "random": lambda: random_triangles(np.random.default_rng(5), 400),
}


@pytest.mark.parametrize("three", [False, pytest.param(True, marks=pytest.mark.slow)], ids=["1-2 grids", "3 grids"])
@pytest.mark.parametrize("name", sorted(SCENES))
def test_grid_sequences_match_brute_force(name, three):
    """Tuples of 1 and 2 uniform grids against the float64 brute force; in the slow run (each
    tuple type is a compile of its own of the two test kernels) 3 uniform grids, and two-level
    grids alone and beside uniform ones."""
    tris = np.asarray(SCENES[name](), np.float32)
    o, d = rays(tris, 1500)
    ref = R.ref_cast(tris, o, d)
    assert ref.hit.sum() > 200, "the rays should hit the scene"
    tmax = np.full(len(o), np.inf)
    t_first = None
    for parts in (3,) if three else (1, 2):
        grids, ids, origin = split_scene(tris, parts)
        assert isinstance(grids[0], GridArrays) and len(grids) == parts
        for kernel in (_dda, _packets):
            tri, t = trace(kernel, grids, ids, origin, o, d, tmax, False)
            diff = R.compare_hits(t, tri, ref)
            assert len(diff.bad) == 0, f"{name}, {parts} grids, {kernel.__name__}: rays {diff.bad[:10]} disagree"
            if t_first is None:
                t_first = t
            assert np.array_equal(t, t_first), f"{name}, {parts} grids, {kernel.__name__}: t differs"
        print(f"{name}, {parts} grids: {int(ref.hit.sum())} hits, {len(diff.tie)} ties")
    # two-level grids, alone and beside a uniform one (whose GridArrays then carry empty leaf arrays)
    for kinds in (("uniform", "two_level", "uniform"), ("two_level",), ("two_level", "uniform")) if three else ():
        grids, ids, origin = split_scene(tris, len(kinds), kinds=kinds)
        assert all(g.leaf_first is not None for g in grids)
        assert [len(g.leaf_first) > 0 for g in grids] == [k == "two_level" for k in kinds]
        for kernel in (_dda, _packets):
            tri, t = trace(kernel, grids, ids, origin, o, d, tmax, False)
            diff = R.compare_hits(t, tri, ref)
            assert len(diff.bad) == 0, f"{name}, grids {kinds}, {kernel.__name__}: rays {diff.bad[:10]} disagree"


def _defined_functions(llvm_ir):
    """The names of the functions an LLVM module defines."""
    return [line.split("@", 1)[1].split("(", 1)[0] for line in llvm_ir.splitlines() if line.startswith("define ")]


def test_uniform_grids_compile_no_two_level_code():
    """A kernel given only uniform grids holds none of the two-level traversal: GridArrays without
    leaf arrays are a numba type of their own, and the two-level calls are overloads that compile
    to nothing for it.  Checked on the machine code's LLVM module of a fresh (uncached) compile of
    trace_grids: the two-level DDA's function is defined in it only for grids that carry leaves."""
    tris = random_triangles(np.random.default_rng(4), 200)
    uni, _, _ = split_scene(tris, 2)
    mixed, _, _ = split_scene(tris, 2, kinds=("two_level", "uniform"))
    assert uni[0].leaf_first is None and mixed[1].leaf_first is not None
    assert not carries_leaves(typeof(uni[0])) and carries_leaves(typeof(mixed[1]))
    fresh = njit(_dda.py_func)  # no cache: compiled here, with its callees linked into its module
    o, d = rays(tris, 8)
    tmax = np.full(len(o), np.inf)
    for grids, two in ((uni, False), (mixed, True)):
        w, f, t = np.empty(8, np.int64), np.empty(8, np.int64), np.empty(8)
        fresh(grids, o, d, tmax, False, w, f, t)
        sig = fresh.signatures[-1]
        names = _defined_functions(fresh.inspect_llvm(sig))
        assert any("trace_ray" in n for n in names), "the traversal should be in the kernel's module"
        assert any("trace_ray_2l" in n for n in names) == two, \
            f"grids {'with' if two else 'without'} leaf arrays: trace_ray_2l {'missing' if two else 'compiled in'}"


@pytest.mark.parametrize("parts", [2, pytest.param(3, marks=pytest.mark.slow)], ids=["2 grids", "3 grids"])
@pytest.mark.parametrize("kernel", [_dda, _packets], ids=["dda", "packets"])
def test_grid_sequences_any_hit(kernel, parts):
    """Shadow-ray semantics over two grids (three in the slow run, a compile of its own): a hit iff
    the scene has one in (0, tmax)."""
    tris = np.asarray(icosphere_tris(3, radius=1.0), np.float32)
    o, d = rays(tris, 1200, seed=2)
    ref = R.ref_cast(tris, o, d)
    # rays ending halfway to their nearest hit (none may be found) or beyond it (one must be)
    far = np.arange(len(o)) % 2 == 0
    tmax = np.where(ref.hit, np.where(far, 1.5 * ref.t, 0.5 * ref.t), np.inf)
    want = ref.hit & far
    grids, ids, origin = split_scene(tris, parts)
    tri, t = trace(kernel, grids, ids, origin, o, d, tmax, True)
    got = tri >= 0
    assert ref.hit.sum() > 200 and want.sum() > 100
    assert np.array_equal(got, want), f"any_hit differs on rays {np.flatnonzero(got != want)[:10]}"
    assert (t[got] < tmax[got]).all()
    # the hit found is one of the scene's triangles on the ray before tmax
    for i in np.flatnonzero(got)[:50]:
        one = R.ref_cast(tris[tri[i] : tri[i] + 1], o[i : i + 1], d[i : i + 1], tmax=tmax[i])
        assert one.hit[0] and abs(one.t[0] - t[i]) <= 1e-5 * max(one.t[0], 1e-6)
