"""Render the app's OpenAPI schema as a Markdown reference (``openapi.md`` at the repo root).

``python -m service.openapi_doc`` writes it; ``python -m service.openapi_doc --check`` exits 1 with
a diff when the checked-in file is not current (``tests/test_openapi_doc.py`` runs the check).
The output is deterministic: the app is built with default settings (the environment does not
leak in), everything is ordered, and there are no timestamps.
"""

from __future__ import annotations

import argparse
import ast
import difflib
import json
import re
import sys
from collections.abc import Iterable
from pathlib import Path
from typing import Any

REPO_ROOT = Path(__file__).resolve().parent.parent
DEFAULT_OUTPUT = REPO_ROOT / "openapi.md"
TAG_ORDER = ("maps", "references", "queries", "jobs", "system")
"""Sections in this order; other tags follow alphabetically."""
METHOD_ORDER = ("get", "post", "put", "patch", "delete")
FASTAPI_VALIDATION_SCHEMAS = ("HTTPValidationError", "ValidationError")
"""FastAPI's default 422 body; this app answers 422 with ``ErrorResponse`` instead (service/errors.py)."""
HTTP_PHRASES = {
    200: "OK", 201: "Created", 202: "Accepted", 204: "No Content", 400: "Bad Request", 401: "Unauthorized",
    403: "Forbidden", 404: "Not Found", 405: "Method Not Allowed", 409: "Conflict", 413: "Request Entity Too Large",
    415: "Unsupported Media Type", 422: "Unprocessable Entity", 429: "Too Many Requests",
    500: "Internal Server Error", 503: "Service Unavailable",
}  # fmt: skip


def build_schema() -> tuple[dict[str, Any], dict[tuple[str, str], str | None]]:
    """The OpenAPI schema of the app with default settings, and the API-key scope of each (method, path)."""
    from service.app import create_app
    from service.auth import require_read, require_write
    from service.settings import Settings

    app = create_app(Settings.from_values(data_dir=Path("/nonexistent-geoloc-data")))  # not touched: no lifespan runs
    scopes: dict[tuple[str, str], str | None] = {}
    for route in _api_routes(app.router.routes):
        calls = {dep.call for dep in route.dependant.dependencies}
        scope = "write" if require_write in calls else "read" if require_read in calls else None
        for method in route.methods or ():
            scopes[(method.lower(), route.path_format)] = scope
    return app.openapi(), scopes


def _api_routes(routes: Iterable[Any]) -> Iterable[Any]:
    """Every ``APIRoute``, also inside included routers (FastAPI >= 0.13x keeps those as ``original_router``)."""
    from fastapi.routing import APIRoute

    for route in routes:
        if isinstance(route, APIRoute):
            yield route
        elif getattr(route, "original_router", None) is not None:
            yield from _api_routes(route.original_router.routes)


def error_codes() -> list[tuple[int, str]]:
    """(status, code) of every ``ApiError(status, "code", ...)`` and ``error_body("code", ...)`` in the
    service, found in its source (so new codes show up without a list to maintain)."""
    found: set[tuple[int, str]] = set()
    for path in sorted(Path(__file__).parent.glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if not isinstance(node, ast.Call):
                continue
            name = getattr(node.func, "id", None) or getattr(node.func, "attr", None)
            args = [a.value if isinstance(a, ast.Constant) else None for a in node.args]
            if name == "ApiError" and len(args) >= 2 and isinstance(args[0], int) and isinstance(args[1], str):
                found.add((args[0], args[1]))
            elif name == "error_body" and args and isinstance(args[0], str):
                status = {"payload_too_large": 413, "not_ready": 503}.get(args[0])
                if status is not None:
                    found.add((status, args[0]))
    from service.errors import _CODES_BY_STATUS

    found.update(_CODES_BY_STATUS.items())
    return sorted(found)


# --- small renderers ----------------------------------------------------------------------------


def slug(heading: str) -> str:
    """GitHub's anchor for a heading."""
    text = re.sub(r"[^\w\- ]", "", heading.strip().lower())
    return text.replace(" ", "-")


def ref_name(ref: str) -> str:
    return ref.rsplit("/", 1)[-1]


def model_link(name: str) -> str:
    return f"[`{name}`](#{slug(name)})"


def prose(text: str | None) -> str:
    """Docstring text as Markdown: RST literals to backticks, paragraphs kept."""
    text = (text or "").strip()
    return re.sub(r"``([^`]+)``", r"`\1`", text)


def cell(text: str | None) -> str:
    """Text for a table cell (one line, pipes escaped)."""
    return " ".join(prose(text).split()).replace("|", "\\|")


def type_of(schema: dict[str, Any]) -> str:
    """A short, readable type: ``integer``, ``number | null``, ``list[MapOut]``, ``"a" | "b"``, ``file``."""
    if "$ref" in schema:
        return model_link(ref_name(schema["$ref"]))
    if "anyOf" in schema or "oneOf" in schema:
        parts = [type_of(s) for s in schema.get("anyOf", schema.get("oneOf", []))]
        return " \\| ".join(dict.fromkeys(parts))
    if "enum" in schema:
        return " \\| ".join(json.dumps(v) for v in schema["enum"])
    if "const" in schema:
        return json.dumps(schema["const"])
    kind = schema.get("type")
    if kind == "array":
        return f"list[{type_of(schema.get('items', {}))}]"
    if kind == "string" and (schema.get("format") == "binary" or "contentMediaType" in schema):
        return "file"
    if kind == "string" and "format" in schema:
        return f"string ({schema['format']})"
    if kind == "object" or (kind is None and "additionalProperties" in schema):
        return "object"
    return str(kind or "any")


def constraints(schema: dict[str, Any]) -> str:
    """Bounds and lengths of a field, e.g. ``1 ≤ x ≤ 100``."""
    parts = []
    for key, text in (("minimum", "≥"), ("exclusiveMinimum", ">"), ("maximum", "≤"), ("exclusiveMaximum", "<")):
        if key in schema:
            parts.append(f"{text} {schema[key]}")
    if "minLength" in schema or "maxLength" in schema:
        parts.append(f"length {schema.get('minLength', 0)}..{schema.get('maxLength', '')}")
    for sub in schema.get("anyOf", []):
        extra = constraints(sub)
        if extra:
            parts.append(extra)
    return ", ".join(parts)


def describe(schema: dict[str, Any], *, required: bool) -> str:
    """Description cell: text, constraints, default."""
    text = cell(schema.get("description"))
    extra = constraints(schema)
    if extra:
        text = f"{text} ({extra})" if text else extra
    if not required and "default" in schema and schema["default"] is not None:
        text = f"{text} Default `{json.dumps(schema['default'])}`.".strip()
    return text


def table(header: Iterable[str], rows: Iterable[Iterable[str]]) -> list[str]:
    header = list(header)
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join(" --- " for _ in header) + "|"]
    lines += ["| " + " | ".join(row) + " |" for row in rows]
    return lines


def json_block(value: Any) -> list[str]:
    return ["```json", json.dumps(value, indent=2, sort_keys=True, ensure_ascii=False), "```"]


class Renderer:
    """Turns one OpenAPI document into Markdown."""

    def __init__(self, spec: dict[str, Any], scopes: dict[tuple[str, str], str | None]) -> None:
        self.spec = spec
        self.scopes = scopes
        self.schemas: dict[str, Any] = spec.get("components", {}).get("schemas", {})

    # -- schemas and examples --

    def resolve(self, schema: dict[str, Any]) -> dict[str, Any]:
        while "$ref" in schema:
            schema = self.schemas[ref_name(schema["$ref"])]
        return schema

    def example(self, schema: dict[str, Any], depth: int = 0) -> Any:
        """An example value: the model's own ``examples``, else one built from its fields' examples
        (None when a required field has none)."""
        if depth > 8:
            return None
        schema = self.resolve(schema)
        if schema.get("examples"):
            return schema["examples"][0]
        if "example" in schema:
            return schema["example"]
        if "anyOf" in schema:
            options = [s for s in schema["anyOf"] if s.get("type") != "null"]
            return self.example(options[0], depth + 1) if len(options) == 1 else None
        if schema.get("type") == "array":
            item = self.example(schema.get("items", {}), depth + 1)
            return [item] if item is not None else None
        if "properties" not in schema:
            return None
        out: dict[str, Any] = {}
        required = set(schema.get("required", []))
        for name, field in schema["properties"].items():
            value = self.example(field, depth + 1)
            if value is None and name in required:
                return None
            if value is not None:
                out[name] = value
        return out or None

    def fields_table(self, schema: dict[str, Any]) -> list[str]:
        schema = self.resolve(schema)
        required = set(schema.get("required", []))
        rows = [
            [
                f"`{name}`",
                type_of(field),
                "yes" if name in required else "no",
                describe(field, required=name in required),
            ]
            for name, field in schema.get("properties", {}).items()
        ]
        return table(["field", "type", "required", "description"], rows) if rows else ["(no fields)"]

    # -- operations --

    def operations(self) -> list[tuple[str, str, str, dict[str, Any]]]:
        """(tag, method, path, operation), in section order, then by path and method."""
        ops = []
        for path, item in self.spec.get("paths", {}).items():
            for method, op in item.items():
                if method in METHOD_ORDER:
                    ops.append(((op.get("tags") or ["other"])[0], method, path, op))

        def key(entry: tuple[str, str, str, dict[str, Any]]) -> tuple[int, str, str, int]:
            tag, method, path, _ = entry
            rank = TAG_ORDER.index(tag) if tag in TAG_ORDER else len(TAG_ORDER)
            return rank, tag, path, METHOD_ORDER.index(method)

        return sorted(ops, key=key)

    def summary_of(self, op: dict[str, Any]) -> str:
        """First sentence of the description, else FastAPI's summary."""
        first = prose(op.get("description")).split("\n\n")[0]
        return cell(first) or cell(op.get("summary"))

    def auth_of(self, method: str, path: str, op: dict[str, Any]) -> str:
        scope = self.scopes.get((method, path))
        if scope:
            return f"`X-API-Key` with scope `{scope}`"
        return "API key (any scope)" if op.get("security") else "none"

    def body_of(self, response: dict[str, Any]) -> tuple[str, dict[str, Any] | None]:
        """(what the body is, its schema) for a response."""
        content = response.get("content") or {}
        if not content:
            return "(empty)", None
        media, entry = sorted(content.items())[0]
        schema = entry.get("schema") or {}
        if "$ref" in schema and ref_name(schema["$ref"]) in FASTAPI_VALIDATION_SCHEMAS:
            schema = {"$ref": "#/components/schemas/ErrorResponse"}
        if not schema or schema == {}:
            return f"`{media}`", None
        return (type_of(schema) if media == "application/json" else f"`{media}`: {type_of(schema)}"), schema

    def operation(self, method: str, path: str, op: dict[str, Any]) -> list[str]:
        lines = [f"### {method.upper()} {path}", ""]
        description = prose(op.get("description")) or cell(op.get("summary"))
        lines += [description, "", f"Auth: {self.auth_of(method, path, op)}.", ""]

        params = op.get("parameters", [])
        for where in ("path", "query", "header"):
            rows = [
                [f"`{p['name']}`", type_of(p.get("schema", {})), "yes" if p.get("required") else "no",
                 describe({**p.get("schema", {}), "description": p.get("description")}, required=p.get("required"))]
                for p in params
                if p.get("in") == where
            ]  # fmt: skip
            if rows:
                lines += [f"**{where.capitalize()} parameters**", ""]
                lines += table(["name", "type", "required", "description"], rows) + [""]

        body = op.get("requestBody")
        if body:
            media, entry = sorted(body.get("content", {}).items())[0]
            schema = entry.get("schema", {})
            lines += [f"**Request body** (`{media}`{', required' if body.get('required') else ''})", ""]
            lines += self.fields_table(schema) + [""]
            if media == "application/json":
                example = self.example(schema)
                if example is not None:
                    lines += ["Example request body:", "", *json_block(example), ""]

        responses = op.get("responses", {})
        rows: list[list[str]] = []
        examples: dict[str, list[str]] = {}  # example JSON -> statuses it answers
        for status in sorted(responses, key=lambda s: (int(s) if s.isdigit() else 999, s)):
            response = responses[status]
            what, schema = self.body_of(response)
            code = int(status) if status.isdigit() else None
            meaning = response.get("description") or ""
            if meaning in ("Successful Response", "Validation Error") or not meaning:
                meaning = HTTP_PHRASES.get(code or 0, meaning)
            rows.append([f"`{status}`", cell(meaning), what])
            if code is not None and 200 <= code < 300 and schema is not None:
                example = self.example(schema)
                if example is not None:
                    examples.setdefault(json.dumps(example, sort_keys=True), []).append(f"`{status}`")
        lines += ["**Responses**", "", *table(["status", "meaning", "body"], rows), ""]
        for example, statuses in examples.items():
            lines += [f"Example {' / '.join(statuses)} response:", "", *json_block(json.loads(example)), ""]
        return lines

    # -- the document --

    def render(self) -> str:
        info = self.spec.get("info", {})
        lines = [
            f"# {info.get('title', 'API')} REST API reference (version {info.get('version', '?')})",
            "",
            "<!-- Generated from the FastAPI app by `python -m service.openapi_doc`; do not edit by hand. "
            "CI checks it is current (tests/test_openapi_doc.py). -->",
            "",
        ]
        if info.get("summary"):
            lines += [f"*{cell(info['summary'])}*", ""]
        if info.get("description"):
            lines += [prose(info["description"]), ""]
        lines += self.conventions()
        ops = self.operations()
        lines += ["## Endpoints", ""]
        lines += table(
            ["method", "path", "what", "auth"],
            [
                [f"`{m.upper()}`", f"[`{p}`](#{slug(f'{m} {p}')})", self.summary_of(op), self.scopes.get((m, p)) or "-"]
                for _, m, p, op in ops
            ],
        )
        lines.append("")
        current = None
        for tag, method, path, op in ops:
            if tag != current:
                current = tag
                lines += [f"## {tag.capitalize()}", ""]
                tag_doc = next((t for t in self.spec.get("tags", []) if t.get("name") == tag), None)
                if tag_doc and tag_doc.get("description"):
                    lines += [prose(tag_doc["description"]), ""]
            lines += self.operation(method, path, op)
        lines += self.models()
        return "\n".join(line.rstrip() for line in lines).rstrip() + "\n"

    def conventions(self) -> list[str]:
        schemes = self.spec.get("components", {}).get("securitySchemes", {})
        lines = ["## Conventions", "", "### Authentication", ""]
        for name, scheme in sorted(schemes.items()):
            if scheme.get("type") == "apiKey":
                where = f"`{scheme.get('name')}` {scheme.get('in')}"
                lines.append(f"Send the key in the {where} ({name}): {prose(scheme.get('description'))}.")
        lines += [
            "",
            "Keys and their scopes are configured with `GEOLOC_API_KEYS` (`KEY:SCOPES`, scopes `read`, `write` "
            "joined by `+`; `write` implies `read`). A missing or unknown key is `401`, a key without the "
            "endpoint's scope is `403`. With no keys configured authentication is off and the service only "
            "listens on a loopback address. Each endpoint below states the scope it needs.",
            "",
            "### Errors",
            "",
            "Every 4xx and 5xx answer has the same JSON body, "
            + (model_link("ErrorResponse") if "ErrorResponse" in self.schemas else "`{error: {...}}`")
            + ": a machine-readable `code`, a `message` for people, and optional `details` (limits, distances, "
            "the invalid fields):",
            "",
        ]
        if "ErrorResponse" in self.schemas:
            example = self.example({"$ref": "#/components/schemas/ErrorResponse"})
            if example is not None:
                lines += [*json_block(example), ""]
        codes = error_codes()
        if codes:
            lines += ["Error codes the service answers with:", ""]
            lines += table(
                ["status", "code"], [[f"`{s}` {HTTP_PHRASES.get(s, '')}".rstrip(), f"`{c}`"] for s, c in codes]
            )
            lines.append("")
        lines += [
            "Request validation errors (a missing field, a value of the wrong type) are `422` with code "
            "`invalid_request` and `details.problems`, a list of `{field, problem}`.",
            "",
            "### Formats",
            "",
            "Positions are WGS84 latitude/longitude in degrees; headings are degrees clockwise from north; "
            "times are ISO 8601 in UTC. Uploads are `multipart/form-data`; files are checked by their content, "
            "not their name.",
            "",
        ]
        return lines

    def models(self) -> list[str]:
        names = sorted(n for n in self.schemas if n not in FASTAPI_VALIDATION_SCHEMAS and not n.startswith("Body_"))
        lines = ["## Models", ""]
        for name in names:
            schema = self.schemas[name]
            lines += [f"### {name}", ""]
            if schema.get("description"):
                lines += [prose(schema["description"]), ""]
            lines += self.fields_table(schema) + [""]
            example = self.example(schema)
            if example is not None:
                lines += ["Example:", "", *json_block(example), ""]
        return lines


def render_markdown() -> str:
    """The Markdown reference of the current app."""
    spec, scopes = build_schema()
    return Renderer(spec, scopes).render()


def main(argv: list[str] | None = None) -> int:
    """Write ``openapi.md`` (or check it is current with ``--check``)."""
    parser = argparse.ArgumentParser(prog="python -m service.openapi_doc", description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="exit 1 if the file is not current; write nothing")
    parser.add_argument("--output", type=Path, default=DEFAULT_OUTPUT, help="default: openapi.md at the repo root")
    args = parser.parse_args(argv)
    text = render_markdown()
    current = args.output.read_text() if args.output.exists() else ""
    if args.check:
        if current == text:
            print(f"{args.output} is current")
            return 0
        diff = list(
            difflib.unified_diff(current.splitlines(), text.splitlines(), "checked in", "generated", lineterm="")
        )
        shown = "\n".join(diff[:60]) + (f"\n... ({len(diff) - 60} more diff lines)" if len(diff) > 60 else "")
        print(
            f"{args.output} is out of date with the app; regenerate it with `python -m service.openapi_doc`.\n{shown}",
            file=sys.stderr,
        )
        return 1
    if current != text:
        args.output.write_text(text)
        print(f"wrote {args.output}")
    else:
        print(f"{args.output} already current")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
