"""A bounded, seeded schemathesis run of every operation of the OpenAPI document against the real service
(bundled cities, the real dispatch core, an in-memory store, ``app.entrypoints.server``'s uvicorn), with
every check schemathesis has but one: no server error (5xx), and every response conforming to the document
(status codes, content types, headers, schemas), schema-invalid requests refused.

The check left out is ``positive_data_acceptance`` ("a schema-valid request must be accepted"): a few rules
cannot be written in JSON Schema, and the server rightly answers 422 to them: ids unique within a request,
``confirm`` equal to the path's city, samples whose range overflows a float. ``bench/bench_hardening.py``
runs more examples and reports the counts.
"""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

from app.adapters import MemoryStore
from app.adapters.city_registry import CityRegistry
from app.bootstrap import create_app
from app.entrypoints.serve import serve_app_in_thread
from app.runs import RunCache, Runner
from app.schemas.fleet import render_recommendation
from app.settings import Settings
from app.usecases.fleet_history import SizingConfig
from app.usecases.fleet_solve import FleetSolver
from app.worker.heartbeat import Heartbeat, WorkerStatus

TOKEN = "schemathesis-token-0001"
MAX_EXAMPLES = 10  # per operation and phase: about 800 requests, a minute on two cores


def run_schemathesis(max_examples: int) -> tuple[int, str]:
    """Run ``st run`` against a fresh in-thread service; its exit code and output."""
    binary = shutil.which("st", path=str(Path(sys.executable).parent))
    assert binary is not None, "schemathesis is a dev dependency: pip install -e '.[dev]'"
    settings = Settings().with_values(
        tokens={TOKEN: ["read", "dispatch", "admin"]}, store="memory", log_level="error"
    )
    store = MemoryStore()
    app = create_app(settings, store=store)
    # a fleet worker's heartbeat (it never solves): a solve request is queued, as a deployment answers it
    beats = Heartbeat(
        FleetSolver(
            store,
            Runner(RunCache(Path(tempfile.mkdtemp()))),
            SizingConfig(),
            render=render_recommendation,
            cities=CityRegistry(),
        ),
        WorkerStatus(embedded=False, poll_s=2.0),
        ["chengdu", "manhattan"],
        interval_s=2.0,
    )
    beats.start()
    with serve_app_in_thread(app, settings) as url:
        cmd = [binary, "run", f"{url}/openapi.json", "--max-examples", str(max_examples),
               "--generation-deterministic", "--header", f"Authorization: Bearer {TOKEN}",
               "--checks", "all", "--exclude-checks", "positive_data_acceptance",
               "--request-timeout", "60", "--warnings", "off", "--no-color"]  # fmt: skip
        with tempfile.TemporaryDirectory() as scratch:  # schemathesis keeps a cache in its working directory
            done = subprocess.run(cmd, capture_output=True, text=True, timeout=900, check=False, cwd=scratch)
    beats.stop()
    return done.returncode, done.stdout + done.stderr


def generated(output: str) -> int:
    """The number of test cases the run generated (from its summary)."""
    m = re.search(r"(\d+) generated", output)
    return int(m.group(1)) if m else 0


def operations() -> int:
    """How many operations the document has."""
    doc = create_app(Settings(), store=MemoryStore()).openapi()
    return sum(len(methods) for methods in doc["paths"].values())


def test_every_operation_holds_under_schemathesis() -> None:
    code, output = run_schemathesis(MAX_EXAMPLES)
    assert code == 0, output[-8000:]
    assert f"Tested: {operations()}" in output, output[-3000:]
    assert generated(output) >= 500, output[-3000:]
