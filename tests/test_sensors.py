"""The depth camera and the LiDAR against brute-force casts of rays the tests make themselves
(pinhole and beam geometry written out here, poses interpolated by hand), on a deforming mesh
updated between steps."""

import math

import numpy as np
import pytest

import gridrt
from gridrt.errors import InputError
from gridrt.scene import icosphere_mesh
from reference import ref_cast


def _caster():
    m = icosphere_mesh(5120)
    return m, gridrt.RayCaster(m.vertices, m.faces)


def _pinhole(eye, target, up, fov, w, h):
    eye, target, up = (np.asarray(v, float) for v in (eye, target, up))
    f = (target - eye) / np.linalg.norm(target - eye)
    r = np.cross(f, up)
    r /= np.linalg.norm(r)
    u = np.cross(r, f)
    th = math.tan(math.radians(fov) / 2)
    x, y = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    d = f + ((2 * x / w - 1) * th * w / h)[..., None] * r + ((1 - 2 * y / h) * th)[..., None] * u
    return f, (d / np.linalg.norm(d, axis=-1, keepdims=True)).reshape(-1, 3)


def test_depth_camera_against_brute_force():
    """Depth (along the optical axis), range, ids and normals (facing the camera) of every pixel are
    the brute force's on the same mesh; after update() they follow the deformed mesh."""
    m, caster = _caster()
    w, h, fov = 48, 36, 50.0
    cam = gridrt.DepthCamera(w, h, fov=fov)
    eye, target, up = (0.3, 1.2, 3.0), (0.0, 0.1, 0.0), (0.0, 1.0, 0.0)
    for step in range(2):
        if step:
            caster.update(m.vertices * np.array([1.3, 0.8, 1.0]))
        img = cam.render(caster, eye, target, up)
        f, d = _pinhole(eye, target, up, fov, w, h)
        tris = (caster.triangles.astype(np.float64) + caster.origin)
        ref = ref_cast(tris, np.broadcast_to(np.asarray(eye, float), d.shape), d)
        hit = ref.tri >= 0
        assert 0.2 < hit.mean() < 0.9
        assert np.array_equal(img.ids.reshape(-1), ref.tri)
        assert np.allclose(img.range.reshape(-1)[hit], ref.t[hit], rtol=1e-5)
        assert np.allclose(img.depth.reshape(-1)[hit], ref.t[hit] * (d[hit] @ f), rtol=1e-5)
        assert np.isinf(img.depth.reshape(-1)[~hit]).all() and np.isnan(img.normals.reshape(-1, 3)[~hit]).all()
        n = img.normals.reshape(-1, 3)[hit]
        T = tris[ref.tri[hit]]
        want = np.cross(T[:, 1] - T[:, 0], T[:, 2] - T[:, 0])
        want /= np.linalg.norm(want, axis=1, keepdims=True)
        want *= -np.sign(np.einsum("ij,ij->i", want, d[hit]))[:, None]
        assert np.allclose(n, want, atol=1e-5)
    near = gridrt.DepthCamera(w, h, fov=fov, near=3.2, far=3.4).render(caster, eye, target, up)
    r = near.range[np.isfinite(near.range)]
    assert len(r) and r.min() > 3.2 and r.max() < 3.4


def _rot_z(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


def test_lidar_sweep_against_brute_force():
    """A 16-channel LiDAR turning once while it moves (translation and a yaw of 0.4 rad during the
    sweep): each beam leaves the pose at its column's time, at its channel's elevation and column's
    azimuth (written out here), and its range and triangle are the brute force's; returns beyond
    max_range are misses; points are origin + range x direction."""
    _, caster = _caster()
    lidar = gridrt.Lidar(channels=16, vertical_fov=(-30.0, 15.0), azimuth_resolution=360 / 90, max_range=4.0)
    p0, p1 = np.eye(4), np.eye(4)
    p0[:3, 3] = (-2.5, 0.1, 0.2)
    p1[:3, :3] = _rot_z(0.4)
    p1[:3, 3] = (-2.3, 0.3, 0.2)
    scan = lidar.scan(caster, p0, p1, t_start=10.0, sweep_time=0.1)
    assert scan.ranges.shape == scan.ids.shape == (16, 90) and scan.points.shape == (16, 90, 3)
    f = np.arange(90) / 90
    assert np.allclose(scan.times, 10.0 + 0.1 * f)
    el = np.radians(np.linspace(-30.0, 15.0, 16))
    O, D = [], []
    for a in range(90):
        yaw = 0.4 * f[a]
        pos = (1 - f[a]) * p0[:3, 3] + f[a] * p1[:3, 3]
        az = 2 * math.pi * a / 90 + yaw
        for e in el:
            O.append(pos)
            D.append((math.cos(e) * math.cos(az), math.cos(e) * math.sin(az), math.sin(e)))
    O, D = np.array(O), np.array(D)
    tris = caster.triangles.astype(np.float64) + caster.origin
    ref = ref_cast(tris, O, D, tmax=4.0)
    rng, ids = scan.ranges.T.reshape(-1), scan.ids.T.reshape(-1)
    hit = ref.tri >= 0
    assert 0.1 < hit.mean() < 0.9
    assert np.array_equal(ids, ref.tri)
    assert np.allclose(rng[hit], ref.t[hit], rtol=1e-6) and np.isinf(rng[~hit]).all()
    pts = scan.points.transpose(1, 0, 2).reshape(-1, 3)
    assert np.allclose(pts[hit], O[hit] + ref.t[hit, None] * D[hit], atol=1e-6) and np.isnan(pts[~hit]).all()
    assert np.allclose(scan.origins, O[::16])
    still = lidar.scan(caster, p0)
    assert np.allclose(still.origins, p0[:3, 3]) and np.allclose(still.times, 0.1 * f)


def test_lidar_vertical_angles_and_bad_input():
    lidar = gridrt.Lidar(vertical_angles=[-10.0, 0.0, 5.0], azimuth_resolution=90.0)
    d = lidar.directions()
    assert d.shape == (4, 3, 3) and np.allclose(d[1, 2], [0, math.cos(math.radians(5)), math.sin(math.radians(5))])
    bad = np.eye(4)
    bad[0, 0] = 2.0
    for kw, message in (({"channels": 0}, "channels must be a whole number"),
                        ({"vertical_fov": (10, -10)}, "vertical_fov must be"),
                        ({"azimuth_resolution": 0}, "azimuth_resolution"),
                        ({"min_range": 5, "max_range": 1}, "min range < far/max range"),
                        ({"vertical_angles": [100.0]}, "vertical_angles")):
        with pytest.raises(InputError, match=message):
            gridrt.Lidar(**kw)
    _, caster = _caster()
    with pytest.raises(InputError, match="rotation"):
        lidar.scan(caster, bad)
    with pytest.raises(InputError, match="4x4"):
        lidar.scan(caster, np.eye(3))
    with pytest.raises(InputError, match="width must be a whole number"):
        gridrt.DepthCamera(0, 10)
