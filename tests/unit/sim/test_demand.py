"""Demand sets: the synthetic Chengdu generator, the real and bootstrapped NYC day, CSV and JSON files."""

from __future__ import annotations

import csv
import datetime as dt
import gzip
import json
from pathlib import Path

import numpy as np
import pytest
from numpy.typing import NDArray
from scipy.spatial import ConvexHull
from scipy.spatial.distance import pdist

from services.city import City
from services.citydata import load_city
from services.sim.demand import DemandFileError, DemandSet, demand_from_json, demand_to_json
from services.sim.demand_chengdu import (
    HOURLY_PROFILE,
    LENGTH_QUANTILES_KM,
    DemandShape,
    PoiDensity,
    chengdu_demand,
    length_quantile_m,
    pick_destinations,
    poi_density,
    read_pois_csv,
)
from services.sim.demand_csv import read_demand_csv, write_demand_csv
from services.sim.demand_nyc import TripRecords, manhattan_demand, read_nyc_requests, thinned_counts

ROOT = Path(__file__).resolve().parents[3]
CHENGDU = ROOT / "app" / "data" / "cities" / "chengdu"
MANHATTAN = ROOT / "app" / "data" / "cities" / "manhattan"
POIS = CHENGDU / "chengdu_2ndring_osm_pois.csv"
NYC = MANHATTAN / "nyc_20k.csv.gz"
N_DAYS = 40
SEED = 7


@pytest.fixture(scope="module")
def chengdu() -> City:
    return load_city(CHENGDU)


@pytest.fixture(scope="module")
def density(chengdu: City) -> PoiDensity:
    return poi_density(chengdu, read_pois_csv(POIS))


@pytest.fixture(scope="module")
def days(chengdu: City, density: PoiDensity) -> dict[int, list[DemandSet]]:
    """N_DAYS days of each scenario, one seed."""
    return {
        s: [chengdu_demand(chengdu, density, seed=SEED, scenario=s, day=d) for d in range(N_DAYS)]
        for s in (1, 2, 3)
    }


def _od(sets: list[DemandSet]) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    o = np.array([r.origin for s in sets for r in s.requests], dtype=np.int64)
    d = np.array([r.destination for s in sets for r in s.requests], dtype=np.int64)
    return o, d


def _lengths_m(city: City, sets: list[DemandSet]) -> NDArray[np.float64]:
    o, d = _od(sets)
    net = city.network
    return np.asarray(np.hypot(net.x_m[o] - net.x_m[d], net.y_m[o] - net.y_m[d]), dtype=np.float64)


# ------------------------------------------------------------------------------------------ Chengdu


def test_bundled_pois_are_read(density: PoiDensity) -> None:
    assert read_pois_csv(POIS).shape == (774, 2)
    assert density.n_pois == 774
    assert density.node_weight.sum() == pytest.approx(1.0)
    assert (density.node_weight > 0).all()


def test_same_seed_scenario_day_give_the_same_set(chengdu: City, density: PoiDensity) -> None:
    a = chengdu_demand(chengdu, density, seed=3, scenario=2, day=5)
    b = chengdu_demand(chengdu, read_pois_csv(POIS), seed=3, scenario=2, day=5)  # density built inside
    assert a == b
    assert a.seed == 3 and a.generator == "chengdu-synthetic"
    assert a.params["scenario"] == 2 and a.params["day"] == 5


def test_other_day_or_seed_gives_another_set(chengdu: City, density: PoiDensity) -> None:
    base = chengdu_demand(chengdu, density, seed=3, day=5)
    assert chengdu_demand(chengdu, density, seed=3, day=6).requests != base.requests
    assert chengdu_demand(chengdu, density, seed=4, day=5).requests != base.requests
    assert (
        chengdu_demand(chengdu, density, seed=3, day=6).params["volume_factor"]
        != base.params["volume_factor"]
    )


def test_requests_are_well_formed(chengdu: City, days: dict[int, list[DemandSet]]) -> None:
    hz = chengdu.horizon
    for s in days[3][:5]:
        start = hz.start_s(s.date)
        times = [r.time_s for r in s.requests]
        assert times == sorted(times)
        assert all(start <= t < start + hz.length_s and t == int(t) for t in times)
        assert len({r.id for r in s.requests}) == len(s.requests)
        assert all(r.origin != r.destination for r in s.requests)
        assert all(0 <= r.origin < chengdu.network.n_nodes for r in s.requests)
        assert s.manifest()["n_requests"] == len(s.requests)
        json.dumps(s.manifest())  # JSON-ready


def test_hourly_counts_follow_the_profile(chengdu: City, days: dict[int, list[DemandSet]]) -> None:
    hz = chengdu.horizon
    counts = np.array(
        [s.counts_per_interval(hz.start_s(s.date), hz.interval_s, hz.n_intervals) for s in days[1]]
    )
    assert counts.sum(axis=1).tolist() == [len(s.requests) for s in days[1]]  # nothing outside the horizon
    share = counts.sum(axis=0) / counts.sum()
    target = np.array(HOURLY_PROFILE) / sum(HOURLY_PROFILE)
    # ~23,000 requests: the standard error of a share is below 0.003; allow four of them
    assert np.abs(share - target).max() < 0.012, share
    # mean per hour: the daily factor (sd 0.1) averages to sd 0.016 over 40 days; allow three of them
    assert counts.mean() == pytest.approx(144.0, rel=0.05)
    factors = [s.params["volume_factor"] for s in days[1]]
    assert 0.05 < float(np.std(factors)) < 0.15


def test_no_variation_gives_the_expected_volume(chengdu: City, density: PoiDensity) -> None:
    s = chengdu_demand(chengdu, density, seed=1, shape=DemandShape(volume_sd=0.0, jitter_sd=0.0))
    assert s.params["volume_factor"] == 1.0
    expected = 144.0 * 4 * np.array(HOURLY_PROFILE) / sum(HOURLY_PROFILE)
    assert s.params["expected_per_interval"] == pytest.approx(expected.tolist())


def test_quantile_function_passes_through_the_knots() -> None:
    p = [k[0] for k in LENGTH_QUANTILES_KM]
    km = [k[1] for k in LENGTH_QUANTILES_KM]
    assert length_quantile_m(p).tolist() == pytest.approx([1000.0 * q for q in km])
    assert length_quantile_m([0.375]).tolist() == pytest.approx([4200.0])  # halfway between P25 and P50


def test_the_network_cannot_host_the_measured_p90(chengdu: City) -> None:
    """Why the P90 tolerance below is wide: the longest straight line between two nodes is ~11.8 km."""
    xy = np.column_stack([chengdu.network.x_m, chengdu.network.y_m])
    longest = float(pdist(xy[ConvexHull(xy).vertices]).max())
    assert 11_500.0 < longest < 12_000.0


def test_trip_lengths_match_the_measured_quantiles(chengdu: City, days: dict[int, list[DemandSet]]) -> None:
    length = _lengths_m(chengdu, days[1])
    got = np.percentile(length, [10, 25, 50, 75, 90]) / 1000.0
    p10, p25, p50, p75, p90 = got
    assert p10 == pytest.approx(1.8, rel=0.10)
    assert p25 == pytest.approx(3.0, rel=0.10)
    assert p50 == pytest.approx(5.4, rel=0.10)
    assert p75 == pytest.approx(8.1, rel=0.15)  # about 10 % short: the longest trips are clamped
    # P90 cannot be reached in a 9 x 9 km box (see the test above): about 8.7 km instead of 11.7
    assert 0.70 * 11.7 < p90 < 0.80 * 11.7, got


def test_remote_cells_have_low_request_density(
    chengdu: City, density: PoiDensity, days: dict[int, list[DemandSet]]
) -> None:
    occupied = np.bincount(density.node_cell, minlength=chengdu.grid.n_cells) > 0
    assert 0.2 < density.remote_cell.sum() / occupied.sum() < 0.3
    o, _ = _od(days[1])
    cell_counts = np.bincount(density.node_cell[o], minlength=chengdu.grid.n_cells)
    # the generated origins agree: a remote cell sees fewer requests than any of most other cells
    assert cell_counts[density.remote_cell].max() < np.median(cell_counts[occupied & ~density.remote_cell])
    assert density.remote_node[o].mean() < 0.03


def test_scenarios_move_destinations_into_remote_cells_at_the_same_volume(
    chengdu: City, density: PoiDensity, days: dict[int, list[DemandSet]]
) -> None:
    share = {}
    for s in (1, 2, 3):
        o, d = _od(days[s])
        share[s] = float(density.remote_node[d].mean())
    for day in range(N_DAYS):
        one, two, three = (days[s][day] for s in (1, 2, 3))
        # same times, origins and ids: only destinations differ
        assert [(r.id, r.time_s, r.origin) for r in one.requests] == [
            (r.id, r.time_s, r.origin) for r in three.requests
        ]
        moved2 = {r.id for r, q in zip(one.requests, two.requests, strict=True) if r != q}
        moved3 = {r.id for r, q in zip(one.requests, three.requests, strict=True) if r != q}
        assert moved2 <= moved3  # scenario 3 moves what scenario 2 moves, and more
    n2 = sum(s.params["n_moved_remote"] for s in days[2])
    n3 = sum(s.params["n_moved_remote"] for s in days[3])
    n = sum(len(s.requests) for s in days[1])
    assert n2 / n == pytest.approx(0.2, abs=0.01) and n3 / n == pytest.approx(0.4, abs=0.01)
    # a moved destination is always remote, so the share rises by 20 (40) % of the non-remote rest
    assert share[2] == pytest.approx(share[1] + 0.2 * (1 - share[1]), abs=0.02)
    assert share[3] == pytest.approx(share[1] + 0.4 * (1 - share[1]), abs=0.02)
    assert share[1] < 0.25
    # the trip-length calibration survives the move
    for s in (2, 3):
        assert np.median(_lengths_m(chengdu, days[s])) / 1000.0 == pytest.approx(5.4, rel=0.10)


def test_unknown_scenario_and_bad_profile_are_errors(chengdu: City, density: PoiDensity) -> None:
    with pytest.raises(ValueError, match="scenario"):
        chengdu_demand(chengdu, density, seed=0, scenario=4)
    with pytest.raises(ValueError, match="profile"):
        chengdu_demand(chengdu, density, seed=0, shape=DemandShape(profile=(1.0, 2.0)))
    with pytest.raises(ValueError, match="seed"):
        chengdu_demand(chengdu, density, seed=-1)


def test_pick_destinations_follows_the_length_rule() -> None:
    x = np.arange(11, dtype=np.float64) * 1000.0  # nodes every km on a line
    y = np.zeros(11)
    w = np.ones(11)
    origins = np.array([0, 0, 5, 5, 0], dtype=np.int64)
    lengths = np.array([3000.0, 20_000.0, 2000.0, 0.0, 3000.0])
    u = np.array([0.5, 0.5, 0.0, 0.5, 0.5])
    allowed = np.ones(11, dtype=bool)
    got = pick_destinations(x, y, origins, lengths, u, w, allowed)
    assert got[0] == 3  # the node 3 km away
    assert got[1] == 10  # too long for the line: the farthest node
    assert got[2] == 3  # two nodes 2 km away (3 and 7): u = 0 takes the first
    assert got[3] in (4, 6)  # length 0: the nearest nodes other than the origin itself
    allowed[:8] = False
    assert pick_destinations(x, y, origins[:1], lengths[:1], u[:1], w, allowed)[0] == 8  # nearest in length
    assert pick_destinations(x, y, origins[:1], lengths[:1], u[:1], w, np.arange(11) == 0)[0] == -1
    # weights: node 7 has all the weight among the two candidates 2 km from node 5
    w2 = np.ones(11)
    w2[3] = 0.0
    assert pick_destinations(x, y, origins[2:3], lengths[2:3], u[2:3], w2)[0] == 7


def test_poi_file_errors_name_the_row(tmp_path: Path) -> None:
    p = tmp_path / "pois.csv"
    p.write_text("osm_node_id,lon,lat\n1,104.05,30.7\n2,east,30.7\n", encoding="utf-8")
    with pytest.raises(DemandFileError, match=r"^pois\.csv, row 2: lon/lat must be numbers"):
        read_pois_csv(p)
    p.write_text("osm_node_id,lon\n1,104.05\n", encoding="utf-8")
    with pytest.raises(DemandFileError, match=r"^pois\.csv: missing column\(s\) lat"):
        read_pois_csv(p)


# ---------------------------------------------------------------------------------------- Manhattan


@pytest.fixture(scope="module")
def manhattan() -> City:
    return load_city(MANHATTAN)


@pytest.fixture(scope="module")
def nyc() -> TripRecords:
    return read_nyc_requests(NYC)


@pytest.fixture(scope="module")
def nyc_day0(manhattan: City, nyc: TripRecords) -> DemandSet:
    return manhattan_demand(manhattan, nyc)


def test_nyc_file_is_read_whole(nyc: TripRecords) -> None:
    assert len(nyc) == 19_979
    assert nyc.source == "nyc_20k.csv.gz"


def test_nyc_day0_is_the_real_morning(manhattan: City, nyc_day0: DemandSet) -> None:
    """Independent count: the csv module for the horizon, brute-force nearest nodes for the snap."""
    with gzip.open(NYC, "rt", encoding="utf-8", newline="") as f:
        rows = [
            r
            for r in csv.DictReader(f)
            if "2014-12-21 08:00:00" <= r["departure_time"] < "2014-12-21 12:00:00"
        ]
    assert len(rows) == 2598  # data/README.md
    net = manhattan.network

    def nearest_m(lon: list[float], lat: list[float]) -> NDArray[np.float64]:
        x, y = net.project(np.array(lon), np.array(lat))
        d2 = (x[:, None] - net.x_m[None, :]) ** 2 + (y[:, None] - net.y_m[None, :]) ** 2
        return np.asarray(np.sqrt(d2.min(axis=1)), dtype=np.float64)

    o = nearest_m([float(r["o_lon"]) for r in rows], [float(r["o_lat"]) for r in rows])
    d = nearest_m([float(r["d_lon"]) for r in rows], [float(r["d_lat"]) for r in rows])
    kept = {r["request_id"] for r, a, b in zip(rows, o, d, strict=True) if a <= 500.0 and b <= 500.0}
    assert {r.id for r in nyc_day0.requests} == kept
    assert len(nyc_day0.requests) == 2497  # 101 trips leave Manhattan (more than 500 m from every node)
    assert nyc_day0.params["n_dropped_off_network"] == 2598 - len(kept)
    assert nyc_day0.generator == "nyc-2014-12-21" and nyc_day0.seed is None
    # times as they are: 08:00 New York is 13:00 UTC in winter
    first = min(r.time_s for r in nyc_day0.requests)
    assert dt.datetime.fromtimestamp(first, dt.UTC) == dt.datetime(2014, 12, 21, 13, 0, tzinfo=dt.UTC)


def test_nyc_bootstrap_keeps_the_hourly_counts(
    manhattan: City, nyc: TripRecords, nyc_day0: DemandSet
) -> None:
    hz = manhattan.horizon
    start = hz.start_s(nyc_day0.date)
    real = nyc_day0.counts_per_interval(start, hz.interval_s, hz.n_intervals)
    assert real == nyc_day0.params["real_per_interval"] == [612, 616, 608, 661]
    real_od = [
        {
            (r.origin, r.destination)
            for r in nyc_day0.requests
            if start + k * 3600 <= r.time_s < start + (k + 1) * 3600
        }
        for k in range(4)
    ]
    one = manhattan_demand(manhattan, nyc, seed=5, day=1)
    assert one == manhattan_demand(manhattan, nyc, seed=5, day=1)
    assert one.requests != manhattan_demand(manhattan, nyc, seed=5, day=2).requests
    assert one.generator == "nyc-bootstrap" and one.seed == 5
    assert one.counts_per_interval(start, hz.interval_s, hz.n_intervals) == real
    assert len({r.id for r in one.requests}) == len(one.requests)
    for r in one.requests:
        k = int((r.time_s - start) // 3600)
        assert (r.origin, r.destination) in real_od[k]  # resampled within its own hour
        assert r.time_s == int(r.time_s)
    # with replacement: some real request is drawn twice somewhere in the day
    assert len({(r.origin, r.destination) for r in one.requests}) < len(one.requests)


def test_nyc_thinned_to_the_paper_rate(manhattan: City, nyc: TripRecords, nyc_day0: DemandSet) -> None:
    thin = manhattan_demand(manhattan, nyc, seed=2, rate_per_hour=144.0)
    assert len(thin.requests) == 576
    assert thin.params["per_interval"] == thinned_counts(np.array([612, 616, 608, 661]), 576).tolist()
    assert {r.id for r in thin.requests} <= {r.id for r in nyc_day0.requests}
    boot = manhattan_demand(manhattan, nyc, seed=2, day=3, rate_per_hour=144.0)
    assert len(boot.requests) == 576
    with pytest.raises(ValueError, match="seed"):
        manhattan_demand(manhattan, nyc, rate_per_hour=144.0)
    with pytest.raises(ValueError, match="thin"):
        manhattan_demand(manhattan, nyc, seed=2, rate_per_hour=10_000.0)


def test_thinned_counts_split_by_largest_remainder() -> None:
    assert thinned_counts(np.array([10, 10, 10]), 10).tolist() == [4, 3, 3]
    assert thinned_counts(np.array([612, 616, 608, 661]), 576).sum() == 576
    assert thinned_counts(np.array([5, 0]), 5).tolist() == [5, 0]


def test_nyc_reader_errors_name_the_row(tmp_path: Path) -> None:
    p = tmp_path / "trips.csv"
    head = "request_id,o_lat,o_lon,d_lat,d_lon,departure_time,passengers\n"
    good = "1,40.72,-73.99,40.73,-74.00,2014-12-21 08:00:00,1\n"
    p.write_text(head + good + "2,40.72,-73.99,40.73,-74.00,21/12/2014 08:00,1\n", encoding="utf-8")
    with pytest.raises(DemandFileError, match=r"^trips\.csv, row 2: departure_time"):
        read_nyc_requests(p)
    p.write_text(head + good + good, encoding="utf-8")
    with pytest.raises(DemandFileError, match=r"^trips\.csv, row 2: request_id '1'"):
        read_nyc_requests(p)


# ---------------------------------------------------------------------------------------- CSV, JSON


def test_csv_round_trip(chengdu: City, density: PoiDensity, tmp_path: Path) -> None:
    s = chengdu_demand(chengdu, density, seed=0, scenario=3, day=1)
    for name in ("demand.csv", "demand.csv.gz"):
        back = read_demand_csv(chengdu, write_demand_csv(s, chengdu, tmp_path / name))
        assert back.requests == s.requests and back.date == s.date and back.city == s.city
        assert back.generator == "csv" and back.params["format"] == "node"
    assert read_demand_csv(chengdu, tmp_path / "demand.csv", date=s.date).requests == s.requests


def test_json_round_trip(
    chengdu: City, manhattan: City, nyc: TripRecords, days: dict[int, list[DemandSet]]
) -> None:
    s = days[2][0]
    assert demand_from_json(json.loads(json.dumps(demand_to_json(s, chengdu))), chengdu) == s
    b = manhattan_demand(manhattan, nyc, seed=1, day=2)
    assert demand_from_json(json.loads(json.dumps(demand_to_json(b, manhattan))), manhattan) == b
    bad = demand_to_json(s, chengdu)
    bad["requests"][4][2] = 1
    with pytest.raises(DemandFileError, match=r"^demand\.json, row 5: unknown node id 1"):
        demand_from_json(bad, chengdu)


def _node_id(city: City, i: int) -> int:
    return int(city.network.node_ids[i])


def _lonlat(city: City, i: int) -> str:
    """Node ``i``'s exact lon,lat as CSV text."""
    return f"{float(city.network.lon[i])!r},{float(city.network.lat[i])!r}"


def test_csv_lonlat_and_local_times(chengdu: City, tmp_path: Path) -> None:
    a, b = 10, 2000
    p = tmp_path / "user.csv"
    p.write_text(
        "request_id,time,origin_lon,origin_lat,destination_lon,destination_lat,passengers\n"
        f"x,2016-11-02 09:30:00,{_lonlat(chengdu, a)},{_lonlat(chengdu, b)},2\n"
        f"y,2016-11-02T01:30:00Z,{_lonlat(chengdu, b)},{_lonlat(chengdu, b)},1\n",
        encoding="utf-8",
    )
    s = read_demand_csv(chengdu, p)
    assert [(r.id, r.origin, r.destination) for r in s.requests] == [("x", a, b), ("y", b, b)]
    t_local = dt.datetime(2016, 11, 2, 9, 30, tzinfo=dt.timezone(dt.timedelta(hours=8))).timestamp()
    assert [r.time_s for r in s.requests] == [t_local, t_local]  # 01:30Z is 09:30 in Chengdu
    assert s.date == "2016-11-02" and s.params["format"] == "lonlat"
    assert s.params["ignored_columns"] == ["passengers"] and s.params["max_snap_m"] < 1.0


NODE_HEAD = "request_id,time,origin_node,destination_node\n"


@pytest.mark.parametrize(
    ("body", "row", "problem"),
    [
        ("r1,2016-11-02 08:10:00,{a},999\n", 1, "destination_node 999 is not a node"),
        ("r1,2016-11-02 08:10:00,{a},{b}\nr2,2016-11-02 8:10,{a},{b}\n", 2, "time '2016-11-02 8:10' is not"),
        ("r1,2016-11-02 08:10:00.5,{a},{b}\n", 1, "must be whole seconds"),
        ("r1,2016-11-02 13:10:00,{a},{b}\n", 1, "outside the horizon"),
        ("r1,2016-11-02T08:10:00+01:00,{a},{b}\n", 1, "outside the horizon"),  # 15:10 in Chengdu
        ("r1,2016-11-02 08:10:00,{a},{b}\nr1,2016-11-02 08:20:00,{a},{b}\n", 2, "duplicate request_id 'r1'"),
        ("r1,2016-11-02 08:10:00,{a},{b}\n,2016-11-02 08:20:00,{a},{b}\n", 2, "empty request_id"),
        ("r1,2016-11-02 08:10:00,{a},{b}\nr2,2016-11-02 08:20:00,{a}\n", 2, "expected 4 fields, found 3"),
        ("r1,2016-11-02 08:10:00,4.5,{b}\n", 1, "origin_node must be an integer"),
        ("r1,2016-11-03 08:10:00,{a},{b}\nr2,2016-11-02 08:20:00,{a},{b}\n", 2, "outside the horizon"),
    ],
)
def test_csv_errors_name_file_and_row(
    chengdu: City, tmp_path: Path, body: str, row: int, problem: str
) -> None:
    p = tmp_path / "bad.csv"
    p.write_text(NODE_HEAD + body.format(a=_node_id(chengdu, 0), b=_node_id(chengdu, 1)), encoding="utf-8")
    with pytest.raises(DemandFileError) as err:
        read_demand_csv(chengdu, p)
    assert err.value.file == "bad.csv" and err.value.row == row
    assert str(err.value).startswith(f"bad.csv, row {row}: ") and problem in str(err.value)


def test_csv_off_network_position_names_the_row(chengdu: City, tmp_path: Path) -> None:
    net = chengdu.network
    p = tmp_path / "far.csv"
    p.write_text(
        "request_id,time,origin_lon,origin_lat,destination_lon,destination_lat\n"
        f"a,2016-11-02 08:00:00,{net.lon[0]},{net.lat[0]},{net.lon[1]},{net.lat[1]}\n"
        f"b,2016-11-02 08:00:00,{net.lon[0]},{net.lat[0]},104.3,30.7\n",
        encoding="utf-8",
    )
    with pytest.raises(
        DemandFileError, match=r"^far\.csv, row 2: destination is \d+ m from the nearest node"
    ):
        read_demand_csv(chengdu, p)


@pytest.mark.parametrize(
    ("header", "problem"),
    [
        ("request_id,origin_node,destination_node", "missing column(s) time"),
        ("request_id,time,origin_node", "missing column(s) destination_node"),
        ("request_id,time,origin_node,destination_node,origin_lon", "not both"),
        ("request_id,time,time,origin_node,destination_node", "duplicate column(s) time"),
    ],
)
def test_csv_header_errors_name_the_file(chengdu: City, tmp_path: Path, header: str, problem: str) -> None:
    p = tmp_path / "head.csv"
    p.write_text(header + "\n", encoding="utf-8")
    with pytest.raises(DemandFileError) as err:
        read_demand_csv(chengdu, p)
    assert str(err.value).startswith("head.csv: ") and problem in str(err.value)


def test_csv_same_origin_and_destination_is_allowed(chengdu: City, tmp_path: Path) -> None:
    p = tmp_path / "loop.csv"
    a = _node_id(chengdu, 7)
    p.write_text(NODE_HEAD + f"r1,2016-11-02 08:10:00,{a},{a}\n", encoding="utf-8")
    (r,) = read_demand_csv(chengdu, p).requests
    assert r.origin == r.destination == 7


def test_csv_empty_file_needs_a_date(chengdu: City, tmp_path: Path) -> None:
    p = tmp_path / "empty.csv"
    p.write_text(NODE_HEAD, encoding="utf-8")
    assert read_demand_csv(chengdu, p, date="2016-11-02").requests == ()
    with pytest.raises(DemandFileError, match="no data rows"):
        read_demand_csv(chengdu, p)


def test_a_local_time_a_clock_change_skips_is_named_once(manhattan: City, tmp_path: Path) -> None:
    """New York skips 02:00-03:00 on 8 March 2026: a local time in that hour is an error naming the file and
    row once."""
    p = tmp_path / "gap.csv"
    ids = manhattan.network.node_ids
    p.write_text(NODE_HEAD + f"x,2026-03-08 02:30:00,{ids[0]},{ids[1]}\n", encoding="utf-8")
    with pytest.raises(DemandFileError) as err:
        read_demand_csv(manhattan, p)
    assert str(err.value) == (
        "gap.csv, row 1: local time '2026-03-08 02:30:00' does not exist in America/New_York (clock change)"
    )
