"""gridrt.compiles.inner: a kernel that only other kernels call is compiled without numba's
Python entry point.  Called from a kernel it computes what its Python source computes; called
from Python it raises a TypeError naming it (without the guard, numba would call a null entry
point and the process would die); and numba's own record of the compiled code has no CPython
wrapper for it, where a plain njit function has one."""

import numpy as np
import pytest
from numba import njit

from gridrt.compiles import InnerDispatcher, inner
from gridrt.trace import intersect


@njit(cache=False)
def _fast_hits(tris, o, d):
    """intersect_fast (an inner kernel) on each triangle of tris (n, 3, 3) with one ray."""
    out = np.empty((tris.shape[0], 4))
    for i in range(tris.shape[0]):
        v0 = (tris[i, 0, 0], tris[i, 0, 1], tris[i, 0, 2])
        v1 = (tris[i, 1, 0], tris[i, 1, 1], tris[i, 1, 2])
        v2 = (tris[i, 2, 0], tris[i, 2, 1], tris[i, 2, 2])
        hit, t, u, v = intersect.intersect_fast(v0, v1, v2, o, d, 0.0, np.inf)
        out[i, 0], out[i, 1], out[i, 2], out[i, 3] = hit, t, u, v
    return out


def _analytic(tris, o, d):
    """(hit, t, u, v) of each triangle by solving o + t d = v0 + u (v1 - v0) + v (v2 - v0) in
    float64 with numpy's solver."""
    out = np.zeros((len(tris), 4))
    for i, (v0, v1, v2) in enumerate(tris):
        t, u, v = np.linalg.solve(np.column_stack([-d, v1 - v0, v2 - v0]), o - v0)
        if t > 0 and u >= 0 and v >= 0 and u + v <= 1:
            out[i] = 1.0, t, u, v
    return out


def test_an_inner_kernel_called_from_a_kernel_computes_its_source():
    rng = np.random.default_rng(3)
    tris = rng.uniform(-1, 1, (200, 3, 3))
    o, d = np.array([0.05, -0.02, -3.0]), np.array([0.01, 0.02, 1.0])
    got = _fast_hits(tris, tuple(o), tuple(d))
    ref = _analytic(tris, o, d)
    assert 5 < ref[:, 0].sum() < 195
    np.testing.assert_array_equal(got[:, 0], ref[:, 0])
    hit = ref[:, 0] == 1
    np.testing.assert_allclose(got[hit, 1:], ref[hit, 1:], rtol=1e-9, atol=1e-12)


def test_a_call_from_python_is_refused_by_name():
    assert isinstance(intersect.intersect_fast, InnerDispatcher)
    with pytest.raises(TypeError, match=r"gridrt\.trace\.intersect\.intersect_fast is a kernel that only "
                                        r"other kernels call"):
        intersect.intersect_fast((0.0, 0.0, 0.0), (1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.2, 0.2, -1.0),
                                 (0.0, 0.0, 1.0), 0.0, np.inf)


@inner(cache=False)
def _twice(a, i):
    return 2.0 * a[i]


@njit(cache=False)
def _plain(a, i):
    return 2.0 * a[i]


@njit(cache=False)
def _caller(a):
    s = 0.0
    for i in range(a.shape[0]):
        s += _twice(a, i) + _plain(a, i)
    return s


def _wrapper_address(dispatcher):
    (result,) = dispatcher.overloads.values()
    return result.library.get_pointer_to_function(result.fndesc.llvm_cpython_wrapper_name)


def test_the_inner_kernel_has_no_python_wrapper_and_the_plain_one_has():
    a = np.arange(5.0)
    assert _caller(a) == 4.0 * a.sum()
    assert _wrapper_address(_twice) == 0, "numba made a CPython wrapper for an inner kernel"
    assert _wrapper_address(_plain) != 0 and _wrapper_address(_caller) != 0
    assert _plain(a, 3) == 6.0
    with pytest.raises(TypeError, match="_twice is a kernel that only other kernels call"):
        _twice(a, 3)
