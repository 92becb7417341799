"""The cold start's progress display (gridrt.warmup.compile_progress and the dump's display of it).

What compiled is read independently of the display: numba writes one cache index file
(``<module>.<function>-<line>.pyXY.nbi``) per kernel it compiles with cache=True, and a dispatcher's
``signatures`` list what it compiled in this process.
"""

import importlib
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
from numba import njit

from gridrt.warmup import compile_progress, kernels_reached

REPO = Path(__file__).resolve().parents[1]
PACKAGE = __name__.split(".")[0]


@njit  # not cached: compiles at its first call with each argument type
def _leaf(x):
    return x * 2


@njit
def _middle(x):
    return _leaf(x) + 1


@njit
def _top(x):
    return _middle(x) + _leaf(x)


@njit
def _alone(x):
    return x - 1


def test_compile_progress_names_kernels_and_counts_them():
    events = []

    def report(p, started):
        events.append((started, p.kernel, p.again, p.done, p.expected))

    assert {id(k) for k in kernels_reached(_top)} == {id(_top), id(_middle), id(_leaf)}
    with compile_progress(report, package=PACKAGE) as progress:
        assert _top(3) == 13
        assert len(_top.signatures) == len(_middle.signatures) == len(_leaf.signatures) == 1
        # the three kernels were expected from the start: the top one's call tree
        assert events[0] == (True, f"{__name__}._top", False, 0, 3)
        started = [e[1] for e in events if e[0]]
        assert sorted(started) == sorted(f"{__name__}.{n}" for n in ("_top", "_middle", "_leaf"))
        assert (progress.done, progress.expected, progress.kernel) == (3, 3, None)
        n = len(events)
        assert _top(3) == 13 and len(events) == n, "a compiled kernel reported again"
        assert _leaf(2.5) == 5.0  # another argument type: compiles again, counted once
        assert len(_leaf.signatures) == 2
        assert events[n] == (True, f"{__name__}._leaf", True, 3, 3)
        assert _alone(1) == 0  # a kernel nobody expected: the total grows
        assert events[-1][1:] == (None, False, 4, 4)
    assert "4/4 kernels done" in str(progress)
    with compile_progress(report, package=PACKAGE):
        assert _top(4) == 17 and _alone(2) == 1  # all compiled: nothing to report
    assert len(events) == n + 4
    with compile_progress(report, package="not_this_package"):
        assert _alone(2.5) == 1.5  # compiles, but not one of the package's kernels
    assert len(_alone.signatures) == 2 and len(events) == n + 4


@njit
def _late(x):
    return x + 3


def test_compile_progress_ignores_a_compile_it_did_not_see_start():
    """A compile already under way in another thread when the progress begins (an earlier run's
    background compile in the same process) ends under it: that end is not one of its compiles,
    and numba's event, raised inside the compile, must not fail."""
    from numba.core import event

    events = []
    with compile_progress(lambda p, started: events.append((started, p.done)), package=PACKAGE) as progress:
        event.end_event("numba:compile", data={"dispatcher": _top, "args": (), "return_type": None})
        assert (progress.done, progress.expected, events) == (0, 0, [])
        assert _late(1) == 4  # a compile it sees whole is counted as before
        assert (progress.done, progress.expected) == (1, 1) and events == [(True, 0), (False, 1)]


def gridrt(*args, env):
    return subprocess.run([sys.executable, "-m", "gridrt", *args], cwd=REPO, capture_output=True, text=True,
                          env={**os.environ, **env}, timeout=900)


LINE = re.compile(r"gridrt: compiling (\S+)( again \(other argument types\))? \((\d+)/(\d+) kernels done, ([\d.]+) s\)$")
LAST = re.compile(r"gridrt: compiled (\d+)/(\d+) kernels in ([\d.]+) s$")


def index_files(folder):
    """{(module file stem, function): (size, mtime)} of the numba cache index files under folder."""
    out = {}
    for p in Path(folder).rglob("*.nbi"):
        stem, func = re.match(r"(?:inner-)?(\w+)\.(.+)-\d+\.py\d+\.nbi$", p.name).groups()
        out[(stem, func)] = (p.stat().st_size, p.stat().st_mtime_ns)
    return out


HELPER = re.compile(r"gridrt: helper process: compiling (\S+)( again \(other argument types\))? "
                    r"\((\d+)/(\d+) kernels done, ([\d.]+) s\)$")
HELPER_LAST = re.compile(r"gridrt: helper process: compiled (\d+)/(\d+) kernels in ([\d.]+) s$")


def _check_counts(shown, last, what):
    """The lines of one compiling process (this one's, or its helper's) count as they should."""
    done = [int(d) for _, _, d, _, _ in shown]
    expected = [int(e) for _, _, _, e, _ in shown]
    seconds = [float(s) for *_, s in shown]
    # the expected count grows with each call tree and drops the kernels of a finished tree that numba
    # pruned for its argument types (the shadow path, the bounding-box build's overlap test): never
    # below the kernels done
    assert done == sorted(done) and seconds == sorted(seconds) and all(d <= e for d, e in zip(done, expected)), what
    assert all(d < e for (_, a, *_), d, e in zip(shown, done, expected) if not a), \
        f"{what}: a kernel started for the first time with every expected kernel done"
    named = {name for name, *_ in shown}
    again = [name for name, a, *_ in shown if a]
    assert all(name in named for name in again)
    assert len(shown) == len(named) + len(again), f"{what}: a kernel named again without 'again'"
    assert int(last[0]) == int(last[1]) == len(named), (what, last)
    return named


def _module_and_function(name):
    return name.rpartition(".")[0].rpartition(".")[2], name.rpartition(".")[2]


@pytest.mark.slow
def test_cold_dump_shows_what_compiles_and_warm_dump_compiles_nothing(tmp_path):
    """A first frame of the default scene on an empty numba cache names every kernel it compiles
    (the cache folder's index files, one per compiled kernel, are the reference) and counts them
    up to the total; on two cores or more its helper process compiles the ray casting (its lines
    name those kernels, and this process compiles none of them) while this one compiles the scene
    and the grid build; the same dump again loads everything from the cache and says nothing."""
    cache = tmp_path / "cache"
    env = {"NUMBA_CACHE_DIR": str(cache)}
    args = ["dump", "--frames", "1", "--size", "16x12", "--out", str(tmp_path / "d")]
    r = gridrt(*args, env=env)
    assert r.returncode == 0, r.stderr
    assert r.stderr.count("Compiling numba kernels") == 1
    lines = [s.strip() for s in re.split(r"[\r\n]", r.stderr)]
    shown = [m.groups() for m in map(LINE.search, lines) if m]
    last = [m.groups() for m in map(LAST.search, lines) if m]
    by_helper = [m.groups() for m in map(HELPER.search, lines) if m]
    helper_last = [m.groups() for m in map(HELPER_LAST.search, lines) if m]
    assert shown and len(last) == 1, r.stderr
    named = _check_counts(shown, last[0], "this process")
    helped = set()
    if len(os.sched_getaffinity(0)) >= 2:
        assert by_helper and len(helper_last) == 1, r.stderr
        helped = _check_counts(by_helper, helper_last[0], "the helper process")
        assert "gridrt.trace.cgt.frame._render_tiles" in helped and not any(".trace." in n for n in named), \
            (sorted(named), sorted(helped))
        assert any(".grid." in n for n in named) and not any(".grid." in n for n in helped)
    else:
        assert not by_helper and not helper_last, r.stderr
    for name in named | helped:  # each name is a real kernel of the package
        module, _, func = name.rpartition(".")
        assert module.startswith("gridrt.") and hasattr(getattr(importlib.import_module(module), func), "py_func")
    compiled = index_files(cache)
    # every kernel cached was named by the process that compiled it (both compile the scene's)
    assert {_module_and_function(n) for n in named | helped} == set(compiled)
    # a render without shadows compiles no shadow path (the CGT kernel gets light=None, numba prunes it)
    assert not any(n.endswith(".shadow_ray") for n in named | helped), sorted(named | helped)

    r = gridrt(*args, "--overwrite", env=env)  # the same folder: replace the first dump's frame
    assert r.returncode == 0, r.stderr
    assert "Compiling numba kernels" not in r.stderr and "gridrt: compil" not in r.stderr, r.stderr
    assert "helper process" not in r.stderr, r.stderr
    assert index_files(cache) == compiled, "the warm run compiled something"


@pytest.mark.slow
def test_bench_start_quick(tmp_path):
    """``gridrt bench start --quick``: one cold run (it compiles kernels), one cold run with
    --no-helper (every kernel in the dump's process: as many or fewer, the helper compiles the
    scene's kernels again) and warm runs (they compile none), in the CSV and the summary."""
    import csv

    out = tmp_path / "start"
    r = subprocess.run([sys.executable, "-m", "gridrt", "bench", "start", "--quick", "--no-progress", "--out",
                        str(out)], cwd=REPO, capture_output=True, text=True, timeout=900)
    assert r.returncode == 0, r.stderr
    with open(out / "start.csv") as fh:
        rows = list(csv.DictReader(fh))
    cold = [row for row in rows if row["kind"] == "cold"]
    one = [row for row in rows if row["kind"] == "cold, no helper"]
    warm = [row for row in rows if row["kind"].startswith("warm")]
    assert len(cold) == len(one) == 1 and warm
    assert int(cold[0]["kernels"]) >= int(one[0]["kernels"]) > 10 and all(int(row["kernels"]) == 0 for row in warm)
    assert all(float(row["wall_s"]) > 0 and float(row["cpu_s"]) > 0 for row in rows)
    import json

    assert json.loads((out / "machine.json").read_text())["threads_used"] == [os.cpu_count()]  # the dump's default
    summary = (out / "summary.md").read_text()
    assert "| cold | 1 |" in summary and "| cold, no helper | 1 |" in summary and "| warm | 1 |" in summary


@pytest.mark.parametrize("args, message", [
    (["--dump-args", "--frames 3"], "--dump-args sets --frames"),
    (["--dump-args", "'unclosed"], "--dump-args"),
    (["--dump-args", "--threads two"], "--threads must be an integer"),
    (["--runs", "0"], "--runs must be >= 1"),
    (["--cold-runs", "-1"], "--cold-runs must be >= 0"),
])
def test_bench_start_bad_arguments(tmp_path, args, message):
    r = subprocess.run([sys.executable, "-m", "gridrt", "bench", "start", "--no-progress", "--out", str(tmp_path / "s"),
                        *args], cwd=REPO, capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and message in r.stderr and "Traceback" not in r.stderr, r.stderr


def test_default_dump_imports_no_heavy_module(tmp_path):
    """The default scene's dump (a warm start's work) imports none of the modules it does not
    need: mesh loaders (trimesh, pygltflib), plots (matplotlib), the viewer's GL and UI, the
    benchmarks and the viewer's own modules."""
    heavy = ("trimesh", "pygltflib", "matplotlib", "glfw", "moderngl", "imgui_bundle", "gridrt.app.bench",
             "gridrt.app.viewer")
    code = (
        "import sys; from gridrt.app.__main__ import main; "
        f"rc = main(['dump', '--frames', '1', '--size', '16x12', '--no-progress', '--out', r'{tmp_path}']); "
        f"print('LOADED', [m for m in {heavy!r} if m in sys.modules], rc)"
    )
    r = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=900)
    assert r.returncode == 0, r.stderr
    assert "LOADED [] 0" in r.stdout, r.stdout


@pytest.mark.slow
def test_no_helper_compiles_every_kernel_here(tmp_path):
    """``--no-helper``: the same cold first frame compiles every kernel in the dump's own process,
    the ray casting included, and starts no helper."""
    cache = tmp_path / "cache"
    r = gridrt("dump", "--frames", "1", "--size", "16x12", "--no-helper", "--out", str(tmp_path / "d"),
               env={"NUMBA_CACHE_DIR": str(cache)})
    assert r.returncode == 0, r.stderr
    lines = [s.strip() for s in re.split(r"[\r\n]", r.stderr)]
    named = {m.group(1) for m in map(LINE.search, lines) if m}
    assert "gridrt.trace.cgt.frame._render_tiles" in named and any(".grid." in n for n in named), sorted(named)
    assert "helper process" not in r.stderr, r.stderr
    assert {_module_and_function(n) for n in named} == set(index_files(cache))
