"""Midpoint subdivision to a target triangle count, for scaling experiments.

Each pass splits every triangle 1 -> 4 at its edge midpoints (shared edges get one shared
midpoint vertex, so a closed mesh stays closed).  The surface does not change shape, only its
triangle count: a renderer shows the same image, while the grid holds 4x more triangles per pass.
The four children of triangle f are triangles ``4f .. 4f+3`` (memory order stays spatially
coherent) and keep its orientation and its looks (``Mesh.surface``): the material of f, and per
corner uv, colours and normals interpolated linearly at the edge midpoints (normals normalised
again; a midpoint of two zero normals, "the geometric normal", stays zero)::

        c                 children of (a, b, c), with m_ab, m_bc, m_ca the edge midpoints:
       / \\                  4f+0: (a, m_ab, m_ca)     4f+1: (m_ab, b, m_bc)
   m_ca---m_bc              4f+2: (m_ca, m_bc, c)     4f+3: (m_ab, m_bc, m_ca)
     / \\ / \\
    a---m_ab--b
"""

from numbers import Integral

import numpy as np

from ..arrays import TRI_DTYPE, storage_centre
from ..errors import InputError
from .mesh import Mesh

__all__ = ["subdivide_mesh", "split_once", "split_surface", "MAX_SUBDIVIDED_TRIANGLES"]

#: Largest triangle count a subdivision may target.
MAX_SUBDIVIDED_TRIANGLES = 100_000_000


def split_once(vertices, faces):
    """One 1 -> 4 midpoint split: ``(vertices (V + E, 3), faces (4F, 3) int32)``.

    vertices (V,3) float32 or float64 and faces (F,3) int32 must be valid (see :class:`Mesh`).
    New vertex ``V + e`` is the midpoint (computed in float64, returned in the dtype of
    ``vertices``) of the e-th distinct undirected edge.
    """
    v = np.asarray(vertices)
    f = np.asarray(faces, dtype=np.int64)
    nv = len(v)
    edges = f[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    lo = edges.min(axis=1)
    hi = edges.max(axis=1)
    uniq, inv = np.unique(lo * nv + hi, return_inverse=True)
    a, b = uniq // nv, uniq % nv
    dtype = np.float64 if v.dtype == np.float64 else TRI_DTYPE
    mid = (0.5 * (v[a].astype(np.float64) + v[b].astype(np.float64))).astype(dtype)
    m = (inv.reshape(-1, 3) + nv).astype(np.int64)
    m_ab, m_bc, m_ca = m[:, 0], m[:, 1], m[:, 2]
    c0, c1, c2 = f[:, 0], f[:, 1], f[:, 2]
    children = np.stack([
        np.stack([c0, m_ab, m_ca], axis=1),
        np.stack([m_ab, c1, m_bc], axis=1),
        np.stack([m_ca, m_bc, c2], axis=1),
        np.stack([m_ab, m_bc, m_ca], axis=1),
    ], axis=1).reshape(-1, 3)
    return np.concatenate([v.astype(dtype), mid]), children.astype(np.int32)


def _split_corners(a, unit=False):
    """(4F, 3, k) per-corner values of the children of (F, 3, k) ``a``, in split_once's order."""
    a = np.asarray(a, np.float32)  # float32 like the Surface (halves the memory of large splits)
    c0, c1, c2 = a[:, 0], a[:, 1], a[:, 2]
    m_ab, m_bc, m_ca = 0.5 * (c0 + c1), 0.5 * (c1 + c2), 0.5 * (c2 + c0)
    if unit:
        for m in (m_ab, m_bc, m_ca):
            length = np.sqrt((m * m).sum(axis=1, keepdims=True))
            np.divide(m, length, out=m, where=length > 0)
    out = np.stack([
        np.stack([c0, m_ab, m_ca], axis=1),
        np.stack([m_ab, c1, m_bc], axis=1),
        np.stack([m_ca, m_bc, c2], axis=1),
        np.stack([m_ab, m_bc, m_ca], axis=1),
    ], axis=1)
    return out.reshape(-1, 3, a.shape[2])


def split_surface(surface):
    """The surface of ``split_once``'s children: one 1 -> 4 split of a Surface (or None)."""
    if surface is None:
        return None
    from .surface import Surface

    s = surface
    split = (lambda a, unit=False: None if a is None else _split_corners(a, unit))
    return Surface(np.repeat(s.material, 4), s.diffuse, s.ambient, s.texture, s.textures,
                   split(s.uv), split(s.colors), split(s.normals, unit=True))


def subdivide_mesh(mesh, target):
    """Split ``mesh`` 1 -> 4 until it has at least ``target`` triangles; return a new :class:`Mesh`.

    A mesh that already has ``target`` triangles or more is returned unchanged.  Raises InputError
    for a non-Mesh, a non-integer or non-positive target, or a target above
    :data:`MAX_SUBDIVIDED_TRIANGLES` (or one the int32 vertex indices cannot reach).
    """
    if not isinstance(mesh, Mesh):
        raise InputError(f"subdivide needs an gridrt.scene.Mesh, got {type(mesh).__name__}")
    if isinstance(target, (bool, np.bool_)) or not isinstance(target, (Integral, np.integer)):
        raise InputError(f"subdivide target must be an integer triangle count, got {target!r}")
    if not 1 <= target <= MAX_SUBDIVIDED_TRIANGLES:
        raise InputError(f"subdivide target must be between 1 and {MAX_SUBDIVIDED_TRIANGLES:,}, got {target}")
    # far from the origin the split runs on the exact float64 vertices (float32 world coordinates
    # would round every new vertex); near it, as before, on float32 vertices
    v, f = (mesh.vertices64 if storage_centre(mesh.vertices64).any() else mesh.vertices), mesh.faces
    passes = 0
    surface = mesh.surface
    while len(f) < target:
        v, f = split_once(v, f)
        surface = split_surface(surface)
        passes += 1
    if passes == 0:
        return mesh
    return Mesh(v, f, name=f"{mesh.name} (subdivided x{4 ** passes})", path=mesh.path, surface=surface)
