"""Cache prefetch hints and the cycle counter for the traversal kernels (numba intrinsics around
llvm.prefetch and llvm.readcyclecounter, and the loops over a cell that the walks share)."""

from llvmlite import ir
from numba import njit, types
from numba.core import cgutils
from numba.extending import intrinsic


def _prefetch_codegen(write, nidx=1):
    """Codegen of a prefetch (llvm.prefetch, for reading or writing, kept in every cache level;
    a prefetch never faults) of arr[i, 0, ...] (nidx = 1) or arr[l, i, 0, ...] (nidx = 2): the
    element at the indices given, then zeros up to the array's dimensions."""

    def codegen(context, builder, signature, args):
        aryty = signature.args[0]
        ary = context.make_array(aryty)(context, builder, args[0])
        zero = context.get_constant(types.intp, 0)
        idx = [context.cast(builder, args[k], signature.args[k], types.intp) for k in range(1, nidx + 1)]
        ptr = cgutils.get_item_pointer(context, builder, aryty, ary, idx + [zero] * (aryty.ndim - nidx),
                                       wraparound=False)
        i8p = ir.PointerType(ir.IntType(8))
        i32 = ir.IntType(32)
        fn = cgutils.get_or_insert_function(builder.module, ir.FunctionType(ir.VoidType(), [i8p, i32, i32, i32]),
                                            "llvm.prefetch.p0")
        builder.call(fn, [builder.bitcast(ptr, i8p), ir.Constant(i32, 1 if write else 0), ir.Constant(i32, 3),
                          ir.Constant(i32, 1)])
        return context.get_dummy_value()

    return codegen


@intrinsic
def _prefetch_tri(typingctx, tris, f):
    """Prefetch triangle f of tris (F, 3, 3) into the caches, for reading."""
    return types.void(tris, f), _prefetch_codegen(False)


@intrinsic
def _prefetch_write(typingctx, arr, i):
    """Prefetch element i of the 1D array arr, for writing."""
    return types.void(arr, i), _prefetch_codegen(True)


@intrinsic
def _prefetch_row(typingctx, arr, l, i):
    """Prefetch element [l, i] of the 2D array arr (a cell's range in one layer of cell_start),
    for reading."""
    return types.void(arr, l, i), _prefetch_codegen(False, 2)


@njit(cache=True, inline="always")
def prefetch_range(cell_start, c):
    """Start the load of cell c's range, in every layer of cell_start (L, C + 1)."""
    for l in range(cell_start.shape[0]):
        _prefetch_row(cell_start, l, c)


@njit(cache=True, inline="always")
def prefetch_ids(tri_ids, r):
    """Start the load of tri_ids[r] (the start of a cell's references)."""
    _prefetch_tri(tri_ids, r)


@njit(cache=True, inline="always")
def prefetch_triangles(tris, tri_ids, cell_start, c):
    """Start the loads of the triangles cell c lists (every layer of cell_start), so that their
    cache misses (a cell's triangles lie anywhere in tris) overlap instead of queueing one test at
    a time."""
    for l in range(cell_start.shape[0]):
        for r in range(cell_start[l, c], cell_start[l, c + 1]):
            _prefetch_tri(tris, tri_ids[r])


@intrinsic
def _cycles(typingctx):
    """The CPU's cycle counter (llvm.readcyclecounter: rdtsc on x86), for profiling builds only."""
    sig = types.int64()

    def codegen(context, builder, signature, args):
        i64 = ir.IntType(64)
        fn = cgutils.get_or_insert_function(builder.module, ir.FunctionType(i64, []), "llvm.readcyclecounter")
        return builder.call(fn, [])

    return sig, codegen
