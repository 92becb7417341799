"""What a new user meets in the first hour, through the real command line: the default build
strategy, the scene's own camera, vectors with a leading minus, a thread count above the cores,
the no-display hint, figures that do not apply, frames that compiled kernels, and a file's normals
under the default shading."""

import csv
import math
import os
import shlex
import subprocess
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np
import pytest

from gridrt.app.__main__ import build_parser, main
from gridrt.app.cli import join_negative_values
from gridrt.config import (PARALLEL_DEFAULT_STRATEGY, SERIAL_ORDER_STRATEGIES, STRATEGIES, GridParams,
                           resolve_strategy)
from gridrt.grid import build_grid
from gridrt.scene import make_scene
from gridrt.threads import usable_cores
from gridrt.trace.twin import parallel_first
from helpers.cli import gridrt

REPO = Path(__file__).resolve().parents[1]


def dump_rows(tmp_path, *args):
    """stats.csv rows of a one-frame dump with ``args`` (and the run's stderr)."""
    out = tmp_path / "d"
    r = gridrt("dump", "--frames", "1", "--size", "32x24", "--out", str(out), "--overwrite", "--no-progress",
               *map(str, args), timeout=900)
    assert r.returncode == 0, r.stderr[-3000:]
    with open(out / "stats.csv", newline="") as fh:
        return list(csv.DictReader(fh)), r.stderr


# ------------------------------------------------------------------------------ default strategy


def serial_order(name, tris, threads, grid="uniform"):
    """Whether the strategy ``name`` at ``threads`` threads builds the serial grid of ``tris``: the
    same cells, each cell's triangles in the same order."""
    ref = build_grid(tris, GridParams(strategy="serial", threads=1, grid=grid))
    cs, ids = ref.cell_start.copy(), ref.tri_ids[:ref.references].copy()
    g = build_grid(tris, GridParams(strategy=name, threads=threads, grid=grid))
    return np.array_equal(g.cell_start, cs) and np.array_equal(g.tri_ids[:g.references], ids)


def test_serial_order_strategies_build_the_serial_grid_and_the_others_do_not():
    tris = make_scene("marbles", count=20000).triangles_at(0.3)
    for name in STRATEGIES:
        same = all(serial_order(name, tris, t) for t in (2, 3, 7)) and serial_order(name, tris, 2, "two_level")
        assert same == (name in SERIAL_ORDER_STRATEGIES), name


def test_default_strategy_is_the_fastest_measured_that_builds_the_serial_grid():
    """auto is serial at one thread and, above, of the strategies that build the serial grid (frames
    the same every run, a resumed dump the one-run dump), the one whose build times in the kept
    `gridrt bench build` run (results/build, every scene) have the smallest geometric mean at 2
    threads."""
    times = defaultdict(list)
    with open(REPO / "results" / "build" / "build_sweep.csv", newline="") as fh:
        for r in csv.DictReader(fh):
            if r["grid"] == "uniform" and int(r["threads"]) == 2:
                times[r["strategy"]].append(math.log(float(r["build_ms"])))
    assert len(times) == 9 and len({len(v) for v in times.values()}) == 1
    fastest = min(SERIAL_ORDER_STRATEGIES, key=lambda s: sum(times[s]))
    assert PARALLEL_DEFAULT_STRATEGY == fastest
    assert GridParams().strategy == "auto"
    assert resolve_strategy("auto", 1) == "serial" and resolve_strategy("auto", 2) == fastest
    assert resolve_strategy("auto", 7) == fastest and resolve_strategy("sort_first", 2) == "sort_first"


def test_default_strategy_builds_and_reports_the_strategy_it_stands_for(tmp_path):
    tris = make_scene("icosphere", count=320).triangles_at(0.0)
    for threads, name in ((1, "serial"), (2, PARALLEL_DEFAULT_STRATEGY)):
        with parallel_first():  # (not its serial stand-in on a cold cache: tests/test_twin.py)
            g = build_grid(tris, GridParams(threads=threads))
        explicit = build_grid(tris, GridParams(strategy=name, threads=threads))
        assert g.stats.strategy == name
        assert np.array_equal(g.cell_start, explicit.cell_start) and g.references == explicit.references
    # a dump of two animated frames warms the parallel strategy up if its kernels were not cached
    # (and waits for that at exit); a dump after it builds with it from its first frame
    anim = ("--threads", "2", "--scene", "icosphere", "--count", "320", "--animate", "twist")
    rows, _ = dump_rows(tmp_path, *anim, "--frames", "2")
    assert {r["strategy"] for r in rows} <= {"serial", PARALLEL_DEFAULT_STRATEGY}
    rows, _ = dump_rows(tmp_path, *anim)
    assert rows[0]["strategy"] == PARALLEL_DEFAULT_STRATEGY
    rows, _ = dump_rows(tmp_path, "--threads", "1", "--scene", "icosphere", "--count", "320")
    assert rows[0]["strategy"] == "serial"


# ------------------------------------------------------------------------------ parsing and warnings


def test_vectors_with_a_leading_minus_parse(capsys):
    argv = ["dump", "--eye", "1,2,3", "--target", "-0.02,0.1,0", "--up", "-1e-3,1,0", "--t0", "-1e6"]
    a = build_parser("dump").parse_args(join_negative_values(argv))
    assert a.target == (-0.02, 0.1, 0.0) and a.up == (-1e-3, 1.0, 0.0) and a.eye == (1.0, 2.0, 3.0)
    assert a.t0 == -1e6
    # through the program: parsed, then refused for the frame count only
    assert main([*argv, "--frames", "0"]) == 2
    err = capsys.readouterr().err
    assert "--frames must be at least 1" in err and "expected one argument" not in err


def test_more_threads_than_cores_is_warned_about_once(tmp_path):
    n = usable_cores() + 1
    rows, err = dump_rows(tmp_path, "--threads", n, "--scene", "icosphere", "--count", "80")
    lines = [ln for ln in err.splitlines() if "threads on" in ln]
    assert len(lines) == 1 and lines[0].startswith(f"gridrt: warning: {n} threads on {usable_cores()} core"), err
    assert int(rows[0]["threads"]) == n
    _, err = dump_rows(tmp_path, "--threads", usable_cores(), "--scene", "icosphere", "--count", "80")
    assert "threads on" not in err


def test_no_display_hint_carries_the_users_options():
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    args = ["view", "--scene", "teapot", "--threads", "1", "--eye", "3,2,1", "--target", "-0.5,0,0",
            "--shading", "normal", "--size", "320x200", "--scale", "0.5", "--hide-panel"]
    r = subprocess.run([sys.executable, "-m", "gridrt", *args], cwd=REPO, capture_output=True, text=True, env=env,
                       timeout=300)
    assert r.returncode == 3
    cmd = r.stderr.strip().split("render headless instead: ", 1)[1]
    words = shlex.split(cmd)
    dump = build_parser().parse_args(join_negative_values(words[words.index("dump"):]))
    assert dump.command == "dump" and dump.scene == "teapot" and dump.threads == 1 and dump.shading == "normal"
    assert dump.eye == (3.0, 2.0, 1.0) and dump.target == (-0.5, 0.0, 0.0) and dump.size == (320, 200)
    assert str(dump.out) == "out/teapot" and dump.frames == 60
    assert "--scale" not in words and "--hide-panel" not in words  # the viewer's own options stay behind


# ------------------------------------------------------------------------------ the scene's camera


def test_dump_looks_through_the_scenes_camera_by_default(tmp_path):
    """The BART museum's own camera, as in the viewer: the default and --follow-camera give the same
    frame; --no-scene-camera frames the scene's bounds instead."""
    def frame(tag, *opts):
        out = tmp_path / tag
        r = gridrt("dump", "--scene", "museum", "--frames", "1", "--t0", "1.5", "--size", "40x30", "--shading", "lambert",
                   "--save-buffers", "--out", str(out), "--no-progress", *opts, timeout=900)
        assert r.returncode == 0, r.stderr[-3000:]
        return np.load(out / "frame_00000_t.npy"), np.load(out / "frame_00000_id.npy")

    default, follow, framing = frame("a"), frame("b", "--follow-camera"), frame("c", "--no-scene-camera")
    scene = make_scene("museum")
    assert scene.camera_at(1.5) is not None
    assert np.array_equal(default[1], follow[1]) and np.array_equal(default[0], follow[0])
    assert (default[1] != framing[1]).mean() > 0.2


# ------------------------------------------------------------------------------ stats


def test_stats_say_n_a_where_a_figure_does_not_apply_and_mark_compile_frames(tmp_path):
    rows, _ = dump_rows(tmp_path, "--scene", "icosphere", "--count", "320", "--shading", "lambert", "--shadows")
    assert rows[0]["shadow_rays_per_pixel"] == "n/a"  # lambert's shadow rays are not counted
    assert rows[0]["compiled"] in ("0", "1")
    rows, _ = dump_rows(tmp_path, "--scene", "icosphere", "--count", "320", "--shading", "lambert")
    assert float(rows[0]["shadow_rays_per_pixel"]) == 0.0
    rows, _ = dump_rows(tmp_path, "--scene", "museum", "--shading", "material", "--shadows")
    assert 0.0 < float(rows[0]["shadow_rays_per_pixel"]) <= 1.0 * int(rows[0]["lights"])


def test_compile_watch_sees_a_compile_and_only_then():
    from numba import njit

    from gridrt.compiles import CompileWatch

    @njit
    def twice(x):
        return 2 * x

    with CompileWatch() as w:
        assert twice(3) == 6
    assert w.compiled
    with CompileWatch() as w:
        assert twice(4) == 8
    assert not w.compiled


@pytest.mark.slow  # (compiles the dump's kernels from scratch, as the other cold-cache tests)
def test_dump_leaves_compile_frames_out_of_its_medians(tmp_path):
    """A fresh numba cache: the first frames compile (marked in stats.csv), and the dump's summary
    says its medians leave them out (or include them, when every frame compiled)."""
    out = tmp_path / "d"
    r = gridrt("dump", "--scene", "icosphere", "--count", "80", "--frames", "3", "--size", "16x12", "--threads", "1",
               "--traversal", "dda", "--out", str(out), "--no-progress", env={"NUMBA_CACHE_DIR": str(tmp_path / "cache")},
               timeout=900)
    assert r.returncode == 0, r.stderr[-3000:]
    with open(out / "stats.csv", newline="") as fh:
        flags = [row["compiled"] for row in csv.DictReader(fh)]
    assert flags[0] == "1"
    done = flags.count("1")
    summary = r.stdout
    if done < len(flags):
        assert f"({done} frame{'s' if done > 1 else ''} that compiled kernels left out)" in summary
    else:
        assert "every frame compiled kernels" in summary


@pytest.mark.parametrize("scene", ["morph_sphere"])
def test_default_shading_uses_a_files_normals(tmp_path, scene):
    """The morphing glTF sphere carries normals and no materials: the default shading is the
    material mode, with its smooth normals, and gives the same image as asking for it."""
    rows, _ = dump_rows(tmp_path, "--scene", scene)
    assert rows[0]["shading"] == "material"
