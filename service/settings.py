"""Settings of the service and its workers, read from environment variables.

============================== ============ ===================================================
Variable                       Default      Meaning
============================== ============ ===================================================
``GEOLOC_DATA_DIR``            ~/.local/    Database ``geoloc.sqlite3``, stored maps
                               share/geoloc (``maps/``), photos (``images/``), temp uploads
                                            (``tmp/``) and caches (see ``geoloc.config``).
``GEOLOC_API_KEYS``            (none)       Comma-separated ``KEY:SCOPES`` with SCOPES among
                                            ``read``, ``write`` joined by ``+``, e.g.
                                            ``k1:read+write,k2:read``. ``write`` (maps,
                                            references) implies ``read`` (GETs, queries).
                                            With no keys, auth is off and the service only
                                            binds to a loopback host.
``GEOLOC_MAX_MAP_BYTES``       268435456    Largest map upload (bytes); larger is 413.
``GEOLOC_MAX_IMAGE_BYTES``     33554432     Largest photo upload (bytes); larger is 413.
``GEOLOC_MAX_IMAGE_PIXELS``    60000000     Most pixels (width x height) of a photo; more is
                                            413 (decompression-bomb guard, read from the
                                            header before decoding).
``GEOLOC_MIN_IMAGE_SIDE``      64           Smallest accepted width/height in pixels (422).
``GEOLOC_POSITION_MARGIN_M``   250          A reference's position may lie this far outside
                                            the map's bounding box; farther is 422.
``GEOLOC_JOB_LEASE_S``         60           Lease of a running job; the worker extends it
                                            every lease/3 s. A dead worker's job is taken again
                                            after the lease expires.
``GEOLOC_JOB_MAX_ATTEMPTS``    3            Attempts per job before it is ``failed``.
``GEOLOC_JOB_RETRY_DELAY_S``   5            Delay before a retry, doubled per attempt (<= 300).
``GEOLOC_WORKER_POLL_MAX_S``   2            Longest idle sleep between polls (backoff from
                                            0.1 s).
``GEOLOC_WORKER_GRACE_S``      20           On SIGTERM a worker lets its current job run this
                                            long, then gives it back to the queue and exits.
``GEOLOC_WORKER_PLUGINS``      (none)       Comma-separated modules or ``.py`` files imported
                                            by workers to register extra job handlers.
``GEOLOC_READY_WORKER_S``      30           ``/readyz`` needs a worker heartbeat this recent.
``GEOLOC_LOG_LEVEL``           INFO         Log level of ``python -m workers`` when started
                                            without ``--log-level``.
============================== ============ ===================================================
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

from geoloc.config import data_dir

SCOPES = ("read", "write")
LOOPBACK_HOSTS = ("127.0.0.1", "::1", "localhost")


class SettingsError(ValueError):
    """A setting has an invalid value."""


def _env_number(name: str, default: float, cast: type = float) -> float:
    raw = os.environ.get(name)
    if raw is None or raw.strip() == "":
        return default
    try:
        value = cast(raw)
    except ValueError as exc:
        raise SettingsError(f"{name}={raw!r} is not a number") from exc
    if value < 0:
        raise SettingsError(f"{name}={raw!r} must not be negative")
    return value


def parse_api_keys(raw: str) -> dict[str, frozenset[str]]:
    """``'k1:read+write,k2:read'`` -> ``{'k1': {'read', 'write'}, 'k2': {'read'}}``."""
    keys: dict[str, frozenset[str]] = {}
    for item in raw.split(","):
        item = item.strip()
        if not item:
            continue
        key, _, scope_text = item.partition(":")
        scopes = {s.strip() for s in (scope_text or "read+write").split("+") if s.strip()}
        unknown = scopes - set(SCOPES)
        if not key or unknown:
            raise SettingsError(f"GEOLOC_API_KEYS: bad entry {item!r} (expected KEY:read, KEY:write or KEY:read+write)")
        if "write" in scopes:
            scopes.add("read")
        keys[key.strip()] = frozenset(scopes)
    return keys


def is_loopback_host(host: str) -> bool:
    """Whether binding to ``host`` only accepts local connections."""
    return host in LOOPBACK_HOSTS or host.startswith("127.")


@dataclass(frozen=True)
class Settings:
    """All settings; build with :func:`load_settings`."""

    data_dir: Path
    api_keys: dict[str, frozenset[str]] = field(default_factory=dict)
    max_map_bytes: int = 256 * 1024 * 1024
    max_image_bytes: int = 32 * 1024 * 1024
    max_image_pixels: int = 60_000_000
    min_image_side: int = 64
    position_margin_m: float = 250.0
    job_lease_s: float = 60.0
    job_max_attempts: int = 3
    job_retry_delay_s: float = 5.0
    worker_poll_max_s: float = 2.0
    worker_grace_s: float = 20.0
    worker_plugins: tuple[str, ...] = ()
    ready_worker_s: float = 30.0

    @property
    def database_path(self) -> Path:
        return self.data_dir / "geoloc.sqlite3"

    @property
    def auth_enabled(self) -> bool:
        return bool(self.api_keys)


def load_settings() -> Settings:
    """Read every setting from the environment (raises :class:`SettingsError` on a bad value)."""
    plugins = tuple(p.strip() for p in os.environ.get("GEOLOC_WORKER_PLUGINS", "").split(",") if p.strip())
    return Settings(
        data_dir=data_dir(),
        api_keys=parse_api_keys(os.environ.get("GEOLOC_API_KEYS", "")),
        max_map_bytes=int(_env_number("GEOLOC_MAX_MAP_BYTES", 256 * 1024 * 1024, int)),
        max_image_bytes=int(_env_number("GEOLOC_MAX_IMAGE_BYTES", 32 * 1024 * 1024, int)),
        max_image_pixels=int(_env_number("GEOLOC_MAX_IMAGE_PIXELS", 60_000_000, int)),
        min_image_side=int(_env_number("GEOLOC_MIN_IMAGE_SIDE", 64, int)),
        position_margin_m=_env_number("GEOLOC_POSITION_MARGIN_M", 250.0),
        job_lease_s=max(_env_number("GEOLOC_JOB_LEASE_S", 60.0), 0.5),
        job_max_attempts=max(int(_env_number("GEOLOC_JOB_MAX_ATTEMPTS", 3, int)), 1),
        job_retry_delay_s=_env_number("GEOLOC_JOB_RETRY_DELAY_S", 5.0),
        worker_poll_max_s=max(_env_number("GEOLOC_WORKER_POLL_MAX_S", 2.0), 0.05),
        worker_grace_s=_env_number("GEOLOC_WORKER_GRACE_S", 20.0),
        worker_plugins=plugins,
        ready_worker_s=_env_number("GEOLOC_READY_WORKER_S", 30.0),
    )
