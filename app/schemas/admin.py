"""Models of the admin routes (``app.api.admin``): rewinding or resetting a city's epoch stream."""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from app.schemas.common import Identifier, RequestModel, ResponseModel, Rfc3339, TimedRequest

__all__ = ["RewindIn", "ResetIn", "EpochStreamOut"]

_CONFIRM = "The city's name, repeated: the request is refused unless it equals the `{city}` of the path."


class RewindIn(TimedRequest):
    """Move the city's last epoch time back to `to`: epochs at `to` or later are accepted again."""

    to: Rfc3339 = Field(description="The new last epoch time (not later than the current one).")
    confirm: Identifier = Field(description=_CONFIRM)


class ResetIn(RequestModel):
    """Delete the city's epoch stream: counts, visits, epoch records, recorded demand and tasks."""

    confirm: Identifier = Field(description=_CONFIRM)


class EpochStreamOut(ResponseModel):
    """The city's epoch stream after a rewind or a reset."""

    city: str
    action: Literal["rewind", "reset"]
    previous_last_epoch_time: str | None = Field(
        description="The last epoch time before the request (null when no epoch was committed)."
    )
    last_epoch_time: str | None = Field(description="The last epoch time now (null after a reset).")
    committed: int = Field(description="Epochs the city has committed now (0 after a reset).")
    deleted_keys: int = Field(description="Store entries deleted (0 for a rewind).")
