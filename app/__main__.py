"""``gridrt`` / ``python -m gridrt``: view | dump | bench | strategies."""

import argparse
import contextlib
import gc
import sys
import warnings

import gridrt  # noqa: F401  (sets NUMBA_NUM_THREADS before numba loads)
from gridrt.config import AUTO_STRATEGY, PARALLEL_DEFAULT_STRATEGY
from gridrt.errors import GridrtError
from gridrt.grid.registry import BUILDERS, names
from gridrt.memory import allocating
from gridrt.trace.twin import parallel_first

from . import cli, dump, exit_now


class DefaultsHelpFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """``--help`` shows every option's default: appended as ``(default: X)`` unless the help text
    already says it (``%(default)s``, or the word default, as for options whose default is a
    behaviour such as "all cores"); sizes print as WxH and vectors as X,Y,Z, as they are typed."""

    def _get_help_string(self, action):
        text = action.help or ""
        d = action.default
        if ("default" in text.lower() or not action.option_strings or d is None or d is argparse.SUPPRESS
                or isinstance(d, bool)):
            return text
        return (text + " " if text else "") + "(default: " + show_default(action).replace("%", "%%") + ")"


def show_default(action):
    """An option's default as it would be typed on the command line."""
    d = action.default
    if isinstance(d, (tuple, list)):
        sep = "x" if getattr(action.type, "__name__", "") == "size" else ","
        return sep.join(show_default(argparse.Namespace(default=x, type=None)) for x in d)
    if isinstance(d, float):
        return f"{d:g}"
    return str(d)


class Parser(argparse.ArgumentParser):
    """The gridrt parser: its subcommands' parsers are Parsers too (argparse makes subparsers of
    the parent's class), so every ``--help`` shows defaults (:class:`DefaultsHelpFormatter`)."""

    def __init__(self, *args, **kw):
        kw.setdefault("formatter_class", DefaultsHelpFormatter)
        super().__init__(*args, **kw)


def build_parser(command=None):
    """The command line's parser; with ``command="dump"`` only the dump's subcommand, so that a
    dump starts without importing the benchmarks and the viewer."""
    p = Parser(prog="gridrt", description="Per-frame parallel uniform-grid ray tracer for "
               "animated triangle scenes (Ize, Wald, Robertson, Parker, \"An Evaluation of Parallel Grid "
               "Construction for Ray Tracing Dynamic Scenes\", IEEE RT 2006).")
    sub = p.add_subparsers(dest="command", required=True)
    dump.add_parser(sub)
    if command == "dump":
        return p
    from .bench import main as bench  # deferred: the benchmarks (matplotlib, embreex...) are not a dump's
    from .viewer import view  # deferred: the viewer (glfw, moderngl, imgui_bundle) is not a dump's

    view.add_parser(sub)
    bench.add_parser(sub)
    s = sub.add_parser("strategies", help="list the grid build strategies")
    s.set_defaults(func=_list_strategies)
    return p


def _list_strategies(a):
    print(f"{AUTO_STRATEGY:20s} the default: serial at 1 thread, {PARALLEL_DEFAULT_STRATEGY} above (of the strategies that build "
          "the serial grid, cell lists in the same order, the fastest at 2 threads in BENCHMARKS.md section 2)")
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


def leave(code, finish=False):
    """The program's exit status ``code`` once its work is done.  When parallel kernels are still
    compiling in the background (gridrt.trace.twin): with ``finish`` and status 0 (a dump that
    did its work: batch work, whose next run should find the kernels cached), says so in one line
    and waits for the compile, which Ctrl-C skips; otherwise (the viewer, a failed or interrupted
    dump, or Ctrl-C) says in one line that it does not wait and ends the process at once
    (os._exit, after flushing stdout and stderr): the interpreter's shutdown then never runs
    beside the compiling thread, and numba's cache stays consistent (see gridrt.trace.twin)."""
    twin = sys.modules.get("gridrt.trace.twin")
    kernels = twin.TWINS.compiling() if twin is not None else []
    if not kernels:
        return code
    names = ", ".join(kernels)
    if finish and code == 0:
        try:
            print(f"gridrt: finishing the background compile of {names} for later runs (Ctrl-C skips it)",
                  file=sys.stderr, flush=True)
            twin.TWINS.wait()
            return code
        except KeyboardInterrupt:
            pass
        except (OSError, ValueError):  # stderr closed: as below, leave without waiting
            pass
    try:
        print(f"gridrt: not waiting for the background compile of {names} (it compiles again next start)",
              file=sys.stderr)
    except (OSError, ValueError):
        pass
    exit_now(code)


def main(argv=None):
    """The command line (``argv``: the arguments, default sys.argv's).  Run as the program (no
    ``argv``), it leaves through :func:`leave`, and its work done, freezes the garbage collector:
    the interpreter's shutdown then does not search every object left (numba's types, compiled
    libraries and dispatchers) for reference cycles, a tenth of a second of a warm one-frame dump;
    every file the command wrote is closed by then.  With ``argv`` (in-process) it returns the
    status."""
    if argv is None:
        argv = sys.argv[1:]
        code = leave(_main(argv), finish=argv[:1] == ["dump"])
        gc.freeze()
        return code
    return _main(list(argv))


def _main(argv):
    args = build_parser("dump" if argv[:1] == ["dump"] else None).parse_args(cli.join_negative_values(argv))
    if args.command == "bench":  # warm-up runs compile the parallel kernels the timed runs use
        kernels = parallel_first()
    else:
        kernels = contextlib.nullcontext()
    with warnings.catch_warnings(), kernels:  # restores the formatter when main returns (main may run in-process)
        warnings.showwarning = _show_warning
        try:
            with allocating(f"in gridrt {args.command}"):  # (a MemoryError the estimates missed: one line too)
                return args.func(args) or 0
        except GridrtError as e:
            print(f"gridrt: error: {e}", file=sys.stderr)
            return 2
        except KeyboardInterrupt:
            return 130


if __name__ == "__main__":
    sys.exit(main())
