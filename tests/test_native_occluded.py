"""The native occlusion tool behind the shadow-ray table's native columns (gridrt.app.bench.occluded,
occluded.cpp): compiled here when Embree 3's headers and g++ are installed (.ci/apt-packages installs
them), its verdicts in every mode are those of a float64 brute force on segments clear of rounding,
over two meshes (in any order) and batches whose lengths are not multiples of a packet or a group, segments
that cross and that end short of a crossing or just past it."""

import numpy as np
import pytest
import trimesh

from reference import ref_cast

from gridrt.app.bench import occluded
from gridrt.app.bench.sides import MissingPeer
from gridrt.errors import InputError

#: barycentric margin that float32 rounding cannot cross on these unit-sized meshes
TOL = 1e-5


@pytest.fixture(scope="module")
def tool(tmp_path_factory):
    try:
        return occluded.build(tmp_path_factory.mktemp("bin") / "embree_occluded")
    except MissingPeer as e:
        pytest.skip(str(e))


def _points(rng, n, r0, r1):
    v = rng.normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1)[:, None] * rng.uniform(r0, r1, (n, 1))


def _segments(rng, n, inner):
    """n segments from points at radius 1.5-3 to points at radius <= 0.5 (inner) or 1.5-3: their
    ends lie far from the unit meshes' surfaces."""
    a = _points(rng, n, 1.5, 3.0)
    return a, (_points(rng, n, 0.0, 0.5) if inner else _points(rng, n, 1.5, 3.0)) - a


def _short_segments(rng, n, tris):
    """n segments from points at radius 1.5-3 towards points near the centre, ending 3-10 % short
    of the first crossing of the mesh or 3-10 % beyond it (so a segment's end decides it)."""
    a = _points(rng, n, 1.5, 3.0)
    d = _points(rng, n, 0.0, 0.3) - a
    t = ref_cast(tris, a, d).t
    assert np.isfinite(t).all()
    f = rng.uniform(0.03, 0.1, n) * np.where(rng.random(n) < 0.5, -1.0, 1.0)
    return a, d * (t * (1.0 + f))[:, None]


def _clear_and_blocked(tris, o, d):
    """(clear, blocked) of the float64 brute force: clear where no edge of a triangle lies within TOL
    (barycentric) of the segment's crossing of its plane."""
    ref = ref_cast(tris, o, d, 0.0, 1.0)
    hit = ref.hit
    clear = np.where(hit, np.nan_to_num(ref.edge, nan=-1.0) > TOL, ref.graze < -TOL)
    return clear, hit


def test_every_mode_matches_the_float64_brute_force(tool, tmp_path):
    rng = np.random.default_rng(7)
    sphere = trimesh.creation.icosphere(subdivisions=3)
    box = trimesh.creation.box(extents=(1.2, 0.4, 1.0))
    meshes = [np.asarray(box.triangles, np.float32), np.asarray(sphere.triangles, np.float32)]
    # lengths that leave partial 16-ray packets and 64-ray groups; the larger mesh used first
    batches = [(1, *_segments(rng, 1000, True)), (0, *_segments(rng, 77, False)), (1, *_segments(rng, 333, False)),
               (1, *_short_segments(rng, 500, meshes[1]))]
    occluded.write_folder(tmp_path, meshes, batches)
    clear, want = [], []
    for m, o, d in batches:
        c, h = _clear_and_blocked(meshes[m], np.asarray(o, np.float32), np.asarray(d, np.float32))
        clear.append(c)
        want.append(h)
    clear, want = np.concatenate(clear), np.concatenate(want)
    assert clear.mean() > 0.95 and 0.2 < want.mean() < 0.8   # (the segments test both verdicts)
    for robust in (False, True):
        res = occluded.cast(tool, tmp_path, threads=2, reps=1, warmup=0, robust=robust, verdicts=True)
        assert sorted(res) == sorted(occluded.MODES)
        for mode, r in res.items():
            assert r["segments"] == len(want) == len(r["verdicts"]) and r["batches"] == 4, mode
            assert r["robust"] is robust and r["threads"] == 2 and r["ms"] > 0
            assert np.array_equal(r["verdicts"][clear], want[clear]), (mode, robust)
            assert r["verdicts"].sum() == r["blocked"]


def test_a_bad_folder_is_a_clear_error(tool, tmp_path):
    occluded.write_folder(tmp_path, [np.zeros((1, 3, 3))], [(0, np.zeros((4, 3)), np.ones((4, 3)))])
    (tmp_path / "batch_0_directions.npy").unlink()
    with pytest.raises(InputError, match="batch_0_directions.npy"):
        occluded.cast(tool, tmp_path, 1, 1, 0)
    with pytest.raises(InputError, match="must both be"):
        occluded.write_folder(tmp_path, [np.zeros((1, 3, 3))], [(0, np.zeros((4, 3)), np.ones((5, 3)))])
    with pytest.raises(InputError, match="no mesh 1"):
        occluded.write_folder(tmp_path, [np.zeros((1, 3, 3))], [(1, np.zeros((4, 3)), np.ones((4, 3)))])
