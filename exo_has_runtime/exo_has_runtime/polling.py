"""Subscriptions taken in batches from a timer, not by a callback per message.

On this project's target machines a message that wakes an executor costs more in scheduling
than in work (bench/README.md, "Why messaging costs so much here"): rclpy's EventsExecutor
wakes its thread once per message, on top of the DDS receive thread. A node that only stores
what it hears (the recorder) needs no such wake-up; it may take everything queued every few
milliseconds. rclpy offers no subscription without a callback, and an executor registers one
for every subscription of the nodes it spins, so the subscriptions live on a second node of
the same context, ``<name>_inbox``, which no executor spins; the owner's timer drains them.
DDS still queues every message (up to the subscription's depth) and stamps its reception, so
nothing is lost and the reception times are those a callback would have seen.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

from rclpy.exceptions import InvalidHandle
from rclpy.node import Node
from rclpy.qos import QoSProfile
from rclpy.subscription import Subscription

#: Suffix of the name of the node that holds an owner's polled subscriptions.
INBOX_SUFFIX = '_inbox'


@dataclass(frozen=True)
class Taken:
    """One message taken from a polled subscription.

    Attributes
    ----------
    topic : str
        The subscription's key (the owner's name for the topic).
    data : Any
        The message, or its CDR bytes for a raw subscription.
    received_ns : int
        When DDS received it, on the system clock [ns].

    """

    topic: str
    data: Any
    received_ns: int


class Inbox:
    """Subscriptions of an owner node that its timer drains, none of them waking an executor.

    Parameters
    ----------
    owner : Node
        The node the subscriptions serve; the inbox node shares its context and namespace.

    """

    def __init__(self, owner: Node) -> None:
        # use_global_arguments=False: a command line's `-r __node:=other` must rename the owner
        # only, not give two nodes one name; the owner resolves every topic name itself.
        self._node = Node(owner.get_name() + INBOX_SUFFIX, namespace=owner.get_namespace(),
                          context=owner.context, use_global_arguments=False,
                          enable_rosout=False, start_parameter_services=False)
        self._subscriptions: dict[str, Subscription] = {}

    @property
    def node_name(self) -> str:
        """Name of the node that holds the subscriptions."""
        return self._node.get_name()

    def subscribe(self, key: str, message_type: type, topic: str, qos: QoSProfile,
                  raw: bool = False) -> Subscription:
        """Subscribe to ``topic`` under ``key``.

        Raises
        ------
        ValueError
            If ``key`` is subscribed already (:meth:`unsubscribe` returns what it held).

        """
        if key in self._subscriptions:
            msg = f'{key} is subscribed already: unsubscribe it first'
            raise ValueError(msg)
        subscription = self._node.create_subscription(message_type, topic, _never_called, qos,
                                                      raw=raw)
        self._subscriptions[key] = subscription
        return subscription

    def unsubscribe(self, key: str) -> list[Taken]:
        """Drop the subscription of ``key``; return what it still held."""
        subscription = self._subscriptions.pop(key)
        left = list(_take_all(key, subscription))
        self._node.destroy_subscription(subscription)
        return left

    def drain(self) -> list[Taken]:
        """Take every queued message of every subscription, in order of reception."""
        taken = [message for key, subscription in self._subscriptions.items()
                 for message in _take_all(key, subscription)]
        taken.sort(key=lambda message: message.received_ns)
        return taken

    def destroy(self) -> None:
        """Leave the graph (undrained messages are dropped: drain first)."""
        self._subscriptions.clear()
        self._node.destroy_node()


def _take_all(key: str, subscription: Subscription) -> Iterator[Taken]:
    try:
        with subscription.handle:
            take = subscription.handle.take_message
            while (taken := take(subscription.msg_type, subscription.raw)) is not None:
                message, info = taken
                yield Taken(key, message, int(info['received_timestamp']))
    except InvalidHandle:  # destroyed with its node on shutdown: nothing left to take
        return


def _never_called(_: object) -> None:  # pragma: no cover - no executor spins the inbox node
    msg = 'a polled subscription was given to an executor'
    raise AssertionError(msg)
