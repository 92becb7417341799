"""Animated characters filling the frame, with their materials and shadows: BENCHMARKS.md section
15, table "scene | triangles | threads | shading | frame ms | fps | build ms | trace ms | material
pass ms | hit | shadow rays/px".

    .venv/bin/python scripts/character_frame.py

Each skinned or keyframed character (Cesium Man's glTF skin; the MD2 models) is looked at from
its own camera moved towards its target until at least 90% of a probe image hits it at t = 0
(gridrt.app.bench.scenes.fill_camera), then held there.  The frame pipeline renders SIZE x SIZE
(SIZE 1024) frames through that camera with the CGT traversal, stepping through the animation
(t = k / 30 s for the k-th frame), in three modes whose pipelines take each frame in turns:
``lambert``, ``material`` (the character's materials, textures, smooth normals and its lights or
the default light) and ``material`` with hard shadows of each light.  Every frame animates the
mesh and rebuilds its grid.  Figures are medians over ``--runs`` frames after ``--warmup``, at each
thread count (the process pinned to as many cores): frame ms is the whole step (animation, grid,
render: FrameStats frame_ms), build ms the grid's, trace ms the render without its material pass,
material pass ms that pass with its shadow rays (shade_ms).
"""

import argparse

import numpy as np

import gridrt  # noqa: F401  (sets NUMBA_NUM_THREADS before numba loads)
from gridrt.app.bench.affinity import Affinity
from gridrt.app.bench.scenes import fill_camera, resolve_scene, scene_camera
from gridrt.config import GridParams, RenderParams
from gridrt.frame import FrameSpec, ViewSpec
from gridrt.pipeline import FramePipeline
from gridrt.trace.twin import TWINS
from tables import add_out_option, items, print_table, start

SCENES = "cesium_man,sydney,faerie"
MODES = (("lambert", False), ("material", False), ("material", True))
HEADER = ["scene", "triangles", "threads", "shading", "frame ms", "fps", "build ms", "trace ms", "material pass ms",
          "hit", "shadow rays/px"]


def parse_args(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--scenes", default=SCENES, help="comma-separated animated bench scenes (default: the table's, "
                   "%(default)s)")
    p.add_argument("--size", type=int, default=1024, help="square image edge (default: the table's, %(default)s)")
    p.add_argument("--threads", default="1,2", help="thread counts (default: the table's, %(default)s)")
    p.add_argument("--runs", type=int, default=15, help="timed frames, the median kept (default: the table's, 15)")
    p.add_argument("--warmup", type=int, default=2, help="untimed frames first (default: the table's, 2)")
    add_out_option(p)
    return start(p, argv)


def filled_view(sc, size):
    """The ViewSpec of the scene's camera moved in until the character fills the view at t = 0."""
    origin = sc.scene.frame_origin(0.0)
    tris = np.array(sc.scene.triangles_at(0.0, origin=origin))
    cam = fill_camera(tris, scene_camera(sc.scene, tris, origin=origin))
    eye, target = np.asarray(cam.eye) + origin, np.asarray(cam.target) + origin
    return ViewSpec(eye=tuple(eye), target=tuple(target), fov=cam.fov, up=tuple(cam.up))


def measure(a):
    rows = []
    for name in items(a.scenes):
        sc = resolve_scene(name)
        view = filled_view(sc, a.size)
        for T in (int(x) for x in items(a.threads)):
            with Affinity(T):
                pipes = {}
                for mode, shadows in MODES:
                    spec = FrameSpec(scene=sc.spec, grid=GridParams(threads=T), view=view,
                                     render=RenderParams(shading=mode, shadows=shadows, threads=T))
                    pipes[mode, shadows] = FramePipeline.from_spec(spec.resized(a.size, a.size), sc.scene)
                for p in pipes.values():  # (compiles)
                    p.step(0.0)
                TWINS.wait()
                got = {k: [] for k in pipes}
                for f in range(a.warmup + a.runs):
                    for k, p in pipes.items():  # in turns, each at the same time of the animation
                        st = p.step(f / 30.0).stats
                        if f >= a.warmup:
                            got[k].append((st["frame_ms"], st["build_ms"], st["render_ms"] - st["shade_ms"],
                                           st["shade_ms"], st["hit_fraction"], st["shadow_rays_per_pixel"] or 0.0))
                for (mode, shadows), v in got.items():
                    frame, build, trace, shade, hit, rays = np.median(np.array(v), axis=0)
                    label = mode + (" + shadows" if shadows else "")
                    rows.append([sc.label, f"{sc.scene.n_triangles:,}", str(T), label, f"{frame:.1f}",
                                 f"{1e3 / frame:.1f}", f"{build:.2f}", f"{trace:.1f}", f"{shade:.1f}", f"{hit:.2f}",
                                 f"{rays:.2f}"])
                    print(f"# {sc.label} T={T} {label}: frame {frame:.1f} ms ({1e3 / frame:.1f} fps), build "
                          f"{build:.2f}, trace {trace:.1f}, material pass {shade:.1f} ms; hit {hit:.2f}", flush=True)
    return rows


def main(argv=None):
    return print_table(HEADER, measure, parse_args(argv))


if __name__ == "__main__":
    raise SystemExit(main())
