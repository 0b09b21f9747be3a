"""The seven divergences: φ, φ*, φ''(1), L, φ(0) against their definitions; I_φ conventions; the J inverse."""

from __future__ import annotations

import numpy as np
import pytest

from services.fleet.dro import DIVERGENCE_NAMES, DIVERGENCES, divergence_value, get_divergence
from services.fleet.dro.divergences import j_inverse_derivative
from tests.unit.dro.oracle import POPPING, textbook_divergence

# docs/METHOD.md section 8: φ''(1) and popping; suppression from the paper's Table A.1
TABLE = {
    "kl": (1.0, False, True),
    "burg": (1.0, True, False),
    "j": (2.0, False, False),
    "chi2": (2.0, True, False),
    "modified_chi2": (2.0, False, True),
    "hellinger": (0.5, True, True),
    "variation": (None, True, True),
}


def test_the_seven_divergences_in_the_papers_order() -> None:
    assert DIVERGENCE_NAMES == ("kl", "burg", "j", "chi2", "modified_chi2", "hellinger", "variation")
    assert set(DIVERGENCES) == set(TABLE) == set(POPPING)


@pytest.mark.parametrize("name", DIVERGENCE_NAMES)
def test_curvature_popping_and_suppression_match_the_table(name: str) -> None:
    div = DIVERGENCES[name]
    curvature, popping, suppression = TABLE[name]
    assert div.popping is popping and div.suppression is suppression
    if curvature is None:
        assert div.curvature is None
        return
    assert div.curvature == curvature
    h = 1e-4  # central second difference of φ at 1
    second = float(
        div.phi(np.array([1 + h]))[0] - 2 * div.phi(np.array([1.0]))[0] + div.phi(np.array([1 - h]))[0]
    )
    assert second / h**2 == pytest.approx(curvature, rel=1e-6)


@pytest.mark.parametrize("name", DIVERGENCE_NAMES)
def test_phi_vanishes_at_one_and_is_convex(name: str) -> None:
    div = DIVERGENCES[name]
    t = np.linspace(0.01, 20.0, 2001)
    values = div.phi(t)
    assert div.phi(np.array([1.0]))[0] == 0.0
    assert np.all(values >= 0)
    assert np.all(values[:-2] + values[2:] - 2 * values[1:-1] >= -1e-12)


@pytest.mark.parametrize("name", DIVERGENCE_NAMES)
def test_slope_at_infinity_and_phi_at_zero(name: str) -> None:
    div = DIVERGENCES[name]
    ratio = div.phi(np.array([1e6, 1e12])) / np.array([1e6, 1e12])
    if np.isfinite(div.slope_at_infinity):
        assert ratio[1] == pytest.approx(div.slope_at_infinity, rel=1e-5)
    else:
        assert ratio[1] > 20 and ratio[1] > ratio[0] + 5  # grows without bound (like log t or t)
    at_zero = float(div.phi(np.array([0.0]))[0])
    assert at_zero == div.phi_at_zero


@pytest.mark.parametrize("name", DIVERGENCE_NAMES)
def test_phi_1p_is_phi_of_one_plus_u(name: str) -> None:
    div = DIVERGENCES[name]
    u = np.concatenate([np.linspace(-0.99, 5.0, 500), [-1.0]])
    expected = div.phi(1.0 + u)
    got = div.phi_1p(u)
    finite = np.isfinite(expected)
    assert np.array_equal(finite, np.isfinite(got))
    assert np.allclose(got[finite], expected[finite], rtol=1e-12, atol=1e-15)
    # near u = 0 the shifted form keeps its digits: φ(1 + u) ≈ φ''(1) u² / 2
    if div.curvature is not None:
        tiny = np.array([1e-7])
        assert float(div.phi_1p(tiny)[0]) == pytest.approx(div.curvature / 2 * 1e-14, rel=1e-6)


@pytest.mark.parametrize("name", DIVERGENCE_NAMES)
def test_conjugate_is_the_supremum(name: str) -> None:
    """φ*(s) = sup_{t >= 0} s t - φ(t), checked against a fine grid (and infinite outside the domain)."""
    div = DIVERGENCES[name]
    t = np.concatenate([[0.0, 1.0], np.geomspace(1e-8, 1e4, 200_001)])
    phi_t = div.phi(t)
    for s in (-5.0, -2.5, -1.0, -0.3, 0.0, 0.4, 0.9, 1.5, 3.0):
        grid = float(np.max(s * t - phi_t))
        conj = float(div.conjugate(np.array([s]))[0])
        if s > div.slope_at_infinity:
            assert np.isinf(conj), (name, s)
        else:
            assert conj == pytest.approx(grid, rel=1e-5, abs=1e-5), (name, s)
            assert conj >= grid - 1e-9


def test_j_inverse_derivative_solves_the_equation() -> None:
    y = np.concatenate([-np.geomspace(1e-12, 1e12, 300), [0.0], np.geomspace(1e-12, 600, 300)])
    x = j_inverse_derivative(y)
    t = np.exp(x)
    residual = np.log(t) + 1.0 - 1.0 / t - y
    assert np.all(np.abs(residual) <= 1e-12 * (1.0 + np.abs(y)))


@pytest.mark.parametrize("name", DIVERGENCE_NAMES)
def test_divergence_value_matches_the_textbook_formula(name: str) -> None:
    rng = np.random.default_rng(11)
    for _ in range(20):
        q = rng.dirichlet(np.ones(6))
        q[rng.integers(6)] = 0.0
        q /= q.sum()
        p = rng.dirichlet(np.ones(6))
        if not POPPING[name]:
            p[q == 0] = 0.0
            p /= p.sum()
        assert divergence_value(p, q, name) == pytest.approx(textbook_divergence(p, q, name), rel=1e-12)


def test_empty_cells_cost_l_per_unit_or_are_forbidden() -> None:
    q = np.array([0.5, 0.5, 0.0])
    p = np.array([0.4, 0.4, 0.2])
    assert divergence_value(p, q, "variation") == pytest.approx(0.1 + 0.1 + 0.2)
    assert divergence_value(p, q, "hellinger") == pytest.approx(2 * (np.sqrt(0.4) - np.sqrt(0.5)) ** 2 + 0.2)
    assert np.isinf(divergence_value(p, q, "kl"))
    assert np.isinf(divergence_value(p, q, "modified_chi2"))
    assert divergence_value(np.array([0.5, 0.5, 0.0]), q, "kl") == 0.0


def test_unknown_divergence_is_a_value_error() -> None:
    with pytest.raises(ValueError, match="unknown divergence 'tv'; expected one of kl, burg"):
        get_divergence("tv")
    with pytest.raises(ValueError, match="differ in shape"):
        divergence_value([0.5, 0.5], [1.0], "kl")
