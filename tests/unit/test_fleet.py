"""Fleet sizing (services.fleet.sizing, services.fleet.evaluation): the total-cost objective and the subsidy,
exact hand-solvable cases, ties, the completion target, the rolling horizon's conditioning, realized test-day
costs, and brute-force cross-checks against the DRO engine on random instances."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.optimize import brentq
from scipy.stats import chi2

from services.fleet.dro import DIVERGENCE_NAMES, worst_case
from services.fleet.evaluation import realized_by_hour, realized_fixed, rolling_decisions
from services.fleet.sizing import (
    Ambiguity,
    CandidateTable,
    CostModel,
    DayOutcomes,
    FleetInputError,
    candidate_table,
    choose,
    plan_fleet,
    rolling_hour,
    similar_days,
    size_table,
    subsidy_sweep,
)


def outcomes(cost: list[list[float]], due: int = 0, done: int = 0) -> DayOutcomes:
    """Days x hours of Step 3 cost with ``due`` reachable tasks an hour, ``done`` of them completed."""
    shape = np.shape(cost)
    return DayOutcomes.of(cost, np.full(shape, due), np.full(shape, done))


def one_hour(samples: dict[int, list[float]], amb: Ambiguity | None = None) -> CandidateTable:
    """A candidate table whose total cost samples are ``samples`` (one interval a day, no subsidy)."""
    return candidate_table({x: outcomes([[v] for v in vals]) for x, vals in samples.items()}, amb)


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
    det, robust = choose(one_hour(samples), "deterministic"), choose(one_hour(samples), "dro")
    assert det.size == 20 and det.status == "unique" and det.target_met is None
    assert robust.size == 20 and robust.objective == 3.0


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
    cand = one_hour(samples, Ambiguity("kl", 0.05))
    assert choose(cand, "deterministic").size == 10
    assert choose(cand, "dro").size == 20 and choose(cand, "dro").objective == 1.5


@pytest.mark.parametrize("divergence", DIVERGENCE_NAMES)
def test_a_dominated_size_is_never_chosen(divergence: str) -> None:
    """Every sample of size 10 lies above every sample of size 20: any p on the ball keeps that order."""
    rng = np.random.default_rng(3)
    samples = {10: rng.uniform(8.0, 9.0, 12), 20: rng.uniform(1.0, 2.0, 12), 30: rng.uniform(1.5, 2.5, 12)}
    table = size_table(samples, Ambiguity(divergence, 0.05))
    assert table.row(10).worst_case >= 8.0 > 2.0 >= table.row(20).worst_case
    for row in table.rows:
        assert row.worst_case >= row.mean - 1e-12 and row.premium >= -1e-12
    cand = one_hour({x: list(v) for x, v in samples.items()}, Ambiguity(divergence, 0.05))
    assert choose(cand, "dro").size != 10 and choose(cand, "deterministic").size == 20


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
            Ambiguity(**kwargs)
        assert info.value.parameter == parameter
    with pytest.raises(FleetInputError, match="size"):
        realized_fixed({10: outcomes([[1.0]])}, 20)
    with pytest.raises(FleetInputError, match="subsidy"):
        CostModel(-1.0)
    with pytest.raises(FleetInputError, match="samples"):
        DayOutcomes.of([[1.0, 2.0]], [[1, 1]], [[2, 0]])  # done > due
    with pytest.raises(FleetInputError, match="target"):
        choose(candidate_table({10: outcomes([[1.0], [2.0]])}), "dro", 1.5)


# ------------------------------------------------------------------------------ the total-cost objective


def test_total_cost_per_hour_by_hand() -> None:
    """Two days of two half-hour intervals, ζ = 0.5: day cost / 1 h + 0.5 x; one interval: cost / 0.5 h."""
    o = {10: outcomes([[3.0, 1.0], [2.0, 2.0]]), 20: outcomes([[1.0, 1.0], [0.0, 4.0]])}
    table = candidate_table(o, costs=CostModel(0.5, interval_hours=0.5))
    assert table.cost_samples[10] == pytest.approx([4.0 + 5.0, 4.0 + 5.0])
    assert table.cost_samples[20] == pytest.approx([2.0 + 10.0, 4.0 + 10.0])
    assert table.row(20).design_kpi_mean == pytest.approx(13.0 / 20)
    hour1 = candidate_table(o, costs=CostModel(0.5, interval_hours=0.5), hour=1)
    assert hour1.cost_samples[20] == pytest.approx([2.0 + 10.0, 8.0 + 10.0])


def test_the_subsidy_moves_the_argmin_and_the_design_kpi_never_does() -> None:
    """Step 3 cost falls slowly with N1 (30, 25, 22 CNY/h): at ζ = 0 the largest fleet is cheapest, at ζ = 1
    (totals 40, 45, 52) the smallest; the per-vehicle KPI (3.0, 1.25, 0.73 at ζ = 0) always picks 30."""
    rng = np.random.default_rng(5)
    o = {
        x: outcomes((c + rng.uniform(-0.5, 0.5, (10, 4))).tolist())
        for x, c in ((10, 30.0), (20, 25.0), (30, 22.0))
    }
    for zeta, want in ((0.0, 30), (0.25, 30), (1.0, 10), (2.0, 10)):
        table = candidate_table(o, costs=CostModel(zeta))
        assert choose(table, "dro").size == want and choose(table, "deterministic").size == want, zeta
        per_vehicle = min(table.rows, key=lambda r: r.design_kpi_worst_case)
        assert per_vehicle.size == 30


def test_the_subsidy_shifts_every_worst_case_by_zeta_x() -> None:
    """A constant added to every sample shifts the worst case by that constant, for every divergence."""
    rng = np.random.default_rng(8)
    o = {x: outcomes(rng.uniform(0, 40, (12, 4)).tolist()) for x in (10, 40)}
    for name in DIVERGENCE_NAMES:
        amb = Ambiguity(name, 0.1)
        base, paid = candidate_table(o, amb), candidate_table(o, amb, CostModel(1.5))
        for x in (10, 40):
            assert paid.row(x).cost.worst_case == pytest.approx(
                base.row(x).cost.worst_case + 1.5 * x, rel=1e-7
            )


def test_the_sweep_finds_the_middle_size_between_the_break_evens() -> None:
    """Step 3 cost 30, 25, 22 CNY/h at N1 = 10, 20, 30 on every day and hour: 30 is cheapest below ζ = 0.3
    (25 + 20ζ = 22 + 30ζ), 10 above ζ = 0.5 (30 + 10ζ = 25 + 20ζ), 20 in between; every method agrees (the
    samples have no spread, so the worst case is the mean)."""
    o = {x: outcomes([[c] * 4 for _ in range(5)]) for x, c in ((10, 30.0), (20, 25.0), (30, 22.0))}
    points = subsidy_sweep(o, np.full((5, 4), 100.0), [1.0, 0.0, 0.35, 0.35], hour=2, keep=3)
    assert [p.subsidy_cny_per_vehicle_hour for p in points] == [0.0, 0.35, 1.0]
    for p, want in zip(points, (30, 20, 10), strict=True):
        assert (p.deterministic.size, p.dro.size, p.dro_rh.size) == (want, want, want)
    assert points[1].dro.objective == pytest.approx(25.0 + 20 * 0.35)


def test_each_point_of_the_sweep_is_the_plan_at_that_subsidy() -> None:
    rng = np.random.default_rng(21)
    o = {x: outcomes((rng.uniform(20, 40, (8, 4)) - 0.2 * x).tolist(), 3, 3) for x in (10, 20, 30, 40)}
    volumes = rng.uniform(50, 150, (8, 4))
    observed = volumes[3, :2] * 1.05
    zetas = [0.0, 0.1, 0.2, 0.3, 0.5, 1.0]
    points = subsidy_sweep(o, volumes, zetas, hour=3, interval_hours=0.5, observed=observed, keep=5)
    sizes = []
    for z, p in zip(zetas, points, strict=True):
        plan = plan_fleet(o, volumes, costs=CostModel(z, 0.5), observed=observed, keep=5)
        assert p.deterministic == plan.deterministic and p.dro == plan.dro
        assert p.dro_rh == plan.rolling[3].choice
        assert plan.point(3) == p
        sizes.append(p.dro.size)
    assert sizes == sorted(sizes, reverse=True)  # a dearer vehicle-hour never buys a larger fleet


def test_a_bad_subsidy_in_the_sweep_names_the_parameter() -> None:
    o = {10: outcomes([[1.0], [2.0]]), 20: outcomes([[1.0], [2.0]])}
    with pytest.raises(FleetInputError, match="subsidy_cny_per_vehicle_hour"):
        subsidy_sweep(o, [[1.0], [1.0]], [0.0, -0.5], hour=0)


def test_rows_carry_the_engine_values_and_the_box_lp() -> None:
    rng = np.random.default_rng(2)
    o = {x: outcomes(rng.uniform(0, 30, (9, 3)).tolist(), due=4, done=3) for x in (10, 20)}
    amb = Ambiguity("burg", 0.1)
    table = candidate_table(o, amb, CostModel(0.5))
    for x in (10, 20):
        f = table.cost_samples[x]
        row = table.row(x)
        assert row.cost.worst_case == pytest.approx(worst_case(f, "burg", alpha=0.1).value, rel=1e-12)
        assert row.box_lp_worst_case == pytest.approx(worst_case(f, "burg", alpha=0.1, method="box_lp").value)
        assert row.completion is not None and row.completion.mean == pytest.approx(0.75)
        assert row.completion.worst_case == pytest.approx(0.75)  # constant samples: no premium
    assert table.days == tuple(range(9))


# ------------------------------------------------------------------------------------ the completion target


def test_the_target_restricts_each_method_to_the_sizes_meeting_it() -> None:
    """Size 10 is cheapest but completes 2 of 4 due tasks; 20 completes 4 of 4; 30 also, at a higher cost."""
    o = {
        10: outcomes([[1.0], [1.2], [1.1]], due=4, done=2),
        20: outcomes([[2.0], [2.1], [2.2]], due=4, done=4),
        30: outcomes([[3.0], [3.0], [3.0]], due=4, done=4),
    }
    table = candidate_table(o)
    for method in ("deterministic", "dro", "box_lp"):
        assert choose(table, method).size == 10
        c = choose(table, method, 0.9)
        assert c.size == 20 and c.target_met is True
    unmet = choose(candidate_table({10: o[10]}), "dro", 0.9)
    assert unmet.size == 10 and unmet.target_met is False


def test_the_target_uses_the_worst_case_for_dro_and_the_mean_for_deterministic() -> None:
    """Size 10 completes everything on 9 days and 1 of 2 on one: mean 0.95, worst case below 0.95."""
    due = np.full((10, 1), 2)
    done = due.copy()
    done[9, 0] = 1
    o = {10: DayOutcomes.of(np.ones((10, 1)), due, done), 20: outcomes([[2.0]] * 10, due=2, done=2)}
    table = candidate_table(o)
    row = table.row(10).completion
    assert row is not None and row.mean == pytest.approx(0.95) and row.worst_case < 0.95
    assert choose(table, "deterministic", 0.95).size == 10
    assert choose(table, "dro", 0.95).size == 20


def test_no_tasks_means_no_completion_and_the_target_is_moot() -> None:
    table = candidate_table({10: outcomes([[1.0], [2.0]]), 20: outcomes([[0.5], [0.5]])})
    assert table.completion_samples is None and table.row(10).completion is None
    assert choose(table, "dro", 0.99).size == 20 and choose(table, "dro", 0.99).target_met is None


def test_ties_go_to_the_smaller_fleet() -> None:
    same = [[3.0], [1.0], [2.0], [5.0], [4.0]]
    table = candidate_table({40: outcomes(same), 20: outcomes(same), 60: outcomes([[9.0]] * 5)})
    for method in ("deterministic", "dro"):
        c = choose(table, method)
        assert c.size == 20 and c.tied == (20, 40) and c.status == "tie"


# -------------------------------------------------------------------------------------- rolling horizon


def test_similar_days_by_hand() -> None:
    volumes = [[10, 12, 9], [50, 60, 40], [11, 30, 30], [48, 10, 10]]
    assert similar_days(volumes, [], 2) == (0, 1, 2, 3)  # nothing observed yet
    assert similar_days(volumes, [10], 2) == (0, 2)
    assert similar_days(volumes, [49], 2) == (1, 3)
    assert similar_days(volumes, [49, 58], 2) == (1, 2)  # day 2's second hour (30) beats day 3's (10)
    assert similar_days(volumes, [10], 9) == (0, 1, 2, 3)  # keep >= M
    # ties (equal distance) go to the lower index
    assert similar_days([[9.0], [9.0], [9.0]], [9.0], 2) == (0, 1)
    with pytest.raises(FleetInputError, match="keep"):
        similar_days(volumes, [10], 1)
    with pytest.raises(FleetInputError, match="observed"):
        similar_days(volumes, [1, 2, 3, 4], 2)


def _two_kinds_of_day() -> tuple[dict[int, DayOutcomes], list[list[float]]]:
    """Days 0, 1 are quiet (10 requests an hour), 2, 3 busy (50). In hour 1 a fleet of 10 costs 5 on quiet
    days and 50 on busy ones, a fleet of 20 costs 10 and 20."""
    o = {
        10: outcomes([[1.0, 5.0], [1.0, 5.0], [1.0, 50.0], [1.0, 50.0]]),
        20: outcomes([[2.0, 10.0], [2.0, 10.0], [2.0, 20.0], [2.0, 20.0]]),
    }
    return o, [[10, 10], [10, 10], [50, 50], [50, 50]]


def test_a_later_hours_choice_follows_what_the_day_has_shown() -> None:
    o, volumes = _two_kinds_of_day()
    before = rolling_hour(o, volumes, [], 1, keep=2)
    quiet = rolling_hour(o, volumes, [11], 1, keep=2)
    busy = rolling_hour(o, volumes, [47], 1, keep=2)
    assert before.observed_hours == 0 and before.table.days == (0, 1, 2, 3) and before.choice.size == 20
    assert quiet.table.days == (0, 1) and quiet.choice.size == 10 and quiet.choice.objective == 5.0
    assert busy.table.days == (2, 3) and busy.choice.size == 20 and busy.choice.objective == 20.0
    # hour 0 cannot use hour 0's own volume
    assert rolling_hour(o, volumes, [11], 0, keep=2).table.days == (0, 1, 2, 3)
    plan = plan_fleet(o, volumes, observed=[11], keep=2)
    assert plan.rolling_sizes == (10, 10) and plan.rolling[1].table.days == (0, 1)


def test_rolling_decisions_never_peek_at_the_hour_they_decide() -> None:
    """Changing a test day's volume of hour h or later leaves the decisions for hours <= h unchanged."""
    rng = np.random.default_rng(4)
    o = {x: outcomes(rng.uniform(0, 30, (8, 4)).tolist()) for x in (10, 20, 30)}
    volumes = rng.integers(20, 80, (8, 4)).astype(float)
    day = rng.integers(20, 80, 4).astype(float)
    base = [r.choice.size for r in rolling_decisions(o, volumes, day, keep=4)]
    for h in range(4):
        other = day.copy()
        other[h:] = rng.integers(20, 80, 4 - h)
        again = [r.choice.size for r in rolling_decisions(o, volumes, other, keep=4)]
        assert again[: h + 1] == base[: h + 1]


# ------------------------------------------------------------------------------------ realized test costs


def test_realized_costs_by_hand() -> None:
    """Two test days of two hours, ζ = 1: sizes (10, 20) on day 0 cost (10 + 10, 40 + 20) / 2 h = 40."""
    test = {10: outcomes([[10.0, 20.0], [20.0, 0.0]]), 20: outcomes([[30.0, 40.0], [5.0, 20.0]])}
    cm = CostModel(1.0)
    r = realized_by_hour(test, [[10, 20], [20, 20]], cm)
    assert r.per_hour == ((20.0, 60.0), (25.0, 40.0))
    assert r.per_day == (40.0, 32.5) and r.value == pytest.approx(36.25)
    fixed = realized_fixed(test, 10, cm)
    assert fixed.per_day == (25.0, 20.0) and fixed.value == pytest.approx(22.5)
    # a fixed size realizes the mean of its daily total-cost samples
    assert fixed.value == pytest.approx(float(np.mean(candidate_table(test, costs=cm).cost_samples[10])))


def test_brute_force_cross_check_on_random_instances() -> None:
    """Random instances: every choice equals an exhaustive scan of the engine's worst case (or the mean) of
    the total cost computed here independently, smallest of the best; DRO_RH scans the kept days."""
    rng = np.random.default_rng(11)
    for trial in range(20):
        sizes = sorted(rng.choice(np.arange(1, 9) * 10, size=int(rng.integers(2, 5)), replace=False).tolist())
        m, hours = int(rng.integers(3, 12)), int(rng.integers(1, 4))
        divergence = DIVERGENCE_NAMES[trial % len(DIVERGENCE_NAMES)]
        amb = Ambiguity(divergence, float(rng.uniform(0.01, 0.3)), "binned" if trial % 3 else "samples", 5)
        zeta = float(rng.choice([0.0, 0.5, 1.0]))
        # a coarse grid of values makes exact ties between sizes common
        raw = {x: rng.integers(0, 4, (m, hours)).astype(float) * 5 for x in sizes}
        o = {x: outcomes(raw[x].tolist()) for x in sizes}
        table = candidate_table(o, amb, CostModel(zeta))

        def scan(values: dict[int, float]) -> int:
            best = min(values.values())
            return min(x for x in values if math.isclose(values[x], best, rel_tol=1e-9) or values[x] == best)

        totals = {x: raw[x].mean(axis=1) + zeta * x for x in sizes}
        wc = {
            x: worst_case(totals[x], divergence, alpha=amb.alpha, support=amb.support, bins=5).value
            for x in sizes
        }
        assert choose(table, "dro").size == scan(wc)
        assert choose(table, "deterministic").size == scan({x: float(np.mean(totals[x])) for x in sizes})
        volumes = rng.integers(10, 60, (m, hours)).astype(float)
        observed = rng.integers(10, 60, hours - 1).astype(float)
        h = hours - 1
        rh = rolling_hour(o, volumes, observed, h, keep=3, ambiguity=amb, costs=CostModel(zeta))
        kept = list(similar_days(volumes, observed[:h], 3))
        wc_h = {
            x: worst_case(
                raw[x][kept, h] + zeta * x, divergence, alpha=amb.alpha, support=amb.support, bins=5
            ).value
            for x in sizes
        }
        assert rh.choice.size == scan(wc_h)
