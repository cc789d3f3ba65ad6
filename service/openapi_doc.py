"""Write the API reference from the app's own OpenAPI JSON: ``openapi.json`` and ``openapi.md``.

``python -m service.openapi_doc`` writes both files at the repository root; with ``--check`` it
writes nothing and exits 1 with a diff when either is not current (``tests/unit/service/test_openapi_doc.py``
runs the check in CI). The Markdown is rendered from the JSON alone (:func:`render_markdown`),
so it shows exactly what the schema says: auth scopes from each operation's security
requirement, error codes from ``ErrorDetail.code``'s ``x-error-codes``, and every field's
constraints (bounds, lengths, enums, defaults). The app is built with default settings and one API
key configured (the served document follows the running configuration, :mod:`service.spec`; the
reference shows a deployment with keys, whose surface includes authentication, ``401``/``403`` and the
rate limit), so the environment does not leak into the output.
"""

from __future__ import annotations

import argparse
import difflib
import json
import re
import sys
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from contracts.settings import Settings
from service.app import create_app

REPO_ROOT = Path(__file__).resolve().parent.parent
DEFAULT_JSON = REPO_ROOT / "openapi.json"
DEFAULT_MARKDOWN = REPO_ROOT / "openapi.md"
TAG_ORDER = ("maps", "references", "queries", "jobs", "system")
"""Sections in this order; other tags follow alphabetically."""
METHOD_ORDER = ("get", "post", "put", "patch", "delete")
HIDDEN_SCHEMAS = ("HTTPValidationError", "ValidationError")
"""FastAPI's default 422 body; this app answers 422 with ``ErrorResponse`` instead (``service/errors.py``)."""
HTTP_PHRASES = {
    200: "OK", 201: "Created", 202: "Accepted", 204: "No Content", 400: "Bad Request", 401: "Unauthorized",
    403: "Forbidden", 404: "Not Found", 405: "Method Not Allowed", 409: "Conflict", 413: "Content Too Large",
    415: "Unsupported Media Type", 422: "Unprocessable Content", 429: "Too Many Requests",
    500: "Internal Server Error", 503: "Service Unavailable", 507: "Insufficient Storage",
}  # fmt: skip
Schema = dict[str, Any]


def openapi_spec() -> Schema:
    """The app's OpenAPI document with default settings and API keys configured (no database is touched)."""
    settings = Settings.from_values(data_dir=Path("/nonexistent-geoloc-data"), api_keys="documented-key:read+write")
    return create_app(settings).openapi()


def openapi_json(spec: Schema) -> str:
    """The document as the committed ``openapi.json`` text."""
    return json.dumps(spec, indent=2, ensure_ascii=False) + "\n"


# --- small renderers ----------------------------------------------------------------------------


def _slug(heading: str) -> str:
    """GitHub's anchor for a heading."""
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


def _ref_name(ref: str) -> str:
    return ref.rsplit("/", 1)[-1]


def _model_link(name: str) -> str:
    return f"[`{name}`](#{_slug(name)})"


def _prose(text: str | None) -> str:
    """Docstring text as Markdown: RST literals to backticks, paragraphs kept."""
    return re.sub(r"``([^`]+)``", r"`\1`", (text or "").strip())


def _cell(text: str | None) -> str:
    """Text for a table cell (one line, pipes escaped)."""
    return " ".join(_prose(text).split()).replace("|", "\\|")


def _number(value: float) -> str:
    """A bound as written: integers exactly (ids reach 2**63 - 1), other numbers short."""
    return str(value) if isinstance(value, int) else f"{value:g}"


def _table(header: list[str], rows: Iterable[list[str]]) -> list[str]:
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join(" --- " for _ in header) + "|"]
    return lines + ["| " + " | ".join(row) + " |" for row in rows]


def _json_block(value: Any) -> list[str]:
    return ["```json", json.dumps(value, indent=2, sort_keys=True, ensure_ascii=False), "```"]


def type_of(schema: Schema) -> str:
    """A short, readable type: ``integer``, ``number | null``, ``list[MapOut]``, ``file``."""
    if "$ref" in schema:
        return _model_link(_ref_name(schema["$ref"]))
    if "anyOf" in schema or "oneOf" in schema:
        parts = [type_of(s) for s in schema.get("anyOf") or schema.get("oneOf") or []]
        return " \\| ".join(dict.fromkeys(parts))
    if "const" in schema:
        return json.dumps(schema["const"])
    kind = schema.get("type")
    if kind == "array":
        items = schema.get("prefixItems")
        if items:
            return "[" + ", ".join(type_of(s) for s in items) + "]"
        return f"list[{type_of(schema.get('items', {}))}]"
    if kind == "string" and (schema.get("format") == "binary" or "contentMediaType" in schema):
        return "file"
    if kind == "string" and "format" in schema:
        return f"string ({schema['format']})"
    if kind == "object" or (kind is None and "additionalProperties" in schema):
        return "object"
    return str(kind or "any")


def constraints(schema: Schema, *, required: bool) -> str:
    """What a value must satisfy and its default, e.g. ``1 – 50; default `10```.

    Reads ``minimum``/``maximum`` (also exclusive), ``minLength``/``maxLength``, ``minItems``/
    ``maxItems``, ``pattern``, ``enum`` and ``default``, on the schema and on the branches of an ``anyOf``.
    """
    merged = dict(schema)
    for branch in schema.get("anyOf", []):
        merged.update({k: v for k, v in branch.items() if k not in merged})
    if type_of(schema) == "file":  # a file's minLength counts bytes: 1 means it may not be empty
        parts = ["not empty"] if merged.get("minLength") == 1 else []
    else:
        parts = [*_bounds(merged), *_sizes(merged)]
    if merged.get("pattern"):
        parts.append(f"matches `{merged['pattern']}`")
    if merged.get("enum"):
        parts.append("one of " + ", ".join(f"`{json.dumps(v)}`" for v in merged["enum"]))
    if not required and merged.get("default") is not None:
        parts.append(f"default `{json.dumps(merged['default'])}`")
    return "; ".join(parts)


def _bounds(schema: Schema) -> list[str]:
    """Numeric bounds: ``low – high`` when both are inclusive, else one ``≥ / ≤ / > / <`` each."""
    low, high = schema.get("minimum"), schema.get("maximum")
    if low is not None and high is not None:
        parts = [f"{_number(low)} – {_number(high)}"]
    else:
        parts = [
            f"{sign} {_number(schema[key])}" for key, sign in (("minimum", "≥"), ("maximum", "≤")) if key in schema
        ]
    signs = (("exclusiveMinimum", ">"), ("exclusiveMaximum", "<"))
    return parts + [f"{sign} {_number(schema[key])}" for key, sign in signs if key in schema]


def _sizes(schema: Schema) -> list[str]:
    """Length limits of strings (characters) and arrays (items)."""
    sizes = (("characters", "minLength", "maxLength"), ("items", "minItems", "maxItems"))
    return [
        f"{schema.get(low, 0)} – {schema.get(high, '∞')} {unit}"
        for unit, low, high in sizes
        if low in schema or high in schema
    ]


class Renderer:
    """Turns one OpenAPI document into the Markdown reference."""

    def __init__(self, spec: Schema) -> None:
        self.spec = spec
        self.schemas: dict[str, Schema] = spec.get("components", {}).get("schemas", {})

    def resolve(self, schema: Schema) -> Schema:
        """Follow ``$ref`` to the component schema."""
        while "$ref" in schema:
            schema = self.schemas[_ref_name(schema["$ref"])]
        return schema

    def example(self, schema: Schema, depth: int = 0) -> Any:
        """An example: the schema's own, else one built from its fields' (None if a required field has none)."""
        schema = self.resolve(schema)
        if depth > 8:
            return None
        if schema.get("examples"):
            return schema["examples"][0]
        if "anyOf" in schema:
            options = [s for s in schema["anyOf"] if s.get("type") != "null"]
            return self.example(options[0], depth + 1) if len(options) == 1 else None
        if schema.get("type") == "array" and "items" in schema:
            item = self.example(schema["items"], depth + 1)
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

    def fields_table(self, schema: Schema) -> list[str]:
        """One row per property: name, type, required, constraints, description."""
        schema = self.resolve(schema)
        required = set(schema.get("required", []))
        rows = [
            [
                f"`{name}`",
                type_of(field),
                "yes" if name in required else "no",
                constraints(field, required=name in required),
                _cell(field.get("description")),
            ]
            for name, field in schema.get("properties", {}).items()
        ]
        if not rows:
            return ["(no fields)"]
        return _table(["field", "type", "required", "constraints", "description"], rows)

    def operations(self) -> list[tuple[str, str, str, Schema]]:
        """(tag, method, path, operation) in section order, then by path and method."""
        ops = [
            ((op.get("tags") or ["other"])[0], method, path, op)
            for path, item in self.spec.get("paths", {}).items()
            for method, op in item.items()
            if method in METHOD_ORDER
        ]

        def key(entry: tuple[str, str, str, Schema]) -> tuple[int, str, str, int]:
            tag, method, path, _ = entry
            rank = TAG_ORDER.index(tag) if tag in TAG_ORDER else len(TAG_ORDER)
            return rank, tag, path, METHOD_ORDER.index(method)

        return sorted(ops, key=key)

    @staticmethod
    def scope_of(op: Schema) -> str | None:
        """The API-key scope of an operation's security requirement, ``"any"`` without one, None if open."""
        for requirement in op.get("security", []):
            for scopes in requirement.values():
                return ", ".join(scopes) or "any"
        return None

    def body_of(self, response: Schema) -> tuple[str, Schema | None]:
        """(what the body is, its schema) for a response: JSON first, then the other media types it may have."""
        content = response.get("content") or {}
        if not content:
            return "(empty)", None
        (media, entry), *others = sorted(content.items(), key=lambda item: (item[0] != "application/json", item[0]))
        also = "".join(f"; or `{other}`" for other, _ in others)
        schema = entry.get("schema") or {}
        if "$ref" in schema and _ref_name(schema["$ref"]) in HIDDEN_SCHEMAS:
            schema = {"$ref": "#/components/schemas/ErrorResponse"}
        if not schema:
            return f"`{media}`{also}", None
        return (type_of(schema) if media == "application/json" else f"`{media}`: {type_of(schema)}") + also, schema

    def operation(self, method: str, path: str, op: Schema) -> list[str]:
        """The section of one operation: description, auth, parameters, body, responses, example."""
        scope = self.scope_of(op)
        auth = f"`X-API-Key` with scope `{scope}`" if scope else "none"
        lines = [f"### {method.upper()} {path}", "", _prose(op.get("description")) or _cell(op.get("summary"))]
        lines += ["", f"Auth: {auth}.", ""]
        for where in ("path", "query", "header"):
            parameter_rows = [
                [
                    f"`{p['name']}`",
                    type_of(p.get("schema", {})),
                    "yes" if p.get("required") else "no",
                    constraints(p.get("schema", {}), required=bool(p.get("required"))),
                    _cell(p.get("description") or p.get("schema", {}).get("description")),
                ]
                for p in op.get("parameters", [])
                if p.get("in") == where
            ]
            if parameter_rows:
                lines += [f"**{where.capitalize()} parameters**", ""]
                lines += _table(["name", "type", "required", "constraints", "description"], parameter_rows) + [""]
        body = op.get("requestBody")
        if body:
            for media, entry in sorted(body.get("content", {}).items()):  # each form a route takes (tracks: two)
                lines += [f"**Request body** (`{media}`{', required' if body.get('required') else ''})", ""]
                lines += self.fields_table(entry.get("schema", {})) + [""]
        rows: list[list[str]] = []
        examples: dict[str, list[str]] = {}  # example JSON -> the statuses it answers
        responses = op.get("responses", {})
        for status in sorted(responses, key=lambda s: (int(s) if s.isdigit() else 999, s)):
            what, schema = self.body_of(responses[status])
            code = int(status) if status.isdigit() else 0
            meaning = responses[status].get("description") or ""
            if meaning in ("", "Successful Response", "Validation Error"):
                meaning = HTTP_PHRASES.get(code, meaning)
            rows.append([f"`{status}`", _cell(meaning), what])
            example = self.example(schema) if schema is not None and 200 <= code < 300 else None
            if example is not None:
                examples.setdefault(json.dumps(example, sort_keys=True), []).append(f"`{status}`")
        lines += ["**Responses**", "", *_table(["status", "meaning", "body"], rows), ""]
        for example_text, statuses in examples.items():
            lines += [f"Example {' / '.join(statuses)} response:", "", *_json_block(json.loads(example_text)), ""]
        return lines

    def conventions(self) -> list[str]:
        """Authentication (from the security schemes) and errors (from ``ErrorDetail``)."""
        lines = ["## Authentication", ""]
        for name, scheme in sorted(self.spec.get("components", {}).get("securitySchemes", {}).items()):
            where = f"`{scheme.get('name')}` {scheme.get('in')}" if scheme.get("type") == "apiKey" else name
            lines += [f"Send the key in the {where} ({name}). {_prose(scheme.get('description'))}", ""]
        lines += ["Each endpoint below states the scope it needs.", "", "## Errors", ""]
        if "ErrorResponse" in self.schemas:
            lines += [
                f"Every 4xx and 5xx answer has the same JSON body, {_model_link('ErrorResponse')}: a "
                "machine-readable `code`, a `message` for people, and optional `details`:",
                "",
            ]
            example = self.example({"$ref": "#/components/schemas/ErrorResponse"})
            if example is not None:
                lines += [*_json_block(example), ""]
        codes = self.schemas.get("ErrorDetail", {}).get("properties", {}).get("code", {}).get("x-error-codes", [])
        if codes:
            lines += ["Error codes the service answers with:", ""]
            rows = [[f"`{c['status']}` {HTTP_PHRASES.get(c['status'], '')}".rstrip(), f"`{c['code']}`"] for c in codes]
            lines += _table(["status", "code"], rows) + [""]
        return lines

    def models(self) -> list[str]:
        """Every component schema but the request bodies (shown with their operation) and FastAPI's 422."""
        lines = ["## Models", ""]
        for name in sorted(self.schemas):
            if name in HIDDEN_SCHEMAS or name.startswith("Body_"):
                continue
            schema = self.schemas[name]
            lines += [f"### {name}", ""]
            if schema.get("description"):
                lines += [_prose(schema["description"]), ""]
            lines += self.fields_table(schema) + [""]
            example = self.example(schema)
            if example is not None:
                lines += ["Example:", "", *_json_block(example), ""]
        return lines

    def render(self) -> str:
        """The whole reference."""
        info = self.spec.get("info", {})
        lines = [
            f"# {info.get('title', 'API')} REST API reference (version {info.get('version', '?')})",
            "",
            "<!-- Generated from the app's OpenAPI JSON (openapi.json) by `python -m service.openapi_doc`; "
            "do not edit by hand. CI checks it is current (tests/unit/service/test_openapi_doc.py). -->",
            "",
        ]
        if info.get("summary"):
            lines += [f"*{_cell(info['summary'])}*", ""]
        if info.get("description"):
            lines += [_prose(info["description"]), ""]
        lines += self.conventions()
        ops = self.operations()
        lines += ["## Endpoints", ""]
        lines += _table(
            ["method", "path", "what", "auth"],
            [
                [
                    f"`{method.upper()}`",
                    f"[`{path}`](#{_slug(f'{method} {path}')})",
                    _cell(_prose(op.get("description")).split("\n\n")[0]) or _cell(op.get("summary")),
                    self.scope_of(op) or "-",
                ]
                for _, method, path, op in ops
            ],
        )
        lines.append("")
        current = None
        for tag, method, path, op in ops:
            if tag != current:
                current = tag
                lines += [f"## {tag.capitalize()}", ""]
            lines += self.operation(method, path, op)
        lines += self.models()
        return "\n".join(line.rstrip() for line in lines).rstrip() + "\n"


def render_markdown(spec: Schema) -> str:
    """The Markdown reference of an OpenAPI document."""
    return Renderer(spec).render()


def _stale(path: Path, text: str) -> str | None:
    """None when ``path`` holds ``text``, else a short diff."""
    current = path.read_text() if path.exists() else ""
    if current == text:
        return None
    diff = list(difflib.unified_diff(current.splitlines(), text.splitlines(), "checked in", "generated", lineterm=""))
    return "\n".join(diff[:60]) + (f"\n... ({len(diff) - 60} more diff lines)" if len(diff) > 60 else "")


def main(argv: list[str] | None = None) -> int:
    """Write ``openapi.json`` and ``openapi.md`` (or, with ``--check``, exit 1 when either is stale)."""
    parser = argparse.ArgumentParser(prog="python -m service.openapi_doc", description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="exit 1 if a file is not current; write nothing")
    parser.add_argument("--json", type=Path, default=DEFAULT_JSON, help="default: openapi.json at the repo root")
    parser.add_argument("--output", type=Path, default=DEFAULT_MARKDOWN, help="default: openapi.md at the repo root")
    args = parser.parse_args(argv)
    spec = openapi_spec()
    outputs = {args.json: openapi_json(spec), args.output: render_markdown(spec)}
    failed = False
    for path, text in outputs.items():
        diff = _stale(path, text)
        if diff is None:
            print(f"{path} is current")
        elif args.check:
            failed = True
            print(f"{path} is out of date with the app; regenerate it with `python -m service.openapi_doc`.\n{diff}",
                  file=sys.stderr)  # fmt: skip
        else:
            path.write_text(text)
            print(f"wrote {path}")
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
