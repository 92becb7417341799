"""Incoherent single rays traced several at a time, interleaved, so that their memory loads overlap.

A random ray through a large mesh spends most of its time waiting on memory (BENCHMARKS.md
section 13): each cell it visits is a chain of dependent loads, the cell's range in
``cell_start``, then its references in ``tri_ids`` and the triangles they name.  One ray cannot
start the next load of the chain before the previous one has arrived.  Here :data:`LANES` rays
are traced together, in step (after Kocberber et al.'s asynchronous memory access chaining): the
step that finds a lane's next cell starts the load of that cell's range; then every lane starts
the loads of its cell's triangles, and then every lane tests its cell and moves on.  The loads of
the lanes overlap, and each arrives while the other lanes work.  A lane whose ray is done takes
the next ray.

Each ray visits the same cells and tests the same triangles in the same order as
:func:`gridrt.trace.traverse.trace_ray`, with the same termination rule, so its hit (triangle, t,
u, v), its cells and its tests are the same; only the order in which rays finish changes.  Rays
from far away (:func:`gridrt.trace.traverse.is_far`) and two-level grids go through trace_ray.
"""

import numpy as np
from numba import njit

from ..compiles import inner
from .grids import is_two_level
from .prefetch import prefetch_range, prefetch_triangles
from .query import Ray, Shear, StreamScratch
from .traverse import (MAILBOX, SCRATCH, _block_box, _clip_box, _entry_cells, _macro_start, _next_block, _next_cell,
                       _ray_setup, _result, _test_cell, is_far, trace_ray)

#: rays interleaved (each with its own state row and mailbox)
LANES = 8
#: what a lane does next: test its next cell (STAY), step through the macro cells from the one it
#: left (LEAVE) or from the one its new ray starts in (ENTER), hand in its ray's hit (DONE), take
#: a new ray (FREE)
STAY, LEAVE, ENTER, DONE, FREE = 0, 1, 2, 3, 4
#: batch casts trace their incoherent rays interleaved on meshes of at least this many triangles
#: (measured: BENCHMARKS.md section 13; on smaller meshes, whose cells and triangles stay in the
#: caches, keeping the lanes' state costs more than the overlap gains)
STREAM_TRIANGLES = 1 << 18
#: the float64 state row of a lane: origin, direction, 1 / direction, the watertight shear's
#: origin and factors, the clipped exit t1, the macro cell's exits, the t where the ray entered
#: it, and the nearest hit so far (t, u, v)
F_O, F_D, F_INV, F_OK, F_S, F_T1, F_TM, F_TIN, F_T, F_U, F_V, NF = 0, 3, 6, 9, 12, 15, 16, 19, 20, 21, 22, 23
#: the int64 state row: the ray's index (-1: the lane is free), the steps along each axis, the
#: shear's permutation, the macro cell's indices and linear index, the cell's indices and linear
#: index, the axis it entered the macro cell through, cells, tests, and the triangle of the
#: nearest hit so far
I_RAY, I_S, I_K, I_M, I_MLIN, I_C, I_CLIN, I_ENT, I_CELLS, I_TESTS, I_F, NI = (
    0, 1, 4, 7, 10, 11, 14, 15, 16, 17, 18, 19)


@njit(cache=True, inline="always")
def stream_scratch():
    """A new :class:`gridrt.trace.query.StreamScratch` of LANES lanes (in a kernel)."""
    return StreamScratch(np.empty((LANES, NF)), np.empty((LANES, NI), np.int64), np.empty((LANES, SCRATCH), np.int32))


@njit(cache=True, inline="always")
def _hand_in(out, counts, i, hit):
    """Ray i's hit (triangle, t, u, v, cells, tests) into row i of the :class:`HitArrays` out, and
    its counts into column i of counts unless it is empty."""
    out.tri[i], out.t[i], out.u[i], out.v[i] = hit[0], hit[1], hit[2], hit[3]
    if counts.shape[1] > 0:
        counts[0, i], counts[1, i] = hit[4], hit[5]


@njit(cache=True, inline="always")
def _lane_ray(fs, is_, k, tmin, watertight, any_hit):
    """Lane k's :class:`Ray` from its state rows."""
    sh = Shear(is_[k, I_K], is_[k, I_K + 1], is_[k, I_K + 2], fs[k, F_OK], fs[k, F_OK + 1], fs[k, F_OK + 2],
               fs[k, F_S], fs[k, F_S + 1], fs[k, F_S + 2])
    return Ray((fs[k, F_O], fs[k, F_O + 1], fs[k, F_O + 2]), (fs[k, F_D], fs[k, F_D + 1], fs[k, F_D + 2]),
               (is_[k, I_S], is_[k, I_S + 1], is_[k, I_S + 2]), (fs[k, F_INV], fs[k, F_INV + 1], fs[k, F_INV + 2]),
               sh, tmin, watertight, any_hit)


@njit(cache=True, inline="always")
def _to_macro(g, fs, is_, k, ray, step_first):
    """Lane k from its macro cell on (the one it starts in, or entered at t F_TIN through axis
    I_ENT; with step_first, from the macro cell after it): the first macro cell that holds
    triangles and the cell where the ray enters it, its range's load started; or, when the ray
    leaves the grid or passes t1 or its nearest hit first, True (the ray is done)."""
    lo, n, kk = g.lo, g.dims, g.macro
    nx, ny, nz = n[0], n[1], n[2]
    m = is_[k, I_MLIN]
    mi, mj, mk = is_[k, I_M], is_[k, I_M + 1], is_[k, I_M + 2]
    while True:
        if not step_first and g.macro_full[m] != 0:
            if is_[k, I_ENT] >= 0:
                b0, b1 = _block_box((mi, mj, mk), kk, (nx, ny, nz))
                is_[k, I_C], is_[k, I_C + 1], is_[k, I_C + 2] = _entry_cells(
                    lo, g.inv_cell, (nx, ny, nz), ray, fs[k, F_TIN], b0, b1, is_[k, I_ENT])
            c = is_[k, I_C] + nx * (is_[k, I_C + 1] + ny * is_[k, I_C + 2])
            is_[k, I_CLIN] = c
            is_[k, I_M], is_[k, I_M + 1], is_[k, I_M + 2], is_[k, I_MLIN] = mi, mj, mk, m
            prefetch_range(g.cell_start, c)
            return False
        te, ent, mi, mj, mk, m, tmx, tmy, tmz, out = _next_block(
            ray, (fs[k, F_TM], fs[k, F_TM + 1], fs[k, F_TM + 2]), (mi, mj, mk), m, (g.mdims[0], g.mdims[1], g.mdims[2]),
            kk, (lo[0], lo[1], lo[2]), (g.cell[0], g.cell[1], g.cell[2]), (nx, ny, nz))
        if out or te > fs[k, F_T1] or fs[k, F_T] <= te:
            return True
        step_first = False
        fs[k, F_TM], fs[k, F_TM + 1], fs[k, F_TM + 2] = tmx, tmy, tmz
        is_[k, I_ENT] = ent
        fs[k, F_TIN] = te


@njit(cache=True, inline="always")
def _lane_start(g, o, d, q, sc, k):
    """Ray (o, d) of the :class:`Query` q set up in lane k of the scratch sc, in the macro cell it
    starts in (:func:`_to_macro` goes on from there), or True when it misses the grid's box."""
    tmin, tmax = q.tmin, q.tmax
    fs, is_, mbs = sc.fs, sc.is_, sc.mbs
    lo, hi = g.lo, g.hi
    t0, t1 = _clip_box(lo, hi, o, d, tmin, tmax)
    if not (t0 <= t1):
        return True
    n = g.dims
    ix, iy, iz, ray = _ray_setup(lo, g.inv_cell, n, o, d, t0, tmin, q.watertight, q.any_hit, mbs[k])
    for a in range(3):
        fs[k, F_O + a] = o[a]
        fs[k, F_D + a] = d[a]
        fs[k, F_INV + a] = ray.inv[a]
        is_[k, I_S + a] = ray.s[a]
    sh = ray.sh
    fs[k, F_OK], fs[k, F_OK + 1], fs[k, F_OK + 2] = sh.okx, sh.oky, sh.okz
    fs[k, F_S], fs[k, F_S + 1], fs[k, F_S + 2] = sh.Sx, sh.Sy, sh.Sz
    is_[k, I_K], is_[k, I_K + 1], is_[k, I_K + 2] = sh.kx, sh.ky, sh.kz
    fs[k, F_T1] = t1
    fs[k, F_T] = tmax
    fs[k, F_U] = 0.0
    fs[k, F_V] = 0.0
    is_[k, I_F] = -1
    is_[k, I_CELLS] = 0
    is_[k, I_TESTS] = 0
    is_[k, I_C], is_[k, I_C + 1], is_[k, I_C + 2] = ix, iy, iz
    (is_[k, I_M], is_[k, I_M + 1], is_[k, I_M + 2], is_[k, I_MLIN], fs[k, F_TM], fs[k, F_TM + 1],
     fs[k, F_TM + 2]) = _macro_start(lo, g.cell, n, g.macro, g.mdims, (ix, iy, iz), ray)
    is_[k, I_ENT] = -1
    fs[k, F_TIN] = t0
    return False


@njit(cache=True, inline="always")
def _test_step(g, sc, k, ray):
    """Lane k's step (of the scratch sc) that tests its cell's triangles and moves on to the next
    cell: STAY when that one lies in the same macro cell (its range's load started), LEAVE when
    the ray leaves the macro cell (:func:`_to_macro` steps on), DONE when the ray is done."""
    fs, is_, mbs = sc.fs, sc.is_, sc.mbs
    lo, cl, n, kk = g.lo, g.cell, g.dims, g.macro
    nx, ny, nz = n[0], n[1], n[2]
    c = is_[k, I_CLIN]
    is_[k, I_CELLS] += 1
    b0, b1 = _block_box((is_[k, I_M], is_[k, I_M + 1], is_[k, I_M + 2]), kk, (nx, ny, nz))
    te, ix, iy, iz, leaves = _next_cell(ray, (lo[0], lo[1], lo[2]), (cl[0], cl[1], cl[2]),
                                        (is_[k, I_C], is_[k, I_C + 1], is_[k, I_C + 2]), b0, b1)
    mb = mbs[k]
    best_f, best_t, best_u, best_v, tests, done = _test_cell(
        g.tris, g.tri_ids, g.cell_start, c, mb, mb[MAILBOX:].view(np.float64), ray,
        (is_[k, I_F], fs[k, F_T], fs[k, F_U], fs[k, F_V]), is_[k, I_TESTS])
    is_[k, I_F] = best_f
    fs[k, F_T], fs[k, F_U], fs[k, F_V] = best_t, best_u, best_v
    is_[k, I_TESTS] = tests
    if done or best_t <= te or te > fs[k, F_T1]:
        return DONE
    if leaves:
        return LEAVE
    cn = ix + nx * (iy + ny * iz)
    is_[k, I_C], is_[k, I_C + 1], is_[k, I_C + 2], is_[k, I_CLIN] = ix, iy, iz, cn
    prefetch_range(g.cell_start, cn)
    return STAY


@inner(cache=True, _nrt=False)
def stream_rays(g, origins, dirs, idx, s, n, q, sc, out, counts):
    """Rays idx[s:s+n] (rays s..s+n-1 when idx is empty) of (origins, dirs) (N, 3) float64, LANES
    at a time interleaved (the module's docstring), for the :class:`Query` q: ray i's triangle, t,
    u, v into row i of the :class:`HitArrays` out, the same as trace_ray gives, and its cells
    visited and triangle tests into counts[0, i], counts[1, i] when counts (int64, (2, N) or
    (2, 0)) is not empty.  sc: the worker's :class:`StreamScratch`."""
    tmin, tmax, watertight, any_hit = q.tmin, q.tmax, q.watertight, q.any_hit
    fs, is_, mbs = sc.fs, sc.is_, sc.mbs
    use_idx = idx.shape[0] > 0
    lo, hi = g.lo, g.hi
    nxt = 0
    busy = 0
    for k in range(LANES):
        is_[k, I_RAY] = -1
    while True:
        # the lanes in step: every busy lane's triangles' loads (its cell's range has arrived),
        # then its tests (the steps of one kind take the same branches, and their loads overlap)
        for k in range(LANES):
            if is_[k, I_RAY] >= 0:
                prefetch_triangles(g.tris, g.tri_ids, g.cell_start, is_[k, I_CLIN])
        for k in range(LANES):
            i = is_[k, I_RAY]
            step = FREE
            if i >= 0:
                step = _test_step(g, sc, k, _lane_ray(fs, is_, k, tmin, watertight, any_hit))
            while step != STAY:
                if step == LEAVE or step == ENTER:
                    done = _to_macro(g, fs, is_, k, _lane_ray(fs, is_, k, tmin, watertight, any_hit), step == LEAVE)
                    step = DONE if done else STAY
                    continue
                if step == DONE:
                    _hand_in(out, counts, is_[k, I_RAY], _result(is_[k, I_F], fs[k, F_T], fs[k, F_U], fs[k, F_V],
                                                                 is_[k, I_CELLS], is_[k, I_TESTS]))
                    is_[k, I_RAY] = -1
                    busy -= 1
                # the lane is free: it takes the next ray that has something to trace (its first
                # cell's range then arrives while the other lanes take their steps)
                step = STAY
                while nxt < n:
                    i = idx[s + nxt] if use_idx else s + nxt
                    nxt += 1
                    o = (origins[i, 0], origins[i, 1], origins[i, 2])
                    d = (dirs[i, 0], dirs[i, 1], dirs[i, 2])
                    if is_two_level(g) or is_far(lo, hi, o[0], o[1], o[2]):
                        _hand_in(out, counts, i, trace_ray(g, o, d, tmin, tmax, watertight, any_hit, mbs[k]))
                        continue
                    if _lane_start(g, o, d, q, sc, k):
                        _hand_in(out, counts, i, (-1, np.inf, 0.0, 0.0, 0, 0))
                        continue
                    is_[k, I_RAY] = i
                    busy += 1
                    step = ENTER
                    break
        if busy == 0:
            return
