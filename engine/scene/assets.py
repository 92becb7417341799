"""The real meshes and animations that ship with gridrt (the repository's ``assets/``), by name.

Each built-in asset scene is one file of ``assets/`` (origins, licences and checksums in
``assets/README.md``); :func:`gridrt.scene.make_scene` loads it like the file itself, so the
file's options (``clip``, ``fps``, ``subdivide``, ``animate``) apply.  The folder is found in a
wheel install (``gridrt/assets``, pyproject package-data) or else in the source checkout beside
``engine/`` (editable install, running from the repository).
"""

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


#: the asset scenes that do not move (the ones a deformation can animate)
STATIC_ASSETS = ("armadillo", "teapot")


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


def asset_path(name):
    """Path of the file behind a built-in asset scene name (KeyError for other names); the file
    may be missing from a broken install (make_scene then raises SceneFileError naming it)."""
    return ASSET_DIR / ASSET_SCENES[name][0]
