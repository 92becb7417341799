"""BENCHMARKS.md section 10, "Where the cold start's time goes": one ``gridrt dump`` run with an
empty numba cache, in this process, and the time numba spends compiling each kernel.

    .venv/bin/python scripts/compile_times.py --frames 1 --size 320x240 --no-progress

takes ``gridrt dump``'s own arguments (``--out`` defaults to a temporary folder) and prints each
kernel's own compile time (numba's ``numba:compile`` events, less the compiles of the kernels it
calls, which numba runs within it), the sum per part of the engine, and the run's wall time.  The
numba cache is a fresh temporary folder (NUMBA_CACHE_DIR, set before numba loads), so every kernel
the run needs compiles; nothing is written to the project's own cache, and the temporary folders
(the cache, and the dump's when no ``--out`` is given) are removed at the end.  The dump runs with
``--no-helper``: every kernel compiles in this process, one after the other (a dump's cold start
otherwise compiles its ray casting in a helper process, gridrt.coldstart).
"""

import os
import shutil
import sys
import tempfile
import time
from collections import defaultdict

PARTS = (("gridrt.trace", "tracing and shading"), ("gridrt.grid", "grid build"), ("gridrt.scene", "scene"),
         ("numba.", "numba's own helpers"))


def part(name):
    return next((label for prefix, label in PARTS if name.startswith(prefix)), "other")


def main(argv):
    tmp = tempfile.mkdtemp(prefix="gridrt-compile-")
    try:
        return _run(argv, tmp)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def _run(argv, tmp):
    os.environ["NUMBA_CACHE_DIR"] = os.path.join(tmp, "numba")
    if "--out" not in argv and not any(a.startswith("--out=") for a in argv):
        argv = [*argv, "--out", os.path.join(tmp, "dump")]
    if "--no-helper" not in argv:
        argv = [*argv, "--no-helper"]
    t0 = time.perf_counter()
    import gridrt  # noqa: F401  (sets NUMBA_NUM_THREADS before numba loads)
    from gridrt.app.__main__ import main as dump
    from gridrt.warmup import kernel_name
    from numba.core import event

    records = []  # (kernel, own seconds)
    stack = []  # [start, seconds of the compiles nested in it]

    class Listener(event.Listener):
        def on_start(self, ev):
            stack.append([time.perf_counter(), 0.0])

        def on_end(self, ev):
            start, nested = stack.pop()
            took = time.perf_counter() - start
            if stack:
                stack[-1][1] += took
            records.append((kernel_name(ev.data["dispatcher"]), took - nested))

    with event.install_listener("numba:compile", Listener()):
        status = dump(["dump", *argv])
    wall = time.perf_counter() - t0
    per_kernel = defaultdict(lambda: [0, 0.0])
    per_part = defaultdict(lambda: [0, 0.0])
    for name, own in records:
        for table in (per_kernel[name], per_part[part(name)]):
            table[0] += 1
            table[1] += own
    total = sum(own for _, own in records)
    print(f"\n{len(records)} compiles of {len(per_kernel)} functions, {total:.1f} s of compile "
          f"in a run of {wall:.1f} s of wall time (gridrt dump {' '.join(argv)})")
    print("\n| part | compiles | s |\n|---|---|---|")
    for label, (n, s) in sorted(per_part.items(), key=lambda kv: -kv[1][1]):
        print(f"| {label} | {n} | {s:.1f} |")
    print("\n| kernel | compiles | s |\n|---|---|---|")
    for name, (n, s) in sorted(per_kernel.items(), key=lambda kv: -kv[1][1]):
        if s >= 0.1:
            print(f"| {name} | {n} | {s:.2f} |")
    return status


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
