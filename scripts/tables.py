"""What the table scripts of this folder share: the names BENCHMARKS.md's tables give scenes, the
print-out of a script's settings, the common scene, view, size and runs options, and --out (what a
script prints, kept in a folder with the machine record, as the bench commands keep theirs).

The scripts import it as ``tables`` (their own folder is first on ``sys.path`` when run as
``python scripts/NAME.py``)."""

import atexit
import io
import shlex
import sys
from pathlib import Path

import numpy as np

from gridrt.app.bench.affinity import Affinity
from gridrt.app.bench.looks import looks_spec
from gridrt.app.bench.machine import finish_machine, machine_info
from gridrt.app.bench.output import md_table, out_dir, write_json, write_summary
from gridrt.app.bench.scenes import resolve_scene
from gridrt.pipeline import FramePipeline
from gridrt.trace.twin import parallel_first

#: names the tables give the scenes of the development data set
NAMES = {"cesium": "Cesium Man", "lucy": "Lucy"}


def scene_label(text, n):
    """The table's name of a scene spec of n triangles: "Lucy 100k twisted", "Cesium Man 4.7k"."""
    base, *mods = text.split(":")
    count = f"{n / 1e6:.1f}M" if n >= 1e6 else f"{n / 1e3:.0f}k" if n >= 1e4 else f"{n / 1e3:.1f}k"
    return f"{NAMES.get(base, base)} {count}" + (" twisted" if "twist" in mods else "")


def start(p, argv=None):
    """Parse ``argv`` with the parser p (which has :func:`add_out_option`), keep what the script
    prints from here on in --out (:func:`keep_output`) and print the settings; the parsed options."""
    a = p.parse_args(argv)
    keep_output(a.out)
    print_settings(p, a)
    return a


def print_table(header, measure, a):
    """Print the markdown table of the rows ``measure(a)`` makes (the frames compile their parallel
    kernels in this thread, not beside the timing); 0, the exit code."""
    with parallel_first():
        table = md_table(header, measure(a))
    print("\n".join(table))
    return 0


def add_frame_options(p, scenes):
    """The options of a script that runs ``gridrt bench frame`` two ways, back to back: --scenes,
    --threads, --size, --runs, --warmup, --rounds (the table's values as defaults) and --out."""
    p.add_argument("--scenes", default=scenes, help="comma-separated bench scene specs (default: the table's, %(default)s)")
    p.add_argument("--threads", default="1,2", help="thread counts (default: the table's, %(default)s)")
    p.add_argument("--size", type=int, default=1024, help="image edge (default: the table's, %(default)s)")
    p.add_argument("--runs", type=int, default=5, help="timed frames a run (default: the table's, %(default)s)")
    p.add_argument("--warmup", type=int, default=2, help="untimed frames a run (default: the table's, %(default)s)")
    p.add_argument("--rounds", type=int, default=2,
                   help="rounds of the two runs, back to back (default: the table's, %(default)s)")
    add_out_option(p)


def build_render_rows(scenes, labels, got, tris, threads):
    """The rows of a table of build and render ms, one column pair per way of running (labels):
    each cell the medians at the thread counts, "/"-separated, of got[(scene, label, threads)],
    a list of (build ms, render ms) a round; tris: the triangle count of each scene."""
    rows = []
    for text in scenes:
        cells = []
        for i in (0, 1):
            for label in labels:
                cells.append(" / ".join(f"{np.median([v[i] for v in got[text, label, t]]):.1f}" for t in threads))
        rows.append([scene_label(text, tris[text]), *cells])
    return rows


def print_settings(p, a):
    """Each option's value and where it comes from: the table (the option's default) or the command line."""
    for k, v in vars(a).items():
        print(f"{k}: {v} ({'the table' if v == p.get_default(k) else 'command line'})")


def items(text):
    """The non-empty items of a comma-separated option, stripped."""
    return [s.strip() for s in text.split(",") if s.strip()]


def add_ray_options(p, scenes, views, size, runs, what_views, what_runs):
    """--scenes, --views, --size and --runs, the table's values as defaults."""
    p.add_argument("--scenes", default=scenes,
                   help="comma-separated bench scene specs (default: the table's, %(default)s)")
    p.add_argument("--views", default=views, help=f"comma-separated {what_views} of bench peers (default: %(default)s)")
    p.add_argument("--size", type=int, default=size, help=f"size x size rays (default {size}, the table's)")
    p.add_argument("--runs", type=int, default=runs, help=f"{what_runs}, the best kept (default {runs}, the table's)")


def add_out_option(p):
    """--out: the folder where the script keeps what it prints (:func:`keep_output`)."""
    p.add_argument("--out", default=None, help="also write what the script prints into OUT/summary.md, under the "
                   "machine record, and the machine record into OUT/machine.json (as the bench commands' --out)")


class _Tee(io.TextIOBase):
    """Writes to both streams."""

    def __init__(self, first, second):
        self.first, self.second = first, second

    def write(self, text):
        self.second.write(text)
        return self.first.write(text)

    def flush(self):
        self.first.flush()


def keep_output(out):
    """From here on, what the script prints also goes into ``out``/summary.md (under the machine
    record: date, CPU, load, versions, commit and this command line), written with
    ``out``/machine.json when the script ends without an uncaught exception.  None: nothing kept."""
    if not out:
        return
    folder = out_dir(out)
    info = machine_info([])
    info["command"] = "python " + " ".join(shlex.quote(x) for x in sys.argv)
    printed = io.StringIO()
    stdout = sys.stdout
    sys.stdout = _Tee(stdout, printed)
    failed = []
    hook = sys.excepthook

    def on_error(*exc):
        failed.append(exc)
        hook(*exc)

    def write():
        sys.stdout = stdout
        if failed:
            return
        done = finish_machine(info)
        write_json(done, folder / "machine.json")
        write_summary(folder / "summary.md", f"scripts/{Path(sys.argv[0]).name}", done,
                      [("Output", printed.getvalue().rstrip("\n").split("\n"))])
        print(f"wrote {folder}/summary.md, machine.json")

    sys.excepthook = on_error
    atexit.register(write)


def add_own_camera_options(p, scenes):
    """--scenes (NAME:T each, T the time of its first frame) and --size of a script that renders
    scenes through their own camera at SIZE x 3/4 SIZE (the table's values as defaults)."""
    p.add_argument("--scenes", default=scenes, help="comma-separated bench scenes with their own camera, each "
                   "NAME:T (the time of its first frame) (default: the table's, %(default)s)")
    p.add_argument("--size", type=int, default=1024, help="image width; the height is 3/4 of it (default: the "
                   "table's, %(default)s)")


def material_pipeline(sc, size, threads, light_samples=0):
    """The frame pipeline of a bench scene through its own camera at size x 3/4 size: material
    shading with hard shadows, CGT, light_samples k (0: every light)."""
    spec = looks_spec(sc.spec, size, threads, "cgt", "material", True).resized(size, size * 3 // 4)
    return FramePipeline.from_spec(spec.replace(render=spec.render.replace(light_samples=light_samples)), sc.scene)


def own_camera_runs(a):
    """(scene, t, threads) for each NAME:T of --scenes (the bench scene, T its first frame's time)
    and each count of --threads, the process pinned to that many cores while the caller runs it."""
    for text in items(a.scenes):
        name, t = text.rsplit(":", 1)
        sc = resolve_scene(name)
        for T in (int(x) for x in items(a.threads)):
            with Affinity(T):
                yield sc, float(t), T
