"""Distributionally robust worst-case expectations over φ-divergence balls (paper Section 3.3,
docs/METHOD.md section 8).

Framework-free (numpy and scipy). Entry point: :func:`worst_case` (samples to a :class:`WorstCase`); the
pieces are the divergences (:mod:`.divergences`), the radius rule (:mod:`.radius`), the support
(:mod:`.support`), the exact solver and its dual (:mod:`.exact`, :mod:`.solvers`) and the paper's box LP
(:mod:`.box_lp`). docs/DRO.md explains the engine.
"""

from services.fleet.dro.box_lp import coordinate_bounds, solve_box_lp
from services.fleet.dro.divergences import (
    DIVERGENCE_NAMES,
    DIVERGENCES,
    Divergence,
    divergence_value,
    get_divergence,
)
from services.fleet.dro.engine import DEFAULT_ALPHA, worst_case
from services.fleet.dro.exact import dual_objective, solve_exact
from services.fleet.dro.inputs import DroInputError
from services.fleet.dro.radius import rho_from_alpha
from services.fleet.dro.result import METHODS, Method, Status, WorstCase
from services.fleet.dro.support import (
    SUPPORT_KINDS,
    Support,
    SupportKind,
    binned_support,
    make_support,
    sample_support,
)

__all__ = [
    "DEFAULT_ALPHA",
    "DIVERGENCE_NAMES",
    "DIVERGENCES",
    "METHODS",
    "SUPPORT_KINDS",
    "Divergence",
    "DroInputError",
    "Method",
    "Status",
    "Support",
    "SupportKind",
    "WorstCase",
    "binned_support",
    "coordinate_bounds",
    "divergence_value",
    "dual_objective",
    "get_divergence",
    "make_support",
    "rho_from_alpha",
    "sample_support",
    "solve_box_lp",
    "solve_exact",
    "worst_case",
]
