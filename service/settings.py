"""The service's settings: the one :class:`contracts.settings.Settings`, and the rule for binding without keys.

Every setting, its default and its meaning are written once, in ``contracts/settings.py``; this module
re-exports what the routes and entry points use so that they need not know where it lives.
"""

from __future__ import annotations

from contracts.settings import Settings, SettingsError, get_settings

__all__ = ["LOOPBACK_HOSTS", "Settings", "SettingsError", "get_settings", "is_loopback_host"]

LOOPBACK_HOSTS = ("127.0.0.1", "::1", "localhost")


def is_loopback_host(host: str) -> bool:
    """Whether binding to ``host`` only accepts local connections."""
    return host in LOOPBACK_HOSTS or host.startswith("127.")
