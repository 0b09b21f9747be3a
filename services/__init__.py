"""The framework-free core of the drive-by sensing dispatch service: numpy, scipy, numba and pyproj (the
projection of a city's coordinates); no HTTP, Redis, settings, environment or clocks.

Laid out like the method (docs/METHOD.md):

* ``network/``: the road network, its search graphs and the canonical shortest paths (paper Section 3).
* ``sensing/``: the grid, the counts Λ, the weights Θ and the marginal gain ϑ (Section 3.1).
* ``matching/``: pickups, trips, the exact assignment; Steps 1 and 2 of an epoch (Section 4).
* ``routing/``: Algorithm 1, Step 3 and Algorithm 2 (Sections 4-5).
* ``fleet/``: the DRO engine and the fleet-sizing methods Deterministic, DRO, DRO_RH (Section 3.3).
* ``sim/``: demand, the simulator and its KPIs (Section 6's numerical test).
* ``kernel/``: the compiled-function decorator and the thread map the others run on.
* ``dispatch``: ``decide``, one epoch from snapshot to decision; ``model``, ``city``, ``tasks``, ``ledger``:
  the records, the served city, the task lifecycle and the commit rule; ``citydata``, ``importers``,
  ``geojson``, ``rfc3339``: the city bundles, the network importers and the documents and times of the API.
"""
