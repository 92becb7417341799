"""Scene files are untrusted input: every file a scene names must resolve inside the scene's folder
(or be trusted with allow_outside / --allow-outside-refs), only regular files are read, declared
sizes are checked first, images have a pixel limit, no message quotes a file that is not a scene,
and a huge light saturates.  Every scene here is crafted by the test in tmp_path."""

import base64
import json
import os
import struct
import subprocess
import sys
import uuid
import warnings
import zlib
from io import BytesIO
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from gridrt.camera import Camera
from gridrt.config import GridParams, RenderParams
from gridrt.errors import SceneFileError
from gridrt.grid import GridBuilder
from gridrt.scene import SceneSpec, make_scene
from gridrt.scene.surface import MAX_TEXTURE_PIXELS, TextureWarning, load_texture
from gridrt.trace.render import Looks, Renderer

REPO = Path(__file__).resolve().parents[1]
FLAG = "--allow-outside-refs"
OUTSIDE = "outside the scene's folder"

TRI = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32)
UV = np.array([[0, 0], [1, 0], [0, 1]], np.float32)
BLOB = TRI.tobytes() + UV.tobytes()   # 36 bytes of positions, 24 of uv


def png_bytes(rgb=(200, 40, 10), size=(4, 4)):
    out = BytesIO()
    Image.new("RGB", size, rgb).save(out, "PNG")
    return out.getvalue()


def layout(tmp_path):
    """(the scene's folder, a folder beside it that is outside) with a buffer and an image in each."""
    scene, out = tmp_path / "scene", tmp_path / "out"
    for d in (scene, out):
        d.mkdir()
        (d / "tri.bin").write_bytes(BLOB)
        (d / "tex.png").write_bytes(png_bytes())
    return scene, out


def write_gltf(path, buffer_uri="tri.bin", image_uri=None, byte_length=len(BLOB), views=None):
    """A one-triangle glTF whose buffer is ``buffer_uri``; with ``image_uri`` it is textured with it."""
    g = {
        "asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
        "buffers": [{"uri": buffer_uri, "byteLength": byte_length}],
        "bufferViews": views or [{"buffer": 0, "byteOffset": 0, "byteLength": 36},
                                 {"buffer": 0, "byteOffset": 36, "byteLength": 24}],
        "accessors": [{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3",
                       "min": [0, 0, 0], "max": [1, 1, 0]},
                      {"bufferView": 1, "componentType": 5126, "count": 3, "type": "VEC2"}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "TEXCOORD_0": 1}}]}],
    }
    if image_uri is not None:
        g["meshes"][0]["primitives"][0]["material"] = 0
        g["materials"] = [{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}}]
        g["textures"] = [{"source": 0}]
        g["images"] = [{"uri": image_uri}]
    path.write_text(json.dumps(g))
    return path


def textured(scene):
    s = scene.surface
    return s is not None and s.textured


def load_quietly(*args, **kw):
    """make_scene with the TextureWarnings it gives, as one string."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        scene = make_scene(*args, **kw)
    return scene, "\n".join(str(w.message) for w in caught if issubclass(w.category, TextureWarning))


def refused(path, reference, **kw):
    """The SceneFileError of loading ``path``: one line naming ``reference`` and the way to allow it."""
    with pytest.raises(SceneFileError) as info:
        make_scene(path, **kw)
    msg = str(info.value)
    assert OUTSIDE in msg and FLAG in msg and "allow_outside=True" in msg and repr(reference) in msg, msg
    assert "\n" not in msg
    return msg


def escape_routes(scene, out):
    """{route: the reference, as a scene in ``scene`` writes it, to a file of ``out`` (``{}``: its
    name)}; the symlink route needs the link made (:func:`prepare`)."""
    return {
        "relative": "../out/{}",
        "absolute": str(out) + "/{}",
        "percent-encoded slash": "..%2Fout%2F{}",
        "percent-encoded dots": "%2E%2E%2Fout%2F{}",
        "file URI": (out / "X").as_uri()[:-1] + "{}",
        "symlink": "link_{}",
    }


ROUTES = list(escape_routes(Path("/s"), Path("/o")))


def prepare(route, tmp_path, name):
    scene, out = layout(tmp_path)
    ref = escape_routes(scene, out)[route].format(name)
    if route == "symlink":
        (scene / ref).symlink_to(out / name)
    return scene, ref


# ----------------------------------------------------------------------------- glTF buffers and images


@pytest.mark.parametrize("route", ROUTES)
def test_gltf_buffer_outside_refused_unless_trusted(tmp_path, route):
    scene, ref = prepare(route, tmp_path, "tri.bin")
    p = write_gltf(scene / "s.gltf", buffer_uri=ref)
    refused(p, ref)
    got = make_scene(p, allow_outside=True)
    assert np.array_equal(got.triangles_at(0.0), TRI[None])
    # the same file inside the folder loads by default
    assert make_scene(write_gltf(scene / "in.gltf")).n_triangles == 1


@pytest.mark.parametrize("route", ROUTES)
def test_gltf_image_outside_dropped_unless_trusted(tmp_path, route):
    scene, ref = prepare(route, tmp_path, "tex.png")
    p = write_gltf(scene / "s.gltf", image_uri=ref)
    got, warned = load_quietly(p)
    assert not textured(got) and got.n_triangles == 1
    assert OUTSIDE in warned and FLAG in warned and repr(ref) in warned, warned
    got, warned = load_quietly(p, allow_outside=True)
    assert textured(got) and warned == ""
    assert tuple(got.surface.textures[0].texels[0, 0]) == (200, 40, 10)
    got, warned = load_quietly(write_gltf(scene / "in.gltf", image_uri="tex.png"))
    assert textured(got) and warned == ""


def test_load_mesh_gltf_through_trimesh(tmp_path, monkeypatch):
    """load_mesh reads a glTF with trimesh: its buffers are refused as make_scene's, and trimesh
    reads no image outside the folder (nor one that is not a regular file)."""
    from gridrt.scene import files, load_mesh, loader

    scene, out = layout(tmp_path)
    read = []
    real = files.read_regular
    # the loader's resolver (the one trimesh asks for every file) reads through its own name
    monkeypatch.setattr(loader, "read_regular", lambda p, limit=None: read.append(Path(p).name) or real(p, limit))
    assert load_mesh(write_gltf(scene / "a.gltf", image_uri="../out/tex.png")).n_triangles == 1
    assert read == ["tri.bin"]
    with pytest.raises(SceneFileError, match=f"buffer 0 '../out/tri.bin' leads {OUTSIDE}"):
        load_mesh(write_gltf(scene / "b.gltf", buffer_uri="../out/tri.bin"))
    assert load_mesh(scene / "b.gltf", allow_outside=True).n_triangles == 1


def test_gltf_other_uri_schemes_refused_even_trusted(tmp_path):
    scene, _ = layout(tmp_path)
    for uri in ("http://example.com/tri.bin", "https://example.com/tri.bin", "ftp://x/tri.bin"):
        p = write_gltf(scene / "s.gltf", buffer_uri=uri)
        for trust in (False, True):
            with pytest.raises(SceneFileError, match="only local files are read"):
                make_scene(p, allow_outside=trust)
    # data: URIs are inside the file
    data = "data:application/octet-stream;base64," + base64.b64encode(BLOB).decode()
    assert make_scene(write_gltf(scene / "d.gltf", buffer_uri=data)).n_triangles == 1


def test_gltf_declared_sizes(tmp_path):
    scene, _ = layout(tmp_path)
    # byteLength larger than the file: refused, naming both sizes
    with pytest.raises(SceneFileError, match=f"has {len(BLOB)} bytes, byteLength says 1000"):
        make_scene(write_gltf(scene / "big.gltf", byte_length=1000))
    # smaller: only byteLength bytes are read, so a view past it is refused although the file holds it
    short = write_gltf(scene / "short.gltf", byte_length=36, views=[{"buffer": 0, "byteOffset": 24, "byteLength": 36}])
    with pytest.raises(SceneFileError, match="runs past the end of its 36-byte buffer"):
        make_scene(short)
    views = [{"buffer": 0, "byteOffset": 0, "byteLength": 36}, {"buffer": 0, "byteOffset": 0, "byteLength": 24}]
    assert make_scene(write_gltf(scene / "ok.gltf", byte_length=36, views=views)).n_triangles == 1


def test_gltf_device_buffer_refused(tmp_path):
    scene, _ = layout(tmp_path)
    # trusted: still not read, being a device (it would fill the memory)
    with pytest.raises(SceneFileError, match="device, not a regular file"):
        make_scene(write_gltf(scene / "z.gltf", buffer_uri="/dev/zero"), allow_outside=True)
    (scene / "zero.bin").symlink_to("/dev/zero")
    refused(write_gltf(scene / "z2.gltf", buffer_uri="zero.bin"), "zero.bin")


FIFO_SCRIPT = r"""
import sys, warnings
from gridrt.errors import SceneFileError
from gridrt.scene import make_scene
try:
    make_scene(sys.argv[1])
except SceneFileError as e:
    print("BUFFER", e)
with warnings.catch_warnings(record=True) as w:
    warnings.simplefilter("always")
    s = make_scene(sys.argv[2])
print("TEXTURE", s.surface.textured, *[str(x.message) for x in w])
for root in sys.argv[3:]:
    try:
        make_scene(root)
    except SceneFileError as e:
        print("ROOT", e)
"""


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs on this system")
def test_fifo_buffer_and_texture_do_not_hang(tmp_path):
    scene, _ = layout(tmp_path)
    os.mkfifo(scene / "pipe.bin")
    os.mkfifo(scene / "pipe.png")
    g = write_gltf(scene / "f.gltf", buffer_uri="pipe.bin")
    o = write_obj(scene / "f.obj", "mtllib f.mtl\n", "usemtl a\n")
    (scene / "f.mtl").write_text("newmtl a\nKd 1 1 1\nmap_Kd pipe.png\n")
    roots = [scene / f"root{ext}" for ext in (".obj", ".gltf", ".aff", ".md2")]   # the scene file itself
    for p in roots:
        os.mkfifo(p)
    r = subprocess.run([sys.executable, "-c", FIFO_SCRIPT, str(g), str(o), *map(str, roots)], capture_output=True,
                       text=True, timeout=300, cwd=REPO)
    assert r.returncode == 0, r.stderr[-3000:]
    assert "BUFFER" in r.stdout and "FIFO, not a regular file" in r.stdout, r.stdout
    assert "TEXTURE False" in r.stdout and "pipe.png: is a FIFO" in r.stdout, r.stdout
    for p in roots:
        assert f"ROOT {p}: is a FIFO, not a regular file" in r.stdout, r.stdout


# ----------------------------------------------------------------------------- OBJ


def write_obj(path, head="", mtl_line="usemtl a\n", n=1):
    """An OBJ of ``n`` textured triangles side by side, material ``a``, ``b``, ... each (or ``mtl_line``)."""
    lines = [head]
    for i in range(n):
        lines.append(f"v {2 * i} 0 0\nv {2 * i + 1} 0 0\nv {2 * i} 1 0\n")
    lines.append("vt 0 0\nvt 1 0\nvt 0 1\n")
    for i in range(n):
        lines.append(mtl_line if n == 1 else f"usemtl {chr(97 + i)}\n")
        lines.append(f"f {3 * i + 1}/1 {3 * i + 2}/2 {3 * i + 3}/3\n")
    path.write_text("".join(lines))
    return path


@pytest.mark.parametrize("route", ["relative", "absolute", "symlink"])
def test_obj_mtllib_outside(tmp_path, route):
    scene, out = layout(tmp_path)
    (out / "m.mtl").write_text("newmtl a\nKd 0 1 0\n")
    ref = escape_routes(scene, out)[route].format("m.mtl")
    if route == "symlink":
        (scene / ref).symlink_to(out / "m.mtl")
    p = write_obj(scene / "a.obj", f"mtllib {ref}\n")
    got, warned = load_quietly(p)
    assert OUTSIDE in warned and FLAG in warned and repr(ref) in warned, warned
    assert np.allclose(got.surface.diffuse, [0.85, 0.78, 0.66]) if got.surface is not None else True
    got, warned = load_quietly(p, allow_outside=True)
    assert np.allclose(got.surface.diffuse, [[0, 1, 0]]) and warned == ""


@pytest.mark.parametrize("route", ["relative", "absolute", "symlink"])
def test_obj_map_kd_outside(tmp_path, route):
    scene, out = layout(tmp_path)
    ref = escape_routes(scene, out)[route].format("tex.png")
    if route == "symlink":
        (scene / ref).symlink_to(out / "tex.png")
    (scene / "m.mtl").write_text(f"newmtl a\nKd 1 1 1\nmap_Kd {ref}\n")
    p = write_obj(scene / "a.obj", "mtllib m.mtl\n")
    got, warned = load_quietly(p)
    assert not textured(got) and OUTSIDE in warned and FLAG in warned and repr(ref) in warned, warned
    got, warned = load_quietly(p, allow_outside=True)
    assert textured(got) and warned == ""


def bomb_png(path, w, h):
    """A PNG whose header says w x h pixels (a 1 x 1 image written with PIL, its IHDR rewritten)."""
    raw = bytearray(png_bytes(size=(1, 1)))
    assert raw[12:16] == b"IHDR"
    raw[16:24] = struct.pack(">II", w, h)
    raw[29:33] = struct.pack(">I", zlib.crc32(bytes(raw[12:29])))
    path.write_bytes(bytes(raw))
    return path


def test_one_bad_obj_texture_among_good_ones(tmp_path):
    scene, out = layout(tmp_path)
    (scene / "good.png").write_bytes(png_bytes((10, 250, 30)))
    (scene / "corrupt.png").write_bytes(png_bytes()[:40])
    bomb_png(scene / "bomb.png", 100_000, 100_000)   # PIL's own DecompressionBombError
    bomb_png(scene / "big.png", 8193, 8192)         # under PIL's limit, over gridrt's
    (scene / "folder.png").mkdir()
    names = ["good.png", "missing.png", "corrupt.png", "bomb.png", "big.png", "folder.png", "../out/tex.png"]
    (scene / "m.mtl").write_text("".join(f"newmtl {chr(97 + i)}\nKd 1 1 1\nmap_Kd {n}\n" for i, n in enumerate(names)))
    p = write_obj(scene / "a.obj", "mtllib m.mtl\n", n=len(names))
    got, warned = load_quietly(p)
    s = got.surface
    tex_of_triangle = s.texture[s.material]
    assert tex_of_triangle[0] >= 0 and (tex_of_triangle[1:] == -1).all(), tex_of_triangle
    assert tuple(s.textures[tex_of_triangle[0]].texels[0, 0]) == (10, 250, 30)
    lines = warned.splitlines()
    assert len(lines) == len(names) - 1, warned
    for n, words in [("missing.png", "file not found"), ("corrupt.png", "not a readable image"),
                     ("bomb.png", "image of 10,000,000,000 pixels"), ("big.png", "8193 x 8192 pixels"),
                     ("folder.png", "directory"), ("tex.png", OUTSIDE)]:
        assert any(n in ln and words in ln for ln in lines), (n, warned)
    assert sum(f"{MAX_TEXTURE_PIXELS:,} pixels" in ln for ln in lines) == 2


def test_pixel_limit_checked_before_decoding(tmp_path):
    # a header of exactly the limit is decoded (and fails for the missing data), one pixel more is not
    with pytest.warns(TextureWarning, match="not a readable image"):
        assert load_texture(bomb_png(tmp_path / "edge.png", 8192, 8192)) is None
    with pytest.warns(TextureWarning, match=f"8192 x 8193 pixels, more than the limit of {MAX_TEXTURE_PIXELS:,}"):
        assert load_texture(bomb_png(tmp_path / "over.png", 8192, 8193)) is None
    with pytest.warns(TextureWarning, match="embedded image: image of 400,000,000 pixels"):
        assert load_texture(None, data=bomb_png(tmp_path / "b.png", 20000, 20000).read_bytes()) is None


# ----------------------------------------------------------------------------- BART

AFF_HEAD = "v\nfrom 0 0 5\nat 0 0 0\nup 0 1 0\nangle 45\nhither 0.01\nresolution 16 16\n"
SQUARE = "p 4\n-1 -1 0\n1 -1 0\n1 1 0\n-1 1 0\n"


@pytest.mark.parametrize("route", ["relative", "absolute", "symlink"])
def test_bart_include_outside(tmp_path, route):
    scene, out = layout(tmp_path)
    (out / "part.aff").write_text(SQUARE)
    ref = escape_routes(scene, out)[route].format("part.aff")
    if route == "symlink":
        (scene / ref).symlink_to(out / "part.aff")
    p = scene / "s.aff"
    p.write_text(AFF_HEAD + f"i 0 {ref}\n")
    with pytest.raises(SceneFileError) as info:
        make_scene(p)
    msg = str(info.value)
    assert msg.startswith(f"{p}: line 8: include {ref!r} leads {OUTSIDE}") and FLAG in msg, msg
    assert make_scene(p, allow_outside=True).n_triangles == 2


def tt_line(name):
    return f"tt {name}\n-1 -1 0 0 1\n1 -1 0 1 1\n0 1 0 0.5 0\n"


@pytest.mark.parametrize("route", ["relative", "absolute", "symlink"])
def test_bart_texture_outside(tmp_path, route):
    scene, out = layout(tmp_path)
    (out / "t.ppm").write_bytes(b"P6 1 1 255\n" + bytes([9, 99, 199]))
    ref = escape_routes(scene, out)[route].format("t.ppm")
    if route == "symlink":
        (scene / ref).symlink_to(out / "t.ppm")
    p = scene / "s.aff"
    p.write_text(AFF_HEAD + tt_line(ref))
    got, warned = load_quietly(p)
    assert not textured(got) and OUTSIDE in warned and FLAG in warned and repr(ref) in warned, warned
    got, warned = load_quietly(p, allow_outside=True)
    assert textured(got) and warned == "" and tuple(got.surface.textures[0].texels[0, 0]) == (9, 99, 199)


def test_bart_texture_files_beside_aff_folder(tmp_path):
    """The BART layout (kitchen/aff/kitchen.aff, kitchen/TextureFiles/*.ppm) loads by default; the
    folder that holds aff/ itself does not count as inside."""
    aff, tf = tmp_path / "k" / "aff", tmp_path / "k" / "TextureFiles"
    aff.mkdir(parents=True)
    tf.mkdir()
    (tf / "t.ppm").write_bytes(b"P6 1 1 255\n" + bytes([1, 2, 3]))
    (tmp_path / "k" / "u.ppm").write_bytes(b"P6 1 1 255\n" + bytes([4, 5, 6]))
    p = aff / "s.aff"
    p.write_text(AFF_HEAD + tt_line("t.ppm"))
    got, warned = load_quietly(p)
    assert textured(got) and warned == ""
    p.write_text(AFF_HEAD + tt_line("../u.ppm"))
    got, warned = load_quietly(p)
    assert not textured(got) and OUTSIDE in warned
    # TextureFiles beside is for textures only: an include there is outside
    (tf / "part.aff").write_text(SQUARE)
    p.write_text(AFF_HEAD + "i 0 ../TextureFiles/part.aff\n")
    with pytest.raises(SceneFileError, match=OUTSIDE):
        make_scene(p)


# ----------------------------------------------------------------------------- MD2 skins, frame folders


def test_md2_skin_symlink_outside(tmp_path):
    scene, out = layout(tmp_path)
    model = scene / "sydney.md2"
    model.write_bytes((REPO / "assets" / "sydney.md2").read_bytes())
    (out / "skin.bmp").write_bytes((REPO / "assets" / "sydney.bmp").read_bytes())
    (scene / "sydney.bmp").symlink_to(out / "skin.bmp")
    got, warned = load_quietly(model)
    assert not textured(got) and "skin 'sydney.bmp'" in warned and OUTSIDE in warned and FLAG in warned, warned
    got, warned = load_quietly(model, allow_outside=True)
    assert textured(got) and warned == ""


def test_frame_folder_symlink_outside(tmp_path):
    scene, out = layout(tmp_path)
    frames = scene / "frames"
    frames.mkdir()
    write_obj(frames / "f000.obj", mtl_line="")
    write_obj(out / "f001.obj", mtl_line="")
    (frames / "f001.obj").symlink_to(out / "f001.obj")
    refused(frames, "f001.obj")
    assert make_scene(frames, allow_outside=True).n_frames == 2
    # the first frame's materials: checked against the frame folder
    (out / "m.mtl").write_text("newmtl a\nKd 0 0 1\n")
    (frames / "f001.obj").unlink()
    write_obj(frames / "f000.obj", "mtllib ../../out/m.mtl\n")
    got, warned = load_quietly(frames)
    assert OUTSIDE in warned and FLAG in warned


# ----------------------------------------------------------------------------- secrets never printed


def secret_file(tmp_path):
    token = "SECRET" + uuid.uuid4().hex
    p = tmp_path / "secrets.txt"
    p.write_text(f"{token} {token}\nKd {token}\nnewmtl {token}\nKd {token} 1 1\n")
    return p, token


def test_secrets_never_in_messages(tmp_path):
    scene, out = layout(tmp_path)
    secrets, token = secret_file(out)
    cases = []
    # BART include of a file that is no scene (trusted, so it is read): an error names file and line only
    p = scene / "inc.aff"
    p.write_text(AFF_HEAD + f"i 0 {secrets}\n")
    cases.append((p, True))
    # OBJ material library that is no MTL file, trusted
    cases.append((write_obj(scene / "m.obj", f"mtllib {secrets}\n"), True))
    # glTF whose image and buffer are the secrets
    cases.append((write_gltf(scene / "i.gltf", image_uri=str(secrets)), True))
    cases.append((write_gltf(scene / "b.gltf", buffer_uri=str(secrets), byte_length=10), True))
    # BART texture that is the secrets; and everything untrusted
    p2 = scene / "tex.aff"
    p2.write_text(AFF_HEAD + tt_line(str(secrets)))
    cases.append((p2, True))
    cases += [(c, False) for c, _ in list(cases)]
    for path, trust in cases:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            try:
                make_scene(path, allow_outside=trust)
                msg = ""
            except SceneFileError as e:
                msg = str(e)
        text = msg + "\n".join(str(w.message) for w in caught)
        assert token not in text, (path, trust, text)
    # the include did fail, naming the file and the line, not quoting it
    with pytest.raises(SceneFileError, match="line 1: unknown AFF command .text of an included file, not quoted."):
        make_scene(scene / "inc.aff", allow_outside=True)


def gridrt(*args, env=None):
    e = dict(os.environ)
    e.update(env or {})
    return subprocess.run([sys.executable, "-m", "gridrt", *map(str, args)], cwd=REPO, capture_output=True,
                          text=True, env=e, timeout=600)


def test_cli_refuses_and_trusts_and_keeps_secrets(tmp_path):
    """Through the real command line: a refused include is one line naming the flag; with the flag
    the scene renders; an include of the process's environment (trusted) prints none of it."""
    scene, out = layout(tmp_path)
    (out / "part.aff").write_text(SQUARE)
    p = scene / "s.aff"
    p.write_text(AFF_HEAD + "i 0 ../out/part.aff\n")
    args = ["dump", "--scene", p, "--frames", 1, "--size", "8x8", "--no-progress", "--out"]
    r = gridrt(*args, tmp_path / "d0")
    lines = [ln for ln in r.stderr.splitlines() if ln.strip() and not ln.startswith("Compiling")]
    assert r.returncode != 0 and "Traceback" not in r.stderr, r.stderr[-3000:]
    assert len(lines) == 1 and "include '../out/part.aff' leads outside" in lines[0] and FLAG in lines[0], lines
    r = gridrt(*args, tmp_path / "d1", FLAG)
    assert r.returncode == 0, r.stderr[-3000:]
    assert len(list((tmp_path / "d1").glob("*.png"))) == 1
    token = "SECRET" + uuid.uuid4().hex
    p.write_text(AFF_HEAD + "i 0 /proc/self/environ\n")
    r = gridrt(*args, tmp_path / "d2", FLAG, env={"GRIDRT_TEST_SECRET": token})
    assert r.returncode != 0 and "Traceback" not in r.stderr, r.stderr[-3000:]
    assert "/proc/self/environ" in r.stderr and token not in r.stdout + r.stderr, r.stderr[-3000:]


def test_scene_spec_carries_the_trust(tmp_path):
    scene, out = layout(tmp_path)
    p = write_gltf(scene / "s.gltf", buffer_uri="../out/tri.bin")
    with pytest.raises(SceneFileError, match=OUTSIDE):
        SceneSpec(source=str(p)).make()
    spec = SceneSpec(source=str(p), allow_outside=True)
    assert spec.options() == {"allow_outside": True}
    assert spec.make().n_triangles == 1


# ----------------------------------------------------------------------------- lights


def test_huge_light_saturates(tmp_path):
    """A light of colour 1e38 (finite) lights the square to full white, with and without shadows:
    expected colour min(1, A + D * E * n.l) = 1 for every lit pixel."""
    p = tmp_path / "l.aff"
    p.write_text(AFF_HEAD + "l 0 0 10 1e38 1e38 1e38\nf 0.5 0.5 0.5 1 0 0 0 1\n" + SQUARE)
    sc = make_scene(p)
    tris = sc.triangles_at(0.0)
    cam = Camera(eye=(0.0, 0.0, 5.0), target=(0.0, 0.0, 0.0), fov=45.0)
    g = GridBuilder().build(tris, GridParams())
    for shadows in (False, True):
        res = Renderer().render(g, tris, cam, RenderParams(width=16, height=16, shading="material", shadows=shadows),
                                looks=Looks(tris, sc.surface, None, sc.lights_at(0.0)))
        hit = res.tri >= 0
        assert hit.sum() > 50
        assert (res.image[hit][:, :3] == 255).all(), (shadows, np.unique(res.image[hit][:, :3], axis=0))


def test_cli_flag_and_viewer_state_carry_the_trust():
    import argparse

    from gridrt.app import cli
    from gridrt.app.viewer.state import ViewerState
    from gridrt.frame import FrameSpec

    p = argparse.ArgumentParser()
    cli.add_scene_args(p)
    assert cli.scene_spec(p.parse_args(["--scene", "x.gltf"])).allow_outside is False
    spec = cli.scene_spec(p.parse_args(["--scene", "x.gltf", FLAG]))
    assert spec.allow_outside is True
    # the viewer's file box starts trusted when the command line's scene is (view --allow-outside-refs)
    assert ViewerState(spec=FrameSpec(scene=spec)).file_allow_outside is True
    assert ViewerState(spec=FrameSpec(scene=spec.replace(allow_outside=False))).file_allow_outside is False


class _FakeGlfw:
    """Just what InputHandler calls at set-up (callbacks are recorded, none fire)."""

    PRESS, REPEAT, RELEASE = 1, 2, 0

    def get_cursor_pos(self, window):
        return (0.0, 0.0)

    def __getattr__(self, name):
        if name.startswith("set_") and name.endswith("_callback"):
            return lambda window, fn: None
        raise AttributeError(name)


@pytest.mark.parametrize("trusted", [False, True])
def test_a_file_dropped_on_the_viewer_takes_the_file_box_trust(trusted):
    from types import SimpleNamespace

    from gridrt.app.viewer.input import InputHandler
    from gridrt.app.viewer.state import ViewerState

    st = ViewerState()
    st.file_allow_outside = trusted
    h = InputHandler(_FakeGlfw(), None, st, ["serial"])
    h._on_drop(None, ["/somewhere/scene.gltf"])
    h.process(SimpleNamespace(want_capture_mouse=False, want_capture_keyboard=True), 0.0)
    assert st.scene_request.source == "/somewhere/scene.gltf"
    assert st.scene_request.allow_outside is trusted
