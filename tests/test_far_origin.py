"""Every entry point works in a frame centred on the scene.

A real mesh, an animated glTF and a BART scene are moved far from the world origin (1e3 .. 1e9)
by writing them into new files with the offset in their coordinates (or in a root transform),
with the camera moved alike, and rendered through the real command line (``gridrt dump
--save-buffers``).  The hit buffers must be those of a float64 brute force over the scene at
offset 0 (tests/reference.py), with no more hit/miss disagreements than the dump at offset 0 has
plus 0.05 % of the pixels, and a median relative error of t below 1e-6.  The functional API
(build_grid / render / cast_rays), the viewer's worker and the float32 floor warning are checked
the same way.
"""

import json
import os
import shutil
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

from conftest import data_path
from reference import ref_camera_rays, ref_cast

REPO = Path(__file__).resolve().parents[1]
OFFSETS = (1e3, 1e5, 1e6, 1e7, 1e9)
W, H = 160, 120
#: direction of the offset: not along an axis, so every coordinate is large
AXIS = np.array([1.0, -0.7, 0.3])


def gridrt(*args, timeout=600):
    return subprocess.run([sys.executable, "-m", "gridrt", *args], cwd=REPO, capture_output=True, text=True,
                          timeout=timeout, env=dict(os.environ))


def vec(v):
    return ",".join(repr(float(x)) for x in v)


def dump_hits(tmp_path, tag, scene, eye, target, extra=(), size=(W, H)):
    """(t (N,), tri (N,)) of one frame of ``gridrt dump`` with an explicit camera."""
    out = tmp_path / tag
    r = gridrt("dump", "--scene", str(scene), "--frames", "1", "--size", f"{size[0]}x{size[1]}", "--save-buffers",
               f"--eye={vec(eye)}", f"--target={vec(target)}", "--out", str(out), "--no-progress", *extra)
    assert r.returncode == 0, r.stderr
    assert "Traceback" not in r.stderr
    return np.load(out / "frame_00000_t.npy").reshape(-1), np.load(out / "frame_00000_id.npy").reshape(-1)


def agreement(t, tri, ref):
    """(hit/miss disagreements, median relative t error over rays both hit)."""
    hit = tri >= 0
    flips = int((hit != ref.hit).sum())
    both = hit & ref.hit
    assert both.sum() > 0.05 * len(t), "the camera sees too little of the scene"
    rel = np.abs(t[both].astype(np.float64) - ref.t[both]) / ref.t[both]
    return flips, float(np.median(rel))


def check_offsets(results, ref, n):
    flips0, rel0 = results[0.0]
    assert rel0 < 1e-6
    for X, (flips, rel) in results.items():
        print(f"FIGURE far-origin offset {X:g}: {flips} of {n} pixels disagree on hit/miss "
              f"(offset 0: {flips0}), median relative t error {rel:.2e}")
        assert flips <= flips0 + 0.0005 * n, f"offset {X:g}: {flips} hit/miss disagreements (offset 0: {flips0})"
        assert rel < 1e-6, f"offset {X:g}: median relative t error {rel:.2e}"


def dump_moved(tmp_path, moved, eye, target, ref, t_anim, size, offsets=(0.0, 1e6, 1e9), extra=()):
    """{X: agreement} of the dump at time t_anim of the scene file ``moved(X, off)`` writes for each
    offset X (off = X * AXIS), with the camera moved alike (``extra``: more dump options)."""
    results = {}
    for X in offsets:
        off = X * AXIS
        t, tri = dump_hits(tmp_path, f"o{X:g}", moved(X, off), eye + off, target + off,
                           ("--t0", str(t_anim), *extra), size=size)
        results[X] = agreement(t, tri, ref)
    return results


def write_obj(path, v, f):
    with open(path, "w") as fh:
        fh.writelines("v %.17g %.17g %.17g\n" % tuple(p) for p in v)
        fh.writelines("f %d %d %d\n" % tuple(q) for q in f + 1)


def view_of(lo, hi, dist=1.3):
    c = 0.5 * (lo + hi)
    d = np.array([0.55, 0.45, 1.0])
    return c + d / np.linalg.norm(d) * dist * float(np.linalg.norm(hi - lo)), c


# ------------------------------------------------------------------------------------- mesh


@pytest.fixture(scope="module")
def teapot():
    from gridrt.scene import load_mesh

    m = load_mesh(data_path("static/utah_teapot/teapot.obj"))
    return m.vertices64, m.faces.astype(np.int64)


def test_dump_mesh_far_from_origin(teapot, tmp_path):
    v, f = teapot
    eye, target = view_of(v.min(axis=0), v.max(axis=0))
    o, d = ref_camera_rays(eye, target, (0, 1, 0), 45.0, W, H)
    ref = ref_cast(v[f], o, d)
    results = {}
    for X in (0.0,) + OFFSETS:
        off = X * AXIS
        write_obj(tmp_path / f"m{X:g}.obj", v + off, f)
        t, tri = dump_hits(tmp_path, f"m{X:g}", tmp_path / f"m{X:g}.obj", eye + off, target + off)
        results[X] = agreement(t, tri, ref)
        assert (tri[tri >= 0] < len(f)).all()
    check_offsets(results, ref, W * H)


@pytest.mark.slow  # (the second traversal and a deformed mesh: the quick run keeps the CGT dump)
def test_dump_mesh_far_from_origin_dda_and_deformed(teapot, tmp_path):
    """The single-ray traversal, and a twisted mesh (the deformer evaluates in the scene's frame)."""
    from gridrt.scene import Deform, Mesh

    v, f = teapot
    X = 1e7
    off = X * AXIS
    write_obj(tmp_path / "far.obj", v + off, f)
    eye, target = view_of(v.min(axis=0), v.max(axis=0))
    o, d = ref_camera_rays(eye, target, (0, 1, 0), 45.0, W, H)
    ref = ref_cast(v[f], o, d)
    t, tri = dump_hits(tmp_path, "dda", tmp_path / "far.obj", eye + off, target + off, ("--traversal", "dda"))
    flips, rel = agreement(t, tri, ref)
    assert flips <= 0.0005 * W * H and rel < 1e-6
    # twisted at t = 0.2: the reference is the same twist evaluated near the origin in float64 terms
    # (amplitude fixed so both twist alike)
    write_obj(tmp_path / "near.obj", v, f)
    amp = 0.3
    near = Deform(Mesh(v, f), kind="twist", amplitude=amp).triangles_at(0.2).astype(np.float64)
    ref_tw = ref_cast(near, o, d)
    t0, tri0 = dump_hits(tmp_path, "tw0", tmp_path / "near.obj", eye, target,
                         ("--animate", "twist", "--amplitude", str(amp), "--t0", "0.2"))
    tX, triX = dump_hits(tmp_path, "twX", tmp_path / "far.obj", eye + off, target + off,
                         ("--animate", "twist", "--amplitude", str(amp), "--t0", "0.2"))
    check_offsets({0.0: agreement(t0, tri0, ref_tw), X: agreement(tX, triX, ref_tw)}, ref_tw, W * H)


@pytest.mark.parametrize("scale", [1e-6, 1e6])
def test_dump_mesh_scaled_stays_exact(teapot, tmp_path, scale):
    v, f = teapot
    vs = v * scale
    eye, target = view_of(vs.min(axis=0), vs.max(axis=0))
    o, d = ref_camera_rays(eye, target, (0, 1, 0), 45.0, W // 2, H // 2)
    ref = ref_cast(vs[f], o, d)
    write_obj(tmp_path / "s.obj", vs, f)
    t, tri = dump_hits(tmp_path, "s", tmp_path / "s.obj", eye, target, size=(W // 2, H // 2))
    flips, rel = agreement(t, tri, ref)
    assert flips <= 0.0005 * len(t) and rel < 1e-6


# ------------------------------------------------------------------------------------- glTF


def _gltf_moved(src, dst, offset):
    """Copy a .gltf (+ its buffers) with every scene root under a new node translated by offset."""
    doc = json.loads(Path(src).read_text())
    for b in doc.get("buffers", []):
        if "uri" in b and not b["uri"].startswith("data:") and Path(src).parent != Path(dst).parent:
            shutil.copy(Path(src).parent / b["uri"], Path(dst).parent / b["uri"])
    nodes = doc.setdefault("nodes", [])
    for sc in doc["scenes"]:
        nodes.append({"children": list(sc["nodes"]), "translation": [float(x) for x in offset]})
        sc["nodes"] = [len(nodes) - 1]
    Path(dst).write_text(json.dumps(doc))


@pytest.mark.slow  # (the same dump far from the origin through another loader: the quick run keeps the mesh's)
def test_dump_animated_gltf_far_from_origin(tmp_path):
    from gridrt.scene import make_scene

    src = data_path("animated/animated_morph_sphere/AnimatedMorphSphere.gltf")
    t_anim = 1.3
    near = make_scene(str(src)).triangles_at(t_anim).astype(np.float64)
    p = near.reshape(-1, 3)
    eye, target = view_of(p.min(axis=0), p.max(axis=0))
    o, d = ref_camera_rays(eye, target, (0, 1, 0), 45.0, W, H)
    ref = ref_cast(near, o, d)
    def moved(X, off):
        dst = tmp_path / f"g{X:g}.gltf"
        _gltf_moved(src, dst, off)
        return dst

    check_offsets(dump_moved(tmp_path, moved, eye, target, ref, t_anim, (W, H)), ref, W * H)


def test_static_gltf_far_from_origin(tmp_path):
    """A glTF without animation becomes a static mesh (GltfAnimation.to_mesh): posed in float64 far
    from the origin, not through float32 world coordinates."""
    from gridrt.scene import make_scene

    src = data_path("animated/animated_morph_sphere/AnimatedMorphSphere.gltf")
    doc = json.loads(Path(src).read_text())
    doc.pop("animations")
    plain = tmp_path / "plain.gltf"
    plain.write_text(json.dumps(doc))
    for b in doc["buffers"]:
        shutil.copy(Path(src).parent / b["uri"], tmp_path / b["uri"])
    near = make_scene(str(plain))
    assert near.static
    X = 1e9
    far_path = tmp_path / "far.gltf"
    _gltf_moved(plain, far_path, X * AXIS)
    far = make_scene(str(far_path))
    ref = near.mesh.vertices64
    got = far.mesh.vertices64 - X * AXIS
    assert np.abs(got - ref).max() <= 1e-6 * np.abs(ref).max()


# ------------------------------------------------------------------------------------- BART


@pytest.mark.slow  # (the same dump far from the origin through another loader: the quick run keeps the mesh's)
def test_dump_bart_far_from_origin(tmp_path):
    from gridrt.scene import make_scene

    root = data_path("animated/bart/museum/aff/museum5.aff")
    t_anim, w, h = 0.7, 96, 72
    near = make_scene(str(root)).triangles_at(t_anim).astype(np.float64)
    eye, target = np.array([0.5, 1.7, -5.5]), np.array([0.0, 1.4, 0.0])  # inside the museum, facing the art
    o, d = ref_camera_rays(eye, target, (0, 1, 0), 45.0, w, h)
    ref = ref_cast(near, o, d)
    def moved(X, off):
        far = tmp_path / f"b{X:g}.aff"
        # a static transform (xs: scale, rotation axis and degrees, translation) around the whole scene
        tx, ty, tz = (float(x) for x in off)
        far.write_text(f"xs 1 1 1 0 1 0 0 {tx!r} {ty!r} {tz!r} {{\ni 0 {root}\n}}\n")
        return far

    # (the moved scene includes the museum from its own folder: a reference outside the scene's)
    check_offsets(dump_moved(tmp_path, moved, eye, target, ref, t_anim, (w, h), extra=("--allow-outside-refs",)),
                  ref, w * h)


# ------------------------------------------------------------------------------- Python API


def test_build_grid_render_cast_rays_far_from_origin(teapot):
    """build_grid centres a far scene (grid.origin) from its float64 triangles; render and
    cast_rays take world inputs; both agree with the brute force at offset 0."""
    import gridrt

    v, f = teapot
    eye, target = view_of(v.min(axis=0), v.max(axis=0))
    w, h = 80, 60
    o, d = ref_camera_rays(eye, target, (0, 1, 0), 45.0, w, h)
    ref = ref_cast(v[f], o, d)
    for X in (0.0, 1e7, 1e9):
        off = X * AXIS
        tris = v[f] + off  # float64 world triangles
        grid = gridrt.build_grid(tris)
        centre = 0.5 * (v.min(axis=0) + v.max(axis=0)) + off
        assert (grid.origin == 0).all() if X == 0 else np.allclose(grid.origin, centre, rtol=1e-12)
        img = gridrt.render(grid, tris, gridrt.Camera(tuple(eye + off), tuple(target + off)),
                            gridrt.RenderParams(w, h, traversal="dda"))
        flips, rel = agreement(img.t.reshape(-1), img.tri.reshape(-1), ref)
        assert flips <= 0.0005 * w * h and rel < 1e-6, X
        hits = gridrt.cast_rays(grid, tris, o + off, d)
        flips, rel = agreement(hits.t, hits.tri, ref)
        assert flips <= 0.0005 * w * h and rel < 1e-6, X


def test_viewer_worker_far_from_origin(teapot, tmp_path):
    """The viewer's render worker after a frame: the camera it reports is the world camera, and the
    frame it rendered is the brute force's image of the scene at offset 0."""
    from gridrt.app.viewer.state import SceneSpec
    from gridrt.app.viewer.worker import FrameJob, LoadJob, RenderWorker
    from gridrt.camera import Camera
    from gridrt.config import GridParams, RenderParams
    from gridrt.frame import FrameSpec, ViewSpec
    from gridrt.pipeline import FramePipeline

    v, f = teapot
    X = 1e9
    off = X * AXIS
    write_obj(tmp_path / "far.obj", v + off, f)
    eye, target = view_of(v.min(axis=0), v.max(axis=0))
    w, h = 64, 48
    spec = FrameSpec(scene=SceneSpec(source=str(tmp_path / "far.obj")), grid=GridParams(threads=1),
                     render=RenderParams(w, h, threads=1, shading="normal", traversal="dda"),
                     view=ViewSpec(size=(w, h)))
    pipes = []

    def factory(scene, job):
        pipes.append(FramePipeline.from_spec(job.spec, scene=scene))
        return pipes[-1]

    worker = RenderWorker(factory)
    try:
        worker.submit(LoadJob(spec))
        results = _wait(worker, 1)
        assert results[0].error is None, results[0].error
        cam = Camera(tuple(eye + off), tuple(target + off))
        worker.submit(FrameJob(spec.replace(view=spec.view.replace(eye=cam.eye, target=cam.target)), 0.0))
        res = _wait(worker, 1)[0]
        assert res.error is None, res.error
    finally:
        worker.stop()
    assert res.camera == cam  # world coordinates, as the viewer's camera controls expect
    assert np.allclose(pipes[0].origin, 0.5 * (v.min(axis=0) + v.max(axis=0)) + off, rtol=1e-12)
    o, d = ref_camera_rays(eye, target, (0, 1, 0), 45.0, w, h)
    ref = ref_cast(v[f], o, d)
    fr = pipes[0].step(0.0, camera=cam)
    flips, rel = agreement(fr.t.reshape(-1), fr.tri.reshape(-1), ref)
    assert flips <= 0.0005 * w * h and rel < 1e-6
    # the image the worker published is that frame's image
    assert np.array_equal(res.image, fr.image)


def _wait(worker, n, timeout=300):
    import time

    got = []
    t_end = time.time() + timeout
    while len(got) < n and time.time() < t_end:
        got += worker.take()
        time.sleep(0.01)
    assert len(got) >= n, "the worker produced no result"
    return got


# ------------------------------------------------------------------------------ the frame


def test_pipeline_frame_follows_a_moving_scene():
    """A scene that travels 1e8 units over its animation: the pipeline's frame follows it
    (re-centred when the scene drifted by more than its extent) and every frame stays exact."""
    from gridrt.camera import Camera
    from gridrt.config import GridParams, RenderParams
    from gridrt.pipeline import FramePipeline
    from gridrt.scene import KeyframeMesh, icosphere_mesh

    ico = icosphere_mesh(320)
    v = ico.vertices64
    path = np.array([0.0, 3e7, 1e8])
    frames = np.stack([v + p * AXIS for p in path] + [v + path[-1] * AXIS])  # frame 2 held for a second
    scene = KeyframeMesh(frames, ico.faces, fps=1.0)
    assert not scene.static
    pipe = FramePipeline(scene, GridParams(threads=1), RenderParams(48, 36, threads=1, traversal="dda"))
    origins = []
    for k, p in enumerate(path):
        eye = p * AXIS + np.array([0.3, 0.4, 3.0])
        fr = pipe.step(float(k), camera=Camera(tuple(eye), tuple(p * AXIS)))
        origins.append(fr.origin.copy())
        o, d = ref_camera_rays(eye - p * AXIS, (0, 0, 0), (0, 1, 0), 45.0, 48, 36)
        ref = ref_cast(v[ico.faces], o, d)
        flips, rel = agreement(fr.t.reshape(-1), fr.tri.reshape(-1), ref)
        assert flips <= 1 and rel < 1e-6, (k, flips, rel)
    assert pipe.recentred == 2
    assert np.allclose(origins[2], path[2] * AXIS, rtol=1e-9)


def test_float32_floor_warns():
    """Detail under FLOOR_STEPS float32 steps of the scene's own size is warned about (by the
    pipeline and by build_grid); an ordinary scene far from the origin is not."""
    import gridrt
    from gridrt.config import RenderParams
    from gridrt.pipeline import FramePipeline
    from gridrt.precision import FLOOR_STEPS, PrecisionWarning, detail_steps
    from gridrt.scene import Mesh, StaticMesh, icosphere_mesh

    ico = icosphere_mesh(1280)
    v = ico.vertices64
    far_away = v + 1e9 * AXIS
    with warnings.catch_warnings():
        warnings.simplefilter("error", PrecisionWarning)
        FramePipeline(StaticMesh(Mesh(far_away, ico.faces)), render_params=RenderParams(8, 6)).step(0.0)
        gridrt.build_grid(far_away[ico.faces])
    # the same sphere with one triangle 1e7 radii away: the frame is 1e7 across, the sphere's edges are
    # a few float32 steps of it
    D = 1e7
    V = np.concatenate([v - D / 2 * AXIS, [[D / 2, 0, 0], [D / 2, 1, 0], [D / 2, 0, 1]]])
    F = np.concatenate([ico.faces, [[len(v), len(v) + 1, len(v) + 2]]])
    _, _, steps = detail_steps(V[F] - 0.5 * (V.min(axis=0) + V.max(axis=0)))
    assert steps < FLOOR_STEPS
    with pytest.warns(PrecisionWarning, match="float32 steps"):
        pipe = FramePipeline(StaticMesh(Mesh(V, F)), render_params=RenderParams(8, 6))
        pipe.step(0.0)
    assert "median triangle edge" in pipe.precision_warning
    with pytest.warns(PrecisionWarning):
        gridrt.build_grid(V[F])
    # RayCaster: at construction, and when an update makes the mesh too fine (once, not every update)
    with pytest.warns(PrecisionWarning):
        assert gridrt.RayCaster(V, F).precision_warning is not None
    with warnings.catch_warnings():
        warnings.simplefilter("error", PrecisionWarning)
        caster = gridrt.RayCaster(far_away, ico.faces)
    stretched = far_away.copy()
    stretched[0] += 1e7 * AXIS  # one vertex 1e7 away: the mesh's frame is 1e7 across, its edges tiny
    with pytest.warns(PrecisionWarning):
        caster.update(stretched)
    with warnings.catch_warnings():
        warnings.simplefilter("error", PrecisionWarning)
        caster.update(stretched + 1.0)  # still too fine: said already
        caster.update(far_away)
    assert caster.precision_warning is None


def test_two_grids_in_different_frames_refused():
    """Grids traversed together must share a frame: a clear error naming the fix."""
    import gridrt
    from conftest import icosphere_tris

    near = icosphere_tris(1, 0.5)
    far = icosphere_tris(1, 0.5, center=(30.0, 0.0, 0.0))  # centred by build_grid: 30 > its extent
    ga, gb = gridrt.build_grid(near), gridrt.build_grid(far)
    cam = gridrt.Camera((0, 0, 1.5), (0, 0, 0))
    ids_a, ids_b = np.arange(len(near), dtype=np.int32), np.arange(len(far), dtype=np.int32) + len(near)
    with pytest.raises(gridrt.InputError, match="origin=first.origin"):
        gridrt.Renderer().render(ga, near, cam, gridrt.RenderParams(8, 6), second=(gb, far, ids_a, ids_b))
    gb = gridrt.build_grid(far, origin=ga.origin)
    res = gridrt.Renderer().render(ga, near, cam, gridrt.RenderParams(8, 6), second=(gb, far, ids_a, ids_b))
    assert (res.tri >= 0).any()


def test_dump_warns_at_the_float32_floor(teapot, tmp_path):
    """Through the CLI: a scene 1e7 teapots across with the teapot at one end renders (exit 0) with
    one clean warning line naming the problem; an ordinary far scene gets none."""
    v, f = teapot
    size = float((v.max(axis=0) - v.min(axis=0)).max())
    D = 1e7 * size
    V = np.concatenate([v - [D / 2, 0, 0], [[D / 2, 0, 0], [D / 2, size, 0], [D / 2, 0, size]]])
    F = np.concatenate([f, [[len(v), len(v) + 1, len(v) + 2]]])
    write_obj(tmp_path / "wide.obj", V, F)
    eye, target = view_of(v.min(axis=0), v.max(axis=0))
    r = gridrt("dump", "--scene", str(tmp_path / "wide.obj"), "--frames", "1", "--size", "16x12", "--no-progress",
               f"--eye={vec(eye - [D / 2, 0, 0])}", f"--target={vec(target - [D / 2, 0, 0])}", "--out", str(tmp_path / "w"))
    assert r.returncode == 0, r.stderr
    lines = [ln for ln in r.stderr.splitlines() if "warning" in ln.lower()]
    assert len(lines) == 1 and lines[0].startswith("gridrt: warning: ") and "float32 steps" in lines[0], r.stderr
    assert "Traceback" not in r.stderr and "warnings.warn" not in r.stderr
    write_obj(tmp_path / "far.obj", v + 1e9 * AXIS, f)
    r = gridrt("dump", "--scene", str(tmp_path / "far.obj"), "--frames", "1", "--size", "16x12", "--no-progress",
               "--out", str(tmp_path / "f"))
    assert r.returncode == 0 and "warning" not in r.stderr.lower(), r.stderr
