"""Smoke runs of the long commands: the research experiments (tiny; the reference one twice: the second
run resumes and redoes nothing) and the replay client, in-process and over HTTP."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest

from app.adapters.city_registry import CityRegistry
from app.entrypoints.replay import replay_main
from app.runs import RunJob, RunResult, runner
from research.cli import experiment_main, fleet_experiment_main, main
from research.reference import ExperimentConfig, specs
from services.fleet.dro import worst_case


def test_experiment_smoke_writes_everything_and_resumes(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    out, report = tmp_path / "runs", tmp_path / "report"
    argv = ["--scenarios", "1,2", "--sizes", "2,3", "--seeds", "1", "--n0", "2", "--tasks", "4",
            "--jobs", "1", "--out", str(out), "--report-dir", str(report), "--quiet"]  # fmt: skip
    assert experiment_main(argv) == 0
    cfg = ExperimentConfig(scenarios=(1, 2), sizes=(2, 3), seeds=1, n0=2, n_tasks=4)
    bundle = CityRegistry().bundle_dir("chengdu")
    expected = {s.key for s in specs(cfg)}
    assert len(expected) == 12  # 2 scenarios x 2 sizes x (active, passive, wait-only)
    assert {p.stem for p in (out / "runs").glob("*.json")} == {RunJob(s, bundle).key for s in specs(cfg)}
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

    def spy(job: RunJob) -> RunResult:
        calls.append(job.key)
        raise AssertionError("a saved run was simulated again")

    monkeypatch.setattr(runner, "run_job", spy)
    assert experiment_main(argv) == 0
    assert calls == []  # every run was already saved: nothing is redone


def test_research_command_names_its_subcommands(capsys: pytest.CaptureFixture[str]) -> None:
    assert main([]) == 2 and main(["nonsense"]) == 2
    assert "experiment, fleet-experiment" in capsys.readouterr().err


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
    report = tmp_path / "report"
    argv = ["--scenarios", "1", "--sizes", "2,4", "--train-days", "3", "--test-days", "2", "--n0", "3",
            "--total-fleet", "off", "--zetas", "0,1", "--keep", "2", "--tasks", "4", "--jobs", "1",
            "--out", str(tmp_path / "runs"), "--report-dir", str(report), "--quiet",
            "--sweep-alphas", "0.05"]  # fmt: skip
    assert fleet_experiment_main(argv) == 0
    manifest = json.loads((report / "fleet_manifest.json").read_text())
    decisions = manifest["decisions"]
    assert [(d["scenario"], d["zeta"]) for d in decisions] == [(1, 0.0), (1, 1.0)]
    assert manifest["train_days"] == [1, 2, 3] and manifest["test_days"] == [4, 5]
    # an independent check: the DRO and Deterministic choices re-derived from the published samples
    samples = json.loads((report / "fleet_samples.json").read_text())["N0 = 3 | scenario 1"]
    for d in decisions:
        totals = {x: np.mean(samples["train"][str(x)]["cost_cny"], axis=1) + d["zeta"] * x for x in (2, 4)}
        wc = {x: worst_case(totals[x], "kl", alpha=0.05).value for x in (2, 4)}
        assert d["dro"]["size"] == min((2, 4), key=lambda x: (wc[x], x))
        assert d["deterministic"]["size"] == min((2, 4), key=lambda x: (float(np.mean(totals[x])), x))
        assert len(d["dro_rh_test_sizes"]) == 2 and all(len(day) == 4 for day in d["dro_rh_test_sizes"])
        test = {x: np.mean(samples["test"][str(x)]["cost_cny"], axis=1) + d["zeta"] * x for x in (2, 4)}
        assert d["realized"]["dro"] == pytest.approx(float(np.mean(test[d["dro"]["size"]])))
    with (report / "fleet_table.csv").open() as f:
        table = list(csv.DictReader(f))
    assert [int(r["n1"]) for r in table] == [2, 4, 2, 4]
    for r in table:  # the worst case is never below the sample mean for a cost to minimize
        assert float(r["worst_case"]) >= float(r["mean"]) - 1e-9
    with (report / "fleet_sensitivity.csv").open() as f:
        assert len(list(csv.DictReader(f))) == 7  # seven divergences x one alpha
    assert (report / "figures" / "fleet_tradeoff.png").stat().st_size > 5_000
    text = (report / "FLEET_SIZING.md").read_text()
    assert "DRO_RH" in text and "both wait" not in text and "pickup travel time" in text
    assert "N0 = 3, scenario 1, zeta 0: Deterministic" in capsys.readouterr().out
