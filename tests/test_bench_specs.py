"""The benchmarks' configurations are FrameSpecs whose parts are the options given: each benchmark's
spec builders are fed the options its own parser reads from a command line, and every part is
checked against those options as this file reads them (and against the settings' field defaults
where the benchmark leaves a setting alone)."""

from dataclasses import fields

import numpy as np
import pytest

from gridrt.app.__main__ import build_parser, main
from gridrt.app.bench import core, packets, peers
from gridrt.camera import Camera
from gridrt.config import GridParams, RenderParams
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
            # --strategy auto: serial at 1 thread, sort_middle above (the option's help)
            assert g.strategy == ((("serial" if T == 1 else "sort_middle") if strategy == "auto" else strategy))
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


def test_bench_core_renders_and_builds_what_its_specs_say(tmp_path, monkeypatch):
    """What a run of ``bench core`` hands its builders and renderers: the grid settings of the
    serial rows and the render settings and camera of the ray rows, against the options and an
    independent framing of the scene (facing_camera over its triangles' bounds)."""
    built, rendered = [], []

    class Builder(core.GridBuilder):
        def __init__(self, params=None):
            built.append(params)
            super().__init__(params)

    class Spy(core.Renderer):
        def render(self, grid, tris, camera, params=None, *rest, **kw):
            rendered.append((camera, params))
            return super().render(grid, tris, camera, params, *rest, **kw)

    monkeypatch.setattr(core, "GridBuilder", Builder)
    monkeypatch.setattr(core, "Renderer", Spy)
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
