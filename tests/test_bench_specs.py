"""The benchmarks' configurations are FrameSpecs whose parts are the options given: each benchmark's
spec builders are fed the options its own parser reads from a command line, and every part is
checked against those options as this file reads them (and against the settings' field defaults
where the benchmark leaves a setting alone)."""

from dataclasses import fields

import numpy as np
import pytest

from gridrt.app.__main__ import build_parser, main
from gridrt.app.bench import build, core, looks, packets, peers
from gridrt.app.bench.scenes import resolve_scene
from gridrt.camera import Camera
from gridrt.config import PARALLEL_DEFAULT_STRATEGY, GridParams, RenderParams
from gridrt.frame import FrameSpec, ViewSpec
from gridrt.scene import SceneSpec, make_scene

SCENE = SceneSpec(source="icosphere", count=1280)
CAM = Camera(eye=(0.5, 1.0, 4.0), target=(0.0, 0.1, 0.0), up=(0.0, 1.0, 0.0), fov=38.0)


def parse(*argv):
    return build_parser().parse_args(["bench", *argv])


def check_defaults(part, cls, *changed):
    """Every field of ``part`` not named in ``changed`` is that of the class's default instance."""
    default = cls()
    for f in fields(cls):
        if f.name not in changed:
            assert getattr(part, f.name) == getattr(default, f.name), f.name


def check_camera(spec, cam):
    v = spec.view
    assert (v.eye, v.target, v.up, v.fov) == (cam.eye, cam.target, cam.up, cam.fov)
    assert spec.camera() == cam


def test_bench_core_configurations_are_the_options():
    a = parse("core", "--size", "48", "--threads", "1,2", "--traversal", "cgt,dda")
    threads = [int(t) for t in a.threads.split(",")]
    travs = a.traversal.split(",")
    base = core.core_spec(SCENE, a.size)
    assert isinstance(base, FrameSpec) and base.scene == SCENE and base.size == (48, 48)
    builds = core.build_specs(base)
    assert [s.grid.insert for s in builds] == ["bbox", "exact"]  # the two serial build rows
    for s in builds:
        assert (s.grid.strategy, s.grid.threads) == ("serial", 1)
        check_defaults(s.grid, GridParams, "strategy", "threads", "insert")
        assert s.render == base.render and s.view == base.view
    rays = core.ray_specs(base, CAM, threads, travs)
    assert [(s.render.threads, s.render.traversal) for s in rays] == [(t, v) for t in threads for v in travs]
    for s in rays:
        assert s.scene == SCENE and s.grid == base.grid
        assert (s.render.width, s.render.height) == s.size == (a.size, a.size)
        check_defaults(s.render, RenderParams, "width", "height", "threads", "traversal")
        check_camera(s, CAM)
        check_defaults(s.view, ViewSpec, "eye", "target", "up", "fov", "size")


def test_bench_packets_configurations_are_the_options():
    a = parse("packets", "--size", "40", "--precision", "float32,float64")
    for prec in a.precision.split(","):
        s = packets.seen_through(packets.packet_spec(SCENE, a.size, prec), CAM)
        assert s.scene == SCENE and s.size == (40, 40)
        assert s.grid.threads == 1
        check_defaults(s.grid, GridParams, "threads")
        r = s.render
        assert (r.width, r.height, r.threads, r.traversal, r.packet_precision) == (40, 40, 1, "cgt", prec)
        assert r.tile == packets.TILE
        check_defaults(r, RenderParams, "width", "height", "threads", "traversal", "tile", "packet_precision")
        check_camera(s, CAM)


@pytest.mark.parametrize("strategy", ["auto", "counting"])
def test_bench_peers_configurations_are_the_options(strategy):
    a = parse("peers", "--size", "32", "--threads", "1,2", "--grid", "uniform,two_level", "--top-density", "0.125",
              "--leaf-density", "3", "--packet", "4x8", "--packet-precision", "float32", "--dt", "0.05",
              "--strategy", strategy)
    threads = [int(t) for t in a.threads.split(",")]
    kinds = a.grid.split(",")
    base = peers.peers_spec(a, a.size)
    for cam in (CAM, None):  # (a camera view, the random rays)
        specs = peers.peer_specs(base, SCENE, cam, threads, kinds, a.strategy)
        assert [(s.grid.threads, s.grid.grid) for s in specs] == [(t, k) for t in threads for k in kinds]
        for s in specs:
            g, r, T = s.grid, s.render, s.grid.threads
            # --strategy auto: serial at 1 thread, PARALLEL_DEFAULT_STRATEGY above (the option's help)
            auto = "serial" if T == 1 else PARALLEL_DEFAULT_STRATEGY
            assert g.strategy == (auto if strategy == "auto" else strategy)
            assert (g.top_density, g.leaf_density) == (0.125, 3.0)
            check_defaults(g, GridParams, "strategy", "threads", "grid", "top_density", "leaf_density")
            assert (r.width, r.height, r.threads, r.traversal) == (32, 32, T, "cgt")
            assert (r.packet, r.packet_precision) == ((4, 8), "float32")
            check_defaults(r, RenderParams, "width", "height", "threads", "traversal", "packet", "packet_precision")
            assert s.scene == SCENE and s.view.dt == 0.05 and s.size == (32, 32)
            if cam is None:
                assert s.camera() is None
            else:
                check_camera(s, cam)


def spy(monkeypatch, module):
    """Lists that record the GridParams of every GridBuilder and the (camera, RenderParams) of
    every Renderer.render of the benchmark ``module``."""
    built, rendered = [], []

    class Builder(module.GridBuilder):
        def __init__(self, params=None):
            built.append(params)
            super().__init__(params)

    class Spy(module.Renderer):
        def render(self, grid, tris, camera, params=None, *rest, **kw):
            rendered.append((camera, params))
            return super().render(grid, tris, camera, params, *rest, **kw)

    monkeypatch.setattr(module, "GridBuilder", Builder)
    monkeypatch.setattr(module, "Renderer", Spy)
    return built, rendered


def test_bench_core_renders_and_builds_what_its_specs_say(tmp_path, monkeypatch):
    """What a run of ``bench core`` hands its builders and renderers: the grid settings of the
    serial rows and the render settings and camera of the ray rows, against the options and an
    independent framing of the scene (facing_camera over its triangles' bounds)."""
    built, rendered = spy(monkeypatch, core)
    argv = ["core", "--scenes", "icosphere:1280", "--size", "24", "--threads", "1", "--traversal", "dda",
            "--runs", "1", "--warmup", "0", "--no-progress", "--out", str(tmp_path)]
    assert main(["bench", *argv]) == 0
    a = parse(*argv)
    assert {(p.insert, p.strategy, p.threads) for p in built} == {("bbox", "serial", 1), ("exact", "serial", 1)}
    tris = make_scene("icosphere", count=1280).triangles_at(0.0).reshape(-1, 3)
    want = core.facing_camera(tris.min(axis=0), tris.max(axis=0))
    assert rendered
    for camera, rp in rendered:
        assert (rp.width, rp.height, rp.threads, rp.traversal) == (a.size, a.size, 1, a.traversal)
        np.testing.assert_allclose(camera.eye, want.eye, rtol=1e-6)
        np.testing.assert_allclose(camera.target, want.target, rtol=1e-6, atol=1e-7)
        assert camera.fov == want.fov


def test_bench_build_configurations_are_the_options():
    a = parse("build", "--lambda", "2.5", "--macro", "2", "--insert", "exact", "--grid", "uniform,two_level",
              "--top-density", "0.125", "--leaf-density", "3", "--size", "32", "--threads", "1,2")
    options = dict(density=2.5, macro=2, insert="exact", top_density=0.125, leaf_density=3.0)
    base = build.build_base(a)
    assert {k: getattr(base.grid, k) for k in options} == options
    check_defaults(base.grid, GridParams, *options)
    assert base.render == RenderParams() and base.view == ViewSpec()
    threads, kinds, strategies = [int(t) for t in a.threads.split(",")], a.grid.split(","), ["serial", "counting"]
    calls = build.build_calls(["icosphere:1280"], strategies, kinds, threads, base, 1, 0, a.size)
    specs = [FrameSpec.from_wire(args[1]) for _, args in calls]
    assert [(s.grid.strategy, s.grid.grid, s.grid.threads) for s in specs] == [
        (st, k, t) for st in strategies for k in kinds for t in threads]
    for s in specs:
        assert {k: getattr(s.grid, k) for k in options} == options
        check_defaults(s.grid, GridParams, "strategy", "grid", "threads", *options)
        assert (s.render.width, s.render.height, s.render.threads) == (32, 32, s.grid.threads) and s.size == (32, 32)
        check_defaults(s.render, RenderParams, "width", "height", "threads")
    local = build.build_spec(build.build_base(a).resized(32, 32), "counting", 2, "two_level", SCENE)
    assert local.scene == SCENE and local.replace(scene=SceneSpec()) == specs[-1]


def test_bench_build_sweep_builds_and_renders_its_specs(monkeypatch):
    """run_build_sweep hands each configuration's builder its spec's grid and its renderer the
    spec's render settings (the given FrameSpec's, at the render size and the thread count)."""
    built, rendered = spy(monkeypatch, build)
    measured = []
    measure = build._measure
    monkeypatch.setattr(build, "_measure", lambda name, src, group, *rest: measured.extend(group) or measure(
        name, src, group, *rest))
    base = FrameSpec(grid=GridParams(density=2.0, macro=2), render=RenderParams(shading="normal", traversal="dda"))
    scenes = {"ico": make_scene("icosphere", count=320), "bench": resolve_scene("icosphere:80")}
    rows = build.run_build_sweep(scenes, ["serial", "counting"], [1, 2], runs=1, warmup=0, progress=False, params=base,
                                 render=16)
    # a BenchScene's SceneSpec is its configurations' scene; a bare Animation leaves the base's
    assert [s.scene for s in measured] == [base.scene] * 4 + [SceneSpec(source="icosphere", count=80)] * 4
    assert {(p.strategy, p.threads, p.density, p.macro) for p in built} == {
        (s, t, 2.0, 2) for s in ("serial", "counting") for t in (1, 2)}
    assert {(p.width, p.height, p.threads, p.shading, p.traversal) for _, p in rendered} == {
        (16, 16, t, "normal", "dda") for t in (1, 2)}
    assert {(r["strategy"], r["threads"], r["density"], r["macro"]) for r in rows} == {
        (s, t, 2.0, 2) for s in ("serial", "counting") for t in (1, 2)}


def test_bench_looks_configurations_are_the_options():
    a = parse("looks", "--size", "40", "--threads", "1,2", "--traversal", "dda")
    for t in (int(x) for x in a.threads.split(",")):
        for mode, shadows in looks.MODES:
            s = looks.looks_spec(SCENE, a.size, t, a.traversal, mode, shadows)
            assert s.scene == SCENE and s.size == (40, 40) and s.grid.threads == t
            check_defaults(s.grid, GridParams, "threads")
            r = s.render
            assert (r.width, r.height, r.threads, r.traversal, r.shading, r.shadows) == (40, 40, t, "dda", mode, shadows)
            check_defaults(r, RenderParams, "width", "height", "threads", "traversal", "shading", "shadows")
            assert s.view.follow_camera and s.camera() is None
            check_defaults(s.view, ViewSpec, "follow_camera", "size")
    assert parse("looks").traversal == RenderParams().traversal
