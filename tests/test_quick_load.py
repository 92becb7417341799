"""A gridrt kernel loaded from numba's on-disk cache skips numba's full context refresh
(gridrt.compiles): checked in fresh processes, the first of which compiles into a cache folder and
the second of which loads from it, each result against numpy or plain Python.

numba's full refresh imports numba.np.linalg (among its extensions' registries) and nothing on
these paths does otherwise, so its absence from sys.modules after a load tells the two paths apart.
"""

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]

# A kernel that hashes strings (a set of the numbers written out), in a module named as gridrt's:
# its machine code reads the hash secret numba registers only when numba.cpython.hashing is imported.
PROBE = '''
import numpy as np
from numba import njit


@njit(cache=True)
def distinct(a):
    seen = set()
    for x in a:
        seen.add(str(x))
    return len(seen)
'''

# Run in a fresh process: loads (or compiles) the kernels, reports their results and how they came.
SCRIPT = '''
import importlib.util, json, sys
import numpy as np
points = np.load(sys.argv[1])
spec = importlib.util.spec_from_file_location("gridrt.quick_load_probe", sys.argv[2])
probe = sys.modules[spec.name] = importlib.util.module_from_spec(spec)
spec.loader.exec_module(probe)
from gridrt.grid.common import bounds_f64, point_bounds
lo, hi, bad = point_bounds(points)
n = probe.distinct(np.floor(points[:, 0] * 10).astype(np.int64))
out = {"lo": lo.tolist(), "hi": hi.tolist(), "bad": bool(bad), "distinct": int(n),
       "hits": [bounds_f64.stats.cache_hits[s] for s in bounds_f64.signatures]
               + [probe.distinct.stats.cache_hits[s] for s in probe.distinct.signatures],
       "refreshed": "numba.np.linalg" in sys.modules}
if len(sys.argv) > 3:
    # a compile after the quick load: numba's full refresh runs first (it registers np.cumsum)
    from numba import njit
    last = njit(lambda a: np.cumsum(a)[-1])
    out["cumsum"] = float(last(np.arange(1.0, 101.0)))
    out["refreshed_after_compile"] = "numba.np.linalg" in sys.modules
print(json.dumps(out))
'''


def _run(tmp_path, *extra):
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"), PYTHONPATH=str(REPO))
    proc = subprocess.run([sys.executable, "-c", SCRIPT, str(tmp_path / "points.npy"), str(tmp_path / "probe.py"),
                           *extra], capture_output=True, text=True, env=env, cwd=tmp_path, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return json.loads(proc.stdout.strip().splitlines()[-1])


@pytest.mark.slow  # (a fresh process loading a cache it fills first)
def test_a_cached_gridrt_kernel_loads_without_numbas_full_refresh(tmp_path):
    rng = np.random.default_rng(7)
    points = rng.normal(size=(5000, 3)) * [1.0, 20.0, 300.0] + [5.0, -7.0, 1e4]
    np.save(tmp_path / "points.npy", points)
    (tmp_path / "probe.py").write_text(textwrap.dedent(PROBE))
    want_distinct = len(set(np.floor(points[:, 0] * 10).astype(np.int64).tolist()))

    first = _run(tmp_path)                      # compiles both kernels into the cache folder
    assert first["hits"] == [0, 0] and first["refreshed"]
    second = _run(tmp_path, "compile")          # a fresh process: both load from the cache
    for got in (first, second):
        assert got["lo"] == points.min(axis=0).tolist() and got["hi"] == points.max(axis=0).tolist()
        assert got["bad"] is False
        assert got["distinct"] == want_distinct
    assert second["hits"] == [1, 1], "a kernel compiled again instead of loading from the cache"
    assert not second["refreshed"], "a gridrt kernel's cache load ran numba's full refresh"
    assert second["cumsum"] == 5050.0 and second["refreshed_after_compile"]


def test_a_cached_function_outside_gridrt_loads_as_numba_loads_it(tmp_path):
    rng = np.random.default_rng(8)
    np.save(tmp_path / "points.npy", rng.normal(size=(100, 3)))
    script = textwrap.dedent('''
        import sys
        import numpy as np
        import gridrt  # noqa: F401  (the quick load is installed)
        sys.path.insert(0, sys.argv[1])
        import user_kernels
        print(user_kernels.total(np.arange(10.0)), user_kernels.total.stats.cache_hits[user_kernels.total.signatures[0]],
              "numba.np.linalg" in sys.modules)
    ''')
    (tmp_path / "user_kernels.py").write_text("from numba import njit\n\n\n@njit(cache=True)\ndef total(a):\n"
                                              "    return a.sum()\n")
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"), PYTHONPATH=str(REPO))
    outs = []
    for _ in range(2):
        proc = subprocess.run([sys.executable, "-c", script, str(tmp_path)], capture_output=True, text=True,
                              env=env, cwd=tmp_path, timeout=600)
        assert proc.returncode == 0, proc.stderr[-3000:]
        outs.append(proc.stdout.split())
    assert outs[0] == ["45.0", "0", "True"]
    assert outs[1] == ["45.0", "1", "True"], "a user's cached function did not load through numba's own path"
