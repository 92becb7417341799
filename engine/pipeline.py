"""FramePipeline: the one place that chains scene -> grid -> render.  The viewer, the frame
dump and the benchmarks all call :meth:`FramePipeline.step`; there is no second renderer."""

import time
from dataclasses import dataclass

import numpy as np

from .camera import Camera
from .config import GridParams, RenderParams
from .grid.build import GridBuilder
from .threads import use_threads
from .trace.render import Renderer

#: columns every stats row has, in this order (the dump's stats.csv header starts with them)
STATS_COLUMNS = (
    "frame", "t", "triangles", "cells", "references", "threads", "strategy", "insert",
    "clear_ms", "insert_ms", "macro_ms", "build_ms", "render_ms", "frame_ms",
    "anim_ms", "bounds_ms", "rebuilt", "refs_per_tri", "dims", "macro_full", "grid_bytes",
    "width", "height", "shading", "traversal", "mrays", "hit_fraction", "tests_per_ray", "cells_per_ray",
)


@dataclass
class Frame:
    """One rendered frame: image (H,W,4) uint8, t (H,W) float32, tri (H,W) int32, stats dict."""

    image: np.ndarray
    t: np.ndarray
    tri: np.ndarray
    stats: dict
    grid: object = None


class FramePipeline:
    """Per frame: triangles_at(t) -> grid rebuild -> primary rays (+ shadows) -> image.

    scene          an engine.scene Animation (triangles_at(t) reuses one buffer)
    grid_params    GridParams (strategy, lambda, macro size, insertion test, threads)
    render_params  RenderParams (size, shading, shadows, intersection test, threads)
    camera         Camera, or None to frame the scene's bounds at the first frame
                   (with vertical field of view ``fov`` and up vector ``up``)
    follow_camera  use the scene's animated camera (``scene.camera_at(t)``) where it has one

    A static scene is gridded once and not rebuilt until the grid parameters change.  A scene
    whose ``static_mask`` marks some triangles as never moving is split (``split_static``): the
    static part gets its own grid, built once, the moving part is rebuilt every frame, and the ray
    caster traverses both; triangle ids in the output stay the scene's.
    """

    def __init__(self, scene, grid_params=None, render_params=None, camera=None, fov=45.0, up=(0.0, 1.0, 0.0),
                 split_static=True, follow_camera=False):
        self.scene = scene
        self.fov = fov
        self.up = up
        self.grid_params = grid_params or GridParams()
        self.render_params = render_params or RenderParams()
        self.camera = camera
        self.builder = GridBuilder(self.grid_params)
        self.renderer = Renderer()
        self.grid = None
        self._built_params = None
        self.frame_index = 0
        self.split_static = split_static
        self.follow_camera = follow_camera  # use the scene's own animated camera (BART, glTF)
        self.last_camera = None
        self._split = None  # (ids_static, ids_moving, static tris, moving tris buffer, static builder)
        self.static_grid = None
        self._static_params = None

    def _split_parts(self):
        """The static/moving split of the scene, or None when it does not apply."""
        mask = getattr(self.scene, "static_mask", None)
        if not self.split_static or mask is None or self.scene.static:
            return None
        mask = np.asarray(mask, bool)
        if mask.shape != (self.scene.n_triangles,) or mask.all() or not mask.any():
            return None
        if self._split is None:
            ids_s = np.flatnonzero(mask).astype(np.int32)
            ids_m = np.flatnonzero(~mask).astype(np.int32)
            self._split = (ids_s, ids_m, None, np.empty((len(ids_m), 3, 3), np.float32), GridBuilder())
        return self._split

    def _build(self, tris, gp):
        """(grid, second-grid tuple or None, rebuilt?, static_build_ms) for this frame."""
        parts = self._split_parts()
        if parts is None:
            rebuild = self.grid is None or not self.scene.static or self._built_params != gp
            if rebuild:
                self.grid = self.builder.build(tris, gp)
                self._built_params = gp
            return self.grid, None, rebuild, 0.0
        ids_s, ids_m, static_tris, moving, sbuilder = parts
        static_ms = 0.0
        if self.static_grid is None or self._static_params != gp:
            static_tris = np.ascontiguousarray(tris[ids_s])
            self._split = (ids_s, ids_m, static_tris, moving, sbuilder)
            self.static_grid = sbuilder.build(static_tris, gp)
            self._static_params = gp
            static_ms = self.static_grid.stats["build_ms"]
        np.take(tris, ids_m, axis=0, out=moving)
        self.grid = self.builder.build(moving, gp)
        self._built_params = gp
        second = (self.grid, moving, ids_s, ids_m)
        return self.static_grid, second, True, static_ms

    def step(self, t, camera=None):
        """Render the scene at time t; returns a Frame. ``camera`` overrides the pipeline's."""
        t_frame = time.perf_counter()
        t0 = time.perf_counter()
        # the animation's parallel kernels run at the rebuild's thread count, not at whatever count
        # the last kernel anywhere in the process left behind (another pipeline's render, say)
        use_threads(self.grid_params.threads)
        tris = self.scene.triangles_at(float(t))
        anim_ms = (time.perf_counter() - t0) * 1e3
        gp = self.grid_params
        grid, second, rebuild, static_ms = self._build(tris, gp)
        cam = None
        if self.follow_camera:
            cam = self.scene.camera_at(float(t))
        cam = cam or camera or self.camera
        if cam is None:
            lo, hi = grid.spec.scene_lo, grid.spec.scene_hi
            if second is not None:
                lo = np.minimum(lo, second[0].spec.scene_lo)
                hi = np.maximum(hi, second[0].spec.scene_hi)
            cam = self.camera = Camera.frame(lo, hi, fov=self.fov, up=self.up)
        if second is not None:
            res = self.renderer.render(self.static_grid, self._split[2], cam, self.render_params, second=second)
            grid = second[0]
        else:
            res = self.renderer.render(grid, tris, cam, self.render_params)
        self.last_camera = cam
        gs = grid.stats
        rp = self.render_params
        stats = {
            "frame": self.frame_index,
            "t": float(t),
            "triangles": self.scene.n_triangles,
            "cells": gs["cells"] + (self.static_grid.stats["cells"] if second is not None else 0),
            "references": gs["references"] + (self.static_grid.stats["references"] if second is not None else 0),
            "threads": gs["threads"],
            "strategy": gs["strategy"],
            "insert": gs["insert"],
            "clear_ms": gs["clear_ms"] if rebuild else 0.0,
            "insert_ms": gs["insert_ms"] if rebuild else 0.0,
            "macro_ms": gs["macro_ms"] if rebuild else 0.0,
            "build_ms": gs["build_ms"] if rebuild else 0.0,
            "render_ms": res.stats["render_ms"],
            "anim_ms": anim_ms,
            "bounds_ms": gs.get("bounds_ms", 0.0) if rebuild else 0.0,
            "rebuilt": int(rebuild),
            "refs_per_tri": gs["refs_per_tri"],
            "moving_triangles": gs["triangles"],
            "static_build_ms": static_ms,
            "dims": gs["dims"],
            "macro_full": gs["macro_full"],
            "grid_bytes": gs["grid_bytes"] + (self.static_grid.stats["grid_bytes"] if second is not None else 0),
            "width": rp.width,
            "height": rp.height,
            "shading": rp.shading,
            "traversal": rp.traversal,
            "fallback_rays": res.stats.get("fallback_rays", 0),
        }
        for k in ("mrays", "hit_fraction", "tests_per_ray", "cells_per_ray"):
            stats[k] = res.stats[k]
        for k, v in gs.items():  # strategy-specific stages (count_ms, bucket_ms, merge_ms, ...)
            if k.endswith("_ms") and k not in stats:
                stats[k] = v if rebuild else 0.0
        stats["frame_ms"] = (time.perf_counter() - t_frame) * 1e3
        self.frame_index += 1
        return Frame(res.image, res.t, res.tri, stats, grid)
