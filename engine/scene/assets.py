"""The real meshes and animations known by name: those that ship with gridrt (the repository's
``assets/``) and those of the development data set beside the repository (when present).

Each built-in asset scene is one file of ``assets/`` (origins, licences and checksums in
``assets/README.md``); :func:`gridrt.scene.make_scene` loads it like the file itself, so the
file's options (``clip``, ``fps``, ``subdivide``, ``animate``) apply.  The folder is found in a
wheel install (``gridrt/assets``, pyproject package-data) or else in the source checkout beside
``engine/`` (editable install, running from the repository).

The development data set (``shared/data`` beside the repository, on the development machines; not
part of the repository or of a wheel) holds larger real scenes: :data:`DATA_SCENES` names those that
do not ship.  Its copies of the shipped scenes are the same files (byte for byte; the Armadillo the
same mesh as PLY), so a shipped name means its ``assets/`` file on every machine.
"""

import os
from pathlib import Path

#: name -> (file inside the assets folder, one-line description)
ASSET_SCENES = {
    "armadillo": ("armadillo.ply", "Stanford Armadillo scan, decimated: 52,000 triangles, closed (static)"),
    "teapot": ("teapot.obj", "Utah teapot: 6,320 triangles, not closed (static)"),
    "cesium_man": ("CesiumMan.glb", "Cesium Man, skinned glTF: 4,672 triangles, 2 s walk loop"),
    "morph_sphere": ("AnimatedMorphSphere.gltf", "glTF sphere with 2 morph targets: 960 triangles, 7.2 s loop"),
    "sydney": ("sydney.md2", "Quake II MD2 keyframe model: 679 triangles, 198 frames"),
    "museum": ("museum/museum5.aff", "BART museum: 11,308 triangles, moving art and camera, 6 s"),
}


#: the development data set's scenes that do not ship: name -> (file inside the data set, one-line
#: description).  Their files are absent from a user's clone (see :func:`scene_file`).
DATA_SCENES = {
    "lucy": ("static/lucy/Lucy100k.ply", "Stanford Lucy, decimated: 100,000 triangles, closed (static)"),
    "dragon": ("static/stanford_dragon/dragon.obj", "Stanford dragon: 93,600 triangles, closed (static)"),
    "bunny": ("static/stanford_bunny/stanford-bunny.obj", "Stanford bunny: 69,451 triangles, has holes (static)"),
    "kitchen": ("animated/bart/kitchen/aff/kitchen.aff", "BART kitchen: 110,561 triangles, rigid animation and camera"),
    "robots": ("animated/bart/robots/aff/Robot.aff", "BART robots: 71,708 triangles, ten robots walking in a city"),
    "tokyo": ("animated/littlest_tokyo/LittlestTokyo.glb",
              "Littlest Tokyo, Draco-compressed glTF (needs DracoPy): 141,802 triangles, 10 s clip"),
    "faerie": ("animated/md2_faerie/faerie.md2", "Quake II MD2 keyframe model: 654 triangles, 198 frames"),
}

#: the asset scenes that do not move (the ones a deformation can animate)
STATIC_ASSETS = ("armadillo", "teapot")
#: the data set's scenes that do not move (a deformation can animate them too)
STATIC_DATA_SCENES = ("lucy", "dragon", "bunny")


def _asset_dir():
    """The folder holding the assets: the copy inside the installed package (gridrt/assets) or
    the repository's assets/ (this file is engine/scene/assets.py in a checkout)."""
    here = Path(__file__).resolve()
    for d in (here.parents[1] / "assets", here.parents[2] / "assets"):
        if (d / "README.md").is_file():
            return d
    return here.parents[2] / "assets"  # absent: asset_path names where it looked


#: folder of the shipped assets (README.md with origins and licences, and the files)
ASSET_DIR = _asset_dir()


#: folder of the development data set: shared/data beside the repository (this file is
#: engine/scene/assets.py in a checkout)
DATA_DIR = Path(__file__).resolve().parents[3] / "shared" / "data"
#: GRIDRT_NO_SHARED_DATA (anything but "" or "0") hides the data set, as in a user's clone (the
#: tests' quick run sets it)
DATA_HIDDEN = os.environ.get("GRIDRT_NO_SHARED_DATA", "") not in ("", "0")

def asset_path(name):
    """Path of the file behind a built-in asset scene name (KeyError for other names); the file
    may be missing from a broken install (make_scene then raises SceneFileError naming it)."""
    return ASSET_DIR / ASSET_SCENES[name][0]


def scene_file(name):
    """The file behind a named real scene: its shipped asset (:data:`ASSET_SCENES`) or its file in
    the development data set (:data:`DATA_SCENES`); KeyError for other names.  The file may be
    absent (:func:`scene_present`; :func:`gridrt.scene.make.named_scene_file` says what else there is)."""
    if name in ASSET_SCENES:
        return asset_path(name)
    return DATA_DIR / DATA_SCENES[name][0]


def scene_present(name):
    """Whether the file behind a named real scene (:func:`scene_file`) is there: a data set scene's
    is not where the data set is absent or hidden (:data:`DATA_HIDDEN`)."""
    return not (name in DATA_SCENES and DATA_HIDDEN) and scene_file(name).exists()

