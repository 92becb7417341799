"""Array conventions and the validation done at the Python boundary.

Conventions used throughout the engine:

* triangles: ``(F, 3, 3) float32`` C-contiguous, ``tris[f, j]`` is vertex ``j`` of triangle ``f``.
* vertices: ``(V, 3) float32``; faces: ``(F, 3) int32`` indices into vertices.
* rays: origins and directions ``(N, 3) float64``.

Every function here either returns arrays that kernels may trust or raises
:class:`engine.errors.InputError` naming the problem.
"""

import numpy as np

from .errors import InputError

TRI_DTYPE = np.float32
INDEX_DTYPE = np.int32


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
    for float32, or (unless ``allow_degenerate``) a scene whose triangles all have zero area.
    """
    a = np.asarray(tris)
    if a.dtype == object or not (np.issubdtype(a.dtype, np.floating) or np.issubdtype(a.dtype, np.integer)):
        raise InputError(f"{what} must be a numeric array, got dtype {a.dtype}")
    if a.ndim != 3 or a.shape[1:] != (3, 3):
        raise InputError(f"{what} must have shape (F, 3, 3), got {a.shape}")
    if a.shape[0] == 0:
        raise InputError(f"{what}: the scene is empty (0 triangles)")
    _finite_check(a, what)
    if np.abs(a).max() > 1e30:
        raise InputError(f"{what} have coordinates beyond 1e30, too large for float32")
    out = np.ascontiguousarray(a, dtype=TRI_DTYPE)
    if not allow_degenerate and not (triangle_areas2(out) > 0).any():
        raise InputError(f"{what}: all {len(out)} triangles are degenerate (zero area)")
    return out


def as_mesh(vertices, faces, what="mesh"):
    """Validate an indexed mesh; return ``(vertices (V,3) float32, faces (F,3) int32)``.

    Checks shapes, emptiness, NaN/inf vertices, negative or out-of-range face indices and
    meshes whose triangles all have zero area.
    """
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
    v32 = np.ascontiguousarray(v, dtype=TRI_DTYPE)
    f32 = np.ascontiguousarray(f, dtype=INDEX_DTYPE)
    if not (triangle_areas2(v32[f32]) > 0).any():
        raise InputError(f"{what}: all {len(f32)} triangles are degenerate (zero area)")
    return v32, f32


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
    """InputError for NaN/inf origins or directions, or a zero direction, in rays ``o``, ``d``
    (N, 3) as returned by :func:`check_rays`: a slice of a batch whose first ray is number
    ``first`` (the messages give batch indices).  ``frame``: (3,) float64 origin of the frame the
    rays will be moved into (``o - frame`` must be finite too).  Allocates (N, 3) booleans (and
    for a dtype wider than float64 or a frame beyond 2**969, one (N, 3) float64 array)."""
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
    nonzero = (d[:, 0] != 0) | (d[:, 1] != 0) | (d[:, 2] != 0)  # (4x faster than an axis-1 any)
    if not nonzero.all():
        raise InputError(f"ray direction {int(np.argmin(nonzero)) + first} is the zero vector")


def as_rays(origins, directions):
    """Validate ray arrays; return C-contiguous (N, 3) float64 origins and directions (copies
    unless they already are; batch casts check and convert chunk by chunk instead)."""
    o, d = check_rays(origins, directions)
    check_ray_values(o, d)
    return np.ascontiguousarray(o, dtype=np.float64), np.ascontiguousarray(d, dtype=np.float64)
