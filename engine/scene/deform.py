"""Procedural deformations that animate any static mesh.

Two kinds, both pure functions of ``t`` and periodic with ``duration = 1 / |speed|``:

``"twist"``
    Rotation about the vertical axis through the centre of the mesh's bounding box
    (the line ``x = cx, z = cz``) by an angle that grows linearly with height and oscillates
    in time::

        theta(y, t) = alpha * sin(2 pi speed t) * (y - y_min) / (y_max - y_min)

    ``alpha = amplitude / max_v(rho_v * h_v)`` where ``rho_v`` is a vertex's distance to the axis
    and ``h_v`` its relative height.  A vertex moves along a chord of length
    ``2 rho |sin(theta / 2)| <= rho |theta| <= amplitude``, so no vertex moves farther than
    ``amplitude``; distances to the axis and heights are preserved (up to float32 rounding),
    and at ``t = 0`` the mesh is bitwise at rest.

``"wave"``
    A travelling wave along x that displaces vertices vertically::

        y' = y + amplitude * sin(2 pi (x / wavelength + speed t)),  wavelength = (x_max - x_min) / 2

    so two wave crests fit across the mesh.

The mesh's looks (``Mesh.surface``: materials, textures, uv, colours) move with it.  Its smooth
normals are transformed with the deformation (:meth:`Deform.normals_at`): a normal n at rest point
p becomes ``J^-T n``, normalised, with J the deformation's Jacobian at p, exactly:

* twist, ``k = alpha sin(2 pi speed t) / (y_max - y_min)``: ``J = R(theta) (I + u e_y^T)`` with
  ``u = k (-(z - cz), 0, x - cx)``, so ``n' = R(theta) (n - e_y (u . n))``;
* wave: ``J = I + e_y w^T`` with ``w = (g, 0, 0)``,
  ``g = amplitude 2 pi / wavelength cos(2 pi (x / wavelength + speed t))``, so
  ``n' = (n_x - g n_y, n_y, n_z)``.

A zero normal ("the geometric normal") stays zero.
"""

import math
from numbers import Real

import numpy as np
from numba import njit, prange

from ..arrays import TRI_DTYPE, as_origin
from ..errors import InputError
from .animation import Animation, check_time, gather_unchecked
from .mesh import Mesh

__all__ = ["Deform", "DEFORM_KINDS", "DEFAULT_AMPLITUDE_FRACTION"]

#: Deformation kinds accepted by :class:`Deform` (and ``make_scene(animate=...)``).
DEFORM_KINDS = ("twist", "wave")

#: Default amplitude as a fraction of the mesh's bounding-box diagonal.
DEFAULT_AMPLITUDE_FRACTION = 0.05


@njit(cache=True, parallel=True)
def _twist_kernel(rest, cx, cz, y0, inv_height, angle, origin, out):
    """Twist (V,3) f64 ``rest`` into (V,3) f32 ``out``: rotate about (cx, cz) by angle*(y-y0)*inv_height,
    then move by -origin ((3,) f64) before rounding."""
    ox, oy, oz = origin[0], origin[1], origin[2]
    for v in prange(rest.shape[0]):
        x = rest[v, 0]
        y = rest[v, 1]
        z = rest[v, 2]
        th = angle * (y - y0) * inv_height
        c = math.cos(th) - 1.0
        s = math.sin(th)
        dx = x - cx
        dz = z - cz
        out[v, 0] = (x - ox) + (dx * c - dz * s)
        out[v, 1] = y - oy
        out[v, 2] = (z - oz) + (dx * s + dz * c)


@njit(cache=True, parallel=True)
def _wave_kernel(rest, amplitude, inv_wavelength, phase, origin, out):
    """Wave (V,3) f64 ``rest`` into (V,3) f32 ``out``: y += amplitude*sin(2pi(x*inv_wavelength + phase)),
    then move by -origin ((3,) f64) before rounding."""
    two_pi = 2.0 * math.pi
    for v in prange(rest.shape[0]):
        x = rest[v, 0]
        out[v, 0] = x - origin[0]
        out[v, 1] = (rest[v, 1] - origin[1]) + amplitude * math.sin(two_pi * (x * inv_wavelength + phase))
        out[v, 2] = rest[v, 2] - origin[2]


def _finite_real(value, what):
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (Real, np.integer, np.floating)):
        raise InputError(f"{what} must be a real number, got {value!r}")
    value = float(value)
    if not math.isfinite(value):
        raise InputError(f"{what} must be finite, got {value}")
    return value


class Deform(Animation):
    """Animate a static mesh with a procedural twist or wave (see the module docstring).

    Parameters
    ----------
    mesh : gridrt.scene.Mesh
        The rest pose: (V,3) float32 vertices, (F,3) int32 faces.
    kind : str
        ``"twist"`` or ``"wave"``.
    amplitude : float, optional
        Largest vertex displacement in scene units, > 0.  Default: 5% of the bounding-box diagonal.
    speed : float
        Oscillations per second (non-zero; negative reverses the motion); ``duration = 1/|speed|``.

    Attributes
    ----------
    wavelength : float or None
        Wave length along x (``"wave"`` only): half the mesh's x extent.
    axis : tuple of float
        ``(cx, cz)``, the twist axis (``"twist"`` only; None for waves).
    max_angle : float or None
        ``alpha``, the twist angle in radians at the top of the mesh at full swing.

    Raises InputError for an unknown kind, a non-positive or non-finite amplitude, a zero or
    non-finite speed, or a mesh the deformation cannot move (no height or no radius for a twist,
    no x extent for a wave).
    """

    static = False

    def __init__(self, mesh, kind="twist", amplitude=None, speed=1.0):
        if not isinstance(mesh, Mesh):
            raise InputError(f"Deform needs an gridrt.scene.Mesh, got {type(mesh).__name__}")
        if kind not in DEFORM_KINDS:
            raise InputError(f"unknown deformation kind {kind!r}; choose one of: {', '.join(DEFORM_KINDS)}")
        lo, hi = mesh.bounds()
        if amplitude is None:
            amplitude = DEFAULT_AMPLITUDE_FRACTION * float(np.linalg.norm(hi - lo))
        amplitude = _finite_real(amplitude, "deformation amplitude")
        if amplitude <= 0.0:
            raise InputError(f"deformation amplitude must be > 0, got {amplitude}")
        speed = _finite_real(speed, "deformation speed")
        if speed == 0.0:
            raise InputError("deformation speed must be non-zero (use a static mesh for no motion)")

        self.mesh = mesh
        self.kind = kind
        self.amplitude = amplitude
        self.speed = speed
        self.duration = 1.0 / abs(speed)
        self.name = f"{mesh.name} ({kind})"
        self.n_triangles = mesh.n_triangles
        self.wavelength = None
        self.axis = None
        self.max_angle = None

        v = mesh.vertices64
        if kind == "twist":
            cx, cz = 0.5 * (lo[0] + hi[0]), 0.5 * (lo[2] + hi[2])
            height = hi[1] - lo[1]
            rho = np.hypot(v[:, 0] - cx, v[:, 2] - cz)
            reach = float((rho * (v[:, 1] - lo[1])).max() / height) if height > 0 else 0.0
            if reach <= 0.0:
                raise InputError(
                    f"mesh {mesh.name!r} has no height along y or lies on its vertical axis: "
                    "a twist cannot move it (use kind='wave')"
                )
            self.axis = (float(cx), float(cz))
            self._y0 = float(lo[1])
            self._inv_height = 1.0 / float(height)
            self.max_angle = amplitude / reach
        else:
            extent = float(hi[0] - lo[0])
            if extent <= 0.0:
                raise InputError(f"mesh {mesh.name!r} has no extent along x: a wave along x cannot move it")
            self.wavelength = 0.5 * extent

        self._vertices = np.zeros(mesh.vertices.shape, dtype=TRI_DTYPE)
        self.surface = mesh.surface

    def vertices_at(self, t, out=None, origin=None):
        """Deformed vertices at time ``t``: (V, 3) float32 (in the frame of ``origin``, as
        :meth:`triangles_at`).

        Written into ``out`` ((V,3) float32 C-contiguous) when given, else into an internal
        scratch buffer that is reused on every call.
        """
        t = check_time(t)
        origin = as_origin(origin)
        if out is None:
            out = self._vertices
        elif not (isinstance(out, np.ndarray) and out.shape == self._vertices.shape
                  and out.dtype == TRI_DTYPE and out.flags.c_contiguous and out.flags.writeable):
            raise InputError(f"out must be a writeable C-contiguous {self._vertices.shape} float32 array")
        rest = self.mesh.vertices64
        if self.kind == "twist":
            swing = math.sin(2.0 * math.pi * ((self.speed * t) % 1.0))
            cx, cz = self.axis
            _twist_kernel(rest, cx, cz, self._y0, self._inv_height, self.max_angle * swing, origin, out)
        else:
            _wave_kernel(rest, self.amplitude, 1.0 / self.wavelength, (self.speed * t) % 1.0, origin, out)
        return out

    def _fill(self, t, out, origin):
        gather_unchecked(self.vertices_at(t, origin=origin), self.mesh.faces, out)

    def _fill_normals(self, t, out):
        """The rest normals moved by the deformation at ``t`` (the module docstring's J^-T n),
        per corner in float32 (the per-vertex factors in float64)."""
        n = self.surface.normals
        rest = self.mesh.vertices64
        f = self.mesh.faces
        nx, ny, nz = n[..., 0], n[..., 1], n[..., 2]
        if self.kind == "twist":
            angle = self.max_angle * math.sin(2.0 * math.pi * ((self.speed * t) % 1.0))
            k = angle * self._inv_height
            cx, cz = self.axis
            theta = k * (rest[:, 1] - self._y0)
            c, s = np.cos(theta).astype(TRI_DTYPE)[f], np.sin(theta).astype(TRI_DTYPE)[f]
            # u . n with u = k (-(z - cz), 0, x - cx): k x and k z per vertex
            kx = (k * (rest[:, 0] - cx)).astype(TRI_DTYPE)[f]
            kz = (k * (rest[:, 2] - cz)).astype(TRI_DTYPE)[f]
            out[..., 0] = nx * c - nz * s
            out[..., 1] = ny - (nz * kx - nx * kz)
            out[..., 2] = nx * s + nz * c
        else:
            g = (self.amplitude * 2.0 * math.pi / self.wavelength) * np.cos(
                2.0 * math.pi * (rest[:, 0] / self.wavelength + (self.speed * t) % 1.0))
            out[...] = n
            out[..., 0] -= g.astype(TRI_DTYPE)[f] * ny
        length = np.sqrt((out * out).sum(axis=-1, keepdims=True))
        np.divide(out, length, out=out, where=length > 0)
        return True
