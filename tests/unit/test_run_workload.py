"""A run on a bundle that can draw no demand of its own fails before its network is loaded."""

from __future__ import annotations

import json
import pickle
from pathlib import Path

import pytest

from app.adapters.city_registry import BUNDLED_DIR
from app.runs.spec import RunJob, RunSpec
from app.runs.workload import NoDemandSource, check_demand_source, run_job
from services.citydata import CityDataError
from services.sim.demand import DemandSet, Request


def _bare(tmp_path: Path) -> Path:
    """Chengdu's ``city.json`` without its POIs (no ``files``), beside a network file that cannot be read."""
    d = tmp_path / "bare"
    d.mkdir()
    meta = json.loads((BUNDLED_DIR / "chengdu" / "city.json").read_text())
    meta["name"], meta["files"] = "bare", {}
    (d / "city.json").write_text(json.dumps(meta))
    (d / "network.npz").write_bytes(b"not a network")
    return d


def test_a_bundle_without_pois_or_requests_fails_before_its_network_is_read(tmp_path: Path) -> None:
    bare = _bare(tmp_path)
    with pytest.raises(NoDemandSource, match="'bare' has neither POIs nor recorded requests"):
        check_demand_source(bare)
    with pytest.raises(NoDemandSource) as raised:  # not the unreadable network's CityDataError: never opened
        run_job(RunJob(RunSpec(city="bare"), bare))
    assert str(pickle.loads(pickle.dumps(raised.value))) == str(raised.value)  # as a pool process sends it
    check_demand_source(BUNDLED_DIR / "chengdu")  # POIs
    check_demand_source(BUNDLED_DIR / "manhattan")  # recorded requests


def test_a_run_on_recorded_demand_needs_no_source_in_the_bundle(tmp_path: Path) -> None:
    """With the demand given (recorded epochs), the bundle's network is what the run reads first."""
    bare = _bare(tmp_path)
    demand = DemandSet("bare", "2026-11-23", (Request("a", 1.8e9, 1, 3),), "recorded")
    with pytest.raises(CityDataError):
        run_job(RunJob(RunSpec(city="bare"), bare, demand))
