"""Looks of loaded meshes (``Mesh.surface`` / ``Animation.surface``): OBJ + MTL materials, textures,
uv and normals; PLY vertex colours and normals; MD2 skins, texture coordinates and the Quake II
normal table; and how subdivision, deformations and frame folders carry them.

References are independent of the code under test: the files are written here by hand (OBJ/MTL
text, PNG bytes made with zlib and struct, binary PLY and MD2 made with struct), the real MD2 is
decoded here with struct and its skin read with Pillow, the normal table is checked against
published entries and against a frequency-4 geodesic icosahedron built here, and deformed normals
against finite differences of the deformed positions.
"""

import shutil
import struct
import warnings
import zlib

import numpy as np
import pytest

import gridrt  # noqa: F401  (sets numba's thread count before numba loads)
from gridrt.errors import SceneFileError
from gridrt.scene import Deform, Md2Model, load_mesh, make_scene, subdivide_mesh
from gridrt.scene.frames import load_frame_folder
from gridrt.scene.md2 import ANORMS, find_skin
from gridrt.scene.mesh import AMBIENT_FRACTION, DEFAULT_DIFFUSE, Mesh
from gridrt.scene.surface import TextureWarning

from conftest import ASSETS, data_path

GREY = (0.85, 0.78, 0.66)


def png_bytes(pixels):
    """A PNG file of (H, W, 3) uint8 ``pixels``: 8-bit RGB, no interlace, filter 0 on every row."""
    px = np.asarray(pixels, np.uint8)
    h, w, _ = px.shape

    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    raw = b"".join(b"\x00" + px[y].tobytes() for y in range(h))
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0))
            + chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b""))


TEXELS = np.array([[[255, 0, 0], [0, 255, 0], [0, 0, 255]],
                   [[255, 255, 0], [0, 255, 255], [255, 0, 255]]], np.uint8)  # 2 rows, 3 columns

# a square (quad, triangulated), a triangle before any usemtl, a textured triangle and a pentagon
OBJ_V = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (2, 0, 0), (3, 0, 0), (3, 1, 0), (2.5, 1.5, 0), (2, 1, 0)]
OBJ_VT = [(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0), (0.25, 0.75)]
OBJ_VN = [(0.0, 0.0, 2.0), (0.0, 3.0, 4.0)]
OBJ_TEXT = """# hand-written test file
mtllib looks.mtl
{v}
{vt}
{vn}
f 1 2 9
usemtl red
f 1/1/1 2/2/1 3/3/2 4/4/2
usemtl tex
f 2/5 5/2 3/3
usemtl red
f 5//1 6//2 7//1 8//2 9//1
""".format(v="\n".join("v %r %r %r" % p for p in OBJ_V), vt="\n".join("vt %r %r" % t for t in OBJ_VT),
           vn="\n".join("vn %r %r %r" % n for n in OBJ_VN))
MTL_TEXT = """# two materials
newmtl red
Ka 1 1 1
Kd 0.9 0.1 0.2
newmtl tex
Kd 0.5 0.25 1
map_Kd -s 1 1 1 tex.png
"""
#: per polygon of OBJ_TEXT: (material diffuse, [(v, vt, vn) 1-based per corner, 0 = none])
OBJ_POLYS = [
    (GREY, [(1, 0, 0), (2, 0, 0), (9, 0, 0)]),
    ((0.9, 0.1, 0.2), [(1, 1, 1), (2, 2, 1), (3, 3, 2), (4, 4, 2)]),
    ((0.5, 0.25, 1.0), [(2, 5, 0), (5, 2, 0), (3, 3, 0)]),
    ((0.9, 0.1, 0.2), [(5, 0, 1), (6, 0, 2), (7, 0, 1), (8, 0, 2), (9, 0, 1)]),
]


def write_obj_scene(folder, obj=OBJ_TEXT, mtl=MTL_TEXT, png=True):
    p = folder / "looks.obj"
    p.write_text(obj)
    if mtl is not None:
        (folder / "looks.mtl").write_text(mtl)
    if png:
        (folder / "tex.png").write_bytes(png_bytes(TEXELS))
    return p


def polygon_of(tri, polys, verts):
    """Index of the polygon whose corner positions hold the triangle's three corners (the
    triangulation order is not assumed); each triangle of the test files lies in one polygon."""
    hits = [i for i, (_, corners) in enumerate(polys)
            if all(any(np.array_equal(c, verts[v - 1]) for v, _, _ in corners) for c in tri)]
    assert len(hits) >= 1, tri
    return hits


def corner_of(pos, corners, verts):
    return next(k for k in corners if np.array_equal(verts[k[0] - 1], pos))


def test_default_material_is_the_lambert_albedo():
    from gridrt.trace.shade import ALBEDO

    assert tuple(DEFAULT_DIFFUSE) == tuple(ALBEDO) == GREY and AMBIENT_FRACTION == 0.15


def test_obj_materials_uv_normals_and_texture(tmp_path):
    p = write_obj_scene(tmp_path)
    m = load_mesh(p)
    s = m.surface
    verts = np.array(OBJ_V, np.float64)
    assert m.n_triangles == 1 + 2 + 1 + 3 == s.n_triangles
    tris = m.triangles().astype(np.float64)
    # the triangles are the polygons' fans in file order (the same faces as the Surface's rows)
    owner = [0, 1, 1, 2, 3, 3, 3]
    for f, tri in enumerate(tris):
        assert owner[f] in polygon_of(tri, OBJ_POLYS, verts)
    diffuse = s.diffuse[s.material]
    ambient = s.ambient[s.material]
    for f in range(m.n_triangles):
        want, corners = OBJ_POLYS[owner[f]]
        np.testing.assert_allclose(diffuse[f], want, rtol=1e-6)
        np.testing.assert_allclose(ambient[f], 0.15 * np.array(want), rtol=1e-6)  # Ka is ignored
        for j in range(3):
            v, vt, vn = corner_of(tris[f, j], corners, verts)
            if vt:
                u, w = OBJ_VT[vt - 1]
                np.testing.assert_allclose(s.uv[f, j], (u, 1.0 - w), atol=1e-7)  # OBJ's v goes up: 1 - v
            else:
                np.testing.assert_array_equal(s.uv[f, j], 0.0)
            if vn:
                n = np.array(OBJ_VN[vn - 1], np.float64)
                np.testing.assert_allclose(s.normals[f, j], n / np.linalg.norm(n), atol=1e-7)
            else:
                np.testing.assert_array_equal(s.normals[f, j], 0.0)  # the geometric normal
    # only the 'tex' material has the texture: the PNG's texels, as written
    textured = s.texture[s.material] >= 0
    np.testing.assert_array_equal(textured, [f == 3 for f in range(7)])
    assert len(s.textures) == 1
    np.testing.assert_array_equal(s.textures[0].texels, TEXELS)
    assert s.colors is None


def test_obj_clamped_texture_and_shared_images(tmp_path):
    mtl = MTL_TEXT.replace("map_Kd -s 1 1 1 tex.png", "map_Kd -clamp on -o 0.5 tex.png")
    mtl += "newmtl tex2\nmap_Kd tex.png\n"
    obj = OBJ_TEXT + "usemtl tex2\nf 2/1 5/2 3/3\n"
    s = load_mesh(write_obj_scene(tmp_path, obj=obj, mtl=mtl)).surface
    rows = s.material[[3, 7]]
    assert s.textures[s.texture[rows[0]]].wrap == ("clamp", "clamp")
    assert s.textures[s.texture[rows[1]]].wrap == ("repeat", "repeat")
    # a material with map_Kd and no Kd is white times the texture
    np.testing.assert_array_equal(s.diffuse[rows[1]], [1, 1, 1])


def test_obj_without_looks_has_no_surface_and_normals_only_get_the_grey(tmp_path):
    p = tmp_path / "plain.obj"
    p.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\nf 1 2 4\n")
    assert load_mesh(p).surface is None
    assert load_mesh(ASSETS / "teapot.obj").surface is None
    q = tmp_path / "normals.obj"
    q.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 -1\nvn 0 0 1\nf 1//2 2//2 3//1\n")
    s = load_mesh(q).surface
    assert s.n_materials == 1 and not s.textured and s.uv is None and s.colors is None
    np.testing.assert_allclose(s.diffuse[0], GREY, rtol=1e-6)
    np.testing.assert_allclose(s.ambient[0], 0.15 * np.array(GREY), rtol=1e-6)
    np.testing.assert_array_equal(s.normals[0], [[0, 0, 1], [0, 0, 1], [0, 0, -1]])


def test_obj_relative_indices_vt_with_u_only_and_vertex_colours(tmp_path):
    p = tmp_path / "rel.obj"
    p.write_text("v 0 0 0 1 0 0\nv 1 0 0 0 1 0\nv 0 1 0 0 0 1\nvt 0.5\nvt 0.25 0.5\n"
                 "f -3/-2 -2/-1 -1/-1\n")
    m = load_mesh(p)
    np.testing.assert_array_equal(m.triangles()[0], [[0, 0, 0], [1, 0, 0], [0, 1, 0]])
    s = m.surface
    np.testing.assert_allclose(s.uv[0], [[0.5, 1.0], [0.25, 0.5], [0.25, 0.5]])  # 'vt 0.5': v = 0
    np.testing.assert_array_equal(s.colors[0], np.eye(3))
    assert s.n_materials == 1
    np.testing.assert_allclose(s.diffuse, [GREY], rtol=1e-6)


def test_obj_missing_library_or_texture_warns_and_loads(tmp_path):
    p = write_obj_scene(tmp_path, mtl=None)
    with pytest.warns(TextureWarning, match="looks.mtl"):
        m = load_mesh(p)
    s = m.surface
    assert m.n_triangles == 7 and not s.textured
    np.testing.assert_allclose(s.diffuse[s.material], np.tile(GREY, (7, 1)), rtol=1e-6)
    (tmp_path / "looks.mtl").write_text(MTL_TEXT)
    (tmp_path / "tex.png").unlink()
    with pytest.warns(TextureWarning, match="tex.png"):
        s = load_mesh(p).surface
    assert not s.textured
    np.testing.assert_allclose(s.diffuse[s.material[3]], (0.5, 0.25, 1.0))  # Kd without its texture
    (tmp_path / "tex.png").write_bytes(b"not an image at all")
    with pytest.warns(TextureWarning, match="tex.png"):
        assert not load_mesh(p).surface.textured


def test_obj_unknown_material_warns(tmp_path):
    p = write_obj_scene(tmp_path, obj=OBJ_TEXT + "usemtl nosuch\nf 1 2 3\n")
    with pytest.warns(TextureWarning, match="nosuch"):
        s = load_mesh(p).surface
    np.testing.assert_allclose(s.diffuse[s.material[-1]], GREY, rtol=1e-6)


@pytest.mark.parametrize("body,line,words", [
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nf 1/1 2/2 3/1\n", 5, ["texture coordinate", "2", "out of range"]),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 1\nf 1//1 2//1 3//7\n", 5, ["normal", "7", "out of range"]),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nf 1/-4 2/1 3/1\n", 5, ["texture coordinate", "-4"]),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 1\nf 1//1 2//1 3//1\n", 4, ["vn needs 3 numbers"]),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 zero\nf 1/1 2/1 3/1\n", 4, ["not a number"]),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\n\nf 1/x/1 2/1/1 3/1/1\n", 5, ["integer"]),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1/1/1/1 2 3\n", 4, ["malformed corner"]),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2\n", 4, ["at least 3 corners"]),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n", 4, ["index 0"]),
    ("v 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", 1, ["v needs 3 numbers"]),
], ids=["vt-range", "vn-range", "vt-relative", "vn-short", "vt-word", "corner-word", "corner-4", "face-2", "zero",
        "v-short"])
def test_obj_malformed_attributes(tmp_path, body, line, words):
    p = tmp_path / "bad.obj"
    p.write_text(body)
    with pytest.raises(SceneFileError) as info:
        load_mesh(p)
    err = info.value
    assert err.path == str(p) and str(err).startswith(str(p))
    assert f"line {line}:" in err.problem, err.problem
    for w in words:
        assert w in err.problem, err.problem


def test_malformed_kd_names_the_library(tmp_path):
    p = write_obj_scene(tmp_path, mtl=MTL_TEXT.replace("Kd 0.9 0.1 0.2", "Kd red"))
    with pytest.raises(SceneFileError) as info:
        load_mesh(p)
    assert info.value.path == str(tmp_path / "looks.mtl") and "line 4" in info.value.problem


def test_real_obj_geometry_is_trimesh_s_and_dragon_normals_are_its_vn(tmp_path):
    """The teapot, bunny and dragon keep the vertices and faces trimesh reads (process=False); the
    dragon's vn lines (one per v, 'f a//a ...') are its per-corner normals."""
    import trimesh

    checked = 0
    for rel in ("static/utah_teapot/teapot.obj", "static/stanford_bunny/stanford-bunny.obj",
                "static/stanford_dragon/dragon.obj"):
        try:
            p = data_path(rel)
        except pytest.skip.Exception:
            continue
        ref = trimesh.load(p, force="mesh", process=False)
        m = load_mesh(p)
        np.testing.assert_array_equal(m.vertices64, np.asarray(ref.vertices))
        np.testing.assert_array_equal(m.faces, np.asarray(ref.faces))
        checked += 1
        if rel.endswith("dragon.obj"):
            vn = np.array([ln.split()[1:4] for ln in p.read_text().splitlines() if ln.startswith("vn ")], float)
            vn /= np.linalg.norm(vn, axis=1, keepdims=True)
            np.testing.assert_allclose(m.surface.normals, vn[m.faces], atol=1e-6)
            np.testing.assert_allclose(m.surface.diffuse, [GREY], rtol=1e-6)
        else:
            assert m.surface is None
    assert checked  # the teapot ships in assets/


# ----------------------------------------------------------------------------- PLY


def write_ply(path, verts, faces, props, values, fmt="binary_little_endian"):
    """PLY with vertex properties x y z + ``props`` ((name, ply type, numpy type) ...) holding ``values``
    ((V, len(props)) numbers) and triangle faces."""
    head = ["ply", f"format {fmt} 1.0", f"element vertex {len(verts)}"]
    head += [f"property float {c}" for c in "xyz"] + [f"property {t} {n}" for n, t, _ in props]
    head += [f"element face {len(faces)}", "property list uchar int vertex_indices", "end_header"]
    text = "\n".join(head) + "\n"
    if fmt == "ascii":
        rows = [" ".join([repr(float(x)) for x in v] + [str(x) for x in vals]) for v, vals in zip(verts, values)]
        rows += ["3 " + " ".join(str(int(i)) for i in f) for f in faces]
        path.write_text(text + "\n".join(rows) + "\n")
        return path
    dt = np.dtype([("p", "<f4", 3)] + [(n, np.dtype(t).newbyteorder("<")) for n, _, t in props])
    a = np.zeros(len(verts), dt)
    a["p"] = verts
    for k, (n, _, _) in enumerate(props):
        a[n] = np.asarray(values)[:, k]
    fa = np.zeros(len(faces), [("n", "u1"), ("i", "<i4", 3)])
    fa["n"] = 3
    fa["i"] = faces
    path.write_bytes(text.encode() + a.tobytes() + fa.tobytes())
    return path


PLY_V = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], np.float32)
PLY_F = np.array([[0, 1, 2], [0, 2, 3]])


def test_ply_byte_colours_and_normals(tmp_path):
    rgb = np.array([[255, 0, 0], [0, 255, 0], [0, 0, 255], [51, 102, 204]])
    nrm = np.array([[0, 0, 2], [0, 1, 1], [1, 0, 0], [0, 0, 1]], np.float64)
    props = [(n, "uchar", "u1") for n in ("red", "green", "blue", "alpha")] + \
            [(n, "float", "f4") for n in ("nx", "ny", "nz")]
    vals = np.c_[rgb, np.full(4, 7), nrm]
    m = load_mesh(write_ply(tmp_path / "c.ply", PLY_V, PLY_F, props, vals))
    s = m.surface
    np.testing.assert_array_equal(m.faces, PLY_F)
    np.testing.assert_allclose(s.colors, (rgb / 255.0)[PLY_F], atol=1e-7)
    np.testing.assert_allclose(s.normals, (nrm / np.linalg.norm(nrm, axis=1, keepdims=True))[PLY_F], atol=1e-7)
    np.testing.assert_array_equal(s.diffuse, [[1, 1, 1]])  # the colours replace the grey
    np.testing.assert_allclose(s.ambient, [[0.15, 0.15, 0.15]])


def test_ply_float_colours_ascii_and_normals_only(tmp_path):
    rgb = np.array([[0.5, 0.25, 1.0], [0.0, 1.0, 0.0], [1.0, 1.0, 1.0], [0.2, 0.4, 0.6]])
    props = [(n, "float", "f4") for n in ("red", "green", "blue")]
    s = load_mesh(write_ply(tmp_path / "f.ply", PLY_V, PLY_F, props, rgb, fmt="ascii")).surface
    np.testing.assert_allclose(s.colors, rgb[PLY_F], atol=1e-7)
    props = [(n, "float", "f4") for n in ("nx", "ny", "nz")]
    s = load_mesh(write_ply(tmp_path / "n.ply", PLY_V, PLY_F, props, np.tile([0.0, 0.0, -1.0], (4, 1)))).surface
    assert s.colors is None
    np.testing.assert_allclose(s.diffuse, [GREY], rtol=1e-6)
    np.testing.assert_array_equal(s.normals, np.tile([0, 0, -1.0], (2, 3, 1)))
    plain = write_ply(tmp_path / "p.ply", PLY_V, PLY_F, [], np.zeros((4, 0)))
    assert load_mesh(plain).surface is None


# ----------------------------------------------------------------------------- MD2

#: entries of Quake II's anorms.h (id Software, 1997), as published
PUBLISHED_ANORMS = {
    0: (-0.525731, 0.000000, 0.850651),
    1: (-0.442863, 0.238856, 0.864188),
    5: (0.000000, 0.000000, 1.000000),
    32: (0.000000, 1.000000, 0.000000),
    52: (1.000000, 0.000000, 0.000000),
    84: (0.000000, 0.000000, -1.000000),
    104: (0.000000, -1.000000, 0.000000),
    143: (-1.000000, 0.000000, 0.000000),
    161: (-0.688191, -0.587785, -0.425325),
}


def geodesic_points(freq=4):
    """The vertices of a frequency-``freq`` geodesic icosahedron (barycentric grid on each face,
    projected on the unit sphere), icosahedron vertices (+-1, 0, +-phi) and cyclic."""
    phi = (1 + 5 ** 0.5) / 2
    ico = []
    for a in (-1, 1):
        for b in (-phi, phi):
            ico += [(a, 0, b), (0, b, a), (b, a, 0)]
    ico = np.array(ico, np.float64)
    d = np.linalg.norm(ico[:, None] - ico[None], axis=2)
    faces = [(i, j, k) for i in range(12) for j in range(i + 1, 12) for k in range(j + 1, 12)
             if np.isclose(d[i, j], 2) and np.isclose(d[j, k], 2) and np.isclose(d[i, k], 2)]
    assert len(faces) == 20
    pts = []
    for i, j, k in faces:
        for a in range(freq + 1):
            for b in range(freq + 1 - a):
                q = (a * ico[i] + b * ico[j] + (freq - a - b) * ico[k]) / freq
                pts.append(q / np.linalg.norm(q))
    return np.unique(np.round(pts, 9), axis=0)


def test_anorms_table():
    assert ANORMS.shape == (162, 3)
    for k, v in PUBLISHED_ANORMS.items():
        np.testing.assert_array_equal(ANORMS[k], v)
    np.testing.assert_allclose(np.linalg.norm(ANORMS, axis=1), 1.0, atol=2e-6)
    geo = geodesic_points()
    assert len(geo) == 162
    dist = np.linalg.norm(ANORMS[:, None] - geo[None], axis=2)
    assert dist.min(axis=1).max() < 2e-6 and len(set(dist.argmin(axis=1))) == 162  # the same 162 directions


def decode_md2_looks(path):
    """Independent struct reader: (skin size, st (N, 2), tris (F, 6), normal index (K, V), frame
    positions (K, V, 3) float64 in MD2 axes)."""
    raw = path.read_bytes()
    h = struct.unpack_from("<4s16i", raw)
    sw, sh, framesize, nskins, nv, nst, nt, _, nf, ofs_skins, ofs_st, ofs_tris, ofs_frames = h[2:15]
    st = np.array([struct.unpack_from("<2h", raw, ofs_st + 4 * i) for i in range(nst)], np.float64).reshape(-1, 2)
    tris = np.array([struct.unpack_from("<6H", raw, ofs_tris + 12 * i) for i in range(nt)])
    nid = np.zeros((nf, nv), np.int64)
    pos = np.zeros((nf, nv, 3))
    for k in range(nf):
        o = ofs_frames + k * framesize
        sc = np.array(struct.unpack_from("<3f", raw, o))
        tr = np.array(struct.unpack_from("<3f", raw, o + 12))
        for i in range(nv):
            x, y, z, n = struct.unpack_from("<4B", raw, o + 40 + 4 * i)
            nid[k, i] = n
            pos[k, i] = np.array([x, y, z]) * sc + tr
    return (sw, sh), st, tris, nid, pos


def md2_axes(v):
    v = np.asarray(v, np.float64)
    return np.stack([v[..., 0], v[..., 2], -v[..., 1]], axis=-1)  # MD2 z-up -> gridrt y-up


def unit(a):
    a = np.asarray(a, np.float64)
    return a / np.linalg.norm(a, axis=-1, keepdims=True)


@pytest.fixture
def sydney_with_skin(tmp_path):
    md2 = data_path("animated/md2_sydney/sydney.md2")
    bmp = data_path("animated/md2_sydney/sydney.bmp")
    shutil.copy(md2, tmp_path / "sydney.md2")
    shutil.copy(bmp, tmp_path / "sydney.bmp")
    return tmp_path / "sydney.md2", bmp


def test_md2_skin_uv_and_normals_of_sydney(sydney_with_skin):
    from PIL import Image

    path, bmp = sydney_with_skin
    m = Md2Model(path)
    s = m.surface
    assert m.skin == path.parent / "sydney.bmp"
    with Image.open(bmp) as im:
        texels = np.asarray(im.convert("RGB"))
    assert s.textured and len(s.textures) == 1
    np.testing.assert_array_equal(s.textures[0].texels, texels)
    np.testing.assert_array_equal(s.diffuse, [[1, 1, 1]])
    np.testing.assert_allclose(s.ambient, [[0.15, 0.15, 0.15]])
    (sw, sh), st, tris, nid, pos = decode_md2_looks(path)
    np.testing.assert_allclose(s.uv, st[tris[:, 3:]] / [sw, sh], atol=1e-7)
    faces = tris[:, :3]
    table = np.array([PUBLISHED_ANORMS.get(k, ANORMS[k]) for k in range(162)])
    for k in (0, 1, 57, m.n_frames - 1):
        want = md2_axes(unit(table[nid[k]]))[faces]
        np.testing.assert_allclose(m.normals_at(k / m.fps), want, atol=1e-6)
        # the same rotation as the positions
        np.testing.assert_allclose(m.triangles_at(k / m.fps), md2_axes(pos[k])[faces], atol=1e-4)
    np.testing.assert_allclose(s.normals, md2_axes(unit(table[nid[0]]))[faces], atol=1e-6)
    # between frames: the normalised blend; the last frame blends back into the first
    for k0, k1, w in ((3, 4, 0.25), (m.n_frames - 1, 0, 0.5)):
        a, b = md2_axes(unit(table[nid[k0]])), md2_axes(unit(table[nid[k1]]))
        want = unit((1 - w) * a + w * b)[faces]
        np.testing.assert_allclose(m.normals_at((k0 + w) / m.fps), want, atol=1e-5)
    out = np.zeros((m.n_triangles, 3, 3), np.float32)
    assert m.normals_at(0.0, out=out) is out
    # a clip starts at its own first frame
    run = Md2Model(path, clip="run")
    np.testing.assert_allclose(run.surface.normals, md2_axes(unit(table[nid[run.first_frame]]))[faces], atol=1e-6)


def test_md2_shipped_with_its_skin():
    """The shipped sydney.md2 finds the shipped sydney.bmp beside it (the header names no skin: the
    model's stem); the texels are Pillow's RGB of the file, read here."""
    from PIL import Image

    path = ASSETS / "sydney.md2"
    if not (path.exists() and (ASSETS / "sydney.bmp").exists()):
        pytest.skip("assets/sydney.md2 or its skin is not in this checkout")
    with warnings.catch_warnings():
        warnings.simplefilter("error", TextureWarning)  # the header names no skin: nothing to warn about
        m = Md2Model(path)
    s = m.surface
    assert s.textured and s.uv is not None and s.normals is not None
    with Image.open(ASSETS / "sydney.bmp") as im:
        np.testing.assert_array_equal(s.textures[0].texels, np.asarray(im.convert("RGB")))


def write_md2(path, skins=(), st=None, st_ids=None, normal_ids=None, skin_size=(8, 4)):
    """A 2-frame MD2 of 4 vertices and 2 triangles with skins, st and normal indices (struct)."""
    packed = np.array([[[0, 0, 0], [10, 0, 0], [0, 10, 0], [0, 0, 10]],
                       [[0, 0, 0], [20, 0, 0], [0, 20, 0], [0, 0, 20]]], np.uint8)
    nid = np.zeros((2, 4), np.uint8) if normal_ids is None else np.asarray(normal_ids, np.uint8)
    tris = [(0, 1, 2), (0, 2, 3)]
    st = [] if st is None else st
    st_ids = [(0, 0, 0), (0, 0, 0)] if st_ids is None else st_ids
    nv, k = 4, 2
    framesize = 40 + 4 * nv
    ofs_skins = 68
    ofs_st = ofs_skins + 64 * len(skins)
    ofs_tris = ofs_st + 4 * len(st)
    ofs_frames = ofs_tris + 12 * len(tris)
    ofs_end = ofs_frames + k * framesize
    head = struct.pack("<4s16i", b"IDP2", 8, skin_size[0], skin_size[1], framesize, len(skins), nv, len(st),
                       len(tris), 0, k, ofs_skins, ofs_st, ofs_tris, ofs_frames, ofs_end, ofs_end)
    body = b"".join(s.encode().ljust(64, b"\0") for s in skins)
    body += b"".join(struct.pack("<2h", *x) for x in st)
    body += b"".join(struct.pack("<6H", *t, *i) for t, i in zip(tris, st_ids))
    for f in range(k):
        body += struct.pack("<3f3f16s", 0.5, 0.5, 0.5, 1.0, 2.0, 3.0, f"frame{f + 1}".encode())
        rec = np.zeros((nv, 4), np.uint8)
        rec[:, :3] = packed[f]
        rec[:, 3] = nid[f]
        body += rec.tobytes()
    path.write_bytes(head + body)
    return path


ST = [(0, 0), (8, 0), (4, 4), (2, 1)]
ST_IDS = [(0, 1, 2), (0, 2, 3)]


def test_md2_skin_rules(tmp_path):
    img = png_bytes(TEXELS)
    # 1. the header's skin name: the file itself, or its stem with another image extension
    d = tmp_path / "named"
    d.mkdir()
    p = write_md2(d / "model.md2", skins=["models/monsters/tank/skin.pcx"], st=ST, st_ids=ST_IDS)
    (d / "skin.png").write_bytes(img)
    (d / "other.png").write_bytes(img)
    (d / "model.png").write_bytes(img)
    assert find_skin(p, ["models/monsters/tank/skin.pcx"]) == d / "skin.png"
    m = Md2Model(p)
    assert m.skin == d / "skin.png"
    np.testing.assert_array_equal(m.surface.textures[0].texels, TEXELS)
    np.testing.assert_allclose(m.surface.uv, np.array(ST, float)[np.array(ST_IDS)] / [8, 4])
    # 2. the model's stem
    (d / "skin.png").unlink()
    assert Md2Model(p).skin == d / "model.png"
    # 3. the folder's only image
    (d / "model.png").unlink()
    assert Md2Model(p).skin == d / "other.png"
    # none: the header names a skin that is nowhere: warned, untextured
    (d / "other.png").unlink()
    with pytest.warns(TextureWarning, match="skin.pcx"):
        m = Md2Model(p)
    assert m.skin is None and not m.surface.textured
    # two unrelated images and no name: no skin, no warning when the header names none
    e = tmp_path / "two"
    e.mkdir()
    q = write_md2(e / "thing.md2", st=ST, st_ids=ST_IDS)
    (e / "a.png").write_bytes(img)
    (e / "b.png").write_bytes(img)
    with warnings.catch_warnings():
        warnings.simplefilter("error", TextureWarning)
        assert Md2Model(q).skin is None


def test_md2_normals_of_a_written_model(tmp_path):
    nid = [[5, 32, 52, 0], [84, 104, 143, 161]]
    p = write_md2(tmp_path / "n.md2", normal_ids=nid)
    m = Md2Model(p, fps=2.0)
    faces = np.array([(0, 1, 2), (0, 2, 3)])
    for k in (0, 1):
        want = md2_axes(unit([PUBLISHED_ANORMS[i] for i in nid[k]]))[faces]
        np.testing.assert_allclose(m.normals_at(k / 2.0), want, atol=1e-6)
    assert m.surface.uv is None and not m.surface.textured  # no st block: no texture coordinates
    # an index past the table is "no normal" (zero: the geometric normal)
    q = write_md2(tmp_path / "z.md2", normal_ids=[[200, 5, 5, 5], [5, 5, 5, 5]])
    np.testing.assert_array_equal(Md2Model(q).surface.normals[0, 0], 0.0)


def test_md2_texture_coordinate_index_out_of_range(tmp_path):
    p = write_md2(tmp_path / "bad.md2", st=ST, st_ids=[(0, 1, 2), (0, 2, 9)])
    with pytest.raises(SceneFileError) as info:
        Md2Model(p)
    assert info.value.path == str(p) and "texture coordinate index 9" in info.value.problem


# ----------------------------------------------------------------------------- subdivide, deform, frames


def barycentric(p, tri):
    a, b, c = tri
    m = np.array([b - a, c - a]).T
    x, *_ = np.linalg.lstsq(m, p - a, rcond=None)
    return np.array([1 - x.sum(), x[0], x[1]])


def test_subdivide_keeps_materials_and_interpolates_corners(tmp_path):
    m = load_mesh(write_obj_scene(tmp_path))
    s = m.surface
    rng = np.random.default_rng(3)
    colors = rng.uniform(0, 1, (m.n_triangles, 3, 3)).astype(np.float32)
    from gridrt.scene.surface import Surface

    m = Mesh(m.vertices, m.faces, name="looks", surface=Surface(s.material, s.diffuse, s.ambient, s.texture, s.textures,
                                                                 s.uv, colors, s.normals))
    parent = m.triangles().astype(np.float64)
    for passes in (1, 2):
        sub = subdivide_mesh(m, 4 ** passes * m.n_triangles)
        t = sub.surface
        k = 4 ** passes  # the children of f are k f .. k f + k - 1
        assert sub.n_triangles == k * m.n_triangles == t.n_triangles
        assert t.textures == s.textures
        np.testing.assert_array_equal(t.diffuse[t.material], np.repeat(s.diffuse[s.material], k, axis=0))
        np.testing.assert_array_equal(t.texture[t.material], np.repeat(s.texture[s.material], k))
        child = sub.triangles().astype(np.float64)
        for f in range(sub.n_triangles):
            pf = f // k
            for j in range(3):
                w = barycentric(child[f, j], parent[pf])
                np.testing.assert_allclose(t.uv[f, j], w @ s.uv[pf], atol=1e-6)
                np.testing.assert_allclose(t.colors[f, j], w @ colors[pf], atol=1e-6)
                n = w @ s.normals[pf].astype(np.float64)
                if np.linalg.norm(n) == 0:
                    np.testing.assert_array_equal(t.normals[f, j], 0.0)  # zero ("geometric") stays zero
                elif passes == 1:  # the corner's blend, normalised
                    np.testing.assert_allclose(t.normals[f, j], n / np.linalg.norm(n), atol=1e-6)
                else:
                    np.testing.assert_allclose(np.linalg.norm(t.normals[f, j]), 1.0, atol=1e-6)
    assert subdivide_mesh(m, 1) is m


def sphere_with_probes(eps):
    """An icosphere with exact sphere normals, plus, for some of its vertices p (away from the
    bounding box's faces), unreferenced probe vertices p +- eps t along two tangents t."""
    from gridrt.scene import icosphere_mesh

    ico = icosphere_mesh(320)
    v = ico.vertices64
    f = ico.faces
    n = unit(v)
    picks = [i for i in range(len(v)) if np.abs(v[i]).max() < 0.85][:40]
    probes, tangents = [], []
    for i in picks:
        t1 = unit(np.cross(n[i], [0.3, 1.0, 0.2]))
        t2 = np.cross(n[i], t1)
        tangents.append((t1, t2))
        probes += [v[i] + eps * t1, v[i] - eps * t1, v[i] + eps * t2, v[i] - eps * t2]
    from gridrt.scene.surface import Surface

    surface = Surface.plain(len(f), GREY, 0.15 * np.array(GREY))
    surface = Surface(surface.material, surface.diffuse, surface.ambient, surface.texture, (),
                      None, None, n[f].astype(np.float32))
    mesh = Mesh(np.concatenate([v, probes]), f, name="probed", surface=surface)
    return mesh, picks


@pytest.mark.parametrize("kind", ["twist", "wave"])
def test_deformed_normals_are_normal_to_the_deformed_surface(kind):
    eps = 1e-3
    mesh, picks = sphere_with_probes(eps)
    d = Deform(mesh, kind, amplitude=0.4, speed=1.0)
    assert d.surface is mesh.surface
    if kind == "twist":  # at rest at t = 0
        np.testing.assert_allclose(d.normals_at(0.0), mesh.surface.normals, atol=1e-7)
    f = mesh.faces
    V = len(mesh.vertices) - 4 * len(picks)
    for t in (0.2, 0.65):
        q = d.vertices_at(t).astype(np.float64)
        normals = d.normals_at(t)
        rest_err, err = 0.0, 0.0
        for k, i in enumerate(picks):
            fi, j = np.argwhere(f == i)[0]
            n = normals[fi, j].astype(np.float64)
            n0 = mesh.surface.normals[fi, j].astype(np.float64)
            assert abs(np.linalg.norm(n) - 1) < 1e-6
            base = V + 4 * k
            for a, b in ((base, base + 1), (base + 2, base + 3)):
                chord = (q[a] - q[b]) / (2 * eps)  # the image of a unit tangent (central difference)
                err = max(err, abs(n @ chord) / np.linalg.norm(chord))
                rest_err = max(rest_err, abs(n0 @ chord) / np.linalg.norm(chord))
        assert err < 2e-3, err
        assert rest_err > 0.05  # the rest normals would be wrong: the check can tell


def test_deform_keeps_the_surface(tmp_path):
    m = load_mesh(write_obj_scene(tmp_path))
    d = Deform(m, "wave", amplitude=0.1)
    assert d.surface is m.surface
    assert np.isfinite(d.normals_at(0.3)).all()
    s = make_scene(str(tmp_path / "looks.obj"), animate="twist")
    assert s.surface is not None and s.surface.textured


def test_frame_folder_keeps_the_first_frame_s_looks_without_normals(tmp_path):
    folder = tmp_path / "frames"
    folder.mkdir()
    for k in range(3):
        text = OBJ_TEXT.replace("v 1.0 1.0 0", f"v 1.0 {1.0 + 0.1 * k!r} 0").replace("v 1 1 0", f"v 1 {1 + k} 0")
        (folder / f"f{k:03d}.obj").write_text(text)
    (folder / "looks.mtl").write_text(MTL_TEXT)
    (folder / "tex.png").write_bytes(png_bytes(TEXELS))
    first = load_mesh(folder / "f000.obj")
    scene = load_frame_folder(folder, fps=10.0)
    s = scene.surface
    assert s is not None and s.normals is None and scene.normals_at(0.05) is None
    np.testing.assert_array_equal(s.material, first.surface.material)
    np.testing.assert_array_equal(s.uv, first.surface.uv)
    np.testing.assert_array_equal(s.textures[0].texels, TEXELS)


# ----------------------------------------------------------------------------- the two OBJ readers

MUTANT_BASE = OBJ_TEXT + "# relative corners\nf -9/-5/-2 -8/-4/-1 -7/-3/-2\n  f 1 2 3\nvt 0.5\n"
MUTANT_BYTES = [" ", "/", "//", "-", "0", "1", "9", "\n", "#", "\t", "x", "v", "f", "vt", "vn", ".", "e", "inf", "1e300"]


def _same_parse(a, b):
    from gridrt.scene.obj import _ObjError

    np.testing.assert_array_equal(a.pos, b.pos)  # NaN-aware
    for name in ("vcount", "lens", "fv", "ft", "fn", "bases"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    assert a.usemtl == b.usemtl and a.mtllibs == b.mtllibs
    for name in ("tex", "nrm"):
        got = []
        for r in (a, b):
            try:
                got.append(getattr(r, name)())
            except _ObjError as e:
                got.append((e.key, e.row))
        if isinstance(got[0], tuple) or isinstance(got[1], tuple):
            assert got[0] == got[1], name
        else:
            np.testing.assert_array_equal(got[0], got[1], err_msg=name)


def test_obj_readers_agree_on_mutants():
    """The vectorised reader (the usual file) and the line-by-line one (any file) read the same
    records whenever the vectorised one takes a file (hypothesis mutants of a file with every kind
    of statement, relative indices and an indented face)."""
    from hypothesis import HealthCheck, given, settings
    from hypothesis import strategies as st

    from gridrt.scene.obj import _obj_parse_fast, _obj_parse_lines, _ObjError

    taken = []

    @settings(max_examples=150, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
    @given(data=st.data())
    def check(data):
        text = MUTANT_BASE
        for _ in range(data.draw(st.integers(0, 3), label="edits")):
            i = data.draw(st.integers(0, len(text)), label="at")
            cut = data.draw(st.integers(0, 3), label="cut")
            text = text[:i] + data.draw(st.sampled_from(MUTANT_BYTES), label="insert") + text[i + cut:]
        if data.draw(st.booleans(), label="unindent"):
            text = text.replace("  f 1 2 3", "f 1 2 3")
        fast = _obj_parse_fast(text)
        try:
            slow = _obj_parse_lines(text)
        except _ObjError:
            assert fast is None, "the vectorised reader took a file the line reader refuses"
            return
        if fast is not None:
            taken.append(1)
            _same_parse(fast, slow)

    check()
    assert len(taken) > 20  # the comparison ran on many mutants


def test_obj_mutants_load_or_fail_cleanly(tmp_path):
    """Mutants of an OBJ file with a material library and a texture load, or raise SceneFileError
    naming the OBJ or MTL file, without numpy RuntimeWarnings."""
    from hypothesis import HealthCheck, given, settings
    from hypothesis import strategies as st

    write_obj_scene(tmp_path)
    p = tmp_path / "looks.obj"

    @settings(max_examples=60, deadline=None, derandomize=True,
              suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
    @given(data=st.data())
    def check(data):
        text = MUTANT_BASE
        for _ in range(data.draw(st.integers(1, 4), label="edits")):
            i = data.draw(st.integers(0, len(text)), label="at")
            text = text[:i] + data.draw(st.sampled_from(MUTANT_BYTES), label="insert") + text[i:]
        p.write_text(text)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            try:
                m = load_mesh(p)
                assert np.isfinite(m.vertices).all()
                if m.surface is not None:
                    assert m.surface.n_triangles == m.n_triangles
            except SceneFileError as e:
                assert e.path in (str(p), str(tmp_path / "looks.mtl")) and e.problem
        bad = [str(w.message) for w in caught if issubclass(w.category, RuntimeWarning)]
        assert not bad, bad

    check()
