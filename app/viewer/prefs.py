"""The viewer's remembered settings: whether the panel is hidden (H) or collapsed to a strip, kept
across runs in a small JSON file, ``viewer.json`` in the user's config folder:

* ``$GRIDRT_CONFIG_HOME`` when set (the folder that holds viewer.json; tests point it at a
  temporary folder),
* else ``$XDG_CONFIG_HOME/gridrt`` (an absolute XDG_CONFIG_HOME only, as the XDG spec asks),
* else ``~/.config/gridrt``.

A file that cannot be read or parsed counts as empty, and a write that fails is ignored silently:
remembering the panel is a convenience, never a reason for the viewer to stop or to complain.
"""

import json
import os
from pathlib import Path

#: environment variable naming the folder of viewer.json (overrides the XDG location)
CONFIG_ENV = "GRIDRT_CONFIG_HOME"
PREFS_NAME = "viewer.json"


def config_dir():
    """gridrt's config folder (see the module docstring); not created here."""
    own = os.environ.get(CONFIG_ENV, "")
    if own:
        return Path(os.path.expanduser(own))
    xdg = os.environ.get("XDG_CONFIG_HOME", "")
    base = Path(xdg) if xdg and os.path.isabs(xdg) else Path(os.path.expanduser("~")) / ".config"
    return base / "gridrt"


def prefs_path():
    return config_dir() / PREFS_NAME


def load_prefs(path=None):
    """The remembered settings as a dict ({} when there are none or the file is unreadable)."""
    try:
        data = json.loads(Path(path or prefs_path()).read_text())
    except (OSError, ValueError):
        return {}
    return data if isinstance(data, dict) else {}


def save_prefs(changes, path=None):
    """Merge the dict ``changes`` into the remembered settings (other keys are kept); True when
    written.  Failures (a read-only or missing home, a full disk) are ignored silently."""
    p = Path(path or prefs_path())
    data = load_prefs(p)
    data.update(changes)
    tmp = p.with_name(p.name + ".tmp")
    try:
        p.parent.mkdir(parents=True, exist_ok=True)
        tmp.write_text(json.dumps(data, indent=1, sort_keys=True) + "\n")
        os.replace(tmp, p)
    except OSError:
        try:
            tmp.unlink()
        except OSError:
            pass
        return False
    return True


def panel_prefs(data):
    """(show_panel, panel_collapsed) from remembered settings ``data`` (defaults: shown, expanded;
    a value of the wrong type counts as absent)."""
    show = data.get("show_panel", True)
    collapsed = data.get("panel_collapsed", False)
    return (show if isinstance(show, bool) else True, collapsed if isinstance(collapsed, bool) else False)
