"""``gridrt bench SUBCOMMAND``: benchmarks.  Each subcommand writes a CSV, PNG plots, a short
``summary.md`` and ``machine.json`` (CPU model, cores, threads used, versions, commit, load
average, effective cores) into ``--out``, and shows progress bars.  Every timing is the median of ``--runs`` runs
after ``--warmup`` untimed runs (numba compiles, buffers grow), with min and max.

* ``core``:  serial grid build (bbox and exact insertion) and primary-ray Mrays/s (DDA and CGT)
  at 1 thread and all cores on a ~100k and a ~1M triangle mesh.
* ``build``: build strategies x thread counts x scenes, total and per stage (Ize et al.
  2006's "Comparison build methods" and "Individual steps"; :func:`gridrt.app.bench.build.run_build_sweep`),
  and a render of each configuration's grid (render ms, tests and cells per ray).
* ``frame``: animation + rebuild + render per frame at 1024x1024 for each scene at 1 thread and
  all cores (Ize et al. 2006's "Total performance", CGT's fps table); CGT traversal by default (DDA on
  request), static/moving split on and off.

``build``, ``frame`` and ``peers`` take ``--grid`` (grid kinds, comma-separated: uniform,two_level
measures both side by side) with ``--top-density`` and ``--leaf-density``; every row records the
grid kind asked for and built, the densities, cells (a two-level grid's leaf cells), references,
grid bytes and bytes per triangle (:func:`gridrt.app.bench.output.grid_columns`).
* ``trade``: every knob that trades speed for accuracy against a brute-force float64 reference
  (:mod:`gridrt.app.bench.trade`).
* ``peers``: the same animated mesh and rays through Intel Embree (embreex) side by side
  (:mod:`gridrt.app.bench.peers`).
* ``start``: cold (fresh numba cache) and warm start of ``gridrt dump --frames 1`` to its first
  frame, wall and CPU time (:mod:`gridrt.app.bench.start`).
* ``cluster``: frames/s of a dump in one process against local Dask clusters
  (:mod:`gridrt.app.bench.cluster_bench`).

``build`` and ``frame`` take ``--workers N`` / ``--scheduler ADDRESS`` to spread their
configurations over a Dask cluster (:mod:`gridrt.app.bench.on_cluster`).
"""

import gridrt  # noqa: F401  (sets NUMBA_NUM_THREADS before numba loads)
from gridrt.config import INSERT_MODES, SHADING_MODES, TRAVERSALS, GridParams

from ..cli import add_packet_args, defaults
from ..cluster import add_cluster_args
from .build import BUILD_FALLBACK, BUILD_RENDER_SIZE, BUILD_SCENES, run_build
from .core import CORE_FALLBACK, CORE_SCENES, run_core
from .frame import FRAME_FALLBACK, FRAME_SCENES, FRAME_TRAVERSAL, run_frame
from .options import add_grid_kind_args
from .scenes import scenes_help


def add_parser(sub):
    p = sub.add_parser("bench", help="benchmarks: CSV + PNG plots + summary.md (medians after warm-up)",
                       description=__doc__.split("\n\n")[0])
    bsub = p.add_subparsers(dest="bench", required=True)

    def common(q, out, runs=5, warmup=1, scenes=None):
        """The options every benchmark has; ``scenes`` = (defaults, fallback) adds --scenes."""
        q.add_argument("--runs", type=int, default=runs, help=f"timed runs per figure, median reported (default {runs})")
        q.add_argument("--warmup", type=int, default=warmup, help=f"untimed runs first (default {warmup})")
        q.add_argument("--out", default=f"out/bench_{out}", help=f"output folder (default out/bench_{out})")
        q.add_argument("--quick", action="store_true", help="tiny scenes and sizes, one run (smoke test)")
        q.add_argument("--no-progress", action="store_true", help="no progress bars")
        if scenes:
            q.add_argument("--scenes", default=None, help=scenes_help(*scenes))

    c = bsub.add_parser("core", help="serial build ms (bbox, exact) and primary-ray Mrays/s on ~100k and ~1M triangles")
    common(c, "core", scenes=(CORE_SCENES, CORE_FALLBACK))
    c.add_argument("--size", type=int, default=1024, help="square image edge for the ray figures (default 1024)")
    c.add_argument("--threads", default=None, help="thread counts for the ray figures (default: 1 and all cores)")
    c.add_argument("--traversal", default=",".join(TRAVERSALS), help=f"ray traversals, comma-separated of "
                   f"{', '.join(TRAVERSALS)} (default {','.join(TRAVERSALS)}: DDA and CGT side by side)")
    c.set_defaults(func=run_core)

    b = bsub.add_parser("build", help="build strategies x threads x scenes, total and per stage")
    common(b, "build", warmup=2, scenes=(BUILD_SCENES, BUILD_FALLBACK))
    b.add_argument("--strategies", default=None, help="comma-separated strategy names (default: all)")
    b.add_argument("--threads", default=None, help="thread counts (default: 1 .. all cores)")
    g = defaults(GridParams)
    b.add_argument("--insert", choices=INSERT_MODES, default=g["insert"],
                   help=f"insertion test (default {g['insert']})")
    b.add_argument("--lambda", dest="density", type=float, default=g["density"],
                   help=f"grid density (default {g['density']:g})")
    b.add_argument("--macro", type=int, default=g["macro"], help=f"macro-cell edge in cells (default {g['macro']})")
    add_grid_kind_args(b)
    b.add_argument("--size", type=int, default=BUILD_RENDER_SIZE,
                   help="square image edge of a render of each configuration's last grid, for its render ms, tests "
                        f"and cells per ray (0: no render; default {BUILD_RENDER_SIZE})")
    b.add_argument("--back-to-back", action="store_true",
                   help="build each configuration's frames in a row, as a viewer rebuilds with one builder (its "
                        "buffers stay in cache); default: strategies round-robin, fairer under host noise but "
                        "every build of a large scene starts with its buffers out of cache")
    add_cluster_args(b, "configurations (each measured whole by one worker, its builds back to back)")
    b.set_defaults(func=run_build)

    f = bsub.add_parser("frame", help="rebuild + render per frame at 1024x1024 per scene, 1 thread and all cores")
    common(f, "frame", warmup=2, scenes=(FRAME_SCENES, FRAME_FALLBACK))
    f.add_argument("--threads", default=None, help="thread counts (default: 1 and all cores)")
    f.add_argument("--size", type=int, default=1024, help="square image edge (default 1024)")
    f.add_argument("--strategy", default="auto",
                   help="build strategy (default auto: serial at 1 thread, sort_middle above)")
    f.add_argument("--traversal", default=FRAME_TRAVERSAL, help=f"comma-separated of {', '.join(TRAVERSALS)} (default "
                   f"{FRAME_TRAVERSAL}: the packet traversal the fps figures of Ize et al. 2006 and CGT used; single-ray DDA "
                   "takes seconds per frame on some scenes)")
    f.add_argument("--split", choices=("both", "on", "off"), default="both",
                   help="static/moving split for scenes with static parts (default both: measure on and off)")
    f.add_argument("--shading", choices=SHADING_MODES, default="lambert",
                   help="shading of the rendered frames (default %(default)s)")
    f.add_argument("--dt", type=float, default=1.0 / 30.0, help="seconds between frames (default 1/30)")
    add_grid_kind_args(f)
    add_packet_args(f)
    add_cluster_args(f, "configurations (each measured whole by one worker)")
    f.set_defaults(func=run_frame)

    from . import cluster_bench as bench_cluster
    from . import looks as bench_looks, packets as bench_packets, peers as bench_peers, start as bench_start
    from . import trade as bench_trade

    bench_trade.add_parser(bsub, common)
    bench_peers.add_parser(bsub, common)
    bench_start.add_parser(bsub, common)
    bench_packets.add_parser(bsub, common)
    bench_looks.add_parser(bsub, common)
    bench_cluster.add_parser(bsub, common)
    return p
