"""Quake II MD2 models: a keyframe vertex sequence, interpolated between frames.

Layout (id Software, Quake II, 1997; little-endian): a 68-byte header of 17 int32 (``"IDP2"``,
version 8, skin size, frame size, counts of skins, vertices, texture coordinates, triangles,
GL commands and frames, then the offsets of those blocks and of the end of file); triangles are
6 uint16 (3 vertex and 3 texture-coordinate indices); each frame is ``scale`` (3 float32),
``translate`` (3 float32), a 16-byte name and one 4-byte record per vertex (3 uint8 packed
coordinates and a normal index): ``position = scale * packed + translate``.

MD2 is z-up; gridrt is y-up, so positions are mapped ``(x, y, z) -> (x, z, -y)`` (a rotation,
so the winding is kept).  Frames play at ``fps`` (Quake II's 10 by default) and loop.  Frame names
such as ``run1 .. run6`` form clips; ``clip="run"`` (or its index in :attr:`Md2Model.clips`)
plays one of them.
"""

import os
import re
import struct
from pathlib import Path

import numpy as np

from ..errors import InputError, SceneFileError
from .frames import KeyframeMesh, check_fps

__all__ = ["Md2Model", "read_md2", "MD2_TO_GRIDRT"]

_MAGIC = b"IDP2"
_HEADER = struct.Struct("<4s16i")
_LIMIT = 1 << 20

#: Axis change applied to MD2 positions: gridrt = MD2_TO_GRIDRT @ md2.
MD2_TO_GRIDRT = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])


def read_md2(path):
    """Decode an MD2 file: ``(frames (K, V, 3) float64 in MD2 axes, faces (F, 3) int64, names)``.

    Raises SceneFileError naming the file for a wrong magic or version, counts or offsets outside
    the file, truncated blocks or vertex indices out of range.
    """
    p = Path(path)
    try:
        raw = p.read_bytes()
    except PermissionError as e:
        raise SceneFileError(p, "permission denied: the file is not readable") from e
    except OSError as e:
        raise SceneFileError(p, f"cannot read the file ({e.strerror or e})") from e
    if not raw:
        raise SceneFileError(p, "file is empty (0 bytes)")
    if len(raw) < _HEADER.size:
        raise SceneFileError(p, f"truncated MD2 file: {len(raw)} bytes, the header alone needs {_HEADER.size}")
    h = _HEADER.unpack_from(raw, 0)
    magic, version = h[0], h[1]
    (_, _, framesize, _, n_verts, _, n_tris, _, n_frames,
     _, _, ofs_tris, ofs_frames, _, ofs_end) = h[2:]
    if magic != _MAGIC:
        raise SceneFileError(p, f"not an MD2 file: magic {magic!r}, expected {_MAGIC!r}")
    if version != 8:
        raise SceneFileError(p, f"unsupported MD2 version {version}, expected 8")
    for what, n in (("vertices", n_verts), ("triangles", n_tris), ("frames", n_frames)):
        if not 1 <= n <= _LIMIT:
            raise SceneFileError(p, f"malformed MD2 header: {n} {what}")
    if framesize < 40 + 4 * n_verts:
        raise SceneFileError(p, f"malformed MD2 header: frame size {framesize} is too small for {n_verts} vertices")
    for what, ofs, size in (("triangles", ofs_tris, 12 * n_tris), ("frames", ofs_frames, framesize * n_frames)):
        if ofs < _HEADER.size or ofs + size > len(raw):
            raise SceneFileError(
                p, f"truncated or malformed MD2 file: the {what} block (bytes {ofs}..{ofs + size}) lies outside "
                   f"the file's {len(raw)} bytes")
    if ofs_end > len(raw):
        raise SceneFileError(p, f"truncated MD2 file: the header says {ofs_end} bytes, the file has {len(raw)}")
    tris = np.frombuffer(raw, dtype="<u2", count=6 * n_tris, offset=ofs_tris).reshape(n_tris, 6)
    faces = tris[:, :3].astype(np.int64)
    if faces.max() >= n_verts:
        bad = int(np.argmax(faces.max(axis=1)))
        raise SceneFileError(p, f"triangle {bad} has vertex index {int(faces[bad].max())}, but frames have "
                                f"{n_verts} vertices")
    frames = np.empty((n_frames, n_verts, 3))
    names = []
    rec = np.dtype([("scale", "<f4", 3), ("translate", "<f4", 3), ("name", "S16")])
    for k in range(n_frames):
        o = ofs_frames + k * framesize
        head = np.frombuffer(raw, dtype=rec, count=1, offset=o)[0]
        packed = np.frombuffer(raw, dtype=np.uint8, count=4 * n_verts, offset=o + 40).reshape(n_verts, 4)[:, :3]
        scale = head["scale"].astype(np.float64)
        shift = head["translate"].astype(np.float64)
        if not (np.isfinite(scale).all() and np.isfinite(shift).all()):
            raise SceneFileError(p, f"frame {k} has a non-finite scale or translation")
        frames[k] = packed * scale + shift
        names.append(head["name"].split(b"\0", 1)[0].decode("latin-1"))
    return frames, faces, names


def _clip_name(frame_name):
    return re.sub(r"\d+$", "", frame_name) or frame_name


class Md2Model(KeyframeMesh):
    """An MD2 model as an animation: frames interpolated linearly at ``fps``, looping.

    Parameters
    ----------
    path : str or os.PathLike
    clip : str or int, optional
        A frame-name prefix (``"run"`` for ``run1 .. run6``) or its index in :attr:`clips`;
        default: all frames.
    fps : float
        Frames per second (Quake II: 10).

    Attributes
    ----------
    clips : list of str
        Clip names in file order (frame names without their trailing numbers).
    clip : str or None
    first_frame : int
        Index in the file of the clip's first frame (frame k of the clip is file frame
        ``first_frame + k``).
    """

    def __init__(self, path, clip=None, fps=10.0):
        if not isinstance(path, (str, os.PathLike)):
            raise InputError(f"MD2 path must be a str or path-like object, got {type(path).__name__}")
        p = Path(path)
        if not p.exists():
            raise SceneFileError(p, "file not found")
        if p.is_dir():
            raise SceneFileError(p, "is a directory, not an MD2 file")
        fps = check_fps(fps)
        frames, faces, names = read_md2(p)
        groups = []
        for k, n in enumerate(names):
            c = _clip_name(n)
            if not groups or groups[-1][0] != c:
                groups.append((c, []))
            groups[-1][1].append(k)
        self.clips = [g[0] for g in groups]
        sel = list(range(len(names)))
        self.clip = None
        if clip is not None:
            listing = ", ".join(f"{i}: {c!r}" for i, c in enumerate(self.clips))
            if isinstance(clip, (bool, np.bool_)):
                raise InputError(f"clip must be a clip name or index, got {clip!r}")
            if isinstance(clip, (int, np.integer)):
                if not 0 <= clip < len(groups):
                    raise InputError(f"clip index {clip} out of range; {p.name} has clips {listing}")
                self.clip, sel = groups[clip]
            elif isinstance(clip, str):
                match = [g for g in groups if g[0] == clip]
                if not match:
                    raise InputError(f"no clip named {clip!r} in {p.name}; clips: {listing}")
                self.clip, sel = match[0]
            else:
                raise InputError(f"clip must be a clip name or index, got {clip!r}")
        self.first_frame = sel[0]
        self.path = p
        moved = frames[sel] @ MD2_TO_GRIDRT.T
        name = p.stem if self.clip is None else f"{p.stem} ({self.clip})"
        try:
            super().__init__(moved, faces, fps, wrap=True, name=name, frame_names=[names[k] for k in sel])
        except InputError as e:
            raise SceneFileError(p, str(e)) from e
