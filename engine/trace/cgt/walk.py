"""One packet through a grid: the slices, cells and macro cells it visits, the two-level walk,
rays from far outside the grid, incoherent packets split by direction class (trace_packet), and a
packet through a tuple of grids (trace_packet_grids)."""

import math

import numpy as np
from numba import njit

from ...compiles import inner, one_per_types
from ...grid.two_level import _leaf_range, leaf_axis
from ..grids import is_two_level, with_leaves_only
from ..prefetch import _prefetch_tri
from ..traverse import MOVED, NEAR, _floor_clamp, far_interval, far_shift, far_t, is_far
from .profile import (C_CELLS, C_PACKETS, C_SLICES, C_TESTS, P_CELLS, P_MACRO, P_RETIRE, P_SETUP, P_SLICE, P_SPLIT,
                      P_TESTS, _lap, _now, _prof_count)
from .rays import (IO_DX, IO_DY, IO_DZ, IO_F, IO_MV, IO_NC, IO_NT, IO_OX, IO_OY, IO_OZ, IO_SH, IO_SL, IO_T, IO_TMAX,
                   IO_TMO, IO_W, IO_XO, IO_YO, IO_ZO, O_DX, O_IDK, O_OK, O_OU, O_OV, O_OX, O_OY, O_OZ, PN,
                   Packet, _finish, _fix_wt64, _gather, _outside, _reference_plane, _setup, _setup32, _spread, _step,
                   _test_mt, _test_mt32, _test_wt, _test_wt32, _up32, rows32)


#: the distance (in cells along the packet's major axis) at which a batch cast judges a packet's
#: width (trace_packet's max_cells): rays through a scene that fills their view mostly end within it
HORIZON = 32.0
#: bounds are grown by this many cell sizes before cells and triangles are picked (rounding slack;
#: insertion itself grows triangles by INSERT_EPS = 1e-5 cells)
EPS_CELL = 1e-5
#: with float32 tests the bounds are grown by this much more, times the distance D from the
#: packet's reference origin to the far corner of the grid box: a float32 test decides exactly
#: for sheared vertex coordinates rounded by a few float32 ulps (about 3.6e-7 D, from the
#: rounding of the vertices, the origins and the shear), so the ray a float32 test sees can pass
#: that far from the float64 ray; a triangle it crosses must not be culled, or a ray at a shared
#: vertex finds none of its triangles (measured: 1 such hole in 10M star probes on the
#: Armadillo with the float64 margin alone)
EPS32 = 1e-6


@inner(cache=True)
def _strides(K, U, V, nx, ny):
    """Index steps along the axes K, U, V of an nx x ny x nz array of cells stored x fastest."""
    return (1 if K == 0 else (nx if K == 1 else nx * ny), 1 if U == 0 else (nx if U == 1 else nx * ny),
            1 if V == 0 else (nx if V == 1 else nx * ny))


@inner(cache=True)
def _extent(bounds, ha, hb, grow):
    """The packet's (U, V) extent between the K planes at ha and hb from the reference plane, from
    its bounds (cu0, cu1, cv0, cv1, su0, su1, sv0, sv1, see _spread), grown by grow = (eU, eV):
    (ulo, uhi, vlo, vhi)."""
    cu0, cu1, cv0, cv1, su0, su1, sv0, sv1 = bounds
    eU, eV = grow
    ulo = cu0 + min(min(ha * su0, ha * su1), min(hb * su0, hb * su1)) - eU
    uhi = cu1 + max(max(ha * su0, ha * su1), max(hb * su0, hb * su1)) + eU
    vlo = cv0 + min(min(ha * sv0, ha * sv1), min(hb * sv0, hb * sv1)) - eV
    vhi = cv1 + max(max(ha * sv0, ha * sv1), max(hb * sv0, hb * sv1)) + eV
    return ulo, uhi, vlo, vhi


@njit(cache=True, inline="always")
def _cells_of(box, loU, icU, nU, loV, icV, nV):
    """The cells [cu_0, cu_1] x [cv_0, cv_1] of a slice (nU x nV cells of size 1 / icU, 1 / icV
    from loU, loV) that the box (ulo, uhi, vlo, vhi) overlaps."""
    return (_floor_clamp((box[0] - loU) * icU, nU), _floor_clamp((box[1] - loU) * icU, nU),
            _floor_clamp((box[2] - loV) * icV, nV), _floor_clamp((box[3] - loV) * icV, nV))


@inner(cache=True, _nrt=False)
def _any_macro_full(macro_full, mk, mu0, mu1, mv0, mv1, mstK, mstU, mstV):
    """True when a macro cell of slab mk within [mu0, mu1] x [mv0, mv1] holds triangles."""
    for mu in range(mu0, mu1 + 1):
        for mv in range(mv0, mv1 + 1):
            if macro_full[mk * mstK + mu * mstU + mv * mstV] != 0:
                return True
    return False


@inner(cache=True, _nrt=False)
def _prefetch_slice(g, span):
    """Start the loads of the triangles of grid g in the cells span = (ck, stU, stV, cu_0, cu_1,
    cv_0, cv_1) of one slice ([cu_0, cu_1] x [cv_0, cv_1], ck: its first cell's index, stU, stV:
    the index steps along U and V), so that their cache misses overlap instead of queueing."""
    tris, cell_start, tri_ids = g.tris, g.cell_start, g.tri_ids
    ck, stU, stV, cu_0, cu_1, cv_0, cv_1 = span
    for iu in range(cu_0, cu_1 + 1):
        for iv in range(cv_0, cv_1 + 1):
            c = ck + iu * stU + iv * stV
            for l in range(cell_start.shape[0]):
                for r in range(cell_start[l, c], cell_start[l, c + 1]):
                    _prefetch_tri(tris, tri_ids[r])


@inner(cache=True, _nrt=False, error_model="numpy")
def _test_slice(g, span, axes, box, planes, pk, S32, na, prof=None):
    """Test the triangles of grid g in the cells span = (ck, stU, stV, cu_0, cu_1, cv_0, cv_1) of
    one slice (see _prefetch_slice) against the na active rays of the packet pk
    (:class:`gridrt.trace.cgt.rays.Packet`; axes = (U, V, K), its permutation): each once (the
    packet's mailbox mb), unless it lies outside the packet's extent in the slice (box = (ulo,
    uhi, vlo, vhi)) or beyond one of its four bounding planes (planes = (xr, the planes' offsets
    u0, u1, v0, v1 and slopes, see _outside)).  With f32 the tests run in float32 (_test_wt32
    with its float64 fallback, or _test_mt32) on the float32 rows S32 and I32, vertices less the
    reference origin ref (see _setup32); S32 is the packet's pk.S32, an argument of its own so that
    numba drops the float32 tests where it is None (a float64 packet).
    Returns (cells visited, triangle tests, rays hit).  With ``prof`` the tests' cycles go to its
    P_TESTS slot."""
    tris, cell_start, tri_ids = g.tris, g.cell_start, g.tri_ids
    ck, stU, stV, cu_0, cu_1, cv_0, cv_1 = span
    U, V, K = axes
    S, I32, mb, tmin32 = pk.S, pk.I32, pk.mb, pk.tmin32
    watertight, tmin, f32 = pk.q.watertight, pk.q.tmin, pk.q.f32
    rx, ry, rz, ru, rv, rk = pk.ref
    ulo, uhi, vlo, vhi = box
    mmask = mb.shape[0] - 1
    cells = 0
    tests = 0
    hits = 0
    for iu in range(cu_0, cu_1 + 1):
        for iv in range(cv_0, cv_1 + 1):
            c = ck + iu * stU + iv * stV
            cells += 1
            for l in range(cell_start.shape[0]):
                for r in range(cell_start[l, c], cell_start[l, c + 1]):
                    f = tri_ids[r]
                    slot = f & mmask
                    if mb[slot] == f:
                        continue
                    p0u = np.float64(tris[f, 0, U])
                    p1u = np.float64(tris[f, 1, U])
                    p2u = np.float64(tris[f, 2, U])
                    if max(p0u, max(p1u, p2u)) < ulo or min(p0u, min(p1u, p2u)) > uhi:
                        continue
                    p0v = np.float64(tris[f, 0, V])
                    p1v = np.float64(tris[f, 1, V])
                    p2v = np.float64(tris[f, 2, V])
                    if max(p0v, max(p1v, p2v)) < vlo or min(p0v, min(p1v, p2v)) > vhi:
                        continue
                    p0k = np.float64(tris[f, 0, K])
                    p1k = np.float64(tris[f, 1, K])
                    p2k = np.float64(tris[f, 2, K])
                    mb[slot] = f
                    if _outside((p0u, p0v, p0k), (p1u, p1v, p1k), (p2u, p2v, p2k), planes):
                        continue  # the packet's bounds only shrink: it stays outside
                    tests += 1
                    t0 = _now(prof)
                    if S32 is not None and f32 and watertight:
                        q0u, q0v, q0k = np.float32(p0u - ru), np.float32(p0v - rv), np.float32(p0k - rk)
                        q1u, q1v, q1k = np.float32(p1u - ru), np.float32(p1v - rv), np.float32(p1k - rk)
                        q2u, q2v, q2k = np.float32(p2u - ru), np.float32(p2v - rv), np.float32(p2k - rk)
                        q0 = (np.float32(p0u - ru), np.float32(p0v - rv), np.float32(p0k - rk))
                        q1 = (np.float32(p1u - ru), np.float32(p1v - rv), np.float32(p1k - rk))
                        q2 = (np.float32(p2u - ru), np.float32(p2v - rv), np.float32(p2k - rk))
                        nh, nz = _test_wt32(S32, I32, na, q0, q1, q2, np.int32(f), tmin32)
                        hits += nh
                        if nz > 0:
                            hits += _fix_wt64(S32, I32, na, q0, q1, q2, np.int32(f), tmin32)
                    elif S32 is not None and f32:
                        hits += _test_mt32(
                            S32, I32, na,
                            (np.float32(np.float64(tris[f, 0, 0]) - rx), np.float32(np.float64(tris[f, 0, 1]) - ry),
                             np.float32(np.float64(tris[f, 0, 2]) - rz)),
                            (np.float32(np.float64(tris[f, 1, 0]) - rx), np.float32(np.float64(tris[f, 1, 1]) - ry),
                             np.float32(np.float64(tris[f, 1, 2]) - rz)),
                            (np.float32(np.float64(tris[f, 2, 0]) - rx), np.float32(np.float64(tris[f, 2, 1]) - ry),
                             np.float32(np.float64(tris[f, 2, 2]) - rz)),
                            np.int32(f), tmin32)
                    elif watertight:
                        hits += _test_wt(S, na, (p0u, p0v, p0k), (p1u, p1v, p1k), (p2u, p2v, p2k), np.float64(f), tmin)
                    else:
                        hits += _test_mt(
                            S, na, (np.float64(tris[f, 0, 0]), np.float64(tris[f, 0, 1]), np.float64(tris[f, 0, 2])),
                            (np.float64(tris[f, 1, 0]), np.float64(tris[f, 1, 1]), np.float64(tris[f, 1, 2])),
                            (np.float64(tris[f, 2, 0]), np.float64(tris[f, 2, 1]), np.float64(tris[f, 2, 2])),
                            np.float64(f), tmin)
                    _lap(prof, P_TESTS, t0)
    return cells, tests, hits


@one_per_types
@inner(cache=True, _nrt=False)
def _move_far(g, n, io, far):
    """Rays 0..n-1 of io whose origins lie far outside the grid box start from just before it
    (:func:`gridrt.trace.traverse.far_shift`): their own origins and tmax go to rows XO, YO, ZO,
    TMO, their shifts to SH, SL and the verdict to MV; a ray that misses the box by far gets tmax
    -inf.  Returns how many rays are not NEAR.  far None (PacketQuery.far): no ray is far, and
    nothing of this is compiled."""
    if far is None:
        return 0
    k = 0
    lo, hi = g.lo, g.hi
    for j in range(n):
        ox, oy, oz = io[IO_OX * PN + j], io[IO_OY * PN + j], io[IO_OZ * PN + j]
        if not is_far(lo, hi, ox, oy, oz):  # inline: a near ray calls nothing
            io[IO_MV * PN + j] = NEAR
            continue
        v, mx, my, mz, th, tl = far_shift(lo, hi, ox, oy, oz, io[IO_DX * PN + j], io[IO_DY * PN + j],
                                          io[IO_DZ * PN + j])
        io[IO_MV * PN + j] = v
        if v == NEAR:
            continue
        k += 1
        tmax = io[IO_TMAX * PN + j]
        io[IO_XO * PN + j] = ox
        io[IO_YO * PN + j] = oy
        io[IO_ZO * PN + j] = oz
        io[IO_TMO * PN + j] = tmax
        if v == MOVED:
            io[IO_OX * PN + j] = mx
            io[IO_OY * PN + j] = my
            io[IO_OZ * PN + j] = mz
            io[IO_TMAX * PN + j] = far_interval(0.0, tmax, th, tl)[1]
            io[IO_SH * PN + j] = th
            io[IO_SL * PN + j] = tl
        else:
            io[IO_TMAX * PN + j] = -np.inf
    return k


@one_per_types
@inner(cache=True, _nrt=False)
def _restore_far(n, io, results, far):
    """Undo _move_far: the rays' own origins and tmax, and with ``results`` their hits' t from
    their own origins (far None: nothing to undo, and nothing of this compiled)."""
    if far is None:
        return
    for j in range(n):
        v = io[IO_MV * PN + j]
        if v == NEAR:
            continue
        io[IO_OX * PN + j] = io[IO_XO * PN + j]
        io[IO_OY * PN + j] = io[IO_YO * PN + j]
        io[IO_OZ * PN + j] = io[IO_ZO * PN + j]
        io[IO_TMAX * PN + j] = io[IO_TMO * PN + j]
        if results and v == MOVED:
            io[IO_T * PN + j] = far_t(io[IO_T * PN + j], io[IO_SH * PN + j], io[IO_SL * PN + j])


@njit(cache=True, _nrt=False, error_model="numpy", inline="always")
def trace_packet(g, n, io, q, S, mb, max_cells=np.inf, prof=None):
    """:func:`_trace_packet`, with rays from far outside the grid traced from just before its box
    as trace_ray traces them (:func:`gridrt.trace.traverse.far_shift`).  A packet with such a ray
    and q.tmin > 0 is not traced: it returns -1, as with a finite max_cells (the packet's rays
    share tmin, a moved ray's would differ).  io's input rows are as they were on return.
    Inlined into its callers at numba's IR level (it is small), so that the call tree below it is
    optimised and compiled to machine code once less."""
    moved = _move_far(g, n, io, q.far) != 0
    if moved and q.tmin > 0.0:
        _restore_far(n, io, False, q.far)
        return -1
    r = _trace_packet(g, n, io, q, S, mb, max_cells, prof)
    if moved:
        _restore_far(n, io, r >= 0, q.far)
    return r


@one_per_types
@inner(cache=True, _nrt=False, error_model="numpy")
def _trace_packet(g, n, io, q, S, mb, max_cells, prof):
    """Trace rays 0..n-1 of the table io (NIO * PN,) float64 (origin, direction, tmax per ray)
    through the grid g (:class:`gridrt.trace.grids.GridArrays`) for the
    :class:`gridrt.trace.cgt.rays.PacketQuery` q (tmin, watertight, any_hit, f32).

    Fills io's result rows (IO_T, IO_F, IO_NT, IO_NC) with the hits :func:`trace_ray` finds
    (nearest, or with any_hit some hit, in (tmin, tmax)).  S (NS * PN,) float64 and mb (MBOX,)
    int32 are scratch.

    A packet whose rays disagree on the direction class (the major axis of the direction and its
    sign, which fix the watertight test's permutation and the order of the slices) is traced as
    one coherent packet per class among its rays, each gathered anew from io; a ray with a tiny
    major component (a zero or subnormal direction, never a camera or shadow ray) is then left a
    miss.  Returns the number of rays traced in such split packets (0 for a coherent packet).

    With a finite ``max_cells`` a packet is traced only when it is coherent and its bounds cover
    at most that many cells in the slice HORIZON cells from the reference plane; otherwise
    nothing is traced, io's results are undefined, and it returns -1 (the batch caster then
    traces those rays another way).

    ``prof`` ((NPROF,) int64, or None: nothing measured, and nothing of it compiled) adds the
    cycles of each phase (the P_* slots: gather, setup and bounds; macro-cell slab checks; slice
    ranges and prefetch; cell visits, mailbox and culls, with the triangle tests apart in
    P_TESTS; retiring rays; the gathers of a split packet's classes) and the counts C_*
    (packets, slices, cells, tests).  Profiling costs a counter read per phase and per test.

    With ``f32`` the triangle tests run in float32 (_test_wt32, _test_mt32: twice the lanes of a
    vector register), relative to the packet's reference origin (active ray 0's); the
    watertight test decides rays with an edge function exactly 0 in float64.  A ray's hit and
    its t then agree with the float64 tests' up to float32 rounding (about 1e-7 relative): at
    near-ties in t and within that distance of an edge, the triangle may differ.
    """
    t = _now(prof)
    _prof_count(prof, C_PACKETS, 1)
    na, K, neg, uniform, cmin, cmax = _gather(io, n, S, g.lo, g.hi, q.tmin, -1)
    if not uniform and max_cells < np.inf:
        _lap(prof, P_SETUP, t)
        return -1
    nsplit = 0
    for p in range(1 if uniform else cmax - cmin + 1):
        if not uniform:  # one class of an incoherent packet's rays
            t = _lap(prof, P_SETUP, t)
            na, K, neg, _, _, _ = _gather(io, n, S, g.lo, g.hi, q.tmin, cmin + p)
            nsplit += na
            t = _lap(prof, P_SPLIT, t)
        if na == 0:
            t = _lap(prof, P_SETUP, t)
            continue
        if _walk_packet(g, na, (K, neg), io, q, S, mb, max_cells, prof, t) < 0:
            return -1
        t = _now(prof)
    return nsplit


@njit(cache=True, _nrt=False, error_model="numpy", inline="always")
def _walk_packet(g, na, major, io, q, S, mb, max_cells, prof, t):
    """The coherent packet of the na active rays gathered in S (major = (K, neg): their major
    axis K, its sign negative with neg) through the grid g, as _trace_packet says; t is the profile's time of the current
    phase (setup).  Returns 0, or -1 where max_cells stops it.  Inlined into its one caller at
    numba's IR level: a kernel of its own would be optimised once more within its caller."""
    K, neg0 = major
    tmin, watertight, f32 = q.tmin, q.watertight, q.f32
    lo, cell, inv_cell, dims = g.lo, g.cell, g.inv_cell, g.dims
    M, mdims, macro_full = g.macro, g.mdims, g.macro_full
    # the permutation of shear_setup: kx = (kz + 1) % 3, ky = (kx + 1) % 3, swapped when d[kz] < 0
    U = (K + 1) % 3
    V = (U + 1) % 3
    if neg0:
        U, V = V, U
    _setup(S, na, U, V, K)
    S32, I32 = rows32(S, f32)
    ref = (S[O_OX], S[O_OY], S[O_OZ], S[O_OU], S[O_OV], S[O_OK])
    tmin32 = _up32(tmin)
    if f32:
        _setup32(S, S32, I32, na, ref, watertight)
    pk = Packet(io, S, S32, I32, mb, q, tmin32, ref)
    loK, loU, loV = lo[K], lo[U], lo[V]
    cK = cell[K]
    icK, icU, icV = inv_cell[K], inv_cell[U], inv_cell[V]
    nK, nU, nV = dims[K], dims[U], dims[V]
    stK, stU, stV = _strides(K, U, V, dims[0], dims[1])
    mstK, mstU, mstV = _strides(K, U, V, mdims[0], mdims[1])
    eU = EPS_CELL * cell[U]
    eV = EPS_CELL * cell[V]
    if f32:
        D = 0.0
        for a in range(3):
            D += max(abs(lo[a] - ref[a]), abs(g.hi[a] - ref[a])) ** 2
        eU += EPS32 * math.sqrt(D)
        eV += EPS32 * math.sqrt(D)
    sK = 1 if S[O_IDK] > 0.0 else -1
    xr, side, xlo, xhi, cu0, cu1, cv0, cv1, su0, su1, sv0, sv1 = _reference_plane(S, na, O_DX + K * PN)
    if max_cells < np.inf:
        # the packet's extent in the slice (one cell thick) HORIZON cells along K from the
        # reference plane, or at the far end of its K range when nearer; in a two-level grid, in
        # leaf cells of the top cell the packet starts in (top cells when that one is empty)
        hK, iU, iV = cK, icU, icV
        if is_two_level(g):
            tc = (_floor_clamp((ref[0] - lo[0]) * inv_cell[0], dims[0]) + dims[0] * (
                _floor_clamp((ref[1] - lo[1]) * inv_cell[1], dims[1])
                + dims[1] * _floor_clamp((ref[2] - lo[2]) * inv_cell[2], dims[2])))
            if g.macro_full[tc] != 0:
                rx, ry, rz = _leaf_res_at(g, tc)
                r = (rx, ry, rz)
                hK /= r[K]
                iU *= r[U]
                iV *= r[V]
        h = min(xhi - xlo, HORIZON * hK) * side
        ulo, uhi, vlo, vhi = _extent((cu0, cu1, cv0, cv1, su0, su1, sv0, sv1), h - hK * side, h, (eU, eV))
        if ((uhi - ulo) * iU + 1.0) * ((vhi - vlo) * iV + 1.0) > max_cells:
            _lap(prof, P_SETUP, t)
            return -1

    # first slice: where the earliest ray (in traversal order) enters the grid
    xs = xlo if sK > 0 else xhi
    k = _floor_clamp((xs - loK) * icK - sK * EPS_CELL, nK)
    for s in range(mb.shape[0]):
        mb[s] = -1
    xa = loK + (k if sK > 0 else k + 1) * cK
    if is_two_level(g):
        _lap(prof, P_SETUP, t)
        _walk_two_level(g, pk, na, (U, V, K), (sK, k, xa), (xr, side), (cu0, cu1, cv0, cv1, su0, su1, sv0, sv1), (eU, eV))
        return 0
    tests = 0
    cells = 0
    pending = 0
    t = _lap(prof, P_SETUP, t)
    while na > 0 and 0 <= k < nK:
        mk = k // M
        if sK > 0:
            kend = min((mk + 1) * M, nK) - 1
            xm = loK + (kend + 1) * cK
        else:
            kend = mk * M
            xm = loK + kend * cK
        # skip the rest of this macro-cell slab when the packet overlaps only empty macro cells there
        ulo, uhi, vlo, vhi = _extent((cu0, cu1, cv0, cv1, su0, su1, sv0, sv1), xa - xr, xm - xr, (eU, eV))
        if _any_macro_full(macro_full, mk, _floor_clamp((ulo - loU) * icU, nU) // M,
                           _floor_clamp((uhi - loU) * icU, nU) // M, _floor_clamp((vlo - loV) * icV, nV) // M,
                           _floor_clamp((vhi - loV) * icV, nV) // M, mstK, mstU, mstV):
            t = _lap(prof, P_MACRO, t)
            while True:
                xb = loK + (k + 1 if sK > 0 else k) * cK
                ulo, uhi, vlo, vhi = _extent((cu0, cu1, cv0, cv1, su0, su1, sv0, sv1), xa - xr, xb - xr, (eU, eV))
                pl_u0 = cu0 - eU
                pl_u1 = cu1 + eU
                pl_v0 = cv0 - eV
                pl_v1 = cv1 + eV
                sl_u0 = su0 if side > 0 else su1
                sl_u1 = su1 if side > 0 else su0
                sl_v0 = sv0 if side > 0 else sv1
                sl_v1 = sv1 if side > 0 else sv0
                cu_0, cu_1, cv_0, cv_1 = _cells_of((ulo, uhi, vlo, vhi), loU, icU, nU, loV, icV, nV)
                span = (k * stK, stU, stV, cu_0, cu_1, cv_0, cv_1)
                _prefetch_slice(g, span)
                t = _lap(prof, P_SLICE, t)
                nc, nt, nh = _test_slice(
                    g, span, (U, V, K), (ulo, uhi, vlo, vhi),
                    (xr, pl_u0, pl_u1, pl_v0, pl_v1, sl_u0, sl_u1, sl_v0, sl_v1), pk, S32, na, prof)
                t = _lap(prof, P_CELLS, t)
                _prof_count(prof, C_SLICES, 1)
                _prof_count(prof, C_CELLS, nc)
                _prof_count(prof, C_TESTS, nt)
                cells += nc
                tests += nt
                pending += nh
                xa = xb
                if pending > 0:
                    nb, pending = _step(pk, na, xb, (tests, cells))
                    if nb != na:
                        na = nb
                        if na == 0:
                            _lap(prof, P_RETIRE, t)
                            return 0
                        cu0, cu1, cv0, cv1, su0, su1, sv0, sv1 = _spread(S, na, xr)
                    t = _lap(prof, P_RETIRE, t)
                if k == kend:
                    break
                k += sK
        else:
            xa = xm
            t = _lap(prof, P_MACRO, t)
        # once per macro slab: also retire rays whose segment has ended
        nb, pending = _step(pk, na, xa, (tests, cells))
        if nb != na:
            na = nb
            if na == 0:
                _lap(prof, P_RETIRE, t)
                return 0
            cu0, cu1, cv0, cv1, su0, su1, sv0, sv1 = _spread(S, na, xr)
        k = kend + sK
        t = _lap(prof, P_RETIRE, t)
    for a in range(na):
        _finish(pk, a, (tests, cells))
    _lap(prof, P_RETIRE, t)
    return 0


@njit(cache=True, inline="always")
def _planes(xr, side, bounds, eU, eV):
    """The packet's four bounding planes about xr (see _outside), from its bounds (cu0, cu1, cv0,
    cv1, su0, su1, sv0, sv1 about xr; side 1: the segments lie beyond xr, -1: before it), grown
    by (eU, eV)."""
    cu0, cu1, cv0, cv1, su0, su1, sv0, sv1 = bounds
    return (xr, cu0 - eU, cu1 + eU, cv0 - eV, cv1 + eV, su0 if side > 0 else su1, su1 if side > 0 else su0,
            sv0 if side > 0 else sv1, sv1 if side > 0 else sv0)


@njit(cache=True, inline="always")
def _advance(pk, na, xp, counts, xr, bounds):
    """_step at the K plane xp (counters counts = (tests, cells)): returns (active rays, active
    rays with a hit, the packet's bounds about xr, taken again when rays left)."""
    nb, pending = _step(pk, na, xp, counts)
    if nb != na and nb > 0:
        bounds = _spread(pk.S, nb, xr)
    return nb, pending, bounds


@inner(cache=True, _nrt=False, error_model="numpy")
def _walk_2l(g, pk, na, axes, start, plane, bounds, grow):
    """trace_packet's slice walk of the na active rays of the packet pk
    (:class:`gridrt.trace.cgt.rays.Packet`, its mailbox cleared) through a two-level grid g
    (gridrt.grid.two_level), with axes = (U, V, K) the packet's permutation, from start = (sK, k,
    xa) on (the direction sK of the walk along K, the first top slice k, and the K plane xa where
    the packet's rays start), plane = (xr, side) the reference plane (see _reference_plane),
    bounds the packet's bounds about xr (see _spread) and grow = (eU, eV) their growth.  Each top
    slice (fixed K index of the top level) that holds triangles within the packet's bounds is cut
    into R sub-slices, R the finest leaf resolution along K among its non-empty top cells within
    the bounds.  In each sub-slice, every non-empty top cell the
    packet's bounds overlap there has the leaf slices (fixed K index of its leaf grid) that the
    sub-slice reaches and the sub-slice before did not visited (_test_slice), each once and whole:
    the leaf cells the packet's bounds overlap over all of the leaf slice it crosses.  Then rays
    final at the sub-slice's far plane retire (trace_packet's termination rule: every leaf cell
    the rays crossed up to that plane has been visited).  Writes io's results for every active
    ray."""
    lo, cell, inv_cell, dims = g.lo, g.cell, g.inv_cell, g.dims
    leaf_first, leaf_res, macro_full = g.leaf_first, g.leaf_res, g.macro_full
    U, V, K = axes
    sK, k, xa = start
    xr, side = plane
    eU, eV = grow
    cu0, cu1, cv0, cv1, su0, su1, sv0, sv1 = bounds
    loK, loU, loV = lo[K], lo[U], lo[V]
    cK, cU, cV = cell[K], cell[U], cell[V]
    icU, icV = inv_cell[U], inv_cell[V]
    nK, nU, nV = dims[K], dims[U], dims[V]
    stK, stU, stV = _strides(K, U, V, dims[0], dims[1])
    tests = 0
    cells = 0
    pending = 0
    while na > 0 and 0 <= k < nK:
        xb = loK + (k + 1 if sK > 0 else k) * cK
        ulo, uhi, vlo, vhi = _extent((cu0, cu1, cv0, cv1, su0, su1, sv0, sv1), xa - xr, xb - xr, grow)
        tu0, tu1, tv0, tv1 = _cells_of((ulo, uhi, vlo, vhi), loU, icU, nU, loV, icV, nV)
        # the sub-slices: as many as the finest leaf resolution along K of the non-empty top
        # cells in reach
        R = 0
        for iu in range(tu0, tu1 + 1):
            for iv in range(tv0, tv1 + 1):
                tc = k * stK + iu * stU + iv * stV
                if macro_full[tc] != 0:
                    R = max(R, leaf_res[tc, K])
        xs_a = xa
        xt0 = min(xa, xb)  # the part of the top slice the packet still crosses
        xt1 = max(xa, xb)
        ptu0, ptu1, ptv0, ptv1 = 0, -1, 0, -1  # the top cells of the sub-slice before (none yet)
        xs_p = xa
        for sub in range(R):
            if sub == R - 1:
                xs_b = xb
            else:
                xs_b = loK + (k * cK + (sub + 1) * cK / R if sK > 0 else (k + 1) * cK - (sub + 1) * cK / R)
            ulo, uhi, vlo, vhi = _extent((cu0, cu1, cv0, cv1, su0, su1, sv0, sv1), xs_a - xr, xs_b - xr, grow)
            planes = _planes(xr, side, (cu0, cu1, cv0, cv1, su0, su1, sv0, sv1), eU, eV)
            xk0 = min(xs_a, xs_b)
            xk1 = max(xs_a, xs_b)
            qu0, qu1, qv0, qv1 = _cells_of((ulo, uhi, vlo, vhi), loU, icU, nU, loV, icV, nV)
            for iu in range(qu0, qu1 + 1):
                for iv in range(qv0, qv1 + 1):
                    tc = k * stK + iu * stU + iv * stV
                    if macro_full[tc] == 0:
                        continue
                    rK = leaf_res[tc, K]
                    sloK, scK, iscK = leaf_axis(loK, cK, k, rK)
                    jk0, jk1 = _leaf_range(xk0, xk1, sloK, iscK, rK)
                    if ptu0 <= iu <= ptu1 and ptv0 <= iv <= ptv1:
                        # the leaf slices the sub-slice before reached were visited then, whole
                        pk0, pk1 = _leaf_range(min(xs_a, xs_p), max(xs_a, xs_p), sloK, iscK, rK)
                        if sK > 0:
                            jk0 = max(jk0, pk1 + 1)
                        else:
                            jk1 = min(jk1, pk0 - 1)
                    if jk0 > jk1:
                        continue
                    rU, rV = leaf_res[tc, U], leaf_res[tc, V]
                    sloU, scU, iscU = leaf_axis(loU, cU, iu, rU)
                    sloV, scV, iscV = leaf_axis(loV, cV, iv, rV)
                    lK, lU, lV = _strides(K, U, V, leaf_res[tc, 0], leaf_res[tc, 1])
                    q0 = leaf_first[tc]
                    for jk in range(jk0, jk1 + 1):
                        # a leaf slice is visited once, over all of it the packet crosses in
                        # this top slice
                        za = max(sloK + jk * scK, xt0)
                        zb = min(sloK + (jk + 1) * scK, xt1)
                        box = _extent((cu0, cu1, cv0, cv1, su0, su1, sv0, sv1), za - xr, zb - xr, grow)
                        ju0, ju1, jv0, jv1 = _cells_of(box, sloU, iscU, rU, sloV, iscV, rV)
                        span = (q0 + jk * lK, lU, lV, ju0, ju1, jv0, jv1)
                        _prefetch_slice(g, span)
                        nc, nt, nh = _test_slice(g, span, axes, box, planes, pk, pk.S32, na, None)
                        cells += nc
                        tests += nt
                        pending += nh
            ptu0, ptu1, ptv0, ptv1 = qu0, qu1, qv0, qv1
            xs_p = xs_a
            xs_a = xs_b
            if pending > 0:
                na, pending, bounds = _advance(pk, na, xs_b, (tests, cells), xr, bounds)
                if na == 0:
                    return
                cu0, cu1, cv0, cv1, su0, su1, sv0, sv1 = bounds
        xa = xb
        # once per top slice: also retire rays whose segment has ended
        na, pending, bounds = _advance(pk, na, xa, (tests, cells), xr, bounds)
        if na == 0:
            return
        cu0, cu1, cv0, cv1, su0, su1, sv0, sv1 = bounds
        k += sK
    for a in range(na):
        _finish(pk, a, (tests, cells))


@njit(cache=True, inline="always")
def _leaf_res(g, tc):
    """The leaf resolution of top cell tc of the two-level grid g."""
    return g.leaf_res[tc, 0], g.leaf_res[tc, 1], g.leaf_res[tc, 2]


#: (kernels only) :func:`_leaf_res` and :func:`_walk_2l`, compiled only for grids that carry leaf
#: arrays (for the others, a constant that is_two_level never lets a kernel use)
_leaf_res_at = with_leaves_only("_leaf_res_at", "g, tc", _leaf_res, (np.int32(1), np.int32(1), np.int32(1)))
_walk_two_level = with_leaves_only("_walk_two_level", "g, pk, na, axes, start, plane, bounds, grow", _walk_2l, None)


@njit(cache=True, _nrt=False, error_model="numpy", inline="always")
def trace_packet_grids(grids, n, io, io2, q, S, mb):
    """:func:`trace_packet` over the tuple of grids, in order (as trace_grids does for one ray):
    each later grid's rays end at the hit found before it (nearest), or are skipped where one was
    found (q.any_hit).  io's IO_W row tells which grid the hit is in; io2 is scratch.  Returns the
    number of rays traced in packets split by direction class (summed over the grids).  q.tmin is
    0 for its callers (the render's queries): trace_packet's -1 never comes back."""
    nf = 0
    for i in range(len(grids)):  # (one call of trace_packet, which numba inlines: one copy of it)
        if i > 0:
            _chain_rays(io, io2, n, q.any_hit)
        nf += trace_packet(grids[i], n, io2 if i > 0 else io, q, S, mb, np.inf, None)
        if i > 0:
            _merge_hits(io, io2, n, i)
        else:
            for j in range(n):
                io[IO_W * PN + j] = 0.0
    return nf


@one_per_types
@inner(cache=True, _nrt=False)
def _chain_rays(io, io2, n, any_hit):
    """io's rays into io2, each ending where io found a hit (any_hit: not traced at all there)."""
    for j in range(n):
        for r in range(IO_TMAX):
            io2[r * PN + j] = io[r * PN + j]
        if io[IO_F * PN + j] >= 0.0:
            io2[IO_TMAX * PN + j] = -np.inf if any_hit else io[IO_T * PN + j]
        else:
            io2[IO_TMAX * PN + j] = io[IO_TMAX * PN + j]


@one_per_types
@inner(cache=True, _nrt=False)
def _merge_hits(io, io2, n, which):
    """io2's hits (in grid ``which``) replace io's; the counters add up."""
    for j in range(n):
        if io2[IO_F * PN + j] >= 0.0:
            io[IO_T * PN + j] = io2[IO_T * PN + j]
            io[IO_F * PN + j] = io2[IO_F * PN + j]
            io[IO_W * PN + j] = which
        io[IO_NT * PN + j] += io2[IO_NT * PN + j]
        io[IO_NC * PN + j] += io2[IO_NC * PN + j]
