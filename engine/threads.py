"""Thread-count plumbing for numba.

numba fixes the size of its thread pool from NUMBA_NUM_THREADS when it is first imported, and
``numba.set_num_threads(n)`` only accepts ``n`` up to that size.  gridrt lets users pick any
thread count up to MAX_THREADS (also above the core count, for scaling experiments), so
``engine/__init__.py`` calls :func:`configure_env` before anything imports numba.
"""

import os

#: Largest thread count a user may ask for (the viewer slider, ``--threads``).
MAX_THREADS = max(16, os.cpu_count() or 1)


def configure_env():
    """Set NUMBA_NUM_THREADS (unless the user did) and prefer the OpenMP threading layer.

    Must run before the first ``import numba`` to take effect.  The omp layer is the one that
    tolerates parallel kernels launched from two Python threads at once (the viewer does that).
    """
    os.environ.setdefault("NUMBA_NUM_THREADS", str(MAX_THREADS))
    os.environ.setdefault("NUMBA_THREADING_LAYER", "omp")


def max_threads():
    """The largest thread count numba accepts in this process."""
    import numba

    return numba.config.NUMBA_NUM_THREADS


def check_threads(n):
    """Validate a thread count and return it as int; ``None`` means all cores."""
    from .errors import InputError

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


def use_threads(n):
    """Set numba's thread count for kernels launched from the calling Python thread."""
    import numba

    numba.set_num_threads(check_threads(n))
