"""The exact worst case against the primal convex program (cvxpy), by hand, at its limits, with its dual."""

from __future__ import annotations

import math

import numpy as np
import pytest

from services.fleet.dro import (
    DIVERGENCE_NAMES,
    DIVERGENCES,
    DroInputError,
    WorstCase,
    binned_support,
    divergence_value,
    dual_objective,
    rho_from_alpha,
    sample_support,
    solve_exact,
)
from services.fleet.dro.solvers import Reduced, solve_j
from tests.unit.dro.oracle import POPPING, primal_worst_case, textbook_divergence

Instance = tuple[str, np.ndarray, np.ndarray, float]


def _saturation(values: np.ndarray, q: np.ndarray, name: str) -> float:
    """ρ at which the ball first reaches all mass on the top value (inf if it never does), by hand."""
    full = q > 0
    top_full = values[full].max()
    above = (~full) & (values > top_full)
    if POPPING[name] and above.any():
        return {"hellinger": 2.0, "variation": 2.0}.get(name, math.inf)
    qt = float(q[full & (values == top_full)].sum())
    return {
        "kl": -math.log(qt),
        "modified_chi2": 1.0 / qt - 1.0,
        "hellinger": 2.0 - 2.0 * math.sqrt(qt),
        "variation": 2.0 * (1.0 - qt),
    }.get(name, math.inf)


def _instances(name: str) -> list[Instance]:
    """Seeded: bins with and without empty cells, cells above the data, small and large M, near saturation."""
    rng = np.random.default_rng(20261122)
    out: list[Instance] = []
    for m_samples in (4, 30, 2000):
        x = rng.lognormal(2.5, 0.4, m_samples)
        sup = binned_support(x, 10)
        out.append((f"binned M={m_samples}", sup.values, sup.q, rho_from_alpha(name, 0.05, m_samples, 10)))
    gap = np.concatenate([rng.normal(10, 1, 25), rng.normal(30, 1, 5)])  # two clusters: empty bins between
    sup = binned_support(gap, 12)
    assert (sup.q == 0).any()
    out.append(("binned with empty bins", sup.values, sup.q, rho_from_alpha(name, 0.05, 30, 12)))
    samp = sample_support(np.round(rng.normal(5, 2, 12)))  # ties: cells of equal value
    out.append(("samples with ties", samp.values, samp.q, 0.2))
    # a grid reaching beyond the data: empty cells below, between and above (where popping matters)
    grid = np.linspace(0.0, 10.0, 11)
    q = np.array([0, 0.1, 0.25, 0, 0.3, 0.2, 0.15, 0, 0, 0, 0], dtype=float)
    for rho in (0.05, 0.4, 1.2):
        out.append((f"grid with empty top, rho={rho}", grid, q, rho))
    sup = binned_support(rng.lognormal(2.5, 0.4, 30), 10)
    sat = _saturation(sup.values, sup.q, name)
    near = 0.97 * sat if math.isfinite(sat) else 4.0
    out.append(("near saturation", sup.values, sup.q, near))
    out.append(("small rho", sup.values, sup.q, 1e-4))
    return out


@pytest.mark.parametrize("name", DIVERGENCE_NAMES)
def test_agrees_with_the_primal_convex_program(name: str) -> None:
    for label, values, q, rho in _instances(name):
        got = solve_exact(values, q, rho, name)
        expected, _ = primal_worst_case(values, q, rho, name)
        span = float(values.max() - values.min())
        assert abs(got.value - expected) <= 1e-8 * span, (label, got.value, expected, got.note)
        _assert_feasible(got, name)


def _assert_feasible(wc: WorstCase, name: str) -> None:
    assert np.all(wc.p >= 0) and wc.p.sum() == pytest.approx(1.0, abs=1e-12)
    assert textbook_divergence(wc.p, wc.q, name) <= wc.rho * (1 + 1e-9) + 1e-14
    assert wc.divergence_at_p <= wc.rho * (1 + 1e-9) + 1e-14
    assert wc.value == pytest.approx(float(np.dot(wc.p, wc.support_values)), rel=1e-13, abs=1e-13)


@pytest.mark.parametrize("name", DIVERGENCE_NAMES)
def test_worst_case_p_is_feasible_and_certified_by_the_dual(name: str) -> None:
    rng = np.random.default_rng(7)
    for _ in range(25):
        m = int(rng.integers(2, 40))
        values = np.sort(rng.normal(0, rng.uniform(0.1, 100), m)) + rng.normal(0, 100)
        q = rng.dirichlet(np.ones(m) * rng.uniform(0.2, 3))
        q[rng.random(m) < 0.2] = 0.0
        if q.sum() == 0:
            continue
        q /= q.sum()
        if rng.random() < 0.5:  # cells in any order
            order = rng.permutation(m)
            values, q = values[order], q[order]
        rho = float(np.exp(rng.uniform(np.log(1e-6), np.log(5.0))))
        wc = solve_exact(values, q, rho, name)
        _assert_feasible(wc, name)
        span = float(values.max() - values.min())
        # the certificate: the dual objective at (eta, lam) equals the value (strong duality) ...
        assert dual_objective(values, q, rho, name, wc.eta, wc.lam) == pytest.approx(
            wc.value, abs=1e-9 * span
        )
        # ... and any other dual point bounds it from above (weak duality)
        for _ in range(5):
            eta = wc.eta + rng.normal(0, span)
            lam = abs(wc.lam * math.exp(rng.normal(0, 1)) if math.isfinite(wc.lam) else 1.0) + 1e-3
            assert dual_objective(values, q, rho, name, eta, lam) >= wc.value - 1e-9 * span


TWO_POINT_P = 0.8


def _two_point_rho(name: str, q: float, p: float) -> float:
    """``I_φ((1-p, p), (1-q, q))`` written out by hand."""
    a, b = (1 - p, p), (1 - q, q)
    return {
        "kl": sum(x * math.log(x / y) for x, y in zip(a, b, strict=True)),
        "burg": sum(y * math.log(y / x) for x, y in zip(a, b, strict=True)),
        "j": sum((x - y) * math.log(x / y) for x, y in zip(a, b, strict=True)),
        "chi2": sum((x - y) ** 2 / x for x, y in zip(a, b, strict=True)),
        "modified_chi2": sum((x - y) ** 2 / y for x, y in zip(a, b, strict=True)),
        "hellinger": sum((math.sqrt(x) - math.sqrt(y)) ** 2 for x, y in zip(a, b, strict=True)),
        "variation": sum(abs(x - y) for x, y in zip(a, b, strict=True)),
    }[name]


@pytest.mark.parametrize("name", DIVERGENCE_NAMES)
def test_two_points_by_hand(name: str) -> None:
    """On {0, 1} the worst case is the largest p_1 on the ball's boundary: pick it, derive ρ, get it back."""
    for q1 in (0.5, 0.3):
        rho = _two_point_rho(name, q1, TWO_POINT_P)
        wc = solve_exact([0.0, 1.0], [1 - q1, q1], rho, name)
        assert wc.value == pytest.approx(TWO_POINT_P, abs=1e-10)
        assert wc.status == "optimal"
        assert wc.p == pytest.approx([1 - TWO_POINT_P, TWO_POINT_P], abs=1e-10)


def test_variation_closed_form_on_three_points() -> None:
    values, q = [0.0, 1.0, 3.0], [0.3, 0.3, 0.4]
    # move ρ/2 from the lowest values to the top
    wc = solve_exact(values, q, 0.4, "variation")
    assert wc.value == pytest.approx(0.1 * 0 + 0.3 * 1 + 0.6 * 3)
    assert wc.p == pytest.approx([0.1, 0.3, 0.6])
    wc = solve_exact(values, q, 0.8, "variation")
    assert wc.p == pytest.approx([0.0, 0.2, 0.8])
    assert wc.value == pytest.approx(2.6)
    # saturation at ρ/2 = 1 - q_max
    wc = solve_exact(values, q, 1.2, "variation")
    assert wc.status == "saturated" and wc.value == 3.0


def test_modified_chi2_closed_form_and_truncation() -> None:
    values, q = np.array([0.0, 1.0, 3.0]), np.array([0.3, 0.3, 0.4])
    mean = float(q @ values)
    var = float(q @ (values - mean) ** 2)
    wc = solve_exact(values, q, 0.1, "modified_chi2")
    assert wc.value == pytest.approx(mean + math.sqrt(0.1 * var), rel=1e-13)
    # at ρ = 1 mean + sqrt(ρ var) would need negative mass on 0; the lowest cell drops out
    assert 1 + math.sqrt(1.0 / var) * (0.0 - mean) < 0
    wc = solve_exact(values, q, 1.0, "modified_chi2")
    qa, fa = q[1:], values[1:]
    q0 = qa.sum()
    mu = float(qa @ fa) / q0
    sigma2 = float(qa @ (fa - mu) ** 2) / q0
    assert wc.p[0] == 0.0
    assert wc.value == pytest.approx(mu + math.sqrt(sigma2 * ((1 + 1.0) * q0 - 1)), rel=1e-13)
    assert wc.status == "optimal" and wc.value < 3.0


@pytest.mark.parametrize("name", DIVERGENCE_NAMES)
def test_rho_to_zero_gives_the_mean(name: str) -> None:
    values, q = np.array([1.0, 2.0, 4.0, 7.0]), np.array([0.1, 0.4, 0.3, 0.2])
    mean = float(q @ values)
    var = float(q @ (values - mean) ** 2)
    assert solve_exact(values, q, 0.0, name).value == mean
    rho = 1e-10
    wc = solve_exact(values, q, rho, name)
    curvature = DIVERGENCES[name].curvature
    if curvature is None:  # variation: ρ/2 moves from the lowest value to the highest
        assert wc.value - mean == pytest.approx(rho / 2 * (7.0 - 1.0), rel=1e-4)
    else:  # first order: mean + sqrt(2 ρ var / φ''(1))
        assert wc.value - mean == pytest.approx(math.sqrt(2 * rho * var / curvature), rel=1e-3)


@pytest.mark.parametrize("name", DIVERGENCE_NAMES)
def test_large_rho_gives_the_max_where_the_divergence_allows(name: str) -> None:
    # data on 1..4, empty cells at 0 (below) and 9 (above)
    values = np.array([0.0, 1.0, 2.0, 3.0, 4.0, 9.0])
    q = np.array([0.0, 0.2, 0.3, 0.3, 0.2, 0.0])
    div = DIVERGENCES[name]
    wc = solve_exact(values, q, 60.0, name)
    _assert_feasible(wc, name)
    if not div.popping:  # mass stays on the data: the max over non-empty cells
        assert wc.value == pytest.approx(4.0, abs=1e-9)
        assert wc.p[-1] == 0.0 and wc.p[0] == 0.0
    elif name == "chi2":  # pops, but the data keep mass (1 + g) / (1 + ρ): the approach to 9 is slow
        assert 8.5 < wc.value < 9.0
        assert solve_exact(values, q, 6.0, name).value < wc.value
    else:  # mass pops to the empty cell above
        assert wc.value == pytest.approx(9.0, abs=1e-9)
    assert (wc.status == "saturated") == (name not in ("burg", "j", "chi2"))


@pytest.mark.parametrize("name", ["kl", "modified_chi2", "hellinger", "variation"])
def test_saturation_thresholds(name: str) -> None:
    values, q = np.array([0.0, 2.0, 5.0]), np.array([0.5, 0.3, 0.2])
    sat = _saturation(values, q, name)
    at = solve_exact(values, q, sat, name)
    assert at.status == "saturated" and at.value == 5.0 and at.p.tolist() == [0.0, 0.0, 1.0]
    below = solve_exact(values, q, sat * (1 - 1e-6), name)
    assert below.status == "optimal" and 4.9 < below.value < 5.0
    just_below = solve_exact(values, q, math.nextafter(sat, 0.0), name)
    assert just_below.value == pytest.approx(5.0, abs=1e-6)
    _assert_feasible(just_below, name)


@pytest.mark.parametrize("name", ["burg", "chi2", "hellinger", "variation"])
def test_popping_uses_only_the_highest_empty_cell(name: str) -> None:
    values = np.array([-3.0, 0.0, 1.0, 2.0, 6.0, 8.0])
    q = np.array([0.0, 0.5, 0.0, 0.5, 0.0, 0.0])
    wc = solve_exact(values, q, 0.5, name)
    assert wc.p[0] == 0.0 and wc.p[2] == 0.0 and wc.p[4] == 0.0
    assert wc.p[5] > 0.0
    expected, _ = primal_worst_case(values, q, 0.5, name)
    assert wc.value == pytest.approx(expected, abs=1e-6 * 11)


@pytest.mark.parametrize("name", DIVERGENCE_NAMES)
def test_equal_values_are_one_cell(name: str) -> None:
    """Splitting a cell into two of the same value changes nothing; p stays proportional to q among them."""
    merged = solve_exact([0.0, 1.0, 4.0], [0.3, 0.5, 0.2], 0.3, name)
    split = solve_exact([0.0, 1.0, 1.0, 4.0], [0.3, 0.2, 0.3, 0.2], 0.3, name)
    assert split.value == pytest.approx(merged.value, rel=1e-12)
    assert split.p[1] / split.p[2] == pytest.approx(0.2 / 0.3, rel=1e-12)


@pytest.mark.parametrize("name", DIVERGENCE_NAMES)
def test_one_value_is_degenerate(name: str) -> None:
    wc = solve_exact([3.5, 3.5, 3.5], [0.2, 0.3, 0.5], 0.7, name)
    assert wc.status == "degenerate" and wc.value == 3.5 and wc.mean == 3.5
    # non-popping divergences ignore empty cells, so a lone data value is degenerate too
    wc = solve_exact([3.5, 9.0], [1.0, 0.0], 0.7, name)
    if POPPING[name]:
        assert wc.status in ("optimal", "saturated") and wc.value > 3.5
    else:
        assert wc.status == "degenerate" and wc.value == 3.5


def test_translation_and_scale() -> None:
    rng = np.random.default_rng(3)
    values, q = np.sort(rng.normal(size=8)), rng.dirichlet(np.ones(8))
    for name in DIVERGENCE_NAMES:
        base = solve_exact(values, q, 0.3, name).value
        moved = solve_exact(1e4 + 250.0 * values, q, 0.3, name).value
        assert moved == pytest.approx(1e4 + 250.0 * base, rel=1e-12)


def test_j_newton_and_nested_roots_agree() -> None:
    rng = np.random.default_rng(5)
    for _ in range(10):
        f = np.sort(rng.normal(size=int(rng.integers(2, 30))))
        q = rng.dirichlet(np.ones(f.size))
        mean = float(q @ f)
        f = (f - mean) / float(f[-1] - f[0])
        u, inverse = np.unique(f, return_inverse=True)
        reduced = Reduced(
            u, np.bincount(inverse, weights=q).astype(np.float64), None, float(np.exp(rng.uniform(-8, 2)))
        )
        fast, nested = solve_j(reduced), solve_j(reduced, fast=False)
        assert "Newton on the KKT" in fast.note and "nested" in nested.note
        assert fast.p == pytest.approx(nested.p, abs=1e-10)
        assert fast.lam == pytest.approx(nested.lam, rel=1e-8)


def test_divergence_at_p_is_reported() -> None:
    wc = solve_exact([0.0, 1.0, 3.0], [0.3, 0.3, 0.4], 0.2, "kl")
    assert wc.divergence_at_p == pytest.approx(0.2, rel=1e-10)
    assert wc.divergence_at_p == divergence_value(wc.p, wc.q, "kl")


@pytest.mark.parametrize(
    ("kwargs", "parameter", "message"),
    [
        ({"values": [0.0, 1.0], "q": [0.5, 0.6]}, "q", "must sum to 1"),
        ({"values": [0.0, 1.0], "q": [1.2, -0.2]}, "q", "non-negative"),
        ({"values": [0.0, math.nan], "q": [0.5, 0.5]}, "values", "finite"),
        ({"values": [0.0, 1.0], "q": [1.0]}, "q", "shape"),
        ({"values": [], "q": []}, "values", "non-empty"),
        ({"rho": -0.1}, "rho", "must be finite and >= 0"),
        ({"rho": math.inf}, "rho", "must be finite and >= 0"),
    ],
)
def test_bad_input_raises_value_error(kwargs: dict[str, object], parameter: str, message: str) -> None:
    args: dict[str, object] = {"values": [0.0, 1.0], "q": [0.5, 0.5], "rho": 0.1, "divergence": "kl"} | kwargs
    with pytest.raises(ValueError, match=message) as info:
        solve_exact(**args)  # type: ignore[arg-type]
    assert isinstance(info.value, DroInputError) and info.value.parameter == parameter


def test_unknown_divergence() -> None:
    with pytest.raises(ValueError, match="unknown divergence 'kld'"):
        solve_exact([0.0, 1.0], [0.5, 0.5], 0.1, "kld")
