"""gridrt.compiles.one_per_types: a kernel called from other kernels with constant arguments
compiles once per argument types, not once per constant, and still honours each constant.

What compiled is read from the dispatchers' own ``signatures`` (numba's record, independent of
the decorator); numba without it types ``f(x, True)`` from jitted code as a call with a
``Literal[bool](True)`` argument and compiles f for it."""

import numpy as np
from numba import njit, types

import reference as R
from conftest import random_triangles
from gridrt.compiles import one_per_types
from gridrt.grid import build_grid
from gridrt.trace.grids import grid_tuple
from gridrt.trace.traverse import SCRATCH, trace_grids, trace_ray


@njit
def _plain(x, flag, k):
    return x + k if flag else x


@one_per_types
@njit
def _once(x, flag, k):
    return x + k if flag else x


@njit
def _call_plain(x):
    return _plain(x, True, 1) + _plain(x, False, 2)


@njit
def _call_once(x):
    return _once(x, True, 1), _once(x, False, 2), _once(x, x > 0, 3)


def _literal(sig):
    return any(isinstance(a, types.Literal) for a in sig)


def test_constants_compile_once_and_keep_their_values():
    assert _call_plain(10) == 21
    assert len(_plain.signatures) == 2 and all(_literal(s) for s in _plain.signatures), \
        "numba should compile the undecorated function once per constant (what the decorator prevents)"
    assert _call_once(10) == (11, 10, 13)
    assert _once.signatures == [(types.int64, types.boolean, types.int64)]


@njit
def _nearest_and_any(grids, origins, dirs, out_f, out_t, out_any):
    """Each ray's nearest hit and its any-hit answer, each asked with constant flags."""
    mb = np.empty(SCRATCH, np.int32)
    for i in range(origins.shape[0]):
        o = (origins[i, 0], origins[i, 1], origins[i, 2])
        d = (dirs[i, 0], dirs[i, 1], dirs[i, 2])
        w, f, t, u, v, nc, nt = trace_grids(grids, o, d, 0.0, np.inf, True, False, mb)
        sw, sf, st, su, sv, snc, snt = trace_grids(grids, o, d, 0.0, np.inf, True, True, mb)
        out_f[i], out_t[i], out_any[i] = f, t, sf >= 0


def test_traversal_compiles_once_for_nearest_and_any_hit():
    """The camera rays (any_hit False) and the shadow rays (True) share one compile of the
    traversal, and each still gets its own answer (checked against a float64 brute force)."""
    rng = np.random.default_rng(7)
    tris = random_triangles(rng, 300)
    grids = grid_tuple((build_grid(tris), tris, None))
    origins = rng.uniform(-0.5, 1.5, (400, 3))
    dirs = rng.normal(size=(400, 3))
    ref = R.ref_cast(tris, origins, dirs)
    f, t, hit = np.empty(400, np.int64), np.empty(400), np.empty(400, np.bool_)
    _nearest_and_any(grids, origins, dirs, f, t, hit)
    assert ref.hit.any() and not ref.hit.all()
    np.testing.assert_array_equal(hit, ref.hit)
    np.testing.assert_array_equal(f >= 0, ref.hit)
    np.testing.assert_allclose(t[ref.hit], ref.t[ref.hit], rtol=1e-5)
    for kernel in (trace_grids, trace_ray):
        assert not any(_literal(s) for s in kernel.signatures), \
            f"{kernel.__name__} compiled for literal arguments: {kernel.signatures}"
