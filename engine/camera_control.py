"""Interactive camera moves as pure functions: each takes an :class:`gridrt.camera.Camera` and
returns a new one (cameras are frozen).  The viewer maps mouse and keys onto these; they need no
window and are unit-tested on their own.

Conventions (matching :mod:`gridrt.camera`: pixel (0, 0) is the top-left pixel, x grows to the
right, y grows downwards):

* ``fwd = normalize(target - eye)``, ``right = normalize(fwd x up)``, ``up' = right x fwd``.
* :func:`orbit` turns the eye about the target: ``yaw`` radians about the world ``up`` axis
  (right-handed, so a positive yaw carries +z towards +x when up is +y) and ``pitch`` radians of
  elevation (positive raises the eye towards ``up``).  The angle between ``eye - target`` and
  ``up`` is kept within [:data:`MIN_POLAR`, pi - :data:`MIN_POLAR`] so the view never becomes
  parallel to ``up``.  The distance to the target is unchanged.
* :func:`pan` slides eye and target together so that a point at the target's depth moves by
  (dx, dy) pixels in an image ``height`` pixels tall: the grabbed point follows the mouse.
* :func:`dolly` scales the eye-target distance by ``factor`` (< 1 moves closer).
* :func:`fly` translates eye and target together along fwd, right and the world up axis.
"""

import math

import numpy as np

from .checks import check_finite
from .errors import InputError

#: smallest angle (radians) between the viewing axis and the world up axis that orbit allows
MIN_POLAR = math.radians(1.0)
#: default floor on the eye-target distance for dolly (scene units)
MIN_DISTANCE = 1e-9


def _finite(x, name):
    return check_finite(name, x)


def _unit(v):
    return v / np.linalg.norm(v)


def frame_axes(cam):
    """(fwd, right, up') unit vectors, each (3,) float64, of ``cam``'s image plane."""
    eye = np.asarray(cam.eye)
    fwd = _unit(np.asarray(cam.target) - eye)
    right = _unit(np.cross(fwd, np.asarray(cam.up)))
    return fwd, right, np.cross(right, fwd)


def distance(cam):
    """Eye-to-target distance (float)."""
    return float(np.linalg.norm(np.asarray(cam.target) - np.asarray(cam.eye)))


def orbit(cam, yaw, pitch):
    """Turn the eye about the target by ``yaw`` (about world up) and ``pitch`` (elevation),
    both in radians; returns a new Camera with the same target, up, fov and distance."""
    yaw = _finite(yaw, "orbit yaw")
    pitch = _finite(pitch, "orbit pitch")
    target = np.asarray(cam.target)
    off = np.asarray(cam.eye) - target
    r = np.linalg.norm(off)
    u = _unit(np.asarray(cam.up))
    polar = math.acos(max(-1.0, min(1.0, float(off @ u) / r)))
    h = off - (off @ u) * u
    h = _unit(h)
    c, s = math.cos(yaw), math.sin(yaw)
    h = h * c + np.cross(u, h) * s
    polar = min(max(polar - pitch, MIN_POLAR), math.pi - MIN_POLAR)
    eye = target + r * (math.cos(polar) * u + math.sin(polar) * h)
    return cam.replace(eye=tuple(eye))


def pan(cam, dx, dy, height):
    """Slide the camera so a point at the target's depth moves (dx, dy) pixels in an image
    ``height`` pixels tall (x right, y down).  Eye and target move by the same vector, which
    lies in the image plane."""
    dx = _finite(dx, "pan dx")
    dy = _finite(dy, "pan dy")
    height = _finite(height, "image height")
    if height <= 0:
        raise InputError(f"image height must be positive, got {height}")
    _, right, up = frame_axes(cam)
    world_per_px = 2.0 * distance(cam) * math.tan(math.radians(cam.fov) / 2) / height
    shift = (-dx * right + dy * up) * world_per_px
    return cam.replace(eye=tuple(np.asarray(cam.eye) + shift), target=tuple(np.asarray(cam.target) + shift))


def dolly(cam, factor, min_distance=MIN_DISTANCE):
    """Move the eye along the viewing axis so its distance to the target becomes
    ``factor * distance`` (never below ``min_distance``); ``factor`` must be positive."""
    factor = _finite(factor, "dolly factor")
    if factor <= 0:
        raise InputError(f"dolly factor must be positive, got {factor}")
    target = np.asarray(cam.target)
    off = np.asarray(cam.eye) - target
    d = np.linalg.norm(off)
    new_d = max(d * factor, float(min_distance))
    return cam.replace(eye=tuple(target + off * (new_d / d)))


def fly(cam, forward=0.0, right=0.0, up=0.0):
    """Translate eye and target together by ``forward`` along fwd, ``right`` along the image's
    right axis and ``up`` along the world up axis (all in scene units)."""
    forward = _finite(forward, "fly forward")
    right = _finite(right, "fly right")
    up = _finite(up, "fly up")
    f, r, _ = frame_axes(cam)
    u = _unit(np.asarray(cam.up))
    shift = forward * f + right * r + up * u
    return cam.replace(eye=tuple(np.asarray(cam.eye) + shift), target=tuple(np.asarray(cam.target) + shift))


def orbit_from_drag(cam, dx, dy, height):
    """Orbit for a mouse drag of (dx, dy) pixels in a window ``height`` pixels tall: dragging the
    full height turns the view by pi.  Dragging right turns the scene right (the eye moves left),
    dragging down tips the scene's top towards the viewer (the eye rises)."""
    k = math.pi / max(_finite(height, "window height"), 1.0)
    return orbit(cam, -dx * k, dy * k)

