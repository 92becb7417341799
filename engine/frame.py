"""FrameSpec: the one description of what to render, as one frozen value.

A FrameSpec holds the scene (:class:`gridrt.scene.SceneSpec`), how to grid it (:class:`GridParams`),
how to cast and shade it (:class:`RenderParams`) and how to look at it over time (:class:`ViewSpec`).
The command line builds one from its arguments, the viewer holds one and changes it with
``dataclasses.replace``, the dump and :class:`gridrt.pipeline.FramePipeline` take one, and a Dask
cluster ships one as :meth:`FrameSpec.to_wire` (a plain JSON-able dict, versioned) that its workers
read back with :meth:`FrameSpec.from_wire`, which checks every field before constructing anything.
"""

import math
import types
import typing
from dataclasses import dataclass, field, fields, replace

import numpy as np

from .camera import DEFAULT_FOV, DEFAULT_UP, Camera, check_fov, check_up
from .checks import check_finite
from .config import GridParams, RenderParams
from .errors import InputError
from .scene.spec import SceneSpec

#: the name a wire dict carries in its "format" key
WIRE_FORMAT = "gridrt.FrameSpec"
#: the version of the wire format this gridrt writes and reads (a dict of another version is refused)
WIRE_VERSION = 1


def _point(name, v):
    """``v`` as a tuple of 3 finite floats, or None."""
    if v is None:
        return None
    try:
        p = tuple(float(x) for x in v)
    except (TypeError, ValueError):
        raise InputError(f"view {name} must be 3 numbers, got {v!r}") from None
    if len(p) != 3 or not all(math.isfinite(x) for x in p):
        raise InputError(f"view {name} must be 3 finite numbers, got {v!r}")
    return p


def _size(v):
    try:
        w, h = v
    except (TypeError, ValueError):
        raise InputError(f"view size must be (width, height), got {v!r}") from None
    return (_whole("view width", w), _whole("view height", h))


def _whole(name, v):
    if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, np.integer)):
        raise InputError(f"{name} must be an integer, got {v!r}")
    if v < 1:
        raise InputError(f"{name} must be >= 1, got {v}")
    return int(v)


@dataclass(frozen=True)
class ViewSpec:
    """How to look at the scene, and when.

    eye, target    the camera's position and look-at point (3 floats each), both or neither;
                   neither: the scene's own camera with ``follow_camera``, else a camera that
                   frames the scene's bounds at the first frame (:meth:`gridrt.camera.Camera.frame`)
    fov            vertical field of view in degrees, in (0, 180)
    up             the camera's up vector (3 floats, not zero)
    follow_camera  look through the scene's own animated camera (BART, glTF) where it has one
    split_static   grid a scene's static triangles once and its moving ones every frame (else
                   the whole scene every frame)
    t0, dt         the time of the first frame and the step between frames, seconds
    size           the image's (width, height) in pixels (:class:`FrameSpec` keeps its
                   RenderParams at this size)
    """

    eye: tuple | None = None
    target: tuple | None = None
    fov: float = DEFAULT_FOV
    up: tuple = DEFAULT_UP
    follow_camera: bool = False
    split_static: bool = True
    t0: float = 0.0
    dt: float = 1.0 / 30.0
    size: tuple = (RenderParams.width, RenderParams.height)

    def __post_init__(self):
        eye, target = _point("eye", self.eye), _point("target", self.target)
        if (eye is None) != (target is None):
            raise InputError("an explicit camera needs both an eye and a target (--eye and --target)")
        object.__setattr__(self, "eye", eye)
        object.__setattr__(self, "target", target)
        object.__setattr__(self, "fov", check_fov(self.fov))
        object.__setattr__(self, "up", check_up(self.up))
        for name in ("follow_camera", "split_static"):
            v = getattr(self, name)
            if not isinstance(v, (bool, np.bool_)):
                raise InputError(f"view {name} must be true or false, got {v!r}")
            object.__setattr__(self, name, bool(v))
        object.__setattr__(self, "t0", check_finite("view t0", self.t0))
        object.__setattr__(self, "dt", check_finite("view dt", self.dt))
        object.__setattr__(self, "size", _size(self.size))
        self.camera()  # (an eye on its target, an up along the view: refused here)

    def camera(self):
        """The explicit Camera (eye, target, up, fov), or None when the view has none."""
        if self.eye is None:
            return None
        return Camera(eye=self.eye, target=self.target, up=self.up, fov=self.fov)

    def time(self, i):
        """The time of frame ``i``: ``t0 + i * dt``."""
        return self.t0 + i * self.dt

    def replace(self, **kw):
        return replace(self, **kw)


@dataclass(frozen=True)
class FrameSpec:
    """What to render: ``scene`` (SceneSpec), ``grid`` (GridParams), ``render`` (RenderParams) and
    ``view`` (ViewSpec).  The image size is ``view.size``; ``render``'s width and height must
    equal it (:meth:`resized` changes both).  Construction validates every part (InputError
    naming the field); ``dataclasses.replace`` and :meth:`replace` give a changed copy, validated
    again."""

    scene: SceneSpec = field(default_factory=SceneSpec)
    grid: GridParams = field(default_factory=GridParams)
    render: RenderParams = field(default_factory=RenderParams)
    view: ViewSpec = field(default_factory=ViewSpec)

    def __post_init__(self):
        for f in fields(self):
            v = getattr(self, f.name)
            if not isinstance(v, _PARTS[f.name]):
                raise InputError(f"FrameSpec.{f.name} must be a {_PARTS[f.name].__name__}, got {type(v).__name__}")
        if (self.render.width, self.render.height) != self.view.size:
            raise InputError(f"FrameSpec: render size {self.render.width}x{self.render.height} differs from view size "
                             f"{self.view.size[0]}x{self.view.size[1]} (FrameSpec.resized changes both)")

    @property
    def size(self):
        """(width, height) of the image."""
        return self.view.size

    def resized(self, width, height):
        """The same spec for a ``width`` x ``height`` image."""
        return replace(self, render=self.render.replace(width=width, height=height),
                       view=self.view.replace(size=(width, height)))

    def replace(self, **kw):
        return replace(self, **kw)

    def camera(self):
        """The view's explicit Camera, or None (the scene's own camera, or automatic framing)."""
        return self.view.camera()

    # ---- the wire format -----------------------------------------------------------------------
    def to_wire(self):
        """This spec as a plain dict of JSON values: ``{"format": WIRE_FORMAT, "version":
        WIRE_VERSION, "scene": {...}, "grid": {...}, "render": {...}, "view": {...}}``, each part
        a dict of its fields (tuples as lists)."""
        out = {"format": WIRE_FORMAT, "version": WIRE_VERSION}
        for f in fields(self):
            value = getattr(self, f.name)
            out[f.name] = {g.name: _plain(getattr(value, g.name)) for g in fields(value)}
        return out

    @classmethod
    def from_wire(cls, d):
        """The FrameSpec of a dict written by :meth:`to_wire` (e.g. after a JSON round trip), checked
        on arrival: its format and version (another version, older or newer, is refused naming
        both), no unknown or missing part, no unknown field, each field's JSON type, and then its
        value by the parts' own constructors.  Any problem is an InputError of one line."""
        if not isinstance(d, dict):
            raise InputError(f"a FrameSpec on the wire must be a dict, got {type(d).__name__}")
        if d.get("format") != WIRE_FORMAT:
            raise InputError(f"not a FrameSpec: format {d.get('format')!r}, expected {WIRE_FORMAT!r}")
        version = d.get("version")
        if isinstance(version, bool) or not isinstance(version, int):
            raise InputError(f"FrameSpec wire version must be an integer, got {version!r}")
        if version != WIRE_VERSION:
            age = "older" if version < WIRE_VERSION else "newer"
            raise InputError(f"FrameSpec wire version {version} is {age} than this gridrt's version {WIRE_VERSION}: "
                             "run the same gridrt on both sides")
        names = [f.name for f in fields(cls)]
        unknown = sorted(set(d) - {"format", "version", *names})
        if unknown:
            raise InputError(f"FrameSpec wire dict has unknown keys: {', '.join(map(str, unknown))}")
        parts = {}
        for name in names:
            if name not in d:
                raise InputError(f"FrameSpec wire dict has no {name!r} part")
            parts[name] = _part_from_wire(name, _PARTS[name], d[name])
        return cls(**parts)


_PARTS = {"scene": SceneSpec, "grid": GridParams, "render": RenderParams, "view": ViewSpec}


def _plain(v):
    """A field's value as JSON values (tuples as lists, numpy scalars as Python's)."""
    if isinstance(v, (tuple, list)):
        return [_plain(x) for x in v]
    if isinstance(v, np.generic):
        return v.item()
    return v


def _part_from_wire(name, cls, d):
    """``cls(**d)`` for the part ``name`` of a wire dict, each field's JSON type checked first."""
    if not isinstance(d, dict):
        raise InputError(f"FrameSpec wire part {name!r} must be a dict, got {type(d).__name__}")
    hints = typing.get_type_hints(cls)
    known = {f.name for f in fields(cls)}
    unknown = sorted(set(d) - known, key=str)
    if unknown:
        raise InputError(f"FrameSpec wire part {name!r} has unknown keys: {', '.join(map(str, unknown))}")
    for key, v in d.items():
        if not _json_fits(v, hints[key]):
            raise InputError(f"FrameSpec wire field {name}.{key} must be {_describe(hints[key])}, got {v!r}")
    return cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in d.items()})


def _options(hint):
    if isinstance(hint, types.UnionType) or typing.get_origin(hint) is typing.Union:
        return typing.get_args(hint)
    return (hint,)


def _json_fits(v, hint):
    """True when the JSON value ``v`` has a type the field's annotation ``hint`` allows (float
    takes an integer; a tuple is a list of numbers)."""
    for t in _options(hint):
        if t is type(None) and v is None:
            return True
        if t is bool and isinstance(v, bool):
            return True
        if t is int and isinstance(v, int) and not isinstance(v, bool):
            return True
        if t is float and isinstance(v, (int, float)) and not isinstance(v, bool):
            return True
        if t is str and isinstance(v, str):
            return True
        if t is tuple and isinstance(v, list) and all(isinstance(x, (int, float)) and not isinstance(x, bool)
                                                      for x in v):
            return True
    return False


def _describe(hint):
    words = {type(None): "null", bool: "true/false", int: "an integer", float: "a number", str: "a string",
             tuple: "a list of numbers"}
    return " or ".join(words.get(t, getattr(t, "__name__", str(t))) for t in _options(hint))
