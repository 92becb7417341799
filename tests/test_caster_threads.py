"""One RayCaster shared by Python threads: casts and updates from any number
of threads, no crash, and every cast sees one whole mesh (before or after a concurrent update).

The stress runs in a subprocess (a crash, which is what two threads updating one caster without its
snapshot swap would cause, is then a failed test with its exit code, not a dead test run): 4 threads cast and 2 update, for a
few seconds, alternating the caster between meshes A and B (same faces, different vertices, far
from the world origin so their frames differ too).  Each cast is compared as a whole with the
float64 brute-force reference of A and of B; it must agree with one of them on every ray.  The
rays are chosen so that the two references differ on a large share of them: a cast against a
mix (A's grid with B's triangles or frame, part of the rays on each) matches neither.
"""

import json
import os
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np

from reference import compare_hits, ref_cast

REPO = Path(__file__).resolve().parents[1]
#: world offset of both meshes: the caster's frame (the mesh's centre) moves between A and B
OFFSET = np.array([1000.0, -250.0, 40.0])


def meshes():
    """(A, B, faces, origins, dirs): two vertex sets of one icosphere and 1500 rays through it."""
    from conftest import icosphere

    v, f = icosphere(3)
    v = v.astype(np.float64)
    a = v + OFFSET
    b = v * np.array([1.25, 0.8, 1.1]) + OFFSET + np.array([0.15, -0.1, 0.05])
    rng = np.random.default_rng(12)
    o = rng.normal(size=(1500, 3))
    o = o / np.linalg.norm(o, axis=1, keepdims=True) * 3.0
    d = -o + rng.normal(scale=0.5, size=o.shape)
    return a, b, f, o + OFFSET, d


def reference(v, f, o, d):
    """Brute-force hits of the mesh (v, f): float64, over the triangles as float32 stores them in
    a frame centred on their bounds (the caster's documented frame), the rays moved alike."""
    c = 0.5 * (v.min(axis=0) + v.max(axis=0))
    return ref_cast((v - c)[f], o - c, d)


def _agrees(h, ref):
    return len(compare_hits(h.t, h.tri, ref).bad) == 0


def stress(seconds, casters=4, updaters=2, min_casts=40):
    """Run the threads on one caster; return a summary dict (also what the subprocess prints).
    Each updater runs for ``seconds`` and at least 14 rounds (12 updates, 2 refused), each caster
    until then and for at least its share of ``min_casts``: the counts the checks ask for do not
    depend on the machine's speed or load."""
    import numba

    import gridrt

    a, b, f, o, d = meshes()
    refs = {"A": reference(a, f, o, d), "B": reference(b, f, o, d)}
    differ = int((refs["A"].tri != refs["B"].tri).sum())
    caster = gridrt.RayCaster(a, f)
    single = {}
    for name, verts in (("B", b), ("A", a)):
        caster.update(verts)
        single[name] = _agrees(caster.cast(o, d), refs[name])
    out = dict(casts=0, saw_A=0, saw_B=0, matched_neither=0, updates=0, refused_updates=0, errors=[],
               differ=differ, rays=len(o), single_threaded_ok=single)
    lock = threading.Lock()
    stop = time.perf_counter() + seconds
    bad_update = np.zeros_like(a)  # all triangles degenerate: refused, the caster keeps its mesh

    def note(key, n=1):
        with lock:
            out[key] += n

    updating = [updaters]

    def cast_loop(k):
        i = 0
        while time.perf_counter() < stop or i < -(-min_casts // casters) or updating[0] > 0:
            i += 1
            try:
                h = caster.cast(o, d, threads=1 + (i + k) % 2)
            except Exception as e:  # noqa: BLE001 (any error at all fails the test)
                with lock:
                    out["errors"].append(f"cast: {type(e).__name__}: {e}")
                continue
            ok_a, ok_b = _agrees(h, refs["A"]), _agrees(h, refs["B"])
            note("casts")
            note("saw_A" if ok_a else "saw_B" if ok_b else "matched_neither")

    def update_loop(k):
        i = 0
        while time.perf_counter() < stop or i < 14:
            i += 1
            try:
                if i % 7 == 0:
                    try:
                        caster.update(bad_update)
                    except gridrt.InputError:
                        note("refused_updates")
                    continue
                caster.update(a if (i + k) % 2 else b)
                note("updates")
            except Exception as e:  # noqa: BLE001
                with lock:
                    out["errors"].append(f"update: {type(e).__name__}: {e}")
        with lock:
            updating[0] -= 1

    threads = [threading.Thread(target=cast_loop, args=(k,)) for k in range(casters)]
    threads += [threading.Thread(target=update_loop, args=(k,)) for k in range(updaters)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    out["threading_layer"] = numba.threading_layer()
    return out


def run_stress(seconds, env_extra=None, timeout=300, min_casts=40):
    env = dict(os.environ)
    env.update(env_extra or {})
    env["PYTHONPATH"] = os.pathsep.join([str(REPO), str(REPO / "tests"), env.get("PYTHONPATH", "")])
    code = (f"import json, test_caster_threads as t; "
            f"print('RESULT', json.dumps(t.stress({seconds}, min_casts={min_casts})))")
    r = subprocess.run([sys.executable, "-c", code], cwd=REPO, env=env, capture_output=True, text=True, timeout=timeout)
    lines = [ln for ln in r.stdout.splitlines() if ln.startswith("RESULT ")]
    assert r.returncode == 0 and lines, f"exit code {r.returncode}: {r.stdout[-1000:]} {r.stderr[-2000:]}"
    return json.loads(lines[-1][len("RESULT "):])


def check_summary(s, min_casts):
    assert s["single_threaded_ok"] == {"A": True, "B": True}, s
    # the two meshes are told apart on a large share of the rays, so a mix cannot pass as one
    assert s["differ"] > s["rays"] // 4, s
    assert not s["errors"], s["errors"][:5]
    assert s["matched_neither"] == 0, s
    assert s["casts"] >= min_casts and s["updates"] >= 10 and s["refused_updates"] >= 1, s
    assert s["saw_A"] > 0 and s["saw_B"] > 0, s


def test_threads_share_one_caster():
    """4 casting and 2 updating threads for 3 s (omp layer): no crash, no error, every cast is A
    or B as a whole."""
    s = run_stress(3.0)
    print(f"FIGURE threads: {s['casts']} casts ({s['saw_A']} saw A, {s['saw_B']} saw B, {s['matched_neither']} "
          f"neither), {s['updates']} updates + {s['refused_updates']} refused, layer {s['threading_layer']}, "
          f"{s['differ']} of {s['rays']} rays tell A from B")
    check_summary(s, min_casts=40)


def test_threads_share_one_caster_workqueue():
    """The same under numba's workqueue layer (the fallback without libgomp), which aborts the
    process when two threads launch parallel kernels at once: the caster serialises its launches."""
    s = run_stress(1.5, {"NUMBA_THREADING_LAYER": "workqueue"}, min_casts=10)
    print(f"FIGURE threads (workqueue): {s['casts']} casts, {s['updates']} updates, layer {s['threading_layer']}")
    assert s["threading_layer"] == "workqueue", s
    check_summary(s, min_casts=10)
