"""Registry of grid build strategies, chosen by name (``GridParams.strategy``).

A strategy is a subclass of :class:`gridrt.grid.strategies.base.Strategy` (the contract is in
that module's docstring) with a ``name``, the flags ``parallel_stages`` and ``layered``, and an
``insert(tris, spec, bufs, threads, exact, times)`` method that fills the cell lists of a
:class:`gridrt.grid.buffers.GridBuffers` and returns the number of references; the builder
(:class:`gridrt.grid.build.GridBuilder`) runs the shared clear and macro-cell stages around it.
:data:`BUILDERS` lists every strategy class of :mod:`gridrt.grid.strategies` by name, in the
order of the table of Ize et al. 2006 (plus Lagae & Dutré 2008's counting).  The first line of a
class's docstring is what ``gridrt strategies`` prints.
"""

from ..config import STRATEGIES, check_strategy
from ..errors import InputError
from .strategies.counting import Counting
from .strategies.serial import Serial
from .strategies.sort_first import SortFirst
from .strategies.sort_last_locks import CellLocks, GlobalLock, LockPool
from .strategies.sort_middle import SortMiddle
from .strategies.thread_grids import ThreadGrids, ThreadGridsMerge

#: strategy name -> class, in registry order
BUILDERS = {cls.name: cls for cls in (Serial, SortFirst, GlobalLock, CellLocks, LockPool, ThreadGridsMerge,
                                      ThreadGrids, SortMiddle, Counting)}
if tuple(BUILDERS) != STRATEGIES:
    raise ImportError(f"gridrt.grid.registry: strategy classes {tuple(BUILDERS)} differ from gridrt.config.STRATEGIES "
                      f"{STRATEGIES}")


def get_builder(name):
    """The strategy class registered as ``name``; InputError listing the valid names otherwise
    ("auto" names no class: gridrt.config.resolve_strategy gives the one it stands for)."""
    if check_strategy(name) not in BUILDERS:
        raise InputError(f"build strategy {name!r} stands for one of the others at a given thread count; "
                         f"choose one of {', '.join(STRATEGIES)}")
    return BUILDERS[name]


def names():
    """The registered strategy names, in registry order."""
    return list(BUILDERS)
