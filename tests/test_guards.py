"""Every numba kernel that could read or write out of bounds on bad data is guarded at the Python
boundary.

numba kernels do no bounds checks, so bad indices, shapes, dtypes, sizes or NaN coordinates must be
refused before a kernel runs.  This module

* enumerates every ``@njit`` / ``@intrinsic`` kernel in ``engine/`` from the source (AST), finds
  every place where Python code refers to one (the *boundaries*), and checks that each boundary is
  listed in :data:`BOUNDARIES` with the tests below that prove its guard (a new kernel call from
  Python fails :func:`test_kernel_inventory` until it is classified); kernels reached only from other
  kernels are covered by the boundary that reaches them;
* proves each guard with a tripwire: every entry kernel is replaced by a function that raises
  ``KernelCalled``, bad input must raise the engine's own error first, and the same call with good
  input must reach the tripwire (so the tripwire is really on the path);
* fuzzes real files of every supported format (OBJ, OFF, binary and ASCII PLY, binary and ASCII
  STL, GLB, glTF + .bin, BART .aff with includes, MD2, a folder of OBJ frames) with hypothesis:
  truncations, byte flips, spliced junk, numbers replaced by extreme values.  Each case is loaded in
  a worker process with a time limit, so a crash (segfault) or a hang is caught and reported as
  such; the outcome must be a scene with finite triangles that grids and casts, or a
  SceneFileError naming the file -- never another exception;
* keeps regression tests of the unguarded paths this work found (stale grids, unchecked gather
  indices, a builder corrupted by a refused build, a half-applied RayCaster update), run in a
  subprocess where the bug crashed the interpreter.

The full fuzz (300 examples per target, ``-m soak`` or GRIDRT_SOAK=1) prints its outcome counts;
the default run does 14 per target.
"""

import ast
import functools
import json
import os
import re
import select
import shutil
import subprocess
import sys
import tempfile
import textwrap
import time
import warnings
from importlib import import_module
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from conftest import ARMADILLO, TEAPOT, data_path
from gridrt.camera import Camera
from gridrt.config import GridParams, RenderParams
from gridrt.errors import InputError
from gridrt.grid import GridBuilder, build_grid, names
from gridrt.threads import max_threads
from helpers.memory import traced

REPO = Path(__file__).resolve().parents[1]
ENGINE = REPO / "engine"
STRATEGIES = names()
GOOD = np.array([[[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 0, 1], [1, 0, 1], [0, 1, 1]]], np.float32)


# ----------------------------------------------------------------------------------------------
# kernel inventory


def _decorator_name(dec):
    f = dec.func if isinstance(dec, ast.Call) else dec
    return f.attr if isinstance(f, ast.Attribute) else getattr(f, "id", None)


@functools.lru_cache(maxsize=1)
def kernel_inventory():
    """(kernels, references): kernels maps (module, name) -> set of kernel names it calls;
    references is the set of (module, python_qualname, kernel_name) where Python code (not a
    kernel) refers to a kernel by name -- the boundaries."""
    trees = {}
    for p in sorted(ENGINE.rglob("*.py")):
        mod = ".".join(("gridrt",) + p.relative_to(ENGINE).with_suffix("").parts)  # engine/ is the gridrt package
        trees[mod] = ast.parse(p.read_text())
    kernels = {}
    for mod, tree in trees.items():
        for node in ast.walk(tree):
            if isinstance(node, ast.FunctionDef) and any(_decorator_name(d) in ("njit", "jit", "inner", "intrinsic")
                                                          for d in node.decorator_list):
                kernels[(mod, node.name)] = node
    knames = {n for _, n in kernels}
    graph = {}
    for key, node in kernels.items():
        used = set()
        for x in ast.walk(node):
            n = x.id if isinstance(x, ast.Name) else (x.attr if isinstance(x, ast.Attribute) else None)
            if n in knames and n != key[1]:
                used.add(n)
        graph[key] = used
    refs = set()

    def visit(mod, node, stack):
        for ch in ast.iter_child_nodes(node):
            if isinstance(ch, ast.FunctionDef) and (mod, ch.name) in kernels:
                continue
            if isinstance(ch, (ast.FunctionDef, ast.ClassDef)):
                visit(mod, ch, stack + [ch.name])
                continue
            if stack and isinstance(ch, (ast.Name, ast.Attribute)):
                n = ch.id if isinstance(ch, ast.Name) else ch.attr
                if n in knames and isinstance(getattr(ch, "ctx", None), ast.Load):
                    refs.add((mod, ".".join(stack), n))
            visit(mod, ch, stack)

    for mod, tree in trees.items():
        visit(mod, tree, [])
    return graph, refs


#: Every Python function that refers to a kernel, with what its kernels index using caller data
#: and the tests below that prove the guard.  "internal" boundaries only pass arrays the engine made
#: and sized itself (covered by the guards of the public function that reaches them).
BOUNDARIES = {
    "gridrt.camera:Camera.rays": ("writes W*H rays into buffers it allocates; W, H validated",
                                  ["test_guard_camera_rays"]),
    "gridrt.grid.build:GridBuilder.build": (
        "bounds pass reads tris (shape/dtype checked first; it is itself the NaN/inf/1e30 guard)",
        ["test_guard_build_triangles", "test_guard_build_nonfinite_every_strategy", "test_guard_build_params"]),
    "gridrt.api:_in_centred_frame": (
        "RayCaster's mesh and updates: reached after _centred_mesh / _centred_vertices checked shapes, dtypes, "
        "values (the bounds pass) and face indices; to_frame and first_nondegenerate read and write arrays of "
        "those shapes", ["test_guard_raycaster", "test_raycaster_update_is_atomic"]),
    "gridrt.trace.all_hits:query_hits": (
        "RayCaster.all_hits / count_hits / contains: rays through check_rays and check_ray_values, t bounds of one "
        "a ray, not NaN, 0 <= t_min <= t_max, max_hits whole and >= 1, before any kernel; the grid and triangles "
        "are the caster's snapshot; a ray's hits go into a scratch of FIRST_CAP (a fuller ray is counted again with "
        "room for every triangle); all_hits writes at most SLOT_HITS hits a ray into (N, SLOT_HITS) slots, and a "
        "ray with more is walked again with a scratch and slots of its own count", ["test_guard_all_hits"]),
    "gridrt.trace.all_hits:_all_hits": (
        "internal: reached only from query_hits after its checks; slots sized (block, SLOT_HITS) or (rays, their "
        "largest count) before slot_kernel writes at most that many hits a row, and a ray whose first walk "
        "overflowed its scratch is walked again with a scratch of its own count (test_all_hits shrinks both sizes)",
        ["test_guard_all_hits"]),
    "gridrt.trace.all_hits:_recount": (
        "internal: reached only from query_hits after its checks; the rays whose count overflowed the first "
        "scratch counted again with room for every triangle", ["test_guard_all_hits"]),
    "gridrt.instances:RayScene._reaching": (
        "RayScene's queries: rays through check_rays and check_ray_values (and no zero direction), t bounds of "
        "one a ray, not NaN, 0 <= t_min <= t_max, before the box test; its output made here of the rays' length",
        ["test_guard_ray_scene"]),
    "gridrt.grid.common:point_bounds": (
        "the one-pass bounds kernels on a C-contiguous float32/float64 array its callers made (shape checked "
        "first); the pass is itself the NaN/inf/1e30 guard", ["test_guard_build_triangles", "test_guard_raycaster"]),
    "gridrt.grid.build:build_grid": (
        "shape/dtype checked first, contiguous float32 or float64 made, values through point_bounds (messages "
        "from the slow checks when it finds one); to_frame and first_nondegenerate write/read arrays of the "
        "checked shape",
        ["test_guard_build_triangles", "test_guard_build_nonfinite_every_strategy"]),
    "gridrt.grid.two_level:build_leaves": (
        "internal: the leaf level of a two-level grid over a top level just built from checked triangles; "
        "leaf cells and then leaf references checked against int32 and max_bytes before the arrays they size "
        "are allocated and written; leaf ranges clamped to each top cell's resolution",
        ["test_guard_two_level_budget_before_allocation"]),
    "gridrt.grid.build:GridBuilder._build": (
        "internal: clear and macro stages index count/macro arrays sized from the spec; reached only after the "
        "triangles, params and memory budget passed; buffers reset when a build fails",
        ["test_guard_build_nonfinite_every_strategy", "test_refused_build_leaves_builder_usable",
         "test_guard_memory_budget_before_allocation"]),
    "gridrt.grid.strategies.serial:Serial.insert": (
        "internal: cell ranges clamped to dims in the range pass (common._ranges_block); tri_ids sized by the "
        "counted total, which must fit int32; assumes the count buffer is zero", ["test_guard_reference_overflow_tripwire",
                                                        "test_guard_reference_overflow_real",
                                                        "test_refused_build_leaves_builder_usable"]),
    "gridrt.grid.strategies.counting:Counting.insert": ("internal, as serial",
                                                        ["test_guard_reference_overflow_tripwire"]),
    "gridrt.grid.strategies.shared:ranges": ("internal: rng scratch sized (F, 6)",
                                             ["test_guard_reference_overflow_tripwire"]),
    "gridrt.grid.strategies.shared:_scan": ("internal: guards the int32 total (check_total)",
                                            ["test_guard_reference_overflow_tripwire"]),
    "gridrt.grid.strategies.sort_first:SortFirst.insert": ("internal, as serial",
                                                           ["test_guard_reference_overflow_tripwire"]),
    "gridrt.grid.strategies.sort_last_locks:_SortLastLocked.insert": (
        "internal: lock arrays sized by the lock granularity", ["test_guard_reference_overflow_tripwire"]),
    "gridrt.grid.strategies.sort_middle:SortMiddle.insert": (
        "internal: (T, F) bucket lists checked against max_bytes; the z % T table sized dims[2]",
        ["test_guard_reference_overflow_tripwire", "test_guard_memory_budget_before_allocation"]),
    "gridrt.grid.traffic:stream_bandwidth": ("mib, runs and thread counts checked; streams buffers it allocates",
                                             ["test_guard_stream_bandwidth"]),
    "gridrt.grid.strategies.thread_grids:_insert_layers": ("internal, as serial, one layer per thread",
                                                           ["test_guard_reference_overflow_tripwire"]),
    "gridrt.grid.strategies.thread_grids:ThreadGridsMerge.insert": (
        "internal: merged grid sized by the layers' total", ["test_guard_reference_overflow_tripwire"]),
    "gridrt.trace.render:cast_batch": (
        "odd_directions reads the chunk's float64 directions (N, 3), after every check below",
        ["test_guard_cast_rays", "test_guard_cast_batch"]),
    "gridrt.trace.batch:cast_grouped": (
        "called by cast_batch only, after its checks (the rows it sorts are indices it computes itself); cast_batch: "
        "walks grid cell lists and reads tris[tri_ids[r]]: tris must be the grid's own float32 array (cast_rays "
        "checks it, RayCaster holds it); rays shape/dtype, t range, threads and the memory budget, then every "
        "chunk's values (finite, non-zero directions), all before the first chunk is cast",
        ["test_guard_cast_rays", "test_stale_grid_is_refused", "test_guard_cast_batch"]),
    "gridrt.trace.batch:cast_runs": (
        "internal: called by cast_grouped only, after cast_batch's checks, with the rows it ordered or sorted "
        "itself and out's (N,) arrays; the work items' counter made there, one thread a work item at most",
        ["test_guard_cast_rays", "test_stale_grid_is_refused", "test_guard_cast_batch"]),
    "gridrt.trace.batch:stream_runs": (
        "internal: called by cast_grouped only, after cast_batch's checks, with the rows it ordered itself (or "
        "none: every ray) and out's (N,) arrays, as cast_runs",
        ["test_guard_cast_rays", "test_stale_grid_is_refused", "test_guard_cast_batch"]),
    "gridrt.trace.batch:image_width": (
        "internal: called by cast_grouped only, after cast_batch's checks (rays (N, 3) float64); _steps reads rows "
        "0..K-1 of the rays into a buffer of K - 1 it allocates, K <= N",
        ["test_guard_cast_rays", "test_guard_cast_batch"]),
    "gridrt.trace.batch:pass1_order": (
        "internal: as image_width; tile_order writes each of the N rays' indices once into the (N,) buffer it "
        "allocates (a width and first column from image_width, checked there)",
        ["test_guard_cast_rays", "test_guard_cast_batch"]),
    "gridrt.trace.cgt.frame:cgt_render.work": (
        "internal: one thread's share of cgt_render, Renderer.render's CGT path, called after its checks, with its "
        "buffers and a checked thread count; the runs' counter and each thread's scratch made there",
        ["test_guard_render", "test_stale_grid_is_refused"]),
    "gridrt.trace.material:shade.work": (
        "internal: one thread's share of the material pass, called by Renderer._shade_material after its checks, "
        "with the buffers it sized W x H and a checked thread count; the rows' counter made there",
        ["test_guard_render_material"]),
    "gridrt.trace.render:dda_render.work": (
        "internal: one thread's share of dda_render, Renderer.render's DDA path, called after its checks (as "
        "cast_rays, plus the second grid's tris and id maps) with image buffers sized W x H and a checked thread "
        "count; the runs' counter made there",
        ["test_guard_render", "test_stale_grid_is_refused"]),
    "gridrt.trace.render:Renderer._shade_material": (
        "the material pass: called by Renderer.render after _check_looks (the scene's triangles (F, 3, 3) "
        "float32 and finite, F the grids' triangles; a Surface of F triangles, validated and frozen when made: "
        "material and texture indices in range, texels, uv/colour/normal shapes; normals (F, 3, 3) float32 "
        "finite; lights (L, 8) finite, known kinds, unit directions); buffers sized W x H",
        ["test_guard_render_material"]),
    "gridrt.trace.render:Renderer._shade_material.blocked_of": (
        "internal: the material pass's casts of segments s0 .. s0 + m of a ShadowSegments it made (m at most "
        "its rows); live_segments and mark_blocked read and write rows 0..m-1 of the segments' marks, the "
        "blocked flags (W * H) and a live list of m they are given, the casts' out of W * H rows",
        ["test_guard_render_material", "test_guard_light_samples"]),
    "gridrt.trace.render:Renderer._shade_material.leave_clear": (
        "internal: as blocked_of; clear_lit reads segments s0 .. s0 + m, their pixels (rows the segment kernels "
        "wrote, each below W * H) in the HitPoints of W * H, and a light map LightMaps made (cells clamped into "
        "its RES x RES faces, its triangle indices those of the grid's tris it was made from)",
        ["test_guard_render_material", "test_guard_light_samples"]),
    "gridrt.trace.lightmap:LightMap.build": (
        "internal: called by LightMaps.for_lights and _warm_build with the tris the clusters were found for "
        "(one cluster number each, below the clusters' count); build_light_map writes the map's arrays, "
        "allocated here, every cell index clamped into [0, RES)",
        ["test_guard_render_material"]),
    "gridrt.trace.lightmap:_compiled": (
        "internal: whether build_light_map and clear_lit are compiled (their cache entries), else their compile "
        "started through _warm_build; no data", ["test_guard_render_material"]),
    "gridrt.trace.lightmap:_warm_build": (
        "internal: its own data only: a map over one triangle of its own, and clear_lit on an empty batch (no "
        "segment: no index read)", ["test_guard_render_material"]),
    "gridrt.trace.render:Renderer.light_guide": (
        "internal: called by _shade_material only, where lights are drawn (RenderParams.light_samples 1..8, "
        "checked when made), with the frame's W and H and the lights _check_looks validated; the probes are "
        "the squares' centres clamped into the W x H image, and the draws' rows and segments are sized for "
        "every probe and light",
        ["test_guard_render_material", "test_guard_light_samples"]),
    "gridrt.trace.render:Renderer.shadow_buffers": (
        "internal: called by _shade_material only, with the frame's W and H (RenderParams, checked there); "
        "tile_order writes each of the W * H pixels' indices once into the (W * H,) buffer it allocates",
        ["test_guard_render_material"]),
    "gridrt.scene.animation:gather_unchecked": (
        "reads vertices[faces] unchecked: reached from gather_triangles after its shape, dtype and index checks, "
        "and from the loaders' per-frame paths whose faces were validated at load time",
        ["test_guard_gather_shapes", "test_gather_triangles_checks_indices", "test_guard_keyframes",
         "test_fuzz_real_files"]),
    "gridrt.scene.deform:Deform.vertices_at": ("rest and out (V,3): out validated",
                                               ["test_guard_scene_buffers"]),
    "gridrt.scene.marbles:Marbles._fill": ("internal arrays sized at construction; out validated by triangles_at",
                                           ["test_guard_scene_buffers"]),
    "gridrt.scene.kernels:lerp_rows": ("internal: KeyframeMesh frames validated (K, V, 3) at construction",
                                       ["test_guard_keyframes", "test_fuzz_real_files"]),
    "gridrt.scene.kernels:deform_vertices": ("internal: glTF indices (joints, nodes, morph rows) validated by the "
                                             "loader", ["test_fuzz_real_files"]),
    "gridrt.scene.gltf:GltfAnimation._update_world": ("internal: channel/node tables validated by the loader",
                                                      ["test_fuzz_real_files"]),
    "gridrt.scene.gltf:GltfAnimation._pose": ("internal: joint tables validated by the loader",
                                              ["test_fuzz_real_files"]),
    "gridrt.scene.gltf:GltfAnimation.bind_triangles": ("internal: node tables validated by the loader",
                                                       ["test_fuzz_real_files"]),
    "gridrt.scene.bart:_static_matrix": ("4x4 output it allocates", ["test_fuzz_real_files"]),
    "gridrt.scene.bart:BartAnimation._update_world": ("internal: spline/node tables validated by the parser",
                                                      ["test_fuzz_real_files"]),
    "gridrt.scene.bart:BartAnimation.spline_value": ("internal: spline index from the parser's tables",
                                                     ["test_fuzz_real_files"]),
    "gridrt.scene.bart:BartAnimation.transform_at": ("internal, by transform name (KeyError checked)",
                                                     ["test_fuzz_real_files"]),
    "gridrt.scene.bart:BartAnimation.camera_at": ("internal: camera keys from the parser", ["test_fuzz_real_files"]),
    "gridrt.warmup:_kernels": ("no call: inspects the kernels' compile cache files", []),
    "gridrt.grid.build:_parallel_ready": ("no call: inspects the kernels' compiled signatures and cache index", []),
    "gridrt.grid.build:_parallel_ready.job": (
        "internal: the parallel bounds pass over a copy of at most WARM_TRIANGLES of triangles the build already "
        "checked, into a (threads, 7) array it makes", ["test_guard_build_triangles"]),
    "gridrt.grid.strategies.sort_first:SortFirst": ("no call: names its parallel kernels", []),
}


def test_kernel_inventory():
    """Every Python reference to a kernel is a classified boundary whose guard tests exist here."""
    graph, refs = kernel_inventory()
    boundaries = {}
    for mod, fn, k in refs:
        boundaries.setdefault(f"{mod}:{fn}", set()).add(k)
    entry = {k for _, _, k in refs}
    inner = sorted(f"{m}.{n}" for (m, n) in graph if n not in entry)
    print(f"FIGURE kernels: {len(graph)} @njit/@inner/@intrinsic kernels in engine/, {len(entry)} referenced from "
          f"{len(boundaries)} Python functions (the boundaries), {len(inner)} reached only from other kernels")
    for b, ks in sorted(boundaries.items()):
        print(f"  {b}: {', '.join(sorted(ks))} -- {BOUNDARIES.get(b, ('UNCLASSIFIED',))[0]}")
    unclassified = sorted(set(boundaries) - set(BOUNDARIES))
    assert not unclassified, f"Python functions call kernels without a classified guard: {unclassified}"
    stale = sorted(set(BOUNDARIES) - set(boundaries))
    assert not stale, f"BOUNDARIES lists functions that no longer call a kernel: {stale}"
    here = sys.modules[__name__]
    for b, (_, tests) in BOUNDARIES.items():
        for t in tests:
            assert callable(getattr(here, t, None)), f"{b}: guard test {t} does not exist"
    assert len(graph) > 60 and len(entry) > 20


# ----------------------------------------------------------------------------------------------
# tripwires


class KernelCalled(AssertionError):
    pass


def entry_kernels():
    """Names of kernels referenced from Python and not called by any kernel (patching a kernel
    that other kernels call could break their compilation while the patch is active)."""
    graph, refs = kernel_inventory()
    called_by_kernels = set().union(*graph.values())
    return sorted({k for _, _, k in refs} - called_by_kernels)


def install_tripwires(mp, allow=()):
    """Replace every entry kernel, in every loaded engine module that binds it, with a tripwire,
    once the background compiles an earlier test started have ended (gridrt.trace.twin: a warm-up
    that ran into a tripwire would be remembered as failed for the rest of the process)."""
    import gridrt.scene  # noqa: F401  (load every module that binds a kernel)
    import gridrt.grid.strategies  # noqa: F401
    import gridrt.trace.render  # noqa: F401
    import gridrt.grid.traffic  # noqa: F401
    from gridrt.trace.twin import TWINS

    TWINS.wait()

    patched = []
    for name in entry_kernels():
        if name in allow:
            continue
        for modname, mod in list(sys.modules.items()):
            if not (modname == "gridrt" or modname.startswith("gridrt.")) or modname.startswith("gridrt.app") \
                    or mod is None:
                continue
            obj = getattr(mod, name, None)
            if obj is not None and hasattr(obj, "py_func"):

                def trip(*a, _n=name, **k):
                    raise KernelCalled(f"kernel {_n} ran before the bad input was rejected")

                mp.setattr(mod, name, trip)
                patched.append(f"{modname}.{name}")
    assert patched
    return patched


@pytest.fixture
def tripwires(monkeypatch):
    return install_tripwires(monkeypatch)


def expect_guard(call, match):
    with pytest.raises(InputError, match=match):
        call()


def test_tripwires_cover_the_boundaries():
    """Positive controls: with good input every guarded boundary reaches a tripwire."""
    from gridrt.scene import Mesh, gather_triangles, make_scene
    from gridrt.scene.deform import Deform
    from gridrt.scene.frames import KeyframeMesh
    from gridrt.trace import cast_rays, render

    grid = build_grid(GOOD)
    v = GOOD.reshape(-1, 3)
    f = np.arange(6).reshape(2, 3).astype(np.int32)
    deform = Deform(Mesh(v + np.float32([0, 0, 0]), f), "wave")
    marbles = make_scene("marbles", count=400)
    keys = KeyframeMesh(np.stack([v, v + 1]), f, fps=10)
    with pytest.MonkeyPatch.context() as mp:
        patched = install_tripwires(mp)
        print(f"FIGURE tripwires: {len(patched)} kernel bindings replaced")
        calls = [
            lambda: build_grid(GOOD),
            lambda: GridBuilder().build(GOOD),
            lambda: cast_rays(grid, GOOD, [[0.2, 0.2, 2]], [[0, 0, -1]]),
            lambda: render(grid, GOOD, Camera(), RenderParams(width=4, height=4)),
            lambda: render(grid, GOOD, Camera(), RenderParams(width=4, height=4, shading="material")),
            lambda: render(grid, GOOD, Camera(), RenderParams(width=4, height=4, traversal="cgt")),
            lambda: Camera().rays(4, 4),
            lambda: gather_triangles(v, f, np.empty((2, 3, 3), np.float32)),
            lambda: deform.triangles_at(0.3),
            lambda: marbles.triangles_at(0.3),
            lambda: keys.triangles_at(0.05),
        ]
        for c in calls:
            with pytest.raises(KernelCalled):
                c()


def _with(flat_index, value, dtype):
    t = GOOD.astype(dtype)
    t.reshape(-1)[flat_index] = value
    return t


BAD_TRIS = {
    "2d": (np.zeros((2, 3), np.float32), r"shape \(F, 3, 3\)"),
    "4 vertices": (np.zeros((2, 4, 3), np.float32), r"shape \(F, 3, 3\)"),
    "2 coords": (np.zeros((2, 3, 2), np.float32), r"shape \(F, 3, 3\)"),
    "empty": (np.zeros((0, 3, 3), np.float32), "empty"),
    "object": (np.array([[[None] * 3] * 3], dtype=object), "numeric"),
    "string": (np.full((1, 3, 3), "1"), "numeric"),
    "complex": (GOOD.astype(np.complex64), "numeric"),
    "bool": (GOOD.astype(bool), "numeric"),
    "nan": (_with(7, np.nan, np.float32), "NaN"),
    "+inf": (_with(16, np.inf, np.float32), "NaN.* infinity"),
    "-inf float64": (_with(2, -np.inf, np.float64), "NaN.* infinity"),
    "1e31": (_with(4, 1e31, np.float32), "1e30"),
    "-1e38 float64": (_with(4, -1e38, np.float64), "1e30"),
    "1e300 float64": (_with(4, 1e300, np.float64), "1e30"),
}


@pytest.mark.parametrize("case", sorted(BAD_TRIS))
def test_guard_build_triangles(case):
    """Bad triangle arrays are refused by build_grid and by the per-frame GridBuilder before any
    kernel runs (wrong shapes and dtypes), or before any kernel but a bounds pass (bad values: the
    pass only reads the array within its checked shape, and is the NaN / inf / 1e30 check;
    build_grid's runs in float32 or float64, GridBuilder's on float32 frames)."""
    tris, match = BAD_TRIS[case]
    values = case in ("nan", "+inf", "1e31", "-inf float64", "-1e38 float64", "1e300 float64")
    with pytest.MonkeyPatch.context() as mp:
        install_tripwires(mp, allow=("scene_bounds_serial", "bounds_f64") if values else ())
        expect_guard(lambda: build_grid(tris), match)
    with pytest.MonkeyPatch.context() as mp:
        install_tripwires(mp)
        if case not in ("nan", "+inf", "1e31"):  # float32 frames with bad values reach the bounds pass
            expect_guard(lambda: GridBuilder().build(tris), match)
    with pytest.MonkeyPatch.context() as mp:
        install_tripwires(mp, allow=("scene_bounds", "scene_bounds_serial"))
        expect_guard(lambda: GridBuilder().build(tris), match)


@pytest.mark.parametrize("strategy", STRATEGIES)
def test_guard_build_nonfinite_every_strategy(monkeypatch, strategy):
    """float32 frames with NaN / inf / |x| > 1e30 given straight to GridBuilder.build (the
    animation path, no as_triangles): the bounds pass counts them and the build stops before the
    clear, insert or macro stage of every strategy; a degenerate-only frame is fine."""
    install_tripwires(monkeypatch, allow=("scene_bounds", "scene_bounds_serial"))
    b = GridBuilder(GridParams(strategy=strategy, threads=3))
    big = np.tile(GOOD, (40000, 1, 1))  # > 65536 triangles: the parallel bounds pass
    for tris in (GOOD, big):
        for pos, val in ((0, np.nan), (-1, np.inf), (len(tris) // 2, -1e31)):
            t = tris.copy()
            t[pos, 1, 2] = val
            with pytest.raises(InputError, match=f"first at triangle {pos % len(tris)}, vertex 1, axis 2"):
                b.build(t)
    with pytest.raises(KernelCalled):  # positive control: a good frame goes on to the stages
        b.build(np.ones((3, 3, 3), np.float32))


def test_guard_build_params(tripwires):
    """Thread counts, strategies and sizes are validated before a kernel sees them (kernels size
    per-thread arrays by the thread count and index cells by the spec)."""
    hi = max_threads()
    for th in (0, -1, hi + 1, 2.5, "2", True):
        expect_guard(lambda: GridParams(threads=th), "thread count")
    for kw, match in ((dict(macro=0), "macro"), (dict(macro=65), "macro"), (dict(density=float("nan")), "density"),
                      (dict(max_cells=0), "max_cells"), (dict(max_cells=1 << 40), "max_cells"),
                      (dict(max_bytes=0), "max_bytes"), (dict(max_bytes="1G"), "max_bytes"),
                      (dict(strategy="fast"), "strategy"), (dict(insert="sat"), "insert")):
        expect_guard(lambda: GridParams(**kw), match)


#: strategy -> (module, count kernel, [kernels that run after the total is known])
COUNT_STAGE = {
    "serial": ("gridrt.grid.strategies.serial", "count_serial", ["scatter_serial"]),
    "counting": ("gridrt.grid.strategies.counting", "count_atomic", ["scatter_ranked"]),
    "global_lock": ("gridrt.grid.strategies.sort_last_locks", "count_locked", ["scatter_locked"]),
    "cell_locks": ("gridrt.grid.strategies.sort_last_locks", "count_locked", ["scatter_locked"]),
    "lock_pool": ("gridrt.grid.strategies.sort_last_locks", "count_locked", ["scatter_locked"]),
    "sort_first": ("gridrt.grid.strategies.sort_first", "count_slabs", ["scan_scatter_slabs"]),
    "sort_middle": ("gridrt.grid.strategies.sort_middle", "count_owned", ["scatter_owned"]),
    "thread_grids": ("gridrt.grid.strategies.thread_grids", "count_layers", ["scan_scatter_layers"]),
    "thread_grids_merge": ("gridrt.grid.strategies.thread_grids", "count_layers",
                           ["scan_scatter_layers", "merge_counts", "merge_copy"]),
}


def test_count_stage_table_is_complete():
    assert sorted(COUNT_STAGE) == sorted(STRATEGIES)


@pytest.mark.parametrize("strategy", STRATEGIES)
def test_guard_reference_overflow_tripwire(monkeypatch, strategy):
    """The CSR offsets are int32: when the counted references exceed 2**31 - 1 the build must stop
    with a clear InputError before any scatter kernel writes through the offsets.  The count
    kernel is replaced by one that reports 2**31 - 1 + 2 * 7 references (two cells of 2**30 + ...);
    the real prefix sums then run and the scatter kernels are tripwires."""
    modname, count_name, later = COUNT_STAGE[strategy]
    mod = import_module(modname)
    for k in later:
        monkeypatch.setattr(mod, k, lambda *a, _k=k, **kw: (_ for _ in ()).throw(KernelCalled(f"{_k} ran")))
    calls = []

    def fake_count(*args):
        count = args[-2] if count_name in ("count_slabs", "count_layers") else args[-1]
        if count_name in ("count_locked", "count_atomic"):  # count_atomic(..., count, ranks)
            count = args[-2]
        flat = count.reshape(-1)
        flat[0] = (1 << 30) + 7
        flat[-1] = (1 << 30) + 7
        if count_name in ("count_slabs", "count_layers"):  # per-thread totals
            tot = args[-1]
            tot[:] = 0
            tot[0] = 2 * ((1 << 30) + 7)
        calls.append(count_name)

    monkeypatch.setattr(mod, count_name, fake_count)
    with pytest.raises(InputError, match="int32"):
        build_grid(GOOD, GridParams(strategy=strategy, threads=2, density=64.0))
    assert calls, "the fake count kernel was not on the path"


@pytest.mark.parametrize("strategy", ["serial", "thread_grids"])
def test_guard_reference_overflow_real(strategy):
    """For real: 1100 triangles spanning the scene box in 2**21 cells would need 2.3e9 references;
    the build stops with the int32 message after counting, without allocating the references."""
    import warnings

    from gridrt.grid import GridCapWarning

    rng = np.random.default_rng(1)
    F = 1100
    u = rng.uniform(0, 1, (F, 3))
    tris = np.stack([np.stack([np.zeros(F), u[:, 0], np.ones(F)], 1), np.stack([np.ones(F), np.zeros(F), u[:, 1]], 1),
                     np.stack([u[:, 2], np.ones(F), np.zeros(F)], 1)], axis=1).astype(np.float32)
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", GridCapWarning)
        with pytest.raises(InputError, match=r"would hold 2306867200 references, more than int32"):
            build_grid(tris, GridParams(strategy=strategy, threads=2, density=1e9, max_cells=1 << 21))
    print(f"FIGURE int32 overflow ({strategy}): refused after {time.perf_counter() - t0:.1f} s of counting")


@pytest.fixture(scope="module")
def good_grid():
    return build_grid(GOOD)


def spanning_triangles(n, seed=1):
    """n triangles whose bounding boxes are the whole unit cube: each is in every cell."""
    u = np.random.default_rng(seed).uniform(0, 1, (n, 3))
    return np.stack([np.stack([np.zeros(n), u[:, 0], np.ones(n)], 1),
                     np.stack([np.ones(n), np.zeros(n), u[:, 1]], 1),
                     np.stack([u[:, 2], np.ones(n), np.zeros(n)], 1)], axis=1).astype(np.float32)


@pytest.mark.parametrize("strategy", STRATEGIES)
def test_guard_memory_budget_before_allocation(monkeypatch, strategy):
    """GridParams.max_bytes is enforced before the memory is committed: the cell arrays of all
    layers before any build stage runs, the references after the count pass and before any kernel
    writes them (the scatter kernels are tripwires; the count and scan run for real)."""
    from gridrt.grid import GridCapWarning

    tris = spanning_triangles(60)
    warnings.filterwarnings("ignore", category=GridCapWarning)  # undone by pytest's per-test warnings capture
    with pytest.MonkeyPatch.context() as mp:
        install_tripwires(mp, allow=("scene_bounds", "scene_bounds_serial"))
        # about 2^20 cells x 8 B = 8 MiB per layer (thread_grids: 16 layers) against 4 MiB
        with pytest.raises(InputError, match="max_bytes"):
            GridBuilder(GridParams(strategy=strategy, threads=16, density=1e12, max_cells=1 << 20,
                                   max_bytes=4 << 20)).build(tris)
    modname, count_name, later = COUNT_STAGE[strategy]
    mod = import_module(modname)
    for k in later:
        monkeypatch.setattr(mod, k, lambda *a, _k=k, **kw: (_ for _ in ()).throw(KernelCalled(f"{_k} ran")))
    with pytest.raises(InputError, match="max_bytes"):  # 60 x 64000 references x 4 B = 14.6 MiB
        build_grid(tris, GridParams(strategy=strategy, threads=2, density=1e12, max_cells=1 << 16, max_bytes=8 << 20))


def test_guard_two_level_budget_before_allocation(monkeypatch):
    """A two-level grid's leaf level is held to max_bytes before it is written: too many leaf
    cells stop the build before the count pass (both leaf passes are tripwires), too many leaf
    references before the scatter pass (the count pass runs for real); the builder then builds
    the next frame correctly."""
    from gridrt.grid import two_level

    tris = spanning_triangles(60)  # each triangle in every top cell and, at a high leaf density, every leaf
    builder = GridBuilder()
    for k in ("leaf_count", "leaf_scatter"):
        monkeypatch.setattr(two_level, k, lambda *a, _k=k, **kw: (_ for _ in ()).throw(KernelCalled(f"{_k} ran")))
    # 60 refs per top cell x about 60,000 leaf cells each x 8 B, far above 4 MiB
    with pytest.raises(InputError, match=r"leaf cells\), above the memory budget max_bytes"):
        builder.build(tris, GridParams(grid="two_level", leaf_density=1e3, top_density=1.0, max_bytes=4 << 20))
    monkeypatch.undo()
    for k in ("leaf_scatter",):
        monkeypatch.setattr(two_level, k, lambda *a, _k=k, **kw: (_ for _ in ()).throw(KernelCalled(f"{_k} ran")))
    # few leaf cells (60 top cells x about 60), but every triangle in each: x 60 x 4 B = about 0.8 MiB > 0.5 MiB
    with pytest.raises(InputError, match=r"leaf references\), above the memory budget max_bytes"):
        builder.build(tris, GridParams(grid="two_level", leaf_density=1.0, top_density=1.0, max_bytes=1 << 19))
    monkeypatch.undo()
    g = builder.build(tris, GridParams(grid="two_level", leaf_density=1.0, top_density=1.0))
    # every triangle's bounding box is the whole scene: each is in every leaf cell
    assert g.references == g.n_leaf * len(tris)


@pytest.mark.parametrize("kw,match", [(dict(mib=0), "mib"), (dict(mib=1.5), "mib"), (dict(mib=1, runs=0), "runs"),
                                      (dict(mib=1, threads=(0,)), "thread"), (dict(mib=1, threads=(10**6,)), "thread")])
def test_guard_stream_bandwidth(tripwires, kw, match):
    from gridrt.grid.traffic import stream_bandwidth

    with pytest.raises(InputError, match=match):
        stream_bandwidth(**kw)


def test_guard_cast_rays(good_grid, tripwires):
    """Rays, t range, threads and the triangle array are checked before cast_grouped."""
    from gridrt.trace import cast_rays

    grid = good_grid
    o, d = np.array([[0.2, 0.2, 2.0]]), np.array([[0.0, 0.0, -1.0]])
    bad_rays = [
        (np.ones((5, 3)), np.ones((4, 3)), "differ in shape"),
        (np.ones((5, 2)), np.ones((5, 2)), r"shape \(N, 3\)"),
        (np.ones(3), np.ones(3), r"shape \(N, 3\)"),
        (np.ones((1, 3), complex), d, "real numbers"),
        (np.array([["a", "b", "c"]]), d, "real numbers"),
        (np.array([[None, 1, 2]], dtype=object), d, "real numbers"),
        (np.array([[np.nan, 0, 0]]), d, "origins contain NaN"),
        (o, np.array([[0, 0, -np.inf]]), "directions contain NaN"),
        (o, np.array([[0.0, -0.0, 0.0]]), "zero vector"),
    ]
    for oo, dd, match in bad_rays:
        expect_guard(lambda: cast_rays(grid, GOOD, oo, dd), match)
    for tmin, tmax in ((-1.0, 1.0), (2.0, 1.0), (np.nan, 1.0), (0.0, np.nan)):
        expect_guard(lambda: cast_rays(grid, GOOD, o, d, tmin=tmin, tmax=tmax), "tmin")
    expect_guard(lambda: cast_rays(grid, GOOD, o, d, threads=max_threads() + 1), "thread count")
    for tris, match in ((GOOD[:1], "built over 2 triangles but 1"), (np.concatenate([GOOD] * 2), "but 4"),
                        (GOOD.astype(complex), "array the grid was built from"),
                        (np.where(np.arange(18).reshape(2, 3, 3) == 4, np.nan, GOOD.astype(np.float64)), "NaN"),
                        (GOOD.reshape(2, 9), "array the grid was built from"),
                        ([GOOD[0].tolist(), [[0.0, 0.0]] * 3], "array the grid was built from")):  # ragged list
        expect_guard(lambda: cast_rays(grid, tris, o, d), match)


@pytest.fixture(scope="module")
def good_caster():
    from gridrt.api import RayCaster

    return RayCaster(GOOD.reshape(-1, 3), np.arange(6).reshape(2, 3))


def test_guard_cast_batch(good_grid, good_caster, tripwires, monkeypatch):
    """The chunked caster behind cast_rays and RayCaster.cast checks every chunk's rays before it
    casts the first one (a bad ray in the last chunk reaches no kernel), refuses a batch beyond
    its memory budget before allocating, and checks its own arguments."""
    render_mod = import_module("gridrt.trace.render")  # (gridrt.trace.render is also a function's name)
    grid, caster = good_grid, good_caster
    monkeypatch.setattr(render_mod, "CAST_CHUNK", 4)
    o = np.tile([[0.2, 0.2, 2.0]], (50, 1))
    d = np.tile([[0.0, 0.0, -1.0]], (50, 1))
    for col, value, which, match in ((0, np.nan, "o", r"origins contain NaN or infinity \(first at index \(47, 0\)"),
                                     (2, -np.inf, "d", r"directions contain NaN or infinity \(first at index \(47, 2"),
                                     (None, 0.0, "d", "ray direction 47 is the zero vector")):
        oo, dd = o.copy(), d.copy()
        target = oo if which == "o" else dd
        if col is None:
            target[47] = value
        else:
            target[47, col] = value
        for cast in (lambda: render_mod.cast_rays(grid, GOOD, oo, dd), lambda: caster.cast(oo, dd),
                     lambda: render_mod.cast_batch(grid, GOOD, oo, dd, chunk=4)):
            expect_guard(cast, match)
    huge = 10**12
    ob, db = np.broadcast_to(o[:1], (huge, 3)), np.broadcast_to(d[:1], (huge, 3))  # costs no memory
    with traced() as m:
        for cast in (lambda: render_mod.cast_rays(grid, GOOD, ob, db), lambda: caster.cast(ob, db)):
            expect_guard(cast, f"casting {huge} rays at once needs .* above the memory budget")
    assert m.peak < 1 << 20, f"a refused batch allocated {m.peak} bytes"
    expect_guard(lambda: render_mod.cast_rays(grid, GOOD, o, d, max_bytes=28 * 50 - 1), "memory budget")
    expect_guard(lambda: render_mod.cast_rays(grid, GOOD, o, d, max_bytes=0), "max_bytes")
    for kw, match in ((dict(chunk=0), "chunk"), (dict(origin=[0, np.nan, 0]), "origin"),
                      (dict(origin=[1, 2]), "origin")):
        expect_guard(lambda: render_mod.cast_batch(grid, GOOD, o, d, **kw), match)
    for tris in (GOOD.astype(np.float64), GOOD[:1], np.asfortranarray(GOOD)):
        expect_guard(lambda: render_mod.cast_batch(grid, tris, o, d), "own C-contiguous")
    far = np.array([[1.79e308, 0, 0]])
    expect_guard(lambda: render_mod.cast_batch(grid, GOOD, far, d[:1], origin=[-1e307, 0, 0]),
                 "beyond float64 range")


def test_guard_render(good_grid, tripwires):
    """render / Renderer.render check the triangles of both grids and the id maps before either
    render kernel (DDA or CGT); the camera and parameters validate themselves."""
    from gridrt.trace import Renderer, render

    grid = good_grid
    cam = Camera()
    for trav in ("dda", "cgt"):
        p = RenderParams(width=4, height=4, traversal=trav)
        expect_guard(lambda: render(grid, GOOD[:1], cam, p), "built over 2 triangles")
        expect_guard(lambda: render(grid, GOOD.astype(complex), cam, p), "array the grid was built from")
        expect_guard(lambda: render(grid, np.full((2, 3, 3), np.inf), cam, p), "NaN or infinity")
        r = Renderer()
        expect_guard(lambda: r.render(grid, GOOD, cam, p, second=(grid, GOOD[:1], [0, 1], [0, 1])), "built over")
        expect_guard(lambda: r.render(grid, GOOD, cam, p, second=(grid, GOOD, [0], [0, 1])), "id maps")
        expect_guard(lambda: r.render(grid, GOOD, cam, p, second=(grid, GOOD, [0, 1], np.zeros((2, 2)))), "id maps")
    for kw, match in ((dict(width=0), "width"), (dict(height=16385), "height"), (dict(tile=0), "tile"),
                      (dict(tile=257), "tile"), (dict(threads=0), "thread"), (dict(traversal="bvh"), "traversal"),
                      (dict(light=(0, np.inf, 0)), "light")):
        expect_guard(lambda: RenderParams(**kw), match)
    for kw in (dict(eye=(np.nan, 0, 0)), dict(fov=0.0), dict(eye=(0, 0, 0), target=(0, 0, 0)), dict(up=(0, 0, 0))):
        expect_guard(lambda: Camera(**kw), "camera")


def test_guard_render_material(good_grid, tripwires):
    """The material mode checks the scene's looks before the shading kernels; a Surface refuses bad
    tables when it is made."""
    from gridrt.scene.surface import Surface, Texture
    from gridrt.trace.render import Looks, Renderer

    cam = Camera()
    r = Renderer()
    p = RenderParams(width=4, height=4, shading="material")
    surf = Surface(np.zeros(2, np.int32), [[1, 1, 1]], [[0, 0, 0]], [-1])
    for looks, match in ((Looks(GOOD[:1], surf), "looks.tris"), (Looks(GOOD.astype(np.float64), surf), "looks.tris"),
                         (Looks(np.full((2, 3, 3), np.nan, np.float32), surf), "NaN"),
                         (Looks(GOOD, surf.subset([0])), "looks.surface"),
                         (Looks(GOOD, surf, np.zeros((2, 3, 2), np.float32)), "looks.normals"),
                         (Looks(GOOD, surf, np.full((2, 3, 3), np.inf, np.float32)), "NaN"),
                         (Looks(GOOD, surf, None, np.full((1, 8), np.nan)), "NaN"),
                         (Looks(GOOD, surf, None, np.array([[7.0, 0, 0, 0, 1, 1, 1, 0]])), "kind"),
                         (Looks(GOOD, surf, None, np.array([[1.0, 0, 0, 0, 1, 1, 1, 0]])), "unit vector")):
        expect_guard(lambda: r.render(good_grid, GOOD, cam, p, looks=looks), match)
    for kw, match in ((dict(material=[0, 5]), "material index"), (dict(texture=[2]), "texture index"),
                      (dict(material=[[0, 0]]), "material must be"), (dict(diffuse=[[1, 1]]), "diffuse"),
                      (dict(diffuse=[[np.nan, 1, 1]]), "finite"), (dict(uv=np.zeros((3, 3, 2))), "uv")):
        args = dict(material=[0, 0], diffuse=[[1, 1, 1]], ambient=[[0, 0, 0]], texture=[-1]) | kw
        expect_guard(lambda: Surface(**args), match)
    expect_guard(lambda: Texture(np.zeros((2, 2), np.float32)), "uint8")
    expect_guard(lambda: Texture(np.zeros((2, 2, 3), np.uint8), ("repeat", "wrap")), "wrap")


def test_guard_light_samples(good_grid, tripwires):
    """Lights drawn per pixel: the count and the seed are checked when the RenderParams is made,
    and the looks before the draws' kernels, as without them."""
    from gridrt.trace.render import Looks, Renderer

    for kw, match in ((dict(light_samples=9), "light samples"), (dict(light_samples=-1), "light samples"),
                      (dict(light_samples=float("inf")), "light samples"), (dict(light_seed=-3), "light seed")):
        expect_guard(lambda: RenderParams(width=4, height=4, shading="material", shadows=True, **kw), match)
    p = RenderParams(width=4, height=4, shading="material", shadows=True, light_samples=2)
    lights = np.array([[0.0, 0, 0, 5, 1, 1, 1, 0], [0.0, 1, 0, np.nan, 1, 1, 1, 0]])
    expect_guard(lambda: Renderer().render(good_grid, GOOD, Camera(), p, looks=Looks(GOOD, None, None, lights)), "NaN")


def test_guard_camera_rays(tripwires):
    cam = Camera()
    for w, h, match in ((0, 4, "width"), (4, -1, "height"), (16385, 4, "width"), (2.5, 4, "width"), ("8", 4, "width")):
        expect_guard(lambda: cam.rays(w, h), match)


def test_guard_gather_shapes(tripwires):
    """gather_triangles checks shapes and dtypes of vertices, faces and out before the kernel."""
    from gridrt.scene import gather_triangles

    v = GOOD.reshape(-1, 3)
    f = np.arange(6).reshape(2, 3).astype(np.int32)
    out = np.empty((2, 3, 3), np.float32)
    for args, match in (((v.astype(np.float64), f, out), "vertices"), ((v[:, :2], f, out), "vertices"),
                        ((v, f.astype(np.int64), out), "faces"), ((v, f[:, :2], out), "faces"),
                        ((v, f, out[:1]), "out"), ((v, f, out.astype(np.float64)), "out")):
        expect_guard(lambda: gather_triangles(*args), match)


def test_guard_scene_buffers(tripwires):
    """Animations refuse a bad time or output buffer before their kernels run."""
    from gridrt.scene import Mesh, make_scene
    from gridrt.scene.deform import Deform

    v = GOOD.reshape(-1, 3)
    f = np.arange(6).reshape(2, 3)
    scenes = [Deform(Mesh(v, f), "wave"), Deform(Mesh(v + [0, 0, 0], f), "twist"), make_scene("marbles", count=400)]
    for s in scenes:
        F = s.n_triangles
        for out, match in ((np.empty((F + 1, 3, 3), np.float32), "shape"), (np.empty((F, 3, 3)), "float32"),
                           (np.empty((F, 3, 6), np.float32)[:, :, ::2], "C-contiguous"), ([0] * F, "numpy array")):
            expect_guard(lambda: s.triangles_at(0.1, out=out), match)
        ro = np.empty((F, 3, 3), np.float32)
        ro.setflags(write=False)
        expect_guard(lambda: s.triangles_at(0.1, out=ro), "writeable")
        for t in (np.nan, np.inf, "0.1", None, True):
            expect_guard(lambda: s.triangles_at(t), "time")
    d = scenes[0]
    for out in (np.empty((5, 3), np.float32), np.empty((6, 3)), np.empty((6, 3), np.float32).T.copy().T):
        expect_guard(lambda: d.vertices_at(0.1, out=out), "out")
    for count in (0, -5, 2.5, "100", 10**9):
        with pytest.raises(InputError):
            make_scene("marbles", count=count)


def test_guard_keyframes(tripwires):
    """KeyframeMesh refuses frames that its lerp and gather kernels would misread."""
    from gridrt.scene.frames import KeyframeMesh

    v = GOOD.reshape(-1, 3)
    f = np.arange(6).reshape(2, 3)
    for frames, faces, match in (
        (np.zeros((2, 6, 2)), f, "shape"),
        (np.zeros((0, 6, 3)), f, "shape"),
        (np.stack([v, np.where(v == 1, np.nan, v)]), f, "NaN"),
        (np.stack([v, v * 1e31]), f, "1e30"),
        (np.stack([v, v]), f + 1, "out of range"),
        (np.stack([v, v]), -f, "negative"),
        (np.stack([v, v]).astype(complex), f, "real"),
    ):
        expect_guard(lambda: KeyframeMesh(frames, faces, fps=10), match)


def test_guard_raycaster():
    """RayCaster validates its mesh (indices, NaN, sizes) and the shape of updates."""
    from gridrt.api import RayCaster

    v = GOOD.reshape(-1, 3)
    f = np.arange(6).reshape(2, 3)
    for vv, ff, match in ((v, f + 1, "out of range"), (v, -f, "negative"), (np.where(v == 1, np.nan, v), f, "NaN"),
                          (v[:, :2], f, "shape"), (v, f[:, :2], "shape"), (v, f + 0.5, "integers")):
        expect_guard(lambda: RayCaster(vv, ff), match)
    c = RayCaster(v, f)
    expect_guard(lambda: c.update(v[:-1]), "shape")
    expect_guard(lambda: c.update(np.where(v == 1, np.inf, v)), "NaN")


@pytest.fixture
def all_hits_caster():
    """A RayCaster over two triangles, built before the tripwires go in (a test asks for it first)."""
    from gridrt.api import RayCaster

    return RayCaster(GOOD.reshape(-1, 3), np.arange(6).reshape(2, 3))


def test_guard_all_hits(all_hits_caster, tripwires):
    """all_hits, count_hits and contains refuse bad rays, t bounds and caps before any kernel runs."""
    c = all_hits_caster
    o, d = np.zeros((2, 3)), np.ones((2, 3))
    for kw, match in (({"t_min": 1.0, "t_max": 0.5}, "t_min"), ({"t_min": np.nan}, "t_min"),
                      ({"t_max": np.ones(3)}, "one number a ray"), ({"max_hits": 0}, "max_hits")):
        expect_guard(lambda: c.all_hits(o, d, **kw), match)
    expect_guard(lambda: c.count_hits(np.array([[0.0, np.nan, 0.0]]), np.ones((1, 3))), "NaN")
    expect_guard(lambda: c.count_hits(o, np.zeros((2, 3))), "zero")
    expect_guard(lambda: c.all_hits(o[:, :2], d), "shape")
    expect_guard(lambda: c.contains(np.array([[0.0, 0.0, 0.0]])), "closed mesh")
    expect_guard(lambda: c.contains(np.full((1, 3), np.inf), best_effort=True), "NaN|inf")
    with pytest.raises(KernelCalled):   # positive control: good rays reach the kernels
        c.count_hits(o, d)


@pytest.fixture
def ray_scene():
    """A RayScene placing the two triangles twice, built before the tripwires go in."""
    from gridrt.instances import RayScene

    s = RayScene()
    m = s.add_mesh(GOOD.reshape(-1, 3), np.arange(6).reshape(2, 3))
    s.add_instance(m)
    s.add_instance(m, np.diag([2.0, 2.0, 2.0, 1.0]))
    return s


def test_guard_ray_scene(ray_scene, tripwires):
    """RayScene's cast, all_hits, count_hits and contains refuse bad rays and t bounds before its box
    test or any caster's kernel runs."""
    s = ray_scene
    o, d = np.zeros((2, 3)), np.ones((2, 3))
    for kw, match in (({"t_min": 1.0, "t_max": 0.5}, "t_min"), ({"t_min": np.nan}, "t_min"),
                      ({"t_min": -1.0}, "t_min")):
        expect_guard(lambda: s.cast(o, d, **kw), match)
        expect_guard(lambda: s.all_hits(o, d, **kw), match)
    expect_guard(lambda: s.cast(o, d, t_max=np.ones(2)), "numbers")
    expect_guard(lambda: s.count_hits(o, d, t_max=np.ones(3)), "one number a ray")
    expect_guard(lambda: s.count_hits(np.array([[0.0, np.nan, 0.0]]), np.ones((1, 3))), "NaN")
    expect_guard(lambda: s.cast(o, np.zeros((2, 3))), "zero")
    expect_guard(lambda: s.all_hits(o[:, :2], d), "shape")
    expect_guard(lambda: s.contains(np.full((1, 3), np.inf)), "NaN|inf")
    with pytest.raises(KernelCalled):   # positive control: good rays reach the kernels
        s.cast(o, d)


def test_raycaster_update_is_atomic():
    """An update refused with InputError leaves the caster as it was (same hits as before);
    regression test of a half-applied update (since fixed)."""
    from gridrt.api import RayCaster

    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1], [0, 1, 1]], np.float64)
    c = RayCaster(v, np.array([[0, 1, 2], [3, 4, 5]]))
    o, d = np.array([[0.2, 0.2, 2.0]]), np.array([[0.0, 0.0, -1.0]])
    before = c.cast(o, d)
    bad = v.copy()
    bad[3:, 2] = 1e39  # finite float64, beyond float32
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        with pytest.raises(InputError):
            c.update(bad)
    after = c.cast(o, d)
    assert after.tri[0] == before.tri[0] == 1 and after.t[0] == before.t[0]
    with pytest.raises(InputError):
        c.update(np.full(v.shape, "x"))


# ----------------------------------------------------------------------------------------------
# unguarded paths that can crash: checked in a subprocess


def run_python(code, timeout=240):
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(REPO), str(REPO / "tests"), env.get("PYTHONPATH", "")])
    return subprocess.run([sys.executable, "-c", textwrap.dedent(code)], cwd=REPO, env=env, capture_output=True,
                          text=True, timeout=timeout)


def test_gather_triangles_checks_indices():
    """The public gather_triangles refuses face indices outside [0, V) (regression test:
    this segfaulted)."""
    r = run_python("""
        import numpy as np, engine
        from gridrt.errors import InputError
        from gridrt.scene import gather_triangles
        v = np.zeros((3, 3), np.float32)
        out = np.empty((1, 3, 3), np.float32)
        for bad in ([[0, 1, 50_000_000]], [[0, -7, 1]]):
            try:
                gather_triangles(v, np.array(bad, np.int32), out)
                print("NO ERROR", bad)
            except InputError as e:
                print("InputError", e)
    """)
    print(f"FIGURE gather_triangles with a bad index: exit code {r.returncode}; {r.stdout.strip()!r}")
    assert r.returncode == 0 and r.stdout.count("InputError") == 2, (r.returncode, r.stdout, r.stderr[-500:])


def test_stale_grid_is_refused():
    """A grid whose builder has built another grid since must be refused (or still be correct)
    by cast_rays and render, never read the new cell lists (regression test:
    this returned triangle ids out of bounds)."""
    r = run_python("""
        import numpy as np, engine
        from gridrt.camera import Camera
        from gridrt.config import RenderParams
        from gridrt.errors import InputError
        from gridrt.grid import GridBuilder, GridParams
        from gridrt.trace import cast_rays, render
        rng = np.random.default_rng(0)
        A = rng.random((10, 3, 3)).astype(np.float32)
        B = (rng.random((3000, 1, 3)) + rng.normal(0, 0.01, (3000, 3, 3))).astype(np.float32)
        b = GridBuilder()
        ga = b.build(A, GridParams(density=3000.0))
        o = rng.random((20000, 3)); d = rng.normal(size=(20000, 3))
        before = cast_rays(ga, A, o, d)
        b.build(B, GridParams(density=2.0))
        for what, call in (("cast", lambda: cast_rays(ga, A, o, d)),
                           ("render", lambda: render(ga, A, Camera(eye=(0.5, 0.5, 3), target=(0.5, 0.5, 0.5)),
                                                     RenderParams(width=32, height=32, traversal="dda")).tri)):
            try:
                res = call()
            except InputError as e:
                print(what, "refused:", e)
                continue
            tri = res.tri if what == "cast" else res
            ok = (tri.max() < len(A)) and (what != "cast" or np.array_equal(res.tri, before.tri))
            print(what, "OK" if ok else f"WRONG: max tri id {tri.max()} for {len(A)} triangles")
    """)
    print(f"FIGURE stale grid: exit code {r.returncode}; {r.stdout.strip()!r}")
    assert r.returncode == 0 and "WRONG" not in r.stdout and r.stdout.count("\n") == 2, (r.returncode, r.stdout,
                                                                                        r.stderr[-500:])


def test_refused_build_leaves_builder_usable():
    """After GridBuilder.build refuses a frame (too many references for int32 offsets), the next
    build on the same builder equals a fresh build (serial and thread_grids; regression test:
    this left corrupt grids and a segfault)."""
    r = run_python("""
        import warnings, numpy as np, engine
        from gridrt.errors import InputError
        from gridrt.grid import GridBuilder, GridCapWarning, GridParams, build_grid
        warnings.simplefilter("ignore", GridCapWarning)
        rng = np.random.default_rng(1)
        F = 1100
        u = rng.uniform(0, 1, (F, 3))
        huge = np.stack([np.stack([np.zeros(F), u[:, 0], np.ones(F)], 1), np.stack([np.ones(F), np.zeros(F), u[:, 1]], 1),
                         np.stack([u[:, 2], np.ones(F), np.zeros(F)], 1)], axis=1).astype(np.float32)
        small = (rng.random((2000, 1, 3)) + rng.normal(0, 0.02, (2000, 3, 3))).astype(np.float32)
        for s in ("serial", "thread_grids"):
            p = GridParams(strategy=s, threads=2, density=4.0)
            b = GridBuilder()
            b.build(small, p)
            try:
                b.build(huge, GridParams(strategy=s, threads=2, density=1e9, max_cells=1 << 21))
                print(s, "NOT REFUSED")
            except InputError:
                pass
            g = b.build(small, p)
            f = build_grid(small, p)
            ok = g.references == f.references and np.array_equal(g.pairs(), f.pairs())
            print(s, "OK" if ok else f"CORRUPT: {g.references} references, fresh build {f.references}", flush=True)
    """)
    print(f"FIGURE refused build: exit code {r.returncode}; {r.stdout.strip()!r}")
    assert r.returncode == 0 and r.stdout.count("OK") == 2, (r.returncode, r.stdout, r.stderr[-800:])


# ----------------------------------------------------------------------------------------------
# malformed files: hypothesis mutations of real files, each loaded in a worker with a time limit


WORKER = r"""
import json, sys, traceback, warnings
import numpy as np
import gridrt
from gridrt.errors import SceneFileError
from gridrt.grid import GridBuilder, GridParams
from gridrt.scene import make_scene
from gridrt.trace import cast_rays

def load(path):
    s = make_scene(path)
    tris = s.triangles_at(0.37)
    if tris.ndim != 3 or tris.shape[1:] != (3, 3) or len(tris) == 0:
        return {"outcome": "bad_array", "shape": list(tris.shape)}
    if not np.isfinite(tris).all() or np.abs(tris).max() > 1e30:
        return {"outcome": "nonfinite"}
    g = GridBuilder(GridParams(density=2.0)).build(tris)
    lo, hi = g.spec.lo, g.spec.hi
    rng = np.random.default_rng(0)
    o = lo - (hi - lo) + rng.random((256, 3)) * 3 * (hi - lo)
    d = lo + rng.random((256, 3)) * (hi - lo) - o
    h = cast_rays(g, tris, o, d)
    if not ((h.tri >= -1) & (h.tri < len(tris))).all():
        return {"outcome": "bad_hits"}
    return {"outcome": "ok", "triangles": int(len(tris)), "hits": int((h.tri >= 0).sum())}

for line in sys.stdin:
    req = json.loads(line)
    if req.get("crash"):  # the harness's self-test: a real segfault
        import ctypes
        ctypes.string_at(0)
    if req.get("hang"):  # the harness's self-test: a real block (reading a FIFO nobody writes)
        open(req["path"]).read()
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        try:
            res = load(req["path"])
        except SceneFileError as e:
            res = {"outcome": "scene_error", "path": e.path, "message": str(e)[:300], "problem": bool(e.problem)}
        except BaseException as e:
            res = {"outcome": "foreign", "type": type(e).__module__ + "." + type(e).__qualname__,
                   "message": str(e)[:300], "traceback": traceback.format_exc()[-1500:]}
    res["warnings"] = sorted({f"{x.category.__name__}: {str(x.message)[:80]}" for x in w})[:3]
    sys.stdout.write(json.dumps(res) + "\n")
    sys.stdout.flush()
"""

#: seconds one file may take in the worker (load, one frame, grid, 256 rays) before it counts as a hang
CASE_TIMEOUT = 30.0


class LoaderWorker:
    """A Python process that loads scene files on request; a case that crashes it or runs past
    its time limit is reported as ``crash`` / ``timeout`` and the worker is restarted."""

    def __init__(self):
        self.proc = None
        self.log = tempfile.TemporaryFile(mode="w+")
        self.restarts = 0

    def start(self):
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join([str(REPO), env.get("PYTHONPATH", "")])
        self.proc = subprocess.Popen([sys.executable, "-c", WORKER], cwd=REPO, env=env, stdin=subprocess.PIPE,
                                     stdout=subprocess.PIPE, stderr=self.log, text=True, bufsize=1)

    def stop(self):
        if self.proc is not None:
            if self.proc.poll() is None:
                self.proc.kill()  # the worker this object started, by its own handle
            self.proc.wait()
            self.proc = None

    def load(self, path, timeout=CASE_TIMEOUT, **extra):
        if self.proc is None or self.proc.poll() is not None:
            self.stop()
            self.start()
            self.restarts += 1
        t0 = time.perf_counter()
        self.proc.stdin.write(json.dumps({"path": str(path), **extra}) + "\n")
        self.proc.stdin.flush()
        ready, _, _ = select.select([self.proc.stdout], [], [], timeout)
        if not ready:
            self.stop()
            return {"outcome": "timeout", "seconds": timeout}
        line = self.proc.stdout.readline()
        if not line:
            rc = self.proc.wait()
            self.proc = None
            self.log.seek(0)
            tail = self.log.read()[-800:]
            return {"outcome": "crash", "returncode": rc, "stderr": tail}
        res = json.loads(line)
        res["seconds"] = time.perf_counter() - t0
        return res


def make_seeds(tmp):
    """(target name -> (path to load, file to mutate), target name -> why it is missing).  Real
    files (the repository's assets/ first, then the development data set: conftest.data_path),
    copied; STL and ASCII PLY are written from the real teapot by trimesh's exporters (the data
    set has no such file).  Without the data set (a user's clone) the binary PLY is the shipped
    armadillo.ply instead of Lucy and the OFF is armadillo.ply written by trimesh's OFF exporter;
    a target whose source is absent is missing (its test skips with the reason)."""
    import trimesh

    out, missing = {}, {}

    def have(rel, converted=False):
        try:
            return data_path(rel, converted)
        except pytest.skip.Exception as e:
            missing[rel] = str(e)
            return None

    def copy(src, name=None):
        dst = tmp / (name or src.name)
        shutil.copyfile(src, dst)
        return dst

    def exported(mesh, name, **kw):
        data = mesh.export(**kw)
        (tmp / name).write_bytes(data if isinstance(data, bytes) else data.encode())
        return tmp / name

    def need(names, *rels):
        why = [missing[r] for r in rels if r in missing]
        for name in names:
            if why:
                missing[name] = why[0]
        return not why

    teapot = have(TEAPOT)
    if need(["obj", "ply-ascii", "stl-binary", "stl-ascii", "frames"], TEAPOT):
        obj = copy(teapot)
        out["obj"] = (obj, obj)  # (path to load, file to mutate)
    armadillo = have(ARMADILLO, converted=True)
    if need(["off"], ARMADILLO):
        off = copy(armadillo) if armadillo.suffix == ".off" else exported(
            trimesh.load(armadillo, force="mesh", process=False), "armadillo.off", file_type="off")
        out["off"] = (off, off)
    lucy = have("static/lucy/Lucy100k.ply")
    ply = lucy if lucy is not None else armadillo if armadillo is not None and armadillo.suffix == ".ply" else None
    if ply is not None:
        ply = copy(ply)
        out["ply-binary"] = (ply, ply)
    else:
        need(["ply-binary"], "static/lucy/Lucy100k.ply")
    if "obj" in out:
        mesh = trimesh.load(out["obj"][0], force="mesh", process=False)
        for key, name, kw in (("ply-ascii", "teapot_ascii.ply", dict(file_type="ply", encoding="ascii")),
                              ("stl-binary", "teapot.stl", dict(file_type="stl")),
                              ("stl-ascii", "teapot_ascii.stl", dict(file_type="stl_ascii"))):
            p = exported(mesh, name, **kw)
            out[key] = (p, p)
    glb = have("animated/cesium_man/CesiumMan.glb")
    if need(["glb"], "animated/cesium_man/CesiumMan.glb"):
        glb = copy(glb)
        out["glb"] = (glb, glb)
    morph = "animated/animated_morph_sphere/AnimatedMorphSphere"
    gltf, gbin = have(morph + ".gltf"), have(morph + ".bin")
    if need(["gltf-json", "gltf-bin"], morph + ".gltf", morph + ".bin"):
        gdir = tmp / "morph"
        gdir.mkdir()
        out["gltf-json"] = (gdir / gltf.name,) * 2
        out["gltf-bin"] = (gdir / gltf.name, gdir / gbin.name)
        for q in (gltf, gbin):
            shutil.copyfile(q, gdir / q.name)
    museum = have("animated/bart/museum/aff")
    if need(["aff-root", "aff-include", "aff-mesh"], "animated/bart/museum/aff"):
        adir = tmp / "museum"
        shutil.copytree(museum, adir)
        for q in adir.iterdir():
            q.chmod(0o644)
        out["aff-root"] = (adir / "museum5.aff", adir / "museum5.aff")
        out["aff-include"] = (adir / "museum5.aff", adir / "camera.aff")
        out["aff-mesh"] = (adir / "museum5.aff", adir / "room.aff")
    md2 = have("animated/md2_sydney/sydney.md2")
    if need(["md2"], "animated/md2_sydney/sydney.md2"):
        md2 = copy(md2)
        out["md2"] = (md2, md2)
    if "obj" in out:
        fdir = tmp / "frames"
        fdir.mkdir()
        for k in range(3):
            shutil.copyfile(out["obj"][0], fdir / f"f{k:03d}.obj")
        out["frames"] = (fdir, fdir / "f001.obj")
    return out, missing


TARGETS = ["obj", "off", "ply-binary", "ply-ascii", "stl-binary", "stl-ascii", "glb", "gltf-json", "gltf-bin",
           "aff-root", "aff-include", "aff-mesh", "md2", "frames"]
EXTREME_NUMBERS = [b"1e300", b"-1e300", b"1e39", b"nan", b"inf", b"-1", b"0", b"-0", b"1e-320", b"999999999",
                   b"4294967296", b"2147483648", b"0x10", b"", b"3.", b"-"]
EXTREME_WORDS = [b"\xff\xff\xff\xff", b"\xff\xff\xff\x7f", b"\x00\x00\x00\x80", b"\x00\x00\xc0\x7f",
                 b"\x00\x00\x80\x7f", b"\x00\x00\x00\x00", b"\x01\x00\x00\x00", b"\xca\xf2\x49\xf1"]
NUM = re.compile(rb"-?\d+(\.\d*)?([eE][-+]?\d+)?")
_SPANS = {}


def number_spans(path, raw):
    if path not in _SPANS:
        _SPANS[path] = [(m.start(), m.end()) for m in NUM.finditer(raw[:4_000_000])]
    return _SPANS[path]


@st.composite
def mutation(draw, raw, spans, text):
    """A mutated copy of ``raw`` (bytes) and a short description."""
    kinds = ["truncate", "flip", "splice", "word"] + (["number"] * 3 if spans and text else []) + \
            (["header-word"] * 2 if not text else [])
    kind = draw(st.sampled_from(kinds), label="kind")
    n = len(raw)
    if kind == "truncate":
        cut = draw(st.integers(0, n - 1), label="cut")
        return raw[:cut], f"truncate at {cut}"
    if kind == "flip":
        buf = bytearray(raw)
        where = []
        for _ in range(draw(st.integers(1, 8), label="flips")):
            i = draw(st.integers(0, n - 1), label="at")
            buf[i] = draw(st.integers(0, 255), label="byte")
            where.append(i)
        return bytes(buf), f"flip bytes at {where}"
    if kind == "splice":
        i = draw(st.integers(0, n), label="at")
        junk = draw(st.binary(max_size=16) | st.sampled_from(EXTREME_NUMBERS + [b"}", b"{", b"\n", b'"', b"[", b"null"]),
                    label="junk")
        return raw[:i] + junk + raw[i:], f"insert {junk!r} at {i}"
    if kind in ("word", "header-word"):
        hi = min(n, 4096) if kind == "header-word" else n
        i = draw(st.integers(0, max(0, hi - 4)), label="at") & ~3
        w = draw(st.sampled_from(EXTREME_WORDS), label="word")
        return raw[:i] + w + raw[i + 4:], f"word {w!r} at {i}"
    j = draw(st.integers(0, len(spans) - 1), label="token")
    a, b = spans[j]
    v = draw(st.sampled_from(EXTREME_NUMBERS), label="value")
    return raw[:a] + v + raw[b:], f"number {raw[a:b]!r} at {a} -> {v!r}"


@pytest.fixture(scope="module")
def fuzz_env(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("realfuzz")
    seeds, missing = make_seeds(tmp)
    worker = LoaderWorker()
    try:
        for name, (path, target) in seeds.items():  # the unmutated files load (and warm the worker's compile cache)
            res = worker.load(path, timeout=300)
            assert res["outcome"] == "ok", (name, res)
        yield seeds, worker, {}, missing
    finally:
        worker.stop()


ALLOWED_OUTCOMES = ("ok", "scene_error")


def check_case(seeds, worker, stats, name, raw_new, what):
    path, target = seeds[name]
    original = target.read_bytes()
    try:
        target.write_bytes(raw_new)
        res = worker.load(path)
    finally:
        target.write_bytes(original)
    st_ = stats.setdefault(name, {})
    st_[res["outcome"]] = st_.get(res["outcome"], 0) + 1
    if res.get("warnings"):  # e.g. numpy RuntimeWarnings while loading: reported, not an error
        st_["warned"] = st_.get("warned", 0) + 1
        st_.setdefault("warning", res["warnings"][0])
    st_["max_s"] = max(st_.get("max_s", 0.0), res.get("seconds", CASE_TIMEOUT))
    assert res["outcome"] in ALLOWED_OUTCOMES, f"{name}: {what}: {res}"
    if res["outcome"] == "scene_error":
        allowed = {str(path), str(target)}
        if name.startswith(("aff", "gltf", "frames")):  # an include, the .bin, another frame
            allowed |= {str(q) for q in target.parent.iterdir()} | {str(target.parent)}
        assert res["path"] in allowed, f"{name}: {what}: the error names {res['path']}, not the file"
        assert res["message"].startswith(res["path"]) and res["problem"], res


def _fuzz(seeds, worker, stats, name, data):
    path, target = seeds[name]
    raw = target.read_bytes()
    text = name not in ("ply-binary", "stl-binary", "glb", "gltf-bin", "md2")
    new, what = data.draw(mutation(raw, number_spans(target, raw), text), label="mutation")
    check_case(seeds, worker, stats, name, new, what)


FUZZ_DEFAULT = settings(max_examples=14, deadline=None, derandomize=True, database=None,
                        suppress_health_check=list(HealthCheck))
FUZZ_SOAK = settings(max_examples=int(os.environ.get("GRIDRT_FUZZ_EXAMPLES", "300")), deadline=None,
                     derandomize=True, database=None, suppress_health_check=list(HealthCheck))


@pytest.mark.parametrize("name", TARGETS)
def test_fuzz_real_files(fuzz_env, name):
    """Mutated and truncated real files of every format: a scene with finite triangles that
    grids and casts, or a SceneFileError naming the file; never another exception, a crash or a
    case longer than CASE_TIMEOUT (the worker enforces it)."""
    seeds, worker, stats, missing = fuzz_env
    if name not in seeds:
        pytest.skip(missing[name])

    @FUZZ_DEFAULT
    @given(data=st.data())
    def run(data):
        _fuzz(seeds, worker, stats, name, data)

    run()
    print(f"FIGURE fuzz {name}: {stats.get(name)}")


@pytest.mark.soak
@pytest.mark.parametrize("name", TARGETS)
def test_fuzz_real_files_soak(fuzz_env, name):
    seeds, worker, stats, missing = fuzz_env
    if name not in seeds:
        pytest.skip(missing[name])

    @FUZZ_SOAK
    @given(data=st.data())
    def run(data):
        _fuzz(seeds, worker, stats, name, data)

    run()
    print(f"FIGURE fuzz soak {name}: {stats.get(name)}")


def test_worker_reports_crashes_and_hangs(tmp_path):
    """The fuzz harness itself: a case that kills the worker (a real segfault) is a 'crash', one
    that blocks past its limit (reading a FIFO nobody writes: the loaders refuse one, so the worker
    reads it itself) a 'timeout', and the next case runs in a fresh worker."""
    w = LoaderWorker()
    try:
        missing = tmp_path / "missing.obj"
        res = w.load(missing, timeout=300)
        assert res["outcome"] == "scene_error" and res["path"] == str(missing)
        res = w.load(missing, crash=True)
        assert res["outcome"] == "crash" and res["returncode"] == -11, res
        assert w.load(missing, timeout=300)["outcome"] == "scene_error" and w.restarts == 2
        fifo = tmp_path / "hang.obj"
        os.mkfifo(fifo)
        t0 = time.perf_counter()
        res = w.load(fifo, timeout=3.0, hang=True)
        assert res["outcome"] == "timeout" and w.proc is None and time.perf_counter() - t0 < 60
        assert w.load(missing, timeout=300)["outcome"] == "scene_error" and w.restarts == 3
    finally:
        w.stop()
