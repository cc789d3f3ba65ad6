"""The broker's Redis transport (``workers/redis_transport.py``): a failed acknowledgement still frees its slot."""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any

import pytest
import redis
from kombu import Connection
from kombu.transport import redis as kombu_redis
from kombu.transport import virtual

from workers.broker import celery_app
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
