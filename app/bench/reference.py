"""Independent references for ``gridrt bench trade`` and ``gridrt bench peers``.

Nothing here calls the engine's grid or ray kernels: the benchmark measures the engine against
these, so they are written from the documented definitions only.

* :func:`brute_cast`: nearest hit of every ray over *all* triangles, double-sided
  Moller-Trumbore (Moller, Trumbore, JGT 2(1), 1997) in float64 on whatever vertex values it is
  given (float64 source geometry, or the float32 values the engine stores, widened).  A triangle
  is hit iff det != 0, u >= 0, v >= 0, u + v <= 1 and tmin < t < tmax.  O(rays x triangles):
  meant for a few thousand sampled rays, not whole images.
* :func:`sample_pixels` / :func:`pixel_rays`: a seeded random sample of pixels and their primary
  rays, from the pinhole model documented in ``engine/camera.py`` (re-derived here, not called).
* :func:`probe_rays`: rays aimed exactly at shared vertices and edges of a closed mesh from
  outside it, each from a direction in front of every face touching its target, so on a closed
  mesh a ray must hit some triangle no farther than its target (pbrt-v4's ``Triangle.Watertight``
  property, done on shared edges).  :func:`count_holes` counts the rays that do not.
"""

import math

import numpy as np
from numba import njit, prange

import gridrt  # noqa: F401  (sets NUMBA_NUM_THREADS before numba compiles anything)
from gridrt.errors import InputError
from gridrt.threads import check_threads, use_threads

#: a probe ray is a hole when it misses or hits farther than (1 + HOLE_REL) x its target distance
HOLE_REL = 1e-6
#: two hits closer than this (relative) are a tie: either triangle is a right answer
TIE_REL = 1e-9


@njit(cache=True, parallel=True)
def _brute_kernel(v0, e1, e2, origins, dirs, tmin, tmax, out_t, out_f, out_t2):
    """Nearest (t, triangle) and the nearest t of any other triangle, per ray, over all
    triangles.  v0, e1, e2 (F,3) float64; origins, dirs (N,3) float64; out_* (N,)."""
    N = origins.shape[0]
    F = v0.shape[0]
    for i in prange(N):
        ox, oy, oz = origins[i, 0], origins[i, 1], origins[i, 2]
        dx, dy, dz = dirs[i, 0], dirs[i, 1], dirs[i, 2]
        best = np.inf
        second = np.inf
        bf = -1
        for f in range(F):
            ax, ay, az = e1[f, 0], e1[f, 1], e1[f, 2]
            bx, by, bz = e2[f, 0], e2[f, 1], e2[f, 2]
            px = dy * bz - dz * by
            py = dz * bx - dx * bz
            pz = dx * by - dy * bx
            det = ax * px + ay * py + az * pz
            if det == 0.0:
                continue
            inv = 1.0 / det
            sx = ox - v0[f, 0]
            sy = oy - v0[f, 1]
            sz = oz - v0[f, 2]
            u = (sx * px + sy * py + sz * pz) * inv
            if u < 0.0 or u > 1.0:
                continue
            qx = sy * az - sz * ay
            qy = sz * ax - sx * az
            qz = sx * ay - sy * ax
            v = (dx * qx + dy * qy + dz * qz) * inv
            if v < 0.0 or u + v > 1.0:
                continue
            t = (bx * qx + by * qy + bz * qz) * inv
            if t <= tmin or t >= tmax:
                continue
            if t < best:
                second = best
                best = t
                bf = f
            elif t < second:
                second = t
        out_t[i] = best
        out_f[i] = bf
        out_t2[i] = second


def brute_cast(tris, origins, dirs, tmin=0.0, tmax=np.inf, threads=None):
    """Brute-force nearest hits in float64.

    tris (F,3,3) float32 or float64 (used as given, widened to float64); origins, dirs (N,3).
    Returns (t (N,) float64 [inf: miss], tri (N,) int64 [-1: miss], t2 (N,) float64: nearest t of
    any other triangle, so ties can be told).  Directions need not be unit length.
    """
    T = np.asarray(tris)
    if T.ndim != 3 or T.shape[1:] != (3, 3) or len(T) == 0:
        raise InputError(f"triangles must have shape (F, 3, 3) with F >= 1, got {T.shape}")
    T = T.astype(np.float64)
    if not np.isfinite(T).all():
        raise InputError("triangles contain NaN or infinity")
    o = np.ascontiguousarray(np.asarray(origins, np.float64).reshape(-1, 3))
    d = np.ascontiguousarray(np.asarray(dirs, np.float64).reshape(-1, 3))
    if o.shape != d.shape:
        raise InputError(f"origins and directions differ in shape: {o.shape} vs {d.shape}")
    if not (np.isfinite(o).all() and np.isfinite(d).all()):
        raise InputError("rays contain NaN or infinity")
    if len(d) and not (np.abs(d).max(axis=1) > 0).all():
        raise InputError("a ray direction is the zero vector")
    tmin, tmax = float(tmin), float(tmax)
    if math.isnan(tmin) or math.isnan(tmax) or tmin < 0 or tmax < tmin:
        raise InputError(f"need 0 <= tmin <= tmax, got tmin={tmin}, tmax={tmax}")
    v0 = np.ascontiguousarray(T[:, 0])
    e1 = np.ascontiguousarray(T[:, 1] - T[:, 0])
    e2 = np.ascontiguousarray(T[:, 2] - T[:, 0])
    N = len(o)
    t = np.empty(N)
    f = np.empty(N, np.int64)
    t2 = np.empty(N)
    if N:
        use_threads(check_threads(threads))
        _brute_kernel(v0, e1, e2, o, d, tmin, tmax, t, f, t2)
    return t, f, t2


# ----------------------------------------------------------------------------------------------
# sampled primary rays
# ----------------------------------------------------------------------------------------------


def sample_pixels(width, height, n, seed=0):
    """``min(n, W*H)`` distinct pixels drawn uniformly at random with numpy's default_rng(seed):
    (xs (n,) int64, ys (n,) int64), pixel (0, 0) top-left."""
    if n < 1:
        raise InputError(f"need at least one sample pixel, got {n}")
    total = int(width) * int(height)
    idx = np.random.default_rng(seed).choice(total, min(int(n), total), replace=False)
    idx.sort()
    return idx % width, idx // width


def pixel_rays(eye, target, up, fov, width, height, xs, ys):
    """Primary rays of pixels (xs, ys) of a W x H pinhole image, through pixel centres.

    fwd = normalize(target - eye), right = normalize(fwd x up), up' = right x fwd;
    d = normalize(fwd + sx right + sy up') with sx = (2 (x + 0.5) / W - 1) tan(fov/2) W/H and
    sy = (1 - 2 (y + 0.5) / H) tan(fov/2), fov vertical in degrees.
    Returns origins, unit dirs: (n, 3) float64.
    """
    eye = np.asarray(eye, np.float64)
    fwd = np.asarray(target, np.float64) - eye
    fwd = fwd / np.linalg.norm(fwd)
    right = np.cross(fwd, np.asarray(up, np.float64))
    right = right / np.linalg.norm(right)
    upv = np.cross(right, fwd)
    th = math.tan(math.radians(fov) / 2.0)
    xs = np.asarray(xs, np.float64)
    ys = np.asarray(ys, np.float64)
    sx = (2.0 * (xs + 0.5) / width - 1.0) * th * (width / height)
    sy = (1.0 - 2.0 * (ys + 0.5) / height) * th
    d = fwd + sx[:, None] * right + sy[:, None] * upv
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return np.broadcast_to(eye, d.shape).copy(), d


def compare_to_reference(tri, t, ref_tri, ref_t, ref_t2):
    """Per-sample comparison of engine hits (tri (n,), t (n,)) with a brute-force reference.

    A sample *differs* when the hit triangle differs (a hit against a miss counts), except for a
    *tie*: both hit, the reference's second-nearest triangle lies within TIE_REL of its nearest
    and the engine's t matches the reference's within 1e-6 (relative).  |dt| is taken over the
    samples where both hit.  Returns a dict: differs, ties, both_hit, dt_mean, dt_max,
    dt_rel_mean, dt_rel_max.
    """
    tri = np.asarray(tri, np.int64)
    t = np.asarray(t, np.float64)
    both = (tri >= 0) & (ref_tri >= 0)
    scale = np.maximum(np.abs(ref_t), 1e-30)
    with np.errstate(invalid="ignore"):
        tie = both & (tri != ref_tri) & (np.abs(ref_t2 - ref_t) <= TIE_REL * scale) & (
            np.abs(t - ref_t) <= 1e-6 * scale)
        dt = np.abs(t - ref_t)[both]
        rel = dt / scale[both]
    differs = (tri != ref_tri) & ~tie
    return dict(
        samples=int(len(tri)),
        differs=int(differs.sum()),
        ties=int(tie.sum()),
        both_hit=int(both.sum()),
        dt_mean=float(dt.mean()) if len(dt) else float("nan"),
        dt_max=float(dt.max()) if len(dt) else float("nan"),
        dt_rel_mean=float(rel.mean()) if len(rel) else float("nan"),
        dt_rel_max=float(rel.max()) if len(rel) else float("nan"),
    )


# ----------------------------------------------------------------------------------------------
# probe rays at shared vertices and edges of a closed mesh
# ----------------------------------------------------------------------------------------------


def _outward_normals(v, faces):
    t = v[faces]
    n = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
    vol6 = float(np.einsum("fc,fc->", t[:, 0], n))
    ln = np.linalg.norm(n, axis=1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        n = np.where(ln > 0, n / ln, 0.0)
    return n if vol6 > 0 else -n


def _edges(faces):
    """Unique undirected edges (E,2) and their two faces (E,2); InputError unless every edge has
    exactly two faces (closed, manifold)."""
    F = len(faces)
    e = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    fid = np.tile(np.arange(F), 3)
    key = e[:, 0].astype(np.int64) * (int(faces.max()) + 1) + e[:, 1]
    order = np.argsort(key, kind="stable")
    key, e, fid = key[order], e[order], fid[order]
    starts = np.flatnonzero(np.r_[True, key[1:] != key[:-1]])
    counts = np.diff(np.r_[starts, len(key)])
    if not (counts == 2).all():
        bad = int((counts != 2).sum())
        raise InputError(f"probe mesh is not closed and manifold: {bad} of {len(counts)} edges do not have "
                         "exactly two faces (holes can only be counted on a closed mesh)")
    return e[starts], np.stack([fid[starts], fid[starts + 1]], axis=1)


def _ranges(starts, lens):
    """Concatenation of arange(s, s + l) for each (s, l): (sum(lens),) int64."""
    lens = np.asarray(lens, np.int64)
    first = np.repeat(np.asarray(starts, np.int64) - np.concatenate([[0], np.cumsum(lens)[:-1]]), lens)
    return first + np.arange(int(lens.sum()))


def probe_rays(vertices, faces, n, seed=0, min_cos=0.1):
    """Rays from outside a closed mesh at its shared vertices and edges.

    vertices (V,3) (any float; used in float64), faces (F,3) int.  About a quarter of the targets
    are vertices, a quarter edge midpoints, the rest uniform random points on edges (targets in
    float64 from the given vertex values).  Each ray's direction u satisfies u . n > min_cos for
    every face touching its target (n: outward unit normals), and its origin lies beyond the
    mesh's bounding sphere, so the ray enters the mesh at its target.  Targets with no such
    direction (after 40 tries) are dropped.

    Returns origins (m,3) float64, unit dirs (m,3) float64, dist (m,) float64 = |target - origin|.
    """
    v = np.asarray(vertices, np.float64)
    faces = np.asarray(faces, np.int64)
    if v.ndim != 2 or v.shape[1] != 3 or faces.ndim != 2 or faces.shape[1] != 3 or not len(faces):
        raise InputError(f"probe mesh needs (V,3) vertices and (F,3) faces, got {v.shape} and {faces.shape}")
    if n < 1:
        raise InputError(f"need at least one probe ray, got {n}")
    rng = np.random.default_rng(seed)
    normals = _outward_normals(v, faces)
    edges, efaces = _edges(faces)
    # vertex fans (CSR)
    vf_v = faces.reshape(-1)
    vf_f = np.repeat(np.arange(len(faces)), 3)
    order = np.argsort(vf_v, kind="stable")
    vf_v, vf_f = vf_v[order], vf_f[order]
    vstart = np.searchsorted(vf_v, np.arange(len(v) + 1))
    used = np.flatnonzero(np.diff(vstart) > 0)
    n_vert = min(n // 4, len(used))
    n_mid = min(n // 4, len(edges))
    n_rand = n - n_vert - n_mid
    vids = rng.choice(used, n_vert, replace=False)
    mids = rng.choice(len(edges), n_mid, replace=False)
    rids = rng.integers(0, len(edges), n_rand)
    s = rng.uniform(0.0, 1.0, (n_rand, 1))
    a, b = v[edges[rids, 0]], v[edges[rids, 1]]
    targets = np.concatenate([v[vids], 0.5 * (v[edges[mids, 0]] + v[edges[mids, 1]]), a + s * (b - a)])
    vfan_len = vstart[vids + 1] - vstart[vids]
    lens = np.concatenate([vfan_len, np.full(n_mid + n_rand, 2)])
    fan = np.concatenate([vf_f[_ranges(vstart[vids], vfan_len)], efaces[mids].reshape(-1),
                          efaces[rids].reshape(-1)]).astype(np.int64)
    offs = np.concatenate([[0], np.cumsum(lens)])
    navg = np.add.reduceat(normals[fan], offs[:-1], axis=0)
    navg /= np.maximum(np.linalg.norm(navg, axis=1, keepdims=True), 1e-300)
    T = len(targets)
    u = np.zeros((T, 3))
    ok = np.zeros(T, bool)
    for attempt in range(40):
        todo = np.flatnonzero(~ok)
        if not len(todo):
            break
        spread = 0.0 if attempt == 0 else 0.6
        cand = navg[todo] + spread * rng.normal(size=(len(todo), 3))
        cand /= np.maximum(np.linalg.norm(cand, axis=1, keepdims=True), 1e-300)
        sub_len = lens[todo]
        sub_offs = np.concatenate([[0], np.cumsum(sub_len)])
        sub_fan = fan[_ranges(offs[todo], sub_len)]
        dots = np.einsum("kc,kc->k", np.repeat(cand, sub_len, axis=0), normals[sub_fan])
        good = np.minimum.reduceat(dots, sub_offs[:-1]) > min_cos
        u[todo[good]] = cand[good]
        ok[todo[good]] = True
    centre = 0.5 * (v.min(axis=0) + v.max(axis=0))
    radius = float(np.linalg.norm(v - centre, axis=1).max())
    L = radius * rng.uniform(1.5, 3.0, T) + np.linalg.norm(targets - centre, axis=1)
    o = targets + L[:, None] * u
    o, targets = o[ok], targets[ok]
    d = targets - o
    dist = np.linalg.norm(d, axis=1)
    return o, d / dist[:, None], dist


def count_holes(t, tri, dist):
    """Probe rays (unit directions) that miss, or hit farther than dist * (1 + HOLE_REL)."""
    t = np.asarray(t, np.float64)
    tri = np.asarray(tri)
    return int(((tri < 0) | (t > dist * (1.0 + HOLE_REL))).sum())
