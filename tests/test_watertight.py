"""No ray slips through a closed mesh at a shared edge or vertex (watertight intersection).

Rays are aimed exactly at the mesh's vertices, at the midpoints of its edges and at random points
along its edges (targets computed in float64 from the float32 vertices and used as they are),
from random origins outside the mesh's bounding sphere.  Each origin lies strictly in front of
every face that touches its target (the ray crosses the surface at the target instead of grazing
it), so on a closed mesh the ray must hit some triangle no later than the target:
the watertight test (Woop, Benthin, Wald, JCGT 2013) must give 0 misses and 0 hits with
t > |target - origin| * (1 + 1e-6).  The same rays through the fast Moller-Trumbore test are
counted and printed (it gives no such guarantee; nothing is asserted about it).

Meshes: an icosphere (trimesh.creation), a radially jittered icosphere shot from inside, and the
closed Armadillo from ../shared/data (skipped when absent).  This is pbrt-v4's
``Triangle.Watertight`` property, done on shared edges instead of random points.
"""

import numpy as np
import pytest

from conftest import ARMADILLO, icosphere, load_mesh_arrays
from engine.grid import GridParams, build_grid
from engine.trace import cast_rays

REL = 1e-6


def edge_table(faces):
    """Unique undirected edges (E, 2) and, for a closed manifold mesh, their two faces (E, 2)."""
    F = len(faces)
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    f = np.tile(np.arange(F), 3)
    e = np.sort(e, axis=1)
    uniq, inv, counts = np.unique(e, axis=0, return_inverse=True, return_counts=True)
    assert (counts == 2).all(), "mesh is not closed and manifold: an edge has other than 2 faces"
    order = np.argsort(inv.reshape(-1), kind="stable")
    return uniq, f[order].reshape(-1, 2)


def face_normals(v, faces):
    """Unit normals (F, 3) float64, oriented outwards (by the sign of the enclosed volume)."""
    t = v[faces].astype(np.float64)
    n = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
    vol = np.einsum("fc,fc->", t[:, 0], n)  # 6 x signed volume
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    return n if vol > 0 else -n


def targets_and_fans(rng, v, faces, n_vertices, n_mid, n_rand):
    """Targets (T, 3) float64 with their incident faces as CSR (offsets (T+1,), face ids)."""
    v64 = v.astype(np.float64)
    edges, ef = edge_table(faces)
    # vertices and their fans
    vf_v = faces.reshape(-1)
    vf_f = np.repeat(np.arange(len(faces)), 3)
    order = np.argsort(vf_v, kind="stable")
    vf_v, vf_f = vf_v[order], vf_f[order]
    vstart = np.searchsorted(vf_v, np.arange(len(v) + 1))
    vids = rng.choice(len(v), min(n_vertices, len(v)), replace=False)
    pts = [v64[vids]]
    fans = [vf_f[vstart[i] : vstart[i + 1]] for i in vids]
    # edge midpoints and random points along edges: fans of two faces
    for n, mid in ((n_mid, True), (n_rand, False)):
        k = min(n, len(edges)) if mid else n
        eids = rng.choice(len(edges), k, replace=k > len(edges))
        a, b = v64[edges[eids, 0]], v64[edges[eids, 1]]
        s = np.full((len(eids), 1), 0.5) if mid else rng.uniform(0.0, 1.0, (len(eids), 1))
        pts.append(a + s * (b - a))
        fans += list(ef[eids])
    counts = np.array([len(x) for x in fans])
    return np.concatenate(pts), np.concatenate([[0], np.cumsum(counts)]), np.concatenate(fans)


def origins_in_front(rng, targets, offs, fan, normals, centre, radius, min_cos=0.1):
    """For each target a direction u with u . n > min_cos for every face of its fan, and the
    origin target + L u outside the bounding sphere.  Targets with no such u are dropped."""
    T = len(targets)
    navg = np.add.reduceat(normals[fan], offs[:-1], axis=0)
    navg /= np.linalg.norm(navg, axis=1, keepdims=True)
    u = np.zeros((T, 3))
    ok = np.zeros(T, bool)
    for attempt in range(40):
        todo = np.flatnonzero(~ok)
        if not len(todo):
            break
        spread = 0.6 if attempt < 30 else 0.0
        cand = navg[todo] + spread * rng.normal(size=(len(todo), 3))
        cand /= np.linalg.norm(cand, axis=1, keepdims=True)
        rep = np.repeat(cand, np.diff(offs)[todo], axis=0)
        sub_offs = np.concatenate([[0], np.cumsum(np.diff(offs)[todo])])
        sub_fan = np.concatenate([fan[offs[i] : offs[i + 1]] for i in todo])
        dots = np.einsum("kc,kc->k", rep, normals[sub_fan])
        good = np.minimum.reduceat(dots, sub_offs[:-1]) > min_cos
        u[todo[good]] = cand[good]
        ok[todo[good]] = True
    L = radius * rng.uniform(1.5, 3.0, T) + np.linalg.norm(targets - centre, axis=1)
    o = targets + L[:, None] * u
    assert (np.linalg.norm(o[ok] - centre, axis=1) > radius).all()
    return o[ok], targets[ok], ok


def shoot(v, faces, origins, targets, label, params=GridParams(density=4.0, macro=4)):
    tris = np.ascontiguousarray(v[faces])
    grid = build_grid(tris, params)
    d = targets - origins
    dist = np.linalg.norm(d, axis=1)
    d /= dist[:, None]
    res = {}
    for wt in (True, False):
        h = cast_rays(grid, tris, origins, d, watertight=wt)
        miss = h.tri < 0
        far = ~miss & (h.t > dist * (1 + REL))
        res[wt] = (int(miss.sum()), int(far.sum()), h)
    print(
        f"{label}: {len(origins)} rays at shared vertices/edges; watertight: {res[True][0]} misses, "
        f"{res[True][1]} hits beyond the target; fast (Moller-Trumbore): {res[False][0]} misses, "
        f"{res[False][1]} hits beyond the target"
    )
    m, f, h = res[True]
    bad = np.flatnonzero((h.tri < 0) | (h.t > dist * (1 + REL)))
    assert m == 0 and f == 0, (
        f"{label}: watertight test let {m} rays through and hit {f} beyond the target; first rays: "
        f"origins {origins[bad[:3]].tolist()} targets {targets[bad[:3]].tolist()}"
    )
    return res


def test_icosphere_shared_edges_from_outside(rng):
    v, f = icosphere(3, radius=1.0, center=(0.1, -0.2, 0.3))
    n = face_normals(v, f)
    tg, offs, fan = targets_and_fans(rng, v, f, len(v), 3000, 9000)
    centre = v.astype(np.float64).mean(axis=0)
    radius = np.linalg.norm(v - centre, axis=1).max()
    o, t, ok = origins_in_front(rng, tg, offs, fan, n, centre, radius)
    assert ok.mean() > 0.99
    shoot(v, f, o, t, "icosphere (outside)")


@pytest.mark.parametrize("density,macro", [(0.5, 1), (12.0, 8)])
def test_icosphere_grid_params(rng, density, macro):
    """Watertightness does not depend on the grid (cell faces through vertices and edges)."""
    v, f = icosphere(2, radius=2.0)
    n = face_normals(v, f)
    tg, offs, fan = targets_and_fans(rng, v, f, len(v), 1000, 2000)
    centre = np.zeros(3)
    o, t, _ = origins_in_front(rng, tg, offs, fan, n, centre, 2.0 + 1e-6)
    shoot(v, f, o, t, f"icosphere density={density} macro={macro}", GridParams(density=density, macro=macro))


def test_jittered_sphere_from_inside(rng):
    """Rays from near the centre of a radially jittered (star-shaped) icosphere to its vertices
    and edges must leave it through a triangle no later than the target."""
    v, f = icosphere(3, radius=1.0)
    v = (v * rng.uniform(0.97, 1.03, (len(v), 1))).astype(np.float32)
    tg, _, _ = targets_and_fans(rng, v, f, len(v), 3000, 6000)
    o = rng.uniform(-0.2, 0.2, (len(tg), 3))  # every face plane is > 0.8 from the centre
    shoot(v, f, o, tg, "jittered icosphere (inside)")


def test_armadillo_shared_edges():
    v, f = load_mesh_arrays(ARMADILLO)
    rng = np.random.default_rng(11)
    n = face_normals(v, f)
    tg, offs, fan = targets_and_fans(rng, v, f, 8000, 8000, 16000)
    v64 = v.astype(np.float64)
    centre = 0.5 * (v64.min(0) + v64.max(0))
    radius = np.linalg.norm(v64 - centre, axis=1).max()
    o, t, ok = origins_in_front(rng, tg, offs, fan, n, centre, radius)
    print(f"armadillo: {ok.mean():.3f} of the targets have an origin in front of all their faces")
    assert ok.sum() > 25000
    shoot(v, f, o, t, "armadillo (outside)")
