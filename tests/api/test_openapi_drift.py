"""The committed OpenAPI document matches the code (regenerate with `python -m app openapi`)."""

from __future__ import annotations

import json

from app.entrypoints.cli import OPENAPI_PATH, openapi_document


def test_committed_openapi_matches_the_app() -> None:
    assert OPENAPI_PATH.is_file(), "openapi/openapi.json is missing: run `python -m app openapi`"
    committed = json.loads(OPENAPI_PATH.read_text(encoding="utf-8"))
    generated = json.loads(openapi_document())
    assert committed == generated, (
        "openapi/openapi.json is out of date: run `python -m app openapi` and commit it"
    )


def test_document_declares_errors_and_auth() -> None:
    doc = json.loads(openapi_document())
    assert doc["components"]["securitySchemes"]["HTTPBearer"]["scheme"] == "bearer"
    post = doc["paths"]["/v1/cities/{city}/epochs"]["post"]
    assert post["operationId"] == "post_epoch"
    for code in ("400", "401", "403", "404", "409", "413", "422", "503"):
        assert post["responses"][code]["content"]["application/json"]["schema"]["$ref"].endswith("/ErrorOut")
    assert "Idempotent-Replayed" in post["responses"]["200"]["headers"]
    for path, ops in doc["paths"].items():
        for method, op in ops.items():
            if path.startswith("/v1/"):
                assert op.get("security") == [{"HTTPBearer": []}], (method, path)
                assert "422" in op["responses"] and "HTTPValidationError" not in json.dumps(op)
