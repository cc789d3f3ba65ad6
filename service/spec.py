"""The app's OpenAPI document, describing the running configuration.

FastAPI's document is adjusted once per app (:func:`install_openapi`), so that every status it lists
can happen and every status the service answers with is listed:

- **Auth.** With API keys configured, each protected operation keeps its security requirement (the
  scope) and lists ``401`` and ``403``, and ``429`` ``rate_limited`` when a rate limit is set. With no
  keys, requests need no key: the requirements, the ``X-API-Key`` scheme and those answers are dropped.
- **Errors.** ``422`` has the service's own body (:class:`contracts.api.ErrorResponse`), not FastAPI's
  default; multipart uploads list ``400`` (a body that is not valid multipart); operations that write
  (POST, DELETE) list ``507`` (disk full).
- **Forms.** An optional form field is simply left out; multipart has no ``null``, so the ``null``
  branch FastAPI derives from ``float | None`` is removed from the form schemas. File fields say
  ``minLength: 1`` (an empty file is refused).
"""

from __future__ import annotations

from typing import Any

from fastapi import FastAPI
from fastapi.openapi.utils import get_openapi

from contracts.settings import Settings

Schema = dict[str, Any]
ERROR_REF = {"$ref": "#/components/schemas/ErrorResponse"}
FASTAPI_VALIDATION_SCHEMAS = ("HTTPValidationError", "ValidationError")
RETRY_AFTER_HEADER: Schema = {
    "Retry-After": {
        "description": "Seconds to wait before trying again",
        "schema": {"type": "integer", "minimum": 1},
    }
}
WRITE_METHODS = ("post", "put", "patch", "delete")


def error_response(description: str, headers: Schema | None = None) -> Schema:
    """An OpenAPI response with the service's error body."""
    response: Schema = {"description": description, "content": {"application/json": {"schema": ERROR_REF}}}
    if headers:
        response["headers"] = headers
    return response


QUEUE_FULL_RESPONSE: dict[int | str, dict[str, Any]] = {
    429: {
        "description": "The job queue is full (`queue_full`): nothing was stored; retry after `Retry-After` seconds",
        "content": {"application/json": {"schema": ERROR_REF}},
        "headers": RETRY_AFTER_HEADER,
    }
}
"""``responses=`` entry of the routes that enqueue jobs (:func:`service.limits.require_queue_capacity`)."""


def _strip_null(schema: Schema) -> None:
    """``anyOf: [X, {type: null}]`` -> X, in place, on every property of a form schema."""
    for name, prop in list(schema.get("properties", {}).items()):
        branches = prop.get("anyOf")
        if not branches:
            continue
        kept = [branch for branch in branches if branch.get("type") != "null"]
        if len(kept) == len(branches):
            continue
        rest = {key: value for key, value in prop.items() if key != "anyOf"}
        if rest.get("default", ...) is None:
            del rest["default"]
        schema["properties"][name] = {**kept[0], **rest} if len(kept) == 1 else {**rest, "anyOf": kept}


def _files_not_empty(schema: Schema) -> None:
    """Mark the file fields of a form schema ``minLength: 1``: an empty upload is ``422 empty_file``."""
    for prop in schema.get("properties", {}).values():
        if prop.get("type") == "string" and ("contentMediaType" in prop or prop.get("format") == "binary"):
            prop["minLength"] = 1


def _file_lists_required(schema: Schema) -> None:
    """Mark a form's repeated file field (a track's ``images``) required, at least one: none is a ``422``.

    Such a field is optional in the route's signature only because the operation also takes a JSON body.
    """
    for name, prop in schema.get("properties", {}).items():
        items = prop.get("items", {})
        if prop.get("type") == "array" and ("contentMediaType" in items or items.get("format") == "binary"):
            prop["minItems"] = 1
            prop.pop("default", None)
            if name not in schema.setdefault("required", []):
                schema["required"].append(name)


def _form_schema(spec: Schema, operation: Schema) -> Schema | None:
    content = operation.get("requestBody", {}).get("content", {})
    ref = content.get("multipart/form-data", {}).get("schema", {}).get("$ref")
    return spec["components"]["schemas"].get(ref.rsplit("/", 1)[-1]) if ref else None


def adjust(spec: Schema, settings: Settings) -> Schema:
    """Make FastAPI's document ``spec`` describe the service as configured by ``settings`` (in place)."""
    schemas: Schema = spec.setdefault("components", {}).setdefault("schemas", {})
    for item in spec.get("paths", {}).values():
        for method, operation in item.items():
            responses: Schema = operation.setdefault("responses", {})
            if "422" in responses:
                responses["422"] = error_response("The request is invalid: the error's `code` and `message` say how")
            form = _form_schema(spec, operation)
            if form is not None:
                _strip_null(form)
                _files_not_empty(form)
                _file_lists_required(form)
                responses.setdefault("400", error_response("The body is not valid `multipart/form-data`"))
            if method in WRITE_METHODS:
                responses.setdefault("507", error_response("The server's storage is full: nothing was stored"))
            _adjust_security(operation, responses, settings)
            operation["responses"] = dict(sorted(responses.items()))
    for name in FASTAPI_VALIDATION_SCHEMAS:
        schemas.pop(name, None)
    if not settings.auth_enabled:
        spec["components"].pop("securitySchemes", None)
    return spec


def _adjust_security(operation: Schema, responses: Schema, settings: Settings) -> None:
    """Drop an operation's security requirement when auth is off; else document its 401, 403 and 429."""
    if "security" not in operation:
        return
    if not settings.auth_enabled:
        del operation["security"]
        return
    responses.setdefault("401", error_response("Missing or unknown API key"))
    responses.setdefault("403", error_response("The API key lacks the scope"))
    if settings.rate_limit_per_min > 0:
        description = f"More than {settings.rate_limit_per_min} requests a minute with this key"
        description += " (`rate_limited`)"
        if "429" in responses:
            description = f"{responses['429']['description']}; or: {description}"
        responses["429"] = error_response(description, RETRY_AFTER_HEADER)


def install_openapi(app: FastAPI, settings: Settings) -> None:
    """Serve :func:`adjust`-ed OpenAPI for ``app`` (built on first use, then cached by FastAPI)."""

    def openapi() -> Schema:
        if app.openapi_schema is None:
            spec = get_openapi(
                title=app.title,
                version=app.version,
                summary=app.summary,
                description=app.description,
                routes=app.routes,
            )
            app.openapi_schema = adjust(spec, settings)
        return app.openapi_schema

    # FastAPI's documented way to customise the document is to replace the app's ``openapi`` method.
    app.openapi = openapi  # type: ignore[method-assign]
