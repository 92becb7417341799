"""Bad input raises a clear error naming the problem, before any numba kernel runs.

Each case checks the exception type (gridrt.errors.InputError) and a message fragment; the
``no_kernels`` fixture replaces the engine's kernels with tripwires, so a check that happens too
late (inside or after a kernel) fails the test.  The last tests check that a flat scene (zero
extent along an axis) is not an error and renders correctly (brute-force reference).
"""

import numpy as np
import pytest

import reference as R
from conftest import random_rays, random_triangles
from gridrt.arrays import as_mesh
from gridrt.camera import Camera
from gridrt.config import GridParams, RenderParams
from gridrt.errors import InputError
from gridrt.grid import GridBuilder, build_grid
from gridrt.threads import max_threads
from gridrt.trace import cast_rays, render

GOOD = np.array([[[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 0, 1], [1, 0, 1], [0, 1, 1]]], np.float32)


class KernelCalled(AssertionError):
    pass


@pytest.fixture
def no_kernels(monkeypatch):
    """Replace every kernel entry point the Python wrappers call with a tripwire."""
    install_kernel_tripwires(monkeypatch)


def install_kernel_tripwires(monkeypatch):
    from importlib import import_module

    from gridrt.grid.registry import BUILDERS, get_builder
    from gridrt.trace.twin import TWINS

    TWINS.wait()  # (a background warm-up of an earlier test must not meet the tripwires)

    # import_module: gridrt.trace.render is also the name of a function in gridrt.trace
    cam_mod = import_module("gridrt.camera")
    build_mod = import_module("gridrt.grid.build")
    common = import_module("gridrt.grid.common")
    render_mod = import_module("gridrt.trace.render")

    get_builder("serial")  # make sure every strategy is registered

    def trip(name):
        def f(*a, **k):
            raise KernelCalled(f"kernel {name} ran before the input was rejected")

        return f

    for mod, names in (
        (common, ["scene_bounds", "clear_macro_range", "clear_macro_parallel", "macro_build_range", "macro_build_parallel"]),
        (render_mod, ["cast_grouped", "dda_render", "cgt_render", "shade"]),
        (cam_mod, ["_fill_rays"]),
    ):
        for n in names:
            monkeypatch.setattr(mod, n, trip(n))
    for cls in BUILDERS.values():
        monkeypatch.setattr(cls, "insert", trip(f"{cls.__name__}.insert"))
    assert build_mod.common is common


@pytest.fixture
def no_insert(monkeypatch):
    """Tripwires on the insertion, clear and macro stages only (the bounds pass may run)."""
    install_insert_tripwires(monkeypatch)


def install_insert_tripwires(monkeypatch):
    from importlib import import_module

    from gridrt.grid.registry import BUILDERS, get_builder
    from gridrt.trace.twin import TWINS

    TWINS.wait()  # (a background warm-up of an earlier test must not meet the tripwires)

    get_builder("serial")
    common = import_module("gridrt.grid.common")

    def trip(*a, **k):
        raise KernelCalled("a grid build stage ran before the input was rejected")

    for n in ("clear_macro_range", "clear_macro_parallel", "macro_build_range", "macro_build_parallel"):
        monkeypatch.setattr(common, n, trip)
    for cls in BUILDERS.values():
        monkeypatch.setattr(cls, "insert", trip)


def test_tripwires_work(grid):
    """The fixtures above do catch kernels that run (so the tests below can fail)."""
    o, d = [[0.2, 0.2, 2]], [[0, 0, -1]]
    with pytest.MonkeyPatch.context() as mp:
        install_kernel_tripwires(mp)
        with pytest.raises(KernelCalled):
            build_grid(GOOD)
        with pytest.raises(KernelCalled):
            cast_rays(grid, GOOD, o, d)
        with pytest.raises(KernelCalled):
            render(grid, GOOD, Camera(), RenderParams(width=4, height=4))
        with pytest.raises(KernelCalled):
            Camera().rays(4, 4)
    with pytest.MonkeyPatch.context() as mp:
        install_insert_tripwires(mp)
        with pytest.raises(KernelCalled):
            GridBuilder().build(GOOD)


@pytest.fixture(scope="module")
def grid():
    return build_grid(GOOD, GridParams(density=4.0))


def bad_tris(kind):
    t = GOOD.copy()
    if kind == "nan":
        t[1, 2, 0] = np.nan
    elif kind == "inf":
        t[0, 1, 2] = np.inf
    elif kind == "-inf":
        t[0, 0, 1] = -np.inf
    return t


# ----------------------------------------------------------------------------------------------
# triangles and meshes


@pytest.mark.parametrize("kind", ["nan", "inf", "-inf"])
def test_nonfinite_triangles(no_kernels, kind):
    with pytest.raises(InputError, match="NaN or infinity"):
        build_grid(bad_tris(kind))


@pytest.mark.parametrize("kind", ["nan", "inf"])
def test_nonfinite_triangles_frame_builder(no_insert, kind):
    """GridBuilder (the per-frame path) rejects NaN/inf too, before inserting anything."""
    with pytest.raises(InputError, match="NaN"):
        GridBuilder(GridParams()).build(bad_tris(kind))


def test_nonfinite_vertices_in_mesh(no_kernels):
    v = np.array([[0, 0, 0], [1, 0, 0], [0, np.nan, 0]], np.float32)
    with pytest.raises(InputError, match="NaN or infinity"):
        as_mesh(v, [[0, 1, 2]])


@pytest.mark.parametrize(
    "faces,match",
    [
        ([[0, 1, 3]], "face index 3 out of range for 3 vertices"),
        ([[0, 1, 2], [0, 7, 1]], "face index 7 out of range"),
        ([[0, -1, 2]], "negative face index -1"),
        ([[0, 1]], "faces must have shape"),
        ([[0.5, 1, 2]], "face indices must be integers"),
    ],
)
def test_bad_face_indices(no_kernels, faces, match):
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32)
    with pytest.raises(InputError, match=match):
        as_mesh(v, faces)


def test_bad_face_indices_scene_mesh(no_kernels):
    from gridrt.scene import Mesh

    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32)
    with pytest.raises(InputError, match="out of range"):
        Mesh(v, np.array([[0, 1, 5]]))
    with pytest.raises(InputError, match="negative face index"):
        Mesh(v, np.array([[0, 1, -2]]))


def test_empty_scene(no_kernels):
    with pytest.raises(InputError, match="empty"):
        build_grid(np.zeros((0, 3, 3), np.float32))
    with pytest.raises(InputError, match="empty"):
        as_mesh(np.zeros((0, 3), np.float32), np.zeros((0, 3), np.int32))
    with pytest.raises(InputError, match="empty"):
        GridBuilder().build(np.zeros((0, 3, 3), np.float32))


@pytest.mark.parametrize("shape", [(2, 3), (2, 3, 2), (2, 4, 3), (3,)])
def test_bad_triangle_shape(no_kernels, shape):
    with pytest.raises(InputError, match=r"shape \(F, 3, 3\)"):
        build_grid(np.zeros(shape, np.float32))


def test_all_degenerate(no_kernels):
    point = np.ones((4, 3, 3), np.float32)
    line = np.array([[[0, 0, 0], [1, 1, 1], [2, 2, 2]]] * 3, np.float32)
    for tris in (point, line):
        with pytest.raises(InputError, match="degenerate"):
            build_grid(tris)
    with pytest.raises(InputError, match="degenerate"):
        as_mesh(np.array([[0, 0, 0], [1, 1, 1], [2, 2, 2]], np.float32), [[0, 1, 2], [2, 1, 0]])


def test_some_degenerate_is_fine():
    tris = np.concatenate([GOOD, np.ones((2, 3, 3), np.float32)])
    g = build_grid(tris)
    assert g.n_triangles == 4


def test_non_numeric_triangles(no_kernels):
    with pytest.raises(InputError, match="numeric"):
        build_grid(np.array([[["a", "b", "c"]] * 3]))


# ----------------------------------------------------------------------------------------------
# parameters


@pytest.mark.parametrize("density", [0, -1.0, float("nan"), float("inf"), "many", None])
def test_bad_density(density):
    with pytest.raises(InputError, match="density"):
        GridParams(density=density)


@pytest.mark.parametrize("macro", [0, -2, 1.5, 65, "four"])
def test_bad_macro(macro):
    with pytest.raises(InputError, match="macro"):
        GridParams(macro=macro)


def test_unknown_strategy():
    with pytest.raises(InputError, match=r"unknown build strategy 'nope'.*serial"):
        GridParams(strategy="nope")


@pytest.mark.parametrize("insert", ["sat", "", None, "BBOX"])
def test_bad_insert_mode(insert):
    with pytest.raises(InputError, match=r"unknown insertion test.*bbox, exact"):
        GridParams(insert=insert)


@pytest.mark.parametrize("threads", [0, -1, 10**6, 2.5, "two"])
def test_bad_thread_count(threads):
    with pytest.raises(InputError, match="thread count"):
        GridParams(threads=threads)
    with pytest.raises(InputError, match="thread count"):
        RenderParams(threads=threads)


def test_thread_count_above_pool(no_kernels, grid):
    too_many = max_threads() + 1
    with pytest.raises(InputError, match=f"thread count must be between 1 and {max_threads()}"):
        cast_rays(grid, GOOD, [[0.2, 0.2, 2]], [[0, 0, -1]], threads=too_many)
    with pytest.raises(InputError, match="thread count"):
        cast_rays(grid, GOOD, [[0.2, 0.2, 2]], [[0, 0, -1]], threads=0)


@pytest.mark.parametrize("field,value,match", [
    ("width", 0, "image width"),
    ("width", -5, "image width"),
    ("height", 0, "image height"),
    ("height", -1, "image height"),
    ("width", 2.5, "image width"),
    ("shading", "phong", "unknown shading mode"),
    ("light", (1, 2), "light"),
    ("light", (1, float("nan"), 2), "light"),
])
def test_bad_render_params(field, value, match):
    with pytest.raises(InputError, match=match):
        RenderParams(**{field: value})


def test_camera_rays_bad_size(no_kernels):
    cam = Camera()
    with pytest.raises(InputError, match="image width"):
        cam.rays(0, 4)
    with pytest.raises(InputError, match="image height"):
        cam.rays(4, -1)


@pytest.mark.parametrize("kw,match", [
    (dict(eye=(0, 0, 0), target=(0, 0, 0)), "coincide"),
    (dict(up=(0, 0, 0)), "up vector is zero"),
    (dict(eye=(0, 5, 0), target=(0, 0, 0), up=(0, 1, 0)), "parallel"),
    (dict(fov=0.0), "fov"),
    (dict(fov=180.0), "fov"),
    (dict(eye=(0, np.nan, 1)), "eye"),
])
def test_bad_camera(kw, match):
    with pytest.raises(InputError, match=match):
        Camera(**kw)


@pytest.mark.parametrize("fov", [0.0, -30.0, 180.0, float("inf"), float("-inf"), float("nan"), True, "wide"])
def test_bad_fov_is_named_by_camera_and_automatic_framing(no_kernels, fov):
    """Both the explicit camera and automatic framing refuse a bad fov, naming the fov (automatic
    framing once divided by sin(0) or took sin(inf): ZeroDivisionError / math domain error; a NaN fov
    made a NaN eye, and the error blamed the eye)."""
    for make in (lambda: Camera(fov=fov), lambda: Camera.frame((0, 0, 0), (1, 1, 1), fov=fov)):
        with pytest.raises(InputError) as info:
            make()
        msg = str(info.value)
        assert msg.startswith("camera fov") and "eye" not in msg, msg


def test_fov_too_narrow_to_frame_the_scene_names_the_fov(no_kernels):
    with pytest.raises(InputError, match=r"camera fov 1e-300 is too narrow to frame a scene 1\.73 across"):
        Camera.frame((0, 0, 0), (1, 1, 1), fov=1e-300)
    cam = Camera.frame((0, 0, 0), (1, 1, 1), fov=1e-20)  # 1e22 away: still inside the coordinate limit
    dist = 0.5 * np.sqrt(3.0) / np.sin(np.radians(1e-20) / 2) * 1.05
    assert np.linalg.norm(np.subtract(cam.eye, cam.target)) == pytest.approx(dist, rel=1e-12) and dist > 1e22


@pytest.mark.parametrize("name", ["eye", "target"])
def test_camera_beyond_the_coordinate_limit_names_the_point_not_the_up_vector(no_kernels, name):
    """An eye at 1e308 once overflowed the viewing direction's norm, and the error said the up vector
    was parallel to the viewing direction."""
    kw = {"eye": (0.0, 0.0, 5.0), "target": (0.0, 0.0, 0.0), name: (1e308, 0.0, 0.0)}
    with pytest.raises(InputError) as info:
        Camera(**kw)
    msg = str(info.value)
    assert msg.startswith(f"camera {name} (1e+308, 0, 0) is beyond the coordinate limit of 1e+30"), msg
    assert "up" not in msg
    Camera(**{**kw, name: (1e30, 0.0, 0.0)})  # at the limit: accepted


def test_camera_basis_is_exact_and_survives_extreme_vectors():
    """Ordinary cameras keep the documented formula bit for bit; a huge or tiny up vector and eye and
    target 1e30 apart (whose squared norms overflow / underflow) give the same basis as a unit one."""
    eye, target, up = np.array([0.5, 4.0, 14.0]), np.array([0.0, 0.8, 0.0]), np.array([0.0, 1.0, 0.0])
    b = Camera(eye=tuple(eye), target=tuple(target), up=tuple(up), fov=50.0).basis()
    fwd = (target - eye) / np.linalg.norm(target - eye)
    right = np.cross(fwd, up) / np.linalg.norm(np.cross(fwd, up))
    np.testing.assert_array_equal(b[:4], [eye, fwd, right, np.cross(right, fwd)])
    assert b[4, 0] == np.tan(np.radians(50.0) / 2)
    rng = np.random.default_rng(7)
    for _ in range(300):  # random cameras from 1e-6 to 1e6 across: the same bits as np.cross's formula
        eye, target, up = rng.normal(size=(3, 3)) * 10.0 ** rng.uniform(-6, 6, (3, 1))
        b = Camera(eye=tuple(eye), target=tuple(target), up=tuple(up), fov=50.0).basis()
        fwd = (target - eye) / np.linalg.norm(target - eye)
        right = np.cross(fwd, up) / np.linalg.norm(np.cross(fwd, up))
        np.testing.assert_array_equal(b[:4], [eye, fwd, right, np.cross(right, fwd)])
    unit = Camera(eye=(3.0, 0.0, 0.0), target=(0.0, 0.0, 0.0), up=(0.0, 1.0, 1.0)).basis()
    for up_ in [(0.0, 1e300, 1e300), (0.0, 1e-300, 1e-300)]:
        np.testing.assert_allclose(Camera(eye=(3.0, 0.0, 0.0), target=(0.0, 0.0, 0.0), up=up_).basis(), unit,
                                   rtol=0, atol=1e-15)
    far = Camera(eye=(1e30, 0.0, 0.0), target=(-1e30, 0.0, 0.0), up=(0.0, 1e300, 1e300)).basis()
    np.testing.assert_allclose(far[1:4], [[-1, 0, 0], [0, _H, -_H], [0, _H, _H]], rtol=0, atol=1e-15)


_H = np.sqrt(0.5)


# ----------------------------------------------------------------------------------------------
# rays


def test_zero_ray_direction(no_kernels, grid):
    with pytest.raises(InputError, match="ray direction 1 is the zero vector"):
        cast_rays(grid, GOOD, [[0, 0, 2], [0, 0, 2]], [[0, 0, -1], [0, 0, 0]])


@pytest.mark.parametrize("o_shape,d_shape,match", [
    ((5, 3), (4, 3), "differ in shape"),
    ((5, 2), (5, 2), r"origins must have shape \(N, 3\)"),
    ((5, 3), (5, 3, 1), r"directions must have shape \(N, 3\)"),
    ((3,), (3,), r"must have shape \(N, 3\)"),
])
def test_mismatched_ray_shapes(no_kernels, grid, o_shape, d_shape, match):
    with pytest.raises(InputError, match=match):
        cast_rays(grid, GOOD, np.ones(o_shape), np.ones(d_shape))


def test_nonfinite_rays(no_kernels, grid):
    with pytest.raises(InputError, match="ray origins contain NaN"):
        cast_rays(grid, GOOD, [[0, np.nan, 2]], [[0, 0, -1]])
    with pytest.raises(InputError, match="ray directions contain NaN"):
        cast_rays(grid, GOOD, [[0, 0, 2]], [[0, 0, np.inf]])


@pytest.mark.parametrize("tmin,tmax", [(-1.0, 1.0), (2.0, 1.0), (float("nan"), 1.0), (0.0, float("nan"))])
def test_bad_t_range(no_kernels, grid, tmin, tmax):
    with pytest.raises(InputError, match="tmin"):
        cast_rays(grid, GOOD, [[0.2, 0.2, 2]], [[0, 0, -1]], tmin=tmin, tmax=tmax)


def test_triangles_do_not_match_grid(no_kernels, grid):
    with pytest.raises(InputError, match="built over 2 triangles but 3"):
        cast_rays(grid, np.concatenate([GOOD, GOOD[:1]]), [[0.2, 0.2, 2]], [[0, 0, -1]])
    with pytest.raises(InputError, match=r"\(F,3,3\) array the grid was built from"):
        cast_rays(grid, GOOD.astype(complex), [[0.2, 0.2, 2]], [[0, 0, -1]])
    with pytest.raises(InputError, match="built over 2 triangles but 3"):
        render(grid, np.concatenate([GOOD, GOOD[:1]]), Camera(), RenderParams(width=4, height=4))


def test_zero_rays_is_fine(grid):
    h = cast_rays(grid, GOOD, np.zeros((0, 3)), np.zeros((0, 3)))
    assert h.t.shape == (0,) and h.tri.shape == (0,)


# ----------------------------------------------------------------------------------------------
# flat scenes are valid and render correctly


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_flat_scene_renders_correctly(rng, axis):
    """All triangles in one plane (zero extent along ``axis``): the grid is one cell thick and
    the camera and random rays agree with the brute-force reference."""
    tris = random_triangles(rng, 150, size=0.2)
    tris[:, :, axis] = 0.375
    g = build_grid(tris, GridParams(density=4.0, macro=2))
    assert g.spec.dims[axis] == 1 and (g.spec.dims >= 1).all()
    lo, hi = g.spec.lo, g.spec.hi
    view = np.array([0.55, 0.45, 1.0])
    view[axis] += 1.0  # look at the plane obliquely
    cam = Camera.frame(lo, hi, direction=tuple(view))
    w, h = 48, 40
    res = render(g, tris, cam, RenderParams(width=w, height=h, shading="normal", traversal="dda"))
    ref = R.ref_cast(tris, *R.ref_camera_rays(cam.eye, cam.target, cam.up, cam.fov, w, h))
    diff = R.compare_hits(res.t.reshape(-1).astype(np.float64), res.tri.reshape(-1), ref, t_rtol=1e-6, graze_tol=1e-9)
    assert len(diff.bad) == 0, f"{len(diff.bad)} pixels differ from the reference"
    assert ref.hit.mean() > 0.08, "framing sees almost nothing: the test would be vacuous"
    img = R.ref_render(tris, cam, w, h, "normal").image
    assert (np.abs(img.astype(int) - res.image.astype(int)).max(axis=2) > 2).sum() <= 0.005 * w * h
    o, d = random_rays(rng, 20_000, lo, hi, outside=0.3, aim=True)
    diff = R.compare_hits(*_cast(g, tris, o, d), R.ref_cast(tris, o, d), graze_tol=1e-9)
    assert len(diff.bad) == 0
    # rays lying in the scene's plane hit nothing (they are parallel to every triangle)
    o2 = o.copy()
    o2[:, axis] = 0.375
    d2 = d.copy()
    d2[:, axis] = 0.0
    ok = np.linalg.norm(d2, axis=1) > 0
    h2 = cast_rays(g, tris, o2[ok], d2[ok])
    assert (h2.tri == -1).all()


def _cast(g, tris, o, d):
    h = cast_rays(g, tris, o, d)
    return h.t, h.tri


def test_flat_scene_viewed_head_on(rng):
    """Camera looking straight down the flat axis: every pixel's hit agrees with the reference."""
    tris = random_triangles(rng, 100, size=0.15)
    tris[:, :, 1] = -2.0
    g = build_grid(tris)
    c = 0.5 * (g.spec.lo + g.spec.hi) + g.origin  # the grid's frame -> world
    cam = Camera(eye=(c[0], -1.2, c[2]), target=(c[0], -2.0, c[2]), up=(0, 0, 1), fov=60.0)
    res = render(g, tris, cam, RenderParams(width=40, height=40, traversal="dda"))
    o, d = R.ref_camera_rays(cam.eye, cam.target, cam.up, cam.fov, 40, 40)
    ref = R.ref_cast(tris, o, d)
    diff = R.compare_hits(res.t.reshape(-1).astype(np.float64), res.tri.reshape(-1), ref, t_rtol=1e-6, graze_tol=1e-9)
    assert len(diff.bad) == 0 and ref.hit.mean() > 0.2
    # analytic: every hit lies on the plane y = -2, at depth 0.8 along the view axis (0, -1, 0)
    hit = res.tri.reshape(-1) >= 0
    np.testing.assert_allclose(res.t.reshape(-1)[hit] * -d[hit, 1], 0.8, rtol=1e-6)
