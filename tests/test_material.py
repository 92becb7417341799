"""The ``material`` shading mode against the independent reference
(tests/reference.py ref_material: float64 brute-force hits and barycentrics, the shading formula
re-typed from engine/scene/surface.py): textures with every wrap mode and bilinear filtering,
vertex colours, smooth normals, lights with and without falloff, hard shadows; for DDA and CGT,
uniform and two-level grids, one grid and the static/moving split, 1 and 3 threads; far from the
origin; and the analytic normals of a sphere.
"""

import math

import numpy as np
import pytest
from numba import njit

import reference as R
from gridrt.camera import Camera
from gridrt.config import GridParams, RenderParams
from gridrt.errors import InputError
from gridrt.grid import GridBuilder
from gridrt.pipeline import FramePipeline
from gridrt.scene.animation import Animation, StaticMesh
from gridrt.scene.mesh import Mesh
from gridrt.scene.surface import Surface, Texture
from gridrt.trace.material import _near_box
from gridrt.trace.render import Looks, Renderer
from helpers.material_scene import CAM, H, W, _diag, _quad, compare, engine_lights, engine_surface, scene

@pytest.mark.parametrize("shadows", [False, True])
@pytest.mark.parametrize("traversal,grid,threads", [("dda", "uniform", 1), ("cgt", "uniform", 3),
                                                    ("cgt", "two_level", 2), ("dda", "two_level", 3)])
def test_material_matches_reference(rng, shadows, traversal, grid, threads):
    tris, looks = scene(rng)
    ref = R.ref_material(tris, CAM, W, H, looks, shadows=shadows, shadow_offset=1e-6 * _diag(tris))
    g = GridBuilder().build(tris, GridParams(grid=grid))
    params = RenderParams(width=W, height=H, shading="material", shadows=shadows, traversal=traversal, threads=threads)
    res = Renderer().render(g, tris, CAM, params, looks=Looks(tris, engine_surface(looks), looks.normals,
                                                              engine_lights(looks)))
    inside = compare(res, ref, shadows)
    # the picture is not trivial: textures, several materials and (with shadows) shadowed floor
    assert len(np.unique(res.image[inside][:, :3], axis=0)) > 200
    assert res.stats["lights"] == 3
    if shadows:
        assert 0 < res.stats["shadow_rays_per_pixel"] <= 3
    else:
        assert res.stats["shadow_rays_per_pixel"] == 0


@pytest.mark.parametrize("traversal", ["cgt", "dda"])
def test_material_shadows_with_partial_tiles_match_reference(rng, traversal):
    """Shadow rays go to the caster tile by tile of the image: an image whose sides are no
    multiple of the tile (61 x 45) still gets every pixel's shadows right, with packets (cgt) and
    single rays (dda)."""
    tris, looks = scene(rng)
    w, h = 61, 45
    ref = R.ref_material(tris, CAM, w, h, looks, shadows=True, shadow_offset=1e-6 * _diag(tris))
    g = GridBuilder().build(tris)
    params = RenderParams(width=w, height=h, shading="material", shadows=True, traversal=traversal, threads=2)
    res = Renderer().render(g, tris, CAM, params, looks=Looks(tris, engine_surface(looks), looks.normals,
                                                              engine_lights(looks)))
    inside = compare(res, ref, True)
    # the reference's shadowed floor: pixels the lights reach in the unshadowed reference only
    lit = R.ref_material(tris, CAM, w, h, looks, shadows=False)
    dark = inside & (np.abs(lit.image[..., :3].astype(int) - ref.image[..., :3].astype(int)).max(axis=2) > 8)
    assert dark.sum() > 20  # shadows are there to be got right
    assert 0 < res.stats["shadow_rays_per_pixel"] <= 3


@pytest.mark.parametrize("shadows", [False, True])
@pytest.mark.parametrize("w,h", [(7, 5), (16, 3), (40, 4)])
def test_material_rows_narrower_or_not_a_multiple_of_the_lanes(rng, w, h, shadows):
    """The material pass shades a row's pixels gridrt.trace.material.LANES (16) at a time: rows
    narrower than that, exactly that wide, and half a block over two blocks still get every hit's
    colour of the reference."""
    tris, looks = scene(rng)
    # looking down on the textured floor and the blocker's shadow, 30 degrees across: every pixel a hit
    fov = 2 * math.degrees(math.atan(math.tan(math.radians(15.0)) * h / w))
    cam = Camera(eye=(0.3, 6.0, 1.5), target=(0.2, 0.0, 0.0), fov=fov)
    ref = R.ref_material(tris, cam, w, h, looks, shadows=shadows, shadow_offset=1e-6 * _diag(tris))
    params = RenderParams(width=w, height=h, shading="material", shadows=shadows, threads=2)
    g, r = GridBuilder().build(tris), Renderer()
    r.render(g, tris, cam, params.replace(shading="lambert", shadows=False))  # (its colours in r's buffers)
    res = r.render(g, tris, cam, params, looks=Looks(tris, engine_surface(looks), looks.normals, engine_lights(looks)))
    inside = compare(res, ref, shadows)
    assert (ref.tri >= 0).all() and inside.mean() > 0.5


def test_shadow_pixel_dark_and_lit_pixel_lit():
    """A floor under a blocker and one point light: the floor point below the blocker gets only the
    ambient term, one beside it the light too (expected colours computed here)."""
    floor = _quad(-2, 2, -2, 2, 0.0)
    blocker = [[(-0.5, 1.0, -0.5), (0.5, 1.0, -0.5), (0.0, 1.0, 0.5)]]
    tris = np.asarray(floor + blocker, np.float32)
    surf = Surface(np.zeros(3, np.int32), [[0.8, 0.6, 0.4]], [[0.1, 0.1, 0.1]], [-1])
    light = np.array([[0.0, 3.0, 3.0, 0.0, 1.0, 1.0, 1.0, 0.0]])  # the blocker's shadow falls about (-1.5, 0, -0.2)
    cam = Camera(eye=(0.0, 6.0, 0.01), target=(0, 0, 0), fov=60.0)
    g = GridBuilder().build(tris)
    res = Renderer().render(g, tris, cam, RenderParams(width=101, height=101, shading="material", shadows=True),
                            looks=Looks(tris, surf, None, light))
    # pixel rays, to find the pixels whose hits are at (-1.5, 0, -0.2) (in the shadow) and (1.5, 0, 1.5)
    o, d = R.ref_camera_rays(cam.eye, cam.target, cam.up, cam.fov, 101, 101)
    t = -o[:, 1] / d[:, 1]
    p = o + t[:, None] * d
    under = np.argmin(np.linalg.norm(p - (-1.5, 0.0, -0.2), axis=1))
    beside = np.argmin(np.linalg.norm(p - (1.5, 0.0, 1.5), axis=1))
    img = res.image.reshape(-1, 4)[:, :3].astype(int)
    assert res.tri.reshape(-1)[under] in (0, 1) and res.tri.reshape(-1)[beside] in (0, 1)
    assert np.abs(img[under] - R.to_u8([0.1, 0.1, 0.1])).max() <= 1  # ambient only
    lv = np.array([3.0, 3.0, 0.0]) - p[beside]
    s = lv[1] / np.linalg.norm(lv)
    assert np.abs(img[beside] - R.to_u8(np.array([0.1, 0.1, 0.1]) + np.array([0.8, 0.6, 0.4]) * s)).max() <= 1


def test_sphere_normals_match_the_analytic_normal():
    """Smooth normals interpolated on an icosphere: the shading of each hit is that of the sphere's
    analytic normal (p / |p|) within 2 levels (the corners' normals are the unit vertices, so their
    blend points at p exactly); flat shading (no normals) is visibly off."""
    from gridrt.scene import icosphere_mesh

    mesh = icosphere_mesh(5120)
    v = mesh.vertices64 / np.linalg.norm(mesh.vertices64, axis=1, keepdims=True)
    tris = mesh.triangles()
    normals = v[mesh.faces].astype(np.float32)
    surf = Surface(np.zeros(len(tris), np.int32), [[1.0, 1.0, 1.0]], [[0.0, 0.0, 0.0]], [-1], normals=normals)
    ldir = np.array([0.4, 0.5, 0.76])
    ldir /= np.linalg.norm(ldir)
    light = np.array([[1.0, *ldir, 1.0, 1.0, 1.0, 0.0]])
    cam = Camera(eye=(0.0, 0.0, 3.5), target=(0, 0, 0), fov=40.0)
    g = GridBuilder().build(tris)
    n = 96
    o, d = R.ref_camera_rays(cam.eye, cam.target, cam.up, cam.fov, n, n)
    h = R.ref_cast(tris, o, d)
    hit = h.tri >= 0
    p = o[hit] + h.t[hit, None] * d[hit]
    cos = (p / np.linalg.norm(p, axis=1, keepdims=True)) @ ldir
    expect = R.to_u8(np.maximum(cos, 0.0))
    # away from the terminator, where a facet's geometric normal may already face away from the
    # light (a light counts only where both normals face it)
    away = cos > 0.1
    for nrm, tol in ((normals, 2), (None, None)):
        res = Renderer().render(g, tris, cam, RenderParams(width=n, height=n, shading="material"),
                                looks=Looks(tris, surf if nrm is not None else
                                            Surface(surf.material, surf.diffuse, surf.ambient, surf.texture),
                                            nrm, light))
        got = res.image.reshape(-1, 4)[hit, 0].astype(int)
        err = np.abs(got - expect.astype(int))[away]
        if tol is not None:
            assert err.max() <= tol
        else:
            assert err.max() >= 8  # facets show


class _Moving(Animation):
    """The reference scene with its random triangles sliding along x: a static floor and blocker."""

    def __init__(self, tris, surface):
        self._tris0 = tris
        self.n_triangles = len(tris)
        self.name = "moving"
        self.surface = surface
        mask = np.zeros(len(tris), bool)
        mask[:7] = True
        self.static_mask = mask
        self.duration = 1.0

    def _fill_normals(self, t, out):
        out[:] = self.surface.normals  # a translation leaves the normals as they are
        return True

    def _fill(self, t, out, origin):
        tri = self._tris0.astype(np.float64).copy()
        tri[7:, :, 0] += 0.3 * np.sin(2 * np.pi * t)
        out[:] = (tri - origin).astype(np.float32)


@pytest.mark.parametrize("split", [True, False])
def test_pipeline_material_split_and_far_origin(rng, split):
    """The frame pipeline's material mode (scene ids through the static/moving split, lights moved
    into the frame of a scene far from the origin) against the reference of the world scene."""
    tris, looks = scene(rng)
    surf = engine_surface(looks)
    lights = engine_lights(looks)
    for shift in (np.zeros(3), np.array([3.0e6, -2.0e6, 1.0e6])):
        class Scene(_Moving):
            def lights_at(self, t):
                li = lights.copy()
                li[li[:, 0] == 0.0, 1:4] += shift
                return li

        sc = Scene((tris.astype(np.float64) + shift), surf)
        cam = Camera(eye=tuple(np.array(CAM.eye) + shift), target=tuple(np.array(CAM.target) + shift), fov=CAM.fov)
        pipe = FramePipeline(sc, GridParams(), RenderParams(width=W, height=H, shadows=True), camera=cam,
                             split_static=split)
        fr = pipe.step(0.25)
        assert fr.stats["shading"] == "material"  # auto: the scene has a surface
        world = sc.triangles_at(0.25) if not shift.any() else None
        if world is not None:
            ref = R.ref_material(world, cam, W, H, looks, shadows=True, shadow_offset=1e-6 * _diag(world))
            compare(fr, ref, True)
            base = fr.image.copy()
        else:
            # far away: the same picture as at the origin (the frame keeps float32's precision)
            diff = np.abs(fr.image[..., :3].astype(int) - base[..., :3].astype(int)).max(axis=2)
            assert (diff > 1).mean() < 0.003


def test_auto_is_lambert_without_a_surface_and_material_has_a_default():
    from gridrt.scene import icosphere_mesh

    sc = StaticMesh(icosphere_mesh(320))
    fr = FramePipeline(sc, render_params=RenderParams(width=32, height=24)).step(0.0)
    assert fr.stats["shading"] == "lambert"
    fr2 = FramePipeline(sc, render_params=RenderParams(width=32, height=24, shading="material")).step(0.0)
    assert fr2.stats["shading"] == "material" and fr2.stats["lights"] == 1
    assert (fr2.tri == fr.tri).all()


def test_extreme_uv_and_degenerate_inputs(rng):
    """uv of 1e15 and -1e15 (every wrap mode) and a zero-normal corner render finite colours and
    the reference's texel (the coordinate is reduced before it is scaled to texels)."""
    tris, looks = scene(rng)
    looks.uv[:6] = looks.uv[:6] + np.float32(2.0**40)  # huge, but exactly representable shifts: same texels
    ref = R.ref_material(tris, CAM, W, H, looks)
    g = GridBuilder().build(tris)
    res = Renderer().render(g, tris, CAM, RenderParams(width=W, height=H, shading="material"),
                            looks=Looks(tris, engine_surface(looks), looks.normals, engine_lights(looks)))
    compare(res, ref, False)
    looks.uv[:6] = np.float32(1e15)
    looks.uv[6:] = np.float32(-1e30)
    res = Renderer().render(g, tris, CAM, RenderParams(width=W, height=H, shading="material"),
                            looks=Looks(tris, engine_surface(looks), looks.normals, engine_lights(looks)))
    assert (res.tri >= 0).any()


def test_bad_looks_are_refused(rng):
    tris, looks = scene(rng)
    g = GridBuilder().build(tris)
    p = RenderParams(width=8, height=8, shading="material")
    surf = engine_surface(looks)
    for bad, what in ((Looks(tris[:-1], surf), "looks.tris"), (Looks(tris, surf.subset(np.arange(3))), "looks.surface"),
                      (Looks(tris, surf, np.zeros((3, 3, 3), np.float32)), "looks.normals"),
                      (Looks(tris, surf, None, np.zeros((1, 5))), "looks.lights"),
                      (Looks(tris, surf, None, np.array([[1.0, 0, 0, 2.0, 1, 1, 1, 0]])), "unit vector"),
                      ("nope", "Looks")):
        with pytest.raises(InputError, match=what):
            Renderer().render(g, tris, CAM, p, looks=bad)
    with pytest.raises(InputError, match="texture index"):
        Surface(np.zeros(len(tris), np.int32), [[1, 1, 1]], [[0, 0, 0]], [3], uv=looks.uv)
    with pytest.raises(InputError, match="uv"):
        Surface(np.zeros(len(tris), np.int32), [[1, 1, 1]], [[0, 0, 0]], [0], (Texture(np.zeros((2, 2, 3), np.uint8)),))
    with pytest.raises(InputError, match="material index"):
        Surface(np.full(len(tris), 2, np.int32), [[1, 1, 1]], [[0, 0, 0]], [-1])
    with pytest.raises(InputError, match="NaN"):
        Surface(np.zeros(len(tris), np.int32), [[1, 1, 1]], [[0, 0, 0]], [-1], normals=np.full((len(tris), 3, 3), np.nan))
    with pytest.raises(InputError, match="surface describes"):
        Mesh(np.eye(3), [[0, 1, 2]], surface=surf)


def _write_checker_gltf(path, colours, uv):
    """A unit quad in the plane z = 0 (normal +z) with the 8x8 texture whose 2x2 blocks are the 4x4
    ``colours``, its uv per vertex, and a directional light of intensity 0.85 shining along -z."""
    import base64
    import io
    import json

    from PIL import Image

    texels = np.repeat(np.repeat(colours, 2, axis=0), 2, axis=1)  # (8, 8, 3)
    png = io.BytesIO()
    Image.fromarray(texels).save(png, format="PNG")
    pos = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], np.float32)
    idx = np.array([0, 1, 2, 0, 2, 3], np.uint16)
    blob = pos.tobytes() + uv.astype(np.float32).tobytes() + idx.tobytes()
    img_off = len(blob) + (-len(blob)) % 4
    blob = blob + b"\0" * (img_off - len(blob)) + png.getvalue()
    tree = {
        "asset": {"version": "2.0"},
        "extensionsUsed": ["KHR_lights_punctual"],
        "extensions": {"KHR_lights_punctual": {"lights": [{"type": "directional", "intensity": 0.85}]}},
        "buffers": [{"byteLength": len(blob), "uri": "data:application/octet-stream;base64,"
                     + base64.b64encode(blob).decode()}],
        "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": 48}, {"buffer": 0, "byteOffset": 48, "byteLength": 32},
                        {"buffer": 0, "byteOffset": 80, "byteLength": 12},
                        {"buffer": 0, "byteOffset": img_off, "byteLength": len(png.getvalue())}],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3", "min": [-1, -1, 0], "max": [1, 1, 0]},
            {"bufferView": 1, "componentType": 5126, "count": 4, "type": "VEC2"},
            {"bufferView": 2, "componentType": 5123, "count": 6, "type": "SCALAR"}],
        "images": [{"bufferView": 3, "mimeType": "image/png"}],
        "samplers": [{"wrapS": 33071, "wrapT": 33071}],
        "textures": [{"source": 0, "sampler": 0}],
        "materials": [{"pbrMetallicRoughness": {"baseColorFactor": [1, 1, 1, 1], "baseColorTexture": {"index": 0}}}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "TEXCOORD_0": 1}, "indices": 2, "material": 0}]}],
        "nodes": [{"mesh": 0}, {"extensions": {"KHR_lights_punctual": {"light": 0}}}],
        "scenes": [{"nodes": [0, 1]}],
        "scene": 0,
    }
    path.write_text(json.dumps(tree))
    return texels


@pytest.mark.parametrize("traversal", ["cgt", "dda"])
def test_gltf_checkerboard_texels(tmp_path, rng, traversal):
    """A glTF written here: every pixel whose hit (float64 brute force, its barycentrics) lands inside
    a checker square, away from the square's border by more than the bilinear footprint, has that
    square's colour; the light (0.85, along the normal) plus the ambient 0.15 give the texel itself."""
    from gridrt.scene import make_scene

    colours = rng.integers(0, 256, (4, 4, 3), dtype=np.uint8)
    uv = np.array([[0.0, 1.0], [1.0, 1.0], [1.0, 0.0], [0.0, 0.0]])  # image top-left at the quad's top-left
    _write_checker_gltf(tmp_path / "checker.gltf", colours, uv)
    sc = make_scene(tmp_path / "checker.gltf")
    assert sc.surface is not None and sc.surface.textured and len(sc.lights_at(0.0)) == 1
    cam = Camera(eye=(0.3, -0.2, 3.0), target=(0.0, 0.0, 0.0), fov=50.0)
    n = 80
    fr = FramePipeline(sc, render_params=RenderParams(width=n, height=n, traversal=traversal), camera=cam).step(0.0)
    assert fr.stats["shading"] == "material"
    o, d = R.ref_camera_rays(cam.eye, cam.target, cam.up, cam.fov, n, n)
    tris = sc.triangles_at(0.0).copy()
    h = R.ref_cast(tris, o, d)
    hit = np.flatnonzero(h.tri >= 0)
    w = np.stack([1 - h.u[hit] - h.v[hit], h.u[hit], h.v[hit]], axis=1)
    # the scene's triangle f is the file's (one primitive, in order); match by position to be sure
    corner_uv = np.empty((2, 3, 2))
    pos = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], np.float64)
    for f in range(2):
        for j in range(3):
            k = int(np.argmin(np.linalg.norm(pos - tris[f, j], axis=1)))
            corner_uv[f, j] = uv[k]
    uvh = np.einsum("nk,nkc->nc", w, corner_uv[h.tri[hit]])
    tx, ty = uvh[:, 0] * 8, uvh[:, 1] * 8  # texel coordinates; a square is 2 texels
    fx, fy = np.mod(tx, 2.0), np.mod(ty, 2.0)
    inside = (fx > 0.55) & (fx < 1.45) & (fy > 0.55) & (fy < 1.45)
    assert inside.sum() > 300
    sq = colours[(ty // 2).astype(int)[inside].clip(0, 3), (tx // 2).astype(int)[inside].clip(0, 3)]
    got = fr.image.reshape(-1, 4)[hit[inside], :3].astype(int)
    assert np.abs(got - sq.astype(int)).max() <= 1
    assert len(np.unique(got, axis=0)) == 16  # every square seen


def test_auto_shades_a_file_with_normals_only_with_its_normals(tmp_path):
    """An OBJ whose only looks are its normals renders with them by default (auto = material: its
    smooth normals under the default material, whose colour is lambert's), not faceted; the same
    file with a material of its own renders in the material mode too."""
    from gridrt.scene import make_scene
    from gridrt.scene.surface import AMBIENT_FRACTION, DEFAULT_DIFFUSE

    assert DEFAULT_DIFFUSE == R.ALBEDO and AMBIENT_FRACTION == R.AMBIENT
    body = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0.2\nvn 0 0 1\nvn 0.1 0 1\nvn 0 0.1 1\nvn 0.1 0.1 1\n"
    (tmp_path / "n.obj").write_text(body + "f 1//1 2//2 3//3\nf 2//2 4//4 3//3\n")
    (tmp_path / "m.mtl").write_text("newmtl red\nKd 0.9 0.1 0.1\n")
    (tmp_path / "m.obj").write_text("mtllib m.mtl\n" + body + "usemtl red\nf 1//1 2//2 3//3\nf 2//2 4//4 3//3\n")
    rp = RenderParams(width=24, height=24)
    plain, red = make_scene(tmp_path / "n.obj"), make_scene(tmp_path / "m.obj")
    assert plain.surface is not None and plain.surface.normals is not None and not plain.surface.has_materials
    assert red.surface.has_materials
    auto = FramePipeline(plain, render_params=rp).step(0.0)
    assert auto.stats["shading"] == "material"
    smooth = FramePipeline(plain, render_params=rp.replace(shading="material")).step(0.0)
    flat = FramePipeline(plain, render_params=rp.replace(shading="lambert")).step(0.0)
    hit = auto.tri >= 0
    assert hit.sum() > 50 and np.array_equal(auto.image, smooth.image)
    # the vertex normals lean away from the faces' own: the faceted image differs from the smooth one
    assert (np.abs(auto.image[hit][:, :3].astype(int) - flat.image[hit][:, :3].astype(int)) > 2).any()
    fr = FramePipeline(red, render_params=rp).step(0.0)
    assert fr.stats["shading"] == "material"
    lit = fr.image[fr.tri >= 0][:, :3].astype(int)
    assert (lit[:, 0] > 3 * lit[:, 1]).all()  # red


def _pixel_of(cam, n, point):
    """The pixel (row-major index) whose ray passes closest to ``point``, and the ray's direction."""
    o, d = R.ref_camera_rays(cam.eye, cam.target, cam.up, cam.fov, n, n)
    v = np.asarray(point, np.float64) - o
    t = (v * d).sum(axis=1)
    i = int(np.argmin(np.linalg.norm(v - t[:, None] * d, axis=1)))
    return i, d[i]


def test_bart_material_colours_at_chosen_pixels(tmp_path):
    """A BART file written here: two quads with their own fm materials under an am ambient light and
    one point light; the pixels at chosen points of each have c = amb * am + diff * light * cos,
    computed here (the scene's camera from its v block)."""
    from gridrt.scene import make_scene

    aff = """v
from 0 0 6
at 0 0 0
up 0 1 0
angle 40
hither 0.01
resolution 64 64
am 0.5 0.5 0.5
l 1 2 4 0.8 0.7 0.6
fm 0.2 0.1 0.1  0.7 0.2 0.1  0 0 0  0 0 0
p 4  -2 -1 0  0 -1 0  0 1 0  -2 1 0
fm 0.05 0.1 0.2  0.1 0.3 0.8  0 0 0  0 0 0
p 4  0 -1 0  2 -1 0  2 1 0  0 1 0
"""
    (tmp_path / "two.aff").write_text(aff)
    sc = make_scene(tmp_path / "two.aff")
    cam = sc.camera_at(0.0)
    n = 64
    fr = FramePipeline(sc, render_params=RenderParams(width=n, height=n), follow_camera=True).step(0.0)
    assert fr.stats["shading"] == "material" and fr.stats["lights"] == 1
    for point, amb, diff in (((-1.0, 0.2, 0.0), (0.2, 0.1, 0.1), (0.7, 0.2, 0.1)),
                             ((1.2, -0.4, 0.0), (0.05, 0.1, 0.2), (0.1, 0.3, 0.8))):
        i, _ = _pixel_of(cam, n, point)
        lv = np.array([1.0, 2.0, 4.0]) - np.asarray(point)
        cos = lv[2] / np.linalg.norm(lv)  # the quads' normal is +z, facing the camera
        expect = np.array(amb) * 0.5 + np.array(diff) * np.array([0.8, 0.7, 0.6]) * cos
        got = fr.image.reshape(-1, 4)[i, :3].astype(int)
        # (the pixel's hit is within half a pixel of the point: cos changes by far less than a level)
        assert np.abs(got - R.to_u8(expect).astype(int)).max() <= 1, (point, got, R.to_u8(expect))


def test_mtl_kd_at_chosen_pixels(tmp_path):
    """An OBJ quad with an MTL Kd and no lights of its own, lit by the documented default light
    (eye + (0.6 right + up) * diag, colour 1): c = Kd * (0.15 + cos) at a chosen pixel."""
    from gridrt.scene import make_scene

    (tmp_path / "k.mtl").write_text("newmtl k\nKd 0.2 0.6 0.4\n")
    (tmp_path / "k.obj").write_text("mtllib k.mtl\nv -1 -1 0\nv 1 -1 0\nv 1 1 0\nv -1 1 0\nusemtl k\nf 1 2 3 4\n")
    sc = make_scene(tmp_path / "k.obj")
    cam = Camera(eye=(0.2, 0.1, 4.0), target=(0.0, 0.0, 0.0), fov=45.0)
    n = 48
    fr = FramePipeline(sc, render_params=RenderParams(width=n, height=n), camera=cam).step(0.0)
    assert fr.stats["shading"] == "material"
    eye = np.array(cam.eye)
    fwd = -eye / np.linalg.norm(eye)
    right = np.cross(fwd, (0.0, 1.0, 0.0))
    right /= np.linalg.norm(right)
    up = np.cross(right, fwd)
    diag = np.linalg.norm([2.0, 2.0, 0.0])
    light = eye + (0.6 * right + up) * diag
    for point in ((0.3, -0.5, 0.0), (-0.6, 0.4, 0.0)):
        i, _ = _pixel_of(cam, n, point)
        lv = light - np.asarray(point)
        cos = lv[2] / np.linalg.norm(lv)
        expect = np.array([0.2, 0.6, 0.4]) * (0.15 + cos)
        got = fr.image.reshape(-1, 4)[i, :3].astype(int)
        assert np.abs(got - R.to_u8(expect).astype(int)).max() <= 1, (point, got, R.to_u8(expect))


def _segment_meets_box(o, d, lo, hi):
    """Exact (rational arithmetic) test of whether the segment o + t d, 0 <= t <= 1, meets the
    closed box lo..hi."""
    from fractions import Fraction as Q

    t0, t1 = Q(0), Q(1)
    for a in range(3):
        oa, da, la, ha = Q(float(o[a])), Q(float(d[a])), Q(float(lo[a])), Q(float(hi[a]))
        if da == 0:
            if oa < la or oa > ha:
                return False
            continue
        ta, tb = (la - oa) / da, (ha - oa) / da
        if ta > tb:
            ta, tb = tb, ta
        t0, t1 = max(t0, ta), min(t1, tb)
    return t0 <= t1


@njit
def _near_box_marks(box, o, d, out):
    """out[i] = gridrt.trace.material._near_box's verdict on segment i (o, d (N, 3)) and box."""
    for i in range(o.shape[0]):
        out[i] = _near_box(box, (o[i, 0], o[i, 1], o[i, 2]), (d[i, 0], d[i, 1], d[i, 2]))


def test_near_box_keeps_every_segment_that_meets_the_box(rng):
    """The shadow pass traces a segment through a grid only where _near_box says it may meet the
    grid's box (grown by near_boxes): it does for every segment that meets the box (exact rational
    reference), among them segments that end on a face, an edge or a corner, run along a face,
    lie inside it, or graze it from just outside, and for none that passes it at more than the
    margin; an origin a million diagonals away is kept."""
    from gridrt.trace.material import near_boxes

    class Grid:  # (near_boxes reads a grid's lo and hi)
        lo, hi = np.array([-1.0, -2.0, 0.5]), np.array([2.0, 1.0, 3.0])

    lo, hi = Grid.lo, Grid.hi
    diag = float(np.linalg.norm(hi - lo))
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    o, d = [], []
    for _ in range(3000):  # random segments around the box, and inside it
        a, b = rng.uniform(-6, 6, 3), rng.uniform(-6, 6, 3)
        o.append(a)
        d.append(b - a)
        a, b = rng.uniform(lo, hi), rng.uniform(lo, hi)
        o.append(a)
        d.append(b - a)
    for c in corners:  # segments that end on a corner
        for _ in range(10):
            a = c + rng.normal(size=3) * 3
            o.append(a)
            d.append(c - a)
    for _ in range(300):
        p = rng.uniform(lo, hi)
        axis = rng.integers(3)
        p[axis] = lo[axis] if rng.random() < 0.5 else hi[axis]  # a point on a face
        a = p + rng.normal(size=3) * 2
        o.append(a)
        d.append(p - a)
        q = p.copy()  # along the face: a zero step in its normal's direction
        q[(axis + 1) % 3] += 5.0
        o.append(p.copy())
        d.append(q - p)
        g = p + 1e-9 * diag * np.sign(p - 0.5 * (lo + hi))  # just outside the face, grazing it
        o.append(g - 3 * (q - p))
        d.append(6 * (q - p))
    o.append(np.array([1e7 * diag, 0.0, 0.0]))  # far away, heading away: kept
    d.append(np.array([1.0, 0.0, 0.0]))
    o, d = np.array(o), np.array(d)
    got = np.zeros(len(o), np.bool_)
    _near_box_marks(near_boxes([Grid])[0], o, d, got)
    grow = 2e-6 * diag
    meets = np.array([_segment_meets_box(o[i], d[i], lo, hi) for i in range(len(o))])
    near = np.array([_segment_meets_box(o[i], d[i], lo - grow, hi + grow) for i in range(len(o))])
    assert got[meets].all(), np.flatnonzero(meets & ~got)[:5]
    assert not got[:-1][~near[:-1]].any()  # the others are not kept (all but the far origin)
    assert got[-1]
    assert 0 < meets.sum() < len(o) - 100  # both kinds are there


@pytest.mark.parametrize("light_y, beyond", [(3.0, 0.0), (0.9, 0.0), (0.9, 4e-6), (0.9, -4e-6)])
def test_light_segments_mark_the_grids_each_segment_may_meet(rng, light_y, beyond):
    """With several grids' boxes, bit g of each segment's mark is _near_box's verdict for grid
    g's box on that segment (a large box most segments meet, a small one few do): with the light
    above the large box, and inside it, where light_segments marks every segment without testing
    each (_holds_light), also where some hits lie just beyond the grown box (``beyond``: a few
    hits moved past its top or bottom face by that much more than its margin, the light above
    them past the top one)."""
    from gridrt.trace.material import _holds_light, light_segments, near_boxes
    from gridrt.trace.records import HitPoints, ShadowRays, ShadowSegments

    class Grid:
        def __init__(self, lo, hi):
            self.lo, self.hi = np.array(lo), np.array(hi)

    n = 20000
    pos = rng.uniform(-1, 1, (n, 3))
    boxes = near_boxes([Grid([-1, -1, -1], [1, 1, 1]), Grid([0.0, 0.5, 0.0], [0.3, 0.7, 0.4])])
    lights = np.array([[0.0, 0.1, light_y, 0.2, 1.0, 1.0, 1.0, 0.0]])
    pos[pos[:, 1] > light_y - 0.05, 1] = light_y - 0.05  # (every hit faces the light above it)
    if beyond:
        edge = boxes[0, 4] if beyond > 0 else boxes[0, 1]
        pos[:5, 1] = edge + beyond  # (the normal is (0, 1, 0): these hits' ends lie past the face)
    if beyond > 0:
        lights[0, 2] = boxes[0, 4] + 2 * beyond  # (above the hits past the top face: their segments miss it)
    ng = np.tile([0.0, 1.0, 0.0], (n, 1))
    hp = HitPoints(pos, ng, ng.astype(np.float32), np.zeros((n, 3), np.float32), np.zeros((n, 3), np.float32))
    rays = ShadowRays(np.zeros(n, np.uint8), np.zeros(n))
    segs = ShadowSegments(np.zeros(n, np.int64), np.zeros((n, 3)), np.zeros((n, 3)), np.zeros(n, np.uint8), np.zeros(n))
    m = light_segments(lights, 0, hp, 1e-6, 5.0, np.arange(n, dtype=np.int64), rays, segs, boxes)
    assert m == n  # every hit faces the light above
    for k in range(2):
        want = np.zeros(m, np.bool_)
        _near_box_marks(boxes[k], segs.o[:m], segs.d[:m], want)
        assert (((segs.grids[:m] >> k) & 1) == want).all()
    assert ((segs.grids[:m] & 1) == 1).mean() > 0.9 and 0 < ((segs.grids[:m] & 2) == 2).mean() < 0.6
    assert _holds_light.py_func(boxes[0], tuple(lights[0, 1:4])) == (light_y < 1.0 and beyond <= 0)
    if beyond > 0:
        assert not ((segs.grids[:m] & 1) == 1).all()  # the segments above the face miss the box


def test_drawn_segments_mark_the_grids_each_segment_may_meet(rng):
    """drawn_segments (every light of each pixel, and 2 drawn a pixel) marks each segment as
    _near_box does, grid by grid: for point lights inside the large box (marked without testing
    each segment), above it, and a directional light."""
    from gridrt.trace.material import drawn_segments, near_boxes
    from gridrt.trace.records import HitPoints, make_draws
    from gridrt.trace.render import segment_buffers

    class Grid:
        def __init__(self, lo, hi):
            self.lo, self.hi = np.array(lo), np.array(hi)

    n = 6000
    pos = rng.uniform(-1, 1, (n, 3))
    pos[:, 1] = np.minimum(pos[:, 1], 0.4)
    ng = np.tile([0.0, 1.0, 0.0], (n, 1))
    hp = HitPoints(pos, ng, ng.astype(np.float32), np.ones((n, 3), np.float32), np.zeros((n, 3), np.float32))
    lights = np.array([[0.0, 0.1, 0.9, 0.2, 1.0, 1.0, 1.0, 0.0], [0.0, -0.3, 3.0, 0.4, 1.0, 1.0, 1.0, 0.0],
                       [1.0, 0.0, 1.0, 0.0, 1.0, 1.0, 1.0, 0.0], [0.0, 0.15, 0.6, 0.2, 1.0, 1.0, 1.0, 0.0]])
    boxes = near_boxes([Grid([-1, -1, -1], [1, 1, 1]), Grid([0.0, 0.5, 0.0], [0.3, 0.7, 0.4])])
    for k in (0, 2):
        K = len(lights) if k == 0 else k
        draws = make_draws(k, 0.25, np.empty((n, K), np.int32), np.empty((n, K)))
        segs = segment_buffers(n * K)
        start = drawn_segments(lights, hp, 100, draws, 1e-6, 5.0, np.arange(n, dtype=np.int64), segs, boxes)
        m = int(start[-1])
        assert m >= n and all(start[li + 1] > start[li] for li in range(len(lights)))
        for g in range(2):
            want = np.zeros(m, np.bool_)
            _near_box_marks(boxes[g], segs.o[:m], segs.d[:m], want)
            assert (((segs.grids[:m] >> g) & 1) == want).all()
        assert 0 < ((segs.grids[:m] & 2) == 2).mean() < 0.6


@pytest.mark.parametrize("n", [1, 16384, 50_001])
def test_light_segments_against_numpy(rng, n):
    """light_segments over a random image of hits (some misses, normals either way, a point light
    and a directional one): the lit pixels in the order's order (over several of its parallel
    chunks and a partial last one), each weight as light_weight gives it (per pixel and per
    segment), and each segment from the light's end back to the offset hit point, against NumPy."""
    from gridrt.trace.material import light_segments, light_weight
    from gridrt.trace.records import HitPoints, ShadowRays, ShadowSegments

    pos = rng.uniform(-1, 1, (n, 3))
    ng = rng.normal(size=(n, 3))
    ng /= np.linalg.norm(ng, axis=1)[:, None]
    ns = (ng + 0.3 * rng.normal(size=(n, 3))).astype(np.float32)
    acc = np.where(rng.random((n, 1)) < 0.2, -1.0, 0.5) * np.ones((1, 3))
    hp = HitPoints(pos, ng, ns, np.zeros((n, 3), np.float32), acc.astype(np.float32))
    # a point light with falloff, and a directional one (unit vector towards it)
    lights = np.array([[0.0, 0.3, 2.0, -0.5, 1.0, 1.0, 1.0, 1.0], [1.0, 0.0, 0.6, 0.8, 0.5, 0.5, 0.5, 0.0]])
    order = rng.permutation(n).astype(np.int64)
    off, far = 1e-5, 7.0
    for li in range(2):
        rays = ShadowRays(np.full(n, 7, np.uint8), np.full(n, np.nan))
        segs = ShadowSegments(np.full(n, -1, np.int64), np.full((n, 3), np.nan), np.full((n, 3), np.nan),
                              np.zeros(n, np.uint8), np.full(n, np.nan))
        m = light_segments(lights, li, hp, off, far, order, rays, segs, np.empty((0, 7)))
        w = np.array([light_weight.py_func(lights, li, tuple(pos[i]), tuple(ng[i]), tuple(ns[i].astype(np.float64)))[0]
                      if acc[i, 0] >= 0 else 0.0 for i in range(n)])
        lit = w > 0
        assert (rays.need == lit).all() and (rays.weight[lit] == w[lit]).all()
        want = order[lit[order]]
        assert m == len(want) and (segs.rows[:m] == want).all() and (segs.rows[m:] == -1).all()
        start = pos[want] + ng[want] * off
        to_light = lights[li, 1:4] * far if li == 1 else lights[li, 1:4] - start
        assert (segs.o[:m] == start + to_light).all() and (segs.d[:m] == -to_light).all()
        assert (segs.grids[:m] == 255).all()  # no boxes: every grid traces every segment
        assert (segs.weight[:m] == w[want]).all()
        assert n < 100 or 0 < m < n  # lit and unlit hits both


def test_renderer_keeps_shadow_buffers_without_leaking_between_frames(rng):
    """A Renderer keeps the material pass's shadow buffers from frame to frame: a frame rendered
    after others (another camera, another size, a frame without shadows in between) is the image
    a fresh Renderer makes of it, and matches the reference."""
    tris, looks = scene(rng)
    g = GridBuilder().build(tris, GridParams())
    lk = Looks(tris, engine_surface(looks), looks.normals, engine_lights(looks))
    side = Camera(eye=(2.5, 1.5, 3.0), target=CAM.target, fov=CAM.fov)

    def params(w, h, shadows=True):
        return RenderParams(width=w, height=h, shading="material", shadows=shadows, threads=2)

    r = Renderer()
    r.render(g, tris, side, params(W, H), looks=lk)
    r.render(g, tris, CAM, params(W + 7, H - 5), looks=lk)
    r.render(g, tris, side, params(W, H, shadows=False), looks=lk)
    got = r.render(g, tris, CAM, params(W, H), looks=lk).image.copy()
    fresh = Renderer().render(g, tris, CAM, params(W, H), looks=lk)
    assert np.array_equal(got, fresh.image)
    ref = R.ref_material(tris, CAM, W, H, looks, shadows=True, shadow_offset=1e-6 * _diag(tris))
    compare(fresh, ref, True)
