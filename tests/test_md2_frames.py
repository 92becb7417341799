"""MD2 keyframe models and folders of OBJ/PLY frames, interpolated linearly between frames.

References: MD2 files are written here with ``struct`` and the real ones decoded here with a
separate ``struct`` reader (position = scale * packed + translate, then gridrt's y-up axes
(x, z, -y)); frame folders are written here as OBJ text.  Interpolation is checked against the
float64 average of the two neighbouring frames.
"""

import struct

import numpy as np
import pytest

import gridrt  # noqa: F401  (sets numba's thread count before numba loads)
from gridrt.errors import InputError, SceneFileError
from gridrt.scene import KeyframeMesh, Md2Model, make_scene
from gridrt.scene.frames import load_frame_folder

from conftest import available, data_path
from helpers.scene_files import GRID_F, grid_frame, write_md2, write_obj


def need_data(rel):
    """A real file by its name in the development data set (assets/ ships some); skips when absent."""
    return data_path(rel)


def to_gridrt(v):
    """MD2 is z-up; gridrt is y-up: (x, y, z) -> (x, z, -y)."""
    v = np.asarray(v, dtype=np.float64)
    return np.stack([v[..., 0], v[..., 2], -v[..., 1]], axis=-1)


# ----------------------------------------------------------------------------- MD2


def decode_md2(path):
    """Independent reader: (frames (K, V, 3) float64 in MD2 axes, faces (F, 3), names)."""
    raw = path.read_bytes()
    h = struct.unpack_from("<4s16i", raw)
    framesize, nv, nt, nf, ofs_tris, ofs_frames = h[4], h[6], h[8], h[10], h[13], h[14]
    faces = np.array([struct.unpack_from("<3H", raw, ofs_tris + 12 * i) for i in range(nt)])
    frames, names = [], []
    for k in range(nf):
        o = ofs_frames + k * framesize
        sx, sy, sz, tx, ty, tz = struct.unpack_from("<6f", raw, o)
        names.append(raw[o + 24:o + 40].split(b"\0")[0].decode())
        pk = np.frombuffer(raw, np.uint8, 4 * nv, o + 40).reshape(nv, 4)[:, :3].astype(np.float64)
        frames.append(pk * [sx, sy, sz] + [tx, ty, tz])
    return np.array(frames), faces, names


@pytest.fixture
def small_md2(tmp_path):
    rng = np.random.default_rng(5)
    packed = rng.integers(0, 256, size=(5, 12, 3), dtype=np.uint8)
    scales = rng.uniform(0.05, 0.3, size=(5, 3))
    shifts = rng.uniform(-10, 10, size=(5, 3))
    names = ["stand01", "stand02", "run1", "run2", "run3"]
    tris = [(i, (i + 1) % 12, (i + 5) % 12) for i in range(12)]
    return write_md2(tmp_path / "toy.md2", packed, scales, shifts, names, tris)


def test_md2_frames_equal_decoded_frames(small_md2):
    frames, faces, names = decode_md2(small_md2)
    m = Md2Model(small_md2, fps=4.0)
    assert m.n_frames == 5 and m.fps == 4.0 and m.n_triangles == 12
    assert m.clips == ["stand", "run"] and m.frame_names == names
    assert m.duration == pytest.approx(5 / 4.0)  # loops: the last frame blends back into the first
    for k in range(5):
        got = m.triangles_at(k / 4.0).astype(np.float64)
        np.testing.assert_allclose(got, to_gridrt(frames[k])[faces], rtol=0, atol=2e-6 * np.abs(frames).max())
        # frames are stored as float32: frame k is reproduced exactly
        np.testing.assert_array_equal(m.triangles_at(k / 4.0), m.frame_vertices(k)[faces])


def test_md2_midpoints_are_averages(small_md2):
    frames, faces, _ = decode_md2(small_md2)
    m = Md2Model(small_md2, fps=4.0)
    g = to_gridrt(frames)
    for k in range(5):
        nxt = (k + 1) % 5  # wraps from the last frame to the first
        got = m.triangles_at((k + 0.5) / 4.0).astype(np.float64)
        np.testing.assert_allclose(got, (0.5 * (g[k] + g[nxt]))[faces], atol=3e-6 * np.abs(g).max())
    # a quarter of the way: 3/4 of frame 1 and 1/4 of frame 2
    got = m.triangles_at(1.25 / 4.0).astype(np.float64)
    np.testing.assert_allclose(got, (0.75 * g[1] + 0.25 * g[2])[faces], atol=3e-6 * np.abs(g).max())


def test_md2_clips(small_md2):
    frames, faces, _ = decode_md2(small_md2)
    run = Md2Model(small_md2, clip="run", fps=10.0)
    assert run.clip == "run" and run.n_frames == 3 and run.first_frame == 2
    np.testing.assert_allclose(run.triangles_at(0.1), to_gridrt(frames[3])[faces], atol=1e-4)
    assert Md2Model(small_md2, clip=0).n_frames == 2
    with pytest.raises(InputError) as info:
        Md2Model(small_md2, clip="walk")
    assert "'stand'" in str(info.value) and "'run'" in str(info.value)
    for bad in (2, -1, 1.5):
        with pytest.raises(InputError):
            Md2Model(small_md2, clip=bad)
    with pytest.raises(InputError, match="fps"):
        Md2Model(small_md2, fps=0)
    s = make_scene(small_md2, clip="run", fps=5)
    assert isinstance(s, Md2Model) and s.fps == 5.0 and s.name == "toy (run)"


#: the data set's MD2 models: (triangles, frames); assets/ ships sydney
REAL_MD2 = {"animated/md2_sydney/sydney.md2": (679, 198), "animated/md2_faerie/faerie.md2": (654, 198)}


def test_real_md2():
    for rel, p in available(*REAL_MD2).items():
        check_real_md2(p, *REAL_MD2[rel])


def check_real_md2(p, n_tris, n_frames):
    frames, faces, names = decode_md2(p)
    m = make_scene(p)
    assert isinstance(m, Md2Model) and m.n_triangles == n_tris and m.n_frames == n_frames
    assert m.fps == 10.0 and "run" in m.clips
    g = to_gridrt(frames)
    scale = np.abs(g).max()
    for k in (0, 1, 57, 197):
        np.testing.assert_allclose(m.triangles_at(k / 10.0), g[k][faces], atol=2e-6 * scale, err_msg=f"frame {k}")
    for k in (3, 100):
        mid = m.triangles_at((k + 0.5) / 10.0).astype(np.float64)
        np.testing.assert_allclose(mid, (0.5 * (g[k] + g[k + 1]))[faces], atol=3e-6 * scale)
    # an MD2 character is upright in gridrt's y-up axes: taller than wide and deep
    ext = np.ptp(g[0], axis=0)
    assert ext[1] > ext[0] and ext[1] > ext[2]


# ----------------------------------------------------------------------------- frame folders


def test_frame_folder(tmp_path):
    folder = tmp_path / "sheet"
    folder.mkdir()
    for k in range(12):  # natural order: f2 before f10
        write_obj(folder / f"f{k}.obj", grid_frame(k), GRID_F)
    s = make_scene(folder, fps=5)
    assert isinstance(s, KeyframeMesh) and s.n_frames == 12 and s.name == "sheet"
    assert s.frame_names[:3] == ["f0.obj", "f1.obj", "f2.obj"] and s.frame_names[10] == "f10.obj"
    assert s.duration == pytest.approx(11 / 5) and s.time_range == (0.0, pytest.approx(11 / 5))
    for k in range(11):
        np.testing.assert_array_equal(s.triangles_at(k / 5), grid_frame(k)[GRID_F].astype(np.float32))
        mid = s.triangles_at((k + 0.5) / 5).astype(np.float64)
        np.testing.assert_allclose(mid, (0.5 * (grid_frame(k) + grid_frame(k + 1)))[GRID_F], atol=1e-5)
    # only the triangles touching the rising column move
    np.testing.assert_array_equal(s.static_mask, [True, True, False, False])
    assert load_frame_folder(folder).fps == 30.0


def test_frame_folder_errors(tmp_path):
    folder = tmp_path / "bad"
    folder.mkdir()
    for k in range(3):
        write_obj(folder / f"f{k:03d}.obj", grid_frame(k), GRID_F)
    write_obj(folder / "f003.obj", grid_frame(3), GRID_F[:3])
    with pytest.raises(SceneFileError) as info:
        make_scene(folder)
    assert info.value.path == str(folder / "f003.obj") and "connectivity" in info.value.problem
    (folder / "f003.obj").unlink()
    write_obj(folder / "f003.obj", grid_frame(3), GRID_F[:, ::-1])  # same counts, other faces
    with pytest.raises(SceneFileError, match="f003.obj"):
        make_scene(folder)
    (folder / "f003.obj").unlink()
    (folder / "f004.ply").write_text("ply\n")
    with pytest.raises(SceneFileError, match="mixes"):
        make_scene(folder)
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(SceneFileError, match="no frame files"):
        make_scene(empty)
    for kw in ({"clip": 1}, {"animate": "wave"}, {"subdivide": 10}, {"fps": -1}):
        with pytest.raises(InputError):
            make_scene(tmp_path / "bad", **kw)


def test_keyframe_mesh_validation():
    v = np.stack([grid_frame(k) for k in range(3)])
    with pytest.raises(InputError):
        KeyframeMesh(v[0], GRID_F, 10)
    bad = v.copy()
    bad[2, 0, 0] = np.nan
    with pytest.raises(InputError, match="frame 2"):
        KeyframeMesh(bad, GRID_F, 10)
    with pytest.raises(InputError):
        KeyframeMesh(v, GRID_F + 10, 10)
    one = KeyframeMesh(v[:1], GRID_F, 10)
    assert one.static and one.duration is None
