"""The package's layers (docs/architecture.md): every import of every module points down, never up.

Each module of ``lagsplat`` belongs to one layer (:data:`LAYERS`, bottom first).
A module may import from its own layer or below; an import of a higher layer,
at the top of a module or inside a function, fails the test with the module,
the line and both layers. So do imports of another module's private names.
"""

from __future__ import annotations

import ast
import warnings
from pathlib import Path

import pytest

PKG = Path(__file__).resolve().parents[1] / "lagsplat"

# bottom to top; a module's layer is the one of its longest matching prefix
LAYERS: list[tuple[str, list[str]]] = [
    ("io", ["lagsplat", "lagsplat.io"]),
    ("signals", ["lagsplat.timeseries", "lagsplat.motion", "lagsplat.metrics"]),
    ("render and synthetic clips", ["lagsplat.render", "lagsplat.synth"]),
    ("ingest and models", ["lagsplat.ingest", "lagsplat.prepare", "lagsplat.views", "lagsplat.views_sharp", "lagsplat.models"]),
    ("dynamics", ["lagsplat.dynamics"]),
    ("chart", ["lagsplat.chart"]),
    ("train", ["lagsplat.train"]),
    ("artifacts", ["lagsplat.artifacts"]),
    ("evaluate, forces, export", ["lagsplat.evaluate", "lagsplat.forces", "lagsplat.export"]),
    ("diagnose, baselines, viewer, figures", ["lagsplat.diagnose", "lagsplat.baselines", "lagsplat.viewer", "lagsplat.viz"]),
    ("report", ["lagsplat.report"]),
    ("cli", ["lagsplat.cli", "lagsplat.__main__", "lagsplat.config_schema", "lagsplat.config_check", "lagsplat.cli_common", "lagsplat.stages", "lagsplat.stages_report", "lagsplat.stages_baselines", "lagsplat.stages_deformation"]),
]


def layer_of(module: str) -> int:
    """Index in :data:`LAYERS` of ``module`` (longest matching prefix).

    Raises:
        KeyError: if no layer claims it.
    """
    best, rank = -1, None
    for i, (_, prefixes) in enumerate(LAYERS):
        for p in prefixes:
            if (module == p or module.startswith(p + ".")) and len(p) > best:
                best, rank = len(p), i
    if rank is None:
        raise KeyError(module)
    return rank


def module_name(path: Path) -> str:
    parts = list(path.relative_to(PKG.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def _is_module_file(name: str, root: Path = PKG.parent) -> bool:
    """Whether the dotted ``name`` is a module or package under ``root``."""
    p = root / name.replace(".", "/")
    return p.with_suffix(".py").exists() or p.is_dir()


def _import_targets(node: ast.Import | ast.ImportFrom, pkg: str, top: str, is_module) -> list[tuple[str, list[str]]]:
    """``(imported module, imported names)`` of one import statement in package ``pkg``, for the modules of the
    package ``top`` only; ``from top.a import b`` with ``b`` a submodule (``is_module``) imports ``top.a.b``."""
    if isinstance(node, ast.Import):
        return [(a.name, []) for a in node.names if a.name == top or a.name.startswith(top + ".")]
    if node.level:
        base = pkg.split(".")[: len(pkg.split(".")) - (node.level - 1)]
        target = ".".join(base + ([node.module] if node.module else []))
    else:
        target = node.module or ""
    if not (target == top or target.startswith(top + ".")):
        return []
    names = [a.name for a in node.names]
    # "from lagsplat import metrics" imports the submodule lagsplat.metrics
    subs = [n for n in names if is_module(f"{target}.{n}")]
    out: list[tuple[str, list[str]]] = [(f"{target}.{n}", []) for n in subs]
    rest = [n for n in names if n not in subs]
    if rest or not subs:
        out.append((target, rest))
    return out


def imports_of(path: Path, mod: str | None = None) -> list[tuple[int, str, list[str]]]:
    """``(line, imported module, imported names)`` of every ``lagsplat`` import in ``path`` (module ``mod``,
    default its name in the package), nested ones included."""
    mod = mod or module_name(path)
    pkg = mod if path.name == "__init__.py" else mod.rpartition(".")[0]
    out = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            out += [(node.lineno, t, names) for t, names in _import_targets(node, pkg, "lagsplat", _is_module_file)]
    return out


MODULES = sorted(PKG.rglob("*.py"))


def test_every_module_has_a_layer() -> None:
    missing = [module_name(p) for p in MODULES if not _has_layer(module_name(p))]
    assert not missing, f"modules outside every layer of tests/test_layers.py (and docs/architecture.md): {missing}"


def _has_layer(m: str) -> bool:
    try:
        layer_of(m)
    except KeyError:
        return False
    return True


@pytest.mark.parametrize("path", MODULES, ids=lambda p: module_name(p))
def test_imports_point_down(path: Path) -> None:
    src = module_name(path)
    here = layer_of(src)
    up = [
        f"{path.relative_to(PKG.parent)}:{line} imports {target} (layer '{LAYERS[layer_of(target)][0]}') from layer '{LAYERS[here][0]}'"
        for line, target, _ in imports_of(path)
        if _has_layer(target) and layer_of(target) > here
    ]
    assert not up, "imports pointing up a layer:\n" + "\n".join(up)


@pytest.mark.parametrize("path", MODULES, ids=lambda p: module_name(p))
def test_no_private_names_of_other_modules(path: Path) -> None:
    src = module_name(path)
    bad = []
    for line, target, names in imports_of(path):
        if target == src:
            continue
        bad += [f"{line}: {n} from {target}" for n in names if n.startswith("_") and not n.startswith("__")]
        # a private module (io/_x.py) is for its own package only
        priv = [p for p in target.split(".") if p.startswith("_") and not p.startswith("__")]
        if priv and not src.startswith(target.rpartition(".")[0] + "."):
            bad.append(f"{line}: private module {target}")
    assert not bad, f"{path.relative_to(PKG.parent)} imports private names of other modules: {bad}"


def test_the_checker_sees_an_upward_import(tmp_path: Path) -> None:
    """The test itself: a module of a low layer importing the CLI is caught, nested imports included."""
    fake = tmp_path / "probe.py"
    fake.write_text("import numpy\n\ndef f():\n    from lagsplat.cli import main\n    from lagsplat import chart\n    return main\n")
    found = [(t, layer_of(t)) for _, t, _ in imports_of(fake, "lagsplat.io.zz_layer_probe")]
    assert found == [("lagsplat.cli", len(LAYERS) - 1), ("lagsplat.chart", layer_of("lagsplat.chart"))]
    assert layer_of("lagsplat.io.zz_layer_probe") == 0


# --- import cycles -------------------------------------------------------------------------------------------
#
# A module's imports run when it is imported if they sit at module level (inside ``if``/``try``/``with`` blocks
# and class bodies too, but not under ``if TYPE_CHECKING:``) or inside a module-level function that the module
# calls while it loads (directly, from a decorator, or through another such function). Those are the
# import-time edges; an import inside any other function runs only when the function is called (deferred).
# A cycle of import-time edges can leave a module half-initialised for another: it fails the test. A cycle that
# needs a deferred edge is listed as a warning only.


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")  # fmt: skip


def _load_time_nodes(nodes: list[ast.AST]):
    """Every node under ``nodes`` that runs when they run: function bodies (not their decorators and defaults)
    and ``if TYPE_CHECKING:`` bodies left out."""
    stack = list(nodes)
    while stack:
        n = stack.pop()
        yield n
        if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
            args = n.args
            stack += list(args.defaults) + [d for d in args.kw_defaults if d is not None]
            if not isinstance(n, ast.Lambda):
                stack += n.decorator_list
            continue
        if isinstance(n, ast.If) and _is_type_checking(n.test):
            stack += n.orelse
            continue
        stack += list(ast.iter_child_nodes(n))


def _import_edges(tree: ast.Module, mod: str, pkg: str, top: str, is_module) -> list[tuple[str, int, bool]]:
    """``(imported module, line, at import time)`` of every import of package ``top`` in module ``mod`` (those under
    ``if TYPE_CHECKING:`` never run and are left out)."""
    defs = {n.name: n for n in tree.body if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef))}
    at_load: set[int] = set()  # id() of the import nodes that run while the module loads
    todo, called = [tree.body], set()
    while todo:
        for n in _load_time_nodes(todo.pop()):
            if isinstance(n, (ast.Import, ast.ImportFrom)):
                at_load.add(id(n))
            # a module-level function called (or applied as a decorator) while the module loads runs its body
            name = n.func.id if isinstance(n, ast.Call) and isinstance(n.func, ast.Name) else None
            if name is None and isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                for d in n.decorator_list:
                    if isinstance(d, ast.Name) and d.id in defs and d.id not in called:
                        called.add(d.id)
                        todo.append(defs[d.id].body)
            if name in defs and name not in called:
                called.add(name)
                todo.append(defs[name].body)
    never = {id(m) for n in ast.walk(tree) if isinstance(n, ast.If) and _is_type_checking(n.test)
             for b in n.body for m in ast.walk(b)}  # fmt: skip
    edges = []
    for n in ast.walk(tree):
        if isinstance(n, (ast.Import, ast.ImportFrom)) and id(n) not in never:
            for target, _ in _import_targets(n, pkg, top, is_module):
                while target and not is_module(target):  # "import top.a.b" of a name: its module
                    target = target.rpartition(".")[0]
                if target and target != mod:
                    edges.append((target, n.lineno, id(n) in at_load))
    return edges


def import_graph(pkg_dir: Path) -> dict[str, list[tuple[str, int, bool]]]:
    """The package's import graph: module -> ``(imported module, line, at import time)``, modules of the package only."""
    root, top = pkg_dir.parent, pkg_dir.name
    paths = sorted(pkg_dir.rglob("*.py"))

    def name_of(p: Path) -> str:
        parts = list(p.relative_to(root).with_suffix("").parts)
        return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)

    names = {name_of(p) for p in paths}
    graph = {}
    for p in paths:
        mod = name_of(p)
        pkg = mod if p.name == "__init__.py" else mod.rpartition(".")[0]
        graph[mod] = _import_edges(ast.parse(p.read_text(), str(p)), mod, pkg, top, names.__contains__)
    return graph


def import_cycles(graph: dict[str, list[tuple[str, int, bool]]], load_time_only: bool) -> list[list[tuple[str, int]]]:
    """One cycle ``[(module, line of its import of the next), ...]`` per strongly connected group of modules of
    ``graph`` (Tarjan), through import-time edges only or through every edge."""
    succ = {m: [(t, line) for t, line, now in es if now or not load_time_only] for m, es in graph.items()}
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    groups: list[set[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w, _ in succ.get(v, []):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            group = set()
            while True:
                w = stack.pop()
                on.discard(w)
                group.add(w)
                if w == v:
                    break
            if len(group) > 1:
                groups.append(group)

    for v in sorted(succ):
        if v not in index:
            visit(v)
    cycles = []
    for group in groups:
        # the shortest way back to the group's first module, inside the group (breadth first)
        start = min(group)
        prev: dict[str, tuple[str, int]] = {}
        frontier, seen, found = [start], {start}, None
        while frontier and found is None:
            nxt = []
            for v in frontier:
                for w, line in succ[v]:
                    if w == start and found is None:
                        found = (v, line)
                    elif w in group and w not in seen:
                        seen.add(w)
                        prev[w] = (v, line)
                        nxt.append(w)
            frontier = nxt
        path, (v, line) = [], found
        path.append((v, line))
        while v != start:
            v, line = prev[v]
            path.append((v, line))
        cycles.append(path[::-1])
    return cycles


def _show(cycle: list[tuple[str, int]]) -> str:
    return " -> ".join(f"{m} (line {line})" for m, line in cycle) + f" -> {cycle[0][0]}"


GRAPH = import_graph(PKG)


def test_no_import_cycles() -> None:
    """No cycle of imports that run at import time (module level, or in a function the module calls as it loads)."""
    cycles = import_cycles(GRAPH, load_time_only=True)
    assert not cycles, "import cycles at import time:\n" + "\n".join(_show(c) for c in cycles)


def test_deferred_import_cycles_are_listed() -> None:
    """Cycles closed only by an import inside a function: allowed (the import runs after both modules have loaded),
    listed as a warning so that they stay visible."""
    for c in import_cycles(GRAPH, load_time_only=False):
        warnings.warn(f"import cycle through a function-level import: {_show(c)}", stacklevel=1)


def test_the_cycle_check_sees_a_cycle(tmp_path: Path) -> None:
    """The check itself, on a made-up package: a module-level cycle is found; one closed inside a function counts
    only if the module calls that function while it loads; ``if TYPE_CHECKING:`` imports never run."""
    pkg = tmp_path / "cyc"
    (pkg / "sub").mkdir(parents=True)
    files = {
        "__init__.py": "",
        "a.py": "from cyc.b import f\n",
        "b.py": "import cyc.sub.c\n\ndef f():\n    return 1\n",
        "sub/__init__.py": "",
        "sub/c.py": "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from cyc import d\n\n"
                    "def g():\n    from cyc import a\n    return a\n",
        "d.py": "from cyc.sub import c\n",
        "e.py": "def h():\n    from cyc.g import x\n    return x\n\n@h\ndef k():\n    pass\n",
        "g.py": "try:\n    from cyc.e import k as x\nexcept ImportError:\n    x = None\n",
    }  # fmt: skip
    for name, text in files.items():
        (pkg / name).write_text(text)
    graph = import_graph(pkg)
    assert graph["cyc.sub.c"] == [("cyc.a", 6, False)]
    assert graph["cyc.e"] == [("cyc.g", 2, True)]  # h runs as k's decorator
    assert [_show(c) for c in import_cycles(graph, load_time_only=True)] == ["cyc.e (line 2) -> cyc.g (line 2) -> cyc.e"]
    every = {frozenset(m for m, _ in c) for c in import_cycles(graph, load_time_only=False)}
    assert every == {frozenset({"cyc.e", "cyc.g"}), frozenset({"cyc.a", "cyc.b", "cyc.sub.c"})}
