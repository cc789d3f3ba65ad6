"""Kombu's Redis transport with two fixes for a broker that goes away: failed acknowledgements and abandoned polls.

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

Kombu 5.7's ``MultiChannelPoller`` opens an epoll file descriptor when its transport is made and never closes it:
it goes only when the garbage collector finds the transport, which its channels keep in a reference cycle. Every
publish that fails while Redis is down makes a transport and abandons it, so an API process under load held one
more descriptor per failed publish until a full collection (measured: +10 open files in one API process across a
20 s Redis outage of the distributed soak, still held minutes later). Publishing never polls, and a Celery worker
polls with its event loop's poller (``on_poll_init``), so here the transport's own poller is opened only when
something uses it.

Selected by ``broker_transport`` (:func:`workers.broker.celery_app`); the URL stays ``redis://``.
"""

from __future__ import annotations

from typing import Any

from kombu.transport import redis, virtual
from kombu.utils.eventio import poll


class QoS(redis.QoS):
    """Redis QoS whose :meth:`ack` frees the prefetch slot even when Redis cannot be told."""

    def ack(self, delivery_tag: Any) -> None:
        """Remove the message from Redis's unacked index and from the local state; the latter always."""
        try:
            super().ack(delivery_tag)  # type: ignore[no-untyped-call]
        except Exception:  # forget it here all the same; the broker's error still propagates
            virtual.QoS.ack(self, delivery_tag)  # type: ignore[no-untyped-call]
            raise


class LazyPoll:
    """``kombu.utils.eventio.poll()``, opened on first use: a transport that never polls holds no epoll."""

    def __init__(self) -> None:
        self._poll: Any = None

    def __getattr__(self, name: str) -> Any:
        """``register``, ``poll``, ...: those of the poll, opened now if not yet."""
        if self._poll is None:
            self._poll = poll()  # type: ignore[no-untyped-call]
        return getattr(self._poll, name)

    def close(self) -> None:
        """Close the poll if it was opened."""
        if self._poll is not None:
            self._poll.close()
            self._poll = None


class MultiChannelPoller(redis.MultiChannelPoller):
    """Kombu's poller of the Redis channels, with a :class:`LazyPoll`."""

    def __init__(self) -> None:
        super().__init__()  # type: ignore[no-untyped-call]
        self.poller.close()  # the one kombu opened: unused yet
        self.poller = LazyPoll()


class Channel(redis.Channel):
    """The Redis channel with :class:`QoS`."""

    QoS = QoS


class Transport(redis.Transport):
    """The Redis transport with :class:`Channel` and :class:`MultiChannelPoller`."""

    Channel = Channel

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)  # type: ignore[no-untyped-call]
        opened: Any = self.cycle  # kombu's poller, its epoll open: closed here, not left to the GC
        opened.poller.close()
        self.cycle = MultiChannelPoller()  # type: ignore[assignment]
