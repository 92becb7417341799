"""Watertightness at scale and a long-run soak.

Watertightness: probe rays aimed exactly at shared vertices, edge midpoints and random points of
shared edges of closed real meshes (the shipped Armadillo; dragon and Lucy from the development data set, when present), each from an
origin outside the mesh's bounding sphere and in front of every face touching its target (so the
ray crosses the surface there, see tests/test_watertight.py).  On a closed mesh such a ray must
hit no later than its target: a miss or a hit at t > |target - origin| (1 + 1e-6) is a *hole*.
The grid of every build strategy is built once per mesh, and every strategy's grid must hold the
serial one's (cell, triangle) pairs.  The probes are cast in batches through the serial
strategy's grid, and each batch also through the other strategies' grids (in a long run, one
other strategy's per batch, in turn); the watertight test (Woop, Benthin, Wald, JCGT 2013) must
give 0 holes in every grid, and the fast Moller-Trumbore test's hole rate is printed.  Default:
40,000 probes per mesh, through every strategy's grid (1.08M watertight casts in all);
``-m soak``: 10M probes per mesh (GRIDRT_SOAK_RAYS to change it), about 1.25M of them through each
other strategy's grid.

The same meshes through the packet traversal (CGT), with the two probe sets of
tests/test_watertight.py (see its docstring): star packets (up to 8 x 8 rays from one eye, aimed
at a vertex, its one-ring vertices and points of its spokes and link edges, traced by the
packet kernel cgt.trace_packet) and camera rows (512 x 1 images through Renderer.render with
traversal="cgt", every pixel ray crossing one shared edge).  Same criterion, 0 holes with the
watertight test, in float64 and in float32 (packet_precision="float32", t judged within 1e-5);
the fast test's hole rate is printed.  Default: about 190,000 packet probes and
65,536 row rays per mesh; ``-m soak``: at least 10M rays traced as packets and 10M row rays per mesh (GRIDRT_SOAK_RAYS).

Soak: the Marbles scene (8,800 triangles) is rendered frame after frame (t = i / 30 s) by two
pipelines: a reference (serial build, 1 build thread, 1 render thread, DDA) and one whose build
strategy, build thread count (1..16, more than the cores), render thread count and traversal
(DDA / CGT) change every frame, shadows on every third frame in both.  Every frame's image, t and
triangle buffers must be bit-identical to the reference's (exact ties, two triangles at the same
t, would be the only allowed difference and are counted), and the process's resident memory must
stay flat after warm-up (sampled every 10 frames; growth and slope are printed).  The warm-up
ends once the parallel render kernels that compile in a background thread (gridrt.trace.twin: those
the on-disk cache lacks) are compiled, and none may start compiling after it: a compile's memory
is the compiler's, not a leak of the frames.  Default: 300
frames; ``-m soak``: 10,000 (GRIDRT_SOAK_FRAMES).
"""

import os
import time

import numpy as np
import pytest

from conftest import ARMADILLO, available, load_mesh_arrays
from gridrt.config import GridParams, RenderParams
from gridrt.grid import GridBuilder, build_grid, names
from gridrt.pipeline import FramePipeline
from gridrt.scene import make_scene
from gridrt.trace import cast_rays
from gridrt.trace.twin import TWINS
from helpers.watertight import ROW_WIDTH, ProbeMesh, cgt_counts, cgt_report

DRAGON = "static/stanford_dragon/dragon.obj"
LUCY = "static/lucy/Lucy100k.ply"
MESHES = [ARMADILLO, DRAGON, LUCY]
STRATEGIES = names()
REL = 1e-6
BATCH = 200_000


def rss_mb():
    """Resident set size of this process in MiB (Linux /proc)."""
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    pytest.skip("no /proc/self/status: cannot measure RSS on this platform")


# ----------------------------------------------------------------------------------------------
# watertightness at scale


class Prober:
    """A closed mesh (ProbeMesh: its probes) and its grids, one per strategy."""

    def __init__(self, relpath):
        self.name = relpath.split("/")[-1]
        self.mesh = ProbeMesh(*load_mesh_arrays(relpath))
        self.tris = self.mesh.tris
        self.grids = {s: build_grid(self.tris, GridParams(strategy=s, threads=2, density=4.0)) for s in STRATEGIES}

    def check_same_pairs(self):
        """Every strategy's grid holds the serial one's cells and (cell, triangle) pairs (in its
        own layers and order: those may differ)."""
        ref = self.grids["serial"]
        want = np.unique(ref.pairs(), axis=0)
        for s, g in self.grids.items():
            assert np.array_equal(g.spec.dims, ref.spec.dims) and np.array_equal(g.spec.lo, ref.spec.lo), s
            got = np.unique(g.pairs(), axis=0)
            assert np.array_equal(got, want), f"{self.name}: the {s} grid holds other pairs than serial's"


def holes(h, dist):
    return int(((h.tri < 0) | (h.t > dist * (1 + REL))).sum())


def probe(relpath, n_probes):
    """n_probes probes in batches of BATCH through the serial strategy's grid (watertight and fast
    test); the other strategies' grids, which hold the same pairs (checked), take the batches in
    turn: every batch when there are fewer batches than strategies, else every eighth."""
    p = Prober(relpath)
    p.check_same_pairs()
    others = [s for s in STRATEGIES if s != "serial"]
    every = -(-n_probes // BATCH) < len(others)
    t0 = time.perf_counter()
    wt = {s: 0 for s in STRATEGIES}
    cast = {s: 0 for s in STRATEGIES}
    fast = done = dropped = at_target = 0
    seed = 0
    while done < n_probes:
        o, d, dist, drop = p.mesh.edge_probes(1000 + seed, min(BATCH, n_probes - done + 64))
        o, d, dist = o[: n_probes - done], d[: n_probes - done], dist[: n_probes - done]
        dropped += drop
        for s in ["serial"] + (others if every else [others[seed % len(others)]]):
            h = cast_rays(p.grids[s], p.tris, o, d, watertight=True)
            wt[s] += holes(h, dist)
            cast[s] += len(o)
            if s == "serial":
                at_target += int((np.abs(h.t - dist) <= 1e-6 * dist).sum())
                fast += holes(cast_rays(p.grids[s], p.tris, o, d, watertight=False), dist)
        seed += 1
        done += len(o)
    secs = time.perf_counter() - t0
    rate = fast / done
    print(f"FIGURE watertight {p.name}: {done} probes, {sum(cast.values())} watertight casts through the "
          f"{len(STRATEGIES)} strategies' grids ({cast}) in {secs:.1f} s; holes with the watertight test: "
          f"{sum(wt.values())} ({wt}); {at_target} probes ({100 * at_target / done:.1f}%) hit at their target; "
          f"fast (Moller-Trumbore) test: {fast} holes, rate {100 * rate:.3f}%; {dropped} targets dropped (no origin in "
          f"front of all their faces)")
    assert sum(wt.values()) == 0, f"{p.name}: the watertight test let rays through: {wt}"
    assert min(cast.values()) > 0
    assert at_target > 0.5 * done  # the probes really reach their targets (most are not blocked earlier)
    assert dropped < 0.01 * done
    return done, rate


def test_watertight_probes():
    """The Armadillo (shipped in assets/); the data set's closed scans below."""
    probe(ARMADILLO, 40_000)


def test_watertight_probes_data_set_scans():
    """test_watertight_probes and test_cgt_watertight_probes on the data set's other closed scans (the
    dragon, Lucy), each one that is present."""
    for relpath in available(DRAGON, LUCY):
        probe(relpath, 40_000)
        cgt_probe(relpath, 180_000, 128 * ROW_WIDTH)


@pytest.mark.soak
@pytest.mark.parametrize("relpath", MESHES, ids=["armadillo", "dragon", "lucy"])
def test_watertight_probes_soak(relpath):
    probe(relpath, int(os.environ.get("GRIDRT_SOAK_RAYS", "10000000")))


def cgt_probe(relpath, n_rays, n_row_rays):
    """Packet probes until n_rays were traced as packets, camera rows until n_row_rays, in
    batches of about BATCH rays; one FIGURE line (helpers.watertight.cgt_report checks it)."""
    m = ProbeMesh(*load_mesh_arrays(relpath))
    grid = GridBuilder(GridParams(threads=2, density=4.0)).build(m.tris)
    rng = np.random.default_rng(2024)
    t0 = time.perf_counter()
    pk, rows = cgt_counts(m, grid, rng, n_rays, n_row_rays, BATCH)
    cgt_report(relpath.split("/")[-1], pk, rows, time.perf_counter() - t0)


def test_cgt_watertight_probes():
    cgt_probe(ARMADILLO, 180_000, 128 * ROW_WIDTH)


@pytest.mark.soak
@pytest.mark.parametrize("relpath", MESHES, ids=["armadillo", "dragon", "lucy"])
def test_cgt_watertight_probes_soak(relpath):
    n = int(os.environ.get("GRIDRT_SOAK_RAYS", "10000000"))
    cgt_probe(relpath, n, n)


# ----------------------------------------------------------------------------------------------
# soak: strategy and thread count changing every frame


THREADS = (1, 2, 3, 4, 7, 16)


def frame_settings(i):
    """(strategy, build threads, render threads, traversal, shadows) of frame i: every strategy
    and thread count combination comes round (9 and 6 are not coprime, hence the skew)."""
    s = STRATEGIES[i % len(STRATEGIES)]
    bt = THREADS[(i + i // len(STRATEGIES)) % len(THREADS)]
    rt = THREADS[(5 * i + 1) % len(THREADS)]
    return s, bt, rt, ("dda", "cgt")[i % 2], i % 3 == 0


def soak(n_frames, warmup, report_at, width=64, height=48, count=8800):
    ref = FramePipeline(make_scene("marbles", count=count), GridParams(strategy="serial", threads=1),
                        RenderParams(width=width, height=height, threads=1, traversal="dda"))
    var = FramePipeline(make_scene("marbles", count=count), GridParams(), RenderParams(width=width, height=height, traversal="dda"))
    identical = tie_frames = 0
    samples = []
    at = {}
    t0 = time.perf_counter()
    for i in range(n_frames):
        s, bt, rt, trav, shadows = frame_settings(i)
        ref.render_params = RenderParams(width=width, height=height, threads=1, shadows=shadows, traversal="dda")
        var.grid_params = GridParams(strategy=s, threads=bt)
        var.render_params = RenderParams(width=width, height=height, threads=rt, traversal=trav, shadows=shadows)
        a = ref.step(i / 30.0)
        b = var.step(i / 30.0)
        if np.array_equal(a.image, b.image) and np.array_equal(a.tri, b.tri) and np.array_equal(a.t, b.t):
            identical += 1
        else:
            px = (a.tri != b.tri) | (a.image != b.image).any(axis=2) | (a.t != b.t)
            tie = np.array_equal(a.t[px], b.t[px]) and (a.tri[px] >= 0).all() and (b.tri[px] >= 0).all()
            assert tie, (f"frame {i} ({s}, {bt} build / {rt} render threads, {trav}, shadows={shadows}): "
                         f"{int(px.sum())} pixels differ from the serial reference")
            tie_frames += 1
        assert b.stats["strategy"] == s and b.stats["threads"] == bt
        if i + 1 == warmup:
            # the parallel render kernels this run has not found in the on-disk cache compile in a
            # background thread (gridrt.trace.twin) from their second call on: the warm-up ends when
            # they have, so that the figures after it measure frames, not a compiler's memory
            TWINS.wait()
            started_in_warmup = TWINS.started
        if i % 10 == 0 or i == n_frames - 1:
            samples.append((i + 1, rss_mb()))
        if i + 1 in report_at:
            at[i + 1] = rss_mb()
    secs = time.perf_counter() - t0
    late = TWINS.started - started_in_warmup  # background compiles started after the warm-up
    after = np.array([(f, m) for f, m in samples if f >= warmup])
    slope_kb = float(np.polyfit(after[:, 0], after[:, 1], 1)[0] * 1024) if len(after) > 2 else 0.0
    growth = float(after[-1, 1] - after[0, 1])
    print(f"FIGURE soak: {n_frames} frames of {count} triangles at {width}x{height} in {secs:.1f} s "
          f"({1e3 * secs / n_frames:.1f} ms per frame pair); {identical} frames bit-identical to the serial reference, "
          f"{tie_frames} differing only at exact ties; RSS " + ", ".join(f"frame {k}: {v:.1f} MiB" for k, v in at.items())
          + f"; growth after warm-up (frame {warmup}) {growth:+.2f} MiB, slope {slope_kb:+.3f} KiB/frame; "
          f"{TWINS.started} background compiles, {late} after the warm-up")
    assert late == 0, "a parallel kernel compiled after the warm-up: lengthen it, or the RSS figures hold a compile"
    assert identical + tie_frames == n_frames
    return growth, slope_kb


def test_soak_short():
    """300 frames, strategy / threads / traversal changing every frame: identical to serial, and
    RSS flat after 100 frames of warm-up (growth < 8 MiB, slope < 20 KiB per frame)."""
    growth, slope = soak(300, 100, (100, 200, 300))
    assert growth < 8.0 and slope < 20.0


@pytest.mark.soak
def test_soak_long():
    """10,000 frames: identical to serial, RSS flat after 500 frames (growth < 16 MiB, slope
    < 1 KiB per frame: a leak of one small array per frame would show)."""
    n = int(os.environ.get("GRIDRT_SOAK_FRAMES", "10000"))
    growth, slope = soak(n, min(500, n // 4), (500, n // 2, n))
    assert growth < 16.0 and slope < 1.0
