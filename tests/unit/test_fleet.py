"""Fleet sizing (services.fleet): exact hand-solvable cases, ties, the completion target, test-day KPIs, and a
brute-force cross-check on random instances."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.optimize import brentq
from scipy.stats import chi2

from services.dro import DIVERGENCE_NAMES, worst_case
from services.fleet import (
    Ambiguity,
    FleetInputError,
    cheapest_meeting_target,
    deterministic,
    dro,
    dro_rh,
    plan_fleet,
    realized_fixed,
    realized_rolling,
    size_table,
)


def kl_two_point_top_mass(q_top: float, rho: float) -> float:
    """The largest mass ``t`` on the higher of two points with KL((1-t, t) || (1-q, q)) <= rho."""

    def kl(t: float) -> float:
        return t * math.log(t / q_top) + (1 - t) * math.log((1 - t) / (1 - q_top)) - rho

    return float(brentq(kl, q_top, 1 - 1e-15, xtol=1e-15))


def test_constant_samples_have_no_premium_and_pick_the_lowest() -> None:
    samples = {30: [4.0] * 8, 10: [5.0] * 8, 20: [3.0] * 8}
    table = size_table(samples)
    assert table.sizes == (10, 20, 30)
    for row, c in zip(table.rows, (5.0, 3.0, 4.0), strict=True):
        assert row.mean == c and row.worst_case == c and row.premium == 0.0
        assert row.status == "degenerate" and row.n_samples == 8
    assert deterministic(table).size == 20 and deterministic(table).status == "unique"
    assert dro(table).size == 20 and dro(table).objective == 3.0


def test_two_point_kl_worst_case_reverses_the_deterministic_choice() -> None:
    """Size 10: mean 1 with a 10 % tail at 10; size 20: always 1.5. The mean prefers 10; under KL the tail's
    mass can grow to t (closed form below), a worst case of 10 t = 4.56 > 1.5, so DRO prefers 20."""
    samples = {10: [0.0] * 9 + [10.0], 20: [1.5] * 10}
    table = size_table(samples, Ambiguity("kl", 0.05))
    rho = 1.0 / (2 * 10) * float(chi2.ppf(0.95, 10 - 1))  # phi''(1) = 1, M = 10, m = w = 10 bins
    t = kl_two_point_top_mass(0.1, rho)
    row = table.row(10)
    assert row.rho == pytest.approx(rho, rel=1e-12) and row.m == 10
    assert row.mean == pytest.approx(1.0)
    assert row.worst_case == pytest.approx(10.0 * t, rel=1e-9)
    assert row.premium == pytest.approx(10.0 * t - 1.0, rel=1e-9)
    assert deterministic(table).size == 10
    assert dro(table).size == 20 and dro(table).objective == 1.5


@pytest.mark.parametrize("divergence", DIVERGENCE_NAMES)
def test_a_dominated_size_is_never_chosen(divergence: str) -> None:
    """Every sample of size 10 lies above every sample of size 20: any p on the ball keeps that order."""
    rng = np.random.default_rng(3)
    samples = {10: rng.uniform(8.0, 9.0, 12), 20: rng.uniform(1.0, 2.0, 12), 30: rng.uniform(1.5, 2.5, 12)}
    table = size_table(samples, Ambiguity(divergence, 0.05))
    assert table.row(10).worst_case >= 8.0 > 2.0 >= table.row(20).worst_case
    for row in table.rows:
        assert row.worst_case >= row.mean - 1e-12 and row.premium >= -1e-12
    assert dro(table).size != 10 and deterministic(table).size == 20


def test_ties_go_to_the_smaller_fleet() -> None:
    same = [3.0, 1.0, 2.0, 5.0, 4.0]
    table = size_table({40: same, 20: list(same), 60: [9.0] * 5})
    for choice in (deterministic(table), dro(table)):
        assert choice.size == 20 and choice.tied == (20, 40) and choice.status == "tie"
    rolling = dro_rh([table, size_table({20: [2.0, 2.0], 40: [1.0, 1.5]})])
    assert rolling.sizes == (20, 40) and rolling.status == "tie"
    assert [c.method for c in rolling.choices] == ["dro_rh", "dro_rh"]


def test_dro_rh_chooses_per_hour() -> None:
    hour0 = {10: [1.0, 1.2, 1.1], 20: [2.0, 2.1, 2.2]}
    hour1 = {10: [5.0, 6.0, 5.5], 20: [3.0, 3.1, 3.2]}
    rolling = dro_rh([size_table(hour0), size_table(hour1)])
    assert rolling.sizes == (10, 20) and rolling.status == "unique"
    assert rolling.tables[1].row(20).mean == pytest.approx(3.1)


def test_higher_is_better_worst_case_is_the_infimum() -> None:
    """Completion 1.0 on 9 days, 0.0 on one: the infimum moves mass t (the KL closed form) down to 0."""
    samples = {10: [1.0] * 9 + [0.0]}
    table = size_table(samples, sense="max")
    rho = float(chi2.ppf(0.95, 9)) / 20
    t = kl_two_point_top_mass(0.1, rho)
    row = table.row(10)
    assert row.mean == pytest.approx(0.9)
    assert row.worst_case == pytest.approx(1.0 - t, rel=1e-9)
    assert row.premium < 0
    assert size_table({10: [0.5] * 4}, sense="max").row(10).worst_case == 0.5


def test_completion_target_takes_the_cheapest_size_that_meets_it() -> None:
    samples = {30: [1.0] * 6, 10: [0.90] * 6, 20: [0.96] * 6, 40: [0.99] * 6}
    goal = cheapest_meeting_target(samples, 0.95)
    assert goal.status == "met" and goal.size == 20 and goal.target == 0.95
    assert goal.best_size == 30 and goal.best_worst_case == 1.0
    unmet = cheapest_meeting_target(samples, 1.01)
    assert unmet.status == "unmet" and unmet.size is None and unmet.best_size == 30


def test_completion_target_uses_the_worst_case_not_the_mean() -> None:
    """Size 10 averages 0.96 but had a bad day; its worst case falls below 0.95, size 20's does not."""
    samples = {10: [1.0] * 9 + [0.6], 20: [0.97] * 10}
    goal = cheapest_meeting_target(samples, 0.95)
    row = goal.table.row(10)
    assert row.mean == pytest.approx(0.96) and row.worst_case < 0.95
    assert goal.size == 20


def test_plan_fleet_bundles_the_methods() -> None:
    daily = {10: [3.0, 3.5, 2.5], 20: [2.0, 2.2, 2.4]}
    hourly = [{10: [1.0, 1.0], 20: [2.0, 2.0]}, {10: [4.0, 5.0], 20: [2.0, 3.0]}]
    plan = plan_fleet(daily, hourly, completion={10: [0.9, 0.8], 20: [1.0, 1.0]}, target=0.95)
    assert plan.deterministic.size == 20 and plan.dro.size == 20
    assert plan.rolling.sizes == (10, 20)
    assert plan.completion is not None and plan.completion.size == 20
    assert plan_fleet(daily, hourly).completion is None
    with pytest.raises(FleetInputError, match="target"):
        plan_fleet(daily, hourly, target=0.9)


def test_realized_fixed_is_the_mean_daily_kpi() -> None:
    r = realized_fixed({10: [1.0, 2.0, 4.5], 20: [0.0, 0.0, 0.0]}, 10)
    assert r.value == pytest.approx(2.5) and r.per_day == (1.0, 2.0, 4.5) and r.sizes == (10,)
    with pytest.raises(FleetInputError, match="size"):
        realized_fixed({10: [1.0]}, 30)


def test_realized_rolling_by_hand() -> None:
    """Two hours, sizes (10, 20): day 1 (10 + 40) / (10 + 20) h, day 2 (20 + 20) / 30 h."""
    costs = {10: [[10.0, 20.0], [20.0, 0.0]], 20: [[30.0, 40.0], [5.0, 20.0]]}
    r = realized_rolling(costs, [10, 20])
    assert r.per_day == pytest.approx((50.0 / 30.0, 40.0 / 30.0))
    assert r.value == pytest.approx(1.5) and r.sizes == (10, 20)
    with_subsidy = realized_rolling(costs, [10, 20], subsidy_cny_per_vehicle_hour=2.0, interval_hours=0.5)
    assert with_subsidy.per_day == pytest.approx(((50.0 + 2 * 15.0) / 15.0, (40.0 + 2 * 15.0) / 15.0))


def test_realized_rolling_with_one_size_is_the_daily_design_kpi() -> None:
    from services.sim.kpi import design_kpi

    costs = {20: [[3.0, 0.0, 7.5, 1.25]]}
    r = realized_rolling(costs, [20, 20, 20, 20], subsidy_cny_per_vehicle_hour=0.3)
    assert r.value == pytest.approx(design_kpi(11.75, 20, 4.0, 0.3), rel=1e-12)


@pytest.mark.parametrize(
    ("samples", "parameter"),
    [
        ({}, "samples"),
        ({10: [1.0]}, "samples"),
        ({10: [1.0, float("nan")]}, "samples"),
        ({0: [1.0, 2.0]}, "samples"),
        ({10: [[1.0, 2.0]]}, "samples"),
    ],
)
def test_bad_samples_name_the_parameter(samples: dict[int, list[float]], parameter: str) -> None:
    with pytest.raises(FleetInputError) as info:
        size_table(samples)
    assert info.value.parameter == parameter


def test_bad_ambiguity_names_the_parameter() -> None:
    for kwargs, parameter in (
        ({"divergence": "nope"}, "divergence"),
        ({"alpha": 1.0}, "alpha"),
        ({"bins": 1}, "bins"),
        ({"support": "grid"}, "support"),
    ):
        with pytest.raises(FleetInputError) as info:
            Ambiguity(**kwargs)  # type: ignore[arg-type]
        assert info.value.parameter == parameter
    with pytest.raises(FleetInputError, match="sizes_by_hour"):
        realized_rolling({10: [[1.0]]}, [20])
    with pytest.raises(FleetInputError, match="test_hour_cost"):
        realized_rolling({10: [[1.0, 2.0]]}, [10])


def test_brute_force_cross_check_on_random_instances() -> None:
    """Random small instances: every choice equals an exhaustive scan over the sizes of the engine's worst
    case (or the mean), with the smallest of the best taken; the rolling KPI equals a loop over days."""
    rng = np.random.default_rng(11)
    for trial in range(25):
        sizes = sorted(rng.choice(np.arange(1, 9) * 10, size=int(rng.integers(2, 6)), replace=False).tolist())
        m = int(rng.integers(2, 15))
        divergence = DIVERGENCE_NAMES[trial % len(DIVERGENCE_NAMES)]
        amb = Ambiguity(divergence, float(rng.uniform(0.01, 0.3)), "binned" if trial % 3 else "samples", 5)
        # a coarse grid of values makes exact ties between sizes common
        samples = {x: rng.integers(0, 4, m).astype(float) / 2 for x in sizes}
        table = size_table(samples, amb)
        brute = {
            x: worst_case(samples[x], divergence, alpha=amb.alpha, support=amb.support, bins=5).value
            for x in sizes
        }
        best = min(brute.values())
        expect = min(x for x in sizes if math.isclose(brute[x], best, rel_tol=1e-9) or brute[x] == best)
        assert dro(table).size == expect
        means = {x: float(np.mean(samples[x])) for x in sizes}
        assert deterministic(table).size == min(
            x for x in sizes if math.isclose(means[x], min(means.values()))
        )

        n_days, n_hours = int(rng.integers(1, 4)), int(rng.integers(1, 5))
        costs = {x: rng.uniform(0, 50, (n_days, n_hours)) for x in sizes}
        by_hour = [int(rng.choice(sizes)) for _ in range(n_hours)]
        loop = []
        for d in range(n_days):
            num = sum(costs[by_hour[h]][d, h] for h in range(n_hours))
            loop.append(num / sum(by_hour))
        assert realized_rolling(costs, by_hour).per_day == pytest.approx(loop, rel=1e-12)

        target = float(rng.uniform(0.2, 0.9))
        completion = {x: rng.uniform(0.0, 1.0, m) for x in sizes}
        goal = cheapest_meeting_target(completion, target, amb)
        lows = {
            x: -worst_case(-completion[x], divergence, alpha=amb.alpha, support=amb.support, bins=5).value
            for x in sizes
        }
        meeting = [x for x in sizes if lows[x] >= target]
        assert goal.size == (meeting[0] if meeting else None)
