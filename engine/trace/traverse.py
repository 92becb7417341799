"""Single-ray traversal of the uniform grid: 3D DDA (Amanatides & Woo, "A Fast Voxel Traversal
Algorithm for Ray Tracing", Eurographics 1987) with empty macro cells skipped in one step and a
small per-ray mailbox so a triangle spanning several cells is tested once.

Termination: the nearest hit found so far is kept across cells; traversal stops once it lies
inside the current cell's t-range (t_hit <= t at which the ray leaves the cell).  Because
insertion is conservative (every cell a triangle's grown bounds touch), no nearer triangle can
be waiting in a later cell, and a triangle tested early whose hit lies in a later cell is not
lost to the mailbox.

Per-ray and per-triangle helpers that take arrays are compiled with ``_nrt=False``: they never
allocate, and without it numba reference-counts every array argument on every call (measured:
about 90 ns of a 110 ns ray that misses the grid).
"""

import math

import numpy as np
from numba import njit

from .intersect import intersect_fast, intersect_watertight, permute, shear_setup

#: mailbox slots per ray (direct-mapped by triangle id)
MAILBOX = 32
#: direction components smaller than this never step the DDA (their inverse would overflow to
#: inf and turn 0 * inf into NaN); over any representable t they move the ray by nothing.
TINY_DIR = 1e-300


@njit(cache=True)
def _floor_clamp(x, n):
    i = int(math.floor(x)) if x > -1e18 else -1
    if i < 0:
        return 0
    if i > n - 1:
        return n - 1
    return i


@njit(cache=True)
def _slab(o, d, lo, hi, t0, t1):
    """Clip [t0, t1] to the slab lo <= o + t d <= hi; returns an empty range (t0 > t1) on a miss."""
    if abs(d) < TINY_DIR:
        if o < lo or o > hi:
            return np.inf, -np.inf
        return t0, t1
    inv = 1.0 / d
    ta = (lo - o) * inv
    tb = (hi - o) * inv
    if ta > tb:
        ta, tb = tb, ta
    return max(t0, ta), min(t1, tb)


@njit(cache=True, _nrt=False)
def trace_ray(
    tris, lo, hi, cell, inv_cell, dims, cell_start, tri_ids, macro, mdims, macro_full,
    ox, oy, oz, dx, dy, dz, tmin, tmax, watertight, any_hit, mailbox,
):
    """Nearest (or, with any_hit, any) hit of one ray with tmin < t < tmax.

    Returns (tri, t, u, v, cells_visited, tests); tri = -1 and t = inf on a miss.
    mailbox (MAILBOX,) int32 scratch.
    """
    # clip the ray to the grid box (axis-parallel rays: a zero component never steps)
    t0, t1 = _slab(ox, dx, lo[0], hi[0], tmin, tmax)
    t0, t1 = _slab(oy, dy, lo[1], hi[1], t0, t1)
    t0, t1 = _slab(oz, dz, lo[2], hi[2], t0, t1)
    if not (t0 <= t1):
        return -1, np.inf, 0.0, 0.0, 0, 0

    nx, ny, nz = dims[0], dims[1], dims[2]
    px = ox + t0 * dx
    py = oy + t0 * dy
    pz = oz + t0 * dz
    ix = _floor_clamp((px - lo[0]) * inv_cell[0], nx)
    iy = _floor_clamp((py - lo[1]) * inv_cell[1], ny)
    iz = _floor_clamp((pz - lo[2]) * inv_cell[2], nz)
    sx = 0 if abs(dx) < TINY_DIR else (1 if dx > 0.0 else -1)
    sy = 0 if abs(dy) < TINY_DIR else (1 if dy > 0.0 else -1)
    sz = 0 if abs(dz) < TINY_DIR else (1 if dz > 0.0 else -1)
    idx = 1.0 / dx if sx != 0 else np.inf
    idy = 1.0 / dy if sy != 0 else np.inf
    idz = 1.0 / dz if sz != 0 else np.inf

    kx = ky = kz = 0
    okx = oky = okz = 0.0
    Sx = Sy = Sz = 0.0
    if watertight:
        kx, ky, kz, Sx, Sy, Sz = shear_setup(dx, dy, dz)
        okx, oky, okz = permute(ox, oy, oz, kx, ky, kz)
    for s in range(mailbox.shape[0]):
        mailbox[s] = -1
    mmask = mailbox.shape[0] - 1

    best_t = tmax
    best_f = -1
    best_u = 0.0
    best_v = 0.0
    cells = 0
    tests = 0
    L = cell_start.shape[0]
    k = macro
    mx, my = mdims[0], mdims[1]
    while True:
        mi = ix // k
        mj = iy // k
        mk = iz // k
        if macro_full[mi + mx * (mj + my * mk)] == 0:
            # leave the empty macro cell in one step
            bx = (lo[0] + min((mi + 1) * k, nx) * cell[0]) if sx > 0 else (lo[0] + mi * k * cell[0])
            by = (lo[1] + min((mj + 1) * k, ny) * cell[1]) if sy > 0 else (lo[1] + mj * k * cell[1])
            bz = (lo[2] + min((mk + 1) * k, nz) * cell[2]) if sz > 0 else (lo[2] + mk * k * cell[2])
            tx = (bx - ox) * idx if sx != 0 else np.inf
            ty = (by - oy) * idy if sy != 0 else np.inf
            tz = (bz - oz) * idz if sz != 0 else np.inf
            if tx <= ty and tx <= tz:
                te = tx
                ax = 0
            elif ty <= tz:
                te = ty
                ax = 1
            else:
                te = tz
                ax = 2
            if te > t1 or best_t <= te:
                break
            cpx = (ox + te * dx - lo[0]) * inv_cell[0]
            cpy = (oy + te * dy - lo[1]) * inv_cell[1]
            cpz = (oz + te * dz - lo[2]) * inv_cell[2]
            # along the exit axis: first cell of the next macro cell; others stay in this one
            if ax == 0:
                ix = (mi + 1) * k if sx > 0 else mi * k - 1
            else:
                ix = min(max(_floor_clamp(cpx, nx), mi * k), min((mi + 1) * k, nx) - 1)
            if ax == 1:
                iy = (mj + 1) * k if sy > 0 else mj * k - 1
            else:
                iy = min(max(_floor_clamp(cpy, ny), mj * k), min((mj + 1) * k, ny) - 1)
            if ax == 2:
                iz = (mk + 1) * k if sz > 0 else mk * k - 1
            else:
                iz = min(max(_floor_clamp(cpz, nz), mk * k), min((mk + 1) * k, nz) - 1)
            if ix < 0 or iy < 0 or iz < 0 or ix >= nx or iy >= ny or iz >= nz:
                break
            continue

        cells += 1
        c = ix + nx * (iy + ny * iz)
        for l in range(L):
            r0 = cell_start[l, c]
            r1 = cell_start[l, c + 1]
            for r in range(r0, r1):
                f = tri_ids[r]
                slot = f & mmask
                if mailbox[slot] == f:
                    continue
                mailbox[slot] = f
                tests += 1
                if watertight:
                    hit, t, u, v = intersect_watertight(
                        np.float64(tris[f, 0, kx]), np.float64(tris[f, 0, ky]), np.float64(tris[f, 0, kz]),
                        np.float64(tris[f, 1, kx]), np.float64(tris[f, 1, ky]), np.float64(tris[f, 1, kz]),
                        np.float64(tris[f, 2, kx]), np.float64(tris[f, 2, ky]), np.float64(tris[f, 2, kz]),
                        okx, oky, okz, Sx, Sy, Sz, tmin, best_t)
                else:
                    hit, t, u, v = intersect_fast(
                        np.float64(tris[f, 0, 0]), np.float64(tris[f, 0, 1]), np.float64(tris[f, 0, 2]),
                        np.float64(tris[f, 1, 0]), np.float64(tris[f, 1, 1]), np.float64(tris[f, 1, 2]),
                        np.float64(tris[f, 2, 0]), np.float64(tris[f, 2, 1]), np.float64(tris[f, 2, 2]),
                        ox, oy, oz, dx, dy, dz, tmin, best_t)
                if hit:
                    best_t = t
                    best_f = f
                    best_u = u
                    best_v = v
                    if any_hit:
                        return best_f, best_t, best_u, best_v, cells, tests
        # step to the next cell
        tx = (lo[0] + (ix + 1) * cell[0] - ox) * idx if sx > 0 else ((lo[0] + ix * cell[0] - ox) * idx if sx < 0 else np.inf)
        ty = (lo[1] + (iy + 1) * cell[1] - oy) * idy if sy > 0 else ((lo[1] + iy * cell[1] - oy) * idy if sy < 0 else np.inf)
        tz = (lo[2] + (iz + 1) * cell[2] - oz) * idz if sz > 0 else ((lo[2] + iz * cell[2] - oz) * idz if sz < 0 else np.inf)
        if tx <= ty and tx <= tz:
            te = tx
            ix += sx
        elif ty <= tz:
            te = ty
            iy += sy
        else:
            te = tz
            iz += sz
        if best_t <= te or te > t1:
            break
        if ix < 0 or iy < 0 or iz < 0 or ix >= nx or iy >= ny or iz >= nz:
            break
    if best_f < 0:
        return -1, np.inf, 0.0, 0.0, cells, tests
    return best_f, best_t, best_u, best_v, cells, tests

