"""No ray slips through a closed mesh at a shared edge or vertex (watertight intersection).

Rays are aimed exactly at the mesh's vertices, at the midpoints of its edges and at random points
along its edges (targets computed in float64 from the float32 vertices and used as they are),
from random origins outside the mesh's bounding sphere.  Each origin lies strictly in front of
every face that touches its target (the ray crosses the surface at the target instead of grazing
it), so on a closed mesh the ray must hit some triangle no later than the target:
the watertight test (Woop, Benthin, Wald, JCGT 2013) must give 0 misses and 0 hits with
t > |target - origin| * (1 + 1e-6).  The same rays through the fast Moller-Trumbore test are
counted and printed (it gives no such guarantee; nothing is asserted about it).

Meshes: an icosphere (trimesh.creation), a radially jittered icosphere shot from inside, and the
closed Armadillo shipped in assets/ (skipped when absent).  This is pbrt-v4's
``Triangle.Watertight`` property, done on shared edges instead of random points.

The packet traversal (CGT, engine/trace/cgt.py) gets the same kind of probes, with the same
criterion (a hole: a miss, or a hit beyond the target), two ways:

* Star packets, traced by ``cgt.trace_packet``, the packet kernel the renderer runs for every
  8 x 8 block of pixels (a small parallel driver below fills its ray table, as the renderer fills
  it with camera rays).  A packet belongs to a random vertex v and has up to 64 rays from one eye,
  as a camera packet does, the eye being in front of all of v's faces: a ray at v, at each vertex
  of v's one-ring, at the midpoint of each spoke (v, w) and of each link edge (w, w') (the edges
  opposite v in its fan), then at random points along the spokes and link edges.  Ring vertices
  and link-edge points whose own faces do not all face the eye are left out.  The rays at the
  ring and its link edges bound the packet, so triangles beyond them are the ones the packet's
  frustum culling and cell ranges decide about.
* Camera rows, through the renderer (``Renderer.render``, ``RenderParams(traversal="cgt")``): for a
  random shared edge and an eye in front of both its faces, a camera whose ROW_WIDTH x 1 image
  lies in the plane through the eye and the edge (up vector: that plane's normal, view direction:
  the bisector of the directions to the edge's ends, field of view: the edge less 0.1 %).  Every
  pixel-centre ray of the row crosses the edge; where, and how far along the ray, is computed
  here in float64 from the documented pinhole formula (tests/reference.py), and checked.  The
  renderer traces the row as 8 x 1 packets.

Both print the fast test's hole rate, which is also required to be non-zero: probes that were not
at the edges within float64 rounding would not find its leaks.  (Removing the 1e-5-cell margin of
the packet's culling planes in cgt.py makes both probe sets report holes.)  tests/test_soak.py
runs the same on the Armadillo, the dragon and Lucy, with 10M rays of each kind under ``-m soak``.
"""

import time

import numpy as np
import pytest

from conftest import ARMADILLO, icosphere, load_mesh_arrays
from gridrt.grid import GridBuilder, GridParams
from helpers.watertight import (ProbeMesh, cgt_report, face_normals, origins_in_front, packet_counts, row_counts, shoot,
                                targets_and_fans)


def test_icosphere_shared_edges_from_outside(rng):
    v, f = icosphere(3, radius=1.0, center=(0.1, -0.2, 0.3))
    n = face_normals(v, f)
    tg, offs, fan = targets_and_fans(rng, v, f, len(v), 3000, 9000)
    centre = v.astype(np.float64).mean(axis=0)
    radius = np.linalg.norm(v - centre, axis=1).max()
    o, t, ok = origins_in_front(rng, tg, offs, fan, n, centre, radius)
    assert ok.mean() > 0.99
    shoot(v, f, o, t, "icosphere (outside)")


@pytest.mark.parametrize("density,macro", [(0.5, 1), (12.0, 8)])
def test_icosphere_grid_params(rng, density, macro):
    """Watertightness does not depend on the grid (cell faces through vertices and edges)."""
    v, f = icosphere(2, radius=2.0)
    n = face_normals(v, f)
    tg, offs, fan = targets_and_fans(rng, v, f, len(v), 1000, 2000)
    centre = np.zeros(3)
    o, t, _ = origins_in_front(rng, tg, offs, fan, n, centre, 2.0 + 1e-6)
    shoot(v, f, o, t, f"icosphere density={density} macro={macro}", GridParams(density=density, macro=macro))


def test_jittered_sphere_from_inside(rng):
    """Rays from near the centre of a radially jittered (star-shaped) icosphere to its vertices
    and edges must leave it through a triangle no later than the target."""
    v, f = icosphere(3, radius=1.0)
    v = (v * rng.uniform(0.97, 1.03, (len(v), 1))).astype(np.float32)
    tg, _, _ = targets_and_fans(rng, v, f, len(v), 3000, 6000)
    o = rng.uniform(-0.2, 0.2, (len(tg), 3))  # every face plane is > 0.8 from the centre
    shoot(v, f, o, tg, "jittered icosphere (inside)")


def test_armadillo_shared_edges():
    v, f = load_mesh_arrays(ARMADILLO)
    rng = np.random.default_rng(11)
    n = face_normals(v, f)
    tg, offs, fan = targets_and_fans(rng, v, f, 8000, 8000, 16000)
    v64 = v.astype(np.float64)
    centre = 0.5 * (v64.min(0) + v64.max(0))
    radius = np.linalg.norm(v64 - centre, axis=1).max()
    o, t, ok = origins_in_front(rng, tg, offs, fan, n, centre, radius)
    print(f"armadillo: {ok.mean():.3f} of the targets have an origin in front of all their faces")
    assert ok.sum() > 25000
    shoot(v, f, o, t, "armadillo (outside)")


# ----------------------------------------------------------------------------------------------
# the same probes through the packet traversal (CGT)


@pytest.mark.parametrize("density,macro", [(4.0, 4), (0.5, 1), (12.0, 8)])
def test_icosphere_cgt(rng, density, macro):
    """Packet traversal on an icosphere: star packets and camera rows, 0 holes on any grid."""
    m = ProbeMesh(*icosphere(3, radius=1.0, center=(0.1, -0.2, 0.3)))
    grid = GridBuilder(GridParams(density=density, macro=macro)).build(m.tris)
    t0 = time.perf_counter()
    pk = packet_counts(m, grid, rng, 1500)
    rows = row_counts(m, grid, rng, 50)
    cgt_report(f"icosphere density={density} macro={macro}", pk, rows, time.perf_counter() - t0)
