"""BENCHMARKS.md is checked against the benchmarks' own output files.

Every table of BENCHMARKS.md has a source line right above it (a blank line between them is
allowed), which says where its figures come from::

    *Measured:* 2026-11-22 · *machine:* AMD EPYC · *command:* `gridrt bench core` · *output:* results/core/

* ``output: results/<name>/``: the folder that ``gridrt bench ... --out results/<name>``
  wrote (``summary.md``, the CSV files, ``machine.json``), committed.  The table's header must be
  the header of a table in that folder's ``summary.md`` and each of its rows one of that table's
  rows, cell for cell (a table may leave rows out, never change one); the date, the machine's CPU
  and the command must be the ones ``machine.json`` records.
* ``output: not kept``: figures measured before output folders were kept; the line still names
  the date, the machine and the command that measures them.

The documents describe the present: no commit hashes, no issue numbers and no history words
("was", "now", "since", ...) in README.md, BENCHMARKS.md and docs/.
"""

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
BENCHMARKS = REPO / "BENCHMARKS.md"
DOCUMENTS = [REPO / "README.md", BENCHMARKS] + sorted((REPO / "docs").glob("**/*.md"))

SOURCE = re.compile(r"^\*Measured:\* (?P<body>.*)$")
FIELDS = ("measured", "machine", "command", "output")


def parse_source(line):
    """{field: value} of a source line, or None when the line is not one.  Fields are separated
    by `` · `` and written ``*name:* value``."""
    if not line.startswith("*Measured:* "):
        return None
    out = {}
    for part in line.split(" · "):
        m = re.fullmatch(r"\*(\w+):\* (.+)", part.strip())
        if not m:
            return {"error": f"unreadable part {part!r}"}
        out[m.group(1).lower()] = m.group(2).strip()
    return out


def split_row(line):
    """The cells of a markdown table row (``\\|`` inside a cell is kept)."""
    cells = re.split(r"(?<!\\)\|", line.strip())
    return [c.strip() for c in cells[1:-1]]


def tables(text):
    """[(line number of the header, header cells, [row cells], source line or None)] of every
    markdown table in ``text``; the source line is the nearest non-blank line above the table."""
    lines = text.split("\n")
    out, i = [], 0
    in_code = False
    while i < len(lines):
        if lines[i].startswith("```"):
            in_code = not in_code
        rule = i + 1 < len(lines) and re.match(r"^\|[\s:|-]+\|$", lines[i + 1])
        if not in_code and lines[i].startswith("|") and rule:
            j = i + 2
            rows = []
            while j < len(lines) and lines[j].startswith("|"):
                rows.append(split_row(lines[j]))
                j += 1
            k = i - 1
            while k >= 0 and not lines[k].strip():
                k -= 1
            out.append((i + 1, split_row(lines[i]), rows, lines[k] if k >= 0 else None))
            i = j
            continue
        i += 1
    return out


def check_document(path, repo=REPO):
    """Problems (one line each, with the table's line) of a benchmarks document: tables without a
    source line, source lines without a field, and tables whose output folder disagrees."""
    problems = []
    text = Path(path).read_text(encoding="utf-8")
    for line, header, rows, above in tables(text):
        where = f"{Path(path).name}:{line}"
        src = parse_source(above or "")
        if src is None:
            problems.append(f"{where}: no '*Measured:* ...' source line above the table")
            continue
        if "error" in src:
            problems.append(f"{where}: {src['error']}")
            continue
        missing = [f for f in FIELDS if f not in src]
        if missing:
            problems.append(f"{where}: the source line lacks {', '.join(missing)}")
            continue
        if not re.fullmatch(r"\d{4}-\d{2}-\d{2}( to \d{4}-\d{2}-\d{2})?", src["measured"]):
            problems.append(f"{where}: measured {src['measured']!r} is not a date (YYYY-MM-DD)")
            continue
        if src["output"] == "not kept":
            continue
        problems += [f"{where}: {p}" for p in check_output(src, header, rows, repo)]
    return problems


def check_output(src, header, rows, repo=REPO):
    """Problems of a table that names its output folder: the folder's summary.md must hold a table
    with this header and every row of this one; machine.json's date, CPU and command must be the
    source line's."""
    folder = repo / src["output"].strip("`")
    if not (folder / "summary.md").is_file() or not (folder / "machine.json").is_file():
        return [f"output {src['output']} has no summary.md and machine.json"]
    problems = []
    machine = json.loads((folder / "machine.json").read_text(encoding="utf-8"))
    if machine.get("date", "")[:10] != src["measured"]:
        problems.append(f"measured {src['measured']} but machine.json says {machine.get('date')}")
    if not src["machine"].startswith(machine.get("cpu", "?")):
        problems.append(f"machine {src['machine']!r} but machine.json says {machine.get('cpu')!r}")
    if src["command"].strip("`") != machine.get("command"):
        problems.append(f"command {src['command']} but machine.json says `{machine.get('command')}`")
    candidates = [t for t in tables((folder / "summary.md").read_text(encoding="utf-8")) if t[1] == header]
    if not candidates:
        return problems + [f"no table of {src['output']}summary.md has the header {header}"]
    have = [r for t in candidates for r in t[2]]
    for r in rows:
        if r not in have:
            problems.append(f"row {r} is not in {src['output']}summary.md")
    return problems


def test_every_table_says_where_it_comes_from_and_agrees_with_its_output():
    problems = check_document(BENCHMARKS)
    assert not problems, "BENCHMARKS.md:\n" + "\n".join(problems)
    assert len(tables(BENCHMARKS.read_text(encoding="utf-8"))) >= 10


def test_backed_and_unbacked_tables_are_listed():
    """Which tables come from committed output folders, and which were measured before they were
    kept (printed with -s; the test only checks both lists cover every table)."""
    found = tables(BENCHMARKS.read_text(encoding="utf-8"))
    output = [(n, (parse_source(s or "") or {}).get("output")) for n, _, _, s in found]
    backed = [(n, o) for n, o in output if o not in (None, "not kept")]
    unbacked = [n for n, o in output if o == "not kept"]
    print(f"BENCHMARKS.md: {len(backed)} tables backed by output files {backed}, "
          f"{len(unbacked)} without (lines {unbacked})")
    assert len(backed) + len(unbacked) == len(found)


HASH = re.compile(r"(?<![\w/.-])(?=[0-9a-f]*\d)(?=[0-9a-f]*[a-f])[0-9a-f]{7,40}(?![\w-])")
ISSUE = re.compile(r"\b(issue|point|PR)\s*#?\d+|#\d{2,}\b", re.I)


@pytest.mark.parametrize("doc", DOCUMENTS, ids=lambda p: str(p.relative_to(REPO)))
def test_documents_name_no_commit_or_issue(doc):
    bad = []
    for i, line in enumerate(doc.read_text(encoding="utf-8").split("\n"), 1):
        for m in list(HASH.finditer(line)) + list(ISSUE.finditer(line)):
            bad.append(f"{doc.name}:{i}: {m.group(0)!r} in {line.strip()[:100]}")
    assert not bad, "commit hashes or issue numbers in a document:\n" + "\n".join(bad)


HISTORY = re.compile(r"\b(was|were|now|since|used to|previously|no longer)\b", re.I)


@pytest.mark.parametrize("doc", DOCUMENTS, ids=lambda p: str(p.relative_to(REPO)))
def test_documents_describe_the_present(doc):
    """No diary: the documents say what is true and how to measure it, not what changed."""
    bad = [f"{doc.name}:{i}: {m.group(0)!r} in {line.strip()[:100]}"
           for i, line in enumerate(doc.read_text(encoding="utf-8").split("\n"), 1) for m in HISTORY.finditer(line)]
    assert not bad, "history words in a document:\n" + "\n".join(bad)


def test_history_and_hash_checks_catch_a_planted_line(tmp_path):
    # the tracker reference is assembled here, so that this file itself holds none
    tracker = "issue " + str(12)
    line = f"The build was 2x slower before 1a2b3c4d ({tracker}), and now it is not."
    assert [m.group(0) for m in HISTORY.finditer(line)] == ["was", "now"]
    assert [m.group(0) for m in HASH.finditer(line)] == ["1a2b3c4d"]
    assert [m.group(0) for m in ISSUE.finditer(line)] == [tracker]
    assert not HASH.search("icosphere:1310720 at 1e-5, 2026-12-03, 0.5 s") and not HISTORY.search("nowhere washed")


# ----------------------------------------------------------------------------------------------
# the checker fails when it should: a synthetic output folder and document


SUMMARY = """# gridrt bench core

## Results

| scene | triangles | what | threads | ms median [min-max] |
|---|---|---|---|---|
| icosphere | 1,280 | serial build bbox | 1 | 6.2 [6.2-6.2] |
| icosphere | 1,280 | serial build exact | 1 | 1.1 [1.1-1.1] |
"""
MACHINE = {"date": "2026-12-03T09:35:00+00:00", "cpu": "AMD EPYC", "cores": 2,
           "command": "gridrt bench core --quick --out results/core"}
SOURCE_LINE = ("*Measured:* 2026-12-03 · *machine:* AMD EPYC, 2 cores · "
               "*command:* `gridrt bench core --quick --out results/core` · *output:* results/core/")
TABLE = """| scene | triangles | what | threads | ms median [min-max] |
|---|---|---|---|---|
| icosphere | 1,280 | serial build exact | 1 | 1.1 [1.1-1.1] |
"""


def synthetic(tmp_path, doc, summary=SUMMARY, machine=MACHINE):
    out = tmp_path / "results" / "core"
    out.mkdir(parents=True)
    (out / "summary.md").write_text(summary)
    (out / "machine.json").write_text(json.dumps(machine))
    (tmp_path / "B.md").write_text(doc)
    return check_document(tmp_path / "B.md", repo=tmp_path)


def test_checker_passes_a_table_taken_from_its_output(tmp_path):
    unbacked = ("*Measured:* 2026-11-22 · *machine:* Intel Xeon, 2 vCPUs · *command:* `gridrt bench build` · "
                "*output:* not kept\n\n| a | b |\n|---|---|\n| 1 | 2 |\n")
    assert synthetic(tmp_path, f"# B\n\n{SOURCE_LINE}\n\n{TABLE}\ntext\n\n{unbacked}") == []


def test_checker_catches_a_changed_figure(tmp_path):
    problems = synthetic(tmp_path, f"{SOURCE_LINE}\n\n{TABLE.replace('1.1 [1.1-1.1]', '1.0 [1.1-1.1]')}")
    assert len(problems) == 1 and "B.md:3: row" in problems[0] and "1.0 [1.1-1.1]" in problems[0], problems


def test_checker_catches_a_table_without_source(tmp_path):
    doc = f"{SOURCE_LINE}\n\n{TABLE}\nA sentence.\n\n{TABLE}"
    problems = synthetic(tmp_path, doc)
    second = tables(doc)[1][0]
    assert problems == [f"B.md:{second}: no '*Measured:* ...' source line above the table"], problems


def test_checker_catches_a_wrong_date_machine_or_command(tmp_path):
    line = SOURCE_LINE.replace("2026-12-03", "2026-12-02").replace("AMD EPYC", "Intel Xeon").replace(
        "--quick ", "")
    problems = synthetic(tmp_path, f"{line}\n\n{TABLE}")
    assert len(problems) == 3 and all(p.startswith("B.md:3: ") for p in problems), problems
    assert "machine.json says 2026-12-03" in problems[0] and "'AMD EPYC'" in problems[1] and "command" in problems[2]


def test_checker_catches_a_missing_output_or_field(tmp_path):
    gone = SOURCE_LINE.replace("results/core/", "results/frame/")
    no_date = SOURCE_LINE.replace("*Measured:* 2026-12-03", "*Measured:* last week")
    no_output = SOURCE_LINE.split(" · *output:*")[0]
    doc = f"{gone}\n\n{TABLE}\n{no_date}\n\n{TABLE}\n{no_output}\n\n{TABLE}"
    problems = synthetic(tmp_path, doc)
    a, b, c = (t[0] for t in tables(doc))
    assert problems == [
        f"B.md:{a}: output results/frame/ has no summary.md and machine.json",
        f"B.md:{b}: measured 'last week' is not a date (YYYY-MM-DD)",
        f"B.md:{c}: the source line lacks output",
    ], problems


@pytest.mark.slow
def test_a_quick_benchmark_run_backs_a_table(tmp_path):
    """A real run: ``gridrt bench core --quick`` writes an output folder; its summary's first row,
    with a source line made from its machine.json, passes the check, and passes no longer once a
    figure in it is changed."""
    out = tmp_path / "results" / "core"
    cmd = [sys.executable, "-m", "gridrt", "bench", "core", "--quick", "--no-progress", "--out", str(out)]
    r = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, timeout=1200)
    assert r.returncode == 0, r.stderr[-2000:]
    machine = json.loads((out / "machine.json").read_text())
    line, header, rows, _ = tables((out / "summary.md").read_text())[0]
    source = (f"*Measured:* {machine['date'][:10]} · *machine:* {machine['cpu']}, {machine['cores']} cores · "
              f"*command:* `{machine['command']}` · *output:* results/core/")
    table = "| " + " | ".join(header) + " |\n|" + "---|" * len(header) + "\n| " + " | ".join(rows[0]) + " |\n"
    (tmp_path / "B.md").write_text(f"{source}\n\n{table}")
    assert check_document(tmp_path / "B.md", repo=tmp_path) == []
    changed = rows[0][:-1] + [rows[0][-1] + "0"]
    (tmp_path / "B.md").write_text(f"{source}\n\n" + table.replace(" | ".join(rows[0]), " | ".join(changed)))
    assert len(check_document(tmp_path / "B.md", repo=tmp_path)) == 1
