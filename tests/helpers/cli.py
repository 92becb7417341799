"""Running the gridrt command in a subprocess and reading its one-line errors."""

import argparse
import os
import subprocess
import sys
from pathlib import Path

from gridrt.app.__main__ import build_parser

REPO = Path(__file__).resolve().parents[2]


def gridrt(*args, env=None, timeout=600):
    e = dict(os.environ)
    e.update(env or {})
    return subprocess.run([sys.executable, "-m", "gridrt", *args], cwd=REPO, capture_output=True, text=True,
                          env=e, timeout=timeout)


def cache_files(folder):
    """{path: (size, mtime in ns)} of the numba cache files (.nbi index, .nbc data) under folder."""
    files = [p for p in Path(folder).rglob("*") if p.suffix in (".nbi", ".nbc")]
    return {p: (p.stat().st_size, p.stat().st_mtime_ns) for p in files}


COMPILING = "Compiling numba kernels"


def stderr_lines(r):
    return [ln for ln in r.stderr.splitlines() if ln.strip() and not ln.startswith(COMPILING)]


def one_error(r, *words):
    """The single error line of a refused command (asserting exit status 2 and nothing else on stderr)."""
    lines = stderr_lines(r)
    assert r.returncode == 2, (r.returncode, r.stderr[-2000:])
    assert "Traceback" not in r.stderr and "Warning" not in r.stderr, r.stderr[-2000:]
    assert len(lines) == 1 and lines[0].startswith("gridrt: error: "), r.stderr[-2000:]
    for w in words:
        assert w in lines[0], lines[0]
    return lines[0]


def all_parsers():
    """(command words, parser) of gridrt and every subcommand, nested ones included."""
    todo = [("gridrt", build_parser())]
    while todo:
        name, p = todo.pop(0)
        yield name, p
        for a in p._actions:
            if isinstance(a, argparse._SubParsersAction):
                todo += [(f"{name} {n}", q) for n, q in a.choices.items()]
