"""Light maps (gridrt.trace.lightmap): the shadow segments a map shows clear are those nothing
blocks (the single-ray DDA's verdict, one ray per light per pixel, and a float64 brute force), and
renders that use maps are the renders without them, pixel for pixel, and match the material
reference; maps are made only for triangles and point lights seen in an earlier frame."""

import numpy as np
import pytest

import reference as R
from gridrt.app.bench.reference import brute_cast
from gridrt.camera import Camera
from gridrt.config import GridParams, RenderParams
from gridrt.grid import GridBuilder
from gridrt.grid.build import build_grid
from gridrt.trace.batch import cast_grouped
from gridrt.trace.grids import grid_arrays
from gridrt.trace.lightmap import CLUSTER_EPS, LightMap, LightMaps, NoLightMaps, clear_lit, plane_clusters
from gridrt.trace.records import HitPoints
from gridrt.trace.render import Looks, Renderer
from gridrt.trace.twin import TWINS
from helpers.material_scene import CAM, _diag, compare, engine_lights, engine_surface, scene


def _floor_and_clutter(rng):
    """A floor of 20 x 20 quads (shared edges and corners), and 600 small triangles above it."""
    tris = []
    for i in range(20):
        for k in range(20):
            x0, z0 = -2.0 + 0.2 * i, -2.0 + 0.2 * k
            a, b, c, d = (x0, 0.0, z0), (x0 + 0.2, 0.0, z0), (x0 + 0.2, 0.0, z0 + 0.2), (x0, 0.0, z0 + 0.2)
            tris += [[a, c, b], [a, d, c]]
    centres = rng.uniform([-2.0, 0.2, -2.0], [2.0, 1.5, 2.0], (600, 1, 3))
    tris = np.concatenate([np.asarray(tris), centres + rng.normal(0, 0.06, (600, 3, 3))])
    return np.ascontiguousarray(tris, np.float32)


def _segments(rng, tris, light, off, n):
    """Shadow segments as the material pass makes them: from the light back to points p on
    triangles facing it (some at corners and on edges) moved off by off along their normal towards
    the light; and the hits (p and that normal) as the material pass keeps them."""
    t64 = tris.astype(np.float64)
    nrm = np.cross(t64[:, 1] - t64[:, 0], t64[:, 2] - t64[:, 0])
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    nrm *= np.sign(((light - t64[:, 0]) * nrm).sum(1))[:, None]   # facing the light
    f = rng.integers(0, len(tris), n)
    w = rng.dirichlet([1, 1, 1], n)
    w[: n // 8] = np.eye(3)[rng.integers(0, 3, n // 8)]              # corners
    w[n // 8: n // 4, rng.integers(0, 3)] = 0.0                       # edges
    w /= w.sum(1, keepdims=True)
    p = (w[:, :, None] * t64[f]).sum(1)
    return p, nrm[f]


def _hits(p, n):
    """HitPoints of hits p with normals n (the fields clear_lit reads: pos, ng)."""
    z = np.zeros((len(p), 3), np.float32)
    return HitPoints(np.ascontiguousarray(p), np.ascontiguousarray(n), z, z, z)


def test_light_map_clears_only_segments_nothing_blocks(rng):
    """Segments from a point light to points on a tiled floor (its shared edges and corners too),
    on clutter above it and in the space between (as another grid's hits, with normals drawn at
    random towards the light): every segment the map shows clear is clear for the single-ray DDA
    and for a float64 brute force, and the map shows most of the clear ones; every one it shows
    blocked is blocked for both."""
    tris = _floor_and_clutter(rng)
    light = np.array([0.15, 2.2, -0.35])
    off = 1e-6 * _diag(tris)
    p, n = _segments(rng, tris, light, off, 24000)
    q = rng.uniform([-2.0, 0.05, -2.0], [2.0, 1.6, 2.0], (12000, 3))
    nq = rng.normal(size=(12000, 3))
    nq /= np.linalg.norm(nq, axis=1, keepdims=True)
    nq *= np.sign(((light - q) * nq).sum(1))[:, None]
    p, n = np.concatenate([p, q]), np.concatenate([n, nq])
    end = p + n * off
    o, d = end + (light - end), -(light - end)
    lm = LightMap(light, plane_clusters(tris, CLUSTER_EPS * _diag(tris)))
    near = lm.build(tris)
    assert near > 0.1
    marks = np.full(len(o), 3, np.uint8)
    blocked_map = np.zeros(len(o), bool)
    cleared, shown = clear_lit(lm.arrays(tris), _hits(p, n), np.arange(len(o)), off, o, d, 1, marks, blocked_map)
    clear = (marks & 1) == 0
    assert cleared == clear.sum() and ((marks & 2) == 2).all()   # (only bit 0 is touched)
    g = grid_arrays(GridBuilder().build(tris, GridParams()), tris)
    out = (np.empty(len(o)), np.empty(len(o), np.int32), np.empty(len(o)), np.empty(len(o)))
    cast_grouped(g, o, d, 0.0, 1.0, True, True, out, 0.0, tri_only=True)   # one ray at a time
    blocked = out[1] >= 0
    assert not (clear & blocked).any(), np.flatnonzero(clear & blocked)[:5]
    assert clear.sum() > 0.5 * (~blocked).sum() and blocked.mean() > 0.1
    pick = rng.choice(np.flatnonzero(clear), 1500, replace=False)
    t, f, _ = brute_cast(tris, o[pick], d[pick], 0.0, 1.0)
    assert (f < 0).all()
    assert shown == blocked_map.sum() and not (blocked_map & clear).any()
    assert not (blocked_map & ~blocked).any(), np.flatnonzero(blocked_map & ~blocked)[:5]
    assert shown > 0.1 * blocked.sum()
    pick = rng.choice(np.flatnonzero(blocked_map), min(shown, 1500), replace=False)
    t, f, _ = brute_cast(tris, o[pick], d[pick], 0.0, 1.0)
    assert (f >= 0).all()


def test_light_map_shows_blocked_only_what_a_roof_blocks(rng):
    """A light under a roof of 8 x 8 quads (shared edges and corners): segments to points beyond
    the roof, through its inside, edges and corners, and to points just short of it: the map shows
    blocked only segments the DDA and a float64 brute force find blocked, and most of those that
    pass through a quad's inside, none that end short of the roof."""
    roof = np.ascontiguousarray(_tiles(8, 0.25, y=1.0), np.float32)
    light = np.array([0.05, 0.2, -0.1])
    n = 30000
    g = rng.uniform(-0.9, 0.9, (n, 2))
    g[: n // 6] = np.round(g[: n // 6] / 0.25) * 0.25                                  # at corners
    g[n // 6: n // 3, 0] = np.round(g[n // 6: n // 3, 0] / 0.25) * 0.25                # on edges
    q = np.column_stack([g[:, 0], np.ones(n), g[:, 1]])                                # on the roof
    v = q - light
    k = rng.uniform(0.0, 1.0, n)
    scale = np.where(k < 0.5, 1.0 + rng.uniform(1e-4, 0.5, n), np.where(k < 0.75, 1.0 - 1e-7, 1.0 + 1e-7))
    end = light + v * scale[:, None]
    o, d = end + (light - end), -(light - end)
    up = np.tile([0.0, -1.0, 0.0], (n, 1))
    lm = LightMap(light, plane_clusters(roof, CLUSTER_EPS * _diag(roof)))
    lm.build(roof)
    marks = np.full(n, 1, np.uint8)
    shown = np.zeros(n, bool)
    cl, bl = clear_lit(lm.arrays(roof), _hits(end, up), np.arange(n), 0.0, o, d, 1, marks, shown)
    assert bl == shown.sum()
    gr = grid_arrays(GridBuilder().build(roof, GridParams()), roof)
    out = (np.empty(n), np.empty(n, np.int32), np.empty(n), np.empty(n))
    cast_grouped(gr, o, d, 0.0, 1.0, True, True, out, 0.0, tri_only=True)
    blocked = out[1] >= 0
    assert not (shown & ~blocked).any(), np.flatnonzero(shown & ~blocked)[:5]
    assert not shown[scale < 1.0].any()
    inside = (scale > 1.0 + 1e-5) & (np.arange(n) >= n // 3)
    assert blocked[inside].all() and shown[inside].mean() > 0.7   # (not the cells a triangle's edge crosses)
    pick = rng.choice(np.flatnonzero(shown), 2000, replace=False)
    t, f, _ = brute_cast(roof, o[pick], d[pick], 0.0, 1.0)
    assert (f >= 0).all()


def _tiles(n, size, y=0.0, tilt=0.0):
    """n x n quads of side size centred on the origin at height y (two triangles each, sharing
    edges and corners), turned by tilt radians about the x axis."""
    i, k = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    x0, z0 = (i.ravel() - n / 2) * size, (k.ravel() - n / 2) * size
    a = np.stack([x0, np.zeros_like(x0), z0], 1)
    b, c, d = a + [size, 0, 0], a + [size, 0, size], a + [0, 0, size]
    t = np.concatenate([np.stack([a, c, b], 1), np.stack([a, d, c], 1)])
    rot = np.array([[1, 0, 0], [0, np.cos(tilt), -np.sin(tilt)], [0, np.sin(tilt), np.cos(tilt)]])
    return t @ rot.T + [0.0, y, 0.0]


def test_plane_clusters_hold_their_triangles(rng):
    """Clusters of triangles in one plane: every triangle's corners lie within its cluster's tol of
    the cluster's plane (float64, computed here); a floor's tiles share one cluster, as do a tilted
    plane's (its corners rounded to float32); a parallel floor 10 eps above, a triangle without
    area and clutter each stay apart; lone names the triangle of each one-triangle cluster."""
    eps = 1e-6
    floor = _tiles(12, 0.25)
    tilted = _tiles(8, 0.2, y=0.7, tilt=0.3)
    above = _tiles(4, 0.25, y=10 * eps)
    clutter = rng.uniform(-1, 1, (50, 3, 3))
    flat = np.array([[[0.0, 1.0, 0.0], [1.0, 1.0, 0.0], [2.0, 1.0, 0.0]]])   # no area
    parts = [floor, tilted, above, clutter, flat]
    tris = np.ascontiguousarray(np.concatenate(parts), np.float32)
    cl = plane_clusters(tris, eps)
    of, planes, lone = cl.of, cl.planes, cl.lone
    start = np.cumsum([0] + [len(t) for t in parts])
    part = [of[start[k]:start[k + 1]] for k in range(len(parts))]
    assert len(np.unique(part[0])) == 1 and len(np.unique(part[1])) == 1 and len(np.unique(part[2])) == 1
    assert part[0][0] != part[2][0] and not np.isin(part[3], np.concatenate(part[:3])).any()
    assert len(np.unique(part[3])) == len(clutter) and np.isinf(planes[part[4][0], 4])
    t = tris.astype(np.float64)
    n, h, tol = planes[of, :3], planes[of, 3], planes[of, 4]
    ok = np.isfinite(tol)
    assert np.allclose(np.linalg.norm(n[ok], axis=1), 1.0, atol=1e-12)
    dev = np.abs(np.einsum("fkc,fc->fk", t, n) - h[:, None]).max(1)
    assert (dev[ok] <= tol[ok]).all() and (tol[ok] <= eps + 1e-9).all()
    count = np.bincount(of, minlength=len(planes))
    assert np.array_equal(lone[of], np.where(count[of] == 1, np.arange(len(tris)), -1))


def test_light_map_keeps_a_cluster_s_triangles_off_its_plane(rng):
    """A floor of flat square tiles, each at its own height between 1 and 9 mm, in one cluster
    (clusters of triangles within 1 cm of a plane): segments from a light above it to points from
    0 to 1.2 cm above the floor are shown clear only where nothing blocks them (the DDA): the
    cluster's corners' distance from its plane counts, not only the plane."""
    tris = _tiles(60, 0.05)
    tris[:, :, 1] = np.tile(rng.uniform(0.001, 0.009, 3600), 2)[:, None]   # (a quad's two triangles alike)
    tris = np.ascontiguousarray(tris, np.float32)
    cl = plane_clusters(tris, 0.01)
    assert len(np.unique(cl.of)) == 1 and 0.005 < cl.planes[0, 4] < 0.01
    light = np.array([0.1, 1.0, -0.2])
    n = 20000
    p = np.column_stack([rng.uniform(-1.4, 1.4, n), rng.uniform(0.0, 0.012, n), rng.uniform(-1.4, 1.4, n)])
    up = np.tile([0.0, 1.0, 0.0], (n, 1))
    off = 1e-6 * _diag(tris)
    end = p + up * off
    o, dd = end + (light - end), -(light - end)
    lm = LightMap(light, cl)
    lm.build(tris)
    marks = np.full(n, 1, np.uint8)
    clear_lit(lm.arrays(tris), _hits(p, up), np.arange(n), off, o, dd, 1, marks, np.zeros(n, bool))
    g = grid_arrays(GridBuilder().build(tris, GridParams()), tris)
    out = (np.empty(n), np.empty(n, np.int32), np.empty(n), np.empty(n))
    cast_grouped(g, o, dd, 0.0, 1.0, True, True, out, 0.0, tri_only=True)
    blocked = out[1] >= 0
    assert 0.2 < blocked.mean() < 0.8
    assert not ((marks == 0) & blocked).any()
    assert (marks == 0).sum() > 0.1 * n   # (the points above every tile)


def test_light_map_clears_a_floor_of_small_tiles(rng):
    """A floor of small tiles under a point light, so that more than K of them come within a cell
    of each of the map's cells: nothing blocks its segments, and the map shows every one clear (its
    tiles are one cluster, kept once a cell).  With every tile a cluster of its own, the cells
    are full and most segments are not shown clear."""
    tris = np.ascontiguousarray(_tiles(150, 0.02), np.float32)   # 45,000 triangles, 3 m wide
    light = np.array([0.1, 1.2, -0.2])
    off = 1e-6 * _diag(tris)
    p, n = _segments(rng, tris, light, off, 20000)
    end = p + n * off
    o, d = end + (light - end), -(light - end)
    cleared = []
    for eps in (CLUSTER_EPS * _diag(tris), -1.0):   # (below 0: each triangle alone)
        lm = LightMap(light, plane_clusters(tris, eps))
        lm.build(tris)
        marks = np.full(len(o), 1, np.uint8)
        cleared.append(clear_lit(lm.arrays(tris), _hits(p, n), np.arange(len(o)), off, o, d, 1, marks,
                                 np.zeros(len(o), bool))[0])
        assert cleared[-1] == (marks == 0).sum()
    assert cleared[0] == len(o) and cleared[1] < 0.5 * len(o)


@pytest.mark.parametrize("traversal,threads,samples", [("cgt", 2, 0), ("dda", 1, 0), ("cgt", 2, 2)])
def test_renders_with_light_maps_are_the_renders_without(rng, traversal, threads, samples):
    """The material pass with shadows over one grid, frame after frame with the camera moving:
    from the second frame the renderer leaves out segments its light maps show clear (its two
    point lights, one map a frame; the directional one has none; a frame later on a cold compile
    cache), and
    every frame equals, pixel for pixel and in the colours before clamping, the frame of a
    renderer without maps, and the reference (with 2 lights drawn a pixel: the renderer without
    maps, draw by draw)."""
    tris, looks = scene(rng)
    w, h = 128, 96
    g = GridBuilder().build(tris)
    looks_e = Looks(tris, engine_surface(looks), looks.normals, engine_lights(looks))
    params = RenderParams(width=w, height=h, shading="material", shadows=True, traversal=traversal, threads=threads,
                          light_samples=samples)
    with_maps, without = Renderer(), Renderer()
    without._lightmaps = NoLightMaps()
    cleared = []
    for k in range(5):
        cam = Camera(eye=(0.5 + 0.3 * k, 4.5, 5.5 - 0.2 * k), target=CAM.target, fov=CAM.fov)
        a = with_maps.render(g, tris, cam, params, looks=looks_e)
        img, hdr = a.image.copy(), a.hdr.copy()
        b = without.render(g, tris, cam, params, looks=looks_e)
        assert np.array_equal(img, b.image) and np.array_equal(hdr, b.hdr)
        cleared.append(with_maps.shadow_clear)
        assert without.shadow_clear == 0
        TWINS.wait()   # (on a cold cache the maps' kernel compiles in the background from the second frame)
    assert cleared[0] == 0 and min(cleared[2:]) > 0 and cleared[-1] > (0.2 if samples == 0 else 0.1) * w * h
    if samples == 0:
        ref = R.ref_material(tris, cam, w, h, looks, shadows=True, shadow_offset=1e-6 * _diag(tris))
        compare(a, ref, True)


def test_renders_with_light_maps_of_a_split_scene(rng):
    """Two grids (static and moving): the maps are the first grid's, the second grid still traces
    the segments marked for it, and the frames equal a renderer's without maps."""
    tris, looks = scene(rng)
    w, h = 128, 96
    stat, mov = np.arange(7), np.arange(7, len(tris))
    ts = tris[stat]   # (the same array every frame, as a pipeline keeps its static part)
    ga = build_grid(ts, GridParams(), origin=np.zeros(3))
    looks_e = Looks(tris, engine_surface(looks), looks.normals, engine_lights(looks))
    params = RenderParams(width=w, height=h, shading="material", shadows=True, threads=2)
    with_maps, without = Renderer(), Renderer()
    without._lightmaps = NoLightMaps()
    for k in range(3):
        moved = tris[mov] + np.float32([0.1 * k, 0.0, 0.0])
        gb = build_grid(moved, GridParams(), origin=np.zeros(3))
        second = (gb, moved, stat.astype(np.int32), mov.astype(np.int32))
        a = with_maps.render(ga, ts, CAM, params, second=second, looks=looks_e)
        img = a.image.copy()
        b = without.render(ga, ts, CAM, params, second=second, looks=looks_e)
        assert np.array_equal(img, b.image)
        TWINS.wait()
    assert with_maps.shadow_clear > 0


def test_light_maps_are_made_for_what_comes_back(rng):
    """A point light gets a map the second time the same triangles and light are seen, keeps it
    while they stay, loses it when the triangles change in place; a directional light, a light
    that moves every frame and a light on a triangle get none."""
    tris = _floor_and_clutter(rng)
    g = grid_arrays(GridBuilder().build(tris), tris)
    lights = np.array([[0.0, 0.1, 2.0, 0.3, 1, 1, 1, 0], [1.0, 0.0, 1.0, 0.0, 1, 1, 1, 0],
                       [0.0, 0.0, 2.0, 0.0, 1, 1, 1, 0], [0.0, *tris[0, 0], 1, 1, 1, 0]])
    maps = LightMaps()
    maps.for_lights(g, lights[:1], 6.0)
    maps.for_lights(g, lights[:1], 6.0)
    TWINS.wait()   # (build_light_map compiled, as on a warm cache)
    maps = LightMaps()
    made = []
    for k in range(4):
        lights[2, 1] = 0.1 * k   # moves
        made.append([m is not None for m in maps.for_lights(g, lights, 6.0)])
    assert made == [[False] * 4] + [[True, False, False, False]] * 3
    first = maps.for_lights(g, lights, 6.0)[0]
    assert maps.for_lights(g, lights, 6.0)[0] is first   # kept
    tris[5, 0, 1] += 0.5   # in place
    assert maps.for_lights(g, lights, 6.0)[0] is None
    assert maps.for_lights(g, lights, 6.0)[0] is not None


def test_a_light_map_without_memory_is_not_made(rng, monkeypatch):
    """Where a map's arrays cannot be allocated, the light goes on without one (no error), and no
    later frame tries again."""
    import gridrt.trace.lightmap as LM

    tris = _floor_and_clutter(rng)
    g = grid_arrays(GridBuilder().build(tris), tris)
    lights = np.array([[0.0, 0.1, 2.0, 0.3, 1, 1, 1, 0]])
    maps = LightMaps()
    maps.for_lights(g, lights, 6.0)
    TWINS.wait()
    tries = []

    class NoMemory(LightMap):
        def __init__(self, light, cl):
            tries.append(light)
            raise MemoryError

    monkeypatch.setattr(LM, "LightMap", NoMemory)
    assert maps.for_lights(g, lights, 6.0) == [None] and maps.for_lights(g, lights, 6.0) == [None]
    assert len(tries) == 1


def test_the_background_compile_takes_the_render_s_types(rng, monkeypatch):
    """The maps' background compile (_warm_build) calls build_light_map and clear_lit with the
    argument types a render with maps passes them, so that on a cold compile cache no frame
    compiles them in the render's thread (a new type would: numba compiles per type)."""
    import importlib

    import numba

    import gridrt.trace.lightmap as LM
    render_module = importlib.import_module("gridrt.trace.render")
    phase, seen = ["warm"], {"warm": {}, "render": {}}

    def spy(name, fn):
        def call(*args):
            seen[phase[0]].setdefault(name, set()).add(tuple(str(numba.typeof(a)) for a in args))
            return fn(*args)
        return call

    for name in ("build_light_map", "clear_lit"):
        monkeypatch.setattr(LM, name, spy(name, getattr(LM, name)))
    monkeypatch.setattr(render_module, "clear_lit", LM.clear_lit)
    LM._warm_build()
    phase[0] = "render"
    monkeypatch.setattr(LM, "_READY", [True])   # (the kernels taken as compiled: no background warm-up here)
    tris, looks = scene(rng)
    g = GridBuilder().build(tris)
    looks_e = Looks(tris, engine_surface(looks), looks.normals, engine_lights(looks))
    params = RenderParams(width=64, height=48, shading="material", shadows=True, threads=2)
    r = Renderer()
    for _ in range(4):
        r.render(g, tris, CAM, params, looks=looks_e)
    assert r.shadow_clear > 0   # (the maps were made and used)
    assert sorted(seen["render"]) == ["build_light_map", "clear_lit"]
    for name, types in seen["render"].items():
        assert types <= seen["warm"][name], name
