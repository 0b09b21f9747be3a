"""Smoke runs of the product's long commands: the experiment (tiny, twice: the second run resumes and
redoes nothing) and the replay client, in-process and over HTTP."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest

from app.experiment import runner
from app.experiment.cli import experiment_main, replay_main
from app.experiment.reference import ExperimentConfig, specs


def test_experiment_smoke_writes_everything_and_resumes(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    out, report = tmp_path / "runs", tmp_path / "report"
    argv = ["--scenarios", "1,2", "--sizes", "2,3", "--seeds", "1", "--n0", "2", "--tasks", "4",
            "--jobs", "1", "--out", str(out), "--report-dir", str(report), "--quiet"]  # fmt: skip
    assert experiment_main(argv) == 0
    cfg = ExperimentConfig(scenarios=(1, 2), sizes=(2, 3), seeds=1, n0=2, n_tasks=4)
    expected = {s.key for s in specs(cfg)}
    assert len(expected) == 12  # 2 scenarios x 2 sizes x (active, passive, wait-only)
    assert {p.stem for p in (out / "runs").glob("*.json")} == expected
    with (report / "experiment_runs.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert {r["key"] for r in rows} == expected
    assert {r["mode"] for r in rows} == {"active", "passive", "wait_only"}
    active = [r for r in rows if r["mode"] == "active"]
    assert all(r["pos_extra_wait_s"] != "" for r in active)
    manifest = json.loads((report / "experiment_manifest.json").read_text())
    assert manifest["runs"] == 12 and manifest["versions"]["demand"] and manifest["seeds"]["runs"] == [0]
    for name in ("kpi_vs_n1.png", "timeliness.png", "price_of_sensing.png", "routes.png"):
        assert (report / "figures" / name).stat().st_size > 10_000
    text = (report / "EXPERIMENT.md").read_text()
    assert "Against the paper's findings" in text and "figures/kpi_vs_n1.png" in text

    calls: list[str] = []
    monkeypatch.setattr(runner, "run_result", lambda spec: calls.append(spec.key))
    assert experiment_main(argv) == 0
    assert calls == []  # every run was already saved: nothing is redone


def test_experiment_rejects_bad_arguments(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        experiment_main(["--sizes", "ten"])
    with pytest.raises(SystemExit):
        experiment_main(["--seeds", "0"])
    assert "at least one" in capsys.readouterr().err


@pytest.mark.parametrize("how", [["--inprocess"], []], ids=["inprocess", "http"])
def test_replay_prints_kpis(how: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    assert replay_main([*how, "--n1", "3", "--n0", "3", "--tasks", "5", "--seed", "4"]) == 0
    out = capsys.readouterr().out
    assert "requests" in out and "design KPI" in out and "hour 3" in out


def test_fleet_experiment_smoke(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from app.experiment.cli import fleet_experiment_main

    report = tmp_path / "report"
    argv = ["--scenarios", "1", "--sizes", "2,4", "--train-days", "3", "--test-days", "2", "--n0", "3",
            "--tasks", "4", "--jobs", "1", "--out", str(tmp_path / "runs"), "--report-dir", str(report),
            "--quiet", "--sweep-alphas", "0.05"]  # fmt: skip
    assert fleet_experiment_main(argv) == 0
    manifest = json.loads((report / "fleet_manifest.json").read_text())
    s = manifest["summary"]["1"]
    assert s["deterministic"]["size"] in (2, 4) and s["dro"]["size"] in (2, 4)
    assert len(s["dro_rh"]["sizes_by_hour"]) == 4 and manifest["train_days"] == [1, 2, 3]
    with (report / "fleet_table.csv").open() as f:
        table = list(csv.DictReader(f))
    assert [int(r["n1"]) for r in table] == [2, 4]
    for r in table:  # the worst case is never below the sample mean for a KPI to minimize
        assert float(r["dro_worst_case"]) >= float(r["deterministic_mean"]) - 1e-12
    with (report / "fleet_sensitivity.csv").open() as f:
        assert len(list(csv.DictReader(f))) == 7  # seven divergences x one alpha
    assert (report / "figures" / "fleet_design_kpi_hist.png").stat().st_size > 5_000
    assert "DRO_RH" in (report / "FLEET_SIZING.md").read_text()
    assert "scenario 1: Deterministic N1=" in capsys.readouterr().out
