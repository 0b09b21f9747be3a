"""The in-process dispatcher's kept state: the view an epoch reads equals ``services.ledger.ledger_view`` of
its ledger, epoch after epoch of a real run."""

from __future__ import annotations

import numpy as np

from app.adapters.city_registry import CityRegistry
from app.runs import RunSpec, open_bundle
from app.runs.workload import demand_for, tasks_for
from services.ledger import ledger_view
from services.model import Snapshot, TaxiId
from services.sim.engine import SimConfig, simulate
from services.sim.local import LocalDispatcher, Outcome


class ViewChecking(LocalDispatcher):
    """Before every epoch, the view the dispatcher keeps must be ``ledger_view`` of its ledger."""

    checked = 0

    def epoch(self, snapshot: Snapshot) -> Outcome:
        ids = [t.id for t in snapshot.taxis if t.instrumented]
        mine = self.counts_view(ids)
        theirs = ledger_view(self.ledger, ids, self.city.grid.n_cells)
        assert mine.visited == theirs.visited
        assert list(mine.counts) == list(theirs.counts)
        assert all(np.array_equal(mine.counts[k], theirs.counts[k]) for k in theirs.counts)
        ViewChecking.checked += 1
        return super().epoch(snapshot)


def test_the_in_process_dispatcher_keeps_the_ledgers_view() -> None:
    bundle = open_bundle(CityRegistry().bundle_dir("chengdu"))
    spec = RunSpec("chengdu", 1, 30, 30, seed=2, day=1, n_tasks=20)
    demand = demand_for(spec, bundle)
    dispatcher = ViewChecking(bundle.city)
    trace = simulate(
        bundle.city, demand, tasks_for(spec, bundle, demand.date), SimConfig(30, 30, 20, seed=2), dispatcher
    )
    assert ViewChecking.checked == 72
    assert (
        sum(
            len(pairs)
            for pairs in dispatcher.counts_view(TaxiId(f"i{k:03d}") for k in range(30)).visited.values()
        )
        > 100
    )
    assert trace.assignments  # Step 3 routes were counted too
