"""``gridrt bench start``: how long ``gridrt dump --frames 1`` (the default scene, one frame) takes
from the command to its first frame written, on a cold numba cache (a fresh NUMBA_CACHE_DIR per
run: every kernel compiles) and on a warm one (every kernel loads from the cache).

Each run is a fresh process (``python -m gridrt dump ...``); its wall time is measured around it
and its CPU time (user + system) from the children's resource usage, since on a shared machine the
wall time also counts the other processes' share of the cores (the load average is recorded at
every run).  Cold runs count the kernels compiled from the dump's progress lines (its own and
its helper process's, gridrt.coldstart: the CPU time counts both processes); each cold run is
paired with one of ``--no-helper`` ("cold, no helper": every kernel compiles in the dump's own
process), run next to it on its own fresh cache.  With
PYTHONDONTWRITEBYTECODE set (Python writes no ``.pyc`` files, so a source without one compiles at
every start, unlike an installed copy), the warm runs are also measured with it unset.
"""

import argparse
import os
import re
import resource
import shlex
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from gridrt.errors import InputError
from gridrt.threads import check_threads

from .machine import finish_machine, machine_info
from .output import md_table, out_dir, progress, write_csv, write_json, write_summary

#: the cold start's aim (seconds of wall time to the first frame) and the warm start's
COLD_AIM_S = 10.0
WARM_AIM_S = 0.8
_COMPILED = re.compile(r"gridrt: compiled (\d+)/(\d+) kernels in ([\d.]+) s")
_HELPER_COMPILED = re.compile(r"gridrt: helper process: compiled (\d+)/(\d+) kernels in ([\d.]+) s")


def add_parser(bsub, common):
    s = bsub.add_parser("start", help="cold (fresh numba cache) and warm start of `gridrt dump --frames 1`",
                        description=__doc__.split("\n\n")[0])
    common(s, "start", runs=3, warmup=1, scenes=False)
    s.add_argument("--cold-runs", type=int, default=None, help="cold runs (default: --runs)")
    s.add_argument("--dump-args", default="", help="more arguments for the dump, e.g. \"--traversal dda\" "
                   "(default: none, the dump's defaults)")
    s.set_defaults(func=run_start)


def _cpu():
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def _load():
    try:
        return round(os.getloadavg()[0], 2)
    except OSError:
        return float("nan")


def dump_once(cache_dir, out, extra=(), env=None):
    """One ``gridrt dump --frames 1`` in a fresh process with NUMBA_CACHE_DIR=cache_dir: a dict of
    wall_s, cpu_s, load (1-minute load average before the run), kernels (compiled; 0 when warm)."""
    e = dict(os.environ if env is None else env)
    e["NUMBA_CACHE_DIR"] = str(cache_dir)
    cmd = [sys.executable, "-m", "gridrt", "dump", "--frames", "1", "--out", str(out), "--overwrite", *extra]
    load = _load()
    c0 = _cpu()
    t0 = time.perf_counter()
    r = subprocess.run(cmd, capture_output=True, text=True, env=e)
    wall = time.perf_counter() - t0
    cpu = _cpu() - c0
    if r.returncode != 0:
        last = (r.stderr.strip().splitlines() or ["(no output)"])[-1]
        raise InputError(f"the dump failed (exit {r.returncode}): {last}")
    m, h = _COMPILED.findall(r.stderr), _HELPER_COMPILED.findall(r.stderr)
    return dict(wall_s=wall, cpu_s=cpu, load=load, kernels=(int(m[-1][0]) if m else 0) + (int(h[-1][0]) if h else 0))


def dump_threads(extra):
    """The thread count the dumps run with: --threads among the dump's arguments extra, else the
    dump's default (all cores)."""
    p = argparse.ArgumentParser(add_help=False)
    p.add_argument("--threads")
    given = p.parse_known_args(extra)[0].threads
    try:
        return check_threads(None if given is None else int(given))
    except ValueError:
        raise InputError(f"--dump-args: --threads must be an integer, got {given!r}") from None


def run_start(a):
    if a.runs < 1 or a.warmup < 0:
        raise InputError(f"--runs must be >= 1 and --warmup >= 0, got {a.runs} and {a.warmup}")
    cold_runs = a.runs if a.cold_runs is None else a.cold_runs
    if cold_runs < 0:
        raise InputError(f"--cold-runs must be >= 0, got {cold_runs}")
    try:
        extra = shlex.split(a.dump_args)
    except ValueError as e:
        raise InputError(f"--dump-args: {e}") from None
    if any(x in ("--frames", "--out", "--no-progress", "--overwrite", "--resume", "--no-helper") for x in extra):
        raise InputError("--dump-args sets --frames, --out, --overwrite, --no-helper and the progress display itself")
    if a.quick:
        cold_runs, runs, warmup, extra = min(cold_runs, 1), 1, 1, ["--size", "16x12", *extra]
    else:
        runs, warmup = a.runs, a.warmup
    out = out_dir(a.out)
    info = machine_info([dump_threads(extra)], probe=not a.quick)
    pyc_off = bool(os.environ.get("PYTHONDONTWRITEBYTECODE"))
    kinds = [("warm", None)] + ([("warm, .pyc files", {k: v for k, v in os.environ.items()
                                                        if k != "PYTHONDONTWRITEBYTECODE"})] if pyc_off else [])
    bar = progress(2 * cold_runs + len(kinds) * (warmup + runs) + (cold_runs == 0), "bench start", a.no_progress)
    rows = []
    with tempfile.TemporaryDirectory(prefix="gridrt_start_") as tmp:
        tmp = Path(tmp)
        for i in range(cold_runs):  # (in pairs: the machine's speed drifts)
            cache = tmp / f"cold{i}"  # fresh: nothing cached
            rows.append(dict(kind="cold", run=i, **dump_once(cache, tmp / "frames", extra)))
            bar.update()
            one = dump_once(tmp / f"one{i}", tmp / "frames", [*extra, "--no-helper"])
            rows.append(dict(kind="cold, no helper", run=i, **one))
            bar.update()
        warm_cache = tmp / "cold0"
        if cold_runs == 0:  # fill a cache for the warm runs
            dump_once(warm_cache, tmp / "frames", extra)
            bar.update()
        for kind, env in kinds:
            for i in range(warmup + runs):
                r = dump_once(warm_cache, tmp / "frames", ["--no-progress", *extra], env=env)
                bar.update()
                if i >= warmup:
                    rows.append(dict(kind=kind, run=i - warmup, **r))
    bar.close()
    info = finish_machine(info)
    write_csv(rows, out / "start.csv")
    write_json(info, out / "machine.json")
    table, lines = [], []
    for kind in dict.fromkeys(r["kind"] for r in rows):
        rs = [r for r in rows if r["kind"] == kind]
        wall = statistics.median(r["wall_s"] for r in rs)
        cpu = statistics.median(r["cpu_s"] for r in rs)
        aim = COLD_AIM_S if kind.startswith("cold") else WARM_AIM_S
        table.append([kind, len(rs), f"{wall:.2f}", f"{min(r['wall_s'] for r in rs):.2f}-{max(r['wall_s'] for r in rs):.2f}",
                      f"{cpu:.2f}", f"{statistics.median(r['load'] for r in rs):.2f}",
                      str(rs[0]["kernels"]) if kind.startswith("cold") else "0", f"{aim:g}"])
        lines.append(f"{kind}: median {wall:.2f} s wall, {cpu:.2f} s CPU ({len(rs)} runs; aim {aim:g} s wall)")
    dump = " ".join(["gridrt dump --frames 1", *map(shlex.quote, extra)])
    body = [f"`{dump}` from the command to its first frame written, each run a fresh process.  Cold: a fresh "
            f"NUMBA_CACHE_DIR per run (every kernel compiles: in the dump and its helper process, which compiles "
            "the ray casting while the dump compiles the grid build; 'cold, no helper': --no-helper, all in the "
            f"dump, each run next to a cold one); warm: {warmup} untimed run(s), then the cache "
            "as the runs left it.  Wall time is what a user waits; CPU time is the processes' own (user + "
            "system), the figure that does not depend on other processes sharing the cores (load: the 1-minute "
            "load average before each run)."
            + ("  PYTHONDONTWRITEBYTECODE is set here: Python writes no .pyc files, so a source without one "
               "compiles at every start; 'warm, .pyc files' unsets it, as an installed copy runs." if pyc_off else ""),
            "", *md_table(["start", "runs", "wall s median", "wall s range", "CPU s median", "load", "kernels compiled",
                           "aim s"], table)]
    write_summary(out / "summary.md", "Cold and warm start", info, [("Start to first frame", body)])
    for line in lines:
        print(line)
    print(f"wrote {out}/start.csv, summary.md, machine.json")
    return 0
