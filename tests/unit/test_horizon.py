"""Interval arithmetic of the operating horizon (keys, labels, start times, parsing) and RFC 3339 text."""

from __future__ import annotations

import datetime as dt
from zoneinfo import ZoneInfo

import numpy as np
import pytest

from services.city import Horizon
from services.model import IntervalKey
from services.rfc3339 import check_text, format_time, parse_rfc3339

SHANGHAI = ZoneInfo("Asia/Shanghai")
NEW_YORK = ZoneInfo("America/New_York")


def days_since_epoch(day: dt.date) -> int:
    return (day - dt.date(1970, 1, 1)).days


# ------------------------------------------------------------------------------------------- keys and labels


def test_key_label_and_start_of_an_hour_by_hand() -> None:
    hz = Horizon()  # Asia/Shanghai, hourly from 08:00, 4 hours
    # local seconds of 2026-11-23T09:00 minus the 08:00 start, in hours: 24 per day plus one
    k = IntervalKey(days_since_epoch(dt.date(2026, 11, 23)) * 24 + 1)
    start = dt.datetime(2026, 11, 23, 9, 0, tzinfo=SHANGHAI).timestamp()
    assert hz.interval_of(start) == k and hz.interval_of(start + 3599.5) == k
    assert hz.interval_of(start - 0.5) == k - 1
    assert hz.label(k) == "2026-11-23T09:00"
    assert hz.interval_start_s(k) == start
    assert hz.position(k) == 1 and hz.in_horizon(k)
    assert not hz.in_horizon(k + 3)  # 12:00: the horizon ends at noon


def test_interval_starts_follow_the_wall_clock_across_a_dst_change() -> None:
    hz = Horizon(timezone="America/New_York")
    before = hz.interval_of(dt.datetime(2026, 3, 7, 8, 0, tzinfo=NEW_YORK).timestamp())
    after = hz.interval_of(dt.datetime(2026, 3, 8, 8, 0, tzinfo=NEW_YORK).timestamp())
    # keys count local wall-clock time: one day apart is 24 keys, though the night lost an hour
    assert after - before == 24
    assert hz.interval_start_s(after) - hz.interval_start_s(before) == 23 * 3600
    assert hz.interval_start_s(after) == dt.datetime(2026, 3, 8, 12, 0, tzinfo=dt.UTC).timestamp()  # EDT


@pytest.mark.parametrize(
    ("tz", "start", "interval_s", "n"),
    [
        ("Asia/Shanghai", dt.time(8, 0), 3600, 4),
        ("America/New_York", dt.time(7, 30), 1800, 10),
        ("Asia/Kolkata", dt.time(6, 0), 7200, 6),  # a +05:30 offset
        ("UTC", dt.time(0, 0), 86400, 1),
    ],
)
def test_labels_start_times_and_parsing_agree(tz: str, start: dt.time, interval_s: int, n: int) -> None:
    hz = Horizon(timezone=tz, start=start, interval_s=interval_s, n_intervals=n)
    rng = np.random.default_rng(12)
    first = hz.interval_of(dt.datetime(2026, 1, 1, tzinfo=dt.UTC).timestamp())
    keys = [
        k for k in (first + int(d) for d in rng.integers(0, 3 * 365 * hz.per_day, 400)) if hz.in_horizon(k)
    ]
    assert len(keys) > 20
    for k in keys:
        t0 = hz.interval_start_s(k)
        assert hz.interval_of(t0) == k and hz.interval_of(t0 - 1.0) == k - 1
        assert hz.interval_of(t0 + interval_s - 1.0) == k
        assert hz.parse_interval(hz.label(k)) == k
        inside = t0 + float(rng.uniform(0, interval_s - 1))
        assert hz.parse_interval(format_time(inside, tz)) == k
        assert hz.parse_interval(format_time(inside, "UTC").replace("+00:00", "Z")) == k


def test_parse_interval_errors() -> None:
    hz = Horizon()
    with pytest.raises(
        ValueError, match=r"^2026-11-23T08:30 is not the start of an interval \(e.g. 2026-11-23T08:00\)$"
    ):
        hz.parse_interval("2026-11-23T08:30")
    with pytest.raises(ValueError, match="^not a valid date and time$"):
        hz.parse_interval("2026-02-30T08:00")
    with pytest.raises(ValueError, match="^give a label YYYY-MM-DDTHH:MM or an RFC 3339 time with an offset"):
        hz.parse_interval("tomorrow")
    with pytest.raises(ValueError, match="year must lie in 1970..2999"):
        hz.parse_interval("3000-01-01T00:00:00Z")
    with pytest.raises(ValueError, match="an offset"):
        hz.parse_interval("2026-11-23T08:00:00")  # a naive time is ambiguous
    # a label whose interval would start before year 1 is refused, not an overflow
    daily = Horizon(interval_s=86400, n_intervals=1)
    with pytest.raises(ValueError, match="^0001-01-01T00:00 is not the start of an interval$"):
        daily.parse_interval("0001-01-01T00:00")
    # off-horizon intervals have labels too: the night of the day before
    assert hz.parse_interval("2026-11-23T03:00") == hz.parse_interval("2026-11-23T08:00") - 5


# ------------------------------------------------------------------------------------------------- RFC 3339


@pytest.mark.parametrize(
    ("text", "utc"),
    [
        ("2026-11-23T08:00:00+08:00", dt.datetime(2026, 11, 23, 0, 0, tzinfo=dt.UTC)),
        ("2026-11-23t00:00:00z", dt.datetime(2026, 11, 23, 0, 0, tzinfo=dt.UTC)),
        ("2026-11-23 05:30:00.250+05:30", dt.datetime(2026, 11, 23, 0, 0, 0, 250000, tzinfo=dt.UTC)),
    ],
)
def test_parse_rfc3339_accepts(text: str, utc: dt.datetime) -> None:
    assert parse_rfc3339(text) == utc


@pytest.mark.parametrize(
    "text",
    ["2026-11-23T08:00+08:00", "2026-11-23T08:00:00", "1700000000", "1969-12-31T23:59:59Z", "x" * 41],
)
def test_parse_rfc3339_refuses(text: str) -> None:
    with pytest.raises(ValueError):
        parse_rfc3339(text)


def test_check_text_refuses_numbers() -> None:
    with pytest.raises(ValueError, match="string"):
        check_text(1700000000)


def test_format_time_in_the_city_zone() -> None:
    assert format_time(0, "UTC") == "1970-01-01T00:00:00+00:00"
    t = dt.datetime(2026, 11, 23, 8, 0, tzinfo=SHANGHAI).timestamp()
    assert format_time(t, "Asia/Shanghai") == "2026-11-23T08:00:00+08:00"
    assert parse_rfc3339(format_time(t + 0.5, "Asia/Shanghai")).timestamp() == t + 0.5
