"""Algorithm 2: several vacant instrumented taxis' routes improved together (docs/METHOD.md section 5).

Start from the Step 3 routes, each planned against the counts of the epoch. Then, for each taxi in turn,
re-plan its route (Algorithm 1, same POI) against the counts plus the other taxis' planned visits, and
keep the new route only if the joint utility of all planned routes rises; stop after a pass that changes
nothing or after ``max_iter`` passes. The joint utility after each accepted re-plan is returned, so it is
non-decreasing by construction (the tests check it against a recomputation).
"""

from __future__ import annotations

import dataclasses
import functools
from collections import Counter
from collections.abc import Iterable, Mapping, Sequence
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from services.epoch import Epoch
from services.kernel.parallel import parallel_map
from services.model import IntervalKey, TaxiId
from services.routing.algorithm1 import Drive, Route, evaluate, plan_one
from services.sensing.gains import Counted, gain_table, timed_pairs
from services.sensing.sensing import theta_gain

if TYPE_CHECKING:
    from services.city import City

__all__ = ["improve_routes", "route_pairs", "joint_utility", "pair_counts"]


def improve_routes(
    epoch: Epoch,
    taxi_ids: Sequence[TaxiId],
    counted: Counted,
    routes: list[Route],
    fastest: Sequence[NDArray[np.int64]],
    n_slots: int,
) -> tuple[list[Route], list[float], int]:
    """Algorithm 2 over ``routes`` (route ``i`` is taxi ``taxi_ids[i]``'s, row ``i`` of ``counted``;
    ``fastest[i]`` its fastest path to the same POI), every route departing at ``epoch.now`` on gain tables
    of ``n_slots`` intervals from ``epoch.k0``. Returns the routes, the joint utility after the initial
    matching and after each accepted re-plan, and the number of passes.

    The others' planned visits enter each re-plan's gain table as a dense count per (slot, cell), kept up
    to date as routes are replaced (counts are whole numbers, so Lambda + n is the same float either way).
    Re-plans are independent until one is accepted: a batch of the next ones is planned at once (on
    ``workers`` threads) and taken in order; after an acceptance the rest of the batch is planned again
    against the new counts, so the outcome is that of one re-plan after the other.
    """
    city, graph, counts, pool = epoch.city, epoch.graph, epoch.counts, epoch.pool
    depart_s, k0 = epoch.now, epoch.k0
    kappas = city.params.kappas
    visited = [counts.visited.get(t, frozenset()) for t in taxi_ids]
    pairs = [route_pairs(city, r.edges, v, depart_s) for r, v in zip(routes, visited, strict=True)]
    total = pair_counts(pairs)
    slots_cells = functools.partial(_slots_cells, k0=k0, n_slots=n_slots)
    dense = [slots_cells(ps) for ps in pairs]
    total_n = _dense_total(dense, n_slots, city.grid.n_cells)
    history = [joint_utility(city, counts.counts, total)]
    # no route of a taxi costs more under any kappa metric than its fastest path's travel time
    limits = [int(graph.edges.time_us[f].sum()) for f in fastest]

    def replan(total_n: NDArray[np.int64], todo: Sequence[int]) -> list[tuple[Route, NDArray[np.int64]]]:
        out = []
        with pool.take() as scratch:
            for i in todo:
                r = routes[i]
                others_n = total_n.copy()
                others_n[dense[i]] -= 1
                gn = gain_table(city, counts.counts, k0, n_slots, depart_s, extra_counts=others_n)
                drive = Drive(i, r.source, r.target, limits[i])
                cand = plan_one(graph, gn, counted, drive, fastest[i], kappas, depart_s, scratch)
                out.append((cand, others_n))
        return out

    batch = 1 if epoch.workers <= 1 else 4 * epoch.workers
    passes, accepted = 0, 0  # accepted: routes replaced so far (a taxi re-planned since would repeat itself)
    planned_at = [-1] * len(routes)
    accepted_by = [False] * len(routes)  # the route is a re-plan's
    for _ in range(city.params.max_iter):
        passes += 1
        changed = False
        i = 0
        while i < len(routes):
            todo, i = _next_batch(planned_at, accepted, i, batch)
            results = parallel_map(functools.partial(replan, total_n), todo, epoch.workers)
            for a, (cand, others_n) in zip(todo, results, strict=True):
                planned_at[a] = accepted
                if np.array_equal(cand.edges, routes[a].edges):
                    continue
                cand_pairs = route_pairs(city, cand.edges, visited[a], depart_s)
                trial = _swapped(total, pairs[a], cand_pairs)
                u_new = joint_utility(city, counts.counts, trial)
                if u_new > history[-1] * (1 + 1e-12) + 1e-300:
                    routes[a] = cand
                    accepted_by[a] = True
                    pairs[a] = cand_pairs
                    total = trial
                    dense[a] = slots_cells(cand_pairs)
                    total_n = others_n
                    total_n[dense[a]] += 1
                    history.append(u_new)
                    accepted += 1
                    planned_at[a] = accepted
                    changed = True
                    i = a + 1  # the rest of the batch saw the old counts
                    break
        if not changed:
            break
    return _own_gains(epoch, counted, routes, accepted_by, n_slots), history, passes


def _dense_total(
    dense: Sequence[tuple[NDArray[np.int64], NDArray[np.int64]]], n_slots: int, n_cells: int
) -> NDArray[np.int64]:
    """The routes' planned visits as a dense count per (slot, cell), from each route's (slot, cell) pairs."""
    total_n = np.zeros((n_slots, n_cells), dtype=np.int64)
    for rows, cells in dense:
        total_n[rows, cells] += 1  # a route's pairs are distinct
    return total_n


def _swapped(
    total: Counter[tuple[int, int]], old: set[tuple[int, int]], new: set[tuple[int, int]]
) -> Counter[tuple[int, int]]:
    """``total`` (a copy) with one route's pairs ``old`` replaced by ``new``."""
    trial = total.copy()
    trial.subtract(old)
    trial.update(new)
    return trial


def _next_batch(planned_at: Sequence[int], accepted: int, start: int, batch: int) -> tuple[list[int], int]:
    """Up to ``batch`` routes from ``start`` on not re-planned since the last acceptance, and where to go
    on."""
    todo: list[int] = []
    j = start
    while j < len(planned_at) and len(todo) < batch:
        if planned_at[j] != accepted:
            todo.append(j)
        j += 1
    return todo, j


def _slots_cells(
    ps: set[tuple[int, int]], k0: int, n_slots: int
) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """The (slot, cell) pairs of ``ps`` (interval, cell) within the ``n_slots`` tabulated from ``k0``."""
    rows = np.array([k - k0 for k, _ in ps], dtype=np.int64)
    cells = np.array([c for _, c in ps], dtype=np.int64)
    keep = (rows >= 0) & (rows < n_slots)
    return rows[keep], cells[keep]


def _own_gains(
    epoch: Epoch, counted: Counted, routes: list[Route], replanned: Sequence[bool], n_slots: int
) -> list[Route]:
    """The routes with a re-planned route's gain taken against the epoch's counts, as every Step 3 route's
    is (a re-plan evaluates its candidates against the counts plus the other routes' visits)."""
    out = list(routes)
    with epoch.pool.take() as scratch:
        for i, r in enumerate(routes):
            if not replanned[i]:
                continue
            gn = gain_table(
                epoch.city, epoch.counts.counts, epoch.k0, max(n_slots, r.max_slot + 1), epoch.now
            )
            g, _t, _l, _ms = evaluate(epoch.graph, gn, counted, i, r.edges, epoch.now, scratch)
            out[i] = dataclasses.replace(r, gain=g)
    return out


def route_pairs(
    city: City, edges: NDArray[np.int64], visited: frozenset[tuple[IntervalKey, int]] | None, depart_s: float
) -> set[tuple[int, int]]:
    """The (interval, cell) pairs a path would add to Lambda (first visits the taxi is not counted in)."""
    seen = visited or frozenset()
    return {p for p in timed_pairs(city, edges, depart_s) if p not in seen}


def joint_utility(
    city: City, counts: Mapping[IntervalKey, NDArray[np.int64]], taxis_per_pair: Mapping[tuple[int, int], int]
) -> float:
    """Marginal Gamma of several paths together: sum mu s ((L + n)**rho - L**rho), n the number of taxis
    adding a (interval, cell) pair."""
    rho = city.params.rho
    total = 0.0
    for (k, c), n in taxis_per_pair.items():
        if n <= 0:
            continue
        lam_arr = counts.get(IntervalKey(k))
        lam = float(lam_arr[c]) if lam_arr is not None else 0.0
        total += city.mu(k) * float(city.cell_weight[c]) * float(theta_gain(lam, n, rho))
    return total


def pair_counts(pair_sets: Iterable[set[tuple[int, int]]]) -> Counter[tuple[int, int]]:
    """How many of the sets hold each pair."""
    n: Counter[tuple[int, int]] = Counter()
    for ps in pair_sets:
        n.update(ps)
    return n
