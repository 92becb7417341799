"""glTF looks: materials, base colour textures, uv, COLOR_0, NORMAL (posed with the scene) and
KHR_lights_punctual lights (gridrt.scene.gltf -> gridrt.scene.surface).

References are independent of the code under test:

* small glTF files (JSON + .bin, and .glb) are written here byte by byte, with a checkerboard PNG
  written by Pillow, embedded in a buffer view, as a data: URI and as a file beside the scene; the
  expected surface is what was written (colours, uv, texels, wrap modes);
* posed normals are computed here in numpy from the transforms the files animate (rotation about a
  fixed axis, so slerp's angle grows linearly with time; linear translations and morph weights):
  the inverse transpose of a node's linear part, and for skins the blend
  ``normalize(sum_j w_j * L_j^-T n)`` that gridrt.scene.gltf documents;
* the real files are read with Pillow and numpy from their own bytes (CesiumMan's image and uv),
  and their posed normals are checked against the posed triangles' own geometry.
"""

import base64
import importlib.util
import io
import json
import math
import struct
import warnings

import numpy as np
import pytest
from PIL import Image

import gridrt  # noqa: F401  (sets numba's thread count before numba loads)
from gridrt.errors import SceneFileError
from gridrt.scene import GltfAnimation, StaticMesh, make_scene
from gridrt.scene.surface import (FALLOFF_INVERSE_SQUARE, FALLOFF_NONE, LIGHT_DIRECTIONAL, LIGHT_POINT,
                                  TextureWarning)

from conftest import data_path

HAVE_DRACO = importlib.util.find_spec("DracoPy") is not None
FLOAT, UBYTE, USHORT, UINT = 5126, 5121, 5123, 5125
_DT = {FLOAT: "<f4", UBYTE: "u1", USHORT: "<u2", UINT: "<u4"}
_NC = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT4": 16}
AMBIENT = 0.15  # gridrt.scene.gltf.AMBIENT_FRACTION, as documented


# ----------------------------------------------------------------------------- a raw glTF writer


class Writer:
    """Builds a glTF 2.0 JSON tree and one binary buffer; saves .gltf + .bin or .glb."""

    def __init__(self):
        self.blob = bytearray()
        self.t = {"asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": []}], "nodes": [], "meshes": [],
                  "accessors": [], "bufferViews": [], "buffers": []}

    def add(self, key, item):
        self.t.setdefault(key, []).append(item)
        return len(self.t[key]) - 1

    def view(self, data):
        while len(self.blob) % 4:
            self.blob.append(0)
        off = len(self.blob)
        self.blob.extend(data)
        return self.add("bufferViews", {"buffer": 0, "byteOffset": off, "byteLength": len(data)})

    def acc(self, arr, ctype=FLOAT, typ="VEC3", normalized=False):
        a = np.ascontiguousarray(np.asarray(arr), dtype=_DT[ctype])
        acc = {"bufferView": self.view(a.tobytes()), "componentType": ctype, "count": a.size // _NC[typ],
               "type": typ}
        if normalized:
            acc["normalized"] = True
        return self.add("accessors", acc)

    def prim(self, positions, faces, material=None, normal=None, uv=(), color=None, targets=(), joints=None,
             weights=None):
        """``uv``: TEXCOORD_0, TEXCOORD_1, ... arrays; ``color``: (array, componentType, type)."""
        attrs = {"POSITION": self.acc(positions)}
        if normal is not None:
            attrs["NORMAL"] = self.acc(normal)
        for k, a in enumerate(uv):
            attrs[f"TEXCOORD_{k}"] = self.acc(a, typ="VEC2")
        if color is not None:
            arr, ct, typ = color
            attrs["COLOR_0"] = self.acc(arr, ct, typ, normalized=ct != FLOAT)
        if joints is not None:
            attrs["JOINTS_0"] = self.acc(joints, UBYTE, "VEC4")
            attrs["WEIGHTS_0"] = self.acc(weights, FLOAT, "VEC4")
        p = {"attributes": attrs, "indices": self.acc(np.ravel(faces), UINT, "SCALAR"), "mode": 4}
        if material is not None:
            p["material"] = material
        if targets:
            p["targets"] = [{k: self.acc(v) for k, v in tg.items()} for tg in targets]
        return p

    def mesh(self, *prims, weights=None):
        m = {"primitives": list(prims)}
        if weights is not None:
            m["weights"] = list(weights)
        return self.add("meshes", m)

    def node(self, root=True, **kw):
        i = self.add("nodes", kw)
        if root:
            self.t["scenes"][0]["nodes"].append(i)
        return i

    def image_view(self, data, mime="image/png"):
        return self.add("images", {"bufferView": self.view(data), "mimeType": mime})

    def image_uri(self, uri):
        return self.add("images", {"uri": uri})

    def sampler(self, s, t):
        return self.add("samplers", {"wrapS": s, "wrapT": t, "magFilter": 9729})

    def texture(self, image, sampler=None):
        return self.add("textures", {"source": image} if sampler is None else {"source": image, "sampler": sampler})

    def material(self, factor=None, texture=None, texcoord=None):
        pbr = {"metallicFactor": 0.0}
        if factor is not None:
            pbr["baseColorFactor"] = list(factor)
        if texture is not None:
            pbr["baseColorTexture"] = {"index": texture} if texcoord is None else {"index": texture,
                                                                                   "texCoord": texcoord}
        return self.add("materials", {"pbrMetallicRoughness": pbr})

    def animation(self, channels):
        """channels: (node, path, times, flat values); LINEAR."""
        an = {"channels": [], "samplers": []}
        for node, path, times, values in channels:
            typ = {"translation": "VEC3", "scale": "VEC3", "rotation": "VEC4", "weights": "SCALAR"}[path]
            an["samplers"].append({"input": self.acc(times, typ="SCALAR"), "output": self.acc(values, typ=typ),
                                   "interpolation": "LINEAR"})
            an["channels"].append({"sampler": len(an["samplers"]) - 1, "target": {"node": node, "path": path}})
        self.add("animations", an)

    def lights(self, lights):
        self.t.setdefault("extensionsUsed", []).append("KHR_lights_punctual")
        self.t["extensions"] = {"KHR_lights_punctual": {"lights": lights}}

    def save(self, path, edit=None):
        while len(self.blob) % 4:
            self.blob.append(0)
        tree = json.loads(json.dumps(self.t))
        tree["buffers"] = [{"byteLength": len(self.blob)}]
        if path.suffix == ".gltf":
            tree["buffers"][0]["uri"] = path.stem + ".bin"
            (path.parent / (path.stem + ".bin")).write_bytes(bytes(self.blob))
        if edit is not None:
            edit(tree)
        if path.suffix == ".gltf":
            path.write_text(json.dumps(tree))
        else:
            js = json.dumps(tree).encode()
            js += b" " * (-len(js) % 4)
            body = struct.pack("<II", len(js), 0x4E4F534A) + js + struct.pack("<II", len(self.blob), 0x004E4942) \
                + bytes(self.blob)
            path.write_bytes(struct.pack("<4sII", b"glTF", 2, 12 + len(body)) + body)
        return path


def quat(axis, angle):
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    return np.r_[a * math.sin(angle / 2), math.cos(angle / 2)]


def rot(axis, angle):
    """Rodrigues: the rotation by ``angle`` about ``axis`` (column vectors)."""
    k = np.asarray(axis, float) / np.linalg.norm(axis)
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(angle) * kx + (1 - math.cos(angle)) * kx @ kx


def unit(a):
    a = np.asarray(a, float)
    return a / np.linalg.norm(a, axis=-1, keepdims=True)


def normal_matrix(m):
    return np.linalg.inv(m[:3, :3]).T


def png_bytes(texels):
    buf = io.BytesIO()
    Image.fromarray(texels, "RGB").save(buf, format="PNG")
    return buf.getvalue()


def checkerboard():
    """A 3 x 4 (H x W) checkerboard of two colours with a red top-left texel (shows a flip)."""
    a = np.where(((np.arange(3)[:, None] + np.arange(4)[None, :]) % 2)[..., None] == 0,
                 np.array([30, 60, 90], np.uint8), np.array([200, 180, 160], np.uint8)).astype(np.uint8)
    a[0, 0] = (255, 0, 0)
    return a


# ----------------------------------------------------------------------------- materials, uv, colours, normals

QUAD_V = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], np.float32)
QUAD_F = np.array([[0, 1, 2], [0, 2, 3]])
TRI_V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32)
TRI_F = np.array([[0, 1, 2]])
QUAD_UV = np.array([[-0.5, 0.0], [1.5, 0.25], [0.75, 2.0], [0.125, 0.5]], np.float32)  # beyond [0, 1] too
QUAD_COLOR = np.array([[255, 0, 0, 255], [0, 128, 0, 10], [0, 0, 255, 0], [51, 102, 153, 255]], np.uint8)
QUAD_NORMAL = np.array([[0, 0, 2], [0, 1, 1], [1, 0, 1], [0.5, 0.5, 3]], np.float32)  # not unit: normalized
TRI_UV0 = np.array([[0.1, 0.2], [0.3, 0.4], [0.5, 0.6]], np.float32)
TRI_UV1 = np.array([[0.9, 0.8], [0.7, 0.6], [0.5, 0.25]], np.float32)
TRI_NORMAL = np.array([[0, 0, 1], [0, 0.6, 0.8], [0.6, 0, 0.8]], np.float32)
TRI_FCOLOR = np.array([[0.25, 0.5, 0.75], [1, 1, 1], [0, 0.125, 1]], np.float32)
TRI_SCOLOR = np.array([[65535, 0, 32768], [0, 65535, 0], [13107, 26214, 39321]], np.uint16)
M0 = (0.5, 0.25, 1.0, 0.3)
M2 = (0.2, 0.4, 0.6, 1.0)
M3 = (0.9, 0.8, 0.7, 1.0)


def write_looks(path):
    """Six triangles, one root node per mesh in this order:
    0-1 quad: material 0 (factor M0, embedded PNG, sampler clamp/mirror), uv, COLOR_0 ubyte VEC4, NORMAL;
    2 tri: material 1 (external PNG, no sampler: repeat), uv, no normal or colour;
    3 tri: material 2 (factor M2, data: URI PNG on TEXCOORD_1, sampler mirror/repeat), COLOR_0 float, NORMAL;
    4 tri: no material, NORMAL;
    5 tri: material 3 (factor M3, untextured), COLOR_0 ushort VEC3."""
    tex = checkerboard()
    (path.parent / "checker file.png").write_bytes(png_bytes(tex))
    w = Writer()
    img_emb = w.image_view(png_bytes(tex))
    img_file = w.image_uri("checker%20file.png")
    img_data = w.image_uri("data:image/png;base64," + base64.b64encode(png_bytes(tex)).decode())
    t0 = w.texture(img_emb, w.sampler(33071, 33648))
    t1 = w.texture(img_file)
    t2 = w.texture(img_data, w.sampler(33648, 10497))
    m0 = w.material(M0, t0)
    m1 = w.material(None, t1)
    m2 = w.material(M2, t2, texcoord=1)
    m3 = w.material(M3)
    meshes = [
        w.mesh(w.prim(QUAD_V, QUAD_F, m0, normal=QUAD_NORMAL, uv=[QUAD_UV], color=(QUAD_COLOR, UBYTE, "VEC4"))),
        w.mesh(w.prim(TRI_V, TRI_F, m1, uv=[TRI_UV0])),
        w.mesh(w.prim(TRI_V, TRI_F, m2, normal=TRI_NORMAL, uv=[TRI_UV0, TRI_UV1], color=(TRI_FCOLOR, FLOAT, "VEC3"))),
        w.mesh(w.prim(TRI_V, TRI_F, normal=TRI_NORMAL)),
        w.mesh(w.prim(TRI_V, TRI_F, m3, color=(TRI_SCOLOR, USHORT, "VEC3"))),
    ]
    for m in meshes:
        w.node(mesh=m)
    return w.save(path), tex


def check_looks(s, tex):
    sf = s.surface
    assert sf is not None and sf.n_triangles == 6
    diffuse = np.array([M0[:3], M0[:3], (1, 1, 1), M2[:3], (1, 1, 1), M3[:3]], np.float32)
    np.testing.assert_array_equal(sf.diffuse[sf.material], diffuse)
    np.testing.assert_allclose(sf.ambient[sf.material], AMBIENT * diffuse, rtol=1e-6)
    # textures: the PNG's texels (row 0 = the image's top), the samplers' wrap modes
    wraps = [("clamp", "mirror")] * 2 + [("repeat", "repeat"), ("mirror", "repeat")]
    for f, wrap in enumerate(wraps):
        t = sf.textures[sf.texture[sf.material[f]]]
        np.testing.assert_array_equal(t.texels, tex)
        assert t.wrap == wrap, (f, t.wrap)
    assert (sf.texture[sf.material[4:]] == -1).all()
    assert len(sf.textures) == 3
    # uv exactly as written (glTF's convention is the surface's), TEXCOORD_1 where the material says
    np.testing.assert_array_equal(sf.uv[:2], QUAD_UV[QUAD_F])
    np.testing.assert_array_equal(sf.uv[2], TRI_UV0)
    np.testing.assert_array_equal(sf.uv[3], TRI_UV1)
    # colours: normalized integers / their maximum, alpha dropped; ones without COLOR_0
    col = np.ones((6, 3, 3))
    col[:2] = (QUAD_COLOR[:, :3] / 255.0)[QUAD_F]
    col[3] = TRI_FCOLOR
    col[5] = TRI_SCOLOR / 65535.0
    np.testing.assert_allclose(sf.colors, col, atol=1e-7)
    # normals: unit, zero for primitives without NORMAL
    nrm = np.zeros((6, 3, 3))
    nrm[:2] = unit(QUAD_NORMAL)[QUAD_F]
    nrm[3] = unit(TRI_NORMAL)
    nrm[4] = unit(TRI_NORMAL)
    np.testing.assert_allclose(sf.normals, nrm, atol=1e-7)


@pytest.mark.parametrize("ext", [".gltf", ".glb"])
def test_materials_textures_uv_colours_normals(tmp_path, ext):
    p, tex = write_looks(tmp_path / f"looks{ext}")
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # nothing to warn about
        s = GltfAnimation(p)
    check_looks(s, tex)
    assert s.static and s.lights_at(0.0).shape == (0, 8)
    # a static file: make_scene gives a StaticMesh whose Mesh carries the same surface
    sm = make_scene(p)
    assert isinstance(sm, StaticMesh) and sm.mesh.surface is not None
    check_looks(sm, tex)
    np.testing.assert_array_equal(sm.normals_at(3.0), s.surface.normals)


def test_files_without_looks_have_no_surface(tmp_path):
    w = Writer()
    w.node(mesh=w.mesh(w.prim(TRI_V, TRI_F)))
    s = GltfAnimation(w.save(tmp_path / "plain.glb"))
    assert s.surface is None and s.normals_at(0.0) is None and len(s.lights_at(0.0)) == 0
    assert make_scene(tmp_path / "plain.glb").mesh.surface is None


# ----------------------------------------------------------------------------- normals in motion

SCALE = np.array([2.0, 1.0, 0.5])
AXIS = np.array([1.0, 2.0, 3.0])
ANGLE = 2 * math.pi / 3  # reached at t = 2; slerp about one axis: the angle grows linearly
GEO_V = np.array([[0, 0, 0], [1, 0.2, 0.1], [0.3, 1, -0.2]], np.float32)
GEO_N = unit(np.cross(GEO_V[1] - GEO_V[0], GEO_V[2] - GEO_V[0]))


def write_rigid(path):
    """A non-uniformly scaled parent (SCALE) over a child rotating about AXIS (0 -> ANGLE over 2 s);
    the child holds a triangle with three different normals and one whose normals are its own
    geometric normal."""
    w = Writer()
    mesh = w.mesh(w.prim(TRI_V, TRI_F, normal=TRI_NORMAL), w.prim(GEO_V, TRI_F, normal=np.tile(GEO_N, (3, 1))))
    w.node(children=[1], scale=SCALE.tolist())
    w.node(root=False, mesh=mesh)
    w.animation([(1, "rotation", [0.0, 2.0], np.r_[quat(AXIS, 0.0), quat(AXIS, ANGLE)])])
    return w.save(path)


def test_rigid_node_normals_use_the_inverse_transpose(tmp_path):
    s = GltfAnimation(write_rigid(tmp_path / "rigid.gltf"))
    assert not s.static
    rest = np.concatenate([TRI_NORMAL[None], np.tile(GEO_N, (1, 3, 1))]).astype(float)
    # the surface's normals are those of clip time 0 (the scale applies, the rotation is 0)
    np.testing.assert_allclose(s.surface.normals, unit(rest @ normal_matrix(np.diag(np.r_[SCALE, 1])).T),
                               atol=1e-6)
    for t in (0.0, 0.5, 1.3, 1.9):  # (t = 2 is clip time 0 again: the clip loops)
        m = np.diag(SCALE) @ rot(AXIS, ANGLE * t / 2)
        got = s.normals_at(t)
        np.testing.assert_allclose(got, unit(rest @ np.linalg.inv(m)), atol=2e-6, err_msg=f"t={t}")
        # the second triangle's normals stay its (posed) geometric normal
        tri = s.triangles_at(t).astype(float)[1]
        np.testing.assert_allclose(got[1], np.tile(unit(np.cross(tri[1] - tri[0], tri[2] - tri[0])), (3, 1)),
                                   atol=2e-6)
    # pure in t, with the internal buffer or out=
    a = s.normals_at(1.3).copy()
    s.normals_at(0.2)
    np.testing.assert_array_equal(s.normals_at(1.3), a)
    out = np.empty_like(a)
    assert s.normals_at(1.3, out=out) is out
    np.testing.assert_array_equal(out, a)
    # to_mesh(t) carries the normals of t
    np.testing.assert_allclose(s.to_mesh(1.3).surface.normals, a, atol=1e-7)


ARM_V = np.array([[0, 0, 0], [0.2, 0, 0], [0, 1, 0], [0.2, 1, 0], [0, 2, 0], [0.2, 2, 0]], np.float32)
ARM_F = np.array([[0, 1, 3], [0, 3, 2], [2, 3, 5], [2, 5, 4]])
ARM_W = np.array([[1, 0], [1, 0], [0.25, 0.75], [0.6, 0.4], [0, 1], [0, 1]])
ARM_N = unit(np.array([[0, 0, 1], [1, 0, 1], [0, 1, 1], [1, 1, 1], [-1, 0, 1], [0.3, -0.2, 1]]))
ELBOW_S = np.array([1.5, 0.5, 1.0])


def write_skin(path):
    """Root joint 0 slides along x (0 -> 2 over 2 s); elbow joint 1 at y = 1, scaled ELBOW_S, bends
    90 degrees about z over the first second, then holds.  The mesh node's own transform is ignored."""
    w = Writer()
    j = np.zeros((6, 4), int)
    j[:, 1] = 1
    wt = np.zeros((6, 4))
    wt[:, :2] = ARM_W
    mesh = w.mesh(w.prim(ARM_V, ARM_F, normal=ARM_N, joints=j, weights=wt))
    w.node(children=[1])  # 0: root joint
    w.node(root=False, translation=[0.0, 1.0, 0.0], scale=ELBOW_S.tolist())  # 1: elbow
    w.node(mesh=mesh, skin=0, rotation=quat([0, 1, 0], 1.0).tolist())  # 2: ignored (skinned)
    ibm = np.stack([np.eye(4), np.eye(4)])
    ibm[1, 1, 3] = -1.0  # the inverse of the elbow's bind translation; the scale is part of the pose
    w.add("skins", {"joints": [0, 1], "inverseBindMatrices": w.acc(ibm.transpose(0, 2, 1).ravel(), typ="MAT4")})
    w.animation([(0, "translation", [0.0, 2.0], [0, 0, 0, 2, 0, 0]),
                 (1, "rotation", [0.0, 1.0], np.r_[quat([0, 0, 1], 0.0), quat([0, 0, 1], math.pi / 2)])])
    return w.save(path)


def skin_normals(t):
    """normalize(sum_j w_j L_j^-T n) with L_j the linear part of world[joint_j] @ inverseBind_j."""
    root = np.eye(4)
    root[0, 3] = t
    elbow = np.eye(4)
    elbow[:3, :3] = rot([0, 0, 1], math.pi / 2 * min(t, 1.0)) @ np.diag(ELBOW_S)
    elbow[1, 3] = 1.0
    ibm1 = np.eye(4)
    ibm1[1, 3] = -1.0
    jm = [root, root @ elbow @ ibm1]
    n = sum(ARM_W[:, [k]] * (ARM_N @ normal_matrix(jm[k]).T) for k in range(2))
    return unit(n)[ARM_F]


def test_skinned_normals_blend_the_joints_normal_matrices(tmp_path):
    s = GltfAnimation(write_skin(tmp_path / "skin.glb"))
    for t in (0.0, 0.5, 1.0, 1.5):  # 1.0: a key
        np.testing.assert_allclose(s.normals_at(t), skin_normals(t), atol=2e-6, err_msg=f"t={t}")
    np.testing.assert_allclose(s.surface.normals, skin_normals(0.0), atol=2e-6)


TARGET_D = np.array([[0, 0, 0.5], [0.1, 0, 0], [0, 0.2, 0]], np.float32)
TARGET_DN = np.array([[1, 0, 0], [0, -0.5, 0.2], [0.3, 0.3, -1.5]], np.float32)


def write_morph(path):
    """A triangle with NORMAL and two morph targets (the first without NORMAL deltas, weight 0.5
    held; the second with them, weight 0 -> 1 over 1 s) on a node turned 90 degrees about x."""
    w = Writer()
    mesh = w.mesh(w.prim(TRI_V, TRI_F, normal=TRI_NORMAL,
                         targets=[{"POSITION": TARGET_D}, {"POSITION": TARGET_D, "NORMAL": TARGET_DN}]),
                  weights=[0.5, 0.0])
    w.node(mesh=mesh, rotation=quat([1, 0, 0], math.pi / 2).tolist())
    w.animation([(0, "weights", [0.0, 1.0], [0.5, 0.0, 0.5, 1.0])])
    return w.save(path)


def test_morph_target_normal_deltas(tmp_path):
    s = GltfAnimation(write_morph(tmp_path / "morph.gltf"))
    for t in (0.0, 0.25, 0.6, 0.95):
        n = unit((TRI_NORMAL + t * TARGET_DN) @ rot([1, 0, 0], math.pi / 2).T)
        np.testing.assert_allclose(s.normals_at(t)[0], n, atol=2e-6, err_msg=f"t={t}")


# ----------------------------------------------------------------------------- lights

LIGHTS = [
    {"type": "point", "color": [1.0, 0.5, 0.25], "intensity": 8.0, "range": 20.0},
    {"type": "directional", "color": [0.2, 0.4, 0.6], "intensity": 3.0},
    {"type": "spot", "intensity": 2.0, "spot": {"innerConeAngle": 0.1, "outerConeAngle": 0.5}},
    {"type": "directional"},
]


def write_lights(path, animated=True):
    """Point light 0 one unit above a node moving (0,0,0) -> (2,4,6) over 2 s; directional light 1 on a
    node turning 0 -> 90 degrees about y over 2 s; spot light 2 at (5, 5, 5); directional light 3 on a
    node tilted 90 degrees about x (shines along +y, so the vector towards it is -y)."""
    w = Writer()
    w.lights(LIGHTS)
    w.node(mesh=w.mesh(w.prim(TRI_V, TRI_F)))  # 0
    w.node(children=[2])  # 1: moves
    w.node(root=False, translation=[0.0, 1.0, 0.0], extensions={"KHR_lights_punctual": {"light": 0}})  # 2
    w.node(extensions={"KHR_lights_punctual": {"light": 1}})  # 3: turns
    w.node(translation=[5.0, 5.0, 5.0], extensions={"KHR_lights_punctual": {"light": 2}})  # 4
    w.node(rotation=quat([1, 0, 0], math.pi / 2).tolist(), extensions={"KHR_lights_punctual": {"light": 3}})
    w.node(root=False, extensions={"KHR_lights_punctual": {"light": 0}})  # 6: not in the scene
    if animated:
        w.animation([(1, "translation", [0.0, 2.0], [0, 0, 0, 2, 4, 6]),
                     (3, "rotation", [0.0, 2.0], np.r_[quat([0, 1, 0], 0.0), quat([0, 1, 0], math.pi / 2)])])
    return w.save(path)


def expected_lights(t):
    return np.array([
        [LIGHT_POINT, t, 2 * t + 1, 3 * t, 8.0, 4.0, 2.0, FALLOFF_INVERSE_SQUARE],
        [LIGHT_DIRECTIONAL, *(rot([0, 1, 0], math.pi / 4 * t) @ [0, 0, 1]), 0.6, 1.2, 1.8, FALLOFF_NONE],
        [LIGHT_POINT, 5, 5, 5, 2, 2, 2, FALLOFF_INVERSE_SQUARE],
        [LIGHT_DIRECTIONAL, 0, -1, 0, 1, 1, 1, FALLOFF_NONE],
    ])


def test_punctual_lights_follow_their_nodes(tmp_path):
    with pytest.warns(UserWarning, match="spot lights"):
        s = GltfAnimation(write_lights(tmp_path / "lights.glb"))
    assert s.n_lights == 4 and s.surface is None  # lights alone are no surface
    for t in (0.0, 0.7, 1.5, 1.9):
        np.testing.assert_allclose(s.lights_at(t), expected_lights(t), atol=1e-12, err_msg=f"t={t}")
    with pytest.warns(UserWarning, match="spot lights"):
        still = GltfAnimation(write_lights(tmp_path / "still.gltf", animated=False))
    assert still.lights_at(0.0) is still.lights_at(5.0)  # lights on still nodes are computed once
    np.testing.assert_allclose(still.lights_at(3.0), expected_lights(0.0), atol=1e-12)


# ----------------------------------------------------------------------------- bad input


def small_textured(path, edit=None, uri=None):
    w = Writer()
    img = w.image_uri(uri) if uri else w.image_view(png_bytes(checkerboard()))
    m = w.material(M0, w.texture(img))
    w.node(mesh=w.mesh(w.prim(QUAD_V, QUAD_F, m, normal=QUAD_NORMAL, uv=[QUAD_UV])))
    return w.save(path, edit)


def test_missing_image_warns_and_loads(tmp_path):
    p = small_textured(tmp_path / "missing.gltf", uri="nowhere.png")
    with pytest.warns(TextureWarning, match="nowhere.png.*not found"):
        s = GltfAnimation(p)
    assert not s.surface.textured and s.surface.n_triangles == 2
    np.testing.assert_array_equal(s.surface.diffuse[s.surface.material], [M0[:3]] * 2)


def test_texcoord_set_the_primitive_lacks_warns(tmp_path):
    def edit(t):
        t["materials"][0]["pbrMetallicRoughness"]["baseColorTexture"]["texCoord"] = 2

    with pytest.warns(TextureWarning, match="TEXCOORD_2"):
        s = GltfAnimation(small_textured(tmp_path / "set.glb", edit))
    assert not s.surface.textured


def test_texture_transform_warns_and_spec_gloss_gives_the_diffuse(tmp_path):
    def edit(t):
        t["materials"][0]["pbrMetallicRoughness"]["baseColorTexture"]["extensions"] = {
            "KHR_texture_transform": {"scale": [2, 2]}}
        t["materials"].append({"extensions": {"KHR_materials_pbrSpecularGlossiness": {
            "diffuseFactor": [0.1, 0.2, 0.3, 1.0]}}})
        t["meshes"][0]["primitives"][0]["material"] = 1
        t["meshes"].append({"primitives": [dict(t["meshes"][0]["primitives"][0], material=0)]})
        t["nodes"].append({"mesh": 1})
        t["scenes"][0]["nodes"].append(1)

    with pytest.warns(UserWarning, match="KHR_texture_transform"):
        s = GltfAnimation(small_textured(tmp_path / "ext.glb", edit))
    sf = s.surface
    np.testing.assert_array_equal(sf.diffuse[sf.material], np.float32([[0.1, 0.2, 0.3]] * 2 + [M0[:3]] * 2))
    np.testing.assert_array_equal(sf.texture[sf.material] >= 0, [False, False, True, True])


def _uv_count(t):
    t["accessors"][t["meshes"][0]["primitives"][0]["attributes"]["TEXCOORD_0"]]["count"] = 3


def _set(path, value):
    def edit(t):
        obj = t
        for k in path[:-1]:
            obj = obj[k]
        obj[path[-1]] = value
    return edit


PBR = ("materials", 0, "pbrMetallicRoughness")
BAD = {
    "uv count": (_uv_count, "TEXCOORD_0 must be VEC2 with one entry per vertex (4)"),
    "uv accessor": (_set(("meshes", 0, "primitives", 0, "attributes", "TEXCOORD_0"), 99), "accessors[99]"),
    "normal count": (lambda t: t["accessors"][t["meshes"][0]["primitives"][0]["attributes"]["NORMAL"]].update(count=2),
                     "NORMAL must be VEC3 with one entry per vertex (4)"),
    "texture index": (_set(PBR + ("baseColorTexture", "index"), 7), "textures[7]"),
    "texCoord": (_set(PBR + ("baseColorTexture", "texCoord"), -1), "'texCoord' must be an integer >= 0"),
    "material index": (_set(("meshes", 0, "primitives", 0, "material"), 3), "materials[3]"),
    "factor": (_set(PBR + ("baseColorFactor",), [1, 1]), "'baseColorFactor' must be a list of 4 numbers"),
    "wrap": (lambda t: t.setdefault("samplers", []).append({"wrapS": 12345})
             or t["textures"][0].update(sampler=0), "unknown wrapS 12345"),
    "light": (lambda t: t["nodes"][0].update(extensions={"KHR_lights_punctual": {"light": 0}}),
              "refers to light 0, but the file defines 0"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_looks_name_the_file_and_the_problem(tmp_path, case):
    edit, problem = BAD[case]
    p = small_textured(tmp_path / "bad.gltf", edit)
    with pytest.raises(SceneFileError) as info:
        GltfAnimation(p)
    assert info.value.path == str(p)
    assert problem in info.value.problem, info.value.problem


# ----------------------------------------------------------------------------- real files


def read_glb(path):
    """(JSON tree, binary chunk) of a .glb, read here with struct."""
    raw = path.read_bytes()
    n, = struct.unpack_from("<I", raw, 12)
    tree = json.loads(raw[20:20 + n])
    m, = struct.unpack_from("<I", raw, 20 + n)
    return tree, raw[28 + n:28 + n + m]


def glb_accessor(tree, blob, i):
    a = tree["accessors"][i]
    bv = tree["bufferViews"][a["bufferView"]]
    dt = np.dtype(_DT[a["componentType"]])
    n = _NC[a["type"]]
    assert bv.get("byteStride", dt.itemsize * n) == dt.itemsize * n
    off = bv.get("byteOffset", 0) + a.get("byteOffset", 0)
    return np.frombuffer(blob, dt, a["count"] * n, off).reshape(a["count"], n)


def geometric_agreement(tris, normals):
    """Per triangle: the cosine between its geometric normal and the mean of its corner normals."""
    t = np.asarray(tris, float)
    g = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
    m = np.asarray(normals, float).mean(axis=1)
    ok = (np.linalg.norm(g, axis=1) > 0) & (np.linalg.norm(m, axis=1) > 0)
    return np.einsum("fi,fi->f", unit(g[ok]), unit(m[ok]))


def test_cesium_man_texture_uv_and_posed_normals():
    p = data_path("animated/cesium_man/CesiumMan.glb")
    tree, blob = read_glb(p)
    bv = tree["bufferViews"][tree["images"][0]["bufferView"]]
    img = Image.open(io.BytesIO(blob[bv.get("byteOffset", 0):bv.get("byteOffset", 0) + bv["byteLength"]]))
    texels = np.asarray(img.convert("RGB"))
    prim = tree["meshes"][0]["primitives"][0]
    faces = glb_accessor(tree, blob, prim["indices"]).reshape(-1, 3).astype(int)
    uv = glb_accessor(tree, blob, prim["attributes"]["TEXCOORD_0"])
    bind_normals = glb_accessor(tree, blob, prim["attributes"]["NORMAL"])

    s = GltfAnimation(p)
    sf = s.surface
    assert sf.n_triangles == s.n_triangles == len(faces) == 4672
    assert len(sf.textures) == 1 and sf.textures[0].texels.shape == (img.height, img.width, 3)
    np.testing.assert_array_equal(sf.textures[0].texels, texels)
    assert sf.textures[0].wrap == ("repeat", "repeat")
    assert (sf.texture[sf.material] == 0).all()
    np.testing.assert_array_equal(sf.diffuse, [[1, 1, 1]])
    np.testing.assert_array_equal(sf.uv, uv[faces])
    assert sf.colors is None
    # posed normals are unit and lie along the posed geometry; the file's bind-pose normals do not
    for t in (0.0, 0.37, 1.21):
        n = s.normals_at(t)
        np.testing.assert_allclose(np.linalg.norm(n, axis=2), 1.0, atol=1e-6)
        tris = s.triangles_at(t)
        posed = geometric_agreement(tris, n)
        assert np.median(posed) > 0.97 and (posed > 0.5).mean() > 0.97, (t, np.median(posed))
        bind = geometric_agreement(tris, bind_normals[faces])
        assert np.median(bind) < 0.5  # (the check is sensitive: the normals as the file has them fail it)


def test_brainstem_materials():
    p = data_path("animated/brainstem/BrainStem.glb")
    tree, _ = read_glb(p)
    s = GltfAnimation(p)
    want = {tuple(np.float32(m["pbrMetallicRoughness"].get("baseColorFactor", [1, 1, 1, 1])[:3]).tolist())
            for m in tree["materials"]}
    used = {tuple(c) for c in s.surface.diffuse[np.unique(s.surface.material)].tolist()}
    assert used <= want and len(used) > 1
    assert not s.surface.textured and s.surface.normals is not None
    t = 11.0
    a = geometric_agreement(s.triangles_at(t), s.normals_at(t))
    assert np.median(a) > 0.97


def test_littlest_tokyo_loads_with_textures():
    p = data_path("animated/littlest_tokyo/LittlestTokyo.glb")
    if not HAVE_DRACO:
        pytest.skip("DracoPy is not installed: LittlestTokyo's Draco-compressed meshes cannot be decoded")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # Pillow's note on a palette PNG with transparency
        s = GltfAnimation(p)
    sf = s.surface
    sizes = sorted(t.texels.shape for t in sf.textures)
    assert sizes == [(512, 512, 3), (1024, 1024, 3), (4096, 4096, 3)]
    assert (sf.texture[sf.material] >= 0).mean() > 0.5  # (two of its 15 materials are untextured)
    assert np.isfinite(sf.uv).all() and sf.normals is not None
    t = 2.0
    n = s.normals_at(t)
    length = np.linalg.norm(n, axis=2)
    assert (np.abs(length - 1) < 1e-5).mean() > 0.99
    moving = ~s.static_mask
    a = geometric_agreement(s.triangles_at(t)[moving], n[moving])
    assert np.median(a) > 0.95
