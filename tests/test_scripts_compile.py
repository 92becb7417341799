"""scripts/compile_times.py (BENCHMARKS.md section 10's per-kernel breakdown of a cold start) runs
a real dump with an empty numba cache and lists the kernels that compiled: for the single-ray
traversal on one thread, the DDA render tile and the serial build's passes, and none of the CGT
packet walk, which that path never calls.  scripts/inner_optimise.py (the same section's inner
kernels compiled gridrt's way against numba's) runs both ways and prints its table."""

import re
import subprocess
import sys

import pytest
from helpers.cli import REPO


@pytest.mark.slow
def test_compile_times_lists_the_kernels_of_the_path_that_ran(tmp_path):
    r = subprocess.run([sys.executable, "scripts/compile_times.py", "--frames", "1", "--size", "16x12", "--traversal",
                        "dda", "--threads", "1", "--no-progress", "--out", str(tmp_path / "d")],
                       cwd=REPO, capture_output=True, text=True, timeout=900, check=False)
    assert r.returncode == 0, r.stderr[-3000:]
    assert (tmp_path / "d" / "frame_00000.png").is_file()
    m = re.search(r"(\d+) compiles of (\d+) functions, ([\d.]+) s of compile in a run of ([\d.]+) s", r.stdout)
    assert m, r.stdout
    compiles, functions, compile_s, wall_s = int(m[1]), int(m[2]), float(m[3]), float(m[4])
    assert compiles >= functions > 10 and 0 < compile_s <= wall_s
    kernels = re.findall(r"^\| (gridrt\.[\w.]+) \| (\d+) \|", r.stdout, re.MULTILINE)
    names = {k for k, _ in kernels}
    assert {"gridrt.trace.traverse.trace_ray", "gridrt.trace.render._render_tile",
            "gridrt.grid.strategies.serial.count_serial", "gridrt.grid.strategies.serial.scatter_serial"} <= names, names
    assert not any(".cgt." in k for k in names), names
    parts = dict(re.findall(r"^\| (tracing and shading|grid build) \| (\d+) \|", r.stdout, re.MULTILINE))
    assert int(parts["tracing and shading"]) > 0 and int(parts["grid build"]) > 0


@pytest.mark.slow
def test_inner_optimise_runs_both_ways(tmp_path):
    """scripts/inner_optimise.py (BENCHMARKS.md section 10) runs bench frame compiled gridrt's way
    and numba's way, each in a process with a numba cache of its own, and prints the table of
    both, with each run's wall time."""
    r = subprocess.run([sys.executable, "scripts/inner_optimise.py", "--scenes", "icosphere:1280:twist", "--size",
                        "24", "--runs", "1", "--warmup", "0", "--rounds", "1", "--threads", "1", "--out",
                        str(tmp_path / "o")], cwd=REPO, capture_output=True, text=True, timeout=900, check=False)
    assert r.returncode == 0, r.stderr[-3000:]
    assert "| scene | build, gridrt | build, numba | render, gridrt | render, numba |" in r.stdout, r.stdout
    row = re.search(r"^\| icosphere 1\.3k twisted \| ([\d.]+) \| ([\d.]+) \| ([\d.]+) \| ([\d.]+) \|$", r.stdout,
                    re.MULTILINE)
    assert row and all(float(x) > 0 for x in row.groups()), r.stdout
    assert re.search(r"whole run \(cold compile and every frame\), s: gridrt [\d.]+; numba [\d.]+", r.stdout), r.stdout
    assert (tmp_path / "o" / "summary.md").is_file()
