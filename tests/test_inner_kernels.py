"""gridrt.compiles.inner: a kernel that only other kernels call is compiled without numba's
Python entry point.  Called from a kernel it computes what its Python source computes; called
from Python it raises a TypeError naming it (without the guard, numba would call a null entry
point and the process would die); and numba's own record of the compiled code has no CPython
wrapper for it, where a plain njit function has one.

An inner kernel is never compiled to machine code of its own (its callers link in its LLVM IR):
numba's object-code hook never sees its module, where it sees a plain kernel's; and through the
on-disk cache, a caller compiled afresh over inner kernels loaded from the cache, and a caller
loaded whole, compute what the first compile computed."""

import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest
from numba import njit
from numba.core import config as numba_config

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


def test_an_inner_kernel_has_no_machine_code_of_its_own():
    a = np.arange(7.0)
    assert _caller(a) == 4.0 * a.sum()
    (inner_result,) = _twice.overloads.values()
    (plain_result,) = _plain.overloads.values()
    # numba's object-code hook marks a library whose module the JIT compiled to machine code
    assert plain_result.library._compiled and _caller.overloads[_caller.signatures[0]].library._compiled
    assert not inner_result.library._compiled, "the inner kernel was compiled to machine code"


def _module_passes(library):
    """The names of the module-level optimisation runs numba recorded for a code library."""
    return [name for name, _ in library.recorded_timings if name.startswith("Module passes")]


def test_an_inner_kernels_module_is_optimised_only_within_its_callers(monkeypatch):
    """numba optimises the module of every library it finalises; an inner kernel's IR is only
    ever linked into its callers, whose libraries optimise it with their own code: its own
    library runs no module optimisation, where a plain kernel's and the caller's do (numba's
    record of the LLVM passes each library ran, kept while NUMBA_LLVM_PASS_TIMINGS is on)."""
    monkeypatch.setattr(numba_config, "LLVM_PASS_TIMINGS", True)

    @inner(cache=False)
    def halve(a, i):
        return 0.5 * a[i]

    @njit(cache=False)
    def plain(a, i):
        return a[i] + 1.0

    @njit(cache=False)
    def caller(a):
        s = 0.0
        for i in range(a.shape[0]):
            s += halve(a, i) + plain(a, i)
        return s

    a = np.arange(7.0)
    assert caller(a) == 1.5 * a.sum() + 7.0
    (inner_result,) = halve.overloads.values()
    (plain_result,) = plain.overloads.values()
    (caller_result,) = caller.overloads.values()
    assert "Module passes (full optimization)" in _module_passes(plain_result.library)
    assert "Module passes (full optimization)" in _module_passes(caller_result.library)
    assert _module_passes(inner_result.library) == [], "the inner kernel's module was optimised on its own"


_CACHED_MODULE = """
import numpy as np
from numba import njit
from gridrt.compiles import inner

@inner(cache=True)
def scaled(a, i, k):
    return k * a[i] + 1.0

@inner(cache=True)
def pair(a, i):
    return scaled(a, i, 2.0) - scaled(a, i, 0.5)

@njit(cache=True)
def total(a):
    s = 0.0
    for i in range(a.shape[0]):
        s += pair(a, i) * (i + 1)
    return s
"""

_RUN = """
import json, sys
import numpy as np
sys.path.insert(0, sys.argv[1])
import cached_kernels as m
a = np.linspace(-2.0, 3.0, 11)
r = m.total(a)
print(json.dumps({"total": r, "compiled": sorted(str(k) for k, v in m.total.stats.cache_misses.items()),
                  "inner_hits": sum(m.pair.stats.cache_hits.values()),
                  "inner_libraries": sorted({type(c.library).__name__ for d in (m.pair, m.scaled)
                                             for c in d.overloads.values()})}))
"""


def test_inner_kernels_through_the_cache(tmp_path):
    import json

    (tmp_path / "cached_kernels.py").write_text(textwrap.dedent(_CACHED_MODULE))
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"))

    def run():
        r = subprocess.run([sys.executable, "-c", _RUN, str(tmp_path)], env=env, capture_output=True, text=True,
                           timeout=300)
        assert r.returncode == 0, r.stderr[-2000:]
        return json.loads(r.stdout.strip().splitlines()[-1])

    a = np.linspace(-2.0, 3.0, 11)
    want = float(sum((1.5 * x) * (i + 1) for i, x in enumerate(a)))  # (2a + 1) - (0.5a + 1) = 1.5a
    first = run()
    assert first["total"] == pytest.approx(want, rel=1e-12) and first["inner_hits"] == 0
    assert first["inner_libraries"] == ["_InnerLibrary"]
    # the inner kernels' entries are files of their own, which a numba without gridrt never reads
    stems = sorted(p.name.rsplit("-", 1)[0] for p in (tmp_path / "cache").rglob("*.nbi"))
    assert stems == ["cached_kernels.total", "inner-cached_kernels.pair", "inner-cached_kernels.scaled"], stems
    # the caller compiles again, over the inner kernels from the cache
    files = list((tmp_path / "cache").rglob("*total*"))
    assert files
    for f in files:
        f.unlink()
    again = run()
    assert again["compiled"] and again["inner_hits"] == 1  # (pair's IR holds scaled's, linked in)
    assert again["inner_libraries"] == ["_InnerLibrary"]  # (pair's, loaded from the cache)
    assert again["total"] == first["total"]
    # and the whole caller loads from the cache
    loaded = run()
    assert not loaded["compiled"] and loaded["total"] == first["total"]
