"""The one settings object of the service (environment prefix ``SD_``)."""

from __future__ import annotations

from pathlib import Path
from typing import Literal

from pydantic import Field, field_validator, model_validator
from pydantic_settings import BaseSettings, SettingsConfigDict

from services.kernel.parallel import default_workers

__all__ = [
    "Scope",
    "Settings",
    "SCOPES",
    "DivergenceName",
    "SUBSIDY_DEFAULT_CNY_PER_VEHICLE_HOUR",
    "SUBSIDY_SWEEP_DEFAULT",
]

Scope = Literal["read", "dispatch", "admin"]
SCOPES: tuple[Scope, ...] = ("read", "dispatch", "admin")
DivergenceName = Literal["kl", "burg", "j", "chi2", "modified_chi2", "hellinger", "variation"]

SUBSIDY_DEFAULT_CNY_PER_VEHICLE_HOUR = 0.94
"""ζ's default: a low-cost sensor kit amortized over its service hours plus the incentive that keeps an
instrumented driver accepting orders (the sources and the arithmetic: docs/FLEET.md, "The subsidy ζ")."""
SUBSIDY_SWEEP_DEFAULT = (0.0, 0.2, 0.3, 0.4, 0.5, 0.75, 1.0, 1.5, 2.0, 3.0)
"""The subsidies at which every solve also reports each method's choice (the trade-off curve)."""


class Settings(BaseSettings):
    """Service configuration; every field can be set as ``SD_<NAME>`` (e.g. ``SD_STORE=redis``)."""

    model_config = SettingsConfigDict(env_prefix="SD_", env_file=None, extra="forbid", frozen=True)

    store: Literal["memory", "redis"] = Field(default="memory", description="State backend.")
    redis_url: str = Field(
        default="redis://localhost:6379/0",
        description="Redis URL when store=redis (in cluster mode: any node of the cluster).",
    )
    redis_mode: Literal["standalone", "cluster"] = Field(
        default="standalone", description="One Redis server, or a Redis Cluster (redis-py's cluster client)."
    )
    store_timeout_s: float = Field(
        default=1.0,
        gt=0.0,
        le=60.0,
        description="Bound on every connect, read and write of the Redis store (a frozen Redis: 503).",
    )
    store_concurrency: int = Field(
        default=16,
        ge=1,
        le=1024,
        description="Store calls in flight at once per process; a request finding all taken waits at most "
        "store_queue_s, then gets 503 (a frozen store never ties up every worker thread).",
    )
    store_queue_s: float = Field(
        default=0.1, ge=0.0, le=60.0, description="How long a store call waits for a free slot (then 503)."
    )
    redis_prefix: str = Field(
        default="sd", pattern=r"^[A-Za-z0-9_.-]{1,40}$", description="Redis key prefix (one per deployment)."
    )
    host: str = Field(default="127.0.0.1", description="Bind address of `python -m app run`.")
    port: int = Field(default=8000, ge=0, le=65535, description="Port of `python -m app run`.")
    tokens: dict[str, list[Scope]] = Field(
        default_factory=dict,
        description='Bearer tokens and their scopes (read, dispatch, admin), JSON: {"tok1": ["read"]}.',
    )
    cities_dir: Path = Field(default=Path("var/cities"), description="Directory of user-imported cities.")
    bundled_cities_dir: Path | None = Field(
        default=None, description="Directory of bundled cities (default: the package's app/data/cities)."
    )
    max_body_bytes: int = Field(
        default=1 << 20, ge=1024, description="Largest accepted request body (413 above)."
    )
    max_riders: int = Field(default=2000, ge=1, description="Most riders in one epoch.")
    max_taxis: int = Field(default=5000, ge=1, description="Most taxis in one epoch.")
    max_tasks: int = Field(default=1000, ge=1, description="Most tasks in one POST.")
    epoch_max_ahead_s: int = Field(
        default=86400,
        ge=0,
        description="Latest accepted epoch time, in seconds after the service clock (422 beyond; older "
        "epochs are always accepted).",
    )
    header_timeout_s: float = Field(
        default=10.0,
        gt=0.0,
        le=3600.0,
        description="A connection must deliver a request's headers within this time (then 408 and closed).",
    )
    body_timeout_s: float = Field(
        default=30.0,
        gt=0.0,
        le=3600.0,
        description="A request must deliver its whole body within this time after its headers (then 408).",
    )
    max_connections: int | None = Field(
        default=None,
        ge=1,
        description="Open connections per process; one more is answered 503 and closed at once (default: "
        "the file descriptor limit minus 64, at most 4096).",
    )
    dispatch_workers: int = Field(
        default_factory=default_workers,
        ge=1,
        le=64,
        description="Threads that share an epoch's independent searches (default: the CPUs, at most 4).",
    )
    max_solves: int = Field(
        default=2,
        ge=1,
        le=64,
        description="Epochs solved at once per process (each takes the dispatch threads and, at the API's "
        "limits, ~1 GB); an epoch finding every slot taken waits at most solve_queue_s, then gets 503 busy.",
    )
    solve_queue_s: float = Field(
        default=30.0,
        ge=0.0,
        le=600.0,
        description="How long an epoch waits for a free solve slot (then 503).",
    )
    commit_attempts: int = Field(
        default=8, ge=1, le=100, description="Solve/commit tries on version conflicts."
    )
    retention_s: int = Field(
        default=15 * 86400,
        ge=3600,
        description="How long counts, epoch records and recorded demand are kept (over the worker's M days).",
    )
    log_level: Literal["debug", "info", "warning", "error"] = Field(default="info", description="Log level.")
    var_dir: Path = Field(
        default=Path("var"), description="Directory for the service's files (worker run cache)."
    )

    # -- the fleet-sizing worker (`python -m app worker`, docs/FLEET.md) ----------------------------------
    worker_cities: list[str] = Field(
        default_factory=list,
        description="Cities the worker sizes, JSON list (default []: every bundled city).",
    )
    worker_sizes: list[int] = Field(
        default_factory=lambda: [10, 20, 30, 40, 50, 60],
        min_length=1,
        description="Candidate instrumented fleet sizes N1, JSON list.",
    )
    worker_days: int = Field(default=10, ge=2, le=366, description="M: days of demand history per solve.")
    worker_divergence: DivergenceName = Field(
        default="kl", description="phi-divergence of the ambiguity set."
    )
    worker_alpha: float = Field(default=0.05, gt=0.0, lt=1.0, description="Significance level alpha.")
    worker_support: Literal["binned", "samples"] = Field(
        default="binned", description="Support of the samples."
    )
    worker_bins: int = Field(default=10, ge=2, le=1000, description="Bins w of the binned support.")
    worker_completion_target: float | None = Field(
        default=None,
        ge=0.0,
        le=1.0,
        description="Worst-case completion rate of reachable POI tasks every choice must meet (null: off).",
    )
    worker_subsidy_cny_per_vehicle_hour: float = Field(
        default=SUBSIDY_DEFAULT_CNY_PER_VEHICLE_HOUR,
        ge=0.0,
        description="ζ: cost per instrumented vehicle-hour in the total cost (default: a sensor kit "
        "amortized over its service hours plus the driver incentive, derived in docs/FLEET.md).",
    )
    worker_subsidy_sweep: list[float] = Field(
        default_factory=lambda: list(SUBSIDY_SWEEP_DEFAULT),
        max_length=32,
        description="Other values of ζ at which each solve also reports the chosen sizes (the trade-off "
        "curve on the dashboard), JSON list; the configured ζ is always among them.",
    )
    worker_rolling_days: int = Field(
        default=7, ge=2, le=366, description="DRO_RH: history days kept after conditioning on the day so far."
    )
    worker_reach_s: float = Field(
        default=1200.0, ge=0.0, description="Tasks due this close to the horizon's end do not count."
    )
    worker_vary_tasks: bool = Field(
        default=False, description="Redraw synthetic POI tasks every simulated day (default: one set)."
    )
    worker_jobs: int = Field(
        default=2, ge=1, le=256, description="Local processes simulating (size, day) runs (executor local)."
    )
    worker_executor: Literal["local", "dask"] = Field(
        default="local",
        description="Where runs execute: local processes, or the Dask cluster at SD_DASK_SCHEDULER.",
    )
    worker_run_cache: Literal["auto", "disk", "redis"] = Field(
        default="auto",
        description="Finished runs: under SD_VAR_DIR, or in Redis shared by every worker (auto: redis "
        "when SD_STORE=redis).",
    )
    dask_scheduler: str | None = Field(
        default=None,
        pattern=r"^(tcp|tls|inproc|ucx)://\S+$",
        description="Address of the Dask scheduler when SD_WORKER_EXECUTOR=dask, e.g. tcp://scheduler:8786.",
    )
    dask_timeout_s: float = Field(
        default=10.0,
        gt=0.0,
        le=600.0,
        description="Connecting to the Dask scheduler and waiting for a worker.",
    )
    worker_n0: int = Field(default=60, ge=0, description="Ordinary (not instrumented) taxis in every run.")
    worker_tasks: int = Field(default=85, ge=0, description="POI monitoring tasks in every run.")
    worker_rate_per_hour: float | None = Field(
        default=None, gt=0.0, description="Synthetic history: requests per hour (null: the city's default)."
    )
    worker_seed: int = Field(default=0, ge=0, description="Seed of the synthetic history, tasks and taxis.")
    worker_lead_s: int = Field(
        default=3600, ge=60, le=86400, description="Solve an hour this long before it starts."
    )
    worker_poll_s: float = Field(default=5.0, gt=0.0, le=3600.0, description="How often the queue is polled.")
    worker_lock_ttl_s: int = Field(
        default=1800, ge=10, description="Lifetime of a solve lock (a crash frees it)."
    )
    worker_metrics_port: int | None = Field(
        default=None, ge=0, le=65535, description="Serve the worker's Prometheus metrics on this port."
    )
    worker_history: int = Field(
        default=100, ge=1, le=10000, description="Recommendation history kept per city."
    )
    worker_embedded: Literal["auto", "on", "off"] = Field(
        default="auto",
        description="Run the fleet worker inside `python -m app run` (auto: with the memory store, where no "
        "other process could share its results).",
    )
    worker_nice: int = Field(
        default=10,
        ge=0,
        le=19,
        description="Niceness added to the worker's simulation processes, so that epochs come first.",
    )
    worker_heartbeat_s: float = Field(
        default=2.0, gt=0.0, le=300.0, description="How often a running worker writes its heartbeat."
    )
    worker_stale_s: float = Field(
        default=30.0,
        gt=0.0,
        le=86400.0,
        description="A worker whose last heartbeat is older than this is gone: POST fleet/solve answers 503 "
        "no_worker.",
    )

    @field_validator("tokens")
    @classmethod
    def _tokens_sane(cls, value: dict[str, list[Scope]]) -> dict[str, list[Scope]]:
        for token in value:
            if len(token) < 8 or any(c.isspace() for c in token):
                raise ValueError("tokens must be at least 8 characters without whitespace")
        return value

    @model_validator(mode="after")
    def _executor_reachable(self) -> Settings:
        if self.worker_executor == "dask" and self.dask_scheduler is None:
            raise ValueError("SD_WORKER_EXECUTOR=dask needs SD_DASK_SCHEDULER (e.g. tcp://scheduler:8786)")
        return self

    def run_cache_kind(self) -> Literal["disk", "redis"]:
        """Where the worker keeps finished runs (``auto``: Redis when the store is)."""
        if self.worker_run_cache == "auto":
            return "redis" if self.store == "redis" else "disk"
        return self.worker_run_cache

    @model_validator(mode="after")
    def _heartbeat_fresh(self) -> Settings:
        if self.worker_stale_s <= self.worker_heartbeat_s:
            raise ValueError(
                f"SD_WORKER_STALE_S ({self.worker_stale_s}) must exceed SD_WORKER_HEARTBEAT_S "
                f"({self.worker_heartbeat_s}): a live worker would look gone between two beats"
            )
        return self

    def embeds_worker(self) -> bool:
        """Whether ``python -m app run`` runs the fleet worker in its own process (``auto``: on the memory
        store, whose results no other process could read)."""
        if self.worker_embedded == "auto":
            return self.store == "memory"
        return self.worker_embedded == "on"

    @field_validator("worker_subsidy_sweep")
    @classmethod
    def _sweep_sane(cls, value: list[float]) -> list[float]:
        if any(not (v >= 0.0 and v < float("inf")) for v in value):
            raise ValueError("subsidies must be finite and non-negative")
        return sorted(set(value))

    @field_validator("worker_sizes")
    @classmethod
    def _sizes_sane(cls, value: list[int]) -> list[int]:
        if any(x < 1 for x in value) or len(set(value)) != len(value):
            raise ValueError("fleet sizes must be distinct positive integers")
        return sorted(value)
