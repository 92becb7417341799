"""Indexed triangle meshes and loading them from files.

Static meshes are read with trimesh (OBJ, PLY, STL, OFF, glTF 2.0 as .glb or .gltf).  Polygons
(quads, pentagons, ...) are triangulated by trimesh; a glTF file with several meshes is
flattened into one mesh with every node transform applied, in its bind pose (skins, morph
targets and animation clips are ignored here).  Every failure raises
:class:`gridrt.errors.SceneFileError` naming the file and the problem.
"""

import contextlib
import importlib.util
import json
import logging
import os
import struct
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..arrays import TRI_DTYPE, as_mesh64, as_origin, bounds_centre
from ..errors import InputError, SceneFileError
from .textenc import TEXT_EXTENSIONS, utf8_source

__all__ = ["Mesh", "load_mesh", "quiet_trimesh", "SUPPORTED_EXTENSIONS"]

#: File extensions :func:`load_mesh` reads (lower case, with the dot).
SUPPORTED_EXTENSIONS = (".obj", ".ply", ".stl", ".off", ".glb", ".gltf")

_GLB_MAGIC = b"glTF"
_GLB_JSON_CHUNK = 0x4E4F534A


@dataclass(frozen=True, eq=False)
class Mesh:
    """A validated indexed triangle mesh.

    Attributes
    ----------
    vertices : ndarray
        (V, 3) float32 world coordinates, read-only (rounded: far from the origin, use
        :meth:`triangles` with ``origin`` or :attr:`vertices64`).
    vertices64 : ndarray
        (V, 3) float64, read-only: the vertices exactly as given.
    faces : ndarray
        (F, 3) int32 indices into ``vertices``, read-only.
    name : str
        Short name (the file stem for loaded meshes).
    path : pathlib.Path or None
        The file the mesh came from, None for generated meshes.
    surface : gridrt.scene.surface.Surface or None
        The mesh's materials, textures and per-corner attributes (one row per face), or None.

    Construction validates with :func:`gridrt.arrays.as_mesh` (shapes, NaN/inf, index range,
    all-degenerate) and raises InputError; the arrays are copied, so the caller's arrays are
    never frozen or aliased.
    """

    vertices: np.ndarray
    faces: np.ndarray
    name: str = "mesh"
    path: Path | None = None
    surface: object = None

    vertices64: np.ndarray = field(default=None, init=False, repr=False)

    def __post_init__(self):
        v64, f = as_mesh64(self.vertices, self.faces, what=f"mesh {self.name!r}")
        v64 = v64.copy() if v64 is self.vertices else v64
        f = f.copy()
        v = v64.astype(TRI_DTYPE)
        for a in (v, v64, f):
            a.setflags(write=False)
        object.__setattr__(self, "vertices", v)
        object.__setattr__(self, "vertices64", v64)
        object.__setattr__(self, "faces", f)
        if self.path is not None:
            object.__setattr__(self, "path", Path(self.path))
        if self.surface is not None and getattr(self.surface, "n_triangles", None) != len(f):
            raise InputError(f"mesh {self.name!r}: its surface describes {getattr(self.surface, 'n_triangles', '?')} "
                             f"triangles, the mesh has {len(f)}")

    @property
    def n_triangles(self):
        """Number of triangles F."""
        return int(len(self.faces))

    @property
    def n_vertices(self):
        """Number of vertices V."""
        return int(len(self.vertices))

    def triangles(self, origin=None):
        """A new (F, 3, 3) float32 C-contiguous array ``vertices[faces]``; with ``origin`` ((3,)
        float64) the vertices are moved by ``-origin`` in float64 before rounding to float32."""
        if origin is None:
            return np.ascontiguousarray(self.vertices[self.faces])
        local = (self.vertices64 - as_origin(origin)).astype(TRI_DTYPE)
        return np.ascontiguousarray(local[self.faces])

    def bounds(self):
        """Axis-aligned bounding box ``(lo (3,) float64, hi (3,) float64)`` of the vertices."""
        return self.vertices64.min(axis=0), self.vertices64.max(axis=0)

    @property
    def centre(self):
        """(3,) float64 centre of :meth:`bounds`."""
        return bounds_centre(self.vertices64)

    def __repr__(self):
        return f"Mesh(name={self.name!r}, vertices={self.n_vertices}, faces={self.n_triangles})"


@contextlib.contextmanager
def quiet_trimesh():
    """Silence the loggers of trimesh and of PIL (which trimesh uses for glTF textures) for a block.

    trimesh logs warnings such as 'unable to use sparse matrix' or failed glTF extensions; gridrt
    reports problems through exceptions instead.
    """
    loggers = [logging.getLogger(name) for name in ("trimesh", "PIL")]
    old = [lg.level for lg in loggers]
    for lg in loggers:
        lg.setLevel(logging.CRITICAL + 1)
    try:
        yield
    finally:
        for lg, level in zip(loggers, old):
            lg.setLevel(level)


def _gltf_json(path, ext):
    """The JSON tree of a .gltf or .glb file; raise SceneFileError when it is not readable as one."""
    if ext == ".gltf":
        try:
            return json.loads(path.read_text(encoding="utf-8"))
        except (UnicodeDecodeError, json.JSONDecodeError) as e:
            raise SceneFileError(path, f"malformed .gltf file: not valid JSON ({e})") from e
    with open(path, "rb") as fh:
        header = fh.read(20)
        if len(header) < 20 or header[:4] != _GLB_MAGIC:
            raise SceneFileError(path, "malformed .glb file: missing the 'glTF' binary header")
        _, version, _, chunk_len, chunk_type = struct.unpack("<4sIIII", header)
        from .gltf import glb_version_problem

        if glb_version_problem(version):
            raise SceneFileError(path, glb_version_problem(version))
        if chunk_type != _GLB_JSON_CHUNK:
            raise SceneFileError(path, "malformed .glb file: the first chunk is not JSON")
        raw = fh.read(chunk_len)
    if len(raw) < chunk_len:
        raise SceneFileError(path, "malformed .glb file: truncated JSON chunk")
    try:
        return json.loads(raw.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as e:
        raise SceneFileError(path, f"malformed .glb file: JSON chunk is not valid JSON ({e})") from e


def _check_gltf(path, ext):
    """Reject glTF files whose geometry trimesh would silently replace with zeros."""
    tree = _gltf_json(path, ext)
    if not isinstance(tree, dict):
        raise SceneFileError(path, f"malformed {ext} file: top-level JSON is not an object")
    from .gltf import gltf_version_problem  # here: gltf imports this module (through animation)

    if gltf_version_problem(tree):
        raise SceneFileError(path, gltf_version_problem(tree))
    required = set(tree.get("extensionsRequired") or ())
    if "KHR_draco_mesh_compression" in required and importlib.util.find_spec("DracoPy") is None:
        from .gltf import DRACO_HINT

        raise SceneFileError(path, f"geometry is Draco-compressed (KHR_draco_mesh_compression); {DRACO_HINT}")
    if "EXT_meshopt_compression" in required:
        raise SceneFileError(path, "geometry uses EXT_meshopt_compression, which trimesh cannot decode")


def load_mesh(path):
    """Load a static triangle mesh from a file.

    Parameters
    ----------
    path : str or os.PathLike
        A file with one of :data:`SUPPORTED_EXTENSIONS` (case-insensitive).

    Returns
    -------
    Mesh
        vertices (V, 3) float32, faces (F, 3) int32, ``name`` = file stem, ``path``.

    Raises
    ------
    SceneFileError
        The file is missing, a directory, unreadable, has an unsupported extension, is empty or
        malformed, holds no faces (a point cloud), or its mesh fails validation (NaN vertices,
        face indices out of range, all triangles degenerate).  ``str(err)`` starts with the path.
    InputError
        ``path`` is not a str or path-like object.
    """
    if not isinstance(path, (str, os.PathLike)):
        raise InputError(f"mesh path must be a str or path-like object, got {type(path).__name__}")
    p = Path(path)
    ext = p.suffix.lower()
    supported = ", ".join(SUPPORTED_EXTENSIONS)
    if not p.exists():
        raise SceneFileError(p, "file not found")
    if p.is_dir():
        raise SceneFileError(p, "is a directory, not a mesh file")
    if ext not in SUPPORTED_EXTENSIONS:
        what = f"unsupported file extension {ext!r}" if ext else "no file extension"
        raise SceneFileError(p, f"{what}; supported extensions: {supported}")
    try:
        with open(p, "rb") as fh:
            first = fh.read(1)
    except PermissionError as e:
        raise SceneFileError(p, "permission denied: the file is not readable") from e
    except OSError as e:
        raise SceneFileError(p, f"cannot read the file ({e.strerror or e})") from e
    if not first:
        raise SceneFileError(p, "file is empty (0 bytes)")
    if ext in (".glb", ".gltf"):
        _check_gltf(p, ext)

    # np.errstate: trimesh's arithmetic on a malformed file's values (overflowing casts, normals of
    # huge or NaN vertices) must not print numpy RuntimeWarnings; the values are validated below
    with quiet_trimesh(), np.errstate(all="ignore"):
        import trimesh

        try:
            # text (OBJ/MTL, OFF, ASCII STL, PLY headers) in UTF-16, Latin-1, ...: decoded by textenc, as
            # trimesh would need the optional charset_normalizer (and guess)
            src, kw = utf8_source(p) if ext in TEXT_EXTENSIONS else (str(p), {})
            loaded = trimesh.load(src, file_type=ext[1:], force="mesh", process=False, **kw)
        except SceneFileError:
            raise
        except FileNotFoundError as e:
            raise SceneFileError(p, f"a file that {p.name} refers to is missing ({e})") from e
        except IndexError as e:
            raise SceneFileError(p, f"malformed {ext} file: face index out of range ({e})") from e
        except Exception as e:
            raise SceneFileError(p, f"malformed {ext} file ({type(e).__name__}: {e})") from e
    if not isinstance(loaded, trimesh.Trimesh):
        raise SceneFileError(p, f"{ext} file holds no triangle mesh (trimesh read a {type(loaded).__name__})")
    n_v, n_f = len(loaded.vertices), len(loaded.faces)
    if n_f == 0:
        if n_v:
            raise SceneFileError(p, f"file has {n_v} vertices but no faces (a point cloud?)")
        raise SceneFileError(p, f"file contains no triangles (no faces, only points, or not a valid {ext} file)")
    try:
        return Mesh(np.asarray(loaded.vertices), np.asarray(loaded.faces), name=p.stem, path=p)
    except InputError as e:
        raise SceneFileError(p, str(e)) from e
