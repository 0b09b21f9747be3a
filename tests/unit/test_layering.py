"""The core stays framework-free: nothing under ``services/`` imports the shell or reads the environment."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

SERVICES = Path(__file__).resolve().parents[2] / "services"
FORBIDDEN = {
    "fastapi",
    "starlette",
    "pydantic",
    "pydantic_settings",
    "redis",
    "app",
    "uvicorn",
    "httpx",
    "prometheus_client",
}
FILES = sorted(SERVICES.rglob("*.py"))


def _violations(path: Path) -> list[str]:
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    found: list[str] = []
    for node in ast.walk(tree):
        names: list[str] = []
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names = [node.module]
            if node.module == "os":
                names += [f"os.{alias.name}" for alias in node.names]
        line = node.lineno if isinstance(node, ast.stmt) else 0
        for name in names:
            if name.split(".")[0] in FORBIDDEN:
                found.append(f"line {line}: imports {name}")
            if name in ("os.environ", "os.getenv", "os.putenv"):
                found.append(f"line {line}: imports {name}")
        if (
            isinstance(node, ast.Attribute)
            and isinstance(node.value, ast.Name)
            and node.value.id == "os"
            and node.attr in ("environ", "getenv", "putenv", "environb")
        ):
            found.append(f"line {node.lineno}: uses os.{node.attr}")
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "__import__":
            found.append(f"line {node.lineno}: dynamic __import__")
    return found


def test_there_are_core_modules() -> None:
    assert len(FILES) >= 5


@pytest.mark.parametrize("path", FILES, ids=[str(p.relative_to(SERVICES)) for p in FILES])
def test_core_module_is_framework_free(path: Path) -> None:
    assert _violations(path) == [], f"{path.name} breaks the layering (docs/DESIGN.md)"


def test_the_check_catches_violations(tmp_path: Path) -> None:
    bad = tmp_path / "bad.py"
    bad.write_text(
        "import os\nfrom app.ports import Store\nimport redis.client\nfrom pydantic import BaseModel\n"
        "from os import environ\nx = os.environ.get('A')\ny = os.getenv('B')\n"
    )
    assert len(_violations(bad)) == 6
