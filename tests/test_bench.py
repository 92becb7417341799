"""Smoke tests of ``gridrt bench`` (every subcommand on a tiny scene with --quick) and checks of
the benchmark's own references (app/bench/reference.py) against tests/reference.py.

The bench's error figures are recomputed here independently: the engine's image at the sampled
pixels against ``reference.ref_cast`` on ``reference.ref_camera_rays``.
"""

import json
import os
import sys

import numpy as np
import pytest

import gridrt
from PIL import Image

from conftest import icosphere, icosphere_tris, random_triangles
from reference import compare_hits, ref_camera_rays, ref_cast

from helpers.bench import check_outputs, read_csv

from gridrt.app.__main__ import main
from gridrt.app.bench.scenes import facing_camera, parse_scene_spec
from gridrt.app.bench.stats import pareto_front
from gridrt.app.bench.reference import brute_cast, compare_to_reference, count_holes, pixel_rays, probe_rays, sample_pixels


# ----------------------------------------------------------------------------------------------
# the bench's references


def test_brute_cast_matches_reference(rng):
    tris = np.concatenate([random_triangles(rng, 150, size=0.3), icosphere_tris(2, 0.4, (0.5, 0.5, 0.5))])
    o = rng.uniform(-1.0, 2.0, (300, 3))
    d = rng.uniform(0.2, 0.8, (300, 3)) - o + rng.normal(0, 0.2, (300, 3))
    t, f, t2 = brute_cast(tris, o, d, threads=1)
    ref = ref_cast(tris, o, d)
    diff = compare_hits(t, f, ref, t_rtol=1e-12)
    assert len(diff.bad) == 0 and len(diff.t_off) == 0
    assert (f >= 0).sum() > 100
    hit = f >= 0
    assert np.allclose(t2[hit], ref.t2[hit], rtol=1e-12)
    # tmin / tmax are open bounds, as in the reference
    t_lim, f_lim, _ = brute_cast(tris, o, d, tmin=0.5, tmax=1.5)
    ref = ref_cast(tris, o, d, 0.5, 1.5)
    assert len(compare_hits(t_lim, f_lim, ref, t_rtol=1e-12).bad) == 0


def test_pixel_rays_match_reference_camera():
    cam = facing_camera(np.array([-1.0, -2.0, -0.5]), np.array([1.0, 2.0, 0.25]))
    xs, ys = sample_pixels(40, 30, 200, seed=3)
    assert len(set(zip(xs.tolist(), ys.tolist()))) == 200 and xs.max() < 40 and ys.max() < 30
    o, d = pixel_rays(cam.eye, cam.target, cam.up, cam.fov, 40, 30, xs, ys)
    ro, rd = ref_camera_rays(cam.eye, cam.target, cam.up, cam.fov, 40, 30)
    assert np.allclose(o, ro[ys * 40 + xs]) and np.allclose(d, rd[ys * 40 + xs], atol=1e-14)


def test_probe_rays_enter_a_closed_mesh_at_their_target():
    v, f = icosphere(2, 1.3, (0.2, -0.1, 0.4))
    o, d, dist = probe_rays(v, f, 1200, seed=5)
    assert len(o) > 1100
    assert np.allclose(np.linalg.norm(d, axis=1), 1.0)
    centre = v.astype(np.float64).mean(axis=0)
    assert (np.linalg.norm(o - centre, axis=1) > 1.3).all()
    target = o + d * dist[:, None]
    # every target lies on an edge or vertex: distance to the nearest vertex or edge line ~ 0
    vv = v.astype(np.float64)
    ea, eb = vv[f[:, [0, 1, 2]]].reshape(-1, 3), vv[f[:, [1, 2, 0]]].reshape(-1, 3)
    ab = eb - ea
    s = np.clip(np.einsum("nkc,kc->nk", target[:, None] - ea, ab) / (ab * ab).sum(1), 0, 1)
    near = np.linalg.norm(target[:, None] - (ea + s[..., None] * ab), axis=2).min(axis=1)
    assert near.max() < 1e-6
    # independent float64 brute force: nothing before the surface is missed; a ray either hits no
    # later than its target or passes within rounding of an edge (Moller-Trumbore is not watertight)
    ref = ref_cast(v[f], o, d)
    ok = (ref.tri >= 0) & (ref.t <= dist * (1 + 1e-6))
    assert (ok | (ref.graze >= -1e-9)).all()
    assert ok.mean() > 0.5
    assert count_holes(ref.t, ref.tri, dist) == int((~ok).sum())


def test_probe_rays_reject_an_open_mesh():
    from gridrt.errors import InputError

    v, f = icosphere(1)
    with pytest.raises(InputError, match="not closed"):
        probe_rays(v, f[1:], 100)


def test_compare_to_reference_counts_by_hand():
    ref_t = np.array([1.0, 2.0, np.inf, 3.0, 4.0])
    ref_f = np.array([0, 1, -1, 2, 3])
    ref_t2 = np.array([5.0, 2.0, np.inf, np.inf, 4.5])  # sample 1: two triangles at t = 2 (a tie)
    tri = np.array([0, 7, -1, -1, 4])
    t = np.array([1.0 + 1e-7, 2.0, np.inf, np.inf, 4.25])
    c = compare_to_reference(tri, t, ref_f, ref_t, ref_t2)
    assert (c["differs"], c["ties"], c["both_hit"]) == (2, 1, 3)
    assert c["dt_max"] == pytest.approx(0.25) and c["dt_mean"] == pytest.approx((1e-7 + 0 + 0.25) / 3)


def test_pareto_front_by_hand():
    pts = [(10.0, 0.0, 0.0), (5.0, 0.1, 0.0), (20.0, 0.0, 0.0), (5.1, 0.1, 0.0), (4.0, 0.0, 5.0), (30.0, 0.5, 0.0)]
    # 2 is slower than 0 at the same error; 5 is worse than 0 in both; 3 ties 1 within 3%
    assert pareto_front(pts) == [0, 1, 3, 4]
    assert pareto_front(pts, rel_tol=0.0) == [0, 1, 4]


def test_scene_specs():
    assert parse_scene_spec("marbles:2k") == ("marbles", {"count": 2000})
    assert parse_scene_spec("icosphere:1.3M:twist") == ("icosphere", {"count": 1300000, "animate": "twist"})
    from gridrt.errors import InputError

    with pytest.raises(InputError, match="neither"):
        parse_scene_spec("marbles:lots")


# ----------------------------------------------------------------------------------------------
# the subcommands


def test_bench_core_quick(tmp_path):
    out = tmp_path / "core"
    assert main(["bench", "core", "--quick", "--no-progress", "--out", str(out), "--threads", "1",
                 "--traversal", "dda"]) == 0
    rows, summary = check_outputs(out, "core.csv", ["core.png"])
    builds = [r for r in rows if r["what"].startswith("serial build")]
    assert {r["what"] for r in builds} == {"serial build bbox", "serial build exact"}
    bbox, exact = (next(r for r in builds if r["what"].endswith(k)) for k in ("bbox", "exact"))
    assert int(exact["references"]) < int(bbox["references"])  # exact insertion drops references
    for r in rows:
        assert float(r["min_ms"]) <= float(r["median_ms"]) <= float(r["max_ms"])


def check_grid_columns(r, stats, triangles):
    """A bench row's grid columns against the stats of an independent build (or frame) of the same triangles."""
    assert r["grid_built"] == stats["grid"]
    for k in ("cells", "references", "grid_bytes"):
        assert int(r[k]) == stats[k], k
    assert float(r["bytes_per_tri"]) == pytest.approx(stats["grid_bytes"] / triangles, rel=1e-6)


def test_bench_build_quick(tmp_path):
    """Strategies x grid kinds x threads side by side; every row's grid is the one an independent build of
    the scene makes, and rendering it gives the row its render ms and tests and cells per ray."""
    from gridrt import GridParams, build_grid
    from gridrt.scene import make_scene

    out = tmp_path / "build"
    assert main(["bench", "build", "--quick", "--no-progress", "--out", str(out), "--strategies",
                 "serial,sort_middle", "--threads", "1,2", "--grid", "uniform,two_level", "--top-density", "0.125"]) == 0
    rows, summary = check_outputs(out, "build_sweep.csv", ["build_methods.png", "build_steps.png"])
    kinds = ("uniform", "two_level")
    assert {(r["strategy"], r["grid"], r["threads"]) for r in rows} == {
        (s, g, t) for s in ("serial", "sort_middle") for g in kinds for t in "12"}
    tris = make_scene("icosphere", count=1280).triangles_at(0.0)
    for g in kinds:
        stats = build_grid(tris, GridParams(grid=g, top_density=0.125)).stats
        for r in (r for r in rows if r["grid"] == g):
            check_grid_columns(r, stats, 1280)
            assert (float(r["top_density"]), float(r["leaf_density"])) == (0.125, 2.0)
            assert r["render_size"] == "64" and float(r["render_ms_min"]) <= float(r["render_ms"]) > 0
            assert float(r["tests_per_ray"]) > 0 and float(r["cells_per_ray"]) > 0
            assert (r["leaf_count_ms"] != "") == (g == "two_level")  # (the leaf passes: a two-level grid's stages)
    assert "sort_middle (two_level)" in summary and "Memory traffic" in summary and "Grid kinds at 2 thread(s)" in summary
    # the traffic model's columns ride along in the CSV (a uniform grid's: the model has no leaf
    # passes); its total is the sum of its stages
    for r in rows:
        stages = [k for k in r if k.endswith("_mb") and k != "model_mb" and r[k] != ""]
        if r["grid"] == "two_level":
            assert r["model_mb"] == "" and not stages
            continue
        assert {"bounds_mb", "count_mb", "scatter_mb", "macro_mb"} <= set(stages)
        assert abs(float(r["model_mb"]) - sum(float(r[k]) for k in stages)) < 1e-6 * float(r["model_mb"]) + 1e-9


def test_bench_frame_quick(tmp_path):
    from gridrt import GridParams, RenderParams
    from gridrt.pipeline import FramePipeline
    from gridrt.scene import make_scene

    out = tmp_path / "frame"
    assert main(["bench", "frame", "--quick", "--no-progress", "--out", str(out), "--threads", "1",
                 "--traversal", "dda", "--grid", "uniform,two_level", "--leaf-density", "3"]) == 0
    rows, summary = check_outputs(out, "frame.csv", ["frame.png"])
    # marbles have static walls: the split is measured on and off, with each grid kind
    assert {(r["split"], r["grid"]) for r in rows} == {(s, g) for s in "01" for g in ("uniform", "two_level")}
    on, off = (next(r for r in rows if r["split"] == s) for s in "10")
    assert int(on["moving_triangles"]) < int(on["triangles"]) == int(off["moving_triangles"])
    for r in rows:
        assert float(r["fps"]) == pytest.approx(1000.0 / float(r["frame_ms"]))
        assert float(r["frame_ms"]) >= float(r["build_ms"]) + float(r["render_ms"]) - 1e-6
        assert (float(r["top_density"]), float(r["leaf_density"])) == (0.0625, 3.0)
        assert float(r["tests_per_ray"]) > 0 and float(r["cells_per_ray"]) > 0
        # the row's grids are those of a pipeline's frames with its settings (the quick run: one warm-up
        # frame, then one timed at t = 1/30 s)
        pipe = FramePipeline(make_scene("marbles", count=500), GridParams(threads=1, grid=r["grid"], leaf_density=3.0),
                             RenderParams(8, 8, threads=1, traversal="dda"), split_static=r["split"] == "1")
        pipe.step(0.0)
        check_grid_columns(r, pipe.step(1 / 30).stats, 500)
    assert "Static/moving split" in summary and "Grid kinds side by side" in summary
    # a smoke run records no effective cores (it starts none of the probe's busy processes)
    info = json.loads((out / "machine.json").read_text())
    assert info["effective_cores_start"] is None and info["effective_cores_end"] is None
    assert "effective cores: not measured (a --quick smoke run)" in summary


def test_effective_cores_probe_runs_busy_processes_and_only_when_asked(monkeypatch):
    """machine_info measures the effective cores with busy processes (1 alone, twice, then one
    per core at once) and finish_machine again at the end; without ``probe`` neither starts one."""
    from gridrt.app.bench import machine

    started = []
    real = machine.subprocess.Popen

    def popen(args, *a, **k):
        if args[0] == sys.executable:  # (not the CPU model's uname or the commit's git)
            started.append(args)
        return real(args, *a, **k)

    monkeypatch.setattr(machine.subprocess, "Popen", popen)
    info = machine.finish_machine(machine.machine_info([1], probe=False))
    assert started == [] and info["effective_cores_start"] is None and info["effective_cores_end"] is None
    info = machine.finish_machine(machine.machine_info([1]))
    cores = os.cpu_count()
    assert len(started) == 2 * (2 + cores) and all(a[1] == "-c" for a in started)
    for key in ("effective_cores_start", "effective_cores_end"):
        assert 0 < info[key] < float("inf")
    assert "effective cores (" in "\n".join(machine.machine_md(info))


@pytest.mark.slow  # (the trade benchmark's quick sweep: nine knobs, several of them kernels of their own to compile)
def test_bench_trade_quick_matches_an_independent_recount(tmp_path):
    from gridrt import GridParams, RenderParams, build_grid, render

    out = tmp_path / "trade"
    assert main(["bench", "trade", "--quick", "--no-progress", "--out", str(out), "--threads", "1"]) == 0
    rows, summary = check_outputs(out, "trade.csv", ["trade.png", "trade_knobs.png"])
    knobs = {r["knob"] for r in rows}
    assert knobs == {"insert", "lambda", "macro", "intersect", "resolution", "precision", "grid", "top_density",
                     "leaf_density"}
    by = {(r["knob"], r["value"]): r for r in rows}
    # the watertight test leaves no hole at shared edges; bbox insertion holds more references
    assert by[("intersect", "watertight")]["holes"] == "0"
    assert int(by[("insert", "exact")]["references"]) < int(by[("insert", "bbox")]["references"])
    assert any(r["pareto"] == "1" for r in rows) and by[("precision", "float32 storage")]["pareto"] == ""
    from gridrt.scene import make_scene

    tris = make_scene("icosphere", count=1280).triangles_at(0.0)
    # the two-level knobs: a row per grid kind, and each density swept with the other at its default,
    # on two-level grids (the grids an independent build makes), watertight as the uniform grid
    assert {v for k, v in by if k == "grid"} == {"uniform", "two_level", "auto"} and by[("grid", "uniform")]["default"] == "1"
    assert {v for k, v in by if k == "top_density"} == {"0.03125", "0.0625", "0.25"}
    assert {v for k, v in by if k == "leaf_density"} == {"1", "2", "4"}
    for (knob, value), r in by.items():
        if knob in ("top_density", "leaf_density") or (knob, value) == ("grid", "two_level"):
            top = float(value) if knob == "top_density" else 0.0625
            leaf = float(value) if knob == "leaf_density" else 2.0
            assert (r["grid"], float(r["top_density"]), float(r["leaf_density"])) == ("two_level", top, leaf)
            check_grid_columns(r, build_grid(tris, GridParams(grid="two_level", top_density=top, leaf_density=leaf)).stats,
                               1280)
            assert r["holes"] == "0" and r["pareto"] in ("0", "1") and float(r["tests_per_ray"]) > 0
    assert by[("grid", "two_level")]["build_ms"] == by[("leaf_density", "2")]["build_ms"]  # one configuration, measured once
    # recount the pixel error of the half-resolution row with tests/reference.py
    v = tris.reshape(-1, 3)
    cam = facing_camera(v.min(axis=0), v.max(axis=0))
    xs, ys = sample_pixels(64, 64, 256, seed=0)
    _, rd = ref_camera_rays(cam.eye, cam.target, cam.up, cam.fov, 64, 64)
    ref = ref_cast(tris, np.broadcast_to(np.asarray(cam.eye), (256, 3)), rd[ys * 64 + xs])
    img = render(build_grid(tris, GridParams()), tris, cam, RenderParams(32, 32, threads=1, traversal="dda"))
    tri = img.tri[ys // 2, xs // 2]
    expect = int((tri != ref.tri).sum())
    assert expect > 0
    assert int(by[("resolution", "32x32")]["pixels_differ"]) == expect
    assert "Conference point" in summary and "Pareto front" in summary
    # the CGT packets' knobs (not in the quick default set): float64 packets of every size give the
    # same hits; float32 ones stay within float32 rounding of the brute force's t
    out2 = tmp_path / "trade_packets"
    assert main(["bench", "trade", "--quick", "--no-progress", "--out", str(out2), "--threads", "1",
                 "--knobs", "packet,packet_precision"]) == 0
    rows2, _ = check_outputs(out2, "trade.csv", ["trade.png", "trade_knobs.png"])
    by2 = {(r["knob"], r["value"]): r for r in rows2}
    assert set(by2) == {("packet", "8x8"), ("packet", "16x16"), ("packet_precision", "float64"),
                        ("packet_precision", "float32")}
    assert all(r["traversal"] == "cgt" for r in rows2)
    f64 = [r for r in rows2 if r["packet_precision"] == "float64"]
    assert len({(r["pixels_differ"], r["dt_max"]) for r in f64}) == 1
    assert float(by2[("packet_precision", "float32")]["dt_rel_max"]) <= 1e-5


def test_bench_peers_quick(tmp_path, monkeypatch):
    """The quick peers run: its rows per view, agreement, and the other peers where installed; then
    with Open3D and Mitsuba hidden: the run goes on and the summary says how to get them."""
    pytest.importorskip("embreex", reason="embreex (optional extra 'peers') is not installed")
    out = tmp_path / "peers"
    assert main(["bench", "peers", "--quick", "--no-progress", "--out", str(out), "--threads", "1"]) == 0
    rows, summary = check_outputs(out, "peers.csv", ["peers.png"])
    assert [r["view"] for r in rows] == ["frame", "fill", "random"]
    for r in rows:
        assert int(r["rays"]) == 64 * 64
        assert float(r["agree"]) >= 0.999  # two watertight-grade engines on a closed sphere
    view = {r["view"]: r for r in rows}
    assert float(view["fill"]["hit_fraction"]) >= 0.9 > float(view["frame"]["hit_fraction"])
    assert 0.0 < float(view["random"]["hit_fraction"]) < 1.0  # (origins in the bounding box: some lie outside)
    assert "o_mrays_cgt" not in view["random"] or view["random"]["o_mrays_cgt"] == ""
    assert "sched_setaffinity" in summary
    r = rows[0]
    # the other peers, where installed: the same rays, agreeing hits, their own timings
    import importlib.util

    # Embree's fast scene beside the robust one, in the same run
    assert float(r["embree_fast_agree"]) >= 0.999 and float(r["embree_fast_mrays"]) > 0
    assert "Embree (fast)" in summary
    for name, module in (("open3d", "open3d"), ("mitsuba", "mitsuba")):
        if importlib.util.find_spec(module) is None:
            assert f"{module} is not installed" in summary
            continue
        try:
            importlib.import_module(module)
        except ImportError:  # installed, but a system library it loads is missing: named in the summary
            assert f"{module} is installed but does not load" in summary
            continue
        assert float(r[f"{name}_agree"]) >= 0.999
        assert float(r[f"{name}_frame_ms"]) > 0 and float(r[f"{name}_mrays"]) > 0
    for module in ("open3d", "mitsuba", "drjit"):
        monkeypatch.setitem(sys.modules, module, None)  # import -> ImportError
    out = tmp_path / "peers_without"
    assert main(["bench", "peers", "--quick", "--no-progress", "--out", str(out), "--threads", "1",
                 "--views", "frame"]) == 0
    summary = (out / "summary.md").read_text()
    assert "pip install open3d-cpu" in summary and "pip install mitsuba drjit" in summary




def test_peers_side_by_side_table_derives_its_ratios():
    """The all-engines table of bench peers' summary (the one BENCHMARKS.md's peers tables are made
    of), on made-up rows: static ratios against Embree robust and the best peer, and the dynamic
    frame of the best peer, Embree's without its upload, against gridrt's (no peer needs to be
    installed)."""
    from types import SimpleNamespace

    from gridrt.app.bench.peers import _side_by_side

    fast = SimpleNamespace(name="embree_fast", label="Embree (fast)")
    o3d = SimpleNamespace(name="open3d", label="Open3D")
    row = dict(scene="s [fill]", threads=2, hit_fraction=0.5, o_mrays=10.0, o_mrays_cgt=30.0, e_mrays=8.0,
               embree_fast_mrays=12.0, open3d_mrays=6.0, o_build_ms=5.0, o_render_cgt_ms=35.0, o_frame_cgt_ms=40.0,
               e_frame_ms=200.0, e_frame_noupload_ms=100.0, embree_fast_frame_ms=150.0, embree_fast_upload_ms=90.0,
               open3d_frame_ms=120.0)
    # random rays have no CGT render: the run leaves its figures NaN
    random_rays = dict(row, scene="s [random]", o_mrays=1.0, e_mrays=4.0, o_mrays_cgt=float("nan"),
                       o_render_cgt_ms=float("nan"), o_frame_cgt_ms=float("nan"))
    body = _side_by_side([row, random_rays], SimpleNamespace(robust=True), [fast, o3d])
    tables = [ln for ln in body if ln.startswith("| s [")]
    cells = [[c.strip() for c in ln.strip("|").split("|")] for ln in tables]
    # static: 10 / 8 against Embree robust; CGT 30 against the best peer, Embree fast's 12
    assert cells[0] == ["s [fill]", "2", "0.50", "10.00", "30.00", "8.00", "12.00", "6.00", "1.25", "2.50"]
    assert cells[1] == ["s [random]", "2", "0.50", "1.00", "-", "4.00", "12.00", "6.00", "0.25", "-"]
    # dynamic: the best peer is Embree fast without its upload, 150 - 90 = 60 ms, against gridrt's 40
    assert cells[2] == ["s [fill]", "2", "5.0 + 35.0 = 40.0", "200.0 (100.0)", "150.0 (60.0)", "120.0", "1.5x", "25"]
    assert len(cells) == 3  # no frame row without a CGT render


def test_bench_peers_without_embreex(tmp_path, monkeypatch, capsys):
    """Embree is an optional extra like the others: without embreex the run goes on (gridrt and
    whichever other peers are installed) and says how to install it."""
    monkeypatch.setitem(sys.modules, "embreex", None)  # import embreex -> ImportError
    out = tmp_path / "p"
    assert main(["bench", "peers", "--quick", "--no-progress", "--out", str(out), "--threads", "1",
                 "--views", "fill,random", "--grid", "uniform,two_level"]) == 0
    assert "pip install embreex" in capsys.readouterr().err
    rows, summary = check_outputs(out, "peers.csv", ["peers.png"])
    assert "Not measured: Embree: embreex is not installed" in summary and "pip install embreex" in summary
    # gridrt's grid kinds side by side, each with its columns; the random rays have no image, so no
    # tests and cells per ray
    assert [(r["view"], r["grid"]) for r in rows] == [(v, g) for v in ("fill", "random") for g in ("uniform", "two_level")]
    for r in rows:
        assert float(r["o_mrays"]) > 0 and float(r["o_frame_ms"]) > 0 and "e_mrays" not in r
        assert r["grid_built"] == r["grid"] and int(r["cells"]) > 0 and int(r["references"]) >= 1280
        assert float(r["bytes_per_tri"]) == pytest.approx(int(r["grid_bytes"]) / int(r["triangles"]))
        assert (r["tests_per_ray"] != "" and float(r["cells_per_ray"]) > 0) == (r["view"] == "fill")
    assert float(rows[0]["o_mrays_cgt"]) > 0
    assert "icosphere:1280:twist [fill] (two_level)" in summary


def test_bench_looks_quick(tmp_path):
    """bench looks: lambert, material and material with shadows per thread count, on the shipped Cesium
    Man; its texture's texels and bytes are those of the image in the file (read here with pygltflib
    and Pillow), and the rows' counts are the render's."""
    import io

    import pygltflib

    from gridrt.scene.assets import asset_path

    out = tmp_path / "looks"
    assert main(["bench", "looks", "--quick", "--no-progress", "--out", str(out)]) == 0
    rows = read_csv(out / "looks.csv")
    assert [(r["shading"], r["threads"]) for r in rows] == [
        (m, t) for t in ("1", "2") for m in ("lambert", "material", "material + shadows")]
    g = pygltflib.GLTF2().load(str(asset_path("cesium_man")))
    blob = g.binary_blob()
    texels = 0
    for im in g.images:
        bv = g.bufferViews[im.bufferView]
        with Image.open(io.BytesIO(blob[bv.byteOffset or 0:(bv.byteOffset or 0) + bv.byteLength])) as pic:
            texels += pic.size[0] * pic.size[1]
    for r in rows:
        assert int(r["texels"]) == texels and int(r["texture_bytes"]) == 3 * texels
        assert float(r["render_ms"]) > 0 and float(r["shade_ms"]) >= 0
        if r["shading"] == "lambert":
            assert float(r["vs_lambert"]) == 1.0 and float(r["shade_ms"]) == 0.0
        else:
            assert int(r["lights"]) == 1  # Cesium Man has no lights: the default one
            assert (float(r["shadow_rays_per_pixel"]) > 0) == (r["shading"] == "material + shadows")
            assert float(r["shadow_rays_per_pixel"]) <= float(r["hit_fraction"])
    assert "bytes/texel" in (out / "summary.md").read_text()


@pytest.mark.slow  # (compiles the packet profiler, for this benchmark alone)
def test_bench_packets_quick(tmp_path):
    """The packet profile: its counts equal the CGT render's own (tests per packet from the cost
    buffer, independently), every phase is measured, and profiling leaves every traced result as
    it is."""
    from importlib import import_module

    from gridrt.app.bench import packets as P
    from gridrt.camera import Camera
    from gridrt.config import GridParams, RenderParams
    from gridrt.grid import build_grid
    from gridrt.trace.grids import grid_arrays

    cgt = import_module("gridrt.trace.cgt")
    out = tmp_path / "packets"
    assert main(["bench", "packets", "--quick", "--no-progress", "--out", str(out)]) == 0
    rows = read_csv(out / "packets.csv")
    assert {r["view"] for r in rows} == {"frame", "fill"}
    assert {r["precision"] for r in rows} == {"float64", "float32"}
    for r in rows:
        assert all(float(r[f"{p}_ms"]) >= 0.0 for p in P.PHASES) and float(r["tests_ms"]) > 0.0
        assert int(r["packets"]) == 64 and int(r["tests"]) > 0  # 64x64 pixels: 64 packets of 8x8
    assert "triangle tests" in (out / "summary.md").read_text()
    # the counts against the render's cost buffer: a packet's test count is its rays' largest
    tris = icosphere_tris(3)
    grid = build_grid(tris, GridParams())
    cam = Camera(eye=(0.3, 0.5, 2.5), target=(0.0, 0.0, 0.0), fov=50.0)
    W = H = 48
    res = gridrt.render(grid, tris, cam, RenderParams(W, H, traversal="cgt", tile=P.TILE, shading="normal"))
    per_packet = res.cost.reshape(H // 8, 8, W // 8, 8).max(axis=(1, 3))
    g = grid_arrays(grid, np.ascontiguousarray(tris, np.float32))
    for f32 in (False, True):
        prof = np.zeros(cgt.NPROF, np.int64)
        hits = P.profile_frame(g, cam.basis(), W, H, prof, f32)
        assert hits == int((res.tri >= 0).sum())
        assert prof[cgt.C_PACKETS] == (W // 8) * (H // 8) and prof[cgt.C_TESTS] == per_packet.sum()
        assert (prof[: len(cgt.PROFILE_PHASES)] >= 0).all() and prof[cgt.P_TESTS] > 0
        assert hits == P.profile_frame(g, cam.basis(), W, H, None, f32)


@pytest.mark.parametrize("args,message", [
    (["trade", "--knobs", "insert,colour"], "unknown knob"),
    (["trade", "--knobs", "packet", "--packets", "8,8x40"], "--packets: packet height"),
    (["packets", "--precision", "float16"], "unknown precision"),
    (["frame", "--runs", "0"], "--runs"),
    (["build", "--strategies", "serial,fastest"], "unknown build strategy"),
    (["frame", "--scenes", "marbles:lots"], "neither a triangle count"),
    (["frame", "--traversal", "bvh"], "unknown traversal"),
    (["peers", "--views", "frame,sideways"], "unknown view"),
    (["packets", "--views", "random"], "unknown view"),
    (["build", "--grid", "uniform,octree"], "unknown grid kind 'octree' in --grid"),
    (["frame", "--grid", "two_level", "--leaf-density", "0"], "leaf_density must be a positive"),
    (["peers", "--top-density", "nan"], "top_density must be a positive"),
    (["trade", "--knobs", "top_density", "--top-densities", "0.5,-1"], "--top-densities: need positive"),
])
def test_bench_bad_arguments(tmp_path, capsys, args, message):
    assert main(["bench", *args, "--quick", "--no-progress", "--out", str(tmp_path / "x")]) == 2
    assert message in capsys.readouterr().err


def test_bench_scene_names_without_the_data_set(tmp_path, monkeypatch):
    """Without the development data set, a scene name that ships in assets/ is the asset (as it is
    with the data set: the Armadillo as binary PLY, Cesium Man by its older name too); a data set
    scene says which file it needs."""
    from gridrt.app.bench import scenes
    from gridrt.errors import InputError
    from gridrt.scene import assets

    monkeypatch.setattr(assets, "DATA_DIR", tmp_path)
    assert scenes.data_path("armadillo") == assets.asset_path("armadillo")
    assert scenes.parse_scene_spec("cesium")[0] == str(assets.asset_path("cesium_man"))
    assert scenes.scene_available("morphsphere") and not scenes.scene_available("lucy")
    with pytest.raises(InputError, match="lucy.*needs .*Lucy100k.ply"):
        scenes.parse_scene_spec("lucy")
