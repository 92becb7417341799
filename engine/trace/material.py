"""The ``material`` shading mode: a pass over the primary hits that colours them with the scene's
materials, textures, smooth normals and lights (gridrt.scene.surface has the formula).

It runs after the render kernel has filled the hit distance and triangle buffers (DDA or CGT, any
grid kind, one grid or the static/moving split: it reads only the scene ids of the hits), so the
traversal kernels stay as they are.  Per hit pixel:

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
  scene first.

A scene without lights is lit by one default light (gridrt.trace.render.default_light, colour 1,
no falloff); a render without a scene surface uses one material of gridrt's default colours.
"""

import math

import numpy as np
from numba import njit, prange

from ..camera import pixel_dir
from ..compiles import inner
from ..scene.surface import (AMBIENT_FRACTION, DEFAULT_DIFFUSE, FALLOFF_INVERSE_SQUARE, LIGHT_DIRECTIONAL, LIGHT_POINT,
                             Surface)
from .records import SurfaceArrays
from .shade import put_pixel, unit_normal
from .traverse import _clip_box


@inner(cache=True, _nrt=False, error_model="numpy")
def barycentrics(tris, f, ex, ey, ez, dx, dy, dz):
    """(w0, w1, w2) of the ray eye + t d on triangle f of tris (F,3,3) float32, in float64, clamped
    onto the triangle (each >= 0, sum 1); the centroid for a degenerate triangle."""
    v0x, v0y, v0z = np.float64(tris[f, 0, 0]), np.float64(tris[f, 0, 1]), np.float64(tris[f, 0, 2])
    e1x, e1y, e1z = tris[f, 1, 0] - v0x, tris[f, 1, 1] - v0y, tris[f, 1, 2] - v0z
    e2x, e2y, e2z = tris[f, 2, 0] - v0x, tris[f, 2, 1] - v0y, tris[f, 2, 2] - v0z
    px = dy * e2z - dz * e2y
    py = dz * e2x - dx * e2z
    pz = dx * e2y - dy * e2x
    det = e1x * px + e1y * py + e1z * pz
    if det == 0.0 or not math.isfinite(det):
        return 1.0 / 3.0, 1.0 / 3.0, 1.0 / 3.0
    inv = 1.0 / det  # (one division: a division's latency is most of a hit's shading)
    sx, sy, sz = ex - v0x, ey - v0y, ez - v0z
    u = (sx * px + sy * py + sz * pz) * inv
    qx = sy * e1z - sz * e1y
    qy = sz * e1x - sx * e1z
    qz = sx * e1y - sy * e1x
    v = (dx * qx + dy * qy + dz * qz) * inv
    if not (math.isfinite(u) and math.isfinite(v)):
        return 1.0 / 3.0, 1.0 / 3.0, 1.0 / 3.0
    u = max(u, 0.0)
    v = max(v, 0.0)
    s = u + v
    if s > 1.0:
        r = 1.0 / s
        u *= r
        v *= r
    return 1.0 - u - v, u, v


@inner(cache=True, _nrt=False, error_model="numpy")
def _wrap(i, n, mode):
    """Texel index i in [-1, 2n] (the reduced coordinate's, see _reduce) wrapped into [0, n) by mode
    (0 repeat, 1 clamp, 2 mirror), with compares: an integer division costs more than the rest of
    the lookup."""
    if mode == 1:
        return 0 if i < 0 else (n - 1 if i >= n else i)
    if mode == 2:
        m = i + 2 * n if i < 0 else (i - 2 * n if i >= 2 * n else i)
        return m if m < n else 2 * n - 1 - m
    return i + n if i < 0 else (i - n if i >= n else i)


@inner(cache=True, _nrt=False, error_model="numpy")
def _reduce(c, mode):
    """A texture coordinate brought into [0, 1] (clamp), [0, 1) (repeat) or [0, 2) (mirror) before
    it is scaled to texels, so a huge coordinate never overflows an integer."""
    if mode == 1:
        return min(max(c, 0.0), 1.0)
    if mode == 2:
        return c - 2.0 * math.floor(0.5 * c)
    return c - math.floor(c)


@inner(cache=True, _nrt=False, error_model="numpy")
def sample_bilinear(tex_data, tex_info, k, u, v):
    """Texture k at (u, v) (image convention: (0, 0) top-left), bilinearly filtered: (r, g, b) in [0, 1]."""
    off, w, h, wu, wv = tex_info[k, 0], tex_info[k, 1], tex_info[k, 2], tex_info[k, 3], tex_info[k, 4]
    x = _reduce(u, wu) * w - 0.5
    y = _reduce(v, wv) * h - 0.5
    x0 = math.floor(x)
    y0 = math.floor(y)
    fx = x - x0
    fy = y - y0
    ix0 = _wrap(np.int64(x0), w, wu)
    ix1 = _wrap(np.int64(x0) + 1, w, wu)
    iy0 = _wrap(np.int64(y0), h, wv)
    iy1 = _wrap(np.int64(y0) + 1, h, wv)
    a = off + (iy0 * w + ix0) * 3
    b = off + (iy0 * w + ix1) * 3
    c = off + (iy1 * w + ix0) * 3
    d = off + (iy1 * w + ix1) * 3
    w00 = (1.0 - fx) * (1.0 - fy)
    w01 = fx * (1.0 - fy)
    w10 = (1.0 - fx) * fy
    w11 = fx * fy
    r = w00 * tex_data[a] + w01 * tex_data[b] + w10 * tex_data[c] + w11 * tex_data[d]
    g = w00 * tex_data[a + 1] + w01 * tex_data[b + 1] + w10 * tex_data[c + 1] + w11 * tex_data[d + 1]
    bl = w00 * tex_data[a + 2] + w01 * tex_data[b + 2] + w10 * tex_data[c + 2] + w11 * tex_data[d + 2]
    k255 = 1.0 / 255.0
    return r * k255, g * k255, bl * k255


@inner(cache=True, _nrt=False, error_model="numpy")
def light_weight(lights, li, p, ng, ns):
    """(weight, lx, ly, lz, dist) of light li at the hit p with facing normals n_g, n_s (3-tuples):
    the unit vector l to the light, its distance (inf for a directional light) and weight n_s . l
    (over d^2 with inverse-square falloff), 0 when the light is behind the surface."""
    px, py, pz = p
    ngx, ngy, ngz = ng
    nsx, nsy, nsz = ns
    r = 1.0
    if lights[li, 0] == LIGHT_DIRECTIONAL:
        lx, ly, lz = lights[li, 1], lights[li, 2], lights[li, 3]
        dist = np.inf
    else:
        lx = lights[li, 1] - px
        ly = lights[li, 2] - py
        lz = lights[li, 3] - pz
        dist = math.sqrt(lx * lx + ly * ly + lz * lz)
        if not (dist > 0.0) or not math.isfinite(dist):
            return 0.0, 0.0, 0.0, 0.0, 0.0
        r = 1.0 / dist
        lx *= r
        ly *= r
        lz *= r
    if ngx * lx + ngy * ly + ngz * lz <= 0.0:
        return 0.0, lx, ly, lz, dist
    s = nsx * lx + nsy * ly + nsz * lz
    if s <= 0.0:
        return 0.0, lx, ly, lz, dist
    if lights[li, 7] == FALLOFF_INVERSE_SQUARE and lights[li, 0] == LIGHT_POINT:
        s *= r * r
    return s, lx, ly, lz, dist


@inner(cache=True, _nrt=False, error_model="numpy")
def _shade_row(y, view, ibuf, surf, lights, deferred, img, hp):
    """Row y of shade_kernel.  Per hit pixel, what the camera ray eye + t d sees on its scene
    triangle f of the surface surf (:class:`gridrt.trace.records.SurfaceArrays`): the hit point p
    (float64), the facing geometric and shading normals n_g and n_s, and the colours the lights
    and the ambient term multiply, tvd = T V D and tva = T V A; then the lights' terms, or with
    ``deferred`` those in the hit buffers hp.  (In one function with the loop: a call per pixel
    returning them cost a fifth of the pass.)"""
    basis, W, H = view.basis, view.W, view.H
    pos, ngb, nsb, tvd, acc = hp.pos, hp.ng, hp.ns, hp.tvd, hp.acc
    stris, normals, material, diffuse, ambient = surf.tris, surf.normals, surf.material, surf.diffuse, surf.ambient
    texture, tex_data, tex_info, uv, colors = surf.texture, surf.tex_data, surf.tex_info, surf.uv, surf.colors
    ex, ey, ez = basis[0, 0], basis[0, 1], basis[0, 2]
    for x in range(W):
        f = ibuf[y, x]
        i = y * W + x
        if f < 0:  # a miss: the render kernel has written the background already
            if deferred:
                acc[i, 0], acc[i, 1], acc[i, 2] = -1.0, -1.0, -1.0
            continue
        dx, dy, dz = pixel_dir(basis, W, H, x, y)
        w0, w1, w2 = barycentrics(stris, f, ex, ey, ez, dx, dy, dz)
        px = w0 * stris[f, 0, 0] + w1 * stris[f, 1, 0] + w2 * stris[f, 2, 0]
        py = w0 * stris[f, 0, 1] + w1 * stris[f, 1, 1] + w2 * stris[f, 2, 1]
        pz = w0 * stris[f, 0, 2] + w1 * stris[f, 1, 2] + w2 * stris[f, 2, 2]
        # geometric normal (v1 - v0) x (v2 - v0), towards the viewer (against the ray when degenerate)
        gx, gy, gz = unit_normal(stris, f)
        if gx == 0.0 and gy == 0.0 and gz == 0.0:
            gx, gy, gz = -dx, -dy, -dz
        if gx * dx + gy * dy + gz * dz > 0.0:
            gx, gy, gz = -gx, -gy, -gz
        sx, sy, sz = gx, gy, gz
        if normals.shape[0] > 0:
            nx = w0 * normals[f, 0, 0] + w1 * normals[f, 1, 0] + w2 * normals[f, 2, 0]
            ny = w0 * normals[f, 0, 1] + w1 * normals[f, 1, 1] + w2 * normals[f, 2, 1]
            nz = w0 * normals[f, 0, 2] + w1 * normals[f, 1, 2] + w2 * normals[f, 2, 2]
            nn = math.sqrt(nx * nx + ny * ny + nz * nz)
            if nn > 1e-12 and math.isfinite(nn):
                r = 1.0 / nn
                sx, sy, sz = nx * r, ny * r, nz * r
                if sx * gx + sy * gy + sz * gz < 0.0:
                    sx, sy, sz = -sx, -sy, -sz
        m = material[f]
        tr, tg, tb = 1.0, 1.0, 1.0
        k = texture[m]
        if k >= 0:
            u = w0 * uv[f, 0, 0] + w1 * uv[f, 1, 0] + w2 * uv[f, 2, 0]
            v = w0 * uv[f, 0, 1] + w1 * uv[f, 1, 1] + w2 * uv[f, 2, 1]
            tr, tg, tb = sample_bilinear(tex_data, tex_info, k, u, v)
        if colors.shape[0] > 0:
            tr *= w0 * colors[f, 0, 0] + w1 * colors[f, 1, 0] + w2 * colors[f, 2, 0]
            tg *= w0 * colors[f, 0, 1] + w1 * colors[f, 1, 1] + w2 * colors[f, 2, 1]
            tb *= w0 * colors[f, 0, 2] + w1 * colors[f, 1, 2] + w2 * colors[f, 2, 2]
        dr, dg, db = tr * diffuse[m, 0], tg * diffuse[m, 1], tb * diffuse[m, 2]
        ar, ag, ab = tr * ambient[m, 0], tg * ambient[m, 1], tb * ambient[m, 2]
        if deferred:  # the lights are added once their shadow rays are cast
            pos[i, 0], pos[i, 1], pos[i, 2] = px, py, pz
            ngb[i, 0], ngb[i, 1], ngb[i, 2] = gx, gy, gz
            nsb[i, 0], nsb[i, 1], nsb[i, 2] = sx, sy, sz
            tvd[i, 0], tvd[i, 1], tvd[i, 2] = dr, dg, db
            acc[i, 0], acc[i, 1], acc[i, 2] = ar, ag, ab
            continue
        r, g, b = ar, ag, ab
        for li in range(lights.shape[0]):
            s, lx, ly, lz, dist = light_weight(lights, li, (px, py, pz), (gx, gy, gz), (sx, sy, sz))
            if s > 0.0:
                r += dr * lights[li, 4] * s
                g += dg * lights[li, 5] * s
                b += db * lights[li, 6] * s
        # clamped here: a huge light or colour (1e38) must saturate, and beyond int64 put_pixel's rounding is undefined
        put_pixel(img, y, x, min(r, 1.0), min(g, 1.0), min(b, 1.0))


@njit(cache=True, parallel=True, error_model="numpy")
def shade_kernel(view, ibuf, surf, lights, deferred, img, hp):
    """Colour the hit pixels of img (H,W,4) (ibuf: scene ids, -1 a miss, whose background the render
    kernel wrote; view: :class:`gridrt.trace.records.View`) with the surface surf
    (:class:`gridrt.trace.records.SurfaceArrays`) and the lights (L, 8) (frame coordinates), or
    with ``deferred`` (shadows) write each hit's point, normals, T V D and T V A (acc; -1 in
    acc[i] for a miss) into the flat (W*H, 3) buffers of hp
    (:class:`gridrt.trace.records.HitPoints`) for :func:`light_segments`, :func:`add_light` and
    :func:`compose`."""
    for y in prange(view.H):
        _shade_row(np.int64(y), view, ibuf, surf, lights, deferred, img, hp)


@njit(cache=True, error_model="numpy")
def shade_serial(view, ibuf, surf, lights, deferred, img, hp):
    """shade_kernel on one thread (gridrt.trace.twin)."""
    for y in range(view.H):
        _shade_row(y, view, ibuf, surf, lights, deferred, img, hp)


#: pixels of the order per work item of light_segments (its passes over the order)
LIT_CHUNK = 16384


@njit(cache=True, parallel=True, error_model="numpy")
def light_segments(lights, li, hp, off, far, order, rays, segs, boxes):
    """The shadow segments of light li from the hits of hp (:class:`gridrt.trace.records.HitPoints`;
    acc[i, 0] >= 0) it lights, in the pixel order ``order`` (a permutation of the image's pixels).
    Per pixel (rays: :class:`gridrt.trace.records.ShadowRays`): need[i] = 1 where the light
    lights the hit, and its weight there in weight[i].  The lit pixels' segments go, in the
    order's order, to segs (:class:`gridrt.trace.records.ShadowSegments`, :func:`_put_segment`).
    Returns how many.  In three parallel passes: the lit hits, in pixel order; then over chunks of
    LIT_CHUNK pixels of the order, each chunk's count of them, and each chunk's segments from its
    place after the chunks before it."""
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
            _put_segment(lights, li, hp, i, off, far, boxes, segs, m, weight[i])
            m += 1
    return start[nc]


@inner(cache=True, _nrt=False, error_model="numpy")
def _put_segment(lights, li, hp, i, off, far, boxes, segs, m, weight):
    """Segment m of segs (:class:`gridrt.trace.records.ShadowSegments`): pixel i's, towards light
    li, of that weight.  The light's end to the hit turned round: the ray from p + n_g * off to
    the light (a point light's vector to it, or far times a directional light's unit vector)
    starts at the light's end, o = origin + direction, d = -direction (t in (0, 1)).  A point
    light's segments then share one origin, and one blocked near its light stops there.  With
    several grids, boxes (G, 7) (:func:`near_boxes`, G <= 8) gives their boxes, and bit g of
    segs.grids[m] is set where the segment may meet grid g's box (:func:`_near_box`): the grids
    it misses need not trace it; with boxes (0, 7) every bit is set."""
    pos, ngb = hp.pos, hp.ng
    ox, oy, oz = pos[i, 0] + ngb[i, 0] * off, pos[i, 1] + ngb[i, 1] * off, pos[i, 2] + ngb[i, 2] * off
    if lights[li, 0] == LIGHT_DIRECTIONAL:
        dx, dy, dz = lights[li, 1] * far, lights[li, 2] * far, lights[li, 3] * far
    else:
        dx, dy, dz = lights[li, 1] - ox, lights[li, 2] - oy, lights[li, 3] - oz
    segs.rows[m] = i
    sx, sy, sz = ox + dx, oy + dy, oz + dz
    o, d = segs.o, segs.d
    o[m, 0], o[m, 1], o[m, 2] = sx, sy, sz
    d[m, 0], d[m, 1], d[m, 2] = -dx, -dy, -dz
    bits = 255
    if boxes.shape[0] > 0:
        bits = 0
        for gi in range(boxes.shape[0]):
            if _near_box(boxes[gi], (sx, sy, sz), (-dx, -dy, -dz)):
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
                _put_segment(lights, li, hp, i, off, far, boxes, segs, at[c, li], s * factor[kk, j])
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
    return SurfaceArrays(*(_read_only(a) for a in (tris, nrm, ps.material, ps.diffuse, ps.ambient, ps.texture,
                                                   ps.tex_data, ps.tex_info, ps.uv, ps.colors)))


def _read_only(a):
    """A read-only view of a (no copy): every field of a SurfaceArrays is read-only whether its
    array came from a file's buffer or was made here, so the material kernels compile once (numba
    types a read-only array apart from a writable one)."""
    v = a.view()
    v.flags.writeable = False
    return v
