"""Renders on any number of threads (gridrt.threads.on_threads) and the background warm-ups of
parallel work (gridrt.trace.twin).

* The DDA render (gridrt.trace.render.dda_render) and the CGT render (gridrt.trace.cgt.cgt_render),
  each one kernel that threads share, with and without shadows, on one grid and a split scene of
  two, write the same image, t, triangle and counter buffers on 1, 2 and 3 threads (the CGT one
  returns the same sums), and give the brute-force float64 caster's hits (tests/reference.py) on
  the primary rays.
* on_threads runs its calls at the same time, in order, raises once all have ended, and works in
  a forked child.
* Twins.warm runs a job once, in the background, reports its failure in the caller's thread, and
  a library program that ends during a warm-up waits for it at exit.
"""

import json
import subprocess
import sys
import textwrap

import numpy as np
import pytest

import reference as R
from conftest import icosphere_tris
from gridrt.camera import Camera
from gridrt.grid import build_grid
from gridrt.trace.grids import grid_arrays
from gridrt.trace.records import Buffers, make_packets, make_shading, make_view
from gridrt.trace.cgt import cgt_render
from gridrt.trace.render import dda_render
from gridrt.trace.traverse import near_all
from gridrt.trace.twin import Twins, parallel_first



def _args(grids, camera, W, H, shadows, shading=0, light=None, off=1e-6, f32=None):
    """Render kernel arguments (gridrt.trace.records), the buffers last; f32 (True / False: the
    CGT kernels' packet precision, with the packet shape; without the far-ray path, as the
    renderer has it for a camera and light near the grids) or None (the DDA kernels)."""
    bufs = Buffers(np.zeros((H, W, 4), np.uint8), np.zeros((H, W), np.float32), np.zeros((H, W), np.int32),
                   np.zeros((H, W), np.int32), np.zeros((H, W), np.int32))
    prec = () if f32 is None else (make_packets(f32, 8, 8, far=False),)
    looks = make_shading(shading, shadows, off, True)
    return (grids, make_view(camera.basis(), W, H, 16), looks, light) + prec + (bufs,)


def _scene():
    tris = icosphere_tris(3, radius=1.0)
    moving = icosphere_tris(2, radius=0.4) + np.float32(0.9)
    both = np.concatenate([tris, moving])
    g_a = build_grid(tris, origin=np.zeros(3))
    g_b = build_grid(moving, origin=np.zeros(3))
    one = (grid_arrays(build_grid(both, origin=np.zeros(3)), both),)
    two = (grid_arrays(g_a, tris, np.arange(len(tris), dtype=np.int32)),
           grid_arrays(g_b, moving, np.arange(len(tris), len(both), dtype=np.int32)))
    cam = Camera.frame(both.min(axis=(0, 1)), both.max(axis=(0, 1)))
    return both, one, two, cam


@pytest.mark.parametrize("traversal", ["dda", "cgt"])
@pytest.mark.parametrize("shadows", [False, True])
def test_render_on_any_thread_count_equals_one_thread(traversal, shadows):
    both, one, two, cam = _scene()
    render = cgt_render if traversal == "cgt" else dda_render
    W, H = 96, 72
    light = cam.basis()[0] + np.array([2.0, 3.0, 1.0]) if shadows else None
    if traversal == "dda" and light is None:
        light = np.zeros(3)  # the DDA kernel takes the light as an array and `shadows` as the switch
    f32 = False if traversal == "cgt" else None
    for grids in (one, two):
        assert near_all([(g.lo, g.hi) for g in grids], [cam.basis()[0]] + ([light] if shadows else []))  # (see _args)
        a = _args(grids, cam, W, H, shadows, light=light, f32=f32)
        ref = render(*a, threads=1)
        ref_bufs = [b.copy() for b in a[-1]]
        for threads in (2, 3):
            b = _args(grids, cam, W, H, shadows, light=light, f32=f32)
            out = render(*b, threads=threads)
            for x, y in zip(ref_bufs, b[-1]):
                np.testing.assert_array_equal(x, y)
            if traversal == "cgt":
                np.testing.assert_array_equal(ref, out)
        # the primary hits against the float64 brute-force caster
        origins, dirs = cam.rays(W, H)
        diff = R.compare_hits(ref_bufs[1].reshape(-1), ref_bufs[2].reshape(-1), R.ref_cast(both, origins, dirs))
        assert len(diff.bad) == 0, f"{len(diff.bad)} of {W * H} primary hits differ from the reference"


_KERNELS = '''
import numpy as np
from numba import njit, prange


@njit(cache=True, parallel=True)
def par(x, out):
    for i in prange(x.shape[0]):
        out[i] = 2.0 * x[i] + 1.0
'''


def test_on_threads_runs_every_call_at_once_and_raises_once_all_have_ended():
    """gridrt.threads.on_threads: the calls run at the same time (three calls meet at a barrier,
    which times out unless all three are running), their results come back in order, and the
    exception of one call is raised only after every other call has ended."""
    import threading

    from gridrt.threads import on_threads

    meet = threading.Barrier(3, timeout=60)
    names = on_threads(3, lambda k: (meet.wait(), k, threading.current_thread().name)[1:])
    assert [k for k, _ in names] == [0, 1, 2]
    assert names[0][1] == threading.current_thread().name and len({n for _, n in names}) == 3
    ended, meet = [], threading.Barrier(3, timeout=60)

    def work(k):
        meet.wait()
        if k == 1:
            raise ValueError("call 1 fails")
        threading.Event().wait(0.2 * k)  # call 2 ends well after the failing one and call 0
        ended.append(k)

    with pytest.raises(ValueError, match="call 1 fails"):
        on_threads(3, work)
    assert sorted(ended) == [0, 2]


_FORKED = """
import os
from gridrt.threads import on_threads
assert on_threads(2, lambda k: k) == [0, 1]  # (the pool's threads exist now)
pid = os.fork()
if pid == 0:
    print("child", on_threads(2, lambda k: 10 * k), flush=True)
    os._exit(0)
_, status = os.waitpid(pid, 0)
print("parent", on_threads(2, lambda k: k), os.waitstatus_to_exitcode(status), flush=True)
"""


@pytest.mark.skipif(not hasattr(__import__("os"), "fork"), reason="no os.fork on this platform")
def test_on_threads_in_a_forked_child():
    """A process forked after on_threads started its pool (whose threads the child does not have)
    runs on_threads on a pool of its own, rather than waiting for ever on threads that are gone."""
    r = subprocess.run([sys.executable, "-c", _FORKED], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr[-2000:]
    assert r.stdout.splitlines() == ["child [0, 10]", "parent [0, 1] 0"], r.stdout


# ------------------------------------------------------------------------ the build's stand-in

_BUILD_DRIVER = '''
import json, sys
import numpy as np
from gridrt.compiles import CompileWatch
from gridrt.config import GridParams
from gridrt.grid import GridBuilder, build_grid
from gridrt.grid.build import BOUNDS_CHUNK
from gridrt.scene import make_scene
from gridrt.trace.twin import TWINS

scene = make_scene("icosphere", count=1280, animate="twist")
builder = GridBuilder(GridParams(threads=2))
steps = []
for i, wait in enumerate(json.loads(sys.argv[1])):
    tris = scene.triangles_at(0.1 * i)
    with CompileWatch() as w:
        g = builder.build(tris)
    listed = TWINS.compiling()
    if wait:
        TWINS.wait()
    ref = build_grid(tris, strategy="serial", threads=1)
    same = (np.array_equal(g.cell_start, ref.cell_start) and g.references == ref.references
            and np.array_equal(g.tri_ids[:g.references], ref.tri_ids[:ref.references]))
    steps.append([g.stats.strategy, w.compiled, listed, same])
print(json.dumps(steps))
'''


def _build_drive(tmp_path, cache, waits, **env):
    (tmp_path / "build_driver.py").write_text(textwrap.dedent(_BUILD_DRIVER))
    env = {**__import__("os").environ, "NUMBA_CACHE_DIR": str(cache), **env}
    r = subprocess.run([sys.executable, str(tmp_path / "build_driver.py"), json.dumps(waits)], capture_output=True,
                       text=True, env=env, timeout=900)
    assert r.returncode == 0, r.stderr[-3000:]
    return json.loads(r.stdout.strip().splitlines()[-1])


@pytest.mark.slow
def test_default_build_stands_in_serially_on_a_cold_cache(tmp_path):
    """GridParams(strategy="auto") on two threads with a fresh numba cache: the serial strategy
    builds (the same grid as sort_first and serial: the same cells, each list in the same order),
    the builder's second build starts the background warm-up of sort_first, and once it is done
    sort_first builds; a later process with that cache builds with sort_first from the first
    build and compiles nothing for it; with numba's workqueue threading layer there is no
    stand-in."""
    cache = tmp_path / "cache"
    cold = _build_drive(tmp_path, cache, [False, True, False, False])
    assert [s[0] for s in cold] == ["serial", "serial", "sort_first", "sort_first"]
    assert [s[2] for s in cold] == [[], ["sort_first build"], [], []]
    # compiles: the first build's serial kernels, then the warm-up under way as the second ended
    # (CompileWatch counts a compile in any thread); none once sort_first builds
    assert [s[1] for s in cold] == [True, True, False, False]
    assert all(s[3] for s in cold)
    warm = _build_drive(tmp_path, cache, [False])
    assert warm == [["sort_first", False, [], True]]
    # numba's workqueue layer must not run parallel kernels from two threads at once: no warm-up
    # beside the frames, sort_first compiles where it is first used
    # (the second build compiles the clear stage's kernel, which a first build does not run)
    queue = _build_drive(tmp_path, tmp_path / "cache2", [False, False, False], NUMBA_THREADING_LAYER="workqueue")
    assert queue == [["sort_first", True, [], True], ["sort_first", True, [], True], ["sort_first", False, [], True]]


def test_warm_runs_a_job_once_when_started_and_reports_its_failure():
    t = Twins()
    runs = []
    assert t.warm(("k",), "job", lambda: runs.append(1), start=False) is False
    assert runs == [] and t.compiling() == []
    assert t.warm(("k",), "job", lambda: runs.append(1), start=True) is False
    t.wait()
    assert t.warm(("k",), "job", lambda: runs.append(1), start=True) is True
    assert runs == [1]

    def fail():
        raise ValueError("no")

    t.warm(("bad",), "bad job", fail, start=True)
    t.wait()
    with pytest.raises(RuntimeError, match="warming up bad job failed"):
        t.warm(("bad",), "bad job", fail, start=True)
    with parallel_first():
        assert t.warm(("other",), "job", fail, start=False) is True


_EXIT_DRIVER = '''
import json, sys
import numpy as np
import gridrt
from gridrt.trace.twin import TWINS
import twin_kernels as k

x = np.arange(1000.0)
out = np.zeros_like(x)
TWINS.warm(("par",), "par", lambda: k.par(x, out), True)  # compiles the parallel kernel in the background
print(json.dumps({"compiling": TWINS.compiling()}), flush=True)
'''


def test_library_exit_waits_for_a_background_compile(tmp_path):
    """A program that uses gridrt as a library and ends while a warm-up compiles a parallel kernel in
    the background: the interpreter's exit waits for the compile (one line on stderr says so), exits
    with status 0, and the kernel is in the cache for the next run."""
    (tmp_path / "twin_kernels.py").write_text(_KERNELS)
    (tmp_path / "driver.py").write_text(textwrap.dedent(_EXIT_DRIVER))
    cache = tmp_path / "cache"
    env = {"NUMBA_CACHE_DIR": str(cache), "PYTHONPATH": str(tmp_path), "PATH": "/usr/bin:/bin"}
    r = subprocess.run([sys.executable, str(tmp_path / "driver.py")], capture_output=True, text=True, env=env,
                       timeout=300)
    assert r.returncode == 0, r.stderr
    seen = json.loads(r.stdout.strip().splitlines()[-1])
    assert seen == {"compiling": ["par"]}
    assert "gridrt: finishing the background compile of par before exit" in r.stderr, r.stderr
    assert "Assertion" not in r.stderr and "Traceback" not in r.stderr, r.stderr
    # the compile ended before the process did: the parallel kernel loads from the cache
    assert any(p.name.startswith("twin_kernels.par") and p.suffix == ".nbi" for p in cache.rglob("*")), \
        sorted(p.name for p in cache.rglob("*"))
