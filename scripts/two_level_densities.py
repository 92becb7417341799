"""BENCHMARKS.md section 14, "Densities": per scene and grid density (a uniform grid, or a
two-level grid's top and leaf density), the build ms of the part rebuilt every frame, the DDA and
CGT render ms and the DDA's triangle tests a ray.

    .venv/bin/python scripts/two_level_densities.py

makes the table (512x512, 2 threads, the counting build strategy, 1 untimed and 3 timed frames,
medians); ``--size 16 --runs 1 --warmup 0`` is a quick check.  Each configuration is a FrameSpec
(``gridrt.app.bench.frame.frame_spec``: the scene followed through its own camera, Lambert
shading, ``bench frame``'s time step) rendered frame by frame by ``FramePipeline.from_spec``,
all configurations of a scene round-robin, frame by frame, as ``bench frame`` does: the kitchen
with its static/moving split (its moving part rebuilt every frame), the robots rebuilt whole.
The build ms is the median over both traversals' timed frames.
"""

import argparse
from fractions import Fraction

import numpy as np

import gridrt  # noqa: F401  (sets NUMBA_NUM_THREADS before numba loads)
from gridrt.app.bench.frame import frame_spec
from gridrt.app.bench.output import md_table
from gridrt.app.bench.scenes import resolve_scene
from gridrt.config import GridParams, RenderParams
from gridrt.errors import InputError
from gridrt.frame import FrameSpec, ViewSpec
from gridrt.pipeline import FramePipeline

from tables import add_out_option, keep_output, print_settings

#: the table's scenes, each with its static/moving split on or off (section 14)
SCENES = "kitchen:on,robots:off"
#: the table's grids: uniform, or a two-level grid's top density, leaf density
DENSITIES = "uniform,1/16:1,1/16:2,1/8:2,1/4:4"
SIZE, THREADS, STRATEGY, RUNS, WARMUP = 512, 2, "counting", 3, 1
#: what the script does not let an option change
FIXED = ("Lambert shading, the scene's own camera, the rest FrameSpec's defaults; "
         "medians of the timed frames")
HEADER = ["scene", "top, leaf density", "build ms", "DDA ms", "CGT ms", "tests/ray DDA"]


def grid_of(text):
    """(label, GridParams) of a --densities item: "uniform", or "TOP:LEAF" (fractions allowed)."""
    if text == "uniform":
        return text, GridParams(grid="uniform")
    try:
        top, leaf = (Fraction(x) for x in text.split(":"))
    except ValueError:
        raise InputError(f"--densities: {text!r} is neither uniform nor TOP:LEAF") from None
    return f"{top}, {leaf}", GridParams(grid="two_level", top_density=float(top), leaf_density=float(leaf))


def scene_rows(text, split, grids, a):
    """The table's rows of one scene (its spec text, split on or off) over ``grids``
    [(label, GridParams)]."""
    sc = resolve_scene(text)
    base = FrameSpec(render=RenderParams(shading="lambert"), view=ViewSpec(follow_camera=True)).resized(a.size, a.size)
    specs = [frame_spec(base.replace(grid=gp), sc.spec, (a.threads, tr, split, gp.grid), a.strategy)
             for _label, gp in grids for tr in ("dda", "cgt")]
    pipes = [FramePipeline.from_spec(s, sc.scene) for s in specs]
    frames = [[] for _ in specs]
    for i in range(a.warmup + a.runs):
        for pipe, got in zip(pipes, frames):
            st = pipe.step(base.view.time(i)).stats
            if i >= a.warmup:
                got.append(st)
    rows = []
    for k, (label, _gp) in enumerate(grids):
        dda, cgt = frames[2 * k], frames[2 * k + 1]
        med = lambda smp, key: float(np.median([s[key] for s in smp]))  # noqa: E731
        rows.append([f"{text} ({'split' if split else 'no split'})", label, f"{med(dda + cgt, 'build_ms'):.1f}",
                     f"{med(dda, 'render_ms'):.1f}", f"{med(cgt, 'render_ms'):.1f}", f"{med(dda, 'tests_per_ray'):.1f}"])
    return rows


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--scenes", default=SCENES,
                   help="comma-separated SPEC:on|off, a bench scene spec and its static/moving split (default: the "
                        "table's, %(default)s)")
    p.add_argument("--densities", default=DENSITIES, help="comma-separated grids: uniform or TOP:LEAF two-level "
                   "densities (default: the table's, %(default)s)")
    p.add_argument("--size", type=int, default=SIZE, help=f"size x size image (default {SIZE}, the table's)")
    p.add_argument("--threads", type=int, default=THREADS,
                   help=f"build and render threads (default {THREADS}, the table's)")
    p.add_argument("--strategy", default=STRATEGY, help=f"build strategy (default {STRATEGY}, the table's)")
    p.add_argument("--runs", type=int, default=RUNS, help=f"timed frames, medians (default {RUNS}, the table's)")
    p.add_argument("--warmup", type=int, default=WARMUP, help=f"untimed frames first (default {WARMUP}, the table's)")
    add_out_option(p)
    a = p.parse_args(argv)
    keep_output(a.out)
    scenes = [s.strip().rsplit(":", 1) for s in a.scenes.split(",") if s.strip()]
    if any(len(s) != 2 or s[1] not in ("on", "off") for s in scenes):
        p.error(f"--scenes: each item is SPEC:on or SPEC:off, got {a.scenes!r}")
    grids = [grid_of(x.strip()) for x in a.densities.split(",") if x.strip()]
    print_settings(p, a)
    print(f"fixed: {FIXED}")
    print()
    rows = []
    for text, split in scenes:
        rows += scene_rows(text, split == "on", grids, a)
    print("\n".join(md_table(HEADER, rows)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
