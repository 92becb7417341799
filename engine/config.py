"""Settings that flow into the engine as plain values (kernels never read globals).

Each dataclass validates itself in ``__post_init__`` and raises InputError naming the field.
"""

import math
from dataclasses import dataclass, replace

from .checks import MAX_IMAGE_SIDE, _positive_int
from .errors import InputError
from .memory import check_render_fits
from .threads import check_threads

INSERT_MODES = ("bbox", "exact")
#: Build strategies (GridParams.strategy), in the order of the table of Ize et al. 2006 (plus
#: Lagae & Dutre 2008's counting): the names gridrt.grid.registry maps to their classes (it
#: refuses to load when its classes and these names differ)
STRATEGIES = ("serial", "sort_first", "global_lock", "cell_locks", "lock_pool", "thread_grids_merge", "thread_grids",
              "sort_middle", "counting")
#: GridParams.strategy "auto" (the default): serial at one thread, and above it the fastest at 2
#: threads in BENCHMARKS.md section 2 (``gridrt bench build``, geometric mean over its scenes) of
#: the strategies whose grids equal the serial build's, cell lists in the same order, at any
#: thread count (:data:`SERIAL_ORDER_STRATEGIES`): frames then come out the same every run, and a
#: resumed dump is the one-run dump (counting and thread_grids, a little faster, scatter with
#: atomics in an order that changes from run to run); :func:`resolve_strategy` gives the name
AUTO_STRATEGY = "auto"
PARALLEL_DEFAULT_STRATEGY = "sort_first"
#: the strategies whose grids equal the serial build's, cell lists in the same order
SERIAL_ORDER_STRATEGIES = ("serial", "sort_first", "thread_grids_merge", "sort_middle")
#: Grid kinds (GridParams.grid): one uniform grid, a two-level grid (gridrt.grid.two_level), or
#: the one of the two that the scene's spread of triangles asks for (gridrt.grid.build.crowding,
#: AUTO_CROWDING)
GRID_KINDS = ("uniform", "two_level", "auto")
#: Shading modes (RenderParams.shading): "auto" is "material" for a scene with looks of its own
#: (Surface.has_looks: materials or smooth normals) and "lambert" for one without (RenderParams.resolved)
SHADING_MODES = ("auto", "material", "lambert", "normal", "cost")
#: Ray traversal: single-ray 3D DDA, or coherent grid traversal of ray packets (gridrt.trace.cgt)
TRAVERSALS = ("dda", "cgt")
#: precisions of the CGT packets' triangle tests (RenderParams.packet_precision)
PACKET_PRECISIONS = ("float64", "float32")
#: the largest CGT packet edge in pixels (RenderParams.packet)
PACKET_MAX = 16
#: the most lights drawn per hit pixel (RenderParams.light_samples)
MAX_LIGHT_SAMPLES = 8
#: Default ceiling on grid cells (two int32 arrays of this size plus cell lists): 256 MiB.
DEFAULT_MAX_CELLS = 1 << 25
#: Default memory budget of one grid (cell arrays + references): 2 GiB.
DEFAULT_MAX_BYTES = 1 << 31
#: Default densities of two-level grids (top cells per triangle, leaf cells per top-cell
#: reference): BENCHMARKS.md section 14
DEFAULT_TOP_DENSITY = 0.0625
DEFAULT_LEAF_DENSITY = 2.0


def check_strategy(name):
    """``name`` if it is a registered build strategy (:data:`STRATEGIES`) or "auto"; InputError
    listing the valid names otherwise."""
    if not isinstance(name, str) or (name not in STRATEGIES and name != AUTO_STRATEGY):
        raise InputError(f"unknown build strategy {name!r}; choose one of {AUTO_STRATEGY}, {', '.join(STRATEGIES)}")
    return name


def resolve_strategy(name, threads):
    """The registered strategy a GridParams.strategy of ``name`` builds with at ``threads`` threads:
    "auto" is serial at one thread and :data:`PARALLEL_DEFAULT_STRATEGY` above; any other name is
    itself."""
    if name == AUTO_STRATEGY:
        return "serial" if threads == 1 else PARALLEL_DEFAULT_STRATEGY
    return name


@dataclass(frozen=True)
class GridParams:
    """How to build the grid each frame.

    strategy   name of a registered build strategy (gridrt.grid.registry), or "auto" (the
               default): serial at one thread, sort_first above (:func:`resolve_strategy`);
               on a cold numba cache the serial strategy stands in for sort_first (the same
               grid) until sort_first has compiled in the background (GridBuilder.build)
    density    lambda: target cells ~ density * triangles, shaped by the scene bounds
    macro      macro-cell edge k in cells (a macro cell is k**3 cells); 1 disables skipping gain
    insert     "bbox" (triangle bounding box, fast) or "exact" (separating-axis test, fewer refs)
    threads    build thread count (None: all cores); may exceed the core count
    grid       "uniform" (one grid of about density * triangles cells), "two_level" (a coarse
               grid of about top_density * triangles cells whose non-empty cells each hold a grid
               of about leaf_density * (its triangles) cells: resolution where the triangles
               are; gridrt.grid.two_level) or "auto" (two_level where the triangles crowd into
               few top cells, uniform otherwise: gridrt.grid.build.crowding and AUTO_CROWDING;
               a uniform choice is kept for AUTO_RECHECK builds)
    top_density   two_level: top-level cells per triangle
    leaf_density  two_level: leaf cells per reference of a top cell
    max_cells  ceiling on nx*ny*nz; a larger request is reduced to it with a warning
    max_bytes  memory budget of the cell arrays plus references (thread_grids_merge: plus the
               per-thread grids it merges); a build that would need more stops with an
               InputError before allocating.  RayCaster.cast holds a batch's results plus its
               scratch to the same budget (cast_rays: the default one), refusing a batch before
               allocating.  Whatever the budget, each of these allocations is also refused
               beforehand when it exceeds the memory this process has left (gridrt.memory)
    """

    strategy: str = AUTO_STRATEGY
    density: float = 4.0
    macro: int = 4
    insert: str = "bbox"
    threads: int | None = None
    max_cells: int = DEFAULT_MAX_CELLS
    max_bytes: int = DEFAULT_MAX_BYTES
    grid: str = "uniform"
    top_density: float = DEFAULT_TOP_DENSITY
    leaf_density: float = DEFAULT_LEAF_DENSITY

    def __post_init__(self):
        for name, what in (("density", "density (lambda)"), ("top_density", "top_density"),
                           ("leaf_density", "leaf_density")):
            v = getattr(self, name)
            try:
                d = float(v)
            except (TypeError, ValueError):
                raise InputError(f"{what} must be a number, got {v!r}") from None
            if not math.isfinite(d) or d <= 0:
                raise InputError(f"{what} must be a positive finite number, got {v!r}")
            object.__setattr__(self, name, d)
        if self.grid not in GRID_KINDS:
            raise InputError(f"unknown grid kind {self.grid!r}; choose one of {', '.join(GRID_KINDS)}")
        object.__setattr__(self, "macro", _positive_int("macro cell size", self.macro, 1, 64))
        if self.insert not in INSERT_MODES:
            raise InputError(f"unknown insertion test {self.insert!r}; choose one of {', '.join(INSERT_MODES)}")
        object.__setattr__(self, "max_cells", _positive_int("max_cells", self.max_cells, 1, (1 << 31) - 2))
        object.__setattr__(self, "max_bytes", _positive_int("max_bytes", self.max_bytes, 1))
        if self.threads is not None:
            object.__setattr__(self, "threads", check_threads(self.threads))
        check_strategy(self.strategy)

    def replace(self, **kw):
        return replace(self, **kw)


def _packet_shape(p):
    """RenderParams.packet as (width, height): an edge n gives (n, n)."""
    if isinstance(p, str):  # "8" or "16x4" (the command line's form)
        parts = p.lower().split("x")
        if len(parts) > 2 or not all(q.strip().isdigit() for q in parts):
            raise InputError(f"packet size must be N or WxH in pixels, e.g. 8 or 16x4; got {p!r}")
        p = tuple(int(q) for q in parts) if len(parts) == 2 else int(parts[0])
    if isinstance(p, (tuple, list)):
        if len(p) != 2:
            raise InputError(f"packet size must be an edge or (width, height), got {p!r}")
        w, h = p
    else:
        w = h = p
    return (_positive_int("packet width", w, 1, PACKET_MAX), _positive_int("packet height", h, 1, PACKET_MAX))


@dataclass(frozen=True)
class RenderParams:
    """How to cast and shade the primary rays.

    width, height  image size in pixels (each 1..MAX_IMAGE_SIDE); a size whose buffers
                   (gridrt.memory.render_bytes) exceed the memory this process has left
                   (gridrt.memory) is refused, stating both
    shading        "auto" (the default: "material" for a scene with materials, textures, vertex
                   colours or smooth normals (Surface.has_looks), else "lambert"),
                   "material" (the scene's materials, textures, smooth normals and lights:
                   gridrt.trace.material), "lambert" (one colour; a headlight, or the point
                   light when shadows are on), "normal" (geometric normal facing the viewer,
                   mapped to RGB) or "cost" (heat map of triangle tests per ray)
    shadows        cast hard shadow rays: towards ``light`` (lambert), or towards each of the
                   scene's lights (material)
    light          point-light position (3 floats); None: above and behind the camera (lambert;
                   material: the scene's own lights, or that default light when it has none).
                   Given, it replaces the scene's lights in the material mode
    watertight     Woop-Benthin-Wald watertight ray-triangle test (True) or the faster
                   Moller-Trumbore test (False)
    threads        render thread count (None: all cores)
    tile           square tile edge in pixels; tiles are the unit of parallel work
    traversal      "cgt" (packets of up to 8 x 8 rays, coherent grid traversal, Wald et al. 2006;
                   the default: BENCHMARKS.md section 6 finds it on the Pareto front, several times
                   faster than DDA at no measured error) or "dda" (one ray at a time); same hits
                   except at exact ties
    packet         CGT packet size in pixels: an edge n (n x n pixels) or (width, height), each
                   1..16; default 8 x 8 (BENCHMARKS.md, "Packet size and precision")
    packet_precision
                   "float64" (the CGT packets' triangle tests in float64: the same hits as the
                   DDA bit for bit) or "float32" (twice the rays a vector instruction; the
                   watertight test keeps its guarantee through a float64 fallback, and hits agree
                   up to float32 rounding: about 1e-7 relative in t, the triangle only at
                   near-ties and within that distance of an edge; at that level results may
                   then also depend on the packet size).  CGT only.
    light_samples  0 (the default, exact): the material mode's shadows cast a ray towards every
                   light that lights a hit.  k (1..MAX_LIGHT_SAMPLES): k rays a hit pixel, towards
                   lights drawn in proportion to their unshadowed light there (stratified over
                   the k draws), each weighted by 1 / (k p): an unbiased estimate of the exact
                   image, noisy in shadows and penumbrae; lights that do not light a hit are
                   never drawn.  A light that the centre of the pixel's 8 x 8 square does not
                   see (one ray a light and square) is drawn a tenth as often there
                   (gridrt.trace.render.Renderer.light_guide).  A scene of one light is exact
                   either way (gridrt.trace.material.drawn_segments)
    light_seed     which draw (an int >= 0): the same seed draws the same lights; the mean of the
                   images of seeds 0 .. n-1 tends to the exact image as n grows (each pixel's
                   draws follow a shifted van der Corput sequence; the viewer accumulates them
                   while the view is still)
    """

    width: int = 1024
    height: int = 768
    shading: str = "auto"
    shadows: bool = False
    light: tuple | None = None
    watertight: bool = True
    threads: int | None = None
    tile: int = 16
    traversal: str = "cgt"
    packet: int | tuple = (8, 8)
    packet_precision: str = "float64"
    light_samples: int = 0
    light_seed: int = 0

    def __post_init__(self):
        W, H = _positive_int("image width", self.width, 1), _positive_int("image height", self.height, 1)
        object.__setattr__(self, "light_samples",
                           _positive_int("light samples", self.light_samples, 0, MAX_LIGHT_SAMPLES))
        object.__setattr__(self, "light_seed", _positive_int("light seed", self.light_seed, 0, 2**31 - 1))
        # (shading "auto" with shadows: FramePipeline.step checks the shadow rays once it is resolved)
        check_render_fits(W, H, self.shading == "material" and bool(self.shadows), light_samples=self.light_samples)
        object.__setattr__(self, "width", _positive_int("image width", W, 1, MAX_IMAGE_SIDE))
        object.__setattr__(self, "height", _positive_int("image height", H, 1, MAX_IMAGE_SIDE))
        object.__setattr__(self, "tile", _positive_int("tile size", self.tile, 1, 256))
        if self.shading not in SHADING_MODES:
            raise InputError(f"unknown shading mode {self.shading!r}; choose one of {', '.join(SHADING_MODES)}")
        if self.traversal not in TRAVERSALS:
            raise InputError(f"unknown traversal {self.traversal!r}; choose one of {', '.join(TRAVERSALS)}")
        object.__setattr__(self, "packet", _packet_shape(self.packet))
        if self.packet_precision not in PACKET_PRECISIONS:
            raise InputError(f"unknown packet precision {self.packet_precision!r}; choose one of "
                             f"{', '.join(PACKET_PRECISIONS)}")
        if self.light is not None:
            try:
                light = tuple(float(x) for x in self.light)
            except (TypeError, ValueError):
                raise InputError(f"light must be 3 numbers, got {self.light!r}") from None
            if len(light) != 3 or not all(math.isfinite(x) for x in light):
                raise InputError(f"light must be 3 finite numbers, got {self.light!r}")
            object.__setattr__(self, "light", light)
        if self.threads is not None:
            object.__setattr__(self, "threads", check_threads(self.threads))

    def replace(self, **kw):
        return replace(self, **kw)

    def resolved(self, has_materials):
        """The shading mode to render with: "auto" is "material" when ``has_materials`` (the
        scene's surface has looks of its own: Surface.has_looks), else "lambert"; the others are
        themselves."""
        if self.shading != "auto":
            return self.shading
        return "material" if has_materials else "lambert"
