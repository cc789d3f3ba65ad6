"""The one settings object of geoloc: the API, the workers, the CLI and the method read it.

Every setting is an environment variable ``GEOLOC_<NAME>``; its default and meaning are written
once, in :class:`Settings` below. The README's settings table is generated from this class
(``python -m contracts.settings`` prints it; ``tests/unit/contracts/test_settings.py`` fails when the README differs).

The environment is read once per process, on the first :func:`get_settings` call. Code that
changes ``os.environ`` afterwards (tests that point ``GEOLOC_DATA_DIR`` at a temporary folder) calls
:func:`reset_settings` after the change and again after restoring it; ``tests/conftest.py`` also
resets before and after every test.
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import Field, ValidationError, field_validator, model_validator
from pydantic_settings import BaseSettings, NoDecode, PydanticBaseSettingsSource, SettingsConfigDict

from contracts.keys import ApiKey, parse_api_keys
from contracts.queries import DEFAULT_QUERY_PRESET, QueryPreset
from contracts.settings_http import HttpSettings
from contracts.settings_table import fields_table

REPO_ROOT = Path(__file__).resolve().parent.parent
ENV_PREFIX = "GEOLOC_"


class SettingsError(ValueError):
    """A setting has an invalid value; the message names the variable, its value and the rule."""


def _shown(default: str) -> dict[str, Any]:
    """Field metadata: how the README shows a default that depends on the machine."""
    return {"shown_default": default}


class Settings(HttpSettings):
    """Every setting of the service, its workers and the method, read from ``GEOLOC_*`` variables.

    Build with :func:`get_settings` (the process's settings, from the environment) or
    :meth:`from_values` (defaults and explicit values only, for documentation and tests).
    An empty variable counts as unset. Invalid values raise :class:`SettingsError`.
    """

    model_config = SettingsConfigDict(env_prefix=ENV_PREFIX, env_ignore_empty=True, frozen=True, extra="ignore")

    shared: Path = Field(
        default=REPO_ROOT.parent / "shared",
        description="shared data and pretrained weights (read-only; never copied into the repo)",
        json_schema_extra=_shown("`../shared` from the repo root"),
    )
    data_dir: Path = Field(
        default=Path.home() / ".local" / "share" / "geoloc",
        description="the embedded database (`geoloc.sqlite3`), stored maps and photos (unless "
        "`GEOLOC_STORE_DIR`), temporary uploads (`tmp/`), and caches (`cache/models`: ONNX, vocabulary; "
        "`cache/maps`: loaded maps for the workers, memory-mapped; `cache/sbow`: each map's SBoW base segment, "
        "mapped by every worker process of the machine)",
        json_schema_extra=_shown("`~/.local/share/geoloc`"),
    )
    database_url: str | None = Field(
        default=None,
        description="`postgresql://USER:PASSWORD@HOST:PORT/DB`: the catalogue, jobs and SBoW index live in "
        "PostgreSQL instead of `GEOLOC_DATA_DIR/geoloc.sqlite3` (the distributed profile; set together "
        "with `GEOLOC_BROKER_URL`)",
        json_schema_extra=_shown("(none: SQLite)"),
    )
    broker_url: str | None = Field(
        default=None,
        description="`redis://HOST:PORT/N`: jobs run on Celery workers (`geoloc worker`) fed through this Redis, "
        "which also holds the API keys' rate limits (the distributed profile; set together with "
        "`GEOLOC_DATABASE_URL`)",
        json_schema_extra=_shown("(none: built-in pool)"),
    )
    store_dir: Path | None = Field(
        default=None,
        description="where uploaded maps and photos are kept (`maps/`, `images/`, `queries/`, uploads in "
        "`tmp/`); in the distributed profile a volume every API and worker machine mounts",
        json_schema_extra=_shown("`GEOLOC_DATA_DIR`"),
    )
    api_keys: Annotated[dict[str, ApiKey], NoDecode] = Field(
        default_factory=dict,
        description="`KEY:SCOPES@TENANT,…` with scopes `read`, `write` joined by `+` (`write` implies `read`) "
        "and an optional tenant (the key sees only that tenant's maps; without one, only untenanted data); "
        "with no keys, auth is off and the service binds to loopback only",
        json_schema_extra=_shown("(none)"),
    )
    max_map_bytes: int = Field(default=256 * 1024 * 1024, ge=0, description="largest map upload (413 above)")
    max_decompressed_bytes: int = Field(
        default=1024 * 1024 * 1024,
        ge=0,
        description="most bytes a compressed map upload (.gz, .bz2, .zip) may inflate to, counted at upload "
        "(413 above; 4 x the default upload limit)",
    )
    max_image_bytes: int = Field(default=32 * 1024 * 1024, ge=0, description="largest photo upload (413 above)")
    max_image_pixels: int = Field(
        default=60_000_000,
        ge=0,
        description="most pixels per photo, checked from the header (decompression-bomb guard, 413)",
    )
    max_track_frames: int = Field(
        default=50, ge=1, description="most photos in one track (`POST /v1/maps/{id}/tracks`; 413 above)"
    )
    min_image_side: int = Field(default=64, ge=0, description="smallest accepted side in pixels (422)")
    position_margin_m: float = Field(
        default=250.0,
        ge=0,
        description="how far outside the map's bounding box a reference (or a query's prior) may lie (422 beyond)",
    )
    job_lease_s: float = Field(
        default=60.0,
        ge=0.5,
        description="job lease, renewed every lease/3 s; a dead worker's job is taken again after it expires",
    )
    job_max_attempts: int = Field(default=3, ge=1, description="attempts per job before `failed`")
    job_retry_delay_s: float = Field(
        default=5.0, ge=0, description="delay before a retry, doubled per attempt (≤ 300 s)"
    )
    worker_poll_max_s: float = Field(
        default=0.05,
        ge=0.02,
        description="longest idle sleep between polls of the job table (a cheap indexed read): at most this is "
        "added to a job's start",
    )
    worker_grace_s: float = Field(
        default=20.0, ge=0, description="on SIGTERM, how long a worker lets its job run before handing it back"
    )
    worker_trim_idle_s: float = Field(
        default=1.0,
        ge=0,
        description="a worker returns its heap's free pages to the system once idle this long after a job (and "
        "after every 16th job in a row); 0: after every job. Trimming costs the next job its page faults (~5 % CPU)",
    )
    worker_plugins: Annotated[tuple[str, ...], NoDecode] = Field(
        default=(),
        description="extra modules or `.py` files with job handlers, comma-separated",
        json_schema_extra=_shown("(none)"),
    )
    worker_kinds: Annotated[tuple[str, ...], NoDecode] = Field(
        default=(),
        description="job kinds the embedded pool's workers claim, comma-separated (e.g. `load_map` for workers "
        "that only parse maps)",
        json_schema_extra=_shown("(all)"),
    )
    worker_start: Literal["fork", "spawn"] = Field(
        default="spawn",
        description="how the embedded profile starts its workers: `spawn` (separate `python -m workers` processes) "
        "or `fork` (Linux: one pool process imports and warms what every worker uses, then forks them: they share "
        "those pages; worth it with four or more workers on a city-sized map, docs/operations.md)",
    )
    worker_nice: int = Field(
        default=10,
        ge=0,
        le=19,
        description="CPU niceness added to worker processes, so that the API answers promptly while they are busy",
    )
    max_queued_jobs: int = Field(
        default=100,
        ge=1,
        description="most jobs waiting in the queue; beyond it new references and queries get `429` with `Retry-After`",
    )
    rate_limit_per_min: int = Field(
        default=600,
        ge=0,
        description="requests per minute per API key (`429` with `Retry-After` beyond; 0: no limit); with no keys "
        "configured there is no limit",
    )
    query_retention_s: float = Field(
        default=30 * 24 * 3600.0,
        ge=0,
        description="the workers delete finished queries (photo and answer) older than this; 0 keeps them "
        "forever; references are never deleted implicitly",
        json_schema_extra=_shown("2592000 (30 days)"),
    )
    query_preset: QueryPreset = Field(
        default=DEFAULT_QUERY_PRESET,
        description="the preset of a query that names none: `fast`, `balanced` or `accurate` (the query stage's "
        "configurations, `geoloc/localize/query/config.py: PRESETS`)",
    )
    database_timeout_s: float = Field(
        default=5.0,
        ge=1,
        description="longest the API waits to open a PostgreSQL connection; while the database is down or "
        "restarting (or SQLite's file is read-only or locked past `GEOLOC_DATABASE_LOCK_TIMEOUT_S`) requests get "
        "`503` `database_unavailable` with `Retry-After` and workers pause claiming until it is back",
    )
    database_lock_timeout_s: float = Field(
        default=30.0,
        ge=0.1,
        description="longest an API request waits for a database lock (SQLite busy, PG `lock_timeout`)",
    )
    ready_worker_s: float = Field(
        default=30.0,
        ge=0,
        description="`/readyz` needs a heartbeat this recent from a worker that takes queries (not a map-only one)",
    )
    seg_threads: int | None = Field(
        default=None,
        ge=1,
        description="onnxruntime threads for segmentation and ALIKED (threads wait without spinning)",
        json_schema_extra=_shown("`GEOLOC_JOB_THREADS`"),
    )
    device: Literal["auto", "cpu", "cuda"] = Field(
        default="auto",
        description="where segmentation and ALIKED run: `cpu`; `cuda` (needs the `gpu` extra and a GPU: workers "
        "refuse to start without them); `auto`: CUDA when onnxruntime can use a GPU here, else CPU",
    )
    segmentation_size: str | None = Field(
        default=None,
        pattern=r"^[0-9]+x[0-9]+$",
        description="the segmentation network's input `WxH`, multiples of 16 (`geoloc models build` builds it); "
        "default the method's (docs/speed.md#the-segmentation-network); `768x384` answers as before issue 52",
    )
    job_threads: int = Field(
        default=2,
        ge=1,
        description="threads one job (a query, a label) uses for its independent parts: the features beside the "
        "facades, each shortlisted reference's matching and RANSAC, each PnP proposal (`geoloc/core/parallel.py`); "
        "answers do not depend on it",
    )
    worker_threads: int = Field(
        default=1,
        ge=1,
        description="threads of numpy's BLAS and OpenCV calls in each worker process (the processes and job "
        "threads are the parallelism)",
    )
    log_level: str = Field(default="INFO", description="log level of the workers")
    log_format: Literal["text", "json"] = Field(
        default="text",
        description="how the API and the workers log: `text` lines, or `json`: one JSON object a line, with the "
        "request id (`X-Request-ID`) on a request's line and on its jobs' lines (docs/operations.md#logs)",
    )
    metrics: bool = Field(
        default=True,
        description="`GET /metrics` in Prometheus's text format (requests, latencies, jobs, stages, workers, "
        "sizes, rejections); `false`: a 404 there, and no process records any",
    )
    metrics_key: str | None = Field(
        default=None, description="when set, `/metrics` needs `Authorization: Bearer KEY` (without: open)"
    )
    metrics_dir: Path | None = Field(
        default=None,
        description="the folder where every API and worker process of a machine writes its metrics "
        "(prometheus-client's `PROMETHEUS_MULTIPROC_DIR`); `/metrics` adds them up",
        json_schema_extra=_shown("a folder of the system's temporary directory, named after `GEOLOC_DATA_DIR`"),
    )

    @field_validator("shared", "data_dir", "store_dir", "metrics_dir", mode="after")
    @classmethod
    def _absolute(cls, path: Path | None) -> Path | None:
        return path.expanduser().resolve() if path is not None else None

    @field_validator("database_url", mode="after")
    @classmethod
    def _postgres_url(cls, url: str | None) -> str | None:
        if url is not None and not url.startswith(("postgresql://", "postgres://")):
            raise ValueError("must be a PostgreSQL URL, postgresql://USER:PASSWORD@HOST:PORT/DATABASE")
        return url

    @field_validator("broker_url", mode="after")
    @classmethod
    def _redis_url(cls, url: str | None) -> str | None:
        if url is not None and not url.startswith(("redis://", "rediss://")):
            raise ValueError("must be a Redis URL, redis://HOST:PORT/DB (or rediss:// for TLS)")
        return url

    @model_validator(mode="after")
    def _one_profile(self) -> Settings:
        if (self.database_url is None) != (self.broker_url is None):
            given, missing = (
                ("GEOLOC_DATABASE_URL", "GEOLOC_BROKER_URL")
                if self.broker_url is None
                else ("GEOLOC_BROKER_URL", "GEOLOC_DATABASE_URL")
            )
            raise ValueError(
                f"{given} is set but {missing} is not: the distributed profile needs both "
                "(PostgreSQL and Redis); unset both for the embedded one (SQLite, built-in workers)"
            )
        return self

    @field_validator("api_keys", mode="before")
    @classmethod
    def _parse_api_keys(cls, value: object) -> object:
        return parse_api_keys(value) if isinstance(value, str) else value

    @field_validator("worker_plugins", "worker_kinds", mode="before")
    @classmethod
    def _split_plugins(cls, value: object) -> object:
        return tuple(p.strip() for p in value.split(",") if p.strip()) if isinstance(value, str) else value

    @classmethod
    def settings_customise_sources(
        cls,
        settings_cls: type[BaseSettings],
        init_settings: PydanticBaseSettingsSource,
        env_settings: PydanticBaseSettingsSource,
        dotenv_settings: PydanticBaseSettingsSource,
        file_secret_settings: PydanticBaseSettingsSource,
    ) -> tuple[PydanticBaseSettingsSource, ...]:
        """Explicit values, then the environment; no ``.env`` or secrets files."""
        return (init_settings, env_settings)

    @classmethod
    def from_values(cls, **values: Any) -> Settings:
        """Settings from the defaults and ``values`` only: the environment is not read.

        Raises
        ------
        SettingsError
            A value is invalid.
        """
        return _validated(_DefaultsOnly, values)

    @property
    def database_path(self) -> Path:
        """The embedded profile's SQLite database: ``data_dir/geoloc.sqlite3``."""
        return self.data_dir / "geoloc.sqlite3"

    @property
    def database(self) -> str | Path:
        """What :func:`db.connect` opens: ``database_url`` in the distributed profile, else :attr:`database_path`."""
        return self.database_url or self.database_path

    @property
    def distributed(self) -> bool:
        """Whether this is the distributed profile (PostgreSQL and a Celery broker), not the embedded one."""
        return self.broker_url is not None

    @property
    def file_store_dir(self) -> Path:
        """Where stored maps and photos live: ``store_dir``, else ``data_dir``."""
        return self.store_dir or self.data_dir

    @property
    def auth_enabled(self) -> bool:
        """Whether API keys are required (some are configured)."""
        return bool(self.api_keys)


class _DefaultsOnly(Settings):
    """:class:`Settings` that ignores the environment (see :meth:`Settings.from_values`)."""

    @classmethod
    def settings_customise_sources(
        cls,
        settings_cls: type[BaseSettings],
        init_settings: PydanticBaseSettingsSource,
        env_settings: PydanticBaseSettingsSource,
        dotenv_settings: PydanticBaseSettingsSource,
        file_secret_settings: PydanticBaseSettingsSource,
    ) -> tuple[PydanticBaseSettingsSource, ...]:
        """Explicit values only."""
        return (init_settings,)


def _validated(settings_cls: type[Settings], values: dict[str, Any]) -> Settings:
    """Build ``settings_cls``, turning pydantic's errors into one :class:`SettingsError` per variable."""
    try:
        return settings_cls(**values)
    except ValidationError as exc:
        problems = []
        for error in exc.errors(include_url=False):
            message = str(error["msg"]).removeprefix("Value error, ")
            if not error["loc"]:  # a rule across settings: its message names them
                problems.append(message)
                continue
            name = ENV_PREFIX + str(error["loc"][0]).upper()
            problems.append(f"{name}={error['input']!r}: {message}")
        raise SettingsError("invalid setting: " + "; ".join(problems)) from None


@lru_cache(maxsize=1)
def get_settings() -> Settings:
    """The process's settings, read from the environment on the first call and then cached.

    Raises
    ------
    SettingsError
        A variable has an invalid value (the message names it).
    """
    return _validated(Settings, {})


def reset_settings() -> None:
    """Forget the cached settings: the next :func:`get_settings` reads the environment again."""
    get_settings.cache_clear()


def shared_dir() -> Path:
    """Folder with the shared data and weights (``GEOLOC_SHARED``)."""
    return get_settings().shared


def data_dir() -> Path:
    """Folder for the database, photos and caches (``GEOLOC_DATA_DIR``); created on demand."""
    path = get_settings().data_dir
    path.mkdir(parents=True, exist_ok=True)
    return path


def cache_dir() -> Path:
    """Folder for derived artefacts that can be rebuilt (exported ONNX models): ``DATA_DIR/cache``."""
    path = data_dir() / "cache"
    path.mkdir(parents=True, exist_ok=True)
    return path


def models_dir() -> Path:
    """Folder of the built models (ONNX networks, their metadata, SBoW vocabularies): ``DATA_DIR/cache/models``."""
    return cache_dir() / "models"


def shared_path(*parts: str) -> Path:
    """A path inside the shared folder.

    Raises
    ------
    FileNotFoundError
        The path does not exist; the message says which setting to fix.
    """
    path = shared_dir().joinpath(*parts)
    if not path.exists():
        raise FileNotFoundError(f"{path} not found; set GEOLOC_SHARED to the shared data folder (now {shared_dir()})")
    return path


def default_threads() -> int:
    """Threads for the networks: ``GEOLOC_SEG_THREADS``, else ``GEOLOC_JOB_THREADS`` (default 2).

    Their threads do not spin while waiting (``geoloc/vision/segmentation.py``), so a second thread costs little
    CPU when the pool's processes already fill the cores and shortens a query when a core is free
    (``benchmarks/bench_service.py`` compares thread counts through the service).
    """
    settings = get_settings()
    return settings.seg_threads or settings.job_threads


def settings_table() -> str:
    """The settings table of docs/operations.md (markdown): variable, default, bounds, meaning; one row per field."""
    return fields_table(Settings.model_fields, ENV_PREFIX)


if __name__ == "__main__":
    print(settings_table())
