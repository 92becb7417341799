"""RayCaster.all_hits and count_hits against references of their own: a float64 brute force over
every triangle (random rays on real meshes), crossings that must pair up on closed meshes (rays
through the shared edges and vertices of the icosphere and of the shipped armadillo, from outside
and from inside), the exact sign of a 2x2 determinant (fractions), and the same hits for every
thread count, ray order, grid kind, t range and cap."""

from fractions import Fraction
from pathlib import Path

import numpy as np
import pytest
from numba import njit

import gridrt
from gridrt.config import GridParams
from gridrt.errors import InputError
from gridrt.scene import icosphere_mesh
from gridrt.trace import all_hits as ah
from gridrt.trace.all_hits import det2_sign
from gridrt.trace.intersect import ray_shear
from reference import ref_all_hits

ASSETS = Path(__file__).resolve().parents[1] / "assets"


def _armadillo():
    import trimesh

    m = trimesh.load(ASSETS / "armadillo.ply", process=False)
    return np.asarray(m.vertices, np.float64), np.asarray(m.faces, np.int64)


def test_det2_sign_exact():
    """The sign of a d - b c, also where float64 rounding of the products would decide it."""
    rng = np.random.default_rng(5)
    cases = [(1.0, 1.0, 1.0, 1.0), (0.0, 3.0, 0.0, 7.0), (1e-300, 1e300, 1e-300, 1e300)]
    for _ in range(3000):
        a, b = rng.normal(size=2) * 10.0 ** rng.integers(-8, 8, 2)
        k = rng.normal()
        c, d = a * k, b * k   # nearly dependent rows: a d - b c is tiny against its terms
        c = np.nextafter(c, c + rng.choice([-1, 1])) if rng.random() < 0.5 else c
        cases.append((a, b, c, d))
    for a, b, c, d in cases:
        exact = Fraction(a) * Fraction(d) - Fraction(b) * Fraction(c)
        assert det2_sign(a, b, c, d) == (exact > 0) - (exact < 0), (a, b, c, d)


@pytest.mark.parametrize("mesh, grid, prefetch", [("icosphere", "uniform", False), ("icosphere", "two_level", False),
                                                  ("icosphere", "uniform", True), ("icosphere", "two_level", True),
                                                  ("ellipsoid", "two_level", False),
                                                  ("soup", "uniform", False), ("soup", "uniform", True),
                                                  pytest.param("armadillo", "uniform", False, marks=pytest.mark.slow)])
def test_all_hits_against_brute_force(monkeypatch, mesh, grid, prefetch):
    """Random rays (origins inside and around the mesh): the hits, in order, are the float64 brute
    force's, triangle for triangle, wherever no brute-force hit lies within 1e-6 (barycentric) of
    an edge; count_hits agrees with all_hits; every ray's crossings of a closed mesh pair up
    (even counts from outside the bounds).  The ellipsoid's two-level grid has leaf grids of
    different resolutions along the three axes.  The soup of small triangles fills its box, so
    every macro cell holds triangles and rays list more cells than the walk visits at once
    (all_hits.CELLS).  With ``prefetch`` the walk starts the loads of its cells' references and
    triangles before it tests them (which it does on large meshes only) on these small ones."""
    walks = []
    if prefetch:
        monkeypatch.setattr(ah, "PREFETCH_TRIANGLES", 1)
    on_chunks = ah._on_chunks

    def noted(kernel, threads, g, *rest):
        walks.append(g.prefetch)
        return on_chunks(kernel, threads, g, *rest)

    monkeypatch.setattr(ah, "_on_chunks", noted)
    if mesh in ("icosphere", "ellipsoid"):
        m = icosphere_mesh(5120)
        V, Fc = m.vertices * ([1.0, 1.7, 0.6] if mesh == "ellipsoid" else 1.0), m.faces
    elif mesh == "soup":
        r = np.random.default_rng(3)
        centres = (np.stack(np.meshgrid(*[np.arange(12)] * 3, indexing="ij"), -1).reshape(-1, 1, 3) + 0.5) / 12
        V = (centres + r.normal(0, 0.05, (len(centres), 3, 3))).reshape(-1, 3)   # one on each point of a lattice
        Fc = np.arange(len(V)).reshape(-1, 3)
    else:
        V, Fc = _armadillo()
    caster = gridrt.RayCaster(V, Fc, GridParams(grid=grid))
    if mesh == "ellipsoid":
        res = caster.grid.leaf_res[caster.grid.leaf_res[:, 0] > 0]
        assert np.any((res[:, 0] != res[:, 1]) | (res[:, 1] != res[:, 2]))
    tris = caster.triangles   # the mesh as the caster keeps it: float32, in its frame at caster.origin
    lo, hi = V.min(0), V.max(0)
    rng = np.random.default_rng(11)
    N = 400
    O = rng.uniform(lo - 0.3 * (hi - lo), hi + 0.3 * (hi - lo), (N, 3))
    D = rng.uniform(lo + 0.2 * (hi - lo), hi - 0.2 * (hi - lo), (N, 3)) - O   # towards the mesh's middle
    got = caster.all_hits(O, D)
    assert np.array_equal(caster.count_hits(O, D), got.counts())
    ref = ref_all_hits(tris, O - caster.origin, D)
    compared = 0
    for i, (t, f, u, v, edge) in enumerate(ref):
        s = slice(got.offsets[i], got.offsets[i + 1])
        assert np.all(np.diff(got.t[s]) >= 0)
        if len(edge) and edge.min() < 1e-6:
            continue
        compared += 1
        assert np.array_equal(got.tri[s], f), i
        assert np.allclose(got.t[s], t, rtol=1e-9, atol=0) and np.allclose(got.u[s], u, atol=1e-9) \
            and np.allclose(got.v[s], v, atol=1e-9)
    assert compared > 0.95 * N and got.counts().sum() > N, (compared, got.counts().sum())
    if mesh == "soup":   # the cells of the box a ray crosses (every one listed: all macro cells hold triangles)
        assert np.all(caster.grid.macro_full)
        sp = caster.grid.spec
        cell, dims, glo = np.asarray(sp.cell), np.asarray(sp.dims), np.asarray(sp.lo) + caster.origin
        inv = 1.0 / np.where(D == 0, 1e-300, D)
        ta, tb = (glo - O) * inv, (glo + dims * cell - O) * inv
        t0, t1 = np.maximum(np.minimum(ta, tb).max(1), 0), np.maximum(ta, tb).min(1)
        at = lambda t: np.clip(np.floor((O + t[:, None] * D - glo) / cell), 0, dims - 1)
        crossed = np.where(t0 < t1, np.abs(at(t1) - at(t0)).sum(1) + 1, 0)
        assert crossed.max() > ah.CELLS, crossed.max()
    else:
        outside = np.any((O < lo) | (O > hi), axis=1)
        assert np.all(got.counts()[outside] % 2 == 0)
    assert walks and set(walks) == {prefetch}


def _edges_and_vertices(faces):
    e = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    return np.unique(e, axis=0)


def test_one_crossing_at_shared_edges_and_vertices():
    """Rays aimed exactly at the icosphere's vertices and edge midpoints (and at points along its
    edges): from outside, through the sphere, exactly 2 crossings each; from inside, exactly 1 (no
    hole, no double count where two or six triangles meet); the armadillo (closed, not convex):
    an even count for every ray from outside its bounds through its vertices and edges."""
    m = icosphere_mesh(20480)
    V, Fc = m.vertices, m.faces
    caster = gridrt.RayCaster(V, Fc)
    E = _edges_and_vertices(Fc)
    rng = np.random.default_rng(2)
    w = rng.random((len(E), 1))
    targets = np.concatenate([V, 0.5 * (V[E[:, 0]] + V[E[:, 1]]), (1 - w) * V[E[:, 0]] + w * V[E[:, 1]]])
    inner = rng.normal(size=(len(targets), 3)) * 0.2
    inner /= np.maximum(1.0, np.linalg.norm(inner, axis=1) / 0.8)[:, None]   # origins inside (|o| <= 0.8)
    outer = targets * 3.0 + rng.normal(size=(len(targets), 3)) * 0.2   # outside (10 sigma), aimed through the target
    for O, want in ((inner, 1), (outer, 2), (np.zeros((len(targets), 3)), 1)):
        D = targets - O
        n = caster.count_hits(O, D)
        assert np.all(n == want), (want, np.bincount(n))
    assert len(targets) > 60000

    V, Fc = _armadillo()
    caster = gridrt.RayCaster(V, Fc)
    E = _edges_and_vertices(Fc)
    targets = np.concatenate([V, 0.5 * (V[E[:, 0]] + V[E[:, 1]])]).astype(np.float64)
    lo, hi = V.min(0), V.max(0)
    O = rng.uniform(lo, hi, (len(targets), 3))
    O[:, rng.integers(0, 3, len(O))[0]] = hi.max() + 2 * (hi - lo).max()   # beyond the bounds
    n = caster.count_hits(O, targets - O)
    assert np.all(n % 2 == 0) and np.mean(n >= 2) > 0.99, np.bincount(n)


def test_rays_from_the_surface_and_grazing():
    """A ray starting on the sphere's surface (t_min 0: the open interval leaves its own point out
    when the ray leaves the surface along the normal): inward, one crossing, outward none; a ray in
    a triangle's plane (det 0) never hits it."""
    m = icosphere_mesh(1280)
    caster = gridrt.RayCaster(m.vertices, m.faces)
    tris = m.vertices[m.faces]
    rng = np.random.default_rng(4)
    b = rng.dirichlet([2, 2, 2], len(tris))
    P = np.einsum("ij,ijk->ik", b, tris)
    normal = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
    normal *= np.sign(np.einsum("ij,ij->i", normal, P))[:, None]
    eps = np.full(len(P), 1e-9)
    assert np.all(caster.count_hits(P, -normal, t_min=eps) == 1)
    assert np.all(caster.count_hits(P, normal, t_min=eps) == 0)
    flat = gridrt.RayCaster(np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]]), np.array([[0, 1, 2]]))
    assert flat.count_hits(np.array([[-1.0, 0.25, 0.0]]), np.array([[1.0, 0.0, 0.0]]))[0] == 0


@pytest.mark.slow
@pytest.mark.parametrize("grid", ["uniform", "two_level"])
def test_all_hits_ranges_cap_threads_order(grid):
    """t_min / t_max (numbers or one per ray) keep the hits inside them; max_hits keeps each ray's
    nearest ones; the hits are the same for 1, 2 and 3 threads, for the rays in any order, and for
    a uniform or two-level grid.  Rays and bounds given as numbers, arrays or read-only arrays are
    one kind of input to the kernels (one compile each for a grid kind)."""
    m = icosphere_mesh(5120)
    V = np.concatenate([m.vertices, m.vertices * 0.5 + 0.1])   # two nested spheres: up to 4 crossings
    Fc = np.concatenate([m.faces, m.faces + len(m.vertices)])
    caster = gridrt.RayCaster(V, Fc, GridParams(grid=grid))
    base = gridrt.RayCaster(V, Fc, GridParams(grid="uniform", threads=1))
    rng = np.random.default_rng(8)
    N = 3000
    O = rng.uniform(-3, 3, (N, 3))
    D = (rng.normal(scale=0.2, size=(N, 3)) - O)
    ref = base.all_hits(O, D, threads=1)
    assert np.bincount(ref.counts()).shape[0] == 5   # rays with 0 .. 4 crossings
    for threads in (1, 2, 3):
        h = caster.all_hits(O, D, threads=threads)
        for a, b in zip(h, ref):
            assert np.array_equal(a, b)
    perm = rng.permutation(N)
    h = caster.all_hits(O[perm], D[perm])
    for i in range(0, N, 97):
        j = perm[i]
        assert np.array_equal(h.t[h.offsets[i]:h.offsets[i + 1]], ref.t[ref.offsets[j]:ref.offsets[j + 1]])
    tmin = rng.uniform(0, 0.5, N)
    tmax = tmin + rng.uniform(0, 1.0, N)
    r = caster.all_hits(O, D, t_min=tmin, t_max=tmax)
    for i in range(N):
        t = ref.t[ref.offsets[i]:ref.offsets[i + 1]]
        assert np.array_equal(r.t[r.offsets[i]:r.offsets[i + 1]], t[(t > tmin[i]) & (t < tmax[i])])
    frozen = [a.copy() for a in (O, D, tmin, tmax)]
    for a in frozen:
        a.flags.writeable = False
    for a, b in zip(caster.all_hits(*frozen), r):
        assert np.array_equal(a, b)
    assert np.array_equal(caster.count_hits(*frozen), r.counts())
    for kernel in (ah.slot_kernel, ah.count_kernel):
        kinds = {}
        for sig in kernel.signatures:
            kinds.setdefault(sig[0], set()).add(sig[1])
        assert all(len(rays) == 1 for rays in kinds.values()), (kernel, kinds)
    assert np.array_equal(caster.count_hits(O, D, 0.2, 0.9), np.diff(caster.all_hits(O, D, 0.2, 0.9).offsets))
    c = caster.all_hits(O, D, max_hits=2)
    assert np.array_equal(c.counts(), np.minimum(ref.counts(), 2))
    for i in range(N):
        assert np.array_equal(c.tri[c.offsets[i]:c.offsets[i + 1]], ref.tri[ref.offsets[i]:ref.offsets[i + 1]][:2])


def test_all_hits_after_update_and_far_from_the_origin():
    """update() moves the hits with the mesh; a mesh far from the world origin gives the same hits
    (the caster's frame)."""
    m = icosphere_mesh(1280)
    caster = gridrt.RayCaster(m.vertices, m.faces)
    O = np.array([[0.0, 0.0, 5.0], [0.3, 0.1, -5.0]])
    D = -O
    h0 = caster.all_hits(O, D)
    caster.update(m.vertices * 2.0)
    h1 = caster.all_hits(O, D)
    z0, z1 = 5.0 - 5.0 * h0.t[:2], 5.0 - 5.0 * h1.t[:2]   # ray 0, along the z axis through the centre
    assert h0.counts()[0] == h1.counts()[0] == 2 and np.allclose(z1, 2 * z0, rtol=1e-6)
    shift = np.array([1e6, -2e6, 3e5])
    far = gridrt.RayCaster(m.vertices + shift, m.faces).all_hits(O + shift, D)
    assert np.array_equal(far.tri, h0.tri) and np.allclose(far.t, h0.t, rtol=1e-6)


@pytest.mark.parametrize("kw, message", [
    ({"t_min": 2.0, "t_max": 1.0}, "need 0 <= t_min <= t_max"),
    ({"t_min": np.nan}, "need 0 <= t_min <= t_max"),
    ({"t_min": -1.0}, "need 0 <= t_min <= t_max"),
    ({"t_max": np.ones(5)}, "t_max must be a number or an array of one number a ray"),
    ({"max_hits": 0}, "max_hits must be a whole number >= 1"),
    ({"max_hits": True}, "max_hits must be a whole number >= 1"),
    ({"max_hits": 2.5}, "max_hits must be a whole number >= 1"),
])
def test_all_hits_bad_arguments(kw, message):
    m = icosphere_mesh(80)
    caster = gridrt.RayCaster(m.vertices, m.faces)
    with pytest.raises(InputError, match=message):
        caster.all_hits(np.zeros((3, 3)), np.ones((3, 3)), **kw)
    with pytest.raises(InputError, match="NaN"):
        caster.count_hits(np.array([[0.0, np.nan, 0]]), np.ones((1, 3)))
    empty = caster.all_hits(np.zeros((0, 3)), np.zeros((0, 3)))
    assert empty.offsets.tolist() == [0] and len(empty.t) == 0


# ---- contains ---------------------------------------------------------------------------------
def test_contains_sphere_through_vertices_and_edges():
    """Inside the icosphere: every point well inside, none outside; points whose ray (the fixed
    direction) passes exactly through a vertex or an edge midpoint on its way in or out are decided
    by the parity of real crossings; a triangle soup of the same sphere (corners welded by
    position) gives the same answers; the answers do not depend on the thread count."""
    from gridrt.api import CONTAINS_DIRECTION

    m = icosphere_mesh(5120)
    V, Fc = m.vertices, m.faces
    caster = gridrt.RayCaster(V, Fc)
    rng = np.random.default_rng(6)
    P = rng.uniform(-1.3, 1.3, (20000, 3))
    r = np.linalg.norm(P, axis=1)
    got = caster.contains(P)
    assert got[r < 0.99].all() and not got[r > 1.0].any()
    d = np.asarray(CONTAINS_DIRECTION) / np.linalg.norm(CONTAINS_DIRECTION)
    E = _edges_and_vertices(Fc)
    targets = np.concatenate([V, 0.5 * (V[E[:, 0]] + V[E[:, 1]])])
    cos = targets @ d
    leave = targets[cos > 0.3] - 0.4 * d    # inside; the ray leaves through the target
    enter = targets[cos < -0.3] - 0.4 * d   # outside; the ray enters through the target and leaves
    assert len(leave) > 2000 and len(enter) > 2000
    assert caster.contains(leave).all() and not caster.contains(enter).any()
    soup = gridrt.RayCaster.from_triangles(V[Fc])
    for threads in (1, 3):
        assert np.array_equal(soup.contains(P, threads=threads), got)


@pytest.mark.slow
def test_contains_armadillo_against_parity():
    """The armadillo (closed, not convex): contains equals the parity of a float64 brute-force
    count of crossings along three directions, at points where the three agree."""
    V, Fc = _armadillo()
    caster = gridrt.RayCaster(V, Fc)
    lo, hi = V.min(0), V.max(0)
    rng = np.random.default_rng(9)
    P = rng.uniform(lo, hi, (150, 3))
    tris = caster.triangles
    parity = []
    for d in ((0.3, 0.5, 0.81), (-0.7, 0.2, 0.3), (0.1, -0.9, -0.2)):
        hits = ref_all_hits(tris, P - caster.origin, np.broadcast_to(np.asarray(d, float), P.shape))
        parity.append([len(h[0]) % 2 for h in hits])
    parity = np.asarray(parity)
    agree = (parity == parity[0]).all(axis=0)
    assert agree.mean() > 0.95 and 10 < parity[0][agree].sum() < agree.sum() - 10
    assert np.array_equal(caster.contains(P)[agree], parity[0][agree] == 1)


def test_contains_open_mesh():
    """A mesh with borders (the teapot) is refused, naming how many edges are open, unless
    best_effort: then the vote of three rays, the same on every call."""
    import trimesh

    t = trimesh.load(ASSETS / "teapot.obj", process=False)
    caster = gridrt.RayCaster(np.asarray(t.vertices), np.asarray(t.faces))
    P = np.random.default_rng(1).uniform(t.bounds[0], t.bounds[1], (500, 3))
    with pytest.raises(InputError, match=r"contains needs a closed mesh: [\d,]+ of its edges .* best_effort=True"):
        caster.contains(P)
    a = caster.contains(P, best_effort=True)
    assert a.dtype == bool and 0 < a.sum() < len(a) and np.array_equal(a, caster.contains(P, best_effort=True))


# ---- attributes at hits -----------------------------------------------------------------------
def test_attributes_at_hits():
    """Interpolated per-vertex arrays at the hits of cast and of all_hits: the vertices themselves
    give the hit points o + t d, a linear function of position gives its value there (texture
    coordinates of a planar projection); geometric normals are the triangles' own, unit, facing
    out of the sphere; vertex normals of the sphere point along the vertices, and the shading
    normals at a hit along the hit point; misses give NaN."""
    m = icosphere_mesh(5120)
    V, Fc = m.vertices, m.faces
    caster = gridrt.RayCaster(V, Fc)
    rng = np.random.default_rng(12)
    N = 2000
    O = rng.normal(size=(N, 3)) * 3
    D = rng.uniform(-0.7, 0.7, (N, 3)) - O
    for hits, idx in ((caster.cast(O, D), np.arange(N)),
                      (caster.all_hits(O, D), np.repeat(np.arange(N), caster.count_hits(O, D)))):
        hit = hits.tri >= 0
        assert 0.3 < hit.mean() <= 1
        P = O[idx] + hits.t[:, None] * D[idx]
        got = caster.interpolate(hits, V)
        assert np.allclose(got[hit], P[hit], atol=1e-6) and np.isnan(got[~hit]).all()
        A = np.array([[0.3, -1.2], [0.7, 0.1], [-0.4, 2.0]])
        uv = caster.interpolate(hits, V @ A + [0.5, -0.25])
        assert uv.shape == (len(hits.tri), 2) and np.allclose(uv[hit], P[hit] @ A + [0.5, -0.25], atol=1e-6)
        n = caster.geometric_normals(hits)
        T = V[Fc[hits.tri[hit]]]
        want = np.cross(T[:, 1] - T[:, 0], T[:, 2] - T[:, 0])
        want /= np.linalg.norm(want, axis=1, keepdims=True)
        assert np.allclose(n[hit], want, atol=1e-6) and np.isnan(n[~hit]).all()
        assert (np.einsum("ij,ij->i", n[hit], P[hit]) > 0).all()   # the icosphere's winding faces out
        s = caster.shading_normals(hits)
        assert np.allclose(np.linalg.norm(s[hit], axis=1), 1) and \
            (np.einsum("ij,ij->i", s[hit], P[hit] / np.linalg.norm(P[hit], axis=1, keepdims=True)) > 0.999).all()
    vn = caster.vertex_normals()
    assert (np.einsum("ij,ij->i", vn, V / np.linalg.norm(V, axis=1, keepdims=True)) > 0.9999).all()
    h = caster.cast(O[:3], D[:3])
    with pytest.raises(InputError, match="one row a vertex"):
        caster.interpolate(h, V[:-1])
    with pytest.raises(InputError, match="hits must be what cast or all_hits returns"):
        caster.interpolate((1, 2, 3), V)
    with pytest.raises(InputError, match="outside this mesh"):
        caster.geometric_normals(type(h)(h.t, np.array([0, 5120, 1], np.int32), h.u, h.v))


def test_cast_takes_t_min_and_t_max():
    """cast's t_min / t_max are its tmin / tmax (the names all_hits uses); giving both names is refused."""
    m = icosphere_mesh(1280)
    caster = gridrt.RayCaster(m.vertices, m.faces)
    O, D = np.array([[0.0, 0.0, 3.0], [0.0, 0.0, 0.0]]), np.array([[0.0, 0.0, -1.0], [0.0, 0.0, 1.0]])
    a = caster.cast(O, D, t_min=2.5, t_max=10.0)
    b = caster.cast(O, D, 2.5, 10.0)
    assert np.array_equal(a.t, b.t) and np.array_equal(a.tri, b.tri)
    assert a.t[0] > 3.5 and a.tri[1] == -1   # the near side of the sphere left out by t_min; ray 1 ends inside
    with pytest.raises(InputError, match="give tmin or t_min, not both"):
        caster.cast(O, D, 1.0, t_min=2.0)


def _ordering(monkeypatch, on):
    """Make count_hits and all_hits take every batch in the order of order_keys (on) or never
    (off); returns the list the keys' calls are counted in."""
    monkeypatch.setattr(ah, "ORDER_RAYS", 1 if on else 1 << 62)
    monkeypatch.setattr(ah, "ORDER_TRIANGLES", 1 if on else 1 << 62)
    calls, keys = [], ah.order_keys

    def counted(*a):
        calls.append(1)
        return keys(*a)
    monkeypatch.setattr(ah, "order_keys", counted)
    return calls


@pytest.mark.parametrize("first_cap, block, ordered", [(1024, 1 << 16, False), (5, 7, False), (5, 7, True)])
def test_rays_with_many_hits_and_small_blocks(monkeypatch, first_cap, block, ordered):
    """A stack of 20 squares crossed by every ray: more hits a ray than all_hits keeps in its first
    walk (and, with the scratch made small, more than its first scratch holds), rays in blocks
    smaller than the batch, taken in the caller's order or in the cache-friendly one; the hits, in
    order, are the float64 brute force's, with and without a max_hits cap below and above what the
    first walk keeps."""
    monkeypatch.setattr(ah, "FIRST_CAP", first_cap)
    monkeypatch.setattr(ah, "SLOT_BLOCK", block)
    keyed = _ordering(monkeypatch, ordered)
    quad = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], np.float64)
    V = np.concatenate([quad + [0, 0, 0.1 * k] for k in range(20)])
    F = np.concatenate([np.array([[0, 1, 2], [0, 2, 3]]) + 4 * k for k in range(20)])
    caster = gridrt.RayCaster(V, F)
    rng = np.random.default_rng(9)
    N = 60
    O = np.column_stack([rng.uniform(0.1, 0.9, (N, 2)), np.full(N, -0.5)])
    D = np.column_stack([rng.uniform(-0.2, 0.2, (N, 2)), np.ones(N)]) * 3.0
    D[::4, 2] *= -1   # every fourth ray points away: no hits
    tris = caster.triangles.astype(np.float64) + caster.origin
    ref = ref_all_hits(tris, O, D)
    assert max(len(r[0]) for r in ref) == 20 > ah.SLOT_HITS
    for cap in (None, 3, 15):
        got = caster.all_hits(O, D, max_hits=cap)
        for i, (t, f, u, v, _) in enumerate(ref):
            k = len(t) if cap is None else min(cap, len(t))
            s = slice(got.offsets[i], got.offsets[i + 1])
            assert np.array_equal(got.tri[s], f[:k]), (cap, i)
            assert np.allclose(got.t[s], t[:k], rtol=1e-12) and np.allclose(got.u[s], u[:k], atol=1e-12)
    assert np.array_equal(caster.count_hits(O, D), [len(r[0]) for r in ref])
    assert len(keyed) == (4 if ordered else 0)


def test_rays_in_cache_order_give_the_callers_order(monkeypatch):
    """Rays of every direction with a t range each, through a sphere, taken in the order of their
    keys (origin along a Morton curve, direction class) or as given: the same hits, ray for ray
    in the caller's order, with and without max_hits, the same counts, and the counts the float64
    brute force finds where no hit lies within 1e-6 of an edge.  The rays' keys do order them
    (the order differs from the caller's)."""
    m = icosphere_mesh(5120)
    caster = gridrt.RayCaster(m.vertices, m.faces)
    rng = np.random.default_rng(4)
    N = 3000
    O = rng.uniform(-1.3, 1.3, (N, 3))
    D = rng.normal(size=(N, 3))
    tmin, tmax = rng.uniform(0, 0.5, N), rng.uniform(0.5, 4.0, N)
    tmax[::7] = np.inf
    got = {}
    for on in (False, True):
        keyed = _ordering(monkeypatch, on)
        got[on] = (caster.all_hits(O, D, tmin, tmax), caster.all_hits(O, D, tmin, tmax, max_hits=1),
                   caster.count_hits(O, D, tmin, tmax))
        assert len(keyed) == (3 if on else 0)
    for a, b in zip(got[False], got[True]):
        for x, y in zip(a if isinstance(a, tuple) else (a,), b if isinstance(b, tuple) else (b,)):
            assert x.dtype == y.dtype and np.array_equal(x, y)
    assert got[True][0].counts().sum() > N // 5
    keys = np.empty(N, np.int64)
    s = caster.grid.spec
    lo, hi = np.asarray(s.lo, np.float64), np.asarray(s.hi, np.float64)
    ah.order_keys(O - caster.origin, D, lo, 1024.0 / (hi - lo), keys)
    assert not np.array_equal(np.argsort(keys), np.arange(N))
    ref = ref_all_hits(caster.triangles.astype(np.float64) + caster.origin, O, D)
    counts = got[True][2]
    compared = 0
    for i, (t, f, u, v, edge) in enumerate(ref):
        if len(edge) and edge.min() < 1e-6:
            continue
        compared += 1
        assert counts[i] == np.count_nonzero((t > tmin[i]) & (t < tmax[i])), i
    assert compared > 0.95 * N


@njit
def _lanes_and_once(tris, o, d, tmin, tmax, sizes, lanes, once):
    """Every triangle of tris against the ray (o, d): through ah._test_lanes in chunks of
    sizes[k % len(sizes)] triangles, its hits into the HitBuffers ``lanes``, and through
    ah.intersect_once one at a time, into ``once``; the two counts."""
    sh = ray_shear((o[0], o[1], o[2]), (d[0], d[1], d[2]))
    s = ah.hit_scratch()
    pend, rows = s.pend, s.rows
    n_lanes = np.int64(0)
    f0, k = 0, 0
    while f0 < len(tris):
        m = min(sizes[k % len(sizes)], len(tris) - f0)
        for j in range(m):
            pend[j] = f0 + j
        n_lanes = ah._test_lanes(tris, pend, np.int64(m), rows, sh, tmin, tmax, n_lanes, lanes)
        f0 += m
        k += 1
    n_once = 0
    for f in range(len(tris)):
        hit, t, u, v = ah.intersect_once(tris, f, sh, tmin, tmax)
        if hit:
            once.t[n_once], once.tri[n_once], once.u[n_once], once.v[n_once] = t, f, u, v
            n_once += 1
    return n_lanes, n_once


def _undecided(tris, o, d):
    """Whether any edge function of any triangle at the ray is exactly 0 in float64 (numpy's own
    shear: the lanes must hand such a triangle to the exact test)."""
    k = int(np.argmax(np.abs(d)))
    kx, ky = (k + 1) % 3, (k + 2) % 3
    if d[k] < 0:
        kx, ky = ky, kx
    p = tris.astype(np.float64) - o
    x = p[..., kx] - d[kx] / d[k] * p[..., k]
    y = p[..., ky] - d[ky] / d[k] * p[..., k]
    e = [x[:, b] * y[:, a] - y[:, b] * x[:, a] for a, b in ((1, 2), (2, 0), (0, 1))]
    return bool(np.any(np.stack(e) == 0.0))


def test_side_by_side_lanes_equal_one_at_a_time():
    """The walk tests the triangles it collects side by side, LANES at a time (_test_lanes), and
    hands a lane whose float64 edge values do not decide their signs to the one-at-a-time exact
    test: for every chunk size, on rays through a flat mesh of integer coordinates exactly at its
    vertices and edges (edge functions exactly 0: the exact test's tie rule), tilted rays, and
    random rays through the icosphere with t ranges, the hits are intersect_once's, triangle for
    triangle, bit for bit in t, u and v."""
    # a 6 x 6 square of unit cells, two triangles each, in the plane z = 0
    n = 6
    ii, jj = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
    V = np.column_stack([ii.ravel(), jj.ravel(), np.zeros(ii.size)]).astype(np.float64)
    at = lambda i, j: i * (n + 1) + j
    F = np.array([q for i in range(n) for j in range(n)
                  for q in ([at(i, j), at(i + 1, j), at(i + 1, j + 1)], [at(i, j), at(i + 1, j + 1), at(i, j + 1)])])
    flat = np.ascontiguousarray(V[F], np.float32)
    rays = []
    for x in np.arange(1.0, n, 0.5):          # vertices and edge midpoints, straight down and tilted
        for y in np.arange(1.0, n, 0.5):
            rays += [((x, y, 2.0), (0.0, 0.0, -1.0)), ((x, y, 2.0), (0.0, 0.0, 1.0)),
                     ((x - 1.0, y - 0.5, 2.0), (0.5, 0.25, -1.0)), ((x + 2.0, y, 1.0), (-2.0, 0.0, -1.0))]
    m = icosphere_mesh(1280)
    sphere = np.ascontiguousarray(m.vertices[m.faces], np.float32)
    rng = np.random.default_rng(12)
    cases = [(flat, np.array(o, np.float64), np.array(d, np.float64), 0.0, np.inf) for o, d in rays]
    for _ in range(40):
        o = rng.normal(size=3) * 2.0
        cases.append((sphere, o, rng.uniform(-0.5, 0.5, 3) - o, rng.uniform(0, 0.3), rng.choice([np.inf, 0.6])))
    for t_ in m.vertices[rng.integers(0, len(m.vertices), 20)]:   # rays at the sphere's vertices
        o = 3.0 * rng.normal(size=3)
        cases.append((sphere, o, t_ - o, 0.0, np.inf))
    buffers = lambda: ah.HitBuffers(np.empty(2000), np.empty(2000, np.int32), np.empty(2000), np.empty(2000))
    undecided = flat_hits = 0
    for c, (tris, o, d, tmin, tmax) in enumerate(cases):
        sizes = np.array([ah.LANES, 1 + c % ah.LANES, 3], np.int64)
        lanes, once = buffers(), buffers()
        nl, no = _lanes_and_once(tris, o, d, tmin, tmax, sizes, lanes, once)
        a = np.argsort(lanes.tri[:nl])
        assert nl == no, c
        for x, y in zip(lanes, once):
            assert np.array_equal(x[:nl][a], y[:no]), c
        undecided += _undecided(tris, o, d)
        if tris is flat and d[2] != 0 and tmax == np.inf:
            flat_hits += nl
            assert nl == (1 if (o[2] > 0) == (d[2] < 0) else 0), c   # one triangle where the ray meets the plane
    assert undecided > 100 and flat_hits > 100, (undecided, flat_hits)
