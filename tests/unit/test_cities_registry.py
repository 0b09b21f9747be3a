"""The city registry: bundled Chengdu and Manhattan, imports by API and CLI."""

from __future__ import annotations

import io
import json
import time
from pathlib import Path

import numpy as np
import pytest

from app.adapters.city_registry import BUNDLED_DIR, CityRegistry, import_city
from app.entrypoints.import_city import import_city_cli
from app.errors import UnknownCity
from services.city import FleetParams
from services.citydata import CityDataError, CityMeta, load_city
from services.network.network import SnapError

NODES = "id,lon,lat\n1,104.000,30.000\n2,104.001,30.000\n3,104.001,30.001\n"
EDGES = "u,v,length_m\n1,2,100\n2,3,110\n3,1,150\n"


@pytest.fixture(scope="module")
def bundled() -> CityRegistry:
    return CityRegistry()


def test_bundled_names(bundled: CityRegistry) -> None:
    assert {"chengdu", "manhattan"} <= set(bundled.names())
    assert "chengdu" in bundled and "atlantis" not in bundled and "../x" not in bundled


def test_chengdu_bundle(bundled: CityRegistry) -> None:
    t0 = time.perf_counter()
    city = load_city(BUNDLED_DIR / "chengdu")
    assert time.perf_counter() - t0 < 2.0
    net, grid = city.network, city.grid
    assert city.name == "chengdu" and city.horizon.timezone == "Asia/Shanghai"
    assert 5000 <= net.n_nodes <= 9000 and 10000 <= net.n_edges <= 15000
    assert 1000 <= net.edge_length_m.sum() / 1000 <= 1200  # km of road
    assert grid.crs == net.crs == "EPSG:32648" and grid.cell_m == 1000.0
    assert 9 <= grid.n_cols <= 11 and 9 <= grid.n_rows <= 11
    w, s, e, n = net.bbox()
    # the extract keeps whole ways, so a few nodes lie just outside its box
    assert 104.02 <= w < e <= 104.15 and 30.63 <= s < n <= 30.75
    assert city.cell_weight.sum() == pytest.approx(1.0) and city.interval_weight.sum() == pytest.approx(1.0)
    assert np.all(net.edge_length_m > 0)
    # Tianfu Square is served; a point 5 km outside the box is refused
    _, dist = net.snap(104.0657, 30.6574, city.params.snap_limit_m)
    assert dist < 200
    with pytest.raises(SnapError):
        net.snap(104.0657, 30.61, city.params.snap_limit_m)
    assert (bundled.bundle_dir("chengdu") / "chengdu_2ndring_osm_pois.csv").is_file()


def test_manhattan_bundle(bundled: CityRegistry) -> None:
    city = bundled.get("manhattan")
    assert city.horizon.timezone == "America/New_York" and city.network.crs == "EPSG:32618"
    assert city.network.n_nodes == 4197 and 7500 <= city.network.n_edges <= 7534
    assert 8 <= city.grid.n_cols <= 12 and 17 <= city.grid.n_rows <= 21
    np.testing.assert_allclose(city.network.edge_time_s, city.network.edge_length_m / (35 / 3.6))
    assert (bundled.bundle_dir("manhattan") / "nyc_20k.csv.gz").is_file()
    assert bundled.get("manhattan") is city  # loaded once


def test_attribution_present() -> None:
    text = (BUNDLED_DIR.parent / "ATTRIBUTION.md").read_text(encoding="utf-8")
    for line in (
        "© OpenStreetMap contributors, ODbL 1.0",
        "lizihan021/ETA",
        "NREL/hive",
        "BSD-3-Clause",
        "Taxi & Limousine Commission",
        "GPL-3.0",
        "TrajRF",
    ):
        assert line in text


def test_unknown_city(bundled: CityRegistry) -> None:
    with pytest.raises(UnknownCity, match="unknown city 'atlantis'") as info:
        bundled.get("atlantis")
    assert isinstance(info.value, KeyError) and info.value.status == 404
    with pytest.raises(UnknownCity):
        bundled.get("../chengdu")


def _csv(tmp_path: Path) -> tuple[Path, Path]:
    n, e = tmp_path / "nodes.csv", tmp_path / "edges.csv"
    n.write_text(NODES, encoding="utf-8")
    e.write_text(EDGES, encoding="utf-8")
    return n, e


def test_import_then_serve_by_name(tmp_path: Path) -> None:
    user = tmp_path / "cities"
    reg = CityRegistry(user_dir=user)
    assert "tiny" not in reg.names()
    path, _, _ = import_city(
        "csv", _csv(tmp_path), CityMeta("tiny", timezone="Asia/Shanghai", start="07:00"), user
    )
    assert path == user / "tiny"
    assert "tiny" in reg.names() and "chengdu" in reg.names()
    city = reg.get("tiny")
    assert city.network.n_nodes == 3 and city.horizon.start.hour == 7
    meta = json.loads((path / "city.json").read_text(encoding="utf-8"))
    assert (
        meta["built_with"]["input"] == ["nodes.csv", "edges.csv"] and len(meta["built_with"]["sha256"]) == 2
    )
    with pytest.raises(FileExistsError):
        import_city("csv", _csv(tmp_path), CityMeta("tiny"), user)
    import_city("csv", _csv(tmp_path), CityMeta("tiny", timezone="UTC"), user, overwrite=True)
    reg.forget("tiny")
    assert reg.get("tiny").horizon.timezone == "UTC"
    assert [p.name for p in user.iterdir()] == ["tiny"]  # no temporary directories left behind


def test_import_refuses_bad_name_timezone_and_data(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="invalid city name"):
        import_city("csv", _csv(tmp_path), CityMeta("Tiny City"), tmp_path / "out")
    with pytest.raises(ValueError, match="unknown timezone"):
        import_city("csv", _csv(tmp_path), CityMeta("tiny", timezone="Nowhere/Land"), tmp_path / "out")
    (tmp_path / "edges.csv").write_text("u,v,length_m\n1,2,0\n", encoding="utf-8")
    with pytest.raises(CityDataError, match=r"edges\.csv, row 1: length_m must be positive"):
        import_city(
            "csv", [tmp_path / "nodes.csv", tmp_path / "edges.csv"], CityMeta("tiny"), tmp_path / "out"
        )
    assert not (tmp_path / "out" / "tiny").exists()


def test_registry_refuses_mismatched_name(tmp_path: Path) -> None:
    import_city("csv", _csv(tmp_path), CityMeta("tiny"), tmp_path / "c")
    (tmp_path / "c" / "tiny").rename(tmp_path / "c" / "other")
    with pytest.raises(CityDataError, match="names city 'tiny', not 'other'"):
        CityRegistry(user_dir=tmp_path / "c").get("other")


def test_cli_import_csv_and_osm(tmp_path: Path) -> None:
    out, err = io.StringIO(), io.StringIO()
    n, e = _csv(tmp_path)
    code = import_city_cli(
        [
            "tiny",
            "--nodes",
            str(n),
            "--edges",
            str(e),
            "--timezone",
            "Asia/Shanghai",
            "--start",
            "08:30",
            "--out",
            str(tmp_path / "c"),
        ],
        stdout=out,
        stderr=err,
    )
    assert code == 0, err.getvalue()
    line = out.getvalue()
    assert line.count("\n") == 1 and "3 nodes, 3 edges" in line and "EPSG:32648" in line
    osm = tmp_path / "x.osm"
    osm.write_text(
        "<osm><node id='1' lat='30' lon='104'/><node id='2' lat='30' lon='104.001'/>"
        "<way id='9'><nd ref='1'/><nd ref='2'/><tag k='highway' v='residential'/></way></osm>",
        encoding="utf-8",
    )
    code = import_city_cli(["osmtown", "--osm", str(osm)], default_out=tmp_path / "c", stdout=out, stderr=err)
    assert code == 0, err.getvalue()
    assert CityRegistry(user_dir=tmp_path / "c").get("osmtown").network.n_edges == 2


def test_cli_errors(tmp_path: Path) -> None:
    n, e = _csv(tmp_path)
    e.write_text("u,v,length_m\n1,9,5\n", encoding="utf-8")
    out, err = io.StringIO(), io.StringIO()
    code = import_city_cli(
        ["tiny", "--nodes", str(n), "--edges", str(e), "--out", str(tmp_path)], stdout=out, stderr=err
    )
    assert code != 0 and "edges.csv, row 1: v names unknown node id 9" in err.getvalue()
    code = import_city_cli(
        ["tiny", "--osm", "a.osm", "--nodes", str(n), "--out", str(tmp_path)], stdout=out, stderr=err
    )
    assert code != 0 and "either --osm" in err.getvalue()
    assert import_city_cli(["tiny", "--osm", "a.osm"], stdout=out, stderr=err) != 0  # no --out
    assert import_city_cli(["BAD", "--osm", "a.osm", "--out", str(tmp_path)], stdout=out, stderr=err) != 0
    assert "invalid city name" in err.getvalue()
    assert out.getvalue() == ""


def test_cli_import_sets_dispatch_parameters(tmp_path: Path) -> None:
    """``--param NAME=JSON`` writes the city's dispatch parameters (here Step 3's reach, and none at all);
    an unknown name or a value the parameter refuses is a usage error that writes nothing."""
    n, e = _csv(tmp_path)
    out, err = io.StringIO(), io.StringIO()
    base = ["--nodes", str(n), "--edges", str(e), "--out", str(tmp_path / "c")]
    assert import_city_cli(["tiny", *base, "--param", "step3_reach_s=600"], stdout=out, stderr=err) == 0
    assert import_city_cli(["open", *base, "--param", "step3_reach_s=null"], stdout=out, stderr=err) == 0
    reg = CityRegistry(user_dir=tmp_path / "c")
    assert reg.get("tiny").params.step3_reach_s == 600.0
    assert reg.get("open").params.step3_reach_s is None
    for bad in ("no_such=1", "step3_reach_s=-5", "step3_reach_s", "step3_reach_s={"):
        assert import_city_cli(["bad", *base, "--param", bad], stdout=out, stderr=err) == 2, bad
    assert not (tmp_path / "c" / "bad").exists()


def test_cli_import_sets_fleet_sizing_parameters(tmp_path: Path) -> None:
    """``--fleet NAME=JSON`` writes the city's fleet-sizing parameters into its city.json; the ones not set
    stay null (derived from the fleet posted, or the worker's settings). A bad value writes nothing, and a
    demo city's synthetic history needs a demand generator in the bundle."""
    n, e = _csv(tmp_path)
    out, err = io.StringIO(), io.StringIO()
    base = ["--nodes", str(n), "--edges", str(e), "--out", str(tmp_path / "c")]
    fleet = ["--fleet", "sizes=[300, 100, 200]", "--fleet", "n0=450", "--fleet", "completion_target=0.9"]
    assert import_city_cli(["own", *base, *fleet], stdout=out, stderr=err) == 0, err.getvalue()
    assert import_city_cli(["bare", *base], stdout=out, stderr=err) == 0
    reg = CityRegistry(user_dir=tmp_path / "c")
    assert reg.get("own").fleet == FleetParams(sizes=(300, 100, 200), n0=450, completion_target=0.9)
    assert json.loads((tmp_path / "c" / "own" / "city.json").read_text())["fleet"] == {
        "sizes": [300, 100, 200],
        "n0": 450,
        "completion_target": 0.9,
    }
    assert reg.get("bare").fleet == FleetParams()
    assert "fleet" not in json.loads((tmp_path / "c" / "bare" / "city.json").read_text())
    for bad in ("sizes=[10, 10]", "sizes=[0]", "n0=-1", "days=1", "completion_target=2", "budget=3", "n0"):
        err = io.StringIO()
        assert import_city_cli(["bad", *base, "--fleet", bad], stdout=out, stderr=err) == 2, bad
        assert "fleet" in err.getvalue(), bad
    assert import_city_cli(["bad", *base, "--fleet", "synthetic_history=true"], stdout=out, stderr=err) == 1
    assert not (tmp_path / "c" / "bad").exists()


def test_the_bundled_cities_are_demo_cities_sized_on_synthetic_history(bundled: CityRegistry) -> None:
    for name in ("chengdu", "manhattan"):
        assert bundled.get(name).fleet == FleetParams(synthetic_history=True)
