"""The cold start on two cores (gridrt.coldstart): the one-cell grids its helper process renders
over (gridrt.grid.one_cell), the helper's protocol, and the pipeline's hook that waits for it.

The cold dump that runs the helper for real, with the kernels each process compiled read from
the numba cache folder, is tests/test_warmup.py's cold-dump test."""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from numba import typeof

import reference as R
from gridrt import FramePipeline, FrameSpec, GridBuilder, GridParams, RenderParams, render
from gridrt.coldstart import CompileHelper, request
from gridrt.grid.one_cell import OneCellBuilder
from gridrt.scene import make_scene
from gridrt.trace import cast_rays
from gridrt.trace.grids import grid_tuple
from helpers.cgt import camera, scene
from reference import compare_hits, ref_cast

REPO = Path(__file__).resolve().parents[1]
KINDS = ("uniform", "two_level")


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("strategy", ["serial", "sort_middle", "thread_grids"])
def test_one_cell_grids_have_the_built_grids_types(kind, strategy):
    """What the ray casting kernels are given (grid_tuple) has one numba type for a built grid and
    a one-cell grid of the same kind, alone and beside a second grid (a split scene)."""
    tris = scene("icosphere")
    p = GridParams(grid=kind, strategy=strategy, threads=2)
    built = GridBuilder(p).build(tris)
    built_b = GridBuilder(p).build(tris[:10].copy())
    one = OneCellBuilder(p).build(tris)
    one_b = OneCellBuilder(p).build(tris[:10].copy())
    assert one.kind == built.kind == kind
    assert typeof(grid_tuple((one, tris, None))) == typeof(grid_tuple((built, tris, None)))
    ids = np.arange(len(tris), dtype=np.int32)
    ids_b = np.arange(10, dtype=np.int32)
    assert (typeof(grid_tuple((one, tris, ids), (one_b, tris[:10], ids_b)))
            == typeof(grid_tuple((built, tris, ids), (built_b, tris[:10], ids_b))))


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("name", ["random", "icosphere", "cubes"])
def test_one_cell_grid_finds_the_brute_force_hits(kind, name):
    """A one-cell grid is a real grid: renders (CGT and DDA) and cast rays through it agree with
    the float64 brute-force caster, and its bounds are those of the built grid."""
    tris = scene(name)
    p = GridParams(grid=kind)
    grid = OneCellBuilder(p).build(tris)
    built = GridBuilder(p).build(tris)
    np.testing.assert_array_equal(grid.spec.lo, built.spec.lo)
    np.testing.assert_array_equal(grid.spec.hi, built.spec.hi)
    assert grid.pairs().shape == (len(tris), 2)
    for view in ("framed", "inside"):
        cam = camera(view, tris)
        ref = R.ref_render(tris, cam, 33, 21, "normal")
        for traversal in ("cgt", "dda"):
            res = render(grid, tris, cam, RenderParams(width=33, height=21, tile=8, shading="normal",
                                                       traversal=traversal))
            diff = compare_hits(res.t.reshape(-1).astype(np.float64), res.tri.reshape(-1), ref.hits, t_rtol=1e-6,
                                graze_tol=1e-9)
            assert len(diff.bad) == 0, f"{name}/{kind}/{view}/{traversal}: {len(diff.bad)} pixels differ"
            assert (res.tri >= 0).any()
    rng = np.random.default_rng(5)
    o = rng.normal(size=(500, 3)) * 2.0
    d = -o + rng.normal(scale=0.5, size=(500, 3))
    hits = cast_rays(grid, tris, o, d)
    diff = compare_hits(hits.t, hits.tri, ref_cast(tris, o, d))
    assert len(diff.bad) == 0


def test_one_cell_builder_refuses_what_it_cannot_bound():
    from gridrt.errors import InputError

    tris = scene("icosphere").copy()
    tris[3, 1, 2] = np.nan
    with pytest.raises(InputError, match="NaN"):
        OneCellBuilder().build(tris)
    with pytest.raises(InputError, match="non-empty"):
        OneCellBuilder().build(np.zeros((0, 3, 3), np.float32))


class _Hook:
    def __init__(self, answer):
        self.calls = []
        self.answer = answer

    def __call__(self, kinds):
        self.calls.append(set(kinds))
        return self.answer


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("answer", [True, False])
def test_before_render_runs_once_with_the_frames_grid_kinds(kind, answer):
    """The pipeline calls its ``before_render`` in the first frame only, after the grid is built
    and before anything renders, with the frame's grid kinds; a hook that waited for kernels
    compiled elsewhere marks that frame as one that compiled."""
    spec = FrameSpec().replace(grid=GridParams(grid=kind, threads=1), render=RenderParams(threads=1)).resized(24, 16)
    pipe = FramePipeline.from_spec(spec.replace(scene=spec.scene.replace(source="icosphere")))
    pipe.step(0.0)  # (the kernels compiled or loaded: the next frames compile nothing)
    hook = _Hook(answer)
    again = FramePipeline.from_spec(spec.replace(scene=spec.scene.replace(source="icosphere")))
    seen = {}

    def check(kinds):
        seen["grid"] = again.grid  # built already
        return hook(kinds)

    again.before_render = check
    first = again.step(0.0)
    second = again.step(0.1)
    assert hook.calls == [{kind}] and seen["grid"] is not None
    assert bool(first.stats["compiled"]) is answer  # (one thread: no parallel kernel compiles beside)
    assert not second.stats["compiled"]
    np.testing.assert_array_equal(first.image, pipe.step(0.0).image)


def test_before_render_sees_both_parts_of_a_split_scene():
    """A scene whose static triangles get a grid of their own: the hook gets both grids' kinds."""
    scene_ = make_scene("marbles", count=400)
    mask = getattr(scene_, "static_mask", None)
    if mask is None or np.all(mask) or not np.any(mask):
        pytest.skip("the marbles scene has no static part to split")
    pipe = FramePipeline(scene_, GridParams(), RenderParams(width=16, height=12))
    hook = _Hook(False)
    pipe.before_render = hook
    pipe.step(0.0)
    assert pipe._split is not None and hook.calls == [{"uniform"}]


def _helper(stdin_text, timeout=600):
    return subprocess.run([sys.executable, "-m", "gridrt.coldstart"], input=stdin_text, capture_output=True,
                          text=True, cwd=REPO, timeout=timeout)


def _held(spec, env=None, preexec_fn=None, timeout=900):
    """A helper run on the request for the frame of ``spec`` at time 0 with its input held open
    until it ends, as CompileHelper does (closing it would end the helper): (exit status, standard
    output, standard error) as text."""
    p = subprocess.Popen([sys.executable, "-m", "gridrt.coldstart"], cwd=REPO, stdin=subprocess.PIPE,
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env, preexec_fn=preexec_fn)
    p.stdin.write(request(spec, 0.0))
    p.stdin.flush()
    out, err = p.stdout.read(), p.stderr.read()
    p.stdin.close()
    return p.wait(timeout=timeout), out.decode(), err.decode()


def test_helper_with_a_bad_request_ends_and_says_nothing():
    """Whatever it is given, the helper writes no traceback and no echo of its input: it ends with
    1, and the frame of its parent reports the problem itself."""
    for text in ("not json\n", json.dumps({"spec": {"format": "nope"}, "t": 0.0}) + "\n",
                 json.dumps({"spec": FrameSpec().to_wire()}) + "\n", ""):
        r = _helper(text)
        assert (r.returncode, r.stdout, r.stderr) == (1, "", ""), text


def test_helper_ends_when_its_input_closes():
    """A helper whose parent is gone (its standard input closed) ends at once with 3, compiling
    nothing more: here its input closes right after the request."""
    r = _helper(request(FrameSpec().resized(8, 6), 0.0).decode())
    assert (r.returncode, r.stderr) == (3, ""), r


def test_helper_stops_for_other_grid_kinds_and_on_one_core(monkeypatch):
    """``wait`` with a frame of another grid kind stops the helper (False) instead of waiting for
    kernels that frame would not use; one core, or a warm cache, starts none."""
    import gridrt.coldstart

    spec = FrameSpec().resized(8, 6)
    assert CompileHelper.start(spec, 0.0, cores=1) is None
    monkeypatch.setattr(gridrt.coldstart, "cache_is_cold", lambda traversal="dda": False)
    assert CompileHelper.start(spec, 0.0, cores=2) is None
    monkeypatch.setattr(gridrt.coldstart, "cache_is_cold", lambda traversal="dda": True)
    helper = CompileHelper.start(spec, 0.0, cores=2)
    assert helper is not None and helper.kind == "uniform"
    assert helper.wait({"two_level"}) is False
    assert helper.proc.returncode is not None and helper.proc.stdin.closed
    assert helper.wait({"uniform"}) is False  # (ended: nothing to wait for)
    two = CompileHelper.start(spec.replace(grid=GridParams(grid="two_level")), 0.0, cores=2)
    assert two.kind == "two_level"
    two.stop()
    assert two.proc.returncode is not None


PROBE = """
import json, sys
import numpy as np
from numba.core import event
from gridrt import FrameSpec, FramePipeline
from gridrt.warmup import kernel_name
names = []
class L(event.Listener):
    def on_start(self, ev): names.append(kernel_name(ev.data["dispatcher"]))
    def on_end(self, ev): pass
event.register("numba:compile", L())
fr = FramePipeline.from_spec(FrameSpec.from_wire(json.loads(sys.argv[1]))).step(0.0)
np.save(sys.argv[2], fr.image)
print(json.dumps(names))
"""


def _probe(spec, cache, out):
    """The kernels a fresh process compiles rendering the first frame of ``spec`` with the numba
    cache ``cache``, and its image (saved to ``out``)."""
    r = subprocess.run([sys.executable, "-c", PROBE, json.dumps(spec.to_wire()), str(out)], cwd=REPO,
                       capture_output=True, text=True, env={**os.environ, "NUMBA_CACHE_DIR": str(cache)}, timeout=900)
    assert r.returncode == 0, r.stderr
    return json.loads(r.stdout.splitlines()[-1]), np.load(out)


@pytest.mark.slow
def test_helper_compiles_what_the_first_frame_then_loads(tmp_path):
    """On an empty numba cache, a helper for a small scene renders its frame over one-cell grids and
    says what it compiled; a process given that cache then renders the frame compiling no ray
    casting kernel (only the scene's and the grid build's), and its image is the one a process
    that compiled everything itself makes."""
    cache = tmp_path / "cache"
    spec = FrameSpec().replace(scene=FrameSpec().scene.replace(source="icosphere")).resized(40, 30)
    code, out, err = _held(spec, env={**os.environ, "NUMBA_CACHE_DIR": str(cache)})
    assert code == 0 and err == "", err
    lines = out.splitlines()
    assert lines[-1].startswith("compiled ") and any("_render_tiles" in ln for ln in lines), out
    names, image = _probe(spec, cache, tmp_path / "a.npy")
    assert names and not any(".trace." in n for n in names), names
    fresh, reference = _probe(spec, tmp_path / "fresh", tmp_path / "b.npy")
    assert any(".trace." in n for n in fresh)
    np.testing.assert_array_equal(image, reference)


def test_a_silent_helper_is_stopped():
    """A helper that writes nothing for ``line_timeout`` seconds is taken for stuck: ``wait``
    stops it and answers False (the frame then compiles its kernels itself)."""
    proc = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(600)"], stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL)
    helper = CompileHelper(proc, "uniform")
    assert helper.wait({"uniform"}, line_timeout=0.5) is False
    assert proc.returncode is not None and proc.returncode != 0


def test_wait_hands_over_each_line():
    """The helper's lines reach ``report`` whole, however its output is cut into reads."""
    script = (
        "import sys, time\n"
        "sys.stdout.write('compiling a (0/2 kernels'); sys.stdout.flush(); time.sleep(0.2)\n"
        "sys.stdout.write(' done, 0.0 s)' + chr(10) + 'compiled 2/2 kernels in 0.1 s' + chr(10))\n"
        "sys.stdout.flush()\n"
    )
    proc = subprocess.Popen([sys.executable, "-c", script], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                            stderr=subprocess.DEVNULL)
    lines = []
    assert CompileHelper(proc, "uniform").wait({"uniform"}, lines.append) is True
    assert lines == ["compiling a (0/2 kernels done, 0.0 s)", "compiled 2/2 kernels in 0.1 s"]


CAP = """
import json, resource, sys
from gridrt.memory import available, cap_address_space
preset = int(sys.argv[1])
if preset:
    resource.setrlimit(resource.RLIMIT_AS, (preset, resource.getrlimit(resource.RLIMIT_AS)[1]))
vm = int(open('/proc/self/status').read().split('VmSize:')[1].split()[0]) * 1024
avail = available()[0]
cap = cap_address_space(0.25)
print(json.dumps([vm, avail, cap, resource.getrlimit(resource.RLIMIT_AS)[0]]))
"""


@pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="no /proc to read the address space from")
def test_cap_address_space_keeps_a_share_of_the_memory_left():
    """The helper's cap: what the process maps plus the share of the memory left, never above a
    limit already set (run in processes of their own: the limit stays with a process)."""
    for preset in (0, 1 << 40, 900 << 20):
        r = subprocess.run([sys.executable, "-c", CAP, str(preset)], cwd=REPO, capture_output=True, text=True,
                           timeout=120)
        assert r.returncode == 0, r.stderr
        vm, avail, cap, soft = json.loads(r.stdout)
        assert soft == cap
        expected = vm + avail // 4
        if preset:
            expected = min(expected, preset)
        assert abs(cap - expected) <= 64 << 20, (preset, vm, avail, cap)  # (VmSize read twice, a page apart)


def test_a_helper_without_the_memory_for_its_scene_fails_quietly():
    """A scene that does not fit in the helper's share of the memory: the helper ends with 1,
    having written no traceback and finished no compile (its parent then compiles alone)."""
    import resource

    def tight():  # what the interpreter and its imports map, and little more
        resource.setrlimit(resource.RLIMIT_AS, (1 << 30, resource.getrlimit(resource.RLIMIT_AS)[1]))

    spec = FrameSpec().replace(scene=FrameSpec().scene.replace(source="marbles", count=40_000_000)).resized(8, 6)
    code, out, err = _held(spec, preexec_fn=tight, timeout=600)
    assert code == 1, (out, err)
    assert err == "" and "compiled " not in out, (out, err)
