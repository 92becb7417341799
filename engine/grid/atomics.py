"""CPU atomics and spin locks for numba kernels.

numba has no public atomics on the CPU target, so these ``@intrinsic`` functions emit the LLVM
atomic instructions directly (``atomicrmw``, ``cmpxchg``, atomic load/store).  They work inside
``prange`` loops and in ``cache=True`` kernels.  Arrays must be 1-D int32 or int64; the value
arguments take the array's dtype (pass ``np.int32(1)`` for an int32 array).  Indices are not
bounds-checked, like every kernel of the engine: callers validate at the Python boundary.

The spin lock is a test-and-test-and-set lock on one int32 slot (0 free, 1 held): spin on a
relaxed load with the x86 ``pause`` hint, try ``cmpxchg`` (acquire) when the slot looks free,
and after :data:`SPINS_BEFORE_YIELD` failed looks give the core away with ``sched_yield``, so a
waiting thread does not burn the time slice of a preempted lock holder when there are more
threads than cores.  Unlock is a release store of 0.  These are the mutexes of the
sort-last strategies of Ize et al. 2006 ("Sort-last: global grid").
"""

import os
import platform

import numpy as np
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic

from ..compiles import inner

#: failed looks at a held lock before the waiting thread calls sched_yield (then after every 16)
SPINS_BEFORE_YIELD = 64

_X86 = platform.machine().lower() in ("x86_64", "amd64", "i386", "i686", "x86")
_INT_TYPES = (types.int32, types.int64)


def _ok(arr):
    return isinstance(arr, types.Array) and arr.ndim == 1 and arr.dtype in _INT_TYPES


def _ptr(context, builder, arrty, arr, idx):
    ary = context.make_array(arrty)(context, builder, arr)
    return cgutils.get_item_pointer(context, builder, arrty, ary, [idx], wraparound=False)


@intrinsic
def atomic_add(typingctx, arr, idx, val):
    """``old = arr[idx]; arr[idx] += val`` as one sequentially consistent step; returns old."""
    if not _ok(arr):
        return None
    sig = arr.dtype(arr, types.intp, arr.dtype)

    def codegen(context, builder, signature, args):
        p = _ptr(context, builder, signature.args[0], args[0], args[1])
        return builder.atomic_rmw("add", p, args[2], "seq_cst")

    return sig, codegen


@intrinsic
def atomic_cas(typingctx, arr, idx, expected, desired):
    """Compare-and-swap: if ``arr[idx] == expected`` store ``desired``; returns the old value
    (success when it equals ``expected``).  Acquire ordering on success."""
    if not _ok(arr):
        return None
    sig = arr.dtype(arr, types.intp, arr.dtype, arr.dtype)

    def codegen(context, builder, signature, args):
        p = _ptr(context, builder, signature.args[0], args[0], args[1])
        res = builder.cmpxchg(p, args[2], args[3], "acquire", "monotonic")
        return builder.extract_value(res, 0)

    return sig, codegen


@intrinsic
def atomic_load_relaxed(typingctx, arr, idx):
    """``arr[idx]`` read atomically with no ordering (for spinning on a lock)."""
    if not _ok(arr):
        return None
    sig = arr.dtype(arr, types.intp)

    def codegen(context, builder, signature, args):
        p = _ptr(context, builder, signature.args[0], args[0], args[1])
        return builder.load_atomic(p, "monotonic", align=signature.args[0].dtype.bitwidth // 8)

    return sig, codegen


@intrinsic
def atomic_store_release(typingctx, arr, idx, val):
    """``arr[idx] = val`` with release ordering (unlock: earlier writes become visible first)."""
    if not _ok(arr):
        return None
    sig = types.void(arr, types.intp, arr.dtype)

    def codegen(context, builder, signature, args):
        p = _ptr(context, builder, signature.args[0], args[0], args[1])
        builder.store_atomic(args[2], p, "release", align=signature.args[0].dtype.bitwidth // 8)
        return context.get_dummy_value()

    return sig, codegen


@intrinsic
def cpu_pause(typingctx):
    """The x86 ``pause`` spin-wait hint (nothing on other architectures)."""
    sig = types.void()

    def codegen(context, builder, signature, args):
        if _X86:
            fnty = cgutils.ir.FunctionType(cgutils.ir.VoidType(), [])
            fn = cgutils.get_or_insert_function(builder.module, fnty, "llvm.x86.sse2.pause")
            builder.call(fn, [])
        return context.get_dummy_value()

    return sig, codegen


#: Give up the core: POSIX sched_yield (C library), or SwitchToThread on Windows; resolved by
#: name when the kernel is linked.
sched_yield = types.ExternalFunction("SwitchToThread" if os.name == "nt" else "sched_yield", types.int32())


@inner(cache=True)
def spin_lock(locks, i):
    """Take lock ``i`` of ``locks`` (int32 array, 0 = free).  Returns the failed looks (0 when
    the lock was free at once): the contention figure the lock strategies report."""
    waits = 0
    while True:
        if atomic_load_relaxed(locks, i) == 0:
            if atomic_cas(locks, i, np.int32(0), np.int32(1)) == 0:
                return waits
        waits += 1
        if waits >= SPINS_BEFORE_YIELD and (waits & 15) == 0:
            sched_yield()
        else:
            cpu_pause()


@inner(cache=True)
def spin_unlock(locks, i):
    """Release lock ``i`` (release store of 0)."""
    atomic_store_release(locks, i, np.int32(0))
