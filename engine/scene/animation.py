"""The animation protocol: a scene is a pure function from time to triangles.

Every animated scene is an :class:`Animation`.  ``triangles_at(t)`` returns the scene's
triangles at time ``t`` (seconds) as a C-contiguous ``(F, 3, 3) float32`` array, where
``tris[f, j]`` is vertex ``j`` of triangle ``f``; the triangle count ``F`` never changes.

Two rules hold for every subclass:

* **Pure in t.**  The triangles depend only on ``t`` (and the constructor arguments), never on
  which times were asked for before: the same ``t`` gives bitwise the same array in any call order.
* **One reused buffer.**  Without ``out`` an animation writes into a single internal buffer that
  it allocates once, so consecutive calls return the *same* array object (the previous frame is
  overwritten).  Pass ``out`` to keep frames apart.

Instances are not safe to share between Python threads (the internal buffers are shared).
"""

import math
from abc import ABC, abstractmethod
from numbers import Real

import numpy as np
from numba import njit, prange

from ..arrays import TRI_DTYPE
from ..errors import InputError
from .mesh import Mesh

__all__ = ["Animation", "StaticMesh", "check_time", "gather_triangles"]


def check_time(t):
    """Validate a time value; return it as a Python float.

    Raises InputError for non-numbers, booleans, NaN and infinities.
    """
    if isinstance(t, (bool, np.bool_)) or not isinstance(t, (Real, np.integer, np.floating)):
        raise InputError(f"time t must be a real number of seconds, got {t!r}")
    t = float(t)
    if not math.isfinite(t):
        raise InputError(f"time t must be finite, got {t}")
    return t


@njit(cache=True, parallel=True)
def _gather_kernel(vertices, faces, out):
    """out[f, j, :] = vertices[faces[f, j], :] for (V,3) float32 vertices, (F,3) int32 faces."""
    for f in prange(faces.shape[0]):
        for j in range(3):
            v = faces[f, j]
            out[f, j, 0] = vertices[v, 0]
            out[f, j, 1] = vertices[v, 1]
            out[f, j, 2] = vertices[v, 2]


def gather_triangles(vertices, faces, out):
    """Fill ``out`` (F,3,3) float32 with ``vertices[faces]``; return ``out``.

    ``vertices`` (V,3) float32 and ``faces`` (F,3) int32 must already be validated (for example by
    :func:`engine.arrays.as_mesh`): the kernel does no bounds checks.  Only shapes and dtypes are
    re-checked here.
    """
    if vertices.dtype != TRI_DTYPE or vertices.ndim != 2 or vertices.shape[1] != 3:
        raise InputError(f"vertices must be (V, 3) float32, got {vertices.shape} {vertices.dtype}")
    if faces.dtype != np.int32 or faces.ndim != 2 or faces.shape[1] != 3:
        raise InputError(f"faces must be (F, 3) int32, got {faces.shape} {faces.dtype}")
    if out.shape != (len(faces), 3, 3) or out.dtype != TRI_DTYPE:
        raise InputError(f"out must be ({len(faces)}, 3, 3) float32, got {out.shape} {out.dtype}")
    _gather_kernel(vertices, faces, out)
    return out


class Animation(ABC):
    """Base class of every scene: triangles as a pure function of time.

    Attributes
    ----------
    n_triangles : int
        Triangle count F, the same at every t.
    name : str
        Human-readable scene name (shown by the viewer and written to stats files).
    static : bool
        True when the triangles never change with t (the pipeline may then skip rebuilds).
    duration : float or None
        Length in seconds of one loop (``triangles_at(t + duration)`` equals ``triangles_at(t)``
        up to float rounding), or None when the animation does not loop.
    """

    n_triangles: int
    name: str
    static: bool = False
    duration: float | None = None

    _buffer: np.ndarray | None = None

    def triangles_at(self, t, out=None):
        """Return the triangles at time ``t`` seconds, shape (F, 3, 3) float32, C-contiguous.

        Parameters
        ----------
        t : float
            Time in seconds; any finite real number (negative times are allowed).
        out : ndarray, optional
            A writeable C-contiguous (F, 3, 3) float32 array to fill.  When omitted, the
            animation's single internal buffer is filled and returned (the same object on
            every call, so the previous frame is overwritten).

        Raises InputError for a bad ``t`` or a badly shaped/typed ``out``.
        """
        t = check_time(t)
        buf = self._output(out)
        self._fill(t, buf)
        return buf

    def _output(self, out):
        shape = (self.n_triangles, 3, 3)
        if out is None:
            if self._buffer is None:
                self._buffer = np.zeros(shape, dtype=TRI_DTYPE)
            return self._buffer
        if not isinstance(out, np.ndarray):
            raise InputError(f"out must be a numpy array, got {type(out).__name__}")
        if out.shape != shape:
            raise InputError(f"out must have shape {shape}, got {out.shape}")
        if out.dtype != TRI_DTYPE:
            raise InputError(f"out must have dtype float32, got {out.dtype}")
        if not out.flags.c_contiguous:
            raise InputError("out must be C-contiguous")
        if not out.flags.writeable:
            raise InputError("out must be writeable")
        return out

    @abstractmethod
    def _fill(self, t, out):
        """Write the triangles at validated time ``t`` (float) into validated ``out`` (F,3,3) f32."""

    def __repr__(self):
        return f"{type(self).__name__}(name={self.name!r}, n_triangles={self.n_triangles})"


class StaticMesh(Animation):
    """A mesh that does not move: ``triangles_at(t)`` is the same for every t.

    Parameters
    ----------
    mesh : engine.scene.mesh.Mesh
        The validated indexed mesh ((V,3) float32 vertices, (F,3) int32 faces).
    """

    static = True
    duration = None

    def __init__(self, mesh):
        if not isinstance(mesh, Mesh):
            raise InputError(f"StaticMesh needs an engine.scene.Mesh, got {type(mesh).__name__}")
        self.mesh = mesh
        self.name = mesh.name
        self.n_triangles = int(len(mesh.faces))
        self._tris = mesh.triangles()
        self._tris.setflags(write=False)

    def _fill(self, t, out):
        # Copied on every call: a caller may have scribbled on the previously returned buffer.
        np.copyto(out, self._tris)
