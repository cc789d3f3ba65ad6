"""The broker's Redis transport (``workers/redis_transport.py``) and publisher with Redis down.

A failed acknowledgement still frees its prefetch slot; a publish that fails fails at once and leaves no epoll
descriptor open.
"""

from __future__ import annotations

import gc
import os
import socket
import time
from types import SimpleNamespace
from typing import Any

import pytest
import redis
from kombu import Connection
from kombu.transport import redis as kombu_redis
from kombu.transport import virtual

from workers.broker import CeleryPublisher, celery_app
from workers.redis_transport import QoS, Transport


class Unreachable:
    """A Redis pipeline whose broker went away."""

    def execute(self) -> None:
        raise redis.exceptions.ConnectionError("Error 111 connecting to 127.0.0.1:6379. Connection refused.")


def held(qos_class: type[Any]) -> Any:
    """A QoS (prefetch 1) holding one delivered message, whose acknowledgement cannot reach Redis."""
    qos = qos_class(channel=SimpleNamespace(do_restore=False), prefetch_count=1)  # nothing to restore at exit
    virtual.QoS.append(qos, object(), "tag-1")  # delivered: the prefetch slot is taken
    qos._remove_from_indices = lambda delivery_tag, pipe=None: Unreachable()
    assert not qos.can_consume()
    return qos


def test_a_failed_acknowledgement_frees_the_prefetch_slot_and_still_raises() -> None:
    qos = held(QoS)
    with pytest.raises(redis.exceptions.ConnectionError):
        qos.ack("tag-1")
    assert qos.can_consume()  # the consumer asks Redis for messages again (and so finds its connection dead)
    stuck = held(kombu_redis.QoS)  # kombu's own: the slot stays taken, the consumer never takes another message
    with pytest.raises(redis.exceptions.ConnectionError):
        stuck.ack("tag-1")
    assert not stuck.can_consume()


def test_the_celery_app_uses_it_for_the_redis_url() -> None:
    app = celery_app("redis://127.0.0.1:6379/3")
    with app.connection_for_read() as connection:
        assert isinstance(connection, Connection)
        assert connection.transport_cls is not None and connection.get_transport_cls() is Transport
        assert (connection.hostname, connection.port, connection.virtual_host) == ("127.0.0.1", 6379, "3")
        assert connection.transport.Channel.QoS is QoS


def epolls() -> int:
    """The open epoll descriptors of the test's process."""
    links = []
    for fd in os.listdir("/proc/self/fd"):
        try:
            links.append(os.readlink(f"/proc/self/fd/{fd}"))
        except OSError:  # the listing's own descriptor, closed since
            continue
    return sum(link == "anon_inode:[eventpoll]" for link in links)


def test_publishes_failing_with_redis_down_fail_at_once_and_leave_no_epoll_open() -> None:
    """Kombu retried each for 6 s, and its transport opened an epoll per try, closed when the collector came by."""
    with socket.socket() as probe:  # a port nothing listens on: Redis is down
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    publisher = CeleryPublisher(f"redis://127.0.0.1:{port}/1")
    gc.collect()
    gc.disable()  # as in a process whose full collections are rare: what is left to the collector stays
    try:
        before, started = epolls(), time.monotonic()
        assert [publisher.send([job_id]) for job_id in range(10)] == [[]] * 10
        assert time.monotonic() - started < 5.0
        assert epolls() == before
    finally:
        gc.enable()
