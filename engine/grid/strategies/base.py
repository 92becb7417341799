"""The contract every build strategy fulfils.

A strategy fills the cell lists of a grid whose geometry (GridSpec) is already fixed and whose
count buffer is already zero (the shared clear stage ran).  On return:

* ``bufs.count[l, c]``  number of references of cell c in layer l,
* ``bufs.start[l, c]``  CSR start of cell c in layer l, ``bufs.start[l, C]`` the layer's end,
* the references themselves in the array returned by ``bufs.refs(n)``, layers back to back.

The ``insert`` method returns the total number of references and records its sub-stages in
``times`` (ms).  Contents per cell, as a set, must not depend on the strategy or thread count.
"""

import time
from contextlib import contextmanager


@contextmanager
def timed(times, key):
    """Add the wall time of the block, in ms, to ``times[key]``."""
    t0 = time.perf_counter()
    try:
        yield
    finally:
        times[key] = times.get(key, 0.0) + (time.perf_counter() - t0) * 1e3


class Strategy:
    #: registry name
    name = ""
    #: True: clear and macro stages run in parallel (contiguous macro-cell sections per thread)
    parallel_stages = True
    #: True: one layer of cell lists per thread, kept apart for the ray caster
    layered = False
    #: keys of the counts ``insert`` adds to its ``times`` (the rest are stage times in ms); the
    #: build keeps them apart, as BuildStats.counters
    counters = ()
    #: the parallel kernels (numba dispatchers) ``insert`` calls on more than one thread: for a
    #: strategy GridParams(strategy="auto") may pick, whether they are compiled or cached decides
    #: if it builds or its serial stand-in does (gridrt.grid.build._parallel_ready)
    parallel_kernels = ()

    def layers(self, threads):
        return threads if self.layered else 1

    def insert(self, tris, spec, bufs, threads, exact, times):  # pragma: no cover - interface
        raise NotImplementedError
