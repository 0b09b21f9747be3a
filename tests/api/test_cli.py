"""`python -m app`: token, openapi, dev settings, demo, import-city and worker delegation."""

from __future__ import annotations

import argparse
import io
import json
import secrets
from pathlib import Path

import pytest

from app.entrypoints import cli
from app.entrypoints.demo import DemoConfig, run_demo
from app.settings import Settings


def test_token(capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(["token"]) == 0
    a = capsys.readouterr().out.strip()
    cli.main(["token"])
    b = capsys.readouterr().out.strip()
    assert len(a) >= 40 and a != b


def test_a_token_can_follow_an_option_on_a_command_line(monkeypatch: pytest.MonkeyPatch) -> None:
    """A token whose random part starts with ``-`` (one in 64 of them) still does not: ``replay --token
    $TOKEN`` would read it as an option."""
    monkeypatch.setattr(secrets, "token_urlsafe", lambda n: "-" + "A" * (4 * n // 3))
    token = cli.new_token()
    assert not token.startswith("-") and token.endswith("-" + "A" * 42)
    ap = argparse.ArgumentParser()
    ap.add_argument("--token")
    assert ap.parse_args(["--token", token]).token == token


def test_openapi_writes_the_document(tmp_path: Path) -> None:
    out = tmp_path / "o.json"
    assert cli.main(["openapi", "--out", str(out)]) == 0
    assert json.loads(out.read_text())["info"]["title"] == "sensedispatch"


def test_dev_settings_make_a_token_and_bind_loopback() -> None:
    s, token = cli.dev_settings(Settings().with_values(tokens={}, host="0.0.0.0"))
    assert (
        token is not None
        and s.auth.tokens == {token: ["read", "dispatch", "admin"]}
        and s.server.host == "127.0.0.1"
    )
    configured = Settings().with_values(tokens={"abcdefgh123": ["read"]}, host="0.0.0.0")
    assert cli.dev_settings(configured) == (configured, None)


def test_settings_from_environment(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("SD_TOKENS", '{"tok1-abcdefgh": ["read", "dispatch"]}')
    monkeypatch.setenv("SD_STORE", "redis")
    monkeypatch.setenv("SD_MAX_BODY_BYTES", "2048")
    s = Settings()
    assert (
        s.auth.tokens == {"tok1-abcdefgh": ["read", "dispatch"]}
        and s.store.kind == "redis"
        and s.server.max_body_bytes == 2048
    )
    monkeypatch.setenv("SD_TOKENS", '{"tok1-abcdefgh": ["root"]}')
    with pytest.raises(ValueError):
        Settings()


def test_import_city_is_delegated(tmp_path: Path) -> None:
    nodes = tmp_path / "nodes.csv"
    edges = tmp_path / "edges.csv"
    nodes.write_text("id,lon,lat\n1,104.06,30.66\n2,104.07,30.66\n")
    edges.write_text("u,v,length_m\n1,2,960\n2,1,960\n")
    rc = cli.main(
        ["import-city", "mini", "--nodes", str(nodes), "--edges", str(edges), "--out", str(tmp_path / "c")]
    )
    assert rc == 0 and (tmp_path / "c" / "mini" / "city.json").is_file()


def test_worker_is_delegated(capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("SD_STORE", "memory")
    assert cli.main(["worker", "--once", "--city", "atlantis"]) == 2
    assert "unknown cities ['atlantis']" in capsys.readouterr().err


@pytest.mark.parametrize("command", ["experiment", "fleet-experiment"])
def test_the_experiments_point_to_the_research_package(
    command: str, capsys: pytest.CaptureFixture[str]
) -> None:
    assert cli.main([command, "--seeds", "1"]) == 2
    assert f"python -m research {command}" in capsys.readouterr().err


def test_demo_in_process() -> None:
    out = io.StringIO()
    rc = run_demo(DemoConfig(epochs=2, riders=6, taxis=10, tasks=2, seed=3), out=out)
    text = out.getvalue()
    assert rc == 0, text
    assert "epoch 2/2" in text and "step 1" in text and "coverage of interval" in text
