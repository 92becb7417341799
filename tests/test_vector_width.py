"""Vector width of the compiled kernels (gridrt.threads.wide_vector_features, GRIDRT_VECTOR_WIDTH).

On a CPU with AVX-512F, gridrt lets LLVM use 512-bit registers (LLVM's tuning for these cores
otherwise prefers 256-bit ones); on an AVX2-only CPU nothing changes.  Checked on the generated
code itself: the float32 packet test (cgt._test_wt32) is compiled in a fresh process with a
fresh numba cache (inspection is not available for code loaded from the cache), and its machine
code must use zmm packed-single arithmetic with the default width on an AVX-512 CPU, and only
ymm (no zmm packed-single) with GRIDRT_VECTOR_WIDTH=256, on Intel cores (whose LLVM tuning
prefers 256-bit vectors anyway) and AMD's Zen 4 (whose tuning does not) alike.  The single-ray
traversal's side-by-side cell test is checked the same way, on packed-double arithmetic.
"""

import json
import os
import subprocess
import sys

import pytest

from gridrt.threads import VECTOR_WIDTHS, wide_vector_features


def _host_features():
    import llvmlite.binding as ll

    ll.initialize_native_target()
    return ll.get_host_cpu_features().flatten()


AVX512 = "+avx512f" in _host_features().split(",")
#: the widths whose generated code is checked, each a fresh compile in a process of its own: these
#: checks are in the slow set (.ci/run runs it); the quick run keeps the features' check
WIDTHS = ["auto", "256"]


def test_features_for_each_width():
    host = _host_features()
    assert wide_vector_features("256") == (host + ",+prefer-256-bit" if AVX512 else None)
    for w in ("auto", "512"):
        f = wide_vector_features(w)
        if AVX512:
            assert f == host + ",-prefer-256-bit"
        else:
            assert f is None
    with pytest.warns(UserWarning, match="GRIDRT_VECTOR_WIDTH"):
        assert wide_vector_features("1024") == wide_vector_features("auto")
    assert VECTOR_WIDTHS == ("auto", "512", "256")


_PROBE = r"""
import json, re
import numpy as np
import gridrt
from numba.core import config
from gridrt.trace import cgt
S = np.zeros(cgt.NS * cgt.PN)
S32 = S[cgt.O_F32:].view(np.float32)
I32 = S[cgt.O_F32:].view(np.int32)
q = [np.float32(x) for x in range(9)]
cgt._test_wt32(S32, I32, 40, tuple(q[0:3]), tuple(q[3:6]), tuple(q[6:9]), np.int32(1), np.float32(0.0))
asm = cgt._test_wt32.inspect_asm(cgt._test_wt32.signatures[0])
ops = re.findall(r"^\s+(v(?:sub|mul|add)ps)\s+([^\n]*)", asm, re.M)
print(json.dumps({"features": config.CPU_FEATURES or "", "zmm_ps": sum("zmm" in a for _, a in ops),
                  "ymm_ps": sum("ymm" in a and "zmm" not in a for _, a in ops)}))
"""


def _run_probe(tmp_path, width, src, warm=None):
    """The JSON line a probe ``src`` prints, run in a fresh process with GRIDRT_VECTOR_WIDTH=width
    and a fresh numba cache (inspection is not available for code loaded from the cache), into
    which a process running ``warm`` first has cached what it compiles."""
    env = {k: v for k, v in os.environ.items() if k not in ("NUMBA_CPU_FEATURES", "NUMBA_CACHE_DIR")}
    env.update(GRIDRT_VECTOR_WIDTH=width, NUMBA_CACHE_DIR=str(tmp_path / "cache"))
    if warm is not None:
        out = subprocess.run([sys.executable, "-c", warm], env=env, capture_output=True, text=True, timeout=600)
        assert out.returncode == 0, out.stderr[-2000:]
    out = subprocess.run([sys.executable, "-c", src], env=env, capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-2000:]
    return json.loads(out.stdout.strip().splitlines()[-1])


@pytest.mark.slow
@pytest.mark.parametrize("width", WIDTHS)
def test_generated_code_width(tmp_path, width):
    r = _run_probe(tmp_path, width, _PROBE)
    print(width, r["zmm_ps"], "zmm packed-single ops,", r["ymm_ps"], "ymm")
    if width == "auto" and AVX512:
        assert r["features"].endswith("-prefer-256-bit")
        assert r["zmm_ps"] >= 30, "the float32 packet test does not use 512-bit registers"
    else:
        assert r["zmm_ps"] == 0 and r["ymm_ps"] >= 30, "the float32 packet test is not 8-wide ymm code"


_PROBE_SINGLE = r"""
import json, re
import numpy as np
import gridrt
from numba import njit
from numba.core import config
from gridrt.config import GridParams
from gridrt.grid import build_grid
from gridrt.trace.grids import grid_arrays
from gridrt.trace.traverse import SCRATCH, trace_ray

@njit
def one(g, mb):
    return trace_ray(g, (0.1, 0.2, -1.0), (0.0, 0.0, 1.0), 0.0, np.inf, True, False, mb)

tris = np.random.default_rng(0).uniform(0, 1, (50, 3, 3)).astype(np.float32)
g = grid_arrays(build_grid(tris, GridParams(density=0.2)), tris)
one(g, np.empty(SCRATCH, np.int32))
asm = one.overloads[one.signatures[0]].library.get_asm_str()
ops = re.findall(r"^\s+(v(?:sub|mul|div)pd)\s+([^\n]*)", asm, re.M)
print(json.dumps({"features": config.CPU_FEATURES or "", "zmm_pd": sum("zmm" in a for _, a in ops),
                  "ymm_pd": sum("ymm" in a and "zmm" not in a for _, a in ops)}))
"""


_PROBE_ALL_HITS = r"""
import json, re
import numpy as np
import gridrt
from numba import njit
from gridrt.trace import all_hits as ah
from gridrt.trace.intersect import ray_shear

@njit
def one(tris, pend, rows, buf):
    sh = ray_shear((0.1, 0.2, -1.0), (0.0, 0.0, 1.0))
    return ah._test_lanes(tris, pend, np.int64(ah.LANES), rows, sh, 0.0, np.inf, np.int64(0), buf)

tris = np.random.default_rng(0).uniform(0, 1, (50, 3, 3)).astype(np.float32)
buf = ah.HitBuffers(np.empty(50), np.empty(50, np.int32), np.empty(50), np.empty(50))
one(tris, np.arange(ah.LANES, dtype=np.int32), np.zeros(ah.LANE_ROWS * ah.LANES), buf)
asm = one.overloads[one.signatures[0]].library.get_asm_str()
ops = re.findall(r"^\s+(v(?:sub|mul|add)pd)\s+([^\n]*)", asm, re.M)
print(json.dumps({"zmm_pd": sum("zmm" in a for _, a in ops),
                  "ymm_pd": sum("ymm" in a and "zmm" not in a for _, a in ops)}))
"""


@pytest.mark.slow
@pytest.mark.parametrize("width", WIDTHS)
@pytest.mark.parametrize("what", ["the single-ray cell test", "the all-hits lane test"])
def test_packed_double_width(tmp_path, width, what):
    """Two loops test triangles side by side in float64 lanes: the single-ray traversal's crowded
    cells (gridrt.trace.traverse._test_cell_wt, compiled in trace_ray) and the all-hits walk's
    collected triangles (gridrt.trace.all_hits._test_lanes).  In a fresh process and cache, the
    compiled code of each holds packed-double arithmetic, in zmm registers with the default width
    on an AVX-512 CPU and in ymm ones with GRIDRT_VECTOR_WIDTH=256 (scalar code has none)."""
    r = _run_probe(tmp_path, width, _PROBE_SINGLE if what.startswith("the single") else _PROBE_ALL_HITS)
    print(what, width, r["zmm_pd"], "zmm packed-double ops,", r["ymm_pd"], "ymm")
    if width == "auto" and AVX512:
        assert r["zmm_pd"] >= 20, f"{what} does not use 512-bit registers"
    else:
        assert r["zmm_pd"] == 0 and r["ymm_pd"] >= 20, f"{what} is not 4-wide ymm code"


_WARM_CAMERA = r"""
import gridrt
from gridrt.camera import Camera
Camera().rays(8, 6)
"""

_PROBE_SHADE = r"""
import json, re
import numpy as np
import gridrt
from numba.core import config
from gridrt.camera import Camera
from gridrt.trace.material import shade_rows, surface_arrays
from gridrt.trace.records import HitPoints, make_view

tris = np.random.default_rng(0).uniform(0, 1, (50, 3, 3)).astype(np.float32)
view = make_view(Camera(eye=(0.5, 0.5, 3.0), target=(0.5, 0.5, 0.5)).basis(), 40, 30, 8)
ibuf = np.zeros((30, 40), np.int32)
lights = np.array([[0.0, 2.0, 2.0, 2.0, 1.0, 1.0, 1.0, 0.0]])
e64, e32 = np.empty((0, 3)), np.empty((0, 3), np.float32)
shade_rows(view, ibuf, surface_arrays(tris, None, None), lights, False, np.zeros((30, 40, 4), np.uint8),
           HitPoints(e64, e64, e32, e32, e32), np.zeros(1, np.int64))
asm = shade_rows.inspect_asm(shade_rows.signatures[0])
ops = re.findall(r"^\s+(v(?:sub|mul|div|sqrt)pd)\s+([^\n]*)", asm, re.M)
print(json.dumps({"features": config.CPU_FEATURES or "", "zmm_pd": sum("zmm" in a for _, a in ops),
                  "ymm_pd": sum("ymm" in a and "zmm" not in a for _, a in ops),
                  "div_sqrt": sum(o in ("vdivpd", "vsqrtpd") for o, _ in ops)}))
"""


@pytest.mark.slow
@pytest.mark.parametrize("width", WIDTHS)
def test_material_pass_width(tmp_path, width):
    """The material pass shades LANES hits side by side (gridrt.trace.material._surface_lanes,
    _texel_lanes, _shade_lanes): its compiled code (shade_rows, in a fresh process and cache)
    holds packed-double arithmetic, divisions and square roots included, in zmm registers with
    the default width on an AVX-512 CPU and in ymm ones with GRIDRT_VECTOR_WIDTH=256 (a pixel at
    a time has none).  As in a frame, the camera's rays are in the cache before the pass compiles:
    a kernel loaded from the cache is machine code, which LLVM cannot inline into the lanes' loop."""
    r = _run_probe(tmp_path, width, _PROBE_SHADE, warm=_WARM_CAMERA)
    print(width, r["zmm_pd"], "zmm packed-double ops,", r["ymm_pd"], "ymm,", r["div_sqrt"], "divisions and roots")
    assert r["div_sqrt"] >= 6, "the material pass divides and takes roots a hit at a time"
    if width == "auto" and AVX512:
        assert r["zmm_pd"] >= 100, "the material pass does not use 512-bit registers"
    else:
        assert r["zmm_pd"] == 0 and r["ymm_pd"] >= 100, "the material pass is not 4-wide ymm code"


_PROBE_BUILD = r"""
import json, re
import numpy as np
import gridrt
from gridrt.grid import common
common.scene_bounds_serial(np.zeros((100, 3, 3), np.float32), np.empty((1, 7)))
common.macro_build_range(np.zeros((1, 512), np.int32), np.array([8, 8, 8]), 4, np.array([2, 2, 2]),
                         np.zeros(8, np.uint8), 0, 2)
def ops(f):
    asm = f.overloads[f.signatures[0]].library.get_asm_str()
    return [(o, "zmm" in a or "ymm" in a) for o, a in re.findall(r"^\s+(v\w+)\s+([^\n]*)", asm, re.M)]
b, m = ops(common.scene_bounds_serial), ops(common.macro_build_range)
print(json.dumps({"bounds_ps": sum(w for o, w in b if re.fullmatch(r"v(?:min|max|blendv|blendm|cmp\w*)ps", o)),
                  "macro_or": sum(w for o, w in m if re.fullmatch(r"vpor[dq]?", o))}))
"""


@pytest.mark.slow
def test_build_passes_width(tmp_path):
    """Two passes of every build are vector code when compiled without parallel=True (the
    serial strategy's and every small scene's): the bounds lanes (gridrt.grid.common
    ._bounds_lanes: packed-single minima and maxima, or the compares and selects that make them)
    and the macro
    pass's row of ORs (macro_build_range: packed integer ORs).  Before, with Python's min and
    max and a scan of each macro cell's cells, both compiled to scalar code (about 3x slower);
    the bounds kernel then held 24 packed compares or selects (outside the lanes' loop) against
    84 now.  At 256 bits on every CPU, so that the counts compare across them."""
    r = _run_probe(tmp_path, "256", _PROBE_BUILD)
    print(r)
    assert r["bounds_ps"] >= 48, "the bounds lanes' loop is scalar code"
    assert r["macro_or"] >= 2, "the macro pass's ORs are scalar code"
