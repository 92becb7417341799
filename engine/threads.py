"""Thread-count plumbing for numba.

numba fixes the size of its thread pool from NUMBA_NUM_THREADS when it is first imported, and
``numba.set_num_threads(n)`` only accepts ``n`` up to that size.  gridrt lets users pick any
thread count up to MAX_THREADS (also above the core count, for scaling experiments), so
``engine/__init__.py`` calls :func:`configure_env` before anything imports numba.
"""

import contextlib
import ctypes.util
import hashlib
import os
import shutil
import sys
import threading
import time
import warnings
from pathlib import Path

from .errors import InputError

#: Largest thread count a user may ask for (the viewer slider, ``--threads``).
MAX_THREADS = max(16, os.cpu_count() or 1)


def configure_env():
    """Set NUMBA_NUM_THREADS (unless the user did), prefer the OpenMP threading layer, point
    numba's compile cache at a folder keyed by the engine's source and let numba's loops use the
    CPU's widest vectors (see :func:`wide_vector_features`).

    Must run before the first ``import numba`` to take effect.  The omp layer is the one that
    tolerates parallel kernels launched from two Python threads at once (the viewer does that).
    numba keys a cached kernel on its own file only, so after an edit to a function it calls
    from another file it would load stale machine code; a cache folder per source hash avoids that.
    Where numba was imported first, its thread count stands (NUMBA_NUM_THREADS is set to it): numba
    reads its variables again before each compile, and a thread count other than that of its
    launched threads would stop the program's next compile with a RuntimeError.
    """
    config = sys.modules.get("numba.core.config")
    os.environ.setdefault("NUMBA_NUM_THREADS", str(MAX_THREADS if config is None else config.NUMBA_NUM_THREADS))
    if "NUMBA_THREADING_LAYER" not in os.environ and _have_gomp():
        os.environ["NUMBA_THREADING_LAYER"] = "omp"
    if "OMP_WAIT_POLICY" not in os.environ:
        # idle OpenMP threads of the (MAX_THREADS-sized) pool otherwise spin for ~300k iterations
        # after every parallel region and steal the cores from the next kernel (measured: ~10 ms
        # stalls between a grid build and the next kernel on 2 cores)
        os.environ.setdefault("GOMP_SPINCOUNT", "10000")
    if "NUMBA_CACHE_DIR" not in os.environ:
        os.environ["NUMBA_CACHE_DIR"] = _cache_dir()
    if "NUMBA_CPU_FEATURES" not in os.environ:
        features = wide_vector_features(os.environ.get("GRIDRT_VECTOR_WIDTH", "auto"))
        if features is not None:
            os.environ["NUMBA_CPU_FEATURES"] = features


#: values of GRIDRT_VECTOR_WIDTH: the widest vectors numba's kernels may use ("auto": the CPU's widest)
VECTOR_WIDTHS = ("auto", "512", "256")


def wide_vector_features(width):
    """The NUMBA_CPU_FEATURES that let LLVM vectorize loops with 512-bit registers (zmm: 16 float32
    or 8 float64 lanes), or None to leave numba's default.

    LLVM's tuning for the Intel cores with AVX-512 (Skylake-X to Sapphire Rapids) prefers 256-bit
    vectors ("prefer-256-bit"), so by default numba's loops use ymm registers even where zmm ones
    exist; its tuning for AMD's Zen 4 does not, and uses zmm ones.  On a CPU with AVX-512F this
    returns the host's features with that preference turned off for width "auto" or "512", and
    turned on for "256" (ymm registers on Intel and AMD alike); on a CPU without AVX-512 (AVX2 only)
    there is nothing wider and it returns None.  Any other width is reported (a warning) and
    treated as "auto".  The setting is process-wide and must be made before numba is imported:
    gridrt's ``configure_env`` applies GRIDRT_VECTOR_WIDTH, unless NUMBA_CPU_FEATURES is set."""
    if width not in VECTOR_WIDTHS:
        warnings.warn(f"GRIDRT_VECTOR_WIDTH={width!r} is not one of {', '.join(VECTOR_WIDTHS)}; using auto",
                      stacklevel=3)
        width = "auto"
    try:
        import llvmlite.binding as ll  # deferred: llvmlite's LLVM library, loaded only when this is asked

        ll.initialize_native_target()
        features = ll.get_host_cpu_features().flatten()
    except Exception:  # (no llvmlite, or a host it cannot describe: numba's default)
        return None
    if "+avx512f" not in features.split(","):
        return None
    return features + (",+prefer-256-bit" if width == "256" else ",-prefer-256-bit")


def _have_gomp():
    """True when GNU OpenMP (libgomp, Debian package libgomp1) can be loaded; without it numba
    falls back to its workqueue layer, which must not be entered from two threads at once."""
    return ctypes.util.find_library("gomp") is not None


#: numba cache folders of other source versions kept beside the current one (see _cache_dir)
CACHE_KEEP = 3


def _cache_dir():
    root = Path(__file__).resolve().parent
    h = hashlib.sha1()
    for p in sorted(root.rglob("*.py")):
        h.update(str(p.relative_to(root)).encode())
        h.update(p.read_bytes())
    base = root / "__pycache__"
    here = base / f"numba-{h.hexdigest()[:16]}"
    try:
        # caches of older sources go, but not one another process may still be compiling into (an
        # edit while a run is under way): the newest few stay, and none touched in the last hour goes
        def touched(p):  # numba writes into one sub-folder per source folder
            return max([p.stat().st_mtime] + [q.stat().st_mtime for q in p.iterdir()])

        old = sorted(((touched(p), p) for p in base.glob("numba-*") if p != here), reverse=True)
        for when, p in old[CACHE_KEEP:]:
            if time.time() - when > 3600:
                shutil.rmtree(p, ignore_errors=True)
    except OSError:
        pass
    return str(here)


def max_threads():
    """The largest thread count numba accepts in this process."""
    import numba  # deferred: numba reads the settings configure_env makes when it is first imported

    return numba.config.NUMBA_NUM_THREADS


def check_threads(n):
    """Validate a thread count and return it as int; ``None`` means all cores."""
    if n is None:
        return min(os.cpu_count() or 1, max_threads())
    if isinstance(n, bool) or not isinstance(n, (int,)) and not hasattr(n, "__index__"):
        raise InputError(f"thread count must be an integer, got {n!r}")
    n = int(n)
    hi = max_threads()
    if n < 1 or n > hi:
        raise InputError(
            f"thread count must be between 1 and {hi}, got {n} "
            f"(set NUMBA_NUM_THREADS before starting gridrt to allow more)"
        )
    return n


def usable_cores():
    """The cores this process may run on (its CPU affinity where the OS tells, else all)."""
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


_WARNED_CORES = []


def warn_more_threads_than_cores(n):
    """Warn, once per process, when ``n`` threads are more than :func:`usable_cores`: they run
    correctly, sharing the cores, but cannot run faster than as many threads as cores."""
    cores = usable_cores()
    if n is not None and n > cores and not _WARNED_CORES:
        _WARNED_CORES.append(n)
        warnings.warn(f"{n} threads on {cores} core{'s' if cores != 1 else ''}: the threads share the cores, so the "
                      f"build and render run no faster than with {cores} (correct all the same)", stacklevel=2)


def use_threads(n):
    """Set numba's thread count for kernels launched from the calling Python thread."""
    import numba  # deferred: numba reads the settings configure_env makes when it is first imported

    numba.set_num_threads(check_threads(n))



#: the process's pool of worker threads for on_threads (made at its first use; a forked child,
#: which has none of its threads, makes its own)
_POOL = []
_POOL_LOCK = threading.Lock()
if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_POOL.clear)


def on_threads(n, work):
    """``[work(0), ..., work(n - 1)]``: work(0) in the calling thread, the others at the same time
    on the process's pool of worker threads (``max_threads() - 1`` of them, started as needed).

    For kernels compiled with ``nogil=True`` that share one piece of work among their calls through
    an atomic counter: each call takes the next part until none is left, so a call that starts late
    (the pool busy with another caller's calls) finds less or nothing to do, and the calls finish
    together however the threads were scheduled.  numba's own parallel loops need a second, larger
    compile of the code they call (the parfor lowering and one more optimisation pass over the
    whole call tree); these threads run the one compiled kernel.  An exception of any call is
    raised here once every call has ended."""
    futures = []
    if n > 1:
        with _POOL_LOCK:
            if not _POOL:
                from concurrent.futures import ThreadPoolExecutor  # deferred: only multi-threaded work needs it

                _POOL.append(ThreadPoolExecutor(max(1, max_threads() - 1), thread_name_prefix="gridrt"))
        futures = [_POOL[0].submit(work, k) for k in range(1, n)]
    try:
        first = work(0)
    finally:
        for f in futures:  # every call ends before this returns or raises
            f.exception()
    return [first] + [f.result() for f in futures]


#: threading layers that tolerate parallel kernels launched from several Python threads at once
#: (numba's workqueue layer aborts the process: "Concurrent access has been detected")
_CONCURRENT_LAYERS = ("omp", "tbb")
_CONCURRENT_CONFIGS = ("omp", "tbb", "threadsafe", "safe")
_LAUNCH_LOCK = threading.RLock()
_NO_LOCK = contextlib.nullcontext()


def concurrent_launches_ok():
    """True when the threading layer in use (or, before the first parallel kernel has run, the
    one configured) lets several Python threads run parallel kernels at the same time."""
    import numba  # deferred: numba reads the settings configure_env makes when it is first imported

    try:
        return numba.threading_layer() in _CONCURRENT_LAYERS
    except ValueError:  # no parallel kernel has run yet: numba has not picked a layer
        return str(numba.config.THREADING_LAYER) in _CONCURRENT_CONFIGS


def launch_guard():
    """Context manager to hold while launching parallel kernels that other Python threads may
    launch too: nothing with the omp or tbb layers; one process-wide lock otherwise (workqueue,
    the layer numba falls back to without libgomp), which serialises those launches."""
    return _NO_LOCK if concurrent_launches_ok() else _LAUNCH_LOCK
