"""The batch ray-casting API (engine.RayCaster) against the brute-force float64 caster."""

import numpy as np
import pytest

import engine
from conftest import icosphere
from reference import compare_hits, ref_cast


def _rays(rng, n, r=3.0):
    o = rng.normal(size=(n, 3))
    o = o / np.linalg.norm(o, axis=1, keepdims=True) * r
    d = -o + rng.normal(scale=0.6, size=(n, 3))
    return o, d


def test_cast_and_update_match_brute_force(rng):
    v, f = icosphere(3)
    caster = engine.RayCaster(v, f)
    o, d = _rays(rng, 3000)
    for frame in range(3):
        verts = v * (1.0 + 0.3 * frame) + np.array([0.1 * frame, 0.0, -0.2 * frame], np.float32)
        if frame:
            caster.update(verts)
        hits = caster.cast(o, d)
        ref = ref_cast(verts[f], o, d)
        diff = compare_hits(hits.t, hits.tri, ref)
        assert len(diff.bad) == 0, f"frame {frame}: {len(diff.bad)} rays disagree"
        hit = hits.tri >= 0
        assert hit.any() and (~hit).any()
        # barycentrics reproduce the hit point
        tri = verts[f][hits.tri[hit]].astype(np.float64)
        u, w = hits.u[hit, None], hits.v[hit, None]
        p = (1 - u - w) * tri[:, 0] + u * tri[:, 1] + w * tri[:, 2]
        q = o[hit] + hits.t[hit, None] * d[hit]
        assert np.abs(p - q).max() < 1e-5
        assert np.isinf(hits.t[~hit]).all() and (hits.tri[~hit] == -1).all()


def test_from_triangles_any_hit_and_thread_counts(rng):
    v, f = icosphere(2)
    tris = v[f]
    caster = engine.RayCaster.from_triangles(tris)
    o, d = _rays(rng, 2000)
    ref = ref_cast(tris, o, d, tmax=2.5)
    base = caster.cast(o, d, tmax=2.5, threads=1)
    assert len(compare_hits(base.t, base.tri, ref).bad) == 0
    anyh = caster.cast(o, d, tmax=2.5, any_hit=True)
    assert np.array_equal(anyh.tri >= 0, ref.tri >= 0)
    for n in (2, 3, 8, engine.threads.max_threads()):
        h = caster.cast(o, d, tmax=2.5, threads=n)
        assert np.array_equal(h.tri, base.tri) and np.array_equal(h.t, base.t)


@pytest.mark.parametrize(
    "bad, message",
    [
        (lambda v: v[:-1], "shape"),
        (lambda v: np.where(np.arange(len(v))[:, None] == 3, np.nan, v), "NaN"),
    ],
)
def test_update_rejects_bad_vertices(bad, message):
    v, f = icosphere(1)
    caster = engine.RayCaster(v, f)
    with pytest.raises(engine.InputError, match=message):
        caster.update(bad(v))


def test_bad_meshes_rejected():
    v, f = icosphere(1)
    with pytest.raises(engine.InputError, match="out of range"):
        engine.RayCaster(v, f + len(v))
    with pytest.raises(engine.InputError, match="negative"):
        engine.RayCaster(v, f - 1)
    with pytest.raises(engine.InputError, match="empty"):
        engine.RayCaster(v[:0], f[:0])
    with pytest.raises(engine.InputError, match="degenerate"):
        engine.RayCaster(np.zeros((3, 3)), [[0, 1, 2]])
    caster = engine.RayCaster(v, f)
    with pytest.raises(engine.InputError, match="zero vector"):
        caster.cast([[0, 0, 5.0]], [[0, 0, 0.0]])
    with pytest.raises(engine.InputError, match="tmin"):
        caster.cast([[0, 0, 5.0]], [[0, 0, -1.0]], tmin=2.0, tmax=1.0)
