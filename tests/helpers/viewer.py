"""Running the viewer's App headless under Xvfb."""

import json
import os
import subprocess
import sys
import time
from pathlib import Path


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
