"""RayScene (several meshes, instances placed by 4x4 transforms) against the same meshes baked into
world coordinates by the test: a float64 brute force over the baked triangles for nearest hits,
every hit, counts, inside tests and attributes; crossings that pair up through the placed meshes'
shared edges and vertices; updates that rebuild only what changed; the sensors' instance ids."""

import math

import numpy as np
import pytest

import gridrt
from gridrt.errors import InputError
from gridrt.scene import icosphere_mesh
from reference import ref_all_hits, ref_cast


def _rotation(axis, angle):
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + math.sin(angle) * K + (1 - math.cos(angle)) * K @ K


def _matrix(A, b):
    M = np.eye(4)
    M[:3, :3], M[:3, 3] = A, b
    return M


#: object-to-world transforms: a rotation with a uniform scale, a rotated non-uniform scale, a
#: mirroring one (determinant < 0), and the second mesh's
TRANSFORMS = [
    _matrix(0.8 * _rotation((1, 2, 3), 0.7), (-2.0, 0.0, 0.0)),
    _matrix(_rotation((0, 1, 1), -0.4) @ np.diag([1.5, 0.6, 1.0]), (1.5, 0.5, 0.0)),
    _matrix(np.diag([-1.0, 1.0, 1.0]) @ _rotation((1, 0, 0), 0.3), (0.0, -2.0, 0.5)),
    _matrix(_rotation((0, 0, 1), 0.9) * 1.2, (0.2, 2.2, -0.3)),
]


def _meshes():
    a = icosphere_mesh(1280)
    b = icosphere_mesh(320)
    v = b.vertices * np.array([1.0, 0.5, 0.7])
    v *= (1 + 0.15 * np.sin(3 * v[:, :1]) * np.cos(2 * v[:, 1:2]))   # bumps; still closed
    return (a.vertices, a.faces), (v, b.faces)


def _scene():
    (va, fa), (vb, fb) = _meshes()
    s = gridrt.RayScene()
    ma, mb = s.add_mesh(va, fa), s.add_mesh(vb, fb)
    ids = [s.add_instance(ma, TRANSFORMS[0]), s.add_instance(ma, TRANSFORMS[1]), s.add_instance(ma, TRANSFORMS[2]),
           s.add_instance(mb, TRANSFORMS[3])]
    assert (ma, mb, ids) == (0, 1, [0, 1, 2, 3])
    return s


def _baked(scene):
    """(world triangles (F, 3, 3) float64 of every instance, instance of each, triangle of each), as
    the scene's casters keep their meshes (float32 in their frame) mapped by each transform in
    float64."""
    tris, inst, tri = [], [], []
    for i in scene.instances():
        c = scene.meshes[scene.mesh_of(i)]
        M = scene.transform(i)
        T = c.triangles.astype(np.float64) + c.origin
        tris.append(T @ M[:3, :3].T + M[:3, 3])
        inst.append(np.full(len(T), i))
        tri.append(np.arange(len(T)))
    return np.concatenate(tris), np.concatenate(inst), np.concatenate(tri)


def _rays(scene, n, seed):
    lo, hi = scene.bounds()
    rng = np.random.default_rng(seed)
    O = rng.uniform(lo - 0.5 * (hi - lo), hi + 0.5 * (hi - lo), (n, 3))
    D = rng.uniform(lo, hi, (n, 3)) - O
    D *= rng.uniform(0.3, 3.0, (n, 1))   # lengths other than 1: t is along d as given
    return O, D


def test_cast_against_the_baked_scene():
    """Nearest hits (t, instance, triangle, barycentrics) equal a float64 brute force over the
    baked triangles wherever the brute-force hit is not within 1e-6 (barycentric) of an edge or tied
    with another triangle; any_hit finds a hit exactly where the brute force does; t ranges."""
    scene = _scene()
    T, inst, tri = _baked(scene)
    O, D = _rays(scene, 3000, 1)
    h = scene.cast(O, D)
    ref = ref_cast(T, O, D)
    hit = ref.tri >= 0
    assert 0.3 < hit.mean() < 0.9
    assert np.array_equal(h.tri >= 0, hit)
    clear = hit & (ref.edge > 1e-6) & (ref.t2 > ref.t * (1 + 1e-9))
    assert clear.sum() > 0.9 * hit.sum()
    assert np.array_equal(h.instance[clear], inst[ref.tri[clear]])
    assert np.array_equal(h.tri[clear], tri[ref.tri[clear]])
    assert np.array_equal(h.mesh[clear], np.where(inst[ref.tri[clear]] == 3, 1, 0))
    # (t within cast's tolerance; barycentrics of these small triangles within 1e-5, as a
    # RayCaster over the baked triangles gives them)
    assert np.allclose(h.t[hit], ref.t[hit], rtol=1e-5)
    assert np.allclose(h.u[clear], ref.u[clear], atol=1e-5) and np.allclose(h.v[clear], ref.v[clear], atol=1e-5)
    assert np.all(h.instance[~hit] == -1) and np.all(h.mesh[~hit] == -1) and np.isinf(h.t[~hit]).all()
    # the instances the rays hit: all four
    assert set(np.unique(h.instance[hit])) == {0, 1, 2, 3}
    a = scene.cast(O, D, any_hit=True)
    assert np.array_equal(a.tri >= 0, hit)
    k = a.tri >= 0
    # an any hit is a real hit: its t is that of its triangle, on the baked mesh
    back = np.array([np.flatnonzero((inst == i) & (tri == f))[0] for i, f in zip(a.instance[k], a.tri[k])])
    W = T[back]   # each ray against its own triangle: the plane's t (Moller-Trumbore's t)
    e1, e2, s = W[:, 1] - W[:, 0], W[:, 2] - W[:, 0], O[k] - W[:, 0]
    p, q = np.cross(D[k], e2), np.cross(s, e1)
    t_own = np.einsum("ij,ij->i", e2, q) / np.einsum("ij,ij->i", e1, p)
    assert np.allclose(a.t[k], t_own, rtol=1e-5)
    # a t range: hits beyond the nearest one's t are those of the brute force from there
    tmin = 0.5 * np.nanmin(np.where(hit, ref.t, np.nan))
    r = scene.cast(O, D, t_min=tmin, t_max=4.0)
    ref2 = ref_cast(T, O, D, tmin=tmin, tmax=4.0)
    ok = (ref2.tri < 0) | ((ref2.edge > 1e-6) & (ref2.t2 > ref2.t * (1 + 1e-9)))
    assert np.array_equal((r.tri >= 0)[ok], (ref2.tri >= 0)[ok])
    assert np.allclose(r.t[ok & (ref2.tri >= 0)], ref2.t[ok & (ref2.tri >= 0)], rtol=1e-5)


def test_all_hits_and_counts_against_the_baked_scene():
    """Every hit, in order, is the brute force's over the baked triangles (instance and triangle
    for each) for rays whose hits lie clear of edges; count_hits equals all_hits' counts; max_hits
    keeps each ray's nearest; per-ray t ranges; the result does not depend on the rays' order.
    Bounds given as numbers or as (read-only) arrays are one kind of input to the kernel that
    finds the instances a ray reaches (one compile)."""
    from gridrt.instances import reach_box

    scene = _scene()
    T, inst, tri = _baked(scene)
    O, D = _rays(scene, 400, 2)
    got = scene.all_hits(O, D)
    assert np.array_equal(scene.count_hits(O, D), got.counts())
    ref = ref_all_hits(T, O, D)
    compared = 0
    for i, (t, f, u, v, edge) in enumerate(ref):
        s = slice(got.offsets[i], got.offsets[i + 1])
        assert np.all(np.diff(got.t[s]) >= 0)
        if len(edge) and edge.min() < 1e-6:
            continue
        compared += 1
        assert np.array_equal(got.instance[s], inst[f]) and np.array_equal(got.tri[s], tri[f]), i
        assert np.allclose(got.t[s], t, rtol=1e-9) and np.allclose(got.u[s], u, atol=1e-7)
    assert compared > 0.95 * len(O) and got.counts().sum() > len(O)
    capped = scene.all_hits(O, D, max_hits=2)
    assert np.array_equal(capped.counts(), np.minimum(got.counts(), 2))
    for i in range(len(O)):
        a, b = slice(got.offsets[i], got.offsets[i] + capped.counts()[i]), slice(capped.offsets[i], capped.offsets[i + 1])
        assert np.array_equal(got.t[a], capped.t[b]) and np.array_equal(got.instance[a], capped.instance[b])
    rng = np.random.default_rng(3)
    t0, t1 = rng.uniform(0, 0.5, len(O)), rng.uniform(0.5, 2.0, len(O))
    ranged = scene.all_hits(O, D, t_min=t0, t_max=t1)
    for i in range(len(O)):
        s = slice(got.offsets[i], got.offsets[i + 1])
        want = (got.t[s] > t0[i]) & (got.t[s] < t1[i])
        assert np.array_equal(ranged.t[ranged.offsets[i]:ranged.offsets[i + 1]], got.t[s][want])
    frozen = [a.copy() for a in (O, D, t0, t1)]
    for a in frozen:
        a.flags.writeable = False
    for a, b in zip(scene.all_hits(*frozen), ranged):
        assert np.array_equal(a, b)
    assert len(reach_box.signatures) == 1, reach_box.signatures
    p = rng.permutation(len(O))
    shuffled = scene.all_hits(O[p], D[p])
    assert np.array_equal(shuffled.counts(), got.counts()[p])
    assert np.array_equal(np.concatenate([got.t[got.offsets[i]:got.offsets[i + 1]] for i in p]), shuffled.t)


def test_one_crossing_through_placed_edges_and_vertices():
    """Rays from outside every instance aimed exactly at the world positions of the placed meshes'
    vertices and edge midpoints cross the scene an even number of times, nearly all at least twice: no hole
    and no double count where triangles meet, whatever the transform (mirroring included)."""
    scene = _scene()
    targets = []
    for i in scene.instances():
        c = scene.meshes[scene.mesh_of(i)]
        M = scene.transform(i)
        V = c.vertices.astype(np.float64) + c.origin
        E = np.unique(np.sort(np.concatenate([c.faces[:, [0, 1]], c.faces[:, [1, 2]], c.faces[:, [2, 0]]]), axis=1), axis=0)
        P = np.concatenate([V, 0.5 * (V[E[:, 0]] + V[E[:, 1]])])
        targets.append(P @ M[:3, :3].T + M[:3, 3])
    P = np.concatenate(targets)
    lo, hi = scene.bounds()
    rng = np.random.default_rng(4)
    d = rng.normal(size=P.shape)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    O = P - d * 3 * (hi - lo).max()    # beyond the scene's bounds
    n = scene.count_hits(O, P - O)
    # (a ray through a vertex or edge may also only touch the mesh there: 0 crossings of it)
    assert np.all(n % 2 == 0) and np.mean(n >= 2) > 0.95, np.bincount(n)
    assert len(P) > 8000


def test_contains_against_parity_of_the_baked_scene():
    """Points inside and around the instances: inside exactly when a float64 brute-force ray from
    the point crosses the baked triangles an odd number of times (three directions agreeing)."""
    scene = _scene()
    T, _, _ = _baked(scene)
    lo, hi = scene.bounds()
    rng = np.random.default_rng(5)
    P = rng.uniform(lo, hi, (1500, 3))
    got = scene.contains(P)
    votes = []
    for d in ((0.31, 0.72, -0.62), (-0.8, 0.1, 0.59), (0.2, -0.3, 0.93)):
        D = np.broadcast_to(np.asarray(d), P.shape)
        votes.append(np.array([len(h[0]) % 2 for h in ref_all_hits(T, P, D)]))
    votes = np.array(votes)
    sure = (votes == votes[0]).all(axis=0)
    assert sure.mean() > 0.99
    assert np.array_equal(got[sure], votes[0][sure] == 1)
    assert 0.05 < got.mean() < 0.6


def test_updates_cost_what_changed():
    """A new transform leaves every grid as it was (the same grid objects) and casts as a scene
    built with that transform does; new vertices of one mesh rebuild its grid alone and move all
    its instances; a removed instance is no longer hit."""
    scene = _scene()
    grids = [c.grid for c in scene.meshes]
    O, D = _rays(scene, 1000, 6)
    M = _matrix(_rotation((1, 1, 0), 1.1), (-1.0, -0.5, 0.3))
    scene.update(transforms={1: M})
    assert [c.grid for c in scene.meshes] == grids
    (va, fa), (vb, fb) = _meshes()
    fresh = gridrt.RayScene()
    fresh.add_mesh(va, fa), fresh.add_mesh(vb, fb)
    for i, m in ((0, 0), (1, 0), (2, 0), (3, 1)):
        fresh.add_instance(m, M if i == 1 else TRANSFORMS[i])
    a, b = scene.cast(O, D), fresh.cast(O, D)
    assert np.array_equal(a.t, b.t) and np.array_equal(a.tri, b.tri) and np.array_equal(a.instance, b.instance)
    assert np.array_equal(scene.transform(1), M)

    scene.update(vertices={0: va * 1.2})
    assert scene.meshes[0].grid is not grids[0] and scene.meshes[1].grid is grids[1]
    lo, hi = scene.meshes[0].bounds()
    assert np.all(lo <= va.min(0) * 1.2) and np.all(hi >= va.max(0) * 1.2) and np.all(hi - lo < 2.41)
    T, inst, tri = _baked(scene)
    ref = ref_cast(T, O, D)
    h = scene.cast(O, D)
    hit = ref.tri >= 0
    assert np.array_equal(h.tri >= 0, hit) and np.allclose(h.t[hit], ref.t[hit], rtol=1e-5)
    T0 = T[inst == 0]
    assert np.allclose(T0, (va[fa] * 1.2) @ TRANSFORMS[0][:3, :3].T + TRANSFORMS[0][:3, 3], atol=1e-5)

    scene.remove_instance(3)
    h = scene.cast(O, D)
    assert 3 not in h.instance and scene.instances() == [0, 1, 2]
    with pytest.raises(InputError, match="no instance 3"):
        scene.set_transform(3, np.eye(4))


def test_attributes_in_world_coordinates():
    """Geometric normals are the baked world triangles' (winding included, also under the
    mirroring transform), shading normals the baked meshes' area-weighted vertex normals
    interpolated, and per-mesh values are interpolated with the hit's barycentrics; NaN on misses."""
    scene = _scene()
    T, inst, tri = _baked(scene)
    O, D = _rays(scene, 2000, 7)
    h = scene.cast(O, D)
    hit = h.tri >= 0
    back = {(i, f): k for k, (i, f) in enumerate(zip(inst, tri))}
    k = np.array([back[(i, f)] for i, f in zip(h.instance[hit], h.tri[hit])])
    W = T[k]
    n = np.cross(W[:, 1] - W[:, 0], W[:, 2] - W[:, 0])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    g = scene.geometric_normals(h)
    assert np.allclose(g[hit], n, atol=1e-6) and np.isnan(g[~hit]).all()
    assert (h.instance[hit] == 2).sum() > 20   # the mirrored instance is among them

    # baked vertex normals, per instance: sums of the world triangles' cross products at each vertex
    sn = scene.shading_normals(h)
    want = np.empty((hit.sum(), 3))
    for i in scene.instances():
        c = scene.meshes[scene.mesh_of(i)]
        Wi = T[inst == i]
        cr = np.cross(Wi[:, 1] - Wi[:, 0], Wi[:, 2] - Wi[:, 0])
        vn = np.zeros((len(c.vertices), 3))
        for j in range(3):
            np.add.at(vn, c.faces[:, j], cr)
        vn /= np.linalg.norm(vn, axis=1, keepdims=True)
        sel = h.instance[hit] == i
        f = c.faces[h.tri[hit][sel]]
        u, v = h.u[hit][sel, None], h.v[hit][sel, None]
        x = (1 - u - v) * vn[f[:, 0]] + u * vn[f[:, 1]] + v * vn[f[:, 2]]
        want[sel] = x / np.linalg.norm(x, axis=1, keepdims=True)
    assert np.allclose(sn[hit], want, atol=1e-6)

    (va, _), (vb, _) = _meshes()
    uv_a, uv_b = va[:, :2] * 0.5 + 0.5, vb[:, 1:] * 2.0
    got = scene.interpolate(h, [uv_a, uv_b])
    for i, uv in ((0, uv_a), (2, uv_a), (3, uv_b)):
        sel = h.instance == i
        c = scene.meshes[scene.mesh_of(i)]
        f = c.faces[h.tri[sel]]
        u, v = h.u[sel, None], h.v[sel, None]
        assert np.allclose(got[sel], (1 - u - v) * uv[f[:, 0]] + u * uv[f[:, 1]] + v * uv[f[:, 2]], atol=1e-9)
    assert np.isnan(got[~hit]).all()
    only_b = scene.interpolate(h, {1: uv_b})
    assert np.isnan(only_b[h.mesh == 0]).all() and np.allclose(only_b[h.mesh == 1], got[h.mesh == 1])

    hits = scene.all_hits(O[:50], D[:50])
    assert np.allclose(scene.geometric_normals(hits)[:3], scene.geometric_normals(
        gridrt.SceneHits(hits.t[:3], hits.tri[:3], hits.u[:3], hits.v[:3], hits.mesh[:3], hits.instance[:3])))


def test_sensors_name_instances():
    """The depth camera's instance image and the LiDAR's instance ids are those of the brute force's
    nearest baked triangle; on a RayCaster they are 0 where a ray hit and -1 elsewhere."""
    scene = _scene()
    T, inst, _ = _baked(scene)
    cam = gridrt.DepthCamera(40, 30, fov=70.0)
    eye, target = (0.0, 0.0, 7.0), (0.0, 0.0, 0.0)
    img = cam.render(scene, eye, target)
    _, o, d = cam.rays(eye, target)
    ref = ref_cast(T, o, d)
    clear = (ref.tri < 0) | (ref.edge > 1e-6)
    want = np.where(ref.tri >= 0, inst[np.maximum(ref.tri, 0)], -1)
    assert np.array_equal(img.instances.reshape(-1)[clear], want[clear])
    assert len(set(want) - {-1}) == 4
    assert np.allclose(img.range.reshape(-1)[ref.tri >= 0], ref.t[ref.tri >= 0], rtol=1e-5)

    lidar = gridrt.Lidar(channels=8, vertical_fov=(-20.0, 20.0), azimuth_resolution=4.0, max_range=20.0)
    pose = np.eye(4)
    scan = lidar.scan(scene, pose)
    o, d, _ = lidar.rays(pose)
    ref = ref_cast(T, o, d, tmax=20.0)
    want = np.where(ref.tri >= 0, inst[np.maximum(ref.tri, 0)], -1).reshape(lidar.columns, lidar.channels).T
    clear = ((ref.tri < 0) | (ref.edge > 1e-6)).reshape(lidar.columns, lidar.channels).T
    assert np.array_equal(scan.instances[clear], want[clear]) and (want >= 0).sum() > 10

    (va, fa), _ = _meshes()
    caster = gridrt.RayCaster(va, fa)
    one = cam.render(caster, (0.0, 0.0, 3.0), target)
    assert np.array_equal(one.instances, np.where(one.ids >= 0, 0, -1))


@pytest.mark.parametrize("call, message", [
    (lambda s: s.add_instance(0, np.diag([1.0, 1e-14, 1.0, 1.0])), "singular"),
    (lambda s: s.add_instance(0, np.ones((3, 4))), "4x4"),
    (lambda s: s.add_instance(0, np.array([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 1, 1.0]])), "affine"),
    (lambda s: s.add_instance(0, np.full((4, 4), np.nan)), "NaN"),
    (lambda s: s.add_instance(0, "eye"), "real 4x4"),
    (lambda s: s.add_instance(5), "no mesh 5"),
    (lambda s: s.add_instance(True), "no mesh True"),
    (lambda s: s.update(transforms={7: np.eye(4)}), "no instance 7"),
    (lambda s: s.update(vertices={0: np.zeros((5, 3))}), "shape"),
    (lambda s: s.cast(np.zeros((2, 3)), np.zeros((2, 3))), "zero"),
    (lambda s: s.cast(np.zeros((2, 3)), np.full((2, 3), np.nan)), "NaN"),
    (lambda s: s.all_hits(np.zeros((2, 3)), np.ones((2, 3)), t_min=np.zeros(3)), "t_min"),
    (lambda s: s.geometric_normals(np.zeros(3)), "hits must be"),
    (lambda s: s.interpolate(s.cast(np.zeros((1, 3)), np.ones((1, 3))), {4: np.zeros(3)}), "no mesh 4"),
])
def test_bad_input_named(call, message):
    """Bad transforms, ids, rays and hits are refused with an InputError naming the problem, and the
    scene keeps working afterwards."""
    s = gridrt.RayScene()
    (va, fa), _ = _meshes()
    s.add_mesh(va, fa)
    s.add_instance(0)
    with pytest.raises(InputError, match=message):
        call(s)
    h = s.cast(np.array([[0.0, 0.0, 5.0]]), np.array([[0.0, 0.0, -1.0]]))
    assert h.instance[0] == 0 and abs(h.t[0] - 4.0) < 0.01


def test_empty_scene_and_unplaced_mesh():
    """A scene with no instances (or only unplaced meshes) hits nothing and contains nothing."""
    s = gridrt.RayScene()
    O, D = np.zeros((3, 3)), np.ones((3, 3))
    assert np.isinf(s.cast(O, D).t).all() and s.bounds() is None
    (va, fa), _ = _meshes()
    s.add_mesh(va, fa)
    assert (s.count_hits(O, D) == 0).all() and not s.contains(O).any()
    assert s.all_hits(O, D).offsets.tolist() == [0, 0, 0, 0]


def test_refused_update_changes_what_its_doc_says():
    """An update whose second mesh's vertices are refused: the first mesh has its new vertices, the
    refused one keeps its old ones, and no transform has changed."""
    scene = _scene()
    (va, _), (vb, _) = _meshes()
    grids = [c.grid for c in scene.meshes]
    M = _matrix(np.eye(3), (5.0, 5.0, 5.0))
    bad = vb.copy()
    bad[3, 1] = np.nan
    with pytest.raises(InputError, match="NaN"):
        scene.update(vertices={0: va * 1.1, 1: bad}, transforms={0: M})
    assert scene.meshes[0].grid is not grids[0] and scene.meshes[1].grid is grids[1]
    assert np.allclose(scene.meshes[0].vertices + scene.meshes[0].origin, va * 1.1, atol=1e-6)
    assert np.array_equal(scene.transform(0), TRANSFORMS[0])
