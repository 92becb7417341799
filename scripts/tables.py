"""What the table scripts of this folder share: the names BENCHMARKS.md's tables give scenes, the
print-out of a script's settings, and the common scene, view, size and runs options.

The scripts import it as ``tables`` (their own folder is first on ``sys.path`` when run as
``python scripts/NAME.py``)."""

#: names the tables give the scenes of the development data set
NAMES = {"cesium": "Cesium Man", "lucy": "Lucy"}


def scene_label(text, n):
    """The table's name of a scene spec of n triangles: "Lucy 100k twisted", "Cesium Man 4.7k"."""
    base, *mods = text.split(":")
    count = f"{n / 1e6:.1f}M" if n >= 1e6 else f"{n / 1e3:.0f}k" if n >= 1e4 else f"{n / 1e3:.1f}k"
    return f"{NAMES.get(base, base)} {count}" + (" twisted" if "twist" in mods else "")


def print_settings(p, a):
    """Each option's value and where it comes from: the table (the option's default) or the command line."""
    for k, v in vars(a).items():
        print(f"{k}: {v} ({'the table' if v == p.get_default(k) else 'command line'})")


def items(text):
    """The non-empty items of a comma-separated option, stripped."""
    return [s.strip() for s in text.split(",") if s.strip()]


def add_ray_options(p, scenes, views, size, runs, what_views, what_runs):
    """--scenes, --views, --size and --runs, the table's values as defaults."""
    p.add_argument("--scenes", default=scenes,
                   help="comma-separated bench scene specs (default: the table's, %(default)s)")
    p.add_argument("--views", default=views, help=f"comma-separated {what_views} of bench peers (default: %(default)s)")
    p.add_argument("--size", type=int, default=size, help=f"size x size rays (default {size}, the table's)")
    p.add_argument("--runs", type=int, default=runs, help=f"{what_runs}, the best kept (default {runs}, the table's)")
