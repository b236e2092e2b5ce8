"""Record topics to a bag (rosbag2, MCAP): the CDR bytes as received, stamped at reception.

Each message is written as received, never deserialised: a raw subscription hands over its
serialized bytes. The subscriptions are taken in batches every ``poll_period``
(:mod:`exo_has_runtime.polling`): a recorder has nothing to do the moment a message arrives,
and a callback per message would wake the executor some 2000 times a second in a session
(bench/README.md, "Recorder"). Its bag time is the system time at which DDS received it, as
rosbag2's ``recv_timestamp`` is; under ``use_sim_time`` it is the simulated time of the batch
(0 before the first ``/clock``), up to ``poll_period`` after the reception. With
``poll_period`` 0 each message has its callback and its bag time is read there (the system
time with ``time.time_ns()``, the same clock at a thirtieth of the cost of ``Clock.now()``).
Whether simulated time is active is checked again every ``discovery_period``. Topics and types
come from graph discovery, every ``discovery_period``; a topic is subscribed once it has a
publisher, with the QoS :mod:`exo_has_runtime.recording` derives from the publishers' offers.
A topic that came steadily and stops for a while (a lost link) is logged as a gap when it
comes back (:mod:`exo_has_common.bags.gaps`; ``exo-has bag info`` lists them from the bag).
The bag is flushed as a complete chunk every ``flush_period``, so a killed recorder loses at
most that much (``exo-has bag recover``), and is closed (``metadata.yaml`` written, after a
last batch is taken) when the node is destroyed, which
:func:`~exo_has_runtime.execution.run_node` does on SIGINT and SIGTERM.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from datetime import datetime
from typing import Any

from rcl_interfaces.msg import FloatingPointRange, ParameterDescriptor
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.subscription import Subscription

from exo_has_common.bag import BagWriter, offered_qos
from exo_has_common.bags.gaps import Gap, GapFinder
from exo_has_common.errors import BagError
from exo_has_runtime.execution import run_node
from exo_has_runtime.message_types import message_class
from exo_has_runtime.polling import Inbox, Taken
from exo_has_runtime.recording import (
    QosChoice,
    bag_path,
    subscription_qos,
    topics_to_record,
    weakened_qos,
)


class Recorder(Node):
    """Subscribe to the topics of the graph (or the given ones) and write them to a bag."""

    def __init__(self, **options: Any) -> None:
        # options: Node's keyword arguments (cli_args, context, ...), so that a container
        # can compose this node with others in one process (exo_has_runtime.container).
        super().__init__('recorder', **options)
        self.declare_parameter('output', '', ParameterDescriptor(
            description='bag directory to create; empty: '
                        '~/.ros/exo_has_bags/session_<YYYYmmdd_HHMMSS>'))
        # Dynamically typed: an empty list default would otherwise fix the type to a byte array.
        self.declare_parameter('topics', [], ParameterDescriptor(
            description='topics to record (string array); empty: every topic of the graph '
                        'but the hidden ones and ros_discovery_info', dynamic_typing=True))
        self.declare_parameter('discovery_period', 0.5, ParameterDescriptor(
            description='period of the search for new topics [s]',
            floating_point_range=[FloatingPointRange(from_value=0.01, to_value=60.0)]))
        self.declare_parameter('flush_period', 1.0, ParameterDescriptor(
            description='period of the writes to disk [s]: what a crash may lose',
            floating_point_range=[FloatingPointRange(from_value=0.05, to_value=60.0)]))
        self.declare_parameter('compress', False, ParameterDescriptor(
            description='compress the chunks with zstd'))
        self.declare_parameter('poll_period', 0.02, ParameterDescriptor(
            description='period of the batches taken from the subscriptions [s]; 0: a '
                        'callback per message',
            floating_point_range=[FloatingPointRange(from_value=0.0, to_value=1.0)]))
        topics = self.get_parameter('topics').value or []
        if not isinstance(topics, list) or not all(isinstance(t, str) for t in topics):
            msg = f'parameter topics must be a list of topic names, got {topics!r}'
            raise ValueError(msg)
        self._wanted = {self.resolve_topic_name(topic) for topic in topics} or None
        self._path = bag_path(self.get_parameter('output').value, datetime.now())
        try:
            self._bag: BagWriter | None = BagWriter(
                self._path, compress=bool(self.get_parameter('compress').value))
        except BagError as exc:  # a bad configuration: run_node reports it in one line
            msg = f'parameter output: {exc}'
            raise ValueError(msg) from exc
        self._sim_time = self.get_clock().ros_time_is_active
        self._gaps = GapFinder()
        # Topic: (subscription, the QoS it asks for).
        self._recorded: dict[str, tuple[Subscription, QosChoice]] = {}
        self._given_up: set[str] = set()
        # Discovery, batches and disk writes run on wall time, also while simulated time
        # stands still.
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        poll_period = self.get_parameter('poll_period').value
        self._inbox = Inbox(self) if poll_period > 0.0 else None
        if self._inbox is not None:
            self.create_timer(poll_period, self._take_batch, clock=steady)
        self.create_timer(self.get_parameter('discovery_period').value, self._discover,
                          clock=steady)
        self.create_timer(self.get_parameter('flush_period').value, self._flush, clock=steady)
        wanted = ', '.join(sorted(self._wanted)) if self._wanted else 'every topic'
        self.get_logger().info(f'opened bag {self._path}; waiting for publishers on {wanted}')
        self._discover()

    def _discover(self) -> None:
        self._sim_time = self.get_clock().ros_time_is_active
        new, ambiguous = topics_to_record(self.get_topic_names_and_types(), self._wanted,
                                          {*self._recorded, *self._given_up})
        for topic, types in ambiguous:
            self._give_up(topic, f'it carries several types ({", ".join(types)})')
        for topic, (subscription, choice) in list(self._recorded.items()):
            weaker = weakened_qos(choice, self._offers(topic))
            if weaker is not None:
                self.get_logger().warning(
                    f'{topic}: a publisher offers less than the recording asked for; '
                    f'subscribing again {_describe(weaker)}')
                self._recorded[topic] = (self._subscription(
                    subscription, subscription.msg_type, topic, qos_profile(weaker)), weaker)
        added = 0
        for topic, msgtype in new:
            offers = self._offers(topic)
            if offers and self._subscribe(topic, msgtype, offers):
                added += 1
        if added:
            self.get_logger().info(
                f'recording {len(self._recorded)} topics to {self._path}')

    def _subscribe(self, topic: str, msgtype: str, offers: list[Any]) -> bool:
        assert self._bag is not None
        try:
            message_type = message_class(msgtype)
            self._bag.add_topic(topic, msgtype, [offered_qos(offer) for offer in offers])
        except Exception as exc:  # one topic of an unknown type must not stop the others
            self._give_up(topic, str(exc))
            return False
        choice = subscription_qos(offers)
        self._recorded[topic] = (
            self._subscription(None, message_type, topic, qos_profile(choice)), choice)
        return True

    def _subscription(self, replaced: Subscription | None, message_type: type, topic: str,
                      qos: QoSProfile) -> Subscription:
        """Subscribe (raw) to a topic for the bag, in place of ``replaced`` if given."""
        if self._inbox is not None:
            if replaced is not None:
                self._write(self._inbox.unsubscribe(topic))
            return self._inbox.subscribe(topic, message_type, topic, qos, raw=True)
        if replaced is not None:
            self.destroy_subscription(replaced)
        return self.create_subscription(message_type, topic, self._writer_for(topic), qos,
                                        raw=True)

    def _take_batch(self) -> None:
        if self._inbox is not None:
            self._write(self._inbox.drain())

    def _write(self, batch: list[Taken]) -> None:
        if self._bag is None or not batch:
            return
        write, gap_after = self._bag.write, self._gaps.take
        if self._sim_time:
            now_ns = self.get_clock().now().nanoseconds
            for taken in batch:
                write(taken.topic, now_ns, taken.data)
        else:
            for taken in batch:
                write(taken.topic, taken.received_ns, taken.data)
                if (gap := gap_after(taken.topic, taken.received_ns)) is not None:
                    self._log_gap(gap)

    def _offers(self, topic: str) -> list[Any]:
        return [info.qos_profile for info in self.get_publishers_info_by_topic(topic)]

    def _writer_for(self, topic: str) -> Callable[[bytes], None]:
        bag, clock, wall_ns = self._bag, self.get_clock(), time.time_ns
        assert bag is not None
        write = bag.write

        def on_message(data: bytes) -> None:
            if self._sim_time:
                write(topic, clock.now().nanoseconds, data)
                return
            now_ns = wall_ns()
            write(topic, now_ns, data)
            if (gap := self._gaps.take(topic, now_ns)) is not None:
                self._log_gap(gap)
        return on_message

    def _log_gap(self, gap: Gap) -> None:
        self.get_logger().warning(f'gap in the recording: {gap.describe()}')

    def _give_up(self, topic: str, reason: str) -> None:
        self._given_up.add(topic)
        self.get_logger().warning(f'not recording {topic}: {reason}')

    def _flush(self) -> None:
        if self._bag is not None:
            self._bag.flush()

    def destroy_node(self) -> None:
        """Take a last batch, close the bag (metadata.yaml written), log its counts, leave."""
        inbox, self._inbox = getattr(self, '_inbox', None), None
        if inbox is not None:
            self._write(inbox.drain())
            inbox.destroy()
        bag, self._bag = getattr(self, '_bag', None), None
        if bag is not None:
            try:
                counts = bag.close()
            except BagError as exc:
                self.get_logger().error(str(exc))
            else:
                listed = ', '.join(f'{topic}: {count}' for topic, count in sorted(counts.items()))
                self.get_logger().info(f'closed {bag.path}: {sum(counts.values())} messages'
                                       + (f' ({listed})' if listed else ''))
        super().destroy_node()


def qos_profile(choice: QosChoice) -> QoSProfile:
    """Return the rclpy QoS profile of a recording's or replay's choice (keep last)."""
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST, depth=choice.depth,
        reliability=ReliabilityPolicy.RELIABLE if choice.reliable
        else ReliabilityPolicy.BEST_EFFORT,
        durability=DurabilityPolicy.TRANSIENT_LOCAL if choice.transient_local
        else DurabilityPolicy.VOLATILE)


def _describe(choice: QosChoice) -> str:
    return (f'{"reliable" if choice.reliable else "best effort"}, '
            f'{"transient local" if choice.transient_local else "volatile"}')


def main(args: list[str] | None = None) -> None:
    """Record until interrupted (SIGINT or SIGTERM), then close the bag."""
    run_node(Recorder, args, name='recorder')


if __name__ == '__main__':
    main()
