"""Pinhole camera: eye, target, up and vertical field of view, with automatic framing.

Pixel (0, 0) is the top-left pixel; the ray of pixel (x, y) passes through its centre:
``d = normalize(fwd + sx * right + sy * up)`` with
``sx = (2 (x + 0.5) / W - 1) * tan(fov / 2) * W / H`` and ``sy = (1 - 2 (y + 0.5) / H) * tan(fov / 2)``,
where ``fwd = normalize(target - eye)``, ``right = normalize(fwd x up)``, ``up' = right x fwd``.

A camera's ``shift`` (sx0, sy0) moves the image window in its own plane (at unit distance from the
eye): ``d = normalize(fwd + (sx + sx0) * right + (sy + sy0) * up)``.  :meth:`Camera.jittered`
shifts it by a fraction of a pixel, exactly, for progressive anti-aliasing: the basis's forward
row becomes ``fwd + sx0 * right + sy0 * up`` and every ray generator reads it as it is.
"""

import math
from dataclasses import dataclass, replace

import numpy as np
from numba import njit, prange

from .checks import MAX_IMAGE_SIDE, _positive_int
from .errors import InputError
from .memory import check_fits

#: default viewing direction (from target towards eye) for automatic framing
FRAME_DIR = (0.55, 0.45, 1.0)
#: default vertical field of view in degrees (Camera, automatic framing, gridrt.frame.ViewSpec)
DEFAULT_FOV = 45.0
#: default up vector (Camera, automatic framing, gridrt.frame.ViewSpec)
DEFAULT_UP = (0.0, 1.0, 0.0)


#: largest eye/target coordinate magnitude (the scenes' own limit, gridrt.grid.common.BAD_MAGNITUDE)
COORD_LIMIT = 1e30


def _vec3(v, name):
    try:
        a = np.asarray(v, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise InputError(f"camera {name} must be 3 numbers, got {v!r}") from None
    if a.shape != (3,) or not np.isfinite(a).all():
        raise InputError(f"camera {name} must be 3 finite numbers, got {_plain(v)}")
    return a


def _plain(v):
    """``v`` as text with plain numbers (no ``np.float64(...)``)."""
    try:
        return "(" + ", ".join(f"{float(x):g}" for x in np.asarray(v, dtype=np.float64).reshape(-1)) + ")"
    except (TypeError, ValueError):
        return repr(v)


def check_fov(fov):
    """``fov`` (vertical field of view, degrees) as a float in (0, 180); InputError naming the fov otherwise."""
    if isinstance(fov, (bool, np.bool_)):
        raise InputError(f"camera fov must be a number of degrees, got {fov!r}")
    try:
        f = float(fov)
    except (TypeError, ValueError):
        raise InputError(f"camera fov must be a number of degrees, got {fov!r}") from None
    if not (0.0 < f < 180.0):
        raise InputError(f"camera fov must be between 0 and 180 degrees (exclusive), got {f:g}")
    return f


def check_up(up):
    """``up`` as a tuple of 3 finite floats, not all zero; InputError naming the up vector otherwise."""
    u = _vec3(up, "up")
    if _unit(u) is None:
        raise InputError("camera up vector is zero")
    return tuple(u.tolist())


def cross3(a, b):
    """np.cross of two 3-vectors, the same products and differences (so the same bits), without
    its general-shape set-up (about 50 us a call, a camera's basis made twice a frame)."""
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


def _unit(v):
    """``v / |v|``, also where ``|v|`` would overflow or underflow (then ``v`` is first scaled by its
    largest component); None for the zero vector."""
    with np.errstate(over="ignore", under="ignore"):
        n = float(np.linalg.norm(v))
    if 1e-150 < n < 1e150:
        return v / n
    m = float(np.abs(v).max())
    if not m > 0:
        return None
    w = v / m
    return w / float(np.linalg.norm(w))


@njit(cache=True, _nrt=False)
def pixel_dir(basis, W, H, x, y):
    """Unit direction of the ray through the centre of pixel (x, y); basis from Camera.basis."""
    th = basis[4, 0]
    asp = W / H
    sx = (2.0 * (x + 0.5) / W - 1.0) * th * asp
    sy = (1.0 - 2.0 * (y + 0.5) / H) * th
    dx = basis[1, 0] + sx * basis[2, 0] + sy * basis[3, 0]
    dy = basis[1, 1] + sx * basis[2, 1] + sy * basis[3, 1]
    dz = basis[1, 2] + sx * basis[2, 2] + sy * basis[3, 2]
    n = math.sqrt(dx * dx + dy * dy + dz * dz)
    return dx / n, dy / n, dz / n


@njit(cache=True, parallel=True)
def _fill_rays(basis, W, H, origins, dirs):
    for y in prange(H):
        for x in range(W):
            i = y * W + x
            dx, dy, dz = pixel_dir(basis, W, H, x, np.int64(y))
            origins[i, 0] = basis[0, 0]
            origins[i, 1] = basis[0, 1]
            origins[i, 2] = basis[0, 2]
            dirs[i, 0] = dx
            dirs[i, 1] = dy
            dirs[i, 2] = dz


@dataclass(frozen=True)
class Camera:
    """Pinhole camera. eye, target, up: 3 floats each; fov: vertical field of view in degrees."""

    eye: tuple = (0.0, 0.0, 5.0)
    target: tuple = (0.0, 0.0, 0.0)
    up: tuple = DEFAULT_UP
    fov: float = DEFAULT_FOV
    #: the image window's shift in its plane at unit distance, (right, up); (0, 0): centred
    shift: tuple = (0.0, 0.0)

    def __post_init__(self):
        eye = _vec3(self.eye, "eye")
        target = _vec3(self.target, "target")
        up = _vec3(self.up, "up")
        fov = check_fov(self.fov)
        for name, p in (("eye", eye), ("target", target)):
            if np.abs(p).max() > COORD_LIMIT:
                raise InputError(f"camera {name} {_plain(p)} is beyond the coordinate limit of "
                                 f"{COORD_LIMIT:g} (the limit for scene coordinates too)")
        fwd = _unit(target - eye)
        if fwd is None:
            raise InputError("camera eye and target coincide")
        u = _unit(up)
        if u is None:
            raise InputError("camera up vector is zero")
        if np.linalg.norm(cross3(fwd, u)) < 1e-9:
            raise InputError("camera up vector is parallel to the viewing direction")
        object.__setattr__(self, "eye", tuple(eye.tolist()))
        object.__setattr__(self, "target", tuple(target.tolist()))
        object.__setattr__(self, "up", tuple(up.tolist()))
        object.__setattr__(self, "fov", fov)
        try:
            shift = tuple(float(v) for v in self.shift)
        except (TypeError, ValueError):
            raise InputError(f"camera shift must be 2 numbers, got {self.shift!r}") from None
        if len(shift) != 2 or not all(math.isfinite(v) and abs(v) <= 1e6 for v in shift):
            raise InputError(f"camera shift must be 2 finite numbers of magnitude at most 1e6, got {self.shift!r}")
        object.__setattr__(self, "shift", shift)

    @classmethod
    def frame(cls, lo, hi, fov=DEFAULT_FOV, direction=FRAME_DIR, up=DEFAULT_UP):
        """A camera looking at the centre of the box [lo, hi] from ``direction``, far enough
        that the box's bounding sphere fits the vertical field of view (with a 5% margin)."""
        fov = check_fov(fov)
        lo = np.asarray(lo, np.float64)
        hi = np.asarray(hi, np.float64)
        c = 0.5 * (lo + hi)
        r = 0.5 * float(np.linalg.norm(hi - lo))
        if r == 0:
            r = max(1e-6 * float(np.abs(c).max()), 1e-12)
        d = _unit(np.asarray(direction, np.float64))
        if d is None:
            raise InputError("camera framing direction is the zero vector")
        dist = r / math.sin(math.radians(fov) / 2) * 1.05
        eye = c + d * dist
        if not np.abs(eye).max() <= COORD_LIMIT:
            raise InputError(f"camera fov {fov:g} is too narrow to frame a scene {2 * r:.3g} across: the camera "
                             f"would stand {dist:.3g} away, beyond the coordinate limit of {COORD_LIMIT:g}")
        return cls(eye=tuple(eye.tolist()), target=tuple(c.tolist()), up=tuple(up), fov=fov)

    def basis(self):
        """(5, 3) float64: eye, fwd, right, up, [tan(fov/2), 0, 0] for the kernels."""
        eye = np.asarray(self.eye)
        fwd = _unit(np.asarray(self.target) - eye)
        up = np.asarray(self.up)
        with np.errstate(over="ignore", under="ignore"):
            if not 1e-150 < np.linalg.norm(up) < 1e150:  # a huge or tiny up vector: scale it first
                up = _unit(up)
        right = _unit(cross3(fwd, up))
        up = cross3(right, fwd)
        b = np.zeros((5, 3))
        b[0], b[1], b[2], b[3] = eye, fwd, right, up
        if self.shift != (0.0, 0.0):
            b[1] = fwd + self.shift[0] * right + self.shift[1] * up
        b[4, 0] = math.tan(math.radians(self.fov) / 2)
        return b

    def jittered(self, width, height, jx, jy):
        """This camera with its pixel grid moved by (jx, jy) pixels (right, down) at width x height:
        the ray of pixel (x, y) passes through the point (x + 0.5 + jx, y + 0.5 + jy) of its image,
        exactly (the shift adds to sx and sy alike for every pixel)."""
        th = math.tan(math.radians(self.fov) / 2)
        return replace(self, shift=(self.shift[0] + 2.0 * float(jx) / width * th * width / height,
                                    self.shift[1] - 2.0 * float(jy) / height * th))

    def rays(self, width, height):
        """Primary rays, row-major from the top-left pixel: (origins, dirs), each (H*W, 3) float64;
        InputError before allocating when their 48 bytes a pixel exceed the memory left
        (gridrt.memory)."""
        W = _positive_int("image width", width, 1, MAX_IMAGE_SIDE)
        H = _positive_int("image height", height, 1, MAX_IMAGE_SIDE)
        check_fits(48 * W * H, f"making the primary rays of {W:,}x{H:,} pixels", "float64 origins and directions",
                   lambda avail: f"ask for at most {avail // 48:,} pixels")
        o = np.empty((W * H, 3))
        d = np.empty((W * H, 3))
        _fill_rays(self.basis(), W, H, o, d)
        return o, d

    def moved(self, offset):
        """The same view with eye and target moved by ``offset`` (3 floats), in float64: the camera
        in a frame whose origin lies at ``-offset`` (e.g. ``cam.moved(-origin)`` for a scene
        rendered in world - origin)."""
        o = np.asarray(offset, np.float64)
        if not o.any():
            return self
        return Camera(eye=tuple(np.asarray(self.eye) + o), target=tuple(np.asarray(self.target) + o),
                      up=self.up, fov=self.fov, shift=self.shift)

    def replace(self, **kw):
        return replace(self, **kw)
