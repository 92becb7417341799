"""The float32 floor: BENCHMARKS.md section 8, table "D / teapot size | median edge in float32
steps | hit/miss flips | median rel. t error".

    .venv/bin/python scripts/float32_floor.py

The Utah teapot centred at x = -D/2 and one small triangle at x = +D/2 (so the frame, centred on
the bounds, is about D across and the teapot sits about D/2 from its centre), rendered through
``FramePipeline`` (CGT, 160x120, a camera on the teapot moved with it) for each D, against a
float64 brute force over the teapot alone at offset 0 (gridrt.app.bench.reference.brute_cast) on
the same pixels' rays.  "steps"
is the teapot's median edge in float32 steps of the largest coordinate in the frame
(gridrt.precision.detail_steps).  Nothing here is timed.
"""

import argparse
import warnings

import numpy as np

import gridrt  # noqa: F401  (sets NUMBA_NUM_THREADS before numba loads)
from gridrt.app.bench.reference import brute_cast, pixel_rays
from gridrt.app.bench.scenes import data_path
from gridrt.config import GridParams, RenderParams
from gridrt.frame import FrameSpec, ViewSpec
from gridrt.pipeline import FramePipeline
from gridrt.precision import PrecisionWarning, detail_steps
from gridrt.scene import Mesh, StaticMesh, load_mesh
from tables import add_out_option, keep_output

#: the table's ratios D / teapot size
RATIOS = "10,100,1000,10000,100000,300000,1000000,10000000"
#: the direction the camera looks at the teapot from (as tests/test_far_origin.py)
VIEW_DIR = np.array([0.55, 0.45, 1.0])


def parse_args():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--ratios", default=RATIOS, help=f"comma-separated D / teapot size (default: the table's, {RATIOS})")
    p.add_argument("--size", default="160x120", help="image WxH (default: the table's, 160x120)")
    add_out_option(p)
    return p.parse_args()


def scene_at(v, f, D):
    """The teapot (v, f) moved by ``teapot_offset(v, D)``, with one triangle a tenth of its size at
    x = +D/2."""
    lo, hi = v.min(axis=0), v.max(axis=0)
    s = float((hi - lo).max())
    x = 0.5 * D
    far = np.array([[x, 0.0, 0.0], [x, 0.1 * s, 0.0], [x, 0.0, 0.1 * s]])
    fv = np.concatenate([v + teapot_offset(v, D), far])
    ff = np.concatenate([f, np.array([[len(v), len(v) + 1, len(v) + 2]])])
    return StaticMesh(Mesh(fv, ff))


def teapot_offset(v, D):
    """The translation putting the centre of the teapot's bounds at x = -D/2."""
    return np.array([-0.5 * D, 0.0, 0.0]) - 0.5 * (v.min(axis=0) + v.max(axis=0))


def row(v, f, ratio, W, H, ref):
    """(steps, flips, median relative t error) of the teapot rendered D = ratio x its size away."""
    lo, hi = v.min(axis=0), v.max(axis=0)
    D = ratio * float((hi - lo).max())
    eye, target = (p + teapot_offset(v, D) for p in view_of(lo, hi))
    spec = FrameSpec(render=RenderParams(traversal="cgt"), grid=GridParams(),
                     view=ViewSpec(eye=tuple(eye), target=tuple(target))).resized(W, H)
    scene = scene_at(v, f, D)
    pipe = FramePipeline.from_spec(spec, scene)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", PrecisionWarning)
        frame = pipe.step(0.0)
    tris = np.asarray(scene.triangles_at(0.0, origin=pipe.origin))
    # the teapot's own median edge (float64, at offset 0) against the largest coordinate in the frame
    _, big, _ = detail_steps(tris)
    _, _, steps = detail_steps(v[f], big=big)
    t = frame.t.reshape(-1).astype(np.float64)
    hit = frame.tri.reshape(-1) >= 0
    ref_t, ref_tri, _ = ref
    ref_hit = ref_tri >= 0
    flips = int((hit != ref_hit).sum())
    both = hit & ref_hit
    rel = float(np.median(np.abs(t[both] - ref_t[both]) / ref_t[both]))
    return steps, flips, rel


def view_of(lo, hi, dist=1.3):
    c = 0.5 * (lo + hi)
    return c + VIEW_DIR / np.linalg.norm(VIEW_DIR) * dist * float(np.linalg.norm(hi - lo)), c


def main():
    a = parse_args()
    keep_output(a.out)
    W, H = (int(x) for x in a.size.lower().split("x"))
    ratios = [float(x) for x in a.ratios.split(",") if x.strip()]
    path = data_path("teapot")
    print(f"# scene: {path} (gridrt.app.bench.scenes.data_path('teapot')) at x = -D/2 + one triangle at x = +D/2")
    print(f"# image: {W}x{H} ({'--size' if a.size != '160x120' else 'default, the table'}'s); "
          f"ratios: {', '.join(f'{r:g}' for r in ratios)} ({'--ratios' if a.ratios != RATIOS else 'default, the table'}'s)")
    print("# render: FramePipeline.from_spec, FrameSpec with RenderParams(traversal='cgt'), engine defaults otherwise")
    m = load_mesh(str(path))
    v, f = m.vertices64, m.faces.astype(np.int64)
    eye, target = view_of(v.min(axis=0), v.max(axis=0))
    ys, xs = np.divmod(np.arange(W * H), W)
    o, d = pixel_rays(eye, target, ViewSpec().up, ViewSpec().fov, W, H, xs, ys)
    ref = brute_cast(v[f], o, d)
    n = W * H
    print()
    print("| D / teapot size | median edge in float32 steps | hit/miss flips | median rel. t error |")
    print("|---|---|---|---|")
    for ratio in ratios:
        steps, flips, rel = row(v, f, ratio, W, H, ref)
        st = f"{steps:,.0f}" if steps >= 10 else f"{steps:.2g}"
        pct = 100 * flips / n
        fl = f"{flips}" if flips == 0 else f"{flips} ({pct:.2f} %)" if pct < 1 else f"{flips} ({pct:.2g} %)"
        print(f"| {ratio:,.0f} | {st} | {fl} | {rel:.1e} |", flush=True)


if __name__ == "__main__":
    main()
