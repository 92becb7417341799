"""Sensors on a RayCaster's mesh, every simulation step: a pinhole depth camera and a spinning
LiDAR.  Both make their rays in numpy and cast them with ``RayCaster.cast``, which sends coherent
runs of rays (a camera's pixels, a LiDAR column's channels) through the CGT packets; call the
caster's ``update`` between steps for a deforming mesh.  Both also take a
:class:`gridrt.RayScene` (several meshes and instances) in place of the caster: its ids then say
which instance each pixel or return hit.

Depth camera::

    cam = DepthCamera(640, 480, fov=60.0)
    img = cam.render(caster, eye=(0, 1, 5), target=(0, 0, 0))   # img.depth, img.range, img.normals, img.ids

LiDAR (sensor frame: x forward, y left, z up; poses are 4x4 sensor-to-world matrices)::

    lidar = Lidar(channels=64, vertical_fov=(-24.9, 2.0), azimuth_resolution=360 / 2048, max_range=120.0)
    scan = lidar.scan(caster, pose_start, pose_end, t_start=0.0, sweep_time=0.1)
    scan.points, scan.ranges, scan.ids, scan.times   # (channels, columns) each; points in world coordinates
"""

import math
from typing import NamedTuple

import numpy as np

from .camera import Camera, DEFAULT_UP
from .errors import InputError


class DepthImage(NamedTuple):
    """A depth camera's frame, (H, W) per pixel: depth float32 (distance along the optical axis,
    inf where nothing is hit), range float32 (distance along the pixel's ray), normals (H, W, 3)
    float32 (the hit triangle's unit geometric normal turned towards the camera, NaN on a miss),
    ids int32 (the hit triangle in its mesh, -1 on a miss), instances int32 (the hit instance of a
    RayScene, 0 for a RayCaster's mesh; -1 on a miss)."""

    depth: np.ndarray
    range: np.ndarray
    normals: np.ndarray
    ids: np.ndarray
    instances: np.ndarray


class DepthCamera:
    """A pinhole depth camera of ``width`` x ``height`` pixels and vertical field of view ``fov``
    (degrees); hits nearer than ``near`` or farther than ``far`` (ranges along each pixel's ray)
    count as misses.  Its rays are :class:`gridrt.camera.Camera`'s: through each pixel's centre,
    row 0 at the top."""

    def __init__(self, width, height, fov=60.0, near=0.0, far=np.inf):
        self.camera = Camera(fov=fov)   # (checks the fov)
        self.width, self.height = _whole("width", width), _whole("height", height)
        self.near, self.far = _range_limits(near, far)

    def rays(self, eye, target, up=DEFAULT_UP):
        """(camera, origins, directions) of the pixels, row by row, directions of unit length."""
        cam = self.camera.replace(eye=tuple(eye), target=tuple(target), up=tuple(up))
        o, d = cam.rays(self.width, self.height)
        return cam, o, d

    def render(self, caster, eye, target, up=DEFAULT_UP, threads=None):
        """The :class:`DepthImage` of ``caster``'s current mesh (or a RayScene's instances) seen from ``eye`` towards ``target``."""
        cam, o, d = self.rays(eye, target, up)
        h = caster.cast(o, d, t_min=self.near, t_max=self.far, threads=threads)
        fwd = np.asarray(cam.basis()[1])
        rng = h.t
        depth = rng * (d @ fwd)
        n = caster.geometric_normals(h)
        flip = np.einsum("ij,ij->i", n, d) > 0
        n[flip] *= -1.0
        W, H = self.width, self.height
        return DepthImage(depth.reshape(H, W).astype(np.float32), rng.reshape(H, W).astype(np.float32),
                          n.reshape(H, W, 3).astype(np.float32), h.tri.reshape(H, W).astype(np.int32),
                          _instances(h).reshape(H, W))


class LidarScan(NamedTuple):
    """One sweep, (channels, columns) per return: points (..., 3) float64 world coordinates (NaN
    where nothing was hit), ranges float64 (inf: no return), ids int32 (the hit triangle, -1),
    instances int32 (the hit instance of a RayScene, 0 for a RayCaster's mesh; -1), and times (columns,) float64, the time each column was fired; origins (columns, 3) float64, the
    sensor's position then."""

    points: np.ndarray
    ranges: np.ndarray
    ids: np.ndarray
    instances: np.ndarray
    times: np.ndarray
    origins: np.ndarray


class Lidar:
    """A spinning LiDAR: ``channels`` beams at elevations spread evenly over ``vertical_fov``
    (lowest, highest, degrees; or ``vertical_angles``, one a channel), fired at ``columns``
    azimuths a turn (``360 / azimuth_resolution``), counter-clockwise from the sensor's x axis
    about its z axis, starting at ``azimuth_start`` degrees; returns between ``min_range`` and
    ``max_range``.  Channel 0 is the lowest beam."""

    def __init__(self, channels=64, vertical_fov=(-24.9, 2.0), azimuth_resolution=360.0 / 2048,
                 min_range=0.0, max_range=120.0, vertical_angles=None, azimuth_start=0.0):
        if vertical_angles is not None:
            a = np.asarray(vertical_angles, np.float64)
            if a.ndim != 1 or len(a) < 1 or not np.isfinite(a).all() or np.abs(a).max() > 90:
                raise InputError("vertical_angles must be a 1-D list of finite degrees within [-90, 90]")
            self.elevations = a
        else:
            lo, hi = (float(v) for v in vertical_fov)
            n = _whole("channels", channels)
            if not (-90 <= lo <= hi <= 90):
                raise InputError(f"vertical_fov must be (lowest, highest) within [-90, 90], got {vertical_fov}")
            self.elevations = np.linspace(lo, hi, n) if n > 1 else np.array([0.5 * (lo + hi)])
        res = float(azimuth_resolution)
        if not (math.isfinite(res) and 0 < res <= 360):
            raise InputError(f"azimuth_resolution must be within (0, 360] degrees, got {azimuth_resolution}")
        self.columns = max(1, int(round(360.0 / res)))
        self.azimuth_start = float(azimuth_start)
        self.min_range, self.max_range = _range_limits(min_range, max_range)

    @property
    def channels(self):
        return len(self.elevations)

    def directions(self):
        """(columns, channels, 3) unit beam directions in the sensor's frame."""
        az = np.radians(self.azimuth_start + 360.0 * np.arange(self.columns) / self.columns)[:, None]
        el = np.radians(self.elevations)[None, :]
        return np.stack(np.broadcast_arrays(np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)), axis=-1)

    def rays(self, pose_start, pose_end=None, t_start=0.0, sweep_time=0.1):
        """(origins, directions, times) of a sweep: (columns * channels, 3) world rays, column by
        column (a column's channels together), and the (columns,) firing times.  The sensor moves
        from ``pose_start`` (at t_start) to ``pose_end`` (at t_start + sweep_time; None: it stands
        still) during the sweep: each column is fired from the pose at its own time, the position
        interpolated linearly and the rotation spherically."""
        p0 = _pose(pose_start, "pose_start")
        p1 = p0 if pose_end is None else _pose(pose_end, "pose_end")
        sweep = float(sweep_time)
        if not (math.isfinite(sweep) and sweep >= 0) or not math.isfinite(float(t_start)):
            raise InputError(f"need a finite t_start and sweep_time >= 0, got {t_start}, {sweep_time}")
        f = np.arange(self.columns) / self.columns
        times = float(t_start) + sweep * f
        R, T = _interpolate_poses(p0, p1, f)
        dirs = np.einsum("cij,caj->cai", R, self.directions())
        origins = np.repeat(T, self.channels, axis=0)
        return origins, dirs.reshape(-1, 3), times

    def scan(self, caster, pose_start, pose_end=None, t_start=0.0, sweep_time=0.1, threads=None):
        """The :class:`LidarScan` of ``caster``'s current mesh (or a RayScene's instances; see
        :meth:`rays`)."""
        o, d, times = self.rays(pose_start, pose_end, t_start, sweep_time)
        h = caster.cast(o, d, t_min=self.min_range, t_max=self.max_range, threads=threads)
        C, A = self.channels, self.columns
        rng = h.t.reshape(A, C).T
        t = np.where(np.isfinite(h.t), h.t, np.nan)   # (no inf * 0 where a direction has a zero component)
        pts = (o + t[:, None] * d).reshape(A, C, 3).transpose(1, 0, 2)
        return LidarScan(np.ascontiguousarray(pts), np.ascontiguousarray(rng),
                         np.ascontiguousarray(h.tri.reshape(A, C).T),
                         np.ascontiguousarray(_instances(h).reshape(A, C).T), times, o[::C].copy())


def _instances(h):
    """The instance id of each hit: a RayScene's, else 0 where the ray hit (-1 on a miss)."""
    inst = getattr(h, "instance", None)
    return np.asarray(inst, np.int32) if inst is not None else np.where(h.tri >= 0, 0, -1).astype(np.int32)


def _whole(name, v):
    if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
        raise InputError(f"{name} must be a whole number >= 1, got {v!r}")
    return int(v)


def _range_limits(lo, hi):
    lo, hi = float(lo), float(hi)
    if math.isnan(lo) or math.isnan(hi) or lo < 0 or hi <= lo:
        raise InputError(f"need 0 <= near/min range < far/max range, got {lo}, {hi}")
    return lo, hi


def _pose(m, name):
    a = np.asarray(m, np.float64)
    if a.shape != (4, 4) or not np.isfinite(a).all():
        raise InputError(f"{name} must be a finite 4x4 sensor-to-world matrix, got shape {a.shape}")
    R = a[:3, :3]
    if not np.allclose(R @ R.T, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
        raise InputError(f"{name}'s upper 3x3 block must be a rotation (orthonormal, determinant 1)")
    return a


def _quat(R):
    """The unit quaternion (w, x, y, z) of a rotation matrix."""
    w = math.sqrt(max(0.0, 1 + R[0, 0] + R[1, 1] + R[2, 2])) / 2
    x = math.copysign(math.sqrt(max(0.0, 1 + R[0, 0] - R[1, 1] - R[2, 2])) / 2, R[2, 1] - R[1, 2])
    y = math.copysign(math.sqrt(max(0.0, 1 - R[0, 0] + R[1, 1] - R[2, 2])) / 2, R[0, 2] - R[2, 0])
    z = math.copysign(math.sqrt(max(0.0, 1 - R[0, 0] - R[1, 1] + R[2, 2])) / 2, R[1, 0] - R[0, 1])
    q = np.array([w, x, y, z])
    return q / np.linalg.norm(q)


def _matrices(q):
    """Rotation matrices (n, 3, 3) of unit quaternions q (n, 4)."""
    w, x, y, z = q.T
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1)], axis=1)


def _interpolate_poses(p0, p1, f):
    """(rotations (n, 3, 3), positions (n, 3)) of the poses a fraction f (n,) of the way from p0 to
    p1: positions linearly, rotations along the shortest arc (slerp)."""
    T = p0[:3, 3][None] + f[:, None] * (p1[:3, 3] - p0[:3, 3])[None]
    if np.array_equal(p0[:3, :3], p1[:3, :3]):
        return np.broadcast_to(p0[:3, :3], (len(f), 3, 3)), T
    q0, q1 = _quat(p0[:3, :3]), _quat(p1[:3, :3])
    dot = float(q0 @ q1)
    if dot < 0:
        q1, dot = -q1, -dot
    theta = math.acos(min(dot, 1.0))
    if theta < 1e-12:
        q = np.broadcast_to(q0, (len(f), 4))
    else:
        q = (np.sin((1 - f) * theta)[:, None] * q0 + np.sin(f * theta)[:, None] * q1) / math.sin(theta)
    return _matrices(q), T
