"""Shadow rays as packets against SHADOW_MAX_CELLS and SHADOW_SORTED_MAX_CELLS: BENCHMARKS.md section
15, table "scene | lights | shadow rays/px | single rays (0) | 4 | 8 | 16 | 32 | 64 | sorted 8 | sorted 16
| sorted 64" (the material pass's ms a frame).

    .venv/bin/python scripts/shadow_max_cells.py

For each scene, the frame pipeline renders frames at t = 0.5, 0.5 + 1/30, ... with ``material``
shading and hard shadows of every light (the scene's own camera, size WxH, the CGT traversal,
``--threads`` threads), once for each value N of ``gridrt.trace.render.SHADOW_MAX_CELLS``: the
material pass's shadow rays go to the batch caster tile by tile, and a run of them is traced as a
packet when its bounds cover at most N cells in the widest slice it crosses (0: every shadow ray
on its own); the rays pass 1 leaves are sorted and traced as packets of at most
SHADOW_SORTED_MAX_CELLS cells, at its default.  Then once for each value N of ``--sorted``
("sorted N"): SHADOW_SORTED_MAX_CELLS at N, SHADOW_MAX_CELLS at its default.  The values are set
on the module between frames (the material pass reads them at each frame; no kernel reads them).
The settings take turns frame by frame, so that load falls on all alike; a cell is the median shade
ms (FrameStats shade_ms: the material pass with its shadow rays) of ``--frames`` frames after one
untimed round.  Every setting renders the same image: the script checks that the frames' pixels
are equal.
"""

import argparse
import importlib

import numpy as np

import gridrt  # noqa: F401  (sets NUMBA_NUM_THREADS before numba loads)
from gridrt.pipeline import FramePipeline
from gridrt.app.bench.looks import looks_spec
from gridrt.app.bench.output import md_table
from gridrt.app.bench.scenes import resolve_scene
from tables import add_out_option, items, start

#: the module whose SHADOW_MAX_CELLS the material pass reads (gridrt.trace names its render function
#: render, so the module is imported by its full name)
RENDER = importlib.import_module("gridrt.trace.render")
SCENES = "kitchen,robots,tokyo,museum,cesium_man"
VALUES = "0,4,8,16,32,64"
SORTED = "8,16,64"
DEFAULTS = dict(size="1024x768", frames=9, threads=2)
HEADER = ["scene", "lights", "shadow rays/px"]


def parse_args(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--scenes", default=SCENES, help=f"scene names, comma-separated (default: the table's, {SCENES})")
    p.add_argument("--values", default=VALUES, help=f"SHADOW_MAX_CELLS values (default: the table's, {VALUES})")
    p.add_argument("--sorted", default=SORTED,
                   help=f"SHADOW_SORTED_MAX_CELLS values, '' for none (default: the table's, {SORTED})")
    p.add_argument("--size", default=DEFAULTS["size"], help="WxH (default: the table's, 1024x768)")
    p.add_argument("--frames", type=int, default=DEFAULTS["frames"], help="timed frames a cell (default: the table's, 9)")
    p.add_argument("--threads", type=int, default=DEFAULTS["threads"], help="threads (default: the table's, 2)")
    add_out_option(p)
    return start(p, argv)


def measure(sc, settings, w, h, frames, threads):
    """(lights, shadow rays a pixel, {setting: median shade ms}) of one scene; each setting a pair
    (SHADOW_MAX_CELLS, SHADOW_SORTED_MAX_CELLS) set on the render module."""
    spec = looks_spec(sc.spec, w, threads, "cgt", "material", True).resized(w, h)
    pipe = FramePipeline.from_spec(spec, sc.scene)
    ms = {v: [] for v in settings}
    first = {}
    saved = RENDER.SHADOW_MAX_CELLS, RENDER.SHADOW_SORTED_MAX_CELLS
    try:
        for k in range(frames + 1):  # round 0 untimed (compiles, buffers grow)
            t = 0.5 + k / 30.0
            for v in settings:
                RENDER.SHADOW_MAX_CELLS, RENDER.SHADOW_SORTED_MAX_CELLS = v
                fr = pipe.step(t)
                st, img = fr.stats, np.array(fr.image)
                ref = first.setdefault(k, img)
                if not np.array_equal(img, ref):
                    raise SystemExit(f"{sc.label}: SHADOW_MAX_CELLS, SHADOW_SORTED_MAX_CELLS={v} renders another "
                                     f"image at t = {t:g}")
                if k > 0:
                    ms[v].append(st["shade_ms"])
    finally:
        RENDER.SHADOW_MAX_CELLS, RENDER.SHADOW_SORTED_MAX_CELLS = saved
    return st["lights"], st["shadow_rays_per_pixel"], {v: float(np.median(x)) for v, x in ms.items()}


def main(argv=None):
    a = parse_args(argv)
    firsts, sorts = [float(v) for v in items(a.values)], [float(v) for v in items(a.sorted)]
    settings = ([(v, RENDER.SHADOW_SORTED_MAX_CELLS) for v in firsts]
                + [(RENDER.SHADOW_MAX_CELLS, v) for v in sorts])
    labels = ["single rays (0)" if v == 0 else f"{v:g}" for v in firsts] + [f"sorted {v:g}" for v in sorts]
    w, h = (int(x) for x in a.size.lower().split("x"))
    rows = []
    for name in items(a.scenes):
        sc = resolve_scene(name)
        lights, per_px, ms = measure(sc, list(dict.fromkeys(settings)), w, h, a.frames, a.threads)
        rows.append([name, str(lights), f"{per_px:.2f}", *(f"{ms[v]:.0f}" for v in settings)])
        print(f"# {name} done", flush=True)
    print("\n".join(md_table(HEADER + labels, rows)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
