"""The imgui panel: widgets that change :class:`gridrt.app.viewer.state.ViewerState` fields and nothing else
(no kernels, no GL).  The panel is a column of fixed width at the window's right edge, full height,
beside the image (never over it: ViewerState.layout splits the window); its arrow button collapses
it to a thin strip whose arrow opens it again.  The progress overlay is centred over the image
area while a slow operation runs.

:class:`ImguiRuntime` owns the imgui + implot contexts and imgui's OpenGL 3 renderer (and, in a
window, its glfw backend), for the windowed viewer and the headless panel test alike.
"""

import ctypes
import os

import numpy as np
from imgui_bundle import imgui, implot

from gridrt.config import GRID_KINDS, INSERT_MODES, SHADING_MODES
from gridrt.scene import BUILTIN_SCENES, DEFORM_KINDS, FRAME_EXTENSIONS, SCENE_EXTENSIONS, SceneSpec
from gridrt.scene.assets import DATA_SCENES, STATIC_ASSETS, STATIC_DATA_SCENES, scene_present

from .input import KEY_HELP
from .state import (  # noqa: F401
    LIGHT_SAMPLE_LABELS, PANEL_STRIP_WIDTH, PANEL_WIDTH, SCALE_MAX, SCALE_MIN, SPEED_MAX, SPEED_MIN, light_samples_label,
)

#: panel background (RGB 0..1; opaque: the panel lies beside the image)
PANEL_BG = (0.09, 0.10, 0.12)
INTERSECTION_LABELS = ("watertight (Woop et al.)", "fast (Moller-Trumbore)")
#: ranges of the panel's two-level density sliders (logarithmic): top cells per triangle, leaf
#: cells per reference of a top cell
TOP_DENSITY_RANGE = (1.0 / 128.0, 1.0)
LEAF_DENSITY_RANGE = (0.25, 16.0)
#: the traversals the panel offers: CGT with its packets' size and the precision of their triangle
#: tests (BENCHMARKS.md section 12: 8x16 with float32 tests is the fastest measured, 8x8 float64
#: the exact default), and the single-ray DDA
TRAVERSAL_CHOICES = tuple(f"cgt {p}, {q}" for q in ("float64", "float32") for p in ("8x8", "8x16", "16x16")) + ("dda",)


def traversal_setting(label):
    """The RenderParams fields of a TRAVERSAL_CHOICES label ("dda", or "cgt 8x16, float32": the
    packets' size and the precision of their tests)."""
    if label == "dda":
        return {"traversal": "dda"}
    _, shape, prec = label.split(" ")
    return {"traversal": "cgt", "packet": shape.rstrip(","), "packet_precision": prec}


def shading_label(mode, stats):
    """The shading combo's text: the mode, and for "auto" the mode it resolved to in the last frame
    (the stats row's ``shading``), e.g. "auto: material"."""
    resolved = stats.get("shading") if stats else None
    if mode == "auto" and resolved and resolved != "auto":
        return f"auto: {resolved}"
    return mode


def traversal_label(rp):
    """The panel's label of RenderParams rp's traversal, e.g. "cgt 8x8, float64" or "dda"."""
    if rp.traversal == "dda":
        return "dda"
    return f"cgt {rp.packet[0]}x{rp.packet[1]}, {rp.packet_precision}"
ERROR_COLOR = imgui.ImVec4(1.0, 0.45, 0.4, 1.0)
DIM_COLOR = imgui.ImVec4(0.65, 0.68, 0.72, 1.0)
_ANIMATE = ("none",) + tuple(DEFORM_KINDS)


class ImguiRuntime:
    """imgui + implot contexts and the C++ OpenGL 3 renderer (imgui.backends).  Pass a glfw
    window to also install imgui's glfw platform backend (its callbacks chain to any installed
    before).  No imgui.ini or log file is ever written."""

    def __init__(self, window=None):
        self.window = window
        self.ctx = imgui.create_context()
        self.plot_ctx = implot.create_context()
        io = imgui.get_io()
        io.set_ini_filename(None)
        io.set_log_filename("")
        apply_style()
        if window is not None:
            imgui.backends.glfw_init_for_opengl(ctypes.cast(window, ctypes.c_void_p).value, True)
        imgui.backends.opengl3_init("#version 330")

    def new_frame(self, display_size=None, dt=None):
        """Start a frame.  Headless: pass display_size (w, h) and dt seconds."""
        imgui.backends.opengl3_new_frame()
        if self.window is not None:
            imgui.backends.glfw_new_frame()
        else:
            io = imgui.get_io()
            io.display_size = imgui.ImVec2(*display_size)
            io.delta_time = max(float(dt or 1 / 60), 1e-4)
        imgui.new_frame()

    def render(self):
        """End the frame and draw it into the bound framebuffer."""
        imgui.render()
        imgui.backends.opengl3_render_draw_data(imgui.get_draw_data())

    def shutdown(self):
        imgui.backends.opengl3_shutdown()
        if self.window is not None:
            imgui.backends.glfw_shutdown()
        implot.destroy_context(self.plot_ctx)
        imgui.destroy_context(self.ctx)


def apply_style():
    imgui.style_colors_dark()
    style = imgui.get_style()
    style.window_rounding = 4.0
    style.item_spacing = imgui.ImVec2(6.0, 3.0)
    style.frame_padding = imgui.ImVec2(5.0, 2.0)
    style.set_color_(imgui.Col_.window_bg, imgui.ImVec4(*PANEL_BG, 1.0))
    style.set_color_(imgui.Col_.frame_bg, imgui.ImVec4(0.20, 0.25, 0.33, 1.0))
    style.set_color_(imgui.Col_.frame_bg_hovered, imgui.ImVec4(0.26, 0.34, 0.46, 1.0))
    style.set_color_(imgui.Col_.frame_bg_active, imgui.ImVec4(0.30, 0.40, 0.56, 1.0))


def _rect(state, name, width=None):
    """Record the last widget's rectangle (x, y, w, h) in window pixels under ``name``; ``width``
    (from calc_item_width() before the widget) limits it to the widget's frame, without its label."""
    p = imgui.get_item_rect_min()
    s = imgui.get_item_rect_size()
    w = float(s.x) if width is None else min(float(width), float(s.x))
    state.widget_rects[name] = (float(p.x), float(p.y), w, float(s.y))


def _combo(state, label, items, current, preview=None):
    """A combo box over ``items`` showing ``current`` (or the text ``preview``); the item picked
    this frame, or None.  While its list is open, each item's rectangle is recorded as
    ``"<label>: <item>"``."""
    w = imgui.calc_item_width()
    opened = imgui.begin_combo(label, preview if preview is not None else (current if current in items else ""))
    _rect(state, label, w)
    if not opened:
        return None
    picked = None
    for item in items:
        clicked, _ = imgui.selectable(item, item == current)
        _rect(state, f"{label}: {item}")
        if item == current:
            imgui.set_item_default_focus()
        if clicked:
            picked = item
    imgui.end_combo()
    return picked


def draw_panel(state, strategy_names):
    """Draw the control panel for one frame in its column (``state.layout`` of the window), or
    the collapsed strip; widgets write into ``state`` only (and record their rectangles in
    ``state.widget_rects``)."""
    if state.panel_collapsed:
        _draw_strip(state)
        return
    _begin_panel(state)
    _draw_title(state)
    _section(state, "Scene", "scene header", _draw_scene)
    _section(state, "Animation", "animation header", _draw_animation)
    _section(state, "Grid", "grid header", lambda st: _draw_grid(st, strategy_names))
    _section(state, "Render", "render header", _draw_render)
    _section(state, "Stats", "stats header", _draw_stats)
    _draw_help()


#: flags of the panel's and the strip's windows: fixed in their column, no title bar
_COLUMN_FLAGS = (imgui.WindowFlags_.no_title_bar | imgui.WindowFlags_.no_move | imgui.WindowFlags_.no_resize
                 | imgui.WindowFlags_.no_collapse | imgui.WindowFlags_.no_saved_settings)


def _begin_column(state, name, flags, padding):
    """Begin the window ``name`` filling the panel's column of the window's layout (square
    corners, no border, ``padding`` pixels inside); records it as ``state.panel_rect``."""
    io = imgui.get_io()
    _, (x, y, w, h) = state.layout(io.display_size.x, io.display_size.y)
    imgui.set_next_window_pos(imgui.ImVec2(x, y), imgui.Cond_.always)
    imgui.set_next_window_size(imgui.ImVec2(w, h), imgui.Cond_.always)
    imgui.push_style_var(imgui.StyleVar_.window_rounding, 0.0)
    imgui.push_style_var(imgui.StyleVar_.window_border_size, 0.0)
    imgui.push_style_var(imgui.StyleVar_.window_min_size, imgui.ImVec2(1.0, 1.0))
    imgui.push_style_var(imgui.StyleVar_.window_padding, imgui.ImVec2(padding, padding))
    imgui.begin(name, None, _COLUMN_FLAGS | flags)
    imgui.pop_style_var(4)
    p, s = imgui.get_window_pos(), imgui.get_window_size()
    state.panel_rect = (float(p.x), float(p.y), float(s.x), float(s.y))


def _begin_panel(state):
    """The panel's window: its whole column (it scrolls when its sections are taller)."""
    _begin_column(state, "gridrt", 0, 8.0)
    imgui.push_item_width(-90.0)


def _draw_strip(state):
    """The collapsed panel: a thin strip at the window's right edge with the arrow that opens it."""
    pad = max((PANEL_STRIP_WIDTH - imgui.get_frame_height()) / 2, 1.0)   # the arrow in the strip's middle
    _begin_column(state, "##panel strip", imgui.WindowFlags_.no_scrollbar, pad)
    _collapse_arrow(state)
    imgui.end()


def _collapse_arrow(state):
    """The arrow that collapses the panel to its strip (right), or in the strip opens it (left);
    recorded as "collapse panel" / "expand panel"."""
    name, tip = (("expand panel", "open the panel") if state.panel_collapsed
                 else ("collapse panel", "collapse the panel to a strip"))
    if imgui.arrow_button("##" + name, imgui.Dir.left if state.panel_collapsed else imgui.Dir.right):
        state.panel_collapsed = not state.panel_collapsed
    _rect(state, name)
    if imgui.is_item_hovered():
        imgui.set_tooltip(tip + " (H hides it altogether)")


def _draw_title(state):
    """The collapse arrow and the scene's name and size, then the last error and message."""
    _collapse_arrow(state)
    imgui.same_line()
    title = state.scene_name or state.scene.source
    imgui.text(f"{title}: {state.triangles:,} triangles" if state.triangles else title)
    imgui.push_text_wrap_pos(0.0)
    if state.scene_error:
        imgui.text_colored(ERROR_COLOR, state.scene_error)
    if state.message:
        imgui.text_colored(DIM_COLOR, state.message)
    imgui.pop_text_wrap_pos()


def _section(state, title, rect_name, draw):
    """A collapsing header (open at first) recorded as ``rect_name``; ``draw(state)`` fills it."""
    opened = imgui.collapsing_header(title, imgui.TreeNodeFlags_.default_open)
    _rect(state, rect_name)
    if opened:
        draw(state)


def _draw_help():
    """The key help line, then the end of the panel's window."""
    imgui.separator()
    imgui.push_text_wrap_pos(0.0)
    imgui.text_colored(DIM_COLOR, KEY_HELP)
    imgui.pop_text_wrap_pos()
    imgui.pop_item_width()
    imgui.end()


def _draw_animation(state):
    """Play/pause, the time slider and the playback speed."""
    if imgui.button("Pause" if state.playing else "Play", imgui.ImVec2(50, 0)):
        state.playing = not state.playing
    _rect(state, "play")
    imgui.same_line()
    span = state.time_span()
    w = imgui.calc_item_width()
    changed, t = imgui.slider_float("time", float(state.time), 0.0, float(span),
                                    "static" if state.static else "%.2f s")
    _rect(state, "time", w)
    if changed:
        state.time = min(max(t, 0.0), span)
    w = imgui.calc_item_width()
    changed, v = imgui.slider_float("speed", float(state.speed), SPEED_MIN, SPEED_MAX, "%.2fx")
    _rect(state, "speed", w)
    if changed:
        state.speed = v


def _density_slider(state, label, field, lo, hi):
    """A logarithmic slider over GridParams field ``field`` (a positive density)."""
    w = imgui.calc_item_width()
    changed, d = imgui.slider_float(label, float(getattr(state.grid, field)), lo, hi, "%.3g",
                                    imgui.SliderFlags_.logarithmic)
    _rect(state, label, w)
    if changed and d > 0:
        state.set_grid(**{field: d})


def _draw_grid(state, strategy_names):
    """Build strategy, threads, grid kind (with a two-level grid's densities), lambda, macro-cell
    size and insertion test."""
    gp = state.grid
    v = _combo(state, "strategy", list(strategy_names), gp.strategy)
    if v is not None:
        state.set_grid(strategy=v)
    w = imgui.calc_item_width()
    changed, n = imgui.slider_int("threads", int(state.threads), 1, int(state.max_threads))
    _rect(state, "threads", w)
    if changed:
        state.set_threads(n)
    v = _combo(state, "grid", list(GRID_KINDS), gp.grid)
    if v is not None:
        state.set_grid(grid=v)
    if gp.grid != "uniform":  # (auto builds a two-level grid with these densities when it picks one)
        _density_slider(state, "top density", "top_density", *TOP_DENSITY_RANGE)
        _density_slider(state, "leaf density", "leaf_density", *LEAF_DENSITY_RANGE)
    _density_slider(state, "lambda", "density", 0.125, 64.0)
    w = imgui.calc_item_width()
    changed, m = imgui.slider_int("macro cell", int(gp.macro), 1, 16)
    _rect(state, "macro cell", w)
    if changed:
        state.set_grid(macro=min(max(m, 1), 16))
    v = _combo(state, "insertion", list(INSERT_MODES), gp.insert)
    if v is not None:
        state.set_grid(insert=v)


def _draw_render(state):
    """Intersection test, shading, traversal, shadows, scene camera, resolution and the
    image / window / view buttons."""
    rp = state.render
    v = _combo(state, "intersection", list(INTERSECTION_LABELS), INTERSECTION_LABELS[0 if rp.watertight else 1])
    if v is not None:
        state.set_render(watertight=v == INTERSECTION_LABELS[0])
    v = _combo(state, "shading", list(SHADING_MODES), rp.shading, shading_label(rp.shading, state.stats))
    if v is not None:
        state.set_render(shading=v)
    v = _combo(state, "traversal", list(TRAVERSAL_CHOICES), traversal_label(rp))
    if v is not None:
        state.set_render(**traversal_setting(v))
    changed, b = imgui.checkbox("shadows", bool(rp.shadows))
    _rect(state, "shadows")
    if changed:
        state.set_render(shadows=b)
    imgui.same_line()
    imgui.begin_disabled(not state.scene_camera)
    changed, b = imgui.checkbox("scene camera", bool(state.follow_camera))
    imgui.end_disabled()
    _rect(state, "scene camera")
    if changed:
        state.set_scene_camera(b)
    if imgui.is_item_hovered(imgui.HoveredFlags_.allow_when_disabled):
        imgui.set_tooltip("look through the scene's own (animated) camera (C); moving the view leaves it"
                          if state.scene_camera else "this scene has no camera of its own")
    imgui.begin_disabled(not rp.shadows)
    current = light_samples_label(rp.light_samples)
    v = _combo(state, "shadow rays", list(LIGHT_SAMPLE_LABELS), current)
    imgui.end_disabled()
    if imgui.is_item_hovered(imgui.HoveredFlags_.allow_when_disabled):
        imgui.set_tooltip("material shading with shadows: a ray towards every light, or towards lights drawn by "
                          "their light at each pixel (faster, noisy in shadows; averaged towards the exact image "
                          "while the view is still)")
    if v is not None:
        state.set_render(light_samples=LIGHT_SAMPLE_LABELS[v])
    w = imgui.calc_item_width()
    changed, sc = imgui.slider_float("resolution", float(state.scale), SCALE_MIN, SCALE_MAX, "%.2fx")
    _rect(state, "resolution", w)
    if changed:
        state.scale = min(max(sc, SCALE_MIN), SCALE_MAX)
    if imgui.button("Save image"):
        state.want_shot = True
    _rect(state, "save image")
    imgui.same_line()
    if imgui.button("Save window"):
        state.want_window_shot = True
    _rect(state, "save window")
    imgui.same_line()
    if imgui.button("Reset view"):
        state.reset_view()
    _rect(state, "reset view")


def _draw_scene(state):
    # the data set's scenes where they are present (a user's clone has the shipped ones only)
    builtins = [n for n in BUILTIN_SCENES if n not in DATA_SCENES or scene_present(n)]
    is_builtin = state.scene.source in builtins
    v = _combo(state, "built-in", builtins, state.scene.source if is_builtin else None)
    if v is not None:
        state.scene_request = SceneSpec(source=v)
    if state.scene.source in ("marbles", "icosphere"):  # the scenes whose size is a triangle count
        w = imgui.calc_item_width()
        changed, n = imgui.input_int("triangles", int(state.scene.count or state.triangles or 1), 1000, 10000,
                                     imgui.InputTextFlags_.enter_returns_true)
        _rect(state, "triangles", w)
        if changed and n >= 1:
            state.scene_request = SceneSpec(source=state.scene.source, count=int(n), seed=state.scene.seed)
        if imgui.is_item_hovered():
            imgui.set_tooltip("press Enter to rebuild the scene with this many triangles")
    if state.scene.source == "icosphere" or state.scene.source in STATIC_ASSETS + STATIC_DATA_SCENES or not is_builtin:
        v = _combo(state, "deform", list(_ANIMATE), state.scene.animate or "none")
        if v is not None:
            s = state.scene
            state.scene_request = SceneSpec(source=s.source, count=s.count,
                                            animate=None if v == "none" else v, seed=s.seed,
                                            allow_outside=s.allow_outside)
    w = imgui.calc_item_width()
    enter, txt = imgui.input_text_with_hint("##file", "mesh file path", state.file_text,
                                             imgui.InputTextFlags_.enter_returns_true)
    _rect(state, "mesh file", w)
    state.file_text = txt
    if imgui.is_item_hovered():
        imgui.set_tooltip(f"path of a scene file ({' '.join(SCENE_EXTENSIONS)}) or a folder of frames "
                          f"({' '.join(FRAME_EXTENSIONS)}); Enter or Open loads it (or drop a file on the window)")
    imgui.same_line()
    if (imgui.button("Open file") or enter) and state.file_text.strip():
        state.scene_request = SceneSpec(source=os.path.expanduser(state.file_text.strip()),
                                        allow_outside=state.file_allow_outside)
    _rect(state, "open file")
    changed, b = imgui.checkbox("trust references outside the scene's folder", bool(state.file_allow_outside))
    _rect(state, "trust outside refs")
    if changed:
        state.file_allow_outside = b
    if imgui.is_item_hovered():
        imgui.set_tooltip("the file opened from the box may read the files it names (buffers, images, materials, "
                          "includes, textures) outside its own folder (--allow-outside-refs); off: they are refused")


def _fmt_bytes(n):
    n = float(n)
    for unit in ("B", "KiB", "MiB", "GiB"):
        if n < 1024 or unit == "GiB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.2f} {unit}"
        n /= 1024


def _dims(d):
    if isinstance(d, (tuple, list, np.ndarray)):
        return "x".join(str(int(v)) for v in d)
    return str(d)


def _line(state, name, text, color=None):
    """One line of the stats (wrapped at the panel's edge), also kept in ``state.panel_text[name]``
    (the state dump's; for tests)."""
    state.panel_text[name] = text
    imgui.push_text_wrap_pos(0.0)
    if color is None:
        imgui.text(text)
    else:
        imgui.text_colored(color, text)
    imgui.pop_text_wrap_pos()


def shade_line(st):
    """The stats' shading line: the material pass's time (its shading and shadow rays, part of
    the render's) and the mode the frame was shaded with (an "auto" resolved)."""
    return f"shade  {float(st.get('shade_ms', 0.0) or 0.0):8.2f} ms  {st.get('shading', '')}"


def lights_line(st):
    """The stats' lights line: the lights the hits were shaded with and the shadow rays per pixel."""
    rays = st.get("shadow_rays_per_pixel", 0.0)
    return (f"lights {int(st.get('lights', 0) or 0)}   "
            f"shadow rays {'n/a' if rays is None or rays != rays else f'{float(rays):.2f}/px'}")


def references_line(st):
    """The stats' references line: the whole scene's references and references per triangle (a
    split scene's static and moving parts together), and a split scene's moving part's figure."""
    text = f"references {st['references']:,} ({st.get('refs_per_tri', 0):.2f}/tri"
    if getattr(st, "static", None) is not None:
        text += f", moving {st.get('moving_refs_per_tri', 0):.2f}"
    return text + ")"


def _draw_stats(state):
    st = state.stats
    state.panel_text = {}
    if not st:
        imgui.text_colored(DIM_COLOR, "no frame yet")
        return
    stages = [(k.removesuffix("_ms"), v) for k, v in st.build_stages.items()]
    if st.static is not None:
        stages.append(("static build", st.static_build_ms))
    if st.get("rebuilt", 1):
        _line(state, "build", f"build  {st['build_ms']:8.2f} ms  {st['strategy']}, {st['threads']} thr")
        imgui.push_text_wrap_pos(0.0)
        imgui.text_colored(DIM_COLOR, "  " + "  ".join(f"{k} {v:.2f}" for k, v in stages))
        imgui.pop_text_wrap_pos()
    else:
        _line(state, "build", "build  reused (static scene)")
    _line(state, "render",
          f"render {st['render_ms']:8.2f} ms  {st['width']}x{st['height']}, {st.get('mrays', 0):.1f} Mray/s"
          + ("  (compiled kernels)" if st.get("compiled") else ""))
    _line(state, "shade", shade_line(st))
    _line(state, "lights", lights_line(st))
    _line(state, "frame", f"frame  {st['frame_ms']:8.2f} ms  {state.render_fps:.1f} fps (window {state.ui_fps:.0f})")
    kind = st.get("grid", "uniform")
    two_level = kind == "two_level"  # its cells and references are the leaf level's, its dims the top's
    _line(state, "grid", f"grid {kind}   dims {_dims(st.get('dims', ''))}"
          + (f" top, {st.get('macro_full', 0):,} full" if two_level else ""))
    _line(state, "triangles", f"triangles {st['triangles']:,}   {'leaf cells' if two_level else 'cells'} {st['cells']:,}")
    _line(state, "references", references_line(st))
    _line(state, "memory", f"grid memory {_fmt_bytes(st.get('grid_bytes', 0))}   {st.get('bytes_per_tri', 0):.1f} B/tri")
    b, r = state.history.arrays()
    if len(b) >= 2 and implot.begin_plot("##ms", imgui.ImVec2(-1, 130)):
        fit = implot.AxisFlags_.auto_fit
        implot.setup_axes("frame", "ms", fit, fit)
        implot.plot_line("build", np.ascontiguousarray(b))
        implot.plot_line("render", np.ascontiguousarray(r))
        implot.end_plot()
        _rect(state, "plot")


#: a window over the image that takes no input and keeps no settings (the figures, the busy box)
_OVERLAY_FLAGS = (imgui.WindowFlags_.no_decoration | imgui.WindowFlags_.always_auto_resize
                  | imgui.WindowFlags_.no_saved_settings | imgui.WindowFlags_.no_inputs
                  | imgui.WindowFlags_.no_focus_on_appearing | imgui.WindowFlags_.no_nav)


def draw_figures(state):
    """The figures of the frame on screen (ViewerState.figures_text) over the image's top-left
    corner, while ``state.show_overlay`` (the O key)."""
    if not state.show_overlay or not state.overlay_text:
        return
    x, y, _, _ = state.image_rect
    imgui.set_next_window_pos(imgui.ImVec2(x + 8, y + 8), imgui.Cond_.always)
    imgui.set_next_window_bg_alpha(0.55)
    flags = _OVERLAY_FLAGS
    imgui.begin("##figures", None, flags)
    imgui.text(state.overlay_text)
    p, s = imgui.get_window_pos(), imgui.get_window_size()
    state.widget_rects["figures overlay"] = (float(p.x), float(p.y), float(s.x), float(s.y))
    imgui.end()


def draw_overlay(state, elapsed):
    """A box centred over the image area with the label of the slow operation in progress and an
    indeterminate progress bar (only while ``state.busy`` is set)."""
    if not state.busy:
        return
    io = imgui.get_io()
    (x, y, w, h), _ = state.layout(io.display_size.x, io.display_size.y)
    imgui.set_next_window_pos(imgui.ImVec2(x + w * 0.5, y + h * 0.5), imgui.Cond_.always, imgui.ImVec2(0.5, 0.5))
    imgui.set_next_window_bg_alpha(0.95)
    flags = _OVERLAY_FLAGS
    imgui.begin("##busy", None, flags)
    imgui.text(state.busy)
    imgui.progress_bar(-1.0 * float(imgui.get_time()), imgui.ImVec2(300, 0), f"{elapsed:.1f} s")
    p, s = imgui.get_window_pos(), imgui.get_window_size()
    state.widget_rects["busy overlay"] = (float(p.x), float(p.y), float(s.x), float(s.y))
    imgui.end()
