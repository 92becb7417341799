"""Work whose parallel kernels compile in the background while a serial stand-in serves.

On a cold numba cache a kernel with a numba parallel loop (``prange``) compiles seconds slower
than the same work on one thread: numba's parfor lowering adds one more optimisation and
machine-code pass over the whole call tree (BENCHMARKS.md section 10).  The renders need no such
stand-in: their kernels are ``nogil`` and several threads share one compiled kernel
(gridrt.threads.on_threads).  Two pieces of work keep parallel loops and a stand-in:

* the default build strategy's parallel kernels (gridrt.grid.build._parallel_ready), while the
  serial strategy builds the same grids;
* the light maps' kernel (gridrt.trace.lightmap), while frames render without maps (the same
  images).

:meth:`Twins.warm` decides, per piece of work, whether it has warmed up in this process (its
kernels compiled by a run of it, a job) and otherwise starts that job on a daemon thread, once
(``TWINS``, the process's scheduler).  :func:`has_cache_entry` tells whether a kernel would load
from the on-disk cache instead (in milliseconds).

Benchmarks run under :func:`parallel_first`: the work then counts as warm, and the untimed
warm-up runs compile the parallel kernels on first use, in the caller's thread, so that timed
runs never time a stand-in.

The background compile is a daemon thread.  A dump that did its work waits for it at exit, after
saying so in one line, so that its next run finds the kernels cached (gridrt.app.__main__.leave,
:meth:`Twins.compiling`, :meth:`Twins.wait`); Ctrl-C skips that wait.  The viewer, a failed
dump, or a skipped wait does not wait: the command line leaves at once with os._exit after saying
so (the kernels then compile again on the next start), so that the interpreter's shutdown never
runs beside a compiling thread.  A program that uses gridrt as a library and ends while a
background compile runs waits for it at exit in the same way (an atexit handler, registered with
the first background compile, says so in one line on stderr; Ctrl-C ends the process at once):
LLVM aborts the process when the interpreter shuts down beside a compile.  The on-disk cache stays consistent:
numba writes each cache file under a temporary name and renames it into place (os.replace, in
numba.core.caching's IndexDataCacheFile._open_for_write), so no file is ever seen half written; an
abandoned compile leaves at most a stray ``*.tmp.*`` file, or an index entry whose data file was
not written yet, which numba's loader (IndexDataCacheFile.load) takes for a miss and compiles
again.
"""

import atexit
import os
import sys
import threading
from contextlib import contextmanager


def has_cache_entry(kernel):
    """True when the kernel's on-disk cache index holds a compiled version (for any argument types)
    for this machine (CPU and numba version) and the kernel's current source, as numba's own loader
    requires."""
    cache = getattr(kernel, "_cache", None)
    try:
        index = cache._cache_file._load_index()  # {} when absent, from another numba, or stale
        codegen = kernel.targetctx.codegen()
        return any(cache._index_key(key[0], codegen) == key for key in index)
    except Exception:  # numba's internals moved: fall back to the existence of the index file
        path = getattr(getattr(cache, "_cache_file", None), "_index_path", None)
        return path is not None and os.path.exists(path)


@contextmanager
def parallel_first():
    """Within the block, :meth:`Twins.warm` says yes at once: the parallel kernels compile when
    first needed, in the caller's thread, as a benchmark wants."""
    before = Twins.eager
    Twins.eager = True
    try:
        yield
    finally:
        Twins.eager = before


class Twins:
    """Background warm-ups of parallel work (the module docstring), keeping per piece of work what
    has warmed up, what is warming up and what failed."""

    eager = False  # parallel_first()

    def __init__(self):
        self._lock = threading.Lock()
        self._compiling = {}  # key of the work -> background thread
        self._failed = {}  # key of the work -> the exception of its background job that failed
        self._ready = set()  # keys of the work warmed up
        self.started = 0  # background compiles started in this process
        self._exit_wait = False  # the atexit handler is registered

    def warm(self, key, name, job, start):
        """Whether the work behind ``key`` has warmed up in this process (its kernels compiled by
        ``job()``, a run of that work): yes once the job ended without error.  Until then, with
        ``start``, the job runs on a daemon thread (once), listed as ``name`` by :meth:`compiling`
        while it runs.  A job that failed raises in the next caller's thread.  Under
        :func:`parallel_first`: yes."""
        if self.eager:
            return True
        with self._lock:
            failed = self._failed.get(key)
            if failed is not None:
                raise RuntimeError(f"warming up {name} failed") from failed
            if key in self._ready:
                return True
            if start and key not in self._compiling:
                self._start(key, name, self._warm, key, job)
            return False

    def _start(self, key, name, target, *args):
        """Run target(*args) on a daemon thread kept under ``key``, listed as ``name`` by
        :meth:`compiling` while it runs (the caller holds the lock)."""
        thread = threading.Thread(target=target, args=args, name="gridrt-compile-parallel", daemon=True)
        thread.kernel = name
        self._compiling[key] = thread
        self.started += 1
        if not self._exit_wait:
            self._exit_wait = True
            atexit.register(self._finish_at_exit)
        thread.start()

    def _finish_at_exit(self):
        """At the interpreter's exit: wait for the background compiles still running, after one
        line on stderr; on Ctrl-C end the process at once (os._exit), before the shutdown."""
        names = self.compiling()
        if not names:
            return
        try:
            print(f"gridrt: finishing the background compile of {', '.join(names)} before exit (Ctrl-C skips it)",
                  file=sys.stderr, flush=True)
        except (OSError, ValueError):
            pass
        try:
            self.wait()
        except KeyboardInterrupt:
            try:
                sys.stdout.flush()
                sys.stderr.flush()
            except (OSError, ValueError):
                pass
            os._exit(130)

    def _warm(self, key, job):
        try:
            job()
        except Exception as e:  # noqa: BLE001 (raised in the next caller's thread)
            self._failed[key] = e
        with self._lock:
            if key not in self._failed:
                self._ready.add(key)

    def compiling(self):
        """The names of the work whose background compile is still running (sorted)."""
        with self._lock:
            return sorted({job.kernel for job in self._compiling.values() if job.is_alive()})

    def wait(self):
        """Block until background compiles started so far have ended (tests, benchmarks)."""
        with self._lock:
            jobs = list(self._compiling.values())
        for job in jobs:
            job.join()

#: the process's scheduler
TWINS = Twins()
