"""Batch ray casting for users who only want hits: vertices + faces in, per-ray t, triangle id
and barycentrics out, with cheap per-frame vertex updates.

    caster = RayCaster(vertices, faces)             # builds the grid
    hits = caster.cast(origins, directions)         # Hits(t, tri, u, v); miss: inf, -1
    caster.update(new_vertices)                     # same topology, next frame: rebuilds

The caster works in a frame centred on the mesh: it subtracts the float64 centre of the
vertices' bounds before storing them as float32 (and from every ray origin), so a mesh far from
the world origin keeps its precision; t, triangle ids and barycentrics are unchanged by that.

Threads: ``cast`` and ``update`` may be called from any number of Python threads on one caster.
The mesh is held in an immutable snapshot (frame origin, vertices, triangles, grid and the
builder that owns the grid's buffers).  A cast reads the snapshot once, at its start, and casts
against that mesh to the end, whatever updates happen meanwhile: every cast sees one whole mesh,
the one before or the one after a concurrent update.  Updates are serialised by a lock; each
builds into a builder that no snapshot in use holds (the spare one, or a new one when a cast
still holds it), then swaps the snapshot reference.  A builder returns to spare only once no
cast holds its snapshot, so a grid is never rebuilt under a cast.  An update writes the new
vertices and triangles into the arrays of the mesh before the last one when nothing holds them
any more (no cast, no user's reference or view), so a step faults in no new memory.  The cost is
a second builder's buffers (about the grid's memory), a second copy of the mesh's arrays (12
bytes a vertex, 36 a triangle) and two short lock acquisitions per cast.
"""

import sys
import threading
import warnings

import numpy as np

from .arrays import as_mesh, as_triangles, float_contiguous
from .config import GridParams
from .errors import InputError
from .grid import common
from .grid.build import GridBuilder
from .memory import allocating, check_fits
from .precision import ONE_SHOT_SAMPLE, PrecisionWarning, detail_warning, warn_detail
from .scene.animation import gather_unchecked
from .threads import launch_guard
from .trace.all_hits import AllHits, query_hits
from .trace.render import Hits, cast_batch


def _vertices64(vertices, what):
    v = np.asarray(vertices)
    if v.dtype == object or not (np.issubdtype(v.dtype, np.floating) or np.issubdtype(v.dtype, np.integer)):
        raise InputError(f"{what} must be a real numeric array, got dtype {v.dtype}")
    if v.ndim != 2 or v.shape[1] != 3:
        raise InputError(f"{what} must have shape (V, 3), got {v.shape}")
    v = v.astype(np.float64)
    if len(v) and not np.isfinite(v).all():
        raise InputError(f"{what} contain NaN or infinity")
    if len(v) and np.abs(v).max() > 1e30:
        raise InputError(f"{what} have coordinates beyond 1e30")
    return v


def _vertex_array(vertices, what):
    """``vertices`` as a C-contiguous float32 or float64 (V, 3) array, reading no values; InputError
    for a wrong dtype or shape."""
    v = np.asarray(vertices)
    if v.dtype == object or not (np.issubdtype(v.dtype, np.floating) or np.issubdtype(v.dtype, np.integer)) \
            or v.ndim != 2 or v.shape[1] != 3:
        v = _vertices64(vertices, what)  # raises naming the dtype or shape
    return float_contiguous(v)


def _in_centred_frame(v, lo, hi, faces, what, spare=None):
    """(origin, vertices (V,3) float32 and triangles (F,3,3) float32 in the frame centred on the
    bounds lo, hi of the checked vertices ``v``, the largest |coordinate| there) over checked
    ``faces`` (F,3) int32: one conversion and one gather, into the arrays ``spare`` (vertices,
    triangles) where given; InputError when every triangle has zero area."""
    origin = 0.5 * (lo + hi)
    verts = np.empty(v.shape, np.float32) if spare is None else spare[0]
    common.to_frame(v, float(origin[0]), float(origin[1]), float(origin[2]), verts)
    tris = gather_unchecked(verts, faces, np.empty((len(faces), 3, 3), np.float32) if spare is None else spare[1])
    if common.first_nondegenerate(tris) < 0:
        raise InputError(f"{what}: all {len(faces)} triangles are degenerate (zero area)")
    return origin, verts, tris, float(max(np.abs(lo - origin).max(), np.abs(hi - origin).max()))


def _centred_mesh(vertices, faces):
    """(origin, vertices, faces (F,3) int32, triangles, largest |coordinate|) of a mesh in the
    frame centred on its vertices' bounds (see _in_centred_frame), or InputError naming its
    problem.  One pass over the vertex values (bounds, NaN/inf/1e30), one over the faces (index
    range), then the conversion and the gather: about the cost of the grid build it comes with.
    Anything unusual (no vertices, bad values, float faces, indices out of range) goes through the
    slow checks, which say what is wrong (or accept integral float faces)."""
    v = _vertex_array(vertices, "vertices")
    f = np.asarray(faces)
    lo, hi, bad = common.point_bounds(v) if len(v) else (None, None, True)
    slow = bad or f.ndim != 2 or f.shape[1:] != (3,) or len(f) == 0 \
        or not np.issubdtype(f.dtype, np.integer) or len(v) > np.iinfo(np.int32).max
    if not slow:
        fmin, fmax = int(f.min()), int(f.max())
        slow = fmin < 0 or fmax >= len(v)
    if slow:  # the checks that name the problem (or accept what is only unusual)
        v64 = _vertices64(vertices, "vertices")
        origin = RayCaster._centre(v64)
        verts, f32 = as_mesh(v64 - origin, faces)
        tris = np.take(verts, f32, axis=0)
        return origin, verts, f32, tris, max(abs(float(verts.min())), abs(float(verts.max())))
    f32 = np.ascontiguousarray(f, dtype=np.int32)
    origin, verts, tris, big = _in_centred_frame(v, lo, hi, f32, "mesh")
    return origin, verts, f32, tris, big


def _centred_vertices(vertices, faces, shape, spare=None):
    """update's (origin, vertices, triangles, largest |coordinate|, bounds in the frame) for new
    ``vertices`` of ``shape`` over the caster's validated ``faces``: one pass over the values for
    bounds and NaN/inf/1e30 (the messages from the slow checks when it finds one), then as
    _centred_mesh (into the arrays ``spare`` where given).

    The bounds in the frame are float32(lo - origin) and float32(hi - origin): the conversion of
    the least and the greatest coordinate, as both the float64 difference and the rounding to
    float32 keep the order of the values (no pass over the vertices)."""
    v = _vertex_array(vertices, "update: vertices")
    if v.shape != shape:
        raise InputError(f"update needs vertices of shape {shape}, got {v.shape}")
    lo, hi, bad = common.point_bounds(v)
    if bad:
        _vertices64(vertices, "update: vertices")  # raises naming the bad values
    origin, verts, tris, big = _in_centred_frame(v, lo, hi, faces, "update", spare)
    box = tuple((b - origin).astype(np.float32).astype(np.float64) for b in (lo, hi))
    return origin, verts, tris, big, box


#: contains' ray directions: the first alone for a closed mesh, all three for a best-effort vote
#: (directions that no axis-aligned or simply placed mesh holds: fewer grazing rays)
CONTAINS_DIRECTIONS = ((0.5772854991, 0.3316624790, 0.7461309638), (-0.2673, 0.8018, -0.5345),
                       (0.8944, -0.4472, 0.0313))
CONTAINS_DIRECTION = CONTAINS_DIRECTIONS[0]

#: bytes a RayCaster's mesh takes beyond its grid (which GridBuilder checks itself): per vertex its
#: float32 copy in the caster's frame, per face the int32 indices and the float32 triangles
MESH_VERTEX_BYTES, MESH_FACE_BYTES, TRIANGLE_BYTES = 12, 48, 36


def _check_mesh_fits(what, n_vertices, n_faces, face_bytes):
    """InputError before the mesh arrays of a RayCaster (``face_bytes`` a face) are allocated
    when they exceed the memory left (gridrt.memory)."""
    check_fits(MESH_VERTEX_BYTES * n_vertices + face_bytes * n_faces, f"{what} ({n_faces:,} triangles)",
               "vertices, faces and triangles in the caster's frame, before its grid",
               "split the mesh or free memory")


def _rows(a):
    """len(a), or 0 for what has none (refused later, with its own message)."""
    try:
        return len(a)
    except TypeError:
        return 0


class _Snapshot:
    """One mesh as casts see it; never modified after construction (``users`` aside: the casts
    holding it, counted under the caster's lock)."""

    __slots__ = ("origin", "vertices", "triangles", "grid", "builder", "users", "normals")

    def __init__(self, origin, vertices, triangles, grid, builder):
        self.origin, self.vertices, self.triangles, self.grid, self.builder = origin, vertices, triangles, grid, builder
        self.users = 0
        self.normals = None  # vertex normals, made on the first RayCaster.vertex_normals


class RayCaster:
    """A grid over an indexed triangle mesh, rebuilt on :meth:`update`; safe to share between
    Python threads (see the module doc).

    vertices (V,3) float, faces (F,3) int; params: GridParams (strategy, lambda, threads,
    max_bytes: also the memory budget of one cast's results...).
    Attributes (of the current mesh): origin (3,) float64 centre of the frame the grid lives in;
    vertices (V,3) float32 and triangles (F,3,3) float32 in that frame; grid.
    """

    def __init__(self, vertices, faces, params: GridParams | None = None):
        self.params = params or GridParams()
        _check_mesh_fits("building a RayCaster", _rows(vertices), _rows(faces), MESH_FACE_BYTES)
        with allocating(lambda: f"building a RayCaster over {len(faces):,} triangles"):
            origin, verts, self.faces, tris, big = _centred_mesh(vertices, faces)
            self.precision_warning = warn_detail(tris, "RayCaster mesh", big=big, sample=ONE_SHOT_SAMPLE)
            builder = GridBuilder(self.params)
            with launch_guard():
                grid = builder.build(tris, self.params)
        self._snap = _Snapshot(origin, verts, tris, grid, builder)
        self._lock = threading.Lock()  # guards _snap, its users counts and _spare
        self._update_lock = threading.Lock()  # one update at a time
        self._spare = None  # a builder no snapshot holds, for the next update
        self._spare_mesh = None  # (vertices, triangles) of a snapshot no cast holds, for the next update
        # whether every vertex is a corner of some face (found at the first update): the vertices'
        # bounds are then the triangles', and the updates' builds skip their pass over the triangles
        self._every_vertex_used = None
        self._open = None  # how many edges do not have two triangles (contains), once asked

    # the current mesh (read together, under updates from other threads, through one snapshot:
    # a cast does that itself)
    origin = property(lambda self: self._snap.origin)
    vertices = property(lambda self: self._snap.vertices)
    triangles = property(lambda self: self._snap.triangles)
    grid = property(lambda self: self._snap.grid)

    def bounds(self):
        """(lo, hi), (3,) float64 world coordinates: the current mesh's grid box, which holds the
        mesh (slightly padded)."""
        snap = self._snap
        spec = snap.grid.spec
        return np.asarray(spec.lo, np.float64) + snap.origin, np.asarray(spec.hi, np.float64) + snap.origin

    @staticmethod
    def _centre(v64):
        if len(v64) == 0:
            return np.zeros(3)
        # column by column: numpy's axis-0 reductions of (V, 3) arrays are about 10x slower
        return np.array([0.5 * (v64[:, i].min() + v64[:, i].max()) for i in range(3)])

    @classmethod
    def from_triangles(cls, tris, params: GridParams | None = None):
        """A caster over a triangle soup (F,3,3)."""
        t = np.asarray(tris)
        if t.ndim != 3 or t.shape[1:] != (3, 3):
            as_triangles(t)  # raises with the shape in the message
        F = len(t)
        with allocating(f"building a RayCaster over {F:,} triangles"):
            v, f = _vertices64(t.reshape(-1, 3), "triangles"), np.arange(3 * F, dtype=np.int32).reshape(F, 3)
        return cls(v, f, params)

    def update(self, vertices):
        """New vertex positions (same count and order); rebuilds the grid.  On an error the
        caster keeps its previous mesh.  Casts running meanwhile finish on the previous mesh."""
        with allocating(f"updating a RayCaster of {len(self.faces):,} triangles"):
            return self._update(vertices)

    def _update(self, vertices):
        _check_mesh_fits("updating a RayCaster", len(self._snap.vertices), len(self.faces), TRIANGLE_BYTES)
        origin, verts, tris, big, box = _centred_vertices(vertices, self.faces, self._snap.vertices.shape,
                                                          self._take_spare_mesh())
        # a cheap look (1024 triangles' edges, the extent from the vertices): warn when the mesh has
        # just become too fine for float32 at its size, not on every update of such a mesh
        if len(verts):
            msg = detail_warning(tris, "RayCaster mesh", sample=1024, big=big)
            if msg is not None and self.precision_warning is None:
                warnings.warn(msg, PrecisionWarning, stacklevel=3)
            self.precision_warning = msg
        with self._update_lock:
            with self._lock:
                builder, self._spare = self._spare, None
            if builder is None:
                builder = GridBuilder(self.params)
            if self._every_vertex_used is None:
                used = np.zeros(len(verts), np.bool_)
                used[self.faces.reshape(-1)] = True
                self._every_vertex_used = bool(used.all())
            with launch_guard():
                # (on an error the builder is dropped)
                grid = builder.build(tris, self.params, bounds=box if self._every_vertex_used else None)
            new = _Snapshot(origin, verts, tris, grid, builder)
            with self._lock:
                old, self._snap = self._snap, new
                if old.users == 0:
                    self._spare = old.builder
                # (a cast still running holds the old snapshot, and so its arrays: see _take_spare_mesh)
                self._spare_mesh = (old.vertices, old.triangles)
        return self

    def _take_spare_mesh(self):
        """The (vertices, triangles) arrays of the snapshot the last update replaced, to be
        written over by this update, when nothing else holds either of them; else None (the
        update makes new ones).  A cast still running on that mesh holds its snapshot, which
        holds them; so does a user who kept ``caster.vertices`` or ``caster.triangles``, or a
        view of one: those arrays stay as they were."""
        with self._lock:
            spare, self._spare_mesh = self._spare_mesh, None
        if spare is None:
            return None
        v, t = spare
        del spare
        # the references left: the local name and getrefcount's argument
        return (v, t) if sys.getrefcount(v) == 2 and sys.getrefcount(t) == 2 else None

    def _release(self, snap):
        with self._lock:
            snap.users -= 1
            if snap.users == 0 and snap is not self._snap and self._spare is None:
                self._spare = snap.builder

    def all_hits(self, origins, directions, t_min=0.0, t_max=np.inf, max_hits=None, threads=None) -> AllHits:
        """Every crossing of every ray with the mesh with t_min < t < t_max, in order of t:
        :class:`gridrt.trace.all_hits.AllHits` (offsets, t, tri, u, v; ray i's hits are the slice
        ``offsets[i]:offsets[i + 1]``).  One hit per crossing, also where a ray passes through a
        shared edge or vertex (gridrt.trace.all_hits: exact edge signs and one tie rule), so
        crossings through a closed mesh always pair up.  t_min, t_max: numbers or one per ray;
        ``max_hits``: each ray's nearest ones only."""
        return self._query(origins, directions, t_min, t_max, max_hits, threads, False)

    def count_hits(self, origins, directions, t_min=0.0, t_max=np.inf, threads=None):
        """The number of crossings of each ray (:meth:`all_hits`'s, without storing them), (N,) int64."""
        return self._query(origins, directions, t_min, t_max, None, threads, True)

    def contains(self, points, best_effort=False, threads=None):
        """Whether each point ((N, 3), world coordinates) lies inside the closed mesh, (N,) bool:
        the parity of the crossings (:meth:`count_hits`) of a ray from the point in the fixed
        direction :data:`CONTAINS_DIRECTION`.  Deterministic, and exact where that ray passes
        through edges and vertices (one crossing each); a point on the surface itself may go
        either way.  A mesh that is not closed (an edge with other than two triangles) is refused
        with InputError, unless ``best_effort``: then a point is inside when most of three rays
        (the direction and two others) cross an odd number of times."""
        open_edges = self._open_edges()
        if open_edges and not best_effort:
            raise InputError(f"contains needs a closed mesh: {open_edges:,} of its edges do not have exactly two "
                             f"triangles (holes, borders or non-manifold edges); pass best_effort=True for a vote "
                             f"of three rays")
        p = np.asarray(points)
        dirs = CONTAINS_DIRECTIONS[:1] if not open_edges else CONTAINS_DIRECTIONS
        votes = None
        for d in dirs:
            D = np.broadcast_to(np.asarray(d, np.float64), p.shape) if p.ndim == 2 and p.shape[1:] == (3,) else d
            odd = self._query(p, D, 0.0, np.inf, None, threads, True) % 2 == 1
            votes = odd.astype(np.int64) if votes is None else votes + odd
        return votes * 2 > len(dirs)

    # ---- surface attributes at hits (cast's Hits, all_hits' AllHits: anything with tri, u, v) ----
    def interpolate(self, hits, values):
        """A per-vertex array ``values`` ((V,) or (V, k): texture coordinates, colours, normals,
        anything) at each hit: ``(1 - u - v) values[i0] + u values[i1] + v values[i2]`` over the hit
        triangle's vertices, float64; NaN for a miss (tri -1)."""
        tri, u, v = self._hit_parts(hits)
        a = np.asarray(values)
        if a.ndim not in (1, 2) or len(a) != len(self._snap.vertices):
            raise InputError(f"values must have one row a vertex ({len(self._snap.vertices)}), got shape {a.shape}")
        if not (np.issubdtype(a.dtype, np.floating) or np.issubdtype(a.dtype, np.integer)):
            raise InputError(f"values must be real numbers, got dtype {a.dtype}")
        a = a.astype(np.float64, copy=False)
        hit = tri >= 0
        f = self.faces[np.where(hit, tri, 0)]
        ex = (slice(None),) + (None,) * (a.ndim - 1)
        out = (1.0 - u - v)[ex] * a[f[:, 0]] + u[ex] * a[f[:, 1]] + v[ex] * a[f[:, 2]]
        out[~hit] = np.nan
        return out

    def geometric_normals(self, hits):
        """The unit normal of each hit triangle ((N, 3), float64, NaN for a miss), on the side its
        winding makes front: ``normalize((p1 - p0) x (p2 - p0))``."""
        tri, _, _ = self._hit_parts(hits)
        hit = tri >= 0
        t = self._snap.triangles[np.where(hit, tri, 0)].astype(np.float64)
        n = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
        with np.errstate(invalid="ignore", divide="ignore"):
            n /= np.linalg.norm(n, axis=1, keepdims=True)
        n[~hit] = np.nan
        return n

    def vertex_normals(self):
        """Area-weighted unit normals of the current mesh's vertices, (V, 3) float64 (the sum of
        the adjacent triangles' cross products, normalised; 0 for a vertex of no triangle); made
        once per mesh (update makes a new one)."""
        snap = self._snap
        if snap.normals is None:
            snap.normals = self._vertex_normals(snap)
        return snap.normals

    def _vertex_normals(self, snap):
        v = snap.vertices.astype(np.float64)
        f = self.faces
        c = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
        n = np.zeros_like(v)
        for k in range(3):
            np.add.at(n, f[:, k], c)
        length = np.linalg.norm(n, axis=1, keepdims=True)
        return np.divide(n, length, out=np.zeros_like(n), where=length > 0)

    def shading_normals(self, hits):
        """The interpolated vertex normals at each hit, normalised ((N, 3), NaN for a miss)."""
        n = self.interpolate(hits, self.vertex_normals())
        with np.errstate(invalid="ignore", divide="ignore"):
            return n / np.linalg.norm(n, axis=1, keepdims=True)

    def _hit_parts(self, hits):
        try:
            tri, u, v = (np.asarray(getattr(hits, k)) for k in ("tri", "u", "v"))
        except AttributeError:
            raise InputError(f"hits must be what cast or all_hits returns (with tri, u, v), got "
                             f"{type(hits).__name__}") from None
        if not (tri.ndim == u.ndim == v.ndim == 1 and len(tri) == len(u) == len(v)) \
                or not np.issubdtype(tri.dtype, np.integer):
            raise InputError("hits need tri, u, v of one length each, tri integers")
        if len(tri) and (tri.min() < -1 or tri.max() >= len(self.faces)):
            raise InputError(f"hits name triangles outside this mesh's {len(self.faces)}")
        return tri.astype(np.int64), u.astype(np.float64), v.astype(np.float64)

    def _open_edges(self):
        """How many of the mesh's edges do not have exactly two triangles, its corners welded by
        position (counted once: faces never change)."""
        if self._open is None:
            # corners at the same position are one vertex (a triangle soup, or a mesh split at seams)
            _, weld = np.unique(self._snap.vertices, axis=0, return_inverse=True)
            f = weld.reshape(-1)[np.asarray(self.faces, np.int64)]
            e = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
            _, n = np.unique(e[:, 0] * (int(f.max(initial=0)) + 1) + e[:, 1], return_counts=True)
            self._open = int(np.count_nonzero(n != 2))
        return self._open

    def _query(self, origins, directions, t_min, t_max, max_hits, threads, count_only):
        with self._lock:
            snap = self._snap
            snap.users += 1
        try:
            with allocating(lambda: f"finding the hits of {_rows(origins):,} rays", "cast fewer rays at a time"):
                return query_hits(snap.grid, snap.triangles, origins, directions, snap.origin, t_min, t_max,
                                  max_hits, threads if threads is not None else self.params.threads, count_only)
        finally:
            self._release(snap)

    def cast(self, origins, directions, tmin=0.0, tmax=np.inf, watertight=True, any_hit=False, threads=None,
             max_bytes=None, packets=True, packet_precision="float64", *, t_min=None, t_max=None) -> Hits:
        """Nearest hit per ray (any hit with any_hit=True) with tmin < t < tmax (``t_min`` and
        ``t_max`` name them as all_hits does). origins, directions: (N,3), world
        coordinates, any real dtype and strides (read in chunks, not copied).  Memory: the
        results (28 bytes a ray) plus a bounded scratch; a batch needing more than ``max_bytes``
        (default: params.max_bytes) or than this process has left (gridrt.memory) is refused
        before anything is allocated.  Coherent runs of
        rays (camera rays, shadow rays towards a point, in any order) go through CGT packets
        (``packets=False``: every ray on its own); the hits do not depend on it, nor on the rays'
        order or grouping.  ``packet_precision="float32"`` runs the packets' triangle tests in
        float32 (faster on large meshes; hits then agree up to float32 rounding, see
        gridrt.trace.batch)."""
        for alias, value, name in ((t_min, tmin, "tmin"), (t_max, tmax, "tmax")):
            if alias is not None and value != (0.0 if name == "tmin" else np.inf):
                raise InputError(f"give {name} or t_{name[1:]}, not both")
        tmin = tmin if t_min is None else t_min
        tmax = tmax if t_max is None else t_max
        with self._lock:
            snap = self._snap
            snap.users += 1
        try:
            with allocating(lambda: f"casting {len(origins):,} rays", "cast fewer rays at a time"):
                return cast_batch(snap.grid, snap.triangles, origins, directions, snap.origin, tmin, tmax, watertight,
                                  any_hit, threads, self.params.max_bytes if max_bytes is None else max_bytes,
                                  packets=packets, packet_precision=packet_precision)
        finally:
            self._release(snap)
