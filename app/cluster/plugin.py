"""The worker plugin of gridrt's local clusters (imported only when a cluster runs: it needs Dask)."""

import signal
import threading

from distributed import WorkerPlugin


class IgnoreSigint(WorkerPlugin):
    """A local cluster's worker processes share the terminal's process group, so Ctrl-C reaches
    them as well as the client.  They ignore it (no KeyboardInterrupt tracebacks from workers
    stopping half-way) and the client, which handles it, stops them.  Workers started with the
    cluster inherit "ignore" from the client (:class:`gridrt.app.cluster.scheduler.CtrlC`); this plugin
    covers a worker the cluster restarts later, from its set-up on."""

    name = "gridrt-ignore-sigint"

    def setup(self, worker):
        if threading.current_thread() is threading.main_thread():
            signal.signal(signal.SIGINT, signal.SIG_IGN)
