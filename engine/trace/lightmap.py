"""Shadow rays the material pass need not cast: for a point light over triangles that stay the same
from frame to frame, a map of the directions around the light that tells, per direction, how near
the nearest triangles come.

The triangles are first put in clusters (:func:`plane_clusters`): triangles whose corners all lie
within CLUSTER_EPS of the scene's diagonal of one plane (a floor's tiles, a wall, a table top) share
one, with that plane and how far its corners lie from it at most; every other triangle is a cluster
of its own.

The map (:class:`LightMap`) covers the sphere of directions around the light with the six faces
of a cube, RES x RES cells a face.  Each cell keeps the K (3) least distances from the light of
the clusters whose triangles' directions (as seen from the light) come within one cell of it, and
those clusters' numbers: a cluster's distance is the least of its triangles'.  A triangle's
directions are its corners' after clipping it to the face's pyramid, projected onto the face: the
cells of each column its projection spans, with a column and a row to spare on each side.  Its
distance in a cell is a lower bound, the greater of two: the distance from the light to its
bounding box, and the least distance from the light to its plane along the cell's directions
(where all of them meet the plane in front of the light), both shrunk by DIST_SHRINK before they
are rounded to float32.

A shadow segment from the light to a lit hit p' = p + n_g off (the hit p on its triangle moved off
it towards the light by the shadow offset, :func:`gridrt.trace.material._put_segment`) at distance
d is clear, exactly, when each of the cell's clusters nearer than d (grown by DIST_GROW) is passed
over, and fewer than K of them are: no other triangle comes nearer than p' in its directions.  A
cluster is passed over when the segment's two ends lie on the same side of its plane, both farther
from it than its triangles' corners (with a margin for rounding): the segment then meets none of
them.  That passes over the cluster p lies on (p' lies off above it), and flat neighbours of the
hit facing the light.  A cluster of one triangle is passed over as well when that triangle lies
wholly at or below the plane through p along n_g, to within off / 4 (its corners' heights above
that plane) while the light lies at least off / 2 above it: the segment lies at least off / 2
above that plane (a convex neighbour's triangles, a curved surface's).  Such a segment is left out
of the grid's casts (its grid bit cleared), and the verdict is the one the casts would give:
nothing blocks it.

A map also keeps, per cell, the least over the triangles whose projection covers the cell (every
direction of the cell passes through the triangle, with COVER_MARGIN of a cell to spare) of the
greatest distance from the light to the triangle along the cell's directions (grown by COVER_GROW).
A segment whose hit end lies farther than that is blocked, exactly: it passes through that
triangle's inside before its end.  No grid casts it.  Such cells are those of a lamp's shade around
its light, or of a table seen from below; the cells a triangle's edge crosses are not covered.

A map is never made for a light with a triangle nearer than NEAR_FLOOR of the scene's diagonal
(segments that start there could leave the light's cell by rounding).

The maps are made for the first grid of a render (the static part of a split scene, or a scene's
only grid) when the same triangles (the same array, of the same contents: :func:`tri_digest`) and
the same light come back in a following frame (:class:`LightMaps`): a scene whose triangles move
every frame never makes one.  A frame makes at most one map (the lights' maps come one by one in
the frames that follow), and the clusters are found with the first.  On a cold compile cache,
build_light_map and clear_lit first compile on a background thread while the frames go on
without maps.  Each map takes 8 K + 4 bytes a cell (10.5 MiB at RES 256); the clusters at most 48
bytes a triangle."""

import hashlib

import numpy as np
from numba import njit, prange

from ..compiles import inner
from ..scene.surface import LIGHT_POINT
from .records import HitPoints, LightMapArrays
from .twin import TWINS, has_cache_entry

#: cells along each edge of a face of a light's direction cube (measured: BENCHMARKS.md section 15,
#: "Shadow segments left out by light maps")
RES = 256
#: the triangles a cell of a map keeps, nearest first
K = 3
#: the distances a map keeps are lower bounds shrunk by this fraction before their float32 rounding
DIST_SHRINK = 1e-6
#: a segment's length is grown by this fraction before it is compared with a map's distance
DIST_GROW = 1e-9
#: no map for a light nearer than this fraction of the scene's diagonal to a triangle
NEAR_FLOOR = 1e-9
#: lights whose maps a renderer keeps (the first ones of the scene's list)
MAX_MAPS = 16
#: triangles whose corners lie within this fraction of the scene's diagonal of one plane share a
#: cluster (a tenth of the shadow offset, gridrt.trace.render.SHADOW_OFFSET)
CLUSTER_EPS = 1e-7
#: a map's cell counts as covered by a triangle when its directions pass through the triangle with
#: this fraction of a cell to spare on every side
COVER_MARGIN = 0.01
#: the greatest distance of a covering triangle along a cell's directions is grown by this fraction
COVER_GROW = 1e-6
#: heights above a cluster's plane count only beyond this fraction of the coordinates' size (the
#: rounding of the casts and of the heights themselves, with room to spare)
PLANE_SLACK = 1e-9


class Clusters:
    """Triangles in clusters (:func:`plane_clusters`): of (F,) int32 each triangle's cluster,
    planes (C, 5) float64 each cluster's plane (nx, ny, nz, h: the points x with n . x = h, n a
    unit vector; 0, 0, 0, 0 for a triangle without area) and tol, the farthest its corners lie from
    it (inf without area), and lone (C,) int32 a cluster's triangle where it has one, else -1."""

    __slots__ = ("of", "planes", "lone")

    def __init__(self, of, planes, lone):
        self.of, self.planes, self.lone = of, planes, lone


def plane_clusters(tris, eps):
    """:class:`Clusters` of the triangles tris (F, 3, 3) float32: triangles whose corners all lie
    within eps of the plane of the first triangle of their class (their unit normals, turned so
    that their largest component is positive, rounded to 2^-13, and their planes' distances from
    the origin in steps of 4 eps) share a cluster, with that plane; every other triangle is one of
    its own.  tol: the corners' farthest distance from the cluster's plane (float64), plus 1e-12 of
    the largest coordinate for its rounding."""
    t = tris.astype(np.float64)
    F = len(t)
    n = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
    length = np.sqrt((n * n).sum(1))
    ok = np.isfinite(length) & (length > 0.0)
    n = np.where(ok[:, None], n / np.where(ok, length, 1.0)[:, None], 0.0)
    rows = np.arange(F)
    n[n[rows, np.abs(n).argmax(1)] < 0.0] *= -1.0
    h = (n * t[:, 0]).sum(1)
    q = np.round(n * 8192.0).astype(np.int64)
    qh = np.floor(h / (4.0 * eps)) if eps > 0.0 else np.zeros(F)
    qh = np.where(np.isfinite(qh), qh, 0.0).astype(np.int64)
    key = (q[:, 0] * np.int64(0x9E3779B97F4A7C15 - (1 << 64)) ^ q[:, 1] * np.int64(0x632BE59BD9B4E019)
           ^ q[:, 2] * np.int64(0x2545F4914F6CDD1D) ^ qh * np.int64(0x1B873593))
    key[~ok] = rows[~ok]   # (each on its own below)
    _, first, cls = np.unique(key, return_index=True, return_inverse=True)
    cls = cls.reshape(-1)
    rep = first[cls]
    dev = np.abs(np.einsum("fkc,fc->fk", t, n[rep]) - h[rep][:, None]).max(1)
    alone = ~ok | ~(dev <= eps) | ~ok[rep]
    C0 = len(first)
    of = np.where(alone, C0 + np.cumsum(alone) - 1, cls).astype(np.int32)
    C = C0 + int(alone.sum())
    planes = np.zeros((C, 5))
    planes[:C0, :3], planes[:C0, 3] = n[first], h[first]
    planes[C0:, :3], planes[C0:, 3] = n[alone], h[alone]
    dev[alone] = np.abs(np.einsum("fkc,fc->fk", t[alone], n[alone]) - h[alone][:, None]).max(1)
    np.maximum.at(planes[:, 4], of, dev)
    planes[:, 4] += 1e-12 * float(np.abs(t).max(initial=0.0))
    planes[of[~ok], 4] = np.inf
    count = np.bincount(of, minlength=C)
    lone = np.full(C, -1, np.int32)
    single = count[of] == 1
    lone[of[single]] = rows[single]
    return Clusters(of, planes, lone)


class LightMap:
    """One point light's map: light (3,) float64 (in the grid's frame), dist (6, RES, RES, K)
    float32 and key (6, RES, RES, K) int32, clusters of the :class:`Clusters` cl (-1 and inf where
    a cell keeps fewer), and cover (6, RES, RES) float32 (inf where no triangle covers the cell; see
    the module docstring)."""

    __slots__ = ("light", "dist", "key", "cover", "cl")

    def __init__(self, light, cl):
        self.light = np.array(light, np.float64)
        self.dist = np.empty((6, RES, RES, K), np.float32)
        self.key = np.empty((6, RES, RES, K), np.int32)
        self.cover = np.empty((6, RES, RES), np.float32)
        self.cl = cl

    def build(self, tris):
        """Fill the map over tris (the clusters' triangles); returns build_light_map's least
        distance."""
        return build_light_map(tris, self.cl.of, self.light, self.dist, self.key, self.cover)

    def arrays(self, tris):
        """Its :class:`gridrt.trace.records.LightMapArrays` over the mapped triangles tris."""
        return LightMapArrays(self.light, self.dist, self.key, self.cover, self.cl.planes, self.cl.lone, tris)


@njit(cache=True, parallel=True, error_model="numpy")
def build_light_map(tris, of, light, dist, key, cover):
    """Fill a map's dist, key and cover (see the module docstring) from the triangles tris (F, 3,
    3) float32 in the clusters of[f] (int32) for a point light at light (3,) float64, the six faces
    in parallel.  Returns the least distance of a triangle (its bounding box) from the light."""
    F = tris.shape[0]
    R = dist.shape[1]
    near = np.full(6, np.inf)
    for face in prange(6):
        a = face >> 1
        s = 1.0 if (face & 1) == 0 else -1.0
        b = (a + 1) % 3
        c = (a + 2) % 3
        P = np.empty((3, 8))
        Q = np.empty((3, 8))
        dist[face] = np.inf
        key[face] = -1
        cover[face] = np.inf
        for f in range(F):
            cf = of[f]
            mind = _box_distance(tris, f, light)
            near[face] = min(near[face], mind)
            for k in range(3):
                P[0, k] = s * (np.float64(tris[f, k, a]) - light[a])
                P[1, k] = np.float64(tris[f, k, b]) - light[b]
                P[2, k] = np.float64(tris[f, k, c]) - light[c]
            plane = _plane(P)
            n = _clip_to_pyramid(P, Q)
            if n == 0:
                continue
            umin = np.inf
            umax = -np.inf
            for k in range(n):
                u = P[1, k] / max(P[0, k], 1e-300)
                umin = min(umin, u)
                umax = max(umax, u)
            i0 = max(0, int(np.floor((max(umin, -1.0) + 1.0) * 0.5 * R)) - 1)
            i1 = min(R - 1, int(np.floor((min(umax, 1.0) + 1.0) * 0.5 * R)) + 1)
            for i in range(i0, i1 + 1):
                wl, wh = _column_span(P, n, (i - 1) * 2.0 / R - 1.0, (i + 2) * 2.0 / R - 1.0)
                if not wl <= wh:
                    continue
                j0 = max(0, int(np.floor((max(wl, -1.0) + 1.0) * 0.5 * R)) - 1)
                j1 = min(R - 1, int(np.floor((min(wh, 1.0) + 1.0) * 0.5 * R)) + 1)
                for j in range(j0, j1 + 1):
                    d = np.float32(max(mind, _plane_distance(plane, i, j, R)) * (1.0 - DIST_SHRINK))
                    _keep(dist, key, face, i, j, d, cf)
                _cover(P, n, plane, i, R, cover[face])
    return near.min()


@inner(cache=True, _nrt=False, error_model="numpy")
def _cover(P, n, plane, i, R, cover):
    """The cells of column i of a face (cover (R, R) float32) whose directions all pass through
    the projected polygon P[:, :n] (:func:`_clip_to_pyramid`: a triangle seen from the light, convex)
    with COVER_MARGIN of a cell to spare: cover keeps the least, over the triangles, of the greatest
    distance from the light to the triangle's plane along a cell's directions (its corners', grown
    by COVER_GROW; the plane in front at each).  A cell's corners lie in a convex polygon when both
    ends of each of its rows do: its rows w lie in the spans of w at the column's two sides."""
    nz, nu, nw, h = plane
    if not h > 0.0:   # (a triangle without area, or edge-on to the light)
        return
    m = COVER_MARGIN * 2.0 / R
    ua, ub = i * 2.0 / R - 1.0 - m, (i + 1) * 2.0 / R - 1.0 + m
    la, ha = _column_span(P, n, ua, ua)
    lb, hb = _column_span(P, n, ub, ub)
    lo, hi = max(la, lb) + m, min(ha, hb) - m
    if not lo < hi:
        return
    j0 = max(0, int(np.ceil((lo + 1.0) * 0.5 * R)))
    j1 = min(R, int(np.floor((hi + 1.0) * 0.5 * R)))   # (cells j0 .. j1 - 1: [w_j, w_j+1] in [lo, hi])
    for j in range(j0, j1):
        w0, w1 = j * 2.0 / R - 1.0 - m, (j + 1) * 2.0 / R - 1.0 + m
        far = 0.0
        for u in (ua, ub):
            for w in (w0, w1):
                dot = nz + nu * u + nw * w
                far = max(far, h * np.sqrt(1.0 + u * u + w * w) / dot) if dot > 0.0 else np.inf
        c = np.float32(far * (1.0 + COVER_GROW))
        if c < cover[i, j]:
            cover[i, j] = c


@inner(cache=True, _nrt=False, error_model="numpy")
def _keep(dist, key, face, i, j, d, cf):
    """Cell (i, j) of a face keeps cluster cf at distance d among its K nearest clusters (nearest
    first; a cluster once, at the least distance of its triangles)."""
    k = K - 1
    for q in range(K):
        if key[face, i, j, q] == cf:
            if not d < dist[face, i, j, q]:
                return
            k = q
            break
    if not d < dist[face, i, j, k]:
        return
    while k > 0 and d < dist[face, i, j, k - 1]:
        dist[face, i, j, k] = dist[face, i, j, k - 1]
        key[face, i, j, k] = key[face, i, j, k - 1]
        k -= 1
    dist[face, i, j, k] = d
    key[face, i, j, k] = cf


@inner(cache=True, _nrt=False, error_model="numpy")
def _plane(P):
    """(n_z, n_u, n_w, h): the unit normal of the triangle P[:, :3] (rows z, u, w: its corners in a
    face's frame, relative to the light) turned away from the light, and the light's distance h
    from its plane (0 for a triangle without area)."""
    e1z, e1u, e1w = P[0, 1] - P[0, 0], P[1, 1] - P[1, 0], P[2, 1] - P[2, 0]
    e2z, e2u, e2w = P[0, 2] - P[0, 0], P[1, 2] - P[1, 0], P[2, 2] - P[2, 0]
    nz, nu, nw = e1u * e2w - e1w * e2u, e1w * e2z - e1z * e2w, e1z * e2u - e1u * e2z
    length = np.sqrt(nz * nz + nu * nu + nw * nw)
    if not length > 0.0:
        return 0.0, 0.0, 0.0, 0.0
    nz, nu, nw = nz / length, nu / length, nw / length
    h = nz * P[0, 0] + nu * P[1, 0] + nw * P[2, 0]
    if h < 0.0:
        return -nz, -nu, -nw, -h
    return nz, nu, nw, h


@inner(cache=True, _nrt=False, error_model="numpy")
def _plane_distance(plane, i, j, R):
    """A lower bound of the distance from the light to the plane (:func:`_plane`) along the
    directions of cell (i, j) of a face (grown by a hundredth of a cell): h |c| / (n . c) over
    the cell's directions c = (1, u, w), at least h |c|min / max(n . c) over its corners, where
    every corner meets the plane in front of the light (n . c > 0); 0 otherwise."""
    nz, nu, nw, h = plane
    u0, u1 = (i - 0.01) * 2.0 / R - 1.0, (i + 1.01) * 2.0 / R - 1.0
    w0, w1 = (j - 0.01) * 2.0 / R - 1.0, (j + 1.01) * 2.0 / R - 1.0
    lo = min(min(nz + nu * u0 + nw * w0, nz + nu * u1 + nw * w0), min(nz + nu * u0 + nw * w1, nz + nu * u1 + nw * w1))
    hi = max(max(nz + nu * u0 + nw * w0, nz + nu * u1 + nw * w0), max(nz + nu * u0 + nw * w1, nz + nu * u1 + nw * w1))
    if not (h > 0.0 and lo > 0.0):
        return 0.0
    um = 0.0 if u0 <= 0.0 <= u1 else min(abs(u0), abs(u1))
    wm = 0.0 if w0 <= 0.0 <= w1 else min(abs(w0), abs(w1))
    return h * np.sqrt(1.0 + um * um + wm * wm) / hi


@inner(cache=True, _nrt=False, error_model="numpy")
def _box_distance(tris, f, light):
    """The distance from light (3,) to the bounding box of triangle f of tris (0 inside it)."""
    d2 = 0.0
    for a in range(3):
        lo = min(np.float64(tris[f, 0, a]), min(np.float64(tris[f, 1, a]), np.float64(tris[f, 2, a]))) - light[a]
        hi = max(np.float64(tris[f, 0, a]), max(np.float64(tris[f, 1, a]), np.float64(tris[f, 2, a]))) - light[a]
        e = max(0.0, max(lo, -hi))
        d2 += e * e
    return np.sqrt(d2)


@inner(cache=True, _nrt=False, error_model="numpy")
def _clip_to_pyramid(P, Q):
    """Clip the triangle P[:, :3] (rows z, u, w: its corners in a face's frame, z along the face's
    axis) to the face's pyramid z >= |u|, z >= |w| (Sutherland-Hodgman, the polygon left in P,
    Q scratch).  Returns its corners (0 when nothing is left)."""
    n = 3
    for pl in range(4):
        row = 1 if pl < 2 else 2
        sg = 1.0 if (pl & 1) == 0 else -1.0
        m = 0
        for k in range(n):
            k2 = k + 1 if k + 1 < n else 0
            e1 = P[0, k] - sg * P[row, k]
            e2 = P[0, k2] - sg * P[row, k2]
            if e1 >= 0.0:
                Q[0, m] = P[0, k]
                Q[1, m] = P[1, k]
                Q[2, m] = P[2, k]
                m += 1
            if (e1 >= 0.0) != (e2 >= 0.0):
                t = e1 / (e1 - e2)
                Q[0, m] = P[0, k] + t * (P[0, k2] - P[0, k])
                Q[1, m] = P[1, k] + t * (P[1, k2] - P[1, k])
                Q[2, m] = P[2, k] + t * (P[2, k2] - P[2, k])
                m += 1
        n = m
        for k in range(n):
            P[0, k] = Q[0, k]
            P[1, k] = Q[1, k]
            P[2, k] = Q[2, k]
        if n == 0:
            break
    return n


@inner(cache=True, _nrt=False, error_model="numpy")
def _column_span(P, n, ua, ub):
    """(wl, wh): the range of w / z over the part of the projected polygon P[:, :n] (see
    _clip_to_pyramid) whose u / z lies in [ua, ub] (wl > wh where it has none): its corners in
    the band and its edges' crossings of the band's sides."""
    wl = np.inf
    wh = -np.inf
    for k in range(n):
        k2 = k + 1 if k + 1 < n else 0
        z1 = max(P[0, k], 1e-300)
        z2 = max(P[0, k2], 1e-300)
        u1 = P[1, k] / z1
        w1 = P[2, k] / z1
        u2 = P[1, k2] / z2
        w2 = P[2, k2] / z2
        if ua <= u1 <= ub:
            wl = min(wl, w1)
            wh = max(wh, w1)
        for ue in (ua, ub):
            if (u1 - ue) * (u2 - ue) < 0.0:
                we = w1 + (ue - u1) / (u2 - u1) * (w2 - w1)
                wl = min(wl, we)
                wh = max(wh, we)
    return wl, wh


@njit(cache=True, parallel=True, error_model="numpy")
def clear_lit(lmap, hp, rows, off, o, d, bit, marks, blocked):
    """Clear ``bit`` in marks[m] (uint8) of each shadow segment m (o + t d, 0 < t < 1, from the
    light's end o to its hit end o + d, by the hit of pixel rows[m] of hp,
    :class:`gridrt.trace.records.HitPoints`, moved off by off along its normal n_g) that the map
    lmap (:class:`gridrt.trace.records.LightMapArrays`) shows clear, and set blocked[m] (bool)
    where it shows the segment blocked (False elsewhere; see the module docstring).  Returns (how
    many it showed clear, how many blocked).  (The test is written out in the loop: as a function
    of its own, called per segment with the map's arrays, it took twice as long.)"""
    light, dist, key, planes, lone, tris = lmap.light, lmap.dist, lmap.key, lmap.planes, lmap.lone, lmap.tris
    cover = lmap.cover
    pos, ng = hp.pos, hp.ng
    R = dist.shape[1]
    lx, ly, lz = light[0], light[1], light[2]
    cleared = 0
    shown = 0
    for m in prange(o.shape[0]):
        blocked[m] = False
        ex, ey, ez = o[m, 0] + d[m, 0], o[m, 1] + d[m, 1], o[m, 2] + d[m, 2]
        vx, vy, vz = ex - lx, ey - ly, ez - lz
        ax, ay, az = abs(vx), abs(vy), abs(vz)
        if ax >= ay and ax >= az:
            face, z, u, w = (0 if vx > 0.0 else 1), ax, vy, vz
        elif ay >= az:
            face, z, u, w = (2 if vy > 0.0 else 3), ay, vz, vx
        else:
            face, z, u, w = (4 if vz > 0.0 else 5), az, vx, vy
        if not z > 0.0:
            continue
        i = min(R - 1, max(0, int(np.floor((u / z + 1.0) * 0.5 * R))))
        j = min(R - 1, max(0, int(np.floor((w / z + 1.0) * 0.5 * R))))
        dd = np.sqrt(vx * vx + vy * vy + vz * vz)
        if dd * (1.0 - DIST_GROW) > cover[face, i, j]:   # a triangle covers the cell before the end
            blocked[m] = True
            shown += 1
            continue
        dd *= 1.0 + DIST_GROW
        r = rows[m]
        px, py, pz = pos[r, 0], pos[r, 1], pos[r, 2]
        nx, ny, nz = ng[r, 0], ng[r, 1], ng[r, 2]
        size = max(max(max(abs(lx), abs(ly)), max(abs(lz), abs(ex))), max(abs(ey), abs(ez)))
        above = nx * (lx - px) + ny * (ly - py) + nz * (lz - pz) > 0.5 * off
        clear = False
        for k in range(K):
            if not dd > dist[face, i, j, k]:   # nothing else comes nearer
                clear = True
                break
            c = key[face, i, j, k]
            cx, cy, cz, h = planes[c, 0], planes[c, 1], planes[c, 2], planes[c, 3]
            tol = planes[c, 4] + PLANE_SLACK * (size + abs(h))
            hl = cx * lx + cy * ly + cz * lz - h
            he = cx * ex + cy * ey + cz * ez - h
            if (hl > tol and he > tol) or (hl < -tol and he < -tol):   # both ends off its slab, one side
                continue
            f = lone[c]
            if f < 0 or not above:
                break
            below = True   # its one triangle under the hit's tangent plane
            for q in range(3):
                hc = (nx * (np.float64(tris[f, q, 0]) - px) + ny * (np.float64(tris[f, q, 1]) - py)
                      + nz * (np.float64(tris[f, q, 2]) - pz))
                if not hc <= 0.25 * off:
                    below = False
                    break
            if not below:
                break
        if clear:
            marks[m] &= ~np.uint8(bit)
            cleared += 1
    return cleared, shown


def tri_digest(tris):
    """A digest of the bits of a triangle array (hashlib's SHA-1: no kernel to compile, about the
    time of one pass over the array): whether its contents changed in place between two frames."""
    return hashlib.sha1(np.ascontiguousarray(tris)).digest()


_UNSEEN = object()
#: set once the maps' kernels are known to run without compiling in the render's thread
_READY = []


def _compiled():
    """Whether the maps' kernels (build_light_map and clear_lit) can run without compiling in the
    render's thread: they are in the on-disk cache, or compiled in this process.  On a cold cache
    the first call (a frame that would make a map: not the first frame, whose kernels load from
    the cache through numba's compiler lock, which a compile holds) starts their compile on a
    background thread (gridrt.trace.twin.Twins.warm: a map over one triangle and its test of no
    segment, with the types the renders pass) and the frames go on without maps (the same images)
    until it is done."""
    if not _READY and (all(has_cache_entry(k) for k in (build_light_map, clear_lit))
                       or TWINS.warm("light-map", "build_light_map", _warm_build, True)):
        _READY.append(True)
    return bool(_READY)


def _warm_build():
    """A map over one triangle and its test of an empty batch: build_light_map and clear_lit
    compiled for the types the renders pass (the material pass's shadow buffers: hit points in
    float64 and float32 rows, segments' rows int64, ends float64, grid marks uint8, blocked flags
    bool; tests/test_lightmap.py sets these against a render's)."""
    tris = np.ones((1, 3, 3), np.float32)
    lm = LightMap(np.zeros(3), plane_clusters(tris, 1.0))
    lm.build(tris)
    f64, f32 = np.empty((0, 3)), np.empty((0, 3), np.float32)
    clear_lit(lm.arrays(tris), HitPoints(f64, f64, f32, f32, f32), np.empty(0, np.int64), 0.0, f64, f64, 1,
              np.empty(0, np.uint8), np.empty(0, bool))


class LightMaps:
    """A renderer's light maps for the first grid of its renders (see the module docstring): made
    for a point light when the same triangles and light were seen in an earlier frame, one map a
    frame (a map of the kitchen's 110k triangles takes about 0.1-0.15 s), kept while they stay the
    same, at most MAX_MAPS lights."""

    def __init__(self):
        self._tris = None    # the triangle array the maps are for (held: its id stays its own)
        self._hash = None
        self._maps = {}      # light position bytes -> LightMap, or None once seen (made when seen again)
        self._clusters = None   # the triangles' Clusters, found with the first map

    def for_lights(self, g, lights, diag):
        """The maps (LightMap or None per light) of the grid g (GridArrays) for lights (L, 8) in
        its frame, this frame; diag: the scene's diagonal."""
        tris = g.tris
        h = tri_digest(tris)
        if self._tris is not tris or self._hash != h:
            self._tris, self._hash, self._maps, self._clusters = tris, h, {}, None
        out, maps, made = [], {}, False
        for li in range(len(lights)):
            if lights[li, 0] != LIGHT_POINT or li >= MAX_MAPS:
                out.append(None)
                continue
            key = np.ascontiguousarray(lights[li, 1:4], np.float64).tobytes()
            lm = self._maps.get(key, _UNSEEN)
            if lm is None and not made and _compiled():   # seen in an earlier frame: made now (one a frame)
                made = True
                try:
                    if self._clusters is None:
                        self._clusters = plane_clusters(tris, CLUSTER_EPS * diag)
                    lm = LightMap(lights[li, 1:4], self._clusters)
                except MemoryError:   # (a map only saves time: the frames go on without)
                    lm = False
                else:
                    near = lm.build(tris)
                    lm = lm if near > NEAR_FLOOR * diag else False   # (False: never for this light)
            maps[key] = None if lm is _UNSEEN else lm
            out.append(lm if isinstance(lm, LightMap) else None)
        self._maps = maps   # (the lights of this frame only)
        return out


class NoLightMaps(LightMaps):
    """Light maps never made: a renderer given these casts every shadow segment (benchmarks that
    time the casts of all of them)."""

    def for_lights(self, g, lights, diag):
        return [None] * len(lights)
