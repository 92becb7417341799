"""Batch ray casting for users who only want hits: vertices + faces in, per-ray t, triangle id
and barycentrics out, with cheap per-frame vertex updates.

    caster = RayCaster(vertices, faces)             # builds the grid
    hits = caster.cast(origins, directions)         # Hits(t, tri, u, v); miss: inf, -1
    caster.update(new_vertices)                     # same topology, next frame: rebuilds

The caster works in a frame centred on the mesh: it subtracts the float64 centre of the
vertices' bounds before storing them as float32 (and from every ray origin), so a mesh far from
the world origin keeps its precision; t, triangle ids and barycentrics are unchanged by that.
"""

import numpy as np

from .arrays import as_mesh, as_rays, as_triangles
from .config import GridParams
from .errors import InputError
from .grid.build import GridBuilder
from .trace.render import Hits, cast_rays


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


class RayCaster:
    """A grid over an indexed triangle mesh, rebuilt on :meth:`update`.

    vertices (V,3) float, faces (F,3) int; params: GridParams (strategy, lambda, threads...).
    Attributes: origin (3,) float64 centre of the frame the grid lives in; vertices (V,3)
    float32 and triangles (F,3,3) float32 in that frame; grid.
    """

    def __init__(self, vertices, faces, params: GridParams | None = None):
        self.params = params or GridParams()
        v64 = _vertices64(vertices, "vertices")
        self.origin = self._centre(v64)
        self.vertices, self.faces = as_mesh(v64 - self.origin, faces)
        self.triangles = np.take(self.vertices, self.faces, axis=0)
        self._builder = GridBuilder(self.params)
        self.grid = self._builder.build(self.triangles, self.params)

    @staticmethod
    def _centre(v64):
        if len(v64) == 0:
            return np.zeros(3)
        return 0.5 * (v64.min(axis=0) + v64.max(axis=0))

    @classmethod
    def from_triangles(cls, tris, params: GridParams | None = None):
        """A caster over a triangle soup (F,3,3)."""
        t = np.asarray(tris)
        if t.ndim != 3 or t.shape[1:] != (3, 3):
            as_triangles(t)  # raises with the shape in the message
        F = len(t)
        return cls(_vertices64(t.reshape(-1, 3), "triangles"), np.arange(3 * F, dtype=np.int32).reshape(F, 3), params)

    def update(self, vertices):
        """New vertex positions (same count and order); rebuilds the grid.  On an error the
        caster keeps its previous vertices and grid."""
        v64 = _vertices64(vertices, "update: vertices")
        if v64.shape != self.vertices.shape:
            raise InputError(f"update needs vertices of shape {self.vertices.shape}, got {v64.shape}")
        origin = self._centre(v64)
        verts = (v64 - origin).astype(np.float32)
        tris = np.take(verts, self.faces, axis=0)
        try:
            grid = self._builder.build(tris, self.params)
        except BaseException:
            self.grid = self._builder.build(self.triangles, self.params)  # the old grid was reused
            raise
        self.origin, self.vertices, self.triangles, self.grid = origin, verts, tris, grid
        return self

    def cast(self, origins, directions, tmin=0.0, tmax=np.inf, watertight=True, any_hit=False, threads=None) -> Hits:
        """Nearest hit per ray (any hit with any_hit=True). origins, directions: (N,3)."""
        o, d = as_rays(origins, directions)
        return cast_rays(self.grid, self.triangles, o - self.origin, d, tmin=tmin, tmax=tmax,
                         watertight=watertight, any_hit=any_hit, threads=threads)
