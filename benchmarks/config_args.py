"""``--config NAME=FIELD:VALUE,...`` of the benchmarks that compare a stage's configurations side by side.

A configuration is a frozen dataclass of options (:class:`geoloc.localize.query.QueryConfig`,
:class:`geoloc.localize.sequence.PlacementOptions`); each assignment replaces one field of its default, typed as
that field's default value is (``none`` for a field that may be None); an unknown field or a value of the wrong
type is refused with the reason.
"""

from __future__ import annotations

import argparse
from collections.abc import Mapping
from dataclasses import fields, replace
from pathlib import Path
from typing import Any, TypeVar, cast

BOOLEANS = {"true": True, "yes": True, "1": True, "false": False, "no": False, "0": False}

Options = TypeVar("Options")


def parse_config(text: str, default: Options) -> tuple[str, Options]:
    """``NAME=FIELD:VALUE,...`` -> (name, ``default`` with those fields replaced); SystemExit with the reason."""
    name, _, assignments = text.partition("=")
    kinds = {f.name: type(getattr(default, f.name)) for f in fields(cast(Any, default))}
    changes: dict[str, Any] = {}
    for assignment in filter(None, assignments.split(",")):
        field, _, value = assignment.partition(":")
        if field not in kinds:
            raise SystemExit(f"--config {text}: {type(default).__name__} has no field {field!r}")
        kind = kinds[field]
        if kind not in (bool, int, float, str):
            raise SystemExit(f"--config {text}: {field} is {kind.__name__}, which --config cannot set")
        try:
            if value.lower() == "none":
                changes[field] = None
            else:
                changes[field] = BOOLEANS[value.lower()] if kind is bool else kind(value)
        except (KeyError, ValueError):
            raise SystemExit(f"--config {text}: {field} is {kind.__name__}, not {value!r}") from None
    if not name or not changes:
        raise SystemExit(f"--config {text}: expected NAME=FIELD:VALUE[,FIELD:VALUE...]")
    return name, cast(Options, replace(cast(Any, default), **changes))


def comparison_arguments(
    description: str,
    json_default: str,
    switches: Mapping[str, str] | None = None,
    repeated_floats: Mapping[str, str] | None = None,
) -> argparse.Namespace:
    """The comparison benchmarks' command line: ``--world`` (repeatable), ``--config`` (repeatable), ``--json``.

    switches: a benchmark's own on/off flags (``--name``: help), false unless given. repeated_floats: its own
    repeatable numbers (``--name``: help), a list, empty unless given.
    """
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("--world", type=Path, action="append", required=True, help="a world folder (repeatable)")
    parser.add_argument("--config", action="append", default=[], help="NAME=FIELD:VALUE,... (repeatable)")
    parser.add_argument("--json", type=Path, default=Path(json_default))
    for flag, text in (switches or {}).items():
        parser.add_argument(flag, action="store_true", help=text)
    for flag, text in (repeated_floats or {}).items():
        parser.add_argument(flag, type=float, action="append", default=[], help=text)
    return parser.parse_args()
