"""ViewerState: the viewer's only mutable UI state.  The panel (app/ui.py) and the input
handler (app/input.py) change its fields; the frame loop (app/view.py) turns them into frozen
GridParams / RenderParams for the pipeline and reports them in the state dump."""

import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from gridrt.camera import Camera
from gridrt.config import GridParams, RenderParams

#: frames kept for the live build/render plots
HISTORY = 300
#: render resolution scale limits (render size = framebuffer size x scale)
SCALE_MIN, SCALE_MAX = 0.1, 2.0
#: animation speed limits (x real time)
SPEED_MIN, SPEED_MAX = 0.0, 4.0
#: time range of the scrub slider when the scene does not loop
DEFAULT_SPAN = 10.0


@dataclass
class SceneSpec:
    """What to load: a built-in scene name or a mesh path, with the make_scene options."""

    source: str = "marbles"
    count: int | None = None
    animate: str | None = None
    amplitude: float | None = None
    speed: float = 1.0
    seed: int = 0
    clip: int | str | None = None
    subdivide: int | None = None
    fps: float | None = None

    def label(self):
        return self.source if self.count is None else f"{self.source} ({self.count} triangles)"


@dataclass
class StatsHistory:
    """Ring buffers of the last HISTORY rendered frames' build and render ms."""

    build_ms: deque = field(default_factory=lambda: deque(maxlen=HISTORY))
    render_ms: deque = field(default_factory=lambda: deque(maxlen=HISTORY))
    frame_ms: deque = field(default_factory=lambda: deque(maxlen=HISTORY))

    def add(self, stats):
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


@dataclass
class ViewerState:
    """Everything the viewer's widgets and keys can change, plus what they display."""

    # scene
    scene: SceneSpec = field(default_factory=SceneSpec)
    scene_name: str = ""
    triangles: int = 0
    duration: float | None = None
    static: bool = False
    file_text: str = ""                     # the panel's "mesh file" text box
    scene_request: SceneSpec | None = None  # set by the panel; the loop starts the load
    scene_error: str = ""
    # animation
    playing: bool = True
    time: float = 0.0
    speed: float = 1.0
    # grid
    strategy: str = "serial"
    threads: int = 1
    max_threads: int = 1
    density: float = 4.0
    macro: int = 4
    insert: str = "bbox"
    max_cells: int | None = None
    # render
    watertight: bool = True
    shading: str = "lambert"
    shadows: bool = False
    follow_camera: bool = False  # look through the scene's animated camera (BART, glTF)
    traversal: str = "dda"  # "dda" single rays or "cgt" packets
    light: tuple | None = None
    scale: float = 1.0
    # camera
    camera: Camera | None = None
    home: Camera | None = None
    fov: float = 45.0
    up: tuple = (0.0, 1.0, 0.0)
    scene_radius: float = 1.0
    # window / ui
    show_panel: bool = True
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
    stats: dict = field(default_factory=dict)
    history: StatsHistory = field(default_factory=StatsHistory)
    ui_frames: int = 0
    rendered_frames: int = 0
    ui_fps: float = 0.0
    render_fps: float = 0.0
    panel_rect: tuple = (0.0, 0.0, 0.0, 0.0)   # x, y, w, h in window pixels
    widget_rects: dict = field(default_factory=dict)  # label -> (x, y, w, h), for tests

    # ---- derived engine parameters -------------------------------------------------------
    def grid_params(self):
        kw = dict(strategy=self.strategy, density=self.density, macro=self.macro, insert=self.insert,
                  threads=self.threads)
        if self.max_cells is not None:
            kw["max_cells"] = self.max_cells
        return GridParams(**kw)

    def render_size_for(self, fb_w, fb_h):
        """Render resolution for a framebuffer of fb_w x fb_h pixels at the current scale."""
        s = min(max(float(self.scale), SCALE_MIN), SCALE_MAX)
        return max(1, int(round(fb_w * s))), max(1, int(round(fb_h * s)))

    def render_params(self, width, height):
        return RenderParams(width=width, height=height, shading=self.shading, shadows=self.shadows,
                            light=self.light, watertight=self.watertight, threads=self.threads,
                            traversal=self.traversal)

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
        i = names.index(self.strategy) if self.strategy in names else -step
        self.strategy = names[(i + step) % len(names)]

    def change_threads(self, step):
        self.threads = min(max(self.threads + step, 1), self.max_threads)

    def reset_view(self):
        if self.home is not None:
            self.camera = self.home

    def snapshot(self):
        """A JSON-ready dict of the state (the --state-file dump)."""
        cam = self.camera
        st = {k: _plain(v) for k, v in self.stats.items()}
        return {
            "ui_frames": self.ui_frames,
            "rendered_frames": self.rendered_frames,
            "scene": self.scene.source,
            "scene_name": self.scene_name,
            "triangles": self.triangles,
            "scene_error": self.scene_error,
            "playing": self.playing,
            "time": self.time,
            "speed": self.speed,
            "strategy": self.strategy,
            "threads": self.threads,
            "max_threads": self.max_threads,
            "density": self.density,
            "macro": self.macro,
            "insert": self.insert,
            "watertight": self.watertight,
            "shading": self.shading,
            "shadows": self.shadows,
            "follow_camera": self.follow_camera,
            "traversal": self.traversal,
            "scale": self.scale,
            "show_panel": self.show_panel,
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
            "widget_rects": {k: list(v) for k, v in self.widget_rects.items()},
            "stats": st,
            "ui_fps": self.ui_fps,
            "render_fps": self.render_fps,
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
