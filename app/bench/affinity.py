"""CPU affinity for ``gridrt bench peers``: pinning this process's threads to the first n CPUs (the
only way to limit Embree's own build threads from Python)."""

import os


class Affinity:
    """Context manager pinning every thread of this process (and threads they start later) to
    the first ``n`` of the CPUs it may use; restores the previous masks on exit.  A no-op where
    the OS has no sched_setaffinity (``self.applied`` is then False)."""

    def __init__(self, n):
        self.n = n
        self.applied = False
        self._saved = {}

    @staticmethod
    def _tids():
        try:
            return [int(t) for t in os.listdir("/proc/self/task")]
        except OSError:
            return [0]

    def __enter__(self):
        if not hasattr(os, "sched_setaffinity"):
            return self
        cpus = sorted(os.sched_getaffinity(0))
        self.cpus = set(cpus[: self.n]) if self.n <= len(cpus) else set(cpus)
        for tid in self._tids():
            try:
                self._saved[tid] = os.sched_getaffinity(tid)
                os.sched_setaffinity(tid, self.cpus)
            except OSError:
                pass
        self.applied = True
        return self

    def __exit__(self, *exc):
        if not self.applied:
            return False
        allowed = set().union(*self._saved.values()) if self._saved else None
        for tid in self._tids():
            try:
                os.sched_setaffinity(tid, self._saved.get(tid, allowed))
            except (OSError, TypeError):
                pass
        return False
