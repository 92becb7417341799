"""Packet size and precision: BENCHMARKS.md section 12, table "packet | Lucy 100k [fill] | Lucy
100k [frame] | icosphere 1.3M [fill] | icosphere 1.3M [frame] | geometric mean against 8x8
float64" (render ms, float64 / float32).

    .venv/bin/python scripts/packet_size_precision.py

For each scene and view (``bench packets``' configuration: gridrt.app.bench.packets.packet_spec,
one thread, CGT in 16-pixel tiles, the camera of gridrt.app.bench.scenes.camera_rays, the scene
at t = 0), ``Renderer.render`` with each ``RenderParams(packet=..., packet_precision=...)``: one
untimed render of each setting, then two alternating rounds of ``--renders`` renders of each,
the median of all of them.  In bold, each column's fastest float64 and float32 figures (the last
column: the fastest overall).  Also checks that the float64 images are identical across packet
sizes.
"""

import argparse
import math
import time

import numpy as np

import gridrt  # noqa: F401  (sets NUMBA_NUM_THREADS before numba loads)
from gridrt.app.bench.packets import packet_spec
from gridrt.app.bench.scenes import camera_rays, resolve_scene, seen_through
from gridrt.app.bench.stats import stat
from gridrt.config import PACKET_PRECISIONS, RenderParams
from gridrt.grid.build import GridBuilder
from gridrt.trace.render import Renderer
from tables import add_out_option, keep_output

#: the table's scenes, and their labels in it
SCENES = {"lucy:twist": "Lucy 100k", "icosphere:1310720:twist": "icosphere 1.3M"}
VIEWS = ("fill", "frame")
PACKETS = ((4, 4), (8, 8), (16, 16), (16, 8), (8, 16))
PRECISIONS = PACKET_PRECISIONS  # (float64, float32: the table's order)
ROUNDS = 2
DEFAULTS = dict(size=1024, renders=5)


def parse_args():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--size", type=int, default=DEFAULTS["size"], help="size x size images (default: the table's, 1024)")
    p.add_argument("--renders", type=int, default=DEFAULTS["renders"],
                   help=f"timed renders of each setting a round, {ROUNDS} rounds (default: the table's, 5)")
    add_out_option(p)
    return p.parse_args()


def measure(sc, view, size, renders):
    """{(packet, precision): median ms} of one scene and view, and whether the float64 images agree."""
    origin, cam, *_ = camera_rays(sc, size, fill=view == "fill")
    tris = np.ascontiguousarray(sc.scene.triangles_at(0.0, origin=origin), np.float32)
    specs = {(pk, prec): seen_through(packet_spec(sc.spec, size, prec), cam) for pk in PACKETS for prec in PRECISIONS}
    specs = {k: s.replace(render=s.render.replace(packet=k[0])) for k, s in specs.items()}
    grid = GridBuilder(next(iter(specs.values())).grid).build(tris)
    renderer = Renderer()
    images = {}
    for k, s in specs.items():  # the untimed warm-up, and the float64 images
        images[k] = renderer.render(grid, tris, s.camera(), s.render).image.copy()
    same = all(np.array_equal(images[(pk, "float64")], images[(PACKETS[0], "float64")]) for pk in PACKETS)
    times = {k: [] for k in specs}
    for _ in range(ROUNDS):
        for k, s in specs.items():
            cam_k, rp = s.camera(), s.render
            for _ in range(renders):
                t0 = time.perf_counter()
                renderer.render(grid, tris, cam_k, rp)
                times[k].append((time.perf_counter() - t0) * 1e3)
    return {k: stat(v)[0] for k, v in times.items()}, same


def bold_where_least(cells, values):
    """cells with ``**...**`` around those whose value is the least of ``values``."""
    least = min(values)
    return [f"**{c}**" if v == least else c for c, v in zip(cells, values)]


def main():
    a = parse_args()
    keep_output(a.out)
    for name in ("size", "renders"):
        given = getattr(a, name) != DEFAULTS[name]
        print(f"# {name}: {getattr(a, name)} ({'--' + name if given else 'default, the table'}'s); rounds: {ROUNDS}")
    print(f"# scenes: {', '.join(SCENES)}, views: {', '.join(VIEWS)}, packets: "
          f"{', '.join(f'{w}x{h}' for w, h in PACKETS)} (the table's); default packet: RenderParams().packet")
    cols, labels = [], []
    for spec, label in SCENES.items():
        sc = resolve_scene(spec)
        for view in VIEWS:
            ms, same = measure(sc, view, a.size, a.renders)
            print(f"# {label} [{view}]: float64 images identical across packet sizes: {'yes' if same else 'NO'}", flush=True)
            cols.append(ms)
            labels.append(f"{label} [{view}]")
    default = tuple(RenderParams().packet)
    ref = (default, "float64")
    table = {pk: [] for pk in PACKETS}
    for ms in cols:  # each column: its float64 and float32 figures, the least of each in bold
        for prec in PRECISIONS:
            cells = bold_where_least([f"{ms[(pk, prec)]:.1f}" for pk in PACKETS], [ms[(pk, prec)] for pk in PACKETS])
            for pk, c in zip(PACKETS, cells):
                table[pk].append(c)
    geo = {(pk, prec): math.exp(np.mean([math.log(ms[(pk, prec)] / ms[ref]) for ms in cols]))
           for pk in PACKETS for prec in PRECISIONS}
    keys = list(geo)
    geo_cells = dict(zip(keys, bold_where_least([f"{geo[k]:.2f}" if k != ref else "1" for k in keys],
                                                [geo[k] for k in keys])))
    print()
    print("| packet | " + " | ".join(labels) + " | geometric mean against 8x8 float64 |")
    print("|---" * (len(labels) + 2) + "|")
    for pk in PACKETS:
        name = f"{pk[0]}x{pk[1]}"
        name = f"**{name} (default)**" if pk == default else name
        pairs = [f"{table[pk][2 * i]} / {table[pk][2 * i + 1]}" for i in range(len(cols))]
        print(f"| {name} | " + " | ".join(pairs) + f" | {geo_cells[(pk, 'float64')]} / {geo_cells[(pk, 'float32')]} |")


if __name__ == "__main__":
    main()
