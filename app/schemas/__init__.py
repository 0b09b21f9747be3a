"""Request and response models of the HTTP API, one module per router, and their conversion from the core.

``common`` holds what the routers share (base classes, identifiers, RFC 3339 times, locations, the error
shape); ``ops``, ``cities``, ``tasks``, ``decision``, ``coverage``, ``fleet`` and ``dro`` the models of
their routes. The names below are re-exported for ``from app.schemas import EpochIn``.
"""

from app.schemas.cities import (
    CitiesOut,
    CityOut,
    GraphEdgeOut,
    GraphNodeOut,
    GraphOut,
    GridOut,
    HorizonOut,
    NetworkSizeOut,
    ParamsOut,
)
from app.schemas.common import (
    ID_MAX_LEN,
    ErrorOut,
    FieldErrorOut,
    Identifier,
    LocationIn,
    Rfc3339,
    format_time,
    parse_rfc3339,
)
from app.schemas.coverage import CellCountOut, CoverageOut
from app.schemas.decision import EpochIn, EpochOut, RiderIn, RiderMatchOut, TaskAssignmentOut, TaxiIn
from app.schemas.ops import HealthOut, ReadyOut
from app.schemas.tasks import TaskIn, TaskOut, TasksOut, TasksPutOut

__all__ = [
    "ID_MAX_LEN",
    "Identifier",
    "Rfc3339",
    "parse_rfc3339",
    "format_time",
    "LocationIn",
    "RiderIn",
    "TaxiIn",
    "EpochIn",
    "TaskIn",
    "FieldErrorOut",
    "ErrorOut",
    "HealthOut",
    "ReadyOut",
    "NetworkSizeOut",
    "GridOut",
    "HorizonOut",
    "ParamsOut",
    "CityOut",
    "CitiesOut",
    "GraphNodeOut",
    "GraphEdgeOut",
    "GraphOut",
    "TaskOut",
    "TasksOut",
    "TasksPutOut",
    "RiderMatchOut",
    "TaskAssignmentOut",
    "EpochOut",
    "CellCountOut",
    "CoverageOut",
]
