"""A dump leaves only whole frames, each with its stats row, whatever stops it: a full disk (an
injected ENOSPC at every write of a small dump, and a real small file system where this machine
lets the test mount one), a folder removed or renamed mid-run, a read-only folder, SIGINT and
SIGTERM at random (seeded) moments of a one-process and a cluster dump.  A folder holding another
dump is refused unless ``--overwrite`` (the old files go first) or ``--resume`` (the result is the
straight dump's, byte for byte, also across the pipeline's moves of its frame of reference).

After every stop: each PNG decodes, each PNG has exactly one row of ``stats.csv`` and each row its
PNG (and buffers), no temporary file is left, and stderr holds one line, without a traceback,
saying how many frames are complete.  The references are straight dumps of the same options and
the files' own contents (PIL decodes them, csv reads the rows), not what the stopped run claims.
"""

import csv
import errno
import os
import random
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from gridrt.app import frame_out
from gridrt.app.__main__ import main

REPO = Path(__file__).resolve().parents[1]
#: a small dump: 3 frames with their buffers; one thread (the dumps run in this process, one after
#: another: no parallel kernel compiles in the background meanwhile)
SMALL = ["--scene", "icosphere", "--count", "320", "--frames", "3", "--size", "32x24", "--save-buffers",
         "--threads", "1", "--no-progress"]
#: stats columns that differ between two runs of the same frames: timings, rates, threads (and the
#: strategy "auto" resolves to for them), the worker, whether kernels compiled during the frame
TIMED = {"mrays", "threads", "render_threads", "worker", "strategy", "compiled"}
STOP_LINE = re.compile(r"gridrt: stopped after (\d+) of (\d+) frames \((.*)\): (.*)\Z")


def gridrt(*args, **kw):
    return subprocess.Popen([sys.executable, "-m", "gridrt", *map(str, args)], cwd=REPO, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, **kw)


def rows_of(folder):
    path = Path(folder) / "stats.csv"
    if not path.exists():
        return []
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def untimed(row):
    return {k: v for k, v in row.items() if not k.endswith("_ms") and k not in TIMED}


def whole_frames(folder, buffers=False):
    """The number of frames in ``folder``, checked: frames 0 .. n-1 each with one row, rows in
    order, each PNG decodes, buffers load with the image's shape, no other frame file and no
    temporary file."""
    folder = Path(folder)
    names = sorted(p.name for p in folder.iterdir())
    assert not [x for x in names if x.endswith(".part") or x.startswith(".")], f"temporary files left: {names}"
    rows = rows_of(folder)
    n = len(rows)
    assert [int(r["frame"]) for r in rows] == list(range(n)), "rows out of order or repeated"
    kinds = [".png"] + (["_t.npy", "_id.npy"] if buffers else [])
    frames = sorted(x for x in names if x.startswith("frame_"))
    assert frames == sorted(f"frame_{i:05d}{k}" for i in range(n) for k in kinds), "a frame without its row, or a row without its files"
    for i in range(n):
        png = folder / f"frame_{i:05d}.png"
        with Image.open(png) as im:
            im.verify()
        with Image.open(png) as im:
            im.load()
            size = im.size
        assert size == (int(rows[i]["width"]), int(rows[i]["height"]))
        if buffers:
            for k in ("_t.npy", "_id.npy"):
                assert np.load(folder / f"frame_{i:05d}{k}").shape == size[::-1]
    if n == 0:
        assert "run.json" not in names, "a run with no frame left its run.json"
    return n


def same_frames(got, ref, n=None):
    """The first ``n`` frames (all of ``ref``'s) of ``got`` are ``ref``'s: files byte for byte,
    stats rows but for timings."""
    ref_rows = rows_of(ref)
    n = len(ref_rows) if n is None else n
    got_rows = rows_of(got)
    assert len(got_rows) == n
    assert [untimed(r) for r in got_rows] == [untimed(r) for r in ref_rows[:n]]
    names = sorted(p.name for p in Path(ref).iterdir() if p.name.startswith("frame_") and int(p.name[6:11]) < n)
    assert sorted(p.name for p in Path(got).iterdir() if p.name.startswith("frame_")) == names
    for name in names:
        assert (Path(got) / name).read_bytes() == (Path(ref) / name).read_bytes(), name


def one_line(err):
    """The one line a stopped dump prints (notices of numba's compiles aside)."""
    assert "Traceback" not in err, err
    lines = [x for x in err.splitlines() if x.strip() and not x.startswith(("Compiling numba kernels", "gridrt: compil"))
             and "background compile" not in x]
    assert len(lines) == 1, err
    return lines[0]


def stop_line(err):
    """The one ``gridrt: stopped`` line of a cluster dump's stderr (other lines, from the cluster's
    start, may stand beside it), with no traceback."""
    lines = [x for x in err.splitlines() if x.startswith("gridrt: stopped")]
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


def check_stop_line(line, folder, frames, why):
    """``line`` says how many frames of ``frames`` are complete (the folder's count) and ``why``."""
    m = STOP_LINE.match(line)
    assert m, line
    n = len(rows_of(folder)) if Path(folder).exists() else int(m.group(1))
    assert (int(m.group(1)), int(m.group(2))) == (n, frames), line
    assert (f"frames 0-{n - 1} complete" if n > 1 else "frame 0 complete" if n == 1 else "no frame complete") in m.group(3)
    assert why in m.group(4), line
    return n


def dump(capsys, *args):
    """The dump in this process: (exit status, stderr)."""
    capsys.readouterr()
    rc = main(["dump", *map(str, args)])
    return rc, capsys.readouterr().err


@pytest.fixture(scope="module")
def small_ref(tmp_path_factory):
    out = tmp_path_factory.mktemp("ref") / "small"
    assert main(["dump", *SMALL, "--out", str(out)]) == 0
    assert whole_frames(out, buffers=True) == 3
    return out


class Faults:
    """``os`` as :mod:`gridrt.app.frame_out` sees it, with its writes failing: from the
    ``fail_at``-th call of os.open, write, fsync and replace on, each raises OSError(``err``)
    (a full disk stays full; the call that fills it writes half its bytes first), or, with
    ``action``, that call runs ``action()`` first and then goes on as usual."""

    def __init__(self, fail_at=None, err=errno.ENOSPC, action=None):
        self.calls = 0
        self.fail_at = fail_at
        self.err = err
        self.action = action

    def __getattr__(self, name):
        return getattr(os, name)

    def _call(self, name, *args, **kw):
        k, self.calls = self.calls, self.calls + 1
        if self.fail_at is not None and k >= self.fail_at:
            if self.action is not None:
                if k == self.fail_at:
                    self.action()
            else:
                if name == "write" and k == self.fail_at and len(args[1]) > 1:
                    return os.write(args[0], bytes(args[1])[:len(args[1]) // 2])
                raise OSError(self.err, os.strerror(self.err))
        return getattr(os, name)(*args, **kw)

    def open(self, *args, **kw):
        return self._call("open", *args, **kw)

    def write(self, *args, **kw):
        return self._call("write", *args, **kw)

    def fsync(self, *args, **kw):
        return self._call("fsync", *args, **kw)

    def replace(self, *args, **kw):
        return self._call("replace", *args, **kw)


def count_writes(monkeypatch, capsys, out, args=SMALL):
    faults = Faults()
    monkeypatch.setattr(frame_out, "os", faults)
    assert dump(capsys, *args, "--out", out)[0] == 0
    monkeypatch.setattr(frame_out, "os", os)
    return faults.calls


# ---------------------------------------------------------------------------------------------
# a full disk, a folder gone, a read-only folder
# ---------------------------------------------------------------------------------------------

def test_full_disk_at_every_write_leaves_whole_frames_and_resumes_to_the_straight_dump(
        tmp_path, monkeypatch, capsys, small_ref):
    """ENOSPC from the k-th write call on, for every k of a 3-frame dump with buffers: exit 2, one
    line naming the full disk and the frames complete, whole frames only; then --resume completes
    the dump, byte for byte the straight one."""
    total = count_writes(monkeypatch, capsys, tmp_path / "count")
    assert total >= 3 * 10, "fewer write calls than a frame's files need: the count is wrong"
    stopped_at = set()
    for k in range(total):
        out = tmp_path / f"k{k}"
        monkeypatch.setattr(frame_out, "os", Faults(fail_at=k))
        rc, err = dump(capsys, *SMALL, "--out", out)
        monkeypatch.setattr(frame_out, "os", os)
        assert rc == 2, (k, err)
        line = one_line(err)
        assert "no space left on device" in line, line
        if line.startswith("gridrt: error: cannot write to the output folder"):
            n = 0  # refused before the run began
        else:
            n = check_stop_line(line, out, 3, "no space left on device")
        assert whole_frames(out, buffers=True) == n
        stopped_at.add(n)
        rc, err = dump(capsys, *SMALL, "--out", out, "--resume")
        assert rc == 0, (k, err)
        same_frames(out, small_ref)
    assert stopped_at == {0, 1, 2}, "some frame's writes were never hit"


def test_folder_removed_at_every_write_stops_the_run(tmp_path, monkeypatch, capsys):
    """The output folder removed just before the k-th write call, for every k: exit 2 and one line,
    no traceback (what was written is gone with the folder)."""
    total = count_writes(monkeypatch, capsys, tmp_path / "count")
    for k in range(total):
        out = tmp_path / f"k{k}"
        monkeypatch.setattr(frame_out, "os", Faults(fail_at=k, action=lambda out=out: shutil.rmtree(out)))
        rc, err = dump(capsys, *SMALL, "--out", out)
        monkeypatch.setattr(frame_out, "os", os)
        assert rc == 2, (k, err)
        line = one_line(err)
        assert "no such file or directory" in line, line
        assert not out.exists()


def test_folder_renamed_mid_run_keeps_the_whole_run(tmp_path, monkeypatch, capsys, small_ref):
    """The output folder renamed during the run (at a write of each frame): the run goes on in the
    folder it opened; the renamed folder holds the straight dump, nothing lands in the old name."""
    total = count_writes(monkeypatch, capsys, tmp_path / "count")
    for k in range(3, total, total // 3):
        out, moved = tmp_path / f"k{k}", tmp_path / f"moved{k}"
        monkeypatch.setattr(frame_out, "os", Faults(fail_at=k, action=lambda out=out, moved=moved: out.rename(moved)))
        rc, err = dump(capsys, *SMALL, "--out", out)
        monkeypatch.setattr(frame_out, "os", os)
        assert rc == 0, err
        assert not out.exists()
        same_frames(moved, small_ref)
        assert whole_frames(moved, buffers=True) == 3


def test_an_error_mid_run_says_which_frames_are_complete(tmp_path, monkeypatch, capsys):
    """gridrt's own error at the third frame (injected into the pipeline): exit 2, one line with
    the two complete frames and the error; an error before any frame is the plain error line."""
    from gridrt.errors import InputError
    from gridrt.pipeline import FramePipeline

    step = FramePipeline.step

    def fails_at(k):
        def spy(self, t, *a, **kw):
            if self.frame_index == k:
                raise InputError("the injected error")
            return step(self, t, *a, **kw)
        return spy

    monkeypatch.setattr(FramePipeline, "step", fails_at(2))
    out = tmp_path / "d"
    rc, err = dump(capsys, *SMALL, "--out", out)
    assert rc == 2
    assert check_stop_line(one_line(err), out, 3, "the injected error") == 2
    assert whole_frames(out, buffers=True) == 2
    monkeypatch.setattr(FramePipeline, "step", fails_at(0))
    rc, err = dump(capsys, *SMALL, "--out", tmp_path / "e")
    assert rc == 2 and one_line(err) == "gridrt: error: the injected error"
    assert list((tmp_path / "e").iterdir()) == []


def test_read_only_folder_fails_before_rendering(tmp_path, monkeypatch, capsys):
    """A folder that refuses new files (EROFS from every os.open that creates one): one line,
    exit 2, nothing rendered (the pipeline is never built) and nothing written."""
    from gridrt.pipeline import FramePipeline

    class ReadOnly(Faults):
        def open(self, path, flags, *args, **kw):
            if flags & os.O_CREAT:
                raise OSError(errno.EROFS, os.strerror(errno.EROFS))
            return os.open(path, flags, *args, **kw)

    def no_render(*a, **kw):
        raise AssertionError("the scene was loaded for a folder that cannot be written")

    out = tmp_path / "ro"
    monkeypatch.setattr(frame_out, "os", ReadOnly())
    monkeypatch.setattr(FramePipeline, "from_spec", no_render)
    rc, err = dump(capsys, *SMALL, "--out", out)
    assert rc == 2
    assert one_line(err) == (f"gridrt: error: cannot write to the output folder {out}/: read-only file system; "
                             "give a writable --out")
    assert list(out.iterdir()) == []


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into a folder whatever its mode")
def test_read_only_folder_by_its_mode(tmp_path):
    out = tmp_path / "ro"
    out.mkdir()
    out.chmod(0o555)
    try:
        p = gridrt("dump", *SMALL, "--out", out)
        _, err = p.communicate(timeout=600)
    finally:
        out.chmod(0o755)
    assert p.returncode == 2
    assert "cannot write to the output folder" in one_line(err)


@pytest.fixture
def small_fs(tmp_path):
    """A 160 KiB tmpfs mounted at a folder (skipped where this process may not mount one)."""
    mnt = tmp_path / "fs"
    mnt.mkdir()
    try:
        r = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=160k", "tmpfs", str(mnt)], capture_output=True,
                           timeout=30)
    except (OSError, subprocess.TimeoutExpired):
        pytest.skip("mount is not available here")
    if r.returncode != 0:
        pytest.skip(f"cannot mount a small file system here: {r.stderr.decode(errors='replace').strip()}")
    try:
        yield mnt
    finally:
        subprocess.run(["umount", "-l", str(mnt)], capture_output=True, timeout=30)


def test_a_real_full_file_system(small_fs, tmp_path):
    """A dump that fills a real 160 KiB file system: exit 2 and one line naming the full disk,
    whole frames only, each with its row in stats.csv."""
    out = small_fs / "d"
    p = gridrt("dump", "--scene", "icosphere", "--count", "320", "--frames", "40", "--size", "48x32",
               "--save-buffers", "--no-progress", "--out", out)
    _, err = p.communicate(timeout=600)
    assert p.returncode == 2, err
    n = check_stop_line(one_line(err), out, 40, "no space left on device")
    assert 1 <= n < 40
    assert whole_frames(out, buffers=True) == n


@pytest.mark.slow  # (a real cluster started for it; the quick run keeps the one-process cases)
def test_a_real_full_file_system_under_a_cluster_dump(small_fs):
    """The same on a cluster (--workers 1): the client stops at the write that fails, with one
    line, and the folder holds whole frames only."""
    pytest.importorskip("distributed", reason="the cluster extra is not installed")
    out = small_fs / "d"
    p = gridrt("dump", "--scene", "icosphere", "--count", "320", "--frames", "40", "--size", "48x32",
               "--save-buffers", "--no-progress", "--workers", "1", "--chunk", "4", "--out", out)
    _, err = p.communicate(timeout=600)
    assert p.returncode == 2, err
    n = check_stop_line(stop_line(err), out, 40, "no space left on device")
    assert 1 <= n < 40
    assert whole_frames(out, buffers=True) == n


def test_a_real_read_only_file_system(small_fs):
    subprocess.run(["mount", "-o", "remount,ro", str(small_fs)], check=True, timeout=30)
    p = gridrt("dump", *SMALL, "--out", small_fs)
    _, err = p.communicate(timeout=600)
    assert p.returncode == 2
    assert one_line(err) == (f"gridrt: error: cannot write to the output folder {small_fs}/: read-only file "
                             "system; give a writable --out")


# ---------------------------------------------------------------------------------------------
# another dump in the folder: refused, --overwrite, --resume
# ---------------------------------------------------------------------------------------------

def snapshot(folder):
    return {p.name: p.read_bytes() for p in Path(folder).iterdir()}


def test_another_dump_is_refused_and_overwrite_removes_it_first(tmp_path, monkeypatch, capsys, small_ref):
    out = tmp_path / "d"
    shutil.copytree(small_ref, out)
    before = snapshot(out)
    other = ["--scene", "icosphere", "--count", "80", "--frames", "2", "--size", "24x16", "--threads", "1",
             "--no-progress"]
    rc, err = dump(capsys, *other, "--out", out)
    assert rc == 2
    assert one_line(err) == (f"gridrt: error: {out}/ already holds another dump (3 frames, stats.csv); give "
                             "--overwrite to replace it, --resume to continue it, or another --out")
    assert snapshot(out) == before
    # --overwrite: when the first frame renders, the old frames, buffers and stats are gone already
    from gridrt.pipeline import FramePipeline

    seen = []
    step = FramePipeline.step

    def spy(self, *a, **kw):
        seen.append(sorted(p.name for p in out.iterdir()))
        return step(self, *a, **kw)

    monkeypatch.setattr(FramePipeline, "step", spy)
    rc, err = dump(capsys, *other, "--out", out, "--overwrite")
    assert rc == 0, err
    assert seen[0] == ["run.json", "stats.csv"]
    assert whole_frames(out) == 2 and {p.name for p in out.iterdir()} == {
        "frame_00000.png", "frame_00001.png", "stats.csv", "run.json"}
    assert rows_of(out)[0]["width"] == "24"


def test_a_cluster_dump_refuses_another_dump_before_its_cluster_starts(tmp_path, monkeypatch, capsys, small_ref):
    from gridrt.app.cluster import dump as dump_cluster

    def no_cluster(*a, **kw):
        raise AssertionError("a cluster was started for a folder that is refused")

    monkeypatch.setattr(dump_cluster, "Cluster", no_cluster)
    out = tmp_path / "d"
    shutil.copytree(small_ref, out)
    before = snapshot(out)
    rc, err = dump(capsys, *SMALL, "--workers", 1, "--out", out)
    assert rc == 2
    assert "already holds another dump (3 frames, stats.csv); give --overwrite" in one_line(err)
    assert snapshot(out) == before


def test_overwrite_and_resume_exclude_each_other(tmp_path, capsys):
    with pytest.raises(SystemExit) as e:
        main(["dump", *SMALL, "--out", str(tmp_path), "--overwrite", "--resume"])
    assert e.value.code == 2
    assert "not allowed with argument" in capsys.readouterr().err


def test_resume_with_other_settings_is_refused(tmp_path, capsys, small_ref):
    out = tmp_path / "d"
    shutil.copytree(small_ref, out)
    before = snapshot(out)
    rc, err = dump(capsys, *[a if a != "32x24" else "32x25" for a in SMALL], "--out", out, "--resume")
    assert rc == 2
    line = one_line(err)
    assert line.startswith(f"gridrt: error: --resume: the dump in {out}/ was made with other settings (view.size: "
                           "[32, 24] there, [32, 25] now)"), line
    assert snapshot(out) == before


@pytest.mark.slow  # (a real cluster started for it; the quick run keeps the one-process cases)
def test_one_process_and_cluster_dumps_resume_each_others_folders(tmp_path, capsys):
    """A one-process dump of 2 frames resumed on a cluster (--workers 1) to 4 frames, and that
    folder resumed in one process to 6: the folder is the straight one-process dump of 6 frames,
    byte for byte (both kinds of dump record and compare the same run.json)."""
    pytest.importorskip("distributed", reason="the cluster extra is not installed")
    args = [x for x in SMALL if x not in ("--frames", "3")]
    out, ref = tmp_path / "d", tmp_path / "ref"
    assert dump(capsys, *args, "--frames", 2, "--out", out)[0] == 0
    r = subprocess.run([sys.executable, "-m", "gridrt", "dump", *args, "--frames", "4", "--workers", "1",
                        "--resume", "--out", str(out)], cwd=REPO, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    assert "frames 2-3, after the 2 already there" in r.stdout, r.stdout
    rc, err = dump(capsys, *args, "--frames", 6, "--out", out, "--resume")
    assert rc == 0, err
    assert dump(capsys, *args, "--frames", 6, "--out", ref)[0] == 0
    same_frames(out, ref)
    assert whole_frames(out, buffers=True) == 6


def test_resume_of_a_complete_dump_does_nothing(tmp_path, capsys, small_ref):
    out = tmp_path / "d"
    shutil.copytree(small_ref, out)
    before = snapshot(out)
    rc, err = dump(capsys, *SMALL, "--out", out, "--resume")
    assert rc == 0
    assert "nothing to do" in err and snapshot(out) == before


def moving_frames(folder, n=16):
    """A folder of OBJ frames whose object travels 1.5 times its size per frame: the pipeline
    moves its frame of reference again and again."""
    from gridrt.scene import icosphere_mesh

    ico = icosphere_mesh(80)
    folder.mkdir()
    for k in range(n + 1):
        v = ico.vertices64 + np.array([3.0 * k, 0.2 * k, 0.0])
        with open(folder / f"f{k:03d}.obj", "w") as fh:
            fh.writelines(f"v {float(x)!r} {float(y)!r} {float(z)!r}\n" for x, y, z in v)
            fh.writelines(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in ico.faces)
    return folder


def test_resume_is_the_straight_dump_byte_for_byte(tmp_path, capsys):
    """A dump stopped after 7 of 16 frames, with an incomplete eighth frame behind it (its PNG
    without a row, half a row, a temporary file), resumed: the incomplete frame is dropped and
    the result is the straight dump, byte for byte, although the scene moves the pipeline's frame
    of reference before and after the resumed frame."""
    scene = moving_frames(tmp_path / "frames")
    args = ["--scene", scene, "--size", "120x30", "--eye", "22.5,2,15", "--target", "22.5,2,0", "--save-buffers",
            "--threads", "1", "--no-progress"]
    ref, out = tmp_path / "ref", tmp_path / "d"
    assert dump(capsys, *args, "--frames", 16, "--out", ref)[0] == 0
    assert dump(capsys, *args, "--frames", 7, "--out", out)[0] == 0
    shutil.copy(ref / "frame_00007.png", out / "frame_00007.png")
    (out / ".frame_00007_t.npy.part").write_bytes(b"\x93NUMPY")
    with open(out / "stats.csv", "ab") as fh:
        fh.write(b"7,0.23")
    rc, err = dump(capsys, *args, "--frames", 16, "--out", out, "--resume")
    assert rc == 0, err
    same_frames(out, ref)
    assert whole_frames(out, buffers=True) == 16
    # the scene really moves the frame of reference, before and after frame 7
    from gridrt.config import GridParams, RenderParams
    from gridrt.pipeline import FramePipeline
    from gridrt.scene import make_scene

    pipe = FramePipeline(make_scene(str(scene)), GridParams(threads=1), RenderParams(8, 8, threads=1))
    origins = [pipe.step(i / 30.0).origin.copy() for i in range(16)]
    moves = [i for i in range(1, 16) if not np.array_equal(origins[i], origins[i - 1])]
    assert any(i < 7 for i in moves) and any(i > 7 for i in moves), moves
    hits = [np.load(ref / f"frame_{i:05d}_id.npy") for i in (0, 15)]
    assert all((h >= 0).sum() > 10 for h in hits), "the object left the view: the test would show nothing"


# ---------------------------------------------------------------------------------------------
# signals
# ---------------------------------------------------------------------------------------------

def wait_for(path, proc, timeout=300):
    deadline = time.time() + timeout
    while not Path(path).exists():
        assert proc.poll() is None, proc.communicate()[1]
        assert time.time() < deadline, f"no {path} in {timeout} s"
        time.sleep(0.01)


def signal_after(proc, path, delay, sig, group=False, before=lambda: None):
    """Send ``sig`` to ``proc`` (its process group with ``group``, as a terminal sends Ctrl-C)
    ``delay`` s after ``path`` appears (and ``before()``); its stderr once it ended."""
    try:
        wait_for(path, proc)
        time.sleep(delay)
        before()
        if group:
            os.killpg(proc.pid, sig)
        else:
            proc.send_signal(sig)
        return proc.communicate(timeout=300)[1]
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)


@pytest.mark.parametrize("seed", [1, pytest.param(2, marks=pytest.mark.slow)])  # (seed 2: two more moments, slow run)
@pytest.mark.parametrize("sig, code, why", [
    (signal.SIGINT, 130, "interrupted (SIGINT)"),
    (signal.SIGTERM, 143, "terminated (SIGTERM)"),
])
def test_signal_at_a_random_moment_of_a_dump(tmp_path, sig, code, why, seed):
    """SIGINT (to the process group, as a terminal sends Ctrl-C) or SIGTERM (to the process) at a
    seeded random moment after the dump opened its folder (while the scene loads or frames are
    written): the exit status of the signal, one line, whole frames only."""
    delay = random.Random(seed).uniform(0.0, 2.0)
    out = tmp_path / "d"
    p = gridrt("dump", "--scene", "marbles", "--count", "400", "--frames", "3000", "--size", "64x48",
               "--save-buffers", "--no-progress", "--out", out, start_new_session=True)
    err = signal_after(p, out, delay, sig, group=sig == signal.SIGINT)
    assert p.returncode == code, err
    n = check_stop_line(one_line(err), out, 3000, why)
    assert n < 3000, "the dump ended before the signal: make it longer"
    assert whole_frames(out, buffers=True) == n


def test_sigint_during_a_cold_compile_ends_the_dump_at_once(tmp_path):
    """Ctrl-C while numba compiles the first frame's kernels (an empty numba cache): the dump ends
    with 130 and its one line (no frame, so no run.json and no stats.csv left), without waiting
    for the compile and without a traceback from inside numba."""
    out = tmp_path / "d"
    p = gridrt("dump", *SMALL, "--out", out, env={**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "cache")},
               start_new_session=True)
    err = signal_after(p, out, random.Random(4).uniform(0.5, 1.5), signal.SIGINT, group=True)
    assert p.returncode == 130, err
    n = check_stop_line(one_line(err), out, 3, "interrupted (SIGINT)")
    assert whole_frames(out, buffers=True) == n


@pytest.mark.slow  # (a fault on a real cluster; the quick run keeps the one-process SIGTERM)
def test_sigterm_stops_a_cluster_dump_with_whole_frames_and_it_resumes(tmp_path):
    """SIGTERM to a cluster dump (--workers 1) once frames land: exit 143, one line, the workers
    gone, whole frames only; resumed on the cluster for five frames more, the folder is the
    one-process dump's, byte for byte."""
    pytest.importorskip("distributed", reason="the cluster extra is not installed")
    import psutil

    args = ["--scene", "marbles", "--count", "400", "--size", "64x48", "--save-buffers", "--no-progress"]
    out = tmp_path / "d"
    p = gridrt("dump", *args, "--frames", "2000", "--workers", "1", "--chunk", "4", "--out", out,
               start_new_session=True)
    children = []
    err = signal_after(p, out / "frame_00002.png", random.Random(3).uniform(0.0, 0.5), signal.SIGTERM,
                       before=lambda: children.extend(psutil.Process(p.pid).children(recursive=True)))
    assert p.returncode == 143, err
    n = check_stop_line(stop_line(err), out, 2000, "terminated (SIGTERM)")
    assert 3 <= n < 2000
    assert whole_frames(out, buffers=True) == n
    _, alive = psutil.wait_procs(children, timeout=30)
    assert not alive, f"processes left running: {alive}"
    more = ["--frames", str(n + 5)]
    r = subprocess.run([sys.executable, "-m", "gridrt", "dump", *args, *more, "--workers", "1", "--chunk", "2",
                        "--resume", "--out", str(out)], cwd=REPO, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    ref = tmp_path / "ref"
    r = subprocess.run([sys.executable, "-m", "gridrt", "dump", *args, *more, "--out", str(ref)],
                       cwd=REPO, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    same_frames(out, ref)
    assert whole_frames(out, buffers=True) == n + 5
