"""Animated glTF 2.0 scenes (.gltf and .glb): node TRS animation, skinning and morph targets.

The file is read directly (JSON, GLB chunks, buffers, accessors including sparse and normalized
integer accessors); Draco-compressed primitives (``KHR_draco_mesh_compression``) are decoded with
DracoPy when it is installed.  Every scene node that holds a mesh contributes one instance per
triangle primitive (modes TRIANGLES, TRIANGLE_STRIP, TRIANGLE_FAN; points and lines are skipped);
triangles are ordered by node (depth-first from the scene roots) then primitive.

Per frame (:meth:`GltfAnimation.triangles_at`):

1. the clip's channels are sampled at clip time (LINEAR with slerp for rotations, STEP,
   CUBICSPLINE; glTF 2.0 appendix C) into node translation/rotation/scale and morph weights;
2. node world matrices are composed down the hierarchy;
3. each skin's joint matrices ``world[joint] @ inverseBindMatrix`` are formed;
4. vertices are morphed (``p + sum_k w_k d_k``) then skinned by linear blending of up to
   4 * (number of JOINTS_n sets) joints, or moved rigidly by their node's world matrix.  As the
   specification requires, a skinned mesh ignores its own node's transform.  Each vertex's joint
   weights are divided by their sum (as three.js does: exporters that keep 4 influences leave sums
   below 1, e.g. 210 vertices of CesiumMan); a vertex whose weights are all zero moves rigidly
   with its node.

Only vertices of instances that can move are recomputed; the others are posed once.  See
:attr:`GltfAnimation.static_mask`.

Looks (:attr:`GltfAnimation.surface`, a :class:`gridrt.scene.surface.Surface`, and
:meth:`GltfAnimation.lights_at`):

* each triangle's material is its primitive's glTF material (glTF's default material, base colour
  (1, 1, 1), without one): diffuse = the RGB of ``pbrMetallicRoughness.baseColorFactor`` (its alpha,
  ``alphaMode``, metallic/roughness, emissive, occlusion and normal maps are ignored; a material that
  has only ``KHR_materials_pbrSpecularGlossiness`` gives its diffuseFactor/diffuseTexture),
  ambient = :data:`AMBIENT_FRACTION` * diffuse;
* ``baseColorTexture``: the image (PNG or JPEG, embedded in a buffer view or a data: URI, or a file
  named relative to the .gltf, inside its folder: :mod:`gridrt.scene.files`) read with Pillow,
  wrapped as its sampler's wrapS/wrapT say, on the
  primitive's ``TEXCOORD_<texCoord>`` (glTF's uv are stored as they are: both use the image's
  top-left origin).  An image that cannot be read, and a texCoord set the primitive lacks, warn
  (:class:`gridrt.scene.surface.TextureWarning`) and the triangles are drawn without the texture.
  ``KHR_texture_transform`` is ignored (with a warning);
* ``COLOR_0`` (float or normalized unsigned byte/short, VEC3 or VEC4; alpha ignored) gives the
  per-corner colours (ones for primitives without it);
* ``NORMAL`` gives the shading normals.  At time t they move with the vertices: morph targets add
  their NORMAL deltas with the POSITION weights, then a rigid vertex's normal is multiplied by the
  inverse transpose of its node's linear part, and a skinned vertex's by the blend of its joints'
  ``n' = sum_j w_j * L_j^-T n`` (L_j the linear part of ``world[joint_j] @ inverseBind_j``; exact for
  one joint and under non-uniform scale, where the common ``sum_j w_j L_j n`` is not); then the
  normal is normalized.  Primitives without NORMAL get zero normals (the geometric normal).  As the
  positions, only the normals of vertices that can move are recomputed per frame;
* colours are display values: no sRGB decoding of textures or factors (as the rest of gridrt);
* ``KHR_lights_punctual`` lights on the scene's nodes: point lights at their node's origin with
  inverse-square falloff, directional lights shining along their node's -Z axis (so the stored
  vector towards the light is the node's +Z axis in world space) without falloff; both with
  colour * intensity.  Spot lights are drawn as point lights (with a warning) and ``range`` is
  ignored.  Lights follow their (animated) nodes.

:attr:`GltfAnimation.surface` is None when the scene's primitives have no material, NORMAL or
COLOR_0 (such files look as they did before gridrt read looks).
"""

import base64
import binascii
import dataclasses
import importlib.util
import json
import math
import os
import struct
import warnings
from numbers import Integral, Real
from pathlib import Path
from typing import NamedTuple

import numpy as np
from numba import njit, prange

from ..arrays import TRI_DTYPE, as_mesh, as_origin
from ..camera import Camera
from ..commands import pip_command
from ..errors import InputError, SceneFileError
from .animation import Animation, as_static_mask, check_time, gather_unchecked, pose_moving_vertices
from .files import NotRegularFile, OutsideReference, SceneFolder, open_regular, os_problem, read_scene_file
from .kernels import (INTERP_CUBIC, INTERP_LINEAR, INTERP_STEP, KIND_R, KIND_S, KIND_T, KIND_W, SERIAL_BELOW, Pose,
                      as_channels, as_rig, compose_world, deform_vertices, sample_channels, skin_palette)
from .mesh import Mesh
from .surface import (FALLOFF_INVERSE_SQUARE, FALLOFF_NONE, LIGHT_COLUMNS, LIGHT_DIRECTIONAL, LIGHT_POINT,
                      SurfaceBuilder, Texture, TextureWarning, as_lights, load_texture, no_lights)

__all__ = ["GltfAnimation", "DRACO_HINT", "AMBIENT_FRACTION"]

#: How to get Draco support, quoted in error messages: a command that installs DracoPy into the
#: environment gridrt runs in, as it can be pasted (gridrt.commands)
DRACO_HINT = f"install DracoPy to read it: {pip_command()} install DracoPy"

_GLB_MAGIC = b"glTF"
_CHUNK_JSON = 0x4E4F534A
_CHUNK_BIN = 0x004E4942

# componentType -> (little-endian dtype, normalization divisor)
_COMPONENTS = {
    5120: ("<i1", 127.0),
    5121: ("<u1", 255.0),
    5122: ("<i2", 32767.0),
    5123: ("<u2", 65535.0),
    5125: ("<u4", None),
    5126: ("<f4", None),
}
_NCOMP = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}
_PATHS = {"translation": (KIND_T, 3), "rotation": (KIND_R, 4), "scale": (KIND_S, 3), "weights": (KIND_W, 1)}
_INTERP = {"LINEAR": INTERP_LINEAR, "STEP": INTERP_STEP, "CUBICSPLINE": INTERP_CUBIC}
_GEOMETRY_EXTENSIONS_UNSUPPORTED = ("EXT_meshopt_compression", "KHR_meshopt_compression", "EXT_mesh_gpu_instancing")
_MAX_JOINT_SETS = 4
# sampler wrapS / wrapT -> gridrt.scene.surface.WRAP_MODES key
_WRAP = {10497: "repeat", 33071: "clamp", 33648: "mirror"}

#: AMBIENT_FRACTION: a glTF material's ambient colour as a fraction of its base colour.  glTF has no
#: ambient term (its viewers light scenes with an environment); this much keeps the sides the lights
#: miss readable without washing out the lit ones.
from .surface import AMBIENT_FRACTION  # noqa: E402


def _is_int(v):
    return isinstance(v, (Integral, np.integer)) and not isinstance(v, (bool, np.bool_))


_GLTF2_ONLY = "gridrt reads glTF 2.x only"
_GLTF1_HINT = "gridrt reads glTF 2.x only (convert it first, e.g. with gltf-pipeline)"
# top-level collections: lists in glTF 2.0, objects keyed by id in glTF 1.0
_COLLECTIONS = ("accessors", "animations", "bufferViews", "buffers", "cameras", "images", "materials", "meshes",
                "nodes", "samplers", "scenes", "skins", "textures")


def gltf_version_problem(tree):
    """Why the glTF JSON ``tree`` (a dict) is refused as not glTF 2.x, or None.

    ``asset.version`` may be a string (as glTF 2.0 requires) or a number (written by some glTF 1.0
    exporters); without a version, a glTF 1.0 layout (collections that are objects keyed by id, a
    ``scene`` given by name) is recognized as glTF 1.0 too."""
    asset = tree.get("asset")
    version = asset.get("version") if isinstance(asset, dict) else None
    if isinstance(version, Real) and not isinstance(version, (bool, np.bool_)):
        major = str(math.floor(version)) if math.isfinite(version) else None
    elif isinstance(version, str):
        major = version.strip().split(".")[0]
    else:
        major = "2"  # no version: judged by the layout below
        keyed = [k for k in _COLLECTIONS if isinstance(tree.get(k), dict)]
        if keyed or isinstance(tree.get("scene"), str):
            what = f"'{keyed[0]}' is an object keyed by id" if keyed else "'scene' is a name"
            return f"glTF 1.0 is not supported (the file has no asset.version and {what}, as in glTF 1.0); " \
                   + _GLTF1_HINT
    if major == "1":
        return f"glTF 1.0 is not supported (asset.version is {version!r}); " + _GLTF1_HINT
    if major != "2":
        return f"glTF version {version!r} is not supported; " + _GLTF2_ONLY
    return None


def glb_version_problem(version):
    """Why a .glb container of header version ``version`` is refused, or None (version 2)."""
    if version == 1:
        return "glTF 1.0 is not supported (binary glTF 1.0: .glb container version 1); " + _GLTF1_HINT
    if version != 2:
        return f"malformed .glb file: container version {version}, expected 2"
    return None


class _Reader:
    """The JSON tree, buffers and decoded accessors of one glTF file; every failure names the file."""

    def __init__(self, path, folder):
        self.path = Path(path)
        self.folder = folder  # the SceneFolder its buffers and images must lie in
        self._bin = None
        self._buffers = {}
        self._accessors = {}
        self.tree = self._read_tree()
        if not isinstance(self.tree, dict):
            self.fail("malformed glTF: the top-level JSON value is not an object")
        problem = gltf_version_problem(self.tree)
        if problem:
            self.fail(problem)
        required = self.tree.get("extensionsRequired") or []
        if not isinstance(required, list):
            self.fail("malformed glTF: extensionsRequired is not a list")
        for ext in required:
            if ext in _GEOMETRY_EXTENSIONS_UNSUPPORTED:
                self.fail(f"geometry uses {ext}, which gridrt cannot decode")
            if ext == "KHR_draco_mesh_compression" and importlib.util.find_spec("DracoPy") is None:
                self.fail(f"geometry is Draco-compressed (KHR_draco_mesh_compression); {DRACO_HINT}")

    def fail(self, problem):
        raise SceneFileError(self.path, problem)

    # ---------------------------------------------------------------- file containers

    def _read_tree(self):
        raw = read_scene_file(self.path)
        if not raw:
            self.fail("file is empty (0 bytes)")
        if raw[:4] == _GLB_MAGIC:
            return self._read_glb(raw)
        if self.path.suffix.lower() == ".glb":
            self.fail("malformed .glb file: missing the 'glTF' binary header")
        try:
            return json.loads(raw.decode("utf-8"))
        except (UnicodeDecodeError, json.JSONDecodeError, RecursionError) as e:
            self.fail(f"malformed .gltf file: not valid JSON ({e})")

    def _read_glb(self, raw):
        if len(raw) < 20:
            self.fail(f"malformed .glb file: truncated header ({len(raw)} bytes)")
        _, version, length = struct.unpack_from("<4sII", raw, 0)
        if glb_version_problem(version):
            self.fail(glb_version_problem(version))
        if length > len(raw):
            self.fail(f"truncated .glb file: the header says {length} bytes, the file has {len(raw)}")
        pos = 12
        tree = None
        while pos + 8 <= length:
            clen, ctype = struct.unpack_from("<II", raw, pos)
            pos += 8
            if pos + clen > length:
                self.fail(f"truncated .glb file: a chunk of {clen} bytes at byte {pos} runs past the end")
            data = raw[pos:pos + clen]
            if tree is None:
                if ctype != _CHUNK_JSON:
                    self.fail("malformed .glb file: the first chunk is not JSON")
                try:
                    tree = json.loads(data.decode("utf-8"))
                except (UnicodeDecodeError, json.JSONDecodeError, RecursionError) as e:
                    self.fail(f"malformed .glb file: JSON chunk is not valid JSON ({e})")
            elif ctype == _CHUNK_BIN and self._bin is None:
                self._bin = data
            pos += clen + (-clen % 4)
        if tree is None:
            self.fail("malformed .glb file: no JSON chunk")
        return tree

    # ---------------------------------------------------------------- JSON access

    def items(self, key):
        v = self.tree.get(key, [])
        if not isinstance(v, list):
            self.fail(f"malformed glTF: '{key}' is not a list")
        return v

    def item(self, key, index, what):
        arr = self.items(key)
        if not _is_int(index) or not 0 <= index < len(arr):
            self.fail(f"{what} refers to {key}[{index!r}], but the file has {len(arr)} {key}")
        v = arr[index]
        if not isinstance(v, dict):
            self.fail(f"malformed glTF: {key}[{index}] is not an object")
        return v

    def uint(self, obj, key, what, default=None, lo=0):
        v = obj.get(key, default)
        if v is None:
            self.fail(f"{what}: required property '{key}' is missing")
        if not _is_int(v) or v < lo:
            self.fail(f"{what}: '{key}' must be an integer >= {lo}, got {v!r}")
        return int(v)

    def floats(self, obj, key, n, default, what):
        v = obj.get(key)
        if v is None:
            return np.array(default, dtype=np.float64)
        if not isinstance(v, list) or len(v) != n or not all(
            isinstance(x, (Real, np.floating, np.integer)) and not isinstance(x, bool) for x in v
        ):
            self.fail(f"{what}: '{key}' must be a list of {n} numbers")
        a = np.array(v, dtype=np.float64)
        if not np.isfinite(a).all():
            self.fail(f"{what}: '{key}' contains NaN or infinity")
        return a

    # ---------------------------------------------------------------- binary data

    def buffer(self, index, what):
        if index in self._buffers:
            return self._buffers[index]
        b = self.item("buffers", index, what)
        length = self.uint(b, "byteLength", f"buffer {index}")
        uri = b.get("uri")
        if uri is None:
            if self._bin is None:
                self.fail(f"buffer {index} has no uri and the file has no GLB binary chunk")
            data = self._bin
        elif not isinstance(uri, str):
            self.fail(f"buffer {index}: uri is not a string")
        elif uri.startswith("data:"):
            head, _, payload = uri.partition(",")
            if not head.endswith(";base64"):
                self.fail(f"buffer {index}: only base64 data URIs are supported")
            try:
                data = base64.b64decode(payload, validate=True)
            except (binascii.Error, ValueError) as e:
                self.fail(f"buffer {index}: data URI is not valid base64 ({e})")
        else:
            p = self.folder.uri(self.path.parent, f"buffer {index}", uri, self.path)
            try:
                with open_regular(p) as (fh, size):
                    if size < length:
                        self.fail(f"buffer {index} is truncated: {p} has {size} bytes, byteLength says {length}")
                    data = fh.read(length)  # (no more than the scene declares)
            except FileNotFoundError:
                self.fail(f"buffer {index} refers to a missing file: {p}")
            except OSError as e:
                self.fail(f"buffer {index}: {p} {os_problem(e)}" if isinstance(e, NotRegularFile)
                          else f"buffer {index}: cannot read {p} ({e.strerror or e})")
        if len(data) < length:
            self.fail(f"buffer {index} is truncated: {len(data)} bytes, byteLength says {length}")
        self._buffers[index] = data
        return data

    def view(self, index, what):
        """(memoryview of the buffer view's bytes, byteStride or 0)."""
        bv = self.item("bufferViews", index, what)
        w = f"bufferView {index}"
        buf = self.buffer(self.uint(bv, "buffer", w), w)
        off = self.uint(bv, "byteOffset", w, default=0)
        length = self.uint(bv, "byteLength", w, lo=1)
        stride = self.uint(bv, "byteStride", w, default=0)
        if off + length > len(buf):
            self.fail(f"{w} (bytes {off}..{off + length}) runs past the end of its {len(buf)}-byte buffer")
        return memoryview(buf)[off:off + length], stride

    def accessor(self, index, what):
        """Decoded accessor: (count, ncomp) array, float64 for float/normalized data, else int64."""
        key = index
        if _is_int(key) and key in self._accessors:
            return self._accessors[key]
        acc = self.item("accessors", index, what)
        w = f"accessor {index} ({what})"
        ct = acc.get("componentType")
        if ct not in _COMPONENTS:
            self.fail(f"{w}: unknown componentType {ct!r}")
        typ = acc.get("type")
        if typ not in _NCOMP:
            self.fail(f"{w}: unknown type {typ!r}")
        count = self.uint(acc, "count", w, lo=0)
        dtype = np.dtype(_COMPONENTS[ct][0])
        n = _NCOMP[typ]
        if (typ == "MAT2" and dtype.itemsize == 1) or (typ == "MAT3" and dtype.itemsize < 4):
            self.fail(f"{w}: padded {typ} matrices of {dtype.itemsize}-byte components are not supported")
        elem = n * dtype.itemsize
        if "bufferView" in acc:
            data, stride = self.view(acc["bufferView"], w)
            stride = stride or elem
            if stride < elem:
                self.fail(f"{w}: byteStride {stride} is smaller than one element ({elem} bytes)")
            off = self.uint(acc, "byteOffset", w, default=0)
            need = off + stride * (count - 1) + elem if count else off
            if need > len(data):
                self.fail(f"{w}: {count} elements need {need} bytes but its buffer view has {len(data)}")
            if count:
                out = np.ndarray((count, n), dtype=dtype, buffer=data, offset=off, strides=(stride, dtype.itemsize))
                out = out.copy()
            else:
                out = np.zeros((0, n), dtype=dtype)
        else:
            if count * elem > 1 << 28:
                self.fail(f"{w}: {count} elements ({count * elem} bytes) is too large for an accessor without data")
            out = np.zeros((count, n), dtype=dtype)
        sparse = acc.get("sparse")
        if sparse is not None:
            out = self._apply_sparse(out, sparse, w, dtype, n)
        norm = _COMPONENTS[ct][1]
        if acc.get("normalized") and norm is not None:
            res = np.maximum(out.astype(np.float64) / norm, -1.0)
        elif dtype.kind == "f":
            with np.errstate(invalid="ignore"):  # signalling NaN payloads; rejected just below
                res = out.astype(np.float64)
            if not np.isfinite(res).all():
                self.fail(f"{w} contains NaN or infinity")
        else:
            res = out.astype(np.int64)
        res.setflags(write=False)
        self._accessors[key] = res
        return res

    def _apply_sparse(self, out, sparse, w, dtype, n):
        if not isinstance(sparse, dict):
            self.fail(f"{w}: sparse is not an object")
        sc = self.uint(sparse, "count", f"{w} sparse", lo=1)
        idx, val = sparse.get("indices"), sparse.get("values")
        if not isinstance(idx, dict) or not isinstance(val, dict):
            self.fail(f"{w}: sparse needs 'indices' and 'values' objects")
        ict = idx.get("componentType")
        if ict not in (5121, 5123, 5125):
            self.fail(f"{w}: sparse indices have an invalid componentType {ict!r}")
        idt = np.dtype(_COMPONENTS[ict][0])
        ii = self._raw(idx, sc, idt, 1, f"{w} sparse indices")[:, 0].astype(np.int64)
        vv = self._raw(val, sc, dtype, n, f"{w} sparse values")
        if len(ii) and (ii.max() >= len(out)):
            self.fail(f"{w}: sparse index {int(ii.max())} out of range for {len(out)} elements")
        out = out.copy()
        out[ii] = vv
        return out

    def _raw(self, obj, count, dtype, n, w):
        data, _ = self.view(obj.get("bufferView"), w)
        off = self.uint(obj, "byteOffset", w, default=0)
        need = off + count * n * dtype.itemsize
        if need > len(data):
            self.fail(f"{w}: needs {need} bytes but its buffer view has {len(data)}")
        return np.frombuffer(data, dtype=dtype, count=count * n, offset=off).reshape(count, n)


# ------------------------------------------------------------------------------ materials and textures


class _Material(NamedTuple):
    """What gridrt draws of one glTF material."""

    diffuse: tuple  # (r, g, b) base colour factor
    ambient: tuple  # AMBIENT_FRACTION * diffuse
    texture: object  # the base colour Texture, or None (none, or unreadable)
    texcoord: int  # the TEXCOORD_n set the texture is read with (0 without a texture)


_DEFAULT_MATERIAL = _Material((1.0, 1.0, 1.0), (AMBIENT_FRACTION,) * 3, None, 0)


class _Looks:
    """The file's materials and their base colour textures, each read once on first use (only the
    materials of the primitives that are drawn, so unused images are never decoded)."""

    def __init__(self, r):
        self.r = r
        self._materials = {}
        self._images = {}  # image index -> Texture with repeat wrap, or None (unreadable)
        self._textures = {}  # (image index, wrap) -> Texture
        self._warned = set()

    def warn_once(self, key, message, category=UserWarning):
        if key not in self._warned:
            self._warned.add(key)
            warnings.warn(f"{self.r.path}: {message}", category, stacklevel=5)

    def material(self, index, what):
        """The :class:`_Material` of ``materials[index]`` (``what`` names the referrer); checks it."""
        if index is None:
            return _DEFAULT_MATERIAL
        if _is_int(index) and index in self._materials:
            return self._materials[index]
        r = self.r
        mat = r.item("materials", index, what)
        w = f"material {index}"
        pbr, factor, tex_key = mat.get("pbrMetallicRoughness", {}), "baseColorFactor", "baseColorTexture"
        exts = mat.get("extensions")
        sg = exts.get("KHR_materials_pbrSpecularGlossiness") if isinstance(exts, dict) else None
        if "pbrMetallicRoughness" not in mat and isinstance(sg, dict):
            pbr, factor, tex_key = sg, "diffuseFactor", "diffuseTexture"
        if not isinstance(pbr, dict):
            r.fail(f"{w}: pbrMetallicRoughness is not an object")
        rgba = r.floats(pbr, factor, 4, (1.0, 1.0, 1.0, 1.0), w)
        if (rgba < 0).any():
            r.fail(f"{w}: '{factor}' has a negative component {rgba.tolist()}")
        diffuse = tuple(float(c) for c in rgba[:3])  # alpha (and alphaMode) ignored: drawn opaque
        texture, texcoord = None, 0
        info = pbr.get(tex_key)
        if info is not None:
            wt = f"{w} {tex_key}"
            if not isinstance(info, dict):
                r.fail(f"{wt} is not an object")
            ti = r.uint(info, "index", wt)
            texcoord = r.uint(info, "texCoord", wt, default=0)
            texture = self.texture(ti, wt)
            iext = info.get("extensions")
            if isinstance(iext, dict) and "KHR_texture_transform" in iext:
                self.warn_once("KHR_texture_transform", "KHR_texture_transform (texture offset, rotation and "
                               "scale) is not supported: textures are drawn with the file's uv as they are")
        m = _Material(diffuse, tuple(AMBIENT_FRACTION * c for c in diffuse), texture, texcoord)
        self._materials[index] = m
        return m

    def texture(self, index, what):
        """The Texture of ``textures[index]`` (its image with its sampler's wrap modes), or None with a
        TextureWarning when its image cannot be had."""
        r = self.r
        tex = r.item("textures", index, what)
        w = f"texture {index}"
        wrap = ("repeat", "repeat")
        if tex.get("sampler") is not None:
            smp = r.item("samplers", tex.get("sampler"), w)
            modes = []
            for key in ("wrapS", "wrapT"):
                mode = smp.get(key, 10497)
                if not _is_int(mode) or mode not in _WRAP:
                    r.fail(f"sampler {tex.get('sampler')}: unknown {key} {mode!r} (glTF knows 10497 REPEAT, "
                           "33071 CLAMP_TO_EDGE, 33648 MIRRORED_REPEAT)")
                modes.append(_WRAP[mode])
            wrap = tuple(modes)
        source = tex.get("source")
        if source is None:
            exts = sorted(tex.get("extensions") or {}) if isinstance(tex.get("extensions"), dict) else []
            how = f" (only through {', '.join(exts)})" if exts else ""
            warnings.warn(f"{r.path}: {w} has no PNG or JPEG image{how}; drawn without it", TextureWarning,
                          stacklevel=4)
            return None
        r.item("images", source, w)
        base = self.image(source)
        if base is None:
            return None
        if wrap == base.wrap:
            return base
        key = (source, wrap)
        if key not in self._textures:
            self._textures[key] = Texture(base.texels, wrap, f"{base.name} (wrap {wrap[0]}/{wrap[1]})")
        return self._textures[key]

    def image(self, index):
        """``images[index]`` read (once) into a Texture with repeat wrap, or None (TextureWarning)."""
        if index in self._images:
            return self._images[index]
        r = self.r
        im = r.item("images", index, "a texture")
        w = f"image {index}"
        label = f"{r.path} image {index}"
        if isinstance(im.get("name"), str) and im["name"]:
            label += f" ({im['name']})"
        uri = im.get("uri")
        tex = None
        if im.get("bufferView") is not None:
            data, _ = r.view(im["bufferView"], w)
            tex = load_texture(None, data=bytes(data), name=label)
        elif isinstance(uri, str) and uri.startswith("data:"):
            head, _, payload = uri.partition(",")
            try:
                if not head.endswith(";base64"):
                    raise ValueError("not a base64 data URI")
                data = base64.b64decode(payload, validate=True)
            except (binascii.Error, ValueError) as e:
                warnings.warn(f"texture {label}: its data URI cannot be read ({e}); drawn without it",
                              TextureWarning, stacklevel=4)
            else:
                tex = load_texture(None, data=data, name=label)
        elif isinstance(uri, str) and uri:
            try:
                path = r.folder.uri(r.path.parent, "its uri", uri, r.path)
            except OutsideReference as e:
                warnings.warn(f"texture {label}: {e.problem}; drawn without it", TextureWarning, stacklevel=4)
            else:
                tex = load_texture(path, name=str(path))
        else:
            warnings.warn(f"texture {label}: the image has neither a uri nor a bufferView; drawn without it",
                          TextureWarning, stacklevel=4)
        self._images[index] = tex
        return tex


# ------------------------------------------------------------------------------ geometry


def _triangles_from_indices(idx, mode, what, fail, indexed=True):
    """(F,3) int64 triangles from a primitive's index list for modes 4 (list), 5 (strip), 6 (fan);
    ``indexed=False``: ``idx`` is 0..n-1 for a primitive without indices (its vertices in order)."""
    n = len(idx)
    if mode == 4:
        if n % 3:
            if indexed:
                fail(f"{what}: {n} indices is not a multiple of 3 for TRIANGLES")
            fail(f"{what}: {n} vertices is not a multiple of 3 for TRIANGLES (the primitive is not indexed: "
                 f"every 3 vertices in order make a triangle)")
        return idx.reshape(-1, 3)
    if n < 3:
        return np.zeros((0, 3), dtype=np.int64)
    i = np.arange(n - 2)
    if mode == 5:  # glTF 2.0 section 3.7.2.1: p_i = {v_i, v_(i+1+i%2), v_(i+2-i%2)}
        return np.stack([idx[i], idx[i + 1 + i % 2], idx[i + 2 - i % 2]], axis=1)
    return np.stack([idx[i + 1], idx[i + 2], np.full(n - 2, idx[0])], axis=1)


class _Primitive:
    """Decoded geometry of one mesh primitive (shared by every node that instances the mesh)."""

    __slots__ = ("positions", "faces", "joints", "weights", "targets", "material", "looks", "normals", "ntargets",
                 "uv", "colors")

    def __init__(self, positions, faces, joints, weights, targets):
        self.positions = positions  # (n,3) f64
        self.faces = faces  # (f,3) int64 local
        self.joints = joints  # (n,J) int64 or None
        self.weights = weights  # (n,J) f64 or None
        self.targets = targets  # (k,n,3) f64 (k may be 0)
        self.material = None  # the glTF material index, or None
        self.looks = _DEFAULT_MATERIAL  # its _Material (texture None when the primitive has no uv for it)
        self.normals = None  # (n,3) f32 unit NORMAL (zero rows where the file's are zero), or None
        self.ntargets = None  # (k,n,3) f32 morph targets' NORMAL deltas, or None when no target has them
        self.uv = None  # (n,2) f32 the texture's TEXCOORD set (only with a texture), or None
        self.colors = None  # (n,3) f32 COLOR_0 RGB, or None


def _decode_draco(r, prim, ext, what):
    try:
        import DracoPy  # deferred: the optional DracoPy, needed only for Draco-compressed glTF
    except ImportError:
        r.fail(f"{what} is Draco-compressed (KHR_draco_mesh_compression); {DRACO_HINT}")
    if not isinstance(ext, dict):
        r.fail(f"{what}: malformed KHR_draco_mesh_compression extension")
    data, _ = r.view(ext.get("bufferView"), f"{what} Draco data")
    try:
        dm = DracoPy.decode(bytes(data))
    except Exception as e:  # DracoPy raises its own error types for corrupt data
        r.fail(f"{what}: Draco data cannot be decoded ({type(e).__name__}: {e})")
    attrs = ext.get("attributes") or {}
    if not isinstance(attrs, dict):
        r.fail(f"{what}: Draco 'attributes' is not an object")

    def attribute(name):
        uid = attrs.get(name)
        if uid is None:
            return None
        a = dm.get_attribute_by_unique_id(uid) if _is_int(uid) else None
        if a is None:
            r.fail(f"{what}: Draco data has no attribute with id {uid!r} ({name})")
        arr = np.asarray(a["data"])
        if arr.ndim == 1:
            arr = arr[:, None]
        acc_i = prim["attributes"].get(name)
        if acc_i is not None:  # the accessor says how integers are to be read
            acc = r.item("accessors", acc_i, f"{what} {name}")
            norm = _COMPONENTS.get(acc.get("componentType"), (None, None))[1]
            if acc.get("normalized") and norm is not None and arr.dtype.kind in "iu":
                return np.maximum(arr.astype(np.float64) / norm, -1.0)
        return arr.astype(np.float64) if arr.dtype.kind == "f" else arr.astype(np.int64)

    pos = attribute("POSITION")
    if pos is None:
        pos = np.asarray(dm.points, dtype=np.float64).reshape(-1, 3)
    faces = np.asarray(dm.faces, dtype=np.int64).reshape(-1, 3)
    return pos, faces, attribute


def _load_primitive(r, mesh_index, prim_index, prim, looks=None):
    what = f"mesh {mesh_index} primitive {prim_index}"
    if not isinstance(prim, dict):
        r.fail(f"malformed glTF: {what} is not an object")
    attrs = prim.get("attributes")
    if not isinstance(attrs, dict) or "POSITION" not in attrs:
        r.fail(f"{what} has no POSITION attribute")
    mode = prim.get("mode", 4)
    if mode not in (0, 1, 2, 3, 4, 5, 6):
        r.fail(f"{what}: unknown primitive mode {mode!r}")
    if mode < 4:
        return None
    ext = (prim.get("extensions") or {}).get("KHR_draco_mesh_compression") if isinstance(
        prim.get("extensions"), dict) else None
    draco_attr = None
    if ext is not None:
        pos, faces, draco_attr = _decode_draco(r, prim, ext, what)
        if mode != 4:
            faces = _triangles_from_indices(faces.reshape(-1), mode, what, r.fail)
    else:
        pos = r.accessor(attrs["POSITION"], f"{what} POSITION")
        if "indices" in prim:
            idx = r.accessor(prim["indices"], f"{what} indices")
            if idx.dtype.kind == "f" or idx.shape[1] != 1:
                r.fail(f"{what}: indices must be an integer SCALAR accessor")
            idx = idx[:, 0]
        else:
            idx = np.arange(len(pos), dtype=np.int64)
        faces = _triangles_from_indices(idx, mode, what, r.fail, indexed="indices" in prim)
    if pos.ndim != 2 or pos.shape[1] != 3:
        r.fail(f"{what}: POSITION must be VEC3, got {pos.shape[1]} components")
    pos = np.asarray(pos, dtype=np.float64)
    if not np.isfinite(pos).all():
        r.fail(f"{what}: POSITION contains NaN or infinity")
    nv = len(pos)
    if len(faces) and (faces.min() < 0 or faces.max() >= nv):
        r.fail(f"{what}: vertex index {int(faces.max())} out of range for {nv} vertices")

    joints, weights = [], []
    for s in range(_MAX_JOINT_SETS):
        jn, wn = f"JOINTS_{s}", f"WEIGHTS_{s}"
        if jn not in attrs and wn not in attrs:
            break
        if (jn in attrs) != (wn in attrs):
            r.fail(f"{what}: {jn} and {wn} must come together")
        if draco_attr is not None and draco_attr(jn) is not None:
            j, w = draco_attr(jn), draco_attr(wn)
        else:
            j = r.accessor(attrs[jn], f"{what} {jn}")
            w = r.accessor(attrs[wn], f"{what} {wn}")
        if w is None or j.shape != (nv, 4) or w.shape != (nv, 4):
            r.fail(f"{what}: {jn}/{wn} must be VEC4 with one entry per vertex ({nv})")
        if j.dtype.kind == "f":
            r.fail(f"{what}: {jn} must hold unsigned integers")
        joints.append(j)
        weights.append(w.astype(np.float64))
    if joints:
        joints = np.concatenate(joints, axis=1)
        weights = np.concatenate(weights, axis=1)
        if not np.isfinite(weights).all() or (weights < 0).any():
            r.fail(f"{what}: joint weights must be finite and non-negative")
    else:
        joints = weights = None

    targets = prim.get("targets") or []
    if not isinstance(targets, list):
        r.fail(f"{what}: 'targets' is not a list")
    deltas = np.zeros((len(targets), nv, 3))
    for k, tg in enumerate(targets):
        if not isinstance(tg, dict):
            r.fail(f"{what}: morph target {k} is not an object")
        if "POSITION" in tg:
            d = r.accessor(tg["POSITION"], f"{what} morph target {k} POSITION")
            if d.shape != (nv, 3):
                r.fail(f"{what}: morph target {k} POSITION must be VEC3 with {nv} entries, got {d.shape}")
            deltas[k] = d
    out = _Primitive(pos, faces, joints, weights, deltas)
    if looks is not None:
        _load_looks(r, what, prim, attrs, targets, draco_attr, looks, out)
    return out


def _unit_rows(a):
    """(n, 3) float32 rows scaled to unit length (zero rows stay zero)."""
    a = np.asarray(a, np.float64)
    n = np.sqrt((a * a).sum(axis=1, keepdims=True))
    return np.divide(a, n, out=np.zeros_like(a), where=n > 0).astype(np.float32)


def _load_looks(r, what, prim, attrs, targets, draco_attr, looks, out):
    """Fill ``out``'s material, NORMAL, morph NORMAL deltas, base colour uv and COLOR_0 (decoded
    from Draco data when the extension holds them)."""
    nv = len(out.positions)

    def per_vertex(name, sizes, index=None, label=None):
        a = draco_attr(name) if draco_attr is not None and index is None else None
        if a is None:
            a = r.accessor(attrs[name] if index is None else index, f"{what} {label or name}")
        if a.ndim != 2 or a.shape[0] != nv or a.shape[1] not in sizes:
            types = " or ".join(f"VEC{k}" for k in sizes)
            r.fail(f"{what}: {label or name} must be {types} with one entry per vertex ({nv}), "
                   f"got {a.shape[0]} entries of {a.shape[1] if a.ndim == 2 else '?'} components")
        return a

    out.material = prim.get("material")
    mat = looks.material(out.material, what)
    if mat.texture is not None:
        name = f"TEXCOORD_{mat.texcoord}"
        if name in attrs:
            out.uv = np.ascontiguousarray(per_vertex(name, (2,)), np.float32)
        else:
            looks.warn_once(("uv", out.material), f"material {out.material}'s base colour texture is read through "
                            f"{name}, which {what} lacks (and maybe other primitives of the material): they are "
                            "drawn without the texture", TextureWarning)
            mat = mat._replace(texture=None)
    out.looks = mat
    if "NORMAL" in attrs:
        out.normals = _unit_rows(per_vertex("NORMAL", (3,)))
        nd = None
        for k, tg in enumerate(targets):
            if "NORMAL" in tg:
                if nd is None:
                    nd = np.zeros((len(targets), nv, 3), np.float32)
                nd[k] = per_vertex("NORMAL", (3,), tg["NORMAL"], f"morph target {k} NORMAL")
        out.ntargets = nd
    if "COLOR_0" in attrs:
        c = per_vertex("COLOR_0", (3, 4))[:, :3]  # alpha ignored
        if c.dtype.kind in "iu":  # integers the file did not mark normalized (the specification requires it)
            acc = r.item("accessors", attrs["COLOR_0"], f"{what} COLOR_0")
            c = c / (_COMPONENTS.get(acc.get("componentType"), (None, None))[1] or 255.0)
        out.colors = np.clip(c, 0.0, None).astype(np.float32)


# ------------------------------------------------------------------------------ reading the scene's parts
# GltfAnimation._build calls these in the order below; each check fails with the first problem it meets.


def _depth_first(nodes, roots):
    """The nodes below ``roots`` (each root, then its children in order, recursively)."""
    out = []
    for root in roots:
        stack = [int(root)]
        while stack:
            i = stack.pop()
            out.append(i)
            stack.extend(reversed(nodes[i].get("children", [])))
    return out


def _read_hierarchy(r, nodes):
    """(parent (N,) int32 with -1 for roots, every node in depth-first order from the roots); checks
    that nodes are objects, children are node indices and the hierarchy is a forest."""
    n_nodes = len(nodes)
    for i, nd in enumerate(nodes):
        if not isinstance(nd, dict):
            r.fail(f"malformed glTF: nodes[{i}] is not an object")
    parent = np.full(n_nodes, -1, dtype=np.int32)
    for i, nd in enumerate(nodes):
        ch = nd.get("children", [])
        if not isinstance(ch, list):
            r.fail(f"node {i}: 'children' is not a list")
        for c in ch:
            if not _is_int(c) or not 0 <= c < n_nodes:
                r.fail(f"node {i} has a child {c!r} that is not a node index (0..{n_nodes - 1})")
            if parent[c] >= 0 or c == i:
                r.fail(f"node {c} has more than one parent (the node hierarchy must be a forest)")
            parent[c] = i
    order = _depth_first(nodes, np.flatnonzero(parent < 0))
    if len(order) != n_nodes:
        r.fail("the node hierarchy has a cycle")
    return parent, order


class _RestTransforms(NamedTuple):
    """Every node's rest transform: TRS, or a 'matrix' where ``use_matrix`` is set."""

    t: np.ndarray  # (N, 3) translation
    r: np.ndarray  # (N, 4) unit quaternion, xyzw
    s: np.ndarray  # (N, 3) scale
    use_matrix: np.ndarray  # (N,) bool
    matrix: np.ndarray  # (N, 4, 4)


def _read_rest_transforms(r, nodes):
    """:class:`_RestTransforms` of ``nodes``; rotations are normalized."""
    n_nodes = len(nodes)
    node_t = np.zeros((n_nodes, 3))
    node_r = np.zeros((n_nodes, 4))
    node_r[:, 3] = 1.0
    node_s = np.ones((n_nodes, 3))
    use_matrix = np.zeros(n_nodes, dtype=np.bool_)
    node_matrix = np.tile(np.eye(4), (n_nodes, 1, 1))
    for i, nd in enumerate(nodes):
        w = f"node {i}"
        if "matrix" in nd:
            use_matrix[i] = True
            node_matrix[i] = r.floats(nd, "matrix", 16, np.eye(4).ravel(), w).reshape(4, 4).T
        node_t[i] = r.floats(nd, "translation", 3, (0, 0, 0), w)
        q = r.floats(nd, "rotation", 4, (0, 0, 0, 1), w)
        if np.abs(q).max() > 1e150:  # scaled first: a huge quaternion must not overflow the norm
            q = q / np.abs(q).max()
        nq = np.linalg.norm(q)
        node_r[i] = q / nq if nq > 0 else (0, 0, 0, 1)
        node_s[i] = r.floats(nd, "scale", 3, (1, 1, 1), w)
    return _RestTransforms(node_t, node_r, node_s, use_matrix, node_matrix)


def _scene_nodes(r, nodes, parent, scene_index):
    """The nodes of scene ``scene_index`` (default: the file's ``scene``, else 0) in depth-first
    order; every node when the file has no scenes."""
    n_nodes = len(nodes)
    scenes = r.items("scenes")
    if scene_index is None:
        scene_index = r.tree.get("scene", 0) if scenes else None
    if scenes:
        sc = r.item("scenes", scene_index, "the default scene")
        roots = sc.get("nodes", [])
        if not isinstance(roots, list):
            r.fail(f"scene {scene_index}: 'nodes' is not a list")
        for n in roots:
            if not _is_int(n) or not 0 <= n < n_nodes:
                r.fail(f"scene {scene_index} refers to node {n!r}, but the file has {n_nodes} nodes")
    else:
        roots = [int(i) for i in np.flatnonzero(parent < 0)]
    return _depth_first(nodes, roots)


class _Skins(NamedTuple):
    """The file's skins, their joints laid end to end in one joint palette."""

    items: list  # the skins' JSON objects
    offset: list  # each skin's first row in the palette
    joint_node: np.ndarray  # (J,) int32: the node of each palette row ([0] without skins)
    ibm: np.ndarray  # (J, 4, 4) inverse bind matrices (one identity without skins)
    n_joints: int  # J (0 without skins)


def _read_skins(r, n_nodes):
    skins = r.items("skins")
    skin_offset, joint_node, ibm = [], [], []
    total = 0
    for s, sk in enumerate(skins):
        if not isinstance(sk, dict):
            r.fail(f"malformed glTF: skins[{s}] is not an object")
        joints = sk.get("joints")
        if not isinstance(joints, list) or not joints:
            r.fail(f"skin {s} has no joints")
        for j in joints:
            if not _is_int(j) or not 0 <= j < n_nodes:
                r.fail(f"skin {s} refers to joint node {j!r}, but the file has {n_nodes} nodes")
        if "inverseBindMatrices" in sk:
            m = r.accessor(sk["inverseBindMatrices"], f"skin {s} inverseBindMatrices")
            if m.shape[1] != 16 or len(m) < len(joints):
                r.fail(f"skin {s}: inverseBindMatrices must be {len(joints)} MAT4, got {m.shape}")
            ibm.append(m[: len(joints)].reshape(-1, 4, 4).transpose(0, 2, 1))
        else:
            ibm.append(np.tile(np.eye(4), (len(joints), 1, 1)))
        skin_offset.append(total)
        joint_node.extend(int(j) for j in joints)
        total += len(joints)
    joint_node = np.array(joint_node or [0], dtype=np.int32)
    ibm = np.ascontiguousarray(np.concatenate(ibm) if ibm else np.eye(4)[None], dtype=np.float64)
    return _Skins(skins, skin_offset, joint_node, ibm, total)


class _Instance:
    __slots__ = ("node", "mesh", "prim", "skin", "n_targets")

    def __init__(self, node, mesh, prim, skin, n_targets):
        self.node, self.mesh, self.prim, self.skin, self.n_targets = node, mesh, prim, skin, n_targets


class _Morphs(NamedTuple):
    """The morph weights of the nodes whose mesh has morph targets, laid end to end in one vector."""

    offset: dict  # node -> its first entry in the vector
    count: dict  # node -> its number of weights
    weights: np.ndarray  # the initial vector (node weights, else mesh weights, else 0; [0] without morphs)


def _read_instances(r, nodes, visible, skins, looks=None):
    """(instances, :class:`_Morphs`): one :class:`_Instance` per triangle primitive of each visible
    node with a mesh, in depth-first node order then primitive order (a mesh that several nodes use
    is decoded once); ``skins`` is the JSON list.  Fails when the scene holds no triangles."""
    r.items("meshes")  # a 'meshes' that is not a list fails here, before any node's mesh is read
    prim_cache = {}
    instances = []
    weight_offset = {}
    weight_count = {}
    init_weights = []
    n_w = 0
    for i in visible:
        nd = nodes[i]
        if "mesh" not in nd:
            continue
        mi = nd["mesh"]
        mesh = r.item("meshes", mi, f"node {i}")
        prims = mesh.get("primitives")
        if not isinstance(prims, list) or not prims:
            r.fail(f"mesh {mi} has no primitives")
        skin = nd.get("skin")
        if skin is not None and (not _is_int(skin) or not 0 <= skin < len(skins)):
            r.fail(f"node {i} refers to skin {skin!r}, but the file has {len(skins)} skins")
        n_targets = None
        for pi, prim in enumerate(prims):
            key = (mi, pi)
            if key not in prim_cache:
                prim_cache[key] = _load_primitive(r, mi, pi, prim, looks)
            pr = prim_cache[key]
            if pr is None or len(pr.faces) == 0:
                continue
            if n_targets is None:
                n_targets = len(pr.targets)
            elif n_targets != len(pr.targets):
                r.fail(f"mesh {mi}: primitives have different numbers of morph targets")
            use_skin = skin if (skin is not None and pr.joints is not None) else None
            if use_skin is not None:
                nj = len(skins[use_skin]["joints"])
                bad = (pr.joints >= nj) | (pr.joints < 0)
                if (bad & (pr.weights != 0)).any():
                    r.fail(f"mesh {mi} primitive {pi}: joint index {int(pr.joints.max())} out of range "
                           f"for skin {use_skin} with {nj} joints")
            instances.append(_Instance(i, mi, pr, use_skin, len(pr.targets)))
        if n_targets:
            default = r.floats(mesh, "weights", n_targets, np.zeros(n_targets), f"mesh {mi}")
            w0 = r.floats(nd, "weights", n_targets, default, f"node {i}")
            weight_offset[i] = n_w
            weight_count[i] = n_targets
            init_weights.append(w0)
            n_w += n_targets
    if not instances:
        r.fail("the scene holds no triangles (no mesh with a triangle primitive)")
    weights = np.concatenate(init_weights) if init_weights else np.zeros(1)
    return instances, _Morphs(weight_offset, weight_count, weights)


class _Channels(NamedTuple):
    """The chosen clips' channels that move geometry, the flat arrays of kernels.Channels."""

    times: np.ndarray  # every channel's key times, end to end ([0] without channels)
    values: np.ndarray  # every channel's output values, end to end ([0] without channels)
    table: dict  # per channel: tstart, tcount, vstart (int64), ncomp, interp, kind, target (int32)
    moved_nodes: set  # nodes whose translation, rotation or scale a channel changes
    moved_weights: set  # nodes whose morph weights a channel changes
    t_lo: float  # the first key time (inf without channels)
    t_hi: float  # the last key time (-inf without channels)


def _read_channels(r, anims, chosen, n_nodes, morphs, use_matrix):
    """The channels of animations ``chosen`` that target node TRS or morph weights, checked (targets,
    samplers, interpolation, key times, value counts); other targets are skipped, and so are the
    weights of nodes without morph targets.  A channel whose keys are all equal moves nothing."""
    times, values = [], []
    ch = {k: [] for k in ("tstart", "tcount", "vstart", "ncomp", "interp", "kind", "target")}
    moved_nodes = set()
    moved_weights = set()
    t_lo, t_hi = math.inf, -math.inf
    nt, nv = 0, 0
    for a in chosen:
        an = anims[a]
        samplers = an.get("samplers", [])
        channels = an.get("channels", [])
        if not isinstance(samplers, list) or not isinstance(channels, list):
            r.fail(f"animation {a}: 'samplers' and 'channels' must be lists")
        for c, chan in enumerate(channels):
            w = f"animation {a} channel {c}"
            if not isinstance(chan, dict) or not isinstance(chan.get("target"), dict):
                r.fail(f"{w}: missing target")
            tgt = chan["target"]
            path_name = tgt.get("path")
            node = tgt.get("node")
            if path_name not in _PATHS or node is None:
                continue  # e.g. KHR_animation_pointer targets: not geometry
            if not _is_int(node) or not 0 <= node < n_nodes:
                r.fail(f"{w} targets node {node!r}, but the file has {n_nodes} nodes")
            si = chan.get("sampler")
            if not _is_int(si) or not 0 <= si < len(samplers) or not isinstance(samplers[si], dict):
                r.fail(f"{w} refers to sampler {si!r}, but animation {a} has {len(samplers)} samplers")
            smp = samplers[si]
            interp = smp.get("interpolation", "LINEAR")
            if interp not in _INTERP:
                r.fail(f"{w}: unknown interpolation {interp!r}")
            kind, m = _PATHS[path_name]
            if kind == KIND_W:
                if node not in morphs.offset:
                    continue  # weights of a node without morph targets move nothing
                m = morphs.count[node]
            elif use_matrix[node]:
                r.fail(f"{w} animates node {node}, which has a 'matrix' (animated nodes need TRS)")
            per = 3 if interp == "CUBICSPLINE" else 1
            tk, vals = _sampler_keys(r, w, smp, per, m)
            ch["tstart"].append(nt)
            ch["tcount"].append(len(tk))
            ch["vstart"].append(nv)
            ch["ncomp"].append(m)
            ch["interp"].append(_INTERP[interp])
            ch["kind"].append(kind)
            ch["target"].append(morphs.offset[node] if kind == KIND_W else node)
            times.append(tk)
            values.append(vals)
            nt += len(tk)
            nv += len(vals)
            t_lo, t_hi = min(t_lo, float(tk[0])), max(t_hi, float(tk[-1]))
            if not _holds_its_value(vals, len(tk), per, m):
                (moved_weights if kind == KIND_W else moved_nodes).add(node)
    return _Channels(
        np.concatenate(times) if times else np.zeros(1),
        np.concatenate(values) if values else np.zeros(1),
        {k: np.array(v, dtype=np.int64 if k in ("tstart", "vstart") else np.int32) for k, v in ch.items()},
        moved_nodes, moved_weights, t_lo, t_hi,
    )


def _sampler_keys(r, w, smp, per, m):
    """A sampler's key times (K,) and its output values, flat (K * per * m: ``per`` is 3 for
    CUBICSPLINE's in-tangent, value, out-tangent, else 1; ``m`` values each)."""
    tin = r.accessor(smp.get("input"), f"{w} input")
    tout = r.accessor(smp.get("output"), f"{w} output")
    if tin.shape[1] != 1 or tin.dtype.kind != "f" or len(tin) == 0:
        r.fail(f"{w}: sampler input must be a non-empty float SCALAR accessor")
    tk = tin[:, 0]
    if (np.diff(tk) < 0).any():
        r.fail(f"{w}: key times decrease")
    vals = np.asarray(tout, dtype=np.float64).reshape(-1)
    if len(vals) != len(tk) * per * m:
        r.fail(f"{w}: {len(tk)} keys need {len(tk) * per * m} output values, got {len(vals)}")
    return tk, vals


def _holds_its_value(vals, n_keys, per, m):
    """Whether a channel's keys all hold one value (and, for CUBICSPLINE, zero tangents)."""
    recs = vals.reshape(n_keys, per, m)
    constant = bool((np.ptp(recs[:, per // 2], axis=0) == 0).all())
    if per == 3:
        constant = constant and not recs[:, [0, 2]].any()
    return constant


def _moving_nodes(order, parent, moved_nodes):
    """(N,) bool: the nodes a channel moves and every node below one."""
    moving = np.zeros(len(parent), dtype=bool)
    for i in order:
        moving[i] = (i in moved_nodes) or (parent[i] >= 0 and moving[parent[i]])
    return moving


class _Flat(NamedTuple):
    """The instances laid end to end in the arrays of kernels.Rig and deform_vertices."""

    local: np.ndarray  # (V, 3) float32: POSITION data
    vinst: np.ndarray  # (V,) int32: the instance of each vertex
    inst: tuple  # per instance: first vertex (I+1,), node, skinned, morph delta base, target count, weight offset
    joints: np.ndarray  # (V, J) int32 palette rows ((1, J) without skins)
    jweights: np.ndarray  # (V, J) float32 joint weights, divided by their sum
    deltas: np.ndarray  # (D, 3) float32 morph target displacements ([0] without morphs)
    faces: np.ndarray  # (F, 3) int64 vertex indices
    tri_moving: np.ndarray  # (F,) bool: triangles of instances that can move
    inst_moving: np.ndarray  # (I,) bool: instances that can move


def _flatten_instances(instances, skins, moving, morphs, moved_weights):
    """Concatenate the instances' vertices, faces, joints and morph targets, and decide which
    instances can move: rigid ones under a moving node, skinned ones with a moving joint (or with
    unweighted vertices under a moving node), and any whose morph weights are animated."""
    V = sum(len(ins.prim.positions) for ins in instances)
    J = max([ins.prim.joints.shape[1] for ins in instances if ins.skin is not None] or [1])
    local = np.zeros((V, 3), dtype=TRI_DTYPE)
    vinst = np.zeros(V, dtype=np.int32)
    inst_first = np.zeros(len(instances) + 1, dtype=np.int64)
    inst_node = np.zeros(len(instances), dtype=np.int32)
    inst_skinned = np.zeros(len(instances), dtype=np.bool_)
    inst_mbase = np.zeros(len(instances), dtype=np.int64)
    inst_mcount = np.zeros(len(instances), dtype=np.int32)
    inst_woff = np.zeros(len(instances), dtype=np.int64)
    joints = np.zeros((V if any(ins.skin is not None for ins in instances) else 1, J), dtype=np.int32)
    jweights = np.zeros(joints.shape, dtype=TRI_DTYPE)
    faces, tri_moving, deltas = [], [], []
    n_d = 0
    v0 = 0
    inst_moving = np.zeros(len(instances), dtype=bool)
    for k, ins in enumerate(instances):
        pr = ins.prim
        n = len(pr.positions)
        local[v0:v0 + n] = pr.positions
        vinst[v0:v0 + n] = k
        inst_first[k] = v0
        inst_node[k] = ins.node
        mv = False
        if ins.skin is not None:
            inst_skinned[k] = True
            nj = len(skins.items[ins.skin]["joints"])
            jj = np.where((pr.joints >= 0) & (pr.joints < nj), pr.joints, 0)
            ww = pr.weights.copy()
            sums = ww.sum(axis=1, keepdims=True)
            ww = np.divide(ww, sums, out=np.zeros_like(ww), where=sums > 0)
            joints[v0:v0 + n, : jj.shape[1]] = jj + skins.offset[ins.skin]
            jweights[v0:v0 + n, : ww.shape[1]] = ww
            skin_nodes = np.array(skins.items[ins.skin]["joints"])
            mv = bool(moving[skin_nodes].any()) or (bool((sums == 0).any()) and moving[ins.node])
        else:
            mv = bool(moving[ins.node])
        if ins.n_targets:
            inst_mbase[k] = n_d
            inst_mcount[k] = ins.n_targets
            inst_woff[k] = morphs.offset[ins.node]
            deltas.append(pr.targets.reshape(-1, 3))
            n_d += ins.n_targets * n
            mv = mv or ins.node in moved_weights
        inst_moving[k] = mv
        faces.append(pr.faces + v0)
        tri_moving.append(np.full(len(pr.faces), mv))
        v0 += n
    inst_first[-1] = V
    deltas = (np.ascontiguousarray(np.concatenate(deltas), dtype=TRI_DTYPE) if deltas
              else np.zeros((1, 3), dtype=TRI_DTYPE))
    inst = (inst_first, inst_node, inst_skinned, inst_mbase, inst_mcount, inst_woff)
    return _Flat(local, vinst, inst, joints, jweights, deltas, np.concatenate(faces), np.concatenate(tri_moving),
                 inst_moving)


# ------------------------------------------------------------------------------ looks: normals, surface, lights


class _FlatNormals(NamedTuple):
    """The instances' NORMAL data laid end to end beside :class:`_Flat`'s positions."""

    local: np.ndarray  # (V, 3) float32 unit rest normals (zero rows for instances without NORMAL)
    deltas: np.ndarray  # (D, 3) float32 morph NORMAL deltas in _Flat.deltas' rows ([0] when no target has them)
    inst_morph: np.ndarray  # (I,) bool: instances whose morph targets have NORMAL deltas
    inst_has: np.ndarray  # (I,) bool: instances with NORMAL


def _flatten_normals(instances, flat):
    first, _, _, mbase, _, _ = flat.inst
    I = len(instances)
    local = np.zeros((len(flat.local), 3), dtype=TRI_DTYPE)
    inst_morph = np.zeros(I, dtype=np.bool_)
    inst_has = np.zeros(I, dtype=np.bool_)
    any_deltas = any(ins.prim.normals is not None and ins.prim.ntargets is not None and ins.n_targets
                     for ins in instances)
    deltas = np.zeros((len(flat.deltas) if any_deltas else 1, 3), dtype=TRI_DTYPE)
    for k, ins in enumerate(instances):
        pr = ins.prim
        if pr.normals is None:
            continue
        inst_has[k] = True
        local[first[k]:first[k + 1]] = pr.normals
        if pr.ntargets is not None and ins.n_targets:
            inst_morph[k] = True
            deltas[mbase[k]:mbase[k] + pr.ntargets.size // 3] = pr.ntargets.reshape(-1, 3)
    return _FlatNormals(local, deltas, inst_morph, inst_has)


@njit(cache=True)
def _normal_matrices(m, out):
    """out[k] (3,3) = the inverse transpose of m[k][:3, :3] ((K,4,4) f64): its cofactor matrix over its
    determinant, or the cofactor matrix alone when singular (which maps every normal onto the one a
    flattened surface keeps)."""
    for k in range(m.shape[0]):
        a, b, c = m[k, 0, 0], m[k, 0, 1], m[k, 0, 2]
        d, e, f = m[k, 1, 0], m[k, 1, 1], m[k, 1, 2]
        g, h, i = m[k, 2, 0], m[k, 2, 1], m[k, 2, 2]
        c00, c01, c02 = e * i - f * h, f * g - d * i, d * h - e * g
        c10, c11, c12 = c * h - b * i, a * i - c * g, b * g - a * h
        c20, c21, c22 = b * f - c * e, c * d - a * f, a * e - b * d
        det = a * c00 + b * c01 + c * c02
        s = 1.0 / det if det != 0.0 else 1.0
        out[k, 0, 0], out[k, 0, 1], out[k, 0, 2] = c00 * s, c01 * s, c02 * s
        out[k, 1, 0], out[k, 1, 1], out[k, 1, 2] = c10 * s, c11 * s, c12 * s
        out[k, 2, 0], out[k, 2, 1], out[k, 2, 2] = c20 * s, c21 * s, c22 * s


def _normal_body(v, nlocal, vinst, rig, inst_nmorph, pose, out):
    """Pose vertex v's normal as deform_vertices poses its position: morph NORMAL deltas (rig.deltas
    of instances with inst_nmorph), then the blend of its joints' normal matrices (pose.palette) or
    its node's (pose.world), then normalize (a zero result stays zero)."""
    inst_first, inst_node, inst_skinned = rig.first, rig.node, rig.skinned
    inst_mbase, inst_mcount, inst_woff = rig.mbase, rig.mcount, rig.woff
    joints, jweights, ndeltas = rig.joints, rig.jweights, rig.deltas
    mweights, node_nm, joint_nm = pose.weights, pose.world, pose.palette
    i = vinst[v]
    x = np.float64(nlocal[v, 0])
    y = np.float64(nlocal[v, 1])
    z = np.float64(nlocal[v, 2])
    if inst_nmorph[i]:
        nv = inst_first[i + 1] - inst_first[i]
        lv = v - inst_first[i]
        wo = inst_woff[i]
        mb = inst_mbase[i]
        for k in range(inst_mcount[i]):
            mw = mweights[wo + k]
            if mw != 0.0:
                row = mb + k * nv + lv
                x += mw * ndeltas[row, 0]
                y += mw * ndeltas[row, 1]
                z += mw * ndeltas[row, 2]
    ox = 0.0
    oy = 0.0
    oz = 0.0
    wsum = 0.0
    if inst_skinned[i]:
        for j in range(joints.shape[1]):
            w = np.float64(jweights[v, j])
            if w != 0.0:
                g = joints[v, j]
                ox += w * (joint_nm[g, 0, 0] * x + joint_nm[g, 0, 1] * y + joint_nm[g, 0, 2] * z)
                oy += w * (joint_nm[g, 1, 0] * x + joint_nm[g, 1, 1] * y + joint_nm[g, 1, 2] * z)
                oz += w * (joint_nm[g, 2, 0] * x + joint_nm[g, 2, 1] * y + joint_nm[g, 2, 2] * z)
                wsum += w
    if wsum == 0.0:
        n = inst_node[i]
        ox = node_nm[n, 0, 0] * x + node_nm[n, 0, 1] * y + node_nm[n, 0, 2] * z
        oy = node_nm[n, 1, 0] * x + node_nm[n, 1, 1] * y + node_nm[n, 1, 2] * z
        oz = node_nm[n, 2, 0] * x + node_nm[n, 2, 1] * y + node_nm[n, 2, 2] * z
    length = math.sqrt(ox * ox + oy * oy + oz * oz)
    if length > 0.0 and length < math.inf:
        inv = 1.0 / length
        out[v, 0] = ox * inv
        out[v, 1] = oy * inv
        out[v, 2] = oz * inv
    else:
        out[v, 0] = 0.0
        out[v, 1] = 0.0
        out[v, 2] = 0.0


# One body, two compilations: the serial kernel calls it compiled on its own without reference
# counting (as kernels._deform_one), the parallel one has it inlined into its loop, which measured
# several times faster there (BrainStem's 34k skinned vertices on 2 threads: 0.26 ms against 2.3 ms
# for the call, while inlining into the serial loop was slower: 5.8 ms against 1.8 ms).
_normal_one = njit(cache=True, _nrt=False)(_normal_body)
_normal_one_inlined = njit(inline="always")(_normal_body)


@njit(cache=True, parallel=True)
def _normals_parallel(vids, nlocal, vinst, rig, inst_nmorph, pose, out):
    for ii in prange(vids.shape[0]):
        _normal_one_inlined(vids[ii], nlocal, vinst, rig, inst_nmorph, pose, out)


@njit(cache=True)
def _normals_serial(vids, nlocal, vinst, rig, inst_nmorph, pose, out):
    for ii in range(vids.shape[0]):
        _normal_one(vids[ii], nlocal, vinst, rig, inst_nmorph, pose, out)


def _build_surface(instances, normals):
    """The scene's Surface in triangle order (None when no primitive has a material, NORMAL or
    COLOR_0); ``normals`` (F, 3, 3) the posed normals per corner, or None."""
    if not any(ins.prim.material is not None or ins.prim.normals is not None or ins.prim.colors is not None
               for ins in instances):
        return None
    b = SurfaceBuilder()
    f0 = 0
    for ins in instances:
        pr = ins.prim
        m = pr.looks
        n = len(pr.faces)
        b.add(n, m.diffuse, m.ambient, m.texture,
              uv=pr.uv[pr.faces] if m.texture is not None else None,
              colors=pr.colors[pr.faces] if pr.colors is not None else None,
              normals=normals[f0:f0 + n] if pr.normals is not None else None)
        f0 += n
    return b.build()


class _Light(NamedTuple):
    node: int
    kind: float  # LIGHT_POINT or LIGHT_DIRECTIONAL
    rgb: tuple  # colour * intensity
    falloff: float


def _read_lights(r, nodes, visible, looks):
    """The KHR_lights_punctual lights on the nodes ``visible``, checked, in that node order."""
    ext = r.tree.get("extensions")
    ext = ext.get("KHR_lights_punctual") if isinstance(ext, dict) else None
    defs = ext.get("lights") if isinstance(ext, dict) else None
    defs = defs if isinstance(defs, list) else []
    out = []
    for i in visible:
        ne = nodes[i].get("extensions")
        if not isinstance(ne, dict) or ne.get("KHR_lights_punctual") is None:
            continue
        w = f"node {i} KHR_lights_punctual"
        le = ne["KHR_lights_punctual"]
        if not isinstance(le, dict):
            r.fail(f"{w} is not an object")
        li = r.uint(le, "light", w)
        if li >= len(defs) or not isinstance(defs[li], dict):
            r.fail(f"{w} refers to light {li}, but the file defines {len(defs)} KHR_lights_punctual lights")
        light = defs[li]
        wl = f"KHR_lights_punctual light {li}"
        color = r.floats(light, "color", 3, (1.0, 1.0, 1.0), wl)
        intensity = light.get("intensity", 1.0)
        if not isinstance(intensity, (Real, np.floating, np.integer)) or isinstance(intensity, bool) \
                or not math.isfinite(intensity) or intensity < 0 or (color < 0).any():
            r.fail(f"{wl}: colour and intensity must be finite and >= 0")
        kind = light.get("type")
        if kind == "directional":
            out.append(_Light(i, LIGHT_DIRECTIONAL, tuple(color * intensity), FALLOFF_NONE))
        elif kind in ("point", "spot"):
            if kind == "spot":
                looks.warn_once("spot", "spot lights (KHR_lights_punctual) are drawn as point lights "
                                "(their cone is ignored)")
            out.append(_Light(i, LIGHT_POINT, tuple(color * intensity), FALLOFF_INVERSE_SQUARE))
        else:
            r.fail(f"{wl}: unknown type {kind!r} (glTF knows directional, point and spot)")
    return out


# ------------------------------------------------------------------------------ the scene


class GltfAnimation(Animation):
    """A glTF 2.0 scene posed at time t: node animation, skinning and morph targets.

    Parameters
    ----------
    path : str or os.PathLike
        A .gltf (with its .bin and other buffers) or .glb file.
    clip : int or str, optional
        The animation to play: its index in the file's ``animations`` or its name.  By default
        all animations play together when they animate disjoint (node, property) pairs (exporters
        such as COLLADA2GLTF split one clip into one animation per joint), else animation 0.
    scene : int, optional
        Index of the glTF scene to show (default: the file's ``scene``, else 0).
    allow_outside : bool
        Trust the file's buffer and image URIs that lead outside its folder (see
        :mod:`gridrt.scene.files`); by default such a buffer is a SceneFileError and such an image
        is drawn without (TextureWarning).

    Attributes
    ----------
    clips : list of str
        Names of the file's animations (``"animation <i>"`` when unnamed).
    clip : str or None
        The clip being played (``"all"`` when several animations are merged), None without one.
    time_range : tuple of float or None
        (first, last) key time of the clip's channels; ``t`` maps to clip time
        ``first + (t mod (last - first))``.
    static_mask : ndarray
        (F,) bool; True for triangles of instances that cannot move: rigid meshes whose node and
        ancestors are not animated, skinned meshes none of whose joints moves, and no animated
        morph weights.  Channels whose keys are all equal count as not animated.
    surface : gridrt.scene.surface.Surface or None
        The scene's materials, base colour textures, uv, COLOR_0 colours and NORMAL normals (posed at
        clip time 0; :meth:`normals_at` gives them at t), in triangle order; None when no primitive
        has a material, NORMAL or COLOR_0 (see the module's docstring).
    n_joints, n_nodes, n_instances, n_morph_targets, n_lights : int
        Sizes of the scene (for reports).

    Raises
    ------
    SceneFileError
        Missing, unreadable, truncated or malformed file (every index is checked, materials, textures,
        samplers and lights included); Draco geometry without DracoPy; no triangles; a buffer that
        leads outside the file's folder, is not a regular file or is shorter than its byteLength.
        An image that cannot be read (or is refused) only warns (TextureWarning).
    InputError
        ``clip`` is not an index/name of the file's animations (the message lists them).
    """

    def __init__(self, path, clip=None, scene=None, *, allow_outside=False):
        if not isinstance(path, (str, os.PathLike)):
            raise InputError(f"glTF path must be a str or path-like object, got {type(path).__name__}")
        p = Path(path)
        if not p.exists():
            raise SceneFileError(p, "file not found")
        if p.is_dir():
            raise SceneFileError(p, "is a directory, not a glTF file")
        r = _Reader(p, SceneFolder(p, allow_outside))
        self.path = p
        try:
            self._build(r, clip, scene)
        except (KeyError, TypeError, ValueError, IndexError, AttributeError, OverflowError) as e:
            if isinstance(e, (SceneFileError, InputError)):
                raise
            raise SceneFileError(p, f"malformed glTF ({type(e).__name__}: {e})") from e

    # ---------------------------------------------------------------- construction

    def _build(self, r, clip, scene_index):
        """Read the file's parts in the order below (each reader checks what it reads and fails with
        the first problem), then keep the arrays the per-frame kernels take and pose frame 0."""
        nodes = r.items("nodes")
        n_nodes = len(nodes)
        parent, order = _read_hierarchy(r, nodes)
        rest = _read_rest_transforms(r, nodes)
        visible = _scene_nodes(r, nodes, parent, scene_index)
        skins = _read_skins(r, n_nodes)
        self.n_joints = skins.n_joints
        looks = _Looks(r)
        instances, morphs = _read_instances(r, nodes, visible, skins.items, looks)
        self._lights = _read_lights(r, nodes, visible, looks)
        self._weights = morphs.weights

        anims = r.items("animations")
        chosen = self._select_clips(r, anims, clip)
        channels = _read_channels(r, anims, chosen, n_nodes, morphs, rest.use_matrix)
        self._channels = as_channels(channels.times, channels.values, *(channels.table[k] for k in (
            "tstart", "tcount", "vstart", "ncomp", "interp", "kind", "target")))
        self.n_channels = len(channels.table["kind"])

        moving = _moving_nodes(order, parent, channels.moved_nodes)
        flat = _flatten_instances(instances, skins, moving, morphs, channels.moved_weights)
        try:
            local32, faces32 = as_mesh(flat.local, flat.faces, what=f"glTF scene {self.path.name}")
        except InputError as e:
            r.fail(str(e))
        self._local = local32
        self._faces = faces32
        self._vinst = flat.vinst
        self._rig = as_rig(*flat.inst, flat.joints, flat.jweights, flat.deltas)
        self._order = np.array(order, dtype=np.int32)
        self._parent = parent
        self._use_matrix = rest.use_matrix
        self._node_matrix = rest.matrix
        self._rest = (rest.t, rest.r, rest.s)
        self._node_t, self._node_r, self._node_s = rest.t.copy(), rest.r.copy(), rest.s.copy()
        self._world = np.zeros((n_nodes, 4, 4))
        self._joint_node = skins.joint_node
        self._ibm = skins.ibm
        self._palette = np.zeros((len(skins.joint_node), 4, 4))
        self._nodes_json = nodes
        self._cameras = r.items("cameras")
        self._camera_node = self._find_camera(r, visible, nodes)

        self.name = self.path.stem if self.clip in (None, "all") else f"{self.path.stem} ({self.clip})"
        self.n_triangles = int(len(faces32))
        self.n_nodes = n_nodes
        self.n_instances = len(instances)
        self.n_morph_targets = int(sum(ins.n_targets for ins in instances))
        self.n_vertices = len(flat.local)
        mask = ~flat.tri_moving
        self.static = bool(mask.all())
        self.static_mask = as_static_mask(mask, self.n_triangles)
        self._set_clip_range(channels.t_lo, channels.t_hi)
        self._pose_first_frame(r, flat.inst_moving[flat.vinst])
        self._set_looks(instances, flat, moving)

    def _select_clips(self, r, anims, clip):
        """Name the file's clips (``self.clips``), choose the animations to play (their indices,
        returned) and name the choice (``self.clip``)."""
        self.clips = []
        for a, an in enumerate(anims):
            if not isinstance(an, dict):
                r.fail(f"malformed glTF: animations[{a}] is not an object")
            name = an.get("name")
            self.clips.append(name if isinstance(name, str) and name else f"animation {a}")
        chosen = self._choose_clips(r, anims, clip)
        self.clip = None if not chosen else ("all" if len(chosen) > 1 else self.clips[chosen[0]])
        return chosen

    def _set_clip_range(self, t_lo, t_hi):
        """``time_range`` and ``duration`` from the channels' first and last key times."""
        if self.n_channels and t_hi >= t_lo:
            self.time_range = (t_lo, t_hi)
            span = t_hi - t_lo
            self.duration = span if span > 0 else None
        else:
            self.time_range = None
            self.duration = None

    def _pose_first_frame(self, r, vertex_moves):
        """Pose every vertex at clip time 0; later frames recompute the vertices ``vertex_moves``
        (V,) bool marks.  Fails when the pose is not finite or exceeds 1e30."""
        V = self.n_vertices
        vid = np.arange(V, dtype=np.int64)
        self._dynamic_vids = vid[vertex_moves]
        self._verts = np.zeros((V, 3), dtype=TRI_DTYPE)
        self._centre = np.zeros(3)  # POSITION data is float32 in the file: stored as it is
        self._posed_origin = np.zeros(3)  # the frame self._verts is in
        self._pose(self._clip_time(0.0), vid)
        if not (np.isfinite(self._verts).all() and np.abs(self._verts).max() <= 1e30):
            r.fail("posed vertex coordinates are not finite or exceed 1e30 (check scales and matrices)")

    def _set_looks(self, instances, flat, moving):
        """``surface`` (normals posed at clip time 0, as the vertices), the normal posing arrays
        (later frames recompute the normals of the moving vertices that have one) and the lights."""
        fn = _flatten_normals(instances, flat)
        self._has_normals = bool(fn.inst_has.any())
        normals = None
        if self._has_normals:
            self._nlocal, self._inst_nmorph = fn.local, fn.inst_morph
            self._nrig = self._rig._replace(deltas=np.ascontiguousarray(fn.deltas, np.float32))  # NORMAL deltas
            self._nposed = np.zeros((self.n_vertices, 3), dtype=TRI_DTYPE)
            self._node_nm = np.zeros((len(self._world), 3, 3))
            self._joint_nm = np.zeros((len(self._palette), 3, 3))
            has = fn.inst_has[self._vinst]
            self._normal_vids = self._dynamic_vids[has[self._dynamic_vids]]
            self._pose(self._clip_time(0.0), np.flatnonzero(has).astype(np.int64), normals=True)
            normals = gather_unchecked(self._nposed, self._faces, np.empty((self.n_triangles, 3, 3), TRI_DTYPE))
        self.surface = _build_surface(instances, normals)
        self.n_lights = len(self._lights)
        self._fixed_lights = None
        if not any(moving[lt.node] for lt in self._lights):
            self._update_world(self._clip_time(0.0))
            self._fixed_lights = self._light_rows()

    def _choose_clips(self, r, anims, clip):
        if not anims:
            if clip is not None:
                raise InputError(f"{self.path.name} has no animations, so clip={clip!r} cannot be chosen")
            return []
        listing = ", ".join(f"{i}: {n!r}" for i, n in enumerate(self.clips))
        if clip is None:
            seen = set()
            for an in anims:
                for chan in an.get("channels", []) if isinstance(an.get("channels"), list) else []:
                    tgt = chan.get("target") if isinstance(chan, dict) else None
                    if not isinstance(tgt, dict):
                        continue
                    key = (tgt.get("node"), tgt.get("path"))
                    if key in seen:
                        return [0]
                    seen.add(key)
            return list(range(len(anims)))
        if _is_int(clip):
            if not 0 <= clip < len(anims):
                raise InputError(f"clip index {clip} out of range; {self.path.name} has clips {listing}")
            return [int(clip)]
        if isinstance(clip, str):
            if clip in self.clips:
                return [self.clips.index(clip)]
            raise InputError(f"no clip named {clip!r} in {self.path.name}; clips: {listing}")
        raise InputError(f"clip must be an animation index or name, got {clip!r}")

    def _find_camera(self, r, visible, nodes):
        for i in visible:
            c = nodes[i].get("camera")
            if c is None:
                continue
            cam = r.item("cameras", c, f"node {i}")
            if cam.get("type") == "perspective" and isinstance(cam.get("perspective"), dict):
                yfov = cam["perspective"].get("yfov")
                if isinstance(yfov, (Real, np.floating)) and 0 < yfov < math.pi:
                    return i, math.degrees(float(yfov))
        return None

    # ---------------------------------------------------------------- evaluation

    def _clip_time(self, t):
        if self.time_range is None:
            return 0.0
        t0 = self.time_range[0]
        if self.duration is None:
            return t0
        return t0 + (t % self.duration)

    def _update_world(self, tc):
        sample_channels(self._channels, tc, self._node_t, self._node_r, self._node_s, self._weights)
        compose_world(self._order, self._parent, self._use_matrix, self._node_matrix, self._node_t,
                        self._node_r, self._node_s, self._world)

    def _pose(self, tc, vids, normals=False):
        """Bring the vertices ``vids`` of ``self._verts`` (with ``normals``: their normals in
        ``self._nposed``) to clip time ``tc``."""
        self._update_world(tc)
        skin_palette(self._world, self._joint_node, self._ibm, self._palette)
        if not normals:
            pose = Pose(self._weights, self._world, self._palette)
            deform_vertices(vids, self._local, self._vinst, self._rig, pose, self._centre, self._posed_origin,
                              self._verts)
            return
        _normal_matrices(self._world, self._node_nm)
        _normal_matrices(self._palette, self._joint_nm)
        kernel = _normals_serial if len(vids) < SERIAL_BELOW else _normals_parallel
        kernel(vids, self._nlocal, self._vinst, self._nrig, self._inst_nmorph,
               Pose(self._weights, self._node_nm, self._joint_nm), self._nposed)

    def _fill(self, t, out, origin):
        pose_moving_vertices(self, self._clip_time(t), origin)
        gather_unchecked(self._verts, self._faces, out)

    def _fill_normals(self, t, out):
        if not self._has_normals:
            return False
        if len(self._normal_vids):
            self._pose(self._clip_time(t), self._normal_vids, normals=True)
        gather_unchecked(self._nposed, self._faces, out)
        return True

    def _light_rows(self):
        """The lights as an (L, 8) array from the node world matrices in ``self._world``."""
        a = np.zeros((len(self._lights), LIGHT_COLUMNS))
        for k, lt in enumerate(self._lights):
            m = self._world[lt.node]
            if lt.kind == LIGHT_DIRECTIONAL:
                d = m[:3, 2]  # the node's +Z axis: the light shines along its local -Z
                n = float(np.linalg.norm(d))
                a[k, 1:4] = d / n if 0 < n < math.inf else (0.0, 0.0, 1.0)
            else:
                a[k, 1:4] = m[:3, 3]
            a[k, 0] = lt.kind
            a[k, 4:7] = lt.rgb
            a[k, 7] = lt.falloff
        return as_lights(a, f"{self.path.name} lights")

    def lights_at(self, t):
        """The scene's KHR_lights_punctual lights at time ``t`` (see the module's docstring): an
        (L, 8) float64 array in world coordinates, L = 0 without lights."""
        t = check_time(t)
        if not self._lights:
            return no_lights()
        if self._fixed_lights is not None:
            return self._fixed_lights
        self._update_world(self._clip_time(t))
        return self._light_rows()

    def vertices_at(self, t, origin=None):
        """A new (V, 3) float32 array of the posed vertices at time ``t`` (instances concatenated,
        in triangle order; in the frame of ``origin``, as :meth:`triangles_at`); the triangle
        buffer is left alone."""
        t = check_time(t)
        pose_moving_vertices(self, self._clip_time(t), as_origin(origin))
        return self._verts.copy()

    def bind_triangles(self):
        """A new (F, 3, 3) float32 array: the rest pose, without animation, skinning or morphing.

        Each instance's POSITION data moved by its node's rest world matrix (what static loaders
        such as trimesh show).
        """
        world = np.zeros_like(self._world)
        compose_world(self._order, self._parent, self._use_matrix, self._node_matrix, *self._rest, world)
        m = world[self._rig.node[self._vinst]]
        p = self._local.astype(np.float64)
        v = np.einsum("vij,vj->vi", m[:, :3, :3], p) + m[:, :3, 3]
        return np.ascontiguousarray(v.astype(TRI_DTYPE)[self._faces])

    def to_mesh(self, t=0.0):
        """The scene at time ``t`` as an indexed :class:`gridrt.scene.mesh.Mesh` (shared vertices kept),
        with :attr:`surface` (its normals those at ``t``)."""
        # posed in a frame centred on the scene, then moved back in float64: far from the origin the
        # mesh keeps the detail that float32 world coordinates would round away
        origin = self.frame_origin(t)
        v = self.vertices_at(t, origin=origin).astype(np.float64) + origin
        surface = self.surface
        if surface is not None and surface.normals is not None and not self.static:
            normals = self.normals_at(t, out=np.empty((self.n_triangles, 3, 3), TRI_DTYPE))
            surface = dataclasses.replace(surface, normals=normals)
        return Mesh(v, self._faces, name=self.path.stem, path=self.path, surface=surface)

    def camera_at(self, t):
        """The first perspective camera of the scene at time ``t`` (None when the file has none)."""
        t = check_time(t)
        if self._camera_node is None:
            return None
        node, fov = self._camera_node
        self._update_world(self._clip_time(t))
        m = self._world[node]
        eye = m[:3, 3]
        fwd = -m[:3, 2]
        up = m[:3, 1]
        if not (np.linalg.norm(fwd) > 0 and np.linalg.norm(up) > 0):
            return None
        return Camera(eye=tuple(eye), target=tuple(eye + fwd / np.linalg.norm(fwd)), up=tuple(up), fov=fov)
