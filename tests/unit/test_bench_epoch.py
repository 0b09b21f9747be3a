"""Smoke runs of the epoch benchmark (``bench/bench_epoch.py``): its generated cities and a tiny scenario."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.csgraph as cg

from bench import bench_epoch


def test_the_irregular_street_city_is_one_strongly_connected_city_with_one_way_streets() -> None:
    """``street_city``: every node reaches every other, some streets run one way only, the arterials are
    faster than the side streets, and it is as large as the metropolitan scenarios need."""
    net = bench_epoch.street_city().network
    assert 19_000 <= net.n_nodes <= 22_500
    adj = sp.csr_matrix((np.ones(len(net.edge_u)), (net.edge_u, net.edge_v)), shape=(net.n_nodes,) * 2)
    assert cg.connected_components(adj, connection="strong")[0] == 1
    pairs = set(zip(net.edge_u.tolist(), net.edge_v.tolist(), strict=True))
    one_way = sum((v, u) not in pairs for u, v in pairs)
    assert 0.05 * len(pairs) < one_way < 0.3 * len(pairs)
    kmh = net.edge_length_m / net.edge_time_s * 3.6
    assert kmh.min() == pytest.approx(25.0) and kmh.max() == pytest.approx(60.0)


@pytest.mark.slow
def test_a_tiny_paper_run_of_the_epoch_benchmark(capsys: pytest.CaptureFixture[str]) -> None:
    """Two paper epochs in-process beside the floor, without writing the report: each has a latency on
    default threads and on one (their decisions checked equal inside), a floor and the phases."""
    assert bench_epoch.main(["--scenario", "paper", "--epochs", "2", "--no-http", "--no-write"]) == 0
    out = capsys.readouterr().out
    assert out.count("[paper] epoch ") == 2
    r = bench_epoch.run_inprocess(bench_epoch.SCENARIOS["paper"], 2)
    for key in ("latency", "latency_1thread", "floor"):
        assert len(r[key]) == 2  # type: ignore[arg-type]
    assert set(r["phases_ms"]) == set(bench_epoch.PHASES)  # type: ignore[call-overload]
