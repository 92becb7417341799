"""Compile-cache awareness: tell a start that compiles numba kernels (seconds) from one that loads
them from the on-disk cache.

* :func:`compile_notice` reports compiles as they happen.  numba broadcasts a ``numba:compile``
  event only when a dispatcher really compiles a signature: a kernel loaded from the on-disk
  cache (an entry for this machine and the kernel's current source) or compiled earlier in the
  process sends none.  So a notice given from it appears exactly when something compiles, whatever
  the settings decide about which kernels run (strategy, traversal, thread count, scene size,
  number of frames, shadows).  The frame dump uses it.
* :func:`cache_is_cold` predicts, before anything runs (the viewer shows its notice while a worker
  thread computes the first frame): True when the render kernel of the traversal has no cache
  entry for this machine.  Every first frame runs that kernel whatever the other settings, and it
  is most of a cold start's compile time (about 40 of 45 s for the dump on this machine); other
  kernels (a build strategy's first use, say) may still compile when it says False.
* :func:`compile_progress` follows a cold start kernel by kernel: which kernel numba is compiling
  and how many of the kernels expected so far are done (:class:`CompileProgress`).  The expected
  kernels are those a kernel starting to compile from Python reaches through the kernels it calls
  (:func:`kernels_reached`), less the ones whose cache entry numba will load instead.
"""

import re
import threading
import time
import types as _pytypes
from contextlib import contextmanager

from numba.core import event
from numba.core.dispatcher import Dispatcher

from .trace.cgt.frame import _render_tiles
from .trace.render import dda_tiles
from .trace.twin import has_cache_entry


@contextmanager
def compile_notice(callback):
    """Within the block, call ``callback()`` once, when numba starts compiling the first kernel
    (from any thread); never when every kernel comes from the cache."""

    class _First(event.Listener):
        fired = False

        def on_start(self, ev):
            if not self.fired:
                self.fired = True
                callback()

        def on_end(self, ev):
            pass

    with event.install_listener("numba:compile", _First()) as listener:
        yield listener


def _is_dispatcher(obj):
    return isinstance(obj, Dispatcher)


def _names(code):
    """The global and attribute names a function's code (and the code nested in it) loads."""
    names = set(code.co_names)
    for c in code.co_consts:
        if isinstance(c, _pytypes.CodeType):
            names |= _names(c)
    return names


def kernels_reached(kernel):
    """The numba dispatchers ``kernel`` calls, directly or through the kernels it calls, with
    itself: found from the names its Python code loads, looked up in its module's globals (and,
    for an imported module, that module's attributes of those names).  Overloads and intrinsics
    are not dispatchers: numba compiles them as part of the kernel that calls them."""
    seen = {}
    todo = [kernel]
    while todo:
        k = todo.pop()
        if id(k) in seen:
            continue
        seen[id(k)] = k
        fn = k.py_func
        names = _names(fn.__code__)
        g = fn.__globals__
        for n in names:
            obj = g.get(n)
            if _is_dispatcher(obj):
                todo.append(obj)
            elif isinstance(obj, _pytypes.ModuleType):
                todo.extend(a for a in (getattr(obj, m, None) for m in names) if _is_dispatcher(a))
    return list(seen.values())


def kernel_name(kernel):
    """``module.qualname`` of a dispatcher's Python function, e.g. ``gridrt.trace.cgt.trace_packet``."""
    fn = kernel.py_func
    return f"{fn.__module__}.{fn.__qualname__}"


class CompileProgress:
    """Where the compiles seen by :func:`compile_progress` stand.

    ``kernel``: the name of the innermost kernel numba is compiling (None between compiles), and
    ``again`` when it compiled before in this block (numba compiles a kernel once per argument
    types, literal constants included);
    ``done``: kernels compiled; ``expected``: kernels expected to compile so far (done included):
    grows when a kernel that was not expected starts (a later kernel called from Python, a cached
    kernel compiled for a new signature), and drops the kernels of a call tree that did not compile
    once that tree is done (branches numba pruned for the argument types, e.g. the shadow path of a
    render without shadows); ``seconds``: since the first compile started.  Only the
    package's own kernels count (``package``): numba's overload helpers, and the package's own
    overload implementations (functions defined inside another, or generated into no module),
    compile as part of them.
    """

    def __init__(self, package="gridrt"):
        self.package = package
        self.kernel = None
        self.again = False  # the kernel compiles once more (another argument type)
        self.started = None
        self._expected = {}  # id -> name
        self._done = set()
        self._maybe = set()  # ids expected by the outermost compile under way, not compiled yet
        self._stack = []  # dispatchers being compiled, outermost first (numba's compiles nest)

    @property
    def done(self):
        return len(self._done)

    @property
    def expected(self):
        return len(self._expected)

    @property
    def seconds(self):
        return 0.0 if self.started is None else time.perf_counter() - self.started

    def _ours(self, kernel):
        module = getattr(kernel.py_func, "__module__", None) or ""  # None for some numba-made functions
        # a function defined inside another (an overload's implementation) compiles as part of its caller
        return module.split(".")[0] == self.package and "<locals>" not in kernel.py_func.__qualname__

    def _start(self, kernel):
        """Returns True when this start is one a display should show (one of our kernels)."""
        if self.started is None:
            self.started = time.perf_counter()
        outermost = not self._stack
        self._stack.append(kernel)
        if not self._ours(kernel):
            return False
        if outermost:  # called from Python: its whole call tree compiles now, less the cached kernels
            self._maybe = set()
            for k in kernels_reached(kernel):
                if id(k) not in self._done and self._ours(k) and (k is kernel or not has_cache_entry(k)):
                    if id(k) not in self._expected:
                        self._maybe.add(id(k))
                    self._expected.setdefault(id(k), kernel_name(k))
        self._expected.setdefault(id(kernel), kernel_name(kernel))
        self.kernel = kernel_name(kernel)
        self.again = id(kernel) in self._done
        return True

    def _end(self, kernel):
        if not self._stack or self._stack[-1] is not kernel:
            # the end of a compile that was under way before this progress began following (a
            # background compile from an earlier run in this process): not one of its compiles
            return False
        self._stack.pop()
        ours = self._ours(kernel)
        if ours:
            self._done.add(id(kernel))
        if not self._stack:
            # the call tree is compiled: a kernel it names that did not compile sits on a branch numba
            # pruned for these argument types (the shadow path of a render without shadows): not needed
            for k in self._maybe - self._done:
                self._expected.pop(k, None)
            self._maybe = set()
        inner = [k for k in self._stack if self._ours(k)]
        self.kernel = kernel_name(inner[-1]) if inner else None
        self.again = bool(inner) and id(inner[-1]) in self._done
        return ours

    def __str__(self):  # (PROGRESS_LINE reads it back)
        what = f"compiling {self.kernel}" if self.kernel else "compiled"
        if self.kernel and self.again:
            what += " again (other argument types)"
        return f"{what} ({self.done}/{self.expected} kernels done, {self.seconds:.1f} s)"


#: a :class:`CompileProgress` as text while a kernel compiles (its ``str``), read back: the
#: kernel's name, kernels done, kernels expected (gridrt.coldstart's helper writes such lines)
PROGRESS_LINE = re.compile(r"compiling (\S+)(?: again \(other argument types\))? \((\d+)/(\d+) kernels done")


@contextmanager
def compile_progress(report, package="gridrt"):
    """Within the block, call ``report(progress, started)`` when one of the package's kernels
    starts compiling (started True) or finishes (False), with the :class:`CompileProgress`.  Kernels
    loaded from the on-disk cache send nothing.  Compiles in other threads are followed too (numba
    compiles one kernel at a time, under its compiler lock); ``report`` runs in the compiling
    thread."""
    progress = CompileProgress(package)
    lock = threading.Lock()

    class _Listener(event.Listener):
        def on_start(self, ev):
            with lock:
                if progress._start(ev.data["dispatcher"]):
                    report(progress, True)

        def on_end(self, ev):
            with lock:
                if progress._end(ev.data["dispatcher"]):
                    report(progress, False)

    with event.install_listener("numba:compile", _Listener()):
        yield progress


def _kernels(traversal="dda"):
    """The render kernel a first frame of this traversal runs, on any number of threads: the DDA's
    (gridrt.trace.render.dda_render) or the CGT's (gridrt.trace.cgt.cgt_render)."""
    return [_render_tiles] if traversal == "cgt" else [dda_tiles]


def cache_is_cold(traversal="dda"):
    """True when the render kernel of this traversal (every first frame runs it) has no on-disk
    compile cache entry for this machine yet."""
    return not any(has_cache_entry(k) for k in _kernels(traversal))
