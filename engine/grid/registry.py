"""Registry of grid build strategies, chosen by name.

A strategy is a class with a ``name`` and a ``build(tris, spec, bufs, threads, exact)``
method filling a :class:`gridrt.grid.buffers.GridBuffers`; see ``strategies/serial.py`` for the
contract.  Strategy modules register themselves with :func:`register`.
"""

from ..errors import InputError

BUILDERS = {}


def register(cls):
    """Class decorator: add a strategy class to BUILDERS under ``cls.name``."""
    if cls.name in BUILDERS:
        raise RuntimeError(f"strategy {cls.name!r} registered twice")
    BUILDERS[cls.name] = cls
    return cls


def get_builder(name):
    """The strategy class registered as ``name``; InputError listing the valid names otherwise."""
    from . import strategies  # noqa: F401  (registers every strategy)

    try:
        return BUILDERS[name]
    except (KeyError, TypeError):
        raise InputError(f"unknown build strategy {name!r}; choose one of {', '.join(BUILDERS)}") from None


def names():
    from . import strategies  # noqa: F401

    return list(BUILDERS)
