"""Fleet sizing (paper Section 3.3, Eq. (17)-(29); docs/METHOD.md sections 7-8).

* ``dro``: the worst-case expectation over a φ-divergence ball (the DRO engine).
* ``sizing``: the three methods, Deterministic, DRO and DRO_RH, on per-size day outcomes; the ζ sweep.
* ``evaluation``: the realized cost of their choices on held-out test days.
"""

from services.fleet.evaluation import Realized, realized_by_hour, realized_fixed, rolling_decisions
from services.fleet.sizing import (
    TIE_RTOL,
    Ambiguity,
    CandidateRow,
    CandidateTable,
    Choice,
    ChoiceStatus,
    CostModel,
    DayOutcomes,
    FleetInputError,
    FleetMethod,
    FleetPlan,
    RollingHour,
    Sense,
    SizeRow,
    SizeTable,
    SubsidyPoint,
    candidate_table,
    choose,
    completion_samples,
    plan_fleet,
    rolling_hour,
    similar_days,
    size_table,
    subsidy_sweep,
    total_cost_samples,
)

__all__ = [
    "TIE_RTOL",
    "FleetInputError",
    "Sense",
    "FleetMethod",
    "ChoiceStatus",
    "Ambiguity",
    "CostModel",
    "DayOutcomes",
    "SizeRow",
    "SizeTable",
    "CandidateRow",
    "CandidateTable",
    "Choice",
    "RollingHour",
    "FleetPlan",
    "size_table",
    "total_cost_samples",
    "completion_samples",
    "candidate_table",
    "choose",
    "similar_days",
    "rolling_hour",
    "plan_fleet",
    "SubsidyPoint",
    "subsidy_sweep",
    "Realized",
    "realized_fixed",
    "realized_by_hour",
    "rolling_decisions",
]
