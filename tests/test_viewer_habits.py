"""The viewer habits users bring from Embree's tutorial viewer and pbrt-v4's viewer, checked against
references of their own: exact sub-pixel jitter (the camera-ray formula), progressive
accumulation (its mean, and a supersampled render it converges towards), exposure (the light
ratio of a stop), the camera printed as flags (parsed back by the real parser, rendered by the
dump), bookmarks across runs, focus picking (a float64 brute-force cast of the pixel's ray), full
screen (the X screen's size), recording (the video decoded again) and ``--benchmark`` (the
dump's stats.csv of the same frames).
"""

import csv
import json
import math
import re
import subprocess
import sys

import numpy as np
import pytest

import gridrt  # noqa: F401  (sets NUMBA_NUM_THREADS before numba loads)
from gridrt.app.viewer.accumulate import Accumulator, jitter
from gridrt.app.viewer.blit import exposed
from gridrt.app.viewer.bookmarks import camera_flags, load_bookmarks, save_bookmark
from gridrt.app.viewer.prefs import load_prefs
from gridrt.app.viewer.record import Recorder, video_writer_available
from gridrt.camera import Camera
from gridrt.errors import InputError
from helpers.viewer import (
    REPO, H, W, _App, _app_env, _first_frame, _png, _quit, _Run, needs_x, xvfb,  # noqa: F401  (xvfb: a fixture)
)

@pytest.fixture(autouse=True)
def config_home(tmp_path, monkeypatch):
    """The viewers' config folder (bookmarks, the panel): a fresh one per test, never the user's."""
    d = tmp_path / "config"
    monkeypatch.setenv("GRIDRT_CONFIG_HOME", str(d))
    return d


CAM = Camera(eye=(1.0, 2.0, 5.0), target=(0.1, -0.2, 0.3), up=(0.0, 1.0, 0.2), fov=50.0)


def _pixel_dirs(cam, w, h, ox=0.0, oy=0.0):
    """The camera-ray formula of gridrt.camera's docstring, in numpy, through the points
    (x + 0.5 + ox, y + 0.5 + oy) of each pixel: (h, w, 3) unit directions."""
    eye, tgt, up = (np.asarray(v, float) for v in (cam.eye, cam.target, cam.up))
    fwd = (tgt - eye) / np.linalg.norm(tgt - eye)
    right = np.cross(fwd, up)
    right /= np.linalg.norm(right)
    upp = np.cross(right, fwd)
    th = math.tan(math.radians(cam.fov) / 2)
    x, y = np.meshgrid(np.arange(w) + 0.5 + ox, np.arange(h) + 0.5 + oy)
    sx = (2 * x / w - 1) * th * w / h
    sy = (1 - 2 * y / h) * th
    d = fwd + sx[..., None] * right + sy[..., None] * upp
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


@pytest.mark.parametrize("jx, jy", [(0.25, -0.4), (-0.5, 0.5), (0.49, 0.0)])
def test_jittered_camera_rays(jx, jy):
    """Camera.jittered moves every ray to the point (x + 0.5 + jx, y + 0.5 + jy) of its pixel."""
    w, h = 37, 23
    _, d = CAM.jittered(w, h, jx, jy).rays(w, h)
    assert np.allclose(d.reshape(h, w, 3), _pixel_dirs(CAM, w, h, jx, jy), rtol=0, atol=1e-13)
    _, d0 = CAM.rays(w, h)
    assert np.allclose(d0.reshape(h, w, 3), _pixel_dirs(CAM, w, h), rtol=0, atol=1e-13)
    moved = CAM.jittered(w, h, jx, jy).moved((3.0, -1.0, 2.0))
    assert moved.shift == CAM.jittered(w, h, jx, jy).shift
    for bad in ((math.nan, 0.0), (1.0,), "ab", (1e7, 0.0)):
        with pytest.raises(InputError, match="camera shift"):
            CAM.replace(shift=bad)


def test_accumulator_mean_and_offsets():
    """The first sample is centred, the next ones are distinct points of the pixel square; the
    image shown is the mean of the samples of one frame rounded half up, and a new frame starts
    again."""
    offs = [jitter(k) for k in range(64)]
    assert offs[0] == (0.0, 0.0)
    assert len(set(offs)) == 64 and all(-0.5 <= a < 0.5 and -0.5 <= b < 0.5 for a, b in offs)
    # evenly spread: each quarter of the pixel gets a quarter of the 64 samples, give or take the centre
    quarters = [(a >= 0) * 2 + (b >= 0) for a, b in offs]
    assert all(15 <= n <= 17 for n in np.bincount(quarters, minlength=4))
    sixteenths = [int((a + 0.5) * 4) * 4 + int((b + 0.5) * 4) for a, b in offs]
    assert all(3 <= n <= 5 for n in np.bincount(sixteenths, minlength=16))
    rng = np.random.default_rng(3)
    imgs = rng.integers(0, 256, (5, 4, 6, 4), dtype=np.uint8)
    acc = Accumulator(max_samples=5)
    for i, img in enumerate(imgs):
        assert acc.next_jitter("a") == jitter(i)
        shown = acc.add("a", img)
    assert acc.next_jitter("a") is None   # complete
    assert np.array_equal(shown, np.floor(imgs.astype(float).mean(axis=0) + 0.5).astype(np.uint8))
    assert np.array_equal(acc.add("b", imgs[0]), imgs[0]) and acc.count == 1
    assert acc.next_jitter("c") == (0.0, 0.0) and acc.count == 0


def test_exposure_is_a_light_ratio():
    """A stop doubles the linear light (gamma 2.2) of every channel below white; 0 stops is the
    image itself; +1 then -1 gives the image back within rounding."""
    c = np.arange(256, dtype=np.uint8)
    img = np.stack([c, c[::-1], c, np.full(256, 200, np.uint8)], axis=-1)[None]
    assert exposed(img, 0) is img
    up = exposed(img, 1.0)
    assert np.array_equal(up[..., 3], img[..., 3])   # alpha kept
    lin = (img[..., :3] / 255.0) ** 2.2
    want = np.minimum(2 * lin, 1.0)
    got = (up[..., :3] / 255.0) ** 2.2
    step = 2.2 * np.maximum(want, 1e-12) ** (1 - 1 / 2.2) / 255   # one 8-bit step, in linear light
    assert np.all(np.abs(got - want) <= step + 1e-12)
    back = exposed(up, -1.0)
    ok = lin < 0.45   # (not clipped by the first)
    assert np.abs(back[..., :3][ok].astype(int) - img[..., :3][ok].astype(int)).max() <= 1


def test_camera_flags_parse_back():
    """The printed flags, given to gridrt's own parser (dump and view), give the same camera,
    every float bit for bit."""
    from gridrt.app.__main__ import build_parser
    from gridrt.app.cli import camera_from_args

    cam = Camera(eye=(-0.1 / 3, 1e-7, -2.5e3), target=(1 / 7, -0.0, 12.0), up=(0.3, 0.9, -0.1), fov=37.123456789)
    for command in ("dump", "view"):
        a = build_parser().parse_args([command, *camera_flags(cam).split()])
        got = camera_from_args(a)
        assert (got.eye, got.target, got.up, got.fov) == (cam.eye, cam.target, cam.up, cam.fov)


def test_bookmarks_remembered(tmp_path, monkeypatch):
    """Bookmarks are kept per scene (a file by its absolute path) in viewer.json beside the panel's
    settings; entries that are not cameras are left out."""
    monkeypatch.setenv("GRIDRT_CONFIG_HOME", str(tmp_path / "cfg"))
    mesh = tmp_path / "m.obj"
    mesh.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    other = CAM.replace(eye=(0.0, 0.0, 9.0))
    assert save_bookmark("marbles", 1, CAM) and save_bookmark("marbles", 9, other)
    monkeypatch.chdir(tmp_path)
    assert save_bookmark("m.obj", 1, other)
    data = load_prefs()
    assert set(data["bookmarks"]) == {"marbles", str(mesh)}
    assert load_bookmarks("marbles") == {1: CAM, 9: other}
    assert load_bookmarks(str(mesh)) == {1: other} == load_bookmarks("m.obj")
    data["bookmarks"]["marbles"]["2"] = {"eye": [0, 0, 0], "target": [0, 0, 0], "up": [0, 1, 0], "fov": 45}
    data["bookmarks"]["marbles"]["12"] = data["bookmarks"]["marbles"]["1"]
    assert load_bookmarks("marbles", data) == {1: CAM, 9: other}   # eye == target, slot 12: left out
    assert load_bookmarks("cesium_man") == {}


@pytest.mark.parametrize("video", [False, True])
def test_recorder(tmp_path, video):
    """A recording holds every frame added, in order (an MP4 decoded again, or PNGs), and its
    camera path the time and camera of each."""
    if video and not video_writer_available():
        pytest.skip("needs imageio and imageio-ffmpeg (pip install -e '.[video]')")
    rng = np.random.default_rng(0)
    base = rng.integers(0, 256, (6, 8, 3)).repeat(8, 0).repeat(8, 1).astype(np.uint8)   # 48x64, smooth blocks
    frames = [np.roll(base, 8 * i, axis=1) for i in range(5)]
    rec = Recorder(tmp_path / "shots", video=video)
    for i, f in enumerate(frames):
        rec.add(f, 0.5 * i, CAM if i else None)
    path = rec.close()
    assert path.exists() and rec.frames == 5
    if video:
        import imageio.v2 as imageio

        got = [np.asarray(f) for f in imageio.get_reader(str(path))]
    else:
        got = [_png(path / f"frame_{i:05d}.png") for i in range(5)]
        assert sorted(p.name for p in path.iterdir()) == [f"frame_{i:05d}.png" for i in range(5)]
    assert len(got) == 5
    for i, g in enumerate(got):
        err = np.abs(g.astype(int) - frames[i].astype(int)).mean()
        assert err < (12 if video else 1e-9), err   # H.264 is lossy; the PNGs are exact
        assert np.abs(g.astype(int) - frames[(i + 1) % 5].astype(int)).mean() > 3 * max(err, 1)   # in order
    cams = json.loads(rec.camera_path.read_text())["frames"]
    assert [c["t"] for c in cams] == [0.5 * i for i in range(5)] and cams[0]["camera"] is None
    assert cams[1]["camera"] == {"eye": list(CAM.eye), "target": list(CAM.target), "up": list(CAM.up), "fov": CAM.fov}
    assert Recorder(tmp_path / "shots", video=video).path != path   # the next recording: a new name


@pytest.mark.parametrize("args, message", [
    (("--exposure", "9"), "--exposure must be between -8 and 8 stops"),
    (("--exposure", "nan"), "--exposure must be between"),
    (("--benchmark", "1", "0"), "--benchmark needs WARMUP >= 0 and FRAMES >= 1"),
    (("--stats-csv", "x.csv"), "--stats-csv goes with --benchmark"),
])
def test_view_habit_options_refused(tmp_path, args, message):
    """Bad values are refused with one line naming the option, before any window opens."""
    r = subprocess.run([sys.executable, "-m", "gridrt", "view", *args], cwd=tmp_path, capture_output=True, text=True,
                       env=_app_env(DISPLAY=":987"), timeout=120)
    assert r.returncode == 2 and message in r.stderr and "Traceback" not in r.stderr, r.stderr
    assert not (tmp_path / "x.csv").exists()


# ---- under Xvfb ------------------------------------------------------------------------------
def _window(app):
    wid = app.xdo("search", "--sync", "--name", "^gridrt$").split()[0]
    app.xdo("windowfocus", "--sync", wid)


def _key(app, *keys, at=(W // 2, H // 2)):
    app.xdo("mousemove", *at, "sleep", 0.1, *[w for k in keys for w in ("key", k, "sleep", 0.15)])


def _camera(c):
    return Camera(tuple(c["eye"]), tuple(c["target"]), tuple(c["up"]), c["fov"])


def _shot(app, s):
    """A P screenshot taken now: (state, image)."""
    _key(app, "p")
    s = app.wait(lambda q: q["last_screenshot"] and q["last_screenshot"] != s["last_screenshot"], "a screenshot")
    return s, _png(s["last_screenshot"])


@needs_x
@pytest.mark.slow
def test_viewer_camera_exposure_overlay_focus_under_xvfb(tmp_path, xvfb):
    """V prints the camera as flags that make the dump render the viewer's frame pixel for pixel;
    . and , change the exposure by half stops (the screenshot is the shown image: twice the
    light per stop); O shows the frame's figures over the image's corner, as its stats row has
    them; F looks at the surface point under the cursor: the target moves to the float64
    brute-force hit of that pixel's ray, the eye stays."""
    from gridrt.scene import make_scene
    from reference import ref_cast

    app = xvfb.start(_App(xvfb.display, tmp_path, extra=("--paused",)))
    s = _first_frame(app, W, H)
    _window(app)
    s0, exact = _shot(app, s)
    _key(app, "v")
    s = app.wait(lambda q: q["camera_flags"], "the camera printed")
    flags = s["camera_flags"]
    assert f"gridrt view: camera at t=0: {flags}\n" in app.output()
    out = tmp_path / "dump"
    r = subprocess.run([sys.executable, "-m", "gridrt", "dump", "--scene", "marbles", "--count", "2000", "--size",
                        f"{W}x{H}", "--frames", "1", "--no-progress", "--out", str(out), *flags.split()],
                       cwd=tmp_path, env=_app_env(), capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert np.array_equal(_png(out / "frame_00000.png"), exact)

    _key(app, "period", "period")
    s = app.wait(lambda q: q["exposure"] == 1.0, "exposure +1")
    s, bright = _shot(app, s)
    lin0, lin1 = (exact / 255.0) ** 2.2, (bright / 255.0) ** 2.2
    ok = (lin0 > 0.02) & (lin0 < 0.4)
    assert ok.sum() > 1000
    assert np.allclose(lin1[ok] / lin0[ok], 2.0, rtol=0.08)
    _key(app, "comma", "slash")
    app.wait(lambda q: q["exposure"] == 0.0, "exposure back to 0")

    assert not s["show_overlay"] and "figures overlay" not in s["widget_rects"]
    _key(app, "o")
    s = app.wait(lambda q: q["show_overlay"] and "figures overlay" in q["widget_rects"], "the overlay")
    st = s["stats"]
    for figure in (f"{1e3 / st['frame_ms']:.1f} fps", f"{st['mrays']:.2f} Mrays/s", f"build {st['build_ms']:.2f} ms",
                   f"render {st['render_ms']:.2f} ms", f"frame {st['frame_ms']:.2f} ms"):
        assert figure in s["overlay_text"], (figure, s["overlay_text"])
    x, y, w, h = s["widget_rects"]["figures overlay"]
    assert 0 <= x < 20 and 0 <= y < 20 and x + w < 0.7 * W and y + h < H / 3   # the image's top-left corner

    cam = _camera(s["camera"])
    px, py = W // 2 + 17, H // 2 - 9   # a marble, not the floor's centre
    tris = make_scene("marbles", count=2000).triangles_at(0.0).astype(np.float64)
    d = _pixel_dirs(cam, W, H)[py, px]
    ref = ref_cast(tris, np.asarray([cam.eye]), d[None])
    assert ref.tri[0] >= 0
    _key(app, "f", at=(px, py))
    s = app.wait(lambda q: q["focus"], "the focus point")
    want = np.asarray(cam.eye) + ref.t[0] * d
    assert np.allclose(s["focus"], want, rtol=0, atol=1e-5 * ref.t[0])
    assert s["camera"]["eye"] == list(cam.eye) and np.allclose(s["camera"]["target"], want, atol=1e-5 * ref.t[0])
    assert not s["follow_camera"]
    _quit(app)


@needs_x
@pytest.mark.slow
def test_viewer_accumulate_bookmarks_fullscreen_record_under_xvfb(tmp_path, xvfb, config_home):
    """G accumulates sub-pixel samples while nothing moves: the image comes closer to a 4x4
    supersampled render of the same view than the exact frame is, and G again shows the exact
    frame; Ctrl+1 keeps the view, 1 returns to it, also in the next run; F11 fills the X screen
    and returns; K records the frames shown into a video whose frames decode again, with the
    camera path beside it."""
    from gridrt.config import GridParams, RenderParams
    from gridrt.pipeline import FramePipeline
    from gridrt.scene import make_scene

    (tmp_path / "1").mkdir()
    app = xvfb.start(_App(xvfb.display, tmp_path / "1", extra=("--paused",)))
    s = _first_frame(app, W, H)
    _window(app)
    s, exact = _shot(app, s)
    _key(app, "g")
    s = app.wait(lambda q: q["samples"] >= 24, "24 samples", timeout=120)
    s, accumulated = _shot(app, s)
    st, cam = s["stats"], _camera(s["camera"])
    pipe = FramePipeline(make_scene("marbles", count=2000), GridParams(strategy=st["strategy"], threads=st["threads"]),
                         RenderParams(width=4 * W, height=4 * H, threads=st["threads"]))
    big = pipe.step(0.0, camera=cam).image[..., :3].astype(float)
    ref = big.reshape(H, 4, W, 4, 3).mean(axis=(1, 3))
    err_exact, err_acc = np.abs(exact - ref).mean(), np.abs(accumulated - ref).mean()
    assert err_acc < 0.75 * err_exact, (err_acc, err_exact)
    _key(app, "g")
    s = app.wait(lambda q: not q["accumulate"] and q["samples"] == 1, "accumulation off")
    s, again = _shot(app, s)
    assert np.array_equal(again, exact)

    app.xdo("mousemove", 200, 200, "sleep", 0.1, "mousedown", 1, "mousemove", 260, 230, "sleep", 0.1, "mousemove",
            300, 240, "sleep", 0.1, "mouseup", 1)
    app.wait(lambda q: q["camera"]["eye"] != list(cam.eye), "the camera orbited")
    _key(app, "ctrl+1")
    kept = app.wait(lambda q: q["bookmarks"] == [1], "bookmark 1")["camera"]
    assert json.loads((config_home / "viewer.json").read_text())["bookmarks"] == {"marbles": {"1": kept}}
    _key(app, "r")
    app.wait(lambda q: q["camera"]["eye"] == list(cam.eye), "the view reset")
    _key(app, "1")
    s = app.wait(lambda q: q["camera"] == kept, "bookmark 1 back")
    _key(app, "2")
    s = app.wait(lambda q: q["message"].startswith("no bookmark 2"), "no bookmark 2")

    _key(app, "F11")
    s = app.wait(lambda q: q["fullscreen"] and q["window_size"] == [1024, 768]
                 and q["stats"].get("height") == 768, "full screen")
    _key(app, "F11")
    s = app.wait(lambda q: not q["fullscreen"] and q["window_size"][1] == H and q["stats"].get("height") == H,
                 "a window again")

    s, still = _shot(app, s)
    _key(app, "k")
    s = app.wait(lambda q: q["recording"], "recording")
    _key(app, "space")
    app.wait(lambda q: q["rendered_frames"] >= s["rendered_frames"] + 12 and q["time"] > 0.5, "frames while recording",
             timeout=120)
    _key(app, "k", "space")
    s = app.wait(lambda q: q["last_recording"] and not q["recording"], "the recording saved")
    line = next(ln for ln in app.output().splitlines() if ln.startswith("gridrt view: saved recording"))
    n = int(line.split(" (")[1].split()[0])
    assert n >= 6
    path = s["last_recording"]
    cams = json.loads((tmp_path / "1" / "shots" / "gridrt_rec_0000.camera.json").read_text())["frames"]
    assert len(cams) == n and [c["frame"] for c in cams] == list(range(n))
    ts = [c["t"] for c in cams]
    assert ts == sorted(ts) and ts[-1] > ts[0]
    if video_writer_available():
        import imageio.v2 as imageio

        got = [np.asarray(f).astype(int) for f in imageio.get_reader(path)]
        assert len(got) == n and got[0].shape == (H, W, 3)
        assert np.abs(got[0] - still).mean() < 6   # the first frame: the still view (H.264 is lossy)
        last = cams[-1]   # the last frame: the scene at its own time, through its own camera
        pipe = FramePipeline(make_scene("marbles", count=2000),
                             GridParams(strategy=st["strategy"], threads=st["threads"]),
                             RenderParams(width=W, height=H, threads=st["threads"]))
        own = pipe.step(last["t"], camera=_camera(last["camera"])).image[..., :3].astype(int)
        assert np.abs(got[-1] - own).mean() < min(6, np.abs(got[-1] - still).mean()), last
    _quit(app)

    (tmp_path / "2").mkdir()
    app = xvfb.start(_App(xvfb.display, tmp_path / "2", extra=("--paused",)))
    s = _first_frame(app, W, H)
    assert s["bookmarks"] == [1]
    _window(app)
    _key(app, "1")
    app.wait(lambda q: q["camera"] == kept, "bookmark 1 in the next run")
    _quit(app)


@needs_x
@pytest.mark.slow
def test_viewer_benchmark_matches_dump(tmp_path, xvfb):
    """--benchmark WARMUP FRAMES renders the dump's frames (its times), shows each, prints the
    medians of the last FRAMES and exits 0; --stats-csv has the dump's stats.csv columns, with the
    same counts per frame as the dump of the same frames, and the medians printed are those of
    its rows."""
    size = ("--scene", "marbles", "--count", "2000", "--size", "160x120", "--dt", "0.25")
    app = xvfb.start(_Run(xvfb.display, tmp_path / "v", tmp_path, (*size, "--benchmark", "2", "3", "--stats-csv",
                                                                    str(tmp_path / "view.csv"))))
    assert app.proc.wait(180) == 0, app.output()
    r = subprocess.run([sys.executable, "-m", "gridrt", "dump", *size, "--frames", "5", "--no-progress", "--out",
                        str(tmp_path / "dump")], cwd=tmp_path, env=_app_env(), capture_output=True, text=True,
                       timeout=300)
    assert r.returncode == 0, r.stderr
    view = list(csv.DictReader(open(tmp_path / "view.csv")))
    dump = list(csv.DictReader(open(tmp_path / "dump" / "stats.csv")))
    assert list(view[0]) == list(dump[0]) and len(view) == len(dump) == 5
    for a, b in zip(view, dump):
        for col in ("frame", "t", "triangles", "cells", "references", "dims", "width", "height", "strategy", "threads",
                    "hit_fraction", "tests_per_ray", "cells_per_ray", "shading", "traversal", "grid_bytes"):
            assert a[col] == b[col], (col, a[col], b[col])
    assert [float(r["t"]) for r in view] == [0.25 * i for i in range(5)]
    timed = [r for r in view[2:] if r["compiled"] == "0"] or view[2:]
    line = next(ln for ln in app.output().splitlines() if ln.startswith("gridrt view: benchmark of 3 frames"))
    for col, label in (("build_ms", "build"), ("render_ms", "render"), ("frame_ms", "frame")):
        # the line has 2 decimals of the full-precision median; the csv has 6 significant digits
        printed = float(re.search(rf"\b{label} (\d+\.\d\d) ms", line).group(1))
        want = float(np.median([float(r[col]) for r in timed]))
        assert abs(printed - want) <= 0.005 + 1e-5 * want, (col, want, line)


@pytest.mark.slow
def test_accumulation_error_falls_with_still_frames():
    """Headless, the viewer's accumulation (Accumulator + the pipeline's jitter): against a 4x4
    supersampled render of the same view, the mean error falls as still frames add up (1, 4, 16,
    64 samples), the first sample being the exact frame."""
    from gridrt.config import GridParams, RenderParams
    from gridrt.pipeline import FramePipeline
    from gridrt.scene import make_scene

    w, h = 64, 48
    scene = make_scene("marbles", count=2000)
    pipe = FramePipeline(scene, GridParams(threads=2), RenderParams(width=w, height=h, threads=2))
    exact = pipe.step(0.0).image[..., :3]
    cam = pipe.last_camera
    big = FramePipeline(scene, GridParams(threads=2), RenderParams(width=4 * w, height=4 * h, threads=2))
    ref = big.step(0.0, camera=cam).image[..., :3].astype(float).reshape(h, 4, w, 4, 3).mean(axis=(1, 3))
    acc = Accumulator()
    errors = {}
    for k in range(64):
        jit = acc.next_jitter("still")
        shown = acc.add("still", pipe.step(0.0, camera=cam, jitter=jit).image[..., :3])
        if k == 0:
            assert np.array_equal(shown, exact)
        if k + 1 in (1, 4, 16, 64):
            errors[k + 1] = np.abs(shown.astype(float) - ref).mean()
    assert errors[1] > errors[4] > errors[16] > errors[64], errors
    assert errors[64] < 0.5 * errors[1], errors


@needs_x
@pytest.mark.slow
def test_viewer_draws_lights_and_averages_the_draws_under_xvfb(tmp_path, xvfb):
    """--shadows --light-samples 1 on the museum (two lights): each pixel's shadow ray goes to one
    light drawn by its light there; while the view is still the viewer averages draws (its
    samples count up) and the image comes closer to the exact one (the dump with every light, at
    the camera V prints) than one draw (the dump with --light-samples 1) is; the panel's "shadow
    rays" combo set to every light shows the exact frame, pixel for pixel."""
    museum = REPO / "assets" / "museum" / "museum5.aff"
    app = xvfb.start(_App(xvfb.display, tmp_path, scene=("--scene", str(museum)),
                          extra=("--paused", "--shadows", "--light-samples", "1")))
    s = app.wait(lambda q: q["rendered_frames"] >= 1 and q["camera"] and q["stats"].get("width") == W,
                 "the first museum frame", timeout=600)   # a cold cache compiles the material kernels
    assert s["light_samples"] == 1 and s["stats"]["lights"] == 2 and s["stats"]["shadow_rays_per_pixel"] <= 1
    _window(app)
    s = app.wait(lambda q: q["samples"] >= 32, "32 draws averaged", timeout=600)
    s, shown = _shot(app, s)
    _key(app, "v")
    flags = app.wait(lambda q: q["camera_flags"], "the camera printed")["camera_flags"]
    dumps = {}
    for name, extra in (("exact", ()), ("draw", ("--light-samples", "1"))):
        out = tmp_path / name
        r = subprocess.run([sys.executable, "-m", "gridrt", "dump", "--scene", str(museum), "--size", f"{W}x{H}",
                            "--frames", "1", "--no-progress", "--shadows", "--out", str(out), *flags.split(), *extra],
                           cwd=tmp_path, env=_app_env(), capture_output=True, text=True, timeout=600)
        assert r.returncode == 0, r.stderr
        dumps[name] = _png(out / "frame_00000.png").astype(float)
    exact, draw = dumps["exact"], dumps["draw"]
    err_draw, err_shown = np.abs(draw - exact).mean(), np.abs(shown - exact).mean()
    assert err_draw > 0.2 and err_shown < 0.1 * err_draw, (err_shown, err_draw)
    s = app.pick("shadow rays", "every light (exact)")
    s = app.wait(lambda q: q["light_samples"] == 0 and q["samples"] == 1 and q["stats"]["shadow_rays_per_pixel"] > 1,
                 "every light's rays", timeout=300)
    s, again = _shot(app, s)
    assert np.array_equal(again, exact.astype(np.uint8))
    _quit(app)
