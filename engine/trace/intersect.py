"""Ray-triangle tests, float64 arithmetic on float32 triangles.

* Watertight: Woop, Benthin, Wald, "Watertight Ray/Triangle Intersection", JCGT 2(1), 2013.
  The ray is sheared so it runs along +z; the three 2D edge functions of a shared edge are
  computed from the same operands in both triangles, so their signs agree exactly and no ray
  slips between two triangles that share an edge or a vertex.
* Fast: Möller & Trumbore, "Fast, Minimum Storage Ray/Triangle Intersection", JGT 1997,
  without the edge-consistency guarantee (rays can pass through shared edges).

Both are double-sided and return (hit, t, u, v) with p = (1-u-v)*v0 + u*v1 + v*v2.
"""

from numba import njit

from ..compiles import inner
from .query import Shear


@inner(cache=True)
def shear_setup(dx, dy, dz):
    """Per-ray constants of the watertight test: (kx, ky, kz, Sx, Sy, Sz)."""
    ax, ay, az = abs(dx), abs(dy), abs(dz)
    if ax >= ay and ax >= az:
        kz = 0
        dkz = dx
    elif ay >= az:
        kz = 1
        dkz = dy
    else:
        kz = 2
        dkz = dz
    kx = (kz + 1) % 3
    ky = (kx + 1) % 3
    if dkz < 0.0:
        kx, ky = ky, kx
    Sx = _pick(dx, dy, dz, kx) / dkz
    Sy = _pick(dx, dy, dz, ky) / dkz
    Sz = 1.0 / dkz
    return kx, ky, kz, Sx, Sy, Sz


@inner(cache=True)
def _pick(x, y, z, k):
    return x if k == 0 else (y if k == 1 else z)


@inner(cache=True)
def permute(x, y, z, kx, ky, kz):
    """(v[kx], v[ky], v[kz]) of the vector (x, y, z)."""
    return _pick(x, y, z, kx), _pick(x, y, z, ky), _pick(x, y, z, kz)


@njit(cache=True, inline="always")
def ray_shear(o, d):
    """The :class:`gridrt.trace.query.Shear` of the ray from o along d (3-tuples): the watertight
    test's permutation, origin and shear (:func:`shear_setup`, :func:`permute`)."""
    kx, ky, kz, Sx, Sy, Sz = shear_setup(d[0], d[1], d[2])
    okx, oky, okz = permute(o[0], o[1], o[2], kx, ky, kz)
    return Shear(kx, ky, kz, okx, oky, okz, Sx, Sy, Sz)


@njit(cache=True, inline="always")
def woop_shear(p0, p1, p2, ok, Sx, Sy):
    """The vertices p0, p1, p2 (3-tuples) of Woop et al.'s test relative to the ray origin ok and
    sheared onto the plane across the ray: (Ax, Ay, Bx, By, Cx, Cy, az, bz, cz), in the precision
    of the arguments (everything permuted as for :func:`intersect_watertight`).  Inlined where it
    is called, so the packet loops that call it still vectorize."""
    p0x, p0y, p0z = p0
    p1x, p1y, p1z = p1
    p2x, p2y, p2z = p2
    okx, oky, okz = ok
    ax = p0x - okx
    ay = p0y - oky
    az = p0z - okz
    bx = p1x - okx
    by = p1y - oky
    bz = p1z - okz
    cx = p2x - okx
    cy = p2y - oky
    cz = p2z - okz
    return ax - Sx * az, ay - Sy * az, bx - Sx * bz, by - Sy * bz, cx - Sx * cz, cy - Sy * cz, az, bz, cz


@njit(cache=True, inline="always")
def gather_rows(tris, ids, i0, m, kx, ky, kz, rows, C):
    """The triangles ids[i0], ..., ids[i0 + m - 1] of tris ((F, 3, 3)) into the lanes 0..m-1 of
    the rows of ``rows`` (a row of C lanes each): row 3 v + a holds coordinate (kx, ky, kz)[a] of
    vertex v (permuted by a ray's shear, as :func:`woop_shear` takes them), in rows' precision;
    the loops that test C triangles side by side read them from there."""
    for j in range(m):
        f = ids[i0 + j]
        rows[j] = tris[f, 0, kx]
        rows[C + j] = tris[f, 0, ky]
        rows[2 * C + j] = tris[f, 0, kz]
        rows[3 * C + j] = tris[f, 1, kx]
        rows[4 * C + j] = tris[f, 1, ky]
        rows[5 * C + j] = tris[f, 1, kz]
        rows[6 * C + j] = tris[f, 2, kx]
        rows[7 * C + j] = tris[f, 2, ky]
        rows[8 * C + j] = tris[f, 2, kz]


@njit(cache=True, inline="always")
def woop_edges(Ax, Ay, Bx, By, Cx, Cy):
    """The edge functions (U, V, W) of a sheared triangle (see :func:`woop_shear`).  Each is a
    difference of two products of the same vertex coordinates, so a shared edge gives the two
    triangles exact negations in any precision."""
    return Cx * By - Cy * Bx, Ax * Cy - Ay * Cx, Bx * Ay - By * Ax


@njit(cache=True, inline="always")
def woop_terms(U, V, W, az, bz, cz, Sz):
    """Of a sheared triangle's edge functions (U, V, W, :func:`woop_edges`) and its vertices'
    distances along the ray (az, bz, cz, :func:`woop_shear`): (det, T, out) with det = U + V + W,
    T = det times the hit's t, and out whether the ray passes outside the triangle (the edge
    functions' signs differ), as :func:`intersect_watertight` computes them, without branches, for
    the loops that test several triangles or rays side by side and still vectorize."""
    return (U + V + W, U * (Sz * az) + V * (Sz * bz) + W * (Sz * cz),
            ((U < 0.0) | (V < 0.0) | (W < 0.0)) & ((U > 0.0) | (V > 0.0) | (W > 0.0)))


@inner(cache=True)
def intersect_watertight(p0, p1, p2, sh, tmin, tmax):
    """Woop et al. 2013 watertight test; a hit needs tmin < t < tmax.

    The vertices p0, p1, p2 (3-tuples) are given already permuted by the ray's (kx, ky, kz), as
    its origin is in its :class:`gridrt.trace.query.Shear` ``sh`` (see :func:`ray_shear`).
    """
    Sz = sh.Sz
    Ax, Ay, Bx, By, Cx, Cy, az, bz, cz = woop_shear(p0, p1, p2, (sh.okx, sh.oky, sh.okz), sh.Sx, sh.Sy)
    U, V, W = woop_edges(Ax, Ay, Bx, By, Cx, Cy)
    if (U < 0.0 or V < 0.0 or W < 0.0) and (U > 0.0 or V > 0.0 or W > 0.0):
        return False, 0.0, 0.0, 0.0
    det = U + V + W
    if det == 0.0:
        return False, 0.0, 0.0, 0.0
    T = U * (Sz * az) + V * (Sz * bz) + W * (Sz * cz)
    t = T / det
    if not (t > tmin and t < tmax):
        return False, 0.0, 0.0, 0.0
    return True, t, V / det, W / det


@inner(cache=True)
def intersect_fast(v0, v1, v2, o, d, tmin, tmax):
    """Möller-Trumbore test (double-sided, not watertight) of the triangle v0, v1, v2 with the ray
    from o along d (3-tuples)."""
    v0x, v0y, v0z = v0
    v1x, v1y, v1z = v1
    v2x, v2y, v2z = v2
    ox, oy, oz = o
    dx, dy, dz = d
    e1x = v1x - v0x
    e1y = v1y - v0y
    e1z = v1z - v0z
    e2x = v2x - v0x
    e2y = v2y - v0y
    e2z = v2z - v0z
    px = dy * e2z - dz * e2y
    py = dz * e2x - dx * e2z
    pz = dx * e2y - dy * e2x
    det = e1x * px + e1y * py + e1z * pz
    if det == 0.0:
        return False, 0.0, 0.0, 0.0
    inv = 1.0 / det
    sx = ox - v0x
    sy = oy - v0y
    sz = oz - v0z
    u = (sx * px + sy * py + sz * pz) * inv
    if u < 0.0 or u > 1.0:
        return False, 0.0, 0.0, 0.0
    qx = sy * e1z - sz * e1y
    qy = sz * e1x - sx * e1z
    qz = sx * e1y - sy * e1x
    v = (dx * qx + dy * qy + dz * qz) * inv
    if v < 0.0 or u + v > 1.0:
        return False, 0.0, 0.0, 0.0
    t = (e2x * qx + e2y * qy + e2z * qz) * inv
    if not (t > tmin and t < tmax):
        return False, 0.0, 0.0, 0.0
    return True, t, u, v
