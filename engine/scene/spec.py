"""SceneSpec: what scene to load, as one value (the CLI's scene options, the viewer's scene, the
render worker's load job, a benchmark's scene spec) with :meth:`SceneSpec.make` to load it."""

from dataclasses import dataclass, fields, replace

from ..checks import check_finite
from ..errors import InputError
from .make import make_scene


def _number(name, v, optional=True):
    """``v`` as a finite float (None kept when ``optional``); InputError naming the field otherwise."""
    if v is None and optional:
        return None
    return check_finite(f"scene {name}", v)


def _integer(name, v, optional=True):
    """``v`` as an int (None kept when ``optional``); InputError naming the field otherwise."""
    if v is None and optional:
        return None
    if isinstance(v, bool) or not hasattr(v, "__index__"):
        raise InputError(f"scene {name} must be an integer, got {v!r}")
    return int(v)


@dataclass(frozen=True)
class SceneSpec:
    """A built-in scene name or a scene file / frame folder, with :func:`make_scene`'s options
    (see there for what each means; None leaves the scene's own default).

    source     built-in scene name (:data:`BUILTIN_SCENES`), scene file or frame folder
    count      triangles of the marbles and icosphere scenes
    animate    "twist" or "wave": deform a static mesh over time
    amplitude  deformation amplitude in scene units
    speed      animation speed factor
    seed       random seed of procedural scenes
    clip       animation clip (glTF animation or MD2 clip) by name or index
    subdivide  split a static mesh's triangles 1->4 until at least this many
    fps        keyframe rate of MD2 models and frame folders
    allow_outside  trust the files a scene file names outside its folder (gridrt.scene.files)
    """

    source: str = "marbles"
    count: int | None = None
    animate: str | None = None
    amplitude: float | None = None
    speed: float = 1.0
    seed: int = 0
    clip: int | str | None = None
    subdivide: int | None = None
    fps: float | None = None
    allow_outside: bool = False

    def __post_init__(self):
        object.__setattr__(self, "source", str(self.source))
        if isinstance(self.clip, str) and self.clip.isdigit():
            object.__setattr__(self, "clip", int(self.clip))  # "2" on a command line is clip index 2
        elif self.clip is not None and not isinstance(self.clip, str):
            object.__setattr__(self, "clip", _integer("clip", self.clip))
        if self.animate is not None and not isinstance(self.animate, str):
            raise InputError(f"scene animate must be a name, got {self.animate!r}")
        for name in ("count", "subdivide"):
            object.__setattr__(self, name, _integer(name, getattr(self, name)))
        object.__setattr__(self, "seed", _integer("seed", self.seed, optional=False))
        for name in ("amplitude", "fps"):
            object.__setattr__(self, name, _number(name, getattr(self, name)))
        object.__setattr__(self, "speed", _number("speed", self.speed, optional=False))
        if not isinstance(self.allow_outside, bool):
            raise InputError(f"scene allow_outside must be true or false, got {self.allow_outside!r}")

    def options(self):
        """The make_scene keyword arguments this spec sets (fields other than source that
        differ from their defaults)."""
        base = SceneSpec()
        return {f.name: getattr(self, f.name) for f in fields(self)
                if f.name != "source" and getattr(self, f.name) != getattr(base, f.name)}

    def make(self):
        """Load the scene: :func:`gridrt.scene.make_scene` with these options."""
        return make_scene(self.source, count=self.count, animate=self.animate, amplitude=self.amplitude,
                          speed=self.speed, seed=self.seed, clip=self.clip, subdivide=self.subdivide, fps=self.fps,
                          allow_outside=self.allow_outside)

    def label(self):
        return self.source if self.count is None else f"{self.source} ({self.count} triangles)"

    def replace(self, **kw):
        return replace(self, **kw)
