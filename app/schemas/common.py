"""What every router's models share: base classes, identifiers, RFC 3339 times, locations, the error shape."""

from __future__ import annotations

import datetime as dt
from typing import Annotated, Any

from pydantic import (
    AwareDatetime,
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Field,
    Strict,
    StrictInt,
    StringConstraints,
    field_validator,
    model_validator,
)

from services.rfc3339 import check_text, check_year, format_time, parse_rfc3339

__all__ = [
    "ID_MAX_LEN",
    "RequestModel",
    "ResponseModel",
    "TimedRequest",
    "Identifier",
    "Rfc3339",
    "parse_rfc3339",
    "format_time",
    "LocationIn",
    "FieldErrorOut",
    "ErrorOut",
]

ID_MAX_LEN = 128


class RequestModel(BaseModel):
    """Base of request models: unknown fields are errors."""

    model_config = ConfigDict(extra="forbid", frozen=True)


class ResponseModel(BaseModel):
    """Base of response models."""

    model_config = ConfigDict(extra="forbid")


Rfc3339 = Annotated[AwareDatetime, BeforeValidator(check_text)]
"""An RFC 3339 date-time with an explicit offset (the rules of ``services.rfc3339``)."""

Identifier = Annotated[
    str, StringConstraints(min_length=1, max_length=ID_MAX_LEN, pattern=r"^[^\x00-\x1f\x7f]+$")
]
NodeId = Annotated[StrictInt, Field(ge=-(2**63), le=2**63 - 1, description="External node id.")]
Lon = Annotated[float, Strict(), Field(ge=-180.0, le=180.0, allow_inf_nan=False)]
Lat = Annotated[float, Strict(), Field(ge=-90.0, le=90.0, allow_inf_nan=False)]


class LocationIn(RequestModel):
    """A position: ``{"node": id}`` or ``{"lon": x, "lat": y}`` (snapped to the nearest node)."""

    model_config = ConfigDict(
        extra="forbid",
        frozen=True,
        json_schema_extra={"oneOf": [{"required": ["node"]}, {"required": ["lon", "lat"]}]},
    )

    node: NodeId | None = None
    lon: Lon | None = Field(default=None, description="WGS84 longitude, degrees.")
    lat: Lat | None = Field(default=None, description="WGS84 latitude, degrees.")

    @model_validator(mode="after")
    def _one_form(self) -> LocationIn:
        if self.node is not None and (self.lon is not None or self.lat is not None):
            raise ValueError("give either node or lon and lat, not both")
        if self.node is None and (self.lon is None or self.lat is None):
            raise ValueError("give node, or both lon and lat")
        return self


class TimedRequest(RequestModel):
    """Validates the year range of every RFC 3339 field."""

    @field_validator("*", mode="after")
    @classmethod
    def _year_range(cls, value: Any) -> Any:
        return check_year(value) if isinstance(value, dt.datetime) else value


# ----------------------------------------------------------------------------------------- responses


class FieldErrorOut(ResponseModel):
    """One offending field."""

    loc: str = Field(description="Dotted location, e.g. riders[2].origin.lon.")
    msg: str


class ErrorOut(ResponseModel):
    """The one error shape of the API."""

    error: str = Field(description="Machine-readable kind, e.g. validation_error, epoch_conflict.")
    detail: str
    fields: list[FieldErrorOut]
