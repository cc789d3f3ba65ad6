"""Job handlers by kind: the seam where the method plugs into the worker pool.

A handler is ``handler(db, payload) -> dict``: ``db`` is a ``Database`` opened for
this job (autocommit; wrap writes in ``db.connection.transaction``), ``payload`` is the job's JSON
payload, and the returned dict (JSON-serialisable) becomes the job's ``result``. Raise any
exception to fail the attempt (retried up to the job's ``max_attempts``, with the error and a
traceback summary kept); raise :class:`PermanentJobError` for a failure that a retry cannot fix
(exception types that always mean that, such as a model that is not built, are registered once with
:func:`treat_as_permanent`).

Handlers must be idempotent: after a worker crash the same job runs again from the start, so
write results with replace semantics (``save_labels``, ``index_reference`` ...) inside one
transaction at the end. Register with::

    @register("label_reference")
    def label_reference(db, payload): ...

Payloads enqueued by the API (see ``service/routes_references.py``):

- ``label_reference``: ``{"reference_id": int, "map_id": int}``

Extra handlers (e.g. test-only ones) are loaded from ``GEOLOC_WORKER_PLUGINS`` (modules or ``.py``
files that call :func:`register` when imported), see :func:`load_plugins`.
"""

from __future__ import annotations

import importlib
import importlib.util
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

from db import Database
from db import jobs as job_store

JobHandler = Callable[[Database, dict[str, Any]], dict[str, Any]]

HANDLERS: dict[str, JobHandler] = {}
"""Registered handlers by job kind."""

LABEL_REFERENCE = job_store.LABEL_REFERENCE
"""Kind of the job the API enqueues for each new reference (payload: reference_id, map_id)."""


class PermanentJobError(Exception):
    """A job failure that retrying cannot fix (missing input, invalid data): fail at once."""


PERMANENT_ERRORS: list[type[BaseException]] = [PermanentJobError]
"""Exception types that fail a job at once, without retries (see :func:`treat_as_permanent`)."""


def treat_as_permanent(*error_types: type[BaseException]) -> None:
    """Fail jobs at once on these exception types (and their subclasses).

    E.g. a model that is not built: the same attempt would fail again until an operator acts.
    """
    PERMANENT_ERRORS.extend(t for t in error_types if t not in PERMANENT_ERRORS)


def is_permanent(error: BaseException) -> bool:
    """Whether ``error`` fails its job without retries."""
    return isinstance(error, tuple(PERMANENT_ERRORS))


def register(kind: str) -> Callable[[JobHandler], JobHandler]:
    """Decorator registering ``handler`` for jobs of ``kind`` (a later registration replaces)."""

    def decorate(handler: JobHandler) -> JobHandler:
        HANDLERS[kind] = handler
        return handler

    return decorate


def load_plugins(specs: tuple[str, ...] | list[str]) -> list[str]:
    """Import each plugin (a module name, or a path to a ``.py`` file) so it registers its handlers."""
    loaded = []
    for spec in specs:
        if spec.endswith(".py"):
            path = Path(spec).expanduser().resolve()
            module_name = f"geoloc_worker_plugin_{path.stem}"
            module_spec = importlib.util.spec_from_file_location(module_name, path)
            if module_spec is None or module_spec.loader is None:
                raise ImportError(f"cannot load worker plugin {spec}")
            module = importlib.util.module_from_spec(module_spec)
            sys.modules[module_name] = module
            module_spec.loader.exec_module(module)
        else:
            importlib.import_module(spec)
        loaded.append(spec)
    return loaded


def load_builtin_handlers() -> None:
    """Import the modules that register the shipped handlers (the method's, when present)."""
    for module in ("workers.method_handlers",):
        try:
            importlib.import_module(module)
        except ModuleNotFoundError as exc:
            if exc.name != module:
                raise
