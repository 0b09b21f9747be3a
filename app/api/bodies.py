"""JSON request bodies parsed and validated off the event loop, with the cheap checks first.

FastAPI validates a body model inside the event loop, before a plain ``def`` endpoint is handed to the
threadpool, and collects every error: a 1 MiB body of 350,000 empty riders kept the loop busy for 20 s and
rendered a 75 MiB error. Here the raw bytes (already buffered and size-capped by ``BodyLimit``) go to a
plain ``def`` dependency, which FastAPI runs in the threadpool (the epoch route, whose every millisecond
counts, calls ``epoch_post`` itself on its own threadpool thread instead: one hop to the threadpool, not
two): it parses the JSON (pydantic-core's parser: bounded nesting; an epoch's taxis and riders in their
common form are decoded by msgspec instead, ``epoch_post``), refuses arrays longer than the configured
limits *before* the model validates any item, then validates the model. Errors are capped when
rendered (``app.api.handlers``). The routes declare their body schema with ``request_body`` so the OpenAPI
document keeps describing it (``openapi_components``).
"""

from __future__ import annotations

import email.message
from dataclasses import dataclass
from typing import Annotated, Any, TypeVar

import msgspec
import pydantic_core
from fastapi import Depends, Request
from pydantic import BaseModel, TypeAdapter, ValidationError
from pydantic.json_schema import models_json_schema

from app.api.deps import LimitsDep
from app.api.handlers import from_validation_errors
from app.api.inputs import Limits
from app.errors import BadRequest, FieldIssue, InvalidInput, UnsupportedMediaType
from app.schemas.admin import ResetIn, RewindIn
from app.schemas.decision import EpochIn, PlainRiders, PlainTaxis, plain_riders, plain_taxis
from app.schemas.dro import MAX_SAMPLES, WorstCaseIn
from app.schemas.tasks import TaskIn

__all__ = [
    "RawBody",
    "EpochPost",
    "epoch_post",
    "TasksBody",
    "WorstCaseBody",
    "RewindBody",
    "ResetBody",
    "request_body",
    "openapi_components",
]

M = TypeVar("M", bound=BaseModel)

_TASKS = TypeAdapter(list[TaskIn])


async def _raw(request: Request) -> tuple[str | None, bytes]:
    return request.headers.get("content-type"), await request.body()


RawBody = Annotated[tuple[str | None, bytes], Depends(_raw)]


def _content_type(content_type: str | None) -> None:
    """FastAPI's rules: no Content-Type or a JSON one; 415 otherwise."""
    if content_type:
        message = email.message.Message()
        message["content-type"] = content_type
        subtype = message.get_content_subtype()
        if message.get_content_maintype() != "application" or not (
            subtype == "json" or subtype.endswith("+json")
        ):
            raise UnsupportedMediaType(
                "send the body as JSON with Content-Type: application/json",
                [FieldIssue("body", "not application/json")],
            )


def _json(raw: tuple[str | None, bytes]) -> Any:
    """The parsed JSON of a body (FastAPI's rules: no Content-Type or a JSON one; 415 otherwise)."""
    content_type, data = raw
    _content_type(content_type)
    if not data:
        raise InvalidInput.at("body", "Field required")
    try:
        return pydantic_core.from_json(data, allow_inf_nan=True)  # NaN reaches the field, which says why
    except ValueError as exc:
        raise BadRequest(f"the body is not valid JSON: {exc}", [FieldIssue("body", "invalid JSON")]) from None


_MEMBERS = msgspec.json.Decoder(dict[str, msgspec.Raw])


def _members(raw: tuple[str | None, bytes]) -> dict[str, msgspec.Raw] | None:
    """The members of a body that is one JSON object, each as its JSON text (not decoded), else ``None``
    (not an object, not JSON, or JSON that only pydantic-core reads, such as NaN: ``_json`` then says
    what is wrong or parses it)."""
    content_type, data = raw
    _content_type(content_type)
    try:
        return _MEMBERS.decode(data)
    except (msgspec.MsgspecError, RecursionError):  # msgspec's nesting limit is Python's
        return None


def _at_most(value: object, limit: int, where: str) -> None:
    """422 before validation when ``value`` is an array (or the ids of a plain one) of more than ``limit``
    items."""
    if isinstance(value, list | tuple) and len(value) > limit:
        raise InvalidInput.at(where, f"at most {limit} items per request, got {len(value)}")


def _validate(model: type[M], obj: Any) -> M:
    try:
        return model.model_validate(obj)
    except ValidationError as exc:
        raise from_validation_errors(exc) from None


@dataclass(frozen=True, slots=True)
class EpochPost:
    """A validated epoch body. ``taxis`` (``riders``) is set when every taxi (rider) has the common form
    ``plain_taxis`` (``plain_riders``) reads, and ``body`` is then validated without them: one model per
    item is most of the cost at thousands of taxis and hundreds of riders; otherwise ``body`` holds them,
    validated by the model."""

    body: EpochIn
    taxis: PlainTaxis | None = None
    riders: PlainRiders | None = None


def epoch_post(raw: tuple[str | None, bytes], limits: Limits) -> EpochPost:
    """An epoch body parsed and validated (the route calls it on its threadpool thread: one hop, not two).
    Its ``riders`` and ``taxis`` are read by ``plain_riders`` and ``plain_taxis`` straight from their JSON
    text when they have the common form; every other member, and those two otherwise, is parsed as
    ``_json`` parses a body and validated by the model."""
    members = _members(raw)
    if members is None:
        obj = _json(raw)
        if isinstance(obj, dict):
            _at_most(obj.get("riders"), limits.max_riders, "riders")
            _at_most(obj.get("taxis"), limits.max_taxis, "taxis")
        return EpochPost(_validate(EpochIn, obj))
    riders = plain_riders(members["riders"]) if "riders" in members else None
    taxis = plain_taxis(members["taxis"]) if "taxis" in members else None
    plain = {"riders": riders, "taxis": taxis}
    # valid as they are: the model validates the rest, with the same errors
    obj = {
        key: [] if plain.get(key) is not None else pydantic_core.from_json(bytes(text), allow_inf_nan=True)
        for key, text in members.items()
    }
    _at_most(obj.get("riders") if riders is None else riders.ids, limits.max_riders, "riders")
    _at_most(obj.get("taxis") if taxis is None else taxis.ids, limits.max_taxis, "taxis")
    return EpochPost(_validate(EpochIn, obj), taxis, riders)


def _tasks(raw: RawBody, limits: LimitsDep) -> list[TaskIn]:
    obj = _json(raw)
    _at_most(obj, limits.max_tasks, "body")
    try:
        return _TASKS.validate_python(obj)
    except ValidationError as exc:
        raise from_validation_errors(exc) from None


def _worst_case(raw: RawBody) -> WorstCaseIn:
    obj = _json(raw)
    if isinstance(obj, dict):
        _at_most(obj.get("samples"), MAX_SAMPLES, "samples")
    return _validate(WorstCaseIn, obj)


def _rewind(raw: RawBody) -> RewindIn:
    return _validate(RewindIn, _json(raw))


def _reset(raw: RawBody) -> ResetIn:
    return _validate(ResetIn, _json(raw))


# plain ``def`` dependencies: FastAPI runs them in the threadpool, never on the event loop
TasksBody = Annotated[list[TaskIn], Depends(_tasks)]
WorstCaseBody = Annotated[WorstCaseIn, Depends(_worst_case)]
RewindBody = Annotated[RewindIn, Depends(_rewind)]
ResetBody = Annotated[ResetIn, Depends(_reset)]

_MODELS: tuple[type[BaseModel], ...] = (EpochIn, TaskIn, WorstCaseIn, RewindIn, ResetIn)


def ref(name: str | type[BaseModel]) -> dict[str, str]:
    """A JSON reference to a request schema in the document's components (``openapi_components``)."""
    return {"$ref": f"#/components/schemas/{name if isinstance(name, str) else name.__name__}"}


def request_body(schema: str | type[BaseModel]) -> dict[str, Any]:
    """``openapi_extra`` of a route whose body is read by one of the dependencies above."""
    return {"requestBody": {"required": True, "content": {"application/json": {"schema": ref(schema)}}}}


def openapi_components(limits: Limits) -> dict[str, Any]:
    """The request models' schemas for ``components.schemas``, with the configured array limits."""
    _, doc = models_json_schema(
        [(m, "validation") for m in _MODELS], ref_template="#/components/schemas/{model}"
    )
    schemas: dict[str, Any] = doc.get("$defs", {})
    epoch = schemas["EpochIn"]["properties"]
    epoch["riders"]["maxItems"] = limits.max_riders
    epoch["taxis"]["maxItems"] = limits.max_taxis
    schemas["TasksIn"] = {
        "title": "TasksIn",
        "description": "Tasks to register; idempotent per id.",
        "type": "array",
        "items": ref(TaskIn),
        "maxItems": limits.max_tasks,
    }
    return schemas
