"""BART animated scenes: the AFF format of Lext, Assarsson and Moller (2000).

"BART: A Benchmark for Animated Ray Tracing", IEEE Computer Graphics and Applications 21(2),
2001 (Chalmers technical report 00-14, 2000).  AFF extends Eric Haines' NFF with:

* ``m`` indexed triangle meshes (``vertices``, optional ``normals`` and ``texturecoords``,
  ``triangles``), ``p``/``pp`` polygons (fan-triangulated), ``tt``/``ttp`` textured triangles;
* ``i detail file.aff`` includes (skipped when ``detail`` exceeds the ``d`` detail level, 0);
* ``xs sx sy sz  rx ry rz degrees  tx ty tz { ... }`` static transforms ``T * R * S`` and
  ``x name { ... }`` transforms animated by the ``k name { ... }`` block of the same name;
* ``k`` blocks of ``transl``, ``rot`` (axis + degrees) and ``scale`` keys interpolated by
  Kochanek-Bartels splines (Kochanek and Bartels, SIGGRAPH 1984), positions by cubic Hermite
  segments and rotations by squad of quaternions (after D. Eberly's magic-software code that BART
  ships); the first and last keys only shape the end tangents, so the motion is clamped to the
  keys in between; ``visibility`` keys switch an object on and off;
* ``tpa`` animated triangles (vertex keyframes, interpolated linearly and clamped at the ends);
* ``a start end frames`` (the animation's time span) and ``k camera`` (the animated viewpoint:
  eye = translation, view direction = -z and up = +y of the rotation).

Spheres (``s``) and cones (``c``) are not triangles; they are counted in
:attr:`BartAnimation.skipped` and not rendered.

The scene's looks (:attr:`BartAnimation.surface`, a :class:`gridrt.scene.surface.Surface`, and
:meth:`BartAnimation.lights_at`):

* **Materials.**  ``f r g b Kd Ks Shine T ior`` (NFF) gives the diffuse colour ``Kd * (r, g, b)``
  and, as NFF has no ambient term, the ambient reflectance :data:`AMBIENT_DEFAULT` times that;
  ``fm ar ag ab  dr dg db  sr sg sb  Shine T ior`` gives the ambient reflectance (ar, ag, ab) and the
  diffuse colour (dr, dg, db).  A material's ambient colour is its ambient reflectance times the
  scene's one ambient light, ``am r g b`` (1, 1, 1 without one; the last ``am`` of the scene counts,
  wherever it stands).  Specular colour, Shine, T and ior are read and not used.  The material is
  one global state, as in BART's reference parser: each ``f``/``fm`` holds for every polygon, mesh
  and triangle read after it (in include order) until the next one, whatever ``{ }`` blocks or
  included files it stands in (the scenes rely on this: ``i 0 param_wood.aff`` sets the material
  of what follows).  Triangles read before any material get :data:`DEFAULT_DIFFUSE` (gridrt's
  default grey) and an ambient reflectance of :data:`AMBIENT_DEFAULT` times it.
* **Textures.**  ``m`` meshes with ``texturecoords N file``, and ``tt``/``ttp`` triangles, name an
  image (PPM in the BART scenes), read once per file with :func:`gridrt.scene.surface.load_texture`
  and looked for like includes (the including file's folder, then the root's) and then in a
  ``TextureFiles`` folder inside or beside either (the BART distribution's ``aff/`` +
  ``TextureFiles/`` layout).  A missing, unreadable or refused image (see "Files" below) warns
  (TextureWarning) and its triangles are drawn untextured.  Texturing repeats (OpenGL REPEAT, as
  the BART report says) and modulates the material's colours.  BART's (u, v) are stored as they
  are: v = 0 is the image file's first row, as the surface's image convention has it.  The scenes
  show it: the museum's paintings and the kitchen's garden (upright images) have v = 0 along their
  top edge, and the robots' signs, whose images are stored upside down, have v = 1 there; only the
  kitchen car's number plate would read upside down.
* **Normals.**  ``normals N`` in meshes, ``pp`` and ``ttp`` vertex normals and the per-key normals of
  ``tpa`` triangles become per-corner shading normals: ``surface.normals`` holds them at t = 0 in
  world orientation, :meth:`BartAnimation.normals_at` at any t (rotated by the inverse transpose of
  their transform's matrix; ``tpa`` normals interpolated between keys like the positions).
  Triangles without normals in the file get zero normals ("use the geometric normal").
* **Lights.**  ``l x y z [r g b]`` is a point light of the given colour (1, 1, 1 by default) and no
  falloff, at (x, y, z) in world coordinates (as BART's reference parser, lights ignore enclosing
  transforms).  ``la name x y z [r g b]`` is the same, animated by the ``transl`` keys of the
  ``k name`` block when there is one: its position at time t is that spline's value (as the
  camera's eye is), else (x, y, z).

Files.  A scene is untrusted input (:mod:`gridrt.scene.files`): every include and texture must
resolve, symlinks followed, inside the folder of the root .aff file, with one exception for
textures only: the folder ``TextureFiles`` beside it (``<root's folder>/../TextureFiles``, exactly
that folder, resolved), where the BART distribution keeps the images of the scenes in its ``aff/``
folder (``kitchen/aff/kitchen.aff`` and ``kitchen/TextureFiles/*.ppm``).  An include outside is a
SceneFileError, a texture outside is drawn without (TextureWarning); ``allow_outside=True`` (the
command line's ``--allow-outside-refs``) trusts them.  Error messages quote the text of the root
file only: an included file may be no scene file at all, so its errors name the file and the line
and quote none of its text.
"""

import math
import os
import warnings
from collections import namedtuple
from pathlib import Path

import numpy as np
from numba import njit

from ..arrays import TRI_DTYPE, storage_centre
from ..camera import Camera
from ..compiles import inner
from ..errors import InputError, SceneFileError
from .animation import Animation, as_static_mask, check_time, gather_unchecked, pose_moving_vertices
from .files import ALLOW_HINT, SceneFolder, read_scene_file
from .kernels import Pose, as_rig, compose_world, deform_vertices, lerp_rows, trs_matrix
from .surface import FALLOFF_NONE, LIGHT_POINT, SurfaceBuilder, TextureWarning, as_lights, load_texture

__all__ = ["AMBIENT_DEFAULT", "BartAnimation", "DEFAULT_DIFFUSE", "kb_position_coefficients",
           "kb_rotation_segments"]

_MAX_INCLUDE_DEPTH = 32
_MOTIONS = ("transl", "rot", "scale", "visibility")
_ZERO3 = np.zeros(3)
_RGB = ("red", "green", "blue")

#: diffuse colour of triangles read before any ``f``/``fm`` material: gridrt's default grey
#: (gridrt.trace.shade.ALBEDO)
from .surface import AMBIENT_FRACTION, DEFAULT_DIFFUSE  # noqa: E402
#: ambient reflectance of NFF ``f`` materials (and of the default material) as a fraction of their
#: diffuse colour: NFF has no ambient term (gridrt.trace.shade.AMBIENT is the same fraction)
AMBIENT_DEFAULT = AMBIENT_FRACTION
#: the largest colour, texture coordinate or normal component that float32 storage holds
_F32_MAX = float(np.finfo(np.float32).max)


# ------------------------------------------------------------------------------ splines


def kb_position_coefficients(times, points, tcb):
    """Kochanek-Bartels cubic segments through keys 1 .. n-2 of ``n >= 4`` keys.

    times (n,) f64 non-decreasing, points (n,3) f64, tcb (n,3) f64 tension/continuity/bias.
    Returns ``(tmin (n-3,), tmax (n-3,), coef (n-3, 4, 3))``: segment i runs from key i+1 to key
    i+2 as ``P(u) = c0 + u (c1 + u (c2 + u c3))`` with ``u = (t - tmin) / (tmax - tmin)``.
    """
    t = np.asarray(times, np.float64)
    P = np.asarray(points, np.float64)
    T, C, B = (np.asarray(tcb, np.float64)[:, k] for k in range(3))
    i0 = np.arange(len(t) - 3)
    i1, i2, i3 = i0 + 1, i0 + 2, i0 + 3
    dp = P[i2] - P[i1]
    adj0 = (2.0 * (t[i2] - t[i1]) / (t[i2] - t[i0]))[:, None]
    out0 = 0.5 * adj0 * ((1 - T[i1]) * (1 + C[i1]) * (1 + B[i1]))[:, None]
    out1 = 0.5 * adj0 * ((1 - T[i1]) * (1 - C[i1]) * (1 - B[i1]))[:, None]
    t_out = out1 * dp + out0 * (P[i1] - P[i0])
    adj1 = (2.0 * (t[i2] - t[i1]) / (t[i3] - t[i1]))[:, None]
    in0 = 0.5 * adj1 * ((1 - T[i2]) * (1 - C[i2]) * (1 + B[i2]))[:, None]
    in1 = 0.5 * adj1 * ((1 - T[i2]) * (1 + C[i2]) * (1 - B[i2]))[:, None]
    t_in = in1 * (P[i3] - P[i2]) + in0 * dp
    coef = np.stack([P[i1], t_out, 3 * dp - 2 * t_out - t_in, -2 * dp + t_out + t_in], axis=1)
    return t[i1].copy(), t[i2].copy(), coef


def _qmul(a, b):
    """Hamilton product of (..., 4) xyzw quaternions."""
    ax, ay, az, aw = np.moveaxis(a, -1, 0)
    bx, by, bz, bw = np.moveaxis(b, -1, 0)
    return np.stack([
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
        aw * bw - ax * bx - ay * by - az * bz,
    ], axis=-1)


def _qconj(q):
    return q * np.array([-1.0, -1.0, -1.0, 1.0])


def _qlog(q):
    """log of unit quaternions: (0, angle * axis) as (..., 4), angle = acos(w)."""
    w = np.clip(q[..., 3], -1.0, 1.0)
    ang = np.arccos(w)
    sn = np.sin(ang)
    coeff = np.where(np.abs(sn) > 1e-12, ang / np.where(sn == 0, 1.0, sn), 1.0)
    out = np.zeros_like(q)
    out[..., :3] = q[..., :3] * coeff[..., None]
    return out


def _qexp(q):
    v = q[..., :3]
    ang = np.linalg.norm(v, axis=-1)
    sn = np.sin(ang)
    coeff = np.where(ang > 1e-12, sn / np.where(ang == 0, 1.0, ang), 1.0)
    out = np.empty_like(q)
    out[..., :3] = v * coeff[..., None]
    out[..., 3] = np.cos(ang)
    return out


def axis_angle_quaternions(axes, radians):
    """(n,4) xyzw unit quaternions from (n,3) axes (normalized here; zero axes give identity)."""
    axes = np.asarray(axes, np.float64)
    big = np.abs(axes).max(axis=1, keepdims=True) if len(axes) else np.ones((0, 1))
    axes = np.divide(axes, big, out=axes.copy(), where=big > 1e150)  # an axis of 1e300 must not overflow the norm
    n = np.linalg.norm(axes, axis=1, keepdims=True)
    unit = np.divide(axes, n, out=np.zeros_like(axes), where=n > 0)
    half = 0.5 * np.asarray(radians, np.float64)
    half = np.where(n[:, 0] > 0, half, 0.0)
    return np.concatenate([unit * np.sin(half)[:, None], np.cos(half)[:, None]], axis=1)


def kb_rotation_segments(times, quats, tcb):
    """Kochanek-Bartels squad segments through keys 1 .. n-2 of ``n >= 4`` rotation keys.

    quats (n,4) xyzw unit quaternions; consecutive keys are first flipped into the same
    hemisphere.  Returns ``(tmin, tmax, pabq (n-3, 4, 4))``: segment i evaluates
    ``squad(u; p, a, b, q) = slerp(2u(1-u), slerp(u, p, q), slerp(u, a, b))`` with p = key i+1,
    q = key i+2 and the inner control quaternions a, b built from the KB tangents in log space.
    """
    t = np.asarray(times, np.float64)
    q = np.array(quats, np.float64)
    for i in range(1, len(q)):
        if np.dot(q[i - 1], q[i]) < 0:
            q[i] = -q[i]
    T, C, B = (np.asarray(tcb, np.float64)[:, k] for k in range(3))
    i0 = np.arange(len(t) - 3)
    i1, i2, i3 = i0 + 1, i0 + 2, i0 + 3
    logdq = _qlog(_qmul(_qconj(q[i1]), q[i2]))
    adj0 = (2.0 * (t[i2] - t[i1]) / (t[i2] - t[i0]))[:, None]
    out0 = 0.5 * adj0 * ((1 - T[i1]) * (1 + C[i1]) * (1 + B[i1]))[:, None]
    out1 = 0.5 * adj0 * ((1 - T[i1]) * (1 - C[i1]) * (1 - B[i1]))[:, None]
    t_out = out1 * logdq + out0 * _qlog(_qmul(_qconj(q[i0]), q[i1]))
    adj1 = (2.0 * (t[i2] - t[i1]) / (t[i3] - t[i1]))[:, None]
    in0 = 0.5 * adj1 * ((1 - T[i2]) * (1 - C[i2]) * (1 + B[i2]))[:, None]
    in1 = 0.5 * adj1 * ((1 - T[i2]) * (1 + C[i2]) * (1 - B[i2]))[:, None]
    t_in = in1 * _qlog(_qmul(_qconj(q[i2]), q[i3])) + in0 * logdq
    a = _qmul(q[i1], _qexp(0.5 * (t_out - logdq)))
    b = _qmul(q[i2], _qexp(0.5 * (logdq - t_in)))
    return t[i1].copy(), t[i2].copy(), np.stack([q[i1], a, b, q[i2]], axis=1)


@inner(cache=True)
def _segment(tmin, tmax, start, count, t):
    """(segment index, u in [0,1]) of time t in segments [start, start+count), clamped at the ends.

    As in BART's code the segment is the first one with ``t < tmax`` (a linear search, which also
    gives the original's behaviour for the robots' non-monotonic keys); u is clamped to [0, 1].
    """
    if t <= tmin[start]:
        return start, 0.0
    last = start + count - 1
    if t >= tmax[last]:
        return last, 1.0
    i = start
    while i < last and not t < tmax[i]:
        i += 1
    span = tmax[i] - tmin[i]
    u = (t - tmin[i]) / span if span != 0.0 else 0.0
    return i, min(max(u, 0.0), 1.0)


@njit(cache=True)
def kb_position(tmin, tmax, coef, start, count, t, out):
    """Evaluate position spline [start, start+count) at t into out (3,) f64."""
    i, u = _segment(tmin, tmax, start, count, t)
    for c in range(3):
        out[c] = coef[i, 0, c] + u * (coef[i, 1, c] + u * (coef[i, 2, c] + u * coef[i, 3, c]))


@inner(cache=True)
def _slerp(u, p, q, out):
    """Eberly's slerp (no shortest-path flip, as squad requires); p, q, out (4,) f64."""
    cs = p[0] * q[0] + p[1] * q[1] + p[2] * q[2] + p[3] * q[3]
    cs = min(max(cs, -1.0), 1.0)
    ang = math.acos(cs)
    if abs(ang) < 1e-6:
        for c in range(4):
            out[c] = p[c]
        return
    sn = math.sin(ang)
    c0 = math.sin((1.0 - u) * ang) / sn
    c1 = math.sin(u * ang) / sn
    for c in range(4):
        out[c] = c0 * p[c] + c1 * q[c]


@njit(cache=True)
def kb_rotation(tmin, tmax, pabq, start, count, t, out):
    """Evaluate rotation spline [start, start+count) at t into out (4,) f64 xyzw unit quaternion."""
    i, u = _segment(tmin, tmax, start, count, t)
    s1 = np.empty(4)
    s2 = np.empty(4)
    _slerp(u, pabq[i, 0], pabq[i, 3], s1)
    _slerp(u, pabq[i, 1], pabq[i, 2], s2)
    _slerp(2.0 * u * (1.0 - u), s1, s2, out)
    n = math.sqrt(out[0] * out[0] + out[1] * out[1] + out[2] * out[2] + out[3] * out[3])
    for c in range(4):
        out[c] /= n


#: The Kochanek-Bartels splines laid end to end (:meth:`_Splines.arrays`): position splines
#: p_tmin, p_tmax (S,) float64, p_coef (S, 4, 3) float64, p_start, p_count (P,) int64; rotation
#: splines r_tmin, r_tmax (Q,) float64, r_pabq (Q, 4, 4) float64, r_start, r_count (R,) int64.
SplineArrays = namedtuple("SplineArrays", "p_tmin p_tmax p_coef p_start p_count r_tmin r_tmax r_pabq r_start r_count")
#: The animated transforms (A,) int64 each: the node each one moves, its translation, rotation and
#: scale spline (-1: that part is the identity).
TransformAnims = namedtuple("TransformAnims", "node t r s")


@njit(cache=True)
def _animate_nodes(t, sp, anims, node_matrix):
    """node_matrix[anims.node[a]] = T * R * S of animated transform a at time t.

    anims.t / anims.s index position splines (translation / scale) of ``sp`` (:data:`SplineArrays`),
    anims.r rotation splines; -1 means identity for that part.
    """
    p_tmin, p_tmax, p_coef, p_start, p_count = sp.p_tmin, sp.p_tmax, sp.p_coef, sp.p_start, sp.p_count
    r_tmin, r_tmax, r_pabq, r_start, r_count = sp.r_tmin, sp.r_tmax, sp.r_pabq, sp.r_start, sp.r_count
    anim_node, anim_t, anim_r, anim_s = anims.node, anims.t, anims.r, anims.s
    tr = np.zeros(3)
    sc = np.ones(3)
    q = np.zeros(4)
    m = np.empty((4, 4))
    for a in range(anim_node.shape[0]):
        if anim_t[a] >= 0:
            kb_position(p_tmin, p_tmax, p_coef, p_start[anim_t[a]], p_count[anim_t[a]], t, tr)
        else:
            tr[:] = 0.0
        if anim_s[a] >= 0:
            kb_position(p_tmin, p_tmax, p_coef, p_start[anim_s[a]], p_count[anim_s[a]], t, sc)
        else:
            sc[:] = 1.0
        if anim_r[a] >= 0:
            kb_rotation(r_tmin, r_tmax, r_pabq, r_start[anim_r[a]], r_count[anim_r[a]], t, q)
        else:
            q[0] = 0.0
            q[1] = 0.0
            q[2] = 0.0
            q[3] = 1.0
        trs_matrix(tr, q, sc, m)
        n = anim_node[a]
        for i in range(4):
            for j in range(4):
                node_matrix[n, i, j] = m[i, j]


# ------------------------------------------------------------------------------ parser


class _Tokens:
    """Whitespace tokens of one AFF file with their line numbers; comments (# or %) removed.

    ``cache`` (a dict, optional) keeps each file's tokens under ``key`` (its resolved path) for the
    files a scene includes more than once (the robots' parts, the kitchen's stools and wheels).
    ``quote``: messages may quote the file's text (:meth:`q`); False for included files, which
    may be no scene file at all (a file of secrets named by ``i``)."""

    def __init__(self, path, cache=None, key=None, quote=True):
        self.path = path
        self.i = 0
        self.quote = quote
        if cache is not None and key in cache:
            self.toks, self.lines = cache[key]
            return
        raw = read_scene_file(path)
        if not raw.strip():
            raise SceneFileError(path, "file is empty")
        text = raw.decode("latin-1")
        toks, lines = [], []
        for ln, line in enumerate(text.splitlines(), 1):  # (the common lines take the fast tests only)
            if "#" in line:
                line = line[:line.find("#")]
            if "%" in line:
                line = line[:line.find("%")]
            if "{" in line or "}" in line:
                line = line.replace("{", " { ").replace("}", " } ")
            parts = line.split()
            if parts:
                toks += parts
                lines += [ln] * len(parts)
        self.toks = toks
        self.lines = lines
        if cache is not None:
            cache[key] = (toks, lines)

    def q(self, tok):
        """``tok`` (text of this file) as a message quotes it: repr for the scene file the user
        named, a placeholder for an included file (its text never reaches a message)."""
        return repr(tok) if self.quote else "[text of an included file, not quoted]"

    def fail(self, problem, at=None):
        k = self.i if at is None else at
        where = f"line {self.lines[min(k, len(self.lines) - 1)]}" if self.lines else "line 1"
        if k >= len(self.toks):
            where = "end of file"
        raise SceneFileError(self.path, f"{where}: {problem}")

    def more(self):
        return self.i < len(self.toks)

    def next(self, what):
        if self.i >= len(self.toks):
            self.fail(f"unexpected end of file while reading {what}")
        tok = self.toks[self.i]
        self.i += 1
        return tok

    def peek(self):
        return self.toks[self.i] if self.i < len(self.toks) else None

    def peek_is_number(self):
        tok = self.peek()
        if tok is None:
            return False
        try:
            float(tok)
            return True
        except ValueError:
            return False

    def numbers(self, n, what):
        """The next n tokens as a float64 array (finite)."""
        if n < 0:
            self.fail(f"negative count while reading {what}")
        if self.i + n > len(self.toks):
            self.fail(f"unexpected end of file: {what} needs {n} numbers, only {len(self.toks) - self.i} tokens left")
        chunk = self.toks[self.i:self.i + n]
        try:
            a = np.array(chunk, dtype=np.float64)
        except ValueError:
            for k, tok in enumerate(chunk):
                try:
                    float(tok)
                except ValueError:
                    self.fail(f"expected a number in {what}, got {self.q(tok)}", at=self.i + k)
            raise
        if not np.isfinite(a).all():
            k = int(np.argmin(np.isfinite(a)))
            self.fail(f"{what} contains a non-finite number {self.q(chunk[k])}", at=self.i + k)
        self.i += n
        return a

    def count(self, what, limit=50_000_000):
        tok = self.next(what)
        try:
            n = int(tok)
        except ValueError:
            self.fail(f"expected a count for {what}, got {self.q(tok)}", at=self.i - 1)
        if not 0 <= n <= limit:
            self.fail(f"{what} count{f' {n}' if self.quote else ''} is out of range", at=self.i - 1)
        return n

    def expect(self, word, what):
        tok = self.next(what)
        if tok != word:
            self.fail(f"expected '{word}' in {what}, got {self.q(tok)}", at=self.i - 1)


def _static_matrix(values):
    """T * R * S from the 10 numbers of an ``xs`` transform (R: axis + degrees)."""
    s, axis, deg, t = values[0:3], values[3:6], values[6], values[7:10]
    q = axis_angle_quaternions(axis[None], [math.radians(deg)])[0]
    m = np.empty((4, 4))
    trs_matrix(t, q, s, m)
    return m


def _unit_rows(v):
    """(..., 3) float64 vectors scaled to unit length (zero vectors stay zero), without overflow
    or underflow for any finite input.  (Written component by component: numpy's reductions over
    a last axis of 3 are several times slower.)"""
    v = np.asarray(v, np.float64)
    a = np.abs(v)
    big = np.maximum(np.maximum(a[..., 0], a[..., 1]), a[..., 2])[..., None]
    v = v / np.where(big > 0, big, 1.0)  # the largest component is now +-1 (or the row is zero)
    n = np.sqrt(v[..., 0] * v[..., 0] + v[..., 1] * v[..., 1] + v[..., 2] * v[..., 2])[..., None]
    return v / np.where(n > 0, n, 1.0)


class _Parser:
    def __init__(self, root, allow_outside=False):
        self.root = root
        self.folder = SceneFolder(root, allow_outside)
        # the BART distribution's textures: TextureFiles beside the aff/ folder of the scenes
        self.texture_folders = (self.folder.root.parent / "TextureFiles",)
        self.node_parent = [-1]
        self.node_matrix = [np.eye(4)]
        self.node_name = [None]
        self.stack = [0]
        # (node, vertices (n,3), faces (m,3), looks): looks = (material id, Texture or None,
        # uv (m,3,2) float64 as the Surface stores them or None, normals or None: (the file's
        # normal vectors (k,3) float64, normalized when the scene is laid out, and each
        # triangle's corners' rows of them (m,3) int64))
        self.blocks = []
        self.tpa = []  # (node, times (K,), vertices (K, 3, 3), normals as in the file (K, 3, 3), material id)
        # materials: (diffuse (3,), ambient reflectance (3,), (file, line)); 0 is the default one
        default = np.array(DEFAULT_DIFFUSE)
        self.materials = [(default, AMBIENT_DEFAULT * default, (root, 0))]
        self.material = 0
        self.ambient_light = None  # (colour (3,), (file, line)) of the last am line
        self.lights = []  # (name or None, position (3,), colour (3,))
        self.texture_files = {}  # resolved path -> Texture or None
        self.texture_lookups = {}  # (file, name) -> Texture or None
        self.token_cache = {}  # resolved path -> (tokens, line numbers) of the files read
        self.anims = {}
        self.view = None
        self.anim_params = None
        self.detail = 0
        self.skipped = {"spheres": 0, "cones": 0, "includes skipped by detail level": 0}
        self.files = []

    def parse_file(self, path, chain=()):
        path = Path(path)
        if len(chain) > _MAX_INCLUDE_DEPTH:
            raise SceneFileError(path, f"includes nested deeper than {_MAX_INCLUDE_DEPTH} levels")
        real = path.resolve()
        if real in chain:
            raise SceneFileError(path, "include cycle: the file includes itself")
        self.files.append(path)
        tk = _Tokens(path, self.token_cache, real, quote=not chain)
        inner = chain + (real,)
        while tk.more():
            at = tk.i
            cmd = tk.next("a command")
            handler = getattr(self, "_cmd_" + cmd, None) if cmd.isidentifier() else None
            if cmd == "}":
                if len(self.stack) <= 1:
                    tk.fail("'}' without a matching transform '{'", at=at)
                self.stack.pop()
            elif handler is None:
                tk.fail(f"unknown AFF command {tk.q(cmd)}", at=at)
            else:
                handler(tk, inner)
        if path == self.root and len(self.stack) != 1:
            tk.fail(f"{len(self.stack) - 1} transform block(s) not closed with '}}'")

    # --- scene description commands that do not produce geometry
    def _cmd_v(self, tk, chain):
        view = {}
        for word, n in (("from", 3), ("at", 3), ("up", 3), ("angle", 1), ("hither", 1), ("resolution", 2)):
            tk.expect(word, "the viewpoint (v)")
            view[word] = tk.numbers(n, f"viewpoint '{word}'")
        self.view = view

    def _numbers_with_colours(self, tk, n, colours, what):
        """The next n numbers, of which the first ones, named by ``colours`` (one name each), must
        be colour values: 0 or more and within float32."""
        at = tk.i
        v = tk.numbers(n, what)
        c = v[:len(colours)]
        if not (c.min() >= 0 and c.max() <= _F32_MAX):
            k = int(np.argmax((c < 0) | (c > _F32_MAX)))
            tk.fail(f"{what} {colours[k]}: {tk.q(tk.toks[at + k])} is not a colour value (0 or more, within float32)",
                    at=at + k)
        return v

    def _light(self, tk, name):
        pos = tk.numbers(3, "light position")
        colour = self._numbers_with_colours(tk, 3, _RGB, "light colour") if tk.peek_is_number() else np.ones(3)
        self.lights.append((name, pos, colour))

    def _cmd_l(self, tk, chain):
        self._light(tk, None)

    def _cmd_la(self, tk, chain):
        at = tk.i
        name = tk.next("animated light name")
        if name in ("{", "}"):
            tk.fail("animated light (la) needs a name", at=at)
        self._light(tk, name)

    def _cmd_b(self, tk, chain):
        tk.numbers(3, "background colour")

    def _cmd_f(self, tk, chain):
        line = tk.lines[tk.i - 1]
        v = self._numbers_with_colours(tk, 8, ("colour",) * 3 + ("Kd",), "fill material (f)")
        with np.errstate(over="ignore"):
            diffuse = v[3] * v[:3]
        if diffuse.max() > _F32_MAX:
            tk.fail("fill material (f): Kd times the colour exceeds float32")
        self.materials.append((diffuse, AMBIENT_DEFAULT * diffuse, (tk.path, line)))
        self.material = len(self.materials) - 1

    def _cmd_fm(self, tk, chain):
        line = tk.lines[tk.i - 1]
        v = self._numbers_with_colours(tk, 12, ("ambient",) * 3 + ("diffuse",) * 3, "fill material (fm)")
        self.materials.append((v[3:6], v[:3], (tk.path, line)))
        self.material = len(self.materials) - 1

    def _cmd_am(self, tk, chain):
        line = tk.lines[tk.i - 1]
        self.ambient_light = (self._numbers_with_colours(tk, 3, _RGB, "ambient light (am)"), (tk.path, line))

    def _cmd_a(self, tk, chain):
        v = tk.numbers(3, "animation parameters (a start end frames)")
        if not v[1] > v[0] or v[2] < 1 or v[2] != int(v[2]):
            tk.fail("animation parameters need end > start and a positive frame count" +
                    (f", got {v.tolist()}" if tk.quote else ""))
        self.anim_params = (float(v[0]), float(v[1]), int(v[2]))

    def _cmd_d(self, tk, chain):
        self.detail = tk.count("detail level (d)")

    def _cmd_s(self, tk, chain):
        tk.numbers(4, "sphere")
        self.skipped["spheres"] += 1

    def _cmd_c(self, tk, chain):
        tk.numbers(8, "cone")
        self.skipped["cones"] += 1

    def _cmd_i(self, tk, chain):
        level = tk.count("include detail level")
        at = tk.i
        name = tk.next("include file name")
        if level > self.detail:
            self.skipped["includes skipped by detail level"] += 1
            return
        here = tk.path.parent
        candidates = [here / name, self.root.parent / name]
        for c in candidates:
            if c.exists():
                if not self.folder.is_inside(c):
                    tk.fail(f"include {tk.q(name)} leads outside the scene's folder ({self.folder.root}); "
                            f"{ALLOW_HINT}", at=at)
                if not c.is_file():
                    tk.fail(f"include {tk.q(name)} is not a regular file", at=at)
                self.parse_file(c, chain)
                return
        tk.fail(f"included file {tk.q(name)} not found (looked in {here})", at=at)

    # --- transforms
    def _open(self, tk, matrix, name):
        tk.expect("{", "a transform")
        self.node_parent.append(self.stack[-1])
        self.node_matrix.append(matrix)
        self.node_name.append(name)
        self.stack.append(len(self.node_parent) - 1)

    def _cmd_xs(self, tk, chain):
        v = tk.numbers(10, "static transform (xs)")
        if not np.any(v[3:6]) and v[6] != 0:
            tk.fail("static transform (xs) rotates about a zero axis")
        self._open(tk, _static_matrix(v), None)

    def _cmd_x(self, tk, chain):
        name = tk.next("transform name")
        if name in ("{", "}"):
            tk.fail("animated transform (x) needs a name")
        self._open(tk, np.eye(4), name)

    def _cmd_k(self, tk, chain):
        name = tk.next("keyframe block name")
        name_q = tk.q(name)
        tk.expect("{", f"keyframes of {name_q}")
        anim = {}
        while True:
            at = tk.i
            motion = tk.next(f"keyframes of {name_q}")
            if motion == "}":
                break
            what = f"{tk.q(motion) if motion not in _MOTIONS else motion} keys of {name_q}"
            n = tk.count(what, limit=10_000_000)
            if motion in ("transl", "scale", "rot"):
                if n < 4:
                    tk.fail(f"{what}: Kochanek-Bartels splines need at least 4 keys, got {n}", at=at)
                width = 8 if motion == "rot" else 7
                keys = tk.numbers(n * width, what).reshape(n, width)
                t = keys[:, 0]
                if not ((t[2:] != t[:-2]).all()):
                    k = int(np.argmin(t[2:] != t[:-2]))
                    when = f" {t[k]}" if tk.quote else ""
                    tk.fail(f"{what}: keys {k} and {k + 2} have the same time{when}, which leaves the "
                            "spline tangent undefined", at=at)
                if motion == "rot":
                    axis = keys[:, 1:4]
                    zero = ~axis.any(axis=1)
                    if (zero & (keys[:, 4] != 0)).any():
                        tk.fail(f"{what}: rotation about a zero axis", at=at)
                anim[motion] = keys
            elif motion == "visibility":
                keys = tk.numbers(n * 2, what).reshape(n, 2)
                if (np.diff(keys[:, 0]) < 0).any():
                    tk.fail(f"{what}: key times decrease", at=at)
                anim[motion] = keys
            else:
                tk.fail(f"unknown keyframe type {tk.q(motion)} in {name_q} (transl, rot, scale or visibility)", at=at)
        self.anims[name] = anim

    # --- textures
    def _texture(self, tk, name, at):
        """The Texture of image file ``name`` (token ``at`` of ``tk``), or None (warned) when it
        cannot be found or read; each file is read once."""
        key = (tk.path, name)
        if key in self.texture_lookups:
            return self.texture_lookups[key]
        here = tk.path.parent
        top = self.root.parent
        dirs = list(dict.fromkeys([here, top, here / "TextureFiles", here.parent / "TextureFiles",
                                   top / "TextureFiles", top.parent / "TextureFiles"]))
        tex = None
        for d in dirs:
            c = d / name
            try:
                found = c.is_file()
                real = c.resolve() if found else None
            except (OSError, ValueError):
                found = False
            if found and not self.folder.is_inside(c, self.texture_folders):
                where = f"line {tk.lines[min(at, len(tk.lines) - 1)]}"
                warnings.warn(f"texture {tk.q(name)} ({tk.path}, {where}): leads outside the scene's folder "
                              f"({self.folder.root}, or {self.texture_folders[0]} for textures); {ALLOW_HINT}; "
                              "drawn without it", TextureWarning, stacklevel=2)
                break
            if found:
                if real not in self.texture_files:
                    self.texture_files[real] = load_texture(c, name=str(c))
                tex = self.texture_files[real]
                break
        else:
            where = f"line {tk.lines[min(at, len(tk.lines) - 1)]}"
            label = (f"{tk.q(name)} ({tk.path}, {where}; looked in {', '.join(str(d) for d in dirs)})")
            tex = load_texture(dirs[0] / name, name=label)
        self.texture_lookups[key] = tex
        return tex

    def _uv(self, tk, uv, at, what):
        """Texture coordinates (..., 2) as the Surface stores them (as in the file: see the module's
        docstring), float64."""
        uv = np.asarray(uv, np.float64)
        if len(uv) and np.abs(uv).max() > _F32_MAX:
            tk.fail(f"{what}: a texture coordinate exceeds float32", at=at)
        return uv

    # --- geometry
    def _add(self, vertices, faces, texture=None, uv=None, normals=None):
        self.blocks.append((self.stack[-1], vertices, faces, (self.material, texture, uv, normals)))

    def _polygon(self, tk, patch):
        n = tk.count("polygon vertex count")
        if n < 3:
            tk.fail(f"a polygon needs at least 3 vertices, got {n}")
        w = 6 if patch else 3
        rec = tk.numbers(n * w, "polygon vertices").reshape(n, w)
        i = np.arange(1, n - 1)
        faces = np.stack([np.zeros(n - 2, dtype=np.int64), i, i + 1], axis=1)
        self._add(rec[:, :3], faces, normals=(rec[:, 3:6], faces) if patch else None)

    def _cmd_p(self, tk, chain):
        self._polygon(tk, False)

    def _cmd_pp(self, tk, chain):
        self._polygon(tk, True)

    def _textured(self, tk, patch):
        at = tk.i
        name = tk.next("texture name")
        w = 8 if patch else 5
        what = "textured triangle patch (ttp)" if patch else "textured triangle (tt)"
        rec = tk.numbers(3 * w, what).reshape(3, w)
        uv = self._uv(tk, rec[None, :, w - 2:], at, what)
        one = np.array([[0, 1, 2]])
        self._add(rec[:, :3], one, self._texture(tk, name, at), uv, (rec[:, 3:6], one) if patch else None)

    def _cmd_tt(self, tk, chain):
        self._textured(tk, False)

    def _cmd_ttp(self, tk, chain):
        self._textured(tk, True)

    def _cmd_tpa(self, tk, chain):
        n = tk.count("tpa key count", limit=1_000_000)
        if n < 1:
            tk.fail("an animated triangle (tpa) needs at least one key")
        rec = tk.numbers(n * 19, "animated triangle (tpa)").reshape(n, 19)
        times = rec[:, 0]
        if (np.diff(times) < 0).any():
            tk.fail("animated triangle (tpa): key times decrease")
        corners = rec[:, 1:].reshape(n, 3, 6)
        self.tpa.append((self.stack[-1], times, corners[:, :, :3], corners[:, :, 3:], self.material))

    def _cmd_m(self, tk, chain):
        tk.expect("vertices", "mesh (m)")
        nv = tk.count("mesh vertices")
        v = tk.numbers(3 * nv, "mesh vertices").reshape(nv, 3)
        word = tk.next("mesh")
        normals = coords = None
        if word == "normals":
            nn = tk.count("mesh normals")
            normals = tk.numbers(3 * nn, "mesh normals").reshape(nn, 3)
            word = tk.next("mesh")
        if word == "texturecoords":
            nt = tk.count("mesh texture coordinates")
            tex_at = tk.i
            name = tk.next("texture name")
            coords = tk.numbers(2 * nt, "mesh texture coordinates").reshape(nt, 2)
            word = tk.next("mesh")
        if word != "triangles":
            tk.fail(f"expected 'triangles' in mesh, got {tk.q(word)}", at=tk.i - 1)
        nf = tk.count("mesh triangles")
        # each triangle: vertex indices, then normal indices, then texture coordinate indices
        parts = [("vertex", "vertices", nv)]
        if normals is not None:
            parts.append(("normal", "normals", len(normals)))
        if coords is not None:
            parts.append(("texture coordinate", "texture coordinates", len(coords)))
        w = 3 * len(parts)
        at = tk.i
        rows = tk.numbers(w * nf, "mesh triangle indices").reshape(nf, w)
        if not nf:
            return
        limit = np.repeat([n for _, _, n in parts], 3)
        wrong = (rows < 0) | (rows >= limit) | (rows != np.round(rows))
        if wrong.any():
            bad, col = divmod(int(np.argmax(wrong.ravel())), w)
            what, plural, n = parts[col // 3]
            k = 3 * (col // 3)
            tk.fail(f"mesh triangle {bad} has a {what} index out of range for {n} {plural} "
                    + (f"({rows[bad, k:k + 3].tolist()})" if tk.quote else "(not quoted: an included file)"),
                    at=at + bad * w + k)
        idx = rows.astype(np.int64)
        tex = uv = nrm = None
        if normals is not None:
            nrm = (normals, idx[:, 3:6])
        if coords is not None:
            tex = self._texture(tk, name, tex_at)
            uv = self._uv(tk, coords, tex_at, "mesh texture coordinates")[idx[:, w - 3:]]
        self._add(v, idx[:, :3], tex, uv, nrm)


# ------------------------------------------------------------------------------ laying out the scene
# BartAnimation._build calls these after the parser has read every file.


class _Splines:
    """Kochanek-Bartels position and rotation splines laid end to end, as :func:`_animate_nodes`,
    :func:`kb_position` and :func:`kb_rotation` take them; ``add_*`` returns the new spline's index
    and fails, naming ``what``, when the spline through the keys is not finite."""

    def __init__(self, path):
        self.path = path
        self.p_tmin, self.p_tmax, self.p_coef, self.p_start, self.p_count = [], [], [], [], []
        self.r_tmin, self.r_tmax, self.r_pabq, self.r_start, self.r_count = [], [], [], [], []
        self.n_p = self.n_r = 0

    def _check_finite(self, what, *arrays):
        if not all(np.isfinite(a).all() for a in arrays):
            raise SceneFileError(self.path, f"{what}: the spline through these keys is not finite "
                                            "(key values or tension/continuity/bias too large)")

    def add_position(self, keys, what):
        """``transl`` or ``scale`` keys: rows of time, x, y, z, tension, continuity, bias."""
        with np.errstate(all="ignore"):  # overflow is reported below, as an error naming the keys
            tmin, tmax, coef = kb_position_coefficients(keys[:, 0], keys[:, 1:4], keys[:, 4:7])
        self._check_finite(what, tmin, tmax, coef)
        self.p_tmin.append(tmin), self.p_tmax.append(tmax), self.p_coef.append(coef)
        self.p_start.append(self.n_p), self.p_count.append(len(tmin))
        self.n_p += len(tmin)
        return len(self.p_start) - 1

    def add_rotation(self, keys, what):
        """``rot`` keys: rows of time, axis x, y, z, degrees, tension, continuity, bias."""
        with np.errstate(all="ignore"):
            q = axis_angle_quaternions(keys[:, 1:4], np.radians(keys[:, 4]))
            tmin, tmax, pabq = kb_rotation_segments(keys[:, 0], q, keys[:, 5:8])
        self._check_finite(what, tmin, tmax, pabq)
        self.r_tmin.append(tmin), self.r_tmax.append(tmax), self.r_pabq.append(pabq)
        self.r_start.append(self.n_r), self.r_count.append(len(tmin))
        self.n_r += len(tmin)
        return len(self.r_start) - 1

    def arrays(self):
        """The splines as :data:`SplineArrays`, with one placeholder segment where there is no spline
        of a kind."""
        def cat(lst, shape):
            return np.ascontiguousarray(np.concatenate(lst)) if lst else np.zeros(shape)

        return SplineArrays(
            cat(self.p_tmin, (1,)), cat(self.p_tmax, (1,)), cat(self.p_coef, (1, 4, 3)),
            np.array(self.p_start or [0], np.int64), np.array(self.p_count or [1], np.int64),
            cat(self.r_tmin, (1,)), cat(self.r_tmax, (1,)), cat(self.r_pabq, (1, 4, 4)),
            np.array(self.r_start or [0], np.int64), np.array(self.r_count or [1], np.int64),
        )


def _keys_constant(keys, cols):
    """Whether columns ``cols`` of the key rows hold one value (the motion moves nothing)."""
    return bool((np.ptp(keys[:, cols], axis=0) == 0).all())


def _moving_nodes(parent, moved):
    """(N,) bool: the nodes in ``moved`` and every node below one."""
    n_nodes = len(parent)
    moving = np.zeros(n_nodes, dtype=bool)
    for i in range(n_nodes):  # parents are created before their children
        moving[i] = i in moved or (parent[i] >= 0 and moving[parent[i]])
    return moving


def _tpa_groups(tpa):
    """The ``tpa`` triangles grouped by their key times: key-times bytes -> (times, [(node, keyed
    vertices (K, 3, 3), keyed normals (K, 3, 3), material id), ...]), groups and members in file order."""
    groups = {}
    for node, times, tv, tn, mat in tpa:
        groups.setdefault(times.tobytes(), (times, []))[1].append((node, tv, tn, mat))
    return groups


def _key_blend(times, tb):
    """(k, k1, s): time ``tb`` lies between keys k and k1 of ``times`` at fraction s (clamped at the ends)."""
    if tb <= times[0]:
        k, s = 0, 0.0
    elif tb >= times[-1]:
        k, s = len(times) - 1, 0.0
    else:
        k = int(np.searchsorted(times, tb, side="right") - 1)
        s = (tb - times[k]) / (times[k + 1] - times[k])
    return k, min(k + 1, len(times) - 1), float(s)


def _inverse_transposes(world):
    """(N, 4, 4) float64: each node's inverse transpose of its world matrix's linear part, times a
    positive factor that brings its largest entry to 1 (the normals it turns are normalized after),
    in the upper-left 3x3 and zero elsewhere.  A singular part (an invisible node) gives its
    cofactor matrix, zero when the part is zero."""
    a = world[:, :3, :3]
    big = np.abs(a).max(axis=(1, 2), keepdims=True)
    a = np.divide(a, big, out=np.zeros_like(a), where=big > 0)
    c0, c1, c2 = a[:, :, 0], a[:, :, 1], a[:, :, 2]
    cof = np.stack([np.cross(c1, c2), np.cross(c2, c0), np.cross(c0, c1)], axis=2)  # columns: det * inv^T
    det = (c0 * cof[:, :, 0]).sum(axis=1)
    cof *= np.where(det < 0, -1.0, 1.0)[:, None, None]
    big = np.abs(cof).max(axis=(1, 2), keepdims=True)
    out = np.zeros((len(world), 4, 4))
    np.divide(cof, big, out=out[:, :3, :3], where=big > 0)
    return out


# ------------------------------------------------------------------------------ the scene


class BartAnimation(Animation):
    """A BART scene (.aff) posed at time t.

    Parameters
    ----------
    path : str or os.PathLike
        The root .aff file; includes are resolved relative to the including file's folder (then the
        root's).
    allow_outside : bool
        Trust includes and textures that resolve outside the root file's folder (see the module's
        docstring, "Files"); by default such an include is a SceneFileError and such a texture is
        left out with a TextureWarning.

    Attributes
    ----------
    time_range : tuple of float or None
        ``(start, end)`` from the ``a`` line (else the span of the spline keys); ``t`` maps to BART
        time ``start + (t mod (end - start))``.
    n_frames : int or None
        The ``a`` line's frame count; frame k is at ``t = k * duration / (n_frames - 1)``.
    static_mask : ndarray
        (F,) bool, True for triangles under no animated transform that are not ``tpa`` triangles
        (a transform whose keys are all equal counts as not animated).
    view : dict or None
        The ``v`` block: from, at, up (3,) f64, angle (degrees), hither, resolution.
    skipped : dict
        Counts of primitives that are not triangles (spheres, cones) and of includes skipped by the
        detail level.
    files : list of Path
        Every file read, root first.
    surface : gridrt.scene.surface.Surface
        The materials, textures, uv and normals (at t = 0) of the triangles, in the order of
        ``triangles_at``; :meth:`normals_at` and :meth:`lights_at` give the normals and lights at
        time t (see the module's docstring).

    Raises SceneFileError (naming the file and line) for missing, unreadable or malformed files;
    images that cannot be read warn (gridrt.scene.surface.TextureWarning) and are left out.
    """

    def __init__(self, path, *, allow_outside=False):
        if not isinstance(path, (str, os.PathLike)):
            raise InputError(f"AFF path must be a str or path-like object, got {type(path).__name__}")
        p = Path(path)
        if not p.exists():
            raise SceneFileError(p, "file not found")
        if p.is_dir():
            raise SceneFileError(p, "is a directory, not an .aff file")
        ps = _Parser(p, allow_outside)
        ps.parse_file(p)
        if not ps.blocks and not ps.tpa:
            raise SceneFileError(p, "the scene holds no triangles")
        self.path = p
        self.name = p.stem
        self.view = ps.view
        self.skipped = ps.skipped
        self.files = ps.files
        self._build(ps)

    def _build(self, ps):
        """Lay the parsed scene out in the arrays the per-frame kernels take, then pose time 0."""
        n_nodes = len(ps.node_parent)
        parent = np.array(ps.node_parent, dtype=np.int32)
        node_matrix = np.ascontiguousarray(np.stack(ps.node_matrix), dtype=np.float64)

        splines = _Splines(self.path)
        self._anim, moved, key_lo, key_hi = self._read_transform_animations(ps, splines)
        cam = ps.anims.get("camera", {})
        self._cam_t = splines.add_position(cam["transl"], "transl keys of 'camera'") if "transl" in cam else -1
        self._cam_r = splines.add_rotation(cam["rot"], "rot keys of 'camera'") if "rot" in cam else -1
        self._read_lights(ps, splines)
        self._splines = splines.arrays()

        moving = _moving_nodes(parent, moved)
        groups = _tpa_groups(ps.tpa)
        vert_moving, tri_moving = self._lay_out_geometry(ps, moving, groups)
        for times, _ in groups.values():  # the tpa keys widen the span of the spline keys
            key_lo, key_hi = min(key_lo, times[0]), max(key_hi, times[-1])
        self._set_node_arrays(parent, node_matrix)
        self.n_nodes = n_nodes
        self.n_animated_transforms = len(self._anim[0])
        self.n_tpa = sum(len(m[1]) for m in groups.values())

        self.n_triangles = int(len(self._faces))
        mask = ~tri_moving
        self.static = bool(mask.all())
        self.static_mask = as_static_mask(mask, self.n_triangles)
        self._set_time_range(ps.anim_params, key_lo, key_hi)
        self._pose_first_frame(vert_moving)
        self._build_surface(ps, tri_moving)

    def _read_transform_animations(self, ps, splines):
        """The splines of the ``k`` blocks that animate ``x`` transforms (their indices by name in
        ``self._transform_splines``) and their visibility keys (``self._visibility``).  Returns the
        (node, translation, rotation, scale spline) index arrays :func:`_animate_nodes` takes, the
        nodes whose keys move them, and the first and last key times the motion reaches."""
        anim_node, anim_t, anim_r, anim_s = [], [], [], []
        self._transform_splines = {}
        moved = set()
        key_lo, key_hi = math.inf, -math.inf
        self._visibility = []
        for node, name in enumerate(ps.node_name):
            if name is None or name not in ps.anims:
                continue
            an = ps.anims[name]
            ids = [-1, -1, -1]
            for k, motion in enumerate(("transl", "rot", "scale")):
                if motion in an:
                    keys = an[motion]
                    what = f"{motion} keys of {name!r}"
                    ids[k] = splines.add_rotation(keys, what) if motion == "rot" else splines.add_position(keys, what)
                    key_lo, key_hi = min(key_lo, keys[1, 0]), max(key_hi, keys[-2, 0])
                    cols = [1, 2, 3, 4] if motion == "rot" else [1, 2, 3]
                    if not _keys_constant(keys, cols):
                        moved.add(node)
            if "visibility" in an:
                self._visibility.append((node, an["visibility"]))
                if len(np.unique(an["visibility"][:, 1] != 0)) > 1 or not an["visibility"][0, 1]:
                    moved.add(node)
            self._transform_splines[name] = tuple(ids)
            anim_node.append(node)
            anim_t.append(ids[0])
            anim_r.append(ids[1])
            anim_s.append(ids[2])
        anim = TransformAnims(*(np.array(a, dtype=np.int64) for a in (anim_node, anim_t, anim_r, anim_s)))
        return anim, moved, key_lo, key_hi

    def _lay_out_geometry(self, ps, moving, groups):
        """The vertices and faces: static blocks first in file order, then the tpa triangles by
        groups of key times.  Sets ``self._local`` (float32, relative to ``self._centre``),
        ``self._faces``, ``self._vinst`` (each vertex's node), ``self._tpa`` (per group: key
        times, keyed vertices, first and end vertex), ``self._tpa_normal_keys`` (per group: keyed
        normals) and ``self._looks`` (the parser's looks of each piece, in the same triangle order).
        Returns the (V,) vertices and (F,) triangles that can move: under a moving node, or tpa
        triangles whose keys differ."""
        verts, faces, tri_moving, vnode = [], [], [], []
        self._looks = []  # per piece of triangles, in triangle order: (count, node, looks as the parser made them)
        v0 = 0
        for node, v, f, looks in ps.blocks:
            verts.append(v)
            faces.append(f + v0)
            tri_moving.append(np.full(len(f), moving[node]))
            vnode.append(np.full(len(v), node, dtype=np.int32))
            self._looks.append((len(f), node, looks))
            v0 += len(v)
        # float32 storage relative to a float64 centre when the scene lies far from the origin
        centre = storage_centre(np.concatenate([b[1] for b in ps.blocks] + [t[2][0] for t in ps.tpa])
                                if ps.blocks or ps.tpa else np.zeros((0, 3)))
        self._tpa = []
        self._tpa_normal_keys = []  # per group: keyed normals (K, 3m, 3) float32
        for times, members in groups.values():
            frames = np.concatenate([m[1] for m in members], axis=1)  # (K, 3m, 3)
            nodes = np.repeat([m[0] for m in members], 3).astype(np.int32)
            n = frames.shape[1]
            self._tpa.append((times, np.ascontiguousarray(frames - centre, dtype=TRI_DTYPE), v0, v0 + n))
            # Each corner's normals are interpolated like the positions and normalized after, so only
            # their directions and relative lengths matter: each corner's keys are scaled by one factor.
            nk = np.concatenate([m[2] for m in members], axis=1)  # (K, 3m, 3)
            big = np.abs(nk).max(axis=(0, 2), keepdims=True)
            nk = np.divide(nk, big, out=np.zeros_like(nk), where=big > 0)
            self._tpa_normal_keys.append(np.ascontiguousarray(nk, dtype=TRI_DTYPE))
            self._looks.extend((1, m[0], (m[3], None, None, "tpa")) for m in members)
            verts.append(frames[0])
            faces.append(np.arange(v0, v0 + n).reshape(-1, 3))
            moves = moving[nodes[::3]] | (np.ptp(frames, axis=0).reshape(-1, 9).max(axis=1) > 0)
            tri_moving.append(moves)
            vnode.append(nodes)
            v0 += n
        local64 = np.concatenate(verts).astype(np.float64)
        if np.abs(local64).max() > 1e30:
            raise SceneFileError(self.path, "vertex coordinates beyond 1e30, too large for float32")
        self._faces = np.ascontiguousarray(np.concatenate(faces), dtype=np.int32)
        self._local = np.ascontiguousarray(local64 - centre, dtype=TRI_DTYPE)
        self._centre = centre
        self._vinst = np.concatenate(vnode)
        tri_moving = np.concatenate(tri_moving)
        vert_moving = np.zeros(len(self._local), dtype=bool)
        vert_moving[self._faces[tri_moving].ravel()] = True
        return vert_moving, tri_moving

    def _read_lights(self, ps, splines):
        """The ``l``/``la`` lights as a light array (``self._lights``) and, for each ``la`` light
        with ``transl`` keys, its row and position spline (``self._light_splines``)."""
        rows, self._light_splines = [], []
        for i, (name, pos, colour) in enumerate(ps.lights):
            rows.append([LIGHT_POINT, *pos, *colour, FALLOFF_NONE])
            keys = ps.anims.get(name, {}).get("transl") if name is not None else None
            if keys is not None:
                self._light_splines.append((i, splines.add_position(keys, f"transl keys of light {name!r}")))
        self._lights = as_lights(np.array(rows, np.float64).reshape(-1, 8))

    def _build_surface(self, ps, tri_moving):
        """``self.surface`` from the looks of the laid-out triangles (``self._looks``), and what
        :meth:`_fill_normals` takes (see :meth:`_lay_out_normals`)."""
        rest = self._lay_out_normals(tri_moving)
        am = ps.ambient_light[0] if ps.ambient_light is not None else np.ones(3)
        builder = SurfaceBuilder()
        rows = {}
        f0 = 0
        for n, _, (mid, tex, uv, normals) in self._looks:
            key = (mid, id(tex))
            if key not in rows:
                diffuse, reflectance, (path, line) = ps.materials[mid]
                with np.errstate(over="ignore"):
                    ambient = reflectance * am
                if ambient.max() > _F32_MAX:
                    raise SceneFileError(path, f"line {line}: the material's ambient colour times the ambient light "
                                               "(am) exceeds float32")
                rows[key] = builder.material_index(diffuse, ambient, tex)
            builder.add(n, None, None, uv=uv, material=rows[key],
                        normals=None if normals is None else rest[f0:f0 + n])
            f0 += n
        del self._looks
        self.surface = builder.build()

    def _lay_out_normals(self, tri_moving):
        """The shading normals: every distinct normal of the file is one row of a table
        ``self._normal_rows`` (R, 3) float32 (row 0 is the zero normal of the triangles without
        any) and ``self._normal_corners`` (F, 3) int32 names each triangle corner's row, so the
        normals at time t are a gather of the table.  The rows that can turn (under a moving
        transform, and those of ``tpa`` triangles, last) form the table's tail from row
        ``self._normal_set[0]``, posed again for each t from their rows in their node's frame.
        Returns the (F, 3, 3) float32 normals at time 0, or None when the file has no normals."""
        F = self.n_triangles
        corners = np.zeros((F, 3), np.int64)
        parts = ([], [])  # (unit vectors' sources, node, first triangle, corner rows) of static / turning pieces
        f0 = 0
        for n, node, (_, _, _, normals) in self._looks:
            if normals is not None and not isinstance(normals, str):
                parts[bool(tri_moving[f0])].append((normals[0], node, f0, n, normals[1]))
            f0 += n
        tpa_tris = np.arange(F - sum(k.shape[1] for k in self._tpa_normal_keys) // 3, F)
        self._normal_set = None
        if not (parts[0] or parts[1] or len(tpa_tris)):
            return None
        row = 1
        vectors, nodes = [], []
        for group in parts:
            for vecs, node, f0, n, idx in group:
                corners[f0:f0 + n] = idx + row
                vectors.append(vecs)
                nodes.append(np.full(len(vecs), node, np.int32))
                row += len(vecs)
            if group is parts[0]:
                first_turning = row
        corners[tpa_tris] = row + np.arange(3 * len(tpa_tris)).reshape(-1, 3)
        nodes.append(np.repeat(self._tri_node(tpa_tris), 3).astype(np.int32))
        n_rows = row + 3 * len(tpa_tris)
        local = np.zeros((n_rows - 1, 3), TRI_DTYPE)  # rows 1.. in their node's frame; tpa rows filled when posed
        if vectors:
            local[:row - 1] = _unit_rows(np.concatenate(vectors))
        nodes = np.concatenate(nodes)
        self._normal_corners = np.ascontiguousarray(corners, dtype=np.int32)
        self._normal_rows = np.zeros((n_rows, 3), TRI_DTYPE)
        every = (1, local, nodes, np.arange(len(local), dtype=np.int64), np.empty_like(local))
        self._pose_normal_rows(self.bart_time(0.0), every)
        rest = np.empty((F, 3, 3), TRI_DTYPE)
        gather_unchecked(self._normal_rows, self._normal_corners, rest)
        k = first_turning - 1
        if n_rows > first_turning:
            self._normal_set = (first_turning, np.ascontiguousarray(local[k:]), nodes[k:],
                                np.arange(len(local) - k, dtype=np.int64), np.empty_like(local[k:]))
        return rest

    def _tri_node(self, tris):
        """The node of each of the triangles ``tris``."""
        return self._vinst[self._faces[tris, 0]]

    def _pose_normal_rows(self, tb, normal_set):
        """Write the rows ``first..`` of ``self._normal_rows`` at BART time ``tb``: a normal set
        (first, local rows (R, 3) float32 in their node's frame, the last ones those of the ``tpa``
        triangles, nodes (R,) int32, row ids (R,) int64, scratch (R, 3) float32) whose ``tpa`` rows
        are interpolated between their keys, then every row turned by its node's inverse transpose
        (the rigid posing kernel with matrices of no translation) and normalized (zero stays zero)."""
        first, rows, nodes, vids, posed = normal_set
        start = len(rows) - sum(k.shape[1] for k in self._tpa_normal_keys)
        for (times, _, _, _), keys in zip(self._tpa, self._tpa_normal_keys):
            k, k1, s = _key_blend(times, tb)
            lerp_rows(keys[k], keys[k1], s, rows[start:start + keys.shape[1]])
            start += keys.shape[1]
        self._update_world(tb)
        w, pal = self._no_skin
        deform_vertices(vids, rows, nodes, self._rig, Pose(w, _inverse_transposes(self._world), pal), _ZERO3,
                          _ZERO3, posed)
        # each component is at most 3 in size: the rows' components and the matrices' entries are at most 1
        n2 = np.einsum("ij,ij->i", posed, posed)
        inv = np.zeros_like(n2)
        np.divide(1.0, np.sqrt(n2), out=inv, where=n2 > 0)
        np.multiply(posed, inv[:, None], out=self._normal_rows[first:])

    def _set_node_arrays(self, parent, node_matrix):
        """The node hierarchy, and one rigid "instance" per node for the shared deform kernel."""
        n_nodes = len(parent)
        self._rig = as_rig(
            np.zeros(n_nodes + 1, dtype=np.int64),  # unused: no morph targets
            np.arange(n_nodes, dtype=np.int32),
            np.zeros(n_nodes, dtype=np.bool_),
            np.zeros(n_nodes, dtype=np.int64),
            np.zeros(n_nodes, dtype=np.int32),
            np.zeros(n_nodes, dtype=np.int64),
            np.zeros((1, 1), np.int32), np.zeros((1, 1), TRI_DTYPE), np.zeros((1, 3), TRI_DTYPE),
        )
        self._no_skin = (np.zeros(1), np.zeros((1, 4, 4)))  # morph weights and skin palette: none
        self._parent = parent
        self._order = np.arange(n_nodes, dtype=np.int32)
        self._use_matrix = np.ones(n_nodes, dtype=np.bool_)
        self._node_matrix = node_matrix
        self._trs = (np.zeros((n_nodes, 3)), np.zeros((n_nodes, 4)), np.ones((n_nodes, 3)))
        self._world = np.zeros((n_nodes, 4, 4))

    def _set_time_range(self, anim_params, key_lo, key_hi):
        """``time_range``, ``n_frames`` and ``duration``: from the ``a`` line, else the span of the keys."""
        if anim_params is not None:
            start, end, frames = anim_params
            self.time_range = (start, end)
            self.n_frames = frames
        elif key_hi > key_lo:
            self.time_range = (float(key_lo), float(key_hi))
            self.n_frames = None
        else:
            self.time_range = None
            self.n_frames = None
        self.duration = None
        if self.time_range is not None:
            self.duration = self.time_range[1] - self.time_range[0]

    def _pose_first_frame(self, vert_moving):
        """Pose every vertex at time 0; later frames recompute the vertices ``vert_moving`` marks.
        Fails when the pose is not finite or exceeds 1e30."""
        vid = np.arange(len(self._local), dtype=np.int64)
        self._dynamic_vids = vid[vert_moving]
        self._verts = np.zeros_like(self._local)
        self._posed_origin = np.zeros(3)  # the frame self._verts is in
        self._pose(self.bart_time(0.0), vid)
        if not (np.isfinite(self._verts).all() and np.abs(self._verts).max() <= 1e30):
            raise SceneFileError(self.path, "transformed vertex coordinates are not finite or exceed 1e30 "
                                            "(check the xs scales and keyframes)")

    # ---------------------------------------------------------------- evaluation

    def bart_time(self, t):
        """BART clock time of animation time ``t``: ``start + (t mod (end - start))``."""
        t = check_time(t)
        if self.time_range is None:
            return 0.0
        return self.time_range[0] + (t % self.duration)

    def _update_world(self, tb):
        _animate_nodes(tb, self._splines, self._anim, self._node_matrix)
        for node, keys in self._visibility:
            k = np.searchsorted(keys[:, 0], tb, side="right") - 1
            visible = True if k < 0 else bool(keys[k, 1])
            if not visible:
                self._node_matrix[node, :3, :3] = 0.0
        compose_world(self._order, self._parent, self._use_matrix, self._node_matrix, *self._trs, self._world)

    def _pose(self, tb, vids):
        for times, frames, a, b in self._tpa:
            k, k1, s = _key_blend(times, tb)
            lerp_rows(frames[k], frames[k1], s, self._local[a:b])
        self._update_world(tb)
        w, pal = self._no_skin
        deform_vertices(vids, self._local, self._vinst, self._rig, Pose(w, self._world, pal), self._centre,
                          self._posed_origin, self._verts)

    def _fill(self, t, out, origin):
        pose_moving_vertices(self, self.bart_time(t), origin)
        gather_unchecked(self._verts, self._faces, out)

    def _fill_normals(self, t, out):
        """The normals at time t: the rows of the normals that turn posed at t, then gathered."""
        if self._normal_set is not None:
            self._pose_normal_rows(self.bart_time(t), self._normal_set)
        gather_unchecked(self._normal_rows, self._normal_corners, out)
        return True

    def lights_at(self, t):
        """The ``l`` and ``la`` lights at time ``t`` (an (L, 8) float64 light array, see
        gridrt.scene.surface): point lights without falloff, ``la`` lights with ``transl`` keys
        at that spline's value."""
        tb = self.bart_time(t)
        if not self._light_splines:
            return self._lights
        a = self._lights.copy()
        for row, spline in self._light_splines:
            a[row, 1:4] = self.spline_value("position", spline, tb)
        return as_lights(a)

    def spline_value(self, kind, index, tb):
        """Evaluate position spline (kind "position") or rotation spline ("rotation") ``index`` at
        BART time ``tb``: (3,) translation/scale or (4,) xyzw quaternion, float64."""
        sp = self._splines
        if kind == "position":
            out = np.zeros(3)
            kb_position(sp.p_tmin, sp.p_tmax, sp.p_coef, sp.p_start[index], sp.p_count[index], float(tb), out)
        else:
            out = np.zeros(4)
            kb_rotation(sp.r_tmin, sp.r_tmax, sp.r_pabq, sp.r_start[index], sp.r_count[index], float(tb), out)
        return out

    @property
    def animated_transforms(self):
        """Names of the ``x`` transforms that have a ``k`` block (sorted)."""
        return sorted(self._transform_splines)

    def transform_at(self, name, t):
        """Local 4x4 float64 matrix ``T * R * S`` of the animated transform ``name`` at time ``t``.

        Raises InputError for a name that is not an animated transform of the scene.
        """
        if name not in self._transform_splines:
            raise InputError(f"no animated transform {name!r}; the scene has {', '.join(self.animated_transforms)}")
        tb = self.bart_time(t)
        ti, ri, si = self._transform_splines[name]
        tr = self.spline_value("position", ti, tb) if ti >= 0 else np.zeros(3)
        q = self.spline_value("rotation", ri, tb) if ri >= 0 else np.array([0.0, 0.0, 0.0, 1.0])
        sc = self.spline_value("position", si, tb) if si >= 0 else np.ones(3)
        m = np.empty((4, 4))
        trs_matrix(tr, q, sc, m)
        return m

    def camera_at(self, t):
        """The BART viewpoint at time ``t`` (:class:`gridrt.camera.Camera`), or None without one.

        With a ``k camera`` block the eye follows its translation and the view direction and up
        vector are the rotation's -z and +y axes (BART's GetCamera); parts the block lacks come from
        the ``v`` block.  The field of view is the ``v`` block's angle (45 degrees without one).
        """
        tb = self.bart_time(t)
        fov = float(self.view["angle"][0]) if self.view else 45.0
        if self.view is not None:
            eye = self.view["from"]
            fwd = self.view["at"] - self.view["from"]
            up = self.view["up"]
        elif self._cam_t < 0 and self._cam_r < 0:
            return None
        else:
            eye, fwd, up = np.zeros(3), np.array([0.0, 0.0, -1.0]), np.array([0.0, 1.0, 0.0])
        if self._cam_t >= 0:
            eye = self.spline_value("position", self._cam_t, tb)
        if self._cam_r >= 0:
            q = self.spline_value("rotation", self._cam_r, tb)
            m = np.empty((4, 4))
            trs_matrix(np.zeros(3), q, np.ones(3), m)
            fwd, up = -m[:3, 2], m[:3, 1]
        return Camera(eye=tuple(eye), target=tuple(np.asarray(eye) + fwd), up=tuple(up), fov=fov)
