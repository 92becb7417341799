"""``gridrt view``: the interactive viewer.

A glfw window with an OpenGL 3.3 core context, split into the image area and the imgui-bundle
panel's column at the right edge (ViewerState.layout; ui.py): moderngl shows the ray-traced image
in the image area only (blit.py, shaders from shaders/), the render resolution and the camera's
aspect follow that area, and the mouse moves the camera there.  The window opens at --size plus
the panel's column, so the image starts at the size asked for; H hides the panel (the image takes
the whole window), its arrow collapses it to a strip, and both are remembered across runs
(prefs.py).  The FramePipeline runs on a worker thread (worker.py), so the window keeps answering
while a scene loads, the numba kernels compile or a heavy frame renders, and shows what it is
waiting for.

Screenshots (P, F12, the panel's buttons) go to --screenshot-dir, out/screenshots under the
working directory by default, made on the first shot; each saved path is printed in full.  Nothing
else is written to the working directory; imgui.ini is disabled.
"""

import argparse
import json
import math
import os
import shlex
import sys
import time
from pathlib import Path

import numpy as np

from gridrt.camera import pixel_dir
from gridrt.commands import gridrt_command
from gridrt.errors import InputError
from gridrt.frame import ViewSpec
from gridrt.config import AUTO_STRATEGY
from gridrt.grid.registry import names
from gridrt.pipeline import FramePipeline
from gridrt.scene import BUILTIN_SCENES, scene_choices
from gridrt.threads import check_threads, max_threads
from gridrt.warmup import cache_is_cold

from .. import cli, dump, exit_now
from ..frame_out import frame_medians, write_stats_csv
from .accumulate import MAX_SAMPLES, Accumulator
from .blit import Blitter, exposed
from .bookmarks import camera_flags, load_bookmarks, save_bookmark
from .input import KEY_HELP, InputHandler
from .prefs import load_prefs, panel_prefs, prefs_path, save_prefs
from .record import Recorder
from .state import EXPOSURE_LIMIT, SCALE_MAX, SCALE_MIN, ViewerState, view_with_camera
from .worker import FrameJob, LoadJob, LoadResult, RenderWorker

TITLE = "gridrt"
#: UI frame cap (frames per second) when the display has no vsync (Xvfb)
UI_FPS_CAP = 60.0
#: after this many seconds without input (and no progress overlay), the loop sleeps until an input
#: event or a worker result wakes it
IDLE_AFTER_S = 0.5
#: longest sleep of an idle loop (seconds): the state file and fps readouts still refresh
IDLE_WAIT_S = 0.25
#: longest sleep of the loop while the worker is busy and nobody gives input (seconds)
BUSY_WAIT_S = 0.1
#: a frame job shows the progress overlay once it has run this long (seconds)
SLOW_FRAME_S = 1.5
#: a scene load shows the overlay once it has run this long (seconds)
SLOW_LOAD_S = 0.15
#: a slow texture load prints a progress line to stderr at most this often (seconds)
PROGRESS_PRINT_S = 1.0
#: how long the viewer waits at exit for the render thread to finish its frame
STOP_WAIT_S = 1.5
#: where screenshots go without --screenshot-dir (relative to the working directory)
DEFAULT_SHOT_DIR = Path("out") / "screenshots"


def add_parser(sub):
    p = sub.add_parser("view", help="open the interactive viewer (needs a display)",
                       description="Interactive viewer: a window with the ray-traced animation and a control "
                                   "panel in a column beside it.  --size is the image's initial size (the "
                                   "window adds the panel's column); the render resolution follows the image "
                                   "area (times --scale).  Whether the panel is hidden or collapsed is "
                                   "remembered in $XDG_CONFIG_HOME/gridrt/viewer.json (~/.config/gridrt/"
                                   "viewer.json; GRIDRT_CONFIG_HOME names another folder).  Without a display, "
                                   "use `gridrt dump`.",
                       epilog="keys: " + KEY_HELP)
    cli.add_scene_args(p)
    cli.add_grid_args(p)
    cli.add_render_args(p)
    g = p.add_argument_group("viewer")
    g.add_argument("--scale", type=float, default=1.0,
                   help="render resolution as a fraction of the image area (0.1..2; default 1)")
    g.add_argument("--paused", action="store_true", help="start with the animation paused")
    g.add_argument("--hide-panel", action="store_true",
                   help="start with the panel hidden, the image filling the window (H toggles)")
    g.add_argument("--screenshot-dir", type=Path, default=DEFAULT_SHOT_DIR,
                   help="folder for P/F12 screenshots, made on the first shot; each saved path is printed "
                        "(default: %(default)s under the current directory)")
    g.add_argument("--exposure", type=float, default=0.0,
                   help=f"display exposure in stops, -{EXPOSURE_LIMIT:g}..{EXPOSURE_LIMIT:g} (the , . and / keys change it; "
                        "default 0: the image as rendered)")
    g.add_argument("--overlay", action="store_true",
                   help="start with the figures (fps, Mrays/s, build/render/frame ms: the dump's stats columns) over "
                        "the image's top-left corner (O toggles; off by default, so nothing covers the image)")
    g.add_argument("--accumulate", action="store_true",
                   help=f"start with progressive accumulation on (G toggles): while nothing moves, up to "
                        f"{MAX_SAMPLES} samples with sub-pixel offsets are averaged, starting from the exact frame")
    g.add_argument("--benchmark", type=int, nargs=2, metavar=("WARMUP", "FRAMES"), default=None,
                   help="render WARMUP + FRAMES frames at the dump's times (--t0 + i --dt), each shown, print the "
                        "medians of the last FRAMES (frames that compiled kernels left out) and exit (default: none, "
                        "the viewer runs until Esc)")
    g.add_argument("--no-helper", dest="helper", action="store_false", help=cli.option_help("--no-helper"))
    g.add_argument("--stats-csv", type=Path, default=None,
                   help="with --benchmark: write every frame's stats row there, the columns of the dump's stats.csv "
                        "(default: none)")
    view = cli.defaults(ViewSpec)
    g.add_argument("--t0", type=float, default=view["t0"], help="time of the first frame, seconds (default %(default)g)")
    g.add_argument("--dt", type=float, default=view["dt"], help=cli.option_help("--dt", f"{view['dt']:.6g}"))
    g.add_argument("--state-file", type=Path, default=None,
                   help="write the viewer state as JSON to this file several times a second "
                        "(frame counters, parameters, screenshot paths, widget positions; for scripts/tests; default: none)")
    p.set_defaults(func=run)
    return p


def headless_command(a=None):
    """The headless dump to run instead, as a command that works as printed (named the way this
    process was started: ``.venv/bin/gridrt`` after the README's set-up; see gridrt.commands),
    with the options of the parsed view arguments ``a`` that the dump shares and that differ from
    their defaults (the user's scene, camera, grid and render settings), 60 frames into
    out/SCENE."""
    words = ["dump"]
    scene = "marbles"
    if a is not None:
        parser = dump.add_parser(argparse.ArgumentParser().add_subparsers())
        for act in parser._actions:
            if not act.option_strings or act.dest in ("help",) or not hasattr(a, act.dest):
                continue
            v = getattr(a, act.dest)
            if v == act.default:
                continue
            words += _option_words(act, v)
        scene = str(a.scene)
    if "--scene" not in words:
        words[1:1] = ["--scene", scene]
    name = Path(scene).stem or "frames"
    words += ["--frames", "60", "--out", f"out/{name}"]
    return f"{gridrt_command()} {shlex.join(words)}"


def _option_words(act, v):
    """The command-line words that give the option of argparse action ``act`` the value ``v``."""
    opt = act.option_strings[-1] if act.option_strings[-1].startswith("--") else act.option_strings[0]
    if isinstance(act, (argparse._StoreTrueAction, argparse._StoreFalseAction)):
        return [opt]
    if isinstance(v, tuple) and act.dest == "size":
        text = f"{v[0]}x{v[1]}"
    elif isinstance(v, tuple):
        text = ",".join(f"{x:g}" for x in v)
    else:
        text = str(v)
    return [f"{opt}={text}"] if text.startswith("-") else [opt, text]


def no_display_message(a=None):
    return ("gridrt view: no display found (DISPLAY and WAYLAND_DISPLAY are unset); render headless instead: "
            + headless_command(a))


def window_failed_message(why, a=None):
    return f"gridrt view: cannot open an OpenGL 3.3 window ({why}); render headless instead: " + headless_command(a)


def run(a):
    if not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        print(no_display_message(a), file=sys.stderr)
        return 3
    if not (SCALE_MIN <= a.scale <= SCALE_MAX):
        raise InputError(f"--scale must be between {SCALE_MIN} and {SCALE_MAX}, got {a.scale}")
    if not (math.isfinite(a.exposure) and abs(a.exposure) <= EXPOSURE_LIMIT):
        raise InputError(f"--exposure must be between -{EXPOSURE_LIMIT:g} and {EXPOSURE_LIMIT:g} stops, got {a.exposure}")
    if a.benchmark is not None and (a.benchmark[0] < 0 or a.benchmark[1] < 1):
        raise InputError(f"--benchmark needs WARMUP >= 0 and FRAMES >= 1, got {a.benchmark[0]} {a.benchmark[1]}")
    if a.stats_csv is not None and a.benchmark is None:
        raise InputError("--stats-csv goes with --benchmark WARMUP FRAMES")
    if str(a.scene).strip().lower() not in BUILTIN_SCENES and not Path(a.scene).exists():
        raise InputError(f"unknown scene {str(a.scene)!r}: not a built-in scene and not an existing file or folder; "
                         f"a scene may be {scene_choices()}")
    state = initial_state(a)
    viewer = Viewer(a, state)
    return viewer.run()


def start_on_scene_camera(a):
    """Whether the command line's scene starts on its own camera (when it has one): by default,
    unless --no-scene-camera, or an explicit --eye/--target without --follow-camera (as the dump:
    gridrt.app.cli.follows_scene_camera)."""
    return cli.follows_scene_camera(a)


def initial_state(a):
    """A ViewerState from the parsed arguments (validating them the same way dump does)."""
    spec = cli.frame_spec(a)   # validates every setting, as the dump does
    w, h = spec.size
    source = spec.scene.source
    if source.strip().lower() in BUILTIN_SCENES:
        source = source.strip().lower()
    threads = check_threads(spec.grid.threads)
    st = ViewerState(
        spec=spec.replace(scene=spec.scene.replace(source=source), grid=spec.grid.replace(threads=threads),
                          render=spec.render.replace(threads=threads)),
        max_threads=max_threads(),
        playing=not a.paused,
        prefer_scene_camera=bool(getattr(a, "scene_camera", True)) or a.follow_camera,
    )
    st.scale = float(a.scale)
    st.exposure = float(a.exposure)
    st.time = float(spec.view.t0)
    st.accumulate = bool(a.accumulate)
    st.show_overlay = bool(a.overlay)
    st.home = st.camera
    shown, collapsed = panel_prefs(load_prefs())
    st.show_panel = shown and not a.hide_panel
    st.panel_collapsed = collapsed
    st.window_size = st.window_for_image(w, h)   # the image at --size, the panel's column beside it
    st.cold_cache = cache_is_cold(st.render.traversal)
    if source not in BUILTIN_SCENES:
        st.file_text = source
    return st


def draws_lights(rp):
    """Whether frames of the RenderParams ``rp`` may draw their lights (light_samples with shadows):
    their draws are averaged while the view is still, as with accumulation on (the frames of
    shading modes that have no such lights come back without Frame.hdr and are the same every draw)."""
    return bool(rp.light_samples) and bool(rp.shadows)


def frame_key(t, spec):
    """What decides the frame at time ``t`` of the FrameSpec ``spec``: both, but while the scene's
    own camera is followed, the view's camera (eye, target, up, fov) does not choose the frame (it
    is the last frame's, from the scene): a paused frame is not rendered again when it arrives."""
    view = spec.view
    if view.follow_camera:
        view = view_with_camera(view, None).replace(fov=ViewSpec.fov, up=ViewSpec.up)
    return t, spec.scene, spec.grid, spec.render, view


def _next_free(folder, stem):
    i = 0
    while True:
        p = folder / f"{stem}_{i:04d}.png"
        if not p.exists():
            return p
        i += 1


class Viewer:
    """Window, frame loop and lifecycle.  Resources are made in :meth:`run` and freed in its
    ``finally`` block."""

    def __init__(self, args, state):
        self.args = args
        self.state = state
        shot_dir = args.screenshot_dir if args.screenshot_dir is not None else DEFAULT_SHOT_DIR
        self.shot_dir = Path(os.path.abspath(os.path.expanduser(shot_dir)))   # printed in full
        self.state_file = Path(args.state_file) if args.state_file is not None else None
        self.image = None              # the frame on screen, (H, W, 4) uint8
        self.start_view = state.spec.view  # the command line's view (a new scene is framed with its fov and up)
        self.last_key = None           # frame_key of the last submitted frame
        self.generation = 0            # bumped by every scene load; older frame results are dropped
        self.glfw_error = ""
        self._last_state_write = 0.0
        self._last_result_time = None
        self._progress_printed = (0.0, 0)   # (perf_counter, textures) of the last console progress line
        self._panel_kept = (state.show_panel, state.panel_collapsed)   # as remembered (or as started)
        self.accum = Accumulator()
        self._accumulating = False     # st.accumulate as the last frame loop saw it
        self.depth = None              # the frame on screen's hit distances, (H, W) float32
        self.ray_camera = None         # the camera of its rays (jittered for a progressive sample)
        self.recorder = None           # the Recorder while K records
        self._windowed = None          # (position, size) of the window before full screen
        bench = getattr(args, "benchmark", None)
        self.bench = None if bench is None else {"warmup": int(bench[0]), "frames": int(bench[1]), "submitted": 0,
                                                 "rows": [], "started": None}

    # ---- lifecycle ------------------------------------------------------------------------
    def run(self):
        st = self.state
        # The scene loads on the render thread while the window opens, and on a warm cache the
        # kernels of its first frame load with it (LoadJob.warm); a cold cache compiles them with
        # the window up, showing the progress.  The first load's render size is the window's until
        # the window is there to say (a frame is rendered at the image area's size in any case).
        worker = self.worker = RenderWorker(self._make_pipeline)
        st.framebuffer_size = st.window_size
        self._start_load(st.scene, keep_camera=True, scene_camera=start_on_scene_camera(self.args),
                         warm=not st.cold_cache, helper=st.cold_cache and self.args.helper)
        # (imgui first: it points pyglfw at its libglfw)
        from imgui_bundle import imgui  # noqa: F401  # deferred: imgui_bundle loads only when a window opens
        import glfw  # deferred: glfw loads only when a window opens
        import moderngl  # deferred: moderngl loads only when a window opens

        from .ui import ImguiRuntime  # deferred: the panel's imgui_bundle, with the window

        glfw.set_error_callback(self._on_glfw_error)
        if not glfw.init():
            print(window_failed_message(self.glfw_error or "glfw could not initialise", self.args), file=sys.stderr)
            self._leave_without(worker)
            return 3
        win = ui = blitter = ctx = None
        code = 3   # (no window)
        try:
            for hint, value in ((glfw.CONTEXT_VERSION_MAJOR, 3), (glfw.CONTEXT_VERSION_MINOR, 3),
                                (glfw.OPENGL_PROFILE, glfw.OPENGL_CORE_PROFILE),
                                (glfw.OPENGL_FORWARD_COMPAT, True)):
                glfw.window_hint(hint, value)
            w, h = st.window_size
            win = glfw.create_window(int(w), int(h), TITLE, None, None)
            if not win:
                print(window_failed_message(self.glfw_error or "no OpenGL 3.3 core context", self.args), file=sys.stderr)
                return 3
            glfw.make_context_current(win)
            glfw.swap_interval(1)
            ctx = moderngl.create_context()
            self.glfw, self.win, self.ctx = glfw, win, ctx
            self.strategies = (AUTO_STRATEGY, *names())
            self.input = InputHandler(glfw, win, st, self.strategies)
            ui = ImguiRuntime(win)
            blitter = Blitter(ctx)
            worker.attach(glfw.post_empty_event)
            self.ui, self.blitter = ui, blitter
            st.window_size = tuple(glfw.get_window_size(win))   # (the loop keeps both up to date)
            st.framebuffer_size = tuple(glfw.get_framebuffer_size(win))
            if not st.show_panel and not self.args.hide_panel:
                print(f"gridrt view: the panel starts hidden, as last time (H shows it; remembered in "
                      f"{prefs_path()})", flush=True)
            self._loop()
            code = 0
            return code
        finally:
            if blitter is not None:
                blitter.release()
            if ui is not None:
                ui.shutdown()
            if ctx is not None:
                ctx.release()
            if win is not None:
                glfw.destroy_window(win)
            if self.recorder is not None:
                self._stop_recording()
            stopped = self._stop_worker(worker)
            glfw.terminate()
            self._write_state(force=True)
            if not stopped:   # a kernel compile is still running: do not wait for it at exit
                exit_now(code)

    def _leave_without(self, worker):
        """No window after all: stop the render thread, or leave at once without it (with the
        window's failure code) when it is still loading or compiling."""
        if not self._stop_worker(worker):
            exit_now(3)

    def _stop_worker(self, worker):
        """Stop the render thread (the window is already gone); True when it finished within
        STOP_WAIT_S.  Otherwise it is still rendering (or compiling the kernels of) a frame: the
        viewer says so in one line and leaves without it (run's os._exit), so that Esc never waits
        on it."""
        worker.detach()
        if worker.stop(timeout=STOP_WAIT_S):
            return True
        print("gridrt view: not waiting for the render thread (still rendering or compiling a frame); exiting "
              "without it", file=sys.stderr, flush=True)
        return False

    def _on_glfw_error(self, code, description):
        self.glfw_error = description.decode() if isinstance(description, bytes) else str(description)

    @staticmethod
    def _make_pipeline(scene, job):
        return FramePipeline.from_spec(job.spec, scene=scene)

    def _start_load(self, scene, keep_camera=False, scene_camera=None, warm=False, helper=False):
        """Load the SceneSpec ``scene`` on the worker, with the state's spec at the render size;
        ``scene_camera``: look through the scene's own camera once loaded, when it has one (None:
        the state's prefer_scene_camera).  Without ``keep_camera`` the scene is framed with the
        command line's fov and up (not with those of a camera looked through before).  ``warm``:
        load the first frame's kernels with the scene (LoadJob.warm); ``helper``: a cold cache, a
        helper process compiles the first frame's ray casting (LoadJob.helper)."""
        st = self.state
        self.generation += 1
        spec = st.spec.resized(*st.render_size_for(*self._image_viewport()[2:])).replace(scene=scene)
        if not keep_camera:
            start = self.start_view
            spec = spec.replace(view=spec.view.replace(eye=None, target=None, fov=start.fov, up=start.up))
        self.worker.submit(LoadJob(spec, keep_camera=keep_camera,
                                   scene_camera=st.prefer_scene_camera if scene_camera is None else scene_camera,
                                   label=f"loading {scene.label()}", warm=warm, helper=helper))
        self.last_key = None
        self._progress_printed = (0.0, 0)

    def _image_viewport(self):
        """The image area (ViewerState.layout of ``state.window_size``) in framebuffer pixels
        (``state.framebuffer_size``), as a GL viewport (x, y from the bottom, w, h); it also sets
        ``state.image_rect`` (window pixels)."""
        st = self.state
        ww, wh = (max(int(v), 1) for v in st.window_size)
        fw, fh = (max(int(v), 1) for v in st.framebuffer_size)
        (ix, iy, iw, ih), _ = st.layout(ww, wh)
        st.image_rect = (ix, iy, iw, ih)
        s = fh / wh   # framebuffer pixels per window pixel (HiDPI; the same both ways)
        x0, x1 = min(round(ix * s), fw - 1), min(round((ix + iw) * s), fw)
        y0, y1 = min(round(iy * s), fh - 1), min(round((iy + ih) * s), fh)
        return x0, fh - y1, max(x1 - x0, 1), max(y1 - y0, 1)

    # ---- frame loop -----------------------------------------------------------------------
    def _loop(self):
        glfw = self.glfw
        st = self.state
        from imgui_bundle import imgui  # deferred: imgui_bundle loads only when a window opens

        from .ui import draw_figures, draw_overlay, draw_panel  # deferred: the panel's imgui_bundle, with the window

        last = time.perf_counter()
        io = imgui.get_io()
        while not glfw.window_should_close(self.win) and not st.quit:
            if io.want_text_input or last - self.input.last_event < IDLE_AFTER_S:
                glfw.poll_events()
            elif st.busy:
                # the worker is loading, compiling or rendering: redraw a few times a second (the
                # progress display), not at the UI cap; a result or input wakes the loop at once, and
                # the cores stay with the work (on Xvfb every redraw is software OpenGL)
                glfw.wait_events_timeout(BUSY_WAIT_S)
            else:
                glfw.wait_events_timeout(IDLE_WAIT_S)   # woken by input or by a worker result
            now = time.perf_counter()
            dt, last = now - last, now
            if dt > 0:
                st.ui_fps = 1.0 / dt if st.ui_fps == 0 else 0.9 * st.ui_fps + 0.1 / dt
            self._collect_results(now)
            fw, fh = glfw.get_framebuffer_size(self.win)
            if fw == 0 or fh == 0:           # minimised
                time.sleep(0.05)
                continue
            st.framebuffer_size = (fw, fh)
            st.window_size = tuple(glfw.get_window_size(self.win))
            self._image_viewport()   # state.image_rect, where the mouse moves the camera

            self.ui.new_frame()
            self.input.process(io, dt)
            self._requests()
            if st.scene_request is not None:
                spec, st.scene_request = st.scene_request, None
                st.scene_error = ""
                self._start_load(spec)
            if self.bench is None:
                st.advance(dt)
            st.widget_rects = {}
            if st.show_panel:
                draw_panel(st, self.strategies)
            self._update_busy(now)
            job, elapsed = self.worker.current()
            draw_figures(st)
            draw_overlay(st, elapsed)
            self._remember_panel()
            viewport = self._image_viewport()   # this frame's (H or the panel's arrow may have changed it)

            self.ctx.screen.use()
            self.ctx.viewport = (0, 0, fw, fh)
            self.ctx.clear(0.12, 0.13, 0.16, 1.0)
            self.blitter.exposure = st.exposure
            self.blitter.draw(viewport)
            self.ctx.viewport = (0, 0, fw, fh)
            self.ui.render()
            if st.want_window_shot:
                st.want_window_shot = False
                self._save_window_shot(fw, fh)
            glfw.swap_buffers(self.win)
            if st.want_shot:
                st.want_shot = False
                self._save_shot()
            self._submit_frame()
            st.ui_frames += 1
            self._write_state()
            spare = 1.0 / UI_FPS_CAP - (time.perf_counter() - now)
            if spare > 0:
                time.sleep(spare)

    def _collect_results(self, now):
        st = self.state
        for res in self.worker.take():
            if isinstance(res, LoadResult):
                if res.error:
                    st.scene_error = f"cannot load {res.scene.source}: {res.error}"
                    print(f"gridrt view: {st.scene_error}", file=sys.stderr, flush=True)
                    if self.worker.pipeline is None:
                        st.message = "no scene loaded: pick a built-in scene or open a file"
                    continue
                st.scene = res.scene
                if not res.keep_camera:   # frame the new scene, with the fov and up it is framed with
                    st.spec = st.spec.replace(view=view_with_camera(st.spec.view, None).replace(
                        fov=res.job.spec.view.fov, up=res.job.spec.view.up))
                    st.home = None
                st.scene_loaded(res.has_camera, res.job.scene_camera)
                st.scene_name, st.triangles = res.scene_name, res.triangles
                st.bookmarks = load_bookmarks(res.scene.source)
                st.duration, st.static = res.duration, res.static
                st.time = 0.0 if res.duration is None else math.fmod(st.time, res.duration)
                st.history.clear()
                tex = res.textures
                st.textures = tex.as_dict() if tex is not None else None
                tex_text = "" if tex is None or not tex.count else (
                    f", {tex.count} texture{'s' if tex.count != 1 else ''} ({tex.nbytes / 2**20:.2f} MiB)")
                st.message = f"loaded {res.scene_name} in {res.seconds:.2f} s"
                print(f"gridrt view: loaded {res.scene_name} ({res.triangles} triangles{tex_text}) "
                      f"in {res.seconds:.2f} s" + ("; looking through its camera" if st.follow_camera else ""),
                      flush=True)
                self.last_key = None
            elif res.job.generation != self.generation:
                continue                 # rendered for the scene that was just replaced
            elif res.error:
                st.message = ""
                st.scene_error = f"frame failed: {res.error}"
                print(f"gridrt view: {st.scene_error}", file=sys.stderr, flush=True)
            else:
                shown = res.image
                if self.bench is None and (st.accumulate or res.job.jitter is not None or res.hdr is not None):
                    shown = self.accum.add(frame_key(res.job.t, res.job.spec), res.image, res.hdr)
                    st.samples = self.accum.count
                else:
                    self.accum.reset()
                    st.samples = 1
                self.image = shown
                self.depth, self.ray_camera = res.depth, res.ray_camera
                self.blitter.upload(shown)
                st.stats = res.stats
                st.overlay_text = st.figures_text()
                if self.recorder is not None:
                    self.recorder.add(exposed(shown, st.exposure)[..., :3], res.job.t, res.camera)
                if self.bench is not None:
                    self._bench_result(res)
                if res.job.spec.view.follow_camera and st.follow_camera and res.camera is not None:
                    st.camera = res.camera   # the scene's camera at the frame's time: the view on screen
                st.history.add(res.stats)
                st.rendered_frames += 1
                st.cold_cache = False
                st.scene_radius = res.radius
                if st.camera is None:
                    st.camera = res.camera
                    job = res.job
                    if self.last_key == frame_key(job.t, job.spec):   # the frame that framed the scene is on screen
                        self.last_key = frame_key(job.t, job.spec.replace(view=view_with_camera(job.spec.view,
                                                                                                res.camera)))
                if st.home is None:
                    st.home = res.camera
                if self._last_result_time is not None:
                    dt = now - self._last_result_time
                    if dt > 0:
                        st.render_fps = 1 / dt if st.render_fps == 0 else 0.8 * st.render_fps + 0.2 / dt
                self._last_result_time = now

    def _update_busy(self, now):
        st = self.state
        job, elapsed = self.worker.current()
        if job is None:
            st.busy = None
        elif isinstance(job, LoadJob):
            progress = self.worker.progress()
            line = progress.label() if progress is not None else ""
            st.busy = (job.label + ("\n" + line if line else "")) if elapsed >= SLOW_LOAD_S else None
            self._print_progress(now, elapsed, progress, line)
        elif st.cold_cache:
            st.busy = "compiling numba kernels (first run only; cached for later runs)"
        elif elapsed >= SLOW_FRAME_S:
            st.busy = "building the grid and rendering (a strategy's or grid kind's first use compiles its kernels)"
        else:
            st.busy = None

    def _print_progress(self, now, elapsed, progress, line):
        """A console line for a slow texture load (one running PROGRESS_PRINT_S or longer): at most
        one each PROGRESS_PRINT_S, while the count grows."""
        last_t, last_n = self._progress_printed
        if line and elapsed >= PROGRESS_PRINT_S and progress.count != last_n and now - last_t >= PROGRESS_PRINT_S:
            self._progress_printed = (now, progress.count)
            print(f"gridrt view: {line}", file=sys.stderr, flush=True)

    def _submit_frame(self):
        st = self.state
        if self.worker.busy or self.worker.pipeline is None:
            return
        rw, rh = st.render_size_for(*self._image_viewport()[2:])
        st.render_size = (rw, rh)
        if st.spec.size != (rw, rh):
            try:
                st.spec = st.spec.resized(rw, rh)   # the spec is what is on screen: at the render size
            except InputError as e:
                st.scene_error = str(e)
                return
        if self.bench is not None:
            b = self.bench
            i = b["submitted"]
            if i < b["warmup"] + b["frames"]:
                b["submitted"] += 1
                self.worker.submit(FrameJob(st.spec, st.spec.view.time(i), generation=self.generation))
            return
        key = frame_key(st.time, st.spec)
        if key == self.last_key:
            drawn = draws_lights(st.spec.render)
            jitter = self.accum.next_jitter(key) if (st.accumulate or drawn) and self.accum.count else None
            if jitter is not None:   # the view is still: the next progressive sample (a new draw of the lights)
                self.worker.submit(FrameJob(st.spec, st.time, generation=self.generation,
                                            jitter=jitter if st.accumulate else None,
                                            light_seed=self.accum.count if drawn else 0))
            return
        self.last_key = key
        self.worker.submit(FrameJob(st.spec, st.time, generation=self.generation))

    # ---- the habits of Embree's and pbrt's viewers --------------------------------------------
    def _requests(self):
        """Carry out what the keys asked for this frame (input.py sets the requests)."""
        st = self.state
        if st.want_camera_print:
            st.want_camera_print = False
            self._print_camera()
        if st.bookmark_store is not None:
            slot, st.bookmark_store = st.bookmark_store, None
            if st.camera is not None:
                st.bookmarks[slot] = st.camera
                kept = save_bookmark(st.scene.source, slot, st.camera)
                st.message = f"view kept as bookmark {slot}" + ("" if kept else " (for this run only: cannot write "
                                                                                f"{prefs_path()})")
                print(f"gridrt view: {st.message}", flush=True)
        if st.bookmark_recall is not None:
            slot, st.bookmark_recall = st.bookmark_recall, None
            cam = st.bookmarks.get(slot)
            if cam is None:
                st.message = f"no bookmark {slot} for this scene (Ctrl+{slot} keeps one)"
            else:
                st.leave_scene_camera()
                st.camera = cam
                st.message = f"bookmark {slot}"
        if st.focus_request is not None:
            at, st.focus_request = st.focus_request, None
            self._focus(*at)
        if st.want_fullscreen:
            st.want_fullscreen = False
            self._toggle_fullscreen()
        if st.accumulate != self._accumulating:
            self._accumulating = st.accumulate
            self.last_key = None   # render the exact frame again (or start sampling it)
            self.accum.reset()
        if st.want_record:
            st.want_record = False
            if self.recorder is None:
                self._start_recording()
            else:
                self._stop_recording()

    def _print_camera(self):
        st = self.state
        cam = st.camera
        if cam is None:
            st.message = "no camera yet"
            return
        st.camera_flags = camera_flags(cam)
        st.message = "camera printed to the console"
        print(f"gridrt view: camera at t={st.time:g}: {st.camera_flags}", flush=True)

    def _focus(self, x, y):
        """Look at the surface point under window pixel (x, y): the target (the orbit's centre)
        moves to the hit point of that pixel's ray in the frame on screen; the eye stays."""
        st = self.state
        if self.depth is None or self.ray_camera is None or st.camera is None or not st.in_image(x, y):
            return
        ix, iy, iw, ih = st.image_rect
        h, w = self.depth.shape
        px = min(max(int((x - ix) / max(iw, 1) * w), 0), w - 1)
        py = min(max(int((y - iy) / max(ih, 1) * h), 0), h - 1)
        t = float(self.depth[py, px])
        if not math.isfinite(t):
            st.message = "nothing under the cursor to focus on"
            return
        d = np.asarray(pixel_dir(self.ray_camera.basis(), w, h, px, py))   # the pixel's ray, as rendered
        point = np.asarray(self.ray_camera.eye) + t * d
        cam = st.camera
        st.leave_scene_camera()
        try:
            st.camera = cam.replace(target=tuple(point.tolist()))
        except InputError as e:   # (the point is the eye itself: a hit at distance 0)
            st.message = f"cannot focus there: {e}"
            return
        st.focus = tuple(point.tolist())
        st.message = "focus on " + ",".join(f"{v:.6g}" for v in point)
        print(f"gridrt view: {st.message} (pixel {px},{py} at distance {t:.6g})", flush=True)

    def _toggle_fullscreen(self):
        glfw, win, st = self.glfw, self.win, self.state
        if self._windowed is None:
            monitor = glfw.get_primary_monitor()
            mode = glfw.get_video_mode(monitor) if monitor else None
            if mode is None:
                st.message = "no monitor to go full screen on"
                return
            self._windowed = (tuple(glfw.get_window_pos(win)), tuple(glfw.get_window_size(win)))
            glfw.set_window_monitor(win, monitor, 0, 0, mode.size.width, mode.size.height, mode.refresh_rate)
            st.fullscreen = True
        else:
            (x, y), (w, h) = self._windowed
            self._windowed = None
            glfw.set_window_monitor(win, None, x, y, w, h, 0)
            st.fullscreen = False

    def _start_recording(self):
        st = self.state
        try:
            self.recorder = Recorder(self._shot_folder())
        except (OSError, RuntimeError) as e:
            st.message = f"cannot record: {e}"
            print(f"gridrt view: {st.message}", file=sys.stderr, flush=True)
            return
        st.recording = str(self.recorder.path)
        kind = "video" if self.recorder.video else "PNG frames (install '.[video]' for MP4)"
        st.message = f"recording {kind} to {self.recorder.path}"
        print(f"gridrt view: {st.message}", flush=True)
        self.last_key = None   # the frame on screen is the recording's first

    def _stop_recording(self):
        st, rec = self.state, self.recorder
        self.recorder = None
        st.recording = None
        try:
            path = rec.close()
        except (OSError, RuntimeError) as e:
            st.message = f"recording failed: {e}"
            print(f"gridrt view: {st.message}", file=sys.stderr, flush=True)
            return
        st.last_recording = str(path)
        st.message = f"saved {path} ({rec.frames} frames)"
        print(f"gridrt view: saved recording {path} ({rec.frames} frames) and its camera path {rec.camera_path}",
              flush=True)

    def _bench_result(self, res):
        """A --benchmark frame came back: keep its stats; after the last, report and quit."""
        b, st = self.bench, self.state
        b["rows"].append(res.stats)
        if len(b["rows"]) < b["warmup"] + b["frames"]:
            return
        rows = b["rows"][b["warmup"]:]
        med, note = frame_medians(rows)
        r0 = rows[0]
        st.benchmark = {k: med(k) for k in ("build_ms", "render_ms", "frame_ms", "mrays")}
        st.benchmark["frames"] = len(rows)
        st.benchmark["fps"] = 1e3 / st.benchmark["frame_ms"]
        csv_path = getattr(self.args, "stats_csv", None)
        if csv_path is not None:
            write_stats_csv(csv_path, b["rows"])
        print(f"gridrt view: benchmark of {len(rows)} frames after {b['warmup']} warm-up ({st.scene_name}, "
              f"{r0['triangles']} triangles, {r0['width']}x{r0['height']}, {r0['strategy']}, {r0['threads']} threads): "
              f"median build {st.benchmark['build_ms']:.2f} ms, render {st.benchmark['render_ms']:.2f} ms, frame "
              f"{st.benchmark['frame_ms']:.2f} ms ({st.benchmark['fps']:.1f} fps), {st.benchmark['mrays']:.2f} Mrays/s"
              + note + (f"; stats rows in {csv_path}" if csv_path is not None else ""), flush=True)
        st.quit = True

    # ---- outputs --------------------------------------------------------------------------
    def _remember_panel(self):
        """Remember (prefs.py) whether the panel is hidden or collapsed when the user changes it."""
        st = self.state
        now = (st.show_panel, st.panel_collapsed)
        if now != self._panel_kept:
            self._panel_kept = now
            save_prefs({"show_panel": now[0], "panel_collapsed": now[1]})

    def _shot_folder(self):
        self.shot_dir.mkdir(parents=True, exist_ok=True)
        return self.shot_dir

    def _save_png(self, rgb, stem, what):
        """Save (H, W, 3) uint8 ``rgb`` as the next free ``stem_NNNN.png`` in the shot folder and say
        so (panel message and stdout); on an OSError say that instead.  Returns the path or None."""
        from PIL import Image  # deferred: Pillow loads only when a screenshot is saved

        st = self.state
        try:
            p = _next_free(self._shot_folder(), stem)
            Image.fromarray(rgb).save(p)
        except OSError as e:
            st.message = f"{what} failed: {e}"
            print(f"gridrt view: {st.message}", file=sys.stderr, flush=True)
            return None
        st.message = f"saved {p}"
        print(f"gridrt view: saved {what} {p}", flush=True)
        return p

    def _save_shot(self):
        st = self.state
        if self.image is None:
            st.message = "no frame to save yet"
            return
        p = self._save_png(np.ascontiguousarray(exposed(self.image, self.state.exposure)[:, :, :3]), "gridrt",
                           "screenshot")
        if p is not None:
            st.last_screenshot = str(p)

    def _save_window_shot(self, fw, fh):
        raw = self.ctx.screen.read(viewport=(0, 0, fw, fh), components=3)
        _ = self.ctx.error   # reading the default framebuffer leaves a pending GL error on some drivers
        img = np.frombuffer(raw, np.uint8).reshape(fh, fw, 3)[::-1]
        p = self._save_png(np.ascontiguousarray(img), "gridrt_window", "window screenshot")
        if p is not None:
            self.state.last_window_shot = str(p)

    def _write_state(self, force=False):
        if self.state_file is None:
            return
        now = time.perf_counter()
        if not force and now - self._last_state_write < 0.1:
            return
        self._last_state_write = now
        tmp = self.state_file.with_name(self.state_file.name + ".tmp")
        try:
            tmp.write_text(json.dumps(self.state.snapshot()))
            os.replace(tmp, self.state_file)
        except OSError as e:
            print(f"gridrt view: cannot write state file {self.state_file}: {e}", file=sys.stderr, flush=True)
            self.state_file = None
