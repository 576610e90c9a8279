"""facetex's modules import each other in one direction (issue 24): no import circle, counting
imports inside functions too (a lazy import still ties two modules together), not those under
``if TYPE_CHECKING:``."""

from __future__ import annotations

import ast
from pathlib import Path

import facetex

ROOT = Path(facetex.__file__).resolve().parent

#: circles still to break; this list may only shrink (empty: persona.collection <-> persona.texture
#: was broken by moving the alignment into persona.align)
KNOWN: set = set()


def _module_name(path: Path) -> str:
    rel = path.relative_to(ROOT.parent).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def _reexports(mods: dict[str, Path]) -> dict[str, dict[str, str]]:
    """{package: {name: its private module}} of the names a package's ``__init__`` imports from
    its own modules at the top (``from ._read import read_image`` in ``facetex.io``): importing
    such a name from the package ties the importer to that module."""
    out: dict[str, dict[str, str]] = {}
    for name, path in mods.items():
        if path.name != "__init__.py":
            continue
        for node in ast.parse(path.read_text(encoding="utf-8")).body:
            if isinstance(node, ast.ImportFrom) and node.level == 1 and node.module:
                for a in node.names:
                    out.setdefault(name, {})[a.asname or a.name] = f"{name}.{node.module}"
    return out


def _graph() -> dict[str, set[str]]:
    mods = {_module_name(p): p for p in ROOT.rglob("*.py")}
    reexports = _reexports(mods)
    graph: dict[str, set[str]] = {m: set() for m in mods}
    for name, path in mods.items():
        pkg = name if path.name == "__init__.py" else name.rpartition(".")[0]
        tree = ast.parse(path.read_text(encoding="utf-8"))
        # imports for type checkers only are never run: they tie no modules together
        typing_only = {id(n) for node in ast.walk(tree) if isinstance(node, ast.If)
                       and getattr(node.test, "id", getattr(node.test, "attr", None)) == "TYPE_CHECKING"
                       for stmt in node.body for n in ast.walk(stmt)}
        for node in ast.walk(tree):
            if id(node) in typing_only:
                continue
            targets = []
            if isinstance(node, ast.ImportFrom):
                if node.level:
                    base = pkg.split(".")
                    base = base[: len(base) - node.level + 1]
                    mod = ".".join(base + ([node.module] if node.module else []))
                else:
                    mod = node.module or ""
                targets = [mod] + [f"{mod}.{a.name}" for a in node.names]
                targets += [reexports[mod][a.name] for a in node.names if a.name in reexports.get(mod, {})]
            elif isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            for t in targets:
                if t in mods and t != name and not name.startswith(t + ".") and not (
                        mods[t].name == "__init__.py"):
                    graph[name].add(t)
    return graph


def _cycles(graph):
    """Pairs of modules on a common circle (strongly connected components of size > 1, Tarjan)."""
    index, low, stack, on, comps, counter = {}, {}, [], set(), [], [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = set()
            while True:
                w = stack.pop()
                on.discard(w)
                comp.add(w)
                if w == v:
                    break
            if len(comp) > 1:
                comps.append(frozenset(comp))

    import sys

    sys.setrecursionlimit(10000)
    for v in graph:
        if v not in index:
            visit(v)
    return comps


def test_no_import_circles_beyond_the_known_ones():
    comps = set(_cycles(_graph()))
    assert comps <= KNOWN, f"new import circles: {[sorted(c) for c in comps - KNOWN]}"


def test_the_collection_and_the_texture_share_the_alignment_from_below():
    g = _graph()
    assert "facetex.persona.align" in g["facetex.persona.texture"] and "facetex.persona.collection" not in g[
        "facetex.persona.texture"]


def test_the_benches_and_the_report_share_statistics_from_below():
    g = _graph()
    assert "facetex._stats" in g["facetex.report.compare"]
    assert not any(t.startswith("facetex.bench") for t in g["facetex.report.compare"] | g["facetex.report.figures"])


def test_names_imported_from_a_package_tie_the_importer_to_their_module():
    """``from .io import read_image`` ties landmarks to facetex.io._read, where read_image is."""
    g = _graph()
    assert "facetex.io._read" in g["facetex.landmarks"]
    assert "facetex.metrics._transfer" in g["facetex.cli.cmd_metrics"]
