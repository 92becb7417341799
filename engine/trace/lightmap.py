"""Shadow rays the material pass need not cast: for a point light over triangles that stay the same
from frame to frame, a map of the directions around the light that tells, per direction, how near
the nearest triangles come.

The map (:class:`LightMap`) covers the sphere of directions around the light with the six faces
of a cube, RES x RES cells a face.  Each cell keeps the least distance from the light of any
triangle whose directions (as seen from the light) come within one cell of it (d1, and that
triangle's index id1) and the least distance of any other such triangle (d2).  Distances are
lower bounds: the distance from the light to the triangle's bounding box, shrunk by DIST_SHRINK
before they are rounded to float32.  A triangle's directions are its corners' after clipping it
to the face's pyramid, projected onto the face: the cells of each column its projection spans,
with a column and a row to spare on each side.

A shadow segment from the light to a lit hit p' (the hit moved off its triangle T towards the
light, :func:`gridrt.trace.material._put_segment`) at distance d is clear, exactly, when d (grown
by DIST_GROW) lies below the cell's d1, or below d2 where T itself is the cell's nearest: no
triangle but T reaches nearer than p' in those directions, and T cannot block the segment (both
its ends lie on the light's side of T's plane, the hit end by the offset, far beyond rounding).
Such a segment is left out of the grid's casts (:func:`clear_lit` clears its grid bit), and
the verdict is the one the casts would give: nothing blocks it.  A map is never made for a light
with a triangle nearer than NEAR_FLOOR of the scene's diagonal (segments that start there could
leave the light's cell by rounding).

The maps are made for the first grid of a render (the static part of a split scene, or a scene's
only grid) when the same triangles (the same array, of the same contents: :func:`tri_hash`) and
the same light come back in a following frame (:class:`LightMaps`): a scene whose triangles move
every frame never makes one.  On a cold compile cache, build_light_map first compiles on a
background thread while the frames go on without maps.  Each map takes 12 bytes a cell (4.7 MiB
at RES 256)."""

import numpy as np
from numba import njit, prange

from ..compiles import inner
from ..scene.surface import LIGHT_POINT
from .records import LightMapArrays
from .twin import TWINS, has_cache_entry

#: cells along each edge of a face of a light's direction cube (measured: BENCHMARKS.md section 15,
#: "Shadow segments left out by light maps")
RES = 256
#: the distances a map keeps are lower bounds shrunk by this fraction before their float32 rounding
DIST_SHRINK = 1e-6
#: a segment's length is grown by this fraction before it is compared with a map's distance
DIST_GROW = 1e-9
#: no map for a light nearer than this fraction of the scene's diagonal to a triangle
NEAR_FLOOR = 1e-9
#: lights whose maps a renderer keeps (the first ones of the scene's list)
MAX_MAPS = 16


def no_map(tri):
    """The :class:`gridrt.trace.records.LightMapArrays` of a light without a map (R = 0), with
    the types of a map's (one compiled kernel for both)."""
    return LightMapArrays(np.zeros(3), _NO_D, _NO_ID, _NO_D, tri, np.empty(0, np.int32))


_NO_D = np.empty((0, 0, 0), np.float32)
_NO_ID = np.empty((0, 0, 0), np.int32)


class LightMap:
    """One point light's map: light (3,) float64 (in the grid's frame), d1, d2 (6, RES, RES)
    float32 and id1 (6, RES, RES) int32 (see the module docstring)."""

    __slots__ = ("light", "d1", "id1", "d2")

    def arrays(self, tri, local):
        """Its :class:`gridrt.trace.records.LightMapArrays` with the image's flat tri buffer and
        the scene id -> grid index map (:attr:`LightMaps.local`)."""
        return LightMapArrays(self.light, self.d1, self.id1, self.d2, tri, local)

    def __init__(self, light):
        self.light = np.array(light, np.float64)
        self.d1 = np.empty((6, RES, RES), np.float32)
        self.id1 = np.empty((6, RES, RES), np.int32)
        self.d2 = np.empty((6, RES, RES), np.float32)


@njit(cache=True, parallel=True, error_model="numpy")
def build_light_map(tris, light, d1, id1, d2):
    """Fill a map's d1, id1, d2 (see the module docstring) from the triangles tris (F, 3, 3)
    float32 for a point light at light (3,) float64, the six faces in parallel.  Returns the
    least distance of a triangle (its bounding box) from the light."""
    F = tris.shape[0]
    R = d1.shape[1]
    near = np.full(6, np.inf)
    for face in prange(6):
        a = face >> 1
        s = 1.0 if (face & 1) == 0 else -1.0
        b = (a + 1) % 3
        c = (a + 2) % 3
        P = np.empty((3, 8))
        Q = np.empty((3, 8))
        for i in range(R):
            for j in range(R):
                d1[face, i, j] = np.inf
                d2[face, i, j] = np.inf
                id1[face, i, j] = -1
        for f in range(F):
            mind = _box_distance(tris, f, light)
            near[face] = min(near[face], mind)
            dist = np.float32(mind * (1.0 - DIST_SHRINK))
            for k in range(3):
                P[0, k] = s * (np.float64(tris[f, k, a]) - light[a])
                P[1, k] = np.float64(tris[f, k, b]) - light[b]
                P[2, k] = np.float64(tris[f, k, c]) - light[c]
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
                    if dist < d1[face, i, j]:
                        d2[face, i, j] = d1[face, i, j]
                        d1[face, i, j] = dist
                        id1[face, i, j] = f
                    elif dist < d2[face, i, j]:
                        d2[face, i, j] = dist
    return near.min()


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


@inner(cache=True, _nrt=False, error_model="numpy")
def shows_clear(light, d1, id1, d2, end, f):
    """Whether the map (light, d1, id1, d2) shows the shadow segment from the light to its hit
    end ``end`` (a 3-tuple: the hit moved off its triangle towards the light) clear, where f is
    the index of the triangle the hit lies on among the map's triangles (-1 for another grid's);
    see the module docstring."""
    R = d1.shape[1]
    vx = end[0] - light[0]
    vy = end[1] - light[1]
    vz = end[2] - light[2]
    ax, ay, az = abs(vx), abs(vy), abs(vz)
    if ax >= ay and ax >= az:
        face, z, u, w = (0 if vx > 0.0 else 1), ax, vy, vz
    elif ay >= az:
        face, z, u, w = (2 if vy > 0.0 else 3), ay, vz, vx
    else:
        face, z, u, w = (4 if vz > 0.0 else 5), az, vx, vy
    if not z > 0.0:
        return False
    i = min(R - 1, max(0, int(np.floor((u / z + 1.0) * 0.5 * R))))
    j = min(R - 1, max(0, int(np.floor((w / z + 1.0) * 0.5 * R))))
    dist = np.sqrt(vx * vx + vy * vy + vz * vz) * (1.0 + DIST_GROW)
    return dist < (d2[face, i, j] if id1[face, i, j] == f else d1[face, i, j])


@njit(cache=True, parallel=True, error_model="numpy")
def clear_lit(light, d1, id1, d2, o, d, hit_tri, bit, marks):
    """Clear ``bit`` in marks[m] (uint8) of each shadow segment m (o + t d, 0 < t < 1, its hit end
    o + d; hit_tri[m] the index of the triangle the hit lies on among the map's triangles, -1
    for another grid's) that the map (light, d1, id1, d2) shows clear (:func:`shows_clear`).
    Returns how many were cleared."""
    cleared = 0
    for m in prange(o.shape[0]):
        end = (o[m, 0] + d[m, 0], o[m, 1] + d[m, 1], o[m, 2] + d[m, 2])
        if shows_clear(light, d1, id1, d2, end, hit_tri[m]):
            marks[m] &= ~np.uint8(bit)
            cleared += 1
    return cleared


@njit(cache=True, parallel=True, error_model="numpy")
def segment_triangles(rows, tri_buf, local, out):
    """out[m] = local[tri_buf[rows[m]]] (the hit triangle of segment m's pixel, a scene id in
    tri_buf, as an index among a grid's triangles: -1 where it is not one of them), or
    tri_buf[rows[m]] itself where local is empty (scene ids are the grid's)."""
    for m in prange(rows.shape[0]):
        f = tri_buf[rows[m]]
        if local.shape[0] > 0:
            f = local[f] if 0 <= f < local.shape[0] else -1
        out[m] = f


@njit(cache=True, error_model="numpy")
def tri_hash(words):
    """A 64-bit hash of the uint32 words (the bits of a triangle array): whether its contents
    changed in place between two frames."""
    h = np.uint64(0xCBF29CE484222325)
    for k in range(words.shape[0]):
        h = (h ^ np.uint64(words[k])) * np.uint64(0x100000001B3)
        h ^= h >> np.uint64(29)
    return h


_UNSEEN = object()


def _compiled():
    """Whether build_light_map can run without compiling in the render's thread: it is in the
    on-disk cache, or compiled in this process.  On a cold cache the first call starts its compile
    on a background thread (gridrt.trace.twin.Twins.warm: a build over one triangle) and the
    frames go on without maps (the same images) until it is done."""
    return has_cache_entry(build_light_map) or TWINS.warm("light-map", "build_light_map", _warm_build, True)


def _warm_build():
    """A map over one triangle: build_light_map compiled for the types of the renders' maps."""
    lm = LightMap(np.zeros(3))
    build_light_map(np.ones((1, 3, 3), np.float32), lm.light, lm.d1, lm.id1, lm.d2)


class LightMaps:
    """A renderer's light maps for the first grid of its renders (see the module docstring): made
    for a point light when the same triangles and light were seen in an earlier frame, kept while
    they stay the same, at most MAX_MAPS lights."""

    def __init__(self):
        self._tris = None    # the triangle array the maps are for (held: its id stays its own)
        self._hash = None
        self._local = None   # scene id -> the grid's index (-1 elsewhere), or empty
        self._maps = {}      # light position bytes -> LightMap, or None once seen (made when seen again)

    def for_lights(self, g, lights, diag):
        """The maps (LightMap or None per light) of the grid g (GridArrays) for lights (L, 8) in
        its frame, this frame; diag: the scene's diagonal."""
        tris = g.tris
        if self._tris is not tris or self._hash != tri_hash(tris.reshape(-1).view(np.uint32)):
            self._tris, self._maps = tris, {}
            self._hash = tri_hash(tris.reshape(-1).view(np.uint32))
            ids = np.asarray(g.ids)
            if ids.shape[0]:
                local = np.full(int(ids.max()) + 1, -1, np.int32)
                local[ids] = np.arange(len(ids), dtype=np.int32)
            else:
                local = np.empty(0, np.int32)
            self._local = local
        out, maps = [], {}
        for li in range(len(lights)):
            if lights[li, 0] != LIGHT_POINT or li >= MAX_MAPS:
                out.append(None)
                continue
            key = np.ascontiguousarray(lights[li, 1:4], np.float64).tobytes()
            lm = self._maps.get(key, _UNSEEN)
            if lm is None and _compiled():   # seen in an earlier frame: made now
                try:
                    lm = LightMap(lights[li, 1:4])
                except MemoryError:   # (a map only saves time: the frames go on without)
                    lm = False
                else:
                    near = build_light_map(tris, lm.light, lm.d1, lm.id1, lm.d2)
                    lm = lm if near > NEAR_FLOOR * diag else False   # (False: never for this light)
            maps[key] = None if lm is _UNSEEN else lm
            out.append(lm if isinstance(lm, LightMap) else None)
        self._maps = maps   # (the lights of this frame only)
        return out

    @property
    def local(self):
        """scene id -> index among the mapped grid's triangles (-1 elsewhere), or empty."""
        return self._local
