"""Grid contents against the brute-force membership reference (tests/reference.py).

The engine chooses the grid geometry (``grid.spec``); given that geometry, the set of
(cell, triangle) pairs is fully defined by the membership rules of ``engine/grid/layout.py``
(bounding box grown by INSERT_EPS cells; exact = also no separating axis).  The reference
recomputes that set in float64 by brute force, so every difference is an engine bug, except
pairs whose decision is a floating-point tie (reported by the reference as ``ambiguous``).

Also checked: the geometry itself (every vertex strictly inside, cell * dims spans the bounds,
cells ~ density * triangles, never above max_cells), the CSR layout, and the macro-cell flags.
"""

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import reference as R
from conftest import ARMADILLO, TEAPOT, load_tris, random_scene
from gridrt.grid import GridBuilder, GridCapWarning, GridParams, build_grid
from helpers.grids import _check_pairs, check_layout, check_macro, check_spec

# ----------------------------------------------------------------------------------------------
# the reference itself, on hand-computed cases


UNIT = dict(lo=np.zeros(3), cell=np.ones(3), dims=np.array([4, 4, 4]))


def test_reference_bbox_hand_computed():
    # bbox [0.2, 1.6]^2 x {0.5}: cells i, j in {0, 1}, k = 0
    tri = np.array([[[0.2, 0.2, 0.5], [1.6, 0.2, 0.5], [0.2, 1.6, 0.5]]], np.float32)
    r = R.ref_pairs_bbox(tri, **UNIT)
    assert r.pairs.tolist() == [[0, 0], [1, 0], [4, 0], [5, 0]]
    assert len(r.ambiguous) == 0


def test_reference_exact_hand_computed():
    # the hypotenuse x + y = 1.8 passes below cell (1, 1, 0), whose nearest corner has x + y = 2
    tri = np.array([[[0.2, 0.2, 0.5], [1.6, 0.2, 0.5], [0.2, 1.6, 0.5]]], np.float32)
    r = R.ref_pairs_exact(tri, **UNIT)
    assert r.pairs.tolist() == [[0, 0], [1, 0], [4, 0]]
    # with the hypotenuse at x + y = 2.4 the triangle enters cell (1, 1, 0) as well
    tri = np.array([[[0.2, 0.2, 0.5], [2.2, 0.2, 0.5], [0.2, 2.2, 0.5]]], np.float32)
    assert [5, 0] in R.ref_pairs_exact(tri, **UNIT).pairs.tolist()
    # a triangle lying in the face z = 1 belongs to the cells on both sides (grown boxes)
    tri = np.array([[[0.2, 0.2, 1.0], [0.6, 0.2, 1.0], [0.2, 0.6, 1.0]]], np.float32)
    assert R.ref_pairs_exact(tri, **UNIT).pairs.tolist() == [[0, 0], [16, 0]]
    # a tilted triangle in the plane y + z = 2.2 whose bounding box [0.1, 1.9] x [0.3, 1.9] x
    # [0.3, 1.9] covers the 8 cells {0, 1}^3.  It misses the cells with j = 0, k = 0 (there
    # y + z <= 2) and cell (1, 1, 0) (there y >= 1.2, where the triangle has x <= 0.8875); it
    # passes through (1.05, 1.0, 1.2) in cell (1, 1, 1) and (0.5, 1.5, 0.7) in cell (0, 1, 0)
    tri = np.array([[[0.1, 0.3, 1.9], [1.9, 0.3, 1.9], [0.1, 1.9, 0.3]]], np.float32)
    bb = R.pairs_to_set(R.ref_pairs_bbox(tri, **UNIT).pairs)
    ex = R.pairs_to_set(R.ref_pairs_exact(tri, **UNIT).pairs)
    assert len(bb) == 8 and bb - ex == {(0, 0), (1, 0), (5, 0)}


def test_reference_growth_and_ties():
    # a box that ends 0.5e-5 cells before a cell face is grown into the next cell (INSERT_EPS)
    tri = np.array([[[0.2, 0.2, 0.5], [0.999995, 0.3, 0.5], [0.2, 0.6, 0.5]]], np.float32)
    assert R.ref_pairs_bbox(tri, **UNIT).pairs.tolist() == [[0, 0], [1, 0]]
    tri = np.array([[[0.2, 0.2, 0.5], [0.99998, 0.3, 0.5], [0.2, 0.6, 0.5]]], np.float32)
    assert R.ref_pairs_bbox(tri, **UNIT).pairs.tolist() == [[0, 0]]
    # grown box ending exactly on the face of cell 1 (lo chosen so): a tie, reported ambiguous
    tri = np.array([[[0.3, 0.2, 0.5], [0.7, 0.3, 0.5], [0.3, 0.6, 0.5]]], np.float32)
    xmax = np.float64(tri[0, 1, 0])
    lo = np.array([xmax + 1e-5 - 1.0, 0.0, 0.0])
    r = R.ref_pairs_bbox(tri, lo, np.ones(3), np.array([4, 4, 4]))
    assert [1, 0] in r.ambiguous.tolist()
    assert [0, 0] in r.pairs.tolist() and [0, 0] not in r.ambiguous.tolist()


@pytest.mark.parametrize("mode", ["bbox", "exact"])
def test_reference_candidates_equal_all_cells(rng, mode):
    """The candidate-range enumeration loses nothing against testing every cell."""
    fn = R.ref_pairs_bbox if mode == "bbox" else R.ref_pairs_exact
    for trial in range(6):
        tris = random_scene(rng, 40, flat_axis=(trial % 4 if trial % 4 < 3 else None), degen_frac=0.1)
        lo = tris.reshape(-1, 3).min(0).astype(np.float64) - 0.01
        hi = tris.reshape(-1, 3).max(0).astype(np.float64) + 0.01
        dims = rng.integers(1, 7, 3)
        cell = (hi - lo) / dims
        a = fn(tris, lo, cell, dims)
        b = fn(tris, lo, cell, dims, all_cells=True)
        assert np.array_equal(a.pairs, b.pairs)
        assert np.array_equal(a.ambiguous, b.ambiguous)


# ----------------------------------------------------------------------------------------------
# engine vs reference


def check_against_reference(tris, params):
    """Build bbox and exact grids and compare both with the reference; returns the two grids."""
    grids = {}
    for mode, fn in (("bbox", R.ref_pairs_bbox), ("exact", R.ref_pairs_exact)):
        p = params.replace(insert=mode)
        g = build_grid(tris, p)
        # build_grid grids a scene lying farther from the origin than its size in a frame centred on
        # it (g.origin): the reference is taken on the triangles in that frame, as the grid saw them
        local = tris if not g.origin.any() else (tris.astype(np.float64) - g.origin).astype(np.float32)
        check_spec(g, local, p)
        pairs = check_layout(g)
        s = g.spec
        ref = fn(local, s.lo, s.cell, s.dims)
        missing, extra = R.compare_pairs(pairs, ref)
        assert not missing and not extra, (
            f"{mode} insert: {len(missing)} (cell, tri) pairs missing, {len(extra)} extra; "
            f"first missing {missing[:5]}, first extra {extra[:5]}; dims {s.dims.tolist()}"
        )
        check_macro(g, pairs)
        grids[mode] = (g, pairs)
    gb, pb = grids["bbox"]
    ge, pe = grids["exact"]
    assert np.array_equal(gb.spec.dims, ge.spec.dims) and np.array_equal(gb.spec.lo, ge.spec.lo)
    assert R.pairs_to_set(pe) <= R.pairs_to_set(pb), "exact insertion kept a pair that bbox insertion lacks"
    return gb, ge


@settings(
    max_examples=100,
    deadline=None,
    derandomize=True,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)
@given(
    seed=st.integers(0, 2**32 - 1),
    n=st.integers(1, 300),
    size_mode=st.sampled_from(["mixed", "small", "medium", "huge", "sliver"]),
    flat_axis=st.sampled_from([None, None, 0, 1, 2]),
    dup_frac=st.sampled_from([0.0, 0.1, 0.5]),
    degen_frac=st.sampled_from([0.0, 0.1, 0.5]),
    density=st.floats(0.5, 20.0),
    macro=st.integers(1, 8),
    scale=st.sampled_from([1.0, 1.0, 1e-3, 1e4]),
    offset=st.sampled_from([0.0, 0.0, 1e3, -3e4]),
)
def test_grid_equals_reference_random(seed, n, size_mode, flat_axis, dup_frac, degen_frac, density, macro, scale, offset):
    tris = random_scene(np.random.default_rng(seed), n, size_mode, flat_axis, dup_frac, degen_frac)
    tris = (tris.astype(np.float64) * scale + offset).astype(np.float32)
    t = R.tris64(tris)
    if not np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]).any():
        return  # float32 rounding collapsed every triangle (a sliver far from the origin)
    check_against_reference(tris, GridParams(density=density, macro=macro))


@pytest.mark.parametrize("density,macro", [(0.5, 1), (4.0, 4), (20.0, 8)])
def test_grid_single_triangle(density, macro):
    tris = np.array([[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 1.0]]], np.float32)
    check_against_reference(tris, GridParams(density=density, macro=macro))


def test_grid_axis_aligned_on_cell_faces():
    """Axis-aligned quads on integer coordinates: boxes touching faces, duplicated coordinates."""
    quads = []
    for z in range(5):
        quads += [[[0, 0, z], [4, 0, z], [4, 4, z]], [[0, 0, z], [4, 4, z], [0, 4, z]]]
    for x in range(5):
        quads += [[[x, 0, 0], [x, 4, 0], [x, 4, 4]]]
    check_against_reference(np.array(quads, np.float32), GridParams(density=8.0, macro=2))


def test_grid_growth_near_cell_faces():
    """Boxes ending a hair (0.5e-5 cells) before a cell face are grown into the next cell; boxes
    3e-5 cells away are not.  Two triangles fix the bounds to [0, 1]^3 so the probes' positions
    do not change the grid geometry."""
    frame = [[[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[1, 1, 1], [0, 1, 1], [1, 0, 1]]]
    probe = np.array([[0.0, 0.0, 0.0], [-0.02, 0.01, 0.01], [-0.01, 0.02, 0.015]])
    params = GridParams(density=216 / 6, macro=2)
    spec = build_grid(np.array(frame + [probe + 0.5] * 4, np.float32), params).spec
    assert spec.dims.tolist() == [6, 6, 6]
    face = spec.lo[0] + 3 * spec.cell[0]
    c = spec.cell[0]
    mid_yz = spec.lo[1:] + 2.5 * spec.cell[1:]
    probes, expect = [], []
    for xmax, cells in ((face - 0.5e-5 * c, {2, 3}), (face - 3e-5 * c, {2})):
        probes.append(probe + [xmax, *mid_yz])
        expect.append(cells)
    for xmin, cells in ((face + 0.5e-5 * c, {2, 3}), (face + 3e-5 * c, {3})):
        probes.append(probe + [xmin + 0.02, *mid_yz])
        expect.append(cells)
    tris = np.array(frame + probes, np.float32)
    for mode in ("bbox", "exact"):
        g = build_grid(tris, params.replace(insert=mode))
        assert np.array_equal(g.spec.lo, spec.lo) and np.array_equal(g.spec.dims, spec.dims)
        pairs = g.pairs()
        for p, cells in enumerate(expect):
            got = pairs[pairs[:, 1] == 2 + p, 0]
            assert set((got % 6).tolist()) == cells, (mode, p, got)
            assert set((got // 6 % 6).tolist()) == {2} and set((got // 36).tolist()) == {2}
    check_against_reference(tris, params)


def test_grid_max_cells_cap(rng):
    tris = random_scene(rng, 300, "small")
    p = GridParams(density=20.0, macro=2, max_cells=512)
    with pytest.warns(GridCapWarning, match="max_cells=512"):
        gb, _ = check_against_reference(tris, p)
    assert gb.spec.n_cells <= 512
    assert gb.spec.capped


@pytest.mark.parametrize("relpath,density,macro", [(TEAPOT, 4.0, 4), (TEAPOT, 1.0, 2),
                                                     pytest.param(ARMADILLO, 4.0, 4, marks=pytest.mark.slow)])
def test_grid_equals_reference_real_mesh(relpath, density, macro):
    tris = load_tris(relpath)
    check_against_reference(tris, GridParams(density=density, macro=macro))


# ----------------------------------------------------------------------------------------------
# every strategy, every thread count, and buffer reuse from frame to frame


def _strategy_names():
    from gridrt.grid import names

    return names()


@pytest.mark.parametrize("threads", [1, 3])
@pytest.mark.parametrize("strategy", _strategy_names())
def test_every_strategy_equals_reference(strategy, threads):
    scenes = [
        random_scene(np.random.default_rng(21), 300, "mixed", None, 0.1, 0.1),
        random_scene(np.random.default_rng(22), 120, "huge", 1, 0.0, 0.0),
    ]
    for i, tris in enumerate(scenes):
        for mode in ("bbox", "exact"):
            p = GridParams(strategy=strategy, threads=threads, density=5.0, macro=3, insert=mode)
            g = build_grid(tris, p)
            if strategy == "thread_grids":
                assert g.layers == threads
            _check_pairs(g, tris, mode, f"{strategy} threads={threads} scene {i} {mode}")


@pytest.mark.parametrize("strategy", _strategy_names())
def test_builder_reuse_across_frames(strategy):
    """One GridBuilder over a sequence of frames (moving triangles, a changing triangle count,
    so the grid shape changes too): every frame's contents equal the reference, i.e. the clear
    stage (only cells of previously full macro cells) leaves nothing behind."""
    rng = np.random.default_rng(5)
    base = random_scene(rng, 200, "mixed")
    frames = [
        base,
        base + np.float32(0.3),  # everything moves: same shape, new cells
        base[:50] * np.float32(2.0),  # fewer triangles, bigger bounds
        random_scene(rng, 260, "small"),  # more triangles than ever
        base,
    ]
    for mode in ("bbox", "exact"):
        builder = GridBuilder(GridParams(strategy=strategy, threads=2, density=4.0, macro=2, insert=mode))
        for k, tris in enumerate(frames):
            tris = np.ascontiguousarray(tris, dtype=np.float32)
            g = builder.build(tris)
            _check_pairs(g, tris, mode, f"{strategy} frame {k} {mode}")


# ---------------------------------------------------------------------------------------------
# the scene-bounds pass (SIMD lanes) against numpy, including the bad-value flag


@pytest.mark.parametrize("F", [1, 2, 5, 16, 17, 33, 1000, 70_001])
@pytest.mark.parametrize("chunks", [1, 2, 3, 7])
def test_scene_bounds_equal_numpy(F, chunks):
    """Per-chunk bounds reduce to numpy's min/max; every chunk count (including chunks with no
    whole 48-lane row) and sizes with a tail of leftover coordinates.  A NaN, an infinity or a
    coordinate beyond 1e30 at the first, a middle, the last-full-row and the very last position
    sets the bad flag."""
    from gridrt.grid import common

    rng = np.random.default_rng(F * 31 + chunks)
    t = (rng.standard_normal((F, 3, 3)) * 10.0 ** rng.integers(-3, 4, size=(F, 1, 3))).astype(np.float32)
    t += np.float32(rng.uniform(-1e4, 1e4))

    def run(x):
        out = np.empty((chunks, 7))
        if chunks == 1:
            common.scene_bounds_serial(x, out)
        else:
            common.scene_bounds(x, chunks, out)
        return out

    out = run(t)
    flat = t.reshape(-1, 3)
    assert np.array_equal(out[:, 0:3].min(axis=0), flat.min(axis=0).astype(np.float64))
    assert np.array_equal(out[:, 3:6].max(axis=0), flat.max(axis=0).astype(np.float64))
    assert not out[:, 6].any()
    n = t.size
    positions = sorted({0, n // 2, max(0, n // 48 * 48 - 1), n - 1})
    for value in (np.nan, np.inf, -np.inf, 2e30, -3e30):
        for pos in positions:
            u = t.copy().reshape(-1)
            u[pos] = value
            assert run(u.reshape(F, 3, 3))[:, 6].any(), (value, pos)


@pytest.mark.parametrize("F", [1, 15, 16, 17, 1001])
@pytest.mark.parametrize("threads", [1, 2, 3, 16])
def test_cell_ranges_equal_scalar_definition(F, threads):
    """The vectorized cell-range pass (16-triangle blocks, clamp-then-truncate) equals the range's
    written definition, computed here one triangle at a time in numpy float64: floor((x - lo) *
    inv_cell -/+ EPS) of the bounding box, clamped to the grid, and the empty range
    (0, 0, 0, -1, -1, -1) for a triangle of exactly zero area.  Random triangles, degenerate ones
    (repeated and collinear vertices), ones outside the grid on both sides (clamped), and vertices
    exactly on cell faces, where the EPS growth decides."""
    from gridrt.grid.layout import INSERT_EPS, GridBox
    from gridrt.grid.strategies.shared import cell_ranges

    def scalar_range(tri):
        v = tri.astype(np.float64)
        if not np.cross(v[1] - v[0], v[2] - v[0]).any():
            return [0, 0, 0, -1, -1, -1]
        r0 = np.floor((v.min(axis=0) - lo) * inv_cell - INSERT_EPS).astype(np.int64)
        r1 = np.floor((v.max(axis=0) - lo) * inv_cell + INSERT_EPS).astype(np.int64)
        return list(np.clip(r0, 0, dims - 1)) + list(np.clip(r1, 0, dims - 1))

    rng = np.random.default_rng(F * 7 + threads)
    lo = np.array([-1.0, -2.0, 0.5])
    dims = np.array([7, 5, 9], np.int64)
    cell = np.array([0.25, 0.5, 0.125])
    inv_cell = 1.0 / cell
    t = (lo + rng.uniform(-0.3, 1.3, size=(F, 3, 3)) * dims * cell).astype(np.float32)
    on_face = rng.random(F) < 0.2
    t[on_face] = (lo + rng.integers(0, 10, size=(int(on_face.sum()), 3, 3)) * cell).astype(np.float32)
    t[::5, 1] = t[::5, 0]  # repeated vertex
    t[::7, 2] = 2 * t[::7, 1] - t[::7, 0]  # collinear (exact in float32 for these values or not: both paths agree)
    out = np.full((F, 6), 99, np.int32)
    cell_ranges(t, GridBox(lo, cell, inv_cell, dims, 1, dims), threads, out)
    want = np.array([scalar_range(t[f]) for f in range(F)], np.int32)
    assert np.array_equal(out, want)
    assert (want[::5, 3] == -1).all()  # the repeated-vertex triangles really are degenerate
