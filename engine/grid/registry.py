"""Registry of grid build strategies, chosen by name (``GridParams.strategy``).

A strategy is a subclass of :class:`gridrt.grid.strategies.base.Strategy` (the contract is in
that module's docstring) with a ``name``, the flags ``parallel_stages`` and ``layered``, and an
``insert(tris, spec, bufs, threads, exact, times)`` method that fills the cell lists of a
:class:`gridrt.grid.build.GridBuffers` and returns the number of references; the builder
(:class:`gridrt.grid.build.GridBuilder`) runs the shared clear and macro-cell stages around it.
Each strategy module registers its classes with the :func:`register` decorator when
:mod:`gridrt.grid.strategies` imports it, which :func:`get_builder` and :func:`names` do on
first use.  The first line of a class's docstring is what ``gridrt strategies`` prints.
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
    """The registered strategy names, in registry order (:mod:`gridrt.grid.strategies`)."""
    from . import strategies  # noqa: F401

    return list(BUILDERS)
