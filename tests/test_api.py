"""The batch ray-casting API (gridrt.RayCaster) against the brute-force float64 caster."""

import sys

import numpy as np
import pytest

import gridrt
from conftest import icosphere
from helpers.memory import traced
from reference import compare_hits, ref_cast


def _rays(rng, n, r=3.0):
    o = rng.normal(size=(n, 3))
    o = o / np.linalg.norm(o, axis=1, keepdims=True) * r
    d = -o + rng.normal(scale=0.6, size=(n, 3))
    return o, d


def test_cast_and_update_match_brute_force(rng):
    v, f = icosphere(3)
    caster = gridrt.RayCaster(v, f)
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
    caster = gridrt.RayCaster.from_triangles(tris)
    o, d = _rays(rng, 2000)
    ref = ref_cast(tris, o, d, tmax=2.5)
    base = caster.cast(o, d, tmax=2.5, threads=1)
    assert len(compare_hits(base.t, base.tri, ref).bad) == 0
    anyh = caster.cast(o, d, tmax=2.5, any_hit=True)
    assert np.array_equal(anyh.tri >= 0, ref.tri >= 0)
    for n in (2, 3, 8, gridrt.threads.max_threads()):
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
    caster = gridrt.RayCaster(v, f)
    with pytest.raises(gridrt.InputError, match=message):
        caster.update(bad(v))


def test_bad_meshes_rejected():
    v, f = icosphere(1)
    with pytest.raises(gridrt.InputError, match="out of range"):
        gridrt.RayCaster(v, f + len(v))
    with pytest.raises(gridrt.InputError, match="negative"):
        gridrt.RayCaster(v, f - 1)
    with pytest.raises(gridrt.InputError, match="empty"):
        gridrt.RayCaster(v[:0], f[:0])
    with pytest.raises(gridrt.InputError, match="degenerate"):
        gridrt.RayCaster(np.zeros((3, 3)), [[0, 1, 2]])
    caster = gridrt.RayCaster(v, f)
    with pytest.raises(gridrt.InputError, match="zero vector"):
        caster.cast([[0, 0, 5.0]], [[0, 0, 0.0]])
    with pytest.raises(gridrt.InputError, match="tmin"):
        caster.cast([[0, 0, 5.0]], [[0, 0, -1.0]], tmin=2.0, tmax=1.0)


def _local_ref(verts, f, o, d, **kw):
    """Brute-force hits over the triangles as the caster stores them: float32 in a frame centred
    on the vertices' bounds (its documented frame), the rays moved alike, in float64."""
    c = 0.5 * (verts.min(axis=0) + verts.max(axis=0))
    return ref_cast((verts - c)[f], o - c, d, **kw)


def test_update_refuses_all_degenerate_mesh_keeping_old(rng):
    """update() refuses a mesh whose triangles all have zero area, as the constructor does, and
    the caster keeps casting against its previous mesh."""
    v, f = icosphere(2)
    v = v.astype(np.float64) + 50.0
    caster = gridrt.RayCaster(v, f)
    o, d = _rays(rng, 1500)
    o = o + 50.0
    flat = v.copy()
    flat[:, 2] = 7.0  # every triangle in one plane ...
    flat[:, 1] = 2.0 * flat[:, 0]  # ... and on one line: zero area
    with pytest.raises(gridrt.InputError, match=f"all {len(f)} triangles are degenerate") as made:
        gridrt.RayCaster(flat, f)
    with pytest.raises(gridrt.InputError, match=f"all {len(f)} triangles are degenerate") as updated:
        caster.update(flat)
    assert str(updated.value).startswith("update") and str(made.value).endswith("(zero area)")
    hits = caster.cast(o, d)
    ref = _local_ref(v, f, o, d)
    assert (ref.tri >= 0).sum() > 500
    assert len(compare_hits(hits.t, hits.tri, ref).bad) == 0


def test_user_errors_never_mention_internals(rng):
    """What a RayCaster user can get wrong is reported in their terms: no stale grid, no builder,
    no internal function (the caster's grids are never stale: see test_caster_threads)."""
    v, f = icosphere(1)
    caster = gridrt.RayCaster(v, f)
    o, d = _rays(rng, 10)
    huge = np.broadcast_to(o[:1], (10**11, 3))
    calls = [
        lambda: caster.cast(o[:, :2], d[:, :2]), lambda: caster.cast(o, d[:5]),
        lambda: caster.cast(np.where(o > 1, np.nan, o), d), lambda: caster.cast(o, d * 0),
        lambda: caster.cast(o, d, tmin=3, tmax=1), lambda: caster.cast(o, d, threads=0),
        lambda: caster.cast(huge, np.broadcast_to(d[:1], huge.shape)), lambda: caster.cast(o, d, max_bytes=10),
        lambda: caster.update(v[:-1]), lambda: caster.update(np.full(v.shape, np.inf)),
        lambda: caster.update(np.zeros(v.shape)), lambda: caster.update(v * 1e31),
        lambda: caster.update(np.full(v.shape, "x")),
    ]
    for call in calls:
        with pytest.raises(gridrt.InputError) as e:
            call()
        msg = str(e.value)
        for word in ("stale", "GridBuilder", "cast_batch", "build_grid", "_check", "kernel"):
            assert word not in msg, msg
    for _ in range(5):  # many updates later the caster still casts (its grid is never stale)
        caster.update(v * 1.1)
        caster.update(v)
    assert len(compare_hits(caster.cast(o, d).t, caster.cast(o, d).tri, _local_ref(v, f, o, d)).bad) == 0


def _odd_rays(rng, n, offset):
    """Rays through an icosphere at ``offset``, every fifth with a direction scaled far from unit
    length (2**-300 or 2**200: the caster rescales those), as (origins, directions, scale)."""
    o, d = _rays(rng, n)
    scale = np.ones(n)
    scale[::5] = 2.0**-300
    scale[2::10] = 2.0**200
    return o + offset, d * scale[:, None], scale


def test_chunk_boundaries_change_nothing(rng, monkeypatch):
    """A batch cast in chunks (of 1, 7, 1000 rays) gives exactly the hits of one cast, for
    RayCaster.cast and cast_rays, from float64, strided, Fortran-order and float32 inputs, with
    rays of odd direction lengths on both sides of chunk boundaries; and those hits are the
    reference's.  Whatever the inputs' layout, the batch kernel is given C-contiguous rays (one
    compile serves every layout)."""
    from numba import types

    from gridrt.trace import cast_rays
    from gridrt.trace.batch import cast_runs_kernel

    render_mod = sys.modules["gridrt.trace.render"]
    offset = np.array([300.0, -20.0, 7.0])
    v, f = icosphere(3)
    v = v.astype(np.float64) + offset
    caster = gridrt.RayCaster(v, f)
    tris32 = v[f].astype(np.float32)
    grid = gridrt.build_grid(tris32)
    o, d, scale = _odd_rays(rng, 3001, offset)
    wide = np.zeros((len(o), 7))
    wide[:, 1:7:2] = d
    wide_o = np.zeros((len(o), 6))
    wide_o[:, ::2] = o
    variants = {"float64": (o, d), "strided": (wide_o[:, ::2], wide[:, 1:7:2]),
                "fortran": (np.asfortranarray(o), np.asfortranarray(d)),
                "float32": (o.astype(np.float32), (d / scale[:, None]).astype(np.float32))}
    assert not variants["strided"][0].flags.c_contiguous and not variants["strided"][1].flags.c_contiguous
    assert not variants["fortran"][0].flags.c_contiguous
    for name, (oo, dd) in variants.items():
        whole = [caster.cast(oo, dd), cast_rays(grid, tris32, oo, dd)]
        for chunk in (1, 7, 1000):
            n = 300 if chunk == 1 else len(oo)  # (one kernel call a ray: the first 300 rays show it)
            monkeypatch.setattr(render_mod, "CAST_CHUNK", chunk)
            parts = [caster.cast(oo[:n], dd[:n]), cast_rays(grid, tris32, oo[:n], dd[:n])]
            monkeypatch.undo()
            for a, b in zip(whole, parts):
                for field in ("t", "tri", "u", "v"):
                    assert np.array_equal(getattr(a, field)[:n], getattr(b, field)), (name, chunk, field)
        if name != "float32":
            ref = _local_ref(v, f, o, d / scale[:, None])
            assert (ref.tri >= 0).sum() > 1000
            # t is in units of the direction as given: scale it to the unit-length one's
            assert len(compare_hits(whole[0].t * scale, whole[0].tri, ref).bad) == 0, name
    layouts = {a.layout for sig in cast_runs_kernel.signatures for a in sig if isinstance(a, types.Array)}
    assert layouts == {"C"}, cast_runs_kernel.signatures


def test_cast_memory_is_bounded(rng, monkeypatch):
    """A cast allocates its results plus one chunk's scratch, not copies of its inputs: float32,
    strided rays, all with odd direction lengths (the costliest case), cast 8192 at a time."""
    render_mod = sys.modules["gridrt.trace.render"]
    v, f = icosphere(2)
    caster = gridrt.RayCaster(v.astype(np.float64) + 40.0, f)
    n, chunk = 300_000, 8192
    o, d = _rays(rng, n)
    o_in = np.asfortranarray((o + 40.0).astype(np.float32))
    d_in = np.asfortranarray((d * 2.0**-110).astype(np.float32))  # representable, rescaled by the caster
    monkeypatch.setattr(render_mod, "CAST_CHUNK", chunk)
    plain = caster.cast(o_in, np.asfortranarray(d.astype(np.float32)))
    bound = render_mod.cast_bytes(n, chunk)
    # the bound is well below the results plus even one float64 copy of the origins
    assert bound < 28 * n + 24 * n // 2
    with traced() as m:
        hits = caster.cast(o_in, d_in)
    peak = m.peak
    mib = 1 / 2**20
    print(f"FIGURE cast memory: {n} rays, chunk {chunk}: peak {peak * mib:.2f} MiB allocated, results "
          f"{28 * n * mib:.2f} MiB, declared bound {bound * mib:.2f} MiB, "
          f"inputs {(o_in.nbytes + d_in.nbytes) * mib:.2f} MiB")
    assert 28 * n <= peak <= bound, (peak, bound)
    # a direction scaled by a power of two gives the same hits, t scaled back
    assert (plain.tri >= 0).sum() > n // 4
    assert np.array_equal(hits.tri, plain.tri)
    hit = plain.tri >= 0
    assert np.allclose(hits.t[hit], np.ldexp(plain.t[hit], 110), rtol=1e-9, atol=0)


def test_batch_beyond_the_budget_is_refused_before_allocating(rng):
    """A RayCaster's casts share its params' memory budget (max_bytes): a batch whose results do
    not fit is refused with a message naming the rays and the budget, allocating nothing."""
    v, f = icosphere(1)
    caster = gridrt.RayCaster(v, f, gridrt.GridParams(max_bytes=1 << 20))
    o, d = _rays(rng, 3000)
    assert len(compare_hits(caster.cast(o, d).t, caster.cast(o, d).tri, _local_ref(v, f, o, d)).bad) == 0
    n = 1_000_000
    big_o, big_d = np.broadcast_to(o[:1], (n, 3)), np.broadcast_to(d[:1], (n, 3))
    with traced() as m:
        with pytest.raises(gridrt.InputError, match=rf"casting {n} rays at once needs \d+ MiB .*max_bytes=1 MiB"):
            caster.cast(big_o, big_d)
    assert m.peak < 1 << 16, m.peak
    assert caster.cast(big_o, big_d, max_bytes=1 << 30).tri.shape == (n,)


def _grid_equal(a, b):
    """The same grid, cell lists and geometry (and a two-level grid's leaf levels)."""
    np.testing.assert_array_equal(a.spec.lo, b.spec.lo)
    np.testing.assert_array_equal(a.spec.hi, b.spec.hi)
    np.testing.assert_array_equal(a.spec.dims, b.spec.dims)
    assert a.references == b.references
    np.testing.assert_array_equal(a.cell_start, b.cell_start)
    np.testing.assert_array_equal(a.tri_ids[:a.references], b.tri_ids[:b.references])
    assert getattr(a, "kind", "uniform") == getattr(b, "kind", "uniform")
    if getattr(a, "kind", "uniform") == "two_level":
        for name in ("leaf_res", "leaf_first", "top_start"):
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
        np.testing.assert_array_equal(a.top_ids[:a.top_references], b.top_ids[:b.top_references])


@pytest.mark.parametrize("grid,threads", [("uniform", 1), ("uniform", 2), ("two_level", 2)])
@pytest.mark.parametrize("unused", [False, True])
def test_caster_grid_is_the_grid_of_its_triangles(grid, threads, unused, rng):
    """An update gives its build the bounds of the vertices in the caster's frame (float32 of the
    float64 bounds less the origin) in place of a pass over the triangles: the grid equals the
    one a build finds the triangles' bounds for itself, after construction and after updates, for
    a mesh far from the world origin (where the frame's rounding matters); a mesh with a vertex no
    face uses (far outside the triangles' box) gets the triangles' bounds."""
    from gridrt.config import GridParams
    from gridrt.grid.build import GridBuilder

    v, f = icosphere(3)
    v = v.astype(np.float64) * 3.7 + np.array([1e5 + 0.3, -2e4, 7.1])
    if unused:
        v = np.concatenate([v, v[:1] + 50.0])  # a vertex of no face
    params = GridParams(grid=grid, threads=threads)
    caster = gridrt.RayCaster(v, f, params)
    for step in range(3):
        if step:
            caster.update(v * (1.0 + 1e-3 * step) + rng.normal(scale=1e-3, size=v.shape))
        ref = GridBuilder(params).build(np.array(caster.triangles))
        _grid_equal(caster.grid, ref)
        assert np.all(caster.triangles.reshape(-1, 3).min(axis=0) == caster.grid.spec.scene_lo)
        assert np.all(caster.triangles.reshape(-1, 3).max(axis=0) == caster.grid.spec.scene_hi)


def test_update_writes_over_its_old_arrays_only_when_nothing_holds_them(rng):
    """An update writes the new mesh into the arrays of the mesh before the last one when nothing
    holds them (no new memory to fault in); a user's reference to ``caster.triangles`` or
    ``caster.vertices``, a view of one, or a cast still running on that mesh keeps them as they
    were.  Every mesh casts as the brute force does."""
    import weakref

    v, f = icosphere(3)
    o, d = _rays(rng, 1500)
    frames = [v * (1.0 + 0.05 * k) + np.float32(0.01 * k) for k in range(8)]
    caster = gridrt.RayCaster(frames[0], f)

    def check(k):
        hits = caster.cast(o, d)
        assert len(compare_hits(hits.t, hits.tri, _local_ref(frames[k], f, o, d)).bad) == 0

    caster.update(frames[1])
    wt, wv = weakref.ref(caster.triangles), weakref.ref(caster.vertices)
    caster.update(frames[2])
    caster.update(frames[3])  # into the arrays of frame 1
    assert caster.triangles is wt() and caster.vertices is wv()
    check(3)

    held = caster.triangles  # a user's reference
    held_copy = held.copy()
    view = caster.vertices[::7]  # a view keeps its base
    view_copy = view.copy()
    for k in (4, 5, 6):
        caster.update(frames[k])
        check(k)
    assert caster.triangles is not held
    np.testing.assert_array_equal(held, held_copy)
    np.testing.assert_array_equal(view, view_copy)

    # a cast holding the current mesh (as cast and all_hits do, for their whole run)
    with caster._lock:
        snap = caster._snap
        snap.users += 1
    kept = snap.triangles.copy(), snap.vertices.copy()
    for k in (7, 0, 1):
        caster.update(frames[k])
        check(k)
    np.testing.assert_array_equal(snap.triangles, kept[0])
    np.testing.assert_array_equal(snap.vertices, kept[1])
    caster._release(snap)
