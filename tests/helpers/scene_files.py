"""Writers of small scene files (glTF, MD2, OBJ, OFF, PLY, STL, BART AFF) for the loader tests."""

import math
import struct

import numpy as np
import pygltflib as gl


AFF_OK = """v
from 0 0 5
at 0 0 0
up 0 1 0
angle 45
hither 0.1
resolution 64 64
a 0 2 21
x spin
{
  i 0 part.aff
}
k spin
{
  rot 4
  -1 0 1 0 0  0 0 0
   0 0 1 0 0  0 0 0
   2 0 1 0 180  0 0 0
   3 0 1 0 270  0 0 0
}
"""


PART = "m vertices 4  0 0 0  1 0 0  1 1 0  0 1 0\n triangles 2  0 1 2  0 2 3\np 3 0 0 1  1 0 1  0 1 1\n"


def write_aff(tmp_path, root=AFF_OK, part=PART):
    (tmp_path / "part.aff").write_text(part)
    p = tmp_path / "scene.aff"
    p.write_text(root)
    return p


def md2_bytes(tmp_path):
    rng = np.random.default_rng(1)
    p = write_md2(tmp_path / "m.md2", rng.integers(0, 256, (3, 6, 3), dtype=np.uint8),
                  np.full((3, 3), 0.1), np.zeros((3, 3)), ["a1", "a2", "a3"], [(0, 1, 2), (3, 4, 5), (0, 2, 4)])
    return p, bytearray(p.read_bytes())


class Builder:
    """Collects arrays into one binary buffer and writes a glTF 2.0 file with pygltflib."""

    def __init__(self):
        self.blob = bytearray()
        self.g = gl.GLTF2(asset=gl.Asset(version="2.0"), scene=0, scenes=[gl.Scene(nodes=[])])

    def view(self, arr):
        while len(self.blob) % 4:
            self.blob.append(0)
        self.g.bufferViews.append(gl.BufferView(buffer=0, byteOffset=len(self.blob), byteLength=arr.nbytes))
        self.blob.extend(arr.tobytes())
        return len(self.g.bufferViews) - 1

    def acc(self, data, ctype, typ, normalized=False):
        dt = {gl.FLOAT: "<f4", gl.UNSIGNED_BYTE: "u1", gl.UNSIGNED_SHORT: "<u2", gl.UNSIGNED_INT: "<u4"}[ctype]
        arr = np.ascontiguousarray(np.asarray(data), dtype=dt)
        n = {"SCALAR": 1, "VEC3": 3, "VEC4": 4, "MAT4": 16}[typ]
        count = arr.size // n
        kw = {}
        if typ == "VEC3" and ctype == gl.FLOAT:
            a = arr.reshape(count, 3)
            kw = {"min": a.min(0).tolist(), "max": a.max(0).tolist()}
        self.g.accessors.append(gl.Accessor(bufferView=self.view(arr), componentType=ctype, count=count, type=typ,
                                            normalized=normalized, **kw))
        return len(self.g.accessors) - 1

    def mesh(self, vertices, faces, targets=(), weights=None, joints=None, jweights=None, mode=gl.TRIANGLES):
        attrs = gl.Attributes(POSITION=self.acc(vertices, gl.FLOAT, "VEC3"))
        if joints is not None:
            attrs.JOINTS_0 = self.acc(joints, gl.UNSIGNED_BYTE, "VEC4")
            ct, norm = jweights
            attrs.WEIGHTS_0 = self.acc(norm, ct, "VEC4", normalized=ct != gl.FLOAT)
        prim = gl.Primitive(attributes=attrs, indices=self.acc(np.ravel(faces), gl.UNSIGNED_INT, "SCALAR"), mode=mode)
        prim.targets = [gl.Attributes(POSITION=self.acc(d, gl.FLOAT, "VEC3")) for d in targets]
        self.g.meshes.append(gl.Mesh(primitives=[prim], weights=weights))
        return len(self.g.meshes) - 1

    def node(self, root=False, **kw):
        self.g.nodes.append(gl.Node(**kw))
        i = len(self.g.nodes) - 1
        if root:
            self.g.scenes[0].nodes.append(i)
        return i

    def animation(self, name, channels):
        """channels: list of (node, path, times, values (flat), interpolation)."""
        an = gl.Animation(name=name, channels=[], samplers=[])
        for node, path, times, values, interp in channels:
            vals = np.asarray(values, dtype=np.float64)
            typ = {"translation": "VEC3", "scale": "VEC3", "rotation": "VEC4", "weights": "SCALAR"}[path]
            an.samplers.append(gl.AnimationSampler(input=self.acc(times, gl.FLOAT, "SCALAR"),
                                                   output=self.acc(vals, gl.FLOAT, typ), interpolation=interp))
            an.channels.append(gl.AnimationChannel(sampler=len(an.samplers) - 1,
                                                   target=gl.AnimationChannelTarget(node=node, path=path)))
        self.g.animations.append(an)

    def save(self, path):
        while len(self.blob) % 4:
            self.blob.append(0)
        self.g.buffers = [gl.Buffer(byteLength=len(self.blob))]
        self.g.set_binary_blob(bytes(self.blob))
        if path.suffix == ".glb":
            self.g.save_binary(str(path))
        else:
            self.g.save_json(str(path))
        return path


ARM_V = np.array([[0, 0, 0], [0.2, 0, 0], [0, 1, 0], [0.2, 1, 0], [0, 2, 0], [0.2, 2, 0]], dtype=np.float32)


ARM_F = np.array([[0, 1, 3], [0, 3, 2], [2, 3, 5], [2, 5, 4]])


TRI_V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], dtype=np.float32)


TRI_F = np.array([[0, 1, 2]])


H = math.sqrt(0.5)


# joint weights of the arm's rows y = 0, 1, 2: all on joint 0, a blend, all on joint 1
WEIGHT_KINDS = {
    "u8": (gl.UNSIGNED_BYTE, [[255, 0], [128, 127], [0, 255]], 255.0),
    "u16": (gl.UNSIGNED_SHORT, [[65535, 0], [30000, 35535], [0, 65535]], 65535.0),
    "f32": (gl.FLOAT, [[1.0, 0.0], [0.25, 0.75], [0.0, 1.0]], 1.0),
}


def write_arm(path, kind):
    """Root joint 0 slides along x (0 -> 2 over 2 s), elbow joint 1 at y=1 bends 90 deg about z
    over the first second then holds; a skinned arm, a rigid triangle under the root, a static one."""
    ct, rows, _ = WEIGHT_KINDS[kind]
    b = Builder()
    w = np.zeros((6, 4))
    for v in range(6):
        w[v, :2] = rows[v // 2]
    j = np.tile([0, 1, 0, 0], (6, 1))
    arm = b.mesh(ARM_V, ARM_F, joints=j, jweights=(ct, w))
    tri = b.mesh(TRI_V, TRI_F)
    b.node(root=True, name="root", children=[1, 4])  # 0
    b.node(name="elbow", translation=[0.0, 1.0, 0.0])  # 1
    b.node(root=True, name="arm", mesh=arm, skin=0, translation=[10.0, 0.0, 0.0])  # 2: ignored (skinned)
    b.node(root=True, name="static", mesh=tri, translation=[5.0, 0.0, 0.0])  # 3
    b.node(name="carried", mesh=tri, translation=[0.0, 0.0, 3.0])  # 4
    ibm = np.stack([np.eye(4), np.eye(4)])
    ibm[1, 1, 3] = -1.0  # inverse of the elbow's bind world matrix T(0, 1, 0)
    b.g.skins.append(gl.Skin(joints=[0, 1], inverseBindMatrices=b.acc(ibm.transpose(0, 2, 1).ravel(), gl.FLOAT,
                                                                       "MAT4")))
    b.animation("walk", [
        (0, "translation", [0.0, 2.0], [0, 0, 0, 2, 0, 0], "LINEAR"),
        (1, "rotation", [0.0, 1.0], [0, 0, 0, 1, 0, 0, H, H], "LINEAR"),
    ])
    return b.save(path)


def write_md2(path, packed, scales, shifts, names, tris):
    """packed (K, V, 3) uint8, scales/shifts (K, 3), names K strings, tris (F, 3) vertex indices."""
    k, nv, _ = packed.shape
    framesize = 40 + 4 * nv
    ofs_skins = 68
    ofs_st = ofs_skins
    ofs_tris = ofs_st
    ofs_frames = ofs_tris + 12 * len(tris)
    ofs_glcmds = ofs_frames + k * framesize
    ofs_end = ofs_glcmds
    head = struct.pack("<4s16i", b"IDP2", 8, 64, 64, framesize, 0, nv, 0, len(tris), 0, k,
                       ofs_skins, ofs_st, ofs_tris, ofs_frames, ofs_glcmds, ofs_end)
    body = b"".join(struct.pack("<6H", *t, 0, 0, 0) for t in tris)
    for f in range(k):
        body += struct.pack("<3f3f16s", *scales[f], *shifts[f], names[f].encode())
        rec = np.zeros((nv, 4), dtype=np.uint8)
        rec[:, :3] = packed[f]
        body += rec.tobytes()
    path.write_bytes(head + body)
    return path


def write_obj(path, v, f):
    lines = [f"v {x!r} {y!r} {z!r}" for x, y, z in np.asarray(v, dtype=np.float64).tolist()]
    lines += ["f " + " ".join(str(i + 1) for i in face) for face in f]
    path.write_text("\n".join(lines) + "\n")


GRID_F = np.array([[0, 1, 4], [0, 4, 3], [1, 2, 5], [1, 5, 4]])


def grid_frame(k):
    """A 2x3 vertex sheet; the right column (vertices 2 and 5) rises with k, the rest stays."""
    v = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [0, 1, 0], [1, 1, 0], [2, 1, 0]], dtype=np.float64)
    v[[2, 5], 2] = 0.5 * k * k
    return v


# An anisotropic octahedron, off-centre; coordinates are exact in float32.
OCTA_V = np.array(
    [[1.5, 0.25, 0.5], [-0.5, 0.25, 0.5], [0.5, 1.75, 0.5], [0.5, -1.25, 0.5], [0.5, 0.25, 2.0], [0.5, 0.25, -1.0]],
    dtype=np.float32,
)


OCTA_F = np.array(
    [[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]], dtype=np.int32
)


OCTA_T = OCTA_V[OCTA_F]


def write_off(path, v, polys):
    lines = ["OFF", f"{len(v)} {len(polys)} 0"]
    lines += [f"{x!r} {y!r} {z!r}" for x, y, z in v.tolist()]
    lines += [f"{len(p)} " + " ".join(map(str, p)) for p in polys]
    path.write_text("\n".join(lines) + "\n")


def ply_header(fmt, nv, nf):
    return (
        f"ply\nformat {fmt} 1.0\nelement vertex {nv}\nproperty float x\nproperty float y\nproperty float z\n"
        f"element face {nf}\nproperty list uchar int vertex_indices\nend_header\n"
    )


def write_ply_ascii(path, v, f):
    body = [f"{x!r} {y!r} {z!r}" for x, y, z in v.tolist()] + ["3 " + " ".join(map(str, face)) for face in f]
    path.write_text(ply_header("ascii", len(v), len(f)) + "\n".join(body) + "\n")


def write_ply_binary(path, v, f):
    faces = np.zeros(len(f), dtype=[("n", "u1"), ("i", "<i4", (3,))])
    faces["n"] = 3
    faces["i"] = f
    path.write_bytes(
        ply_header("binary_little_endian", len(v), len(f)).encode() + v.astype("<f4").tobytes() + faces.tobytes()
    )


def write_stl_binary(path, tris):
    rec = np.zeros(len(tris), dtype=[("n", "<f4", (3,)), ("v", "<f4", (3, 3)), ("a", "<u2")])
    rec["v"] = tris
    path.write_bytes(b"\0" * 80 + struct.pack("<I", len(tris)) + rec.tobytes())


def write_stl_ascii(path, tris):
    lines = ["solid test"]
    for tri in tris.tolist():
        lines += ["facet normal 0 0 0", "outer loop"]
        lines += [f"vertex {x!r} {y!r} {z!r}" for x, y, z in tri]
        lines += ["endloop", "endfacet"]
    path.write_text("\n".join(lines + ["endsolid test"]) + "\n")
