"""Background thread that owns the FramePipeline, so a slow step (a big scene loading, the first
numba compile, a heavy frame) never blocks the window's event loop.

The window thread submits jobs and polls for results; the worker runs one job at a time.  Each
job carries the :class:`gridrt.frame.FrameSpec` it renders: a load makes the pipeline of its spec,
a frame sets the kept pipeline's settings from its spec (the pipeline is not made again per
frame).  A load with ``warm`` also steps a throwaway pipeline of its spec at a tiny size, so that
the first frame finds its kernels loaded (the viewer's first load, on a warm cache, while its
window opens).  A newly submitted job replaces one that has not started yet (only the latest request
matters).  Results are plain objects handed over under a lock; the worker copies the image out of
the renderer's reused buffer before publishing it.

While a scene loads, the textures its loader reads are counted (gridrt.scene.surface's
texture_progress): :meth:`RenderWorker.progress` has the running count for the window's loading
display, and the LoadResult the totals.
"""

import threading
import time
import traceback
from dataclasses import dataclass, replace

import numpy as np

from gridrt.coldstart import CompileHelper
from gridrt.errors import GridrtError
from gridrt.frame import FrameSpec
from gridrt.scene.surface import texture_progress


@dataclass
class LoadJob:
    """Load the scene of ``spec`` and make a new pipeline for it (the worker's factory: the
    viewer's is :meth:`gridrt.pipeline.FramePipeline.from_spec`)."""

    spec: FrameSpec         # the scene to load, and the settings and view its pipeline starts with
    keep_camera: bool = False  # keep the viewer's camera (else reframe once loaded)
    scene_camera: bool = True  # look through the scene's own camera once loaded, when it has one
    label: str = "loading scene"
    warm: bool = False      # also render a throwaway frame of the spec at WARM_SIZE (see RenderWorker._load)
    helper: bool = False    # a cold cache: a helper process compiles the first frame's ray casting (gridrt.coldstart)


#: the size of a LoadJob's throwaway frame (width, height)
WARM_SIZE = (16, 12)


@dataclass
class FrameJob:
    """Render the frame of ``spec`` at time ``t``: the loaded pipeline takes the spec's grid and
    render settings and its view's camera, fov, up and follow-camera."""

    spec: FrameSpec
    t: float
    generation: int = 0     # scene generation the frame belongs to (stale results are dropped)
    label: str = "rendering"
    jitter: tuple | None = None  # (jx, jy) pixels: a progressive sample's sub-pixel offset (None: centred)
    light_seed: int = 0     # the draw of the lights where the spec draws them (RenderParams.light_seed)


@dataclass
class TextureProgress:
    """Textures read so far by a scene load: how many, their bytes (decoded texels) and the last one's name."""

    count: int = 0
    nbytes: int = 0
    last: str = ""

    def add(self, name, nbytes):
        self.count += 1
        self.nbytes += int(nbytes)
        self.last = str(name)

    def label(self):
        """"loading textures: N read (X MiB), last: name" ("" before the first texture)."""
        if not self.count:
            return ""
        return f"loading textures: {self.count} read ({self.nbytes / 2**20:.2f} MiB), last: {self.last}"

    def as_dict(self):
        return {"count": self.count, "bytes": self.nbytes, "last": self.last}


@dataclass
class LoadResult:
    scene: object              # the SceneSpec loaded (or that failed to load)
    scene_name: str = ""
    triangles: int = 0
    duration: float | None = None
    static: bool = False
    keep_camera: bool = False
    error: str | None = None
    seconds: float = 0.0
    has_camera: bool = False   # the scene has its own camera (scene.camera_at(0) is a Camera)
    textures: TextureProgress | None = None
    job: object = None         # the LoadJob


@dataclass
class FrameResult:
    image: np.ndarray
    stats: object           # the frame's gridrt.stats.FrameStats (frozen), None for a failed frame
    camera: object          # the camera the frame was rendered with
    radius: float           # half the grid's diagonal (for fly speed)
    job: FrameJob
    error: str | None = None
    depth: np.ndarray | None = None   # (H, W) float32 hit distance along each pixel's ray (inf: miss)
    ray_camera: object = None         # the camera of those rays (``camera``, jittered by the job's jitter)
    hdr: np.ndarray | None = None     # (H, W, 3) float32 colours before clamping where lights are drawn (Frame.hdr)


class RenderWorker:
    """Runs LoadJob / FrameJob on one daemon thread.  Use :meth:`submit`, :meth:`take`,
    :attr:`busy`, and :meth:`stop`."""

    def __init__(self, pipeline_factory, on_result=None):
        self._factory = pipeline_factory  # (scene, LoadJob) -> FramePipeline of the job's spec
        self._on_result = on_result       # called on the worker thread after each result (wake the UI)
        self._cond = threading.Condition()
        self._pending = None
        self._results = []
        self._current = None
        self._started_at = 0.0
        self._progress = None             # TextureProgress of the load in progress
        self._stop = False
        self._helper = None               # the CompileHelper of the last load, while it may run
        self.pipeline = None
        self._thread = threading.Thread(target=self._run, name="gridrt-render", daemon=True)
        self._thread.start()

    # ---- window-thread API --------------------------------------------------------------
    def submit(self, job):
        with self._cond:
            self._pending = job
            self._cond.notify_all()

    def take(self):
        """All results finished since the last call (oldest first)."""
        with self._cond:
            out, self._results = self._results, []
        return out

    @property
    def busy(self):
        """True while a job runs or waits, or a result has not been taken yet."""
        with self._cond:
            return self._current is not None or self._pending is not None or bool(self._results)

    def current(self):
        """(job, seconds running) of the running job, or (None, 0)."""
        with self._cond:
            if self._current is None:
                return None, 0.0
            return self._current, time.perf_counter() - self._started_at

    def progress(self):
        """A copy of the running load's TextureProgress (None when no load runs)."""
        with self._cond:
            p = self._progress
            return None if p is None else TextureProgress(p.count, p.nbytes, p.last)

    def attach(self, on_result):
        """Call ``on_result`` after each result from now on (once the window system is up)."""
        self._on_result = on_result

    def detach(self):
        """Stop calling on_result (before the window system shuts down)."""
        self._on_result = None

    def stop(self, timeout=10.0):
        """Ask the thread to finish after its current job; True when it ended within timeout."""
        with self._cond:
            self._stop = True
            self._pending = None
            self._cond.notify_all()
        self._thread.join(timeout)
        return not self._thread.is_alive()

    # ---- worker thread -------------------------------------------------------------------
    def _run(self):
        while True:
            with self._cond:
                while self._pending is None and not self._stop:
                    self._cond.wait()
                if self._stop:
                    return
                job, self._pending = self._pending, None
                self._current = job
                self._started_at = time.perf_counter()
            try:
                res = self._load(job) if isinstance(job, LoadJob) else self._frame(job)
            except Exception as e:  # reported in the panel; the viewer keeps running
                msg = str(e) if isinstance(e, GridrtError) else f"{type(e).__name__}: {e}"
                if not isinstance(e, GridrtError):
                    traceback.print_exc()
                res = (LoadResult(job.spec.scene, error=msg, job=job) if isinstance(job, LoadJob)
                       else FrameResult(None, None, job.spec.camera(), 1.0, job, error=msg))
            with self._cond:
                self._results.append(res)
                self._current = None
                self._progress = None
            notify = self._on_result
            if notify is not None:
                notify()

    def _load(self, job):
        t0 = time.perf_counter()
        s = job.spec.scene
        with self._cond:
            self._progress = TextureProgress()

        def on_texture(name, nbytes):   # on this thread, from the loader
            with self._cond:
                if self._progress is not None:
                    self._progress.add(name, nbytes)
            notify = self._on_result
            if notify is not None:
                notify()                 # wake the window to show it

        if self._helper is not None:  # (a load before the last one's first frame)
            self._helper.stop()
            self._helper = None
        if job.helper:
            # it compiles the ray casting of the first frame (through the scene's own camera where
            # that frame will look through it) while this thread loads the scene and builds the grid
            spec = job.spec
            if job.scene_camera:
                spec = spec.replace(view=spec.view.replace(follow_camera=True))
            self._helper = CompileHelper.start(spec, spec.view.time(0))
        with texture_progress(on_texture):
            scene = s.make()
        has_camera = scene.camera_at(0.0) is not None
        self.pipeline = self._factory(scene, job)
        if self._helper is not None:
            self.pipeline.before_render = self._helper.wait
        if job.warm:
            # a frame of the spec's settings at a tiny size, at its first frame's time, on a pipeline of
            # its own: the kernels the first frame runs load from numba's cache now (the viewer
            # submits the first load while its window opens), not when that frame is asked for
            self._factory(scene, replace(job, spec=job.spec.resized(*WARM_SIZE))).step(job.spec.view.time(0))
        textures = self.progress()
        return LoadResult(s, scene_name=scene.name, triangles=int(scene.n_triangles), duration=scene.duration,
                          static=bool(scene.static), keep_camera=job.keep_camera,
                          seconds=time.perf_counter() - t0, has_camera=has_camera, textures=textures, job=job)

    def _frame(self, job):
        pipe = self.pipeline
        if pipe is None:
            raise GridrtError("no scene loaded")
        spec, view = job.spec, job.spec.view
        pipe.grid_params = spec.grid
        pipe.render_params = spec.render.replace(light_seed=job.light_seed) if job.light_seed else spec.render
        pipe.follow_camera, pipe.fov, pipe.up = view.follow_camera, view.fov, view.up
        fr = pipe.step(job.t, camera=view.camera(), jitter=job.jitter)
        cam = pipe.last_camera
        box = getattr(fr.grid if fr.grid is not None else pipe.grid, "spec", None)   # the grid's bounds
        radius = 1.0 if box is None else 0.5 * float(np.linalg.norm(np.asarray(box.hi) - np.asarray(box.lo)))
        h, w = fr.t.shape
        ray_cam = cam.jittered(w, h, *job.jitter) if job.jitter is not None and cam is not None else cam
        drew = fr.hdr is not None and spec.render.light_samples and fr.stats.render.lights > 1
        hdr = fr.hdr.copy() if drew else None
        return FrameResult(fr.image.copy(), fr.stats, cam, radius, job, depth=fr.t.copy(), ray_camera=ray_cam, hdr=hdr)
