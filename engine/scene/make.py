"""make_scene: an :class:`Animation` from a built-in scene name, a scene file or a folder of frames
(the package's docstring lists what each becomes), and the names and extensions it accepts."""

import math
import os
import warnings
from numbers import Integral
from pathlib import Path

import numpy as np

from ..errors import InputError, SceneFileError
from .animation import StaticMesh
from .assets import ASSET_SCENES, DATA_HIDDEN, DATA_SCENES, scene_file, scene_present
from .bart import BartAnimation
from .deform import DEFORM_KINDS, Deform
from .frames import FRAME_EXTENSIONS, check_fps, is_frame_folder, load_frame_folder
from .gltf import GltfAnimation
from .loader import SUPPORTED_EXTENSIONS, load_mesh
from .marbles import Marbles
from .md2 import Md2Model
from .mesh import Mesh, quiet_trimesh
from .subdivide import subdivide_mesh

#: Every file extension :func:`make_scene` accepts (static meshes, glTF, BART, MD2).
SCENE_EXTENSIONS = SUPPORTED_EXTENSIONS + (".aff", ".md2")

#: The procedural scenes, whose size is ``count``.
PROCEDURAL_SCENES = {
    "marbles": "rigid marbles bouncing in a box; count = exact triangle count (default 8800)",
    "icosphere": "unit icosphere; count = approximate triangle count, 20*4^k (default 5120)",
}

#: Scene names and what each is, the one list of names every command takes (``--scene`` and the
#: benchmarks' scene specs): the procedural ones (``count`` = their size), the shipped assets
#: (:data:`ASSET_SCENES`) and the development data set's other scenes (:data:`DATA_SCENES`, where
#: that data set is present); the real ones are fixed files: ``count`` does not apply.
BUILTIN_SCENES = {
    **PROCEDURAL_SCENES,
    **{name: what for name, (_, what) in ASSET_SCENES.items()},
    **{name: f"{what}; development data set" for name, (_, what) in DATA_SCENES.items()},
}


def scene_choices():
    """What a scene may be, in words: the one list of scene names and formats that ``--help``, the
    error messages and the README quote (a test checks the README's)."""
    return (f"a built-in scene ({', '.join([*PROCEDURAL_SCENES, *ASSET_SCENES])}; with the development data set "
            f"beside the repository also {', '.join(DATA_SCENES)}), a scene file ({', '.join(SCENE_EXTENSIONS)}) "
            f"or a folder of frames f000.obj, f001.obj, ... ({', '.join(FRAME_EXTENSIONS)})")


def named_scene_file(name, count=None):
    """The file behind the real scene called ``name`` (a key of :data:`ASSET_SCENES` or
    :data:`DATA_SCENES`), refusing ``count`` (a fixed mesh) and a file that is not there: a data set
    scene's in one line (InputError naming the file and the scenes that ship), a shipped one's as
    an incomplete install (SceneFileError)."""
    if count is not None:
        raise InputError(f"count applies to the marbles and icosphere scenes, not to {name!r} (a fixed "
                         "mesh: subdivide= splits a static one)")
    path = scene_file(name)
    if scene_present(name):
        return path
    if name in ASSET_SCENES:
        raise SceneFileError(path, f"file of the built-in scene {name!r} not found (an incomplete "
                             "gridrt install: its assets folder is missing)")
    why = "GRIDRT_NO_SHARED_DATA hides" if DATA_HIDDEN else "is absent"
    raise InputError(f"scene {name!r} needs {path}, which {why}: a scene of the development data set, which is not "
                     f"part of gridrt; the scenes that ship: {', '.join([*PROCEDURAL_SCENES, *ASSET_SCENES])}")


_ICOSPHERE_DEFAULT = 5120
_ICOSPHERE_MAX_SUBDIVISIONS = 9


class SceneCountWarning(UserWarning):
    """A built-in scene could not make the triangle count asked for; the message says what it made."""


def icosphere_mesh(count=_ICOSPHERE_DEFAULT):
    """A unit icosphere centred at the origin with ``20 * 4**k`` triangles closest to ``count``.

    ``k`` is ``round(log4(count / 20))`` clamped to [0, 9] (20 to 5,242,880 triangles); a count
    beyond the largest icosphere warns (:class:`SceneCountWarning`) with the count made.
    """
    count = _check_count(count)
    k = int(round(math.log(count / 20.0, 4))) if count > 20 else 0
    if k > _ICOSPHERE_MAX_SUBDIVISIONS:
        made = 20 * 4**_ICOSPHERE_MAX_SUBDIVISIONS
        warnings.warn(f"icosphere: count {count:,} is beyond the largest icosphere (20 x 4^"
                      f"{_ICOSPHERE_MAX_SUBDIVISIONS}); made {made:,} triangles", SceneCountWarning, stacklevel=2)
    k = min(max(k, 0), _ICOSPHERE_MAX_SUBDIVISIONS)
    with quiet_trimesh():
        import trimesh  # deferred: trimesh (about 0.6 s to load), for the icosphere only

        ico = trimesh.creation.icosphere(subdivisions=k, radius=1.0)
    return Mesh(np.asarray(ico.vertices), np.asarray(ico.faces), name="icosphere")


def _check_count(count):
    if isinstance(count, (bool, np.bool_)) or not isinstance(count, (Integral, np.integer)):
        raise InputError(f"triangle count must be an integer, got {count!r}")
    if count < 1:
        raise InputError(f"triangle count must be positive, got {count}")
    return int(count)


def _no(option, value, default, what):
    if value is not default and value != default:
        raise InputError(f"{option} does not apply to {what}")


def make_scene(name_or_path, count=None, animate=None, amplitude=None, speed=1.0, seed=0, *,
               clip=None, subdivide=None, fps=None, allow_outside=False):
    """Build an :class:`Animation` from a built-in scene name, a scene file or a folder of frames.

    Parameters
    ----------
    name_or_path : str or os.PathLike
        One of :data:`BUILTIN_SCENES`, a file with one of :data:`SCENE_EXTENSIONS`, or a folder
        of frame meshes (``f000.obj, f001.obj, ...``).  A real scene's name (a shipped asset, or
        a scene of the development data set where it is present) loads its file, with that
        file's options.
    count : int, optional
        Marbles and icosphere only: triangle count (exact for marbles, nearest ``20*4^k`` for
        icosphere).
    animate : {"twist", "wave"}, optional
        Deform a static mesh (mesh file, glTF without animation, or icosphere) over time; see
        :class:`Deform`.  Not for scenes that are animated already.
    amplitude : float, optional
        Deformation amplitude in scene units (default 5% of the bounding-box diagonal).
    speed : float
        Deformation oscillations per second, or the marbles' playback rate.
    seed : int
        Random seed of the marbles scene (ignored by the others).
    clip : int or str, optional
        glTF: the animation to play (index or name; default all animations when they do not
        overlap, else the first).  MD2: a frame-name clip such as ``"run"`` (default all frames).
    subdivide : int, optional
        Static meshes and the icosphere: split every triangle 1 -> 4 until at least this many
        triangles (e.g. Lucy 100k -> 1.6M -> 6.4M); combine with ``animate`` to move it.
    fps : float, optional
        Keyframe rate of MD2 models (default 10) and frame folders (default 30).
    allow_outside : bool
        Trust the files a scene file names (glTF buffers and images, OBJ material libraries and
        textures, BART includes and textures, MD2 skins, a frame folder's files) where they resolve
        outside the scene file's folder (the frame folder), symlinks followed.  By default such a
        geometry file (a buffer, an include, a frame) is a SceneFileError and such a material or
        texture is left out with a TextureWarning; see :mod:`gridrt.scene.files`.

    Raises
    ------
    InputError
        Unknown scene name that is not an existing file (the message lists the built-in names
        and the supported extensions), a development data set scene whose file is absent (names
        the file and the scenes that ship), unknown ``animate`` kind (lists the kinds), unknown
        clip (lists the clips), or an option that does not apply to the chosen scene.
    SceneFileError
        The file cannot be loaded; the message names the file and the problem.
    """
    if not isinstance(name_or_path, (str, os.PathLike)):
        raise InputError(f"scene must be a built-in name or a file path, got {type(name_or_path).__name__}")
    if animate is not None and animate not in DEFORM_KINDS:
        raise InputError(f"unknown animation {animate!r}; choose one of: {', '.join(DEFORM_KINDS)}")
    if fps is not None:
        fps = check_fps(fps)

    key = name_or_path.strip().lower() if isinstance(name_or_path, str) else None
    if key == "marbles":
        return _marbles_scene(count, animate, amplitude, speed, seed, clip, subdivide, fps)
    if animate is None and (amplitude is not None or speed != 1.0):
        raise InputError("amplitude and speed apply only to the marbles and to deformed meshes: pass "
                         "animate='twist' or 'wave' (clip-based scenes play at their own rate)")
    if key == "icosphere":
        _no("clip", clip, None, "the icosphere")
        _no("fps", fps, None, "the icosphere")
        mesh = icosphere_mesh(_ICOSPHERE_DEFAULT if count is None else count)
        return _static_or_deformed(mesh, subdivide, animate, amplitude, speed)

    if key in ASSET_SCENES or key in DATA_SCENES:
        name_or_path = named_scene_file(key, count)
    path = Path(name_or_path)
    ext = path.suffix.lower()
    if not path.exists() and ext not in SCENE_EXTENSIONS:
        raise InputError(f"unknown scene {str(name_or_path)!r}: not a built-in scene and not an existing file or "
                         f"folder; a scene may be {scene_choices()}")
    if count is not None:
        raise InputError("count applies to built-in scenes only, not to scene files")
    return _file_scene(path, animate, amplitude, speed, clip, subdivide, fps, bool(allow_outside))


def _marbles_scene(count, animate, amplitude, speed, seed, clip, subdivide, fps):
    """The built-in marbles scene; the options that do not apply to it are refused."""
    if animate is not None or amplitude is not None:
        raise InputError("the marbles scene is already animated; animate= and amplitude= apply to meshes")
    _no("clip", clip, None, "the marbles scene")
    _no("fps", fps, None, "the marbles scene")
    if subdivide is not None:
        raise InputError("subdivide does not apply to the marbles scene: choose its size with count=")
    return Marbles(8800 if count is None else count, seed=seed, speed=speed)


def _file_scene(path, animate, amplitude, speed, clip, subdivide, fps, allow_outside):
    """The scene in a file or a folder of frames, by its extension; the options that do not apply
    to its kind are refused."""
    what = f"{path.name}"
    if path.is_dir():
        if not is_frame_folder(path):
            raise SceneFileError(path, f"folder holds no frame files ({', '.join(FRAME_EXTENSIONS)})")
        _no("clip", clip, None, "a folder of frames")
        _animated_only(what, animate, subdivide)
        return load_frame_folder(path, fps=30.0 if fps is None else fps, allow_outside=allow_outside)
    ext = path.suffix.lower()
    if ext not in SCENE_EXTENSIONS:
        what_ext = f"unsupported file extension {ext!r}" if ext else "no file extension"
        raise SceneFileError(path, f"{what_ext}; a scene may be {scene_choices()}")
    if ext == ".aff":
        _no("clip", clip, None, "BART scenes")
        _no("fps", fps, None, "BART scenes (their keys are in seconds)")
        _animated_only(what, animate, subdivide)
        return BartAnimation(path, allow_outside=allow_outside)
    if ext == ".md2":
        _animated_only(what, animate, subdivide)
        return Md2Model(path, clip=clip, fps=10.0 if fps is None else fps, allow_outside=allow_outside)
    _no("fps", fps, None, f"{ext or 'mesh'} files")
    if ext in (".gltf", ".glb"):
        if not path.exists():
            raise SceneFileError(path, "file not found")
        scene = GltfAnimation(path, clip=clip, allow_outside=allow_outside)
        keep = animate is None and subdivide is None and (
            scene.clip is not None or scene.camera_at(0.0) is not None or len(scene.lights_at(0.0)) > 0)
        if not scene.static or keep:
            # animated, or only its camera moves, or a still scene with its own camera or lights: keep them
            _animated_only(what, animate, subdivide)
            return scene
        mesh = scene.to_mesh()
    else:
        _no("clip", clip, None, f"{ext or 'mesh'} files (only glTF and MD2 have clips)")
        mesh = load_mesh(path, allow_outside=allow_outside)
    return _static_or_deformed(mesh, subdivide, animate, amplitude, speed)


def _animated_only(what, animate, subdivide):
    if animate is not None:
        raise InputError(f"{what} is animated already; animate= applies to static meshes")
    if subdivide is not None:
        raise InputError(f"subdivide applies to static meshes, not to the animated scene {what}")


def _static_or_deformed(mesh, subdivide, animate, amplitude, speed):
    if subdivide is not None:
        mesh = subdivide_mesh(mesh, subdivide)
    if animate is None:
        return StaticMesh(mesh)
    return Deform(mesh, kind=animate, amplitude=amplitude, speed=speed)
