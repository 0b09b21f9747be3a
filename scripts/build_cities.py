"""Build the bundled cities in ``app/data/cities`` from the shared reference data.

Usage::

    python scripts/build_cities.py [SHARED_DATA_DIR]      # default: ../shared/data relative to the repo

This is the only code that reads the shared data folder; the service itself runs from the bundles.
"""

from __future__ import annotations

import argparse
import gzip
import shutil
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from services.citydata import CityMeta, load_city, save_bundle, sha256_of  # noqa: E402
from services.importers import ImportResult, read_node_link, read_osm  # noqa: E402

OUT = REPO / "app" / "data" / "cities"
OSM_ODBL = "© OpenStreetMap contributors, ODbL 1.0"

ATTRIBUTION = """\
# Attribution of the bundled data

The city bundles under `cities/` are derived from openly licensed data. Keep these lines with any copy.

## cities/chengdu — central Chengdu ("2nd ring"), the default city

- `network.npz` — drivable road network built by `scripts/build_cities.py` from `chengdu_2ndring.osm`,
  a raw OpenStreetMap XML extract (lon 104.0421–104.1296, lat 30.6528–30.7279; snapshot older than July 2018).
  © OpenStreetMap contributors, ODbL 1.0. Originally published in the public GitHub repository
  lizihan021/ETA (step1/osm2pgrouting/chengdu.osm).
- `chengdu_2ndring_osm_pois.csv` — 774 OSM nodes inside that box tagged
  amenity/shop/tourism/leisure/public_transport/railway/office/healthcare.
  © OpenStreetMap contributors, ODbL 1.0 (derived from the file above).
- `chengdu_aq_stations.csv` — the 16 national air-quality monitoring stations of Chengdu. Public station list
  of the China National Environmental Monitoring Centre, as republished in the GPL-3.0 GitHub repository
  liujun2024/TrajRF (NewSiteList.csv).

## cities/manhattan — Manhattan, the second city

- `network.npz` — built by `scripts/build_cities.py` from `manhattan_network.json`, a networkx node-link
  JSON of Manhattan's drivable OSM network built with OSMnx.
  © OpenStreetMap contributors, ODbL 1.0; file from the BSD-3-Clause repository NREL/hive
  (nrel/hive/resources/scenarios/manhattan/road_network/).
- `nyc_20k.csv.gz` — 19,979 real NYC yellow-taxi requests of Sunday 2014-12-21 in Manhattan (gzip of
  `nyc_20k.csv`). Derived from the NYC Taxi & Limousine Commission public trip records (NYC Open Data);
  file from NREL/hive (BSD-3-Clause), nrel/hive/resources/scenarios/manhattan/requests/.
"""


def _write(name: str, result: ImportResult, meta: CityMeta) -> None:
    target = OUT / name
    if target.exists():
        shutil.rmtree(target)
    save_bundle(target, result.network, meta)


def _report(name: str, result: ImportResult) -> None:
    t0 = time.perf_counter()
    city = load_city(OUT / name)
    dt_s = time.perf_counter() - t0
    g = city.grid
    touched = int((city.cell_weight > 0).sum())
    print(
        f"{name}: {result.summary()}\n"
        f"  read {result.nodes_read} nodes / {result.edges_read} edges; grid {g.n_cols} x {g.n_rows} cells "
        f"of {g.cell_m:.0f} m in {g.crs}, {touched} touched; bundle loads in {dt_s:.2f} s"
    )


def build(shared: Path) -> None:
    """Build both bundles and the attribution file from the shared data directory."""
    OUT.mkdir(parents=True, exist_ok=True)

    osm = shared / "chengdu" / "chengdu_2ndring.osm"
    chengdu = read_osm(osm)
    _write(
        "chengdu",
        chengdu,
        CityMeta(
            name="chengdu",
            timezone="Asia/Shanghai",
            start="08:00",
            source=f"{OSM_ODBL} (extract originally from lizihan021/ETA); see app/data/ATTRIBUTION.md",
            built_with={"script": "scripts/build_cities.py", "input": osm.name, "sha256": sha256_of(osm)},
            files={"pois": "chengdu_2ndring_osm_pois.csv", "aq_stations": "chengdu_aq_stations.csv"},
            fleet={"synthetic_history": True},
        ),
    )
    for extra in ("chengdu_2ndring_osm_pois.csv", "chengdu_aq_stations.csv"):
        shutil.copyfile(shared / "chengdu" / extra, OUT / "chengdu" / extra)
    _report("chengdu", chengdu)

    nl = shared / "manhattan" / "manhattan_network.json"
    manhattan = read_node_link(nl)
    _write(
        "manhattan",
        manhattan,
        CityMeta(
            name="manhattan",
            timezone="America/New_York",
            start="08:00",
            source=f"{OSM_ODBL}; network file from NREL/hive (BSD-3-Clause); see app/data/ATTRIBUTION.md",
            built_with={"script": "scripts/build_cities.py", "input": nl.name, "sha256": sha256_of(nl)},
            files={"requests": "nyc_20k.csv.gz"},
            fleet={"synthetic_history": True},
        ),
    )
    src = shared / "manhattan" / "nyc_20k.csv"
    # mtime=0 keeps the gzip bytes reproducible
    with (
        src.open("rb") as fin,
        (OUT / "manhattan" / "nyc_20k.csv.gz").open("wb") as raw,
        gzip.GzipFile(filename="nyc_20k.csv", mode="wb", fileobj=raw, compresslevel=9, mtime=0) as fout,
    ):
        shutil.copyfileobj(fin, fout)
    _report("manhattan", manhattan)

    (OUT.parent / "ATTRIBUTION.md").write_text(ATTRIBUTION, encoding="utf-8")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    parser.add_argument("shared", nargs="?", type=Path, default=REPO.parent / "shared" / "data")
    args = parser.parse_args(argv)
    if not (args.shared / "chengdu").is_dir() or not (args.shared / "manhattan").is_dir():
        print(f"build_cities: {args.shared} has no chengdu/ and manhattan/ folders", file=sys.stderr)
        return 2
    build(args.shared)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
