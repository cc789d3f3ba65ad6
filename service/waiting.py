"""Waiting for jobs without a thread per waiting request.

A request that waits for its job (``POST /v1/maps/{id}/queries`` with ``wait_s``) awaits a future
on the event loop. One background task of the API (:class:`JobWaiter`, started with the app) looks
up the status of every awaited job in one query per poll, in one worker thread, and resolves the
futures of the jobs that reached a final state. Sixty waiting clients cost sixty futures and one
``SELECT ... WHERE id IN (...)`` every :data:`POLL_S`, not sixty threads sleeping in a loop, so
reads keep their threads however many clients wait.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Callable
from pathlib import Path
from typing import Any, Protocol, TypeVar

import anyio.to_thread
from fastapi import Request, status
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import JSONResponse

from contracts.jobs import FINAL_STATUSES
from db import Database, connect
from db import jobs as job_store

log = logging.getLogger("geoloc.api")

POLL_S = 0.02
"""How often awaited jobs are looked up (at most this much is added to an answer's latency)."""
ERROR_BACKOFF_S = 1.0
"""Pause after a failed lookup (database busy or unreachable) before the next."""


class JobWaiter:
    """Resolves ``await wait(job_id, timeout_s)`` calls when their jobs finish."""

    def __init__(self, database: Path | str, poll_s: float = POLL_S) -> None:
        self.database = database
        self.poll_s = poll_s
        self._waiting: dict[int, list[asyncio.Future[None]]] = {}
        self._wakeup: asyncio.Event | None = None
        self._task: asyncio.Task[None] | None = None
        self._db: Database | None = None

    async def start(self) -> None:
        """Start the polling task (call from the app's lifespan)."""
        self._wakeup = asyncio.Event()
        self._task = asyncio.create_task(self._run(), name="job-waiter")

    async def stop(self) -> None:
        """Stop polling; requests still waiting get their timeout."""
        if self._task is not None:
            self._task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._task
        self._forget_connection()

    async def wait(self, job_id: int, timeout_s: float) -> bool:
        """Wait until job ``job_id`` is done, failed, cancelled or gone; False if ``timeout_s`` passed first."""
        if timeout_s <= 0:
            return False
        future: asyncio.Future[None] = asyncio.get_running_loop().create_future()
        self._waiting.setdefault(job_id, []).append(future)
        if self._wakeup is not None:
            self._wakeup.set()
        try:
            await asyncio.wait_for(future, timeout_s)
            return True
        except TimeoutError:
            return False
        finally:
            futures = self._waiting.get(job_id, [])
            if future in futures:
                futures.remove(future)
            if not futures:
                self._waiting.pop(job_id, None)

    def _forget_connection(self) -> None:
        """Drop the connection after a failure (a restarted database server): the next lookup opens another."""
        if self._db is not None:
            with contextlib.suppress(Exception):
                self._db.close()
            self._db = None

    def _statuses(self, job_ids: list[int]) -> dict[int, str]:
        if self._db is None:
            self._db = connect(self.database, busy_timeout_ms=2000)
        return job_store.job_statuses(self._db, job_ids)

    async def _run(self) -> None:
        assert self._wakeup is not None
        while True:
            if not self._waiting:
                self._wakeup.clear()
                await self._wakeup.wait()
                continue
            job_ids = list(self._waiting)
            try:
                statuses = await anyio.to_thread.run_sync(self._statuses, job_ids)
            except Exception:  # a busy or unreachable database: waiters keep waiting, up to their timeout
                log.exception("looking up awaited jobs failed; retrying in %.0f s", ERROR_BACKOFF_S)
                self._forget_connection()
                await asyncio.sleep(ERROR_BACKOFF_S)
                continue
            for job_id in job_ids:
                status = statuses.get(job_id)
                if status is None or status in FINAL_STATUSES:
                    for future in self._waiting.get(job_id, []):
                        if not future.done():
                            future.set_result(None)
            await asyncio.sleep(self.poll_s)


class Answer(Protocol):
    """What a waited-for answer model has: its status and its job."""

    @property
    def status(self) -> str:
        """``queued``, ``processing``, ``done`` or ``failed``."""
        ...

    @property
    def job_id(self) -> int | None:
        """The job that answers it."""
        ...

    def model_dump(self, *, mode: str) -> dict[str, Any]:
        """Its JSON form (pydantic's)."""
        ...


A = TypeVar("A", bound=Answer)


async def answered(request: Request, job_id: int, wait_s: float, load: Callable[[], A]) -> A | JSONResponse:
    """After an upload: wait up to ``wait_s`` for ``job_id``, then ``load()`` (in a thread) the answer.

    Returns the model (200) when it is done or failed, else a 202 with it (poll its ``GET``).
    """
    waiter: JobWaiter = request.app.state.job_waiter
    await waiter.wait(job_id, wait_s)
    out = await run_in_threadpool(load)
    if out.status in ("done", "failed"):
        return out
    return JSONResponse(out.model_dump(mode="json"), status_code=status.HTTP_202_ACCEPTED)


async def long_poll(request: Request, wait_s: float, load: Callable[[], A]) -> A:
    """A read's long poll: ``load()`` (in a thread), and if not final wait up to ``wait_s`` for its job and reload."""
    out = await run_in_threadpool(load)
    if wait_s > 0 and out.status not in ("done", "failed") and out.job_id is not None:
        waiter: JobWaiter = request.app.state.job_waiter
        await waiter.wait(out.job_id, wait_s)
        out = await run_in_threadpool(load)
    return out
