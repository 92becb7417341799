"""The native Embree harness's folder format: a mesh, its animated frames as vertex sets, a camera and
its rays, and as many random rays, all float32, as ``../shared/tools/embree-native`` reads them."""

import json
from pathlib import Path

import numpy as np

from gridrt.errors import InputError

from ..cli import option_help

from .output import out_dir

#: the harness's untimed dynamic frames before the timed ones
NATIVE_WARMUP = 2


def write_ply(path, V):
    """A binary PLY of the unshared vertices V (3F, 3): triangle f is vertices 3f, 3f+1, 3f+2."""
    F = len(V) // 3
    head = (f"ply\nformat binary_little_endian 1.0\nelement vertex {len(V)}\nproperty float x\nproperty float y\n"
            f"property float z\nelement face {F}\nproperty list uchar int vertex_indices\nend_header\n")
    rec = np.zeros(F, dtype=[("n", "u1"), ("i", "<i4", (3,))])
    rec["n"] = 3
    rec["i"] = np.arange(3 * F, dtype=np.int32).reshape(F, 3)
    with open(path, "wb") as fh:
        fh.write(head.encode("ascii"))
        fh.write(np.ascontiguousarray(V, "<f4").tobytes())
        fh.write(rec.tobytes())


def add_export_args(p, default):
    """--export DIR (``default``: what the command does without it, in words) and --export-only."""
    p.add_argument("--export", default=None, metavar="DIR", help=option_help("--export", default))
    p.add_argument("--export-only", action="store_true", help=option_help("--export-only"))


def export_arg(a):
    """The folder --export names, made where missing (a clear error where it cannot be), or None
    without it; --export-only without --export is an error."""
    if a.export_only and not a.export:
        raise InputError("--export-only writes the folders into --export DIR: give it")
    return out_dir(a.export, "the --export folder") if a.export else None


def export_folder(folder, label, frames, cam, size, o32, d32, ro32, rd32, dt):
    """Write one scene in the harness's folder format: ``frames`` (NF, F, 3, 3) float32 triangles (frame
    0 the mesh at rest; the harness warms up on frames 0 and 1 and times the rest), the camera ``cam``
    and its size x size rays (o32, d32), the random rays (ro32, rd32)."""
    try:
        return _write_folder(folder, label, frames, cam, size, o32, d32, ro32, rd32, dt)
    except OSError as e:
        raise InputError(f"cannot write the harness folder {folder}: {e.strerror}") from None


def _write_folder(folder, label, frames, cam, size, o32, d32, ro32, rd32, dt):
    """The folder's files (:func:`export_folder`)."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    nf, F = frames.shape[:2]
    V = np.ascontiguousarray(frames.reshape(nf, 3 * F, 3), np.float32)
    save = lambda name, x: np.save(folder / name, np.ascontiguousarray(x))
    save("vertices.npy", V[0])
    save("faces.npy", np.arange(3 * F, dtype=np.int32).reshape(F, 3))
    save("frames.npy", V)
    save("primary_origins.npy", np.asarray(o32, np.float32))
    save("primary_directions.npy", np.asarray(d32, np.float32))
    save("incoherent_origins.npy", np.asarray(ro32, np.float32))
    save("incoherent_directions.npy", np.asarray(rd32, np.float32))
    write_ply(folder / "mesh.ply", V[0])
    vec = lambda v: ",".join(repr(float(x)) for x in v)
    camera = dict(eye=list(map(float, cam.eye)), target=list(map(float, cam.target)), up=list(map(float, cam.up)),
                  fov=float(cam.fov), res=size,
                  gridrt_flags=f"--eye={vec(cam.eye)} --target={vec(cam.target)} --up={vec(cam.up)} "
                               f"--fov={float(cam.fov)!r} --size={size}x{size}")
    (folder / "camera.json").write_text(json.dumps(camera, indent=1))
    lo, hi = V[0].min(axis=0), V[0].max(axis=0)
    meta = dict(mesh=label, vertices=3 * F, triangles=F, res=size, incoherent=len(ro32), bbox_lo=lo.tolist(),
                bbox_hi=hi.tolist(), deformation=f"{label}: the scene's own animation", dt=dt,
                frame_t=[dt * i for i in range(nf)], warmup_frames=NATIVE_WARMUP, timed_frames=nf - NATIVE_WARMUP)
    (folder / "meta.json").write_text(json.dumps(meta, indent=1))
    return folder


def folder_name(label):
    return "".join(c if c.isalnum() or c in "-_." else "_" for c in label)
