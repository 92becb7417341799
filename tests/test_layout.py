"""The package's architecture, read from the source with ``ast`` (nothing checked is imported).

* The engine never imports the app (only ``gridrt.__main__``, the entry point, does).
* No import cycle exists among gridrt's modules, counting the imports inside functions too.
* No numba-compiled function takes more than :data:`MAX_KERNEL_PARAMS` parameters: kernels take
  a few records, not long argument lists.
* A jitted function that no Python code uses (only other kernels call it) is compiled with
  ``gridrt.compiles.inner``, which makes no Python entry point for it (compile time).
* Every import inside a function says why it is deferred, on its first line, with a trailing
  comment ``# deferred: <which dependency and why>``.

Each check reports every offender (file:line and name).  The checkers take the package map
(package name -> folder) as an argument, so the tests at the end run them on small synthetic
packages with a planted offence to show that each check fails when it should.
"""

import ast
import functools
import io
import re
import tokenize
import tomllib
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
#: the most parameters a numba-compiled function may take (defaults, *args and **kwargs count)
MAX_KERNEL_PARAMS = 10
#: the numba functions that compile the function they decorate or are applied to
COMPILERS = {"numba.njit", "numba.jit", "numba.generated_jit", "numba.cfunc", "numba.vectorize",
             "numba.guvectorize", "numba.stencil", "numba.core.decorators.njit", "numba.core.decorators.jit"}
#: the package's own decorator for kernels that only kernels call (``<package>.compiles.inner``)
INNER = ".compiles.inner"
DEFERRED = re.compile(r"#\s*deferred:\s*\S")


def package_roots(repo=REPO):
    """{package name: folder} of the installed package gridrt and its app, from pyproject.toml's
    package-dir (engine/ is gridrt, app/ is gridrt.app)."""
    dirs = tomllib.loads((repo / "pyproject.toml").read_text())["tool"]["setuptools"]["package-dir"]
    return {pkg: repo / dirs[pkg] for pkg in ("gridrt", "gridrt.app")}


ROOTS = package_roots()


def modules(roots=None):
    """{module name: path} of every module under the package folders ``roots`` (a folder that is
    the root of a nested package in ``roots`` belongs to that package)."""
    roots = ROOTS if roots is None else roots
    out = {}
    folders = {Path(f).resolve() for f in roots.values()}
    for pkg, root in roots.items():
        root = Path(root)
        for p in sorted(root.rglob("*.py")):
            if "__pycache__" in p.parts:
                continue
            # a file inside another root's folder is that root's (gridrt.app lives in app/, not engine/)
            if any(f != root.resolve() and f in p.resolve().parents and root.resolve() in f.parents
                   for f in folders):
                continue
            rel = p.relative_to(root).with_suffix("").parts
            parts = rel[:-1] if rel[-1] == "__init__" else rel
            out[".".join((pkg,) + parts)] = p
    return out


def _parse(path):
    """The module's syntax tree (parsed once per path and content: the checks read the same files
    many times; nothing changes the trees)."""
    path = Path(path)
    return _parse_text(str(path), path.read_text())


@functools.lru_cache(maxsize=None)
def _parse_text(name, text):
    return ast.parse(text, filename=name)


@functools.lru_cache(maxsize=None)
def _nodes(tree):
    """Every node of a syntax tree (ast.walk's order), listed once per tree: the checks walk the
    same cached trees many times."""
    return list(ast.walk(tree))


def _imported_names(mod, is_pkg, node):
    """Absolute names an Import / ImportFrom node names: for ``from P import a`` both P and P.a
    (P.a counts only where it is a module); relative imports resolved against ``mod``."""
    if isinstance(node, ast.Import):
        return [a.name for a in node.names]
    if node.level:
        base = mod.split(".")
        if not is_pkg:
            base = base[:-1]
        base = base[: len(base) - (node.level - 1)]
        prefix = ".".join(base + ([node.module] if node.module else []))
    else:
        prefix = node.module
    return [prefix] + [f"{prefix}.{a.name}" for a in node.names]


def _function_nodes(tree):
    """ids of the Import / ImportFrom nodes inside a function body (at any depth)."""
    inner = set()
    for fn in _nodes(tree):
        if isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
            for n in ast.walk(fn):
                if isinstance(n, (ast.Import, ast.ImportFrom)):
                    inner.add(id(n))
    return inner


def import_graph(roots=None, top_level_only=False):
    """{module: {imported module: [line, ...]}} over the package's own modules.  Every import
    statement counts (inside functions too unless ``top_level_only``); ``from P import a`` is an
    edge to P (its ``__init__`` runs first) and, when P.a is a module, to P.a, so a package whose
    ``__init__`` imports a submodule that imports the package (``from . import sibling``) is a
    cycle."""
    mods = modules(roots)
    graph = {}
    for mod, path in mods.items():
        tree = _parse(path)
        nodes = tree.body if top_level_only else _nodes(tree)
        edges = {}
        for node in nodes:
            if isinstance(node, (ast.Import, ast.ImportFrom)):
                for name in _imported_names(mod, path.name == "__init__.py", node):
                    if name in mods and name != mod:
                        edges.setdefault(name, []).append(node.lineno)
        graph[mod] = edges
    return graph


def strongly_connected(graph):
    """The strongly connected components with more than one module (each an import cycle), each
    sorted, in sorted order (Tarjan's algorithm, iterative)."""
    index, low, on, stack, out = {}, {}, set(), [], []
    counter = 0
    for root in sorted(graph):
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on.add(root)
        while work:
            v, it = work[-1]
            for w in it:
                if w not in index:
                    index[w] = low[w] = counter
                    counter += 1
                    stack.append(w)
                    on.add(w)
                    work.append((w, iter(sorted(graph.get(w, ())))))
                    break
                if w in on:
                    low[v] = min(low[v], index[w])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[v])
                if low[v] == index[v]:
                    comp = []
                    while True:
                        w = stack.pop()
                        on.discard(w)
                        comp.append(w)
                        if w == v:
                            break
                    if len(comp) > 1:
                        out.append(sorted(comp))
    return sorted(out)


def import_cycles(roots=None):
    """Every import cycle as lines ``a -> b (path:line, ...)``: the edges inside each strongly
    connected component of the import graph (imports inside functions counted)."""
    roots = ROOTS if roots is None else roots
    mods = modules(roots)
    graph = import_graph(roots)
    report = []
    for comp in strongly_connected(graph):
        inside = set(comp)
        report.append("cycle among " + ", ".join(comp) + ":")
        for a in comp:
            for b in sorted(set(graph[a]) & inside):
                where = ", ".join(f"{_rel(mods[a])}:{n}" for n in graph[a][b])
                report.append(f"  {a} -> {b} ({where})")
    return report


def _rel(path):
    path = Path(path)
    try:
        return str(path.relative_to(REPO))
    except ValueError:
        return str(path)


@functools.lru_cache(maxsize=None)
def _aliases(tree, mod="", is_pkg=False):
    """{local name: absolute dotted name} of the module's imports (``import numba as nb`` gives
    nb -> numba, ``from numba import njit as nj`` gives nj -> numba.njit; relative imports are
    resolved against the module ``mod``)."""
    out = {}
    for node in _nodes(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                if a.asname:
                    out[a.asname] = a.name
                else:
                    out[a.name.split(".")[0]] = a.name.split(".")[0]
        elif isinstance(node, ast.ImportFrom) and (node.module or node.level):
            prefix = _imported_names(mod, is_pkg, node)[0] if node.level else node.module
            for a in node.names:
                out[a.asname or a.name] = f"{prefix}.{a.name}"
    return out


def _dotted(expr, aliases):
    """The absolute dotted name of a Name / Attribute chain, through the module's imports."""
    parts = []
    while isinstance(expr, ast.Attribute):
        parts.append(expr.attr)
        expr = expr.value
    if not isinstance(expr, ast.Name):
        return None
    head = aliases.get(expr.id, expr.id)
    return ".".join([head] + parts[::-1])


def _is_inner(expr, aliases):
    """True for the package's ``inner`` or ``inner(...)`` (any arguments)."""
    if isinstance(expr, ast.Call):
        expr = expr.func
    return f".{_dotted(expr, aliases) or ''}".endswith(INNER)


def _is_compiler(expr, aliases):
    """True for ``njit``, ``njit(...)``, ``numba.jit(...)``, the package's ``inner(...)`` and the
    like (any arguments)."""
    if _is_inner(expr, aliases):
        return True
    if isinstance(expr, ast.Call):
        expr = expr.func
    return _dotted(expr, aliases) in COMPILERS


def count_params(fn):
    a = fn.args
    return len(a.posonlyargs) + len(a.args) + len(a.kwonlyargs) + (a.vararg is not None) + (a.kwarg is not None)


def compiled_functions(roots=None):
    """[(path, line, name, parameters)] of every function numba compiles: decorated with a numba
    compiler (any arguments), or passed to one (``f = njit(...)(body)``)."""
    out = []
    for mod, path in modules(roots).items():
        tree = _parse(path)
        aliases = _aliases(tree, mod, path.name == "__init__.py")
        defs = {}
        for node in _nodes(tree):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                defs.setdefault(node.name, node)
                if any(_is_compiler(d, aliases) for d in node.decorator_list):
                    out.append((path, node.lineno, node.name, count_params(node)))
        for node in _nodes(tree):
            # njit(...)(body) or njit(body): the function named by the argument is compiled
            if isinstance(node, ast.Call) and node.args and isinstance(node.args[0], ast.Name):
                if _is_compiler(node.func, aliases) and (isinstance(node.func, ast.Call)
                                                         or _dotted(node.func, aliases) in COMPILERS):
                    fn = defs.get(node.args[0].id)
                    if fn is not None:
                        out.append((path, fn.lineno, fn.name, count_params(fn)))
    return sorted(set(out), key=lambda r: (str(r[0]), r[1]))


def long_kernels(roots=None, limit=MAX_KERNEL_PARAMS):
    """Lines ``path:line name (N parameters)`` of every compiled function over ``limit``."""
    return [f"{_rel(p)}:{line} {name} ({k} parameters)"
            for p, line, name, k in compiled_functions(roots) if k > limit]


def _plain_njit(dec, aliases):
    """True for a decorator that compiles with numba's njit / jit as a separately compiled
    function: not ``inner``, not ``inline="always"`` (inlined into its callers, never compiled on
    its own), not ``parallel=True`` (an entry point with a parallel loop)."""
    if not _is_compiler(dec, aliases) or _is_inner(dec, aliases):
        return False
    kw = {k.arg: k.value for k in dec.keywords} if isinstance(dec, ast.Call) else {}
    const = {k: v.value for k, v in kw.items() if isinstance(v, ast.Constant)}
    return const.get("inline") != "always" and const.get("parallel") is not True


def python_uses(folders):
    """Every name that Python code under ``folders`` loads outside a jitted function (a call, an
    argument, an attribute): the functions Python may call."""
    names = set()
    for folder in folders:
        for p in sorted(Path(folder).rglob("*.py")):
            if "__pycache__" in p.parts:
                continue
            tree = _parse(p)
            aliases = _aliases(tree)
            jitted = set()
            for fn in _nodes(tree):
                if isinstance(fn, ast.FunctionDef) and any(_is_compiler(d, aliases) for d in fn.decorator_list):
                    jitted.update(id(n) for stmt in fn.body for n in ast.walk(stmt))
            for n in _nodes(tree):
                if id(n) not in jitted:
                    if isinstance(n, ast.Name):
                        names.add(n.id)
                    elif isinstance(n, ast.Attribute):
                        names.add(n.attr)
    return names


def _function_defs(roots=None):
    """(path, function node, the module's import aliases) of every function in the package."""
    for mod, path in modules(roots).items():
        tree = _parse(path)
        aliases = _aliases(tree, mod, path.name == "__init__.py")
        for node in _nodes(tree):
            if isinstance(node, ast.FunctionDef):
                yield path, node, aliases


def inner_kernels(roots=None):
    """Lines ``path:line name`` of every function decorated with the package's ``inner``."""
    return sorted(f"{_rel(path)}:{node.lineno} {node.name}" for path, node, aliases in _function_defs(roots)
                  if any(_is_inner(d, aliases) for d in node.decorator_list))


def should_be_inner(roots=None, users=()):
    """Lines ``path:line name`` of every function compiled with plain njit that no Python code
    in the package or in the folders ``users`` (tests, scripts) uses: only kernels call it, so
    :func:`gridrt.compiles.inner` would compile it without a Python entry point."""
    roots = ROOTS if roots is None else roots
    used = python_uses(list(roots.values()) + list(users))
    return sorted(f"{_rel(path)}:{node.lineno} {node.name}" for path, node, aliases in _function_defs(roots)
                  if node.name not in used and any(_plain_njit(d, aliases) for d in node.decorator_list))


def _comments(source):
    """{line: comment text} of a module's comments (tokenize: a '#' inside a string is none)."""
    out = {}
    for tok in tokenize.generate_tokens(io.StringIO(source).readline):
        if tok.type == tokenize.COMMENT:
            out[tok.start[0]] = tok.string
    return out


def undeclared_inner_imports(roots=None):
    """Lines ``path:line import ...`` of every import inside a function whose first line lacks
    the trailing comment ``# deferred: <reason>``."""
    out = []
    for mod, path in modules(roots).items():
        source = path.read_text()
        tree = _parse_text(str(path), source)
        comments = _comments(source)
        inner = _function_nodes(tree)
        for node in _nodes(tree):
            if id(node) in inner and not DEFERRED.search(comments.get(node.lineno, "")):
                out.append(f"{_rel(path)}:{node.lineno} {ast.unparse(node)}")
    return sorted(out, key=lambda s: (s.split(":")[0], int(s.split(":")[1].split()[0])))


# ----------------------------------------------------------------------------------------------
# the real tree


def test_engine_never_imports_the_app():
    graph = import_graph()
    bad = {m: sorted(t for t in ts if t == "gridrt.app" or t.startswith("gridrt.app."))
           for m, ts in graph.items() if not m.startswith("gridrt.app") and m != "gridrt.__main__"}
    bad = {m: ts for m, ts in bad.items() if ts}
    assert not bad, f"engine modules importing the app: {bad}"
    assert "gridrt.app.__main__" in graph["gridrt.__main__"]  # the entry point (and only it) does


def test_the_package_map_covers_the_tree():
    mods = modules()
    assert len(mods) > 40 and "gridrt.grid.build" in mods
    assert mods["gridrt.app.__main__"] == ROOTS["gridrt.app"] / "__main__.py"


def test_no_import_cycles():
    """No cycle, counting every import (inside functions too)."""
    report = import_cycles()
    assert not report, "import cycles (imports inside functions counted):\n" + "\n".join(report)


def test_no_compiled_function_takes_more_than_ten_parameters():
    found = compiled_functions()
    assert len(found) > 100, "the decorator detection finds too few compiled functions"
    bad = long_kernels()
    assert not bad, (f"{len(bad)} numba-compiled functions take more than {MAX_KERNEL_PARAMS} parameters "
                     "(pass records):\n" + "\n".join(bad))


def test_kernels_only_kernels_call_are_inner():
    """A kernel that no Python code calls is compiled with ``inner``: numba's CPython and C
    wrappers of the others (unboxing every argument) are compile time spent for nothing."""
    assert len(inner_kernels()) > 100, "the detection finds too few inner kernels"
    bad = should_be_inner(users=[REPO / "tests", REPO / "scripts"])
    assert not bad, (f"{len(bad)} jitted functions only kernels call, compiled with plain njit "
                     "(decorate them with gridrt.compiles.inner):\n" + "\n".join(bad))


def test_every_import_inside_a_function_says_why_it_is_deferred():
    bad = undeclared_inner_imports()
    assert not bad, (f"{len(bad)} imports inside functions without a trailing '# deferred: <reason>' "
                     "(move them to the top of the module, or say which heavy dependency they defer):\n"
                     + "\n".join(bad))


def imports_of_test_files(tests):
    """Lines ``path:line imports test_x`` of every import of a test module (``test_*.py`` in the
    folder ``tests``) by any module under ``tests``."""
    tests = Path(tests)
    names = {p.stem for p in tests.glob("test_*.py")}
    bad = []
    for p in sorted(tests.rglob("*.py")):
        for node in ast.walk(_parse(p)):
            if isinstance(node, ast.Import):
                hits = [a.name for a in node.names if a.name.split(".")[0] in names]
            elif isinstance(node, ast.ImportFrom) and not node.level:
                hits = [node.module] if (node.module or "").split(".")[0] in names else []
            else:
                continue
            bad += [f"{p.relative_to(tests)}:{node.lineno} imports {h}" for h in hits]
    return bad


def test_no_test_file_imports_another():
    """Test files share helpers through tests/helpers/ and conftest.py, never by importing one
    another (a test module imported by another couples the two files' names and collects its
    module twice)."""
    tests = Path(__file__).resolve().parent
    assert len(list(tests.glob("test_*.py"))) > 40
    bad = imports_of_test_files(tests)
    assert not bad, "test files importing test files (move the helper to tests/helpers/):\n" + "\n".join(bad)


# ----------------------------------------------------------------------------------------------
# the checkers fail when they should: synthetic packages with a planted offence


CLEAN = {
    "__init__.py": "from .core import run\n",
    "core.py": (
        "from numba import njit\n"
        "from .util import helper\n\n\n"
        "@njit(cache=True)\n"
        "def kernel(a, b, c, d, e, f, g, h, i, j):\n"
        "    return a\n\n\n"
        "def run():\n"
        "    import matplotlib  # deferred: matplotlib loads in ~1 s\n"
        "    return helper()\n"
    ),
    "util.py": (
        "import numba as nb\n\n\n"
        "@nb.njit\n"
        "def helper(x=1):\n"
        "    s = '# deferred: inside a string is no comment'\n"
        "    return x\n\n\n"
        "def wide(a, b, c, d, e, f, g, h, i, j, k, l):  # not compiled: any length\n"
        "    return a\n"
    ),
    "app/__init__.py": "",
    "app/cli.py": "from synth.core import run\n",
}


def write_package(tmp_path, files):
    """Write ``files`` ({relative path: source}) as package ``synth`` (app/ mapped to synth.app
    as pyproject maps gridrt.app); returns its package map."""
    root = tmp_path / "src"
    for rel, text in files.items():
        p = root / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(text)
    return {"synth": root, "synth.app": root / "app"}


def line_of(source, text):
    """The 1-based number of the one line of ``source`` that contains ``text``."""
    hits = [i for i, line in enumerate(source.splitlines(), 1) if text in line]
    assert len(hits) == 1, (text, hits)
    return hits[0]


def test_clean_synthetic_package_passes(tmp_path):
    roots = write_package(tmp_path, CLEAN)
    assert set(modules(roots)) == {"synth", "synth.core", "synth.util", "synth.app", "synth.app.cli"}
    assert import_cycles(roots) == []
    assert long_kernels(roots) == []
    assert {(name, k) for _, _, name, k in compiled_functions(roots)} == {("kernel", 10), ("helper", 1)}
    assert undeclared_inner_imports(roots) == []


def test_planted_cycle_through_an_inner_import_is_reported(tmp_path):
    files = dict(CLEAN)
    files["util.py"] = CLEAN["util.py"] + (
        "\n\ndef back():\n    from .app.cli import run  # deferred: x\n    return run\n")
    roots = write_package(tmp_path, files)
    report = import_cycles(roots)
    assert report, "a cycle through an import inside a function went unreported"
    text = "\n".join(report)
    assert "synth.app.cli, synth.core, synth.util" in text
    assert f"synth.util -> synth.app.cli (src/util.py:{line_of(files['util.py'], 'from .app.cli')})" in text.replace(
        str(tmp_path) + "/", "")
    assert "synth.app.cli -> synth.core" in text and "synth.core -> synth.util" in text
    # the module-level graph alone has no cycle: only counting the inner import finds it
    top = import_graph(roots, top_level_only=True)
    assert strongly_connected({m: set(e) for m, e in top.items()}) == []


def test_planted_relative_package_cycle_is_reported(tmp_path):
    files = dict(CLEAN)
    files["util.py"] = "from . import core\n" + CLEAN["util.py"]
    report = import_cycles(write_package(tmp_path, files))
    assert report and report[0].startswith("cycle among ") and {"synth.core", "synth.util"} <= set(
        report[0][len("cycle among "):-1].split(", ")), report
    assert any(line.startswith("  synth.util -> synth.core (") and line.endswith("util.py:1)") for line in report)


def test_planted_long_kernel_is_reported(tmp_path):
    files = dict(CLEAN)
    files["core.py"] = CLEAN["core.py"] + (
        "\n\n@njit(cache=True, parallel=True)\n"
        "def wide_kernel(a, b, c, d, e, f, g, h, i, j, k=0):\n"
        "    return a\n"
    )
    files["util.py"] = CLEAN["util.py"] + (
        "\n\nfrom numba import jit as _jit\n\n\n"
        "@_jit(nopython=True)\n"
        "def aliased(a, b, c, d, e, f, g, h, i, j, *rest):\n"
        "    return a\n\n\n"
        "def _body(a, b, c, d, e, f, g, h, i, j, k, l):\n"
        "    return a\n\n\n"
        "wrapped = nb.njit(inline='always')(_body)\n"
    )
    bad = [line.replace(str(tmp_path) + "/", "") for line in long_kernels(write_package(tmp_path, files))]
    core, util = files["core.py"], files["util.py"]
    assert bad == [f"src/core.py:{line_of(core, 'def wide_kernel')} wide_kernel (11 parameters)",
                   f"src/util.py:{line_of(util, 'def aliased')} aliased (11 parameters)",
                   f"src/util.py:{line_of(util, 'def _body')} _body (12 parameters)"], bad


def test_planted_inner_import_without_reason_is_reported(tmp_path):
    files = dict(CLEAN)
    files["core.py"] = CLEAN["core.py"] + (
        "\n\ndef lazy():\n"
        "    import json\n"
        "    from os import path  # a comment that does not say deferred\n"
        "    import csv  # deferred:\n"
        "    return json, path, csv\n\n\n"
        "class K:\n"
        "    def m(self):\n"
        "        import sys as _s\n"
        "        return _s\n"
    )
    bad = [line.replace(str(tmp_path) + "/", "") for line in undeclared_inner_imports(write_package(tmp_path, files))]
    src = files["core.py"]
    assert bad == [f"src/core.py:{line_of(src, 'import json')} import json",
                   f"src/core.py:{line_of(src, 'from os import path')} from os import path",
                   f"src/core.py:{line_of(src, 'import csv')} import csv",
                   f"src/core.py:{line_of(src, 'import sys as _s')} import sys as _s"], bad


def test_planted_test_file_import_is_reported(tmp_path):
    (tmp_path / "helpers").mkdir()
    (tmp_path / "helpers" / "shared.py").write_text("import numpy\n")
    (tmp_path / "test_a.py").write_text("from helpers.shared import numpy\nimport conftest\n")
    (tmp_path / "conftest.py").write_text("")
    assert imports_of_test_files(tmp_path) == []
    (tmp_path / "test_b.py").write_text("import os\n\n\ndef test_x():\n    from test_a import numpy\n")
    (tmp_path / "helpers" / "more.py").write_text("import test_b as b\n")
    assert imports_of_test_files(tmp_path) == ["helpers/more.py:1 imports test_b", "test_b.py:5 imports test_a"]


def test_planted_kernel_only_kernels_call_is_reported(tmp_path):
    files = dict(CLEAN)
    files["compiles.py"] = "def inner(*a, **k):\n    return lambda f: f\n"
    files["kern.py"] = (
        "from numba import njit\n"
        "from .compiles import inner\n\n\n"
        "@njit(cache=True)\n"
        "def only_kernels(x):\n    return x\n\n\n"
        "@inner(cache=True)\n"
        "def declared(x):\n    return x\n\n\n"
        "@njit(cache=True, inline='always')\n"
        "def inlined(x):\n    return x\n\n\n"
        "@njit(cache=True)\n"
        "def from_python(x):\n    return only_kernels(x) + declared(x) + inlined(x)\n\n\n"
        "def run(x):\n    return from_python(x)\n"
    )
    roots = write_package(tmp_path, files)
    kern = files["kern.py"]
    strip = [line.replace(str(tmp_path) + "/", "") for line in should_be_inner(roots)]
    # CLEAN's kernel (core.py) has no Python caller either; its helper has one (core.run)
    assert strip == [f"src/core.py:{line_of(files['core.py'], 'def kernel')} kernel",
                     f"src/kern.py:{line_of(kern, 'def only_kernels')} only_kernels"], strip
    assert [line.replace(str(tmp_path) + "/", "") for line in inner_kernels(roots)] == [
        f"src/kern.py:{line_of(kern, 'def declared')} declared"]
    assert ("declared", 1) in {(name, k) for _, _, name, k in compiled_functions(roots)}
    # a test folder that calls it from Python makes it an entry point
    users = tmp_path / "tests"
    users.mkdir()
    (users / "test_k.py").write_text("from synth.kern import only_kernels\n\n\ndef test_it():\n"
                                     "    assert only_kernels(1) == 1\n")
    strip = [line.replace(str(tmp_path) + "/", "") for line in should_be_inner(roots, [users])]
    assert not any("only_kernels" in line for line in strip), strip
