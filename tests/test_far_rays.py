"""Rays from far outside the grid: every traversal gives the hits of the exact ray.

Rays start 1e8 .. 1e29 away (within the coordinate limit 1e30) from the Utah teapot and an
icosphere, along every axis in both directions and obliquely, and are cast through every path:
RayCaster.cast ray by ray and in CGT packets (pass 1 and 2 of gridrt.trace.batch, checked to
have made packets), watertight and fast tests, float32 packet tests, tmin > 0 (which sends far
packets ray by ray), uniform and two-level grids, and rendered with the dda and cgt traversals.

The reference (:func:`exact_ref`) is tests/reference.py's float64 brute force cast from a point
of the exact ray near the mesh: each origin is moved along its ray in rational arithmetic
(fractions.Fraction) to three bounding radii before its closest approach to the mesh's centre,
rounded to float64 there (an error of about 1e-16 of the mesh's size), and the distance moved is
added back to t exactly before rounding.  The brute force cast from the far origin itself cannot
serve: from 3e16 the float64 t of the mesh's near and far sides differ by an ulp or two, and its
differences of coordinates lose the mesh (it agrees with :func:`exact_ref` at 1e8 and 1e12, which
is checked).  A ray agrees when it hits the same triangle with t within 1e-9 (relative; the
float32 t buffer of a render within 1e-6), or both miss; a ray within 1e-9 (barycentric) of an
edge, or at a tie, may pick the neighbouring triangle.
"""

import math
from fractions import Fraction

import numpy as np
import pytest

import reference as R
from conftest import data_path
from helpers.grids import CAST_KINDS

DISTANCES = (1e8, 1e12, 3e16, 1e20, 1e29)
AXES = [np.eye(3)[k] * s for k in range(3) for s in (1.0, -1.0)]
#: an oblique direction whose multiples by a power of ten's float stay exact (powers of two)
OBLIQUE = np.array([1.0, -0.5, 0.25])
T_RTOL = 1e-9
GRAZE = 1e-9


def exact_ref(tris, o, d, c, r):
    """RefHits of rays (o, d) (N, 3) over tris, as the module docstring says: moved in exact
    arithmetic to 3 r before their closest approach to c (rays that start nearer stay)."""
    o = np.asarray(o, np.float64)
    d = np.asarray(d, np.float64)
    near = np.empty_like(o)
    moved = []
    C = [Fraction(float(x)) for x in c]
    for i in range(len(o)):
        O = [Fraction(float(x)) for x in o[i]]
        D = [Fraction(float(x)) for x in d[i]]
        dd = sum(x * x for x in D)
        w = sum((C[k] - O[k]) * D[k] for k in range(3)) / dd - Fraction(3.0 * r / math.sqrt(float(dd)))
        w = max(w, Fraction(0))
        near[i] = [float(O[k] + w * D[k]) for k in range(3)]
        moved.append(w)
    with np.errstate(invalid="ignore", over="ignore"):  # (edge-on triangles: 0 / 0)
        ref = R.ref_cast(tris, near, d)
    ref.near, ref.t_near = near, ref.t.copy()  # (where each ray was cast from, and t from there)
    for i, w in enumerate(moved):
        if ref.tri[i] >= 0:
            ref.t[i] = float(w + Fraction(float(ref.t[i])))
        if np.isfinite(ref.t2[i]):
            ref.t2[i] = float(w + Fraction(float(ref.t2[i])))
    return ref


def check(label, t, tri, ref, t_rtol=T_RTOL, graze=GRAZE):
    diff = R.compare_hits(np.asarray(t, np.float64).reshape(-1), np.asarray(tri).reshape(-1), ref, t_rtol=t_rtol,
                          tie_rtol=1e-12, graze_tol=graze)
    first = diff.bad[:5]
    assert len(diff.bad) == 0, (f"{label}: {len(diff.bad)} of {len(ref.t)} rays differ from the exact ray's "
                                f"brute force, first {first}: got tri {np.asarray(tri).reshape(-1)[first]} "
                                f"t {np.asarray(t).reshape(-1)[first]}, want {ref.tri[first]} {ref.t[first]}")
    assert len(diff.grazing) <= 0.01 * len(ref.t) + 1, f"{label}: {len(diff.grazing)} grazing rays"


@pytest.fixture(scope="module")
def teapot():
    from gridrt.scene import load_mesh

    m = load_mesh(data_path("static/utah_teapot/teapot.obj"))
    v, f = m.vertices64, m.faces.astype(np.int64)
    tris = v[f].astype(np.float32)  # (the engine's storage; the scene sits at the world origin: frame 0)
    lo, hi = v.min(axis=0), v.max(axis=0)
    return tris, v, f, 0.5 * (lo + hi), 0.5 * float(np.linalg.norm(hi - lo))


def pencil(c, r, axis, Z, n=16):
    """n * n rays from c + Z * axis towards a square of side r / 4 across the mesh (centre c)."""
    k = int(np.flatnonzero(axis)[0])
    u, v = (k + 1) % 3, (k + 2) % 3
    o = np.array(c, np.float64)
    o[k] += Z * axis[k]
    s = np.linspace(-0.125 * r, 0.125 * r, n)
    A, B = np.meshgrid(s, s)
    tgt = np.tile(np.asarray(c, np.float64), (n * n, 1))
    tgt[:, u] += A.ravel()
    tgt[:, v] += B.ravel()
    d = np.empty((n * n, 3))
    d[:, k] = -axis[k]
    d[:, u] = (tgt[:, u] - o[u]) / Z  # (the minor components of a far ray: exact relative precision)
    d[:, v] = (tgt[:, v] - o[v]) / Z
    d /= np.linalg.norm(d, axis=1)[:, None]
    return np.tile(o, (n * n, 1)), d


def oblique_pencil(Z, n=9):
    """n * n rays from Z * OBLIQUE (exact) with directions -OBLIQUE + offsets of a mesh's width seen
    from Z, or of a few ulps where that is less than one (then only the central ray, through the
    world origin, can hit)."""
    o = Z * OBLIQUE
    step = max(0.1 / Z, 4e-16)
    j = (np.arange(n) - n // 2) * step
    A, B = np.meshgrid(j, j)
    d = np.tile(-OBLIQUE, (n * n, 1))
    d[:, 1] += A.ravel()
    d[:, 2] += B.ravel()
    return np.tile(o, (n * n, 1)), d


def test_exact_ref_is_the_brute_force_where_float64_suffices(teapot):
    tris, v, f, c, r = teapot
    for Z in (1e8, 1e12):
        o, d = pencil(c, r, AXES[4], Z, 8)
        ref, plain = exact_ref(tris, o, d, c, r), R.ref_cast(tris, o, d)
        assert (ref.tri >= 0).sum() > 20
        check(f"reference at {Z:g}", plain.t, plain.tri, ref)


def _casts(caster, o, d, label, ref):
    """Every batch path of RayCaster.cast on rays (o, d) against ref, and the batch caster itself
    (cast_grouped, in the caster's frame); returns how many rays that traced in packets."""
    from gridrt.trace.batch import cast_grouped
    from gridrt.trace.grids import grid_arrays

    for wt in (True, False):
        for packets in (False, True):
            h = caster.cast(o, d, watertight=wt, packets=packets, threads=1)
            check(f"{label} watertight={wt} packets={packets}", h.t, h.tri, ref)
    h = caster.cast(o, d, tmin=1.0, threads=2)  # tmin > 0: far packets go ray by ray
    check(f"{label} tmin=1", h.t, h.tri, ref)
    h = caster.cast(o, d, packet_precision="float32", threads=1)
    check(f"{label} float32 packets", h.t, h.tri, ref, t_rtol=1e-5, graze=1e-5)
    grid, tris32, frame = caster.grid, caster.triangles, caster.origin
    out = (np.empty(len(o)), np.empty(len(o), np.int32), np.empty(len(o)), np.empty(len(o)))
    made = cast_grouped(grid_arrays(grid, tris32), o - frame, d, 0.0, np.inf, True, False, out)
    check(f"{label} cast_grouped", out[0], out[1], ref)
    return made


@pytest.fixture(scope="module")
def axis_pencils(teapot):
    """{(axis number, Z): (origins, directions, exact_ref)} of the pencils along every axis."""
    tris, v, f, c, r = teapot
    out = {}
    for k, axis in enumerate(AXES):
        for Z in DISTANCES:
            o, d = pencil(c, r, axis, Z)
            out[k, Z] = o, d, exact_ref(tris, o, d, c, r)
            assert (out[k, Z][2].tri >= 0).mean() > 0.2
    return out


@pytest.mark.parametrize("kind", CAST_KINDS)
def test_casts_along_every_axis(teapot, axis_pencils, kind):
    import gridrt
    from gridrt.config import GridParams

    tris, v, f, c, r = teapot
    caster = gridrt.RayCaster(v, f, GridParams(grid=kind))
    packets = 0
    for (k, Z), (o, d, ref) in axis_pencils.items():
        made = _casts(caster, o, d, f"{kind} axis {AXES[k]} at {Z:g}", ref)
        packets += made[0] + made[1]
    assert packets > 0.5 * len(AXES) * len(DISTANCES) * 256  # camera-like batches went through packets


def test_oblique_casts(teapot):
    """Oblique rays; from far away only the central one can be aimed at the mesh (float64
    directions), and it must hit the side facing its origin."""
    import gridrt
    from gridrt.scene import icosphere_mesh

    ico = icosphere_mesh(1280)
    v, f = ico.vertices64, ico.faces.astype(np.int64)
    tris = v[f].astype(np.float32)
    caster = gridrt.RayCaster(v, f)
    for Z in DISTANCES:
        for sign in (1.0, -1.0):
            o, d = oblique_pencil(sign * Z)
            d = d if sign > 0 else -d
            ref = exact_ref(tris, o, d, np.zeros(3), 1.0)
            mid = len(o) // 2
            assert ref.tri[mid] >= 0
            p = ref.near[mid] + d[mid] * ref.t_near[mid]
            assert p @ (sign * OBLIQUE) > 0, "the brute force's hit is on the far side"
            _casts(caster, o, d, f"oblique at {sign * Z:g}", ref)


@pytest.fixture(scope="module")
def far_cameras(teapot):
    """[(label, camera, exact_ref of its rays)]: a camera 1e8 .. 1e29 from the teapot on every
    axis, its view just covering the mesh."""
    from gridrt.camera import Camera

    tris, v, f, c, r = teapot
    out = []
    for k, axis in enumerate(AXES):
        up = (0.0, 0.0, 1.0) if k in (2, 3) else (0.0, 1.0, 0.0)
        for Z in DISTANCES:
            eye = np.array(c, np.float64)
            eye[k // 2] += Z * axis[k // 2]
            cam = Camera(tuple(eye), tuple(c), up=up, fov=2.0 * math.degrees(math.atan(0.5 * r / Z)))
            o, d = cam.rays(RW, RH)  # (the kernels' rays, bit for bit: gridrt.camera.pixel_dir)
            ref = exact_ref(tris, o, d, c, r)
            assert (ref.tri >= 0).mean() > 0.2
            out.append((f"along {axis} at {Z:g}", cam, ref))
    return out


RW, RH = 16, 12


@pytest.mark.parametrize("traversal", ["dda", pytest.param("cgt", marks=pytest.mark.slow)])
def test_renders_from_far_away(teapot, far_cameras, traversal):
    """The dda and cgt renders (watertight and fast tests) from far cameras hit what the exact
    camera rays hit."""
    import gridrt

    tris = teapot[0]
    grid = gridrt.build_grid(tris)
    for label, cam, ref in far_cameras:
        for wt in (True, False):
            res = gridrt.render(grid, tris, cam, gridrt.RenderParams(RW, RH, traversal=traversal, watertight=wt,
                                                                    shading="normal", threads=1))
            check(f"{traversal} render {label} watertight={wt}", res.t, res.tri, ref, t_rtol=1e-6)


def test_origins_beyond_the_coordinate_limit_refused():
    """Within the limit (1e30) a cast from its very edge hits what the exact ray hits; beyond it
    the batch is refused with the ray's index and the limit, before anything is cast."""
    import gridrt
    from gridrt.scene import icosphere_mesh

    ico = icosphere_mesh(80)
    v, f = ico.vertices64, ico.faces.astype(np.int64)
    caster = gridrt.RayCaster(v, f)
    o = np.array([[0.0, 0.0, 1e30], [0.0, 0.0, -1e30], [1e30, 0.0, 0.0]])
    d = -o / 1e30
    h = caster.cast(o, d)
    check("at the limit", h.t, h.tri, exact_ref(v[f].astype(np.float32), o, d, np.zeros(3), 1.0))
    assert (h.tri >= 0).all()
    for bad in (2e30, -1.5e30):
        o2 = o.copy()
        o2[2, 1] = bad
        with pytest.raises(gridrt.InputError, match=r"ray origin 2 \(1e\+30, .*\) is beyond the coordinate limit"):
            caster.cast(o2, d)
        with pytest.raises(gridrt.InputError, match="coordinate limit of 1e"):
            gridrt.cast_rays(gridrt.build_grid(v[f]), v[f], o2, d)
