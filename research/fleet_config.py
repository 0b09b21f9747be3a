"""The fleet-sizing experiment's configuration: the fleet variants, the scenarios, the days, the subsidies
(``research.fleet`` runs it, ``research.fleet_report`` writes its report)."""

from __future__ import annotations

from dataclasses import dataclass

from app.runs import RunSpec
from app.settings import SUBSIDY_DEFAULT_CNY_PER_VEHICLE_HOUR

__all__ = ["DEFAULT_ZETAS", "FleetExperimentConfig", "Variant"]


@dataclass(frozen=True, slots=True)
class Variant:
    """How the ordinary fleet is set: ``n0`` taxis beside every N1, or ``total - N1`` (fixed total fleet)."""

    name: str
    n0: int | None = None
    total: int | None = None

    def n0_for(self, n1: int) -> int:
        """Ordinary taxis beside ``n1`` instrumented ones."""
        if self.total is not None:
            return self.total - n1
        assert self.n0 is not None
        return self.n0


DEFAULT_ZETAS = (0.0, 0.5, SUBSIDY_DEFAULT_CNY_PER_VEHICLE_HOUR, 2.0)
"""The subsidies the experiment decides at, the worker's default ζ among them (docs/FLEET.md)."""


@dataclass(frozen=True, slots=True)
class FleetExperimentConfig:
    city: str = "chengdu"
    scenarios: tuple[int, ...] = (1, 2, 3)
    sizes: tuple[int, ...] = (10, 20, 30, 40, 50, 60)
    train_days: int = 10
    test_days: int = 10
    seed: int = 0
    n0: int = 60
    total_fleet: int | None = 120  # the fixed-total-fleet variant (None: skip it)
    n_tasks: int = 85
    vary_tasks: bool = False
    divergence: str = "kl"
    alpha: float = 0.05
    zetas: tuple[float, ...] = DEFAULT_ZETAS
    keep: int = 7  # DRO_RH: history days kept after conditioning on the hours observed
    reach_s: float = 1200.0  # tasks due this close to the end of the horizon do not count for completion
    completion_target: float | None = None
    sweep_alphas: tuple[float, ...] = (0.01, 0.05, 0.1, 0.25)

    def __post_init__(self) -> None:
        if self.train_days < 2 or self.test_days < 1:
            raise ValueError("need at least 2 training days and 1 test day")
        if not self.scenarios or not self.sizes or not self.zetas:
            raise ValueError("need at least one scenario, one size and one subsidy")
        if self.total_fleet is not None and self.total_fleet < max(self.sizes):
            raise ValueError(f"total fleet {self.total_fleet} is below the largest N1 {max(self.sizes)}")
        if self.keep < 2:
            raise ValueError("keep must be at least 2 days")

    @property
    def train(self) -> range:
        return range(1, 1 + self.train_days)

    @property
    def test(self) -> range:
        return range(1 + self.train_days, 1 + self.train_days + self.test_days)

    @property
    def variants(self) -> tuple[Variant, ...]:
        fixed = (Variant(f"N0 = {self.n0}", n0=self.n0),)
        if self.total_fleet is None:
            return fixed
        return (*fixed, Variant(f"N0 + N1 = {self.total_fleet}", total=self.total_fleet))

    def spec(self, variant: Variant, scenario: int, n1: int, day: int) -> RunSpec:
        return RunSpec(
            self.city, scenario, n1, variant.n0_for(n1), self.seed, day, True, False, self.n_tasks,
            tasks_day=None if self.vary_tasks else 0,
        )  # fmt: skip
