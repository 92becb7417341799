"""The package's architecture, read from the source: the engine never imports the app, and no
module-level import cycle exists (imports inside functions, which are lazy on purpose, are not
edges of the graph)."""

import ast
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
#: package name -> folder (pyproject.toml's package-dir)
ROOTS = {"gridrt": REPO / "engine", "gridrt.app": REPO / "app"}


def modules():
    """{module name: path} of every module of the package."""
    out = {}
    for pkg, root in ROOTS.items():
        for p in root.rglob("*.py"):
            rel = p.relative_to(root).with_suffix("").parts
            if pkg == "gridrt" and rel[:1] == ("__pycache__",):
                continue
            parts = rel[:-1] if rel[-1] == "__init__" else rel
            out[".".join((pkg,) + parts)] = p
    return out


def _resolve(mod, is_pkg, node):
    """Absolute names an ImportFrom / Import node imports (module names and module.attribute)."""
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


def import_graph(top_level_only):
    mods = modules()
    graph = {}
    for mod, path in mods.items():
        tree = ast.parse(path.read_text())
        nodes = tree.body if top_level_only else list(ast.walk(tree))
        targets = set()
        for node in nodes:
            if isinstance(node, (ast.Import, ast.ImportFrom)):
                for name in _resolve(mod, path.name == "__init__.py", node):
                    # the longest known module the name starts with
                    while name and name not in mods:
                        name = name.rpartition(".")[0]
                    if name and name != mod:
                        targets.add(name)
        graph[mod] = targets
    return graph


def test_engine_never_imports_the_app():
    graph = import_graph(top_level_only=False)
    bad = {m: sorted(t for t in ts if t == "gridrt.app" or t.startswith("gridrt.app."))
           for m, ts in graph.items() if not m.startswith("gridrt.app") and m != "gridrt.__main__"}
    bad = {m: ts for m, ts in bad.items() if ts}
    assert not bad, f"engine modules importing the app: {bad}"
    assert "gridrt.app.__main__" in graph["gridrt.__main__"]  # the entry point (and only it) does


def find_cycles(graph):
    """Cycles (lists of modules, first == last) of a {module: targets} graph, found by DFS."""
    state, cycles = {}, []

    def visit(m, stack):
        state[m] = 1
        stack.append(m)
        for t in sorted(graph.get(m, ())):
            if state.get(t) == 1:
                cycles.append(stack[stack.index(t):] + [t])
            elif t not in state:
                visit(t, stack)
        stack.pop()
        state[m] = 2

    for m in sorted(graph):
        if m not in state:
            visit(m, [])
    return cycles


def test_cycle_finder_by_hand():
    assert find_cycles({"a": {"b"}, "b": {"c"}, "c": set()}) == []
    assert find_cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == [["a", "b", "c", "a"]]


def test_no_module_level_import_cycles():
    graph = import_graph(top_level_only=True)
    # a package imports its submodules through its __init__; a submodule importing its own package
    # (for a sibling) is the usual idiom, not a cycle worth reporting, so edges to ancestors go
    graph = {m: {t for t in ts if not m.startswith(t + ".")} for m, ts in graph.items()}
    cycles = find_cycles(graph)
    assert not cycles, "module-level import cycles: " + "; ".join(" -> ".join(c) for c in cycles)
    assert len(graph) > 40 and "gridrt.grid.build" in graph["gridrt.grid"] | graph["gridrt"] | {
        t for ts in graph.values() for t in ts}
