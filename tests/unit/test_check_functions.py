"""``scripts/check_functions.py`` counts a function from its ``def`` to its last line and its parameters but
``self``/``cls``, on hand-written files whose counts can be read off."""

from __future__ import annotations

from pathlib import Path

from scripts import check_functions


def _write(tmp_path: Path, text: str) -> Path:
    folder = tmp_path / "pkg"
    folder.mkdir(parents=True)
    (folder / "mod.py").write_text(text, encoding="utf-8")
    return folder


def _function(lines: int, decorators: int = 0, params: str = "") -> str:
    """A function ``f`` of exactly ``lines`` lines from ``def`` to its end (a docstring, then statements)."""
    head = ["@staticmethod"] * decorators + [f"def f({params}):", '    """A docstring."""']
    return "\n".join(head + ["    x = 1"] * (lines - 2)) + "\n"


def test_a_function_of_the_limit_passes_and_one_line_more_is_reported(tmp_path: Path) -> None:
    limit = check_functions.MAX_LINES
    assert check_functions.offenders([_write(tmp_path / "a", _function(limit))]) == []
    found = check_functions.offenders([_write(tmp_path / "b", _function(limit + 1))])
    assert len(found) == 1 and found[0].endswith(f"f: {limit + 1} lines, 0 parameters")


def test_the_signature_and_docstring_count_the_decorators_do_not(tmp_path: Path) -> None:
    limit = check_functions.MAX_LINES
    text = _function(limit, decorators=3)
    assert check_functions.offenders([_write(tmp_path / "a", text)]) == []
    signature = "a,\n    b,\n"  # a signature over two more lines: the function is two lines longer
    found = check_functions.offenders([_write(tmp_path / "b", _function(limit - 1, params=signature))])
    assert len(found) == 1 and found[0].endswith(f"f: {limit + 1} lines, 2 parameters")


def test_parameters_count_all_but_self_and_cls(tmp_path: Path) -> None:
    cap = check_functions.MAX_PARAMS
    names = [f"p{i}" for i in range(cap - 2)]
    ok = f"self, {', '.join(names)}, *args, **kwargs"
    assert check_functions.offenders([_write(tmp_path / "a", _function(3, params=ok))]) == []
    over = f"cls, {', '.join(names)}, q, *args, k=1, **kwargs"
    found = check_functions.offenders([_write(tmp_path / "b", _function(3, params=over))])
    assert len(found) == 1 and found[0].endswith(f"f: 3 lines, {cap + 2} parameters")


def test_the_code_base_passes() -> None:
    assert check_functions.main([]) == 0
