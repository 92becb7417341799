"""The benchmarks' scenes: the spec text NAME[:N][:twist|wave] (NAME: a scene name of ``--scene``,
gridrt.scene.BUILTIN_SCENES, or a mesh or animation file), its parsing, which scenes are present,
the camera a benchmark looks at a scene with and that camera's rays (also moved in until the scene
fills the view)."""

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

import gridrt  # noqa: F401  (sets NUMBA_NUM_THREADS before numba loads)
from gridrt.camera import DEFAULT_FOV, Camera
from gridrt.config import GridParams
from gridrt.errors import InputError
from gridrt.grid.build import GridBuilder
from gridrt.scene import SceneSpec
from gridrt.scene.assets import ASSET_SCENES, DATA_DIR, DATA_HIDDEN, DATA_SCENES, scene_file, scene_present
from gridrt.scene.make import PROCEDURAL_SCENES, named_scene_file
from gridrt.trace.render import cast_rays

#: older names of two scenes, which the recorded benchmark commands use (BENCHMARKS.md,
#: results/*/machine.json): a spec may still say them; help and documents name the scenes as
#: ``--scene`` does
ALIASES = {"cesium": "cesium_man", "morphsphere": "morph_sphere"}

SCENE_HELP = ("comma-separated scene specs NAME[:N][:twist|wave]: a scene of --scene (" + ", ".join(PROCEDURAL_SCENES)
              + ": N = triangle count; " + ", ".join(ASSET_SCENES) + "; with the development data set beside the "
              "repository also " + ", ".join(DATA_SCENES) + ") or a mesh or animation file; N = subdivide a static "
              "mesh to at least N triangles; twist/wave deform a static mesh")


def scene_name(text):
    """The scene name (a key of gridrt.scene.BUILTIN_SCENES) a spec's NAME part stands for, an alias
    (:data:`ALIASES`) as the name it stands for; None for anything else (a file)."""
    key = text.strip().lower()
    key = ALIASES.get(key, key)
    return key if key in PROCEDURAL_SCENES or key in ASSET_SCENES or key in DATA_SCENES else None


def canonical_spec(spec):
    """A spec with its NAME as ``--scene`` spells it ("cesium:twist" -> "cesium_man:twist")."""
    base, *mods = spec.split(":")
    return ":".join([scene_name(base) or base.strip(), *mods])


def scenes_help(defaults, fallback):
    """--scenes help of a benchmark whose default scenes are ``defaults`` (those present) and
    ``fallback`` (when none of them is)."""
    return (f"{SCENE_HELP} (default: {', '.join(map(canonical_spec, defaults))}, those of them present; "
            f"{', '.join(map(canonical_spec, fallback))} when none is)")


@dataclass
class BenchScene:
    """A resolved scene spec: label (the spec text), the :class:`gridrt.scene.SceneSpec` it names,
    the Animation that spec made, and the file it came from (None for built-ins)."""

    label: str
    spec: object
    scene: object
    path: Path | None


def data_path(name):
    """The file behind a real scene's name (or alias): its shipped asset, or its file in the
    development data set; may not exist (see :func:`scene_available`)."""
    return scene_file(scene_name(name) or name)


def scene_available(spec):
    """True unless the spec names a real scene whose file is absent (one of the development data
    set's, where it is absent)."""
    name = scene_name(spec.split(":")[0])
    return name is None or name in PROCEDURAL_SCENES or scene_present(name)


def _count(text, spec):
    """'1600000', '1.6e6', '100k' or '1.6M' -> int."""
    t = text.strip().lower()
    mult = 1
    if t.endswith("k"):
        mult, t = 1000, t[:-1]
    elif t.endswith("m"):
        mult, t = 1000000, t[:-1]
    try:
        v = float(t) * mult
    except ValueError:
        raise InputError(f"scene spec {spec!r}: {text!r} is neither a triangle count nor twist/wave") from None
    if not math.isfinite(v) or v < 1 or v != int(v):
        raise InputError(f"scene spec {spec!r}: triangle count must be a positive integer, got {text!r}")
    return int(v)


def parse_scene_spec(spec):
    """(source, make_scene kwargs) for NAME[:N][:twist|wave]; see SCENE_HELP.  A real scene's name
    becomes its file (gridrt.scene.named_scene_file: InputError where a data set scene's is absent);
    a spec that is an existing file's path is that file."""
    text = spec.strip()
    if not text:
        raise InputError("empty scene spec")
    base, *mods = [m.strip() for m in text.split(":")]
    name = scene_name(base)
    if name is None and Path(text).exists():
        return text, {}
    kw = {}
    procedural = name in PROCEDURAL_SCENES
    src = name if procedural else base if name is None else named_scene_file(name)
    for m in mods:
        if m.lower() in ("twist", "wave"):
            kw["animate"] = m.lower()
        else:
            kw["count" if procedural else "subdivide"] = _count(m, spec)
    return str(src), kw


def scene_spec(text):
    """The :class:`gridrt.scene.SceneSpec` of a spec string (see SCENE_HELP)."""
    src, kw = parse_scene_spec(text)
    return SceneSpec(source=src, **kw)


def resolve_scene(text):
    """BenchScene for a spec string (see SCENE_HELP): its SceneSpec, made."""
    spec = scene_spec(text)
    p = Path(spec.source)
    return BenchScene(text.strip(), spec, spec.make(), p if p.exists() else None)


def scene_list(text, defaults, fallback, quick=None):
    """Scene specs from ``--scenes`` text, or the defaults whose data is present (``fallback``
    when none is), or ``quick`` in --quick mode.  Returns (specs, note or None)."""
    if text:
        return [s.strip() for s in text.split(",") if s.strip()], None
    if quick is not None:
        return list(quick), None
    defaults = [canonical_spec(s) for s in defaults]
    have = [s for s in defaults if scene_available(s)]
    missing = [s for s in defaults if not scene_available(s)]
    note = None
    if missing:
        where = "hidden: GRIDRT_NO_SHARED_DATA is set" if DATA_HIDDEN else f"absent from {DATA_DIR}"
        note = f"skipped ({where}): {', '.join(missing)}"
    if not have:
        return [canonical_spec(s) for s in fallback], note
    return have, note


def facing_camera(lo, hi, fov=DEFAULT_FOV):
    """Look along the box's thinnest axis (slightly tilted) so the mesh fills the view (``fov``: the
    camera's default field of view unless given)."""
    lo = np.asarray(lo, np.float64)
    hi = np.asarray(hi, np.float64)
    ext = hi - lo
    a = int(np.argmin(ext))
    d = np.full(3, 0.15)
    d[a] = 1.0
    up = (0.0, 1.0, 0.0) if a != 1 else (0.0, 0.0, 1.0)
    big = float(np.sort(ext)[1:].max())
    dist = 0.5 * big / math.tan(math.radians(fov) / 2) * 1.05 + 0.5 * ext[a]
    c = 0.5 * (lo + hi)
    d = d / np.linalg.norm(d)
    return Camera(eye=tuple(c + d * dist), target=tuple(c), up=up, fov=fov)


def seen_through(spec, cam):
    """The FrameSpec ``spec`` with its view's explicit camera set to the Camera ``cam`` (its eye,
    target, up and fov)."""
    return spec.replace(view=spec.view.replace(eye=cam.eye, target=cam.target, up=cam.up, fov=cam.fov))


def scene_camera(scene, tris, t=0.0, origin=None):
    """The scene's own camera at time t (BART, glTF) where it has one, else facing_camera over
    the bounds of tris (F,3,3); ``origin``: the frame tris are in (the scene's camera is moved
    there)."""
    cam = None
    if hasattr(scene, "camera_at"):
        try:
            cam = scene.camera_at(float(t))
        except (AttributeError, NotImplementedError):
            cam = None
        if cam is not None and origin is not None:
            cam = cam.moved(-np.asarray(origin, np.float64))
    if cam is None:
        v = np.asarray(tris).reshape(-1, 3)
        cam = facing_camera(v.min(axis=0), v.max(axis=0))
    return cam


#: the hit fraction a "fill" view reaches at least
FILL = 0.9


def fill_camera(tris, cam, probe=64):
    """``cam`` moved towards its target, 24 steps of 0.85x the distance at most, to the first eye from
    which at least FILL of a probe x probe image hits ``tris`` (the scene at time 0; or the closest
    step)."""
    g = GridBuilder(GridParams()).build(tris)
    eye, target = np.asarray(cam.eye), np.asarray(cam.target)
    for k in range(25):
        c = dataclasses.replace(cam, eye=tuple(target + (eye - target) * 0.85 ** k))
        po, pd = c.rays(probe, probe)
        if (cast_rays(g, tris, po, pd).tri >= 0).mean() >= FILL:
            break
    return c


def camera_rays(sc, size, fill=False):
    """(frame origin, camera, float32 origins and directions, the same as float64) of a scene: both
    tracers get the scene in the frame the pipeline uses and the same float32-rounded camera rays;
    ``fill``: from the camera moved in until the scene fills the view (fill_camera)."""
    origin = sc.scene.frame_origin(0.0)
    tris0 = np.array(sc.scene.triangles_at(0.0, origin=origin))
    cam = scene_camera(sc.scene, tris0, origin=origin)
    if fill:
        cam = fill_camera(tris0, cam)
    o, d = cam.rays(size, size)
    o32 = np.ascontiguousarray(o, np.float32)
    d32 = np.ascontiguousarray(d, np.float32)
    return origin, cam, o32, d32, o32.astype(np.float64), d32.astype(np.float64)
