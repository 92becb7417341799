"""Quake II MD2 models: a keyframe vertex sequence, interpolated between frames.

Layout (id Software, Quake II, 1997; little-endian): a 68-byte header of 17 int32 (``"IDP2"``,
version 8, skin size, frame size, counts of skins, vertices, texture coordinates, triangles,
GL commands and frames, then the offsets of those blocks and of the end of file); triangles are
6 uint16 (3 vertex and 3 texture-coordinate indices); each frame is ``scale`` (3 float32),
``translate`` (3 float32), a 16-byte name and one 4-byte record per vertex (3 uint8 packed
coordinates and a normal index): ``position = scale * packed + translate``.

MD2 is z-up; gridrt is y-up, so positions are mapped ``(x, y, z) -> (x, z, -y)`` (a rotation,
so the winding is kept), and so are the normals.

Looks (``Md2Model.surface``): the skin image :func:`find_skin` picks (the header's skin names are
Quake paths, usually .pcx files that do not travel with the model), with texture coordinates
``(s / skinwidth, t / skinheight)`` per triangle corner (MD2's st origin is the image's top-left
corner, as gridrt's); white times the skin, or the default grey without one; ambient 0.15 x that.
Each vertex record's normal index picks one of Quake II's 162 normals (:data:`ANORMS`); between
frames the normals are interpolated like the positions and normalised again
(:meth:`Md2Model.normals_at`).

Frames play at ``fps`` (Quake II's 10 by default) and loop.  Frame names such as ``run1 .. run6``
form clips; ``clip="run"`` (or its index in :attr:`Md2Model.clips`) plays one of them.
"""

import os
import re
import struct
import warnings
from pathlib import Path

import numpy as np

from ..errors import InputError, SceneFileError
from .animation import gather_unchecked
from .files import SceneFolder, open_regular, os_problem
from .frames import KeyframeMesh, check_fps
from .kernels import lerp_rows
from .mesh import AMBIENT_FRACTION, DEFAULT_DIFFUSE, IMAGE_EXTENSIONS
from .surface import Surface, TextureWarning, load_texture

__all__ = ["ANORMS", "Md2Model", "find_skin", "read_md2", "MD2_TO_GRIDRT"]

_MAGIC = b"IDP2"
_HEADER = struct.Struct("<4s16i")
_LIMIT = 1 << 20

#: Axis change applied to MD2 positions and normals: gridrt = MD2_TO_GRIDRT @ md2.
MD2_TO_GRIDRT = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])

#: The 162 unit normals MD2 vertices index (Quake II's ``anorms.h``, the vertices of a frequency-4
#: geodesic icosahedron), three per line, MD2 axes, as published (6 decimals; normalised on use).
_ANORMS_TEXT = """
-0.525731 0.000000 0.850651 -0.442863 0.238856 0.864188 -0.295242 0.000000 0.955423
-0.309017 0.500000 0.809017 -0.162460 0.262866 0.951056 0.000000 0.000000 1.000000
0.000000 0.850651 0.525731 -0.147621 0.716567 0.681718 0.147621 0.716567 0.681718
0.000000 0.525731 0.850651 0.309017 0.500000 0.809017 0.525731 0.000000 0.850651
0.295242 0.000000 0.955423 0.442863 0.238856 0.864188 0.162460 0.262866 0.951056
-0.681718 0.147621 0.716567 -0.809017 0.309017 0.500000 -0.587785 0.425325 0.688191
-0.850651 0.525731 0.000000 -0.864188 0.442863 0.238856 -0.716567 0.681718 0.147621
-0.688191 0.587785 0.425325 -0.500000 0.809017 0.309017 -0.238856 0.864188 0.442863
-0.425325 0.688191 0.587785 -0.716567 0.681718 -0.147621 -0.500000 0.809017 -0.309017
-0.525731 0.850651 0.000000 0.000000 0.850651 -0.525731 -0.238856 0.864188 -0.442863
0.000000 0.955423 -0.295242 -0.262866 0.951056 -0.162460 0.000000 1.000000 0.000000
0.000000 0.955423 0.295242 -0.262866 0.951056 0.162460 0.238856 0.864188 0.442863
0.262866 0.951056 0.162460 0.500000 0.809017 0.309017 0.238856 0.864188 -0.442863
0.262866 0.951056 -0.162460 0.500000 0.809017 -0.309017 0.850651 0.525731 0.000000
0.716567 0.681718 0.147621 0.716567 0.681718 -0.147621 0.525731 0.850651 0.000000
0.425325 0.688191 0.587785 0.864188 0.442863 0.238856 0.688191 0.587785 0.425325
0.809017 0.309017 0.500000 0.681718 0.147621 0.716567 0.587785 0.425325 0.688191
0.955423 0.295242 0.000000 1.000000 0.000000 0.000000 0.951056 0.162460 0.262866
0.850651 -0.525731 0.000000 0.955423 -0.295242 0.000000 0.864188 -0.442863 0.238856
0.951056 -0.162460 0.262866 0.809017 -0.309017 0.500000 0.681718 -0.147621 0.716567
0.850651 0.000000 0.525731 0.864188 0.442863 -0.238856 0.809017 0.309017 -0.500000
0.951056 0.162460 -0.262866 0.525731 0.000000 -0.850651 0.681718 0.147621 -0.716567
0.681718 -0.147621 -0.716567 0.850651 0.000000 -0.525731 0.809017 -0.309017 -0.500000
0.864188 -0.442863 -0.238856 0.951056 -0.162460 -0.262866 0.147621 0.716567 -0.681718
0.309017 0.500000 -0.809017 0.425325 0.688191 -0.587785 0.442863 0.238856 -0.864188
0.587785 0.425325 -0.688191 0.688191 0.587785 -0.425325 -0.147621 0.716567 -0.681718
-0.309017 0.500000 -0.809017 0.000000 0.525731 -0.850651 -0.525731 0.000000 -0.850651
-0.442863 0.238856 -0.864188 -0.295242 0.000000 -0.955423 -0.162460 0.262866 -0.951056
0.000000 0.000000 -1.000000 0.295242 0.000000 -0.955423 0.162460 0.262866 -0.951056
-0.442863 -0.238856 -0.864188 -0.309017 -0.500000 -0.809017 -0.162460 -0.262866 -0.951056
0.000000 -0.850651 -0.525731 -0.147621 -0.716567 -0.681718 0.147621 -0.716567 -0.681718
0.000000 -0.525731 -0.850651 0.309017 -0.500000 -0.809017 0.442863 -0.238856 -0.864188
0.162460 -0.262866 -0.951056 0.238856 -0.864188 -0.442863 0.500000 -0.809017 -0.309017
0.425325 -0.688191 -0.587785 0.716567 -0.681718 -0.147621 0.688191 -0.587785 -0.425325
0.587785 -0.425325 -0.688191 0.000000 -0.955423 -0.295242 0.000000 -1.000000 0.000000
0.262866 -0.951056 -0.162460 0.000000 -0.850651 0.525731 0.000000 -0.955423 0.295242
0.238856 -0.864188 0.442863 0.262866 -0.951056 0.162460 0.500000 -0.809017 0.309017
0.716567 -0.681718 0.147621 0.525731 -0.850651 0.000000 -0.238856 -0.864188 -0.442863
-0.500000 -0.809017 -0.309017 -0.262866 -0.951056 -0.162460 -0.850651 -0.525731 0.000000
-0.716567 -0.681718 -0.147621 -0.716567 -0.681718 0.147621 -0.525731 -0.850651 0.000000
-0.500000 -0.809017 0.309017 -0.238856 -0.864188 0.442863 -0.262866 -0.951056 0.162460
-0.864188 -0.442863 0.238856 -0.809017 -0.309017 0.500000 -0.688191 -0.587785 0.425325
-0.681718 -0.147621 0.716567 -0.442863 -0.238856 0.864188 -0.587785 -0.425325 0.688191
-0.309017 -0.500000 0.809017 -0.147621 -0.716567 0.681718 -0.425325 -0.688191 0.587785
-0.162460 -0.262866 0.951056 0.442863 -0.238856 0.864188 0.162460 -0.262866 0.951056
0.309017 -0.500000 0.809017 0.147621 -0.716567 0.681718 0.000000 -0.525731 0.850651
0.425325 -0.688191 0.587785 0.587785 -0.425325 0.688191 0.688191 -0.587785 0.425325
-0.955423 0.295242 0.000000 -0.951056 0.162460 0.262866 -1.000000 0.000000 0.000000
-0.850651 0.000000 0.525731 -0.955423 -0.295242 0.000000 -0.951056 -0.162460 0.262866
-0.864188 0.442863 -0.238856 -0.951056 0.162460 -0.262866 -0.809017 0.309017 -0.500000
-0.864188 -0.442863 -0.238856 -0.951056 -0.162460 -0.262866 -0.809017 -0.309017 -0.500000
-0.681718 0.147621 -0.716567 -0.681718 -0.147621 -0.716567 -0.850651 0.000000 -0.525731
-0.688191 0.587785 -0.425325 -0.587785 0.425325 -0.688191 -0.425325 0.688191 -0.587785
-0.425325 -0.688191 -0.587785 -0.587785 -0.425325 -0.688191 -0.688191 -0.587785 -0.425325
"""
ANORMS = np.array(_ANORMS_TEXT.split(), dtype=np.float64).reshape(162, 3)
ANORMS.setflags(write=False)


def read_md2(path):
    """Decode an MD2 file: ``(frames (K, V, 3) float64 in MD2 axes, faces (F, 3) int64, names)``.

    Raises SceneFileError naming the file for a wrong magic or version, counts or offsets outside
    the file, truncated blocks or vertex indices out of range.
    """
    d = _decode(Path(path))
    return d.frames, d.faces, d.names


class _Md2Data:
    """Everything :func:`_decode` reads from an MD2 file."""

    frames: np.ndarray          # (K, V, 3) float64, MD2 axes
    faces: np.ndarray           # (F, 3) int64
    names: list                 # K frame names
    normal_ids: np.ndarray      # (K, V) uint8 indices into ANORMS (>= 162: none)
    uv: np.ndarray | None       # (F, 3, 2) float32 (s / skinwidth, t / skinheight), None without st
    skins: list                 # the header's skin names
    skin_size: tuple            # (width, height)


def _decode(p):
    try:
        with open_regular(p) as (fh, size):
            head = fh.read(_HEADER.size)
            end = _HEADER.unpack_from(head, 0)[-1] if len(head) == _HEADER.size else 0
            if head[:4] == _MAGIC and end > size:  # (the size the header declares: checked before reading on)
                raise SceneFileError(p, f"truncated MD2 file: the header says {end} bytes, the file has {size}")
            raw = head + fh.read()
    except OSError as e:
        raise SceneFileError(p, os_problem(e)) from e
    if not raw:
        raise SceneFileError(p, "file is empty (0 bytes)")
    if len(raw) < _HEADER.size:
        raise SceneFileError(p, f"truncated MD2 file: {len(raw)} bytes, the header alone needs {_HEADER.size}")
    h = _HEADER.unpack_from(raw, 0)
    magic, version = h[0], h[1]
    (skin_w, skin_h, framesize, n_skins, n_verts, n_st, n_tris, _, n_frames,
     ofs_skins, ofs_st, ofs_tris, ofs_frames, _, ofs_end) = h[2:]
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
    normal_ids = np.empty((n_frames, n_verts), np.uint8)
    names = []
    rec = np.dtype([("scale", "<f4", 3), ("translate", "<f4", 3), ("name", "S16")])
    for k in range(n_frames):
        o = ofs_frames + k * framesize
        head = np.frombuffer(raw, dtype=rec, count=1, offset=o)[0]
        packed = np.frombuffer(raw, dtype=np.uint8, count=4 * n_verts, offset=o + 40).reshape(n_verts, 4)
        scale = head["scale"].astype(np.float64)
        shift = head["translate"].astype(np.float64)
        if not (np.isfinite(scale).all() and np.isfinite(shift).all()):
            raise SceneFileError(p, f"frame {k} has a non-finite scale or translation")
        frames[k] = packed[:, :3] * scale + shift
        normal_ids[k] = packed[:, 3]
        names.append(head["name"].split(b"\0", 1)[0].decode("latin-1"))
    # looks: skin names and texture coordinates (no st block: no uv; a block the header places outside
    # the file, or an index past it, is an error like any other)
    d = _Md2Data()
    d.frames, d.faces, d.names, d.normal_ids = frames, faces, names, normal_ids
    d.skin_size = (skin_w, skin_h)
    d.skins = []
    if 0 < n_skins <= 32 and ofs_skins >= _HEADER.size and ofs_skins + 64 * n_skins <= len(raw):
        d.skins = [raw[ofs_skins + 64 * i:ofs_skins + 64 * (i + 1)].split(b"\0", 1)[0].decode("latin-1").strip()
                   for i in range(n_skins)]
        d.skins = [n for n in d.skins if n]
    d.uv = None
    if n_st > 0:
        if n_st > _LIMIT or ofs_st < _HEADER.size or ofs_st + 4 * n_st > len(raw):
            raise SceneFileError(p, f"truncated or malformed MD2 file: the texture coordinate block (bytes {ofs_st}.."
                                    f"{ofs_st + 4 * n_st}) lies outside the file's {len(raw)} bytes")
        if skin_w <= 0 or skin_h <= 0:
            raise SceneFileError(p, f"malformed MD2 header: skin size {skin_w} x {skin_h}")
        st = np.frombuffer(raw, dtype="<i2", count=2 * n_st, offset=ofs_st).reshape(n_st, 2).astype(np.float64)
        st_ids = tris[:, 3:].astype(np.int64)
        if st_ids.max() >= n_st:
            bad = int(np.argmax(st_ids.max(axis=1)))
            raise SceneFileError(p, f"triangle {bad} has texture coordinate index {int(st_ids[bad].max())}, but the "
                                    f"file has {n_st} texture coordinates")
        d.uv = (st[st_ids] / [float(skin_w), float(skin_h)]).astype(np.float32)
    return d


def find_skin(path, skins=()):
    """The image file that skins the MD2 model ``path``, or None.  In the model's folder, the first of:

    1. a skin the header names (Quake paths such as ``models/monsters/tank/skin.pcx``): the file of
       that name, or of its stem with any of :data:`~gridrt.scene.mesh.IMAGE_EXTENSIONS` (any case);
    2. an image with the model's stem (``sydney.bmp`` for ``sydney.md2``);
    3. the folder's only image file, when it holds exactly one (``faerie2.bmp`` beside ``faerie.md2``).
    """
    p = Path(path)
    try:
        images = sorted(q for q in p.parent.iterdir() if q.suffix.lower() in IMAGE_EXTENSIONS and q.is_file())
    except OSError:
        return None
    by_name = {q.name.lower(): q for q in images}
    by_stem = {}
    for q in images:
        by_stem.setdefault(q.stem.lower(), q)
    for s in skins:
        base = s.replace("\\", "/").rsplit("/", 1)[-1].lower()
        if base in by_name:
            return by_name[base]
        stem = base.rsplit(".", 1)[0] if "." in base else base
        if stem in by_stem:
            return by_stem[stem]
    if p.stem.lower() in by_stem:
        return by_stem[p.stem.lower()]
    return images[0] if len(images) == 1 else None


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
    allow_outside : bool
        Trust a skin that resolves outside the model's folder (a symlink leading out; see
        :mod:`gridrt.scene.files`); by default it is left out with a TextureWarning.

    Attributes
    ----------
    clips : list of str
        Clip names in file order (frame names without their trailing numbers).
    clip : str or None
    first_frame : int
        Index in the file of the clip's first frame (frame k of the clip is file frame
        ``first_frame + k``).
    skin : pathlib.Path or None
        The skin image :func:`find_skin` found (read into ``surface``; a file Pillow cannot read
        warns TextureWarning and the model is drawn untextured).
    surface : gridrt.scene.surface.Surface
        One material (see the module docstring), uv per corner, the clip's first frame's normals;
        :meth:`normals_at` gives them at any time.
    """

    def __init__(self, path, clip=None, fps=10.0, *, allow_outside=False):
        if not isinstance(path, (str, os.PathLike)):
            raise InputError(f"MD2 path must be a str or path-like object, got {type(path).__name__}")
        p = Path(path)
        if not p.exists():
            raise SceneFileError(p, "file not found")
        if p.is_dir():
            raise SceneFileError(p, "is a directory, not an MD2 file")
        fps = check_fps(fps)
        data = _decode(p)
        frames, faces, names = data.frames, data.faces, data.names
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
        # per-vertex normals of every frame, in gridrt's axes (an index past the table: zero, the
        # geometric normal); only the rotation MD2_TO_GRIDRT applies: the table's vectors are the
        # model's own normals, not ones of the quantised (scaled) grid
        table = np.zeros((256, 3))
        table[:len(ANORMS)] = ANORMS / np.linalg.norm(ANORMS, axis=1, keepdims=True)
        self._normals = np.ascontiguousarray((table @ MD2_TO_GRIDRT.T)[data.normal_ids[sel]], dtype=np.float32)
        self._vnormals = np.zeros(self._normals.shape[1:], dtype=np.float32)
        self.skin = find_skin(p, data.skins)
        self.surface = self._looks(data, allow_outside)

    def _looks(self, data, allow_outside):
        """The model's Surface: one material, white times the skin when there is one (and uv), else
        the default grey; uv from the st block; the first frame's normals at rest.  A skin that
        resolves outside the model's folder (a symlink leading out) is left out with a warning
        unless ``allow_outside``."""
        if self.skin is None and data.skins and data.uv is not None:
            warnings.warn(f"{self.path}: skin {data.skins[0]!r} not found beside the model (nor an image named "
                          f"{self.path.stem}.*); drawn untextured", TextureWarning, stacklevel=3)
        folder = SceneFolder(self.path, allow_outside)
        if self.skin is not None and not folder.is_inside(self.skin):
            warnings.warn(f"{folder.refusal('skin', self.skin.name, self.path)}; drawn untextured", TextureWarning,
                          stacklevel=3)
            self.skin = None
        tex = load_texture(self.skin) if (self.skin is not None and data.uv is not None) else None
        diffuse = np.array([(1.0, 1.0, 1.0) if tex is not None else DEFAULT_DIFFUSE], np.float32)
        rest = self._normals[0][self._faces]
        return Surface(np.zeros(self.n_triangles, np.int32), diffuse, (np.float32(AMBIENT_FRACTION) * diffuse),
                       np.array([0 if tex is not None else -1], np.int32), (tex,) if tex is not None else (),
                       data.uv, None, rest)

    def _fill_normals(self, t, out):
        k0, k1, s = self.frame_position(t)
        n = self._vnormals
        lerp_rows(self._normals[k0], self._normals[k1], s, n)
        if s != 0.0:  # between frames: back to unit length (a zero blend stays zero)
            length = np.sqrt((n * n).sum(axis=1, keepdims=True))
            np.divide(n, length, out=n, where=length > 0)
        gather_unchecked(n, self._faces, out)
        return True
