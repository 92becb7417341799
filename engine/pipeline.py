"""FramePipeline: the one place that chains scene -> grid -> render.  The viewer, the frame
dump and the benchmarks all call :meth:`FramePipeline.step`; there is no second renderer."""

import time
from dataclasses import dataclass

import numpy as np

from .camera import DEFAULT_FOV, DEFAULT_UP, Camera
from .config import GridParams, RenderParams
from .errors import InputError
from .grid.build import GridBuilder
from .memory import allocating, check_render_fits
from .precision import warn_detail
from .compiles import CompileWatch
from .stats import FrameStats
from .threads import use_threads
from .trace.render import Looks, Renderer

#: columns every stats row has, in this order (the dump's stats.csv header starts with them)
STATS_COLUMNS = (
    "frame", "t", "triangles", "cells", "references", "threads", "strategy", "insert",
    "clear_ms", "insert_ms", "macro_ms", "build_ms", "render_ms", "frame_ms",
    "anim_ms", "bounds_ms", "rebuilt", "refs_per_tri", "dims", "macro_full", "grid_bytes",
    "width", "height", "shading", "traversal", "mrays", "hit_fraction", "tests_per_ray", "cells_per_ray",
    "grid", "top_density", "leaf_density", "bytes_per_tri", "lights", "shadow_rays_per_pixel", "shade_ms",
    "compiled",
)


#: The pipeline chooses its frame again when the centre of the scene's bounds has drifted from the
#: frame's origin by more than this many times the bounds' largest extent.
RECENTRE_DRIFT = 1.0


@dataclass
class SplitScene:
    """A scene split into the triangles that never move (gridded once, by their own builder) and
    the others (gathered into ``moving`` and gridded every frame).

    static_ids, moving_ids  (Fs,), (Fm,) int32  the scene's ids of the two parts' triangles
    moving                  (Fm, 3, 3) float32  the moving triangles of the current frame
    static_builder          GridBuilder owning the static grid's buffers
    static_tris             (Fs, 3, 3) float32  the static triangles (None until first gridded)
    """

    static_ids: np.ndarray
    moving_ids: np.ndarray
    moving: np.ndarray
    static_builder: GridBuilder
    static_tris: np.ndarray | None = None

    @classmethod
    def of_mask(cls, mask, builder=GridBuilder):
        """The split of a scene whose triangles ``mask`` ((F,) bool) marks as static; ``builder``:
        the class of its static part's builder."""
        moving_ids = np.flatnonzero(~mask).astype(np.int32)
        return cls(np.flatnonzero(mask).astype(np.int32), moving_ids,
                   np.empty((len(moving_ids), 3, 3), np.float32), builder())

    def second(self, moving_grid):
        """``Renderer.render``'s ``second=`` for the static grid rendered with ``moving_grid``."""
        return (moving_grid, self.moving, self.static_ids, self.moving_ids)


@dataclass
class Frame:
    """One rendered frame: image (H,W,4) uint8, t (H,W) float32, tri (H,W) int32, stats FrameStats.

    ``grid`` is the frame's grid and ``origin`` ((3,) float64) the world position of the frame it
    was built in: the grid covers the scene's triangles moved by ``-origin`` (see FramePipeline).
    ``hdr`` (H,W,3) float32 (material shading with shadows, else None): the hit pixels' colours
    before they are clamped and rounded into the image (RenderResult.hdr).
    """

    image: np.ndarray
    t: np.ndarray
    tri: np.ndarray
    stats: FrameStats
    grid: object = None
    origin: np.ndarray = None
    hdr: np.ndarray = None


class FramePipeline:
    """Per frame: triangles_at(t) -> grid rebuild -> primary rays (+ shadows) -> image.

    scene          an gridrt.scene Animation (triangles_at(t) reuses one buffer)
    grid_params    GridParams (strategy, lambda, macro size, insertion test, threads)
    render_params  RenderParams (size, shading, shadows, intersection test, threads)
    camera         Camera, or None to frame the scene's bounds at the first frame
                   (with vertical field of view ``fov`` and up vector ``up``)
    follow_camera  use the scene's animated camera (``scene.camera_at(t)``) where it has one

    The scene is evaluated, gridded and ray cast in a frame centred on it, so a scene far from the
    world origin keeps float32's precision of its own size: :attr:`origin` (float64) is the centre
    of the scene's bounds at the first frame, or 0 when those bounds reach within one extent of the
    world origin (``Animation.frame_origin``; world coordinates are then as precise), the scene gives its
    triangles in ``world - origin`` (computed in float64 before rounding) and the camera (explicit,
    automatic or the scene's own, all in world coordinates) is moved by ``-origin`` in float64.
    The frame follows a moving scene: when the centre of a frame's bounds has drifted from the
    origin by more than RECENTRE_DRIFT times the bounds' extent, the origin moves to the scene's
    centre and that frame is evaluated again.  Hit distances, triangle ids and images are those of
    the world-space scene.

    A static scene is gridded once and not rebuilt until the grid parameters change.  A scene
    whose ``static_mask`` marks some triangles as never moving is split (``split_static``): the
    static part gets its own grid, built once, the moving part is rebuilt every frame, and the ray
    caster traverses both; triangle ids in the output stay the scene's.

    ``before_render``: None, or a callable run once, in the first frame that has its grids and
    has yet to render (what the cold start's helper process sets, gridrt.coldstart); it gets the
    set of the frame's grid kinds ("uniform", "two_level"), and returns True when it waited for
    kernels compiled elsewhere (the frame's stats then say it compiled).  ``Builder``: the class of the grid
    builders (GridBuilder; a subclass may name another).
    """

    Builder = GridBuilder

    def __init__(self, scene, grid_params=None, render_params=None, camera=None, fov=DEFAULT_FOV, up=DEFAULT_UP,
                 split_static=True, follow_camera=False):
        self.scene = scene
        self.fov = fov
        self.up = up
        self.grid_params = grid_params or GridParams()
        self.render_params = render_params or RenderParams()
        self.camera = camera
        self._camera0 = camera  # the camera asked for (None: frame the scene at the first frame)
        self.builder = self.Builder(self.grid_params)
        self.before_render = None
        self.renderer = Renderer()
        self.grid = None
        self._built_params = None
        self.frame_index = 0
        self.split_static = split_static
        self.follow_camera = follow_camera  # use the scene's own animated camera (BART, glTF)
        self.last_camera = None
        self._split = None  # SplitScene, once the scene is split
        self.static_grid = None
        self._static_params = None
        self.origin = None  # (3,) float64 world position of the frame the scene is gridded in
        self._local_camera = (None, None, None)  # (world camera, origin, the camera in that frame)
        self.recentred = 0  # how often the frame was chosen again after the first frame
        self.precision_warning = None  # the PrecisionWarning message of the first frame, if any
        self._first_t = None  # the time of the first frame (resume)
        self._origin0 = None  # the origin the first frame left (resume)
        self._rendered_size = None  # (width, height) of the renderer's buffers

    @classmethod
    def from_spec(cls, spec, scene=None):
        """The pipeline of the FrameSpec ``spec``: its grid and render parameters and its view
        (camera, fov, up, static split, follow-camera); ``scene``: the Animation of ``spec.scene``
        when already loaded (else it is loaded here).  Frame ``i`` of the spec is
        ``step(spec.view.time(i))``."""
        v = spec.view
        return cls(spec.scene.make() if scene is None else scene, spec.grid, spec.render, camera=v.camera(),
                   fov=v.fov, up=v.up, split_static=v.split_static, follow_camera=v.follow_camera)

    def _set_origin(self, origin):
        """Work in the frame of ``origin`` from now on: every grid is rebuilt in it."""
        self.origin = np.asarray(origin, np.float64).copy()
        self.grid = None
        self.static_grid = None

    def _in_frame(self, cam):
        """``cam`` (world) in the pipeline's frame, in float64 (cached for a camera reused)."""
        w, o, local = self._local_camera
        if w is cam and o is self.origin:
            return local
        local = cam.moved(-self.origin)
        self._local_camera = (cam, self.origin, local)
        return local

    def _frame_bounds(self, grid, split):
        lo, hi = grid.spec.scene_lo, grid.spec.scene_hi
        if split is not None:
            lo = np.minimum(lo, self.static_grid.spec.scene_lo)
            hi = np.maximum(hi, self.static_grid.spec.scene_hi)
        return lo, hi

    def _split_parts(self):
        """The static/moving split of the scene, or None when it does not apply."""
        mask = getattr(self.scene, "static_mask", None)
        if not self.split_static or mask is None or self.scene.static:
            return None
        mask = np.asarray(mask, bool)
        if mask.shape != (self.scene.n_triangles,) or mask.all() or not mask.any():
            return None
        if self._split is None:
            self._split = SplitScene.of_mask(mask, self.Builder)
        return self._split

    def _build(self, tris, gp):
        """(grid, split, rebuilt?, static_build_ms) for this frame: the scene's grid and None, or
        for a split scene the moving part's grid and the SplitScene (its static part's grid is
        :attr:`static_grid`)."""
        split = self._split_parts()
        if split is None:
            rebuild = self.grid is None or not self.scene.static or self._built_params != gp
            if rebuild:
                self.grid = self.builder.build(tris, gp)
                self._built_params = gp
            return self.grid, None, rebuild, 0.0
        static_ms = 0.0
        if self.static_grid is None or self._static_params != gp:
            split.static_tris = np.ascontiguousarray(tris[split.static_ids])
            self.static_grid = split.static_builder.build(split.static_tris, gp)
            self._static_params = gp
            static_ms = self.static_grid.stats["build_ms"]
        np.take(tris, split.moving_ids, axis=0, out=split.moving)
        self.grid = self.builder.build(split.moving, gp)
        self._built_params = gp
        return self.grid, split, True, static_ms

    def _looks(self, t, tris):
        """The material mode's Looks of the frame at t: the scene's triangles (in the pipeline's
        frame), surface, normals at t and lights at t moved into the frame."""
        lights = np.array(self.scene.lights_at(t), np.float64)
        if len(lights) and self.origin.any():
            point = lights[:, 0] == 0.0
            lights[point, 1:4] -= self.origin
        return Looks(tris, self.scene.surface, self.scene.normals_at(t), lights)

    def _place(self, t, camera=None):
        """The first half of a frame: the scene at t in the pipeline's frame (chosen at the first
        frame, moved when the scene drifts away) and its grid, and the camera.  Returns (tris,
        grid, split, rebuilt?, static_build_ms, anim_ms, camera in world, camera in the frame)."""
        t0 = time.perf_counter()
        # the animation's parallel kernels run at the rebuild's thread count, not at whatever count
        # the last kernel anywhere in the process left behind (another pipeline's render, say)
        use_threads(self.grid_params.threads)
        first = self.origin is None
        if first:
            self._set_origin(self.scene.frame_origin(float(t)))
        tris = self.scene.triangles_at(float(t), origin=self.origin)
        if first:
            self.precision_warning = warn_detail(tris, f"scene {self.scene.name!r}")
        anim_ms = (time.perf_counter() - t0) * 1e3
        gp = self.grid_params
        grid, split, rebuild, static_ms = self._build(tris, gp)
        lo, hi = self._frame_bounds(grid, split)
        drift = 0.5 * (lo + hi)
        if np.abs(drift).max() > RECENTRE_DRIFT * max(float((hi - lo).max()), 1e-300):
            # the scene has moved away from the frame: centre the frame on it again
            t0 = time.perf_counter()
            self._set_origin(self.origin + drift)
            self.recentred += 1
            tris = self.scene.triangles_at(float(t), origin=self.origin)
            anim_ms += (time.perf_counter() - t0) * 1e3
            grid, split, rebuild, static_ms = self._build(tris, gp)
            lo, hi = self._frame_bounds(grid, split)
        cam = None
        if self.follow_camera:
            cam = self.scene.camera_at(float(t))
        cam = cam or camera or self.camera
        if cam is None:
            local = Camera.frame(lo, hi, fov=self.fov, up=self.up)
            cam = self.camera = local.moved(self.origin)
            self._local_camera = (cam, self.origin, local)
        return tris, grid, split, rebuild, static_ms, anim_ms, cam, self._in_frame(cam)

    def resume(self, frame, t_first, origin=None):
        """Go on with a sequence at its frame number ``frame`` as this pipeline would had it
        stepped through frames 0 .. frame-1 itself, the first at time ``t_first``: the frames of
        one sequence rendered by several pipelines (processes, machines) in pieces are then those
        of one pipeline, bit for bit.

        ``frame`` 0 starts afresh (as a new pipeline).  Otherwise the pipeline takes the state
        its first frame leaves (the frame's origin and, with no camera of its own, the camera
        that frames the scene), placing that frame itself (the grid is built, nothing is
        rendered) unless it already has, and then the frame's ``origin`` ((3,) float64: where the
        pipeline stood after frame ``frame``-1; None: where the first frame left it, right unless
        the scene drifted far enough to move the frame since).  Grids are kept when nothing
        changes (a static scene is not gridded again).
        """
        frame = int(frame)
        if frame < 0:
            raise InputError(f"resume: frame must be >= 0, got {frame}")
        if frame == 0 or self._first_t != float(t_first):
            self.camera = self._camera0
            self._local_camera = (None, None, None)
            self.origin = None
            self.grid = self.static_grid = None
            self.recentred = 0
            self._first_t = None
        if frame > 0:
            if self.origin is None:
                self._place(float(t_first))
                self._first_t, self._origin0 = float(t_first), self.origin
            origin = self._origin0 if origin is None else np.asarray(origin, np.float64)
            if origin.shape != (3,) or not np.isfinite(origin).all():
                raise InputError(f"resume: origin must be 3 finite numbers, got {origin!r}")
            if not np.array_equal(origin, self.origin):
                self._set_origin(origin)
        self.frame_index = frame

    def step(self, t, camera=None, jitter=None):
        """Render the scene at time t; returns a Frame. ``camera`` overrides the pipeline's;
        ``jitter`` (jx, jy) moves every camera ray by that fraction of a pixel, right and down
        (Camera.jittered: progressive anti-aliasing; the Frame's t and tri are those rays'). A
        render whose buffers and shadow rays (gridrt.memory.render_bytes) exceed the memory
        left (gridrt.memory) is refused before they are allocated, as are grids (GridBuilder); a
        MemoryError all the same becomes an InputError naming the frame."""
        rp = self.render_params
        with allocating(lambda: f"rendering frame {self.frame_index} ({rp.width}x{rp.height} pixels, "
                                f"{self.scene.n_triangles:,} triangles)", "ask for a smaller image or scene"):
            with CompileWatch() as watch:
                return self._render_frame(t, camera, watch, jitter)

    def _render_frame(self, t, camera, watch, jitter=None):
        t_frame = time.perf_counter()
        rp = self.render_params
        surface = self.scene.surface
        shading = rp.resolved(surface is not None and surface.has_looks)
        W, H = rp.width, rp.height
        # the render's buffers and shadow rays, before the scene and its grid take their memory
        check_render_fits(W, H, shading == "material" and bool(rp.shadows), self._rendered_size != (W, H),
                          "rendering a frame of", rp.light_samples)
        first = self.origin is None
        tris, grid, split, rebuild, static_ms, anim_ms, cam, local_cam = self._place(t, camera)
        if first:
            self._first_t, self._origin0 = float(t), self.origin
        if jitter is not None and any(jitter):
            local_cam = local_cam.jittered(W, H, *jitter)
        gp = self.grid_params
        if rp.light is not None and self.origin.any():
            rp = rp.replace(light=tuple(np.asarray(rp.light, np.float64) - self.origin))
        looks = self._looks(float(t), tris) if shading == "material" else None
        waited = False  # for kernels compiled elsewhere (a frame whose time is not a rendering time)
        if self.before_render is not None:
            hook, self.before_render = self.before_render, None
            waited = bool(hook({grid.kind} | ({self.static_grid.kind} if split is not None else set())))
        if split is not None:
            res = self.renderer.render(self.static_grid, split.static_tris, local_cam, rp, second=split.second(grid),
                                       looks=looks)
        else:
            res = self.renderer.render(grid, tris, local_cam, rp, looks=looks)
        self._rendered_size = (W, H)
        self.last_camera = cam
        rp = self.render_params
        stats = FrameStats(
            frame=self.frame_index, t=float(t), triangles=self.scene.n_triangles, build=grid.stats,
            static=self.static_grid.stats if split is not None else None, render=res.stats,
            rebuilt=bool(rebuild), anim_ms=anim_ms, static_build_ms=static_ms,
            frame_ms=(time.perf_counter() - t_frame) * 1e3, width=rp.width, height=rp.height, shading=shading,
            top_density=gp.top_density, leaf_density=gp.leaf_density, compiled=watch.check() or waited,
        )
        self.frame_index += 1
        return Frame(res.image, res.t, res.tri, stats, grid, self.origin, res.hdr)
