"""What every router's models share: base classes, identifiers, RFC 3339 times, locations, the error shape."""

from __future__ import annotations

import datetime as dt
import re
from typing import Annotated, Any

from pydantic import (
    AwareDatetime,
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Field,
    Strict,
    StringConstraints,
    WithJsonSchema,
    field_validator,
    model_validator,
)

from services.rfc3339 import MAX_YEAR, MIN_YEAR, check_text, format_time, parse_rfc3339

__all__ = [
    "ID_MAX_LEN",
    "RequestModel",
    "ResponseModel",
    "TimedRequest",
    "Identifier",
    "Rfc3339",
    "RFC3339_PATTERN",
    "LABEL_PATTERN",
    "JsonInt",
    "integral",
    "check_time_text",
    "utc_year_ok",
    "parse_rfc3339",
    "format_time",
    "LocationIn",
    "FieldErrorOut",
    "HistoryCountOut",
    "ErrorOut",
]

ID_MAX_LEN = 128


class RequestModel(BaseModel):
    """Base of request models: unknown fields are errors."""

    model_config = ConfigDict(extra="forbid", frozen=True)


class ResponseModel(BaseModel):
    """Base of response models."""

    model_config = ConfigDict(extra="forbid")


# The accepted times as a pattern, so that the OpenAPI document states them: RFC 3339 with seconds and an
# offset, written in the years 1970..2999 (the server also wants the UTC instant in those years, which
# moves the edges by the offset). Every part is range-checked here, so no date arithmetic can overflow.
_YEAR = r"(19[7-9][0-9]|2[0-9]{3})"
_DATE = _YEAR + r"-(0[1-9]|1[0-2])-(0[1-9]|[12][0-9]|3[01])"
_HM = r"([01][0-9]|2[0-3]):[0-5][0-9]"
RFC3339_PATTERN = rf"^{_DATE}[Tt ]{_HM}:[0-5][0-9](\.[0-9]{{1,9}})?([Zz]|[+-]{_HM})$"
LABEL_PATTERN = rf"^{_DATE}T{_HM}$"
_RFC3339 = re.compile(RFC3339_PATTERN)
_TIME_RULE = (
    f"must be an RFC 3339 date-time with seconds and an offset in the years {MIN_YEAR}..{MAX_YEAR}, "
    "e.g. 2024-05-06T08:00:00+08:00"
)


def check_time_text(value: object) -> str:
    """``value`` if it is RFC 3339 text the API accepts (``RFC3339_PATTERN``); ``ValueError`` otherwise."""
    text = check_text(value)
    if not _RFC3339.match(text):
        raise ValueError(_TIME_RULE)
    return text


def utc_year_ok(value: dt.datetime) -> dt.datetime:
    """``value`` if its UTC year lies in ``MIN_YEAR..MAX_YEAR``; ``ValueError`` otherwise, never an
    ``OverflowError`` (year 1 at +23:59 has no UTC year)."""
    try:
        year = value.astimezone(dt.UTC).year
    except OverflowError:
        year = None
    if year is None or not MIN_YEAR <= year <= MAX_YEAR:
        raise ValueError(f"the instant must lie in the years {MIN_YEAR}..{MAX_YEAR} UTC")
    return value


Rfc3339 = Annotated[
    AwareDatetime,
    BeforeValidator(check_time_text),
    WithJsonSchema({"type": "string", "format": "date-time", "maxLength": 40, "pattern": RFC3339_PATTERN}),
]
"""An RFC 3339 date-time with an explicit offset, in the years 1970..2999 (``RFC3339_PATTERN``)."""


def integral(value: object) -> object:
    """2.0 is the integer 2, as JSON Schema's ``integer`` says; 2.5, strings and booleans stay refused."""
    return int(value) if isinstance(value, float) and value.is_integer() else value


JsonInt = Annotated[int, Strict(), BeforeValidator(integral)]
"""A JSON integer: a number with no fractional part (``2`` or ``2.0``), never a string or a boolean."""

Identifier = Annotated[
    str, StringConstraints(min_length=1, max_length=ID_MAX_LEN, pattern=r"^[^\x00-\x1f\x7f]+$")
]
NodeId = Annotated[
    int,
    Strict(),
    Field(ge=-(2**63), le=2**63 - 1, description="External node id."),
    BeforeValidator(integral),  # outermost, so that the bounds stay in the JSON schema
]
Lon = Annotated[float, Strict(), Field(ge=-180.0, le=180.0, allow_inf_nan=False)]
Lat = Annotated[float, Strict(), Field(ge=-90.0, le=90.0, allow_inf_nan=False)]


def _no_null(schema: dict[str, Any]) -> None:
    """Drop the ``null`` branch of an optional field's schema: the field may be left out, not be null."""
    branches = schema.pop("anyOf", None)
    if branches is not None:
        kept = [b for b in branches if b.get("type") != "null"]
        schema.update(kept[0] if len(kept) == 1 else {"anyOf": kept})
    schema.pop("default", None)


class LocationIn(RequestModel):
    """A position: ``{"node": id}`` or ``{"lon": x, "lat": y}`` (snapped to the nearest node)."""

    model_config = ConfigDict(
        extra="forbid",
        frozen=True,
        json_schema_extra={"oneOf": [{"required": ["node"]}, {"required": ["lon", "lat"]}]},
    )

    # absent, not null: ``_no_null`` keeps null out of the document, ``_not_null`` out of the server
    node: NodeId | None = Field(default=None, json_schema_extra=_no_null)
    lon: Lon | None = Field(default=None, description="WGS84 longitude, degrees.", json_schema_extra=_no_null)
    lat: Lat | None = Field(default=None, description="WGS84 latitude, degrees.", json_schema_extra=_no_null)

    @field_validator("node", "lon", "lat", mode="before")
    @classmethod
    def _not_null(cls, value: Any) -> Any:
        if value is None:
            raise ValueError("must not be null: leave the field out")
        return value

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
        return utc_year_ok(value) if isinstance(value, dt.datetime) else value


# ----------------------------------------------------------------------------------------- responses


class FieldErrorOut(ResponseModel):
    """One offending field."""

    loc: str = Field(description="Dotted location, e.g. riders[2].origin.lon.")
    msg: str


class HistoryCountOut(ResponseModel):
    """How much of the history a fleet solve needs a city has (docs/FLEET.md)."""

    days: int = Field(description="Local days with epochs in the look-back before today (at most needed).")
    needed: int = Field(description="M, the days a solve is sized on.")
    first_solve_on: str = Field(
        description="The first local day (YYYY-MM-DD) a solve is possible if epochs are posted every day."
    )


class ErrorOut(ResponseModel):
    """The one error shape of the API."""

    error: str = Field(description="Machine-readable kind, e.g. validation_error, epoch_conflict.")
    detail: str
    fields: list[FieldErrorOut]
    history: HistoryCountOut | None = Field(
        default=None, description="insufficient_history only: the history the city has and needs."
    )
