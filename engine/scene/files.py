"""The files a scene names: where they may lie, and reading them.

A scene file names other files: glTF buffers and images, OBJ material libraries (``mtllib``) and
their textures (``map_Kd``), BART includes (``i``) and texture images, MD2 skins; a folder of
frames holds the frame files.  A scene is untrusted input (a file someone sent), so every such
reference goes through a :class:`SceneFolder`:

* it resolves, after following symlinks (:meth:`pathlib.Path.resolve`), inside the folder of the
  scene file the user named (for a folder of frames: that folder), or in a folder the loader adds
  for one kind of file (BART's ``TextureFiles`` beside ``aff/``, see :mod:`gridrt.scene.bart`);
* anything else (``../`` and absolute paths, percent-encoded ones such as ``%2F`` or ``%2E%2E``,
  ``file:`` URIs that leave the folder, symlinks that lead out, other URI schemes) is refused with
  :class:`OutsideReference`, a :class:`SceneFileError` naming the reference as the scene writes
  it and the way to allow it (:data:`ALLOW_HINT`), unless the scene is trusted
  (``allow_outside=True``, the command line's ``--allow-outside-refs``).  A refused geometry file
  (buffer, include) fails the load; a refused material or texture is dropped with a
  :class:`gridrt.scene.surface.TextureWarning` that says why.

Only regular files are read (:func:`open_regular`): a FIFO, a device (``/dev/zero``) or a socket
is refused before a byte is read, so it can neither hang a load nor fill the memory; a size the
scene declares is checked against the file's size before reading, and no more is read.
"""

import contextlib
import errno
import os
import stat
import urllib.parse
from pathlib import Path

from ..errors import SceneFileError

__all__ = ["ALLOW_HINT", "NotRegularFile", "OutsideReference", "SceneFolder", "open_regular", "os_problem",
           "read_regular", "read_scene_file"]

#: how a user trusts a scene's references outside its folder, quoted by every refusal
ALLOW_HINT = "pass --allow-outside-refs (allow_outside=True) to trust references outside the scene's folder"


class OutsideReference(SceneFileError):
    """A file a scene names resolves outside the scene's folder (or is a URI that is no local file):
    ``path`` is the scene file that names it, ``reference`` the reference as the scene writes it."""

    def __init__(self, path, problem, reference=None):
        super().__init__(path, problem)
        self.reference = reference

    def __reduce__(self):
        return (type(self), (self.path, self.problem, self.reference))


class NotRegularFile(OSError):
    """A path that is a FIFO, a device, a socket or a directory: never read."""


def _kind(mode):
    for test, what in ((stat.S_ISDIR, "a directory"), (stat.S_ISFIFO, "a FIFO"), (stat.S_ISCHR, "a device"),
                       (stat.S_ISBLK, "a device"), (stat.S_ISSOCK, "a socket")):
        if test(mode):
            return what
    return "not a regular file"


@contextlib.contextmanager
def open_regular(path):
    """Open ``path`` for binary reading only when it is a regular file: yields ``(file, size)``.

    The file is opened without blocking (a FIFO with no writer does not hang the open) and checked
    with fstat before anything is read; :class:`NotRegularFile` (an OSError whose message says what
    the path is) for a FIFO, device, socket or directory; the other OSErrors (FileNotFoundError,
    PermissionError, ...) as the system raises them.
    """
    flags = os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_BINARY", 0) | getattr(os, "O_CLOEXEC", 0)
    try:
        fd = os.open(path, flags)
    except IsADirectoryError as e:
        raise NotRegularFile(errno.EISDIR, "is a directory, not a file", str(path)) from e
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise NotRegularFile(errno.EINVAL, f"is {_kind(st.st_mode)}, not a regular file: not read", str(path))
        if hasattr(os, "set_blocking"):
            os.set_blocking(fd, True)
        fh = os.fdopen(fd, "rb")
    except BaseException:
        os.close(fd)
        raise
    with fh:
        yield fh, st.st_size


def read_regular(path, limit=None):
    """The bytes of the regular file ``path`` (at most ``limit``), as :func:`open_regular` opens it."""
    with open_regular(path) as (fh, _):
        return fh.read() if limit is None else fh.read(limit)


def os_problem(e):
    """One line for an OSError from :func:`open_regular`: what the path is or why it cannot be read."""
    if isinstance(e, NotRegularFile):
        return e.strerror
    if isinstance(e, FileNotFoundError):
        return "file not found"
    if isinstance(e, PermissionError):
        return "permission denied: the file is not readable"
    return f"cannot read the file ({e.strerror or e})"


def read_scene_file(path):
    """The bytes of a scene file the user named (a regular file), or SceneFileError naming the problem."""
    try:
        return read_regular(path)
    except OSError as e:
        raise SceneFileError(path, os_problem(e)) from e


def _inside(real, folder):
    return real == folder or folder in real.parents


class SceneFolder:
    """The folder a scene's references must stay in, and whether the user trusts it to leave it.

    Parameters
    ----------
    scene : str or os.PathLike
        The scene file the user named (its folder is the scene's folder) or a folder of frames
        (the folder itself, ``folder=True``).
    allow_outside : bool
        True: every reference is followed wherever it leads (the user trusts the scene).
    folder : bool
        ``scene`` is the folder itself.

    ``root`` is the resolved folder; ``scene`` the file (or folder) named, for messages.
    """

    def __init__(self, scene, allow_outside=False, folder=False):
        self.scene = Path(scene)
        self.allow_outside = bool(allow_outside)
        base = self.scene if folder else self.scene.absolute().parent
        try:
            self.root = base.resolve()
        except (OSError, RuntimeError):
            self.root = base.absolute()

    def is_inside(self, path, also=()):
        """True when ``path`` resolves (symlinks followed) inside the scene's folder or one of the
        folders ``also`` (resolved likewise), or the scene is trusted."""
        if self.allow_outside:
            return True
        try:
            real = Path(path).absolute().resolve()
        except (OSError, RuntimeError, ValueError):
            return False
        for folder in (self.root, *also):
            try:
                folder = Path(folder).absolute().resolve()
            except (OSError, RuntimeError, ValueError):
                continue
            if _inside(real, folder):
                return True
        return False

    def refusal(self, what, reference, by=None, why="leads outside the scene's folder", hint=True):
        """The :class:`OutsideReference` for ``what`` (e.g. "buffer 0") named ``reference`` as the
        scene file ``by`` (default: the scene) writes it."""
        by = self.scene if by is None else by
        tail = f" ({self.root}); {ALLOW_HINT}" if hint else ""
        return OutsideReference(by, f"{what} {reference!r} {why}{tail}", reference)

    def check(self, path, what, reference, by=None, also=()):
        """``path`` (the file ``reference`` names) when it resolves inside (see :meth:`is_inside`);
        else raise :meth:`refusal`."""
        if not self.is_inside(path, also):
            raise self.refusal(what, reference, by)
        return Path(path)

    def uri(self, base, what, uri, by=None):
        """The local file a glTF URI names, relative to the folder ``base``: percent-decoded, a
        ``file:`` URI taken as its path; checked with :meth:`check`.  Other URI schemes (http:, ...)
        are refused (OutsideReference) whatever the trust: gridrt reads local files only."""
        parsed = urllib.parse.urlsplit(uri)
        scheme = parsed.scheme.lower()
        if scheme == "file":
            if parsed.netloc not in ("", "localhost"):
                raise self.refusal(what, uri, by, "is a file: URI of another machine: only local files are read",
                                   hint=False)
            path = Path(urllib.parse.unquote(parsed.path))
            if not path.is_absolute():
                path = base / path
        elif len(scheme) > 1:  # (one letter: a Windows drive)
            raise self.refusal(what, uri, by, f"is a {scheme}: URI: only local files are read", hint=False)
        else:
            path = base / urllib.parse.unquote(uri)
        return self.check(path, what, uri, by)
