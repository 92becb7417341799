"""Every parallel build strategy against serial and the brute-force membership reference.

For every registered strategy, thread count in {1, 2, 3, 4, 8, 16} (more threads than this
machine's cores included) and insertion test (bbox, exact), on random hypothesis scenes,
degenerate-heavy scenes, a real mesh and an animated scene, the grid must hold exactly serial's
(cell, triangle) multiset: every cell's sorted contents equal, no reference twice, the CSR
offsets and counts consistent, the macro-cell flags equal.  Serial itself is checked against
``tests/reference.py`` (an independent float64 brute force, ties excepted) on every scene, so
every strategy equals the reference.

Lost updates: many triangles crowded into eight cells, built with 8 and 16 threads again and
again, must give the exact counts for every registered strategy; the same check must catch the
references an unsynchronized insert loses (one interleaving of threads' writes, replayed), and
global_lock's count pass must wait while another thread holds its lock.
"""

import csv
import os
import sys
import threading
import time

import numba
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from numba import njit
from PIL import Image

from conftest import BUNNY, TEAPOT, load_tris, random_scene
from gridrt.camera import Camera
from gridrt.config import GridParams, RenderParams
from gridrt.errors import InputError
from gridrt.grid import GridBuilder, get_builder, names
from gridrt.grid.buffers import GridBuffers
from gridrt.grid.build import make_spec
from gridrt.grid.strategies import sort_last_locks
from gridrt.scene import make_scene
from gridrt.threads import max_threads, use_threads
from gridrt.trace import render

try:  # the shared brute-force reference (another module of the test suite)
    import reference as R
except ImportError:  # pragma: no cover - only while reference.py does not exist
    R = None

EXPECTED_NAMES = [
    "serial", "sort_first", "global_lock", "cell_locks", "lock_pool",
    "thread_grids_merge", "thread_grids", "sort_middle", "counting",
]
STRATEGIES = names()
THREADS = (1, 2, 3, 4, 8, 16)
MODES = ("bbox", "exact")
CORES = os.cpu_count() or 1


# ----------------------------------------------------------------------------------------------
# checks


def _local_ref_bbox(tris, lo, cell, dims):
    """Fallback brute force (bbox rule only) when tests/reference.py is absent: every triangle
    against every cell, float64, grown by INSERT_EPS cells."""
    t = tris.astype(np.float64)
    bmin = t.min(axis=1)
    bmax = t.max(axis=1)
    e = 1e-5 * cell
    rows = []
    for c in range(int(np.prod(dims))):
        ijk = np.array([c % dims[0], c // dims[0] % dims[1], c // (dims[0] * dims[1])])
        cmin = lo + ijk * cell
        cmax = cmin + cell
        hit = ((bmin - e <= cmax) & (bmax + e >= cmin)).all(axis=1)
        rows += [(c, f) for f in np.flatnonzero(hit)]
    return np.array(sorted(rows), np.int64).reshape(-1, 2)


def check_serial_vs_reference(g, tris, mode):
    """Serial's pairs equal the brute-force reference's (ties excepted), and its macro flags the
    occupancy of those pairs."""
    pairs = g.pairs()
    s = g.spec
    if R is not None:
        fn = R.ref_pairs_bbox if mode == "bbox" else R.ref_pairs_exact
        missing, extra = R.compare_pairs(pairs, fn(tris, s.lo, s.cell, s.dims))
        assert not missing and not extra, f"serial {mode}: missing {missing[:5]}, extra {extra[:5]}"
        flags = R.ref_macro_flags(pairs, s.dims, s.macro)
        assert np.array_equal(g.macro_full.astype(bool), flags), f"serial {mode}: macro flags differ from occupancy"
    elif mode == "bbox" and s.n_cells * len(tris) <= 2_000_000:
        assert np.array_equal(pairs, _local_ref_bbox(tris, s.lo, s.cell, s.dims))


def pair_keys(g):
    """Sorted int64 keys cell * F + tri of every stored reference, over all layers, duplicates
    kept (the grid's multiset, read straight from the CSR arrays)."""
    cs = g.cell_start.astype(np.int64)
    C = g.spec.n_cells
    keys = []
    for l in range(g.layers):
        cells = np.repeat(np.arange(C, dtype=np.int64), np.diff(cs[l]))
        keys.append(cells * g.n_triangles + g.tri_ids[cs[l, 0] : cs[l, C]])
    return np.sort(np.concatenate(keys))


def check_grid(g, expect, strategy, threads, what=""):
    """Grid g (built by ``strategy`` with ``threads``) holds exactly ``expect`` = (pairs, macro
    flags) of serial, with a consistent layered CSR layout."""
    pairs_ref, macro_ref = expect
    C = g.spec.n_cells
    L = threads if get_builder(strategy).layered else 1
    tag = f"{strategy} T={threads} {what}"
    cs = g.cell_start.astype(np.int64)
    assert cs.shape == (L, C + 1), tag
    assert g.cell_count.shape == (L, C), tag
    d = np.diff(cs, axis=1)
    assert (d >= 0).all(), f"{tag}: CSR offsets decrease"
    assert np.array_equal(g.cell_count, d), f"{tag}: counts disagree with the offsets"
    assert cs[0, 0] == 0 and np.array_equal(cs[1:, 0], cs[:-1, C]), f"{tag}: layers not back to back"
    assert cs[-1, C] == g.references == g.stats["references"], tag
    assert g.stats["cells"] == C and g.stats["triangles"] == g.n_triangles, tag
    keys = pair_keys(g)
    assert (np.diff(keys) > 0).all(), f"{tag}: a (cell, triangle) reference is stored twice"
    if not np.array_equal(keys, pairs_ref):
        F = g.n_triangles
        a = set(pairs_ref.tolist())
        b = set(keys.tolist())
        miss = [divmod(x, F) for x in sorted(a - b)[:5]]
        extra = [divmod(x, F) for x in sorted(b - a)[:5]]
        raise AssertionError(f"{tag}: {len(a - b)} pairs missing ({miss}), {len(b - a)} extra ({extra})")
    assert np.array_equal(g.macro_full, macro_ref), f"{tag}: macro-cell flags differ from serial"


def check_all_strategies(tris, density=4.0, macro=4, threads=THREADS, strategies=STRATEGIES, modes=MODES):
    """Build tris with every strategy x thread count x insertion test and compare with serial
    (which is compared with the reference).  One GridBuilder per strategy is reused across
    thread counts and modes, so buffer reuse and clearing between layer counts are exercised."""
    expect = {}
    for mode in modes:
        g = GridBuilder(GridParams(strategy="serial", density=density, macro=macro, insert=mode)).build(tris)
        check_serial_vs_reference(g, tris, mode)
        expect[mode] = (pair_keys(g), g.macro_full.copy())
    for s in strategies:
        b = GridBuilder(GridParams(strategy=s, density=density, macro=macro))
        for T in threads:
            for mode in modes:
                g = b.build(tris, GridParams(strategy=s, density=density, macro=macro, insert=mode, threads=T))
                check_grid(g, expect[mode], s, T, mode)


# ----------------------------------------------------------------------------------------------
# registry


def test_registry_names_and_unknown_name():
    assert STRATEGIES == EXPECTED_NAMES
    with pytest.raises(InputError) as e:
        get_builder("sort_sideways")
    for n in EXPECTED_NAMES:
        assert n in str(e.value)
    with pytest.raises(InputError, match="unknown build strategy 'nope'"):
        GridParams(strategy="nope")


def test_strategy_modules_cite_their_source():
    for n in STRATEGIES:
        doc = sys.modules[get_builder(n).__module__].__doc__ or ""
        assert "Ize" in doc or "Lagae" in doc, f"strategy {n}: module docstring cites no source"


def test_thread_count_bounds():
    tris = random_scene(np.random.default_rng(3), 20)
    hi = max_threads()
    assert hi >= 16
    for bad in (0, -1, hi + 1):
        with pytest.raises(InputError, match="thread count"):
            GridParams(strategy="counting", threads=bad)
    g = GridBuilder(GridParams(strategy="counting", threads=hi)).build(tris)
    assert g.stats["threads"] == hi


def test_stats_report_every_stage():
    tris = random_scene(np.random.default_rng(4), 200)
    extra = {"sort_middle": {"bucket_ms"}, "thread_grids_merge": {"merge_ms", "ranges_ms"},
             "thread_grids": {"ranges_ms"}, "sort_first": {"ranges_ms"}, "counting": {"ranges_ms"},
             "global_lock": {"lock_waits", "ranges_ms"}, "cell_locks": {"lock_waits", "ranges_ms"},
             "lock_pool": {"lock_waits", "ranges_ms"}}
    for s in STRATEGIES:
        g = GridBuilder(GridParams(strategy=s, threads=3)).build(tris)
        keys = {"clear_ms", "insert_ms", "macro_ms", "build_ms", "references", "cells", "count_ms", "scatter_ms"}
        keys |= extra.get(s, set())
        assert keys <= set(g.stats), f"{s}: stats lack {keys - set(g.stats)}"
        for k in keys:
            if k.endswith("_ms"):
                assert 0.0 <= g.stats[k] <= g.stats["build_ms"] + 1e-9, (s, k)
        assert g.stats["threads"] == 3 and g.stats["strategy"] == s


def test_thread_grids_keeps_one_layer_per_thread():
    """Layer t holds exactly the references of thread t's block of triangles."""
    tris = random_scene(np.random.default_rng(5), 301)
    F = len(tris)
    serial = GridBuilder(GridParams(strategy="serial")).build(tris)
    sp = serial.pairs()
    for T in (2, 5, 16):
        g = GridBuilder(GridParams(strategy="thread_grids", threads=T)).build(tris)
        assert g.layers == T
        for t in range(T):
            a, b = t * F // T, (t + 1) * F // T
            lo, hi = g.cell_start[t, 0], g.cell_start[t, -1]
            counts = np.diff(g.cell_start[t].astype(np.int64))
            cells = np.repeat(np.arange(g.spec.n_cells), counts)
            layer = np.stack([cells, g.tri_ids[lo:hi]], 1)
            want = sp[(sp[:, 1] >= a) & (sp[:, 1] < b)]
            assert np.array_equal(np.unique(layer, axis=0), want) and len(layer) == len(want), (T, t)


# ----------------------------------------------------------------------------------------------
# scenes


@settings(max_examples=15, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
@given(
    seed=st.integers(0, 2**32 - 1),
    n=st.integers(1, 120),
    size_mode=st.sampled_from(["mixed", "small", "medium", "huge", "sliver"]),
    flat_axis=st.sampled_from([None, None, 0, 1, 2]),
    density=st.floats(0.5, 12.0),
    macro=st.integers(1, 6),
)
def test_random_scenes(seed, n, size_mode, flat_axis, density, macro):
    tris = random_scene(np.random.default_rng(seed), n, size_mode, flat_axis, 0.1, 0.1)
    check_all_strategies(tris, density=density, macro=macro)


@pytest.mark.slow
@settings(max_examples=80, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
@given(
    seed=st.integers(0, 2**32 - 1),
    n=st.integers(1, 400),
    size_mode=st.sampled_from(["mixed", "small", "medium", "huge", "sliver"]),
    flat_axis=st.sampled_from([None, None, 0, 1, 2]),
    dup_frac=st.sampled_from([0.0, 0.1, 0.5]),
    degen_frac=st.sampled_from([0.0, 0.1, 0.5]),
    density=st.floats(0.5, 20.0),
    macro=st.integers(1, 8),
)
def test_random_scenes_slow(seed, n, size_mode, flat_axis, dup_frac, degen_frac, density, macro):
    tris = random_scene(np.random.default_rng(seed), n, size_mode, flat_axis, dup_frac, degen_frac)
    check_all_strategies(tris, density=density, macro=macro)


def _identical(rng):
    """300 copies of one small triangle inside a frame of two big ones: crowded cells."""
    frame = [[[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[1, 1, 1], [0, 1, 1], [1, 0, 1]]]
    t = np.array([[[0.4, 0.4, 0.4], [0.55, 0.45, 0.5], [0.45, 0.6, 0.42]]])
    return np.concatenate([np.array(frame), np.repeat(t, 300, axis=0)]).astype(np.float32)


def _points(rng):
    p = rng.uniform(0, 1, (300, 1, 3))
    t = np.repeat(p, 3, axis=1)
    t[0] = [[0, 0, 0], [1, 0, 0], [0, 1, 1]]
    return t.astype(np.float32)


def _faces(rng):
    quads = []
    for z in range(5):
        quads += [[[0, 0, z], [4, 0, z], [4, 4, z]], [[0, 0, z], [4, 4, z], [0, 4, z]]]
    for x in range(5):
        quads += [[[x, 0, 0], [x, 4, 0], [x, 4, 4]]]
    return np.array(quads, np.float32)


DEGENERATE = {
    "mostly_zero_area": lambda rng: random_scene(rng, 300, degen_frac=0.9),
    "mostly_duplicates": lambda rng: random_scene(rng, 300, dup_frac=0.9),
    "flat_z_one_layer": lambda rng: random_scene(rng, 300, flat_axis=2),
    "flat_x": lambda rng: random_scene(rng, 300, flat_axis=0, degen_frac=0.3),
    "huge_spanning": lambda rng: random_scene(rng, 150, "huge"),
    "slivers": lambda rng: random_scene(rng, 300, "sliver", degen_frac=0.2),
    "single_triangle": lambda rng: random_scene(rng, 1),
    "identical_copies": _identical,
    "points_and_one_triangle": _points,
    "quads_on_cell_faces": _faces,
}


@pytest.mark.parametrize("name", list(DEGENERATE))
def test_degenerate_scenes(name, rng):
    tris = DEGENERATE[name](rng)
    density = 8.0 if name == "quads_on_cell_faces" else 4.0
    check_all_strategies(tris, density=density, macro=2 if name == "quads_on_cell_faces" else 3)


def test_real_mesh_teapot():
    check_all_strategies(load_tris(TEAPOT))


@pytest.mark.slow
def test_real_mesh_bunny_slow():
    check_all_strategies(load_tris(BUNNY))


# ----------------------------------------------------------------------------------------------
# animated scene, strategy and thread count switched every frame


def test_animated_scene_switching_every_frame():
    """One GridBuilder, one animated scene; every frame a different strategy, thread count and
    insertion test (so layer counts change between frames and the clear must cope).  Each grid
    equals a fresh serial build of the same frame, and renders the same image."""
    scene = make_scene("marbles", count=1400, seed=7)
    builder = GridBuilder(GridParams())
    rp = RenderParams(width=40, height=30, threads=2, traversal="dda")
    plan = []
    for i in range(2 * len(STRATEGIES)):
        plan.append((STRATEGIES[(i * 4) % len(STRATEGIES)], THREADS[(i * 5) % len(THREADS)], MODES[(i // 3) % 2]))
    seen = set()
    for i, (s, T, mode) in enumerate(plan):
        tris = scene.triangles_at(0.23 * i).copy()
        ref = GridBuilder(GridParams(strategy="serial", insert=mode)).build(tris)
        if i % 4 == 0:
            check_serial_vs_reference(ref, tris, mode)
        expect = (pair_keys(ref), ref.macro_full.copy())
        cam = Camera.frame(ref.spec.lo, ref.spec.hi, direction=(0.4, 1.0, 0.7))
        want = render(ref, tris, cam, rp)
        g = builder.build(tris, GridParams(strategy=s, threads=T, insert=mode))
        check_grid(g, expect, s, T, f"frame {i}")
        got = render(g, tris, cam, rp)
        assert (want.tri >= 0).mean() > 0.1, "the camera sees too little of the scene for the test to mean much"
        assert np.array_equal(got.tri, want.tri), f"frame {i} {s} T={T}: different triangles hit"
        assert np.array_equal(got.t, want.t), f"frame {i} {s} T={T}: different hit distances"
        assert np.array_equal(got.image, want.image), f"frame {i} {s} T={T}: different image"
        seen.add(s)
    assert seen == set(STRATEGIES)


# ----------------------------------------------------------------------------------------------
# lost updates


def crowded_scene(n=60_000, seed=11):
    """n small triangles in the unit cube; with density 8/n the grid has 2x2x2 cells, so every
    cell receives about n/8 (plus straddlers) references from every thread."""
    rng = np.random.default_rng(seed)
    c = rng.uniform(0.05, 0.95, (n, 1, 3))
    t = c + rng.uniform(-0.01, 0.01, (n, 3, 3))
    t[0] = [[0, 0, 0], [1, 0, 0], [0, 1, 0]]
    t[1] = [[1, 1, 1], [0, 1, 1], [1, 0, 1]]
    return t.astype(np.float32)


def expected_counts(tris, spec):
    """Per-cell reference counts by brute force in numpy (bbox rule), (C,) int64."""
    lo, cell, dims = spec.lo, spec.cell, spec.dims
    t = tris.astype(np.float64)
    e = 1e-5
    i0 = np.clip(np.floor((t.min(1) - lo) / cell - e), 0, dims - 1).astype(np.int64)
    i1 = np.clip(np.floor((t.max(1) - lo) / cell + e), 0, dims - 1).astype(np.int64)
    out = np.zeros(spec.n_cells, np.int64)
    for k in range(dims[2]):
        for j in range(dims[1]):
            for i in range(dims[0]):
                ijk = np.array([i, j, k])
                inside = ((i0 <= ijk) & (ijk <= i1)).all(axis=1)
                out[i + dims[0] * (j + dims[1] * k)] = inside.sum()
    return out


def insert_direct(strategy, tris, spec, threads, times=None):
    """Run only ``strategy.insert`` on fresh buffers (its stage times and counters go to
    ``times``); returns (counts (C,), sorted pairs (P,2), references)."""
    L = strategy.layers(threads)
    bufs = GridBuffers()
    bufs.prepare(spec, L)
    bufs.set_views(spec, L)
    use_threads(threads)
    refs = strategy.insert(tris, spec, bufs, threads, False, {} if times is None else times)
    C = spec.n_cells
    start = bufs.start.astype(np.int64)
    counts = bufs.count.sum(axis=0).astype(np.int64)
    R_ = len(bufs.ref_buffer)
    cells, ids = [], []
    for l in range(L):
        for c in range(C):
            # clipped: a wrong insert may leave offsets out of order or out of range
            a = min(max(int(start[l, c]), 0), R_)
            b = min(max(int(start[l, c + 1]), a), R_)
            ids.append(bufs.ref_buffer[a:b])
            cells.append(np.full(b - a, c))
    pairs = np.stack([np.concatenate(cells), np.concatenate(ids)], 1).astype(np.int64)
    order = np.lexsort((pairs[:, 1], pairs[:, 0]))
    return counts, pairs[order], int(refs)


def lost_updates(result, want_counts, want_pairs):
    """How many references were lost (or duplicated) compared with the brute force: the sum of
    |count differences| plus the pairs that differ.  0 means exact."""
    counts, pairs, refs = result
    bad = int(np.abs(counts - want_counts).sum()) + abs(refs - int(want_counts.sum()))
    if len(pairs) != len(want_pairs):
        bad += abs(len(pairs) - len(want_pairs)) + 1
    else:
        bad += int((pairs != want_pairs).any(axis=1).sum())
    return bad


def interleaved(want_pairs, n_tris, n_cells, threads, stale):
    """What an unsynchronized insert leaves when ``threads`` threads (thread t inserting the t-th
    block of triangles, as every strategy splits them) update the same cells at the same moment,
    made from the correct pairs ``want_pairs`` (P, 2) by replaying one interleaving:

    * ``"count"``: every thread reads a cell's count before the other threads' writes land, so
      the last thread's write wins and the cell keeps only that thread's references;
    * ``"slot"``: two threads claim the same slot of one cell, and the later one's triangle id
      overwrites the earlier one's: the counts stay right, one reference is lost and another is
      stored twice.

    Returns (counts, sorted pairs, references) as :func:`insert_direct` gives them, and how many
    references the interleaving lost."""
    cells, ids = want_pairs[:, 0], want_pairs[:, 1]
    bounds = np.array([t * n_tris // threads for t in range(threads)])
    owner = np.searchsorted(bounds, ids, side="right") - 1
    last = np.full(n_cells, -1)
    np.maximum.at(last, cells, owner)
    first = np.full(n_cells, threads)
    np.minimum.at(first, cells, owner)
    if stale == "count":
        keep = owner == last[cells]
        pairs = want_pairs[keep]
        lost = int((~keep).sum())
    else:
        shared = np.flatnonzero(first < last)[0]  # a cell two threads write
        pairs = want_pairs.copy()
        early = np.flatnonzero((cells == shared) & (owner == first[shared]))[0]
        late = np.flatnonzero((cells == shared) & (owner == last[shared]))[0]
        pairs[early, 1] = pairs[late, 1]
        lost = 1
    counts = np.bincount(pairs[:, 0], minlength=n_cells).astype(np.int64)
    order = np.lexsort((pairs[:, 1], pairs[:, 0]))
    return (counts, pairs[order], int(counts.sum())), lost


@pytest.fixture(scope="module")
def crowded():
    tris = crowded_scene()
    v = tris.reshape(-1, 3)
    spec = make_spec(v.min(0), v.max(0), len(tris), GridParams(density=8 / len(tris)))
    assert spec.n_cells == 8
    want = expected_counts(tris, spec)
    serial = insert_direct(get_builder("serial")(), tris, spec, 1)
    assert np.array_equal(serial[0], want), "serial disagrees with the numpy brute-force counts"
    return tris, spec, want, serial[1]


@pytest.mark.parametrize("strategy", STRATEGIES)
def test_lost_updates_crowded(strategy, crowded):
    """Every registered strategy builds the crowded scene exactly, at 8 and 16 threads, every
    time."""
    tris, spec, want, want_pairs = crowded
    reps = 3 if strategy == "global_lock" else 6
    for T in (8, 16):
        for r in range(reps):
            res = insert_direct(get_builder(strategy)(), tris, spec, T)
            assert lost_updates(res, want, want_pairs) == 0, f"{strategy} T={T} rep {r}: lost or duplicated references"


@pytest.mark.parametrize("stale", ["count", "slot"])
@pytest.mark.parametrize("threads", [2, 8])
def test_lost_update_check_catches_interleaved_writes(stale, threads, crowded):
    """The negative control: the check that every strategy passes above catches what an
    unsynchronized insert leaves (one interleaving of its threads' writes replayed on the
    correct pairs, so the loss is there every run): stale counts, and a slot claimed twice."""
    tris, spec, want, want_pairs = crowded
    result, lost = interleaved(want_pairs, len(tris), spec.n_cells, threads, stale)
    assert lost > 0 and len(result[1]) == len(want_pairs) - (lost if stale == "count" else 0)
    assert lost_updates(result, want, want_pairs) >= lost, f"{stale} x{threads}: {lost} lost references not seen"


#: CPU time (of this process: the kernel's threads spinning) the count pass gets while the lock is held
HELD_CPU_S = 0.5

_real_count_locked = sort_last_locks.count_locked


@njit(nogil=True)
def _count_locked_nogil(args):
    _real_count_locked(*args)


def test_global_lock_excludes_and_reports_waits(crowded, monkeypatch):
    """global_lock's count pass takes the one lock around every update.  While another thread
    holds the lock, the pass (run without the GIL in a second thread) changes no count and does
    not finish, whatever CPU time its threads spend spinning (the wait ends on
    :data:`HELD_CPU_S` of CPU time, not on a clock); released, it finishes with the exact counts,
    and the build reports the failed looks at the held lock as ``lock_waits``."""
    tris, spec, want, want_pairs = crowded
    seen = {}

    def count_while_held(*args):
        locks, count = args[-3], args[-2]  # the kernel takes (..., locks, count, waits)
        _count_locked_nogil.compile((numba.typeof(args),))
        locks[:] = 1  # another thread holds the lock
        done = threading.Event()
        worker = threading.Thread(target=lambda: (_count_locked_nogil(args), done.set()), daemon=True)
        cpu0 = time.process_time()
        stuck = time.monotonic() + 600.0  # only against a hang: the wait below ends on CPU time
        worker.start()
        while not done.is_set() and time.process_time() - cpu0 < HELD_CPU_S and time.monotonic() < stuck:
            done.wait(0.01)
        seen["spun_s"] = time.process_time() - cpu0
        seen["finished_while_held"] = done.is_set()
        seen["counted_while_held"] = int(count.sum())
        locks[:] = 0
        worker.join()

    monkeypatch.setattr(sort_last_locks, "count_locked", count_while_held)
    times = {}
    result = insert_direct(get_builder("global_lock")(), tris, spec, 8, times)
    assert not seen["finished_while_held"], "the count pass finished while another thread held the lock"
    assert seen["counted_while_held"] == 0, "the count pass counted while another thread held the lock"
    assert seen["spun_s"] >= HELD_CPU_S, "the count pass's threads never ran while the lock was held"
    assert lost_updates(result, want, want_pairs) == 0, "lost or duplicated references"
    assert times["lock_waits"] > 0, "the build reports no wait although the lock was held"


# ----------------------------------------------------------------------------------------------
# the benchmark sweep (gridrt.app.bench.build, behind `gridrt bench build`)


def test_build_sweep_writes_rows_csv_and_plots(tmp_path):
    from gridrt.app.bench.build import run_build_sweep  # deferred: the benchmark app (tqdm, the cluster code)

    scenes = {
        "marbles": make_scene("marbles", count=700, seed=1),
        "random": random_scene(np.random.default_rng(8), 200),
    }
    strategies = ["serial", "sort_middle", "thread_grids"]
    rows = run_build_sweep(scenes, strategies, [1, 3], runs=3, warmup=1, out_dir=tmp_path, progress=False)
    assert len(rows) == 2 * 3 * 2
    assert {(r["scene"], r["strategy"], r["threads"]) for r in rows} == {
        (sc, s, t) for sc in scenes for s in strategies for t in (1, 3)
    }
    for r in rows:
        for k in ("build_ms", "clear_ms", "insert_ms", "macro_ms"):
            assert 0 <= r[k + "_min"] <= r[k] <= r[k + "_max"], (r["strategy"], k)
        assert r["insert_ms"] <= r["build_ms_max"]
        assert r["runs"] == 3 and r["oversubscribed"] == int(r["threads"] > CORES)
    # the same frames for every strategy and thread count: the same references
    for sc in scenes:
        assert len({r["references"] for r in rows if r["scene"] == sc}) == 1, sc
    assert "bucket_ms" in next(r for r in rows if r["strategy"] == "sort_middle")
    with open(tmp_path / "build_sweep.csv") as fh:
        table = list(csv.DictReader(fh))
    assert len(table) == len(rows)
    assert float(table[0]["build_ms"]) == pytest.approx(rows[0]["build_ms"])
    for name in ("build_methods.png", "build_steps.png"):
        with Image.open(tmp_path / name) as im:
            assert im.size[0] > 300 and im.size[1] > 200


def test_build_sweep_rejects_bad_arguments(tmp_path):
    from gridrt.app.bench.build import run_build_sweep  # deferred: the benchmark app (tqdm, the cluster code)

    tris = random_scene(np.random.default_rng(9), 20)
    with pytest.raises(InputError, match="unknown build strategy"):
        run_build_sweep([tris], ["serial", "fastest"], [1], runs=1, warmup=0, out_dir=None, progress=False)
    with pytest.raises(InputError, match="thread count"):
        run_build_sweep([tris], ["serial"], [0], runs=1, warmup=0, out_dir=None, progress=False)
    with pytest.raises(InputError, match="runs"):
        run_build_sweep([tris], ["serial"], [1], runs=0, warmup=0, out_dir=None, progress=False)
    with pytest.raises(InputError, match="scene"):
        run_build_sweep(["not a scene"], ["serial"], [1], runs=1, warmup=0, out_dir=None, progress=False)
    assert not any(tmp_path.iterdir())
