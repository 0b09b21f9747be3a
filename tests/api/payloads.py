"""Request bodies for the API tests."""

from __future__ import annotations

import datetime as dt
from typing import Any

from tests.api.fakes import T0, lonlat, node_id, rfc


def at(minutes: float) -> dt.datetime:
    """T0 plus ``minutes``."""
    return T0 + dt.timedelta(minutes=minutes)


def epoch(
    epoch_id: str = "e1",
    minutes: float = 0.0,
    *,
    riders: list[dict[str, Any]] | None = None,
    taxis: list[dict[str, Any]] | None = None,
) -> dict[str, Any]:
    """An epoch at T0 + minutes: by default two riders and three taxis (t0 instrumented)."""
    when = at(minutes)
    if riders is None:
        lon, lat = lonlat(3, 3)
        riders = [
            {
                "id": "r1",
                "origin": {"node": node_id(0, 0)},
                "destination": {"node": node_id(4, 4)},
                "requested_at": rfc(when - dt.timedelta(seconds=30)),
            },
            {
                "id": "r2",
                "origin": {"lon": lon, "lat": lat},
                "destination": {"node": node_id(1, 0)},
                "requested_at": rfc(when),
            },
        ]
    if taxis is None:
        taxis = [
            {"id": "t0", "location": {"node": node_id(0, 1)}, "instrumented": True, "status": "vacant"},
            {"id": "t1", "location": {"node": node_id(2, 2)}, "instrumented": False, "status": "vacant"},
            {"id": "t2", "location": {"node": node_id(4, 0)}, "instrumented": True, "status": "busy"},
        ]
    return {"epoch_id": epoch_id, "time": rfc(when), "riders": riders, "taxis": taxis}


def tasks() -> list[dict[str, Any]]:
    """Two tasks: one on r1's path (completed passively by t0), one elsewhere."""
    lon, lat = lonlat(4, 2)
    return [
        {"id": "poi-a", "location": {"node": node_id(0, 0)}, "scheduled_at": rfc(at(-10))},
        {"id": "poi-b", "location": {"lon": lon, "lat": lat}, "scheduled_at": rfc(at(30))},
    ]


def both_kinds() -> tuple[list[dict[str, Any]], dict[str, Any]]:
    """Three open tasks and an epoch of three vacant instrumented taxis and an ordinary one: on the lattice
    the real solver matches riders and sends idle instrumented taxis to POIs (both kinds of decision)."""
    opened = rfc(at(-5))
    open_tasks = [
        {"id": f"poi{i}", "location": {"node": node_id(c, r)}, "scheduled_at": opened}
        for i, (c, r) in enumerate([(4, 4), (0, 4), (2, 0)])
    ]
    taxis = [
        {"id": "t0", "location": {"node": node_id(0, 1)}, "instrumented": True, "status": "vacant"},
        {"id": "t1", "location": {"node": node_id(2, 2)}, "instrumented": False, "status": "vacant"},
        {"id": "t2", "location": {"node": node_id(4, 0)}, "instrumented": True, "status": "vacant"},
        {"id": "t3", "location": {"node": node_id(1, 3)}, "instrumented": True, "status": "vacant"},
    ]
    return open_tasks, epoch("e1", 0, taxis=taxis)
