"""Scenes: triangles as a pure function of time.

:func:`make_scene` turns a built-in scene name or a mesh file path into an
:class:`Animation`, whose ``triangles_at(t)`` returns (F, 3, 3) float32 triangles:

* ``"marbles"``: rigid marbles bouncing in a box (:class:`Marbles`), ``count`` = exact triangles;
* ``"icosphere"``: a unit icosphere with about ``count`` triangles (static, or deformed with
  ``animate``);
* a path to an .obj/.ply/.stl/.off/.glb/.gltf file: the mesh (:class:`StaticMesh`), or the mesh
  deformed by ``animate="twist"|"wave"`` (:class:`Deform`).
"""

import math
import os
from numbers import Integral
from pathlib import Path

import numpy as np

from ..errors import InputError
from .animation import Animation, StaticMesh, gather_triangles
from .deform import DEFORM_KINDS, Deform
from .marbles import Marbles
from .mesh import SUPPORTED_EXTENSIONS, Mesh, load_mesh, quiet_trimesh

__all__ = [
    "Animation",
    "BUILTIN_SCENES",
    "DEFORM_KINDS",
    "Deform",
    "Marbles",
    "Mesh",
    "StaticMesh",
    "SUPPORTED_EXTENSIONS",
    "gather_triangles",
    "icosphere_mesh",
    "load_mesh",
    "make_scene",
]

#: Built-in scene names and what ``count`` means for each.
BUILTIN_SCENES = {
    "marbles": "rigid marbles bouncing in a box; count = exact triangle count (default 8800)",
    "icosphere": "unit icosphere; count = approximate triangle count, 20*4^k (default 5120)",
}

_ICOSPHERE_DEFAULT = 5120
_ICOSPHERE_MAX_SUBDIVISIONS = 9


def icosphere_mesh(count=_ICOSPHERE_DEFAULT):
    """A unit icosphere centred at the origin with ``20 * 4**k`` triangles closest to ``count``.

    ``k`` is ``round(log4(count / 20))`` clamped to [0, 9] (20 to 5,242,880 triangles).
    """
    count = _check_count(count)
    k = int(round(math.log(count / 20.0, 4))) if count > 20 else 0
    k = min(max(k, 0), _ICOSPHERE_MAX_SUBDIVISIONS)
    with quiet_trimesh():
        import trimesh

        ico = trimesh.creation.icosphere(subdivisions=k, radius=1.0)
    return Mesh(np.asarray(ico.vertices), np.asarray(ico.faces), name="icosphere")


def _check_count(count):
    if isinstance(count, (bool, np.bool_)) or not isinstance(count, (Integral, np.integer)):
        raise InputError(f"triangle count must be an integer, got {count!r}")
    if count < 1:
        raise InputError(f"triangle count must be positive, got {count}")
    return int(count)


def make_scene(name_or_path, count=None, animate=None, amplitude=None, speed=1.0, seed=0):
    """Build an :class:`Animation` from a built-in scene name or a mesh file path.

    Parameters
    ----------
    name_or_path : str or os.PathLike
        One of :data:`BUILTIN_SCENES` or a path to a mesh file with one of
        :data:`SUPPORTED_EXTENSIONS`.
    count : int, optional
        Built-in scenes only: triangle count (exact for marbles, nearest ``20*4^k`` for icosphere).
    animate : {"twist", "wave"}, optional
        Deform a mesh (file or icosphere) over time; see :class:`Deform`.  Not for marbles.
    amplitude : float, optional
        Deformation amplitude in scene units (default 5% of the bounding-box diagonal).
    speed : float
        Deformation oscillations per second, or the marbles' playback rate.
    seed : int
        Random seed of the marbles scene (ignored by the others).

    Raises
    ------
    InputError
        Unknown scene name that is not an existing file (the message lists the built-in names
        and the supported extensions), unknown ``animate`` kind (lists the kinds), or an option
        that does not apply to the chosen scene.
    SceneFileError
        The file cannot be loaded (see :func:`load_mesh`).
    """
    if not isinstance(name_or_path, (str, os.PathLike)):
        raise InputError(f"scene must be a built-in name or a file path, got {type(name_or_path).__name__}")
    if animate is not None and animate not in DEFORM_KINDS:
        raise InputError(f"unknown animation {animate!r}; choose one of: {', '.join(DEFORM_KINDS)}")

    key = name_or_path.strip().lower() if isinstance(name_or_path, str) else None
    if key == "marbles":
        if animate is not None or amplitude is not None:
            raise InputError("the marbles scene is already animated; animate= and amplitude= apply to meshes")
        return Marbles(8800 if count is None else count, seed=seed, speed=speed)
    if animate is None and (amplitude is not None or speed != 1.0):
        raise InputError("amplitude and speed apply only to animated scenes: pass animate='twist' or 'wave'")
    if key == "icosphere":
        mesh = icosphere_mesh(_ICOSPHERE_DEFAULT if count is None else count)
    else:
        path = Path(name_or_path)
        if not path.exists() and path.suffix.lower() not in SUPPORTED_EXTENSIONS:
            raise InputError(
                f"unknown scene {str(name_or_path)!r}: not a built-in scene "
                f"({', '.join(BUILTIN_SCENES)}) and not an existing file; "
                f"mesh files may be {', '.join(SUPPORTED_EXTENSIONS)}"
            )
        if count is not None:
            raise InputError("count applies to built-in scenes only, not to mesh files")
        mesh = load_mesh(path)
    if animate is None:
        return StaticMesh(mesh)
    return Deform(mesh, kind=animate, amplitude=amplitude, speed=speed)
