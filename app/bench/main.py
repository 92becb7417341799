"""``gridrt bench SUBCOMMAND``: benchmarks.  Each subcommand writes a CSV, PNG plots, a short
``summary.md`` and ``machine.json`` (CPU model, cores, threads used, versions, commit, load
average, effective cores) into ``--out``, and shows progress bars.  Every timing is the median of ``--runs`` runs
after ``--warmup`` untimed runs (numba compiles, buffers grow), with min and max.

This module makes the ``bench`` parser and the options every benchmark has (:func:`common`); each
benchmark's module adds its own subcommand (``add_parser(bsub, common)``), runs it and writes its
report: :mod:`~gridrt.app.bench.core`, :mod:`~gridrt.app.bench.build`,
:mod:`~gridrt.app.bench.frame`, :mod:`~gridrt.app.bench.trade`, :mod:`~gridrt.app.bench.peers`,
:mod:`~gridrt.app.bench.native`, :mod:`~gridrt.app.bench.start`, :mod:`~gridrt.app.bench.packets`,
:mod:`~gridrt.app.bench.looks` and :mod:`~gridrt.app.cluster.scaling`.  The helpers they share sit beside them: scenes
(:mod:`~gridrt.app.bench.scenes`), option checks (:mod:`~gridrt.app.bench.options`), statistics
(:mod:`~gridrt.app.bench.stats`), the machine record (:mod:`~gridrt.app.bench.machine`), files and
figures (:mod:`~gridrt.app.bench.output`).
"""

import gridrt  # noqa: F401  (sets NUMBA_NUM_THREADS before numba loads)

from ..cluster import scaling
from . import build, core, frame, looks, native, packets, peers, start, trade
from .scenes import scenes_help

#: the benchmarks, in the order ``gridrt bench --help`` lists them
BENCHMARKS = (core, build, frame, trade, peers, native, start, packets, looks, scaling)


def common(q, out, runs=5, warmup=1, scenes=None):
    """The options every benchmark has; ``scenes`` = (defaults, fallback) adds --scenes."""
    q.add_argument("--runs", type=int, default=runs, help=f"timed runs per figure, median reported (default {runs})")
    q.add_argument("--warmup", type=int, default=warmup, help=f"untimed runs first (default {warmup})")
    q.add_argument("--out", default=f"out/bench_{out}", help=f"output folder (default out/bench_{out})")
    q.add_argument("--quick", action="store_true", help="tiny scenes and sizes, one run (smoke test)")
    q.add_argument("--no-progress", action="store_true", help="no progress bars")
    if scenes:
        q.add_argument("--scenes", default=None, help=scenes_help(*scenes))


def add_parser(sub):
    p = sub.add_parser("bench", help="benchmarks: CSV + PNG plots + summary.md (medians after warm-up)",
                       description=__doc__.split("\n\n")[0])
    bsub = p.add_subparsers(dest="bench", required=True)
    for bench in BENCHMARKS:
        bench.add_parser(bsub, common)
    return p
