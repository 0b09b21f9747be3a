"""Step 3 and the monitoring routes (paper Section 4, Eq. (13)-(16), and Section 5; docs/METHOD.md sections
4-6).

* ``algorithm1``: the enhanced A* family (Algorithm 1): sensing-aware routes from many taxis to many POIs.
* ``step3``: Step 3, vacant instrumented taxis matched to POIs within their reach.
* ``algorithm2``: the joint re-planning of Step 3's routes (Algorithm 2) and its objective, the joint
  utility of several routes (the pairs each adds to Lambda, and Gamma's gain from all of them together).
"""

from services.routing.algorithm1 import (
    Drive,
    Plans,
    Problem,
    Route,
    RouteScratch,
    evaluate,
    kappa_graph,
    plan_one,
    plan_routes,
    problem,
    route_pair,
    route_scratch,
)
from services.routing.algorithm2 import improve_routes, joint_utility, pair_counts, route_pairs
from services.routing.step3 import PHI_BITS, Step3, step3_monitoring_routes, step3_reach, step3_reach_us

__all__ = [
    "Plans",
    "Problem",
    "problem",
    "Route",
    "Drive",
    "RouteScratch",
    "route_scratch",
    "plan_routes",
    "plan_one",
    "route_pair",
    "evaluate",
    "kappa_graph",
    "PHI_BITS",
    "Step3",
    "step3_monitoring_routes",
    "step3_reach",
    "step3_reach_us",
    "improve_routes",
    "route_pairs",
    "joint_utility",
    "pair_counts",
]
