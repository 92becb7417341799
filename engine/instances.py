"""Several meshes, each placed any number of times by a 4x4 transform: :class:`RayScene`.

    scene = RayScene()
    arm = scene.add_mesh(vertices, faces)             # a mesh id; its grid is built once, here
    a = scene.add_instance(arm, transform=M1)         # instance ids: one mesh placed twice,
    b = scene.add_instance(arm, transform=M2)         # sharing the mesh's grid (no copies)
    hits = scene.cast(origins, directions)            # t, tri, u, v, mesh, instance
    scene.update(transforms={a: M1_next}, vertices={arm: V_next})   # the next step

Each mesh is a :class:`gridrt.RayCaster` in its own (object) coordinates.  A world ray meets an
instance of transform ``M`` (object to world: ``x_world = A x + b``, the upper 3x4 of M) as the
object ray ``A^-1 (o - b) + t A^-1 d``: the same t, because the direction keeps its length
relative to the transform (it is not normalised).  So the hits of every instance are the
caster's own, exact and watertight in that mesh's coordinates, and t is comparable across
instances.

What an update costs: a new transform is only stored (the instance's rays are mapped through it at
the next query; its mesh's grid is untouched); new vertices of a mesh rebuild that mesh's grid and
no other, and every instance of the mesh sees them.

Queries test each instance's world box (the transformed corners of its mesh's bounds, slightly
padded) against every ray (a parallel kernel, :func:`reach_box`) and cast only the rays that reach
it, instance by instance: the cost grows with the number of instances each ray reaches, plus a box
test per ray and instance.
That suits tens to a few hundreds of instances (robot links, obstacles); there is no top-level
grid over the instances.

Attributes come back in world coordinates as if each instance's mesh had been transformed into
world coordinates (baked): geometric normals follow the world triangles' winding (a mirroring
transform turns them), shading normals are the baked mesh's vertex normals.
"""

import threading
from typing import NamedTuple

import numpy as np
from numba import njit, prange

from .api import RayCaster
from .arrays import check_ray_values, check_rays, read_only
from .config import GridParams
from .errors import InputError
from .trace.all_hits import t_bounds


class SceneHits(NamedTuple):
    """Nearest hit per ray of a :class:`RayScene`: t (N,) float64 (inf: miss), tri (N,) int32 (the
    triangle in its mesh, -1: miss), u, v (N,) float64 barycentrics, mesh and instance (N,) int32
    (-1: miss)."""

    t: np.ndarray
    tri: np.ndarray
    u: np.ndarray
    v: np.ndarray
    mesh: np.ndarray
    instance: np.ndarray


class SceneAllHits(NamedTuple):
    """Every hit of every ray of a :class:`RayScene`, ray i's in the slice ``offsets[i]:offsets[i + 1]``
    of t, tri, u, v, mesh and instance, sorted by t (ties: by instance, then triangle)."""

    offsets: np.ndarray
    t: np.ndarray
    tri: np.ndarray
    u: np.ndarray
    v: np.ndarray
    mesh: np.ndarray
    instance: np.ndarray

    def counts(self):
        """Hits per ray, (N,) int64."""
        return np.diff(self.offsets)


class _Instance(NamedTuple):
    """One placement: its mesh id, M (4x4 float64), A^-1 (3x3), b (3,), sign of det A."""

    mesh: int
    matrix: np.ndarray
    inverse: np.ndarray
    offset: np.ndarray
    sign: float


def _transform(m, what):
    """A checked affine 4x4 object-to-world matrix as an :class:`_Instance`'s parts."""
    a = np.asarray(m)
    if a.dtype == object or not (np.issubdtype(a.dtype, np.floating) or np.issubdtype(a.dtype, np.integer)):
        raise InputError(f"{what} must be a real 4x4 matrix, got dtype {a.dtype}")
    a = a.astype(np.float64)
    if a.shape != (4, 4):
        raise InputError(f"{what} must be a 4x4 matrix, got shape {a.shape}")
    if not np.isfinite(a).all() or np.abs(a).max() > 1e30:
        raise InputError(f"{what} has NaN, infinite or huge (beyond 1e30) entries")
    if not np.array_equal(a[3], [0.0, 0.0, 0.0, 1.0]):
        raise InputError(f"{what} must be affine: its last row must be 0 0 0 1, got {a[3].tolist()}")
    A = a[:3, :3]
    s = np.linalg.svd(A, compute_uv=False)
    if not s[-1] > 1e-12 * s[0]:
        raise InputError(f"{what} is singular (or nearly: its upper 3x3 block's singular values are "
                         f"{s[0]:.3g} .. {s[-1]:.3g}); an instance needs an invertible transform")
    return a, np.linalg.inv(A), a[:3, 3].copy(), float(np.sign(np.linalg.det(A)))


class RayScene:
    """Meshes placed by transforms, cast together (see the module doc).  ``params``: the
    GridParams of every mesh's caster (strategy, threads, memory budget).

    Ids: :meth:`add_mesh` and :meth:`add_instance` number meshes and instances from 0 in the order
    they are added; an instance's id stays its own after others are removed.

    Threads: queries may run from several Python threads at once, and transforms may change
    meanwhile (a query reads the instances once, at its start).  New vertices for a mesh must not
    come while a query runs: each mesh's caster stays consistent, but the query's box test could
    use the mesh's bounds from before the update."""

    def __init__(self, params: GridParams | None = None):
        self.params = params or GridParams()
        self._meshes = []          # RayCaster per mesh id
        self._instances = ()       # _Instance or None (removed) per instance id; replaced, never changed
        self._lock = threading.Lock()

    # ---- building and updating ----
    def add_mesh(self, vertices, faces):
        """Add a mesh ((V, 3) vertices in its own coordinates, (F, 3) faces) and build its grid;
        its id.  It is not cast until an instance places it."""
        caster = RayCaster(vertices, faces, self.params)
        with self._lock:
            self._meshes.append(caster)
            return len(self._meshes) - 1

    def add_instance(self, mesh, transform=None):
        """Place mesh ``mesh`` by ``transform`` (4x4 affine object-to-world matrix; default the
        identity); the instance's id."""
        m = self._mesh_id(mesh)
        parts = _transform(np.eye(4) if transform is None else transform, "transform")
        with self._lock:
            self._instances = self._instances + (_Instance(m, *parts),)
            return len(self._instances) - 1

    def remove_instance(self, instance):
        """Take instance ``instance`` out of the scene (its id is not reused)."""
        i = self._instance_id(instance)
        with self._lock:
            self._instances = self._instances[:i] + (None,) + self._instances[i + 1:]

    def update(self, vertices=None, transforms=None):
        """One simulation step: ``transforms`` {instance id: 4x4 matrix} moves instances (no grid
        is rebuilt); ``vertices`` {mesh id: (V, 3) array} gives meshes new vertex positions (each
        such mesh's grid is rebuilt once, for all its instances).  Ids and transforms are checked
        first; then the meshes are updated one after another, and the new transforms applied last.
        A mesh whose new vertices are refused (InputError) keeps its old ones and ends the update
        there: the meshes before it have their new vertices, no transform has changed."""
        moves = {}
        for i, m in (transforms or {}).items():
            i = self._instance_id(i)
            moves[i] = _Instance(self._instances[i].mesh, *_transform(m, f"transform of instance {i}"))
        meshes = [(self._mesh_id(k), v) for k, v in (vertices or {}).items()]
        for k, v in meshes:
            self._meshes[k].update(v)
        if moves:
            with self._lock:
                inst = list(self._instances)
                for i, new in moves.items():
                    if inst[i] is None:
                        raise InputError(f"instance {i} was removed")
                    inst[i] = new
                self._instances = tuple(inst)
        return self

    def set_transform(self, instance, transform):
        """Move one instance: :meth:`update` with ``transforms={instance: transform}``."""
        return self.update(transforms={instance: transform})

    # ---- what the scene holds ----
    @property
    def meshes(self):
        """The meshes' casters, by mesh id (each in its own coordinates)."""
        return tuple(self._meshes)

    def transform(self, instance):
        """Instance ``instance``'s 4x4 object-to-world matrix (a copy)."""
        return self._instances[self._instance_id(instance)].matrix.copy()

    def mesh_of(self, instance):
        """The mesh id instance ``instance`` places."""
        return self._instances[self._instance_id(instance)].mesh

    def instances(self):
        """The ids of the instances in the scene, in order."""
        return [i for i, x in enumerate(self._instances) if x is not None]

    def bounds(self):
        """(lo, hi) (3,) float64 of the world boxes of all instances (None for an empty scene)."""
        boxes = [self._box(x) for x in self._instances if x is not None]
        if not boxes:
            return None
        return np.min([b[0] for b in boxes], axis=0), np.max([b[1] for b in boxes], axis=0)

    # ---- queries ----
    def cast(self, origins, directions, t_min=0.0, t_max=np.inf, any_hit=False, threads=None) -> SceneHits:
        """Nearest hit per ray over every instance (``any_hit``: any one) with t_min < t < t_max
        (numbers), as :class:`SceneHits`; ties at one t go to the lower instance id."""
        if np.ndim(t_min) or np.ndim(t_max):
            raise InputError("cast takes numbers for t_min and t_max (all_hits and count_hits take one a ray)")
        o, d, inv, live = self._rays(origins, directions)
        n = len(o)
        lo, hi = _checked_bounds(t_min, t_max, n)
        t = np.full(n, np.inf)
        tri = np.full(n, -1, np.int32)
        u, v = np.zeros(n), np.zeros(n)
        mesh, inst = np.full(n, -1, np.int32), np.full(n, -1, np.int32)
        # (a ray goes on to an instance only while that one could still be nearer, or, for any_hit,
        # while it has hit nothing)
        reach = lambda: hi if any_hit else np.minimum(t, hi)
        keep = (lambda: tri < 0) if any_hit else None
        for i, x, idx, oo, dd in self._reached(live, o, d, inv, lo, reach, keep):
            h = self._meshes[x.mesh].cast(oo, dd, t_min=t_min, t_max=t_max, any_hit=any_hit, threads=threads)
            better = h.t < t[idx]
            k = idx[better]
            t[k], tri[k], u[k], v[k] = h.t[better], h.tri[better], h.u[better], h.v[better]
            mesh[k], inst[k] = x.mesh, i
        return SceneHits(t, tri, u, v, mesh, inst)

    def all_hits(self, origins, directions, t_min=0.0, t_max=np.inf, max_hits=None, threads=None) -> SceneAllHits:
        """Every crossing of every ray with every instance with t_min < t < t_max, in order of t
        (:meth:`gridrt.RayCaster.all_hits` per instance: one hit per crossing, watertight), as
        :class:`SceneAllHits`; ``max_hits``: each ray's nearest ones only."""
        o, d, inv, live = self._rays(origins, directions)
        n = len(o)
        lo, hi = _checked_bounds(t_min, t_max, n)
        parts = []
        for i, x, idx, oo, dd in self._reached(live, o, d, inv, lo, lambda: hi):
            h = self._meshes[x.mesh].all_hits(oo, dd, lo[idx], hi[idx], max_hits, threads)
            ray = np.repeat(idx, np.diff(h.offsets))
            parts.append((ray, h.t, h.tri, h.u, h.v, np.full(len(ray), x.mesh, np.int32),
                          np.full(len(ray), i, np.int32)))
        if not parts:
            e = np.empty(0)
            return SceneAllHits(np.zeros(n + 1, np.int64), e, np.empty(0, np.int32), e.copy(), e.copy(),
                                np.empty(0, np.int32), np.empty(0, np.int32))
        ray, t, tri, u, v, mesh, inst = (np.concatenate(c) for c in zip(*parts))
        order = np.lexsort((tri, inst, t, ray))
        ray, t, tri, u, v, mesh, inst = (a[order] for a in (ray, t, tri, u, v, mesh, inst))
        counts = np.bincount(ray, minlength=n)
        offsets = np.zeros(n + 1, np.int64)
        np.cumsum(counts, out=offsets[1:])
        if max_hits is not None and len(ray):
            keep = np.arange(len(ray)) - offsets[ray] < int(max_hits)
            ray, t, tri, u, v, mesh, inst = (a[keep] for a in (ray, t, tri, u, v, mesh, inst))
            np.cumsum(np.bincount(ray, minlength=n), out=offsets[1:])
        return SceneAllHits(offsets, t, tri, u, v, mesh, inst)

    def count_hits(self, origins, directions, t_min=0.0, t_max=np.inf, threads=None):
        """The number of crossings of each ray with all instances, (N,) int64 (:meth:`all_hits`'s
        counts, without storing the hits)."""
        o, d, inv, live = self._rays(origins, directions)
        n = len(o)
        lo, hi = _checked_bounds(t_min, t_max, n)
        counts = np.zeros(n, np.int64)
        for _, x, idx, oo, dd in self._reached(live, o, d, inv, lo, lambda: hi):
            counts[idx] += self._meshes[x.mesh].count_hits(oo, dd, lo[idx], hi[idx], threads)
        return counts

    def contains(self, points, best_effort=False, threads=None):
        """Whether each point ((N, 3), world coordinates) lies inside at least one instance, (N,)
        bool: :meth:`gridrt.RayCaster.contains` of each instance's mesh at the point mapped into the
        mesh's coordinates (closed meshes only, unless ``best_effort``)."""
        p = np.asarray(points)
        o, _ = check_rays(p, p)
        check_ray_values(o, np.ones_like(o, dtype=np.float64))
        o = o.astype(np.float64)
        inside = np.zeros(len(o), bool)
        for i, x in self._live():
            lo, hi = self._box(x)
            idx = np.flatnonzero(np.all((o >= lo) & (o <= hi), axis=1))
            if len(idx):
                inside[idx] |= self._meshes[x.mesh].contains((o[idx] - x.offset) @ x.inverse.T, best_effort, threads)
        return inside

    # ---- attributes at hits (cast's SceneHits, all_hits' SceneAllHits), world coordinates ----
    def geometric_normals(self, hits):
        """The world unit normal of each hit triangle as placed by its instance ((N, 3), NaN for a
        miss), on the side the world triangle's winding makes front."""
        return self._per_instance(hits, lambda m, c, h, x: _unit(x.sign * (c.geometric_normals(h) @ x.inverse)), True)

    def shading_normals(self, hits):
        """The interpolated vertex normals at each hit in world coordinates, normalised ((N, 3),
        NaN for a miss): those of the instance's mesh baked into world coordinates (its unit vertex
        normals carried into world coordinates and normalised there, then interpolated)."""
        def world(m, c, h, x):
            n = x.sign * (c.vertex_normals() @ x.inverse)
            with np.errstate(invalid="ignore", divide="ignore"):
                n /= np.linalg.norm(n, axis=1, keepdims=True)
            return _unit(c.interpolate(h, np.nan_to_num(n)))
        return self._per_instance(hits, world, True)

    def interpolate(self, hits, values):
        """Per-vertex arrays at each hit, float64, NaN for a miss: ``values`` holds one array a
        mesh ((V,) or (V, k), its mesh's vertex count; texture coordinates, colours...), as a list
        by mesh id or a dict {mesh id: array}; hits on a mesh without one are NaN.  Values are not
        transformed (pass world-space quantities yourself)."""
        table = dict(enumerate(values)) if isinstance(values, (list, tuple)) else dict(values)
        for k in table:
            self._mesh_id(k)
        return self._per_instance(hits, lambda m, c, h, x: c.interpolate(h, table[m]), False,
                                  lambda m: table.get(m) is not None)

    # ---- internals ----
    def _mesh_id(self, mesh):
        if isinstance(mesh, bool) or not isinstance(mesh, (int, np.integer)) or not 0 <= mesh < len(self._meshes):
            raise InputError(f"no mesh {mesh!r} in this scene (it has {len(self._meshes)})")
        return int(mesh)

    def _instance_id(self, instance):
        inst = self._instances
        if isinstance(instance, bool) or not isinstance(instance, (int, np.integer)) or not 0 <= instance < len(inst) \
                or inst[instance] is None:
            raise InputError(f"no instance {instance!r} in this scene (ids in use: {self.instances()})")
        return int(instance)

    def _live(self):
        return [(i, x) for i, x in enumerate(self._instances) if x is not None]

    def _rays(self, origins, directions):
        """(origins, directions, their inverse for the box tests, the live instances): float64
        C-contiguous (N, 3), checked; a zero component's inverse is 1e300 (no inf * 0 in a slab)."""
        o, d = check_rays(origins, directions)
        check_ray_values(o, d)
        if len(d) and not np.abs(d).max(axis=1).min() > 0:
            raise InputError(f"ray direction {int(np.argmin(np.abs(d).max(axis=1)))} is zero")
        o, d = np.ascontiguousarray(o, np.float64), np.ascontiguousarray(d, np.float64)
        return o, d, 1.0 / np.where(d == 0.0, 1e-300, d), self._live()

    def _box(self, x):
        lo, hi = self._meshes[x.mesh].bounds()
        corners = np.array([[(lo, hi)[(k >> a) & 1][a] for a in range(3)] for k in range(8)])
        w = corners @ x.matrix[:3, :3].T + x.offset
        wlo, whi = w.min(axis=0), w.max(axis=0)
        pad = 1e-6 * (whi - wlo).max() + 1e-9 * np.abs(w).max() + 1e-30
        return wlo - pad, whi + pad

    def _reaching(self, x, o, inv, tmin, tmax):
        """The rays whose segment (tmin, tmax) ((N,) arrays) meets instance x's world box (bool (N,))."""
        lo, hi = self._box(x)
        out = np.empty(len(o), np.bool_)
        if len(o):
            # (read-only views: the caller's bounds or arrays made here, one compile)
            reach_box(*(read_only(a) for a in (o, inv, tmin, tmax, lo, hi)), out)
        return out

    def _reached(self, live, o, d, inv, tmin, tmax, keep=None):
        """For each live instance (i, x) that some rays reach: (i, x, their indices, the rays in
        its mesh's coordinates).  ``tmax()`` gives the rays' t limits and ``keep()`` (optional) a
        mask of the rays still asking, both read anew for each instance."""
        for i, x in live:
            sel = self._reaching(x, o, inv, tmin, tmax())
            if keep is not None:
                sel &= keep()
            idx = np.flatnonzero(sel)
            if len(idx):
                yield (i, x, idx, *self._object_rays(x, o[idx], d[idx]))

    @staticmethod
    def _object_rays(x, o, d):
        return (o - x.offset) @ x.inverse.T, d @ x.inverse.T

    def _per_instance(self, hits, f, normals, has=lambda m: True):
        try:
            tri, inst = np.asarray(hits.tri), np.asarray(hits.instance)
            u, v = np.asarray(hits.u), np.asarray(hits.v)
        except AttributeError:
            raise InputError(f"hits must be what RayScene.cast or all_hits returns (with tri, u, v, instance), got "
                             f"{type(hits).__name__}") from None
        if not (tri.shape == inst.shape == u.shape == v.shape and tri.ndim == 1):
            raise InputError("hits need tri, u, v and instance of one length each")
        live = self._instances
        if len(inst) and (inst.min() < -1 or inst.max() >= len(live)):
            raise InputError(f"hits name instances outside this scene's {len(live)}")
        out = None
        for i in np.unique(inst[inst >= 0]):
            x = live[i]
            if x is None:
                raise InputError(f"hits name instance {i}, which was removed")
            if not has(x.mesh):
                continue
            k = np.flatnonzero(inst == i)
            r = f(x.mesh, self._meshes[x.mesh], _Part(tri[k], u[k], v[k]), x)
            if out is None:
                out = np.full((len(tri),) + r.shape[1:], np.nan)
            elif out.shape[1:] != r.shape[1:]:
                raise InputError(f"values of different shapes per mesh: {out.shape[1:]} and {r.shape[1:]}")
            out[k] = r
        if out is None:
            out = np.full((len(tri), 3) if normals else (len(tri),), np.nan)
        return out


@njit(cache=True, parallel=True)
def reach_box(o, inv, tmin, tmax, lo, hi, out):
    """out[i]: whether ray i (origin o[i], inverse direction inv[i], (N, 3) float64) meets the box
    lo, hi ((3,) float64) with t in [tmin[i], tmax[i]] (slabs)."""
    for i in prange(o.shape[0]):
        t0, t1 = tmin[i], tmax[i]
        for a in range(3):
            ta = (lo[a] - o[i, a]) * inv[i, a]
            tb = (hi[a] - o[i, a]) * inv[i, a]
            t0 = max(t0, min(ta, tb))
            t1 = min(t1, max(ta, tb))
        out[i] = t0 <= t1


class _Part(NamedTuple):
    tri: np.ndarray
    u: np.ndarray
    v: np.ndarray


def _checked_bounds(t_min, t_max, n):
    """(t_min, t_max) as (n,) float64 arrays; InputError unless 0 <= t_min <= t_max (no NaN)."""
    lo, hi = t_bounds("t_min", t_min, n), t_bounds("t_max", t_max, n)
    bad = np.isnan(lo) | np.isnan(hi) | (lo < 0) | (hi < lo)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise InputError(f"need 0 <= t_min <= t_max, got t_min={lo[i]}, t_max={hi[i]} for ray {i}")
    return lo, hi


def _unit(n):
    """Rows of n normalised. (Object normals go to world ones as A^-T n, a row n as n A^-1, turned
    with the winding where A mirrors.)"""
    with np.errstate(invalid="ignore", divide="ignore"):
        return n / np.linalg.norm(n, axis=1, keepdims=True)
