"""Shared plumbing of ``gridrt bench``: scene specs, medians, the machine record, CSV /
markdown / plot output, the Pareto front and CPU affinity."""

import datetime
import json
import math
import os
import platform
import shlex
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

import gridrt  # noqa: F401  (sets NUMBA_NUM_THREADS before numba loads)
from gridrt.camera import Camera
from gridrt.errors import InputError
from .sweep import write_csv  # noqa: F401  (one CSV writer for every benchmark)
from gridrt.threads import check_threads

#: the development data set: real meshes in shared/data beside the repository, when present (not
#: part of the repository; a user's clone has the shipped assets/ instead)
DATA = Path(__file__).resolve().parents[3] / "shared" / "data"

#: short names for the real scenes of the development data set
SHORTCUTS = {
    "lucy": "static/lucy/Lucy100k.ply",
    "armadillo": "static/armadillo/armadillo.off",
    "dragon": "static/stanford_dragon/dragon.obj",
    "bunny": "static/stanford_bunny/stanford-bunny.obj",
    "teapot": "static/utah_teapot/teapot.obj",
    "kitchen": "animated/bart/kitchen/aff/kitchen.aff",
    "robots": "animated/bart/robots/aff/Robot.aff",
    "museum": "animated/bart/museum/aff/museum5.aff",
    "cesium": "animated/cesium_man/CesiumMan.glb",
    "tokyo": "animated/littlest_tokyo/LittlestTokyo.glb",
    "sydney": "animated/md2_sydney/sydney.md2",
    "faerie": "animated/md2_faerie/faerie.md2",
    "morphsphere": "animated/animated_morph_sphere/AnimatedMorphSphere.gltf",
}

SCENE_HELP = ("comma-separated scene specs NAME[:N][:twist|wave]: built-ins marbles, icosphere (N = triangle "
              "count), a mesh or animation file, or a short name for a real mesh of the development data set, "
              "when present, or the shipped asset of the same scene (" + ", ".join(SHORTCUTS)
              + "; N = subdivide a static mesh to at least N triangles); twist/wave deform a static mesh")


def scenes_help(defaults, fallback):
    """--scenes help of a benchmark whose default scenes are ``defaults`` (those present) and
    ``fallback`` (when none of them is)."""
    return f"{SCENE_HELP} (default: {', '.join(defaults)}, those of them present; {', '.join(fallback)} when none is)"


@dataclass
class BenchScene:
    """A resolved scene spec: label (the spec text), the :class:`gridrt.scene.SceneSpec` it names,
    the Animation that spec made, and the file it came from (None for built-ins)."""

    label: str
    spec: object
    scene: object
    path: Path | None


#: SHORTCUTS names whose scene also ships in assets/ under another name
_ASSET_NAMES = {"cesium": "cesium_man", "morphsphere": "morph_sphere"}


def data_path(name):
    """The file behind a SHORTCUTS name: the development data set's file, else the same scene's
    shipped asset (assets/, see gridrt.scene.assets) where there is one; may not exist."""
    from gridrt.scene.assets import ASSET_SCENES, asset_path

    p = DATA / SHORTCUTS[name]
    asset = _ASSET_NAMES.get(name, name)
    if not p.exists() and asset in ASSET_SCENES and asset_path(asset).exists():
        return asset_path(asset)
    return p


def scene_available(spec):
    """True unless the spec names a scene of the development data set that is absent."""
    base = spec.split(":")[0].strip().lower()
    return base not in SHORTCUTS or data_path(base).exists()


def _count(text, spec):
    """'1600000', '1.6e6', '100k' or '1.6M' -> int."""
    t = text.strip().lower()
    mult = 1
    if t.endswith("k"):
        mult, t = 1000, t[:-1]
    elif t.endswith("m"):
        mult, t = 1000000, t[:-1]
    try:
        v = float(t) * mult
    except ValueError:
        raise InputError(f"scene spec {spec!r}: {text!r} is neither a triangle count nor twist/wave") from None
    if not math.isfinite(v) or v < 1 or v != int(v):
        raise InputError(f"scene spec {spec!r}: triangle count must be a positive integer, got {text!r}")
    return int(v)


def parse_scene_spec(spec):
    """(source, make_scene kwargs) for NAME[:N][:twist|wave]; see SCENE_HELP."""
    text = spec.strip()
    if not text:
        raise InputError("empty scene spec")
    if Path(text).exists():
        return text, {}
    base, *mods = [m.strip() for m in text.split(":")]
    key = base.lower()
    kw = {}
    if key in SHORTCUTS:
        src = data_path(key)
        if not src.exists():
            raise InputError(f"scene {base!r} needs {src}, which is absent (the development data set is not part "
                             "of the repository; use a built-in scene such as marbles or icosphere)")
    else:
        src = base
    builtin = key in ("marbles", "icosphere")
    for m in mods:
        if m.lower() in ("twist", "wave"):
            kw["animate"] = m.lower()
        else:
            kw["count" if builtin else "subdivide"] = _count(m, spec)
    return str(src), kw


def scene_spec(text):
    """The :class:`gridrt.scene.SceneSpec` of a spec string (see SCENE_HELP)."""
    from gridrt.scene import SceneSpec

    src, kw = parse_scene_spec(text)
    return SceneSpec(source=src, **kw)


def resolve_scene(text):
    """BenchScene for a spec string (see SCENE_HELP): its SceneSpec, made."""
    spec = scene_spec(text)
    p = Path(spec.source)
    return BenchScene(text.strip(), spec, spec.make(), p if p.exists() else None)


def scene_list(text, defaults, fallback, quick=None):
    """Scene specs from ``--scenes`` text, or the defaults whose data is present (``fallback``
    when none is), or ``quick`` in --quick mode.  Returns (specs, note or None)."""
    if text:
        return [s.strip() for s in text.split(",") if s.strip()], None
    if quick is not None:
        return list(quick), None
    have = [s for s in defaults if scene_available(s)]
    missing = [s for s in defaults if not scene_available(s)]
    note = None
    if missing:
        note = f"skipped (absent from {DATA}): {', '.join(missing)}"
    if not have:
        return list(fallback), note
    return have, note


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
    from gridrt.config import GRID_KINDS

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
    from gridrt.config import GRID_KINDS, GridParams

    from ..cli import add_density_args, defaults

    g = defaults(GridParams)
    q.add_argument("--grid", default=g["grid"],
                   help=f"grid kinds, comma-separated of {', '.join(GRID_KINDS)} (uniform,two_level measures both side "
                        f"by side; default {g['grid']})")
    add_density_args(q)


def grid_kinds(a):
    """The grid kinds of a benchmark's --grid, its --top-density and --leaf-density checked too
    (before any scene loads)."""
    from gridrt.config import GridParams

    GridParams(top_density=a.top_density, leaf_density=a.leaf_density)
    return grid_list(a.grid)


def grid_columns(p, stats):
    """The columns every benchmark row records about its grid, from the GridParams ``p`` it was built
    with and its stats (BuildStats, or a frame's FrameStats row): the kind asked for (``grid``:
    uniform, two_level or auto) and the kind built (``grid_built``), the two-level densities, cells
    (a two-level grid's leaf cells), references (its leaf references), grid_bytes and bytes_per_tri
    (grid_bytes / triangles)."""
    return dict(grid=p.grid, grid_built=stats["grid"], top_density=p.top_density, leaf_density=p.leaf_density,
                cells=int(stats["cells"]), references=int(stats["references"]), grid_bytes=int(stats["grid_bytes"]),
                bytes_per_tri=int(stats["grid_bytes"]) / max(int(stats["triangles"]), 1))


def grid_label(r, rows):
    """A row's grid kind, as " (two_level)", for its label in a table or plot of ``rows`` that hold
    more than one kind; "" when they hold one."""
    return f" ({r['grid']})" if len({x.get("grid", "uniform") for x in rows}) > 1 else ""


def thread_list(text):
    """Thread counts from '1,2' (validated), default: 1 and all cores."""
    cores = check_threads(None)
    if text is None:
        return sorted({1, cores})
    return [check_threads(t) for t in int_list(text, "--threads")]


def check_runs(runs, warmup):
    if runs < 1:
        raise InputError(f"--runs must be at least 1, got {runs}")
    if warmup < 0:
        raise InputError(f"--warmup must be >= 0, got {warmup}")


def check_frame_args(a):
    """The options the frame-by-frame benchmarks share: --runs/--warmup, --size, --dt, --strategy."""
    from gridrt.grid.registry import get_builder

    check_runs(a.runs, a.warmup)
    if a.size < 1:
        raise InputError(f"--size must be positive, got {a.size}")
    if not (math.isfinite(a.dt) and a.dt > 0):
        raise InputError(f"--dt must be a positive number of seconds, got {a.dt}")
    if a.strategy != "auto":
        get_builder(a.strategy)


def out_dir(path):
    p = Path(path)
    try:
        p.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise InputError(f"cannot create output folder {p}: {e.strerror}") from None
    return p


def facing_camera(lo, hi, fov=45.0):
    """Look along the box's thinnest axis (slightly tilted) so the mesh fills the view."""
    lo = np.asarray(lo, np.float64)
    hi = np.asarray(hi, np.float64)
    ext = hi - lo
    a = int(np.argmin(ext))
    d = np.full(3, 0.15)
    d[a] = 1.0
    up = (0.0, 1.0, 0.0) if a != 1 else (0.0, 0.0, 1.0)
    big = float(np.sort(ext)[1:].max())
    dist = 0.5 * big / math.tan(math.radians(fov) / 2) * 1.05 + 0.5 * ext[a]
    c = 0.5 * (lo + hi)
    d = d / np.linalg.norm(d)
    return Camera(eye=tuple(c + d * dist), target=tuple(c), up=up, fov=fov)


def scene_camera(scene, tris, t=0.0, origin=None):
    """The scene's own camera at time t (BART, glTF) where it has one, else facing_camera over
    the bounds of tris (F,3,3); ``origin``: the frame tris are in (the scene's camera is moved
    there)."""
    cam = None
    if hasattr(scene, "camera_at"):
        try:
            cam = scene.camera_at(float(t))
        except (AttributeError, NotImplementedError):
            cam = None
        if cam is not None and origin is not None:
            cam = cam.moved(-np.asarray(origin, np.float64))
    if cam is None:
        v = np.asarray(tris).reshape(-1, 3)
        cam = facing_camera(v.min(axis=0), v.max(axis=0))
    return cam


# ----------------------------------------------------------------------------------------------
# statistics
# ----------------------------------------------------------------------------------------------


def stat(values):
    """(median, min, max) of a list of numbers (nan when empty)."""
    v = np.asarray(list(values), np.float64)
    if not len(v):
        return float("nan"), float("nan"), float("nan")
    return float(np.median(v)), float(v.min()), float(v.max())


def put_stat(row, key, values):
    """row[key], row[key_min], row[key_max] = median, min, max of values."""
    row[key], row[key + "_min"], row[key + "_max"] = stat(values)
    return row


def fmt_ms(row, key, digits=1):
    """'median [min-max]' for a put_stat key."""
    m = row.get(key)
    if m is None or (isinstance(m, float) and math.isnan(m)):
        return "n/a"
    return f"{m:.{digits}f} [{row[key + '_min']:.{digits}f}-{row[key + '_max']:.{digits}f}]"


def pareto_front(points, rel_tol=0.03):
    """Indices of the non-dominated points.

    points: list of tuples (cost, err1, err2, ...), all to be minimised; NaN errors count as 0.
    Point a dominates b when a's cost is at most b's cost * (1 - rel_tol) or equal within it,
    every error of a is <= b's, and a is strictly better somewhere beyond the tolerance: costs
    within rel_tol of each other are a tie (timing noise), so neither dominates on cost alone.
    """
    P = [(float(p[0]), *[0.0 if (e is None or math.isnan(e)) else float(e) for e in p[1:]]) for p in points]
    front = []
    for i, b in enumerate(P):
        dominated = False
        for j, a in enumerate(P):
            if i == j:
                continue
            cost_better = a[0] < b[0] * (1.0 - rel_tol)
            cost_tie = not cost_better and a[0] <= b[0] * (1.0 + rel_tol)
            errs_le = all(x <= y for x, y in zip(a[1:], b[1:]))
            errs_lt = any(x < y for x, y in zip(a[1:], b[1:]))
            if errs_le and (cost_better or (cost_tie and errs_lt)):
                dominated = True
                break
        if not dominated:
            front.append(i)
    return front


# ----------------------------------------------------------------------------------------------
# the machine record
# ----------------------------------------------------------------------------------------------


def git_commit():
    """Short commit hash of the repository this code runs from, or 'unknown'."""
    root = Path(__file__).resolve().parents[2]
    try:
        r = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=root, capture_output=True, text=True,
                           timeout=10)
        return r.stdout.strip() or "unknown"
    except (OSError, subprocess.SubprocessError):
        return "unknown"


def _cpu_model():
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def _version(dist):
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version(dist)
    except PackageNotFoundError:
        return "not installed"


_BUSY = ("import time\nt = time.perf_counter()\nx = 0\nfor i in range(3000000):\n    x += i\n"
         "print(time.perf_counter() - t)")


def effective_cores():
    """How many cores' worth of CPU this machine delivers right now: ``n`` busy Python processes
    (n = cpu count) at once against one alone, n * t_alone / t_slowest.  On a shared or
    virtualised host this can be well below the core count (other tenants, CPU quotas)."""
    n = os.cpu_count() or 1

    def run(k):
        procs = [subprocess.Popen([sys.executable, "-c", _BUSY], stdout=subprocess.PIPE, text=True) for _ in range(k)]
        return [float(p.communicate()[0]) for p in procs]

    try:
        alone = min(run(1)[0] for _ in range(2))
        together = max(run(n))
    except (OSError, ValueError):
        return float("nan")
    return round(n * alone / together, 2)


def machine_info(threads):
    """Dict describing this run: date, CPU model, cores, CPUs allowed, threads used, load
    average, memory, versions (python, numpy, numba, embreex, ...), commit, command line."""
    import numba

    try:
        allowed = len(os.sched_getaffinity(0))
    except AttributeError:
        allowed = os.cpu_count()
    mem = ""
    try:
        with open("/proc/meminfo") as fh:
            kb = int(fh.readline().split()[1])
            mem = f"{kb / 2**20:.1f} GiB"
    except (OSError, ValueError, IndexError):
        pass
    try:
        load = [round(x, 2) for x in os.getloadavg()]
    except OSError:
        load = []
    return {
        "date": datetime.datetime.now().astimezone().isoformat(timespec="seconds"),
        "cpu": _cpu_model(),
        "cores": os.cpu_count(),
        "cpus_allowed": allowed,
        "threads_used": list(threads),
        "memory": mem,
        "load_average_start": load,
        "effective_cores_start": effective_cores(),
        "python": platform.python_version(),
        "numpy": np.__version__,
        "numba": numba.__version__,
        "numba_threading_layer": os.environ.get("NUMBA_THREADING_LAYER", "default"),
        "embreex": _version("embreex"),
        "trimesh": _version("trimesh"),
        "matplotlib": _version("matplotlib"),
        "os": platform.platform(),
        "commit": git_commit(),
        "command": "gridrt " + " ".join(shlex.quote(a) for a in sys.argv[1:]) if sys.argv else "",
    }


def finish_machine(info):
    """Add the end-of-run load average (a high one means other processes shared the cores)."""
    try:
        info["load_average_end"] = [round(x, 2) for x in os.getloadavg()]
    except OSError:
        info["load_average_end"] = []
    info["effective_cores_end"] = effective_cores()
    return info


def machine_md(info):
    """Markdown lines for the machine record."""
    noisy = (info.get("load_average_start") or [0])[0]  # the end figure includes this run's own threads
    lines = [
        f"- date: {info['date']}; commit `{info['commit']}`",
        f"- CPU: {info['cpu']}; {info['cores']} cores ({info['cpus_allowed']} allowed); memory {info['memory']}",
        f"- threads used: {', '.join(map(str, info['threads_used']))}",
        f"- python {info['python']}, numpy {info['numpy']}, numba {info['numba']} "
        f"(threading layer {info['numba_threading_layer']}), embreex {info['embreex']}, trimesh {info['trimesh']}",
        f"- load average (1, 5, 15 min) at start {info.get('load_average_start')}, at end "
        f"{info.get('load_average_end')}",
        f"- command: `{info['command']}`",
    ]
    if info.get("workers"):
        lines.append(f"- measured on {info.get('cluster', 'a Dask cluster')}; each row names its worker (CSV columns "
                     "worker, worker_cpu, worker_cores, worker_load_start); the workers' machines:")
        for addr, w in sorted(info["workers"].items()):
            lines.append(f"  - `{addr}`: {w.get('cpu')}; {w.get('cores')} cores; memory {w.get('memory')}; python "
                         f"{w.get('python')}, numpy {w.get('numpy')}, numba {w.get('numba')}; commit `{w.get('commit')}`; "
                         f"effective cores {w.get('effective_cores_start')}")
    eff = [x for x in (info.get("effective_cores_start"), info.get("effective_cores_end")) if x is not None]
    if eff:
        lines.append(f"- effective cores ({info['cores']} busy processes at once against one alone): "
                     f"{info.get('effective_cores_start')} at start, {info.get('effective_cores_end')} at end")
    cores = info["cores"] or 1
    if eff and min(eff) < 0.8 * cores:
        lines.append(f"- **note:** this machine delivered only {min(eff)} of its {cores} cores at some point of the run "
                     "(host contention or a CPU quota): multi-thread timings and speed-ups are lower than the "
                     "hardware allows and vary from run to run.")
    if noisy > 0.5 * cores:
        lines.append(f"- **note:** the 1-minute load average was {noisy:.2f} on {info['cores']} cores at the start: other "
                     "processes shared the CPU during this run, so timings are noisier (and multi-thread "
                     "speed-ups smaller) than on an idle machine; the min column is the least disturbed run.")
    return lines


# ----------------------------------------------------------------------------------------------
# output
# ----------------------------------------------------------------------------------------------





def write_json(obj, path):
    with open(path, "w") as fh:
        json.dump(obj, fh, indent=2, default=str)


def md_table(header, rows):
    """Markdown table from a header list and rows of cell strings."""
    out = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    for r in rows:
        out.append("| " + " | ".join(str(c) for c in r) + " |")
    return out


def write_summary(path, title, info, sections):
    """summary.md: a title, the machine record, then sections (heading, list of lines)."""
    lines = [f"# {title}", "", "## Machine", "", *machine_md(info), ""]
    for heading, body in sections:
        lines += [f"## {heading}", "", *body, ""]
    Path(path).write_text("\n".join(lines))


def figure(nrows=1, ncols=1, w=5.0, h=3.6):
    """A matplotlib Figure on the Agg canvas (no display, no pyplot state)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(w * ncols, h * nrows))
    FigureCanvasAgg(fig)
    return fig, fig.subplots(nrows, ncols, squeeze=False)


def progress(total, desc, disable=False):
    from tqdm import tqdm

    return tqdm(total=total, desc=desc, file=sys.stderr, disable=disable, dynamic_ncols=True)


# ----------------------------------------------------------------------------------------------
# CPU affinity (the only way to limit Embree's own build threads from Python)
# ----------------------------------------------------------------------------------------------


class Affinity:
    """Context manager pinning every thread of this process (and threads they start later) to
    the first ``n`` of the CPUs it may use; restores the previous masks on exit.  A no-op where
    the OS has no sched_setaffinity (``self.applied`` is then False)."""

    def __init__(self, n):
        self.n = n
        self.applied = False
        self._saved = {}

    @staticmethod
    def _tids():
        try:
            return [int(t) for t in os.listdir("/proc/self/task")]
        except OSError:
            return [0]

    def __enter__(self):
        if not hasattr(os, "sched_setaffinity"):
            return self
        cpus = sorted(os.sched_getaffinity(0))
        self.cpus = set(cpus[: self.n]) if self.n <= len(cpus) else set(cpus)
        for tid in self._tids():
            try:
                self._saved[tid] = os.sched_getaffinity(tid)
                os.sched_setaffinity(tid, self.cpus)
            except OSError:
                pass
        self.applied = True
        return self

    def __exit__(self, *exc):
        if not self.applied:
            return False
        allowed = set().union(*self._saved.values()) if self._saved else None
        for tid in self._tids():
            try:
                os.sched_setaffinity(tid, self._saved.get(tid, allowed))
            except (OSError, TypeError):
                pass
        return False
