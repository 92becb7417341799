"""Whether numba compiled while something ran: a frame whose time includes compiling kernels is
not a rendering time (its stats say so, and medians and plots leave it out).

numba broadcasts a ``numba:compile`` event when a dispatcher really compiles (not when it loads
from the on-disk cache); :class:`CompileWatch` counts them from any thread, and also knows a
compile that was under way when it began or ended (a parallel kernel compiling in the background,
gridrt.trace.twin, while frames render on its serial twin)."""

import threading

from numba.core import event


class _Counter(event.Listener):
    """Compiles started and under way in this process, from any thread."""

    def __init__(self):
        self.lock = threading.Lock()
        self.started = 0
        self.under_way = 0

    def on_start(self, ev):
        with self.lock:
            self.started += 1
            self.under_way += 1

    def on_end(self, ev):
        with self.lock:
            self.under_way = max(0, self.under_way - 1)


_COUNTER = _Counter()
event.register("numba:compile", _COUNTER)


class CompileWatch:
    """``with CompileWatch() as w: ...``; then ``w.compiled`` is True when numba compiled during the
    block, or had a compile under way when it began or ended."""

    def __init__(self):
        self.compiled = False

    def __enter__(self):
        with _COUNTER.lock:
            self._started = _COUNTER.started
            self._busy = _COUNTER.under_way > 0
        return self

    def check(self):
        """Whether numba compiled since the block began (or had a compile under way then or now)."""
        with _COUNTER.lock:
            self.compiled = self._busy or _COUNTER.under_way > 0 or _COUNTER.started != self._started
        return self.compiled

    def __exit__(self, *exc):
        self.check()
        return False
