"""``gridrt bench looks``: what the scenes' own looks cost a frame.

Per scene and thread count, the frame pipeline renders the same frame (t = 0, the scene's own
camera where it has one, else a camera framing the scene) with ``lambert`` shading, ``material``
shading (materials, textures, smooth normals, the scene's lights) and ``material`` with hard
shadows, at 1024x1024 with the CGT traversal.  The three are timed in turns (warm-up first, then
``runs`` rounds of one frame each), so that load falls on all alike; render ms is the render
including the material pass and its shadow rays (FrameStats render_ms), median [min-max].  The
memory the looks take is reported per scene: texels and their bytes, the surface's bytes per
triangle (material index and per-corner uv, colours and normals) and the per-frame normal buffer
of an animated scene.
"""

import numpy as np

import gridrt  # noqa: F401
from gridrt.config import TRAVERSALS, GridParams, RenderParams
from gridrt.frame import FrameSpec, ViewSpec
from gridrt.pipeline import FramePipeline

from ..cli import defaults, option_help
from .machine import finish_machine, machine_info
from .options import check_runs, thread_list
from .output import md_table, out_dir, progress, write_csv, write_json, write_summary
from .scenes import resolve_scene, scene_list
from .stats import fmt_ms, put_stat

LOOKS_SCENES = ["kitchen", "cesium", "tokyo"]
LOOKS_FALLBACK = ["cesium_man", "museum"]
MODES = (("lambert", False), ("material", False), ("material", True))


def add_parser(bsub, common):
    p = bsub.add_parser("looks", help="render ms with material shading, textures and shadows against lambert",
                        description=__doc__.split("\n\n")[0])
    common(p, "looks", runs=5, warmup=2, scenes=(LOOKS_SCENES, LOOKS_FALLBACK))
    p.add_argument("--size", type=int, default=1024, help="square image edge (default 1024)")
    p.add_argument("--threads", default="1,2", help=option_help("--threads", several=True))
    p.add_argument("--traversal", choices=sorted(TRAVERSALS), default=defaults(RenderParams)["traversal"],
                   help=option_help("--traversal"))
    p.set_defaults(func=run_looks)


def _label(mode, shadows):
    return mode + (" + shadows" if shadows else "")


def memory(scene):
    """The looks' memory of a scene: texture count, texels, texture bytes, surface bytes per triangle,
    the per-frame normal buffer's bytes per triangle (animated scenes with normals)."""
    s = scene.surface
    if s is None:
        return dict(textures=0, texels=0, texture_bytes=0, surface_bytes_per_tri=0, normal_buffer_bytes_per_tri=0)
    texels = sum(t.texels.shape[0] * t.texels.shape[1] for t in s.textures)
    animated_normals = s.normals is not None and not scene.static
    return dict(textures=len(s.textures), texels=texels, texture_bytes=s.texture_bytes,
                surface_bytes_per_tri=s.bytes_per_triangle, normal_buffer_bytes_per_tri=36 if animated_normals else 0)


def looks_spec(scene, size, threads, traversal, mode, shadows):
    """The FrameSpec of one ``bench looks`` configuration: the SceneSpec ``scene`` through its own
    camera (followed), gridded and rendered on ``threads`` threads with ``traversal``, shading
    ``mode`` with or without ``shadows``, at size x size (every other setting the engine's
    default)."""
    return FrameSpec(scene=scene, grid=GridParams(threads=threads),
                     render=RenderParams(shading=mode, shadows=shadows, threads=threads, traversal=traversal),
                     view=ViewSpec(follow_camera=True)).resized(size, size)


def measure(sc, size, threads, runs, warmup, traversal):
    """Rows (one per mode) of one scene at one thread count: each mode's FrameSpec (:func:`looks_spec`,
    frame 0) rendered by its pipeline."""
    pipes = {}
    for mode, shadows in MODES:
        spec = looks_spec(sc.spec, size, threads, traversal, mode, shadows)
        pipes[(mode, shadows)] = FramePipeline.from_spec(spec, sc.scene)
    for _ in range(warmup):
        for p in pipes.values():
            p.step(0.0)
    times = {k: [] for k in pipes}
    shade = {k: [] for k in pipes}
    last = {}
    for _ in range(runs):
        for k, p in pipes.items():  # in turns
            fr = p.step(0.0)
            times[k].append(fr.stats["render_ms"])
            shade[k].append(fr.stats["shade_ms"])
            last[k] = fr.stats
    mem = memory(sc.scene)
    rows = []
    base = float(np.median(times[("lambert", False)]))
    for (mode, shadows), ts in times.items():
        st = last[(mode, shadows)]
        row = dict(scene=sc.label, triangles=sc.scene.n_triangles, threads=threads, size=size, traversal=traversal,
                   shading=_label(mode, shadows), lights=st["lights"], hit_fraction=st["hit_fraction"],
                   shadow_rays_per_pixel=st["shadow_rays_per_pixel"], **mem)
        put_stat(row, "render_ms", ts)
        put_stat(row, "shade_ms", shade[(mode, shadows)])
        row["vs_lambert"] = row["render_ms"] / base
        rows.append(row)
    return rows


def run_looks(a):
    check_runs(a.runs, a.warmup)
    size = 64 if a.quick else a.size
    runs, warmup = (1, 1) if a.quick else (a.runs, a.warmup)
    threads = thread_list(a.threads)
    specs, note = scene_list(a.scenes, LOOKS_SCENES, LOOKS_FALLBACK, quick=["cesium_man"] if a.quick else None)
    if note:
        print(f"note: {note}")
    out = out_dir(a.out)
    info = machine_info(threads, probe=not a.quick)
    scenes = [resolve_scene(s) for s in specs]
    bar = progress(len(scenes) * len(threads), "bench looks", a.no_progress)
    rows = []
    for sc in scenes:
        for th in threads:
            rows.extend(measure(sc, size, th, runs, warmup, a.traversal))
            bar.update()
    bar.close()
    info = finish_machine(info)
    write_csv(rows, out / "looks.csv")
    write_json(info, out / "machine.json")
    table = [[r["scene"], f"{r['triangles']:,}", r["threads"], r["shading"], fmt_ms(r, "render_ms"),
              fmt_ms(r, "shade_ms"), f"{r['vs_lambert']:.2f}x", r["lights"], f"{r['shadow_rays_per_pixel']:.2f}",
              f"{r['hit_fraction']:.2f}"] for r in rows]
    mem = []
    seen = set()
    for r in rows:
        if r["scene"] in seen:
            continue
        seen.add(r["scene"])
        mem.append([r["scene"], r["textures"], f"{r['texels']:,}", f"{r['texture_bytes'] / 2**20:.1f} MiB",
                    f"{r['texture_bytes'] / max(r['texels'], 1):.0f}", r["surface_bytes_per_tri"],
                    r["normal_buffer_bytes_per_tri"]])
    body = [f"{size}x{size}, {a.traversal} traversal, frame t = 0 through the scene's camera (else a framing one); "
            f"{warmup} warm-up + {runs} timed rounds, the modes in turns; render ms median [min-max] (the material "
            "pass and its shadow rays included; shade ms is that part).", "",
            *md_table(["scene", "triangles", "threads", "shading", "render ms", "shade ms", "vs lambert", "lights",
                       "shadow rays/px", "hit"], table), "",
            "Memory of the looks: textures (RGB, bytes per texel), the surface's bytes per triangle (material "
            "index and per-corner uv, colours, normals present) and an animated scene's per-frame normal buffer.",
            "", *md_table(["scene", "textures", "texels", "texture bytes", "bytes/texel", "surface bytes/tri",
                           "normal buffer bytes/tri"], mem)]
    write_summary(out / "summary.md", "What the scenes' looks cost", info, [("Render", body)])
    for r in rows:
        print(f"{r['scene']} {r['threads']}t {r['shading']}: {fmt_ms(r, 'render_ms')} ms ({r['vs_lambert']:.2f}x "
              f"lambert), shade {r['shade_ms']:.1f} ms, {r['lights']} lights, {r['shadow_rays_per_pixel']:.2f} "
              "shadow rays/px")
    print(f"wrote {out}/looks.csv, summary.md, machine.json")
    return 0
