"""Mouse and keys -> camera moves and viewer actions.

glfw callbacks only queue events.  :meth:`InputHandler.process` runs in the frame loop after
``imgui.new_frame()``, when ``io.want_capture_mouse`` / ``io.want_capture_keyboard`` describe the
current frame (inside a callback they still hold the previous frame's values), and sends each
event either to the panel (imgui already received it through its chained callbacks) or to the
camera.  A drag belongs to whoever got its button press: the camera gets a press (and the wheel)
only in the image area (``ViewerState.image_rect``), never over the panel's column.

Keys (when the panel does not want the keyboard): left drag orbit, right or middle drag pan,
wheel zoom, W/S forward/back, A/D left/right, Q/E down/up, Shift flies 4x faster, R reset view,
C scene camera on/off, Space play/pause, F12 or P screenshot (into --screenshot-dir), H hide/show
panel (the image then takes the whole window), [ and ] previous/next strategy, - and = fewer/more
threads, Esc quit; and the habits of Embree's and pbrt's viewers: , and . exposure down/up half a
stop (/ back to 0), O the figures overlay on/off, G progressive accumulation on/off, V print the
camera as command-line flags, Ctrl+1..9 keep the view as a bookmark (remembered across runs), 1..9
go back to it, F (or a double click) look at the surface point under the cursor, F11 full screen,
K start/stop recording a video and its camera path.

The scene's own camera (BART, glTF; the panel's "scene camera" box, on by default for a scene that
has one): any camera move (drag, wheel, fly keys) leaves it, starting from the view on screen, as
grabbing the view does in a DCC tool's camera view; C or the box returns to it, and R (Reset view)
returns to it when the scene started on it.
"""

import time
from collections import deque

from gridrt import camera_control as cc

from gridrt.scene import SceneSpec

from .state import EXPOSURE_STEP

#: keys listed in the panel's help line
KEY_HELP = (
    "L-drag orbit | R/M-drag pan | wheel zoom | WASD/QE fly (Shift fast) | R reset | C scene camera | "
    "Space play | P/F12 shot | H panel | [ ] strategy | - = threads | , . / exposure | O overlay | "
    "G accumulate | V print camera | Ctrl+1-9 bookmark, 1-9 go | F/double click focus | F11 full screen | "
    "K record | Esc quit"
)
#: two presses of the left button within this many seconds (and DOUBLE_CLICK_PX pixels) are a double click
DOUBLE_CLICK_S, DOUBLE_CLICK_PX = 0.35, 4.0
#: wheel notch -> distance factor
ZOOM_STEP = 0.85
#: fly speed in scene radii per second
FLY_SPEED = 0.6


class InputHandler:
    """Installs glfw callbacks on ``window`` (before imgui's backend, which chains to them) and
    applies queued events to ``state`` in :meth:`process`."""

    def __init__(self, glfw, window, state, strategy_names):
        self.glfw = glfw
        self.window = window
        self.state = state
        self.strategy_names = list(strategy_names)
        self.events = deque()
        self.owner = {}        # mouse button -> "ui" | "camera" for the drag in progress
        self.last_pos = tuple(glfw.get_cursor_pos(window))
        self.dropped = []
        self.last_event = 0.0  # perf_counter() of the latest input event
        self.last_press = (-1.0, (0.0, 0.0))   # (time, position) of the last left press on the image
        glfw.set_key_callback(window, self._on_key)
        glfw.set_mouse_button_callback(window, self._on_button)
        glfw.set_cursor_pos_callback(window, self._on_move)
        glfw.set_scroll_callback(window, self._on_scroll)
        glfw.set_drop_callback(window, self._on_drop)

    # ---- callbacks: queue only ------------------------------------------------------------
    def _on_key(self, win, key, scancode, action, mods):
        self.last_event = time.perf_counter()
        self.events.append(("key", key, action, mods))

    def _on_button(self, win, button, action, mods):
        self.last_event = time.perf_counter()
        self.events.append(("button", button, action, mods))

    def _on_move(self, win, x, y):
        self.last_event = time.perf_counter()
        self.events.append(("move", x, y, 0))

    def _on_scroll(self, win, dx, dy):
        self.last_event = time.perf_counter()
        self.events.append(("scroll", dx, dy, 0))

    def _on_drop(self, win, paths):
        self.last_event = time.perf_counter()
        self.dropped.extend(paths)

    # ---- frame loop ----------------------------------------------------------------------
    def process(self, io, dt):
        """Apply queued events and held keys for this frame (dt seconds since the last one)."""
        glfw = self.glfw
        st = self.state
        ui_mouse = bool(io.want_capture_mouse) and st.show_panel
        ui_keys = bool(io.want_capture_keyboard) and st.show_panel
        while self.events:
            kind, a, b, mods = self.events.popleft()
            if kind == "button":
                if b == glfw.PRESS:
                    self.owner[a] = "ui" if ui_mouse or not st.in_image(*self.last_pos) else "camera"
                    if a == glfw.MOUSE_BUTTON_LEFT and self.owner[a] == "camera":
                        self._double_click()
                elif b == glfw.RELEASE:
                    self.owner.pop(a, None)
            elif kind == "move":
                self._drag(a, b)
            elif kind == "scroll":
                if not ui_mouse and st.in_image(*self.last_pos) and st.camera is not None and b != 0:
                    st.leave_scene_camera()
                    st.camera = cc.dolly(st.camera, ZOOM_STEP ** b)
            elif kind == "key" and b in (glfw.PRESS, glfw.REPEAT) and not ui_keys:
                self._key(a, b, mods)
        if self.dropped:
            st.scene_request = SceneSpec(source=str(self.dropped[-1]), allow_outside=st.file_allow_outside)
            st.file_text = self.dropped[-1]
            self.dropped.clear()
        if not ui_keys:
            self._fly(dt)

    def _double_click(self):
        now, pos = time.perf_counter(), self.last_pos
        t, p = self.last_press
        if now - t <= DOUBLE_CLICK_S and abs(pos[0] - p[0]) <= DOUBLE_CLICK_PX and abs(pos[1] - p[1]) <= DOUBLE_CLICK_PX:
            self.state.focus_request = pos
            now = -1.0   # a third click starts a new pair
        self.last_press = (now, pos)

    def _key(self, key, action, mods):
        glfw = self.glfw
        st = self.state
        if action == glfw.REPEAT and key not in (glfw.KEY_LEFT_BRACKET, glfw.KEY_RIGHT_BRACKET,
                                                 glfw.KEY_MINUS, glfw.KEY_EQUAL, glfw.KEY_COMMA, glfw.KEY_PERIOD):
            return
        if key == glfw.KEY_ESCAPE:
            st.quit = True
        elif key == glfw.KEY_SPACE:
            st.playing = not st.playing
        elif key in (glfw.KEY_F12, glfw.KEY_P):
            st.want_shot = True
        elif key == glfw.KEY_H:
            st.toggle_panel()
        elif key == glfw.KEY_R:
            st.reset_view()
        elif key == glfw.KEY_C:
            st.set_scene_camera(not st.follow_camera)
        elif key == glfw.KEY_LEFT_BRACKET:
            st.cycle_strategy(self.strategy_names, -1)
        elif key == glfw.KEY_RIGHT_BRACKET:
            st.cycle_strategy(self.strategy_names, +1)
        elif key in (glfw.KEY_MINUS, glfw.KEY_KP_SUBTRACT):
            st.change_threads(-1)
        elif key in (glfw.KEY_EQUAL, glfw.KEY_KP_ADD):
            st.change_threads(+1)
        elif key == glfw.KEY_COMMA:
            st.change_exposure(-EXPOSURE_STEP)
        elif key == glfw.KEY_PERIOD:
            st.change_exposure(+EXPOSURE_STEP)
        elif key == glfw.KEY_SLASH:
            st.change_exposure(None)
        elif key == glfw.KEY_O:
            st.show_overlay = not st.show_overlay
        elif key == glfw.KEY_G:
            st.accumulate = not st.accumulate
        elif key == glfw.KEY_V:
            st.want_camera_print = True
        elif glfw.KEY_1 <= key <= glfw.KEY_9:
            if mods & glfw.MOD_CONTROL:
                st.bookmark_store = key - glfw.KEY_0
            else:
                st.bookmark_recall = key - glfw.KEY_0
        elif key == glfw.KEY_F:
            if st.in_image(*self.last_pos):
                st.focus_request = self.last_pos
        elif key == glfw.KEY_F11:
            st.want_fullscreen = True
        elif key == glfw.KEY_K:
            st.want_record = True

    def _drag(self, x, y):
        """The cursor moved to (x, y): orbit or pan for each drag the camera owns."""
        glfw = self.glfw
        st = self.state
        last, self.last_pos = self.last_pos, (x, y)
        if st.camera is None:
            return
        dx, dy = x - last[0], y - last[1]
        if dx == 0 and dy == 0:
            return
        h = max(glfw.get_window_size(self.window)[1], 1)
        if self.owner.get(glfw.MOUSE_BUTTON_LEFT) == "camera":
            st.leave_scene_camera()
            st.camera = cc.orbit_from_drag(st.camera, dx, dy, h)
        elif "camera" in (self.owner.get(glfw.MOUSE_BUTTON_RIGHT), self.owner.get(glfw.MOUSE_BUTTON_MIDDLE)):
            st.leave_scene_camera()
            st.camera = cc.pan(st.camera, dx, dy, h)

    def _fly(self, dt):
        glfw = self.glfw
        st = self.state
        if st.camera is None or dt <= 0:
            return
        down = lambda k: glfw.get_key(self.window, k) == glfw.PRESS  # noqa: E731
        f = down(glfw.KEY_W) - down(glfw.KEY_S)
        r = down(glfw.KEY_D) - down(glfw.KEY_A)
        u = down(glfw.KEY_E) - down(glfw.KEY_Q)
        if f or r or u:
            self.last_event = time.perf_counter()   # a held key keeps the loop awake
            fast = 4.0 if (down(glfw.KEY_LEFT_SHIFT) or down(glfw.KEY_RIGHT_SHIFT)) else 1.0
            step = FLY_SPEED * st.scene_radius * fast * min(dt, 0.1)
            st.leave_scene_camera()
            st.camera = cc.fly(st.camera, f * step, r * step, u * step)

