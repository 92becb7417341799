"""Coherent grid traversal (CGT): packets of rays walked through the grid slice by slice.

Wald, Ize, Kensler, Knoll, Parker, "Ray Tracing Animated Scenes using Coherent Grid Traversal",
ACM SIGGRAPH 2006.  A packet (up to kw x kh camera rays from a block of pixels, 8 x 8 by default,
or the shadow rays of such a block) is traversed along its major axis K, one slice of cells (fixed K
index) at a time.  In each slice the cells overlapped by the packet's bounds are visited; each of
their triangles passes a per-packet mailbox, a bounding-box cull against the packet's extent in
the slice and a cull against the packet's four bounding planes (the paper's frustum culling), and
is then intersected with every active ray in one loop over structure-of-arrays ray data that
LLVM vectorizes (packed AVX2 / AVX-512VL double instructions on this machine).  Empty macro cells
are skipped a whole macro-cell slab at a time.  A two-level grid (gridrt.grid.two_level) is walked
one top-level slice at a time, each cut into sub-slices as fine as the finest leaf grid in reach
along K, visiting the leaf cells of the top cells in reach (:func:`_walk_2l`).

Packets: the rays must agree on the major axis of their direction and its sign (the watertight
test's permutation, :func:`gridrt.trace.intersect.shear_setup`), so that all share the slicing
axis and the permuted intersection arithmetic.  Packets that do not agree fall back to the
single-ray DDA (:func:`gridrt.trace.traverse.trace_ray`).  Signs on the two minor axes may differ
(the bounds below do not need them), so packets straddling a minor-axis sign change, e.g. at the
centre of an axis-aligned view, stay packets.

Bounds: along its segment ray i's minor coordinates are linear in the K coordinate x,
u_i(x) = c_i + (x - xr) s_i.  With xr at one end of all the segments (the camera rays' common
origin, or the end of shadow rays, which converge on the light), every ray lies within
[min c + (x - xr) min s, max c + (x - xr) max s] on that side of xr (and likewise for v): four
planes, evaluated in O(1) per slice and used for the cell range and the triangle culls; they are
recomputed when rays leave the packet.

Termination (same rule as the DDA): after a slice, ray i is final once its best t is at or before
the t where it leaves the slice (or its segment ends there): insertion is conservative, so every
triangle it could hit nearer has been tested against it.  Final rays leave the active set (the
last survivors fill their places), so the loops always run over a contiguous prefix.

Results equal the DDA's bit for bit (same intersection arithmetic: the packet loops repeat
:func:`intersect_watertight` / :func:`intersect_fast` operation for operation, without fast-math
contraction), ties included: of two triangles hit at the same t both take the lower index.

Per-ray counters: ``tests`` counts the triangle tests made while the ray was active (each test
of the packet loop covers every active ray), ``cells`` the cells the packet visited meanwhile.
"""

import math

import numpy as np
from numba import njit, prange

from ..config import PACKET_MAX
from ..grid.two_level import _leaf_range, leaf_axis
from .grids import pack_grids, unpack_grids
from .intersect import woop_edges, woop_shear
from .prefetch import _cycles, _prefetch_tri, _prefetch_write
from .shade import BACKGROUND, _u8, cost_rgb, facing_normal, lambert_rgb, normal_rgb, scene_id, shadow_ray
from .traverse import MAILBOX, MOVED, NEAR, TINY_DIR, _floor_clamp, far_interval, far_shift, far_t, is_far, trace_ray

#: the render's default packet edge in pixels (RenderParams.packet: PK x PK pixels)
PK = 8
#: the largest packet edge (RenderParams.packet up to PK_MAX x PK_MAX pixels)
PK_MAX = PACKET_MAX
#: rays a packet table holds, and the stride of its rows: PK_MAX * PK_MAX, plus 16 so that rows
#: 2 KiB apart do not all fall into the same few cache sets, and a multiple of L32
PN = PK_MAX * PK_MAX + 16
#: per-packet mailbox slots (direct-mapped by triangle id; a power of two)
MBOX = 256
#: the render kernel's parallel work items (runs of consecutive tiles sharing one scratch allocation)
CHUNKS = 256
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

# rows of the flat per-packet scratch S (NS * PN float64) holding the active rays (structure of arrays)
_R_OU, _R_OV, _R_OK = 0, 1, 2  # origin permuted to (kx, ky, kz): minor axes U = kx, V = ky; major K = kz
_R_SU, _R_SV = 3, 4  # dU/dK, dV/dK
_R_IDK, _R_T1 = 5, 6  # 1/dK, end of the ray's segment clipped to the grid box
_R_BT, _R_BF, _R_J = 7, 8, 9  # best t (starts at tmax), best triangle (-1), packet-local ray index
_R_SX, _R_SY, _R_SZ = 10, 11, 12  # watertight shear constants
_R_OX, _R_OY, _R_OZ, _R_DX, _R_DY, _R_DZ = 13, 14, 15, 16, 17, 18  # origin, direction (Moller-Trumbore)
_R_T0 = 19  # start of the clipped segment
_R_CT0, _R_CT1 = 20, 21  # clip results of every packet ray (indexed by packet ray, before compaction)
NS64 = 22
# float32 rows of the packet tests in float32 (trace_packet's f32), after the float64 rows: S32 =
# S[O_F32:].view(np.float32), row r of active ray i at S32[r * PN + i].  Coordinates are taken
# relative to the packet's reference origin (active ray 0's at setup), in float64 before rounding,
# so that float32 keeps its relative precision far from the world's origin.
# The best triangle is an int32 row of the same memory (I32 = S[O_F32:].view(np.int32)).  While a
# packet is traced in float32 these two rows hold its rays' best t and triangle (the float64 rows
# BT, BF are then unused): _count_final32 and _finish read them.
_F_OU, _F_OV, _F_OK, _F_SX, _F_SY, _F_SZ = 0, 1, 2, 3, 4, 5  # Woop: origin - ref (permuted), shear
_F_OX, _F_OY, _F_OZ, _F_DX, _F_DY, _F_DZ = 6, 7, 8, 9, 10, 11  # Moller-Trumbore: origin - ref, direction
_F_BT, _F_BF = 12, 13  # best t (float32), best triangle (int32)
NF32 = 14
#: lanes of the float32 test loops: the active rays are processed in whole blocks of L32 (the rays
#: after the last active one are made inert, see _dead32), so the loops have no scalar remainder
L32 = 16
NS = NS64 + (NF32 + 1) // 2
O_F32 = NS64 * PN
F_OU, F_OV, F_OK, F_SX, F_SY, F_SZ = (r * PN for r in range(6))
F_OX, F_OY, F_OZ, F_DX, F_DY, F_DZ = (r * PN for r in range(6, 12))
F_BT, F_BF = _F_BT * PN, _F_BF * PN
O_OU, O_OV, O_OK = _R_OU * PN, _R_OV * PN, _R_OK * PN
O_SX, O_SY, O_SZ = _R_SX * PN, _R_SY * PN, _R_SZ * PN
O_OX, O_OY, O_OZ = _R_OX * PN, _R_OY * PN, _R_OZ * PN
O_DX, O_DY, O_DZ = _R_DX * PN, _R_DY * PN, _R_DZ * PN
O_SU, O_SV, O_T0, O_T1 = _R_SU * PN, _R_SV * PN, _R_T0 * PN, _R_T1 * PN
O_IDK, O_BT, O_BF, O_J = _R_IDK * PN, _R_BT * PN, _R_BF * PN, _R_J * PN
O_CT0, O_CT1 = _R_CT0 * PN, _R_CT1 * PN

# rows of a packet's flat ray table io (NIO * PN float64), row r of ray j at io[r * PN + j]:
# inputs (origin, direction, tmax), then results
IO_OX, IO_OY, IO_OZ, IO_DX, IO_DY, IO_DZ, IO_TMAX = 0, 1, 2, 3, 4, 5, 6
IO_T, IO_F, IO_NT, IO_NC, IO_W = 7, 8, 9, 10, 11  # t (inf: miss), triangle (-1), tests, cells, grid number
# a far ray's (trace_packet, far_shift): its own origin and tmax while it is traced from nearer, its
# shift (double-double) and far_shift's verdict
IO_XO, IO_YO, IO_ZO, IO_TMO, IO_SH, IO_SL, IO_MV = 12, 13, 14, 15, 16, 17, 18
NIO = 19
_U_OX, _U_OY, _U_OZ = np.uint64(IO_OX * PN), np.uint64(IO_OY * PN), np.uint64(IO_OZ * PN)
_U_DX, _U_DY, _U_DZ = np.uint64(IO_DX * PN), np.uint64(IO_DY * PN), np.uint64(IO_DZ * PN)
_U_TMAX = np.uint64(IO_TMAX * PN)
_U_T, _U_F, _U_NT, _U_NC = np.uint64(IO_T * PN), np.uint64(IO_F * PN), np.uint64(IO_NT * PN), np.uint64(IO_NC * PN)
_U_PN, _U_2PN = np.uint64(PN), np.uint64(2 * PN)


#: slots of a packet profile (trace_packet's ``prof``, (NPROF,) int64): cycles per phase, then counts
P_SETUP, P_MACRO, P_SLICE, P_CELLS, P_TESTS, P_RETIRE, P_FALLBACK, P_RAYS = 0, 1, 2, 3, 4, 5, 6, 7
PROFILE_PHASES = ("setup", "macro", "slice", "cells", "tests", "retire", "fallback", "rays")
C_PACKETS, C_SLICES, C_CELLS, C_TESTS = 8, 9, 10, 11
NPROF = 12


@njit(cache=True, _nrt=False)
def _now(prof):
    """The cycle counter when profiling (prof an array), else 0 (prof None: compiled away)."""
    if prof is None:
        return 0
    return _cycles()


@njit(cache=True, _nrt=False)
def _lap(prof, k, t):
    """Add the cycles since t to phase k of prof; returns the counter now (0 without prof)."""
    if prof is None:
        return 0
    now = _cycles()
    prof[k] += now - t
    return now


@njit(cache=True, _nrt=False)
def _prof_count(prof, k, n):
    if prof is not None:
        prof[k] += n


@njit(cache=True, _nrt=False, error_model="numpy")
def _clip_axis(io, n, S, r_o, r_d, lo, hi):
    """traverse._slab of every packet ray on one axis, applied to the ranges in S rows CT0/CT1."""
    for j in range(n):
        o = io[r_o * PN + j]
        d = io[r_d * PN + j]
        t0 = S[O_CT0 + j]
        t1 = S[O_CT1 + j]
        inv = 1.0 / d
        ta = (lo - o) * inv
        tb = (hi - o) * inv
        sw = ta > tb
        ta2 = tb if sw else ta
        tb2 = ta if sw else tb
        a0 = max(t0, ta2)
        a1 = min(t1, tb2)
        tiny = abs(d) < TINY_DIR
        outside = (o < lo) | (o > hi)
        S[O_CT0 + j] = (np.inf if outside else t0) if tiny else a0
        S[O_CT1 + j] = (-np.inf if outside else t1) if tiny else a1


@njit(cache=True, _nrt=False, error_model="numpy")
def _setup(S, na, kx, ky, kz):
    """Per-ray constants of the active rays (all permuted alike by (kx, ky, kz))."""
    for i in range(na):
        dx = S[O_DX + i]
        dy = S[O_DY + i]
        dz = S[O_DZ + i]
        ox = S[O_OX + i]
        oy = S[O_OY + i]
        oz = S[O_OZ + i]
        dkx = dx if kx == 0 else (dy if kx == 1 else dz)
        dky = dx if ky == 0 else (dy if ky == 1 else dz)
        dkz = dx if kz == 0 else (dy if kz == 1 else dz)
        S[O_OU + i] = ox if kx == 0 else (oy if kx == 1 else oz)
        S[O_OV + i] = ox if ky == 0 else (oy if ky == 1 else oz)
        S[O_OK + i] = ox if kz == 0 else (oy if kz == 1 else oz)
        S[O_SX + i] = dkx / dkz
        S[O_SY + i] = dky / dkz
        S[O_SZ + i] = 1.0 / dkz
        idk = 1.0 / dkz
        S[O_IDK + i] = idk
        S[O_SU + i] = dkx * idk
        S[O_SV + i] = dky * idk


@njit(cache=True, _nrt=False)
def _spread(S, na, xr):
    """Bounding form of the active rays about the K coordinate xr: every ray's (U, V) at K = x is
    within [cu0, cu1] + (x - xr) * [su0, su1] (and likewise for V).  Returns
    (cu0, cu1, cv0, cv1, su0, su1, sv0, sv1)."""
    cu0 = np.inf
    cu1 = -np.inf
    cv0 = np.inf
    cv1 = -np.inf
    su0 = np.inf
    su1 = -np.inf
    sv0 = np.inf
    sv1 = -np.inf
    for i in range(na):
        h = xr - S[O_OK + i]
        su = S[O_SU + i]
        sv = S[O_SV + i]
        u = S[O_OU + i] + h * su
        v = S[O_OV + i] + h * sv
        cu0 = min(cu0, u)
        cu1 = max(cu1, u)
        cv0 = min(cv0, v)
        cv1 = max(cv1, v)
        su0 = min(su0, su)
        su1 = max(su1, su)
        sv0 = min(sv0, sv)
        sv1 = max(sv1, sv)
    return cu0, cu1, cv0, cv1, su0, su1, sv0, sv1


@njit(cache=True, _nrt=False, error_model="numpy")
def _test_wt(S, na, p0x, p0y, p0z, p1x, p1y, p1z, p2x, p2y, p2z, ff, tmin):
    """intersect_watertight of one triangle (vertices permuted by the packet's kx, ky, kz) with
    the active rays, operation for operation; a hit below the ray's best t replaces it.
    Returns the number of rays hit."""
    nh = 0
    for i in range(na):
        Sz = S[O_SZ + i]
        Ax, Ay, Bx, By, Cx, Cy, az, bz, cz = woop_shear(p0x, p0y, p0z, p1x, p1y, p1z, p2x, p2y, p2z, S[O_OU + i],
                                                        S[O_OV + i], S[O_OK + i], S[O_SX + i], S[O_SY + i])
        U, V, W = woop_edges(Ax, Ay, Bx, By, Cx, Cy)
        det = U + V + W
        T = U * (Sz * az) + V * (Sz * bz) + W * (Sz * cz)
        t = T / det
        bt = S[O_BT + i]
        bf = S[O_BF + i]
        out = ((U < 0.0) | (V < 0.0) | (W < 0.0)) & ((U > 0.0) | (V > 0.0) | (W > 0.0))
        hit = (not out) & (det != 0.0) & (t > tmin) & ((t < bt) | ((t == bt) & (ff < bf)))
        S[O_BT + i] = t if hit else bt
        S[O_BF + i] = ff if hit else bf
        nh += hit
    return nh


@njit(cache=True, _nrt=False, error_model="numpy")
def _test_mt(S, na, v0x, v0y, v0z, v1x, v1y, v1z, v2x, v2y, v2z, ff, tmin):
    """intersect_fast (Moller-Trumbore) of one triangle with the active rays, operation for
    operation.  Returns the number of rays hit."""
    nh = 0
    e1x = v1x - v0x
    e1y = v1y - v0y
    e1z = v1z - v0z
    e2x = v2x - v0x
    e2y = v2y - v0y
    e2z = v2z - v0z
    for i in range(na):
        dx = S[O_DX + i]
        dy = S[O_DY + i]
        dz = S[O_DZ + i]
        px = dy * e2z - dz * e2y
        py = dz * e2x - dx * e2z
        pz = dx * e2y - dy * e2x
        det = e1x * px + e1y * py + e1z * pz
        inv = 1.0 / det
        sx = S[O_OX + i] - v0x
        sy = S[O_OY + i] - v0y
        sz = S[O_OZ + i] - v0z
        u = (sx * px + sy * py + sz * pz) * inv
        qx = sy * e1z - sz * e1y
        qy = sz * e1x - sx * e1z
        qz = sx * e1y - sy * e1x
        v = (dx * qx + dy * qy + dz * qz) * inv
        t = (e2x * qx + e2y * qy + e2z * qz) * inv
        bt = S[O_BT + i]
        bf = S[O_BF + i]
        hit = (det != 0.0) & (not ((u < 0.0) | (u > 1.0))) & (not ((v < 0.0) | (u + v > 1.0)))
        hit = hit & (t > tmin) & ((t < bt) | ((t == bt) & (ff < bf)))
        S[O_BT + i] = t if hit else bt
        S[O_BF + i] = ff if hit else bf
        nh += hit
    return nh


@njit(cache=True, _nrt=False, error_model="numpy")
def _setup32(S, S32, I32, na, ref, watertight):
    """The float32 rows of the active rays (see _F_OU), over whole blocks of L32 rays: origins less
    the packet's reference origin ref = (x, y, z, u, v, k), in float64 and then rounded; shear
    constants (watertight) or directions rounded; the best t rounded down (a hit beyond a ray's
    tmax stays beyond it) and the best triangle."""
    rx, ry, rz, ru, rv, rk = ref
    npad = (na + L32 - 1) // L32 * L32
    if watertight:
        for i in range(npad):
            S32[F_OU + i] = np.float32(S[O_OU + i] - ru)
            S32[F_OV + i] = np.float32(S[O_OV + i] - rv)
            S32[F_OK + i] = np.float32(S[O_OK + i] - rk)
            S32[F_SX + i] = np.float32(S[O_SX + i])
            S32[F_SY + i] = np.float32(S[O_SY + i])
            S32[F_SZ + i] = np.float32(S[O_SZ + i])
    else:
        for i in range(npad):
            S32[F_OX + i] = np.float32(S[O_OX + i] - rx)
            S32[F_OY + i] = np.float32(S[O_OY + i] - ry)
            S32[F_OZ + i] = np.float32(S[O_OZ + i] - rz)
            S32[F_DX + i] = np.float32(S[O_DX + i])
            S32[F_DY + i] = np.float32(S[O_DY + i])
            S32[F_DZ + i] = np.float32(S[O_DZ + i])
    up = 0
    for i in range(na):
        b = np.float32(S[O_BT + i])
        S32[F_BT + i] = b
        I32[F_BF + i] = -1
        up += np.float64(b) > S[O_BT + i]
    if up > 0:  # (rare: a finite tmax that float32 rounds up)
        for i in range(na):
            if np.float64(S32[F_BT + i]) > S[O_BT + i]:
                S32[F_BT + i] = np.nextafter(S32[F_BT + i], np.float32(-np.inf))
    _dead32(S32, na)


@njit(cache=True, _nrt=False)
def _dead32(S32, na):
    """Make the rays after the last active one up to its block of L32 inert in the float32 tests:
    a NaN origin fails every comparison (no hit, nothing undecided), so the test loops need not
    check which lanes are active."""
    nan = np.float32(np.nan)
    for i in range(na, (na + L32 - 1) // L32 * L32):
        S32[F_OU + i] = nan
        S32[F_OX + i] = nan
        S32[F_BT + i] = nan


@njit(cache=True, _nrt=False)
def _up32(x):
    """The smallest float32 at or above x (float64)."""
    b = np.float32(x)
    return np.nextafter(b, np.float32(np.inf)) if np.float64(b) < x else b


@njit(cache=True, _nrt=False, inline="always")
def _sheared32(S32, i, q0x, q0y, q0z, q1x, q1y, q1z, q2x, q2y, q2z):
    """woop_shear in float32 of float32 ray i (rows of S32) and the vertices q (see _test_wt32)."""
    return woop_shear(q0x, q0y, q0z, q1x, q1y, q1z, q2x, q2y, q2z, S32[F_OU + i], S32[F_OV + i], S32[F_OK + i],
                      S32[F_SX + i], S32[F_SY + i])


@njit(cache=True, _nrt=False, error_model="numpy")
def _test_wt32(S32, I32, na, q0x, q0y, q0z, q1x, q1y, q1z, q2x, q2y, q2z, ff, tmin32):
    """_test_wt in float32 over the packet, L32 rays at a time (16 lanes of a zmm register where
    512-bit vectors are enabled, see gridrt.threads): the vertices q (permuted, less the packet's
    reference origin, rounded to float32) against the float32 rows.  Shared vertices give every
    ray the same sheared coordinates in every triangle, so the edge functions of a shared edge
    are exact negations and the test stays watertight in float32 (Woop, Benthin, Wald 2013).  A
    ray for which an edge function is exactly 0 and the other signs do not already exclude the
    triangle is not decided here: it is counted in the second result, for _fix_wt64 to decide in
    float64.  Returns (1 if some ray was hit else 0, 1 if some ray is left to float64 else 0)."""
    zero = np.float32(0.0)
    nh = False  # (flags, not counts: an int64 count would halve the lanes of the loop)
    nz = False
    for b in range((na + L32 - 1) // L32):
        for l in range(L32):
            i = b * L32 + l
            Sz = S32[F_SZ + i]
            Ax, Ay, Bx, By, Cx, Cy, az, bz, cz = _sheared32(S32, i, q0x, q0y, q0z, q1x, q1y, q1z, q2x, q2y, q2z)
            U, V, W = woop_edges(Ax, Ay, Bx, By, Cx, Cy)
            det = U + V + W
            T = U * (Sz * az) + V * (Sz * bz) + W * (Sz * cz)
            t = T / det
            bt = S32[F_BT + i]
            bf = I32[F_BF + i]
            out = ((U < zero) | (V < zero) | (W < zero)) & ((U > zero) | (V > zero) | (W > zero))
            undecided = (not out) & ((U == zero) | (V == zero) | (W == zero))
            hit = (not out) & (not undecided) & (det != zero) & (t > tmin32) & ((t < bt) | ((t == bt) & (ff < bf)))
            S32[F_BT + i] = t if hit else bt
            I32[F_BF + i] = ff if hit else bf
            nh |= hit
            nz |= undecided
    return int(nh), int(nz)


@njit(cache=True, _nrt=False, error_model="numpy")
def _fix_wt64(S32, I32, na, q0x, q0y, q0z, q1x, q1y, q1z, q2x, q2y, q2z, ff, tmin):
    """The rays _test_wt32 left undecided (an edge function exactly 0 in float32), decided in
    float64 as Woop et al. do: the edge functions again from the same float32 sheared vertex
    coordinates, whose products are exact in float64, so the signs are exact and agree with those
    every neighbouring triangle got in float32 (a shared edge still gives exact negations).  An
    edge function still 0 means the ray meets the edge or vertex exactly: both triangles count it.
    Returns 1 if some ray was hit, else 0."""
    zero = np.float32(0.0)
    nh = 0
    for i in range(na):
        Sz = S32[F_SZ + i]
        Ax, Ay, Bx, By, Cx, Cy, az, bz, cz = _sheared32(S32, i, q0x, q0y, q0z, q1x, q1y, q1z, q2x, q2y, q2z)
        U, V, W = woop_edges(Ax, Ay, Bx, By, Cx, Cy)
        out = ((U < zero) | (V < zero) | (W < zero)) & ((U > zero) | (V > zero) | (W > zero))
        if out or not ((U == zero) | (V == zero) | (W == zero)):
            continue  # decided in float32
        # exact products of the float32 coordinates
        U64, V64, W64 = woop_edges(np.float64(Ax), np.float64(Ay), np.float64(Bx), np.float64(By), np.float64(Cx),
                                   np.float64(Cy))
        if (U64 < 0.0 or V64 < 0.0 or W64 < 0.0) and (U64 > 0.0 or V64 > 0.0 or W64 > 0.0):
            continue
        det = U64 + V64 + W64
        if det == 0.0:
            continue
        T = U64 * (np.float64(Sz) * np.float64(az)) + V64 * (np.float64(Sz) * np.float64(bz)) + W64 * (
            np.float64(Sz) * np.float64(cz))
        t32 = np.float32(T / det)
        bt = S32[F_BT + i]
        if t32 > np.float32(tmin) and ((t32 < bt) or (t32 == bt and ff < I32[F_BF + i])):
            S32[F_BT + i] = t32
            I32[F_BF + i] = ff
            nh = 1
    return nh


@njit(cache=True, _nrt=False, error_model="numpy")
def _test_mt32(S32, I32, na, q0x, q0y, q0z, q1x, q1y, q1z, q2x, q2y, q2z, ff, tmin32):
    """_test_mt in float32 over the packet, L32 rays at a time (vertices less the packet's
    reference origin, rounded).  Returns 1 if some ray was hit, else 0."""
    zero = np.float32(0.0)
    one = np.float32(1.0)
    nh = False
    e1x = q1x - q0x
    e1y = q1y - q0y
    e1z = q1z - q0z
    e2x = q2x - q0x
    e2y = q2y - q0y
    e2z = q2z - q0z
    for b in range((na + L32 - 1) // L32):
        for l in range(L32):
            i = b * L32 + l
            dx = S32[F_DX + i]
            dy = S32[F_DY + i]
            dz = S32[F_DZ + i]
            px = dy * e2z - dz * e2y
            py = dz * e2x - dx * e2z
            pz = dx * e2y - dy * e2x
            det = e1x * px + e1y * py + e1z * pz
            inv = one / det
            sx = S32[F_OX + i] - q0x
            sy = S32[F_OY + i] - q0y
            sz = S32[F_OZ + i] - q0z
            u = (sx * px + sy * py + sz * pz) * inv
            qx = sy * e1z - sz * e1y
            qy = sz * e1x - sx * e1z
            qz = sx * e1y - sy * e1x
            v = (dx * qx + dy * qy + dz * qz) * inv
            t = (e2x * qx + e2y * qy + e2z * qz) * inv
            bt = S32[F_BT + i]
            bf = I32[F_BF + i]
            hit = (det != zero) & (not ((u < zero) | (u > one))) & (not ((v < zero) | (u + v > one)))
            hit = hit & (t > tmin32) & ((t < bt) | ((t == bt) & (ff < bf)))
            S32[F_BT + i] = t if hit else bt
            I32[F_BF + i] = ff if hit else bf
            nh |= hit
    return int(nh)


@njit(cache=True)
def _outside(p0u, p0v, p0k, p1u, p1v, p1k, p2u, p2v, p2k, xr, u0, u1, v0, v1, su0, su1, sv0, sv1):
    """True when the triangle lies wholly beyond one of the packet's four bounding planes
    u = u0 + (k - xr) su0 (below), u = u1 + (k - xr) su1 (above), and likewise for v."""
    h0 = p0k - xr
    h1 = p1k - xr
    h2 = p2k - xr
    if p0u < u0 + h0 * su0 and p1u < u0 + h1 * su0 and p2u < u0 + h2 * su0:
        return True
    if p0u > u1 + h0 * su1 and p1u > u1 + h1 * su1 and p2u > u1 + h2 * su1:
        return True
    if p0v < v0 + h0 * sv0 and p1v < v0 + h1 * sv0 and p2v < v0 + h2 * sv0:
        return True
    return p0v > v1 + h0 * sv1 and p1v > v1 + h1 * sv1 and p2v > v1 + h2 * sv1


@njit(cache=True, _nrt=False)
def _finish(S, a, io, tests, cells, f32, S32, I32):
    """Active ray a's results into io (from the float32 tests' rows with f32)."""
    j = int(S[O_J + a])
    if f32:
        bf = np.float64(I32[F_BF + a])
        bt = np.float64(S32[F_BT + a])
    else:
        bf = S[O_BF + a]
        bt = S[O_BT + a]
    io[IO_T * PN + j] = bt if bf >= 0.0 else np.inf
    io[IO_F * PN + j] = bf
    io[IO_NT * PN + j] = tests
    io[IO_NC * PN + j] = cells


@njit(cache=True, _nrt=False, error_model="numpy")
def _count_final(S, na, xp, any_hit):
    """Flag (row CT0, free after setup) the active rays that are final once the packet has passed
    the K plane xp: their best t is at or before the t where they cross xp, or their segment ends
    there (or, any_hit, they have a hit).  Returns (final rays, rays with a hit that are not
    final).  A loop that vectorizes."""
    nf = 0
    pend = 0
    for i in range(na):
        te = (xp - S[O_OK + i]) * S[O_IDK + i]
        hit = S[O_BF + i] >= 0.0
        fin = (S[O_BT + i] <= te) | (S[O_T1 + i] <= te) | (any_hit & hit)
        S[O_CT0 + i] = 1.0 if fin else 0.0
        nf += fin
        pend += hit & (not fin)
    return nf, pend


@njit(cache=True, _nrt=False, error_model="numpy")
def _count_final32(S, S32, I32, na, xp, any_hit):
    """_count_final on the float32 tests' best t and triangle."""
    nf = 0
    pend = 0
    for i in range(na):
        te = (xp - S[O_OK + i]) * S[O_IDK + i]
        hit = I32[F_BF + i] >= 0
        fin = (np.float64(S32[F_BT + i]) <= te) | (S[O_T1 + i] <= te) | (any_hit & hit)
        S[O_CT0 + i] = 1.0 if fin else 0.0
        nf += fin
        pend += hit & (not fin)
    return nf, pend


@njit(cache=True, _nrt=False)
def _retire(S, na, io, watertight, tests, cells, f32, S32, I32):
    """Write out the rays flagged by _count_final and remove them from the active set; survivors
    from the end fill the gaps, so the active rays stay a contiguous prefix and each ray is moved
    at most once.  Returns the number of active rays left."""
    a = 0
    while a < na:
        if S[O_CT0 + a] == 0.0:
            a += 1
            continue
        _finish(S, a, io, tests, cells, f32, S32, I32)
        na -= 1
        while na > a and S[O_CT0 + na] != 0.0:
            _finish(S, na, io, tests, cells, f32, S32, I32)
            na -= 1
        if na > a:  # move the last surviving ray here: the rows read after setup
            for r in range(_R_SX):
                S[r * PN + a] = S[r * PN + na]
            r0, r1 = (_R_SX, _R_OX) if watertight else (_R_OX, _R_T0)
            for r in range(r0, r1):
                S[r * PN + a] = S[r * PN + na]
            if f32:  # the float32 rows of the test in use, and the best t and triangle
                q0, q1 = (_F_OU, _F_OX) if watertight else (_F_OX, _F_BT)
                for r in range(q0, q1):
                    S32[r * PN + a] = S32[r * PN + na]
                S32[F_BT + a] = S32[F_BT + na]
                I32[F_BF + a] = I32[F_BF + na]
            S[O_CT0 + a] = 0.0
            a += 1
    if f32:
        _dead32(S32, na)
    return na


@njit(cache=True, _nrt=False, error_model="numpy")
def _step(S, na, io, xp, any_hit, watertight, tests, cells, f32, S32, I32):
    """Retire the rays that are final at xp; returns (active rays, active rays with a hit).  With
    f32 the float32 tests' rows are read."""
    nf, pend = _count_final32(S, S32, I32, na, xp, any_hit) if f32 else _count_final(S, na, xp, any_hit)
    if nf == 0:
        return na, pend
    return _retire(S, na, io, watertight, tests, cells, f32, S32, I32), pend


@njit(cache=True, inline="always")
def direction_class(dx, dy, dz):
    """(c, dk): the permutation class of a direction, c = 2 * major axis + 1 where its component dk
    is negative (the watertight test's permutation, shear_setup's choice), without branches.
    Inlined where it is called, so the loops that call it still vectorize."""
    ax, ay, az = abs(dx), abs(dy), abs(dz)
    xmaj = (ax >= ay) & (ax >= az)
    ymaj = (not xmaj) & (ay >= az)
    dk = dx if xmaj else (dy if ymaj else dz)
    return (0 if xmaj else (2 if ymaj else 4)) + (1 if dk < 0.0 else 0), dk


@njit(cache=True, _nrt=False, error_model="numpy")
def _classify(io, n, S):
    """Of rays 0..n-1 of io, clipped (S rows CT0, CT1): how many meet the box and, over those, the
    least and the greatest permutation class (2 * major axis + 1 where its component is negative:
    the watertight test's permutation, shear_setup's choice) and how many have a tiny major
    component.  A loop that vectorizes."""
    nin = 0
    cmin = 6
    cmax = -1
    ntiny = 0
    for j in range(n):
        c, dk = direction_class(io[IO_DX * PN + j], io[IO_DY * PN + j], io[IO_DZ * PN + j])
        inside = S[O_CT0 + j] <= S[O_CT1 + j]
        cmin = min(cmin, c if inside else 6)
        cmax = max(cmax, c if inside else -1)
        nin += inside
        ntiny += inside & (not (abs(dk) >= TINY_DIR))
    return nin, cmin, cmax, ntiny


@njit(cache=True, _nrt=False, error_model="numpy")
def _gather(io, n, S, lo, hi, tmin):
    """Clip rays 0..n-1 of io to the grid box (lo, hi) and gather those that meet it into the
    active rows of S, their results in io reset to a miss.  Returns (active rays, K, neg,
    coherent): coherent when the active rays agree on the watertight test's permutation (major
    axis K of the direction and its sign, neg) and none has a tiny major component."""
    for j in range(n):
        S[O_CT0 + j] = tmin
        S[O_CT1 + j] = io[IO_TMAX * PN + j]
        io[IO_T * PN + j] = np.inf
        io[IO_F * PN + j] = -1.0
        io[IO_NT * PN + j] = 0.0
        io[IO_NC * PN + j] = 0.0
    _clip_axis(io, n, S, IO_OX, IO_DX, lo[0], hi[0])
    _clip_axis(io, n, S, IO_OY, IO_DY, lo[1], hi[1])
    _clip_axis(io, n, S, IO_OZ, IO_DZ, lo[2], hi[2])
    nin, cmin, cmax, ntiny = _classify(io, n, S)
    K, neg, uniform = cmin // 2, cmin % 2 == 1, cmin == cmax and ntiny == 0
    if nin == n:
        # every ray meets the box (the common case): straight row copies, which vectorize
        for j in range(n):
            S[O_OX + j] = io[IO_OX * PN + j]
            S[O_OY + j] = io[IO_OY * PN + j]
            S[O_OZ + j] = io[IO_OZ * PN + j]
            S[O_DX + j] = io[IO_DX * PN + j]
            S[O_DY + j] = io[IO_DY * PN + j]
            S[O_DZ + j] = io[IO_DZ * PN + j]
            S[O_T0 + j] = S[O_CT0 + j]
            S[O_T1 + j] = S[O_CT1 + j]
            S[O_BT + j] = io[IO_TMAX * PN + j]
            S[O_BF + j] = -1.0
            S[O_J + j] = j
        return n, K, neg, uniform
    na = 0  # some rays miss the box: gather the others
    for j in range(n):
        t0 = S[O_CT0 + j]
        t1 = S[O_CT1 + j]
        if not (t0 <= t1):
            continue
        S[O_OX + na] = io[IO_OX * PN + j]
        S[O_OY + na] = io[IO_OY * PN + j]
        S[O_OZ + na] = io[IO_OZ * PN + j]
        S[O_DX + na] = io[IO_DX * PN + j]
        S[O_DY + na] = io[IO_DY * PN + j]
        S[O_DZ + na] = io[IO_DZ * PN + j]
        S[O_T0 + na] = t0
        S[O_T1 + na] = t1
        S[O_BT + na] = io[IO_TMAX * PN + j]
        S[O_BF + na] = -1.0
        S[O_J + na] = j
        na += 1
    return na, K, neg, uniform


@njit(cache=True, _nrt=False)
def _trace_singly(g, S, na, io, tmin, watertight, any_hit, mb1):
    """The single-ray fallback of an incoherent packet: each active ray through trace_ray."""
    for a in range(na):
        j = int(S[O_J + a])
        f, t, u, v, nc, nt = trace_ray(
            g, S[O_OX + a], S[O_OY + a], S[O_OZ + a], S[O_DX + a], S[O_DY + a], S[O_DZ + a],
            tmin, S[O_BT + a], watertight, any_hit, mb1,
        )
        io[IO_T * PN + j] = t
        io[IO_F * PN + j] = f
        io[IO_NT * PN + j] = nt
        io[IO_NC * PN + j] = nc


@njit(cache=True, _nrt=False)
def _reference_plane(S, na, oD):
    """The K coordinate xr about which the packet's bounds are taken, beyond which (or before
    which) all ray segments lie: the near end (camera rays share their origin) or the far end
    (shadow rays converge on the light), whichever gives the tighter bounds.  On that one side
    the bounds are four planes, used to cull triangles (Wald et al. 2006, frustum culling).
    oD: the row of S holding d[K].  Returns (xr, side, xlo, xhi) and the bounding form about
    xr (see _spread): side is 1 for the near end, -1 for the far one, [xlo, xhi] the K range
    of the segments."""
    xlo = np.inf
    xhi = -np.inf
    for a in range(na):
        x0 = S[O_OK + a] + S[O_T0 + a] * S[oD + a]
        x1 = S[O_OK + a] + S[O_T1 + a] * S[oD + a]
        xlo = min(xlo, min(x0, x1))
        xhi = max(xhi, max(x0, x1))
    cu0, cu1, cv0, cv1, su0, su1, sv0, sv1 = _spread(S, na, xlo)
    e0, e1, e2, e3, e4, e5, e6, e7 = _spread(S, na, xhi)
    if (e1 - e0) + (e3 - e2) < (cu1 - cu0) + (cv1 - cv0):
        return xhi, -1.0, xlo, xhi, e0, e1, e2, e3, e4, e5, e6, e7
    return xlo, 1.0, xlo, xhi, cu0, cu1, cv0, cv1, su0, su1, sv0, sv1


@njit(cache=True)
def _strides(K, U, V, nx, ny):
    """Index steps along the axes K, U, V of an nx x ny x nz array of cells stored x fastest."""
    return (1 if K == 0 else (nx if K == 1 else nx * ny), 1 if U == 0 else (nx if U == 1 else nx * ny),
            1 if V == 0 else (nx if V == 1 else nx * ny))


@njit(cache=True)
def _extent(cu0, cu1, cv0, cv1, su0, su1, sv0, sv1, ha, hb, eU, eV):
    """The packet's (U, V) extent between the K planes at ha and hb from the reference plane,
    grown by (eU, eV): (ulo, uhi, vlo, vhi)."""
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


@njit(cache=True, _nrt=False)
def _any_macro_full(macro_full, mk, mu0, mu1, mv0, mv1, mstK, mstU, mstV):
    """True when a macro cell of slab mk within [mu0, mu1] x [mv0, mv1] holds triangles."""
    for mu in range(mu0, mu1 + 1):
        for mv in range(mv0, mv1 + 1):
            if macro_full[mk * mstK + mu * mstU + mv * mstV] != 0:
                return True
    return False


@njit(cache=True, _nrt=False)
def _prefetch_slice(tris, cell_start, tri_ids, ck, stU, stV, cu_0, cu_1, cv_0, cv_1):
    """Start the loads of the triangles of the cells [cu_0, cu_1] x [cv_0, cv_1] of one slice (ck:
    its first cell's index), so that their cache misses overlap instead of queueing."""
    for iu in range(cu_0, cu_1 + 1):
        for iv in range(cv_0, cv_1 + 1):
            c = ck + iu * stU + iv * stV
            for l in range(cell_start.shape[0]):
                for r in range(cell_start[l, c], cell_start[l, c + 1]):
                    _prefetch_tri(tris, tri_ids[r])


@njit(cache=True, _nrt=False, error_model="numpy")
def _test_slice(tris, cell_start, tri_ids, ck, stU, stV, cu_0, cu_1, cv_0, cv_1, U, V, K, box, planes, S, na, mb,
                watertight, tmin, f32, S32, I32, ref, tmin32, prof=None):
    """Test the triangles of the cells [cu_0, cu_1] x [cv_0, cv_1] of one slice (ck: its first
    cell's index) against the active rays: each once (the packet's mailbox mb), unless it lies
    outside the packet's extent in the slice (box = (ulo, uhi, vlo, vhi)) or beyond one of its
    four bounding planes (planes = (xr, the planes' offsets u0, u1, v0, v1 and slopes, see
    _outside)).  With f32 the tests run in float32 (_test_wt32 with its float64 fallback, or
    _test_mt32) on the float32 rows S32 and I32, vertices less the reference origin ref (see
    _setup32).
    Returns (cells visited, triangle tests, rays hit).  With ``prof`` the tests' cycles go to its
    P_TESTS slot."""
    rx, ry, rz, ru, rv, rk = ref
    ulo, uhi, vlo, vhi = box
    xr, pl_u0, pl_u1, pl_v0, pl_v1, sl_u0, sl_u1, sl_v0, sl_v1 = planes
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
                    if _outside(p0u, p0v, p0k, p1u, p1v, p1k, p2u, p2v, p2k, xr,
                                pl_u0, pl_u1, pl_v0, pl_v1, sl_u0, sl_u1, sl_v0, sl_v1):
                        continue  # the packet's bounds only shrink: it stays outside
                    tests += 1
                    t0 = _now(prof)
                    if f32 and watertight:
                        q0u, q0v, q0k = np.float32(p0u - ru), np.float32(p0v - rv), np.float32(p0k - rk)
                        q1u, q1v, q1k = np.float32(p1u - ru), np.float32(p1v - rv), np.float32(p1k - rk)
                        q2u, q2v, q2k = np.float32(p2u - ru), np.float32(p2v - rv), np.float32(p2k - rk)
                        nh, nz = _test_wt32(S32, I32, na, q0u, q0v, q0k, q1u, q1v, q1k, q2u, q2v, q2k, np.int32(f),
                                            tmin32)
                        hits += nh
                        if nz > 0:
                            hits += _fix_wt64(S32, I32, na, q0u, q0v, q0k, q1u, q1v, q1k, q2u, q2v, q2k, np.int32(f),
                                              tmin32)
                    elif f32:
                        hits += _test_mt32(
                            S32, I32, na, np.float32(np.float64(tris[f, 0, 0]) - rx),
                            np.float32(np.float64(tris[f, 0, 1]) - ry), np.float32(np.float64(tris[f, 0, 2]) - rz),
                            np.float32(np.float64(tris[f, 1, 0]) - rx), np.float32(np.float64(tris[f, 1, 1]) - ry),
                            np.float32(np.float64(tris[f, 1, 2]) - rz), np.float32(np.float64(tris[f, 2, 0]) - rx),
                            np.float32(np.float64(tris[f, 2, 1]) - ry), np.float32(np.float64(tris[f, 2, 2]) - rz),
                            np.int32(f), tmin32)
                    elif watertight:
                        hits += _test_wt(
                            S, na, p0u, p0v, p0k, p1u, p1v, p1k, p2u, p2v, p2k, np.float64(f), tmin)
                    else:
                        hits += _test_mt(
                            S, na, np.float64(tris[f, 0, 0]), np.float64(tris[f, 0, 1]),
                            np.float64(tris[f, 0, 2]), np.float64(tris[f, 1, 0]),
                            np.float64(tris[f, 1, 1]), np.float64(tris[f, 1, 2]),
                            np.float64(tris[f, 2, 0]), np.float64(tris[f, 2, 1]),
                            np.float64(tris[f, 2, 2]), np.float64(f), tmin)
                    _lap(prof, P_TESTS, t0)
    return cells, tests, hits


@njit(cache=True, _nrt=False)
def _move_far(g, n, io):
    """Rays 0..n-1 of io whose origins lie far outside the grid box start from just before it
    (:func:`gridrt.trace.traverse.far_shift`): their own origins and tmax go to rows XO, YO, ZO,
    TMO, their shifts to SH, SL and the verdict to MV; a ray that misses the box by far gets tmax
    -inf.  Returns how many rays are not NEAR."""
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


@njit(cache=True, _nrt=False)
def _restore_far(n, io, results):
    """Undo _move_far: the rays' own origins and tmax, and with ``results`` their hits' t from
    their own origins."""
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


@njit(cache=True, _nrt=False)
def _trace_rows_singly(g, n, io, tmin, watertight, any_hit, mb1):
    """Rays 0..n-1 of io, each through trace_ray."""
    for j in range(n):
        f, t, u, v, nc, nt = trace_ray(g, io[IO_OX * PN + j], io[IO_OY * PN + j], io[IO_OZ * PN + j],
                                       io[IO_DX * PN + j], io[IO_DY * PN + j], io[IO_DZ * PN + j], tmin,
                                       io[IO_TMAX * PN + j], watertight, any_hit, mb1)
        io[IO_T * PN + j] = t
        io[IO_F * PN + j] = f
        io[IO_NT * PN + j] = nt
        io[IO_NC * PN + j] = nc


@njit(cache=True, _nrt=False, error_model="numpy")
def trace_packet(g, n, io, tmin, watertight, any_hit, S, mb, mb1, max_cells=np.inf, prof=None, f32=False):
    """:func:`_trace_packet`, with rays from far outside the grid traced from just before its box
    as trace_ray traces them (:func:`gridrt.trace.traverse.far_shift`; with tmin > 0 such a
    packet's rays go one by one through trace_ray, or with a finite max_cells it returns -1).
    io's input rows are as they were on return."""
    if _move_far(g, n, io) == 0:
        return _trace_packet(g, n, io, tmin, watertight, any_hit, S, mb, mb1, max_cells, prof, f32)
    if tmin > 0.0:  # (the packet's rays share tmin; moved rays' would differ)
        _restore_far(n, io, False)
        if max_cells < np.inf:
            return -1
        _trace_rows_singly(g, n, io, tmin, watertight, any_hit, mb1)
        return n
    r = _trace_packet(g, n, io, tmin, watertight, any_hit, S, mb, mb1, max_cells, prof, f32)
    _restore_far(n, io, r >= 0)
    return r


@njit(cache=True, _nrt=False, error_model="numpy")
def _trace_packet(g, n, io, tmin, watertight, any_hit, S, mb, mb1, max_cells, prof, f32):
    """Trace rays 0..n-1 of the table io (NIO * PN,) float64 (origin, direction, tmax per ray)
    through the grid g (:class:`gridrt.trace.grids.GridArrays`).

    Fills io's result rows (IO_T, IO_F, IO_NT, IO_NC) with the hits :func:`trace_ray` finds
    (nearest, or with any_hit some hit, in (tmin, tmax)).  S (NS * PN,) float64 and mb (MBOX,)
    int32 are scratch; mb1 (MAILBOX,) int32 is the fallback DDA's mailbox.  Returns the number of
    rays traced by the single-ray fallback (0 when the packet was coherent).

    With a finite ``max_cells`` a packet is traced only when it is coherent and its bounds cover
    at most that many cells in the slice HORIZON cells from the reference plane; otherwise
    nothing is traced, io's results are undefined, and it returns -1 (the batch caster then
    traces those rays another way).

    ``prof`` ((NPROF,) int64, or None: nothing measured, and nothing of it compiled) adds the
    cycles of each phase (the P_* slots: gather, setup and bounds; macro-cell slab checks; slice
    ranges and prefetch; cell visits, mailbox and culls, with the triangle tests apart in
    P_TESTS; retiring rays; the single-ray fallback) and the counts C_* (packets, slices, cells,
    tests).  Profiling costs a counter read per phase and per test.

    With ``f32`` the triangle tests run in float32 (_test_wt32, _test_mt32: twice the lanes of a
    vector register), relative to the packet's reference origin (active ray 0's); the
    watertight test decides rays with an edge function exactly 0 in float64.  A ray's hit and
    its t then agree with the float64 tests' up to float32 rounding (about 1e-7 relative): at
    near-ties in t and within that distance of an edge, the triangle may differ.
    """
    t = _now(prof)
    tris, lo, cell, inv_cell, dims = g.tris, g.lo, g.cell, g.inv_cell, g.dims
    cell_start, tri_ids, M, mdims, macro_full = g.cell_start, g.tri_ids, g.macro, g.mdims, g.macro_full
    na, K, neg0, uniform = _gather(io, n, S, lo, g.hi, tmin)
    _prof_count(prof, C_PACKETS, 1)
    if na == 0:
        _lap(prof, P_SETUP, t)
        return 0
    if not uniform:
        if max_cells < np.inf:
            _lap(prof, P_SETUP, t)
            return -1
        t = _lap(prof, P_SETUP, t)
        _trace_singly(g, S, na, io, tmin, watertight, any_hit, mb1)
        _lap(prof, P_FALLBACK, t)
        return na

    # the permutation of shear_setup: kx = (kz + 1) % 3, ky = (kx + 1) % 3, swapped when d[kz] < 0
    U = (K + 1) % 3
    V = (U + 1) % 3
    if neg0:
        U, V = V, U
    _setup(S, na, U, V, K)
    S32 = S[O_F32:].view(np.float32)
    I32 = S[O_F32:].view(np.int32)
    ref = (S[O_OX], S[O_OY], S[O_OZ], S[O_OU], S[O_OV], S[O_OK])
    tmin32 = _up32(tmin)
    if f32:
        _setup32(S, S32, I32, na, ref, watertight)
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
        if g.leaf_first.shape[0] > 0:
            tc = (_floor_clamp((ref[0] - lo[0]) * inv_cell[0], dims[0]) + dims[0] * (
                _floor_clamp((ref[1] - lo[1]) * inv_cell[1], dims[1])
                + dims[1] * _floor_clamp((ref[2] - lo[2]) * inv_cell[2], dims[2])))
            if g.macro_full[tc] != 0:
                hK /= g.leaf_res[tc, K]
                iU *= g.leaf_res[tc, U]
                iV *= g.leaf_res[tc, V]
        h = min(xhi - xlo, HORIZON * hK) * side
        ulo, uhi, vlo, vhi = _extent(cu0, cu1, cv0, cv1, su0, su1, sv0, sv1, h - hK * side, h, eU, eV)
        if ((uhi - ulo) * iU + 1.0) * ((vhi - vlo) * iV + 1.0) > max_cells:
            _lap(prof, P_SETUP, t)
            return -1

    # first slice: where the earliest ray (in traversal order) enters the grid
    xs = xlo if sK > 0 else xhi
    k = _floor_clamp((xs - loK) * icK - sK * EPS_CELL, nK)
    for s in range(mb.shape[0]):
        mb[s] = -1
    xa = loK + (k if sK > 0 else k + 1) * cK
    if g.leaf_first.shape[0] > 0:
        _lap(prof, P_SETUP, t)
        _walk_2l(g, io, S, na, mb, U, V, K, sK, k, xa, xr, side, (cu0, cu1, cv0, cv1, su0, su1, sv0, sv1), eU, eV,
                 watertight, tmin, any_hit, f32, S32, I32, ref, tmin32)
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
        ulo, uhi, vlo, vhi = _extent(cu0, cu1, cv0, cv1, su0, su1, sv0, sv1, xa - xr, xm - xr, eU, eV)
        if _any_macro_full(macro_full, mk, _floor_clamp((ulo - loU) * icU, nU) // M,
                           _floor_clamp((uhi - loU) * icU, nU) // M, _floor_clamp((vlo - loV) * icV, nV) // M,
                           _floor_clamp((vhi - loV) * icV, nV) // M, mstK, mstU, mstV):
            t = _lap(prof, P_MACRO, t)
            while True:
                xb = loK + (k + 1 if sK > 0 else k) * cK
                ulo, uhi, vlo, vhi = _extent(cu0, cu1, cv0, cv1, su0, su1, sv0, sv1, xa - xr, xb - xr, eU, eV)
                pl_u0 = cu0 - eU
                pl_u1 = cu1 + eU
                pl_v0 = cv0 - eV
                pl_v1 = cv1 + eV
                sl_u0 = su0 if side > 0 else su1
                sl_u1 = su1 if side > 0 else su0
                sl_v0 = sv0 if side > 0 else sv1
                sl_v1 = sv1 if side > 0 else sv0
                cu_0, cu_1, cv_0, cv_1 = _cells_of((ulo, uhi, vlo, vhi), loU, icU, nU, loV, icV, nV)
                _prefetch_slice(tris, cell_start, tri_ids, k * stK, stU, stV, cu_0, cu_1, cv_0, cv_1)
                t = _lap(prof, P_SLICE, t)
                nc, nt, nh = _test_slice(
                    tris, cell_start, tri_ids, k * stK, stU, stV, cu_0, cu_1, cv_0, cv_1, U, V, K,
                    (ulo, uhi, vlo, vhi), (xr, pl_u0, pl_u1, pl_v0, pl_v1, sl_u0, sl_u1, sl_v0, sl_v1),
                    S, na, mb, watertight, tmin, f32, S32, I32, ref, tmin32, prof)
                t = _lap(prof, P_CELLS, t)
                _prof_count(prof, C_SLICES, 1)
                _prof_count(prof, C_CELLS, nc)
                _prof_count(prof, C_TESTS, nt)
                cells += nc
                tests += nt
                pending += nh
                xa = xb
                if pending > 0:
                    nb, pending = _step(S, na, io, xb, any_hit, watertight, tests, cells, f32, S32, I32)
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
        nb, pending = _step(S, na, io, xa, any_hit, watertight, tests, cells, f32, S32, I32)
        if nb != na:
            na = nb
            if na == 0:
                _lap(prof, P_RETIRE, t)
                return 0
            cu0, cu1, cv0, cv1, su0, su1, sv0, sv1 = _spread(S, na, xr)
        k = kend + sK
        t = _lap(prof, P_RETIRE, t)
    for a in range(na):
        _finish(S, a, io, tests, cells, f32, S32, I32)
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
def _advance(S, na, io, xp, any_hit, watertight, tests, cells, f32, S32, I32, xr, bounds):
    """_step at the K plane xp: returns (active rays, active rays with a hit, the packet's bounds
    about xr, taken again when rays left)."""
    nb, pending = _step(S, na, io, xp, any_hit, watertight, tests, cells, f32, S32, I32)
    if nb != na and nb > 0:
        bounds = _spread(S, nb, xr)
    return nb, pending, bounds


@njit(cache=True, _nrt=False, error_model="numpy")
def _walk_2l(g, io, S, na, mb, U, V, K, sK, k, xa, xr, side, bounds, eU, eV, watertight, tmin, any_hit, f32, S32, I32, ref,
             tmin32):
    """trace_packet's slice walk through a two-level grid g (gridrt.grid.two_level), from top
    slice k on (the packet's rays start at the K plane xa; mb is cleared): each top slice (fixed
    K index of the top level) that holds triangles within the packet's bounds is cut into R sub-slices, R the finest leaf resolution along K among its
    non-empty top cells within the bounds.  In each sub-slice, every non-empty top cell the
    packet's bounds overlap there has the leaf slices (fixed K index of its leaf grid) that the
    sub-slice reaches and the sub-slice before did not visited (_test_slice), each once and whole:
    the leaf cells the packet's bounds overlap over all of the leaf slice it crosses.  Then rays
    final at the sub-slice's far plane retire (trace_packet's termination rule: every leaf cell
    the rays crossed up to that plane has been visited).  Writes io's results for every active
    ray."""
    tris, lo, cell, inv_cell, dims = g.tris, g.lo, g.cell, g.inv_cell, g.dims
    cell_start, tri_ids, leaf_first, leaf_res, macro_full = g.cell_start, g.tri_ids, g.leaf_first, g.leaf_res, \
        g.macro_full
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
        ulo, uhi, vlo, vhi = _extent(cu0, cu1, cv0, cv1, su0, su1, sv0, sv1, xa - xr, xb - xr, eU, eV)
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
            ulo, uhi, vlo, vhi = _extent(cu0, cu1, cv0, cv1, su0, su1, sv0, sv1, xs_a - xr, xs_b - xr, eU, eV)
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
                        box = _extent(cu0, cu1, cv0, cv1, su0, su1, sv0, sv1, za - xr, zb - xr, eU, eV)
                        ju0, ju1, jv0, jv1 = _cells_of(box, sloU, iscU, rU, sloV, iscV, rV)
                        _prefetch_slice(tris, cell_start, tri_ids, q0 + jk * lK, lU, lV, ju0, ju1, jv0, jv1)
                        nc, nt, nh = _test_slice(
                            tris, cell_start, tri_ids, q0 + jk * lK, lU, lV, ju0, ju1, jv0, jv1, U, V, K, box, planes,
                            S, na, mb, watertight, tmin, f32, S32, I32, ref, tmin32)
                        cells += nc
                        tests += nt
                        pending += nh
            ptu0, ptu1, ptv0, ptv1 = qu0, qu1, qv0, qv1
            xs_p = xs_a
            xs_a = xs_b
            if pending > 0:
                na, pending, bounds = _advance(S, na, io, xs_b, any_hit, watertight, tests, cells, f32, S32, I32, xr,
                                               bounds)
                if na == 0:
                    return
                cu0, cu1, cv0, cv1, su0, su1, sv0, sv1 = bounds
        xa = xb
        # once per top slice: also retire rays whose segment has ended
        na, pending, bounds = _advance(S, na, io, xa, any_hit, watertight, tests, cells, f32, S32, I32, xr, bounds)
        if na == 0:
            return
        cu0, cu1, cv0, cv1, su0, su1, sv0, sv1 = bounds
        k += sK
    for a in range(na):
        _finish(S, a, io, tests, cells, f32, S32, I32)


@njit(cache=True, _nrt=False, error_model="numpy", inline="always")
def trace_packet_grids(grids, n, io, io2, tmin, watertight, any_hit, S, mb, mb1, f32):
    """:func:`trace_packet` over the tuple of grids, in order (as trace_grids does for one ray):
    each later grid's rays end at the hit found before it (nearest), or are skipped where one was
    found (any_hit).  io's IO_W row tells which grid the hit is in; io2 is scratch.  Returns the
    number of rays traced by the fallback."""
    nf = trace_packet(grids[0], n, io, tmin, watertight, any_hit, S, mb, mb1, np.inf, None, f32)
    for j in range(n):
        io[IO_W * PN + j] = 0.0
    for i in range(1, len(grids)):
        _chain_rays(io, io2, n, any_hit)
        nf += trace_packet(grids[i], n, io2, tmin, watertight, any_hit, S, mb, mb1, np.inf, None, f32)
        _merge_hits(io, io2, n, i)
    return nf


@njit(cache=True, _nrt=False)
def _chain_rays(io, io2, n, any_hit):
    """io's rays into io2, each ending where io found a hit (any_hit: not traced at all there)."""
    for j in range(n):
        for r in range(IO_TMAX):
            io2[r * PN + j] = io[r * PN + j]
        if io[IO_F * PN + j] >= 0.0:
            io2[IO_TMAX * PN + j] = -np.inf if any_hit else io[IO_T * PN + j]
        else:
            io2[IO_TMAX * PN + j] = io[IO_TMAX * PN + j]


@njit(cache=True, _nrt=False)
def _merge_hits(io, io2, n, which):
    """io2's hits (in grid ``which``) replace io's; the counters add up."""
    for j in range(n):
        if io2[IO_F * PN + j] >= 0.0:
            io[IO_T * PN + j] = io2[IO_T * PN + j]
            io[IO_F * PN + j] = io2[IO_F * PN + j]
            io[IO_W * PN + j] = which
        io[IO_NT * PN + j] += io2[IO_NT * PN + j]
        io[IO_NC * PN + j] += io2[IO_NC * PN + j]


@njit(cache=True, _nrt=False, error_model="numpy")
def _camera_rays(basis, W, H, px0, py0, pw, ph, io):
    """Camera rays of the pw x ph pixels from (px0, py0) into io, row by row.

    The directions are camera.pixel_dir's, operation for operation (so bit for bit; the tests
    compare whole images with the DDA kernel, which calls pixel_dir), with the basis read into
    locals first so that the loop vectorizes.
    """
    ex, ey, ez = basis[0, 0], basis[0, 1], basis[0, 2]
    f0, f1, f2 = basis[1, 0], basis[1, 1], basis[1, 2]
    r0, r1, r2 = basis[2, 0], basis[2, 1], basis[2, 2]
    u0, u1, u2 = basis[3, 0], basis[3, 1], basis[3, 2]
    th = basis[4, 0]
    asp = W / H
    for yy in range(ph):
        sy = (1.0 - 2.0 * (py0 + yy + 0.5) / H) * th
        row = np.uint64(yy * pw)  # unsigned indices: no wraparound test, so the loop vectorizes
        for xx in range(pw):
            j = row + np.uint64(xx)
            sx = (2.0 * (px0 + xx + 0.5) / W - 1.0) * th * asp
            dx = f0 + sx * r0 + sy * u0
            dy = f1 + sx * r1 + sy * u1
            dz = f2 + sx * r2 + sy * u2
            n = math.sqrt(dx * dx + dy * dy + dz * dz)
            io[_U_OX + j] = ex
            io[_U_OY + j] = ey
            io[_U_OZ + j] = ez
            io[_U_DX + j] = dx / n
            io[_U_DY + j] = dy / n
            io[_U_DZ + j] = dz / n
            io[_U_TMAX + j] = np.inf


@njit(cache=True, _nrt=False, error_model="numpy")
def _write_out(io, col, W, px0, py0, pw, ph, grids, img, tbuf, idbuf, costbuf, cellbuf):
    """Write a packet's results (io) and colours (col, 3 * PN) into the image buffers (the
    triangles' scene ids through the grids' ids maps when there are several grids), given
    flat: img (H * W * 4,) uint8, tbuf (H * W,) float32, idbuf, costbuf, cellbuf (H * W,) int32.
    Returns (hits, sum of tests, sum of cells).  Flat buffers and unsigned indices (no
    wraparound tests) let the row loop vectorize."""
    hits = 0
    tests = 0
    cells = 0
    for yy in range(ph):
        p0 = np.uint64((py0 + yy) * W + px0)
        jr = np.uint64(yy * pw)
        for xx in range(pw):
            p = p0 + np.uint64(xx)
            j = jr + np.uint64(xx)
            f = int(io[_U_F + j])
            nt = int(io[_U_NT + j])
            nc = int(io[_U_NC + j])
            tbuf[p] = np.float32(io[_U_T + j])
            idbuf[p] = f
            costbuf[p] = nt
            cellbuf[p] = nc
            q = np.uint64(4) * p
            img[q] = _u8(col[j])
            img[q + np.uint64(1)] = _u8(col[_U_PN + j])
            img[q + np.uint64(2)] = _u8(col[_U_2PN + j])
            img[q + np.uint64(3)] = np.uint8(255)
            hits += f >= 0
            tests += nt
            cells += nc
    if len(grids) > 1 and hits > 0:  # scene ids of the grids' triangles
        for yy in range(ph):
            for xx in range(pw):
                j = yy * pw + xx
                idbuf[(py0 + yy) * W + px0 + xx] = scene_id(grids, int(io[IO_W * PN + j]), int(io[IO_F * PN + j]))
    return hits, tests, cells


@njit(cache=True, _nrt=False)
def _prefetch_tile(ti, ntx, tile, W, H, img, tbuf, idbuf, costbuf, cellbuf):
    """Prefetch (for writing) the lines of the flat output buffers that tile ti covers."""
    tx0 = (ti % ntx) * tile
    ty0 = (ti // ntx) * tile
    tx1 = min(tx0 + tile, W)
    for y in range(ty0, min(ty0 + tile, H)):
        for x in range(tx0, tx1, 16):  # 16 pixels = one 64-byte line of a 4-byte buffer
            p = y * W + x
            _prefetch_write(tbuf, p)
            _prefetch_write(idbuf, p)
            _prefetch_write(costbuf, p)
            _prefetch_write(cellbuf, p)
            _prefetch_write(img, 4 * p)
        p = y * W + tx1 - 1  # the last line of the row when the tile is not line-aligned
        _prefetch_write(tbuf, p)
        _prefetch_write(idbuf, p)
        _prefetch_write(costbuf, p)
        _prefetch_write(cellbuf, p)
        _prefetch_write(img, 4 * p)


@njit(cache=True, _nrt=False, error_model="numpy")
def _render_tiles(
    grids, basis, W, H, tile, t0, t1, mode, shadows, light, off, watertight, f32, kw, kh,
    img, tbuf, idbuf, costbuf, cellbuf, S, io, io2, sio, sj, col, mb, mb1, acc,
):
    """Render tiles t0..t1-1 (row-major), each as packets of up to kw x kh pixels: trace and shade
    each packet (and its shadow rays as another packet) into the flat buffers (see _write_out).
    ``light`` is None without shadows: numba then compiles no shadow path at all (a first frame
    without shadows compiles about a third less), and the (3,) light position with them.
    Adds (hits, triangle tests, cells, fallback rays) to acc (4,) int64.  (One function without
    reference counting: numba would otherwise count references to every array argument of every
    call.)"""
    ntx = (W + tile - 1) // tile
    ex, ey, ez = basis[0, 0], basis[0, 1], basis[0, 2]
    if t0 < t1:
        _prefetch_tile(t0, ntx, tile, W, H, img, tbuf, idbuf, costbuf, cellbuf)
    for ti in range(t0, t1):
        tx0 = (ti % ntx) * tile
        ty0 = (ti // ntx) * tile
        tx1 = min(tx0 + tile, W)
        ty1 = min(ty0 + tile, H)
        if ti + 1 < t1:  # the next tile's output lines load while this tile is traced
            _prefetch_tile(ti + 1, ntx, tile, W, H, img, tbuf, idbuf, costbuf, cellbuf)
        for py0 in range(ty0, ty1, kh):
            for px0 in range(tx0, tx1, kw):
                pw = min(kw, tx1 - px0)
                ph = min(kh, ty1 - py0)
                n = pw * ph
                _camera_rays(basis, W, H, px0, py0, pw, ph, io)
                nfb = trace_packet_grids(grids, n, io, io2, 0.0, watertight, False, S, mb, mb1, f32)
                # colours into col (3 * PN), shadow rays of lit hits into sio
                m = 0
                for j in range(n):
                    f = int(io[IO_F * PN + j])
                    r, g, b = BACKGROUND[0], BACKGROUND[1], BACKGROUND[2]
                    if mode == 2:
                        r, g, b = cost_rgb(int(io[IO_NT * PN + j]))
                    elif f >= 0:
                        t = io[IO_T * PN + j]
                        dx = io[IO_DX * PN + j]
                        dy = io[IO_DY * PN + j]
                        dz = io[IO_DZ * PN + j]
                        nx, ny, nz, dn = facing_normal(grids[int(io[IO_W * PN + j])].tris, f, dx, dy, dz)
                        if mode == 1:
                            r, g, b = normal_rgb(nx, ny, nz)
                        else:
                            if light is None:  # no shadows: numba prunes the shadow path (light: NoneType)
                                s = -dn
                            else:
                                need, sox, soy, soz, lx, ly, lz, ld, s = shadow_ray(
                                    ex, ey, ez, t, dx, dy, dz, nx, ny, nz, light, off)
                                if need:
                                    sio[IO_OX * PN + m] = sox
                                    sio[IO_OY * PN + m] = soy
                                    sio[IO_OZ * PN + m] = soz
                                    sio[IO_DX * PN + m] = lx
                                    sio[IO_DY * PN + m] = ly
                                    sio[IO_DZ * PN + m] = lz
                                    sio[IO_TMAX * PN + m] = ld
                                    sj[m] = j
                                    col[j] = s  # lit unless the shadow ray hits something
                                    m += 1
                                    continue
                            r, g, b = lambert_rgb(s)
                    col[j] = r
                    col[PN + j] = g
                    col[2 * PN + j] = b
                if light is not None and m > 0:
                    nfb += trace_packet_grids(grids, m, sio, io2, 0.0, watertight, True, S, mb, mb1, f32)
                    for q in range(m):
                        j = sj[q]
                        r, g, b = lambert_rgb(col[j] if sio[IO_F * PN + q] < 0.0 else 0.0)
                        col[j] = r
                        col[PN + j] = g
                        col[2 * PN + j] = b
                hits, tests, cells = _write_out(io, col, W, px0, py0, pw, ph, grids, img, tbuf, idbuf, costbuf, cellbuf)
                acc[0] += hits
                acc[1] += tests
                acc[2] += cells
                acc[3] += nfb


@njit(cache=True)
def _sums(acc):
    """The column sums of acc (nch, 4) int64, in a new (4,) array.  (A loop: acc.sum(axis=0) would
    compile numba's string formatting for its axis error, a second on a cold start.)"""
    out = np.zeros(4, np.int64)
    for ch in range(acc.shape[0]):
        for k in range(4):
            out[k] += acc[ch, k]
    return out


@njit(cache=True)
def _chunking(W, H, tile):
    """(tiles, chunks, tiles per chunk): the frame's tiles in runs of consecutive tiles."""
    ntiles = ((W + tile - 1) // tile) * ((H + tile - 1) // tile)
    nch = min(ntiles, CHUNKS)
    return ntiles, nch, (ntiles + nch - 1) // nch


@njit(cache=True, parallel=True, error_model="numpy")
def cgt_render_kernel(
    grids, basis, W, H, tile, mode, shadows, light, off, watertight, f32, kw, kh, img, tbuf, idbuf, costbuf, cellbuf,
):
    """render_kernel (same arguments and f32, kw, kh; same buffers, same shading) with primary and
    shadow rays traced as packets of up to kw x kh pixels (at most PN rays) within each tile, their
    triangle tests in float32 with f32 (see trace_packet).  costbuf / cellbuf hold the CGT
    counters (see the module docstring).  Returns (4,) int64: pixels hit, the sums of costbuf and
    cellbuf, and the number of rays (primary and shadow) that took the single-ray fallback."""
    # scratch is allocated once per chunk (a run of consecutive tiles); call under
    # numba.parallel_chunksize(1) so threads take chunks dynamically.  The result does not
    # depend on the chunking or the scheduling.
    ntiles, nch, per = _chunking(W, H, tile)
    acc = np.zeros((nch, 4), np.int64)
    flat = pack_grids(grids)  # (a tuple of grids cannot enter the parallel loop as it is: see grids.py)
    for ch in prange(nch):
        _render_tiles(
            unpack_grids(flat), basis, W, H, tile, ch * per, min((ch + 1) * per, ntiles), mode, shadows, light, off,
            watertight, f32, kw, kh, img.reshape(H * W * 4), tbuf.reshape(H * W), idbuf.reshape(H * W), costbuf.reshape(H * W),
            cellbuf.reshape(H * W), np.empty(NS * PN), np.empty(NIO * PN), np.empty(NIO * PN), np.empty(NIO * PN),
            np.empty(PN, np.int64), np.empty(3 * PN), np.empty(MBOX, np.int32), np.empty(MAILBOX, np.int32), acc[ch],
        )
    return _sums(acc)


def cgt_render_serial(
    grids, basis, W, H, tile, mode, shadows, light, off, watertight, f32, kw, kh, img, tbuf, idbuf, costbuf, cellbuf,
):
    """cgt_render_kernel on one thread: all tiles in order, one scratch; the same buffers and sums
    bit for bit (tiles are independent).  A Python function around the kernel _render_tiles, so
    that a cold first frame compiles one level of kernels less: numba optimises and generates
    machine code for a kernel's whole call tree again at every level that wraps it (about 1 s
    here; gridrt.trace.twin)."""
    ntiles = ((W + tile - 1) // tile) * ((H + tile - 1) // tile)
    acc = np.zeros(4, np.int64)
    _render_tiles(
        grids, basis, W, H, tile, 0, ntiles, mode, shadows, light, off, watertight, f32, kw, kh,
        img.reshape(H * W * 4), tbuf.reshape(H * W), idbuf.reshape(H * W), costbuf.reshape(H * W),
        cellbuf.reshape(H * W), np.empty(NS * PN), np.empty(NIO * PN), np.empty(NIO * PN), np.empty(NIO * PN),
        np.empty(PN, np.int64), np.empty(3 * PN), np.empty(MBOX, np.int32), np.empty(MAILBOX, np.int32), acc,
    )
    return acc
