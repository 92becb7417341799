"""gridrt applications: the viewer, the headless frame dump and the benchmarks (``gridrt ...``)."""

import os
import sys


def exit_now(code):
    """End the process at once with ``code`` (os._exit), stdout and stderr flushed where they can
    be: no interpreter shutdown beside a thread still running numba code."""
    for f in (sys.stdout, sys.stderr):
        try:
            f.flush()
        except (OSError, ValueError):
            pass
    os._exit(code)
