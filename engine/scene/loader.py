"""load_mesh: a static triangle mesh from a file, by its extension.

Static meshes are read with trimesh (PLY, STL, OFF, glTF 2.0 as .glb or .gltf) or, for OBJ, with
gridrt's own reader (:func:`gridrt.scene.obj.read_obj`).  Polygons (quads, pentagons, ...) are
triangulated (OBJ: as fans ``(0, i, i + 1)`` in file order); a glTF file with several meshes is
flattened into one mesh with every node transform applied, in its bind pose (skins, morph targets
and animation clips are ignored here).  Every failure raises :class:`gridrt.errors.SceneFileError`
naming the file and the problem.

Looks (``Mesh.surface``, a :class:`gridrt.scene.surface.Surface` with one row per face):

* OBJ: the materials of its MTL libraries, texture coordinates, normals and vertex colours
  (:mod:`gridrt.scene.obj`).
* PLY: vertex colours (``red``/``green``/``blue``, bytes or floats; alpha ignored) per corner
  with a white material (the colours replace the grey), per-face colours likewise, and vertex
  normals ``nx``/``ny``/``nz`` (with the default grey when there are no colours).
* Other formats: no surface.
"""

import importlib.util
import json
import os
import struct
from pathlib import Path

import numpy as np

from ..errors import InputError, SceneFileError
from .files import SceneFolder, open_regular, os_problem, read_regular
from .gltf import DRACO_HINT, glb_version_problem, gltf_version_problem
from .mesh import DEFAULT_DIFFUSE, Mesh, _material_row, _unit_rows, quiet_trimesh
from .obj import read_obj
from .surface import Surface
from .textenc import TEXT_EXTENSIONS, utf8_source

__all__ = ["SUPPORTED_EXTENSIONS", "load_mesh"]

#: File extensions :func:`load_mesh` reads (lower case, with the dot).
SUPPORTED_EXTENSIONS = (".obj", ".ply", ".stl", ".off", ".glb", ".gltf")

_GLB_MAGIC = b"glTF"
_GLB_JSON_CHUNK = 0x4E4F534A


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


class _FolderResolver:
    """What trimesh reads for a glTF file's URIs: only regular files inside the SceneFolder
    ``folder`` (else OSError or OutsideReference: trimesh leaves such an image out; the buffers
    are checked before, by :func:`_check_gltf`)."""

    def __init__(self, folder, path):
        self.folder, self.path = folder, Path(path)

    def get(self, name):
        return read_regular(self.folder.uri(self.path.parent, "file", name, self.path))

    __getitem__ = get


def _check_gltf(path, ext, folder):
    """Reject glTF files whose geometry trimesh would silently replace with zeros, and those whose
    buffers lie outside the SceneFolder ``folder`` or are not regular files."""
    tree = _gltf_json(path, ext)
    if not isinstance(tree, dict):
        raise SceneFileError(path, f"malformed {ext} file: top-level JSON is not an object")
    if gltf_version_problem(tree):
        raise SceneFileError(path, gltf_version_problem(tree))
    required = set(tree.get("extensionsRequired") or ())
    if "KHR_draco_mesh_compression" in required and importlib.util.find_spec("DracoPy") is None:
        raise SceneFileError(path, f"geometry is Draco-compressed (KHR_draco_mesh_compression); {DRACO_HINT}")
    if "EXT_meshopt_compression" in required:
        raise SceneFileError(path, "geometry uses EXT_meshopt_compression, which trimesh cannot decode")
    buffers = tree.get("buffers")
    for i, item in enumerate(buffers if isinstance(buffers, list) else ()):
        uri = item.get("uri") if isinstance(item, dict) else None
        if isinstance(uri, str) and uri and not uri.startswith("data:"):
            ref = folder.uri(path.parent, f"buffer {i}", uri, path)
            if ref.exists() and not ref.is_file():  # (a FIFO or a device)
                raise SceneFileError(path, f"buffer {i} {uri!r} is not a regular file")


# ----------------------------------------------------------------------------- PLY


def _color_scale(dtype):
    dt = np.dtype(dtype)
    if dt.kind == "f":
        return 1.0
    if dt.kind in "ui":
        return 1.0 / float(np.iinfo(dt).max)
    return None


def _ply_column(data, name, n):
    """The (n,) values of property ``name`` of a PLY element trimesh read (a structured array, or
    for ASCII files a dict of (n, 1) arrays), or None."""
    try:
        c = np.asarray(data[name])
    except (KeyError, ValueError, TypeError, IndexError):
        return None
    return c.reshape(n) if c.size == n and c.dtype.kind in "uif" else None


def _ply_colors(element, n):
    """(n, 3) float64 colours in [0, 1] of a PLY element's red/green/blue properties, or None."""
    if not isinstance(element, dict):
        return None
    props = element.get("properties") or {}
    data = element.get("data")
    for names in (("red", "green", "blue"), ("diffuse_red", "diffuse_green", "diffuse_blue"), ("r", "g", "b")):
        if all(k in props for k in names):
            cols = [_ply_column(data, k, n) for k in names]
            if any(c is None for c in cols):
                return None
            scale = _color_scale(cols[0].dtype)
            if scale is None:
                return None
            c = np.stack(cols, axis=1).astype(np.float64) * scale
            return np.clip(np.nan_to_num(c, nan=0.0, posinf=1.0, neginf=0.0), 0.0, 1.0)
    return None


def _ply_surface(loaded, faces):
    """The surface of a PLY file trimesh read (vertex/face colours, vertex normals), or None."""
    elements = (getattr(loaded, "metadata", None) or {}).get("_ply_raw")
    if not isinstance(elements, dict) or not isinstance(elements.get("vertex"), dict):
        return None
    vert = elements["vertex"]
    nv = len(loaded.vertices)
    colors = normals = None
    vc = _ply_colors(vert, nv)
    if vc is not None:
        colors = vc[faces]
    else:
        fc = _ply_colors(elements.get("face"), len(faces))
        if fc is not None:
            colors = np.repeat(fc[:, None, :], 3, axis=1)
    props = vert.get("properties") or {}
    if all(k in props for k in ("nx", "ny", "nz")):
        cols = [_ply_column(vert.get("data"), k, nv) for k in ("nx", "ny", "nz")]
        if all(c is not None for c in cols):
            n = np.stack(cols, axis=1).astype(np.float64)
            n = np.where(np.isfinite(n), n, 0.0)
            normals = _unit_rows(n)[faces]
    if colors is None and normals is None:
        return None
    diffuse, ambient = _material_row((1.0, 1.0, 1.0) if colors is not None else DEFAULT_DIFFUSE)
    return Surface(np.zeros(len(faces), np.int32), diffuse[None], ambient[None], np.full(1, -1, np.int32), (),
                   None, colors, normals)


def load_mesh(path, looks=True, *, allow_outside=False, folder=None):
    """Load a static triangle mesh from a file.

    Parameters
    ----------
    path : str or os.PathLike
        A file with one of :data:`SUPPORTED_EXTENSIONS` (case-insensitive).
    looks : bool
        False: leave the materials, textures and per-corner attributes out (``surface`` None; no
        MTL or image file is read).
    allow_outside : bool
        Trust the file's references (OBJ ``mtllib`` and ``map_Kd``, glTF buffers and images) that
        lead outside its folder (see :mod:`gridrt.scene.files`); by default a material or texture
        outside is left out with a TextureWarning and a glTF buffer or image outside is an error.
    folder : gridrt.scene.files.SceneFolder, optional
        The folder the references must lie in instead (a frame folder's), with its trust.

    Returns
    -------
    Mesh
        vertices (V, 3) float32, faces (F, 3) int32, ``name`` = file stem, ``path``, ``surface``
        (see the module docstring; None when the file has no looks).

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
    folder = SceneFolder(p, allow_outside) if folder is None else folder
    try:
        with open_regular(p) as (fh, _):
            first = fh.read(1)
    except OSError as e:
        raise SceneFileError(p, os_problem(e)) from e
    if not first:
        raise SceneFileError(p, "file is empty (0 bytes)")
    if ext in (".glb", ".gltf"):
        _check_gltf(p, ext, folder)
    if ext == ".obj":
        try:
            v, f, surface = read_obj(p, looks=looks, folder=folder)
        except SceneFileError:
            raise
        except MemoryError as e:
            raise SceneFileError(p, "the file is too large to read into memory") from e
        except Exception as e:  # a reader bug must still name the file
            raise SceneFileError(p, f"malformed .obj file ({type(e).__name__}: {e})") from e
        try:
            return Mesh(v, f, name=p.stem, path=p, surface=surface)
        except InputError as e:
            raise SceneFileError(p, str(e)) from e

    # np.errstate: trimesh's arithmetic on a malformed file's values (overflowing casts, normals of
    # huge or NaN vertices) must not print numpy RuntimeWarnings; the values are validated below
    with quiet_trimesh(), np.errstate(all="ignore"):
        import trimesh  # deferred: trimesh (about 0.6 s to load), for non-OBJ files only

        try:
            # text (OBJ/MTL, OFF, ASCII STL, PLY headers) in UTF-16, Latin-1, ...: decoded by textenc, as
            # trimesh would need the optional charset_normalizer (and guess)
            src, kw = utf8_source(p) if ext in TEXT_EXTENSIONS else (str(p), {})
            if ext in (".glb", ".gltf"):
                kw["resolver"] = _FolderResolver(folder, p)
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
    faces = np.asarray(loaded.faces)
    surface = None
    if looks and ext == ".ply" and len(faces) and 0 <= faces.min() and faces.max() < n_v:
        try:
            with np.errstate(all="ignore"):  # extreme values are refused by Surface, without RuntimeWarnings
                surface = _ply_surface(loaded, faces)
        except InputError as e:
            raise SceneFileError(p, str(e)) from e
    try:
        return Mesh(np.asarray(loaded.vertices), faces, name=p.stem, path=p, surface=surface)
    except InputError as e:
        raise SceneFileError(p, str(e)) from e
