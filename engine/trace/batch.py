"""Batch casting of arbitrary rays: coherent groups of rays as CGT packets, the rest one at a time.

A batch (``cast_rays``, ``RayCaster.cast``) is cast in two passes over groups of up to
:data:`RUN` rays:

1. the rays in the caller's order, in runs of RUN: camera rays in pixel order, the shadow rays of
   a block of pixels and the like arrive coherent.  When the rays look like the pixels of an image
   in row order (:func:`image_width`: neighbours in the list and one row apart are neighbours,
   and the list jumps at every row's end), the runs are TILE x TILE squares of that image
   (:func:`tile_order`) instead of strips of one row, which make packets several times narrower
   (measured: BENCHMARKS.md section 13).  A run that is coherent (its rays agree on the
   major axis of their direction and its sign) and narrow (its bounds, those the packet traversal
   uses, cover at most ``max_cells`` cells in the widest slice they cross) is traced as one CGT
   packet (:func:`gridrt.trace.cgt.trace_packet`); the others are left for pass 2;
2. the rays left, sorted by a key (:func:`sort_keys`: the permutation class of the direction, the
   macro cell of the origin, then the direction's slopes on a Morton curve), again in runs of RUN:
   rays the caller shuffled come together again.  A run that passes the same test is a packet,
   the other rays are traced one at a time (:func:`gridrt.trace.traverse.trace_ray`).  When the
   rays left are all over the place (not sorted) on a uniform grid of at least
   ``STREAM_TRIANGLES`` triangles, they are traced one at a time but several interleaved
   (:func:`stream_runs`, gridrt.trace.stream), so that their cache misses overlap; a cast that
   asks for no packets (``max_cells`` <= 0) takes the same path there.

Results do not depend on the order or grouping of the rays: the packet loops repeat the single
ray's intersection arithmetic operation for operation and both give a tie (two triangles hit at
the same t) to the lower triangle index, so a ray's t, triangle, u and v are the same whichever
way it is traced (u and v of a packet hit are recomputed by the single-ray test of the triangle
hit).  With ``any_hit`` a ray that hits anything in (tmin, tmax) is reported with a hit either
way; which hit is reported may depend on the way.

With the packets' tests in float32 (``packet_precision="float32"``) a packet picks each ray's
triangle in float32; its t, u and v are then the float64 test's of that triangle, and a ray whose
triangle the float64 test misses (float32 rounding at an edge or at tmax) is traced again on its
own in float64.  Hits may then depend on the grouping, but only at near-ties and within float32
rounding of an edge.
"""

import numba
import numpy as np
from numba import njit, prange

from ..compiles import inner
from ..grid.atomics import atomic_add
from ..threads import on_threads
from .cgt import (IO_DX, IO_DY, IO_DZ, IO_F, IO_OX, IO_OY, IO_OZ, IO_TMAX, MBOX, NIO, NS, PN, PacketQuery,
                  direction_class, trace_packet)
from .intersect import ray_shear
from .query import HitArrays, PacketScratch, cast_pass, query
from .stream import STREAM_TRIANGLES, stream_rays, stream_scratch
from .traverse import (MOVED, NEAR, SCRATCH, TINY_DIR, _floor_clamp, _test_triangle, far_interval, far_shift, far_t,
                       is_far, trace_ray)

#: rays in a run (a packet's worth; at most cgt.PN)
RUN = 64
#: a run of rays is traced as a packet when its bounds cover at most this many cells in the
#: widest slice (measured: BENCHMARKS.md, "Batch casts")
MAX_CELLS = 32.0
#: the same for the material pass's shadow rays (gridrt.trace.render), which start from a tile's hit
#: points rather than from one eye: a run wider than this goes through the single-ray DDA (measured:
#: BENCHMARKS.md section 15, "Shadow rays as packets")
SHADOW_MAX_CELLS = 8.0
#: the bound for the shadow rays pass 1 leaves, once sorted (cast_grouped's ``sorted_max_cells``):
#: sorted by direction from the light they share, the runs are coherent and wide packets pay
#: (measured: BENCHMARKS.md section 15, "Hard shadows of point lights: the casts alone")
SHADOW_SORTED_MAX_CELLS = MAX_CELLS
#: runs per work item, the batch's share that a thread takes at a time (cast_runs)
GROUPS_PER_ITEM = 16
#: bits of each slope in the sort key's Morton code
SLOPE_BITS = 10
#: the rays left by pass 1 are sorted when they average at least MIN_PER_BIN rays per bin of
#: slopes cut to COARSE_BITS bits (rays_per_bin)
COARSE_BITS = 5
MIN_PER_BIN = 16.0
NO_ROWS = np.zeros(0, np.int64)
NO_LEFT = np.zeros(0, np.uint8)
NO_COUNTS = np.zeros((2, 0), np.int64)


@inner(cache=True, _nrt=False)
def _single(g, origins, dirs, i, q, mb1, out):
    """Ray i traced on its own (trace_ray, the :class:`Query` q, mailbox mb1) into row i of the
    :class:`HitArrays` out."""
    f, t, u, v, nc, nt = trace_ray(g, (origins[i, 0], origins[i, 1], origins[i, 2]),
                                   (dirs[i, 0], dirs[i, 1], dirs[i, 2]), q.tmin, q.tmax, q.watertight, q.any_hit, mb1)
    out.t[i] = t
    out.tri[i] = f
    out.u[i] = u
    out.v[i] = v


@inner(cache=True, _nrt=False)
def _one_class(dirs, idx, s, n, use_idx):
    """Whether rays idx[s:s+n] (s..s+n-1 when not use_idx) all have the same permutation class
    (major axis of the direction and its sign: cgt.direction_class).  A run that fails this
    cannot be a packet (its rays that meet the grid may still agree, but runs of arbitrary rays,
    which is what fails here, almost never do), so it is left without gathering it."""
    cmin = 6
    cmax = -1
    for j in range(n):
        i = idx[s + j] if use_idx else s + j
        c, _ = direction_class(dirs[i, 0], dirs[i, 1], dirs[i, 2])
        cmin = min(cmin, c)
        cmax = max(cmax, c)
    return cmin == cmax


@inner(cache=True, _nrt=False, error_model="numpy")
def _cast_run(g, origins, dirs, idx, s, n, q, how, scratch, out):
    """Rays idx[s:s+n] (rays s..s+n-1 when idx is empty) for the :class:`Query` q, as the
    :class:`CastPass` ``how`` says: as one packet when they make one (see the module docstring;
    never when how.max_cells <= 0), its triangle tests in float32 with how.f32; otherwise one at
    a time (how.singly) or flagged in out.left.  Results go to the :class:`HitArrays` out, the
    :class:`PacketScratch` ``scratch`` is the worker's.  Returns the number of rays traced as a
    packet (n or 0)."""
    tmin, tmax, watertight, any_hit = q.tmin, q.tmax, q.watertight, q.any_hit
    max_cells, f32 = how.max_cells, how.f32
    io, mb1 = scratch.io, scratch.mb1
    use_idx = idx.shape[0] > 0
    r = -1
    if max_cells > 0.0 and _one_class(dirs, idx, s, n, use_idx):
        for j in range(n):
            i = idx[s + j] if use_idx else s + j
            io[IO_OX * PN + j] = origins[i, 0]
            io[IO_OY * PN + j] = origins[i, 1]
            io[IO_OZ * PN + j] = origins[i, 2]
            io[IO_DX * PN + j] = dirs[i, 0]
            io[IO_DY * PN + j] = dirs[i, 1]
            io[IO_DZ * PN + j] = dirs[i, 2]
            io[IO_TMAX * PN + j] = tmax
        r = trace_packet(g, n, io, PacketQuery(tmin, watertight, any_hit, f32, True), scratch.S, scratch.mb, max_cells, None)
    if r < 0:
        for j in range(n):
            i = idx[s + j] if use_idx else s + j
            if how.singly:
                _single(g, origins, dirs, i, q, mb1, out)
            else:
                out.left[i] = 1
        return 0
    tris = g.tris
    for j in range(n):
        i = idx[s + j] if use_idx else s + j
        f = int(io[IO_F * PN + j])
        out.tri[i] = f
        if f < 0:
            out.t[i] = np.inf
            out.u[i] = 0.0
            out.v[i] = 0.0
            continue
        if how.tri_only and not f32:
            continue  # the float64 packet's test is the single ray's: its triangle is hit in range
        # the single-ray test of the triangle hit: the packet's t bit for bit, and u, v (from
        # where the packet traced the ray: a far one from just before the grid box)
        ox, oy, oz = origins[i, 0], origins[i, 1], origins[i, 2]
        dx, dy, dz = dirs[i, 0], dirs[i, 1], dirs[i, 2]
        verdict = NEAR
        mx = my = mz = th = tl = 0.0
        if is_far(g.lo, g.hi, ox, oy, oz):
            verdict, mx, my, mz, th, tl = far_shift(g.lo, g.hi, ox, oy, oz, dx, dy, dz)
        t_lo = tmin
        if verdict == MOVED:
            ox, oy, oz = mx, my, mz
            t_lo = far_interval(tmin, np.inf, th, tl)[0]
        o = (ox, oy, oz)
        d = (dx, dy, dz)
        hit, t, u, v = _test_triangle(tris, f, watertight, ray_shear(o, d), o, d, t_lo, np.inf)
        if verdict == MOVED:
            t = far_t(t, th, tl)
        if f32 and not (hit and t < tmax):
            # the float32 tests chose a triangle the float64 test misses (within float32 rounding
            # of an edge or of tmax): the ray goes again in float64, on its own
            _single(g, origins, dirs, i, q, mb1, out)
            continue
        out.t[i] = t
        out.u[i] = u
        out.v[i] = v
    return n


@njit(cache=True, error_model="numpy", nogil=True)
def cast_runs_kernel(g, origins, dirs, idx, q, how, out, nxt):
    """Pass 1 (idx empty: the rays in order, how.singly False) or pass 2 (idx: the rays left,
    sorted; how.singly True) of a batch cast (the :class:`Query` q, the :class:`CastPass` how)
    over the grid g (GridArrays), in runs of RUN rays, into the :class:`HitArrays` out of (N,)
    arrays (pass 1 sets out.left to 1 for the rays it leaves).  The runs go in work items of
    GROUPS_PER_ITEM runs, and each call takes the next item (an atomic add on nxt (1,) int64, the
    items taken so far) until none is left, so that calls on several threads share the batch
    (cast_runs).  Returns the number of rays this call traced in packets."""
    M = idx.shape[0] if idx.shape[0] > 0 else origins.shape[0]
    nruns = (M + RUN - 1) // RUN
    nitems = (nruns + GROUPS_PER_ITEM - 1) // GROUPS_PER_ITEM
    scratch = PacketScratch(np.empty(NIO * PN), np.empty(NS * PN), np.empty(MBOX, np.int32),
                            np.empty(SCRATCH, np.int32))
    total = 0
    while True:
        it = atomic_add(nxt, 0, np.int64(1))
        if it >= nitems:
            break
        for run in range(it * GROUPS_PER_ITEM, min((it + 1) * GROUPS_PER_ITEM, nruns)):
            s = run * RUN
            total += _cast_run(g, origins, dirs, idx, s, min(RUN, M - s), q, how, scratch, out)
    return total


@njit(cache=True, nogil=True)
def stream_runs_kernel(g, origins, dirs, idx, q, out, counts, nxt):
    """The rays idx (all rays when idx is empty) traced one at a time, interleaved
    (:func:`gridrt.trace.stream.stream_rays`), into the :class:`HitArrays` out (and each ray's
    cells visited and triangle tests into counts, (2, N) int64, unless it is (2, 0)), in work items
    of RUN * GROUPS_PER_ITEM rays taken as cast_runs_kernel takes its items."""
    M = idx.shape[0] if idx.shape[0] > 0 else origins.shape[0]
    per = RUN * GROUPS_PER_ITEM
    nitems = (M + per - 1) // per
    sc = stream_scratch()
    while True:
        it = atomic_add(nxt, 0, np.int64(1))
        if it >= nitems:
            break
        s = it * per
        stream_rays(g, origins, dirs, idx, s, min(per, M - s), q, sc, out, counts)


def streams(g):
    """Whether a batch cast traces the rays it takes one at a time interleaved
    (:func:`stream_runs`): on uniform grids of at least STREAM_TRIANGLES triangles."""
    return len(g.tris) >= STREAM_TRIANGLES and (g.leaf_first is None or len(g.leaf_first) == 0)


def stream_runs(g, origins, dirs, idx, q, out, counts=NO_COUNTS):
    """stream_runs_kernel on the threads cast_runs would use (the same hits on any number of
    threads)."""
    threads, nxt = _work_items(origins, idx)
    on_threads(threads, lambda k: stream_runs_kernel(g, origins, dirs, idx, q, out, counts, nxt))


def _work_items(origins, idx):
    """(threads, counter) for a batch's work items of RUN * GROUPS_PER_ITEM rays (the rays idx,
    every ray when it is empty): the calling thread's numba thread count, at most one a work item,
    and the (1,) int64 counter of the items taken."""
    M = idx.shape[0] if idx.shape[0] > 0 else origins.shape[0]
    items = -(-M // (RUN * GROUPS_PER_ITEM))
    return max(1, min(numba.get_num_threads(), items)), np.zeros(1, np.int64)


def cast_runs(g, origins, dirs, idx, q, how, out):
    """cast_runs_kernel on the calling thread's numba thread count (gridrt.threads.use_threads) of
    threads, at most one a work item (gridrt.threads.on_threads): the same hits on any number of
    threads, as each ray's are its own.  Returns the rays traced in packets.  (Python threads
    around one kernel: numba's parallel loop would compile the whole call tree a second time.)"""
    threads, nxt = _work_items(origins, idx)
    return sum(on_threads(threads, lambda k: cast_runs_kernel(g, origins, dirs, idx, q, how, out, nxt)))


@njit(cache=True, error_model="numpy")
def odd_directions(dirs):
    """Indices (int64) of the rays of dirs (N, 3) float64 whose largest direction component lies
    below 2**-101 or at or above 2**100 (cast_batch rescales them by powers of two).  Two passes,
    no temporaries the size of the batch."""
    n = 0
    for i in range(dirs.shape[0]):
        n += _odd(dirs[i, 0], dirs[i, 1], dirs[i, 2])
    out = np.empty(n, np.int64)
    k = 0
    if n > 0:
        for i in range(dirs.shape[0]):
            if _odd(dirs[i, 0], dirs[i, 1], dirs[i, 2]):
                out[k] = i
                k += 1
    return out


@inner(cache=True)
def _odd(dx, dy, dz):
    """max(|dx|, |dy|, |dz|) < 2**-101 or >= 2**100, for finite components, without branches."""
    ax, ay, az = abs(dx), abs(dy), abs(dz)
    lo = 2.0**-101
    hi = 2.0**100
    return ((ax < lo) & (ay < lo) & (az < lo)) | ((ax >= hi) | (ay >= hi) | (az >= hi))


@inner(cache=True)
def _spread_bits(x):
    """The low 16 bits of x with a zero bit after each (for a Morton code)."""
    x &= 0xFFFF
    x = (x | (x << 8)) & 0x00FF00FF
    x = (x | (x << 4)) & 0x0F0F0F0F
    x = (x | (x << 2)) & 0x33333333
    return (x | (x << 1)) & 0x55555555


@njit(cache=True, parallel=True, error_model="numpy")
def sort_keys(g, origins, dirs, rows, keys):
    """keys[r] (int64) of ray rows[r]: the permutation class of its direction (major axis and sign,
    6 classes), the macro cell of its origin (clamped to the grid) and its two slopes (minor over
    major component, in [-1, 1]) on a Morton curve of SLOPE_BITS bits each, most significant first."""
    lo, inv_cell, dims, M, mdims = g.lo, g.inv_cell, g.dims, g.macro, g.mdims
    nb = 1 << SLOPE_BITS
    for r in prange(rows.shape[0]):
        i = rows[r]
        ox, oy, oz = origins[i, 0], origins[i, 1], origins[i, 2]
        dx, dy, dz = dirs[i, 0], dirs[i, 1], dirs[i, 2]
        ax, ay, az = abs(dx), abs(dy), abs(dz)
        if ax >= ay and ax >= az:
            K, dk, du, dv = 0, dx, dy, dz
        elif ay >= az:
            K, dk, du, dv = 1, dy, dz, dx
        else:
            K, dk, du, dv = 2, dz, dx, dy
        cls = 2 * K + (1 if dk < 0.0 else 0)
        inv = 1.0 / dk if abs(dk) >= TINY_DIR else 0.0
        bu = min(nb - 1, max(0, int((du * inv + 1.0) * 0.5 * nb)))
        bv = min(nb - 1, max(0, int((dv * inv + 1.0) * 0.5 * nb)))
        mx = _floor_clamp((ox - lo[0]) * inv_cell[0], dims[0]) // M
        my = _floor_clamp((oy - lo[1]) * inv_cell[1], dims[1]) // M
        mz = _floor_clamp((oz - lo[2]) * inv_cell[2], dims[2]) // M
        mc = mx + mdims[0] * (my + mdims[1] * mz)
        keys[r] = (np.int64(cls) << 58) | (np.int64(mc) << (2 * SLOPE_BITS)) | np.int64(
            _spread_bits(bu) | (_spread_bits(bv) << 1))


@njit(cache=True, error_model="numpy")
def rays_per_bin(keys, drop, max_bits):
    """An estimate of the mean number of rays per occupied bin of the keys with their low ``drop``
    bits dropped (linear counting: the bins hashed into a table of 2**bits flags, bits the least
    giving at least two flags a key, at most max_bits; a full table gives 0)."""
    bits = 10
    while bits < max_bits and (1 << bits) < 2 * keys.shape[0]:
        bits += 1
    m = 1 << bits
    seen = np.zeros(m, np.uint8)
    occ = 0
    for r in range(keys.shape[0]):
        h = (np.uint64(keys[r] >> drop) * np.uint64(0x9E3779B97F4A7C15)) >> np.uint64(64 - bits)
        if seen[h] == 0:
            seen[h] = 1
            occ += 1
    if occ >= m:
        return 0.0
    return keys.shape[0] / (-m * np.log(1.0 - occ / m))


#: rays read to recognise an image's rows, and of those, how many for a median (image_width)
ROWS_PROBE = 1 << 16
ROWS_SAMPLE = 1024
#: side of the square tiles pass 1 takes from an image (TILE * TILE = RUN rays)
TILE = 8


def image_width(origins, dirs):
    """(W, c0) when the rays (N,3) look like the pixels of an image of width W >= 2 * TILE in
    row-major order (or column-major: W is then the height), the first ray in column c0: rays
    next to each other in the list, and rays W apart, are neighbours, and the list jumps at every
    W-th ray (a row's end).  (0, 0) otherwise.  Read on the first ROWS_PROBE rays (a median and
    the rows below on a sample of ROWS_SAMPLE of them); the results never depend on it (it only
    decides how pass 1 groups the rays)."""
    K = min(len(dirs), ROWS_PROBE)
    if K < 4 * TILE * TILE:
        return 0, 0
    step = np.empty(K - 1)
    every = max(1, (K - 1) // ROWS_SAMPLE)
    for a in (dirs, origins):  # pinhole cameras differ in direction, orthographic ones in origin
        _steps(a, step)
        m = float(np.median(step[::every]))
        if not (m > 0.0 and np.isfinite(m)):
            continue
        jumps = np.flatnonzero(step > 4.0 * m)
        if len(jumps) < 2:
            return 0, 0
        gaps = np.diff(jumps)
        W = int(np.bincount(gaps).argmax())
        if W < 2 * TILE or W >= K or (gaps == W).mean() < 0.9:
            return 0, 0
        i = np.arange(0, K - W, max(1, (K - W) // ROWS_SAMPLE))
        down = np.abs(a[i + W] - a[i]).sum(axis=1)
        if not float(np.median(down)) <= 4.0 * m:
            return 0, 0
        return W, (W - 1 - int(jumps[0])) % W
    return 0, 0


@njit(cache=True)
def _steps(a, out):
    """out[i] = |a[i + 1] - a[i]| (L1) for the first len(out) + 1 rows of a (N, 3)."""
    for i in range(out.shape[0]):
        out[i] = abs(a[i + 1, 0] - a[i, 0]) + abs(a[i + 1, 1] - a[i, 1]) + abs(a[i + 1, 2] - a[i, 2])


@njit(cache=True)
def tile_order(N, W, c0, out):
    """out (N,) int64: the rays 0..N-1 of a W-wide image whose first ray is in column c0, tile by
    tile (TILE x TILE pixels, row-major within a tile, tiles row-major)."""
    V = N + c0
    H = (V + W - 1) // W
    k = 0
    for ty in range(0, H, TILE):
        for tx in range(0, W, TILE):
            for y in range(ty, min(ty + TILE, H)):
                for x in range(tx, min(tx + TILE, W)):
                    v = y * W + x
                    if v >= c0 and v < V:
                        out[k] = v - c0
                        k += 1
    return k


def pass1_order(origins, dirs):
    """The order pass 1 takes the rays in: TILE x TILE tiles when they look like an image
    (:func:`image_width`: a run of RUN rays is then a square of pixels, not a strip of one row,
    and makes a far narrower packet), else the caller's order (NO_ROWS)."""
    W, c0 = image_width(origins, dirs)
    if W == 0:
        return NO_ROWS
    order = np.empty(len(dirs), np.int64)
    tile_order(len(dirs), W, c0, order)
    return order


def cast_grouped(g, origins, dirs, tmin, tmax, watertight, any_hit, out, max_cells=MAX_CELLS, f32=False,
                 tri_only=False, rows=None, sorted_max_cells=None):
    """Cast the rays (origins, dirs (N,3) float64, checked) through the grid g (GridArrays) into
    out = (t, tri, u, v) as the module docstring describes; ``max_cells`` <= 0 traces every ray
    singly; ``sorted_max_cells`` (None: max_cells) is pass 2's bound for the sorted rays pass 1
    left; f32: the packets' triangle tests in float32; tri_only: the caller reads only tri (see
    :class:`gridrt.trace.query.CastPass`).  rows (int64, non-empty): only those rays, taken in
    that order by pass 1 (out's other rows are left as they are).  Returns (rays traced in packets
    in pass 1, in pass 2)."""
    N = len(origins)
    if N == 0:
        return 0, 0
    max_cells = float(max_cells)
    sorted_max_cells = max_cells if sorted_max_cells is None else float(sorted_max_cells)
    q = query(tmin, tmax, watertight, any_hit)
    # (cast_runs: runs differ in cost, so threads take work items one at a time)
    if max_cells <= 0.0:
        if streams(g):
            stream_runs(g, origins, dirs, NO_ROWS if rows is None else rows, q, HitArrays(*out, NO_LEFT))
        else:
            cast_runs(g, origins, dirs, NO_ROWS if rows is None else rows, q, cast_pass(-1.0, True, f32, tri_only),
                      HitArrays(*out, NO_LEFT))
        return 0, 0
    left = np.zeros(N, np.uint8)
    p1 = cast_runs(g, origins, dirs, pass1_order(origins, dirs) if rows is None else rows, q,
                   cast_pass(max_cells, False, f32, tri_only), HitArrays(*out, left))
    rows = np.flatnonzero(left.view(np.bool_))   # (0/1 bytes read as bools: numpy finds them 7x faster)
    if len(rows) == 0:
        return int(p1), 0
    # (the macro-cell index fits the 38 key bits between the class and the slopes: grids have
    # far fewer cells, GridParams' cell budget)
    keys = np.empty(len(rows), np.int64)
    sort_keys(g, origins, dirs, rows, keys)
    # sorting pays when the rays left crowd into few bins (class, origin's macro cell, slopes to
    # COARSE_BITS bits); rays all over the place are traced one by one in the caller's order,
    # without trying their runs as packets again (pass 1 found such runs incoherent)
    sort = rays_per_bin(keys, 2 * (SLOPE_BITS - COARSE_BITS), 20) >= MIN_PER_BIN
    if sort:
        # stable: rays of equal keys keep the caller's (pass 1's tile) order, and numpy's stable
        # sort (timsort on int64) runs in about half the time of its quicksort on these keys,
        # which arrive in long sorted runs (a tile's rays share a bin)
        rows = rows[np.argsort(keys, kind="stable")]
    elif streams(g):
        # (on large meshes, interleaved: gridrt.trace.stream)
        stream_runs(g, origins, dirs, rows, q, HitArrays(*out, NO_LEFT))
        return int(p1), 0
    p2 = cast_runs(g, origins, dirs, rows, q, cast_pass(sorted_max_cells if sort else -1.0, True, f32, tri_only),
                   HitArrays(*out, NO_LEFT))
    return int(p1), int(p2)
