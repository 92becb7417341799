"""FramePipeline.resume: a pipeline that takes a sequence up at frame k renders frames k.. as one
pipeline stepping from frame 0 does (images, hit buffers and every stats column but timings), so
a sequence cut into pieces over processes is the one-process sequence bit for bit."""

import numpy as np
import pytest

from gridrt.camera import Camera
from gridrt.config import GridParams, RenderParams
from gridrt.errors import InputError
from gridrt.pipeline import FramePipeline
from gridrt.scene import KeyframeMesh, icosphere_mesh, make_scene

DT = 1.0 / 30.0
#: stats columns that are timings (or derive from one), and whether kernels compiled during the frame
#: (what compiled before in the process): allowed to differ between runs
TIMED = {"mrays", "compiled"}


def untimed(stats):
    return {k: v for k, v in dict(stats).items() if not k.endswith("_ms") and k not in TIMED}


def frames(pipe, ts, **kw):
    """(image, t, tri, untimed stats, origin) of pipe.step at each t, copied (the pipeline reuses
    its buffers)."""
    out = []
    for t in ts:
        fr = pipe.step(t, **kw)
        out.append((fr.image.copy(), fr.t.copy(), fr.tri.copy(), untimed(fr.stats), fr.origin.copy()))
    return out


def same(a, b):
    for x, y in zip(a, b):
        assert np.array_equal(x[0], y[0]) and np.array_equal(x[1], y[1]) and np.array_equal(x[2], y[2])
        assert x[3] == y[3], {k: (x[3][k], y[3].get(k)) for k in x[3] if x[3][k] != y[3].get(k)}
        assert np.array_equal(x[4], y[4])
    assert len(a) == len(b)


@pytest.mark.parametrize("source,count", [("marbles", 2000), ("icosphere", 1280)])
def test_resume_is_the_sequence(source, count):
    """Marbles (a static floor and moving marbles: the split scene) and a static icosphere
    (gridded once: ``rebuilt`` is 1 at frame 0 only): frames 3..6 of a pipeline resumed at 3 are
    frames 3..6 of one that stepped from 0, with the camera that framed frame 0; resuming at 0
    starts afresh (frame 0 rebuilt again)."""
    scene = make_scene(source, count=count)
    gp, rp = GridParams(threads=2), RenderParams(64, 48, threads=2)
    ref = frames(FramePipeline(scene, gp, rp), [i * DT for i in range(7)])
    pipe = FramePipeline(scene, gp, rp)
    pipe.resume(3, 0.0)
    same(frames(pipe, [i * DT for i in range(3, 7)]), ref[3:])
    pipe.resume(1, 0.0)  # back: same frames again
    same(frames(pipe, [DT]), ref[1:2])
    pipe.resume(0, 0.0)
    same(frames(pipe, [0.0, DT]), ref[:2])
    if scene.static:
        assert [r[3]["rebuilt"] for r in ref] == [True] + [False] * 6


def test_resume_with_the_origin_of_a_drifting_scene():
    """A scene that travels 1e8 units: the pipeline moves its frame of reference twice.  Resumed
    at each frame with the origin the sequence stood at, every frame is the sequence's; resumed
    without it (the first frame's origin) the frame after a move is gridded elsewhere and its
    origin differs, which is how a cluster run knows to render it again."""
    ico = icosphere_mesh(320)
    v = ico.vertices64
    path = np.array([0.0, 0.5, 3e7, 3e7 + 1.0, 1e8, 1e8 + 0.5])
    axis = np.array([1.0, -0.7, 0.3])
    keys = [v + p * axis for p in path]
    scene = KeyframeMesh(np.stack(keys + keys[-1:]), ico.faces, fps=1.0)  # (the last key held: t = 5 is key 5)
    cam = Camera((0.3, 0.4, 3.0), (0.0, 0.0, 0.0))
    gp, rp = GridParams(threads=1), RenderParams(40, 30, threads=1, traversal="dda")

    def cams(k):
        return Camera(tuple(cam.eye + path[k] * axis), tuple(path[k] * axis))

    seq = FramePipeline(scene, gp, rp)
    ref, origins = [], []
    for k in range(len(path)):
        ref += frames(seq, [float(k)], camera=cams(k))
        origins.append(ref[-1][4])
    assert seq.recentred == 2
    for k in range(1, len(path)):
        pipe = FramePipeline(scene, gp, rp)
        pipe.resume(k, 0.0, origins[k - 1])
        same(frames(pipe, [float(k)], camera=cams(k)), ref[k:k + 1])
    stale = FramePipeline(scene, gp, rp)
    stale.resume(3, 0.0)  # no origin: frame 0's, but frame 2 moved it
    assert not np.array_equal(stale.origin, origins[2])


def test_resume_refuses_bad_arguments():
    pipe = FramePipeline(make_scene("icosphere", count=80), GridParams(threads=1), RenderParams(8, 8, threads=1))
    with pytest.raises(InputError, match="frame must be >= 0"):
        pipe.resume(-1, 0.0)
    with pytest.raises(InputError, match="origin must be 3 finite numbers"):
        pipe.resume(2, 0.0, [0.0, np.nan, 0.0])
    with pytest.raises(InputError, match="origin must be 3 finite numbers"):
        pipe.resume(2, 0.0, [0.0, 1.0])
