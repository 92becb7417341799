"""A cold start on two cores: a helper process compiles a first frame's ray casting while this
process compiles its grid build.

numba compiles one kernel at a time in a process (under its compiler lock), so a first frame on
an empty numba cache compiles its kernels one after the other on one core: the scene's, the grid
build's, then the ray casting's (most of the time: BENCHMARKS.md section 10).  The ray casting
kernels depend on the grid's array types, not on its contents, so another process can compile
them without building a grid: :func:`main` (``python -m gridrt.coldstart``) steps a throwaway
pipeline of the same FrameSpec at :data:`HELPER_SIZE` whose grids come from
:class:`gridrt.grid.one_cell.OneCellBuilder` (one cell holding every triangle, made with NumPy:
the types of a built grid, no build kernel), so that its frame runs the ray casting, shading and
writing kernels the real first frame runs, with the same argument types, and then exits.  numba
writes what it compiled to the on-disk cache (each file under a temporary name, renamed into
place), and the first frame here loads it there instead of compiling it.

:meth:`CompileHelper.start` starts the helper when it pays: the render kernel of the traversal
has no cache entry for this machine (:func:`gridrt.warmup.cache_is_cold`) and the process may
use two cores or more.  The caller hands :meth:`CompileHelper.wait` to its pipeline as
``before_render``: the first frame builds its grid (compiling the build here, beside the
helper), then waits for the helper, then renders.  A frame whose grids are of another kind than
the helper's (``--grid auto`` choosing a two-level grid) stops the helper and compiles here.

The helper reads its request (the spec in the wire format, and the time) from its standard
input, and ends at once when that closes (its parent gone, or :meth:`CompileHelper.stop`).  It
writes nothing but one line per kernel it starts compiling (``compiling NAME (3/20 kernels
done, 1.2 s)``) and a last line, on its standard output, which :meth:`CompileHelper.wait` hands
to its ``report``.  It reads only the scene the spec names, as this process does; its errors
are not shown (the first frame here meets the same problem and says so itself).  It maps at
most :data:`MEMORY_SHARE` of the memory left when it starts (``RLIMIT_AS``, which gridrt's own
memory checks count): a scene too big to be loaded twice fails in the helper, and the first
frame compiles here.
"""

import json
import os
import select
import subprocess
import sys
import threading

from .frame import FrameSpec
from .grid.one_cell import OneCellBuilder
from .memory import cap_address_space
from .pipeline import FramePipeline
from .warmup import cache_is_cold, compile_progress

#: the helper's frame size (width, height): a frame this small runs every kernel of a large one
HELPER_SIZE = (8, 6)
#: the share of the memory left that the helper may map (the rest is its parent's, which loads
#: the same scene and builds the grid beside it)
MEMORY_SHARE = 1 / 3
#: seconds :meth:`CompileHelper.wait` waits for the helper's next line (a kernel compiles in
#: seconds) before it takes the helper for stuck, stops it and lets the frame compile here
LINE_TIMEOUT_S = 300.0


def request(spec, t):
    """The helper's request for the frame of ``spec`` (FrameSpec) at time ``t``: one line of JSON,
    as bytes."""
    return (json.dumps({"spec": spec.to_wire(), "t": float(t)}) + "\n").encode()


def _cores():
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def _kind(spec):
    """The grid kind the helper compiles for: the spec's ("auto": uniform, the default)."""
    return "two_level" if spec.grid.grid == "two_level" else "uniform"


class CompileHelper:
    """A running helper process (see the module docstring); ``kind``: the grid kind it compiles
    for."""

    def __init__(self, proc, kind):
        self.proc = proc
        self.kind = kind

    @classmethod
    def start(cls, spec, t, cores=None):
        """The helper compiling the ray casting of the frame of ``spec`` (FrameSpec) at time ``t``,
        or None when it would not pay (a warm cache, one core: ``cores``, default the cores this
        process may use) or cannot start."""
        if (cores or _cores()) < 2 or not cache_is_cold(spec.render.traversal):
            return None
        try:
            proc = subprocess.Popen([sys.executable, "-m", "gridrt.coldstart"], stdin=subprocess.PIPE,
                                    stdout=subprocess.PIPE, stderr=subprocess.DEVNULL)
        except OSError:
            return None
        try:
            proc.stdin.write(request(spec, t))
            proc.stdin.flush()
        except OSError:  # (it ended already)
            cls(proc, None).stop()
            return None
        return cls(proc, _kind(spec))

    def wait(self, kinds=None, report=None, line_timeout=LINE_TIMEOUT_S):
        """Block until the helper has ended, calling ``report(line)`` with each line it writes;
        True when it ended having done its work.  ``kinds``: the grid kinds of the frame about to
        render (a set; None: any): when the helper compiles for others, it is stopped instead
        (False); so is a helper silent for ``line_timeout`` seconds."""
        if self.proc.stdout.closed:  # (stopped already)
            return False
        if kinds is not None and set(kinds) != {self.kind}:
            self.stop()
            return False
        try:
            for line in self._lines(line_timeout):
                if report is not None:
                    report(line)
            ok = self.proc.wait() == 0
        except TimeoutError:
            ok = False
        finally:
            self.stop()
        return ok

    def _lines(self, timeout):
        """The helper's lines as it writes them, until it closes its output; TimeoutError when
        none comes within ``timeout`` seconds."""
        fd = self.proc.stdout.fileno()
        rest = b""
        while True:
            if not select.select([fd], [], [], timeout)[0]:
                raise TimeoutError
            chunk = os.read(fd, 65536)
            if not chunk:
                return
            *lines, rest = (rest + chunk).split(b"\n")
            for line in lines:
                yield line.decode("utf-8", "replace")

    def stop(self):
        """End the helper now (when still running) and release its pipes."""
        for f in (self.proc.stdin, self.proc.stdout):
            try:
                if f is not None:
                    f.close()
            except OSError:
                pass
        if self.proc.poll() is None:
            self.proc.kill()
        self.proc.wait()


def _exit_when_closed():
    """Leave the process at once when its standard input reaches its end (the parent closed it or
    is gone): a helper never outlives the reason it was started."""
    try:
        while sys.stdin.buffer.read(65536):
            pass
    finally:
        os._exit(3)


def _say(text):
    sys.stdout.write(text + "\n")
    sys.stdout.flush()


class OneCellPipeline(FramePipeline):
    """A FramePipeline whose grids are one-cell grids (the helper's frame)."""

    Builder = OneCellBuilder


def _warm(spec, t):
    """Step a throwaway pipeline of ``spec`` at HELPER_SIZE at time ``t`` over one-cell grids."""
    OneCellPipeline.from_spec(spec.resized(*HELPER_SIZE)).step(t)


def main():
    """The helper process (``python -m gridrt.coldstart``): its request is one line of JSON on
    standard input.  Exit status 0: done; 1: a request it could not read, or a frame that failed;
    3: its input closed first."""
    code = 1
    try:
        request = json.loads(sys.stdin.readline())
        spec, t = FrameSpec.from_wire(request["spec"]), float(request["t"])
    except Exception:  # noqa: BLE001 (nothing is said: see the module docstring)
        os._exit(code)
    threading.Thread(target=_exit_when_closed, name="gridrt-helper-stdin", daemon=True).start()
    try:
        cap_address_space(MEMORY_SHARE)  # (a scene too big for two copies fails here, not in the parent)
        with compile_progress(lambda p, started: _say(str(p)) if started else None) as progress:
            _warm(spec, t)
        _say(f"compiled {progress.done}/{progress.expected} kernels in {progress.seconds:.1f} s")
        code = 0
    except BaseException:  # noqa: BLE001 (the parent meets the same problem and reports it)
        pass
    sys.stdout.flush()
    os._exit(code)


if __name__ == "__main__":
    main()
