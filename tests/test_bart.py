"""BART (AFF) scenes: Kochanek-Bartels splines, transform hierarchies, tpa triangles, camera.

Independent references: Catmull-Rom curves (what a KB spline with zero tension, continuity and
bias reduces to on evenly spaced keys), coaxial rotations (squad of evenly spaced coaxial keys turns
at a constant rate), key values read from the .aff text by the simple scanners below, triangle
counts as listed with the development data set, and small AFF files written here with hand-computed poses.
"""

import re

import numpy as np
import pytest

import gridrt  # noqa: F401  (sets numba's thread count before numba loads)
from gridrt.errors import InputError
from gridrt.scene import BartAnimation, make_scene
from gridrt.scene.bart import (
    axis_angle_quaternions,
    kb_position,
    kb_position_coefficients,
    kb_rotation,
    kb_rotation_segments,
)

from conftest import available, data_path
from helpers.geometry import rodrigues


def need(rel):
    """A BART scene file by its name in the development data set's animated/bart folder (assets/
    ships the museum); skips when absent."""
    return data_path(f"animated/bart/{rel}")


def quat_to_matrix(q):
    x, y, z, w = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def eval_pos(times, points, tcb, t):
    tmin, tmax, coef = kb_position_coefficients(times, points, tcb)
    out = np.zeros(3)
    kb_position(tmin, tmax, coef, 0, len(tmin), float(t), out)
    return out


def eval_rot(times, axes, degrees, tcb, t):
    q = axis_angle_quaternions(axes, np.radians(degrees))
    tmin, tmax, pabq = kb_rotation_segments(times, q, tcb)
    out = np.zeros(4)
    kb_rotation(tmin, tmax, pabq, 0, len(tmin), float(t), out)
    return out


# ----------------------------------------------------------------------------- splines


def test_position_spline_hits_keys_exactly():
    rng = np.random.default_rng(7)
    n = 9
    times = np.cumsum(rng.uniform(0.2, 1.5, n))
    pts = rng.normal(size=(n, 3)) * 5
    tcb = rng.uniform(-0.8, 0.8, size=(n, 3))
    for k in range(1, n - 1):  # the first and last keys only shape the end tangents
        got = eval_pos(times, pts, tcb, times[k])
        if k < n - 2:
            np.testing.assert_array_equal(got, pts[k])  # u = 0 of segment k: bit for bit
        else:
            np.testing.assert_allclose(got, pts[k], rtol=0, atol=1e-12)  # u = 1 of the last segment
    # clamped outside the interior keys
    np.testing.assert_array_equal(eval_pos(times, pts, tcb, times[0] - 3), pts[1])
    np.testing.assert_allclose(eval_pos(times, pts, tcb, times[-1] + 3), pts[-2], atol=1e-12)


def test_position_spline_is_catmull_rom_for_zero_tcb_and_even_keys():
    rng = np.random.default_rng(3)
    pts = rng.normal(size=(6, 3))
    times = np.arange(6) * 0.5 - 0.5
    tcb = np.zeros((6, 3))
    for k in range(1, 4):
        p0, p1, p2, p3 = pts[k - 1:k + 3]
        for u in (0.1, 0.5, 0.83):
            cr = 0.5 * (2 * p1 + (-p0 + p2) * u + (2 * p0 - 5 * p1 + 4 * p2 - p3) * u**2
                        + (-p0 + 3 * p1 - 3 * p2 + p3) * u**3)
            np.testing.assert_allclose(eval_pos(times, pts, tcb, times[k] + u * 0.5), cr, atol=1e-12)


def test_rotation_spline_hits_keys_and_stays_unit():
    rng = np.random.default_rng(11)
    n = 8
    times = np.cumsum(rng.uniform(0.3, 1.0, n))
    axes = rng.normal(size=(n, 3))
    deg = rng.uniform(-400, 400, n)
    tcb = rng.uniform(-0.5, 0.5, size=(n, 3))
    for k in range(1, n - 1):
        q = eval_rot(times, axes, deg, tcb, times[k])
        np.testing.assert_allclose(quat_to_matrix(q), rodrigues(axes[k], deg[k]), atol=1e-12)
    for t in np.linspace(times[0], times[-1], 37):
        assert np.linalg.norm(eval_rot(times, axes, deg, tcb, t)) == pytest.approx(1.0, abs=1e-12)


def test_coaxial_evenly_spaced_rotations_turn_at_constant_rate():
    times = np.arange(6, dtype=np.float64)
    deg = 25.0 * times - 25.0
    axes = np.tile([0.0, 0.0, 2.0], (6, 1))  # a non-unit axis: BART normalizes
    for t in np.linspace(1.0, 4.0, 13):
        q = eval_rot(times, axes, deg, np.zeros((6, 3)), t)
        np.testing.assert_allclose(quat_to_matrix(q), rodrigues([0, 0, 1], 25.0 * t - 25.0), atol=1e-12)


# ----------------------------------------------------------------------------- a small scene

SMALL = """\
% a small AFF scene written for the tests
v
from 0 0 10
at 0 0 0
up 0 1 0
angle 40
hither 0.1
resolution 320 240
a 0 5 51

xs 2 2 2  0 0 1 90  1 0 0
{
  m vertices 3  0 0 0  1 0 0  0 1 0
    triangles 1  0 1 2
}
x mover
{
  xs 1 1 1  1 0 0 0  0 3 0
  {
    i 0 parts/square.aff
  }
}
x blinker
{
  tt tex.ppm  0 0 -1 0 0  1 0 -1 1 0  0 1 -1 0 1
}
tpa 2
 0
  0 0 5  0 0 1
  1 0 5  0 0 1
  0 1 5  0 0 1
 4
  0 0 9  0 0 1
  2 0 9  0 0 1
  0 2 9  0 0 1

k mover
{
  transl 5
  -2 -4 0 0  0 0 0
   0  0 0 0  0 0 0
   2  4 0 0  0 0 0
   4  8 0 0  0 0 0
   6 12 0 0  0 0 0
}
k blinker
{
  visibility 2
  1 0
  3 1
}
k camera
{
  transl 4
  -1 0 0 10  0 0 0
   0 0 0 10  0 0 0
   5 0 5 10  0 0 0
   6 0 5 10  0 0 0
  rot 4
  -1 0 1 0 0  0 0 0
   0 0 1 0 0  0 0 0
   5 0 1 0 90  0 0 0
   6 0 1 0 90  0 0 0
}
"""

SQUARE = "p 4\n 0 0 0\n 1 0 0\n 1 1 0\n 0 1 0\n"


def write_small(tmp_path, text=SMALL, square=SQUARE):
    (tmp_path / "parts").mkdir(exist_ok=True)
    (tmp_path / "parts" / "square.aff").write_text(square)
    p = tmp_path / "small.aff"
    p.write_text(text)
    return p


def test_small_scene_poses(tmp_path):
    s = BartAnimation(write_small(tmp_path))
    assert s.n_triangles == 1 + 2 + 1 + 1  # mesh, fan of the square, tt, tpa
    assert s.time_range == (0.0, 5.0) and s.duration == 5.0 and s.n_frames == 51
    static_tri = np.array([1.0, 0, 0]) + (rodrigues([0, 0, 1], 90) @ (2 * np.array(
        [[0, 0, 0], [1, 0, 0], [0, 1, 0]], dtype=np.float64)).T).T
    sq = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], dtype=np.float64)
    tt = np.array([[0, 0, -1], [1, 0, -1], [0, 1, -1]], dtype=np.float64)
    a0 = np.array([[0, 0, 5], [1, 0, 5], [0, 1, 5]], dtype=np.float64)
    a1 = np.array([[0, 0, 9], [2, 0, 9], [0, 2, 9]], dtype=np.float64)
    for t in (0.0, 0.5, 1.0, 2.0, 2.9, 3.0, 4.0, 4.5):
        got = s.triangles_at(t).astype(np.float64)
        np.testing.assert_allclose(got[0], static_tri, atol=1e-6)
        # keys are evenly spaced and lie on a line: the Catmull-Rom curve is the line x = 2 t
        shift = np.array([min(2 * t, 8.0), 3.0, 0.0])
        np.testing.assert_allclose(got[1], (sq + shift)[[0, 1, 2]], atol=1e-5)
        np.testing.assert_allclose(got[2], (sq + shift)[[0, 2, 3]], atol=1e-5)
        if 1.0 <= t < 3.0:  # invisible: collapsed onto its node's origin
            np.testing.assert_allclose(got[3], 0.0, atol=1e-7)
        else:
            np.testing.assert_allclose(got[3], tt, atol=1e-7)
        w = min(t, 4.0) / 4.0  # tpa: linear between the keys at 0 and 4, clamped after
        np.testing.assert_allclose(got[4], (1 - w) * a0 + w * a1, atol=1e-6)
    np.testing.assert_array_equal(s.static_mask, [True, False, False, False, False])


def test_small_scene_camera(tmp_path):
    s = BartAnimation(write_small(tmp_path))
    c0 = s.camera_at(0.0)
    np.testing.assert_allclose(c0.eye, [0, 0, 10])
    np.testing.assert_allclose(np.subtract(c0.target, c0.eye), [0, 0, -1], atol=1e-12)
    np.testing.assert_allclose(c0.up, [0, 1, 0], atol=1e-12)
    assert c0.fov == 40.0
    c5 = s.camera_at(4.999999999)
    np.testing.assert_allclose(c5.eye, [0, 5, 10], atol=1e-6)
    # 90 deg about y: the view direction -z turns to -x
    np.testing.assert_allclose(np.subtract(c5.target, c5.eye), [-1, 0, 0], atol=1e-6)
    # without a camera block the v block is the camera
    plain = BartAnimation(write_small(tmp_path, SMALL[: SMALL.index("k camera")]))
    c = plain.camera_at(2.0)
    np.testing.assert_allclose(c.eye, [0, 0, 10])
    np.testing.assert_allclose(c.target, [0, 0, 0])


def test_make_scene_reads_aff(tmp_path):
    p = write_small(tmp_path)
    s = make_scene(p)
    assert isinstance(s, BartAnimation) and s.name == "small"
    for kw in ({"animate": "twist"}, {"subdivide": 100}, {"clip": 0}, {"fps": 10}):
        with pytest.raises(InputError):
            make_scene(p, **kw)


# ----------------------------------------------------------------------------- real scenes


def strip_comments(text):
    return "\n".join(re.split(r"[#%]", line, maxsplit=1)[0] for line in text.splitlines())


def count_aff_triangles(path):
    """Triangle count of an AFF file and its includes (instances counted), by scanning tokens."""
    toks = strip_comments(path.read_text(encoding="latin-1")).split()
    n = 0
    for i, tok in enumerate(toks):
        if tok == "i" and toks[i + 1] == "0":
            n += count_aff_triangles(path.parent / toks[i + 2])
        elif tok == "triangles":
            n += int(toks[i + 1])
        elif tok in ("p", "pp"):
            n += int(toks[i + 1]) - 2
        elif tok in ("tt", "ttp", "tpa"):
            n += 1
    return n


#: the data set's BART scenes (assets/ ships the museum) and their README triangle counts
REAL_BART = {"museum/aff/museum5.aff": None, "kitchen/aff/kitchen.aff": 110_561, "robots/aff/Robot.aff": 71_708}


def real_bart(*rels):
    """{rel: path} of the BART scenes present (the museum always: assets/ ships it)."""
    return {rel.removeprefix("animated/bart/"): p for rel, p in available(*(f"animated/bart/{r}" for r in rels)).items()}


def test_real_triangle_counts():
    for rel, p in real_bart(*REAL_BART).items():
        check_triangle_count(rel, p, REAL_BART[rel])


def check_triangle_count(rel, p, readme):
    s = BartAnimation(p)
    assert s.n_triangles == count_aff_triangles(p)
    if readme is not None:
        assert s.n_triangles == readme
    # README counts museum5 as 11,298: its reader skipped the 10 textured 'tt' triangles
    if "museum" in rel:
        assert s.n_triangles == 11_298 + 10 and s.n_tpa == 1024 and s.skipped["cones"] == 8


def read_keys(path, name, motion):
    """Rows of the ``motion`` keys of ``k name`` in an .aff file (a plain text scan)."""
    text = strip_comments(path.read_text(encoding="latin-1"))
    block = re.search(r"\bk\s+" + re.escape(name) + r"\s*\{(.*?)\}", text, re.S).group(1)
    toks = block.split()
    i = toks.index(motion)
    n = int(toks[i + 1])
    w = 8 if motion == "rot" else 7
    return np.array(toks[i + 2:i + 2 + n * w], dtype=np.float64).reshape(n, w)


def test_keyed_values_at_key_times():
    """The camera at its key times equals its keys: the museum's and, with the data set, the
    kitchen's (at least 30 keys), whose toy car's transform is checked against its keys too."""
    for rel, p in real_bart("museum/aff/museum5.aff", "kitchen/aff/kitchen.aff").items():
        checked = check_camera_keys(p.parent / "camera.aff" if "museum" in rel else p, BartAnimation(p))
        assert checked >= (30 if "kitchen" in rel else 8), (rel, checked)
        if "kitchen" in rel:
            check_toycar(p)


def check_camera_keys(p, s):
    start, end = s.time_range
    transl = read_keys(p, "camera", "transl")
    rot = read_keys(p, "camera", "rot")
    checked = 0
    for row in transl[1:-1]:
        if start <= row[0] < end:
            cam = s.camera_at(row[0] - start)
            np.testing.assert_allclose(cam.eye, row[1:4], atol=1e-9)
            checked += 1
    for row in rot[1:-1]:
        if start <= row[0] < end:
            cam = s.camera_at(row[0] - start)
            r = rodrigues(row[1:4], row[4])
            d = np.subtract(cam.target, cam.eye)
            np.testing.assert_allclose(d / np.linalg.norm(d), -r[:, 2], atol=1e-9)
            np.testing.assert_allclose(cam.up, r[:, 1], atol=1e-9)
            checked += 1
    return checked


def check_toycar(p):
    s = BartAnimation(p)
    keys = read_keys(p, "toycar", "transl")
    assert "toycar" in s.animated_transforms
    for row in keys[1:-1]:
        if 0 <= row[0] < s.duration:
            np.testing.assert_allclose(s.transform_at("toycar", row[0])[:3, 3], row[1:4], atol=1e-12)
    with pytest.raises(InputError, match="toycar"):
        s.transform_at("nope", 0.0)


def test_real_static_mask():
    for p in real_bart("museum/aff/museum5.aff", "kitchen/aff/kitchen.aff", "robots/aff/Robot.aff").values():
        check_static_mask(BartAnimation(p))


def check_static_mask(s):
    frames = [s.triangles_at(t).copy() for t in (0.0, 0.37 * s.duration, 0.81 * s.duration)]
    m = s.static_mask
    assert 0 < m.sum() < s.n_triangles
    for f in frames[1:]:
        np.testing.assert_array_equal(f[m], frames[0][m])
    moved = np.zeros(s.n_triangles, dtype=bool)
    for f in frames[1:]:
        moved |= (f != frames[0]).any(axis=(1, 2))
    assert moved[~m].mean() > 0.5
    assert np.isfinite(frames[1]).all()


def test_museum_tpa_keys_and_midpoints():
    p = need("museum/aff/museum5.aff")
    s = BartAnimation(p)
    start = s.time_range[0]
    text = strip_comments((p.parent / "animart5.aff").read_text(encoding="latin-1")).split()
    i = text.index("tpa")
    n = int(text[i + 1])
    rec = np.array(text[i + 2:i + 2 + 19 * n], dtype=np.float64).reshape(n, 19)
    times = rec[:, 0]
    verts = rec[:, 1:].reshape(n, 3, 6)[:, :, :3]
    first = s.triangles_at(times[0] - start).astype(np.float64)
    hit = np.flatnonzero(np.abs(first - verts[0]).max(axis=(1, 2)) < 1e-6)
    assert len(hit) == 1
    f = hit[0]
    assert not s.static_mask[f]
    for k in range(n):
        np.testing.assert_allclose(s.triangles_at(times[k] - start)[f], verts[k], atol=1e-6)
    for k in range(n - 1):
        mid = 0.5 * (times[k] + times[k + 1]) - start
        np.testing.assert_allclose(s.triangles_at(mid)[f], 0.5 * (verts[k] + verts[k + 1]), atol=1e-6)
