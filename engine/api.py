"""Batch ray casting for users who only want hits: vertices + faces in, per-ray t, triangle id
and barycentrics out, with cheap per-frame vertex updates.

    caster = RayCaster(vertices, faces)             # builds the grid
    hits = caster.cast(origins, directions)         # Hits(t, tri, u, v); miss: inf, -1
    caster.update(new_vertices)                     # same topology, next frame: rebuilds
"""

import numpy as np

from .arrays import as_mesh, as_triangles
from .config import GridParams
from .errors import InputError
from .grid.build import GridBuilder
from .trace.render import Hits, cast_rays


class RayCaster:
    """A grid over an indexed triangle mesh, rebuilt on :meth:`update`.

    vertices (V,3) float, faces (F,3) int; params: GridParams (strategy, lambda, threads...).
    """

    def __init__(self, vertices, faces, params: GridParams | None = None):
        self.params = params or GridParams()
        self.vertices, self.faces = as_mesh(vertices, faces)
        self.triangles = np.empty((len(self.faces), 3, 3), np.float32)
        self._builder = GridBuilder(self.params)
        self._rebuild()

    @classmethod
    def from_triangles(cls, tris, params: GridParams | None = None):
        """A caster over a triangle soup (F,3,3)."""
        t = as_triangles(tris, allow_degenerate=False)
        F = len(t)
        return cls(t.reshape(-1, 3), np.arange(3 * F, dtype=np.int32).reshape(F, 3), params)

    def _rebuild(self):
        np.take(self.vertices, self.faces, axis=0, out=self.triangles)
        self.grid = self._builder.build(self.triangles, self.params)

    def update(self, vertices):
        """New vertex positions (same count and order); rebuilds the grid."""
        v = np.asarray(vertices)
        if v.shape != self.vertices.shape:
            raise InputError(f"update needs vertices of shape {self.vertices.shape}, got {v.shape}")
        if not np.isfinite(v).all():
            raise InputError("update: vertices contain NaN or infinity")
        self.vertices[...] = v
        self._rebuild()
        return self

    def cast(self, origins, directions, tmin=0.0, tmax=np.inf, watertight=True, any_hit=False, threads=None) -> Hits:
        """Nearest hit per ray (any hit with any_hit=True). origins, directions: (N,3)."""
        return cast_rays(self.grid, self.triangles, origins, directions, tmin=tmin, tmax=tmax,
                         watertight=watertight, any_hit=any_hit, threads=threads)
