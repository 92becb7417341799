"""numba kernels shared by the animated scene formats (glTF, BART, MD2, frame sequences).

Every kernel takes arrays, scalars and the records below (:data:`Channels`, :data:`Rig`,
:data:`Pose`: module-level namedtuples of arrays with fixed dtypes), writes into buffers it is
given and does no bounds checks: the loaders validate every index before the first call.

Conventions
-----------
* quaternions are ``(x, y, z, w)`` float64 (glTF order); rotation matrices act on column vectors;
* a node's local matrix is ``T * R * S`` (translation, rotation, scale);
* node world matrices are ``(N, 4, 4)`` float64, ``world[i] = world[parent[i]] @ local[i]``.

Keyframe sampling follows the glTF 2.0 specification, appendix C (LINEAR with spherical linear
interpolation for rotations, STEP, and CUBICSPLINE Hermite splines).  Linear-blend skinning is
``p' = sum_j w_j * (world[joint_j] @ inverseBind_j) @ p`` (Magnenat-Thalmann et al. 1988; glTF 2.0
section 3.7.3); morph targets add ``sum_k w_k * delta_k`` to the rest position before skinning.
"""

import math
from collections import namedtuple

import numpy as np
from numba import njit, prange

from ..compiles import inner

__all__ = [
    "KIND_T", "KIND_R", "KIND_S", "KIND_W",
    "INTERP_LINEAR", "INTERP_STEP", "INTERP_CUBIC",
    "Channels", "Rig", "Pose", "as_channels", "as_rig",
    "sample_channels", "compose_world", "skin_palette", "deform_vertices", "lerp_rows",
    "trs_matrix", "quat_matrix",
]

#: Animation channels as :func:`sample_channels` takes them (see there): times (K,) and values (L,)
#: float64; per channel c: tstart, tcount, vstart (C,) int64, ncomp, interp, kind, target (C,)
#: int32.
Channels = namedtuple("Channels", "times values tstart tcount vstart ncomp interp kind target")

#: Instances and skins as the deform kernels take them (see :func:`deform_vertices`): per instance
#: first (I+1,) int64, node (I,) int32, skinned (I,) bool, mbase (I,) int64, mcount (I,) int32,
#: woff (I,) int64; per vertex joints (V, J) int32 and jweights (V, J) float32; morph deltas (D, 3)
#: float32.
Rig = namedtuple("Rig", "first node skinned mbase mcount woff joints jweights deltas")

#: What poses a :data:`Rig` at one time: morph weights (W,) float64, world (N, 4, 4) float64 the
#: nodes' matrices (rigid vertices), palette (G, 4, 4) float64 the joints' (skinned vertices).
#: The normal kernels take the nodes' and joints' normal matrices in world and palette.
Pose = namedtuple("Pose", "weights world palette")


def as_channels(times, values, tstart, tcount, vstart, ncomp, interp, kind, target):
    """A :data:`Channels` record in its fixed dtypes (C-contiguous copies only where needed)."""
    f64, i64, i32 = np.float64, np.int64, np.int32
    c = np.ascontiguousarray
    return Channels(c(times, f64), c(values, f64), c(tstart, i64), c(tcount, i64), c(vstart, i64), c(ncomp, i32),
                    c(interp, i32), c(kind, i32), c(target, i32))


def as_rig(first, node, skinned, mbase, mcount, woff, joints, jweights, deltas):
    """A :data:`Rig` record in its fixed dtypes (C-contiguous copies only where needed)."""
    c = np.ascontiguousarray
    return Rig(c(first, np.int64), c(node, np.int32), c(skinned, np.bool_), c(mbase, np.int64), c(mcount, np.int32),
               c(woff, np.int64), c(joints, np.int32), c(jweights, np.float32), c(deltas, np.float32))

KIND_T, KIND_R, KIND_S, KIND_W = 0, 1, 2, 3
INTERP_LINEAR, INTERP_STEP, INTERP_CUBIC = 0, 1, 2


@inner(cache=True)
def _find_key(times, start, count, t):
    """Largest k in [0, count-2] with times[start + k] <= t (times sorted, t inside the range)."""
    lo = 0
    hi = count - 2
    while lo < hi:
        mid = (lo + hi + 1) // 2
        if times[start + mid] <= t:
            lo = mid
        else:
            hi = mid - 1
    return lo


@inner(cache=True)
def _store(kind, target, j, value, node_t, node_r, node_s, weights):
    if kind == KIND_T:
        node_t[target, j] = value
    elif kind == KIND_R:
        node_r[target, j] = value
    elif kind == KIND_S:
        node_s[target, j] = value
    else:
        weights[target + j] = value


@njit(cache=True)
def sample_channels(ch, t, node_t, node_r, node_s, weights):
    """Sample every animation channel of ``ch`` (:data:`Channels`) at clip time ``t`` and write the
    results.

    ch.times (K,) f64 concatenated key times; ch.values (L,) f64 concatenated outputs; per channel c:
    key times ``times[tstart[c] : tstart[c] + tcount[c]]``, outputs from ``vstart[c]``
    (``ncomp[c]`` components per key, three records per key in-tangent/value/out-tangent for
    CUBICSPLINE), interpolation ``interp[c]``, kind ``kind[c]`` (T, R, S or W) and target
    ``target[c]`` (node index, or offset into ``weights`` for W).  Writes node_t (N,3),
    node_r (N,4), node_s (N,3) or weights (W,), all f64.  Before the first key the first value
    holds, after the last key the last value.
    """
    times, values = ch.times, ch.values
    ch_tstart, ch_tcount, ch_vstart, ch_ncomp = ch.tstart, ch.tcount, ch.vstart, ch.ncomp
    ch_interp, ch_kind, ch_target = ch.interp, ch.kind, ch.target
    q = np.empty(4)
    for c in range(ch_tstart.shape[0]):
        ts = ch_tstart[c]
        n = ch_tcount[c]
        vs = ch_vstart[c]
        m = ch_ncomp[c]
        interp = ch_interp[c]
        kind = ch_kind[c]
        target = ch_target[c]
        cubic = interp == INTERP_CUBIC
        rec = 3 * m if cubic else m
        off = m if cubic else 0
        hold = -1
        k = 0
        if n == 1 or t <= times[ts]:
            hold = 0
        elif t >= times[ts + n - 1]:
            hold = n - 1
        else:
            k = _find_key(times, ts, n, t)
            if interp == INTERP_STEP:
                hold = k
        if hold >= 0:
            base = vs + hold * rec + off
            if kind == KIND_R:
                nrm = 0.0
                for j in range(4):
                    nrm += values[base + j] * values[base + j]
                nrm = math.sqrt(nrm) if nrm > 0.0 else 1.0
                for j in range(4):
                    node_r[target, j] = values[base + j] / nrm
            else:
                for j in range(m):
                    _store(kind, target, j, values[base + j], node_t, node_r, node_s, weights)
            continue
        t0 = times[ts + k]
        t1 = times[ts + k + 1]
        dt = t1 - t0
        s = (t - t0) / dt
        a = vs + k * rec + off
        b = vs + (k + 1) * rec + off
        if cubic:
            s2 = s * s
            s3 = s2 * s
            h00 = 2.0 * s3 - 3.0 * s2 + 1.0
            h10 = dt * (s3 - 2.0 * s2 + s)
            h01 = -2.0 * s3 + 3.0 * s2
            h11 = dt * (s3 - s2)
            for j in range(m):
                # out-tangent of key k is at a + m, in-tangent of key k+1 at b - m
                v = h00 * values[a + j] + h10 * values[a + m + j] + h01 * values[b + j] + h11 * values[b - m + j]
                if kind == KIND_R:
                    q[j] = v
                else:
                    _store(kind, target, j, v, node_t, node_r, node_s, weights)
        elif kind == KIND_R:
            dot = 0.0
            for j in range(4):
                dot += values[a + j] * values[b + j]
            sign = 1.0
            if dot < 0.0:
                sign = -1.0
                dot = -dot
            if dot > 0.9995:
                w0 = 1.0 - s
                w1 = s * sign
            else:
                theta = math.acos(min(dot, 1.0))
                sn = math.sin(theta)
                w0 = math.sin((1.0 - s) * theta) / sn
                w1 = sign * math.sin(s * theta) / sn
            for j in range(4):
                q[j] = w0 * values[a + j] + w1 * values[b + j]
        else:
            for j in range(m):
                _store(kind, target, j, (1.0 - s) * values[a + j] + s * values[b + j],
                       node_t, node_r, node_s, weights)
        if kind == KIND_R:
            nrm = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
            if nrm == 0.0:
                nrm = 1.0
            for j in range(4):
                node_r[target, j] = q[j] / nrm


@njit(cache=True)
def quat_matrix(x, y, z, w, out):
    """Write the 3x3 rotation of unit quaternion (x, y, z, w) into out[:3, :3]."""
    out[0, 0] = 1.0 - 2.0 * (y * y + z * z)
    out[0, 1] = 2.0 * (x * y - z * w)
    out[0, 2] = 2.0 * (x * z + y * w)
    out[1, 0] = 2.0 * (x * y + z * w)
    out[1, 1] = 1.0 - 2.0 * (x * x + z * z)
    out[1, 2] = 2.0 * (y * z - x * w)
    out[2, 0] = 2.0 * (x * z - y * w)
    out[2, 1] = 2.0 * (y * z + x * w)
    out[2, 2] = 1.0 - 2.0 * (x * x + y * y)


@njit(cache=True)
def trs_matrix(t, r, s, out):
    """out (4,4) f64 = T * R * S for translation t (3,), quaternion r (4,) xyzw, scale s (3,)."""
    quat_matrix(r[0], r[1], r[2], r[3], out)
    for i in range(3):
        for j in range(3):
            out[i, j] *= s[j]
        out[i, 3] = t[i]
        out[3, i] = 0.0
    out[3, 3] = 1.0


@inner(cache=True)
def _matmul4(a, b, out):
    for i in range(4):
        for j in range(4):
            acc = 0.0
            for k in range(4):
                acc += a[i, k] * b[k, j]
            out[i, j] = acc


@njit(cache=True)
def compose_world(order, parent, use_matrix, node_matrix, node_t, node_r, node_s, world):
    """World matrices of all nodes: world (N,4,4) f64.

    order (N,) int32 lists every node after its parent; parent (N,) int32 (-1 for roots);
    use_matrix (N,) bool selects node_matrix (N,4,4) f64 as the local matrix, else the local matrix
    is T*R*S from node_t (N,3), node_r (N,4) xyzw, node_s (N,3).
    """
    local = np.empty((4, 4))
    for ii in range(order.shape[0]):
        i = order[ii]
        if use_matrix[i]:
            for a in range(4):
                for b in range(4):
                    local[a, b] = node_matrix[i, a, b]
        else:
            trs_matrix(node_t[i], node_r[i], node_s[i], local)
        p = parent[i]
        if p < 0:
            for a in range(4):
                for b in range(4):
                    world[i, a, b] = local[a, b]
        else:
            _matmul4(world[p], local, world[i])


@njit(cache=True)
def skin_palette(world, joint_node, inverse_bind, out):
    """out[g] = world[joint_node[g]] @ inverse_bind[g]; (G,4,4) f64 arrays, joint_node (G,) int32."""
    for g in range(joint_node.shape[0]):
        _matmul4(world[joint_node[g]], inverse_bind[g], out[g])


#: Below this many items a kernel runs on the calling thread: waking the thread pool costs
#: tens of microseconds, more than posing a few thousand vertices.
SERIAL_BELOW = 16384


# The serial and parallel kernels share one per-vertex body.  It is compiled with _nrt=False:
# numba would otherwise reference-count each of its array arguments on every call, which made a
# per-vertex helper several times slower than writing the loop body out twice.


@inner(cache=True, _nrt=False)
def _deform_one(v, local, vinst, rig, pose, centre, origin, out):
    """Pose vertex v: morph targets, then linear-blend skinning or its node's world matrix; the
    rest position is local[v] + centre, the result is written as world - origin."""
    inst_first, inst_node, inst_skinned = rig.first, rig.node, rig.skinned
    inst_mbase, inst_mcount, inst_woff = rig.mbase, rig.mcount, rig.woff
    joints, jweights, deltas = rig.joints, rig.jweights, rig.deltas
    mweights, world, palette = pose.weights, pose.world, pose.palette
    i = vinst[v]
    x = np.float64(local[v, 0]) + centre[0]
    y = np.float64(local[v, 1]) + centre[1]
    z = np.float64(local[v, 2]) + centre[2]
    mc = inst_mcount[i]
    if mc > 0:
        nv = inst_first[i + 1] - inst_first[i]
        lv = v - inst_first[i]
        wo = inst_woff[i]
        mb = inst_mbase[i]
        for k in range(mc):
            mw = mweights[wo + k]
            if mw != 0.0:
                row = mb + k * nv + lv
                x += mw * deltas[row, 0]
                y += mw * deltas[row, 1]
                z += mw * deltas[row, 2]
    if inst_skinned[i]:
        ox = 0.0
        oy = 0.0
        oz = 0.0
        wsum = 0.0
        for j in range(joints.shape[1]):
            w = np.float64(jweights[v, j])
            if w != 0.0:
                g = joints[v, j]
                ox += w * (palette[g, 0, 0] * x + palette[g, 0, 1] * y + palette[g, 0, 2] * z + palette[g, 0, 3])
                oy += w * (palette[g, 1, 0] * x + palette[g, 1, 1] * y + palette[g, 1, 2] * z + palette[g, 1, 3])
                oz += w * (palette[g, 2, 0] * x + palette[g, 2, 1] * y + palette[g, 2, 2] * z + palette[g, 2, 3])
                wsum += w
        if wsum != 0.0:
            out[v, 0] = ox - origin[0]
            out[v, 1] = oy - origin[1]
            out[v, 2] = oz - origin[2]
            return
    n = inst_node[i]
    out[v, 0] = world[n, 0, 0] * x + world[n, 0, 1] * y + world[n, 0, 2] * z + (world[n, 0, 3] - origin[0])
    out[v, 1] = world[n, 1, 0] * x + world[n, 1, 1] * y + world[n, 1, 2] * z + (world[n, 1, 3] - origin[1])
    out[v, 2] = world[n, 2, 0] * x + world[n, 2, 1] * y + world[n, 2, 2] * z + (world[n, 2, 3] - origin[2])


@njit(cache=True, parallel=True)
def _deform_parallel(vids, local, vinst, rig, pose, centre, origin, out):
    """:func:`_deform_one` over vids, in parallel."""
    for ii in prange(vids.shape[0]):
        _deform_one(vids[ii], local, vinst, rig, pose, centre, origin, out)


@njit(cache=True)
def _deform_serial(vids, local, vinst, rig, pose, centre, origin, out):
    """:func:`_deform_one` over vids on the calling thread (small scenes)."""
    for ii in range(vids.shape[0]):
        _deform_one(vids[ii], local, vinst, rig, pose, centre, origin, out)


def deform_vertices(vids, local, vinst, rig, pose, centre, origin, out):
    """Pose the vertices listed in ``vids``: morph, then skin or transform rigidly.

    vids (n,) int64 vertex ids; local (V,3) f32 rest positions; vinst (V,) int32 instance of each
    vertex; ``rig`` (:data:`Rig`) per instance i: vertices ``first[i] : first[i+1]``, node
    node[i], skinned[i], morph deltas rows ``mbase[i] + k * n_i + local_index`` for k < mcount[i]
    (n_i = vertex count of the instance) weighted by ``pose.weights[woff[i] + k]``.  Skinned
    vertices blend ``pose.palette[joints[v, j]]`` with jweights[v, j]; a skinned vertex whose weights
    are all zero, and every rigid vertex, uses pose.world[node[i]] (``pose``: :data:`Pose`).  The
    rest position of v is ``local[v] + centre`` (centre (3,) f64: float32 storage relative to it);
    writes ``world - origin`` (origin (3,) f64) into out (V,3) f32.
    The callers validate every index; this wrapper only picks the serial or parallel kernel.
    """
    kernel = _deform_serial if vids.shape[0] < SERIAL_BELOW else _deform_parallel
    kernel(vids, local, vinst, rig, pose, centre, origin, out)


@njit(cache=True, parallel=True)
def _lerp_parallel(a, b, s, shift, out):
    r = 1.0 - s
    for v in prange(a.shape[0]):
        for c in range(3):
            out[v, c] = (r * np.float64(a[v, c]) + s * np.float64(b[v, c])) + shift[c]


@njit(cache=True)
def _lerp_serial(a, b, s, shift, out):
    r = 1.0 - s
    for v in range(a.shape[0]):
        for c in range(3):
            out[v, c] = (r * np.float64(a[v, c]) + s * np.float64(b[v, c])) + shift[c]


_NO_SHIFT = np.zeros(3)


def lerp_rows(a, b, s, out, shift=None):
    """out = (1 - s) * a + s * b + shift row by row, computed in float64; a, b, out (V,3) f32,
    s float, shift (3,) float64 (default 0).

    s = 0 gives a and s = 1 gives b bit for bit (with no shift).
    """
    shift = _NO_SHIFT if shift is None else np.ascontiguousarray(shift, np.float64)
    (_lerp_serial if a.shape[0] < SERIAL_BELOW else _lerp_parallel)(a, b, float(s), shift, out)
