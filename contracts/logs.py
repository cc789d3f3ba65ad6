"""How every process logs (``GEOLOC_LOG_FORMAT``), and the request id that ties a request to its jobs' lines.

The request id lives in a context variable (:data:`REQUEST_ID`): the API sets it for each request (taken from
``X-Request-ID`` or made, :func:`request_id_from_header`), :func:`db.jobs.enqueue_job` stores it on the jobs the
request queues (``jobs.request_id``), and the worker that runs a job sets it again while the job runs. Every log
record then carries it: ``json`` lines as the field ``request_id``, ``text`` lines as ``[request_id]``.

A ``json`` line is one object: ``ts`` (ISO 8601, UTC, milliseconds), ``level``, ``logger``, ``process`` (pid),
``message``, ``request_id`` when one is set, whatever the call passed in ``extra=`` (for example ``method``,
``route``, ``status``, ``duration_ms`` of a request; ``job_id``, ``kind``, ``outcome`` of a job) and ``exc_info``
with the traceback of an exception.
"""

from __future__ import annotations

import contextvars
import json
import logging
import re
import secrets
import sys
import time
from typing import Any, Final, Literal

LogFormat = Literal["text", "json"]

REQUEST_ID: Final[contextvars.ContextVar[str | None]] = contextvars.ContextVar("geoloc_request_id", default=None)
"""The request id of the request (API) or job (worker) this code runs for; None outside both."""
REQUEST_ID_HEADER: Final = "X-Request-ID"
REQUEST_ID_PATTERN: Final = re.compile(r"[A-Za-z0-9._:/+=@-]{1,128}")
"""An incoming request id the service honours: 1 to 128 letters, digits and ``._:/+=@-`` (UUIDs, trace ids)."""

_STANDARD_ATTRIBUTES: Final = frozenset(vars(logging.LogRecord("", 0, "", 0, "", (), None))) | {
    "message",
    "asctime",
    "color_message",  # uvicorn's message with terminal colours
    "request_tag",
}
"""What every :class:`logging.LogRecord` has: anything else on a record came from ``extra=``."""


def new_request_id() -> str:
    """A fresh request id: 32 hexadecimal digits (128 random bits)."""
    return secrets.token_hex(16)


def request_id_from_header(value: str | None) -> str | None:
    """The request id an ``X-Request-ID`` header asks for: the header itself, a new one when absent.

    Returns None when the header is present but not a valid id (:data:`REQUEST_ID_PATTERN`): the API refuses it.
    """
    if value is None or value == "":
        return new_request_id()
    return value if REQUEST_ID_PATTERN.fullmatch(value) else None


def current_request_id() -> str | None:
    """The request id of the request or job this code runs for (None outside both)."""
    return REQUEST_ID.get()


class JsonFormatter(logging.Formatter):
    """One JSON object a line (see the module docstring for its fields)."""

    def format(self, record: logging.LogRecord) -> str:
        """The record as one line of JSON."""
        line: dict[str, Any] = {
            "ts": time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime(record.created)) + f".{int(record.msecs):03d}Z",
            "level": record.levelname,
            "logger": record.name,
            "process": record.process,
            "message": record.getMessage(),
        }
        request_id = getattr(record, "request_id", None) or REQUEST_ID.get()
        if request_id is not None:
            line["request_id"] = request_id
        for key, value in vars(record).items():
            if key not in _STANDARD_ATTRIBUTES and key not in line:
                line[key] = value
        if record.exc_info:
            line["exc_info"] = self.formatException(record.exc_info)
        return json.dumps(line, default=str, ensure_ascii=False)


class TextFormatter(logging.Formatter):
    """``time LEVEL [label pid] [request id] message``: the request id only when one is set."""

    def __init__(self, label: str) -> None:
        super().__init__(f"%(asctime)s %(levelname)s [{label} %(process)d]%(request_tag)s %(message)s")

    def format(self, record: logging.LogRecord) -> str:
        """The record as a text line, with the request id when one is set."""
        request_id = getattr(record, "request_id", None) or REQUEST_ID.get()
        record.request_tag = f" [{request_id}]" if request_id else ""
        return super().format(record)


def configure_logging(level: str, log_format: LogFormat, label: str) -> None:
    """Send every log record of this process to stderr in ``log_format`` at ``level`` (replaces other handlers).

    ``label`` names the process in ``text`` lines (``api``, ``worker``, ``supervisor``).
    """
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(JsonFormatter() if log_format == "json" else TextFormatter(label))
    root = logging.getLogger()
    for old in list(root.handlers):
        root.removeHandler(old)
    root.addHandler(handler)
    root.setLevel(level.upper())
