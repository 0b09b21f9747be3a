"""Models of the committed-epoch routes (``app.api.epochs``): the epoch log. A stored epoch is served as the
``EpochOut`` document its post returned (``app.schemas.decision``)."""

from __future__ import annotations

from pydantic import Field

from app.schemas.common import ResponseModel, format_time
from app.usecases import EpochLog

__all__ = ["LastEpochOut", "EpochLogOut"]


class LastEpochOut(ResponseModel):
    """The last committed epoch of a city."""

    epoch_id: str
    time: str = Field(description="Its time, RFC 3339 in the city's time zone.")


class EpochLogOut(ResponseModel):
    """What a city has committed."""

    city: str
    committed: int = Field(description="Epochs committed so far.")
    last: LastEpochOut | None = Field(description="The last committed epoch (null before the first).")

    @classmethod
    def of(cls, log: EpochLog) -> EpochLogOut:
        """Render the epoch log of a city."""
        last = None
        if log.last_epoch_id is not None and log.last_epoch_time_s is not None:
            time = format_time(log.last_epoch_time_s, log.city.horizon.timezone)
            last = LastEpochOut(epoch_id=log.last_epoch_id, time=time)
        return cls(city=log.city.name, committed=log.committed, last=last)
