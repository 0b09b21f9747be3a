"""Steps 1 and 2 of an epoch: riders matched to vacant taxis (paper Section 4, Eq. (4)-(11); docs/METHOD.md
section 4).

* ``legs``: the pickups (taxi-rider pairs within the radius, with their waits) and the riders' trips.
* ``assignment``: the exact lexicographic assignment every step solves.
* ``steps``: Step 1 (instrumented taxis, the sensing gain of the service leg) and Step 2 (ordinary taxis,
  the remaining riders).
"""

from services.matching.assignment import Assignment, lexicographic_assignment
from services.matching.legs import Leg, Pickups, pickups, trips
from services.matching.steps import Match, Step1, select, step1_sensing_matches, step2_regular_matches

__all__ = [
    "Pickups",
    "pickups",
    "trips",
    "Leg",
    "Assignment",
    "lexicographic_assignment",
    "Match",
    "Step1",
    "select",
    "step1_sensing_matches",
    "step2_regular_matches",
]
