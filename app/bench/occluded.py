"""Native Embree 3 (C++) casting given segments for occlusion: the native columns of the shadow-ray
table (scripts/shadow_rays.py).

occluded.cpp, beside this module, reads a folder of meshes and batches of segments (its head
comment gives the format, the modes and the timing), casts every batch against its mesh with
``rtcOccluded1``, ``rtcOccluded16`` packets or ``rtcOccluded1M`` streams on N pinned threads, and
prints one ``RESULT`` line of timings a mode, as the harness of gridrt.app.bench.native does
(:func:`gridrt.app.bench.native.run_harness` runs both).  :func:`build` compiles it with g++
against Debian's ``libembree-dev`` (``-O3 -march=native``), :func:`write_folder` writes the
folder and :func:`cast` runs it."""

import os
import shutil
import subprocess
from pathlib import Path

import numpy as np

from gridrt.errors import InputError

from .native import run_harness
from .sides import MissingPeer

SOURCE = Path(__file__).with_name("occluded.cpp")
#: where build() puts the binary unless told otherwise
DEFAULT_BIN = Path(os.environ.get("TMPDIR") or "/tmp") / "gridrt-native" / "embree_occluded"
HEADER = Path("/usr/include/embree3/rtcore.h")
MODES = ("1", "p16", "1M")
INSTALL_HINT = "install Embree 3's headers and a C++ compiler (Debian: apt-get install libembree-dev g++)"


def build(binary=DEFAULT_BIN):
    """The path of the compiled tool, compiling occluded.cpp when the binary is missing or older than
    the source; MissingPeer naming what to install when the compiler or Embree's header is absent,
    InputError with the compiler's last line when it fails."""
    binary = Path(binary)
    if binary.is_file() and binary.stat().st_mtime >= SOURCE.stat().st_mtime:
        return binary
    cxx = shutil.which("g++")
    if cxx is None or not HEADER.is_file():
        raise MissingPeer(f"native Embree is not measured: no {'g++' if cxx is None else HEADER}; {INSTALL_HINT}")
    binary.parent.mkdir(parents=True, exist_ok=True)
    tmp = binary.with_name(binary.name + f".{os.getpid()}.tmp")
    p = subprocess.run([cxx, "-O3", "-march=native", "-std=c++17", str(SOURCE), "-o", str(tmp), "-lembree3",
                        "-lpthread"], capture_output=True, text=True)
    if p.returncode != 0:
        last = (p.stderr.strip().splitlines() or ["(no output)"])[-1]
        raise InputError(f"compiling {SOURCE.name} failed (exit {p.returncode}): {last}")
    os.replace(tmp, binary)   # (whole: a concurrent build never runs a half-written binary)
    return binary


def write_folder(folder, meshes, batches):
    """The tool's folder: ``meshes`` a list of (F, 3, 3) triangle arrays, ``batches`` a list of
    (mesh index, origins (N, 3), directions (N, 3)), segments o + t d for t in [0, 1]; everything
    written as float32."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    for m, tris in enumerate(meshes):
        t = np.ascontiguousarray(tris, "<f4")
        if t.ndim != 3 or t.shape[1:] != (3, 3):
            raise InputError(f"mesh {m}: triangles must be (F, 3, 3), got {t.shape}")
        np.save(folder / f"mesh_{m}.npy", t)
    which = []
    for b, (m, o, d) in enumerate(batches):
        if not 0 <= m < len(meshes):
            raise InputError(f"batch {b}: no mesh {m}")
        o, d = np.ascontiguousarray(o, "<f4"), np.ascontiguousarray(d, "<f4")
        if o.ndim != 2 or o.shape[1:] != (3,) or d.shape != o.shape:
            raise InputError(f"batch {b}: origins and directions must both be (N, 3), got {o.shape} and {d.shape}")
        np.save(folder / f"batch_{b}_origins.npy", o)
        np.save(folder / f"batch_{b}_directions.npy", d)
        which.append(m)
    np.save(folder / "batch_mesh.npy", np.asarray(which, "<i4"))
    return folder


def cast(binary, folder, threads, reps, warmup, modes=MODES, robust=False, verdicts=False):
    """Run the tool on ``folder``: {mode: its RESULT dict (ms, ms_min, ms_max of a round, segments,
    batches, blocked: how many)}, each with ``"verdicts"`` (a bool array over every batch's
    segments, the last round's) when ``verdicts``."""
    args = [folder, threads, reps, warmup, "--modes", ",".join(modes)]
    args += ["--robust"] * bool(robust) + ["--verdicts"] * bool(verdicts)
    out = {}
    for r in run_harness(binary, args):   # (the same RESULT lines and errors as the harness's)
        if verdicts:
            r["verdicts"] = np.load(Path(folder) / f"verdicts_{r['mode']}.npy").astype(bool)
        out[r["mode"]] = r
    return out
