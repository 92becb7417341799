"""Checks of a grid's layout, macro-cell flags and (cell, triangle) pairs against the brute-force reference."""

import numpy as np
import pytest

import reference as R

#: the grid kinds of a test that casts rays through a grid (cast_rays, RayCaster): the two-level
#: case in the slow run only, as the two-level grid's batch cast kernel takes about 40 s to compile
#: for those tests alone (test_two_level.py's casts are marked alike)
CAST_KINDS = ["uniform", pytest.param("two_level", marks=pytest.mark.slow)]


def check_spec(grid, tris, params):
    """Grid geometry: bounds enclose every vertex strictly, cells tile the bounds, resolution."""
    s = grid.spec
    v = tris.reshape(-1, 3).astype(np.float64)
    assert s.dims.dtype.kind == "i" and (s.dims >= 1).all()
    assert (v > s.lo).all() and (v < s.hi).all(), "a vertex is not strictly inside the grid bounds"
    np.testing.assert_allclose(s.lo + s.cell * s.dims, s.hi, rtol=1e-12, atol=1e-12 * np.abs(s.hi).max())
    n_cells = int(np.prod(s.dims))
    assert n_cells <= params.max_cells
    target = params.density * len(tris)
    if not s.capped:
        # cells ~ density * triangles: each axis is rounded, so allow a factor 2 when every axis
        # has a few cells, and only an upper bound for grids with 1-3 cells along some axis
        assert n_cells <= max(8.0, 2.0 * target) * (1 + 1e-9), (n_cells, target)
        ext = v.max(axis=0) - v.min(axis=0)
        flat = ext <= 1e-9 * ext.max()
        if ((s.dims >= 4) | flat).all():
            assert n_cells >= target / 2.0, (n_cells, target)
            # shaped: cells are about cubes along the axes that carry the resolution
            c = s.cell[~flat]
            assert c.max() <= 1.5 * c.min(), f"cells far from cubical: {s.cell} for dims {s.dims}"
        assert (s.dims[flat] == 1).all(), "an axis of zero extent got more than one cell"
    macro = params.macro
    assert s.macro == macro
    assert np.array_equal(s.mdims, -(-s.dims // macro))


def check_layout(grid):
    """CSR offsets are monotone, span tri_ids, and hold no duplicate (cell, tri) pair."""
    cs = grid.cell_start.astype(np.int64)
    C = grid.spec.n_cells
    assert cs.shape == (grid.layers, C + 1)
    assert (np.diff(cs, axis=1) >= 0).all()
    total = int((cs[:, -1] - cs[:, 0]).sum())
    assert total == grid.references
    assert grid.stats["references"] == grid.references
    assert grid.stats["cells"] == C
    pairs = grid.pairs()
    assert len(pairs) == grid.references, "a triangle is stored twice in one cell"
    if len(pairs):
        assert pairs[:, 1].min() >= 0 and pairs[:, 1].max() < grid.n_triangles
    return pairs


def check_macro(grid, pairs):
    flags = R.ref_macro_flags(pairs, grid.spec.dims, grid.spec.macro)
    got = np.asarray(grid.macro_full[: grid.spec.n_macro]).astype(bool)
    bad = np.flatnonzero(got != flags)
    assert len(bad) == 0, f"macro flags differ from the occupancy of their cells at macro cells {bad[:10]}"


def _check_pairs(grid, tris, mode, label):
    s = grid.spec
    fn = R.ref_pairs_bbox if mode == "bbox" else R.ref_pairs_exact
    pairs = check_layout(grid)
    missing, extra = R.compare_pairs(pairs, fn(tris, s.lo, s.cell, s.dims))
    assert not missing and not extra, (
        f"{label}: {len(missing)} pairs missing, {len(extra)} extra; first missing {missing[:5]}, "
        f"first extra {extra[:5]}"
    )
    check_macro(grid, pairs)
