"""A smoke run of the search benchmark's measurements (``bench/bench_search.py``) on a small generated city:
no timing is asserted, only that the facts it reports are sane and agree with each other."""

from __future__ import annotations

from functools import cache
from pathlib import Path
from typing import Any

import numpy as np

from bench import bench_epoch, bench_search, metro
from bench.load import Load
from services.city import City


@cache
def _city() -> City:
    return metro.metro_city(scale=0.15)


@cache
def _measured() -> dict[str, Any]:
    return bench_search.measure(_city(), n_sources=4, spread_m=400.0, reach_s=240.0, repeats=1, floor_n=2)


def test_sizes_and_shares_agree() -> None:
    sz = _measured()["sizes"]
    assert 0 < sz["kept"] <= sz["nodes"] and sz["super_edges"] > 0
    assert 0.0 <= sz["super_edges_no_cell_share"] <= 1.0
    assert 0.0 <= sz["edges_entering_a_cell_share"] <= 1.0
    assert sz["edges_entering_a_cell_share"] == sz["crossing_edges"] / sz["edges"]


def test_bounded_trees_settle_part_of_the_whole_and_the_kappa_ball_holds_the_travel_time_one() -> None:
    """The city is strongly connected, so a whole tree settles every kept node; a bounded one settles at
    most that. A kappa metric never costs more than the travel time, so its ball within the same bound holds
    at least the travel time's (the lazy and prepared trees' labels are checked equal inside)."""
    res = _measured()
    tt, kp = res["travel_time"]["raw"], res["kappa"]["raw"]
    kept = res["sizes"]["kept"]
    assert all(s == kept for s in tt["whole_settled"])
    assert all(0 < b <= kept for b in tt["bounded_settled"])
    assert all(k >= b for k, b in zip(kp["settled"], tt["bounded_settled"], strict=True))
    assert all(x > 0 for x in tt["bounded_ms"] + tt["whole_ms"] + kp["lazy_ms"] + kp["precomputed_ms"])
    assert res["kappa"]["metric_mb"] > 0 and res["floor"]["n"] == 2


def test_memory_parts_add_up() -> None:
    mem = _measured()["memory"]
    assert mem["scratch"] == mem["forward_workspace"] + mem["reverse_workspace"] + mem["algorithm1_scratch"]
    assert mem["landmarks"] == _city().network.n_nodes * 16 * 8 / 1e6  # 8 landmarks, there and back
    assert all(v > 0 for v in mem.values())


def test_limits_candidates_and_the_report(tmp_path: Path) -> None:
    """A tiny limits epoch (every taxi and rider within 1 km): its Step 1 candidates are pairs of an
    instrumented taxi and a rider; the report renders every figure into its section."""
    sc = bench_epoch.Scenario("limits", "metro", Load(6, 6, 5, 0), 1, limits=True)
    lim = bench_search.limits_candidates(_city(), sc)
    assert lim["instrumented"] == 6 and lim["riders"] == 5
    assert 0 < lim["step1_candidates"] <= lim["instrumented"] * lim["riders"]
    doc = bench_search.write_report({**_measured(), "limits": lim}, tmp_path / "PERFORMANCE.md")
    text = doc.read_text()
    assert "<!-- bench:search -->" in text and "Searches and memory at metropolitan scale" in text
    assert f"{lim['step1_candidates']:,} Step 1 candidate pairs" in text
    assert np.isfinite(_measured()["kappa"]["ratio"]["median"])


def test_the_hierarchy_fits_its_room_and_its_trips_were_checked() -> None:
    """The generated city gets a hierarchy of at most ``ARCS_PER_EDGE`` arcs per edge; its trips were found
    both ways (the paths are checked equal inside) and have edges."""
    hy = _measured()["hierarchy"]
    assert hy["arcs"] is not None and 1.0 <= hy["arcs_per_edge"] <= 3.0
    assert hy["trips"] == bench_search.TRIPS and hy["edges"] > 0
    assert hy["through_s"] > 0 and hy["guided_s"] > 0 and hy["hierarchy_mb"] > 0


def test_the_node_orders_search_the_same_trees() -> None:
    """Item 9: the same network in four numberings settles the same nodes in every bounded tree; along the
    curve a super-edge's ends lie closer than in a shuffled order."""
    order = _measured()["node_order"]
    assert set(order) == {"generated_curve", "generated_nodes", "shuffled_curve", "shuffled_nodes"}
    assert len({tuple(v["settled"]) for v in order.values()}) == 1
    assert order["shuffled_curve"]["gap"] < order["shuffled_nodes"]["gap"]
    assert all(v["ms"]["n"] == 4 for v in order.values())
