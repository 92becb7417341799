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

Beyond the triangles, every animation describes itself with:

* ``duration`` and ``time_range``: the loop length and the span of the source clip's own clock
  (``clip time = time_range[0] + (t mod duration)`` for clip-based scenes);
* ``static_mask``: which triangles never move, so a renderer may grid them once and rebuild only
  the moving ones every frame;
* ``camera_at(t)``: the scene's own (possibly animated) camera, or None.

Instances are not safe to share between Python threads (the internal buffers are shared).
"""

import math
from abc import ABC, abstractmethod
from numbers import Real

import numpy as np
from numba import njit, prange

from ..arrays import TRI_DTYPE, as_origin, frame_centre
from ..errors import InputError
from .mesh import Mesh
from .surface import no_lights

__all__ = ["Animation", "StaticMesh", "as_static_mask", "check_time", "gather_triangles", "pose_moving_vertices"]


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


@njit(cache=True)
def _gather_serial(vertices, faces, out):
    for f in range(faces.shape[0]):
        for j in range(3):
            v = faces[f, j]
            out[f, j, 0] = vertices[v, 0]
            out[f, j, 1] = vertices[v, 1]
            out[f, j, 2] = vertices[v, 2]


#: Meshes with fewer triangles are gathered on the calling thread (a parallel launch costs more).
GATHER_SERIAL_BELOW = 16384


def as_static_mask(mask, n_triangles, what="static_mask"):
    """Validate a static mask; return it as a read-only (F,) bool array, or None for None.

    Raises InputError when ``mask`` is not a 1-d boolean array of length ``n_triangles``.
    """
    if mask is None:
        return None
    m = np.asarray(mask)
    if m.dtype != np.bool_:
        raise InputError(f"{what} must be a boolean array, got dtype {m.dtype}")
    if m.shape != (n_triangles,):
        raise InputError(f"{what} must have shape ({n_triangles},), got {m.shape}")
    m = m.copy()
    m.setflags(write=False)
    return m


def gather_triangles(vertices, faces, out):
    """Fill ``out`` (F,3,3) float32 with ``vertices[faces]``; return ``out``.

    Checks shapes, dtypes and that every face index lies in [0, V); InputError otherwise.
    """
    if not isinstance(vertices, np.ndarray) or vertices.dtype != TRI_DTYPE or vertices.ndim != 2 \
            or vertices.shape[1] != 3:
        raise InputError(f"vertices must be (V, 3) float32, got {getattr(vertices, 'shape', None)} "
                         f"{getattr(vertices, 'dtype', type(vertices))}")
    if not isinstance(faces, np.ndarray) or faces.dtype != np.int32 or faces.ndim != 2 or faces.shape[1] != 3:
        raise InputError(f"faces must be (F, 3) int32, got {getattr(faces, 'shape', None)} "
                         f"{getattr(faces, 'dtype', type(faces))}")
    if not isinstance(out, np.ndarray) or out.shape != (len(faces), 3, 3) or out.dtype != TRI_DTYPE \
            or not out.flags.c_contiguous or not out.flags.writeable:
        raise InputError(f"out must be a writable C-contiguous ({len(faces)}, 3, 3) float32 array")
    if len(faces):
        lo, hi = int(faces.min()), int(faces.max())
        if lo < 0 or hi >= len(vertices):
            bad = lo if lo < 0 else hi
            raise InputError(f"face index {bad} out of range for {len(vertices)} vertices")
    return gather_unchecked(vertices, faces, out)


def gather_unchecked(vertices, faces, out):
    """gather_triangles for arrays validated once at load time (the per-frame path of the
    loaders, whose faces never change): no checks at all."""
    (_gather_serial if len(faces) < GATHER_SERIAL_BELOW else _gather_kernel)(vertices, faces, out)
    return out


def pose_moving_vertices(scene, clip_time, origin):
    """Bring ``scene._verts`` to ``clip_time`` in the frame of ``origin`` for the posed loaders
    (glTF, BART): only the moving vertices (``scene._dynamic_vids``) when the frame is the one the
    buffer is already in, else every vertex (the static ones move with the frame)."""
    if not np.array_equal(origin, scene._posed_origin):
        scene._posed_origin = origin.copy()
        scene._pose(clip_time, np.arange(len(scene._verts), dtype=np.int64))
    elif len(scene._dynamic_vids):
        scene._pose(clip_time, scene._dynamic_vids)


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
    time_range : tuple of float or None
        ``(start, end)`` of the source clip on its own clock (glTF clip, BART ``a`` line, frame
        sequence), or None.  Clip-based scenes map ``t`` to clip time
        ``start + (t mod duration)``, so ``t = 0`` is the first frame of the clip.
    static_mask : ndarray or None
        None when any triangle may move; else a read-only (F,) bool array, True for triangles
        whose vertices are the same at every t (in the order of ``triangles_at``).  A renderer may
        grid the True triangles once and rebuild only the others every frame.
    """

    n_triangles: int
    name: str
    static: bool = False
    duration: float | None = None
    time_range: tuple | None = None
    static_mask: np.ndarray | None = None

    #: the scene's materials, textures and per-corner attributes (gridrt.scene.surface.Surface), or None
    surface = None

    _buffer: np.ndarray | None = None
    _normal_buffer: np.ndarray | None = None

    def lights_at(self, t):
        """The scene's own lights at time ``t``: an (L, 8) float64 array in world coordinates (see
        gridrt.scene.surface; L = 0 when the scene has none, and renderers then use a default light)."""
        check_time(t)
        return no_lights()

    def normals_at(self, t, out=None):
        """The unit shading normals per triangle corner at time ``t``, (F, 3, 3) float32, or None when
        the scene has none (the geometric normals are then used).  A zero normal stands for the
        geometric normal.  Pure in ``t``; without ``out`` one internal buffer is reused, as
        :meth:`triangles_at` does.  Static scenes return ``surface.normals`` (read-only) as they are."""
        t = check_time(t)
        s = self.surface
        if s is None or s.normals is None:
            return None
        if self.static and out is None:
            return s.normals
        if out is None:
            if self._normal_buffer is None:
                self._normal_buffer = np.zeros((self.n_triangles, 3, 3), TRI_DTYPE)
            out = self._normal_buffer
        elif not (isinstance(out, np.ndarray) and out.shape == (self.n_triangles, 3, 3) and out.dtype == TRI_DTYPE
                  and out.flags.c_contiguous and out.flags.writeable):
            raise InputError(f"out must be a writable C-contiguous ({self.n_triangles}, 3, 3) float32 array")
        if self.static:
            np.copyto(out, s.normals)
            return out
        return out if self._fill_normals(t, out) else None

    def _fill_normals(self, t, out):
        """Write the normals at validated time ``t`` into ``out``; return False when the scene cannot
        move its normals (the geometric normals are then used).  Loaders with normals override it."""
        return False

    def camera_at(self, t):
        """The scene's own camera at time ``t`` (an :class:`gridrt.camera.Camera`), or None.

        The base class has no camera and returns None; BART scenes return their (animated)
        view and glTF scenes their first perspective camera, if any.
        """
        check_time(t)
        return None

    @property
    def n_static(self):
        """Number of triangles that never move (``static_mask.sum()``; F when ``static``, 0 when no mask)."""
        if self.static:
            return self.n_triangles
        return 0 if self.static_mask is None else int(self.static_mask.sum())

    def triangles_at(self, t, out=None, origin=None):
        """Return the triangles at time ``t`` seconds, shape (F, 3, 3) float32, C-contiguous.

        Parameters
        ----------
        t : float
            Time in seconds; any finite real number (negative times are allowed).
        out : ndarray, optional
            A writeable C-contiguous (F, 3, 3) float32 array to fill.  When omitted, the
            animation's single internal buffer is filled and returned (the same object on
            every call, so the previous frame is overwritten).
        origin : (3,) float, optional
            The frame to return the triangles in: ``world - origin``, computed in float64 and
            rounded to float32 only then, so a scene far from the world origin keeps its detail
            in a frame centred on it.  Default: world coordinates (origin 0).

        Raises InputError for a bad ``t``, a badly shaped/typed ``out`` or a bad ``origin``.
        """
        t = check_time(t)
        buf = self._output(out)
        self._fill(t, buf, as_origin(origin))
        return buf

    def bounds_at(self, t=0.0):
        """``(centre, extent)``: the float64 centre of the scene's bounds at time ``t`` and their
        largest side, measured in a frame centred on a first estimate (so float32 rounding of
        world coordinates far from the origin does not blur them)."""
        c = np.zeros(3)
        buf = np.empty((self.n_triangles, 3, 3), TRI_DTYPE)
        for _ in range(4):  # each pass measures in the previous estimate's frame; 2 suffice in practice
            pts = self.triangles_at(t, out=buf, origin=c).reshape(-1, 3)
            lo = pts.min(axis=0).astype(np.float64)
            hi = pts.max(axis=0).astype(np.float64)
            step = 0.5 * (lo + hi)
            c = c + step
            extent = float((hi - lo).max())
            if np.abs(step).max() <= 1e-3 * max(extent, 1e-300):
                break
        return c, extent

    def frame_origin(self, t=0.0):
        """The origin of the frame a renderer should work in at time ``t``: (3,) float64 zeros when
        the scene's bounds reach within one extent of the world origin (world coordinates then keep
        float32's precision of the scene's own size), else the centre of its bounds."""
        return frame_centre(*self.bounds_at(t))

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
    def _fill(self, t, out, origin):
        """Write the triangles at validated time ``t`` (float) into validated ``out`` (F,3,3) f32,
        in the frame of ``origin`` ((3,) float64): ``float32(world - origin)``."""

    def __repr__(self):
        return f"{type(self).__name__}(name={self.name!r}, n_triangles={self.n_triangles})"


class StaticMesh(Animation):
    """A mesh that does not move: ``triangles_at(t)`` is the same for every t.

    Parameters
    ----------
    mesh : gridrt.scene.mesh.Mesh
        The validated indexed mesh ((V,3) float32 vertices, (F,3) int32 faces).
    """

    static = True
    duration = None

    def __init__(self, mesh):
        if not isinstance(mesh, Mesh):
            raise InputError(f"StaticMesh needs an gridrt.scene.Mesh, got {type(mesh).__name__}")
        self.mesh = mesh
        self.name = mesh.name
        self.n_triangles = int(len(mesh.faces))
        self._tris = mesh.triangles()
        self._tris.setflags(write=False)
        self._local = (np.zeros(3), self._tris)  # (origin, triangles in its frame), last frame asked for
        self.surface = getattr(mesh, "surface", None)
        self.static_mask = as_static_mask(np.ones(self.n_triangles, dtype=bool), self.n_triangles)

    def _fill(self, t, out, origin):
        # Copied on every call: a caller may have scribbled on the previously returned buffer.
        o, tris = self._local
        if not np.array_equal(o, origin):
            tris = self.mesh.triangles(origin)
            tris.setflags(write=False)
            self._local = (origin.copy(), tris)
        np.copyto(out, tris)
