"""Compile-cache awareness: tell a cold start (numba compiles for seconds) from a warm one."""

import os


def _kernels(traversal="dda"):
    from .grid import common
    from .grid.strategies.serial import count_serial, scatter_serial
    from .trace.cgt import cgt_render_kernel
    from .trace.render import render_kernel

    return [cgt_render_kernel if traversal == "cgt" else render_kernel, count_serial, scatter_serial,
            common.scene_bounds, common.scene_bounds_serial, common.macro_build_range, common.clear_macro_range]


def cache_is_cold(traversal="dda"):
    """True when a kernel the pipeline runs (with this traversal) has no on-disk compile cache
    yet (first run after install)."""
    for k in _kernels(traversal):
        cache = getattr(k, "_cache", None)
        path = getattr(getattr(cache, "_cache_file", None), "_index_path", None)
        if path is None or not os.path.exists(path):
            return True
    return False
