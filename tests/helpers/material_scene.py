"""The material tests' scene: a textured floor, a blocker and a fan of random triangles with vertex
colours and normals under three lights (a point light, one with falloff, a directional one), its
reference looks for tests/reference.py ref_material and the engine's, and the comparison of an
image with the reference's."""

import numpy as np

import reference as R
from gridrt.camera import Camera
from gridrt.scene.surface import Surface, Texture

W, H = 64, 48


def _quad(x0, x1, z0, z1, y):
    a, b, c, d = (x0, y, z0), (x1, y, z0), (x1, y, z1), (x0, y, z1)
    return [[a, b, c], [a, c, d]]


def scene(rng):
    """A floor of three textured quads (repeat, clamp, mirror; uv beyond [0, 1]), a blocker
    casting a shadow on it, and a fan of random triangles with vertex colours and normals."""
    tris = []
    tris += _quad(-3, -1, -2, 2, 0.0) + _quad(-1, 1, -2, 2, 0.0) + _quad(1, 3, -2, 2, 0.0)
    tris += [[(-0.5, 1.0, -0.5), (0.5, 1.0, -0.5), (0.0, 1.0, 0.6)]]  # blocker
    n_rand = 12
    c = rng.uniform([-2.5, 0.4, -1.5], [2.5, 1.6, 1.5], (n_rand, 1, 3))
    tris += list(c + rng.normal(0, 0.35, (n_rand, 3, 3)))
    tris = np.asarray(tris, np.float32)
    F = len(tris)
    uv = np.zeros((F, 3, 2), np.float32)
    quad_uv = np.array([[[-1.3, -0.7], [2.7, -0.7], [2.7, 1.9]], [[-1.3, -0.7], [2.7, 1.9], [-1.3, 1.9]]])
    for q in range(3):
        uv[2 * q : 2 * q + 2] = quad_uv
    textures = [(rng.integers(0, 256, (5, 7, 3), dtype=np.uint8), (w, w)) for w in ("repeat", "clamp", "mirror")]
    material = np.array([0, 0, 1, 1, 2, 2, 3] + [4 + (i % 2) for i in range(n_rand)], np.int32)
    diffuse = np.array([[0.9, 0.8, 0.7], [0.6, 0.9, 0.8], [0.8, 0.8, 0.95], [0.5, 0.5, 0.5], [0.9, 0.3, 0.2],
                        [0.2, 0.5, 0.9]], np.float32)
    ambient = (diffuse * np.float32(0.15)).astype(np.float32)
    texture = np.array([0, 1, 2, -1, -1, -1], np.int32)
    colors = np.ones((F, 3, 3), np.float32)
    colors[7:] = rng.uniform(0.2, 1.0, (n_rand, 3, 3))
    normals = np.zeros((F, 3, 3), np.float32)  # floor and blocker: geometric
    g = np.cross(tris[7:, 1] - tris[7:, 0], tris[7:, 2] - tris[7:, 0])
    g /= np.linalg.norm(g, axis=1, keepdims=True)
    nr = g[:, None, :] + rng.normal(0, 0.3, (n_rand, 3, 3))
    normals[7:] = nr / np.linalg.norm(nr, axis=2, keepdims=True)
    lights = [("point", (0.3, 3.0, 0.2), (0.7, 0.7, 0.6), False),
              ("point", (-2.0, 2.0, 2.0), (3.0, 2.0, 2.0), True),
              ("directional", tuple(np.array([0.3, 1.0, -0.4]) / np.linalg.norm([0.3, 1.0, -0.4])), (0.3, 0.3, 0.4),
               False)]
    looks = R.RefLooks(material, diffuse, ambient, texture, textures, uv, colors, normals, lights)
    return tris, looks


def engine_surface(looks):
    texs = tuple(Texture(t, wrap, f"t{k}") for k, (t, wrap) in enumerate(looks.textures))
    return Surface(looks.material, looks.diffuse, looks.ambient, looks.texture, texs, looks.uv, looks.colors,
                   looks.normals)


def engine_lights(looks):
    rows = []
    for kind, xyz, rgb, falloff in looks.lights:
        rows.append([0.0 if kind == "point" else 1.0, *xyz, *rgb, 1.0 if falloff else 0.0])
    return np.array(rows)


CAM = Camera(eye=(0.5, 4.5, 5.5), target=(0.0, 0.3, 0.0), fov=50.0)


def _diag(tris):
    p = tris.reshape(-1, 3).astype(np.float64)
    return float(np.linalg.norm(p.max(0) - p.min(0)))


def compare(got, ref, shadows):
    """Pixels where both hit the same triangle (away from edges) agree within one level; with shadows a
    few pixels on shadow boundaries (a shadow ray grazing an edge) may differ."""
    same = (got.tri == ref.tri)
    assert same.mean() > 0.99
    edge = ref.hits.edge.reshape(ref.tri.shape)
    inside = same & ((ref.tri < 0) | (edge > 1e-4))
    diff = np.abs(got.image[..., :3].astype(int) - ref.image[..., :3].astype(int)).max(axis=2)
    bad = inside & (diff > 1)
    allowed = 0.004 * inside.sum() if shadows else 0
    assert bad.sum() <= allowed, (bad.sum(), np.argwhere(bad)[:5], diff[bad][:5])
    return inside
