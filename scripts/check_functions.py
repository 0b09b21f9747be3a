"""Print every function in ``services/`` and ``app/`` longer than MAX_LINES lines or taking more than
MAX_PARAMS parameters; exit 1 when there is one.

A function's length is the lines from its ``def`` (decorators excluded) to its last line, signature,
docstring, comments and blank lines inside it all counted; a nested function counts in its enclosing one and
on its own. Its parameters are all of them but ``self`` and ``cls``, keyword-only and ``*args``/``**kwargs``
included. A function listed in ``KNOWN`` (with the reason) may stay over a limit at its
recorded size, no more. Usage: ``python scripts/check_functions.py [DIR ...]`` (default: services app).
"""

from __future__ import annotations

import ast
import sys
from pathlib import Path

MAX_LINES = 80
MAX_PARAMS = 10
ROOT = Path(__file__).resolve().parents[1]

KNOWN: dict[str, tuple[int, int]] = {
    # Being split with the rest of their modules (the searches, the routing algorithms, the gains); each
    # leaves this list when its module is done.
    "services/routing/algorithm1.py:plan_routes": (88, 5),
}
"""Functions allowed over a limit, by ``path:name``, with the (lines, parameters) they may not exceed."""


def _params(fn: ast.FunctionDef | ast.AsyncFunctionDef) -> int:
    a = fn.args
    names = [p.arg for p in (*a.posonlyargs, *a.args, *a.kwonlyargs)]
    names += [p.arg for p in (a.vararg, a.kwarg) if p is not None]
    return len([n for n in names if n not in ("self", "cls")])


def _lines(fn: ast.FunctionDef | ast.AsyncFunctionDef) -> int:
    """From the ``def`` line (``lineno`` skips the decorators) to the function's last line."""
    end = fn.end_lineno or fn.lineno
    return end - fn.lineno + 1


def offenders(paths: list[Path], known: list[str]) -> list[str]:
    """One line per function over a limit: ``path:line name: N lines, M parameters``; those within their
    ``KNOWN`` allowance go to ``known`` instead."""
    found: list[str] = []
    for path in paths:
        for file in sorted(path.rglob("*.py")):
            tree = ast.parse(file.read_text(encoding="utf-8"), filename=str(file))
            for node in ast.walk(tree):
                if not isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                    continue
                lines, params = _lines(node), _params(node)
                if lines > MAX_LINES or params > MAX_PARAMS:
                    rel = file.relative_to(ROOT) if file.is_relative_to(ROOT) else file
                    text = f"{rel}:{node.lineno} {node.name}: {lines} lines, {params} parameters"
                    cap = KNOWN.get(f"{rel}:{node.name}")
                    if cap is not None and lines <= cap[0] and params <= cap[1]:
                        known.append(text)
                    else:
                        found.append(text)
    return found


def main(argv: list[str]) -> int:
    paths = [ROOT / a for a in argv] if argv else [ROOT / "services", ROOT / "app"]
    known: list[str] = []
    found = offenders(paths, known)
    for line in known:
        print(f"{line} (allowed: scripts/check_functions.py KNOWN)")
    for line in found:
        print(line)
    if found:
        print(f"{len(found)} function(s) over {MAX_LINES} lines or {MAX_PARAMS} parameters", file=sys.stderr)
        return 1
    other = " other" if known else ""
    print(f"no{other} function over {MAX_LINES} lines or {MAX_PARAMS} parameters")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
