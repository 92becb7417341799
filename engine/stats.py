"""Typed statistics of a grid build (:class:`BuildStats`), a render (:class:`RenderStats`) and a
pipeline frame (:class:`FrameStats`): stage timings in ms (``stages``) kept apart from counters
(the typed fields), and one :meth:`as_row` each, the flat column -> value dict a CSV row or a
JSON record holds.

Each is read-only and also reads like that row (``stats["build_ms"]``, ``stats.get(...)``,
``dict(stats)``), so code that prints or tabulates stats by column name needs no special case.
"""

from abc import abstractmethod
from collections.abc import Mapping
from dataclasses import dataclass, field


class _Row(Mapping):
    """Read access to :meth:`as_row` by column name (the row is made once: the stats are frozen)."""

    @abstractmethod
    def as_row(self):
        """The flat column -> value dict (a new dict on each call)."""

    def _row(self):
        row = self.__dict__.get("_row_cache")
        if row is None:
            row = self.as_row()
            object.__setattr__(self, "_row_cache", row)
        return row

    def __getitem__(self, key):
        return self._row()[key]

    def __iter__(self):
        return iter(self._row())

    def __len__(self):
        return len(self._row())


@dataclass(frozen=True, eq=False)
class BuildStats(_Row):
    """One grid build.

    stages           ms per stage, in the order they ran: bounds_ms, clear_ms, insert_ms (with the
                     strategy's own parts of it: count_ms, scan_ms, scatter_ms, bucket_ms, ...),
                     macro_ms
    build_ms         the whole build, ms
    strategy, threads, insert   what built it
    triangles, cells, references, refs_per_tri, dims (e.g. "20x10x25"), macro_cells, macro_full
                     (non-empty macro cells), cells_cleared (cells the clear reset),
                     cells_inspected (cells the macro pass looked at), grid_bytes
    counters         the strategy's own counts (bucket_entries, lock_waits; a two-level grid's
                     top_references)
    grid             the grid's kind, "uniform" or "two_level"; a two-level grid's cells,
                     references and refs_per_tri are its leaf level's, its dims, macro_cells and
                     macro_full its top level's (cells, non-empty cells), and its stages add
                     leaf_res_ms, leaf_count_ms and leaf_scatter_ms
    """

    stages: dict
    build_ms: float
    strategy: str
    threads: int
    insert: str
    triangles: int
    cells: int
    references: int
    refs_per_tri: float
    cells_cleared: int
    cells_inspected: int
    macro_cells: int
    macro_full: int
    dims: str
    grid_bytes: int
    counters: dict = field(default_factory=dict)
    grid: str = "uniform"

    def as_row(self):
        return {**self.stages, "build_ms": self.build_ms, **self.counters, "grid": self.grid,
                "strategy": self.strategy, "threads": self.threads, "insert": self.insert,
                "triangles": self.triangles, "cells": self.cells, "references": self.references,
                "refs_per_tri": self.refs_per_tri, "cells_cleared": self.cells_cleared,
                "cells_inspected": self.cells_inspected, "macro_cells": self.macro_cells,
                "macro_full": self.macro_full, "dims": self.dims, "grid_bytes": self.grid_bytes}


@dataclass(frozen=True, eq=False)
class RenderStats(_Row):
    """One render: its time (render_ms, the kernel's wall time) and what the rays did.

    mrays          million primary rays per second
    hit_fraction   primary rays that hit
    tests_per_ray, cells_per_ray   triangle tests and cells visited per primary ray
    render_threads, traversal      how it ran
    split_rays     rays the packet traversal traced in split packets (their packet disagreed on
                   the major axis or its sign, and was traced as one packet per direction class);
                   None for the single-ray traversal, which has no packets
    lights         lights the hits were shaded with (the ``material`` mode: the scene's, or 1 for
                   the default light; the other modes: 1 with shadows, else 0, a headlight)
    shadow_rays_per_pixel   shadow rays cast, per pixel (None where they are not counted: lambert
                   with shadows; a CSV or panel says "n/a")
    shade_ms       of render_ms, the ``material`` mode's shading pass and its shadow rays (0 otherwise)
    """

    render_ms: float
    mrays: float
    hit_fraction: float
    tests_per_ray: float
    cells_per_ray: float
    render_threads: int
    traversal: str
    split_rays: int | None = None
    lights: int = 0
    shadow_rays_per_pixel: float | None = 0.0
    shade_ms: float = 0.0

    @property
    def stages(self):
        return {"render_ms": self.render_ms}

    def as_row(self):
        row = {"render_ms": self.render_ms, "mrays": self.mrays, "hit_fraction": self.hit_fraction,
               "tests_per_ray": self.tests_per_ray, "cells_per_ray": self.cells_per_ray,
               "render_threads": self.render_threads, "traversal": self.traversal, "lights": self.lights,
               "shadow_rays_per_pixel": self.shadow_rays_per_pixel, "shade_ms": self.shade_ms}
        if self.split_rays is not None:
            row["split_rays"] = self.split_rays
        return row


@dataclass(frozen=True, eq=False)
class FrameStats(_Row):
    """One :meth:`FramePipeline.step`: the frame's build, its render and the frame around them.

    frame, t, triangles   frame index, scene time, the scene's triangles
    build                 BuildStats of the grid built this frame (a split scene: its moving part);
                          its ``grid`` (the kind built: "uniform" or "two_level") is the row's
                          ``grid`` column
    static                BuildStats of a split scene's static grid (None: not split)
    render                RenderStats
    rebuilt               whether ``build`` was built this frame (False: a static scene's grid reused,
                          and its build stages count 0 in the row)
    anim_ms               evaluating the scene's triangles
    static_build_ms       building the static grid this frame (0 when it was reused)
    frame_ms              the whole step
    width, height, shading   the render's image
    top_density, leaf_density   the two-level densities of the GridParams the frame was built
                          with (None: not given); the row also has bytes_per_tri, the grids'
                          bytes (static part included) per triangle of the scene
    compiled              numba compiled kernels while the frame ran (gridrt.compiles): its times
                          are not rendering times, and medians and plots leave it out
    """

    frame: int
    t: float
    triangles: int
    build: BuildStats
    render: RenderStats
    rebuilt: bool
    anim_ms: float
    static_build_ms: float
    frame_ms: float
    width: int
    height: int
    shading: str
    static: BuildStats | None = None
    top_density: float | None = None
    leaf_density: float | None = None
    compiled: bool = False

    def _total(self, name):
        return getattr(self.build, name) + (getattr(self.static, name) if self.static is not None else 0)

    @property
    def build_stages(self):
        """The build's stages of this frame (0 for a grid reused), build_ms excluded."""
        return {k: (v if self.rebuilt else 0.0) for k, v in self.build.stages.items()}

    @property
    def stages(self):
        """Every ms figure of the frame: the build's stages, build_ms, the static build, the
        render, the animation and the whole frame."""
        return {**self.build_stages, "build_ms": self.build.build_ms if self.rebuilt else 0.0,
                "static_build_ms": self.static_build_ms, "render_ms": self.render.render_ms,
                "anim_ms": self.anim_ms, "frame_ms": self.frame_ms}

    def as_row(self):
        """The frame's row: the columns of :data:`gridrt.pipeline.STATS_COLUMNS` (in their order,
        with moving_triangles, static_build_ms and split_rays between them) and then the
        strategy's own stages; frame_ms last."""
        b, r = self.build, self.render
        parts = self.build_stages
        row = {
            "frame": self.frame, "t": self.t, "triangles": self.triangles,
            "cells": self._total("cells"), "references": self._total("references"),
            "threads": b.threads, "strategy": b.strategy, "insert": b.insert,
            "clear_ms": parts.get("clear_ms", 0.0), "insert_ms": parts.get("insert_ms", 0.0),
            "macro_ms": parts.get("macro_ms", 0.0), "build_ms": b.build_ms if self.rebuilt else 0.0,
            "render_ms": r.render_ms, "anim_ms": self.anim_ms, "bounds_ms": parts.get("bounds_ms", 0.0),
            # references per triangle of the whole scene (both parts of a split scene); the moving
            # part's own figure is moving_refs_per_tri
            "rebuilt": int(self.rebuilt), "refs_per_tri": self._total("references") / max(self._total("triangles"), 1),
            "moving_triangles": b.triangles, "moving_refs_per_tri": b.refs_per_tri,
            "static_build_ms": self.static_build_ms, "dims": b.dims, "macro_full": b.macro_full,
            "grid_bytes": self._total("grid_bytes"), "width": self.width, "height": self.height,
            "shading": self.shading, "traversal": r.traversal, "split_rays": r.split_rays or 0,
            "mrays": r.mrays, "hit_fraction": r.hit_fraction, "tests_per_ray": r.tests_per_ray,
            "cells_per_ray": r.cells_per_ray, "grid": b.grid, "top_density": self.top_density,
            "leaf_density": self.leaf_density, "bytes_per_tri": self._total("grid_bytes") / max(self.triangles, 1),
            "lights": r.lights, "shadow_rays_per_pixel": r.shadow_rays_per_pixel, "shade_ms": r.shade_ms,
            "compiled": int(self.compiled),
        }
        for k, v in parts.items():  # the strategy's own stages (count_ms, bucket_ms, merge_ms, ...)
            row.setdefault(k, v)
        row["frame_ms"] = self.frame_ms
        return row
