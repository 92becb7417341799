"""Running the scripts behind BENCHMARKS.md's tables (scripts/) and reading the tables they print
and the tables BENCHMARKS.md holds."""

import re
import subprocess
import sys
from itertools import dropwhile, takewhile
from pathlib import Path

import pytest

from gridrt.app.bench.scenes import scene_available

REPO = Path(__file__).resolve().parents[2]
BENCHMARKS = REPO / "BENCHMARKS.md"
NUMBER = re.compile(r"-?\d+(\.\d+)?")


def cells(line):
    """The cells of a markdown table row."""
    return [c.strip() for c in line.strip().strip("|").split("|")]


def first_table(lines):
    """(header cells, [row cells]) of the first markdown table in ``lines``, and the lines after it."""
    rest = list(dropwhile(lambda ln: not ln.startswith("|"), lines))
    block = list(takewhile(lambda ln: ln.startswith("|"), rest))
    assert len(block) >= 2 and set(block[1]) <= set("|-: "), lines
    return cells(block[0]), [cells(ln) for ln in block[2:]], rest[len(block):]


def doc_table(script):
    """(header, rows) of the BENCHMARKS.md table whose source line's command runs scripts/<script>."""
    lines = BENCHMARKS.read_text(encoding="utf-8").split("\n")
    at = [i for i, ln in enumerate(lines) if ln.startswith("*Measured:*")
          and re.search(rf"python scripts/{re.escape(script)}[` ]", ln)]
    assert len(at) == 1, f"BENCHMARKS.md has {len(at)} source lines running scripts/{script}"
    return first_table(lines[at[0] + 1:])[:2]


def run_script(script, *args, timeout=600, printed=None):
    """(header, rows) of the one markdown table scripts/<script> prints with ``args``; exit code 0.
    ``printed``: a list that gets the script's standard output."""
    p = subprocess.run([sys.executable, str(REPO / "scripts" / script), *args], cwd=REPO, capture_output=True,
                       text=True, timeout=timeout)
    assert p.returncode == 0, p.stderr[-3000:]
    if printed is not None:
        printed.append(p.stdout)
    header, rows, rest = first_table(p.stdout.split("\n"))
    assert not any(ln.startswith("|") for ln in rest), p.stdout
    return header, rows


def needs(*scenes):
    """Skips the test when the development data set lacks any of the bench scene specs ``scenes``."""
    missing = [s for s in scenes if not scene_available(s)]
    return pytest.mark.skipif(bool(missing), reason=f"development data set lacks {', '.join(missing)}")
