"""Procedural "Marbles" scene: rigid marbles bouncing in a box, any triangle count.

A stand-in for the Marbles benchmark of Wald et al., "Ray Tracing Animated Scenes using
Coherent Grid Traversal" (SIGGRAPH 2006) and Ize et al. (IEEE RT 2006), which had about 8.8k
triangles.  The motion is analytic, so ``triangles_at(t)`` is a pure function of ``t``:

* every marble is an icosphere (subdivision 2, 320 triangles) of radius :attr:`Marbles.radius`;
* horizontally (x and z) it moves at constant speed and reflects off the walls: the centre
  follows a triangle wave between ``-L + r`` and ``L - r``;
* vertically it bounces on the floor under gravity ``g``: within each bounce period ``T`` the
  centre height is ``r + 4 h p (1 - p)`` with phase ``p`` in [0, 1) and apex height ``h = g T^2 / 8``
  (a parabola with acceleration ``-g``);
* it spins about a fixed random axis at a constant rate.

Marbles do not collide with each other (they may pass through one another).

All frequencies are integer multiples of ``1 / duration`` (8 s at speed 1), so the scene loops.
The floor, a triangulated square at y = 0 covering the box, takes the triangles left over,
which makes the triangle count exact.
"""

import math
from numbers import Integral, Real

import numpy as np
from numba import njit, prange

from ..errors import InputError
from .animation import Animation, as_static_mask, check_time
from .icosphere import icosphere_triangles

__all__ = ["Marbles"]

TRIS_PER_MARBLE = 320
FLOOR_TARGET = 160
MIN_TRIANGLES = TRIS_PER_MARBLE + 2
MAX_TRIANGLES = 50_000_000

_LOOP_SECONDS = 8.0
_BOUNCE_CYCLES = (4, 8)  # bounces per loop, inclusive range: periods of 1..2 s
_MOVE_CYCLES = (-2, -1, 1, 2)  # wall-to-wall round trips per loop, per horizontal axis
_SPIN_CYCLES = (-3, -2, -1, 1, 2, 3)  # turns per loop
_WALL_GAP = 1e-3  # marbles keep this fraction of their radius away from walls and floor


def _icosphere_triangles(radius):
    """(320, 3, 3) float64 triangles of a subdivision-2 icosphere centred at the origin (trimesh's,
    built without importing trimesh: the default scene starts faster)."""
    return icosphere_triangles(2, radius)


def _band(x_lo, x_hi, z0, z1, count):
    """``count`` >= 2 triangles tiling the rectangle [x_lo, x_hi] x [z0, z1] at y = 0.

    The bottom edge gets ``count // 2 + 1`` evenly spaced points and the top edge the rest
    (``count - count // 2 + 1``); the two rows are stitched in x order, so any count is possible.
    """
    nb = count // 2 + 1
    nt = count - count // 2 + 1
    xb = np.linspace(x_lo, x_hi, nb)
    xt = np.linspace(x_lo, x_hi, nt)
    tris = []
    i = j = 0
    while i < nb - 1 or j < nt - 1:
        if j == nt - 1 or (i < nb - 1 and xb[i + 1] <= xt[j + 1]):
            tris.append(((xb[i], z0), (xb[i + 1], z0), (xt[j], z1)))
            i += 1
        else:
            tris.append(((xb[i], z0), (xt[j + 1], z1), (xt[j], z1)))
            j += 1
    xz = np.array(tris, dtype=np.float64)
    out = np.zeros((count, 3, 3))
    out[:, :, 0] = xz[:, :, 0]
    out[:, :, 2] = xz[:, :, 1]
    return out


def floor_triangles(count, half):
    """``count`` >= 2 triangles (count, 3, 3) float64 tiling the square [-half, half]^2 at y = 0.

    The square is cut into about sqrt(count / 2) bands along z, each tiled by :func:`_band`.
    Every triangle faces +y (counter-clockwise seen from above).
    """
    rows = max(1, min(count // 2, int(round(math.sqrt(count / 2.0)))))
    per_row = [count // rows + (1 if r < count % rows else 0) for r in range(rows)]
    z = np.linspace(-half, half, rows + 1)
    tris = np.concatenate([_band(-half, half, z[r], z[r + 1], c) for r, c in enumerate(per_row)])
    e1 = tris[:, 1] - tris[:, 0]
    e2 = tris[:, 2] - tris[:, 0]
    ny = e1[:, 2] * e2[:, 0] - e1[:, 0] * e2[:, 2]
    flip = ny < 0
    tris[flip, 1], tris[flip, 2] = tris[flip, 2].copy(), tris[flip, 1].copy()
    return tris


@njit(cache=True, inline="always")
def _floor_into(floor, origin, out):
    """The floor triangles (N,3,3) f64 into out[:N], less origin."""
    for f in range(floor.shape[0]):
        for j in range(3):
            for c in range(3):
                out[f, j, c] = floor[f, j, c] - origin[c]


@njit(cache=True, inline="always")
def _marble_into(i, base, rot, centre, origin, out, o):
    """Marble i (base (B,3,3) f64 turned by rot[i] and moved to centre[i]) into out[o:o+B], less
    origin."""
    r00, r01, r02 = rot[i, 0, 0], rot[i, 0, 1], rot[i, 0, 2]
    r10, r11, r12 = rot[i, 1, 0], rot[i, 1, 1], rot[i, 1, 2]
    r20, r21, r22 = rot[i, 2, 0], rot[i, 2, 1], rot[i, 2, 2]
    cx, cy, cz = centre[i, 0] - origin[0], centre[i, 1] - origin[1], centre[i, 2] - origin[2]
    for k in range(base.shape[0]):
        for j in range(3):
            x = base[k, j, 0]
            y = base[k, j, 1]
            z = base[k, j, 2]
            out[o + k, j, 0] = r00 * x + r01 * y + r02 * z + cx
            out[o + k, j, 1] = r10 * x + r11 * y + r12 * z + cy
            out[o + k, j, 2] = r20 * x + r21 * y + r22 * z + cz


@njit(cache=True, parallel=True)
def _marbles_kernel(base, rot, centre, floor, origin, out):
    """Write floor then rigidly moved marbles into ``out``, in the frame of ``origin``, the
    marbles in parallel.

    base (B,3,3) f64 marble triangles about the origin; rot (M,3,3) f64 rotations; centre (M,3) f64;
    floor (N,3,3) f64; origin (3,) f64; out (N + M*B, 3, 3) f32 = world - origin.  Marble i
    occupies out[N + i*B : N + (i+1)*B].
    """
    _floor_into(floor, origin, out)
    nf, nb = floor.shape[0], base.shape[0]
    for i in prange(rot.shape[0]):
        _marble_into(i, base, rot, centre, origin, out, nf + i * nb)


@njit(cache=True)
def _marbles_serial(base, rot, centre, floor, origin, out):
    """_marbles_kernel on the calling thread (the same values)."""
    _floor_into(floor, origin, out)
    nf, nb = floor.shape[0], base.shape[0]
    for i in range(rot.shape[0]):
        _marble_into(i, base, rot, centre, origin, out, nf + i * nb)


#: Scenes with fewer triangles are filled on the calling thread: a parallel launch costs more
#: than the work, and the serial kernel compiles in a fraction of the parallel one's time.
MARBLES_SERIAL_BELOW = 65536


def _rotations(axis, angle):
    """Rodrigues: (M,3) unit axes, (M,) angles -> (M,3,3) float64 rotation matrices."""
    c = np.cos(angle)[:, None, None]
    s = np.sin(angle)[:, None, None]
    x, y, z = axis[:, 0], axis[:, 1], axis[:, 2]
    zero = np.zeros_like(x)
    k = np.stack([zero, -z, y, z, zero, -x, -y, x, zero], axis=1).reshape(-1, 3, 3)
    outer = axis[:, :, None] * axis[:, None, :]
    return c * np.eye(3) + s * k + (1.0 - c) * outer


class Marbles(Animation):
    """Rigid icosphere marbles bouncing under gravity in a box, with a floor.

    Parameters
    ----------
    n_triangles : int
        Exact total triangle count, from 322 to 50,000,000.  The scene has
        ``max(1, (n_triangles - 160) // 320)`` marbles of 320 triangles; the floor takes the
        rest (160 to 479 triangles, or fewer for tiny scenes).  The default 8800 is 27 marbles
        plus a 160-triangle floor.
    seed : int
        Seed of the random start positions, speeds, bounce rates and spin axes.
    speed : float
        Playback rate (non-zero; negative plays backwards): the scene at time ``t`` is the
        speed-1 scene at time ``speed * t``.

    Attributes
    ----------
    n_marbles, n_floor : int
        Marble count and floor triangle count.  Triangles ``[0, n_floor)`` are the floor;
        marble ``i`` owns ``[n_floor + 320 i, n_floor + 320 (i + 1))``.
    radius : float
        Marble radius (1 scene unit).
    box_lo, box_hi : ndarray
        (3,) float64 corners of the box; the floor is at ``y = box_lo[1] = 0``.  Every marble
        stays inside the box at all times.
    gravity : float
        Downward acceleration of the marbles (scene units / s^2), including the ``speed^2`` factor.
    duration : float
        Loop length in seconds (``8 / |speed|``).
    static_mask : ndarray
        (F,) bool, True for the floor triangles ``[0, n_floor)``.
    """

    static = False

    def __init__(self, n_triangles=8800, seed=0, speed=1.0):
        if isinstance(n_triangles, bool) or not isinstance(n_triangles, (Integral, np.integer)):
            raise InputError(f"marbles: triangle count must be an integer, got {n_triangles!r}")
        n = int(n_triangles)
        if not MIN_TRIANGLES <= n <= MAX_TRIANGLES:
            raise InputError(
                f"marbles: triangle count must be between {MIN_TRIANGLES} and {MAX_TRIANGLES:,}, got {n}"
            )
        if isinstance(seed, bool) or not isinstance(seed, (Integral, np.integer)) or seed < 0:
            raise InputError(f"marbles: seed must be a non-negative integer, got {seed!r}")
        if isinstance(speed, (bool, np.bool_)) or not isinstance(speed, (Real, np.integer, np.floating)):
            raise InputError(f"marbles: speed must be a real number, got {speed!r}")
        speed = float(speed)
        if not math.isfinite(speed) or speed == 0.0:
            raise InputError(f"marbles: speed must be finite and non-zero, got {speed}")

        self.name = "marbles"
        self.n_triangles = n
        self.speed = speed
        self.duration = _LOOP_SECONDS / abs(speed)
        self.n_marbles = m = max(1, (n - FLOOR_TARGET) // TRIS_PER_MARBLE)
        self.n_floor = n - m * TRIS_PER_MARBLE
        self.radius = r = 1.0
        half = r * max(3.0, 2.0 * math.sqrt(m))
        self.box_lo = np.array([-half, 0.0, -half])
        self.box_hi = np.array([half, half, half])

        gap_r = r * (1.0 + _WALL_GAP)
        self._xz_lo = -half + gap_r
        self._xz_span = 2.0 * (half - gap_r)
        self._y_base = gap_r
        headroom = half - 2.0 * gap_r
        longest_period = _LOOP_SECONDS / _BOUNCE_CYCLES[0]
        gravity = 8.0 * 0.9 * headroom / longest_period**2
        self.gravity = gravity * speed**2

        rng = np.random.default_rng(int(seed))
        self._move_phase = rng.random((m, 2))
        self._move_cycles = rng.choice(_MOVE_CYCLES, size=(m, 2)).astype(np.float64)
        self._bounce_cycles = rng.integers(_BOUNCE_CYCLES[0], _BOUNCE_CYCLES[1] + 1, size=m).astype(np.float64)
        self._bounce_phase = rng.random(m)
        period = _LOOP_SECONDS / self._bounce_cycles
        self._apex = gravity * period**2 / 8.0
        axis = rng.normal(size=(m, 3))
        self._spin_axis = axis / np.linalg.norm(axis, axis=1, keepdims=True)
        self._spin_cycles = rng.choice(_SPIN_CYCLES, size=m).astype(np.float64)
        self._spin_phase = rng.random(m) * 2.0 * math.pi

        self._base = _icosphere_triangles(r)
        self._floor = floor_triangles(self.n_floor, half)
        mask = np.zeros(n, dtype=bool)
        mask[: self.n_floor] = True
        self.static_mask = as_static_mask(mask, n)

    def _phase(self, t):
        return ((self.speed * t) % _LOOP_SECONDS) / _LOOP_SECONDS

    def centers_at(self, t):
        """Marble centres at time ``t``: (n_marbles, 3) float64."""
        s = self._phase(check_time(t))
        u = (self._move_phase + self._move_cycles * s) % 1.0
        wave = 1.0 - np.abs(2.0 * u - 1.0)
        p = (self._bounce_phase + self._bounce_cycles * s) % 1.0
        c = np.empty((self.n_marbles, 3))
        c[:, 0] = self._xz_lo + wave[:, 0] * self._xz_span
        c[:, 1] = self._y_base + 4.0 * self._apex * p * (1.0 - p)
        c[:, 2] = self._xz_lo + wave[:, 1] * self._xz_span
        return c

    def rotations_at(self, t):
        """Marble orientations at time ``t``: (n_marbles, 3, 3) float64 rotation matrices."""
        s = self._phase(check_time(t))
        angle = self._spin_phase + 2.0 * math.pi * ((self._spin_cycles * s) % 1.0)
        return _rotations(self._spin_axis, angle)

    def _fill(self, t, out, origin):
        fill = _marbles_serial if len(out) < MARBLES_SERIAL_BELOW else _marbles_kernel
        fill(self._base, self.rotations_at(t), self.centers_at(t), self._floor, origin, out)
