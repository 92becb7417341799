"""Per-pixel shading shared by the single-ray (DDA) and the packet (CGT) render kernels, so both
produce the same colours from the same hits.  The formulas are documented in
:mod:`gridrt.trace.render`; colours are linear in [0, 1].
"""

import math

from ..compiles import inner

import numpy as np
BACKGROUND = (0.12, 0.13, 0.16)
ALBEDO = (0.85, 0.78, 0.66)
AMBIENT = 0.15
COST_SCALE = 64.0


@inner(cache=True)
def _u8(c):
    v = int(c * 255.0 + 0.5)
    return np.uint8(0 if v < 0 else (255 if v > 255 else v))


@inner(cache=True, _nrt=False)
def put_pixel(img, y, x, r, g, b):
    """img[y, x] = (r, g, b) as uint8(round(255 c)), alpha 255; img (H, W, 4) uint8."""
    img[y, x, 0] = _u8(r)
    img[y, x, 1] = _u8(g)
    img[y, x, 2] = _u8(b)
    img[y, x, 3] = np.uint8(255)


@inner(cache=True, _nrt=False)
def unit_normal(tris, f):
    """normalize((v1 - v0) x (v2 - v0)) of triangle f of tris (F, 3, 3) float32; zero if degenerate."""
    e1x = np.float64(tris[f, 1, 0]) - tris[f, 0, 0]
    e1y = np.float64(tris[f, 1, 1]) - tris[f, 0, 1]
    e1z = np.float64(tris[f, 1, 2]) - tris[f, 0, 2]
    e2x = np.float64(tris[f, 2, 0]) - tris[f, 0, 0]
    e2y = np.float64(tris[f, 2, 1]) - tris[f, 0, 1]
    e2z = np.float64(tris[f, 2, 2]) - tris[f, 0, 2]
    nx = e1y * e2z - e1z * e2y
    ny = e1z * e2x - e1x * e2z
    nz = e1x * e2y - e1y * e2x
    n = math.sqrt(nx * nx + ny * ny + nz * nz)
    if n == 0.0:
        return 0.0, 0.0, 0.0
    return nx / n, ny / n, nz / n


@inner(cache=True, _nrt=False)
def facing_normal(tris, f, dx, dy, dz):
    """Unit geometric normal of triangle f of tris turned towards the viewer, and its dot product
    with the ray direction (<= 0): (nx, ny, nz, dn)."""
    nx, ny, nz = unit_normal(tris, f)
    dn = nx * dx + ny * dy + nz * dz
    if dn > 0.0:
        nx, ny, nz, dn = -nx, -ny, -nz, -dn
    return nx, ny, nz, dn


@inner(cache=True, _nrt=False)
def scene_id(grids, which, f):
    """The scene's id of triangle f of grid ``which`` of the tuple grids (through the grid's ids
    map when it has one); -1 (a miss) stays -1."""
    if f < 0:
        return -1
    ids = grids[which].ids
    return ids[f] if ids.shape[0] > 0 else f


@inner(cache=True, _nrt=False)
def shadow_ray(e, t, d, n, light, off):
    """Shadow ray of the hit at eye + t d with facing normal n (e, d, n: 3-tuples):
    (need, ox, oy, oz, lx, ly, lz, ld, s).

    s = n . l (l the unit vector to the light, ld the distance); need is True when s > 0, and then
    the segment from p + n * off along l for ld decides visibility, traced from its far end
    (near the light) back: the ray (ox, oy, oz) = p + n * off + ld l along (lx, ly, lz) = -l with
    tmax = ld.  The rays of a packet then start all but together, and a ray blocked near the
    light stops there.  Otherwise s = 0.
    """
    ex, ey, ez = e
    dx, dy, dz = d
    nx, ny, nz = n
    px = ex + t * dx
    py = ey + t * dy
    pz = ez + t * dz
    lx = light[0] - px
    ly = light[1] - py
    lz = light[2] - pz
    ld = math.sqrt(lx * lx + ly * ly + lz * lz)
    s = 0.0
    if ld > 0.0:
        lx /= ld
        ly /= ld
        lz /= ld
        s = nx * lx + ny * ly + nz * lz
        if s > 0.0:
            ox, oy, oz = px + nx * off, py + ny * off, pz + nz * off
            return True, ox + ld * lx, oy + ld * ly, oz + ld * lz, -lx, -ly, -lz, ld, s
        s = 0.0
    return False, px, py, pz, lx, ly, lz, ld, s


@inner(cache=True)
def cost_rgb(nt):
    """Heat map of h = min(1, nt / COST_SCALE): blue -> green -> red."""
    h = min(1.0, nt / COST_SCALE)
    if h < 0.5:
        return 0.0, 2.0 * h, 1.0 - 2.0 * h
    return 2.0 * h - 1.0, 2.0 - 2.0 * h, 0.0


@inner(cache=True)
def normal_rgb(nx, ny, nz):
    return (nx + 1.0) * 0.5, (ny + 1.0) * 0.5, (nz + 1.0) * 0.5


@inner(cache=True)
def lambert_rgb(s):
    k = AMBIENT + (1.0 - AMBIENT) * s
    return ALBEDO[0] * k, ALBEDO[1] * k, ALBEDO[2] * k
