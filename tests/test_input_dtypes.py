"""The public functions take float64, float32 and integer arrays (and lists) alike, as RayCaster does.

``build_grid``, ``cast_rays``, ``render``, ``RayCaster`` and ``Camera`` get the same integer-valued
geometry as float64, float32, int64, int32 and int16 arrays (exactly representable in each; int16
not 10^7 away), near the origin and 10^7 away from it (where float32 world coordinates would be useless and the
engine's frame centred on the scene must take over, integer inputs included).  Every variant's
hits agree with the float64 brute force (tests/reference.py) and the images with each other.
"""

import numpy as np
import pytest

import gridrt
from gridrt.scene import icosphere_mesh
from reference import compare_hits, ref_camera_rays, ref_cast

DTYPES = [np.float64, np.float32, np.int64, np.int32, np.int16]
#: a sphere of radius 1000 with integer vertices (|v| <= 1000: exact in int16 and float32 too)
MESH = icosphere_mesh(320)
VERTS = np.round(np.asarray(MESH.vertices, np.float64) * 1000.0)
FACES = np.asarray(MESH.faces)


def exact(dtype, offset):
    """Whether ``dtype`` holds the integer coordinates used here (within 4000 of ``offset``) exactly:
    int16 does not 1e7 away; float32 does, below 2**24."""
    big = offset + 4000
    if np.issubdtype(dtype, np.integer):
        return big <= np.iinfo(dtype).max
    return big <= 2.0 ** (np.finfo(dtype).nmant + 1)


def scene(dtype, offset):
    """(vertices, faces, triangles) in ``dtype``, the sphere moved by ``offset`` (x, y and z)."""
    v = (VERTS + offset).astype(dtype)
    return v, FACES, v[FACES]


def rays(dtype, offset, n=400, seed=7):
    """Integer-valued rays from outside the sphere towards points around it (some miss)."""
    g = np.random.default_rng(seed)
    o = np.round(g.uniform(-3000, 3000, (n, 3))) + offset
    aim = np.round(g.uniform(-1200, 1200, (n, 3))) + offset
    d = aim - o
    d[np.all(d == 0, axis=1)] = (1, 0, 0)
    return o.astype(dtype), d.astype(dtype)


def check(hits, tris, o, d):
    ref = ref_cast(np.asarray(tris, np.float64), np.asarray(o, np.float64), np.asarray(d, np.float64))
    diff = compare_hits(hits.t, hits.tri, ref, t_rtol=1e-5)
    assert len(diff.bad) == 0, (len(diff.bad), diff)
    assert (ref.tri >= 0).sum() > 50 and (ref.tri < 0).sum() > 50  # both kinds of ray were cast


#: (dtype, offset) pairs where the dtype holds the test's coordinates exactly (int16 does not 1e7 away)
CASES = [pytest.param(t, o, id=f"{np.dtype(t).name}-{o:g}") for o in (0.0, 1e7) for t in DTYPES if exact(t, o)]


@pytest.mark.parametrize("dtype,offset", CASES)
def test_build_grid_and_cast_rays(dtype, offset):
    v, f, tris = scene(dtype, offset)
    grid = gridrt.build_grid(tris, strategy="serial")
    assert np.abs(np.asarray(grid.origin)).max() == (0 if offset == 0 else pytest.approx(offset, rel=1e-3))
    for rdtype in (dtype, np.float64):
        o, d = rays(rdtype, offset)
        check(gridrt.cast_rays(grid, tris, o, d), tris, o, d)
    o, d = rays(np.float64, offset)
    check(gridrt.cast_rays(grid, tris.tolist(), o.tolist(), d.tolist()), tris, o, d)  # nested lists


@pytest.mark.parametrize("dtype,offset", CASES)
def test_raycaster(dtype, offset):
    v, f, tris = scene(dtype, offset)
    o, d = rays(dtype, offset)
    for faces in (f, f.astype(np.int64), f.astype(np.float64)):  # (integral float indices too)
        check(gridrt.RayCaster(v, faces).cast(o, d), tris, o, d)
    caster = gridrt.RayCaster.from_triangles(tris)
    check(caster.cast(o, d), tris, o, d)
    moved = v + np.array([1, 2, 3], dtype=dtype)
    caster.update(moved[f].reshape(-1, 3))  # the soup's own vertices, moved
    check(caster.cast(o, d), moved[f], o, d)


def _camera(kind, offset):
    eye, target, up = (2600 + offset, 1500 + offset, 3400 + offset), (offset,) * 3, (0, 1, 0)
    if kind == "tuple":
        return gridrt.Camera(eye=eye, target=target, up=up, fov=40)
    if kind == "list":
        return gridrt.Camera(eye=list(eye), target=list(target), up=list(up), fov=40)
    return gridrt.Camera(eye=np.array(eye, kind), target=np.array(target, kind), up=np.array(up, kind),
                         fov=np.array(40, kind))


@pytest.mark.parametrize("offset", [0.0, 1e7])
def test_camera_takes_any_real_dtype(offset):
    ref = _camera("tuple", offset)
    kinds = ["list", np.float64, np.int64, np.float32, np.int32] + ([np.int16] if exact(np.int16, offset) else [])
    for kind in kinds:
        cam = _camera(kind, offset)
        assert np.array_equal(cam.basis(), ref.basis()), kind
    lo, hi = VERTS.min(axis=0) + offset, VERTS.max(axis=0) + offset
    framed = gridrt.Camera.frame(lo, hi)
    for kind in [np.int64, list, np.int32, np.float32] + ([np.int16] if exact(np.int16, offset) else []):
        cam = gridrt.Camera.frame(kind(lo.astype(np.int64)) if kind is list else lo.astype(kind),
                                  kind(hi.astype(np.int64)) if kind is list else hi.astype(kind))
        assert np.array_equal(cam.basis(), framed.basis()), kind


@pytest.mark.parametrize("offset", [0.0, 1e7])
def test_render_takes_any_real_dtype(offset):
    W, H = 48, 36
    cam = _camera("tuple", offset)
    o, d = ref_camera_rays(cam.eye, cam.target, cam.up, cam.fov, W, H)
    _, _, tris64 = scene(np.float64, offset)
    ref = ref_cast(tris64, o, d)
    images = {}
    for dtype in DTYPES:
        if not exact(dtype, offset):
            continue
        _, _, tris = scene(dtype, offset)
        grid = gridrt.build_grid(tris, strategy="serial")
        for light in (None, np.array([0, 5000, 0], np.int64) + int(offset)):
            params = gridrt.RenderParams(np.int64(W), np.int32(H), shadows=light is not None, light=light)
            res = gridrt.render(grid, tris, _camera(np.int64, offset), params)
            diff = compare_hits(res.t.reshape(-1), res.tri.reshape(-1), ref, t_rtol=1e-4)
            assert len(diff.bad) == 0, (np.dtype(dtype).name, len(diff.bad))
            images.setdefault(light is None, []).append(res.image)
    assert (ref.tri >= 0).sum() > 200
    for imgs in images.values():  # every dtype renders the same picture
        for img in imgs[1:]:
            assert np.array_equal(img, imgs[0])
