"""Watertightness probes: rays aimed at shared vertices and edges, traced as single rays, packets and camera rows."""

import numpy as np
from numba import njit, prange

from gridrt.camera import Camera
from gridrt.config import RenderParams
from gridrt.grid import GridParams, build_grid
from gridrt.trace import cast_rays, cgt
from gridrt.trace.grids import grid_arrays
from gridrt.trace.render import Renderer
from reference import ref_camera_rays


REL = 1e-6


#: probes of a star packet (a default 8 x 8 render packet's rays)
PROBES = cgt.PK * cgt.PK


#: pixels of a camera-row probe image (one row)
ROW_WIDTH = 512


def edge_table(faces):
    """Unique undirected edges (E, 2) and, for a closed manifold mesh, their two faces (E, 2)."""
    F = len(faces)
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    f = np.tile(np.arange(F), 3)
    e = np.sort(e, axis=1)
    uniq, inv, counts = np.unique(e, axis=0, return_inverse=True, return_counts=True)
    assert (counts == 2).all(), "mesh is not closed and manifold: an edge has other than 2 faces"
    order = np.argsort(inv.reshape(-1), kind="stable")
    return uniq, f[order].reshape(-1, 2)


def face_normals(v, faces):
    """Unit normals (F, 3) float64, oriented outwards (by the sign of the enclosed volume)."""
    t = v[faces].astype(np.float64)
    n = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
    vol = np.einsum("fc,fc->", t[:, 0], n)  # 6 x signed volume
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    return n if vol > 0 else -n


def mesh_tables(faces, n_vertices):
    """A closed mesh's tables: its unique edges and their two faces (edge_table), and its vertex
    fans as CSR (offsets (n_vertices+1,), face ids)."""
    edges, ef = edge_table(faces)
    vf = faces.reshape(-1)
    order = np.argsort(vf, kind="stable")
    return edges, ef, np.searchsorted(vf[order], np.arange(n_vertices + 1)), np.repeat(np.arange(len(faces)), 3)[order]


def targets_and_fans(rng, v, faces, n_vertices, n_mid, n_rand, tables=None):
    """Targets (T, 3) float64 with their incident faces as CSR (offsets (T+1,), face ids).
    ``tables``: the mesh's mesh_tables, when the caller keeps them."""
    v64 = v.astype(np.float64)
    edges, ef, vstart, vf_f = mesh_tables(faces, len(v)) if tables is None else tables
    vids = rng.choice(len(v), min(n_vertices, len(v)), replace=False)
    pts = [v64[vids]]
    counts = [vstart[vids + 1] - vstart[vids]]
    fans = [vf_f[csr_gather(vstart[vids], counts[0])]]
    # edge midpoints and random points along edges: fans of two faces
    for n, mid in ((n_mid, True), (n_rand, False)):
        k = min(n, len(edges)) if mid else n
        eids = rng.choice(len(edges), k, replace=k > len(edges))
        a, b = v64[edges[eids, 0]], v64[edges[eids, 1]]
        s = np.full((len(eids), 1), 0.5) if mid else rng.uniform(0.0, 1.0, (len(eids), 1))
        pts.append(a + s * (b - a))
        counts.append(np.full(len(eids), 2))
        fans.append(ef[eids].reshape(-1))
    counts = np.concatenate(counts)
    return np.concatenate(pts), np.concatenate([[0], np.cumsum(counts)]), np.concatenate(fans)


def csr_gather(starts, counts):
    """The indices starts[i] .. starts[i] + counts[i] - 1 of every i, one after another."""
    ends = np.cumsum(counts)
    return np.arange(ends[-1] if len(ends) else 0) - np.repeat(ends - counts - starts, counts)


def origins_in_front(rng, targets, offs, fan, normals, centre, radius, min_cos=0.1):
    """For each target a direction u with u . n > min_cos for every face of its fan, and the
    origin target + L u outside the bounding sphere.  Targets with no such u are dropped."""
    T = len(targets)
    navg = np.add.reduceat(normals[fan], offs[:-1], axis=0)
    navg /= np.linalg.norm(navg, axis=1, keepdims=True)
    u = np.zeros((T, 3))
    ok = np.zeros(T, bool)
    for attempt in range(40):
        todo = np.flatnonzero(~ok)
        if not len(todo):
            break
        spread = 0.6 if attempt < 30 else 0.0
        cand = navg[todo] + spread * rng.normal(size=(len(todo), 3))
        cand /= np.linalg.norm(cand, axis=1, keepdims=True)
        rep = np.repeat(cand, np.diff(offs)[todo], axis=0)
        sub_offs = np.concatenate([[0], np.cumsum(np.diff(offs)[todo])])
        sub_fan = fan[csr_gather(offs[todo], np.diff(offs)[todo])]
        dots = np.einsum("kc,kc->k", rep, normals[sub_fan])
        good = np.minimum.reduceat(dots, sub_offs[:-1]) > min_cos
        u[todo[good]] = cand[good]
        ok[todo[good]] = True
    L = radius * rng.uniform(1.5, 3.0, T) + np.linalg.norm(targets - centre, axis=1)
    o = targets + L[:, None] * u
    assert (np.linalg.norm(o[ok] - centre, axis=1) > radius).all()
    return o[ok], targets[ok], ok


def shoot(v, faces, origins, targets, label, params=GridParams(density=4.0, macro=4)):
    tris = np.ascontiguousarray(v[faces])
    grid = build_grid(tris, params)
    d = targets - origins
    dist = np.linalg.norm(d, axis=1)
    d /= dist[:, None]
    res = {}
    for wt in (True, False):
        h = cast_rays(grid, tris, origins, d, watertight=wt)
        miss = h.tri < 0
        far = ~miss & (h.t > dist * (1 + REL))
        res[wt] = (int(miss.sum()), int(far.sum()), h)
    print(
        f"{label}: {len(origins)} rays at shared vertices/edges; watertight: {res[True][0]} misses, "
        f"{res[True][1]} hits beyond the target; fast (Moller-Trumbore): {res[False][0]} misses, "
        f"{res[False][1]} hits beyond the target"
    )
    m, f, h = res[True]
    bad = np.flatnonzero((h.tri < 0) | (h.t > dist * (1 + REL)))
    assert m == 0 and f == 0, (
        f"{label}: watertight test let {m} rays through and hit {f} beyond the target; first rays: "
        f"origins {origins[bad[:3]].tolist()} targets {targets[bad[:3]].tolist()}"
    )
    return res


@njit(cache=True, parallel=True)
def _trace_packets(g, eyes, dirs, offs, watertight, f32, t_out, f_out, split):
    """Packet p (rays offs[p]..offs[p+1]-1, from eyes[p] along unit dirs, at most 64) traced by
    cgt.trace_packet through the grid g (GridArrays), as cgt._render_tiles traces a block of
    pixels (its ray table filled from dirs instead of the camera), its triangle tests in float32
    with f32.  split[p]: rays of packet p traced in packets split by direction class."""
    for p in prange(len(offs) - 1):
        S = np.empty(cgt.NS * cgt.PN)
        io = np.empty(cgt.NIO * cgt.PN)
        mb = np.empty(cgt.MBOX, np.int32)
        a = offs[p]
        n = offs[p + 1] - a
        for j in range(n):
            io[cgt.IO_OX * cgt.PN + j] = eyes[p, 0]
            io[cgt.IO_OY * cgt.PN + j] = eyes[p, 1]
            io[cgt.IO_OZ * cgt.PN + j] = eyes[p, 2]
            io[cgt.IO_DX * cgt.PN + j] = dirs[a + j, 0]
            io[cgt.IO_DY * cgt.PN + j] = dirs[a + j, 1]
            io[cgt.IO_DZ * cgt.PN + j] = dirs[a + j, 2]
            io[cgt.IO_TMAX * cgt.PN + j] = np.inf
        q = cgt.PacketQuery(0.0, watertight, False, f32, True)
        split[p] = cgt.trace_packet(g, n, io, q, S, mb, np.inf, None)
        for j in range(n):
            t_out[a + j] = io[cgt.IO_T * cgt.PN + j]
            f_out[a + j] = int(io[cgt.IO_F * cgt.PN + j])


def _unit(x):
    return x / np.linalg.norm(x, axis=-1, keepdims=True)


def edge_probes(v, faces, normals, centre, radius, seed, n, tables=None):
    """About n probes at a closed mesh's shared vertices and edges (faces' outward unit normals,
    bounding sphere centre and radius), from in front of every face at their targets: (origins,
    unit directions, distances to the targets, probes dropped for want of such an origin).
    ``tables``: as targets_and_fans takes them (ProbeMesh.edge_probes passes its own)."""
    rng = np.random.default_rng(seed)
    nv = min(n // 10, len(v))
    tg, offs, fan = targets_and_fans(rng, v, faces, nv, n // 10, n - nv - n // 10, tables)
    o, t, ok = origins_in_front(rng, tg, offs, fan, normals, centre, radius)
    d = t - o
    dist = np.linalg.norm(d, axis=1)
    return o, d / dist[:, None], dist, int((~ok).sum())


class ProbeMesh:
    """A closed mesh with the tables the packet probes need: unique edges and their two faces,
    vertex fans (CSR), outward unit normals, bounding sphere."""

    def __init__(self, v, faces):
        self.v, self.faces = v, faces
        self.tris = np.ascontiguousarray(v[faces])
        self.v64 = v.astype(np.float64)
        self.tables = mesh_tables(faces, len(v))
        self.edges, self.ef, self.vstart, self.vf_f = self.tables
        self.keys = self.edges[:, 0] * len(v) + self.edges[:, 1]  # sorted (np.unique's order)
        self.normals = face_normals(v, faces)
        self.centre = 0.5 * (self.v64.min(0) + self.v64.max(0))
        self.radius = float(np.linalg.norm(self.v64 - self.centre, axis=1).max())

    def fans(self, vids):
        """Fans of vertices vids as CSR: (offsets (len(vids)+1,), face ids, owner index per face)."""
        k = self.vstart[vids + 1] - self.vstart[vids]
        offs = np.concatenate([[0], np.cumsum(k)])
        return offs, self.vf_f[csr_gather(self.vstart[vids], k)], np.repeat(np.arange(len(vids)), k)

    def edge_probes(self, seed, n):
        """edge_probes on this mesh."""
        return edge_probes(self.v, self.faces, self.normals, self.centre, self.radius, seed, n, self.tables)

    def edge_ids(self, a, b):
        key = np.minimum(a, b) * len(self.v) + np.maximum(a, b)
        i = np.searchsorted(self.keys, key)
        assert (self.keys[i] == key).all()
        return i

    def in_front(self, eyes, targets, faces, offs, min_cos):
        """Per target: the unit vector to its eye makes cos > min_cos with the normal of every
        face of its fan (faces[offs[i]:offs[i+1]])."""
        u = _unit(eyes - targets)
        dots = np.einsum("kc,kc->k", np.repeat(u, np.diff(offs), axis=0), self.normals[faces])
        return np.minimum.reduceat(dots, offs[:-1]) > min_cos

    def star_packets(self, rng, n_packets, min_cos=0.1):
        """Packets of up to PROBES probes around random vertices, one eye each.

        Packet of vertex v: v, then each vertex w of its one-ring, the midpoint of each spoke
        (v, w) and of each link edge (w, w') (the edges opposite v in its fan), then random points
        along the spokes and link edges; the eye is in front of all of v's faces, and ring vertices
        and link-edge points whose own faces do not all face the eye are left out.  Returns eyes
        (P, 3), unit directions (N, 3), distances to the targets (N,), packet offsets (P+1,) and
        the kind of each probe (N,): 0 v, 1 a ring vertex, 2 a spoke point, 3 a link-edge point;
        and how many slots were left out.
        """
        used = np.flatnonzero(np.diff(self.vstart) > 0)
        vids = used[rng.integers(0, len(used), n_packets)]
        offs, fan, owner = self.fans(vids)
        eyes, _, ok = origins_in_front(rng, self.v64[vids], offs, fan, self.normals, self.centre, self.radius,
                                       min_cos)
        eye = np.zeros((n_packets, 3))
        eye[ok] = eyes
        fv = self.faces[fan]  # fan face (v, w, w') in winding order from v
        pos = np.argmax(fv == vids[owner][:, None], axis=1)
        r = np.arange(len(fv))
        ring, opp = fv[r, (pos + 1) % 3], fv[r, (pos + 2) % 3]
        spoke, link = self.edge_ids(vids[owner], ring), self.edge_ids(ring, opp)
        k = np.diff(offs)
        # slots 1..PROBES-1: ring vertex, spoke and link midpoints of each fan face, then random edge points
        j = np.tile(np.arange(PROBES - 1), n_packets)
        p = np.repeat(np.arange(n_packets), PROBES - 1)
        first = j < 3 * k[p]
        jj = np.where(first, j, j - 3 * k[p])
        face = offs[p] + np.where(first, jj // 3, (jj // 2) % k[p])
        kind = np.where(first, 1 + jj % 3, 2 + jj % 2)
        e = np.where(kind == 2, spoke[face], link[face])
        s = np.where(first, 0.5, rng.uniform(0.0, 1.0, len(j)))[:, None]
        a, b = self.v64[self.edges[e, 0]], self.v64[self.edges[e, 1]]
        tg = np.where((kind == 1)[:, None], self.v64[ring[face]], a + s * (b - a))
        good = ok[p].copy()
        isv = kind == 1
        foffs, ffaces, _ = self.fans(ring[face[isv]])
        good[isv] &= self.in_front(eye[p[isv]], tg[isv], ffaces, foffs, min_cos)
        good[~isv] &= self.in_front(eye[p[~isv]], tg[~isv], self.ef[e[~isv]].reshape(-1),
                                    np.arange(0, 2 * int((~isv).sum()) + 1, 2), min_cos)
        dropped = int((ok[p] & ~good).sum())
        # packet by packet: v first, then the kept slots
        pk = np.concatenate([np.flatnonzero(ok), p[good]])
        order = np.argsort(pk, kind="stable")
        tgt = np.concatenate([self.v64[vids[ok]], tg[good]])[order]
        kinds = np.concatenate([np.zeros(int(ok.sum()), np.int64), kind[good]])[order]
        live = np.cumsum(ok) - 1
        pk = live[pk[order]]
        poffs = np.concatenate([[0], np.cumsum(np.bincount(pk, minlength=int(ok.sum())))])
        d = tgt - eyes[pk]
        dist = np.linalg.norm(d, axis=1)
        return eyes, d / dist[:, None], dist, poffs, kinds, dropped

    def edge_rows(self, rng, n, width, min_cos=0.1, margin=1e-3):
        """Cameras whose width x 1 images lie on random shared edges.

        For edge (a, b) and an eye in front of both its faces: the camera looks along the bisector
        of the directions to a and b (target as far away as the edge, so that target - eye keeps its
        precision), up is the normal of the plane through the eye and the edge, and the field of
        view spans the edge less ``margin``: with height 1 every pixel-centre ray lies in that
        plane and crosses the edge.  Returns the cameras, per camera and pixel the distance along
        the ray to the crossing, and the rays' unit directions (cameras, width, 3) (rays from the
        documented pinhole formula, reference.py's ref_camera_rays); each ray is checked to pass
        within float64 rounding of the edge line (1e-13 of the eye's largest coordinate plus the
        mesh's radius) and to cross it strictly inside the edge.
        """
        eids = rng.integers(0, len(self.edges), n)
        a, b = self.v64[self.edges[eids, 0]], self.v64[self.edges[eids, 1]]
        mid = 0.5 * (a + b)
        eyes, _, ok = origins_in_front(rng, mid, np.arange(0, 2 * n + 1, 2), self.ef[eids].reshape(-1),
                                       self.normals, self.centre, self.radius, min_cos)
        a, b, mid = a[ok], b[ok], mid[ok]
        ua, ub = _unit(a - eyes), _unit(b - eyes)
        fwd = _unit(ua + ub)
        target = eyes + np.linalg.norm(mid - eyes, axis=1, keepdims=True) * fwd
        up = np.cross(a - eyes, b - a)
        half = 0.5 * np.arctan2(np.linalg.norm(np.cross(ua, ub), axis=1), np.einsum("kc,kc->k", ua, ub))
        fov = np.degrees(2.0 * np.arctan(np.tan(half) * (1.0 - margin) / (width - 1)))
        cams = [Camera(eye=tuple(eyes[i]), target=tuple(target[i]), up=tuple(up[i]), fov=float(fov[i]))
                for i in range(len(eyes))]
        d = np.stack([ref_camera_rays(c.eye, c.target, c.up, c.fov, width, 1)[1] for c in cams])
        # closest points of the ray o + t d and the edge line a + s (b - a)
        e = (b - a)[:, None, :]
        w = (a - eyes)[:, None, :]
        n_ = np.cross(d, e)
        nn = np.einsum("cwk,cwk->cw", n_, n_)
        t = np.einsum("cwk,cwk->cw", np.cross(w, e), n_) / nn
        s = np.einsum("cwk,cwk->cw", np.cross(w, d), n_) / nn
        gap = np.abs(np.einsum("cwk,cwk->cw", w, n_)) / np.sqrt(nn)
        scale = np.abs(eyes).max(axis=1, keepdims=True) + self.radius
        assert (gap <= 1e-13 * scale).all(), f"row rays miss their edge line by up to {(gap / scale).max():.2e}"
        assert ((s > 0.0) & (s < 1.0)).all(), "a row ray crosses the edge line outside the edge"
        return cams, t, d


#: the packet tests: (watertight, float32 tests, key); the float32 watertight test's t is good to
#: float32 rounding, so its probes are judged within REL32.  A float32 test decides exactly for
#: the mesh with each vertex's sheared coordinates rounded (per ray, the same in every triangle:
#: a closed mesh still), about 3.6e-7 of the distance from the eye away from the float64 ones:
#: a probe aimed that close to a silhouette vertex may pass beside it and enter the mesh through
#: a farther triangle facing the eye.  So in float32 a hole is a miss, or a hit beyond the
#: target on a triangle facing away (the ray got inside); hits beyond it on a triangle facing
#: the eye are counted apart ("beside") and must stay rare.
TESTS = ((True, False, "wt"), (False, False, "fast"), (True, True, "wt32"))


REL32 = 1e-5


#: the largest share of float32 probes allowed to pass beside a silhouette vertex
BESIDE_MAX = 1e-5


def facing_eye(m, f, d):
    """Per ray: its hit triangle f (-1: a miss, then meaningless) faces the ray (unit or not)
    coming in along d, i.e. the ray enters the closed mesh m there."""
    return np.einsum("kc,kc->k", m.normals[np.maximum(f, 0)], d) < 0.0


def packet_counts(m, grid, rng, n_packets):
    """Star packets traced by the packet kernel with the three TESTS: counts (see cgt_report)."""
    eyes, d, dist, offs, kinds, _ = m.star_packets(rng, n_packets)
    c = {"packets": len(eyes), "probes": len(d), "kinds": np.bincount(kinds, minlength=4)}
    for wt, f32, key in TESTS:
        rel = REL32 if f32 else REL
        t = np.empty(len(d))
        f = np.empty(len(d), np.int64)
        fb = np.empty(len(eyes), np.int64)
        _trace_packets(grid_arrays(grid, m.tris), eyes, d, offs, wt, f32, t, f, fb)
        beyond = (f >= 0) & (t > dist * (1 + rel))
        hole = (f < 0) | beyond
        if f32:  # (see TESTS)
            beside = beyond & facing_eye(m, f, d)
            c[key + "_beside"] = int(beside.sum())
            hole &= ~beside
        c[key + "_holes"] = np.bincount(kinds[hole], minlength=4)
        c[key + "_at"] = int((np.abs(t - dist) <= rel * dist).sum())
        c[key + "_split"] = int(fb.sum())
    return c


def row_counts(m, grid, rng, n_cameras, width=ROW_WIDTH):
    """Edge-row cameras rendered by Renderer.render with traversal="cgt" and the three TESTS:
    counts (see cgt_report)."""
    cams, tref, dirs = m.edge_rows(rng, n_cameras, width)
    r = Renderer()
    c = {"edges": len(cams), "rays": len(cams) * width}
    for wt, f32, key in TESTS:
        rel = REL32 if f32 else REL
        holes = at = fb = 0
        rp = RenderParams(width=width, height=1, traversal="cgt", watertight=wt, shading="normal",
                          packet_precision="float32" if f32 else "float64")
        for cam, tr, d in zip(cams, tref, dirs):
            out = r.render(grid, m.tris, cam, rp)
            t = out.t.reshape(-1).astype(np.float64)  # a float32 buffer: rounding 6e-8 < REL
            f = out.tri.reshape(-1)
            hole = (f < 0) | (t > tr * (1 + rel))
            if f32:  # a hit beyond the target on a triangle facing the eye is not a hole (see TESTS)
                hole &= ~((f >= 0) & facing_eye(m, f, d))
            holes += int(hole.sum())
            at += int((np.abs(t - tr) <= rel * tr).sum())
            fb += out.stats["split_rays"]
        c[key + "_holes"], c[key + "_at"], c[key + "_split"] = holes, at, fb
    return c


def cgt_counts(m, grid, rng, n_rays, n_row_rays, batch=200_000):
    """(packet counts, camera-row counts) of star packets until n_rays were traced and camera rows
    until n_row_rays, in batches of about ``batch`` rays, on the ProbeMesh m and its grid."""
    pk = rows = {}
    while not pk or pk["probes"] < n_rays:
        left = n_rays - (pk["probes"] if pk else 0)
        pk = add_counts(pk, packet_counts(m, grid, rng, min(batch, left) // 60 + 1))  # ~63 rays a packet
    while not rows or rows["rays"] < n_row_rays:
        left = n_row_rays - (rows["rays"] if rows else 0)
        rows = add_counts(rows, row_counts(m, grid, rng, -(-min(batch, left) // ROW_WIDTH)))
    return pk, rows


def add_counts(a, b):
    return {k: a[k] + b[k] for k in b} if a else b


def cgt_report(label, pk, rows, secs, width=ROW_WIDTH):
    """Print the FIGURE line of packet counts pk and camera-row counts rows and check them:
    0 holes with the watertight test, in float64 and in float32; most probes hit at their target
    (nothing blocks them earlier); and the fast test leaks somewhere (the probes are close enough
    to the edges to catch a test that is not watertight).  Every probe is traced in a packet: a
    star packet whose rays disagree on the direction class is traced as one packet per class."""
    hw, hf, n_pk, n_rows = pk["wt_holes"], pk["fast_holes"], pk["probes"], rows["rays"]
    k = pk["kinds"]
    print(f"FIGURE cgt holes {label}: {n_pk + n_rows} CGT rays in {secs:.1f} s. Packets: {n_pk} probes in "
          f"{pk['packets']} packets ({k[0]} vertices, {k[1]} ring vertices, {k[2]} spoke and {k[3]} link-edge "
          f"points; {pk['wt_split']} rays in packets split by direction class); watertight: {int(hw.sum())} holes, "
          f"{pk['wt_at']} probes hit at their target; fast (Moller-Trumbore): {int(hf.sum())} holes, rate "
          f"{100 * hf.sum() / n_pk:.3f}% (by kind {hf.tolist()}). Camera rows (Renderer, cgt, {width}x1 images): "
          f"{n_rows} pixel rays on {rows['edges']} edges ({rows['wt_split']} in split packets); watertight: "
          f"{rows['wt_holes']} holes, {rows['wt_at']} at their target; fast: {rows['fast_holes']} holes, rate "
          f"{100 * rows['fast_holes'] / n_rows:.3f}%. Watertight in float32: packets {int(pk['wt32_holes'].sum())} "
          f"holes, {pk['wt32_at']} at their target, {pk['wt32_beside']} beside a silhouette vertex; rows "
          f"{rows['wt32_holes']} holes, {rows['wt32_at']} at their target")
    assert pk["wt32_beside"] <= BESIDE_MAX * n_pk, f"{label}: {pk['wt32_beside']} float32 probes passed beside"
    for key, what in (("wt", "watertight test"), ("wt32", "watertight test in float32")):
        assert pk[key + "_holes"].sum() == 0, (
            f"{label}: the {what} let packet probes through: {pk[key + '_holes'].tolist()} (by kind)")
        assert rows[key + "_holes"] == 0, f"{label}: the {what} let {rows[key + '_holes']} camera-row rays through"
        for n, c in ((n_pk, pk), (n_rows, rows)):
            assert c[key + "_at"] > 0.5 * n, f"{label} ({what}): {c[key + '_at']} of {n} probes hit at their target"
    assert hf.sum() > 0 and rows["fast_holes"] > 0, f"{label}: the probes do not find the fast test's leaks"
