"""Memory a call allocates, as tracemalloc sees it (Python's allocator and NumPy's arrays)."""

import tracemalloc
from contextlib import contextmanager

from gridrt.trace.twin import TWINS


class Traced:
    """What :func:`traced` measured: ``peak``, the most bytes held beyond those held at its start
    (None until the block ends)."""

    peak = None


@contextmanager
def traced():
    """``with traced() as m: ...``; then ``m.peak`` is the peak of the memory the block allocated
    beyond what was held when it began.  tracemalloc counts every thread's allocations: background
    compiles (gridrt.trace.twin) started by earlier work end first, so that only the block's own
    work is measured."""
    TWINS.wait()
    m = Traced()
    tracemalloc.start()
    try:
        tracemalloc.reset_peak()
        base = tracemalloc.get_traced_memory()[0]
        yield m
        m.peak = tracemalloc.get_traced_memory()[1] - base
    finally:
        tracemalloc.stop()
