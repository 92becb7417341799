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
"""

import os
from contextlib import contextmanager


@contextmanager
def compile_notice(callback):
    """Within the block, call ``callback()`` once, when numba starts compiling the first kernel
    (from any thread); never when every kernel comes from the cache."""
    from numba.core import event

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


def _kernels(traversal="dda"):
    from .trace.cgt import cgt_render_kernel
    from .trace.render import render_kernel

    return [cgt_render_kernel if traversal == "cgt" else render_kernel]


def _has_cache_entry(kernel):
    """True when the kernel's on-disk cache index holds a compiled version for this machine (CPU
    and numba version) and the kernel's current source, as numba's own loader requires."""
    cache = getattr(kernel, "_cache", None)
    try:
        index = cache._cache_file._load_index()  # {} when absent, from another numba, or stale
        codegen = kernel.targetctx.codegen()
        return any(cache._index_key(key[0], codegen) == key for key in index)
    except Exception:  # numba's internals moved: fall back to the existence of the index file
        path = getattr(getattr(cache, "_cache_file", None), "_index_path", None)
        return path is not None and os.path.exists(path)


def cache_is_cold(traversal="dda"):
    """True when the render kernel of this traversal (run by every first frame) has no on-disk
    compile cache entry for this machine yet."""
    return not all(_has_cache_entry(k) for k in _kernels(traversal))
