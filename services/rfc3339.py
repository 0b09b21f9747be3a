"""RFC 3339 date-time text and POSIX seconds, with the rules the API applies to every time it is given.

Accepted text has seconds and an explicit offset (``2026-11-23T08:00:00+08:00``, ``...Z``; a fraction of up
to nine digits; ``T``, ``t`` or a space between date and time), at most 40 characters, in the years
``MIN_YEAR..MAX_YEAR`` (checked in UTC). Numbers and naive times are refused: a time without an offset is
ambiguous across the cities' time zones.
"""

from __future__ import annotations

import datetime as dt
import re
from zoneinfo import ZoneInfo

__all__ = ["MIN_YEAR", "MAX_YEAR", "check_text", "check_year", "parse_rfc3339", "format_time"]

MIN_YEAR, MAX_YEAR = 1970, 2999
_MAX_LEN = 40
_RFC3339 = re.compile(r"^\d{4}-\d{2}-\d{2}[Tt ]\d{2}:\d{2}:\d{2}(\.\d{1,9})?([Zz]|[+-]\d{2}:\d{2})$")


def check_text(value: object) -> str:
    """``value`` if it is RFC 3339 text with seconds and an offset; ``ValueError`` saying what is expected."""
    if not isinstance(value, str):
        raise ValueError(
            "must be an RFC 3339 date-time string with an offset, e.g. 2024-05-06T08:00:00+08:00"
        )
    if len(value) > _MAX_LEN or not _RFC3339.match(value):
        raise ValueError(
            "must be an RFC 3339 date-time with seconds and an offset, e.g. 2024-05-06T08:00:00+08:00"
        )
    return value


def check_year(value: dt.datetime) -> dt.datetime:
    """``value`` if its UTC year lies in ``MIN_YEAR..MAX_YEAR``; ``ValueError`` otherwise."""
    if not MIN_YEAR <= value.astimezone(dt.UTC).year <= MAX_YEAR:
        raise ValueError(f"year must lie in {MIN_YEAR}..{MAX_YEAR}")
    return value


def parse_rfc3339(text: str) -> dt.datetime:
    """The aware date-time of RFC 3339 ``text`` (the module's rules; ``ValueError`` naming the problem)."""
    check_text(text)
    value = dt.datetime.fromisoformat(text.replace("z", "Z"))
    if value.tzinfo is None:
        raise ValueError("missing offset")
    return check_year(value)


def format_time(time_s: float, tz: str) -> str:
    """RFC 3339 text of POSIX time ``time_s`` in time zone ``tz`` (an IANA name, e.g. ``Asia/Shanghai``)."""
    return dt.datetime.fromtimestamp(time_s, tz=ZoneInfo(tz)).isoformat()
