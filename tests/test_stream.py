"""Incoherent rays traced several at a time, interleaved (gridrt.trace.stream), and the batch casts
that use it on large meshes.

* the interleaved walk gives every ray the hit (triangle, t, u, v bit for bit), the cells visited
  and the triangle tests of trace_ray on its own, for nearest and any hit, the watertight and the
  fast test, rays from inside, outside and far outside the grid, every ray or a shuffled subset,
  on 1 and 3 threads;
* its nearest hits agree with the float64 brute force (tests/reference.py);
* batch casts on a mesh at or above the threshold take it (a wrapped stream_runs records the
  call), below it they do not, and with it forced on a small mesh their hits are the same for
  1, 2 and 3 threads and any order of the rays, and the brute force's.

The slow run's (the interleaved walk's kernel compiles for these tests alone, about 20 s): the
quick run's batch casts, on meshes below the threshold, do not take it.
"""

import importlib

import numpy as np
import pytest
from numba import njit

import reference as R
from conftest import TEAPOT, icosphere_tris, load_tris, random_rays, random_scene
from gridrt.grid import GridParams, build_grid
from gridrt.trace import cast_rays
from gridrt.trace.grids import grid_arrays
from gridrt.threads import use_threads
from gridrt.trace.query import HitArrays, query
from gridrt.trace.stream import STREAM_TRIANGLES
from gridrt.trace.traverse import SCRATCH, trace_ray

batch = importlib.import_module("gridrt.trace.batch")
pytestmark = pytest.mark.slow


@njit(cache=True)
def _one_at_a_time(g, o, d, tmin, tmax, watertight, any_hit, tri, t, u, v, cells, tests):
    mb = np.empty(SCRATCH, np.int32)
    for i in range(o.shape[0]):
        tri[i], t[i], u[i], v[i], cells[i], tests[i] = trace_ray(
            g, (o[i, 0], o[i, 1], o[i, 2]), (d[i, 0], d[i, 1], d[i, 2]), tmin, tmax, watertight, any_hit, mb)


def _outputs(n):
    return (np.full(n, -2, np.int32), np.full(n, np.nan), np.full(n, np.nan), np.full(n, np.nan),
            np.full(n, -1, np.int64), np.full(n, -1, np.int64))


def _mesh(name):
    if name == "icosphere":
        return icosphere_tris(3)
    if name == "teapot":
        return load_tris(TEAPOT)
    if name == "flat":  # every vertex on one plane: a grid one cell thick
        return np.ascontiguousarray(random_scene(np.random.default_rng(17), 300, "mixed", 2), np.float32)
    # duplicated triangles (exact ties) and zero-area ones
    return np.ascontiguousarray(random_scene(np.random.default_rng(13), 400, "mixed", None, dup_frac=0.3,
                                             degen_frac=0.1), np.float32)


def _rays(tris, rng, n):
    """Random rays from inside the mesh's box (grown by 1% of its size), rays aimed at it from
    around it, and rays from 1e7 box sizes away (the far-origin path) aimed at it."""
    lo, hi = tris.reshape(-1, 3).min(0).astype(np.float64), tris.reshape(-1, 3).max(0).astype(np.float64)
    pad = 0.01 * float((hi - lo).max())  # (a flat mesh's box is flat: its origins would lie on the mesh)
    o1, d1 = random_rays(rng, n, lo - pad, hi + pad, outside=0.0)
    o2, d2 = random_rays(rng, n, lo, hi, outside=0.5, aim=True)
    size = float((hi - lo).max())
    o3 = 0.5 * (lo + hi) + rng.normal(size=(n // 8, 3)) * 1e7 * size
    d3 = rng.uniform(lo, hi, (n // 8, 3)) - o3
    return np.concatenate([o1, o2, o3]), np.concatenate([d1, d2, d3])


@pytest.mark.parametrize("name", ["icosphere", "teapot", "dups", "flat"])
def test_interleaved_walk_equals_trace_ray(name):
    """Every ray, in the given order and through a shuffled subset of indices, on 1 and 3 threads."""
    tris = np.ascontiguousarray(_mesh(name), np.float32)
    g = grid_arrays(build_grid(tris, GridParams()), tris)
    o, d = _rays(tris, np.random.default_rng(7), 3000)
    rows = np.random.default_rng(8).permutation(len(o))[: len(o) - 500]
    for watertight in (True, False):
        for any_hit in (False, True):
            for tmax in (np.inf, 0.7):
                want = _outputs(len(o))
                _one_at_a_time(g, o, d, 0.0, tmax, watertight, any_hit, *want)
                label = f"{name} watertight={watertight} any_hit={any_hit} tmax={tmax}"
                for idx, threads in ((batch.NO_ROWS, 1), (rows, 3)):
                    got = _outputs(len(o))
                    counts = np.full((2, len(o)), -1, np.int64)
                    use_threads(threads)
                    batch.stream_runs(g, o, d, idx, query(0.0, tmax, watertight, any_hit),
                                      HitArrays(got[1], got[0], got[2], got[3], batch.NO_LEFT), counts)
                    got = got[:4] + (counts[0], counts[1])
                    picked = idx if len(idx) else slice(None)
                    for field, a, b in zip(("tri", "t", "u", "v", "cells", "tests"), want, got):
                        a, b = a[picked], b[picked]
                        assert np.array_equal(a, b), f"{label}: {field} differs at {np.flatnonzero(a != b)[:5]}"
                    if len(idx):
                        left = np.setdiff1d(np.arange(len(o)), idx)
                        assert (got[0][left] == -2).all(), f"{label}: rays outside the indices were written"
                if watertight and not any_hit:  # (want: the interleaved walk's hits on every ray, as checked)
                    ref = R.ref_cast(tris, o, d, tmax=tmax)
                    diff = R.compare_hits(want[1], want[0], ref, t_rtol=1e-5, tie_rtol=1e-9, graze_tol=1e-9)
                    assert len(diff.bad) == 0 and len(diff.t_off) == 0, label
                    if tmax == np.inf:
                        assert 0.1 < (want[0] >= 0).mean() < 0.9, f"{label}: the rays should both hit and miss"
                        assert (want[4] > 0).mean() > 0.5, f"{label}: most rays should visit cells"


def test_batch_casts_interleave_on_large_meshes(monkeypatch):
    """The threshold decides, and with it forced on a small mesh a batch cast's hits are those of
    the casts without it, in any order and on any number of threads, and the brute force's."""
    calls = []
    real = batch.stream_runs

    def recorded(*args):
        calls.append(len(args[3]) if len(args[3]) else len(args[1]))
        return real(*args)

    monkeypatch.setattr(batch, "stream_runs", recorded)
    big, below = icosphere_tris(7), icosphere_tris(6)  # 327,680 and 81,920 triangles
    assert len(big) >= STREAM_TRIANGLES > len(below)
    assert batch.streams(grid_arrays(build_grid(big, GridParams()), big))
    assert not batch.streams(grid_arrays(build_grid(below, GridParams()), below))
    tris = icosphere_tris(3)
    grid = build_grid(tris, GridParams())
    assert not batch.streams(grid_arrays(grid, tris))
    rng = np.random.default_rng(11)
    o, d = _rays(tris, rng, 2000)
    base = cast_rays(grid, tris, o, d)
    shadow = cast_rays(grid, tris, o, d * 0.5, tmax=1.0, any_hit=True)
    assert calls == []
    monkeypatch.setattr(batch, "STREAM_TRIANGLES", 1)
    assert batch.streams(grid_arrays(grid, tris))
    assert not batch.streams(grid_arrays(build_grid(tris, GridParams(grid="two_level")), tris))
    perm = rng.permutation(len(o))
    for threads in (1, 2, 3):
        for order in (None, perm):
            oo, dd = (o, d) if order is None else (o[order], d[order])
            back = np.argsort(order) if order is not None else slice(None)
            for packets in (True, False):
                got = cast_rays(grid, tris, oo, dd, packets=packets, threads=threads)
                for field in ("t", "tri", "u", "v"):
                    assert np.array_equal(getattr(got, field)[back], getattr(base, field)), (threads, field)
            a = cast_rays(grid, tris, oo, dd * 0.5, tmax=1.0, any_hit=True, threads=threads)
            assert np.array_equal(a.tri[back] >= 0, shadow.tri >= 0), threads
    assert len(calls) >= 12 and sum(calls) >= 0.5 * 12 * len(o), calls
    ref = R.ref_cast(tris, o, d)
    diff = R.compare_hits(base.t, base.tri, ref, t_rtol=1e-5, tie_rtol=1e-9, graze_tol=1e-9)
    assert len(diff.bad) == 0 and len(diff.t_off) == 0
