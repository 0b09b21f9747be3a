"""City data: OSM XML and CSV readers, node-link JSON, the bundle round trip."""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from services.citydata import CityDataError, CityMeta, haversine_m, load_city, save_bundle, validate_city_name
from services.importers import read_csv_network, read_node_link, read_osm
from services.network.contraction import hilbert_key
from services.network.network import Network

# ---------------------------------------------------------------------------------------------- OSM

OSM = """<?xml version='1.0' encoding='UTF-8'?>
<osm version="0.6">
  <node id="1" lat="30.000" lon="104.000"/>
  <node id="2" lat="30.000" lon="104.001"/>
  <node id="3" lat="30.001" lon="104.001"/>
  <node id="4" lat="30.001" lon="104.000"/>
  <node id="5" lat="30.002" lon="104.000"/>
  <node id="6" lat="30.002" lon="104.001"/>
  <node id="7" lat="30.003" lon="104.001"/>
  <node id="8" lat="30.003" lon="104.002"/>
  <node id="9" lat="30.004" lon="104.002"/>
  <way id="100"><nd ref="1"/><nd ref="2"/><tag k="highway" v="residential"/></way>
  <way id="101"><nd ref="2"/><nd ref="3"/><tag k="highway" v="primary"/><tag k="oneway" v="yes"/></way>
  <way id="102"><nd ref="4"/><nd ref="3"/><tag k="highway" v="secondary"/><tag k="oneway" v="-1"/></way>
  <way id="103"><nd ref="4"/><nd ref="1"/><tag k="highway" v="tertiary"/>
    <tag k="junction" v="roundabout"/></way>
  <way id="104"><nd ref="4"/><nd ref="5"/><tag k="highway" v="motorway"/><tag k="oneway" v="no"/></way>
  <way id="105"><nd ref="5"/><nd ref="6"/><tag k="highway" v="footway"/></way>
  <way id="106"><nd ref="6"/><nd ref="3"/><tag k="highway" v="service"/></way>
  <way id="107"><nd ref="5"/><nd ref="7"/><tag k="highway" v="residential"/>
    <tag k="access" v="private"/></way>
  <way id="108"><nd ref="7"/><nd ref="8"/><tag k="highway" v="unclassified"/><tag k="area" v="yes"/></way>
  <way id="109"><nd ref="8"/><nd ref="9"/><tag k="highway" v="motorway_link"/><tag k="access" v="no"/></way>
  <way id="110"><nd ref="5"/><nd ref="4"/><tag k="highway" v="motorway"/></way>
  <way id="111"><nd ref="9"/><nd ref="99"/><tag k="highway" v="road"/></way>
  <relation id="200"><member type="way" ref="100" role=""/></relation>
</osm>
"""


def _edge_list(net: Network) -> list[tuple[int, int]]:
    ids = net.node_ids
    return [(int(ids[u]), int(ids[v])) for u, v in zip(net.edge_u, net.edge_v, strict=True)]


def _edges(net: Network) -> set[tuple[int, int]]:
    return set(_edge_list(net))


def test_osm_directions_and_exclusions(tmp_path: Path) -> None:
    path = tmp_path / "tiny.osm"
    path.write_text(OSM, encoding="utf-8")
    result = read_osm(path)
    net = result.network
    # 1<->2 two-way; 2->3 oneway; 102 reversed gives 3->4; roundabout 4->1 only; motorway oneway=no 4<->5;
    # 110 motorway implies oneway 5->4 (parallel to 104's 5->4, same length: one kept)
    assert _edges(net) == {(1, 2), (2, 1), (2, 3), (3, 4), (4, 1), (4, 5), (5, 4)}
    assert sorted(net.node_ids.tolist()) == [1, 2, 3, 4, 5]
    assert result.nodes_dropped == 0 and result.nodes_read == 5
    # numbered along a Hilbert curve over their positions, not by id
    assert (np.diff(hilbert_key(net.lon, net.lat)) >= 0).all()
    # only 110's 5->4 duplicates an edge: a two-way 110 would duplicate 4->5 as well
    assert "1 parallel edges dropped (kept the shortest)" in result.notes
    assert any("node missing" in n for n in result.notes)
    # haversine length of 0.001 degree of longitude at 30 N
    e12 = net.edge_ids([net.index_of(1), net.index_of(2)])[0]
    assert net.edge_length_m[e12] == pytest.approx(float(haversine_m(104.0, 30.0, 104.001, 30.0)))
    assert net.edge_length_m[e12] == pytest.approx(96.3, abs=0.5)
    np.testing.assert_allclose(net.edge_time_s, net.edge_length_m / (35 / 3.6))


def test_osm_largest_scc_drops_oneway_tail(tmp_path: Path) -> None:
    text = OSM.replace(
        '<way id="111">',
        '<way id="112"><nd ref="5"/><nd ref="9"/><tag k="highway" v="trunk"/>'
        '<tag k="oneway" v="true"/></way><way id="111">',
    )
    path = tmp_path / "tiny.osm"
    path.write_text(text, encoding="utf-8")
    result = read_osm(path)
    assert result.nodes_read == 6 and result.nodes_dropped == 1 and result.edges_dropped == 1
    assert 9 not in result.network.node_ids.tolist()


def test_osm_errors(tmp_path: Path) -> None:
    bad = tmp_path / "bad.osm"
    bad.write_text("<osm>\n<node id='1' lat='1' lon='2'>\n</osm>\n", encoding="utf-8")
    with pytest.raises(CityDataError, match=r"bad\.osm, line 3: malformed XML"):
        read_osm(bad)
    none = tmp_path / "none.osm"
    none.write_text("<osm><node id='1' lat='1' lon='2'/></osm>", encoding="utf-8")
    with pytest.raises(CityDataError, match=r"none\.osm: no drivable road"):
        read_osm(none)
    coord = tmp_path / "coord.osm"
    coord.write_text("<osm><node id='1' lat='95' lon='2'/></osm>", encoding="utf-8")
    with pytest.raises(CityDataError, match=r"coord\.osm: node 1 has lat/lon outside"):
        read_osm(coord)


# ---------------------------------------------------------------------------------------------- CSV

NODES = "id,lon,lat\n1,104.000,30.000\n2,104.001,30.000\n3,104.001,30.001\n4,104.010,30.010\n"
EDGES = "u,v,length_m,speed_kmh\n1,2,100,36\n2,3,110,\n3,1,150,72\n3,4,80,\n"


def _csv(tmp_path: Path, nodes: str = NODES, edges: str = EDGES) -> tuple[Path, Path]:
    n, e = tmp_path / "nodes.csv", tmp_path / "edges.csv"
    n.write_text(nodes, encoding="utf-8")
    e.write_text(edges, encoding="utf-8")
    return n, e


def test_csv_import_reports_dropped_nodes(tmp_path: Path) -> None:
    result = read_csv_network(*_csv(tmp_path))
    net = result.network
    assert sorted(net.node_ids.tolist()) == [1, 2, 3]
    assert result.nodes_dropped == 1 and result.edges_dropped == 1
    assert "dropped 1 nodes" in result.summary()
    # 100 m at 36 km/h = 10 s; blank speed -> 35 km/h; 150 m at 72 km/h = 7.5 s
    time_s = dict(zip(_edge_list(net), net.edge_time_s.tolist(), strict=True))
    assert time_s == pytest.approx({(1, 2): 10.0, (2, 3): 110 / (35 / 3.6), (3, 1): 7.5})


def test_csv_columns_in_any_order_without_speed(tmp_path: Path) -> None:
    result = read_csv_network(
        *_csv(tmp_path, "lat,id,lon\n30,1,104\n30,2,104.001\n", "length_m,v,u\n5,2,1\n5,1,2\n")
    )
    assert result.network.n_edges == 2 and result.network.lon.tolist() == [104.0, 104.001]


CSV_ERRORS = [
    # (nodes, edges, file, row-or-line text, problem regex)
    ("id,lon\n1,104\n", EDGES, "nodes.csv", "line 1", "missing header column.*lat"),
    ("id,lon,lat,name\n1,104,30,a\n", EDGES, "nodes.csv", "line 1", "unexpected header column.*name"),
    ("", EDGES, "nodes.csv", None, "empty file"),
    ("id,lon,lat\n", EDGES, "nodes.csv", None, "no data rows"),
    ("id,lon,lat\n1,104,30\n2,abc,30\n", EDGES, "nodes.csv", "row 2", "lon must be a number"),
    ("id,lon,lat\n1,104,30\n2,104,nan\n", EDGES, "nodes.csv", "row 2", "lat must be finite"),
    ("id,lon,lat\n1,104,30\n2,inf,30\n", EDGES, "nodes.csv", "row 2", "lon must be finite"),
    ("id,lon,lat\nx1,104,30\n", EDGES, "nodes.csv", "row 1", "id must be an integer"),
    ("id,lon,lat\n1,104,30\n2,181,30\n", EDGES, "nodes.csv", "row 2", r"lon 181.0 outside \[-180, 180\]"),
    ("id,lon,lat\n1,104,-91\n", EDGES, "nodes.csv", "row 1", r"lat -91.0 outside \[-90, 90\]"),
    ("id,lon,lat\n1,104,30\n2,104,30\n1,104,30\n", EDGES, "nodes.csv", "row 3", "duplicate node id 1"),
    ("id,lon,lat\n1,104,30\n2,104,30,7\n", EDGES, "nodes.csv", "row 2", "expected 3 fields, found 4"),
    (NODES, "u,v\n1,2\n", "edges.csv", "line 1", "missing header column.*length_m"),
    (NODES, "u,v,length_m,lanes\n1,2,5,2\n", "edges.csv", "line 1", "unexpected header column.*lanes"),
    (NODES, "", "edges.csv", None, "empty file"),
    (NODES, "u,v,length_m\n", "edges.csv", None, "no data rows"),
    (NODES, "u,v,length_m\n1,2,5\n1,7,5\n", "edges.csv", "row 2", "v names unknown node id 7"),
    (NODES, "u,v,length_m\n1,2,0\n", "edges.csv", "row 1", "length_m must be positive"),
    (NODES, "u,v,length_m\n1,2,5\n2,1,-3\n", "edges.csv", "row 2", "length_m must be positive"),
    (NODES, "u,v,length_m\n1,2,five\n", "edges.csv", "row 1", "length_m must be a number"),
    (NODES, "u,v,length_m,speed_kmh\n1,2,5,0\n", "edges.csv", "row 1", "speed_kmh must be positive"),
    (NODES, "u,v,length_m,speed_kmh\n1,2,5,-1\n", "edges.csv", "row 1", "speed_kmh must be positive"),
    (NODES, "u,v,length_m,speed_kmh\n1,2,5,fast\n", "edges.csv", "row 1", "speed_kmh must be a number"),
    (NODES, "u,v,length_m\n1,2,5\n2,1,NaN\n", "edges.csv", "row 2", "length_m must be finite"),
]


@pytest.mark.parametrize(("nodes", "edges", "file", "where", "problem"), CSV_ERRORS)
def test_csv_errors_name_file_row_problem(
    tmp_path: Path, nodes: str, edges: str, file: str, where: str | None, problem: str
) -> None:
    with pytest.raises(CityDataError) as info:
        read_csv_network(*_csv(tmp_path, nodes, edges))
    err = info.value
    assert err.file == file
    msg = str(err)
    assert msg.startswith(f"{file}, {where}: " if where else f"{file}: "), msg
    assert re.search(problem, msg), msg


def test_csv_blank_lines_do_not_shift_row_numbers_silently(tmp_path: Path) -> None:
    with pytest.raises(CityDataError, match=r"nodes\.csv, row 3: lon must be a number"):
        read_csv_network(*_csv(tmp_path, "id,lon,lat\n1,104,30\n\n3,x,30\n"))


def test_csv_missing_file(tmp_path: Path) -> None:
    with pytest.raises(CityDataError, match=r"nowhere\.csv: cannot read"):
        read_csv_network(tmp_path / "nowhere.csv", tmp_path / "edges.csv")


# -------------------------------------------------------------------------------------- node-link JSON


def test_node_link_uses_length_ignores_speed(tmp_path: Path) -> None:
    doc = {
        "directed": True,
        "multigraph": True,
        "nodes": [{"id": 10, "x": -73.97, "y": 40.78}, {"id": 11, "x": -73.969, "y": 40.78}],
        "links": [
            {"source": 10, "target": 11, "length": 90.0, "speed_kmph": 80.0, "key": 0},
            {"source": 10, "target": 11, "length": 120.0, "speed_kmph": 80.0, "key": 1},
            {"source": 11, "target": 10, "length": 95.0, "travel_time": 1.0, "key": 0},
        ],
    }
    path = tmp_path / "net.json"
    path.write_text(json.dumps(doc), encoding="utf-8")
    result = read_node_link(path)
    net = result.network
    assert net.crs == "EPSG:32618"
    assert net.edge_length_m.tolist() == [90.0, 95.0]
    assert net.edge_time_s.tolist() == pytest.approx([90.0 / (35 / 3.6), 95.0 / (35 / 3.6)])
    doc["links"][2]["target"] = 99  # type: ignore[index]
    path.write_text(json.dumps(doc), encoding="utf-8")
    with pytest.raises(CityDataError, match=r"net\.json, link 3: names an unknown node"):
        read_node_link(path)


# ---------------------------------------------------------------------------------------------- bundle


def test_bundle_round_trip(tmp_path: Path) -> None:
    src = tmp_path / "src"
    src.mkdir()
    net = read_csv_network(*_csv(src)).network
    meta = CityMeta(
        name="tiny",
        timezone="Europe/Berlin",
        start="07:30",
        interval_s=1800,
        n_intervals=6,
        epoch_s=120,
        params={"rho": 0.3, "kappas": [0.0, 0.5]},
        source="test data",
    )
    save_bundle(tmp_path / "tiny", net, meta)
    stored = json.loads((tmp_path / "tiny" / "city.json").read_text(encoding="utf-8"))
    assert stored["horizon"] == {"start": "07:30", "interval_s": 1800, "n_intervals": 6, "epoch_s": 120}
    city = load_city(tmp_path / "tiny")
    assert city.name == "tiny" and city.source == "test data"
    assert city.horizon.timezone == "Europe/Berlin" and city.horizon.start.hour == 7
    assert city.horizon.n_intervals == 6 and city.horizon.epoch_s == 120
    assert city.params.rho == 0.3 and city.params.kappas == (0.0, 0.5)
    # mixed speeds survive the round trip
    np.testing.assert_allclose(city.network.edge_time_s, net.edge_time_s)
    np.testing.assert_array_equal(city.network.node_ids, net.node_ids)
    np.testing.assert_array_equal(city.network.edge_u, net.edge_u)
    # weights: uniform over touched cells, uniform over intervals
    touched = city.cell_weight > 0
    assert city.cell_weight.size == city.grid.n_cells
    assert city.cell_weight.sum() == pytest.approx(1.0)
    assert np.allclose(city.cell_weight[touched], 1.0 / touched.sum())
    assert city.interval_weight.tolist() == pytest.approx([1 / 6] * 6)


def test_bundle_uniform_speed_follows_params(tmp_path: Path) -> None:
    net = read_csv_network(*_csv(tmp_path, edges="u,v,length_m\n1,2,100\n2,3,100\n3,1,100\n")).network
    save_bundle(tmp_path / "b", net, CityMeta(name="b"))
    with np.load(tmp_path / "b" / "network.npz") as z:
        assert "edge_speed_kmh" not in z.files
    assert load_city(tmp_path / "b").network.edge_time_s.tolist() == pytest.approx([100 / (35 / 3.6)] * 3)


def test_bundle_errors(tmp_path: Path) -> None:
    net = read_csv_network(*_csv(tmp_path)).network
    save_bundle(tmp_path / "c", net, CityMeta(name="c"))
    meta_path = tmp_path / "c" / "city.json"
    obj = json.loads(meta_path.read_text(encoding="utf-8"))
    changes: list[tuple[dict[str, Any], str]] = [
        ({"timezone": "Mars/Olympus"}, "unknown timezone"),
        ({"params": {"rho": 2.0}}, "rho"),
        ({"params": {"warp": 9}}, "unknown dispatch parameter 'warp'"),
        ({"horizon": {"start": "8am"}}, "start must be HH:MM"),
        ({"horizon": {"interval_s": 7}}, "divide a day"),
        ({"name": "Not A Name"}, "invalid city name"),
        ({"colour": "red"}, "unknown key"),
    ]
    for change, problem in changes:
        meta_path.write_text(json.dumps({**obj, **change}), encoding="utf-8")
        with pytest.raises(CityDataError, match=problem) as info:
            load_city(tmp_path / "c")
        assert "city.json" in str(info.value)
    meta_path.write_text("{", encoding="utf-8")
    with pytest.raises(CityDataError, match="line 1: malformed JSON"):
        load_city(tmp_path / "c")
    with pytest.raises(CityDataError, match="city.json: cannot read"):
        load_city(tmp_path / "nowhere")
    # a bundle that is not strongly connected is refused
    save_bundle(tmp_path / "d", net, CityMeta(name="d"))
    with np.load(tmp_path / "d" / "network.npz") as z:
        arrays = {k: z[k] for k in z.files}
    keep = ~((arrays["edge_u"] == 2) & (arrays["edge_v"] == 0))
    arrays = {k: (a[keep] if k.startswith("edge_") else a) for k, a in arrays.items()}
    np.savez_compressed(tmp_path / "d" / "network.npz", **arrays)
    with pytest.raises(CityDataError, match="not strongly connected"):
        load_city(tmp_path / "d")


def test_city_names() -> None:
    for good in ("chengdu", "new-york_2", "a" * 40):
        assert validate_city_name(good) == good
    for bad in ("", "Chengdu", "a b", "a" * 41, "../x", "é"):
        with pytest.raises(ValueError):
            validate_city_name(bad)
