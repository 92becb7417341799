"""Single-ray traversal of the uniform grid: 3D DDA (Amanatides & Woo, "A Fast Voxel Traversal
Algorithm for Ray Tracing", Eurographics 1987) in two nested loops: one over the macro cells (an
empty one is crossed in one step), one over the cells of a macro cell that holds triangles; and a
small per-ray mailbox so a triangle spanning several cells is tested once.  A cell crowded with
triangles (SIDE_BY_SIDE or more references) has them tested side by side instead, CHUNK at a time
in vector lanes, with the watertight test's arithmetic (:func:`_test_cell_wt`): a triangle met
again there is tested again, which gives the same t and changes no hit.

Termination: the nearest hit found so far is kept across cells; traversal stops once it lies
inside the current cell's t-range (t_hit <= t at which the ray leaves the cell).  Because
insertion is conservative (every cell a triangle's grown bounds touch), no nearer triangle can
be waiting in a later cell, and a triangle tested early whose hit lies in a later cell is not
lost to the mailbox.

Far origins: a ray whose origin lies far outside the grid (more than FAR_RADII half diagonals of
its box from the box's centre) is traced from a point of itself just before the box
(:func:`far_shift`, exact to that point's float64 rounding) and its t is measured from its own
origin again.  The packets (gridrt.trace.cgt.trace_packet) and the batch caster move such a ray
alike, so every traversal gives it the same hit: the exact ray's, for origins anywhere within the
coordinate limit (1e30; gridrt.arrays.check_ray_values).  What float64 cannot keep stays lost
before the traversal: a far origin moved into the frame of a scene far from the world origin
(``o - frame``, gridrt.trace.render.cast_batch, Camera.moved) is rounded at its own magnitude, and
shading from a far camera starts its shadow rays at ``eye + t d`` (exact within about 1e9 scene
sizes, where its rounding stays below the shadow offset).

Per-ray helpers that take arrays are compiled with ``_nrt=False``: they never allocate, and
without it numba reference-counts every array argument on every call (measured: about 90 ns of a
110 ns ray that misses the grid).  Such a function is not inlined into its callers, though, and a
call costs about 17 ns (measured: 23 against 6 ns per triangle test in a loop), so the
per-triangle test is inlined at numba's IR level instead (``inline="always"``).
"""

import math

import numpy as np
from numba import njit

from ..compiles import inner, one_per_types
from ..grid.two_level import leaf_axis
from .grids import is_two_level, with_leaves_only
from .intersect import (gather_rows, intersect_fast, intersect_watertight, ray_shear, woop_edges, woop_shear,
                        woop_terms)
from .prefetch import prefetch_range, prefetch_triangles
from .query import Ray, Shear

#: mailbox slots per ray (direct-mapped by triangle id)
MAILBOX = 32
#: a cell's references tested side by side by the watertight single-ray test (:func:`_test_cell_wt`)
CHUNK = 8
#: cells with at least this many references take _test_cell_wt, the others the scalar test
SIDE_BY_SIDE = 4
#: rows of CHUNK float64 of that test's scratch: 9 vertex coordinates, det, t, V and W
_CROWS = 13
#: int32 slots of a single ray's scratch (trace_ray's ``mailbox``): the mailbox, then the float64
#: rows of _test_cell_wt
SCRATCH = MAILBOX + 2 * _CROWS * CHUNK
#: direction components smaller than this never step the DDA (their inverse would overflow to
#: inf and turn 0 * inf into NaN); over any representable t they move the ray by nothing.
TINY_DIR = 1e-300
#: a ray whose origin lies farther than this many half diagonals of the grid box from the box's
#: centre (along some axis) is traced from just before the box (:func:`far_shift`): from far away
#: the float64 t of the box's near and far sides differ by a few ulps or not at all (at 3e16 from
#: a unit mesh), and the traversal's and the tests' differences of coordinates lose the mesh
FAR_RADII = 1024.0
#: origins farther than this from the box's centre are not moved (coordinates are limited to 1e30)
FAR_MAX = 2.0**110
#: far_shift's verdicts: the origin is near (traced as it is), moved, or the ray misses the box by far
NEAR, MOVED, FAR_MISS = 0, 1, 2


@inner(cache=True)
def _floor_clamp(x, n):
    i = int(math.floor(x)) if x > -1e18 else -1
    if i < 0:
        return 0
    if i > n - 1:
        return n - 1
    return i


@inner(cache=True)
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


@inner(cache=True)
def _cell_exit_t(lo, c, i, s, o, inv_d):
    """t at which a ray (origin coordinate o, 1 / direction inv_d, step s = -1, 0, 1) leaves cell
    i along one axis of a grid starting at lo with cells of size c; inf when it does not step."""
    if s > 0:
        return (lo + (i + 1) * c - o) * inv_d
    if s < 0:
        return (lo + i * c - o) * inv_d
    return np.inf


@inner(cache=True)
def _macro_exit_t(lo, c, mi, k, n, s, o, inv_d):
    """As _cell_exit_t for macro cell mi (k cells wide, the last one cut at the grid's n cells)."""
    if s == 0:
        return np.inf
    b = (lo + min((mi + 1) * k, n) * c) if s > 0 else (lo + mi * k * c)
    return (b - o) * inv_d


@inner(cache=True)
def _entry_cell(lo, ic, n, o, d, t, c0, c1, s, entered):
    """Cell index along one axis where a ray enters the macro cell of cells [c0, c1) at t: along
    the axis it entered through (``entered``) the macro cell's first cell on the ray's side,
    along the others the cell at o + t d, kept within the macro cell."""
    if entered:
        return c0 if s > 0 else c1 - 1
    return min(max(_floor_clamp((o + t * d - lo) * ic, n), c0), c1 - 1)


@inner(cache=True)
def _two_sum(a, b):
    """(s, e) with s = fl(a + b) and s + e = a + b exactly (Knuth)."""
    s = a + b
    bb = s - a
    return s, (a - (s - bb)) + (b - bb)


@inner(cache=True)
def _two_prod(a, b):
    """(p, e) with p = fl(a * b) and p + e = a * b exactly (Dekker; |a|, |b| far below 1e290)."""
    p = a * b
    c = 134217729.0 * a  # 2**27 + 1
    ah = c - (c - a)
    al = a - ah
    c = 134217729.0 * b
    bh = c - (c - b)
    bl = b - bh
    return p, ((ah * bh - p) + ah * bl + al * bh) + al * bl


@inner(cache=True)
def _add_prod(h, l, w, d):
    """The double-double h + l plus w * d (the product exact), as a double-double."""
    ph, pl = _two_prod(w, d)
    a, b = _two_sum(h, ph)
    c = b + (l + pl)
    s = a + c
    return s, c - (s - a)


@njit(cache=True, inline="always")
def is_far(lo, hi, ox, oy, oz):
    """True when far_shift moves the origin (ox, oy, oz): it lies more than FAR_RADII half
    diagonals r of the box lo..hi from the box's centre along some axis (squares compared: no
    square root on the path of every ray), within FAR_MAX, and the box is not a point.  Callers
    test it inline and call far_shift only for a far origin."""
    ex = hi[0] - lo[0]
    ey = hi[1] - lo[1]
    ez = hi[2] - lo[2]
    s = ex * ex + ey * ey + ez * ez
    m = max(abs(ox - 0.5 * (lo[0] + hi[0])), abs(oy - 0.5 * (lo[1] + hi[1])), abs(oz - 0.5 * (lo[2] + hi[2])))
    return m <= FAR_MAX and s > 0.0 and m * m > (0.25 * FAR_RADII * FAR_RADII) * s


def near_all(boxes, points):
    """(Python) True when no ray from any of the points (3-sequences) is far from any of the
    boxes (lo, hi) in :func:`is_far`'s sense, with a margin of 2 in distance (no rounding can
    make one far): a render whose rays start only at those points need not compile the far-ray
    path (gridrt.trace.records.Packets.far)."""
    for lo, hi in boxes:
        lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
        s = float(((hi - lo) ** 2).sum())
        c = 0.5 * (lo + hi)
        for p in points:
            m = float(np.abs(np.asarray(p, np.float64) - c).max())
            if not (s == 0.0 or m * m <= (0.25 * (0.5 * FAR_RADII) ** 2) * s):
                return False
    return True


@inner(cache=True)
def far_shift(lo, hi, ox, oy, oz, dx, dy, dz):
    """Where a ray from far outside the box lo..hi starts instead: (verdict, mx, my, mz, th, tl).

    NEAR: the origin lies within FAR_RADII half diagonals r of the box's centre c (or beyond
    FAR_MAX), and is traced as it is.  FAR_MISS: the ray heads away from the box (it cannot come
    within several r of c).  MOVED: (mx, my, mz) = o + (th + tl) d is a point 2 r to 4 r before
    the ray's closest approach to c, so outside the box (more than r from c), and the ray is
    traced from there with t measured from it: a hit t' from there is t = th + (tl + t') from o, tmin and
    tmax become (tmin - th) - tl (at least 0) and (tmax - th) - tl.

    The point is computed in steps, each aiming at 3 r before the closest approach from the point
    the last step reached (its aim is off by about 1e-16 of the distance it covers), adding w * d
    to the point exactly as a double-double per coordinate (Dekker's product, Knuth's sum), until
    the aim is within r: so the moved point lies on the ray up to its float64 rounding, for any
    distance up to FAR_MAX (float64 arithmetic on o itself would lose the mesh altogether).
    Every traversal (trace_ray, the packets of gridrt.trace.cgt, the batch caster's re-test)
    moves a ray alike, so all give it the same hit."""
    if not is_far(lo, hi, ox, oy, oz):
        return NEAR, ox, oy, oz, 0.0, 0.0
    cx = 0.5 * (lo[0] + hi[0])
    cy = 0.5 * (lo[1] + hi[1])
    cz = 0.5 * (lo[2] + hi[2])
    ex = hi[0] - lo[0]
    ey = hi[1] - lo[1]
    ez = hi[2] - lo[2]
    r = 0.5 * math.sqrt(ex * ex + ey * ey + ez * ez)
    dd = dx * dx + dy * dy + dz * dz
    dn = math.sqrt(dd)
    back = 3.0 * r / dn
    close = r / dn
    xh, yh, zh = ox, oy, oz
    xl = yl = zl = 0.0
    th = tl = 0.0
    for step in range(64):
        w = ((cx - (xh + xl)) * dx + (cy - (yh + yl)) * dy + (cz - (zh + zl)) * dz) / dd - back
        if step == 0 and not (w > 0.0):
            return FAR_MISS, ox, oy, oz, 0.0, 0.0
        if abs(w) <= close:
            break
        xh, xl = _add_prod(xh, xl, w, dx)
        yh, yl = _add_prod(yh, yl, w, dy)
        zh, zl = _add_prod(zh, zl, w, dz)
        th, e = _two_sum(th, w)
        tl += e
        th, tl = th + tl, tl - ((th + tl) - th)
    return MOVED, xh + xl, yh + yl, zh + zl, th, tl


@inner(cache=True)
def far_interval(tmin, tmax, th, tl):
    """(tmin, tmax) of a ray moved by far_shift's th + tl, from its new origin."""
    return max(0.0, (tmin - th) - tl), (tmax - th) - tl


@inner(cache=True)
def far_t(t, th, tl):
    """t from a ray's own origin for t from the origin far_shift moved it to (inf stays inf)."""
    return th + (tl + t)


@njit(cache=True, inline="always")
def _test_triangle(tris, f, watertight, sh, o, d, tmin, tmax):
    """Triangle f of tris against the ray from o along d: (hit, t, u, v) of intersect_watertight
    (vertices permuted and sheared by the ray's :class:`Shear` ``sh``) or of intersect_fast."""
    if watertight:
        kx, ky, kz = sh.kx, sh.ky, sh.kz
        return intersect_watertight(
            (np.float64(tris[f, 0, kx]), np.float64(tris[f, 0, ky]), np.float64(tris[f, 0, kz])),
            (np.float64(tris[f, 1, kx]), np.float64(tris[f, 1, ky]), np.float64(tris[f, 1, kz])),
            (np.float64(tris[f, 2, kx]), np.float64(tris[f, 2, ky]), np.float64(tris[f, 2, kz])),
            sh, tmin, tmax)
    return intersect_fast(
        (np.float64(tris[f, 0, 0]), np.float64(tris[f, 0, 1]), np.float64(tris[f, 0, 2])),
        (np.float64(tris[f, 1, 0]), np.float64(tris[f, 1, 1]), np.float64(tris[f, 1, 2])),
        (np.float64(tris[f, 2, 0]), np.float64(tris[f, 2, 1]), np.float64(tris[f, 2, 2])),
        o, d, tmin, tmax)


@njit(cache=True, inline="always")
def _clip_box(lo, hi, o, d, tmin, tmax):
    """[tmin, tmax] clipped to the grid box lo..hi for the ray from o along d (an empty range,
    t0 > t1, on a miss; a zero direction component never steps: axis-parallel rays)."""
    t0, t1 = _slab(o[0], d[0], lo[0], hi[0], tmin, tmax)
    t0, t1 = _slab(o[1], d[1], lo[1], hi[1], t0, t1)
    return _slab(o[2], d[2], lo[2], hi[2], t0, t1)


@njit(cache=True, inline="always")
def _ray_setup(lo, inv_cell, dims, o, d, t0, tmin, watertight, any_hit, mailbox):
    """A DDA's start: the cell (ix, iy, iz) where the ray from o along d (clipped to the grid box
    from t0 on) starts, the ray's :class:`Ray` (its steps (-1, 0, 1) and 1 / direction along each
    axis, the watertight test's permutation, origin and shear: zeros for the fast test; the
    query tmin, watertight, any_hit), with the mailbox (the first MAILBOX slots of the ray's
    scratch) cleared."""
    ox, oy, oz = o
    dx, dy, dz = d
    ix = _floor_clamp((ox + t0 * dx - lo[0]) * inv_cell[0], dims[0])
    iy = _floor_clamp((oy + t0 * dy - lo[1]) * inv_cell[1], dims[1])
    iz = _floor_clamp((oz + t0 * dz - lo[2]) * inv_cell[2], dims[2])
    sx = 0 if abs(dx) < TINY_DIR else (1 if dx > 0.0 else -1)
    sy = 0 if abs(dy) < TINY_DIR else (1 if dy > 0.0 else -1)
    sz = 0 if abs(dz) < TINY_DIR else (1 if dz > 0.0 else -1)
    idx = 1.0 / dx if sx != 0 else np.inf
    idy = 1.0 / dy if sy != 0 else np.inf
    idz = 1.0 / dz if sz != 0 else np.inf
    if watertight:
        sh = ray_shear(o, d)
    else:
        sh = Shear(0, 0, 0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    for s in range(MAILBOX):
        mailbox[s] = -1
    ray = Ray(o, d, (sx, sy, sz), (idx, idy, idz), sh, tmin, watertight, any_hit)
    return ix, iy, iz, ray


@njit(cache=True, inline="always")
def _test_refs(tris, tri_ids, r0, r1, mailbox, ray, best, tests):
    """The triangles tri_ids[r0:r1] of one cell against the :class:`Ray` ``ray``, each once (the
    mailbox, MAILBOX slots direct-mapped by triangle index): returns the nearest hit so far
    (best_f, best_t, best_u, best_v; ``best`` on entry), the tests counted on, and whether the
    search is over (any_hit and a hit)."""
    best_f, best_t, best_u, best_v = best
    for r in range(r0, r1):
        f = tri_ids[r]
        slot = f & (MAILBOX - 1)
        if mailbox[slot] == f:
            continue
        mailbox[slot] = f
        tests += 1
        hit, t, u, v = _test_triangle(tris, f, ray.watertight, ray.sh, ray.o, ray.d, ray.tmin, np.inf)
        # ties (the same t) go to the lowest triangle index, as in the packet loops, so a ray's
        # hit does not depend on the order in which a traversal meets the triangles
        if hit and (t < best_t or (t == best_t and f < best_f)):
            best_t = t
            best_f = f
            best_u = u
            best_v = v
            if ray.any_hit:
                return best_f, best_t, best_u, best_v, tests, True
    return best_f, best_t, best_u, best_v, tests, False


@njit(cache=True, inline="always")
def _test_cell_wt(tris, tri_ids, r0, r1, buf, ray, best, tests):
    """_test_refs for the watertight test, CHUNK references at a time: their vertices gathered
    into the float64 rows of buf (permuted by the ray's shear), intersect_watertight of each
    repeated operation for operation in one loop over CHUNK lanes that LLVM vectorizes (the
    lanes past the cell's references compute on stale scratch, unread), then the nearest (ties:
    the lowest triangle index) taken in order; u and v are divided out only for a new nearest
    hit.  No mailbox: a triangle met again in a later cell gives the same t and changes nothing
    (measured: the mailbox's test per reference costs more than the repeated lanes)."""
    sh = ray.sh
    kx, ky, kz = sh.kx, sh.ky, sh.kz
    okx, oky, okz, Sx, Sy, Sz = sh.okx, sh.oky, sh.okz, sh.Sx, sh.Sy, sh.Sz
    tmin = ray.tmin
    best_f, best_t, best_u, best_v = best
    C = CHUNK
    for c0 in range(r0, r1, C):
        m = min(C, r1 - c0)
        gather_rows(tris, tri_ids, c0, m, kx, ky, kz, buf, C)
        for j in range(C):  # (a fixed trip count: whole vectors, no scalar remainder; lanes m.. hold
            # whatever the scratch held, and their results are never read)
            Ax, Ay, Bx, By, Cx, Cy, az, bz, cz = woop_shear(
                (buf[j], buf[C + j], buf[2 * C + j]), (buf[3 * C + j], buf[4 * C + j], buf[5 * C + j]),
                (buf[6 * C + j], buf[7 * C + j], buf[8 * C + j]), (okx, oky, okz), Sx, Sy)
            U, V, W = woop_edges(Ax, Ay, Bx, By, Cx, Cy)
            det, T, out = woop_terms(U, V, W, az, bz, cz, Sz)
            # (a zero det, never a hit, divides by 1: the division cannot fail, and the loop has
            # no branch to keep it from vectorizing under numba's Python error model)
            t = T / (det if det != 0.0 else 1.0)
            hit = (not out) & (det != 0.0) & (t > tmin) & (t < np.inf)
            buf[9 * C + j] = det
            buf[10 * C + j] = t if hit else np.inf
            buf[11 * C + j] = V
            buf[12 * C + j] = W
        tests += m
        for j in range(m):
            t = buf[10 * C + j]
            if t <= best_t:
                f = tri_ids[c0 + j]
                if t < best_t or f < best_f:
                    best_t = t
                    best_f = f
                    best_u = buf[11 * C + j] / buf[9 * C + j]
                    best_v = buf[12 * C + j] / buf[9 * C + j]
        if ray.any_hit and best_f >= 0:
            return best_f, best_t, best_u, best_v, tests, True
    return best_f, best_t, best_u, best_v, tests, False


@njit(cache=True, inline="always")
def _test_cell(tris, tri_ids, cell_start, c, mailbox, buf, ray, best, tests):
    """The triangles of cell c (every layer of cell_start) against the :class:`Ray` ``ray``: side
    by side (:func:`_test_cell_wt`, scratch rows buf) when the watertight test is asked for and
    the cell holds SIDE_BY_SIDE references or more, else one by one with the mailbox
    (:func:`_test_refs`), their loads started first: their cache misses (the triangles of a cell
    lie anywhere in tris) then overlap instead of queueing one test at a time.  Returns what
    _test_refs returns."""
    L = cell_start.shape[0]
    best_f, best_t, best_u, best_v = best
    nref = 0
    for l in range(L):
        nref += cell_start[l, c + 1] - cell_start[l, c]
    side = ray.watertight and nref >= SIDE_BY_SIDE
    if not side:
        prefetch_triangles(tris, tri_ids, cell_start, c)
    for l in range(L):
        r0, r1 = cell_start[l, c], cell_start[l, c + 1]
        if side:
            best_f, best_t, best_u, best_v, tests, done = _test_cell_wt(
                tris, tri_ids, r0, r1, buf, ray, (best_f, best_t, best_u, best_v), tests)
        else:
            best_f, best_t, best_u, best_v, tests, done = _test_refs(
                tris, tri_ids, r0, r1, mailbox, ray, (best_f, best_t, best_u, best_v), tests)
        if done:
            return best_f, best_t, best_u, best_v, tests, True
    return best_f, best_t, best_u, best_v, tests, False


@njit(cache=True, inline="always")
def _next_cell(ray, lo, c, i, b0, b1):
    """One step of the inner DDA of the :class:`Ray` ``ray`` over cells of size c from lo: returns
    (t where the ray leaves cell i, the next cell's indices, True when that one lies outside the
    block [b0[0], b1[0]) x [b0[1], b1[1]) x [b0[2], b1[2]) the inner DDA walks)."""
    ix, iy, iz = i
    sx, sy, sz = ray.s
    tx = _cell_exit_t(lo[0], c[0], ix, sx, ray.o[0], ray.inv[0])
    ty = _cell_exit_t(lo[1], c[1], iy, sy, ray.o[1], ray.inv[1])
    tz = _cell_exit_t(lo[2], c[2], iz, sz, ray.o[2], ray.inv[2])
    if tx <= ty and tx <= tz:
        ix += sx
        return tx, ix, iy, iz, ix < b0[0] or ix >= b1[0]
    if ty <= tz:
        iy += sy
        return ty, ix, iy, iz, iy < b0[1] or iy >= b1[1]
    iz += sz
    return tz, ix, iy, iz, iz < b0[2] or iz >= b1[2]


@njit(cache=True, inline="always")
def _next_block(ray, tm, bi, m, mdims, k, lo, c, n):
    """One step of the outer DDA of the :class:`Ray` ``ray`` over blocks of k^3 cells (macro
    cells, or a two-level grid's top cells with k = 1) of an mdims array of them, in a grid of n
    cells of size c from lo; bi the current block's indices, m its linear index and tm its exits:
    returns (t where the ray leaves it, the axis it crosses, the next block's indices, its linear
    index and exits, True when the ray leaves the grid)."""
    tmx, tmy, tmz = tm
    mi, mj, mk = bi
    sx, sy, sz = ray.s
    mx, my, mz = mdims
    if tmx <= tmy and tmx <= tmz:
        te = tmx
        entered = 0
        mi += sx
        if mi < 0 or mi >= mx:
            return te, entered, mi, mj, mk, m, tmx, tmy, tmz, True
        m += sx
        tmx = _macro_exit_t(lo[0], c[0], mi, k, n[0], sx, ray.o[0], ray.inv[0])
    elif tmy <= tmz:
        te = tmy
        entered = 1
        mj += sy
        if mj < 0 or mj >= my:
            return te, entered, mi, mj, mk, m, tmx, tmy, tmz, True
        m += sy * mx
        tmy = _macro_exit_t(lo[1], c[1], mj, k, n[1], sy, ray.o[1], ray.inv[1])
    else:
        te = tmz
        entered = 2
        mk += sz
        if mk < 0 or mk >= mz:
            return te, entered, mi, mj, mk, m, tmx, tmy, tmz, True
        m += sz * mx * my
        tmz = _macro_exit_t(lo[2], c[2], mk, k, n[2], sz, ray.o[2], ray.inv[2])
    return te, entered, mi, mj, mk, m, tmx, tmy, tmz, False


@njit(cache=True, inline="always")
def _macro_start(lo, c, n, k, mdims, i, ray):
    """The macro cell (k^3 cells of size c from lo, mdims of them, in a grid of n cells) holding
    cell i of the :class:`Ray` ``ray``'s start: its indices, its linear index and the t where the
    ray leaves it along each axis."""
    mi, mj, mk = i[0] // k, i[1] // k, i[2] // k
    m = mi + mdims[0] * (mj + mdims[1] * mk)
    tmx = _macro_exit_t(lo[0], c[0], mi, k, n[0], ray.s[0], ray.o[0], ray.inv[0])
    tmy = _macro_exit_t(lo[1], c[1], mj, k, n[1], ray.s[1], ray.o[1], ray.inv[1])
    tmz = _macro_exit_t(lo[2], c[2], mk, k, n[2], ray.s[2], ray.o[2], ray.inv[2])
    return mi, mj, mk, m, tmx, tmy, tmz


@njit(cache=True, inline="always")
def _block_box(bi, k, n):
    """The cells [x0, x1) x [y0, y1) x [z0, z1) of macro cell bi (the last ones cut at the grid's
    n cells): ((x0, y0, z0), (x1, y1, z1))."""
    x0, y0, z0 = bi[0] * k, bi[1] * k, bi[2] * k
    return (x0, y0, z0), (min(x0 + k, n[0]), min(y0 + k, n[1]), min(z0 + k, n[2]))


@njit(cache=True, inline="always")
def _entry_cells(lo, inv_cell, n, ray, t_in, b0, b1, entered):
    """The cell where the :class:`Ray` ``ray`` enters the block of cells [b0, b1) at t_in through
    axis ``entered`` (:func:`_entry_cell` along each axis)."""
    o, d, s = ray.o, ray.d, ray.s
    return (_entry_cell(lo[0], inv_cell[0], n[0], o[0], d[0], t_in, b0[0], b1[0], s[0], entered == 0),
            _entry_cell(lo[1], inv_cell[1], n[1], o[1], d[1], t_in, b0[1], b1[1], s[1], entered == 1),
            _entry_cell(lo[2], inv_cell[2], n[2], o[2], d[2], t_in, b0[2], b1[2], s[2], entered == 2))


@one_per_types
@njit(cache=True, _nrt=False)
def trace_ray(g, o, d, tmin, tmax, watertight, any_hit, mailbox):
    """Nearest (or, with any_hit, any) hit with tmin < t < tmax of the ray from o along d (float64
    3-tuples) in the grid g (:class:`gridrt.trace.grids.GridArrays`).

    Returns (tri, t, u, v, cells_visited, tests); tri = -1 and t = inf on a miss.
    mailbox (SCRATCH,) int32 scratch (the mailbox, then the rows of _test_cell_wt).  A ray from
    far outside the grid is traced from just before its box (:func:`far_shift`).
    """
    moved = False
    th = tl = 0.0
    ox, oy, oz = o
    if is_far(g.lo, g.hi, ox, oy, oz):
        verdict, mx, my, mz, th, tl = far_shift(g.lo, g.hi, ox, oy, oz, d[0], d[1], d[2])
        if verdict == FAR_MISS:
            return -1, np.inf, 0.0, 0.0, 0, 0
        if verdict == MOVED:
            moved = True
            ox, oy, oz = mx, my, mz
            tmin, tmax = far_interval(tmin, tmax, th, tl)
    # one call site, inlined: a near ray pays one inline test for the far case
    f, t, u, v, nc, nt = _trace_near(g, (ox, oy, oz), d, tmin, tmax, watertight, any_hit, mailbox)
    if moved:
        t = far_t(t, th, tl)
    return f, t, u, v, nc, nt


@njit(cache=True, _nrt=False, inline="always")
def _trace_near(g, o, d, tmin, tmax, watertight, any_hit, mailbox):
    """:func:`trace_ray` from the origin as it is."""
    if is_two_level(g):
        return _trace_2l(g, o, d, tmin, tmax, watertight, any_hit, mailbox)
    tris, lo, hi, cell, inv_cell, dims = g.tris, g.lo, g.hi, g.cell, g.inv_cell, g.dims
    cell_start, tri_ids, macro, mdims, macro_full = g.cell_start, g.tri_ids, g.macro, g.mdims, g.macro_full
    t0, t1 = _clip_box(lo, hi, o, d, tmin, tmax)
    if not (t0 <= t1):
        return -1, np.inf, 0.0, 0.0, 0, 0

    nx, ny, nz = dims[0], dims[1], dims[2]
    ix, iy, iz, ray = _ray_setup(lo, inv_cell, dims, o, d, t0, tmin, watertight, any_hit, mailbox)
    buf = mailbox[MAILBOX:].view(np.float64)

    best_t = tmax
    best_f = -1
    best_u = 0.0
    best_v = 0.0
    cells = 0
    tests = 0
    l3 = (lo[0], lo[1], lo[2])
    c3 = (cell[0], cell[1], cell[2])
    n3 = (nx, ny, nz)
    # two nested DDAs: over macro cells (k^3 cells), and over the cells of each macro cell that
    # holds triangles.  The macro cell's indices and its exits along each axis are kept from
    # step to step (no integer division in the loop); a cell's indices are found only when its
    # macro cell holds triangles.
    k = macro
    mx, my, mz = mdims[0], mdims[1], mdims[2]
    mi, mj, mk, m, tmx, tmy, tmz = _macro_start(l3, c3, n3, k, (mx, my, mz), (ix, iy, iz), ray)
    entered = -1  # the axis the ray entered the current macro cell through (-1: it starts in it)
    t_in = t0
    while True:
        if macro_full[m] != 0:
            # the macro cell's cells: [b0, b1) (the last ones cut at the grid)
            b0, b1 = _block_box((mi, mj, mk), k, n3)
            if entered >= 0:
                ix, iy, iz = _entry_cells(l3, inv_cell, n3, ray, t_in, b0, b1, entered)
            c = ix + nx * (iy + ny * iz)
            while True:
                cells += 1
                # the next cell first (the step does not depend on the tests), and its range's load
                # started before the tests of this one
                te, ix, iy, iz, leaves = _next_cell(ray, l3, c3, (ix, iy, iz), b0, b1)
                cn = ix + nx * (iy + ny * iz)
                if not leaves:
                    prefetch_range(cell_start, cn)
                best_f, best_t, best_u, best_v, tests, done = _test_cell(
                    tris, tri_ids, cell_start, c, mailbox, buf, ray, (best_f, best_t, best_u, best_v), tests)
                if done:
                    return best_f, best_t, best_u, best_v, cells, tests
                if best_t <= te or te > t1:
                    return _result(best_f, best_t, best_u, best_v, cells, tests)
                if leaves:
                    break
                c = cn
        # step to the next macro cell (the macro DDA decides where the ray goes next, also when
        # the cell DDA left the macro cell through another face within rounding of a corner)
        te, entered, mi, mj, mk, m, tmx, tmy, tmz, out = _next_block(
            ray, (tmx, tmy, tmz), (mi, mj, mk), m, (mx, my, mz), k, l3, c3, n3)
        if out:
            break
        if te > t1 or best_t <= te:
            break
        t_in = te
    return _result(best_f, best_t, best_u, best_v, cells, tests)


@inner(cache=True, _nrt=False)
def trace_ray_2l(g, o, d, tmin, tmax, watertight, any_hit, mailbox):
    """:func:`trace_ray` through a two-level grid (gridrt.grid.two_level): a DDA over the top
    cells, and in each one that holds triangles a DDA over its own leaf cells from where the ray
    enters it, with the same termination rule (a hit at or before the t where the ray leaves the
    current leaf cell, or top cell, is final)."""
    tris, lo, hi, cell, inv_cell, dims = g.tris, g.lo, g.hi, g.cell, g.inv_cell, g.dims
    cell_start, tri_ids, leaf_first, leaf_res = g.cell_start, g.tri_ids, g.leaf_first, g.leaf_res
    t0, t1 = _clip_box(lo, hi, o, d, tmin, tmax)
    if not (t0 <= t1):
        return -1, np.inf, 0.0, 0.0, 0, 0

    ox, oy, oz = o
    dx, dy, dz = d
    nx, ny, nz = dims[0], dims[1], dims[2]
    ix, iy, iz, ray = _ray_setup(lo, inv_cell, dims, o, d, t0, tmin, watertight, any_hit, mailbox)
    buf = mailbox[MAILBOX:].view(np.float64)
    sx, sy, sz = ray.s
    lx, ly, lz = lo[0], lo[1], lo[2]
    cx, cy, cz = cell[0], cell[1], cell[2]
    l3 = (lx, ly, lz)
    c3 = (cx, cy, cz)
    n3 = (nx, ny, nz)

    best_t = tmax
    best_f = -1
    best_u = 0.0
    best_v = 0.0
    cells = 0
    tests = 0
    m = ix + nx * (iy + ny * iz)
    tmx = _macro_exit_t(lx, cx, ix, 1, nx, sx, ox, ray.inv[0])
    tmy = _macro_exit_t(ly, cy, iy, 1, ny, sy, oy, ray.inv[1])
    tmz = _macro_exit_t(lz, cz, iz, 1, nz, sz, oz, ray.inv[2])
    entered = -1  # the axis the ray entered the current top cell through (-1: it starts in it)
    t_in = t0
    while True:
        q0 = leaf_first[m]
        if leaf_first[m + 1] != q0:
            rx, ry, rz = leaf_res[m, 0], leaf_res[m, 1], leaf_res[m, 2]
            ax, bx, jx_ = leaf_axis(lx, cx, ix, rx)
            ay, by, jy_ = leaf_axis(ly, cy, iy, ry)
            az, bz, jz_ = leaf_axis(lz, cz, iz, rz)
            # the leaf cell where the ray enters (along the axis it entered through: the first
            # one on its side)
            if entered == 0:
                a = 0 if sx > 0 else rx - 1
            else:
                a = _floor_clamp((ox + t_in * dx - ax) * jx_, rx)
            if entered == 1:
                b = 0 if sy > 0 else ry - 1
            else:
                b = _floor_clamp((oy + t_in * dy - ay) * jy_, ry)
            if entered == 2:
                c = 0 if sz > 0 else rz - 1
            else:
                c = _floor_clamp((oz + t_in * dz - az) * jz_, rz)
            while True:
                cells += 1
                q = q0 + a + rx * (b + ry * c)
                best_f, best_t, best_u, best_v, tests, done = _test_cell(
                    tris, tri_ids, cell_start, q, mailbox, buf, ray, (best_f, best_t, best_u, best_v), tests)
                if done:
                    return best_f, best_t, best_u, best_v, cells, tests
                te, a, b, c, leaves = _next_cell(ray, (ax, ay, az), (bx, by, bz), (a, b, c), (0, 0, 0), (rx, ry, rz))
                if best_t <= te or te > t1:
                    return _result(best_f, best_t, best_u, best_v, cells, tests)
                if leaves:
                    break
        # the next top cell
        te, entered, ix, iy, iz, m, tmx, tmy, tmz, out = _next_block(
            ray, (tmx, tmy, tmz), (ix, iy, iz), m, n3, 1, l3, c3, n3)
        if out:
            break
        if te > t1 or best_t <= te:
            break
        t_in = te
    return _result(best_f, best_t, best_u, best_v, cells, tests)


#: (kernels only) :func:`trace_ray_2l`, compiled only for grids that carry leaf arrays (for the
#: others, a miss that is_two_level never lets run)
_trace_2l = with_leaves_only("_trace_2l", "g, o, d, tmin, tmax, watertight, any_hit, mailbox", trace_ray_2l,
                             (-1, np.inf, 0.0, 0.0, 0, 0))


@one_per_types
@inner(cache=True)
def _result(best_f, best_t, best_u, best_v, cells, tests):
    if best_f < 0:
        return -1, np.inf, 0.0, 0.0, cells, tests
    return best_f, best_t, best_u, best_v, cells, tests


@one_per_types
@njit(cache=True, _nrt=False)
def trace_grids(grids, o, d, tmin, tmax, watertight, any_hit, mailbox):
    """Nearest (or, with any_hit, any) hit of the ray from o along d over the tuple of grids, in
    order: each grid is searched up to the nearest hit found in the grids before it (with
    any_hit, the first hit ends the search).  Returns (which, tri, t, u, v, cells_visited, tests): the hit's grid number
    (0 on a miss) and the triangle's index in that grid, the counters summed over the grids
    searched."""
    which = 0
    best_f = -1
    best_t = np.inf
    best_u = 0.0
    best_v = 0.0
    cells = 0
    tests = 0
    i = 0
    for g in grids:
        f, t, u, v, nc, nt = trace_ray(g, o, d, tmin, best_t if best_f >= 0 else tmax, watertight, any_hit, mailbox)
        cells += nc
        tests += nt
        if f >= 0:
            which, best_f, best_t, best_u, best_v = i, f, t, u, v
            if any_hit:
                break
        i += 1
    return which, best_f, best_t, best_u, best_v, cells, tests
