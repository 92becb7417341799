"""Running the viewer's App headless under Xvfb."""

import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from PIL import Image


REPO = Path(__file__).resolve().parents[2]


W, H = 640, 480


def _app_env(**extra):
    env = dict(os.environ)
    env["PYTHONPATH"] = str(REPO) + os.pathsep + env.get("PYTHONPATH", "")
    env.update(extra)
    return env


# ---------------------------------------------------------------------------------------------
class _X:
    """An Xvfb server on a free display number."""

    def __init__(self):
        r, w = os.pipe()
        self.proc = subprocess.Popen(["Xvfb", "-displayfd", str(w), "-screen", "0", "1024x768x24", "-nolisten", "tcp"],
                                     pass_fds=(w,), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        os.close(w)
        buf = b""
        t0 = time.time()
        while not buf.endswith(b"\n") and time.time() - t0 < 20:
            chunk = os.read(r, 16)
            if not chunk:
                break
            buf += chunk
        os.close(r)
        if not buf.strip():
            self.proc.kill()
            raise RuntimeError("Xvfb did not report a display number")
        self.display = ":" + buf.decode().strip()

    def close(self):
        self.proc.terminate()
        try:
            self.proc.wait(10)
        except subprocess.TimeoutExpired:
            self.proc.kill()


class _App:
    def __init__(self, display, tmp, scene=("--scene", "marbles", "--count", "2000"), extra=()):
        self.display = display
        self.cwd = tmp / "cwd"
        self.cwd.mkdir()
        self.shots = tmp / "shots"
        self.state_file = tmp / "state.json"
        self.log = open(tmp / "app.log", "w+")
        cmd = [sys.executable, "-m", "gridrt", "view", *scene, "--size", f"{W}x{H}",
               "--state-file", str(self.state_file), "--screenshot-dir", str(self.shots), *extra]
        self.proc = subprocess.Popen(cmd, cwd=self.cwd, env=_app_env(DISPLAY=display), stdout=self.log,
                                     stderr=subprocess.STDOUT, text=True)

    def output(self):
        self.log.flush()
        self.log.seek(0)
        return self.log.read()

    def state(self):
        try:
            return json.loads(self.state_file.read_text())
        except (FileNotFoundError, json.JSONDecodeError):
            return None

    def wait(self, pred, what, timeout=30.0):
        t0 = time.time()
        while time.time() - t0 < timeout:
            s = self.state()
            if s is not None and pred(s):
                return s
            if self.proc.poll() is not None:
                raise AssertionError(f"viewer exited ({self.proc.returncode}) waiting for {what}:\n{self.output()}")
            time.sleep(0.05)
        raise AssertionError(f"timed out waiting for {what}; last state: {self.state()}\n{self.output()}")

    def settled(self, what, quiet=0.6, timeout=30.0):
        """Wait until no new frame has been rendered for ``quiet`` seconds; return the state."""
        t0 = time.time()
        last = self.wait(lambda s: True, what)
        since = time.time()
        while time.time() - t0 < timeout:
            time.sleep(0.05)
            s = self.state()
            if s["rendered_frames"] != last["rendered_frames"] or s["busy"]:
                last, since = s, time.time()
            elif time.time() - since >= quiet:
                return s
        raise AssertionError(f"frames never settled ({what}): {self.state()}")

    def xdo(self, *args):
        r = subprocess.run(["xdotool", *map(str, args)], env=_app_env(DISPLAY=self.display), capture_output=True,
                           text=True, timeout=30)
        assert r.returncode == 0, r.stderr
        return r.stdout

    def scroll_to(self, state, name):
        """Wheel notches over the panel until widget ``name`` lies inside it (the panel scrolls in a
        window shorter than itself); the state it then shows."""
        for _ in range(12):
            x, y, w, h = state["widget_rects"][name]
            px, py, pw, ph = state["panel_rect"]
            if py <= y and y + h <= py + ph:
                return state
            notch = 5 if y + h > py + ph else 4
            self.xdo("mousemove", int(px + pw / 2), int(py + ph / 2), "sleep", 0.2, "click", notch, "sleep", 0.3)
            frames = self.state()["ui_frames"]
            state = self.wait(lambda q: q["ui_frames"] > frames + 1, f"the panel scrolled towards {name}")
        return state

    def click(self, state, name, fx=0.5, hold=None):
        """Click widget ``name`` of ``state``; with ``hold`` (seconds) the pointer rests on it that
        long before the button goes down and the button stays down that long, as a person's click
        does (a viewer whose frames are slow, while numba compiles in the background, sees both)."""
        x, y, w, h = state["widget_rects"][name]
        px, py, pw, ph = state["panel_rect"]
        assert px <= x and x + w <= px + pw and py <= y and y + h <= py + ph, f"{name} not visible in the panel"
        at = (int(x + min(max(fx * w, 3), w - 3)), int(y + h / 2))
        if hold is None:
            self.xdo("mousemove", *at, "sleep", 0.15, "click", 1)
        else:
            self.xdo("mousemove", *at, "sleep", hold, "mousedown", 1, "sleep", hold, "mouseup", 1)

    def pick(self, combo, item, timeout=120.0):
        """Open the combo ``combo`` and click its item ``item`` ("combo: item" in the state's
        widget rects) until the state says ``combo`` is ``item``; returns that state."""
        t0 = time.time()
        key = f"{combo}: {item}"
        while time.time() - t0 < timeout:
            s = self.state()
            if s is not None and s.get(combo) == item:
                return s
            if s is not None and key in s["widget_rects"]:
                self.click(s, key, hold=0.3)
            elif s is not None and combo in s["widget_rects"]:
                self.click(s, combo, hold=0.3)
            time.sleep(1.0)
        raise AssertionError(f"timed out picking {item} in {combo}; last state: {self.state()}\n{self.output()}")

    def close(self):
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(10)
        self.log.close()


def _dist(cam):
    return float(np.linalg.norm(np.subtract(cam["eye"], cam["target"])))


def _headless_frame(scene, s, width, height):
    """(pipeline, frame): a headless FramePipeline over ``scene`` with the grid and render settings of
    the viewer's state ``s`` (as the state file has it) at width x height, and its frame at the time
    and camera of ``s``."""
    from gridrt.camera import Camera
    from gridrt.config import GridParams, RenderParams
    from gridrt.pipeline import FramePipeline

    st, cam = s["stats"], s["camera"]
    pipe = FramePipeline(scene,
                         GridParams(strategy=st["strategy"], threads=st["threads"], density=s["density"],
                                    macro=s["macro"], insert=s["insert"], grid=s["grid"],
                                    top_density=s["top_density"], leaf_density=s["leaf_density"]),
                         RenderParams(width=width, height=height, shading=s["shading"], shadows=s["shadows"],
                                      watertight=s["watertight"], threads=st["threads"], traversal=s["traversal"],
                                      packet=tuple(s["packet"]), packet_precision=s["packet_precision"]))
    return pipe, pipe.step(st["t"], camera=Camera(cam["eye"], cam["target"], cam["up"], cam["fov"]))


def _check_scene_image(img):
    """A ray-traced marbles frame: background and lit geometry, many distinct colours."""
    from gridrt.trace.render import BACKGROUND

    bg = np.round(np.asarray(BACKGROUND) * 255).astype(np.uint8)
    is_bg = np.all(img[..., :3] == bg, axis=-1)
    assert 0.05 < is_bg.mean() < 0.95, is_bg.mean()
    lum = img[~is_bg][:, :3].astype(float).mean(axis=-1)
    assert lum.std() > 5
    assert len(np.unique(img.reshape(-1, img.shape[-1]), axis=0)) > 50


class _Run(_App):
    """A viewer under Xvfb like _App, on a command line of the test's own: ``gridrt view`` with
    ``args`` and --state-file, started in the folder ``cwd``; its state file and log lie in
    ``tmp``, not in ``cwd``."""

    def __init__(self, display, tmp, cwd, args):
        tmp.mkdir(parents=True, exist_ok=True)
        self.display, self.cwd, self.shots = display, cwd, None
        self.state_file = tmp / "state.json"
        self.log = open(tmp / "app.log", "w+")
        cmd = [sys.executable, "-m", "gridrt", "view", *args, "--state-file", str(self.state_file)]
        self.proc = subprocess.Popen(cmd, cwd=cwd, env=_app_env(DISPLAY=display), stdout=self.log,
                                     stderr=subprocess.STDOUT, text=True)


def _first_frame(app, w, h):
    """The state once the viewer shows its first frame at w x h (the panel's state settled)."""
    return app.wait(lambda q: q["rendered_frames"] >= 1 and q["camera"] and q["stats"].get("width") == w
                    and q["stats"].get("height") == h and q["ui_frames"] >= 3, "the first frame", timeout=180)


def _laid_out(app, s):
    """A state two frames after ``s``: the panel laid out again (after a screenshot, the state that
    first names it has the widgets of the frame before the message with its path)."""
    return app.wait(lambda q: q["ui_frames"] > s["ui_frames"] + 1, "the panel laid out again")


def _png(path):
    return np.asarray(Image.open(path).convert("RGB"))


def _quit(app):
    """Esc; the viewer ends with status 0.  Its output."""
    app.xdo("key", "Escape")
    assert app.proc.wait(30) == 0, app.output()
    return app.output()


needs_x = pytest.mark.skipif(shutil.which("Xvfb") is None or shutil.which("xdotool") is None,
                             reason="needs Xvfb and xdotool (apt-get install xvfb xauth xdotool)")


@pytest.fixture
def xvfb():
    """An Xvfb server for one test; the viewers the test starts on it (``xvfb.start(app)``) are
    killed after it when still running."""
    x = _X()
    apps = []

    def start(app):
        apps.append(app)
        return app

    x.start = start
    try:
        yield x
    finally:
        for app in apps:
            app.close()
        x.close()
