"""Ray-triangle tests, float64 arithmetic on float32 triangles.

* Watertight: Woop, Benthin, Wald, "Watertight Ray/Triangle Intersection", JCGT 2(1), 2013.
  The ray is sheared so it runs along +z; the three 2D edge functions of a shared edge are
  computed from the same operands in both triangles, so their signs agree exactly and no ray
  slips between two triangles that share an edge or a vertex.
* Fast: Möller & Trumbore, "Fast, Minimum Storage Ray/Triangle Intersection", JGT 1997,
  without the edge-consistency guarantee (rays can pass through shared edges).

Both are double-sided and return (hit, t, u, v) with p = (1-u-v)*v0 + u*v1 + v*v2.
"""

import numpy as np
from numba import njit


@njit(cache=True)
def shear_setup(dx, dy, dz):
    """Per-ray constants of the watertight test: (kx, ky, kz, Sx, Sy, Sz)."""
    ax, ay, az = abs(dx), abs(dy), abs(dz)
    if ax >= ay and ax >= az:
        kz = 0
    elif ay >= az:
        kz = 1
    else:
        kz = 2
    kx = (kz + 1) % 3
    ky = (kx + 1) % 3
    d = (dx, dy, dz)
    if d[kz] < 0.0:
        kx, ky = ky, kx
    Sx = d[kx] / d[kz]
    Sy = d[ky] / d[kz]
    Sz = 1.0 / d[kz]
    return kx, ky, kz, Sx, Sy, Sz


@njit(cache=True)
def permute(x, y, z, kx, ky, kz):
    """(v[kx], v[ky], v[kz]) of the vector (x, y, z)."""
    v = (x, y, z)
    return v[kx], v[ky], v[kz]


@njit(cache=True)
def intersect_watertight(tris, f, okx, oky, okz, kx, ky, kz, Sx, Sy, Sz, tmin, tmax):
    """Woop et al. 2013 watertight test of triangle f; a hit needs tmin < t < tmax.

    (okx, oky, okz) is the ray origin permuted by (kx, ky, kz) (see :func:`permute`).
    """
    ax = np.float64(tris[f, 0, kx]) - okx
    ay = np.float64(tris[f, 0, ky]) - oky
    az = np.float64(tris[f, 0, kz]) - okz
    bx = np.float64(tris[f, 1, kx]) - okx
    by = np.float64(tris[f, 1, ky]) - oky
    bz = np.float64(tris[f, 1, kz]) - okz
    cx = np.float64(tris[f, 2, kx]) - okx
    cy = np.float64(tris[f, 2, ky]) - oky
    cz = np.float64(tris[f, 2, kz]) - okz
    Ax = ax - Sx * az
    Ay = ay - Sy * az
    Bx = bx - Sx * bz
    By = by - Sy * bz
    Cx = cx - Sx * cz
    Cy = cy - Sy * cz
    U = Cx * By - Cy * Bx
    V = Ax * Cy - Ay * Cx
    W = Bx * Ay - By * Ax
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


@njit(cache=True)
def intersect_fast(tris, f, ox, oy, oz, dx, dy, dz, tmin, tmax):
    """Möller-Trumbore test of triangle f (double-sided, not watertight)."""
    v0x = np.float64(tris[f, 0, 0])
    v0y = np.float64(tris[f, 0, 1])
    v0z = np.float64(tris[f, 0, 2])
    e1x = tris[f, 1, 0] - v0x
    e1y = tris[f, 1, 1] - v0y
    e1z = tris[f, 1, 2] - v0z
    e2x = tris[f, 2, 0] - v0x
    e2y = tris[f, 2, 1] - v0y
    e2z = tris[f, 2, 2] - v0z
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
