"""A frame rendered as packets: the camera rays of a block of pixels, writing a packet's pixels,
the tiles of a frame (_render_tiles, a kernel that threads share) and the frame on any number of
threads (cgt_render)."""

import math

import numpy as np
from numba import njit

from ...compiles import inner
from ...grid.atomics import atomic_add
from ...threads import on_threads
from ..prefetch import _prefetch_write
from ..records import Buffers, Scratch
from ..shade import BACKGROUND, _u8, cost_rgb, facing_normal, lambert_rgb, normal_rgb, scene_id, shadow_ray
from .rays import (IO_DX, IO_DY, IO_DZ, IO_F, IO_NT, IO_OX, IO_OY, IO_OZ, IO_T, IO_TMAX, IO_W, MBOX, NIO, NS, PN,
                   _U_2PN, _U_DX, _U_DY, _U_DZ, _U_F, _U_NC, _U_NT, _U_OX, _U_OY, _U_OZ, _U_PN, _U_T, _U_TMAX,
                   PacketQuery)
from .walk import trace_packet_grids


#: the runs of consecutive tiles a frame on several threads is shared out in (cgt_render,
#: gridrt.trace.render.dda_render)
CHUNKS = 256


def tile_runs(view):
    """(next, per) for the render kernels that threads share: a fresh (1,) int64 counter of the
    runs taken and ``per``, the tiles of one run, so that the view's tiles (row-major) make at most
    CHUNKS runs."""
    ntiles = ((view.W + view.tile - 1) // view.tile) * ((view.H + view.tile - 1) // view.tile)
    return np.zeros(1, np.int64), -(-ntiles // max(1, min(ntiles, CHUNKS)))


@inner(cache=True, _nrt=False, error_model="numpy")
def _camera_rays(basis, W, H, px0, py0, pw, ph, io):
    """Camera rays of the pw x ph pixels from (px0, py0) into io, row by row.

    The directions are camera.pixel_dir's, operation for operation (so bit for bit; the tests
    compare whole images with the DDA kernel, which calls pixel_dir), with the basis read into
    locals first so that the loop vectorizes.
    """
    ex, ey, ez = basis[0, 0], basis[0, 1], basis[0, 2]
    f0, f1, f2 = basis[1, 0], basis[1, 1], basis[1, 2]
    r0, r1, r2 = basis[2, 0], basis[2, 1], basis[2, 2]
    u0, u1, u2 = basis[3, 0], basis[3, 1], basis[3, 2]
    th = basis[4, 0]
    asp = W / H
    for yy in range(ph):
        sy = (1.0 - 2.0 * (py0 + yy + 0.5) / H) * th
        row = np.uint64(yy * pw)  # unsigned indices: no wraparound test, so the loop vectorizes
        for xx in range(pw):
            j = row + np.uint64(xx)
            sx = (2.0 * (px0 + xx + 0.5) / W - 1.0) * th * asp
            dx = f0 + sx * r0 + sy * u0
            dy = f1 + sx * r1 + sy * u1
            dz = f2 + sx * r2 + sy * u2
            n = math.sqrt(dx * dx + dy * dy + dz * dz)
            io[_U_OX + j] = ex
            io[_U_OY + j] = ey
            io[_U_OZ + j] = ez
            io[_U_DX + j] = dx / n
            io[_U_DY + j] = dy / n
            io[_U_DZ + j] = dz / n
            io[_U_TMAX + j] = np.inf


@inner(cache=True, _nrt=False, error_model="numpy")
def _write_out(io, col, W, block, grids, out):
    """Write a packet's results (io) and colours (col, 3 * PN) for its block = (px0, py0, pw, ph)
    of pixels (pw x ph from (px0, py0), W pixels a row) into the image buffers out
    (:class:`gridrt.trace.records.Buffers`; the triangles' scene ids through the grids' ids maps
    when there are several grids), given flat: img (H * W * 4,) uint8, t (H * W,) float32, tri,
    cost, cells (H * W,) int32.  Returns (hits, sum of tests, sum of cells).  Flat buffers and
    unsigned indices (no wraparound tests) let the row loop vectorize."""
    px0, py0, pw, ph = block
    img, tbuf, idbuf, costbuf, cellbuf = out.img, out.t, out.tri, out.cost, out.cells
    hits = 0
    tests = 0
    cells = 0
    for yy in range(ph):
        p0 = np.uint64((py0 + yy) * W + px0)
        jr = np.uint64(yy * pw)
        for xx in range(pw):
            p = p0 + np.uint64(xx)
            j = jr + np.uint64(xx)
            f = int(io[_U_F + j])
            nt = int(io[_U_NT + j])
            nc = int(io[_U_NC + j])
            tbuf[p] = np.float32(io[_U_T + j])
            idbuf[p] = f
            costbuf[p] = nt
            cellbuf[p] = nc
            q = np.uint64(4) * p
            img[q] = _u8(col[j])
            img[q + np.uint64(1)] = _u8(col[_U_PN + j])
            img[q + np.uint64(2)] = _u8(col[_U_2PN + j])
            img[q + np.uint64(3)] = np.uint8(255)
            hits += f >= 0
            tests += nt
            cells += nc
    if len(grids) > 1 and hits > 0:  # scene ids of the grids' triangles
        for yy in range(ph):
            for xx in range(pw):
                j = yy * pw + xx
                idbuf[(py0 + yy) * W + px0 + xx] = scene_id(grids, int(io[IO_W * PN + j]), int(io[IO_F * PN + j]))
    return hits, tests, cells


@inner(cache=True, _nrt=False)
def _prefetch_tile(ti, ntx, view, out):
    """Prefetch (for writing) the lines of the flat output buffers out that tile ti (of ntx tiles
    a row) of the view covers."""
    tile, W, H = view.tile, view.W, view.H
    img, tbuf, idbuf, costbuf, cellbuf = out.img, out.t, out.tri, out.cost, out.cells
    tx0 = (ti % ntx) * tile
    ty0 = (ti // ntx) * tile
    tx1 = min(tx0 + tile, W)
    for y in range(ty0, min(ty0 + tile, H)):
        for x in range(tx0, tx1, 16):  # 16 pixels = one 64-byte line of a 4-byte buffer
            p = y * W + x
            _prefetch_write(tbuf, p)
            _prefetch_write(idbuf, p)
            _prefetch_write(costbuf, p)
            _prefetch_write(cellbuf, p)
            _prefetch_write(img, 4 * p)
        p = y * W + tx1 - 1  # the last line of the row when the tile is not line-aligned
        _prefetch_write(tbuf, p)
        _prefetch_write(idbuf, p)
        _prefetch_write(costbuf, p)
        _prefetch_write(cellbuf, p)
        _prefetch_write(img, 4 * p)


@njit(cache=True, _nrt=False, error_model="numpy", nogil=True)
def _render_tiles(grids, view, looks, light, packets, tiles, out, scratch):
    """Render the view's tiles (:class:`gridrt.trace.records.View`, row-major) in runs of
    tiles = (next, per): next (1,) int64 counts the runs of ``per`` consecutive tiles taken so far,
    and each call takes the next run (an atomic add) until none is left, so that calls on several
    threads share the frame (cgt_render).  Each tile as packets of up to kw x kh pixels (packets:
    :class:`gridrt.trace.records.Packets`): trace and shade each packet (looks:
    :class:`gridrt.trace.records.Shading`; its shadow rays as another packet) into the flat
    buffers out (see _write_out), with the worker's scratch (:class:`gridrt.trace.records.Scratch`).
    ``light`` is None without shadows: numba then compiles no shadow path at all (a first frame
    without shadows compiles about a third less), and the (3,) light position with them.
    Adds (hits, triangle tests, cells, split rays) to scratch.acc (4,) int64.  (One function
    without reference counting: numba would otherwise count references to every array argument
    of every call.)"""
    basis, W, H, tile = view.basis, view.W, view.H, view.tile
    mode, off, watertight = looks.mode, looks.off, looks.watertight
    f32, kw, kh, far = packets.f32, packets.kw, packets.kh, packets.far
    nxt, per = tiles
    ntiles = ((W + tile - 1) // tile) * ((H + tile - 1) // tile)
    S, io, io2, sio, sj, col, mb, acc = (scratch.S, scratch.io, scratch.io2, scratch.sio, scratch.sj, scratch.col,
                                         scratch.mb, scratch.acc)
    primary = PacketQuery(0.0, watertight, False, f32, far)  # the nearest hit
    shadow = PacketQuery(0.0, watertight, True, f32, far)  # any hit
    ntx = (W + tile - 1) // tile
    ex, ey, ez = basis[0, 0], basis[0, 1], basis[0, 2]
    while True:
        t0 = atomic_add(nxt, 0, np.int64(1)) * per
        if t0 >= ntiles:
            break
        t1 = min(t0 + per, ntiles)
        _prefetch_tile(t0, ntx, view, out)
        for ti in range(t0, t1):
            tx0 = (ti % ntx) * tile
            ty0 = (ti // ntx) * tile
            tx1 = min(tx0 + tile, W)
            ty1 = min(ty0 + tile, H)
            if ti + 1 < t1:  # the next tile's output lines load while this tile is traced
                _prefetch_tile(ti + 1, ntx, view, out)
            for py0 in range(ty0, ty1, kh):
                for px0 in range(tx0, tx1, kw):
                    pw = min(kw, tx1 - px0)
                    ph = min(kh, ty1 - py0)
                    n = pw * ph
                    _camera_rays(basis, W, H, px0, py0, pw, ph, io)
                    nfb = trace_packet_grids(grids, n, io, io2, primary, S, mb)
                    # colours into col (3 * PN), shadow rays of lit hits into sio
                    m = 0
                    for j in range(n):
                        f = int(io[IO_F * PN + j])
                        r, g, b = BACKGROUND[0], BACKGROUND[1], BACKGROUND[2]
                        if mode == 2:
                            r, g, b = cost_rgb(int(io[IO_NT * PN + j]))
                        elif f >= 0 and mode != 3:  # (mode 3: the material pass colours the hits)
                            t = io[IO_T * PN + j]
                            dx = io[IO_DX * PN + j]
                            dy = io[IO_DY * PN + j]
                            dz = io[IO_DZ * PN + j]
                            nx, ny, nz, dn = facing_normal(grids[int(io[IO_W * PN + j])].tris, f, dx, dy, dz)
                            if mode == 1:
                                r, g, b = normal_rgb(nx, ny, nz)
                            else:
                                if light is None:  # no shadows: numba prunes the shadow path (light: NoneType)
                                    s = -dn
                                else:
                                    need, sox, soy, soz, lx, ly, lz, ld, s = shadow_ray(
                                        (ex, ey, ez), t, (dx, dy, dz), (nx, ny, nz), light, off)
                                    if need:
                                        sio[IO_OX * PN + m] = sox
                                        sio[IO_OY * PN + m] = soy
                                        sio[IO_OZ * PN + m] = soz
                                        sio[IO_DX * PN + m] = lx
                                        sio[IO_DY * PN + m] = ly
                                        sio[IO_DZ * PN + m] = lz
                                        sio[IO_TMAX * PN + m] = ld
                                        sj[m] = j
                                        col[j] = s  # lit unless the shadow ray hits something
                                        m += 1
                                        continue
                                r, g, b = lambert_rgb(s)
                        col[j] = r
                        col[PN + j] = g
                        col[2 * PN + j] = b
                    if light is not None and m > 0:
                        nfb += trace_packet_grids(grids, m, sio, io2, shadow, S, mb)
                        for q in range(m):
                            j = sj[q]
                            r, g, b = lambert_rgb(col[j] if sio[IO_F * PN + q] < 0.0 else 0.0)
                            col[j] = r
                            col[PN + j] = g
                            col[2 * PN + j] = b
                    hits, tests, cells = _write_out(io, col, W, (px0, py0, pw, ph), grids, out)
                    acc[0] += hits
                    acc[1] += tests
                    acc[2] += cells
                    acc[3] += nfb


def cgt_render(grids, view, looks, light, packets, out, threads=1):
    """Render the view into the image buffers out (:class:`gridrt.trace.records.Buffers`, (H, W, 4)
    and (H, W)) on ``threads`` threads: each runs the kernel _render_tiles with its own scratch,
    and they share the frame's tiles in runs (CHUNKS of them, on any thread count) through one
    counter (gridrt.threads.on_threads).  The same buffers and sums bit for bit on any number of
    threads, as no pixel depends on which thread renders it.  Returns (4,) int64: pixels hit, the
    sums of out.cost and out.cells, and the number of rays traced in packets split by direction
    class (trace_packet).  A Python function around one kernel, compiled once for every thread
    count: numba's parallel loop would compile the whole call tree a second time, in seconds."""
    W, H = view.W, view.H
    runs = tile_runs(view)
    flat = Buffers(out.img.reshape(H * W * 4), out.t.reshape(H * W), out.tri.reshape(H * W), out.cost.reshape(H * W),
                   out.cells.reshape(H * W))

    def work(k):
        acc = np.zeros(4, np.int64)
        _render_tiles(grids, view, looks, light, packets, runs, flat,
                      Scratch(np.empty(NS * PN), np.empty(NIO * PN), np.empty(NIO * PN), np.empty(NIO * PN),
                              np.empty(PN, np.int64), np.empty(3 * PN), np.empty(MBOX, np.int32), acc))
        return acc

    return np.sum(on_threads(threads, work), axis=0)
