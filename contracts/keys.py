"""API keys as ``GEOLOC_API_KEYS`` states them: each key's scopes and tenant (:func:`parse_api_keys`)."""

from __future__ import annotations

import re
from dataclasses import dataclass

SCOPES = ("read", "write")
"""API-key scopes: ``read`` (GETs, queries) and ``write`` (maps, references; implies ``read``)."""


TENANT_PATTERN = re.compile(r"[A-Za-z0-9_.-]{1,64}")
"""A tenant's name: 1 to 64 letters, digits, ``_``, ``.`` or ``-``."""


@dataclass(frozen=True)
class ApiKey:
    """One configured API key's record: its scopes and its tenant.

    ``tenant`` None: the key sees only untenanted maps (and their references, queries and jobs); a named
    tenant: only that tenant's (``service/tenancy.py``).
    """

    scopes: frozenset[str]
    tenant: str | None = None


def parse_api_keys(raw: str) -> dict[str, ApiKey]:
    """Parse ``GEOLOC_API_KEYS``.

    Parameters
    ----------
    raw
        Comma-separated ``KEY:SCOPES@TENANT`` entries, scopes among :data:`SCOPES` joined by ``+``
        (``KEY`` alone means ``read+write``), the ``@TENANT`` part optional (no tenant: the key sees only
        untenanted data), e.g. ``'k1:read+write@team-a,k2:read@team-b,k3:read'``. A tenant matches
        :data:`TENANT_PATTERN`; it is split off at the last ``@``.

    Returns
    -------
    dict[str, ApiKey]
        The record per key; ``write`` implies ``read``.

    Raises
    ------
    ValueError
        An entry has no key, an unknown scope or a bad tenant name.
    """
    keys: dict[str, ApiKey] = {}
    for entry in raw.split(","):
        item = entry.strip()
        if not item:
            continue
        head, at, tenant_text = item.rpartition("@")
        if not at:
            head = item
        tenant = tenant_text.strip() if at else None
        if tenant is not None and not TENANT_PATTERN.fullmatch(tenant):
            raise ValueError(f"bad entry {item!r}: tenant {tenant!r} must be 1 to 64 letters, digits, '_', '.' or '-'")
        key, _, scope_text = head.partition(":")
        scopes = {s.strip() for s in (scope_text or "read+write").split("+") if s.strip()}
        if not key.strip() or scopes - set(SCOPES):
            raise ValueError(f"bad entry {item!r} (expected KEY:read, KEY:write or KEY:read+write, optionally @TENANT)")
        if "write" in scopes:
            scopes.add("read")
        keys[key.strip()] = ApiKey(frozenset(scopes), tenant)
    return keys
