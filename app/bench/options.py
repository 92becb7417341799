"""Command-line options the benchmarks share: comma-separated lists of numbers, grid kinds, thread
counts, runs and warm-up, and the frame-by-frame benchmarks' options, checked before any scene
loads."""

import math

from gridrt.config import GRID_KINDS, GridParams
from gridrt.errors import InputError
from gridrt.frame import ViewSpec
from gridrt.grid.registry import get_builder
from gridrt.threads import check_threads, warn_more_threads_than_cores

from ..cli import add_density_args, defaults, option_help


def int_list(text, what, lo=1):
    try:
        vals = [int(x) for x in str(text).split(",") if x.strip()]
    except ValueError:
        raise InputError(f"{what}: expected comma-separated integers, got {text!r}") from None
    if not vals or min(vals) < lo:
        raise InputError(f"{what}: need integers >= {lo}, got {text!r}")
    return list(dict.fromkeys(vals))


def float_list(text, what):
    try:
        vals = [float(x) for x in str(text).split(",") if x.strip()]
    except ValueError:
        raise InputError(f"{what}: expected comma-separated numbers, got {text!r}") from None
    if not vals or not all(math.isfinite(v) and v > 0 for v in vals):
        raise InputError(f"{what}: need positive finite numbers, got {text!r}")
    return list(dict.fromkeys(vals))


def grid_list(text):
    """Grid kinds from --grid text 'uniform,two_level' (each of gridrt.config.GRID_KINDS), in order,
    without repeats."""
    kinds = list(dict.fromkeys(k.strip() for k in str(text).split(",") if k.strip()))
    for k in kinds:
        if k not in GRID_KINDS:
            raise InputError(f"unknown grid kind {k!r} in --grid; choose from {', '.join(GRID_KINDS)}")
    if not kinds:
        raise InputError(f"--grid: need at least one of {', '.join(GRID_KINDS)}")
    return kinds


def add_grid_kind_args(q):
    """--grid (grid kinds, comma-separated: measured side by side), --top-density and --leaf-density
    (a two-level grid's densities) of a benchmark; :func:`grid_kinds` reads them."""
    q.add_argument("--grid", default=defaults(GridParams)["grid"], help=option_help("--grid", several=True))
    add_density_args(q)


def grid_kinds(a):
    """The grid kinds of a benchmark's --grid, its --top-density and --leaf-density checked too
    (before any scene loads)."""
    GridParams(top_density=a.top_density, leaf_density=a.leaf_density)
    return grid_list(a.grid)


def thread_list(text):
    """Thread counts from '1,2' (validated), default: 1 and all cores; more than the cores is
    warned about once (the runs are measured all the same: a scaling experiment)."""
    cores = check_threads(None)
    if text is None:
        return sorted({1, cores})
    threads = [check_threads(t) for t in int_list(text, "--threads")]
    warn_more_threads_than_cores(max(threads))
    return threads


def check_runs(runs, warmup):
    if runs < 1:
        raise InputError(f"--runs must be at least 1, got {runs}")
    if warmup < 0:
        raise InputError(f"--warmup must be >= 0, got {warmup}")


def check_frame_args(a):
    """The options the frame-by-frame benchmarks share: --runs/--warmup, --size, --dt, --strategy."""
    check_runs(a.runs, a.warmup)
    if a.size < 1:
        raise InputError(f"--size must be positive, got {a.size}")
    if not (math.isfinite(a.dt) and a.dt > 0):
        raise InputError(f"--dt must be a positive number of seconds, got {a.dt}")
    if a.strategy != "auto":
        get_builder(a.strategy)


def add_dt_arg(q):
    """--dt, the seconds between the frames of a frame-by-frame benchmark (default: ViewSpec's)."""
    dt = defaults(ViewSpec)["dt"]
    q.add_argument("--dt", type=float, default=dt, help=option_help("--dt", f"1/{1 / dt:g}"))
