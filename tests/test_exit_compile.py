"""Leaving and a background compile (gridrt.trace.twin, gridrt.app.__main__.leave): a dump that
did its work finishes it, Ctrl-C skips that, and the viewer never waits on it.

* A real dump with an empty numba cache (``slow``: it compiles every kernel, minutes on a loaded
  machine): from its second frame on the default build strategy's parallel kernels compile in the
  background (the serial strategy builds meanwhile); the dump ends after its last frame with every
  frame and stats row written, says in one line that it finishes that compile, waits for it and
  exits 0.  The next run with the same cache folder
  compiles nothing (the cache files stay as they were) and writes the same images.
* The same dump with Ctrl-C while it finishes the compile (``slow``): status 0, the frames
  written, the one-line notice that it did not wait; a second run with the same cache folder works
  (the cache the abandoned compile left is consistent) and writes the same images.  The Ctrl-C
  tests start their child with SIGINT at its default: a test worker can run with it ignored, and a
  child would inherit that.
* The exit path itself, in a subprocess with a stand-in compile that would run for ten minutes:
  without ``finish`` (the viewer's), or with it after a failed run, the notice, the status, the
  output written before it, and no wait; with ``finish`` and status 0, the finishing line and the
  wait for a short stand-in, and Ctrl-C during the wait for a long one: the notice, status 0.
  In-process callers of main (argv given) never leave the process.
* The viewer: Esc under Xvfb with an empty numba cache (``slow``) ends with status 0, with the
  notice when the build's warm-up is still compiling; a render thread still busy with its frame is
  left behind after at most 2 s.
* Twins' background warm-up compiling a real numba kernel runs on a daemon thread, is listed by
  ``compiling()`` while it runs, and ``wait()`` still waits for it (the benchmarks' and tests' use).
"""

import csv
import os
import shutil
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
from helpers.cli import cache_files

REPO = Path(__file__).resolve().parents[1]
NOTICE = "gridrt: not waiting for the background compile of "
FINISHING = "gridrt: finishing the background compile of "


def sigint_default():
    """(preexec_fn) The child's SIGINT back to the default, so that Python turns it into
    KeyboardInterrupt: a child inherits an ignored SIGINT, and a test worker can run with one."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def run(args, env=None, timeout=900):
    return subprocess.run([sys.executable, *args], cwd=REPO, capture_output=True, text=True, timeout=timeout,
                          env={**os.environ, **(env or {})})


def frames_complete(out, n):
    """The dump folder holds frames 0..n-1, each a whole PNG with its stats row."""
    from PIL import Image

    names = sorted(p.name for p in out.glob("frame_*.png"))
    assert names == [f"frame_{i:05d}.png" for i in range(n)]
    images = []
    for name in names:
        with Image.open(out / name) as im:
            im.load()
            images.append(np.asarray(im))
    with open(out / "stats.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert [int(r["frame"]) for r in rows] == list(range(n))
    return images


DUMP = ["-m", "gridrt", "dump", "--scene", "icosphere", "--animate", "twist", "--frames", "4", "--size", "16x12",
        "--threads", "2", "--traversal", "dda", "--no-progress"]


@pytest.mark.slow
def test_dump_with_a_cold_cache_finishes_the_background_compile(tmp_path):
    cache = tmp_path / "cache"
    env = {"NUMBA_CACHE_DIR": str(cache)}
    r = run(DUMP + ["--out", str(tmp_path / "a")], env)
    assert r.returncode == 0, r.stderr
    assert "Traceback" not in r.stderr
    lines = r.stderr.splitlines()
    assert [ln for ln in lines if ln.startswith(FINISHING)] == [
        FINISHING + "sort_first build for later runs (Ctrl-C skips it)"], r.stderr
    assert not any(ln.startswith(NOTICE) for ln in lines), r.stderr
    assert "wrote 4 frames" in r.stdout
    first = frames_complete(tmp_path / "a", 4)
    written = cache_files(cache)
    assert any(p.name.startswith("sort_first.count_slabs-") and p.suffix == ".nbi" for p in written), sorted(written)
    # the same cache again: the parallel kernels load, nothing compiles
    r = run(DUMP + ["--out", str(tmp_path / "b")], env)
    assert r.returncode == 0, r.stderr
    assert "Compiling numba kernels" not in r.stderr and FINISHING not in r.stderr and NOTICE not in r.stderr, r.stderr
    assert cache_files(cache) == written
    second = frames_complete(tmp_path / "b", 4)
    assert all(np.array_equal(a, b) for a, b in zip(first, second))


@pytest.mark.slow
def test_ctrl_c_skips_the_finishing_compile(tmp_path):
    """Two frames: the background compile starts with the second, the last, so the dump says it is
    finishing that compile while the compile has only begun (a compile takes seconds, a 16x12
    frame milliseconds), and Ctrl-C comes while it runs, however loaded the machine."""
    cache = tmp_path / "cache"
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache)}
    dump = list(DUMP)
    dump[dump.index("--frames") + 1] = "2"
    p = subprocess.Popen([sys.executable, *dump, "--out", str(tmp_path / "a")], cwd=REPO, env=env, text=True,
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, preexec_fn=sigint_default)
    try:
        seen = []
        for line in p.stderr:
            seen.append(line)
            if line.startswith(FINISHING):
                p.send_signal(signal.SIGINT)
                break
        _, err = p.communicate(timeout=600)
    finally:
        p.kill()
    err = "".join(seen) + err
    assert p.returncode == 0, err
    assert NOTICE + "sort_first build (it compiles again next start)" in err.splitlines(), err
    assert "Traceback" not in err
    first = frames_complete(tmp_path / "a", 2)
    # the same cache again: whatever the abandoned compile left, the run loads or compiles cleanly
    r = run(dump + ["--out", str(tmp_path / "b")], {"NUMBA_CACHE_DIR": str(cache)})
    assert r.returncode == 0, r.stderr
    assert "Traceback" not in r.stderr and "error" not in r.stderr.lower(), r.stderr
    second = frames_complete(tmp_path / "b", 2)
    assert all(np.array_equal(a, b) for a, b in zip(first, second))


STAND_IN = """
import sys, threading, time
from gridrt.trace.twin import TWINS
from gridrt.app.__main__ import leave

def compile_():
    time.sleep({seconds})
    print("compiled", flush=True)

job = threading.Thread(target=compile_, daemon=True)
job.kernel = "sort_first build"
TWINS._compiling[("stand-in",)] = job
job.start()
print("the frames are written", flush=False)
sys.exit(leave({code}, finish={finish}))
"""


@pytest.mark.parametrize("code", [0, 3])
def test_leave_does_not_wait_for_a_compile(code):
    r = run(["-c", textwrap.dedent(STAND_IN.format(code=code, seconds=600, finish=False))],
            timeout=300)  # (it would take 600 s to wait)
    assert r.returncode == code, r.stderr
    assert r.stdout == "the frames are written\n"  # (flushed before leaving)
    assert r.stderr == NOTICE + "sort_first build (it compiles again next start)\n"


def test_leave_after_a_dump_waits_for_a_compile():
    """finish and status 0 (a dump that did its work): the finishing line, then the wait (a stand-in
    of 2 s, which prints when done: a daemon thread, it would be cut short by an exit that did not
    wait for it); a failed run (status 2) does not wait on a ten-minute one."""
    r = run(["-c", textwrap.dedent(STAND_IN.format(code=0, seconds=2, finish=True))], timeout=300)
    assert r.returncode == 0, r.stderr
    assert r.stdout == "the frames are written\ncompiled\n"
    assert r.stderr == FINISHING + "sort_first build for later runs (Ctrl-C skips it)\n"
    r = run(["-c", textwrap.dedent(STAND_IN.format(code=2, seconds=600, finish=True))], timeout=300)
    assert r.returncode == 2, r.stderr
    assert r.stderr == NOTICE + "sort_first build (it compiles again next start)\n"


def test_ctrl_c_skips_the_finishing_wait():
    """finish and status 0 with a ten-minute stand-in compile: the finishing line, then Ctrl-C cuts
    the wait short: the one-line notice that it does not wait, status 0, at once."""
    p = subprocess.Popen([sys.executable, "-c", textwrap.dedent(STAND_IN.format(code=0, seconds=600, finish=True))],
                         cwd=REPO, text=True, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                         preexec_fn=sigint_default)
    try:
        line = p.stderr.readline()
        assert line == FINISHING + "sort_first build for later runs (Ctrl-C skips it)\n", line
        p.send_signal(signal.SIGINT)
        out, err = p.communicate(timeout=300)  # (it would take 600 s to wait)
    finally:
        p.kill()
    assert p.returncode == 0, err
    assert out == "the frames are written\n"
    assert err == NOTICE + "sort_first build (it compiles again next start)\n"


def test_leave_without_a_compile_and_in_process():
    import gc

    from gridrt.app.__main__ import leave, main
    from gridrt.trace.twin import TWINS

    assert TWINS.compiling() == []
    assert leave(5) == 5
    # main with arguments runs in-process and returns its status (it never ends the process) and
    # leaves the garbage collector as it was
    frozen = gc.get_freeze_count()
    assert main(["strategies"]) == 0
    assert gc.get_freeze_count() == frozen


def test_the_program_freezes_the_collector_once_its_work_is_done():
    """Run as the program, main freezes the garbage collector after the command (the shutdown then
    searches no object for cycles); what the command printed is all there."""
    r = run(["-c", textwrap.dedent("""
        import atexit, gc, sys
        atexit.register(lambda: print("frozen before exit:", gc.get_freeze_count() > 0))
        from gridrt.app.__main__ import main
        print("frozen before main:", gc.get_freeze_count() > 0)
        sys.argv = ["gridrt", "strategies"]
        sys.exit(main())
    """)], timeout=300)
    assert r.returncode == 0, r.stderr
    lines = r.stdout.splitlines()
    assert lines[0] == "frozen before main: False" and lines[-1] == "frozen before exit: True"
    from gridrt.grid.registry import names

    assert [line.split()[0] for line in lines[2:-1]] == list(names())


def test_background_compile_is_a_daemon_and_listed():
    from numba import njit, prange

    from gridrt.trace.twin import Twins

    @njit(parallel=True)
    def twice(a):
        for i in prange(a.shape[0]):
            a[i] *= 2.0

    tw = Twins()
    a = np.ones(8)
    assert tw.warm(("twice",), "twice", lambda: twice(a), True) is False  # starts the background compile
    jobs = list(tw._compiling.values())
    assert len(jobs) == 1 and jobs[0].daemon
    assert tw.compiling() in (["twice"], [])
    tw.wait()
    assert tw.compiling() == [] and not jobs[0].is_alive()
    assert tw.warm(("twice",), "twice", lambda: twice(a), True) is True  # warm now: the job does not run again
    assert len(twice.signatures) == 1
    np.testing.assert_array_equal(a, 2.0)


def test_viewer_leaves_without_a_busy_render_thread(capsys):
    """The viewer's exit (after Esc, the window gone): a render thread still busy with its frame
    (here a pipeline that would take ten minutes to make) is left behind after STOP_WAIT_S (at most
    2 s) with one line; an idle one stops.  (The window itself needs Xvfb: tests/test_viewer.py.)"""
    import threading

    from gridrt.app.viewer.state import SceneSpec
    from gridrt.app.viewer.view import STOP_WAIT_S, Viewer
    from gridrt.app.viewer.worker import LoadJob, RenderWorker
    from gridrt.config import GridParams, RenderParams
    from gridrt.frame import FrameSpec

    assert STOP_WAIT_S <= 2.0
    started, release = threading.Event(), threading.Event()

    def slow_pipeline(scene, job):
        started.set()
        release.wait(600)

    worker = RenderWorker(slow_pipeline)
    worker.submit(LoadJob(FrameSpec(scene=SceneSpec(source="icosphere"), grid=GridParams(threads=1),
                                    render=RenderParams(threads=1)).resized(8, 6)))
    assert started.wait(300)
    try:
        assert Viewer._stop_worker(None, worker) is False
        err = capsys.readouterr().err
        assert err == ("gridrt view: not waiting for the render thread (still rendering or compiling a frame); "
                       "exiting without it\n")
    finally:
        release.set()
    idle = RenderWorker(slow_pipeline)
    assert Viewer._stop_worker(None, idle) is True
    assert capsys.readouterr().err == ""


@pytest.mark.slow
@pytest.mark.skipif(shutil.which("Xvfb") is None or shutil.which("xdotool") is None,
                    reason="needs Xvfb and xdotool (apt-get install xvfb xauth xdotool)")
def test_viewer_esc_with_a_cold_cache(tmp_path, monkeypatch):
    """The viewer on 2 threads with an empty numba cache (tests/test_viewer.py's Xvfb harness):
    after its first frames (the default build strategy's warm-up compiles in the background from
    the second on, gridrt.grid.build) Esc ends it with status 0, and with the notice that it did
    not wait for that compile when it was still running."""
    from helpers.viewer import _App, _X

    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "cache"))
    x = _X()
    app = None
    try:
        app = _App(x.display, tmp_path, extra=("--threads", "2", "--traversal", "dda"))
        app.wait(lambda s: s["rendered_frames"] >= 3, "the first frames", timeout=900)
        app.xdo("key", "Escape")
        assert app.proc.wait(120) == 0, app.output()
        out = app.output()
        notices = [line for line in out.splitlines() if line.startswith(NOTICE)]
        assert notices in ([NOTICE + "sort_first build (it compiles again next start)"], []), out
        assert "Traceback" not in out
    finally:
        if app is not None:
            app.close()
        x.close()
