"""Bytes a grid build moves, stage by stage, and the machine's streaming bandwidth to hold them
against (Ize et al. 2006 blame the limits of their parallel builds on memory bandwidth; this
module lets `gridrt bench build` check that claim on the machine at hand).

``stage_bytes(stats)`` is a model of what our kernels read and write, counted from the build's
own statistics (triangles F, references R, cells C, cells cleared and inspected, bucket entries B).
It counts each array element once per pass that touches it: a read-modify-write counts twice, a
cache line that serves several elements is not counted again, gathers count the bytes used, not the
line fetched.  It is a floor on traffic, not a measurement: random accesses move whole 64-byte
lines, so a pass with scattered writes moves more than it says.  Modelled: ``serial``,
``counting``, ``sort_middle`` with bbox insertion (exact insertion also reads the triangle for
every tested cell).

``stream_bandwidth`` measures sequential read, write and copy rates with numba kernels on
1..T threads, each thread streaming its own contiguous part of the buffer.
"""

import time

import numpy as np
from numba import njit, prange

from ..compiles import inner
from ..errors import InputError
from ..threads import check_threads, use_threads

MODELLED = ("serial", "counting", "sort_middle")

TRI = 36  # bytes per triangle (3 x 3 float32)
RNG = 24  # bytes per cell range (6 int32)
I32 = 4


def stage_bytes(stats):
    """Model bytes moved per stage of one build, as {stage_ms key: bytes}; None when the
    strategy or insertion mode is not modelled.  ``stats``: a Grid's stats (or a sweep row with
    the same keys)."""
    strategy = stats["strategy"]
    if strategy not in MODELLED or stats.get("insert", "bbox") != "bbox":
        return None
    F = int(stats["triangles"])
    R = int(stats["references"])
    C = int(stats["cells"])
    T = int(stats["threads"])
    ranges = TRI * F + RNG * F  # read vertices, write ranges
    rmw = 2 * I32 * R  # count[c] += 1 or start[c] -= 1 per reference
    scan = 2 * I32 * C if strategy == "serial" or T == 1 else 3 * I32 * C  # block sums read count again
    out = {"bounds_ms": TRI * F, "clear_ms": I32 * int(stats.get("cells_cleared", 0))}
    if strategy == "serial":
        out.update(ranges_ms=ranges, count_ms=RNG * F + rmw, scan_ms=scan,
                   scatter_ms=RNG * F + rmw + I32 * R)
    elif strategy == "counting":
        # count: range volumes (read ranges), ranges again, atomic add, rank written
        # scatter: ranges, rank read, start read, reference written
        out.update(ranges_ms=ranges, count_ms=2 * RNG * F + rmw + I32 * R, scan_ms=scan,
                   scatter_ms=RNG * F + 3 * I32 * R)
    else:  # sort_middle
        B = int(stats.get("bucket_entries", F))
        # bucket: ranges + bucket lists written; count / scatter: list read + one range row per entry
        out.update(bucket_ms=ranges + I32 * B, count_ms=(I32 + RNG) * B + rmw, scan_ms=scan,
                   scatter_ms=(I32 + RNG) * B + rmw + I32 * R)
    out["macro_ms"] = I32 * int(stats.get("cells_inspected", C)) + int(stats.get("macro_cells", 0))
    return out


# ---------------------------------------------------------------------------------------------
# streaming bandwidth


@inner(cache=True, _nrt=False)
def _read_part(a):
    s = 0  # an integer sum: LLVM vectorizes it (no float reassociation needed)
    for i in range(a.shape[0]):
        s += a[i]
    return s


@inner(cache=True, _nrt=False)
def _write_part(a, v):
    for i in range(a.shape[0]):
        a[i] = v


@inner(cache=True, _nrt=False)
def _copy_part(a, b):
    for i in range(a.shape[0]):
        b[i] = a[i]


@njit(cache=True, parallel=True)
def stream_read(a, n_threads, out):
    n = a.shape[0]
    for t in prange(n_threads):
        out[t] = _read_part(a[t * n // n_threads:(t + 1) * n // n_threads])


@njit(cache=True, parallel=True)
def stream_write(a, n_threads, v):
    n = a.shape[0]
    for t in prange(n_threads):
        _write_part(a[t * n // n_threads:(t + 1) * n // n_threads], v)


@njit(cache=True, parallel=True)
def stream_copy(a, b, n_threads):
    n = a.shape[0]
    for t in prange(n_threads):
        _copy_part(a[t * n // n_threads:(t + 1) * n // n_threads], b[t * n // n_threads:(t + 1) * n // n_threads])


def stream_bandwidth(mib=256, threads=(1,), runs=5):
    """Median GB/s of sequential read, write and copy (read + write bytes) over a buffer of
    ``mib`` MiB, per thread count: {T: {"read": .., "write": .., "copy": ..}}.  One warm-up pass
    per kernel first (compilation, page faults)."""
    if not (isinstance(mib, (int, np.integer)) and 1 <= mib <= 16384):
        raise InputError(f"mib must be an integer in 1..16384, got {mib!r}")
    if not (isinstance(runs, (int, np.integer)) and runs >= 1):
        raise InputError(f"runs must be a positive integer, got {runs!r}")
    threads = [check_threads(t) for t in threads]
    n = mib * 2**20 // 4
    a = np.ones(n, np.int32)
    b = np.zeros(n, np.int32)
    res = {}
    for T in threads:
        use_threads(T)
        out = np.zeros(T, np.int64)
        kernels = {
            "read": (lambda: stream_read(a, T, out), a.nbytes),
            "write": (lambda: stream_write(b, T, np.int32(2)), b.nbytes),
            "copy": (lambda: stream_copy(a, b, T), 2 * a.nbytes),
        }
        res[T] = {}
        for name, (fn, nbytes) in kernels.items():
            fn()
            ts = []
            for _ in range(runs):
                t0 = time.perf_counter()
                fn()
                ts.append(time.perf_counter() - t0)
            res[T][name] = nbytes / float(np.median(ts)) / 1e9
    return res
