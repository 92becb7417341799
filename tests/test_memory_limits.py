"""Sizes that will not fit are refused before anything is allocated (gridrt.memory).

* The limit: :func:`gridrt.memory.readings` read from crafted /proc and /sys trees (cgroup v2 and
  v1, with limits on the cgroup and on a parent, "max" and v1's "no limit") and fake rlimits; the
  minimum is what :func:`available` gives.
* The estimates against what the code really allocates: tracemalloc's peak (it sees numpy's
  allocations) of a batch cast, a subdivision (plain, with a surface, far from the origin, an open
  mesh), a grid build and a render (lambert, and the material pass with shadows over a plane that
  fills the frame: one shadow ray a pixel), each within 0.8x .. 1.5x of the estimate.
* Refusals with the limit made small (``available`` monkeypatched): the message states the
  estimate, the limit and its source, and the advice is checked against the estimate (the rays,
  triangles or pixels it names fit, and more would not); nothing is allocated first (tracemalloc).
* For real, in a subprocess under RLIMIT_AS: a 50M-ray cast prints one line (the estimate, the
  limit from RLIMIT_AS), no traceback, no _ArrayMemoryError; with the estimate switched off the
  MemoryError safety net gives one line too.
* The command line: ``--subdivide 100000000`` and ``--size 100000x100000`` refused with one line
  stating the estimate, having allocated little (tracemalloc), and a MemoryError anywhere in a
  command is one line.
"""

import resource
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

import gridrt
from gridrt import memory
from gridrt.errors import InputError

from conftest import icosphere, icosphere_tris
from helpers.memory import traced

ROOT = Path(__file__).resolve().parents[1]
TEAPOT = ROOT / "assets" / "teapot.obj"
#: the factor an estimate may be off the measured peak by: at most 1.5x over, 0.8x under
LOW, HIGH = 0.8, 1.5


def traced_peak(fn):
    """(fn(), the peak of memory allocated during fn beyond what was held at its start)."""
    with traced() as m:
        out = fn()
    return out, m.peak


def limit_to(monkeypatch, nbytes, source="test limit"):
    """Make gridrt.memory.available report ``nbytes`` (and check every estimate against it)."""
    monkeypatch.setattr(memory, "available", lambda: (nbytes, source))
    monkeypatch.setattr(memory, "CHECK_ABOVE", 0)


def number_in(text, after):
    """The integer (with thousands commas) that follows ``after`` in ``text``."""
    rest = text.split(after, 1)[1].split()[0]
    return int(rest.rstrip(",;.").replace(",", ""))


# ----------------------------------------------------------------------------- the limit


def fake_tree(root, files):
    for rel, text in files.items():
        p = root / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(text)


def no_rlimits(which):
    return (resource.RLIM_INFINITY, resource.RLIM_INFINITY)


MEMINFO = "MemTotal:       32000000 kB\nMemFree:         1000000 kB\nMemAvailable:    2000000 kB\n"


def test_readings_cgroup_v2(tmp_path):
    """cgroup v2: each cgroup from the process's up to the root that sets memory.max gives
    max - current; "max" sets none; MemAvailable is read in kB."""
    fake_tree(tmp_path, {
        "proc/meminfo": MEMINFO,
        "proc/self/cgroup": "0::/user.slice/job\n",
        "sys/fs/cgroup/user.slice/job/memory.max": "max\n",
        "sys/fs/cgroup/user.slice/job/memory.current": "123\n",
        "sys/fs/cgroup/user.slice/memory.max": "1000000000\n",
        "sys/fs/cgroup/user.slice/memory.current": "300000000\n",
        "sys/fs/cgroup/memory.max": "5000000000\n",  # (a container's root, usage unknown: ignored)
    })
    r = memory.readings(tmp_path, no_rlimits)
    assert sorted(r) == sorted([("MemAvailable", 2000000 * 1024), ("cgroup memory.max", 700000000)])


def test_readings_cgroup_v1_and_rlimits(tmp_path):
    """cgroup v1: limit_in_bytes - usage_in_bytes where a limit is set (v1 writes about 2**63 for
    none); RLIMIT_AS - VmSize and RLIMIT_DATA - VmData when set; below zero reads as zero."""
    fake_tree(tmp_path, {
        "proc/meminfo": MEMINFO,
        "proc/self/cgroup": "5:cpu,cpuacct:/x\n4:memory:/pods/a\n0::/\n",
        "proc/self/status": "Name:\tpython\nVmPeak:\t  900000 kB\nVmSize:\t  800000 kB\nVmData:\t  300000 kB\n",
        "sys/fs/cgroup/memory/pods/a/memory.limit_in_bytes": "9223372036854771712\n",
        "sys/fs/cgroup/memory/pods/a/memory.usage_in_bytes": "100\n",
        "sys/fs/cgroup/memory/pods/memory.limit_in_bytes": "400000000\n",
        "sys/fs/cgroup/memory/pods/memory.usage_in_bytes": "500000000\n",
    })
    limits = {resource.RLIMIT_AS: (1 << 30, resource.RLIM_INFINITY), resource.RLIMIT_DATA: (200000 * 1024, 1 << 40)}
    r = dict(memory.readings(tmp_path, lambda which: limits.get(which, no_rlimits(which))))
    assert r == {"MemAvailable": 2000000 * 1024, "cgroup memory.limit_in_bytes": 0,
                 "RLIMIT_AS": (1 << 30) - 800000 * 1024, "RLIMIT_DATA": 0}


def test_available_is_the_smallest_reading(monkeypatch):
    monkeypatch.setattr(memory, "readings", lambda: [("MemAvailable", 5 << 30), ("RLIMIT_AS", 3 << 30),
                                                     ("cgroup memory.max", 4 << 30)])
    assert memory.available() == (3 << 30, "RLIMIT_AS")
    monkeypatch.setattr(memory, "readings", lambda: [])
    assert memory.available() == (None, None)  # nothing to read: nothing is refused
    memory.check_fits(1 << 60, "anything", "parts", "advice")


def test_readings_of_this_process():
    """The real files: MemAvailable as /proc/meminfo gives it, and no reading above it."""
    text = Path("/proc/meminfo").read_text() if Path("/proc/meminfo").exists() else ""
    if "MemAvailable" not in text:
        pytest.skip("no /proc/meminfo with MemAvailable here")
    kb = int(text.split("MemAvailable:")[1].split()[0])
    r = dict(memory.readings())
    assert abs(r["MemAvailable"] - kb * 1024) < (256 << 20)  # (read a moment apart)
    avail, source = memory.available()
    # (a second reading, a moment later: the machine's free memory may have moved by then, as above)
    assert source in r and abs(avail - min(r.values())) < (256 << 20)


# ----------------------------------------------------------------------------- estimates vs the measured peak


@pytest.fixture(scope="module")
def caster():
    return gridrt.RayCaster(*icosphere(2))


@pytest.mark.parametrize("odd", [False, True], ids=["unit directions", "some tiny directions"])
def test_cast_estimate_matches_peak(caster, odd):
    """A batch of 4M rays: the results (28 bytes a ray) plus one chunk's scratch, against
    tracemalloc's peak; with every 7th direction scaled by 1e-40 the odd-direction path runs too.
    The origins are one point broadcast (no memory), the directions the caller's."""
    from gridrt.trace.render import cast_bytes

    n = 4_000_000
    rng = np.random.default_rng(3)
    o = np.broadcast_to(np.array([0.0, 0.0, -5.0]), (n, 3))
    d = rng.normal(size=(n, 3)) * [0.1, 0.1, 0.0] + [0.0, 0.0, 1.0]
    if odd:
        d[::7] *= 1e-40
    caster.cast(o[:1000], d[:1000])  # (kernels loaded outside the measurement)
    hits, peak = traced_peak(lambda: caster.cast(o, d))
    assert 0.5 < (hits.tri >= 0).mean() < 1.0  # the sphere is hit, and missed
    assert LOW <= cast_bytes(n) / peak <= HIGH, (cast_bytes(n), peak)


@pytest.mark.parametrize("dtypes", [(np.float32, np.int64), (np.float64, np.int32)])
def test_caster_estimate_matches_peak(dtypes):
    """A RayCaster's mesh arrays (MESH_VERTEX_BYTES, MESH_FACE_BYTES) plus its grid's build_bytes
    against tracemalloc's peak of its construction, from float32 vertices with int64 faces and
    float64 vertices with int32 faces."""
    from gridrt.api import MESH_FACE_BYTES, MESH_VERTEX_BYTES
    from gridrt.grid.buffers import build_bytes

    v, f = icosphere(5)
    v, f = v.astype(dtypes[0]), f.astype(dtypes[1])
    gridrt.RayCaster(v, f)  # (kernels loaded outside the measurement)
    c, peak = traced_peak(lambda: gridrt.RayCaster(v, f))
    g = c.grid
    est = MESH_VERTEX_BYTES * len(v) + MESH_FACE_BYTES * len(f) + build_bytes(g.spec.n_cells, g.references, len(f))
    assert LOW <= est / peak <= HIGH, (est, peak)


def test_caster_refused_with_estimate_and_limit(caster, monkeypatch):
    """A RayCaster, and an update of one, whose mesh arrays exceed the limit: refused before they
    are allocated (the caster keeps its mesh)."""
    from gridrt.api import MESH_FACE_BYTES, MESH_VERTEX_BYTES, TRIANGLE_BYTES

    v, f = icosphere(5)
    limit_to(monkeypatch, 100_000)
    need = MESH_VERTEX_BYTES * len(v) + MESH_FACE_BYTES * len(f)
    with pytest.raises(InputError, match=rf"^building a RayCaster \(20,480 triangles\) needs about "
                                         rf"{memory.human(need)} \(.*100 kB is available \(test limit\)"):
        gridrt.RayCaster(v, f)
    before = caster.vertices
    limit_to(monkeypatch, 1000)
    need = MESH_VERTEX_BYTES * len(before) + TRIANGLE_BYTES * len(caster.faces)
    with pytest.raises(InputError, match=rf"^updating a RayCaster \({len(caster.faces):,} triangles\) needs about "
                                         rf"{memory.human(need)} "):
        caster.update(before * 2)
    assert caster.vertices is before


def indexed_icosphere(subdivisions):
    v, f = icosphere(subdivisions)
    return v, f.astype(np.int32)


def surface_of(F, rng):
    from gridrt.scene.surface import Surface

    return Surface(np.zeros(F, np.int32), np.ones((1, 3), np.float32), np.full((1, 3), 0.1, np.float32),
                   np.full(1, -1, np.int32), (), rng.random((F, 3, 2)), rng.random((F, 3, 3)),
                   rng.random((F, 3, 3)) - 0.5)


@pytest.mark.parametrize("kind", ["plain", "surface", "far", "open"])
def test_subdivide_estimate_matches_peak(kind):
    """subdivide_bytes against tracemalloc's peak of subdivide_mesh, one and two passes: a closed
    icosphere, the same with uv, colours and normals, far from the origin (float64 splits), and
    an open half of it."""
    from gridrt.scene.mesh import Mesh
    from gridrt.scene.subdivide import subdivide_bytes, subdivide_mesh

    v, f = indexed_icosphere(3)
    rng = np.random.default_rng(4)
    mesh = {"plain": lambda: Mesh(v, f), "surface": lambda: Mesh(v, f, surface=surface_of(len(f), rng)),
            "far": lambda: Mesh(v.astype(np.float64) + 1e6, f), "open": lambda: Mesh(v, f[: len(f) // 2])}[kind]()
    for passes in (1, 2):
        target = mesh.n_triangles * 4 ** passes
        out, peak = traced_peak(lambda: subdivide_mesh(mesh, target))
        assert out.n_triangles == target
        est = subdivide_bytes(mesh, target)
        assert LOW <= est / peak <= HIGH, (passes, est, peak)


@pytest.mark.parametrize("strategy", ["serial", "sort_first"])
def test_grid_estimate_matches_peak(strategy):
    """build_bytes (cells, references, triangles, layers: read off the grid built) against
    tracemalloc's peak of a fresh GridBuilder's build, at three densities."""
    from gridrt.grid.buffers import build_bytes
    from gridrt.grid.build import GridBuilder

    tris = icosphere_tris(4)
    for density in (1.0, 4.0, 16.0):
        p = gridrt.GridParams(strategy=strategy, density=density, threads=2)
        GridBuilder(p).build(tris)  # (kernels loaded outside the measurement)
        grid, peak = traced_peak(lambda: GridBuilder(p).build(tris))
        est = build_bytes(grid.spec.n_cells, grid.references, len(tris), layers=grid.cell_count.shape[0])
        assert LOW <= est / peak <= HIGH, (density, est, peak)


PLANE = np.array([[[-10, -10, 0], [10, -10, 0], [10, 10, 0]], [[-10, -10, 0], [10, 10, 0], [-10, 10, 0]]], np.float32)


@pytest.mark.parametrize("shading,shadows,k", [("lambert", False, 0), ("material", True, 0), ("material", True, 4)])
def test_render_estimate_matches_peak(shading, shadows, k):
    """render_bytes against tracemalloc's peak of a fresh Renderer's frame over a plane that
    fills the view (every pixel a hit facing the light: the material pass casts a shadow ray a
    pixel, its most; with 4 lights drawn a pixel of 4 lights, buffers for every light's segments
    at once)."""
    from gridrt.memory import render_bytes
    from gridrt.trace.render import Looks, Renderer

    grid = gridrt.build_grid(PLANE)
    cam = gridrt.Camera(eye=(0, 0, 5), target=(0, 0, 0), fov=40)
    rp = gridrt.RenderParams(400, 300, shading=shading, shadows=shadows, light_samples=k)
    looks = None
    if k:
        lights = np.array([[0, x, y, 3.0, 1, 1, 1, 0] for x in (-1.0, 1.0) for y in (-1.0, 1.0)])
        looks = Looks(PLANE, None, None, lights)
    Renderer().render(grid, PLANE, cam, rp, looks=looks)  # (kernels loaded outside the measurement)
    res, peak = traced_peak(lambda: Renderer().render(grid, PLANE, cam, rp, looks=looks))
    assert res.stats.hit_fraction == 1.0
    if shadows:
        assert res.stats.shadow_rays_per_pixel == 1.0 if not k else 3 < res.stats.shadow_rays_per_pixel <= 4
    est = render_bytes(400, 300, shadows, light_samples=k)
    assert LOW <= est / peak <= HIGH, (est, peak)


def test_frame_estimate_matches_peak():
    """A FramePipeline's first frame of a static plane at 800x600: the render's estimate plus the
    grid's (build_bytes of the grid it built) and the scene's float32 triangles, against
    tracemalloc's peak of the step."""
    from gridrt.grid.buffers import build_bytes
    from gridrt.pipeline import FramePipeline
    from gridrt.scene import make_scene
    from gridrt.memory import render_bytes

    scene = make_scene("icosphere", count=20480)
    cam = gridrt.Camera(eye=(0, 0, 1.6), target=(0, 0, 0), fov=90)
    rp = gridrt.RenderParams(800, 600, shading="lambert", threads=1)
    FramePipeline(scene, render_params=rp, camera=cam).step(0.0)  # (kernels loaded outside the measurement)
    pipe = FramePipeline(scene, render_params=rp, camera=cam)
    frame, peak = traced_peak(lambda: pipe.step(0.0))
    g = frame.grid
    est = render_bytes(800, 600) + build_bytes(g.spec.n_cells, g.references, g.n_triangles) + 36 * g.n_triangles
    assert LOW <= est / peak <= HIGH, (est, peak)


# ----------------------------------------------------------------------------- refusals under a small limit


def test_cast_refused_with_estimate_and_limit(caster, monkeypatch):
    """A 3M-ray cast over a 50 MB limit: InputError before any allocation, stating the estimate,
    the limit and its source; the batch size it advises fits the limit and one more ray would not
    (cast_bytes); a batch of that size is then cast."""
    from gridrt.memory import human
    from gridrt.trace.render import cast_bytes

    limit = 50_000_000
    limit_to(monkeypatch, limit)
    n = 3_000_000
    o = np.broadcast_to(np.array([0.0, 0.0, -5.0]), (n, 3))
    d = np.broadcast_to(np.array([0.0, 0.0, 1.0]), (n, 3))
    with pytest.raises(InputError) as info:
        caster.cast(o, d)
    msg = str(info.value)
    assert msg.startswith(f"casting 3,000,000 rays needs about {human(cast_bytes(n))} (")
    assert f"; {human(limit)} is available (test limit); cast in batches of at most " in msg
    assert "\n" not in msg
    k = number_in(msg, "at most ")
    assert cast_bytes(k) <= limit < cast_bytes(k + 1)
    assert caster.cast(o[:k], d[:k]).tri.shape == (k,)


def test_cast_refusal_allocates_nothing(caster, monkeypatch):
    """The refusal comes before the results, the scratch and the rays' value checks: under 1 MB
    is allocated on the way to it."""
    limit_to(monkeypatch, 1_000_000)
    n = 1_000_000
    o = np.broadcast_to(np.array([0.0, 0.0, -5.0]), (n, 3))
    d = np.broadcast_to(np.array([0.0, 0.0, 1.0]), (n, 3))

    def refused():
        with pytest.raises(InputError, match="^casting 1,000,000 rays needs about 91 MB"):
            caster.cast(o, d)

    assert traced_peak(refused)[1] < 1 << 20


def test_subdivide_refused_with_estimate_and_limit(monkeypatch):
    """make_scene's subdivide over a small limit: refused before splitting, stating the estimate
    (subdivide_bytes) and the limit; the target it advises fits (and is then made under the same
    limit), and the next pass would not."""
    from gridrt.memory import human
    from gridrt.scene import make_scene
    from gridrt.scene.loader import load_mesh
    from gridrt.scene.subdivide import subdivide_bytes

    mesh = load_mesh(TEAPOT)
    limit = 60_000_000
    limit_to(monkeypatch, limit)
    target = 100_000_000
    with pytest.raises(InputError) as info:
        make_scene(str(TEAPOT), subdivide=target)
    msg = str(info.value)
    final = mesh.n_triangles * 4 ** 7  # 6,320 x 4**7 = 103,546,880: the first count >= the target
    assert msg.startswith(f"subdividing 'teapot' ({mesh.n_triangles:,} triangles) to {final:,} triangles needs about "
                          f"{human(subdivide_bytes(mesh, target))} (")
    assert f"{human(limit)} is available (test limit); subdivide to at most " in msg
    k = number_in(msg, "subdivide to at most ")
    assert subdivide_bytes(mesh, k) <= limit < subdivide_bytes(mesh, 4 * k)
    assert make_scene(str(TEAPOT), subdivide=k).n_triangles == k


def test_grid_refused_with_estimate_and_limit(monkeypatch):
    """A grid whose cell arrays, then one whose references, exceed the limit: refused before they
    are allocated, naming the cells or references, the bytes and the limit."""
    from gridrt.grid.buffers import CELL_GROWTH, grown

    tris = icosphere_tris(3)
    limit_to(monkeypatch, 2_000_000)
    # cells: density 200 x 1280 triangles -> about 256,000 cells, 2.6 MB of counts and offsets
    with pytest.raises(InputError) as info:
        gridrt.build_grid(tris, density=200.0)
    msg = str(info.value)
    assert msg.startswith("a grid of ") and " cells needs about " in msg and "2.0 MB is available (test limit)" in msg
    cells = number_in(msg, "a grid of ")
    assert 4 * (grown(cells, CELL_GROWTH) + grown(cells + 1, CELL_GROWTH)) > 2_000_000
    # references: huge triangles at a fine grid, few cells but every triangle in most of them
    big = np.random.default_rng(5).uniform(-1, 1, (2000, 3, 3)).astype(np.float32)
    with pytest.raises(InputError, match=r"^a grid of [\d,]+ references needs about .* is available \(test limit\)"):
        gridrt.build_grid(big, density=20.0)


def test_render_refused_with_estimate_and_limit(monkeypatch):
    """RenderParams of a size whose buffers exceed the limit (the pixel count it advises fits);
    Camera.rays likewise; a pipeline whose limit fell below its material pass with shadows is
    refused at its first step before the scene's grid is built."""
    from gridrt.memory import human, render_bytes
    from gridrt.pipeline import FramePipeline
    from gridrt.scene import make_scene

    limit = 40_000_000
    limit_to(monkeypatch, limit)
    with pytest.raises(InputError) as info:
        gridrt.RenderParams(2000, 2000)
    msg = str(info.value)
    assert msg.startswith(f"rendering 2,000x2,000 pixels needs about {human(render_bytes(2000, 2000))} (")
    k = number_in(msg, "ask for at most ")
    assert render_bytes(k, 1) <= limit < render_bytes(k + 1, 1)
    with pytest.raises(InputError, match=r"^making the primary rays of 1,000x1,000 pixels needs about 48 MB \(float64"):
        gridrt.Camera().rays(1000, 1000)

    monkeypatch.setattr(memory, "available", lambda: (render_bytes(400, 300, True), "test limit"))
    rp = gridrt.RenderParams(400, 300, shading="material", shadows=True)  # (fits, just)
    pipe = FramePipeline(make_scene("icosphere"), render_params=rp)
    monkeypatch.setattr(memory, "available", lambda: (render_bytes(400, 300, True) - 1, "test limit"))
    with pytest.raises(InputError, match=r"^rendering a frame of 400x300 pixels needs about .*and shadow rays\)"):
        pipe.step(0.0)
    assert pipe.grid is None and pipe.renderer._bufs is None  # nothing built, nothing allocated


# ----------------------------------------------------------------------------- the safety net


def test_memory_error_becomes_one_input_error(caster, monkeypatch):
    """A MemoryError that gets past the estimates (another process took the memory) becomes an
    InputError naming what was being allocated: RayCaster's construction, update and cast,
    FramePipeline.step, make_scene's subdivide."""
    import gridrt.api as api
    import gridrt.scene.subdivide as sub
    from gridrt.pipeline import FramePipeline
    from gridrt.scene import make_scene

    def boom(*a, **k):
        raise MemoryError()

    o = np.zeros((10, 3)) + [0, 0, -5.0]
    d = np.zeros((10, 3)) + [0, 0, 1.0]
    n = len(caster.faces)
    with monkeypatch.context() as m:
        m.setattr(api, "_vertices64", boom)
        with pytest.raises(InputError, match=r"^out of memory building a RayCaster over 2 triangles; "):
            gridrt.RayCaster.from_triangles(PLANE)
        m.setattr(api, "_centred_mesh", boom)
        with pytest.raises(InputError, match=r"^out of memory building a RayCaster over 2 triangles; "):
            gridrt.RayCaster(PLANE.reshape(-1, 3), [[0, 1, 2], [3, 4, 5]])
        m.setattr(api, "_centred_vertices", boom)
        with pytest.raises(InputError, match=rf"^out of memory updating a RayCaster of {n:,} triangles; "):
            caster.update(caster.vertices)
    monkeypatch.setattr(api, "cast_batch", boom)
    with pytest.raises(InputError, match=r"^out of memory casting 10 rays; .* is available .*; cast fewer rays"):
        caster.cast(o, d)
    monkeypatch.setattr(sub, "split_once", boom)
    with pytest.raises(InputError, match=r"^out of memory subdividing 'teapot' \(6,320 triangles\) to 25,280"):
        make_scene(str(TEAPOT), subdivide=20000)
    pipe = FramePipeline(make_scene("icosphere"), render_params=gridrt.RenderParams(64, 48))
    monkeypatch.setattr(pipe.renderer, "render", boom)
    with pytest.raises(InputError, match=r"^out of memory rendering frame 0 \(64x48 pixels, 5,120 triangles\)"):
        pipe.step(0.0)


# ----------------------------------------------------------------------------- for real, and the command line

CAST_UNDER_RLIMIT = textwrap.dedent("""
    import resource, sys
    import numpy as np
    import gridrt
    from gridrt import memory

    v = np.array([[-1, -1, 0], [1, -1, 0], [0, 1, 0]], float)
    caster = gridrt.RayCaster(v, [[0, 1, 2]])
    caster.cast(np.zeros((4, 3)) + [0, 0, -1], np.zeros((4, 3)) + [0, 0, 1])
    vm = [int(l.split()[1]) * 1024 for l in open("/proc/self/status") if l.startswith("VmSize:")][0]
    resource.setrlimit(resource.RLIMIT_AS, (vm + (1 << 30), resource.RLIM_INFINITY))
    n = 50_000_000
    o = np.broadcast_to(np.array([0.0, 0.0, -1.0]), (n, 3))
    d = np.broadcast_to(np.array([0.0, 0.0, 1.0]), (n, 3))
    for check in (True, False):
        if not check:
            memory.CHECK_ABOVE = 1 << 62  # the estimate off: the MemoryError safety net
        try:
            caster.cast(o, d)
            print("cast")
        except gridrt.GridrtError as e:
            print(e)
""")


def test_real_rlimit_cast_is_one_line(tmp_path):
    """Under RLIMIT_AS (1 GiB above the process's size) a 50M-ray cast (1.5 GB of results) is
    refused with one line naming the estimate and RLIMIT_AS; with the estimate switched off the
    allocation fails for real and the MemoryError is one line too; no traceback, no
    _ArrayMemoryError."""
    if sys.platform != "linux" or (memory.available()[0] or 0) < 3 << 30:
        pytest.skip("needs Linux and 3 GB free (the limit must be RLIMIT_AS's, not the machine's)")
    script = tmp_path / "cast.py"
    script.write_text(CAST_UNDER_RLIMIT)
    r = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=600, cwd=tmp_path)
    lines = r.stdout.splitlines()
    assert r.returncode == 0 and "Traceback" not in r.stderr and "ArrayMemoryError" not in r.stdout + r.stderr, r
    assert len(lines) == 2, r.stdout
    assert lines[0].startswith("casting 50,000,000 rays needs about 1.5 GB "
                               "(hits, triangle ids, barycentrics and scratch); ")
    assert "is available (RLIMIT_AS); cast in batches of at most " in lines[0]
    assert number_in(lines[0], "at most ") < 50_000_000 * 0.9
    assert lines[1].startswith("out of memory casting 50,000,000 rays; ") and "(RLIMIT_AS)" in lines[1], lines[1]


def run_cli(argv, capsys):
    from app.__main__ import main

    (rc, peak) = traced_peak(lambda: main(argv))
    out = capsys.readouterr()
    return rc, out.out, out.err, peak


def test_cli_subdivide_refused(tmp_path, capsys, monkeypatch):
    """``gridrt dump --subdivide 100000000`` (the largest target): one line stating the estimate
    and the limit, exit 2, and under 64 MB allocated on the way (the refusal comes first)."""
    from gridrt.scene.loader import load_mesh
    from gridrt.scene.subdivide import subdivide_bytes

    monkeypatch.setattr(memory, "available", lambda: (8 * 10**9, "MemAvailable"))
    need = subdivide_bytes(load_mesh(TEAPOT), 100_000_000)
    rc, out, err, peak = run_cli(["dump", "--scene", str(TEAPOT), "--subdivide", "100000000", "--frames", "1",
                                  "--out", str(tmp_path / "d")], capsys)
    assert rc == 2 and out == ""
    assert err.count("\n") == 1 and "Traceback" not in err
    assert err.startswith("gridrt: error: subdividing 'teapot' (6,320 triangles) to 103,546,880 triangles needs about "
                          f"{memory.human(need)} (")
    assert "; 8.0 GB is available (MemAvailable); subdivide to at most " in err
    assert peak < 64 << 20


def test_cli_size_refused(tmp_path, capsys, monkeypatch):
    """``--size 100000x100000``: one line stating the buffers' estimate (21 bytes a pixel: 210 GB)
    and the limit, exit 2."""
    monkeypatch.setattr(memory, "available", lambda: (8 * 10**9, "MemAvailable"))
    rc, out, err, peak = run_cli(["dump", "--scene", "icosphere", "--size", "100000x100000", "--frames", "1",
                                  "--out", str(tmp_path / "d")], capsys)
    assert rc == 2 and out == "" and err.count("\n") == 1
    assert err.startswith("gridrt: error: rendering 100,000x100,000 pixels needs about 210 GB (image, depth, triangle, "
                          "cost and cell buffers); 8.0 GB is available (MemAvailable); ask for at most ")
    assert peak < 64 << 20


def test_cli_memory_error_is_one_line(capsys, monkeypatch):
    """A MemoryError the estimates missed, anywhere in a command: one line, exit 2."""
    import app.__main__ as cli_main

    def boom(a):
        raise MemoryError()

    monkeypatch.setattr(cli_main, "_list_strategies", boom)
    rc, out, err, _ = run_cli(["strategies"], capsys)
    assert rc == 2 and err.count("\n") == 1
    assert err.startswith("gridrt: error: out of memory in gridrt strategies; ") and "is available" in err
