"""ViewerState: the viewer's only mutable UI state.  The panel (app/viewer/ui.py) and the input
handler (app/viewer/input.py) change it; the frame loop (app/viewer/view.py) hands its GridParams /
RenderParams to the pipeline and reports them in the state dump.

What the viewer renders is one :class:`gridrt.frame.FrameSpec` (``ViewerState.spec``: the scene,
the grid and render settings, and the view: camera, fov, up, the scene's own camera), changed only
by ``dataclasses.replace``: :attr:`ViewerState.scene`, ``grid``, ``render``, ``camera``, ``fov``,
``up`` and ``follow_camera`` read it and, set, replace the part in it (a widget replaces a field
with :meth:`ViewerState.set_grid` / :meth:`ViewerState.set_render`); the state keeps no loose copy
of any of them."""

import math
from collections import deque
from dataclasses import dataclass, field, replace

import numpy as np

from gridrt.camera import Camera
from gridrt.errors import InputError
from gridrt.frame import FrameSpec
from gridrt.stats import FrameStats
from gridrt.scene import SceneSpec  # noqa: F401  (the viewer's scene spec; input, ui and tests import it here too)
from gridrt.threads import check_threads

#: the panel's choices of shadow rays a pixel (RenderParams.light_samples): every light, or a few
#: drawn by their light (averaged while the view is still)
LIGHT_SAMPLE_LABELS = {"every light (exact)": 0, "1 drawn a pixel": 1, "2 drawn a pixel": 2, "4 drawn a pixel": 4}


def light_samples_label(k):
    """The panel's words for RenderParams.light_samples ``k``."""
    return "every light (exact)" if k == 0 else f"{k} drawn a pixel"


#: frames kept for the live build/render plots
HISTORY = 300
#: render resolution scale limits (render size = the image area's framebuffer size x scale)
SCALE_MIN, SCALE_MAX = 0.1, 2.0
#: animation speed limits (x real time)
SPEED_MIN, SPEED_MAX = 0.0, 4.0
#: time range of the scrub slider when the scene does not loop
DEFAULT_SPAN = 10.0
#: exposure range (stops either way) and the , and . keys' step
EXPOSURE_LIMIT, EXPOSURE_STEP = 8.0, 0.5
#: width (window pixels) of the panel column at the window's right edge, and of the strip it
#: collapses to; the image area is the rest of the window (all of it while the panel is hidden)
PANEL_WIDTH = 320
PANEL_STRIP_WIDTH = 32


@dataclass
class StatsHistory:
    """Ring buffers of the last HISTORY rendered frames' build and render ms; a frame that compiled
    kernels (``stats["compiled"]``) is left out: its times are not rendering times."""

    build_ms: deque = field(default_factory=lambda: deque(maxlen=HISTORY))
    render_ms: deque = field(default_factory=lambda: deque(maxlen=HISTORY))
    frame_ms: deque = field(default_factory=lambda: deque(maxlen=HISTORY))

    def add(self, stats):
        if stats.get("compiled"):
            return
        self.build_ms.append(float(stats["build_ms"]))
        self.render_ms.append(float(stats["render_ms"]))
        self.frame_ms.append(float(stats["frame_ms"]))

    def arrays(self):
        """(build_ms, render_ms) as float64 arrays (oldest first)."""
        return np.array(self.build_ms, np.float64), np.array(self.render_ms, np.float64)

    def clear(self):
        self.build_ms.clear()
        self.render_ms.clear()
        self.frame_ms.clear()


def _part(name, doc):
    """A property for the part ``name`` of ``ViewerState.spec``: set, it replaces that part."""
    return property(lambda self: getattr(self.spec, name),
                    lambda self, value: setattr(self, "spec", replace(self.spec, **{name: value})), doc=doc)


def _view_field(name, doc):
    """A property for the field ``name`` of ``ViewerState.spec.view``: set, it replaces that field."""
    return property(lambda self: getattr(self.spec.view, name),
                    lambda self, value: setattr(self, "spec", replace(self.spec, view=replace(self.spec.view,
                                                                                               **{name: value}))),
                    doc=doc)


def view_with_camera(view, cam):
    """The ViewSpec ``view`` looking through the Camera ``cam`` (its eye, target, up and fov), or
    with no camera of its own when ``cam`` is None (fov and up kept)."""
    if cam is None:
        return replace(view, eye=None, target=None)
    return replace(view, eye=cam.eye, target=cam.target, up=cam.up, fov=cam.fov)


@dataclass
class ViewerState:
    """Everything the viewer's widgets and keys can change, plus what they display."""

    # what to render: scene, grid, render and view (read and replaced through the properties below)
    spec: FrameSpec = field(default_factory=FrameSpec)
    # scene
    scene_name: str = ""
    triangles: int = 0
    duration: float | None = None
    static: bool = False
    file_text: str = ""                     # the panel's "mesh file" text box
    # the panel's "trust references outside the scene's folder" box: SceneSpec.allow_outside of the file
    # opened from the text box (starts as the command line's scene has it: --allow-outside-refs)
    file_allow_outside: bool = False
    scene_request: SceneSpec | None = None  # set by the panel; the loop starts the load
    scene_error: str = ""
    textures: dict | None = None            # the last load's textures: {"count", "bytes", "last"}
    # animation
    playing: bool = True
    time: float = 0.0
    speed: float = 1.0
    # grid and render settings: spec.grid and spec.render (threads: the same count for both; width
    # and height follow the window)
    max_threads: int = 1
    scale: float = 1.0
    # the scene's own camera (BART, glTF): ``follow_camera`` (spec.view) is the panel's "scene camera" box,
    # on only while the loaded scene has a camera (``scene_camera``).  A scene with a camera
    # starts on it when ``prefer_scene_camera`` (the default; --no-scene-camera clears it; an
    # explicit --eye/--target without --follow-camera keeps the command line's scene off it).
    # While it is on, ``camera`` is the camera of the frame on screen (the scene's at the frame's
    # time), so leaving it (the box, or any camera move: :meth:`leave_scene_camera`) keeps that view.
    scene_camera: bool = False
    prefer_scene_camera: bool = True
    scene_camera_home: bool = False         # Reset view returns to the scene camera (else to ``home``)
    # camera: spec.view (``camera``, ``fov``, ``up``); ``home``: where Reset view returns
    home: Camera | None = None
    scene_radius: float = 1.0
    # window / ui: the panel is a column at the window's right edge (PANEL_WIDTH), a strip
    # (PANEL_STRIP_WIDTH) while collapsed, nothing while hidden; the image fills the rest
    show_panel: bool = True
    panel_collapsed: bool = False
    quit: bool = False
    want_shot: bool = False                 # save the ray-traced image (F12 / P)
    want_window_shot: bool = False          # save the window with the panel (panel button)
    last_screenshot: str | None = None
    last_window_shot: str | None = None
    message: str = ""
    busy: str | None = None                 # label of a slow operation in progress
    cold_cache: bool = False
    window_size: tuple = (0, 0)
    framebuffer_size: tuple = (0, 0)
    render_size: tuple = (0, 0)
    # stats
    stats: FrameStats | None = None         # the last frame's
    history: StatsHistory = field(default_factory=StatsHistory)
    ui_frames: int = 0
    rendered_frames: int = 0
    ui_fps: float = 0.0
    render_fps: float = 0.0
    panel_rect: tuple = (0.0, 0.0, 0.0, 0.0)   # x, y, w, h in window pixels
    image_rect: tuple = (0, 0, 0, 0)           # the image area: x, y, w, h in window pixels
    widget_rects: dict = field(default_factory=dict)  # label -> (x, y, w, h), for tests
    panel_text: dict = field(default_factory=dict)    # name -> a line of the panel's stats, for tests
    # what is shown, and how (keys: see gridrt.app.viewer.input)
    exposure: float = 0.0                   # stops (, and . keys; / back to 0): the display only
    show_overlay: bool = False              # the figures over the image's corner (O key, --overlay)
    overlay_text: str = ""                  # what the overlay shows, for tests
    accumulate: bool = False                # progressive samples while the view is still (G key)
    samples: int = 0                        # samples averaged in the image on screen
    want_camera_print: bool = False         # print the camera as flags (V key)
    camera_flags: str = ""                  # the last flags printed
    bookmark_store: int | None = None       # Ctrl+1..9: keep the view in this slot
    bookmark_recall: int | None = None      # 1..9: go to the view kept in this slot
    bookmarks: dict = field(default_factory=dict)   # slot -> Camera, of the scene on screen
    focus_request: tuple | None = None      # (x, y) window pixel to focus on (F key, double click)
    focus: tuple | None = None              # the last focus point picked (world)
    want_fullscreen: bool = False           # toggle full screen (F11)
    fullscreen: bool = False
    want_record: bool = False               # start or stop recording (K key)
    recording: str | None = None            # the recording in progress (its path)
    last_recording: str | None = None
    benchmark: dict | None = None           # --benchmark's figures, once measured

    def __post_init__(self):
        # one thread count for build and render, a concrete one (None: all cores)
        threads = check_threads(self.grid.threads)
        self.grid = self.grid.replace(threads=threads)
        self.render = self.render.replace(threads=threads)
        self.max_threads = max(self.max_threads, threads)
        self.file_allow_outside = bool(self.file_allow_outside or self.scene.allow_outside)

    # ---- the parts of the FrameSpec ---------------------------------------------------------
    scene = _part("scene", "The scene (SceneSpec) on screen: ``spec.scene``.")
    grid = _part("grid", "The GridParams: ``spec.grid``.")
    fov = _view_field("fov", "The vertical field of view: ``spec.view.fov``.")
    up = _view_field("up", "The up vector: ``spec.view.up``.")
    follow_camera = _view_field("follow_camera", "Look through the scene's own camera: ``spec.view.follow_camera``.")

    @property
    def render(self):
        """The RenderParams: ``spec.render`` (set, its size becomes the view's)."""
        return self.spec.render

    @render.setter
    def render(self, value):
        self.spec = replace(self.spec, render=value, view=replace(self.spec.view, size=(value.width, value.height)))

    @property
    def camera(self):
        """The camera of the view (``spec.view``'s eye, target, up and fov), or None before the
        scene is framed."""
        return self.spec.view.camera()

    @camera.setter
    def camera(self, cam):
        self.spec = replace(self.spec, view=view_with_camera(self.spec.view, cam))

    # ---- settings: widgets replace fields of the frozen params -----------------------------
    @property
    def threads(self):
        return self.grid.threads

    def set_grid(self, **kw):
        """Replace GridParams fields; a refused value leaves the params as they are and shows
        the reason in the panel.  True when replaced."""
        return self._replace("grid", kw)

    def set_render(self, **kw):
        """Replace RenderParams fields (as :meth:`set_grid`)."""
        return self._replace("render", kw)

    def _replace(self, name, kw):
        try:
            setattr(self, name, getattr(self, name).replace(**kw))
        except InputError as e:
            self.scene_error = str(e)
            return False
        return True

    def set_threads(self, n):
        """Build and render on ``n`` threads (clamped to 1..max_threads)."""
        n = min(max(int(n), 1), self.max_threads)
        self.grid = self.grid.replace(threads=n)
        self.render = self.render.replace(threads=n)

    # ---- layout ----------------------------------------------------------------------------
    def panel_width(self):
        """Width of the panel's column in window pixels: PANEL_WIDTH, PANEL_STRIP_WIDTH while
        collapsed, 0 while hidden."""
        if not self.show_panel:
            return 0
        return PANEL_STRIP_WIDTH if self.panel_collapsed else PANEL_WIDTH

    def layout(self, win_w, win_h):
        """(image rect, panel rect), each (x, y, w, h) in window pixels, of a win_w x win_h window:
        the image area at the left, the panel's column at the right edge, full height (the image
        keeps at least one pixel of width in a window narrower than the panel)."""
        win_w, win_h = max(int(win_w), 1), max(int(win_h), 1)
        iw = max(win_w - self.panel_width(), 1)
        return (0, 0, iw, win_h), (iw, 0, win_w - iw, win_h)

    def window_for_image(self, w, h):
        """Window size whose image area is w x h (the panel's column beside it)."""
        return int(w) + self.panel_width(), int(h)

    def in_image(self, x, y):
        """Whether window point (x, y) lies in the image area."""
        ix, iy, iw, ih = self.image_rect
        return ix <= x < ix + iw and iy <= y < iy + ih

    def toggle_panel(self):
        """H: hide the panel (the image takes the whole window) or show it again."""
        self.show_panel = not self.show_panel

    # ---- engine parameters -----------------------------------------------------------------
    def grid_params(self):
        return self.grid

    def render_size_for(self, fb_w, fb_h):
        """Render resolution for an image area of fb_w x fb_h framebuffer pixels at the current
        scale."""
        s = min(max(float(self.scale), SCALE_MIN), SCALE_MAX)
        return max(1, int(round(fb_w * s))), max(1, int(round(fb_h * s)))

    def render_params(self, width, height):
        """The RenderParams of a width x height render."""
        return self.render.replace(width=width, height=height)

    # ---- animation -----------------------------------------------------------------------
    def time_span(self):
        """Upper end of the scrub slider: one loop of the scene, or DEFAULT_SPAN seconds."""
        return self.duration if self.duration else DEFAULT_SPAN

    def advance(self, dt):
        """Move the clock by dt wall seconds x speed when playing, wrapping at time_span()."""
        if self.playing and not self.static:
            span = self.time_span()
            self.time = math.fmod(self.time + dt * self.speed, span)
            if self.time < 0:
                self.time += span

    # ---- discrete actions shared by keys and widgets ---------------------------------------
    def cycle_strategy(self, names, step):
        if not names:
            return
        i = names.index(self.grid.strategy) if self.grid.strategy in names else -step
        self.set_grid(strategy=names[(i + step) % len(names)])

    def change_threads(self, step):
        self.set_threads(self.threads + step)

    def change_exposure(self, step):
        """Exposure up or down by ``step`` stops, within EXPOSURE_LIMIT; ``None``: back to 0."""
        self.exposure = 0.0 if step is None else min(max(self.exposure + step, -EXPOSURE_LIMIT), EXPOSURE_LIMIT)

    def reset_view(self):
        """Back to the starting view: the scene's camera when the scene started on it, else ``home``."""
        if self.scene_camera_home and self.scene_camera:
            self.follow_camera = True
        elif self.home is not None:
            self.camera = self.home

    def set_scene_camera(self, on):
        """The "scene camera" box: look through the scene's own camera (only when it has one).
        Turned off, the view stays where the scene's camera had it (``camera`` is the camera of
        the frame on screen)."""
        self.follow_camera = bool(on) and self.scene_camera

    def leave_scene_camera(self):
        """A camera move (drag, wheel, fly keys) starts here: it leaves the scene's camera, and
        moves on from the view on screen."""
        self.follow_camera = False

    def scene_loaded(self, has_camera, want):
        """A scene was loaded: look through its camera when it has one and ``want`` (the viewer
        wants to: see gridrt.app.viewer.view); Reset view returns to it then."""
        self.scene_camera = bool(has_camera)
        self.follow_camera = self.scene_camera_home = bool(want) and self.scene_camera

    def figures_text(self):
        """The overlay's lines for the frame on screen: its rate and Mrays/s, then its build, render
        and frame times, as its stats row has them (the dump's stats.csv columns: fps is
        1000 / frame_ms), then what is averaged and the exposure when not 0."""
        st = self.stats
        if not st:
            return ""
        lines = [f"{1e3 / max(st['frame_ms'], 1e-9):.1f} fps  {st['mrays']:.2f} Mrays/s"
                 + ("  (compiled kernels)" if st.get("compiled") else ""),
                 f"build {st['build_ms']:.2f} ms  render {st['render_ms']:.2f} ms  frame {st['frame_ms']:.2f} ms"]
        extra = []
        if self.samples > 1:
            extra.append(f"{self.samples} samples")
        if self.exposure:
            extra.append(f"exposure {self.exposure:+g}")
        if self.recording:
            extra.append("recording")
        if extra:
            lines.append("  ".join(extra))
        return "\n".join(lines)

    def snapshot(self):
        """A JSON-ready dict of the state (the --state-file dump)."""
        cam = self.camera
        st = {k: _plain(v) for k, v in (self.stats or {}).items()}
        return {
            "ui_frames": self.ui_frames,
            "rendered_frames": self.rendered_frames,
            "scene": self.scene.source,
            "scene_name": self.scene_name,
            "triangles": self.triangles,
            "scene_error": self.scene_error,
            "allow_outside": self.scene.allow_outside,
            "file_allow_outside": self.file_allow_outside,
            "playing": self.playing,
            "time": self.time,
            "speed": self.speed,
            "strategy": self.grid.strategy,
            "threads": self.grid.threads,
            "max_threads": self.max_threads,
            "density": self.grid.density,
            "grid": self.grid.grid,
            "top_density": self.grid.top_density,
            "leaf_density": self.grid.leaf_density,
            "macro": self.grid.macro,
            "insert": self.grid.insert,
            "watertight": self.render.watertight,
            "shading": self.render.shading,
            "shadows": self.render.shadows,
            "light_samples": self.render.light_samples,
            "shadow rays": light_samples_label(self.render.light_samples),
            "follow_camera": self.follow_camera,
            "scene_camera": self.scene_camera,
            "textures": self.textures,
            "traversal": self.render.traversal,
            "packet": list(self.render.packet),
            "packet_precision": self.render.packet_precision,
            "scale": self.scale,
            "show_panel": self.show_panel,
            "panel_collapsed": self.panel_collapsed,
            "busy": self.busy,
            "window_size": list(self.window_size),
            "framebuffer_size": list(self.framebuffer_size),
            "render_size": list(self.render_size),
            "camera": None if cam is None else {"eye": list(cam.eye), "target": list(cam.target),
                                                "up": list(cam.up), "fov": cam.fov},
            "last_screenshot": self.last_screenshot,
            "last_window_shot": self.last_window_shot,
            "message": self.message,
            "panel_rect": list(self.panel_rect),
            "image_rect": list(self.image_rect),
            "widget_rects": {k: list(v) for k, v in self.widget_rects.items()},
            "panel_text": dict(self.panel_text),
            "stats": st,
            "ui_fps": self.ui_fps,
            "render_fps": self.render_fps,
            "exposure": self.exposure,
            "show_overlay": self.show_overlay,
            "overlay_text": self.overlay_text,
            "accumulate": self.accumulate,
            "samples": self.samples,
            "camera_flags": self.camera_flags,
            "bookmarks": sorted(self.bookmarks),
            "focus": None if self.focus is None else list(self.focus),
            "fullscreen": self.fullscreen,
            "recording": self.recording,
            "last_recording": self.last_recording,
            "benchmark": self.benchmark,
        }


def _plain(v):
    """A JSON-ready version of a stats value (numpy scalars -> Python, anything else -> str)."""
    if isinstance(v, np.generic):
        v = v.item()
    if v is None or isinstance(v, (bool, int, str)):
        return v
    if isinstance(v, float):
        return v if math.isfinite(v) else None
    return str(v)
