"""Ray-level records: the values the single-ray traversal and the batch caster pass their kernels.

Each record is a module-level :func:`collections.namedtuple`; numba types it as a NamedTuple
(its fields by their values), and in a kernel inlined into its caller a record costs nothing: its
fields are plain values there.  A ray's origin, direction, steps and a cell's index triple are
plain 3-tuples.

* :class:`Shear`: the watertight test's per-ray constants (gridrt.trace.intersect.shear_setup);
* :class:`Ray`: one ray as a traversal walks it (gridrt.trace.traverse._ray_setup);
* :class:`Query`: what a batch cast asks of every ray (t range and flags), made by :func:`query`;
* :class:`CastPass`: how one pass of a batch cast traces its runs;
* :class:`HitArrays`: a batch cast's outputs, one row per ray;
* :class:`PacketScratch`: one worker's scratch for packets and single rays;
* :class:`StreamScratch`: one worker's scratch for single rays traced interleaved.
"""

from collections import namedtuple

#: The watertight test's constants of one ray: the axes (kx, ky, kz) the ray's direction is
#: permuted by (kz its major axis), the ray's origin permuted by them (okx, oky, okz) and the
#: shear (Sx, Sy, Sz) that makes the ray run along +z (Woop et al. 2013).  All zeros for the fast
#: test.
Shear = namedtuple("Shear", "kx ky kz okx oky okz Sx Sy Sz")

#: One ray as a traversal walks it: origin o and direction d (float64 3-tuples), the DDA's steps
#: s (-1, 0 or 1 per axis) and inverse direction inv (inf along an axis it does not step), the
#: triangle test's :class:`Shear` sh, and the query: hits need t > tmin; watertight picks the
#: test; any_hit ends the search at the first hit.
Ray = namedtuple("Ray", "o d s inv sh tmin watertight any_hit")

#: What a batch cast asks of every ray: a hit with tmin < t < tmax (float64), by the watertight
#: test or the fast one, the nearest or (any_hit) any.
Query = namedtuple("Query", "tmin tmax watertight any_hit")

#: How one pass of a batch cast traces its runs of rays: as packets when they make one of at
#: most max_cells cells in its widest slice (float64; <= 0: never), the packets' triangle tests
#: in float32 with f32; the runs that do not make one are traced one ray at a time with singly,
#: else flagged in the outputs' ``left``.  With tri_only the caller reads only the outputs' tri
#: (which triangle, or none): a float64 packet's hits then skip the single-ray test that
#: recomputes t, u and v, which stay unwritten for them.
CastPass = namedtuple("CastPass", "max_cells singly f32 tri_only")

#: A batch cast's outputs, (N,) arrays indexed by ray: t (float64, inf on a miss), tri (int32,
#: -1 on a miss), barycentrics u, v (float64), and left (uint8: 1 for a ray the pass left for
#: the next one; an empty array when the pass leaves none).
HitArrays = namedtuple("HitArrays", "t tri u v left")

#: One worker's scratch: a packet's rows io and slices S (float64), its mailbox mb and a single
#: ray's mailbox mb1 (int32).
PacketScratch = namedtuple("PacketScratch", "io S mb mb1")

#: One worker's scratch for rays traced interleaved (gridrt.trace.stream): each lane's float64
#: and int64 state rows fs and is_, and its single-ray scratch mbs (int32 rows of trace_ray's
#: layout: the mailbox, then the side-by-side test's rows).
StreamScratch = namedtuple("StreamScratch", "fs is_ mbs")


def query(tmin, tmax, watertight, any_hit):
    """The :class:`Query` of a batch cast, with the dtypes the kernels are compiled for (float64
    t range, bool flags)."""
    return Query(float(tmin), float(tmax), bool(watertight), bool(any_hit))


def cast_pass(max_cells, singly, f32, tri_only=False):
    """The :class:`CastPass` of one pass, with the dtypes the kernels are compiled for."""
    return CastPass(float(max_cells), bool(singly), bool(f32), bool(tri_only))

