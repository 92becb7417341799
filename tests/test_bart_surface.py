"""BART (AFF) scenes' looks: materials, textures, per-corner uv and normals, lights.

Independent references: small AFF files and PPM images written here with hand-computed colours,
texture coordinates, texels and normals; rotations and inverse transposes computed here with numpy
(Rodrigues' formula, numpy.linalg.inv); shading normals checked against the geometric normals of
``triangles_at`` (a triangle whose file normals are its own face normal must keep them parallel
under any transform); and, on the real scenes, counts and values read from the .aff text by the
small scanner below (materials in use, textured triangles, referenced images, lights, tpa keys).
"""

import re
import warnings
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

import gridrt  # noqa: F401  (sets numba's thread count before numba loads)
from gridrt.errors import SceneFileError
from gridrt.scene import BartAnimation
from gridrt.scene.bart import AMBIENT_DEFAULT, DEFAULT_DIFFUSE
from gridrt.scene.surface import FALLOFF_NONE, LIGHT_POINT, TextureWarning

from conftest import NO_SHARED_DATA, SHARED_DATA, data_path
from helpers.geometry import rodrigues

no_texture_warnings = pytest.mark.filterwarnings("ignore::gridrt.scene.surface.TextureWarning")


def write(path, text):
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


def write_ppm(path, texels):
    """A binary PPM (P6) of (H, W, 3) uint8 texels, row 0 first."""
    h, w, _ = texels.shape
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(f"P6\n# written by the test\n{w} {h}\n255\n".encode() + np.ascontiguousarray(texels).tobytes())
    return path


def unit(v):
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def face_normals(tris):
    t = np.asarray(tris, dtype=np.float64)
    return unit(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]))


def colours(s):
    """(diffuse, ambient) per triangle, float64."""
    m = s.surface.material
    return s.surface.diffuse[m].astype(np.float64), s.surface.ambient[m].astype(np.float64)


TRI = "p 3  0 0 {z}  1 0 {z}  0 1 {z}\n"
#: the rotation keys of a transform named spin: a quarter turn about y a second, -1 s to 3 s
SPIN_KEYS = """k spin
{
  rot 5
  -1  0 1 0 -90  0 0 0
   0  0 1 0   0  0 0 0
   1  0 1 0  90  0 0 0
   2  0 1 0 180  0 0 0
   3  0 1 0 270  0 0 0
}
"""


def test_defaults_match_gridrt_shading():
    from gridrt.trace.shade import ALBEDO, AMBIENT

    assert DEFAULT_DIFFUSE == tuple(ALBEDO) and AMBIENT_DEFAULT == AMBIENT


# ----------------------------------------------------------------------------- materials

MATERIALS = (
    TRI.format(z=0)                                     # 0: before any material
    + "f 0.5 0.4 0.2  0.8 0.1 10 0 1\n"                 # NFF: diffuse 0.8 * (0.5, 0.4, 0.2)
    + TRI.format(z=1)                                   # 1
    + "xs 1 1 1  0 0 1 0  0 0 0\n{\n"
    + "  fm 0.1 0.2 0.3  0.6 0.5 0.4  0.9 0.9 0.9  20 0 1\n"
    + "  " + TRI.format(z=2)                            # 2
    + "}\n"
    + TRI.format(z=3)                                   # 3: the fm still holds after the block
    + "i 0 part.aff\n"                                  # 4: part's triangle, before its f
    + TRI.format(z=5)                                   # 5: the f set in part.aff holds here
)
PART = TRI.format(z=4) + "f 1 1 1  0.5 0 0 0 0\n"

ALBEDO = np.array([0.85, 0.78, 0.66])
F_DIFFUSE = np.array([0.4, 0.32, 0.16])
FM_AMBIENT, FM_DIFFUSE = np.array([0.1, 0.2, 0.3]), np.array([0.6, 0.5, 0.4])
PART_DIFFUSE = np.array([0.5, 0.5, 0.5])


def test_materials_follow_the_file_as_one_global_state(tmp_path):
    write(tmp_path / "part.aff", PART)
    s = BartAnimation(write(tmp_path / "scene.aff", MATERIALS))
    diffuse, ambient = colours(s)
    want_d = np.array([ALBEDO, F_DIFFUSE, FM_DIFFUSE, FM_DIFFUSE, FM_DIFFUSE, PART_DIFFUSE])
    want_a = np.array([0.15 * ALBEDO, 0.15 * F_DIFFUSE, FM_AMBIENT, FM_AMBIENT, FM_AMBIENT, 0.15 * PART_DIFFUSE])
    np.testing.assert_allclose(diffuse, want_d, rtol=1e-6)
    np.testing.assert_allclose(ambient, want_a, rtol=1e-6)
    assert s.surface.n_materials == 4
    assert not s.surface.textured and s.surface.uv is None and s.surface.normals is None
    assert s.normals_at(1.0) is None
    # the scene's ambient light multiplies every material's ambient colour, wherever it stands
    s = BartAnimation(write(tmp_path / "lit.aff", MATERIALS + "am 2 1 0.5\n"))
    diffuse, ambient = colours(s)
    np.testing.assert_allclose(diffuse, want_d, rtol=1e-6)
    np.testing.assert_allclose(ambient, want_a * [2, 1, 0.5], rtol=1e-6)


def test_identical_materials_share_a_row(tmp_path):
    fm = "fm 0.1 0.1 0.1  0.5 0.25 0.125  0 0 0  0 0 0\n"
    write(tmp_path / "a.aff", fm + TRI.format(z=1))
    text = fm + TRI.format(z=0) + "i 0 a.aff\nfm 0.10 0.1 0.1  0.50 0.25 0.125  1 1 1  50 0.5 1.5\n" + TRI.format(z=2)
    s = BartAnimation(write(tmp_path / "scene.aff", text))
    assert s.surface.n_materials == 1 and (s.surface.material == 0).all()


# ----------------------------------------------------------------------------- textures

T_TEXELS = np.array([[[255, 0, 0], [0, 255, 0], [0, 0, 255]],
                     [[10, 20, 30], [40, 50, 60], [70, 80, 90]]], dtype=np.uint8)  # 2 rows of 3
HERE_TEXELS = [[1, 2, 3, 4, 5, 6], [7, 8, 9, 250, 251, 252]]  # 2 x 2, as an ASCII PPM (P3)

TEXTURED = """\
fm 0.2 0.2 0.2  0.7 0.7 0.7  0 0 0  0 0 0
m
 vertices 4   0 0 0  2 0 0  2 1 0  0 1 0
 texturecoords 3 t.ppm
   0.0 0.0
   1.5 0.25
   0.5 1.0
 triangles 2
   0 1 2  2 0 1
   0 2 3  1 1 0
i 0 sub/part.aff
"""
TEXTURED_PART = """\
tt here.ppm  0 0 1  0.25 0.75   1 0 1  1 0.75   0 1 1  0.25 0
m vertices 3  0 0 2  1 0 2  0 1 2  texturecoords 1 t.ppm  0.5 0.5  triangles 1  0 1 2  0 0 0
"""


def write_textured(tmp_path):
    """The BART distribution's layout: aff/ (root and a subfolder) beside TextureFiles/; one
    image beside the root file."""
    write_ppm(tmp_path / "TextureFiles" / "t.ppm", T_TEXELS)
    (tmp_path / "aff").mkdir()
    ascii_rows = "\n".join(" ".join(map(str, r)) for r in HERE_TEXELS)
    (tmp_path / "aff" / "here.ppm").write_text("P3\n2 2\n255\n" + ascii_rows)
    write(tmp_path / "aff" / "sub" / "part.aff", TEXTURED_PART)
    return write(tmp_path / "aff" / "scene.aff", TEXTURED)


def test_mesh_and_tt_textures(tmp_path):
    with warnings.catch_warnings():
        warnings.simplefilter("error", TextureWarning)
        s = BartAnimation(write_textured(tmp_path))
    su = s.surface
    assert su.n_triangles == 4 and len(su.textures) == 2  # t.ppm read once for both files
    tex = su.texture[su.material]
    assert (tex >= 0).all() and tex[0] == tex[1] == tex[3] != tex[2]
    t, here = su.textures[tex[0]], su.textures[tex[2]]
    assert Path(t.name).name == "t.ppm" and Path(here.name).name == "here.ppm"
    np.testing.assert_array_equal(t.texels, T_TEXELS)
    np.testing.assert_array_equal(here.texels, np.array(HERE_TEXELS, dtype=np.uint8).reshape(2, 2, 3))
    assert t.wrap == ("repeat", "repeat")
    # (u, v) as in the file, by each triangle's texture coordinate indices
    want = [[(0.5, 1.0), (0.0, 0.0), (1.5, 0.25)],
            [(1.5, 0.25), (1.5, 0.25), (0.0, 0.0)],
            [(0.25, 0.75), (1.0, 0.75), (0.25, 0.0)],
            [(0.5, 0.5), (0.5, 0.5), (0.5, 0.5)]]
    np.testing.assert_allclose(su.uv, want, atol=0)
    np.testing.assert_allclose(su.diffuse[su.material], 0.7, rtol=1e-6)
    assert su.n_materials == 2


def test_missing_and_broken_textures_warn_and_the_scene_loads(tmp_path):
    (tmp_path / "bad.ppm").write_bytes(b"P6 this is not an image")
    text = ("m vertices 3  0 0 0  1 0 0  0 1 0  texturecoords 1 nope.ppm  0.5 0.5  triangles 1  0 1 2  0 0 0\n"
            "tt bad.ppm  0 0 1  0 0   1 0 1  1 0   0 1 1  0 1\n")
    with pytest.warns(TextureWarning) as caught:
        s = BartAnimation(write(tmp_path / "scene.aff", text))
    messages = [str(w.message) for w in caught]
    assert any("nope.ppm" in m and "file not found" in m and "scene.aff" in m for m in messages), messages
    assert any("bad.ppm" in m and "not a readable image" in m for m in messages), messages
    assert s.n_triangles == 2 and not s.surface.textured
    np.testing.assert_allclose(s.surface.uv[1], [(0, 0), (1, 0), (0, 1)])
    assert np.isfinite(s.triangles_at(0.0)).all()


# ----------------------------------------------------------------------------- normals

SPIN = """\
a 0 4 41
x spin
{
  m
   vertices 3   0 0 0  1 0 0  0 1 0
   normals 2    0 0 2  1 0 0
   triangles 1  0 1 2  0 1 0
}
""" + SPIN_KEYS


def test_mesh_normals_turn_with_their_transform(tmp_path):
    s = BartAnimation(write(tmp_path / "spin.aff", SPIN))
    rest = np.array([[0, 0, 1], [1, 0, 0], [0, 0, 1]], dtype=np.float64)  # unit, by the normal indices
    np.testing.assert_allclose(s.surface.normals[0], rest, atol=1e-7)
    # at the key times the rotation is the key's; the keys are coaxial and evenly spaced, so the
    # squad between them turns at a constant rate (90 degrees a second)
    for t, deg in ((0.0, 0), (1.0, 90), (2.0, 180), (0.5, 45), (1.3, 117)):
        np.testing.assert_allclose(s.normals_at(t)[0], (rodrigues([0, 1, 0], deg) @ rest.T).T, atol=1e-6)
    # pure in t, and out= keeps frames apart
    a = s.normals_at(1.3).copy()
    s.normals_at(0.2)
    np.testing.assert_array_equal(s.normals_at(1.3), a)
    buf = np.empty((1, 3, 3), np.float32)
    assert s.normals_at(1.3, out=buf) is buf
    np.testing.assert_array_equal(buf, a)
    np.testing.assert_allclose(np.linalg.norm(a, axis=2), 1.0, atol=1e-6)


# a triangle whose file normals are its face normal, under a non-uniform static scale and a
# rotating, non-uniformly scaling animated transform: its shading normals must stay its face normal
SQUASH = """\
a 0 4 41
xs 1 3 1  0 0 1 30  0 0 0
{
  x squash
  {
    m
     vertices 3   0 0 0  1 0 1  0 1 1
     normals 1    -1 -1 1
     triangles 1  0 1 2  0 0 0
  }
}
k squash
{
  scale 4
  -1  1 1 1    0 0 0
   0  1 1 1    0 0 0
   2  2 0.5 1  0 0 0
   4  1 1 3    0 0 0
  rot 4
  -1  1 0 0 0    0 0 0
   0  1 0 0 0    0 0 0
   2  1 1 0 60   0 0 0
   4  1 1 0 120  0 0 0
}
"""


def test_normals_follow_the_inverse_transpose(tmp_path):
    s = BartAnimation(write(tmp_path / "squash.aff", SQUASH))
    assert not s.static_mask[0]
    for t in (0.0, 0.7, 1.3, 2.0, 3.1):
        g = face_normals(s.triangles_at(t))[0]
        np.testing.assert_allclose(s.normals_at(t)[0], [g, g, g], atol=2e-6)
    # a mirroring static transform: the normal is turned by inv(M).T (it stays on the same side of
    # the surface as in the file)
    m = rodrigues([0, 0, 1], 40) @ np.diag([-1.0, 2.0, 1.0])  # T * R * S
    text = "xs -1 2 1  0 0 1 40  0 0 0\n{\n pp 3  0 0 0  1 0 0   1 0 0  1 1 0   0 1 0  0 1 0\n}\n"
    s = BartAnimation(write(tmp_path / "mirror.aff", text))
    want = unit((np.linalg.inv(m).T @ np.array([[1.0, 0, 0], [1, 1, 0], [0, 1, 0]]).T).T)
    np.testing.assert_allclose(s.surface.normals[0], want, atol=1e-6)
    assert s.static and s.normals_at(3.0) is s.surface.normals


def test_patch_normals(tmp_path):
    write_ppm(tmp_path / "t.ppm", T_TEXELS)
    text = ("pp 4\n  0 0 0  0 0 1\n  1 0 0  0 1 1\n  1 1 0  2 0 0\n  0 1 0  0 0 3\n"
            "ttp t.ppm\n  0 0 1  0 0 2  0.1 0.2\n  1 0 1  0 2 0  0.3 0.4\n  0 1 1  2 0 0  0.5 0.6\n"
            + TRI.format(z=3))
    s = BartAnimation(write(tmp_path / "patches.aff", text))
    n = unit([[0, 0, 1], [0, 1, 1], [1, 0, 0], [0, 0, 1]])
    np.testing.assert_allclose(s.surface.normals[:3], [n[[0, 1, 2]], n[[0, 2, 3]], np.eye(3)[[2, 1, 0]]], atol=1e-6)
    np.testing.assert_array_equal(s.surface.normals[3], 0.0)  # no normals in the file: the geometric one
    np.testing.assert_allclose(s.surface.uv[2], [(0.1, 0.2), (0.3, 0.4), (0.5, 0.6)], atol=1e-7)
    assert s.surface.texture[s.surface.material].tolist() == [-1, -1, 0, -1]


TPA = """\
a 0 4 41
fm 0.1 0.1 0.1  0.9 0.1 0.1  0 0 0  0 0 0
x spin
{
tpa 3
 0
  0 0 0  0 0 1
  1 0 0  0 0 2
  0 1 0  1 0 0
 1
  0 0 0  0 1 0
  1 0 0  0 0 1
  0 1 0  0 3 0
 3
  0 0 1  1 0 0
  1 0 1  0 0 -1
  0 1 1  0 0 5
}
fm 0.1 0.1 0.1  0.1 0.9 0.1  0 0 0  0 0 0
m vertices 3  5 5 5  6 5 5  5 6 5  normals 1  0 1 0  triangles 1  0 1 2  0 0 0
""" + SPIN_KEYS
TPA_KEYS = np.array([[[0, 0, 1], [0, 0, 2], [1, 0, 0]],
                     [[0, 1, 0], [0, 0, 1], [0, 3, 0]],
                     [[1, 0, 0], [0, 0, -1], [0, 0, 5]]], dtype=np.float64)


def test_tpa_normals_interpolate_like_their_positions(tmp_path):
    s = BartAnimation(write(tmp_path / "tpa.aff", TPA))
    # triangles_at puts the tpa triangle after the mesh (read after it in the file): the surface follows
    tris = s.triangles_at(0.0)
    np.testing.assert_allclose(tris[1], [[0, 0, 0], [1, 0, 0], [0, 1, 0]], atol=1e-7)
    np.testing.assert_allclose(s.surface.diffuse[s.surface.material], [[0.1, 0.9, 0.1], [0.9, 0.1, 0.1]], rtol=1e-6)
    np.testing.assert_allclose(s.normals_at(0.0)[0], [[0, 1, 0]] * 3, atol=1e-7)  # the mesh, not turned at t = 0
    np.testing.assert_allclose(s.surface.normals[1], unit(TPA_KEYS[0]), atol=1e-7)
    r90 = rodrigues([0, 1, 0], 90)
    np.testing.assert_allclose(s.normals_at(1.0)[1], (r90 @ unit(TPA_KEYS[1]).T).T, atol=1e-6)  # key 1 turned 90 deg
    np.testing.assert_allclose(s.normals_at(1.0)[0], [r90 @ [0, 1, 0]] * 3, atol=1e-6)
    # between keys: the file's normals interpolated linearly (their lengths count), then normalized;
    # the coaxial evenly spaced rotation keys turn at 90 degrees a second
    half = unit(0.5 * (TPA_KEYS[0] + TPA_KEYS[1]))
    np.testing.assert_allclose(s.normals_at(0.5)[1], (rodrigues([0, 1, 0], 45) @ half.T).T, atol=1e-6)
    # at t = 2 corner 1's normals cancel: a zero normal (the geometric one is used)
    n2 = s.normals_at(2.0)[1]
    np.testing.assert_array_equal(n2[1], 0.0)
    r180 = rodrigues([0, 1, 0], 180)
    np.testing.assert_allclose(n2[[0, 2]], (r180 @ unit(0.5 * (TPA_KEYS[1] + TPA_KEYS[2])[[0, 2]]).T).T, atol=1e-6)
    # after the last key (t = 3): its normals, under the rotation clamped at its last inner key (180)
    np.testing.assert_allclose(s.normals_at(3.5)[1], (r180 @ unit(TPA_KEYS[2]).T).T, atol=1e-6)


# ----------------------------------------------------------------------------- lights

LIGHTS = """\
a 0 4 41
l 1 2 3
l 4 5 6  0.1 0.2 0.3
xs 2 2 2  0 0 1 30  5 5 5
{
  l 7 8 9
  p 3  0 0 0  1 0 0  0 1 0
}
la lamp  10 10 10  0.5 0.5 0.5
la still 9 9 9
k lamp
{
  transl 4
  -1  0 0 0  0 0 0
   0  1 0 0  0 0 0
   2  3 2 0  0 0 0
   4  5 0 0  0 0 0
}
"""


def test_lights(tmp_path):
    s = BartAnimation(write(tmp_path / "lights.aff", LIGHTS))
    row = lambda x, y, z, r=1.0, g=1.0, b=1.0: [LIGHT_POINT, x, y, z, r, g, b, FALLOFF_NONE]  # noqa: E731
    want = np.array([row(1, 2, 3), row(4, 5, 6, 0.1, 0.2, 0.3), row(7, 8, 9), row(1, 0, 0, 0.5, 0.5, 0.5),
                     row(9, 9, 9)])
    got = s.lights_at(0.0)  # the lamp at its transl key (its keys place it, as the camera's place the eye)
    assert got.dtype == np.float64 and got.shape == (5, 8) and not got.flags.writeable
    np.testing.assert_allclose(got, want, atol=1e-12)
    want[3, 1:4] = [3, 2, 0]  # the lamp's key at t = 2
    np.testing.assert_allclose(s.lights_at(2.0), want, atol=1e-12)
    assert s.lights_at(0.7)[3, 1] != 1.0 and (s.lights_at(0.7)[[0, 1, 2, 4]] == want[[0, 1, 2, 4]]).all()
    plain = BartAnimation(write(tmp_path / "dark.aff", TRI.format(z=0)))
    assert plain.lights_at(1.0).shape == (0, 8)


# ----------------------------------------------------------------------------- bad input


@pytest.mark.parametrize("text,words", [
    ("fm 0.1 0.2 0.3 0.4\n" + TRI.format(z=0), ["fill material (fm)", "expected a number", "'p'", "line 2"]),
    (TRI.format(z=0) + "f 1 1 1 0.5\n", ["unexpected end of file", "fill material (f)"]),
    ("fm 0.1 0.2 0.3  -0.6 0.5 0.4  0 0 0  0 0 0\n" + TRI.format(z=0), ["fill material (fm) diffuse", "'-0.6'",
                                                                         "not a colour value", "line 1"]),
    ("am 1 1\n" + TRI.format(z=0), ["ambient light (am)", "expected a number"]),
    ("l 0 0 0  1 -1 1\n" + TRI.format(z=0), ["light colour", "'-1'"]),
    ("m vertices 3  0 0 0  1 0 0  0 1 0\n normals 2  0 0 1\n triangles 1  0 1 2  0 0 0\n",
     ["mesh normals", "expected a number", "'triangles'", "line 3"]),
    ("m vertices 3  0 0 0  1 0 0  0 1 0\n normals 1  0 0 1\n triangles 1\n 0 1 2  0 1 0\n",
     ["mesh triangle 0", "normal index out of range for 1 normals", "line 4"]),
    ("m vertices 3  0 0 0  1 0 0  0 1 0\n texturecoords 2 t.ppm  0 0  1 1\n triangles 1\n 0 1 2  0 1 2\n",
     ["mesh triangle 0", "texture coordinate index out of range for 2 texture coordinates"]),
    ("m vertices 3  0 0 0  1 0 0  0 1 0\n normals 1  0 0 1\n texturecoords 1 t.ppm  0 0\n triangles 1\n"
     " 0 1 2  0 0 0  0 0 0.5\n", ["texture coordinate index out of range"]),
    ("tt t.ppm  0 0 0  0 0   1 0 0  1 0   0 1 0\n", ["textured triangle (tt)", "unexpected end of file"]),
])
def test_bad_looks_name_the_file_and_problem(tmp_path, text, words):
    for where in ("root", "part"):  # in the root file, and in an included one
        part = write(tmp_path / "part.aff", text)
        root = write(tmp_path / "scene.aff", text if where == "root" else TRI.format(z=9) + "i 0 part.aff\n")
        with pytest.raises(SceneFileError) as e, warnings.catch_warnings():
            warnings.simplefilter("ignore", TextureWarning)
            BartAnimation(root)
        assert e.value.path == str(root if where == "root" else part)
        for w in words:
            if where == "part" and w.startswith("'"):  # an included file's text is never quoted
                assert w not in e.value.problem and "not quoted" in e.value.problem, (w, e.value.problem)
            else:
                assert w in e.value.problem, (w, e.value.problem)


# ----------------------------------------------------------------------------- real scenes


def strip_comments(text):
    return "\n".join(re.split(r"[#%]", line, maxsplit=1)[0] for line in text.splitlines())


def scan_looks(path, state=None):
    """What an .aff file and its includes (detail level 0) draw with, by a plain token scan: the
    current material (its f/fm numbers) as each piece of geometry is read, as one global state.
    Returns state: "pieces" [(material numbers, texture name or None, triangle count)], "am",
    "lights" [the l lines' numbers] and "textures" {name: folder of the file that names it}."""
    state = state or {"mat": None, "pieces": [], "am": None, "lights": [], "textures": {}}
    toks = strip_comments(path.read_text(encoding="latin-1")).split()
    i = 0
    while i < len(toks):
        t = toks[i]
        if t == "i":
            if toks[i + 1] == "0":
                scan_looks(path.parent / toks[i + 2], state)
            i += 3
        elif t in ("f", "fm"):
            n = 8 if t == "f" else 12
            state["mat"] = (t, tuple(float(x) for x in toks[i + 1:i + 1 + n]))
            i += 1 + n
        elif t == "am":
            state["am"] = tuple(float(x) for x in toks[i + 1:i + 4])
            i += 4
        elif t == "l":
            j = i + 1
            while j < len(toks) and re.fullmatch(r"[-+0-9.eE]+", toks[j]):
                j += 1
            state["lights"].append([float(x) for x in toks[i + 1:j]])
            i = j
        elif t == "m":
            j = toks.index("triangles", i)
            tex = None
            if "texturecoords" in toks[i:j]:
                tex = toks[i + toks[i:j].index("texturecoords") + 2]
                state["textures"][tex] = path.parent
            state["pieces"].append((state["mat"], tex, int(toks[j + 1])))
            i = j + 2
        elif t in ("p", "pp"):
            state["pieces"].append((state["mat"], None, int(toks[i + 1]) - 2))
            i += 2
        elif t in ("tt", "ttp"):
            state["pieces"].append((state["mat"], toks[i + 1], 1))
            state["textures"][toks[i + 1]] = path.parent
            i += 2
        elif t == "tpa":
            state["pieces"].append((state["mat"], None, 1))
            i += 2
        else:
            i += 1
    return state


def expected_colours(mat, am):
    """(diffuse, ambient) of a scanned material, float32 tuples, as the BART grammar defines them."""
    am = np.array(am if am is not None else (1.0, 1.0, 1.0))
    if mat is None:
        d = np.array([0.85, 0.78, 0.66])
        a = 0.15 * d
    elif mat[0] == "f":
        d = mat[1][3] * np.array(mat[1][:3])
        a = 0.15 * d
    else:
        a, d = np.array(mat[1][:3]), np.array(mat[1][3:6])
    return tuple(np.float32(d).tolist()), tuple(np.float32(a * am).tolist())


def ppm_size(path):
    """(width, height) from a PPM header."""
    head = re.sub(rb"#[^\n]*\n", b"\n", path.read_bytes()[:200]).split()
    return int(head[1]), int(head[2])


@pytest.fixture(scope="module")
def kitchen():
    p = data_path("animated/bart/kitchen/aff/kitchen.aff")
    with warnings.catch_warnings():
        warnings.simplefilter("error", TextureWarning)  # every image the kitchen names is in the data set
        return p, BartAnimation(p)


def test_kitchen_materials_textures_and_lights(kitchen):
    p, s = kitchen
    su = s.surface
    look = scan_looks(p)
    assert sum(n for _, _, n in look["pieces"]) == s.n_triangles
    want = Counter()
    for mat, tex, n in look["pieces"]:
        want[expected_colours(mat, look["am"]) + (tex,)] += n
    names = [Path(t.name).name for t in su.textures]
    got = Counter()
    for m, n in zip(*np.unique(su.material, return_counts=True)):
        tex = names[su.texture[m]] if su.texture[m] >= 0 else None
        got[(tuple(su.diffuse[m].tolist()), tuple(su.ambient[m].tolist()), tex)] += int(n)
    assert got == want  # the same materials, each on as many triangles
    assert su.n_materials == len(want)
    # every image named is loaded, once, at its size
    assert sorted(names) == sorted(look["textures"])
    root = p.parent.parent
    for t in su.textures:
        w, h = ppm_size(root / "TextureFiles" / Path(t.name).name)
        assert t.texels.shape == (h, w, 3)
    assert int((su.texture[su.material] >= 0).sum()) == sum(n for _, tex, n in look["pieces"] if tex)
    # the 6 l lines of kitchen.aff (the included files have none)
    lights = [row for row in look["lights"]]
    assert len(lights) == 6
    want_l = np.array([[LIGHT_POINT, *row[:3], *row[3:6], FALLOFF_NONE] for row in lights])
    np.testing.assert_allclose(s.lights_at(0.0), want_l, atol=0)
    np.testing.assert_allclose(s.lights_at(7.3), want_l, atol=0)


def check_normals_face_their_triangles(s, times):
    """Wherever the file has normals, they lie on the side of the face its winding gives, at any t
    (the scenes' normals are smooth versions of their face normals)."""
    has = (s.surface.normals != 0).any(axis=2)
    assert has.mean() > 0.5
    for t in times:
        tris = s.triangles_at(t).astype(np.float64)
        area2 = np.linalg.norm(np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]), axis=1)
        ok = has & (area2 > 1e-12)[:, None]
        g = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]) / np.maximum(area2, 1e-300)[:, None]
        d = np.einsum("fj,fcj->fc", g, s.normals_at(t))
        assert (d[ok] > 0).mean() > 0.99, (t, (d[ok] > 0).mean())
        np.testing.assert_allclose(np.linalg.norm(s.normals_at(t)[has], axis=1), 1.0, atol=1e-6)


def test_kitchen_normals_face_their_triangles(kitchen):
    _, s = kitchen
    assert s.surface.normals is not None
    check_normals_face_their_triangles(s, (0.0, 0.41 * s.duration, 0.77 * s.duration))
    np.testing.assert_array_equal(s.normals_at(0.0), s.surface.normals)


@no_texture_warnings
def test_museum_tpa_normals_at_their_keys():
    p = data_path("animated/bart/museum/aff/museum5.aff")  # assets/ ships it (without its images)
    s = BartAnimation(p)
    start = s.time_range[0]
    toks = strip_comments((p.parent / "animart5.aff").read_text(encoding="latin-1")).split()
    firsts = [i for i, t in enumerate(toks) if t == "tpa"][:3]
    checked = 0
    for i in firsts:
        n = int(toks[i + 1])
        rec = np.array(toks[i + 2:i + 2 + 19 * n], dtype=np.float64).reshape(n, 19)
        times, corners = rec[:, 0], rec[:, 1:].reshape(n, 3, 6)
        tris = s.triangles_at(times[0] - start).astype(np.float64)
        f = np.flatnonzero(np.abs(tris - corners[0, :, :3]).max(axis=(1, 2)) < 1e-6)
        assert len(f) == 1
        for k in range(n):
            if start <= times[k] < s.time_range[1]:
                np.testing.assert_allclose(s.normals_at(times[k] - start)[f[0]], unit(corners[k, :, 3:]), atol=1e-6)
                checked += 1
    assert checked >= 6
    check_normals_face_their_triangles(s, (0.0, 0.5 * s.duration))


def check_textures_found(rel):
    """The data set's copy of a scene: every image it names is found (in TextureFiles/ beside
    aff/) and read once, and its textured triangles are those of the meshes and tt lines that name one."""
    p = SHARED_DATA / "animated/bart" / rel
    if NO_SHARED_DATA or not p.is_file():
        pytest.skip(f"the development data set's {rel} (with its images) is not available")
    look = scan_looks(p)
    with warnings.catch_warnings():
        warnings.simplefilter("error", TextureWarning)
        s = BartAnimation(p)
    assert sorted(Path(t.name).name for t in s.surface.textures) == sorted(look["textures"])
    assert int((s.surface.texture[s.surface.material] >= 0).sum()) == sum(n for _, t, n in look["pieces"] if t)


def test_museum_textures_found():
    check_textures_found("museum/aff/museum5.aff")


def test_robots_textures_found():
    check_textures_found("robots/aff/Robot.aff")
