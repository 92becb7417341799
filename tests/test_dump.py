"""The headless frame dump, end to end through the real command line (a subprocess).

Hit buffers are checked against the brute-force float64 caster over the scene's triangles
(gridrt.scene is independent of the grid and the ray caster) and rays from the documented
pinhole formula (tests/reference.py), not against anything the dump produced itself.
"""

import csv
import os
import subprocess
import sys

import numpy as np
import pytest
from PIL import Image

from reference import compare_hits, ref_camera_rays, ref_cast
from helpers.cli import REPO, cache_files, gridrt

REQUIRED = ["frame", "t", "triangles", "cells", "references", "threads", "strategy", "clear_ms", "insert_ms",
            "macro_ms", "build_ms", "render_ms", "frame_ms"]


def test_dump_all_options_and_buffers_match_brute_force(tmp_path):
    out = tmp_path / "d"
    eye, target, up, fov = (0.5, 4.0, 14.0), (0.0, 0.8, 0.0), (0.0, 1.0, 0.0), 50.0
    W, H = 40, 30
    r = gridrt("dump", "--scene", "marbles", "--count", "1000", "--frames", "2", "--size", f"{W}x{H}",
               "--threads", "3", "--strategy", "serial", "--lambda", "3", "--macro", "2", "--insert", "exact",
               "--shading", "normal", "--t0", "0.5", "--dt", "0.25",
               "--eye", ",".join(map(str, eye)), "--target", ",".join(map(str, target)),
               "--up", ",".join(map(str, up)), "--fov", str(fov), "--save-buffers", "--out", str(out))
    assert r.returncode == 0, r.stderr
    assert "100%" in r.stderr, "no progress bar on stderr"
    with open(out / "stats.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == 2
    assert set(REQUIRED) <= set(rows[0])
    from gridrt.scene import make_scene

    scene = make_scene("marbles", count=1000)
    o, d = ref_camera_rays(eye, target, up, fov, W, H)
    for i, row in enumerate(rows):
        t = 0.5 + 0.25 * i
        assert int(row["frame"]) == i and float(row["t"]) == pytest.approx(t)
        assert int(row["triangles"]) == 1000 and int(row["threads"]) == 3 and row["strategy"] == "serial"
        assert int(row["references"]) > 0 and int(row["cells"]) > 0
        assert row["grid"] == "uniform" and float(row["bytes_per_tri"]) == pytest.approx(int(row["grid_bytes"]) / 1000)
        stages = sum(float(row[k]) for k in ("clear_ms", "insert_ms", "macro_ms"))
        assert 0 < stages <= float(row["build_ms"]) <= float(row["frame_ms"])
        img = np.asarray(Image.open(out / f"frame_{i:05d}.png"))
        assert img.shape[:2] == (H, W)
        tb = np.load(out / f"frame_{i:05d}_t.npy")
        ib = np.load(out / f"frame_{i:05d}_id.npy")
        assert tb.dtype == np.float32 and ib.dtype == np.int32 and tb.shape == ib.shape == (H, W)
        tris = scene.triangles_at(t).copy()
        ref = ref_cast(tris, o, d)
        diff = compare_hits(tb.reshape(-1), ib.reshape(-1), ref, t_rtol=1e-6)
        assert len(diff.bad) == 0, f"frame {i}: {len(diff.bad)} pixels differ from brute force"
        assert (ib >= 0).any() and (ib < 0).any(), "camera should see both marbles and background"
        miss = ib < 0
        assert np.isinf(tb[miss]).all()
        # normal shading: hit pixels differ from the background colour, misses equal it
        bg = np.array([31, 33, 41], np.uint8)
        assert (img[miss][:, :3] == bg).all()


def test_dump_two_level_grid(tmp_path):
    """--grid two_level with its densities: stats.csv names the grid's kind, its densities, bytes and bytes
    per triangle, equal to a FramePipeline's over the same frames (marbles: a static box and moving
    marbles, each its own two-level grid), and the hit buffers equal brute force."""
    from gridrt.camera import Camera
    from gridrt.config import GridParams, RenderParams
    from gridrt.pipeline import FramePipeline
    from gridrt.scene import make_scene

    out = tmp_path / "d"
    eye, target, W, H = (0.5, 4.0, 14.0), (0.0, 0.8, 0.0), 24, 16
    r = gridrt("dump", "--scene", "marbles", "--count", "600", "--frames", "2", "--size", f"{W}x{H}", "--threads", "2",
               "--grid", "two_level", "--top-density", "0.25", "--leaf-density", "4", "--traversal", "dda",
               "--eye", ",".join(map(str, eye)), "--target", ",".join(map(str, target)), "--save-buffers",
               "--no-progress", "--out", str(out))
    assert r.returncode == 0, r.stderr
    assert "two_level grid of" in r.stdout and "bytes per triangle" in r.stdout
    with open(out / "stats.csv") as fh:
        rows = list(csv.DictReader(fh))
    scene = make_scene("marbles", count=600)
    pipe = FramePipeline(scene, GridParams(threads=2, grid="two_level", top_density=0.25, leaf_density=4.0),
                         RenderParams(W, H, threads=2, traversal="dda"), camera=Camera(eye=eye, target=target))
    o, d = ref_camera_rays(eye, target, (0.0, 1.0, 0.0), Camera.fov, W, H)
    for i, row in enumerate(rows):
        t = i / 30.0
        st = pipe.step(t).stats
        assert (row["grid"], float(row["top_density"]), float(row["leaf_density"])) == ("two_level", 0.25, 4.0)
        for k in ("cells", "references", "grid_bytes"):
            assert int(row[k]) == st[k], k
        assert float(row["bytes_per_tri"]) == pytest.approx(st["grid_bytes"] / 600, rel=1e-5)
        assert {"leaf_res_ms", "leaf_count_ms", "leaf_scatter_ms"} <= set(row)
        ib = np.load(out / f"frame_{i:05d}_id.npy")
        tb = np.load(out / f"frame_{i:05d}_t.npy")
        diff = compare_hits(tb.reshape(-1), ib.reshape(-1), ref_cast(scene.triangles_at(t).copy(), o, d), t_rtol=1e-6)
        assert len(diff.bad) == 0 and (ib >= 0).any(), f"frame {i}: {len(diff.bad)} pixels differ from brute force"


def test_dump_imports_no_gl(tmp_path):
    code = (
        "import sys; from gridrt.app.__main__ import main; "
        f"rc = main(['dump', '--frames', '1', '--size', '16x12', '--no-progress', '--out', r'{tmp_path}']); "
        "print('GL', 'glfw' in sys.modules, 'moderngl' in sys.modules, 'imgui_bundle' in sys.modules, rc)"
    )
    r = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    assert "GL False False False 0" in r.stdout


@pytest.mark.parametrize(
    "args, message",
    [
        (["--scene", "no_such_scene"], "no_such_scene"),
        (["--strategy", "quantum"], "unknown build strategy"),
        (["--threads", "0"], "thread count"),
        (["--frames", "0"], "--frames"),
        (["--lambda", "-1"], "density"),
        (["--grid", "octree"], "invalid choice: 'octree'"),
        (["--grid", "two_level", "--leaf-density", "0"], "leaf_density must be a positive"),
        (["--eye", "1,2,3"], "--target"),
        (["--scene", "/nonexistent/mesh.obj"], "mesh.obj"),
    ],
)
def test_dump_bad_arguments_give_clear_errors(tmp_path, args, message):
    r = gridrt("dump", "--frames", "1", "--size", "8x8", "--no-progress", "--out", str(tmp_path), *args)
    assert r.returncode == 2
    assert message in r.stderr
    assert "Traceback" not in r.stderr


def test_dump_bad_size_is_rejected_by_parser(tmp_path):
    r = gridrt("dump", "--size", "0x10", "--out", str(tmp_path))
    assert r.returncode == 2 and "image size must be positive" in r.stderr


def cold_render_kernels(env):
    """gridrt.warmup.cache_is_cold for both traversals, in a fresh process with env."""
    r = subprocess.run([sys.executable, "-c", "from gridrt.warmup import cache_is_cold; "
                        "print(cache_is_cold('cgt'), cache_is_cold('dda'))"],
                       cwd=REPO, capture_output=True, text=True, env={**os.environ, **env}, timeout=600)
    assert r.returncode == 0, r.stderr
    return r.stdout.split()


@pytest.mark.slow
def test_compile_notice_only_when_compiling(tmp_path):
    """The dump announces compilation exactly when numba compiles: with an empty numba cache (a
    fresh NUMBA_CACHE_DIR), not on an identical second run (every kernel loads from the cache),
    and again on a third run with a build strategy this cache has not seen (its kernels compile).
    DDA traversal: its cold start compiles in about half the time of the CGT one.  The first run's
    default build strategy compiles in the background from its second frame (the serial strategy
    builds meanwhile), and the dump waits for that compile at exit, so the second run finds every
    kernel cached.

    Whether a run compiled is read from the cache folder, independently of the notice: numba
    writes an index and a data file for every kernel it compiles (cache=True), so a run that
    compiled nothing leaves the folder as it was.  cache_is_cold (the viewer's prediction) goes
    from cold to warm for the DDA render kernel the dumps ran and stays cold for the CGT one."""
    cache = tmp_path / "cache"
    env = {"NUMBA_CACHE_DIR": str(cache)}
    assert cold_render_kernels(env) == ["True", "True"]
    before = {}
    for i, extra in enumerate([(), (), ("--strategy", "thread_grids")]):
        r = gridrt("dump", "--frames", "2", "--size", "8x8", "--traversal", "dda", "--no-progress",
                   "--out", str(tmp_path / f"d{i}"), *extra, env=env)
        assert r.returncode == 0, r.stderr
        after = cache_files(cache)
        compiled = after != before
        assert compiled == (i != 1), f"run {i}: numba compiled: {compiled}"
        assert r.stderr.count("Compiling numba kernels") == int(compiled), f"run {i}: {r.stderr}"
        before = after
    assert cold_render_kernels(env) == ["True", "False"]


def test_compile_notice_fires_once_and_only_on_a_compile():
    """compile_notice calls back once, at the first real compile in its block (numba's
    dispatcher signatures tell independently when one happened), and never outside it."""
    from numba import njit

    from gridrt.warmup import compile_notice

    calls = []

    @njit  # not cached: compiles at its first call with each argument type
    def add_one(x):
        return x + 1

    with compile_notice(lambda: calls.append("compiling")):
        assert add_one(1) == 2 and add_one(2) == 3 and add_one(2.5) == 3.5
    assert len(add_one.signatures) == 2 and calls == ["compiling"]
    with compile_notice(lambda: calls.append("again")):
        assert add_one(3) == 4 and add_one(4.5) == 5.5
    assert len(add_one.signatures) == 2 and calls == ["compiling"]
    assert add_one(1j) == 1 + 1j  # compiles, outside any block
    assert len(add_one.signatures) == 3 and calls == ["compiling"]
