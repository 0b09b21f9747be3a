"""Print every function in ``services/`` and ``app/`` longer than MAX_LINES lines or taking more than
MAX_PARAMS parameters; exit 1 when there is one.

A function's length is the lines from its ``def`` (decorators excluded) to its last line, signature,
docstring, comments and blank lines inside it all counted; a nested function counts in its enclosing one and
on its own. Its parameters are all of them but ``self`` and ``cls``, keyword-only and ``*args``/``**kwargs``
included; there are no exceptions. Usage: ``python scripts/check_functions.py [DIR ...]`` (default:
services app).
"""

from __future__ import annotations

import ast
import sys
from pathlib import Path

MAX_LINES = 80
MAX_PARAMS = 10
ROOT = Path(__file__).resolve().parents[1]


def _params(fn: ast.FunctionDef | ast.AsyncFunctionDef) -> int:
    a = fn.args
    names = [p.arg for p in (*a.posonlyargs, *a.args, *a.kwonlyargs)]
    names += [p.arg for p in (a.vararg, a.kwarg) if p is not None]
    return len([n for n in names if n not in ("self", "cls")])


def _lines(fn: ast.FunctionDef | ast.AsyncFunctionDef) -> int:
    """From the ``def`` line (``lineno`` skips the decorators) to the function's last line."""
    end = fn.end_lineno or fn.lineno
    return end - fn.lineno + 1


def offenders(paths: list[Path]) -> list[str]:
    """One line per function over a limit: ``path:line name: N lines, M parameters``."""
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
                    found.append(f"{rel}:{node.lineno} {node.name}: {lines} lines, {params} parameters")
    return found


def main(argv: list[str]) -> int:
    paths = [ROOT / a for a in argv] if argv else [ROOT / "services", ROOT / "app"]
    found = offenders(paths)
    for line in found:
        print(line)
    if found:
        print(f"{len(found)} function(s) over {MAX_LINES} lines or {MAX_PARAMS} parameters", file=sys.stderr)
        return 1
    print(f"no function over {MAX_LINES} lines or {MAX_PARAMS} parameters")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
