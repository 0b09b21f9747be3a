"""The contraction hierarchy's fastest paths (``services.network.hierarchy``) are the canonical ones.

Checked against the plain lexicographic Dijkstra of ``tests/reference.py`` (every ordered pair of the small
networks: the same path, or the same failure to join) and against the service's own search
(``point_to_point.landmark_fastest_paths``) on the bundled city and on the largest network of the suite, the
generated metropolis, where every trip of a heavy epoch is compared.
"""

from __future__ import annotations

from functools import cache
from pathlib import Path

import numpy as np
import pytest

from bench import metro
from services.citydata import load_city
from services.network import heaps, hierarchy, point_to_point, shortcuts
from services.network.graph import INF, RoadGraph, road_graph
from services.network.scratch import Scratch
from tests.citymaker import grid_city, make_city
from tests.reference import canonical_tree, tree_path

BUNDLES = Path(__file__).resolve().parents[2] / "app" / "data" / "cities"


def _one_way_city():
    """A 4 x 3 lattice with a one-way side, pairs of equal-time routes everywhere (ties broken by the tie
    words alone), a one-way loop and an island no path enters or leaves."""
    nodes = {i: (100.0 * (i % 4), 100.0 * (i // 4)) for i in range(12)}
    nodes |= {20: (1000.0, 0.0), 21: (1100.0, 0.0), 22: (1100.0, 100.0)}
    one_way = [(3, 7), (7, 11), (11, 10), (20, 21), (21, 22), (22, 20)]
    two_way = [(i, i + 1) for i in range(12) if i % 4 != 3] + [(i, i + 4) for i in range(8)]
    two_way = [e for e in two_way if e not in {(3, 7), (7, 11), (10, 11)}]
    return make_city(nodes, [*two_way, *[(v, u) for u, v in two_way], *one_way], both_ways=False)


def _paths(graph: RoadGraph, src: np.ndarray, dst: np.ndarray) -> list[np.ndarray]:
    return hierarchy.fastest_paths(graph, Scratch(graph), src, dst)


@pytest.mark.parametrize(
    ("make", "some_unreachable"), [(_one_way_city, True), (lambda: grid_city(4, 100.0), False)]
)
def test_every_pair_gets_the_reference_path_or_none(make, some_unreachable):
    """Every ordered pair of a small network: the hierarchy's path is the reference's canonical path (a
    lattice of equal blocks has many routes of the same time: the tie words decide), and where none
    exists the query says so."""
    graph = road_graph(make())
    h = shortcuts.build(
        graph.n_nodes,
        graph.edges.tail,
        graph.edges.head,
        graph.edges.time_us,
        graph.edges.tie1,
        graph.edges.tie2,
    )
    assert h is not None
    ln = hierarchy.lanes(graph.n_nodes)
    joined = failed = 0
    for a in range(graph.n_nodes):
        label, pred = canonical_tree(graph, graph.edges.time_us, a)
        for b in range(graph.n_nodes):
            ptr, flat = hierarchy.ch_paths(h, ln, np.array([a]), np.array([b]))
            if label[b] is None:
                assert ptr[1] == -1, (a, b)
                failed += 1
                continue
            assert flat.tolist() == tree_path(graph, pred, a, b), (a, b)
            joined += 1
    assert joined and (failed > 0) == some_unreachable


def test_a_network_that_would_need_too_many_shortcuts_keeps_the_plain_search():
    """Manhattan's street grid would take more than ``ARCS_PER_EDGE`` arcs per edge: it gets no hierarchy,
    and ``fastest_paths`` gives the plain search's paths there."""
    graph = road_graph(load_city(BUNDLES / "manhattan"))
    assert hierarchy.hierarchy(graph) is None
    rng = np.random.default_rng(5)
    src, dst = rng.integers(graph.n_nodes, size=30), rng.integers(graph.n_nodes, size=30)
    want = point_to_point.landmark_fastest_paths(graph, heaps.workspace(graph), src, dst)
    assert [p.tolist() for p in _paths(graph, src, dst)] == [p.tolist() for p in want]


def test_chengdu_paths_are_the_searched_ones_interior_ends_included():
    """The bundled Chengdu network gets a hierarchy (about two arcs per edge); 400 pairs, a quarter of them
    starting and a quarter ending inside degree-2 chains, give the plain search's paths; the hierarchy
    is built once per graph."""
    graph = road_graph(load_city(BUNDLES / "chengdu"))
    h = hierarchy.hierarchy(graph)
    assert h is not None and hierarchy.hierarchy(graph) is h
    assert h.arc_tail.shape[0] <= shortcuts.ARCS_PER_EDGE * graph.n_edges
    rng = np.random.default_rng(11)
    interior = np.flatnonzero(graph.forward.kept_of < 0)
    src, dst = rng.integers(graph.n_nodes, size=400), rng.integers(graph.n_nodes, size=400)
    src[:100] = rng.choice(interior, 100)
    dst[100:200] = rng.choice(interior, 100)
    src[300:310] = dst[300:310]  # the empty path
    want = point_to_point.landmark_fastest_paths(graph, heaps.workspace(graph), src, dst)
    got = _paths(graph, src, dst)
    assert [p.tolist() for p in got] == [p.tolist() for p in want]


def test_an_unreachable_target_is_an_error():
    graph = road_graph(_one_way_city())
    with pytest.raises(ValueError, match="cannot be reached"):
        _paths(graph, np.array([0]), np.array([13]))


@cache
def _metro_graph() -> RoadGraph:
    return road_graph(metro.metro_city())


@pytest.mark.slow
def test_every_trip_on_the_metropolis_is_the_searched_path():
    """The largest network of the suite (the generated metropolis, 260,000 nodes): 800 trips between
    nodes spread over the whole network -- a heavy epoch's riders' trips and pickups -- each the path of
    the service's own search, edge for edge, and the same travel time to the microsecond."""
    graph = _metro_graph()
    h = hierarchy.hierarchy(graph)
    assert h is not None
    rng = np.random.default_rng(20261127)
    src, dst = rng.integers(graph.n_nodes, size=800), rng.integers(graph.n_nodes, size=800)
    want = point_to_point.landmark_fastest_paths(graph, heaps.workspace(graph), src, dst)
    got = _paths(graph, src, dst)
    for a, b in zip(got, want, strict=True):
        assert a.tolist() == b.tolist()
    cost = [int(graph.edges.time_us[p].sum()) for p in got]
    assert max(cost) < INF and min(cost) >= 0


# ---------------------------------------------------------------- kept on disk


def test_a_stored_hierarchy_is_read_back_as_built(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    graph = road_graph(grid_city(9, 100.0))
    built = hierarchy.stored_or_built(graph, root=tmp_path)
    assert built is not None and len(list(tmp_path.glob("hierarchy-*.npz"))) == 1

    def no_build(*_: object) -> None:
        raise AssertionError("built again")

    monkeypatch.setattr(hierarchy, "build", no_build)
    again = hierarchy.stored_or_built(graph, root=tmp_path)
    assert again is not None
    for name in shortcuts.Hierarchy._fields:
        a, b = getattr(built, name), getattr(again, name)
        assert a.dtype == b.dtype and np.array_equal(a, b), name
    # the same streets with other travel times: another key, so built (and the stub says so)
    with pytest.raises(AssertionError, match="built again"):
        hierarchy.stored_or_built(road_graph(grid_city(9, 120.0)), root=tmp_path)


def test_a_network_without_a_hierarchy_is_stored_so(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A network that gets no hierarchy (``build`` says None) is stored as such and read back as None
    without building again."""
    graph = road_graph(grid_city(6, 100.0))
    monkeypatch.setattr(hierarchy, "build", lambda *_: None)
    assert hierarchy.stored_or_built(graph, root=tmp_path) is None
    assert len(list(tmp_path.glob("hierarchy-*.npz"))) == 1

    def no_build(*_: object) -> None:
        raise AssertionError("built again")

    monkeypatch.setattr(hierarchy, "build", no_build)
    assert hierarchy.stored_or_built(graph, root=tmp_path) is None


@pytest.mark.parametrize("damage", ["truncated", "wrong arrays", "wrong dtype"])
def test_a_damaged_stored_hierarchy_is_built_again(tmp_path: Path, damage: str) -> None:
    graph = road_graph(grid_city(7, 100.0))
    built = hierarchy.stored_or_built(graph, root=tmp_path)
    assert built is not None
    (path,) = tmp_path.glob("hierarchy-*.npz")
    if damage == "truncated":
        path.write_bytes(path.read_bytes()[:100])
    elif damage == "wrong arrays":
        np.savez(path, rank=built.rank)
    else:
        np.savez(path, **{k: v.astype(np.int64) for k, v in built._asdict().items()})
    again = hierarchy.stored_or_built(graph, root=tmp_path)
    assert again is not None and np.array_equal(again.arc_edge, built.arc_edge)
    assert again.rank.dtype == np.int32


def test_nowhere_to_store_builds_every_time(tmp_path: Path) -> None:
    graph = road_graph(grid_city(5, 100.0))
    blocked = tmp_path / "a-file"
    blocked.write_text("not a directory")
    h = hierarchy.stored_or_built(graph, root=blocked)
    assert h is not None and h.rank.shape == (graph.n_nodes,)


def test_a_new_graph_of_the_same_network_reads_the_stored_landmarks(monkeypatch: pytest.MonkeyPatch) -> None:
    city = grid_city(8, 100.0)
    first = point_to_point.landmarks(road_graph(city))
    from services.network.graph import build_road_graph

    def no_table(*_: object) -> None:
        raise AssertionError("built again")

    monkeypatch.setattr(point_to_point, "_landmark_table", no_table)
    again = point_to_point.landmarks(build_road_graph(city))  # a new graph object: not in memory
    assert np.array_equal(first, again)


def test_a_landmark_table_under_another_metric_is_read_back(monkeypatch: pytest.MonkeyPatch) -> None:
    graph = road_graph(grid_city(6, 100.0))
    at = point_to_point.landmark_nodes(graph)
    metric = graph.edges.time_us // 2 + 1
    from services.network.graph import prepare

    fwd, rev = prepare(graph.forward, metric), prepare(graph.reverse, metric)
    first = point_to_point.landmark_table(graph, at, fwd, rev, 1)

    def no_search(*_: object) -> None:
        raise AssertionError("searched again")

    monkeypatch.setattr(point_to_point, "_costs_to_or_from", no_search)
    assert np.array_equal(point_to_point.landmark_table(graph, at, fwd, rev, 1), first)
    with pytest.raises(AssertionError, match="searched again"):  # another metric: another key
        point_to_point.landmark_table(graph, at, prepare(graph.forward, metric + 1), rev, 1)
