"""``gridrt`` / ``python -m gridrt``: view | dump | bench | strategies."""

import argparse
import sys
import warnings

import gridrt  # noqa: F401  (sets NUMBA_NUM_THREADS before numba loads)
from gridrt.errors import GridrtError

from . import dump


def build_parser():
    p = argparse.ArgumentParser(prog="gridrt", description="Per-frame parallel uniform-grid ray tracer for "
                                "animated triangle scenes (Ize, Wald, Robertson, Parker, RT 2006).")
    sub = p.add_subparsers(dest="command", required=True)
    dump.add_parser(sub)
    from .bench import main as bench
    from .viewer import view

    view.add_parser(sub)
    bench.add_parser(sub)
    s = sub.add_parser("strategies", help="list the grid build strategies")
    s.set_defaults(func=_list_strategies)
    return p


def _list_strategies(a):
    from gridrt.grid.registry import BUILDERS, names

    for n in names():
        doc = (BUILDERS[n].__doc__ or "").strip().splitlines()
        print(f"{n:20s} {doc[0] if doc else ''}")
    return 0


def _show_warning(message, category, filename, lineno, file=None, line=None):
    """Warnings as one line, ``gridrt: warning: ...``, without Python's source line and location."""
    text = " ".join(str(message).split())
    try:
        print(f"gridrt: warning: {text}", file=sys.stderr if file is None else file, flush=True)
    except (OSError, ValueError):  # stderr closed: as warnings.showwarning, drop it
        pass


def main(argv=None):
    args = build_parser().parse_args(argv)
    with warnings.catch_warnings():  # restores the formatter when main returns (main may run in-process)
        warnings.showwarning = _show_warning
        try:
            return args.func(args) or 0
        except GridrtError as e:
            print(f"gridrt: error: {e}", file=sys.stderr)
            return 2
        except KeyboardInterrupt:
            return 130


if __name__ == "__main__":
    sys.exit(main())
