"""Arguments shared by the subcommands, and their conversion into engine objects."""

import argparse
import re
import warnings
from dataclasses import fields

import gridrt  # noqa: F401  (sets NUMBA_NUM_THREADS before numba loads)
from gridrt.config import (
    AUTO_STRATEGY, GRID_KINDS, INSERT_MODES, MAX_LIGHT_SAMPLES, PACKET_MAX, PACKET_PRECISIONS, PARALLEL_DEFAULT_STRATEGY,
    SHADING_MODES, TRAVERSALS, GridParams, RenderParams,
)
from gridrt.frame import FrameSpec, ViewSpec
from gridrt.pipeline import FramePipeline
from gridrt.scene import DEFORM_KINDS, scene_choices
from gridrt.scene.deform import DEFAULT_AMPLITUDE_FRACTION
from gridrt.scene.spec import SceneSpec
from gridrt.threads import MAX_THREADS, warn_more_threads_than_cores


#: The help of each option that several commands take (view, dump and the benchmarks): the one text
#: every parser shows for it (tests/test_names_and_help.py checks them all).  ``--help`` appends the
#: default; a command whose default the help cannot show (None: "all cores") or that explains its own
#: says it after the text, and a benchmark that measures several values side by side adds
#: :data:`SEVERAL` (:func:`option_help`).
OPTION_HELP = {
    "--strategy": f"grid build strategy: one of `gridrt strategies`, or {AUTO_STRATEGY} (serial at 1 thread, "
                  f"{PARALLEL_DEFAULT_STRATEGY} above, built by serial, the same grid, while it compiles on a "
                  "cold cache)",
    "--threads": f"threads for build and render, 1..{MAX_THREADS}",
    "--lambda": "grid density: cells ~ lambda x triangles",
    "--macro": "macro-cell edge in cells",
    "--grid": "grid kind: one uniform grid, a two-level grid (a coarse grid whose non-empty cells hold grids of their "
              "own) or auto (two_level when the triangles crowd into few top cells)",
    "--top-density": "two-level grid: top cells per triangle",
    "--leaf-density": "two-level grid: leaf cells per reference (triangle) of a top cell",
    "--insert": "triangle insertion test: bounding box (fast) or exact SAT (fewer references)",
    "--shading": "auto (material for a scene with materials, textures, vertex colours or smooth normals, else lambert), material (the "
                 "scene's materials, textures, smooth normals and lights), lambert (one colour; a headlight, or the "
                 "point light when shadows are on), normal (geometric normals as colours) or cost (a heat map of "
                 "triangle tests per ray)",
    "--shadows": "hard shadows: towards the point light (lambert) or each of the scene's lights (material)",
    "--light-samples": f"material shadows: 0 casts a ray towards every light (exact); K (1..{MAX_LIGHT_SAMPLES}) "
                       "casts K a pixel, towards lights drawn by their light there (faster, noisy in shadows; the "
                       "viewer averages draws while the view is still, towards the exact image)",
    "--traversal": "ray traversal: single-ray 3D DDA, or coherent grid traversal of ray packets (cgt; same image, "
                   "faster)",
    "--packet": f"CGT packet size in pixels, N or WxH, each 1..{PACKET_MAX}",
    "--packet-precision": "precision of the CGT packets' triangle tests: float64 (the DDA's hits bit for bit) or "
                          "float32 (twice the lanes; hits agree up to float32 rounding)",
    "--dt": "time step between frames, seconds",
    "--export": "also write the rays, meshes and frames the benchmark casts in the native Embree harness's folder "
                "format here, one folder per scene (bench peers: per scene and camera view, SCENE_frame and "
                "SCENE_fill), for the harness's own `native.py run FOLDER`",
    "--export-only": "only write the folders (into --export), measure nothing",
    "--no-helper": "compile in this process alone; without it, on an empty numba cache and two cores or more, a "
                   "helper process compiles the first frame's ray casting while this one builds its grid",
}


#: what the help of a shared option adds where a benchmark takes several values of it
SEVERAL = "; several, comma-separated, are measured side by side"


def option_help(option, default=None, several=False):
    """The help of a shared option (:data:`OPTION_HELP`): with :data:`SEVERAL` where the command
    takes several values (a benchmark), and ``default`` (words) after it where the command's default
    is one ``--help`` cannot show (None) or explains."""
    return OPTION_HELP[option] + (SEVERAL if several else "") + (f" (default: {default})" if default else "")


#: a value argparse would take for an option: one or more comma-separated numbers starting with a
#: minus sign ("-0.02,0.1,0", "-1e6")
_NEGATIVE_VALUE = re.compile(r"-(\d+\.?\d*|\.\d+)(e[-+]?\d+)?(,\s*[-+]?(\d+\.?\d*|\.\d+)(e[-+]?\d+)?)*", re.I)


def join_negative_values(argv):
    """``argv`` with each ``--option VALUE`` whose VALUE is numbers starting with a minus sign
    written ``--option=VALUE``: argparse takes "-0.02,0.1,0" for an option and "-1e6" too."""
    out = []
    for tok in argv:
        if out and out[-1].startswith("--") and "=" not in out[-1] and _NEGATIVE_VALUE.fullmatch(tok):
            out[-1] = f"{out[-1]}={tok}"
        else:
            out.append(tok)
    return out


def vec3(text):
    try:
        parts = [float(x) for x in text.split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected X,Y,Z (three numbers), got {text!r}") from None
    if len(parts) != 3:
        raise argparse.ArgumentTypeError(f"expected X,Y,Z (three numbers), got {text!r}")
    return tuple(parts)


def size(text):
    try:
        w, h = (int(x) for x in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT, e.g. 1024x768, got {text!r}") from None
    if w < 1 or h < 1:
        raise argparse.ArgumentTypeError(f"image size must be positive, got {text!r}")
    return w, h


def defaults(cls):
    """The field defaults of a settings dataclass (GridParams, RenderParams, SceneSpec), read
    without constructing one (construction validates, which would load the strategy registry)."""
    return {f.name: f.default for f in fields(cls)}


def add_scene_args(p):
    g = p.add_argument_group("scene")
    d = defaults(SceneSpec)
    g.add_argument("--scene", default=d["source"], help=scene_choices())
    g.add_argument("--count", type=int, default=d["count"],
                   help="triangles of the marbles and icosphere scenes (default: 8800 for marbles, 5120 for the "
                        "icosphere; marbles scale past 1M)")
    g.add_argument("--animate", choices=DEFORM_KINDS, default=d["animate"],
                   help="deform a static mesh over time (default: none)")
    g.add_argument("--amplitude", type=float, default=d["amplitude"],
                   help=f"deformation amplitude in scene units (default: {100 * DEFAULT_AMPLITUDE_FRACTION:g}%% of the "
                        "mesh's bounding-box diagonal)")
    g.add_argument("--speed", type=float, default=d["speed"], help="animation speed factor")
    g.add_argument("--seed", type=int, default=d["seed"], help="random seed of procedural scenes")
    g.add_argument("--clip", default=d["clip"],
                   help="animation clip to play: glTF animation or MD2 clip, by name or index (default: a glTF's "
                        "animations together when they do not overlap, else its first; all of an MD2's frames)")
    g.add_argument("--subdivide", type=int, default=d["subdivide"],
                   help="split a static mesh's triangles 1->4 until at least this many (e.g. Lucy 100k -> 1.6M; "
                        "default: none)")
    g.add_argument("--fps", type=float, default=d["fps"],
                   help="keyframe rate of MD2 models and frame folders (default: 10 for MD2, 30 for frames)")
    g.add_argument("--allow-outside-refs", dest="allow_outside", action="store_true",
                   help="trust the files a scene file names (glTF buffers and images, OBJ materials and textures, "
                        "BART includes and textures, MD2 skins) outside the scene file's folder, symlinks followed "
                        "(default: refused; a material or texture outside is left out with a warning)")


def add_grid_args(p):
    d = defaults(GridParams)
    g = p.add_argument_group("grid")
    g.add_argument("--strategy", default=d["strategy"], help=option_help("--strategy"))
    g.add_argument("--threads", type=int, default=d["threads"], help=option_help("--threads", "all cores"))
    g.add_argument("--lambda", dest="density", type=float, default=d["density"], help=option_help("--lambda"))
    g.add_argument("--macro", type=int, default=d["macro"], help=option_help("--macro"))
    g.add_argument("--grid", choices=GRID_KINDS, default=d["grid"], help=option_help("--grid"))
    add_density_args(g)
    g.add_argument("--insert", choices=INSERT_MODES, default=d["insert"], help=option_help("--insert"))
    g.add_argument("--max-cells", type=int, default=d["max_cells"],
                   help=f"ceiling on grid cells (default {d['max_cells']})")
    g.add_argument("--no-split", dest="split_static", action="store_false",
                   help="rebuild the whole scene every frame (default: grid static parts once, moving parts per frame)")


def add_density_args(g):
    """--top-density and --leaf-density (GridParams.top_density, leaf_density: a two-level grid's)
    on the parser or argument group g."""
    d = defaults(GridParams)
    g.add_argument("--top-density", type=float, default=d["top_density"], help=option_help("--top-density"))
    g.add_argument("--leaf-density", type=float, default=d["leaf_density"], help=option_help("--leaf-density"))


def add_render_args(p):
    d = defaults(RenderParams)  # shadows off and the watertight test: the two switches below change them
    g = p.add_argument_group("render")
    g.add_argument("--size", type=size, default=(d["width"], d["height"]), help="image size WIDTHxHEIGHT")
    g.add_argument("--shading", choices=SHADING_MODES, default=d["shading"], help=option_help("--shading"))
    g.add_argument("--shadows", action="store_true", help=option_help("--shadows"))
    g.add_argument("--light-samples", type=int, default=d["light_samples"], metavar="K",
                   help=option_help("--light-samples", "0, every light"))
    g.add_argument("--light", type=vec3, default=d["light"],
                   help="point light X,Y,Z (default: above and behind the camera; in the material mode it replaces "
                        "the scene's lights)")
    g.add_argument("--fast-intersect", action="store_true",
                   help="Moller-Trumbore instead of the watertight test (faster, may leak at edges)")
    g.add_argument("--traversal", choices=TRAVERSALS, default=d["traversal"], help=option_help("--traversal"))
    add_packet_args(g)
    g.add_argument("--eye", type=vec3, default=None,
                   help="camera position X,Y,Z, with --target (default: a camera that frames the scene)")
    g.add_argument("--target", type=vec3, default=None,
                   help="camera look-at point X,Y,Z, with --eye (default: the centre of the scene)")
    c = defaults(ViewSpec)
    g.add_argument("--up", type=vec3, default=c["up"],
                   help=f"camera up vector X,Y,Z (default {','.join(f'{x:g}' for x in c['up'])})")
    g.add_argument("--fov", type=float, default=c["fov"],
                   help=f"vertical field of view in degrees (default {c['fov']:g})")
    g.add_argument("--follow-camera", action="store_true",
                   help="look through the scene's own animated camera (BART, glTF) where it has one, also with "
                        "--eye/--target (default: the scene's camera unless --eye/--target or --no-scene-camera)")
    g.add_argument("--no-scene-camera", dest="scene_camera", action="store_false",
                   help="use a camera that frames the scene, not the scene's own camera (BART, glTF: the default "
                        "where the scene has one and no --eye/--target is given); in the viewer the panel's "
                        "\"scene camera\" box or the C key switches it")


def add_packet_args(g):
    """--packet and --packet-precision (RenderParams.packet, packet_precision) on the parser or
    argument group g."""
    d = defaults(RenderParams)
    g.add_argument("--packet", default="x".join(map(str, d["packet"])), help=option_help("--packet"))
    g.add_argument("--packet-precision", choices=PACKET_PRECISIONS, default=d["packet_precision"],
                   help=option_help("--packet-precision"))


def scene_spec(a):
    """The SceneSpec of the parsed scene arguments."""
    return SceneSpec(source=a.scene, count=a.count, animate=a.animate, amplitude=a.amplitude, speed=a.speed,
                     seed=a.seed, clip=a.clip, subdivide=a.subdivide, fps=a.fps, allow_outside=a.allow_outside)


def scene_from_args(a):
    return scene_spec(a).make()


def grid_params(a):
    return GridParams(strategy=a.strategy, density=a.density, macro=a.macro, insert=a.insert, threads=a.threads,
                      max_cells=a.max_cells, grid=a.grid, top_density=a.top_density, leaf_density=a.leaf_density)


def render_params(a):
    w, h = a.size
    rp = RenderParams(width=w, height=h, shading=a.shading, shadows=a.shadows, light=a.light,
                      watertight=not a.fast_intersect, threads=a.threads, traversal=a.traversal, packet=a.packet,
                      packet_precision=a.packet_precision, light_samples=a.light_samples)
    if rp.light_samples and not rp.shadows:
        warnings.warn(f"--light-samples {rp.light_samples} draws the lights of shadow rays: it has no effect until "
                      "shadows are on (--shadows)")
    return rp


def follows_scene_camera(a):
    """Whether the parsed arguments look through the scene's own camera (where it has one):
    --follow-camera, or neither --eye/--target nor --no-scene-camera."""
    return bool(a.follow_camera) or (bool(getattr(a, "scene_camera", True)) and a.eye is None and a.target is None)


def view_spec(a):
    """The ViewSpec of the parsed arguments: camera (--eye/--target, --fov, --up, --follow-camera),
    --no-split, --size, and a dump's --t0 and --dt (a command without them has the defaults)."""
    d = defaults(ViewSpec)
    return ViewSpec(eye=a.eye, target=a.target, fov=a.fov, up=a.up, follow_camera=follows_scene_camera(a),
                    split_static=a.split_static, t0=getattr(a, "t0", d["t0"]), dt=getattr(a, "dt", d["dt"]),
                    size=tuple(a.size))


def frame_spec(a):
    """The FrameSpec of the parsed arguments: what the command renders (the one conversion of the
    scene, grid, render and view arguments into engine values; each part validated).  More
    --threads than cores is warned about (once)."""
    warn_more_threads_than_cores(a.threads)
    return FrameSpec(scene=scene_spec(a), grid=grid_params(a), render=render_params(a), view=view_spec(a))


def camera_from_args(a):
    """An explicit camera when --eye/--target are given, else None (the pipeline frames the
    scene with --fov and --up)."""
    return view_spec(a).camera()


def pipeline_from_args(a, scene=None):
    """The FramePipeline of the parsed arguments (:func:`frame_spec`); ``scene``: the scene,
    when already loaded."""
    return FramePipeline.from_spec(frame_spec(a), scene=scene)
