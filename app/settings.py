"""The one settings object of the service (environment prefix ``SD_``), grouped by concern.

``Settings`` holds one model per concern (``settings.store.kind``, ``settings.sizing.days``, ...). Every
setting also has a *flat name*, unique across the groups: its field's name, or the one ``Env`` on the field
gives (``kind`` of ``store`` is ``store``, ``days`` of ``sizing`` is ``worker_days``). Its environment
variable is ``SD_`` and the flat name (``SD_STORE``, ``SD_WORKER_DAYS``); ``with_values(worker_days=7)``,
``Settings(**flat)`` and ``Settings.model_validate(flat)`` take flat names too (a flat name given with its
group's dict wins over the dict's field; a flat name that is also a group's, ``store``, is the flat one
unless its value is a mapping or a group).

Groups: ``server`` (the HTTP server), ``auth`` (bearer tokens), ``cities`` (where bundles are),
``limits`` (a request's arrays), ``dispatch`` (solving epochs), ``store`` (state backend and retention),
``worker`` (the fleet worker's loop), ``sizing`` (what a fleet solve simulates and decides), ``runs``
(where the simulation runs execute, the engine), and ``log_level`` on its own.
"""

from __future__ import annotations

import functools
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, create_model, field_validator, model_validator
from pydantic.fields import FieldInfo
from pydantic_settings import (
    BaseSettings,
    EnvSettingsSource,
    PydanticBaseSettingsSource,
    SettingsConfigDict,
)

from services.kernel.parallel import default_workers

__all__ = [
    "Scope",
    "Settings",
    "SCOPES",
    "DivergenceName",
    "SUBSIDY_DEFAULT_CNY_PER_VEHICLE_HOUR",
    "SUBSIDY_SWEEP_DEFAULT",
    "Env",
    "ServerSettings",
    "AuthSettings",
    "CitySettings",
    "LimitSettings",
    "DispatchSettings",
    "StoreSettings",
    "WorkerSettings",
    "SizingSettings",
    "RunSettings",
    "flat_names",
]

Scope = Literal["read", "dispatch", "admin"]
SCOPES: tuple[Scope, ...] = ("read", "dispatch", "admin")
DivergenceName = Literal["kl", "burg", "j", "chi2", "modified_chi2", "hellinger", "variation"]

SUBSIDY_DEFAULT_CNY_PER_VEHICLE_HOUR = 0.94
"""ζ's default: a low-cost sensor kit amortized over its service hours plus the incentive that keeps an
instrumented driver accepting orders (the sources and the arithmetic: docs/FLEET.md, "The subsidy ζ")."""
SUBSIDY_SWEEP_DEFAULT = (0.0, 0.2, 0.3, 0.4, 0.5, 0.75, 1.0, 1.5, 2.0, 3.0)
"""The subsidies at which every solve also reports each method's choice (the trade-off curve)."""


@dataclass(frozen=True, slots=True)
class Env:
    """A setting's flat name when it is not its field's: its environment variable is ``SD_`` and it, upper
    case (``Annotated[int, Env("worker_days")]``)."""

    name: str


class _Group(BaseModel):
    """One concern's settings: frozen, unknown names refused."""

    model_config = ConfigDict(extra="forbid", frozen=True)


class ServerSettings(_Group):
    """The HTTP server of ``python -m app run``: bind address, deadlines, the connection cap, the body."""

    host: str = Field(default="127.0.0.1", description="Bind address of `python -m app run`.")
    port: int = Field(default=8000, ge=0, le=65535, description="Port of `python -m app run`.")
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
    max_body_bytes: int = Field(
        default=1 << 20, ge=1024, description="Largest accepted request body (413 above)."
    )


class AuthSettings(_Group):
    """Who may call: bearer tokens and their scopes."""

    tokens: dict[str, list[Scope]] = Field(
        default_factory=dict,
        description='Bearer tokens and their scopes (read, dispatch, admin), JSON: {"tok1": ["read"]}.',
    )

    @field_validator("tokens")
    @classmethod
    def _tokens_sane(cls, value: dict[str, list[Scope]]) -> dict[str, list[Scope]]:
        for token in value:
            if len(token) < 8 or any(c.isspace() for c in token):
                raise ValueError("tokens must be at least 8 characters without whitespace")
        return value


class CitySettings(_Group):
    """Where the cities' bundles are (``app.adapters.city_registry.CityRegistry``)."""

    user_dir: Annotated[Path, Env("cities_dir")] = Field(
        default=Path("var/cities"), description="Directory of user-imported cities."
    )
    bundled_dir: Annotated[Path | None, Env("bundled_cities_dir")] = Field(
        default=None, description="Directory of bundled cities (default: the package's app/data/cities)."
    )


class LimitSettings(_Group):
    """The longest arrays a request may carry."""

    max_riders: int = Field(default=2000, ge=1, description="Most riders in one epoch.")
    max_taxis: int = Field(default=5000, ge=1, description="Most taxis in one epoch.")
    max_tasks: int = Field(default=1000, ge=1, description="Most tasks in one POST.")


class DispatchSettings(_Group):
    """Solving epochs: threads, solves at once, commit tries, how far ahead an epoch may be dated."""

    workers: Annotated[int, Env("dispatch_workers")] = Field(
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
    epoch_max_ahead_s: int = Field(
        default=86400,
        ge=0,
        description="Latest accepted epoch time, in seconds after the service clock (422 beyond; older "
        "epochs are always accepted).",
    )


class StoreSettings(_Group):
    """The state backend: memory or Redis, its bounds, and how long what it keeps is kept."""

    kind: Annotated[Literal["memory", "redis"], Env("store")] = Field(
        default="memory", description="State backend."
    )
    redis_url: str = Field(
        default="redis://localhost:6379/0",
        description="Redis URL when store=redis (in cluster mode: any node of the cluster).",
    )
    redis_mode: Literal["standalone", "cluster"] = Field(
        default="standalone", description="One Redis server, or a Redis Cluster (redis-py's cluster client)."
    )
    redis_prefix: str = Field(
        default="sd", pattern=r"^[A-Za-z0-9_.-]{1,40}$", description="Redis key prefix (one per deployment)."
    )
    timeout_s: Annotated[float, Env("store_timeout_s")] = Field(
        default=1.0,
        gt=0.0,
        le=60.0,
        description="Bound on every connect, read and write of the Redis store (a frozen Redis: 503).",
    )
    concurrency: Annotated[int, Env("store_concurrency")] = Field(
        default=16,
        ge=1,
        le=1024,
        description="Store calls in flight at once per process; a request finding all taken waits at most "
        "store_queue_s, then gets 503 (a frozen store never ties up every worker thread).",
    )
    queue_s: Annotated[float, Env("store_queue_s")] = Field(
        default=0.1, ge=0.0, le=60.0, description="How long a store call waits for a free slot (then 503)."
    )
    retention_s: int = Field(
        default=15 * 86400,
        ge=3600,
        description="How long counts, epoch records and recorded demand are kept (over the worker's M days).",
    )


class WorkerSettings(_Group):
    """The fleet worker's loop (``python -m app worker``, or inside ``python -m app run``): its cities, its
    schedule, its locks, heartbeat and metrics."""

    cities: Annotated[list[str], Env("worker_cities")] = Field(
        default_factory=list,
        description="Cities the worker sizes, JSON list (default []: every bundled city).",
    )
    lead_s: Annotated[int, Env("worker_lead_s")] = Field(
        default=3600, ge=60, le=86400, description="Solve an hour this long before it starts."
    )
    poll_s: Annotated[float, Env("worker_poll_s")] = Field(
        default=5.0, gt=0.0, le=3600.0, description="How often the queue is polled."
    )
    lock_ttl_s: Annotated[int, Env("worker_lock_ttl_s")] = Field(
        default=1800, ge=10, description="Lifetime of a solve lock (a crash frees it)."
    )
    metrics_port: Annotated[int | None, Env("worker_metrics_port")] = Field(
        default=None, ge=0, le=65535, description="Serve the worker's Prometheus metrics on this port."
    )
    history: Annotated[int, Env("worker_history")] = Field(
        default=100, ge=1, le=10000, description="Recommendation history kept per city."
    )
    embedded: Annotated[Literal["auto", "on", "off"], Env("worker_embedded")] = Field(
        default="auto",
        description="Run the fleet worker inside `python -m app run` (auto: with the memory store, where no "
        "other process could share its results).",
    )
    heartbeat_s: Annotated[float, Env("worker_heartbeat_s")] = Field(
        default=2.0, gt=0.0, le=300.0, description="How often a running worker writes its heartbeat."
    )
    stale_s: Annotated[float, Env("worker_stale_s")] = Field(
        default=30.0,
        gt=0.0,
        le=86400.0,
        description="A worker whose last heartbeat is older than this is gone: POST fleet/solve answers 503 "
        "no_worker.",
    )

    @model_validator(mode="after")
    def _heartbeat_fresh(self) -> WorkerSettings:
        if self.stale_s <= self.heartbeat_s:
            raise ValueError(
                f"SD_WORKER_STALE_S ({self.stale_s}) must exceed SD_WORKER_HEARTBEAT_S "
                f"({self.heartbeat_s}): a live worker would look gone between two beats"
            )
        return self


class SizingSettings(_Group):
    """What a fleet solve simulates and how it decides (docs/FLEET.md); a city's ``city.json`` may set
    some for itself (``app.usecases.fleet_history.SizingConfig``)."""

    sizes: Annotated[list[int], Env("worker_sizes")] = Field(
        default_factory=lambda: [10, 20, 30, 40, 50, 60],
        min_length=1,
        description="Candidate instrumented fleet sizes N1, JSON list.",
    )
    days: Annotated[int, Env("worker_days")] = Field(
        default=10, ge=2, le=366, description="M: days of demand history per solve."
    )
    divergence: Annotated[DivergenceName, Env("worker_divergence")] = Field(
        default="kl", description="phi-divergence of the ambiguity set."
    )
    alpha: Annotated[float, Env("worker_alpha")] = Field(
        default=0.05, gt=0.0, lt=1.0, description="Significance level alpha."
    )
    support: Annotated[Literal["binned", "samples"], Env("worker_support")] = Field(
        default="binned", description="Support of the samples."
    )
    bins: Annotated[int, Env("worker_bins")] = Field(
        default=10, ge=2, le=1000, description="Bins w of the binned support."
    )
    completion_target: Annotated[float | None, Env("worker_completion_target")] = Field(
        default=None,
        ge=0.0,
        le=1.0,
        description="Worst-case completion rate of reachable POI tasks every choice must meet (null: off).",
    )
    subsidy_cny_per_vehicle_hour: Annotated[float, Env("worker_subsidy_cny_per_vehicle_hour")] = Field(
        default=SUBSIDY_DEFAULT_CNY_PER_VEHICLE_HOUR,
        ge=0.0,
        description="ζ: cost per instrumented vehicle-hour in the total cost (default: a sensor kit "
        "amortized over its service hours plus the driver incentive, derived in docs/FLEET.md).",
    )
    subsidy_sweep: Annotated[list[float], Env("worker_subsidy_sweep")] = Field(
        default_factory=lambda: list(SUBSIDY_SWEEP_DEFAULT),
        max_length=32,
        description="Other values of ζ at which each solve also reports the chosen sizes (the trade-off "
        "curve on the dashboard), JSON list; the configured ζ is always among them.",
    )
    rolling_days: Annotated[int, Env("worker_rolling_days")] = Field(
        default=7, ge=2, le=366, description="DRO_RH: history days kept after conditioning on the day so far."
    )
    reach_s: Annotated[float, Env("worker_reach_s")] = Field(
        default=1200.0, ge=0.0, description="Tasks due this close to the horizon's end do not count."
    )
    vary_tasks: Annotated[bool, Env("worker_vary_tasks")] = Field(
        default=False, description="Redraw synthetic POI tasks every simulated day (default: one set)."
    )
    n0: Annotated[int, Env("worker_n0")] = Field(
        default=60, ge=0, description="Ordinary (not instrumented) taxis in every run."
    )
    n_tasks: Annotated[int, Env("worker_tasks")] = Field(
        default=85, ge=0, description="POI monitoring tasks in every run."
    )
    rate_per_hour: Annotated[float | None, Env("worker_rate_per_hour")] = Field(
        default=None, gt=0.0, description="Synthetic history: requests per hour (null: the city's default)."
    )
    seed: Annotated[int, Env("worker_seed")] = Field(
        default=0, ge=0, description="Seed of the synthetic history, tasks and taxis."
    )

    @field_validator("subsidy_sweep")
    @classmethod
    def _sweep_sane(cls, value: list[float]) -> list[float]:
        if any(not (v >= 0.0 and v < float("inf")) for v in value):
            raise ValueError("subsidies must be finite and non-negative")
        return sorted(set(value))

    @field_validator("sizes")
    @classmethod
    def _sizes_sane(cls, value: list[int]) -> list[int]:
        if any(x < 1 for x in value) or len(set(value)) != len(value):
            raise ValueError("fleet sizes must be distinct positive integers")
        return sorted(value)


class RunSettings(_Group):
    """Where the fleet solve's simulation runs execute (the engine) and where finished runs are kept."""

    jobs: Annotated[int, Env("worker_jobs")] = Field(
        default=2, ge=1, le=256, description="Local processes simulating (size, day) runs (executor local)."
    )
    executor: Annotated[Literal["local", "dask"], Env("worker_executor")] = Field(
        default="local",
        description="Where runs execute: local processes, or the Dask cluster at SD_DASK_SCHEDULER.",
    )
    nice: Annotated[int, Env("worker_nice")] = Field(
        default=10,
        ge=0,
        le=19,
        description="Niceness added to the worker's simulation processes, so that epochs come first.",
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
    cache: Annotated[Literal["auto", "disk", "redis"], Env("worker_run_cache")] = Field(
        default="auto",
        description="Finished runs: under SD_VAR_DIR, or in Redis shared by every worker (auto: redis "
        "when SD_STORE=redis).",
    )
    var_dir: Path = Field(
        default=Path("var"), description="Directory for the service's files (worker run cache)."
    )

    @model_validator(mode="after")
    def _executor_reachable(self) -> RunSettings:
        if self.executor == "dask" and self.dask_scheduler is None:
            raise ValueError("SD_WORKER_EXECUTOR=dask needs SD_DASK_SCHEDULER (e.g. tcp://scheduler:8786)")
        return self


class Settings(BaseSettings):
    """Service configuration by concern; every setting can be set as ``SD_<FLAT NAME>`` (e.g.
    ``SD_STORE=redis``, ``SD_WORKER_DAYS=7``; the module says how names map)."""

    model_config = SettingsConfigDict(env_prefix="SD_", env_file=None, extra="forbid", frozen=True)

    server: ServerSettings = Field(default_factory=ServerSettings)
    auth: AuthSettings = Field(default_factory=AuthSettings)
    cities: CitySettings = Field(default_factory=CitySettings)
    limits: LimitSettings = Field(default_factory=LimitSettings)
    dispatch: DispatchSettings = Field(default_factory=DispatchSettings)
    store: StoreSettings = Field(default_factory=StoreSettings)
    worker: WorkerSettings = Field(default_factory=WorkerSettings)
    sizing: SizingSettings = Field(default_factory=SizingSettings)
    runs: RunSettings = Field(default_factory=RunSettings)
    log_level: Literal["debug", "info", "warning", "error"] = Field(default="info", description="Log level.")

    @classmethod
    def settings_customise_sources(
        cls,
        settings_cls: type[BaseSettings],
        init_settings: PydanticBaseSettingsSource,
        env_settings: PydanticBaseSettingsSource,
        dotenv_settings: PydanticBaseSettingsSource,
        file_secret_settings: PydanticBaseSettingsSource,
    ) -> tuple[PydanticBaseSettingsSource, ...]:
        """The keywords first, then the ``SD_*`` variables by their flat names."""
        return init_settings, _FlatEnvSource(settings_cls)

    @model_validator(mode="before")
    @classmethod
    def _nest_flat_names(cls, data: Any) -> Any:
        """Flat names (``worker_days=7``) into their groups; a flat name wins over its group's field given
        in a group's dict (the keywords' flat names over the environment)."""
        if not isinstance(data, Mapping):
            return data
        table = flat_names()
        out = dict(data)
        for key, value in data.items():
            if key not in table or (key in cls.model_fields and _is_group_value(value)):
                continue
            group, field = table[key]
            if group is None:
                continue
            del out[key]
            into = out.get(group, {})
            into = into.model_dump() if isinstance(into, BaseModel) else dict(into)
            out[group] = into | {field: value}
        return out

    def with_values(self, **flat: Any) -> Settings:
        """These settings with some values replaced, by their flat names, validated like the environment."""
        return type(self).model_validate(self.model_dump() | flat)

    def run_cache_kind(self) -> Literal["disk", "redis"]:
        """Where the worker keeps finished runs (``auto``: Redis when the store is)."""
        if self.runs.cache == "auto":
            return "redis" if self.store.kind == "redis" else "disk"
        return self.runs.cache

    def embeds_worker(self) -> bool:
        """Whether ``python -m app run`` runs the fleet worker in its own process (``auto``: on the memory
        store, whose results no other process could read)."""
        if self.worker.embedded == "auto":
            return self.store.kind == "memory"
        return self.worker.embedded == "on"


def _is_group_value(value: Any) -> bool:
    return isinstance(value, BaseModel | Mapping)


def _flat_name(name: str, info: FieldInfo) -> str:
    return next((m.name for m in info.metadata if isinstance(m, Env)), name)


@functools.cache
def flat_names() -> dict[str, tuple[str | None, str]]:
    """Every setting by its flat name: ``(group, field)`` (group ``None``: a field of ``Settings``)."""
    table: dict[str, tuple[str | None, str]] = {}

    def add(flat: str, where: tuple[str | None, str]) -> None:
        if flat in table:
            raise TypeError(f"two settings share the flat name {flat!r}: {table[flat]} and {where}")
        table[flat] = where

    for name, info in Settings.model_fields.items():
        group = info.annotation
        if isinstance(group, type) and issubclass(group, _Group):
            for field, sub in group.model_fields.items():
                add(_flat_name(field, sub), (name, field))
        else:
            add(_flat_name(name, info), (None, name))
    return table


class _FlatSettings(BaseSettings):
    """The base of the flat class ``_FlatEnvSource`` reads the environment with."""

    model_config = SettingsConfigDict(env_prefix="SD_", env_file=None)


class _FlatEnvSource(EnvSettingsSource):
    """The ``SD_*`` variables by flat name, parsed as pydantic-settings parses a flat settings class (JSON
    for lists and dicts), handed on in their groups."""

    def __init__(self, settings_cls: type[BaseSettings]) -> None:
        groups = {name: info for name, info in settings_cls.model_fields.items()}
        fields: dict[str, Any] = {}
        for flat, (group, field) in flat_names().items():
            info = groups[field] if group is None else _group_fields(groups[group])[field]
            fields[flat] = (info.annotation, None)
        super().__init__(create_model("FlatSettings", __base__=_FlatSettings, **fields))

    def __call__(self) -> dict[str, Any]:
        out: dict[str, Any] = {}
        table = flat_names()
        for flat, value in super().__call__().items():
            group, field = table[flat]
            if group is None:
                out[field] = value
            else:
                out.setdefault(group, {})[field] = value
        return out


def _group_fields(info: FieldInfo) -> dict[str, FieldInfo]:
    group = info.annotation
    assert isinstance(group, type) and issubclass(group, _Group)
    return group.model_fields
