"""Headless frame dump: PNG per frame plus a per-frame stats CSV.  Imports neither glfw nor
moderngl; runs the same FramePipeline as the viewer."""

import math
import signal
import sys
from pathlib import Path

from tqdm import tqdm

from gridrt.coldstart import CompileHelper
from gridrt.errors import GridrtError, InputError
from gridrt.frame import ViewSpec
from gridrt.pipeline import FramePipeline
from gridrt.warmup import PROGRESS_LINE, compile_progress

from . import cli
from .cluster.dump import dump_on_cluster
from .cluster.scheduler import add_cluster_args, wants_cluster
from .frame_out import (
    FrameWriteError, FrameWriter, StopSignals, encode_frame, frame_medians, nothing_to_do, replace_mode, resumed, run_settings,
)


def add_parser(sub):
    p = sub.add_parser("dump", help="render frames headless to PNG + stats.csv",
                       description="Render an animated scene headless: DIR/frame_00000.png ... and DIR/stats.csv "
                                   "(a row per frame: timings, the grid's kind, densities, cells, references and "
                                   "bytes, the rays' figures), and DIR/run.json (the run's settings, for --resume: its "
                                   "FrameSpec in the wire format, and --save-buffers). "
                                   "Whatever stops a dump, DIR holds whole frames only, each with its row.")
    cli.add_scene_args(p)
    cli.add_grid_args(p)
    cli.add_render_args(p)
    p.add_argument("--frames", type=int, default=60, help="number of frames (default 60)")
    view = cli.defaults(ViewSpec)
    p.add_argument("--t0", type=float, default=view["t0"],
                   help="time of the first frame, seconds (default %(default)g)")
    p.add_argument("--dt", type=float, default=view["dt"], help=cli.option_help("--dt", f"{view['dt']:.6g}"))
    p.add_argument("--out", type=Path, default=Path("out/dump"),
                   help="output folder (created); one that holds another dump is refused unless --overwrite or "
                        "--resume")
    again = p.add_mutually_exclusive_group()
    again.add_argument("--overwrite", action="store_true",
                       help="replace the dump in --out: its frames, buffers, stats.csv and run.json are removed first")
    again.add_argument("--resume", action="store_true",
                       help="continue the dump in --out after its last complete frame (same options; --frames and "
                            "--threads may differ); the frames are those of one run")
    p.add_argument("--save-buffers", action="store_true",
                   help="also write frame_NNNNN_t.npy (float32 hit distance, inf: miss) and "
                        "frame_NNNNN_id.npy (int32 triangle id, -1: miss), shape (height, width)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--no-helper", dest="helper", action="store_false", help=cli.option_help("--no-helper"))
    g = add_cluster_args(p)
    g.add_argument("--chunk", type=int, default=None,
                   help="frames per task on a cluster (default: about four tasks per worker, at most 16 frames)")
    p.set_defaults(func=run)
    return p


def run(a):
    if a.frames < 1:
        raise InputError(f"--frames must be at least 1, got {a.frames}")
    for name in ("t0", "dt"):
        if not math.isfinite(getattr(a, name)):
            raise InputError(f"--{name} must be finite")
    spec = cli.frame_spec(a)  # every setting checked before the cluster, the folder or the scene
    if wants_cluster(a):  # (imports Dask only then)
        return dump_on_cluster(a, spec)
    if a.chunk is not None:
        raise InputError("--chunk applies to a cluster run: give it with --workers or --scheduler")
    # the notice appears when numba really starts compiling (a cold cache, or settings whose kernels
    # this machine has not compiled yet), not when every kernel loads from the cache; then, unless
    # --no-progress, which kernel compiles and how many are done
    display = CompileDisplay(progress=not a.no_progress)
    try:
        with compile_progress(display):
            return _dump(a, spec, display)
    finally:
        display.close()


#: printed (once, on stderr) when the first kernel of a dump starts compiling
COMPILING = "Compiling numba kernels (about 10-60 s the first time; cached for later runs)..."


def _say_compiling():
    tqdm.write(COMPILING, file=sys.stderr)  # above the progress bar, if one is showing
    sys.stderr.flush()


class CompileDisplay:
    """Shows a cold start on stderr (a ``report`` for :func:`gridrt.warmup.compile_progress`):
    the COMPILING notice once, at the first compile; then, with ``progress``, the kernel numba is
    compiling and the kernels done out of those expected: a bar on a terminal, else one line per
    kernel (``compiling gridrt.trace.cgt.trace_packet (14/43 kernels done, 9.2 s)``) and a last
    line with the total."""

    def __init__(self, progress=True, file=None):
        self.progress = progress
        self.file = file or sys.stderr
        self.tty = bool(getattr(self.file, "isatty", lambda: False)())
        self.noticed = False
        self.bar = None
        self.helper_bar = None
        self.last = None

    def __call__(self, p, started):
        if not self.noticed:
            self.noticed = True
            _say_compiling()
        self.last = (p.done, p.expected, p.seconds)
        if not self.progress:
            return
        if self.tty:
            if self.bar is None:
                self.bar = tqdm(total=p.expected, desc="compiling", unit="kernel", file=self.file, mininterval=0)
            self.bar.total = p.expected
            self.bar.n = p.done
            self.bar.set_postfix_str(p.kernel or "", refresh=False)
            self.bar.refresh()
        elif started:
            tqdm.write(f"gridrt: {p}", file=self.file)
            self.file.flush()

    def helper(self, line):
        """Show a line of the cold start's helper process (gridrt.coldstart): the kernel it is
        compiling and its count, or its last line."""
        if not self.noticed:
            self.noticed = True
            _say_compiling()
        if not self.progress:
            return
        m = PROGRESS_LINE.match(line)
        if self.tty and m:
            if self.helper_bar is None:
                self.helper_bar = tqdm(desc="helper process compiling", unit="kernel", file=self.file, mininterval=0)
            self.helper_bar.total = int(m.group(3))
            self.helper_bar.n = int(m.group(2))
            self.helper_bar.set_postfix_str(m.group(1), refresh=False)
            self.helper_bar.refresh()
        elif not self.tty or line.startswith("compiled "):
            tqdm.write(f"gridrt: helper process: {line}", file=self.file)
            self.file.flush()

    def close(self):
        if self.helper_bar is not None:
            self.helper_bar.close()
            self.helper_bar = None
        if self.bar is not None:
            self.bar.set_postfix_str("", refresh=False)
            self.bar.close()
            self.bar = None
        elif self.progress and self.last is not None:
            done, expected, seconds = self.last
            tqdm.write(f"gridrt: compiled {done}/{expected} kernels in {seconds:.1f} s", file=self.file)
            self.file.flush()


def _dump(a, spec, display):
    """The dump of ``spec`` (FrameSpec) with the options ``a`` (frames, output, progress), its cold
    start shown by ``display`` (CompileDisplay)."""
    out = Path(a.out)
    writer = FrameWriter(out, spec, run_settings(a), a.frames, mode=replace_mode(a))
    rows = []
    bar = error = helper = None

    def stop_now(signum):  # nothing of a frame is being written: end without waiting for it
        writer.exit_now(signum, lead="\n" if bar is not None and not bar.disable else "")

    with StopSignals(now=stop_now) as stop:
        try:
            with stop.deferred():
                start = writer.check()
            if start >= a.frames:
                return nothing_to_do(writer, start)
            # on a cold cache, a helper process compiles the first frame's ray casting while this
            # one loads the scene and compiles its grid build (gridrt.coldstart)
            helper = CompileHelper.start(spec, spec.view.time(start)) if a.helper else None
            pipe = FramePipeline.from_spec(spec)
            if helper is not None:
                pipe.before_render = lambda kinds: helper.wait(kinds, display.helper)
            if start:
                pipe.resume(start, spec.view.t0, writer.origin)
            with stop.deferred():
                writer.begin()
            bar = tqdm(range(start, a.frames), desc=f"dump {pipe.scene.name}", unit="frame", disable=a.no_progress,
                       file=sys.stderr, initial=start, total=a.frames)
            for i in bar:
                if stop():
                    break
                # a signal while the frame renders ends the run at once (nothing of the frame is
                # written yet); while it is written, after the frame
                fr = pipe.step(spec.view.time(i))
                item = encode_frame(fr, a.save_buffers)
                with stop.deferred():
                    writer.write(i, item)
                rows.append(fr.stats)
                bar.set_postfix(build=f"{fr.stats['build_ms']:.1f}ms", render=f"{fr.stats['render_ms']:.1f}ms")
        except GridrtError as e:
            if not isinstance(e, FrameWriteError) and (not writer.begun or writer.done == 0):
                raise  # (no frame to speak of: the error as it is)
            error = e
        except KeyboardInterrupt:  # (one raised before the handlers were in place)
            stop.signum = stop.signum or signal.SIGINT
        finally:
            if helper is not None:
                helper.stop()
            with stop.deferred():  # (temporary files go whatever comes now)
                if bar is not None:
                    bar.close()
                writer.close()
    if error is not None or stop():
        return writer.stopped(error=error, signum=stop.signum)
    # frames that compiled kernels are not rendering times: the medians leave them out
    med, note = frame_medians(rows)
    print(
        f"wrote {len(rows)} frames to {out}/{resumed(start, a.frames)} ({pipe.scene.name}, {rows[0]['triangles']} "
        f"triangles, {rows[0]['width']}x{rows[0]['height']}, {rows[0]['strategy']}, {rows[0]['threads']} threads, "
        f"{rows[0]['grid']} grid of {rows[0]['bytes_per_tri']:.1f} bytes per triangle): "
        f"median build {med('build_ms'):.2f} ms, render {med('render_ms'):.2f} ms, frame {med('frame_ms'):.2f} ms{note}"
    )
    return 0
