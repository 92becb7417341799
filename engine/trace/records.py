"""Frame-level records: the values the render kernels take (gridrt.trace.render's DDA kernels,
gridrt.trace.cgt.frame's packet kernels, gridrt.trace.material's shading pass).

Each record is a module-level :func:`collections.namedtuple` of arrays and scalars; numba types it
as a NamedTuple, field by field, so a kernel compiles once per combination of field types.  The
functions below make each record with the types the kernels are compiled for (float64 basis,
int64 sizes, bool flags, float64 offsets), so that equal settings never compile again.  A
parallel kernel may take these records into its ``prange`` loop as they are: each is one level
of arrays and scalars (a tuple of tuples cannot enter it, see gridrt.trace.grids).

* :class:`View`: the camera and the image's size and tiling;
* :class:`Shading`: how hits are shaded and rays tested;
* :class:`Packets`: the packet shape and precision of the CGT kernels;
* :class:`Buffers`: a render's output buffers;
* :class:`Scratch`: one worker's scratch in the CGT render (gridrt.trace.cgt.frame);
* :class:`SurfaceArrays`: the scene's surface as the material pass reads it;
* :class:`HitPoints`: the material pass's per-pixel buffers while shadows are cast;
* :class:`ShadowRays`: one light's shadow rays from those hits, :class:`Draws`: lights drawn per
  pixel instead, and :class:`ShadowSegments`: the segments cast (all of them in a
  :class:`ShadowBuffers`, kept from frame to frame); :class:`LightMapArrays`: a light's map of
  the segments it need not cast.
"""

from collections import namedtuple

import numpy as np

#: The camera and the image: basis (5, 3) float64 (gridrt.camera.Camera.basis: eye, forward,
#: right, up, then tan(fov / 2)), the image's width W and height H in pixels, and the edge of
#: the square tiles the kernels render it in (tile, pixels).
View = namedtuple("View", "basis W H tile")

#: How hits are shaded and rays tested: mode (gridrt.trace.render.SHADING_CODES: 0 lambert, 1
#: normal, 2 cost, 3 none: a hit's pixel left for the material pass), shadows (bool: the lambert
#: mode casts shadow rays), off (float64: the shadow rays' origins move this far off the surface)
#: and watertight (bool: the watertight triangle test, else the fast one).  The light's position
#: is a kernel argument of its own: the CGT kernels take None without shadows, and numba then
#: compiles no shadow path.
Shading = namedtuple("Shading", "mode shadows off watertight")

#: The packets of the CGT render: their triangle tests in float32 (f32 True) or float64 (f32 None,
#: a numba type of its own: the render's kernels then compile none of the float32 tests, see
#: gridrt.trace.cgt.rays.rows32) and their shape, kw x kh pixels (at most
#: gridrt.trace.cgt.rays.PK_MAX each); far True where a ray of the frame may start far from a
#: grid (gridrt.trace.traverse.is_far), None where none can (the eye, and the light with shadows,
#: near every grid: :func:`gridrt.trace.traverse.near_all`): the kernels then compile none of the
#: far-ray path.
Packets = namedtuple("Packets", "f32 kw kh far")

#: A render's output, pixel by pixel: img (H, W, 4) uint8, t (H, W) float32 hit distance (inf: a
#: miss), tri (H, W) int32 scene id of the triangle hit (-1: a miss), cost (H, W) int32 triangle
#: tests, cells (H, W) int32 cells visited.  The CGT kernels pass the same buffers on flat
#: ((H * W * 4,) and (H * W,)) to their tile kernel.
Buffers = namedtuple("Buffers", "img t tri cost cells")

#: One worker's scratch in the CGT render (sizes in gridrt.trace.cgt.rays): S (NS * PN,) float64,
#: the active rays of a packet; io, io2, sio (NIO * PN,) float64, the ray tables of a packet, of
#: its rays in a later grid and of its shadow rays; sj (PN,) int64, the pixel of each shadow ray;
#: col (3 * PN,) float64, the packet's colours; mb (MBOX,) int32 the packet's mailbox; acc (4,)
#: int64, the sums the kernel returns.
Scratch = namedtuple("Scratch", "S io io2 sio sj col mb acc")

#: The scene's surface as the material pass reads it (gridrt.scene.surface.Surface.packed, by
#: scene id): tris (F, 3, 3) float32 in the render's frame, normals (F, 3, 3) float32 per corner
#: (or (0, 3, 3): geometric normals), material (F,) int32, diffuse and ambient (M, 3) per
#: material, texture (M,) int32 (-1: none), tex_data (all textures' texels, uint8) and tex_info
#: (T, 5) int64 (each texture's offset, width, height and wrap modes), uv (F, 3, 2) and colors
#: (F, 3, 3) per corner (or empty: none).
SurfaceArrays = namedtuple("SurfaceArrays",
                           "tris normals material diffuse ambient texture tex_data tex_info uv colors")

#: The material pass's per-pixel buffers while shadow rays are cast (row y * W + x): pos (W * H,
#: 3) float64 hit point, ng (W * H, 3) float64 facing geometric normal, ns (W * H, 3) float32
#: shading normal, tvd (W * H, 3) float32 the colour the lights multiply, acc (W * H, 3) float32
#: the colour so far (the ambient term first; acc[i] = -1 for a miss).
HitPoints = namedtuple("HitPoints", "pos ng ns tvd acc")

#: One light's shadow rays from the hits, row by pixel: need (W * H,) uint8 (1: the light lights
#: the hit, a ray is cast) and weight (W * H,) float64 the light's weight at the hit.
ShadowRays = namedtuple("ShadowRays", "need weight")

#: Shadow segments, those of the lit hits only, in the order they are cast: rows (N,) int64 the
#: pixel of each, o and d (N, 3) float64 the segment o + t d, 0 < t < 1, from the light's end to
#: the hit, grids (N,) uint8 the grids whose boxes it may meet (bit g: grid g), weight (N,)
#: float64 its light's weight at the hit.
ShadowSegments = namedtuple("ShadowSegments", "rows o d grids weight")

#: Lights drawn per pixel (RenderParams.light_samples; gridrt.trace.material.drawn_segments):
#: k draws a pixel (0: every light), shift (the draw's: gridrt.trace.material.draw_shift), lit
#: (N, K) int32 the distinct lights drawn for each pixel of the order (-1 after them) and factor
#: (N, K) float64 n / (k p) of each; guide (blocks, L) float64 a factor of each light's chance in
#: each block x block square of pixels, bw of them a row (0 rows: none).
Draws = namedtuple("Draws", "k shift lit factor guide block bw")

#: One point light's map for the shadow segments the material pass makes (gridrt.trace.lightmap):
#: light (3,) float64, dist (6, R, R, K) float32, key (6, R, R, K) int32 and cover (6, R, R)
#: float32, the clusters' planes (C, 5) float64 and lone (C,) int32
#: (gridrt.trace.lightmap.Clusters), and tris (F, 3, 3) float32 the mapped grid's triangles.
LightMapArrays = namedtuple("LightMapArrays", "light dist key cover planes lone tris")

#: The material pass's buffers for shadows (Python side, gridrt.trace.render.Renderer keeps them
#: from frame to frame): the :class:`HitPoints` hp, the :class:`ShadowRays` rays, the pixels in
#: tile order (W * H,) int64, the :class:`ShadowSegments` segs, the batch cast's out (t, tri, u,
#: v) and blocked (W * H,) bool.
ShadowBuffers = namedtuple("ShadowBuffers", "hp rays order segs out blocked")


#: Draws.guide of draws without one
NO_GUIDE = np.ones((0, 1))


def make_draws(k, shift, lit, factor, guide=NO_GUIDE, block=1, bw=1):
    """The :class:`Draws` with the types the kernels are compiled for."""
    return Draws(int(k), float(shift), lit, factor, guide, int(block), int(bw))


def make_view(basis, W, H, tile):
    """The :class:`View` with the types the kernels are compiled for."""
    return View(np.ascontiguousarray(basis, np.float64), int(W), int(H), int(tile))


def make_shading(mode, shadows, off, watertight):
    """The :class:`Shading` with the types the kernels are compiled for."""
    return Shading(int(mode), bool(shadows), float(off), bool(watertight))


def make_packets(f32, kw, kh, far=True):
    """The :class:`Packets` with the types the kernels are compiled for."""
    return Packets(True if f32 else None, int(kw), int(kh), True if far else None)
