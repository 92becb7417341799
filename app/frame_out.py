"""Writing a dump's frames (one writer for the one-process dump and the cluster dump): an output
folder only ever holds whole frames, each with its row of ``stats.csv``, whatever stops the run.

A frame's files (``frame_NNNNN.png``, and with ``--save-buffers`` its ``_t.npy`` and ``_id.npy``)
are written under a hidden temporary name beside their final one (``.frame_NNNNN.png.part``),
flushed to disk and renamed; then the frame's row is appended to ``stats.csv`` and flushed to
disk.  A frame is complete when its files are renamed and its row is in ``stats.csv``; frames
complete in order, so a folder holds frames 0 .. n-1.  When a write fails part way (a full disk,
the folder gone), the frame's files are removed and ``stats.csv`` is cut back to its last whole
row; temporary files are removed on every stop.

``run.json`` records the settings of the run: its :class:`gridrt.frame.FrameSpec` in the wire
format (``spec``: :meth:`~gridrt.frame.FrameSpec.to_wire`, a scene file by its absolute path) and
the other options that decide what the frames hold (``settings``: ``save_buffers``), with the
frame count and the pipeline's frame of reference after each frame where it changed (the origin a
resumed run starts from, see :meth:`gridrt.pipeline.FramePipeline.resume`).  A folder that holds
another dump's files is refused unless the run says ``overwrite`` (they are removed first) or
``resume`` (the complete frames are kept and the run goes on after them, with the same settings
only: the spec read back with :meth:`~gridrt.frame.FrameSpec.from_wire`, which refuses one of
another version, must equal the run's but for the thread counts).

A run that stops early (:meth:`FrameWriter.stopped`) says so in one line on stderr, with the
frames complete and why, and exits with 130 (SIGINT), 143 (SIGTERM) or 2 (a write that failed).
SIGINT and SIGTERM (:class:`StopSignals`) never cut a frame's writing short: while files are
written they stop the run after them; otherwise (a frame rendering) they end it at once.
"""

import argparse
import contextlib
import csv
import errno
import io
import json
import os
import re
import signal
import sys
import threading
from dataclasses import fields
from pathlib import Path

import numpy as np

from gridrt.errors import GridrtError, InputError
from gridrt.frame import FrameSpec
from gridrt.pipeline import STATS_COLUMNS

from . import cli

STATS = "stats.csv"
#: what stats.csv and the panel say for a figure that does not apply to a frame (pandas reads it as NaN)
NOT_APPLICABLE = "n/a"
RUN = "run.json"
#: a frame's files: frame number and kind
FRAME_FILE = re.compile(r"frame_(\d{5,})(\.png|_t\.npy|_id\.npy)\Z")
#: the temporary files of a dump (a run killed outright leaves them; the next run removes them)
TEMP_FILE = re.compile(r"\.(frame_\d{5,}(\.png|_t\.npy|_id\.npy)|stats\.csv|run\.json|write-test)\.part\Z")
#: options that do not change what the frames hold: they may differ when a dump is resumed
FREE_OPTIONS = {"func", "command", "out", "no_progress", "helper", "overwrite", "resume", "frames", "threads", "workers",
                "scheduler", "chunk", "listen"}
#: fields of the run's FrameSpec that may differ when a dump is resumed (--threads is free), and
#: those not compared on their own (the render's width and height: the view's size says them)
FREE_FIELDS = {"grid.threads", "render.threads"}
SIZE_FIELDS = {"render.width", "render.height"}
#: the parts of a FrameSpec, in order
SPEC_PARTS = tuple(f.name for f in fields(FrameSpec))


def _options(*adders):
    """The names (dests) of the options that the functions ``adders`` add to a parser."""
    p = argparse.ArgumentParser(add_help=False)
    for add in adders:
        add(p)
    return set(vars(p.parse_args([])))


#: the options that the dump's FrameSpec holds (:func:`gridrt.app.cli.frame_spec` reads them, with
#: the dump's --t0 and --dt): run.json records them as its ``spec``, not among its ``settings``
SPEC_OPTIONS = _options(cli.add_scene_args, cli.add_grid_args, cli.add_render_args) | {"t0", "dt"}
#: whether the folder can be held open and its files named relative to it (POSIX systems; os.replace
#: takes the folder as os.rename does, though supports_dir_fd does not list it)
HOLD_FOLDER = ({os.open, os.unlink, os.rename} <= os.supports_dir_fd and os.listdir in os.supports_fd
               and hasattr(os, "O_DIRECTORY"))
#: exit status and reason of a run stopped by a signal
SIGNALS = {signal.SIGINT: (130, "interrupted (SIGINT)"), signal.SIGTERM: (143, "terminated (SIGTERM)")}


class FrameWriteError(GridrtError):
    """A file of the dump could not be written (the frame being written was removed)."""

    def __init__(self, what, err):
        self.what = what
        self.strerror = (err.strerror or str(err)).lower() if isinstance(err, OSError) else str(err)
        super().__init__(f"cannot write {what}: {self.strerror}")


def stats_columns(stats):
    """stats.csv's columns for the FrameStats ``stats``: STATS_COLUMNS, then its other columns."""
    return list(STATS_COLUMNS) + [k for k in stats if k not in STATS_COLUMNS]


def write_stats_csv(path, rows):
    """A stats.csv of the FrameStats ``rows`` at ``path``, columns and values as the dump writes them."""
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=stats_columns(rows[0]), extrasaction="ignore")
    w.writeheader()
    for r in rows:
        w.writerow({k: fmt(v) for k, v in r.items()})
    Path(path).write_text(buf.getvalue())


def frame_medians(rows):
    """(median, note) of the FrameStats ``rows``: ``median(column)`` is the median over the frames
    that compiled no kernels (their times are not rendering times; over all of them when every
    frame compiled), and ``note`` says what was left out, for a summary line ("" when nothing)."""
    timed = [r for r in rows if not r["compiled"]]
    left_out = len(rows) - len(timed)
    if left_out and timed:
        note = f" ({left_out} frame{'s' if left_out > 1 else ''} that compiled kernels left out)"
    elif left_out:
        note = " (every frame compiled kernels: the medians include compile time)"
    else:
        note = ""
    return (lambda k: float(np.median([r[k] for r in (timed or rows)]))), note


def fmt(v):
    """A stats value as ``stats.csv`` holds it: "n/a" for a figure that does not apply (None)."""
    if v is None:
        return NOT_APPLICABLE
    if isinstance(v, float):
        return f"{v:.6g}"
    return v


def encode_frame(fr, save_buffers):
    """A rendered Frame as the dump writes it: ``{"png": bytes, "stats": dict, "origin": (3,)
    float64}``, plus ``"t"`` and ``"id"`` (``.npy`` bytes) with ``save_buffers``."""
    from PIL import Image  # deferred: Pillow loads when a dump encodes a frame, not for every gridrt command

    buf = io.BytesIO()
    Image.fromarray(fr.image[:, :, :3]).save(buf, format="PNG")
    item = {"png": buf.getvalue(), "stats": dict(fr.stats), "origin": np.array(fr.origin, np.float64)}
    if save_buffers:
        item["t"], item["id"] = npy_bytes(fr.t), npy_bytes(fr.tri)
    return item


def npy_bytes(arr):
    buf = io.BytesIO()
    np.save(buf, arr)
    return buf.getvalue()


def run_settings(a):
    """The options of the dump ``a`` (parsed arguments) that decide what its frames hold and that
    its FrameSpec does not (``save_buffers``), as JSON values."""
    s = {k: v for k, v in vars(a).items() if k not in FREE_OPTIONS and k not in SPEC_OPTIONS}
    return json.loads(json.dumps(s, sort_keys=True, default=str))


def run_spec(spec):
    """The FrameSpec a dump records and a cluster's workers render: ``spec`` with a scene file
    given by a path that exists here made absolute (the same file from any working directory)."""
    source = spec.scene.source
    if os.path.exists(source):
        spec = spec.replace(scene=spec.scene.replace(source=os.path.abspath(source)))
    return spec


def spec_differences(there, now):
    """``[(name, there's value, now's value)]`` for each field in which the FrameSpecs ``there``
    and ``now`` differ, named ``part.field``, as wire values, in the parts' and fields' order;
    the FREE_FIELDS and SIZE_FIELDS are left out."""
    a, b = there.to_wire(), now.to_wire()
    out = []
    for part in SPEC_PARTS:
        for key, value in a[part].items():
            name = f"{part}.{key}"
            if name not in FREE_FIELDS | SIZE_FIELDS and b[part][key] != value:
                out.append((name, value, b[part][key]))
    return out


def _write_all(fd, data):
    view = memoryview(data)
    while view:
        view = view[os.write(fd, view):]


def temp_name(name):
    """The hidden temporary name a file is written under beside its final ``name``."""
    return f".{name}.part"


def write_file(path, data, dir_fd=None):
    """``data`` (bytes) into ``path`` (relative to the folder ``dir_fd`` when given) whole or not
    at all: written to a hidden temporary file beside it, flushed to disk and renamed (the
    temporary file is removed if anything fails)."""
    tmp = put_temp(path, data, dir_fd)
    try:
        os.replace(tmp, path, src_dir_fd=dir_fd, dst_dir_fd=dir_fd)
    except BaseException:
        remove(tmp, dir_fd)
        raise


def put_temp(path, data, dir_fd=None):
    """``data`` written and flushed to disk under ``path``'s temporary name (relative to the
    folder ``dir_fd`` when given); returns that name (nothing is left there if it fails)."""
    head, name = os.path.split(str(path))
    tmp = os.path.join(head, temp_name(name))
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC | getattr(os, "O_CLOEXEC", 0), 0o666, dir_fd=dir_fd)
    try:
        try:
            _write_all(fd, data)
            os.fsync(fd)
        finally:
            os.close(fd)  # (some file systems report a failed write here)
    except BaseException:
        remove(tmp, dir_fd)
        raise
    return tmp


def remove(path, dir_fd=None):
    """Remove a file if it is there (and the folder is)."""
    try:
        os.unlink(path, dir_fd=dir_fd)
    except OSError:
        pass


class FrameWriter:
    """The files of a dump of ``frames`` frames in the folder ``out``, for a run of the FrameSpec
    ``spec`` (recorded as :func:`run_spec`'s) with ``settings`` (:func:`run_settings`); ``mode``:
    None (the folder must hold no other dump), ``"overwrite"`` (another dump's files are removed
    first) or ``"resume"`` (its complete frames are kept; the run goes on after them).

    :meth:`check` (before the scene loads: the folder is made and must be writable; another dump
    there is refused or read), :meth:`begin` (before the first frame: old files removed,
    ``run.json`` written), :meth:`write` per frame in order, :meth:`close` on every exit.
    ``done``: the frames complete (0 .. done-1); ``origin``: the pipeline's origin after frame
    done-1 (None before the first frame).

    The folder is held open from :meth:`check` on and every file is written in it, by name
    relative to it (where the system can): a folder renamed during the run keeps the whole run,
    and one removed stops it at the next write."""

    def __init__(self, out, spec, settings, frames, mode=None):
        if mode not in (None, "overwrite", "resume"):
            raise InputError(f"mode must be None, 'overwrite' or 'resume', got {mode!r}")
        self.out = Path(out)
        self.spec = run_spec(spec)
        self.settings = settings
        self.frames = frames
        self.mode = mode
        self.done = 0
        self.origins = []  # [frame, [x, y, z]]: the origin after that frame, where it changed
        self.columns = None  # stats.csv's header
        self.size = 0  # bytes of stats.csv up to its last whole row
        self.dir = None  # the folder, held open
        self.fd = None  # stats.csv
        self.temps = set()
        self.begun = False

    @property
    def origin(self):
        if self.done == 0 or not self.origins:
            return None
        return np.array(self.origins[-1][1], np.float64)

    def _at(self, name):
        """A file of the folder as the os functions take it with ``dir_fd=self.dir``."""
        return name if self.dir is not None else str(self.out / name)

    # -- before the run ---------------------------------------------------------------------

    def check(self):
        """Make the folder and check it can be written; refuse another dump's files there (or
        read them, to resume).  Returns :attr:`done`."""
        out = self.out
        try:
            out.mkdir(parents=True, exist_ok=True)
            if HOLD_FOLDER and self.dir is None:
                self.dir = os.open(out, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0) | getattr(os, "O_CLOEXEC", 0))
            probe = self._at(temp_name("write-test"))
            os.close(os.open(probe, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o666, dir_fd=self.dir))
            os.unlink(probe, dir_fd=self.dir)
        except OSError as e:
            raise InputError(f"cannot write to the output folder {out}/: {(e.strerror or str(e)).lower()}; "
                             "give a writable --out") from None
        ours = self._ours()
        if not ours:
            return 0
        if self.mode is None:
            pngs = sum(1 for n in ours if n.endswith(".png"))
            raise InputError(f"{out}/ already holds another dump ({pngs} frames{', stats.csv' * (STATS in ours)}); "
                             "give --overwrite to replace it, --resume to continue it, or another --out")
        if self.mode == "resume":
            self._read()
        return self.done

    def _names(self):
        try:
            return os.listdir(self.dir if self.dir is not None else self.out)
        except OSError:
            return []

    def _ours(self):
        """The names in the folder of a dump's files (not its temporary ones)."""
        return [n for n in self._names() if n in (STATS, RUN) or FRAME_FILE.match(n)]

    def _read_file(self, name):
        fd = os.open(self._at(name), os.O_RDONLY, dir_fd=self.dir)
        try:
            with os.fdopen(fd, "rb", closefd=False) as fh:
                return fh.read()
        finally:
            os.close(fd)

    def _read(self):
        """The complete frames of the dump to resume: its settings must be this run's (its spec
        read back with FrameSpec.from_wire, its other options); the rows of stats.csv from frame
        0 on whose files are all there."""
        out = self.out
        try:
            run = json.loads(self._read_file(RUN))
            wire, settings, origins = run["spec"], run["settings"], run["origins"]
        except (OSError, ValueError, KeyError, TypeError):
            raise InputError(f"--resume: {out}/ holds frames but no readable {RUN} (the settings they were made "
                             "with are unknown); give --overwrite to replace them, or another --out") from None
        try:
            spec = FrameSpec.from_wire(wire)
        except InputError as e:
            raise InputError(f"--resume: the settings in {out}/{RUN} cannot be read ({e}); give --overwrite to "
                             "replace the dump, or another --out") from None
        none = object()
        diff = spec_differences(spec, self.spec) + [
            (k, settings.get(k, "unset"), self.settings.get(k, "unset"))
            for k in sorted(set(settings) | set(self.settings)) if settings.get(k, none) != self.settings.get(k, none)]
        if diff:
            shown = ", ".join(f"{k}: {there!r} there, {now!r} now" for k, there, now in diff[:3])
            raise InputError(f"--resume: the dump in {out}/ was made with other settings ({shown}); give the "
                             "same options, --overwrite to replace it, or another --out")
        try:
            data = self._read_file(STATS)
        except OSError:
            data = b""
        names = set(self._names())
        kinds = [".png"] + (["_t.npy", "_id.npy"] if self.settings.get("save_buffers") else [])
        size, done, columns = 0, 0, None
        for line in data.splitlines(keepends=True):
            if not line.endswith(b"\n"):
                break  # a row cut short
            fields = next(csv.reader([line.decode("utf-8", "replace")]), [])
            if columns is None:
                if not fields or fields[0] != "frame":
                    break
                columns = fields
            else:
                whole = len(fields) == len(columns) and fields[0] == str(done)
                if not whole or not all(f"frame_{done:05d}{k}" in names for k in kinds):
                    break
                done += 1
            size += len(line)
        origins = [o for o in origins if o[0] < done]
        if done and (not origins or origins[0][0] != 0):
            raise InputError(f"--resume: {out}/{RUN} does not say where the frames' pipeline stood; give "
                             "--overwrite to replace the dump, or another --out")
        self.done, self.origins = done, origins
        self.columns, self.size = (columns, size) if done else (None, 0)

    def begin(self):
        """Remove what the run replaces (another dump's files with ``overwrite``; frames after the
        last complete one when resuming; temporary files), write ``run.json`` and open
        ``stats.csv``."""
        for name in self._names():
            m = FRAME_FILE.match(name)
            if TEMP_FILE.match(name) or (m and int(m.group(1)) >= self.done) or (self.done == 0 and name in (STATS, RUN)):
                try:
                    os.unlink(self._at(name), dir_fd=self.dir)
                except FileNotFoundError:
                    pass
                except OSError as e:
                    raise FrameWriteError(f"{name} (removing it)", e) from None
        self.begun = True
        self._write_run()
        flags = os.O_WRONLY | os.O_CREAT | os.O_APPEND | getattr(os, "O_CLOEXEC", 0)
        try:
            self.fd = os.open(self._at(STATS), flags, 0o666, dir_fd=self.dir)
            if os.fstat(self.fd).st_size != self.size:
                os.ftruncate(self.fd, self.size)
                os.fsync(self.fd)
        except OSError as e:
            raise FrameWriteError(STATS, e) from None

    def _write_run(self):
        data = json.dumps({"spec": self.spec.to_wire(), "settings": self.settings, "frames": self.frames,
                           "origins": self.origins}, indent=1)
        try:
            write_file(self._at(RUN), data.encode(), self.dir)
        except OSError as e:
            raise FrameWriteError(RUN, e) from None

    def _sync_dir(self):
        """Flush the folder's entries (the names renamed into it) to disk, where the system can."""
        if self.dir is None:
            return
        try:
            os.fsync(self.dir)
        except OSError as e:
            if e.errno != errno.EINVAL:  # (a file system that cannot flush a folder)
                raise

    # -- per frame --------------------------------------------------------------------------

    def write(self, i, item, extra=None):
        """Frame ``i`` (the next one: :attr:`done`) from ``item`` (:func:`encode_frame`'s dict),
        with ``extra`` columns of its stats row (the cluster's worker): whole, with its row, or
        not at all (raises FrameWriteError, having removed what it wrote)."""
        if i != self.done:
            raise InputError(f"frame {i} written after frame {self.done - 1}: frames are written in order")
        name = f"frame_{i:05d}"
        files = [(f"{name}.png", item["png"])]
        if "t" in item:
            files += [(f"{name}_t.npy", item["t"]), (f"{name}_id.npy", item["id"])]
        origin = [float(x) for x in item["origin"]]
        landed, size = [], self.size
        what = files[0][0]
        try:
            temps = []
            for fname, data in files:
                what = fname
                self.temps.add(self._at(temp_name(fname)))
                temps.append(put_temp(self._at(fname), data, self.dir))
            for (fname, _), tmp in zip(files, temps):
                what = fname
                os.replace(tmp, self._at(fname), src_dir_fd=self.dir, dst_dir_fd=self.dir)
                self.temps.discard(tmp)
                landed.append(fname)
            what = f"{self.out}/ (flushing its entries)"
            self._sync_dir()
            if not self.origins or self.origins[-1][1] != origin:
                what = RUN
                self.origins.append([i, origin])
                self._write_run()
            what = STATS
            self._append_row(item["stats"], extra or {})
            what = f"{self.out}/"
            if self.dir is not None and os.fstat(self.dir).st_nlink == 0:  # removed while the frame was written
                raise OSError(errno.ENOENT, os.strerror(errno.ENOENT))
        except BaseException as e:
            if self.origins and self.origins[-1][0] == i:
                self.origins.pop()
            if self.size != size:  # the row went in: out again
                self._cut(size)
            for fname in landed:
                remove(self._at(fname), self.dir)
            self._drop_temps()
            if isinstance(e, FrameWriteError):
                raise
            if isinstance(e, OSError):
                raise FrameWriteError(what, e) from None
            raise
        self.done += 1

    def _append_row(self, stats, extra):
        buf = io.StringIO()
        if self.columns is None:
            self.columns = stats_columns(stats) + list(extra)
            csv.writer(buf).writerow(self.columns)
        row = {**{k: fmt(v) for k, v in stats.items()}, **extra}
        csv.DictWriter(buf, fieldnames=self.columns, extrasaction="ignore").writerow(row)
        data = buf.getvalue().encode()
        try:
            _write_all(self.fd, data)
            os.fsync(self.fd)
        except BaseException:
            self._cut(self.size)
            raise
        self.size += len(data)

    def _cut(self, size):
        """stats.csv back to its first ``size`` bytes (its last whole row then)."""
        try:
            os.ftruncate(self.fd, size)
        except OSError:
            pass
        self.size = size
        if size == 0:
            self.columns = None

    # -- after the run ----------------------------------------------------------------------

    def _drop_temps(self):
        for tmp in list(self.temps):
            remove(tmp, self.dir)
        self.temps.clear()

    def close(self):
        """Remove temporary files and close ``stats.csv``; with no frame complete, remove
        ``stats.csv`` and ``run.json`` too (the folder holds no dump)."""
        self._drop_temps()
        if self.fd is not None:
            fd, self.fd = self.fd, None
            os.close(fd)
        if self.begun and self.done == 0:  # no frame: no trace of the run
            remove(self._at(STATS), self.dir)
            remove(self._at(RUN), self.dir)
        if self.dir is not None:
            fd, self.dir = self.dir, None
            os.close(fd)

    def complete(self):
        """Which frames are complete and where, as the stop line says it."""
        if self.done == 0:
            which = "no frame complete"
        elif self.done == 1:
            which = "frame 0 complete, with its stats row"
        else:
            which = f"frames 0-{self.done - 1} complete, each with its stats row"
        return f"{which}, in {self.out}/"

    def stop_line(self, error=None, signum=None):
        """(exit status, line) of a run stopped by ``error`` (a GridrtError), else by the signal
        ``signum``: 130 for SIGINT, 143 for SIGTERM, 2 for an error; the line says how many
        frames are complete, where, and why the run stopped."""
        if isinstance(error, FrameWriteError):
            code, why = 2, f"{error}; free space or fix the folder, then give --resume to continue"
        elif error is not None:
            code, why = 2, str(error)
        else:
            code, why = SIGNALS.get(signum, SIGNALS[signal.SIGINT])
            why += "; give --resume to continue"
        return code, f"gridrt: stopped after {self.done} of {self.frames} frames ({self.complete()}): {why}"

    def stopped(self, error=None, signum=None):
        """Print :meth:`stop_line` on stderr; returns the exit status."""
        code, line = self.stop_line(error, signum)
        print(line, file=sys.stderr, flush=True)
        return code

    def exit_now(self, signum, lead=""):
        """End the process at once for the signal ``signum``, the folder closed (a run with no
        frame leaves nothing) and the stop line written straight to stderr (after ``lead``): for
        a signal that comes while nothing is being written (a scene loading, a frame rendering,
        maybe a kernel compiling, which a raised KeyboardInterrupt would break with a traceback)."""
        self.close()
        code, line = self.stop_line(signum=signum)
        try:
            os.write(2, f"{lead}{line}\n".encode())
        except OSError:
            pass
        os._exit(code)


class StopSignals:
    """SIGINT and SIGTERM (``signals``) during a dump, as a context manager: a signal is recorded
    (:attr:`signum`; calling the object says whether one came).  Inside :meth:`deferred` (files
    being written), or always with ``defer``, that is all: the run stops at its next check,
    between frames.  Elsewhere (nothing is being written: a scene loading, a frame rendering) it
    calls ``now(signum)`` at once, so that a long render or compile does not hold the run (without
    ``now``, it raises KeyboardInterrupt).  The handlers in place before are restored on exit.
    Outside the main thread it does nothing."""

    def __init__(self, signals=(signal.SIGINT, signal.SIGTERM), defer=False, now=None):
        self.signals = signals
        self.defer = defer
        self.now = now
        self.signum = None
        self.old = {}

    def _heard(self, signum, frame):
        if self.signum is None:
            self.signum = signum
        if self.defer:
            return
        if self.now is not None:
            self.now(signum)
        raise KeyboardInterrupt

    def __call__(self):
        return self.signum is not None

    @contextlib.contextmanager
    def deferred(self):
        """A block that a signal does not interrupt (it is recorded only)."""
        old, self.defer = self.defer, True
        try:
            yield
        finally:
            self.defer = old

    def __enter__(self):
        if threading.current_thread() is threading.main_thread():
            for s in self.signals:
                self.old[s] = signal.signal(s, self._heard)
        return self

    def __exit__(self, *exc):
        for s, old in self.old.items():
            signal.signal(s, old)
        self.old.clear()


def replace_mode(a):
    """What to do with another dump in --out: None (refuse it), "overwrite" or "resume"."""
    return "overwrite" if a.overwrite else "resume" if a.resume else None


def resumed(start, frames):
    """How a summary says that a run went on after ``start`` complete frames ("" for a fresh run)."""
    return f" (frames {start}-{frames - 1}, after the {start} already there)" if start else ""


def nothing_to_do(writer, done):
    print(f"gridrt: nothing to do: {writer.out}/ already holds {done} complete frames (--frames {writer.frames})",
          file=sys.stderr, flush=True)
    return 0
