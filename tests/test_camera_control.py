"""gridrt.camera_control: orbit / pan / dolly / fly as pure functions on Camera.

References are analytic (spherical coordinates, rigid translations) or come from the rays the
engine's own Camera casts (pan: the pixel whose ray passes nearest a world point), so each move
is checked against what the renderer would actually show.
"""

import math

import numpy as np
import pytest

from gridrt import camera_control as cc
from gridrt.camera import Camera
from gridrt.errors import InputError


def _cams(rng, n=20):
    out = []
    while len(out) < n:
        eye = rng.uniform(-10, 10, 3)
        target = rng.uniform(-3, 3, 3)
        up = (0.0, 1.0, 0.0) if len(out) % 2 == 0 else tuple(rng.normal(size=3))
        try:
            out.append(Camera(eye=tuple(eye), target=tuple(target), up=up, fov=float(rng.uniform(20, 90))))
        except InputError:
            continue
    return out


def _polar(cam):
    off = np.subtract(cam.eye, cam.target)
    u = np.asarray(cam.up) / np.linalg.norm(cam.up)
    return math.acos(np.clip(off @ u / np.linalg.norm(off), -1, 1))


def test_orbit_yaw_quarter_turn_about_y():
    cam = Camera(eye=(0, 0, 5), target=(0, 0, 0))
    out = cc.orbit(cam, math.pi / 2, 0.0)
    np.testing.assert_allclose(out.eye, (5, 0, 0), atol=1e-12)   # +z carried to +x (right-handed about +y)
    assert out.target == cam.target and out.up == cam.up and out.fov == cam.fov


def test_orbit_pitch_raises_eye_on_the_sphere():
    cam = Camera(eye=(1, 2, 5), target=(1, 2, 3))
    out = cc.orbit(cam, 0.0, 0.3)
    # eye - target = 2*(0,0,1) before; after: elevation 0.3 rad towards +y
    np.testing.assert_allclose(np.subtract(out.eye, out.target), (0, 2 * math.sin(0.3), 2 * math.cos(0.3)),
                               atol=1e-12)


def test_orbit_matches_spherical_coordinates(rng):
    cam = Camera(eye=(0, 0, 4), target=(0, 0, 0))
    for _ in range(20):
        yaw, pitch = rng.uniform(-3, 3), rng.uniform(-1.2, 1.2)
        out = cc.orbit(cam, yaw, pitch)
        expected = 4 * np.array([math.cos(pitch) * math.sin(yaw), math.sin(pitch), math.cos(pitch) * math.cos(yaw)])
        np.testing.assert_allclose(out.eye, expected, atol=1e-9)


def test_orbit_keeps_target_distance_and_full_turn_returns(rng):
    for cam in _cams(rng):
        d = cc.distance(cam)
        out = cc.orbit(cam, rng.uniform(-7, 7), rng.uniform(-0.2, 0.2))
        assert out.target == cam.target
        assert cc.distance(out) == pytest.approx(d, rel=1e-12)
        back = cc.orbit(cam, 2 * math.pi, 0.0)
        np.testing.assert_allclose(back.eye, cam.eye, atol=1e-9 * max(1.0, d))


def test_orbit_pitch_is_clamped_away_from_up(rng):
    for cam in _cams(rng, 10):
        top = cc.orbit(cam, 0.0, 10.0)
        bottom = cc.orbit(cam, 0.0, -10.0)
        assert _polar(top) == pytest.approx(cc.MIN_POLAR, abs=1e-9)
        assert _polar(bottom) == pytest.approx(math.pi - cc.MIN_POLAR, abs=1e-9)
        # still a valid camera (Camera() rejects a view parallel to up) that can keep orbiting
        cc.orbit(top, 1.0, 1.0)


def test_orbit_from_drag_full_height_turns_half_way():
    cam = Camera(eye=(0, 0, 5), target=(0, 0, 0))
    out = cc.orbit_from_drag(cam, 480, 0, 480)
    np.testing.assert_allclose(out.eye, (0, 0, -5), atol=1e-9)
    right = cc.orbit_from_drag(cam, 48, 0, 480)   # drag right: the eye moves to the camera's left (-x)
    assert right.eye[0] < 0
    down = cc.orbit_from_drag(cam, 0, 48, 480)    # drag down: the eye rises
    assert down.eye[1] > 0


def _nearest_pixel(cam, point, W, H):
    o, d = cam.rays(W, H)
    v = np.asarray(point) - o
    tt = np.einsum("ij,ij->i", v, d)
    dist = np.linalg.norm(v - tt[:, None] * d, axis=1)
    i = int(np.argmin(dist))
    return i % W, i // W


@pytest.mark.parametrize("dx,dy", [(10, -6), (-7, 9), (0, 12), (15, 0)])
def test_pan_moves_target_depth_point_by_pixels(rng, dx, dy):
    W, H = 65, 49   # odd sizes: the target projects onto the centre pixel (32, 24)
    for cam in _cams(rng, 4):
        p = np.asarray(cam.target)
        assert _nearest_pixel(cam, p, W, H) == (W // 2, H // 2)
        out = cc.pan(cam, dx, dy, H)
        assert _nearest_pixel(out, p, W, H) == (W // 2 + dx, H // 2 + dy)
        np.testing.assert_allclose(np.subtract(out.eye, cam.eye), np.subtract(out.target, cam.target), atol=1e-12)
        shift = np.subtract(out.eye, cam.eye)
        fwd = np.subtract(cam.target, cam.eye)
        assert abs(shift @ fwd) <= 1e-9 * np.linalg.norm(shift) * np.linalg.norm(fwd)


def test_dolly_scales_distance_along_the_view_axis(rng):
    for cam in _cams(rng, 10):
        d = cc.distance(cam)
        out = cc.dolly(cam, 0.5)
        assert out.target == cam.target
        assert cc.distance(out) == pytest.approx(0.5 * d, rel=1e-12)
        a = np.subtract(cam.eye, cam.target) / d
        b = np.subtract(out.eye, out.target) / cc.distance(out)
        np.testing.assert_allclose(a, b, atol=1e-12)
    cam = Camera(eye=(0, 0, 1), target=(0, 0, 0))
    assert cc.distance(cc.dolly(cam, 1e-30, min_distance=1e-3)) == pytest.approx(1e-3)


def test_fly_translates_eye_and_target():
    cam = Camera(eye=(0, 0, 5), target=(0, 0, 0))
    out = cc.fly(cam, forward=2.0, right=1.0, up=0.5)
    # fwd = -z, right = fwd x up = +x, world up = +y
    np.testing.assert_allclose(out.eye, (1.0, 0.5, 3.0), atol=1e-12)
    np.testing.assert_allclose(out.target, (1.0, 0.5, -2.0), atol=1e-12)


@pytest.mark.parametrize("call", [
    lambda c: cc.orbit(c, float("nan"), 0),
    lambda c: cc.orbit(c, 0, "x"),
    lambda c: cc.pan(c, 1, 1, 0),
    lambda c: cc.pan(c, float("inf"), 0, 100),
    lambda c: cc.dolly(c, 0.0),
    lambda c: cc.dolly(c, -1.0),
    lambda c: cc.fly(c, forward=float("nan")),
])
def test_bad_input_raises(call):
    with pytest.raises(InputError):
        call(Camera(eye=(0, 0, 5), target=(0, 0, 0)))
