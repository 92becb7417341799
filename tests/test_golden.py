"""64x64 renders compared with golden images in tests/golden/*.png.

The golden PNGs are produced by the *independent* brute-force reference renderer
(``reference.ref_render``: float64 Moller-Trumbore over all triangles, the camera model and the
shading formulas re-typed from the documentation), never by the engine.  To regenerate them
after a deliberate change of the documented camera or shading::

    .venv/bin/python -m pytest tests/test_golden.py --update-golden

which rewrites every golden from ``ref_render`` and then runs the comparisons as usual.  A
missing golden fails the test with that instruction.

Tolerance: at most 0.5% of the pixels may differ by more than 2/255 in some channel (pixels on
silhouettes and edges where float rounding picks the other triangle); the golden must also still
match a fresh ``ref_render`` within the same tolerance (a stale golden fails).
"""

from pathlib import Path

import numpy as np
import pytest
from PIL import Image

import reference as R
from conftest import icosphere_tris, random_triangles
from gridrt.camera import Camera
from gridrt.config import RenderParams
from gridrt.grid import GridParams, build_grid
from gridrt.trace import render

GOLDEN = Path(__file__).resolve().parent / "golden"
SIZE = 64
MAX_FRACTION = 0.005
TOL = 2


def scene_sphere_on_floor():
    sphere = icosphere_tris(2, radius=0.8, center=(0.0, 0.8, 0.0))
    floor = np.array(
        [[[-2, 0, -2], [2, 0, 2], [2, 0, -2]], [[-2, 0, -2], [-2, 0, 2], [2, 0, 2]]], np.float32
    )
    tris = np.concatenate([sphere, floor]).astype(np.float32)
    cam = Camera(eye=(2.2, 2.0, 3.4), target=(0.0, 0.5, 0.0), up=(0, 1, 0), fov=45.0)
    return tris, cam


def scene_random():
    tris = random_triangles(np.random.default_rng(99), 40, size=0.3)
    cam = Camera(eye=(0.5, 0.6, 3.0), target=(0.5, 0.5, 0.5), up=(0, 1, 0), fov=40.0)
    return tris, cam


# name -> (scene function, shading, light or None)
CASES = {
    "sphere_lambert": (scene_sphere_on_floor, "lambert", None),
    "sphere_normal": (scene_sphere_on_floor, "normal", None),
    "sphere_shadows": (scene_sphere_on_floor, "lambert", (1.5, 4.0, 1.0)),
    "random_lambert": (scene_random, "lambert", None),
    "random_normal": (scene_random, "normal", None),
}


def reference_image(name):
    fn, shading, light = CASES[name]
    tris, cam = fn()
    offset = None
    if light is not None:
        # the engine offsets shadow rays by 1e-6 * grid diagonal along the facing normal
        v = tris.reshape(-1, 3).astype(np.float64)
        offset = 1e-6 * np.linalg.norm(v.max(0) - v.min(0))
    return R.ref_render(tris, cam, SIZE, SIZE, shading, light=light, shadow_offset=offset).image


def differing(a, b):
    """Number of pixels whose largest channel difference exceeds TOL."""
    return int((np.abs(a.astype(int) - b.astype(int)).max(axis=2) > TOL).sum())


@pytest.mark.parametrize("name", list(CASES))
def test_render_matches_golden(name, update_golden, tmp_path):
    path = GOLDEN / f"{name}.png"
    if update_golden:
        GOLDEN.mkdir(exist_ok=True)
        Image.fromarray(reference_image(name), "RGBA").save(path)
    if not path.is_file():
        pytest.fail(
            f"golden image {path} is missing; generate it from the reference renderer with "
            f"`pytest tests/test_golden.py --update-golden`"
        )
    golden = np.asarray(Image.open(path).convert("RGBA"))
    assert golden.shape == (SIZE, SIZE, 4)

    fn, shading, light = CASES[name]
    tris, cam = fn()
    grid = build_grid(tris, GridParams(density=4.0, macro=2))
    params = RenderParams(width=SIZE, height=SIZE, shading=shading, shadows=light is not None, light=light, traversal="dda")
    img = render(grid, tris, cam, params).image
    assert img.shape == (SIZE, SIZE, 4) and img.dtype == np.uint8
    n = differing(img, golden)
    limit = MAX_FRACTION * SIZE * SIZE
    if n > limit:
        Image.fromarray(img, "RGBA").save(tmp_path / f"{name}_engine.png")
    assert n <= limit, (
        f"{name}: {n} of {SIZE * SIZE} pixels differ from {path.name} by more than {TOL}/255 "
        f"(limit {limit:.0f}); engine image saved as {tmp_path / (name + '_engine.png')}"
    )

    # the golden is what the reference renders today (no stale goldens)
    assert differing(reference_image(name), golden) <= limit, f"{path.name} is stale: rerun with --update-golden"


def test_goldens_are_not_trivial():
    """Each golden shows geometry (not only background) and the shading modes differ."""
    imgs = {}
    for name in CASES:
        p = GOLDEN / f"{name}.png"
        if not p.is_file():
            pytest.fail(f"golden image {p} is missing; run `pytest tests/test_golden.py --update-golden`")
        imgs[name] = np.asarray(Image.open(p).convert("RGBA"))
        bg = R.to_u8(R.BACKGROUND)
        geom = (imgs[name][:, :, :3] != bg).any(axis=2).mean()
        assert 0.05 < geom < 0.999, f"{name}: {geom:.1%} of pixels show geometry"
    assert differing(imgs["sphere_lambert"], imgs["sphere_normal"]) > 1000
    assert differing(imgs["sphere_lambert"], imgs["sphere_shadows"]) > 50
