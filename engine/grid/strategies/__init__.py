"""Grid build strategies; importing this package registers each one (explicitly, by name).

Registry order: serial, sort_first, global_lock, cell_locks, lock_pool, thread_grids_merge,
thread_grids, sort_middle, counting (the table of Ize et al. 2006, plus Lagae & Dutré 2008).
"""

from . import serial  # noqa: F401
from . import sort_first  # noqa: F401
from . import sort_last_locks  # noqa: F401  (global_lock, cell_locks, lock_pool)
from . import thread_grids  # noqa: F401  (thread_grids_merge, thread_grids)
from . import sort_middle  # noqa: F401
from . import counting  # noqa: F401
