"""The peers of ``gridrt bench peers``: each one builds its acceleration structure over a frame's
triangles and casts rays through it, timed by the caller."""

import time

import numpy as np

from gridrt.commands import pip_command
from gridrt.errors import GridrtError

INSTALL_HINT = f"embreex is not installed: {pip_command()} install embreex"


class MissingPeer(GridrtError):
    """The optional peer library is not installed."""


def import_embreex():
    """(rtcore, rtcore_scene, mesh_construction, version) or MissingPeer with the install hint."""
    try:
        import embreex  # deferred: the optional peers extra (embreex), absent unless installed
        from embreex import mesh_construction, rtcore, rtcore_scene  # deferred: the optional peers extra (embreex)
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

    def _chunks(self, pool, N, threads, job):
        """job(a, b) over chunks [a, b) of N rays, in the pool when threads > 1: the results in order."""
        n_chunks = max(1, min(threads * 8, N // 4096 or 1))
        bounds = np.linspace(0, N, n_chunks + 1).astype(np.int64)
        spans = list(zip(bounds[:-1], bounds[1:]))
        return list(pool.map(lambda ab: job(*ab), spans)) if threads > 1 else [job(a, b) for a, b in spans]

    def cast(self, pool, o32, d32, threads):
        """(t (N,) float64 [inf: miss], prim (N,) int64 [-1: miss]) over chunks in the pool."""
        sc = self.scene
        parts = self._chunks(pool, len(o32), threads, lambda a, b: sc.run(o32[a:b], d32[a:b], output=1))
        prim = np.concatenate([p["primID"] for p in parts]).astype(np.int64)
        t = np.concatenate([p["tfar"] for p in parts]).astype(np.float64)
        miss = prim < 0
        t[miss] = np.inf
        prim[miss] = -1
        return t, prim

    def occluded(self, pool, o32, d32, threads):
        """The segments o + t d, t in (0, 1), as Embree's occlusion query (tfar 1) over chunks in the
        pool: one int32 array per chunk, -1 where a segment is not occluded (join with
        :meth:`blocked`; apart, so that a caller can time the casts alone)."""
        sc = self.scene
        return self._chunks(pool, len(o32), threads, lambda a, b: sc.run(
            o32[a:b], d32[a:b], dists=np.ones(b - a, np.float32), query="OCCLUDED"))

    @staticmethod
    def blocked(parts):
        """(N,) bool of :meth:`occluded`'s chunks: True where a segment is occluded."""
        return np.concatenate(parts) != -1


class EmbreeFastSide(EmbreeSide):
    """Embree without RTC_SCENE_FLAG_ROBUST, measured beside the robust scene of the main side."""

    name, label = "embree_fast", "Embree (fast)"

    def __init__(self):
        super().__init__(robust=False)


class EmbreeRobustSide(EmbreeSide):
    """Embree with RTC_SCENE_FLAG_ROBUST, measured beside the main side when that one is fast
    (``--embree-fast``)."""

    name, label = "embree_robust", "Embree (robust)"

    def __init__(self):
        super().__init__(robust=True)


class Open3DSide:
    """Open3D's RaycastingScene (PyPI ``open3d-cpu``; Embree 3 underneath): per frame a new scene over
    the triangles (the "upload": Open3D tensors of the vertices and faces, and add_triangles), the
    build (its first cast commits the scene: timed by a zero-ray cast) and ``cast_rays`` with
    ``nthreads``."""

    name, label = "open3d", "Open3D"

    def __init__(self):
        try:
            import open3d as o3d  # deferred: the optional peer open3d, absent unless installed
        except ModuleNotFoundError:
            raise MissingPeer(f"open3d is not installed: {pip_command()} install open3d-cpu") from None
        except ImportError as e:  # installed, but a library it loads is missing
            raise MissingPeer(f"open3d is installed but does not load ({e}): it needs the system package "
                              "libusb-1.0-0") from None
        self.o3d = o3d
        self.version = o3d.__version__
        self.scene = None
        self._faces = None  # the (F, 3) faces tensor of a triangle soup, made once per size

    def build(self, tris):
        """New scene over tris (F,3,3) float32: returns (upload ms, commit ms)."""
        o3d = self.o3d
        t0 = time.perf_counter()
        F = len(tris)
        v = o3d.core.Tensor(np.ascontiguousarray(tris, np.float32).reshape(-1, 3))
        if self._faces is None or len(self._faces) != F:  # (the faces never change: as Mitsuba's side)
            self._faces = o3d.core.Tensor(np.arange(3 * F, dtype=np.uint32).reshape(F, 3))
        scene = o3d.t.geometry.RaycastingScene()
        scene.add_triangles(v, self._faces)
        t1 = time.perf_counter()
        scene.cast_rays(o3d.core.Tensor(np.zeros((1, 6), np.float32)), nthreads=1)  # commits the scene
        t2 = time.perf_counter()
        self.scene = scene
        return (t1 - t0) * 1e3, (t2 - t1) * 1e3

    def cast(self, pool, o32, d32, threads):
        """(t (N,) float64 [inf: miss], prim (N,) int64 [-1: miss]) on ``threads`` threads."""
        rays = self.o3d.core.Tensor(np.hstack([o32, d32]))
        ans = self.scene.cast_rays(rays, nthreads=threads)
        t = ans["t_hit"].numpy().astype(np.float64)
        prim = ans["primitive_ids"].numpy().astype(np.int64)
        miss = ~np.isfinite(t) | (prim == self.o3d.t.geometry.RaycastingScene.INVALID_ID)
        t[miss] = np.inf
        prim[miss] = -1
        return t, prim


class MitsubaSide:
    """Mitsuba 3 (PyPI ``mitsuba`` and ``drjit``), variant ``llvm_ad_rgb`` (CPU, JIT-compiled wavefront
    kernels; Embree builds the BVH): one mesh whose vertex positions are replaced every frame
    (``params.update()`` rebuilds the scene's BVH: "commit"; the "upload" is the copy into Dr.Jit
    arrays) and ``ray_intersect_preliminary`` on all rays at once, with Dr.Jit's thread pool set
    to ``threads``."""

    name, label = "mitsuba", "Mitsuba 3"

    def __init__(self):
        try:
            import drjit as dr  # deferred: the optional peer Mitsuba 3 (drjit), absent unless installed
            import mitsuba as mi  # deferred: the optional peer Mitsuba 3, absent unless installed
        except ImportError:
            raise MissingPeer(f"mitsuba is not installed: {pip_command()} install mitsuba drjit") from None
        if "llvm_ad_rgb" not in mi.variants():
            raise MissingPeer("this mitsuba build has no llvm_ad_rgb variant (the CPU one)")
        mi.set_variant("llvm_ad_rgb")
        self.mi, self.dr = mi, dr
        self.version = mi.__version__
        self.scene = self.params = None
        self.F = -1

    def build(self, tris):
        mi, dr = self.mi, self.dr
        F = len(tris)
        t0 = time.perf_counter()
        pos = mi.Float(np.ascontiguousarray(tris, np.float32).reshape(-1))
        if F != self.F:  # a new mesh of this size (the faces never change)
            mesh = mi.Mesh("gridrt", vertex_count=3 * F, face_count=F, has_vertex_normals=False,
                           has_vertex_texcoords=False)
            p = mi.traverse(mesh)
            p["faces"] = mi.UInt32(np.arange(3 * F, dtype=np.uint32))
            p["vertex_positions"] = pos
            p.update()
            self.scene = mi.load_dict({"type": "scene", "mesh": mesh})
            self.params = mi.traverse(self.scene)
            self.key = next(k for k in self.params.keys() if k.endswith("vertex_positions"))
            self.F = F
            t1 = time.perf_counter()
        else:
            self.params[self.key] = pos
            dr.eval(self.params[self.key])
            t1 = time.perf_counter()
            self.params.update()  # rebuilds the BVH
        dr.sync_thread()
        t2 = time.perf_counter()
        return (t1 - t0) * 1e3, (t2 - t1) * 1e3

    def cast(self, pool, o32, d32, threads):
        mi, dr = self.mi, self.dr
        dr.set_thread_count(threads)
        ray = mi.Ray3f(o=mi.Point3f(o32[:, 0], o32[:, 1], o32[:, 2]), d=mi.Vector3f(d32[:, 0], d32[:, 1], d32[:, 2]))
        pi = self.scene.ray_intersect_preliminary(ray, coherent=True)
        valid = np.array(pi.is_valid())
        t = np.array(pi.t).astype(np.float64)
        prim = np.array(pi.prim_index).astype(np.int64)
        t[~valid] = np.inf
        prim[~valid] = -1
        return t, prim
