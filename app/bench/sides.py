"""The peers of ``gridrt bench peers``: each one builds its acceleration structure over a frame's
triangles and casts rays through it, timed by the caller."""

import time

import numpy as np

from gridrt.commands import pip_command
from gridrt.errors import GridrtError

INSTALL_HINT = f"embreex is not installed; `gridrt bench peers` needs it: {pip_command()} install embreex"


class MissingPeer(GridrtError):
    """The optional peer library is not installed."""


def import_embreex():
    """(rtcore, rtcore_scene, mesh_construction, version) or MissingPeer with the install hint."""
    try:
        import embreex
        from embreex import mesh_construction, rtcore, rtcore_scene
    except ImportError:
        raise MissingPeer(INSTALL_HINT) from None
    return rtcore, rtcore_scene, mesh_construction, getattr(embreex, "__version__", "?")


class EmbreeSide:
    """One Embree device for the whole run (created before any affinity change, so Embree's
    task scheduler sees every core) and the per-frame rebuild + pooled cast."""

    def __init__(self, robust):
        self.rtc, self.rs, self.mc, self.version = import_embreex()
        self.device = self.rtc.EmbreeDevice()
        self.robust = robust
        self.scene = None
        self._zero = np.zeros((0, 3), np.float32)
        tiny = np.array([[[0, 0, 0], [1, 0, 0], [0, 1, 0]]], np.float32)
        self.build(tiny)

    def build(self, tris):
        """New scene over tris (F,3,3) float32: returns (upload ms, commit ms)."""
        t0 = time.perf_counter()
        scene = self.rs.EmbreeScene(self.device, robust=self.robust)
        self.mc.TriangleMesh(scene, tris)
        t1 = time.perf_counter()
        scene.run(self._zero, self._zero)  # commits the scene (rtcCommitScene: the BVH build)
        t2 = time.perf_counter()
        self.scene = scene
        return (t1 - t0) * 1e3, (t2 - t1) * 1e3

    def cast(self, pool, o32, d32, threads):
        """(t (N,) float64 [inf: miss], prim (N,) int64 [-1: miss]) over chunks in the pool."""
        N = len(o32)
        n_chunks = max(1, min(threads * 8, N // 4096 or 1))
        bounds = np.linspace(0, N, n_chunks + 1).astype(np.int64)
        sc = self.scene

        def job(k):
            return sc.run(o32[bounds[k]:bounds[k + 1]], d32[bounds[k]:bounds[k + 1]], output=1)

        parts = list(pool.map(job, range(n_chunks))) if threads > 1 else [job(k) for k in range(n_chunks)]
        prim = np.concatenate([p["primID"] for p in parts]).astype(np.int64)
        t = np.concatenate([p["tfar"] for p in parts]).astype(np.float64)
        miss = prim < 0
        t[miss] = np.inf
        prim[miss] = -1
        return t, prim
