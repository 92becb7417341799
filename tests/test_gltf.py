"""Animated glTF 2.0: node animation, linear-blend skinning, morph targets, samplers, clips.

References are independent of gridrt.scene.gltf:

* small glTF files are written here with pygltflib and their poses are computed analytically
  (a joint rotating about z by a known angle, a translation growing linearly in time, a morph
  weight ramp, a STEP staircase and a cubic Hermite segment from the specification's formula);
* the real files (assets/ ships two; the development data set, when present, more) are re-posed by a separate float64 numpy implementation that
  reads them with pygltflib, and their bind poses are compared with trimesh's loads;
* triangle counts are those listed with the development data set.
"""

import importlib.util
import json
import math
import struct
import warnings

import numpy as np
import pygltflib as gl
import pytest

import gridrt  # noqa: F401  (sets numba's thread count before numba loads)
from gridrt.errors import InputError, SceneFileError
from gridrt.scene import GltfAnimation, StaticMesh, make_scene
from gridrt.scene import gltf as gltf_module

from conftest import ASSETS, available, data_path
from helpers.scene_files import ARM_F, ARM_V, Builder, TRI_F, TRI_V, WEIGHT_KINDS, write_arm
HAVE_DRACO = importlib.util.find_spec("DracoPy") is not None


def need_data(rel):
    """A real file by its name in the development data set (assets/ ships some); skips when absent."""
    return data_path(rel)


# ----------------------------------------------------------------------------- a glTF writer


def rot_z(theta):
    c, s = math.cos(theta), math.sin(theta)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


# ----------------------------------------------------------------------------- skinning + node animation


def arm_expected(t, kind):
    """Analytic triangles of write_arm's scene at time t in [0, 2)."""
    _, rows, scale = WEIGHT_KINDS[kind]
    x = t  # root translation 0 -> 2 over 2 s
    theta = min(t, 1.0) * math.pi / 2  # slerp about a fixed axis: the angle grows linearly
    out = np.empty((6, 3))
    for v, p in enumerate(ARM_V.astype(np.float64)):
        w0, w1 = (np.array(rows[v // 2], dtype=np.float64) / scale)
        w0, w1 = w0 / (w0 + w1), w1 / (w0 + w1)
        on0 = p + [x, 0, 0]
        on1 = np.array([x, 1.0, 0.0]) + rot_z(theta) @ (p - [0, 1, 0])
        out[v] = w0 * on0 + w1 * on1
    arm = out[ARM_F]
    static = (TRI_V + [5.0, 0, 0])[TRI_F]
    carried = (TRI_V + [x, 0, 3.0])[TRI_F]
    return np.concatenate([arm, static, carried])  # depth-first order: arm (node 2) before 3, 0 -> 4


@pytest.mark.parametrize("kind", sorted(WEIGHT_KINDS))
@pytest.mark.parametrize("ext", [".glb", ".gltf"])
def test_skinning_and_node_animation_match_analytic_pose(tmp_path, kind, ext):
    p = write_arm(tmp_path / f"arm{ext}", kind)
    s = GltfAnimation(p)
    assert s.n_triangles == 6 and s.clips == ["walk"] and s.clip == "walk"
    assert s.time_range == (0.0, 2.0) and s.duration == 2.0 and not s.static
    for t in (0.0, 0.25, 0.5, 0.8, 1.0, 1.3, 1.99):
        got = s.triangles_at(t).astype(np.float64)
        # order: scene roots 0 (-> 1, 4), 2, 3 depth first -> carried (4), arm (2), static (3)
        exp = arm_expected(t, kind)
        exp = np.concatenate([exp[5:6], exp[:4], exp[4:5]])
        np.testing.assert_allclose(got, exp, atol=2e-6, err_msg=f"t={t}")
    # static mask: only the triangle under the non-animated node is static
    np.testing.assert_array_equal(s.static_mask, [False, False, False, False, False, True])
    assert s.n_static == 1
    # the clip loops: t and t + 2 give the same pose
    np.testing.assert_allclose(s.triangles_at(2.5), s.triangles_at(0.5), atol=1e-6)


def test_joint_rotation_keeps_bone_lengths(tmp_path):
    s = GltfAnimation(write_arm(tmp_path / "arm.glb", "f32"))
    frame = s.triangles_at(0.5).copy()
    s.vertices_at(1.5)  # poses the vertices without touching the returned triangle buffer
    np.testing.assert_array_equal(s.triangles_at(0.5), frame)
    for t in np.linspace(0, 1.9, 7):
        v = s.vertices_at(t).astype(np.float64)
        # the tip row (weights 100% on the elbow) stays 1 from the elbow (x, 1, 0)
        elbow = np.array([t, 1.0, 0.0])
        tip = v[[7, 8]]  # vertices 4, 5 of the arm (after the 3 vertices of the carried triangle)
        np.testing.assert_allclose(np.linalg.norm(tip - elbow, axis=1), [1.0, math.hypot(1.0, 0.2)], atol=1e-6)


def test_bind_pose_applies_node_transforms_only(tmp_path):
    s = GltfAnimation(write_arm(tmp_path / "arm.glb", "u8"))
    b = s.bind_triangles().astype(np.float64)
    np.testing.assert_allclose(b[0], (TRI_V + [0, 0, 3.0])[TRI_F][0])  # carried, root at rest
    np.testing.assert_allclose(b[1:5], (ARM_V + [10.0, 0, 0])[ARM_F])  # the arm node's own transform
    np.testing.assert_allclose(b[5], (TRI_V + [5.0, 0, 0])[TRI_F][0])


# ----------------------------------------------------------------------------- morph, STEP, CUBICSPLINE, clips

MORPH_D0 = np.array([[0, 0, 1], [0, 0, 0], [0, 0, 0]], dtype=np.float32)
MORPH_D1 = np.array([[0, 0, 0], [1, 0, 0], [0, 2, 0]], dtype=np.float32)
CUBIC = {"v0": [0, 0, 0], "out0": [3, 0, 0], "in1": [0, 3, 0], "v1": [1, 1, 0]}


def write_samplers(path, overlap=False):
    b = Builder()
    morph = b.mesh(TRI_V, TRI_F, targets=[MORPH_D0, MORPH_D1], weights=[0.0, 0.0])
    tri = b.mesh(TRI_V, TRI_F)
    b.node(root=True, name="morph", mesh=morph)  # 0
    b.node(root=True, name="step", mesh=tri)  # 1
    b.node(root=True, name="cubic", mesh=tri)  # 2
    z = [0.0, 0.0, 0.0]
    b.animation("main", [
        (0, "weights", [0.0, 1.0], [0, 0, 1, 0.5], "LINEAR"),
        (1, "translation", [0.0, 0.5, 1.0], [0, 0, 0, 1, 0, 0, 2, 0, 0], "STEP"),
        (2, "translation", [0.0, 1.0], z + CUBIC["v0"] + CUBIC["out0"] + CUBIC["in1"] + CUBIC["v1"] + z, "CUBICSPLINE"),
    ])
    spin_path = "translation" if overlap else "rotation"
    spin_vals = [0, 0, 0, 0, 5, 0] if overlap else [0, 0, 0, 1, 0, 0, 1, 0]
    b.animation("spin", [(1, spin_path, [0.0, 4.0], spin_vals, "LINEAR")])
    return b.save(path)


def hermite(s, p0, m0, p1, m1, dt=1.0):
    """Cubic Hermite segment, glTF 2.0 appendix C (written out independently)."""
    p0, m0, p1, m1 = (np.asarray(a, dtype=np.float64) for a in (p0, m0, p1, m1))
    return ((2 * s**3 - 3 * s**2 + 1) * p0 + (s**3 - 2 * s**2 + s) * dt * m0
            + (-2 * s**3 + 3 * s**2) * p1 + (s**3 - s**2) * dt * m1)


def test_morph_step_and_cubicspline_samplers(tmp_path):
    s = GltfAnimation(write_samplers(tmp_path / "samplers.glb", overlap=True), clip="main")
    assert s.clip == "main" and s.time_range == (0.0, 1.0)
    base = TRI_V.astype(np.float64)
    for t in (0.0, 0.2, 0.49, 0.5, 0.7, 0.999):
        got = s.triangles_at(t).astype(np.float64)
        w0, w1 = t, 0.5 * t
        np.testing.assert_allclose(got[0], base + w0 * MORPH_D0 + w1 * MORPH_D1, atol=1e-6, err_msg=f"t={t}")
        step = 0.0 if t < 0.5 else 1.0
        np.testing.assert_allclose(got[1], base + [step, 0, 0], atol=1e-6, err_msg=f"t={t}")
        cub = hermite(t, CUBIC["v0"], CUBIC["out0"], CUBIC["v1"], CUBIC["in1"])
        np.testing.assert_allclose(got[2], base + cub, atol=1e-5, err_msg=f"t={t}")
    assert s.n_static == 0


def test_clip_selection(tmp_path):
    p = write_samplers(tmp_path / "clips.gltf", overlap=True)
    s = GltfAnimation(p)  # the clips overlap (node 1 translation): the first plays
    assert s.clips == ["main", "spin"] and s.clip == "main"
    spin = GltfAnimation(p, clip="spin")
    assert spin.clip == "spin" and spin.time_range == (0.0, 4.0)
    np.testing.assert_allclose(spin.triangles_at(1.0)[1].astype(np.float64), TRI_V + [0, 1.25, 0], atol=1e-6)
    # morph and cubic nodes do not move in "spin"
    assert spin.static_mask.tolist() == [True, False, True]
    by_index = GltfAnimation(p, clip=1)
    np.testing.assert_array_equal(by_index.triangles_at(1.0), spin.triangles_at(1.0))
    for bad in ("run", 2, -1, 1.5):
        with pytest.raises(InputError) as info:
            GltfAnimation(p, clip=bad)
        if isinstance(bad, str):
            assert "'main'" in str(info.value) and "'spin'" in str(info.value)
    with pytest.raises(InputError, match="clip"):
        make_scene(p, clip="nope")


def test_disjoint_animations_play_together(tmp_path):
    s = GltfAnimation(write_samplers(tmp_path / "all.glb", overlap=False))
    assert s.clip == "all" and s.time_range == (0.0, 4.0)
    got = s.triangles_at(2.0).astype(np.float64)
    # node 1: STEP translation holds its last key (2, 0, 0); the spin slerps from identity to
    # 180 deg about z over 4 s, so at t = 2 it has turned 90 deg about z
    np.testing.assert_allclose(got[1], (rot_z(math.pi / 2) @ TRI_V.T).T + [2, 0, 0], atol=1e-6)


def test_static_gltf_with_node_weights_is_a_static_mesh(tmp_path):
    b = Builder()
    m = b.mesh(TRI_V, TRI_F, targets=[MORPH_D0, MORPH_D1], weights=[1.0, 1.0])
    b.node(root=True, mesh=m, translation=[0.0, 1.0, 0.0])
    p = b.save(tmp_path / "still.gltf")
    tree = json.loads(p.read_text())
    tree["nodes"][0]["weights"] = [0.25, 0.0]  # node weights override the mesh's (pygltflib lacks them)
    p.write_text(json.dumps(tree))
    s = make_scene(p)
    assert isinstance(s, StaticMesh)
    np.testing.assert_allclose(s.triangles_at(3.0)[0], TRI_V + 0.25 * MORPH_D0 + [0, 1, 0], atol=1e-6)
    assert GltfAnimation(p).static and GltfAnimation(p).duration is None


def test_strip_and_fan_primitives(tmp_path):
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0], [0, 2, 0]], dtype=np.float32)
    b = Builder()
    strip = b.mesh(v, np.arange(5), mode=gl.TRIANGLE_STRIP)
    fan = b.mesh(v, [0, 1, 3, 4], mode=gl.TRIANGLE_FAN)
    b.node(root=True, mesh=strip)
    b.node(root=True, mesh=fan, translation=[5, 0, 0])
    s = make_scene(b.save(tmp_path / "modes.glb"))
    got = s.triangles_at(0.0).astype(np.float64)
    # spec 3.7.2.1: strip triangle i = (v_i, v_(i+1+i%2), v_(i+2-i%2)); fan i = (v_(i+1), v_(i+2), v_0)
    exp_strip = v[[[0, 1, 2], [1, 3, 2], [2, 3, 4]]]
    exp_fan = v[[[1, 3, 0], [3, 4, 0]]] + [5, 0, 0]
    np.testing.assert_allclose(got, np.concatenate([exp_strip, exp_fan]))


def _without_indices(path):
    tree = json.loads(path.read_text())
    for mesh in tree["meshes"]:
        for prim in mesh["primitives"]:
            del prim["indices"]
    path.write_text(json.dumps(tree))
    return path


def test_non_indexed_primitives(tmp_path):
    """A primitive without indices uses its vertices in order; when they do not make whole triangles
    the error counts vertices, not indices."""
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0], [0, 2, 0], [2, 2, 0]], dtype=np.float32)
    b = Builder()
    b.node(root=True, mesh=b.mesh(v, [0]))
    b.node(root=True, mesh=b.mesh(v[:5], [0], mode=gl.TRIANGLE_STRIP), translation=[5, 0, 0])
    s = make_scene(_without_indices(b.save(tmp_path / "plain.gltf")))
    exp = np.concatenate([v[[[0, 1, 2], [3, 4, 5]]], v[[[0, 1, 2], [1, 3, 2], [2, 3, 4]]] + [5, 0, 0]])
    np.testing.assert_allclose(s.triangles_at(0.0).astype(np.float64), exp)
    b = Builder()
    b.node(root=True, mesh=b.mesh(v[:4], [0]))
    with pytest.raises(SceneFileError) as info:
        make_scene(_without_indices(b.save(tmp_path / "ragged.gltf")))
    assert info.value.problem.startswith("mesh 0 primitive 0: 4 vertices is not a multiple of 3 for TRIANGLES")
    assert "indices" not in info.value.problem


@pytest.mark.parametrize("asset,layout,problem", [
    ({"version": 1.0}, None, "glTF 1.0 is not supported (asset.version is 1.0)"),
    ({"version": 1}, None, "glTF 1.0 is not supported (asset.version is 1)"),
    ({"version": "1.0"}, None, "glTF 1.0 is not supported (asset.version is '1.0')"),
    ({}, "nodes", "glTF 1.0 is not supported (the file has no asset.version and 'nodes' is an object keyed by id"),
    (None, "scene", "glTF 1.0 is not supported (the file has no asset.version and 'scene' is a name"),
    ({"version": "3.0"}, None, "glTF version '3.0' is not supported; gridrt reads glTF 2.x only"),
], ids=["number-1.0", "number-1", "string", "keyed-nodes", "named-scene", "3.0"])
@pytest.mark.parametrize("ext", [".gltf", ".glb"])
def test_gltf_version_is_checked_by_every_loader(tmp_path, asset, layout, problem, ext):
    """A numeric asset.version (as some glTF 1.0 exporters write) once passed the check and ended in
    "'nodes' is not a list"; load_mesh (trimesh) said "NotImplementedError: only GLTF 2 is supported"."""
    from gridrt.scene import load_mesh

    b = Builder()
    b.node(root=True, mesh=b.mesh(TRI_V, TRI_F))
    p = b.save(tmp_path / f"tri{ext}")
    tree = json.loads(b.g.to_json() if ext == ".glb" else p.read_text())

    def write(tree):
        if ext == ".gltf":
            p.write_text(json.dumps(tree))
            return
        blob = b.g.binary_blob()
        js = json.dumps(tree).encode()
        js += b" " * (-len(js) % 4)
        p.write_bytes(struct.pack("<4sII", b"glTF", 2, 28 + len(js) + len(blob)) + struct.pack("<II", len(js), 0x4E4F534A)
                      + js + struct.pack("<II", len(blob), 0x004E4942) + blob)

    write({**tree, "asset": {"version": 2}})  # a numeric 2 is read as glTF 2
    assert make_scene(p).n_triangles == load_mesh(p).n_triangles == 1
    old = {k: v for k, v in tree.items() if k != "asset"}
    if asset is not None:
        old["asset"] = asset
    if layout == "nodes":
        old["nodes"] = {"n0": tree["nodes"][0]}
    elif layout == "scene":
        old["scene"] = "default"
    write(old)
    for load in (make_scene, load_mesh):
        with pytest.raises(SceneFileError) as info:
            load(p)
        assert info.value.path == str(p) and info.value.problem.startswith(problem), (load, info.value.problem)


def test_binary_gltf_1_is_named(tmp_path):
    """Binary glTF 1.0 (KHR_binary_glTF): container version 1."""
    from gridrt.scene import load_mesh

    js = json.dumps({"asset": {"version": "1.0"}, "nodes": {"n": {}}, "scene": "s", "scenes": {"s": {}}}).encode()
    js += b" " * (-len(js) % 4)
    p = tmp_path / "old.glb"
    p.write_bytes(struct.pack("<4sIIII", b"glTF", 1, 20 + len(js), len(js), 0) + js)
    for load in (make_scene, load_mesh):
        with pytest.raises(SceneFileError, match=r"glTF 1\.0 is not supported \(binary glTF 1\.0: \.glb container "
                                                 r"version 1\)"):
            load(p)


def test_sparse_morph_target(tmp_path):
    b = Builder()
    m = b.mesh(TRI_V, TRI_F)
    idx = b.view(np.array([2], dtype="<u2"))
    val = b.view(np.array([0.0, 0.0, 4.0], dtype="<f4"))
    b.g.accessors.append(gl.Accessor(componentType=gl.FLOAT, count=3, type="VEC3", sparse=gl.Sparse(
        count=1, indices=gl.AccessorSparseIndices(bufferView=idx, componentType=gl.UNSIGNED_SHORT),
        values=gl.AccessorSparseValues(bufferView=val))))
    b.g.meshes[m].primitives[0].targets = [gl.Attributes(POSITION=len(b.g.accessors) - 1)]
    b.node(root=True, mesh=m)
    b.animation("grow", [(0, "weights", [0.0, 1.0], [0.0, 1.0], "LINEAR")])
    s = GltfAnimation(b.save(tmp_path / "sparse.glb"))
    exp = TRI_V.astype(np.float64).copy()
    exp[2, 2] = 4.0 * 0.75
    np.testing.assert_allclose(s.triangles_at(0.75)[0], exp, atol=1e-6)


def test_animated_camera(tmp_path):
    b = Builder()
    tri = b.mesh(TRI_V, TRI_F)
    b.node(root=True, mesh=tri)
    b.g.cameras.append(gl.Camera(type="perspective", perspective=gl.Perspective(yfov=0.8, znear=0.1)))
    b.node(root=True, camera=0, translation=[0.0, 0.0, 5.0])
    b.animation("dolly", [(1, "translation", [0.0, 1.0], [0, 0, 5, 0, 0, 3], "LINEAR")])
    s = GltfAnimation(b.save(tmp_path / "cam.glb"))
    assert s.static  # the camera moves, no triangle does
    cam = s.camera_at(0.5)
    np.testing.assert_allclose(cam.eye, [0, 0, 4.0], atol=1e-12)
    np.testing.assert_allclose(np.subtract(cam.target, cam.eye), [0, 0, -1.0], atol=1e-12)
    assert cam.fov == pytest.approx(math.degrees(0.8))
    assert GltfAnimation(write_arm(tmp_path / "arm.glb", "u8")).camera_at(0.0) is None


# ----------------------------------------------------------------------------- real files


def features(tris):
    """Permutation-invariant summaries of a triangle set: sorted centroid and vertex coordinates, areas."""
    t = np.asarray(tris, dtype=np.float64)
    c = t.mean(axis=1)
    area = 0.5 * np.linalg.norm(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), axis=1)
    return [np.sort(c[:, k]) for k in range(3)] + [np.sort(t[:, :, k].ravel()) for k in range(3)] + [np.sort(area)]


REAL = {
    "CesiumMan": ("animated/cesium_man/CesiumMan.glb", 4672),
    "AnimatedMorphSphere": ("animated/animated_morph_sphere/AnimatedMorphSphere.gltf", 960),
    "BrainStem": ("animated/brainstem/BrainStem.glb", 61666),
    "LittlestTokyo": ("animated/littlest_tokyo/LittlestTokyo.glb", 141802),
}
#: the ones assets/ ships (tests run on them everywhere); the others only with the data set
#: (test_data_set_gltf_scenes)
SHIPPED_GLTF = ["AnimatedMorphSphere", "CesiumMan"]
POSE_TIMES = {"CesiumMan": (0.0, 0.37, 1.21), "AnimatedMorphSphere": (0.5, 2.2, 4.9), "BrainStem": (3.3, 11.0, 17.0)}
DRACO_TEAPOT = ASSETS / "teapot_draco.glb"  # assets/teapot.obj through Draco (tests/make_draco_asset.py)


def load_real(name):
    rel, n = REAL[name]
    p = need_data(rel)
    if name == "LittlestTokyo" and not HAVE_DRACO:
        pytest.skip("DracoPy is not installed: LittlestTokyo's Draco-compressed meshes cannot be decoded")
    return p, n


@pytest.mark.parametrize("name", SHIPPED_GLTF)
def test_real_bind_pose_equals_trimesh(name):
    check_bind_pose(name, *load_real(name))


def check_bind_pose(name, p, n):
    import trimesh

    s = GltfAnimation(p)
    assert s.n_triangles == n
    bind = s.bind_triangles()
    m = trimesh.load(str(p), force="mesh", process=False, skip_materials=True)
    ref = np.asarray(m.vertices)[np.asarray(m.faces)]
    assert len(ref) == n
    scale = np.ptp(ref.reshape(-1, 3), axis=0).max()
    fa, fb = features(bind), features(ref)
    for a, b in zip(fa[:6], fb[:6]):
        np.testing.assert_allclose(a, b, atol=2e-6 * scale, rtol=0)
    np.testing.assert_allclose(fa[6], fb[6], atol=1e-9 * scale**2, rtol=1e-4)  # areas


@pytest.mark.parametrize("name", SHIPPED_GLTF)
def test_real_static_mask_and_loop(name):
    check_static_mask_and_loop(name, load_real(name)[0])


def check_static_mask_and_loop(name, p):
    s = GltfAnimation(p)
    d = s.duration
    assert d is not None and d > 0
    frames = [s.triangles_at(t).copy() for t in (0.0, 0.31 * d, 0.77 * d)]
    m = s.static_mask
    for f in frames[1:]:
        np.testing.assert_array_equal(f[m], frames[0][m])
    moved = np.zeros(s.n_triangles, dtype=bool)
    for f in frames[1:]:
        moved |= (f != frames[0]).any(axis=(1, 2))
    assert moved[~m].mean() > 0.5  # the triangles called moving do move
    scale = np.ptp(frames[0].reshape(-1, 3), axis=0).max()
    np.testing.assert_allclose(s.triangles_at(0.31 * d + d), frames[1], atol=2e-5 * scale)
    if name == "LittlestTokyo":
        assert 0 < s.n_static < s.n_triangles  # a static town with a few moving parts
    else:
        assert s.n_static == 0


def reference_pose(path, t):
    """The scene at clip time t, computed with pygltflib + numpy float64 (LINEAR samplers only)."""
    g = gl.GLTF2().load(str(path))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # pygltflib warns that the .bin file is left "orphaned"
        g.convert_buffers(gl.BufferFormat.BINARYBLOB)
    blob = g.binary_blob()
    comp = {5121: "u1", 5123: "<u2", 5125: "<u4", 5126: "<f4"}
    ncomp = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT4": 16}

    def acc(i):
        a = g.accessors[i]
        bv = g.bufferViews[a.bufferView]
        dt = np.dtype(comp[a.componentType])
        n = ncomp[a.type]
        stride = bv.byteStride or dt.itemsize * n
        start = (bv.byteOffset or 0) + (a.byteOffset or 0)
        raw = np.frombuffer(blob, np.uint8, count=stride * (a.count - 1) + dt.itemsize * n, offset=start)
        out = np.lib.stride_tricks.as_strided(raw.view(dt), shape=(a.count, n), strides=(stride, dt.itemsize))
        out = out.astype(np.float64)
        if a.normalized:
            out /= np.iinfo(dt).max
        return out

    trs = {i: [np.array(nd.translation or [0, 0, 0], float), np.array(nd.rotation or [0, 0, 0, 1], float),
               np.array(nd.scale or [1, 1, 1], float)] for i, nd in enumerate(g.nodes)}
    for an in g.animations:
        for ch in an.channels:
            smp = an.samplers[ch.sampler]
            assert smp.interpolation == "LINEAR"
            ts = acc(smp.input)[:, 0]
            vs = acc(smp.output).reshape(len(ts), -1)
            k = int(np.clip(np.searchsorted(ts, t, side="right") - 1, 0, len(ts) - 1))
            if k == len(ts) - 1 or t <= ts[0]:
                val = vs[k if t > ts[0] else 0]
            else:
                s = (t - ts[k]) / (ts[k + 1] - ts[k])
                a, b = vs[k], vs[k + 1]
                if ch.target.path == "rotation":
                    if a @ b < 0:
                        b = -b
                    th = math.acos(min(1.0, a @ b))
                    if th < 1e-6:
                        val = a * (1 - s) + b * s
                    else:
                        val = (math.sin((1 - s) * th) * a + math.sin(s * th) * b) / math.sin(th)
                    val = val / np.linalg.norm(val)
                else:
                    val = (1 - s) * a + s * b
            if ch.target.path == "weights":
                trs[ch.target.node].append(val)
            else:
                trs[ch.target.node][["translation", "rotation", "scale"].index(ch.target.path)] = val

    def local(i):
        nd = g.nodes[i]
        if nd.matrix:
            return np.array(nd.matrix, float).reshape(4, 4).T
        tr, q, sc = trs[i][:3]
        x, y, z, w = q
        r = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                      [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                      [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
        m = np.eye(4)
        m[:3, :3] = r * sc
        m[:3, 3] = tr
        return m

    world, order = {}, []

    def walk(i, parent):
        world[i] = parent @ local(i)
        order.append(i)
        for c in g.nodes[i].children or []:
            walk(c, world[i])

    for r in g.scenes[g.scene or 0].nodes:
        walk(r, np.eye(4))
    tris = []
    for i in order:
        nd = g.nodes[i]
        if nd.mesh is None:
            continue
        mesh = g.meshes[nd.mesh]
        for prim in mesh.primitives:
            pos = acc(prim.attributes.POSITION)
            weights = trs[i][3] if len(trs[i]) > 3 else np.array(mesh.weights or [0.0] * len(prim.targets or []))
            for k, tg in enumerate(prim.targets or []):
                pos = pos + weights[k] * acc(tg["POSITION"] if isinstance(tg, dict) else tg.POSITION)
            ph = np.c_[pos, np.ones(len(pos))]
            if nd.skin is not None:
                sk = g.skins[nd.skin]
                ibm = acc(sk.inverseBindMatrices).reshape(-1, 4, 4).transpose(0, 2, 1)
                jm = np.array([world[j] for j in sk.joints]) @ ibm
                joints = acc(prim.attributes.JOINTS_0).astype(int)
                w = acc(prim.attributes.WEIGHTS_0)
                w = w / w.sum(axis=1, keepdims=True)  # CesiumMan's rows do not all sum to 1
                out = np.einsum("vk,vkij,vj->vi", w, jm[joints], ph)[:, :3]
            else:
                out = (ph @ world[i].T)[:, :3]
            idx = acc(prim.indices).astype(int).reshape(-1, 3)
            tris.append(out[idx])
    return np.concatenate(tris)


@pytest.mark.parametrize("name", SHIPPED_GLTF)
def test_real_pose_equals_numpy_reference(name):
    check_pose(name, load_real(name)[0], POSE_TIMES[name])


def check_pose(name, p, times):
    s = GltfAnimation(p)
    for t in times:
        ref = reference_pose(p, t)
        got = s.triangles_at(t).astype(np.float64)
        scale = np.ptp(ref.reshape(-1, 3), axis=0).max()
        np.testing.assert_allclose(got, ref, atol=5e-6 * scale, rtol=0, err_msg=f"{name} t={t}")


# ----------------------------------------------------------------------------- Draco


def test_data_set_gltf_scenes():
    """The checks above on the data set's glTF scenes that assets/ cannot ship (BrainStem: not to be
    shipped; LittlestTokyo: 4 MB, Draco-compressed), each one that is present."""
    found = available(*(REAL[n][0] for n in ("BrainStem", "LittlestTokyo")))
    for name in ("BrainStem", "LittlestTokyo"):
        rel, n = REAL[name]
        if rel not in found:
            continue
        p = found[rel]
        if name == "LittlestTokyo":
            if not HAVE_DRACO:
                print("DracoPy is not installed: LittlestTokyo's Draco-compressed meshes were not decoded")
                continue
            s = make_scene(p)
            assert isinstance(s, GltfAnimation) and s.n_triangles == n
            assert s.clip == "Take 001" and s.time_range == (0.0, 10.0)
            assert np.isfinite(s.triangles_at(2.0)).all()
        check_bind_pose(name, p, n)
        check_static_mask_and_loop(name, p)
        if name in POSE_TIMES:
            check_pose(name, p, POSE_TIMES[name])


@pytest.mark.skipif(not HAVE_DRACO, reason="DracoPy is not installed (pip install DracoPy, or the test extra)")
def test_draco_teapot_decodes_to_the_obj():
    """assets/teapot_draco.glb (16-bit quantized positions, the OBJ's vertex and face order) against
    assets/teapot.obj read by trimesh: the same faces, every coordinate within half a
    quantization step of the mesh's extent / (2^16 - 1) (and a few float32 ulp), through make_scene."""
    import trimesh

    obj = trimesh.load(str(ASSETS / "teapot.obj"), force="mesh", process=False)
    ref_v, ref_f = np.asarray(obj.vertices), np.asarray(obj.faces)
    s = make_scene(DRACO_TEAPOT)
    tris = s.triangles_at(0.0).astype(np.float64)
    assert tris.shape == (len(ref_f), 3, 3)
    step = np.ptp(ref_v, axis=0).max() / (2**16 - 1)
    err = np.abs(tris - ref_v[ref_f]).max()
    assert err <= 0.5 * step * 1.05, (err, step)  # (Draco dequantizes in float32: a few ulp more)
    assert err > 0  # it was quantized: the file really is the compressed one


def test_draco_without_dracopy_says_how_to_get_it(monkeypatch):
    p = DRACO_TEAPOT
    real_find_spec = importlib.util.find_spec
    monkeypatch.setattr(gltf_module.importlib.util, "find_spec",
                        lambda name, *a: None if name == "DracoPy" else real_find_spec(name, *a))
    with pytest.raises(SceneFileError) as info:
        GltfAnimation(p)
    assert info.value.path == str(p)
    assert "Draco" in info.value.problem and "pip install DracoPy" in info.value.problem
