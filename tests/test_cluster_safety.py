"""A Dask cluster's addresses are untrusted input: a local cluster listens on loopback only
(``--listen`` opens it on purpose), ``--scheduler`` fails with one line within its deadline
whatever is at the address, ``--workers`` beyond what the machine holds is refused with the
figures, and Ctrl-C of a cluster dump prints no traceback, also with a CPU hog beside it.

Everything here runs on 127.0.0.1 (127.0.0.2 once, still loopback): fake servers started by the
test (silent, HTTP, garbage and huge length headers, a closed port), a scheduler in this process,
local clusters of one or two workers.  Elapsed times are asserted generously (the code's own
deadline is checked by what it hands the socket, not by the clock).
"""

import http.server
import ipaddress
import os
import signal
import socket
import struct
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

pytest.importorskip("distributed", reason="the cluster extra (pip install 'gridrt[cluster]') is not installed")

from gridrt.app.cluster import scheduler as cluster  # noqa: E402
from gridrt.errors import InputError  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
#: a generous bound on a refused --scheduler run (the aim is an answer within 10 s; Python's start and a loaded
#: machine come on top of the code's deadline)
SLACK_S = 30


def gridrt(*args, timeout=300):
    return subprocess.run([sys.executable, "-m", "gridrt", *map(str, args)], cwd=REPO, capture_output=True,
                          text=True, timeout=timeout)


def one_error_line(r):
    """The run failed with exactly one ``gridrt: error:`` line and no traceback; returns the line."""
    assert r.returncode == 2, r.stderr
    assert "Traceback" not in r.stderr, r.stderr
    errors = [line for line in r.stderr.splitlines() if line.strip()]
    assert len(errors) == 1 and errors[0].startswith("gridrt: error: "), r.stderr
    return errors[0]


# ---------------------------------------------------------------------------------------------
# a local cluster listens on loopback only
# ---------------------------------------------------------------------------------------------

def listening(pids):
    """{(ip, port)} of the TCP sockets the processes ``pids`` listen on."""
    import psutil

    out = set()
    for pid in pids:
        try:
            conns = psutil.Process(pid).net_connections(kind="inet")
        except psutil.NoSuchProcess:
            continue
        out |= {(c.laddr.ip, c.laddr.port) for c in conns if c.status == psutil.CONN_LISTEN}
    return out


def tree(pid):
    import psutil

    return [pid] + [p.pid for p in psutil.Process(pid).children(recursive=True)]


def port_of(address):
    return int(str(address).rsplit(":", 1)[1].split("/")[0])


@pytest.mark.slow  # (a real cluster or server started for it; the quick run keeps the dump's loopback check)
def test_local_cluster_and_its_dashboard_listen_on_loopback_only():
    """Every socket the scheduler, the nanny, the worker and the dashboard listen on (this process
    and its children) is bound to a loopback address; the scheduler's and the dashboard's ports
    are among them, and the dashboard answers."""
    import urllib.request

    with cluster.Cluster(workers=1) as cl:
        found = listening(tree(os.getpid()))
        assert port_of(cl.cluster.scheduler_address) in {p for _, p in found}
        assert port_of(cl.dashboard) in {p for _, p in found}
        assert len(found) >= 4, found  # scheduler, dashboard, nanny, worker
        assert all(ipaddress.ip_address(ip).is_loopback for ip, _ in found), found
        with urllib.request.urlopen(cl.dashboard, timeout=30) as page:
            assert page.status == 200


def test_listen_reaches_every_component():
    """``listen`` (the CLI's --listen) is where every component listens: 127.0.0.2, another
    loopback address, shows it without exposing anything."""
    with cluster.Cluster(workers=1, listen="127.0.0.2") as cl:
        found = listening(tree(os.getpid()))
        assert cl.dashboard.startswith("http://127.0.0.2:")
        assert len(found) >= 4 and {ip for ip, _ in found} == {"127.0.0.2"}, found


def test_cli_dump_listens_on_loopback_only(tmp_path):
    """The sockets of a ``dump --workers 2`` (the command and every process it starts), looked
    at once all six are up (scheduler, dashboard, two nannies, two workers): loopback only."""
    import psutil

    p = subprocess.Popen([sys.executable, "-m", "gridrt", "dump", "--frames", "400", "--size", "64x48", "--workers",
                          "2", "--chunk", "2", "--no-progress", "--out", str(tmp_path / "d")], cwd=REPO,
                         stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, start_new_session=True)
    found = set()
    try:
        deadline = time.time() + 240
        while p.poll() is None and len(found) < 6 and time.time() < deadline:
            time.sleep(0.05)
            try:
                found = listening(tree(p.pid))
            except psutil.NoSuchProcess:
                pass
        assert p.poll() is None, p.stderr.read()
    finally:
        os.killpg(p.pid, signal.SIGKILL)
        p.communicate(timeout=60)
    assert len(found) >= 6, found
    assert all(ipaddress.ip_address(ip).is_loopback for ip, _ in found), found


@pytest.mark.slow  # (a real cluster or server started for it; the quick run keeps the dump's loopback check)
def test_listen_is_for_a_local_cluster_and_an_address_of_this_machine(tmp_path):
    line = one_error_line(gridrt("dump", "--frames", "1", "--listen", "127.0.0.1", "--out", tmp_path / "a"))
    assert "--listen applies to a local cluster" in line
    # 192.0.2.1 (TEST-NET-1, documentation only) is no address of this machine: nothing can bind it
    line = one_error_line(gridrt("dump", "--frames", "1", "--workers", "1", "--listen", "192.0.2.1",
                                 "--out", tmp_path / "b"))
    assert "did not start on 192.0.2.1" in line and "--listen" in line


@pytest.mark.parametrize("listen,problem", [(" ", "needs an address"), ("::1", "IPv6"), ("[::1]", "IPv6")])
def test_listen_refuses_what_dask_cannot_bind_alone(listen, problem):
    """An empty --listen, or an IPv6 address (for which Dask's dashboard would fall back to
    every interface)."""
    with pytest.raises(InputError, match=problem):
        cluster.Cluster(workers=1, listen=listen)


def test_cli_listen_is_refused_before_anything_starts(tmp_path):
    out = tmp_path / "d"
    line = one_error_line(gridrt("dump", "--frames", "1", "--workers", "1", "--listen", "::1", "--out", out))
    assert "IPv6" in line and not out.exists()  # (the dump's folder is not even made)


def test_listen_help_says_it_exposes_the_cluster():
    r = gridrt("dump", "--help")
    text = " ".join(r.stdout.split())
    assert "--listen HOST" in text and "EXPOSES THE CLUSTER TO THE NETWORK" in text


# ---------------------------------------------------------------------------------------------
# --scheduler: whatever is at the address, one line within the deadline
# ---------------------------------------------------------------------------------------------

class FakeServer:
    """A TCP server on 127.0.0.1 that does ``behave(conn)`` with each connection, keeps it open
    until the test ends (at most a minute), and stops by itself."""

    def __init__(self, behave):
        self.sock = socket.socket()
        self.sock.bind(("127.0.0.1", 0))
        self.sock.listen(8)
        self.sock.settimeout(0.2)
        self.port = self.sock.getsockname()[1]
        self.address = f"tcp://127.0.0.1:{self.port}"
        self.behave = behave
        self.stop = threading.Event()
        self.conns = []
        self.thread = threading.Thread(target=self._serve, daemon=True)
        self.thread.start()

    def _serve(self):
        end = time.time() + 60
        while not self.stop.is_set() and time.time() < end:
            try:
                conn, _ = self.sock.accept()
            except OSError:
                continue
            self.conns.append(conn)
            try:
                self.behave(conn)
            except OSError:
                pass

    def close(self):
        self.stop.set()
        self.thread.join(10)
        for c in self.conns:
            c.close()
        self.sock.close()


def frame(*words, tail=b""):
    return struct.pack(f"{len(words)}Q", *words) + tail


#: what a fake server sends at once on each connection
BEHAVIOURS = {
    "silent": lambda c: None,
    "http": lambda c: c.sendall(b"HTTP/1.1 400 Bad Request\r\nContent-Length: 0\r\n\r\n"),
    "huge length": lambda c: c.sendall(frame(2**62) + b"\0" * 64),
    "huge frame count": lambda c: c.sendall(frame(58, 2**40, 42, tail=b"\x80" * 42)),
    "frames that do not add up": lambda c: c.sendall(frame(58, 1, 4000, tail=b"\x80" * 42)),
    "a frame that is not msgpack": lambda c: c.sendall(frame(24, 1, 8, tail=b"\xc1" * 8)),
    "a few bytes, then silence": lambda c: c.sendall(b"\x07\x00"),
    "closes at once": lambda c: c.close(),
}


@pytest.fixture
def fake_server():
    made = []

    def make(behave):
        s = FakeServer(behave)
        made.append(s)
        return s

    yield make
    for s in made:
        s.close()


class Recorded:
    """A socket that records the timeouts it is given."""

    def __init__(self, sock, log):
        self._sock, self._log = sock, log

    def settimeout(self, t):
        self._log.append(t)
        self._sock.settimeout(t)

    def __getattr__(self, name):
        return getattr(self._sock, name)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self._sock.close()


@pytest.fixture
def timeouts(monkeypatch):
    """The timeouts (s) connect_scheduler hands its socket: the connection's and every read's."""
    log = []
    real = socket.create_connection

    def create_connection(address, timeout=None, **kw):
        log.append(timeout)
        return Recorded(real(address, timeout=timeout, **kw), log)

    monkeypatch.setattr(cluster.socket, "create_connection", create_connection)
    return log


@pytest.mark.parametrize("name", list(BEHAVIOURS))
def test_anything_but_a_scheduler_is_one_line_within_the_deadline(name, fake_server, timeouts):
    """A fake server of each kind: an InputError of one line naming the address; the socket is
    never given more time than the deadline (1 s here), and nothing is read beyond the first
    message's bound whatever the peer claims."""
    srv = fake_server(BEHAVIOURS[name])
    t0 = time.monotonic()
    with pytest.raises(InputError) as e:
        cluster.connect_scheduler(srv.address, timeout=1)
    assert time.monotonic() - t0 < SLACK_S
    message = str(e.value)
    assert "\n" not in message and f"127.0.0.1:{srv.port}" in message
    assert timeouts and all(t is not None and 0 < t <= 1 for t in timeouts), timeouts


@pytest.mark.slow  # (a real cluster or server started for it; the quick run keeps the dump's loopback check)
def test_the_deadline_is_the_issues_and_reaches_the_socket(fake_server, timeouts):
    """The default deadline (a silent port waits it out) is at most 10 s, and is what the
    connection and the reads get."""
    assert 0 < cluster.CONNECT_TIMEOUT <= 10
    srv = fake_server(BEHAVIOURS["silent"])
    t0 = time.monotonic()
    with pytest.raises(InputError, match="sends nothing"):
        cluster.connect_scheduler(srv.address)
    assert time.monotonic() - t0 < SLACK_S
    assert timeouts[0] == pytest.approx(cluster.CONNECT_TIMEOUT, abs=0.5)
    assert all(0 < t <= cluster.CONNECT_TIMEOUT for t in timeouts), timeouts


def test_closed_port(timeouts):
    with socket.socket() as s:  # a port just freed: nothing listens there
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    with pytest.raises(InputError, match="connection refused"):
        cluster.connect_scheduler(f"127.0.0.1:{port}", timeout=2)
    assert timeouts and 0 < timeouts[0] <= 2


def test_a_real_schedulers_greeting_passes_and_the_client_connects():
    """What a real scheduler (started here, on 127.0.0.1) sends first passes the check, and the
    Cluster connects to it, by name too."""
    from distributed import LocalCluster

    with LocalCluster(n_workers=0, processes=False, protocol="tcp://", host="127.0.0.1",
                      dashboard_address=None) as lc:
        port = port_of(lc.scheduler_address)
        shown, answered, _ = cluster.connect_scheduler(lc.scheduler_address, timeout=10)
        assert shown == answered == f"tcp://127.0.0.1:{port}"
        with socket.create_connection(("127.0.0.1", port), timeout=10) as s:
            s.settimeout(10)
            head = s.recv(8)
            (size,) = struct.unpack("Q", head)
            body = b""
            for _ in range(100):  # (a greeting of a few dozen bytes arrives in one or two reads)
                chunk = s.recv(size - len(body)) if len(body) < size else b""
                if not chunk:
                    break
                body += chunk
            assert len(body) == size
        assert cluster.greeting_problem(head + body) is None
        assert cluster.greeting_problem(head + body[:-1]) is not None
        with cluster.Cluster(scheduler=f"localhost:{port}") as cl:
            assert "localhost" in cl.where and "(0 workers)" in cl.where


def test_cli_scheduler_answering_like_http_is_one_line(tmp_path, fake_server):
    """From the command line: a server that answers with HTTP at once (whose first 8 bytes,
    read as Dask's length header, claim exabytes): exit status 2, one line, no traceback, no
    allocation from the header."""
    srv = fake_server(BEHAVIOURS["http"])
    t0 = time.monotonic()
    line = one_error_line(gridrt("dump", "--frames", "2", "--scheduler", srv.address, "--out", tmp_path / "d"))
    assert time.monotonic() - t0 < SLACK_S
    assert "does not answer as a Dask scheduler does" in line
    assert not (tmp_path / "d").exists() or not list((tmp_path / "d").glob("*.png"))


@pytest.mark.slow  # (a real cluster or server started for it; the quick run keeps the dump's loopback check)
def test_cli_real_http_server_is_one_line(tmp_path):
    """A real HTTP server (which waits for a request, as web servers do) on 127.0.0.1: one line
    after the deadline, not a traceback trying to allocate what its answer's bytes would say."""

    class Quiet(http.server.SimpleHTTPRequestHandler):
        def log_message(self, *args):
            pass

    srv = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Quiet)
    t = threading.Thread(target=srv.serve_forever, kwargs={"poll_interval": 0.1}, daemon=True)
    t.start()
    try:
        t0 = time.monotonic()
        r = gridrt("bench", "frame", "--quick", "--scheduler", f"127.0.0.1:{srv.server_address[1]}",
                   "--out", tmp_path / "b", timeout=120)
        line = one_error_line(r)
        assert time.monotonic() - t0 < SLACK_S + 10  # (the bench's parser loads more first)
        assert f"tcp://127.0.0.1:{srv.server_address[1]}" in line and "sends nothing" in line
    finally:
        srv.shutdown()
        srv.server_close()


def test_unresolvable_host_is_one_line(tmp_path):
    t0 = time.monotonic()
    line = one_error_line(gridrt("dump", "--frames", "2", "--scheduler", "tcp://nonexistent.invalid:8786",
                                 "--out", tmp_path / "d"))
    assert time.monotonic() - t0 < SLACK_S
    assert "cannot resolve" in line and "nonexistent.invalid" in line


def test_a_look_up_that_hangs_is_given_up_at_the_deadline(monkeypatch):
    """The system resolver takes no timeout: one that hangs (here until the test ends) is left
    behind in its thread at the deadline."""
    release = threading.Event()

    def hanging(*args, **kw):
        release.wait(60)
        raise socket.gaierror(socket.EAI_AGAIN, "gave up")

    monkeypatch.setattr(cluster.socket, "getaddrinfo", hanging)
    t0 = time.monotonic()
    try:
        with pytest.raises(InputError, match="not resolved within 1 s"):
            cluster.connect_scheduler("tcp://scheduler.example:8786", timeout=1)
        assert time.monotonic() - t0 < SLACK_S
    finally:
        release.set()


@pytest.mark.parametrize("address,problem", [
    ("tls://127.0.0.1:8786", "only tcp://"),
    ("ws://127.0.0.1:8786", "only tcp://"),
    ("tcp://127.0.0.1", "no port"),
    ("127.0.0.1:0", "no port"),
    ("tcp://127.0.0.1:99999", "out of range"),
    ("127.0.0.1:http", "not an address"),
    ("tcp://[::1:8786", "not an address"),
    ("tcp://127.0.0.1:8786/status", "not an address"),
    ("tcp://user@127.0.0.1:8786", "not an address"),
    ("tcp://:8786", "not an address"),
])
def test_malformed_addresses(address, problem):
    with pytest.raises(InputError) as e:
        cluster.scheduler_address(address)
    assert problem in str(e.value) and "\n" not in str(e.value) and "tcp://10.0.0.5:8786" in str(e.value)


@pytest.mark.parametrize("address,expected", [
    ("127.0.0.1:8786", ("127.0.0.1", 8786)),
    (" tcp://10.0.0.5:8786 ", ("10.0.0.5", 8786)),
    ("TCP://Scheduler.Example:9000", ("scheduler.example", 9000)),
    ("tcp://[::1]:8786", ("::1", 8786)),
])
def test_well_formed_addresses(address, expected):
    assert cluster.scheduler_address(address) == expected


def test_cli_malformed_address_is_one_line(tmp_path):
    line = one_error_line(gridrt("dump", "--frames", "2", "--scheduler", "tls://127.0.0.1:8786", "--out", tmp_path / "d"))
    assert "only tcp://" in line


# ---------------------------------------------------------------------------------------------
# --workers beyond what the machine holds
# ---------------------------------------------------------------------------------------------

@pytest.mark.slow  # (a real cluster or server started for it; the quick run keeps the dump's loopback check)
def test_cli_workers_beyond_the_machine_are_refused_before_anything_starts(tmp_path):
    cores = len(os.sched_getaffinity(0))
    out = tmp_path / "d"
    line = one_error_line(gridrt("dump", "--frames", "2", "--workers", "1000", "--out", out))
    assert f"1000 workers on {cores} cores" in line
    assert "of memory" in line and "available" in line and f"--workers {cores} or fewer" in line
    assert not out.exists()  # refused before the dump made its folder (and before any worker started)
    line = one_error_line(gridrt("bench", "build", "--quick", "--workers", "1000", "--out", tmp_path / "b",
                                 timeout=120))
    assert f"1000 workers on {cores} cores" in line
    # bench cluster checks each of its configurations before running the first
    line = one_error_line(gridrt("bench", "cluster", "--quick", "--configs", f"1p1,{cores + 1}x1",
                                 "--out", tmp_path / "c", timeout=120))
    assert f"{cores + 1} workers on {cores} cores" in line and not (tmp_path / "c" / "cluster.csv").exists()


def test_workers_are_checked_against_cores_and_memory(monkeypatch):
    """With 8 cores and room for two and a half workers: 2 fit, 3 are refused naming the memory
    (and not the cores), 9 naming both."""
    from gridrt.memory import human

    room = int(2.5 * cluster.WORKER_MEMORY)
    monkeypatch.setattr(cluster, "usable_cores", lambda: 8)
    monkeypatch.setattr(cluster, "memory_available", lambda: (room, "MemAvailable"))
    cluster.check_workers(1)
    cluster.check_workers(2)
    with pytest.raises(InputError) as e:
        cluster.check_workers(3)
    assert "cores" not in str(e.value).split("(")[0]
    assert f"{human(3 * cluster.WORKER_MEMORY)} of memory, {human(room)} available (MemAvailable)" in str(e.value)
    assert "--workers 2 or fewer" in str(e.value)
    with pytest.raises(InputError) as e:
        cluster.check_workers(9)
    assert "9 workers on 8 cores" in str(e.value) and "available (MemAvailable)" in str(e.value)
    monkeypatch.setattr(cluster, "memory_available", lambda: (cluster.WORKER_MEMORY // 2, "MemAvailable"))
    with pytest.raises(InputError, match="free some memory"):
        cluster.check_workers(1)


def test_one_or_two_workers_fit_here():
    if len(os.sched_getaffinity(0)) < 2:
        pytest.skip("fewer than 2 cores")
    cluster.check_workers(1)
    cluster.check_workers(2)


def test_memory_for_workers_is_the_machines_not_one_process_rlimit(monkeypatch):
    """The memory a cluster's workers share: the smallest of MemAvailable and the cgroups' room;
    an RLIMIT_AS of this process (which bounds each worker apart) is left out."""
    from gridrt import memory

    monkeypatch.setattr(memory, "readings", lambda: [("MemAvailable", 8 * 10**9), ("cgroup memory.max", 3 * 10**9),
                                                     ("RLIMIT_AS", 10**8)])
    assert cluster.memory_available() == (3 * 10**9, "cgroup memory.max")
    monkeypatch.setattr(memory, "readings", lambda: [("RLIMIT_DATA", 10**8)])
    assert cluster.memory_available() == (None, None)


# ---------------------------------------------------------------------------------------------
# Ctrl-C under load
# ---------------------------------------------------------------------------------------------

def cpu_hog(seconds):
    """A process that keeps a core busy for ``seconds`` (then ends by itself)."""
    return subprocess.Popen([sys.executable, "-c", f"import time\nend = time.time() + {seconds}\n"
                             "while time.time() < end: pass"])


def ctrl_c_under_load(tmp_path, frames_first):
    """SIGINT to the process group of a ``dump --workers 2`` once ``frames_first`` frames are
    on disk, with a CPU hog beside it: returns (returncode, stderr, the dump's processes)."""
    import psutil

    out = tmp_path / "d"
    hog = cpu_hog(240)
    p = subprocess.Popen([sys.executable, "-m", "gridrt", "dump", "--scene", "marbles", "--frames", "200",
                          "--size", "320x240", "--traversal", "dda", "--workers", "2", "--chunk", "2",
                          "--no-progress", "--out", str(out)], cwd=REPO, stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        deadline = time.time() + 240
        while (p.poll() is None and len(list(out.glob("frame_*.png"))) < frames_first
               and time.time() < deadline):
            time.sleep(0.02)
        assert p.poll() is None, "the dump ended before Ctrl-C: make its frames slower"
        procs = [psutil.Process(pid) for pid in tree(p.pid)]
        os.killpg(p.pid, signal.SIGINT)
        _, stderr = p.communicate(timeout=180)
    finally:
        hog.kill()
        hog.wait()
        if p.poll() is None:
            os.killpg(p.pid, signal.SIGKILL)
            p.wait()
    return p.returncode, stderr, procs


def assert_quiet_stop(returncode, stderr, procs):
    import psutil

    assert returncode != 0
    assert "Traceback" not in stderr, stderr
    assert all(line.startswith("gridrt: ") for line in stderr.splitlines() if line.strip()), stderr
    _, alive = psutil.wait_procs(procs, timeout=60)
    assert not alive, f"processes left running: {alive}"


@pytest.mark.slow  # (a fault on a real cluster under load)
def test_ctrl_c_of_a_cluster_dump_under_load_prints_no_traceback(tmp_path):
    """Ctrl-C with a CPU hog on the machine: the dump stops with gridrt's own lines only (no
    Dask log line, no traceback from a heartbeat or a connection closed while the cluster
    stops), and every process it started is gone."""
    assert_quiet_stop(*ctrl_c_under_load(tmp_path, 2))


@pytest.mark.soak
@pytest.mark.parametrize("frames_first", [1, 3, 6, 10, 16])
def test_ctrl_c_under_load_at_many_moments(tmp_path, frames_first):
    assert_quiet_stop(*ctrl_c_under_load(tmp_path, frames_first))
