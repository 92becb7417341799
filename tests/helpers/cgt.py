"""The CGT tests' scenes, cameras and comparisons, and the float32 packets' tolerance check."""

import numpy as np

import reference as R
from conftest import TEAPOT, icosphere_tris, load_tris, random_scene, random_triangles
from gridrt.camera import Camera
from gridrt.config import GridParams, RenderParams
from gridrt.grid import build_grid
from gridrt.trace import cgt, render


def terrain(n=16, seed=3):
    """Height field over [0, 1]^2 (y up), 2 n^2 triangles."""
    rng = np.random.default_rng(seed)
    h = rng.uniform(0.0, 0.08, (n + 1, n + 1))
    xs = np.linspace(0.0, 1.0, n + 1)
    v = np.stack(np.meshgrid(xs, xs, indexing="ij"), -1)
    p = np.concatenate([v[..., :1], h[..., None], v[..., 1:]], -1)
    a, b, c, d = p[:-1, :-1], p[1:, :-1], p[1:, 1:], p[:-1, 1:]
    t = np.concatenate([np.stack([a, b, c], -2).reshape(-1, 3, 3), np.stack([a, c, d], -2).reshape(-1, 3, 3)])
    return t.astype(np.float32)


def cubes():
    """Unit cubes at integer offsets (12 triangles each): axis-aligned faces and shared edges."""
    c = np.array([[x, y, z] for z in (0, 1) for y in (0, 1) for x in (0, 1)], np.float32)
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    one = np.array([[c[q[0]], c[q[1]], c[q[2]]] for q in quads] + [[c[q[0]], c[q[2]], c[q[3]]] for q in quads])
    offs = [(0, 0, 0), (1, 0, 0), (0, 2, 0), (2, 2, 1), (3, 0, 3), (1, 1, 2)]
    return np.concatenate([one + np.float32(o) for o in offs]).astype(np.float32)


def scene(name):
    if name == "random":
        return random_triangles(np.random.default_rng(7), 300, size=0.15)
    if name == "icosphere":
        return icosphere_tris(2, radius=1.0, center=(0.3, -0.2, 0.1))
    if name == "teapot":
        return load_tris(TEAPOT)
    if name == "terrain":
        return terrain()
    if name == "cubes":
        return cubes()
    if name == "dups":
        return random_scene(np.random.default_rng(13), 250, "mixed", None, dup_frac=0.3, degen_frac=0.1)
    raise KeyError(name)


def camera(kind, tris):
    lo = tris.reshape(-1, 3).min(0).astype(np.float64)
    hi = tris.reshape(-1, 3).max(0).astype(np.float64)
    c = 0.5 * (lo + hi)
    ext = float((hi - lo).max())
    if kind == "framed":
        return Camera.frame(lo, hi, fov=50.0)
    if kind == "inside":  # wide view from inside the grid: packets straddle major-axis changes
        return Camera(eye=tuple(c + 0.05 * ext), target=tuple(c + np.array([0.4, -0.3, 1.0]) * ext), fov=110.0)
    if kind == "grazing":  # eye just above the top of the box, looking across it at a shallow angle
        eye = np.array([lo[0] - 0.6 * ext, hi[1] + 0.01 * ext, c[2] + 0.1 * ext])
        return Camera(eye=tuple(eye), target=(hi[0], hi[1] - 0.08 * ext, c[2]), fov=30.0)
    if kind == "axis":  # straight down -z: zero direction components, minor signs flip in packets
        return Camera(eye=(c[0], c[1], hi[2] + 2.0 * ext), target=(c[0], c[1], c[2]), up=(0, 1, 0), fov=40.0)
    if kind == "diagonal":  # along (1, 1, 1): |dx| = |dy| = |dz| near the centre (major-axis ties)
        return Camera(eye=tuple(c - 2.0 * ext), target=tuple(c), up=(0, 1, 0), fov=35.0)
    if kind == "face":  # cubes: straight down onto the top face of the unit cube at the origin; in a
        # square image the rays of pixels (x, W-1-x) have dx == dy and hit the face's diagonal edge
        return Camera(eye=(0.5, 0.5, 1.8), target=(0.5, 0.5, 0.0), up=(0, 1, 0), fov=40.0)
    raise KeyError(kind)


_GRIDS = {}


def grid_of(name):
    if name not in _GRIDS:
        tris = scene(name)
        _GRIDS[name] = (tris, build_grid(tris, GridParams(density=4.0, macro=2 if name == "icosphere" else 4)))
    return _GRIDS[name]


def assert_same(a, b, tris, cam, label):
    """CGT result b against DDA result a: identical t, triangles and image, ties included."""
    assert np.array_equal(a.t, b.t), f"{label}: t differs at {int((a.t != b.t).sum())} pixels"
    diff = a.tri != b.tri
    assert not diff.any(), f"{label}: the triangle differs at {int(diff.sum())} pixels"
    other = (a.image != b.image).any(-1)
    assert not other.any(), f"{label}: {int(other.sum())} pixels differ in colour"
    print(f"{label}: {a.tri.size} pixels, {int((a.tri >= 0).sum())} hits")


def render_both(grid, tris, cam, **kw):
    p = RenderParams(**kw)
    return render(grid, tris, cam, p.replace(traversal="dda")), render(grid, tris, cam, p.replace(traversal="cgt"))


#: float32 tolerances: t (relative), near-ties (relative), edges (barycentric)
F32_T = 1e-5


F32_TIE = 1e-5


F32_GRAZE = 1e-5


def check_f32(res, ref, label, max_grazing=0.01):
    """A float32 render or cast against the brute force: nothing wrong beyond float32 rounding."""
    t = res.t.reshape(-1).astype(np.float64)
    tri = res.tri.reshape(-1)
    diff = R.compare_hits(t, tri, ref, t_rtol=F32_T, tie_rtol=F32_TIE, graze_tol=F32_GRAZE)
    assert len(diff.bad) == 0, (f"{label}: {len(diff.bad)} of {len(t)} rays differ from the brute force beyond "
                                f"float32 rounding, first {diff.bad[:5]}")
    assert len(diff.grazing) <= max_grazing * len(t) + 1, f"{label}: {len(diff.grazing)} grazing rays"
    return diff


def trace_one_packet(g, o, d, watertight=True, f32=False, max_cells=np.inf):
    """Rays o, d (n, 3), n <= cgt.PN, as one packet through cgt.trace_packet over the grid g
    (GridArrays), tmin 0 and no tmax: (its return value, t (n,), triangle (n,))."""
    n = len(o)
    S = np.empty(cgt.NS * cgt.PN)
    io = np.empty(cgt.NIO * cgt.PN)
    for r, col in ((cgt.IO_OX, o[:, 0]), (cgt.IO_OY, o[:, 1]), (cgt.IO_OZ, o[:, 2]), (cgt.IO_DX, d[:, 0]),
                   (cgt.IO_DY, d[:, 1]), (cgt.IO_DZ, d[:, 2]), (cgt.IO_TMAX, np.full(n, np.inf))):
        io[r * cgt.PN : r * cgt.PN + n] = col
    r = cgt.trace_packet(g, n, io, cgt.packet_query(0.0, watertight, False, f32), S, np.empty(cgt.MBOX, np.int32),
                         float(max_cells), None)
    return r, io[cgt.IO_T * cgt.PN : cgt.IO_T * cgt.PN + n].copy(), io[cgt.IO_F * cgt.PN : cgt.IO_F * cgt.PN + n].copy()
