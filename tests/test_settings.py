"""One home per setting: the CLI's defaults are the dataclasses', one SceneSpec
serves cli, viewer, worker and bench, and stats are typed (gridrt.stats) with stages and counters
apart and one as_row()."""

import argparse

import numpy as np
import pytest

from gridrt.config import GridParams, RenderParams
from gridrt.grid.build import GridBuilder, build_grid
from gridrt.pipeline import STATS_COLUMNS, FramePipeline
from gridrt.scene import SceneSpec, make_scene
from gridrt.stats import BuildStats, FrameStats, RenderStats


def _parser():
    from gridrt.app import cli

    p = argparse.ArgumentParser()
    cli.add_scene_args(p)
    cli.add_grid_args(p)
    cli.add_render_args(p)
    return cli, p


def test_cli_defaults_are_the_dataclasses():
    cli, p = _parser()
    a = p.parse_args([])
    assert cli.grid_params(a) == GridParams()
    assert cli.render_params(a) == RenderParams()   # the image size included: one default size
    assert cli.scene_spec(a) == SceneSpec()
    assert RenderParams().traversal == "cgt"  # the Pareto choice (BENCHMARKS.md section 6)
    from gridrt.camera import Camera

    assert (a.fov, a.up) == (Camera().fov, Camera().up)
    # and what is given on the command line reaches the same fields
    a = p.parse_args(["--strategy", "sort_middle", "--lambda", "2.5", "--macro", "3", "--insert", "exact",
                      "--max-cells", "5000", "--traversal", "dda", "--shading", "normal", "--fast-intersect",
                      "--scene", "icosphere", "--count", "320", "--clip", "2", "--seed", "7"])
    assert cli.grid_params(a) == GridParams(strategy="sort_middle", density=2.5, macro=3, insert="exact",
                                            max_cells=5000)
    assert cli.render_params(a) == RenderParams(traversal="dda", shading="normal",
                                                watertight=False)
    assert cli.scene_spec(a) == SceneSpec(source="icosphere", count=320, clip=2, seed=7)


def test_one_scene_spec_everywhere():
    from gridrt.app.bench.scenes import resolve_scene, scene_spec
    from gridrt.app.viewer import state

    assert state.SceneSpec is SceneSpec
    spec = SceneSpec(source="marbles", count=600, seed=3)
    a, b = spec.make(), make_scene("marbles", count=600, seed=3)
    assert np.array_equal(a.triangles_at(0.4), b.triangles_at(0.4))
    assert spec.options() == {"count": 600, "seed": 3}
    twisted = SceneSpec(source="icosphere", count=320, animate="twist").make()
    ref = make_scene("icosphere", count=320, animate="twist")
    assert np.array_equal(twisted.triangles_at(0.3), ref.triangles_at(0.3))
    assert not np.array_equal(twisted.triangles_at(0.3).copy(), twisted.triangles_at(0.0))  # one reused buffer
    # the bench's spec text names the same SceneSpec
    assert scene_spec("icosphere:1280:twist") == SceneSpec(source="icosphere", count=1280, animate="twist")
    sc = resolve_scene("marbles:600")
    assert sc.spec == SceneSpec(source="marbles", count=600) and sc.scene.n_triangles == 600


def test_viewer_state_from_the_command_line():
    from gridrt.app.viewer.view import add_parser, initial_state

    sub = argparse.ArgumentParser().add_subparsers()
    p = add_parser(sub)
    a = p.parse_args(["--lambda", "3", "--threads", "1", "--shadows", "--scene", "icosphere", "--count", "80"])
    st = initial_state(a)
    assert st.grid == GridParams(density=3.0, threads=1)
    assert st.render == RenderParams(width=1024, height=768, shadows=True, threads=1)
    assert st.render.traversal == "cgt"
    assert st.scene == SceneSpec(source="icosphere", count=80)


def test_frame_stats_row_of_a_split_scene():
    """Marbles: a static box and moving marbles, gridded apart; the row sums both grids."""
    scene = make_scene("marbles", count=900, seed=1)
    pipe = FramePipeline(scene, GridParams(strategy="sort_middle", threads=2), RenderParams(40, 30, threads=1))
    fr = pipe.step(0.1)
    st = fr.stats
    assert isinstance(st, FrameStats) and isinstance(st.build, BuildStats) and isinstance(st.render, RenderStats)
    assert st.static is not None and st.static is pipe.static_grid.stats
    row = st.as_row()
    assert set(STATS_COLUMNS) <= set(row)
    assert row["cells"] == fr.grid.spec.n_cells + pipe.static_grid.spec.n_cells
    assert row["references"] == fr.grid.references + pipe.static_grid.references
    assert row["moving_triangles"] == fr.grid.n_triangles < row["triangles"] == 900
    assert row["grid_bytes"] == fr.grid.memory_bytes() + pipe.static_grid.memory_bytes()
    assert row["hit_fraction"] == pytest.approx(float((fr.tri >= 0).mean()))
    # stages are ms figures, the counters live apart: sort_middle's bucket count is a counter
    assert set(st.build.stages) >= {"bounds_ms", "clear_ms", "insert_ms", "macro_ms", "bucket_ms", "count_ms"}
    assert "bucket_entries" not in st.build.stages and st.build.counters["bucket_entries"] >= fr.grid.n_triangles
    assert all(isinstance(v, float) and v >= 0 for v in st.stages.values())
    assert sum(st.build.stages[k] for k in ("bounds_ms", "clear_ms", "insert_ms", "macro_ms")) <= st.build.build_ms
    for k in st.build.stages:  # the strategy's own stages are columns too
        assert row[k] == st.build.stages[k]
    assert "bucket_entries" not in row
    assert dict(st) == row and st["render_ms"] == st.render.render_ms


def test_frame_stats_of_a_reused_grid():
    """A static scene is gridded once: the second frame's build stages count 0."""
    pipe = FramePipeline(make_scene("icosphere", count=320), GridParams(threads=1), RenderParams(16, 12, threads=1))
    first, second = pipe.step(0.0).stats, pipe.step(0.5).stats
    assert first["rebuilt"] == 1 and first["build_ms"] > 0
    assert second["rebuilt"] == 0 and second["build_ms"] == 0.0
    assert all(v == 0.0 for v in second.build_stages.values()) and second.build_stages.keys() == first.build.stages.keys()
    assert second.build is first.build  # the same grid's stats
    assert second["split_rays"] == second.render.split_rays >= 0  # CGT by default


def test_build_stats_read_like_a_row():
    tris = make_scene("icosphere", count=320).triangles_at(0.0)
    g = build_grid(tris, GridParams(strategy="global_lock", threads=2))
    s = g.stats
    assert s["references"] == s.references == g.references and s["cells"] == g.spec.n_cells
    assert s["grid_bytes"] == g.memory_bytes() and s["dims"] == "x".join(str(int(d)) for d in g.spec.dims)
    assert "lock_waits" in s.counters and "lock_waits" not in s.stages and s["lock_waits"] == s.counters["lock_waits"]
    assert dict(s) == s.as_row()
    serial = GridBuilder(GridParams(strategy="serial")).build(tris).stats
    assert serial.counters == {} and serial.strategy == "serial"
