"""One-shot builds: build_grid and RayCaster validate and convert their input in
one or two passes (gridrt.grid.common.bounds_f64, to_frame, first_nondegenerate) instead of a dozen
numpy passes.  Checked against numpy references written here:

* the passes: bounds, the bad-value flag at every position class (first, in a full row of lanes,
  in the tail), float32 conversion, the move into a frame (float64 difference, then float32), the
  first triangle with area (exact cross product) including all-degenerate sets;
* build_grid on float32, float64 and int32 input near and far from the origin gives the grid that
  a reused builder gives for the triangles moved into the frame chosen by the rule written out
  here (the bounds' centre when it lies farther than their extent, else 0), array for array;
* RayCaster's vertices, triangles, faces and origin equal numpy's float32(v - centre)[faces], and
  so do an update's; its hits equal the float64 brute force over those triangles.
"""

import numpy as np
import pytest

import reference as R
from conftest import icosphere
from gridrt import GridBuilder, GridParams, RayCaster, build_grid
from gridrt.errors import InputError
from gridrt.grid import common


def _bounds_ref(a):
    p = np.asarray(a, np.float64).reshape(-1, 3)
    return p.min(axis=0), p.max(axis=0)


@pytest.mark.parametrize("n", [1, 5, 16, 17, 1000])
def test_bounds_f64_and_float32_copy(rng, n):
    t = rng.normal(0, 10, (n, 3, 3))
    bb = np.empty((1, 7))
    as32 = np.empty(t.shape, np.float32)
    common.bounds_f64(t, bb, as32)
    lo, hi = _bounds_ref(t)
    np.testing.assert_array_equal(bb[0, :3], lo)
    np.testing.assert_array_equal(bb[0, 3:6], hi)
    assert bb[0, 6] == 0.0
    np.testing.assert_array_equal(as32, t.astype(np.float32))
    for pos in sorted({0, t.size // 2, t.size - 1}):
        for bad in (np.nan, np.inf, -np.inf, 1e31, -1e300):
            u = t.copy()
            u.reshape(-1)[pos] = bad
            common.bounds_f64(u, bb, as32)
            assert bb[0, 6] == 1.0, (pos, bad)


def test_to_frame_is_the_float64_difference_rounded(rng):
    t = rng.normal(0, 1, (300, 3)) + 1e6
    o = np.array([1e6 + 0.25, 1e6 - 3.5, 1e6 + 1.0 / 3.0])
    out = np.empty(t.shape, np.float32)
    common.to_frame(t, float(o[0]), float(o[1]), float(o[2]), out)
    np.testing.assert_array_equal(out, (t - o).astype(np.float32))
    t32 = t.astype(np.float32)
    common.to_frame(t32, float(o[0]), float(o[1]), float(o[2]), out)
    np.testing.assert_array_equal(out, (t32.astype(np.float64) - o).astype(np.float32))


def test_first_nondegenerate(rng):
    good = rng.normal(0, 1, (50, 3, 3)).astype(np.float32)
    line = np.zeros((50, 3, 3), np.float32)
    line[:, 1, 0] = 1.0
    line[:, 2, 0] = 2.0  # collinear along x, exactly
    point = np.repeat(good[:, :1], 3, axis=1)  # three equal vertices
    for k in (0, 7, 49):
        t = np.concatenate([line[:k], good[k:k + 1], point[k + 1:]])
        a = t.astype(np.float64)
        cross = np.cross(a[:, 1] - a[:, 0], a[:, 2] - a[:, 0])
        ref = int(np.flatnonzero((cross != 0).any(axis=1))[0])
        assert common.first_nondegenerate(t) == ref == k
    assert common.first_nondegenerate(np.concatenate([line, point])) == -1


def _frame_rule(t64):
    lo, hi = _bounds_ref(t64)
    c = 0.5 * (lo + hi)
    return c if np.abs(c).max() > (hi - lo).max() else np.zeros(3)


def _same_grid(a, b):
    np.testing.assert_array_equal(a.cell_start, b.cell_start)
    assert a.references == b.references
    np.testing.assert_array_equal(a.tri_ids[:a.references], b.tri_ids[:b.references])
    np.testing.assert_array_equal(a.spec.dims, b.spec.dims)
    np.testing.assert_array_equal(a.spec.lo, b.spec.lo)
    np.testing.assert_array_equal(a.spec.hi, b.spec.hi)


#: (dtype, offset): int32 only where it holds the coordinates (integral, within 2^31)
CASES = [(d, o) for d in (np.float32, np.float64) for o in (0.0, 0.3, 1e6, -1e9)] + [(np.int32, 0.0), (np.int32, 1e6)]


@pytest.mark.parametrize("dtype,offset", CASES)
def test_build_grid_equals_a_reused_build_in_the_ruled_frame(dtype, offset):
    v, f = icosphere(3, radius=1000.0)
    t = (np.round(v.astype(np.float64)[f]) + offset).astype(dtype)
    tw = t.astype(np.float64)
    origin = _frame_rule(tw)
    local = (tw - origin).astype(np.float32)
    g = build_grid(t, GridParams(density=2.0))
    np.testing.assert_array_equal(g.origin, origin)
    _same_grid(g, GridBuilder(GridParams(density=2.0)).build(local))


def test_build_grid_refuses_all_degenerate_in_its_frame():
    t = np.zeros((4, 3, 3))
    t[:, 1, 0] = 1.0
    t[:, 2, 0] = 2.0
    with pytest.raises(InputError, match="all 4 triangles are degenerate"):
        build_grid(t + 5.0)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_raycaster_mesh_and_update_equal_numpy(dtype, rng):
    v, f = icosphere(3, radius=2.0)
    v = (v.astype(np.float64) + [3e4, -2.0, 7.0]).astype(dtype)
    c = RayCaster(v, f)
    v64 = v.astype(np.float64)
    centre = 0.5 * (v64.min(axis=0) + v64.max(axis=0))
    ref_v = (v64 - centre).astype(np.float32)
    np.testing.assert_array_equal(c.origin, centre)
    np.testing.assert_array_equal(c.vertices, ref_v)
    np.testing.assert_array_equal(c.triangles, ref_v[f])
    assert c.faces.dtype == np.int32 and np.array_equal(c.faces, f)
    moved = (v64 * 1.5 + [1.0, 2.0, 3.0]).astype(dtype)
    c.update(moved)
    m64 = moved.astype(np.float64)
    centre = 0.5 * (m64.min(axis=0) + m64.max(axis=0))
    np.testing.assert_array_equal(c.triangles, (m64 - centre).astype(np.float32)[f])
    o = centre + rng.normal(0, 1, (400, 3)) * 8.0
    d = centre + rng.normal(0, 1, (400, 3)) - o
    hits = c.cast(o, d)
    # the reference in the caster's frame (its float32 triangles are exact there; tests/reference.py
    # rounds world coordinates to float32, which 3e4 from the origin would blur)
    diff = R.compare_hits(hits.t, hits.tri, R.ref_cast(c.triangles, o - c.origin, d))
    assert len(diff.bad) == 0 and (hits.tri >= 0).sum() > 100


def test_raycaster_unusual_input_still_takes_the_checks():
    """Integral float faces are accepted and bad indices are named (the slow checks)."""
    v, f = icosphere(1)
    c = RayCaster(v, f.astype(np.float64))
    assert np.array_equal(c.faces, f)
    with pytest.raises(InputError, match="out of range"):
        RayCaster(v, f + len(v))
    with pytest.raises(InputError, match="all .* degenerate"):
        RayCaster(np.zeros((3, 3)), [[0, 1, 2]])
