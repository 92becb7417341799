"""Indexed triangle meshes (:class:`Mesh`) and what the mesh loaders share: the default looks
(:data:`DEFAULT_DIFFUSE`, :data:`AMBIENT_FRACTION`), the image files a material may name
(:data:`IMAGE_EXTENSIONS`) and :func:`quiet_trimesh`.  :func:`gridrt.scene.loader.load_mesh`
reads a mesh from a file (OBJ with :mod:`gridrt.scene.obj`).
"""

import contextlib
import logging
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..arrays import TRI_DTYPE, as_mesh64, as_origin, bounds_centre
from ..errors import InputError

__all__ = ["AMBIENT_FRACTION", "DEFAULT_DIFFUSE", "IMAGE_EXTENSIONS", "Mesh", "quiet_trimesh"]

@dataclass(frozen=True, eq=False)
class Mesh:
    """A validated indexed triangle mesh.

    Attributes
    ----------
    vertices : ndarray
        (V, 3) float32 world coordinates, read-only (rounded: far from the origin, use
        :meth:`triangles` with ``origin`` or :attr:`vertices64`).
    vertices64 : ndarray
        (V, 3) float64, read-only: the vertices exactly as given.
    faces : ndarray
        (F, 3) int32 indices into ``vertices``, read-only.
    name : str
        Short name (the file stem for loaded meshes).
    path : pathlib.Path or None
        The file the mesh came from, None for generated meshes.
    surface : gridrt.scene.surface.Surface or None
        The mesh's materials, textures and per-corner attributes (one row per face), or None.

    Construction validates with :func:`gridrt.arrays.as_mesh` (shapes, NaN/inf, index range,
    all-degenerate) and raises InputError; the arrays are copied, so the caller's arrays are
    never frozen or aliased.
    """

    vertices: np.ndarray
    faces: np.ndarray
    name: str = "mesh"
    path: Path | None = None
    surface: object = None

    vertices64: np.ndarray = field(default=None, init=False, repr=False)

    def __post_init__(self):
        v64, f = as_mesh64(self.vertices, self.faces, what=f"mesh {self.name!r}")
        v64 = v64.copy() if v64 is self.vertices else v64
        f = f.copy()
        v = v64.astype(TRI_DTYPE)
        for a in (v, v64, f):
            a.setflags(write=False)
        object.__setattr__(self, "vertices", v)
        object.__setattr__(self, "vertices64", v64)
        object.__setattr__(self, "faces", f)
        if self.path is not None:
            object.__setattr__(self, "path", Path(self.path))
        if self.surface is not None and getattr(self.surface, "n_triangles", None) != len(f):
            raise InputError(f"mesh {self.name!r}: its surface describes {getattr(self.surface, 'n_triangles', '?')} "
                             f"triangles, the mesh has {len(f)}")

    @property
    def n_triangles(self):
        """Number of triangles F."""
        return int(len(self.faces))

    @property
    def n_vertices(self):
        """Number of vertices V."""
        return int(len(self.vertices))

    def triangles(self, origin=None):
        """A new (F, 3, 3) float32 C-contiguous array ``vertices[faces]``; with ``origin`` ((3,)
        float64) the vertices are moved by ``-origin`` in float64 before rounding to float32."""
        if origin is None:
            return np.ascontiguousarray(self.vertices[self.faces])
        local = (self.vertices64 - as_origin(origin)).astype(TRI_DTYPE)
        return np.ascontiguousarray(local[self.faces])

    def bounds(self):
        """Axis-aligned bounding box ``(lo (3,) float64, hi (3,) float64)`` of the vertices."""
        return self.vertices64.min(axis=0), self.vertices64.max(axis=0)

    @property
    def centre(self):
        """(3,) float64 centre of :meth:`bounds`."""
        return bounds_centre(self.vertices64)

    def __repr__(self):
        return f"Mesh(name={self.name!r}, vertices={self.n_vertices}, faces={self.n_triangles})"


@contextlib.contextmanager
def quiet_trimesh():
    """Silence the loggers of trimesh and of PIL (which trimesh uses for glTF textures) for a block.

    trimesh logs warnings such as 'unable to use sparse matrix' or failed glTF extensions; gridrt
    reports problems through exceptions instead.
    """
    loggers = [logging.getLogger(name) for name in ("trimesh", "PIL")]
    old = [lg.level for lg in loggers]
    for lg in loggers:
        lg.setLevel(logging.CRITICAL + 1)
    try:
        yield
    finally:
        for lg, level in zip(loggers, old):
            lg.setLevel(level)


# ----------------------------------------------------------------------------- looks

#: DEFAULT_DIFFUSE: the default material (faces without a material, files whose only looks are
#: normals); every loaded material's ambient colour is AMBIENT_FRACTION * its diffuse colour (MTL
#: ``Ka`` is ignored: exporters write 1 1 1, 0 0 0, a copy of Kd or nothing)
from .surface import AMBIENT_FRACTION, DEFAULT_DIFFUSE  # noqa: E402
#: image files a material or skin may name (what Pillow reads; lower case)
IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".bmp", ".pcx", ".tga", ".ppm", ".pgm", ".gif", ".tif", ".tiff")


def _material_row(diffuse):
    d = np.asarray(diffuse, np.float32).reshape(3)
    return d, (np.float32(AMBIENT_FRACTION) * d).astype(np.float32)


def _unit_rows(n):
    """Rows of ``n`` (N, 3) scaled to unit length in float64; zero rows stay zero."""
    n = np.asarray(n, np.float64)
    length = np.sqrt((n * n).sum(axis=-1, keepdims=True))
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(length > 0, n / np.where(length > 0, length, 1.0), 0.0)
