"""Prometheus metrics of one app instance (a per-app registry, so tests and apps never share counters)."""

from __future__ import annotations

import math

from prometheus_client import (
    CONTENT_TYPE_LATEST,
    CollectorRegistry,
    Counter,
    Gauge,
    Histogram,
    generate_latest,
)

__all__ = ["Metrics", "CONTENT_TYPE"]

CONTENT_TYPE = CONTENT_TYPE_LATEST


class Metrics:
    """The service's counters and histograms."""

    def __init__(self) -> None:
        self.registry = CollectorRegistry(auto_describe=True)
        self.epochs = Counter(
            "sd_epochs",
            "Epoch posts by outcome (committed, replayed, or the error kind).",
            ["outcome"],
            registry=self.registry,
        )
        self.epoch_latency = Histogram(
            "sd_epoch_latency_seconds",
            "Wall time of POST /epochs, validation to response.",
            buckets=(0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0, 10.0, 30.0),
            registry=self.registry,
        )
        self.matches = Counter(
            "sd_rider_matches",
            "Riders matched, by step of the priority matching.",
            ["step"],
            registry=self.registry,
        )
        self.task_assignments = Counter(
            "sd_task_assignments", "Monitoring routes assigned (Step 3).", registry=self.registry
        )
        self.commit_retries = Counter(
            "sd_commit_retries", "Epoch solves repeated after a version mismatch.", registry=self.registry
        )
        self.errors = Counter("sd_errors", "Error responses by kind.", ["kind"], registry=self.registry)
        self.worker_heartbeat_age = Gauge(
            "sd_fleet_worker_heartbeat_age_seconds",
            "Seconds since the newest fleet worker heartbeat of each city (+Inf: none kept), read from the "
            "store when scraped.",
            ["city"],
            registry=self.registry,
        )
        for step in ("1", "2"):
            self.matches.labels(step=step)
        for outcome in ("committed", "replayed"):
            self.epochs.labels(outcome=outcome)

    def set_heartbeat_ages(self, ages: dict[str, float | None]) -> None:
        """The heartbeat age of every city (``None``: no heartbeat kept, shown as +Inf)."""
        for city, age in ages.items():
            self.worker_heartbeat_age.labels(city=city).set(math.inf if age is None else age)

    def render(self) -> bytes:
        """The Prometheus text exposition."""
        return generate_latest(self.registry)
