"""Find import circles among the modules of ``services/``, ``app/`` and ``research/``; exit 1 on one.

Every import statement counts, wherever it is (at module level, inside a function, under
``if TYPE_CHECKING:``): a lazy import breaks a circle at run time, not in the design. ``from a.b import c``
is an edge to the module ``a.b.c`` when there is one, else to ``a.b``; an edge to a module's own package
(its ``__init__``, which Python runs first anyway) does not count. Circles are the strongly connected
components of more than one module (Tarjan), each printed as its sorted modules.
Usage: ``python scripts/check_imports.py [PACKAGE ...]`` (default: services app research).
"""

from __future__ import annotations

import ast
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def modules(packages: list[str]) -> dict[str, Path]:
    """Every module of ``packages`` by dotted name (a package by its own name, for its ``__init__``)."""
    found: dict[str, Path] = {}
    for pkg in packages:
        for path in sorted((ROOT / pkg).rglob("*.py")):
            parts = list(path.relative_to(ROOT).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            found[".".join(parts)] = path
    return found


def _resolve(name: str, here: str, is_package: bool, level: int) -> str:
    """The absolute name of a relative import's module."""
    if level == 0:
        return name
    base = here.split(".") if is_package else here.split(".")[:-1]
    base = base[: len(base) - (level - 1)]
    return ".".join([*base, name] if name else base)


def edges(mods: dict[str, Path]) -> dict[str, set[str]]:
    """The modules each module imports, among ``mods``."""
    out: dict[str, set[str]] = {m: set() for m in mods}
    for mod, path in mods.items():
        is_package = path.name == "__init__.py"
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), filename=str(path))):
            targets: list[str] = []
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = _resolve(node.module or "", mod, is_package, node.level)
                targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in mods else base for a in node.names]
            for t in targets:
                while t and t not in mods:  # import a.b.c where only a.b is ours: the nearest module
                    t = t.rpartition(".")[0]
                if t and t != mod and not mod.startswith(t + "."):
                    out[mod].add(t)
    return out


def circles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (iterative Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    on_stack: set[str] = set()
    stack: list[str] = []
    found: list[list[str]] = []
    for root in sorted(graph):
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            v, it = work[-1]
            w = next(it, None)
            if w is not None:
                if w not in index:
                    index[w] = low[w] = len(index)
                    stack.append(w)
                    on_stack.add(w)
                    work.append((w, iter(sorted(graph[w]))))
                elif w in on_stack:
                    low[v] = min(low[v], index[w])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[v])
            if low[v] == index[v]:
                comp = []
                while True:
                    w = stack.pop()
                    on_stack.discard(w)
                    comp.append(w)
                    if w == v:
                        break
                if len(comp) > 1:
                    found.append(sorted(comp))
    return found


def main(argv: list[str]) -> int:
    packages = argv or ["services", "app", "research"]
    found = circles(edges(modules(packages)))
    for comp in found:
        print("import circle: " + " <-> ".join(comp))
    if found:
        return 1
    print(f"no import circle among the modules of {', '.join(packages)}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
