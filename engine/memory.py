"""How much memory this process may still take, and the check every large allocation passes first.

:func:`available` is the memory the process can still allocate: the smallest of

* ``MemAvailable`` of ``/proc/meminfo`` (what the kernel can hand out without swapping),
* the cgroup's memory limit minus its usage, for the process's cgroup and each cgroup above it
  that sets one (cgroup v2 ``memory.max`` - ``memory.current``; v1 ``memory.limit_in_bytes`` -
  ``memory.usage_in_bytes``),
* ``RLIMIT_AS`` minus the process's address space (``VmSize``) and ``RLIMIT_DATA`` minus its data
  segment (``VmData``), when those limits are set (``resource.getrlimit``).

Every entry point that allocates in proportion to its input (a batch cast, a subdivision, a grid's
cells and references, a frame's buffers) estimates its bytes first, from the arrays its code
allocates, and calls :func:`check_fits`, which refuses the work with one line stating the
estimate, the limit and the way out.  :func:`allocating` turns a MemoryError that gets past an
estimate (another process took the memory meanwhile) into the same kind of InputError.
"""

import contextlib
import os
import resource

from .errors import InputError

#: estimates below this many bytes are not checked against :func:`available` (reading the limits
#: costs tens of microseconds; a failure that small is left to :func:`allocating`)
CHECK_ABOVE = 32 << 20

#: cgroup v1 writes a limit near 2**63 for "no limit"
_NO_V1_LIMIT = 1 << 60


def _read(path):
    try:
        with open(path) as fh:
            return fh.read()
    except OSError:
        return None


def _kib_field(text, name):
    """The value of ``name:   123 kB`` in a /proc file's text, in bytes, or None."""
    for line in (text or "").splitlines():
        key, _, rest = line.partition(":")
        if key == name:
            parts = rest.split()
            if parts and parts[0].isdigit():
                return int(parts[0]) * (1024 if parts[1:2] == ["kB"] else 1)
    return None


def _number(text):
    text = (text or "").strip()
    return int(text) if text.isdigit() else None


def _ancestors(rel):
    """``rel`` ("/a/b") and every cgroup above it, leaf first, as paths relative to the hierarchy's
    root ("a/b", "a", "")."""
    parts = [p for p in rel.split("/") if p and p not in (".", "..")]
    return ["/".join(parts[:i]) for i in range(len(parts), -1, -1)]


def _cgroup_headroom(root, proc_cgroup):
    """[(source, bytes)]: limit minus usage of each cgroup on the process's path that sets a limit."""
    out = []
    for line in (proc_cgroup or "").splitlines():
        hid, _, rest = line.partition(":")
        controllers, _, rel = rest.partition(":")
        if hid == "0" and controllers == "":  # cgroup v2 (unified); hybrid systems mount it under unified/
            for base in ("sys/fs/cgroup", "sys/fs/cgroup/unified"):
                for d in _ancestors(rel):
                    lim = _number(_read(os.path.join(root, base, d, "memory.max")))
                    use = _number(_read(os.path.join(root, base, d, "memory.current")))
                    if lim is not None and use is not None:
                        out.append(("cgroup memory.max", lim - use))
        elif "memory" in controllers.split(","):  # cgroup v1
            for d in _ancestors(rel):
                base = os.path.join(root, "sys/fs/cgroup/memory", d)
                lim = _number(_read(os.path.join(base, "memory.limit_in_bytes")))
                use = _number(_read(os.path.join(base, "memory.usage_in_bytes")))
                if lim is not None and use is not None and lim < _NO_V1_LIMIT:
                    out.append(("cgroup memory.limit_in_bytes", lim - use))
    return out


def readings(root="/", getrlimit=resource.getrlimit):
    """[(source, bytes)]: every limit on this process's memory that applies, as the bytes it still
    leaves (see the module doc): ``MemAvailable``, ``cgroup memory.max``, ``cgroup
    memory.limit_in_bytes``, ``RLIMIT_AS``, ``RLIMIT_DATA``.  ``root``: where ``proc/`` and
    ``sys/`` are read from; ``getrlimit``: as :func:`resource.getrlimit` (tests pass fakes)."""
    out = []
    meminfo = _kib_field(_read(os.path.join(root, "proc/meminfo")), "MemAvailable")
    if meminfo is not None:
        out.append(("MemAvailable", meminfo))
    out += _cgroup_headroom(root, _read(os.path.join(root, "proc/self/cgroup")))
    status = _read(os.path.join(root, "proc/self/status"))
    for name, field in (("RLIMIT_AS", "VmSize"), ("RLIMIT_DATA", "VmData")):
        soft = getrlimit(getattr(resource, name))[0]
        used = _kib_field(status, field)
        if soft != resource.RLIM_INFINITY and soft >= 0 and used is not None:
            out.append((name, soft - used))
    return [(source, max(0, int(b))) for source, b in out]


def available():
    """(bytes, source): the memory this process can still allocate, the smallest of
    :func:`readings`, and the name of the limit that gives it; (None, None) where none can be read
    (no /proc: nothing is refused then)."""
    r = readings()
    if not r:
        return None, None
    source, b = min(r, key=lambda x: x[1])
    return b, source


def cap_address_space(share):
    """Limit this process's address space (``RLIMIT_AS``, soft) to what it maps now (``VmSize``)
    plus ``share`` times :func:`available`, never above the limits already set; returns the cap in
    bytes, or None where the limits cannot be read.  Used by a process that runs beside another
    doing the same work (gridrt.coldstart's helper): what would not fit twice fails there
    (InputError from :func:`check_fits`, or MemoryError), not in the other process."""
    avail, _ = available()
    used = _kib_field(_read("/proc/self/status"), "VmSize")
    if avail is None or used is None:
        return None
    soft, hard = resource.getrlimit(resource.RLIMIT_AS)
    cap = used + int(share * avail)
    for limit in (soft, hard):
        if limit != resource.RLIM_INFINITY and limit >= 0:
            cap = min(cap, limit)
    resource.setrlimit(resource.RLIMIT_AS, (cap, hard))
    return cap


def human(n):
    """Bytes as text in decimal units: ``2.6 GB``, ``310 MB``, ``12 kB``, ``512 bytes``."""
    n = float(n)
    for unit, scale in (("TB", 1e12), ("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if n >= scale:
            v = n / scale
            return f"{v:.1f} {unit}" if v < 10 else f"{v:,.0f} {unit}"
    return f"{n:.0f} bytes"


def check_fits(need, what, parts, advice):
    """InputError when ``need`` bytes, the estimate of ``what`` ("casting 50,000,000 rays"), exceed
    :func:`available`; the message states the estimate, what it counts (``parts``), the limit and
    ``advice`` (text, or a function of the available bytes giving it).  Needs under
    :data:`CHECK_ABOVE` are not checked."""
    if need < CHECK_ABOVE:
        return
    avail, source = available()
    if avail is None or need <= avail:
        return
    tip = advice(avail) if callable(advice) else advice
    raise InputError(f"{what} needs about {human(need)} ({parts}); {human(avail)} is available ({source}); {tip}")


@contextlib.contextmanager
def allocating(what, advice="free memory or ask for less"):
    """A MemoryError inside the block becomes one InputError naming what was being allocated
    (``what``: text such as "casting 1,000 rays", or a function giving it, called only then) and
    the memory available now: the safety net behind the estimates."""
    try:
        yield
    except MemoryError:
        avail, source = available()
        now = f"; {human(avail)} is available ({source})" if avail is not None else ""
        raise InputError(f"out of memory {what() if callable(what) else what}{now}; {advice}") from None


#: bytes per pixel a render allocates: its image, t, triangle, cost and cell buffers (4 each, kept
#: from frame to frame by a Renderer) and the hit mask of its statistics (1)
RENDER_PIXEL_BYTES = 21
#: bytes per pixel of the material pass's shadows (Renderer._shade_material): the deferred surface
#: points, normals, light terms and sums (84), a light's need flags, shadow rays and weights (65),
#: and the cast of a light's rays, at most one a pixel: their rows (8), origins and directions
#: (48) and their contiguous copies (48), blocked and live flags and rows (17), results (28) and
#: their grouping into packets (33)
SHADOW_PIXEL_BYTES = 331
#: bytes per pixel and light drawn (RenderParams.light_samples): its light and factor (12) and its
#: segment (gridrt.trace.material.drawn_segments: row, origin, direction, grids and weight, 65)
DRAWN_LIGHT_BYTES = 77


def render_bytes(width, height, shadows=False, buffers=True, light_samples=0):
    """Bytes a render of ``width`` x ``height`` pixels allocates at its peak: the output buffers
    (``buffers=False``: a Renderer that already holds them at that size) and, for the material
    mode with shadows (``shadows``), the scratch of its shadow rays, with the lights drawn per
    pixel where ``light_samples`` (RenderParams.light_samples) draws them."""
    n = int(width) * int(height)
    drawn = DRAWN_LIGHT_BYTES * int(light_samples) if shadows else 0
    return n * ((RENDER_PIXEL_BYTES if buffers else 1) + (SHADOW_PIXEL_BYTES if shadows else 0) + drawn)


def check_render_fits(width, height, shadows=False, buffers=True, what="rendering", light_samples=0):
    """InputError (gridrt.memory.check_fits) when :func:`render_bytes` exceed the memory this
    process has left, stating both and the most pixels that fit."""
    check_fits(render_bytes(width, height, shadows, buffers, light_samples), f"{what} {width:,}x{height:,} pixels",
               "image, depth, triangle, cost and cell buffers" + (" and shadow rays" if shadows else ""),
               lambda avail: f"ask for at most {avail // render_bytes(1, 1, shadows, True, light_samples):,} pixels")
