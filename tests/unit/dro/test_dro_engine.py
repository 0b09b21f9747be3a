"""Samples to worst case: the radius rule, the two supports, ``worst_case`` and its errors."""

from __future__ import annotations

import math

import numpy as np
import pytest

from services.fleet.dro import (
    DIVERGENCE_NAMES,
    DroInputError,
    binned_support,
    make_support,
    rho_from_alpha,
    sample_support,
    solve_box_lp,
    solve_exact,
    worst_case,
)

CHI2_9_95 = 16.918977604620448  # the 0.95-quantile of chi-squared with 9 degrees of freedom (tables)


def test_rho_rule() -> None:
    assert rho_from_alpha("kl", 0.05, 30, 10) == pytest.approx(1.0 / 60 * CHI2_9_95, rel=1e-12)
    assert rho_from_alpha("j", 0.05, 30, 10) == pytest.approx(2.0 / 60 * CHI2_9_95, rel=1e-12)
    assert rho_from_alpha("hellinger", 0.05, 30, 10) == pytest.approx(0.5 / 60 * CHI2_9_95, rel=1e-12)
    assert rho_from_alpha("variation", 0.05, 30, 10) == pytest.approx(math.sqrt(CHI2_9_95 / 30), rel=1e-12)
    # m counts cells: with one cell per sample ρ tends to φ''(1)/2 instead of shrinking
    assert rho_from_alpha("kl", 0.05, 10_000, 10_000) == pytest.approx(0.5, rel=0.05)
    assert rho_from_alpha("kl", 0.01, 30, 10) > rho_from_alpha("kl", 0.05, 30, 10)


def test_binned_support_by_hand() -> None:
    x = [0.0, 0.5, 1.0, 9.0, 10.0, 2.5]  # bins of width 2 over [0, 10]
    sup = binned_support(x, 5)
    assert sup.edges is not None and sup.midpoints is not None
    assert sup.edges.tolist() == [0.0, 2.0, 4.0, 6.0, 8.0, 10.0]
    assert sup.counts.tolist() == [3, 1, 0, 0, 2]
    assert sup.q == pytest.approx([3 / 6, 1 / 6, 0, 0, 2 / 6])
    # a bin's value is the mean of its samples; an empty bin's is its midpoint (the max falls in the last bin)
    assert sup.values == pytest.approx([0.5, 2.5, 5.0, 7.0, 9.5])
    assert sup.midpoints == pytest.approx([1.0, 3.0, 5.0, 7.0, 9.0])
    assert sup.m == 5 and sup.nominal_cells == 5 and sup.n_samples == 6 and not sup.degenerate
    assert float(sup.q @ sup.values) == pytest.approx(float(np.mean(x)))


def test_sample_on_an_inner_edge_goes_to_the_bin_above() -> None:
    sup = binned_support([0.0, 2.0, 4.0], 2)
    assert sup.counts.tolist() == [1, 2]


def test_degenerate_samples() -> None:
    sup = binned_support([3.0, 3.0, 3.0], 10)
    assert sup.degenerate and sup.values.tolist() == [3.0] and sup.q.tolist() == [1.0]
    assert sup.nominal_cells == 10
    wc = worst_case([3.0, 3.0, 3.0])
    assert wc.status == "degenerate" and wc.value == 3.0
    assert wc.rho == pytest.approx(rho_from_alpha("kl", 0.05, 3, 10))
    assert sample_support([1.0, 1.0]).degenerate


def test_sample_support_keeps_every_sample() -> None:
    sup = sample_support([3.0, 1.0, 2.0, 1.0])
    assert sup.values.tolist() == [1.0, 1.0, 2.0, 3.0]
    assert sup.q.tolist() == [0.25] * 4
    assert sup.m == 4 and sup.nominal_cells == 4 and sup.edges is None


@pytest.mark.parametrize("name", DIVERGENCE_NAMES)
def test_worst_case_is_support_then_radius_then_solve(name: str) -> None:
    rng = np.random.default_rng(9)
    x = rng.lognormal(2.5, 0.4, 30)
    wc = worst_case(x, name)
    sup = binned_support(x, 10)
    rho = rho_from_alpha(name, 0.05, 30, 10)
    direct = solve_exact(sup.values, sup.q, rho, name)
    assert wc.rho == rho and wc.m == 10 and wc.method == "exact" and wc.divergence == name
    assert wc.value == direct.value and wc.p.tolist() == direct.p.tolist()
    assert wc.mean == pytest.approx(float(np.mean(x)), rel=1e-12)
    assert wc.premium == wc.value - wc.mean and wc.value > wc.mean
    by_samples = worst_case(x, name, support="samples", rho=0.1)
    assert by_samples.m == 30 and by_samples.rho == 0.1
    assert by_samples.value == solve_exact(np.sort(x), np.full(30, 1 / 30), 0.1, name).value
    box = worst_case(x, name, method="box_lp", bins=8, alpha=0.1)
    sup8 = binned_support(x, 8)
    assert sup8.midpoints is not None
    assert box.value == solve_box_lp(sup8.midpoints, sup8.q, rho_from_alpha(name, 0.1, 30, 8), name).value


def test_ties_in_samples_do_not_matter() -> None:
    x = np.array([1.0, 1.0, 1.0, 2.0, 5.0, 5.0])
    for name in DIVERGENCE_NAMES:
        by_samples = worst_case(x, name, support="samples", rho=0.2)
        merged = solve_exact([1.0, 2.0, 5.0], [0.5, 1 / 6, 1 / 3], 0.2, name)
        assert by_samples.value == pytest.approx(merged.value, rel=1e-12)


def test_more_data_shrinks_the_premium() -> None:
    rng = np.random.default_rng(4)
    x = rng.lognormal(2.5, 0.4, 4000)
    small, large = worst_case(x[:40]), worst_case(x)
    assert large.rho < small.rho
    assert large.premium < small.premium


@pytest.mark.parametrize(
    ("kwargs", "parameter", "message"),
    [
        ({"samples": []}, "samples", "at least 2 values, got 0"),
        ({"samples": [1.0]}, "samples", "at least 2 values, got 1"),
        ({"samples": [1.0, math.nan]}, "samples", "must be finite; value nan at index 1"),
        ({"samples": [1.0, math.inf]}, "samples", "must be finite"),
        ({"samples": [[1.0, 2.0]]}, "samples", "one-dimensional"),
        ({"samples": ["a", "b"]}, "samples", "list of numbers"),
        ({"samples": [-1e308, 1e308]}, "samples", "range"),
        ({"divergence": "tv"}, "divergence", "unknown divergence 'tv'"),
        ({"alpha": 0.0}, "alpha", "strictly between 0 and 1"),
        ({"alpha": 1.0}, "alpha", "strictly between 0 and 1"),
        ({"rho": -1.0}, "rho", ">= 0"),
        ({"rho": math.nan}, "rho", ">= 0"),
        ({"rho": 0.1, "alpha": 0.05}, "rho", "not both"),
        ({"bins": 1}, "bins", "2.."),
        ({"bins": 2.5}, "bins", "integer"),
        ({"support": "kde"}, "support", "unknown support 'kde'"),
        ({"method": "cvxpy"}, "method", "unknown method 'cvxpy'"),
        ({"method": "box_lp", "support": "samples"}, "method", "support='binned'"),
    ],
)
def test_bad_input_names_the_parameter(kwargs: dict[str, object], parameter: str, message: str) -> None:
    args: dict[str, object] = {"samples": [1.0, 2.0, 4.0]} | kwargs
    samples = args.pop("samples")
    with pytest.raises(ValueError, match=message) as info:
        worst_case(samples, **args)  # type: ignore[arg-type]
    assert isinstance(info.value, DroInputError)
    assert info.value.parameter == parameter


def test_make_support_rejects_unknown_kinds() -> None:
    with pytest.raises(DroInputError, match="unknown support"):
        make_support([1.0, 2.0], "grid")
