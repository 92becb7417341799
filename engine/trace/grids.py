"""A grid as the traversal kernels see it: one value, :class:`GridArrays`, and sequences of them.

The render and traversal kernels take a tuple of grids (the static and the moving part of a
split scene, later other parts) and trace every ray through all of them, nearest hit first
(:func:`gridrt.trace.traverse.trace_grids`, :func:`gridrt.trace.cgt.trace_packet_grids`).  The
grids of one tuple must have the same numba type (the same array dtypes and layouts:
:func:`grid_arrays` makes them so), so that kernels can loop over the tuple and index it with a
run-time grid number.
"""

from collections import namedtuple

import numpy as np
from numba import types
from numba.extending import overload

#: One grid and its triangles, as the kernels take it (see gridrt.grid.layout for the arrays):
#: tris (F,3,3) float32 in the grid's frame; lo, hi, cell, inv_cell (3,) float64; dims (3,) int64;
#: cell_start (L, C+1) int32; tri_ids (R,) int32; macro int; mdims (3,) int64; macro_full (M,)
#: uint8; ids (F,) int32, the scene's id of each triangle, or empty when the grid's triangle
#: indices are the scene's.  A two-level grid (gridrt.grid.two_level) is the same value: lo..dims,
#: macro (1), mdims and macro_full describe its top level, cell_start and tri_ids its leaf cells,
#: and leaf_first (T+1,) int32, leaf_res (T,3) int32 where each top cell's leaf cells are.
#: A uniform grid has leaf_first = leaf_res = None, a numba type of its own, so that kernels given
#: only uniform grids compile none of the two-level code (:func:`carries_leaves`); beside a two-level
#: grid in one tuple it has both empty instead (leaf_first of size 0), which is how kernels tell the
#: two apart at run time.
GridArrays = namedtuple(
    "GridArrays", "tris lo hi cell inv_cell dims cell_start tri_ids macro mdims macro_full ids leaf_first leaf_res")
NO_IDS = np.zeros(0, np.int32)
NO_LEAVES = np.zeros(0, np.int32)
NO_RES = np.zeros((0, 3), np.int32)


def grid_arrays(grid, tris, ids=None, leaves=None):
    """The :class:`GridArrays` of a built ``grid`` over its own (F,3,3) float32 ``tris`` (checked by
    the caller), with scene ids ``ids`` ((F,) int32, checked by the caller; None: none).  ``leaves``:
    whether it carries leaf arrays (empty ones for a uniform grid); None: when the grid is two-level.
    The grids of one tuple share one setting (:func:`grid_tuple`)."""
    s = grid.spec
    c = np.ascontiguousarray
    two = grid.kind == "two_level"
    if leaves is None:
        leaves = two
    elif two and not leaves:
        raise ValueError("a two-level grid's GridArrays carry its leaf arrays")
    if two:
        leaf = (c(grid.leaf_first, np.int32), c(grid.leaf_res, np.int32))
    else:
        leaf = (NO_LEAVES, NO_RES) if leaves else (None, None)
    return GridArrays(
        c(tris, np.float32), c(s.lo, np.float64), c(s.hi, np.float64), c(s.cell, np.float64),
        c(s.inv_cell, np.float64), c(s.dims, np.int64), c(grid.cell_start, np.int32), c(grid.tri_ids, np.int32),
        int(s.macro), c(s.mdims, np.int64), c(grid.macro_full, np.uint8), NO_IDS if ids is None else c(ids, np.int32),
        *leaf)


def grid_tuple(*parts):
    """The tuple of :class:`GridArrays` of ``parts``, each (grid, tris, ids) as grid_arrays takes
    them: with leaf arrays in every one when any grid is two-level (one numba type for all)."""
    leaves = any(grid.kind == "two_level" for grid, _, _ in parts)
    return tuple(grid_arrays(grid, tris, ids, leaves) for grid, tris, ids in parts)


def carries_leaves(gty):
    """(for overloads) Whether the numba type ``gty`` of a :class:`GridArrays` carries leaf arrays:
    False for uniform grids alone, whose kernels then hold no two-level code."""
    return not isinstance(gty.types[gty.fields.index("leaf_first")], types.NoneType)


def is_two_level(g):
    """(kernels only) Whether the grid g is two-level: False at compile time for a uniform grid
    without leaf arrays.  The two-level code a kernel reaches under it goes through overloads
    that compile to nothing for such grids (:func:`carries_leaves`)."""
    raise NotImplementedError("is_two_level is only callable from numba kernels")


@overload(is_two_level, inline="always")
def _is_two_level(g):
    if not carries_leaves(g):
        return lambda g: False
    return lambda g: g.leaf_first.shape[0] > 0


def with_leaves_only(name, params, call, without):
    """A kernel-only function ``name(params)`` (``params`` its argument names, the grid ``g`` first)
    that returns ``call(params)`` (an njit function) for grids whose numba type carries leaf arrays,
    and the constant ``without`` for the others, a value that :func:`is_two_level` never lets a
    kernel use: kernels given only uniform grids compile none of ``call``.  Inlined at numba's IR
    level."""
    # (_compile's namespace has no __name__: the generated functions belong to no module of the
    # package, so compile progress counts them with their callers, as numba's own overload helpers)
    stub = _compile(f"def {name}({params}):\n    raise NotImplementedError('{name} is only callable from numba "
                    "kernels')\n", name)
    select = _compile(f"def with_leaves({params}):\n    return call({params})\n"
                      f"def without_leaves({params}):\n    return without\n"
                      f"def select({params}):\n    return with_leaves if carries_leaves(g) else without_leaves\n",
                      "select", call=call, without=without, carries_leaves=carries_leaves)
    overload(stub, inline="always")(select)
    return stub


def _compile(src, name, **env):
    ns = dict(env)
    exec(src, ns)  # noqa: S102  (source generated in this module: a tuple's length, fixed argument names)
    return ns[name]
