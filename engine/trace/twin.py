"""A parallel kernel and its serial twin: the first frame need not wait for the parallel one.

The DDA render kernel and the material pass exist twice: ``parallel`` (``prange`` over chunks of
tiles) and ``serial`` (the same tiles in order on one thread, through the same tile kernel).  (The
CGT render needs no twin: its threads share one kernel, gridrt.trace.cgt.cgt_render.)  Both take the same arguments
and write the same buffers bit for bit, since no result depends on which thread renders a tile.
The serial one compiles seconds faster on a cold numba cache: the parallel one adds numba's parfor
lowering and one more optimisation and machine-code pass over its whole call tree (BENCHMARKS.md
section 10).

:class:`Twins` picks one per call (``TWINS``, the process's scheduler; a call names both kernels,
so that every caller of a kernel stays visible where it is called):

* one thread: the serial kernel (the parallel one would run the same code on one thread);
* the parallel kernel compiled for these argument types in this process, or in the on-disk cache
  for this machine (:func:`has_cache_entry`; it then loads in milliseconds): the parallel kernel;
* otherwise (a cold cache): the serial kernel, and from the second call with these argument types
  on, the parallel kernel compiles in a background thread while the serial one goes on serving;
  once compiled it takes over.  A one-frame run never compiles it.

:meth:`Twins.warm` does the same for work that is more than one kernel: the default build
strategy's parallel kernels (gridrt.grid.build), warmed up by a small build in the background
while the serial strategy builds the same grids.

Benchmarks run under :func:`parallel_first`: their untimed warm-up runs then compile the parallel
kernel on first use, in the caller's thread, so that timed runs never time the serial
kernel standing in for it.

The background compile is a daemon thread.  A dump that did its work waits for it at exit, after
saying so in one line, so that its next run finds the kernel cached (gridrt.app.__main__.leave,
:meth:`Twins.compiling`, :meth:`Twins.wait`); Ctrl-C skips that wait.  The viewer, a failed
dump, or a skipped wait does not wait: the command line leaves at once with os._exit after saying
so (the kernel then compiles again on the next start), so that the interpreter's shutdown never
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

import numpy as np


def has_cache_entry(kernel, sig=None):
    """True when the kernel's on-disk cache index holds a compiled version for this machine (CPU
    and numba version) and the kernel's current source, as numba's own loader requires; for the
    argument types ``sig`` (a tuple of numba types) when given, else for any."""
    cache = getattr(kernel, "_cache", None)
    try:
        index = cache._cache_file._load_index()  # {} when absent, from another numba, or stale
        codegen = kernel.targetctx.codegen()
        if sig is not None:
            return cache._index_key(tuple(sig), codegen) in index
        return any(cache._index_key(key[0], codegen) == key for key in index)
    except Exception:  # numba's internals moved: fall back to the existence of the index file
        path = getattr(getattr(cache, "_cache_file", None), "_index_path", None)
        return path is not None and os.path.exists(path)


def _fingerprint(a):
    """A cheap stand-in for the numba type of an argument (numba's typeof of a tuple of grids takes
    about 80 us): Python type, and dtype, dimensions and contiguity for an array, element by element
    for a tuple.  Two arguments with the same fingerprint have the same numba type."""
    if isinstance(a, np.ndarray):
        return (a.dtype.str, a.ndim, a.flags.c_contiguous, a.flags.f_contiguous, a.flags.writeable, a.flags.aligned)
    if isinstance(a, tuple):
        return (type(a), tuple(_fingerprint(x) for x in a))
    return type(a)


@contextmanager
def parallel_first():
    """Within the block, every :class:`Twins` calls the parallel kernel on more than one thread,
    compiling it when first needed, in the caller's thread: what a benchmark wants."""
    before = Twins.eager
    Twins.eager = True
    try:
        yield
    finally:
        Twins.eager = before


class Twins:
    """Calls ``parallel`` (a numba dispatcher) or its serial twin ``serial`` (a dispatcher, or a
    Python function around one; the same arguments and the same results), as the module docstring
    says, keeping per parallel kernel and argument types what has been served and compiled."""

    eager = False  # parallel_first()

    def __init__(self):
        self._lock = threading.Lock()
        self._seen = set()  # (parallel kernel, argument types) served serially once
        self._compiling = {}  # (parallel kernel, argument types) -> background thread
        self._failed = {}  # parallel kernel -> the exception of its background compile that failed
        self._ready = set()  # (parallel kernel, argument fingerprints) the parallel kernel is compiled for
        self.started = 0  # background compiles started in this process
        self._exit_wait = False  # the atexit handler is registered

    @staticmethod
    def signature(parallel, args):
        """The numba argument types of ``args``, as the dispatcher keys its compiled versions."""
        return tuple(parallel.typeof_pyval(a) for a in args)


    def pick(self, threads, parallel, serial, args):
        """The function to call for ``args`` on ``threads`` threads (see the module docstring)."""
        if threads <= 1:
            return serial
        if self.eager or not hasattr(parallel, "overloads"):  # (a stand-in for a kernel, in tests)
            return parallel
        fp = (id(parallel),) + tuple(_fingerprint(a) for a in args)
        if fp in self._ready:
            return parallel
        sig = self.signature(parallel, args)
        key = (id(parallel), sig)
        with self._lock:
            failed = self._failed.get(id(parallel))
            if failed is not None:  # a defect, not bad input: say so in the caller's thread
                raise RuntimeError(f"compiling {parallel.py_func.__qualname__} failed") from failed
            if sig in parallel.overloads:
                self._ready.add(fp)
                return parallel
            if key in self._compiling:
                return serial  # still compiling
            if has_cache_entry(parallel, sig):  # it loads from the on-disk cache in milliseconds
                return parallel
            if key in self._seen:
                self._start(key, parallel.py_func.__qualname__, self._compile, parallel, sig)
            else:
                self._seen.add(key)
            return serial

    def _compile(self, parallel, sig):
        try:
            parallel.compile(sig)
        except Exception as e:  # noqa: BLE001 (raised in the next caller's thread)
            self._failed[id(parallel)] = e
        with self._lock:
            self._compiling.pop((id(parallel), sig), None)

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
        """The names of the parallel kernels whose background compile is still running (sorted)."""
        with self._lock:
            return sorted({job.kernel for job in self._compiling.values() if job.is_alive()})

    def wait(self):
        """Block until background compiles started so far have ended (tests, benchmarks)."""
        with self._lock:
            jobs = list(self._compiling.values())
        for job in jobs:
            job.join()

    def __call__(self, threads, parallel, serial, *args):
        return self.pick(threads, parallel, serial, args)(*args)


#: the process's scheduler
TWINS = Twins()
