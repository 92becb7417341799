"""The benchmarks' output: the output folder, CSV and JSON files, markdown tables and summary.md,
matplotlib figures, progress bars, and the columns every row records about its grid."""

import csv
import json
import sys
from pathlib import Path

from tqdm import tqdm

from gridrt.errors import InputError

from .machine import machine_md


def out_dir(path):
    p = Path(path)
    try:
        p.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise InputError(f"cannot create output folder {p}: {e.strerror}") from None
    return p


def write_csv(rows, path):
    """Write rows (dicts, possibly with different keys) to a CSV; missing cells are empty."""
    cols = []
    for r in rows:
        for k in r:
            if k not in cols:
                cols.append(k)
    with open(path, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=cols, restval="")
        w.writeheader()
        for r in rows:
            w.writerow(r)


def write_json(obj, path):
    with open(path, "w") as fh:
        json.dump(obj, fh, indent=2, default=str)


def md_table(header, rows):
    """Markdown table from a header list and rows of cell strings."""
    out = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    for r in rows:
        out.append("| " + " | ".join(str(c) for c in r) + " |")
    return out


def write_summary(path, title, info, sections):
    """summary.md: a title, the machine record, then sections (heading, list of lines)."""
    lines = [f"# {title}", "", "## Machine", "", *machine_md(info), ""]
    for heading, body in sections:
        lines += [f"## {heading}", "", *body, ""]
    Path(path).write_text("\n".join(lines))


def figure(nrows=1, ncols=1, w=5.0, h=3.6):
    """A matplotlib Figure on the Agg canvas (no display, no pyplot state)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg  # deferred: matplotlib, slow to load; plots only
    from matplotlib.figure import Figure  # deferred: matplotlib, slow to load; plots only

    fig = Figure(figsize=(w * ncols, h * nrows))
    FigureCanvasAgg(fig)
    return fig, fig.subplots(nrows, ncols, squeeze=False)


def progress(total, desc, disable=False):
    return tqdm(total=total, desc=desc, file=sys.stderr, disable=disable, dynamic_ncols=True)


def grid_columns(p, stats):
    """The columns every benchmark row records about its grid, from the GridParams ``p`` it was built
    with and its stats (BuildStats, or a frame's FrameStats row): the kind asked for (``grid``:
    uniform, two_level or auto) and the kind built (``grid_built``), the two-level densities, cells
    (a two-level grid's leaf cells), references (its leaf references), grid_bytes and bytes_per_tri
    (grid_bytes / triangles)."""
    return dict(grid=p.grid, grid_built=stats["grid"], top_density=p.top_density, leaf_density=p.leaf_density,
                cells=int(stats["cells"]), references=int(stats["references"]), grid_bytes=int(stats["grid_bytes"]),
                bytes_per_tri=int(stats["grid_bytes"]) / max(int(stats["triangles"]), 1))


def grid_label(r, rows):
    """A row's grid kind, as " (two_level)", for its label in a table or plot of ``rows`` that hold
    more than one kind; "" when they hold one."""
    return f" ({r['grid']})" if len({x.get("grid", "uniform") for x in rows}) > 1 else ""
