"""Steps 1 and 2 of an epoch: riders matched to vacant taxis (paper Section 4, docs/METHOD.md section 4).

1. Step 1 (Eq. 4-7): vacant instrumented taxis x waiting riders within the pickup radius; a pair's weight is
   the marginal sensing gain of the service leg (pickup -> dropoff) for that taxi, leaving when it reaches
   the rider; pairs with a positive gain only; maximize the total gain, then minimize the total wait.
2. Step 2 (Eq. 8-11): vacant ordinary taxis x the remaining riders; maximize matches, then minimize wait.

Both assignments are exact (``services.matching.assignment``): gains in fixed point whose sums are exact,
waits in whole microseconds (the searches' own cost).
"""

from __future__ import annotations

from collections.abc import Collection, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from services.epoch import Epoch, until_fits
from services.matching.assignment import lexicographic_assignment
from services.matching.legs import Leg, Pickups
from services.sensing.gains import Counted, Gains, eval_pairs, fixed_point_unit, gain_table, pair_gains_q

__all__ = ["Match", "Step1", "select", "step1_sensing_matches", "step2_regular_matches"]


@dataclass(frozen=True, slots=True)
class Match:
    """A matched pair: the taxi (its index among the step's taxis: the instrumented ones in Step 1, the
    ordinary ones in Step 2), the rider (its index among the epoch's riders), the pair's index among the
    step's candidate pickups, and the reported sensing gain (0.0 in Step 2)."""

    taxi: int
    rider: int
    pickup: int
    gain: float


@dataclass(frozen=True, slots=True)
class Step1:
    """Step 1's outcome: the matched pairs, the interval slots the gain tables needed, diagnostics."""

    pairs: list[Match]
    n_slots: int
    stats: dict[str, float | int]


def select(pk: Pickups, keep: NDArray[np.bool_]) -> Pickups:
    """The candidate pairs where ``keep`` is true, in their order."""
    return Pickups(pk.taxi[keep], pk.rider[keep], pk.length_m[keep], pk.wait_s[keep], pk.wait_us[keep])


def _service_edges(service: Sequence[Leg]) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """The service legs' edges, flat, with the offsets of each leg's."""
    leg_ptr = np.zeros(len(service) + 1, dtype=np.int64)
    leg_ptr[1:] = np.cumsum([len(leg.edges) for leg in service])
    leg_edges = np.concatenate([leg.edges for leg in service]).astype(np.int64) if service else leg_ptr[:0]
    return leg_ptr, leg_edges


def step1_sensing_matches(
    epoch: Epoch, counted: Counted, cands: Pickups, service: Sequence[Leg], n_slots: int
) -> Step1:
    """Step 1 (Eq. 4-7) over the instrumented taxis' candidate pairs ``cands`` (taxi ``i``'s counted pairs
    in row ``i`` of ``counted``; ``service[j]``: rider ``j``'s trip). Gain tables start with ``n_slots``
    intervals and grow until every leg fits; a pair is a candidate when its exact gain is positive."""
    stats: dict[str, float | int] = {"step1_candidates": len(cands.taxi)}
    if len(cands.taxi) == 0:
        return Step1([], n_slots, stats)
    ed = epoch.graph.edges
    leg_ptr, leg_edges = _service_edges(service)
    crossings = max(int((ed.ec_ptr[leg.edges + 1] - ed.ec_ptr[leg.edges]).sum()) for leg in service)
    depart = epoch.now + cands.wait_s

    def gains(n: int) -> tuple[tuple[Gains, NDArray[np.int64]], int | None]:
        top = gain_table(epoch.city, epoch.counts.counts, epoch.k0, n, epoch.now)
        unit = fixed_point_unit(float(top.term.max(initial=0.0)), crossings)
        gn = gain_table(epoch.city, epoch.counts.counts, epoch.k0, n, epoch.now, unit=unit)
        gq, max_slot = pair_gains_q(ed, gn, counted, cands.taxi, cands.rider, depart, leg_ptr, leg_edges)
        return (gn, gq), (None if max_slot < n else int(max_slot) + 1)

    (gn, gq), n_slots = until_fits(gains, n_slots)
    ok = np.flatnonzero(gq > 0)  # a pair is a candidate for gain when its exact gain is positive
    sol = lexicographic_assignment(
        cands.taxi[ok], cands.rider[ok], gq[ok], cands.wait_us[ok], secondary_sense="min"
    )
    stats.update({"step1_positive_pairs": len(ok), "step1_gain_unit": gn.unit})
    chosen = ok[sol.pair]
    # the reported gain: the floating-point sum along the path, for the matched pairs only
    g, _gq, _ms = eval_pairs(
        ed, gn, counted, cands.taxi[chosen], cands.rider[chosen], depart[chosen], leg_ptr, leg_edges
    )
    pairs = [
        Match(int(cands.taxi[k]), int(cands.rider[k]), int(k), float(x))
        for k, x in zip(chosen.tolist(), g, strict=True)
    ]
    return Step1(pairs, n_slots, stats)


def step2_regular_matches(cands: Pickups, taken: Collection[int], n_riders: int) -> list[Match]:
    """Step 2 (Eq. 8-11) over the ordinary taxis' candidate pairs ``cands`` x the riders not in ``taken``;
    maximize the matches, then minimize the total wait."""
    left = np.array([j not in taken for j in range(n_riders)], dtype=bool)
    ok = np.flatnonzero(left[cands.rider]) if len(cands.rider) else np.zeros(0, dtype=np.int64)
    sol = lexicographic_assignment(
        cands.taxi[ok],
        cands.rider[ok],
        np.ones(len(ok), dtype=np.int64),
        cands.wait_us[ok],
        secondary_sense="min",
    )
    return [Match(int(cands.taxi[k]), int(cands.rider[k]), int(k), 0.0) for k in ok[sol.pair].tolist()]
