"""gridrt engine: per-frame uniform-grid rebuild and CPU ray casting for animated triangle scenes.

Importing this package sets NUMBA_NUM_THREADS (see :mod:`engine.threads`) before numba loads.
"""

from .threads import configure_env as _configure_env

_configure_env()

from .errors import GridrtError, InputError, SceneFileError  # noqa: E402

__all__ = ["GridrtError", "InputError", "SceneFileError"]
