"""``gridrt bench native``: the folders it writes for the native Embree harness hold the scene's own
triangles, frames and rays in the harness's format, and with the harness built (from its sources
beside the repository, when they and Embree 3's headers are there) the quick run compares the two
tracers on the same rays, gridrt's hits right against the float64 brute force."""

import json

import numpy as np
import pytest
import trimesh

from reference import ref_cast

from helpers.bench import check_outputs

from gridrt.app.__main__ import main
from gridrt.app.bench.native import NATIVE_WARMUP
from gridrt.app.bench.scenes import camera_rays, resolve_scene
from gridrt.camera import Camera

QUICK_SCENE = "icosphere:1280:twist"


def _export(tmp_path, *extra):
    folder = tmp_path / "export"
    assert main(["bench", "native", "--quick", "--no-progress", "--export", str(folder), "--export-only",
                 *extra]) == 0
    return folder / "icosphere_1280_twist"


def test_export_writes_the_harness_folder(tmp_path):
    """Every file the harness reads, with its dtype and shape; the mesh and frames are the scene's
    own triangles at the frames' times (its pipeline frame), the camera rays those of the camera
    camera.json names, the random rays inside the bounds with unit directions."""
    d = _export(tmp_path, "--dt", "0.05")
    meta = json.loads((d / "meta.json").read_text())
    V, F = np.load(d / "vertices.npy"), np.load(d / "faces.npy")
    frames = np.load(d / "frames.npy")
    assert V.dtype == np.float32 and F.dtype == np.int32 and frames.dtype == np.float32
    sc = resolve_scene(QUICK_SCENE)
    origin = sc.scene.frame_origin(0.0)
    n = NATIVE_WARMUP + 1  # the quick run times one frame
    assert frames.shape == (n, len(V), 3) and meta["timed_frames"] == 1 and meta["warmup_frames"] == NATIVE_WARMUP
    for i in range(n):
        want = np.asarray(sc.scene.triangles_at(0.05 * i, origin=origin), np.float32)
        np.testing.assert_array_equal(frames[i][F], want)
    np.testing.assert_array_equal(V, frames[0])
    assert meta["triangles"] == len(F) == 1280 and meta["vertices"] == len(V)
    # the PLY holds the same triangles (read by trimesh, not by the code that wrote it)
    m = trimesh.load(d / "mesh.ply", process=False)
    np.testing.assert_array_equal(np.asarray(m.vertices, np.float32)[np.asarray(m.faces)], frames[0][F])
    # camera rays: those of the camera camera.json describes, as the bench's fill view gives them
    cam = json.loads((d / "camera.json").read_text())
    o, dd = Camera(eye=tuple(cam["eye"]), target=tuple(cam["target"]), up=tuple(cam["up"]), fov=cam["fov"]).rays(64, 64)
    po, pd = np.load(d / "primary_origins.npy"), np.load(d / "primary_directions.npy")
    assert po.shape == pd.shape == (64 * 64, 3) and po.dtype == pd.dtype == np.float32 and meta["res"] == 64
    np.testing.assert_array_equal(po, np.asarray(o, np.float32))
    np.testing.assert_array_equal(pd, np.asarray(dd, np.float32))
    _, _, fo, fd, _, _ = camera_rays(sc, 64, fill=True)
    np.testing.assert_array_equal(pd, fd)
    io, idr = np.load(d / "incoherent_origins.npy"), np.load(d / "incoherent_directions.npy")
    assert io.shape == idr.shape == (64 * 64, 3) and len(io) % 64 == 0 and meta["incoherent"] == len(io)
    lo, hi = frames[0].min(axis=0), frames[0].max(axis=0)
    assert (io >= lo).all() and (io <= hi).all()
    np.testing.assert_allclose(np.linalg.norm(idr.astype(np.float64), axis=1), 1.0, atol=1e-6)
    assert (np.ptp(np.sign(idr), axis=0) == 2).all()  # directions of every sign on every axis


@pytest.mark.parametrize("args,message", [
    (["--size", "60"], "multiple of 8"),
    (["--export-only"], "--export DIR"),
    (["--native-bin", "/nonexistent/embree_bench"], "no native Embree harness at /nonexistent/embree_bench"),
])
def test_bench_native_bad_arguments(tmp_path, capsys, args, message):
    assert main(["bench", "native", "--quick", "--no-progress", "--out", str(tmp_path / "x"), *args]) == 2
    assert message in capsys.readouterr().err


def test_bench_native_quick_against_the_harness(tmp_path, harness):
    """Both tracers on the same rays at 1 and 2 threads: every figure present, the native hit
    fraction that of gridrt's hits, which equal the float64 brute force; the harness's saved hits
    agree with gridrt's on nearly every ray and every disagreement is judged: gridrt's are right or
    within float32 rounding of an edge."""
    out, exp = tmp_path / "out", tmp_path / "export"
    assert main(["bench", "native", "--quick", "--no-progress", "--out", str(out), "--threads", "1,2",
                 "--native-bin", str(harness), "--export", str(exp)]) == 0
    rows, summary = check_outputs(out, "native.csv", ["native.png"])
    assert [int(r["threads"]) for r in rows] == [1, 2]
    for head in ("## Arbitrary rays", "## Camera rays", "## Dynamic frames", "## Hit agreement"):
        assert head in summary
    d = exp / "icosphere_1280_twist"
    tris = np.load(d / "frames.npy")[0].reshape(-1, 3, 3)
    for rays, key in (("incoherent", "random"), ("primary", "camera")):
        o, dr = np.load(d / f"{rays}_origins.npy"), np.load(d / f"{rays}_directions.npy")
        ref_f = ref_cast(tris.astype(np.float64), o.astype(np.float64), dr.astype(np.float64)).tri
        for r in rows:
            assert float(r[f"o_hit_{key}"]) == pytest.approx((ref_f >= 0).mean(), abs=2 / len(o))
            for m in ("1", "p16", "1M"):
                assert float(r[f"n_mrays_{key}_{m}"]) > 0
        native_tri = np.load(d / "hits" / f"{rays}_{'p16' if key == 'camera' else '1'}_tri.npy")
        assert abs((native_tri >= 0).mean() - (ref_f >= 0).mean()) <= 4 / len(o)
        first = rows[0]
        assert float(first[f"{key}_agree"]) >= 0.999
        assert int(first[f"{key}_checked"]) == min(int(first[f"{key}_disagree"]), 256)
        # every disagreement gridrt has is right, or within float32 rounding of a shared edge
        assert int(first[f"{key}_ours_right"]) + int(first[f"{key}_ours_edge"]) == int(first[f"{key}_checked"])
    for r in rows:
        assert float(r["o_frame_ms"]) > 0 and float(r["n_refit_frame_ms"]) > 0 and float(r["n_rebuild_frame_ms"]) > 0
        assert float(r["random_over_native"]) == pytest.approx(float(r["o_mrays_random"]) / float(r["n_mrays_random"]))


def _peers_export(tmp_path, monkeypatch, views):
    """A quick ``bench peers`` run with --export: the folders, and the rays and triangles gridrt's
    batch cast got from that run (a spy on cast_rays), per view in the run's order."""
    from gridrt.app.bench import peers

    cast = []
    real = peers.cast_rays

    def spy(g, tris, o, d, **kw):
        cast.append((np.array(tris, np.float32), np.array(o), np.array(d)))
        return real(g, tris, o, d, **kw)

    monkeypatch.setattr(peers, "cast_rays", spy)
    exp = tmp_path / "export"
    assert main(["bench", "peers", "--quick", "--no-progress", "--out", str(tmp_path / "out"), "--threads", "1",
                 "--views", views, "--dt", "0.05", "--export", str(exp)]) == 0
    return exp, cast


def test_peers_export_holds_the_rays_and_frames_the_peers_cast(tmp_path, monkeypatch):
    """``bench peers --export``: one harness folder per camera view, whose primary rays are the very
    arrays that view's run cast, whose incoherent rays are those the random view cast, and whose
    frames are the triangles each of the run's frames cast against (the harness's format: the
    vertices unshared, warm-up frames first)."""
    exp, cast = _peers_export(tmp_path, monkeypatch, "frame,fill,random")
    assert sorted(p.name for p in exp.iterdir()) == ["icosphere_1280_twist_fill", "icosphere_1280_twist_frame"]
    runs = 2  # the quick run: 1 warm-up frame and 1 timed, then 1 static cast on the last frame
    by_view = {v: cast[i * (runs + 1):(i + 1) * (runs + 1)] for i, v in enumerate(("frame", "fill", "random"))}
    assert len(cast) == 3 * (runs + 1)
    for view in ("frame", "fill"):
        d = exp / f"icosphere_1280_twist_{view}"
        frames, F = np.load(d / "frames.npy"), np.load(d / "faces.npy")
        assert frames.shape[0] == NATIVE_WARMUP + 1  # (the harness times at least one frame after its warm-up)
        for i, (tris, o, dr) in enumerate(by_view[view][:runs]):
            np.testing.assert_array_equal(frames[i][F], tris)
            np.testing.assert_array_equal(np.load(d / "primary_origins.npy"), o.astype(np.float32))
            np.testing.assert_array_equal(np.load(d / "primary_directions.npy"), dr.astype(np.float32))
            assert np.array_equal(o.astype(np.float32).astype(np.float64), o)  # (float32 rays, given once)
        _, ro, rd = by_view["random"][0]
        np.testing.assert_array_equal(np.load(d / "incoherent_origins.npy"), ro.astype(np.float32))
        np.testing.assert_array_equal(np.load(d / "incoherent_directions.npy"), rd.astype(np.float32))
        meta = json.loads((d / "meta.json").read_text())
        assert meta["mesh"] == f"icosphere:1280:twist [{view}]" and meta["res"] == 64
        cam = json.loads((d / "camera.json").read_text())
        o, dd = Camera(eye=tuple(cam["eye"]), target=tuple(cam["target"]), up=tuple(cam["up"]),
                       fov=cam["fov"]).rays(64, 64)
        np.testing.assert_array_equal(np.load(d / "primary_directions.npy"), np.asarray(dd, np.float32))
    # the two views' cameras differ (fill moves in), the random rays are shared
    assert not np.array_equal(np.load(exp / "icosphere_1280_twist_fill" / "primary_origins.npy"),
                              np.load(exp / "icosphere_1280_twist_frame" / "primary_origins.npy"))


def test_peers_export_only_random_uses_the_scene_camera(tmp_path):
    """With no camera view in --views the folder's primary rays are the scene's own camera's (the frame
    view's); --export-only measures nothing and writes no output folder."""
    exp = tmp_path / "export"
    assert main(["bench", "peers", "--quick", "--no-progress", "--views", "random", "--export", str(exp),
                 "--export-only", "--out", str(tmp_path / "out")]) == 0
    assert [p.name for p in exp.iterdir()] == ["icosphere_1280_twist_frame"]
    assert not (tmp_path / "out").exists()
    _, _, fo, fd, _, _ = camera_rays(resolve_scene(QUICK_SCENE), 64)
    np.testing.assert_array_equal(np.load(exp / "icosphere_1280_twist_frame" / "primary_directions.npy"), fd)


@pytest.mark.parametrize("args,message", [
    (["--export-only"], "--export DIR"),
    (["--export", "EXP", "--size", "60"], "multiple of 8"),
])
def test_bench_peers_export_bad_arguments(tmp_path, capsys, args, message):
    args = [str(tmp_path / "e") if x == "EXP" else x for x in args]
    assert main(["bench", "peers", "--no-progress", "--out", str(tmp_path / "x"), "--threads", "1", *args]) == 2
    assert message in capsys.readouterr().err


def test_the_harness_casts_the_peers_export(tmp_path, harness):
    """The native harness runs on a ``bench peers`` folder as it is written, and its hits on the
    camera and random rays are the float64 brute force's."""
    exp = tmp_path / "export"
    assert main(["bench", "peers", "--quick", "--no-progress", "--views", "fill,random", "--export", str(exp),
                 "--export-only"]) == 0
    from gridrt.app.bench.native import run_harness

    d = exp / "icosphere_1280_twist_fill"
    hdir = tmp_path / "hits"
    hdir.mkdir()
    res = run_harness(harness, ["static", d, 1, 1, "--hits", hdir])
    assert {r["rays"] for r in res if r["kind"] == "cast"} == {"primary", "incoherent"}
    tris = np.load(d / "frames.npy")[0].reshape(-1, 3, 3).astype(np.float64)
    for rays, mode in (("primary", "p16"), ("incoherent", "1")):
        o, dr = np.load(d / f"{rays}_origins.npy"), np.load(d / f"{rays}_directions.npy")
        ref = ref_cast(tris, o.astype(np.float64), dr.astype(np.float64)).tri
        native = np.load(hdir / f"{rays}_{mode}_tri.npy")
        assert (ref >= 0).any() and (ref < 0).any()
        assert (native == ref).mean() >= 0.995


@pytest.mark.parametrize("command,scene_folder", [("native", "icosphere_1280_twist"),
                                                  ("peers", "icosphere_1280_twist_frame")])
def test_export_where_no_folder_can_be_made(tmp_path, capsys, command, scene_folder):
    """--export naming a file, a folder under a file, or a folder where a file holds a scene's
    folder's name: a clear error naming the path, before anything is measured, and no traceback."""
    blocker = tmp_path / "a_file"
    blocker.write_bytes(b"not a folder")
    taken = tmp_path / "taken"
    taken.mkdir()
    (taken / scene_folder).write_bytes(b"not a folder")
    for export, message in ((blocker, f"cannot create the --export folder {blocker}"),
                            (blocker / "sub", f"cannot create the --export folder {blocker / 'sub'}"),
                            (taken, f"cannot write the harness folder {taken / scene_folder}")):
        assert main(["bench", command, "--quick", "--no-progress", "--export", str(export), "--export-only"]) == 2
        err = capsys.readouterr().err
        assert message in err and "Traceback" not in err, err
    assert blocker.read_bytes() == b"not a folder" and (taken / scene_folder).read_bytes() == b"not a folder"
