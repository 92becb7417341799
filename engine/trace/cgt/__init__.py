"""Coherent grid traversal (CGT): packets of rays walked through the grid slice by slice.

Wald, Ize, Kensler, Knoll, Parker, "Ray Tracing Animated Scenes using Coherent Grid Traversal",
ACM SIGGRAPH 2006.  A packet (up to kw x kh camera rays from a block of pixels, 8 x 8 by default,
or the shadow rays of such a block) is traversed along its major axis K, one slice of cells (fixed K
index) at a time.  In each slice the cells overlapped by the packet's bounds are visited; each of
their triangles passes a per-packet mailbox, a bounding-box cull against the packet's extent in
the slice and a cull against the packet's four bounding planes (the paper's frustum culling), and
is then intersected with every active ray in one loop over structure-of-arrays ray data that
LLVM vectorizes (packed AVX2 / AVX-512VL double instructions on this machine).  Empty macro cells
are skipped a whole macro-cell slab at a time.  A two-level grid (gridrt.grid.two_level) is walked
one top-level slice at a time, each cut into sub-slices as fine as the finest leaf grid in reach
along K, visiting the leaf cells of the top cells in reach (:func:`_walk_2l`).

Packets: the rays must agree on the major axis of their direction and its sign (the watertight
test's permutation, :func:`gridrt.trace.intersect.shear_setup`), so that all share the slicing
axis and the permuted intersection arithmetic.  A packet whose rays do not agree is traced as one
packet per direction class among its rays, each gathered anew from the packet's ray table (a
camera packet across the view's diagonal planes, where the major axis changes: two classes).  The
batch caster, which makes its packets of rays of one class, never splits one.  Signs on the two
minor axes may differ (the bounds below do not need them), so packets straddling a minor-axis sign
change, e.g. at the centre of an axis-aligned view, stay whole.

Bounds: along its segment ray i's minor coordinates are linear in the K coordinate x,
u_i(x) = c_i + (x - xr) s_i.  With xr at one end of all the segments (the camera rays' common
origin, or the end of shadow rays, which converge on the light), every ray lies within
[min c + (x - xr) min s, max c + (x - xr) max s] on that side of xr (and likewise for v): four
planes, evaluated in O(1) per slice and used for the cell range and the triangle culls; they are
recomputed when rays leave the packet.

Termination (same rule as the DDA): after a slice, ray i is final once its best t is at or before
the t where it leaves the slice (or its segment ends there): insertion is conservative, so every
triangle it could hit nearer has been tested against it.  Final rays leave the active set (the
last survivors fill their places), so the loops always run over a contiguous prefix.

Results equal the DDA's bit for bit (same intersection arithmetic: the packet loops repeat
:func:`intersect_watertight` / :func:`intersect_fast` operation for operation, without fast-math
contraction), ties included: of two triangles hit at the same t both take the lower index.

Per-ray counters: ``tests`` counts the triangle tests made while the ray was active (each test
of the packet loop covers every active ray), ``cells`` the cells the packet visited meanwhile.
The package by layer:

* :mod:`.rays`: a packet's rays: the layout of its ray tables, gathering and clipping the rays,
  their bounds, the triangle tests over all active rays (float64 and float32), retiring rays;
* :mod:`.walk`: one packet through a grid (slices, cells, macro cells, the two-level walk, far
  origins, incoherent packets split by direction class): :func:`trace_packet`,
  :func:`trace_packet_grids`;
* :mod:`.frame`: a frame rendered as packets on any number of threads: :func:`cgt_render`;
* :mod:`.profile`: the cycle counts of a packet's phases (trace_packet's ``prof``).
"""

from .frame import _camera_rays, _render_tiles, cgt_render
from .profile import (C_CELLS, C_PACKETS, C_SLICES, C_TESTS, NPROF, P_RAYS, P_TESTS, PROFILE_PHASES, _lap,
                      _now)
from .rays import (F_BF, F_BT, F_OU, F_OV, F_SZ, IO_DX, IO_DY, IO_DZ, IO_F, IO_NC, IO_NT, IO_OX, IO_OY, IO_OZ, IO_T,
                   IO_TMAX, IO_W, MBOX, NIO, NS, O_F32, PK, PK_MAX, PN, Packet, PacketQuery, _test_wt32,
                   direction_class, packet_query)
from .walk import trace_packet, trace_packet_grids
