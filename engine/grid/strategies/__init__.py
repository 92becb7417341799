"""Grid build strategies, one module per family: serial, sort_first, sort_last_locks
(global_lock, cell_locks, lock_pool), thread_grids (thread_grids_merge, thread_grids),
sort_middle, counting (the table of Ize et al. 2006, plus Lagae & Dutré 2008).
:mod:`gridrt.grid.registry` lists them by name.
"""
