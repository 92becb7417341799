"""Packet profiles: the cycle counter read at each phase of a packet's traversal, and the slots
(phases and counts) of a profile array (trace_packet's ``prof``)."""

from ...compiles import inner, one_per_types
from ..prefetch import _cycles


#: slots of a packet profile (trace_packet's ``prof``, (NPROF,) int64): cycles per phase, then counts
P_SETUP, P_MACRO, P_SLICE, P_CELLS, P_TESTS, P_RETIRE, P_SPLIT, P_RAYS = 0, 1, 2, 3, 4, 5, 6, 7
PROFILE_PHASES = ("setup", "macro", "slice", "cells", "tests", "retire", "split", "rays")
C_PACKETS, C_SLICES, C_CELLS, C_TESTS = 8, 9, 10, 11
NPROF = 12


@inner(cache=True, _nrt=False)
def _now(prof):
    """The cycle counter when profiling (prof an array), else 0 (prof None: compiled away)."""
    if prof is None:
        return 0
    return _cycles()


@one_per_types
@inner(cache=True, _nrt=False)
def _lap(prof, k, t):
    """Add the cycles since t to phase k of prof; returns the counter now (0 without prof)."""
    if prof is None:
        return 0
    now = _cycles()
    prof[k] += now - t
    return now


@one_per_types
@inner(cache=True, _nrt=False)
def _prof_count(prof, k, n):
    if prof is not None:
        prof[k] += n
