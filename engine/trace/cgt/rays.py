"""A packet's rays: the layout of its ray tables (io: inputs and results; S: the active rays as
structure of arrays, float64 and float32 rows), gathering and clipping the rays, their per-ray
constants and bounds, the triangle tests over all active rays (float64 and float32), and retiring
the rays that are final."""

from collections import namedtuple

import numpy as np
from numba import njit, types
from numba.extending import overload

from ...compiles import inner, one_per_types
from ...config import PACKET_MAX
from ..intersect import woop_edges, woop_shear, woop_terms
from ..traverse import TINY_DIR


#: the render's default packet edge in pixels (RenderParams.packet: PK x PK pixels)
PK = 8
#: the largest packet edge (RenderParams.packet up to PK_MAX x PK_MAX pixels)
PK_MAX = PACKET_MAX
#: rays a packet table holds, and the stride of its rows: PK_MAX * PK_MAX, plus 16 so that rows
#: 2 KiB apart do not all fall into the same few cache sets, and a multiple of L32
PN = PK_MAX * PK_MAX + 16
#: per-packet mailbox slots (direct-mapped by triangle id; a power of two)
MBOX = 256

#: What a packet's trace asks of its rays (trace_packet): hits with t > tmin (float64), by the
#: watertight test or the fast one, the nearest or (any_hit) any, the triangle tests in float32
#: (f32 true) or float64 (f32 false, or None: then nothing of the float32 tests is compiled, see
#: rows32); far true where a ray may start far from the grid (trace_packet moves it nearer, see
#: gridrt.trace.traverse.far_shift), None where the caller knows none does (then nothing of that
#: path is compiled).  Each ray's tmax is its own, in the ray table.
PacketQuery = namedtuple("PacketQuery", "tmin watertight any_hit f32 far")

def rows32(S, f32):
    """(kernels only) The float32 rows of the packet scratch S (NS * PN,) float64, as the views
    (S32, I32) = (S[O_F32:] as float32, the same as int32); (None, None) where f32 is None (a
    float64 packet: PacketQuery.f32 None).  The float32 kernels (_setup32, _test_wt32, ...)
    return at once on S32 None, and numba compiles nothing else of them for float64 packets.
    Inlined at numba's IR level."""
    raise NotImplementedError("rows32 is only callable from numba kernels")


@overload(rows32, inline="always")
def _rows32(S, f32):
    if isinstance(f32, types.NoneType):
        return lambda S, f32: (None, None)
    return lambda S, f32: (S[O_F32:].view(np.float32), S[O_F32:].view(np.int32))


#: A coherent packet while it is traced: its ray table io, the active rays' rows S (float64) and
#: their float32 rows S32 / I32 (views of S, see O_F32), its mailbox mb, its :class:`PacketQuery`
#: q, tmin rounded up to float32 (tmin32) and its reference origin ref (x, y, z, u, v, k: active
#: ray 0's at setup, see _setup32).
Packet = namedtuple("Packet", "io S S32 I32 mb q tmin32 ref")


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


@one_per_types
@inner(cache=True, _nrt=False, error_model="numpy")
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


@inner(cache=True, _nrt=False)
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


@inner(cache=True, _nrt=False, error_model="numpy")
def _test_wt(S, na, p0, p1, p2, ff, tmin):
    """intersect_watertight of one triangle (vertices p0, p1, p2, 3-tuples permuted by the
    packet's kx, ky, kz) with the active rays, operation for operation; a hit below the ray's best
    t replaces it.  Returns the number of rays hit."""
    p0x, p0y, p0z = p0
    p1x, p1y, p1z = p1
    p2x, p2y, p2z = p2
    nh = 0
    for i in range(na):
        Sz = S[O_SZ + i]
        Ax, Ay, Bx, By, Cx, Cy, az, bz, cz = woop_shear((p0x, p0y, p0z), (p1x, p1y, p1z), (p2x, p2y, p2z),
                                                        (S[O_OU + i], S[O_OV + i], S[O_OK + i]), S[O_SX + i],
                                                        S[O_SY + i])
        U, V, W = woop_edges(Ax, Ay, Bx, By, Cx, Cy)
        det, T, out = woop_terms(U, V, W, az, bz, cz, Sz)
        t = T / det
        bt = S[O_BT + i]
        bf = S[O_BF + i]
        hit = (not out) & (det != 0.0) & (t > tmin) & ((t < bt) | ((t == bt) & (ff < bf)))
        S[O_BT + i] = t if hit else bt
        S[O_BF + i] = ff if hit else bf
        nh += hit
    return nh


@inner(cache=True, _nrt=False, error_model="numpy")
def _test_mt(S, na, v0, v1, v2, ff, tmin):
    """intersect_fast (Moller-Trumbore) of one triangle (vertices v0, v1, v2, 3-tuples) with the
    active rays, operation for operation.  Returns the number of rays hit."""
    v0x, v0y, v0z = v0
    v1x, v1y, v1z = v1
    v2x, v2y, v2z = v2
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


@inner(cache=True, _nrt=False, error_model="numpy")
def _setup32(S, S32, I32, na, ref, watertight):
    """The float32 rows of the active rays (see _F_OU), over whole blocks of L32 rays: origins less
    the packet's reference origin ref = (x, y, z, u, v, k), in float64 and then rounded; shear
    constants (watertight) or directions rounded; the best t rounded down (a hit beyond a ray's
    tmax stays beyond it) and the best triangle.  (S32 None: a float64 packet, see rows32.)"""
    if S32 is None:
        return
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


@inner(cache=True, _nrt=False)
def _dead32(S32, na):
    """Make the rays after the last active one up to its block of L32 inert in the float32 tests:
    a NaN origin fails every comparison (no hit, nothing undecided), so the test loops need not
    check which lanes are active."""
    if S32 is None:
        return
    nan = np.float32(np.nan)
    for i in range(na, (na + L32 - 1) // L32 * L32):
        S32[F_OU + i] = nan
        S32[F_OX + i] = nan
        S32[F_BT + i] = nan


@inner(cache=True, _nrt=False)
def _up32(x):
    """The smallest float32 at or above x (float64)."""
    b = np.float32(x)
    return np.nextafter(b, np.float32(np.inf)) if np.float64(b) < x else b


@njit(cache=True, _nrt=False, inline="always")
def _sheared32(S32, i, q0, q1, q2):
    """woop_shear in float32 of float32 ray i (rows of S32) and the vertices q0, q1, q2 (see
    _test_wt32)."""
    return woop_shear(q0, q1, q2, (S32[F_OU + i], S32[F_OV + i], S32[F_OK + i]), S32[F_SX + i], S32[F_SY + i])


@njit(cache=True, _nrt=False, error_model="numpy")
def _test_wt32(S32, I32, na, q0, q1, q2, ff, tmin32):
    """_test_wt in float32 over the packet, L32 rays at a time (16 lanes of a zmm register where
    512-bit vectors are enabled, see gridrt.threads): the vertices q0, q1, q2 (float32 3-tuples:
    permuted, less the packet's reference origin, rounded) against the float32 rows.  Shared vertices give every
    ray the same sheared coordinates in every triangle, so the edge functions of a shared edge
    are exact negations and the test stays watertight in float32 (Woop, Benthin, Wald 2013).  A
    ray for which an edge function is exactly 0 and the other signs do not already exclude the
    triangle is not decided here: it is counted in the second result, for _fix_wt64 to decide in
    float64.  Returns (1 if some ray was hit else 0, 1 if some ray is left to float64 else 0).
    (S32 None: a float64 packet, see rows32; nothing of this is compiled.)"""
    if S32 is None:
        return 0, 0
    zero = np.float32(0.0)
    nh = False  # (flags, not counts: an int64 count would halve the lanes of the loop)
    nz = False
    for b in range((na + L32 - 1) // L32):
        for l in range(L32):
            i = b * L32 + l
            Sz = S32[F_SZ + i]
            Ax, Ay, Bx, By, Cx, Cy, az, bz, cz = _sheared32(S32, i, q0, q1, q2)
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


@inner(cache=True, _nrt=False, error_model="numpy")
def _fix_wt64(S32, I32, na, q0, q1, q2, ff, tmin):
    """The rays _test_wt32 left undecided (an edge function exactly 0 in float32), decided in
    float64 as Woop et al. do: the edge functions again from the same float32 sheared vertex
    coordinates, whose products are exact in float64, so the signs are exact and agree with those
    every neighbouring triangle got in float32 (a shared edge still gives exact negations).  An
    edge function still 0 means the ray meets the edge or vertex exactly: both triangles count it.
    Returns 1 if some ray was hit, else 0."""
    if S32 is None:
        return 0
    zero = np.float32(0.0)
    nh = 0
    for i in range(na):
        Sz = S32[F_SZ + i]
        Ax, Ay, Bx, By, Cx, Cy, az, bz, cz = _sheared32(S32, i, q0, q1, q2)
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


@inner(cache=True, _nrt=False, error_model="numpy")
def _test_mt32(S32, I32, na, q0, q1, q2, ff, tmin32):
    """_test_mt in float32 over the packet, L32 rays at a time (vertices q0, q1, q2: float32
    3-tuples, less the packet's reference origin, rounded).  Returns 1 if some ray was hit, else 0."""
    if S32 is None:
        return 0
    q0x, q0y, q0z = q0
    q1x, q1y, q1z = q1
    q2x, q2y, q2z = q2
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


@inner(cache=True)
def _outside(p0, p1, p2, planes):
    """True when the triangle (vertices p0, p1, p2: (u, v, k) 3-tuples) lies wholly beyond one of
    the packet's four bounding planes, planes = (xr, u0, u1, v0, v1, su0, su1, sv0, sv1):
    u = u0 + (k - xr) su0 (below), u = u1 + (k - xr) su1 (above), and likewise for v."""
    p0u, p0v, p0k = p0
    p1u, p1v, p1k = p1
    p2u, p2v, p2k = p2
    xr, u0, u1, v0, v1, su0, su1, sv0, sv1 = planes
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


@one_per_types
@inner(cache=True, _nrt=False)
def _finish(pk, a, counts):
    """Active ray a's results into the packet's io (from the float32 tests' rows with f32), with
    its counters counts = (tests, cells)."""
    S, io = pk.S, pk.io
    tests, cells = counts
    j = int(S[O_J + a])
    if pk.q.f32:
        bt, bf = _best32(pk.S32, pk.I32, a)
    else:
        bf = S[O_BF + a]
        bt = S[O_BT + a]
    io[IO_T * PN + j] = bt if bf >= 0.0 else np.inf
    io[IO_F * PN + j] = bf
    io[IO_NT * PN + j] = tests
    io[IO_NC * PN + j] = cells


@inner(cache=True, _nrt=False)
def _best32(S32, I32, a):
    """Active ray a's best t and triangle in the float32 tests' rows, as float64."""
    if S32 is None:
        return 0.0, 0.0
    return np.float64(S32[F_BT + a]), np.float64(I32[F_BF + a])


@inner(cache=True, _nrt=False)
def _move32(S32, I32, a, b, watertight):
    """Active ray b's float32 rows (those of the test in use, and its best t and triangle) into
    row a."""
    if S32 is None:
        return
    q0, q1 = (_F_OU, _F_OX) if watertight else (_F_OX, _F_BT)
    for r in range(q0, q1):
        S32[r * PN + a] = S32[r * PN + b]
    S32[F_BT + a] = S32[F_BT + b]
    I32[F_BF + a] = I32[F_BF + b]


@inner(cache=True, _nrt=False, error_model="numpy")
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


@inner(cache=True, _nrt=False, error_model="numpy")
def _count_final32(S, S32, I32, na, xp, any_hit):
    """_count_final on the float32 tests' best t and triangle."""
    if S32 is None:
        return 0, 0
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


@one_per_types
@inner(cache=True, _nrt=False)
def _retire(pk, na, counts):
    """Write out the rays flagged by _count_final (with the counters counts = (tests, cells)) and
    remove them from the packet's active set; survivors from the end fill the gaps, so the active
    rays stay a contiguous prefix and each ray is moved at most once.  Returns the number of
    active rays left."""
    S, S32, I32 = pk.S, pk.S32, pk.I32
    watertight, f32 = pk.q.watertight, pk.q.f32
    a = 0
    while a < na:
        if S[O_CT0 + a] == 0.0:
            a += 1
            continue
        _finish(pk, a, counts)
        na -= 1
        while na > a and S[O_CT0 + na] != 0.0:
            _finish(pk, na, counts)
            na -= 1
        if na > a:  # move the last surviving ray here: the rows read after setup
            for r in range(_R_SX):
                S[r * PN + a] = S[r * PN + na]
            r0, r1 = (_R_SX, _R_OX) if watertight else (_R_OX, _R_T0)
            for r in range(r0, r1):
                S[r * PN + a] = S[r * PN + na]
            if f32:
                _move32(S32, I32, a, na, watertight)
            S[O_CT0 + a] = 0.0
            a += 1
    if f32:
        _dead32(S32, na)
    return na


@one_per_types
@inner(cache=True, _nrt=False, error_model="numpy")
def _step(pk, na, xp, counts):
    """Retire the packet's rays that are final at xp (counters counts = (tests, cells)); returns
    (active rays, active rays with a hit).  With f32 the float32 tests' rows are read."""
    S, any_hit = pk.S, pk.q.any_hit
    nf, pend = _count_final32(S, pk.S32, pk.I32, na, xp, any_hit) if pk.q.f32 else _count_final(S, na, xp, any_hit)
    if nf == 0:
        return na, pend
    return _retire(pk, na, counts), pend


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


@one_per_types
@inner(cache=True, _nrt=False, error_model="numpy")
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


@one_per_types
@inner(cache=True, _nrt=False, error_model="numpy")
def _gather(io, n, S, lo, hi, tmin, c):
    """Clip rays 0..n-1 of io to the grid box (lo, hi) and gather those that meet it into the
    active rows of S.  Returns (active rays, K, neg, coherent, least class, greatest class).

    With c < 0: every ray's results in io are reset to a miss, and the rays that meet the box are
    gathered when they are coherent: when they agree on the watertight test's permutation (major
    axis K of the direction and its sign, neg: the direction class 2 K + neg) and none has a tiny
    major component.  Otherwise none is gathered (active rays 0) and the least and greatest
    classes among them tell which classes to gather one by one.

    With c >= 0 (0..5): only the rays of direction class c that meet the box and have no tiny
    major component are gathered (K = c // 2, coherent), and no results are reset (the other
    classes' rays keep theirs).  A ray with a tiny major component (a zero or subnormal direction,
    or NaN: never a camera or shadow ray) then stays a miss."""
    for j in range(n):
        S[O_CT0 + j] = tmin
        S[O_CT1 + j] = io[IO_TMAX * PN + j]
    if c < 0:
        for j in range(n):
            io[IO_T * PN + j] = np.inf
            io[IO_F * PN + j] = -1.0
            io[IO_NT * PN + j] = 0.0
            io[IO_NC * PN + j] = 0.0
    _clip_axis(io, n, S, IO_OX, IO_DX, lo[0], hi[0])
    _clip_axis(io, n, S, IO_OY, IO_DY, lo[1], hi[1])
    _clip_axis(io, n, S, IO_OZ, IO_DZ, lo[2], hi[2])
    if c < 0:
        nin, cmin, cmax, ntiny = _classify(io, n, S)
        K, neg, uniform = cmin // 2, cmin % 2 == 1, cmin == cmax and ntiny == 0
        if not uniform:
            return 0, K, neg, False, cmin, cmax
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
            return n, K, neg, True, cmin, cmax
    else:
        K, neg, cmin, cmax = c // 2, c % 2 == 1, c, c
    na = 0  # some rays miss the box, or are of another class: gather the others
    for j in range(n):
        t0 = S[O_CT0 + j]
        t1 = S[O_CT1 + j]
        if not (t0 <= t1):
            continue
        if c >= 0:
            cj, dk = direction_class(io[IO_DX * PN + j], io[IO_DY * PN + j], io[IO_DZ * PN + j])
            if cj != c or not (abs(dk) >= TINY_DIR):
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
    return na, K, neg, True, cmin, cmax


@inner(cache=True, _nrt=False)
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


def packet_query(tmin, watertight, any_hit, f32, far=True):
    """The :class:`PacketQuery` with the types the kernels are compiled for (float64 tmin, bool
    flags, far True or None)."""
    return PacketQuery(float(tmin), bool(watertight), bool(any_hit), bool(f32), True if far else None)
