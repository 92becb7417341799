"""Vertex keyframe animation: MD2 models and folders of OBJ/PLY/OFF/STL frames, interpolated
linearly (:data:`FRAME_EXTENSIONS`).

:class:`KeyframeMesh` holds K frames of the same connectivity, (K, V, 3) float32 vertices and
(F, 3) faces, shown at ``fps`` frames per second; between frames the vertices are interpolated
linearly.  :func:`load_frame_folder` reads a folder of meshes in the style of the Utah 3D
Animation Repository (``f000.obj, f001.obj, ...``: one file per frame, same faces in every file).
"""

import math
import os
import re
from numbers import Real
from pathlib import Path

import numpy as np

from ..arrays import TRI_DTYPE, as_mesh, as_origin, storage_centre
from ..errors import InputError, SceneFileError
from .animation import Animation, as_static_mask, gather_unchecked
from .files import SceneFolder
from .kernels import lerp_rows
from .loader import load_mesh
from .surface import Surface

__all__ = ["KeyframeMesh", "FRAME_EXTENSIONS", "load_frame_folder", "frame_files"]

#: Mesh formats accepted as frames of a folder sequence.
FRAME_EXTENSIONS = (".obj", ".ply", ".off", ".stl")


def check_fps(fps):
    if isinstance(fps, (bool, np.bool_)) or not isinstance(fps, (Real, np.integer, np.floating)):
        raise InputError(f"fps must be a positive number of frames per second, got {fps!r}")
    fps = float(fps)
    if not (math.isfinite(fps) and fps > 0):
        raise InputError(f"fps must be positive and finite, got {fps}")
    return fps


class KeyframeMesh(Animation):
    """A mesh whose vertices are keyed per frame and interpolated linearly between frames.

    Parameters
    ----------
    frames : ndarray
        (K, V, 3) vertex positions of K >= 1 frames (validated; copied to float32).
    faces : ndarray
        (F, 3) integer indices into the V vertices, shared by all frames.
    fps : float
        Frames per second: frame k is shown at ``t = k / fps``.
    wrap : bool
        True: the sequence loops smoothly, interpolating from the last frame back to the first
        (``duration = K / fps``, as MD2 animation cycles do).  False: ``duration = (K - 1) / fps``
        and the sequence restarts at frame 0.
    name : str

    Attributes
    ----------
    n_frames : int
    fps : float
    time_range : tuple
        ``(0, duration)``.
    static_mask : ndarray
        (F,) bool, True for triangles whose three vertices are the same in every frame.
    frame_names : list of str
        One name per frame (the MD2 frame names or the file names).
    """

    def __init__(self, frames, faces, fps, wrap=False, name="keyframes", frame_names=None):
        fps = check_fps(fps)
        fr = np.asarray(frames)
        if fr.ndim != 3 or fr.shape[2] != 3 or fr.shape[0] < 1:
            raise InputError(f"keyframes must have shape (K, V, 3) with K >= 1, got {fr.shape}")
        _, f = as_mesh(fr[0], faces, what=f"{name} frame 0")
        if not np.issubdtype(fr.dtype, np.number) or np.issubdtype(fr.dtype, np.complexfloating):
            raise InputError(f"{name}: keyframes must be real numbers, got dtype {fr.dtype}")
        finite = np.isfinite(fr).all(axis=(1, 2))
        if not finite.all():
            raise InputError(f"{name}: frame {int(np.argmin(finite))} contains NaN or infinity")
        if np.abs(fr).max() > 1e30:
            raise InputError(f"{name}: vertex coordinates beyond 1e30, too large for float32")
        # float32 storage of each frame relative to a float64 centre of its own when it lies far from
        # the origin (a mesh that travels far keeps its detail in every frame)
        self._centres = np.stack([storage_centre(f_k) for f_k in fr])
        self._frames = np.ascontiguousarray(fr.astype(np.float64) - self._centres[:, None, :]
                                            if self._centres.any() else fr, dtype=TRI_DTYPE)
        self._faces = f
        self.fps = fps
        self.wrap = bool(wrap)
        self.name = name
        self.n_frames = int(fr.shape[0])
        self.frame_names = list(frame_names) if frame_names is not None else [str(k) for k in range(self.n_frames)]
        self.n_triangles = int(len(f))
        span = (self.n_frames if self.wrap else self.n_frames - 1) / fps
        moving_v = np.ptp(fr, axis=0).max(axis=1) > 0
        tri_static = ~moving_v[self._faces].any(axis=1)
        self.static = self.n_frames == 1 or bool(tri_static.all())
        self.duration = None if (self.static or span <= 0) else span
        self.time_range = (0.0, span) if span > 0 else None
        self.static_mask = as_static_mask(tri_static, self.n_triangles)
        self._verts = np.zeros(self._frames.shape[1:], dtype=TRI_DTYPE)

    def frame_vertices(self, k, origin=None):
        """A copy of frame k's (V, 3) float32 vertices (in the frame of ``origin``, as
        :meth:`triangles_at`)."""
        shift = self._centres[k] - as_origin(origin)
        if not shift.any():
            return self._frames[k].copy()
        return (self._frames[k] + shift).astype(TRI_DTYPE)

    @property
    def faces(self):
        """(F, 3) int32 faces (read-only view)."""
        f = self._faces.view()
        f.setflags(write=False)
        return f

    def frame_position(self, t):
        """(k0, k1, s): the vertices at time ``t`` are ``(1 - s) * frame[k0] + s * frame[k1]``."""
        if self.duration is None:
            return 0, 0, 0.0
        u = (t % self.duration) * self.fps
        r = round(u)
        if abs(u - r) <= 1e-9 * max(1.0, abs(u)):
            u = float(r)
        k0 = min(int(math.floor(u)), self.n_frames - 1)
        s = u - k0
        k1 = k0 + 1
        if k1 >= self.n_frames:
            k1 = 0 if self.wrap else self.n_frames - 1
            if not self.wrap:
                s = 0.0
        return k0, k1, float(min(max(s, 0.0), 1.0))

    def _fill(self, t, out, origin):
        k0, k1, s = self.frame_position(t)
        shift = (1.0 - s) * self._centres[k0] + s * self._centres[k1] - origin
        lerp_rows(self._frames[k0], self._frames[k1], s, self._verts, shift)
        gather_unchecked(self._verts, self._faces, out)


def _natural_key(p):
    return [int(s) if s.isdigit() else s for s in re.split(r"(\d+)", p.name)]


def frame_files(folder):
    """The frame files of a folder sequence, in natural order (f2 before f10).

    Every file with one of :data:`FRAME_EXTENSIONS` counts; they must share one extension.
    Raises SceneFileError when the folder holds none or mixes formats.
    """
    folder = Path(folder)
    files = sorted((p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in FRAME_EXTENSIONS),
                   key=_natural_key)
    if not files:
        raise SceneFileError(folder, f"folder holds no frame files ({', '.join(FRAME_EXTENSIONS)})")
    exts = {p.suffix.lower() for p in files}
    if len(exts) > 1:
        raise SceneFileError(folder, f"folder mixes frame formats {sorted(exts)}; keep one per sequence")
    return files


def load_frame_folder(folder, fps=30.0, *, allow_outside=False):
    """A :class:`KeyframeMesh` from a folder of frame meshes (``f000.obj``, ``f001.obj``, ...).

    Every frame must have the vertex count and faces of the first; frames are ``1 / fps`` seconds
    apart and the sequence does not wrap.  The scene's surface is the first frame's (materials,
    textures, uv, colours) without its normals, which would not follow the moving vertices (the
    geometric normals are used); the other frames' looks are not read.  Raises SceneFileError
    naming the offending frame file.

    Every file read (the frames, the first frame's material libraries and textures) must resolve
    inside the folder, symlinks followed (:mod:`gridrt.scene.files`): a frame that is a symlink
    leading out is a SceneFileError, a material or texture outside is left out with a warning,
    unless ``allow_outside`` trusts them.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise SceneFileError(folder, "not a folder of frames")
    fps = check_fps(fps)
    files = frame_files(folder)
    scene = SceneFolder(folder, allow_outside, folder=True)
    for p in files:
        scene.check(p, "frame file", p.name, folder)
    first = load_mesh(files[0], folder=scene)
    frames = np.empty((len(files),) + first.vertices.shape, dtype=np.float64)
    frames[0] = first.vertices64
    for k, p in enumerate(files[1:], 1):
        m = load_mesh(p, looks=False, folder=scene)
        if m.vertices.shape != first.vertices.shape or not np.array_equal(m.faces, first.faces):
            raise SceneFileError(
                p, f"frame has {m.n_vertices} vertices and {m.n_triangles} faces but {files[0].name} has "
                   f"{first.n_vertices} and {first.n_triangles} (or different faces): all frames must share "
                   "one connectivity")
        frames[k] = m.vertices64
    scene = KeyframeMesh(frames, first.faces, fps, wrap=False, name=folder.name,
                         frame_names=[p.name for p in files])
    s = first.surface
    if s is not None and (s.normals is None or s.uv is not None or s.colors is not None or s.n_materials > 1
                          or s.textured):
        scene.surface = Surface(s.material, s.diffuse, s.ambient, s.texture, s.textures, s.uv, s.colors, None)
    return scene


def is_frame_folder(path):
    """True when ``path`` is a directory holding at least one frame file."""
    p = Path(path) if isinstance(path, (str, os.PathLike)) else None
    return p is not None and p.is_dir() and any(
        q.is_file() and q.suffix.lower() in FRAME_EXTENSIONS for q in p.iterdir())
