"""The one settings object of the service (environment prefix ``SD_``)."""

from __future__ import annotations

from pathlib import Path
from typing import Literal

from pydantic import Field, field_validator
from pydantic_settings import BaseSettings, SettingsConfigDict

__all__ = ["Scope", "Settings", "SCOPES"]

Scope = Literal["read", "dispatch"]
SCOPES: tuple[Scope, ...] = ("read", "dispatch")


class Settings(BaseSettings):
    """Service configuration; every field can be set as ``SD_<NAME>`` (e.g. ``SD_STORE=redis``)."""

    model_config = SettingsConfigDict(env_prefix="SD_", env_file=None, extra="forbid", frozen=True)

    store: Literal["memory", "redis"] = Field(default="memory", description="State backend.")
    redis_url: str = Field(default="redis://localhost:6379/0", description="Redis URL when store=redis.")
    redis_prefix: str = Field(
        default="sd", pattern=r"^[A-Za-z0-9_.-]{1,40}$", description="Redis key prefix (one per deployment)."
    )
    host: str = Field(default="127.0.0.1", description="Bind address of `python -m app run`.")
    port: int = Field(default=8000, ge=0, le=65535, description="Port of `python -m app run`.")
    tokens: dict[str, list[Scope]] = Field(
        default_factory=dict,
        description='Bearer tokens and their scopes, JSON: {"tok1": ["read", "dispatch"]}.',
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
    commit_attempts: int = Field(
        default=8, ge=1, le=100, description="Solve/commit tries on version conflicts."
    )
    retention_s: int = Field(
        default=8 * 86400, ge=3600, description="How long counts and epoch records are kept."
    )
    log_level: Literal["debug", "info", "warning", "error"] = Field(default="info", description="Log level.")

    @field_validator("tokens")
    @classmethod
    def _tokens_sane(cls, value: dict[str, list[Scope]]) -> dict[str, list[Scope]]:
        for token in value:
            if len(token) < 8 or any(c.isspace() for c in token):
                raise ValueError("tokens must be at least 8 characters without whitespace")
        return value
