"""The interactive viewer, for real: no mocks.

* ``test_view_without_display``: no DISPLAY (or no X server) -> one-line message naming the
  headless dump, status 3.
* ``test_viewer_state_actions``: the clock, strategy/thread stepping and parameter building of
  gridrt.app.viewer.state.ViewerState.
* ``test_panel_headless_egl``: the real panel (gridrt.app.viewer.ui) and blit (gridrt.app.viewer.blit, shaders/) drawn into an
  EGL framebuffer: the image shows through pixel-exactly outside the panel, the panel's own pixels
  are there, and synthetic mouse clicks on its widgets change the viewer state.
* ``test_viewer_window_under_xvfb``: starts Xvfb, launches ``python -m gridrt view`` on a small
  marbles scene, drives it with xdotool (clicks on panel widgets, strategy and thread keys, mouse
  drag and wheel, pause, screenshot, window resize, Esc) and checks the effects through the state
  file the app writes, the screenshot files, an X root-window capture, and an independent headless
  FramePipeline render of the same frame (the viewer has no renderer of its own).
"""

import json
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

import gridrt  # noqa: F401  (sets NUMBA_NUM_THREADS before numba loads)
from gridrt.camera import DEFAULT_FOV, DEFAULT_UP
from helpers.viewer import (
    REPO, H, W, _App, _app_env, _check_scene_image, _dist, _first_frame, _headless_frame, _laid_out, _png, _quit,
    _Run, _X, needs_x, xvfb,  # noqa: F401  (xvfb: a fixture)
)


@pytest.fixture(autouse=True)
def config_home(tmp_path_factory, monkeypatch):
    """The viewer's config folder (GRIDRT_CONFIG_HOME: where it remembers the panel) for each test:
    a fresh temporary one, inherited by the viewers the tests start; never the user's own."""
    d = tmp_path_factory.mktemp("config")
    monkeypatch.setenv("GRIDRT_CONFIG_HOME", str(d))
    return d


# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize("display", [None, ":987"])
def test_view_without_display(tmp_path, display):
    env = _app_env()
    env.pop("WAYLAND_DISPLAY", None)
    if display is None:
        env.pop("DISPLAY", None)
    else:
        env["DISPLAY"] = display   # no X server there
    r = subprocess.run([sys.executable, "-m", "gridrt", "view", "--scene", "marbles"], cwd=tmp_path, env=env,
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 3, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1, r.stderr
    assert ("no display" if display is None else "cannot open an OpenGL 3.3 window") in lines[0]
    assert "gridrt dump" in lines[0]
    assert list(tmp_path.iterdir()) == []


# ---------------------------------------------------------------------------------------------
def test_traversal_choices_round_trip():
    """The panel's traversal combo: every choice sets RenderParams that show as that choice again,
    the default settings are one of the choices, and the choices differ."""
    from gridrt.app.viewer.ui import TRAVERSAL_CHOICES, traversal_label, traversal_setting
    from gridrt.config import RenderParams

    assert traversal_label(RenderParams()) in TRAVERSAL_CHOICES
    seen = set()
    for label in TRAVERSAL_CHOICES:
        rp = RenderParams().replace(**traversal_setting(label))
        assert traversal_label(rp) == label
        seen.add((rp.traversal, rp.packet, rp.packet_precision) if rp.traversal == "cgt" else "dda")
    assert len(seen) == len(TRAVERSAL_CHOICES)
    assert ("cgt", (8, 16), "float32") in seen


def test_viewer_state_actions():
    from gridrt.app.viewer.state import SCALE_MIN, ViewerState
    from gridrt.config import GridParams, RenderParams

    st = ViewerState(duration=8.0, time=7.9, speed=1.0, playing=True)
    st.advance(0.2)
    assert st.time == pytest.approx(0.1)
    st.speed = 2.0
    st.advance(0.5)
    assert st.time == pytest.approx(1.1)
    st.playing = False
    st.advance(1.0)
    assert st.time == pytest.approx(1.1)
    st.playing, st.static = True, True
    st.advance(1.0)
    assert st.time == pytest.approx(1.1)

    from gridrt.grid.registry import names

    a, b, c = names()[:3]
    st.set_grid(strategy=c)
    st.cycle_strategy([a, b, c], +1)
    assert st.grid.strategy == a
    st.cycle_strategy([a, b, c], -1)
    assert st.grid.strategy == c
    st.set_grid(strategy=b)
    st.cycle_strategy([a, c], +1)   # not in the list: the first
    assert st.grid.strategy == a
    # a refused value keeps the params and says why
    before = st.grid
    assert not st.set_grid(strategy="gone") and st.grid is before and "gone" in st.scene_error

    st.set_threads(1)
    st.max_threads = 3
    st.change_threads(-1)
    assert st.threads == st.grid.threads == st.render.threads == 1
    for _ in range(5):
        st.change_threads(+1)
    assert st.threads == st.grid.threads == st.render.threads == 3

    st.scale = 0.25
    assert st.render_size_for(1000, 500) == (250, 125)
    st.scale = SCALE_MIN
    assert st.render_size_for(3, 3) == (1, 1)

    # the layout: the image area at the left, the panel's column (or its strip) at the right edge,
    # nothing while hidden; a window for a w x h image adds the column
    from gridrt.app.viewer.state import PANEL_STRIP_WIDTH, PANEL_WIDTH

    assert st.show_panel and not st.panel_collapsed
    assert st.window_for_image(640, 480) == (640 + PANEL_WIDTH, 480)
    assert st.layout(640 + PANEL_WIDTH, 480) == ((0, 0, 640, 480), (640, 0, PANEL_WIDTH, 480))
    st.image_rect = st.layout(640 + PANEL_WIDTH, 480)[0]
    assert st.in_image(0, 0) and st.in_image(639, 479) and not st.in_image(640, 10) and not st.in_image(10, 480)
    st.panel_collapsed = True
    assert st.window_for_image(640, 480) == (640 + PANEL_STRIP_WIDTH, 480)
    assert st.layout(1000, 480) == ((0, 0, 1000 - PANEL_STRIP_WIDTH, 480), (1000 - PANEL_STRIP_WIDTH, 0,
                                                                            PANEL_STRIP_WIDTH, 480))
    st.toggle_panel()
    assert not st.show_panel and st.window_for_image(640, 480) == (640, 480)
    assert st.layout(1000, 480) == ((0, 0, 1000, 480), (1000, 0, 0, 480))
    st.toggle_panel()
    st.panel_collapsed = False
    assert st.layout(100, 50) == ((0, 0, 1, 50), (1, 0, 99, 50))   # a window narrower than the panel
    snap = st.snapshot()
    assert (snap["show_panel"], snap["panel_collapsed"], snap["image_rect"]) == (True, False, [0, 0, 640, 480])

    # the defaults are the dataclasses' own (one thread count for both); widgets replace fields
    st = ViewerState(max_threads=4)
    assert st.grid_params() == GridParams(threads=st.threads)
    assert st.render_params(64, 48) == RenderParams(width=64, height=48, threads=st.threads)
    assert st.render.traversal == "cgt"
    assert st.set_grid(density=2.5) and st.set_grid(macro=3, insert="exact")
    assert st.set_render(shading="normal") and st.set_render(shadows=True, watertight=False)
    st.set_threads(1)
    assert st.grid_params() == GridParams(threads=1, density=2.5, macro=3, insert="exact")
    assert st.render_params(64, 48) == RenderParams(width=64, height=48, shading="normal", shadows=True,
                                                    watertight=False, threads=1)
    assert not st.set_grid(density=-1.0) and st.grid.density == 2.5 and "density" in st.scene_error
    # the grid kind and a two-level grid's densities are GridParams fields too, and in the state dump
    assert st.set_grid(grid="two_level") and st.set_grid(top_density=0.25, leaf_density=4.0)
    assert st.grid_params() == GridParams(threads=1, density=2.5, macro=3, insert="exact",
                                          grid="two_level", top_density=0.25, leaf_density=4.0)
    snap = st.snapshot()
    assert (snap["grid"], snap["top_density"], snap["leaf_density"]) == ("two_level", 0.25, 4.0)
    assert not st.set_grid(grid="octree") and st.grid.grid == "two_level" and "octree" in st.scene_error
    assert not st.set_grid(leaf_density=0.0) and st.grid.leaf_density == 4.0 and "leaf_density" in st.scene_error


def test_scene_camera_state():
    """The "scene camera" box: on for a scene with its own camera when the viewer wants it, never
    for one without; turning it off or moving the camera keeps the view on screen; Reset view
    returns to it when the scene started on it, else to the home camera."""
    from gridrt.app.viewer.state import ViewerState
    from gridrt.camera import Camera

    st = ViewerState(max_threads=2)
    st.scene_loaded(has_camera=False, want=True)
    assert not st.follow_camera and not st.scene_camera
    st.set_scene_camera(True)                       # no camera of its own: the box stays off
    assert not st.follow_camera
    home = Camera(eye=(0.0, 0.0, 5.0), target=(0.0, 0.0, 0.0))
    st.home = st.camera = home
    st.scene_loaded(has_camera=True, want=True)
    assert st.follow_camera and st.scene_camera
    shown = Camera(eye=(1.0, 2.0, 3.0), target=(0.0, 1.0, 0.0))   # the scene's camera of the frame on screen
    st.camera = shown
    st.set_scene_camera(False)
    assert not st.follow_camera and st.camera == shown
    st.set_scene_camera(True)
    st.leave_scene_camera()                         # a drag, the wheel or a fly key
    assert not st.follow_camera and st.camera == shown
    st.reset_view()
    assert st.follow_camera and st.camera == shown  # back on the scene's camera
    st.scene_loaded(has_camera=True, want=False)    # --no-scene-camera
    assert not st.follow_camera and st.scene_camera
    st.reset_view()
    assert not st.follow_camera and st.camera == home
    snap = st.snapshot()
    assert (snap["scene_camera"], snap["follow_camera"]) == (True, False)


@pytest.mark.parametrize("argv, first, later", [
    ([], True, True),
    (["--no-scene-camera"], False, False),
    (["--follow-camera"], True, True),
    (["--eye", "0,0,5", "--target", "0,0,0"], False, True),
    (["--eye", "0,0,5", "--target", "0,0,0", "--follow-camera"], True, True),
])
def test_scene_camera_options(argv, first, later):
    """The viewer starts on the scene's own camera unless --no-scene-camera, or an explicit
    --eye/--target without --follow-camera (that one for the command line's scene only)."""
    from gridrt.app.__main__ import build_parser
    from gridrt.app.viewer.view import initial_state, start_on_scene_camera

    a = build_parser().parse_args(["view", "--scene", "marbles", *argv])
    assert start_on_scene_camera(a) is first
    assert initial_state(a).prefer_scene_camera is later


def test_viewer_prefs(tmp_path, monkeypatch, config_home):
    """The remembered panel (prefs.py): GRIDRT_CONFIG_HOME, else $XDG_CONFIG_HOME/gridrt, else
    ~/.config/gridrt; saving merges into what is there; an unreadable file counts as empty and a
    failed write is ignored silently; the viewer's initial state starts the panel as remembered
    (--hide-panel hides it anyway), the window the image's --size plus the panel's column."""
    from gridrt.app.__main__ import build_parser
    from gridrt.app.viewer.prefs import config_dir, load_prefs, panel_prefs, prefs_path, save_prefs
    from gridrt.app.viewer.state import PANEL_STRIP_WIDTH, PANEL_WIDTH
    from gridrt.app.viewer.view import initial_state

    assert config_dir() == config_home and prefs_path() == config_home / "viewer.json"
    monkeypatch.delenv("GRIDRT_CONFIG_HOME")
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "xdg"))
    assert config_dir() == tmp_path / "xdg" / "gridrt"
    monkeypatch.setenv("XDG_CONFIG_HOME", "relative/xdg")   # not absolute: ignored, as the XDG spec asks
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    assert config_dir() == tmp_path / "home" / ".config" / "gridrt"
    monkeypatch.setenv("GRIDRT_CONFIG_HOME", str(config_home))

    assert load_prefs() == {} and panel_prefs({}) == (True, False)
    assert save_prefs({"panel_collapsed": True}) and save_prefs({"other": 1})
    assert load_prefs() == {"panel_collapsed": True, "other": 1} and panel_prefs(load_prefs()) == (True, True)
    assert sorted(p.name for p in config_home.iterdir()) == ["viewer.json"]
    assert panel_prefs({"show_panel": "no", "panel_collapsed": 1}) == (True, False)   # wrong types: defaults
    blocker = tmp_path / "a_file"
    blocker.write_text("")
    assert save_prefs({"show_panel": False}, path=blocker / "viewer.json") is False   # silently refused
    broken = tmp_path / "broken.json"
    broken.write_text("{not json")
    assert load_prefs(broken) == {}

    parse = build_parser().parse_args
    st = initial_state(parse(["view", "--scene", "marbles", "--size", "200x100"]))
    assert (st.show_panel, st.panel_collapsed, st.window_size) == (True, True, (200 + PANEL_STRIP_WIDTH, 100))
    save_prefs({"show_panel": False, "panel_collapsed": False})
    st = initial_state(parse(["view", "--scene", "marbles", "--size", "200x100"]))
    assert (st.show_panel, st.window_size) == (False, (200, 100))
    save_prefs({"show_panel": True})
    st = initial_state(parse(["view", "--scene", "marbles", "--size", "200x100"]))
    assert (st.show_panel, st.panel_collapsed, st.window_size) == (True, False, (200 + PANEL_WIDTH, 100))
    st = initial_state(parse(["view", "--scene", "marbles", "--size", "200x100", "--hide-panel"]))
    assert (st.show_panel, st.window_size) == (False, (200, 100))
    assert load_prefs()["show_panel"] is True   # the option is for this run: not remembered


def _textured_gltf(folder):
    """(path, texel bytes of each texture): a glTF file in ``folder`` with two quads, each with
    its own PNG texture (tex0.png, tex1.png next to it), and a perspective camera node whose
    translation is animated (0..2 s), so that the file loads as an animation with a camera."""
    import base64

    folder = Path(folder)
    pos = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], np.float32)
    pos = np.concatenate([pos, pos + np.float32([1.5, 0, 0])])
    uv = np.array([[0, 1], [1, 1], [1, 0], [0, 0]] * 2, np.float32)
    idx = np.array([0, 1, 2, 0, 2, 3], np.uint16)
    times = np.array([0.0, 2.0], np.float32)
    moves = np.array([[1.25, 0.5, 3.0], [1.25, 0.5, 4.0]], np.float32)
    parts = [pos, uv, idx, idx + np.uint16(4), times, moves]
    offsets = np.concatenate([[0], np.cumsum([a.nbytes for a in parts])]).tolist()
    blob = b"".join(a.tobytes() for a in parts)
    sizes = []
    for i, colour in enumerate(((200, 40, 40), (40, 40, 200))):
        img = np.zeros((8, 16, 3), np.uint8)
        img[:] = colour
        img[::2, ::2] = 255
        Image.fromarray(img).save(folder / f"tex{i}.png")
        sizes.append(img.nbytes)
    kinds = [(5126, "VEC3"), (5126, "VEC2"), (5123, "SCALAR"), (5123, "SCALAR"), (5126, "SCALAR"), (5126, "VEC3")]
    accessors = [{"bufferView": i, "componentType": c, "count": len(a), "type": k}
                 for i, (a, (c, k)) in enumerate(zip(parts, kinds))]
    accessors[0].update(min=pos.min(0).tolist(), max=pos.max(0).tolist())
    accessors[4].update(min=[0.0], max=[2.0])
    doc = {
        "asset": {"version": "2.0"},
        "scene": 0, "scenes": [{"nodes": [0, 1]}],
        "nodes": [{"mesh": 0}, {"camera": 0, "translation": [1.25, 0.5, 3.0]}],
        "cameras": [{"type": "perspective", "perspective": {"yfov": 0.8, "znear": 0.01, "aspectRatio": 1.333}}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "TEXCOORD_0": 1}, "indices": 2 + i, "material": i}
                                   for i in range(2)]}],
        "materials": [{"pbrMetallicRoughness": {"baseColorTexture": {"index": i}}} for i in range(2)],
        "textures": [{"source": i} for i in range(2)],
        "images": [{"uri": f"tex{i}.png"} for i in range(2)],
        "buffers": [{"byteLength": len(blob),
                     "uri": "data:application/octet-stream;base64," + base64.b64encode(blob).decode()}],
        "bufferViews": [{"buffer": 0, "byteOffset": offsets[i], "byteLength": a.nbytes} for i, a in enumerate(parts)],
        "accessors": accessors,
        "animations": [{"channels": [{"sampler": 0, "target": {"node": 1, "path": "translation"}}],
                        "samplers": [{"input": 4, "output": 5}]}],
    }
    path = folder / "quads.gltf"
    path.write_text(json.dumps(doc))
    return path, sizes


def _run_jobs(worker, *jobs):
    """Each job's result on ``worker``, one job at a time."""
    out = []
    for job in jobs:
        worker.submit(job)
        res, t0 = [], time.time()
        while not res and time.time() - t0 < 300:
            res = worker.take()
            time.sleep(0.01)
        [r] = res
        assert r.error is None, r.error
        out.append(r)
    return out


def test_worker_texture_progress(tmp_path):
    """A scene load on the viewer's worker counts the textures its loader reads (texture_progress):
    :meth:`RenderWorker.progress` has the running count during the load (read here from inside it,
    where the pipeline is made), the LoadResult the totals, and whether the scene has a camera."""
    from gridrt.app.viewer.worker import LoadJob, RenderWorker, TextureProgress
    from gridrt.config import GridParams, RenderParams
    from gridrt.frame import FrameSpec
    from gridrt.scene import SceneSpec

    path, sizes = _textured_gltf(tmp_path)
    seen = {}

    def factory(scene, job):   # on the worker thread, after the loader, before the load ends
        seen["progress"], seen["scene"] = worker.progress(), scene
        return scene

    worker = RenderWorker(factory)
    try:
        assert worker.progress() is None
        [r] = _run_jobs(worker, LoadJob(FrameSpec(scene=SceneSpec(source=str(path)), grid=GridParams(threads=1),
                                                  render=RenderParams(threads=1))))
        assert worker.progress() is None   # no load runs
    finally:
        worker.stop()
    assert r.error is None and r.has_camera and r.triangles == 4
    p = seen["progress"]
    assert (p.count, p.nbytes) == (2, sum(sizes)) and p.last.endswith("tex1.png")
    assert p.label() == f"loading textures: 2 read ({sum(sizes) / 2**20:.2f} MiB), last: {p.last}"
    assert r.textures.as_dict() == {"count": 2, "bytes": sum(sizes), "last": p.last}
    scene = seen["scene"]
    assert scene.surface is not None and len(scene.surface.textures) == 2 and scene.camera_at(0.0) is not None
    assert TextureProgress().label() == ""


def test_worker_warm_load_steps_a_throwaway_pipeline_first():
    """LoadJob(warm=True), the viewer's first load on a warm cache: before the load's result the
    worker steps a pipeline of its own, at WARM_SIZE and the spec's first-frame time (so that the
    first frame's kernels have loaded by then); the loaded pipeline is not stepped, and its first
    frame equals, bit for bit, the first frame of a load without it."""
    from gridrt.app.viewer.worker import WARM_SIZE, FrameJob, LoadJob, RenderWorker
    from gridrt.config import GridParams, RenderParams
    from gridrt.frame import FrameSpec, ViewSpec
    from gridrt.pipeline import FramePipeline
    from gridrt.scene import SceneSpec

    made = []

    def factory(scene, job):
        pipe = FramePipeline.from_spec(job.spec, scene=scene)
        steps, step = [], pipe.step
        pipe.step = lambda t, *a, **k: steps.append(t) or step(t, *a, **k)
        made.append((pipe, steps))
        return pipe

    spec = FrameSpec(scene=SceneSpec(source="icosphere", count=320, animate="twist"), grid=GridParams(threads=2),
                     render=RenderParams(threads=2), view=ViewSpec(t0=0.4)).resized(40, 30)
    frames = {}
    for warm in (True, False):
        made.clear()
        worker = RenderWorker(factory)
        try:
            _, frame = _run_jobs(worker, LoadJob(spec, warm=warm), FrameJob(spec, spec.view.t0))
        finally:
            worker.stop()
        frames[warm] = frame
        loaded, loaded_steps = made[0]
        assert loaded_steps == [0.4]   # (the frame job's, after the load)
        if warm:
            [(throwaway, thrown_steps)] = made[1:]
            assert thrown_steps == [0.4]
            assert (throwaway.render_params.width, throwaway.render_params.height) == WARM_SIZE
        else:
            assert len(made) == 1
    assert np.array_equal(frames[True].image, frames[False].image)
    assert frames[True].image.shape[:2] == (30, 40)


# ---------------------------------------------------------------------------------------------
def _pattern(w, h):
    """A test image whose every row and column differs: (h, w, 4) uint8."""
    y, x = np.mgrid[0:h, 0:w]
    img = np.empty((h, w, 4), np.uint8)
    img[..., 0] = x % 256
    img[..., 1] = y % 256
    img[..., 2] = (7 * x + 3 * y) % 256
    img[..., 3] = 255
    return img


def _panel_bg_fraction(pixels):
    """The fraction of ``pixels`` ((..., 3) uint8) that show the panel's own (opaque) background."""
    from gridrt.app.viewer.ui import PANEL_BG

    return np.all(np.abs(pixels.astype(np.float64) - np.asarray(PANEL_BG) * 255.0) <= 3, axis=-1).mean()


def _rect_slice(rect, shrink=2):
    x, y, w, h = (int(round(v)) for v in rect)
    return slice(y + shrink, y + h - shrink), slice(x + shrink, x + w - shrink)


def test_panel_headless_egl(tmp_path, monkeypatch):
    moderngl = pytest.importorskip("moderngl")
    imgui_bundle = pytest.importorskip("imgui_bundle")
    try:
        ctx = moderngl.create_standalone_context(backend="egl")
    except Exception as e:  # pragma: no cover - depends on the machine's GL
        pytest.skip(f"no EGL OpenGL context: {e}")
    monkeypatch.chdir(tmp_path)   # imgui must not write imgui.ini (or anything) here
    from imgui_bundle import imgui

    from gridrt.app.viewer.blit import Blitter
    from gridrt.app.viewer.state import ViewerState
    from gridrt.app.viewer.ui import ImguiRuntime, draw_overlay, draw_panel
    from gridrt.config import GridParams
    from gridrt.frame import FrameSpec
    from gridrt.stats import BuildStats, FrameStats, RenderStats

    from gridrt.app.viewer.ui import PANEL_STRIP_WIDTH, PANEL_WIDTH

    W, H = 960, 870   # tall enough for the whole panel (the viewer scrolls it in smaller windows)
    IW = W - PANEL_WIDTH   # the image area's width beside the panel's column
    fbo = ctx.simple_framebuffer((W, H), components=4)
    ui = ImguiRuntime()
    blit = Blitter(ctx)
    img = _pattern(IW, H)
    st = ViewerState(spec=FrameSpec(grid=GridParams(threads=2)), max_threads=8, triangles=1234, scene_name="marbles")
    build = BuildStats(stages=dict(clear_ms=0.1, insert_ms=1.5, macro_ms=0.2), build_ms=1.8, strategy="serial",
                       threads=2, insert="bbox", triangles=1234, cells=5000, references=8000, refs_per_tri=6.5,
                       cells_cleared=0, cells_inspected=0, macro_cells=0, macro_full=0, dims="20x10x25",
                       grid_bytes=65536)
    render = RenderStats(render_ms=4.0, mrays=10.0, hit_fraction=0.5, tests_per_ray=1.0, cells_per_ray=1.0,
                         render_threads=2, traversal="cgt", lights=2, shadow_rays_per_pixel=1.5, shade_ms=3.25)
    st.stats = FrameStats(frame=1, t=0.0, triangles=1234, build=build, render=render, rebuilt=True, anim_ms=0.1,
                          static_build_ms=0.0, frame_ms=6.5, width=W, height=H, shading="material")
    for i in range(60):   # render time falls steadily, build time stays flat
        st.history.add(dict(build_ms=1.0, render_ms=6.0 - 0.08 * i, frame_ms=7.0))
    names = ["serial", "other"]
    io = imgui.get_io()

    def frame(events=(), overlay=False):
        """One frame as the viewer draws it: the panel in its column, the image (a _pattern of the
        image area's size) in the image area."""
        for ev in events:
            ev()
        ui.new_frame((W, H), 1 / 60)
        st.widget_rects = {}
        draw_panel(st, names)
        if overlay:
            draw_overlay(st, 2.5)
        (ix, iy, iw, ih), _ = st.layout(W, H)
        if blit.size != (iw, ih):
            blit.upload(_pattern(iw, ih))
        fbo.use()
        ctx.clear(0.0, 0.0, 0.0, 1.0)
        blit.draw((ix, H - iy - ih, iw, ih))
        ui.render()
        return np.frombuffer(fbo.read(components=3), np.uint8).reshape(H, W, 3)[::-1]

    def click(name, fx=0.5):
        """Move, press, release over widget ``name`` at fraction fx of its width (3 frames)."""
        x, y, w, h = st.widget_rects[name]
        px, py = x + min(max(fx * w, 2), w - 2), y + h / 2
        frame([lambda: io.add_mouse_pos_event(px, py)])
        frame([lambda: io.add_mouse_button_event(0, True)])
        frame([lambda: io.add_mouse_button_event(0, False)])
        return frame()

    try:
        for _ in range(3):
            out = frame()
        # the panel: a column of its own at the right edge, full height, beside the image area
        px, py, pw, ph = st.panel_rect
        assert st.panel_rect == (IW, 0.0, PANEL_WIDTH, H)
        assert st.layout(W, H) == ((0, 0, IW, H), (IW, 0, PANEL_WIDTH, H))
        # the whole image shows, pixel-exact and the right way up, in the image area: nothing over it
        assert np.array_equal(out[:, :IW], img[..., :3])
        # the panel: mostly its opaque background, plus bright text
        panel = out[:, IW:]
        assert _panel_bg_fraction(panel) > 0.3, _panel_bg_fraction(panel)
        assert (panel.astype(np.float64).mean(axis=-1) > 170).mean() > 0.01
        for name in ("collapse panel", "built-in", "triangles", "mesh file", "open file", "play", "time", "speed",
                     "strategy", "threads", "grid", "lambda", "macro cell", "insertion", "intersection", "shading",
                     "traversal", "shadows", "resolution", "save image", "save window", "reset view", "plot"):
            x, y, w, h = st.widget_rects[name]
            assert px <= x and x + w <= px + pw and py <= y and y + h <= py + ph, name
        assert not (tmp_path / "imgui.ini").exists()
        # the file box's trust checkbox: what "Open file" loads carries it
        assert not st.file_allow_outside
        click("trust outside refs", 0.05)
        assert st.file_allow_outside
        st.file_text = str(tmp_path / "scene.gltf")
        click("open file")
        assert st.scene_request.source == st.file_text and st.scene_request.allow_outside
        st.scene_request = None
        click("trust outside refs", 0.05)
        assert not st.file_allow_outside
        # the implot plot draws the history: the "render" line (implot's second default colour,
        # orange) falls from left to right
        sy, sx = _rect_slice(st.widget_rects["plot"])
        plot = out[sy, sx].astype(int)
        orange = (plot[..., 0] > 170) & (plot[..., 1] > 90) & (plot[..., 1] < 170) & (plot[..., 2] < 120)
        ys, xs = np.nonzero(orange)
        mid = plot.shape[1] / 2
        assert (xs < mid).sum() > 20 and (xs > mid).sum() > 20
        assert ys[xs < mid].mean() < ys[xs > mid].mean() - 10   # image y grows downwards

        # clicks on real widgets change the state (and the pixels)
        sy, sx = _rect_slice(st.widget_rects["shadows"], 0)
        before = out[sy, sx].copy()
        assert st.render.shadows is False
        out = click("shadows", 0.05)
        assert st.render.shadows is True
        assert (np.abs(out[sy, sx].astype(int) - before).sum(axis=-1) > 60).sum() > 5   # the check mark
        assert st.playing is True
        click("play")
        assert st.playing is False
        click("threads", 1.0)
        assert st.threads == st.max_threads
        click("threads", 0.0)
        assert st.threads == 1
        click("save window")
        assert st.want_window_shot is True

        # the stats: the material pass's time, lights and shadow rays; the whole scene's references
        # per triangle (8000 / 1234, not the build's own 6.5), and for a split scene both parts'
        # together, with the moving part's own figure after them
        assert st.panel_text["shade"] == "shade      3.25 ms  material"
        assert st.panel_text["lights"] == "lights 2   shadow rays 1.50/px"
        assert st.panel_text["references"] == f"references 8,000 ({8000 / 1234:.2f}/tri)"
        static = BuildStats(stages=dict(insert_ms=9.0), build_ms=9.0, strategy="serial", threads=2, insert="bbox",
                            triangles=10000, cells=40000, references=30000, refs_per_tri=3.0, cells_cleared=0,
                            cells_inspected=0, macro_cells=0, macro_full=0, dims="40x20x50", grid_bytes=1 << 20)
        single = st.stats
        st.stats = FrameStats(frame=2, t=0.0, triangles=11234, build=build, render=render, rebuilt=True,
                              anim_ms=0.1, static_build_ms=0.0, frame_ms=6.5, width=W, height=H, shading="material",
                              static=static)
        frame()
        assert st.panel_text["references"] == f"references 38,000 ({38000 / 11234:.2f}/tri, moving 6.50)"
        st.stats = single
        # the shading combo offers the modes; "auto" shows what it resolved to in the last frame
        from gridrt.app.viewer.ui import shading_label
        from gridrt.config import SHADING_MODES

        assert shading_label("auto", st.stats) == "auto: material" and shading_label("normal", st.stats) == "normal"
        assert shading_label("auto", None) == "auto"
        assert st.render.shading == "auto"
        click("shading")
        assert {f"shading: {m}" for m in SHADING_MODES} <= set(st.widget_rects)
        click("shading: material")
        assert st.render.shading == "material" and "shading: auto" not in st.widget_rects
        # the scene camera box: greyed out (a click does nothing) for a scene without a camera;
        # for one with a camera a click turns it off and on
        assert not st.scene_camera and not st.follow_camera
        click("scene camera", 0.05)
        assert not st.follow_camera
        st.scene_loaded(has_camera=True, want=True)
        assert st.follow_camera
        click("scene camera", 0.05)
        assert not st.follow_camera and st.scene_camera
        click("scene camera", 0.05)
        assert st.follow_camera

        # the grid kind: a click opens the combo's list, a click on an item picks it; a two-level
        # grid (or auto) shows its density sliders, a uniform one does not
        from gridrt.app.viewer.ui import LEAF_DENSITY_RANGE, TOP_DENSITY_RANGE

        assert st.grid.grid == "uniform" and "top density" not in st.widget_rects
        click("grid")
        assert {"grid: uniform", "grid: two_level", "grid: auto"} <= set(st.widget_rects)
        click("grid: two_level")
        assert st.grid.grid == "two_level" and "grid: auto" not in st.widget_rects
        click("top density", 0.0)
        assert st.grid.top_density == pytest.approx(TOP_DENSITY_RANGE[0], rel=1e-3)
        click("leaf density", 1.0)
        assert st.grid.leaf_density == pytest.approx(LEAF_DENSITY_RANGE[1], rel=1e-3)
        for name in ("top density", "leaf density", "reset view", "plot"):   # the panel still shows it all
            x, y, w, h = st.widget_rects[name]
            assert px <= x and x + w <= px + pw and py <= y and y + h <= st.panel_rect[1] + st.panel_rect[3], name
        click("grid")
        click("grid: uniform")
        assert st.grid.grid == "uniform" and "top density" not in st.widget_rects
        assert st.grid.leaf_density == pytest.approx(LEAF_DENSITY_RANGE[1], rel=1e-3)   # kept for the next switch

        # the progress overlay sits in the middle of the image area
        st.busy = "compiling numba kernels"
        out = frame(overlay=True)
        out = frame(overlay=True)
        x, y, w, h = st.widget_rects["busy overlay"]
        assert abs(x + w / 2 - IW / 2) <= 1 and abs(y + h / 2 - H / 2) <= 1
        sy, sx = _rect_slice((x, y, w, h))
        assert not np.array_equal(out[sy, sx], img[sy, sx, :3])
        st.busy = None

        # the panel's arrow collapses it to a thin strip at the right edge (its own arrow opens it
        # again): the image area takes the rest of the window, the strip only its arrow
        click("collapse panel")
        out = frame()
        assert st.panel_collapsed and st.panel_rect == (W - PANEL_STRIP_WIDTH, 0.0, PANEL_STRIP_WIDTH, H)
        assert set(st.widget_rects) == {"expand panel"}
        x, y, w, h = st.widget_rects["expand panel"]
        assert W - PANEL_STRIP_WIDTH < x and x + w < W and y < 40
        assert np.array_equal(out[:, :W - PANEL_STRIP_WIDTH], _pattern(W - PANEL_STRIP_WIDTH, H)[..., :3])
        assert _panel_bg_fraction(out[:, W - PANEL_STRIP_WIDTH:]) > 0.8
        click("expand panel")
        out = frame()
        assert not st.panel_collapsed and st.panel_rect == (IW, 0.0, PANEL_WIDTH, H)
        assert np.array_equal(out[:, :IW], img[..., :3])
        assert list(tmp_path.iterdir()) == []
    finally:
        ui.shutdown()
        blit.release()
        fbo.release()
        ctx.release()


@pytest.mark.skipif(shutil.which("Xvfb") is None or shutil.which("xdotool") is None,
                    reason="needs Xvfb and xdotool (apt-get install xvfb xauth xdotool)")
def test_viewer_window_under_xvfb(tmp_path):
    from gridrt.grid.registry import names

    from gridrt.app.viewer.state import PANEL_WIDTH

    x = _X()
    app = None
    try:
        app = _App(x.display, tmp_path)
        s = app.wait(lambda s: s["rendered_frames"] >= 3 and s["camera"], "the first frames", timeout=120)
        home = s["camera"]
        # the window: the image at --size, the panel's column beside it
        assert s["render_size"] == [W, H] and s["window_size"] == [W + PANEL_WIDTH, H]
        assert s["image_rect"] == [0, 0, W, H] and s["panel_rect"] == [W, 0, PANEL_WIDTH, H]
        assert s["playing"] and s["scene_name"] == "marbles" and s["triangles"] == 2000
        # frames keep coming and the clock runs
        s2 = app.wait(lambda q: q["rendered_frames"] >= s["rendered_frames"] + 3 and q["time"] != s["time"],
                      "more frames")
        assert s2["ui_frames"] > s["ui_frames"]

        wid = app.xdo("search", "--sync", "--name", "^gridrt$").split()[0]
        app.xdo("windowfocus", "--sync", wid)

        # a real click on a panel widget: shadows on; the click does not move the camera
        assert s2["shadows"] is False
        app.click(s2, "shadows", 0.05)
        s3 = app.wait(lambda q: q["shadows"], "shadows on")
        assert s3["camera"] == home

        # keys: next strategy (the viewer's list: auto, then each strategy), one thread fewer (or
        # more); the pipeline reports using them
        from gridrt.config import AUTO_STRATEGY

        strategies = [AUTO_STRATEGY, *names()]
        want_strategy = strategies[(strategies.index(s3["strategy"]) + 1) % len(strategies)]
        want_threads = s3["threads"] - 1 if s3["threads"] > 1 else s3["threads"] + 1
        app.xdo("key", "bracketright")
        app.xdo("key", "minus" if want_threads < s3["threads"] else "equal")
        app.wait(lambda q: q["strategy"] == want_strategy and q["threads"] == want_threads
                 and q["stats"].get("strategy") == want_strategy and q["stats"].get("threads") == want_threads,
                 f"strategy {want_strategy} with {want_threads} threads", timeout=120)  # may compile

        # left drag on the image orbits (same target and distance, new eye)
        app.xdo("mousemove", 480, 300, "sleep", 0.2, "mousedown", 1, "sleep", 0.2, "mousemove", 540, 280,
                "sleep", 0.2, "mouseup", 1)
        s4 = app.wait(lambda q: q["camera"]["eye"] != home["eye"], "orbit")
        assert s4["camera"]["target"] == home["target"]
        assert _dist(s4["camera"]) == pytest.approx(_dist(home), rel=1e-9)
        # wheel over the image zooms in; over the panel it goes to the panel
        d0 = _dist(s4["camera"])
        app.xdo("mousemove", 500, 240, "sleep", 0.2, "click", 4)
        s5 = app.wait(lambda q: _dist(q["camera"]) < d0 * 0.999, "zoom")
        from gridrt.app.viewer.input import ZOOM_STEP

        assert _dist(s5["camera"]) == pytest.approx(d0 * ZOOM_STEP, rel=1e-9)
        px, py, pw, ph = s5["panel_rect"]
        app.xdo("mousemove", int(px + pw / 2), int(py + ph - 20), "sleep", 0.2, "click", 5, "sleep", 0.3)
        assert _dist(app.state()["camera"]) == pytest.approx(_dist(s5["camera"]), rel=1e-12)
        # right drag pans: eye and target move together
        c0 = s5["camera"]
        app.xdo("mousemove", 480, 300, "sleep", 0.2, "mousedown", 3, "sleep", 0.2, "mousemove", 520, 330,
                "sleep", 0.2, "mouseup", 3)
        s_pan = app.wait(lambda q: q["camera"]["target"] != c0["target"], "pan")
        np.testing.assert_allclose(np.subtract(s_pan["camera"]["eye"], s_pan["camera"]["target"]),
                                   np.subtract(c0["eye"], c0["target"]), rtol=1e-9, atol=1e-9)
        # holding W flies forward along the view direction
        c1 = s_pan["camera"]
        app.xdo("keydown", "w", "sleep", 0.4, "keyup", "w")
        s_fly = app.wait(lambda q: q["camera"]["eye"] != c1["eye"], "fly")
        move = np.subtract(s_fly["camera"]["eye"], c1["eye"])
        view = np.subtract(c1["target"], c1["eye"])
        assert move @ view / (np.linalg.norm(move) * np.linalg.norm(view)) > 0.999999
        np.testing.assert_allclose(np.subtract(s_fly["camera"]["target"], c1["target"]), move, atol=1e-9)
        # R resets the view
        app.xdo("mousemove", 500, 240, "key", "r")
        app.wait(lambda q: q["camera"] == home, "view reset")

        # space pauses: the clock stops and frames stop changing
        app.xdo("key", "space")
        app.wait(lambda q: not q["playing"], "pause")
        sp = app.settled("paused frames")
        time.sleep(0.3)
        assert app.state()["time"] == sp["time"]

        # P saves the ray-traced image
        app.xdo("key", "p")
        s6 = app.wait(lambda q: q["last_screenshot"], "screenshot")
        shot_path = Path(s6["last_screenshot"])
        assert shot_path.parent == app.shots and shot_path.is_file()
        shot = np.asarray(Image.open(shot_path).convert("RGB"))
        assert shot.shape == (H, W, 3)
        _check_scene_image(shot)
        assert s6["rendered_frames"] == sp["rendered_frames"]

        # the same frame from a headless FramePipeline (same time, camera, parameters) is identical
        from gridrt.pipeline import FramePipeline
        from gridrt.scene import make_scene

        assert s6["shadows"] and s6["grid"] == "uniform"
        pipe, ref = _headless_frame(make_scene("marbles", count=2000), s6, W, H)
        assert np.array_equal(shot, ref.image[..., :3])
        no_shadow = FramePipeline(make_scene("marbles", count=2000), pipe.grid_params,
                                  pipe.render_params.replace(shadows=False))
        assert not np.array_equal(shot, no_shadow.step(s6["stats"]["t"], camera=pipe.camera).image[..., :3])

        # a click on "Save window": the window as shown: the image, then the panel's column beside it
        # (the panel scrolls to it in 480 pixels, below the message with the screenshot's path)
        app.click(app.scroll_to(_laid_out(app, s6), "save window"), "save window", hold=0.2)
        s7 = app.wait(lambda q: q["last_window_shot"], "window screenshot")
        win = np.asarray(Image.open(s7["last_window_shot"]).convert("RGB"))
        assert win.shape == (H, W + PANEL_WIDTH, 3)
        assert np.array_equal(win[:, :W], shot)
        assert _panel_bg_fraction(win[:, W:]) > 0.3, _panel_bg_fraction(win[:, W:])
        # and what the X server really shows agrees (when imagemagick's `import` is installed)
        if shutil.which("import"):
            root = tmp_path / "root.png"
            subprocess.run(["import", "-window", "root", str(root)], env=_app_env(DISPLAY=x.display), check=True,
                           timeout=30)
            scr = np.asarray(Image.open(root).convert("RGB"))[:H, :W + PANEL_WIDTH]
            assert np.array_equal(scr[:, :W], shot)
            assert _panel_bg_fraction(scr[:, W:]) > 0.3

        # the panel's file box: a missing file reports an error and the viewer carries on; a real
        # file typed in and opened with the "Open file" button replaces the scene
        tet = tmp_path / "tet.obj"
        tet.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n")
        s7 = app.scroll_to(_laid_out(app, s7), "mesh file")
        app.click(s7, "mesh file")
        typed = str(tmp_path / "missing_phr.obj")   # p, h, r typed into the text box are not shortcuts
        app.xdo("type", "--delay", 5, typed)
        app.xdo("key", "Return")
        s_err = app.wait(lambda q: q["scene_error"], "load error")
        assert "missing_phr.obj" in s_err["scene_error"] and s_err["scene_name"] == "marbles"
        assert s_err["show_panel"] and s_err["last_screenshot"] == str(shot_path) and s_err["camera"] == s7["camera"]
        app.click(s_err, "mesh file")
        app.xdo("sleep", 0.2, "keydown", "ctrl", "sleep", 0.1, "key", "a", "sleep", 0.1, "keyup", "ctrl", "sleep", 0.1,
                "key", "BackSpace")
        app.xdo("type", "--delay", 5, str(tet))
        app.click(app.state(), "open file")
        s_tet = app.wait(lambda q: q["triangles"] == 4 and q["stats"].get("triangles") == 4, "tetrahedron loaded")
        assert s_tet["scene_error"] == "" and s_tet["camera"] != s7["camera"]   # reframed
        app.xdo("mousemove", 500, 300, "sleep", 0.1, "key", "F12")
        s_tet = app.wait(lambda q: q["last_screenshot"] != str(shot_path), "second screenshot (F12)")
        assert Path(s_tet["last_screenshot"]) == app.shots / "gridrt_0001.png"   # never overwrites
        from gridrt.trace.render import BACKGROUND

        tet_img = np.asarray(Image.open(s_tet["last_screenshot"]).convert("RGB"))
        fg = np.any(tet_img != np.round(np.asarray(BACKGROUND) * 255).astype(np.uint8), axis=-1)
        assert 0.01 < fg.mean() < 0.9   # the reframed tetrahedron fills part of the view

        # resizing the window: the render resolution follows the image area, the window less the
        # panel's column (even while paused); in 420 pixels the panel scrolls (by the wheel) to show
        # the resolution slider
        app.xdo("windowsize", wid, 760, 420)
        iw = 760 - PANEL_WIDTH
        s8 = app.wait(lambda q: q["framebuffer_size"] == [760, 420] and q["stats"].get("width") == iw
                      and q["stats"].get("height") == 420, "resize")
        assert s8["render_size"] == [iw, 420] and s8["image_rect"] == [0, 0, iw, 420]
        assert s8["panel_rect"] == [iw, 0, PANEL_WIDTH, 420]
        # the resolution slider at its left end: render at SCALE_MIN of the image area
        from gridrt.app.viewer.state import SCALE_MIN

        s8 = app.scroll_to(s8, "resolution")
        app.click(s8, "resolution", 0.0)
        want = [round(iw * SCALE_MIN), round(420 * SCALE_MIN)]
        s9 = app.wait(lambda q: q["render_size"] == want and [q["stats"].get("width"), q["stats"].get("height")] == want,
                      "render scale")
        assert s9["framebuffer_size"] == [760, 420] and s9["scale"] == pytest.approx(SCALE_MIN)

        # the panel's grid kind: a click opens the combo's list, a click on an item picks it; the
        # pipeline builds a two-level grid, and the leaf density slider at its right end refines its
        # leaves; the frame is the one a headless FramePipeline renders with those settings
        assert s9["grid"] == "uniform" and s9["stats"]["grid"] == "uniform" and "leaf density" not in s9["widget_rects"]
        app.pick("grid", "two_level")
        s10 = app.wait(lambda q: q["grid"] == "two_level" and q["stats"].get("grid") == "two_level"
                       and "leaf density" in q["widget_rects"], "a two-level grid", timeout=120)  # may compile
        assert s10["stats"]["leaf_density"] == s10["leaf_density"] and s10["stats"]["top_density"] == s10["top_density"]
        app.click(s10, "leaf density", 1.0)
        from gridrt.app.viewer.ui import LEAF_DENSITY_RANGE

        s11 = app.wait(lambda q: q["stats"].get("leaf_density") == q["leaf_density"] != s10["leaf_density"],
                       "leaf density")
        assert s11["leaf_density"] == pytest.approx(LEAF_DENSITY_RANGE[1], rel=1e-3)
        assert s11["stats"]["cells"] > s10["stats"]["cells"] and s11["stats"]["grid"] == "two_level"
        assert s11["stats"]["bytes_per_tri"] == pytest.approx(s11["stats"]["grid_bytes"] / 4)
        app.xdo("mousemove", 300, 300, "sleep", 0.1, "key", "p")
        s12 = app.wait(lambda q: q["last_screenshot"] != s_tet["last_screenshot"], "two-level screenshot")
        _, ref = _headless_frame(make_scene(str(tet)), s12, *want)
        assert ref.stats["grid"] == "two_level" and ref.stats["cells"] == s12["stats"]["cells"]
        assert np.array_equal(np.asarray(Image.open(s12["last_screenshot"]).convert("RGB")), ref.image[..., :3])

        # H hides the panel: the image takes the whole window; Esc quits with status 0
        app.xdo("key", "h")
        app.wait(lambda q: not q["show_panel"] and not q["widget_rects"] and q["image_rect"] == [0, 0, 760, 420]
                 and q["render_size"] == [round(760 * SCALE_MIN), want[1]], "panel hidden")
        app.xdo("key", "Escape")
        assert app.proc.wait(30) == 0, app.output()
        out = app.output()
        assert f"saved screenshot {shot_path}" in out
        assert list(app.cwd.iterdir()) == []   # nothing written where the viewer was started
    finally:
        if app is not None:
            app.close()
        x.close()


@pytest.mark.slow  # (a window of its own under Xvfb; the quick run keeps the main window test)
@needs_x
def test_viewer_side_panel_under_xvfb(tmp_path, xvfb):
    """At the window size the viewer opens with, the panel hides nothing of the image: the window
    is --size plus the panel's column; a window shot (the panel's "Save window") holds the frame the
    P key saves, pixel for pixel, in the --size area at its left, and the panel's column at its
    right.  H hides the panel: the image then fills the window (rendered at the window's size, with
    the window's aspect: the headless pipeline's frame at that size), and H shows it again."""
    from gridrt.app.viewer.state import PANEL_WIDTH
    from gridrt.scene import make_scene

    app = xvfb.start(_App(xvfb.display, tmp_path, extra=("--paused",)))
    s = _first_frame(app, W, H)
    assert s["window_size"] == s["framebuffer_size"] == [W + PANEL_WIDTH, H]
    assert s["image_rect"] == [0, 0, W, H] and s["render_size"] == [W, H]
    assert s["panel_rect"] == [W, 0, PANEL_WIDTH, H] and s["show_panel"] and not s["panel_collapsed"]
    for name in ("collapse panel", "built-in", "play", "strategy", "shading", "save window"):
        rx, _, rw, _ = s["widget_rects"][name]
        assert W <= rx and rx + rw <= W + PANEL_WIDTH, name   # in the panel's column, right of the image
    wid = app.xdo("search", "--sync", "--name", "^gridrt$").split()[0]
    app.xdo("windowfocus", "--sync", wid)

    app.xdo("mousemove", W // 2, H // 2, "sleep", 0.1, "key", "p")
    s1 = app.wait(lambda q: q["last_screenshot"], "screenshot (P)")
    shot = _png(s1["last_screenshot"])
    assert shot.shape == (H, W, 3)
    _check_scene_image(shot)
    app.click(app.scroll_to(_laid_out(app, s1), "save window"), "save window", hold=0.2)   # (scrolls in 480 px)
    s2 = app.wait(lambda q: q["last_window_shot"], "window screenshot")
    win = _png(s2["last_window_shot"])
    assert win.shape == (H, W + PANEL_WIDTH, 3)
    assert np.array_equal(win[:, :W], shot)   # the whole image, no panel pixel over it
    assert _panel_bg_fraction(win[:, W:]) > 0.3   # the panel beside it

    app.xdo("key", "h")
    s3 = app.wait(lambda q: not q["show_panel"] and q["stats"].get("width") == W + PANEL_WIDTH
                  and q["stats"].get("height") == H, "the image over the whole window")
    assert s3["image_rect"] == [0, 0, W + PANEL_WIDTH, H] and s3["render_size"] == [W + PANEL_WIDTH, H]
    assert s3["window_size"] == [W + PANEL_WIDTH, H] and not s3["widget_rects"]
    app.xdo("key", "p")
    s4 = app.wait(lambda q: q["last_screenshot"] != s1["last_screenshot"], "screenshot without the panel")
    full = _png(s4["last_screenshot"])
    _, ref = _headless_frame(make_scene("marbles", count=2000), s4, W + PANEL_WIDTH, H)
    assert np.array_equal(full, ref.image[..., :3])
    if shutil.which("import"):   # what the X server shows: the image over the whole window
        root = tmp_path / "root.png"
        subprocess.run(["import", "-window", "root", str(root)], env=_app_env(DISPLAY=xvfb.display), check=True,
                       timeout=30)
        assert np.array_equal(_png(root)[:H, :W + PANEL_WIDTH], full)
    app.xdo("key", "h")
    s5 = app.wait(lambda q: q["show_panel"] and q["stats"].get("width") == W and q["widget_rects"], "the panel back")
    assert s5["image_rect"] == [0, 0, W, H] and s5["panel_rect"] == [W, 0, PANEL_WIDTH, H]
    _quit(app)


@pytest.mark.slow  # (a window of its own under Xvfb; the quick run keeps the main window test)
@needs_x
def test_viewer_panel_remembered_under_xvfb(tmp_path, xvfb, config_home):
    """The panel's arrow collapses it to a strip (the image takes the rest of the window); the next
    run starts collapsed, its window --size plus the strip; there the strip's arrow opens the panel
    and H hides it, and the run after starts hidden (saying so), its window --size.  The choice
    lies in GRIDRT_CONFIG_HOME/viewer.json."""
    from gridrt.app.viewer.state import PANEL_STRIP_WIDTH, PANEL_WIDTH

    prefs = config_home / "viewer.json"

    def run(n):
        (tmp_path / n).mkdir()
        app = xvfb.start(_App(xvfb.display, tmp_path / n, extra=("--paused",)))
        return app, _first_frame(app, W, H)

    app, s = run("1")
    assert not s["panel_collapsed"] and not prefs.exists()
    app.click(s, "collapse panel", hold=0.2)
    wide = W + PANEL_WIDTH - PANEL_STRIP_WIDTH   # the image area beside the strip
    s = app.wait(lambda q: q["panel_collapsed"] and q["stats"].get("width") == wide, "the panel collapsed")
    assert s["image_rect"] == [0, 0, wide, H] and s["panel_rect"] == [wide, 0, PANEL_STRIP_WIDTH, H]
    assert list(s["widget_rects"]) == ["expand panel"]
    assert json.loads(prefs.read_text()) == {"show_panel": True, "panel_collapsed": True}
    _quit(app)

    app, s = run("2")
    assert s["panel_collapsed"] and s["show_panel"] and s["window_size"] == [W + PANEL_STRIP_WIDTH, H]
    assert s["image_rect"] == [0, 0, W, H] and s["panel_rect"] == [W, 0, PANEL_STRIP_WIDTH, H]
    app.click(s, "expand panel", hold=0.2)
    s = app.wait(lambda q: not q["panel_collapsed"] and "collapse panel" in q["widget_rects"], "the panel open")
    assert s["image_rect"] == [0, 0, W + PANEL_STRIP_WIDTH - PANEL_WIDTH, H]
    assert json.loads(prefs.read_text()) == {"show_panel": True, "panel_collapsed": False}
    app.xdo("mousemove", 100, 100, "sleep", 0.1, "key", "h")
    app.wait(lambda q: not q["show_panel"], "the panel hidden")
    _quit(app)
    assert json.loads(prefs.read_text()) == {"show_panel": False, "panel_collapsed": False}

    app, s = run("3")
    assert not s["show_panel"] and s["window_size"] == [W, H] and s["image_rect"] == [0, 0, W, H]
    assert f"the panel starts hidden, as last time (H shows it; remembered in {prefs})" in _quit(app)


@needs_x
def test_viewer_screenshot_default_folder_under_xvfb(tmp_path, xvfb):
    """Without --screenshot-dir, P saves into out/screenshots under the viewer's working directory
    (made on the first shot), prints the file's full path and shows it in the panel; nothing else
    lands in that folder."""
    cwd = tmp_path / "cwd"
    cwd.mkdir()
    app = xvfb.start(_Run(xvfb.display, tmp_path / "run", cwd,
                          ("--scene", "marbles", "--count", "2000", "--size", f"{W}x{H}", "--paused")))
    _first_frame(app, W, H)
    assert list(cwd.iterdir()) == []
    wid = app.xdo("search", "--sync", "--name", "^gridrt$").split()[0]
    app.xdo("windowfocus", "--sync", wid)
    app.xdo("mousemove", W // 2, H // 2, "sleep", 0.1, "key", "p")
    s = app.wait(lambda q: q["last_screenshot"], "screenshot (P)")
    saved = Path(s["last_screenshot"])
    assert saved.is_absolute() and saved.resolve() == (cwd / "out" / "screenshots" / "gridrt_0000.png").resolve()
    assert _png(saved).shape == (H, W, 3) and s["message"] == f"saved {saved}"
    assert f"gridrt view: saved screenshot {saved}\n" in _quit(app)
    assert sorted(str(p.relative_to(cwd)) for p in cwd.rglob("*")) == [
        "out", "out/screenshots", "out/screenshots/gridrt_0000.png"]


def _same_camera(cam_json, cam):
    """The state file's camera is ``cam`` (a gridrt Camera): every coordinate, up and fov."""
    got = [*cam_json["eye"], *cam_json["target"], *cam_json["up"], cam_json["fov"]]
    want = [*cam.eye, *cam.target, *cam.up, cam.fov]
    return np.allclose(got, want, rtol=1e-12, atol=1e-12)


@pytest.mark.skipif(shutil.which("Xvfb") is None or shutil.which("xdotool") is None,
                    reason="needs Xvfb and xdotool (apt-get install xvfb xauth xdotool)")
@pytest.mark.slow  # (a window of its own under Xvfb; the quick run keeps the main window test)
def test_viewer_scene_camera_under_xvfb(tmp_path):
    """The viewer on a BART scene (the museum): it starts looking through the scene's own camera
    (the state's camera is the scene's at the frame's time, computed here); the "scene camera" box
    turns it off where the view is, C turns it on again, a drag leaves it from the view on screen
    and R returns to it; the stats show the whole scene's references per triangle (both grids of
    the split scene, built here); the shading combo offers material; a textured glTF file opened
    from the panel reports its textures (the texture_progress callback's counts) and its camera."""
    import warnings

    from gridrt.scene import make_scene
    from gridrt.scene.surface import TextureWarning

    museum = REPO / "assets" / "museum" / "museum5.aff"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", TextureWarning)   # the museum's paintings are not in the repository
        scene = make_scene(str(museum))
    assert scene.camera_at(0.0) is not None and scene.n_static not in (0, scene.n_triangles)   # a split scene
    x = _X()
    app = None
    try:
        app = _App(x.display, tmp_path, scene=("--scene", str(museum)), extra=("--paused", "--scale", "0.5"))
        s = app.wait(lambda q: q["rendered_frames"] >= 1 and q["camera"] and q["stats"].get("t") is not None,
                     "the first museum frame", timeout=600)   # a cold cache compiles the material kernels
        assert s["scene_camera"] and s["follow_camera"] and s["scene_name"] == "museum5"
        assert _same_camera(s["camera"], scene.camera_at(s["stats"]["t"]))
        # "auto" shading resolves to the scene's materials when it has them, and the panel says so
        assert s["shading"] == "auto"
        assert s["stats"]["shading"] == ("material" if scene.surface is not None else "lambert")
        assert s["panel_text"]["shade"].endswith(f" ms  {s['stats']['shading']}")
        assert s["panel_text"]["lights"] == (f"lights {s['stats']['lights']}   "
                                             f"shadow rays {s['stats']['shadow_rays_per_pixel']:.2f}/px")

        # references per triangle: the whole scene's (static and moving grids), as the grids built
        # here with the viewer's settings have them
        pipe, _ = _headless_frame(scene, s, 16, 12)
        grids = [pipe.grid, pipe.static_grid]
        assert pipe.static_grid is not None
        for g in grids:
            if g.kind == "uniform":
                assert g.references == int(g.cell_start[:, -1].sum())
        whole = sum(g.references for g in grids) / sum(g.n_triangles for g in grids)
        assert sum(g.n_triangles for g in grids) == scene.n_triangles
        assert s["stats"]["refs_per_tri"] == pytest.approx(whole, rel=1e-12)
        assert f"({whole:.2f}/tri, moving {pipe.grid.references / pipe.grid.n_triangles:.2f})" \
            in s["panel_text"]["references"]

        wid = app.xdo("search", "--sync", "--name", "^gridrt$").split()[0]
        app.xdo("windowfocus", "--sync", wid)
        # playing: the scene's camera moves and the view follows it
        app.xdo("mousemove", 500, 300, "key", "space")
        s2 = app.wait(lambda q: q["playing"] and q["stats"]["t"] > s["stats"]["t"] + 0.05, "the camera moving",
                      timeout=60)
        assert _same_camera(s2["camera"], scene.camera_at(s2["stats"]["t"])) and s2["camera"] != s["camera"]
        # paused, the box off: the view stays where the scene's camera had it, also while playing on
        app.xdo("key", "space")
        sp = app.settled("paused")
        assert _same_camera(sp["camera"], scene.camera_at(sp["stats"]["t"]))
        app.click(sp, "scene camera", 0.05)
        s3 = app.wait(lambda q: not q["follow_camera"], "scene camera off")
        assert s3["camera"] == sp["camera"] and s3["scene_camera"]
        app.xdo("mousemove", 500, 300, "key", "space")
        s4 = app.wait(lambda q: q["stats"]["t"] > sp["stats"]["t"] + 0.05, "frames off the scene camera",
                      timeout=60)
        assert s4["camera"] == sp["camera"] and not _same_camera(s4["camera"], scene.camera_at(s4["stats"]["t"]))
        # C: back on the scene's camera
        app.xdo("key", "c")
        app.wait(lambda q: q["follow_camera"] and _same_camera(q["camera"], scene.camera_at(q["stats"]["t"]))
                      and q["camera"] != sp["camera"], "the scene's camera again")
        # paused, a left drag on the image leaves the scene's camera: it orbits the view on screen
        app.xdo("key", "space")
        sp2 = app.settled("paused again")
        assert sp2["follow_camera"] and not sp2["playing"]
        app.xdo("mousemove", 480, 300, "sleep", 0.2, "mousedown", 1, "sleep", 0.2, "mousemove", 520, 290,
                "sleep", 0.2, "mouseup", 1)
        s6 = app.wait(lambda q: not q["follow_camera"] and q["camera"]["eye"] != sp2["camera"]["eye"], "orbit")
        assert s6["camera"]["target"] == sp2["camera"]["target"]
        assert _dist(s6["camera"]) == pytest.approx(_dist(sp2["camera"]), rel=1e-9)
        # R: back to the scene's camera (the scene started on it)
        app.xdo("key", "r")
        app.wait(lambda q: q["follow_camera"] and q["camera"] == sp2["camera"], "view reset to the scene camera")

        # the shading combo offers material (and the other modes); picking one renders with it
        app.pick("shading", "normal")
        app.wait(lambda q: q["stats"].get("shading") == "normal", "normal shading")
        app.pick("shading", "material")
        s8 = app.wait(lambda q: q["stats"].get("shading") == "material" and q["shading"] == "material",
                      "material shading", timeout=120)

        # a textured glTF file, opened from the panel: its textures are counted while it loads
        # (texture_progress), and it starts on its own (animated) camera
        path, sizes = _textured_gltf(tmp_path)
        app.click(s8, "mesh file")
        app.xdo("sleep", 0.2, "keydown", "ctrl", "sleep", 0.1, "key", "a", "sleep", 0.1, "keyup", "ctrl", "sleep", 0.1,
                "key", "BackSpace")
        app.xdo("type", "--delay", 5, str(path))
        app.xdo("key", "Return")
        s9 = app.wait(lambda q: q["triangles"] == 4 and q["stats"].get("triangles") == 4, "the glTF file loaded",
                      timeout=120)
        assert s9["textures"]["count"] == 2 and s9["textures"]["bytes"] == sum(sizes)
        assert s9["textures"]["last"].endswith("tex1.png")
        assert s9["scene_camera"] and s9["follow_camera"]
        quads = make_scene(str(path))
        assert _same_camera(s9["camera"], quads.camera_at(s9["stats"]["t"]))
        assert s9["camera"]["fov"] != pytest.approx(DEFAULT_FOV)   # the file's camera has its own fov
        # a mesh without a camera, opened next, is framed with the command line's fov and up (their
        # defaults here), not with those of the camera looked through before
        app.click(s9, "mesh file")
        app.xdo("sleep", 0.2, "keydown", "ctrl", "sleep", 0.1, "key", "a", "sleep", 0.1, "keyup", "ctrl", "sleep", 0.1,
                "key", "BackSpace")
        app.xdo("type", "--delay", 5, str(REPO / "assets" / "teapot.obj"))
        app.xdo("key", "Return")
        s10 = app.wait(lambda q: q["triangles"] not in (0, 4) and q["stats"].get("triangles") == q["triangles"]
                       and q["camera"], "the teapot loaded", timeout=120)
        assert not s10["scene_camera"]
        assert s10["camera"]["fov"] == DEFAULT_FOV and tuple(s10["camera"]["up"]) == DEFAULT_UP
        app.xdo("mousemove", 500, 300, "key", "Escape")
        assert app.proc.wait(30) == 0, app.output()
        out = app.output()
        assert f"({sum(sizes) / 2**20:.2f} MiB)" in out and "2 textures" in out
        assert "looking through its camera" in out
    finally:
        if app is not None:
            app.close()
        x.close()
