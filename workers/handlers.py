"""Job handlers by kind: the seam where the method plugs into the worker pool.

A handler is ``handler(db, payload) -> result``: ``db`` is a ``Database`` opened for this job (autocommit;
wrap writes in ``db.connection.transaction``), ``payload`` is the job's payload read back with the model the
kind was registered with (a :class:`contracts.jobs.JobPayload`), and the returned
:class:`contracts.jobs.JobResult` becomes the job's ``result`` (its JSON form). A payload that does not fit
its model fails the job at once. Raise any exception to fail the attempt (retried up to the job's
``max_attempts``, with the error and a traceback summary kept); raise :class:`PermanentJobError` for a
failure that a retry cannot fix (exception types that always mean that, such as a model that is not built,
are registered once with :func:`treat_as_permanent`). Build answers inside :func:`answer_checked`: a
malformed one then fails the job at once, naming the field, before anything is stored.

Handlers must be idempotent: after a worker crash the same job runs again from the start, so
write results with replace semantics (``save_labels``, ``index_reference`` ...) inside one
transaction at the end. Register with::

    @register(LABEL_REFERENCE, LabelReferencePayload)
    def label_reference(db: Database, payload: LabelReferencePayload) -> LabelReferenceResult: ...

Extra handlers (e.g. test-only ones) are loaded from ``GEOLOC_WORKER_PLUGINS`` (modules or ``.py``
files that call :func:`register` when imported), see :func:`load_plugins`.
"""

from __future__ import annotations

import contextlib
import importlib
import importlib.util
import sys
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Generic, TypeVar

from pydantic import ValidationError

from contracts.jobs import JobPayload, JobResult
from db import Database

P = TypeVar("P", bound=JobPayload)
R = TypeVar("R", bound=JobResult)


class PermanentJobError(Exception):
    """A job failure that retrying cannot fix (missing input, invalid data): fail at once."""


@dataclass(frozen=True)
class Registration(Generic[P]):
    """A kind's handler and the model its payload is read with."""

    payload_type: type[P]
    handler: Callable[[Database, P], JobResult]

    def run(self, db: Database, payload: Mapping[str, Any]) -> dict[str, Any]:
        """Read ``payload`` with the kind's model, run the handler, return its result's JSON form.

        Raises :class:`PermanentJobError` when the payload does not fit the model.
        """
        try:
            typed = self.payload_type.model_validate(payload)
        except ValidationError as exc:
            raise PermanentJobError(f"malformed job payload: {_problems(exc)}") from None
        return self.handler(db, typed).to_json()


HANDLERS: dict[str, Registration[Any]] = {}
"""Registered handlers by job kind."""

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


def register(kind: str, payload_type: type[P]) -> Callable[[Callable[[Database, P], R]], Callable[[Database, P], R]]:
    """Decorator registering ``handler`` for jobs of ``kind``, its payload read as ``payload_type``.

    A later registration of the same kind replaces the earlier one (plugins replace shipped handlers).
    """

    def decorate(handler: Callable[[Database, P], R]) -> Callable[[Database, P], R]:
        HANDLERS[kind] = Registration(payload_type, handler)
        return handler

    return decorate


@contextlib.contextmanager
def answer_checked(what: str) -> Iterator[None]:
    """Build an answer (``contracts.answers`` models) inside this block; a malformed one fails the job for good.

    A pydantic ``ValidationError`` raised in the block (a missing or unknown field, a wrong type, a NaN)
    becomes a :class:`PermanentJobError` whose message starts ``malformed <what>, not stored`` and lists each
    bad field and why, so the job fails at once, without retries, and nothing is stored.
    """
    try:
        yield
    except ValidationError as exc:
        raise PermanentJobError(
            f"malformed {what}, not stored ({exc.error_count()} problem(s) against {exc.title}): {_problems(exc)}"
        ) from None


def _problems(exc: ValidationError) -> str:
    """``field.path: why; ...`` for each error of ``exc``."""
    return "; ".join(
        f"{'.'.join(str(part) for part in error['loc']) or '(root)'}: {error['msg']}"
        for error in exc.errors(include_url=False)
    )


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
    shipped = (
        "workers.reference_handlers",
        "workers.sequence_handlers",
        "workers.query_handlers",
        "workers.track_handlers",
        "workers.map_handlers",
    )
    for module in shipped:
        try:
            importlib.import_module(module)
        except ModuleNotFoundError as exc:
            if exc.name != module:
                raise
