"""Shared fixtures and scene helpers for the gridrt tests.

* ``rng``: a seeded numpy Generator (fixed seed, so failures reproduce).
* ``data_path(relpath)`` (also the ``shared_data`` fixture): path of a real third-party file named
  by its place in the development data set (real meshes kept beside the repository, on the
  development machines only): the repository's ``assets/`` copy when it ships one
  (:data:`SHIPPED`), else the data set's; skips the test with a reason when neither has it.
  ``GRIDRT_NO_SHARED_DATA=1`` ignores the data set, so a run shows what a user's clone runs and
  skips.
* ``--update-golden``: regenerate ``tests/golden/*.png`` from the brute-force reference renderer
  (see ``test_golden.py``).
* Procedural scenes: :func:`random_triangles`, :func:`random_scene` (slivers, huge, flat,
  duplicated and zero-area triangles), :func:`icosphere`, :func:`load_tris`.
* ``harness``: the native Embree harness compiled from its sources beside the repository, or a
  skip saying what is missing.
"""

import compileall
import fnmatch
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import gridrt  # noqa: F401  (sets NUMBA_NUM_THREADS before anything imports numba)

REPO = Path(__file__).resolve().parents[1]

#: the development data set, shared/data beside the repository (present on the development
#: machines only; treated as absent when GRIDRT_NO_SHARED_DATA is set to anything but "" or "0").
SHARED_DATA = REPO.parent / "shared" / "data"
NO_SHARED_DATA = os.environ.get("GRIDRT_NO_SHARED_DATA", "") not in ("", "0")

#: the repository's assets/ (real files that ship with gridrt; see assets/README.md)
ASSETS = REPO / "assets"

TEAPOT = "static/utah_teapot/teapot.obj"
ARMADILLO = "static/armadillo/armadillo.off"
BUNNY = "static/stanford_bunny/stanford-bunny.obj"

#: data set files (or folders) that assets/ ships byte for byte -> their name in assets/
SHIPPED = {
    TEAPOT: "teapot.obj",
    "animated/cesium_man/CesiumMan.glb": "CesiumMan.glb",
    "animated/animated_morph_sphere/AnimatedMorphSphere.gltf": "AnimatedMorphSphere.gltf",
    "animated/animated_morph_sphere/AnimatedMorphSphere.bin": "AnimatedMorphSphere.bin",
    "animated/md2_sydney/sydney.md2": "sydney.md2",
    "animated/md2_sydney/sydney.bmp": "sydney.bmp",
    "animated/bart/museum/aff": "museum",
    **{f"animated/bart/museum/aff/{n}.aff": f"museum/{n}.aff"
       for n in ("museum5", "animart5", "block", "camera", "paintings", "pillar", "room")},
    **{f"animated/bart/museum/TextureFiles/{n}.ppm": f"museum/TextureFiles/{n}.ppm"
       for n in ("balls4", "checkmarb1", "gears4", "mount6", "tetra6")},
}
#: data set meshes that assets/ ships converted (the same vertices as float32, the same
#: faces, another format) -> their name in assets/
CONVERTED = {ARMADILLO: "armadillo.ply"}


#: the repository's folders of Python files that the tests import or start processes of
SOURCES = ("engine", "app", "scripts", "tests")


def pytest_configure(config):
    """Where Python writes no bytecode (PYTHONDONTWRITEBYTECODE, set on some hosts), every process
    the tests start (most of them gridrt commands) would compile gridrt's sources again, about
    0.3 s each on a 2-vCPU host: the controlling process compiles them once here,
    before the workers start, and the processes read the bytecode (only its writing is off).
    Likewise pytest's rewriting of the test modules' asserts, which each worker would otherwise
    do again on every run (8-16 s a worker): see :func:`_rewrite_asserts_once`."""
    if hasattr(config, "workerinput") or not sys.dont_write_bytecode:
        return
    for folder in SOURCES:
        compileall.compile_dir(REPO / folder, quiet=2)
    _rewrite_asserts_once(config)


def _rewrite_asserts_once(config):
    """Write pytest's cached, assert-rewritten bytecode of the test modules and conftest files
    (pytest reads that cache whether or not Python may write bytecode, but writes it only where it
    may).  Through pytest's own rewriting functions, as its import hook calls them; with another
    pytest whose internals differ, nothing is written and the workers rewrite as before."""
    try:
        from _pytest.assertion.rewrite import (PYC_TAIL, _read_pyc, _rewrite_test, _write_pyc, assertstate_key,
                                               get_cache_dir)

        state = config.stash[assertstate_key]
    except (ImportError, AttributeError, KeyError):
        return
    patterns = ["conftest.py", *config.getini("python_files")]  # (what pytest's import hook rewrites)
    for fn in sorted((REPO / "tests").rglob("*.py")):
        if not any(fnmatch.fnmatch(fn.name, p) for p in patterns):
            continue
        cache = get_cache_dir(fn)
        pyc = cache / (fn.name[:-3] + PYC_TAIL)
        if _read_pyc(fn, pyc, state.trace) is not None:
            continue
        cache.mkdir(exist_ok=True)
        source_hash, co = _rewrite_test(fn, config)
        _write_pyc(state, co, source_hash, pyc)


def soak_requested(config):
    """True when the run asks for the ``soak`` marker's slow exhaustive cases (``-m soak``,
    GRIDRT_SOAK=1 or ``--rest``)."""
    return ("soak" in (config.getoption("markexpr") or "") or os.environ.get("GRIDRT_SOAK", "") not in ("", "0")
            or config.getoption("rest"))


#: the pytest cache key of the tests a run with GRIDRT_NO_SHARED_DATA skipped (the README's quick
#: command): ``--rest`` runs them
QUICK_SKIPPED = "gridrt/quick_skipped"
_SKIPPED = set()


def pytest_collection_modifyitems(config, items):
    """Without ``-m soak`` (or GRIDRT_SOAK=1) the soak cases are deselected, not skipped: they are
    opt-in (the default run has shorter versions of each), and a skip would say something is
    missing.  With ``--rest``: only what the README's quick command (GRIDRT_NO_SHARED_DATA=1,
    ``-m "not slow"``) left out: the tests its last run in this checkout skipped, the slow ones and
    the soak (every test when no quick run is remembered)."""
    if config.getoption("rest"):
        skipped = config.cache.get(QUICK_SKIPPED, None)
        if skipped is None:
            return
        skipped = set(skipped)

        def left_out(it):
            return (it.get_closest_marker("slow") is not None or it.get_closest_marker("soak") is not None
                    or it.nodeid in skipped or it.nodeid.split("::")[0] in skipped)

        drop = [it for it in items if not left_out(it)]
        if drop:
            config.hook.pytest_deselected(items=drop)
            items[:] = [it for it in items if left_out(it)]
        return
    if soak_requested(config):
        return
    soak = [it for it in items if it.get_closest_marker("soak") is not None]
    if soak:
        config.hook.pytest_deselected(items=soak)
        items[:] = [it for it in items if it.get_closest_marker("soak") is None]


def pytest_runtest_logreport(report):
    if report.skipped:
        _SKIPPED.add(report.nodeid)


def pytest_collectreport(report):
    if report.skipped:  # a module that skips as a whole
        _SKIPPED.add(report.nodeid)


def pytest_sessionfinish(session):
    """A quick run (GRIDRT_NO_SHARED_DATA, not --rest) remembers the tests it skipped for --rest."""
    config = session.config
    worker = hasattr(config, "workerinput")  # a pytest-xdist worker: the controller sees every report
    if NO_SHARED_DATA and not config.getoption("rest") and not worker and getattr(config, "cache", None) is not None:
        config.cache.set(QUICK_SKIPPED, sorted(_SKIPPED))


#: test files that compile the same kernels (every build strategy's, for uniform and two-level
#: grids): under ``--dist loadfile`` they are one work unit, so that on a cold numba cache one
#: worker compiles those kernels once instead of two workers compiling them at the same time
SHARED_COMPILES = {"tests/test_grid_reference.py": "every strategy's builds",
                   "tests/test_two_level.py": "every strategy's builds"}


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_make_scheduler(config, log):
    """pytest-xdist's loadfile scheduling with the files of SHARED_COMPILES in one work unit."""
    if config.getoption("dist", None) != "loadfile":
        return None
    from xdist.scheduler import LoadFileScheduling

    class SharedCompiles(LoadFileScheduling):
        def _split_scope(self, nodeid):
            path = super()._split_scope(nodeid)
            return SHARED_COMPILES.get(path, path)

    return SharedCompiles(config, log)


def pytest_addoption(parser):
    parser.addoption(
        "--rest",
        action="store_true",
        default=False,
        help="run what the README's quick test command left out in this checkout: the tests it skipped "
             "(the development data set ignored), the slow ones and the soak",
    )
    parser.addoption(
        "--update-golden",
        action="store_true",
        default=False,
        help="regenerate tests/golden/*.png from the brute-force reference renderer (tests/reference.py)",
    )


@pytest.fixture
def update_golden(request):
    return request.config.getoption("--update-golden")


@pytest.fixture
def rng():
    """Seeded numpy Generator; every test gets the same fresh stream."""
    return np.random.default_rng(20061204)


def data_path(relpath, converted=False):
    """The real file (or folder) known by its place ``relpath`` in the development data set: the
    copy in assets/ when the repository ships it byte for byte, else the data set's, else
    (with ``converted``, for callers that only need the mesh's arrays) the converted copy in
    assets/; pytest.skip naming what is missing when there is none."""
    if relpath in SHIPPED and (ASSETS / SHIPPED[relpath]).exists():
        return ASSETS / SHIPPED[relpath]
    p = SHARED_DATA / relpath
    if not NO_SHARED_DATA and p.exists():
        return p
    if converted and relpath in CONVERTED and (ASSETS / CONVERTED[relpath]).is_file():
        return ASSETS / CONVERTED[relpath]
    why = "GRIDRT_NO_SHARED_DATA is set" if NO_SHARED_DATA else "the development data set is not part of the repository"
    pytest.skip(f"real test data not available: {p} ({why}; assets/ does not ship it)")


def available(*relpaths, converted=False):
    """{relpath: path} of those of ``relpaths`` that :func:`data_path` finds, in order; skips
    (naming them) only when none is there.  For a test that checks the same property on several
    real files, where a clone without the development data set still has the shipped ones."""
    found, missing = {}, []
    for rel in relpaths:
        try:
            found[rel] = data_path(rel, converted=converted)
        except pytest.skip.Exception:
            missing.append(rel)
    if not found:
        pytest.skip(f"none of these real files is available: {', '.join(missing)} (the development data set)")
    if missing:
        print(f"data set files not available (their checks did not run): {', '.join(missing)}")
    return found


@pytest.fixture
def shared_data():
    """The :func:`data_path` helper as a fixture: ``shared_data("static/...")``."""
    return data_path


def load_mesh_arrays(relpath):
    """(vertices (V, 3) float32, faces (F, 3) int64) of a real mesh (see :func:`data_path`; a
    converted copy in assets/ will do), loaded with trimesh without merging or reordering
    anything (skips when the file is absent)."""
    import trimesh

    p = data_path(relpath, converted=True)
    m = trimesh.load(p, force="mesh", process=False)
    return np.asarray(m.vertices, np.float32), np.asarray(m.faces, np.int64)


def load_tris(relpath):
    """(F, 3, 3) float32 triangles of a real mesh (see :func:`load_mesh_arrays`; skips when absent)."""
    v, f = load_mesh_arrays(relpath)
    return np.ascontiguousarray(v[f])


def icosphere(subdivisions=2, radius=1.0, center=(0.0, 0.0, 0.0)):
    """Closed icosphere from trimesh.creation: (vertices (V, 3) float32, faces (F, 3) int64)."""
    import trimesh

    m = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    v = (np.asarray(m.vertices) + np.asarray(center)).astype(np.float32)
    return v, np.asarray(m.faces, np.int64)


def icosphere_tris(subdivisions=2, radius=1.0, center=(0.0, 0.0, 0.0)):
    v, f = icosphere(subdivisions, radius, center)
    return np.ascontiguousarray(v[f])


def random_triangles(rng, n, size=0.2, box=1.0):
    """n random triangles (float32): centres uniform in [0, box]^3, vertices within ``size``."""
    c = rng.uniform(0.0, box, (n, 1, 3))
    return (c + rng.uniform(-size, size, (n, 3, 3))).astype(np.float32)


def random_scene(rng, n, size_mode="mixed", flat_axis=None, dup_frac=0.0, degen_frac=0.0):
    """A varied random scene of ``n`` float32 triangles in roughly [0, 1]^3.

    size_mode: "small" (edges ~1e-3..1e-2), "medium" (~0.05..0.3), "huge" (~0.5..2, spanning the
    scene), "sliver" (one edge 1e-6..1e-3 of the others) or "mixed" (each triangle picks one).
    flat_axis: 0, 1 or 2 sets that coordinate of every vertex to one value (zero extent).
    dup_frac / degen_frac: fraction of triangles replaced by copies of others / zero-area ones
    (repeated vertex or collinear), always leaving at least one proper triangle.
    """
    modes = ("small", "medium", "huge", "sliver")
    pick = rng.integers(0, len(modes), n) if size_mode == "mixed" else np.full(n, modes.index(size_mode))
    centres = rng.uniform(0.0, 1.0, (n, 3))
    tris = np.empty((n, 3, 3))
    for f in range(n):
        mode = modes[pick[f]]
        if mode == "small":
            s = 10.0 ** rng.uniform(-3, -2)
        elif mode == "medium":
            s = rng.uniform(0.05, 0.3)
        elif mode == "huge":
            s = rng.uniform(0.5, 2.0)
        else:
            s = rng.uniform(0.05, 0.5)
        tri = centres[f] + rng.normal(0.0, s, (3, 3))
        if mode == "sliver":
            tri[2] = tri[1] + (tri[1] - tri[0]) * 10.0 ** rng.uniform(-6, -3) * rng.normal(size=3)
        tris[f] = tri
    if flat_axis is not None:
        tris[:, :, flat_axis] = rng.uniform(0.0, 1.0)
    keep = 0  # triangle 0 stays a proper triangle
    n_dup = int(dup_frac * n)
    n_deg = int(degen_frac * n)
    slots = rng.permutation(np.arange(1, n)) if n > 1 else np.zeros(0, int)
    for s in slots[:n_dup]:
        tris[s] = tris[rng.integers(0, n)]
    for s in slots[n_dup : n_dup + n_deg]:
        if rng.random() < 0.5:
            tris[s, 2] = tris[s, rng.integers(0, 2)]
        else:
            tris[s, 2] = tris[s, 0] + rng.uniform(-2, 3) * (tris[s, 1] - tris[s, 0])
    out = tris.astype(np.float32)
    assert np.linalg.norm(np.cross(out[keep, 1] - out[keep, 0], out[keep, 2] - out[keep, 0]).astype(np.float64)) > 0
    return out


def random_rays(rng, n, lo, hi, outside=0.5, aim=False):
    """n rays: origins uniform in the box [lo, hi] grown by ``outside`` times its size on each
    side (so some start inside the grid, some outside); directions random unit vectors, or, with
    ``aim``, towards random points of the box [lo, hi] (so more rays hit something).
    Returns float64 origins and directions (n, 3)."""
    lo = np.asarray(lo, np.float64)
    hi = np.asarray(hi, np.float64)
    ext = hi - lo
    o = rng.uniform(lo - outside * ext, hi + outside * ext, (n, 3))
    if not aim:
        d = rng.normal(size=(n, 3))
    else:
        d = rng.uniform(lo, hi, (n, 3)) - o
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return o, d


@pytest.fixture(scope="module")
def harness(tmp_path_factory):
    """The harness compiled from its sources beside the repository (as its build.sh does, without
    installing anything), or a skip saying what is missing."""
    from gridrt.app.bench.native import HARNESS_DIR  # deferred: the app's import only where the harness is asked for

    src = HARNESS_DIR / "embree_bench.cpp"
    if not src.is_file():
        pytest.skip(f"the native Embree harness is not beside this clone ({src} is absent)")
    gxx = shutil.which("g++")
    if gxx is None:
        pytest.skip("no g++ to compile the native Embree harness")
    out = tmp_path_factory.mktemp("harness") / "embree_bench"
    p = subprocess.run([gxx, "-O2", "-march=native", "-std=c++17", "-o", str(out), str(src), "-lembree3", "-lpthread"],
                       capture_output=True, text=True)
    if p.returncode != 0:
        pytest.skip(f"the native Embree harness does not compile here (Embree 3's headers: libembree-dev): "
                    f"{p.stderr.strip()[-200:]}")
    return out
