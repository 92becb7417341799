"""``gridrt bench packets``: where a CGT packet's time goes.

A frame's primary rays are traced packet by packet on one thread, as the CGT render traces them
(8x8-pixel packets in 16-pixel tiles, watertight test), by a driver kernel that passes a profile
to :func:`gridrt.trace.cgt.trace_packet`; the cycle counter is read at every phase boundary and
around every triangle test.  Phases: camera rays; gather, setup and bounds; macro-cell slab
checks; slice ranges and prefetch; cell visits, the mailbox and the box and frustum culls; the
triangle tests; retiring rays; the gathers of packets split by direction class.  Shading and writing the image are the
CGT render's time (one thread, lambert) less the driver's without the profile.  The profile's
own cost is reported (the driver with and without it); the phases are shares of the profiled
run's cycles, scaled to the unprofiled driver's time.
"""

import numpy as np
from numba import njit

import gridrt  # noqa: F401
from gridrt.config import PACKET_PRECISIONS, GridParams, RenderParams
from gridrt.errors import InputError
from gridrt.frame import FrameSpec
from gridrt.grid.build import GridBuilder
from gridrt.trace import cgt
from gridrt.trace.grids import grid_arrays
from gridrt.trace.render import Renderer

from .machine import finish_machine, machine_info
from .options import check_runs
from .output import md_table, out_dir, progress, write_csv, write_json, write_summary
from .scenes import camera_rays, resolve_scene, scene_list, seen_through
from .stats import timings

PACKET_SCENES = ["lucy:twist", "icosphere:1310720:twist"]
PACKET_FALLBACK = ["icosphere:81920:twist", "icosphere:1310720:twist"]
TILE = 16
#: the phases reported, in order (cgt.PROFILE_PHASES, with "cells" less the tests)
PHASES = ("rays", "setup", "macro", "slice", "cells", "tests", "retire", "split")
PHASE_TEXT = {
    "rays": "camera rays", "setup": "gather, setup, bounds", "macro": "macro-cell slab checks",
    "slice": "slice ranges, prefetch", "cells": "cell visits, mailbox, culls", "tests": "triangle tests",
    "retire": "retiring rays", "split": "incoherent packets split by class",
}


def add_parser(bsub, common):
    p = bsub.add_parser("packets", help="where a CGT packet's time goes: phases of the packet traversal, per packet",
                        description=__doc__.split("\n\n")[0])
    common(p, "packets", runs=3, warmup=1, scenes=(PACKET_SCENES, PACKET_FALLBACK))
    p.add_argument("--size", type=int, default=1024, help="square image edge (default 1024)")
    p.add_argument("--views", default="frame,fill", help="frame (the scene's camera) and/or fill (moved in until "
                   "90%% of the pixels hit) (default frame,fill)")
    p.add_argument("--precision", default="float64,float32",
                   help="precisions of the packets' triangle tests, comma-separated (RenderParams.packet_precision; "
                        "default float64,float32)")
    p.set_defaults(func=run_packets)


@njit(cache=True, error_model="numpy")
def profile_frame(g, basis, W, H, prof, f32):
    """Trace the frame's primary rays through the grid g (GridArrays) as packets of up to PK x PK
    pixels in TILE-pixel tiles, row-major, on this thread; ``prof`` (cgt.NPROF,) int64 or None;
    f32: float32 triangle tests.  Returns the number of pixels hit."""
    PN = cgt.PN
    S = np.empty(cgt.NS * PN)
    io = np.empty(cgt.NIO * PN)
    mb = np.empty(cgt.MBOX, np.int32)
    hits = 0
    for ty0 in range(0, H, TILE):
        for tx0 in range(0, W, TILE):
            for py0 in range(ty0, min(ty0 + TILE, H), cgt.PK):
                for px0 in range(tx0, min(tx0 + TILE, W), cgt.PK):
                    pw = min(cgt.PK, min(tx0 + TILE, W) - px0)
                    ph = min(cgt.PK, min(ty0 + TILE, H) - py0)
                    n = pw * ph
                    t = cgt._now(prof)
                    cgt._camera_rays(basis, W, H, px0, py0, pw, ph, io)
                    cgt._lap(prof, cgt.P_RAYS, t)
                    cgt.trace_packet(g, n, io, cgt.PacketQuery(0.0, True, False, f32, True), S, mb, np.inf, prof)
                    for j in range(n):
                        hits += io[cgt.IO_F * PN + j] >= 0.0
    return hits


def packet_spec(scene, size, precision):
    """The FrameSpec of a ``bench packets`` configuration before its camera: the SceneSpec ``scene``,
    gridded on one thread and rendered on one with the CGT traversal in TILE-pixel tiles, the
    packets' triangle tests in ``precision``, at size x size (every other setting the engine's
    default)."""
    render = RenderParams(threads=1, traversal="cgt", tile=TILE, packet_precision=precision)
    return FrameSpec(scene=scene, grid=GridParams(threads=1), render=render).resized(size, size)


def measure(sc, size, view, runs, warmup, precision="float64"):
    """One scene and view: a row of times (ms medians) and the per-phase split."""
    origin, cam, *_ = camera_rays(sc, size, fill=view == "fill")
    spec = seen_through(packet_spec(sc.spec, size, precision), cam)
    tris = np.ascontiguousarray(sc.scene.triangles_at(0.0, origin=origin), np.float32)
    grid = GridBuilder(spec.grid).build(tris)
    g = grid_arrays(grid, tris)
    cam, rp = spec.camera(), spec.render
    basis = cam.basis()
    f32 = rp.packet_precision == "float32"
    renderer = Renderer()
    render_ms = timings(lambda: renderer.render(grid, tris, cam, rp), runs, warmup)[0]
    trace = timings(lambda: profile_frame(g, basis, size, size, None, f32), runs, warmup)[0]
    profs = []

    def profiled():
        prof = np.zeros(cgt.NPROF, np.int64)
        profile_frame(g, basis, size, size, prof, f32)
        profs.append(prof)

    prof_ms = timings(profiled, runs, warmup)[0]
    prof = np.median(np.array(profs[warmup:]), axis=0)
    cyc = {name: float(prof[i]) for i, name in enumerate(cgt.PROFILE_PHASES)}
    cyc["cells"] -= cyc["tests"]  # the tests are timed inside the cell visits
    total = sum(cyc.values())
    row = dict(scene=sc.label, triangles=len(tris), view=view, size=size, precision=precision,
               hit_fraction=profile_frame(g, basis, size, size, None, f32) / size**2,
               packets=int(prof[cgt.C_PACKETS]), slices=int(prof[cgt.C_SLICES]), cells=int(prof[cgt.C_CELLS]),
               tests=int(prof[cgt.C_TESTS]), render_ms=render_ms, trace_ms=trace, profiled_ms=prof_ms)
    row["shade_ms"] = row["render_ms"] - trace
    for name in PHASES:
        row[f"{name}_ms"] = cyc[name] / total * trace
    return row


def run_packets(a):
    check_runs(a.runs, a.warmup)
    views = [v.strip() for v in a.views.split(",") if v.strip()]
    for v in views:
        if v not in ("frame", "fill"):
            raise InputError(f"unknown view {v!r} in --views; choose from frame, fill")
    precisions = [v.strip() for v in a.precision.split(",") if v.strip()]
    for v in precisions:
        if v not in PACKET_PRECISIONS:
            raise InputError(f"unknown precision {v!r} in --precision; choose from {', '.join(PACKET_PRECISIONS)}")
    if not precisions:
        raise InputError("--precision needs at least one of " + ", ".join(PACKET_PRECISIONS))
    size = 64 if a.quick else a.size
    runs, warmup = (1, 1) if a.quick else (a.runs, a.warmup)
    specs, note = scene_list(a.scenes, PACKET_SCENES, PACKET_FALLBACK, quick=["icosphere:1280"] if a.quick else None)
    if note:
        print(f"note: {note}")
    out = out_dir(a.out)
    info = machine_info([1], probe=not a.quick)
    scenes = [resolve_scene(s) for s in specs]
    bar = progress(len(scenes) * len(views) * len(precisions), "bench packets", a.no_progress)
    rows = []
    for sc in scenes:
        for view in views:
            for prec in precisions:
                rows.append(measure(sc, size, view, runs, warmup, prec))
                bar.update()
    bar.close()
    info = finish_machine(info)
    write_csv(rows, out / "packets.csv")
    write_json(info, out / "machine.json")
    table = []
    for r in rows:
        per = 1e6 / r["packets"]  # ns per packet from ms
        table.append([f"{r['scene']} [{r['view']}]", r["precision"], f"{r['triangles']:,}", f"{r['hit_fraction']:.2f}",
                      f"{r['render_ms']:.1f}", f"{r['shade_ms']:.1f}", f"{r['trace_ms']:.1f}",
                      *(f"{r[f'{p}_ms'] * per:.0f} ({100 * r[f'{p}_ms'] / r['render_ms']:.0f}%)" for p in PHASES),
                      f"{r['tests'] / r['packets']:.1f}", f"{r['cells'] / r['packets']:.1f}",
                      f"{r['profiled_ms'] / r['trace_ms']:.2f}"])
    body = [f"{size}x{size} primary rays, one thread, {warmup} warm-up + {runs} timed runs (medians).  Render: the "
            "CGT render (lambert, no shadows); shading + output = render less the traced time; trace: the driver "
            "without the profile.  Per phase: ns per packet, and in brackets its share of the render.  Tests and "
            "cells: per packet.  Overhead: the profiled driver's time over the unprofiled one's.", "",
            *md_table(["scene", "tests in", "triangles", "hit", "render ms", "shading + output ms", "trace ms",
                       *(PHASE_TEXT[p] for p in PHASES), "tests", "cells", "profile overhead"], table)]
    write_summary(out / "summary.md", "Where a CGT packet's time goes", info, [("Phases", body)])
    for r in rows:
        print(f"{r['scene']} [{r['view']}] {r['precision']}: render {r['render_ms']:.1f} ms = shading {r['shade_ms']:.1f} + trace "
              f"{r['trace_ms']:.1f}: " + ", ".join(f"{p} {r[f'{p}_ms']:.1f}" for p in PHASES))
    print(f"wrote {out}/packets.csv, summary.md, machine.json")
    return 0
