"""The idle drift's map against a dense reference: one whole-network reverse tree per hub from scipy, held
as (hubs x nodes) arrays, as docs/SIMULATOR.md defines the drift. On the bundled cities every hub, every
kept tree entry, every draw and every walk must be the same, and so must whole simulated runs."""

from __future__ import annotations

import dataclasses
from functools import cache

import numpy as np
import pytest
import scipy.sparse.csgraph as cg
from numpy.typing import NDArray

from app.adapters.city_registry import CityRegistry
from app.runs import RunSpec, open_bundle
from app.runs.workload import demand_for, tasks_for
from services.city import City, Horizon
from services.sim.drift import DriftMap, drift_map
from services.sim.engine import RunTrace, SimConfig, simulate
from services.sim.local import LocalDispatcher
from tests.citymaker import make_city

RADIUS_M = 3000.0


class DenseDrift:
    """The reference: every cell's hub and a full reverse shortest-path tree per hub (scipy's
    ``dijkstra`` with predecessors), ``toward[h, u]`` the node after ``u`` toward hub ``h`` and
    ``time_to[h, u]`` its time."""

    def __init__(self, city: City, radius_m: float) -> None:
        net, grid = city.network, city.grid
        self.radius_m = radius_m
        col = np.floor((net.x_m - grid.origin_x_m) / grid.cell_m).astype(np.int64)
        row = np.floor((net.y_m - grid.origin_y_m) / grid.cell_m).astype(np.int64)
        self.node_cell: NDArray[np.int64] = row * grid.n_cols + col
        self.cells = np.unique(self.node_cell)
        self.hubs: NDArray[np.int64] = np.empty(self.cells.size, dtype=np.int64)
        self.center_x_m = np.empty(self.cells.size)
        self.center_y_m = np.empty(self.cells.size)
        for i, c in enumerate(self.cells):
            members = np.flatnonzero(self.node_cell == c)
            self.center_x_m[i] = grid.origin_x_m + (c % grid.n_cols + 0.5) * grid.cell_m
            self.center_y_m[i] = grid.origin_y_m + (c // grid.n_cols + 0.5) * grid.cell_m
            d2 = (net.x_m[members] - self.center_x_m[i]) ** 2 + (net.y_m[members] - self.center_y_m[i]) ** 2
            self.hubs[i] = members[int(np.argmin(d2))]
        reverse = net.csr(net.edge_time_s).T.tocsr()
        self.time_to, pred = cg.dijkstra(reverse, directed=True, indices=self.hubs, return_predecessors=True)
        self.toward = pred.astype(np.int64)
        self.toward[self.toward < 0] = -1
        self.hub_of_cell = {int(c): i for i, c in enumerate(self.cells)}

    def choose_target(self, node: int, density: NDArray[np.float64], rng: np.random.Generator) -> int:
        here = self.hub_of_cell[int(self.node_cell[node])]
        d2 = (self.center_x_m - self.center_x_m[here]) ** 2 + (self.center_y_m - self.center_y_m[here]) ** 2
        near = np.flatnonzero(d2 <= self.radius_m**2)
        w = density[self.cells[near]]
        total = float(w.sum())
        if total <= 0.0:
            return -1
        pick = int(near[int(np.searchsorted(np.cumsum(w), rng.random() * total, side="right"))])
        if not np.isfinite(self.time_to[pick, node]):
            return -1
        return pick

    def walk(self, hub_row: int, node: int, budget_s: float) -> tuple[int, float]:
        toward, time_to = self.toward[hub_row], self.time_to[hub_row]
        used = 0.0
        while True:
            nxt = int(toward[node])
            if nxt < 0:
                return node, used
            step = float(time_to[node] - time_to[nxt])
            if used + step > budget_s:
                return node, used
            used += step
            node = nxt


@cache
def bundled(name: str) -> City:
    return open_bundle(CityRegistry().bundle_dir(name)).city


@cache
def dense(name: str) -> DenseDrift:
    return DenseDrift(bundled(name), RADIUS_M)


def region(dm: DriftMap, row: int) -> NDArray[np.int64]:
    """The nodes of the cells within the radius of hub ``row``'s cell: the taxis that can draw it."""
    return np.flatnonzero(np.isin(dm.node_cell, dm.cells[dm.near(row)]))


@pytest.mark.parametrize("name", ["chengdu", "manhattan"])
def test_hubs_and_centres_are_the_dense_references(name: str) -> None:
    dm, ref = DriftMap(bundled(name), RADIUS_M), dense(name)
    assert np.array_equal(dm.cells, ref.cells)
    assert np.array_equal(dm.hubs, ref.hubs)
    assert np.array_equal(dm.center_x_m, ref.center_x_m) and np.array_equal(dm.center_y_m, ref.center_y_m)
    assert np.array_equal(dm.node_cell, ref.node_cell)


@pytest.mark.parametrize("name", ["chengdu", "manhattan"])
def test_every_kept_tree_entry_is_scipys_on_every_hub(name: str) -> None:
    """Each hub's tree holds every node that can draw the hub, with scipy's next node and its exact time."""
    dm, ref = DriftMap(bundled(name), RADIUS_M), dense(name)
    for row in range(dm.cells.size):
        tree = dm.tree(row)
        assert np.isin(region(dm, row), tree.nodes).all()
        nxt = np.where(tree.next_pos < 0, -1, tree.nodes[tree.next_pos])
        assert np.array_equal(nxt, ref.toward[row, tree.nodes]), row
        assert np.array_equal(tree.time_to, ref.time_to[row, tree.nodes]), row
    assert dm.stats().grown == dm.cells.size


@pytest.mark.parametrize("name", ["chengdu", "manhattan"])
def test_draws_and_walks_are_the_dense_references(name: str) -> None:
    city, ref = bundled(name), dense(name)
    dm = DriftMap(city, RADIUS_M)
    rng = np.random.default_rng(11)
    n_cells = int(ref.node_cell.max()) + 1
    for trial in range(400):
        density = np.zeros(n_cells)
        hot = rng.choice(ref.cells, size=int(rng.integers(1, 12)))
        density[hot] = rng.integers(1, 9, size=hot.size).astype(float)
        node = int(rng.integers(city.network.n_nodes))
        a, b = np.random.default_rng(trial), np.random.default_rng(trial)
        pick = dm.choose_target(node, density, a)
        assert pick == ref.choose_target(node, density, b)
        assert a.random() == b.random()  # the same draws consumed
        if pick < 0:
            continue
        for budget in (0.0, 35.0, 200.0, 1e9):
            assert dm.walk(pick, node, budget) == ref.walk(pick, node, budget)


def trace_facts(trace: RunTrace) -> tuple[object, ...]:
    """Everything a run produced but the solve times."""
    epochs = tuple(dataclasses.replace(e, solve_ms=0.0) for e in trace.epochs)
    counts = tuple((k, v.tolist()) for k, v in sorted(trace.counts.items()))
    return (trace.riders, trace.tasks, trace.assignments, counts, epochs, trace.n_unposted)


@pytest.mark.slow
@pytest.mark.parametrize(
    ("name", "n1", "n0", "rate"), [("chengdu", 60, 60, None), ("manhattan", 40, 120, 300.0)]
)
def test_whole_runs_are_those_of_the_dense_reference(name: str, n1: int, n0: int, rate: float | None) -> None:
    bundle = open_bundle(CityRegistry().bundle_dir(name))
    spec = RunSpec(name, 1, n1, n0, seed=3, day=1, n_tasks=20, rate_per_hour=rate)
    demand = demand_for(spec, bundle)
    tasks = tasks_for(spec, bundle, demand.date)
    config = SimConfig(n1, n0, len(tasks), seed=spec.seed)
    city = bundle.city
    ours = simulate(city, demand, tasks, config, LocalDispatcher(city))
    theirs = simulate(city, demand, tasks, config, LocalDispatcher(city), drift=dense(name))
    assert trace_facts(ours) == trace_facts(theirs)
    assert drift_map(city, RADIUS_M).stats().grown > 0  # the run drew hubs: the drift was exercised


def grid_city(n: int, spacing_m: float) -> City:
    """An n x n two-way street grid, ``spacing_m`` apart (36 km/h: 100 m take 10 s)."""
    nodes = {r * n + c: (c * spacing_m, r * spacing_m) for r in range(n) for c in range(n)}
    edges = [(r * n + c, r * n + c + 1) for r in range(n) for c in range(n - 1)]
    edges += [(r * n + c, (r + 1) * n + c) for r in range(n - 1) for c in range(n)]
    return make_city(nodes, edges, horizon=Horizon(timezone="UTC"))


def test_a_tree_keeps_the_region_that_can_draw_its_hub_and_its_paths() -> None:
    """A line of 100 nodes 100 m apart (10 km): with a 1.5 km radius cell 0's hub is drawn only from
    cells 0 and 1 (x < 2 km), so its search stops once those 20 nodes are settled and keeps them alone."""
    city = make_city(
        {i: (i * 100.0, 0.0) for i in range(100)},
        [(i, i + 1) for i in range(99)],
        horizon=Horizon(timezone="UTC"),
    )
    dm = DriftMap(city, 1500.0)
    row = dm.hub_of_cell[0]
    assert int(dm.hubs[row]) == 5  # x = 500 m, the centre of cell 0
    tree = dm.tree(row)
    assert tree.nodes.tolist() == list(range(20))
    assert tree.time_to.tolist() == pytest.approx([10.0 * abs(i - 5) for i in range(20)])
    assert dm.stats().settled == 20
    assert dm.walk(row, 19, 45.0) == (15, pytest.approx(40.0))  # 4 edges of 10 s fit in 45 s
    assert dm.walk(row, 50, 1e9) == (50, 0.0)  # a node outside the region: never drawn, never moved


def test_equal_times_keep_the_first_settled_predecessor() -> None:
    """A 3 x 3 grid, 100 m edges (10 s), one cell whose centre (500, 500) is nearest the corner node 8, the
    hub. Nodes settle in order of (time, index) and keep the first node that reached them: 5 and 7 at 10 s
    (5 first), so 4 (20 s) and 2 go through 5 and 6 through 7; then 2 before 4 at 20 s, so 1 (30 s) goes
    through 2 and 3 through 4; 0 (40 s) through 1, settled before 3."""
    city = grid_city(3, 100.0)
    dm = DriftMap(city, 3000.0)
    assert dm.hubs.tolist() == [8]
    tree = dm.tree(0)
    nxt = np.where(tree.next_pos < 0, -1, tree.nodes[tree.next_pos])
    assert tree.nodes.tolist() == list(range(9))
    assert nxt.tolist() == [1, 2, 5, 4, 5, 8, 7, 8, -1]
    assert tree.time_to.tolist() == pytest.approx([40, 30, 20, 30, 20, 10, 20, 10, 0])
    assert dm.walk(0, 0, 25.0) == (2, pytest.approx(20.0))


def test_a_bounded_cache_regrows_the_same_trees() -> None:
    city = bundled("manhattan")
    roomy, tight = DriftMap(city, RADIUS_M), DriftMap(city, RADIUS_M, cache_bytes=0)
    rng = np.random.default_rng(5)
    density = np.ones(int(roomy.node_cell.max()) + 1)
    for _ in range(60):
        node = int(rng.integers(city.network.n_nodes))
        seed = int(rng.integers(2**31))
        pick = roomy.choose_target(node, density, np.random.default_rng(seed))
        assert pick == tight.choose_target(node, density, np.random.default_rng(seed)) >= 0
        assert roomy.walk(pick, node, 150.0) == tight.walk(pick, node, 150.0)
    assert tight.stats().held == 1 and tight.stats().evicted > 0
    assert tight.stats().grown > roomy.stats().grown
