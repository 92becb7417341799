"""The machine record every benchmark writes (machine.json, the summary's Machine section): date,
CPU, cores, threads, load, effective cores, versions, commit and command line."""

import datetime
import os
import platform
import shlex
import subprocess
import sys
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

import llvmlite.binding as ll
import numba
import numpy as np


def git_commit():
    """Short commit hash of the repository this code runs from, or 'unknown'."""
    root = Path(__file__).resolve().parents[2]
    try:
        r = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=root, capture_output=True, text=True,
                           timeout=10)
        return r.stdout.strip() or "unknown"
    except (OSError, subprocess.SubprocessError):
        return "unknown"


def _cpu_model():
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def _simd():
    """The widest x86 vector extension LLVM may use here ("AVX-512", "AVX2", ...): hosts named
    alike (a KVM guest's "AMD EPYC") differ in it, and so do the kernels' vector widths."""
    ll.initialize_native_target()
    have = set(ll.get_host_cpu_features().flatten().split(","))
    for flag, name in (("+avx512f", "AVX-512"), ("+avx2", "AVX2"), ("+avx", "AVX"), ("+sse4.2", "SSE4.2")):
        if flag in have:
            return name
    return "none known"


def _version(dist):
    try:
        return version(dist)
    except PackageNotFoundError:
        return "not installed"


_BUSY = ("import time\nt = time.perf_counter()\nx = 0\nfor i in range(3000000):\n    x += i\n"
         "print(time.perf_counter() - t)")


def effective_cores():
    """How many cores' worth of CPU this machine delivers right now: ``n`` busy Python processes
    (n = cpu count) at once against one alone, n * t_alone / t_slowest.  On a shared or
    virtualised host this can be well below the core count (other tenants, CPU quotas)."""
    n = os.cpu_count() or 1

    def run(k):
        procs = [subprocess.Popen([sys.executable, "-c", _BUSY], stdout=subprocess.PIPE, text=True) for _ in range(k)]
        return [float(p.communicate()[0]) for p in procs]

    try:
        alone = min(run(1)[0] for _ in range(2))
        together = max(run(n))
    except (OSError, ValueError):
        return float("nan")
    return round(n * alone / together, 2)


def machine_info(threads, probe=True):
    """Dict describing this run: date, CPU model, cores, CPUs allowed, threads used, load
    average, memory, versions (python, numpy, numba, embreex, ...), commit, command line, and with
    ``probe`` the effective cores (:func:`effective_cores`, None without: a --quick smoke run, whose
    figures are not measurements, skips the probe's busy processes)."""
    try:
        allowed = len(os.sched_getaffinity(0))
    except AttributeError:
        allowed = os.cpu_count()
    mem = ""
    try:
        with open("/proc/meminfo") as fh:
            kb = int(fh.readline().split()[1])
            mem = f"{kb / 2**20:.1f} GiB"
    except (OSError, ValueError, IndexError):
        pass
    try:
        load = [round(x, 2) for x in os.getloadavg()]
    except OSError:
        load = []
    return {
        "date": datetime.datetime.now().astimezone().isoformat(timespec="seconds"),
        "cpu": _cpu_model(),
        "simd": _simd(),
        "cores": os.cpu_count(),
        "cpus_allowed": allowed,
        "threads_used": list(threads),
        "memory": mem,
        "load_average_start": load,
        "effective_cores_start": effective_cores() if probe else None,
        "python": platform.python_version(),
        "numpy": np.__version__,
        "numba": numba.__version__,
        "numba_threading_layer": os.environ.get("NUMBA_THREADING_LAYER", "default"),
        "embreex": _version("embreex"),
        "trimesh": _version("trimesh"),
        "matplotlib": _version("matplotlib"),
        "os": platform.platform(),
        "commit": git_commit(),
        "command": "gridrt " + " ".join(shlex.quote(a) for a in sys.argv[1:]) if sys.argv else "",
    }


def finish_machine(info):
    """Add the end-of-run load average (a high one means other processes shared the cores) and
    the effective cores, where machine_info measured them at the start (None where it did not)."""
    try:
        info["load_average_end"] = [round(x, 2) for x in os.getloadavg()]
    except OSError:
        info["load_average_end"] = []
    info["effective_cores_end"] = None if info.get("effective_cores_start") is None else effective_cores()
    return info


def machine_md(info):
    """Markdown lines for the machine record."""
    noisy = (info.get("load_average_start") or [0])[0]  # the end figure includes this run's own threads
    lines = [
        f"- date: {info['date']}; commit `{info['commit']}`",
        f"- CPU: {info['cpu']} ({info.get('simd', 'vector extension not recorded')}); {info['cores']} cores "
        f"({info['cpus_allowed']} allowed); memory {info['memory']}",
        f"- threads used: {', '.join(map(str, info['threads_used']))}",
        f"- python {info['python']}, numpy {info['numpy']}, numba {info['numba']} "
        f"(threading layer {info['numba_threading_layer']}), embreex {info['embreex']}, trimesh {info['trimesh']}",
        f"- load average (1, 5, 15 min) at start {info.get('load_average_start')}, at end "
        f"{info.get('load_average_end')}",
        f"- command: `{info['command']}`",
    ]
    if info.get("workers"):
        lines.append(f"- measured on {info.get('cluster', 'a Dask cluster')}; each row names its worker (CSV columns "
                     "worker, worker_cpu, worker_cores, worker_load_start); the workers' machines:")
        for addr, w in sorted(info["workers"].items()):
            lines.append(f"  - `{addr}`: {w.get('cpu')}; {w.get('cores')} cores; memory {w.get('memory')}; python "
                         f"{w.get('python')}, numpy {w.get('numpy')}, numba {w.get('numba')}; commit `{w.get('commit')}`; "
                         f"effective cores {w.get('effective_cores_start')}")
    eff = [x for x in (info.get("effective_cores_start"), info.get("effective_cores_end")) if x is not None]
    if eff:
        lines.append(f"- effective cores ({info['cores']} busy processes at once against one alone): "
                     f"{info.get('effective_cores_start')} at start, {info.get('effective_cores_end')} at end")
    elif "effective_cores_start" in info:
        lines.append("- effective cores: not measured (a --quick smoke run)")
    cores = info["cores"] or 1
    if eff and min(eff) < 0.8 * cores:
        lines.append(f"- **note:** this machine delivered only {min(eff)} of its {cores} cores at some point of the run "
                     "(host contention or a CPU quota): multi-thread timings and speed-ups are lower than the "
                     "hardware allows and vary from run to run.")
    if noisy > 0.5 * cores:
        lines.append(f"- **note:** the 1-minute load average was {noisy:.2f} on {info['cores']} cores at the start: other "
                     "processes shared the CPU during this run, so timings are noisier (and multi-thread "
                     "speed-ups smaller) than on an idle machine; the min column is the least disturbed run.")
    return lines
