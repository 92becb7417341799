"""The ``material`` shading mode: a pass over the primary hits that colours them with the scene's
materials, textures, smooth normals and lights (gridrt.scene.surface has the formula).

It runs after the render kernel has filled the hit distance and triangle buffers (DDA or CGT, any
grid kind, one grid or the static/moving split: it reads only the scene ids of the hits), so the
traversal kernels stay as they are; in this mode they leave the hits' pixels to it (shading
mode 3).  Per hit pixel:

* the hit's barycentrics (w0, w1, w2) = (1 - u - v, u, v) come from the float64 ray-triangle
  test of the triangle hit (the camera ray against the scene's triangle in the render's frame),
  clamped onto the triangle; the hit point is the triangle's point of those barycentrics, so it
  lies on the triangle's plane to float64 precision (not t's float32);
* uv, vertex colour and shading normal are the corners' values weighted by the barycentrics;
  the normal is normalised, and a zero normal (no normals in the file) is the geometric one;
  the geometric normal n_g is turned towards the viewer and the shading normal n_s to n_g's side;
* the texel is filtered bilinearly between the four texels around (u W - 1/2, v H - 1/2), each
  wrapped by the texture's mode (repeat, clamp to edge, mirrored repeat);
* a light lights the hit when it lies on the visible side of the surface (n_g . l > 0) and
  n_s . l > 0; its weight is n_s . l (times 1 / d^2 with inverse-square falloff).  With shadows a
  shadow ray from p + n_g * off towards the light (its direction the vector to a point light, or
  2 * diag times the unit vector to a directional one, tmax 1) must hit nothing; shadow rays are
  cast as a batch per light (gridrt.trace.batch: coherent runs as CGT packets with the ``cgt``
  traversal, one at a time with ``dda``), tile by tile of the image and from the light's end of
  the segment back to the hit (:func:`light_segments`): a point light's rays then share one origin,
  and a ray blocked near its light (inside a lamp's shade) stops there instead of crossing the
  scene first.  Over triangles that stay from frame to frame, the segments a light's map shows
  clear (gridrt.trace.lightmap) are left out of that grid's casts.

The pass takes a row's pixels LANES at a time (:func:`_shade_row`): their triangles' corners
gathered into scratch rows, then every step above in loops over the lanes without branches, which
LLVM compiles to packed float64 code (512-bit on AVX-512), with the same operations in the same
order as one pixel at a time, so the colours do not depend on the lanes.

A scene without lights is lit by one default light (gridrt.trace.render.default_light, colour 1,
no falloff); a render without a scene surface uses one material of gridrt's default colours.
"""

import math

import numpy as np
from numba import njit, prange

from ..arrays import read_only
from ..compiles import inner
from ..grid.atomics import atomic_add
from ..scene.surface import (AMBIENT_FRACTION, DEFAULT_DIFFUSE, FALLOFF_INVERSE_SQUARE, LIGHT_DIRECTIONAL, LIGHT_POINT,
                             Surface)
from ..threads import on_threads
from .records import SurfaceArrays
from .shade import put_pixel
from .traverse import _clip_box


#: pixels shaded side by side: the lanes of the material pass's vector loops (float64, two
#: 512-bit registers a row of scratch)
LANES = 16
# float64 scratch rows of a block of LANES hits (each LANES apart): the corners as gathered
# (vertices, normals, uv, vertex colours; the material's diffuse and ambient colours), then what
# the pass computes from them
R_V, R_N, R_UV, R_COL, R_DIF, R_AMB = 0, 9, 18, 24, 33, 36
R_NS, R_NG, R_P, R_TUV, R_C, R_TEX, R_TVD, R_TVA, R_RGB = 39, 42, 45, 48, 50, 53, 56, 59, 62
ROWS = 65
# int64 scratch rows: the texture of each hit (-1: none), its offset, size and wrap modes, and
# its four texels' offsets
I_K, I_INFO, I_TEXEL = 0, 1, 6
IROWS = 10


@inner(cache=True, _nrt=False, error_model="numpy")
def _gather(n, fs, surf, buf):
    """The corners of the scene triangles fs[:n] (a miss, -1, reads triangle 0, unused) into the
    rows of buf: vertices, and where the surface has them normals, uv and vertex colours (else
    those rows keep the zero _shade_row wrote); each one's material's diffuse and ambient
    colours.  A loop per kind of value, so that a surface without one does not test for it per
    hit."""
    C = LANES
    stris, normals, uv, colors = surf.tris, surf.normals, surf.uv, surf.colors
    material, diffuse, ambient = surf.material, surf.diffuse, surf.ambient
    for j in range(n):
        f = max(fs[j], 0)
        for c in range(9):
            buf[(R_V + c) * C + j] = stris[f, c // 3, c % 3]
        m = material[f]
        for a in range(3):
            buf[(R_DIF + a) * C + j] = diffuse[m, a]
            buf[(R_AMB + a) * C + j] = ambient[m, a]
    if normals.shape[0] > 0:
        for j in range(n):
            f = max(fs[j], 0)
            for c in range(9):
                buf[(R_N + c) * C + j] = normals[f, c // 3, c % 3]
    if uv.shape[0] > 0:
        for j in range(n):
            f = max(fs[j], 0)
            for c in range(6):
                buf[(R_UV + c) * C + j] = uv[f, c // 2, c % 2]
    if colors.shape[0] > 0:
        for j in range(n):
            f = max(fs[j], 0)
            for c in range(9):
                buf[(R_COL + c) * C + j] = colors[f, c // 3, c % 3]


@inner(cache=True, _nrt=False, error_model="numpy")
def _surface_lanes(x0, y, view, buf):
    """What the camera rays of pixels x0 .. x0 + LANES - 1 of row y see on the triangles whose
    corners _gather put into buf, in one loop over the lanes that LLVM vectorizes (no branch: each
    choice computes both sides and keeps one).  Per hit, into the rows of buf:

    * the barycentrics (w0, w1, w2) = (1 - u - v, u, v) of the float64 ray-triangle test, clamped
      onto the triangle (u, v >= 0, scaled down where u + v > 1); the centroid where the
      determinant or u, v is zero or not finite;
    * the hit point p = w0 v0 + w1 v1 + w2 v2 (R_P), on the triangle's plane to float64
      precision (not t's float32);
    * the unit geometric normal n_g (R_NG), turned towards the viewer (against the ray for a
      degenerate triangle); the shading normal n_s (R_NS): the corner normals weighted by the
      barycentrics, normalised, turned to n_g's side (n_g itself where that sum is under 1e-12 or
      not finite: no normals in the file);
    * uv (R_TUV) and vertex colour (R_C), the corners' weighted by the barycentrics."""
    C = LANES
    basis, W, H = view.basis, view.W, view.H
    ex, ey, ez = basis[0, 0], basis[0, 1], basis[0, 2]
    th = basis[4, 0]
    asp = W / H
    wy = (1.0 - 2.0 * (y + 0.5) / H) * th
    for j in range(C):
        # the ray's direction: gridrt.camera.pixel_dir's, operation for operation (a call to it
        # keeps this loop from vectorizing when pixel_dir comes from the cache, as machine code)
        wx = (2.0 * (x0 + j + 0.5) / W - 1.0) * th * asp
        dx = basis[1, 0] + wx * basis[2, 0] + wy * basis[3, 0]
        dy = basis[1, 1] + wx * basis[2, 1] + wy * basis[3, 1]
        dz = basis[1, 2] + wx * basis[2, 2] + wy * basis[3, 2]
        dn = math.sqrt(dx * dx + dy * dy + dz * dz)
        dx, dy, dz = dx / dn, dy / dn, dz / dn
        v0x, v0y, v0z = buf[(R_V + 0) * C + j], buf[(R_V + 1) * C + j], buf[(R_V + 2) * C + j]
        e1x, e1y, e1z = buf[(R_V + 3) * C + j] - v0x, buf[(R_V + 4) * C + j] - v0y, buf[(R_V + 5) * C + j] - v0z
        e2x, e2y, e2z = buf[(R_V + 6) * C + j] - v0x, buf[(R_V + 7) * C + j] - v0y, buf[(R_V + 8) * C + j] - v0z
        px = dy * e2z - dz * e2y
        py = dz * e2x - dx * e2z
        pz = dx * e2y - dy * e2x
        det = e1x * px + e1y * py + e1z * pz
        bad = (det == 0.0) | (not math.isfinite(det))
        inv = 1.0 / (1.0 if bad else det)  # (one division: its latency is most of a hit's shading)
        sx, sy, sz = ex - v0x, ey - v0y, ez - v0z
        u = (sx * px + sy * py + sz * pz) * inv
        qx = sy * e1z - sz * e1y
        qy = sz * e1x - sx * e1z
        qz = sx * e1y - sy * e1x
        v = (dx * qx + dy * qy + dz * qz) * inv
        bad = bad | (not (math.isfinite(u) & math.isfinite(v)))
        u = u if u > 0.0 else 0.0
        v = v if v > 0.0 else 0.0
        s = u + v
        r = 1.0 / (s if s > 1.0 else 1.0)
        u, v = u * r, v * r
        w0 = 1.0 / 3.0 if bad else 1.0 - u - v
        w1 = 1.0 / 3.0 if bad else u
        w2 = 1.0 / 3.0 if bad else v
        for a in range(3):
            buf[(R_P + a) * C + j] = (w0 * buf[(R_V + a) * C + j] + w1 * buf[(R_V + 3 + a) * C + j]
                                      + w2 * buf[(R_V + 6 + a) * C + j])
        # geometric normal (v1 - v0) x (v2 - v0), towards the viewer (against the ray when degenerate)
        nx = e1y * e2z - e1z * e2y
        ny = e1z * e2x - e1x * e2z
        nz = e1x * e2y - e1y * e2x
        nn = math.sqrt(nx * nx + ny * ny + nz * nz)
        zero = nn == 0.0
        nn = 1.0 if zero else nn
        gx = 0.0 if zero else nx / nn
        gy = 0.0 if zero else ny / nn
        gz = 0.0 if zero else nz / nn
        none = (gx == 0.0) & (gy == 0.0) & (gz == 0.0)
        gx, gy, gz = (-dx if none else gx), (-dy if none else gy), (-dz if none else gz)
        back = gx * dx + gy * dy + gz * dz > 0.0
        gx, gy, gz = (-gx if back else gx), (-gy if back else gy), (-gz if back else gz)
        mx = w0 * buf[(R_N + 0) * C + j] + w1 * buf[(R_N + 3) * C + j] + w2 * buf[(R_N + 6) * C + j]
        my = w0 * buf[(R_N + 1) * C + j] + w1 * buf[(R_N + 4) * C + j] + w2 * buf[(R_N + 7) * C + j]
        mz = w0 * buf[(R_N + 2) * C + j] + w1 * buf[(R_N + 5) * C + j] + w2 * buf[(R_N + 8) * C + j]
        mn = math.sqrt(mx * mx + my * my + mz * mz)
        ok = (mn > 1e-12) & math.isfinite(mn)
        rm = 1.0 / (mn if ok else 1.0)
        nsx, nsy, nsz = (mx * rm if ok else gx), (my * rm if ok else gy), (mz * rm if ok else gz)
        flip = nsx * gx + nsy * gy + nsz * gz < 0.0  # (never where n_s is n_g)
        buf[R_NS * C + j] = -nsx if flip else nsx
        buf[(R_NS + 1) * C + j] = -nsy if flip else nsy
        buf[(R_NS + 2) * C + j] = -nsz if flip else nsz
        buf[R_NG * C + j], buf[(R_NG + 1) * C + j], buf[(R_NG + 2) * C + j] = gx, gy, gz
        for a in range(2):
            buf[(R_TUV + a) * C + j] = (w0 * buf[(R_UV + a) * C + j] + w1 * buf[(R_UV + 2 + a) * C + j]
                                        + w2 * buf[(R_UV + 4 + a) * C + j])
        for a in range(3):
            buf[(R_C + a) * C + j] = (w0 * buf[(R_COL + a) * C + j] + w1 * buf[(R_COL + 3 + a) * C + j]
                                      + w2 * buf[(R_COL + 6 + a) * C + j])


@inner(cache=True, _nrt=False, error_model="numpy")
def _reduce(c, mode):
    """A texture coordinate brought into [0, 1] (mode 1, clamp), [0, 1) (0, repeat) or [0, 2)
    (2, mirrored repeat) before it is scaled to texels, so a huge coordinate never overflows an
    integer.  All three computed and one kept: no branch in the lanes' loop."""
    clamp = min(max(c, 0.0), 1.0)
    mirror = c - 2.0 * math.floor(0.5 * c)
    repeat = c - math.floor(c)
    return clamp if mode == 1 else (mirror if mode == 2 else repeat)


@inner(cache=True, _nrt=False, error_model="numpy")
def _wrap(i, n, mode):
    """Texel index i in [-1, 2n] (the reduced coordinate's, see _reduce) wrapped into [0, n) by mode
    (0 repeat, 1 clamp, 2 mirror), with compares (an integer division costs more than the rest
    of the lookup), all three computed and one kept."""
    clamp = 0 if i < 0 else (n - 1 if i >= n else i)
    m = i + 2 * n if i < 0 else (i - 2 * n if i >= 2 * n else i)
    mirror = m if m < n else 2 * n - 1 - m
    repeat = i + n if i < 0 else (i - n if i >= n else i)
    return clamp if mode == 1 else (mirror if mode == 2 else repeat)


@inner(cache=True, _nrt=False, error_model="numpy")
def _texel_lanes(n, fs, surf, buf, ib):
    """The texels at the uv (R_TUV) of the hits fs[:n] in buf into R_TEX ((1, 1, 1) for a hit
    whose material has no texture): each texture (image convention, (0, 0) top-left) filtered
    bilinearly between the four texels around (u W - 1/2, v H - 1/2), each wrapped by the
    texture's mode.  Its size, offset and modes gathered into the int64 rows of ib, the texels'
    offsets and weights computed side by side, then the texels fetched."""
    C = LANES
    material, texture, tex_data, tex_info = surf.material, surf.texture, surf.tex_data, surf.tex_info
    if tex_data.shape[0] == 0:
        buf[R_TEX * C:(R_TEX + 3) * C] = 1.0
        return
    for j in range(C):
        k = texture[material[max(fs[j], 0)]] if j < n else -1
        ib[I_K * C + j] = k
        for a in range(5):
            ib[(I_INFO + a) * C + j] = tex_info[max(k, 0), a]
    for j in range(C):
        off, w, h = ib[I_INFO * C + j], ib[(I_INFO + 1) * C + j], ib[(I_INFO + 2) * C + j]
        wu, wv = ib[(I_INFO + 3) * C + j], ib[(I_INFO + 4) * C + j]
        x = _reduce(buf[R_TUV * C + j], wu) * w - 0.5
        y = _reduce(buf[(R_TUV + 1) * C + j], wv) * h - 0.5
        x0 = math.floor(x)
        y0 = math.floor(y)
        buf[R_TEX * C + j] = x - x0
        buf[(R_TEX + 1) * C + j] = y - y0
        ix0 = _wrap(np.int64(x0), w, wu)
        ix1 = _wrap(np.int64(x0) + 1, w, wu)
        iy0 = _wrap(np.int64(y0), h, wv)
        iy1 = _wrap(np.int64(y0) + 1, h, wv)
        some = ib[I_K * C + j] >= 0  # (a lane without texture reads the first texel)
        ib[I_TEXEL * C + j] = off + (iy0 * w + ix0) * 3 if some else 0
        ib[(I_TEXEL + 1) * C + j] = off + (iy0 * w + ix1) * 3 if some else 0
        ib[(I_TEXEL + 2) * C + j] = off + (iy1 * w + ix0) * 3 if some else 0
        ib[(I_TEXEL + 3) * C + j] = off + (iy1 * w + ix1) * 3 if some else 0
    k255 = 1.0 / 255.0
    for j in range(C):
        fx, fy = buf[R_TEX * C + j], buf[(R_TEX + 1) * C + j]
        w00 = (1.0 - fx) * (1.0 - fy)
        w01 = fx * (1.0 - fy)
        w10 = (1.0 - fx) * fy
        w11 = fx * fy
        a, b = ib[I_TEXEL * C + j], ib[(I_TEXEL + 1) * C + j]
        c, d = ib[(I_TEXEL + 2) * C + j], ib[(I_TEXEL + 3) * C + j]
        some = ib[I_K * C + j] >= 0
        for e in range(3):
            t = w00 * tex_data[a + e] + w01 * tex_data[b + e] + w10 * tex_data[c + e] + w11 * tex_data[d + e]
            buf[(R_TEX + e) * C + j] = t * k255 if some else 1.0


@inner(cache=True, _nrt=False, error_model="numpy")
def light_weight(lights, li, p, ng, ns):
    """(weight, lx, ly, lz, dist) of light li at the hit p with facing normals n_g, n_s (3-tuples):
    the unit vector l to the light, its distance (inf for a directional light) and weight n_s . l
    (over d^2 with inverse-square falloff), 0 when the light is behind the surface (all zero for
    a point light at the hit or at no finite distance).  No branch on the hit's values: it
    vectorizes in the lanes' loop of :func:`_shade_lanes`."""
    px, py, pz = p
    ngx, ngy, ngz = ng
    nsx, nsy, nsz = ns
    directional = lights[li, 0] == LIGHT_DIRECTIONAL
    lx = lights[li, 1] if directional else lights[li, 1] - px
    ly = lights[li, 2] if directional else lights[li, 2] - py
    lz = lights[li, 3] if directional else lights[li, 3] - pz
    dist = math.sqrt(lx * lx + ly * ly + lz * lz)
    gone = (not directional) & ((not (dist > 0.0)) | (not math.isfinite(dist)))
    r = 1.0 / (dist if not (directional | gone) else 1.0)
    dist = np.inf if directional else dist
    lx, ly, lz = lx * r, ly * r, lz * r
    facing = ngx * lx + ngy * ly + ngz * lz > 0.0
    s = nsx * lx + nsy * ly + nsz * lz
    lit = facing & (s > 0.0) & (not gone)
    square = (lights[li, 7] == FALLOFF_INVERSE_SQUARE) & (lights[li, 0] == LIGHT_POINT)
    s = s * (r * r) if square else s
    return ((s if lit else 0.0), (0.0 if gone else lx), (0.0 if gone else ly), (0.0 if gone else lz),
            (0.0 if gone else dist))


@inner(cache=True, _nrt=False, error_model="numpy")
def _shade_lanes(lights, buf):
    """The colour of each of the LANES hits in buf (R_RGB): T V A plus every light's T V D times its
    colour and weight (:func:`light_weight`), side by side."""
    C = LANES
    for j in range(C):
        for e in range(3):
            buf[(R_RGB + e) * C + j] = buf[(R_TVA + e) * C + j]
    for li in range(lights.shape[0]):
        lr, lg, lb = lights[li, 4], lights[li, 5], lights[li, 6]
        for j in range(C):
            s, lx, ly, lz, dist = light_weight(
                lights, li, (buf[R_P * C + j], buf[(R_P + 1) * C + j], buf[(R_P + 2) * C + j]),
                (buf[R_NG * C + j], buf[(R_NG + 1) * C + j], buf[(R_NG + 2) * C + j]),
                (buf[R_NS * C + j], buf[(R_NS + 1) * C + j], buf[(R_NS + 2) * C + j]))
            lit = s > 0.0
            r, g, b = buf[R_RGB * C + j], buf[(R_RGB + 1) * C + j], buf[(R_RGB + 2) * C + j]
            buf[R_RGB * C + j] = r + buf[R_TVD * C + j] * lr * s if lit else r
            buf[(R_RGB + 1) * C + j] = g + buf[(R_TVD + 1) * C + j] * lg * s if lit else g
            buf[(R_RGB + 2) * C + j] = b + buf[(R_TVD + 2) * C + j] * lb * s if lit else b


@inner(cache=True, _nrt=False, error_model="numpy")
def _shade_row(y, view, ibuf, surf, lights, deferred, img, hp, buf, ib):
    """Row y of shade_rows, LANES pixels at a time side by side (buf, ib: the scratch rows,
    ROWS and IROWS of LANES): their corners gathered (:func:`_gather`), the surface they show
    (:func:`_surface_lanes`), the texels (:func:`_texel_lanes`), the colours the lights and the
    ambient term multiply, tvd = T V D and tva = T V A; then the lights' terms
    (:func:`_shade_lanes`), or with ``deferred`` those in the hit buffers hp."""
    C = LANES
    W = view.W
    pos, ngb, nsb, tvd, acc = hp.pos, hp.ng, hp.ns, hp.tvd, hp.acc
    fs = ibuf[y]
    hc = surf.colors.shape[0] > 0
    # zero in the rows _gather leaves alone for a surface without normals (then the geometric
    # normal shades), uv or vertex colours, and in the lanes past the row's end (computed, unread)
    buf[:] = 0.0
    for x0 in range(0, W, C):
        n = min(C, W - x0)
        hits = 0
        for j in range(n):
            hits += fs[x0 + j] >= 0
        if hits == 0:  # (no corners to gather: a scene may have no triangles at all)
            if deferred:
                acc[y * W + x0:y * W + x0 + n] = -1.0
            continue
        _gather(n, fs[x0:], surf, buf)
        _surface_lanes(x0, y, view, buf)
        _texel_lanes(n, fs[x0:], surf, buf, ib)
        if hc:  # (the texel times the vertex colour; not times the weights' sum without colours)
            for j in range(C):
                for e in range(3):
                    buf[(R_TEX + e) * C + j] *= buf[(R_C + e) * C + j]
        for j in range(C):
            for e in range(3):
                buf[(R_TVD + e) * C + j] = buf[(R_TEX + e) * C + j] * buf[(R_DIF + e) * C + j]
                buf[(R_TVA + e) * C + j] = buf[(R_TEX + e) * C + j] * buf[(R_AMB + e) * C + j]
        if deferred:  # the lights are added once their shadow rays are cast
            for j in range(n):
                i = y * W + x0 + j
                if fs[x0 + j] < 0:  # a miss
                    acc[i, 0], acc[i, 1], acc[i, 2] = -1.0, -1.0, -1.0
                    continue
                for e in range(3):
                    pos[i, e] = buf[(R_P + e) * C + j]
                    ngb[i, e] = buf[(R_NG + e) * C + j]
                    nsb[i, e] = buf[(R_NS + e) * C + j]
                    tvd[i, e] = buf[(R_TVD + e) * C + j]
                    acc[i, e] = buf[(R_TVA + e) * C + j]
            continue
        _shade_lanes(lights, buf)
        for j in range(n):
            if fs[x0 + j] >= 0:  # (a miss: the render kernel has written the background already)
                # clamped here: a huge light or colour (1e38) must saturate, and beyond int64
                # put_pixel's rounding is undefined
                put_pixel(img, y, x0 + j, min(buf[R_RGB * C + j], 1.0), min(buf[(R_RGB + 1) * C + j], 1.0),
                          min(buf[(R_RGB + 2) * C + j], 1.0))


@njit(cache=True, nogil=True, error_model="numpy")
def shade_rows(view, ibuf, surf, lights, deferred, img, hp, nxt):
    """Colour the hit pixels of img (H,W,4) (ibuf: scene ids, -1 a miss, whose background the render
    kernel wrote; view: :class:`gridrt.trace.records.View`) with the surface surf
    (:class:`gridrt.trace.records.SurfaceArrays`) and the lights (L, 8) (frame coordinates), or
    with ``deferred`` (shadows) write each hit's point, normals, T V D and T V A (acc; -1 in
    acc[i] for a miss) into the flat (W*H, 3) buffers of hp
    (:class:`gridrt.trace.records.HitPoints`) for :func:`light_segments`, :func:`add_light` and
    :func:`compose`: the rows taken one at a time from the counter nxt ((1,) int64) until none is
    left, so that calls on several threads share one image (:func:`shade`)."""
    # (a row's scratch: 8 KiB, next to a row's shading)
    buf, ib = np.empty(ROWS * LANES), np.empty(IROWS * LANES, np.int64)
    while True:
        y = atomic_add(nxt, 0, np.int64(1))
        if y >= view.H:
            break
        _shade_row(y, view, ibuf, surf, lights, deferred, img, hp, buf, ib)


def shade(view, ibuf, surf, lights, deferred, img, hp, threads=1):
    """The material pass (:func:`shade_rows`) on ``threads`` threads (gridrt.threads.on_threads),
    sharing the image's rows through one counter: the same pixels and hit buffers bit for bit on
    any number of threads."""
    nxt = np.zeros(1, np.int64)

    def work(k):
        shade_rows(view, ibuf, surf, lights, deferred, img, hp, nxt)

    on_threads(threads, work)


#: pixels of the order per work item of light_segments (its passes over the order)
LIT_CHUNK = 16384


@njit(cache=True, parallel=True, error_model="numpy")
def light_segments(lights, li, hp, off, far, order, rays, segs, boxes):
    """The shadow segments of light li from the hits of hp (:class:`gridrt.trace.records.HitPoints`;
    acc[i, 0] >= 0) it lights, in the pixel order ``order`` (a permutation of the image's pixels).
    Per pixel (rays: :class:`gridrt.trace.records.ShadowRays`): need[i] = 1 where the light
    lights the hit, and its weight there in weight[i].  The lit pixels' segments go, in the
    order's order, to segs (:class:`gridrt.trace.records.ShadowSegments`, :func:`_put_segment`).
    Returns how many.  In three parallel passes: the lit hits, in pixel order; then over
    chunks of LIT_CHUNK pixels of the order, each chunk's count of them, and each chunk's segments
    from its place after the chunks before it.  A grid whose box holds a point light
    (:func:`_holds_light`) is marked on every segment without testing each: they all start inside
    it."""
    pos, ngb, nsb, acc = hp.pos, hp.ng, hp.ns, hp.acc
    need, weight = rays.need, rays.weight
    N = order.shape[0]
    for i in prange(N):  # (in pixel order: the hit buffers are read front to back)
        need[i] = 0
        if acc[i, 0] < 0.0:
            continue
        s, lx, ly, lz, dist = light_weight(lights, li, (pos[i, 0], pos[i, 1], pos[i, 2]),
                                           (ngb[i, 0], ngb[i, 1], ngb[i, 2]),
                                           (np.float64(nsb[i, 0]), np.float64(nsb[i, 1]), np.float64(nsb[i, 2])))
        if s > 0.0:
            need[i] = 1
            weight[i] = s
    held = 0
    if lights[li, 0] != LIGHT_DIRECTIONAL:
        for gi in range(boxes.shape[0]):
            if _holds_light(boxes[gi], (lights[li, 1], lights[li, 2], lights[li, 3])):
                held |= 1 << gi
    nc = (N + LIT_CHUNK - 1) // LIT_CHUNK
    start = np.zeros(nc + 1, np.int64)
    for c in prange(nc):
        m = 0
        for k in range(c * LIT_CHUNK, min(N, (c + 1) * LIT_CHUNK)):
            m += need[order[k]]
        start[c + 1] = m
    for c in range(nc):
        start[c + 1] += start[c]
    for c in prange(nc):
        m = start[c]
        for k in range(c * LIT_CHUNK, min(N, (c + 1) * LIT_CHUNK)):
            i = order[k]
            if need[i] == 0:
                continue
            _put_segment(lights[li], hp, i, off, far, (boxes, held), segs, m, weight[i])
            m += 1
    return start[nc]


@inner(cache=True, _nrt=False, error_model="numpy")
def _put_segment(light, hp, i, off, far, near, segs, m, weight):
    """Segment m of segs (:class:`gridrt.trace.records.ShadowSegments`): pixel i's, towards the
    light ``light`` (a row of the lights), of that weight.  The light's end to the hit turned
    round: the ray from p + n_g * off to the light (a point light's vector to it, or far times a
    directional light's unit vector) starts at the light's end, o = origin + direction, d =
    -direction (t in (0, 1)).  A point
    light's segments then share one origin, and one blocked near its light stops there.  With
    several grids, boxes (G, 7) (:func:`near_boxes`, G <= 8) gives their boxes, and bit g of
    segs.grids[m] is set where the segment may meet grid g's box (:func:`_near_box`): the grids
    it misses need not trace it; with boxes (0, 7) every bit is set (near = (boxes, held)).  Bit
    g of ``held`` set: grid g's box holds the light (:func:`_holds_light`), its bit is set without
    the test."""
    boxes, held = near
    pos, ngb = hp.pos, hp.ng
    ox, oy, oz = pos[i, 0] + ngb[i, 0] * off, pos[i, 1] + ngb[i, 1] * off, pos[i, 2] + ngb[i, 2] * off
    if light[0] == LIGHT_DIRECTIONAL:
        dx, dy, dz = light[1] * far, light[2] * far, light[3] * far
    else:
        dx, dy, dz = light[1] - ox, light[2] - oy, light[3] - oz
    segs.rows[m] = i
    sx, sy, sz = ox + dx, oy + dy, oz + dz
    o, d = segs.o, segs.d
    o[m, 0], o[m, 1], o[m, 2] = sx, sy, sz
    d[m, 0], d[m, 1], d[m, 2] = -dx, -dy, -dz
    bits = 255
    if boxes.shape[0] > 0:
        bits = held
        for gi in range(boxes.shape[0]):
            if (held >> gi) & 1 == 0 and _near_box(boxes[gi], (sx, sy, sz), (-dx, -dy, -dz)):
                bits |= 1 << gi
    segs.grids[m] = bits
    segs.weight[m] = weight


#: the pixel shift of the draws of :func:`_draw`: the R2 sequence's (the plastic number's
#: inverse and its square), so neighbouring pixels draw far apart
R2_X, R2_Y = 0.7548776662466927, 0.5698402909980532


def radical_inverse(i, base):
    """The base-``base`` radical inverse of the integer i >= 0: its digits mirrored about the
    point (base 2: 0, 1/2, 1/4, 3/4, 1/8, ...)."""
    f, r = 1.0, 0.0
    while i > 0:
        f /= base
        r += f * (i % base)
        i //= base
    return r


def draw_shift(seed):
    """The shift of draw ``seed`` (RenderParams.light_seed) common to every pixel: the base-2
    radical inverse of seed (0, 1/2, 1/4, 3/4, ...), so seeds 0 .. 2^m - 1 give each pixel 2^m
    evenly spaced draws."""
    return radical_inverse(int(seed), 2)


@inner(cache=True, _nrt=False, error_model="numpy")
def _draw(lights, hp, i, r, W, draws, w):
    """Draw draws.k lights for hit pixel i of hp (W pixels a row) into row r of draws.lit and
    draws.factor: with probability p in proportion to w = n_s . l (over d^2 with falloff:
    :func:`light_weight`) times the light's r + g + b times the guide of the pixel's block (w:
    scratch of L); lit[r] and factor[r] get the distinct lights drawn, -1 after them, and n / (k
    p) for a light drawn n times; returns how many.  The k draws are stratified: u_j = (j + x) /
    k, with x = frac(R2_X px + R2_Y py + draws.shift) at pixel (px, py).  draws.k = 0 takes every
    light that lights the hit, factor 1 (the exact sum).  Where the total weight is infinite (a
    light at the hit itself, with falloff) the pixel keeps the first K lights of infinite
    weight, factor 1: lit by them, the pixel is white as in the exact sum."""
    pos, ngb, nsb = hp.pos, hp.ng, hp.ns
    k, lit, factor, guide = draws.k, draws.lit, draws.factor, draws.guide
    L, K = lights.shape[0], lit.shape[1]
    for j in range(K):
        lit[r, j] = -1
        factor[r, j] = 0.0
    if hp.acc[i, 0] < 0.0:
        return 0
    py = i // W
    px = i - py * W
    b = -1
    if guide.shape[0] > 0:
        b = (py // draws.block) * draws.bw + px // draws.block
    total, last = 0.0, -1
    for li in range(L):
        s, lx, ly, lz, dist = light_weight(lights, li, (pos[i, 0], pos[i, 1], pos[i, 2]),
                                           (ngb[i, 0], ngb[i, 1], ngb[i, 2]),
                                           (np.float64(nsb[i, 0]), np.float64(nsb[i, 1]), np.float64(nsb[i, 2])))
        wl = s * (lights[li, 4] + lights[li, 5] + lights[li, 6])
        if b >= 0:
            wl *= guide[b, li]
        w[li] = wl if wl > 0.0 else 0.0
        total += w[li]
        if wl > 0.0:
            last = li
    if last < 0:
        return 0
    m = 0
    if k == 0 or not math.isfinite(total):
        for li in range(last + 1):
            if (w[li] > 0.0 if k == 0 else w[li] == np.inf) and m < K:
                lit[r, m] = li
                factor[r, m] = 1.0
                m += 1
        return m
    x = R2_X * px + R2_Y * py + draws.shift
    x -= math.floor(x)
    j, cw = 0, 0.0
    for li in range(last + 1):
        if w[li] == 0.0:
            continue
        cw += w[li]
        j0 = j
        if li == last:  # (the rest, whatever the rounding of cw)
            j = k
        else:
            while j < k and (j + x) * total < cw * k:
                j += 1
        if j > j0:
            lit[r, m] = li
            factor[r, m] = (j - j0) * total / (k * w[li])
            m += 1
    return m


@njit(cache=True, parallel=True, error_model="numpy")
def drawn_segments(lights, hp, W, draws, off, far, order, segs, boxes):
    """The shadow segments of the hits of hp (:class:`gridrt.trace.records.HitPoints`, W pixels a
    row) of the pixels ``order`` lists, towards lights drawn per pixel (draws:
    :class:`gridrt.trace.records.Draws`, :func:`_draw`, row kk of its lit and factor for
    order[kk]): the sum over a pixel's drawn lights of their light, each weighted by its factor,
    is an unbiased estimate of the sum over every light.  The segments go to segs
    (:class:`gridrt.trace.records.ShadowSegments` of at least len(order) * K,
    :func:`_put_segment`, weight n_s . l times the factor) light by light, each light's in the
    order of ``order``.  Returns start (L + 1,) int64: light li's segments are start[li]:start[li
    + 1].  In two parallel passes over chunks of LIT_CHUNK pixels of the order: the draws,
    counted per light and chunk; then each chunk's segments from its place in each light's run."""
    L, N = lights.shape[0], order.shape[0]
    lit, factor = draws.lit, draws.factor
    nc = (N + LIT_CHUNK - 1) // LIT_CHUNK
    count = np.zeros((nc, L), np.int64)
    for c in prange(nc):
        w = np.empty(L)
        for kk in range(c * LIT_CHUNK, min(N, (c + 1) * LIT_CHUNK)):
            for j in range(_draw(lights, hp, order[kk], kk, W, draws, w)):
                count[c, lit[kk, j]] += 1
    start = np.zeros(L + 1, np.int64)
    at = np.empty((nc, L), np.int64)
    m = 0
    for li in range(L):
        start[li] = m
        for c in range(nc):
            at[c, li] = m
            m += count[c, li]
    start[L] = m
    held = np.zeros(L, np.int64)
    for li in range(L):
        if lights[li, 0] != LIGHT_DIRECTIONAL:
            for gi in range(boxes.shape[0]):
                if _holds_light(boxes[gi], (lights[li, 1], lights[li, 2], lights[li, 3])):
                    held[li] |= 1 << gi
    pos, ngb, nsb = hp.pos, hp.ng, hp.ns
    for c in prange(nc):
        for kk in range(c * LIT_CHUNK, min(N, (c + 1) * LIT_CHUNK)):
            i = order[kk]
            for j in range(lit.shape[1]):
                li = lit[kk, j]
                if li < 0:
                    break
                s, lx, ly, lz, dist = light_weight(lights, li, (pos[i, 0], pos[i, 1], pos[i, 2]),
                                                   (ngb[i, 0], ngb[i, 1], ngb[i, 2]),
                                                   (np.float64(nsb[i, 0]), np.float64(nsb[i, 1]),
                                                    np.float64(nsb[i, 2])))
                _put_segment(lights[li], hp, i, off, far, (boxes, held[li]), segs, at[c, li], s * factor[kk, j])
                at[c, li] += 1
    return start


#: a grid box (its lo and hi, see near_boxes) is grown by this fraction of its diagonal before a
#: shadow segment is tested against it
BOX_MARGIN = 1e-6


def near_boxes(grids):
    """(G, 7) float64 of the grids (GridArrays) for light_segments: each box lo..hi grown by
    BOX_MARGIN of its diagonal on every side (x0, y0, z0, x1, y1, z1), and the distance (a million
    diagonals from its centre along an axis) beyond which a segment's origin is taken to meet it."""
    out = np.empty((len(grids), 7))
    for k, g in enumerate(grids):
        lo, hi = np.asarray(g.lo, np.float64), np.asarray(g.hi, np.float64)
        diag = float(np.sqrt(((hi - lo) ** 2).sum()))
        out[k, 0:3] = lo - BOX_MARGIN * diag
        out[k, 3:6] = hi + BOX_MARGIN * diag
        out[k, 6] = 1e6 * diag
    return out


@inner(cache=True, _nrt=False, error_model="numpy")
def _near_box(box, o, d):
    """Whether the segment o + t d, 0 <= t <= 1 (3-tuples) may meet the grown box ``box`` (a row
    of near_boxes): False only where it certainly misses it.  A segment whose origin lies beyond
    the box's far distance from its centre, where rounding could exceed the margin, is kept; one
    whose own bounding box lies apart from the box is not, one whose own box lies inside it is,
    without a division; the others are clipped to it as the traversal clips a ray to its grid's box
    (gridrt.trace.traverse._clip_box)."""
    ox, oy, oz = o
    ex, ey, ez = ox + d[0], oy + d[1], oz + d[2]
    if max(abs(ox - 0.5 * (box[0] + box[3])), abs(oy - 0.5 * (box[1] + box[4])),
           abs(oz - 0.5 * (box[2] + box[5]))) > box[6]:
        return True
    if (min(ox, ex) > box[3] or max(ox, ex) < box[0] or min(oy, ey) > box[4] or max(oy, ey) < box[1]
            or min(oz, ez) > box[5] or max(oz, ez) < box[2]):
        return False
    if (min(ox, ex) >= box[0] and max(ox, ex) <= box[3] and min(oy, ey) >= box[1] and max(oy, ey) <= box[4]
            and min(oz, ez) >= box[2] and max(oz, ez) <= box[5]):
        return True
    t0, t1 = _clip_box((box[0], box[1], box[2]), (box[3], box[4], box[5]), o, d, 0.0, 1.0)
    return t0 <= t1


@inner(cache=True, _nrt=False, error_model="numpy")
def _holds_light(box, light):
    """Whether the grown box ``box`` (a row of near_boxes) holds a point light at ``light`` (a
    3-tuple) with room to spare: then every segment :func:`_put_segment` makes from it starts
    inside the box (at the light, rounded by a few units in the last place), and :func:`_near_box`
    keeps each (its clip to the box starts at t = 0), so testing them one by one can be skipped.
    The room: 1e-12 of the largest coordinate, far beyond that rounding."""
    s = 1e-12 * max(max(abs(light[0]), abs(light[1])), max(abs(light[2]), max(abs(box[0]), abs(box[3]))))
    s = max(s, 1e-12 * max(max(abs(box[1]), abs(box[4])), max(abs(box[2]), abs(box[5]))))
    inside = True
    for a in range(3):
        inside &= (light[a] - s >= box[a]) & (light[a] + s <= box[3 + a])
    return inside


@njit(cache=True, error_model="numpy")
def live_segments(blocked, marks, bit, live):
    """How many segments j are not blocked[j] and have ``bit`` set in marks[j] (uint8; bit -1
    takes every mark); unless that is all of them, their indices go to live[:count] (int64) in
    order.  One pass, two where some are left out."""
    n = 0
    for j in range(blocked.shape[0]):
        n += (not blocked[j]) & ((marks[j] & bit) != 0)
    if n < blocked.shape[0]:
        k = 0
        for j in range(blocked.shape[0]):
            if (not blocked[j]) & ((marks[j] & bit) != 0):
                live[k] = j
                k += 1
    return n


@njit(cache=True, error_model="numpy")
def mark_blocked(live, n, every, tri, blocked):
    """blocked[r] = True for the segments r of a cast that hit a triangle (tri[r] >= 0): r = 0 ..
    n - 1 where the cast took every segment (``every``), else r = live[j], j < n."""
    for j in range(n):
        r = j if every else live[j]
        if tri[r] >= 0:
            blocked[r] = True


@njit(cache=True, parallel=True, error_model="numpy")
def add_light(rows, blocked, weight, tvd, r, g, b, acc):
    """acc[rows[j]] += tvd * (r, g, b) * weight[j] for every shadow ray j that hit nothing (not blocked[j])."""
    for j in prange(rows.shape[0]):
        if not blocked[j]:
            i = rows[j]
            s = weight[j]
            acc[i, 0] += tvd[i, 0] * r * s
            acc[i, 1] += tvd[i, 1] * g * s
            acc[i, 2] += tvd[i, 2] * b * s


@njit(cache=True, parallel=True, error_model="numpy")
def compose(W, H, acc, img):
    """img from the accumulated colours of the hits (acc[i, 0] >= 0; the render kernel has written
    the background of the misses)."""
    for y in prange(H):
        for x in range(W):
            i = y * W + x
            if acc[i, 0] >= 0.0:
                put_pixel(img, np.int64(y), x, min(acc[i, 0], 1.0), min(acc[i, 1], 1.0), min(acc[i, 2], 1.0))  # (as _shade_row)


def default_surface(n_triangles):
    """One material of gridrt's default colours (DEFAULT_DIFFUSE, the lambert mode's ALBEDO, and
    AMBIENT_FRACTION of it as ambient) for every triangle."""
    return Surface.plain(n_triangles, DEFAULT_DIFFUSE, tuple(AMBIENT_FRACTION * c for c in DEFAULT_DIFFUSE))


def surface_arrays(tris, surface, normals):
    """The :class:`gridrt.trace.records.SurfaceArrays` of the scene's triangles ``tris`` (F, 3, 3)
    float32, its Surface (None: :func:`default_surface`) and its per-corner normals ((F, 3, 3)
    float32, or None: the geometric ones)."""
    ps = (surface if surface is not None else default_surface(len(tris))).packed
    nrm = normals if normals is not None else np.zeros((0, 3, 3), np.float32)
    return SurfaceArrays(*(read_only(a) for a in (tris, nrm, ps.material, ps.diffuse, ps.ambient, ps.texture,
                                                   ps.tex_data, ps.tex_info, ps.uv, ps.colors)))
