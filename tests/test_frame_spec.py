"""FrameSpec: one description of a frame through the command line, the viewer's state, its render
worker's jobs and pipeline, a dump's run.json and the Dask wire format (each gives back an equal
spec), a wire dict of another version or with a bad field refused (on a worker, and on a dump's
--resume), and a spec shipped to a Dask worker rendering the frame a local pipeline renders."""

import argparse
import dataclasses
import io
import json
import time
from types import SimpleNamespace

import numpy as np
import pytest

from gridrt import FrameSpec, GridParams, InputError, RenderParams, ViewSpec
from gridrt.app import cli
from gridrt.app.__main__ import main
from gridrt.app.frame_out import spec_differences
from gridrt.app.viewer.view import Viewer, add_parser, initial_state
from gridrt.app.viewer.worker import RenderWorker
from gridrt.camera import Camera
from gridrt.frame import WIRE_VERSION
from gridrt.scene import SceneSpec

#: a spec in which every part differs from its defaults
SPEC = FrameSpec(
    scene=SceneSpec(source="icosphere", count=320, seed=3),
    grid=GridParams(strategy="sort_middle", density=2.5, macro=3, insert="exact", threads=1, max_cells=1 << 20,
                    grid="two_level", top_density=0.125, leaf_density=3.0),
    render=RenderParams(width=40, height=30, shading="normal", shadows=True, light=(1.0, 5.0, 2.0), watertight=False,
                        threads=1, traversal="dda", packet=(4, 2), packet_precision="float32"),
    view=ViewSpec(eye=(2.0, 1.5, 3.0), target=(0.0, 0.25, 0.0), fov=35.0, up=(0.0, 0.0, 1.0), follow_camera=True,
                  split_static=False, t0=0.5, dt=0.25, size=(40, 30)),
)


def spec_argv(s, times=True):
    """The command line that asks for the spec ``s`` (written from the spec's fields, option by
    option); without ``times``, leaving out --t0 and --dt (the viewer has none)."""
    g, r, v, sc = s.grid, s.render, s.view, s.scene
    xyz = lambda p: ",".join(map(repr, p))  # noqa: E731
    argv = ["--scene", sc.source, "--count", str(sc.count), "--seed", str(sc.seed),
            "--strategy", g.strategy, "--lambda", repr(g.density), "--macro", str(g.macro), "--insert", g.insert,
            "--threads", str(g.threads), "--max-cells", str(g.max_cells), "--grid", g.grid,
            "--top-density", repr(g.top_density), "--leaf-density", repr(g.leaf_density),
            "--size", f"{r.width}x{r.height}", "--shading", r.shading, "--light", xyz(r.light),
            "--traversal", r.traversal, "--packet", "x".join(map(str, r.packet)),
            "--packet-precision", r.packet_precision,
            "--eye", xyz(v.eye), "--target", xyz(v.target), "--fov", repr(v.fov), "--up", xyz(v.up)]
    argv += ["--t0", repr(v.t0), "--dt", repr(v.dt)] * times
    argv += ["--shadows"] * r.shadows + ["--fast-intersect"] * (not r.watertight)
    argv += ["--follow-camera"] * v.follow_camera + ["--no-split"] * (not v.split_static)
    return argv


def dump_parser():
    from gridrt.app import dump

    p = argparse.ArgumentParser()
    dump.add_parser(p.add_subparsers())
    return p


def test_command_line_gives_the_spec():
    a = dump_parser().parse_args(["dump", *spec_argv(SPEC)])
    assert cli.frame_spec(a) == SPEC


def test_command_line_defaults_are_the_spec_defaults():
    """Every default is FrameSpec's, but for the command line's camera policy: the scene's own
    camera (where it has one) unless --eye/--target or --no-scene-camera, as in the viewer."""
    a = dump_parser().parse_args(["dump"])
    spec = cli.frame_spec(a)
    assert spec == FrameSpec(view=ViewSpec(follow_camera=True)).resized(*a.size)
    for argv, follows in ((["--no-scene-camera"], False), (["--eye", "1,2,3", "--target", "0,0,0"], False),
                          (["--eye", "1,2,3", "--target", "0,0,0", "--follow-camera"], True)):
        assert cli.frame_spec(dump_parser().parse_args(["dump", *argv])).view.follow_camera is follows, argv


def test_viewer_state_changes_the_spec_by_replace():
    from gridrt.app.viewer.state import ViewerState
    from gridrt.app.viewer.view import add_parser, initial_state

    p = argparse.ArgumentParser()
    add_parser(p.add_subparsers())
    st = initial_state(p.parse_args(["view", *spec_argv(SPEC, times=False)]))
    # the viewer has no --t0/--dt: its spec is SPEC with the view's default times
    assert st.spec == dataclasses.replace(SPEC, view=SPEC.view.replace(t0=0.0, dt=ViewSpec.dt))
    # the widgets' and keys' changes, and back again: the same spec
    st = ViewerState(spec=SPEC, max_threads=1)
    before = st.spec
    assert st.set_grid(density=7.0) and st.set_render(shading="cost")
    st.camera = Camera(eye=(9.0, 9.0, 9.0), target=(1.0, 1.0, 1.0), up=SPEC.view.up, fov=50.0)
    st.follow_camera = False
    assert st.spec.grid.density == 7.0 and st.spec.render.shading == "cost"
    assert (st.spec.view.eye, st.spec.view.fov, st.spec.view.follow_camera) == ((9.0, 9.0, 9.0), 50.0, False)
    assert st.spec.scene is before.scene  # (untouched parts are the same objects)
    assert st.set_grid(density=SPEC.grid.density) and st.set_render(shading=SPEC.render.shading)
    st.camera = SPEC.camera()
    st.follow_camera = True
    assert st.spec == before == SPEC
    # a refused value leaves the spec unchanged
    assert not st.set_grid(density=-1.0)
    assert st.spec == SPEC


def test_wire_round_trip_through_json():
    wire = json.loads(json.dumps(SPEC.to_wire()))
    assert wire["format"] == "gridrt.FrameSpec" and wire["version"] == WIRE_VERSION
    back = FrameSpec.from_wire(wire)
    assert back == SPEC
    assert FrameSpec.from_wire(json.loads(json.dumps(FrameSpec().to_wire()))) == FrameSpec()


@pytest.mark.parametrize("version, word", [(WIRE_VERSION - 1, "older"), (WIRE_VERSION + 1, "newer")])
def test_wire_of_another_version_is_refused(version, word):
    wire = dict(SPEC.to_wire(), version=version)
    with pytest.raises(InputError) as e:
        FrameSpec.from_wire(wire)
    msg = str(e.value)
    assert "\n" not in msg and word in msg
    assert f"version {version}" in msg and f"version {WIRE_VERSION}" in msg


@pytest.mark.parametrize("change, words", [
    (lambda w: w.update(colour=1), "unknown keys: colour"),
    (lambda w: w["view"].update(zoom=2.0), "unknown keys: zoom"),
    (lambda w: w["grid"].update(density="2.5"), "grid.density must be a number"),
    (lambda w: w["render"].update(width=40.0), "render.width must be an integer"),
    (lambda w: w["render"].update(shadows=1), "render.shadows must be true/false"),
    (lambda w: w["view"].update(eye="2,1.5,3"), "view.eye must be a list of numbers or null"),
    (lambda w: w["scene"].update(count=True), "scene.count must be an integer or null"),
    (lambda w: w.update(format="other"), "not a FrameSpec"),
    (lambda w: w.pop("grid"), "no 'grid' part"),
    (lambda w: w["grid"].update(strategy="nope"), "nope"),
    (lambda w: w["view"].update(fov=180.0), "fov"),
    (lambda w: w["view"].update(size=[41, 30]), "differs from view size 41x30"),
])
def test_wire_with_a_bad_field_is_refused(change, words):
    wire = json.loads(json.dumps(SPEC.to_wire()))
    change(wire)
    with pytest.raises(InputError, match=words.replace(".", r"\.").replace("(", r"\(")):
        FrameSpec.from_wire(wire)


def test_spec_validates_on_construction_and_replace():
    with pytest.raises(InputError, match="both an eye and a target"):
        ViewSpec(eye=(1, 2, 3))
    with pytest.raises(InputError, match="view dt must be finite"):
        dataclasses.replace(SPEC.view, dt=float("nan"))
    with pytest.raises(InputError, match="render size 50x30 differs"):
        dataclasses.replace(SPEC, render=SPEC.render.replace(width=50))
    assert SPEC.resized(50, 20).render.width == 50 and SPEC.resized(50, 20).size == (50, 20)
    with pytest.raises(InputError, match="scene count must be an integer"):
        SceneSpec(count="many")


def test_dask_worker_renders_the_spec_it_was_shipped():
    """A spec shipped over a real (in-process) Dask cluster: the worker rebuilds it from the wire
    and renders the frame that a local pipeline renders from the same spec."""
    distributed = pytest.importorskip("distributed")
    from gridrt.app.cluster.dump import render_chunk
    from gridrt.app.frame_out import encode_frame
    from gridrt.pipeline import FramePipeline

    spec = FrameSpec(scene=SceneSpec(source="icosphere", count=80), grid=GridParams(threads=1),
                     render=RenderParams(width=24, height=16, threads=1, shading="normal"),
                     view=ViewSpec(size=(24, 16), t0=0.0, dt=0.5))
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=False, protocol="tcp://",
                                  host="127.0.0.1", dashboard_address=None) as lc, distributed.Client(lc) as client:
        r = client.submit(render_chunk, json.loads(json.dumps(spec.to_wire())), True, 0, 2, None, pure=False).result()
        bad = client.submit(render_chunk, dict(spec.to_wire(), version=WIRE_VERSION + 1), False, 0, 1, None,
                            pure=False).result()
    assert "error" not in r
    pipe = FramePipeline.from_spec(spec)
    for i, item in enumerate(r["frames"]):
        fr = pipe.step(spec.view.time(i))
        assert item["stats"]["t"] == spec.view.time(i)
        assert item["png"] == encode_frame(fr, False)["png"]  # (the normal shading the spec asks for)
        assert np.array_equal(np.load(io.BytesIO(item["t"])), fr.t)
        assert np.array_equal(np.load(io.BytesIO(item["id"])), fr.tri)
        assert (fr.tri >= 0).any()
    # a spec of another version is refused on arrival, as gridrt's own error (not a crash)
    assert isinstance(bad["error"], InputError) and "newer" in str(bad["error"])


def _results(worker, n=1, timeout=300):
    got, t_end = [], time.time() + timeout
    while len(got) < n and time.time() < t_end:
        got += worker.take()
        time.sleep(0.02)
    assert len(got) == n, f"{len(got)} of {n} results in {timeout} s"
    return got


def _pipeline_spec(pipe, scene, times):
    """The FrameSpec that the FramePipeline ``pipe`` renders (its settings and the camera of its
    last frame), with the SceneSpec ``scene`` and the view's ``times`` (t0, dt; a pipeline is
    stepped to times, it holds none)."""
    cam, rp = pipe.last_camera, pipe.render_params
    return FrameSpec(scene=scene, grid=pipe.grid_params, render=rp,
                     view=ViewSpec(eye=cam.eye, target=cam.target, fov=pipe.fov, up=pipe.up,
                                   follow_camera=pipe.follow_camera, split_static=pipe.split_static, t0=times[0],
                                   dt=times[1], size=(rp.width, rp.height)))


def test_viewer_jobs_carry_the_command_lines_spec_to_the_pipeline():
    """The command line's spec through the viewer (its state, the load and frame jobs it submits,
    the pipeline its render worker makes): the pipeline renders SPEC (written option by option
    by spec_argv) in a window of SPEC's size; a setting and the camera changed in the state reach
    the same pipeline (kept across frames, not made again)."""
    p = argparse.ArgumentParser()
    add_parser(p.add_subparsers())
    a = p.parse_args(["view", *spec_argv(SPEC, times=False)])
    want = dataclasses.replace(SPEC, view=SPEC.view.replace(t0=0.0, dt=ViewSpec.dt))  # (the viewer has no times)
    times = (want.view.t0, want.view.dt)
    st = initial_state(a)
    viewer = Viewer(a, st)
    viewer.glfw, viewer.win = SimpleNamespace(get_framebuffer_size=lambda win: SPEC.size), None
    st.framebuffer_size = SPEC.size
    worker = viewer.worker = RenderWorker(viewer._make_pipeline)
    try:
        viewer._start_load(st.scene, keep_camera=True)
        [load] = _results(worker)
        assert load.error is None and load.job.spec == want
        viewer._submit_frame()
        [frame] = _results(worker)
        assert frame.error is None and frame.job.spec == want
        pipe = worker.pipeline
        assert _pipeline_spec(pipe, load.scene, times) == want
        assert frame.camera == SPEC.camera()
        # a widget's and a camera move's changes: the kept pipeline renders the state's new spec
        assert st.set_grid(density=7.0) and st.set_render(shading="cost")
        st.camera = Camera(eye=(3.0, 2.0, 1.0), target=(0.0, 0.5, 0.0), up=SPEC.view.up, fov=50.0)
        viewer._submit_frame()
        [frame] = _results(worker)
        assert frame.error is None and worker.pipeline is pipe
        assert _pipeline_spec(pipe, load.scene, times) == st.spec != want
        assert (pipe.grid_params.density, pipe.render_params.shading, pipe.fov) == (7.0, "cost", 50.0)
        viewer._submit_frame()  # nothing changed: no frame rendered again
        assert not worker.busy
    finally:
        worker.stop()


def dump_argv(out, *more):
    return ["dump", *spec_argv(SPEC), "--frames", "1", "--no-progress", "--out", str(out), *map(str, more)]


def test_dump_records_its_spec_and_resumes_only_the_same(tmp_path, capsys):
    """A dump's run.json holds the dump's FrameSpec in the wire format, read back equal to SPEC
    (the command line's), beside the options the spec does not hold; --resume refuses other
    settings naming the fields that differ, and a spec of another version with its own message:
    one line each, no traceback, the folder as it was."""
    out = tmp_path / "d"
    assert main(dump_argv(out)) == 0
    run = json.loads((out / "run.json").read_text())
    assert FrameSpec.from_wire(run["spec"]) == SPEC
    assert run["settings"] == {"save_buffers": False} and run["frames"] == 1
    before = {q.name: q.read_bytes() for q in out.iterdir()}

    def refused(*argv):
        capsys.readouterr()
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert "Traceback" not in err and len(err.strip().splitlines()) == 1, err
        assert {q.name: q.read_bytes() for q in out.iterdir()} == before
        return err.strip()

    other = [x if x != SPEC.grid.strategy else "serial" for x in spec_argv(SPEC)]
    other[other.index("--fov") + 1] = "50"
    err = refused("dump", *other, "--frames", "2", "--no-progress", "--out", str(out), "--resume")
    assert f"was made with other settings (grid.strategy: {SPEC.grid.strategy!r} there, 'serial' now, " \
           f"view.fov: {SPEC.view.fov!r} there, 50.0 now)" in err, err
    err = refused(*dump_argv(out, "--frames", "2", "--resume", "--save-buffers"))
    assert "(save_buffers: False there, True now)" in err, err
    for version, word in ((WIRE_VERSION + 1, "newer"), (WIRE_VERSION - 1, "older")):
        (out / "run.json").write_text(json.dumps(dict(run, spec=dict(run["spec"], version=version))))
        before["run.json"] = (out / "run.json").read_bytes()
        err = refused(*dump_argv(out, "--frames", "2", "--resume"))
        assert err.startswith(f"gridrt: error: --resume: the settings in {out}/run.json cannot be read "
                              f"(FrameSpec wire version {version} is {word} than this gridrt's version "
                              f"{WIRE_VERSION}"), err
    # the same settings resume (the run.json of this version back)
    (out / "run.json").write_text(json.dumps(run))
    assert main(dump_argv(out, "--frames", "2", "--resume")) == 0
    assert (out / "frame_00001.png").exists()


def test_spec_differences_name_the_fields_a_resume_compares():
    """The fields a resumed dump's spec must share: any but the thread counts; a size is the view's."""
    threads = SPEC.replace(grid=SPEC.grid.replace(threads=4), render=SPEC.render.replace(threads=4))
    assert spec_differences(SPEC, threads) == []
    assert spec_differences(SPEC, SPEC.resized(41, 30)) == [("view.size", [40, 30], [41, 30])]
    changed = SPEC.replace(scene=SPEC.scene.replace(seed=4), view=SPEC.view.replace(t0=1.5))
    assert spec_differences(SPEC, changed) == [("scene.seed", 3, 4), ("view.t0", 0.5, 1.5)]
