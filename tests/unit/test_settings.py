"""The settings: one model per concern, every setting read from the environment variable it always had
(``SD_`` and its flat name), the flat names taken as keywords too, and the README's configuration table
naming only settings that exist while README.md and docs/FLEET.md together name every one."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import pytest
from pydantic import ValidationError

from app.settings import Settings, flat_names

ROOT = Path(__file__).resolve().parents[2]

ENVIRONMENT = {
    "SD_STORE": ("redis", ("store", "kind"), "redis"),
    "SD_REDIS_URL": ("redis://h:1/2", ("store", "redis_url"), "redis://h:1/2"),
    "SD_STORE_TIMEOUT_S": ("2.5", ("store", "timeout_s"), 2.5),
    "SD_RETENTION_S": ("7200", ("store", "retention_s"), 7200),
    "SD_HOST": ("0.0.0.0", ("server", "host"), "0.0.0.0"),
    "SD_MAX_CONNECTIONS": ("33", ("server", "max_connections"), 33),
    "SD_TOKENS": ('{"abcdefgh1": ["read"]}', ("auth", "tokens"), {"abcdefgh1": ["read"]}),
    "SD_CITIES_DIR": ("/x/cities", ("cities", "user_dir"), Path("/x/cities")),
    "SD_BUNDLED_CITIES_DIR": ("/y", ("cities", "bundled_dir"), Path("/y")),
    "SD_MAX_TAXIS": ("7", ("limits", "max_taxis"), 7),
    "SD_DISPATCH_WORKERS": ("3", ("dispatch", "workers"), 3),
    "SD_EPOCH_MAX_AHEAD_S": ("60", ("dispatch", "epoch_max_ahead_s"), 60),
    "SD_WORKER_CITIES": ('["chengdu"]', ("worker", "cities"), ["chengdu"]),
    "SD_WORKER_STALE_S": ("40", ("worker", "stale_s"), 40.0),
    "SD_WORKER_SIZES": ("[40, 20]", ("sizing", "sizes"), [20, 40]),
    "SD_WORKER_TASKS": ("12", ("sizing", "n_tasks"), 12),
    "SD_WORKER_COMPLETION_TARGET": ("0.5", ("sizing", "completion_target"), 0.5),
    "SD_WORKER_JOBS": ("5", ("runs", "jobs"), 5),
    "SD_WORKER_RUN_CACHE": ("disk", ("runs", "cache"), "disk"),
    "SD_VAR_DIR": ("/v", ("runs", "var_dir"), Path("/v")),
    "SD_LOG_LEVEL": ("debug", (None, "log_level"), "debug"),
}
"""A variable of every group: its text, where it lands, its value there."""


def _at(settings: Settings, group: str | None, field: str) -> Any:
    return getattr(settings if group is None else getattr(settings, group), field)


def test_every_setting_has_one_flat_name_and_they_are_the_fields_there_were() -> None:
    table = flat_names()  # raises on two fields with one flat name
    assert len(table) == 58
    assert table["store"] == ("store", "kind") and table["worker_tasks"] == ("sizing", "n_tasks")
    assert {f"SD_{flat.upper()}" for flat in table} >= set(ENVIRONMENT)


def test_each_variable_lands_in_its_group(monkeypatch: pytest.MonkeyPatch) -> None:
    for name, (text, _, _) in ENVIRONMENT.items():
        monkeypatch.setenv(name, text)
    settings = Settings()
    for name, (_, (group, field), value) in ENVIRONMENT.items():
        assert _at(settings, group, field) == value, name
    other = Settings().sizing
    assert other.days == 10 and other.alpha == 0.05  # the group's other fields keep their defaults


def test_keywords_take_flat_names_and_groups_and_win_over_the_environment(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setenv("SD_WORKER_DAYS", "7")
    monkeypatch.setenv("SD_WORKER_ALPHA", "0.1")
    monkeypatch.setenv("SD_STORE", "redis")
    flat: dict[str, Any] = {"worker_days": 3, "store": "memory"}
    s = Settings(**flat)
    assert (s.sizing.days, s.sizing.alpha, s.store.kind) == (3, 0.1, "memory")
    grouped: dict[str, Any] = {"sizing": {"days": 4}}
    nested = Settings(**grouped)
    assert (nested.sizing.days, nested.sizing.alpha, nested.store.kind) == (4, 0.1, "redis")
    moved = s.with_values(host="0.0.0.0", worker_days=5)
    assert (moved.server.host, moved.sizing.days, moved.sizing.alpha) == ("0.0.0.0", 5, 0.1)
    assert s.with_values() == s and s.server.host == "127.0.0.1"
    with pytest.raises(ValidationError):
        Settings(**{"worker_dayz": 3, **flat})
    with pytest.raises(ValidationError):
        s.with_values(worker_days=1)


def _readme_table_names() -> list[str]:
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    rows = [line for line in text.splitlines() if line.startswith("| `SD_")]
    return [name for row in rows for name in re.findall(r"`(SD_[A-Z0-9_]+\*?)`", row.split("|")[1])]


def test_the_readme_table_names_settings_that_exist() -> None:
    known = {f"SD_{flat.upper()}" for flat in flat_names()}
    named = _readme_table_names()
    assert len(named) >= 30
    for name in named:
        if name.endswith("*"):
            assert any(k.startswith(name[:-1]) for k in known), name
        else:
            assert name in known, name


def test_the_docs_name_every_setting() -> None:
    text = (ROOT / "README.md").read_text(encoding="utf-8") + (ROOT / "docs" / "FLEET.md").read_text(
        encoding="utf-8"
    )
    missing = [f"SD_{f.upper()}" for f in flat_names() if not re.search(rf"\bSD_{f.upper()}\b", text)]
    assert missing == []
