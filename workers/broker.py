"""The distributed profile's task queue: Celery on Redis, carrying job ids only.

The database stays the source of truth for every job (status, attempts, lease, result); a broker
message says no more than "job N may be claimable now". So:

- the API commits the job first, then publishes its id (:class:`CeleryPublisher`) and records when
  (``jobs.published_at``); a failed publish is only logged;
- a worker that receives an id claims that job in the database (:func:`db.jobs.claim_job_by_id`); a
  duplicate message, or one for a job that waits for its retry delay, claims nothing and is dropped;
- the reconciler (:func:`reconcile`, run by every worker process about once a second) publishes again
  what no message will bring: a job committed but never published (the API died in between, or the
  broker was down), a retry whose delay passed, a job whose worker died (its lease expired), and,
  when the broker's queue is empty, any claimable job published more than :data:`REPUBLISH_AFTER_S`
  ago (its message was lost with a broker restart).

Delivery is therefore at least once; the handlers are idempotent (they compute first and write once,
with replace semantics), so a job delivered twice never stores a reference or an answer twice.
A message is acknowledged when a worker process starts its task (early acknowledgement, prefetch of
one per process): a worker killed mid-job is recovered by the job's lease in the database, not by the
broker redelivering, so no acknowledgement is ever owed to a broker that restarted meanwhile (a late
acknowledgement that failed during a Redis outage left the Celery consumer stuck in our fault test). An early
acknowledgement can fail too, for a message that waited in the worker for a free process while Redis went away:
kombu's Redis transport then kept it counted against the prefetch limit, which stalled the consumer; the transport
of :mod:`workers.redis_transport` frees the slot.

The embedded profile has no broker: its workers claim straight from the table (:class:`NoPublisher`).
"""

from __future__ import annotations

import logging
import time
from typing import TYPE_CHECKING, Any, Protocol

from db import Database, transaction
from db import jobs as job_store

if TYPE_CHECKING:
    from celery import Celery

    from contracts.settings import Settings

log = logging.getLogger("geoloc.broker")

QUEUE = "geoloc-jobs"
"""The broker queue (a Redis list of this name) that carries job ids."""
RUN_JOB_TASK = "geoloc.run_job"
"""Name of the Celery task that claims and runs one job by id (:mod:`workers.celery_worker`)."""
UNPUBLISHED_GRACE_S = 2.0
"""A job this old that was never published is published by the reconciler (the API publishes at once)."""
REPUBLISH_AFTER_S = 5.0
"""With the broker's queue empty, a claimable job published longer ago than this lost its message."""
RECONCILE_INTERVAL_S = 1.0
"""How often each worker process reconciles the table with the broker."""
REDIS_TRANSPORT = "workers.redis_transport:Transport"
"""The kombu transport of the ``redis://`` broker URL (:mod:`workers.redis_transport`)."""
VISIBILITY_TIMEOUT_S = 3600
"""Redis gives a message reserved but not yet acknowledged (its worker died before starting it) to another
worker after this long; the reconciler usually publishes such a job again much sooner."""


class JobPublisher(Protocol):
    """Hands new jobs to the workers."""

    def publish(self, db: Database, job_ids: list[int]) -> None:
        """Tell the workers that these committed jobs may be claimed."""


class NoPublisher:
    """The embedded profile: the built-in workers poll the jobs table, nothing to publish."""

    def publish(self, db: Database, job_ids: list[int]) -> None:
        """Nothing to do."""


def celery_app(broker_url: str) -> Celery:
    """The Celery application of the distributed profile (job ids over Redis, no result backend)."""
    from celery import Celery

    app = Celery("geoloc", broker=broker_url, set_as_current=False)
    app.conf.update(
        broker_transport=REDIS_TRANSPORT,  # kombu's, but a failed acknowledgement frees its prefetch slot
        task_default_queue=QUEUE,
        task_acks_late=False,  # a job whose worker died comes back through its lease, not the broker
        worker_cancel_long_running_tasks_on_connection_loss=False,  # a running job keeps its lease
        task_ignore_result=True,
        task_serializer="json",
        accept_content=["json"],
        worker_prefetch_multiplier=1,
        worker_hijack_root_logger=False,
        worker_enable_remote_control=False,  # liveness is the workers table (GEOLOC_READY_WORKER_S)
        worker_send_task_events=False,
        broker_connection_retry_on_startup=True,
        broker_connection_max_retries=None,
        broker_connection_timeout=3,
        broker_transport_options={
            "visibility_timeout": VISIBILITY_TIMEOUT_S,
            "socket_connect_timeout": 3,
            # A publish tries the connection once: with Redis down kombu would retry it for broker_connection_timeout
            # plus its retry interval (6 s per upload, holding an API thread); the reconciler publishes the job later.
            # The worker's consumer reconnects by its own retries (broker_connection_max_retries).
            "max_retries": 0,
        },
    )
    return app


class CeleryPublisher:
    """Publishes job ids to the Celery queue and records when (``jobs.published_at``)."""

    def __init__(self, broker_url: str) -> None:
        self.broker_url = broker_url
        self.app = celery_app(broker_url)

    def send(self, job_ids: list[int]) -> list[int]:
        """Send one message per id; returns the ids sent (a broker error is logged, the rest skipped)."""
        sent: list[int] = []
        for job_id in job_ids:
            try:
                self.app.send_task(RUN_JOB_TASK, args=[job_id], queue=QUEUE, retry=False)
            except Exception as exc:  # the reconciler publishes it once the broker is back
                log.warning("could not publish job %s (%s); the reconciler will publish it", job_id, exc)
                break
            sent.append(job_id)
        return sent

    def publish(self, db: Database, job_ids: list[int]) -> None:
        """Send the ids and mark them published."""
        sent = self.send(job_ids)
        if sent:
            job_store.mark_published(db, sent)

    def queue_length(self) -> int:
        """Messages waiting in the broker's queue."""
        return int(redis_client(self.broker_url).llen(QUEUE))


def publisher_for(settings: Settings) -> JobPublisher:
    """:class:`CeleryPublisher` in the distributed profile, else :class:`NoPublisher`."""
    if settings.broker_url is None:
        return NoPublisher()
    return CeleryPublisher(settings.broker_url)


_redis_clients: dict[str, Any] = {}


def redis_client(url: str) -> Any:
    """A ``redis.Redis`` for ``url`` (one per process and URL, thread-safe, short timeouts)."""
    client = _redis_clients.get(url)
    if client is None:
        import redis
        from redis.backoff import NoBackoff
        from redis.retry import Retry

        client = redis.Redis.from_url(  # no retries: a caller that finds Redis away carries on without it
            url, socket_connect_timeout=2, socket_timeout=5, health_check_interval=30, retry=Retry(NoBackoff(), 0)
        )
        _redis_clients[url] = client
    return client


def broker_problem(url: str) -> str | None:
    """None when the broker answers a ping, else why not."""
    try:
        redis_client(url).ping()
    except Exception as exc:
        return f"broker unreachable: {type(exc).__name__}: {exc}"
    return None


def reconcile(db: Database, publisher: CeleryPublisher, now: float | None = None) -> list[int]:
    """Fail exhausted jobs of dead workers and publish again the jobs no message will bring; returns their ids.

    See the module docstring for which jobs; safe to run from many processes at once.
    """
    now = time.time() if now is None else now
    try:
        queue_empty = publisher.queue_length() == 0
    except Exception as exc:  # broker down: nothing can be published now anyway
        log.debug("reconcile: broker unreachable (%s)", exc)
        return []
    with transaction(db):
        job_store.fail_exhausted_jobs(db, now)
        job_ids = job_store.jobs_to_publish(
            db,
            now,
            unpublished_grace_s=UNPUBLISHED_GRACE_S,
            republish_before=now - REPUBLISH_AFTER_S if queue_empty else None,
        )
    if job_ids:
        sent = publisher.send(job_ids)
        log.info("reconcile: published %d job(s) again: %s", len(sent), sent)
        unsent = sorted(set(job_ids) - set(sent))
        if unsent:  # not sent after all: let the next round take them again
            job_store.mark_unpublished(db, unsent)
    return job_ids
