"""No import cycle between files, and no folder of more than 16 modules (docs/architecture.md).

Every file of every package (``src/<pkg>/<pkg>/**/*.py``) is a node of the import graph. Each
import in it, at module level or inside a function, is an edge to the one file it names: the
longest module name the import spells (``from a.b import c`` is ``a/b/c.py`` when that exists,
else ``a/b/__init__.py``). An import of a package is an edge to its ``__init__`` only: a package
``__init__`` exports its names lazily, so it has edges only where it imports something itself.
Relative imports are resolved against the file's package. A strongly connected component of more
than one file is a cycle: its files can be neither understood nor tested apart. A folder of more
than 16 modules holds more than one concept: it wants subpackages. ``python THIS_FILE`` prints
the cycles and the folders over the limit.
"""
from __future__ import annotations

import ast
import pathlib
from typing import Iterable, Mapping

REPO = pathlib.Path(__file__).resolve().parents[4]
SRC = REPO / "src"
MAX_MODULES_PER_FOLDER = 16


def package_modules(src: pathlib.Path) -> dict[str, pathlib.Path]:
    """Dotted module name -> file, for every ``src/<pkg>/<pkg>/**/*.py`` (a package is its ``__init__``)."""
    modules = {}
    for pkg_dir in sorted(p for p in src.iterdir() if (p / p.name).is_dir()):
        for path in sorted((pkg_dir / pkg_dir.name).rglob("*.py")):
            parts = path.relative_to(pkg_dir).with_suffix("").parts
            modules[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return modules


def _resolve(name: str, modules: Mapping[str, pathlib.Path]) -> str | None:
    """The longest prefix of dotted ``name`` that is one of ``modules`` (None: not ours)."""
    while name and name not in modules:
        name = name.rpartition(".")[0]
    return name or None


def _from_base(module: str, path: pathlib.Path, node: ast.ImportFrom) -> str:
    """The absolute module a ``from ... import`` names (relative ones against the file's package)."""
    if node.level == 0:
        return node.module or ""
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    for _ in range(node.level - 1):
        package = package.rpartition(".")[0]
    return f"{package}.{node.module}" if node.module else package


def imported_files(module: str, path: pathlib.Path, modules: Mapping[str, pathlib.Path]) -> set[str]:
    """The modules of ``modules`` that ``module`` (file ``path``) imports anywhere in the file."""
    out = set()
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            out.update(_resolve(a.name, modules) for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = _from_base(module, path, node)
            out.update(f"{base}.{a.name}" if f"{base}.{a.name}" in modules else _resolve(base, modules)
                       for a in node.names)
    return out - {None, module}


def import_graph(modules: Mapping[str, pathlib.Path]) -> dict[str, set[str]]:
    return {m: imported_files(m, path, modules) for m, path in modules.items()}


def strongly_connected(graph: Mapping[str, Iterable[str]]) -> list[list[str]]:
    """Tarjan's strongly connected components of more than one node, each sorted (iterative:
    an import chain may be deeper than the recursion limit)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found = []
    for root in sorted(graph):
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            v, edges = work[-1]
            w = next((w for w in edges if w not in index or w in on_stack), None)
            if w is not None:
                if w in index:
                    low[v] = min(low[v], index[w])
                else:
                    index[w] = low[w] = len(index)
                    stack.append(w)
                    on_stack.add(w)
                    work.append((w, iter(sorted(graph.get(w, ())))))
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[v])
            if low[v] == index[v]:
                component = []
                while True:
                    w = stack.pop()
                    on_stack.discard(w)
                    component.append(w)
                    if w == v:
                        break
                if len(component) > 1:
                    found.append(sorted(component))
    return sorted(found)


def one_cycle(graph: Mapping[str, Iterable[str]], component: list[str]) -> list[str]:
    """A shortest import cycle through the first file of ``component`` (for the failure message)."""
    inside, start = set(component), component[0]
    paths = {start: [start]}
    frontier = [start]
    while frontier:
        nxt = []
        for v in frontier:
            for w in sorted(graph[v]):
                if w == start:
                    return paths[v] + [start]
                if w in inside and w not in paths:
                    paths[w] = paths[v] + [w]
                    nxt.append(w)
        frontier = nxt
    return component


def crowded_folders(src: pathlib.Path, limit: int = MAX_MODULES_PER_FOLDER) -> dict[str, int]:
    """Folders of a package (``src/<pkg>/<pkg>/**``) with more than ``limit`` modules (``__init__`` not counted)."""
    folders = {path.parent for path in package_modules(src).values()}
    counts = {str(d.relative_to(src)): sum(1 for f in d.glob("*.py") if f.name != "__init__.py") for d in folders}
    return {d: n for d, n in sorted(counts.items()) if n > limit}


def _cycles_report(graph: Mapping[str, Iterable[str]]) -> list[str]:
    return [" -> ".join(one_cycle(graph, c)) + f"  (component: {', '.join(c)})" for c in strongly_connected(graph)]


def test_no_import_cycle_between_files():
    graph = import_graph(package_modules(SRC))
    assert len(graph) > 100, f"only {len(graph)} modules found under {SRC}"
    cycles = _cycles_report(graph)
    assert not cycles, "import cycles between files:\n" + "\n".join(cycles)


def test_no_folder_holds_more_than_16_modules():
    crowded = crowded_folders(SRC)
    assert not crowded, f"folders with more than {MAX_MODULES_PER_FOLDER} modules (split into subpackages): {crowded}"


def test_cycle_finder_on_small_graphs():
    assert strongly_connected({"a": {"b"}, "b": {"c"}, "c": set()}) == []
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a", "d"}, "d": {"e"}, "e": {"d"}, "f": {"a"}}
    assert strongly_connected(graph) == [["a", "b", "c"], ["d", "e"]]
    assert one_cycle(graph, ["a", "b", "c"]) == ["a", "b", "c", "a"]
    chain = {str(i): {str(i + 1)} for i in range(5000)} | {"5000": {"0"}}      # deeper than the recursion limit
    assert strongly_connected(chain) == [sorted(chain)]


def _write(root: pathlib.Path, files: Mapping[str, str]) -> None:
    for rel, text in files.items():
        path = root / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)


def test_graph_counts_function_level_and_relative_imports_and_stops_at_lazy_packages(tmp_path):
    _write(tmp_path, {
        "pkg/pkg/__init__.py": "from lib.public_api import lazy_exports\n",
        "pkg/pkg/base.py": "import numpy\n\ndef restore():\n    from pkg.sub.variant import Variant\n",
        "pkg/pkg/sub/__init__.py": '"""Lazy exports only."""\n',
        "pkg/pkg/sub/variant.py": "from ..base import restore\nfrom pkg.sub import helper, NAME\n",
        "pkg/pkg/sub/helper.py": "from pkg import Anything\n",
        "other/other/__init__.py": "",
        "other/other/user.py": "import pkg.sub.helper\nfrom pkg.sub import Variant\n",
    })
    modules = package_modules(tmp_path)
    graph = import_graph(modules)
    assert graph == {"pkg": set(), "pkg.base": {"pkg.sub.variant"}, "pkg.sub": set(),
                     "pkg.sub.variant": {"pkg.base", "pkg.sub.helper", "pkg.sub"}, "pkg.sub.helper": {"pkg"},
                     "other": set(), "other.user": {"pkg.sub.helper", "pkg.sub"}}
    assert strongly_connected(graph) == [["pkg.base", "pkg.sub.variant"]]
    _write(tmp_path, {"pkg/pkg/base.py": "def restore():\n    pass\n"})
    assert strongly_connected(import_graph(modules)) == []


def test_crowded_folders_counts_modules_per_folder(tmp_path):
    _write(tmp_path, {"pkg/pkg/__init__.py": "", **{f"pkg/pkg/m{i}.py": "" for i in range(3)},
                      "pkg/pkg/sub/__init__.py": "", "pkg/pkg/sub/a.py": ""})
    assert crowded_folders(tmp_path, limit=3) == {}
    assert crowded_folders(tmp_path, limit=2) == {"pkg/pkg": 3}


if __name__ == "__main__":
    print("\n".join(_cycles_report(import_graph(package_modules(SRC)))) or "no import cycle")
    for folder, n in crowded_folders(SRC).items():
        print(f"{folder}: {n} modules")
