"""Icosphere triangles without trimesh (importing trimesh costs a start-up that needs only a sphere).

The construction is ``trimesh.creation.icosphere``'s, step for step, so the triangles are the same
bit for bit (tests/test_scene.py compares them): the unit icosahedron in trimesh's vertex and face
order; per subdivision one midpoint per edge, each face replaced by its four children in trimesh's
order, and every vertex moved onto the sphere of the given radius.
"""

import numpy as np

_PHI = (1.0 + np.sqrt(5.0)) / 2.0
_A = 1.0 / np.sqrt(1.0 + _PHI * _PHI)  # (A, B, 0) = (1, phi, 0) / |(1, phi, 0)|
_B = _PHI * _A
_ICOSAHEDRON_VERTICES = np.array([
    (-_A, _B, 0.0), (_A, _B, 0.0), (-_A, -_B, 0.0), (_A, -_B, 0.0),
    (0.0, -_A, _B), (0.0, _A, _B), (0.0, -_A, -_B), (0.0, _A, -_B),
    (_B, 0.0, -_A), (_B, 0.0, _A), (-_B, 0.0, -_A), (-_B, 0.0, _A),
], np.float64)
_ICOSAHEDRON_FACES = np.array([
    (0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11), (1, 5, 9), (5, 11, 4), (11, 10, 2), (10, 7, 6),
    (7, 1, 8), (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8), (3, 8, 9), (4, 9, 5), (2, 4, 11), (6, 2, 10),
    (8, 6, 7), (9, 8, 1),
], np.int64)


def _subdivide(vertices, faces):
    """Each face into four (corner, edge midpoints) with one new vertex per edge, after the old."""
    edges = np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    unique, inverse = np.unique(edges, axis=0, return_inverse=True)
    mid = inverse.reshape(-1, 3) + len(vertices)  # midpoints of edges (0,1), (1,2), (2,0) of each face
    children = np.column_stack([
        faces[:, 0], mid[:, 0], mid[:, 2],
        mid[:, 0], faces[:, 1], mid[:, 1],
        mid[:, 2], mid[:, 1], faces[:, 2],
        mid[:, 0], mid[:, 1], mid[:, 2],
    ]).reshape(-1, 3)
    return np.vstack((vertices, vertices[unique].mean(axis=1))), children


def icosphere_triangles(subdivisions, radius=1.0):
    """(20 * 4**subdivisions, 3, 3) float64 triangles of an icosphere of ``radius`` centred at the
    origin (outward winding), equal to ``trimesh.creation.icosphere(subdivisions, radius)``'s."""
    radius = float(radius)
    vertices, faces = _ICOSAHEDRON_VERTICES, _ICOSAHEDRON_FACES
    for _ in range(max(int(subdivisions), 0)):
        vertices, faces = _subdivide(vertices, faces)
        vertices = _onto_sphere(vertices, radius)
    if int(subdivisions) <= 0:
        vertices = _onto_sphere(vertices, radius)
    return np.ascontiguousarray(vertices[faces])


def _onto_sphere(vertices, radius):
    norm = np.sqrt(np.dot(vertices ** 2, [1, 1, 1]))
    return vertices + vertices / norm.reshape(-1, 1) * (radius - norm).reshape(-1, 1)
