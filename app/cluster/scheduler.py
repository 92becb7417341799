"""Starting a local Dask cluster or connecting to an existing one (``--workers N``, ``--scheduler
ADDRESS``): the options, their checks, the scheduler's address and greeting, :class:`Cluster`,
Ctrl-C while it runs (:class:`CtrlC`)."""

import logging
import os
import signal
import socket
import struct
import threading
import time
import warnings
from urllib.parse import urlsplit

from gridrt import memory
from gridrt.commands import pip_command
from gridrt.errors import InputError
from gridrt.memory import human


def install_hint():
    """How to get the cluster extra, with the pip of the running interpreter."""
    pip = pip_command()
    return (f"{pip} install 'gridrt[cluster]' (in a checkout: {pip} install -e '.[cluster]'; or {pip} install "
            "distributed bokeh)")

#: seconds from reading a --scheduler address to a connected client, whatever is at the address: the
#: host's look-up, the connection, the scheduler's greeting and the client's start share them
CONNECT_TIMEOUT = 5
#: the most bytes the first message of a --scheduler may claim: a Dask scheduler greets a new connection
#: with its handshake, under 100 bytes; anything announcing more is not one (and is never allocated)
GREETING_MAX = 1 << 16
#: the interface a local cluster's scheduler, workers, nannies and dashboard listen on unless --listen
#: says otherwise: loopback, so that nothing of it is reachable from other machines
LOOPBACK = "127.0.0.1"
#: seconds a local cluster's workers are given to silence their logs before it stops
QUIET_TIMEOUT = 5
#: the port of a local cluster's dashboard (Dask takes another free one when it is taken)
DASHBOARD_PORT = 8787
#: memory a local cluster's worker process takes, for the --workers check: its RSS measured 220 MB
#: rendering the default marbles at 640x480, and 300 MB at 1920x1080 with buffers or rendering the
#: shipped MD2 with its skin (numba, gridrt and Dask loaded); rounded up for larger scenes
WORKER_MEMORY = 500 * 10**6


def add_cluster_args(p, what="frames"):
    g = p.add_argument_group("cluster (Dask; needs the extra: pip install 'gridrt[cluster]')")
    g.add_argument("--workers", type=int, default=None,
                   help=f"spread the {what} over a local Dask cluster of this many worker processes, each with "
                        "--threads threads (default: the cores divided among the workers)")
    g.add_argument("--scheduler", default=None,
                   help=f"spread the {what} over an existing Dask cluster: its scheduler's address, e.g. "
                        "tcp://10.0.0.5:8786 (start one with `dask scheduler` and `dask worker ADDRESS --nthreads 1`; "
                        "each worker uses --threads threads, default: its machine's cores divided among the "
                        "workers on it)")
    g.add_argument("--listen", default=None, metavar="HOST",
                   help=f"the interface a local cluster (--workers) listens on: its scheduler, workers and "
                        f"dashboard (default {LOOPBACK}: this machine only). Another address, or 0.0.0.0 for "
                        "every interface, EXPOSES THE CLUSTER TO THE NETWORK: whoever reaches it can run code "
                        "in its workers")
    return g


def wants_cluster(a):
    """True when the parsed arguments ask for a cluster (validated: a local cluster's size is
    checked against the machine, :func:`check_workers`)."""
    workers, scheduler = getattr(a, "workers", None), getattr(a, "scheduler", None)
    listen = getattr(a, "listen", None)
    if workers is not None and scheduler is not None:
        raise InputError("give --workers (a local cluster) or --scheduler (an existing one), not both")
    if workers is not None and workers < 1:
        raise InputError(f"--workers must be at least 1, got {workers}")
    if scheduler is not None and not str(scheduler).strip():
        raise InputError("--scheduler needs an address, e.g. tcp://127.0.0.1:8786")
    if listen is not None and workers is None:
        raise InputError("--listen applies to a local cluster: give it with --workers")
    if workers is not None:
        listen_host(listen)
        check_workers(workers)
    return workers is not None or scheduler is not None


def listen_host(listen):
    """The host a local cluster listens on: ``listen`` (--listen), or :data:`LOOPBACK` for None;
    an InputError for an empty one or an IPv6 address (Dask's dashboard takes none: a port alone
    would open it on every interface)."""
    host = LOOPBACK if listen is None else str(listen).strip()
    if not host:
        raise InputError(f"--listen needs an address of this machine, e.g. {LOOPBACK} (the default)")
    if ":" in host:
        raise InputError(f"--listen {host}: give an IPv4 address or a host name (Dask's dashboard cannot listen on "
                         f"an IPv6 address); default {LOOPBACK}")
    return host


def usable_cores():
    """The cores this process may run on (its affinity; all of them where that is unknown)."""
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def memory_available():
    """(bytes, source): the memory new processes may still take here, the smallest of
    ``MemAvailable`` and the cgroups' limits less their usage (:func:`gridrt.memory.readings`;
    a process's own RLIMIT_AS and RLIMIT_DATA bound each worker apart, not their sum); (None,
    None) where none can be read."""
    shared = [(b, source) for source, b in memory.readings() if not source.startswith("RLIMIT")]
    return min(shared) if shared else (None, None)


def check_workers(workers):
    """Refuse (InputError, with the figures) a local cluster of ``workers`` processes that this
    machine cannot hold: more workers than the cores this process may use, or ``workers`` times
    :data:`WORKER_MEMORY` more than the memory available (:func:`memory_available`)."""
    cores, (room, source) = usable_cores(), memory_available()
    problems = []
    if workers > cores:
        problems.append(f"{workers} workers on {cores} cores")
    if room is not None and workers * WORKER_MEMORY > room:
        problems.append(f"{workers} workers x {human(WORKER_MEMORY)} = {human(workers * WORKER_MEMORY)} of memory, "
                        f"{human(room)} available ({source})")
    if not problems:
        return
    fit = min(cores, cores if room is None else room // WORKER_MEMORY)
    way = f"give --workers {fit} or fewer" if fit >= 1 else "free some memory"
    raise InputError(f"--workers {workers} does not fit this machine: {'; '.join(problems)} (a worker takes a core "
                     f"and about {human(WORKER_MEMORY)}); {way}, or use --scheduler with workers on other machines")


def import_distributed():
    """The ``distributed`` module, or an InputError saying how to install it."""
    try:
        import distributed  # deferred: the optional cluster extra (distributed) loads in about a second
    except ImportError as e:
        raise InputError(f"--workers and --scheduler need Dask's distributed scheduler, which is not installed "
                         f"({e}); install the cluster extra: {install_hint()}") from None
    return distributed


def scheduler_address(text):
    """(host, port) of a --scheduler address: ``tcp://HOST:PORT``, ``HOST:PORT`` or
    ``tcp://[IPv6]:PORT``; an InputError that says what is wrong with anything else."""
    shown = " ".join(str(text).split())
    scheme, sep, rest = shown.partition("://")
    if not sep:
        scheme, rest = "tcp", shown
    how = "give HOST:PORT as `dask scheduler` prints it, e.g. tcp://10.0.0.5:8786"
    if scheme.lower() != "tcp":
        raise InputError(f"--scheduler {shown}: only tcp:// addresses are supported; {how}")
    try:
        u = urlsplit("tcp://" + rest)
        host, port = u.hostname, u.port
    except ValueError as e:
        raise InputError(f"--scheduler {shown}: not an address ({e}); {how}") from None
    if not host or u.path or u.query or u.fragment or u.username is not None:
        raise InputError(f"--scheduler {shown}: not an address; {how}")
    if not port:
        raise InputError(f"--scheduler {shown}: no port; {how}")
    return host, port


def _resolve(host, port, deadline, timeout):
    """The TCP addresses of ``host`` (``getaddrinfo``), looked up in a helper thread: the
    system's resolver takes no timeout, so a look-up not done by ``deadline`` (``time.monotonic()``,
    ``timeout`` s after the start) is given up (its thread ends by itself, and never holds the
    process at exit)."""
    box = {}

    def look_up():
        try:
            box["found"] = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)
        except (OSError, UnicodeError, ValueError) as e:
            box["error"] = e

    t = threading.Thread(target=look_up, name="gridrt-resolve", daemon=True)
    t.start()
    t.join(max(0.0, deadline - time.monotonic()))
    if "found" in box and box["found"]:
        return [info[4][:2] for info in box["found"]]
    why = (f"not resolved within {timeout:g} s" if t.is_alive()
           else getattr(box.get("error"), "strerror", None) or str(box.get("error", "no address")))
    raise InputError(f"cannot resolve the Dask scheduler's host {host} ({why}); check the name in --scheduler, "
                     "or give the scheduler's IP address")


def _receive(sock, n, deadline):
    """Up to ``n`` bytes from ``sock``, as many as arrive by ``deadline`` (fewer: the peer closed
    the connection, or time ran out)."""
    data = bytearray()
    while len(data) < n:
        left = deadline - time.monotonic()
        if left <= 0:
            break
        sock.settimeout(left)
        try:
            chunk = sock.recv(min(n - len(data), GREETING_MAX))
        except (socket.timeout, InterruptedError):
            break
        if not chunk:
            break
        data += chunk
    return bytes(data)


def greeting_problem(data):
    """None when ``data``, the bytes a peer sent first (its first 8, then as many more as they
    announce), is a Dask handshake: a message of its size (8 bytes, then the rest), its frame
    count, each frame's size and the frames, whose sizes add up, small, the first frame a msgpack
    map; else what is wrong with it.  Nothing is allocated from the sizes it claims."""
    word = struct.Struct("Q")  # (native order, as Dask's TCP comm writes them)
    if len(data) < 8:
        return f"it sent {len(data)} bytes and stopped" if data else "it sent nothing"
    (size,) = word.unpack_from(data)
    if not 2 * word.size <= size <= GREETING_MAX:
        return f"its first message claims {size} bytes (a scheduler's greeting is under {GREETING_MAX} bytes)"
    body = data[8:]
    if len(body) < size:
        return f"its first message stopped after {len(body)} of the {size} bytes it claimed"
    (count,) = word.unpack_from(body)
    if not 1 <= count <= (size - word.size) // word.size - 1:
        return f"its first message claims {count} frames in {size} bytes"
    lengths = struct.unpack_from(f"{count}Q", body, word.size)
    start = word.size * (count + 1)
    if sum(lengths) != size - start:
        return f"its first message's frames do not add up to its size ({sum(lengths)} + {start} != {size} bytes)"
    import msgpack  # deferred: msgpack comes with the optional cluster extra (distributed)

    try:
        greeting = msgpack.unpackb(body[start:start + lengths[0]], raw=False)
    except (ValueError, msgpack.UnpackException):
        greeting = None
    if not isinstance(greeting, dict):
        return "its first message is not a handshake"
    return None


def connect_scheduler(text, timeout=CONNECT_TIMEOUT):
    """Check within ``timeout`` s, on a plain socket, that a Dask scheduler answers at the
    --scheduler address ``text``: its host resolves, a connection opens, and the first bytes
    the peer sends (at once, unasked, as a scheduler does) are a Dask handshake, which
    :func:`greeting_problem` reads without allocating from what they claim.  Anything else (a
    name that does not resolve, a closed port, a port that accepts and stays silent, an HTTP or
    any other server) is an InputError of one line.  Returns (``tcp://HOST:PORT`` as the user
    named it, the address that answered: ``tcp://IP:PORT``, the ``time.monotonic()`` deadline)."""
    host, port = scheduler_address(text)
    deadline = time.monotonic() + timeout
    shown = f"tcp://[{host}]:{port}" if ":" in host else f"tcp://{host}:{port}"
    how = "is `dask scheduler` running there, and is the port open?"
    problem = "no address"
    for ip, p in _resolve(host, port, deadline, timeout):
        left = deadline - time.monotonic()
        if left <= 0:
            break
        try:
            sock = socket.create_connection((ip, p), timeout=left)
        except socket.timeout:
            problem = "the connection did not open"
            continue
        except OSError as e:
            problem = (e.strerror or type(e).__name__).lower()
            continue
        with sock:
            data = _receive(sock, 8, deadline)
            if len(data) == 8 and 16 <= struct.unpack_from("Q", data)[0] <= GREETING_MAX:
                data += _receive(sock, struct.unpack_from("Q", data)[0], deadline)
        if not data:
            raise InputError(f"cannot reach the Dask scheduler at {shown} within {timeout:g} s (the port accepts "
                             "connections but sends nothing, where a Dask scheduler greets at once); is it the "
                             "port `dask scheduler` printed?")
        wrong = greeting_problem(data)
        if wrong:
            raise InputError(f"{shown} does not answer as a Dask scheduler does: {wrong} (its first bytes: "
                             f"{data[:16]!r}); give the address `dask scheduler` prints (tcp://HOST:8786 by default)")
        return shown, f"tcp://[{ip}]:{p}" if ":" in ip else f"tcp://{ip}:{p}", deadline
    raise InputError(f"cannot reach the Dask scheduler at {shown} within {timeout:g} s ({problem}); {how}")


class Cluster:
    """A Dask client on a local cluster of ``workers`` processes (started here, stopped on
    :meth:`close`) or on the scheduler at ``scheduler``.  ``threads``: threads per worker (None:
    a local cluster's cores divided among its workers; an existing cluster's workers divide their
    own machine's cores among the workers on it).  A local cluster's scheduler, nannies, workers
    and dashboard listen on ``listen`` only (None: :data:`LOOPBACK`), and its size is checked
    against the machine first (:func:`check_workers`); an existing scheduler is checked on a
    plain socket first (:func:`connect_scheduler`): whatever is at its address, the client is
    connected or an InputError raised within about :data:`CONNECT_TIMEOUT` s."""

    def __init__(self, workers=None, scheduler=None, threads=None, listen=None):
        dist = import_distributed()
        self.threads = threads
        self.cluster = None
        self.client = None
        if workers is not None:
            check_workers(workers)
            cores = os.cpu_count() or 1
            if threads is None:
                self.threads = max(1, cores // workers)
            if workers * self.threads > cores:
                warnings.warn(f"{workers} workers x {self.threads} threads = {workers * self.threads} threads on "
                              f"{cores} cores: they compete for them (--threads sets the threads per worker)",
                              stacklevel=2)
            host = listen_host(listen)
            dashboard = f"{host}:{DASHBOARD_PORT}"
            # one task at a time per worker (a chunk or a configuration uses its own threads);
            # logs above errors only: a worker killed on purpose is not news
            try:
                with warnings.catch_warnings():
                    # Dask warns when the dashboard's port is taken (another cluster running) and serves it
                    # on a free one: the address printed (self.dashboard) is the one it took
                    warnings.filterwarnings("ignore", message=r"Port \d+ is already in use")
                    self.cluster = dist.LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                                                     host=host, dashboard_address=dashboard,
                                                     silence_logs=logging.ERROR)
            except (OSError, RuntimeError) as e:  # (Dask reports a failed bind as a RuntimeError)
                raise InputError(f"the local cluster did not start on {host} ({' '.join(str(e).split())}); "
                                 f"--listen takes an address of this machine (default {LOOPBACK})") from None
            try:
                self.client = dist.Client(self.cluster)
                from .plugin import IgnoreSigint  # deferred: the plugin's module imports distributed

                self.client.register_plugin(IgnoreSigint())  # (a worker restarted later ignores Ctrl-C too)
            except BaseException:
                self.close()
                raise
            self.where = f"a local cluster of {workers} worker processes"
        else:
            address, answered, deadline = connect_scheduler(scheduler)
            try:
                self.client = dist.Client(answered, timeout=max(1.0, deadline - time.monotonic()))
            except (OSError, TimeoutError, ValueError) as e:
                raise InputError(f"cannot reach the Dask scheduler at {address} within {CONNECT_TIMEOUT} s "
                                 f"({' '.join(str(e).split()) or type(e).__name__}); is `dask scheduler` running "
                                 "there, and is the port open?") from None
            info = self.client.scheduler_info()
            n = len(info.get("workers", {}))
            self.where = f"the Dask cluster at {address} ({n} workers)"
        self.dashboard = self.client.dashboard_link

    def hosts(self):
        """{host: workers on it} of the workers connected now."""
        out = {}
        for addr in self.client.scheduler_info().get("workers", {}):
            h = _host(addr)
            out[h] = out.get(h, 0) + 1
        return out

    def close(self):
        """Close the client, then the local cluster, with the logs of Dask (and of asyncio and
        tornado under it) silenced meanwhile, here and in the local cluster's workers: a worker's
        heartbeat to a scheduler that is stopping, or a connection closed under a task, is no
        news at the end of a run (nor, after Ctrl-C, a traceback on the terminal)."""
        with quiet_logs():
            try:
                if self.client is not None:
                    if self.cluster is not None:
                        try:  # (a worker busy with a task answers between its frames; a hung one is not waited for)
                            self.client.run(_silence, callback_timeout=QUIET_TIMEOUT)
                        except Exception:
                            pass
                    self.client.close()
            finally:
                if self.cluster is not None:
                    self.cluster.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


class CtrlC:
    """Ctrl-C during a cluster run, as a context manager around the cluster: while a ``local``
    cluster starts (a second or two) SIGINT is ignored (its worker processes share the terminal's
    process group, so Ctrl-C reaches them too; they inherit "ignore" and leave it to the client,
    which stops them); after :meth:`listen` (at once for an existing cluster) it raises a flag, which the client's loop checks between
    frames (``ctrl_c()`` is true once pressed: the loop stops with every frame written whole).
    The handler in place before is restored on exit.  Outside the main thread it does nothing."""

    def __init__(self, local=True):
        self.flag = threading.Event()
        self.old = None
        self.local = local

    def __enter__(self):
        if threading.current_thread() is threading.main_thread():
            self.old = signal.signal(signal.SIGINT, signal.SIG_IGN)
            if not self.local:  # no worker processes start here: heard at once, acted on once connected
                self.listen()
        return self

    def listen(self):
        if self.old is not None:
            signal.signal(signal.SIGINT, lambda *_: self.flag.set())

    def __call__(self):
        return self.flag.is_set()

    def __exit__(self, *exc):
        if self.old is not None:
            signal.signal(signal.SIGINT, self.old)


class quiet_logs:
    """No log records while inside (``logging.disable``), then the previous setting again."""

    def __enter__(self):
        self.before = logging.root.manager.disable
        logging.disable(logging.CRITICAL)
        return self

    def __exit__(self, *exc):
        logging.disable(self.before)


def _silence():
    """On a local cluster's worker about to stop: no more log records."""
    logging.disable(logging.CRITICAL)


def _host(address):
    """The host part of a Dask address (``tcp://10.0.0.5:40123`` -> ``10.0.0.5``)."""
    s = str(address).split("://", 1)[-1]
    return s.rsplit(":", 1)[0] if ":" in s else s
