"""gridrt engine: per-frame uniform-grid rebuild and CPU ray casting for animated triangle scenes.

Importing this package sets NUMBA_NUM_THREADS (see :mod:`gridrt.threads`) before numba loads.
"""

from .threads import configure_env as _configure_env

_configure_env()

from .errors import GridrtError, InputError, SceneFileError  # noqa: E402
from .config import GridParams, RenderParams  # noqa: E402
from .camera import Camera  # noqa: E402
from .grid import Grid, GridBuilder, build_grid  # noqa: E402
from .trace import Hits, Renderer, cast_rays, render  # noqa: E402
from .pipeline import Frame, FramePipeline  # noqa: E402
from .api import RayCaster  # noqa: E402
from .instances import RayScene, SceneAllHits, SceneHits  # noqa: E402
from .frame import FrameSpec, ViewSpec  # noqa: E402
from .sensors import DepthCamera, Lidar  # noqa: E402

__all__ = [
    "GridrtError", "InputError", "SceneFileError", "GridParams", "RenderParams", "Camera", "Grid",
    "GridBuilder", "build_grid", "Hits", "Renderer", "cast_rays", "render", "Frame", "FramePipeline",
    "RayCaster", "RayScene", "SceneHits", "SceneAllHits", "FrameSpec", "ViewSpec", "DepthCamera", "Lidar",
]
