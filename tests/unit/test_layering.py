"""The layers hold: nothing under ``services/`` imports the shell or reads the environment, and the API and
the fleet worker reach the store only through the use cases."""

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


APP = SERVICES.parent / "app"
STORE_PARTS = {
    "Store",
    "EpochStore",
    "TaskStore",
    "AdminStore",
    "FleetStore",
    "DispatchStore",
    "StreamStore",
    "WorkerStore",
}
"""The store port's protocols (``app.ports``): what a use case takes (its records and errors are free)."""
CALLERS = sorted([*(APP / "api").glob("*.py"), *(APP / "worker").glob("*.py")])
"""The API and the worker; the composition root (``app/bootstrap.py``) hands them the store's use cases."""


def _store_imports(path: Path) -> list[str]:
    """The store port's protocols and adapters ``path`` imports."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    found: list[str] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module == "app.ports":
            found += [f"line {node.lineno}: {a.name}" for a in node.names if a.name in STORE_PARTS]
        elif isinstance(node, ast.ImportFrom) and (node.module or "").startswith("app.adapters"):
            found.append(f"line {node.lineno}: {node.module}")
        elif isinstance(node, ast.Import):
            found += [
                f"line {node.lineno}: {a.name}" for a in node.names if a.name.startswith("app.adapters")
            ]
    return found


@pytest.mark.parametrize("path", CALLERS, ids=[str(p.relative_to(APP)) for p in CALLERS])
def test_the_api_and_the_worker_reach_the_store_through_the_use_cases(path: Path) -> None:
    assert _store_imports(path) == [], f"{path.name} takes the store itself, not a use case (docs/DESIGN.md)"


def test_the_store_check_catches_a_store(tmp_path: Path) -> None:
    bad = tmp_path / "bad.py"
    bad.write_text(
        "from app.ports import FleetRecord, WorkerStore\nfrom app.adapters.memory_store import MemoryStore\n"
        "import app.adapters.redis_store\n"
    )
    assert _store_imports(bad) == [
        "line 1: WorkerStore",
        "line 2: app.adapters.memory_store",
        "line 3: app.adapters.redis_store",
    ]
    assert len(CALLERS) >= 15
