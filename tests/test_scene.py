"""Scene layer: mesh loading, the animation protocol, marbles and deformations.

References are independent of the code under test: files are written by hand here (OBJ, OFF,
PLY, STL, glTF), areas and node transforms are computed in float64 numpy, triangle counts of the
real meshes are those listed with the development data set, and motions are checked against their analytic
formulas.
"""

import json
import math
import os
import struct

import numpy as np
import pytest

import gridrt  # noqa: F401  (sets numba's thread count before numba loads)
from gridrt.errors import InputError, SceneFileError
from gridrt.scene import (
    ASSET_SCENES,
    BUILTIN_SCENES,
    DATA_SCENES,
    SCENE_EXTENSIONS,
    SUPPORTED_EXTENSIONS,
    Animation,
    Deform,
    Marbles,
    Mesh,
    StaticMesh,
    load_mesh,
    make_scene,
    subdivide_mesh,
)
from gridrt.scene import files as files_module
from gridrt.scene import loader as loader_module
from gridrt.scene.animation import as_static_mask

from conftest import ASSETS, available, data_path
from helpers.scene_files import (OCTA_F, OCTA_T, OCTA_V, ply_header, write_off, write_ply_ascii, write_ply_binary,
                                 write_stl_ascii, write_stl_binary)


# ----------------------------------------------------------------------------- helpers


def areas(tris):
    """Triangle areas, float64, from (F,3,3) triangles."""
    t = np.asarray(tris, dtype=np.float64)
    n = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
    return 0.5 * np.linalg.norm(n, axis=1)


def canonical(tris):
    """Triangles as a sorted (F, 9) float64 array, each rotated to start at its smallest vertex.

    Rotation keeps the winding, so two meshes compare equal only with the same orientation.
    Coordinates are rounded to 1e-6 first so float noise cannot change the order.
    """
    t = np.round(np.asarray(tris, dtype=np.float64), 6) + 0.0
    out = []
    for tri in t:
        rolls = [np.roll(tri, -k, axis=0) for k in range(3)]
        out.append(min(r.ravel().tolist() for r in rolls))
    return np.array(sorted(out))


def shoelace(xy):
    x, y = np.asarray(xy, dtype=np.float64).T
    return 0.5 * abs(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))


def need_data(rel):
    """A real file by its name in the development data set (assets/ ships some; a converted mesh will do: these
    tests load meshes); skips when absent."""
    return data_path(rel, converted=True)


def write_obj(path, v, f):
    lines = [f"v {x!r} {y!r} {z!r}" for x, y, z in v.tolist()]
    lines += ["f " + " ".join(str(i + 1) for i in face) for face in f]
    path.write_text("\n".join(lines) + "\n")


def write_gltf(path, meshes, nodes, roots, extra=None):
    """Write a glTF 2.0 file by hand (.glb binary or .gltf + .bin): meshes = [(V,3) f32, (F,3) int]."""
    blob = bytearray()
    views, accessors, gl_meshes = [], [], []

    def add(arr, target, kind, comp, count, minmax=None):
        while len(blob) % 4:
            blob.append(0)
        views.append({"buffer": 0, "byteOffset": len(blob), "byteLength": arr.nbytes, "target": target})
        blob.extend(arr.tobytes())
        acc = {"bufferView": len(views) - 1, "componentType": comp, "count": count, "type": kind}
        if minmax is not None:
            acc["min"], acc["max"] = minmax
        accessors.append(acc)
        return len(accessors) - 1

    for v, f in meshes:
        v = np.ascontiguousarray(v, dtype="<f4")
        ip = add(v, 34962, "VEC3", 5126, len(v), (v.min(0).tolist(), v.max(0).tolist()))
        ii = add(np.ascontiguousarray(f, dtype="<u4").ravel(), 34963, "SCALAR", 5125, 3 * len(f))
        gl_meshes.append({"primitives": [{"attributes": {"POSITION": ip}, "indices": ii, "mode": 4}]})
    while len(blob) % 4:
        blob.append(0)
    tree = {
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": roots}],
        "nodes": nodes,
        "meshes": gl_meshes,
        "accessors": accessors,
        "bufferViews": views,
        "buffers": [{"byteLength": len(blob)}],
    }
    tree.update(extra or {})
    if path.suffix == ".gltf":
        bin_name = path.stem + ".bin"
        (path.parent / bin_name).write_bytes(bytes(blob))
        tree["buffers"][0]["uri"] = bin_name
        path.write_text(json.dumps(tree))
        return
    js = json.dumps(tree).encode()
    js += b" " * (-len(js) % 4)
    total = 12 + 8 + len(js) + 8 + len(blob)
    path.write_bytes(
        struct.pack("<4sII", b"glTF", 2, total)
        + struct.pack("<II", len(js), 0x4E4F534A) + js
        + struct.pack("<II", len(blob), 0x004E4942) + bytes(blob)
    )


def quat_matrix(q):
    x, y, z, w = q
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def trs(t=(0, 0, 0), r=(0, 0, 0, 1), s=(1, 1, 1)):
    m = np.eye(4)
    m[:3, :3] = quat_matrix(r) @ np.diag(s)
    m[:3, 3] = t
    return m


# A quad (two triangles) as the second glTF mesh.
QUAD_V = np.array([[0, 0, 0], [2, 0, 0], [2, 0, 1], [0, 0, 1]], dtype=np.float32)
QUAD_F = np.array([[0, 2, 1], [0, 3, 2]], dtype=np.int32)
_H = math.sqrt(0.5)
GLTF_NODES = [
    {"mesh": 0, "translation": [3.0, 0.0, -1.0]},
    {"mesh": 1, "rotation": [0.0, 0.0, _H, _H], "scale": [1.0, 2.0, 0.5]},
    {"translation": [0.0, 5.0, 0.0], "scale": [2.0, 2.0, 2.0], "children": [3]},
    {"mesh": 0, "rotation": [_H, 0.0, 0.0, _H]},
]


def gltf_expected():
    """World-space triangles of GLTF_NODES, computed with numpy (column vectors, M = T R S)."""
    w0 = trs(t=GLTF_NODES[0]["translation"])
    w1 = trs(r=GLTF_NODES[1]["rotation"], s=GLTF_NODES[1]["scale"])
    w3 = trs(t=GLTF_NODES[2]["translation"], s=GLTF_NODES[2]["scale"]) @ trs(r=GLTF_NODES[3]["rotation"])
    out = []
    for m, (v, f) in ((w0, (OCTA_V, OCTA_F)), (w1, (QUAD_V, QUAD_F)), (w3, (OCTA_V, OCTA_F))):
        vh = np.c_[v.astype(np.float64), np.ones(len(v))] @ m.T
        out.append(vh[:, :3][f])
    return np.concatenate(out)


# ----------------------------------------------------------------------------- loading


def test_obj_quad_and_pentagon_are_triangulated(tmp_path):
    pent = [(2.0, 0.0), (3.0, 0.0), (3.5, 1.0), (2.5, 2.0), (1.5, 1.0)]  # convex
    lines = ["v 0 0 0", "v 1 0 0", "v 1 1 0", "v 0 1 0"] + [f"v {x} {y} 0" for x, y in pent]
    lines += ["f 1 2 3 4", "f 5 6 7 8 9"]
    p = tmp_path / "polys.obj"
    p.write_text("\n".join(lines) + "\n")
    m = load_mesh(p)
    assert m.n_triangles == 2 + 3
    assert m.vertices.dtype == np.float32 and m.faces.dtype == np.int32
    assert m.vertices.shape == (9, 3) and m.faces.shape == (5, 3)
    tris = m.triangles()
    assert areas(tris).sum() == pytest.approx(1.0 + shoelace(pent), rel=1e-12)
    assert areas(tris).min() > 0
    # every triangle keeps the polygons' counter-clockwise winding (normal +z)
    n = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
    assert (n[:, 2] > 0).all()
    assert m.name == "polys" and m.path == p


def test_off_with_quads_is_triangulated(tmp_path):
    v = np.array([[0, 0, 0], [2, 0, 0], [2, 3, 0], [0, 3, 0], [0, 0, 1]], dtype=np.float32)
    p = tmp_path / "q.off"
    write_off(p, v, [(0, 1, 2, 3), (0, 1, 4)])
    m = load_mesh(p)
    assert m.n_triangles == 3
    assert areas(m.triangles()).sum() == pytest.approx(6.0 + 1.0)


@pytest.mark.parametrize(
    "ext,writer",
    [
        (".obj", lambda p: write_obj(p, OCTA_V, OCTA_F)),
        (".off", lambda p: write_off(p, OCTA_V, OCTA_F.tolist())),
        (".ply", lambda p: write_ply_ascii(p, OCTA_V, OCTA_F)),
        (".PLY", lambda p: write_ply_binary(p, OCTA_V, OCTA_F)),
        (".stl", lambda p: write_stl_binary(p, OCTA_T)),
        (".Stl", lambda p: write_stl_ascii(p, OCTA_T)),
    ],
    ids=["obj", "off", "ply-ascii", "ply-binary", "stl-binary", "stl-ascii"],
)
def test_formats_round_trip(tmp_path, ext, writer):
    p = tmp_path / f"octa{ext}"
    writer(p)
    m = load_mesh(p)
    assert m.n_triangles == len(OCTA_F)
    np.testing.assert_array_equal(canonical(m.triangles()), canonical(OCTA_T))
    assert areas(m.triangles()).sum() == pytest.approx(areas(OCTA_T).sum(), rel=1e-12)


@pytest.mark.parametrize("ext", [".glb", ".gltf"])
def test_gltf_multi_mesh_concatenated_with_node_transforms(tmp_path, ext):
    p = tmp_path / f"scene{ext}"
    write_gltf(p, [(OCTA_V, OCTA_F), (QUAD_V, QUAD_F)], GLTF_NODES, roots=[0, 1, 2])
    m = load_mesh(p)
    expected = gltf_expected()
    assert m.n_triangles == len(expected) == 2 * 8 + 2
    np.testing.assert_allclose(canonical(m.triangles()), canonical(expected), atol=1e-5)
    assert areas(m.triangles()).sum() == pytest.approx(areas(expected).sum(), rel=1e-5)


#: real meshes and their triangle counts (the data set's README)
REAL_COUNTS = {
    "static/utah_teapot/teapot.obj": 6320,
    "static/armadillo/armadillo.off": 52000,
    "animated/cesium_man/CesiumMan.glb": 4672,
    "animated/animated_morph_sphere/AnimatedMorphSphere.gltf": 960,
    "static/lucy/Lucy100k.ply": 100000,
    "static/stanford_bunny/stanford-bunny.obj": 69451,
    "static/stanford_dragon/dragon.obj": 93600,
}
#: the data set's scans that assets/ does not ship (checked together, each one that is present)
SCANS = ["static/lucy/Lucy100k.ply", "static/stanford_bunny/stanford-bunny.obj", "static/stanford_dragon/dragon.obj"]


def check_real_mesh(rel, path):
    m = load_mesh(path)
    assert m.n_triangles == REAL_COUNTS[rel], rel
    assert m.vertices.dtype == np.float32 and m.faces.dtype == np.int32
    assert np.isfinite(m.vertices).all()
    assert m.faces.min() >= 0 and m.faces.max() < m.n_vertices
    assert areas(m.triangles()).sum() > 0


@pytest.mark.parametrize("rel", [r for r in REAL_COUNTS if r not in SCANS])
def test_real_meshes_triangle_counts(rel):
    check_real_mesh(rel, need_data(rel))


def test_data_set_scans_triangle_counts():
    for rel, path in available(*SCANS).items():
        check_real_mesh(rel, path)


def test_real_closed_meshes_have_no_boundary_edges():
    """The closed scans (data set README: the Armadillo, Lucy100k and the dragon): every undirected
    edge is shared by exactly two triangles."""
    found = available("static/armadillo/armadillo.off", "static/lucy/Lucy100k.ply", "static/stanford_dragon/dragon.obj",
                      converted=True)
    for rel, path in found.items():
        m = load_mesh(path)
        e = np.sort(m.faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1).astype(np.int64)
        _, counts = np.unique(e[:, 0] * m.n_vertices + e[:, 1], return_counts=True)
        assert (counts == 2).all(), rel


def hide_dracopy(monkeypatch):
    """Make the loaders believe DracoPy is not installed."""
    import importlib.util

    real = importlib.util.find_spec
    monkeypatch.setattr(loader_module.importlib.util, "find_spec",
                        lambda name, *a: None if name == "DracoPy" else real(name, *a))


def test_draco_glb_without_dracopy_is_refused_quickly(monkeypatch):
    hide_dracopy(monkeypatch)
    p = ASSETS / "teapot_draco.glb"  # assets/teapot.obj through Draco (tests/make_draco_asset.py)
    with pytest.raises(SceneFileError, match="DracoPy"):
        load_mesh(p)
    with pytest.raises(SceneFileError, match="DracoPy"):
        make_scene(p)


# ----------------------------------------------------------------------------- text encodings

ENC_V = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0.5, 0.5, 1.25]])
ENC_F = np.array([[0, 1, 2], [0, 2, 3], [0, 1, 4], [1, 2, 4]])
MTL_NAME = "matériaux.mtl"
MTL_TEXT = "# bibliothèque de matériaux\nnewmtl matériau_é\nKd 0.8 0.1 0.1\nnewmtl grün\nKd 0.1 0.8 0.1\n"
#: name -> (codec, byte-order mark written before the text)
ENCODINGS = {
    "utf-8": ("utf-8", b""),
    "utf-8-bom": ("utf-8", b"\xef\xbb\xbf"),
    "latin-1": ("latin-1", b""),
    "windows-1252": ("cp1252", b""),
    "utf-16-le-bom": ("utf-16-le", b"\xff\xfe"),
    "utf-16-be-bom": ("utf-16-be", b"\xfe\xff"),
    "utf-16-le-no-bom": ("utf-16-le", b""),
}


def encoded_obj_text(codec):
    """An OBJ file with a material library, two non-ASCII material names, a non-ASCII object name and
    comments (the euro sign only where the codec has one)."""
    euro = " (5 €)" if codec != "latin-1" else ""
    lines = [f"# modèle créé à Zürich: façade, Größe{euro}", f"mtllib {MTL_NAME}", "o objét_ü"]
    lines += [f"v {x!r} {y!r} {z!r}" for x, y, z in ENC_V.tolist()]
    lines += ["usemtl matériau_é", "f 1 2 3", "f 1 3 4", "usemtl grün", "f 1 2 5", "f 2 3 5"]
    return "\n".join(lines) + "\n"


@pytest.mark.parametrize("enc", list(ENCODINGS))
def test_obj_and_mtl_load_in_any_common_encoding(tmp_path, enc):
    """Latin-1 and UTF-16 files once failed with "No module named 'charset_normalizer'" (trimesh's
    guess at non-UTF-8 text); a UTF-8 byte-order mark must not hide the first line."""
    import trimesh

    from gridrt.scene.textenc import utf8_source

    codec, bom = ENCODINGS[enc]
    text = encoded_obj_text(codec)
    (tmp_path / MTL_NAME).write_bytes(bom + MTL_TEXT.encode(codec))
    p = tmp_path / "modèle.obj"
    p.write_bytes(bom + text.encode(codec))
    m = load_mesh(p)
    # trimesh groups an OBJ's faces by material: compare the triangles (coordinates, winding kept)
    assert m.n_triangles == len(ENC_F)
    np.testing.assert_array_equal(canonical(m.triangles()), canonical(ENC_V[ENC_F]))
    # the text trimesh reads is the text written; the MTL file it asks for too; and the materials
    # the faces name are the ones the library defines
    src, kw = utf8_source(p)
    assert src.read().decode("utf-8") == text
    assert kw["resolver"].get(MTL_NAME).decode("utf-8") == MTL_TEXT
    src.seek(0)
    scene = trimesh.load(src, file_type="obj", process=False, force="scene", **kw)
    assert sorted(g.visual.material.name for g in scene.geometry.values()) == ["grün", "matériau_é"]


@pytest.mark.parametrize("codec,bom", [("latin-1", b""), ("utf-16-le", b"\xff\xfe"), ("utf-8", b"\xef\xbb\xbf")],
                         ids=["latin-1", "utf-16-bom", "utf-8-bom"])
@pytest.mark.parametrize("ext", [".off", ".ply", ".stl"])
def test_other_text_formats_load_in_any_common_encoding(tmp_path, ext, codec, bom):
    """A Latin-1 comment in an OFF or ASCII PLY file, or a Latin-1 solid name in an ASCII STL file."""
    p = tmp_path / f"octa{ext}"
    {".off": lambda: write_off(p, OCTA_V, OCTA_F.tolist()), ".ply": lambda: write_ply_ascii(p, OCTA_V, OCTA_F),
     ".stl": lambda: write_stl_ascii(p, OCTA_T)}[ext]()
    text = p.read_text()
    text = {".off": lambda: text.replace("OFF\n", "OFF\n# modèle créé à Zürich\n", 1),
            ".ply": lambda: text.replace("format ascii 1.0\n", "format ascii 1.0\ncomment modèle ü\n", 1),
            ".stl": lambda: text.replace("solid test", "solid Pièce1", 1).replace("endsolid test", "endsolid Pièce1")}[ext]()
    p.write_bytes(bom + text.encode(codec))
    np.testing.assert_array_equal(canonical(load_mesh(p).triangles()), canonical(OCTA_T))


def test_binary_files_with_latin1_headers_are_left_binary(tmp_path):
    """Only a binary PLY's header is text; a binary STL header may hold any bytes, even 'solid ...'."""
    p = tmp_path / "octa.ply"
    write_ply_binary(p, OCTA_V, OCTA_F)
    raw = p.read_bytes()
    p.write_bytes(raw.replace(b"format binary_little_endian 1.0\n",
                              "format binary_little_endian 1.0\ncomment modèle ü\n".encode("latin-1"), 1))
    np.testing.assert_array_equal(canonical(load_mesh(p).triangles()), canonical(OCTA_T))
    s = tmp_path / "octa.stl"
    write_stl_binary(s, OCTA_T)
    raw = bytearray(s.read_bytes())
    raw[:20] = "solid Pièce ü ".encode("latin-1").ljust(20, b" ")
    s.write_bytes(bytes(raw))
    np.testing.assert_array_equal(canonical(load_mesh(s).triangles()), canonical(OCTA_T))


def test_text_decoding_rule():
    from gridrt.scene.textenc import decode_text

    assert decode_text("é€".encode("utf-8")) == ("é€", "UTF-8")
    assert decode_text(b"\xef\xbb\xbfv 1 2 3") == ("v 1 2 3", "UTF-8")
    assert decode_text("é€".encode("cp1252")) == ("é€", "Windows-1252")
    assert decode_text(b"caf\xe9 \x81") == ("café \x81", "Latin-1")  # 0x81: undefined in Windows-1252
    assert decode_text("v 1 é".encode("utf-16-be")) == ("v 1 é", "UTF-16-BE")
    assert decode_text(b"\xff\xfe\x00\x00" + "v é".encode("utf-32-le")) == ("v é", "UTF-32-LE")


def test_utf8_byte_order_mark_does_not_hide_the_first_vertex(tmp_path):
    """trimesh kept the mark as part of the first line: 'v 0 0 0' was lost and face 'f 1 2 4' refused."""
    p = tmp_path / "bom.obj"
    p.write_bytes(b"\xef\xbb\xbf" + b"v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\nf 1 2 4\n")
    m = load_mesh(p)
    np.testing.assert_array_equal(m.vertices, [[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    np.testing.assert_array_equal(m.faces, [[0, 1, 2], [0, 1, 3]])


def test_truncated_utf16_obj_is_a_clear_error(tmp_path):
    p = tmp_path / "cut.obj"
    p.write_bytes(b"\xff\xfe" + "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n".encode("utf-16-le")[:-1])
    _raises_file_error(p, "not valid UTF-16-LE")


# ----------------------------------------------------------------------------- file errors


def _raises_file_error(path, *words):
    with pytest.raises(SceneFileError) as info:
        load_mesh(path)
    err = info.value
    assert err.path == str(path)
    assert str(path) in str(err)
    for w in words:
        assert w.lower() in err.problem.lower(), err.problem
    return err


def test_missing_file(tmp_path):
    _raises_file_error(tmp_path / "nope.obj", "not found")


def test_directory(tmp_path):
    d = tmp_path / "dir.obj"
    d.mkdir()
    _raises_file_error(d, "directory")


def test_unreadable_file(tmp_path, monkeypatch):
    p = tmp_path / "locked.obj"
    write_obj(p, OCTA_V, OCTA_F)
    p.chmod(0)
    if os.access(p, os.R_OK):  # root ignores permissions: make opening fail as it would for a user

        def denied(path, *args, **kwargs):
            raise PermissionError(13, "Permission denied", str(path))

        monkeypatch.setattr(files_module, "open_regular", denied)
    try:
        _raises_file_error(p, "permission denied")
    finally:
        p.chmod(0o644)


@pytest.mark.parametrize("name", ["mesh.xyz", "mesh.dae", "noext"])
def test_unsupported_extension_lists_supported(tmp_path, name):
    p = tmp_path / name
    p.write_text("v 0 0 0\n")
    err = _raises_file_error(p, "extension")
    for ext in SUPPORTED_EXTENSIONS:
        assert ext in err.problem


@pytest.mark.parametrize("ext", SUPPORTED_EXTENSIONS)
def test_empty_file(tmp_path, ext):
    p = tmp_path / f"empty{ext}"
    p.write_bytes(b"")
    _raises_file_error(p, "empty")


@pytest.mark.parametrize(
    "name,content,word",
    [
        ("junk.ply", b"\x00\x01garbage" * 10, "malformed"),
        ("junk.glb", b"glTF\x02\x00\x00\x00garbage", "malformed"),
        ("junk.gltf", b"{not json", "json"),
        ("junk.off", b"OFF\n3 1 0\n0 0 0\n1 0\n", "malformed"),
        ("junk.obj", b"hello world\nthis is not an obj file\n", "no triangles"),
        ("junk.stl", b"\x00\x01garbage" * 10, "no triangles"),
        ("cloud.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\n", "no triangles"),
        ("cloud.off", b"OFF\n3 0 0\n0 0 0\n1 0 0\n0 1 0\n", "no faces"),
        (
            "cloud.ply",
            b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
            b"property float z\nend_header\n0 0 0\n1 0 0\n0 1 0\n",
            "no triangles",
        ),
    ],
)
def test_malformed_files(tmp_path, name, content, word):
    p = tmp_path / name
    p.write_bytes(content)
    _raises_file_error(p, word)


@pytest.mark.parametrize(
    "name,text,word",
    [
        ("nan.obj", "v nan 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", "nan"),
        ("inf.off", "OFF\n3 1 0\ninf 0 0\n1 0 0\n0 1 0\n3 0 1 2\n", "infinity"),
        ("badidx.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n", "index"),
        ("badidx.off", "OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 7\n", "index"),
        (
            "badidx.ply",
            ply_header("ascii", 3, 1) + "0 0 0\n1 0 0\n0 1 0\n3 0 1 5\n",
            "index",
        ),
        ("flat.obj", "v 0 0 0\nv 1 0 0\nv 2 0 0\nv 3 0 0\nf 1 2 3\nf 2 3 4\n", "degenerate"),
    ],
)
def test_invalid_mesh_contents(tmp_path, name, text, word):
    p = tmp_path / name
    p.write_text(text)
    _raises_file_error(p, word)


def test_gltf_with_missing_buffer_file(tmp_path):
    p = tmp_path / "lonely.gltf"
    write_gltf(p, [(OCTA_V, OCTA_F)], [{"mesh": 0}], roots=[0])
    (tmp_path / "lonely.bin").unlink()
    _raises_file_error(p, "missing")


def test_glb_requiring_draco_is_refused(tmp_path, monkeypatch):
    hide_dracopy(monkeypatch)
    p = tmp_path / "draco.glb"
    ext = ["KHR_draco_mesh_compression"]
    extra = {"extensionsRequired": ext, "extensionsUsed": ext}
    write_gltf(p, [(OCTA_V, OCTA_F)], [{"mesh": 0}], roots=[0], extra=extra)
    _raises_file_error(p, "draco")


def test_load_mesh_rejects_non_path():
    with pytest.raises(InputError):
        load_mesh(42)


# ----------------------------------------------------------------------------- Mesh


def test_mesh_validates_and_copies():
    v = OCTA_V.copy()
    m = Mesh(v, OCTA_F, name="octa")
    assert not m.vertices.flags.writeable and not m.faces.flags.writeable
    assert v.flags.writeable and not np.shares_memory(v, m.vertices)
    np.testing.assert_array_equal(m.triangles(), OCTA_T)
    lo, hi = m.bounds()
    np.testing.assert_array_equal(lo, OCTA_V.min(0))
    np.testing.assert_array_equal(hi, OCTA_V.max(0))
    bad = v.copy()
    bad[2, 1] = np.nan
    with pytest.raises(InputError, match="NaN"):
        Mesh(bad, OCTA_F)
    with pytest.raises(InputError, match="out of range"):
        Mesh(v, OCTA_F + 1)


# ----------------------------------------------------------------------------- animation protocol


def _twisted_teapot_or_octa():
    p = ASSETS / "teapot.obj"
    return load_mesh(p) if p.exists() else Mesh(OCTA_V, OCTA_F, name="octa")


SCENES = {
    "marbles": lambda: Marbles(8800, seed=1),
    "static": lambda: StaticMesh(Mesh(OCTA_V, OCTA_F, name="octa")),
    "twist": lambda: Deform(_twisted_teapot_or_octa(), "twist", speed=0.5),
    "wave": lambda: make_scene("icosphere", count=1280, animate="wave", amplitude=0.1, speed=2.0),
}


@pytest.fixture(params=sorted(SCENES))
def make(request):
    """A zero-argument constructor of one of SCENES (call it twice for two equal scenes)."""
    return SCENES[request.param]


@pytest.fixture
def scene(make):
    return make()


def test_triangles_at_shape_dtype_and_buffer_reuse(scene):
    assert isinstance(scene, Animation)
    a = scene.triangles_at(0.25)
    assert a.shape == (scene.n_triangles, 3, 3)
    assert a.dtype == np.float32 and a.flags.c_contiguous
    b = scene.triangles_at(0.5)
    assert b is a
    out = np.empty_like(a)
    r = scene.triangles_at(0.75, out=out)
    assert r is out and r is not a
    np.testing.assert_array_equal(out, scene.triangles_at(0.75))


def test_triangles_at_is_pure(scene, make):
    t1, t2 = 0.37, 2.9
    first = scene.triangles_at(t1).copy()
    scene.triangles_at(t2)
    again = scene.triangles_at(t1)
    np.testing.assert_array_equal(first, again)
    fresh = make().triangles_at(t1)
    np.testing.assert_array_equal(first, fresh)
    # scribbling on the returned buffer does not leak into the next frame
    again[:] = 7.0
    np.testing.assert_array_equal(scene.triangles_at(t1), first)


def test_triangles_at_is_continuous(scene):
    a = scene.triangles_at(1.1).astype(np.float64)
    b = scene.triangles_at(1.1 + 1e-5).astype(np.float64)
    c = scene.triangles_at(1.1 + 0.2).astype(np.float64)
    size = np.ptp(a.reshape(-1, 3), axis=0).max()
    small = np.abs(b - a).max()
    assert small <= 1e-3 * size
    if scene.static:
        np.testing.assert_array_equal(a, c)
        assert small == 0
    else:
        assert np.abs(c - a).max() > 100 * small


def test_triangles_at_loops(scene):
    if scene.duration is None:  # no period: only a static scene may say so
        assert scene.static
        return
    a = scene.triangles_at(0.3).copy()
    b = scene.triangles_at(0.3 + scene.duration)
    size = np.ptp(a.reshape(-1, 3), axis=0).max()
    np.testing.assert_allclose(b, a, atol=1e-5 * size)


@pytest.mark.parametrize("t", [float("nan"), float("inf"), "1.0", None, True, [0.5]])
def test_bad_time(scene, t):
    with pytest.raises(InputError):
        scene.triangles_at(t)


def test_bad_out_buffers(scene):
    n = scene.n_triangles
    bad = [
        np.zeros((n, 3, 3), dtype=np.float64),
        np.zeros((n + 1, 3, 3), dtype=np.float32),
        np.zeros((n, 3), dtype=np.float32),
        np.zeros((n, 3, 3, 2), dtype=np.float32)[..., 0],
        [[0.0] * 3] * 3,
    ]
    ro = np.zeros((n, 3, 3), dtype=np.float32)
    ro.setflags(write=False)
    bad.append(ro)
    for out in bad:
        with pytest.raises(InputError):
            scene.triangles_at(0.0, out=out)


def test_static_mesh_triangles_equal_faces_gather():
    s = StaticMesh(Mesh(OCTA_V, OCTA_F, name="octa"))
    assert s.static and s.duration is None and s.n_triangles == 8 and s.name == "octa"
    np.testing.assert_array_equal(s.triangles_at(-3.0), OCTA_T)
    with pytest.raises(InputError):
        StaticMesh(OCTA_T)


# ----------------------------------------------------------------------------- marbles


@pytest.mark.parametrize("n", [322, 479, 8800, 100_000, 1_000_000])
def test_marbles_count_exact_and_inside_box(n):
    m = Marbles(n)
    assert m.n_triangles == n
    assert m.n_marbles * 320 + m.n_floor == n and m.n_marbles >= 1 and m.n_floor >= 2
    if n == 8800:
        assert (m.n_marbles, m.n_floor) == (27, 160)
    lo = m.box_lo.astype(np.float32)
    hi = m.box_hi.astype(np.float32)
    times = np.linspace(-3.0, 2 * m.duration, 9 if n >= 1_000_000 else 61)
    for t in times:
        v = m.triangles_at(t).reshape(-1, 3)
        assert (v >= lo).all() and (v <= hi).all(), t
    floor = m.triangles_at(0.0)[: m.n_floor].astype(np.float64)
    assert (floor[:, :, 1] == 0).all()
    n_floor = np.cross(floor[:, 1] - floor[:, 0], floor[:, 2] - floor[:, 0])
    assert (n_floor[:, 1] > 0).all()
    box_area = (m.box_hi[0] - m.box_lo[0]) * (m.box_hi[2] - m.box_lo[2])
    assert n_floor[:, 1].sum() / 2 == pytest.approx(box_area, rel=1e-5)


def _closest_approach(m, i, axis, sign):
    """Time in [0, duration) where marble i's centre is extreme along ``sign * axis``.

    Dense sampling, then a ternary search on the (locally unimodal) coordinate.
    """
    ts = np.linspace(0.0, m.duration, 4001)
    vals = np.array([sign * m.centers_at(t)[i, axis] for t in ts])
    k = int(np.argmax(vals))
    a, b = ts[max(k - 1, 0)], ts[min(k + 1, len(ts) - 1)]
    for _ in range(60):
        x1, x2 = a + (b - a) / 3, b - (b - a) / 3
        if sign * m.centers_at(x1)[i, axis] < sign * m.centers_at(x2)[i, axis]:
            a = x1
        else:
            b = x2
    return 0.5 * (a + b)


def test_marbles_inside_box_at_wall_and_floor_contacts():
    m = Marbles(960, seed=4)  # 2 marbles, all contacts checked
    lo = m.box_lo.astype(np.float32)
    hi = m.box_hi.astype(np.float32)
    for i in range(m.n_marbles):
        for axis, sign in ((0, 1), (0, -1), (2, 1), (2, -1), (1, -1)):
            t = _closest_approach(m, i, axis, sign)
            v = m.triangles_at(t)[m.n_floor + 320 * i : m.n_floor + 320 * (i + 1)].reshape(-1, 3)
            assert (v >= lo).all() and (v <= hi).all(), (i, axis, sign, t)
            # the marble really reaches the wall or floor (its flat facets may stay ~2% of r away)
            gap = (hi[axis] - v[:, axis].max()) if sign > 0 else (v[:, axis].min() - lo[axis])
            assert gap < 0.05 * m.radius, (i, axis, sign, gap)


def test_marbles_are_rigid_spheres_about_their_centres():
    m = Marbles(8800, seed=3)
    for t in (0.0, 1.234, 5.5):
        tris = m.triangles_at(t)[m.n_floor :].reshape(m.n_marbles, 320 * 3, 3).astype(np.float64)
        c = m.centers_at(t)
        dist = np.linalg.norm(tris - c[:, None, :], axis=2)
        np.testing.assert_allclose(dist, m.radius, rtol=1e-5, atol=1e-5)
    # rigid motion keeps every triangle's area
    a0 = areas(m.triangles_at(0.0)[m.n_floor :])
    a1 = areas(m.triangles_at(3.3)[m.n_floor :])
    np.testing.assert_allclose(a1, a0, rtol=1e-4)


def test_marbles_fall_with_gravity_and_move_at_constant_speed():
    m = Marbles(100_000, seed=5)
    dt = 1e-3
    for t in (0.41, 2.77, 6.03):
        y = [m.centers_at(t + k * dt)[:, 1] for k in (-1, 0, 1)]
        acc = (y[0] - 2 * y[1] + y[2]) / dt**2
        free = np.abs(acc + m.gravity) < 1e-3 * m.gravity
        # only marbles bouncing off the floor inside [t - dt, t + dt] may differ
        assert free.mean() > 0.9
        assert (y[1][~free] < m.radius + 2 * m.gravity * dt + 1e-3 * m.radius).all()
        xz = [m.centers_at(t + k * dt)[:, [0, 2]] for k in (0, 1)]
        speed = np.abs(xz[1] - xz[0]) / dt
        box = m.box_hi[0] - m.box_lo[0] - 2 * m.radius
        # horizontal speeds are whole round trips per loop: 2 * width * k / duration, k in {1, 2}
        k = speed * m.duration / (2 * box)
        near = np.abs(k - np.round(k)) < 1e-2
        assert near.mean() > 0.95 and set(np.round(k[near]).astype(int).ravel()) <= {1, 2}


@pytest.mark.parametrize("n", [8800, 100_000])
def test_marbles_triangles_are_the_rotated_and_moved_base(n):
    """Both fills (on the calling thread below MARBLES_SERIAL_BELOW triangles, in parallel from
    there) give the floor and each marble's base triangles turned by its rotation and moved to its
    centre, computed here with numpy."""
    from gridrt.scene.marbles import MARBLES_SERIAL_BELOW

    assert (n < MARBLES_SERIAL_BELOW) == (n == 8800)
    m = Marbles(n, seed=2)
    t = 1.7
    got = m.triangles_at(t).astype(np.float64)
    rot, c = m.rotations_at(t), m.centers_at(t)
    want = np.einsum("mij,bkj->mbki", rot, m._base) + c[:, None, None, :]
    np.testing.assert_allclose(got[: m.n_floor], m._floor, rtol=1e-6, atol=1e-6)  # (float32 rounding)
    np.testing.assert_allclose(got[m.n_floor :].reshape(want.shape), want, rtol=1e-6, atol=1e-6)


def test_marbles_seed():
    a = Marbles(8800, seed=0).triangles_at(1.0).copy()
    b = Marbles(8800, seed=0).triangles_at(1.0)
    c = Marbles(8800, seed=1).triangles_at(1.0)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)


def test_marbles_speed_is_a_time_scale():
    slow = Marbles(8800, seed=2)
    fast = Marbles(8800, seed=2, speed=2.5)
    for t in (0.0, 0.3, 1.7, -2.2):
        np.testing.assert_array_equal(fast.triangles_at(t), slow.triangles_at(2.5 * t))
    assert fast.duration == pytest.approx(slow.duration / 2.5)
    assert fast.gravity == pytest.approx(slow.gravity * 2.5**2)
    back = Marbles(8800, seed=2, speed=-1.0)
    np.testing.assert_array_equal(back.triangles_at(1.25), slow.triangles_at(-1.25))
    for bad in (0.0, float("nan"), "x"):
        with pytest.raises(InputError, match="speed"):
            Marbles(8800, speed=bad)


@pytest.mark.parametrize("n", [321, 0, -5, 1.5, True, "8800", 50_000_001])
def test_marbles_bad_count(n):
    with pytest.raises(InputError):
        Marbles(n)


@pytest.mark.parametrize("seed", [-1, 0.5, None])
def test_marbles_bad_seed(seed):
    with pytest.raises(InputError):
        Marbles(8800, seed=seed)


# ----------------------------------------------------------------------------- deformations


def _asym_mesh():
    """A lumpy off-centre mesh: an anisotropically scaled, shifted icosphere."""
    import trimesh

    ico = trimesh.creation.icosphere(subdivisions=3)
    v = ico.vertices * [2.0, 3.0, 1.0] + [5.0, -1.0, 2.0]
    v[:, 0] += 0.3 * np.sin(3 * v[:, 1])
    return Mesh(v, ico.faces, name="lumpy")


def _twist_reference(v, amplitude, speed, t):
    """Twist formula from the deform module docstring, in float64 numpy."""
    lo, hi = v.min(0), v.max(0)
    cx, cz = (lo[0] + hi[0]) / 2, (lo[2] + hi[2]) / 2
    h = (v[:, 1] - lo[1]) / (hi[1] - lo[1])
    rho = np.hypot(v[:, 0] - cx, v[:, 2] - cz)
    alpha = amplitude / (rho * h).max()
    th = alpha * np.sin(2 * np.pi * speed * t) * h
    dx, dz = v[:, 0] - cx, v[:, 2] - cz
    out = v.copy()
    out[:, 0] = cx + dx * np.cos(th) - dz * np.sin(th)
    out[:, 2] = cz + dx * np.sin(th) + dz * np.cos(th)
    return out, (cx, cz)


@pytest.mark.parametrize("speed", [1.0, -0.7])
def test_twist_matches_formula_and_preserves_radius(speed):
    mesh = _asym_mesh()
    v = mesh.vertices.astype(np.float64)
    amp = 0.4
    d = Deform(mesh, "twist", amplitude=amp, speed=speed)
    assert not d.static and d.duration == pytest.approx(1 / abs(speed))
    scale = np.ptp(v, axis=0).max()
    worst = 0.0
    for t in np.linspace(0.0, d.duration, 23):
        got = d.vertices_at(t).astype(np.float64)
        ref, (cx, cz) = _twist_reference(v, amp, speed, t)
        np.testing.assert_allclose(got, ref, atol=2e-6 * scale)
        np.testing.assert_array_equal(got[:, 1], v[:, 1])
        r0 = np.hypot(v[:, 0] - cx, v[:, 2] - cz)
        r1 = np.hypot(got[:, 0] - cx, got[:, 2] - cz)
        np.testing.assert_allclose(r1, r0, atol=2e-6 * scale)
        disp = np.linalg.norm(got - v, axis=1).max()
        assert disp <= amp * (1 + 1e-5)
        worst = max(worst, disp)
        tris = d.triangles_at(t)
        np.testing.assert_array_equal(tris, d.vertices_at(t)[mesh.faces])
    # at full swing the farthest vertex moves (almost) the whole amplitude
    assert worst > 0.95 * amp


def test_twist_at_rest_at_t0_and_default_amplitude():
    mesh = _asym_mesh()
    d = Deform(mesh, "twist")
    np.testing.assert_array_equal(d.triangles_at(0.0), mesh.triangles())
    lo, hi = mesh.bounds()
    diag = np.linalg.norm(hi - lo)
    assert d.amplitude == pytest.approx(0.05 * diag)
    disp = np.linalg.norm(d.vertices_at(0.25).astype(np.float64) - mesh.vertices, axis=1).max()
    assert 0.95 * 0.05 * diag < disp <= 0.05 * diag * (1 + 1e-5)


def test_wave_matches_formula():
    mesh = _asym_mesh()
    v = mesh.vertices.astype(np.float64)
    amp, speed = 0.25, 1.5
    d = Deform(mesh, "wave", amplitude=amp, speed=speed)
    wavelength = (v[:, 0].max() - v[:, 0].min()) / 2
    assert d.wavelength == pytest.approx(wavelength)
    idx = [0, 7, 100, len(v) - 1]
    for t in (0.0, 0.1, 0.55, 3.21):
        got = d.vertices_at(t)
        np.testing.assert_array_equal(got[:, [0, 2]], mesh.vertices[:, [0, 2]])
        ref_y = v[:, 1] + amp * np.sin(2 * np.pi * (v[:, 0] / wavelength + speed * t))
        np.testing.assert_allclose(got[idx, 1], ref_y[idx], atol=1e-5)
        np.testing.assert_allclose(got[:, 1], ref_y, atol=1e-5)
        assert np.abs(got[:, 1] - v[:, 1]).max() <= amp + 1e-5
        np.testing.assert_array_equal(d.triangles_at(t), got[mesh.faces])


def test_deform_real_mesh_twist():
    mesh = load_mesh(need_data("static/armadillo/armadillo.off"))
    d = Deform(mesh, "twist")
    a = d.triangles_at(0.25)
    assert a.shape == (52_000, 3, 3)
    disp = np.linalg.norm(a.reshape(-1, 3).astype(np.float64) - mesh.triangles().reshape(-1, 3), axis=1)
    assert disp.max() <= d.amplitude * (1 + 1e-5)


@pytest.mark.parametrize(
    "kwargs,word",
    [
        ({"kind": "spin"}, "twist, wave"),
        ({"amplitude": 0.0}, "> 0"),
        ({"amplitude": -1.0}, "> 0"),
        ({"amplitude": float("nan")}, "finite"),
        ({"amplitude": "big"}, "real number"),
        ({"speed": 0.0}, "non-zero"),
        ({"speed": float("inf")}, "finite"),
    ],
)
def test_deform_bad_parameters(kwargs, word):
    with pytest.raises(InputError, match=word):
        Deform(_asym_mesh(), **kwargs)


def test_deform_needs_extent():
    flat_y = Mesh([[0, 0, 0], [1, 0, 0], [0, 0, 1]], [[0, 1, 2]], name="flat")
    with pytest.raises(InputError, match="twist"):
        Deform(flat_y, "twist")
    Deform(flat_y, "wave")
    flat_x = Mesh([[0, 0, 0], [0, 1, 0], [0, 0, 1]], [[0, 1, 2]], name="wall")
    with pytest.raises(InputError, match="x"):
        Deform(flat_x, "wave")
    with pytest.raises(InputError):
        Deform(OCTA_T, "twist")


def test_deform_bad_vertex_out():
    d = Deform(_asym_mesh(), "wave")
    with pytest.raises(InputError):
        d.vertices_at(0.0, out=np.zeros((3, 3), dtype=np.float32))


# ----------------------------------------------------------------------------- make_scene


def test_make_scene_builtins():
    # the shipped assets (test_assets.py) and the development data set's scenes, by name
    assert set(BUILTIN_SCENES) == {"marbles", "icosphere", *ASSET_SCENES, *DATA_SCENES}
    m = make_scene("marbles")
    assert isinstance(m, Marbles) and m.n_triangles == 8800
    assert make_scene("Marbles", count=10_000, seed=2).n_triangles == 10_000
    assert make_scene("marbles", speed=2.0).duration == pytest.approx(m.duration / 2)
    ico = make_scene("icosphere", count=5000)
    assert isinstance(ico, StaticMesh) and ico.n_triangles == 5120
    assert make_scene("icosphere", count=1).n_triangles == 20
    tris = ico.triangles_at(0.0).astype(np.float64)
    np.testing.assert_allclose(np.linalg.norm(tris, axis=2), 1.0, rtol=1e-6)
    tw = make_scene("icosphere", animate="twist", amplitude=0.1, speed=2.0)
    assert isinstance(tw, Deform) and tw.kind == "twist" and tw.amplitude == 0.1 and tw.duration == 0.5


def test_icosphere_count_beyond_the_largest_warns_with_the_count_made(monkeypatch):
    """The icosphere caps at 20 x 4^9 triangles; a larger count is capped with a warning that names the count made."""
    import warnings

    from gridrt.scene import make as scene_module

    monkeypatch.setattr(scene_module, "_ICOSPHERE_MAX_SUBDIVISIONS", 2)  # a small cap keeps the test fast
    with pytest.warns(scene_module.SceneCountWarning) as caught:
        assert make_scene("icosphere", count=100_000).n_triangles == 320
    assert [str(w.message) for w in caught] == [
        "icosphere: count 100,000 is beyond the largest icosphere (20 x 4^2); made 320 triangles"]
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # within the range (or below it: 20 is the nearest), no warning
        assert make_scene("icosphere", count=400).n_triangles == 320
        assert make_scene("icosphere", count=1).n_triangles == 20


def test_make_scene_paths(tmp_path):
    p = tmp_path / "octa.obj"
    write_obj(p, OCTA_V, OCTA_F)
    s = make_scene(p)
    assert isinstance(s, StaticMesh) and s.n_triangles == 8
    w = make_scene(str(p), animate="wave")
    assert isinstance(w, Deform) and w.kind == "wave"
    with pytest.raises(SceneFileError, match="not found"):
        make_scene(tmp_path / "missing.ply")
    with pytest.raises(InputError, match="count"):
        make_scene(p, count=100)


def test_make_scene_unknown_name_lists_choices():
    with pytest.raises(InputError) as info:
        make_scene("marble")
    msg = str(info.value)
    for word in list(BUILTIN_SCENES) + list(SUPPORTED_EXTENSIONS):
        assert word in msg


@pytest.mark.parametrize(
    "args,kwargs,word",
    [
        (("icosphere",), {"animate": "spin"}, "twist, wave"),
        (("marbles",), {"animate": "twist"}, "already animated"),
        (("icosphere",), {"amplitude": 1.0}, "animate"),
        (("icosphere",), {"speed": 2.0}, "animate"),
        (("marbles",), {"amplitude": 1.0}, "already animated"),
        (("marbles",), {"count": 100}, "between"),
        (("icosphere",), {"count": 0}, "positive"),
        (("marbles",), {"count": 2.5}, "integer"),
        ((42,), {}, "built-in name"),
    ],
)
def test_make_scene_bad_options(args, kwargs, word):
    with pytest.raises(InputError, match=word):
        make_scene(*args, **kwargs)


def test_make_scene_new_options_are_checked(tmp_path):
    p = tmp_path / "octa.obj"
    write_obj(p, OCTA_V, OCTA_F)
    for args, kwargs, word in [
        (("marbles",), {"subdivide": 10_000}, "count"),
        (("marbles",), {"clip": 0}, "clip"),
        (("icosphere",), {"fps": 10}, "fps"),
        ((p,), {"clip": "walk"}, "clip"),
        ((p,), {"fps": 10}, "fps"),
        ((p,), {"subdivide": 0}, "subdivide"),
        ((p,), {"subdivide": 2.5}, "subdivide"),
    ]:
        with pytest.raises(InputError, match=word):
            make_scene(*args, **kwargs)
    with pytest.raises(InputError) as info:
        make_scene("no-such-scene")
    for ext in SCENE_EXTENSIONS:
        assert ext in str(info.value)
    assert ".aff" in SCENE_EXTENSIONS and ".md2" in SCENE_EXTENSIONS


def test_make_scene_static_gltf_is_static_mesh(tmp_path):
    p = tmp_path / "scene.glb"
    write_gltf(p, [(OCTA_V, OCTA_F), (QUAD_V, QUAD_F)], GLTF_NODES, roots=[0, 1, 2])
    s = make_scene(p)
    assert isinstance(s, StaticMesh) and s.n_triangles == 18
    np.testing.assert_allclose(canonical(s.triangles_at(0.0)), canonical(gltf_expected()), atol=1e-5)
    w = make_scene(p, animate="wave", subdivide=72)
    assert isinstance(w, Deform) and w.n_triangles == 72  # 18 triangles split once


# ----------------------------------------------------------------------------- protocol additions


def test_static_mask_and_camera_protocol(scene):
    mask = scene.static_mask
    assert scene.camera_at(0.5) is None
    with pytest.raises(InputError):
        scene.camera_at(float("nan"))
    if mask is None:
        assert scene.n_static == 0
        return
    assert mask.shape == (scene.n_triangles,) and mask.dtype == np.bool_ and not mask.flags.writeable
    a = scene.triangles_at(0.3).copy()
    b = scene.triangles_at(2.1)
    np.testing.assert_array_equal(a[mask], b[mask])
    assert scene.n_static == (scene.n_triangles if scene.static else int(mask.sum()))


def test_marbles_static_mask_is_the_floor():
    m = Marbles(8800)
    assert m.static_mask[: m.n_floor].all() and not m.static_mask[m.n_floor:].any()
    assert m.n_static == 160
    assert StaticMesh(Mesh(OCTA_V, OCTA_F)).static_mask.all()
    assert Deform(Mesh(OCTA_V, OCTA_F), "wave").static_mask is None


def test_as_static_mask_validation():
    assert as_static_mask(None, 3) is None
    m = as_static_mask(np.array([True, False, True]), 3)
    assert not m.flags.writeable
    for bad in (np.ones(4, dtype=bool), np.ones(3), [[True] * 3]):
        with pytest.raises(InputError):
            as_static_mask(bad, 3)


# ----------------------------------------------------------------------------- subdivision


def test_subdivide_keeps_the_surface():
    base = Mesh(OCTA_V, OCTA_F, name="octa")
    sub = subdivide_mesh(base, 500)
    assert sub.n_triangles == 8 * 4**3 and sub.name == "octa (subdivided x64)"
    parent = OCTA_T.astype(np.float64)
    tris = sub.triangles().astype(np.float64)
    assert areas(tris).sum() == pytest.approx(areas(parent).sum(), rel=1e-6)
    # children 64 f .. 64 f + 63 of triangle f lie inside it (barycentric coordinates in [0, 1])
    # and keep its orientation
    for f in range(8):
        a, b, c = parent[f]
        kids = tris[64 * f: 64 * (f + 1)].reshape(-1, 3)
        m = np.stack([b - a, c - a], axis=1)
        uv, *_ = np.linalg.lstsq(m, (kids - a).T, rcond=None)
        assert (uv > -1e-6).all() and (uv.sum(axis=0) < 1 + 1e-6).all()
        np.testing.assert_allclose(m @ uv + a[:, None], (kids).T, atol=1e-6)
        n0 = np.cross(b - a, c - a)
        kt = tris[64 * f: 64 * (f + 1)]
        nk = np.cross(kt[:, 1] - kt[:, 0], kt[:, 2] - kt[:, 0])
        assert (nk @ n0 > 0).all()
    # closed stays closed: every undirected edge is shared by exactly two triangles
    e = np.sort(sub.faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1).astype(np.int64)
    _, counts = np.unique(e[:, 0] * sub.n_vertices + e[:, 1], return_counts=True)
    assert (counts == 2).all()
    assert sub.n_vertices == sub.n_triangles // 2 + 2  # Euler, closed genus-0 mesh: V = F/2 + 2
    assert subdivide_mesh(base, 8) is base
    for bad in (0, -3, 2.0, True, 10**9):
        with pytest.raises(InputError):
            subdivide_mesh(base, bad)


def test_make_scene_subdivides_a_scan_to_832k():
    """The Armadillo (52,000 triangles) subdivided twice (x 16)."""
    p = need_data("static/armadillo/armadillo.off")
    s = make_scene(p, subdivide=832_000, animate="twist")
    assert isinstance(s, Deform) and s.n_triangles == 832_000
    base = load_mesh(p)
    tris = s.triangles_at(0.0)  # the twist is at rest at t = 0
    assert areas(tris[:64_000]).sum() == pytest.approx(areas(base.triangles()[:4000]).sum(), rel=1e-5)


@pytest.mark.slow
def test_make_scene_subdivides_a_scan_to_3_3m():
    p = need_data("static/armadillo/armadillo.off")
    s = make_scene(p, subdivide=3_328_000)
    assert s.n_triangles == 3_328_000 and s.static


def test_pipeline_animates_at_its_own_thread_count():
    """Two pipelines of one scene at 1 and 3 threads, stepped in turn (as `gridrt bench frame`
    does): each pipeline's animation step runs at its own thread count, not at the count the
    other pipeline's render left behind (which made a 2-thread twist look slower than 1 thread)."""
    import numba

    from gridrt.config import GridParams, RenderParams
    from gridrt.pipeline import FramePipeline
    from gridrt.scene import make_scene

    scene = make_scene("icosphere", animate="twist")
    seen = []
    fill = scene.triangles_at

    def spy(t, out=None, origin=None):
        seen.append(numba.get_num_threads())
        return fill(t, out, origin)

    scene.triangles_at = spy
    pipes = {T: FramePipeline(scene, GridParams(threads=T), RenderParams(width=16, height=12, threads=T))
             for T in (1, 3)}
    for i in range(3):
        for T in (3, 1):
            seen.clear()
            pipes[T].step(i / 30)
            # every evaluation of the step (the first also measures the scene to choose its frame)
            assert seen and set(seen) == {T}


@pytest.mark.parametrize("subdivisions", [0, 1, 2, 3])
@pytest.mark.parametrize("radius", [1.0, 0.37, 12.5])
def test_icosphere_equals_trimesh_bit_for_bit(subdivisions, radius):
    """gridrt's icosphere (the marbles, built without importing trimesh) is trimesh's."""
    import trimesh

    from gridrt.scene.icosphere import icosphere_triangles

    ref = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    want = np.asarray(ref.vertices, np.float64)[np.asarray(ref.faces)]
    got = icosphere_triangles(subdivisions, radius)
    assert got.dtype == np.float64 and got.shape == (20 * 4 ** subdivisions, 3, 3)
    assert np.array_equal(got, want)
