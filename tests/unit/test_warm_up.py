"""``services.dispatch.warm_up`` compiles every kernel a real epoch calls, so none is compiled inside one.

Checked in a fresh process (in this one, earlier tests have already called every kernel): after the warm-up,
real epochs with evolving counts, on the bundled Chengdu and Manhattan cities, on one thread and two, add no
signature to any compiled function of ``services``. A signature added there is a compilation (seconds on a
fresh install) that the first real epoch to need it would pay.
"""

from __future__ import annotations

import importlib
import json
import pkgutil
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

ROOT = Path(__file__).resolve().parents[2]


def compiled_functions() -> dict[str, object]:
    """Every numba dispatcher defined at module level in ``services`` (packages included)."""
    from numba.core.registry import CPUDispatcher

    import services

    found: dict[str, object] = {}
    for info in pkgutil.walk_packages(services.__path__, "services."):
        module = importlib.import_module(info.name)
        for name, value in vars(module).items():
            if isinstance(value, CPUDispatcher) and value.__module__ == module.__name__:
                found[f"{module.__name__}.{name}"] = value
    return found


def new_signatures_after_warm_up(scenario: str, epochs: int) -> dict[str, list[int]]:
    """Warm the scenario's city up, then solve ``epochs`` of its epochs (committing their visits) on one and
    two threads; the functions whose signature count grew, with the counts before and after."""
    from bench.bench_epoch import SCENARIOS, Epochs, load_city
    from services.dispatch import decide, warm_up
    from services.ledger import Ledger, apply_decision, ledger_view

    functions = compiled_functions()
    sc = SCENARIOS[scenario]
    city = load_city(sc)
    warm_up(city)
    before = {k: len(f.signatures) for k, f in functions.items()}  # type: ignore[attr-defined]
    ledger = Ledger()
    feed = Epochs(sc, city)
    for e in range(epochs):
        snap, tasks = feed.next()
        ledger.tasks.update({t.id: t for t in tasks})
        view = ledger_view(ledger, (t.id for t in snap.taxis if t.instrumented), city.grid.n_cells)
        d = decide(city, view, snap, list(ledger.tasks.values()), workers=1 + e % 2)
        apply_decision(ledger, d.visits, d.task_updates)
        feed.apply(d)
    after = {k: len(f.signatures) for k, f in functions.items()}  # type: ignore[attr-defined]
    return {k: [before[k], after[k]] for k in functions if after[k] != before[k]}


def in_a_fresh_process(function: str, *args: object) -> Any:
    """``function`` of this module called with ``args`` in a new interpreter (no kernel compiled or loaded
    yet); its JSON result."""
    code = (
        f"import json; from tests.unit.test_warm_up import {function} as f; print(json.dumps(f(*{args!r})))"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=900, check=False
    )
    assert out.returncode == 0, out.stderr[-3000:]
    return json.loads(out.stdout.strip().splitlines()[-1])


@pytest.mark.slow
@pytest.mark.parametrize("scenario", ["paper", "city"])
def test_after_the_warm_up_real_epochs_compile_nothing(scenario: str) -> None:
    grown = in_a_fresh_process("new_signatures_after_warm_up", scenario, 4)
    assert grown == {}, f"compiled inside a real epoch, not by the warm-up: {grown}"


def overlay_signatures_after_warm_up(scenario: str) -> int:
    """Warm the scenario's city up; the signatures of the kernel that computes Step 3's base costs
    (``algorithm1._overlay_base``), which only epochs with at least ``OVERLAY_TAXIS`` taxis growing their
    own trees call (the kernels it hands the costs to are the same either way)."""
    from bench.bench_epoch import SCENARIOS, load_city
    from services.dispatch import warm_up
    from services.routing import algorithm1

    warm_up(load_city(SCENARIOS[scenario]))
    return len(algorithm1._overlay_base.signatures)  # type: ignore[attr-defined]


@pytest.mark.slow
@pytest.mark.parametrize("scenario", ["paper", "city"])
def test_the_warm_up_compiles_the_base_cost_overlay(scenario: str) -> None:
    """The real epochs above may not reach an epoch that reads the base costs; the warm-up compiles those
    kernels anyway."""
    assert in_a_fresh_process("overlay_signatures_after_warm_up", scenario) > 0


def test_the_compiled_functions_are_found() -> None:
    found = compiled_functions()
    assert "services.routing.algorithm1._from_taxi" in found and "services.network.dijkstra.run" in found
    assert len(found) > 30
