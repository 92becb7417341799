"""Kernels shared by every build strategy: bounds, triangle-to-cell ranges, the exact
triangle/box test, clearing, prefix sums and the macro-cell build.

All kernels take arrays, scalars and the grid's :data:`gridrt.grid.layout.GridBox` record, and
write into buffers they are given.  Cell coordinates are computed in float64 from the float32
triangles.
"""

import numpy as np
from numba import njit, prange

from ..compiles import inner
from .layout import INSERT_EPS

EPS = INSERT_EPS


# ---------------------------------------------------------------------------------------------
# scene bounds (+ the finiteness check that guards every later kernel)


BOUNDS_LANES = 48  # 16 vertices x 3 axes: lane l of a row holds axis l % 3
BAD_MAGNITUDE = 1e30  # coordinates beyond this are refused (cell arithmetic would overflow)


@inner(cache=True, _nrt=False)
def _bounds_lanes(flat, mn, mx, nan, out=None):
    """Lane-wise min/max of flat (a slice starting on a row boundary) into mn, mx (W,) (of flat's
    dtype), and nan (W,) += x - x, which turns NaN exactly when a NaN or infinity went by; with
    ``out`` (flat's size, float32), also out = float32(flat) in the same pass (without, numba
    compiles no store at all).

    Every lane is independent of the others, so LLVM turns the inner loop into SIMD min/max
    (a scalar min/max chain over the triangles runs at about a tenth of the speed).  Loops
    start at 0 on a slice, not at a signed offset: numba wraps negative indices, and with an
    offset of unknown sign LLVM keeps that check and vectorizes with gathers, 3-4x slower.
    np.minimum and np.maximum, not Python's min and max: with those a kernel compiled without
    parallel=True keeps the loop scalar (2.5-3.5x slower); they differ only for NaN, which the
    nan lanes report anyway.
    """
    W = BOUNDS_LANES
    rows = flat.shape[0] // W
    for r in range(rows):
        for l in range(W):
            x = flat[r * W + l]
            mn[l] = np.minimum(mn[l], x)
            mx[l] = np.maximum(mx[l], x)
            nan[l] += x - x
            if out is not None:
                out[r * W + l] = np.float32(x)
    for l in range(flat.shape[0] - rows * W):
        x = flat[rows * W + l]
        mn[l] = np.minimum(mn[l], x)
        mx[l] = np.maximum(mx[l], x)
        nan[l] += x - x
        if out is not None:
            out[rows * W + l] = np.float32(x)


@inner(cache=True)
def _bounds_chunk(flat, e0, e1, out, row):
    """out[row] = [xmin, ymin, zmin, xmax, ymax, zmax, bad] over the coordinates flat[e0:e1],
    bad = 1 when one of them is NaN, infinite or beyond BAD_MAGNITUDE."""
    W = BOUNDS_LANES
    mn = np.full(W, np.inf, np.float32)
    mx = np.full(W, -np.inf, np.float32)
    nan = np.zeros(W, np.float32)
    _bounds_lanes(flat[e0:e1], mn, mx, nan)
    bad = 0.0
    for a in range(3):
        lo = np.inf
        hi = -np.inf
        for l in range(a, W, 3):
            lo = min(lo, np.float64(mn[l]))
            hi = max(hi, np.float64(mx[l]))
            if not (nan[l] == 0.0):
                bad = 1.0
        if e1 > e0 and not (abs(lo) <= BAD_MAGNITUDE and abs(hi) <= BAD_MAGNITUDE):
            bad = 1.0
        out[row, a] = lo
        out[row, 3 + a] = hi
    out[row, 6] = bad


@njit(cache=True, parallel=True)
def scene_bounds(tris, n_chunks, out):
    """Per-chunk bounds of tris (F,3,3) float32 (C-contiguous) into out (n_chunks, 7) float64,
    in parallel: out[ch] = [xmin, ymin, zmin, xmax, ymax, zmax, bad] (see _bounds_chunk)."""
    flat = tris.reshape(tris.size)
    n_rows = flat.size // BOUNDS_LANES
    for ch in prange(n_chunks):
        e0 = ch * n_rows // n_chunks * BOUNDS_LANES
        e1 = (ch + 1) * n_rows // n_chunks * BOUNDS_LANES if ch < n_chunks - 1 else flat.size
        _bounds_chunk(flat, e0, e1, out, np.int64(ch))


@njit(cache=True)
def scene_bounds_serial(tris, out):
    """scene_bounds on one thread (small scenes: no parallel launch)."""
    flat = tris.reshape(tris.size)
    _bounds_chunk(flat, 0, flat.size, out, 0)


@njit(cache=True)
def bounds_f64(tris, out, as32=None):
    """scene_bounds_serial for float64 points, C-contiguous (F,3,3) triangles or (V,3) vertices:
    out (1, 7) float64 as there; with as32 (same shape, float32), also as32 = float32(tris) in the
    same pass (without, numba compiles no store)."""
    flat = tris.reshape(tris.size)
    W = BOUNDS_LANES
    mn = np.full(W, np.inf)
    mx = np.full(W, -np.inf)
    nan = np.zeros(W)
    if as32 is None:
        _bounds_lanes(flat, mn, mx, nan)
    else:
        _bounds_lanes(flat, mn, mx, nan, as32.reshape(as32.size))
    bad = 0.0
    for a in range(3):
        lo = np.inf
        hi = -np.inf
        for l in range(a, W, 3):
            lo = min(lo, mn[l])
            hi = max(hi, mx[l])
            if not (nan[l] == 0.0):
                bad = 1.0
        if flat.size > 0 and not (abs(lo) <= BAD_MAGNITUDE and abs(hi) <= BAD_MAGNITUDE):
            bad = 1.0
        out[0, a] = lo
        out[0, 3 + a] = hi
    out[0, 6] = bad


def point_bounds(a, as32=None):
    """(lo (3,), hi (3,), bad) of a C-contiguous float32 or float64 array of points, (F,3,3)
    triangles or (V,3) vertices, in one SIMD pass (the Python boundary's value check: reads the
    array within its shape only); bad: a NaN, an infinity or a coordinate beyond BAD_MAGNITUDE is
    among them.  ``as32`` (float32, a's shape; float64 ``a`` only) receives float32(a) in the same
    pass."""
    bb = np.empty((1, 7))
    if a.dtype == np.float32:
        scene_bounds_serial(a, bb)
    else:
        bounds_f64(a, bb, as32)
    return bb[0, 0:3], bb[0, 3:6], bb[0, 6] != 0.0


@njit(cache=True, _nrt=False)
def to_frame(src, ox, oy, oz, out):
    """out = float32(src - (ox, oy, oz)) per point, the difference taken in float64: src (N,3)
    float32 or float64, out (N,3) float32, both C-contiguous (checked by the caller; pass
    triangles as (3F, 3) views)."""
    for i in range(src.shape[0]):
        out[i, 0] = np.float32(np.float64(src[i, 0]) - ox)
        out[i, 1] = np.float32(np.float64(src[i, 1]) - oy)
        out[i, 2] = np.float32(np.float64(src[i, 2]) - oz)


@njit(cache=True, _nrt=False)
def first_nondegenerate(tris):
    """The index of the first triangle of tris (F,3,3) float32 with non-zero area, or -1 when every
    one has zero area: the same exact test as the cell-range pass (_ranges_block), which gives
    such triangles no cells."""
    for f in range(tris.shape[0]):
        ax = np.float64(tris[f, 0, 0])
        ay = np.float64(tris[f, 0, 1])
        az = np.float64(tris[f, 0, 2])
        ux = np.float64(tris[f, 1, 0]) - ax
        uy = np.float64(tris[f, 1, 1]) - ay
        uz = np.float64(tris[f, 1, 2]) - az
        vx = np.float64(tris[f, 2, 0]) - ax
        vy = np.float64(tris[f, 2, 1]) - ay
        vz = np.float64(tris[f, 2, 2]) - az
        if not ((uy * vz == uz * vy) and (uz * vx == ux * vz) and (ux * vy == uy * vx)):
            return f
    return -1


# ---------------------------------------------------------------------------------------------
# triangle -> cells


RANGE_LANES = 16  # triangles per block of the vectorized cell-range pass


@inner(cache=True, _nrt=False)
def _ranges_block(flat, n, lo, inv, top, out):
    """Cell ranges of n <= RANGE_LANES triangles: flat (9n,) float32 slice, out (6n,) int32, six
    values per triangle, (i0, j0, k0, i1, j1, k1), the inclusive range of cells its bounding box
    overlaps, grown by EPS cells and clamped to the grid: floor((x - lo) * inv_cell -/+ EPS).
    lo, inv (the grid's lo and inv_cell) and top (dims - 1) are tuples of three float64.

    A triangle of exactly zero area (collinear or coincident vertices) gets the empty range
    (0, 0, 0, -1, -1, -1): it has no surface to hit and goes into no cell.  The test is exact:
    differences of float32 coordinates and their products are exact in float64, so the cross
    product is exactly zero only for truly degenerate triangles.

    Branch-free over a short loop that starts at 0, so LLVM vectorizes it across triangles
    (about 4x the scalar speed).  Clamping the float cell coordinate to [0, dims-1] and then
    truncating gives the same integer as flooring and clamping the integer: the float is finite,
    and on [0, dims-1] truncation is floor.
    """
    lx, ly, lz = lo
    ix, iy, iz = inv
    mx, my, mz = top
    for l in range(n):
        ax = np.float64(flat[9 * l + 0])
        ay = np.float64(flat[9 * l + 1])
        az = np.float64(flat[9 * l + 2])
        bx = np.float64(flat[9 * l + 3])
        by = np.float64(flat[9 * l + 4])
        bz = np.float64(flat[9 * l + 5])
        cx = np.float64(flat[9 * l + 6])
        cy = np.float64(flat[9 * l + 7])
        cz = np.float64(flat[9 * l + 8])
        ux, uy, uz = bx - ax, by - ay, bz - az
        vx, vy, vz = cx - ax, cy - ay, cz - az
        degen = (uy * vz == uz * vy) & (uz * vx == ux * vz) & (ux * vy == uy * vx)
        i0 = min(max((min(ax, bx, cx) - lx) * ix - EPS, 0.0), mx)
        j0 = min(max((min(ay, by, cy) - ly) * iy - EPS, 0.0), my)
        k0 = min(max((min(az, bz, cz) - lz) * iz - EPS, 0.0), mz)
        i1 = min(max((max(ax, bx, cx) - lx) * ix + EPS, 0.0), mx)
        j1 = min(max((max(ay, by, cy) - ly) * iy + EPS, 0.0), my)
        k1 = min(max((max(az, bz, cz) - lz) * iz + EPS, 0.0), mz)
        out[6 * l + 0] = 0 if degen else np.int32(i0)
        out[6 * l + 1] = 0 if degen else np.int32(j0)
        out[6 * l + 2] = 0 if degen else np.int32(k0)
        out[6 * l + 3] = -1 if degen else np.int32(i1)
        out[6 * l + 4] = -1 if degen else np.int32(j1)
        out[6 * l + 5] = -1 if degen else np.int32(k1)


@njit(cache=True, _nrt=False)
def cell_ranges_into(flat, box, out):
    """Cell ranges of the triangles in flat (9n,) float32 into out (6n,) int32, six values each
    (see _ranges_block), in the grid ``box`` (layout.GridBox).  Pass slices: loops start at 0."""
    F = flat.shape[0] // 9
    lo = (box.lo[0], box.lo[1], box.lo[2])
    inv = (box.inv_cell[0], box.inv_cell[1], box.inv_cell[2])
    top = (np.float64(box.dims[0] - 1), np.float64(box.dims[1] - 1), np.float64(box.dims[2] - 1))
    B = RANGE_LANES
    nb = F // B
    for b in range(nb):
        _ranges_block(flat[9 * B * b:9 * B * (b + 1)], B, lo, inv, top, out[6 * B * b:6 * B * (b + 1)])
    _ranges_block(flat[9 * B * nb:], F - nb * B, lo, inv, top, out[6 * B * nb:])


@inner(cache=True)
def _axis_test(p0, p1, p2, r):
    """True when the projections p0..p2 of the triangle are separated from [-r, r]."""
    return min(p0, p1, p2) > r or max(p0, p1, p2) < -r


@inner(cache=True, _nrt=False)
def tri_box_overlap(tris, f, cx, cy, cz, hx, hy, hz):
    """Separating-axis test of triangle f against the box centre c, half-size h (float64).

    Akenine-Möller, "Fast 3D Triangle-Box Overlap Testing", JGT 2001.  The three box-normal
    axes are skipped: callers only test cells inside the triangle's bounding-box range.
    Touching counts as overlap; degenerate triangles fall through to True on zero axes.
    """
    v0x = tris[f, 0, 0] - cx
    v0y = tris[f, 0, 1] - cy
    v0z = tris[f, 0, 2] - cz
    v1x = tris[f, 1, 0] - cx
    v1y = tris[f, 1, 1] - cy
    v1z = tris[f, 1, 2] - cz
    v2x = tris[f, 2, 0] - cx
    v2y = tris[f, 2, 1] - cy
    v2z = tris[f, 2, 2] - cz
    e0x = v1x - v0x
    e0y = v1y - v0y
    e0z = v1z - v0z
    e1x = v2x - v1x
    e1y = v2y - v1y
    e1z = v2z - v1z
    e2x = v0x - v2x
    e2y = v0y - v2y
    e2z = v0z - v2z
    # plane
    nx = e0y * e1z - e0z * e1y
    ny = e0z * e1x - e0x * e1z
    nz = e0x * e1y - e0y * e1x
    d = nx * v0x + ny * v0y + nz * v0z
    r = hx * abs(nx) + hy * abs(ny) + hz * abs(nz)
    if abs(d) > r:
        return False
    # nine edge x axis cross products: a = e x X = (0, ez, -ey), etc.
    for ex, ey, ez in ((e0x, e0y, e0z), (e1x, e1y, e1z), (e2x, e2y, e2z)):
        # X axis: (0, ez, -ey)
        r = hy * abs(ez) + hz * abs(ey)
        if _axis_test(ez * v0y - ey * v0z, ez * v1y - ey * v1z, ez * v2y - ey * v2z, r):
            return False
        # Y axis: (-ez, 0, ex)
        r = hx * abs(ez) + hz * abs(ex)
        if _axis_test(-ez * v0x + ex * v0z, -ez * v1x + ex * v1z, -ez * v2x + ex * v2z, r):
            return False
        # Z axis: (ey, -ex, 0)
        r = hx * abs(ey) + hy * abs(ex)
        if _axis_test(ey * v0x - ex * v0y, ey * v1x - ex * v1y, ey * v2x - ex * v2y, r):
            return False
    return True


@inner(cache=True, _nrt=False)
def cell_overlaps(tris, f, i, j, k, lo, cell):
    """Exact-insertion test of triangle f against cell (i, j, k) grown by EPS cells."""
    hx = cell[0] * (0.5 + EPS)
    hy = cell[1] * (0.5 + EPS)
    hz = cell[2] * (0.5 + EPS)
    cx = lo[0] + (i + 0.5) * cell[0]
    cy = lo[1] + (j + 0.5) * cell[1]
    cz = lo[2] + (k + 0.5) * cell[2]
    return tri_box_overlap(tris, f, cx, cy, cz, hx, hy, hz)


# ---------------------------------------------------------------------------------------------
# clear / scan / macro cells


@inner(cache=True)
def _macro_cells_range(m, dims, k, mdims):
    mi = m % mdims[0]
    mj = (m // mdims[0]) % mdims[1]
    mk = m // (mdims[0] * mdims[1])
    i0 = mi * k
    j0 = mj * k
    k0 = mk * k
    return i0, j0, k0, min(i0 + k, dims[0]), min(j0 + k, dims[1]), min(k0 + k, dims[2])


@njit(cache=True)
def clear_macro_range(count, dims, k, mdims, macro_full, m0, m1):
    """Zero the counts of every layer's cells inside the non-empty macro cells m0..m1-1.

    count (L, C) int32 viewed with the PREVIOUS frame's dims; macro_full (M,) its flags.
    Cells of empty macro cells are already zero and are not touched (the clear of Ize et al. 2006).
    Returns the number of cells zeroed.
    """
    nx = dims[0]
    nxy = dims[0] * dims[1]
    L = count.shape[0]
    touched = 0
    for m in range(m0, m1):
        if macro_full[m] == 0:
            continue
        i0, j0, k0, i1, j1, k1 = _macro_cells_range(m, dims, k, mdims)
        for l in range(L):
            for kk in range(k0, k1):
                for jj in range(j0, j1):
                    base = kk * nxy + jj * nx
                    for ii in range(i0, i1):
                        count[l, base + ii] = 0
        touched += (i1 - i0) * (j1 - j0) * (k1 - k0) * L
    return touched


@njit(cache=True, parallel=True)
def clear_macro_parallel(count, dims, k, mdims, macro_full, n_threads, touched):
    """Parallel clear: thread t takes the t-th contiguous section of macro cells (as Ize et al. 2006).

    touched (n_threads,) int64 receives cells zeroed per thread (load-balance figure).
    """
    M = macro_full.shape[0]
    for t in prange(n_threads):
        touched[t] = clear_macro_range(count, dims, k, mdims, macro_full, t * M // n_threads, (t + 1) * M // n_threads)


@njit(cache=True)
def macro_build_range(count, dims, k, mdims, macro_full, z0, z1):
    """Flag the macro cells of macro-cell slabs z0..z1-1 (along z): 1 where one of its cells (in
    any layer) is non-empty.

    Band by band (a slab's k rows of macro cells along y), the counts of the band's cell rows
    are OR-ed into one row of scratch, a loop along x over contiguous cells that LLVM
    vectorizes; then each macro cell's k entries of that row decide its flag.  Every cell is
    read once, in memory order: 1.7-3.5x faster than scanning each macro cell's k^3 cells
    (k-long loops on k^2 rows) until a non-empty one, on scenes with 10-44 % of their macro cells
    full (BENCHMARKS.md section 2).  Returns the number of cells read."""
    nx, ny, nz = dims[0], dims[1], dims[2]
    nxy = nx * ny
    mdx, mdy = mdims[0], mdims[1]
    L = count.shape[0]
    row = np.empty(nx, np.int32)
    read = 0
    for mz in range(z0, z1):
        k0, k1 = mz * k, min(mz * k + k, nz)
        for my in range(mdy):
            j0, j1 = my * k, min(my * k + k, ny)
            row[:] = 0
            for l in range(L):
                for kk in range(k0, k1):
                    for jj in range(j0, j1):
                        base = kk * nxy + jj * nx
                        for ii in range(nx):
                            row[ii] |= count[l, base + ii]
            read += L * (k1 - k0) * (j1 - j0) * nx
            m0 = (mz * mdy + my) * mdx
            for mi in range(mdx):
                v = 0
                for ii in range(mi * k, min(mi * k + k, nx)):
                    v |= row[ii]
                macro_full[m0 + mi] = 1 if v != 0 else 0
    return read


@njit(cache=True, parallel=True)
def macro_build_parallel(count, dims, k, mdims, macro_full, n_threads, looked):
    """Parallel macro build, one contiguous run of macro-cell slabs (along z) per thread."""
    Z = mdims[2]
    for t in prange(n_threads):
        looked[t] = macro_build_range(count, dims, k, mdims, macro_full, t * Z // n_threads, (t + 1) * Z // n_threads)


@njit(cache=True)
def scan_inclusive(count, start):
    """start[c] = count[0] + ... + count[c] for c < C, start[C] = total; returns the total.

    count (C,) int32, start (C+1,) int32.  A scatter that pre-decrements start[c] then leaves
    start[c] at the first slot of cell c: the CSR offsets.
    """
    C = count.shape[0]
    s = scan_into(count, 0, start)
    start[C] = s
    return s


@njit(cache=True, _nrt=False)
def scan_into(count, s, out):
    """out[c] = s + count[0] + ... + count[c] over the slices count, out; returns the last sum.
    Callers pass slices so the loop index starts at 0 (see _bounds_lanes on signed offsets)."""
    for c in range(count.shape[0]):
        s += count[c]
        out[c] = s
    return s


@inner(cache=True, _nrt=False)
def sum_of(count):
    """Sum of an int32 slice as int64 (vectorized)."""
    s = 0
    for c in range(count.shape[0]):
        s += count[c]
    return s
