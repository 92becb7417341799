"""The hard ray cases (grazing, ties, edges) and the comparison of hits with the reference."""

import numpy as np

import reference as R
from conftest import TEAPOT, icosphere_tris, load_tris, random_rays, random_triangles
from gridrt.camera import Camera
from gridrt.grid import GridParams, build_grid


GRAZE = 1e-9  # barycentric distance from an edge under which a disagreement is tolerated


MAX_GRAZING = 1e-3  # ... and the largest tolerated fraction of such rays


def _hard_rays(rng, spec, n):
    """Rays that stress the DDA: axis-parallel (1 and 2 zero components), exact diagonals
    through cell corners, origins on cell faces, on the grid bounds, and in its boundary planes."""
    lo, hi, cell, dims = spec.lo, spec.hi, spec.cell, spec.dims
    out_o, out_d = [], []
    k = n // 5
    # axis-parallel, from a random interior cell corner / face point
    ijk = rng.integers(0, dims + 1, (k, 3))
    o = lo + ijk * cell
    o[:, 0] += rng.uniform(0, 1, k) * cell[0] * (rng.random(k) < 0.5)
    a = rng.integers(0, 3, k)
    d = np.zeros((k, 3))
    d[np.arange(k), a] = rng.choice([-1.0, 1.0], k)
    out_o.append(o)
    out_d.append(d)
    # one zero component
    d = rng.normal(size=(k, 3))
    d[np.arange(k), rng.integers(0, 3, k)] = 0.0
    out_o.append(rng.uniform(lo - 0.2 * (hi - lo), hi + 0.2 * (hi - lo), (k, 3)))
    out_d.append(d / np.linalg.norm(d, axis=1, keepdims=True))
    # diagonals through cell corners: direction = (±cell_x, ±cell_y, ±cell_z)
    ijk = rng.integers(0, dims + 1, (k, 3))
    out_o.append(lo + ijk * cell)
    out_d.append(rng.choice([-1.0, 1.0], (k, 3)) * cell)
    # origins on the grid bounds, pointing anywhere
    o = rng.uniform(lo, hi, (k, 3))
    ax = rng.integers(0, 3, k)
    side = rng.random(k) < 0.5
    o[np.arange(k), ax] = np.where(side, lo[ax], hi[ax])
    d = rng.normal(size=(k, 3))
    out_o.append(o)
    out_d.append(d / np.linalg.norm(d, axis=1, keepdims=True))
    # rays lying in a boundary plane of the grid (parallel to it)
    m = n - 4 * k
    o = rng.uniform(lo, hi, (m, 3))
    ax = rng.integers(0, 3, m)
    o[np.arange(m), ax] = np.where(rng.random(m) < 0.5, lo[ax], hi[ax])
    d = rng.normal(size=(m, 3))
    d[np.arange(m), ax] = 0.0
    out_o.append(o)
    out_d.append(d / np.linalg.norm(d, axis=1, keepdims=True))
    return np.concatenate(out_o), np.concatenate(out_d)


class Case:
    """A scene, its grid, a ray set and the reference answer for it."""

    def __init__(self, name, tris, n_random, n_hard, params, seed):
        rng = np.random.default_rng(seed)
        self.name = name
        self.tris = tris
        self.params = params
        self.grid = build_grid(tris, params)
        s = self.grid.spec
        lo = tris.reshape(-1, 3).min(0)
        hi = tris.reshape(-1, 3).max(0)
        parts = [
            random_rays(rng, n_random // 2, lo, hi, outside=0.5, aim=True),
            random_rays(rng, n_random - n_random // 2, lo, hi, outside=0.2),
            _hard_rays(rng, s, n_hard),
        ]
        self.camera = Camera.frame(s.lo, s.hi, fov=50.0)
        self.cam_size = (64, 48)
        parts.append(R.ref_camera_rays(self.camera.eye, self.camera.target, self.camera.up, self.camera.fov, *self.cam_size))
        self.o = np.concatenate([p[0] for p in parts])
        self.d = np.concatenate([p[1] for p in parts])
        self.ref = R.ref_cast(tris, self.o, self.d)


_CASES = {}


def get_case(name):
    if name not in _CASES:
        if name == "random":
            tris = random_triangles(np.random.default_rng(7), 200, size=0.15)
            _CASES[name] = Case(name, tris, 45_000, 10_000, GridParams(density=4.0, macro=4), 1)
        elif name == "icosphere":
            tris = icosphere_tris(2, radius=1.0, center=(0.3, -0.2, 0.1))
            _CASES[name] = Case(name, tris, 30_000, 5_000, GridParams(density=3.0, macro=2), 2)
        elif name == "teapot":
            tris = load_tris(TEAPOT)
            _CASES[name] = Case(name, tris, 4_000, 1_000, GridParams(density=4.0, macro=4), 3)
        else:
            raise KeyError(name)
    return _CASES[name]


def assert_hits_match(hits, ref, label, rays_o=None, rays_d=None, uv_atol=1e-6):
    diff = R.compare_hits(hits.t, hits.tri, ref, t_rtol=1e-5, tie_rtol=1e-9, graze_tol=GRAZE)
    n = len(ref.t)
    print(f"{label}: {n} rays, {int(ref.hit.sum())} hits, {len(diff.tie)} ties, {len(diff.grazing)} grazing")
    if len(diff.bad):
        i = diff.bad[:5]
        raise AssertionError(
            f"{label}: {len(diff.bad)} of {n} rays differ from the brute-force reference "
            f"({len(diff.t_off)} with t off); first rays {i.tolist()}: engine tri {hits.tri[i].tolist()} "
            f"t {hits.t[i].tolist()}, reference tri {ref.tri[i].tolist()} t {ref.t[i].tolist()}"
            + (f"; origins {rays_o[i].tolist()} dirs {rays_d[i].tolist()}" if rays_o is not None else "")
        )
    assert len(diff.grazing) <= MAX_GRAZING * n, f"{label}: {len(diff.grazing)} grazing disagreements"
    miss = hits.tri < 0
    assert np.isinf(hits.t[miss]).all() and (hits.t[miss] > 0).all(), "a miss must report t = +inf"
    same = np.flatnonzero((hits.tri == ref.tri) & ~miss)
    np.testing.assert_allclose(hits.u[same], ref.u[same], rtol=0, atol=uv_atol, err_msg=f"{label}: u")
    np.testing.assert_allclose(hits.v[same], ref.v[same], rtol=0, atol=uv_atol, err_msg=f"{label}: v")
    return diff
