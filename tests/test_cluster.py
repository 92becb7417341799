"""Frame dumps and benchmark sweeps on a Dask cluster, with real components only: the
real command line in a subprocess, a local cluster of 2 worker processes (``--workers 2``), and
a real ``dask scheduler`` with two ``dask worker`` processes started here on 127.0.0.1 (random
free ports, torn down at the end).

The reference is the one-process dump of the same options: a cluster run must write the same
PNGs and buffers byte for byte, and the same stats rows in the same order except for timings,
thread counts and the worker column.  Faults: a worker killed with SIGKILL mid-run, Ctrl-C
(SIGINT to the whole process group, as a terminal sends it), a scene that does not load, an
unreachable scheduler, and the cluster extra missing.
"""

import csv
import json
import os
import signal
import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

pytest.importorskip("distributed", reason="the cluster extra (pip install 'gridrt[cluster]') is not installed")

REPO = Path(__file__).resolve().parents[1]
DASK = Path(sys.executable).parent / "dask"
#: stats columns a cluster run may change: timings (and the rate made of one), thread counts (and the
#: strategy the default "auto" resolves to for them: each builds the serial grid), the worker, and
#: whether kernels compiled during the frame
UNCOMPARED = {"mrays", "threads", "render_threads", "worker", "strategy", "compiled"}

FAST = ["--scene", "marbles", "--count", "3000", "--frames", "30", "--size", "96x72", "--save-buffers"]
#: frames slow enough (single-ray DDA at 640x480, about 80 ms each) that a kill or a Ctrl-C lands mid-run
SLOW = ["--scene", "marbles", "--frames", "60", "--size", "640x480", "--traversal", "dda", "--chunk", "2"]


def gridrt(*args, timeout=600, **kw):
    return subprocess.run([sys.executable, "-m", "gridrt", *map(str, args)], cwd=REPO, capture_output=True,
                          text=True, timeout=timeout, **kw)


def start_gridrt(*args, **kw):
    return subprocess.Popen([sys.executable, "-m", "gridrt", *map(str, args)], cwd=REPO, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, **kw)


def rows_of(folder):
    with open(Path(folder) / "stats.csv") as fh:
        return list(csv.DictReader(fh))


def untimed(row):
    return {k: v for k, v in row.items() if not k.endswith("_ms") and k not in UNCOMPARED}


def assert_same_dump(got, ref, frames=None):
    """The files of dump ``got`` are those of ``ref`` (all, or its first ``frames``)."""
    ref_rows, got_rows = rows_of(ref), rows_of(got)
    n = len(ref_rows) if frames is None else frames
    assert len(got_rows) == n
    assert [int(r["frame"]) for r in got_rows] == list(range(n))
    for a, b in zip(got_rows, ref_rows):
        assert untimed(a) == untimed(b)
    names = sorted(p.name for p in Path(ref).iterdir() if p.suffix in (".png", ".npy")
                   and int(p.name[6:11]) < n)
    assert sorted(p.name for p in Path(got).iterdir() if p.name not in ("stats.csv", "run.json")) == names
    for name in names:
        assert (Path(got) / name).read_bytes() == (Path(ref) / name).read_bytes(), name


def worker_column(folder):
    return [r["worker"] for r in rows_of(folder)]


@pytest.fixture(scope="module")
def fast_ref(tmp_path_factory):
    out = tmp_path_factory.mktemp("ref") / "fast"
    r = gridrt("dump", *FAST, "--threads", "2", "--no-progress", "--out", out)
    assert r.returncode == 0, r.stderr
    assert "worker" not in rows_of(out)[0]  # a one-process dump keeps its columns
    return out


@pytest.fixture(scope="module")
def slow_ref(tmp_path_factory):
    out = tmp_path_factory.mktemp("ref") / "slow"
    r = gridrt("dump", *[a for a in SLOW if a not in ("--chunk", "2")], "--threads", "2", "--no-progress",
               "--out", out)
    assert r.returncode == 0, r.stderr
    return out


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class DaskCluster:
    """A real ``dask scheduler`` and ``dask worker`` processes (no nanny: a killed worker stays
    dead) on 127.0.0.1, random free ports."""

    def __init__(self, folder, workers=2):
        self.folder = Path(folder)
        self.folder.mkdir(parents=True, exist_ok=True)
        self.procs = []
        try:
            self._up(workers)
        except BaseException:
            self.close()
            raise

    def _up(self, workers):
        info = self.folder / "scheduler.json"
        self.scheduler = self._start("scheduler", "--host", "127.0.0.1", "--port", "0", "--dashboard-address",
                                     "127.0.0.1:0", "--scheduler-file", info)
        deadline = time.time() + 60
        while not info.exists() and time.time() < deadline:
            time.sleep(0.1)
        assert info.exists(), "the dask scheduler did not start"
        time.sleep(0.2)
        self.address = json.loads(info.read_text())["address"]
        self.workers = [self._start("worker", self.address, "--nthreads", "1", "--no-nanny", "--name", f"w{i}",
                                    "--host", "127.0.0.1") for i in range(workers)]
        from distributed import Client

        with Client(self.address, timeout=30) as c:
            c.wait_for_workers(workers, timeout=60)
            self.addresses = {v["name"]: k for k, v in c.scheduler_info()["workers"].items()}

    def _start(self, *args):
        log = open(self.folder / f"{args[0]}-{len(self.procs)}.log", "w")
        p = subprocess.Popen([str(DASK), *map(str, args)], cwd=self.folder, stdout=log, stderr=subprocess.STDOUT)
        self.procs.append(p)
        return p

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def close(self):
        for p in reversed(self.procs):  # the workers first: they do not wait for a scheduler gone
            if p.poll() is None:
                p.terminate()
            try:
                p.wait(timeout=10)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()


@pytest.fixture
def dask_cluster(tmp_path):
    """A cluster of the test's own (a test that kills a worker)."""
    with DaskCluster(tmp_path / "cluster") as cl:
        yield cl


@pytest.fixture(scope="module")
def shared_cluster(tmp_path_factory):
    """One cluster for the module's tests that leave its processes as they found them."""
    with DaskCluster(tmp_path_factory.mktemp("shared") / "cluster") as cl:
        yield cl


# ---------------------------------------------------------------------------------------------
# the output is the one-process dump's
# ---------------------------------------------------------------------------------------------

def test_local_cluster_dump_is_the_one_process_dump(tmp_path, fast_ref):
    """``--workers 2``: both workers render (chunks of 3 frames), the client writes every frame
    once, in order, with a worker column; PNGs, buffers and stats are the one-process dump's; the
    dashboard's address is printed, and the summary names the cluster and its threads."""
    out = tmp_path / "d"
    r = gridrt("dump", *FAST, "--workers", 2, "--chunk", 3, "--out", out)
    assert r.returncode == 0, r.stderr
    assert_same_dump(out, fast_ref)
    workers = worker_column(out)
    assert all(w.startswith("tcp://127.0.0.1:") for w in workers)
    assert len(set(workers)) == 2, "one worker rendered every chunk"
    for c in range(0, 30, 3):  # a chunk is rendered by one worker
        assert len(set(workers[c:c + 3])) == 1
    assert "dashboard: http://" in r.stderr
    assert "30/30" in r.stderr, "no progress bar over frames"
    threads = {int(x["threads"]) for x in rows_of(out)}
    assert threads == {max(1, (os.cpu_count() or 1) // 2)}  # the cores shared among the workers
    assert "a local cluster of 2 worker processes" in r.stdout


@pytest.mark.slow  # (a real cluster started for it; the quick run keeps the local cluster's dump)
def test_more_threads_than_cores_are_warned_about(tmp_path):
    cores = os.cpu_count() or 1
    r = gridrt("dump", "--frames", "2", "--size", "16x12", "--workers", 2, "--threads", cores, "--no-progress",
               "--out", tmp_path / "d")
    assert r.returncode == 0, r.stderr
    assert f"gridrt: warning: 2 workers x {cores} threads = {2 * cores} threads on {cores} cores" in r.stderr


@pytest.mark.slow  # (a real cluster started for it; the quick run keeps the local cluster's dump)
def test_settable_threads_and_a_scene_with_looks(tmp_path):
    """``--threads 1`` per worker is taken; a scene with textures and lights (the shipped MD2 with
    its skin) renders the same on the cluster as in one process."""
    args = ["--scene", REPO / "assets" / "sydney.md2", "--frames", "8", "--size", "64x48", "--save-buffers"]
    ref, out = tmp_path / "ref", tmp_path / "d"
    assert gridrt("dump", *args, "--no-progress", "--out", ref).returncode == 0
    r = gridrt("dump", *args, "--workers", 2, "--threads", 1, "--no-progress", "--out", out)
    assert r.returncode == 0, r.stderr
    assert_same_dump(out, ref)
    assert {int(x["threads"]) for x in rows_of(out)} == {1}
    assert {x["shading"] for x in rows_of(out)} == {"material"}


@pytest.mark.slow  # (a real cluster started for it; the quick run keeps the local cluster's dump)
def test_a_scene_that_moves_its_frame_between_chunks(tmp_path):
    """A folder of frames whose object travels 1.5 times its size per frame: the pipeline moves
    its frame of reference again and again, so chunks started from the first frame's origin are
    rendered again from where their predecessor ended; the dump is still the one-process dump."""
    from gridrt.scene import icosphere_mesh

    ico = icosphere_mesh(80)
    folder = tmp_path / "frames"
    folder.mkdir()
    for k in range(21):
        v = ico.vertices64 + np.array([3.0 * k, 0.2 * k, 0.0])
        with open(folder / f"f{k:03d}.obj", "w") as fh:
            fh.writelines(f"v {float(x)!r} {float(y)!r} {float(z)!r}\n" for x, y, z in v)
            fh.writelines(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in ico.faces)
    args = ["--scene", folder, "--frames", "20", "--size", "240x60", "--eye", "30,2,25", "--target", "30,2,0",
            "--save-buffers"]
    ref, out = tmp_path / "ref", tmp_path / "d"
    assert gridrt("dump", *args, "--no-progress", "--out", ref).returncode == 0
    r = gridrt("dump", *args, "--workers", 2, "--chunk", 3, "--no-progress", "--out", out)
    assert r.returncode == 0, r.stderr
    assert_same_dump(out, ref)
    hits = [np.load(ref / f"frame_{i:05d}_id.npy") for i in (0, 19)]
    assert all((h >= 0).sum() > 10 for h in hits), "the object left the view: the test would show nothing"
    from gridrt.config import GridParams, RenderParams
    from gridrt.pipeline import FramePipeline
    from gridrt.scene import make_scene

    pipe = FramePipeline(make_scene(str(folder)), GridParams(threads=1), RenderParams(8, 8, threads=1))
    for i in range(20):
        pipe.step(i / 30.0)
    assert pipe.recentred >= 5, "the scene does not move the pipeline's frame: the test shows nothing"


@pytest.mark.slow  # (a real cluster started for it; the quick run keeps the local cluster's dump)
def test_existing_scheduler_dump(tmp_path, fast_ref, shared_cluster):
    """``--scheduler`` on a real ``dask scheduler`` with two ``dask worker`` processes: the same
    files; each worker divides the machine's cores with the other."""
    out = tmp_path / "d"
    r = gridrt("dump", *FAST, "--scheduler", shared_cluster.address, "--chunk", 4, "--no-progress", "--out", out)
    assert r.returncode == 0, r.stderr
    assert_same_dump(out, fast_ref)
    assert set(worker_column(out)) <= set(shared_cluster.addresses.values())
    assert {int(x["threads"]) for x in rows_of(out)} == {max(1, (os.cpu_count() or 1) // 2)}


# ---------------------------------------------------------------------------------------------
# faults
# ---------------------------------------------------------------------------------------------

def wait_for_frames(folder, n, proc, timeout=300):
    deadline = time.time() + timeout
    while time.time() < deadline:
        if proc.poll() is not None:
            return len(list(Path(folder).glob("frame_*.png")))
        k = len(list(Path(folder).glob("frame_*.png")))
        if k >= n:
            return k
        time.sleep(0.02)
    raise AssertionError(f"no {n} frames in {timeout} s")


@pytest.mark.slow  # (a fault on a real cluster: a reference dump and a cluster run of 60 frames, about 25 s)
def test_worker_killed_mid_run_loses_no_frame(tmp_path, slow_ref, dask_cluster):
    """SIGKILL one of the two workers while both are busy: its chunks run again on the other, the
    dump completes and is the one-process dump; after the kill only the survivor renders."""
    out = tmp_path / "d"
    p = start_gridrt("dump", *SLOW, "--scheduler", dask_cluster.address, "--no-progress", "--out", out)
    try:
        written = wait_for_frames(out, 6, p)
        assert p.poll() is None and written < 40, "the run ended before the kill: make its frames slower"
        victim = dask_cluster.workers[0]
        victim.send_signal(signal.SIGKILL)
        victim.wait(timeout=30)
        stdout, stderr = p.communicate(timeout=600)
    finally:
        if p.poll() is None:
            p.kill()
    assert p.returncode == 0, stderr
    assert_same_dump(out, slow_ref)
    dead = dask_cluster.addresses["w0"]
    workers = worker_column(out)
    last_dead = max((i for i, w in enumerate(workers) if w == dead), default=-1)
    assert last_dead < written + 4 * 2, "the killed worker kept rendering"  # (results ahead of the writes: a few chunks of 2)
    assert workers[-1] == dask_cluster.addresses["w1"]


def descendants(pid):
    import psutil

    try:
        return psutil.Process(pid).children(recursive=True)
    except psutil.NoSuchProcess:
        return []


@pytest.mark.slow  # (a fault on a real cluster, with the 60-frame reference dump)
def test_ctrl_c_stops_the_cluster_and_leaves_whole_frames(tmp_path, slow_ref):
    """Ctrl-C (SIGINT to the process group, as a terminal sends it) on ``--workers 2``: the
    command exits with 130, its worker processes are gone, and the folder holds whole frames
    only, each the one-process dump's, with their stats rows and nothing else."""
    import psutil

    out = tmp_path / "d"
    p = start_gridrt("dump", *SLOW, "--workers", 2, "--no-progress", "--out", out, start_new_session=True)
    try:
        written = wait_for_frames(out, 4, p)
        assert p.poll() is None and written < 40, "the run ended before Ctrl-C: make its frames slower"
        children = descendants(p.pid)
        assert len(children) >= 2
        os.killpg(p.pid, signal.SIGINT)
        stdout, stderr = p.communicate(timeout=120)
    finally:
        if p.poll() is None:
            os.killpg(p.pid, signal.SIGKILL)
    assert p.returncode == 130, stderr
    assert "interrupted" in stderr and "Traceback" not in stderr
    _, alive = psutil.wait_procs(children, timeout=30)
    assert not alive, f"processes left running: {alive}"
    n = len(rows_of(out))
    assert 4 <= n < 60
    assert_same_dump(out, slow_ref, frames=n)
    for i in range(n):
        Image.open(out / f"frame_{i:05d}.png").load()  # whole: decodes


@pytest.mark.slow  # (a real cluster started for it; the quick run keeps the local cluster's dump)
def test_scene_that_fails_to_load_gives_the_local_error_once(tmp_path):
    """A scene file the workers cannot read stops the run with the error a local run gives, printed
    once, and exit status 2."""
    bad = tmp_path / "bad.obj"
    bad.write_text("v 0 0 0\nv 1 0 0\nf 1 2 7\n")
    local = gridrt("dump", "--scene", bad, "--frames", "40", "--no-progress", "--out", tmp_path / "a")
    assert local.returncode == 2
    error = [line for line in local.stderr.splitlines() if line.startswith("gridrt: error:")]
    assert len(error) == 1 and "bad.obj" in error[0]
    r = gridrt("dump", "--scene", bad, "--frames", "40", "--workers", 2, "--chunk", 1, "--no-progress",
               "--out", tmp_path / "b")
    assert r.returncode == 2
    assert [line for line in r.stderr.splitlines() if "error" in line.lower()] == error
    assert "Traceback" not in r.stderr
    assert not list((tmp_path / "b").glob("*.png"))


@pytest.mark.slow  # (a real cluster started for it; the quick run keeps the local cluster's dump)
def test_a_warning_is_printed_once_as_a_local_run_prints_it(tmp_path):
    """A scene whose detail is under float32's floor (80 triangles 1e-3 across beside one 1e4
    across): every worker's pipeline warns at its first frame; the client prints the warning once,
    the line a one-process dump prints."""
    from gridrt.scene import icosphere_mesh

    ico = icosphere_mesh(80)
    path = tmp_path / "fine.obj"
    with open(path, "w") as fh:
        fh.writelines(f"v {float(x) * 1e-3!r} {float(y) * 1e-3!r} {float(z) * 1e-3!r}\n" for x, y, z in ico.vertices64)
        fh.write("v 1e4 0 0\nv 0 1e4 0\nv 0 0 1e4\n")
        fh.writelines(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in ico.faces)
        n = len(ico.vertices64)
        fh.write(f"f {n + 1} {n + 2} {n + 3}\n")
    args = ["dump", "--scene", path, "--frames", "8", "--size", "16x12", "--no-progress"]
    local = gridrt(*args, "--out", tmp_path / "a")
    assert local.returncode == 0, local.stderr
    warned = [line for line in local.stderr.splitlines() if line.startswith("gridrt: warning:")]
    assert len(warned) == 1 and "float32" in warned[0], local.stderr
    r = gridrt(*args, "--workers", 2, "--chunk", 1, "--out", tmp_path / "b")
    assert r.returncode == 0, r.stderr
    assert [line for line in r.stderr.splitlines() if "warning" in line.lower()] == warned


def test_unreachable_scheduler_is_a_clear_error_within_seconds(tmp_path):
    port = free_port()
    t0 = time.perf_counter()
    r = gridrt("dump", "--frames", "2", "--scheduler", f"tcp://127.0.0.1:{port}", "--out", tmp_path / "d")
    took = time.perf_counter() - t0
    assert r.returncode == 2
    assert f"gridrt: error: cannot reach the Dask scheduler at tcp://127.0.0.1:{port}" in r.stderr
    assert "Traceback" not in r.stderr
    assert took < 30  # 5 s for the connection, the rest is Python starting


def test_missing_extra_says_how_to_install_it(tmp_path):
    """Without ``distributed`` (hidden from the import system) --workers and --scheduler name the
    extra to install; a dump without them works and never imports Dask."""
    hide = ("import sys; sys.modules['distributed'] = None; sys.modules['dask'] = None; "
            "from gridrt.app.__main__ import main; sys.exit(main(sys.argv[1:]))")
    for flag in (["--workers", "2"], ["--scheduler", "tcp://127.0.0.1:1"]):
        r = subprocess.run([sys.executable, "-c", hide, "dump", "--frames", "1", *flag, "--out", tmp_path / "d"],
                           cwd=REPO, capture_output=True, text=True, timeout=300)
        assert r.returncode == 2, r.stderr
        assert "python -m pip install 'gridrt[cluster]'" in r.stderr and "Traceback" not in r.stderr
    probe = ("import sys; from gridrt.app.__main__ import main; rc = main(sys.argv[1:]); "
             "print('DASK', sorted(m for m in sys.modules if m.split('.')[0] in ('dask', 'distributed'))); "
             "sys.exit(rc)")
    r = subprocess.run([sys.executable, "-c", probe, "dump", "--frames", "1", "--size", "16x12", "--no-progress",
                        "--out", tmp_path / "e"], cwd=REPO, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert "DASK []" in r.stdout


@pytest.mark.parametrize("args,message", [
    (["--workers", "2", "--scheduler", "tcp://127.0.0.1:1"], "not both"),
    (["--workers", "0"], "--workers must be at least 1"),
    (["--workers", "2", "--chunk", "0"], "--chunk must be at least 1"),
    (["--chunk", "4"], "--chunk applies to a cluster run"),
    (["--scheduler", " "], "--scheduler needs an address"),
])
def test_bad_cluster_options(tmp_path, args, message):
    r = gridrt("dump", "--frames", "2", *args, "--out", tmp_path / "d")
    assert r.returncode == 2 and message in r.stderr and "Traceback" not in r.stderr


@pytest.mark.slow  # (a real cluster started for it; the quick run keeps the local cluster's dump)
def test_dashboard_is_live():
    """The dashboard address a local cluster prints answers (bokeh serves it), also when its usual
    port is taken (another cluster running): then it is served on another port, the address says
    which, and no warning about the port reaches the user."""
    import warnings

    from gridrt.app.cluster.scheduler import DASHBOARD_PORT, Cluster

    with socket.socket() as held:
        try:
            held.bind(("127.0.0.1", DASHBOARD_PORT))
            held.listen()
        except OSError:
            pass  # taken already, by something else
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            with Cluster(workers=1) as cl:
                assert cl.dashboard.startswith("http://127.0.0.1:")
                assert f":{DASHBOARD_PORT}/" not in cl.dashboard, cl.dashboard
                with urllib.request.urlopen(cl.dashboard, timeout=30) as page:
                    assert page.status == 200
    assert not [w for w in caught if "in use" in str(w.message)], [str(w.message) for w in caught]


# ---------------------------------------------------------------------------------------------
# benchmarks
# ---------------------------------------------------------------------------------------------

GRID_COLUMNS = ["scene", "triangles", "strategy", "threads", "grid", "grid_built", "cells", "references",
                "grid_bytes"]


def bench_rows(folder, name):
    with open(Path(folder) / name) as fh:
        return list(csv.DictReader(fh))


@pytest.mark.slow  # (a sweep here and on a local cluster of 2 processes, 25 s; the quick run benches on a scheduler)
def test_bench_build_on_a_local_cluster(tmp_path):
    """``bench build --workers 2``: the rows (grid contents: cells, references, bytes) are a local
    run's, in its order; every row names its worker and that worker's machine, and machine.json
    holds every worker's record."""
    args = ["bench", "build", "--quick", "--strategies", "serial,sort_middle", "--threads", "1,2", "--no-progress"]
    local, remote = tmp_path / "local", tmp_path / "cluster"
    assert gridrt(*args, "--out", local).returncode == 0
    r = gridrt(*args, "--workers", 2, "--out", remote)
    assert r.returncode == 0, r.stderr
    a, b = bench_rows(local, "build_sweep.csv"), bench_rows(remote, "build_sweep.csv")
    assert [[x[k] for k in GRID_COLUMNS] for x in b] == [[x[k] for k in GRID_COLUMNS] for x in a]
    info = json.loads((remote / "machine.json").read_text())
    assert set(info["workers"]) == {x["worker"] for x in b}
    for x in b:
        w = info["workers"][x["worker"]]
        assert x["worker_cpu"] == w["cpu"] and int(x["worker_cores"]) == w["cores"] == os.cpu_count()
        assert float(x["build_ms"]) > 0
    assert "measured on a local cluster of 2 worker processes" in (remote / "summary.md").read_text()


@pytest.mark.slow  # (a real cluster started for it; the quick run keeps the local cluster's dump)
def test_bench_frame_on_an_existing_scheduler(tmp_path, shared_cluster):
    """``bench frame --scheduler``: the frames' figures that are not timings (hit fraction, tests
    and cells per ray, references) are a local run's; each row names one of the cluster's workers."""
    args = ["bench", "frame", "--quick", "--scenes", "marbles:500,icosphere:320", "--threads", "1,2",
            "--no-progress"]
    local, remote = tmp_path / "local", tmp_path / "cluster"
    assert gridrt(*args, "--out", local).returncode == 0
    r = gridrt(*args, "--scheduler", shared_cluster.address, "--out", remote)
    assert r.returncode == 0, r.stderr
    a, b = bench_rows(local, "frame.csv"), bench_rows(remote, "frame.csv")
    keys = ["scene", "threads", "traversal", "split", "grid", "references", "hit_fraction", "tests_per_ray",
            "cells_per_ray"]
    assert [[x[k] for k in keys] for x in b] == [[x[k] for k in keys] for x in a]
    assert {x["worker"] for x in b} <= set(shared_cluster.addresses.values())
    assert all(float(x["fps"]) > 0 for x in b)
