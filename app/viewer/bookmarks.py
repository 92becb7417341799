"""The camera as command-line flags (the V key prints them: ``gridrt view`` or ``gridrt dump``
with them renders the same view) and camera bookmarks: Ctrl+1..9 keeps the view in slot 1..9 of
the scene on screen, 1..9 returns to it, and the slots are remembered across runs in the viewer's
settings file (prefs.py), per scene (its built-in name, or the absolute path of its file).
"""

import os

from gridrt.camera import Camera
from gridrt.errors import InputError

from .prefs import load_prefs, save_prefs

#: the bookmark slots (keys 1..9)
SLOTS = tuple(range(1, 10))


def _vec(v):
    return ",".join(repr(float(x)) for x in v)


def camera_flags(cam):
    """The flags that give ``cam`` (a Camera) on a gridrt command line, each number written so
    that it parses back to the same float: ``--eye=X,Y,Z --target=X,Y,Z --up=X,Y,Z --fov=F``."""
    return f"--eye={_vec(cam.eye)} --target={_vec(cam.target)} --up={_vec(cam.up)} --fov={float(cam.fov)!r}"


def scene_key(source):
    """A scene's key in the bookmarks: a built-in name as it is, a file's absolute path."""
    s = str(source)
    return os.path.abspath(os.path.expanduser(s)) if os.path.exists(s) else s


def _camera(d):
    try:
        return Camera(eye=tuple(d["eye"]), target=tuple(d["target"]), up=tuple(d["up"]), fov=float(d["fov"]))
    except (KeyError, TypeError, ValueError, InputError):
        return None


def load_bookmarks(source, data=None):
    """{slot: Camera} of the scene ``source`` from the remembered settings (``data``: as
    load_prefs returns them; read from the file when None); an entry that is not a valid camera
    is left out."""
    data = load_prefs() if data is None else data
    marks = data.get("bookmarks")
    mine = marks.get(scene_key(source)) if isinstance(marks, dict) else None
    if not isinstance(mine, dict):
        return {}
    out = {}
    for k, v in mine.items():
        cam = _camera(v) if isinstance(v, dict) else None
        if cam is not None and k.isdigit() and int(k) in SLOTS:
            out[int(k)] = cam
    return out


def save_bookmark(source, slot, cam):
    """Remember ``cam`` in slot ``slot`` of the scene ``source`` (other scenes' and slots' kept);
    True when written."""
    data = load_prefs()
    marks = data.get("bookmarks") if isinstance(data.get("bookmarks"), dict) else {}
    key = scene_key(source)
    mine = marks.get(key) if isinstance(marks.get(key), dict) else {}
    mine[str(int(slot))] = {"eye": list(cam.eye), "target": list(cam.target), "up": list(cam.up),
                            "fov": float(cam.fov)}
    marks[key] = mine
    return save_prefs({"bookmarks": marks})
