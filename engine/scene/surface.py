"""What a scene's triangles look like: materials, textures, per-corner attributes and lights.

A scene that carries its looks has a :class:`Surface` (``Animation.surface``), fixed in time:

* ``material`` (F,) int32: each triangle's row in the material table, whose rows are
  ``diffuse`` (M, 3) and ``ambient`` (M, 3) float32 colours and ``texture`` (M,) int32 (an index
  into ``textures``, -1: none);
* ``uv`` (F, 3, 2) float32 texture coordinates per triangle corner, in the image's convention:
  (0, 0) is the top-left corner of the image, u goes right and v goes down (glTF's, BART's and
  MD2's convention; OBJ's v goes up, and its loader stores ``1 - v``); None when the file has none;
* ``colors`` (F, 3, 3) float32 vertex colours per corner (multiplying the material's), or None;
* ``normals`` (F, 3, 3) float32 unit shading normals per corner at rest, or None.  A zero
  normal means "the geometric normal" (a part of a scene whose file has no normals).  An
  animated scene's normals at time t are ``Animation.normals_at(t)``.

Colours are display values in [0, 1] (texels are bytes / 255), as the rest of gridrt's
shading: no gamma is applied on the way in or out.  The ``material`` shading mode (see
gridrt.trace.material) colours a hit

    c = T(uv) * V * (A + D * sum_l E_l * vis_l * max(0, n . l_l))

with T the bilinearly filtered texel (1 without a texture), V the interpolated vertex colour,
A and D the material's ambient and diffuse colours, n the interpolated shading normal, and per
light l_l the unit vector to it, E_l its colour at the hit and vis_l its shadow test.

Lights are a (L, LIGHT_COLUMNS) float64 array (``Animation.lights_at(t)``, world coordinates):
one row ``kind, x, y, z, r, g, b, falloff`` per light, kind LIGHT_POINT (x, y, z its position) or
LIGHT_DIRECTIONAL (x, y, z the unit vector towards the light), r, g, b its colour and falloff
FALLOFF_NONE (E = colour, BART) or FALLOFF_INVERSE_SQUARE (E = colour / d^2, glTF's
KHR_lights_punctual point lights, colour = colour * intensity in candela).
"""

import contextlib
import contextvars
import re
import warnings
from dataclasses import dataclass, field
from io import BytesIO

import numpy as np

from ..errors import InputError
from .files import open_regular, os_problem

__all__ = [
    "AMBIENT_FRACTION", "DEFAULT_DIFFUSE", "FALLOFF_INVERSE_SQUARE", "FALLOFF_NONE", "LIGHT_COLUMNS", "LIGHT_DIRECTIONAL", "LIGHT_POINT", "WRAP_MODES",
    "MAX_TEXTURE_PIXELS",
    "PackedSurface", "Surface", "SurfaceBuilder", "Texture", "TextureWarning", "as_lights", "load_texture", "no_lights",
    "texture_progress",
]

#: the default material's diffuse colour (triangles a file gives no material, files whose only looks
#: are normals): gridrt's grey, the same as gridrt.trace.shade.ALBEDO (a test keeps them equal)
DEFAULT_DIFFUSE = (0.85, 0.78, 0.66)
#: a material's ambient colour as a fraction of its diffuse colour where the file has no ambient
#: term of its own (NFF ``f``, MTL, glTF, MD2, the default material): the same fraction as the
#: ``lambert`` mode's ambient term (gridrt.trace.shade.AMBIENT)
AMBIENT_FRACTION = 0.15
#: texture wrap modes: glTF's REPEAT (10497), CLAMP_TO_EDGE (33071), MIRRORED_REPEAT (33648)
WRAP_MODES = {"repeat": 0, "clamp": 1, "mirror": 2}
LIGHT_POINT = 0.0
LIGHT_DIRECTIONAL = 1.0
FALLOFF_NONE = 0.0
FALLOFF_INVERSE_SQUARE = 1.0
LIGHT_COLUMNS = 8


class TextureWarning(UserWarning):
    """A texture could not be read (missing, unreadable or not an image), or a file the looks come
    from (an MTL library, a material name, an MD2 skin) is missing: the scene loads without it."""


#: the Pillow formats load_texture reads
TEXTURE_FORMATS = ("PNG", "JPEG", "PPM", "BMP", "PCX", "TGA", "GIF", "TIFF", "WEBP")

#: the most pixels a texture may have: a larger image (a "decompression bomb" among them: a few
#: bytes that decode to gigabytes) is dropped with a TextureWarning before it is decoded
MAX_TEXTURE_PIXELS = 8192 * 8192

_progress = contextvars.ContextVar("texture_progress", default=None)


@contextlib.contextmanager
def texture_progress(callback):
    """Within the block, :func:`load_texture` calls ``callback(name, nbytes)`` after each texture it
    reads (the viewer's loading display)."""
    token = _progress.set(callback)
    try:
        yield
    finally:
        _progress.reset(token)


def load_texture(path, wrap=("repeat", "repeat"), data=None, name=None):
    """Read an image file (PNG, JPEG, PPM/PGM, BMP, PCX, ... whatever Pillow reads) or the bytes
    ``data`` of one (embedded images) into a :class:`Texture`; None, with a :class:`TextureWarning`
    naming the file and the problem, when it cannot be read: missing, not a regular file (a FIFO
    or a device is never opened for reading), not an image, or larger than
    :data:`MAX_TEXTURE_PIXELS` (checked from the image's header, before decoding)."""
    from PIL import Image, UnidentifiedImageError  # deferred: Pillow, for textures only

    label = name or (str(path) if path is not None else "embedded image")

    def drop(problem):
        warnings.warn(f"texture {label}: {problem}; drawn without it", TextureWarning, stacklevel=3)

    try:
        with contextlib.ExitStack() as stack:
            fh = BytesIO(data)
            if data is None:
                try:
                    fh = stack.enter_context(open_regular(path))[0]
                except OSError as e:
                    return drop(os_problem(e))
            with warnings.catch_warnings():
                warnings.simplefilter("error", Image.DecompressionBombWarning)  # (refused below as one)
                # only the image formats scene files use: a plugin another library registers must not take
                # a file that is no image for one
                im = stack.enter_context(Image.open(fh, formats=TEXTURE_FORMATS))
            w, h = im.size
            if w * h > MAX_TEXTURE_PIXELS:
                return drop(_too_large(f"{w} x {h} pixels"))
            im.load()
            if im.mode != "RGB":  # (a palette with transparency goes through RGBA, as Pillow asks)
                im = im.convert("RGBA" if im.mode == "P" and "transparency" in im.info else "RGB")
            rgb = np.asarray(im)
    except (Image.DecompressionBombError, Image.DecompressionBombWarning) as e:
        m = re.search(r"\((\d+) pixels\)", str(e))
        return drop(_too_large(f"{int(m.group(1)):,} pixels" if m else "its size"))
    except (OSError, UnidentifiedImageError, ValueError, SyntaxError, MemoryError) as e:
        # (bytes Pillow quotes from the file, such as a chunk name, are left out: the file may be no scene's)
        return drop(f"not a readable image ({_QUOTED_BYTES.sub('[bytes of the file]', str(e))})")
    tex = Texture(rgb, wrap, label)
    cb = _progress.get()
    if cb is not None:
        cb(label, tex.nbytes)
    return tex


_QUOTED_BYTES = re.compile(r"b'(?:[^'\\]|\\.)*'" + r'|b"(?:[^"\\]|\\.)*"')  # a Python bytes repr


def _too_large(size):
    return (f"image of {size}, more than the limit of {MAX_TEXTURE_PIXELS:,} pixels "
            f"(gridrt.scene.surface.MAX_TEXTURE_PIXELS)")


@dataclass(frozen=True, eq=False)
class Texture:
    """An RGB image: ``texels`` (H, W, 3) uint8, row 0 the top of the image; ``wrap`` the
    (u, v) wrap modes, keys of :data:`WRAP_MODES`; ``name`` for messages (usually the file)."""

    texels: np.ndarray
    wrap: tuple = ("repeat", "repeat")
    name: str = "texture"

    def __post_init__(self):
        a = np.asarray(self.texels)
        if a.ndim == 2:
            a = np.repeat(a[:, :, None], 3, axis=2)
        if a.ndim != 3 or a.shape[2] not in (3, 4) or a.shape[0] < 1 or a.shape[1] < 1:
            raise InputError(f"texture {self.name!r}: texels must be (H, W, 3) (or RGBA, or grey), got {a.shape}")
        if a.dtype != np.uint8:
            raise InputError(f"texture {self.name!r}: texels must be uint8, got {a.dtype}")
        a = np.array(a[:, :, :3], order="C")  # a copy: the caller's array is never frozen
        a.setflags(write=False)
        object.__setattr__(self, "texels", a)
        wrap = tuple(self.wrap)
        if len(wrap) != 2 or any(w not in WRAP_MODES for w in wrap):
            raise InputError(f"texture {self.name!r}: wrap must be two of {', '.join(WRAP_MODES)}, got {self.wrap!r}")
        object.__setattr__(self, "wrap", wrap)

    @property
    def nbytes(self):
        return int(self.texels.nbytes)


def _per_corner(a, F, k, what):
    if a is None:
        return None
    a = np.asarray(a)
    if a.shape != (F, 3, k) or a.dtype.kind not in "fiu":
        raise InputError(f"surface {what} must be ({F}, 3, {k}) numbers, got {a.shape} {a.dtype}")
    a = np.array(a, np.float32, order="C")  # a copy: the caller's array is never frozen
    if not np.isfinite(a).all():
        raise InputError(f"surface {what} contain NaN or infinity")
    a.setflags(write=False)
    return a


@dataclass(frozen=True, eq=False)
class Surface:
    """A scene's materials and per-corner attributes (see the module's docstring); validated and
    frozen on construction (InputError names the problem)."""

    material: np.ndarray
    diffuse: np.ndarray
    ambient: np.ndarray
    texture: np.ndarray
    textures: tuple = ()
    uv: np.ndarray | None = None
    colors: np.ndarray | None = None
    normals: np.ndarray | None = None
    packed: "PackedSurface" = field(default=None, init=False, repr=False)

    def __post_init__(self):
        mat = np.ascontiguousarray(self.material)
        if mat.ndim != 1 or mat.dtype.kind not in "iu":
            raise InputError(f"surface material must be (F,) integers, got {mat.shape} {mat.dtype}")
        F = len(mat)
        mat = mat.astype(np.int32)  # (a copy)
        cols = []
        for name in ("diffuse", "ambient"):
            c = np.asarray(getattr(self, name))
            if c.ndim != 2 or c.shape[1] != 3 or c.dtype.kind not in "fiu":
                raise InputError(f"surface {name} must be (M, 3) colours, got {c.shape} {c.dtype}")
            c = np.array(c, np.float32, order="C")
            if not np.isfinite(c).all() or (c < 0).any():
                raise InputError(f"surface {name} colours must be finite and >= 0")
            cols.append(c)
        M = len(cols[0])
        tex = np.ascontiguousarray(self.texture)
        if tex.shape != (M,) or tex.dtype.kind not in "iu" or cols[1].shape[0] != M:
            raise InputError(f"surface: diffuse {cols[0].shape}, ambient {cols[1].shape} and texture {tex.shape} "
                             "must have one row per material")
        tex = tex.astype(np.int32)  # (a copy)
        textures = tuple(self.textures)
        if not all(isinstance(t, Texture) for t in textures):
            raise InputError("surface textures must be Texture objects")
        if M == 0:
            raise InputError("surface has no materials")
        if F and (mat.min() < 0 or mat.max() >= M):
            raise InputError(f"surface material index out of range [0, {M})")
        if M and (tex.min() < -1 or tex.max() >= len(textures)):
            raise InputError(f"surface texture index out of range [-1, {len(textures)})")
        for a in (mat, cols[0], cols[1], tex):
            a.setflags(write=False)
        object.__setattr__(self, "material", mat)
        object.__setattr__(self, "diffuse", cols[0])
        object.__setattr__(self, "ambient", cols[1])
        object.__setattr__(self, "texture", tex)
        object.__setattr__(self, "textures", textures)
        object.__setattr__(self, "uv", _per_corner(self.uv, F, 2, "uv"))
        object.__setattr__(self, "colors", _per_corner(self.colors, F, 3, "colors"))
        object.__setattr__(self, "normals", _per_corner(self.normals, F, 3, "normals"))
        if (tex >= 0).any() and self.uv is None:
            raise InputError("surface has textured materials but no uv coordinates")
        object.__setattr__(self, "packed", PackedSurface.of(self))

    @property
    def n_triangles(self):
        return int(len(self.material))

    @property
    def n_materials(self):
        return int(len(self.diffuse))

    @property
    def has_materials(self):
        """True when the file gave the triangles looks of their own: a texture, vertex colours, or a
        material other than a default one (gridrt's grey DEFAULT_DIFFUSE, or glTF's white, each with
        AMBIENT_FRACTION of it as ambient).  A surface of normals only has none (see
        :attr:`has_looks`)."""
        if self.textured or self.colors is not None:
            return True
        for d in (DEFAULT_DIFFUSE, (1.0, 1.0, 1.0)):
            dd = np.asarray(d, np.float32)
            if np.allclose(self.diffuse, dd, atol=1e-6) and np.allclose(self.ambient, np.float32(AMBIENT_FRACTION) * dd,
                                                                            atol=1e-6):
                return False
        return True

    @property
    def has_looks(self):
        """True when the file gave the triangles anything the ``material`` shading shows and
        ``lambert`` does not: materials (:attr:`has_materials`) or smooth normals.  Shading "auto"
        is "material" for such a surface."""
        return self.has_materials or self.normals is not None

    @property
    def textured(self):
        return bool((self.texture >= 0).any())

    @property
    def texture_bytes(self):
        return sum(t.nbytes for t in self.textures)

    @property
    def bytes_per_triangle(self):
        """Bytes of per-triangle data: the material index and the per-corner attributes present."""
        return 4 + sum(a[0].nbytes for a in (self.uv, self.colors, self.normals) if a is not None and len(a))

    def subset(self, ids):
        """The surface of the triangles ``ids`` (in that order), sharing the material table."""
        ids = np.asarray(ids, np.int64)
        pick = (lambda a: None if a is None else a[ids])
        return Surface(self.material[ids], self.diffuse, self.ambient, self.texture, self.textures,
                       pick(self.uv), pick(self.colors), pick(self.normals))

    @classmethod
    def plain(cls, n_triangles, diffuse, ambient):
        """One material of the given colours for every triangle, no textures or attributes."""
        return cls(np.zeros(n_triangles, np.int32), np.asarray([diffuse], np.float32),
                   np.asarray([ambient], np.float32), np.full(1, -1, np.int32))


@dataclass(frozen=True, eq=False)
class PackedSurface:
    """A Surface as the kernels take it: empty arrays stand for absent attributes.

    tex_data (sum of H*W*3,) uint8: every texture's texels one after the other;
    tex_info (T, 5) int64: offset into tex_data, width, height, wrap u, wrap v (WRAP_MODES values)."""

    material: np.ndarray
    diffuse: np.ndarray
    ambient: np.ndarray
    texture: np.ndarray
    tex_data: np.ndarray
    tex_info: np.ndarray
    uv: np.ndarray
    colors: np.ndarray

    @classmethod
    def of(cls, s):
        sizes = [t.texels.size for t in s.textures]
        offs = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64) if sizes else np.zeros(1, np.int64)
        data = np.concatenate([t.texels.ravel() for t in s.textures]) if sizes else np.zeros(0, np.uint8)
        info = np.array([[offs[i], t.texels.shape[1], t.texels.shape[0], WRAP_MODES[t.wrap[0]], WRAP_MODES[t.wrap[1]]]
                         for i, t in enumerate(s.textures)], np.int64).reshape(-1, 5)
        return cls(s.material, s.diffuse, s.ambient, s.texture, data, info,
                   s.uv if s.uv is not None else np.zeros((0, 3, 2), np.float32),
                   s.colors if s.colors is not None else np.zeros((0, 3, 3), np.float32))


class SurfaceBuilder:
    """Assembles a Surface from the pieces of a scene file, in triangle order.

    ``add(n, diffuse, ambient, texture=None, uv=None, colors=None, normals=None)`` appends n
    triangles of one material (colours (3,), texture a :class:`Texture` or None; identical
    materials and textures (the same object or the same ``name``) share one row); absent per-corner
    attributes are filled with zeros (uv, normals: "the geometric normal") or ones (colours) where
    another piece has them.  ``build()`` returns the Surface (None when nothing was added)."""

    def __init__(self):
        self._mats = {}
        self._tex = {}
        self._textures = []
        self._material = []
        self._attrs = {"uv": [], "colors": [], "normals": []}
        self._n = 0

    def texture_index(self, texture):
        if texture is None:
            return -1
        key = texture.name if texture.name != "texture" else id(texture)
        if key not in self._tex:
            self._tex[key] = len(self._textures)
            self._textures.append(texture)
        return self._tex[key]

    def material_index(self, diffuse, ambient, texture=None):
        ti = self.texture_index(texture)
        key = (tuple(np.float32(np.asarray(diffuse, np.float64)).tolist()),
               tuple(np.float32(np.asarray(ambient, np.float64)).tolist()), ti)
        if len(key[0]) != 3 or len(key[1]) != 3:
            raise InputError("material colours must be 3 numbers")
        return self._mats.setdefault(key, len(self._mats))

    def add(self, n, diffuse, ambient, texture=None, uv=None, colors=None, normals=None, material=None):
        """Append n triangles; ``material`` (an index from :meth:`material_index`) overrides the colours."""
        m = self.material_index(diffuse, ambient, texture) if material is None else int(material)
        self._material.append(np.full(n, m, np.int32))
        for name, a, k in (("uv", uv, 2), ("colors", colors, 3), ("normals", normals, 3)):
            self._attrs[name].append((self._n, None if a is None else np.asarray(a, np.float32).reshape(n, 3, k)))
        self._n += n

    def build(self):
        if not self._n:
            return None
        table = sorted(self._mats.items(), key=lambda kv: kv[1])
        diffuse = np.array([k[0] for k, _ in table], np.float32).reshape(-1, 3)
        ambient = np.array([k[1] for k, _ in table], np.float32).reshape(-1, 3)
        texture = np.array([k[2] for k, _ in table], np.int32)
        out = {}
        for name, k, fill in (("uv", 2, 0.0), ("colors", 3, 1.0), ("normals", 3, 0.0)):
            parts = self._attrs[name]
            if all(a is None for _, a in parts):
                out[name] = None
                continue
            a = np.full((self._n, 3, k), fill, np.float32)
            for start, p in parts:
                if p is not None:
                    a[start:start + len(p)] = p
            out[name] = a
        return Surface(np.concatenate(self._material), diffuse, ambient, texture, tuple(self._textures), **out)


def as_lights(lights, what="lights"):
    """Validate a (L, LIGHT_COLUMNS) light array; return it as float64 (C-contiguous, read-only)."""
    a = np.asarray(lights if lights is not None else np.zeros((0, LIGHT_COLUMNS)), np.float64)
    if a.ndim != 2 or a.shape[1] != LIGHT_COLUMNS:
        raise InputError(f"{what} must be an (L, {LIGHT_COLUMNS}) array, got {a.shape}")
    if not np.isfinite(a).all():
        raise InputError(f"{what} contain NaN or infinity")
    if len(a) and (not np.isin(a[:, 0], (LIGHT_POINT, LIGHT_DIRECTIONAL)).all()
                   or not np.isin(a[:, 7], (FALLOFF_NONE, FALLOFF_INVERSE_SQUARE)).all() or (a[:, 4:7] < 0).any()):
        raise InputError(f"{what}: unknown kind or falloff, or a negative colour")
    d = a[a[:, 0] == LIGHT_DIRECTIONAL, 1:4]
    if len(d) and (np.abs(np.linalg.norm(d, axis=1) - 1.0) > 1e-6).any():
        raise InputError(f"{what}: a directional light's direction must be a unit vector")
    a = np.ascontiguousarray(a)
    a.setflags(write=False)
    return a


def no_lights():
    return as_lights(None)
