"""Two-level grids (engine/grid/two_level.py) against independent references.

The engine chooses the geometry: the top level's placement (``grid.spec``) and each top cell's
leaf resolution (``grid.leaf_res``).  Given that geometry, the contents of both levels are fully
defined by the membership rules (engine/grid/layout.py, engine/grid/two_level.py): the top level
is a uniform grid under the uniform rule, and top cell t's leaf cells hold, among t's triangles,
those the uniform rule puts in each cell of the leaf grid over t's box.  tests/reference.py
recomputes both levels by brute force in float64 (``ref_pairs_two_level``), with floating-point
ties as don't-care (a triangle whose top-level membership is a tie makes every leaf pair it could
have a tie).  The leaf resolution itself is checked against its written rule (about
leaf_density * n_t leaf cells, shaped like the top cell, at least one a side, none for an empty
top cell), and leaf_first against the prefix sum of the leaf cell counts.

Hits are compared with the float64 brute-force caster (``reference.ref_cast``) as
tests/test_rays.py does, through cast_rays (single rays and packets, watertight and fast tests),
RayCaster and the renderer (DDA and CGT, 1/2/3 threads, shadows): the same images as the uniform
grid's of the same scene (the same hits; a triangle may differ only at an exact tie, which the
brute force confirms).  A split BART scene (the shipped museum) through FramePipeline, and a
scene 1e6 from the origin.  Watertightness with tests/test_watertight.py's probes (a 10M-probe
version under ``-m soak``), the input and memory guards, a GridBuilder switching between grid
kinds from frame to frame, and GridParams(grid="auto") (its choice against the documented
crowding, computed from the reference's top level).

Build threads: the contents are checked for 1-4 build threads (a multi-threaded case builds
several frames, since a race shows on some builds only, such as a leaf scatter that lets two
threads write the first leaf cell of a chunk); the other tests build on the default thread count.
"""

import os
import time
import warnings

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import reference as R
from conftest import (ARMADILLO, TEAPOT, data_path, icosphere, load_mesh_arrays, load_tris, random_scene,
                      random_triangles)
from gridrt import RayCaster
from gridrt.camera import Camera
from gridrt.config import GridParams, RenderParams
from gridrt.errors import InputError
from gridrt.grid import GridBuilder, build_grid, names
from gridrt.trace import cast_rays, render
from helpers.grids import _check_pairs, check_spec
from helpers.memory import traced
from helpers.cgt import assert_same, check_f32, render_both
from helpers.cgt import camera as cgt_camera
from helpers.cgt import scene as cgt_scene
from helpers.rays import GRAZE, _hard_rays, assert_hits_match, get_case
from helpers.watertight import (REL, ProbeMesh, add_counts, face_normals, origins_in_front, packet_counts,
                             row_counts, shoot, targets_and_fans)

STRATEGIES = names()
#: the largest leaf cell count per axis the engine allows (two_level.leaf_resolution's max_res)
MAX_LEAF_RES = 1 << 10


def two_level(**kw):
    """GridParams of a two-level grid."""
    return GridParams(grid="two_level", **kw)


def in_frame(tris, grid):
    """The triangles as the grid stores them: in its frame (build_grid centres a far scene)."""
    return tris if not grid.origin.any() else (np.asarray(tris, np.float64) - grid.origin).astype(np.float32)


# ----------------------------------------------------------------------------------------------
# scenes


def uneven_base(seed=2011, clusters=4, per_cluster=2500, huge=16, medium=100, degenerate=40):
    """Clusters of small triangles, a few huge ones spanning the scene, medium ones scattered,
    and zero-area ones (repeated vertex, collinear) among the clusters."""
    rng = np.random.default_rng(seed)
    parts = []
    for c in rng.uniform(0.1, 0.9, (clusters, 3)):
        centres = c + rng.normal(0.0, 0.03, (per_cluster, 1, 3))
        parts.append(centres + rng.normal(0.0, 0.004, (per_cluster, 3, 3)))
    parts.append(rng.uniform(-0.2, 1.2, (huge, 3, 3)))
    parts.append(rng.uniform(0.0, 1.0, (medium, 1, 3)) + rng.normal(0.0, 0.05, (medium, 3, 3)))
    t = np.concatenate(parts)
    deg = t[rng.choice(clusters * per_cluster, degenerate, replace=False)].copy()
    h = degenerate // 2
    deg[:h, 2] = deg[:h, 0]
    deg[h:, 2] = 2.0 * deg[h:, 1] - deg[h:, 0]
    t = np.concatenate([t, deg])
    return t[rng.permutation(len(t))].astype(np.float32)


_SCENES = {}


def uneven_scene():
    """:func:`uneven_base` plus one tiny triangle in the lowest corner of every top cell of its
    default two-level grid, so every top cell, and the first leaf cell of each, holds something
    (wherever a parallel pass splits the top cells into chunks, the first leaf cell of a chunk is
    written: where a racy leaf scatter shows).  The corner triangles are placed after a
    build with as many placeholders, so the scene's bounds and triangle count, hence its top-level
    geometry, do not change."""
    if "uneven" not in _SCENES:
        base = uneven_base()
        p = two_level()
        T = 0
        for _ in range(10):
            spec = build_grid(np.concatenate([base, np.repeat(base[:1], T, axis=0)]), p).spec
            if spec.n_cells == T:
                break
            T = spec.n_cells
        d = spec.dims
        i = np.arange(T)
        ijk = np.stack([i % d[0], i // d[0] % d[1], i // (d[0] * d[1])], axis=1)
        c0 = spec.lo + (ijk + 0.01) * spec.cell
        e = 0.001 * spec.cell
        corner = np.stack([c0, c0 + [e[0], 0.0, 0.0], c0 + [0.0, e[1], e[2]]], axis=1)
        tris = np.concatenate([base, corner.astype(np.float32)])
        s2 = build_grid(tris, p).spec
        assert np.array_equal(s2.lo, spec.lo) and np.array_equal(s2.dims, spec.dims)
        _SCENES["uneven"] = tris
    return _SCENES["uneven"]


def spanning_triangles(n, seed=1):
    """n triangles whose bounding boxes are the whole unit cube (each in every cell)."""
    u = np.random.default_rng(seed).uniform(0, 1, (n, 3))
    return np.stack([np.stack([np.zeros(n), u[:, 0], np.ones(n)], 1),
                     np.stack([np.ones(n), np.zeros(n), u[:, 1]], 1),
                     np.stack([u[:, 2], np.ones(n), np.zeros(n)], 1)], axis=1).astype(np.float32)


# ----------------------------------------------------------------------------------------------
# the reference itself


UNIT2 = dict(lo=np.zeros(3), cell=np.ones(3), dims=np.array([2, 1, 1]))


def test_reference_two_level_hand_computed():
    """Top grid of two unit cells along x; cell 0 split 2 x 2 x 2 (leaf cells 0..7), cell 1 into
    one (leaf cell 8)."""
    res = np.array([[2, 2, 2], [1, 1, 1]])
    assert R.ref_leaf_first(res).tolist() == [0, 8, 9]
    # in the plane z = 0.25, bbox [0.1, 0.7] x [0.1, 0.3]: top cell 0, leaf cells (0, 0, 0), (1, 0, 0)
    tri = np.array([[[0.1, 0.1, 0.25], [0.7, 0.1, 0.25], [0.1, 0.3, 0.25]]], np.float32)
    top, leaf = R.ref_pairs_two_level(tri, **UNIT2, leaf_res=res, exact=False)
    assert top.pairs.tolist() == [[0, 0]] and leaf.pairs.tolist() == [[0, 0], [1, 0]]
    assert len(leaf.ambiguous) == 0
    # crossing into top cell 1 (x up to 1.4): leaf cells 0, 1 of cell 0 and the one leaf of cell 1;
    # with z from 0.25 to 0.75 the bounding box also covers leaf cells (0, 0, 1) and (1, 0, 1)
    tri = np.array([[[0.1, 0.1, 0.25], [1.4, 0.1, 0.75], [0.1, 0.3, 0.25]]], np.float32)
    _, leaf = R.ref_pairs_two_level(tri, **UNIT2, leaf_res=res, exact=False)
    assert leaf.pairs[:, 0].tolist() == [0, 1, 4, 5, 8]
    # exact: the triangle's plane z = 0.25 + (x - 0.1) * 0.5 / 1.3 (constant in y) reaches z = 0.5 only
    # at x = 0.75, so leaf (0, 0, 1) (x <= 0.5) is out (bbox-only), (1, 0, 1) in
    _, leaf = R.ref_pairs_two_level(tri, **UNIT2, leaf_res=res, exact=True)
    assert leaf.pairs[:, 0].tolist() == [0, 1, 5, 8]
    # growth is in leaf cell sizes: a box ending 0.4e-5 leaf cells (0.2e-5 top cells) before the
    # leaf face x = 0.5 is grown into leaf cell (1, 0, 0); 2.4e-5 leaf cells before, it is not
    for gap, want in ((0.2e-5, [0, 1]), (1.2e-5, [0])):
        tri = np.array([[[0.1, 0.1, 0.25], [0.5 - gap, 0.1, 0.25], [0.1, 0.3, 0.25]]], np.float32)
        _, leaf = R.ref_pairs_two_level(tri, **UNIT2, leaf_res=res, exact=False)
        assert leaf.pairs[:, 0].tolist() == want, gap
    # zero area: in no cell of either level
    tri = np.array([[[0.1, 0.1, 0.25], [0.7, 0.1, 0.25], [0.4, 0.1, 0.25]]], np.float32)
    top, leaf = R.ref_pairs_two_level(tri, **UNIT2, leaf_res=res, exact=False)
    assert len(top.pairs) == len(leaf.pairs) == 0


def test_reference_two_level_ties_propagate():
    """A triangle whose top-level membership is a tie (its grown box ends exactly on top cell
    1's face) makes its leaf pairs in that top cell ties too."""
    tri = np.array([[[0.3, 0.2, 0.5], [0.7, 0.3, 0.5], [0.3, 0.6, 0.5]]], np.float32)
    xmax = np.float64(tri[0, 1, 0])
    lo = np.array([xmax + 1e-5 - 1.0, 0.0, 0.0])
    res = np.array([[2, 2, 2], [3, 1, 2]])
    top, leaf = R.ref_pairs_two_level(tri, lo, np.ones(3), np.array([2, 1, 1]), res, exact=False)
    assert [1, 0] in top.ambiguous.tolist()
    first = R.ref_leaf_first(res)
    in_1 = leaf.ambiguous[(leaf.ambiguous[:, 0] >= first[1]) & (leaf.ambiguous[:, 0] < first[2])]
    assert len(in_1) > 0
    missing, extra = R.compare_pairs_array(leaf.pairs[leaf.pairs[:, 0] < first[1]], leaf)
    assert len(missing) == len(extra) == 0  # leaving out top cell 1's leaves is allowed


@pytest.mark.parametrize("exact", [False, True], ids=["bbox", "exact"])
def test_reference_two_level_candidates_equal_all_cells(rng, exact):
    """The leaf candidate ranges lose nothing against testing every leaf cell of the top cell."""
    for trial in range(4):
        tris = random_scene(rng, 30, flat_axis=(trial if trial < 3 else None), degen_frac=0.1)
        lo = tris.reshape(-1, 3).min(0).astype(np.float64) - 0.01
        hi = tris.reshape(-1, 3).max(0).astype(np.float64) + 0.01
        dims = rng.integers(1, 4, 3)
        res = rng.integers(0, 5, (int(np.prod(dims)), 3))
        res[res.min(axis=1) == 0] = 0
        a = R.ref_pairs_two_level(tris, lo, (hi - lo) / dims, dims, res, exact)[1]
        b = R.ref_pairs_two_level(tris, lo, (hi - lo) / dims, dims, res, exact, all_cells=True)[1]
        assert np.array_equal(a.pairs, b.pairs) and np.array_equal(a.ambiguous, b.ambiguous)


def test_compare_pairs_array_equals_compare_pairs(rng):
    pairs = rng.integers(0, 50, (400, 2))
    ref = R.RefPairs(np.unique(rng.integers(0, 50, (300, 2)), axis=0), np.unique(rng.integers(0, 50, (80, 2)), axis=0))
    m, x = R.compare_pairs_array(pairs, ref)
    m2, x2 = R.compare_pairs(pairs, ref)
    assert [tuple(r) for r in m.tolist()] == m2 and [tuple(r) for r in x.tolist()] == x2


# ----------------------------------------------------------------------------------------------
# contents against the reference


def ideal_leaf_res(cell, active, target):
    """The written leaf resolution rule, solved continuously: per axis max(1, e * s) for the top
    cell's extents e (0 along an axis of zero scene extent), with s such that the product is
    ``target`` (about target cubical cells, an axis too thin for one cell keeps one and the others
    share the count).  target (n,) >= 1; returns (n, 3) float64."""
    e = np.where(active, np.asarray(cell, np.float64), 0.0)
    if not (e > 0).any():
        return np.ones((len(target), 3))
    lo = np.full(len(target), np.log(1.0 / e.max()))  # prod == 1 here
    hi = np.log(np.asarray(target, np.float64) / e[e > 0].min()) + 1.0
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        prod = np.prod(np.maximum(1.0, e[None, :] * np.exp(mid)[:, None]), axis=1)
        big = prod >= target
        hi = np.where(big, mid, hi)
        lo = np.where(big, lo, mid)
    return np.maximum(1.0, e[None, :] * np.exp(hi)[:, None])


def check_leaf_resolution(g, n_t, leaf_density, label):
    """leaf_res against its rule, for the top cells' reference counts n_t (T,)."""
    res = np.asarray(g.leaf_res, np.int64)
    T = g.spec.n_cells
    assert res.shape == (T, 3), f"{label}: leaf_res shape {res.shape} for {T} top cells"
    empty = n_t == 0
    assert (res[empty] == 0).all(), f"{label}: an empty top cell has leaf cells"
    full = ~empty
    assert (res[full] >= 1).all(), f"{label}: a non-empty top cell has an axis without a leaf cell"
    s = g.spec
    ext = s.scene_hi - s.scene_lo
    active = ext > 1e-9 * max(float(ext.max()), 1e-300)
    target = np.maximum(1.0, leaf_density * n_t[full])
    ideal = ideal_leaf_res(s.cell, active, target)
    got = res[full]
    ok = (np.abs(got - ideal) <= 1.0 + 1e-9) | ((ideal > MAX_LEAF_RES) & (got >= MAX_LEAF_RES - 1))
    assert (got <= MAX_LEAF_RES).all()
    bad = np.flatnonzero(~ok.all(axis=1))
    assert len(bad) == 0, (f"{label}: {len(bad)} top cells' leaf resolution is off the rule; first: n_t "
                           f"{n_t[full][bad[:3]].tolist()}, leaf_res {got[bad[:3]].tolist()}, about "
                           f"{np.round(ideal[bad[:3]], 2).tolist()} (top cell {s.cell.tolist()})")
    assert (got[:, ~active] == 1).all(), f"{label}: an axis of zero scene extent was split"


_REFS = {}


def two_level_reference(local, g, exact):
    """ref_pairs_two_level on the grid's geometry, cached (the matrix tests share scenes)."""
    s = g.spec
    key = (hash(local.tobytes()), local.shape, s.lo.tobytes(), s.cell.tobytes(), s.dims.tobytes(),
           np.asarray(g.leaf_res, np.int64).tobytes(), exact)
    if key not in _REFS:
        if len(_REFS) > 16:
            _REFS.clear()
        _REFS[key] = R.ref_pairs_two_level(local, s.lo, s.cell, s.dims, g.leaf_res, exact)
    return _REFS[key]


def check_two_level(g, local, params, label):
    """Both levels of two-level grid ``g`` (built with ``params`` over ``local``, the triangles in
    its frame) against the brute force; the leaf resolution, leaf_first, CSR layout and stats."""
    exact = params.insert == "exact"
    assert g.kind == "two_level" and g.stats.grid == "two_level", label
    for stage in ("leaf_res_ms", "leaf_count_ms", "leaf_scatter_ms"):
        assert stage in g.stats.stages, f"{label}: stage {stage} missing from the build stats"
    s = g.spec
    check_spec(g, local, params.replace(density=params.top_density, macro=1))
    T = s.n_cells
    F = len(local)
    top, leaf = two_level_reference(local, g, exact)
    # top level
    tp = g.top_pairs()
    missing, extra = R.compare_pairs_array(tp, top)
    assert not len(missing) and not len(extra), (
        f"{label}: top level: {len(missing)} (top cell, tri) pairs missing, {len(extra)} extra; first missing "
        f"{missing[:5].tolist()}, first extra {extra[:5].tolist()}; dims {s.dims.tolist()}")
    assert g.top_references == len(tp) == g.stats.counters["top_references"], f"{label}: top references"
    n_t = np.bincount(tp[:, 0], minlength=T) if len(tp) else np.zeros(T, np.int64)
    occupied = np.asarray(g.macro_full[:T]).astype(bool)
    assert np.array_equal(occupied, n_t > 0), f"{label}: top cell occupancy flags differ from the top cells' lists"
    # leaf geometry
    check_leaf_resolution(g, n_t, params.leaf_density, label)
    first = R.ref_leaf_first(g.leaf_res)
    assert np.array_equal(np.asarray(g.leaf_first, np.int64), first), f"{label}: leaf_first is not the prefix sum"
    N = int(first[-1])
    assert g.n_leaf == N == g.stats["cells"], f"{label}: leaf cell count"
    for t in np.flatnonzero(n_t)[:: max(1, int(np.count_nonzero(n_t)) // 5)]:
        ijk = np.array([t % s.dims[0], t // s.dims[0] % s.dims[1], t // (s.dims[0] * s.dims[1])])
        llo, lcell, lres = g.leaf_geometry(t)
        assert np.array_equal(lres, g.leaf_res[t]) and np.allclose(llo, s.lo + ijk * s.cell, rtol=0, atol=1e-12 * (
            np.abs(s.lo).max() + np.abs(s.hi).max())) and np.allclose(lcell, s.cell / g.leaf_res[t], rtol=1e-12), \
            f"{label}: leaf_geometry({t})"
    # leaf CSR
    cs = np.asarray(g.cell_start, np.int64)
    assert cs.shape == (1, N + 1) and cs[0, 0] == 0 and (np.diff(cs[0]) >= 0).all(), f"{label}: leaf offsets"
    assert cs[0, -1] == g.references == g.stats["references"], f"{label}: references"
    assert np.array_equal(np.asarray(g.cell_count[0, :N], np.int64), np.diff(cs[0])), f"{label}: leaf counts"
    ids = np.asarray(g.tri_ids[: g.references], np.int64)
    assert ((ids >= 0) & (ids < F)).all(), f"{label}: a leaf cell holds a triangle id out of range"
    lp = np.stack([np.repeat(np.arange(N), np.diff(cs[0])), ids], axis=1)  # every (leaf cell, tri) entry
    assert len(np.unique(lp[:, 0] * F + lp[:, 1])) == len(lp), f"{label}: a triangle is stored twice in one leaf cell"
    used = 4 * (N + 1) + 4 * g.references + 4 * (T + 1) + 12 * T + 4 * (T + 1) + 4 * g.top_references
    assert g.memory_bytes() >= used and g.stats["grid_bytes"] == g.memory_bytes(), f"{label}: memory_bytes"
    missing, extra = R.compare_pairs_array(lp, leaf)
    assert not len(missing) and not len(extra), (
        f"{label}: leaf level: {len(missing)} (leaf cell, tri) pairs missing, {len(extra)} extra; first missing "
        f"{missing[:5].tolist()}, first extra {extra[:5].tolist()}")
    return top, leaf


def check_both_inserts(tris, params, label):
    """build_grid with bbox and exact insertion, each against the reference; exact keeps a subset."""
    out = {}
    for mode in ("bbox", "exact"):
        p = params.replace(insert=mode)
        g = build_grid(tris, p)
        _, leaf = check_two_level(g, in_frame(tris, g), p, f"{label} {mode}")
        missing, extra = R.compare_pairs_array(g.pairs(), leaf)  # the public listing too
        assert not len(missing) and not len(extra), f"{label} {mode}: TwoLevelGrid.pairs() differs"
        out[mode] = g
    b, e = out["bbox"], out["exact"]
    assert np.array_equal(b.spec.lo, e.spec.lo) and np.array_equal(b.spec.dims, e.spec.dims)
    assert R.pairs_to_set(e.top_pairs()) <= R.pairs_to_set(b.top_pairs())
    return out


#: builds per multi-threaded case (a race shows on some builds only): threads 3 in the default run, threads 2 and 4 (more builds) under the soak marker
REPEATS, REPEATS_SLOW = 2, 8


def _matrix():
    out = []
    for strategy in STRATEGIES:
        for threads in (1, 2, 3, 4):
            for insert in ("bbox", "exact"):
                marks = [pytest.mark.soak] if threads in (2, 4) else []
                out.append(pytest.param(strategy, threads, insert, marks=marks, id=f"{strategy}-{threads}-{insert}"))
    return out


@pytest.mark.parametrize("strategy,threads,insert", _matrix())
def test_contents_every_strategy_and_thread_count(strategy, threads, insert):
    """The uneven scene (clusters of small triangles, huge ones, zero-area ones), every strategy
    building the top level, 1-4 threads, both insertion tests; a multi-threaded case builds a few
    frames on one GridBuilder and every one must equal the reference."""
    tris = uneven_scene()
    p = GridParams(grid="two_level", strategy=strategy, threads=threads, insert=insert)
    builder = GridBuilder(p)
    for rep in range(1 if threads == 1 else REPEATS if threads == 3 else REPEATS_SLOW):
        g = builder.build(tris)
        if strategy == "thread_grids":
            assert g.top_start.shape[0] == threads  # one top-level layer per thread, all of them read
        check_two_level(g, tris, p, f"{strategy} threads={threads} {insert} build {rep}")


def check_grid(g, tris, p, label):
    """Contents of ``g`` (built with ``p`` over ``tris``), whichever kind it is, against the reference."""
    if g.kind == "two_level":
        check_two_level(g, tris, p, label)
    else:
        assert g.kind == "uniform" and g.stats.grid == "uniform", label
        check_spec(g, tris, p)
        _check_pairs(g, tris, p.insert, label)


def crowding(counts):
    """The documented crowding of a top level with reference counts ``counts`` per cell
    (gridrt.grid.build.crowding): the mean count of the cell a reference lies in, over the mean
    count of a non-empty cell."""
    n = np.asarray(counts, np.float64)
    n = n[n > 0]
    return float((n * n).sum() / n.sum() / (n.sum() / len(n))) if len(n) else 1.0


@pytest.mark.parametrize("scene", ["uneven", "even"])
def test_auto_kind(scene):
    """GridParams(grid="auto"): a two-level grid where the top level's crowding reaches
    AUTO_CROWDING (the crowding computed here from the reference's top-level contents), a
    uniform grid otherwise; either way the contents equal the reference."""
    from gridrt.grid.build import AUTO_CROWDING

    if scene == "uneven":
        tris = uneven_base(per_cluster=400, huge=6)
    else:
        tris = random_triangles(np.random.default_rng(5), 2000, size=0.03)
    for mode in ("bbox", "exact"):
        p = GridParams(grid="auto", insert=mode)
        g = build_grid(tris, p)
        s = build_grid(tris, two_level(insert=mode)).spec  # the top level's geometry
        top = (R.ref_pairs_exact if mode == "exact" else R.ref_pairs_bbox)(tris, s.lo, s.cell, s.dims)
        c = crowding(np.bincount(top.pairs[:, 0], minlength=s.n_cells))
        print(f"{scene} {mode}: crowding {c:.2f} -> {g.kind}")
        assert g.kind == ("two_level" if c >= AUTO_CROWDING else "uniform"), (scene, mode, c)
        assert g.kind == ("two_level" if scene == "uneven" else "uniform")  # (the scenes are far from the threshold)
        check_grid(g, tris, p, f"auto {scene} {mode}")


def _random_case(seed, n, size_mode, flat_axis, dup_frac, degen_frac, scale, offset):
    try:
        tris = random_scene(np.random.default_rng(seed), n, size_mode, flat_axis, dup_frac, degen_frac)
    except AssertionError:  # the generator's triangle 0 came out degenerate in float32 (a sliver)
        return None
    tris = (tris.astype(np.float64) * scale + offset).astype(np.float32)
    t = R.tris64(tris)
    if not np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]).any():
        return None  # float32 rounding collapsed every triangle (a sliver far from the origin)
    return tris


RANDOM = dict(
    seed=st.integers(0, 2**32 - 1),
    n=st.integers(1, 120),
    size_mode=st.sampled_from(["mixed", "small", "medium", "huge", "sliver"]),
    flat_axis=st.sampled_from([None, None, 0, 1, 2]),
    dup_frac=st.sampled_from([0.0, 0.1, 0.5]),
    degen_frac=st.sampled_from([0.0, 0.1, 0.5]),
    top_density=st.sampled_from([0.01, 0.0625, 0.3, 1.0]),
    leaf_density=st.sampled_from([0.1, 0.5, 2.0, 6.0]),
    scale=st.sampled_from([1.0, 1.0, 1e-3, 1e4]),
    offset=st.sampled_from([0.0, 0.0, 1e3, -3e4, 1e6]),
)


def _random_contents(seed, n, size_mode, flat_axis, dup_frac, degen_frac, top_density, leaf_density, scale, offset):
    tris = _random_case(seed, n, size_mode, flat_axis, dup_frac, degen_frac, scale, offset)
    if tris is not None:
        check_both_inserts(tris, two_level(top_density=top_density, leaf_density=leaf_density), "random scene")


@settings(max_examples=60, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
@given(**RANDOM)
def test_contents_random_scenes(seed, n, size_mode, flat_axis, dup_frac, degen_frac, top_density, leaf_density, scale,
                                offset):
    """Random scenes (slivers, huge, flat, duplicated and zero-area triangles; scaled; far from
    the origin, where build_grid grids them in a frame centred on them) and densities."""
    _random_contents(seed, n, size_mode, flat_axis, dup_frac, degen_frac, top_density, leaf_density, scale, offset)


@pytest.mark.soak
@settings(max_examples=600, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
@given(**RANDOM)
def test_contents_random_scenes_many(seed, n, size_mode, flat_axis, dup_frac, degen_frac, top_density, leaf_density,
                                     scale, offset):
    _random_contents(seed, n, size_mode, flat_axis, dup_frac, degen_frac, top_density, leaf_density, scale, offset)


@pytest.mark.parametrize("flat_axis", [0, 1, 2])
def test_contents_flat_scene(flat_axis):
    """A scene of zero extent along one axis: one top cell and one leaf cell along it."""
    tris = random_scene(np.random.default_rng(40 + flat_axis), 400, "mixed", flat_axis, 0.0, 0.05)
    out = check_both_inserts(tris, two_level(top_density=0.2, leaf_density=3.0), f"flat {flat_axis}")
    g = out["bbox"]
    assert g.spec.dims[flat_axis] == 1
    assert (g.leaf_res[g.leaf_res.any(axis=1), flat_axis] == 1).all()


@pytest.mark.parametrize("relpath,top_density,leaf_density", [
    (TEAPOT, 0.0625, 2.0),
    (TEAPOT, 0.01, 8.0),
    pytest.param(ARMADILLO, 0.0625, 2.0, marks=pytest.mark.soak),
])
def test_contents_real_mesh(relpath, top_density, leaf_density):
    tris = load_tris(relpath)
    check_both_inserts(tris, two_level(top_density=top_density, leaf_density=leaf_density), relpath)


def test_contents_far_from_origin():
    """The teapot 1e6 from the origin: gridded in a frame centred on it, same contents there."""
    tris = load_tris(TEAPOT).astype(np.float64) + np.array([1e6, -7e5, 3e5])
    out = check_both_inserts(tris, two_level(), "teapot at 1e6")
    assert np.abs(out["bbox"].origin).max() > 1e5


@pytest.mark.parametrize("top_density,leaf_density", [(1e-6, 2.0), (2.0, 0.01), (0.0625, 40.0)])
def test_contents_extreme_densities(top_density, leaf_density):
    """One top cell; one leaf cell per top cell; a very fine leaf level."""
    tris = uneven_base(per_cluster=150, huge=3)
    check_both_inserts(tris, two_level(top_density=top_density, leaf_density=leaf_density),
                       f"densities {top_density}/{leaf_density}")


# ----------------------------------------------------------------------------------------------
# hits against the brute force


def leaf_hard_rays(rng, grid, n):
    """Rays that stress the two-level DDA: test_rays' hard rays (axis-parallel, in cell faces,
    through cell corners, on the bounds) over the top level, and over the leaf grids of the
    fullest top cells (geometry from the spec and leaf_res by the documented formula)."""
    s = grid.spec
    parts = [_hard_rays(rng, s, n // 2)]
    res = np.asarray(grid.leaf_res, np.int64)
    full = np.argsort(-res.prod(axis=1))[:4]
    for t in full:
        if res[t].prod() == 0:
            continue
        ijk = np.array([t % s.dims[0], t // s.dims[0] % s.dims[1], t // (s.dims[0] * s.dims[1])])
        lo = s.lo + ijk * s.cell
        cell = s.cell / res[t]

        class Leaf:  # the leaf grid, as _hard_rays reads a spec
            pass

        lg = Leaf()
        lg.lo, lg.cell, lg.dims, lg.hi = lo, cell, res[t], lo + s.cell
        parts.append(_hard_rays(rng, lg, n // 8))
    return np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts])


_HARD = {}


def hard_case(scene):
    """(tris, origins, dirs, reference) of leaf_hard_rays on the default two-level grid of a
    test_rays scene."""
    if scene not in _HARD:
        c = get_case(scene)
        g = build_grid(c.tris, two_level())
        o, d = leaf_hard_rays(np.random.default_rng(77), g, 8000)
        _HARD[scene] = (c.tris, o, d, R.ref_cast(c.tris, o, d))
    return _HARD[scene]


#: the tests that cast rays through two-level grids (cast_rays, RayCaster): the slow run's, as the
#: two-level grid's batch cast kernel takes about 40 s to compile for them alone; the quick run
#: keeps the two-level contents, renders (DDA and CGT, with their watertightness probes) and all-hits
BATCH_CAST = pytest.mark.slow


@BATCH_CAST
@pytest.mark.parametrize("packets", [False, True], ids=["single", "packets"])
@pytest.mark.parametrize("watertight", [True, False], ids=["watertight", "fast"])
@pytest.mark.parametrize("scene", ["random", "icosphere", "teapot"])
def test_cast_rays_match_reference(scene, watertight, packets):
    """test_rays' rays (random, aimed, axis-parallel, through the uniform grid's corners, camera
    rays) and rays at the two-level grid's own top and leaf cell faces and corners."""
    c = get_case(scene)
    g = build_grid(c.tris, two_level())
    label = f"{scene} two-level {'watertight' if watertight else 'fast'} packets={packets}"
    hits = cast_rays(g, c.tris, c.o, c.d, watertight=watertight, packets=packets)
    assert_hits_match(hits, c.ref, label, c.o, c.d)
    tris, o, d, ref = hard_case(scene)
    assert_hits_match(cast_rays(g, tris, o, d, watertight=watertight, packets=packets), ref, label + " hard", o, d)


@pytest.mark.parametrize("strategy,top_density,leaf_density,insert", [
    ("serial", 0.01, 0.5, "bbox"),
    ("counting", 0.5, 8.0, "exact"),
    ("thread_grids", 0.0625, 2.0, "bbox"),
    ("sort_middle", 2.0, 1.0, "exact"),
])
@BATCH_CAST
def test_cast_rays_grid_params(strategy, top_density, leaf_density, insert):
    """Top strategy, densities and insertion test change no hit."""
    c = get_case("random")
    g = build_grid(c.tris, two_level(strategy=strategy, top_density=top_density, leaf_density=leaf_density,
                                     insert=insert))
    assert_hits_match(cast_rays(g, c.tris, c.o, c.d), c.ref, f"random {strategy} {top_density}/{leaf_density}",
                      c.o, c.d)


@BATCH_CAST
def test_cast_rays_tmin_tmax_and_any_hit():
    c = get_case("icosphere")
    g = build_grid(c.tris, two_level())
    o, d = c.o[:20_000], c.d[:20_000]
    for tmin, tmax in ((0.3, np.inf), (0.0, 0.7), (1.0, 1.6)):
        ref = R.ref_cast(c.tris, o, d, tmin=tmin, tmax=tmax)
        assert_hits_match(cast_rays(g, c.tris, o, d, tmin=tmin, tmax=tmax), ref, f"tmin={tmin} tmax={tmax}", o, d)
    for packets in (False, True):
        h = cast_rays(g, c.tris, o, d, any_hit=True, packets=packets)
        hit = h.tri >= 0
        assert np.array_equal(hit, c.ref.tri[:20_000] >= 0)
        idx = np.flatnonzero(hit)[:1500]
        own = np.array([R.ref_cast(c.tris[h.tri[i]: h.tri[i] + 1], o[i: i + 1], d[i: i + 1]).t[0] for i in idx])
        np.testing.assert_allclose(h.t[idx], own, rtol=1e-9)


@BATCH_CAST
def test_cast_rays_threads_identical():
    c = get_case("random")
    g = build_grid(c.tris, two_level())
    base = cast_rays(g, c.tris, c.o, c.d, threads=1)
    for n in (2, 3):
        h = cast_rays(g, c.tris, c.o, c.d, threads=n)
        for f in ("t", "tri", "u", "v"):
            assert np.array_equal(getattr(h, f), getattr(base, f)), f"{f} differs between 1 and {n} threads"


@BATCH_CAST
def test_raycaster_two_level():
    """RayCaster over an indexed mesh far from the origin, two-level grid, then an update."""
    v, f = icosphere(3, radius=1.0)
    off = np.array([2e5, -1e5, 5e4])
    v64 = v.astype(np.float64) + off
    rng = np.random.default_rng(4)
    o = off + rng.normal(size=(20_000, 3)) * 2.0
    d = off + rng.normal(size=(20_000, 3)) * 0.5 - o
    caster = RayCaster(v64, f, GridParams(grid="two_level"))
    assert caster.grid.kind == "two_level"
    for k, verts in enumerate((v64, (v64 - off) * np.array([1.3, 0.8, 1.1]) + off + 0.05)):
        if k:
            caster.update(verts)
            assert caster.grid.kind == "two_level"
        # the reference in the caster's frame: its origin is the engine's choice, the triangles are
        # rounded from float64 here
        local = (verts - caster.origin)[f].astype(np.float32)
        ref = R.ref_cast(local, o - caster.origin, d)
        for packets in (True, False):
            assert_hits_match(caster.cast(o, d, packets=packets), ref, f"RayCaster frame {k} packets={packets}", o, d)


@BATCH_CAST
def test_far_from_origin_hits():
    """A scene 1e6 from the origin: the brute force's hits (in the grid's frame, where the grid
    keeps the scene's float32 precision)."""
    c = get_case("icosphere")
    off = 1e6 * np.array([1.0, -0.7, 0.3])
    world = c.tris.astype(np.float64) + off
    g = build_grid(world, two_level())
    assert np.abs(g.origin - off).max() < 10.0
    local = (world - g.origin).astype(np.float32)
    o, d = c.o + off, c.d
    ref = R.ref_cast(local, o - g.origin, d)
    for wt in (True, False):
        assert_hits_match(cast_rays(g, world, o, d, watertight=wt), ref, f"offset 1e6 watertight={wt}", o, d)
    cam = Camera.frame(c.grid.spec.lo + off, c.grid.spec.hi + off, fov=50.0)
    res = render(g, world, cam, RenderParams(width=40, height=30, traversal="cgt"))
    ro, rd = R.ref_camera_rays(cam.eye, cam.target, cam.up, cam.fov, 40, 30)
    diff = R.compare_hits(res.t.reshape(-1).astype(np.float64), res.tri.reshape(-1),
                          R.ref_cast(local, ro - g.origin, rd), t_rtol=1e-6, graze_tol=GRAZE)
    assert len(diff.bad) == 0


# ----------------------------------------------------------------------------------------------
# rendered images


def explained_by_ties(a, b, tris, cam, label):
    """Pixels whose triangle differs between renders a and b: each must be an exact tie (the brute
    force hits both triangles at the pixel's t, which both renders report).  Returns them."""
    H, W = a.tri.shape
    assert np.array_equal(a.t, b.t), f"{label}: t differs at {int((a.t != b.t).sum())} pixels"
    diff = np.flatnonzero((a.tri != b.tri).reshape(-1))
    if len(diff):
        o, d = R.ref_camera_rays(cam.eye, cam.target, cam.up, cam.fov, W, H)
        for p in diff:
            fa, fb = int(a.tri.reshape(-1)[p]), int(b.tri.reshape(-1)[p])
            assert fa >= 0 and fb >= 0, f"{label}: pixel {p} is a hit in one render only"
            ta = R.ref_cast(tris[[fa]], o[p: p + 1], d[p: p + 1]).t[0]
            tb = R.ref_cast(tris[[fb]], o[p: p + 1], d[p: p + 1]).t[0]
            assert abs(ta - tb) <= 1e-9 * max(ta, 1e-9), f"{label}: pixel {p}: triangles {fa}, {fb} at {ta}, {tb}"
    return diff


def scene_light(grid):
    lo, hi = grid.spec.scene_lo, grid.spec.scene_hi
    return tuple(0.5 * (lo + hi) + np.array([0.3, 1.5, 0.8]) * float((hi - lo).max()))


@pytest.mark.parametrize("name", ["teapot", "random"])
def test_render_two_level(name):
    """DDA and CGT, with and without shadows, on 1, 2 and 3 threads: one image, the brute force's
    hits, and the uniform grid's image of the scene (a triangle may differ only at an exact tie,
    where the colour may differ too)."""
    c = get_case(name)
    g = build_grid(c.tris, two_level())
    u = build_grid(c.tris, GridParams())
    cam = c.camera
    W, H = 72, 54
    ref = R.ref_cast(c.tris, *R.ref_camera_rays(cam.eye, cam.target, cam.up, cam.fov, W, H))
    assert ref.hit.mean() > 0.05
    for shadows in (False, True):
        kw = dict(width=W, height=H, shadows=shadows, light=scene_light(g) if shadows else None, tile=8)
        base = render(g, c.tris, cam, RenderParams(traversal="dda", threads=1, **kw))
        diff = R.compare_hits(base.t.reshape(-1).astype(np.float64), base.tri.reshape(-1), ref, t_rtol=1e-6,
                              graze_tol=GRAZE)
        assert len(diff.bad) == 0, f"{name} shadows={shadows}: {len(diff.bad)} pixels differ from the brute force"
        for traversal in ("dda", "cgt"):
            for threads in (1, 2, 3):
                r = render(g, c.tris, cam, RenderParams(traversal=traversal, threads=threads, **kw))
                for f in ("image", "t", "tri"):
                    assert np.array_equal(getattr(r, f), getattr(base, f)), \
                        f"{name} shadows={shadows}: {f} of {traversal} on {threads} threads differs from dda on 1"
        uni = render(u, c.tris, cam, RenderParams(traversal="cgt", **kw))
        ties = explained_by_ties(uni, base, c.tris, cam, f"{name} uniform vs two-level")
        same = np.ones(H * W, bool)
        same[ties] = False
        assert np.array_equal(uni.image.reshape(-1, 4)[same], base.image.reshape(-1, 4)[same]), \
            f"{name} shadows={shadows}: the two-level image differs from the uniform grid's"


_CGT = {}


def cgt_grid(name):
    """test_cgt's scenes (random, icosphere, teapot, a terrain seen at grazing angles, axis-aligned
    cubes, duplicated triangles) on two-level grids, fine leaf grids for some."""
    if name not in _CGT:
        tris = cgt_scene(name)
        fine = name in ("cubes", "terrain", "icosphere")
        _CGT[name] = (tris, build_grid(tris, two_level(top_density=0.02 if fine else 0.0625,
                                                       leaf_density=8.0 if fine else 2.0)))
    return _CGT[name]


@pytest.mark.parametrize("view", ["framed", "inside", "grazing", "axis", "diagonal"])
@pytest.mark.parametrize("name", ["random", "icosphere", "teapot", "terrain", "cubes", "dups"])
def test_cgt_equals_dda(name, view):
    """test_cgt's views (outside, inside with a wide field of view, grazing, exactly axis-aligned,
    diagonal) on two-level grids: CGT renders the DDA's t, triangles and colours bit for bit, with
    shadow rays and without."""
    tris, grid = cgt_grid(name)
    cam = cgt_camera(view, tris)
    a, b = render_both(grid, tris, cam, width=61, height=47, tile=16, shadows=True, light=scene_light(grid))
    assert_same(a, b, tris, cam, f"two-level {name}/{view}")
    a, b = render_both(grid, tris, cam, width=61, height=47, tile=16, shading="normal")
    assert_same(a, b, tris, cam, f"two-level {name}/{view}/normal")


_CAMREF = {}


@pytest.mark.slow  # (every packet shape in both precisions; test_render_two_level renders CGT in the quick run)
@pytest.mark.parametrize("packet", [1, 4, 16, (16, 4), (3, 7), pytest.param((1, 16), marks=pytest.mark.soak),
                                    pytest.param((16, 8), marks=pytest.mark.soak)])
def test_cgt_packet_sizes(packet):
    """Packets of any size and shape on two-level grids: the DDA's buffers in float64, the brute
    force's hits up to float32 rounding in float32 (test_packet_precision's tolerances)."""
    for name in ("teapot", "cubes", "icosphere"):
        tris, grid = cgt_grid(name)
        for view in ("framed", "inside", "axis"):
            cam = cgt_camera(view, tris)
            kw = dict(width=45, height=37, tile=12, shadows=True, light=scene_light(grid))
            a = render(grid, tris, cam, RenderParams(traversal="dda", **kw))
            b = render(grid, tris, cam, RenderParams(traversal="cgt", packet=packet, **kw))
            assert_same(a, b, tris, cam, f"two-level {name}/{view} packet {packet}")
            c = render(grid, tris, cam, RenderParams(traversal="cgt", packet=packet, packet_precision="float32", **kw))
            if (name, view) not in _CAMREF:
                _CAMREF[name, view] = R.ref_cast(tris, *R.ref_camera_rays(cam.eye, cam.target, cam.up, cam.fov, 45, 37))
            check_f32(c, _CAMREF[name, view], f"two-level {name}/{view} packet {packet} float32")


def museum():
    from gridrt.scene import make_scene

    return make_scene(str(data_path("animated/bart/museum/aff/museum5.aff")))


@pytest.mark.slow  # (the split scene's two-level kernels: 40 s of compiles on a cold cache)
def test_pipeline_split_scene():
    """The museum (BART; its static_mask splits it into a static grid built once and a moving one
    rebuilt every frame) through FramePipeline: grid="two_level" renders grid="uniform"'s frames
    (DDA and CGT, shadows), and both parts really are two-level grids."""
    frames = {}
    times = None
    for kind in ("uniform", "two_level"):
        sc = museum()
        times = (0.0, 0.37 * sc.duration, 0.81 * sc.duration)
        out = []
        for traversal in ("dda", "cgt"):
            p = pipeline(sc, kind, traversal)
            out.append([p.step(t) for t in times])
            if kind == "two_level":
                assert p.static_grid.kind == "two_level" and p.grid.kind == "two_level"
                assert p.static_grid.n_triangles + p.grid.n_triangles == sc.n_triangles
        frames[kind] = out
    for i, t in enumerate(times):
        for k in range(2):
            a, b = frames["uniform"][k][i], frames["two_level"][k][i]
            assert np.array_equal(a.t, b.t), f"t={t}: t differs at {int((a.t != b.t).sum())} pixels"
            assert np.array_equal(a.tri, b.tri), f"t={t}: the triangle differs at {int((a.tri != b.tri).sum())} pixels"
            assert np.array_equal(a.image, b.image), f"t={t}: the image differs"
            assert (a.tri >= 0).mean() > 0.5
    # and the hits are the brute force's (over the whole scene, in the pipeline's frame)
    sc = museum()
    p = pipeline(sc, "two_level", "cgt", size=(40, 30))
    fr = p.step(times[1])
    tris = sc.triangles_at(times[1], origin=p.origin).copy()
    cam = p.last_camera.moved(-p.origin)
    H, W = fr.tri.shape
    ref = R.ref_cast(tris, *R.ref_camera_rays(cam.eye, cam.target, cam.up, cam.fov, W, H))
    diff = R.compare_hits(fr.t.reshape(-1).astype(np.float64), fr.tri.reshape(-1), ref, t_rtol=1e-6, graze_tol=GRAZE)
    assert len(diff.bad) == 0, f"{len(diff.bad)} pixels differ from the brute force, first {diff.bad[:5].tolist()}"


def pipeline(scene, kind, traversal, size=(80, 60)):
    """A FramePipeline of the scene with the scene's own camera, shadows on."""
    from gridrt.pipeline import FramePipeline

    return FramePipeline(scene, GridParams(grid=kind),
                         RenderParams(width=size[0], height=size[1], shadows=True, traversal=traversal),
                         follow_camera=True)


# ----------------------------------------------------------------------------------------------
# watertightness (tests/test_watertight.py's probes)


@BATCH_CAST
@pytest.mark.parametrize("top_density,leaf_density", [(0.0625, 2.0), (0.01, 8.0), (1.0, 0.5)])
def test_watertight_icosphere(rng, top_density, leaf_density):
    """Rays at shared vertices and edges of a closed icosphere from in front of all their faces:
    0 misses and 0 hits beyond the target with the watertight test."""
    v, f = icosphere(3, radius=1.0, center=(0.1, -0.2, 0.3))
    n = face_normals(v, f)
    tg, offs, fan = targets_and_fans(rng, v, f, len(v), 3000, 6000)
    centre = v.astype(np.float64).mean(axis=0)
    o, t, ok = origins_in_front(rng, tg, offs, fan, n, centre, np.linalg.norm(v - centre, axis=1).max())
    assert ok.mean() > 0.99
    shoot(v, f, o, t, f"icosphere two-level {top_density}/{leaf_density}",
          two_level(top_density=top_density, leaf_density=leaf_density))


@BATCH_CAST
def test_watertight_jittered_sphere_from_inside(rng):
    v, f = icosphere(3, radius=1.0)
    v = (v * rng.uniform(0.97, 1.03, (len(v), 1))).astype(np.float32)
    tg, _, _ = targets_and_fans(rng, v, f, len(v), 3000, 6000)
    o = rng.uniform(-0.2, 0.2, (len(tg), 3))
    shoot(v, f, o, tg, "jittered icosphere (inside) two-level", two_level(insert="exact"))


def probe_two_level(relpath, n_probes, batch=200_000):
    """Probes at the closed mesh's shared vertices and edges through a two-level grid, DDA, in
    batches; 0 holes with the watertight test, most probes hit at their target."""
    m = ProbeMesh(*load_mesh_arrays(relpath))
    g = build_grid(m.tris, two_level())
    holes = fast = at = done = dropped = seed = 0
    t0 = time.perf_counter()
    while done < n_probes:
        o, d, dist, drop = m.edge_probes(500 + seed, min(batch, n_probes - done + 64))
        o, d, dist = o[: n_probes - done], d[: n_probes - done], dist[: n_probes - done]
        seed += 1
        dropped += drop
        h = cast_rays(g, m.tris, o, d, watertight=True, packets=False)
        holes += int(((h.tri < 0) | (h.t > dist * (1 + REL))).sum())
        at += int((np.abs(h.t - dist) <= REL * dist).sum())
        hf = cast_rays(g, m.tris, o, d, watertight=False, packets=False)
        fast += int(((hf.tri < 0) | (hf.t > dist * (1 + REL))).sum())
        done += len(o)
    print(f"FIGURE two-level watertight {relpath.split('/')[-1]}: {done} probes in {time.perf_counter() - t0:.1f} s; "
          f"watertight: {holes} holes, {at} at their target; fast: {fast} holes ({100 * fast / done:.3f}%)")
    assert holes == 0, f"{relpath}: the watertight test let {holes} probes through a two-level grid"
    assert at > 0.5 * done and dropped < 0.01 * done


def test_watertight_armadillo():
    probe_two_level(ARMADILLO, 40_000)


@pytest.mark.soak
def test_watertight_armadillo_soak():
    probe_two_level(ARMADILLO, int(os.environ.get("GRIDRT_SOAK_RAYS", "10000000")))


def cgt_two_level(m, grid, rng, n_rays, n_row_rays, label, batch=200_000):
    """test_watertight's packet probes (star packets through cgt.trace_packet) and camera rows
    (Renderer, traversal="cgt") on a two-level grid: 0 holes with the watertight test in float64
    and float32; most probes hit at their target; the fast test leaks (the probes are at the
    edges)."""
    pk = rows = {}
    t0 = time.perf_counter()
    while not pk or pk["probes"] < n_rays:
        pk = add_counts(pk, packet_counts(m, grid, rng, min(batch, n_rays - (pk["probes"] if pk else 0)) // 60 + 1))
    while not rows or rows["rays"] < n_row_rays:
        rows = add_counts(rows, row_counts(m, grid, rng, -(-min(batch, n_row_rays - (rows["rays"] if rows else 0))
                                                           // 512)))
    print(f"FIGURE two-level cgt holes {label}: {pk['probes']} packet probes, {rows['rays']} row rays in "
          f"{time.perf_counter() - t0:.1f} s; watertight {int(pk['wt_holes'].sum())} / {rows['wt_holes']} holes, "
          f"float32 {int(pk['wt32_holes'].sum())} / {rows['wt32_holes']} ({pk['wt32_beside']} beside); fast "
          f"{int(pk['fast_holes'].sum())} / {rows['fast_holes']}; rays in split packets {pk['wt_split']} / "
          f"{rows['wt_split']}")
    for key in ("wt", "wt32"):
        assert pk[key + "_holes"].sum() == 0, f"{label}: {key} packet holes by kind {pk[key + '_holes'].tolist()}"
        assert rows[key + "_holes"] == 0, f"{label}: {key} camera-row holes {rows[key + '_holes']}"
        assert pk[key + "_at"] > 0.5 * pk["probes"] and rows[key + "_at"] > 0.5 * rows["rays"]
    assert pk["wt32_beside"] <= 1e-5 * pk["probes"] + 1
    assert pk["fast_holes"].sum() + rows["fast_holes"] > 0, f"{label}: the probes do not find the fast test's leaks"


@pytest.mark.slow  # (the probes' own packet kernels on two-level grids: 25 s of compiles on a cold cache)
def test_cgt_watertight_icosphere(rng):
    m = ProbeMesh(*icosphere(3, radius=1.0, center=(0.1, -0.2, 0.3)))
    cgt_two_level(m, build_grid(m.tris, two_level()), rng, 60_000, 50 * 512, "icosphere")


@pytest.mark.soak
def test_cgt_watertight_armadillo_soak():
    m = ProbeMesh(*load_mesh_arrays(ARMADILLO))
    n = int(os.environ.get("GRIDRT_SOAK_RAYS", "10000000"))
    cgt_two_level(m, build_grid(m.tris, two_level()), np.random.default_rng(2024), n, n, "armadillo")


# ----------------------------------------------------------------------------------------------
# guards


@pytest.mark.parametrize("value", [np.nan, np.inf, -np.inf, 2e31])
def test_refuses_bad_values(value):
    tris = uneven_base(per_cluster=50, huge=2)
    tris[37, 1, 2] = value
    with pytest.raises(InputError, match="NaN|infinity|1e30"):
        build_grid(tris, two_level())
    with pytest.raises(InputError, match="first at triangle 37, vertex 1, axis 2"):
        GridBuilder(two_level(threads=2)).build(tris)


@BATCH_CAST
def test_all_degenerate():
    """build_grid refuses a scene of zero-area triangles; a frame of them (GridBuilder, the
    animation path) gives an empty two-level grid, in which every ray misses."""
    t = uneven_base(per_cluster=40, huge=2)
    t[:, 2] = t[:, 0]
    with pytest.raises(InputError, match="degenerate"):
        build_grid(t, two_level())
    for mode in ("bbox", "exact"):
        p = two_level(insert=mode)
        g = GridBuilder(p).build(t)
        check_two_level(g, t, p, f"degenerate frame {mode}")
        assert g.references == g.top_references == g.n_leaf == 0
        h = cast_rays(g, t, np.full((100, 3), 0.5), np.random.default_rng(1).normal(size=(100, 3)))
        assert (h.tri == -1).all()


def test_huge_and_degenerate_triangles_mixed():
    """Triangles spanning the whole scene (in every top cell, and with bbox insertion in every
    leaf cell), zero-area ones and small ones."""
    rng = np.random.default_rng(9)
    small = (rng.random((600, 1, 3)) + rng.normal(0, 0.01, (600, 3, 3))).astype(np.float32)
    deg = small[:60].copy()
    deg[:, 1] = deg[:, 0]
    tris = np.concatenate([spanning_triangles(12), small, deg])[rng.permutation(672)]
    out = check_both_inserts(tris, two_level(leaf_density=3.0), "spanning + degenerate")
    g = out["bbox"]
    assert (g.leaf_res.prod(axis=1) > 0).all()  # the spanning triangles are in every top cell


def peak_during(call):
    """(exception, peak bytes traced while ``call`` ran)."""
    err = None
    with traced() as m:
        try:
            call()
        except InputError as e:
            err = e
    return err, m.peak


MIB = 1 << 20


@pytest.mark.parametrize("case", ["top cells", "leaf cells", "leaf references"])
def test_memory_budget_before_allocating(case):
    """max_bytes is enforced before the memory is taken: a refused build never allocates more
    than the budget (tracemalloc's peak), says so naming the budget, and the builder builds the
    next frame right."""
    tris = spanning_triangles(60)
    # 60 spanning triangles: every top cell holds all 60; leaf density 1000: about 60,000 leaf
    # cells per top cell (about 1 MiB of offsets and counts), each holding all 60 with bbox insertion
    params = {
        "top cells": (two_level(top_density=2e5, max_cells=1 << 24), 8 * MIB),  # 12M top cells
        "leaf cells": (two_level(top_density=1.0, leaf_density=1e5), 64 * MIB),  # 60 x 6M leaf cells
        "leaf references": (two_level(top_density=1.0, leaf_density=1000.0), 64 * MIB),  # 216M references
    }
    p, budget = params[case]
    small = uneven_base(per_cluster=100, huge=3)
    # (a first build loads the kernels: numba's first call in a process allocates for itself)
    GridBuilder(p.replace(top_density=0.0625, leaf_density=2.0)).build(small)
    builder = GridBuilder(p.replace(max_bytes=budget))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        err, peak = peak_during(lambda: builder.build(tris))
    assert err is not None, f"{case}: a build over the memory budget was not refused"
    msg = str(err)
    assert "memory budget" in msg and "max_bytes" in msg, msg
    assert peak < budget, f"{case}: the refused build allocated {peak / MIB:.1f} MiB, above the budget"
    print(f"{case}: refused after {peak / MIB:.2f} MiB: {msg}")
    good = two_level()
    check_two_level(builder.build(small, good), small, good, f"after the refused {case} build")


def test_leaf_cells_beyond_int32():
    tris = spanning_triangles(60)
    with pytest.raises(InputError, match="int32"):
        build_grid(tris, two_level(top_density=1.0, leaf_density=1e12))


# ----------------------------------------------------------------------------------------------
# one builder, frame after frame


@BATCH_CAST
def test_builder_switches_kinds_over_frames():
    """One GridBuilder over an animated scene (the marbles, moving every frame), with the grid
    kind, insertion test and densities changing, and a frame of another size: every frame's
    contents equal the reference; a grid of an earlier build is refused as stale."""
    from gridrt.scene import make_scene

    sc = make_scene("marbles", count=1500)
    other = uneven_base(per_cluster=300, huge=4)
    plan = [
        (0.0, two_level()),
        (0.2, GridParams()),
        (0.4, two_level(insert="exact")),
        (None, two_level(top_density=0.2, leaf_density=5.0)),
        (0.6, GridParams(insert="exact", density=2.0)),
        (0.8, two_level()),
        (1.0, two_level(strategy="thread_grids", leaf_density=1.0)),
        (1.2, GridParams(grid="auto")),
        (None, GridParams(grid="auto")),
        (1.4, GridParams(grid="auto", insert="exact")),
        (1.6, two_level()),
    ]
    b = GridBuilder()
    old = []
    for k, (t, p) in enumerate(plan):
        tris = np.ascontiguousarray(other if t is None else sc.triangles_at(t).copy())
        g = b.build(tris, p)
        label = f"frame {k} ({p.grid} -> {g.kind}, {p.insert})"
        assert g.kind == p.grid or p.grid == "auto", label
        check_grid(g, tris, p, label)
        g.check_current()
        for og, otris in old:
            with pytest.raises(InputError, match="stale"):
                og.check_current()
            with pytest.raises(InputError, match="stale"):
                cast_rays(og, otris, np.zeros((1, 3)), np.ones((1, 3)))
        old.append((g, tris))
    # the newest grid traces the newest frame as the brute force does
    rng = np.random.default_rng(3)
    lo, hi = tris.reshape(-1, 3).min(0), tris.reshape(-1, 3).max(0)
    o = rng.uniform(lo, hi, (5000, 3))
    d = rng.normal(size=(5000, 3))
    assert_hits_match(cast_rays(g, tris, o, d), R.ref_cast(tris, o, d), "last frame", o, d)
