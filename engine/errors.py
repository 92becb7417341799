"""Exception types raised at gridrt's Python boundary.

Kernels never validate: every check happens before a kernel runs, and a failed check raises
one of these with a message that names the problem (and the file, for file errors).
"""


class GridrtError(Exception):
    """Base class of every error gridrt raises on purpose."""


class InputError(GridrtError, ValueError):
    """Bad arrays or parameters handed to the engine (NaN vertices, bad indices, bad sizes...)."""


class SceneFileError(GridrtError, ValueError):
    """A scene file that cannot be read: missing, unreadable, unknown format, malformed."""

    def __init__(self, path, problem):
        self.path = str(path)
        self.problem = problem
        super().__init__(f"{self.path}: {problem}")

    def __reduce__(self):  # pickled whole (a worker process's error reaches the client as raised)
        return (type(self), (self.path, self.problem))
