"""The benchmarks' output: the output folder, CSV and JSON files, markdown tables and summary.md,
matplotlib figures, progress bars, and the columns every row records about its grid."""

import csv
import functools
import json
import math
import sys
import textwrap
from pathlib import Path

from tqdm import tqdm

from gridrt.errors import InputError

from .machine import machine_md


def out_dir(path, what="output folder"):
    """The folder ``path``, made where missing; a clear error naming it (as ``what``) where it cannot be."""
    p = Path(path)
    try:
        p.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise InputError(f"cannot create {what} {p}: {e.strerror}") from None
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


#: the least size of a saved benchmark figure's text, in points, and the least resolution it is saved
#: at: 8 points at 110 dpi are 12 pixels
MIN_FONT = 8.0
MIN_DPI = 110
#: how many times its own width a figure may grow so that its x tick labels stand apart
MAX_WIDEN = 3.0
#: the angles x tick labels that would overlap level are turned to, in turn, in degrees
TICK_ANGLES = (45.0, 90.0)


def figure(nrows=1, ncols=1, w=5.0, h=3.6):
    """A matplotlib Figure on the Agg canvas (no display, no pyplot state) and its nrows x ncols axes
    (a 2-D array).  Its ``savefig`` makes it legible at the saved size first (:func:`legible`) and
    saves the area its artists cover (``bbox_inches="tight"``: nothing is cut) at MIN_DPI or more."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg  # deferred: matplotlib, slow to load; plots only

    fig = _bench_figure()(figsize=(w * ncols, h * nrows))
    FigureCanvasAgg(fig)
    return fig, fig.subplots(nrows, ncols, squeeze=False)


@functools.cache
def _bench_figure():
    """The Figure class of :func:`figure`, made on first use (matplotlib loads slowly)."""
    from matplotlib.figure import Figure  # deferred: matplotlib, slow to load; plots only

    class BenchFigure(Figure):
        """A Figure that keeps the arguments of its last tight_layout (:func:`legible` lays it out
        again with them) and is made legible before it is saved."""

        layout_kw = {}

        def tight_layout(self, **kw):
            self.layout_kw = kw
            super().tight_layout(**kw)

        def savefig(self, fname, **kw):
            legible(self)
            kw.setdefault("bbox_inches", "tight")
            kw["dpi"] = max(kw.get("dpi") or MIN_DPI, MIN_DPI)
            super().savefig(fname, **kw)

    return BenchFigure


def legible(fig):
    """Make ``fig`` legible at its size, once: text of MIN_FONT points at least; each axes' legend
    outside it, to its right (the figure widened by the widest legend of each column) and each
    figure legend right of all axes, so that no legend covers data; the layout done again
    (tight_layout, with the arguments it was last given); x tick labels that overlap turned
    (TICK_ANGLES), and the figure widened (MAX_WIDEN times at most) while they still do."""
    if getattr(fig, "made_legible", False):
        return
    fig.made_legible = True
    axes = [ax for ax in fig.axes if ax.get_visible()]
    _least_font(fig)
    _legends_beside(fig, axes)
    layout = getattr(fig, "layout_kw", {})
    fig.tight_layout(**layout)
    _wrap_labels(fig, axes)
    fig.tight_layout(**layout)
    _tick_labels_apart(fig, axes, layout)
    _figure_legends_right(fig, axes)


def _least_font(fig):
    """Every text of ``fig`` (tick labels through their axis, which keeps the size for the ticks it
    makes later) at MIN_FONT points at least."""
    from matplotlib.text import Text  # deferred: matplotlib, slow to load; plots only

    for ax in fig.axes:
        for axis in (ax.xaxis, ax.yaxis):
            if any(t.get_fontsize() < MIN_FONT for t in axis.get_ticklabels(which="both")):
                axis.set_tick_params(which="both", labelsize=MIN_FONT)
    for t in fig.findobj(Text):
        if t.get_fontsize() < MIN_FONT:
            t.set_fontsize(MIN_FONT)


def _legends_beside(fig, axes):
    """Each axes' legend outside it, its top left corner at the axes' top right; the figure wider by
    the widest legend of each column of axes."""
    renderer = fig.canvas.get_renderer()
    extra = {}
    for ax in axes:
        leg = ax.get_legend()
        if leg is None:
            continue
        leg.set_loc("upper left")
        leg.set_bbox_to_anchor((1.02, 1.0), transform=ax.transAxes)
        spec = ax.get_subplotspec()
        col = spec.colspan.stop if spec is not None else 0
        extra[col] = max(extra.get(col, 0.0), leg.get_window_extent(renderer).width / fig.dpi + 0.2)
    if extra:
        w, h = fig.get_size_inches()
        fig.set_size_inches(w + sum(extra.values()), h)


def _wrap_labels(fig, axes):
    """Each axes' x label and title wrapped onto lines as long as the axes are wide, its y label onto
    lines as long as they are high, where longer (so that they run into no neighbour)."""
    fig.draw_without_rendering()
    renderer = fig.canvas.get_renderer()
    for ax in axes:
        box = ax.get_window_extent(renderer)
        for t, side, along in ((ax.xaxis.label, box.width, "width"), (ax.title, box.width, "width"),
                               (ax.yaxis.label, box.height, "height")):
            text = t.get_text()
            length = getattr(t.get_window_extent(renderer), along)
            if "\n" not in text and length > side > 0:
                t.set_text(textwrap.fill(text, max(int(len(text) * side / length), 8)))


def _tick_labels(ax):
    """The x tick labels (major and minor) ``ax`` shows: visible, with text, inside its limits."""
    lo, hi = sorted(ax.get_xlim())
    ticks = ax.xaxis.get_major_ticks() + ax.xaxis.get_minor_ticks()
    return [t.label1 for t in ticks if t.label1.get_visible() and t.label1.get_text() and lo <= t.get_loc() <= hi]


def _crowding(ax, renderer):
    """How much wider ``ax`` must grow for its x tick labels to stand apart (1: they do): turned
    labels stand apart when the distance of their anchors times the sine of their angle is their
    height, level ones when their boxes do not overlap."""
    labels = sorted(_tick_labels(ax), key=lambda t: t.get_transform().transform(t.get_position())[0])
    need = 1.0
    for a, b in zip(labels, labels[1:]):
        ea, eb = a.get_window_extent(renderer), b.get_window_extent(renderer)
        if ea.x1 <= eb.x0 or ea.x0 >= eb.x1:
            continue
        d = abs(b.get_transform().transform(b.get_position())[0] - a.get_transform().transform(a.get_position())[0])
        sine = math.sin(math.radians(a.get_rotation() % 180))
        if sine > 0.05:
            height = (_level_height(a, renderer) + _level_height(b, renderer)) / 2
            need = max(need, height / (sine * max(d, 1e-9)) * 1.05)
        else:
            need = max(need, (eb.width + ea.width) / 2 / max(d, 1e-9) * 1.05)
    return need


def _level_height(t, renderer):
    """The height of the text ``t`` unturned, in pixels."""
    angle = t.get_rotation()
    t.set_rotation(0)
    h = t.get_window_extent(renderer).height
    t.set_rotation(angle)
    return h


def _tick_labels_apart(fig, axes, layout):
    """x tick labels that overlap turned (TICK_ANGLES, anchored at their end under their tick) until
    they stand apart, then the figure widened, MAX_WIDEN times at most, while they still overlap;
    laid out again after each change."""
    crowded = []
    for angle in TICK_ANGLES:
        fig.draw_without_rendering()
        crowded = [ax for ax in axes if _crowding(ax, fig.canvas.get_renderer()) > 1]
        if not crowded:
            return
        for ax in crowded:
            for t in ax.get_xticklabels(which="both"):
                t.set_rotation(angle)
                t.set_horizontalalignment("right" if angle < 90 else "center")
                t.set_rotation_mode("anchor" if angle < 90 else "default")
        fig.tight_layout(**layout)
    w0, h = fig.get_size_inches()
    for _ in range(4):
        fig.draw_without_rendering()
        need = max(_crowding(ax, fig.canvas.get_renderer()) for ax in crowded)
        w = fig.get_size_inches()[0]
        if need <= 1 or w >= w0 * MAX_WIDEN:
            return
        fig.set_size_inches(min(w * need, w0 * MAX_WIDEN), h)
        fig.tight_layout(**layout)


def _figure_legends_right(fig, axes):
    """Each figure legend (Figure.legend) right of all axes and what they show, centred in height."""
    if not fig.legends:
        return
    fig.draw_without_rendering()
    renderer = fig.canvas.get_renderer()
    right = max(ax.get_tightbbox(renderer).x1 for ax in axes) / fig.bbox.width
    for leg in fig.legends:
        leg.set_loc("center left")
        leg.set_bbox_to_anchor((right + 0.005, 0.5), transform=fig.transFigure)


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
