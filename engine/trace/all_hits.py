"""Every crossing along a ray, in order of t: the kernels behind ``RayCaster.all_hits`` and
``RayCaster.count_hits``.

One crossing, one hit.  The triangle test is Woop et al.'s watertight test (gridrt.trace.intersect)
with two changes that make it count crossings exactly:

* The three edge functions get their exact sign: each is a 2x2 determinant of the ray-sheared
  vertex coordinates (float64 values every triangle that shares the vertex computes alike); where
  its float64 value is too small to trust, the determinant is evaluated exactly (Dekker's
  two-product and an exact sum), so the signs are those of the real numbers.
* An edge function that is exactly zero (the ray passes through the edge, or through a vertex)
  takes the sign it would have for the ray moved by an infinitesimal amount in a fixed direction
  of the sheared plane (a symbolic perturbation, as rasterisers' fill rules): the two triangles
  that share an edge see it with opposite signs, so exactly one of them is hit, and around a
  vertex exactly one triangle of the fan.  The hits are those of a ray in general position
  infinitesimally close to the ray: through a closed mesh, every ray crosses an even number of
  times, and a ray that only touches the mesh at an edge or vertex crosses zero or two times.

Triangles whose plane contains the ray (det = 0) are never hit.  A hit needs t_min < t < t_max.

The traversal visits the grid's cells along the ray with a 3D DDA from the box entry to the exit
or t_max (macro cells, and the cells of those that hold triangles; a two-level grid's top cells,
and the leaf cells of those that hold triangles), collects the triangles listed in each, each
once as far as a small mailbox remembers, tests them LANES at a time side by side (a ray's hits
do not depend on the order of its tests: there is no early exit), and keeps each triangle's hit
once (a triangle listed in several cells gives the same hit each time).  The hits of a ray are
sorted by t, ties by triangle id.  A large batch on a large mesh is walked in the order of its
rays' origins along a Morton curve (:func:`order_keys`), so that rays from nearby points meet
the same cells one after another, and its results are put back in the caller's order.
"""

import math
from collections import namedtuple
from typing import NamedTuple

import numpy as np
from numba import njit, prange

from ..arrays import check_ray_values, check_rays, read_only
from ..compiles import inner
from ..errors import InputError
from ..grid.atomics import atomic_add
from ..grid.two_level import leaf_axis
from ..memory import check_fits
from ..threads import check_threads, launch_guard, on_threads, use_threads
from .cgt.rays import direction_class
from .intersect import gather_rows, ray_shear, woop_shear, woop_terms
from .prefetch import prefetch_ids, prefetch_range, prefetch_triangles


@njit(cache=True, inline="always")
def _two_product(a, b):
    """(p, e) with p + e = a * b exactly (Dekker's split; no FMA needed)."""
    p = a * b
    c = 134217729.0 * a   # 2^27 + 1
    ah = c - (c - a)
    al = a - ah
    c = 134217729.0 * b
    bh = c - (c - b)
    bl = b - bh
    e = ((ah * bh - p) + ah * bl + al * bh) + al * bl
    return p, e


@njit(cache=True, inline="always")
def _two_sum(a, b):
    s = a + b
    bb = s - a
    return s, (a - (s - bb)) + (b - bb)


#: slots of a ray's mailbox (direct-mapped by triangle id; a power of two)
MAILBOX = 32
#: triangles a ray's walk collects before it tests them side by side (:func:`_test_lanes`)
LANES = 8
#: rows of _test_lanes' scratch
LANE_ROWS = 14
#: cells a ray's walk lists before it visits them (_visit_cells)
CELLS = 32
#: on a mesh of at least this many triangles (2.4 MB of them) the walk starts the loads of its
#: listed cells' references, then of their triangles, before it tests them, so that their cache
#: misses overlap (HitGrid.prefetch, _visit_cells); on smaller ones, which stay in the caches,
#: those passes over the cells' lists cost more than they save (measured: BENCHMARKS.md section 18)
PREFETCH_TRIANGLES = 1 << 16
#: a 2x2 determinant a d - b c whose float64 value exceeds this fraction of |a d| + |b c| has that
#: value's sign (the rounding of two products and a difference stays below 3 units of 2^-53 of it)
TRUST = 1e-14


@njit(cache=True)
def det2_sign(a, b, c, d):
    """The exact sign (-1, 0, 1) of a * d - b * c for finite float64 a, b, c, d (no overflow)."""
    x, y = a * d, b * c
    r = x - y
    if abs(r) > TRUST * (abs(x) + abs(y)):
        return 1 if r > 0 else -1
    return _det2_sign_exact(a, b, c, d)


@inner(cache=True)
def _det2_sign_exact(a, b, c, d):
    """det2_sign where rounding could decide it: the products split exactly (two-product) and
    summed exactly."""
    p1, e1 = _two_product(a, d)
    p2, e2 = _two_product(-b, c)
    # the exact sum of p1 + e1 + p2 + e2 as a non-overlapping expansion: its sign is its largest term's
    s, t1 = _two_sum(p1, p2)
    u, t2 = _two_sum(e1, e2)
    v, t3 = _two_sum(s, u)
    w, t4 = _two_sum(t1, t2)
    q, t5 = _two_sum(v, w)
    rest = t3 + t4 + t5   # |rest| is below half an ulp of q whenever q != 0
    if q != 0.0:
        return 1 if q > 0 else -1
    if rest != 0.0:
        return 1 if rest > 0 else -1
    return 0


@njit(cache=True, inline="always")
def _edge(px, py, qx, qy):
    """(value, sign) of the edge function of the sheared edge p -> q at the ray (the origin of the
    sheared plane), qx * py - qy * px: its float64 value, and its sign when that value decides it
    (0 when it does not: :func:`_edge_sign` then)."""
    x, y = qx * py, qy * px
    r = x - y
    if abs(r) > TRUST * (abs(x) + abs(y)):
        return r, (1 if r > 0 else -1)
    return r, 0


@inner(cache=True)
def _edge_sign(px, py, qx, qy):
    """The exact sign of the edge function of p -> q, perturbed where it is exactly zero (see
    the module doc)."""
    s = _det2_sign_exact(qx, qy, px, py)
    if s != 0:
        return s
    dx, dy = qx - px, qy - py
    if dx != 0.0:
        return -1 if dx > 0 else 1
    if dy != 0.0:
        return 1 if dy > 0 else -1
    return 0


@inner(cache=True, _nrt=False)
def intersect_once(tris, f, sh, tmin, tmax):
    """(hit, t, u, v) of triangle f of tris ((F, 3, 3) float32, world order) with the ray of the
    :class:`gridrt.trace.query.Shear` ``sh`` (intersect.ray_shear): Woop's test with exact,
    perturbed edge signs (one hit per crossing, see the module doc).  It takes the triangle's
    index, not its rows: three array views a call cost more than the test's arithmetic; inlined,
    it would save a little more a test at a longer first compile (measured: BENCHMARKS.md section
    18)."""
    kx, ky, kz, okx, oky, okz, Sx, Sy, Sz = sh
    p0 = (float(tris[f, 0, kx]), float(tris[f, 0, ky]), float(tris[f, 0, kz]))
    p1 = (float(tris[f, 1, kx]), float(tris[f, 1, ky]), float(tris[f, 1, kz]))
    p2 = (float(tris[f, 2, kx]), float(tris[f, 2, ky]), float(tris[f, 2, kz]))
    Ax, Ay, Bx, By, Cx, Cy, az, bz, cz = woop_shear(p0, p1, p2, (okx, oky, okz), Sx, Sy)
    U, su = _edge(Bx, By, Cx, Cy)   # U = Cx By - Cy Bx: the edge B -> C
    V, sv = _edge(Cx, Cy, Ax, Ay)   # V: the edge C -> A
    W, sw = _edge(Ax, Ay, Bx, By)   # W: the edge A -> B
    if su * sv < 0 or sv * sw < 0 or su * sw < 0:   # two signs the values decide disagree: a miss
        return False, 0.0, 0.0, 0.0
    if su == 0:
        su = _edge_sign(Bx, By, Cx, Cy)
    if sv == 0:
        sv = _edge_sign(Cx, Cy, Ax, Ay)
    if sw == 0:
        sw = _edge_sign(Ax, Ay, Bx, By)
    if su == 0 or su != sv or sv != sw:
        return False, 0.0, 0.0, 0.0
    det = U + V + W   # (of the signs su: never 0 where all three agree, unless it underflows)
    if det == 0.0:
        return False, 0.0, 0.0, 0.0
    t = (U * (Sz * az) + V * (Sz * bz) + W * (Sz * cz)) / det
    if not (tmin < t < tmax):
        return False, 0.0, 0.0, 0.0
    return True, t, V / det, W / det


@inner(cache=True, _nrt=False, error_model="numpy")
def _test_lanes(tris, pend, m, rows, sh, tmin, tmax, nh, buf):
    """The triangles pend[:m] (m <= LANES) against the ray of the Shear sh, side by side: their
    vertices gathered into the float64 rows of ``rows`` (permuted by the shear), then Woop's test
    of each in one loop over LANES lanes without branches, which LLVM vectorizes (lanes m.. compute
    on stale scratch, unread).  A lane whose three edge functions' float64 values decide their
    signs is a hit or a miss exactly as :func:`intersect_once` finds it (the same operations in the
    same order); a lane where a value does not decide its sign, and two decided signs do not
    already disagree, goes to intersect_once.  The hits go into buf (:func:`_add_hit`); returns the
    new count, or -1 when they do not fit.  Compiled once for ray_hits' two calls (_nrt=False:
    numba does not inline it), with numpy's error model (no check of the division by det, which a
    zero det never reaches as 0)."""
    kx, ky, kz, okx, oky, okz, Sx, Sy, Sz = sh
    bt, bf, bu, bv = buf
    C = LANES
    gather_rows(tris, pend, 0, m, kx, ky, kz, rows, C)
    for j in range(C):
        Ax, Ay, Bx, By, Cx, Cy, az, bz, cz = woop_shear(
            (rows[j], rows[C + j], rows[2 * C + j]), (rows[3 * C + j], rows[4 * C + j], rows[5 * C + j]),
            (rows[6 * C + j], rows[7 * C + j], rows[8 * C + j]), (okx, oky, okz), Sx, Sy)
        U, su = _edge(Bx, By, Cx, Cy)   # as intersect_once: the edges B -> C, C -> A, A -> B
        V, sv = _edge(Cx, Cy, Ax, Ay)
        W, sw = _edge(Ax, Ay, Bx, By)
        det, T, _ = woop_terms(U, V, W, az, bz, cz, Sz)
        t = T / (det if det != 0.0 else 1.0)
        hit = (det != 0.0) & (tmin < t) & (t < tmax)
        # 0: a miss (two decided signs disagree, or all three agree and no hit in range), 1: a hit,
        # 2: for intersect_once (a sign left undecided)
        disagree = (su * sv < 0) | (sv * sw < 0) | (su * sw < 0)
        rows[9 * C + j] = 0.0 if disagree else (2.0 if su * sv * sw == 0 else (1.0 if hit else 0.0))
        rows[10 * C + j] = t
        rows[11 * C + j] = V
        rows[12 * C + j] = W
        rows[13 * C + j] = det
    for j in range(m):
        how = rows[9 * C + j]
        if how == 0.0:
            continue
        f = pend[j]
        if how == 1.0:
            det = rows[13 * C + j]
            nh = _add_hit(f, rows[10 * C + j], rows[11 * C + j] / det, rows[12 * C + j] / det, nh, bt, bf, bu, bv)
        else:
            hit, t, u, v = intersect_once(tris, f, sh, tmin, tmax)
            if hit:
                nh = _add_hit(f, t, u, v, nh, bt, bf, bu, bv)
        if nh < 0:
            return -1
    return nh


@inner(cache=True)
def _clip(lo, hi, o, d, tmin, tmax):
    t0, t1 = tmin, tmax
    for a in range(3):
        if d[a] != 0.0:
            inv = 1.0 / d[a]
            ta, tb = (lo[a] - o[a]) * inv, (hi[a] - o[a]) * inv
            if ta > tb:
                ta, tb = tb, ta
            t0 = max(t0, ta)
            t1 = min(t1, tb)
        elif o[a] < lo[a] or o[a] > hi[a]:
            return 1.0, 0.0
    return t0, t1


@njit(cache=True, inline="always")
def _index(p, lo, size, n):
    """The index of the slab of ``size`` from ``lo`` holding ``p``, clamped to [0, n - 1]."""
    x = (p - lo) / size
    i = int(math.floor(x)) if x > -1.0 else -1
    return min(max(i, 0), n - 1)


@njit(cache=True, inline="always")
def _axis(o, d, lo, size, i):
    """(step, t of the next slab boundary, t across a slab) along one axis from slab i."""
    if d > 0.0:
        return 1, (lo + (i + 1) * size - o) / d, size / d
    if d < 0.0:
        return -1, (lo + i * size - o) / d, -size / d
    return 0, np.inf, np.inf


@njit(cache=True, inline="always")
def _advance(i, s, t, dt, i0, i1, tend):
    """One DDA step along an axis from slab i, whose far boundary is at t: (stop, slab, its far
    boundary); stop when that boundary lies beyond tend or the slab beyond [i0, i1]."""
    if t > tend:
        return True, i, t
    i += s
    if i < i0 or i > i1:
        return True, i, t
    return False, i, t + dt


@njit(cache=True, inline="always")
def _add_hit(f, t, u, v, nh, bt, bf, bu, bv):
    """Keep the hit of triangle f unless it is kept already (a triangle listed in several cells);
    the new count, or -1 when the buffers are full."""
    for j in range(nh):
        if bf[j] == f:
            return nh
    if nh == len(bt):
        return -1
    bt[nh] = t
    bf[nh] = f
    bu[nh] = u
    bv[nh] = v
    return nh + 1


@njit(cache=True, inline="always")
def _leaf_block(g, m, top):
    """The leaf grid of top cell m (indices top) of the two-level HitGrid g, as ray_hits walks a
    block of cells: its corner, its cells' size, its first and last cell indices, its first
    cell's linear index and the index steps along x, y, z."""
    rx, ry, rz = np.int64(g.leaf_res[m, 0]), np.int64(g.leaf_res[m, 1]), np.int64(g.leaf_res[m, 2])
    ax, sx, _ = leaf_axis(g.lo[0], g.cell[0], top[0], rx)
    ay, sy, _ = leaf_axis(g.lo[1], g.cell[1], top[1], ry)
    az, sz, _ = leaf_axis(g.lo[2], g.cell[2], top[2], rz)
    zero = np.int64(0)
    return ((ax, ay, az), (sx, sy, sz), (zero, zero, zero), (rx - 1, ry - 1, rz - 1), np.int64(g.leaf_first[m]),
            (np.int64(1), rx, rx * ry))


@inner(cache=True, _nrt=False)
def ray_hits(g, o, d, tmin, tmax, buf, scratch, leaf_first):
    """The hits of the ray from o along d ((3,) float64) with tmin < t < tmax in the
    :data:`HitGrid` g, each triangle once, into the :data:`HitBuffers` buf (unsorted); their
    count, or -1 when they do not fit.  Two nested DDAs: over the macro cells (k^3 cells; an
    empty one is crossed in one step) and over the cells of each macro cell that holds triangles
    (a two-level grid: over its top cells, and the leaf cells of each that holds triangles).
    The walk lists the cells it crosses (starting the load of each one's range as it lists it)
    and visits them CELLS at a time and at its end (:func:`_visit_cells`), which collects their
    triangles and tests them LANES at a time (:func:`_test_lanes`).  scratch
    (:data:`HitScratch`): the mailbox, so that a triangle listed in the cells the ray crossed last
    is not tested again (a test gives the same hit every time), the triangles collected for the
    next test and that test's rows, and the cells listed.  leaf_first: g's,
    an argument of its own so that for a uniform grid (None) numba prunes the leaf walk before
    compiling (through gridrt.trace.grids.is_two_level the first count_hits compiled 0.3 s
    longer).  Compiled without reference counting (_nrt=False: it allocates nothing): counting
    references on the arrays it is given cost about 200 ns a call (BENCHMARKS.md section 18)."""
    tris, lo, hi, cell, dims, k, mdims, macro_full, cs, _, _, _, _ = g
    mb, pend, rows, todo = scratch
    t0, t1 = _clip(lo, hi, o, d, tmin, tmax)
    if not (t0 <= t1):
        return 0
    for s in range(MAILBOX):
        mb[s] = -1
    sh = ray_shear((o[0], o[1], o[2]), (d[0], d[1], d[2]))
    ox, oy, oz = o[0], o[1], o[2]
    dx, dy, dz = d[0], d[1], d[2]
    nx, ny, nz = dims[0], dims[1], dims[2]
    mx, my, mz = mdims[0], mdims[1], mdims[2]
    cx, cy, cz = cell[0], cell[1], cell[2]
    bx, by, bz = k * cx, k * cy, k * cz
    mi = _index(ox + t0 * dx, lo[0], bx, mx)
    mj = _index(oy + t0 * dy, lo[1], by, my)
    mk = _index(oz + t0 * dz, lo[2], bz, mz)
    msx, mtx, mdtx = _axis(ox, dx, lo[0], bx, mi)
    msy, mty, mdty = _axis(oy, dy, lo[1], by, mj)
    msz, mtz, mdtz = _axis(oz, dz, lo[2], bz, mk)
    # (typed as the counts they become: a literal 0 would compile _test_lanes once more)
    nh = np.int64(0)
    npend = np.int64(0)
    nt = np.int64(0)
    tin = t0
    while True:
        tout = min(mtx, mty, mtz)
        m = mi + mx * (mj + my * mk)
        if macro_full[m] != 0:
            if leaf_first is not None:   # the top cell's own leaf grid
                blo, bsz, i0, i1, base, st = _leaf_block(g, m, (mi, mj, mk))
            else:     # the macro cell's k^3 cells of the grid
                blo = (lo[0], lo[1], lo[2])
                bsz = (cx, cy, cz)
                i0 = (np.int64(mi * k), np.int64(mj * k), np.int64(mk * k))
                i1 = (np.int64(min(i0[0] + k, nx) - 1), np.int64(min(i0[1] + k, ny) - 1),
                      np.int64(min(i0[2] + k, nz) - 1))
                base, st = np.int64(0), (np.int64(1), np.int64(nx), np.int64(nx * ny))
            x0, y0, z0 = i0
            x1, y1, z1 = i1
            ix = min(max(_index(ox + tin * dx, blo[0], bsz[0], x1 + 1), x0), x1)
            iy = min(max(_index(oy + tin * dy, blo[1], bsz[1], y1 + 1), y0), y1)
            iz = min(max(_index(oz + tin * dz, blo[2], bsz[2], z1 + 1), z0), z1)
            sx, tx, dtx = _axis(ox, dx, blo[0], bsz[0], ix)
            sy, ty, dty = _axis(oy, dy, blo[1], bsz[1], iy)
            sz, tz, dtz = _axis(oz, dz, blo[2], bsz[2], iz)
            tend = min(tout, t1)
            c = base + ix * st[0] + iy * st[1] + iz * st[2]
            while True:
                prefetch_range(cs, c)
                todo[nt] = c
                nt += 1
                if nt == CELLS:
                    nh, npend = _visit_cells(g, todo, nt, sh, tmin, tmax, nh, npend, buf, scratch)
                    if nh < 0:
                        return -1
                    nt = 0
                if tx <= ty and tx <= tz:
                    stop, ix, tx = _advance(ix, sx, tx, dtx, x0, x1, tend)
                elif ty <= tz:
                    stop, iy, ty = _advance(iy, sy, ty, dty, y0, y1, tend)
                else:
                    stop, iz, tz = _advance(iz, sz, tz, dtz, z0, z1, tend)
                if stop:
                    break
                c = base + ix * st[0] + iy * st[1] + iz * st[2]
        # the next macro cell, entered at tout
        if mtx <= mty and mtx <= mtz:
            stop, mi, mtx = _advance(mi, msx, mtx, mdtx, 0, mx - 1, t1)
        elif mty <= mtz:
            stop, mj, mty = _advance(mj, msy, mty, mdty, 0, my - 1, t1)
        else:
            stop, mk, mtz = _advance(mk, msz, mtz, mdtz, 0, mz - 1, t1)
        if stop:
            break
        tin = tout
    if nt:
        nh, npend = _visit_cells(g, todo, nt, sh, tmin, tmax, nh, npend, buf, scratch)
        if nh < 0:
            return -1
    if npend:
        nh = _test_lanes(tris, pend, npend, rows, sh, tmin, tmax, nh, buf)
    return nh


@inner(cache=True, _nrt=False)
def _visit_cells(g, todo, n, sh, tmin, tmax, nh, npend, buf, scratch):
    """The triangles of the cells todo[:n] that the mailbox has not seen, added to the ones
    collected (scratch.pend[:npend]) and tested LANES at a time: (hits so far or -1, collected
    and not yet tested).  On a large mesh (g.prefetch) the loads of the cells' reference lists
    start first, then those of their triangles, each for all n cells before the next: the cache
    misses of a ray's cells overlap (the ray has no early exit, so its cells are known)."""
    tris, cs, tri_ids = g.tris, g.cs, g.tri_ids
    mb, pend, rows, _ = scratch
    L = cs.shape[0]
    if g.prefetch:
        for k in range(n):
            for l in range(L):
                prefetch_ids(tri_ids, cs[l, todo[k]])
        for k in range(n):
            prefetch_triangles(tris, tri_ids, cs, todo[k])
    for k in range(n):
        c = todo[k]
        for l in range(L):
            for r in range(cs[l, c], cs[l, c + 1]):
                f = tri_ids[r]
                slot = f & (MAILBOX - 1)
                if mb[slot] == f:
                    continue
                mb[slot] = f
                pend[npend] = f
                npend += 1
                if npend == LANES:
                    nh = _test_lanes(tris, pend, npend, rows, sh, tmin, tmax, nh, buf)
                    if nh < 0:
                        return nh, npend
                    npend = 0
    return nh, npend


@inner(cache=True)
def sort_hits(bt, bf, bu, bv, n):
    """Sort the first n hits by t, ties by triangle id (insertion sort: a ray's hits are few)."""
    for i in range(1, n):
        t, f, u, v = bt[i], bf[i], bu[i], bv[i]
        j = i - 1
        while j >= 0 and (bt[j] > t or (bt[j] == t and bf[j] > f)):
            bt[j + 1], bf[j + 1], bu[j + 1], bv[j + 1] = bt[j], bf[j], bu[j], bv[j]
            j -= 1
        bt[j + 1], bf[j + 1], bu[j + 1], bv[j + 1] = t, f, u, v


@njit(cache=True, nogil=True)
def count_kernel(g, rays, cap, chunks, counts, nxt):
    """counts[i]: the hits of ray i of the :data:`HitRays` rays (in the grid's frame) in the
    :data:`HitGrid` g; -1 for a ray with more than ``cap`` hits.  The rays go in ``chunks`` runs:
    each call takes the next (an atomic add on nxt (1,) int64, the runs taken so far) until none is
    left, so that calls on several threads share the rays (_on_chunks)."""
    O, D, tmin, tmax = rays
    N = len(O)
    buf = HitBuffers(np.empty(cap), np.empty(cap, np.int32), np.empty(cap), np.empty(cap))
    scratch = hit_scratch()
    while True:
        part = atomic_add(nxt, 0, np.int64(1))
        if part >= chunks:
            break
        for i in range(part * N // chunks, (part + 1) * N // chunks):
            counts[i] = ray_hits(g, O[i], D[i], tmin[i], tmax[i], buf, scratch, g.leaf_first)


@njit(cache=True, nogil=True)
def slot_kernel(g, rays, cap, chunks, counts, slots, nxt):
    """One walk a ray: counts[i] as count_kernel's (-1 above ``cap``), and ray i's nearest K hits,
    sorted, into row i of the :data:`HitBuffers` slots ((N, K) each; K = slots.t.shape[1]): the
    first min(counts[i], K) entries of the row hold hits.  The rays in runs, as count_kernel's."""
    O, D, tmin, tmax = rays
    st, sf, su, sv = slots
    K = st.shape[1]
    N = len(O)
    buf = HitBuffers(np.empty(cap), np.empty(cap, np.int32), np.empty(cap), np.empty(cap))
    bt, bf, bu, bv = buf
    scratch = hit_scratch()
    while True:
        part = atomic_add(nxt, 0, np.int64(1))
        if part >= chunks:
            break
        for i in range(part * N // chunks, (part + 1) * N // chunks):
            nh = ray_hits(g, O[i], D[i], tmin[i], tmax[i], buf, scratch, g.leaf_first)
            counts[i] = nh
            if nh > 0:
                sort_hits(bt, bf, bu, bv, nh)
                for j in range(min(nh, K)):
                    st[i, j], sf[i, j], su[i, j], sv[i, j] = bt[j], bf[j], bu[j], bv[j]


def _on_chunks(kernel, threads, g, rays, cap, chunks, *out):
    """count_kernel or slot_kernel over ``chunks`` runs of the rays, on up to ``threads`` threads
    (gridrt.threads.on_threads; numba's parallel loop would compile the whole walk a second time):
    the same counts and hits on any number of threads, as each ray's are its own."""
    nxt = np.zeros(1, np.int64)
    on_threads(max(1, min(threads, chunks)), lambda k: kernel(g, rays, cap, chunks, *out, nxt))


#: one worker's scratch for ray_hits: the mailbox (MAILBOX,) int32, the triangles collected for the
#: next side-by-side test (LANES,) int32, that test's rows (LANE_ROWS * LANES,) float64, and the
#: cells listed for the next visit (CELLS,) int64
HitScratch = namedtuple("HitScratch", "mb pend rows todo")


@inner(cache=True)
def hit_scratch():
    """A fresh :data:`HitScratch`."""
    return HitScratch(np.empty(MAILBOX, np.int32), np.empty(LANES, np.int32), np.zeros(LANE_ROWS * LANES),
                      np.empty(CELLS, np.int64))


#: the grid as the all-hits kernels take it: the grid's (F, 3, 3) float32 triangles, its box lo,
#: hi, cell size and dims, macro size k, macro dims and flags, one CSR of triangle ids over its
#: cells (a two-level grid's leaf cells): cs (L, C + 1) int32, tri_ids (R,) int32, and a two-level
#: grid's leaf_first (T + 1,) and leaf_res (T, 3) int32 (gridrt.grid.two_level; None for a uniform
#: grid); prefetch: whether the walk starts the loads of its cells' references and triangles before
#: it tests them (PREFETCH_TRIANGLES)
HitGrid = namedtuple("HitGrid", "tris lo hi cell dims k mdims macro_full cs tri_ids leaf_first leaf_res prefetch")
#: the rays: origins and directions (N, 3) float64 in the grid's frame, t bounds (N,) float64
HitRays = namedtuple("HitRays", "O D tmin tmax")
#: one worker's scratch: t, triangle, u, v of a ray's hits so far
HitBuffers = namedtuple("HitBuffers", "t tri u v")


@njit(cache=True, parallel=True)
def order_keys(O, D, lo, scale, keys):
    """keys[i] (int64) of ray i: the class of its direction (major axis and sign, 6 classes) above
    the Morton code of its origin on a 1024^3 lattice over the grid box (lo, cells of 1 / scale,
    clamped): rays from nearby origins in similar directions get nearby keys."""
    for i in prange(len(O)):
        cls, _ = direction_class(D[i, 0], D[i, 1], D[i, 2])
        key = np.int64(cls)
        code = np.int64(0)
        for a in range(3):
            x = (O[i, a] - lo[a]) * scale[a]
            q = np.int64(min(max(x, 0.0), 1023.0))
            q = (q | (q << 16)) & 0x030000FF
            q = (q | (q << 8)) & 0x0300F00F
            q = (q | (q << 4)) & 0x030C30C3
            q = (q | (q << 2)) & 0x09249249
            code |= q << a
        keys[i] = (key << 30) | code


# ---- the Python boundary: every check before a kernel runs --------------------------------------
#: count_hits and all_hits take a batch's rays in the order of order_keys (nearby rays one after
#: another: their cells and triangles stay in the caches) when it has at least ORDER_RAYS rays and
#: the mesh at least ORDER_TRIANGLES triangles: a mesh whose rays wait on memory, and enough rays to
#: pay for the sort and the reordering, which run on one thread (measured: BENCHMARKS.md section 18)
ORDER_RAYS, ORDER_TRIANGLES = 200_000, 1_000_000
#: hits a ray may have before its count is taken again with room for every triangle
FIRST_CAP = 1024
#: all_hits keeps this many hits a ray in its first walk (a ray with more is walked again with room
#: for all of them), over blocks of SLOT_BLOCK rays: a bounded scratch of 28 * SLOT_HITS bytes a ray
SLOT_HITS, SLOT_BLOCK = 8, 1 << 16


class AllHits(NamedTuple):
    """Every hit of every ray: ray i's hits are ``t[offsets[i]:offsets[i + 1]]`` (and the same
    slice of tri, u, v), sorted by t; offsets (N + 1,) int64, t float64, tri int32 (the mesh's
    triangle index), u, v float64 barycentrics (p = (1 - u - v) v0 + u v1 + v v2)."""

    offsets: np.ndarray
    t: np.ndarray
    tri: np.ndarray
    u: np.ndarray
    v: np.ndarray

    def counts(self):
        """Hits per ray, (N,) int64."""
        return np.diff(self.offsets)


def t_bounds(name, value, n):
    try:
        a = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        a = None
    if a is None or a.ndim > 1 or (a.ndim == 1 and len(a) != n):
        raise InputError(f"{name} must be a number or an array of one number a ray ({n}), got "
                         f"{'shape ' + str(a.shape) if a is not None else repr(value)}")
    return np.ascontiguousarray(np.broadcast_to(a, (n,)), np.float64)


def query_hits(grid, tris, origins, dirs, origin, t_min, t_max, max_hits=None, threads=None, count_only=False):
    """The hits (AllHits) or, with ``count_only``, the hit counts ((N,) int64) of rays ``origins``,
    ``dirs`` (N, 3) in world coordinates against ``grid`` over its own (F, 3, 3) float32 ``tris``
    in the frame at ``origin`` ((3,) float64); t_min, t_max: numbers or (N,) arrays;
    ``max_hits``: keep each ray's nearest ones only (None: all)."""
    o, d = check_rays(origins, dirs)
    N = len(o)
    check_ray_values(o, d, 0, origin)
    tmin, tmax = t_bounds("t_min", t_min, N), t_bounds("t_max", t_max, N)
    bad = np.isnan(tmin) | np.isnan(tmax) | (tmin < 0) | (tmax < tmin)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise InputError(f"need 0 <= t_min <= t_max, got t_min={tmin[i]}, t_max={tmax[i]} for ray {i}")
    if max_hits is not None and (isinstance(max_hits, bool) or not isinstance(max_hits, (int, np.integer))
                                 or max_hits < 1):
        raise InputError(f"max_hits must be a whole number >= 1 or None, got {max_hits!r}")
    threads = check_threads(threads)
    F = len(tris)
    order = N >= ORDER_RAYS and F >= ORDER_TRIANGLES
    check_fits((144 if order else 64) * N, f"finding every hit of {N:,} rays",
               "rays in float64, t bounds and counts" + (", and the rays in a cache-friendly order" if order else ""),
               "cast fewer rays at a time")
    O = np.ascontiguousarray(o, np.float64) - np.asarray(origin, np.float64)
    D = np.ascontiguousarray(d, np.float64)
    s = grid.spec
    lo, hi = np.ascontiguousarray(s.lo, np.float64), np.ascontiguousarray(s.hi, np.float64)
    use_threads(threads)
    perm = None
    if order:
        keys = np.empty(N, np.int64)
        with launch_guard():
            order_keys(O, D, lo, 1024.0 / np.maximum(hi - lo, 1e-300), keys)
        perm = np.argsort(keys)
        del keys
        O, D, tmin, tmax = O[perm], D[perm], tmin[perm], tmax[perm]
    cell, dims = np.ascontiguousarray(s.cell, np.float64), np.ascontiguousarray(s.dims, np.int64)
    cs = np.ascontiguousarray(grid.cell_start, np.int32)
    if grid.kind == "two_level":   # the leaf cells of each top cell, walked in its own DDA
        leaf_first = np.ascontiguousarray(grid.leaf_first, np.int32)
        leaf_res = np.ascontiguousarray(grid.leaf_res, np.int32)
    else:
        leaf_first, leaf_res = None, None
    ids = np.ascontiguousarray(grid.tri_ids, np.int32)
    chunks = max(1, min(N, 4 * threads))
    counts = np.zeros(N, np.int64)
    g = HitGrid(tris, lo, hi, cell, dims, int(s.macro), np.ascontiguousarray(s.mdims, np.int64),
                np.ascontiguousarray(grid.macro_full, np.uint8), cs, ids, leaf_first, leaf_res,
                len(tris) >= PREFETCH_TRIANGLES)
    rays = _rays(O, D, tmin, tmax)
    with launch_guard():
        if count_only:
            if N:
                _on_chunks(count_kernel, threads, g, rays, min(F, FIRST_CAP), chunks, counts)
                _recount(g, rays, counts, F, threads)
            return counts if perm is None else _unpermuted(counts, perm)
        hits = _all_hits(g, rays, counts, F, chunks, threads, max_hits)
        return hits if perm is None else _unpermuted_hits(hits, perm)


def _unpermuted(a, perm):
    """a's rows back in the caller's order: row k of a belongs to ray perm[k]."""
    out = np.empty_like(a)
    out[perm] = a
    return out


def _unpermuted_hits(h, perm):
    """The AllHits h of the rays perm (h's ray k is ray perm[k]) in the caller's order."""
    n = np.diff(h.offsets)
    total = int(h.offsets[-1])
    check_fits(36 * total, f"putting {total:,} hits back in the order of their rays", "t, triangle ids, "
               "barycentrics and where each goes", "cast fewer rays at a time, or give max_hits")
    offsets = np.zeros(len(n) + 1, np.int64)
    np.cumsum(_unpermuted(n, perm), out=offsets[1:])
    # hit j of sorted ray k goes to offsets[perm[k]] + j
    dest = np.repeat(offsets[perm] - h.offsets[:-1], n) + np.arange(total, dtype=np.int64)
    flat = []
    for a in (h.t, h.tri, h.u, h.v):
        b = np.empty_like(a)
        b[dest] = a
        flat.append(b)
    return AllHits(offsets, *flat)


def _recount(g, rays, counts, F, threads):
    """counts of the rays whose count is -1 (more hits than the first scratch held), again with room
    for every triangle."""
    many = np.flatnonzero(counts < 0)
    if len(many):
        sub = np.zeros(len(many), np.int64)
        _on_chunks(count_kernel, threads, g, _take(rays, many), F, max(1, min(len(many), threads)), sub)
        counts[many] = sub
    return many


def _take(rays, idx):
    return _rays(*(a[idx] for a in rays))


def _rays(*arrays):
    """HitRays of read-only views of the arrays: the caller's arrays (read-only or not) or copies
    made here, the kernels compile once (numba types read-only arrays apart)."""
    return HitRays(*(read_only(a) for a in arrays))


def _slots(n, k):
    return HitBuffers(np.empty((n, k)), np.empty((n, k), np.int32), np.empty((n, k)), np.empty((n, k)))


def _all_hits(g, rays, counts, F, chunks, threads, max_hits):
    """AllHits of the rays: blocks of SLOT_BLOCK rays walked once each (slot_kernel keeps SLOT_HITS
    hits a ray), the rays with more hits than that walked again with room for all; then the rows'
    hits, in ray order, into flat arrays (at most max_hits a ray)."""
    N = len(counts)
    keep = SLOT_HITS if max_hits is None else min(SLOT_HITS, max_hits)
    parts = []
    for s in range(0, N, SLOT_BLOCK):
        e = min(N, s + SLOT_BLOCK)
        block = _take(rays, slice(s, e))
        slots = _slots(e - s, keep)
        _on_chunks(slot_kernel, threads, g, block, min(F, FIRST_CAP), max(1, min(e - s, chunks)), counts[s:e], slots)
        over = _recount(g, block, counts[s:e], F, threads)   # (their slots were not written)
        n = counts[s:e] if max_hits is None else np.minimum(counts[s:e], max_hits)
        full = n > keep   # rays whose hits the slots do not all hold
        full[over] = True
        if not full.any():
            mask = np.arange(keep)[None, :] < n[:, None]
            rows = [a[mask] for a in slots]
        else:   # those rays walked again, with room for all their hits
            idx = np.flatnonzero(full)
            wide = _slots(len(idx), int(n[idx].max()))
            cap = int(counts[s:e][idx].max())   # (room for every hit, to sort them)
            _on_chunks(slot_kernel, threads, g, _take(block, idx), cap, max(1, min(len(idx), threads)),
                       np.zeros(len(idx), np.int64), wide)
            at = np.zeros(e - s, np.int64)
            np.cumsum(n[:-1], out=at[1:])
            mask = (np.arange(keep)[None, :] < n[:, None]) & ~full[:, None]
            to = (at[:, None] + np.arange(keep)[None, :])[mask]
            wmask = np.arange(wide.t.shape[1])[None, :] < n[idx][:, None]
            wto = (at[idx][:, None] + np.arange(wide.t.shape[1])[None, :])[wmask]
            rows = []
            for a, w in zip(slots, wide):
                r = np.empty(int(n.sum()), a.dtype)
                r[to], r[wto] = a[mask], w[wmask]
                rows.append(r)
        parts.append((n, rows))
    kept = np.concatenate([p[0] for p in parts]) if parts else np.zeros(0, np.int64)
    offsets = np.zeros(N + 1, np.int64)
    np.cumsum(kept, out=offsets[1:])
    total = int(offsets[-1])
    check_fits(28 * total, f"keeping {total:,} hits of {N:,} rays", "t, triangle ids and barycentrics",
               "cast fewer rays at a time, or give max_hits")
    flat = [np.concatenate([p[1][k] for p in parts]) if parts else np.empty(0, dt)
            for k, dt in enumerate((np.float64, np.int32, np.float64, np.float64))]
    return AllHits(offsets, *flat)
