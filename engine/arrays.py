"""Array conventions and the validation done at the Python boundary.

Conventions used throughout the engine:

* triangles: ``(F, 3, 3) float32`` C-contiguous, ``tris[f, j]`` is vertex ``j`` of triangle ``f``.
* vertices: ``(V, 3) float32``; faces: ``(F, 3) int32`` indices into vertices.
* rays: origins and directions ``(N, 3) float64``.

Every function here either returns arrays that kernels may trust or raises
:class:`gridrt.errors.InputError` naming the problem.
"""

import numpy as np

from .errors import InputError

TRI_DTYPE = np.float32
INDEX_DTYPE = np.int32
#: the largest coordinate magnitude of scenes, cameras and ray origins (gridrt.camera.COORD_LIMIT)
COORD_LIMIT = 1e30


def read_only(a):
    """A read-only view of a (no copy).  numba types a read-only array apart from a writable one:
    a record whose arrays may come from either (a file's buffer, a caller's array, an array made
    here) gets read-only views of all of them, so that its kernels compile once."""
    v = a.view()
    v.flags.writeable = False
    return v


def _finite_check(a, what):
    if not np.isfinite(a).all():
        bad = np.argwhere(~np.isfinite(a))[0]
        raise InputError(f"{what} contain NaN or infinity (first at index {tuple(int(i) for i in bad)})")


def triangle_areas2(tris):
    """Twice the area of each triangle, float64, shape (F,)."""
    t = np.asarray(tris, dtype=np.float64)
    n = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
    return np.sqrt((n * n).sum(axis=1))


def as_triangles(tris, what="triangles", allow_degenerate=True):
    """Return ``tris`` as a validated C-contiguous (F, 3, 3) float32 array.

    Raises InputError for a wrong shape, an empty array, non-finite values, values too large
    for float32, or (unless ``allow_degenerate``) a scene whose triangles all have zero area
    (judged in a frame centred on the scene).
    """
    return np.ascontiguousarray(as_triangles64(tris, what, allow_degenerate), dtype=TRI_DTYPE)


def triangle_array(tris, what="triangles"):
    """``tris`` as an (F, 3, 3) real-valued array with F > 0, or InputError; reads no values (see
    :func:`refuse_bad_values` for those)."""
    a = np.asarray(tris)
    if a.dtype == object or not (np.issubdtype(a.dtype, np.floating) or np.issubdtype(a.dtype, np.integer)):
        raise InputError(f"{what} must be a numeric array, got dtype {a.dtype}")
    if a.ndim != 3 or a.shape[1:] != (3, 3):
        raise InputError(f"{what} must have shape (F, 3, 3), got {a.shape}")
    if a.shape[0] == 0:
        raise InputError(f"{what}: the scene is empty (0 triangles)")
    return a


def float_contiguous(a):
    """A real array as a C-contiguous float32 array when it is float32 (no copy when it already is
    one), else float64: what the one-pass bounds kernels take (gridrt.grid.common.point_bounds)."""
    return np.ascontiguousarray(a, dtype=np.float32 if a.dtype == np.float32 else np.float64)


def refuse_bad_values(a, what="triangles"):
    """InputError naming the first NaN or infinity of ``a``, or its coordinates beyond 1e30; returns
    when there are none."""
    _finite_check(a, what)
    if np.abs(a).max() > 1e30:
        raise InputError(f"{what} have coordinates beyond 1e30, too large for float32")


def as_triangles64(tris, what="triangles", allow_degenerate=True):
    """:func:`as_triangles`, but the triangles are returned as given, in float64."""
    a = triangle_array(tris, what)
    refuse_bad_values(a, what)
    out = np.ascontiguousarray(a, dtype=np.float64)
    if not allow_degenerate:
        local = (out - bounds_centre(out)).astype(TRI_DTYPE)
        if not (triangle_areas2(local) > 0).any():
            raise InputError(f"{what}: all {len(out)} triangles are degenerate (zero area)")
    return out


def as_mesh64(vertices, faces, what="mesh"):
    """Validate an indexed mesh; return ``(vertices (V,3) float64, faces (F,3) int32)``, the
    vertices exactly as given (see :func:`as_mesh`)."""
    v = np.asarray(vertices)
    f = np.asarray(faces)
    if v.ndim != 2 or v.shape[1] != 3:
        raise InputError(f"{what}: vertices must have shape (V, 3), got {v.shape}")
    if not np.issubdtype(v.dtype, np.number) or np.issubdtype(v.dtype, np.complexfloating):
        raise InputError(f"{what}: vertices must be real numbers, got dtype {v.dtype}")
    if f.ndim != 2 or f.shape[1] != 3:
        raise InputError(f"{what}: faces must have shape (F, 3), got {f.shape}")
    if len(v) == 0 or len(f) == 0:
        raise InputError(f"{what} is empty ({len(v)} vertices, {len(f)} faces)")
    if not np.issubdtype(f.dtype, np.integer):
        if np.issubdtype(f.dtype, np.floating) and np.isfinite(f).all() and (f == np.round(f)).all():
            f = f.astype(np.int64)
        else:
            raise InputError(f"{what}: face indices must be integers, got dtype {f.dtype}")
    _finite_check(v, f"{what}: vertices")
    if np.abs(v).max() > 1e30:
        raise InputError(f"{what}: vertex coordinates beyond 1e30, too large for float32")
    fmin, fmax = int(f.min()), int(f.max())
    if fmin < 0:
        raise InputError(f"{what}: negative face index {fmin} (face {int(np.argmin(f.min(axis=1)))})")
    if fmax >= len(v):
        raise InputError(
            f"{what}: face index {fmax} out of range for {len(v)} vertices "
            f"(face {int(np.argmax(f.max(axis=1)))})"
        )
    if len(v) > np.iinfo(np.int32).max or len(f) > np.iinfo(np.int32).max:
        raise InputError(f"{what}: too many vertices or faces for int32 indices")
    v64 = np.ascontiguousarray(v, dtype=np.float64)
    f32 = np.ascontiguousarray(f, dtype=INDEX_DTYPE)
    # degeneracy is judged in a frame centred on the mesh (as every renderer sees it), so a mesh far
    # from the world origin is not refused because float32 world coordinates would collapse it
    local = (v64 - bounds_centre(v64)).astype(TRI_DTYPE)
    if not (triangle_areas2(local[f32]) > 0).any():
        raise InputError(f"{what}: all {len(f32)} triangles are degenerate (zero area)")
    return v64, f32


def as_mesh(vertices, faces, what="mesh"):
    """Validate an indexed mesh; return ``(vertices (V,3) float32, faces (F,3) int32)``.

    Checks shapes, emptiness, NaN/inf vertices, negative or out-of-range face indices and
    meshes whose triangles all have zero area (in a frame centred on the mesh).
    """
    v64, f32 = as_mesh64(vertices, faces, what)
    return v64.astype(TRI_DTYPE), f32


def bounds_centre(points):
    """Float64 centre of the axis-aligned bounds of (..., 3) points ((3,) zeros when empty)."""
    p = np.asarray(points, np.float64).reshape(-1, 3)
    if len(p) == 0:
        return np.zeros(3)
    return 0.5 * (p.min(axis=0) + p.max(axis=0))


def storage_centre(points):
    """Where to centre float32 storage of float64 ``points`` (..., 3): (3,) zeros when the points'
    bounds reach within one extent of the world origin (float32 world coordinates then keep the
    precision of the scene's own size), else the bounds' centre (far away: store ``p - centre``)."""
    p = np.asarray(points, np.float64).reshape(-1, 3)
    if len(p) == 0:
        return np.zeros(3)
    lo, hi = p.min(axis=0), p.max(axis=0)
    return frame_centre(0.5 * (lo + hi), float((hi - lo).max()))


def frame_centre(centre, extent):
    """The one rule for where a frame centred on a scene sits: (3,) zeros when bounds with this
    ``centre`` and largest side ``extent`` reach within one extent of the world origin (world
    coordinates are then as precise), else ``centre``."""
    return np.zeros(3) if np.abs(centre).max() <= extent else np.asarray(centre, np.float64)


def as_origin(origin):
    """Validate a frame origin: None -> (3,) zeros; else 3 finite numbers as (3,) float64."""
    if origin is None:
        return np.zeros(3)
    try:
        o = np.asarray(origin, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise InputError(f"frame origin must be 3 numbers, got {origin!r}") from None
    if o.shape != (3,) or not np.isfinite(o).all():
        raise InputError(f"frame origin must be 3 finite numbers, got {origin!r}")
    return o


def check_rays(origins, directions):
    """Check the shape and dtype of ray arrays without copying them; return them as arrays
    (any strides, any real dtype).  :func:`check_ray_values` checks their values."""
    o = np.asarray(origins)
    d = np.asarray(directions)
    for a, name in ((o, "ray origins"), (d, "ray directions")):
        if a.ndim != 2 or a.shape[1] != 3:
            raise InputError(f"{name} must have shape (N, 3), got {a.shape}")
        if not np.issubdtype(a.dtype, np.number) or np.issubdtype(a.dtype, np.complexfloating):
            raise InputError(f"{name} must be real numbers, got dtype {a.dtype}")
    if o.shape != d.shape:
        raise InputError(f"ray origins {o.shape} and directions {d.shape} differ in shape")
    return o, d


def check_ray_values(o, d, first=0, frame=None):
    """InputError for NaN/inf origins or directions, origins beyond COORD_LIMIT, or a zero
    direction, in rays ``o``, ``d`` (N, 3) as returned by :func:`check_rays`: a slice of a batch
    whose first ray is number ``first`` (the messages give batch indices).  ``frame``: (3,)
    float64 origin of the frame the rays will be moved into (``o - frame`` must be finite too).
    Allocates (N, 3) booleans (and for a dtype wider than float64 or a frame beyond 2**969, one
    (N, 3) float64 array)."""
    for a, name in ((o, "ray origins"), (d, "ray directions")):
        if a.dtype.kind != "f":
            continue
        with np.errstate(over="ignore"):
            finite = np.isfinite(a if a.dtype.itemsize <= 8 else a.astype(np.float64))
        if not finite.all():
            bad = np.argwhere(~finite)[0]
            raise InputError(f"{name} contain NaN or infinity (first at index ({int(bad[0]) + first}, {int(bad[1])}))")
    if frame is not None and float(np.abs(frame).max()) >= 2.0**969:
        # (a frame within 2**969, under half an ulp of float64's largest value, cannot make a
        # finite o - frame overflow)
        with np.errstate(over="ignore"):
            moved = np.subtract(o, frame, dtype=np.float64)
        if not np.isfinite(moved).all():
            bad = np.argwhere(~np.isfinite(moved))[0]
            raise InputError(f"ray origin {int(bad[0]) + first} is beyond float64 range once moved into the frame "
                             f"centred at {tuple(float(x) for x in frame)}")
    if len(o) and not max(float(o.max()), -float(o.min())) <= COORD_LIMIT:  # (no temporaries)
        bad = int(np.argmax(np.abs(o).max(axis=1)))
        raise InputError(f"ray origin {bad + first} {tuple(float(x) for x in o[bad])} is beyond the coordinate limit "
                         f"of {COORD_LIMIT:g} (the limit for scene and camera coordinates too)")
    nonzero = (d[:, 0] != 0) | (d[:, 1] != 0) | (d[:, 2] != 0)  # (4x faster than an axis-1 any)
    if not nonzero.all():
        raise InputError(f"ray direction {int(np.argmin(nonzero)) + first} is the zero vector")


def as_rays(origins, directions):
    """Validate ray arrays; return C-contiguous (N, 3) float64 origins and directions (copies
    unless they already are; batch casts check and convert chunk by chunk instead)."""
    o, d = check_rays(origins, directions)
    check_ray_values(o, d)
    return np.ascontiguousarray(o, dtype=np.float64), np.ascontiguousarray(d, dtype=np.float64)
