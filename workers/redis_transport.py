"""Kombu's Redis transport with one fix: an acknowledgement that fails with the broker frees its prefetch slot.

Kombu 5.7's Redis ``QoS.ack`` first removes the message from Redis's unacked index and only then forgets it
locally; when the removal raises (Redis was killed while the message waited in the worker for a free pool process,
so its early acknowledgement came after), the message stays counted against the prefetch limit for good. Once
every slot (``worker_prefetch_multiplier`` x concurrency) is held so, the consumer stops asking Redis for messages,
and since it no longer reads from its dead connection it never reconnects either: measured in the distributed
soak (``benchmarks/bench_soak.py``), until the consumer watchdog (:func:`workers.celery_worker.watch_consumer`)
killed the worker 30 s later, its running jobs with it. Here the message is forgotten locally whatever the broker
answered, and the error still propagates (Celery logs "Couldn't ack"). Nothing is lost: a restarted Redis has no
unacked index left, and a message that stayed in a live one is delivered again after the visibility timeout, a
duplicate the job table drops (:mod:`workers.broker`).

Selected by ``broker_transport`` (:func:`workers.broker.celery_app`); the URL stays ``redis://``.
"""

from __future__ import annotations

from typing import Any

from kombu.transport import redis, virtual


class QoS(redis.QoS):
    """Redis QoS whose :meth:`ack` frees the prefetch slot even when Redis cannot be told."""

    def ack(self, delivery_tag: Any) -> None:
        """Remove the message from Redis's unacked index and from the local state; the latter always."""
        try:
            super().ack(delivery_tag)  # type: ignore[no-untyped-call]
        except Exception:  # forget it here all the same; the broker's error still propagates
            virtual.QoS.ack(self, delivery_tag)  # type: ignore[no-untyped-call]
            raise


class Channel(redis.Channel):
    """The Redis channel with :class:`QoS`."""

    QoS = QoS


class Transport(redis.Transport):
    """The Redis transport with :class:`Channel`."""

    Channel = Channel
