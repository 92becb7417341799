"""Scenes: triangles as a pure function of time.

:func:`make_scene` turns a built-in scene name, a scene file or a folder of frames into an
:class:`Animation`, whose ``triangles_at(t)`` returns (F, 3, 3) float32 triangles:

* ``"marbles"``: rigid marbles bouncing in a box (:class:`Marbles`), ``count`` = exact triangles;
* ``"icosphere"``: a unit icosphere with about ``count`` triangles (static, or deformed with
  ``animate``);
* the real assets that ship with gridrt (``"armadillo"``, ``"teapot"``, ``"cesium_man"``,
  ``"morph_sphere"``, ``"sydney"``, ``"museum"``; see :data:`ASSET_SCENES` and
  ``assets/README.md``) and, where the development data set is present beside the repository,
  its other scenes (``"lucy"``, ``"dragon"``, ``"bunny"``, ``"kitchen"``, ``"robots"``,
  ``"tokyo"``, ``"faerie"``; see :data:`DATA_SCENES`): loaded as their files below;
* a .gltf/.glb file with animations: :class:`GltfAnimation` (node animation, skinning, morph
  targets); without animations it is static;
* a BART .aff file: :class:`BartAnimation` (spline-animated transform hierarchy, ``tpa``
  triangles, animated camera);
* a Quake II .md2 file: :class:`Md2Model` (interpolated keyframes);
* a folder of OBJ/PLY/OFF/STL frames (``f000.obj, f001.obj, ...``): :class:`KeyframeMesh`;
* any other mesh file (.obj/.ply/.stl/.off): the mesh (:class:`StaticMesh`), or the mesh deformed
  by ``animate="twist"|"wave"`` (:class:`Deform`).

Static meshes (and the icosphere) can be split 1 -> 4 to a target triangle count with
``subdivide`` (see :mod:`gridrt.scene.subdivide`).
"""

from .animation import Animation, StaticMesh, gather_triangles
from .assets import ASSET_DIR, ASSET_SCENES, DATA_SCENES, asset_path, scene_file
from .bart import BartAnimation
from .deform import DEFORM_KINDS, Deform
from .frames import FRAME_EXTENSIONS, KeyframeMesh, load_frame_folder
from .gltf import DRACO_HINT, GltfAnimation
from .loader import SUPPORTED_EXTENSIONS, load_mesh
from .make import (
    BUILTIN_SCENES, SCENE_EXTENSIONS, SceneCountWarning, icosphere_mesh, make_scene, named_scene_file, scene_choices,
)
from .marbles import Marbles
from .md2 import Md2Model
from .mesh import Mesh
from .spec import SceneSpec
from .subdivide import subdivide_mesh

__all__ = [
    "ASSET_DIR",
    "ASSET_SCENES",
    "Animation",
    "BUILTIN_SCENES",
    "BartAnimation",
    "DATA_SCENES",
    "DEFORM_KINDS",
    "DRACO_HINT",
    "Deform",
    "FRAME_EXTENSIONS",
    "GltfAnimation",
    "KeyframeMesh",
    "Marbles",
    "Md2Model",
    "Mesh",
    "SCENE_EXTENSIONS",
    "SceneCountWarning",
    "SceneSpec",
    "StaticMesh",
    "SUPPORTED_EXTENSIONS",
    "asset_path",
    "gather_triangles",
    "icosphere_mesh",
    "load_frame_folder",
    "load_mesh",
    "make_scene",
    "named_scene_file",
    "scene_choices",
    "scene_file",
    "subdivide_mesh",
]
