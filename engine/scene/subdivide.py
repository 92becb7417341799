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
from ..memory import allocating, check_fits, human
from .mesh import Mesh
from .surface import Surface

__all__ = ["subdivide_mesh", "split_once", "split_surface", "subdivide_bytes", "MAX_SUBDIVIDED_TRIANGLES"]

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
    s = surface
    split = (lambda a, unit=False: None if a is None else _split_corners(a, unit))
    return Surface(np.repeat(s.material, 4), s.diffuse, s.ambient, s.texture, s.textures,
                   split(s.uv), split(s.colors), split(s.normals, unit=True))


#: bytes a split_once of F faces allocates per face at its peak: faces as int64 (24), the edge list
#: (48), its ends (48), the edge of each corner (24), the midpoint indices and their copy (48), the
#: four children stacks and their stack (192), and np.unique's sort of the edge keys beside them
#: (about 123, but it is over before the stacks start: not added)
SPLIT_FACE_BYTES = 384
#: per new vertex (edge): the unique keys and their two ends (24) and the float64 midpoint's
#: temporaries (72)
SPLIT_EDGE_BYTES = 96
#: bytes the Mesh of F faces and V vertices allocates while it checks itself, per face: the
#: float32 triangles gathered (36) and the area test's float64 triangles, edges and cross product
#: with np.cross's copies (200); per vertex: float64 vertices (24) and float32 centred ones (12)
MESH_CHECK_FACE_BYTES = 236
MESH_CHECK_VERTEX_BYTES = 36
#: per face of a split surface: the repeated materials (16) and the Surface's copy (16); per corner
#: component: the (F,3,k) float32 children (48) and the Surface's copy of them (48) (the midpoints
#: and stacks of the attribute being split, 60 a component, come before the copies: less)
SURFACE_FACE_BYTES = 32
SURFACE_COMPONENT_BYTES = 96


def _passes(F, V, target):
    """[(faces, vertices, edges)] of the mesh before each 1 -> 4 split that reaching ``target``
    triangles takes, then after the last: the edges of the first mesh taken as 3F (at most; a
    closed mesh has 1.5F), a split making 2E + 3F of E edges and F faces."""
    E = 3 * F
    out = [(F, V, E)]
    while F < target:
        F, V, E = 4 * F, V + E, 2 * E + 3 * F
        out.append((F, V, E))
    return out


def subdivide_bytes(mesh, target):
    """Bytes :func:`subdivide_mesh` allocates at its peak to split ``mesh`` up to ``target``
    triangles: the larger of a split's peak (split_once, split_surface, beside the mesh being
    split) and the final Mesh's check beside its vertices, faces and surface."""
    vs = 8 if storage_centre(mesh.vertices64).any() else 4
    s = mesh.surface
    K = sum(a.shape[2] for a in ((s.uv, s.colors, s.normals) if s is not None else ()) if a is not None)
    surface = (lambda F: (4 + 12 * K) * F) if s is not None else (lambda F: 0)
    peak = 0
    passes = _passes(mesh.n_triangles, mesh.n_vertices, target)
    for (F, V, E), (F1, V1, _) in zip(passes, passes[1:]):
        held = V * vs + 12 * F + surface(F)
        split = SPLIT_FACE_BYTES * F + SPLIT_EDGE_BYTES * E + V1 * vs + 12 * F1
        if s is not None:  # split_surface, beside the split vertices and faces
            split = max(split, V1 * vs + 12 * F1 + (SURFACE_FACE_BYTES + SURFACE_COMPONENT_BYTES * K) * F)
        peak = max(peak, held + split)
    F, V, _ = passes[-1]
    if len(passes) > 1:
        peak = max(peak, V * vs + 12 * F + surface(F) + MESH_CHECK_FACE_BYTES * F + MESH_CHECK_VERTEX_BYTES * V)
    return peak


def subdivide_mesh(mesh, target):
    """Split ``mesh`` 1 -> 4 until it has at least ``target`` triangles; return a new :class:`Mesh`.

    A mesh that already has ``target`` triangles or more is returned unchanged.  Raises InputError
    for a non-Mesh, a non-integer or non-positive target, or a target above
    :data:`MAX_SUBDIVIDED_TRIANGLES` (or one the int32 vertex indices cannot reach), and for a
    subdivision whose memory (:func:`subdivide_bytes`) exceeds what the process has left
    (gridrt.memory), before splitting anything.
    """
    if not isinstance(mesh, Mesh):
        raise InputError(f"subdivide needs an gridrt.scene.Mesh, got {type(mesh).__name__}")
    if isinstance(target, (bool, np.bool_)) or not isinstance(target, (Integral, np.integer)):
        raise InputError(f"subdivide target must be an integer triangle count, got {target!r}")
    if not 1 <= target <= MAX_SUBDIVIDED_TRIANGLES:
        raise InputError(f"subdivide target must be between 1 and {MAX_SUBDIVIDED_TRIANGLES:,}, got {target}")
    final = _passes(mesh.n_triangles, mesh.n_vertices, target)[-1][0]
    what = f"subdividing {mesh.name!r} ({mesh.n_triangles:,} triangles) to {final:,} triangles"
    check_fits(subdivide_bytes(mesh, target), what, "vertices, faces, surface corners and their checks",
               lambda avail: _within(mesh, avail))
    # far from the origin the split runs on the exact float64 vertices (float32 world coordinates
    # would round every new vertex); near it, as before, on float32 vertices
    v, f = (mesh.vertices64 if storage_centre(mesh.vertices64).any() else mesh.vertices), mesh.faces
    passes = 0
    surface = mesh.surface
    with allocating(what, "ask for fewer triangles"):
        while len(f) < target:
            v, f = split_once(v, f)
            surface = split_surface(surface)
            passes += 1
        if passes == 0:
            return mesh
        return Mesh(v, f, name=f"{mesh.name} (subdivided x{4 ** passes})", path=mesh.path, surface=surface)


def _within(mesh, avail):
    """The advice of a refused subdivision: the largest target within ``avail`` bytes."""
    fits = [F for F, _, _ in _passes(mesh.n_triangles, mesh.n_vertices, MAX_SUBDIVIDED_TRIANGLES)[1:]
            if F <= MAX_SUBDIVIDED_TRIANGLES and subdivide_bytes(mesh, F) <= avail]
    if not fits:
        return f"a subdivision of this mesh needs more than {human(avail)}: free memory or skip subdivide"
    return f"subdivide to at most {fits[-1]:,} triangles"
