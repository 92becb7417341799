"""The tests' ray/triangle reference: ``ref_cast`` (a numba loop) gives what ``ref_cast_numpy``
(the same Moller-Trumbore formulas vectorised in numpy) gives, and both give the analytic hits of
hand-made cases.

The two sum the dot products in different orders (numpy's einsum against a plain loop), so their
floats may differ in the last bits: t, u, v, t2, edge and graze are compared within 1e-12 of the
coordinate scale, the triangle ids exactly (no ray of these sets lies within 1e-12 of a tie or an
edge, which the sets are drawn to avoid and the test checks).
"""

from dataclasses import fields

import numpy as np
import pytest
from reference import RefHits, ref_cast, ref_cast_numpy

FIELDS = ("t", "u", "v", "t2", "edge", "graze")


def assert_same(a, b, scale=1.0):
    assert np.array_equal(a.tri, b.tri)
    for name in FIELDS:
        x, y = getattr(a, name), getattr(b, name)
        assert np.array_equal(np.isnan(x), np.isnan(y)), name
        assert np.array_equal(np.isinf(x) & (x > 0), np.isinf(y) & (y > 0)), name
        assert np.array_equal(np.isinf(x) & (x < 0), np.isinf(y) & (y < 0)), name
        fin = np.isfinite(x)
        np.testing.assert_allclose(x[fin], y[fin], rtol=1e-12, atol=1e-12 * scale, err_msg=name)


def clear_of_ties(h, eps=1e-9):
    """Rays whose nearest hit is neither within eps of a second one nor of an edge."""
    with np.errstate(invalid="ignore"):
        return ~((h.tri >= 0) & ((np.abs(h.t2 - h.t) <= eps * np.maximum(1.0, np.abs(h.t))) | (h.edge <= eps)))


@pytest.mark.parametrize("seed", [0, 1])
def test_random_triangles_and_rays(seed):
    rng = np.random.default_rng(seed)
    F, N = 400, 2000
    tris = (rng.random((F, 3, 3)) * 4 - 2).astype(np.float32)
    o = rng.random((N, 3)) * 6 - 3
    d = rng.normal(size=(N, 3))
    for tmin, tmax in [(0.0, np.inf), (0.5, 2.0), (rng.random(N), 1.0 + 3 * rng.random(N))]:
        ref = ref_cast_numpy(tris, o, d, tmin, tmax)
        keep = clear_of_ties(ref)
        assert keep.mean() > 0.99 and (ref.tri[keep] >= 0).sum() > 200
        got = ref_cast(tris, o[keep], d[keep], np.broadcast_to(tmin, (N,))[keep], np.broadcast_to(tmax, (N,))[keep])
        # (each ray's reference hit depends on that ray alone: the kept rays' rows of ref)
        assert_same(got, RefHits(**{f.name: getattr(ref, f.name)[keep] for f in fields(RefHits)}), 4.0)


def test_degenerate_duplicated_and_huge_triangles():
    """Zero-area triangles (det = 0), a triangle twice (a tie: the lower id, t2 = t), a needle,
    and coordinates near 1e30 whose products overflow to inf and NaN."""
    rng = np.random.default_rng(3)
    base = (rng.random((50, 3, 3)) * 2 - 1).astype(np.float32)
    flat = np.repeat(rng.random((20, 1, 3)), 3, axis=1).astype(np.float32)  # three equal vertices
    line = np.stack([np.zeros((20, 3)), np.ones((20, 3)), 2 * np.ones((20, 3))], axis=1).astype(np.float32)
    huge = (rng.random((10, 3, 3)) * 2e30 - 1e30).astype(np.float32)
    tris = np.concatenate([base, base[:10], flat, line, huge])
    o = rng.random((3000, 3)) * 4 - 2
    d = rng.normal(size=(3000, 3))
    got = ref_cast(tris, o, d)
    want = ref_cast_numpy(tris, o, d)
    assert_same(got, want, 1e30)
    dup = got.tri[(got.tri >= 0)]
    assert np.isin(dup, np.arange(10)).any()  # rays through the duplicated triangles: the first copy
    assert not np.isin(dup, np.arange(50, 60)).any()
    tied = np.isin(got.tri, np.arange(10))
    np.testing.assert_array_equal(got.t2[tied], got.t[tied])


def test_analytic_hits():
    """A unit right triangle in z = 0 and its copy moved to z = -1, hit from z = 1 straight down:
    t = 1 at (u, v) = the ray's (x, y), second hit at t = 2; a ray beside the triangles misses,
    and its graze is the barycentric minimum of where it crosses their planes."""
    tri = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32)
    tris = np.stack([tri, tri + np.float32([0, 0, -1])])
    o = np.array([[0.25, 0.125, 1.0], [1.0, 1.0, 1.0], [0.25, 0.125, 1.0]])
    d = np.array([[0.0, 0.0, -1.0], [0.0, 0.0, -1.0], [0.0, 0.0, -1.0]])
    for cast in (ref_cast, ref_cast_numpy):
        h = cast(tris, o, d, 0.0, np.array([np.inf, np.inf, 1.5]))
        np.testing.assert_array_equal(h.tri, [0, -1, 0])
        np.testing.assert_allclose(h.t, [1.0, np.inf, 1.0])
        np.testing.assert_allclose(h.u[[0, 2]], [0.25, 0.25])
        np.testing.assert_allclose(h.v[[0, 2]], [0.125, 0.125])
        np.testing.assert_allclose(h.edge[[0, 2]], [0.125, 0.125])
        np.testing.assert_allclose(h.t2, [2.0, np.inf, np.inf])  # the third ray's tmax cuts the copy off
        np.testing.assert_allclose(h.graze, [-np.inf, -1.0, -np.inf])  # (1, 1): w = 1 - 1 - 1
