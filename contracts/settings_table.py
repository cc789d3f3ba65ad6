"""The markdown table of settings fields (variable, default, valid range, meaning), for docs/operations.md.

:func:`contracts.settings.settings_table` renders :class:`contracts.settings.Settings` with it (``python -m
contracts.settings`` prints it; ``tests/unit/contracts/test_settings.py`` fails when the docs differ).
"""

from __future__ import annotations

from pydantic.fields import FieldInfo


def fields_table(fields: dict[str, FieldInfo], prefix: str) -> str:
    """The settings table (markdown): variable (``prefix`` + the field's name), default, bounds, meaning."""
    rows = ["| variable | default | valid | what |", "| --- | --- | --- | --- |"]
    for name, info in fields.items():
        rows.append(
            f"| `{prefix}{name.upper()}` | {_shown_default(info)} | {_lower_bound(info)} | {info.description} |"
        )
    return "\n".join(rows)


def _lower_bound(info: FieldInfo) -> str:
    """The valid range of a numeric field: ``≥ low``, or ``low – high`` when it also has an upper bound."""
    lows = [m.ge for m in info.metadata if isinstance(getattr(m, "ge", None), int | float)]
    highs = [m.le for m in info.metadata if isinstance(getattr(m, "le", None), int | float)]
    if lows and highs:
        return f"{lows[0]:g} – {highs[0]:g}"
    return f"≥ {lows[0]:g}" if lows else ""


def _shown_default(info: FieldInfo) -> str:
    extra = info.json_schema_extra
    if isinstance(extra, dict) and "shown_default" in extra:
        return str(extra["shown_default"])
    default = info.get_default(call_default_factory=True)
    return f"{default:g}" if isinstance(default, float) else str(default)
