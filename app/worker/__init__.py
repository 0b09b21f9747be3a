"""The fleet-sizing worker (``python -m app worker``; docs/FLEET.md): re-solves DRO_RH every hour and
serves admin solve requests, reading and publishing through ``app.usecases.fleet_solve.FleetSolver``."""
