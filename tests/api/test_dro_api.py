"""POST /v1/dro/worst-case: the core's answer over HTTP, the `read` scope, and every bad input named."""

from __future__ import annotations

import json
import math
from typing import Any

import numpy as np
import pytest

from services.fleet.dro import DIVERGENCE_NAMES, worst_case
from tests.api.conftest import DISPATCH, READ, MakeClient, auth

PATH = "/v1/dro/worst-case"
SAMPLES = [float(v) for v in np.random.default_rng(8).lognormal(2.5, 0.4, 30)]


def _post(client: Any, body: Any, token: str = READ) -> Any:
    return client.post(PATH, json=body, headers=auth(token))


@pytest.mark.parametrize("name", DIVERGENCE_NAMES)
def test_agrees_with_the_core(make_client: MakeClient, name: str) -> None:
    client = make_client()
    r = _post(client, {"samples": SAMPLES, "divergence": name})
    assert r.status_code == 200, r.text
    out = r.json()
    core = worst_case(SAMPLES, name)
    assert out["value"] == core.value and out["mean"] == core.mean and out["rho"] == core.rho
    assert out["p"] == core.p.tolist() and out["q"] == core.q.tolist()
    assert out["support_values"] == core.support_values.tolist()
    assert out["m"] == 10 and out["status"] == core.status
    assert out["divergence"] == name and out["method"] == "exact"
    assert set(out) == {
        "value",
        "mean",
        "rho",
        "m",
        "support_values",
        "q",
        "p",
        "status",
        "divergence",
        "method",
    }


def test_options_reach_the_core(make_client: MakeClient) -> None:
    client = make_client()
    cases: list[tuple[dict[str, Any], dict[str, Any]]] = [
        ({"rho": 0.2, "support": "samples"}, {"rho": 0.2, "support": "samples"}),
        ({"alpha": 0.1, "bins": 6, "divergence": "hellinger"}, {"alpha": 0.1, "bins": 6}),
        ({"method": "box_lp", "divergence": "variation"}, {"method": "box_lp"}),
    ]
    for extra, kwargs in cases:
        out = _post(client, {"samples": SAMPLES} | extra).json()
        core = worst_case(SAMPLES, extra.get("divergence", "kl"), **kwargs)
        assert out["value"] == core.value and out["m"] == core.m and out["method"] == core.method
    # integers are numbers too
    assert _post(client, {"samples": [1, 2, 2, 5]}).status_code == 200


def test_degenerate_and_saturated_statuses(make_client: MakeClient) -> None:
    client = make_client()
    out = _post(client, {"samples": [7.0, 7.0, 7.0]}).json()
    assert out["status"] == "degenerate" and out["value"] == 7.0
    out = _post(client, {"samples": [1.0, 2.0, 9.0], "rho": 50.0}).json()
    assert out["status"] == "saturated" and out["value"] == 9.0


def test_needs_the_read_scope(make_client: MakeClient) -> None:
    client = make_client()
    body = {"samples": SAMPLES}
    r = client.post(PATH, json=body)
    assert r.status_code == 401 and r.json()["error"] == "unauthorized"
    r = _post(client, body, token=DISPATCH)
    assert r.status_code == 403 and r.json()["error"] == "forbidden"
    assert _post(client, {"nonsense": True}, token=DISPATCH).status_code == 403  # auth before the body
    assert _post(client, body).status_code == 200


BAD: list[tuple[str, Any, str]] = [
    ("empty samples", {"samples": []}, "samples"),
    ("one sample", {"samples": [1.0]}, "samples"),
    ("missing samples", {}, "samples"),
    ("string sample", {"samples": [1.0, "2"]}, "samples[1]"),
    ("too many samples", {"samples": [0.5] * 100_001}, "samples"),
    ("unknown divergence", {"samples": SAMPLES, "divergence": "tv"}, "divergence"),
    ("alpha zero", {"samples": SAMPLES, "alpha": 0.0}, "alpha"),
    ("alpha one", {"samples": SAMPLES, "alpha": 1.0}, "alpha"),
    ("alpha above one", {"samples": SAMPLES, "alpha": 1.5}, "alpha"),
    ("negative rho", {"samples": SAMPLES, "rho": -0.1}, "rho"),
    ("alpha and rho", {"samples": SAMPLES, "alpha": 0.05, "rho": 0.1}, "rho"),
    ("bins below two", {"samples": SAMPLES, "bins": 1}, "bins"),
    ("fractional bins", {"samples": SAMPLES, "bins": 2.5}, "bins"),
    ("too many bins", {"samples": SAMPLES, "bins": 1001}, "bins"),
    ("unknown support", {"samples": SAMPLES, "support": "kde"}, "support"),
    ("unknown method", {"samples": SAMPLES, "method": "cvxpy"}, "method"),
    ("box_lp on samples", {"samples": SAMPLES, "method": "box_lp", "support": "samples"}, "method"),
    ("extra field", {"samples": SAMPLES, "weights": [1.0]}, "weights"),
    ("range too wide", {"samples": [-1e308, 1e308]}, "samples"),
]


@pytest.mark.parametrize(("label", "body", "loc"), BAD, ids=[b[0] for b in BAD])
def test_bad_input_is_422_naming_the_field(make_client: MakeClient, label: str, body: Any, loc: str) -> None:
    r = _post(make_client(), body)
    assert r.status_code == 422, (label, r.text)
    err = r.json()
    assert err["error"] == "validation_error"
    assert err["fields"][0]["loc"] == loc, err
    assert err["detail"].startswith(loc)


@pytest.mark.parametrize(
    ("raw", "loc"), [("NaN", "samples[1]"), ("Infinity", "samples[1]"), ("-Infinity", "samples[1]")]
)
def test_non_finite_samples_are_422(make_client: MakeClient, raw: str, loc: str) -> None:
    client = make_client()
    content = '{"samples": [1.0, ' + raw + ", 3.0]}"
    r = client.post(PATH, content=content, headers=auth(READ) | {"Content-Type": "application/json"})
    assert r.status_code == 422 and r.json()["fields"][0]["loc"] == loc
    r = client.post(
        PATH,
        content=json.dumps({"samples": [1.0, 2.0], "rho": math.nan}),
        headers=auth(READ) | {"Content-Type": "application/json"},
    )
    assert r.status_code == 422 and r.json()["fields"][0]["loc"] == "rho"


def test_body_must_be_json_object(make_client: MakeClient) -> None:
    client = make_client()
    r = client.post(PATH, content="{not json", headers=auth(READ) | {"Content-Type": "application/json"})
    assert r.status_code == 400 and r.json()["error"] == "bad_json"
    r = _post(client, [1.0, 2.0])
    assert r.status_code == 422


def test_openapi_documents_the_route(make_client: MakeClient) -> None:
    doc = make_client().get("/openapi.json").json()
    op = doc["paths"][PATH]["post"]
    assert op["operationId"] == "post_worst_case"
    assert op["security"] == [{"HTTPBearer": []}]
    for code in ("401", "403", "422"):
        assert op["responses"][code]["content"]["application/json"]["schema"]["$ref"].endswith("/ErrorOut")
    props = doc["components"]["schemas"]["WorstCaseIn"]["properties"]
    assert set(props) == {"samples", "divergence", "alpha", "rho", "support", "bins", "method"}
