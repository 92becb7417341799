"""Commands that gridrt's messages print, written so that they can be pasted as printed.

After the README's set-up (a virtual environment in ``.venv``, not activated) neither ``gridrt``
nor ``pip`` is on PATH, so a message that said "run gridrt dump ..." or "pip install X" would
not work.  These functions name the program the way the running process was started instead:
the ``gridrt`` script by the path it was run as (``.venv/bin/gridrt`` from the repository root;
plain ``gridrt`` when that is what PATH finds), otherwise the running interpreter with ``-m``.
A path inside the working directory is given relative to it, any other path in full, so the
command works in the shell (and folder) the user typed the first one in.
"""

import os
import shlex
import shutil
import sys


def _as_typed(path):
    """``path`` relative to the working directory when inside it (``./x`` for a bare name, which
    the shell would otherwise look up on PATH), else absolute; shell-quoted."""
    full = os.path.abspath(path)
    try:
        rel = os.path.relpath(full)
    except ValueError:  # another drive (Windows)
        rel = full
    if rel.startswith(os.pardir):
        rel = full
    elif os.sep not in rel:
        rel = os.curdir + os.sep + rel
    return shlex.quote(rel)


def python_command():
    """The running Python interpreter as a command (``.venv/bin/python``, or its full path)."""
    return _as_typed(sys.executable) if sys.executable else "python3"


def pip_command():
    """``pip`` of the running interpreter (``.venv/bin/python -m pip``): installs where gridrt runs."""
    return f"{python_command()} -m pip"


def gridrt_command():
    """The ``gridrt`` command as this process was started: ``gridrt`` when PATH finds the script
    that is running, else the script's path (``.venv/bin/gridrt``), or ``python -m gridrt`` with
    the running interpreter when gridrt was not started through its script."""
    argv0 = sys.argv[0] if sys.argv and sys.argv[0] else ""
    if os.path.basename(argv0) in ("gridrt", "gridrt.exe") and os.path.isfile(argv0):
        found = shutil.which("gridrt")
        if found and os.path.samefile(found, argv0):
            return "gridrt"
        return _as_typed(argv0)
    return f"{python_command()} -m gridrt"
